//! Distances between forecasts and ground truth (METHOD.md §5 "short-horizon" and
//! "stochastic"; paper Tables 7.1/7.2), in metres.
//!
//! Notation: forecast `x̂_{k,t,p,j}` (sample k of K, forecast frame t, person p, joint j),
//! ground truth `x_{t,p,j}`, hip midpoint `m_{t,p} = ½(x_{t,p,L} + x_{t,p,R})` (3D, body-frame
//! joints of the skeleton), `‖·‖` Euclidean.
//!
//! # Pose errors at a horizon ([`pose_error_curve`], [`mpjpe_at_horizons`])
//! | [`PoseError`] | `e_k(t)` |
//! |---|---|
//! | `Global` | `mean_{p,j} ‖x̂_{k,t,p,j} − x_{t,p,j}‖` (MPJPE) |
//! | `Root` | `mean_p ‖m̂_{k,t,p} − m_{t,p}‖` |
//! | `RootAligned` | `mean_{p,j} ‖(x̂_{k,t,p,j} − m̂_{k,t,p}) − (x_{t,p,j} − m_{t,p})‖` |
//!
//! A horizon of `h` seconds is forecast frame `round(h·fps) − 1` ([`super::horizon_frame`]);
//! one past the forecast gives `None`. [`SampleStats`] holds `mean_k e_k(t)` and
//! `min_k e_k(t)` (best of K: a sample is a whole scene, so all persons come from the same
//! sample).
//!
//! # Stochastic metrics (DLow / Yuan & Kitani 2020 definitions, per person, over the pose
//! vector `X_{t,p} ∈ ℝ^{3J}`)
//! - ADE = `min_k mean_{t,p} ‖X̂_{k,t,p} − X_{t,p}‖`;
//! - FDE = `min_k mean_p ‖X̂_{k,T−1,p} − X_{T−1,p}‖` (last forecast frame);
//! - APD = `mean_p mean_{k≠l} ‖X̂_{k,·,p} − X̂_{l,·,p}‖`, the norm over the whole flattened
//!   forecast of the person (all frames and joints); 0 for K = 1;
//! - MMADE / MMFDE: the same ADE / FDE against each of a set of *alternative futures* `Y^a`
//!   (ground-truth continuations of other, similar observations — in DLow, every test
//!   sequence whose last observed pose lies within a distance threshold of this one's),
//!   averaged over the set: `MMADE = mean_a min_k mean_{t,p} ‖X̂_{k,t,p} − Y^a_{t,p}‖`. The caller
//!   chooses the set; an empty set gives `None`.
//!
//! # Speed ([`mean_joint_speed`])
//! `v(t) = fps · mean_{p,j} ‖x_{t+1,p,j} − x_{t,p,j}‖` in m/s, `t = 0..frames−2`.

use super::horizon_frame;
use crate::data::rotation::norm;
use crate::{bail, Result};
use ndarray::{Array2, ArrayView4, ArrayView5, Axis};
use rayon::prelude::*;

/// Which pose error [`pose_error_curve`] measures (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PoseError {
    /// All joints, world positions (MPJPE).
    Global,
    /// The hip midpoint only.
    Root,
    /// All joints after subtracting each pose's own hip midpoint.
    RootAligned,
}

/// Mean and best (minimum) over K samples of an error.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SampleStats {
    /// Mean over samples.
    pub mean: f64,
    /// Best of K: the smallest error of any sample.
    pub best: f64,
}

/// Stochastic forecast metrics of one scene (module docs), metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StochasticErrors {
    /// Average pairwise distance between samples (diversity).
    pub apd: f64,
    /// Average displacement error, best sample.
    pub ade: f64,
    /// Final displacement error, best sample.
    pub fde: f64,
    /// Multimodal ADE over the alternative futures (`None` without alternatives).
    pub mmade: Option<f64>,
    /// Multimodal FDE over the alternative futures (`None` without alternatives).
    pub mmfde: Option<f64>,
}

