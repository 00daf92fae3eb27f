//! Mapping poses between skeletons by joint names, so that datasets recorded with different
//! skeletons (bandai2's 21 BVH joints, CMU BVH, MuPoTS-17, Panoptic-19) can be trained on
//! together.
//!
//! What a joint is, from its name, is [`super::joints`]'s vocabulary.
//!
//! # Rules
//! Each target joint gets one [`JointRule`]:
//! 1. the source joint of the same name (ignoring case), else of the same part and side → copy;
//! 2. a missing pelvis → the midpoint of the hips; a missing neck → the midpoint of the shoulders;
//! 3. anything else (e.g. MuPoTS's `head_top` from bandai2, which has no head-top point) is
//!    *derived*: the nearest target joint (along the target's bones) that the source has, plus a
//!    constant offset in the person's body frame (origin at that joint; x along the left→right
//!    hip axis, y forward, z up), fitted as the mean offset over the frames of target-skeleton
//!    scenes ([`JointMap::by_names`]'s `fit`). With no scenes to fit on (a forecast of a scene
//!    on another skeleton), a head top takes [`DEFAULT_OFFSETS`], MuPoTS-3D's mean; any other
//!    derived joint is an error naming it.
//!
//! Derived joints follow the body's heading but not e.g. the tilt of the head; that is the price
//! of training on sources without them, and [`JointMap::describe`] lists them.

use super::joints::{joint_parts, Part, Side};
use super::scene::Scene;
use super::skeleton::Skeleton;
use crate::data::body::Anchor;
use crate::{bail, Result};
use ndarray::Array4;
use std::collections::VecDeque;

/// How one target joint is computed from a source pose.
#[derive(Clone, Debug, PartialEq)]
pub enum JointRule {
    /// The source joint with this index.
    Copy(usize),
    /// The mean of these source joints.
    Midpoint(Vec<usize>),
    /// A source joint plus a constant offset in the body frame (x along the left→right hip
    /// axis, y forward, z up), metres.
    BodyOffset {
        /// Source joint the offset starts from.
        base: usize,
        /// Offset (x, y, z) in the body frame.
        offset: [f64; 3],
    },
}

/// Body-frame offsets (x right, y forward, z up; metres) of a derived target joint from the
/// joint it is derived from, by their parts, for maps with no scenes to fit on: the means of
/// `head_top − head` and `head_top − neck` over MuPoTS-3D's train split (15,019 person-frames;
/// x, whose mean is under 1 cm, set to 0), rounded to the centimetre.
pub const DEFAULT_OFFSETS: [(Part, Part, [f64; 3]); 2] = [(Part::HeadTop, Part::Head, [0.0, 0.04, 0.17]), (Part::HeadTop, Part::Neck, [0.0, 0.10, 0.24])];

/// A mapping from poses of `source` to poses of `target` (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct JointMap {
    /// Skeleton of the input scenes.
    pub source: Skeleton,
    /// Skeleton of the output scenes.
    pub target: Skeleton,
    /// One rule per target joint.
    pub rules: Vec<JointRule>,
    /// Frames the derived offsets were fitted on (0: [`DEFAULT_OFFSETS`]).
    pub fitted_frames: usize,
}

