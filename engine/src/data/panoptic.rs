//! CMU Panoptic Studio 3D body poses: a folder of per-frame `body3DScene_<frame>.json` files (the
//! `hdPose3d_stage1_coco19` folders of the Panoptic toolbox), read as one scene.
//!
//! Each file is `{"version": …, "univTime": …, "fpsType": "hd_29_97" | "vga_25", "bodies": [{"id":
//! N, "joints19": [x, y, z, confidence, …]}]}` with 19 joints × 4 values in centimetres, y down,
//! in [`Skeleton::panoptic19`]'s order. Frames are the files in name order; persons are the body
//! ids seen in any frame, in increasing order. A person absent from a frame is invalid there
//! (its pose held from the nearest frame that has it); the frame rate comes from `fpsType`.

use super::ground::UpAxis;
use super::scene::Scene;
use super::skeleton::Skeleton;
use crate::{Error, Result};
use ndarray::{Array2, Array4};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Largest per-frame file read.
const MAX_FRAME_FILE_BYTES: u64 = 16 << 20;

#[derive(Deserialize)]
struct FrameFile {
    #[serde(rename = "fpsType")]
    fps_type: Option<String>,
    bodies: Vec<Body>,
}

#[derive(Deserialize)]
struct Body {
    id: i64,
    joints19: Vec<f64>,
}

/// The `body3DScene_*.json` files directly in `dir`, sorted by name.
pub fn frame_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with("body3DScene_") && n.ends_with(".json")))
        .collect();
    files.sort();
    Ok(files)
}

/// The scene of a folder of Panoptic frame files (module docs), named after the folder. Errors
/// name the file and what is wrong with it.
pub fn read_panoptic_dir(dir: &Path) -> Result<Scene> {
    let files = frame_files(dir)?;
    if files.is_empty() {
        return Err(Error::format(dir, "no body3DScene_*.json files"));
    }
    crate::data::check_size(&dir.display().to_string(), files.len() as f64, 1, 1)?;
    let skeleton = Skeleton::panoptic19();
    let mut fps_type: Option<String> = None;
    // Per frame: (body id, 19 joints in metres, z up).
    let mut frames: Vec<Vec<(i64, [[f32; 3]; 19])>> = Vec::with_capacity(files.len());
    let to_z_up = UpAxis::NegY.to_z_up();
    for file in &files {
        let bytes = crate::files::read_bounded(file, MAX_FRAME_FILE_BYTES, "Panoptic frame file")?;
        let frame: FrameFile = serde_json::from_slice(&bytes).map_err(|e| Error::format(file, format!("not a Panoptic body3DScene file: {e}")))?;
        match (&fps_type, frame.fps_type) {
            (None, t) => fps_type = t,
            (Some(a), Some(b)) if *a != b => return Err(Error::format(file, format!("fpsType {b:?} differs from the earlier frames' {a:?}"))),
            _ => {}
        }
        let mut bodies = Vec::with_capacity(frame.bodies.len());
        for body in frame.bodies {
            if body.joints19.len() != 19 * 4 {
                return Err(Error::format(
                    file,
                    format!("body {}: joints19 has {} values, expected 76 (19 joints × x, y, z, confidence)", body.id, body.joints19.len()),
                ));
            }
            if bodies.iter().any(|(id, _)| *id == body.id) {
                return Err(Error::format(file, format!("body id {} appears twice", body.id)));
            }
            let mut joints = [[0f32; 3]; 19];
            for (j, out) in joints.iter_mut().enumerate() {
                let cm = &body.joints19[4 * j..4 * j + 3];
                for (k, o) in out.iter_mut().enumerate() {
                    *o = (0..3).map(|c| to_z_up[k][c] * cm[c] * 0.01).sum::<f64>() as f32;
                }
            }
            bodies.push((body.id, joints));
        }
        frames.push(bodies);
    }
    let fps = match fps_type.as_deref() {
        None | Some("hd_29_97") => 29.97,
        Some("vga_25") => 25.0,
        Some(other) => return Err(Error::format(&files[0], format!("fpsType {other:?} is neither hd_29_97 nor vga_25"))),
    };
    let mut ids: Vec<i64> = frames.iter().flatten().map(|(id, _)| *id).collect();
    ids.sort_unstable();
    ids.dedup();
    if ids.is_empty() {
        return Err(Error::format(dir, "no frame holds a body"));
    }
    crate::data::check_size(&dir.display().to_string(), frames.len() as f64, ids.len(), 1)?;
    let (nf, np) = (frames.len(), ids.len());
    let mut pos = Array4::<f32>::zeros((nf, np, 19, 3));
    let mut valid = Array2::from_elem((nf, np), false);
    for (f, bodies) in frames.iter().enumerate() {
        for (id, joints) in bodies {
            let p = ids.binary_search(id).expect("id of a frame");
            valid[[f, p]] = true;
            for (j, xyz) in joints.iter().enumerate() {
                for k in 0..3 {
                    pos[[f, p, j, k]] = xyz[k];
                }
            }
        }
    }
    // Hold each person's pose across the frames it is absent from: the nearest earlier frame
    // that has it, else the first later one.
    for p in 0..np {
        let first = (0..nf).find(|&f| valid[[f, p]]).expect("every id is in some frame");
        let mut last = first;
        for f in 0..nf {
            if valid[[f, p]] {
                last = f;
            } else {
                let from = if f < first { first } else { last };
                let pose = pos.slice(ndarray::s![from, p, .., ..]).to_owned();
                pos.slice_mut(ndarray::s![f, p, .., ..]).assign(&pose);
            }
        }
    }
    let name = dir.file_name().map_or_else(|| "panoptic".to_string(), |n| n.to_string_lossy().into_owned());
    let scene = Scene::new(name, fps, skeleton, pos).map_err(|e| e.in_file(dir))?;
    let scene = if valid.iter().all(|&v| v) { scene } else { scene.with_valid(valid)? };
    Ok(scene)
}

