//! Up-axis conversion and ground alignment.
//!
//! Camera-frame captures (MuPoTS) are neither upright nor ground-aligned: the camera is tilted
//! and its height unknown. [`align_ground`] fits the floor plane to the lowest foot joint of
//! every valid (frame, person), rotates the scene so that the floor normal is +z and shifts it so
//! that the floor is z = 0.

use super::rotation::{apply, mul, normalize, rotation_between, IDENTITY};
use super::scene::Scene;
use crate::{bail, Result};
use serde::{Deserialize, Serialize};

/// Which source axis points up, as written in `dataset.json` (`up_axis`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpAxis {
    /// Already z up.
    Z,
    /// y up (BVH, most mocap).
    Y,
    /// y down (camera frame: x right, y down, z forward).
    NegY,
}

impl UpAxis {
    /// Parses `z`, `+z`, `y`, `+y` or `-y`.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "z" | "+z" => Ok(UpAxis::Z),
            "y" | "+y" => Ok(UpAxis::Y),
            "-y" => Ok(UpAxis::NegY),
            _ => bail!("unsupported up_axis {s:?} (expected z, y or -y)"),
        }
    }

    /// The proper rotation (det +1) taking this frame to z up.
    pub fn to_z_up(self) -> [[f64; 3]; 3] {
        match self {
            UpAxis::Z => [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            // (x, y, z) ↦ (x, −z, y)
            UpAxis::Y => [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]],
            // (x, y, z) ↦ (x, z, −y)
            UpAxis::NegY => [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]],
        }
    }
}

/// What [`align_ground`] removed.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GroundAlignment {
    /// Angle between the fitted floor normal and +z before alignment, degrees.
    pub tilt_deg: f64,
    /// Height of the floor (under the feet's centre, after rotation) that was subtracted, metres.
    pub floor_height_m: f64,
    /// Number of foot points the plane was fitted to (after outlier trimming).
    pub inliers: usize,
    /// Whether the floor plane's slope refined the body-axis estimate (false when the feet cover
    /// too small an area to tell a slope, or the plane disagrees with the body axis by > 15°).
    pub tilt_fitted: bool,
}

/// Aligns a scene with its floor in two stages, then records the result in
/// `scene.metadata["ground_alignment"]`:
/// 1. coarse: the mean body axis (foot joints → head joints) over all valid (frame, person) is
///    turned to +z — people stand upright on average, whatever the camera's roll or pitch;
/// 2. fine: a plane is fitted to the lowest foot joint of every valid (frame, person) (trimming
///    feet in swing) and, when the feet cover enough ground to tell a slope and the plane agrees
///    with the body axis within 15°, its normal is turned to +z. The floor height is then
///    subtracted, so that the floor is z = 0.
pub fn align_ground(scene: &mut Scene) -> Result<GroundAlignment> {
    let feet = scene.skeleton.foot_joints();
    if feet.is_empty() {
        bail!("scene {}: skeleton {} has no foot joints (ankle/foot/toe) to fit the floor to", scene.name, scene.skeleton.name);
    }
    let heads = scene.skeleton.head_joints();
    let tops: Vec<usize> = if heads.is_empty() { (0..scene.num_joints()).filter(|j| !feet.contains(j)).collect() } else { heads };
    let mean_of = |f: usize, p: usize, joints: &[usize]| -> [f64; 3] {
        let mut m = [0.0; 3];
        for &j in joints {
            for (k, v) in m.iter_mut().enumerate() {
                *v += scene.positions[[f, p, j, k]] as f64 / joints.len() as f64;
            }
        }
        m
    };
    let mut axis = [0.0; 3];
    for f in 0..scene.num_frames() {
        for p in 0..scene.num_persons() {
            if scene.is_valid(f, p) {
                let (top, bottom) = (mean_of(f, p, &tops), mean_of(f, p, &feet));
                for k in 0..3 {
                    axis[k] += top[k] - bottom[k];
                }
            }
        }
    }
    if axis.iter().all(|v| *v == 0.0) {
        bail!("scene {}: no valid frames to find the floor from", scene.name);
    }
    let coarse = rotation_between(normalize(axis), [0.0, 0.0, 1.0]);
    scene.transform(coarse, [0.0; 3]);

    let mut points: Vec<[f64; 3]> = Vec::new();
    for f in 0..scene.num_frames() {
        for p in 0..scene.num_persons() {
            if !scene.is_valid(f, p) {
                continue;
            }
            let lowest = feet
                .iter()
                .map(|&j| {
                    let v = scene.positions.slice(ndarray::s![f, p, j, ..]);
                    [v[0] as f64, v[1] as f64, v[2] as f64]
                })
                .min_by(|a, b| a[2].total_cmp(&b[2]))
                .expect("feet non-empty");
            points.push(lowest);
        }
    }
    if points.len() < 3 {
        bail!("scene {}: too few valid frames ({}) to fit a floor", scene.name, points.len());
    }
    // Feet in swing are above the floor: refit on the lower part of the residuals.
    let mut inliers = points.clone();
    let mut plane = fit_plane(&inliers);
    for _ in 0..3 {
        let mut res: Vec<f64> = points.iter().map(|q| q[2] - plane.height_at(q)).collect();
        res.sort_by(f64::total_cmp);
        let cut = res[(res.len() * 6) / 10];
        inliers = points.iter().copied().filter(|q| q[2] - plane.height_at(q) <= cut).collect();
        if inliers.len() < 3 {
            break;
        }
        plane = fit_plane(&inliers);
    }
    let n = normalize([-plane.a, -plane.b, 1.0]);
    let plane_used = plane.tilt_fitted && n[2].acos() < 15f64.to_radians();
    let fine = if plane_used { rotation_between(n, [0.0, 0.0, 1.0]) } else { IDENTITY };
    // x' = F(x − centre) + centre − (0, 0, floor height): rotate about the feet's centre.
    let c = plane.centre;
    let centre = [c[0], c[1], plane.height_at(&c)];
    let fc = apply(&fine, centre);
    let floor = if plane_used { centre[2] } else { plane.c };
    scene.transform(fine, [centre[0] - fc[0], centre[1] - fc[1], centre[2] - fc[2] - floor]);
    // Total rotation F·C; its tilt is the angle between the old up axis and the new one.
    let total = mul(&fine, &coarse);
    let report =
        GroundAlignment { tilt_deg: total[2][2].clamp(-1.0, 1.0).acos().to_degrees(), floor_height_m: floor, inliers: inliers.len(), tilt_fitted: plane_used };
    scene.metadata.insert("ground_alignment".into(), serde_json::to_value(report).expect("plain struct"));
    Ok(report)
}

