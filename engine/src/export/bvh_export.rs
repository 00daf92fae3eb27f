//! BVH export: one file per person, a fixed skeleton and joint rotations solved from positions.
//!
//! # Skeleton
//! The joints form a tree built by breadth-first search over the skeleton's bones (taken as
//! undirected) from the root: the joint named `pelvis`, `hips`, `hip`, `root`, `midhip` or
//! `hip_centre` (ignoring case and punctuation), else the joint closest to the midpoint of the
//! body-frame joints (hips) on average, or the joint named by [`BvhExportOptions::root`].
//! Bones that would close a cycle (e.g. Panoptic's face) are left out of the hierarchy; joints
//! that no bone connects to the root are an error naming them. Each bone's length is its mean
//! over the person's valid frames; bones shorter than 0.1 mm (CMU's `lhipjoint`) get a zero
//! offset. Joint names are written with whitespace and braces replaced by `_`.
//!
//! Rest pose (all rotations zero): bone directions of the person's first valid frame, turned
//! about the vertical so that the person faces the file's +z, except that the children of a
//! joint with several children get their Procrustes-mean directions over the valid frames (in
//! that joint's own frame), which minimizes the least-squares fit below.
//!
//! # Rotations
//! Joints are solved from the root outwards, frame by frame. The root's position channels hold
//! its observed position. A joint's global rotation maps the rest offsets of its children
//! (looking through zero-length children to theirs) onto the observed directions from the
//! joint's *reconstructed* position to the children's observed positions, so errors do not
//! accumulate along chains:
//! - one child: the smallest rotation from the parent's frame that aligns the bone (no twist
//!   relative to the parent),
//! - several children: the rotation that minimizes the summed squared child position errors
//!   (Horn's quaternion solution of Wahba's problem), weakly pulled towards the parent's frame
//!   so that collinear children (two hips) leave no free twist,
//! - no children: the parent's rotation (zero local rotation).
//!
//! # File conventions
//! - Units: centimetres by default ([`BvhUnits`]); re-import with scale 0.01
//!   (`BvhImport { scale: 0.01, .. }`, or `--bvh-scale 0.01` / `auto`).
//! - Axes: y up, the standard for BVH; re-import with [`UpAxis::Y`]. A scene point
//!   `(x, y, z)` (z up) is written as `(x, z, -y)`.
//! - Channels: the root has `Xposition Yposition Zposition Zrotation Xrotation Yrotation`, every
//!   other joint `Zrotation Xrotation Yrotation` (the CMU order): the local rotation is
//!   `R = Rz(a) · Rx(b) · Ry(c)` in degrees, intrinsic, as [`crate::data::bvh`] reads it.
//!   Angles are unwrapped over time (no ±360° jumps). Leaves end with an `End Site` that
//!   continues their bone by 10 cm (or half its length, if shorter).
//!
//! # Accuracy, and `stretch`
//! Re-importing a fixed-skeleton file reproduces the joint positions up to the residual of the
//! multi-child fits and each bone's deviation from its mean length; [`ExportedBvh`] reports the
//! error measured by re-importing the text. Rigid mocap (the bundled CMU clip) comes back to
//! within 1e-6 m. Markerless data need not have constant bones: in MuPoTS-3D a person's
//! hip–knee distance varies by up to 22.5 cm, which no fixed skeleton can follow. With
//! [`BvhExportOptions::stretch`] every non-root joint also gets position channels
//! (`Xposition Yposition Zposition Zrotation Xrotation Yrotation`) holding its recorded offset
//! in its parent's frame for each frame; the rotations are fitted the same way (to the frame's
//! bone lengths), and re-importing is exact up to the written precision (1e-5 units). Blender's
//! importer reads per-joint position channels; tools that ignore them see the fixed skeleton.

