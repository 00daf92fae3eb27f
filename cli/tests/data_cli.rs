//! `socdiff data inspect|convert` end to end: real files, and bad input that must produce one
//! clear error line naming the file, a non-zero exit, and nothing written.

mod common;

use common::{assert_fails, shared, socdiff, tmp};
use std::path::{Path, PathBuf};

fn fixture(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../engine/tests/fixtures").join(rel)
}

#[test]
fn inspect_mupots_reports_the_dataset() {
    let Some(dir) = shared("mupots3d") else { return };
    let (ok, out, err) = socdiff(&["data", "inspect", dir.to_str().unwrap(), "--sequences"]);
    assert!(ok, "{err}");
    for line in ["sequences     20", "frames        8370", "persons       2–3", "split         train 15 / test 5", "joints        17 "] {
        assert!(out.contains(line), "missing {line:?} in\n{out}");
    }
    assert!(out.contains("TS12") && out.contains("tilt°"));
}

#[test]
fn convert_mupots_and_read_back() {
    let Some(dir) = shared("mupots3d") else { return };
    let out = tmp("mupots");
    let (ok, stdout, err) = socdiff(&["data", "convert", dir.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(stdout.contains("20 sequences, 8370 frames"), "{stdout}");
    let (ok, info, _) = socdiff(&["data", "inspect", out.to_str().unwrap()]);
    assert!(ok && info.contains("frames        8370") && info.contains("dataset       mupots3d"), "{info}");
    // Converting again into the same directory is refused.
    let (ok, _, err) = socdiff(&["data", "convert", dir.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(!ok && err.contains("not empty"), "{err}");
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn convert_bvh_files_into_one_group_scene_at_30_fps() {
    let (Some(a), Some(b)) = (shared("cmu_bvh/131_01.bvh"), shared("cmu_bvh/131_02.bvh")) else { return };
    let out = tmp("group");
    let (ok, _, err) = socdiff(&[
        "data",
        "convert",
        a.to_str().unwrap(),
        b.to_str().unwrap(),
        "--persons-from-files",
        "--resample",
        "30",
        "--bvh-scale",
        "cmu",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let (ok, info, err) = socdiff(&["data", "inspect", out.to_str().unwrap(), "--sequences"]);
    assert!(ok, "{err}");
    // 994 frames at 120 fps → 249 at 30 fps; the group is as long as its shorter member.
    assert!(info.contains("persons       2") && info.contains("fps           30") && info.contains("frames        249"), "{info}");

    // The group forecasts with a MuPoTS-17 model: its joints are mapped by name, the head top
    // (which CMU's joints lack) at MuPoTS's mean offset from the head.
    let Some(mupots) = shared("mupots3d") else { return };
    let (run, fc) = (tmp("group-model"), tmp("group-fc"));
    let args = ["train", "--data", mupots.to_str().unwrap(), "--out", run.to_str().unwrap(), "--steps", "2", "--hidden", "16", "--batch", "2"];
    let (ok, _, err) = socdiff(&args);
    assert!(ok, "{err}");
    let (ok, _, err) = socdiff(&[
        "forecast",
        "--model",
        run.to_str().unwrap(),
        "--input",
        out.to_str().unwrap(),
        "--joint-map",
        "auto",
        "--observe",
        "30",
        "--horizon",
        "30",
        "--samples",
        "2",
        "--steps",
        "2",
        "--out",
        fc.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(err.contains("head_top ← Head + (0.000, 0.040, 0.170) m in the body frame (MuPoTS-3D's mean offset)"), "{err}");
    let forecast = socdiff_engine::data::dataset::read_dataset(&fc, &Default::default()).unwrap();
    assert_eq!(forecast.sequences.last().unwrap().scene.positions.dim(), (60, 2, 17, 3));
    for dir in [out, run, fc] {
        std::fs::remove_dir_all(dir).unwrap();
    }
}

#[test]
fn inspect_haggling_speech_and_body() {
    if let Some(p) = shared("haggling_speech/170221_haggling_b1_group0.pkl") {
        let (ok, out, err) = socdiff(&["data", "inspect", p.to_str().unwrap()]);
        assert!(ok, "{err}");
        assert!(out.contains("1223..3055 (1833 frames)") && out.contains("buyer         2"), "{out}");
    }
    let body = fixture("haggling/body_p0.pkl");
    let (ok, out, err) = socdiff(&["data", "inspect", body.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(out.contains("persons       3") && out.contains("=buyer") && out.contains("panoptic19"), "{out}");
}

#[test]
fn missing_input_is_an_error() {
    let out = tmp("missing");
    assert_fails(&["data", "convert", "/nonexistent/x.bvh", "--out", out.to_str().unwrap()], &["/nonexistent/x.bvh"], &out);
    assert_fails(&["data", "inspect", "/nonexistent/dir"], &["/nonexistent/dir"], &tmp("never"));
}

#[test]
fn truncated_and_foreign_pickles_are_errors() {
    let dir = tmp("pkl");
    std::fs::create_dir_all(&dir).unwrap();
    let body = std::fs::read(fixture("haggling/body_p2.pkl")).unwrap();
    let truncated = dir.join("truncated.pkl");
    std::fs::write(&truncated, &body[..body.len() / 2]).unwrap();
    let out = dir.join("out");
    assert_fails(&["data", "convert", truncated.to_str().unwrap(), "--out", out.to_str().unwrap()], &["truncated.pkl"], &out);
    // A pickle that would run os.system when unpickled by Python.
    let foreign = dir.join("foreign.pkl");
    std::fs::write(&foreign, b"cos\nsystem\n(S'echo hi'\ntR.").unwrap();
    assert_fails(&["data", "convert", foreign.to_str().unwrap(), "--out", out.to_str().unwrap()], &["foreign.pkl", "os.system"], &out);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bvh_with_a_bad_channel_line_is_an_error() {
    let dir = tmp("bvh");
    std::fs::create_dir_all(&dir).unwrap();
    let text = std::fs::read_to_string(fixture("bvh/other_source.bvh")).unwrap();
    let line = text.lines().position(|l| l.trim_start().starts_with("CHANNELS")).unwrap();
    let bad: Vec<String> = text.lines().enumerate().map(|(i, l)| if i == line { l.replace("CHANNELS 6", "CHANNELS 7") } else { l.to_string() }).collect();
    let path = dir.join("bad.bvh");
    std::fs::write(&path, bad.join("\n")).unwrap();
    let out = dir.join("out");
    assert_fails(&["data", "convert", path.to_str().unwrap(), "--out", out.to_str().unwrap()], &["bad.bvh", &format!("line {}", line + 1)], &out);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A copy of a small converted dataset, to break in various ways.
fn small_dataset(tag: &str) -> Option<(PathBuf, PathBuf)> {
    let bvh = fixture("bvh/other_source.bvh");
    let dir = tmp(tag);
    std::fs::create_dir_all(&dir).unwrap();
    let ds = dir.join("ds");
    let (ok, _, err) = socdiff(&["data", "convert", bvh.to_str().unwrap(), "--out", ds.to_str().unwrap()]);
    assert!(ok, "{err}");
    Some((dir, ds))
}

#[test]
fn broken_dataset_directories_are_errors() {
    let Some((dir, ds)) = small_dataset("ds") else { return };
    let json = std::fs::read_to_string(ds.join("dataset.json")).unwrap();
    let npy = ds.join("train/other_source.npy");
    let out = dir.join("out");
    let conv = |names: &[&str]| assert_fails(&["data", "convert", ds.to_str().unwrap(), "--out", out.to_str().unwrap()], names, &out);

    // dataset.json naming a missing file
    std::fs::write(ds.join("dataset.json"), json.replace("train/other_source.npy", "train/gone.npy")).unwrap();
    conv(&["train/gone.npy"]);
    // unknown joint
    let left = json.find("\"left\":").unwrap();
    let end = left + json[left..].find([',', '\n', '}']).unwrap();
    std::fs::write(ds.join("dataset.json"), format!("{}\"left\": \"no_such_joint\"{}", &json[..left], &json[end..])).unwrap();
    conv(&["dataset.json", "no_such_joint"]);
    std::fs::write(ds.join("dataset.json"), &json).unwrap();
    // .npy of the wrong dtype
    let bytes = std::fs::read(&npy).unwrap();
    let at = bytes.windows(3).position(|w| w == b"<f4").unwrap();
    let mut wrong = bytes.clone();
    wrong[at + 1] = b'i';
    std::fs::write(&npy, &wrong).unwrap();
    conv(&["other_source.npy", "<i4"]);
    // .npy of the wrong shape (one value short)
    std::fs::write(&npy, &bytes[..bytes.len() - 4]).unwrap();
    conv(&["other_source.npy", "bytes"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A bare `[frames, 17, 3]` array in millimetres, the distinct value of every entry.
fn write_array(path: &Path, frames: usize, joints: usize) {
    let data: Vec<f32> = (0..frames * joints * 3).map(|i| 100.0 + i as f32).collect();
    socdiff_engine::data::npy::write_npy_f32(path, &[frames, joints, 3], &data).unwrap();
}

#[test]
fn bare_arrays_and_folders_of_them_import_with_a_named_skeleton() {
    let root = tmp("arrays");
    std::fs::create_dir_all(root.join("clips")).unwrap();
    for k in 0..4 {
        write_array(&root.join(format!("clips/clip{k}.npy")), 12, 17);
    }
    let one = root.join("one");
    let args = ["--skeleton", "mupots17", "--fps", "30", "--units", "mm", "--up", "z"];
    let mut a = vec!["data".to_string(), "convert".into(), root.join("clips/clip0.npy").to_str().unwrap().into(), "--out".into(), one.to_str().unwrap().into()];
    a.extend(args.iter().map(|s| s.to_string()));
    let (ok, stdout, err) = socdiff(&a);
    assert!(ok, "{err}");
    assert!(stdout.contains("1 sequences, 12 frames"), "{stdout}");
    let (ok, info, _) = socdiff(&["data", "inspect", one.to_str().unwrap()]);
    assert!(ok && info.contains("mupots17") && info.contains("fps           30"), "{info}");
    // A folder: one sequence per file; every second one to the test split.
    let folder = root.join("folder");
    let mut a = vec![
        "data".to_string(),
        "convert".into(),
        root.join("clips").to_str().unwrap().into(),
        "--test-every".into(),
        "2".into(),
        "--out".into(),
        folder.to_str().unwrap().into(),
    ];
    a.extend(args.iter().map(|s| s.to_string()));
    let (ok, stdout, err) = socdiff(&a);
    assert!(ok, "{err}");
    assert!(stdout.contains("4 sequences, 48 frames (2 sequences in the test split)"), "{stdout}");
    // Bad input: one error line naming the problem, nothing written.
    let bad = root.join("bad");
    let clip = root.join("clips/clip1.npy");
    let c = clip.to_str().unwrap();
    let b = bad.to_str().unwrap();
    assert_fails(
        &["data", "convert", c, "--skeleton", "smpl", "--fps", "30", "--units", "mm", "--up", "z", "--out", b],
        &["unknown skeleton \"smpl\"", "smpl22"],
        &bad,
    );
    assert_fails(
        &["data", "convert", c, "--skeleton", "smpl22", "--fps", "30", "--units", "mm", "--up", "z", "--out", b],
        &["clip1.npy", "[12, 17, 3]", "smpl22 (22 joints)"],
        &bad,
    );
    assert_fails(&["data", "convert", c, "--skeleton", "mupots17", "--fps", "30", "--up", "z", "--out", b], &["--units is missing"], &bad);
    assert_fails(&["data", "convert", c, "--out", b], &["clip1.npy", "skeleton"], &bad);
    assert_fails(&["data", "convert", c, "--skeleton", "mupots17", "--fps", "30", "--units", "mm", "--up", "x", "--out", b], &["up_axis \"x\""], &bad);
}

#[test]
fn groups_are_composed_from_recorded_scenes() {
    let Some(mupots) = shared("mupots3d") else { return };
    let m = mupots.to_str().unwrap();
    let root = tmp("compose");
    let out = root.join("group7");
    let scene = |s: &str| format!("{m}:{s}");
    let (ok, stdout, err) = socdiff(&[
        "data",
        "compose",
        "--scene",
        &scene("TS16"),
        "--scene",
        &scene("TS17"),
        "--scene",
        &scene("TS19:0"),
        "--spacing",
        "5",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(stdout.contains("7 persons") && stdout.contains("test split"), "{stdout}");
    let (ok, info, _) = socdiff(&["data", "inspect", out.to_str().unwrap()]);
    assert!(ok && info.contains("persons       7"), "{info}");
    let bad = root.join("bad");
    let b = bad.to_str().unwrap();
    // A train scene beside test scenes, the same scene twice where it was recorded, a sequence
    // that is not there, a person twice.
    assert_fails(
        &["data", "compose", "--scene", &scene("TS1"), "--scene", &scene("TS16"), "--spacing", "5", "--out", b],
        &["TS1 is in the train split", "--mix-splits"],
        &bad,
    );
    assert_fails(
        &["data", "compose", "--scene", &scene("TS16"), "--scene", &scene("TS16"), "--placement", "recorded", "--out", b],
        &["come within 0.00 m", "closer than 0.5 m"],
        &bad,
    );
    assert_fails(&["data", "compose", "--scene", &scene("TS99"), "--out", b], &["mupots3d", "no sequence \"TS99\""], &bad);
    assert_fails(&["data", "compose", "--scene", &scene("TS16:0,0"), "--out", b], &["person 0 selected twice"], &bad);
}

#[test]
fn convert_maps_bvh_onto_a_named_skeleton_and_names_joints_it_cannot_make() {
    let clip = common::cmu_clip();
    let out = tmp("map-to");
    let (ok, _, err) = socdiff(&["data", "convert", clip.to_str().unwrap(), "--bvh-scale", "cmu", "--map-to", "mrt15", "--out", out.to_str().unwrap()]);
    assert!(ok, "{err}");
    let (ok, info, err) = socdiff(&["data", "inspect", out.to_str().unwrap()]);
    assert!(ok, "{err}");
    // The head top is the BVH's head end site; every one of MRT's 15 joints is there, in order.
    assert!(info.contains("joints        15 (mrt15): pelvis, left_hip, left_knee"), "{info}");
    assert!(info.contains("neck – head_top"), "{info}");
    // MRT's 15 joints have no spine or head: MuPoTS-17 cannot be made from them alone.
    let bad = tmp("map-to-bad");
    assert_fails(&["data", "convert", out.to_str().unwrap(), "--map-to", "mupots17", "--out", bad.to_str().unwrap()], &["spine"], &bad);
    let (ok, _, err) = socdiff(&["data", "convert", clip.to_str().unwrap(), "--map-to", "nosuch", "--out", bad.to_str().unwrap()]);
    assert!(!ok && err.contains("mupots17") && !bad.exists(), "{err}");
    std::fs::remove_dir_all(&out).unwrap();
}