impl JointMap {
    /// Builds the mapping by joint names (module docs). `fit`: scenes on the target skeleton
    /// whose valid frames give the body-frame offsets of derived joints (only needed when the
    /// source lacks a target joint that is not the pelvis or the neck).
    pub fn by_names(source: &Skeleton, target: &Skeleton, fit: &[&Scene]) -> Result<Self> {
        let src_parts = joint_parts(&source.joints);
        let tgt_parts = joint_parts(&target.joints);
        let src_of = |key: (Part, Side)| src_parts.iter().find(|(k, _)| *k == key).map(|&(_, j)| j);
        let part_of = |t: usize| tgt_parts.iter().find(|(_, j)| *j == t).map(|&(k, _)| k);
        let exact = |t: usize| source.joints.iter().position(|s| s.eq_ignore_ascii_case(&target.joints[t]));
        let copied: Vec<Option<usize>> = (0..target.num_joints()).map(|t| exact(t).or_else(|| part_of(t).and_then(src_of))).collect();

        let mut rules = Vec::with_capacity(target.num_joints());
        let mut to_fit = Vec::new();
        for t in 0..target.num_joints() {
            if let Some(s) = copied[t] {
                rules.push(JointRule::Copy(s));
                continue;
            }
            let pair = |p: Part| Some(vec![src_of((p, Side::Left))?, src_of((p, Side::Right))?]);
            let mid = match part_of(t).map(|k| k.0) {
                Some(Part::Pelvis) => pair(Part::Hip),
                Some(Part::Neck) => pair(Part::Shoulder),
                _ => None,
            };
            if let Some(m) = mid {
                rules.push(JointRule::Midpoint(m));
                continue;
            }
            let Some(base) = nearest_copied(target, t, &copied) else {
                bail!("joint map {} → {}: no joint of {} is near target joint {:?}", source.name, target.name, source.name, target.joints[t]);
            };
            to_fit.push((t, base));
            rules.push(JointRule::BodyOffset { base: copied[base].expect("copied"), offset: [0.0; 3] });
        }
        let mut fitted_frames = 0;
        if !to_fit.is_empty() {
            let names: Vec<&str> = to_fit.iter().map(|&(t, _)| target.joints[t].as_str()).collect();
            let defaults: Option<Vec<[f64; 3]>> = to_fit
                .iter()
                .map(|&(t, base)| {
                    let (tp, bp) = (part_of(t)?.0, part_of(base)?.0);
                    DEFAULT_OFFSETS.iter().find(|(p, b, _)| (*p, *b) == (tp, bp)).map(|d| d.2)
                })
                .collect();
            let (offsets, frames) = match (fit.is_empty(), defaults) {
                (false, _) => fit_offsets(target, &to_fit, fit)?,
                (true, Some(d)) => (d, 0),
                (true, None) => bail!(
                    "joint map {} → {}: {} has no joint for {} — give scenes on the {} skeleton to fit a derived position",
                    source.name,
                    target.name,
                    source.name,
                    names.join(", "),
                    target.name
                ),
            };
            fitted_frames = frames;
            for (&(t, _), o) in to_fit.iter().zip(offsets) {
                if let JointRule::BodyOffset { offset, .. } = &mut rules[t] {
                    *offset = o;
                }
            }
        }
        Ok(Self { source: source.clone(), target: target.clone(), rules, fitted_frames })
    }

    /// Whether every target joint is a plain copy of a source joint.
    pub fn is_exact(&self) -> bool {
        self.rules.iter().all(|r| matches!(r, JointRule::Copy(_)))
    }

    /// One line per target joint: where it comes from.
    pub fn describe(&self) -> Vec<String> {
        let s = &self.source.joints;
        self.target
            .joints
            .iter()
            .zip(&self.rules)
            .map(|(t, r)| match r {
                JointRule::Copy(j) => format!("{t} ← {}", s[*j]),
                JointRule::Midpoint(v) => format!("{t} ← midpoint of {}", v.iter().map(|&j| s[j].as_str()).collect::<Vec<_>>().join(", ")),
                JointRule::BodyOffset { base, offset: o } => {
                    let how = match self.fitted_frames {
                        0 => "MuPoTS-3D's mean offset".to_string(),
                        n => format!("fitted on {n} frames of {}", self.target.name),
                    };
                    format!("{t} ← {} + ({:.3}, {:.3}, {:.3}) m in the body frame ({how})", s[*base], o[0], o[1], o[2])
                }
            })
            .collect()
    }

    /// Maps one pose.
    ///
    /// # Shapes
    /// - `pose`: `[source joints · 3]`; `out`: `[target joints · 3]`.
    pub fn map_pose(&self, pose: &[f32], heading: f64, out: &mut [f32]) {
        let (s, c) = heading.sin_cos();
        for (r, o) in self.rules.iter().zip(out.chunks_exact_mut(3)) {
            match r {
                JointRule::Copy(j) => o.copy_from_slice(&pose[3 * j..3 * j + 3]),
                JointRule::Midpoint(v) => {
                    for (k, ok) in o.iter_mut().enumerate() {
                        *ok = (v.iter().map(|&j| pose[3 * j + k] as f64).sum::<f64>() / v.len() as f64) as f32;
                    }
                }
                JointRule::BodyOffset { base, offset: d } => {
                    let b = &pose[3 * base..3 * base + 3];
                    o[0] = (b[0] as f64 + c * d[0] - s * d[1]) as f32;
                    o[1] = (b[1] as f64 + s * d[0] + c * d[1]) as f32;
                    o[2] = (b[2] as f64 + d[2]) as f32;
                }
            }
        }
    }

