//! NDMS, the normalized directional motion similarity (METHOD.md §5; thesis Ch. 6.3).
//!
//! # Motion words
//! A word is κ consecutive frames of one person on a joint set 𝒥 (default: head or nose,
//! shoulders, elbows, wrists, knees, ankles; see [`NdmsJoints`]). κ = 10 at 30 Hz and
//! `round(fps/3)` otherwise ([`super::word_length_for_fps`]). The word is expressed in the body
//! frame of its *first* frame (origin: hip midpoint on the ground; left→right hip axis along
//! +x; heights kept), so that for the first frame's root `r` and heading `h`
//!
//! ```text
//! w[t, j] = Rz(−h)·(p_j(s + t) − (r_x, r_y, 0)),   t = 0..κ−1,  j ∈ 𝒥      (f64, D = 3κ|𝒥|)
//! ```
//!
//! # Database and nearest neighbour
//! The database holds every word of a reference set of scenes (METHOD: the test set), every
//! person, every start frame `s = 0..=frames−κ` — except words that touch a frame the scene's
//! validity mask marks invalid, and words whose first frame has a degenerate hip axis (counted
//! in [`NdmsDatabase::num_skipped_degenerate`]). Each forecast word is matched to its **exact**
//! Euclidean nearest database word (positions, f64; see [`super::nn`]; ties → the earliest
//! word in database order).
//!
//! # Score
//! With velocities `a_t,j = w[t+1, j] − w[t, j]` of the forecast word and `b_t,j` of its
//! neighbour (t = 0..κ−2):
//!
//! ```text
//! ψ(a, b) = ½ (1 + a·b / (|a|·|b|)) · min(|a|, |b|) / max(|a|, |b|),  |·| floored at 1e-7
//! NDMS(word) = mean over t and j of ψ(a_t,j, b_t,j)                  ∈ [0, 1]
//! ```
//!
//! computed as `cos = a·b / √(|a|²·|b|²)` and `ratio = √(min(|a|², |b|²)/max(|a|², |b|²))` with
//! `|·|²` floored at 1e-14 — the same numbers, but a word matched to an identical word scores
//! exactly 1. As in the reference, a joint at rest in *both* words scores ½ (cos = 0, ratio 1).
//!
//! # Forecast words and the curve
//! For a sequence whose first forecast frame is `f`, word `i` starts at frame `f − lead + i`
//! (default `lead = κ`: the first word is the last κ observed frames), for every start where a
//! whole word fits. [`NdmsCurve::per_frame`]`[i]` is the score of word `i`, its mean the NDMS
//! of the sequence. The body frame of a forecast word whose first frame has a degenerate hip
//! axis uses heading 0 (a forecast is scored, not rejected).

use super::nn::{dist2, ExactNn, Neighbour};
use super::word_length_for_fps;
use crate::data::joints::{find_part, Part, Side};
use crate::data::{Scene, Skeleton};
use crate::features::{ground_midpoint, Anchor};
use crate::{bail, Error, Result};
use ndarray::{Array2, ArrayView3, ArrayView5, Axis};
use rayon::prelude::*;

/// Velocity norms are floored at this (m/frame) before ψ.
pub const NORM_FLOOR: f64 = 1e-7;

/// Which joints make up a motion word.
#[derive(Clone, Debug, PartialEq, Default)]
pub enum NdmsJoints {
    /// Head (nose, else head, else head top), and left and right shoulder, elbow, wrist, knee
    /// and ankle — 11 joints, found by name for any skeleton (see [`default_joints`]).
    #[default]
    Default,
    /// Exactly these joint names of the skeleton.
    Names(Vec<String>),
    /// Every joint of the skeleton (for skeletons without the default set, e.g. upper bodies).
    All,
}

impl NdmsJoints {
    /// Parses `default`, `all` or comma-separated joint names.
    pub fn parse(s: &str) -> Result<Self> {
        match s.trim() {
            "default" => Ok(NdmsJoints::Default),
            "all" => Ok(NdmsJoints::All),
            "" => bail!("NDMS joints: empty list (give joint names, all or default)"),
            list => Ok(NdmsJoints::Names(list.split(',').map(|n| n.trim().to_string()).filter(|n| !n.is_empty()).collect())),
        }
    }

    /// Joint indices in `skeleton`, or an error naming the joint that is missing.
    pub fn resolve(&self, skeleton: &Skeleton) -> Result<Vec<usize>> {
        match self {
            NdmsJoints::Default => default_joints(skeleton),
            NdmsJoints::All => Ok((0..skeleton.num_joints()).collect()),
            NdmsJoints::Names(names) => {
                if names.is_empty() {
                    bail!("NDMS joints: the list of joint names is empty");
                }
                let idx = names.iter().map(|n| skeleton.require_joint(n)).collect::<Result<Vec<_>>>()?;
                for (i, a) in idx.iter().enumerate() {
                    if idx[..i].contains(a) {
                        bail!("NDMS joints: joint {:?} is listed twice", names[i]);
                    }
                }
                Ok(idx)
            }
        }
    }
}