fn check_pair(forecasts: &ArrayView5<f32>, truth: &ArrayView4<f32>, what: &str) -> Result<()> {
    let (k, f, p, j, three) = forecasts.dim();
    if k == 0 || f == 0 || p == 0 || j == 0 || three != 3 {
        bail!("{what}: forecasts have shape [{k}, {f}, {p}, {j}, {three}], expected non-empty [samples, frames, persons, joints, 3]");
    }
    if truth.dim() != (f, p, j, 3) {
        let (a, b, c, d) = truth.dim();
        bail!("{what}: ground truth has shape [{a}, {b}, {c}, {d}], the forecasts' frames are [{f}, {p}, {j}, 3]");
    }
    Ok(())
}

/// Per-sample, per-frame pose error (module docs).
///
/// # Shapes
/// - `forecasts`: `[K, frames, persons, joints, 3]`; `truth`: `[frames, persons, joints, 3]`;
///   output `[K, frames]`, metres.
pub fn pose_error_curve(forecasts: ArrayView5<f32>, truth: ArrayView4<f32>, left: usize, right: usize, kind: PoseError) -> Result<Array2<f64>> {
    check_pair(&forecasts, &truth, "pose error")?;
    let (k, f, p, j, _) = forecasts.dim();
    if left >= j || right >= j {
        bail!("pose error: body-frame joints ({left}, {right}) out of range for {j} joints");
    }
    let mid = |x: ndarray::ArrayView2<f32>| -> [f64; 3] { std::array::from_fn(|d| 0.5 * (x[[left, d]] as f64 + x[[right, d]] as f64)) };
    let rows: Vec<Vec<f64>> = (0..k)
        .into_par_iter()
        .map(|s| {
            (0..f)
                .map(|t| {
                    let mut sum = 0.0;
                    for pp in 0..p {
                        let a = forecasts.slice(ndarray::s![s, t, pp, .., ..]);
                        let b = truth.slice(ndarray::s![t, pp, .., ..]);
                        let (ma, mb) = (mid(a), mid(b));
                        match kind {
                            PoseError::Root => sum += norm(std::array::from_fn(|d| ma[d] - mb[d])),
                            PoseError::Global | PoseError::RootAligned => {
                                let (oa, ob) = if kind == PoseError::Global { ([0.0; 3], [0.0; 3]) } else { (ma, mb) };
                                for jj in 0..j {
                                    sum += norm(std::array::from_fn(|d| (a[[jj, d]] as f64 - oa[d]) - (b[[jj, d]] as f64 - ob[d])));
                                }
                            }
                        }
                    }
                    sum / (p * if kind == PoseError::Root { 1 } else { j }) as f64
                })
                .collect()
        })
        .collect();
    Ok(Array2::from_shape_fn((k, f), |(s, t)| rows[s][t]))
}

/// Pose error at horizons given in seconds after the last observed frame (module docs):
/// mean and best over the K samples, `None` where the horizon is beyond the forecast.
///
/// # Shapes
/// - `forecasts`: `[K, frames, persons, joints, 3]` (frame 0 = first forecast frame);
///   `truth`: `[frames, persons, joints, 3]`; output `[horizons]`.
pub fn mpjpe_at_horizons(
    forecasts: ArrayView5<f32>,
    truth: ArrayView4<f32>,
    left: usize,
    right: usize,
    fps: f64,
    horizons_s: &[f64],
    kind: PoseError,
) -> Result<Vec<Option<SampleStats>>> {
    let curve = pose_error_curve(forecasts, truth, left, right, kind)?;
    let (k, f) = curve.dim();
    Ok(horizons_s
        .iter()
        .map(|&h| {
            horizon_frame(h, fps, f).map(|t| {
                let col = curve.column(t);
                SampleStats { mean: col.sum() / k as f64, best: col.fold(f64::INFINITY, |m, &v| m.min(v)) }
            })
        })
        .collect())
}

