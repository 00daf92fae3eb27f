//! Scoring every method with every requested metric ([`evaluate`]).
//!
//! Per scene, with K samples `[K, observed + H, persons, joints, 3]` and the reference scene:
//!
//! | metric | computed on | pooled over scenes |
//! |---|---|---|
//! | NDMS | each sample and person, words from `observed − lead` on, against the database of the reference split ([`EvalConfig::ndms_database`]) | every word equally; curve per word index |
//! | MPJPE global / root / root-aligned | forecast frames vs the reference; (frame, person) pairs the reference marks invalid are left out | scenes weighted by their valid persons; per horizon: mean over K and best of K per scene |
//! | APD, ADE, FDE | the first `round(stochastic_horizon_s · fps)` forecast frames (fewer if the forecast is shorter) | scenes weighted by persons |
//! | MMADE, MMFDE | per person: the alternative futures are the continuations of every (track, frame) of the reference split whose body-frame pose is within [`EvalConfig::multimodal_threshold`] of the person's last observed pose (DLow's rule; the person's own future included), moved rigidly into the person's body frame | persons equally |
//! | speed | per frame step of the whole sample, mean over K | scenes weighted by persons |
//! | bone length, acceleration, jerk, foot sliding | per sample; acceleration and jerk include the join to the last observed frames | scenes weighted by persons × forecast frames |
//! | speed JS | forecast parts of all samples vs the reference's futures (from the same observed frame), per time bin | — |
//! | SSCP | states of the forecast frames of every sample vs the reference's future frames ([`super::signals`]) | transition counts summed |
//! | coverage | words starting every [`CoverageConfig::word_stride`] forecast frames of every sample and person vs the NDMS database's words: precision and recall ([`crate::metrics::coverage`]) | all words of the method together |
//! | kinds | windows of the forecast frames of every sample and person vs windows of the reference split's scenes, labelled by [`EvalConfig::kinds`] | all windows of the method together |

use super::inputs::{Method, Reference};
use super::report::*;
use super::signals::{Availability, SignalSource};
use super::Metric;
use crate::data::dataset::Split;
use crate::metrics::coverage::{precision_recall, thin, CoverageConfig, Manifold, Origin, Words};
use crate::metrics::distance::{ade, apd, fde, mean_joint_speed, pose_error_curve, PoseError, SampleStats};
use crate::metrics::horizon_frame;
use crate::metrics::kinds::{KindDistribution, MotionKindClassifier};
use crate::metrics::ndms::{anchor_or_level, NdmsConfig, NdmsCurve, NdmsDatabase, NdmsScore};
use crate::metrics::plausibility::{
    ankle_joints, bone_length_deviation, foot_sliding, mean_acceleration, mean_jerk, speed_histogram_distance, FootSlidingConfig, SpeedHistogramConfig,
};
use crate::metrics::sscp::{sscp_distance, transition_counts, transition_distribution, SscpConfig};
use crate::{bail, Result};
use ndarray::{s, Array2, Array4, ArrayView4, ArrayView5, Axis};
use rayon::prelude::*;
use serde_json::{json, Map};
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

/// Evaluation settings. Every field is recorded in the report.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalConfig {
    /// Metrics to compute.
    pub metrics: Vec<Metric>,
    /// MPJPE horizons in seconds after the last observed frame (default 1, 2, 3).
    pub horizons_s: Vec<f64>,
    /// NDMS word settings.
    pub ndms: NdmsConfig,
    /// Split whose words form the NDMS database; `None`: the scored split (METHOD.md §5).
    pub ndms_database: Option<Split>,
    /// Seconds of forecast over which APD, ADE, FDE, MMADE, MMFDE are computed (default 3).
    pub stochastic_horizon_s: f64,
    /// Body-frame pose distance (m, norm over all joints) under which another observation's
    /// future is an alternative for MMADE/MMFDE (default 0.5, DLow's).
    pub multimodal_threshold: f64,
    /// Foot sliding.
    pub foot_sliding: FootSlidingConfig,
    /// Speed histograms.
    pub speed_histogram: SpeedHistogramConfig,
    /// SSCP.
    pub sscp: SscpConfig,
    /// Precision and recall of motion words.
    pub coverage: CoverageConfig,
    /// The motion-kind classifier of [`Metric::Kinds`] (`None`: that metric is refused).
    pub kinds: Option<Arc<MotionKindClassifier>>,
}

impl Default for EvalConfig {
    fn default() -> Self {
        Self {
            metrics: Metric::everything_without_classifier(),
            horizons_s: vec![1.0, 2.0, 3.0],
            ndms: NdmsConfig::default(),
            ndms_database: None,
            stochastic_horizon_s: 3.0,
            multimodal_threshold: 0.5,
            foot_sliding: FootSlidingConfig::default(),
            speed_histogram: SpeedHistogramConfig::default(),
            sscp: SscpConfig::default(),
            coverage: CoverageConfig::default(),
            kinds: None,
        }
    }
}

impl EvalConfig {
    fn wants(&self, m: Metric) -> bool {
        self.metrics.contains(&m)
    }

    fn wants_any(&self, ms: &[Metric]) -> bool {
        ms.iter().any(|m| self.wants(*m))
    }
}

/// Progress of a long stage.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Progress {
    /// What is being done.
    pub stage: String,
    /// Units done.
    pub done: usize,
    /// Units in all.
    pub total: usize,
}

/// Weighted per-offset sums, turned into a [`Curve`].
#[derive(Default)]
struct Pool(BTreeMap<i64, (f64, f64)>);

impl Pool {
    fn add(&mut self, offset: i64, value: f64, weight: f64) {
        if value.is_finite() && weight > 0.0 {
            let e = self.0.entry(offset).or_insert((0.0, 0.0));
            e.0 += value * weight;
            e.1 += weight;
        }
    }

    fn curve(&self) -> Curve {
        let (Some((&a, _)), Some((&b, _))) = (self.0.first_key_value(), self.0.last_key_value()) else {
            return Curve { first_offset: 0, values: Vec::new() };
        };
        let values = (a..=b).map(|o| self.0.get(&o).map_or(f64::NAN, |(s, w)| s / w)).collect();
        Curve { first_offset: a, values }
    }
}

/// A weighted mean.
#[derive(Default, Clone, Copy)]
struct Mean {
    sum: f64,
    weight: f64,
}

impl Mean {
    fn add(&mut self, v: f64, w: f64) {
        if v.is_finite() && w > 0.0 {
            self.sum += v * w;
            self.weight += w;
        }
    }

