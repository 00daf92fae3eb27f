//! Generated haggling triads: real speaking timelines drive bodies animated with real motion.
//!
//! Real scenes that carry both bodies and speech annotations are not available to this project
//! (only the Haggling *speech* files are), so the classifiers are trained and measured here on
//! generated triads. Accuracy on them says how well the models pick up the cues the generator
//! puts in — state that wherever such numbers are reported; it is not the accuracy on real
//! Haggling recordings.
//!
//! # What a generated triad is
//! - **Who speaks when**: a real timeline (a segment of a Haggling speech file,
//!   [`SpeakingTimeline::from_speech`]), so turn lengths, pauses, overlaps and backchannels are
//!   real.
//! - **Bodies**: each person is one track of a [`MotionLibrary`] — real recorded motion (e.g.
//!   MuPoTS-3D people) in the body frame, cut into 1.5 s clips ranked by arm motion energy.
//!   Two streams per person chain clips with cross-fades: a *calm* stream (the track's lowest
//!   arm and leg energy clips, low-passed with τ = 0.4 s and damped to 30 % around the mean
//!   calm pose — MuPoTS people are rarely still) and an *active* one (the clips with the most
//!   arm motion, as recorded). The upper body is
//!   `(1 − w)·calm + w·active`; pelvis, hips and legs hold the track's stance (a still frame
//!   with both feet down: haggling people stand). The gesture intensity
//!   `w` follows speech: most turns are animated (target 1), some still (0.25); listeners
//!   fidget now and then (0.6 for 0.5–2 s); `w` is smoothed with τ = 0.25 s.
//! - **Where people stand**: the buyer opposite the two sellers, who stand side by side
//!   (sellers 0.9–1.6 m apart, 1.2–1.8 m from the buyer), everybody swaying a few cm; the scene
//!   is rotated and moved at random.
//! - **Whom people look at**: listeners turn their faces to the speaker 0.15–0.5 s after a turn
//!   starts (the buyer to the seller who spoke last; a seller to the buyer, or — half of the
//!   time — to the other seller while that one speaks); speakers mostly address the buyer (the
//!   buyer: one of the sellers); everybody glances elsewhere now and then. The head follows its
//!   target with τ = 0.15 s within ±80° of the torso, the torso turns 30 % of the way with
//!   τ = 1.2 s. Speakers nod slightly with their gestures.
//! - **Skeleton**: Panoptic-19 (the Haggling layout) at 30 fps. Nose, eyes and ears are placed
//!   on the track's head by the head orientation; the other joints come from the track.
//! - **Labels**: the `speaking` signal and the roles `buyer`, `left_seller`, `right_seller`; the
//!   persons are listed in random order.

use crate::data::body::{degenerate_error, pose_of, Anchor};
use crate::data::dataset::Sequence;
use crate::data::haggling::SpeechFile;
use crate::data::joints::{find_part, sided_pair, Part, Side};
use crate::data::{Dataset, Person, Scene, Skeleton, Split};
use crate::{bail, Result};
use ndarray::{Array2, Array4};
use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use std::f64::consts::PI;

/// Frame rate of generated scenes and of the motion library.
pub const FPS: f64 = 30.0;

/// The body joints a track holds (body frame), in this order.
pub const TRACK_JOINTS: [&str; 15] = [
    "neck",
    "pelvis",
    "left_shoulder",
    "left_elbow",
    "left_wrist",
    "left_hip",
    "left_knee",
    "left_ankle",
    "right_shoulder",
    "right_elbow",
    "right_wrist",
    "right_hip",
    "right_knee",
    "right_ankle",
    "head",
];
/// Indices into [`TRACK_JOINTS`] of the joints taken from the blended upper body; the others
/// (pelvis, hips, knees, ankles) are the track's stance.
const UPPER: [usize; 8] = [0, 2, 3, 4, 8, 9, 10, 14];
const HEAD: usize = 14;

/// Frames per motion clip (1.5 s) and between clip starts.
const CLIP: usize = 45;
const CLIP_STRIDE: usize = 15;
/// Fewest frames of a track: five clips.
const MIN_TRACK: usize = CLIP + 4 * CLIP_STRIDE;
/// Cross-fade between consecutive clips, frames.
const FADE: usize = 12;

type Pose = [[f32; 3]; 15];

/// One person's recorded motion in the body frame, cut into clips ranked by arm energy.
#[derive(Clone, Debug)]
pub struct Track {
    /// Where it came from (`scene/person`).
    pub name: String,
    poses: Vec<Pose>,
    calm: Vec<usize>,
    active: Vec<usize>,
    /// The pose whose legs every generated frame uses (a still frame with both feet down).
    stance: Pose,
    /// Mean pose of the calm clips: listeners relax toward it.
    rest: Pose,
}