/// `‖X̂_{k,t,p} − Y_{t,p}‖` over the 3J pose vector, `[K, frames, persons]` flattened.
fn displacements(forecasts: &ArrayView5<f32>, truth: &ArrayView4<f32>) -> Vec<f64> {
    let (k, f, p, _, _) = forecasts.dim();
    let mut out = Vec::with_capacity(k * f * p);
    for s in 0..k {
        for t in 0..f {
            for pp in 0..p {
                let a = forecasts.slice(ndarray::s![s, t, pp, .., ..]);
                let b = truth.slice(ndarray::s![t, pp, .., ..]);
                out.push(a.iter().zip(b.iter()).map(|(x, y)| (*x as f64 - *y as f64).powi(2)).sum::<f64>().sqrt());
            }
        }
    }
    out
}

/// Average displacement error: `min_k mean_{t,p} ‖X̂_{k,t,p} − X_{t,p}‖` (module docs).
///
/// # Shapes
/// - `forecasts`: `[K, frames, persons, joints, 3]`; `truth`: `[frames, persons, joints, 3]`.
pub fn ade(forecasts: ArrayView5<f32>, truth: ArrayView4<f32>) -> Result<f64> {
    check_pair(&forecasts, &truth, "ADE")?;
    let (_, f, p, _, _) = forecasts.dim();
    let d = displacements(&forecasts, &truth);
    Ok(d.chunks_exact(f * p).map(|c| c.iter().sum::<f64>() / (f * p) as f64).fold(f64::INFINITY, f64::min))
}

/// Final displacement error: `min_k mean_p ‖X̂_{k,T−1,p} − X_{T−1,p}‖` (module docs).
///
/// # Shapes
/// - `forecasts`: `[K, frames, persons, joints, 3]`; `truth`: `[frames, persons, joints, 3]`.
pub fn fde(forecasts: ArrayView5<f32>, truth: ArrayView4<f32>) -> Result<f64> {
    check_pair(&forecasts, &truth, "FDE")?;
    let f = forecasts.dim().1;
    let last = forecasts.slice(ndarray::s![.., f - 1..f, .., .., ..]);
    ade(last, truth.slice(ndarray::s![f - 1..f, .., .., ..]))
}

/// Average pairwise distance between samples: `mean_p mean_{k≠l} ‖X̂_{k,·,p} − X̂_{l,·,p}‖`
/// over each person's whole flattened forecast; 0 for a single sample.
///
/// # Shapes
/// - `forecasts`: `[K, frames, persons, joints, 3]`.
pub fn apd(forecasts: ArrayView5<f32>) -> Result<f64> {
    let (k, f, p, j, three) = forecasts.dim();
    if k == 0 || f == 0 || p == 0 || j == 0 || three != 3 {
        bail!("APD: forecasts have shape [{k}, {f}, {p}, {j}, {three}], expected non-empty [samples, frames, persons, joints, 3]");
    }
    if k == 1 {
        return Ok(0.0);
    }
    let mut total = 0.0;
    for pp in 0..p {
        let x = forecasts.index_axis(Axis(2), pp); // [K, frames, joints, 3]
        for a in 0..k {
            for b in a + 1..k {
                let d: f64 = x.index_axis(Axis(0), a).iter().zip(x.index_axis(Axis(0), b).iter()).map(|(u, v)| (*u as f64 - *v as f64).powi(2)).sum();
                total += 2.0 * d.sqrt();
            }
        }
    }
    Ok(total / (p * k * (k - 1)) as f64)
}

/// Multimodal ADE: the mean over `alternatives` of [`ade`] against each (module docs);
/// `None` for an empty set.
///
/// # Shapes
/// - `forecasts`: `[K, frames, persons, joints, 3]`; each alternative `[frames, persons, joints, 3]`.
pub fn mmade(forecasts: ArrayView5<f32>, alternatives: &[ArrayView4<f32>]) -> Result<Option<f64>> {
    if alternatives.is_empty() {
        return Ok(None);
    }
    let mut s = 0.0;
    for a in alternatives {
        s += ade(forecasts.view(), a.view())?;
    }
    Ok(Some(s / alternatives.len() as f64))
}

