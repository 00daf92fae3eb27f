//! The distribution of motion kinds: a small motion-kind classifier and the Jensen–Shannon
//! distance between the kinds of generated and of real motion.
//!
//! A model that collapses onto the commonest motion (standing, walking) shows it here even when
//! every one of its words looks real. The classifier labels windows of one person's motion
//! ([`WINDOW_S`] seconds at [`CLASSIFIER_FPS`]; other rates are resampled) with the kinds of a
//! labelled dataset — bandai2's five motion kinds (walk, walk-turn, run, wave, raise-up; its ten
//! motions without their sides), read from its sequence names ([`bandai_kind`]) — by softmax
//! regression on 97 features of the window:
//!
//! - the 13 body points head, shoulders, elbows, wrists, hips, knees and ankles (found by name
//!   on any skeleton, [`crate::data::joints::joint_parts`]), in each frame's body frame and
//!   divided by the person's leg length: mean and std of x, y, z (78), mean speed (13);
//! - the root: net displacement in the first frame's body frame (2), mean and std of its
//!   horizontal speed (2), net and mean absolute heading rate (2) — all per leg length and
//!   second.
//!
//! Features are z-scored on the training windows; the weights are fitted by full-batch Adam on
//! the mean cross-entropy plus an L2 penalty, from zero, so training is deterministic.
//! Because body points are found by name and scaled by leg length, a classifier trained on
//! bandai2 labels MuPoTS or CMU motion as well.

use super::js_distance;
use crate::data::joints::{joint_parts, Part, Side};
use crate::data::{Scene, Skeleton, Split};
use crate::features::Anchor;
use crate::{bail, Dataset, Result};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Frame rate the classifier reads (scenes at other rates are resampled).
pub const CLASSIFIER_FPS: f64 = 30.0;
/// Seconds of one classified window.
pub const WINDOW_S: f64 = 2.0;
/// Body points of the features, in order.
const POINTS: [(Part, Side); 13] = [
    (Part::Head, Side::Centre),
    (Part::Shoulder, Side::Left),
    (Part::Shoulder, Side::Right),
    (Part::Elbow, Side::Left),
    (Part::Elbow, Side::Right),
    (Part::Wrist, Side::Left),
    (Part::Wrist, Side::Right),
    (Part::Hip, Side::Left),
    (Part::Hip, Side::Right),
    (Part::Knee, Side::Left),
    (Part::Knee, Side::Right),
    (Part::Ankle, Side::Left),
    (Part::Ankle, Side::Right),
];
/// Features per window.
pub const FEATURES: usize = POINTS.len() * 7 + 6;

/// Frames of one window at [`CLASSIFIER_FPS`].
pub fn window_frames() -> usize {
    (WINDOW_S * CLASSIFIER_FPS).round() as usize
}

/// The motion kind of a bandai2 sequence name: the word between the first and second
/// underscore with its side dropped (`dataset-2_walk-turn-left_active_001` → `walk-turn`,
/// `…_wave-right-hand_…` → `wave`, `…_raise-up-both-hands_…` → `raise-up`; `walk`, `run` as
/// they are). Sides are dropped because a window rarely tells a left from a right variant of an
/// unseen style apart, and coverage asks which motions are there, not which hand.
pub fn bandai_kind(name: &str) -> Option<String> {
    let mut parts = name.split('_');
    parts.next()?;
    let motion = parts.next().filter(|m| !m.is_empty())?;
    let mut kind = motion;
    for suffix in ["-both-hands", "-left-hand", "-right-hand", "-left", "-right"] {
        if let Some(k) = kind.strip_suffix(suffix) {
            kind = k;
            break;
        }
    }
    Some(kind.to_string())
}

/// The joint index of each of the 13 body points on `skeleton`, or an error naming the missing
/// ones.
fn point_joints(skeleton: &Skeleton) -> Result<Vec<usize>> {
    let parts = joint_parts(&skeleton.joints);
    let mut out = Vec::with_capacity(POINTS.len());
    let mut missing = Vec::new();
    for want in POINTS {
        match parts.iter().find(|(p, _)| *p == want) {
            Some((_, j)) => out.push(*j),
            None => missing.push(format!("{:?} {:?}", want.1, want.0).to_lowercase()),
        }
    }
    if !missing.is_empty() {
        bail!("motion kinds: skeleton {} has no joint for {} (found by name)", skeleton.name, missing.join(", "));
    }
    Ok(out)
}

