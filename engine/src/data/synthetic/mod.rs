//! Scenes built from recorded motion: synthetic groups of single-person clips placed around a
//! shared centre (as MRT does with CMU mocap), and leader/follower episodes that probe whether
//! a model uses the other persons; and generated haggling triads for the speech classifiers
//! ([`triads`]).
//!
//! # Stitched tracks
//! A person of a synthetic group performs a sequence of clips. The first clip starts at a random
//! frame of its first half, its body frame moved to the person's place (on a circle around the
//! group centre) and turned to face the centre (± `facing_jitter`). Each following clip is
//! rotated about z and translated so that its first body frame (root and heading) equals the
//! last body frame of the track, and the remaining jump of each joint,
//! `d = last pose − first pose of the moved clip`, is added with a linearly decaying weight
//! `1 − i/(blend + 1)` to its frames `i = 1..=blend` (frame 0 is dropped: it repeats the last
//! frame). Up to `tries` random clips are tried per join; the first whose end stays within
//! `stay_within` metres of the centre is taken (else the one ending nearest), so that walking
//! clips do not carry the group apart.
//!
//! All random choices come from one `StdRng` seeded by [`GroupConfig::seed`], so a seed gives the
//! same groups every time (training data fingerprints then match on resume).

pub mod triads;

use super::scene::{Person, Scene};
use crate::data::body::{body_frame, Anchor};
use crate::{bail, Result};
use ndarray::Array4;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// How synthetic groups are built (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct GroupConfig {
    /// Fewest persons per group (≥ 1).
    pub persons_min: usize,
    /// Most persons per group (≥ persons_min).
    pub persons_max: usize,
    /// Frames of each group scene.
    pub frames: usize,
    /// Range of each person's start distance from the centre, metres.
    pub radius: (f64, f64),
    /// Persons face the centre ± this many radians (uniform).
    pub facing_jitter: f64,
    /// Clips are chosen so that a track ends within this distance of the centre, metres.
    pub stay_within: f64,
    /// Frames over which the jump at a join is blended out.
    pub blend: usize,
    /// Random clips tried per join.
    pub tries: usize,
    /// Seed of every random choice.
    pub seed: u64,
}

impl Default for GroupConfig {
    fn default() -> Self {
        Self { persons_min: 2, persons_max: 3, frames: 600, radius: (0.8, 1.8), facing_jitter: 0.6, stay_within: 3.0, blend: 8, tries: 8, seed: 0 }
    }
}

impl GroupConfig {
    fn validate(&self) -> Result<()> {
        if self.persons_min == 0 || self.persons_min > self.persons_max {
            bail!("synthetic groups: persons {}..={} must satisfy 1 ≤ min ≤ max", self.persons_min, self.persons_max);
        }
        if self.frames < 2 {
            bail!("synthetic groups: frames must be at least 2, got {}", self.frames);
        }
        let (a, b) = self.radius;
        if !(a.is_finite() && b.is_finite() && 0.0 <= a && a <= b) {
            bail!("synthetic groups: radius range {a}..{b} must satisfy 0 ≤ min ≤ max");
        }
        if !(self.facing_jitter.is_finite() && self.facing_jitter >= 0.0 && self.stay_within.is_finite() && self.stay_within > 0.0) {
            bail!("synthetic groups: facing_jitter must be ≥ 0 and stay_within > 0");
        }
        if self.tries == 0 {
            bail!("synthetic groups: tries must be at least 1");
        }
        Ok(())
    }
}

/// One single-person clip with its per-frame body frames.
struct Clip {
    /// `[frames · J · 3]`.
    pos: Vec<f32>,
    frames: usize,
    anchors: Vec<Anchor>,
}