/// Multimodal FDE: the mean over `alternatives` of [`fde`] against each; `None` for an empty set.
///
/// # Shapes
/// - `forecasts`: `[K, frames, persons, joints, 3]`; each alternative `[frames, persons, joints, 3]`.
pub fn mmfde(forecasts: ArrayView5<f32>, alternatives: &[ArrayView4<f32>]) -> Result<Option<f64>> {
    if alternatives.is_empty() {
        return Ok(None);
    }
    let mut s = 0.0;
    for a in alternatives {
        s += fde(forecasts.view(), a.view())?;
    }
    Ok(Some(s / alternatives.len() as f64))
}

/// APD, ADE, FDE, MMADE and MMFDE of one scene.
///
/// # Shapes
/// - `forecasts`: `[K, frames, persons, joints, 3]`; `truth` and each alternative:
///   `[frames, persons, joints, 3]`.
pub fn stochastic_errors(forecasts: ArrayView5<f32>, truth: ArrayView4<f32>, alternatives: &[ArrayView4<f32>]) -> Result<StochasticErrors> {
    Ok(StochasticErrors {
        apd: apd(forecasts.view())?,
        ade: ade(forecasts.view(), truth.view())?,
        fde: fde(forecasts.view(), truth.view())?,
        mmade: mmade(forecasts.view(), alternatives)?,
        mmfde: mmfde(forecasts.view(), alternatives)?,
    })
}

/// The largest distance any joint of any person moves between frames `a` and `b` (m).
///
/// # Shapes
/// - `positions`: `[frames, persons, joints, 3]`, `a`, `b` < frames.
pub fn largest_joint_move(positions: ArrayView4<f32>, a: usize, b: usize) -> f64 {
    let (_, np, nj, _) = positions.dim();
    let mut m = 0f64;
    for p in 0..np {
        for j in 0..nj {
            let d: f64 = (0..3).map(|k| (positions[[b, p, j, k]] - positions[[a, p, j, k]]) as f64).map(|v| v * v).sum();
            m = m.max(d.sqrt());
        }
    }
    m
}

/// The largest frame-to-frame joint move of a sequence (m; 0 for one frame).
///
/// # Shapes
/// - `positions`: `[frames, persons, joints, 3]`.
pub fn largest_frame_step(positions: ArrayView4<f32>) -> f64 {
    (1..positions.dim().0).map(|f| largest_joint_move(positions, f - 1, f)).fold(0.0, f64::max)
}

/// Mean horizontal speed (m/s) of the hip midpoint (joints `left`, `right`) over every person
/// and frame step.
///
/// # Shapes
/// - `positions`: `[frames ≥ 2, persons, joints, 3]`.
pub fn mean_root_speed(positions: ArrayView4<f32>, left: usize, right: usize, fps: f64) -> Result<f64> {
    let (nf, np, nj, _) = positions.dim();
    if nf < 2 || np == 0 || left >= nj || right >= nj {
        bail!("root speed: {nf} frames, {np} persons, joints {left}/{right} of {nj}");
    }
    let mid = |f: usize, p: usize, k: usize| 0.5 * (positions[[f, p, left, k]] as f64 + positions[[f, p, right, k]] as f64);
    let mut sum = 0.0;
    for p in 0..np {
        for f in 1..nf {
            sum += (mid(f, p, 0) - mid(f - 1, p, 0)).hypot(mid(f, p, 1) - mid(f - 1, p, 1));
        }
    }
    Ok(sum * fps / ((nf - 1) * np) as f64)
}

