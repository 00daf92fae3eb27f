//! The joint vocabulary: what a joint is, from its name. Every module that reads joint names
//! (joint maps, the body frame, NDMS's joints, facing for SSCP, motion kinds, importers) asks
//! here, so that one table says which names mean which body point.
//!
//! Every joint name is split into lowercase words (at `_`, `-`, spaces, digits and camel-case
//! boundaries: `UpperArm_L` → `upper arm l`, `LeftUpLeg` → `left up leg`); a word `l`/`left` or
//! `r`/`right` gives the side, the other words (joined) say what the joint is. [`Part`] lists
//! the body points socdiff knows, each with the words that name it in common layouts, in order
//! of preference:
//!
//! | part | names (side words removed) |
//! |---|---|
//! | pelvis | pelvis, hips, hip (no side), root, midhip, hipcentre, pelvisroot |
//! | spine / chest | spine, upperback, lowerback / chest, spine2, spine1, thorax, upperchest |
//! | neck, head, head top, nose | neck, lowerneck; head; headtop, headend, topofhead; nose |
//! | eye, ear (sided) | eye; ear |
//! | shoulder (sided) | upperarm, arm, humerus, shoulder — the glenohumeral joint |
//! | clavicle (sided) | clavicle, collar, shoulder when the side also has an upperarm/arm joint |
//! | elbow, wrist (sided) | elbow, lowerarm, forearm, radius; wrist, hand |
//! | hip, knee, ankle, toe (sided) | hip, upleg, upperleg, thigh, femur, hipjoint; knee, lowerleg, leg, shin, tibia; ankle, foot; toe, toes, toebase |
//!
//! A one-word lowercase name that is `l` or `r` followed by a known name (CMU's ASF-derived
//! `lfemur`, `rhumerus`) is sided too; an end site `head_end` is the head top.
//!
//! (In bandai2 and CMU BVH `Shoulder_L`/`LeftShoulder` is the clavicle and `UpperArm_L`/`LeftArm`
//! the shoulder; in MuPoTS and Panoptic `left_shoulder` is the shoulder.)
//!

use std::collections::HashMap;

/// Side of a body part.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Side {
    /// On the body's mid-line.
    Centre,
    /// The person's left.
    Left,
    /// The person's right.
    Right,
}

/// Body points with a known meaning (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[allow(missing_docs)]
pub enum Part {
    Pelvis,
    Spine,
    Chest,
    Neck,
    Head,
    HeadTop,
    Nose,
    Eye,
    Ear,
    Clavicle,
    Shoulder,
    Elbow,
    Wrist,
    Hip,
    Knee,
    Ankle,
    Toe,
}

/// Names of each part (side words removed), in order of preference. The order of this table is
/// also the order in which parts claim joints: the shoulder claims `upperarm`/`arm` before the
/// clavicle may take `shoulder`.
const PART_NAMES: [(Part, &[&str]); 17] = [
    (Part::Pelvis, &["pelvis", "hips", "hip", "root", "midhip", "hipcentre", "hipcenter", "pelvisroot"]),
    (Part::Spine, &["spine", "upperback", "lowerback"]),
    (Part::Chest, &["chest", "spine2", "spine1", "thorax", "upperchest"]),
    (Part::Neck, &["neck", "lowerneck"]),
    (Part::Head, &["head"]),
    (Part::HeadTop, &["headtop", "headend", "topofhead"]),
    (Part::Nose, &["nose"]),
    (Part::Eye, &["eye"]),
    (Part::Ear, &["ear"]),
    (Part::Shoulder, &["upperarm", "arm", "humerus", "shoulder"]),
    (Part::Clavicle, &["clavicle", "collar", "shoulder"]),
    (Part::Elbow, &["elbow", "lowerarm", "forearm", "radius"]),
    (Part::Wrist, &["wrist", "hand"]),
    (Part::Hip, &["hip", "upleg", "upperleg", "thigh", "femur", "hipjoint"]),
    (Part::Knee, &["knee", "lowerleg", "leg", "shin", "tibia"]),
    (Part::Ankle, &["ankle", "foot"]),
    (Part::Toe, &["toe", "toes", "toebase"]),
];

fn is_sided(part: Part) -> bool {
    !matches!(part, Part::Pelvis | Part::Spine | Part::Chest | Part::Neck | Part::Head | Part::HeadTop | Part::Nose)
}

/// A joint name as every name lookup compares it: without a `namespace:` prefix (Mixamo's
/// `mixamorig:`), letters and digits only, lower case (`mixamorig:Left_Fore-Arm` →
/// `leftforearm`).
pub fn normalize_joint_name(name: &str) -> String {
    strip_namespace(name).chars().filter(|c| c.is_alphanumeric()).flat_map(char::to_lowercase).collect()
}

