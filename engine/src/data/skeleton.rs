//! Skeletons: joint names, bones and the pair of joints that defines the body frame.

use crate::{bail, Result};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// A kinematic skeleton. Joints are addressed by index; `bones` are (parent, child) pairs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Skeleton {
    /// Short name of the layout (`mupots17`, `panoptic19`, the BVH file stem, ...).
    pub name: String,
    /// Joint names, unique.
    pub joints: Vec<String>,
    /// Bones as (parent, child) joint indices.
    pub bones: Vec<(usize, usize)>,
    /// The person's left body-frame joint (left hip by default).
    pub left: usize,
    /// The person's right body-frame joint (right hip by default).
    pub right: usize,
}

impl Skeleton {
    /// Builds a skeleton and checks that every index is in range and names are unique.
    pub fn new(name: impl Into<String>, joints: Vec<String>, bones: Vec<(usize, usize)>, left: usize, right: usize) -> Result<Self> {
        let name = name.into();
        let n = joints.len();
        if n == 0 {
            bail!("skeleton {name}: no joints");
        }
        for (i, j) in joints.iter().enumerate() {
            if joints[..i].contains(j) {
                bail!("skeleton {name}: joint name {j:?} appears twice");
            }
        }
        for &(a, b) in &bones {
            if a >= n || b >= n || a == b {
                bail!("skeleton {name}: bone ({a}, {b}) is not a pair of distinct joints of {n}");
            }
        }
        if left >= n || right >= n || left == right {
            bail!("skeleton {name}: body-frame joints ({left}, {right}) are not two distinct joints of {n}");
        }
        Ok(Self { name, joints, bones, left, right })
    }

    /// Checks that `other` lays out joints like `self` (the layout a model was trained on):
    /// the same joint names in the same order, the same body-frame joints and the same bones.
    /// The error names the first joint or bone that differs.
    pub fn check_same_layout(&self, other: &Skeleton) -> Result<()> {
        let (a, b) = (self, other);
        if let Some(i) = (0..a.num_joints().min(b.num_joints())).find(|&i| !a.joints[i].eq_ignore_ascii_case(&b.joints[i])) {
            let moved = b.joints.iter().position(|j| j.eq_ignore_ascii_case(&a.joints[i]));
            let hint = match moved {
                Some(k) => format!(" (the data has {:?} at joint {k}: map it with `joint_map` auto)", a.joints[i]),
                None => format!(" (the data has no joint {:?})", a.joints[i]),
            };
            bail!("joint {i} is {:?} in skeleton {} but {:?} in skeleton {}{hint}", a.joints[i], a.name, b.joints[i], b.name);
        }
        if a.num_joints() != b.num_joints() {
            let (longer, name) = if a.num_joints() > b.num_joints() { (a, &b.name) } else { (b, &a.name) };
            let extra = &longer.joints[a.num_joints().min(b.num_joints())];
            bail!("skeleton {} has {} joints, skeleton {} has {} joints: {name} has no joint {extra:?}", a.name, a.num_joints(), b.name, b.num_joints());
        }
        if (a.left, a.right) != (b.left, b.right) {
            bail!(
                "the body-frame joints (left, right) are {} / {} in skeleton {} but {} / {} in skeleton {}",
                a.joints[a.left],
                a.joints[a.right],
                a.name,
                b.joints[b.left],
                b.joints[b.right],
                b.name
            );
        }
        let undirected = |(x, y): (usize, usize)| (x.min(y), x.max(y));
        let bones_b: std::collections::BTreeSet<_> = b.bones.iter().map(|&e| undirected(e)).collect();
        let bones_a: std::collections::BTreeSet<_> = a.bones.iter().map(|&e| undirected(e)).collect();
        if let Some(&(x, y)) = bones_a.symmetric_difference(&bones_b).next() {
            let (has, lacks) = if bones_a.contains(&(x, y)) { (&a.name, &b.name) } else { (&b.name, &a.name) };
            bail!("bone {} – {} is in skeleton {has} but not in skeleton {lacks}", a.joints[x], a.joints[y]);
        }
        Ok(())
    }

    /// Number of joints.
    pub fn num_joints(&self) -> usize {
        self.joints.len()
    }

