//! Seeing the motion: a self-contained HTML viewer ([`html`]), BVH files per person
//! ([`bvh_export`]), JSON arrays ([`json`]) and PNG filmstrips ([`png`]).
//!
//! Every writer is atomic: it writes a temporary sibling (`.NAME.tmp-PID`) and renames it into
//! place, so a failure never leaves partial output ([`write_file_atomic`], [`write_dir_atomic`]).
//!
//! # Observed and forecast frames, samples
//!
//! Viewers and filmstrips show [`SceneGroup`]s: one or more *samples* (scenes with the same
//! skeleton, persons, fps and frame count) of one scene, whose frames `0..observed_frames` were
//! observed and whose later frames were forecast. [`group_scenes`] builds them from a dataset:
//!
//! - A sequence without `forecast` metadata is a group of its own with one sample and all
//!   frames observed.
//! - Forecasts are written as a dataset directory whose sequences carry, in their free metadata
//!   (kept in `dataset.json` next to `name`, `split`, ...):
//!
//!   ```json
//!   "forecast": {"observed_frames": 60, "sample": 3, "source": "TS16"}
//!   ```
//!
//!   `source` names the scene that was forecast (the group), `sample` is the 0-based sample
//!   index `k` (unique inside a group), and frames `>= observed_frames` are forecast frames.
//!   Sequences with the same `source` are the samples of one group, shown in order of `sample`.
//!   A sequence with `"ground_truth": true` instead of `sample` is the recorded future of the
//!   same scene; it is shown first, labelled "ground truth". Every sequence of a group must have
//!   the same `observed_frames`, skeleton, fps, frame count and person count. Sequence names
//!   are free (e.g. `TS16_s03`); [`ForecastInfo::insert_into`] writes the entry.
//! - An explicit observed-frame count (`socdiff view --observed N`) overrides every group's.
//!
//! All samples of a group normally share their observed frames; the viewer stores them once.

pub mod bvh_export;
pub mod html;
pub mod json;
pub mod output;
pub mod png;

use crate::data::dataset::Dataset;
use crate::data::scene::Scene;
use crate::{bail, Error, Result};
use serde_json::{Map, Value};

/// Forecast provenance of one sequence (see the module docs).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ForecastInfo {
    /// Frames `0..observed_frames` were observed, later frames forecast.
    pub observed_frames: usize,
    /// Sample index `k`, or `None` for the ground-truth future.
    pub sample: Option<usize>,
    /// Name of the scene that was forecast; sequences with the same source form one group.
    pub source: String,
}

impl ForecastInfo {
    /// Reads the `forecast` entry of a scene's metadata: `Ok(None)` when absent, an error naming
    /// the sequence when malformed.
    pub fn from_scene(scene: &Scene) -> Result<Option<Self>> {
        let Some(v) = scene.metadata.get("forecast") else { return Ok(None) };
        let bad = |what: &str| Error::invalid(format!("sequence {}: metadata \"forecast\" {what}", scene.name));
        let obj = v.as_object().ok_or_else(|| bad("is not an object"))?;
        let observed_frames =
            obj.get("observed_frames").and_then(Value::as_u64).ok_or_else(|| bad("needs \"observed_frames\": a non-negative integer"))? as usize;
        let source = obj
            .get("source")
            .and_then(Value::as_str)
            .filter(|s| !s.is_empty())
            .ok_or_else(|| bad("needs \"source\": the name of the forecast scene"))?
            .to_string();
        let ground_truth = obj.get("ground_truth").and_then(Value::as_bool).unwrap_or(false);
        let sample = match obj.get("sample") {
            Some(s) => Some(s.as_u64().ok_or_else(|| bad("has a \"sample\" that is not a non-negative integer"))? as usize),
            None if ground_truth => None,
            None => return Err(bad("needs \"sample\" (or \"ground_truth\": true)")),
        };
        if sample.is_some() && ground_truth {
            return Err(bad("has both \"sample\" and \"ground_truth\": true"));
        }
        if observed_frames > scene.num_frames() {
            return Err(bad(&format!("says observed_frames {observed_frames}, but the sequence has {} frames", scene.num_frames())));
        }
        Ok(Some(Self { observed_frames, sample, source }))
    }

