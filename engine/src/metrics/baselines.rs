//! Forecasting baselines: the reference points of every metric.
//!
//! With observed poses `x_0 … x_{T−1}` (per person and joint) and forecast frame `i = 0, 1, …`:
//!
//! | baseline | forecast |
//! |---|---|
//! | [`zero_velocity`] | `x̂_i = x_{T−1}` |
//! | [`constant_velocity`] | `x̂_i = x_{T−1} + (i + 1)·(x_{T−1} − x_{T−2})` |
//! | [`nearest_continuation`] | real motion from a database, matched and continued (below) |
//!
//! # Nearest real continuation
//! Per person: the last κ frames of the sequence so far (observed, then forecast) form a
//! motion word in the body frame of its first frame (exactly as NDMS words; see
//! [`super::ndms`]). Its exact nearest database word *that is followed by at least κ valid
//! frames* is found (shorter continuations let a forecast get stuck re-matching the last words
//! of a track), and the frames following that word in its database track are copied — mapped
//! rigidly from the body frame of the database word's *last* frame into that of the query's
//! last frame, `x̂ = Rz(h_q − h_db)·(p − (r_db, 0)) + (r_q, 0)`, so that the continuation moves
//! on from where the query ends — until the track ends, a frame is invalid, or the horizon is
//! reached. Then the last κ frames are matched again, and so on. Heights are
//! copied unchanged. Use a database that does not contain the scene being forecast (e.g. the
//! train split), or the "forecast" is the ground truth.

use super::ndms::{anchor_or_level, NdmsDatabase};
use crate::{bail, Result};
use ndarray::{s, Array4, ArrayView4, Axis};
use rayon::prelude::*;

fn check_observed(observed: &ArrayView4<f32>, min_frames: usize, what: &str) -> Result<()> {
    let (f, p, j, three) = observed.dim();
    if three != 3 || p == 0 || j == 0 {
        bail!("{what}: observed poses have shape [{f}, {p}, {j}, {three}], expected [frames, persons, joints, 3]");
    }
    if f < min_frames {
        bail!("{what}: needs at least {min_frames} observed frame(s), got {f}");
    }
    Ok(())
}

/// Zero velocity: the last observed pose, repeated `horizon` times.
///
/// # Shapes
/// - `observed`: `[frames ≥ 1, persons, joints, 3]`; output `[horizon, persons, joints, 3]`.
pub fn zero_velocity(observed: ArrayView4<f32>, horizon: usize) -> Result<Array4<f32>> {
    check_observed(&observed, 1, "zero-velocity baseline")?;
    let (f, p, j, _) = observed.dim();
    let last = observed.index_axis(Axis(0), f - 1);
    Ok(last.broadcast((horizon, p, j, 3)).expect("same trailing shape").to_owned())
}

/// Constant velocity: every joint keeps its last observed velocity `x_{T−1} − x_{T−2}`
/// (per frame), extrapolated linearly (module docs). Arithmetic in f64.
///
/// # Shapes
/// - `observed`: `[frames ≥ 2, persons, joints, 3]`; output `[horizon, persons, joints, 3]`.
pub fn constant_velocity(observed: ArrayView4<f32>, horizon: usize) -> Result<Array4<f32>> {
    check_observed(&observed, 2, "constant-velocity baseline")?;
    let (f, p, j, _) = observed.dim();
    let last = observed.index_axis(Axis(0), f - 1);
    let prev = observed.index_axis(Axis(0), f - 2);
    Ok(Array4::from_shape_fn((horizon, p, j, 3), |(i, pp, jj, k)| {
        let (a, b) = (last[[pp, jj, k]] as f64, prev[[pp, jj, k]] as f64);
        (a + (i + 1) as f64 * (a - b)) as f32
    }))
}