    /// Index of the joint called `name`.
    pub fn joint_index(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j == name)
    }

    /// Index of the joint called `name`, or an error naming the skeleton and the joint.
    pub fn require_joint(&self, name: &str) -> Result<usize> {
        match self.joint_index(name) {
            Some(i) => Ok(i),
            None => bail!("skeleton {} has no joint {name:?} (joints: {})", self.name, crate::files::list_some(&self.joints, 12)),
        }
    }

    /// Joints that touch the floor when standing: names containing ankle, foot, toe or heel
    /// ([`super::joints::FOOT_WORDS`]).
    pub fn foot_joints(&self) -> Vec<usize> {
        super::joints::joints_with_words(&self.joints, &super::joints::FOOT_WORDS)
    }

    /// Joints at the top of the body: names containing head, nose, eye or ear
    /// ([`super::joints::HEAD_WORDS`]).
    pub fn head_joints(&self) -> Vec<usize> {
        super::joints::joints_with_words(&self.joints, &super::joints::HEAD_WORDS)
    }

    /// Panoptic Studio COCO-19 layout used by the Haggling dataset (hips 6 and 12).
    pub fn panoptic19() -> Self {
        let joints = [
            "neck",
            "nose",
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
            "left_eye",
            "left_ear",
            "right_eye",
            "right_ear",
        ];
        let bones = vec![
            (0, 3),
            (3, 4),
            (4, 5),
            (0, 9),
            (9, 10),
            (10, 11),
            (0, 1),
            (0, 2),
            (2, 6),
            (2, 12),
            (6, 7),
            (7, 8),
            (12, 13),
            (13, 14),
            (15, 16),
            (15, 17),
            (17, 18),
            (1, 17),
            (1, 15),
        ];
        Self::new("panoptic19", joints.iter().map(|s| s.to_string()).collect(), bones, 6, 12).expect("panoptic19 preset is valid")
    }

    /// MuPoTS-3D 17-joint layout (hips 11 and 8), as in MuPoTS's `dataset.json`.
    pub fn mupots17() -> Self {
        let joints = [
            "head_top",
            "neck",
            "right_shoulder",
            "right_elbow",
            "right_wrist",
            "left_shoulder",
            "left_elbow",
            "left_wrist",
            "right_hip",
            "right_knee",
            "right_ankle",
            "left_hip",
            "left_knee",
            "left_ankle",
            "pelvis",
            "spine",
            "head",
        ];
        let bones =
            vec![(0, 16), (16, 1), (1, 15), (15, 14), (1, 2), (2, 3), (3, 4), (1, 5), (5, 6), (6, 7), (14, 8), (8, 9), (9, 10), (14, 11), (11, 12), (12, 13)];
        Self::new("mupots17", joints.iter().map(|s| s.to_string()).collect(), bones, 11, 8).expect("mupots17 preset is valid")
    }
}

/// The skeletons known by name (`data convert --skeleton NAME`, [`Skeleton::named`]).
pub const NAMED_SKELETONS: [&str; 8] = ["mupots17", "mrt15", "h36m17", "smpl22", "smpl24", "panoptic19", "bandai21", "cmu31"];

impl Skeleton {
    /// The skeleton called `name` ([`NAMED_SKELETONS`]); the error lists the names.
    pub fn named(name: &str) -> Result<Self> {
        Ok(match name {
            "mupots17" => Self::mupots17(),
            "mrt15" => Self::mrt15(),
            "h36m17" => Self::h36m17(),
            "smpl22" => Self::smpl22(),
            "smpl24" => Self::smpl24(),
            "panoptic19" => Self::panoptic19(),
            "bandai21" => Self::bandai21(),
            "cmu31" => Self::cmu31(),
            _ => bail!("unknown skeleton {name:?}: the named skeletons are {}", NAMED_SKELETONS.join(", ")),
        })
    }

    /// A tree skeleton from each joint's parent (`None` for the root); `left`/`right` name
    /// the body-frame joints. For the presets below, whose tables are known to be valid.
    fn preset(name: &str, joints: &[&str], parents: &[Option<usize>], left: &str, right: &str) -> Self {
        let joints: Vec<String> = joints.iter().map(|j| j.to_string()).collect();
        let bones = parents.iter().enumerate().filter_map(|(j, p)| p.map(|p| (p, j))).collect();
        let at = |n: &str| joints.iter().position(|j| j == n).expect("body-frame joint of a preset");
        let (l, r) = (at(left), at(right));
        Self::new(name, joints, bones, l, r).expect("presets are valid")
    }