/// The default NDMS joint set of a skeleton, found by name: head (`nose`, else `head`, else
/// `head_top`), then left and right shoulder, elbow, wrist, knee and ankle, read from the names
/// by the joint vocabulary ([`crate::data::joints`]: `LeftForeArm`, `lradius`, `LowerArm_L` are
/// the elbow). Panoptic-19 gives
/// `[nose, left_shoulder, left_elbow, left_wrist, left_knee, left_ankle, right_…]` (the
/// reference's joints), MuPoTS-17 the same with `head` for the nose.
pub fn default_joints(skeleton: &Skeleton) -> Result<Vec<usize>> {
    let j = &skeleton.joints;
    let find = |wanted: &[(Part, Side)], what: &str| -> Result<usize> {
        find_part(j, wanted).ok_or_else(|| {
            Error::invalid(format!(
                "NDMS joints: skeleton {} has no joint for the {what} (joints: {}); give the NDMS joints by name, or use all joints",
                skeleton.name,
                j.join(", ")
            ))
        })
    };
    let mut out = vec![find(&[(Part::Nose, Side::Centre), (Part::Head, Side::Centre), (Part::HeadTop, Side::Centre)], "head")?];
    for (side, word) in [(Side::Left, "left"), (Side::Right, "right")] {
        for (part, what) in [(Part::Shoulder, "shoulder"), (Part::Elbow, "elbow"), (Part::Wrist, "wrist"), (Part::Knee, "knee"), (Part::Ankle, "ankle")] {
            out.push(find(&[(part, side)], &format!("{word} {what}"))?);
        }
    }
    for (i, a) in out.iter().enumerate() {
        if out[..i].contains(a) {
            bail!("NDMS joints: skeleton {}: joint {} matched twice in the default set", skeleton.name, skeleton.joints[*a]);
        }
    }
    Ok(out)
}

/// NDMS settings.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct NdmsConfig {
    /// Joints of a word (default: [`NdmsJoints::Default`]).
    pub joints: NdmsJoints,
    /// Word length κ in frames; `None`: 10 at 30 Hz, `round(fps/3)` otherwise.
    pub word_length: Option<usize>,
    /// How many frames before the first forecast frame the first forecast word starts;
    /// `None`: κ (the reference's choice).
    pub lead: Option<usize>,
}

/// NDMS of one sequence.
#[derive(Clone, Debug, PartialEq)]
pub struct NdmsCurve {
    /// Frame (of the scored array) where word 0 starts: first forecast frame − lead.
    pub first_word_frame: usize,
    /// Score of word `i` (frames `first_word_frame + i ..+ κ`); NaN for a word that was
    /// skipped because it touches an invalid frame.
    pub per_frame: Vec<f64>,
    /// Mean over the scored words (NaN when none was scored).
    pub mean: f64,
}

impl NdmsCurve {
    fn from_scores(first_word_frame: usize, per_frame: Vec<f64>) -> Self {
        let (s, n) = per_frame.iter().filter(|v| !v.is_nan()).fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
        Self { first_word_frame, per_frame, mean: if n == 0 { f64::NAN } else { s / n as f64 } }
    }
}

/// NDMS of several sequences (persons, samples, scenes).
#[derive(Clone, Debug, PartialEq)]
pub struct NdmsScore {
    /// One curve per sequence (for [`NdmsDatabase::score_forecasts`]: sample-major, index
    /// `k · persons + p`).
    pub curves: Vec<NdmsCurve>,
    /// Mean over the curves of word `i` (curves that lack word `i` or skipped it do not count).
    pub per_frame: Vec<f64>,
    /// Mean over every scored word of every curve (NaN when none).
    pub mean: f64,
}

impl NdmsScore {
    /// Pools curves: the per-word mean curve and the mean over all scored words. Use it to
    /// average over scenes, too (collect every scene's curves first).
    pub fn from_curves(curves: Vec<NdmsCurve>) -> Self {
        let len = curves.iter().map(|c| c.per_frame.len()).max().unwrap_or(0);
        let mut sum = vec![0.0; len];
        let mut cnt = vec![0usize; len];
        for c in &curves {
            for (i, v) in c.per_frame.iter().enumerate() {
                if !v.is_nan() {
                    sum[i] += v;
                    cnt[i] += 1;
                }
            }
        }
        let total: usize = cnt.iter().sum();
        let mean = if total == 0 { f64::NAN } else { sum.iter().sum::<f64>() / total as f64 };
        let per_frame = sum.iter().zip(&cnt).map(|(s, &n)| if n == 0 { f64::NAN } else { s / n as f64 }).collect();
        Self { curves, per_frame, mean }
    }
}

/// ψ averaged over the velocities of two words (module docs).
///
/// # Shapes
/// - `a`, `b`: `[κ · joints · 3]` (frame-major), κ ≥ 2.
///
/// # Panics
/// If the lengths differ or are not a multiple of `3 · joints` with κ ≥ 2.
pub fn word_similarity(a: &[f64], b: &[f64], joints: usize) -> f64 {
    let row = 3 * joints;
    assert!(
        a.len() == b.len() && joints > 0 && a.len().is_multiple_of(row) && a.len() >= 2 * row,
        "word_similarity: words of {} and {} values, {joints} joints",
        a.len(),
        b.len()
    );
    let floor2 = NORM_FLOOR * NORM_FLOOR;
    let mut sum = 0.0;
    let kappa = a.len() / row;
    for t in 0..kappa - 1 {
        for j in 0..joints {
            let o = t * row + 3 * j;
            let va = [a[o + row] - a[o], a[o + row + 1] - a[o + 1], a[o + row + 2] - a[o + 2]];
            let vb = [b[o + row] - b[o], b[o + row + 1] - b[o + 1], b[o + row + 2] - b[o + 2]];
            let na2 = (va[0] * va[0] + va[1] * va[1] + va[2] * va[2]).max(floor2);
            let nb2 = (vb[0] * vb[0] + vb[1] * vb[1] + vb[2] * vb[2]).max(floor2);
            let dot = va[0] * vb[0] + va[1] * vb[1] + va[2] * vb[2];
            let cos = (dot / (na2 * nb2).sqrt()).clamp(-1.0, 1.0);
            let ratio = (na2.min(nb2) / na2.max(nb2)).sqrt();
            sum += 0.5 * (1.0 + cos) * ratio;
        }
    }
    sum / ((kappa - 1) * joints) as f64
}