fn clips_of(scenes: &[Scene]) -> Result<Vec<Clip>> {
    let Some(first) = scenes.first() else { bail!("synthetic groups: no clips") };
    let mut out = Vec::with_capacity(scenes.len());
    for s in scenes {
        if s.skeleton.joints != first.skeleton.joints {
            bail!("synthetic groups: clip {} has skeleton {}, clip {} has {}", s.name, s.skeleton.name, first.name, first.skeleton.name);
        }
        if (s.fps - first.fps).abs() > 1e-6 * first.fps {
            bail!("synthetic groups: clip {} is at {} fps, clip {} at {} fps (resample first)", s.name, s.fps, first.name, first.fps);
        }
        if s.num_frames() < 2 {
            continue;
        }
        for p in 0..s.num_persons() {
            let anchors = (0..s.num_frames()).map(|f| body_frame(s, f, p)).collect::<Result<Vec<_>>>()?;
            let pos: Vec<f32> = s.person(p).iter().copied().collect();
            out.push(Clip { pos, frames: s.num_frames(), anchors });
        }
    }
    if out.is_empty() {
        bail!("synthetic groups: every clip is shorter than 2 frames");
    }
    Ok(out)
}

/// `x ↦ R(θ)(x − from) + to` in the ground plane, heights kept.
fn move_pose(pose: &[f32], from: [f64; 2], to: [f64; 2], theta: f64, out: &mut [f32]) {
    let (s, c) = theta.sin_cos();
    for (q, o) in pose.chunks_exact(3).zip(out.chunks_exact_mut(3)) {
        let (dx, dy) = (q[0] as f64 - from[0], q[1] as f64 - from[1]);
        o[0] = (to[0] + c * dx - s * dy) as f32;
        o[1] = (to[1] + s * dx + c * dy) as f32;
        o[2] = q[2];
    }
}

/// A segment of `clip` from frame `start`, moved so that its first body frame becomes `target`.
fn placed(clip: &Clip, start: usize, target: Anchor) -> Vec<f32> {
    let n = clip.pos.len() / clip.frames;
    let a0 = clip.anchors[start];
    let mut out = vec![0.0; (clip.frames - start) * n];
    for (i, o) in out.chunks_exact_mut(n).enumerate() {
        move_pose(&clip.pos[(start + i) * n..][..n], a0.root, target.root, target.heading - a0.heading, o);
    }
    out
}

fn end_root(seg: &[f32], n: usize, l: usize, r: usize) -> [f64; 2] {
    crate::data::body::ground_midpoint(&seg[seg.len() - n..], l, r)
}

/// One person's track of `frames` frames (module docs), `[frames · J · 3]`.
fn stitched_track(clips: &[Clip], frames: usize, start: Anchor, centre: [f64; 2], body: (usize, usize), cfg: &GroupConfig, rng: &mut StdRng) -> Vec<f32> {
    let n = clips[0].pos.len() / clips[0].frames;
    let (l, r) = body;
    let mut out: Vec<f32> = Vec::with_capacity(frames * n);
    // First segment: a random clip from a random frame of its first half.
    let c = &clips[rng.gen_range(0..clips.len())];
    let s0 = rng.gen_range(0..c.frames.div_ceil(2));
    out.extend(placed(c, s0, start));
    while out.len() < frames * n {
        let last = out[out.len() - n..].to_vec();
        let here = Anchor::of_pose(&last, l, r).unwrap_or(Anchor { root: crate::data::body::ground_midpoint(&last, l, r), heading: 0.0 });
        let mut best: Option<(f64, Vec<f32>)> = None;
        for _ in 0..cfg.tries {
            let c = &clips[rng.gen_range(0..clips.len())];
            let seg = placed(c, 0, here);
            let e = end_root(&seg, n, l, r);
            let dist = (e[0] - centre[0]).hypot(e[1] - centre[1]);
            let better = best.as_ref().is_none_or(|b| dist < b.0);
            if better {
                best = Some((dist, seg));
            }
            if dist <= cfg.stay_within {
                break;
            }
        }
        let (_, mut seg) = best.expect("tries ≥ 1");
        let jump: Vec<f32> = last.iter().zip(&seg[..n]).map(|(a, b)| a - b).collect();
        for (i, pose) in seg.chunks_exact_mut(n).enumerate().skip(1).take(cfg.blend) {
            let w = 1.0 - i as f32 / (cfg.blend as f32 + 1.0);
            for (v, d) in pose.iter_mut().zip(&jump) {
                *v += w * d;
            }
        }
        if seg.len() > n {
            out.extend_from_slice(&seg[n..]);
        }
    }
    out.truncate(frames * n);
    out
}

