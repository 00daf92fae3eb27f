//! Bad dataset directories get one clear error naming the file and the problem; the `.npy`
//! reader survives mutated real files.

use ndarray::Array4;
use rand::{Rng, SeedableRng};
use socdiff_engine::data::dataset::{read_dataset, write_dataset, ReadOptions, Sequence};
use socdiff_engine::data::npy::{parse_npy, write_npy_f32};
use socdiff_engine::{Dataset, Scene, Skeleton, Split};
use std::path::{Path, PathBuf};

/// A fresh two-sequence dataset directory in a temp folder.
fn fixture(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("socdiff-bad-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let sk = Skeleton::mupots17();
    let scene = |name: &str| {
        let pos = Array4::from_shape_fn((12, 2, 17, 3), |(f, p, j, k)| (f + p + j) as f32 * 0.01 + k as f32);
        Scene::new(name, 30.0, sk.clone(), pos).unwrap()
    };
    let ds = Dataset {
        name: "toy".into(),
        sequences: vec![Sequence { split: Split::Train, scene: scene("a") }, Sequence { split: Split::Test, scene: scene("b") }],
        metadata: Default::default(),
    };
    write_dataset(&ds, &dir).unwrap();
    dir
}

fn read_err(dir: &Path) -> String {
    let e = read_dataset(dir, &ReadOptions::default()).unwrap_err().to_string();
    let _ = std::fs::remove_dir_all(dir);
    assert!(!e.contains('\n'), "one line: {e}");
    e
}

fn edit_json(dir: &Path, from: &str, to: &str) {
    let p = dir.join("dataset.json");
    let text = std::fs::read_to_string(&p).unwrap();
    assert!(text.contains(from), "fixture has {from}");
    std::fs::write(&p, text.replacen(from, to, 1)).unwrap();
}

#[test]
fn fixture_reads() {
    let dir = fixture("ok");
    let ds = read_dataset(&dir, &ReadOptions::default()).unwrap();
    assert_eq!(ds.sequences.len(), 2);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn missing_file_is_named() {
    let dir = fixture("missing");
    std::fs::remove_file(dir.join("test/b.npy")).unwrap();
    let e = read_err(&dir);
    assert!(e.contains("test/b.npy") && e.contains("No such file"), "{e}");
}

#[test]
fn missing_dataset_json_is_named() {
    let dir = fixture("nojson");
    std::fs::remove_file(dir.join("dataset.json")).unwrap();
    let e = read_err(&dir);
    assert!(e.contains("dataset.json"), "{e}");
}

#[test]
fn wrong_dtype_is_named() {
    let dir = fixture("dtype");
    let raw: Vec<u8> = std::iter::repeat_n(0u8, 12 * 2 * 17 * 3 * 8).collect();
    let mut bytes = std::fs::read(dir.join("train/a.npy")).unwrap();
    let header_end = bytes.len() - 12 * 2 * 17 * 3 * 4;
    let at = bytes[..header_end].windows(3).position(|w| w == b"<f4").unwrap();
    bytes.truncate(header_end);
    bytes[at + 2] = b'8';
    bytes.extend_from_slice(&raw);
    std::fs::write(dir.join("train/a.npy"), bytes).unwrap();
    let e = read_err(&dir);
    assert!(e.contains("train/a.npy") && e.contains("<f8") && e.contains("float32"), "{e}");
}

#[test]
fn wrong_shape_is_named() {
    let dir = fixture("shape");
    write_npy_f32(&dir.join("train/a.npy"), &[12, 2, 16, 3], &vec![0.0; 12 * 2 * 16 * 3]).unwrap();
    let e = read_err(&dir);
    assert!(e.contains("train/a.npy") && e.contains("[12, 2, 16, 3]") && e.contains("[12, 2, 17, 3]"), "{e}");
}

#[test]
fn truncated_npy_is_named() {
    let dir = fixture("trunc");
    let p = dir.join("test/b.npy");
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() - 100]).unwrap();
    let e = read_err(&dir);
    assert!(e.contains("test/b.npy") && e.contains("needs 4896 bytes") && e.contains("has 4796"), "{e}");
}