/// Writes the word starting at `start` of a `[frames · nj · 3]` pose track, in body frame
/// `anchor`, into `out` (`[κ · joints.len() · 3]`).
fn word_into(pos: &[f32], nj: usize, joints: &[usize], anchor: &Anchor, start: usize, out: &mut [f64]) {
    let (s, c) = anchor.heading.sin_cos();
    let [ox, oy] = anchor.root;
    let kappa = out.len() / (3 * joints.len());
    let mut o = 0;
    for t in start..start + kappa {
        let pose = &pos[t * nj * 3..(t + 1) * nj * 3];
        for &j in joints {
            let (dx, dy) = (pose[3 * j] as f64 - ox, pose[3 * j + 1] as f64 - oy);
            out[o] = c * dx + s * dy;
            out[o + 1] = -s * dx + c * dy;
            out[o + 2] = pose[3 * j + 2] as f64;
            o += 3;
        }
    }
}

/// Body frame of a pose, heading 0 when the hip axis is degenerate.
pub(crate) fn anchor_or_level(pose: &[f32], left: usize, right: usize) -> Anchor {
    Anchor::of_pose(pose, left, right).unwrap_or(Anchor { root: ground_midpoint(pose, left, right), heading: 0.0 })
}

/// One person of one database scene.
#[derive(Clone, Debug)]
pub(crate) struct Track {
    /// Index of the scene in the build list.
    pub scene: usize,
    /// Person index in the scene.
    pub person: usize,
    /// Poses `[frames · joints · 3]`.
    pub pos: Vec<f32>,
    /// Validity per frame.
    pub valid: Vec<bool>,
    /// Body frame per frame (`None`: degenerate hip axis).
    pub anchors: Vec<Option<Anchor>>,
}

impl Track {
    pub fn frames(&self) -> usize {
        self.valid.len()
    }
}

/// The NDMS reference database: every motion word of a set of scenes, indexed for exact
/// nearest-neighbour search.
#[derive(Clone, Debug)]
pub struct NdmsDatabase {
    skeleton: Skeleton,
    fps: f64,
    kappa: usize,
    lead: usize,
    joints: Vec<usize>,
    scene_names: Vec<String>,
    pub(crate) tracks: Vec<Track>,
    /// (track, start frame) of every word.
    words: Vec<(u32, u32)>,
    index: ExactNn,
    skipped_degenerate: usize,
}

impl NdmsDatabase {
    /// Collects every word of `scenes` (module docs). All scenes must share one skeleton and
    /// frame rate.
    pub fn build(scenes: &[&Scene], cfg: &NdmsConfig) -> Result<Self> {
        let Some(first) = scenes.first() else {
            bail!("NDMS database: no scenes");
        };
        for s in scenes {
            if s.skeleton.joints != first.skeleton.joints || (s.skeleton.left, s.skeleton.right) != (first.skeleton.left, first.skeleton.right) {
                bail!("NDMS database: scene {} has skeleton {}, scene {} has {}", s.name, s.skeleton.name, first.name, first.skeleton.name);
            }
            if (s.fps - first.fps).abs() > 1e-6 {
                bail!("NDMS database: scene {} is at {} fps, scene {} at {} fps (resample first)", s.name, s.fps, first.name, first.fps);
            }
        }
        let skeleton = first.skeleton.clone();
        let kappa = cfg.word_length.unwrap_or_else(|| word_length_for_fps(first.fps));
        if kappa < 2 {
            bail!("NDMS: word length must be at least 2 frames, got {kappa}");
        }
        let lead = cfg.lead.unwrap_or(kappa);
        let joints = cfg.joints.resolve(&skeleton)?;
        let (nj, l, r) = (skeleton.num_joints(), skeleton.left, skeleton.right);
        let mut tracks = Vec::new();
        for (si, s) in scenes.iter().enumerate() {
            for p in 0..s.num_persons() {
                let pos: Vec<f32> = s.person(p).iter().copied().collect();
                let valid: Vec<bool> = (0..s.num_frames()).map(|f| s.is_valid(f, p)).collect();
                let anchors = pos.chunks_exact(3 * nj).map(|pose| Anchor::of_pose(pose, l, r)).collect();
                tracks.push(Track { scene: si, person: p, pos, valid, anchors });
            }
        }
        let mut words = Vec::new();
        let mut skipped_degenerate = 0;
        for (ti, t) in tracks.iter().enumerate() {
            let n = t.frames();
            // run[f] = number of consecutive valid frames starting at f.
            let mut run = vec![0usize; n + 1];
            for f in (0..n).rev() {
                run[f] = if t.valid[f] { run[f + 1] + 1 } else { 0 };
            }
            for (s, &r) in run.iter().enumerate().take((n + 1).saturating_sub(kappa)) {
                if r < kappa {
                    continue;
                }
                if t.anchors[s].is_none() {
                    skipped_degenerate += 1;
                    continue;
                }
                words.push((ti as u32, s as u32));
            }
        }
        if words.is_empty() {
            bail!("NDMS database: no valid word of {kappa} frames in {} scene(s)", scenes.len());
        }
        let dim = 3 * kappa * joints.len();
        let index = ExactNn::build(words.len(), dim, |i, out| {
            let (t, s) = words[i];
            let t = &tracks[t as usize];
            word_into(&t.pos, nj, &joints, &t.anchors[s as usize].expect("checked"), s as usize, out)
        })?;
        let scene_names = scenes.iter().map(|s| s.name.clone()).collect();
        Ok(Self { skeleton, fps: first.fps, kappa, lead, joints, scene_names, tracks, words, index, skipped_degenerate })
    }

    /// Number of words.
    pub fn num_words(&self) -> usize {
        self.words.len()
    }

    /// Word length κ in frames.
    pub fn word_length(&self) -> usize {
        self.kappa
    }

    /// Frames between the start of the first forecast word and the first forecast frame.
    pub fn lead(&self) -> usize {
        self.lead
    }

    /// Joint indices of a word.
    pub fn joints(&self) -> &[usize] {
        &self.joints
    }

