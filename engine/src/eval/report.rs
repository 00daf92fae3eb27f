//! The evaluation report: every number with its provenance and settings (`report.json`), and
//! a human-readable table.
//!
//! Per-frame curves ([`Curve`]) are indexed by frames relative to the first forecast frame:
//! value `i` belongs to frame offset `first_offset + i` (negative offsets are observed frames;
//! NDMS word `i` starts at offset `i − lead`; speed step `i` ends at offset `first_offset + i`).
//! Aggregates over scenes weight each scene by its persons (per-frame curves) or by its
//! persons × forecast frames (plausibility); `null` in JSON marks "nothing to score".

use crate::metrics::distance::SampleStats;
use serde::Serialize;
use serde_json::{Map, Value};
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// A per-frame curve (module docs).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Curve {
    /// Frame offset of `values[0]` from the first forecast frame.
    pub first_offset: i64,
    /// Values; NaN (`null`) where no scene contributes.
    pub values: Vec<f64>,
}

impl Curve {
    /// `(seconds from the first forecast frame, value)` of every finite value.
    pub fn points(&self, fps: f64) -> Vec<(f64, f64)> {
        self.values.iter().enumerate().filter(|(_, v)| v.is_finite()).map(|(i, &v)| ((self.first_offset + i as i64) as f64 / fps, v)).collect()
    }

    /// The value at frame offset `offset`, if finite.
    pub fn at(&self, offset: i64) -> Option<f64> {
        let i = usize::try_from(offset - self.first_offset).ok()?;
        self.values.get(i).copied().filter(|v| v.is_finite())
    }
}

/// A scene of the reference split.
#[derive(Clone, Debug, Serialize)]
pub struct ReferenceScene {
    /// Sequence name.
    pub name: String,
    /// Frames.
    pub frames: usize,
    /// Persons.
    pub persons: usize,
}

/// The reference dataset.
#[derive(Clone, Debug, Serialize)]
pub struct ReferenceInfo {
    /// Where it was read from.
    pub path: String,
    /// Dataset name.
    pub dataset: String,
    /// Scored split.
    pub split: String,
    /// Frames per second.
    pub fps: f64,
    /// Skeleton name and joints.
    pub skeleton: String,
    /// Joint names.
    pub joints: Vec<String>,
    /// Scenes of the split.
    pub scenes: Vec<ReferenceScene>,
    /// The dataset's own metadata (source, licence, notes).
    pub metadata: Map<String, Value>,
}

/// One input directory of a method.
#[derive(Clone, Debug, Serialize)]
pub struct InputReport {
    /// Directory.
    pub path: String,
    /// Dataset name.
    pub dataset: String,
    /// Its `dataset.json` metadata (forecast provenance).
    pub provenance: Map<String, Value>,
}

/// One scored scene of a method.
#[derive(Clone, Debug, Serialize)]
pub struct SceneReport {
    /// Reference scene.
    pub name: String,
    /// Persons.
    pub persons: usize,
    /// Observed frames.
    pub observed_frames: usize,
    /// Forecast frames.
    pub forecast_frames: usize,
    /// Samples K.
    pub samples: usize,
    /// NDMS of this scene (all samples and persons), when scored.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ndms: Option<f64>,
}

/// NDMS of a method.
#[derive(Clone, Debug, Serialize)]
pub struct NdmsReport {
    /// Mean over every scored word of every sample, person and scene.
    pub mean: f64,
    /// Mean per word index (word `i` starts at offset `i − lead`).
    pub per_frame: Curve,
    /// Query words scored.
    pub words: usize,
    /// Seconds spent scoring (nearest neighbours + ψ).
    pub seconds: f64,
}

/// Pose errors at one horizon.
#[derive(Clone, Debug, Serialize)]
pub struct HorizonReport {
    /// Seconds after the last observed frame.
    pub horizon_s: f64,
    /// Forecast frame index (`round(h·fps) − 1`).
    pub frame: usize,
    /// Scenes whose forecast reaches it.
    pub scenes: usize,
    /// MPJPE of all joints (m): mean over K and best of K.
    pub global: Option<SampleStats>,
    /// Error of the hip midpoint (m).
    pub root: Option<SampleStats>,
    /// MPJPE after aligning the hip midpoints (m).
    pub root_aligned: Option<SampleStats>,
}

