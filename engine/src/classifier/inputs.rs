//! Per-frame inputs of the social-signal classifiers, computed from a scene's poses.
//!
//! # Per person (`6J` dims)
//! The body-frame pose `ℓ_1 … ℓ_J` of [`crate::features`] (hip midpoint on the ground, hip axis
//! along +x, facing +y, heights kept) and its velocity `(ℓ_t − ℓ_{t−1})·fps` in m/s (frame 0
//! repeats frame 1's). Both are invariant to where the person stands and which way they face.
//!
//! # Per ordered pair (p, q), q ≠ p ([`PAIR_DIMS`] = 7 dims)
//! Where q is for p and who looks at whom — the cues of turn-taking:
//!
//! | dims | meaning |
//! |---|---|
//! | 0, 1 | unit direction from p's root to q's root in p's body frame (+y = ahead of p) |
//! | 2 | ground distance of the roots, metres |
//! | 3, 4 | cos, sin of q's heading relative to p's |
//! | 5 | q's face toward p: `look_q · unit(pos_p − pos_q)` |
//! | 6 | p's face toward q: `look_p · unit(pos_q − pos_p)` |
//!
//! `look` and `pos` are the SSCP face direction and head position ([`Facing`]: the eye or ear
//! axis turned +90°, else the body frame). The others of p are listed in ascending person order
//! with p left out, so that slot k of p is person `k + (k ≥ p)`.

use crate::data::Scene;
use crate::features::{PoseFeatures, ROOT_DIMS};
use crate::metrics::sscp::Facing;
use crate::{bail, Result};
use ndarray::{Array3, Array4};

/// Dims of a pair feature vector.
pub const PAIR_DIMS: usize = 7;

/// Dims of a person's feature vector for a skeleton of `joints` joints: pose and velocity.
pub fn person_dims(joints: usize) -> usize {
    6 * joints
}

/// The person slot `k` of person `p`'s others: person `k + (k ≥ p)`.
pub fn other(p: usize, k: usize) -> usize {
    k + usize::from(k >= p)
}

/// Inputs of a whole scene (unstandardized).
#[derive(Clone, Debug, PartialEq)]
pub struct SceneInputs {
    /// Per-person features `[frames, persons, 6J]`.
    pub person: Array3<f32>,
    /// Pair features `[frames, persons, persons − 1, 7]`.
    pub pairs: Array4<f32>,
}

impl SceneInputs {
    /// Number of frames.
    pub fn num_frames(&self) -> usize {
        self.person.dim().0
    }

    /// Number of persons.
    pub fn num_persons(&self) -> usize {
        self.person.dim().1
    }
}

fn unit(v: [f64; 2]) -> [f64; 2] {
    let n = v[0].hypot(v[1]);
    if n > 1e-9 {
        [v[0] / n, v[1] / n]
    } else {
        [0.0, 0.0]
    }
}

