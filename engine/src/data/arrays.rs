//! Motion arrays: joint positions in `.npy` files, `.npz` archives and folders of them, and the
//! releases of the field that ship that way. An array says nothing of its skeleton, frame rate,
//! units or up axis, so the user names them ([`ArrayImport`]); what each layout holds:
//!
//! | input | layout | sequences |
//! |---|---|---|
//! | `.npy`, float32 or float64 | `[frames, joints, 3]`, `[frames, joints·3]` (one person) or `[frames, persons, joints, 3]` | one, named after the file |
//! | `.npy`, 4-D with a last axis of `joints·3` | `[windows, persons, frames, joints·3]`: MRT's preprocessed CMU-Mocap and MuPoTS files (45 columns of MRT's 15 joints, `--skeleton mrt15`, `--units mrt`, `--up y`) | one per window, `<file>_<window>` |
//! | `.npz` | one array per key, as above | one per key, `<file>_<key>` |
//! | `.npz` holding `positions_3d` | VideoPose3D's `data_3d_h36m.npz`: a pickled dict subject → action → `[frames, 32, 3]` metres, z up; the 17 joints of [`Skeleton::h36m17`] are kept | one per subject and action, `<subject>_<action>` |
//! | a folder of the above | one file after another, by name | as each file |
//!
//! SMPL joint arrays as HumanML3D and AMASS pipelines write them (`new_joints/*.npy`,
//! `[frames, 22, 3]`, metres, y up) are the first row with `--skeleton smpl22 --units m --up y`.
//! CMU Panoptic's per-frame `body3DScene_*.json` files are read by [`super::panoptic`].

use super::ground::UpAxis;
use super::npy::{parse_npy, NpyArray, NpyData};
use super::scene::Scene;
use super::skeleton::Skeleton;
use crate::{bail, Error, Result};
use ndarray::Array4;
use std::io::Read;
use std::path::{Path, PathBuf};

/// MRT's units per millimetre (their `mupots3d/preprocess_mupots.py`: 0.017 · 0.1 · 1.8 / 3).
pub const MRT_UNITS_PER_MM: f64 = 0.017 * 0.1 * 1.8 / 3.0;

/// Units of a motion array's positions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Units {
    /// Metres.
    M,
    /// Centimetres.
    Cm,
    /// Millimetres.
    Mm,
    /// MRT's preprocessed MuPoTS-3D files: millimetres × 0.00102 (`preprocess_mupots.py` scales
    /// by 0.017 · 0.1 · 1.8 / 3; its first version had 0.015), so 1/1.02 m per unit.
    Mrt,
}

impl Units {
    /// Metres per unit.
    pub fn metres(self) -> f64 {
        match self {
            Units::M => 1.0,
            Units::Cm => 0.01,
            Units::Mm => 0.001,
            Units::Mrt => 1e-3 / MRT_UNITS_PER_MM,
        }
    }
}

/// What a motion array does not say: how to read it.
#[derive(Clone, Debug, PartialEq)]
pub struct ArrayImport {
    /// The skeleton its joints follow, in its order (a named skeleton, [`Skeleton::named`]).
    pub skeleton: Skeleton,
    /// Frames per second.
    pub fps: f64,
    /// Units of the positions.
    pub units: Units,
    /// Which axis points up.
    pub up: UpAxis,
}

/// Largest `.npz` archive read, and largest array inside one.
const MAX_NPZ_BYTES: u64 = 16 << 30;

/// Whether `path` names a file of a motion-array format (`.npy`, `.npz`).
pub fn is_array_file(path: &Path) -> bool {
    matches!(path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref(), Some("npy" | "npz"))
}

/// The motion-array files directly in `dir`, sorted by name.
pub fn array_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && is_array_file(p) && !p.file_name().is_some_and(|n| n.to_string_lossy().ends_with("_valid.npy")))
        .collect();
    files.sort();
    Ok(files)
}