fn dist(a: [f32; 3], b: [f32; 3]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

impl Track {
    /// A track from consecutive body-frame poses (30 fps). `None` when it has fewer than five
    /// clips (two calm, two active, in the 40 % at either end of the ranking).
    pub fn from_poses(name: impl Into<String>, poses: Vec<[[f32; 3]; 15]>) -> Option<Self> {
        if poses.len() < MIN_TRACK {
            return None;
        }
        // Frame-to-frame motion of the arms (wrists, half of elbows) and legs (ankles, half of
        // knees), summed per clip.
        let step = |w: &[Pose], a: usize, b: usize, c: usize, d: usize| {
            dist(w[0][a], w[1][a]) + dist(w[0][b], w[1][b]) + 0.5 * (dist(w[0][c], w[1][c]) + dist(w[0][d], w[1][d]))
        };
        let arms: Vec<f32> = poses.windows(2).map(|w| step(w, 4, 10, 3, 9)).collect();
        let legs: Vec<f32> = poses.windows(2).map(|w| step(w, 7, 13, 6, 12)).collect();
        let starts: Vec<usize> = (0..=poses.len() - CLIP).step_by(CLIP_STRIDE).collect();
        let energy = |e: &[f32], s: usize| e[s..s + CLIP - 1].iter().sum::<f32>();
        let k = (starts.len() * 2 / 5).max(1);
        // Calm: still arms and legs. Active: the most arm motion.
        let ranked = |key: &dyn Fn(usize) -> f32| {
            let mut v: Vec<(f32, usize)> = starts.iter().map(|&s| (key(s), s)).collect();
            v.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            v.into_iter().map(|x| x.1).collect::<Vec<usize>>()
        };
        let calm = ranked(&|s| energy(&arms, s) + energy(&legs, s))[..k].to_vec();
        let active: Vec<usize> = ranked(&|s| -energy(&arms, s)).into_iter().filter(|s| !calm.contains(s)).take(k).collect();
        // Stance: both ankles low, feet 0.1–0.45 m apart, legs still.
        let stance_cost = |t: usize| {
            let p = &poses[t];
            let width = (p[7][0] - p[13][0]).hypot(p[7][1] - p[13][1]);
            p[7][2].abs() + p[13][2].abs() + 2.0 * (width - 0.25).abs().max(0.0) + 20.0 * legs[t.min(legs.len() - 1)]
        };
        let still = (0..poses.len()).min_by(|&a, &b| stance_cost(a).total_cmp(&stance_cost(b))).expect("non-empty");
        let stance = poses[still];
        let mut rest = [[0f32; 3]; 15];
        for &c in &calm {
            for pose in &poses[c..c + CLIP] {
                for (r, q) in rest.iter_mut().zip(pose) {
                    for d in 0..3 {
                        r[d] += q[d] / (calm.len() * CLIP) as f32;
                    }
                }
            }
        }
        Some(Self { name: name.into(), poses, calm, active, stance, rest })
    }

    /// Number of frames.
    pub fn num_frames(&self) -> usize {
        self.poses.len()
    }

    /// Mean arm energy (m per frame) of the calm and the active clips.
    pub fn energies(&self) -> (f32, f32) {
        let e = |starts: &[usize]| {
            let per: f32 =
                starts.iter().map(|&s| self.poses[s..s + CLIP].windows(2).map(|w| dist(w[0][4], w[1][4]) + dist(w[0][10], w[1][10])).sum::<f32>()).sum();
            per / (starts.len() * (CLIP - 1)) as f32
        };
        (e(&self.calm), e(&self.active))
    }

    /// `frames` poses chaining clips of the calm or active pool with cross-fades; each next clip
    /// is one of the two whose first pose is nearest to the current one (a jump between distant
    /// poses would itself be fast motion). The calm stream is then slowed and damped.
    fn stream(&self, active: bool, frames: usize, rng: &mut StdRng) -> Vec<Pose> {
        let pool = if active { &self.active } else { &self.calm };
        let mut out: Vec<Pose> = Vec::with_capacity(frames + CLIP);
        while out.len() < frames {
            let start = match out.last() {
                None => pool[rng.gen_range(0..pool.len())],
                Some(last) => {
                    let gap = |s: usize| UPPER.iter().map(|&j| dist(last[j], self.poses[s][j])).sum::<f32>();
                    let mut near: Vec<usize> = pool.clone();
                    near.sort_by(|&a, &b| gap(a).total_cmp(&gap(b)).then(a.cmp(&b)));
                    near[rng.gen_range(0..near.len().min(2))]
                }
            };
            let clip = &self.poses[start..start + CLIP];
            if out.is_empty() {
                out.extend_from_slice(clip);
                continue;
            }
            let base = out.len() - FADE;
            for (i, pose) in clip.iter().enumerate() {
                if i < FADE {
                    let a = (i + 1) as f32 / (FADE + 1) as f32;
                    let prev = out[base + i];
                    out[base + i] = lerp(&prev, pose, a);
                } else {
                    out.push(*pose);
                }
            }
        }
        out.truncate(frames);
        if !active {
            // Listeners: the real motion slowed (low-pass, τ = 0.4 s) and damped to 30 % around
            // the rest pose.
            let a = smoothing(0.4) as f32;
            let mut lp = out[0];
            for pose in out.iter_mut() {
                lp = lerp(&lp, pose, a);
                *pose = lerp(&self.rest, &lp, CALM_AMPLITUDE);
            }
        }
        out
    }
}

/// How much of the calm clips' motion listeners keep (around the rest pose).
const CALM_AMPLITUDE: f32 = 0.3;

fn lerp(a: &Pose, b: &Pose, w: f32) -> Pose {
    let mut o = *a;
    for j in 0..15 {
        for d in 0..3 {
            o[j][d] = (1.0 - w) * a[j][d] + w * b[j][d];
        }
    }
    o
}

/// Real (or procedural) motion to animate generated persons with.
#[derive(Clone, Debug, Default)]
pub struct MotionLibrary {
    /// The tracks.
    pub tracks: Vec<Track>,
}

/// Whether a body-frame pose stands upright (see [`MotionLibrary::from_scenes`]).
fn upright(p: &Pose) -> bool {
    let (neck, pelvis) = (p[0], p[1]);
    pelvis[2] > 0.75 && neck[2] - pelvis[2] > 0.4 && (neck[0] - pelvis[0]).hypot(neck[1] - pelvis[1]) < 0.2
}

/// What each of [`TRACK_JOINTS`] is, in the joint vocabulary.
const TRACK_PARTS: [(Part, Side); 15] = [
    (Part::Neck, Side::Centre),
    (Part::Pelvis, Side::Centre),
    (Part::Shoulder, Side::Left),
    (Part::Elbow, Side::Left),
    (Part::Wrist, Side::Left),
    (Part::Hip, Side::Left),
    (Part::Knee, Side::Left),
    (Part::Ankle, Side::Left),
    (Part::Shoulder, Side::Right),
    (Part::Elbow, Side::Right),
    (Part::Wrist, Side::Right),
    (Part::Hip, Side::Right),
    (Part::Knee, Side::Right),
    (Part::Ankle, Side::Right),
    (Part::Head, Side::Centre),
];

/// How to read [`TRACK_JOINTS`] from a skeleton: per joint, the source joints to average (the
/// joint of that part, else for the pelvis the hips, for the neck the shoulders, for the head
/// the ears, the nose or the head top).
fn joint_map(sk: &Skeleton) -> Result<Vec<Vec<usize>>> {
    let j = &sk.joints;
    let pair = |p: Part| sided_pair(j, p).map(|(l, r)| vec![l, r]);
    let one = |p: Part| find_part(j, &[(p, Side::Centre)]).map(|i| vec![i]);
    TRACK_PARTS
        .iter()
        .zip(TRACK_JOINTS)
        .map(|(&(part, side), name)| {
            if let Some(i) = find_part(j, &[(part, side)]) {
                return Ok(vec![i]);
            }
            let alt = match part {
                Part::Pelvis => Some(vec![sk.left, sk.right]),
                Part::Neck => pair(Part::Shoulder),
                Part::Head => pair(Part::Ear).or_else(|| one(Part::Nose)).or_else(|| one(Part::HeadTop)),
                _ => None,
            };
            alt.ok_or_else(|| crate::Error::invalid(format!("motion library: skeleton {} has no joint {name:?} (joints: {})", sk.name, sk.joints.join(", "))))
        })
        .collect()
}

impl MotionLibrary {
    /// Tracks from every person of `scenes` (resampled to 30 fps), over runs of valid frames
    /// where the person stands upright (pelvis above 0.75 m, neck at least 0.4 m above it and
    /// within 0.2 m horizontally — haggling people stand; scenes must be ground aligned, z up).
    /// Errors when a skeleton lacks a needed joint or no track is long enough.
    pub fn from_scenes<'a>(scenes: impl IntoIterator<Item = &'a Scene>) -> Result<Self> {
        let mut tracks = Vec::new();
        for scene in scenes {
            let scene = if (scene.fps - FPS).abs() > 1e-6 { scene.resample(FPS)? } else { scene.clone() };
            let map = joint_map(&scene.skeleton)?;
            let pos = scene.positions.as_standard_layout();
            let pos = pos.as_slice().expect("standard layout");
            let (l, r) = (scene.skeleton.left, scene.skeleton.right);
            let mut local = vec![0f32; 3 * scene.num_joints()];
            for p in 0..scene.num_persons() {
                let mut run: Vec<Pose> = Vec::new();
                let mut part = 0;
                for f in 0..=scene.num_frames() {
                    let pose = if f < scene.num_frames() && scene.is_valid(f, p) {
                        let world = pose_of(pos, &scene, f, p);
                        let body = Anchor::of_pose(world, l, r).ok_or_else(|| degenerate_error(&scene, p, f, world))?;
                        body.localize(world, &mut local);
                        let mut pose = [[0f32; 3]; 15];
                        for (o, src) in pose.iter_mut().zip(&map) {
                            for &j in src {
                                for d in 0..3 {
                                    o[d] += local[3 * j + d] / src.len() as f32;
                                }
                            }
                        }
                        Some(pose)
                    } else {
                        None
                    };
                    if let Some(pose) = pose.filter(upright) {
                        run.push(pose);
                    } else if !run.is_empty() {
                        if let Some(t) = Track::from_poses(format!("{}/{p}.{part}", scene.name), std::mem::take(&mut run)) {
                            tracks.push(t);
                        }
                        part += 1;
                    }
                }
            }
        }
        if tracks.is_empty() {
            bail!("motion library: no person stands upright on {MIN_TRACK} valid frames in a row");
        }
        Ok(Self { tracks })
    }

    /// Synthetic tracks (for tests without recorded motion): a standing body, still in the first
    /// half of the track and waving its forearms (1–2.5 Hz, 10–25 cm) in the second.
    pub fn procedural(tracks: usize, seed: u64) -> Self {
        let mut rng = StdRng::seed_from_u64(seed);
        let base: Pose = [
            [0.0, 0.0, 1.45],
            [0.0, 0.0, 0.95],
            [-0.18, 0.0, 1.42],
            [-0.22, 0.02, 1.15],
            [-0.22, 0.08, 0.9],
            [-0.1, 0.0, 0.93],
            [-0.1, 0.02, 0.5],
            [-0.1, 0.0, 0.08],
            [0.18, 0.0, 1.42],
            [0.22, 0.02, 1.15],
            [0.22, 0.08, 0.9],
            [0.1, 0.0, 0.93],
            [0.1, 0.02, 0.5],
            [0.1, 0.0, 0.08],
            [0.0, 0.02, 1.6],
        ];
        let frames = 600;
        let tracks = (0..tracks)
            .map(|k| {
                let scale: f32 = rng.gen_range(0.9..1.1);
                let (f1, f2): (f32, f32) = (rng.gen_range(1.0..2.5), rng.gen_range(1.0..2.5));
                let (a1, a2): (f32, f32) = (rng.gen_range(0.1..0.25), rng.gen_range(0.1..0.25));
                let poses = (0..frames)
                    .map(|t| {
                        let s = t as f32 / FPS as f32;
                        let mut p = base;
                        for j in p.iter_mut() {
                            for v in j.iter_mut() {
                                *v *= scale;
                            }
                        }
                        let sway = 0.01 * (2.0 * std::f32::consts::PI * 0.3 * s).sin();
                        for j in [0, 2, 3, 4, 8, 9, 10, 14] {
                            p[j][0] += sway;
                        }
                        if t >= frames / 2 {
                            let w = |f: f32, ph: f32| (2.0 * std::f32::consts::PI * f * s + ph).sin();
                            p[4][1] += a1 * w(f1, 0.0);
                            p[4][2] += 0.6 * a1 * w(f1, 1.0);
                            p[3][1] += 0.3 * a1 * w(f1, 0.0);
                            p[10][1] += a2 * w(f2, 2.0);
                            p[10][2] += 0.6 * a2 * w(f2, 0.5);
                            p[9][1] += 0.3 * a2 * w(f2, 2.0);
                        }
                        p
                    })
                    .collect();
                Track::from_poses(format!("procedural/{k}"), poses).expect("600 frames make clips")
            })
            .collect();
        Self { tracks }
    }
}