/// z = a·x + b·y + c, fitted by least squares.
struct Plane {
    a: f64,
    b: f64,
    c: f64,
    centre: [f64; 3],
    tilt_fitted: bool,
}

impl Plane {
    fn height_at(&self, q: &[f64; 3]) -> f64 {
        self.a * q[0] + self.b * q[1] + self.c
    }
}

fn fit_plane(points: &[[f64; 3]]) -> Plane {
    let n = points.len() as f64;
    let mean = |k: usize| points.iter().map(|q| q[k]).sum::<f64>() / n;
    let (mx, my, mz) = (mean(0), mean(1), mean(2));
    let (mut sxx, mut sxy, mut syy, mut sxz, mut syz) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for q in points {
        let (x, y, z) = (q[0] - mx, q[1] - my, q[2] - mz);
        sxx += x * x;
        sxy += x * y;
        syy += y * y;
        sxz += x * z;
        syz += y * z;
    }
    let det = sxx * syy - sxy * sxy;
    // The smaller spread of the foot points must be ≥ 10 cm (std) to tell a slope from noise.
    let min_eig = 0.5 * (sxx + syy - ((sxx - syy).powi(2) + 4.0 * sxy * sxy).sqrt());
    let tilt_fitted = min_eig / n > 0.1 * 0.1 && det.abs() > 1e-12;
    let (a, b) = if tilt_fitted { ((sxz * syy - syz * sxy) / det, (syz * sxx - sxz * sxy) / det) } else { (0.0, 0.0) };
    Plane { a, b, c: mz - a * mx - b * my, centre: [mx, my, mz], tilt_fitted }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::Skeleton;
    use ndarray::Array4;

    #[test]
    fn up_axis_rotations_are_proper() {
        for ax in [UpAxis::Z, UpAxis::Y, UpAxis::NegY] {
            let m = ax.to_z_up();
            assert_eq!(crate::data::rotation::determinant(&m), 1.0);
        }
        assert_eq!(apply(&UpAxis::NegY.to_z_up(), [0.0, -1.0, 0.0]), [0.0, 0.0, 1.0]);
        assert_eq!(apply(&UpAxis::Y.to_z_up(), [0.0, 1.0, 0.0]), [0.0, 0.0, 1.0]);
    }

    /// People walking on a floor tilted by 10° at height 1.5 m are put back on z = 0.
    #[test]
    fn removes_known_tilt_and_height() {
        let sk = Skeleton::mupots17();
        let (frames, persons) = (60, 3);
        let tilt = 10f64.to_radians();
        let mut pos = Array4::<f32>::zeros((frames, persons, 17, 3));
        for f in 0..frames {
            for p in 0..persons {
                let (x, y) = (p as f64 * 1.5 - 1.5 + f as f64 * 0.02, (p as f64 - 1.0) * 1.2 + (f as f64 * 0.1).sin());
                for j in 0..17 {
                    // ankles on the floor (one foot lifted every other frame), the rest above
                    let h = match j {
                        10 => 0.0,
                        13 => {
                            if f % 2 == 0 {
                                0.15
                            } else {
                                0.0
                            }
                        }
                        _ => 0.3 + j as f64 * 0.08,
                    };
                    // tilt about the x axis, then lift by 1.5 m
                    let (yy, zz) = (y * tilt.cos() - h * tilt.sin(), y * tilt.sin() + h * tilt.cos() + 1.5);
                    pos[[f, p, j, 0]] = x as f32;
                    pos[[f, p, j, 1]] = yy as f32;
                    pos[[f, p, j, 2]] = zz as f32;
                }
            }
        }
        let mut scene = Scene::new("tilted", 30.0, sk, pos).unwrap();
        let r = align_ground(&mut scene).unwrap();
        assert!(r.tilt_fitted);
        assert!((r.tilt_deg - 10.0).abs() < 0.05, "{r:?}");

        for f in 0..frames {
            for p in 0..persons {
                assert!(scene.positions[[f, p, 10, 2]].abs() < 1e-3);
                let head = scene.positions[[f, p, 16, 2]] as f64;
                assert!((head - (0.3 + 16.0 * 0.08)).abs() < 1e-3);
            }
        }
        assert!(scene.metadata.contains_key("ground_alignment"));
    }
}
