//! Per-person pose features, anchoring, standardization and training windows (METHOD.md §2).
//!
//! # Body frame
//! For a pose with body-frame joints `L` (left, the left hip by default) and `R` (right), in
//! metres, z up:
//!
//! - root `r = ((L_x + R_x)/2, (L_y + R_y)/2)`: the joints' midpoint projected on the ground
//!   (z = 0);
//! - heading `h = atan2(R_y − L_y, R_x − L_x)`: the angle of the left→right axis in the ground
//!   plane; the facing direction is `h + 90°` (the person looks along `(−sin h, cos h)`);
//! - local joints `ℓ_j = Rz(−h)·(p_j − (r_x, r_y, 0))`: every joint relative to the root, rotated
//!   so that the axis L→R lies along +x (and the person faces +y); heights are kept.
//!
//! The axis is *degenerate* when `|R − L|` in the ground plane is below
//! [`MIN_HIP_DISTANCE`] (1 mm): on a valid frame that is an input error naming scene, person
//! and frame. On a frame the validity mask marks invalid, the heading of the person's nearest
//! valid non-degenerate frame is used instead (ties → the earlier frame; heading 0 if the
//! person has none) and the root is still the midpoint, so the round trip stays exact there.
//!
//! # Anchored feature vector (δ = 4 + 3J)
//! Each person gets an [`Anchor`] `(r_a, h_a)`: the body frame at the anchor frame (the last
//! observed frame). Per frame:
//!
//! ```text
//! x = [ Rz(−h_a)·(r − r_a) (2) | cos(h − h_a), sin(h − h_a) (2) | ℓ_1 … ℓ_J (3J) ]
//! ```
//!
//! The local joints do not depend on the anchor. With [`Anchor::IDENTITY`] the features are in
//! world coordinates. Translating a scene in the ground plane, or rotating it about any vertical
//! axis, leaves anchored features unchanged.
//!
//! # Residual pose encoding
//! With [`PoseEncoding::Residual`] the local joints are stored as offsets from the person's own
//! local joints at the anchor frame, `ℓ_j(t) − ℓ_j(a)` (the root dims are anchored already), and
//! [`PoseFeatures::offsets`] keeps `ℓ_j(a)` for the inverse. Standing still is then the zero
//! signal and a body's proportions are added back rather than predicted, so a network trained on
//! few bodies is not pulled towards them. [`PoseEncoding::Absolute`] (the paper) keeps `ℓ_j`.
//!
//! # Inverse
//! `h = atan2(x_3, x_2) + h_a` (so a non-unit `(cos, sin)` pair — e.g. a network output — is
//! normalized), `r = r_a + Rz(h_a)·(x_0, x_1)`, `p_j = (r_x, r_y, 0) + Rz(h)·ℓ_j`. Math is f64,
//! storage f32; the round trip is below 1e-5 m for every non-degenerate pose.
//!
//! # Standardization
//! [`Standardization`] z-scores *every* dimension (unlike the reference, which leaves the root
//! raw): per-dim mean and population std over every window, person and frame of the training
//! windows, in the anchored representation. A dim whose std is below [`STD_FLOOR`] (1e-6) gets
//! std 1, so it is only centred (e.g. a joint height that never changes). A run's `min_std`
//! raises the other small stds to it ([`Standardization::with_min_std`]).
//!
//! # Training windows and validity
//! [`training_windows`] cuts every sequence into windows of `length` frames at `stride`. A
//! window only contains persons that are valid on *every* one of its frames; short gaps should
//! be closed first with [`fill_short_gaps`] (linear interpolation of gaps of at most `max_gap`
//! frames between two valid frames, [`DEFAULT_MAX_GAP`] = 10 frames by default), longer gaps
//! and gaps at either end of a sequence stay invalid. With `persons = None` a window holds all
//! persons of its scene and is dropped if any of them is invalid somewhere in it; with
//! `Some((min, max))` it yields every subset of min..=max of the fully valid persons.

pub use crate::data::body::{body_frame, ground_midpoint, hip_distance, Anchor, MIN_HIP_DISTANCE};
use crate::data::body::{degenerate_error, fallback_headings, pose_of};
use crate::data::Scene;
use crate::{bail, Error, Result};
use ndarray::{Array2, Array3, Array4, ArrayBase, ArrayView, Axis, Data, DataMut, Dimension};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::ops::Range;
use std::path::Path;

/// Number of leading non-joint dims: root x, root y, cos h, sin h.
pub const ROOT_DIMS: usize = 4;

/// Standard deviations below this get replaced by 1 (the dim is only centred).
pub const STD_FLOOR: f64 = 1e-6;

/// Default longest gap (frames) that [`fill_short_gaps`] interpolates.
pub const DEFAULT_MAX_GAP: usize = 10;

/// Feature dimension δ = 4 + 3J for a skeleton of `joints` joints.
pub fn feature_dim(joints: usize) -> usize {
    ROOT_DIMS + 3 * joints
}

/// Number of joints J for a feature dimension δ = 4 + 3J, or an error if δ has no such form.
pub fn joints_of_dim(dim: usize) -> Result<usize> {
    let joints = dim.saturating_sub(ROOT_DIMS) / 3;
    if joints == 0 || feature_dim(joints) != dim {
        bail!("feature dimension {dim} is not 4 + 3·joints with at least one joint");
    }
    Ok(joints)
}

/// What the local joints of a feature vector are measured from (module docs; the config field `pose`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum PoseEncoding {
    /// `ℓ_j` as they are (the paper).
    #[default]
    Absolute,
    /// `ℓ_j(t) − ℓ_j(anchor frame)`: offsets from the person's pose at the anchor frame.
    Residual,
}

impl PoseEncoding {
    /// Parses `absolute` or `residual`.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "absolute" => Ok(PoseEncoding::Absolute),
            "residual" => Ok(PoseEncoding::Residual),
            _ => bail!("unknown pose encoding {s:?} (absolute or residual)"),
        }
    }
}

/// Encodes one pose with body frame `body` (usually [`Anchor::of_pose`]) relative to `anchor`.
///
/// # Shapes
/// - `pose`: `[J · 3]`; `out`: `[4 + 3J]`.
///
/// # Panics
/// If the lengths do not match.
pub fn encode_frame(pose: &[f32], body: &Anchor, anchor: &Anchor, out: &mut [f32]) {
    assert!(pose.len() / 3 * 3 == pose.len() && out.len() == ROOT_DIMS + pose.len(), "encode_frame: pose {} / out {}", pose.len(), out.len());
    let (sa, ca) = anchor.heading.sin_cos();
    let (rx, ry) = (body.root[0] - anchor.root[0], body.root[1] - anchor.root[1]);
    out[0] = (ca * rx + sa * ry) as f32;
    out[1] = (-sa * rx + ca * ry) as f32;
    let (sr, cr) = (body.heading - anchor.heading).sin_cos();
    out[2] = cr as f32;
    out[3] = sr as f32;
    body.localize(pose, &mut out[ROOT_DIMS..]);
}