/// Who speaks on every frame of a haggling conversation.
#[derive(Clone, Debug, PartialEq)]
pub struct SpeakingTimeline {
    /// Where it came from.
    pub name: String,
    /// Per frame: the buyer, the left seller, the right seller speaks.
    pub speaking: Vec<[bool; 3]>,
}

/// Index of the buyer, left and right seller in a [`SpeakingTimeline`] row.
const BUYER: usize = 0;

impl SpeakingTimeline {
    /// Every annotated entry of a Haggling speech file.
    pub fn from_speech(name: impl Into<String>, speech: &SpeechFile) -> Result<Self> {
        let get = |id: i64| speech.speaker(id).map(|s| &s.indicator).ok_or_else(|| crate::Error::invalid(format!("speech file: no speaker with humanId {id}")));
        let (b, l, r) = (get(speech.buyer_id)?, get(speech.left_seller_id)?, get(speech.right_seller_id)?);
        let n = b.len().min(l.len()).min(r.len());
        Ok(Self { name: name.into(), speaking: (0..n).map(|t| [b[t] > 0.5, l[t] > 0.5, r[t] > 0.5]).collect() })
    }

    /// A made-up conversation (for tests without speech files): turns of 0.5–6 s handed between
    /// random persons, with pauses, overlaps and short backchannels.
    pub fn procedural(frames: usize, seed: u64) -> Self {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut speaking = vec![[false; 3]; frames];
        let mut t = 0;
        let mut who = rng.gen_range(0..3);
        while t < frames {
            let len = rng.gen_range(15..180);
            for row in speaking.iter_mut().skip(t).take(len) {
                row[who] = true;
            }
            if rng.gen_bool(0.3) {
                let other = (who + rng.gen_range(1..3)) % 3;
                let at = t + rng.gen_range(0..len);
                for row in speaking.iter_mut().skip(at).take(rng.gen_range(5..25)) {
                    row[other] = true;
                }
            }
            t += len + rng.gen_range(0..30);
            who = (who + rng.gen_range(1..3)) % 3;
        }
        Self { name: format!("procedural-{seed}"), speaking }
    }