#[test]
fn nan_position_is_named() {
    let dir = fixture("nan");
    let mut v = vec![0.5f32; 12 * 2 * 17 * 3];
    v[(3 * 2 + 1) * 17 * 3 + 4 * 3] = f32::NAN;
    write_npy_f32(&dir.join("train/a.npy"), &[12, 2, 17, 3], &v).unwrap();
    let e = read_err(&dir);
    assert!(e.contains("train/a.npy") && e.contains("frame 3, person 1, joint 4"), "{e}");
}

#[test]
fn unknown_joint_is_named() {
    let dir = fixture("joint");
    edit_json(&dir, "\"left\": 11", "\"left\": \"left_hip_joint\"");
    let e = read_err(&dir);
    assert!(e.contains("dataset.json") && e.contains("unknown joint \"left_hip_joint\""), "{e}");
}

#[test]
fn file_named_but_missing_in_json() {
    let dir = fixture("json-file");
    edit_json(&dir, "\"file\": \"train/a.npy\"", "\"file\": \"train/zzz.npy\"");
    let e = read_err(&dir);
    assert!(e.contains("train/zzz.npy"), "{e}");
}

#[test]
fn frame_count_mismatch_is_named() {
    let dir = fixture("frames");
    edit_json(&dir, "\"frames\": 12", "\"frames\": 13");
    let e = read_err(&dir);
    assert!(e.contains("train/a.npy") && e.contains("shape"), "{e}");
}

#[test]
fn bad_split_and_json_are_named() {
    let dir = fixture("split");
    edit_json(&dir, "\"split\": \"train\"", "\"split\": \"holdout\"");
    let e = read_err(&dir);
    assert!(e.contains("dataset.json") && e.contains("holdout"), "{e}");
    let dir = fixture("json");
    std::fs::write(dir.join("dataset.json"), "{\"name\": 3").unwrap();
    let e = read_err(&dir);
    assert!(e.contains("dataset.json"), "{e}");
}

/// Thousands of seeded mutations of a real MuPoTS `.npy` file: the parser returns Ok or Err,
/// never panics, and never allocates beyond the file.
#[test]
fn npy_reader_survives_mutations() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/mupots3d/train/TS1_valid.npy");
    let Ok(original) = std::fs::read(&path) else {
        socdiff_engine::testing::skip_absent(&path, "shared MuPoTS data");
        return;
    };
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    let (mut ok, mut err) = (0, 0);
    for _ in 0..5000 {
        let mut b = original.clone();
        for _ in 0..rng.gen_range(1..4) {
            match rng.gen_range(0..5) {
                0 => {
                    let i = rng.gen_range(0..b.len());
                    b[i] = rng.gen();
                }
                1 => b.truncate(rng.gen_range(0..b.len().max(1))),
                2 => {
                    // Rewrite a digit of the header (shape) to a long number.
                    let i = rng.gen_range(0..b.len().min(128));
                    let digits = format!("{}", rng.gen::<u64>());
                    b.splice(i..i, digits.bytes());
                }
                3 => {
                    let i = rng.gen_range(0..b.len());
                    let n = rng.gen_range(0..16).min(b.len() - i);
                    b.drain(i..i + n);
                }
                _ => {
                    let i = rng.gen_range(0..b.len().min(64));
                    b[i] = b"0123456789(),' "[rng.gen_range(0..15)];
                }
            }
            if b.is_empty() {
                break;
            }
        }
        match parse_npy(&b) {
            Ok(a) => {
                ok += 1;
                assert!(a.shape.iter().product::<usize>() <= b.len());
            }
            Err(_) => err += 1,
        }
    }
    eprintln!("npy mutations: {ok} parsed, {err} rejected");
    assert!(err > 1000);
}