    fn get(&self) -> Option<f64> {
        (self.weight > 0.0).then(|| self.sum / self.weight)
    }
}

/// One person track of the reference split, for the multimodal alternatives.
struct Track {
    /// `[frames · joints · 3]` world positions.
    pos: Vec<f32>,
    valid: Vec<bool>,
    /// Body-frame pose per frame (`[joints · 3]`, f32).
    body: Vec<Vec<f32>>,
    anchors: Vec<crate::features::Anchor>,
}

/// A pose in its own body frame (heading 0 when degenerate), and that frame.
fn body_pose(pose: &[f32], left: usize, right: usize) -> (Vec<f32>, crate::features::Anchor) {
    let a = anchor_or_level(pose, left, right);
    let (s, c) = a.heading.sin_cos();
    let mut out = Vec::with_capacity(pose.len());
    for v in pose.chunks_exact(3) {
        let (dx, dy) = (v[0] as f64 - a.root[0], v[1] as f64 - a.root[1]);
        out.extend([(c * dx + s * dy) as f32, (-s * dx + c * dy) as f32, v[2]]);
    }
    (out, a)
}

fn reference_tracks(reference: &Reference) -> Vec<Track> {
    let sk = reference.skeleton();
    let mut out = Vec::new();
    for s in reference.scenes() {
        for p in 0..s.num_persons() {
            let pos: Vec<f32> = s.person(p).iter().copied().collect();
            let (body, anchors) = pos.chunks_exact(3 * sk.num_joints()).map(|pose| body_pose(pose, sk.left, sk.right)).unzip();
            out.push(Track { pos, valid: (0..s.num_frames()).map(|f| s.is_valid(f, p)).collect(), body, anchors });
        }
    }
    out
}

/// Evaluates `methods` against `reference` (module docs). `signals` provides SSCP's speaking
/// and buyer information; `progress` hears about the long stages.
pub fn evaluate(reference: &Reference, methods: &[Method], cfg: &EvalConfig, signals: SignalSource, progress: &mut dyn FnMut(&Progress)) -> Result<Report> {
    if methods.is_empty() {
        bail!("nothing to evaluate: give forecasts or baselines");
    }
    if cfg.metrics.is_empty() {
        bail!("no metrics requested");
    }
    if let Some(h) = cfg.horizons_s.iter().find(|h| !(h.is_finite() && **h > 0.0)) {
        bail!("MPJPE horizon {h} s: horizons must be positive");
    }
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if !positive(cfg.stochastic_horizon_s) || !positive(cfg.multimodal_threshold) {
        bail!("the stochastic horizon and the multimodal threshold must be positive");
    }
    let fps = reference.fps();
    let sk = reference.skeleton();
    for m in methods {
        if m.scenes.is_empty() {
            bail!("method {}: no scenes to score", m.label);
        }
    }
    let mut settings = Map::new();
    settings.insert("fps".into(), fps.into());
    settings.insert("scene_weighting".into(), "curves and MPJPE: persons; plausibility: persons × forecast frames; NDMS: every word".into());
    let db_split = cfg.ndms_database.unwrap_or(reference.split);
    if cfg.wants(Metric::Kinds) && cfg.kinds.is_none() {
        bail!("metric kinds needs a motion-kind classifier (trained on labelled motion, e.g. bandai2)");
    }
    let db = if cfg.wants_any(&[Metric::Ndms, Metric::Coverage]) {
        progress(&Progress { stage: format!("building the NDMS database ({} split)", db_split.as_str()), done: 0, total: 1 });
        let scenes = reference.split_scenes(db_split);
        if scenes.is_empty() {
            bail!("NDMS database: the reference has no {} sequences", db_split.as_str());
        }
        let t0 = Instant::now();
        let db = NdmsDatabase::build(&scenes, &cfg.ndms)?;
        settings.insert(
            "ndms".into(),
            json!({
                "database": {"split": db_split.as_str(), "scenes": scenes.iter().map(|s| s.name.clone()).collect::<Vec<_>>(),
                             "words": db.num_words(), "skipped_degenerate_words": db.num_skipped_degenerate(),
                             "build_seconds": t0.elapsed().as_secs_f64()},
                "word_length": db.word_length(),
                "lead": db.lead(),
                "joints": db.joints().iter().map(|&j| sk.joints[j].clone()).collect::<Vec<_>>(),
                "nearest_neighbour": "exact Euclidean (f32 gemm screening, f64 re-check)",
                "velocity_norm_floor": crate::metrics::ndms::NORM_FLOOR,
            }),
        );
        Some(db)
    } else {
        None
    };
    if cfg.wants(Metric::Mpjpe) {
        settings.insert("mpjpe".into(), json!({"horizons_s": cfg.horizons_s, "body_frame_joints": [sk.joints[sk.left], sk.joints[sk.right]]}));
    }
    let tracks = if cfg.wants_any(&[Metric::Mmade, Metric::Mmfde]) { reference_tracks(reference) } else { Vec::new() };
    if cfg.wants_any(&[Metric::Apd, Metric::Ade, Metric::Fde, Metric::Mmade, Metric::Mmfde]) {
        settings.insert(
            "stochastic".into(),
            json!({"horizon_s": cfg.stochastic_horizon_s, "frames": (cfg.stochastic_horizon_s * fps).round() as usize,
                   "multimodal_threshold_m": cfg.multimodal_threshold,
                   "multimodal_candidates": format!("every valid frame of every person of the {} split", reference.split.as_str())}),
        );
    }
    if cfg.wants(Metric::FootSliding) {
        settings.insert(
            "foot_sliding".into(),
            json!({"height_m": cfg.foot_sliding.height, "joints": ankle_joints(sk).iter().map(|&j| sk.joints[j].clone()).collect::<Vec<_>>()}),
        );
    }
    if cfg.wants(Metric::SpeedJs) {
        let h = &cfg.speed_histogram;
        settings.insert("speed_histogram".into(), json!({"bins": h.bins, "max_speed_m_s": h.max_speed, "time_bin_s": h.time_bin_s}));
    }
    if cfg.wants(Metric::Sscp) {
        settings.insert(
            "sscp".into(),
            json!({"signals": signals.describe(&cfg.sscp), "speaking_threshold": cfg.sscp.speaking_threshold,
                   "smoothing_sigma_frames": cfg.sscp.smoothing_sigma, "distance": "Jensen-Shannon distance, natural log"}),
        );
    }
    // Coverage: the reference words (thinned once); kinds: the reference split's histogram.
    let real_words = match (&db, cfg.wants(Metric::Coverage)) {
        (Some(db), true) => {
            let rows = thin(db.num_words(), cfg.coverage.max_words);
            let mut a = Array2::zeros((rows.len(), db.dim()));
            let mut tracks: BTreeMap<(&str, usize), usize> = BTreeMap::new();
            let mut origins = Vec::with_capacity(rows.len());
            for (r, &i) in rows.iter().enumerate() {
                a.row_mut(r).assign(&ndarray::ArrayView1::from(&db.word(i)));
                let (scene, person, frame) = db.word_origin(i);
                let next = tracks.len();
                origins.push(Origin { track: *tracks.entry((scene, person)).or_insert(next), frame });
            }
            settings.insert(
                "coverage".into(),
                json!({"k": cfg.coverage.k, "max_words": cfg.coverage.max_words, "word_stride": cfg.coverage.word_stride,
                       "real_words": format!("NDMS database words ({} split), thinned evenly", db_split.as_str()),
                       "radius_neighbours": "words of another track, or of the same track a word length or more away"}),
            );
            Some(Manifold::new(Words { values: a.view(), origins: &origins }, db.word_length(), &cfg.coverage, "real")?)
        }
        _ => None,
    };
    let kinds_reference = match (&cfg.kinds, cfg.wants(Metric::Kinds)) {
        (Some(clf), true) => {
            progress(&Progress { stage: "motion kinds of the reference".into(), done: 0, total: 1 });
            let scenes: Vec<&crate::Scene> = reference.scenes().collect();
            let h = clf.histogram(&scenes, KINDS_STRIDE)?;
            settings.insert(
                "kinds".into(),
                json!({"labels": clf.labels, "window_s": crate::metrics::kinds::WINDOW_S, "stride_frames": KINDS_STRIDE,
                       "training_windows": clf.windows_per_class, "reference_windows": h, "distance": "Jensen-Shannon distance, natural log"}),
            );
            Some(h)
        }
        _ => None,
    };
    let shared = Shared { db: db.as_ref(), tracks: &tracks, real_words: real_words.as_ref(), kinds_reference: kinds_reference.as_deref() };
    let ndms_total: usize = if cfg.wants(Metric::Ndms) && db.is_some() { methods.iter().map(Method::num_samples).sum() } else { 0 };
    let mut ndms_done = 0;
    let mut reports = Vec::with_capacity(methods.len());
    for m in methods {
        progress(&Progress { stage: format!("scoring {}", m.label), done: 0, total: 1 });
        let mut ndms_progress = |n: usize| {
            ndms_done += n;
            progress(&Progress { stage: format!("NDMS {}", m.label), done: ndms_done, total: ndms_total });
        };
        reports.push(score_method(m, reference, cfg, &shared, signals, &mut ndms_progress)?);
    }
    let reference_speed = cfg.wants(Metric::Speed).then(|| {
        let mut pool = Pool::default();
        for sc in &methods[0].scenes {
            if let Ok(v) = mean_joint_speed(sc.reference.positions.view(), fps) {
                for (t, s) in v.iter().enumerate() {
                    pool.add(t as i64 + 1 - sc.observed as i64, *s, sc.reference.num_persons() as f64);
                }
            }
        }
        pool.curve()
    });
    Ok(Report {
        socdiff_version: env!("CARGO_PKG_VERSION").to_string(),
        provenance: Map::new(),
        reference: ReferenceInfo {
            path: reference.path.display().to_string(),
            dataset: reference.dataset.name.clone(),
            split: reference.split.as_str().to_string(),
            fps,
            skeleton: sk.name.clone(),
            joints: sk.joints.clone(),
            scenes: reference.scenes().map(|s| ReferenceScene { name: s.name.clone(), frames: s.num_frames(), persons: s.num_persons() }).collect(),
            metadata: reference.dataset.metadata.clone(),
        },
        settings,
        metrics: cfg.metrics.iter().map(|m| m.name().to_string()).collect(),
        reference_speed,
        methods: reports,
    })
}