/// Features of every window of one person (`[frames · joints · 3]`, [`CLASSIFIER_FPS`]),
/// windows starting every `stride` frames.
fn person_windows(pos: &[f32], nj: usize, skeleton: &Skeleton, points: &[usize], stride: usize) -> Vec<[f64; FEATURES]> {
    let w = window_frames();
    let frames = pos.len() / (3 * nj);
    if frames < w {
        return Vec::new();
    }
    let pose = |t: usize| &pos[t * nj * 3..(t + 1) * nj * 3];
    let p3 = |t: usize, j: usize| {
        let q = &pose(t)[3 * j..3 * j + 3];
        [q[0] as f64, q[1] as f64, q[2] as f64]
    };
    let anchors: Vec<Anchor> = (0..frames)
        .map(|t| {
            Anchor::of_pose(pose(t), skeleton.left, skeleton.right)
                .unwrap_or(Anchor { root: crate::features::ground_midpoint(pose(t), skeleton.left, skeleton.right), heading: 0.0 })
        })
        .collect();
    let norm = |a: [f64; 3], b: [f64; 3]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
    // Leg length: hip → knee → ankle, both sides, over the whole track.
    let (hl, hr, kl, kr, al, ar) = (points[7], points[8], points[9], points[10], points[11], points[12]);
    let leg = (0..frames)
        .map(|t| 0.5 * (norm(p3(t, hl), p3(t, kl)) + norm(p3(t, kl), p3(t, al)) + norm(p3(t, hr), p3(t, kr)) + norm(p3(t, kr), p3(t, ar))))
        .sum::<f64>()
        / frames as f64;
    let scale = 1.0 / leg.max(0.1);
    // Each body point in its frame's body frame, per leg length, once per track (windows overlap).
    let body: Vec<[f64; 3]> = (0..frames)
        .flat_map(|t| {
            let a = &anchors[t];
            let (s, c) = a.heading.sin_cos();
            points.iter().map(move |&j| {
                let q = p3(t, j);
                let (dx, dy) = (q[0] - a.root[0], q[1] - a.root[1]);
                [(c * dx + s * dy) * scale, (-s * dx + c * dy) * scale, q[2] * scale]
            })
        })
        .collect();
    let local = |t: usize, pi: usize| body[t * points.len() + pi];
    let fps = CLASSIFIER_FPS;
    let mut out = Vec::new();
    let mut start = 0;
    while start + w <= frames {
        let mut f = [0.0; FEATURES];
        let n = w as f64;
        for pi in 0..points.len() {
            let mut sum = [0.0; 3];
            let mut sq = [0.0; 3];
            let mut speed = 0.0;
            let mut prev = local(start, pi);
            for t in start..start + w {
                let l = local(t, pi);
                for d in 0..3 {
                    sum[d] += l[d];
                    sq[d] += l[d] * l[d];
                }
                if t > start {
                    speed += norm(l, prev) * fps;
                }
                prev = l;
            }
            for d in 0..3 {
                let mean = sum[d] / n;
                f[pi * 7 + d] = mean;
                f[pi * 7 + 3 + d] = (sq[d] / n - mean * mean).max(0.0).sqrt();
            }
            f[pi * 7 + 6] = speed / (n - 1.0);
        }
        let o = POINTS.len() * 7;
        let (a0, a1) = (&anchors[start], &anchors[start + w - 1]);
        let (s, c) = a0.heading.sin_cos();
        let (dx, dy) = (a1.root[0] - a0.root[0], a1.root[1] - a0.root[1]);
        let secs = (w - 1) as f64 / fps;
        f[o] = (c * dx + s * dy) * scale / secs;
        f[o + 1] = (-s * dx + c * dy) * scale / secs;
        let speeds: Vec<f64> = (start + 1..start + w)
            .map(|t| (anchors[t].root[0] - anchors[t - 1].root[0]).hypot(anchors[t].root[1] - anchors[t - 1].root[1]) * scale * fps)
            .collect();
        let ms = speeds.iter().sum::<f64>() / speeds.len() as f64;
        f[o + 2] = ms;
        f[o + 3] = (speeds.iter().map(|v| (v - ms).powi(2)).sum::<f64>() / speeds.len() as f64).sqrt();
        let turns: Vec<f64> = (start + 1..start + w)
            .map(|t| {
                let d = anchors[t].heading - anchors[t - 1].heading;
                (d + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
            })
            .collect();
        f[o + 4] = turns.iter().sum::<f64>() / secs;
        f[o + 5] = turns.iter().map(|v| v.abs()).sum::<f64>() / secs;
        out.push(f);
        start += stride;
    }
    out
}

/// Features of every window of every person of `scene` (valid frames only: a person's track is
/// cut at invalid frames), windows every `stride` frames after resampling.
pub fn scene_windows(scene: &Scene, stride: usize) -> Result<Vec<[f64; FEATURES]>> {
    let points = point_joints(&scene.skeleton)?;
    let resampled;
    let scene = if (scene.fps - CLASSIFIER_FPS).abs() > 1e-9 {
        resampled = scene.resample(CLASSIFIER_FPS)?;
        &resampled
    } else {
        scene
    };
    let nj = scene.num_joints();
    let mut out = Vec::new();
    for p in 0..scene.num_persons() {
        let person = scene.person(p);
        let mut run: Vec<f32> = Vec::new();
        for t in 0..=scene.num_frames() {
            if t < scene.num_frames() && scene.is_valid(t, p) {
                run.extend(person.slice(ndarray::s![t, .., ..]).iter());
            } else if !run.is_empty() {
                out.extend(person_windows(&run, nj, &scene.skeleton, &points, stride.max(1)));
                run.clear();
            }
        }
    }
    Ok(out)
}

/// Settings of [`MotionKindClassifier::train`].
#[derive(Clone, Debug, PartialEq)]
pub struct KindTraining {
    /// Frames between training windows (default 15).
    pub stride: usize,
    /// Adam steps over the whole set (default 400).
    pub steps: usize,
    /// Adam learning rate (default 0.05).
    pub lr: f64,
    /// L2 penalty on the weights (default 1e-3).
    pub l2: f64,
}

impl Default for KindTraining {
    fn default() -> Self {
        Self { stride: 15, steps: 400, lr: 0.05, l2: 1e-3 }
    }
}

/// A softmax-regression motion-kind classifier (module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MotionKindClassifier {
    /// Kind names, index = class.
    pub labels: Vec<String>,
    /// Feature means and standard deviations of the training windows.
    pub mean: Vec<f64>,
    pub std: Vec<f64>,
    /// `[classes][FEATURES]` weights and `[classes]` biases.
    pub weights: Vec<Vec<f64>>,
    pub bias: Vec<f64>,
    /// Training windows per class.
    pub windows_per_class: Vec<usize>,
}