    /// Consecutive pieces of `frames` frames (a last piece of at least half that is kept).
    pub fn segments(&self, frames: usize) -> Vec<SpeakingTimeline> {
        let frames = frames.max(1);
        let mut out = Vec::new();
        let mut start = 0;
        while start < self.speaking.len() {
            let end = (start + frames).min(self.speaking.len());
            if end - start >= frames.div_ceil(2) || out.is_empty() {
                out.push(Self { name: format!("{}@{start}", self.name), speaking: self.speaking[start..end].to_vec() });
            }
            start = end;
        }
        out
    }
}

/// First-order smoothing factor for a time constant of `tau` seconds at 30 fps.
fn smoothing(tau: f64) -> f64 {
    1.0 - (-1.0 / (tau * FPS)).exp()
}

fn wrap(a: f64) -> f64 {
    (a + PI).rem_euclid(2.0 * PI) - PI
}

/// Per person and frame: whom they look at (0 buyer, 1 left, 2 right seller).
fn attention_targets(speaking: &[[bool; 3]], rng: &mut StdRng) -> Vec<[usize; 3]> {
    let n = speaking.len();
    let delays: Vec<usize> = (0..3).map(|_| rng.gen_range(5..15)).collect();
    let heard = |p: usize, t: usize| -> [bool; 3] {
        if t >= delays[p] {
            speaking[t - delays[p]]
        } else {
            [false; 3]
        }
    };
    let mut out = vec![[0usize; 3]; n];
    let mut last_onset = [0usize; 3];
    let mut decision = [0usize; 3]; // chosen target during the current situation
    let mut situation = [[false; 3]; 3];
    let mut glance: [(usize, usize); 3] = [(0, 0); 3]; // (until frame, target)
    let mut buyer_target = 1 + rng.gen_range(0..2);
    for (t, row) in out.iter_mut().enumerate() {
        for p in 0..3 {
            let s = heard(p, t);
            let before = if t > 0 { heard(p, t - 1) } else { [false; 3] };
            for q in 0..3 {
                if s[q] && !before[q] && p == 0 {
                    last_onset[q] = t;
                }
            }
            let changed = s != situation[p];
            situation[p] = s;
            let target = if p == BUYER {
                match (s[1], s[2]) {
                    (true, false) => buyer_target = 1,
                    (false, true) => buyer_target = 2,
                    (true, true) => buyer_target = if last_onset[1] >= last_onset[2] { 1 } else { 2 },
                    (false, false) => {
                        if changed && s[0] && rng.gen_bool(0.3) {
                            buyer_target = 3 - buyer_target;
                        }
                    }
                }
                buyer_target
            } else {
                let other = 3 - p;
                if changed {
                    decision[p] = if s[0] {
                        0
                    } else if s[other] {
                        if rng.gen_bool(0.5) {
                            other
                        } else {
                            0
                        }
                    } else if s[p] {
                        if rng.gen_bool(0.85) {
                            0
                        } else {
                            other
                        }
                    } else {
                        0
                    };
                }
                decision[p]
            };
            // Glances: ~0.1 per second, 0.5–1.5 s at someone else.
            if glance[p].0 <= t && rng.gen_bool(0.1 / FPS) {
                let others: Vec<usize> = (0..3).filter(|&q| q != p && q != target).collect();
                glance[p] = (t + rng.gen_range(15..45), others[rng.gen_range(0..others.len())]);
            }
            row[p] = if glance[p].0 > t { glance[p].1 } else { target };
        }
    }
    out
}