/// `[K, H]` error per sample and forecast frame, averaged over the persons valid in the
/// reference at that frame (NaN where none is), and the valid-person count per frame.
fn valid_person_errors(
    f: ArrayView5<f32>,
    truth: ArrayView4<f32>,
    valid: &Array2<bool>,
    left: usize,
    right: usize,
    kind: PoseError,
) -> Result<(Array2<f64>, Vec<usize>)> {
    let (k, h, p, _, _) = f.dim();
    let mut sum = Array2::<f64>::zeros((k, h));
    let mut count = vec![0usize; h];
    for pp in 0..p {
        let e = pose_error_curve(f.slice(s![.., .., pp..pp + 1, .., ..]), truth.slice(s![.., pp..pp + 1, .., ..]), left, right, kind)?;
        for t in 0..h {
            if valid[[t, pp]] {
                count[t] += 1;
                for kk in 0..k {
                    sum[[kk, t]] += e[[kk, t]];
                }
            }
        }
    }
    for t in 0..h {
        for kk in 0..k {
            sum[[kk, t]] = if count[t] > 0 { sum[[kk, t]] / count[t] as f64 } else { f64::NAN };
        }
    }
    Ok((sum, count))
}

/// MMADE and MMFDE of one person (module docs): `(mmade, mmfde, alternatives)`.
///
/// # Shapes
/// - `f`: `[K, S, 1, joints, 3]` forecast frames; `last_observed`: `[joints · 3]`.
fn multimodal(f: ArrayView5<f32>, last_observed: &[f32], tracks: &[Track], left: usize, right: usize, threshold: f64) -> Result<(f64, f64, usize)> {
    let (_, sf, _, nj, _) = f.dim();
    let (q, qa) = body_pose(last_observed, left, right);
    let thr2 = threshold * threshold;
    let mut buf = Array4::<f32>::zeros((sf, 1, nj, 3));
    let (mut sa, mut sfd, mut n) = (0.0, 0.0, 0usize);
    for t in tracks {
        let frames = t.valid.len();
        // run[c] = consecutive valid frames from c.
        let mut run = vec![0usize; frames + 1];
        for c in (0..frames).rev() {
            run[c] = if t.valid[c] { run[c + 1] + 1 } else { 0 };
        }
        for (c, &valid_run) in run.iter().enumerate().take(frames.saturating_sub(sf)) {
            if valid_run < sf + 1 {
                continue;
            }
            let d2: f64 = t.body[c].iter().zip(&q).map(|(a, b)| (*a as f64 - *b as f64).powi(2)).sum();
            if d2 > thr2 {
                continue;
            }
            let ca = t.anchors[c];
            let (sn, cs) = (qa.heading - ca.heading).sin_cos();
            for i in 0..sf {
                let pose = &t.pos[(c + 1 + i) * nj * 3..(c + 2 + i) * nj * 3];
                for (j, v) in pose.chunks_exact(3).enumerate() {
                    let (dx, dy) = (v[0] as f64 - ca.root[0], v[1] as f64 - ca.root[1]);
                    buf[[i, 0, j, 0]] = (qa.root[0] + cs * dx - sn * dy) as f32;
                    buf[[i, 0, j, 1]] = (qa.root[1] + sn * dx + cs * dy) as f32;
                    buf[[i, 0, j, 2]] = v[2];
                }
            }
            sa += ade(f.view(), buf.view())?;
            sfd += fde(f.view(), buf.view())?;
            n += 1;
        }
    }
    Ok(if n == 0 { (f64::NAN, f64::NAN, 0) } else { (sa / n as f64, sfd / n as f64, n) })
}