    /// Writes this entry as `metadata["forecast"]`.
    pub fn insert_into(&self, metadata: &mut Map<String, Value>) {
        let mut m = Map::new();
        m.insert("observed_frames".into(), self.observed_frames.into());
        match self.sample {
            Some(k) => m.insert("sample".into(), k.into()),
            None => m.insert("ground_truth".into(), true.into()),
        };
        m.insert("source".into(), self.source.clone().into());
        metadata.insert("forecast".into(), Value::Object(m));
    }
}

/// One sample of a [`SceneGroup`]: a label (`sample 3`, `ground truth`, or the sequence name)
/// and its motion.
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    /// Shown above the sample's panel.
    pub label: String,
    /// The motion.
    pub scene: Scene,
}

/// Several samples of one scene, observed up to `observed_frames` (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct SceneGroup {
    /// Scene name (the forecast `source`, or the sequence name).
    pub name: String,
    /// Frames `0..observed_frames` are observed, later frames forecast.
    pub observed_frames: usize,
    /// At least one sample; all with the same skeleton, persons, fps and frame count.
    pub samples: Vec<Sample>,
}

impl SceneGroup {
    /// A group of one scene whose frames `0..observed` were observed (`None`: all of them).
    pub fn single(scene: Scene, observed: Option<usize>) -> Result<Self> {
        let g = Self {
            name: scene.name.clone(),
            observed_frames: observed.unwrap_or(scene.num_frames()),
            samples: vec![Sample { label: scene.name.clone(), scene }],
        };
        g.check()?;
        Ok(g)
    }

    /// Marks frames `n` and later as forecast; `n` may not exceed the frame count.
    pub fn set_observed(&mut self, n: usize) -> Result<()> {
        let f = self.num_frames();
        if n > f {
            bail!("`observed` {n} exceeds the {f} frames of {}", self.name);
        }
        self.observed_frames = n;
        Ok(())
    }

    /// The first sample's scene (skeleton, persons and fps are the same in all).
    pub fn first(&self) -> &Scene {
        &self.samples[0].scene
    }

    /// Frames per sample.
    pub fn num_frames(&self) -> usize {
        self.first().num_frames()
    }

    /// Checks that the samples agree with each other and with `observed_frames`.
    pub fn check(&self) -> Result<()> {
        let Some(first) = self.samples.first() else { bail!("scene {}: no samples", self.name) };
        let a = &first.scene;
        if self.observed_frames > a.num_frames() {
            bail!("scene {}: {} observed frames, but it has only {} frames", self.name, self.observed_frames, a.num_frames());
        }
        for s in &self.samples[1..] {
            let b = &s.scene;
            let differ = |what: &str, x: String, y: String| {
                Err(Error::invalid(format!(
                    "scene {}: sequence {} has {x} {what}, sequence {} has {y} (samples of one scene must agree)",
                    self.name, b.name, a.name
                )))
            };
            if b.skeleton.joints != a.skeleton.joints || b.skeleton.bones != a.skeleton.bones {
                return differ("skeleton", b.skeleton.name.clone(), a.skeleton.name.clone());
            }
            if b.num_persons() != a.num_persons() {
                return differ("persons", b.num_persons().to_string(), a.num_persons().to_string());
            }
            if b.num_frames() != a.num_frames() {
                return differ("frames", b.num_frames().to_string(), a.num_frames().to_string());
            }
            if (b.fps - a.fps).abs() > 1e-9 {
                return differ("fps", b.fps.to_string(), a.fps.to_string());
            }
        }
        Ok(())
    }
}