/// Gesture intensity targets per person and frame (before smoothing).
fn gesture_targets(speaking: &[[bool; 3]], rng: &mut StdRng) -> Vec<[f64; 3]> {
    let n = speaking.len();
    let mut out = vec![[0.0; 3]; n];
    for p in 0..3 {
        let mut style = 1.0;
        let mut fidget_until = 0;
        for t in 0..n {
            let s = speaking[t][p];
            if s && (t == 0 || !speaking[t - 1][p]) {
                style = if rng.gen_bool(0.7) { 1.0 } else { 0.25 };
            }
            if !s && fidget_until <= t && rng.gen_bool(0.08 / FPS) {
                fidget_until = t + rng.gen_range(15..60);
            }
            out[t][p] = if s {
                style
            } else if fidget_until > t {
                0.6
            } else {
                0.0
            };
        }
    }
    out
}

/// Face points in the head frame (x right, y forward, z up), metres from the head joint:
/// nose, left eye, left ear, right eye, right ear.
const FACE: [[f64; 3]; 5] = [[0.0, 0.1, -0.02], [-0.032, 0.085, 0.015], [-0.075, 0.0, 0.0], [0.032, 0.085, 0.015], [0.075, 0.0, 0.0]];

/// Generates one triad (module docs) from a timeline and a motion library; `seed` fixes every
/// random choice.
pub fn generate_triad(timeline: &SpeakingTimeline, library: &MotionLibrary, seed: u64) -> Result<Scene> {
    let n = timeline.speaking.len();
    if n < 2 {
        bail!("generated triad: timeline {} has {n} frame(s)", timeline.name);
    }
    if library.tracks.is_empty() {
        bail!("generated triad: the motion library is empty");
    }
    let mut rng = StdRng::seed_from_u64(seed);
    let gauss = Normal::new(0.0, 1.0).expect("valid normal");
    // Tracks (distinct when the library has three).
    let mut ids: Vec<usize> = (0..library.tracks.len()).collect();
    ids.shuffle(&mut rng);
    let tracks: Vec<&Track> = (0..3).map(|k| &library.tracks[ids[k % ids.len()]]).collect();

    // Layout in the buyer's frame: buyer at the origin facing +y, sellers ahead.
    let half_gap = rng.gen_range(0.45..0.8);
    let depth = rng.gen_range(1.2..1.8);
    let home: [[f64; 2]; 3] = [
        [rng.gen_range(-0.1..0.1), rng.gen_range(-0.1..0.1)],
        [-half_gap + rng.gen_range(-0.1..0.1), depth + rng.gen_range(-0.15..0.15)],
        [half_gap + rng.gen_range(-0.1..0.1), depth + rng.gen_range(-0.15..0.15)],
    ];
    let toward = |a: [f64; 2], b: [f64; 2]| (b[1] - a[1]).atan2(b[0] - a[0]);
    let centre = [0.5 * (home[1][0] + home[2][0]), 0.5 * (home[1][1] + home[2][1])];
    let home_facing = [
        toward(home[0], centre) + rng.gen_range(-0.1..0.1),
        toward(home[1], home[0]) + rng.gen_range(-0.3..0.1),
        toward(home[2], home[0]) + rng.gen_range(-0.1..0.3),
    ];

    let targets = attention_targets(&timeline.speaking, &mut rng);
    let gestures = gesture_targets(&timeline.speaking, &mut rng);
    let (a_head, a_torso, a_gesture, a_sway) = (smoothing(0.15), smoothing(1.2), smoothing(0.25), smoothing(2.0));
    let nod_freq: Vec<f64> = (0..3).map(|_| rng.gen_range(1.5..3.0)).collect();

    let mut positions = Array4::<f32>::zeros((n, 3, 19, 3));
    let sk = Skeleton::panoptic19();
    let track_to_panoptic: Vec<usize> = TRACK_JOINTS.iter().filter(|&&j| j != "head").map(|j| sk.joint_index(j).expect("panoptic joint")).collect();
    let face_joints: Vec<usize> =
        ["nose", "left_eye", "left_ear", "right_eye", "right_ear"].iter().map(|j| sk.joint_index(j).expect("panoptic face joint")).collect();
    for p in 0..3 {
        let calm = tracks[p].stream(false, n, &mut rng);
        let active = tracks[p].stream(true, n, &mut rng);
        let (mut head_yaw, mut torso) = (home_facing[p], home_facing[p]);
        let (mut w, mut sway, mut gaze_noise) = (0.0f64, [0.0f64; 2], 0.0f64);
        for t in 0..n {
            let target = targets[t][p];
            let desired = if target == p { home_facing[p] } else { toward(home[p], home[target]) };
            gaze_noise += 0.05 * (-gaze_noise) + 0.02 * gauss.sample(&mut rng);
            head_yaw += a_head * wrap(desired + gaze_noise - head_yaw);
            torso += a_torso * wrap(home_facing[p] + 0.3 * wrap(desired - home_facing[p]) - torso);
            let rel = wrap(head_yaw - torso).clamp(-80f64.to_radians(), 80f64.to_radians());
            w += a_gesture * (gestures[t][p] - w);
            for s in sway.iter_mut() {
                *s += a_sway * (-*s) + 0.004 * gauss.sample(&mut rng);
            }
            let pitch = 0.1 * w * (2.0 * PI * nod_freq[p] * t as f64 / FPS).sin();

            let mut pose = tracks[p].stance;
            let moved = lerp(&calm[t], &active[t], w as f32);
            for &j in &UPPER {
                pose[j] = moved[j];
            }
            // Torso: body frame facing +y → world facing `torso` (heading = facing − 90°).
            let h = torso - PI / 2.0;
            let (sh, ch) = h.sin_cos();
            let root = [home[p][0] + sway[0], home[p][1] + sway[1]];
            let world = |x: f64, y: f64, z: f64| [root[0] + ch * x - sh * y, root[1] + sh * x + ch * y, z];
            for (k, &pj) in track_to_panoptic.iter().enumerate() {
                let l = pose[k];
                let wv = world(l[0] as f64, l[1] as f64, l[2] as f64);
                for d in 0..3 {
                    positions[[t, p, pj, d]] = wv[d] as f32;
                }
            }
            // Face on the head: pitch about the head's x axis, then yaw `rel` about z.
            let hd = pose[HEAD];
            let (sp, cp) = pitch.sin_cos();
            let (sr, cr) = rel.sin_cos();
            for (f, &pj) in FACE.iter().zip(&face_joints) {
                let (y1, z1) = (cp * f[1] - sp * f[2], sp * f[1] + cp * f[2]);
                let (x2, y2) = (cr * f[0] - sr * y1, sr * f[0] + cr * y1);
                let wv = world(hd[0] as f64 + x2, hd[1] as f64 + y2, hd[2] as f64 + z1);
                for d in 0..3 {
                    positions[[t, p, pj, d]] = wv[d] as f32;
                }
            }
        }
    }

    // Random placement of the whole scene, random person order.
    let mut order = [0usize, 1, 2];
    order.shuffle(&mut rng);
    let positions = positions.select(ndarray::Axis(1), &order);
    let mut scene = Scene::new(format!("{}#{seed}", timeline.name), FPS, sk, positions)?;
    let (sa, ca) = rng.gen_range(-PI..PI).sin_cos();
    scene.transform([[ca, -sa, 0.0], [sa, ca, 0.0], [0.0, 0.0, 1.0]], [rng.gen_range(-2.0..2.0), rng.gen_range(-2.0..2.0), 0.0]);
    let roles = ["buyer", "left_seller", "right_seller"];
    let persons = order.iter().enumerate().map(|(i, &r)| Person { id: i.to_string(), role: Some(roles[r].to_string()) }).collect();
    let speaking = Array2::from_shape_fn((n, 3), |(t, i)| if timeline.speaking[t][order[i]] { 1.0 } else { 0.0 });
    let mut scene = scene.with_persons(persons)?.with_signal("speaking", speaking)?;
    let m = &mut scene.metadata;
    m.insert(
        "generated".into(),
        "socdiff classifier synth: real speaking timeline, bodies from a motion library (see socdiff_engine::data::synthetic::triads)".into(),
    );
    m.insert("speech_source".into(), timeline.name.clone().into());
    m.insert("motion_tracks".into(), tracks.iter().map(|t| t.name.clone()).collect::<Vec<_>>().into());
    m.insert("seed".into(), seed.into());
    Ok(scene)
}

