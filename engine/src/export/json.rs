//! JSON export: a scene's joint positions as nested arrays, for plotting and other tools.
//!
//! One object per scene (compact, one line):
//!
//! ```json
//! {"format": "socdiff-positions", "version": 1, "name": "TS16", "fps": 30.0,
//!  "skeleton": "mupots17", "units": "metres", "up_axis": "z", "frames": 501, "persons": [{"id": "0"}, ...],
//!  "joints": ["head_top", ...], "bones": [[0, 16], ...], "hip_joints": {"left": 11, "right": 8},
//!  "positions": [[[[x, y, z], ...joints], ...persons], ...frames],
//!  "valid": [[true, ...persons], ...frames],              (only when the scene has a mask)
//!  "signals": {"speaking": [[0.0, ...persons], ...frames]},  (only when it has signals)
//!  "metadata": {...}}
//! ```
//!
//! `positions[f][p][j]` is joint `j` of person `p` at frame `f`. Numbers are written in the
//! shortest form that reads back to the same `f32`, so [`read_json`] returns the scene exactly.

use crate::data::scene::{Person, Scene};
use crate::data::skeleton::Skeleton;
use crate::files::write_file_atomic;
use crate::{Error, Result};
use ndarray::{Array2, Array4};
use serde::ser::{SerializeSeq, Serializer};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// The `format` tag of socdiff position files.
pub const FORMAT: &str = "socdiff-positions";

#[derive(Serialize)]
struct Out<'a> {
    format: &'static str,
    version: u32,
    name: &'a str,
    skeleton: &'a str,
    fps: f64,
    units: &'static str,
    up_axis: &'static str,
    frames: usize,
    persons: &'a [Person],
    joints: &'a [String],
    bones: &'a [(usize, usize)],
    hip_joints: Hips,
    positions: Positions<'a>,
    #[serde(skip_serializing_if = "Option::is_none")]
    valid: Option<BoolTable<'a>>,
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    signals: BTreeMap<&'a str, Table<'a>>,
    metadata: &'a serde_json::Map<String, serde_json::Value>,
}

#[derive(Serialize, Deserialize)]
struct Hips {
    left: usize,
    right: usize,
}

struct Positions<'a>(&'a Array4<f32>);

impl Serialize for Positions<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        let (frames, persons, joints, _) = self.0.dim();
        let mut seq = s.serialize_seq(Some(frames))?;
        for f in 0..frames {
            let frame: Vec<Vec<[f32; 3]>> = (0..persons).map(|p| (0..joints).map(|j| std::array::from_fn(|k| self.0[[f, p, j, k]])).collect()).collect();
            seq.serialize_element(&frame)?;
        }
        seq.end()
    }
}

/// A `[frames, persons]` table as nested arrays.
struct Table<'a>(&'a Array2<f32>);

impl Serialize for Table<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        let mut seq = s.serialize_seq(Some(self.0.nrows()))?;
        for row in self.0.rows() {
            seq.serialize_element(&row.to_vec())?;
        }
        seq.end()
    }
}

/// A `[frames, persons]` mask as nested arrays.
struct BoolTable<'a>(&'a Array2<bool>);

impl Serialize for BoolTable<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        let mut seq = s.serialize_seq(Some(self.0.nrows()))?;
        for row in self.0.rows() {
            seq.serialize_element(&row.to_vec())?;
        }
        seq.end()
    }
}

/// The JSON text of `scene` (see the module docs).
pub fn scene_to_json(scene: &Scene) -> Result<String> {
    let sk = &scene.skeleton;
    let out = Out {
        format: FORMAT,
        version: 1,
        name: &scene.name,
        skeleton: &sk.name,
        fps: scene.fps,
        units: "metres",
        up_axis: "z",
        frames: scene.num_frames(),
        persons: &scene.persons,
        joints: &sk.joints,
        bones: &sk.bones,
        hip_joints: Hips { left: sk.left, right: sk.right },
        positions: Positions(&scene.positions),
        valid: scene.valid.as_ref().map(BoolTable),
        signals: scene.signals.iter().map(|(k, v)| (k.as_str(), Table(v))).collect(),
        metadata: &scene.metadata,
    };
    serde_json::to_string(&out).map_err(|e| Error::invalid(format!("scene {}: cannot write JSON: {e}", scene.name)))
}

/// Writes `scene` as JSON to `path` (atomically).
pub fn write_json(scene: &Scene, path: &Path) -> Result<()> {
    write_file_atomic(path, scene_to_json(scene)?.as_bytes())
}