/// MPJPE of a method.
#[derive(Clone, Debug, Serialize)]
pub struct MpjpeReport {
    /// At each requested horizon.
    pub horizons: Vec<HorizonReport>,
    /// Per forecast frame, mean over samples (m).
    pub global_per_frame: Curve,
    /// Root error per forecast frame (m).
    pub root_per_frame: Curve,
    /// Root-aligned MPJPE per forecast frame (m).
    pub root_aligned_per_frame: Curve,
}

/// Stochastic errors of a method (m), over the first `frames` forecast frames.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StochasticReport {
    /// Frames scored per scene (at most).
    pub frames: usize,
    /// Average pairwise distance between samples.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub apd: Option<f64>,
    /// Average displacement error, best of K.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ade: Option<f64>,
    /// Final displacement error, best of K.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fde: Option<f64>,
    /// Multimodal ADE.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mmade: Option<f64>,
    /// Multimodal FDE.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mmfde: Option<f64>,
    /// Mean number of alternative futures per person (multimodal metrics).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub alternatives_per_person: Option<f64>,
}

/// Joint speed of a method.
#[derive(Clone, Debug, Serialize)]
pub struct SpeedReport {
    /// Mean joint speed (m/s) per frame step, mean over samples; step `i` ends at offset
    /// `first_offset + i`.
    pub per_frame: Curve,
    /// Mean over the forecast steps (m/s).
    pub forecast_mean: f64,
}

/// Physical plausibility of a method.
#[derive(Clone, Debug, Default, Serialize)]
pub struct PlausibilityReport {
    /// Mean absolute bone-length deviation from the observed part (mm).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bone_length_mm: Option<f64>,
    /// Mean joint acceleration (m/s²), from the last observed frames on.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub acceleration_m_s2: Option<f64>,
    /// Mean joint jerk (m/s³), from the last observed frames on.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub jerk_m_s3: Option<f64>,
    /// Horizontal speed of planted ankles (m/s); `null` when no foot was planted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub foot_sliding_m_s: Option<Option<f64>>,
    /// JS distance between forecast and real joint-speed histograms per time bin.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub speed_js_per_bin: Option<Vec<Option<f64>>>,
    /// Mean of `speed_js_per_bin` over the bins with a value.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub speed_js_mean: Option<f64>,
    /// The jump into the forecast, over the scenes with two observed frames or more.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub first_step: Option<FirstStepReport>,
}

/// How far the first forecast frame moves from the last observed one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct FirstStepReport {
    /// Scenes whose every sample moves no joint at the first forecast frame farther than the
    /// largest frame-to-frame joint move of its observed frames.
    pub within_observed: usize,
    /// Scenes scored.
    pub scenes: usize,
    /// Mean over scenes of the largest first-frame joint move of any sample (m).
    pub mean_largest_m: f64,
    /// The largest first-frame move over the largest observed move, worst scene.
    pub worst_ratio: f64,
}

/// SSCP of a method: a score, or why it was skipped.
#[derive(Clone, Debug, Serialize)]
pub struct SscpReport {
    /// JS distance to the reference's transition distribution.
    pub value: Option<f64>,
    /// Why SSCP was not computed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub skipped: Option<String>,
    /// The method's 16×16 transition distribution (rows: from-state).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub transitions: Option<Vec<Vec<f64>>>,
    /// The reference's distribution over the same scenes and frames.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference_transitions: Option<Vec<Vec<f64>>>,
}