/// The name after the last `:`.
fn strip_namespace(name: &str) -> &str {
    name.rsplit(':').next().unwrap_or(name)
}

/// Splits a joint name into its side and the remaining words joined: `UpperArm_L` →
/// `(Left, "upperarm")`, `LeftUpLeg` → `(Left, "upleg")`, `Spine1` → `(Centre, "spine1")`.
pub fn parse_joint_name(name: &str) -> (Side, String) {
    let name = strip_namespace(name);
    let mut words: Vec<String> = Vec::new();
    let mut cur = String::new();
    let chars: Vec<char> = name.chars().collect();
    for (i, &c) in chars.iter().enumerate() {
        if !c.is_alphanumeric() {
            if !cur.is_empty() {
                words.push(std::mem::take(&mut cur));
            }
            continue;
        }
        // Camel case: a new word at an upper-case letter after a lower-case one, or before a
        // lower-case one after upper-case ones ("LHip" → "L", "Hip").
        let prev = i.checked_sub(1).map(|p| chars[p]);
        let next = chars.get(i + 1).copied();
        let boundary = c.is_uppercase()
            && (prev.is_some_and(|p| p.is_lowercase() || p.is_ascii_digit())
                || (prev.is_some_and(|p| p.is_uppercase()) && next.is_some_and(|n| n.is_lowercase())));
        if boundary && !cur.is_empty() {
            words.push(std::mem::take(&mut cur));
        }
        cur.extend(c.to_lowercase());
    }
    if !cur.is_empty() {
        words.push(cur);
    }
    let mut side = Side::Centre;
    let mut rest = String::new();
    for w in words {
        match w.as_str() {
            "l" | "left" if side == Side::Centre => side = Side::Left,
            "r" | "right" if side == Side::Centre => side = Side::Right,
            _ => rest.push_str(&w),
        }
    }
    // "lfemur": a side letter glued to a known name.
    if side == Side::Centre {
        for (letter, s) in [('l', Side::Left), ('r', Side::Right)] {
            if let Some(tail) = rest.strip_prefix(letter) {
                if PART_NAMES.iter().any(|(_, names)| names.contains(&tail)) {
                    return (s, tail.to_string());
                }
            }
        }
    }
    (side, rest)
}

/// The joint (index into `joints`, a skeleton's joint names) that plays each part, found by
/// name (module docs).
pub fn joint_parts(joints: &[String]) -> Vec<((Part, Side), usize)> {
    let parsed: Vec<(Side, String)> = joints.iter().map(|j| parse_joint_name(j)).collect();
    let mut taken = vec![false; parsed.len()];
    let mut out = Vec::new();
    for (part, names) in PART_NAMES {
        let sides: &[Side] = if is_sided(part) { &[Side::Left, Side::Right] } else { &[Side::Centre] };
        for &side in sides {
            let found = names.iter().find_map(|n| (0..parsed.len()).find(|&j| !taken[j] && parsed[j].0 == side && parsed[j].1 == *n));
            if let Some(j) = found {
                taken[j] = true;
                out.push(((part, side), j));
            }
        }
    }
    out
}

/// The body-frame joints (left, right) of a skeleton with these joint names: the hips, else the
/// shoulders, found by name (module docs); `None` when neither pair is there.
pub fn body_frame_from_names(joints: &[String]) -> Option<(usize, usize)> {
    if joints.len() < 2 {
        return None;
    }
    [Part::Hip, Part::Shoulder].into_iter().find_map(|p| sided_pair(joints, p))
}

/// The first of `wanted` (part, side) that `joints` has, in order of preference.
pub fn find_part(joints: &[String], wanted: &[(Part, Side)]) -> Option<usize> {
    let parts: HashMap<(Part, Side), usize> = joint_parts(joints).into_iter().collect();
    wanted.iter().find_map(|k| parts.get(k).copied())
}

/// The left and right joint of a sided `part`, when `joints` has both.
pub fn sided_pair(joints: &[String], part: Part) -> Option<(usize, usize)> {
    let parts: HashMap<(Part, Side), usize> = joint_parts(joints).into_iter().collect();
    Some((*parts.get(&(part, Side::Left))?, *parts.get(&(part, Side::Right))?))
}

/// Words whose presence in a joint's name marks a joint that touches the floor when standing.
pub const FOOT_WORDS: [&str; 4] = ["ankle", "foot", "toe", "heel"];
/// Words whose presence in a joint's name marks a joint at the top of the body.
pub const HEAD_WORDS: [&str; 4] = ["head", "nose", "eye", "ear"];