    /// Maps every pose of `scene` (which must use the source skeleton) to the target skeleton;
    /// validity, signals, persons and metadata are kept (plus `joint_map`: the source skeleton).
    pub fn apply(&self, scene: &Scene) -> Result<Scene> {
        if scene.skeleton.joints != self.source.joints {
            bail!("joint map {} → {}: scene {} has skeleton {}", self.source.name, self.target.name, scene.name, scene.skeleton.name);
        }
        let (nf, np, nj, _) = scene.positions.dim();
        let nt = self.target.num_joints();
        let src = scene.positions.as_standard_layout();
        let src = src.as_slice().expect("standard layout");
        let mut out = Array4::<f32>::zeros((nf, np, nt, 3));
        let dst = out.as_slice_mut().expect("fresh array");
        let (l, r) = (self.source.left, self.source.right);
        for p in 0..np {
            let mut heading = 0.0;
            for f in 0..nf {
                let pose = &src[(f * np + p) * nj * 3..][..nj * 3];
                if let Some(a) = Anchor::of_pose(pose, l, r) {
                    heading = a.heading;
                }
                self.map_pose(pose, heading, &mut dst[(f * np + p) * nt * 3..][..nt * 3]);
            }
        }
        let mut mapped = Scene::new(scene.name.clone(), scene.fps, self.target.clone(), out)?.with_persons(scene.persons.clone())?;
        mapped.valid = scene.valid.clone();
        mapped.signals = scene.signals.clone();
        mapped.metadata = scene.metadata.clone();
        mapped.metadata.insert("joint_map".into(), format!("{} → {}", self.source.name, self.target.name).into());
        Ok(mapped)
    }
}

/// The target joint nearest to `t` along the target's bones that has a copied source joint.
fn nearest_copied(target: &Skeleton, t: usize, copied: &[Option<usize>]) -> Option<usize> {
    let mut seen = vec![false; target.num_joints()];
    let mut queue = VecDeque::from([t]);
    seen[t] = true;
    while let Some(j) = queue.pop_front() {
        if j != t && copied[j].is_some() {
            return Some(j);
        }
        for &(a, b) in &target.bones {
            for (x, y) in [(a, b), (b, a)] {
                if x == j && !seen[y] {
                    seen[y] = true;
                    queue.push_back(y);
                }
            }
        }
    }
    None
}