/// Everything measured for one method.
#[derive(Clone, Debug, Serialize)]
pub struct MethodReport {
    /// Label.
    pub label: String,
    /// `forecasts`, `dataset` or `baseline:NAME`.
    pub kind: String,
    /// Input directories with their provenance.
    pub inputs: Vec<InputReport>,
    /// Settings that produced the method (baselines).
    pub settings: Map<String, Value>,
    /// Scored scenes.
    pub scenes: Vec<SceneReport>,
    /// NDMS.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ndms: Option<NdmsReport>,
    /// MPJPE.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mpjpe: Option<MpjpeReport>,
    /// APD, ADE, FDE, MMADE, MMFDE.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stochastic: Option<StochasticReport>,
    /// Joint speed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub speed: Option<SpeedReport>,
    /// Plausibility.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub plausibility: Option<PlausibilityReport>,
    /// SSCP.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sscp: Option<SscpReport>,
    /// Precision and recall of motion words.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub coverage: Option<crate::metrics::coverage::Coverage>,
    /// Motion-kind distribution against the reference's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub kinds: Option<crate::metrics::kinds::KindDistribution>,
}

/// The whole evaluation.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// socdiff version that wrote it.
    pub socdiff_version: String,
    /// Caller's provenance (command line, time).
    pub provenance: Map<String, Value>,
    /// The reference.
    pub reference: ReferenceInfo,
    /// Every setting that affects a number.
    pub settings: Map<String, Value>,
    /// Metrics computed.
    pub metrics: Vec<String>,
    /// Real joint speed of the reference scenes (aligned like the first method's scenes).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference_speed: Option<Curve>,
    /// Methods, in the order given.
    pub methods: Vec<MethodReport>,
}

fn fmt_opt(v: Option<f64>, scale: f64, digits: usize) -> String {
    match v {
        Some(v) if v.is_finite() => format!("{:.*}", digits, v * scale),
        _ => "-".into(),
    }
}

/// Column-aligned text table: a header row and rows of cells.
fn table(title: &str, header: &[String], rows: &[Vec<String>]) -> String {
    let cols = header.len();
    let width: Vec<usize> = (0..cols).map(|c| rows.iter().map(|r| r[c].chars().count()).chain([header[c].chars().count()]).max().unwrap_or(0)).collect();
    let line = |cells: &[String]| -> String {
        let mut s = String::new();
        for (c, cell) in cells.iter().enumerate() {
            let pad = width[c] - cell.chars().count();
            if c == 0 {
                s.push_str(cell);
                s.push_str(&" ".repeat(pad));
            } else {
                s.push_str("  ");
                s.push_str(&" ".repeat(pad));
                s.push_str(cell);
            }
        }
        s.trim_end().to_string() + "\n"
    };
    let mut out = format!("{title}\n");
    out += &line(header);
    out += &(width.iter().map(|w| "-".repeat(*w)).collect::<Vec<_>>().join("  ") + "\n");
    for r in rows {
        out += &line(r);
    }
    out
}