/// `count` synthetic group scenes built from single-person `clips` (module docs), named
/// `{prefix}_g0000`, … Every person of a clip scene counts as one clip.
///
/// # Shapes
/// - each output: `[cfg.frames, P, J, 3]` with `P` uniform in `persons_min..=persons_max`.
pub fn synthetic_groups(clips: &[Scene], count: usize, prefix: &str, cfg: &GroupConfig) -> Result<Vec<Scene>> {
    cfg.validate()?;
    let parsed = clips_of(clips)?;
    let first = &clips[0];
    let body = (first.skeleton.left, first.skeleton.right);
    let n = first.num_joints() * 3;
    let mut rng = StdRng::seed_from_u64(cfg.seed);
    let mut out = Vec::with_capacity(count);
    for g in 0..count {
        let np = rng.gen_range(cfg.persons_min..=cfg.persons_max);
        let turn = rng.gen_range(-PI..PI);
        let mut pos = vec![0.0f32; cfg.frames * np * n];
        for p in 0..np {
            let angle = turn + TAU * p as f64 / np as f64 + rng.gen_range(-0.3..=0.3) / np as f64;
            let radius = rng.gen_range(cfg.radius.0..=cfg.radius.1);
            let root = [radius * angle.cos(), radius * angle.sin()];
            // Facing the centre: facing = angle + π, heading = facing − π/2.
            let jitter = if cfg.facing_jitter > 0.0 { rng.gen_range(-cfg.facing_jitter..=cfg.facing_jitter) } else { 0.0 };
            let start = Anchor { root, heading: angle + PI - FRAC_PI_2 + jitter };
            let track = stitched_track(&parsed, cfg.frames, start, [0.0, 0.0], body, cfg, &mut rng);
            for f in 0..cfg.frames {
                pos[(f * np + p) * n..][..n].copy_from_slice(&track[f * n..][..n]);
            }
        }
        let positions = Array4::from_shape_vec((cfg.frames, np, n / 3, 3), pos).map_err(|e| crate::Error::invalid(e.to_string()))?;
        let name = format!("{prefix}_g{g:04}");
        let persons = (0..np).map(|p| Person { id: format!("{name}_p{p}"), role: None }).collect();
        let mut scene = Scene::new(name, first.fps, first.skeleton.clone(), positions)?.with_persons(persons)?;
        scene.metadata.insert("synthetic_group".into(), serde_json::json!({"clips": clips.len(), "seed": cfg.seed, "index": g}));
        out.push(scene);
    }
    Ok(out)
}

/// Knobs of a leader/follower episode ([`leader_follower_scene`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LeaderFollower {
    /// Frames of the episode.
    pub frames: usize,
    /// Observed frames: the follower starts walking at or after this frame.
    pub observed: usize,
    /// Frames by which the follower repeats the leader's motion.
    pub lag: usize,
    /// Walking speed, metres per frame.
    pub speed: f64,
    /// Distance between the two persons, metres.
    pub spacing: f64,
}

impl Default for LeaderFollower {
    fn default() -> Self {
        Self { frames: 64, observed: 32, lag: 16, speed: 1.0 / 30.0, spacing: 1.5 }
    }
}