/// Decodes one feature vector anchored at `anchor` back to world joints; returns the decoded
/// body frame. `(cos, sin)` need not be unit: the heading is `atan2(sin, cos)` (0 for (0, 0)).
///
/// # Shapes
/// - `features`: `[4 + 3J]`; `out`: `[J · 3]`.
///
/// # Panics
/// If the lengths do not match.
pub fn decode_frame(features: &[f32], anchor: &Anchor, out: &mut [f32]) -> Anchor {
    assert!(out.len() / 3 * 3 == out.len() && features.len() == ROOT_DIMS + out.len(), "decode_frame: features {} / out {}", features.len(), out.len());
    let (sa, ca) = anchor.heading.sin_cos();
    let (x, y) = (features[0] as f64, features[1] as f64);
    let root = [anchor.root[0] + ca * x - sa * y, anchor.root[1] + sa * x + ca * y];
    let heading = (features[3] as f64).atan2(features[2] as f64) + anchor.heading;
    let (s, c) = heading.sin_cos();
    for (l, o) in features[ROOT_DIMS..].chunks_exact(3).zip(out.chunks_exact_mut(3)) {
        let (lx, ly) = (l[0] as f64, l[1] as f64);
        o[0] = (root[0] + c * lx - s * ly) as f32;
        o[1] = (root[1] + s * lx + c * ly) as f32;
        o[2] = l[2];
    }
    Anchor { root, heading }
}

/// Anchored pose features of several persons over a range of frames.
///
/// # Shapes
/// - `data`: `[frames, persons, δ]`, δ = 4 + 3J (layout in the module docs).
/// - `anchors`: `[persons]`.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseFeatures {
    /// Features `[frames, persons, δ]`.
    pub data: Array3<f32>,
    /// Each person's anchor (world frame).
    pub anchors: Vec<Anchor>,
    /// [`PoseEncoding::Residual`]: each person's local joints at the anchor frame, which the
    /// local dims of `data` are relative to, `[persons, 3J]`; `None` for absolute features.
    pub offsets: Option<Array2<f32>>,
}

impl PoseFeatures {
    /// Wraps features and anchors, checking that they fit together.
    ///
    /// # Shapes
    /// - `data`: `[frames, persons, δ]`; `anchors`: `[persons]`.
    pub fn new(data: Array3<f32>, anchors: Vec<Anchor>) -> Result<Self> {
        let (_, p, d) = data.dim();
        joints_of_dim(d)?;
        if anchors.len() != p {
            bail!("pose features: {} anchors for {p} persons", anchors.len());
        }
        Ok(Self { data, anchors, offsets: None })
    }

    /// [`PoseFeatures::new`] for features in `encoding`: residual features need the local
    /// joints they are relative to, `offsets: [persons, 3J]`.
    pub fn with_encoding(data: Array3<f32>, anchors: Vec<Anchor>, offsets: Option<Array2<f32>>) -> Result<Self> {
        let mut f = Self::new(data, anchors)?;
        if let Some(o) = &offsets {
            if o.dim() != (f.num_persons(), f.dim() - ROOT_DIMS) {
                bail!("pose features: offsets of shape {:?} for {} persons of {} local dims", o.dim(), f.num_persons(), f.dim() - ROOT_DIMS);
            }
        }
        f.offsets = offsets;
        Ok(f)
    }

    /// Features of every frame and person of `scene`, each person anchored at its body frame
    /// at `anchor_frame` (see [`body_frame`] for invalid frames).
    ///
    /// # Shapes
    /// - output `data`: `[scene frames, scene persons, 4 + 3J]`.
    pub fn from_scene(scene: &Scene, anchor_frame: usize) -> Result<Self> {
        let persons: Vec<usize> = (0..scene.num_persons()).collect();
        Self::encode(scene, 0..scene.num_frames(), &persons, anchor_frame)
    }

    /// Features of frames `frames` of the given `persons` (in that order) of `scene`, each
    /// person anchored at its body frame at scene frame `anchor_frame` (any frame of the scene).
    ///
    /// # Shapes
    /// - output `data`: `[frames.len(), persons.len(), 4 + 3J]`.
    pub fn encode(scene: &Scene, frames: Range<usize>, persons: &[usize], anchor_frame: usize) -> Result<Self> {
        Self::encode_as(scene, frames, persons, anchor_frame, PoseEncoding::Absolute)
    }

    /// [`PoseFeatures::encode`] in the given encoding (residual: local joints relative to those
    /// at `anchor_frame`, which need not lie in `frames`).
    pub fn encode_as(scene: &Scene, frames: Range<usize>, persons: &[usize], anchor_frame: usize, encoding: PoseEncoding) -> Result<Self> {
        let nf = scene.num_frames();
        if frames.start >= frames.end || frames.end > nf {
            bail!("scene {}: frame range {}..{} is not a non-empty part of 0..{nf}", scene.name, frames.start, frames.end);
        }
        if anchor_frame >= nf {
            bail!("scene {}: anchor frame {anchor_frame} is outside 0..{nf}", scene.name);
        }
        if persons.is_empty() {
            bail!("scene {}: no persons to encode", scene.name);
        }
        if let Some(&p) = persons.iter().find(|&&p| p >= scene.num_persons()) {
            bail!("scene {}: person {p} out of range (scene has {} persons)", scene.name, scene.num_persons());
        }
        let anchors = persons.iter().map(|&p| body_frame(scene, anchor_frame, p)).collect::<Result<Vec<_>>>()?;
        let pos = scene.positions.as_standard_layout();
        let pos = pos.as_slice().expect("standard layout");
        let dim = feature_dim(scene.num_joints());
        let (l, r) = (scene.skeleton.left, scene.skeleton.right);
        let mut data = Array3::<f32>::zeros((frames.len(), persons.len(), dim));
        let out = data.as_slice_mut().expect("fresh array");
        let mut fallback: Vec<Option<Vec<f64>>> = vec![None; persons.len()];
        for (fi, f) in frames.enumerate() {
            for (pi, &p) in persons.iter().enumerate() {
                let pose = pose_of(pos, scene, f, p);
                let body = match Anchor::of_pose(pose, l, r) {
                    Some(a) => a,
                    None if scene.is_valid(f, p) => return Err(degenerate_error(scene, p, f, pose)),
                    None => {
                        let table = fallback[pi].get_or_insert_with(|| fallback_headings(scene, pos, p));
                        Anchor { root: ground_midpoint(pose, l, r), heading: table[f] }
                    }
                };
                encode_frame(pose, &body, &anchors[pi], &mut out[(fi * persons.len() + pi) * dim..][..dim]);
            }
        }
        let offsets = match encoding {
            PoseEncoding::Absolute => None,
            PoseEncoding::Residual => {
                let mut offsets = Array2::<f32>::zeros((persons.len(), dim - ROOT_DIMS));
                let mut row = vec![0.0f32; dim];
                for (pi, &p) in persons.iter().enumerate() {
                    encode_frame(pose_of(pos, scene, anchor_frame, p), &anchors[pi], &anchors[pi], &mut row);
                    offsets.row_mut(pi).iter_mut().zip(&row[ROOT_DIMS..]).for_each(|(o, &v)| *o = v);
                }
                shift_local_dims(&mut data, &offsets, -1.0);
                Some(offsets)
            }
        };
        Ok(Self { data, anchors, offsets })
    }

    /// The encoding of these features.
    pub fn encoding(&self) -> PoseEncoding {
        if self.offsets.is_some() {
            PoseEncoding::Residual
        } else {
            PoseEncoding::Absolute
        }
    }