fn as_rows(a: &Array2<f64>) -> Vec<Vec<f64>> {
    a.rows().into_iter().map(|r| r.to_vec()).collect()
}

/// SSCP of one method (module docs).
fn score_sscp(m: &Method, cfg: &EvalConfig, signals: SignalSource) -> Result<SscpReport> {
    let skipped = |why: String| SscpReport { value: None, skipped: Some(why), transitions: None, reference_transitions: None };
    let mut ref_counts = Vec::new();
    let mut counts = Vec::new();
    for sc in &m.scenes {
        let n = sc.observed;
        match signals.states(&sc.reference, &cfg.sscp)? {
            Availability::States(st) => ref_counts.push(transition_counts(&st[n..])?),
            Availability::Missing(why) => return Ok(skipped(format!("reference: {why}"))),
        }
        for s in &sc.samples {
            match signals.states(s, &cfg.sscp)? {
                Availability::States(st) => counts.push(transition_counts(&st[n..])?),
                Availability::Missing(why) => return Ok(skipped(why)),
            }
        }
    }
    let p_ref = transition_distribution(&ref_counts)?;
    let p = transition_distribution(&counts)?;
    Ok(SscpReport { value: Some(sscp_distance(&p_ref, &p)?), skipped: None, transitions: Some(as_rows(&p)), reference_transitions: Some(as_rows(&p_ref)) })
}

/// Frames between classified windows of [`Metric::Kinds`] (1 s at 30 fps).
const KINDS_STRIDE: usize = 30;

/// What every method is scored against, built once.
struct Shared<'a> {
    db: Option<&'a NdmsDatabase>,
    tracks: &'a [Track],
    /// The reference's words with their radii (coverage).
    real_words: Option<&'a Manifold>,
    kinds_reference: Option<&'a [usize]>,
}

