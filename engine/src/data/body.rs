//! The body frame of a pose: root on the ground and heading, from the two body-frame joints
//! (the hips by default). The geometry is documented in [`crate::features`], which encodes
//! poses relative to it.

use super::Scene;
use crate::{bail, Error, Result};
use serde::{Deserialize, Serialize};

/// Body-frame joints closer than this in the ground plane (metres) make a degenerate axis.
pub const MIN_HIP_DISTANCE: f64 = 1e-3;

/// A planar frame on the ground: root position and heading (angle of the left→right axis,
/// radians, counter-clockwise from +x). It is the body frame of a pose, and — at the anchor
/// frame — the reference that a person's trajectory is expressed in.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Anchor {
    /// Root (x, y) in metres.
    pub root: [f64; 2],
    /// Heading in radians.
    pub heading: f64,
}

impl Anchor {
    /// The world frame: features anchored here are in world coordinates.
    pub const IDENTITY: Anchor = Anchor { root: [0.0, 0.0], heading: 0.0 };

    /// Body frame of one pose, or `None` if the axis between joints `left` and `right` is
    /// shorter than [`MIN_HIP_DISTANCE`] in the ground plane (or not finite).
    ///
    /// # Shapes
    /// - `pose`: `[joints · 3]` (x, y, z per joint).
    pub fn of_pose(pose: &[f32], left: usize, right: usize) -> Option<Anchor> {
        let (dx, dy) = axis(pose, left, right);
        let d = dx.hypot(dy);
        if !(d >= MIN_HIP_DISTANCE && d.is_finite()) {
            return None;
        }
        Some(Anchor { root: ground_midpoint(pose, left, right), heading: dy.atan2(dx) })
    }

    /// Facing direction in radians: heading + 90°.
    pub fn facing(&self) -> f64 {
        self.heading + std::f64::consts::FRAC_PI_2
    }

    /// Joints of `pose` in this body frame: ground offsets from the root turned by −heading
    /// (the left→right axis along +x), heights as they are.
    ///
    /// # Shapes
    /// - `pose`, `out`: `[joints · 3]`.
    ///
    /// # Panics
    /// If the lengths differ.
    pub fn localize(&self, pose: &[f32], out: &mut [f32]) {
        assert_eq!(pose.len(), out.len(), "localize: pose and output lengths differ");
        let (s, c) = self.heading.sin_cos();
        let [ox, oy] = self.root;
        for (q, o) in pose.chunks_exact(3).zip(out.chunks_exact_mut(3)) {
            let (dx, dy) = (q[0] as f64 - ox, q[1] as f64 - oy);
            o[0] = (c * dx + s * dy) as f32;
            o[1] = (-s * dx + c * dy) as f32;
            o[2] = q[2];
        }
    }
}

pub(crate) fn axis(pose: &[f32], left: usize, right: usize) -> (f64, f64) {
    (pose[3 * right] as f64 - pose[3 * left] as f64, pose[3 * right + 1] as f64 - pose[3 * left + 1] as f64)
}

/// Midpoint of joints `left` and `right` projected on the ground, `(x, y)`.
///
/// # Shapes
/// - `pose`: `[joints · 3]`.
pub fn ground_midpoint(pose: &[f32], left: usize, right: usize) -> [f64; 2] {
    [0.5 * (pose[3 * left] as f64 + pose[3 * right] as f64), 0.5 * (pose[3 * left + 1] as f64 + pose[3 * right + 1] as f64)]
}

/// Distance of joints `left` and `right` in the ground plane, metres.
///
/// # Shapes
/// - `pose`: `[joints · 3]`.
pub fn hip_distance(pose: &[f32], left: usize, right: usize) -> f64 {
    let (dx, dy) = axis(pose, left, right);
    dx.hypot(dy)
}

pub(crate) fn degenerate_error(scene: &Scene, person: usize, frame: usize, pose: &[f32]) -> Error {
    let (l, r) = (scene.skeleton.left, scene.skeleton.right);
    Error::invalid(format!(
        "scene {}: person {person}, frame {frame}: hip axis degenerate ({} and {} {:.4} m apart in the ground plane, need at least {MIN_HIP_DISTANCE} m)",
        scene.name,
        scene.skeleton.joints[l],
        scene.skeleton.joints[r],
        hip_distance(pose, l, r)
    ))
}

/// Contiguous `[frames · persons · joints · 3]` positions of a scene.
pub(crate) fn pose_of<'a>(pos: &'a [f32], scene: &Scene, frame: usize, person: usize) -> &'a [f32] {
    let n = scene.num_joints() * 3;
    &pos[(frame * scene.num_persons() + person) * n..][..n]
}

/// Body frame of person `person` at frame `frame` of `scene`.
///
/// A degenerate axis is an error on a valid frame; on an invalid frame the root is the
/// midpoint and the heading that of the nearest valid non-degenerate frame of the person
/// (ties → earlier; 0 if there is none).
pub fn body_frame(scene: &Scene, frame: usize, person: usize) -> Result<Anchor> {
    if frame >= scene.num_frames() || person >= scene.num_persons() {
        bail!("scene {}: frame {frame}, person {person} out of range ({} frames, {} persons)", scene.name, scene.num_frames(), scene.num_persons());
    }
    let pos = scene.positions.as_standard_layout();
    let pos = pos.as_slice().expect("standard layout");
    let (l, r) = (scene.skeleton.left, scene.skeleton.right);
    let pose = pose_of(pos, scene, frame, person);
    if let Some(a) = Anchor::of_pose(pose, l, r) {
        return Ok(a);
    }
    if scene.is_valid(frame, person) {
        return Err(degenerate_error(scene, person, frame, pose));
    }
    let good = |f: usize| scene.is_valid(f, person) && Anchor::of_pose(pose_of(pos, scene, f, person), l, r).is_some();
    let nf = scene.num_frames();
    let mut heading = 0.0;
    for d in 1..nf.max(1) {
        let cand = [frame.checked_sub(d), Some(frame + d).filter(|&f| f < nf)];
        if cand.iter().all(|c| c.is_none()) {
            break;
        }
        if let Some(f) = cand.into_iter().flatten().find(|&f| good(f)) {
            heading = Anchor::of_pose(pose_of(pos, scene, f, person), l, r).expect("good").heading;
            break;
        }
    }
    Ok(Anchor { root: ground_midpoint(pose, l, r), heading })
}

/// Fallback heading of every frame of person `p` (same rule as [`body_frame`]), in O(frames).
pub(crate) fn fallback_headings(scene: &Scene, pos: &[f32], p: usize) -> Vec<f64> {
    let nf = scene.num_frames();
    let (l, r) = (scene.skeleton.left, scene.skeleton.right);
    let good: Vec<Option<f64>> =
        (0..nf).map(|f| if scene.is_valid(f, p) { Anchor::of_pose(pose_of(pos, scene, f, p), l, r).map(|a| a.heading) } else { None }).collect();
    let mut prev = vec![None; nf];
    let mut last = None;
    for f in 0..nf {
        if good[f].is_some() {
            last = Some(f);
        }
        prev[f] = last;
    }
    let mut out = vec![0.0; nf];
    let mut next = None;
    for f in (0..nf).rev() {
        if good[f].is_some() {
            next = Some(f);
        }
        let pick = match (prev[f], next) {
            (Some(a), Some(b)) => Some(if f - a <= b - f { a } else { b }),
            (a, b) => a.or(b),
        };
        out[f] = pick.and_then(|g| good[g]).unwrap_or(0.0);
    }
    out
}