/// A two-person episode probing the social channel: the leader (person 0) holds `poses[0]`,
/// the follower (person 1) `poses[1]` (poses of `skeleton`, `[J · 3]`; make them differ, e.g.
/// the follower's lower, so that each person can tell its role from its own pose). They stand
/// `spacing` apart in a random direction, facing one random way. The leader starts gliding at
/// `speed` in a random direction at a random frame in `observed − lag .. observed − lag/4`; the
/// follower repeats that motion `lag` frames later, so it starts in the forecast part. Only the
/// leader's observed past tells when and where the follower will go.
pub fn leader_follower_scene(skeleton: &crate::Skeleton, poses: [&[f32]; 2], fps: f64, lf: &LeaderFollower, name: &str, seed: u64) -> Result<Scene> {
    let nj = skeleton.num_joints();
    if !(lf.lag >= 4 && lf.lag <= lf.observed && lf.observed < lf.frames) {
        bail!("leader/follower: need 4 ≤ lag ≤ observed < frames, got lag {}, observed {}, frames {}", lf.lag, lf.observed, lf.frames);
    }
    let mut anchors = [Anchor::IDENTITY; 2];
    for (q, pose) in poses.iter().enumerate() {
        if pose.len() != 3 * nj {
            bail!("leader/follower: pose {q} has {} values, skeleton {} needs {}", pose.len(), skeleton.name, 3 * nj);
        }
        let Some(a) = Anchor::of_pose(pose, skeleton.left, skeleton.right) else {
            bail!("leader/follower: the hip axis of pose {q} is degenerate");
        };
        anchors[q] = a;
    }
    let mut rng = StdRng::seed_from_u64(seed);
    let start = rng.gen_range(lf.observed - lf.lag..lf.observed - lf.lag / 4);
    let (dir, side, heading): (f64, f64, f64) = (rng.gen_range(-PI..PI), rng.gen_range(-PI..PI), rng.gen_range(-PI..PI));
    let origins = [[0.0, 0.0], [lf.spacing * side.cos(), lf.spacing * side.sin()]];
    let mut pos = Array4::<f32>::zeros((lf.frames, 2, nj, 3));
    let mut buf = vec![0.0f32; 3 * nj];
    for f in 0..lf.frames {
        for (q, origin) in origins.iter().enumerate() {
            let d = f.saturating_sub(start + q * lf.lag) as f64 * lf.speed;
            let root = [origin[0] + d * dir.cos(), origin[1] + d * dir.sin()];
            move_pose(poses[q], anchors[q].root, root, heading - anchors[q].heading, &mut buf);
            for j in 0..nj {
                for k in 0..3 {
                    pos[[f, q, j, k]] = buf[3 * j + k];
                }
            }
        }
    }
    let mut scene = Scene::new(name, fps, skeleton.clone(), pos)?;
    scene.persons = vec![Person { id: "leader".into(), role: Some("leader".into()) }, Person { id: "follower".into(), role: Some("follower".into()) }];
    scene.metadata.insert("leader_follower".into(), serde_json::json!({"start": start, "lag": lf.lag, "seed": seed}));
    Ok(scene)
}

/// `persons` persons of `skeleton` walking on circles around the origin, `frames` frames at
/// `fps`: person `p` at radius `1 + 0.4 p`, at angle `0.3 t + 0.9 p + phase` (t in seconds),
/// facing along the circle (counter-clockwise). `body(f, p, pose)` writes the pose of person `p`
/// at frame `f` in its body frame (x right, y forward, z up, metres; `[J · 3]`).
///
/// # Shapes
/// - positions `[frames, persons, J, 3]`
pub fn circle_walkers(
    skeleton: &crate::Skeleton,
    frames: usize,
    persons: usize,
    fps: f64,
    phase: f32,
    body: impl Fn(usize, usize, &mut [f32]),
) -> Result<Scene> {
    crate::data::check_size("circle walkers", frames as f64, persons, 1)?;
    let nj = skeleton.num_joints();
    let mut pos = Array4::<f32>::zeros((frames, persons, nj, 3));
    let mut pose = vec![0f32; 3 * nj];
    for f in 0..frames {
        let t = f as f32 / fps as f32;
        for p in 0..persons {
            let a = 0.3 * t + p as f32 * 0.9 + phase;
            let (s, c) = a.sin_cos();
            let r = 1.0 + 0.4 * p as f32;
            body(f, p, &mut pose);
            for (j, q) in pose.chunks_exact(3).enumerate() {
                let [x, y, z] = [q[0], q[1], q[2]];
                pos[[f, p, j, 0]] = r * c + x * c - y * s;
                pos[[f, p, j, 1]] = r * s + x * s + y * c;
                pos[[f, p, j, 2]] = z;
            }
        }
    }
    Scene::new(format!("walkers_{persons}p"), fps, skeleton.clone(), pos)
}