/// Nearest real continuation from `db` (module docs), for every person independently.
///
/// # Shapes
/// - `observed`: `[frames ≥ κ, persons, joints, 3]` on the database's skeleton; output
///   `[horizon, persons, joints, 3]`.
pub fn nearest_continuation(db: &NdmsDatabase, observed: ArrayView4<f32>, horizon: usize) -> Result<Array4<f32>> {
    let kappa = db.word_length();
    check_observed(&observed, kappa, "nearest-continuation baseline")?;
    let (nobs, persons, nj, _) = observed.dim();
    if nj != db.skeleton().num_joints() {
        bail!("nearest-continuation baseline: poses have {nj} joints, the database's skeleton {} has {}", db.skeleton().name, db.skeleton().num_joints());
    }
    if let Some(i) = observed.iter().position(|v| !v.is_finite()) {
        bail!("nearest-continuation baseline: non-finite observed position at frame {}", i / (persons * nj * 3));
    }
    // Words followed by at least κ valid frames.
    let allowed: Vec<bool> = (0..db.num_words())
        .map(|w| {
            let (t, s) = db.word_ref(w);
            let t = &db.tracks[t];
            s + 2 * kappa <= t.frames() && t.valid[s + kappa..s + 2 * kappa].iter().all(|&v| v)
        })
        .collect();
    if !allowed.iter().any(|&a| a) {
        bail!("nearest-continuation baseline: no database word is followed by {kappa} valid frames");
    }
    let per_person: Vec<Result<Vec<f32>>> = (0..persons)
        .into_par_iter()
        .map(|p| {
            let mut seq: Vec<f32> = observed.slice(s![.., p, .., ..]).iter().copied().collect();
            let pose_len = nj * 3;
            let target = nobs + horizon;
            let mut q = vec![0.0; db.dim()];
            while seq.len() / pose_len < target {
                let start = seq.len() / pose_len - kappa;
                db.track_word(&seq, start, &mut q);
                let Some(n) = db.nearest_where(&q, Some(&allowed))?[0] else {
                    bail!("nearest-continuation baseline: no neighbour for person {p} at frame {start}");
                };
                let (t, s) = db.word_ref(n.index);
                let track = &db.tracks[t];
                // Map from the words' last frames, so the continuation starts where the query ends.
                let (l, r) = (db.skeleton().left, db.skeleton().right);
                let last = seq.len() / pose_len - 1;
                let qa = anchor_or_level(&seq[last * pose_len..], l, r);
                let da = anchor_or_level(&track.pos[(s + kappa - 1) * pose_len..(s + kappa) * pose_len], l, r);
                let (sn, cs) = (qa.heading - da.heading).sin_cos();
                let mut f = s + kappa;
                while f < track.frames() && track.valid[f] && seq.len() / pose_len < target {
                    for v in track.pos[f * pose_len..(f + 1) * pose_len].chunks_exact(3) {
                        let (dx, dy) = (v[0] as f64 - da.root[0], v[1] as f64 - da.root[1]);
                        seq.push((qa.root[0] + cs * dx - sn * dy) as f32);
                        seq.push((qa.root[1] + sn * dx + cs * dy) as f32);
                        seq.push(v[2]);
                    }
                    f += 1;
                }
            }
            Ok(seq.split_off(nobs * pose_len))
        })
        .collect();
    let mut out = Array4::<f32>::zeros((horizon, persons, nj, 3));
    for (p, seq) in per_person.into_iter().enumerate() {
        let seq = seq?;
        let v = ndarray::ArrayView3::from_shape((horizon, nj, 3), &seq).expect("horizon frames");
        out.slice_mut(s![.., p, .., ..]).assign(&v);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::distance::mean_joint_speed;
    use crate::metrics::ndms::tests::random_motion;
    use crate::metrics::ndms::{NdmsConfig, NdmsDatabase};

    #[test]
    fn zero_velocity_has_zero_speed() {
        let scene = random_motion(40, 2, 20);
        let f = zero_velocity(scene.positions.view(), 25).unwrap();
        assert_eq!(f.dim(), (25, 2, 17, 3));
        assert!(mean_joint_speed(f.view(), 30.0).unwrap().iter().all(|&v| v == 0.0));
        assert_eq!(f.slice(s![7, .., .., ..]), scene.positions.slice(s![39, .., .., ..]));
        assert!(zero_velocity(scene.positions.slice(s![..0, .., .., ..]), 3).is_err());
    }

    #[test]
    fn constant_velocity_reproduces_constant_velocity_motion() {
        // x(t) = x0 + t·v per joint, with values exact in f32.
        let motion = Array4::from_shape_fn((60, 2, 4, 3), |(t, p, j, k)| (p * 8 + j * 2 + k) as f32 * 0.5 + t as f32 * ((j + k) as f32 * 0.25 - 0.5));
        let obs = motion.slice(s![..20, .., .., ..]);
        let f = constant_velocity(obs, 40).unwrap();
        assert_eq!(f, motion.slice(s![20.., .., .., ..]));
        assert!(constant_velocity(motion.slice(s![..1, .., .., ..]), 3).is_err());
    }

    /// Continuing a scene that is in the database reproduces it (the observed end matches the
    /// scene itself at distance 0), also after a rigid move; past the end of the track the
    /// forecast chains on other matches.
    #[test]
    fn nearest_continuation_continues_real_motion() {
        let a = random_motion(300, 2, 21);
        let b = random_motion(200, 1, 22);
        let db = NdmsDatabase::build(&[&a, &b], &NdmsConfig::default()).unwrap();
        let obs = a.positions.slice(s![..100, .., .., ..]);
        let f = nearest_continuation(&db, obs, 150).unwrap();
        let want = a.positions.slice(s![100..250, .., .., ..]);
        let err = (&f - &want).iter().fold(0f32, |m, v| m.max(v.abs()));
        assert!(err < 1e-5, "{err}");
        let mut moved = a.clone();
        let (sn, cs) = 2.0f64.sin_cos();
        moved.transform([[cs, -sn, 0.0], [sn, cs, 0.0], [0.0, 0.0, 1.0]], [-4.0, 7.0, 0.0]);
        let f = nearest_continuation(&db, moved.positions.slice(s![..100, .., .., ..]), 400).unwrap();
        assert_eq!(f.dim(), (400, 2, 17, 3));
        let err = (&f.slice(s![..150, .., .., ..]) - &moved.positions.slice(s![100..250, .., .., ..])).iter().fold(0f32, |m, v| m.max(v.abs()));
        assert!(err < 1e-3, "{err}");
        assert!(f.iter().all(|v| v.is_finite()));
        // Chained segments stay near the person: no jump larger than 0.5 m per frame.
        let speed = mean_joint_speed(f.view(), 1.0).unwrap();
        assert!(speed.iter().all(|&v| v < 0.5), "{:?}", speed.iter().fold(0f64, |m, &v| m.max(v)));
        assert!(nearest_continuation(&db, obs.slice(s![..5, .., .., ..]), 10).is_err());
    }

    /// MuPoTS test scenes: observe 1 s (30 frames), forecast the rest with each baseline, score
    /// NDMS against the test database (the real-motion level is in `ndms::tests`).
    #[test]
    fn mupots_baseline_ndms() {
        let Some(ds) = crate::metrics::ndms::tests::mupots() else { return };
        let test: Vec<&crate::Scene> = ds.split(crate::Split::Test).collect();
        let train: Vec<&crate::Scene> = ds.split(crate::Split::Train).collect();
        let db = NdmsDatabase::build(&test, &NdmsConfig::default()).unwrap();
        let train_db = NdmsDatabase::build(&train, &NdmsConfig::default()).unwrap();
        let n_obs = 30;
        let mut curves: [Vec<_>; 3] = Default::default();
        for s in &test {
            let obs = s.positions.slice(s![..n_obs, .., .., ..]);
            let horizon = s.num_frames() - n_obs;
            let forecasts =
                [zero_velocity(obs, horizon).unwrap(), constant_velocity(obs, horizon).unwrap(), nearest_continuation(&train_db, obs, horizon).unwrap()];
            for (c, f) in curves.iter_mut().zip(forecasts) {
                let full = ndarray::concatenate(Axis(0), &[obs.view(), f.view()]).unwrap();
                c.extend(db.score_forecasts(full.view().insert_axis(Axis(0)), n_obs).unwrap().curves);
            }
        }
        let [zv, cv, nc] = curves.map(|c| crate::metrics::NdmsScore::from_curves(c).mean);
        println!(
            "MuPoTS test, 1 s observed, NDMS vs test database: zero velocity {zv:.4}, constant velocity {cv:.4}, nearest continuation (train database) {nc:.4}"
        );
        assert!(zv < 0.1 && cv > 0.0 && cv < 1.0 && nc > 0.0 && nc < 1.0, "{zv} {cv} {nc}");
    }
}