    /// Skeleton of the database scenes (scored poses must use it).
    pub fn skeleton(&self) -> &Skeleton {
        &self.skeleton
    }

    /// Frame rate of the database scenes.
    pub fn fps(&self) -> f64 {
        self.fps
    }

    /// Word dimension D = 3κ|𝒥|.
    pub fn dim(&self) -> usize {
        self.index.dim()
    }

    /// Valid words left out because their first frame has a degenerate hip axis.
    pub fn num_skipped_degenerate(&self) -> usize {
        self.skipped_degenerate
    }

    /// Where word `i` comes from: (scene name, person, start frame).
    pub fn word_origin(&self, i: usize) -> (&str, usize, usize) {
        let (t, s) = self.words[i];
        let t = &self.tracks[t as usize];
        (&self.scene_names[t.scene], t.person, s as usize)
    }

    /// Word `i` of the database (f64, body frame of its first frame).
    ///
    /// # Shapes
    /// - output: `[κ · joints · 3]`, frame-major.
    pub fn word(&self, i: usize) -> Vec<f64> {
        let mut out = vec![0.0; self.dim()];
        self.word_into(i, &mut out);
        out
    }

    pub(crate) fn word_into(&self, i: usize, out: &mut [f64]) {
        let (t, s) = self.words[i];
        let t = &self.tracks[t as usize];
        word_into(&t.pos, self.skeleton.num_joints(), &self.joints, &t.anchors[s as usize].expect("checked"), s as usize, out);
    }

    /// (track, start frame) of word `i`.
    pub(crate) fn word_ref(&self, i: usize) -> (usize, usize) {
        let (t, s) = self.words[i];
        (t as usize, s as usize)
    }

    /// Word starting at `start` of a pose track `[frames · J · 3]` (this skeleton), in the
    /// body frame of its first frame (heading 0 if degenerate); returns that body frame.
    pub(crate) fn track_word(&self, pos: &[f32], start: usize, out: &mut [f64]) -> Anchor {
        let nj = self.skeleton.num_joints();
        let a = anchor_or_level(&pos[start * nj * 3..(start + 1) * nj * 3], self.skeleton.left, self.skeleton.right);
        word_into(pos, nj, &self.joints, &a, start, out);
        a
    }

    /// Words of a sequence starting at frames `first_word_frame..=frames − κ`, each in the
    /// body frame of its first frame (heading 0 if that is degenerate).
    ///
    /// # Shapes
    /// - `positions`: `[frames, joints, 3]` of this skeleton; output: `[words, κ · |𝒥| · 3]`.
    pub fn sequence_words(&self, positions: ArrayView3<f32>, first_word_frame: usize) -> Result<Array2<f64>> {
        let pos = self.check_sequence(positions, first_word_frame + self.kappa, "sequence")?;
        let n = positions.dim().0 + 1 - self.kappa - first_word_frame;
        let dim = self.dim();
        let mut out = Array2::zeros((n, dim));
        for (i, mut row) in out.axis_iter_mut(Axis(0)).enumerate() {
            self.track_word(&pos, first_word_frame + i, row.as_slice_mut().expect("row of a fresh array"));
        }
        Ok(out)
    }

    /// Exact nearest database word of each query word.
    ///
    /// # Shapes
    /// - `words`: `[queries, D]`; output `[queries]`.
    pub fn nearest(&self, words: ndarray::ArrayView2<f64>) -> Result<Vec<Neighbour>> {
        if words.dim().1 != self.dim() {
            bail!("NDMS nearest: query words have {} values, the database's {}", words.dim().1, self.dim());
        }
        let q = words.as_standard_layout();
        let got = self.nearest_where(q.as_slice().expect("standard layout"), None)?;
        got.into_iter().enumerate().map(|(i, n)| n.ok_or_else(|| crate::Error::invalid(format!("NDMS nearest: query word {i} is not finite")))).collect()
    }

    /// Exact nearest allowed word of each query (`[Q · D]`), `None` when there is none.
    pub(crate) fn nearest_where(&self, queries: &[f64], allowed: Option<&[bool]>) -> Result<Vec<Option<Neighbour>>> {
        self.index.search(queries, allowed, |j, q| {
            let mut w = vec![0.0; self.dim()];
            self.word_into(j, &mut w);
            dist2(&w, q)
        })
    }

    /// Checks a `[frames, joints, 3]` sequence (skeleton, length ≥ `min_frames`, finite) and
    /// returns it as a contiguous `[frames · joints · 3]` buffer.
    fn check_sequence(&self, positions: ArrayView3<f32>, min_frames: usize, what: &str) -> Result<Vec<f32>> {
        let (nf, nj, three) = positions.dim();
        if nj != self.skeleton.num_joints() || three != 3 {
            bail!("NDMS: {what} has shape [{nf}, {nj}, {three}], expected [frames, {}, 3] (skeleton {})", self.skeleton.num_joints(), self.skeleton.name);
        }
        if nf < min_frames {
            bail!("NDMS: {what} has {nf} frames; its first word needs frames up to {min_frames} (κ = {}, lead = {})", self.kappa, self.lead);
        }
        let pos: Vec<f32> = positions.iter().copied().collect();
        if let Some(i) = pos.iter().position(|v| !v.is_finite()) {
            bail!("NDMS: {what} has a non-finite position at frame {}, joint {}", i / (3 * nj), (i / 3) % nj);
        }
        Ok(pos)
    }

    /// NDMS of one person's sequence whose first forecast frame is `first_forecast_frame`
    /// (module docs: words start `lead` frames earlier, so the array holds observed frames too).
    ///
    /// # Shapes
    /// - `positions`: `[frames, joints, 3]`, this skeleton.
    pub fn score_sequence(&self, positions: ArrayView3<f32>, first_forecast_frame: usize) -> Result<NdmsCurve> {
        Ok(self.score_sequences(&[positions], first_forecast_frame)?.remove(0))
    }