    /// Number of frames.
    pub fn num_frames(&self) -> usize {
        self.data.dim().0
    }

    /// Number of persons.
    pub fn num_persons(&self) -> usize {
        self.data.dim().1
    }

    /// Feature dimension δ.
    pub fn dim(&self) -> usize {
        self.data.dim().2
    }

    /// World joint positions (the inverse of [`PoseFeatures::encode`]). Non-finite features
    /// are an error naming frame, person and dim.
    ///
    /// # Shapes
    /// - output: `[frames, persons, J, 3]`, J = (δ − 4)/3.
    pub fn to_positions(&self) -> Result<Array4<f32>> {
        let (nf, np, dim) = self.data.dim();
        let nj = joints_of_dim(dim)?;
        if self.anchors.len() != np {
            bail!("pose features: {} anchors for {np} persons", self.anchors.len());
        }
        let mut data = self.data.as_standard_layout().into_owned();
        if let Some(offsets) = &self.offsets {
            shift_local_dims(&mut data, offsets, 1.0);
        }
        let data = data.as_slice().expect("standard layout");
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            bail!("pose features: non-finite value {} at frame {}, person {}, dim {}", data[i], i / (np * dim), (i / dim) % np, i % dim);
        }
        let mut out = Array4::<f32>::zeros((nf, np, nj, 3));
        let o = out.as_slice_mut().expect("fresh array");
        for (i, (x, y)) in data.chunks_exact(dim).zip(o.chunks_exact_mut(3 * nj)).enumerate() {
            decode_frame(x, &self.anchors[i % np], y);
        }
        Ok(out)
    }
}

/// Adds `sign ×` each person's offsets to the local dims of every frame.
///
/// # Shapes
/// - `data`: `[frames, persons, 4 + 3J]`; `offsets`: `[persons, 3J]`.
fn shift_local_dims(data: &mut Array3<f32>, offsets: &Array2<f32>, sign: f32) {
    for mut frame in data.outer_iter_mut() {
        for (mut x, o) in frame.outer_iter_mut().zip(offsets.outer_iter()) {
            x.slice_mut(ndarray::s![ROOT_DIMS..]).zip_mut_with(&o, |v, &a| *v += sign * a);
        }
    }
}

/// Per-dim standardization `x ↦ (x − mean) / std` over the last axis.
///
/// # Shapes
/// - `mean`, `std`: `[δ]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Standardization {
    /// Per-dim mean.
    pub mean: Vec<f32>,
    /// Per-dim population std (1 where it was below [`STD_FLOOR`]).
    pub std: Vec<f32>,
}

/// Shifted first and second moments, mergeable.
#[derive(Clone, Debug)]
struct Moments {
    n: u64,
    shift: Vec<f64>,
    sum: Vec<f64>,
    sum2: Vec<f64>,
}

impl Moments {
    fn new(dim: usize) -> Self {
        Self { n: 0, shift: vec![0.0; dim], sum: vec![0.0; dim], sum2: vec![0.0; dim] }
    }

    fn add(&mut self, row: &[f32]) {
        if self.n == 0 {
            for (k, &v) in self.shift.iter_mut().zip(row) {
                *k = v as f64;
            }
        }
        self.n += 1;
        for (((s, s2), k), &v) in self.sum.iter_mut().zip(&mut self.sum2).zip(&self.shift).zip(row) {
            let d = v as f64 - k;
            *s += d;
            *s2 += d * d;
        }
    }

    fn merge(mut self, other: Moments) -> Moments {
        if other.n == 0 {
            return self;
        }
        if self.n == 0 {
            return other;
        }
        let nb = other.n as f64;
        for i in 0..self.sum.len() {
            let dk = other.shift[i] - self.shift[i];
            self.sum2[i] += other.sum2[i] + 2.0 * dk * other.sum[i] + nb * dk * dk;
            self.sum[i] += other.sum[i] + nb * dk;
        }
        self.n += other.n;
        self
    }

    fn finish(&self) -> Result<Standardization> {
        if self.n == 0 {
            bail!("standardization: no data to fit");
        }
        let n = self.n as f64;
        let (mut mean, mut std) = (Vec::new(), Vec::new());
        for i in 0..self.sum.len() {
            let m = self.sum[i] / n;
            let sd = (self.sum2[i] / n - m * m).max(0.0).sqrt();
            mean.push((self.shift[i] + m) as f32);
            std.push(if sd < STD_FLOOR { 1.0 } else { sd as f32 });
        }
        Ok(Standardization { mean, std })
    }
}

/// Calls `f` on every row (last-axis lane) of `x`.
fn for_each_row<S: Data<Elem = f32>, D: Dimension>(x: &ArrayBase<S, D>, mut f: impl FnMut(&[f32])) {
    let last = Axis(x.ndim() - 1);
    let dim = x.len_of(last);
    if let Some(s) = x.as_slice() {
        s.chunks_exact(dim).for_each(f);
    } else {
        let mut buf = vec![0.0; dim];
        for lane in x.lanes(last) {
            for (b, &v) in buf.iter_mut().zip(lane.iter()) {
                *b = v;
            }
            f(&buf);
        }
    }
}

impl Standardization {
    /// Mean 0, std 1 for every dim.
    pub fn identity(dim: usize) -> Self {
        Self { mean: vec![0.0; dim], std: vec![1.0; dim] }
    }

    /// Raises every std below `floor` to `floor` (a std of 1, from a dim that never changed,
    /// stays for `floor` ≤ 1): dims scaled as if they moved at least that much.
    pub fn with_min_std(mut self, floor: f64) -> Self {
        for s in &mut self.std {
            *s = s.max(floor as f32);
        }
        self
    }

    /// Feature dimension δ.
    pub fn dim(&self) -> usize {
        self.mean.len()
    }

    /// Fits per-dim mean and population std over every row of every array (e.g. every window,
    /// person and frame). Stds below [`STD_FLOOR`] become 1.
    ///
    /// # Shapes
    /// - each array: `[.., δ]`, same δ for all.
    pub fn fit<'a, D, I>(arrays: I) -> Result<Self>
    where
        D: Dimension + 'a,
        I: IntoIterator<Item = ArrayView<'a, f32, D>>,
    {
        let mut m: Option<Moments> = None;
        for x in arrays {
            if x.ndim() == 0 {
                bail!("standardization: cannot fit a 0-dimensional array");
            }
            let dim = x.len_of(Axis(x.ndim() - 1));
            let acc = m.get_or_insert_with(|| Moments::new(dim));
            if acc.sum.len() != dim {
                bail!("standardization: arrays with last dimension {} and {dim}", acc.sum.len());
            }
            if dim > 0 {
                for_each_row(&x, |row| acc.add(row));
            }
        }
        match m {
            Some(m) => m.finish(),
            None => bail!("standardization: no data to fit"),
        }
    }

