//! The dataset-directory importer on the real MuPoTS-3D files in ../shared/data/mupots3d.

use socdiff_engine::data::dataset::{read_dataset, write_dataset, ReadOptions};
use socdiff_engine::data::ground::{align_ground, GroundAlignment};
use socdiff_engine::{Dataset, Split};
use std::path::{Path, PathBuf};

fn mupots_dir() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/mupots3d");
    if dir.join("dataset.json").exists() {
        Some(dir)
    } else {
        socdiff_engine::testing::skip_absent(&dir, "shared MuPoTS data");
        None
    }
}

fn read(dir: &Path) -> Dataset {
    read_dataset(dir, &ReadOptions::default()).unwrap()
}

#[test]
fn reads_all_sequences_with_split_and_masks() {
    let Some(dir) = mupots_dir() else { return };
    let ds = read(&dir);
    assert_eq!(ds.sequences.len(), 20);
    assert_eq!(ds.num_frames(), 8370);
    assert_eq!(ds.split(Split::Train).count(), 15);
    assert_eq!(ds.split(Split::Test).count(), 5);
    assert_eq!(ds.split(Split::Train).map(|s| s.num_frames()).sum::<usize>(), 6410);
    for s in ds.split(Split::Train).chain(ds.split(Split::Test)) {
        assert_eq!(s.num_joints(), 17);
        assert!((2..=3).contains(&s.num_persons()), "{}", s.name);
        assert_eq!(s.fps, 30.0);
    }
    // TS12 and TS15 have invalid frames.
    assert!(ds.scene("TS12").unwrap().num_invalid() > 0);
    assert!(ds.scene("TS15").unwrap().num_invalid() > 0);
}

#[test]
fn people_stand_upright_on_an_aligned_floor() {
    let Some(dir) = mupots_dir() else { return };
    let ds = read(&dir);
    let (mut upright, mut near_floor, mut total, mut level_scenes) = (0usize, 0usize, 0usize, 0usize);
    for seq in &ds.sequences {
        let s = &seq.scene;
        let report: GroundAlignment = serde_json::from_value(s.metadata["ground_alignment"].clone()).unwrap();
        eprintln!("{}: removed tilt {:.2}°, floor {:.3} m ({} inliers)", s.name, report.tilt_deg, report.floor_height_m, report.inliers);
        // Aligned means aligned: aligning again finds the floor level, and planted feet (the
        // lowest fifth of each person-frame's lowest foot) stand at z = 0 within 6 cm, mostly 1 cm.
        let second = align_ground(&mut s.clone()).unwrap();
        assert!(second.tilt_deg < 0.5, "{}: first {report:?}, again {second:?}", s.name);
        let feet = s.skeleton.foot_joints();
        let mut lowest: Vec<f32> = (0..s.num_frames())
            .flat_map(|f| (0..s.num_persons()).map(move |p| (f, p)))
            .filter(|&(f, p)| s.is_valid(f, p))
            .map(|(f, p)| feet.iter().map(|&j| s.positions[[f, p, j, 2]]).fold(f32::INFINITY, f32::min))
            .collect();
        lowest.sort_by(f32::total_cmp);
        let planted = lowest[lowest.len() / 5];
        assert!(planted.abs() < 0.06, "{}: planted feet at {planted} m", s.name);
        level_scenes += (planted.abs() < 0.01) as usize;
        let sk = &s.skeleton;
        let head = sk.require_joint("head_top").unwrap();
        let ankles = [sk.require_joint("left_ankle").unwrap(), sk.require_joint("right_ankle").unwrap()];
        for f in 0..s.num_frames() {
            for p in 0..s.num_persons() {
                if !s.is_valid(f, p) {
                    continue;
                }
                total += 1;
                let low = ankles.iter().map(|&a| s.positions[[f, p, a, 2]]).fold(f32::INFINITY, f32::min);
                upright += (s.positions[[f, p, head, 2]] > low) as usize;
                near_floor += (low.abs() < 0.05) as usize;
            }
        }
    }
    let up = upright as f64 / total as f64;
    let floor = near_floor as f64 / total as f64;
    eprintln!("upright {:.4}, lowest ankle within 5 cm of z=0: {:.4} of {total} valid person-frames", up, floor);
    assert!(up > 0.99, "upright fraction {up}");
    // Measured: 18 of the 20 scenes within 1 cm; TS6 and TS9 at −4.9 and −3.3 cm.
    assert!(level_scenes >= 18, "{level_scenes} of 20 scenes with planted feet within 1 cm of z = 0");
    assert!(floor > 0.8, "near-floor fraction {floor}");
}

#[test]
fn written_dataset_reads_back_bit_identically() {
    let Some(dir) = mupots_dir() else { return };
    let ds = read(&dir);
    let out = std::env::temp_dir().join(format!("socdiff-rt-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    write_dataset(&ds, &out).unwrap();
    let back = read(&out);
    assert_eq!(back, ds);
    // Writing again into the same non-empty directory is refused and leaves it intact.
    let e = write_dataset(&ds, &out).unwrap_err().to_string();
    assert!(e.contains("not empty"), "{e}");
    assert_eq!(read(&out), ds);
    std::fs::remove_dir_all(&out).unwrap();
}