/// Indices of the joints whose normalized name contains one of `words`.
pub fn joints_with_words(joints: &[String], words: &[&str]) -> Vec<usize> {
    joints.iter().enumerate().filter(|(_, j)| words.iter().any(|w| normalize_joint_name(j).contains(w))).map(|(i, _)| i).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::Skeleton;

    #[test]
    fn names_split_into_side_and_part() {
        assert_eq!(parse_joint_name("UpperArm_L"), (Side::Left, "upperarm".into()));
        assert_eq!(parse_joint_name("LeftUpLeg"), (Side::Left, "upleg".into()));
        assert_eq!(parse_joint_name("right_shoulder"), (Side::Right, "shoulder".into()));
        assert_eq!(parse_joint_name("RHipJoint"), (Side::Right, "hipjoint".into()));
        assert_eq!(parse_joint_name("head_top"), (Side::Centre, "headtop".into()));
        assert_eq!(parse_joint_name("Spine1"), (Side::Centre, "spine1".into()));
        assert_eq!(parse_joint_name("LowerArm_R"), (Side::Right, "lowerarm".into()));
        assert_eq!(parse_joint_name("lfemur"), (Side::Left, "femur".into()));
        assert_eq!(parse_joint_name("rradius"), (Side::Right, "radius".into()));
        assert_eq!(parse_joint_name("root"), (Side::Centre, "root".into()));
        assert_eq!(parse_joint_name("lowerback"), (Side::Centre, "lowerback".into()));
    }

    fn part(sk: &Skeleton, p: Part, s: Side) -> Option<&str> {
        joint_parts(&sk.joints).into_iter().find(|(k, _)| *k == (p, s)).map(|(_, j)| sk.joints[j].as_str())
    }

    #[test]
    fn shoulders_and_clavicles_are_told_apart() {
        let b = crate::data::Skeleton::bandai21();
        assert_eq!(part(&b, Part::Shoulder, Side::Left), Some("UpperArm_L"));
        assert_eq!(part(&b, Part::Clavicle, Side::Left), Some("Shoulder_L"));
        assert_eq!(part(&b, Part::Hip, Side::Right), Some("UpperLeg_R"));
        assert_eq!(part(&b, Part::Knee, Side::Right), Some("LowerLeg_R"));
        assert_eq!(part(&b, Part::Ankle, Side::Left), Some("Foot_L"));
        assert_eq!(part(&b, Part::Pelvis, Side::Centre), Some("Hips"));
        let m = Skeleton::mupots17();
        assert_eq!(part(&m, Part::Shoulder, Side::Left), Some("left_shoulder"));
        assert_eq!(part(&m, Part::Clavicle, Side::Left), None);
        assert_eq!(part(&m, Part::HeadTop, Side::Centre), Some("head_top"));
        assert_eq!(joint_parts(&m.joints).len(), 17, "every MuPoTS joint has a meaning");
        assert_eq!(joint_parts(&Skeleton::panoptic19().joints).len(), 19, "every Panoptic joint has a meaning");
    }

    #[test]
    fn parts_and_words_find_the_joints_every_module_asks_for() {
        let m = Skeleton::mupots17();
        let j = &m.joints;
        let name = |i: Option<usize>| i.map(|i| j[i].as_str());
        // Head: nose first, then head, then head top.
        assert_eq!(name(find_part(j, &[(Part::Nose, Side::Centre), (Part::Head, Side::Centre), (Part::HeadTop, Side::Centre)])), Some("head"));
        assert_eq!(sided_pair(j, Part::Hip).map(|(l, r)| (j[l].as_str(), j[r].as_str())), Some(("left_hip", "right_hip")));
        assert_eq!(body_frame_from_names(j), sided_pair(j, Part::Hip));
        assert_eq!(find_part(j, &[(Part::Eye, Side::Left)]), None);
        let feet: Vec<&str> = joints_with_words(j, &FOOT_WORDS).iter().map(|&i| j[i].as_str()).collect();
        assert_eq!(feet, ["right_ankle", "left_ankle"]);
        // CMU's ASF-derived names and a hip joint named only by its bone.
        let cmu: Vec<String> = ["root", "lhipjoint", "rhipjoint", "ltibia", "rtibia"].iter().map(|s| s.to_string()).collect();
        assert_eq!(sided_pair(&cmu, Part::Hip), Some((1, 2)));
        assert_eq!(find_part(&cmu, &[(Part::Pelvis, Side::Centre)]), Some(0));
    }
}
