//! Physical plausibility of a forecast, without ground truth.
//!
//! For positions `x_{t,p,j}` at `fps` frames per second:
//!
//! | metric | definition | unit |
//! |---|---|---|
//! | [`bone_length_deviation`] | `1000 · mean_{t,p,b} |ℓ_{t,p,b} − ℓ̄_{p,b}|`, `ℓ̄` = mean length of bone b of person p over the *observed* frames | mm |
//! | [`mean_acceleration`] | `fps² · mean_{t,p,j} ‖x_{t+1} − 2x_t + x_{t−1}‖` | m/s² |
//! | [`mean_jerk`] | `fps³ · mean_{t,p,j} ‖x_{t+2} − 3x_{t+1} + 3x_t − x_{t−1}‖` | m/s³ |
//! | [`foot_sliding`] | `fps · mean ‖xy(a_{t+1}) − xy(a_t)‖` over the steps where an ankle `a` is at most `h` above its floor at t and t+1 | m/s |
//! | [`speed_histogram_distance`] | per time bin, [`super::js_distance`] between the joint-speed histograms of the forecasts and of a reference | – |
//!
//! Foot sliding: a person's floor is the lowest height of any of its feet over the observed
//! frames; a foot is planted when it is within `h` (default 5 cm, [`FootSlidingConfig`]) of
//! that floor, and a planted foot should not move horizontally. `None` when no foot is ever
//! planted.
//!
//! Speed histograms: the joint speeds `fps·‖x_{t+1,p,j} − x_{t,p,j}‖` of every sequence are
//! grouped by time bin (step `t` falls in bin `⌊t / n⌋`, `n = round(time_bin_s · fps)`) and
//! counted in `bins` equal speed bins over `[0, max_speed)`, faster speeds in the last bin; the
//! same bins are used for forecasts and reference.
//!
//! Acceleration and jerk of a forecast alone ignore the join to the observation: pass the last
//! observed frames in front of it to include that.

use super::js_distance;
use crate::data::Skeleton;
use crate::{bail, Result};
use ndarray::ArrayView4;

fn check(x: &ArrayView4<f32>, min_frames: usize, what: &str) -> Result<()> {
    let (f, p, j, three) = x.dim();
    if f < min_frames || p == 0 || j == 0 || three != 3 {
        bail!("{what}: positions have shape [{f}, {p}, {j}, {three}], expected [frames ≥ {min_frames}, persons, joints, 3]");
    }
    Ok(())
}

fn dist(x: &ArrayView4<f32>, t: usize, p: usize, a: usize, b: usize) -> f64 {
    (0..3).map(|d| (x[[t, p, a, d]] as f64 - x[[t, p, b, d]] as f64).powi(2)).sum::<f64>().sqrt()
}

/// Mean absolute deviation of bone lengths in the forecast from each person's mean bone
/// lengths over the observed frames, in millimetres.
///
/// # Shapes
/// - `observed`: `[frames ≥ 1, persons, joints, 3]`; `forecast`: `[frames ≥ 1, persons, joints, 3]`.
pub fn bone_length_deviation(observed: ArrayView4<f32>, forecast: ArrayView4<f32>, bones: &[(usize, usize)]) -> Result<f64> {
    check(&observed, 1, "bone-length deviation (observed)")?;
    check(&forecast, 1, "bone-length deviation (forecast)")?;
    let (fo, p, j, _) = observed.dim();
    let (ff, pf, jf, _) = forecast.dim();
    if (p, j) != (pf, jf) {
        bail!("bone-length deviation: observed has {p} persons × {j} joints, forecast {pf} × {jf}");
    }
    if bones.is_empty() {
        bail!("bone-length deviation: no bones");
    }
    if let Some(&(a, b)) = bones.iter().find(|&&(a, b)| a >= j || b >= j) {
        bail!("bone-length deviation: bone ({a}, {b}) out of range for {j} joints");
    }
    let mut sum = 0.0;
    for pp in 0..p {
        for &(a, b) in bones {
            let mean = (0..fo).map(|t| dist(&observed, t, pp, a, b)).sum::<f64>() / fo as f64;
            sum += (0..ff).map(|t| (dist(&forecast, t, pp, a, b) - mean).abs()).sum::<f64>();
        }
    }
    Ok(1000.0 * sum / (ff * p * bones.len()) as f64)
}