/// How to generate a dataset of triads.
#[derive(Clone, Debug, PartialEq)]
pub struct SynthConfig {
    /// Frames per generated scene (timelines are cut into pieces this long).
    pub segment_frames: usize,
    /// Generated scenes per timeline segment (each with other bodies and layout).
    pub variants: usize,
    /// Seed of every random choice.
    pub seed: u64,
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self { segment_frames: 1800, variants: 1, seed: 0 }
    }
}

/// Triads generated from files: the speaking timelines of the Haggling speech files `speech`
/// (the last `test_files` of them for the test split) animated with the motion of `motion`
/// (its train split for training, its test split — or, without one, its train split again —
/// for testing; `import` reads it). Returns the dataset, the track counts of the two motion
/// libraries and notes.
pub fn generate_from_files(
    name: &str,
    speech: &[std::path::PathBuf],
    test_files: usize,
    motion: &std::path::Path,
    import: &crate::data::import::ImportOptions,
    cfg: &SynthConfig,
) -> Result<(Dataset, [usize; 2], Vec<String>)> {
    if test_files >= speech.len() {
        bail!("`test_files` {test_files} leaves no speech file for training ({} given)", speech.len());
    }
    let mut timelines = Vec::with_capacity(speech.len());
    for p in speech {
        let stem = p.file_stem().map_or_else(|| p.display().to_string(), |s| s.to_string_lossy().into_owned());
        timelines.push(SpeakingTimeline::from_speech(stem, &crate::data::haggling::load_speech(p)?).map_err(|e| e.in_file(p))?);
    }
    let data = crate::data::import::load(motion, import)?;
    let train_lib = MotionLibrary::from_scenes(data.split(Split::Train)).map_err(|e| e.in_file(motion))?;
    let mut notes = Vec::new();
    let test_lib = if data.split(Split::Test).next().is_some() {
        MotionLibrary::from_scenes(data.split(Split::Test)).map_err(|e| e.in_file(motion))?
    } else {
        notes.push(format!("{} has no test split: test scenes reuse the training motion", motion.display()));
        train_lib.clone()
    };
    let cut = speech.len() - test_files;
    let ds = generate_dataset(name, &timelines[..cut], &train_lib, &timelines[cut..], &test_lib, cfg)?;
    Ok((ds, [train_lib.tracks.len(), test_lib.tracks.len()], notes))
}