/// A standing MuPoTS-17 pose (x right, y forward, z up), metres.
const MUPOTS_REST: [[f32; 3]; 17] = [
    [0.0, 0.0, 1.75],
    [0.0, 0.0, 1.45],
    [-0.18, 0.0, 1.42],
    [-0.2, 0.0, 1.12],
    [-0.2, 0.05, 0.88],
    [0.18, 0.0, 1.42],
    [0.2, 0.0, 1.12],
    [0.2, 0.05, 0.88],
    [-0.12, 0.0, 0.92],
    [-0.12, 0.02, 0.5],
    [-0.12, 0.0, 0.08],
    [0.12, 0.0, 0.92],
    [0.12, 0.02, 0.5],
    [0.12, 0.0, 0.08],
    [0.0, 0.0, 0.92],
    [0.0, 0.0, 1.18],
    [0.0, 0.02, 1.58],
];

/// `persons` MuPoTS-17 skeletons walking on circles ([`circle_walkers`]), `frames` frames at 30
/// fps, forearms and shins swinging rigidly about the elbows and knees (bone lengths fixed).
pub fn walkers(frames: usize, persons: usize, phase: f32) -> Scene {
    let swing = |f: usize, _p: usize, out: &mut [f32]| {
        let t = f as f32 / 30.0;
        let phi = 0.5 * (6.0 * t + phase).sin();
        for (j, o) in out.chunks_exact_mut(3).enumerate() {
            let pivot = match j {
                4 => Some((3, phi)),
                7 => Some((6, -phi)),
                10 => Some((9, -phi)),
                13 => Some((12, phi)),
                _ => None,
            };
            let [x, mut y, mut z] = MUPOTS_REST[j];
            if let Some((q, ang)) = pivot {
                let (sa, ca) = ang.sin_cos();
                let (dy, dz) = (y - MUPOTS_REST[q][1], z - MUPOTS_REST[q][2]);
                y = MUPOTS_REST[q][1] + ca * dy - sa * dz;
                z = MUPOTS_REST[q][2] + sa * dy + ca * dz;
            }
            o.copy_from_slice(&[x, y, z]);
        }
    };
    let mut scene = circle_walkers(&crate::Skeleton::mupots17(), frames, persons, 30.0, phase, swing).expect("small sizes");
    scene.name = "walkers".into();
    scene
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::test_util::walkers;

    fn clip_scenes() -> Vec<Scene> {
        (0..3)
            .map(|i| walkers(40 + 10 * i, 1, i as f32))
            .enumerate()
            .map(|(i, mut s)| {
                s.name = format!("clip{i}");
                s
            })
            .collect()
    }

    #[test]
    fn groups_are_reproducible_continuous_and_placed_around_the_centre() {
        let clips = clip_scenes();
        let cfg = GroupConfig { frames: 150, persons_min: 2, persons_max: 4, blend: 6, ..Default::default() };
        let a = synthetic_groups(&clips, 5, "syn", &cfg).unwrap();
        let b = synthetic_groups(&clips, 5, "syn", &cfg).unwrap();
        assert_eq!(a, b, "a seed gives the same groups");
        let c = synthetic_groups(&clips, 5, "syn", &GroupConfig { seed: 1, ..cfg.clone() }).unwrap();
        assert_ne!(a[0].positions, c[0].positions);
        let sk = &clips[0].skeleton;
        let max_step = clips
            .iter()
            .flat_map(|s| {
                (1..s.num_frames()).map(move |f| {
                    (0..s.num_joints())
                        .map(|j| (0..3).map(|k| (s.positions[[f, 0, j, k]] - s.positions[[f - 1, 0, j, k]]).powi(2)).sum::<f32>().sqrt())
                        .fold(0f32, f32::max)
                })
            })
            .fold(0f32, f32::max);
        for g in &a {
            assert_eq!(g.num_frames(), 150);
            assert!((2..=4).contains(&g.num_persons()), "{}", g.num_persons());
            assert_eq!(g.name[..5].to_string(), "syn_g");
            for p in 0..g.num_persons() {
                // Start within the radius range, facing the centre ± jitter.
                let a0 = body_frame(g, 0, p).unwrap();
                let r = a0.root[0].hypot(a0.root[1]);
                assert!(r >= cfg.radius.0 - 1e-3 && r <= cfg.radius.1 + 1e-3, "radius {r}");
                let to_centre = (-a0.root[1]).atan2(-a0.root[0]);
                let off = (a0.facing() - to_centre + PI).rem_euclid(TAU) - PI;
                assert!(off.abs() <= cfg.facing_jitter + 1e-6, "facing off by {off}");
                // No frame-to-frame jump larger than the clips' own plus the blended share of a join.
                for f in 1..g.num_frames() {
                    for j in 0..sk.num_joints() {
                        let step = (0..3).map(|k| (g.positions[[f, p, j, k]] - g.positions[[f - 1, p, j, k]]).powi(2)).sum::<f32>().sqrt();
                        assert!(step < max_step + 0.6, "group {} person {p} frame {f} joint {j}: step {step}", g.name);
                    }
                }
            }
        }
        assert!(synthetic_groups(&clips, 1, "x", &GroupConfig { persons_min: 0, ..cfg.clone() }).is_err());
        assert!(synthetic_groups(&[], 1, "x", &cfg).unwrap_err().to_string().contains("no clips"));
    }

    #[test]
    fn joins_continue_the_previous_clip() {
        // One clip of a person walking on a circle: a stitched track keeps going at the same
        // pace without a jump of the root at the joins (same heading, same speed).
        let clip = walkers(20, 1, 0.0);
        let cfg = GroupConfig { frames: 70, persons_min: 1, persons_max: 1, blend: 4, stay_within: 1e9, ..Default::default() };
        let g = &synthetic_groups(std::slice::from_ref(&clip), 1, "w", &cfg).unwrap()[0];
        let root = |f: usize| body_frame(g, f, 0).unwrap().root;
        let step = |f: usize| (root(f)[0] - root(f - 1)[0]).hypot(root(f)[1] - root(f - 1)[1]);
        let clip_step = {
            let a = body_frame(&clip, 1, 0).unwrap().root;
            let b = body_frame(&clip, 0, 0).unwrap().root;
            (a[0] - b[0]).hypot(a[1] - b[1])
        };
        for f in 1..70 {
            assert!(step(f) <= 2.0 * clip_step + 1e-4, "frame {f}: step {} vs clip {clip_step}", step(f));
        }
    }

    #[test]
    fn leader_follower_episodes_lag_by_the_lag() {
        let s = walkers(1, 1, 0.0);
        let pose: Vec<f32> = s.person(0).iter().copied().collect();
        let lower: Vec<f32> = pose.chunks(3).flat_map(|q| [q[0], q[1], 0.9 * q[2]]).collect();
        let lf = LeaderFollower::default();
        let e = leader_follower_scene(&s.skeleton, [&pose, &lower], 30.0, &lf, "lf", 3).unwrap();
        assert_eq!(e.positions.dim(), (64, 2, s.num_joints(), 3));
        let start = e.metadata["leader_follower"]["start"].as_u64().unwrap() as usize;
        assert!(start + lf.lag >= lf.observed && start < lf.observed);
        let root = |f: usize, p: usize| body_frame(&e, f, p).unwrap().root;
        let moved = |p: usize, f: usize| (root(f, p)[0] - root(0, p)[0]).hypot(root(f, p)[1] - root(0, p)[1]);
        for f in 0..64 {
            assert!((moved(1, f) - if f >= lf.lag { moved(0, f - lf.lag) } else { 0.0 }).abs() < 1e-4, "frame {f}");
        }
        assert!(moved(1, lf.observed - 1) < 1e-6 && moved(1, 63) > 0.5);
        // Each person keeps its own pose's heights on every frame.
        for f in [0, 40, 63] {
            for (q, pose) in [&pose, &lower].into_iter().enumerate() {
                for j in 0..s.num_joints() {
                    assert_eq!(e.positions[[f, q, j, 2]], pose[3 * j + 2], "frame {f}, person {q}, joint {j}");
                }
            }
        }
        let err = leader_follower_scene(&s.skeleton, [&pose, &pose[1..]], 30.0, &lf, "x", 0).unwrap_err().to_string();
        assert!(err.contains("pose 1 has"), "{err}");
    }
}