impl MotionKindClassifier {
    /// Trains on windows of labelled scenes (`(scene, kind)`); classes are the kinds in sorted
    /// order.
    pub fn train(examples: &[(&Scene, &str)], cfg: &KindTraining) -> Result<Self> {
        let mut labels: Vec<String> = examples.iter().map(|(_, l)| l.to_string()).collect();
        labels.sort();
        labels.dedup();
        if labels.len() < 2 {
            bail!("motion kinds: training needs at least two kinds, got {:?}", labels);
        }
        let per: Vec<Vec<[f64; FEATURES]>> = examples.par_iter().map(|(s, _)| scene_windows(s, cfg.stride)).collect::<Result<_>>()?;
        let mut x = Vec::new();
        let mut y = Vec::new();
        for ((_, l), w) in examples.iter().zip(per) {
            let c = labels.iter().position(|k| k == l).expect("label listed");
            y.extend(std::iter::repeat_n(c, w.len()));
            x.extend(w);
        }
        let mut windows_per_class = vec![0; labels.len()];
        y.iter().for_each(|&c| windows_per_class[c] += 1);
        if let Some(c) = windows_per_class.iter().position(|&n| n == 0) {
            bail!("motion kinds: kind {} has no window of {} s", labels[c], WINDOW_S);
        }
        let n = x.len() as f64;
        let mut mean = vec![0.0; FEATURES];
        let mut std = vec![0.0; FEATURES];
        for f in &x {
            for d in 0..FEATURES {
                mean[d] += f[d] / n;
            }
        }
        for f in &x {
            for d in 0..FEATURES {
                std[d] += (f[d] - mean[d]).powi(2) / n;
            }
        }
        std.iter_mut().for_each(|s| *s = s.sqrt().max(1e-6));
        let z: Vec<[f64; FEATURES]> = x.iter().map(|f| std::array::from_fn(|d| (f[d] - mean[d]) / std[d])).collect();
        let classes = labels.len();
        let mut w = vec![vec![0.0; FEATURES + 1]; classes];
        let (mut m1, mut m2) = (vec![vec![0.0; FEATURES + 1]; classes], vec![vec![0.0; FEATURES + 1]; classes]);
        let (b1, b2, eps) = (0.9, 0.999, 1e-8);
        for step in 1..=cfg.steps {
            let grads = z
                .par_iter()
                .zip(&y)
                .fold(
                    || vec![vec![0.0; FEATURES + 1]; classes],
                    |mut g, (f, &c)| {
                        let p = softmax(&w, f);
                        for k in 0..classes {
                            let e = (p[k] - if k == c { 1.0 } else { 0.0 }) / n;
                            for d in 0..FEATURES {
                                g[k][d] += e * f[d];
                            }
                            g[k][FEATURES] += e;
                        }
                        g
                    },
                )
                .reduce(
                    || vec![vec![0.0; FEATURES + 1]; classes],
                    |mut a, b| {
                        a.iter_mut().zip(b).for_each(|(ra, rb)| ra.iter_mut().zip(rb).for_each(|(u, v)| *u += v));
                        a
                    },
                );
            for k in 0..classes {
                for d in 0..=FEATURES {
                    let g = grads[k][d] + if d < FEATURES { cfg.l2 * w[k][d] } else { 0.0 };
                    m1[k][d] = b1 * m1[k][d] + (1.0 - b1) * g;
                    m2[k][d] = b2 * m2[k][d] + (1.0 - b2) * g * g;
                    let (h1, h2) = (m1[k][d] / (1.0 - b1.powi(step as i32)), m2[k][d] / (1.0 - b2.powi(step as i32)));
                    w[k][d] -= cfg.lr * h1 / (h2.sqrt() + eps);
                }
            }
        }
        let bias = w.iter().map(|r| r[FEATURES]).collect();
        let weights = w.into_iter().map(|mut r| {
            r.truncate(FEATURES);
            r
        });
        Ok(Self { labels, mean, std, weights: weights.collect(), bias, windows_per_class })
    }