use super::safe_file_name;
use crate::data::bvh::{parse_bvh, BvhImport, UpAxis};
use crate::data::rotation::{add, apply, best_fit_rotation, cross, euler_zxy, mul, norm, normalize, rotation_between, scale, sub, transpose, IDENTITY, M3, V3};
use crate::data::scene::Scene;
use crate::data::skeleton::Skeleton;
pub use crate::data::skeleton::{joint_tree, JointTree};
use crate::{bail, Error, Result};
use std::fmt::Write as _;
use std::path::Path;

/// Bones shorter than this (metres) are treated as zero-length.
const ZERO_BONE: f64 = 1e-4;
/// Scene (z up) to file (y up) axes: `(x, y, z) ↦ (x, z, -y)`.
const C: M3 = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]];

/// Length unit of the written file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum BvhUnits {
    /// Centimetres (default; the common BVH unit).
    #[default]
    #[cfg_attr(feature = "clap", value(name = "cm"))]
    Centimetres,
    /// Metres.
    #[cfg_attr(feature = "clap", value(name = "m"))]
    Metres,
}

impl BvhUnits {
    /// File units per metre.
    pub fn per_metre(self) -> f64 {
        match self {
            BvhUnits::Centimetres => 100.0,
            BvhUnits::Metres => 1.0,
        }
    }

    /// Metres per file unit: the scale to re-import with ([`BvhImport::scale`]).
    pub fn import_scale(self) -> f64 {
        1.0 / self.per_metre()
    }
}

/// Options for BVH export.
#[derive(Clone, Debug, Default)]
pub struct BvhExportOptions {
    /// Length unit of the file.
    pub units: BvhUnits,
    /// Root joint by name (default: found automatically, see the module docs).
    pub root: Option<String>,
    /// Give every non-root joint position channels holding its recorded per-frame offset in its
    /// parent's frame, so that re-importing reproduces the positions exactly even where bone
    /// lengths and angles between sibling bones vary (default false: a fixed skeleton; see the
    /// module docs).
    pub stretch: bool,
}

/// One written BVH: its file name, text and the measured re-import error.
#[derive(Clone, Debug)]
pub struct ExportedBvh {
    /// Person index in the scene.
    pub person: usize,
    /// Suggested file name (`SCENE_PERSON.bvh`, or `SCENE.bvh` for a one-person scene whose
    /// person is named like it).
    pub file_name: String,
    /// The BVH text.
    pub text: String,
    /// Root joint name.
    pub root: String,
    /// Largest joint position error after re-importing the text, metres, over valid frames.
    pub max_error_m: f64,
    /// Mean joint position error after re-importing, metres, over valid frames.
    pub mean_error_m: f64,
}

/// File names for the persons of `scene` (unique, file-name safe).
pub fn file_names(scene: &Scene) -> Vec<String> {
    let base = safe_file_name(&scene.name);
    let mut names: Vec<String> = scene
        .persons
        .iter()
        .map(|p| if scene.num_persons() == 1 && p.id == scene.name { format!("{base}.bvh") } else { format!("{base}_{}.bvh", safe_file_name(&p.id)) })
        .collect();
    for i in 0..names.len() {
        if names[..i].contains(&names[i]) || names[i + 1..].contains(&names[i]) {
            names[i] = format!("{base}_p{i}.bvh");
        }
    }
    names
}

/// Joint names as written: whitespace, braces and `:` replaced by `_`, made unique.
fn bvh_names(sk: &Skeleton) -> Vec<String> {
    let mut names: Vec<String> = Vec::with_capacity(sk.num_joints());
    for j in &sk.joints {
        let mut n: String = j.chars().map(|c| if c.is_whitespace() || "{}".contains(c) { '_' } else { c }).collect();
        if n.is_empty() {
            n.push('_');
        }
        let base = n.clone();
        let mut k = 2;
        while names.contains(&n) {
            n = format!("{base}_{k}");
            k += 1;
        }
        names.push(n);
    }
    names
}