/// A dataset of generated triads: `train` timelines animated with `train_motion`, `test`
/// timelines with `test_motion` (keep both apart, so test scenes have unseen timelines and
/// bodies).
pub fn generate_dataset(
    name: &str,
    train: &[SpeakingTimeline],
    train_motion: &MotionLibrary,
    test: &[SpeakingTimeline],
    test_motion: &MotionLibrary,
    cfg: &SynthConfig,
) -> Result<Dataset> {
    if cfg.segment_frames < 2 || cfg.variants == 0 {
        bail!("synth: segment_frames must be at least 2 and variants at least 1");
    }
    let mut sequences = Vec::new();
    let mut k = 0u64;
    for (split, timelines, lib) in [(Split::Train, train, train_motion), (Split::Test, test, test_motion)] {
        for tl in timelines {
            for seg in tl.segments(cfg.segment_frames) {
                for _ in 0..cfg.variants {
                    let seed = cfg.seed.wrapping_mul(0x9E37_79B9).wrapping_add(k);
                    k += 1;
                    let mut scene = generate_triad(&seg, lib, seed)?;
                    scene.name = format!("{}_{k:04}", split.as_str());
                    sequences.push(Sequence { split, scene });
                }
            }
        }
    }
    let mut metadata = serde_json::Map::new();
    metadata.insert(
        "description".into(),
        "Generated haggling triads (socdiff classifier synth): real speaking timelines, bodies animated with recorded motion. Not real Haggling recordings."
            .into(),
    );
    Ok(Dataset { name: name.to_string(), sequences, metadata })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::sscp::{attention, Facing, Triad};

    #[test]
    fn procedural_tracks_rank_clips_by_arm_energy() {
        let lib = MotionLibrary::procedural(3, 1);
        for t in &lib.tracks {
            let (calm, active) = t.energies();
            assert!(active > 5.0 * calm, "{}: calm {calm}, active {active}", t.name);
        }
    }

    #[test]
    fn timelines_cut_into_segments() {
        let tl = SpeakingTimeline::procedural(1000, 2);
        assert_eq!(tl.speaking.len(), 1000);
        let seg = tl.segments(300);
        assert_eq!(seg.iter().map(|s| s.speaking.len()).collect::<Vec<_>>(), vec![300, 300, 300]);
        assert_eq!(seg[1].speaking[..], tl.speaking[300..600]);
        assert_eq!(tl.segments(400).len(), 3); // 400, 400, 200 (half kept)
        let fractions: Vec<f64> = (0..3).map(|p| tl.speaking.iter().filter(|r| r[p]).count() as f64 / 1000.0).collect();
        assert!(fractions.iter().all(|&f| f > 0.03 && f < 0.8), "{fractions:?}");
    }

    /// A generated triad: labels follow the timeline, roles are consistent with the geometry,
    /// the buyer's face points to the speaking seller most of the time, speakers move their
    /// wrists faster than listeners (by `ratio`).
    fn assert_cues(scene: &Scene, tl: &SpeakingTimeline, ratio: f32) {
        let n = tl.speaking.len();
        assert_eq!(scene.positions.dim(), (n, 3, 19, 3));
        let triad = Triad::from_roles(scene).unwrap();
        assert_eq!(Triad::from_buyer(scene, triad.buyer).unwrap(), triad, "left/right roles match the geometry");
        let sp = &scene.signals["speaking"];
        for t in 0..n {
            assert_eq!([sp[[t, triad.buyer]] > 0.5, sp[[t, triad.left]] > 0.5, sp[[t, triad.right]] > 0.5], tl.speaking[t]);
        }
        // Attention (SSCP's, from the eye axis): while exactly one seller speaks (after a
        // reaction time), the buyer mostly faces that seller.
        let att = attention(scene.positions.view(), &triad, &Facing::for_skeleton(&scene.skeleton), 0.0).unwrap();
        let (mut agree, mut total) = (0, 0);
        for (t, &faces_right) in att.iter().enumerate().skip(30) {
            let (l, r) = (tl.speaking[t - 20][1] && tl.speaking[t][1], tl.speaking[t - 20][2] && tl.speaking[t][2]);
            if l != r {
                total += 1;
                agree += usize::from(faces_right == r);
            }
        }
        assert!(total > 100 && agree as f64 > 0.75 * total as f64, "{agree} of {total}");
        // Wrist speed relative to the neck (no sway), while speaking vs listening, per person
        // (persons have different tracks); persons who never or always speak are skipped.
        let (wrists, neck) = (["left_wrist", "right_wrist"].map(|j| scene.skeleton.joint_index(j).unwrap()), scene.skeleton.joint_index("neck").unwrap());
        let mut ratios = Vec::new();
        for p in 0..3 {
            let (mut s, mut ns, mut l, mut nl) = (0.0, 0, 0.0, 0);
            for t in 1..n {
                let rel = |t: usize, w: usize| [0, 1, 2].map(|d| scene.positions[[t, p, w, d]] - scene.positions[[t, p, neck, d]]);
                let v: f32 = wrists.iter().map(|&w| (0..3).map(|d| (rel(t, w)[d] - rel(t - 1, w)[d]).powi(2)).sum::<f32>().sqrt()).sum();
                if sp[[t, p]] > 0.5 {
                    (s, ns) = (s + v, ns + 1);
                } else {
                    (l, nl) = (l + v, nl + 1);
                }
            }
            if ns > 30 && nl > 30 {
                ratios.push((s / ns as f32) / (l / nl as f32));
            }
        }
        eprintln!("wrist speed speaking / listening per person: {ratios:?}");
        assert!(!ratios.is_empty() && ratios.iter().sum::<f32>() / ratios.len() as f32 > ratio, "{ratios:?}");
        // Everybody stands: feet near the floor, heads up.
        let (nose, ankle) = (scene.skeleton.joint_index("nose").unwrap(), scene.skeleton.joint_index("left_ankle").unwrap());
        for t in (0..n).step_by(10) {
            for p in 0..3 {
                assert!(scene.positions[[t, p, ankle, 2]] < 0.25 && scene.positions[[t, p, nose, 2]] > 1.2, "frame {t} person {p}");
            }
        }
    }

    #[test]
    fn generated_triads_carry_the_cues() {
        let lib = MotionLibrary::procedural(4, 3);
        let tl = SpeakingTimeline::procedural(900, 4);
        let scene = generate_triad(&tl, &lib, 5).unwrap();
        assert_cues(&scene, &tl, 2.0);
        // Deterministic for a seed.
        assert_eq!(generate_triad(&tl, &lib, 5).unwrap(), scene);
        assert_ne!(generate_triad(&tl, &lib, 6).unwrap().positions, scene.positions);
    }

    /// Real data: MuPoTS-3D people as the motion library (upright clips only, active clips move
    /// the arms more than calm ones), a real Haggling timeline, and the cues of a generated
    /// triad.
    #[test]
    fn real_motion_and_real_timelines_make_triads_with_the_cues() {
        let root = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data"));
        let (mupots, speech) = (root.join("mupots3d"), root.join("haggling_speech/170221_haggling_b1_group0.pkl"));
        if !mupots.is_dir() || !speech.is_file() {
            crate::testing::skip_absent(if mupots.is_dir() { &speech } else { &mupots }, "shared MuPoTS or Haggling speech data");
            return;
        }
        let ds = crate::data::import::load(&mupots, &Default::default()).unwrap();
        let lib = MotionLibrary::from_scenes(ds.split(Split::Train)).unwrap();
        assert!(lib.tracks.len() >= 20, "{} tracks", lib.tracks.len());
        for t in &lib.tracks {
            assert!(t.poses.iter().all(upright), "{}", t.name);
            let (calm, active) = t.energies();
            assert!(active > calm, "{}: calm {calm}, active {active}", t.name);
        }
        let sp = crate::data::haggling::load_speech(&speech).unwrap();
        let tl = SpeakingTimeline::from_speech("b1_group0", &sp).unwrap();
        assert_eq!(tl.speaking.len(), sp.num_entries());
        let scene = generate_triad(&tl, &lib, 1).unwrap();
        assert_cues(&scene, &tl, 1.5);
        // A library from a skeleton without the needed joints is an error naming the joint.
        let bad = Scene::new(
            "x",
            30.0,
            crate::data::Skeleton::new("stick", vec!["a".into(), "b".into()], vec![], 0, 1).unwrap(),
            ndarray::Array4::zeros((90, 1, 2, 3)),
        )
        .unwrap();
        let e = MotionLibrary::from_scenes([&bad]).unwrap_err().to_string();
        assert!(e.contains("neck") && e.contains("stick"), "{e}");
    }

    #[test]
    fn datasets_keep_train_and_test_apart() {
        let lib = MotionLibrary::procedural(3, 1);
        let tls: Vec<SpeakingTimeline> = (0..3).map(|s| SpeakingTimeline::procedural(400, s)).collect();
        let cfg = SynthConfig { segment_frames: 200, variants: 2, seed: 9 };
        let ds = generate_dataset("synth", &tls[..2], &lib, &tls[2..], &lib, &cfg).unwrap();
        assert_eq!(ds.split(Split::Train).count(), 2 * 2 * 2);
        assert_eq!(ds.split(Split::Test).count(), 2 * 2);
        assert!(ds.sequences.iter().all(|s| s.scene.signals.contains_key("speaking") && Triad::from_roles(&s.scene).is_ok()));
        assert!(generate_dataset("x", &tls, &lib, &[], &lib, &SynthConfig { variants: 0, ..cfg }).is_err());
    }
}