    /// Trains on the `split` scenes of a bandai2-style dataset, kinds from the names
    /// ([`bandai_kind`]); sequences whose names carry no kind are an error naming one.
    pub fn train_on_names(dataset: &Dataset, split: Split, cfg: &KindTraining) -> Result<Self> {
        let named: Vec<(&Scene, String)> = dataset
            .split(split)
            .map(|s| {
                bandai_kind(&s.name).map(|k| (s, k)).ok_or_else(|| {
                    crate::Error::invalid(format!(
                        "motion kinds: dataset {}: sequence {} has no kind in its name (expected <prefix>_<kind>_…)",
                        dataset.name, s.name
                    ))
                })
            })
            .collect::<Result<_>>()?;
        let examples: Vec<(&Scene, &str)> = named.iter().map(|(s, k)| (*s, k.as_str())).collect();
        Self::train(&examples, cfg)
    }

    /// The most likely kind of each window of features.
    pub fn classify(&self, windows: &[[f64; FEATURES]]) -> Vec<usize> {
        windows
            .iter()
            .map(|f| {
                let z: [f64; FEATURES] = std::array::from_fn(|d| (f[d] - self.mean[d]) / self.std[d]);
                let scores: Vec<f64> = self.weights.iter().zip(&self.bias).map(|(w, b)| b + w.iter().zip(&z).map(|(a, b)| a * b).sum::<f64>()).collect();
                (0..scores.len()).max_by(|&a, &b| scores[a].total_cmp(&scores[b]).then(b.cmp(&a))).expect("two classes or more")
            })
            .collect()
    }

