//! Pose features on real data: every frame of every MuPoTS-3D scene round-trips below 1e-5 m,
//! and anchored features of every real scene do not change when it is moved on the ground.
//!
//! Reads `shared/data/mupots3d/{train,test}/TS*.npy` with a tiny local `.npy` reader (the
//! engine's dataset reader is tested elsewhere); skipped with a message if the data is absent.

use ndarray::{Array2, Array4};
use socdiff_engine::features::{fill_short_gaps, training_windows, window_features, PoseEncoding, PoseFeatures, Standardization, DEFAULT_MAX_GAP};
use socdiff_engine::{Scene, Skeleton};
use std::path::{Path, PathBuf};

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/mupots3d");

/// `.npy` v1.0, C order: (descr, shape, data bytes).
fn read_npy(path: &Path) -> (String, Vec<usize>, Vec<u8>) {
    let b = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(b.starts_with(b"\x93NUMPY\x01\x00"), "{}: not an .npy v1.0 file", path.display());
    let n = u16::from_le_bytes([b[8], b[9]]) as usize;
    let header = std::str::from_utf8(&b[10..10 + n]).unwrap();
    let field = |key: &str| {
        let i = header.find(key).unwrap_or_else(|| panic!("{}: no {key} in {header}", path.display())) + key.len();
        header[i..].trim_start_matches([':', ' ', '\''])
    };
    let descr = field("'descr'").split('\'').next().unwrap().to_string();
    assert!(field("'fortran_order'").starts_with("False"), "{}: Fortran order", path.display());
    let shape_text = field("'shape'");
    let shape = shape_text[1..shape_text.find(')').unwrap()].split(',').filter(|s| !s.trim().is_empty()).map(|s| s.trim().parse().unwrap()).collect();
    (descr, shape, b[10 + n..].to_vec())
}

/// A MuPoTS scene in socdiff axes: camera (x right, y down, z forward) ↦ (x, z, −y).
fn load_scene(path: &Path) -> Scene {
    let (descr, shape, bytes) = read_npy(path);
    assert_eq!(descr, "<f4");
    let (frames, persons) = (shape[0], shape[1]);
    assert_eq!(&shape[2..], &[17, 3]);
    let v: Vec<f32> = bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    let pos = Array4::from_shape_fn((frames, persons, 17, 3), |(f, p, j, k)| {
        let i = ((f * persons + p) * 17 + j) * 3;
        [v[i], v[i + 2], -v[i + 1]][k]
    });
    let name = path.file_stem().unwrap().to_string_lossy().to_string();
    let mut scene = Scene::new(name, 30.0, Skeleton::mupots17(), pos).unwrap();
    let valid_path = path.with_file_name(format!("{}_valid.npy", scene.name));
    if valid_path.exists() {
        let (descr, shape, bytes) = read_npy(&valid_path);
        assert_eq!((descr.as_str(), shape.as_slice()), ("|u1", &[frames, persons][..]));
        scene = scene.with_valid(Array2::from_shape_vec((frames, persons), bytes.iter().map(|&b| b != 0).collect()).unwrap()).unwrap();
    }
    scene
}

fn scenes() -> Option<Vec<Scene>> {
    let root = PathBuf::from(DATA);
    if !root.is_dir() {
        println!("skipped: MuPoTS data not found at {}", root.display());
        return None;
    }
    let mut files: Vec<PathBuf> = ["train", "test"]
        .iter()
        .flat_map(|d| std::fs::read_dir(root.join(d)).unwrap().map(|e| e.unwrap().path()))
        .filter(|p| p.extension().is_some_and(|e| e == "npy") && !p.to_string_lossy().ends_with("_valid.npy"))
        .collect();
    files.sort_by_key(|p| p.file_stem().unwrap().to_string_lossy()[2..].parse::<u32>().unwrap());
    Some(files.iter().map(|p| load_scene(p)).collect())
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (*x as f64 - *y as f64).abs()).fold(0.0, f64::max)
}