    /// Fits over the anchored features of training windows (see [`window_features`]),
    /// streaming them in parallel; same statistics as [`Standardization::fit`] on the windows.
    pub fn fit_windows(scenes: &[Scene], windows: &[Window], anchor_offset: usize, encoding: PoseEncoding) -> Result<Self> {
        if windows.is_empty() {
            bail!("standardization: no windows to fit");
        }
        let dims: Vec<usize> = windows.iter().map(|w| scenes.get(w.scene).map_or(0, |s| feature_dim(s.num_joints()))).collect();
        let dim = dims[0];
        if let Some(i) = dims.iter().position(|&d| d != dim) {
            bail!("standardization: window {i} has feature dimension {} but window 0 has {dim} (different skeletons)", dims[i]);
        }
        let m = windows
            .par_iter()
            .try_fold(
                || Moments::new(dim),
                |mut acc, w| -> Result<Moments> {
                    let scene = scenes.get(w.scene).ok_or_else(|| Error::invalid(format!("window refers to scene {} of {}", w.scene, scenes.len())))?;
                    let x = window_features(scene, w, anchor_offset, encoding)?;
                    for_each_row(&x, |row| acc.add(row));
                    Ok(acc)
                },
            )
            .try_reduce(|| Moments::new(dim), |a, b| Ok(a.merge(b)))?;
        m.finish()
    }

    fn check<S: Data<Elem = f32>, D: Dimension>(&self, x: &ArrayBase<S, D>) -> Result<()> {
        if self.std.len() != self.mean.len() {
            bail!("standardization: {} means but {} stds", self.mean.len(), self.std.len());
        }
        let last = if x.ndim() == 0 { None } else { Some(x.len_of(Axis(x.ndim() - 1))) };
        if last != Some(self.dim()) {
            bail!("standardization of dimension {} applied to an array of shape {:?}", self.dim(), x.shape());
        }
        Ok(())
    }

    fn map_rows<S: DataMut<Elem = f32>, D: Dimension>(&self, x: &mut ArrayBase<S, D>, f: impl Fn(f64, f64, f64) -> f64) -> Result<()> {
        self.check(x)?;
        let row = |r: &mut [f32]| {
            for ((v, &m), &s) in r.iter_mut().zip(&self.mean).zip(&self.std) {
                *v = f(*v as f64, m as f64, s as f64) as f32;
            }
        };
        let last = Axis(x.ndim() - 1);
        if let Some(s) = x.as_slice_mut() {
            s.chunks_exact_mut(self.dim().max(1)).for_each(row);
        } else {
            for mut lane in x.lanes_mut(last) {
                for ((v, &m), &s) in lane.iter_mut().zip(&self.mean).zip(&self.std) {
                    *v = f(*v as f64, m as f64, s as f64) as f32;
                }
            }
        }
        Ok(())
    }

    /// In place `x ↦ (x − mean) / std` along the last axis.
    ///
    /// # Shapes
    /// - `x`: `[.., δ]`.
    pub fn apply<S: DataMut<Elem = f32>, D: Dimension>(&self, x: &mut ArrayBase<S, D>) -> Result<()> {
        self.map_rows(x, |v, m, s| (v - m) / s)
    }

    /// In place `x ↦ x · std + mean` along the last axis (inverse of [`Standardization::apply`]).
    ///
    /// # Shapes
    /// - `x`: `[.., δ]`.
    pub fn invert<S: DataMut<Elem = f32>, D: Dimension>(&self, x: &mut ArrayBase<S, D>) -> Result<()> {
        self.map_rows(x, |v, m, s| v * s + m)
    }

    /// Writes `{"mean": [...], "std": [...]}` to `path`.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let text = serde_json::to_string_pretty(self).map_err(|e| Error::format(path, e.to_string()))?;
        std::fs::write(path, text).map_err(|e| Error::io(path, e))
    }

    /// Reads a file written by [`Standardization::save`]; its dimension must be `dim`, every
    /// value finite and every std positive, otherwise an error names the file.
    pub fn load(path: impl AsRef<Path>, dim: usize) -> Result<Self> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let s: Self = serde_json::from_str(&text).map_err(|e| Error::format(path, format!("not a standardization file: {e}")))?;
        if s.mean.len() != dim || s.std.len() != dim {
            return Err(Error::format(path, format!("standardization has {} means and {} stds, expected feature dimension {dim}", s.mean.len(), s.std.len())));
        }
        if let Some(i) = (0..dim).find(|&i| !(s.mean[i].is_finite() && s.std[i].is_finite() && s.std[i] > 0.0)) {
            return Err(Error::format(path, format!("dim {i}: mean {} / std {} (need finite values and std > 0)", s.mean[i], s.std[i])));
        }
        Ok(s)
    }
}

/// One training window: `length` frames from `start` of scene `scene`, for `persons` (indices
/// into the scene, ascending).
#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Window {
    /// Index of the scene in the slice given to [`training_windows`].
    pub scene: usize,
    /// First frame.
    pub start: usize,
    /// Number of frames.
    pub length: usize,
    /// Persons of the window.
    pub persons: Vec<usize>,
}

impl Window {
    /// Frames of the window, `start..start + length`.
    pub fn frames(&self) -> Range<usize> {
        self.start..self.start + self.length
    }
}

/// Linearly interpolates, per person, every run of invalid frames of at most `max_gap` frames
/// that has a valid frame on both sides, and marks it valid. Longer gaps, gaps at either end
/// of the sequence, and gaps whose interpolation would make the hip axis degenerate (a person
/// turning about 180° inside the gap) stay as they are. Signals are not touched. When anything
/// was filled, `metadata["filled_gap_entries"]` holds the number of (frame, person) entries.
pub fn fill_short_gaps(scene: &Scene, max_gap: usize) -> Scene {
    let mut out = scene.clone();
    let Some(valid) = out.valid.as_mut() else { return out };
    let (nf, np) = valid.dim();
    let nj = scene.num_joints();
    let (l, r) = (scene.skeleton.left, scene.skeleton.right);
    let mut filled = 0usize;
    let mut buf = vec![0f32; nj * 3];
    for p in 0..np {
        let mut f = 0;
        while f < nf {
            if valid[[f, p]] {
                f += 1;
                continue;
            }
            let start = f;
            while f < nf && !valid[[f, p]] {
                f += 1;
            }
            let end = f;
            if start == 0 || end == nf || end - start > max_gap {
                continue;
            }
            let (a, b) = (start - 1, end);
            let mut gap = Vec::with_capacity((end - start) * nj * 3);
            let mut ok = true;
            for g in start..end {
                let w = (g - a) as f64 / (b - a) as f64;
                for j in 0..nj {
                    for k in 0..3 {
                        let (pa, pb) = (scene.positions[[a, p, j, k]] as f64, scene.positions[[b, p, j, k]] as f64);
                        buf[3 * j + k] = ((1.0 - w) * pa + w * pb) as f32;
                    }
                }
                ok &= Anchor::of_pose(&buf, l, r).is_some();
                gap.extend_from_slice(&buf);
            }
            if !ok {
                continue;
            }
            for (g, pose) in (start..end).zip(gap.chunks_exact(nj * 3)) {
                for j in 0..nj {
                    for k in 0..3 {
                        out.positions[[g, p, j, k]] = pose[3 * j + k];
                    }
                }
                valid[[g, p]] = true;
            }
            filled += end - start;
        }
    }
    if filled > 0 {
        out.metadata.insert("filled_gap_entries".into(), serde_json::Value::from(filled));
    }
    out
}