/// Mean body-frame offset of each `(joint, base)` pair over every valid frame of `scenes`.
fn fit_offsets(target: &Skeleton, pairs: &[(usize, usize)], scenes: &[&Scene]) -> Result<(Vec<[f64; 3]>, usize)> {
    let mut sums = vec![[0.0f64; 3]; pairs.len()];
    let mut n = 0usize;
    for sc in scenes {
        if sc.skeleton.joints != target.joints {
            bail!("joint map: fitting scene {} has skeleton {}, not {}", sc.name, sc.skeleton.name, target.name);
        }
        let nj = sc.num_joints();
        let pos = sc.positions.as_standard_layout();
        let pos = pos.as_slice().expect("standard layout");
        for f in 0..sc.num_frames() {
            for p in 0..sc.num_persons() {
                if !sc.is_valid(f, p) {
                    continue;
                }
                let pose = &pos[(f * sc.num_persons() + p) * nj * 3..][..nj * 3];
                let Some(a) = Anchor::of_pose(pose, target.left, target.right) else { continue };
                let (s, c) = a.heading.sin_cos();
                for (sum, &(t, b)) in sums.iter_mut().zip(pairs) {
                    let d = [0, 1, 2].map(|k| pose[3 * t + k] as f64 - pose[3 * b + k] as f64);
                    sum[0] += c * d[0] + s * d[1];
                    sum[1] += -s * d[0] + c * d[1];
                    sum[2] += d[2];
                }
                n += 1;
            }
        }
    }
    if n == 0 {
        bail!("joint map: the fitting scenes have no valid frame");
    }
    Ok((sums.into_iter().map(|s| s.map(|v| v / n as f64)).collect(), n))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A standing MuPoTS-17 person facing +y (heading 0), head top 0.2 m above the head and
    /// 0.05 m forward, at (x0, y0).
    fn mupots_pose(x0: f32, y0: f32, heading: f32) -> Vec<f32> {
        let local: [[f32; 3]; 17] = [
            [0.0, 0.05, 1.80],
            [0.0, 0.0, 1.45],
            [0.2, 0.0, 1.4],
            [0.25, 0.0, 1.15],
            [0.3, 0.0, 0.9],
            [-0.2, 0.0, 1.4],
            [-0.25, 0.0, 1.15],
            [-0.3, 0.0, 0.9],
            [0.1, 0.0, 0.9],
            [0.1, 0.0, 0.5],
            [0.1, 0.0, 0.1],
            [-0.1, 0.0, 0.9],
            [-0.1, 0.0, 0.5],
            [-0.1, 0.0, 0.1],
            [0.0, 0.0, 0.9],
            [0.0, 0.0, 1.2],
            [0.0, 0.0, 1.60],
        ];
        let (s, c) = heading.sin_cos();
        local.iter().flat_map(|p| [x0 + c * p[0] - s * p[1], y0 + s * p[0] + c * p[1], p[2]]).collect()
    }

    #[test]
    fn bandai_to_mupots_copies_by_meaning_and_derives_the_head_top() {
        let m = Skeleton::mupots17();
        let fit = Scene::new(
            "fit",
            30.0,
            m.clone(),
            Array4::from_shape_vec((2, 1, 17, 3), [mupots_pose(0.0, 0.0, 0.0), mupots_pose(1.0, 2.0, 1.0)].concat()).unwrap(),
        )
        .unwrap();
        let map = JointMap::by_names(&Skeleton::bandai21(), &m, &[&fit]).unwrap();
        let names: Vec<String> = map.describe();
        assert_eq!(names[m.joint_index("left_shoulder").unwrap()], "left_shoulder ← UpperArm_L");
        assert_eq!(names[m.joint_index("right_wrist").unwrap()], "right_wrist ← Hand_R");
        assert_eq!(names[m.joint_index("pelvis").unwrap()], "pelvis ← Hips");
        assert_eq!(names[m.joint_index("spine").unwrap()], "spine ← Spine");
        let JointRule::BodyOffset { base, offset } = map.rules[0] else { panic!("{:?}", map.rules[0]) };
        assert_eq!(map.source.joints[base], "Head");
        // head_top − head = (0, 0.05, 0.2) in the body frame, whatever the heading.
        for (got, want) in offset.iter().zip([0.0, 0.05, 0.2]) {
            assert!((got - want).abs() < 1e-6, "{offset:?}");
        }
        assert_eq!(map.fitted_frames, 2);
        assert!(!map.is_exact());

        // Map a bandai pose turned by 90°: the head top goes 0.05 m along the facing direction.
        let b = Skeleton::bandai21();
        let mut pose = vec![0.0f32; 21 * 3];
        let set = |pose: &mut Vec<f32>, j: &str, p: [f32; 3]| pose[3 * b.joint_index(j).unwrap()..][..3].copy_from_slice(&p);
        set(&mut pose, "UpperLeg_L", [0.0, -0.1, 0.9]);
        set(&mut pose, "UpperLeg_R", [0.0, 0.1, 0.9]);
        set(&mut pose, "Head", [0.0, 0.0, 1.5]);
        let sc = Scene::new("b", 30.0, b.clone(), Array4::from_shape_vec((1, 1, 21, 3), pose).unwrap()).unwrap();
        let out = map.apply(&sc).unwrap();
        assert_eq!(out.skeleton, m);
        // Heading 90° (hip axis along +y), facing −x.
        let top: Vec<f32> = (0..3).map(|k| out.positions[[0, 0, 0, k]]).collect();
        assert!((top[0] + 0.05).abs() < 1e-6 && top[1].abs() < 1e-6 && (top[2] - 1.7).abs() < 1e-6, "{top:?}");
        assert_eq!(out.positions[[0, 0, m.joint_index("left_hip").unwrap(), 1]], -0.1);
    }

    #[test]
    fn the_bundled_cmu_clip_maps_onto_mupots_without_fitting() {
        let text = std::fs::read_to_string(crate::data::test_util::cmu_clip()).unwrap();
        let opts = crate::data::bvh::BvhImport { scale: crate::data::bvh::CMU_SCALE, include_end_sites: true, ..Default::default() };
        let clip = crate::data::bvh::parse_bvh(&text).unwrap().to_scene("cmu", &opts).unwrap();
        let m = Skeleton::mupots17();
        let map = JointMap::by_names(&clip.skeleton, &m, &[]).unwrap();
        assert!(map.is_exact(), "{:?}", map.describe());
        let d = map.describe();
        for want in [
            "head_top ← head_end",
            "neck ← lowerneck",
            "left_shoulder ← lhumerus",
            "right_elbow ← rradius",
            "left_hip ← lfemur",
            "right_knee ← rtibia",
            "left_ankle ← lfoot",
            "pelvis ← hip",
            "spine ← upperback",
        ] {
            assert!(d.iter().any(|l| l == want), "{want} not in {d:?}");
        }
        let mapped = map.apply(&clip).unwrap();
        // Standing: the head top 1.37 m above the ankles (CMU's subject 18 at the CMU scale:
        // femur 0.42 m, tibia 0.43 m, pelvis to head 0.43 m, head 0.09 m).
        let h = mapped.positions[[0, 0, 0, 2]] - mapped.positions[[0, 0, 10, 2]];
        assert!((1.2..1.6).contains(&h), "height {h}");
    }

    #[test]
    fn identity_and_missing_fits() {
        let m = Skeleton::mupots17();
        let id = JointMap::by_names(&m, &m, &[]).unwrap();
        assert!(id.is_exact());
        assert_eq!(id.rules[5], JointRule::Copy(5));
        // Without scenes to fit on, a head top is MuPoTS's mean offset from the head (or the
        // neck); other derived joints (Panoptic's face points) are an error naming them.
        let map = JointMap::by_names(&Skeleton::bandai21(), &m, &[]).unwrap();
        assert_eq!(map.describe()[0], "head_top ← Head + (0.000, 0.040, 0.170) m in the body frame (MuPoTS-3D's mean offset)");
        let map = JointMap::by_names(&Skeleton::bandai21(), &Skeleton::mrt15(), &[]).unwrap();
        let top = Skeleton::mrt15().joint_index("head_top").unwrap();
        assert_eq!(map.rules[top], JointRule::BodyOffset { base: Skeleton::bandai21().joint_index("Neck").unwrap(), offset: [0.0, 0.10, 0.24] });
        let e = JointMap::by_names(&m, &Skeleton::panoptic19(), &[]).unwrap_err().to_string();
        assert!(e.contains("nose") && e.contains("fit"), "{e}");
        // Panoptic from MuPoTS: nose, eyes and ears are derived; a fitting scene on the wrong
        // skeleton is refused.
        let fit = Scene::new("f", 30.0, m.clone(), Array4::zeros((1, 1, 17, 3))).unwrap();
        let e = JointMap::by_names(&m, &Skeleton::panoptic19(), &[&fit]).unwrap_err().to_string();
        assert!(e.contains("fitting scene"), "{e}");
        // A missing pelvis and neck become midpoints.
        let sk =
            Skeleton::new("no-mid", ["l_hip", "r_hip", "l_shoulder", "r_shoulder", "head", "head_top"].iter().map(|s| s.to_string()).collect(), vec![], 0, 1)
                .unwrap();
        let to = Skeleton::new("mid", ["pelvis", "neck", "l_hip", "r_hip"].iter().map(|s| s.to_string()).collect(), vec![], 2, 3).unwrap();
        let map = JointMap::by_names(&sk, &to, &[]).unwrap();
        assert_eq!(map.rules, vec![JointRule::Midpoint(vec![0, 1]), JointRule::Midpoint(vec![2, 3]), JointRule::Copy(0), JointRule::Copy(1)]);
    }
}