/// The BVH of person `person` of `scene` (see the module docs), with its measured re-import
/// error.
#[allow(clippy::needless_range_loop)] // index-heavy kinematics reads best with indices
pub fn person_to_bvh(scene: &Scene, person: usize, opts: &BvhExportOptions) -> Result<ExportedBvh> {
    if person >= scene.num_persons() {
        bail!("scene {}: person {person} out of range ({} persons)", scene.name, scene.num_persons());
    }
    let sk = &scene.skeleton;
    let nj = sk.num_joints();
    let root = scene.root_joint(person, opts.root.as_deref())?;
    let tree = joint_tree(sk, root)?;
    let frames = scene.num_frames();
    let x = |f: usize, j: usize| -> V3 { std::array::from_fn(|k| scene.positions[[f, person, j, k]] as f64) };
    let mut valid: Vec<usize> = (0..frames).filter(|&f| scene.is_valid(f, person)).collect();
    if valid.is_empty() {
        valid = (0..frames).collect();
    }

    // Bone lengths (mean over valid frames) and rest directions.
    let mut length = vec![0.0f64; nj];
    for j in 0..nj {
        if let Some(p) = tree.parent[j] {
            length[j] = valid.iter().map(|&f| norm(sub(x(f, j), x(f, p)))).sum::<f64>() / valid.len() as f64;
        }
    }
    let zero = |j: usize| tree.parent[j].is_some() && length[j] < ZERO_BONE;
    let f_ref = valid[0];
    let facing = facing_rotation(x(f_ref, sk.left), x(f_ref, sk.right));
    let mut offset = vec![[0.0f64; 3]; nj];
    for j in 0..nj {
        let Some(p) = tree.parent[j] else { continue };
        if zero(j) {
            continue;
        }
        let dir = std::iter::once(f_ref).chain(valid.iter().copied()).map(|f| sub(x(f, j), x(f, p))).find(|d| norm(*d) > 1e-9).unwrap_or([0.0, 0.0, 1.0]);
        offset[j] = scale(normalize(apply(&facing, dir)), length[j]);
    }
    // Fit targets: children, looking through zero-length children.
    let mut targets: Vec<Vec<usize>> = vec![Vec::new(); nj];
    for j in 0..nj {
        let mut stack: Vec<usize> = tree.children[j].iter().rev().copied().collect();
        while let Some(c) = stack.pop() {
            if zero(c) {
                stack.extend(tree.children[c].iter().rev());
            } else {
                targets[j].push(c);
            }
        }
    }
    // Procrustes-mean rest directions for joints with several targets.
    let stride = (valid.len() / 1500).max(1);
    for j in 0..nj {
        if targets[j].len() < 2 {
            continue;
        }
        for _ in 0..4 {
            let mut acc = vec![[0.0f64; 3]; targets[j].len()];
            for &f in valid.iter().step_by(stride) {
                let obs: Vec<V3> = targets[j].iter().map(|&t| sub(x(f, t), x(f, j))).collect();
                let pairs: Vec<(V3, V3, f64)> = targets[j].iter().zip(&obs).map(|(&t, &o)| (offset[t], o, 1.0)).collect();
                let r = fit_rotation(&pairs, &IDENTITY);
                for (a, o) in acc.iter_mut().zip(&obs) {
                    if norm(*o) > 1e-9 {
                        *a = add(*a, apply(&transpose(&r), normalize(*o)));
                    }
                }
            }
            for (&t, a) in targets[j].iter().zip(&acc) {
                if norm(*a) > 1e-9 {
                    offset[t] = scale(normalize(*a), length[t]);
                }
            }
        }
    }

    // Solve every frame: global rotations G, reconstructed positions P, local Euler angles.
    let mut dfs = Vec::with_capacity(nj);
    let mut stack = vec![root];
    while let Some(j) = stack.pop() {
        dfs.push(j);
        stack.extend(tree.children[j].iter().rev());
    }
    let upm = opts.units.per_metre();
    let mut g = vec![IDENTITY; nj];
    let mut p = vec![[0.0f64; 3]; nj];
    let mut prev_root = facing_inverse_guess(&facing);
    let mut prev_angles = vec![[f64::NAN; 3]; nj];
    let mut motion = String::with_capacity(frames * (nj * 3 + 3) * 11);
    // Per frame: `ro` are the rest vectors the rotations are fitted with (scaled to the frame's
    // bone lengths with `stretch`), `eo` the offsets written (exact with `stretch`).
    let mut ro = offset.clone();
    let mut eo = offset.clone();
    for f in 0..frames {
        if opts.stretch {
            for j in 0..nj {
                if let Some(par) = tree.parent[j].filter(|_| !zero(j)) {
                    ro[j] = scale(offset[j], norm(sub(x(f, j), x(f, par))) / length[j]);
                }
            }
        }
        for &j in &tree.order {
            let (pos, prior) = match tree.parent[j] {
                None => (x(f, j), prev_root),
                Some(par) => {
                    if opts.stretch {
                        eo[j] = apply(&transpose(&g[par]), sub(x(f, j), p[par]));
                    }
                    (add(p[par], apply(&g[par], eo[j])), g[par])
                }
            };
            p[j] = pos;
            let pairs: Vec<(V3, V3, f64)> = targets[j].iter().map(|&t| (ro[t], sub(x(f, t), pos), 1.0)).collect();
            g[j] = fit_rotation(&pairs, &prior);
        }
        prev_root = g[root];
        for (k, &j) in dfs.iter().enumerate() {
            let local = match tree.parent[j] {
                None => g[j],
                Some(par) => mul(&transpose(&g[par]), &g[j]),
            };
            let file_rot = mul(&mul(&C, &local), &transpose(&C));
            let mut a = euler_zxy(&file_rot);
            for (ai, prev) in a.iter_mut().zip(&prev_angles[j]) {
                if prev.is_finite() {
                    *ai += 360.0 * ((prev - *ai) / 360.0).round();
                }
            }
            prev_angles[j] = a;
            if k > 0 {
                motion.push(' ');
            }
            if tree.parent[j].is_none() {
                let r = scale(apply(&C, p[j]), upm);
                let _ = write!(motion, "{:.5} {:.5} {:.5} ", r[0], r[1], r[2]);
            } else if opts.stretch {
                let r = scale(apply(&C, eo[j]), upm);
                let _ = write!(motion, "{:.5} {:.5} {:.5} ", r[0], r[1], r[2]);
            }
            let _ = write!(motion, "{:.6} {:.6} {:.6}", a[0], a[1], a[2]);
        }
        motion.push('\n');
    }

    // Hierarchy.
    let names = bvh_names(sk);
    let mut text = String::with_capacity(motion.len() + nj * 200);
    text.push_str("HIERARCHY\n");
    write_joint(&mut text, &tree, &names, &offset, upm, opts.stretch, root, 0);
    let _ = write!(text, "MOTION\nFrames: {frames}\nFrame Time: {:.8}\n", 1.0 / scene.fps);
    text.push_str(&motion);

    // Re-import and measure.
    let (max_error_m, mean_error_m) = reimport_error(scene, person, &text, &names, &valid, opts.units)?;
    Ok(ExportedBvh { person, file_name: file_names(scene).swap_remove(person), text, root: sk.joints[root].clone(), max_error_m, mean_error_m })
}