/// Average joint speed per frame step, m/s: `fps · mean_{p,j} ‖x_{t+1} − x_t‖`.
///
/// # Shapes
/// - `positions`: `[frames ≥ 2, persons, joints, 3]`; output `[frames − 1]`.
pub fn mean_joint_speed(positions: ArrayView4<f32>, fps: f64) -> Result<Vec<f64>> {
    let (f, p, j, three) = positions.dim();
    if f < 2 || p == 0 || j == 0 || three != 3 {
        bail!("joint speed: positions have shape [{f}, {p}, {j}, {three}], expected [frames ≥ 2, persons, joints, 3]");
    }
    Ok((0..f - 1)
        .map(|t| {
            let (a, b) = (positions.index_axis(Axis(0), t), positions.index_axis(Axis(0), t + 1));
            let mut s = 0.0;
            for (x, y) in a.exact_chunks((1, 1, 3)).into_iter().zip(b.exact_chunks((1, 1, 3))) {
                s += norm(std::array::from_fn(|d| y[[0, 0, d]] as f64 - x[[0, 0, d]] as f64));
            }
            fps * s / (p * j) as f64
        })
        .collect())
}

/// [`mean_joint_speed`] averaged over the K samples of a forecast.
///
/// # Shapes
/// - `forecasts`: `[K ≥ 1, frames ≥ 2, persons, joints, 3]`; output `[frames − 1]`.
pub fn mean_joint_speed_samples(forecasts: ArrayView5<f32>, fps: f64) -> Result<Vec<f64>> {
    let k = forecasts.dim().0;
    if k == 0 {
        bail!("joint speed: no samples");
    }
    let mut acc = vec![0.0; forecasts.dim().1.saturating_sub(1)];
    for s in forecasts.axis_iter(Axis(0)) {
        for (a, v) in acc.iter_mut().zip(mean_joint_speed(s, fps)?) {
            *a += v / k as f64;
        }
    }
    Ok(acc)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{Array4, Array5};

    /// Two joints (hips 0 and 1), one person, two frames. Truth: hips at (0,0,0) and (2,0,0).
    /// Sample 0 shifts everything by (0, 3, 4) at frame 1 → global 5, root 5, aligned 0.
    /// Sample 1 moves joint 1 by (0, 0, 2) at frame 1 → global (0 + 2)/2 = 1, root |(0,0,1)| = 1,
    /// aligned (|(0,0,−1)| + |(0,0,1)|)/2 = 1.
    fn toy() -> (Array5<f32>, Array4<f32>) {
        let truth = Array4::from_shape_fn((2, 1, 2, 3), |(_, _, j, d)| if d == 0 { 2.0 * j as f32 } else { 0.0 });
        let mut f = Array5::zeros((2, 2, 1, 2, 3));
        for k in 0..2 {
            f.index_axis_mut(Axis(0), k).assign(&truth);
        }
        f[[0, 1, 0, 0, 1]] += 3.0;
        f[[0, 1, 0, 0, 2]] += 4.0;
        f[[0, 1, 0, 1, 1]] += 3.0;
        f[[0, 1, 0, 1, 2]] += 4.0;
        f[[1, 1, 0, 1, 2]] += 2.0;
        (f, truth)
    }

    #[test]
    fn pose_errors_match_hand_values() {
        let (f, truth) = toy();
        let g = pose_error_curve(f.view(), truth.view(), 0, 1, PoseError::Global).unwrap();
        assert_eq!(g, ndarray::array![[0.0, 5.0], [0.0, 1.0]]);
        let r = pose_error_curve(f.view(), truth.view(), 0, 1, PoseError::Root).unwrap();
        assert_eq!(r, ndarray::array![[0.0, 5.0], [0.0, 1.0]]);
        let a = pose_error_curve(f.view(), truth.view(), 0, 1, PoseError::RootAligned).unwrap();
        assert_eq!(a, ndarray::array![[0.0, 0.0], [0.0, 1.0]]);
        // At 2 fps, 1 s is forecast frame 1; 2 s is beyond the forecast.
        let h = mpjpe_at_horizons(f.view(), truth.view(), 0, 1, 2.0, &[0.5, 1.0, 2.0], PoseError::Global).unwrap();
        assert_eq!(h, vec![Some(SampleStats { mean: 0.0, best: 0.0 }), Some(SampleStats { mean: 3.0, best: 1.0 }), None]);
        assert!(pose_error_curve(f.view(), truth.slice(ndarray::s![..1, .., .., ..]), 0, 1, PoseError::Global).is_err());
    }

    /// Pose-vector displacements: sample 0 is (0, |(0,3,4,0,3,4)| = √50) per frame, sample 1
    /// (0, 2). ADE = min(√50/2, 1) = 1; FDE = min(√50, 2) = 2. APD: the two samples differ at
    /// frame 1 by (0,3,4) and (0,3,2) → ‖·‖ = √(25 + 13) = √38.
    #[test]
    fn stochastic_metrics_match_hand_values() {
        let (f, truth) = toy();
        let e = stochastic_errors(f.view(), truth.view(), &[]).unwrap();
        assert!((e.ade - 1.0).abs() < 1e-12 && (e.fde - 2.0).abs() < 1e-12, "{e:?}");
        assert!((e.apd - 38f64.sqrt()).abs() < 1e-12, "{e:?}");
        assert_eq!((e.mmade, e.mmfde), (None, None));
        // Alternatives: the truth itself and sample 0 → MMADE = (1 + 0)/2, MMFDE = (2 + 0)/2.
        let alt0 = f.index_axis(Axis(0), 0);
        let e = stochastic_errors(f.view(), truth.view(), &[truth.view(), alt0]).unwrap();
        assert!((e.mmade.unwrap() - 0.5).abs() < 1e-12 && (e.mmfde.unwrap() - 1.0).abs() < 1e-12, "{e:?}");
        assert_eq!(apd(f.slice(ndarray::s![..1, .., .., .., ..])).unwrap(), 0.0);
    }

    #[test]
    fn joint_speed_of_known_motion() {
        // Joint 0 moves 0.1 m/frame along x, joint 1 0.2 m/frame along z; 30 fps → (3 + 6)/2 m/s.
        let x = Array4::from_shape_fn((4, 1, 2, 3), |(t, _, j, d)| match (j, d) {
            (0, 0) => 0.1 * t as f32,
            (1, 2) => 0.2 * t as f32,
            _ => 0.0,
        });
        let v = mean_joint_speed(x.view(), 30.0).unwrap();
        assert_eq!(v.len(), 3);
        assert!(v.iter().all(|s| (s - 4.5).abs() < 1e-5), "{v:?}");
        let s = mean_joint_speed_samples(x.view().insert_axis(Axis(0)), 30.0).unwrap();
        assert_eq!(s, v);
        assert!(mean_joint_speed(x.slice(ndarray::s![..1, .., .., ..]), 30.0).is_err());
    }

    #[test]
    fn root_speed_and_largest_steps_of_known_motion() {
        // Two hips (joints 0, 1) moving 0.1 m/frame along x and 0.05 along y: 30 fps →
        // √(0.1² + 0.05²)·30 m/s; joint 2 jumps 0.5 m along z between frames 1 and 2.
        let x = Array4::from_shape_fn((4, 1, 3, 3), |(t, _, j, d)| match (j, d) {
            (0 | 1, 0) => 0.1 * t as f32 + j as f32 * 0.3,
            (0 | 1, 1) => 0.05 * t as f32,
            (2, 2) if t >= 2 => 0.5,
            _ => 0.0,
        });
        let v = mean_root_speed(x.view(), 0, 1, 30.0).unwrap();
        assert!((v - 0.1f64.hypot(0.05) * 30.0).abs() < 1e-5, "{v}");
        assert!((largest_joint_move(x.view(), 1, 2) - 0.5).abs() < 1e-6);
        assert!((largest_joint_move(x.view(), 0, 1) - 0.1f64.hypot(0.05)).abs() < 1e-6);
        assert!((largest_frame_step(x.view()) - 0.5).abs() < 1e-6);
        assert!(mean_root_speed(x.slice(ndarray::s![..1, .., .., ..]), 0, 1, 30.0).is_err());
    }
}