/// Mean norm of the finite difference with coefficients `c` (applied to frames t..t+c.len()),
/// times `scale`.
fn mean_difference(x: &ArrayView4<f32>, c: &[f64], scale: f64) -> f64 {
    let (f, p, j, _) = x.dim();
    let steps = f + 1 - c.len();
    let mut sum = 0.0;
    for t in 0..steps {
        for pp in 0..p {
            for jj in 0..j {
                let v: [f64; 3] = std::array::from_fn(|d| c.iter().enumerate().map(|(i, w)| w * x[[t + i, pp, jj, d]] as f64).sum());
                sum += (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            }
        }
    }
    scale * sum / (steps * p * j) as f64
}

/// Mean joint acceleration magnitude, m/s² (module docs).
///
/// # Shapes
/// - `positions`: `[frames ≥ 3, persons, joints, 3]`.
pub fn mean_acceleration(positions: ArrayView4<f32>, fps: f64) -> Result<f64> {
    check(&positions, 3, "acceleration")?;
    Ok(mean_difference(&positions, &[1.0, -2.0, 1.0], fps * fps))
}

/// Mean joint jerk magnitude, m/s³ (module docs).
///
/// # Shapes
/// - `positions`: `[frames ≥ 4, persons, joints, 3]`.
pub fn mean_jerk(positions: ArrayView4<f32>, fps: f64) -> Result<f64> {
    check(&positions, 4, "jerk")?;
    Ok(mean_difference(&positions, &[-1.0, 3.0, -3.0, 1.0], fps * fps * fps))
}

/// Foot-sliding settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FootSlidingConfig {
    /// A foot is planted when at most this far (m) above the person's floor (default 0.05).
    pub height: f64,
}

impl Default for FootSlidingConfig {
    fn default() -> Self {
        Self { height: 0.05 }
    }
}

/// The joints foot sliding watches: those named `…ankle…`, else [`Skeleton::foot_joints`].
pub fn ankle_joints(skeleton: &Skeleton) -> Vec<usize> {
    let ankles: Vec<usize> =
        skeleton.joints.iter().enumerate().filter(|(_, n)| crate::data::joints::normalize_joint_name(n).contains("ankle")).map(|(i, _)| i).collect();
    if ankles.is_empty() {
        skeleton.foot_joints()
    } else {
        ankles
    }
}

/// Mean horizontal speed (m/s) of planted feet in the forecast (module docs); `None` when no
/// foot is planted on two consecutive forecast frames.
///
/// # Shapes
/// - `observed`: `[frames ≥ 1, persons, joints, 3]` (sets each person's floor);
///   `forecast`: `[frames, persons, joints, 3]`; `feet`: joint indices (e.g. [`ankle_joints`]).
pub fn foot_sliding(observed: ArrayView4<f32>, forecast: ArrayView4<f32>, feet: &[usize], fps: f64, cfg: &FootSlidingConfig) -> Result<Option<f64>> {
    check(&observed, 1, "foot sliding (observed)")?;
    check(&forecast, 1, "foot sliding (forecast)")?;
    let (_, p, j, _) = observed.dim();
    let (ff, pf, jf, _) = forecast.dim();
    if (p, j) != (pf, jf) {
        bail!("foot sliding: observed has {p} persons × {j} joints, forecast {pf} × {jf}");
    }
    if feet.is_empty() || feet.iter().any(|&a| a >= j) {
        bail!("foot sliding: foot joints {feet:?} are empty or out of range for {j} joints");
    }
    let (mut sum, mut n) = (0.0, 0usize);
    for pp in 0..p {
        let floor = feet.iter().flat_map(|&a| observed.slice(ndarray::s![.., pp, a, 2]).to_vec()).fold(f64::INFINITY, |m, z| m.min(z as f64));
        let top = floor + cfg.height;
        for &a in feet {
            for t in 0..ff.saturating_sub(1) {
                if forecast[[t, pp, a, 2]] as f64 <= top && forecast[[t + 1, pp, a, 2]] as f64 <= top {
                    let dx = forecast[[t + 1, pp, a, 0]] as f64 - forecast[[t, pp, a, 0]] as f64;
                    let dy = forecast[[t + 1, pp, a, 1]] as f64 - forecast[[t, pp, a, 1]] as f64;
                    sum += fps * dx.hypot(dy);
                    n += 1;
                }
            }
        }
    }
    Ok((n > 0).then(|| sum / n as f64))
}