    /// [`NdmsDatabase::score_sequence`] for several sequences at once (one parallel search).
    ///
    /// # Shapes
    /// - each sequence: `[frames, joints, 3]`.
    pub fn score_sequences(&self, sequences: &[ArrayView3<f32>], first_forecast_frame: usize) -> Result<Vec<NdmsCurve>> {
        let items: Vec<(ArrayView3<f32>, Option<Vec<bool>>)> = sequences.iter().map(|s| (s.view(), None)).collect();
        self.score_items(&items, first_forecast_frame)
    }

    /// NDMS of every sample and person of a forecast.
    ///
    /// # Shapes
    /// - `forecasts`: `[K, frames, persons, joints, 3]`, holding at least `lead` observed frames
    ///   before `first_forecast_frame`; `curves` of the result: `[K · persons]`, sample-major.
    pub fn score_forecasts(&self, forecasts: ArrayView5<f32>, first_forecast_frame: usize) -> Result<NdmsScore> {
        let (k, _, persons, _, _) = forecasts.dim();
        let mut items = Vec::with_capacity(k * persons);
        for sample in forecasts.axis_iter(Axis(0)) {
            for p in 0..persons {
                items.push((sample.index_axis_move(Axis(1), p), None));
            }
        }
        Ok(NdmsScore::from_curves(self.score_items(&items, first_forecast_frame)?))
    }

    /// NDMS of every person of a scene (e.g. real motion against the database); words that
    /// touch a frame the scene marks invalid are skipped (NaN in the curve).
    pub fn score_scene(&self, scene: &Scene, first_forecast_frame: usize) -> Result<NdmsScore> {
        if scene.skeleton.joints != self.skeleton.joints {
            bail!("NDMS: scene {} has skeleton {}, the database {}", scene.name, scene.skeleton.name, self.skeleton.name);
        }
        let items: Vec<_> =
            (0..scene.num_persons()).map(|p| (scene.person(p), Some((0..scene.num_frames()).map(|f| scene.is_valid(f, p)).collect::<Vec<_>>()))).collect();
        Ok(NdmsScore::from_curves(self.score_items(&items, first_forecast_frame)?))
    }