/// Groups a dataset's sequences into scenes with samples (see the module docs). `observed`
/// overrides every group's observed-frame count (it must not exceed any group's frames; to
/// override after [`select_groups`], use [`SceneGroup::set_observed`]).
pub fn group_scenes(ds: &Dataset, observed: Option<usize>) -> Result<Vec<SceneGroup>> {
    /// A group being collected: its entries are (sample index, `None` = ground truth; scene).
    struct Pending {
        name: String,
        forecast: bool,
        entries: Vec<(Option<usize>, Scene)>,
        observed: usize,
    }
    let mut groups: Vec<Pending> = Vec::new();
    for seq in &ds.sequences {
        let scene = &seq.scene;
        match ForecastInfo::from_scene(scene)? {
            None => groups.push(Pending { name: scene.name.clone(), forecast: false, entries: vec![(None, scene.clone())], observed: scene.num_frames() }),
            Some(info) => match groups.iter_mut().find(|g| g.forecast && g.name == info.source) {
                Some(g) => {
                    if g.observed != info.observed_frames {
                        bail!(
                            "sequence {}: forecast observed_frames {} differs from {} of the other samples of {}",
                            scene.name,
                            info.observed_frames,
                            g.observed,
                            info.source
                        );
                    }
                    if let Some((_, other)) = g.entries.iter().find(|e| e.0 == info.sample) {
                        let what = info.sample.map_or("ground truth".to_string(), |k| format!("sample {k}"));
                        bail!("sequences {} and {} are both {what} of {}", other.name, scene.name, info.source);
                    }
                    g.entries.push((info.sample, scene.clone()));
                }
                None => groups.push(Pending {
                    name: info.source.clone(),
                    forecast: true,
                    entries: vec![(info.sample, scene.clone())],
                    observed: info.observed_frames,
                }),
            },
        }
    }
    let mut out = Vec::with_capacity(groups.len());
    for Pending { name, forecast: is_forecast, mut entries, observed: obs } in groups {
        // Ground truth (None) first, then samples by index.
        entries.sort_by_key(|e| e.0.map_or(0, |k| k + 1));
        let samples = entries
            .into_iter()
            .map(|(k, scene)| {
                let label = match (is_forecast, k) {
                    (false, _) => scene.name.clone(),
                    (true, None) => "ground truth".to_string(),
                    (true, Some(k)) => format!("sample {k}"),
                };
                Sample { label, scene }
            })
            .collect();
        let observed_frames = obs;
        let mut g = SceneGroup { name, observed_frames, samples };
        g.check()?;
        if let Some(n) = observed {
            g.set_observed(n)?;
        }
        out.push(g);
    }
    if out.is_empty() {
        bail!("dataset {}: no sequences", ds.name);
    }
    Ok(out)
}

/// Keeps the groups called `names` (group names are forecast sources or sequence names), in
/// the order given; an empty list keeps all.
pub fn select_groups(groups: Vec<SceneGroup>, names: &[String]) -> Result<Vec<SceneGroup>> {
    if names.is_empty() {
        return Ok(groups);
    }
    let mut out = Vec::with_capacity(names.len());
    for n in names {
        match groups.iter().find(|g| &g.name == n || g.samples.iter().any(|s| &s.scene.name == n)) {
            Some(g) => out.push(g.clone()),
            None => bail!("no sequence {n:?} (sequences: {})", groups.iter().map(|g| g.name.as_str()).collect::<Vec<_>>().join(", ")),
        }
    }
    Ok(out)
}

/// Colour of person `p` (sRGB), shared by the viewer and the filmstrips.
pub fn person_colour(p: usize) -> [u8; 3] {
    const PALETTE: [[u8; 3]; 10] = [
        [31, 119, 180],
        [214, 39, 40],
        [44, 160, 44],
        [148, 103, 189],
        [255, 127, 14],
        [23, 190, 207],
        [227, 119, 194],
        [140, 86, 75],
        [188, 189, 34],
        [127, 127, 127],
    ];
    PALETTE[p % PALETTE.len()]
}

/// A file-name-safe version of `s`: ASCII letters, digits, `-`, `_` and `.` kept, anything else
/// replaced by `_` (never empty, never starting with `.`).
pub fn safe_file_name(s: &str) -> String {
    let mut out: String = s.chars().map(|c| if c.is_ascii_alphanumeric() || "-_.".contains(c) { c } else { '_' }).collect();
    if out.is_empty() || out.starts_with('.') {
        out.insert(0, '_');
    }
    out
}