impl Report {
    /// The report as pretty JSON (NaN as `null`).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("report serializes")
    }

    /// Human-readable tables: NDMS and MPJPE; stochastic errors; plausibility and SSCP.
    pub fn table(&self) -> String {
        let mut out = String::new();
        let labels: Vec<String> = self.methods.iter().map(|m| m.label.clone()).collect();
        let _ = writeln!(out, "{} ({}, {} scenes, {} fps)", self.reference.dataset, self.reference.split, self.reference.scenes.len(), self.reference.fps);
        // NDMS and MPJPE.
        let mut header = vec!["method".to_string(), "K".into(), "obs".into()];
        let has = |f: &dyn Fn(&MethodReport) -> bool| self.methods.iter().any(f);
        let horizons: Vec<f64> =
            self.methods.iter().find_map(|m| m.mpjpe.as_ref()).map(|p| p.horizons.iter().map(|h| h.horizon_s).collect()).unwrap_or_default();
        // Word indices as in the thesis' Table 7.3 (word 0 = the last κ observed frames).
        let ndms_frames: [i64; 7] = [1, 5, 10, 30, 60, 120, 250];
        if has(&|m| m.ndms.is_some()) {
            header.push("NDMS".into());
            header.extend(ndms_frames.iter().map(|f| format!("@{f}")));
        }
        for h in &horizons {
            header.push(format!("MPJPE {h}s"));
            header.push("best".into());
            header.push(format!("root {h}s"));
            header.push(format!("aligned {h}s"));
        }
        let rows: Vec<Vec<String>> = self
            .methods
            .iter()
            .zip(&labels)
            .map(|(m, l)| {
                let ks: Vec<usize> = m.scenes.iter().map(|s| s.samples).collect();
                let obs: Vec<usize> = m.scenes.iter().map(|s| s.observed_frames).collect();
                let range = |v: &[usize]| {
                    let (a, b) = (v.iter().min().copied().unwrap_or(0), v.iter().max().copied().unwrap_or(0));
                    if a == b {
                        a.to_string()
                    } else {
                        format!("{a}-{b}")
                    }
                };
                let mut r = vec![l.clone(), range(&ks), range(&obs)];
                if header.iter().any(|h| h == "NDMS") {
                    match &m.ndms {
                        Some(n) => {
                            r.push(fmt_opt(Some(n.mean), 1.0, 4));
                            r.extend(ndms_frames.iter().map(|&i| fmt_opt(n.per_frame.at(n.per_frame.first_offset + i), 1.0, 3)));
                        }
                        None => r.extend(std::iter::repeat_n("-".to_string(), 1 + ndms_frames.len())),
                    }
                }
                for (i, _) in horizons.iter().enumerate() {
                    let h = m.mpjpe.as_ref().and_then(|p| p.horizons.get(i));
                    let mm = |s: Option<SampleStats>, best: bool| fmt_opt(s.map(|s| if best { s.best } else { s.mean }), 1000.0, 0);
                    r.push(mm(h.and_then(|h| h.global), false));
                    r.push(mm(h.and_then(|h| h.global), true));
                    r.push(mm(h.and_then(|h| h.root), false));
                    r.push(mm(h.and_then(|h| h.root_aligned), false));
                }
                r
            })
            .collect();
        out += "\n";
        out +=
            &table("NDMS (↑; @i: word i, word 0 = the last κ observed frames) and MPJPE in mm (↓; mean over K, best of K, root, root-aligned)", &header, &rows);
        // Stochastic.
        if has(&|m| m.stochastic.is_some()) {
            let header: Vec<String> = ["method", "APD", "ADE", "FDE", "MMADE", "MMFDE", "futures/person"].map(String::from).to_vec();
            let frames = self.methods.iter().find_map(|m| m.stochastic.as_ref()).map_or(0, |s| s.frames);
            let rows: Vec<Vec<String>> = self
                .methods
                .iter()
                .map(|m| {
                    let s = m.stochastic.clone().unwrap_or_default();
                    vec![
                        m.label.clone(),
                        fmt_opt(s.apd, 1.0, 3),
                        fmt_opt(s.ade, 1.0, 3),
                        fmt_opt(s.fde, 1.0, 3),
                        fmt_opt(s.mmade, 1.0, 3),
                        fmt_opt(s.mmfde, 1.0, 3),
                        fmt_opt(s.alternatives_per_person, 1.0, 1),
                    ]
                })
                .collect();
            out += "\n";
            out += &table(&format!("Stochastic errors in m over the first {frames} forecast frames (APD ↑ diversity; others ↓)"), &header, &rows);
            out += "  APD: mean distance between two samples of a person, each sample's whole forecast flattened into one vector (m)\n";
            out += "  ADE / FDE: best of K, mean joint distance over the forecast frames / at the last one (m)\n";
            out +=
                "  MMADE / MMFDE: the same against every recorded continuation of a pose near the last observed one (DLow's rule); futures/person: how many\n";
        }
        // Speed, plausibility, SSCP.
        if has(&|m| m.speed.is_some() || m.plausibility.is_some() || m.sscp.is_some()) {
            let header: Vec<String> =
                ["method", "speed m/s", "bone mm", "accel m/s²", "jerk m/s³", "foot slide m/s", "speed JS", "first step", "SSCP"].map(String::from).to_vec();
            let mut notes = BTreeMap::new();
            let rows: Vec<Vec<String>> = self
                .methods
                .iter()
                .map(|m| {
                    let p = m.plausibility.clone().unwrap_or_default();
                    let sscp = match &m.sscp {
                        Some(SscpReport { value: Some(v), .. }) => format!("{v:.4}"),
                        Some(SscpReport { skipped: Some(why), .. }) => {
                            notes.insert(why.clone(), ());
                            "skipped".into()
                        }
                        _ => "-".into(),
                    };
                    vec![
                        m.label.clone(),
                        fmt_opt(m.speed.as_ref().map(|s| s.forecast_mean), 1.0, 3),
                        fmt_opt(p.bone_length_mm, 1.0, 1),
                        fmt_opt(p.acceleration_m_s2, 1.0, 2),
                        fmt_opt(p.jerk_m_s3, 1.0, 1),
                        fmt_opt(p.foot_sliding_m_s.flatten(), 1.0, 3),
                        fmt_opt(p.speed_js_mean, 1.0, 3),
                        p.first_step.map_or("-".into(), |f| format!("{} of {}", f.within_observed, f.scenes)),
                        sscp,
                    ]
                })
                .collect();
            out += "\n";
            out += &table("Speed of the forecast, plausibility (↓ except speed) and SSCP (↓)", &header, &rows);
            out += "  first step: scenes whose first forecast frame moves no joint farther than the largest move between observed frames\n";
            for why in notes.keys() {
                let _ = writeln!(out, "SSCP skipped: {why}");
            }
        }
        // Coverage and motion kinds.
        if has(&|m| m.coverage.is_some() || m.kinds.is_some()) {
            let labels = self.methods.iter().find_map(|m| m.kinds.as_ref()).map(|k| k.labels.clone()).unwrap_or_default();
            let mut header: Vec<String> = ["method", "precision", "recall", "kinds JS"].map(String::from).to_vec();
            header.extend(labels.iter().map(|l| format!("% {l}")));
            let share = |v: &[usize], i: usize| format!("{:.0}", 100.0 * v[i] as f64 / v.iter().sum::<usize>().max(1) as f64);
            let mut rows: Vec<Vec<String>> = self
                .methods
                .iter()
                .map(|m| {
                    let mut r = vec![
                        m.label.clone(),
                        fmt_opt(m.coverage.as_ref().map(|c| c.precision), 1.0, 3),
                        fmt_opt(m.coverage.as_ref().map(|c| c.recall), 1.0, 3),
                        fmt_opt(m.kinds.as_ref().map(|k| k.js), 1.0, 3),
                    ];
                    r.extend((0..labels.len()).map(|i| m.kinds.as_ref().map_or("-".into(), |k| share(&k.windows, i))));
                    r
                })
                .collect();
            if let Some(k) = self.methods.iter().find_map(|m| m.kinds.as_ref()) {
                let mut r = vec!["(reference)".to_string(), "-".into(), "-".into(), "-".into()];
                r.extend((0..labels.len()).map(|i| share(&k.reference_windows, i)));
                rows.push(r);
            }
            out += "\n";
            out += &table("Coverage: precision and recall of motion words (↑), motion kinds (JS ↓; % of windows)", &header, &rows);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn curves_and_tables() {
        let c = Curve { first_offset: -2, values: vec![1.0, f64::NAN, 3.0] };
        assert_eq!(c.points(2.0), vec![(-1.0, 1.0), (0.0, 3.0)]);
        assert_eq!((c.at(-2), c.at(-1), c.at(0), c.at(1)), (Some(1.0), None, Some(3.0), None));
        let t = table("T", &["a".into(), "bb".into()], &[vec!["xyz".into(), "1".into()]]);
        assert_eq!(t, "T\na    bb\n---  --\nxyz   1\n");
        assert_eq!(serde_json::to_string(&c).unwrap(), r#"{"first_offset":-2,"values":[1.0,null,3.0]}"#);
    }
}