/// The scenes of one `.npy` or `.npz` file (module docs). Errors name the file.
pub fn read_array_file(path: &Path, how: &ArrayImport) -> Result<Vec<Scene>> {
    let stem = path.file_stem().map_or_else(|| "motion".to_string(), |s| s.to_string_lossy().into_owned());
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    let scenes = if ext.as_deref() == Some("npz") {
        let entries = read_npz(path)?;
        if let Some((_, bytes)) = entries.iter().find(|(k, _)| k == "positions_3d") {
            h36m_scenes(bytes, how).map_err(|e| e.in_file(path))?
        } else {
            let mut out = Vec::new();
            for (key, bytes) in &entries {
                crate::files::check_name("array", key).map_err(|e| e.in_file(path))?;
                let array = parse_npy(bytes).map_err(|e| Error::format(path, format!("array {key}: {e}")))?;
                out.extend(scenes_of(array, &format!("{stem}_{key}"), how).map_err(|e| Error::format(path, format!("array {key}: {e}")))?);
            }
            out
        }
    } else {
        let array = super::npy::read_npy(path)?;
        scenes_of(array, &stem, how).map_err(|e| e.in_file(path))?
    };
    if scenes.is_empty() {
        return Err(Error::format(path, "holds no motion"));
    }
    Ok(scenes)
}

/// The arrays of an `.npz` archive, `(key, .npy bytes)` in archive order; sizes are checked
/// against the archive before anything is read.
fn read_npz(path: &Path) -> Result<Vec<(String, Vec<u8>)>> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.len() > MAX_NPZ_BYTES {
        return Err(Error::format(path, format!("{} bytes: more than the {MAX_NPZ_BYTES} an .npz may have", meta.len())));
    }
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut zip = zip::ZipArchive::new(file).map_err(|e| Error::format(path, format!("not an .npz (zip) archive: {e}")))?;
    let mut out = Vec::new();
    for i in 0..zip.len() {
        let mut entry = zip.by_index(i).map_err(|e| Error::format(path, format!("entry {i}: {e}")))?;
        let name = entry.name().map_err(|e| Error::format(path, format!("entry {i}: {e}")))?.to_string();
        let Some(key) = name.strip_suffix(".npy") else { continue };
        // An entry may claim any size: read at most what an array may be, then one byte more.
        let limit = entry.size().min(MAX_NPZ_BYTES);
        let mut bytes = Vec::with_capacity(limit.min(1 << 26) as usize);
        (&mut entry).take(limit + 1).read_to_end(&mut bytes).map_err(|e| Error::format(path, format!("array {key}: {e}")))?;
        if bytes.len() as u64 > limit {
            return Err(Error::format(path, format!("array {key}: more data than its entry states")));
        }
        out.push((key.to_string(), bytes));
    }
    Ok(out)
}

/// The scenes of one array (module docs), named `name` (with `_<window>` for windowed arrays).
fn scenes_of(array: NpyArray, name: &str, how: &ArrayImport) -> Result<Vec<Scene>> {
    let nj = how.skeleton.num_joints();
    let shape = array.shape.clone();
    let values: Vec<f32> = match array.data {
        NpyData::F32(v) => v,
        NpyData::F64(v) => v.into_iter().map(|x| x as f32).collect(),
        NpyData::U8(_) => bail!("dtype {} is not a position (float32 or float64)", array.descr),
    };
    let fits = |j: usize| j == nj;
    let wrong = || {
        Error::invalid(format!(
            "shape {shape:?} does not hold skeleton {} ({nj} joints): expected [frames, {nj}, 3], [frames, {}], [frames, persons, {nj}, 3] or [windows, persons, frames, {}]",
            how.skeleton.name,
            3 * nj,
            3 * nj
        ))
    };
    // (windows, frames, persons) of the array, in its own axis order.
    let (windows, frames, persons, window_major) = match *shape.as_slice() {
        [f, j, 3] if fits(j) => (1, f, 1, false),
        [f, c] if c == 3 * nj => (1, f, 1, false),
        [f, p, j, 3] if fits(j) => (1, f, p, false),
        [w, p, f, c] if c == 3 * nj && c != 3 => (w, f, p, true),
        _ => return Err(wrong()),
    };
    if frames < 1 || persons < 1 {
        bail!("shape {shape:?}: no frames or no persons");
    }
    crate::data::check_size(name, frames as f64 * windows as f64, persons, 1)?;
    let mut out = Vec::with_capacity(windows);
    for w in 0..windows {
        let mut pos = Array4::<f32>::zeros((frames, persons, nj, 3));
        for f in 0..frames {
            for p in 0..persons {
                // Offset of (window w, frame f, person p) in the array.
                let at = if window_major { ((w * persons + p) * frames + f) * 3 * nj } else { (f * persons + p) * 3 * nj };
                for (k, v) in values[at..at + 3 * nj].iter().enumerate() {
                    pos[[f, p, k / 3, k % 3]] = (*v as f64 * how.units.metres()) as f32;
                }
            }
        }
        let scene_name = if window_major { format!("{name}_{w:05}") } else { name.to_string() };
        out.push(to_scene(scene_name, pos, how)?);
    }
    Ok(out)
}