#[allow(clippy::too_many_arguments)]
fn write_joint(out: &mut String, tree: &JointTree, names: &[String], offset: &[V3], upm: f64, stretch: bool, j: usize, depth: usize) {
    let ind = "\t".repeat(depth);
    let o = scale(apply(&C, offset[j]), upm);
    match tree.parent[j] {
        None => {
            let _ = writeln!(out, "ROOT {}\n{{\n{ind}\tOFFSET 0.00000 0.00000 0.00000", names[j]);
            let _ = writeln!(out, "{ind}\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation");
        }
        Some(_) => {
            let _ = writeln!(out, "{ind}JOINT {}\n{ind}{{\n{ind}\tOFFSET {:.5} {:.5} {:.5}", names[j], o[0], o[1], o[2]);
            if stretch {
                let _ = writeln!(out, "{ind}\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation");
            } else {
                let _ = writeln!(out, "{ind}\tCHANNELS 3 Zrotation Xrotation Yrotation");
            }
        }
    }
    if tree.children[j].is_empty() {
        let len = norm(offset[j]);
        let end = if len > 1e-9 { scale(normalize(offset[j]), (0.5 * len).min(0.1)) } else { [0.0, 0.0, 0.05] };
        let e = scale(apply(&C, end), upm);
        let _ = writeln!(out, "{ind}\tEnd Site\n{ind}\t{{\n{ind}\t\tOFFSET {:.5} {:.5} {:.5}\n{ind}\t}}", e[0], e[1], e[2]);
    }
    for &c in &tree.children[j] {
        write_joint(out, tree, names, offset, upm, stretch, c, depth + 1);
    }
    let _ = writeln!(out, "{ind}}}");
}