#[test]
fn mupots_round_trip_every_frame() {
    let Some(scenes) = scenes() else { return };
    assert_eq!(scenes.len(), 20);
    let (mut worst, mut frames, mut invalid) = (0.0f64, 0usize, 0usize);
    for s in &scenes {
        for anchor in [0, s.num_frames() / 2, s.num_frames() - 1] {
            let f = PoseFeatures::from_scene(s, anchor).unwrap_or_else(|e| panic!("{e}"));
            let back = f.to_positions().unwrap();
            let err = max_abs_diff(back.as_slice().unwrap(), s.positions.as_standard_layout().as_slice().unwrap());
            assert!(err < 1e-5, "{} anchored at {anchor}: round trip error {err} m", s.name);
            worst = worst.max(err);
        }
        frames += s.num_frames();
        invalid += s.num_invalid();
    }
    println!("MuPoTS: {} scenes, {frames} frames, {invalid} invalid (frame, person) entries, max round-trip error {worst:.3e} m", scenes.len());
}

#[test]
fn mupots_features_invariant_to_ground_motion() {
    let Some(scenes) = scenes() else { return };
    let mut worst = (0.0f64, String::new());
    for s in &scenes {
        let anchor = s.num_frames() - 1;
        let base = PoseFeatures::from_scene(s, anchor).unwrap();
        for theta in [0.4f64, -2.1, std::f64::consts::PI - 1e-4] {
            let (sn, c) = theta.sin_cos();
            let (px, py) = (0.5, 4.0); // about a vertical axis 4 m in front of the camera
            let mut moved = s.clone();
            moved.transform([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]], [px - (c * px - sn * py) + 1.5, py - (sn * px + c * py) - 2.0, 0.0]);
            let f = PoseFeatures::from_scene(&moved, anchor).unwrap();
            let d = max_abs_diff(f.data.as_slice().unwrap(), base.data.as_slice().unwrap());
            assert!(d < 1e-5, "{} rotated by {theta} rad: anchored features changed by {d}", s.name);
            if d > worst.0 {
                worst = (d, s.name.clone());
            }
        }
    }
    println!("max change of anchored features under ground motion {:.3e} ({})", worst.0, worst.1);
}

#[test]
fn mupots_windows_and_standardization() {
    let Some(scenes) = scenes() else { return };
    let train: Vec<Scene> = scenes[..15].iter().map(|s| fill_short_gaps(s, DEFAULT_MAX_GAP)).collect();
    let windows = training_windows(&train, 64, 10, Some((1, 3))).unwrap();
    assert!(!windows.is_empty());
    let st = Standardization::fit_windows(&train, &windows, 31, PoseEncoding::Absolute).unwrap();
    assert_eq!(st.dim(), 55);
    // Residual local joints spread less than absolute ones: a pose changes less within 1 s of
    // the anchor frame than bodies and poses differ across the data (summed over the local dims:
    // 8.4 vs 17.3).
    let res = Standardization::fit_windows(&train, &windows, 31, PoseEncoding::Residual).unwrap();
    let (abs_spread, res_spread): (f32, f32) = (st.std[4..].iter().sum(), res.std[4..].iter().sum());
    println!("local-joint std summed over dims: absolute {abs_spread:.3}, residual {res_spread:.3}");
    assert!(res_spread < abs_spread, "{res_spread} vs {abs_spread}");
    assert_eq!(res.std[..4], st.std[..4]);
    // Standardizing the first window and inverting it gives it back.
    let x = window_features(&train[windows[0].scene], &windows[0], 31, PoseEncoding::Absolute).unwrap();
    let mut y = x.clone();
    st.apply(&mut y).unwrap();
    st.invert(&mut y).unwrap();
    assert!(max_abs_diff(x.as_slice().unwrap(), y.as_slice().unwrap()) < 1e-4);
    let e = training_windows(&train, 10_000, 10, None).unwrap_err().to_string();
    assert!(e.contains("longer than every sequence"), "{e}");
    println!("MuPoTS train: {} windows of 64 frames (stride 10, 1–3 persons); root std {:?} m", windows.len(), &st.std[..2]);
}