fn score_method(
    m: &Method,
    reference: &Reference,
    cfg: &EvalConfig,
    shared: &Shared,
    signals: SignalSource,
    ndms_progress: &mut dyn FnMut(usize),
) -> Result<MethodReport> {
    let db = if cfg.wants(Metric::Ndms) { shared.db } else { None };
    let tracks = shared.tracks;
    let mut coverage_words: Vec<f64> = Vec::new();
    let mut coverage_origins: Vec<Origin> = Vec::new();
    let mut kind_hist = shared.kinds_reference.map(|r| vec![0usize; r.len()]);
    let fps = reference.fps();
    let sk = reference.skeleton();
    let (left, right) = (sk.left, sk.right);
    let mut scenes = Vec::new();
    // NDMS.
    let mut ndms_curves: Vec<NdmsCurve> = Vec::new();
    let mut ndms_seconds = 0.0;
    // MPJPE.
    let kinds = [PoseError::Global, PoseError::Root, PoseError::RootAligned];
    let mut pose_pools: [Pool; 3] = Default::default();
    let mut at_h: Vec<[(Mean, Mean); 3]> = vec![Default::default(); cfg.horizons_s.len()];
    let mut at_h_scenes = vec![0usize; cfg.horizons_s.len()];
    let mut at_h_frame = vec![0usize; cfg.horizons_s.len()];
    // Stochastic.
    let stoch_frames = ((cfg.stochastic_horizon_s * fps).round() as usize).max(1);
    let [mut m_apd, mut m_ade, mut m_fde, mut m_mmade, mut m_mmfde, mut m_alts] = [Mean::default(); 6];
    // Speed and plausibility.
    let mut speed = Pool::default();
    let mut speed_forecast = Mean::default();
    let (mut bones, mut accel, mut jerk, mut foot) = (Mean::default(), Mean::default(), Mean::default(), Mean::default());
    let mut first_step = FirstStepReport::default();
    let mut any_planted = false;
    let ankles = ankle_joints(sk);
    let mut js_forecasts: Vec<Array4<f32>> = Vec::new();
    let mut js_reference: Vec<ArrayView4<f32>> = Vec::new();

    for sc in &m.scenes {
        let f = sc.stacked();
        let (k, _, persons, _, _) = f.dim();
        let n = sc.observed;
        let h = sc.forecast_frames();
        // Frames with a recorded future (all of them unless the forecast runs past the recording).
        let hr = sc.recorded_forecast_frames();
        let truth = sc.truth();
        let fut = f.slice(s![.., n.., .., .., ..]);
        let fut_rec = f.slice(s![.., n..n + hr, .., .., ..]);
        let truth_fut = truth.slice(s![n.., .., .., ..]);
        let mut scene_ndms = None;
        if let Some(db) = db {
            let t0 = Instant::now();
            let mut curves = Vec::new();
            for kk in 0..k {
                let sc_k = db
                    .score_forecasts(f.slice(s![kk..kk + 1, .., .., .., ..]), n)
                    .map_err(|e| crate::Error::invalid(format!("method {}, scene {}: {e}", m.label, sc.name())))?;
                curves.extend(sc_k.curves);
                ndms_progress(1);
            }
            ndms_seconds += t0.elapsed().as_secs_f64();
            scene_ndms = Some(NdmsScore::from_curves(curves.clone()).mean);
            ndms_curves.extend(curves);
        }
        if cfg.wants(Metric::Mpjpe) && hr > 0 {
            let valid = Array2::from_shape_fn((hr, persons), |(t, p)| sc.reference.is_valid(n + t, p));
            for (ki, kind) in kinds.iter().enumerate() {
                let (e, count) = valid_person_errors(fut_rec.view(), truth_fut.view(), &valid, left, right, *kind)?;
                for (t, &valid_persons) in count.iter().enumerate() {
                    pose_pools[ki].add(t as i64, e.column(t).sum() / k as f64, valid_persons as f64);
                }
                for (hi, &hs) in cfg.horizons_s.iter().enumerate() {
                    let Some(t) = horizon_frame(hs, fps, hr) else { continue };
                    at_h_frame[hi] = t;
                    let col = e.column(t);
                    if count[t] == 0 {
                        continue;
                    }
                    if ki == 0 {
                        at_h_scenes[hi] += 1;
                    }
                    at_h[hi][ki].0.add(col.sum() / k as f64, count[t] as f64);
                    at_h[hi][ki].1.add(col.fold(f64::INFINITY, |a, &b| a.min(b)), count[t] as f64);
                }
            }
        }
        let sf = stoch_frames.min(h);
        let fs = f.slice(s![.., n..n + sf, .., .., ..]);
        // ADE and FDE over the same frames, when all of them are recorded.
        let ts = (sf <= hr).then(|| truth.slice(s![n..n + sf, .., .., ..]));
        let w = persons as f64;
        if cfg.wants(Metric::Apd) {
            m_apd.add(apd(fs.view())?, w);
        }
        if let (true, Some(ts)) = (cfg.wants(Metric::Ade), ts) {
            m_ade.add(ade(fs.view(), ts.view())?, w);
        }
        if let (true, Some(ts)) = (cfg.wants(Metric::Fde), ts) {
            m_fde.add(fde(fs.view(), ts.view())?, w);
        }
        if cfg.wants_any(&[Metric::Mmade, Metric::Mmfde]) {
            let per_person: Vec<Result<(f64, f64, usize)>> = (0..persons)
                .into_par_iter()
                .map(|p| {
                    let last: Vec<f32> = sc.samples[0].positions.slice(s![n - 1, p, .., ..]).iter().copied().collect();
                    multimodal(fs.slice(s![.., .., p..p + 1, .., ..]), &last, tracks, left, right, cfg.multimodal_threshold)
                })
                .collect();
            for r in per_person {
                let (a, b, c) = r?;
                m_mmade.add(a, 1.0);
                m_mmfde.add(b, 1.0);
                m_alts.add(c as f64, 1.0);
            }
        }
        if cfg.wants(Metric::Speed) {
            let mut acc = vec![0.0; sc.frames() - 1];
            for smp in f.axis_iter(Axis(0)) {
                for (a, v) in acc.iter_mut().zip(mean_joint_speed(smp, fps)?) {
                    *a += v / k as f64;
                }
            }
            for (t, v) in acc.iter().enumerate() {
                let off = t as i64 + 1 - n as i64;
                speed.add(off, *v, w);
                if off >= 0 {
                    speed_forecast.add(*v, w);
                }
            }
        }
        if cfg.wants(Metric::FirstStep) && n >= 2 && sc.frames() > n {
            let observed = crate::metrics::distance::largest_frame_step(sc.reference.positions.slice(s![..n, .., .., ..]));
            let jump = f.axis_iter(Axis(0)).map(|smp| crate::metrics::distance::largest_joint_move(smp, n - 1, n)).fold(0.0, f64::max);
            first_step.scenes += 1;
            first_step.within_observed += usize::from(jump <= observed);
            first_step.mean_largest_m += jump;
            first_step.worst_ratio = first_step.worst_ratio.max(jump / observed.max(1e-9));
        }
        let wf = (persons * h) as f64;
        for smp in f.axis_iter(Axis(0)) {
            let (obs, fc) = (smp.slice(s![..n, .., .., ..]), smp.slice(s![n.., .., .., ..]));
            if cfg.wants(Metric::BoneLength) && !sk.bones.is_empty() {
                bones.add(bone_length_deviation(obs, fc, &sk.bones)?, wf / k as f64);
            }
            // Include the join to the observation: 2 (3) observed frames before the forecast.
            if cfg.wants(Metric::Acceleration) {
                let from = n.saturating_sub(2);
                if sc.frames() - from >= 3 {
                    accel.add(mean_acceleration(smp.slice(s![from.., .., .., ..]), fps)?, wf / k as f64);
                }
            }
            if cfg.wants(Metric::Jerk) {
                let from = n.saturating_sub(3);
                if sc.frames() - from >= 4 {
                    jerk.add(mean_jerk(smp.slice(s![from.., .., .., ..]), fps)?, wf / k as f64);
                }
            }
            if cfg.wants(Metric::FootSliding) && !ankles.is_empty() {
                if let Some(v) = foot_sliding(obs, fc, &ankles, fps, &cfg.foot_sliding)? {
                    any_planted = true;
                    foot.add(v, wf / k as f64);
                }
            }
        }
        if cfg.wants(Metric::SpeedJs) {
            js_forecasts.extend(fut.axis_iter(Axis(0)).map(|a| a.to_owned()));
            if hr > 0 {
                js_reference.push(sc.reference.positions.slice(s![n.., .., .., ..]));
            }
        }
        if let (Some(cdb), Some(_)) = (shared.db, shared.real_words) {
            let stride = cfg.coverage.word_stride.max(1);
            for smp in f.axis_iter(Axis(0)) {
                for p in 0..persons {
                    let track = smp.slice(s![.., p, .., ..]);
                    if track.dim().0 >= n + cdb.word_length() {
                        let id = coverage_origins.last().map_or(0, |o| o.track + 1);
                        let words = cdb.sequence_words(track, n)?;
                        for (i, w) in words.axis_iter(Axis(0)).enumerate().step_by(stride) {
                            coverage_words.extend(w.iter());
                            coverage_origins.push(Origin { track: id, frame: n + i });
                        }
                    }
                }
            }
        }
        if let (Some(hist), Some(clf)) = (kind_hist.as_mut(), &cfg.kinds) {
            for smp in &sc.samples {
                let part = smp.slice_frames(n, smp.num_frames())?;
                for (a, b) in hist.iter_mut().zip(clf.histogram(&[&part], KINDS_STRIDE)?) {
                    *a += b;
                }
            }
        }
        scenes.push(SceneReport { name: sc.name().to_string(), persons, observed_frames: n, forecast_frames: h, samples: k, ndms: scene_ndms });
    }
    let coverage = match (shared.db, shared.real_words) {
        (Some(cdb), Some(real)) => {
            let g = Array2::from_shape_vec((coverage_words.len() / cdb.dim(), cdb.dim()), coverage_words).expect("whole words");
            let method_err = |e: crate::Error| crate::Error::invalid(format!("method {}: {e}", m.label));
            let generated =
                Manifold::new(Words { values: g.view(), origins: &coverage_origins }, cdb.word_length(), &cfg.coverage, "generated").map_err(method_err)?;
            Some(precision_recall(real, &generated).map_err(method_err)?)
        }
        _ => None,
    };
    let kinds = match (kind_hist, shared.kinds_reference, &cfg.kinds) {
        (Some(h), Some(r), Some(clf)) => {
            Some(KindDistribution::new(&clf.labels, h, r.to_vec()).map_err(|e| crate::Error::invalid(format!("method {}: {e}", m.label)))?)
        }
        _ => None,
    };

    let ndms = db.map(|_| {
        let words = ndms_curves.iter().map(|c| c.per_frame.iter().filter(|v| !v.is_nan()).count()).sum();
        let lead = db.map_or(0, |d| d.lead()) as i64;
        let score = NdmsScore::from_curves(std::mem::take(&mut ndms_curves));
        NdmsReport { mean: score.mean, per_frame: Curve { first_offset: -lead, values: score.per_frame }, words, seconds: ndms_seconds }
    });
    let mpjpe = cfg.wants(Metric::Mpjpe).then(|| {
        let stats = |p: &(Mean, Mean)| Some(SampleStats { mean: p.0.get()?, best: p.1.get()? });
        let [g, r, a] = pose_pools.map(|p| p.curve());
        MpjpeReport {
            horizons: cfg
                .horizons_s
                .iter()
                .enumerate()
                .map(|(i, &hs)| HorizonReport {
                    horizon_s: hs,
                    frame: if at_h_scenes[i] > 0 { at_h_frame[i] } else { ((hs * fps).round() as usize).saturating_sub(1) },
                    scenes: at_h_scenes[i],
                    global: stats(&at_h[i][0]),
                    root: stats(&at_h[i][1]),
                    root_aligned: stats(&at_h[i][2]),
                })
                .collect(),
            global_per_frame: g,
            root_per_frame: r,
            root_aligned_per_frame: a,
        }
    });
    let stochastic = cfg.wants_any(&[Metric::Apd, Metric::Ade, Metric::Fde, Metric::Mmade, Metric::Mmfde]).then(|| StochasticReport {
        frames: m.scenes.iter().map(|s| stoch_frames.min(s.forecast_frames())).max().unwrap_or(0),
        apd: m_apd.get(),
        ade: m_ade.get(),
        fde: m_fde.get(),
        mmade: cfg.wants(Metric::Mmade).then(|| m_mmade.get()).flatten(),
        mmfde: cfg.wants(Metric::Mmfde).then(|| m_mmfde.get()).flatten(),
        alternatives_per_person: cfg.wants_any(&[Metric::Mmade, Metric::Mmfde]).then(|| m_alts.get()).flatten(),
    });
    let speed = cfg.wants(Metric::Speed).then(|| SpeedReport { per_frame: speed.curve(), forecast_mean: speed_forecast.get().unwrap_or(f64::NAN) });
    let plaus_metrics = [Metric::BoneLength, Metric::Acceleration, Metric::Jerk, Metric::FootSliding, Metric::SpeedJs, Metric::FirstStep];
    let plausibility = if cfg.wants_any(&plaus_metrics) {
        let (per_bin, js_mean) = if cfg.wants(Metric::SpeedJs) {
            let views: Vec<ArrayView4<f32>> = js_forecasts.iter().map(|a| a.view()).collect();
            let d = speed_histogram_distance(&views, &js_reference, fps, &cfg.speed_histogram)?;
            let mut mean = Mean::default();
            d.iter().flatten().for_each(|v| mean.add(*v, 1.0));
            (Some(d), mean.get())
        } else {
            (None, None)
        };
        Some(PlausibilityReport {
            bone_length_mm: bones.get(),
            acceleration_m_s2: accel.get(),
            jerk_m_s3: jerk.get(),
            foot_sliding_m_s: cfg.wants(Metric::FootSliding).then(|| if any_planted { foot.get() } else { None }),
            speed_js_per_bin: per_bin,
            speed_js_mean: js_mean,
            first_step: (first_step.scenes > 0).then(|| FirstStepReport { mean_largest_m: first_step.mean_largest_m / first_step.scenes as f64, ..first_step }),
        })
    } else {
        None
    };
    let sscp = if cfg.wants(Metric::Sscp) { Some(score_sscp(m, cfg, signals)?) } else { None };
    Ok(MethodReport {
        label: m.label.clone(),
        kind: m.kind.name(),
        inputs: m
            .inputs
            .iter()
            .map(|i| InputReport { path: i.path.display().to_string(), dataset: i.dataset.clone(), provenance: i.metadata.clone() })
            .collect(),
        settings: m.settings.clone(),
        scenes,
        ndms,
        mpjpe,
        stochastic,
        speed,
        plausibility,
        sscp,
        coverage,
        kinds,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::dataset::{Dataset, Sequence};
    use crate::data::test_util::walkers;
    use crate::eval::inputs::{MethodKind, MethodScene};
    use std::path::Path;

    /// A reference of one test scene.
    fn toy_reference(scene: &crate::data::Scene) -> Reference {
        let sequences = vec![Sequence { split: Split::Test, scene: scene.clone() }];
        Reference::new(Path::new("toy"), Dataset { name: "toy".into(), sequences, metadata: Map::new() }, Split::Test).unwrap()
    }

    /// Two samples: the ground truth moved by 0.1 m and by 0.3 m along x from the first
    /// forecast frame on. Known values: MPJPE and root error 0.2 (mean) / 0.1 (best), root-aligned
    /// 0; ADE = 0.1·√J (pose-vector norm, best sample), APD = 0.2·√(S·J); no bone stretch; NDMS
    /// 1 for words that do not straddle the jump (body-frame words ignore translation).
    #[test]
    fn shifted_ground_truth_gives_known_errors() {
        let (n, frames, nj) = (20usize, 140usize, 17usize);
        let mut scene = walkers(frames, 3, 0.3);
        scene.name = "A".into();
        let reference = toy_reference(&scene);
        let shifted = |dx: f32, k: usize| {
            let mut s = scene.clone();
            s.name = format!("A_s{k}");
            s.positions.slice_mut(s![n.., .., .., 0]).mapv_inplace(|v| v + dx);
            s
        };
        let method = Method {
            label: "shift".into(),
            kind: MethodKind::Forecasts,
            inputs: Vec::new(),
            settings: Map::new(),
            scenes: vec![MethodScene { reference: scene.clone(), observed: n, samples: vec![shifted(0.1, 0), shifted(0.3, 1)] }],
        };
        let cfg = EvalConfig { stochastic_horizon_s: 1.0, ..Default::default() };
        let mut stages = Vec::new();
        let r = evaluate(&reference, &[method], &cfg, SignalSource::Annotations, &mut |p| stages.push(p.stage.clone())).unwrap();
        assert!(stages.iter().any(|s| s == "NDMS shift"), "{stages:?}");
        let m = &r.methods[0];
        let close = |a: f64, b: f64| (a - b).abs() < 1e-5 * b.abs().max(1.0);
        let p = m.mpjpe.as_ref().unwrap();
        for h in &p.horizons {
            let (g, root, al) = (h.global.unwrap(), h.root.unwrap(), h.root_aligned.unwrap());
            assert!(close(g.mean, 0.2) && close(g.best, 0.1) && close(root.mean, 0.2) && close(root.best, 0.1), "{h:?}");
            assert!(al.mean < 1e-6, "{h:?}");
            assert_eq!(h.scenes, 1);
        }
        assert_eq!((p.horizons[0].frame, p.horizons[2].frame), (29, 89));
        assert!(p.global_per_frame.values.iter().all(|&v| close(v, 0.2)));
        let st = m.stochastic.as_ref().unwrap();
        assert_eq!(st.frames, 30);
        assert!(close(st.ade.unwrap(), 0.1 * (nj as f64).sqrt()) && close(st.fde.unwrap(), 0.1 * (nj as f64).sqrt()), "{st:?}");
        assert!(close(st.apd.unwrap(), 0.2 * ((30 * nj) as f64).sqrt()), "{st:?}");
        // The person's own future is among the alternatives, others may be too.
        assert!(st.alternatives_per_person.unwrap() >= 1.0 && st.mmade.unwrap() >= st.ade.unwrap() - 1e-9, "{st:?}");
        let pl = m.plausibility.as_ref().unwrap();
        assert!(pl.bone_length_mm.unwrap() < 1e-3);
        // NDMS: the words after the jump find themselves (κ = 10, lead 10: word i starts at i − 10).
        let nd = m.ndms.as_ref().unwrap();
        assert_eq!(nd.per_frame.first_offset, -10);
        assert!(nd.per_frame.values[10..].iter().all(|&v| (v - 1.0).abs() < 1e-4), "{:?}", &nd.per_frame.values[8..14]);
        assert!(nd.per_frame.values[..10].iter().any(|&v| v < 0.99), "words across the jump");
        assert_eq!(nd.words, 2 * 3 * (frames - n + 10 - 10 + 1));
        // Speed equals the reference's except at the jump step.
        let sp = m.speed.as_ref().unwrap();
        let real = r.reference_speed.as_ref().unwrap();
        assert_eq!((sp.per_frame.first_offset, real.first_offset), (1 - n as i64, 1 - n as i64));
        for off in 1..(frames - n) as i64 - 1 {
            assert!((sp.per_frame.at(off).unwrap() - real.at(off).unwrap()).abs() < 1e-3, "offset {off}");
        }
        assert!(sp.per_frame.at(0).unwrap() > real.at(0).unwrap() + 1.0, "the 0.1/0.3 m jump at 30 fps");
        assert!(m.sscp.as_ref().unwrap().skipped.as_ref().unwrap().contains("speaking"));
        // The JSON carries every number; a NaN would be null.
        let json: serde_json::Value = serde_json::from_str(&r.to_json()).unwrap();
        assert_eq!(json["methods"][0]["mpjpe"]["horizons"][0]["global"]["best"].as_f64().map(|v| close(v, 0.1)), Some(true));
        assert!(r.table().contains("shift"));
    }

    /// A forecast longer than its recording (a minute from a short scene): MPJPE and ADE/FDE
    /// over the recorded frames only (known values as above), NDMS and bones over every frame.
    #[test]
    fn forecasts_past_the_recording_score_pose_errors_on_the_recorded_part() {
        let (n, recorded, frames) = (20usize, 80usize, 140usize);
        let long = walkers(frames, 2, 0.3);
        let mut scene = long.slice_frames(0, recorded).unwrap();
        scene.name = "A".into();
        let reference = toy_reference(&scene);
        let mut sample = long.clone();
        sample.positions.slice_mut(s![n.., .., .., 0]).mapv_inplace(|v| v + 0.1);
        let sc = MethodScene { reference: scene.clone(), observed: n, samples: vec![sample] };
        assert_eq!((sc.forecast_frames(), sc.recorded_forecast_frames(), sc.truth().dim().0), (120, 60, 80));
        let method = Method { label: "long".into(), kind: MethodKind::Forecasts, inputs: Vec::new(), settings: Map::new(), scenes: vec![sc] };
        let cfg = EvalConfig { stochastic_horizon_s: 1.0, ..Default::default() };
        let r = evaluate(&reference, &[method], &cfg, SignalSource::Annotations, &mut |_| {}).unwrap();
        let m = &r.methods[0];
        let p = m.mpjpe.as_ref().unwrap();
        // 1 s and 2 s lie in the 60 recorded frames, 3 s does not.
        assert_eq!(p.horizons.iter().map(|h| h.scenes).collect::<Vec<_>>(), vec![1, 1, 0]);
        assert!((p.horizons[0].global.unwrap().mean - 0.1).abs() < 1e-5 && p.horizons[2].global.is_none());
        assert_eq!(p.global_per_frame.values.len(), 60);
        let st = m.stochastic.as_ref().unwrap();
        assert!((st.ade.unwrap() - 0.1 * 17f64.sqrt()).abs() < 1e-5, "{st:?}");
        // NDMS words run to the end of the forecast: 120 forecast frames + lead − κ + 1.
        assert_eq!(m.ndms.as_ref().unwrap().words, 2 * (120 + 10 - 10 + 1));
        assert_eq!(m.scenes[0].forecast_frames, 120);
    }

    /// Every frame of `scene` from `n` on replaced by frame `n − 1` (standing still).
    fn frozen(scene: &crate::data::Scene, n: usize) -> crate::data::Scene {
        let mut s = scene.clone();
        let last = s.positions.slice(s![n - 1..n, .., .., ..]).to_owned();
        for f in n..s.num_frames() {
            s.positions.slice_mut(s![f..f + 1, .., .., ..]).assign(&last);
        }
        s
    }

    fn one_scene_method(label: &str, reference: &crate::data::Scene, n: usize, sample: crate::data::Scene) -> Method {
        let scenes = vec![MethodScene { reference: reference.clone(), observed: n, samples: vec![sample] }];
        Method { label: label.into(), kind: MethodKind::Forecasts, inputs: Vec::new(), settings: Map::new(), scenes }
    }

    /// The ground truth's words are database words (precision exactly 1); standing still
    /// finds no real word within reach and covers none (its words are all one word).
    #[test]
    fn coverage_tells_the_recording_from_standing_still() {
        let (n, frames) = (20usize, 200usize);
        let mut scene = walkers(frames, 2, 0.7);
        scene.name = "A".into();
        let reference = toy_reference(&scene);
        let methods = [one_scene_method("truth", &scene, n, scene.clone()), one_scene_method("still", &scene, n, frozen(&scene, n))];
        let cfg = EvalConfig { metrics: vec![Metric::Coverage], ..Default::default() };
        let r = evaluate(&reference, &methods, &cfg, SignalSource::Annotations, &mut |_| {}).unwrap();
        let (truth, still) = (r.methods[0].coverage.clone().unwrap(), r.methods[1].coverage.clone().unwrap());
        assert_eq!(truth.precision, 1.0, "{truth:?}");
        // 2 persons × words starting every 5 frames in 20..=190.
        assert_eq!(truth.generated_words, 2 * ((frames - 10 - n) / 5 + 1));
        assert_eq!(truth.real_words, 2 * (frames - 10 + 1));
        // The forecast part (frames 20..200 of 200) covers most of the real words.
        assert!(truth.recall > 0.8, "{truth:?}");
        assert_eq!((still.precision, still.recall), (0.0, 0.0), "{still:?}");
        assert!(r.methods[0].ndms.is_none(), "NDMS not asked for");
        assert!(r.table().contains("precision"));
    }

    /// A classifier of walking vs standing still: the recording's kinds match the reference's
    /// (JS 0), standing still is disjoint from them (JS = √ln 2); without a classifier the
    /// metric is refused.
    #[test]
    fn kinds_of_forecasts_against_the_reference() {
        use crate::metrics::kinds::{KindTraining, MotionKindClassifier};
        let (n, frames) = (30usize, 240usize);
        let mut scene = walkers(frames, 2, 0.2);
        scene.name = "A".into();
        let train: Vec<crate::data::Scene> = (0..4).map(|i| walkers(150, 1, 1.0 + i as f32)).collect();
        let still: Vec<crate::data::Scene> = train.iter().map(|s| frozen(s, 1)).collect();
        let examples: Vec<(&crate::data::Scene, &str)> = train.iter().map(|s| (s, "walk")).chain(still.iter().map(|s| (s, "still"))).collect();
        let clf = MotionKindClassifier::train(&examples, &KindTraining::default()).unwrap();
        assert_eq!(clf.labels, ["still", "walk"]);
        let reference = toy_reference(&scene);
        let methods = [one_scene_method("truth", &scene, n, scene.clone()), one_scene_method("still", &scene, n, frozen(&scene, n))];
        let mut cfg = EvalConfig { metrics: vec![Metric::Kinds], ..Default::default() };
        let err = evaluate(&reference, &methods, &cfg, SignalSource::Annotations, &mut |_| {}).unwrap_err().to_string();
        assert!(err.contains("needs a motion-kind classifier"), "{err}");
        cfg.kinds = Some(Arc::new(clf));
        let r = evaluate(&reference, &methods, &cfg, SignalSource::Annotations, &mut |_| {}).unwrap();
        let (truth, st) = (r.methods[0].kinds.clone().unwrap(), r.methods[1].kinds.clone().unwrap());
        // Windows of 60 frames every 30: the reference 2 × 7, the forecasts (210 frames) 2 × 6.
        assert_eq!((truth.reference_windows.clone(), truth.windows.clone()), (vec![0, 14], vec![0, 12]));
        assert_eq!(truth.js, 0.0);
        assert_eq!(st.windows, [12, 0]);
        assert!((st.js - crate::metrics::JS_DISTANCE_MAX).abs() < 1e-12);
    }

    /// Generated scenes (no recorded future) are read as one method scene per shape, scored
    /// from frame 0 by NDMS, for bone lengths against their own start and for coverage; a
    /// skeleton other than the reference's is refused naming the directory.
    #[test]
    fn generated_scenes_are_scored_without_a_recorded_future() {
        let mut scene = walkers(150, 2, 0.4);
        scene.name = "A".into();
        let reference = toy_reference(&scene);
        let dir = crate::data::test_util::tmp("generated-eval");
        let sequences = (0..3)
            .map(|k| {
                let mut s = walkers(100, 2, 0.4 + k as f32);
                s.name = format!("gen_{k}");
                Sequence { split: Split::Test, scene: s }
            })
            .collect();
        crate::data::dataset::write_dataset(&Dataset { name: "gen".into(), sequences, metadata: Map::new() }, &dir).unwrap();
        let m = Method::from_generated("gen", &dir, &reference, 10, None).unwrap();
        assert_eq!((m.scenes.len(), m.scenes[0].samples.len(), m.scenes[0].observed), (1, 3, 10));
        let err = Method::from_generated("gen", &dir, &reference, 10, Some(Split::Train)).unwrap_err().to_string();
        assert!(err.contains("holds no train sequences"), "{err}");
        let cfg = EvalConfig { metrics: vec![Metric::Ndms, Metric::Mpjpe, Metric::BoneLength, Metric::Coverage], ..Default::default() };
        let r = evaluate(&reference, &[m], &cfg, SignalSource::Annotations, &mut |_| {}).unwrap();
        let g = &r.methods[0];
        assert_eq!(g.kind, "generated");
        // NDMS from frame 0: 3 samples × 2 persons × (100 − 10 + 1) words.
        assert_eq!(g.ndms.as_ref().unwrap().words, 3 * 2 * 91);
        assert!(g.plausibility.as_ref().unwrap().bone_length_mm.unwrap() < 1e-3);
        assert!(g.mpjpe.as_ref().unwrap().horizons.iter().all(|h| h.scenes == 0), "no recorded future");
        assert!(g.coverage.as_ref().unwrap().precision > 0.0);
        let mut other = walkers(100, 2, 0.0);
        other.skeleton.joints[0] = "nose".into();
        let bad = crate::data::test_util::tmp("generated-eval-bad");
        crate::data::dataset::write_dataset(
            &Dataset { name: "bad".into(), sequences: vec![Sequence { split: Split::Test, scene: other }], metadata: Map::new() },
            &bad,
        )
        .unwrap();
        let err = Method::from_generated("bad", &bad, &reference, 10, None).unwrap_err().to_string();
        assert!(err.contains(&bad.display().to_string()) && err.contains("skeleton"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
        std::fs::remove_dir_all(&bad).ok();
    }
}