    /// The 15 joints MRT's MuPoTS-3D and CMU-Mocap files hold, in their order (MRT,
    /// `preprocess_mupots.py`: MuPoTS joints 14, 11, 12, 13, 8, 9, 10, 1, 0, 5, 6, 7, 2, 3, 4;
    /// bones as its `body_edges`).
    pub fn mrt15() -> Self {
        let joints = [
            "pelvis",
            "left_hip",
            "left_knee",
            "left_ankle",
            "right_hip",
            "right_knee",
            "right_ankle",
            "neck",
            "head_top",
            "left_shoulder",
            "left_elbow",
            "left_wrist",
            "right_shoulder",
            "right_elbow",
            "right_wrist",
        ];
        let parents = [None, Some(0), Some(1), Some(2), Some(0), Some(4), Some(5), Some(0), Some(7), Some(7), Some(9), Some(10), Some(7), Some(12), Some(13)];
        Self::preset("mrt15", &joints, &parents, "left_hip", "right_hip")
    }

    /// Human3.6M's 17 joints as VideoPose3D and most forecasting code use them (its
    /// `data_3d_h36m.npz` keeps 17 of 32: 0 hip centre … 16 right wrist; joint 9 is the
    /// nose/neck point).
    pub fn h36m17() -> Self {
        let joints = [
            "pelvis",
            "right_hip",
            "right_knee",
            "right_ankle",
            "left_hip",
            "left_knee",
            "left_ankle",
            "spine",
            "thorax",
            "nose",
            "head",
            "left_shoulder",
            "left_elbow",
            "left_wrist",
            "right_shoulder",
            "right_elbow",
            "right_wrist",
        ];
        let parents = [
            None,
            Some(0),
            Some(1),
            Some(2),
            Some(0),
            Some(4),
            Some(5),
            Some(0),
            Some(7),
            Some(8),
            Some(9),
            Some(8),
            Some(11),
            Some(12),
            Some(8),
            Some(14),
            Some(15),
        ];
        Self::preset("h36m17", &joints, &parents, "left_hip", "right_hip")
    }

    /// SMPL's 24 body joints (pelvis, hips, spine …, hands), in SMPL's order.
    pub fn smpl24() -> Self {
        Self::preset("smpl24", &SMPL_JOINTS, &SMPL_PARENTS, "left_hip", "right_hip")
    }

    /// SMPL's first 22 joints (no hands): the layout HumanML3D and AMASS pipelines write.
    pub fn smpl22() -> Self {
        Self::preset("smpl22", &SMPL_JOINTS[..22], &SMPL_PARENTS[..22], "left_hip", "right_hip")
    }

    /// The 21-joint skeleton of the bandai2 dataset (Bandai-Namco-Research-Motiondataset-2), as
    /// its `dataset.json` describes it: hips `UpperLeg_L` (13) and `UpperLeg_R` (17).
    pub fn bandai21() -> Self {
        let joints = [
            "Hips",
            "Spine",
            "Chest",
            "Neck",
            "Head",
            "Shoulder_L",
            "UpperArm_L",
            "LowerArm_L",
            "Hand_L",
            "Shoulder_R",
            "UpperArm_R",
            "LowerArm_R",
            "Hand_R",
            "UpperLeg_L",
            "LowerLeg_L",
            "Foot_L",
            "Toes_L",
            "UpperLeg_R",
            "LowerLeg_R",
            "Foot_R",
            "Toes_R",
        ];
        let p = |i| Some(i);
        let parents = [None, p(0), p(1), p(2), p(3), p(2), p(5), p(6), p(7), p(2), p(9), p(10), p(11), p(0), p(13), p(14), p(15), p(0), p(17), p(18), p(19)];
        Self::preset("bandai21", &joints, &parents, "UpperLeg_L", "UpperLeg_R")
    }

    /// The 31 joints of the CMU motion-capture BVH files (end sites left out), at the joints'
    /// origins, as `socdiff data convert` reads them.
    pub fn cmu31() -> Self {
        let joints = [
            "Hips",
            "LHipJoint",
            "LeftHip",
            "LeftKnee",
            "LeftAnkle",
            "LeftToe",
            "RHipJoint",
            "RightHip",
            "RightKnee",
            "RightAnkle",
            "RightToe",
            "lowerback",
            "Chest",
            "Chest2",
            "lowerneck",
            "Neck",
            "Head",
            "LeftCollar",
            "LeftShoulder",
            "LeftElbow",
            "LeftWrist",
            "lhand",
            "LFingers",
            "LThumb",
            "RightCollar",
            "RightShoulder",
            "RightElbow",
            "RightWrist",
            "rhand",
            "RFingers",
            "RThumb",
        ];
        let p = |i| Some(i);
        let parents = [
            None,
            p(0),
            p(1),
            p(2),
            p(3),
            p(4),
            p(0),
            p(6),
            p(7),
            p(8),
            p(9),
            p(0),
            p(11),
            p(12),
            p(13),
            p(14),
            p(15),
            p(13),
            p(17),
            p(18),
            p(19),
            p(20),
            p(21),
            p(20),
            p(13),
            p(24),
            p(25),
            p(26),
            p(27),
            p(28),
            p(27),
        ];
        Self::preset("cmu31", &joints, &parents, "LeftHip", "RightHip")
    }
}

