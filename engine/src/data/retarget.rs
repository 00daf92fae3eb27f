//! Retargeting: a motion on another body's proportions.
//!
//! Every bone keeps its direction on every frame and takes the target body's length. That is
//! what solving each joint's rotation from the positions (as the BVH exporter does) and running
//! forward kinematics over the target's bones gives — a position skeleton has no twist to keep —
//! so the angles between bones are the source's. The root's ground trajectory is scaled by the
//! ratio of leg lengths (strides scale with legs) and its height by the same ratio; then each
//! frame is moved vertically so that its lowest foot is as high as the source's scaled (never
//! below the floor, z = 0).

use super::scene::Scene;
use super::skeleton::joint_tree;
use crate::{bail, Result};

/// Bone lengths (m, in `skeleton.bones` order) of person `person` of `scene`: the median over
/// its valid frames.
pub fn bone_lengths(scene: &Scene, person: usize) -> Result<Vec<f64>> {
    if person >= scene.num_persons() {
        bail!("scene {}: person {person} out of range ({} persons)", scene.name, scene.num_persons());
    }
    let frames: Vec<usize> = (0..scene.num_frames()).filter(|&f| scene.is_valid(f, person)).collect();
    if frames.is_empty() {
        bail!("scene {}: person {person} has no valid frame to measure bones on", scene.name);
    }
    let p = |f: usize, j: usize| -> [f64; 3] { std::array::from_fn(|k| scene.positions[[f, person, j, k]] as f64) };
    Ok(scene
        .skeleton
        .bones
        .iter()
        .map(|&(a, b)| {
            let mut l: Vec<f64> = frames.iter().map(|&f| dist(p(f, a), p(f, b))).collect();
            l.sort_by(f64::total_cmp);
            l[l.len() / 2]
        })
        .collect())
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
}

/// The bone lengths of person `person` of `body` on the skeleton of `motion` ([`bone_lengths`]
/// after mapping `body`'s joints onto `motion`'s by name, with `body` itself returned mapped).
/// A joint the body lacks is placed by an offset fitted on `motion` and has no length of the
/// body's own: one is allowed (CMU's head top), more are an error naming them.
pub fn body_on(body: &Scene, motion: &Scene, person: usize) -> Result<(Scene, Vec<f64>)> {
    use super::joint_map::{JointMap, JointRule};
    let body = if body.skeleton.check_same_layout(&motion.skeleton).is_ok() {
        body.clone()
    } else {
        let map = JointMap::by_names(&body.skeleton, &motion.skeleton, &[motion])?;
        let derived: Vec<&str> =
            map.rules.iter().enumerate().filter(|(_, r)| matches!(r, JointRule::BodyOffset { .. })).map(|(j, _)| motion.skeleton.joints[j].as_str()).collect();
        if derived.len() > 1 {
            bail!("skeleton {} has no joints for {} of {}: its bones cannot be measured", body.skeleton.name, derived.join(", "), motion.skeleton.name);
        }
        let mut mapped = map.apply(body)?;
        mapped.skeleton = motion.skeleton.clone();
        mapped
    };
    let lengths = bone_lengths(&body, person)?;
    Ok((body, lengths))
}

/// What [`retarget`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct Retargeted {
    /// The motion on the target's bones.
    pub scene: Scene,
    /// Target leg length over source leg length (root → lowest foot along the bones, mean of
    /// the feet), per person.
    pub leg_ratio: Vec<f64>,
}

impl Retargeted {
    /// The retargeted motion as a dataset (test split) whose metadata says where the motion and
    /// the body came from (`retarget`: `motion`, `body`, `body_scene`, `body_person`,
    /// `bone_lengths_m`, `leg_ratio`).
    pub fn into_dataset(self, motion: &std::path::Path, body: &std::path::Path, body_scene: &str, body_person: usize, lengths: &[f64]) -> super::Dataset {
        let info = serde_json::json!({"motion": motion.display().to_string(), "body": body.display().to_string(), "body_scene": body_scene,
            "body_person": body_person, "bone_lengths_m": lengths, "leg_ratio": self.leg_ratio});
        let metadata = serde_json::Map::from_iter([("retarget".to_string(), info)]);
        super::Dataset { name: self.scene.name.clone(), sequences: vec![super::dataset::Sequence { split: crate::Split::Test, scene: self.scene }], metadata }
    }
}