/// Speed-histogram settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpeedHistogramConfig {
    /// Number of speed bins (default 30).
    pub bins: usize,
    /// Upper edge of the speed range, m/s (default 3); faster speeds count in the last bin.
    pub max_speed: f64,
    /// Length of a time bin in seconds (default 1).
    pub time_bin_s: f64,
}

impl Default for SpeedHistogramConfig {
    fn default() -> Self {
        Self { bins: 30, max_speed: 3.0, time_bin_s: 1.0 }
    }
}

/// Joint-speed counts per time bin (module docs), pooled over sequences, persons and joints.
///
/// # Shapes
/// - each sequence: `[frames, persons, joints, 3]`; output `[time bins][cfg.bins]`, as many
///   time bins as the longest sequence needs.
pub fn speed_histograms(sequences: &[ArrayView4<f32>], fps: f64, cfg: &SpeedHistogramConfig) -> Result<Vec<Vec<f64>>> {
    let positive = |v: f64| v > 0.0 && v.is_finite();
    if cfg.bins == 0 || !positive(cfg.max_speed) || !positive(cfg.time_bin_s) || !positive(fps) {
        bail!("speed histogram: need bins ≥ 1, max_speed > 0, time_bin_s > 0 and fps > 0 (got {cfg:?}, fps {fps})");
    }
    let per = ((cfg.time_bin_s * fps).round() as usize).max(1);
    let mut out: Vec<Vec<f64>> = Vec::new();
    for (i, x) in sequences.iter().enumerate() {
        check(x, 1, &format!("speed histogram (sequence {i})"))?;
        let (f, p, j, _) = x.dim();
        for t in 0..f.saturating_sub(1) {
            let b = t / per;
            if out.len() <= b {
                out.resize(b + 1, vec![0.0; cfg.bins]);
            }
            for pp in 0..p {
                for jj in 0..j {
                    let v = fps * (0..3).map(|d| (x[[t + 1, pp, jj, d]] as f64 - x[[t, pp, jj, d]] as f64).powi(2)).sum::<f64>().sqrt();
                    let k = ((v / cfg.max_speed * cfg.bins as f64) as usize).min(cfg.bins - 1);
                    out[b][k] += 1.0;
                }
            }
        }
    }
    Ok(out)
}