    /// Windows per kind over every person of `scenes` (windows every `stride` frames).
    pub fn histogram(&self, scenes: &[&Scene], stride: usize) -> Result<Vec<usize>> {
        let mut h = vec![0; self.labels.len()];
        for s in scenes {
            for c in self.classify(&scene_windows(s, stride)?) {
                h[c] += 1;
            }
        }
        Ok(h)
    }

    /// Fraction of windows of labelled scenes classified as their kind, and the windows.
    pub fn accuracy(&self, examples: &[(&Scene, &str)], stride: usize) -> Result<(f64, usize)> {
        let (mut right, mut all) = (0, 0);
        for (s, l) in examples {
            let want = self.labels.iter().position(|k| k == l);
            let got = self.classify(&scene_windows(s, stride)?);
            all += got.len();
            right += got.iter().filter(|&&c| Some(c) == want).count();
        }
        if all == 0 {
            bail!("motion kinds: no window of {WINDOW_S} s to measure accuracy on");
        }
        Ok((right as f64 / all as f64, all))
    }
}

fn softmax(w: &[Vec<f64>], f: &[f64; FEATURES]) -> Vec<f64> {
    let s: Vec<f64> = w.iter().map(|r| r[FEATURES] + r[..FEATURES].iter().zip(f).map(|(a, b)| a * b).sum::<f64>()).collect();
    let m = s.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let e: Vec<f64> = s.iter().map(|v| (v - m).exp()).collect();
    let t: f64 = e.iter().sum();
    e.into_iter().map(|v| v / t).collect()
}

/// The kinds of one set of motion against a reference set: both distributions and their JS
/// distance (natural log, [`js_distance`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KindDistribution {
    /// Kind names.
    pub labels: Vec<String>,
    /// Windows per kind, scored motion.
    pub windows: Vec<usize>,
    /// Windows per kind, reference motion.
    pub reference_windows: Vec<usize>,
    /// JS distance between the two normalized histograms.
    pub js: f64,
}

impl KindDistribution {
    /// Compares two histograms of the same classifier.
    pub fn new(labels: &[String], windows: Vec<usize>, reference_windows: Vec<usize>) -> Result<Self> {
        let f = |v: &[usize]| v.iter().map(|&n| n as f64).collect::<Vec<_>>();
        if windows.iter().sum::<usize>() == 0 || reference_windows.iter().sum::<usize>() == 0 {
            bail!("motion kinds: no window of {WINDOW_S} s to classify (the scored or the reference motion is too short)");
        }
        let js = js_distance(&f(&windows), &f(&reference_windows))?;
        Ok(Self { labels: labels.to_vec(), windows, reference_windows, js })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kinds_come_from_bandai_names() {
        let kind = |n: &str| bandai_kind(n);
        assert_eq!(kind("dataset-2_walk-turn-left_active_001").as_deref(), Some("walk-turn"));
        assert_eq!(kind("dataset-2_run_normal_012").as_deref(), Some("run"));
        assert_eq!(kind("dataset-2_walk_normal_012").as_deref(), Some("walk"));
        assert_eq!(kind("dataset-2_wave-left-hand_youthful_002").as_deref(), Some("wave"));
        assert_eq!(kind("dataset-2_raise-up-both-hands_elderly_002").as_deref(), Some("raise-up"));
        assert_eq!(kind("TS16"), None);
        assert_eq!(FEATURES, 97);
        assert_eq!(window_frames(), 60);
    }

    #[test]
    fn equal_histograms_are_at_distance_zero_and_disjoint_ones_at_the_maximum() {
        let l = vec!["a".to_string(), "b".to_string()];
        assert_eq!(KindDistribution::new(&l, vec![3, 1], vec![6, 2]).unwrap().js, 0.0);
        let d = KindDistribution::new(&l, vec![3, 0], vec![0, 2]).unwrap().js;
        assert!((d - super::super::JS_DISTANCE_MAX).abs() < 1e-12);
        assert!(KindDistribution::new(&l, vec![0, 0], vec![0, 2]).is_err());
    }
}