#[cfg(test)]
mod tests {
    use crate::data::import::{load, ImportOptions};
    use crate::data::test_util::tmp;

    /// A frame file of bodies `(id, offset)`: joint j of a body at (j + offset, −100 − j, 2j) cm.
    fn frame(bodies: &[(i64, f64)]) -> String {
        let body = |(id, off): &(i64, f64)| {
            let joints: Vec<String> = (0..19).flat_map(|j| [j as f64 + off, -100.0 - j as f64, 2.0 * j as f64, 0.9]).map(|v| v.to_string()).collect();
            format!("{{\"id\": {id}, \"joints19\": [{}]}}", joints.join(", "))
        };
        let bodies: Vec<String> = bodies.iter().map(body).collect();
        format!("{{\"version\": 0.7, \"univTime\": 1.0, \"fpsType\": \"hd_29_97\", \"bodies\": [{}]}}", bodies.join(", "))
    }

    #[test]
    fn panoptic_frames_become_one_scene_in_metres_z_up() {
        let dir = tmp("panoptic").join("hdPose3d_stage1_coco19");
        std::fs::create_dir_all(&dir).unwrap();
        for (f, bodies) in [vec![(3, 0.0), (7, 50.0)], vec![(7, 51.0)], vec![(3, 2.0), (7, 52.0)]].iter().enumerate() {
            std::fs::write(dir.join(format!("body3DScene_{:08}.json", 100 + f)), frame(bodies)).unwrap();
        }
        let ds = load(&dir, &ImportOptions::default()).unwrap();
        let s = &ds.sequences[0].scene;
        assert_eq!((s.num_frames(), s.num_persons(), s.skeleton.name.as_str(), s.fps), (3, 2, "panoptic19", 29.97));
        // cm, y down → metres, z up: (x, y, z) ↦ (x, z, −y).
        let j = 4;
        let at = |f: usize, p: usize| [s.positions[[f, p, j, 0]], s.positions[[f, p, j, 1]], s.positions[[f, p, j, 2]]];
        let want = |off: f64| [((j as f64 + off) * 0.01) as f32, (2.0 * j as f64 * 0.01) as f32, ((100.0 + j as f64) * 0.01) as f32];
        assert_eq!(at(2, 1), want(52.0));
        assert_eq!(at(0, 0), want(0.0));
        // Body 3 is absent from frame 1: invalid there, its pose held from frame 0.
        assert!(!s.is_valid(1, 0) && s.is_valid(1, 1) && s.is_valid(2, 0));
        assert_eq!(at(1, 0), want(0.0));
        // A body with the wrong number of values is an error naming the file.
        std::fs::write(dir.join("body3DScene_00000103.json"), "{\"bodies\": [{\"id\": 1, \"joints19\": [1, 2, 3]}]}").unwrap();
        let e = load(&dir, &ImportOptions::default()).unwrap_err().to_string();
        assert!(e.contains("body3DScene_00000103.json") && e.contains("joints19 has 3 values"), "{e}");
    }
}