/// SMPL's joints, in its order.
const SMPL_JOINTS: [&str; 24] = [
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hand",
    "right_hand",
];

/// The parent of each of SMPL's joints.
const SMPL_PARENTS: [Option<usize>; 24] = [
    None,
    Some(0),
    Some(0),
    Some(0),
    Some(1),
    Some(2),
    Some(3),
    Some(4),
    Some(5),
    Some(6),
    Some(7),
    Some(8),
    Some(9),
    Some(9),
    Some(9),
    Some(12),
    Some(13),
    Some(14),
    Some(16),
    Some(17),
    Some(18),
    Some(19),
    Some(20),
    Some(21),
];

/// The joints as a tree rooted at one joint.
#[derive(Clone, Debug, PartialEq)]
pub struct JointTree {
    /// The root joint.
    pub root: usize,
    /// Parent of every joint (`None` for the root).
    pub parent: Vec<Option<usize>>,
    /// Children of every joint, in bone order.
    pub children: Vec<Vec<usize>>,
    /// Joints in breadth-first order from the root (parents before children).
    pub order: Vec<usize>,
    /// Bones left out because they would close a cycle.
    pub dropped_bones: Vec<(usize, usize)>,
}

/// Builds the joint tree of `skeleton` by breadth-first search over its bones from `root`.
/// Joints not connected to the root are an error naming them.
pub fn joint_tree(skeleton: &Skeleton, root: usize) -> Result<JointTree> {
    let n = skeleton.num_joints();
    if root >= n {
        bail!("skeleton {}: root joint {root} out of range ({n} joints)", skeleton.name);
    }
    let mut adj: Vec<Vec<usize>> = vec![Vec::new(); n];
    for &(a, b) in &skeleton.bones {
        adj[a].push(b);
        adj[b].push(a);
    }
    let mut parent = vec![None; n];
    let mut seen = vec![false; n];
    let mut children = vec![Vec::new(); n];
    let mut order = Vec::with_capacity(n);
    let mut queue = VecDeque::from([root]);
    seen[root] = true;
    while let Some(j) = queue.pop_front() {
        order.push(j);
        for &c in &adj[j] {
            if !seen[c] {
                seen[c] = true;
                parent[c] = Some(j);
                children[j].push(c);
                queue.push_back(c);
            }
        }
    }
    let missing: Vec<&str> = (0..n).filter(|&j| !seen[j]).map(|j| skeleton.joints[j].as_str()).collect();
    if !missing.is_empty() {
        bail!(
            "skeleton {}: joint{} {} not connected by bones to the root {}; a BVH needs one tree of joints",
            skeleton.name,
            if missing.len() == 1 { "" } else { "s" },
            crate::files::list_some(&missing, 12),
            skeleton.joints[root]
        );
    }
    let dropped_bones = skeleton.bones.iter().copied().filter(|&(a, b)| parent[b] != Some(a) && parent[a] != Some(b)).collect();
    Ok(JointTree { root, parent, children, order, dropped_bones })
}

#[cfg(test)]
mod layout_tests {
    use super::*;