/// Jensen–Shannon distance (natural log) between the joint-speed histograms of `forecasts`
/// and `reference`, per time bin of the forecasts; `None` where either has no speed in the bin.
///
/// # Shapes
/// - each sequence: `[frames, persons, joints, 3]`; output `[time bins of the forecasts]`.
pub fn speed_histogram_distance(
    forecasts: &[ArrayView4<f32>],
    reference: &[ArrayView4<f32>],
    fps: f64,
    cfg: &SpeedHistogramConfig,
) -> Result<Vec<Option<f64>>> {
    let a = speed_histograms(forecasts, fps, cfg)?;
    let b = speed_histograms(reference, fps, cfg)?;
    a.iter()
        .enumerate()
        .map(|(i, ha)| match b.get(i) {
            Some(hb) if ha.iter().sum::<f64>() > 0.0 && hb.iter().sum::<f64>() > 0.0 => js_distance(ha, hb).map(Some),
            _ => Ok(None),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::JS_DISTANCE_MAX;
    use ndarray::Array4;

    #[test]
    fn constant_velocity_has_zero_acceleration_and_jerk() {
        // x = x0 + t·v with exactly representable values.
        let x = Array4::from_shape_fn((10, 2, 3, 3), |(t, p, j, d)| (p + j + d) as f32 * 0.5 + t as f32 * 0.25 * (d as f32 - 1.0));
        assert_eq!(mean_acceleration(x.view(), 30.0).unwrap(), 0.0);
        assert_eq!(mean_jerk(x.view(), 30.0).unwrap(), 0.0);
        // x = ½·a·(t/fps)² along z with a = 2 m/s² at 10 fps: second difference a/fps² → 2 m/s²;
        // jerk 0.
        let y = Array4::from_shape_fn((8, 1, 1, 3), |(t, _, _, d)| if d == 2 { (t * t) as f32 / 100.0 } else { 0.0 });
        assert!((mean_acceleration(y.view(), 10.0).unwrap() - 2.0).abs() < 1e-4);
        assert!(mean_jerk(y.view(), 10.0).unwrap() < 1e-3);
        assert!(mean_jerk(y.slice(ndarray::s![..3, .., .., ..]), 10.0).is_err());
    }

    /// One bone of 0.5 m while observed; the forecast stretches it to 0.52 m on half the frames
    /// and keeps it on the others → mean deviation 10 mm.
    #[test]
    fn stretched_bone_gives_known_deviation() {
        let obs = Array4::from_shape_fn((5, 1, 2, 3), |(_, _, j, d)| if j == 1 && d == 2 { 0.5 } else { 0.0 });
        let fc = Array4::from_shape_fn((4, 1, 2, 3), |(t, _, j, d)| {
            if j == 1 && d == 2 {
                if t % 2 == 0 {
                    0.52
                } else {
                    0.5
                }
            } else {
                0.0
            }
        });
        let dev = bone_length_deviation(obs.view(), fc.view(), &[(0, 1)]).unwrap();
        assert!((dev - 10.0).abs() < 1e-4, "{dev}");
        assert!(bone_length_deviation(obs.view(), fc.view(), &[(0, 2)]).is_err());
    }

    /// Ankle 0 stays 2 cm up (floor = 2 cm from the observation) and slides 1 cm/frame along x
    /// at 30 fps → 0.3 m/s; ankle 1 swings 30 cm up and fast (not planted).
    #[test]
    fn sliding_planted_foot_gives_known_speed() {
        let obs = Array4::from_shape_fn((3, 1, 2, 3), |(_, _, _, d)| if d == 2 { 0.02 } else { 0.0 });
        let fc = Array4::from_shape_fn((20, 1, 2, 3), |(t, _, j, d)| match (j, d) {
            (0, 0) => 0.01 * t as f32,
            (0, 2) => 0.02,
            (1, 1) => 0.1 * t as f32,
            (1, 2) => 0.32,
            _ => 0.0,
        });
        let s = foot_sliding(obs.view(), fc.view(), &[0, 1], 30.0, &FootSlidingConfig::default()).unwrap().unwrap();
        assert!((s - 0.3).abs() < 1e-5, "{s}");
        // Nothing planted: None. Ankles are found by name.
        let high = fc.mapv(|v| v + 1.0);
        assert_eq!(foot_sliding(obs.view(), high.view(), &[0, 1], 30.0, &FootSlidingConfig::default()).unwrap(), None);
        assert_eq!(ankle_joints(&Skeleton::mupots17()), vec![10, 13]);
    }

    #[test]
    fn speed_histogram_distance_known_values() {
        let cfg = SpeedHistogramConfig::default();
        // Reference joints move 0.0515 m/frame at 30 fps = 1.545 m/s (bin 15); a still forecast
        // sits in bin 0: disjoint → √ln 2 in each of the 2 one-second time bins.
        let moving = Array4::from_shape_fn((61, 1, 2, 3), |(t, _, _, d)| if d == 0 { 0.0515 * t as f32 } else { 0.0 });
        let still = Array4::<f32>::zeros((61, 1, 2, 3));
        let d = speed_histogram_distance(&[still.view()], &[moving.view()], 30.0, &cfg).unwrap();
        assert_eq!(d.len(), 2);
        assert!(d.iter().all(|v| (v.unwrap() - JS_DISTANCE_MAX).abs() < 1e-12), "{d:?}");
        let same = speed_histogram_distance(&[moving.view()], &[moving.view(), moving.view()], 30.0, &cfg).unwrap();
        assert_eq!(same, vec![Some(0.0), Some(0.0)]);
        // A longer forecast than the reference: no reference speeds in the third bin.
        let long = Array4::<f32>::zeros((70, 1, 2, 3));
        let d = speed_histogram_distance(&[long.view()], &[moving.view()], 30.0, &cfg).unwrap();
        assert_eq!(d.len(), 3);
        assert_eq!(d[2], None);
        let h = speed_histograms(&[moving.view()], 30.0, &cfg).unwrap();
        assert_eq!(h[0][15], 60.0);
    }
}