/// Cuts every scene into windows of `length` frames starting at `0, stride, 2·stride, …`
/// (while the window fits). Only persons valid on every frame of a window take part in it:
/// with `persons = None` a window holds all persons of its scene and is dropped if any of them
/// is invalid somewhere in it; with `Some((min, max))` every subset (ascending indices) of
/// `min..=max` fully valid persons is a window — C(n, k) summed over k, so keep `max` small for
/// crowded scenes. Scenes shorter than `length` give no windows. Order: scene, start, subset
/// size, then lexicographic. Run [`fill_short_gaps`] first to keep windows with short gaps.
///
/// Errors: `length` or `stride` 0, no scenes, `min` 0 or `min > max`, or a `length` longer
/// than every sequence.
pub fn training_windows(scenes: &[Scene], length: usize, stride: usize, persons: Option<(usize, usize)>) -> Result<Vec<Window>> {
    if length == 0 {
        bail!("training windows: length must be at least 1 frame");
    }
    if stride == 0 {
        bail!("training windows: stride must be at least 1 frame");
    }
    if let Some((lo, hi)) = persons {
        if lo == 0 || lo > hi {
            bail!("training windows: person count range {lo}..={hi} must satisfy 1 ≤ min ≤ max");
        }
    }
    let Some(longest) = scenes.iter().max_by_key(|s| s.num_frames()) else {
        bail!("training windows: no scenes");
    };
    if longest.num_frames() < length {
        bail!("training windows: a window of {length} frames is longer than every sequence (longest: {} with {} frames)", longest.name, longest.num_frames());
    }
    let mut out = Vec::new();
    for (si, s) in scenes.iter().enumerate() {
        let (nf, np) = (s.num_frames(), s.num_persons());
        if nf < length {
            continue;
        }
        // invalid[p][f] = number of invalid frames of person p before frame f.
        let invalid: Vec<Vec<u32>> = (0..np)
            .map(|p| {
                let mut c = vec![0u32; nf + 1];
                for f in 0..nf {
                    c[f + 1] = c[f] + u32::from(!s.is_valid(f, p));
                }
                c
            })
            .collect();
        for start in (0..=nf - length).step_by(stride) {
            let ok: Vec<usize> = (0..np).filter(|&p| invalid[p][start + length] == invalid[p][start]).collect();
            match persons {
                None => {
                    if ok.len() == np {
                        out.push(Window { scene: si, start, length, persons: ok });
                    }
                }
                Some((lo, hi)) => {
                    for k in lo..=hi.min(ok.len()) {
                        for_each_combination(ok.len(), k, |idx| {
                            out.push(Window { scene: si, start, length, persons: idx.iter().map(|&i| ok[i]).collect() });
                        });
                    }
                }
            }
        }
    }
    Ok(out)
}

/// Calls `f` with every k-subset of `0..n` in lexicographic order.
fn for_each_combination(n: usize, k: usize, mut f: impl FnMut(&[usize])) {
    if k > n {
        return;
    }
    let mut idx: Vec<usize> = (0..k).collect();
    loop {
        f(&idx);
        let Some(i) = (0..k).rev().find(|&i| idx[i] < n - k + i) else { return };
        idx[i] += 1;
        for j in i + 1..k {
            idx[j] = idx[j - 1] + 1;
        }
    }
}