/// `motion` with every person on the bones `lengths` (in `motion.skeleton.bones` order, e.g.
/// [`bone_lengths`] of another scene mapped onto this skeleton); see the module docs.
pub fn retarget(motion: &Scene, lengths: &[f64]) -> Result<Retargeted> {
    let sk = &motion.skeleton;
    if lengths.len() != sk.bones.len() {
        bail!("retargeting {}: {} bone lengths for the {} bones of skeleton {}", motion.name, lengths.len(), sk.bones.len(), sk.name);
    }
    if let Some((i, l)) = lengths.iter().enumerate().find(|(_, l)| !(l.is_finite() && **l > 0.0 && **l < 10.0)) {
        bail!("retargeting {}: bone {i} ({} – {}) has length {l} m", motion.name, sk.joints[sk.bones[i].0], sk.joints[sk.bones[i].1]);
    }
    let root = motion.root_joint(0, None)?;
    let tree = joint_tree(sk, root)?;
    // Length of the bone to each joint from its parent, for bone lengths in bone order.
    let per_joint = |lengths: &[f64]| -> Vec<f64> {
        let mut to_parent = vec![0.0; sk.num_joints()];
        for (&(a, b), &l) in sk.bones.iter().zip(lengths) {
            if tree.parent[b] == Some(a) {
                to_parent[b] = l;
            } else if tree.parent[a] == Some(b) {
                to_parent[a] = l;
            }
        }
        to_parent
    };
    let to_parent = per_joint(lengths);
    let feet = sk.foot_joints();
    if feet.is_empty() {
        bail!("retargeting {}: skeleton {} has no foot joints to keep on the floor", motion.name, sk.name);
    }
    let leg = |len: &dyn Fn(usize) -> f64| -> f64 {
        let per_foot: Vec<f64> = feet
            .iter()
            .map(|&f| {
                let (mut j, mut l) = (f, 0.0);
                while let Some(p) = tree.parent[j] {
                    l += len(j);
                    j = p;
                }
                l
            })
            .collect();
        per_foot.iter().sum::<f64>() / per_foot.len() as f64
    };
    let target_leg = leg(&|j| to_parent[j]);
    let (nf, np) = (motion.num_frames(), motion.num_persons());
    let mut out = motion.clone();
    let mut ratios = Vec::with_capacity(np);
    for p in 0..np {
        let src_to_parent = per_joint(&bone_lengths(motion, p)?);
        let source_leg = leg(&|j| src_to_parent[j]);
        if source_leg <= 0.0 {
            bail!("retargeting {}: person {p} has legs of length 0", motion.name);
        }
        let r = target_leg / source_leg;
        ratios.push(r);
        let x = |f: usize, j: usize| -> [f64; 3] { std::array::from_fn(|k| motion.positions[[f, p, j, k]] as f64) };
        let start = x(0, root);
        for f in 0..nf {
            let mut new = vec![[0.0f64; 3]; sk.num_joints()];
            let rt = x(f, root);
            new[root] = [start[0] + r * (rt[0] - start[0]), start[1] + r * (rt[1] - start[1]), r * rt[2]];
            for &j in &tree.order[1..] {
                let pa = tree.parent[j].expect("non-root joints have parents");
                let (a, b) = (x(f, pa), x(f, j));
                let d = dist(a, b);
                let dir = if d > 1e-9 { [(b[0] - a[0]) / d, (b[1] - a[1]) / d, (b[2] - a[2]) / d] } else { [0.0, 0.0, 0.0] };
                new[j] = std::array::from_fn(|k| new[pa][k] + to_parent[j] * dir[k]);
            }
            let low = |q: &dyn Fn(usize) -> f64| feet.iter().map(|&j| q(j)).fold(f64::INFINITY, f64::min);
            let want = (r * low(&|j| x(f, j)[2])).max(0.0);
            let dz = want - low(&|j| new[j][2]);
            for (j, v) in new.iter().enumerate() {
                for (k, c) in v.iter().enumerate() {
                    out.positions[[f, p, j, k]] = (c + if k == 2 { dz } else { 0.0 }) as f32;
                }
            }
        }
    }
    out.name = format!("{}_retargeted", motion.name);
    Ok(Retargeted { scene: out, leg_ratio: ratios })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::test_util::walkers;

    /// Known values: halving every bone halves the leg ratio, keeps every bone direction, and
    /// gives every bone its new length on every frame; the feet stay at or above the floor; a
    /// wrong number of lengths and a zero length are refused.
    #[test]
    fn bones_take_the_target_lengths_and_keep_their_directions() {
        let scene = walkers(20, 2, 0.3);
        let sk = &scene.skeleton;
        let src = bone_lengths(&scene, 0).unwrap();
        let half: Vec<f64> = src.iter().map(|l| 0.5 * l).collect();
        let r = retarget(&scene, &half).unwrap();
        assert!((r.leg_ratio[0] - 0.5).abs() < 1e-9, "{:?}", r.leg_ratio);
        let x = |s: &Scene, f: usize, p: usize, j: usize| -> [f64; 3] { std::array::from_fn(|k| s.positions[[f, p, j, k]] as f64) };
        for f in 0..20 {
            for (i, &(a, b)) in sk.bones.iter().enumerate() {
                let (u, v) = (x(&scene, f, 0, a), x(&scene, f, 0, b));
                let (nu, nv) = (x(&r.scene, f, 0, a), x(&r.scene, f, 0, b));
                assert!((dist(nu, nv) - half[i]).abs() < 1e-3, "frame {f}, bone {i}");
                let cos: f64 = (0..3).map(|k| (v[k] - u[k]) * (nv[k] - nu[k])).sum::<f64>() / (dist(u, v) * dist(nu, nv));
                assert!(cos > (1f64).to_radians().cos(), "frame {f}, bone {i}: direction changed");
            }
            let feet = sk.foot_joints();
            assert!(feet.iter().all(|&j| r.scene.positions[[f, 0, j, 2]] >= -1e-6));
        }
        assert!(retarget(&scene, &half[1..]).unwrap_err().to_string().contains("bone lengths for the"));
        let mut zero = half.clone();
        zero[0] = 0.0;
        assert!(retarget(&scene, &zero).unwrap_err().to_string().contains("has length 0"));
    }
}