/// Computes the classifier inputs of every frame and person of `scene` (see the module docs).
/// Errors where a valid pose has a degenerate hip axis (as [`PoseFeatures::from_scene`]).
pub fn scene_inputs(scene: &Scene) -> Result<SceneInputs> {
    let (nf, np, nj, _) = scene.positions.dim();
    if nf < 2 {
        bail!("scene {}: {nf} frame(s); the classifiers need at least 2", scene.name);
    }
    let feats = PoseFeatures::from_scene(scene, 0)?;
    let d = person_dims(nj);
    let local = 3 * nj;
    let mut person = Array3::<f32>::zeros((nf, np, d));
    // Body frame (root, heading) of every frame, decoded from the anchored features.
    let mut bodies = vec![([0.0f64; 2], 0.0f64); nf * np];
    for f in 0..nf {
        for p in 0..np {
            let x = feats.data.slice(ndarray::s![f, p, ..]);
            let a = feats.anchors[p];
            let (sa, ca) = a.heading.sin_cos();
            let (rx, ry) = (x[0] as f64, x[1] as f64);
            let root = [a.root[0] + ca * rx - sa * ry, a.root[1] + sa * rx + ca * ry];
            bodies[f * np + p] = (root, (x[3] as f64).atan2(x[2] as f64) + a.heading);
            let prev = if f == 0 { 1 } else { f - 1 };
            let (cur, before) = if f == 0 { (1, 0) } else { (f, prev) };
            for k in 0..local {
                person[[f, p, k]] = x[ROOT_DIMS + k];
                let v = feats.data[[cur, p, ROOT_DIMS + k]] - feats.data[[before, p, ROOT_DIMS + k]];
                person[[f, p, local + k]] = v * scene.fps as f32;
            }
        }
    }
    let facing = Facing::for_skeleton(&scene.skeleton);
    let mut pairs = Array4::<f32>::zeros((nf, np, np.saturating_sub(1), PAIR_DIMS));
    for f in 0..nf {
        let looks: Vec<([f64; 2], [f64; 2])> = (0..np)
            .map(|p| {
                let pose = scene.positions.slice(ndarray::s![f, p, .., ..]);
                (unit(facing.look(pose)), facing.position(pose))
            })
            .collect();
        for p in 0..np {
            let (root_p, h_p) = bodies[f * np + p];
            let (sp, cp) = h_p.sin_cos();
            for k in 0..np - 1 {
                let q = other(p, k);
                let (root_q, h_q) = bodies[f * np + q];
                let (dx, dy) = (root_q[0] - root_p[0], root_q[1] - root_p[1]);
                let local_d = [cp * dx + sp * dy, -sp * dx + cp * dy];
                let u = unit(local_d);
                let (look_p, pos_p) = looks[p];
                let (look_q, pos_q) = looks[q];
                let pq = unit([pos_q[0] - pos_p[0], pos_q[1] - pos_p[1]]);
                let v = [
                    u[0],
                    u[1],
                    dx.hypot(dy),
                    (h_q - h_p).cos(),
                    (h_q - h_p).sin(),
                    -(look_q[0] * pq[0] + look_q[1] * pq[1]),
                    look_p[0] * pq[0] + look_p[1] * pq[1],
                ];
                for (i, x) in v.iter().enumerate() {
                    pairs[[f, p, k, i]] = *x as f32;
                }
            }
        }
    }
    Ok(SceneInputs { person, pairs })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::Skeleton;
    use crate::metrics::sscp::tests::panoptic_pose_with;
    use ndarray::Array4;

    /// Per person: position, facing angle, head yaw, wrist lift.
    type Placement = ([f32; 2], f32, f32, f32);

    fn scene(frames: &[[Placement; 3]]) -> Scene {
        let mut pos = Array4::<f32>::zeros((frames.len(), 3, 19, 3));
        for (f, fr) in frames.iter().enumerate() {
            for (p, &(at, phi, yaw, lift)) in fr.iter().enumerate() {
                for (j, xyz) in panoptic_pose_with(at, phi, yaw, lift).iter().enumerate() {
                    for d in 0..3 {
                        pos[[f, p, j, d]] = xyz[d];
                    }
                }
            }
        }
        Scene::new("inputs", 30.0, Skeleton::panoptic19(), pos).unwrap()
    }

    #[test]
    fn pair_features_know_who_looks_at_whom() {
        use std::f32::consts::FRAC_PI_2;
        // Person 0 at the origin facing +y (φ = 90°), head turned 45° right toward person 2;
        // person 1 at (−1, 1), person 2 at (1, 1), both facing person 0.
        let toward = |from: [f32; 2], to: [f32; 2]| (to[1] - from[1]).atan2(to[0] - from[0]);
        let a = [
            ([0.0, 0.0], FRAC_PI_2, -std::f32::consts::FRAC_PI_4, 0.0),
            ([-1.0, 1.0], toward([-1.0, 1.0], [0.0, 0.0]), 0.0, 0.0),
            ([1.0, 1.0], toward([1.0, 1.0], [0.0, 0.0]), 0.0, 0.3),
        ];
        let mut b = a;
        b[2].3 = 0.0; // frame 1: the wrist is back down
        let s = scene(&[a, b]);
        let inp = scene_inputs(&s).unwrap();
        assert_eq!(inp.person.dim(), (2, 3, 6 * 19));
        assert_eq!(inp.pairs.dim(), (2, 3, 2, PAIR_DIMS));
        let pr = |p: usize, k: usize| inp.pairs.slice(ndarray::s![0, p, k, ..]).to_vec();
        let h = std::f32::consts::FRAC_1_SQRT_2;
        // Person 0's others: 1 (slot 0) ahead-left, 2 (slot 1) ahead-right, √2 m away.
        let close = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5);
        assert!(close(&pr(0, 0)[..3], &[-h, h, 2f32.sqrt()]), "{:?}", pr(0, 0));
        assert!(close(&pr(0, 1)[..3], &[h, h, 2f32.sqrt()]), "{:?}", pr(0, 1));
        // Person 0 looks at person 2 (its face, not its body), not at person 1; both look at 0
        // (up to the noses being 10 cm ahead of the heads).
        assert!((pr(0, 1)[6] - 1.0).abs() < 1e-4 && pr(0, 0)[6].abs() < 0.1, "{:?} {:?}", pr(0, 0), pr(0, 1));
        assert!((pr(0, 0)[5] - 1.0).abs() < 1e-2 && (pr(0, 1)[5] - 1.0).abs() < 1e-4);
        // Seen from person 2: person 0 (slot 0) looks at it.
        assert!((pr(2, 0)[5] - 1.0).abs() < 1e-4);
        // Velocity of person 2's right wrist: down 0.3 m in one frame at 30 fps = −9 m/s (z),
        // the same at frame 0 (which repeats frame 1's velocity).
        let wrist = Skeleton::panoptic19().joint_index("right_wrist").unwrap();
        for f in 0..2 {
            assert!((inp.person[[f, 2, 3 * 19 + 3 * wrist + 2]] + 9.0).abs() < 1e-3);
            assert_eq!(inp.person[[f, 1, 3 * 19 + 3 * wrist + 2]], 0.0);
        }
        // Translation and rotation of the whole scene change nothing.
        let mut moved = s.clone();
        let (sn, cs) = 0.7f64.sin_cos();
        moved.transform([[cs, -sn, 0.0], [sn, cs, 0.0], [0.0, 0.0, 1.0]], [3.0, -2.0, 0.0]);
        let inp2 = scene_inputs(&moved).unwrap();
        for (x, y) in inp.person.iter().zip(inp2.person.iter()).chain(inp.pairs.iter().zip(inp2.pairs.iter())) {
            assert!((x - y).abs() < 2e-4, "{x} vs {y}");
        }
        assert_eq!((other(0, 0), other(0, 1), other(1, 0), other(1, 1), other(2, 1)), (1, 2, 0, 2, 1));
        assert!(scene_inputs(&s.slice_frames(0, 1).unwrap()).is_err());
    }
}