/// A scene from positions in the array's frame: metres already, turned z up.
fn to_scene(name: String, positions: Array4<f32>, how: &ArrayImport) -> Result<Scene> {
    let mut scene = Scene::new(name, how.fps, how.skeleton.clone(), positions)?;
    if how.up != UpAxis::Z {
        scene.transform(how.up.to_z_up(), [0.0; 3]);
    }
    Ok(scene)
}

/// Of VideoPose3D's 32 Human3.6M joints, the 17 of [`Skeleton::h36m17`], in its order.
pub const H36M_KEPT: [usize; 17] = [0, 1, 2, 3, 6, 7, 8, 12, 13, 14, 15, 17, 18, 19, 25, 26, 27];

/// The scenes of VideoPose3D's `positions_3d` (a pickled 0-d object array holding a dict
/// subject → action → `[frames, 32, 3]`). Each action is scaled and turned as `how` says (the
/// release is metres, z up: `--units m --up z`) and keeps [`H36M_KEPT`].
fn h36m_scenes(npy: &[u8], how: &ArrayImport) -> Result<Vec<Scene>> {
    use super::pickle::Value;
    if how.skeleton.name != "h36m17" {
        bail!("positions_3d holds Human3.6M joints: give --skeleton h36m17 (not {})", how.skeleton.name);
    }
    let dict = super::npy::object_npy(npy)?;
    let Value::Dict(subjects) = dict else { bail!("positions_3d is not a dict of subjects") };
    let mut out = Vec::new();
    for (subject, actions) in subjects {
        let (Value::Str(subject), Value::Dict(actions)) = (subject, actions) else { bail!("positions_3d: a subject is not a name with a dict of actions") };
        for (action, array) in actions {
            let (Value::Str(action), Value::NdArray(a)) = (action, array) else { bail!("positions_3d[{subject}]: an action is not a name with an array") };
            let name = format!("{subject}_{}", action.replace([' ', '/'], "_"));
            let [frames, 32, 3] = a.shape[..] else { bail!("positions_3d[{subject}][{action}] has shape {:?}, expected [frames, 32, 3]", a.shape) };
            crate::data::check_size(&name, frames as f64, 1, 1)?;
            let mut pos = Array4::<f32>::zeros((frames, 1, 17, 3));
            for f in 0..frames {
                for (j, &src) in H36M_KEPT.iter().enumerate() {
                    for k in 0..3 {
                        pos[[f, 0, j, k]] = (a.data[(f * 32 + src) * 3 + k] * how.units.metres()) as f32;
                    }
                }
            }
            out.push(to_scene(name, pos, how)?);
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::import::{load, ImportOptions};
    use crate::data::npy::write_npy_f32;
    use crate::data::test_util::tmp;
    use std::io::Write;

    fn how(skeleton: &str, units: Units, up: UpAxis) -> ArrayImport {
        ArrayImport { skeleton: Skeleton::named(skeleton).unwrap(), fps: 20.0, units, up }
    }

    /// Value `k` of joint `j`, person `p`, frame `f` of the fixtures: distinct everywhere.
    fn value(f: usize, p: usize, j: usize, k: usize) -> f32 {
        (f * 1000 + p * 100 + j * 3 + k) as f32
    }

    fn npy_bytes(shape: &[usize], data: &[f32]) -> Vec<u8> {
        let path = tmp("npy-bytes").with_extension("npy");
        write_npy_f32(&path, shape, data).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        std::fs::remove_file(&path).unwrap();
        bytes
    }

    fn write_npz(path: &Path, entries: &[(&str, Vec<u8>)]) {
        let mut zip = zip::ZipWriter::new(std::fs::File::create(path).unwrap());
        for (name, bytes) in entries {
            zip.start_file(format!("{name}.npy"), zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Deflated)).unwrap();
            zip.write_all(bytes).unwrap();
        }
        zip.finish().unwrap();
    }

    /// HumanML3D's layout: `[frames, 22, 3]` metres, y up (SMPL's 22 joints).
    #[test]
    fn smpl_joint_arrays_in_metres_y_up_become_z_up_scenes() {
        let dir = tmp("smpl-arrays");
        std::fs::create_dir_all(&dir).unwrap();
        let (frames, nj) = (5, 22);
        let data: Vec<f32> = (0..frames * nj * 3).map(|i| value(i / (nj * 3), 0, (i / 3) % nj, i % 3) / 1000.0).collect();
        write_npy_f32(&dir.join("000001.npy"), &[frames, nj, 3], &data).unwrap();
        write_npy_f32(&dir.join("000002.npy"), &[frames, nj * 3], &data).unwrap();
        let opts = ImportOptions { arrays: Some(how("smpl22", Units::M, UpAxis::Y)), ..Default::default() };
        let ds = load(&dir, &opts).unwrap();
        assert_eq!(ds.sequences.len(), 2, "a folder: one sequence per file");
        for seq in &ds.sequences {
            let s = &seq.scene;
            assert_eq!((s.num_frames(), s.num_persons(), s.skeleton.name.as_str(), s.fps), (frames, 1, "smpl22", 20.0));
            // y up → z up: (x, y, z) ↦ (x, −z, y).
            let (f, j) = (3, 7);
            let v = |k| value(f, 0, j, k) / 1000.0;
            assert_eq!([s.positions[[f, 0, j, 0]], s.positions[[f, 0, j, 1]], s.positions[[f, 0, j, 2]]], [v(0), -v(2), v(1)]);
        }
        // Without the reading instructions, or with a skeleton of another joint count: an error
        // naming the file and the shape.
        let e = load(&dir.join("000001.npy"), &ImportOptions::default()).unwrap_err().to_string();
        assert!(e.contains("000001.npy") && e.contains("skeleton") && e.contains("units"), "{e}");
        let opts = ImportOptions { arrays: Some(how("mupots17", Units::M, UpAxis::Y)), ..Default::default() };
        let e = load(&dir.join("000001.npy"), &opts).unwrap_err().to_string();
        assert!(e.contains("000001.npy") && e.contains("[5, 22, 3]") && e.contains("mupots17 (17 joints)"), "{e}");
    }

    /// Groups in millimetres, z up (`[frames, persons, joints, 3]`), and an `.npz` of two.
    #[test]
    fn group_arrays_and_npz_archives_in_millimetres() {
        let dir = tmp("group-arrays");
        std::fs::create_dir_all(&dir).unwrap();
        let (frames, persons, nj) = (4, 3, 17);
        let data: Vec<f32> = (0..frames * persons * nj * 3).map(|i| value(i / (persons * nj * 3), (i / (nj * 3)) % persons, (i / 3) % nj, i % 3)).collect();
        let bytes = npy_bytes(&[frames, persons, nj, 3], &data);
        let npz = dir.join("scenes.npz");
        write_npz(&npz, &[("TS1", bytes.clone()), ("TS2", bytes)]);
        let opts = ImportOptions { arrays: Some(how("mupots17", Units::Mm, UpAxis::Z)), ..Default::default() };
        let ds = load(&npz, &opts).unwrap();
        let names: Vec<&str> = ds.sequences.iter().map(|s| s.scene.name.as_str()).collect();
        assert_eq!(names, ["scenes_TS1", "scenes_TS2"]);
        let s = &ds.sequences[1].scene;
        assert_eq!((s.num_frames(), s.num_persons()), (frames, persons));
        assert_eq!(s.positions[[2, 1, 5, 2]], value(2, 1, 5, 2) * 0.001);
    }

    /// MRT's preprocessed files: `[windows, persons, frames, 45]` in MRT's units, y up.
    #[test]
    fn mrt_windows_become_one_sequence_each() {
        let dir = tmp("mrt-arrays");
        std::fs::create_dir_all(&dir).unwrap();
        let (windows, persons, frames, nj) = (2, 3, 6, 15);
        let at = |w: usize, p: usize, f: usize, c: usize| (w * 10_000 + p * 1_000 + f * 50 + c) as f32 * 1e-4;
        let mut data = Vec::new();
        for w in 0..windows {
            for p in 0..persons {
                for f in 0..frames {
                    data.extend((0..3 * nj).map(|c| at(w, p, f, c)));
                }
            }
        }
        let path = dir.join("mupots_120_3persons.npy");
        write_npy_f32(&path, &[windows, persons, frames, 3 * nj], &data).unwrap();
        let opts = ImportOptions { arrays: Some(how("mrt15", Units::Mrt, UpAxis::Y)), ..Default::default() };
        let ds = load(&path, &opts).unwrap();
        assert_eq!(ds.sequences.len(), windows);
        let s = &ds.sequences[1].scene;
        assert_eq!((s.name.as_str(), s.num_frames(), s.num_persons(), s.num_joints()), ("mupots_120_3persons_00001", frames, persons, nj));
        // Joint 4, person 2, frame 5 of window 1: MRT units are 1/1.02 m; y up → z up.
        let v = |k: usize| (at(1, 2, 5, 12 + k) as f64 / 1.02) as f32;
        let got = [s.positions[[5, 2, 4, 0]], s.positions[[5, 2, 4, 1]], s.positions[[5, 2, 4, 2]]];
        assert_eq!(got, [v(0), -v(2), v(1)]);
    }

    /// A protocol-3 pickle of what `np.save` writes for `np.array({"S1": {"Walking 1":
    /// positions}}, dtype=object)`, positions `[frames, 32, 3]` float32.
    fn h36m_pickle(frames: usize, positions: &[f32]) -> Vec<u8> {
        let mut p = vec![0x80, 3];
        let unicode = |p: &mut Vec<u8>, s: &str| {
            p.push(b'X');
            p.extend((s.len() as u32).to_le_bytes());
            p.extend(s.as_bytes());
        };
        let stub = |p: &mut Vec<u8>| {
            p.extend(b"cnumpy.core.multiarray\n_reconstruct\ncnumpy\nndarray\nK\x00\x85C\x01b\x87R");
        };
        let dtype = |p: &mut Vec<u8>, descr: &str, order: &str| {
            p.extend(b"cnumpy\ndtype\n");
            unicode(p, descr);
            p.extend(b"\x89\x88\x87R(K\x03");
            unicode(p, order);
            p.extend(b"NNNJ\xff\xff\xff\xffJ\xff\xff\xff\xffK\x00tb");
        };
        stub(&mut p);
        p.extend(b"(K\x01)");
        dtype(&mut p, "O8", "|");
        p.extend(b"\x89]");
        p.push(b'}');
        unicode(&mut p, "S1");
        p.push(b'}');
        unicode(&mut p, "Walking 1");
        stub(&mut p);
        p.extend(b"(K\x01(");
        p.extend([b'J']);
        p.extend((frames as u32).to_le_bytes());
        p.extend(b"K\x20K\x03t");
        dtype(&mut p, "f4", "<");
        p.push(0x89);
        p.push(b'B');
        p.extend(((positions.len() * 4) as u32).to_le_bytes());
        positions.iter().for_each(|v| p.extend(v.to_le_bytes()));
        p.extend(b"tb"); // the positions array
        p.extend(b"ss"); // {"Walking 1": …}, {"S1": …}
        p.extend(b"atb."); // [dict], the object array's state
        p
    }

    /// VideoPose3D's `data_3d_h36m.npz`: `positions_3d`, a dict subject → action → `[frames,
    /// 32, 3]` metres, z up; 17 of the 32 joints are kept.
    #[test]
    fn videopose3d_h36m_positions_keep_their_17_joints() {
        let dir = tmp("h36m");
        std::fs::create_dir_all(&dir).unwrap();
        let frames = 3;
        let positions: Vec<f32> = (0..frames * 32 * 3).map(|i| i as f32 * 0.001).collect();
        let pickle = h36m_pickle(frames, &positions);
        let header = "{'descr': '|O', 'fortran_order': False, 'shape': (), }";
        let mut npy = b"\x93NUMPY\x01\x00".to_vec();
        let pad = 64 - (10 + header.len() + 1) % 64;
        let header = format!("{header}{}\n", " ".repeat(pad));
        npy.extend((header.len() as u16).to_le_bytes());
        npy.extend(header.as_bytes());
        npy.extend(&pickle);
        let path = dir.join("data_3d_h36m.npz");
        write_npz(&path, &[("positions_3d", npy)]);
        let opts = ImportOptions { arrays: Some(how("h36m17", Units::M, UpAxis::Z)), ..Default::default() };
        let ds = load(&path, &opts).unwrap();
        assert_eq!(ds.sequences.len(), 1);
        let s = &ds.sequences[0].scene;
        assert_eq!((s.name.as_str(), s.num_frames(), s.num_joints()), ("S1_Walking_1", frames, 17));
        for (j, &src) in H36M_KEPT.iter().enumerate() {
            for k in 0..3 {
                assert_eq!(s.positions[[2, 0, j, k]], positions[(2 * 32 + src) * 3 + k], "joint {j}");
            }
        }
        // The H3.6M release read as another skeleton is refused, naming what to give.
        let opts = ImportOptions { arrays: Some(how("smpl24", Units::M, UpAxis::Z)), ..Default::default() };
        let e = load(&path, &opts).unwrap_err().to_string();
        assert!(e.contains("data_3d_h36m.npz") && e.contains("h36m17"), "{e}");
    }
}