    fn score_items(&self, items: &[(ArrayView3<f32>, Option<Vec<bool>>)], first_forecast_frame: usize) -> Result<Vec<NdmsCurve>> {
        let Some(first_word) = first_forecast_frame.checked_sub(self.lead) else {
            bail!("NDMS: first forecast frame {first_forecast_frame} is earlier than the lead of {} frames", self.lead);
        };
        let (dim, kappa) = (self.dim(), self.kappa);
        // Query words of every item, and where each score goes.
        let mut queries = Vec::new();
        let mut slots = Vec::new();
        let mut lens = Vec::with_capacity(items.len());
        for (ii, (positions, valid)) in items.iter().enumerate() {
            let pos = self.check_sequence(positions.view(), first_word + kappa, &format!("sequence {ii}"))?;
            let nf = positions.dim().0;
            let n = nf + 1 - kappa - first_word;
            lens.push(n);
            let mut run = vec![0usize; nf + 1];
            if let Some(v) = valid {
                for f in (0..nf).rev() {
                    run[f] = if v[f] { run[f + 1] + 1 } else { 0 };
                }
            }
            let base = queries.len();
            let mut keep = Vec::with_capacity(n);
            for i in 0..n {
                if valid.is_none() || run[first_word + i] >= kappa {
                    keep.push(i);
                }
            }
            queries.resize(base + keep.len() * dim, 0.0);
            queries[base..].par_chunks_mut(dim).zip(keep.par_iter()).for_each(|(out, &i)| {
                self.track_word(&pos, first_word + i, out);
            });
            slots.extend(keep.into_iter().map(|i| (ii, i)));
        }
        let nn = self.nearest_where(&queries, None)?;
        let scores: Vec<f64> = nn
            .par_iter()
            .zip(queries.par_chunks(dim))
            .map_init(
                || vec![0.0; dim],
                |w, (n, q)| {
                    let n = n.expect("finite queries always have a neighbour");
                    self.word_into(n.index, w);
                    word_similarity(q, w, self.joints.len())
                },
            )
            .collect();
        let mut curves: Vec<Vec<f64>> = lens.iter().map(|&n| vec![f64::NAN; n]).collect();
        for ((ii, i), s) in slots.into_iter().zip(scores) {
            curves[ii][i] = s;
        }
        Ok(curves.into_iter().map(|c| NdmsCurve::from_scores(first_word, c)).collect())
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::metrics::baselines::{constant_velocity, zero_velocity};
    use ndarray::{s, Array4, Array5};
    use rand::{rngs::StdRng, Rng, SeedableRng};
    use std::path::Path;

    /// Smooth random motion on MuPoTS-17: each person walks and turns at random, joints wobble
    /// around a standing pose. `[frames, persons, 17, 3]`.
    pub(crate) fn random_motion(frames: usize, persons: usize, seed: u64) -> Scene {
        let sk = Skeleton::mupots17();
        let mut rng = StdRng::seed_from_u64(seed);
        let base: Vec<[f64; 3]> = (0..17)
            .map(|j| match j {
                11 => [-0.1, 0.0, 0.9],
                8 => [0.1, 0.0, 0.9],
                _ => [rng.gen_range(-0.3..0.3), rng.gen_range(-0.2..0.2), rng.gen_range(0.0..1.7)],
            })
            .collect();
        let mut pos = Array4::<f32>::zeros((frames, persons, 17, 3));
        for p in 0..persons {
            let (mut x, mut y, mut h, mut speed, mut turn) = (p as f64 * 2.0, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
            let mut wob = vec![[0.0f64; 3]; 17];
            let mut wv = vec![[0.0f64; 3]; 17];
            for f in 0..frames {
                speed = (0.9 * speed + rng.gen_range(-0.01..0.012)).clamp(-0.01, 0.05);
                turn = 0.9 * turn + rng.gen_range(-0.01..0.01);
                h += turn;
                x += -h.sin() * speed;
                y += h.cos() * speed;
                let (s, c) = h.sin_cos();
                for j in 0..17 {
                    for k in 0..3 {
                        wv[j][k] = 0.8 * wv[j][k] + rng.gen_range(-0.004..0.004);
                        wob[j][k] = 0.97 * wob[j][k] + wv[j][k];
                    }
                    let b = if j == 8 || j == 11 {
                        [base[j][0], base[j][1], base[j][2] + wob[j][2]]
                    } else {
                        [base[j][0] + wob[j][0], base[j][1] + wob[j][1], base[j][2] + wob[j][2]]
                    };
                    pos[[f, p, j, 0]] = (x + c * b[0] - s * b[1]) as f32;
                    pos[[f, p, j, 1]] = (y + s * b[0] + c * b[1]) as f32;
                    pos[[f, p, j, 2]] = b[2] as f32;
                }
            }
        }
        Scene::new(format!("random{seed}"), 30.0, sk, pos).unwrap()
    }

    pub(crate) const MUPOTS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/mupots3d");

    /// The MuPoTS dataset, or `None` (reason printed) when it is absent.
    pub(crate) fn mupots() -> Option<crate::Dataset> {
        let dir = Path::new(MUPOTS);
        if !dir.join("dataset.json").exists() {
            println!("skipped: {} not found", dir.display());
            return None;
        }
        Some(crate::data::dataset::read_dataset(dir, &Default::default()).expect("read mupots3d"))
    }

    #[test]
    fn default_joints_resolve_by_name() {
        let p = Skeleton::panoptic19();
        assert_eq!(default_joints(&p).unwrap(), vec![1, 3, 4, 5, 7, 8, 9, 10, 11, 13, 14]);
        let m = Skeleton::mupots17();
        let names: Vec<&str> = default_joints(&m).unwrap().iter().map(|&i| m.joints[i].as_str()).collect();
        assert_eq!(
            names,
            [
                "head",
                "left_shoulder",
                "left_elbow",
                "left_wrist",
                "left_knee",
                "left_ankle",
                "right_shoulder",
                "right_elbow",
                "right_wrist",
                "right_knee",
                "right_ankle"
            ]
        );
        // Bandai-style BVH names: the upper arm is the shoulder joint (Shoulder_L is the clavicle).
        let j = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let b = crate::data::Skeleton::bandai21();
        let names: Vec<&str> = default_joints(&b).unwrap().iter().map(|&i| b.joints[i].as_str()).collect();
        assert_eq!(names, ["Head", "UpperArm_L", "LowerArm_L", "Hand_L", "LowerLeg_L", "Foot_L", "UpperArm_R", "LowerArm_R", "Hand_R", "LowerLeg_R", "Foot_R"]);
        let cmu = [
            "hip", "lfemur", "ltibia", "lfoot", "rfemur", "rtibia", "rfoot", "head", "lhumerus", "lradius", "lwrist", "lhand", "rhumerus", "rradius", "rwrist",
            "rhand",
        ];
        let c = Skeleton::new("cmu", j(&cmu), vec![], 1, 4).unwrap();
        let names: Vec<&str> = default_joints(&c).unwrap().iter().map(|&i| cmu[i]).collect();
        assert_eq!(names, ["head", "lhumerus", "lradius", "lwrist", "ltibia", "lfoot", "rhumerus", "rradius", "rwrist", "rtibia", "rfoot"]);
        // Missing joint: the error names it; explicit names are checked too.
        let no_elbow = Skeleton::new("x", j(&["nose", "left_hip", "right_hip"]), vec![], 1, 2).unwrap();
        let e = default_joints(&no_elbow).unwrap_err().to_string();
        assert!(e.contains("left shoulder") && e.contains("give the NDMS joints by name"), "{e}");
        assert_eq!(NdmsJoints::parse("all").unwrap().resolve(&p).unwrap(), (0..p.num_joints()).collect::<Vec<_>>());
        assert_eq!(NdmsJoints::parse(" neck , nose").unwrap(), NdmsJoints::Names(vec!["neck".into(), "nose".into()]));
        let e = NdmsJoints::Names(vec!["nose".into(), "tail".into()]).resolve(&p).unwrap_err().to_string();
        assert!(e.contains("tail"), "{e}");
        assert!(NdmsJoints::Names(vec!["nose".into(), "nose".into()]).resolve(&p).is_err());
        assert_eq!(NdmsJoints::Names(vec!["neck".into()]).resolve(&p).unwrap(), vec![0]);
    }

    /// ψ by hand. Two joints, κ = 2 (one velocity each):
    /// joint 0: a = (3, 4, 0), b = (−8, 6, 0): cos = 0, |a|/|b| = 5/10 → ψ = ½·1·½ = 0.25;
    /// joint 1: a = (1, 0, 0), b = (1, √3, 0): cos = ½, ratio ½ → ψ = ½·1.5·½ = 0.375.
    /// Mean 0.3125. One joint, κ = 3: a = (1,0,0),(0,2,0); b = (2,0,0),(0,2,0): ψ = ½, 1 → 0.75;
    /// against b' = (−1,0,0),(0,0,0): ψ = 0 (opposite), then cos = 0 and ratio = 1e-7/2
    /// (floored norm) → 2.5e-8; mean 1.25e-8.
    #[test]
    fn psi_matches_hand_computation() {
        let a = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 4.0, 0.0, 1.0, 0.0, 0.0];
        let b = [0.0, 0.0, 0.0, 5.0, 5.0, 5.0, -8.0, 6.0, 0.0, 6.0, 5.0 + 3f64.sqrt(), 5.0];
        assert!((word_similarity(&a, &b, 2) - 0.3125).abs() < 1e-12);
        let a = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 2.0, 0.0];
        let b = [1.0, 1.0, 1.0, 3.0, 1.0, 1.0, 3.0, 3.0, 1.0];
        assert!((word_similarity(&a, &b, 1) - 0.75).abs() < 1e-15);
        let b2 = [0.0, 0.0, 0.0, -1.0, 0.0, 0.0, -1.0, 0.0, 0.0];
        assert!((word_similarity(&a, &b2, 1) - 1.25e-8).abs() < 1e-20);
        assert_eq!(word_similarity(&a, &a, 1), 1.0);
        // Both at rest: ½ (reference semantics).
        let z = [0.0; 6];
        assert_eq!(word_similarity(&z, &z, 1), 0.5);
    }