#[derive(Deserialize)]
struct In {
    format: String,
    name: String,
    fps: f64,
    #[serde(default)]
    skeleton: Option<String>,
    persons: Vec<Person>,
    joints: Vec<String>,
    bones: Vec<(usize, usize)>,
    hip_joints: Hips,
    positions: Vec<Vec<Vec<[f32; 3]>>>,
    #[serde(default)]
    valid: Option<Vec<Vec<bool>>>,
    #[serde(default)]
    signals: BTreeMap<String, Vec<Vec<f32>>>,
    #[serde(default)]
    metadata: serde_json::Map<String, serde_json::Value>,
}

/// Reads a file written by [`write_json`] back into a scene; errors name the file.
pub fn read_json(path: &Path) -> Result<Scene> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let v: In = serde_json::from_str(&text).map_err(|e| Error::format(path, format!("not a socdiff positions JSON: {e}")))?;
    if v.format != FORMAT {
        return Err(Error::format(path, format!("format is {:?}, expected {FORMAT:?}", v.format)));
    }
    let bad = |msg: String| Error::format(path, msg);
    let frames = v.positions.len();
    let persons = v.persons.len();
    let joints = v.joints.len();
    let mut flat = Vec::with_capacity(frames * persons * joints * 3);
    for (f, fr) in v.positions.iter().enumerate() {
        if fr.len() != persons {
            return Err(bad(format!("positions[{f}] has {} persons, expected {persons}", fr.len())));
        }
        for (p, pr) in fr.iter().enumerate() {
            if pr.len() != joints {
                return Err(bad(format!("positions[{f}][{p}] has {} joints, expected {joints}", pr.len())));
            }
            flat.extend(pr.iter().flatten());
        }
    }
    let sk =
        Skeleton::new(v.skeleton.unwrap_or_else(|| v.name.clone()), v.joints, v.bones, v.hip_joints.left, v.hip_joints.right).map_err(|e| e.in_file(path))?;
    let positions = Array4::from_shape_vec((frames, persons, joints, 3), flat).expect("sizes checked");
    let mut scene = Scene::new(v.name, v.fps, sk, positions).map_err(|e| e.in_file(path))?.with_persons(v.persons)?;
    let table = |what: &str, rows: &[Vec<f32>]| -> Result<Array2<f32>> {
        if rows.len() != frames || rows.iter().any(|r| r.len() != persons) {
            return Err(Error::format(path, format!("{what} is not [frames, persons] = [{frames}, {persons}]")));
        }
        Ok(Array2::from_shape_vec((frames, persons), rows.concat()).expect("sizes checked"))
    };
    if let Some(valid) = v.valid {
        let rows: Vec<Vec<f32>> = valid.iter().map(|r| r.iter().map(|&b| b as u8 as f32).collect()).collect();
        scene = scene.with_valid(table("valid", &rows)?.mapv(|x| x != 0.0))?;
    }
    for (k, rows) in v.signals {
        let t = table(&format!("signal {k:?}"), &rows)?;
        scene = scene.with_signal(k, t)?;
    }
    scene.metadata = v.metadata;
    Ok(scene)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::test_util::{mupots, tmp, walkers};

    #[test]
    fn json_round_trips_exactly() {
        let mut s = walkers(25, 2, 0.3).with_signal("speaking", Array2::from_shape_fn((25, 2), |(f, p)| ((f + p) % 3 == 0) as u8 as f32)).unwrap();
        s.valid = Some(Array2::from_shape_fn((25, 2), |(f, _)| f != 7));
        s.persons[1].role = Some("buyer".into());
        s.metadata.insert("note".into(), "x".into());
        s.positions[[3, 1, 4, 2]] = 1.0e-7 + 0.1;
        let dir = tmp("json");
        let path = dir.join("walkers.json");
        write_json(&s, &path).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(v["positions"].as_array().unwrap().len(), 25);
        assert_eq!(v["positions"][3][1].as_array().unwrap().len(), 17);
        assert_eq!(v["positions"][3][1][4][2].as_f64().unwrap() as f32, s.positions[[3, 1, 4, 2]]);
        assert_eq!(v["joints"][14], "pelvis");
        assert_eq!(v["fps"], 30.0);
        let back = read_json(&path).unwrap();
        assert_eq!(back, s, "exact round trip");
        println!("walkers 25×2×17: {} bytes of JSON", text.len());
        // Broken files name the file.
        std::fs::write(&path, text.replacen("[[[[", "[[[", 1)).unwrap();
        let e = read_json(&path).unwrap_err().to_string();
        assert!(e.contains("walkers.json"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn mupots_sequence_round_trips() {
        let Some(ds) = mupots() else { return };
        let s = &ds.sequences[11].scene; // TS12: has invalid frames
        assert!(s.valid.is_some());
        let dir = tmp("json-mupots");
        let path = dir.join("ts12.json");
        write_json(s, &path).unwrap();
        let back = read_json(&path).unwrap();
        assert_eq!(&back, s);
        println!("{}: {} frames × {} persons → {} bytes of JSON", s.name, s.num_frames(), s.num_persons(), std::fs::metadata(&path).unwrap().len());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