pub use crate::files::{write_dir_atomic, write_file_atomic};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::dataset::{Sequence, Split};
    use crate::data::test_util::walkers;

    fn forecast(scene: &Scene, name: &str, obs: usize, k: Option<usize>, source: &str) -> Sequence {
        let mut s = scene.clone();
        s.name = name.into();
        ForecastInfo { observed_frames: obs, sample: k, source: source.into() }.insert_into(&mut s.metadata);
        Sequence { split: Split::Test, scene: s }
    }

    #[test]
    fn forecast_sequences_group_by_source() {
        let a = walkers(40, 2, 0.0);
        let b = walkers(50, 3, 1.0);
        let ds = Dataset {
            name: "fc".into(),
            sequences: vec![
                forecast(&a, "a_s1", 10, Some(1), "A"),
                Sequence { split: Split::Train, scene: b.clone() },
                forecast(&a, "a_s0", 10, Some(0), "A"),
                forecast(&a, "a_gt", 10, None, "A"),
            ],
            metadata: Default::default(),
        };
        let g = group_scenes(&ds, None).unwrap();
        assert_eq!(g.len(), 2);
        assert_eq!((g[0].name.as_str(), g[0].observed_frames, g[0].samples.len()), ("A", 10, 3));
        let labels: Vec<&str> = g[0].samples.iter().map(|s| s.label.as_str()).collect();
        assert_eq!(labels, ["ground truth", "sample 0", "sample 1"]);
        assert_eq!((g[1].name.as_str(), g[1].observed_frames), ("walkers", 50));
        let g = group_scenes(&ds, Some(5)).unwrap();
        assert_eq!((g[0].observed_frames, g[1].observed_frames), (5, 5));
        let e = group_scenes(&ds, Some(45)).unwrap_err().to_string();
        assert!(e.contains("`observed` 45") && e.contains("40 frames of A"), "{e}");
        let sel = select_groups(g, &["walkers".into()]).unwrap();
        assert_eq!(sel.len(), 1);
        assert!(select_groups(sel, &["nope".into()]).unwrap_err().to_string().contains("walkers"));
        // Mismatched samples and malformed entries are errors naming the sequence.
        let mut ds2 = ds.clone();
        ds2.sequences.push(forecast(&b, "b_s2", 10, Some(2), "A"));
        let e = group_scenes(&ds2, None).unwrap_err().to_string();
        assert!(e.contains("b_s2") && e.contains("persons"), "{e}");
        let mut ds3 = ds.clone();
        ds3.sequences.push(forecast(&a, "a_dup", 10, Some(1), "A"));
        assert!(group_scenes(&ds3, None).unwrap_err().to_string().contains("a_s1 and a_dup"));
        let mut ds4 = ds;
        ds4.sequences[0].scene.metadata.insert("forecast".into(), serde_json::json!({"observed_frames": 3}));
        let e = group_scenes(&ds4, None).unwrap_err().to_string();
        assert!(e.contains("a_s1") && e.contains("source"), "{e}");
    }

    #[test]
    fn atomic_writers_leave_nothing_on_failure() {
        let dir = crate::data::test_util::tmp("atomic");
        let r: Result<()> = write_dir_atomic(&dir, |tmp| {
            std::fs::write(tmp.join("a"), b"x").unwrap();
            bail!("boom")
        });
        assert!(r.is_err() && !dir.exists());
        let parent = dir.parent().unwrap();
        let stem = dir.file_name().unwrap().to_string_lossy().into_owned();
        assert!(!std::fs::read_dir(parent).unwrap().any(|e| e.unwrap().file_name().to_string_lossy().contains(&format!(".{stem}.tmp"))));
        write_dir_atomic(&dir, |tmp| {
            std::fs::write(tmp.join("a"), b"x").unwrap();
            Ok(())
        })
        .unwrap();
        assert_eq!(std::fs::read(dir.join("a")).unwrap(), b"x");
        assert!(write_dir_atomic(&dir, |_| Ok(())).unwrap_err().to_string().contains("not empty"));
        let f = dir.join("f.txt");
        write_file_atomic(&f, b"1").unwrap();
        write_file_atomic(&f, b"22").unwrap();
        assert_eq!(std::fs::read(&f).unwrap(), b"22");
        assert!(write_file_atomic(&dir, b"1").is_err());
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(safe_file_name("TS 1/a"), "TS_1_a");
        assert_eq!(safe_file_name(".."), "_..");
    }
}