/// Parses `text` with the BVH importer and compares with the scene: (max, mean) joint error in
/// metres over `frames`.
fn reimport_error(scene: &Scene, person: usize, text: &str, names: &[String], frames: &[usize], units: BvhUnits) -> Result<(f64, f64)> {
    let sk = &scene.skeleton;
    let bvh = parse_bvh(text).map_err(|e| Error::invalid(format!("exported BVH does not parse back: {e}")))?;
    let opts = BvhImport {
        scale: units.import_scale(),
        up_axis: UpAxis::Y,
        left_right: Some((names[sk.left].clone(), names[sk.right].clone())),
        ..Default::default()
    };
    let back = bvh.to_scene("reimport", &opts)?;
    let index: Vec<usize> =
        names.iter().map(|n| back.skeleton.joint_index(n).ok_or_else(|| Error::invalid(format!("exported BVH lost joint {n}")))).collect::<Result<_>>()?;
    let (mut max, mut sum, mut n) = (0.0f64, 0.0f64, 0usize);
    for &f in frames {
        for (j, &b) in index.iter().enumerate() {
            let d = (0..3).map(|k| (scene.positions[[f, person, j, k]] as f64 - back.positions[[f, 0, b, k]] as f64).powi(2)).sum::<f64>().sqrt();
            max = max.max(d);
            sum += d;
            n += 1;
        }
    }
    Ok((max, sum / n.max(1) as f64))
}

/// Writes one BVH per person of `scene` into the existing directory `dir`; `on_done` is called
/// after each person.
pub fn write_scene_bvh(scene: &Scene, dir: &Path, opts: &BvhExportOptions, on_done: &mut dyn FnMut(&ExportedBvh)) -> Result<Vec<ExportedBvh>> {
    let mut out = Vec::with_capacity(scene.num_persons());
    for p in 0..scene.num_persons() {
        let e = person_to_bvh(scene, p, opts)?;
        let path = dir.join(&e.file_name);
        std::fs::write(&path, &e.text).map_err(|err| Error::io(&path, err))?;
        on_done(&e);
        out.push(e);
    }
    Ok(out)
}

// ---------------------------------------------------------------------------------------------
// Small 3D rotation toolkit (f64).