    #[test]
    fn words_score_one_against_a_database_holding_them() {
        let scene = random_motion(400, 2, 1);
        let db = NdmsDatabase::build(&[&scene], &NdmsConfig::default()).unwrap();
        assert_eq!(db.num_words(), 2 * (400 - 9));
        assert_eq!(db.dim(), 330);
        let score = db.score_scene(&scene, db.lead()).unwrap();
        assert_eq!(score.curves.len(), 2);
        assert_eq!(score.curves[0].per_frame.len(), 391);
        assert!(score.curves.iter().all(|c| c.per_frame.iter().all(|&v| v == 1.0)));
        assert_eq!(score.mean, 1.0);
        // Same through the forecast API, and with the scene moved rigidly (body-frame words).
        let mut moved = scene.clone();
        let (s, c) = 0.7f64.sin_cos();
        moved.transform([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], [3.0, -2.0, 0.0]);
        let f = moved.positions.view().insert_axis(Axis(0));
        let sc = db.score_forecasts(f, 30).unwrap();
        assert_eq!(sc.per_frame.len(), 400 - 20 - 10 + 1);
        assert_eq!(sc.curves[0].first_word_frame, 20);
        assert!(sc.per_frame.iter().all(|&v| (v - 1.0).abs() < 1e-3), "{:?}", &sc.per_frame[..5]);
    }

    #[test]
    fn zero_velocity_scores_near_zero_and_scores_lie_in_unit_interval() {
        let scene = random_motion(600, 2, 2);
        let db = NdmsDatabase::build(&[&scene], &NdmsConfig::default()).unwrap();
        let other = random_motion(300, 2, 3);
        let obs = other.positions.slice(s![..100, .., .., ..]);
        let zv = zero_velocity(obs, 200).unwrap();
        let full = ndarray::concatenate(Axis(0), &[obs, zv.view()]).unwrap();
        let sc = db.score_forecasts(full.view().insert_axis(Axis(0)), 100).unwrap();
        let kappa = db.word_length();
        // Words from the last observed frame on are entirely at rest.
        for c in &sc.curves {
            assert!(c.per_frame[kappa - 1..].iter().all(|&v| (0.0..0.01).contains(&v)), "{:?}", &c.per_frame[kappa - 1..kappa + 3]);
        }
        let rest: Vec<f64> = sc.per_frame[kappa - 1..].to_vec();
        println!("zero-velocity NDMS {:.2e}", rest.iter().sum::<f64>() / rest.len() as f64);
        // A static whole sequence.
        let still = Array4::from_shape_fn((50, 1, 17, 3), |(_, _, j, k)| other.positions[[0, 0, j, k]]);
        let c = db.score_sequence(still.index_axis(Axis(1), 0), 10).unwrap();
        assert!(c.mean < 0.01, "{}", c.mean);
        // Real-ish and wild motion: every score in [0, 1].
        let cv = constant_velocity(obs, 200).unwrap();
        let noisy = Array5::from_shape_fn((2, 300, 2, 17, 3), |(k, f, p, j, d)| {
            if k == 0 {
                other.positions[[f, p, j, d]]
            } else {
                other.positions[[f, p, j, d]] + ((f * 31 + j * 7 + d) % 13) as f32 * 0.01
            }
        });
        let full_cv = ndarray::concatenate(Axis(0), &[obs, cv.view()]).unwrap();
        for sc in [db.score_forecasts(noisy.view(), 10).unwrap(), db.score_forecasts(full_cv.view().insert_axis(Axis(0)), 100).unwrap()] {
            for c in &sc.curves {
                assert!(c.per_frame.iter().all(|v| (0.0..=1.0).contains(v)));
            }
            assert!(sc.mean > 0.0 && sc.mean < 1.0, "{}", sc.mean);
        }
    }

    /// The database's nearest words equal an f64 brute-force loop over `word(i)`.
    #[test]
    fn nearest_words_match_naive_loop() {
        let a = random_motion(1500, 3, 4);
        let b = random_motion(120, 2, 5);
        let db = NdmsDatabase::build(&[&a, &b], &NdmsConfig::default()).unwrap();
        assert!(db.index.has_bounds(), "{} words: the lower-bound path is tested", db.num_words());
        let words: Vec<Vec<f64>> = (0..db.num_words()).map(|i| db.word(i)).collect();
        let q = random_motion(260, 1, 6);
        let qw = db.sequence_words(q.person(0), 0).unwrap();
        assert_eq!(qw.dim(), (251, 330));
        let got = db.nearest(qw.view()).unwrap();
        for (i, row) in qw.outer_iter().enumerate() {
            let row = row.to_vec();
            let (mut bi, mut bd) = (0, f64::INFINITY);
            for (j, w) in words.iter().enumerate() {
                let d: f64 = w.iter().zip(&row).map(|(x, y)| (x - y) * (x - y)).sum();
                if d < bd {
                    (bi, bd) = (j, d);
                }
            }
            assert_eq!(got[i].index, bi, "query {i}");
            assert!((got[i].dist2 - bd).abs() <= 1e-12 * bd.max(1.0));
        }
        // A word of the database is its own neighbour at distance 0.
        let own = db.sequence_words(a.person(1), 5).unwrap();
        let n = db.nearest(own.slice(s![..1, ..])).unwrap();
        assert_eq!(db.word_origin(n[0].index), ("random4", 1, 5));
        assert_eq!(n[0].dist2, 0.0);
    }