/// Anchored features of one window, every person anchored at frame `start + anchor_offset`
/// (e.g. the last observed frame of the window).
///
/// # Shapes
/// - output: `[window.length, window.persons.len(), 4 + 3J]`.
pub fn window_features(scene: &Scene, window: &Window, anchor_offset: usize, encoding: PoseEncoding) -> Result<Array3<f32>> {
    if anchor_offset >= window.length {
        bail!("scene {}: anchor offset {anchor_offset} is outside a window of {} frames", scene.name, window.length);
    }
    Ok(PoseFeatures::encode_as(scene, window.frames(), &window.persons, window.start + anchor_offset, encoding)?.data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::Skeleton;
    use ndarray::{s, Array2};
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};
    use std::f64::consts::PI;

    /// Random non-degenerate poses: mupots17, roots within ±2 m, hips 0.15–0.35 m apart.
    fn random_scene(rng: &mut StdRng, frames: usize, persons: usize) -> Scene {
        let sk = Skeleton::mupots17();
        let mut pos = Array4::<f32>::zeros((frames, persons, 17, 3));
        for f in 0..frames {
            for p in 0..persons {
                let (cx, cy) = (rng.gen_range(-2.0..2.0), rng.gen_range(-2.0..2.0));
                let h: f64 = rng.gen_range(-PI..PI);
                let w: f64 = rng.gen_range(0.075..0.175);
                for j in 0..17 {
                    pos[[f, p, j, 0]] = (cx + rng.gen_range(-0.8..0.8)) as f32;
                    pos[[f, p, j, 1]] = (cy + rng.gen_range(-0.8..0.8)) as f32;
                    pos[[f, p, j, 2]] = rng.gen_range(0.0..1.9);
                }
                for (j, sign) in [(sk.left, -1.0), (sk.right, 1.0)] {
                    pos[[f, p, j, 0]] = (cx + sign * w * h.cos()) as f32;
                    pos[[f, p, j, 1]] = (cy + sign * w * h.sin()) as f32;
                }
            }
        }
        Scene::new("rand", 30.0, sk, pos).unwrap()
    }

    fn max_abs_diff<D: Dimension>(a: &ndarray::Array<f32, D>, b: &ndarray::Array<f32, D>) -> f64 {
        assert_eq!(a.shape(), b.shape());
        a.iter().zip(b.iter()).map(|(x, y)| (*x as f64 - *y as f64).abs()).fold(0.0, f64::max)
    }

    /// Three-joint skeleton: left hip, right hip, head.
    fn tiny_skeleton() -> Skeleton {
        Skeleton::new("tiny", vec!["left_hip".into(), "right_hip".into(), "head".into()], vec![(0, 2), (1, 2)], 0, 1).unwrap()
    }

    #[test]
    fn known_values() {
        // L = (1, 0, 0.9), R = (1, −0.2, 0.9), head = (1.1, −0.1, 1.7).
        let pose = [1.0f32, 0.0, 0.9, 1.0, -0.2, 0.9, 1.1, -0.1, 1.7];
        let a = Anchor::of_pose(&pose, 0, 1).unwrap();
        assert!((a.root[0] - 1.0).abs() < 1e-7 && (a.root[1] + 0.1).abs() < 1e-7, "{a:?}");
        // axis L→R = (0, −0.2): heading −90°, facing 0 (+x); left hip on +y = the person's left.
        assert!((a.heading + PI / 2.0).abs() < 1e-12);
        assert!(a.facing().abs() < 1e-12);
        let mut x = [0f32; 13];
        encode_frame(&pose, &a, &Anchor::IDENTITY, &mut x);
        let world = x;
        let want = [1.0, -0.1, 0.0, -1.0, -0.1, 0.0, 0.9, 0.1, 0.0, 0.9, 0.0, 0.1, 1.7];
        for (i, (g, w)) in x.iter().zip(want).enumerate() {
            assert!((g - w).abs() < 1e-6, "dim {i}: {g} vs {w}");
        }
        // Anchored at root (0, 0), heading +90°: root' = Rz(−90°)(1, −0.1) = (−0.1, −1); h' = −180°.
        let anchor = Anchor { root: [0.0, 0.0], heading: PI / 2.0 };
        encode_frame(&pose, &a, &anchor, &mut x);
        let want_root = [-0.1, -1.0, -1.0, 0.0];
        for (i, (g, w)) in x[..4].iter().zip(want_root).enumerate() {
            assert!((g - w).abs() < 1e-6, "dim {i}: {g} vs {w}");
        }
        assert_eq!(&x[4..], &world[4..], "local joints do not depend on the anchor");
        // Anchored at itself: [0, 0, 1, 0].
        encode_frame(&pose, &a, &a, &mut x);
        assert_eq!(&x[..4], &[0.0, 0.0, 1.0, 0.0]);
        // Decode; a non-unit (cos, sin) is normalized.
        let mut y = [0f32; 9];
        x[2] *= 3.0;
        x[3] *= 3.0;
        let b = decode_frame(&x, &a, &mut y);
        assert!((b.heading - a.heading).abs() < 1e-12);
        for (g, w) in y.iter().zip(pose) {
            assert!((g - w).abs() < 1e-6);
        }
        assert_eq!(feature_dim(17), 55);
        assert_eq!(joints_of_dim(55).unwrap(), 17);
        assert!(joints_of_dim(56).is_err() && joints_of_dim(4).is_err());
    }

    /// Residual features: zero local dims at the anchor frame, each frame's local dims equal to
    /// the absolute ones minus the anchor frame's (an independent subtraction), an exact round
    /// trip, and an anchor outside the encoded frames.
    #[test]
    fn residual_encoding_is_offsets_from_the_anchor_pose_and_round_trips() {
        let mut rng = StdRng::seed_from_u64(11);
        let scene = random_scene(&mut rng, 30, 2);
        let persons = [1, 0];
        let abs = PoseFeatures::encode(&scene, 0..30, &persons, 12).unwrap();
        let res = PoseFeatures::encode_as(&scene, 0..30, &persons, 12, PoseEncoding::Residual).unwrap();
        assert_eq!((abs.encoding(), res.encoding()), (PoseEncoding::Absolute, PoseEncoding::Residual));
        for p in 0..2 {
            assert!(res.data.slice(s![12, p, ROOT_DIMS..]).iter().all(|&v| v == 0.0));
            for f in [0, 5, 29] {
                assert_eq!(res.data.slice(s![f, p, ..ROOT_DIMS]), abs.data.slice(s![f, p, ..ROOT_DIMS]));
                for d in ROOT_DIMS..abs.dim() {
                    let want = abs.data[[f, p, d]] - abs.data[[12, p, d]];
                    assert!((res.data[[f, p, d]] - want).abs() < 1e-6, "frame {f} person {p} dim {d}");
                }
            }
        }
        assert!(max_abs_diff(&res.to_positions().unwrap(), &abs.to_positions().unwrap()) < 1e-5);
        let part = PoseFeatures::encode_as(&scene, 20..30, &persons, 12, PoseEncoding::Residual).unwrap();
        assert_eq!(part.offsets, res.offsets);
        assert!(max_abs_diff(&part.to_positions().unwrap(), &scene.positions.slice(s![20..30, ..;-1, .., ..]).to_owned()) < 1e-5);
        let bad = PoseFeatures::with_encoding(res.data.clone(), res.anchors.clone(), Some(Array2::zeros((2, 3))));
        assert!(bad.unwrap_err().to_string().contains("offsets of shape"));
    }

    #[test]
    fn round_trip_random_poses() {
        let mut rng = StdRng::seed_from_u64(7);
        let scene = random_scene(&mut rng, 50, 3);
        let mut worst = 0.0f64;
        for anchor in [0, 17, 49] {
            let feats = PoseFeatures::from_scene(&scene, anchor).unwrap();
            assert_eq!(feats.data.dim(), (50, 3, 55));
            for p in 0..3 {
                assert_eq!(feats.data.slice(s![anchor, p, ..4]).to_vec(), vec![0.0, 0.0, 1.0, 0.0]);
            }
            let back = feats.to_positions().unwrap();
            worst = worst.max(max_abs_diff(&back, &scene.positions));
        }
        println!("random poses: max round-trip error {worst:.3e} m");
        assert!(worst < 1e-5, "round trip error {worst} m");
        // Non-unit (cos, sin) from a "network": scaling them changes nothing.
        let mut feats = PoseFeatures::from_scene(&scene, 10).unwrap();
        feats.data.slice_mut(s![.., .., 2..4]).mapv_inplace(|v| v * 0.37);
        assert!(max_abs_diff(&feats.to_positions().unwrap(), &scene.positions) < 1e-5);
        feats.data[[3, 1, 7]] = f32::NAN;
        let e = feats.to_positions().unwrap_err().to_string();
        assert!(e.contains("frame 3, person 1, dim 7"), "{e}");
    }

    #[test]
    fn invariant_to_ground_translation_and_rotation() {
        let mut rng = StdRng::seed_from_u64(11);
        let scene = random_scene(&mut rng, 30, 3);
        let base = PoseFeatures::from_scene(&scene, 19).unwrap();
        let (px, py) = (0.7, -0.4);
        let mut worst = 0.0f64;
        for theta in [0.0, 0.3, -1.2, 2.5, PI - 1e-4, -PI + 1e-4, PI] {
            let (s, c) = f64::sin_cos(theta);
            let (dx, dy) = (0.9, -1.3);
            // x ↦ Rz(θ)(x − p) + p + d
            let t = [px - (c * px - s * py) + dx, py - (s * px + c * py) + dy, 0.0];
            let mut moved = scene.clone();
            moved.transform([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], t);
            let f = PoseFeatures::from_scene(&moved, 19).unwrap();
            let d = max_abs_diff(&f.data, &base.data);
            assert!(d < 1e-5, "θ = {theta}: features changed by {d}");
            worst = worst.max(d);
            let back = f.to_positions().unwrap();
            assert!(max_abs_diff(&back, &moved.positions) < 1e-5);
        }
        println!("random scene: max change of anchored features {worst:.3e}");
        assert!(worst > 0.0, "the transforms should not be exact no-ops in f32");
    }

    #[test]
    fn degenerate_hip_axis() {
        let mut rng = StdRng::seed_from_u64(3);
        let mut scene = random_scene(&mut rng, 25, 2);
        scene.name = "TS3".into();
        let (l, r) = (scene.skeleton.left, scene.skeleton.right);
        // Person 1: frames 16, 17 and 20 degenerate (hips 0.4 mm apart in the ground plane,
        // different heights do not help).
        for f in [16, 17, 20] {
            for k in 0..2 {
                scene.positions[[f, 1, r, k]] = scene.positions[[f, 1, l, k]];
            }
            scene.positions[[f, 1, r, 0]] += 0.0004;
            scene.positions[[f, 1, r, 2]] += 0.3;
        }
        let e = PoseFeatures::from_scene(&scene, 5).unwrap_err().to_string();
        assert!(e.contains("scene TS3: person 1, frame 16: hip axis degenerate"), "{e}");
        assert!(e.contains("0.0004 m apart in the ground plane"), "{e}");
        let e = body_frame(&scene, 17, 1).unwrap_err().to_string();
        assert!(e.contains("scene TS3") && e.contains("person 1") && e.contains("frame 17"), "{e}");

        // Invalid there: frame 16 takes frame 15's heading (nearest), frame 17 frame 18's,
        // frame 20 the earlier of 19 and 21 (tie).
        let mut valid = Array2::from_elem((25, 2), true);
        for f in [16, 17, 20] {
            valid[[f, 1]] = false;
        }
        let scene = scene.with_valid(valid).unwrap();
        let feats = PoseFeatures::from_scene(&scene, 5).unwrap();
        let heading_at = |f: usize| body_frame(&scene, f, 1).unwrap().heading;
        for (f, src) in [(16, 15), (17, 18), (20, 19)] {
            assert_eq!(heading_at(f), heading_at(src), "frame {f}");
            // The encoded relative heading agrees with body_frame's fallback.
            let h = (feats.data[[f, 1, 3]] as f64).atan2(feats.data[[f, 1, 2]] as f64) + feats.anchors[1].heading;
            let d = (h - heading_at(src)).rem_euclid(2.0 * PI);
            assert!(d.min(2.0 * PI - d) < 1e-6, "frame {f}: {h} vs {}", heading_at(src));
        }
        assert_ne!(heading_at(15), heading_at(18));
        // The round trip stays exact on the invalid, degenerate frames.
        assert!(max_abs_diff(&feats.to_positions().unwrap(), &scene.positions) < 1e-5);
        // Anchoring at a degenerate invalid frame: that frame is [0, 0, 1, 0].
        let at17 = PoseFeatures::from_scene(&scene, 17).unwrap();
        assert_eq!(at17.data.slice(s![17, 1, ..4]).to_vec(), vec![0.0, 0.0, 1.0, 0.0]);
        assert!(max_abs_diff(&at17.to_positions().unwrap(), &scene.positions) < 1e-5);
    }

    #[test]
    fn degenerate_person_without_valid_frames_gets_heading_zero() {
        let pos = Array4::from_shape_fn((4, 1, 3, 3), |(_, _, j, k)| if k == 2 { j as f32 } else { 1.5 });
        let scene = Scene::new("flat", 30.0, tiny_skeleton(), pos).unwrap().with_valid(Array2::from_elem((4, 1), false)).unwrap();
        let a = body_frame(&scene, 2, 0).unwrap();
        assert_eq!(a, Anchor { root: [1.5, 1.5], heading: 0.0 });
        let f = PoseFeatures::from_scene(&scene, 0).unwrap();
        assert!(max_abs_diff(&f.to_positions().unwrap(), &scene.positions) < 1e-6);
    }

    #[test]
    fn standardization_known_values() {
        // dim 0: 1, 2, 3, 4 → mean 2.5, std √1.25; dim 1: constant 7 → std 1 (floor);
        // dim 2: 0, 0, 0, 4 → mean 1, std √3.
        let a = Array3::from_shape_vec((2, 1, 3), vec![1.0, 7.0, 0.0, 2.0, 7.0, 0.0]).unwrap();
        let b = Array2::from_shape_vec((2, 3), vec![3.0, 7.0, 0.0, 4.0, 7.0, 4.0]).unwrap();
        let b3 = b.clone().into_shape_with_order((1, 2, 3)).unwrap();
        let st = Standardization::fit([a.view(), b3.view()]).unwrap();
        assert_eq!(st.mean, vec![2.5, 7.0, 1.0]);
        assert!((st.std[0] - 1.25f32.sqrt()).abs() < 1e-6, "{:?}", st.std);
        assert_eq!(st.std[1], 1.0);
        assert!((st.std[2] - 3f32.sqrt()).abs() < 1e-6);
        // Large offset: shifted moments keep precision.
        let big = Array2::from_shape_fn((1000, 1), |(i, _)| 1.0e4 + (i % 2) as f32 * 0.015625);
        let sb = Standardization::fit([big.view()]).unwrap();
        assert_eq!(sb, Standardization { mean: vec![1.0e4 + 1.0 / 128.0], std: vec![1.0 / 128.0] });

        // apply then invert = identity, on a non-contiguous view too.
        let mut x = a.clone();
        st.apply(&mut x).unwrap();
        assert!((x[[0, 0, 0]] + 1.5 / 1.25f32.sqrt()).abs() < 1e-6);
        assert_eq!(x[[1, 0, 1]], 0.0);
        st.invert(&mut x).unwrap();
        assert!(max_abs_diff(&x, &a) < 1e-6);
        let mut t = b.t().to_owned().reversed_axes();
        let mut tv = t.view_mut();
        st.apply(&mut tv).unwrap();
        st.invert(&mut tv).unwrap();
        assert!(max_abs_diff(&t, &b) < 1e-6);
        assert!(st.apply(&mut Array2::<f32>::zeros((2, 4))).is_err());
        assert!(Standardization::fit(Vec::<ndarray::ArrayView2<f32>>::new()).is_err());
        assert!(Standardization::fit([a.view(), Array3::zeros((1, 1, 4)).view()]).is_err());

        // save/load round trip; dimension mismatch names the file.
        let path = std::env::temp_dir().join(format!("socdiff-features-std-{}.json", std::process::id()));
        st.save(&path).unwrap();
        assert_eq!(Standardization::load(&path, 3).unwrap(), st);
        let e = Standardization::load(&path, 55).unwrap_err().to_string();
        assert!(e.contains(&path.display().to_string()) && e.contains("expected feature dimension 55"), "{e}");
        std::fs::write(&path, r#"{"mean": [0, 0, 0], "std": [1, 0, 1]}"#).unwrap();
        let e = Standardization::load(&path, 3).unwrap_err().to_string();
        assert!(e.contains(&path.display().to_string()) && e.contains("dim 1"), "{e}");
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn fit_windows_matches_fit() {
        let mut rng = StdRng::seed_from_u64(5);
        let scenes = vec![random_scene(&mut rng, 40, 3), random_scene(&mut rng, 23, 2)];
        let windows = training_windows(&scenes, 16, 4, None).unwrap();
        assert_eq!(windows.len(), 7 + 2);
        let st = Standardization::fit_windows(&scenes, &windows, 9, PoseEncoding::Absolute).unwrap();
        let feats: Vec<Array3<f32>> = windows.iter().map(|w| window_features(&scenes[w.scene], w, 9, PoseEncoding::Absolute).unwrap()).collect();
        let reference = Standardization::fit(feats.iter().map(|x| x.view())).unwrap();
        assert_eq!(st.dim(), 55);
        assert_eq!((0..55).filter(|&i| st.std[i] == 1.0).collect::<Vec<_>>(), vec![29, 38]);
        for i in 0..55 {
            assert!((st.mean[i] - reference.mean[i]).abs() < 1e-5 && (st.std[i] - reference.std[i]).abs() < 1e-5, "dim {i}");
        }
        // Standardized data has mean 0 and std 1 in every dim except the two constant ones: the
        // local y of both hips is 0 by construction (dims 4 + 3·8 + 1 = 29 and 4 + 3·11 + 1 = 38),
        // their std is floored to 1 and they stay 0.
        let mut all =
            ndarray::concatenate(Axis(0), &feats.iter().map(|x| x.view().into_shape_with_order((x.len() / 55, 55)).unwrap()).collect::<Vec<_>>()).unwrap();
        st.apply(&mut all).unwrap();
        for i in 0..55 {
            let c = all.column(i);
            let m = c.iter().map(|&v| v as f64).sum::<f64>() / c.len() as f64;
            let v = c.iter().map(|&v| (v as f64 - m).powi(2)).sum::<f64>() / c.len() as f64;
            let want_std = if i == 29 || i == 38 { 0.0 } else { 1.0 };
            assert!(m.abs() < 1e-4 && (v.sqrt() - want_std).abs() < 1e-3, "dim {i}: mean {m}, std {}", v.sqrt());
        }
    }

    #[test]
    fn window_counts_and_errors() {
        let mut rng = StdRng::seed_from_u64(1);
        let scenes = vec![random_scene(&mut rng, 10, 3), random_scene(&mut rng, 25, 3), random_scene(&mut rng, 7, 2)];
        // 10 frames: start 0 → 1 window; 25 frames: 0, 5, 10, 15 → 4; 7 frames: none.
        let w = training_windows(&scenes, 8, 5, None).unwrap();
        assert_eq!(w.len(), 5);
        assert_eq!(w.iter().map(|w| (w.scene, w.start)).collect::<Vec<_>>(), vec![(0, 0), (1, 0), (1, 5), (1, 10), (1, 15)]);
        assert!(w.iter().all(|w| w.persons == vec![0, 1, 2] && w.length == 8));
        // Exact fit: 25 frames, length 25 → 1 window; stride 1 → 25 − 8 + 1 = 18 windows.
        assert_eq!(training_windows(&scenes[1..2], 25, 100, None).unwrap().len(), 1);
        assert_eq!(training_windows(&scenes[1..2], 8, 1, None).unwrap().len(), 18);
        // Person subsets of size 2..=3 of 3 persons: C(3,2) + C(3,3) = 4 per start; the 2-person
        // scene is too short anyway.
        let w = training_windows(&scenes, 8, 5, Some((2, 3))).unwrap();
        assert_eq!(w.len(), 5 * 4);
        assert_eq!(w[..4].iter().map(|w| w.persons.clone()).collect::<Vec<_>>(), vec![vec![0, 1], vec![0, 2], vec![1, 2], vec![0, 1, 2]]);
        assert_eq!(training_windows(&scenes, 7, 7, Some((1, 1))).unwrap().len(), 3 + 3 * 3 + 2);

        let err = |r: Result<Vec<Window>>| r.unwrap_err().to_string();
        assert!(err(training_windows(&scenes, 0, 5, None)).contains("length"));
        assert!(err(training_windows(&scenes, 8, 0, None)).contains("stride"));
        assert!(err(training_windows(&[], 8, 1, None)).contains("no scenes"));
        assert!(err(training_windows(&scenes, 8, 1, Some((0, 2)))).contains("min"));
        assert!(err(training_windows(&scenes, 8, 1, Some((3, 2)))).contains("min"));
        let e = err(training_windows(&scenes, 26, 1, None));
        assert!(e.contains("longer than every sequence") && e.contains("25 frames"), "{e}");

        // window_features: anchored at start + offset.
        let w = &training_windows(&scenes, 8, 5, None).unwrap()[2];
        let x = window_features(&scenes[1], w, 7, PoseEncoding::Absolute).unwrap();
        assert_eq!(x.dim(), (8, 3, 55));
        for p in 0..3 {
            assert_eq!(x.slice(s![7, p, ..4]).to_vec(), vec![0.0, 0.0, 1.0, 0.0]);
        }
        let full = PoseFeatures::from_scene(&scenes[1].slice_frames(5, 13).unwrap(), 7).unwrap();
        assert!(max_abs_diff(&x, &full.data) < 1e-6);
        assert!(window_features(&scenes[1], w, 8, PoseEncoding::Absolute).unwrap_err().to_string().contains("anchor offset 8"));
    }

    #[test]
    fn windows_with_invalid_frames() {
        let mut rng = StdRng::seed_from_u64(2);
        let scene = random_scene(&mut rng, 30, 3);
        let mut valid = Array2::from_elem((30, 3), true);
        for f in 12..15 {
            valid[[f, 1]] = false; // 3-frame gap of person 1
        }
        valid[[0, 2]] = false; // gap at the start of person 2: never filled
        let scene = scene.with_valid(valid).unwrap();
        // length 8, stride 2: starts 0, 2, …, 22 (12 windows). Person 1 is invalid in windows
        // starting at 6..=14 (5 windows), person 2 in the window starting at 0.
        let w = training_windows(std::slice::from_ref(&scene), 8, 2, None).unwrap();
        assert_eq!(w.iter().map(|w| w.start).collect::<Vec<_>>(), vec![2, 4, 16, 18, 20, 22]);
        let w = training_windows(std::slice::from_ref(&scene), 8, 2, Some((2, 3))).unwrap();
        let at = |start: usize| w.iter().filter(|x| x.start == start).map(|x| x.persons.clone()).collect::<Vec<_>>();
        assert_eq!(at(0), vec![vec![0, 1]]);
        assert_eq!(at(8), vec![vec![0, 2]]);
        assert_eq!(at(2).len(), 4);

        // Gaps of ≤ 2 frames are not enough; ≤ 3 fills person 1 linearly, not the start gap.
        assert_eq!(fill_short_gaps(&scene, 2), scene);
        let filled = fill_short_gaps(&scene, 3);
        assert_eq!(filled.metadata["filled_gap_entries"], 3);
        let v = filled.valid.as_ref().unwrap();
        assert!((12..15).all(|f| v[[f, 1]]) && !v[[0, 2]]);
        for (f, wgt) in [(12, 0.25f64), (13, 0.5), (14, 0.75)] {
            for j in [0, 8, 16] {
                for k in 0..3 {
                    let want = (1.0 - wgt) * scene.positions[[11, 1, j, k]] as f64 + wgt * scene.positions[[15, 1, j, k]] as f64;
                    assert!((filled.positions[[f, 1, j, k]] as f64 - want).abs() < 1e-6);
                }
            }
        }
        assert_eq!(filled.positions.slice(s![.., 0, .., ..]), scene.positions.slice(s![.., 0, .., ..]));
        let w = training_windows(std::slice::from_ref(&filled), 8, 2, None).unwrap();
        assert_eq!(w.len(), 11, "only the window with the start gap is dropped");
        assert!(fill_short_gaps(&random_scene(&mut rng, 5, 1), 10).valid.is_none());
    }

    #[test]
    fn fill_keeps_gap_that_would_be_degenerate() {
        // Hips turn 180° across a 1-frame gap: the interpolated axis is degenerate.
        let mut pos = Array4::<f32>::zeros((3, 1, 3, 3));
        pos[[0, 0, 0, 0]] = -0.1;
        pos[[0, 0, 1, 0]] = 0.1;
        pos[[2, 0, 0, 0]] = 0.1;
        pos[[2, 0, 1, 0]] = -0.1;
        pos[[1, 0, 1, 0]] = 0.5;
        let mut valid = Array2::from_elem((3, 1), true);
        valid[[1, 0]] = false;
        let scene = Scene::new("turn", 30.0, tiny_skeleton(), pos).unwrap().with_valid(valid).unwrap();
        assert_eq!(fill_short_gaps(&scene, 5), scene);
    }
}