/// Rotation about the vertical (z) that turns the person's facing direction — `(left − right)
/// × up`, horizontal — to −y (the file's +z). Identity when the hips are degenerate.
fn facing_rotation(left: V3, right: V3) -> M3 {
    let f = cross(sub(left, right), [0.0, 0.0, 1.0]);
    if f[0].hypot(f[1]) < 1e-9 {
        return IDENTITY;
    }
    let theta = -std::f64::consts::FRAC_PI_2 - f[1].atan2(f[0]);
    let (s, c) = theta.sin_cos();
    [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
}

/// The root's prior for the first frame: the rotation that undoes the rest pose's facing turn.
fn facing_inverse_guess(facing: &M3) -> M3 {
    transpose(facing)
}

/// The global rotation `R` of a joint from `(rest, observed, weight)` pairs (`R·rest ≈
/// observed`), given the `prior` rotation (the parent's): see the module docs.
fn fit_rotation(pairs: &[(V3, V3, f64)], prior: &M3) -> M3 {
    let usable: Vec<&(V3, V3, f64)> = pairs.iter().filter(|(a, b, w)| norm(*a) > 1e-9 && norm(*b) > 1e-9 && *w > 0.0).collect();
    match usable.len() {
        0 => *prior,
        1 => {
            let (a, b, _) = usable[0];
            mul(&rotation_between(apply(prior, *a), *b), prior)
        }
        _ => {
            let mut all: Vec<(V3, V3, f64)> = usable.iter().map(|p| **p).collect();
            let w: f64 = all.iter().map(|(a, b, w)| w * norm(*a) * norm(*b)).sum::<f64>() * 1e-9;
            for k in 0..3 {
                all.push((IDENTITY[k], std::array::from_fn(|r| prior[r][k]), w));
            }
            best_fit_rotation(&all)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::bvh::{import_bvh, CMU_SCALE};
    use crate::data::rotation::axis_rotation;
    use crate::data::rotation::tests::{max_diff, random_rotation};
    use crate::data::test_util::{cmu_clip, mupots, tmp, walkers};
    use ndarray::Array4;
    use rand::{rngs::StdRng, Rng, SeedableRng};

    /// The rotation toolkit's own tests are in `data::rotation`; here the fit with a prior.
    #[test]
    fn fit_rotation_recovers_known_rotations_and_keeps_the_prior_twist() {
        let mut rng = StdRng::seed_from_u64(7);
        for _ in 0..200 {
            let r = random_rotation(&mut rng);
            let pairs: Vec<(V3, V3, f64)> = (0..3)
                .map(|_| {
                    let a: V3 = std::array::from_fn(|_| rng.gen_range(-1.0..1.0));
                    (a, apply(&r, a), 1.0)
                })
                .collect();
            let fit = fit_rotation(&pairs, &IDENTITY);
            assert!(max_diff(&fit, &r) < 1e-6, "fit: {}", max_diff(&fit, &r));
            // One pair: the smallest turn from the prior.
            let one = fit_rotation(&pairs[..1], &IDENTITY);
            assert!(norm(sub(apply(&one, normalize(pairs[0].0)), normalize(pairs[0].1))) < 1e-9);
        }
        // Collinear pairs keep the prior's twist.
        let prior = axis_rotation(2, 40.0);
        let pairs = [([1.0, 0.0, 0.0], apply(&prior, [1.0, 0.0, 0.0]), 1.0), ([-1.0, 0.0, 0.0], apply(&prior, [-1.0, 0.0, 0.0]), 1.0)];
        assert!(max_diff(&fit_rotation(&pairs, &prior), &prior) < 1e-6);
    }

    #[test]
    fn tree_from_bones_handles_cycles_and_disconnected_joints() {
        let p = Skeleton::panoptic19();
        let t = joint_tree(&p, 2).unwrap();
        assert_eq!(t.order.len(), 19);
        assert_eq!(t.order[0], 2);
        assert_eq!(t.parent[0], Some(2), "neck hangs from the pelvis");
        assert_eq!(t.dropped_bones.len(), 1, "the face cycle loses one bone: {:?}", t.dropped_bones);
        let j = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let sk = Skeleton::new("broken", j(&["hip", "lhip", "rhip", "hand", "finger"]), vec![(0, 1), (0, 2), (3, 4)], 1, 2).unwrap();
        let e = joint_tree(&sk, 0).unwrap_err().to_string();
        assert!(e.contains("joints hand, finger not connected") && e.contains("root hip"), "{e}");
        let scene = Scene::new("b", 30.0, sk, Array4::from_shape_fn((3, 1, 5, 3), |(_, _, j, k)| (j * 3 + k) as f32 * 0.1)).unwrap();
        let e = person_to_bvh(&scene, 0, &BvhExportOptions::default()).unwrap_err().to_string();
        assert!(e.contains("hand, finger"), "{e}");
        assert_eq!(walkers(3, 1, 0.0).root_joint(0, None).unwrap(), 14);
    }

    /// Re-imports every written file and checks the error measured independently of
    /// `person_to_bvh`'s own check.
    fn check_files(scene: &Scene, dir: &Path, exported: &[ExportedBvh], units: BvhUnits) -> f64 {
        let mut worst = 0.0f64;
        for e in exported {
            let sk = &scene.skeleton;
            let opts =
                BvhImport { scale: units.import_scale(), left_right: Some((sk.joints[sk.left].clone(), sk.joints[sk.right].clone())), ..Default::default() };
            let back = import_bvh(dir.join(&e.file_name), &opts).unwrap();
            assert_eq!(back.num_frames(), scene.num_frames());
            assert!((back.fps - scene.fps).abs() < 1e-6, "fps {} vs {}", back.fps, scene.fps);
            let mut w = 0.0f64;
            for (j, name) in sk.joints.iter().enumerate() {
                let b = back.skeleton.require_joint(name).unwrap();
                for f in 0..scene.num_frames() {
                    if !scene.is_valid(f, e.person) {
                        continue;
                    }
                    let d = (0..3).map(|k| (scene.positions[[f, e.person, j, k]] as f64 - back.positions[[f, 0, b, k]] as f64).powi(2)).sum::<f64>().sqrt();
                    w = w.max(d);
                }
            }
            assert!((w - e.max_error_m).abs() < 1e-6, "file says {w}, export measured {}", e.max_error_m);
            worst = worst.max(w);
        }
        worst
    }

    #[test]
    fn cmu_clip_round_trips_through_bvh_export() {
        let opts = BvhImport { scale: CMU_SCALE, ..Default::default() };
        let scene = import_bvh(cmu_clip(), &opts).unwrap();
        let dir = tmp("bvh-cmu");
        std::fs::create_dir_all(&dir).unwrap();
        let out = write_scene_bvh(&scene, &dir, &BvhExportOptions::default(), &mut |_| {}).unwrap();
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].file_name, "cmu_18_01.bvh");
        assert_eq!(out[0].root, "hip");
        let worst = check_files(&scene, &dir, &out, BvhUnits::Centimetres);
        println!(
            "CMU 18_01 ({} frames, {} joints): re-import max error {:.2e} cm, mean {:.2e} cm",
            scene.num_frames(),
            scene.num_joints(),
            worst * 100.0,
            out[0].mean_error_m * 100.0
        );
        assert!(worst < 0.02, "max error {worst} m");
        // In metres too.
        let m = person_to_bvh(&scene, 0, &BvhExportOptions { units: BvhUnits::Metres, ..Default::default() }).unwrap();
        assert!(m.max_error_m < 0.02);
        assert!(m.text.contains("CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Largest deviation of any bone's length from its mean, over the valid frames of person `p`.
    fn bone_length_deviation(s: &Scene, p: usize) -> f64 {
        let valid: Vec<usize> = (0..s.num_frames()).filter(|&f| s.is_valid(f, p)).collect();
        let len =
            |f: usize, a: usize, b: usize| (0..3).map(|k| (s.positions[[f, p, a, k]] - s.positions[[f, p, b, k]]) as f64).map(|x| x * x).sum::<f64>().sqrt();
        let mut worst = 0.0f64;
        for &(a, b) in &s.skeleton.bones {
            let mean = valid.iter().map(|&f| len(f, a, b)).sum::<f64>() / valid.len() as f64;
            worst = valid.iter().map(|&f| (len(f, a, b) - mean).abs()).fold(worst, f64::max);
        }
        worst
    }

    #[test]
    fn mupots_round_trips_through_bvh_export() {
        let Some(ds) = mupots() else { return };
        let (fixed_dir, stretch_dir) = (tmp("bvh-mupots"), tmp("bvh-mupots-stretch"));
        std::fs::create_dir_all(&fixed_dir).unwrap();
        std::fs::create_dir_all(&stretch_dir).unwrap();
        let stretch = BvhExportOptions { stretch: true, ..Default::default() };
        let (mut fixed_max, mut stretch_max, mut dev_max, mut excess_max) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        let (mut fixed_mean, mut stretch_mean, mut n) = (0.0f64, 0.0f64, 0usize);
        let mut fixed_at = String::new();
        for seq in &ds.sequences {
            let s = &seq.scene;
            let fixed = write_scene_bvh(s, &fixed_dir, &BvhExportOptions::default(), &mut |_| {}).unwrap();
            let exact = write_scene_bvh(s, &stretch_dir, &stretch, &mut |_| {}).unwrap();
            check_files(s, &fixed_dir, &fixed, BvhUnits::Centimetres);
            stretch_max = stretch_max.max(check_files(s, &stretch_dir, &exact, BvhUnits::Centimetres));
            for (e, x) in fixed.iter().zip(&exact) {
                let dev = bone_length_deviation(s, e.person);
                // A fixed skeleton cannot follow bones whose recorded length varies: the error is
                // the bone-length deviation plus the residual of the multi-child fits.
                assert!(e.max_error_m <= dev + 0.03, "{} person {}: {} m with bones deviating {} m", s.name, e.person, e.max_error_m, dev);
                excess_max = excess_max.max(e.max_error_m - dev);
                if e.max_error_m > fixed_max {
                    fixed_max = e.max_error_m;
                    fixed_at = format!("{} person {}", s.name, e.person);
                }
                dev_max = dev_max.max(dev);
                fixed_mean += e.mean_error_m;
                stretch_mean += x.mean_error_m;
                n += 1;
            }
        }
        let (fixed_mean, stretch_mean) = (fixed_mean / n as f64, stretch_mean / n as f64);
        println!(
            "MuPoTS, {n} persons in {} sequences, re-imported: fixed skeleton max {:.2} cm ({fixed_at}), mean {:.3} cm \
             (recorded bone lengths deviate from their per-person means by up to {:.2} cm; error beyond that ≤ {:.2} cm); \
             with `stretch` max {:.5} cm, mean {:.5} cm",
            ds.sequences.len(),
            fixed_max * 100.0,
            fixed_mean * 100.0,
            dev_max * 100.0,
            excess_max * 100.0,
            stretch_max * 100.0,
            stretch_mean * 100.0
        );
        assert_eq!(n, 49);
        assert!(fixed_mean < 0.015, "fixed-skeleton mean error {fixed_mean} m");
        assert!(stretch_max < 0.02, "stretch max error {stretch_max} m");
        std::fs::remove_dir_all(&fixed_dir).unwrap();
        std::fs::remove_dir_all(&stretch_dir).unwrap();
    }

    #[test]
    fn synthetic_walkers_export_exactly_and_name_files() {
        let s = walkers(60, 3, 0.5);
        assert_eq!(file_names(&s), ["walkers_0.bvh", "walkers_1.bvh", "walkers_2.bvh"]);
        let e = person_to_bvh(&s, 2, &BvhExportOptions::default()).unwrap();
        println!("walkers: re-import max error {:.2e} m", e.max_error_m);
        assert!(e.max_error_m < 1e-3, "{}", e.max_error_m);
        assert!(e.text.starts_with("HIERARCHY\nROOT pelvis\n"));
        assert!(e.text.contains("Frames: 60\nFrame Time: 0.03333333\n"));
        assert!(person_to_bvh(&s, 3, &BvhExportOptions::default()).is_err());
        let e = person_to_bvh(&s, 0, &BvhExportOptions { root: Some("neck".into()), ..Default::default() }).unwrap();
        assert!(e.text.starts_with("HIERARCHY\nROOT neck\n") && e.max_error_m < 1e-3);
    }
}