    #[test]
    fn bad_inputs_are_errors() {
        let scene = random_motion(50, 1, 8);
        let db = NdmsDatabase::build(&[&scene], &NdmsConfig::default()).unwrap();
        assert!(db.score_sequence(scene.person(0), 5).is_err()); // before the lead
        assert_eq!(db.score_sequence(scene.person(0).slice(s![..10, .., ..]), 10).unwrap().per_frame.len(), 1);
        let e = db.score_sequence(scene.person(0).slice(s![..9, .., ..]), 10).unwrap_err().to_string();
        assert!(e.contains("9 frames"), "{e}");
        let mut bad = scene.person(0).to_owned();
        bad[[20, 3, 1]] = f32::NAN;
        assert!(db.score_sequence(bad.view(), 10).unwrap_err().to_string().contains("frame 20, joint 3"));
        assert!(NdmsDatabase::build(&[], &NdmsConfig::default()).is_err());
        let short = NdmsConfig { word_length: Some(60), ..Default::default() };
        assert!(NdmsDatabase::build(&[&scene], &short).is_err());
        let other = Scene::new("p", 30.0, Skeleton::panoptic19(), Array4::zeros((20, 1, 19, 3))).unwrap();
        assert!(NdmsDatabase::build(&[&scene, &other], &NdmsConfig::default()).is_err());
    }

    /// MuPoTS: the test split against the test database scores 1 (each word finds itself);
    /// the train split is real motion of other people: strictly between 0 and 1.
    #[test]
    fn mupots_real_motion_levels() {
        let Some(ds) = mupots() else { return };
        let test: Vec<&Scene> = ds.split(crate::Split::Test).collect();
        let train: Vec<&Scene> = ds.split(crate::Split::Train).collect();
        let db = NdmsDatabase::build(&test, &NdmsConfig::default()).unwrap();
        println!("MuPoTS test database: {} words, {} skipped (degenerate)", db.num_words(), db.num_skipped_degenerate());
        let mut curves = Vec::new();
        for s in &test {
            curves.extend(db.score_scene(s, db.lead()).unwrap().curves);
        }
        let self_score = NdmsScore::from_curves(curves);
        let min = self_score.curves.iter().flat_map(|c| c.per_frame.iter()).fold(f64::INFINITY, |a, &b| a.min(b));
        println!("MuPoTS test vs test: mean {:.6}, min word {min:.6}", self_score.mean);
        assert_eq!((self_score.mean, min), (1.0, 1.0));
        let mut curves = Vec::new();
        for s in &train {
            curves.extend(db.score_scene(s, db.lead()).unwrap().curves);
        }
        let real = NdmsScore::from_curves(curves);
        println!("MuPoTS train vs test database (real motion level): NDMS {:.4}", real.mean);
        assert!(real.mean > 0.0 && real.mean < 1.0);
    }

    /// Benchmark: 8 samples × 3 persons × 1,800 forecast words against a 50k-word database.
    /// `cargo test --release -p socdiff-engine --lib metrics::ndms::tests::bench_ndms -- --ignored --nocapture`
    #[test]
    #[ignore]
    fn bench_ndms() {
        let db_scene = random_motion(50_009, 1, 10);
        let t0 = std::time::Instant::now();
        let db = NdmsDatabase::build(&[&db_scene], &NdmsConfig::default()).unwrap();
        let build = t0.elapsed().as_secs_f64();
        let q = random_motion(1_810, 3, 11);
        let f = Array5::from_shape_fn((8, 1_810, 3, 17, 3), |(k, fr, p, j, d)| q.positions[[fr, p, j, d]] + k as f32 * 0.001 * (j as f32 - 8.0));
        let t0 = std::time::Instant::now();
        let sc = db.score_forecasts(f.view(), 10).unwrap();
        let secs = t0.elapsed().as_secs_f64();
        println!(
            "NDMS bench: database {} words (build {build:.2} s); {} query words scored in {secs:.2} s on {} threads; mean {:.4}",
            db.num_words(),
            sc.curves.iter().map(|c| c.per_frame.len()).sum::<usize>(),
            rayon::current_num_threads(),
            sc.mean
        );
        // The same queries with plain gemm screening (no lower bounds).
        let mut queries = Vec::new();
        for k in 0..8 {
            for p in 0..3 {
                queries.extend(db.sequence_words(f.slice(s![k, .., p, .., ..]), 0).unwrap().iter().copied());
            }
        }
        let plain = crate::metrics::nn::ExactNn::build_with(db.num_words(), db.dim(), |i, o| db.word_into(i, o), crate::metrics::nn::Bounds::Never).unwrap();
        let cpu = || -> f64 {
            let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
            let f: Vec<&str> = s.rsplit(')').next().unwrap_or("").split_whitespace().collect();
            (f.get(11).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0) + f.get(12).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0)) / 100.0
        };
        let c0 = cpu();
        let t0 = std::time::Instant::now();
        let a = plain.search(&queries, None, |j, q| dist2(&db.word(j), q)).unwrap();
        let t_plain = t0.elapsed().as_secs_f64();
        let c1 = cpu();
        let t0 = std::time::Instant::now();
        let b = db.nearest_where(&queries, None).unwrap();
        let t_bounds = t0.elapsed().as_secs_f64();
        let c2 = cpu();
        println!("CPU seconds: plain {:.2}, bounds {:.2}", c1 - c0, c2 - c1);
        assert_eq!(a, b);
        println!("NN only: plain gemm {t_plain:.2} s, with lower bounds {t_bounds:.2} s");
    }
}