    #[test]
    fn layouts_are_compared_by_names_order_and_bones() {
        let m = Skeleton::mupots17();
        m.check_same_layout(&m).unwrap();
        // Arms swapped, names and data moved together.
        let mut swapped = m.clone();
        for (a, b) in [(2, 5), (3, 6), (4, 7)] {
            swapped.joints.swap(a, b);
        }
        let e = m.check_same_layout(&swapped).unwrap_err().to_string();
        assert!(e.contains("joint 2 is \"right_shoulder\"") && e.contains("\"left_shoulder\"") && e.contains("joint 5"), "{e}");
        // Renamed joint.
        let mut renamed = m.clone();
        renamed.joints[16] = "skull".into();
        let e = m.check_same_layout(&renamed).unwrap_err().to_string();
        assert!(e.contains("joint 16 is \"head\"") && e.contains("\"skull\"") && e.contains("no joint \"head\""), "{e}");
        // Permuted body-frame joints.
        let mut hips = m.clone();
        (hips.left, hips.right) = (m.right, m.left);
        let e = m.check_same_layout(&hips).unwrap_err().to_string();
        assert!(e.contains("left_hip / right_hip") && e.contains("right_hip / left_hip"), "{e}");
        // A bone less.
        let mut bones = m.clone();
        bones.bones.pop();
        assert!(m.check_same_layout(&bones).unwrap_err().to_string().contains("bone left_knee – left_ankle"));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_consistent() {
        let p = Skeleton::panoptic19();
        assert_eq!(p.num_joints(), 19);
        assert_eq!(p.bones.len(), 19);
        assert_eq!(p.joints[p.left], "left_hip");
        assert_eq!(p.joints[p.right], "right_hip");
        assert_eq!(p.foot_joints(), vec![8, 14]);
        let m = Skeleton::mupots17();
        assert_eq!(m.num_joints(), 17);
        assert_eq!(m.bones.len(), 16);
        assert_eq!(m.joints[m.left], "left_hip");
        assert_eq!(m.foot_joints(), vec![10, 13]);
        assert_eq!(m.head_joints(), vec![0, 16]);
    }

    /// Every named skeleton is one tree, its body frame is its hips as the joint vocabulary
    /// reads them, and NDMS finds its default joints; CMU's is what the BVH importer makes of
    /// a CMU file.
    #[test]
    fn named_skeletons_are_trees_with_their_hips_as_body_frame() {
        for name in NAMED_SKELETONS {
            let s = Skeleton::named(name).unwrap();
            assert_eq!(s.name, name);
            // One connected body; a tree except Panoptic's face, whose eyes and ears close a loop.
            let tree = joint_tree(&s, 0).unwrap();
            let loops = if name == "panoptic19" { 1 } else { 0 };
            assert_eq!((s.bones.len(), tree.dropped_bones.len()), (s.num_joints() - 1 + loops, loops), "{name}");
            assert_eq!(crate::data::joints::body_frame_from_names(&s.joints), Some((s.left, s.right)), "{name}");
            assert!(s.joints[s.left].to_lowercase().contains('l') && s.joints[s.right].to_lowercase().contains('r'), "{name}");
            let ndms = crate::metrics::ndms::default_joints(&s).unwrap();
            assert_eq!(ndms.len(), 11, "{name}");
        }
        assert_eq!(
            (Skeleton::mrt15().num_joints(), Skeleton::h36m17().num_joints(), Skeleton::smpl22().num_joints(), Skeleton::smpl24().num_joints()),
            (15, 17, 22, 24)
        );
        // MRT's joints are MuPoTS's, in MRT's order.
        let (mrt, mupots) = (Skeleton::mrt15(), Skeleton::mupots17());
        let picked: Vec<usize> = mrt.joints.iter().map(|j| mupots.joint_index(j).unwrap()).collect();
        assert_eq!(picked, [14, 11, 12, 13, 8, 9, 10, 1, 0, 5, 6, 7, 2, 3, 4]);
        let e = Skeleton::named("smpl").unwrap_err().to_string();
        assert!(e.contains("\"smpl\"") && e.contains("smpl22, smpl24"), "{e}");
    }

    #[test]
    fn cmu31_is_the_layout_of_the_cmu_files() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/cmu_bvh/131_01.bvh");
        if !path.exists() {
            crate::testing::skip_absent(&path, "CMU BVH");
            return;
        }
        let scene = crate::data::import::load_scene(&path).unwrap();
        Skeleton::cmu31().check_same_layout(&scene.skeleton).unwrap();
    }

    #[test]
    fn bad_skeletons_are_errors() {
        let j = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert!(Skeleton::new("x", j(&["a", "a"]), vec![], 0, 1).is_err());
        assert!(Skeleton::new("x", j(&["a", "b"]), vec![(0, 2)], 0, 1).is_err());
        assert!(Skeleton::new("x", j(&["a", "b"]), vec![], 0, 0).is_err());
        let e = Skeleton::mupots17().require_joint("tail").unwrap_err().to_string();
        assert!(e.contains("tail") && e.contains("mupots17"), "{e}");
    }
}
