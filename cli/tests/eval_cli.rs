//! `socdiff eval`: reports on generated data and on MuPoTS, round trips through forecast
//! directories, and bad input.

mod common;

use common::{assert_fails, shared, socdiff, tmp};
use ndarray::Array4;
use serde_json::Value;
use socdiff_engine::data::bvh::{import_bvh, BvhImport, CMU_SCALE};
use socdiff_engine::data::dataset::{write_dataset, Dataset, Sequence};
use socdiff_engine::{Scene, Skeleton, Split};
use std::path::{Path, PathBuf};

/// The bundled CMU clip (real motion, 303 frames at 30 fps), read once.
fn clip() -> &'static Scene {
    static CLIP: std::sync::OnceLock<Scene> = std::sync::OnceLock::new();
    CLIP.get_or_init(|| import_bvh(common::cmu_clip(), &BvhImport { scale: CMU_SCALE, ..Default::default() }).unwrap())
}

/// A group of three people: `frames` frames of the clip from `start`, `start + 12` and
/// `start + 24`, placed 1.5 m apart on a circle.
fn group(name: &str, start: usize, frames: usize) -> Scene {
    let parts: Vec<Scene> = (0..3).map(|p| clip().slice_frames(start + 12 * p, start + 12 * p + frames).unwrap()).collect();
    Scene::around_circle(name, &parts, 1.5).unwrap()
}

/// A reference dataset of real motion: test scenes T0..T2 (3 persons, 120–160 frames), train
/// scenes R0, R1 cut from other times of the clip.
fn write_reference(dir: &Path) {
    let mut sequences: Vec<Sequence> = (0..3).map(|i| Sequence { split: Split::Test, scene: group(&format!("T{i}"), 30 * i, 120 + 20 * i) }).collect();
    sequences.extend((0..2).map(|i| Sequence { split: Split::Train, scene: group(&format!("R{i}"), 140 + 10 * i, 120) }));
    write_dataset(&Dataset { name: "groups".into(), sequences, metadata: Default::default() }, dir).unwrap();
}

/// A fresh folder for one test's files (so that the no-temporary-files check of one test does
/// not see another test's atomic writes).
fn base(tag: &str) -> PathBuf {
    let b = tmp(tag);
    std::fs::create_dir_all(&b).unwrap();
    b
}

fn read_json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn method<'a>(report: &'a Value, label: &str) -> &'a Value {
    report["methods"].as_array().unwrap().iter().find(|m| m["label"] == label).unwrap_or_else(|| panic!("no method {label}"))
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

/// A drawn plot: a PNG with text (near-black pixels) and the first method's line colour.
fn assert_png(path: &Path) {
    let (w, h, rgb) = socdiff_engine::export::png::read_png_rgb(path).unwrap_or_else(|e| panic!("{e}"));
    assert!(w >= 400 && h >= 300, "{}: {w}×{h}", path.display());
    let near = |c: [u8; 3], tol: i32| rgb.chunks_exact(3).filter(|p| p.iter().zip(c).all(|(&a, b)| (a as i32 - b as i32).abs() <= tol)).count();
    let text = near([0, 0, 0], 60);
    let line = near(socdiff_engine::export::person_colour(0), 12);
    assert!(text > 500 && line > 100, "{}: {text} text pixels, {line} pixels of the first method's colour", path.display());
}

#[test]
fn baselines_report_plots_and_round_trip() {
    let b = base("eval-baselines");
    let (data, out, written) = (b.join("data"), b.join("report"), b.join("baselines"));
    write_reference(&data);
    let d = data.to_str().unwrap();
    let (ok, stdout, err) = socdiff(&[
        "eval",
        "--reference",
        d,
        "--baselines",
        "all",
        "--observe",
        "20",
        "--out",
        out.to_str().unwrap(),
        "--write-baselines",
        written.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    for label in ["zero-velocity", "constant-velocity", "nearest", "ground-truth", "NDMS", "MPJPE 1s", "APD", "bone mm"] {
        assert!(stdout.contains(label), "table lacks {label}:\n{stdout}");
    }
    let report = read_json(&out.join("report.json"));
    assert_eq!(report["reference"]["split"], "test");
    assert_eq!(report["settings"]["ndms"]["database"]["split"], "test");
    assert_eq!(report["settings"]["ndms"]["word_length"], 10);
    assert!(report["socdiff_version"].is_string() && report["provenance"]["command"].as_str().unwrap().contains("eval"));
    // Ground truth: every word is in the database (NDMS 1), no error, no stretch, JS 0.
    let gt = method(&report, "ground-truth");
    assert_eq!(f(&gt["ndms"]["mean"]), 1.0);
    for h in gt["mpjpe"]["horizons"].as_array().unwrap() {
        assert_eq!(f(&h["global"]["mean"]), 0.0);
        assert_eq!(h["scenes"], 3, "every scene reaches {}", h["horizon_s"]);
    }
    assert_eq!(f(&gt["stochastic"]["ade"]), 0.0);
    assert_eq!(f(&gt["stochastic"]["mmade"]), f(&gt["stochastic"]["mmade"]));
    assert!(f(&gt["plausibility"]["bone_length_mm"]) < 1e-3);
    assert_eq!(f(&gt["plausibility"]["speed_js_mean"]), 0.0);
    assert!(gt["sscp"]["skipped"].as_str().unwrap().contains("speaking"));
    // Zero velocity: at rest after the last observed frame.
    let zv = method(&report, "zero-velocity");
    assert!(f(&zv["ndms"]["mean"]) < 0.2, "{}", zv["ndms"]["mean"]);
    assert_eq!(f(&zv["speed"]["forecast_mean"]), 0.0);
    let zv1 = f(&zv["mpjpe"]["horizons"][0]["global"]["mean"]);
    let zv3 = f(&zv["mpjpe"]["horizons"][2]["global"]["mean"]);
    assert!(zv1 > 0.01 && zv3 > 0.01, "people move: {zv1} {zv3}");
    // One sample: best of K = mean; APD = 0.
    assert_eq!(zv["mpjpe"]["horizons"][0]["global"]["mean"], zv["mpjpe"]["horizons"][0]["global"]["best"]);
    assert_eq!(f(&zv["stochastic"]["apd"]), 0.0);
    let cv = method(&report, "constant-velocity");
    assert!(f(&cv["ndms"]["mean"]) > f(&zv["ndms"]["mean"]));
    let nc = method(&report, "nearest");
    assert!(f(&nc["ndms"]["mean"]) > 0.2 && f(&nc["ndms"]["mean"]) < 1.0, "{}", nc["ndms"]["mean"]);
    assert_eq!(nc["settings"]["continuation_split"], "train");
    for p in ["ndms_over_time.png", "speed_over_time.png", "mpjpe_by_horizon.png", "speed_js_over_time.png"] {
        assert_png(&out.join(p));
    }
    assert!(!out.join("sscp_transitions.png").exists(), "no SSCP data, no heatmap");

    // The written baselines read back as forecast directories and score the same; the
    // reference directory itself scores as ground truth.
    let out2 = b.join("report2");
    let cv_dir = written.join("constant-velocity");
    let (ok, _, err) = socdiff(&[
        "eval",
        "--reference",
        d,
        "--forecasts",
        &format!("cv={},truth={d}", cv_dir.display()),
        "--observe",
        "20",
        "--metrics",
        "ndms,mpjpe",
        "--out",
        out2.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let r2 = read_json(&out2.join("report.json"));
    let cv2 = method(&r2, "cv");
    assert_eq!(cv2["kind"], "forecasts");
    assert_eq!(cv2["ndms"]["mean"], cv["ndms"]["mean"]);
    assert_eq!(cv2["mpjpe"]["horizons"], cv["mpjpe"]["horizons"]);
    assert_eq!(cv2["inputs"][0]["provenance"]["forecast"]["method"], "constant-velocity");
    let truth = method(&r2, "truth");
    assert_eq!(truth["kind"], "dataset");
    assert_eq!(f(&truth["ndms"]["mean"]), 1.0);
    assert!(truth.get("plausibility").is_none(), "only the requested metrics");
    std::fs::remove_dir_all(&b).unwrap();
}

#[test]
fn bad_input_fails_with_one_line_and_writes_nothing() {
    let b = base("eval-bad");
    let data = b.join("data");
    write_reference(&data);
    let d = data.to_str().unwrap();
    let out = b.join("out");
    let o = out.to_str().unwrap();
    assert_fails(&["eval", "--reference", d, "--forecasts", "/nonexistent/forecasts", "--out", o], &["/nonexistent/forecasts", "not found"], &out);
    assert_fails(&["eval", "--reference", "/nonexistent/ref", "--baselines", "all", "--out", o], &["/nonexistent/ref"], &out);
    assert_fails(&["eval", "--reference", d, "--baselines", "all", "--metrics", "ndms,mpjep", "--out", o], &["mpjep"], &out);
    assert_fails(&["eval", "--reference", d, "--baselines", "zero", "--out", o], &["zero"], &out);
    assert_fails(&["eval", "--reference", d, "--out", o], &["nothing to evaluate"], &out);
    assert_fails(&["eval", "--reference", d, "--baselines", "all", "--horizon", "500", "--out", o], &["--horizon 500", "T0"], &out);
    // Skeleton mismatch: a Panoptic-19 scene under a reference name.
    let other = b.join("skeleton");
    let pan = Scene::new("T0", 30.0, Skeleton::panoptic19(), Array4::zeros((100, 3, 19, 3))).unwrap();
    write_dataset(&Dataset { name: "pan".into(), sequences: vec![Sequence { split: Split::Test, scene: pan }], metadata: Default::default() }, &other).unwrap();
    assert_fails(&["eval", "--reference", d, "--forecasts", other.to_str().unwrap(), "--out", o], &["skeleton", "T0"], &out);
    // A forecast longer than its reference scene (written against a longer reference).
    let long_ref = b.join("longref");
    // T0 of a reference whose scenes run 40 frames longer.
    let long = group("T0", 0, 160);
    write_dataset(&Dataset { name: "long".into(), sequences: vec![Sequence { split: Split::Test, scene: long }], metadata: Default::default() }, &long_ref)
        .unwrap();
    let fc = b.join("long-fc");
    let (ok, _, err) = socdiff(&[
        "eval",
        "--reference",
        long_ref.to_str().unwrap(),
        "--baselines",
        "zero-velocity",
        "--metrics",
        "mpjpe",
        "--out",
        b.join("long-report").to_str().unwrap(),
        "--write-baselines",
        fc.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let fc_dir = fc.join("zero-velocity");
    assert_fails(&["eval", "--reference", d, "--forecasts", fc_dir.to_str().unwrap(), "--out", o], &["longer than the reference scene T0", "160 frames"], &out);
    // ... which --crop accepts.
    let (ok, _, err) = socdiff(&["eval", "--reference", d, "--forecasts", fc_dir.to_str().unwrap(), "--crop", "--metrics", "mpjpe", "--out", o]);
    assert!(ok, "{err}");
    // An existing, non-empty output is refused.
    assert_fails(&["eval", "--reference", d, "--baselines", "all", "--out", d], &["refusing to overwrite"], &b.join("never-written"));
    std::fs::remove_dir_all(&b).unwrap();
}

/// `--generated`: scenes with no recorded future (here the reference's own train split, as
/// `--generated-split train`, i.e. real motion: the real-motion level) scored by NDMS from
/// frame 0, coverage and bone lengths; bad input in one line, nothing written.
#[test]
fn generated_scenes_report_coverage() {
    let b = base("eval-generated");
    let data = b.join("data");
    write_reference(&data);
    let d = data.to_str().unwrap();
    let out = b.join("out");
    let o = out.to_str().unwrap();
    let (ok, stdout, err) = socdiff(&[
        "eval",
        "--reference",
        d,
        "--generated",
        &format!("real={d}"),
        "--generated-split",
        "train",
        "--metrics",
        "ndms,coverage,bone-length,mpjpe",
        "--out",
        o,
    ]);
    assert!(ok, "{err}");
    assert!(stdout.contains("precision") && stdout.contains("recall"), "{stdout}");
    let report = read_json(&out.join("report.json"));
    let m = method(&report, "real");
    assert_eq!(m["kind"], "generated");
    // R0, R1: one shape (3 persons × 120 frames), two samples, from frame 0 (κ = 10 observed).
    assert_eq!(m["scenes"].as_array().unwrap().len(), 1);
    assert_eq!((m["scenes"][0]["samples"].as_u64(), m["scenes"][0]["observed_frames"].as_u64()), (Some(2), Some(10)));
    assert_eq!(m["ndms"]["words"].as_u64(), Some(2 * 3 * (120 - 10 + 1)));
    let (p, r) = (f(&m["coverage"]["precision"]), f(&m["coverage"]["recall"]));
    assert!(p > 0.0 && p <= 1.0 && r > 0.0 && r <= 1.0, "{p} {r}");
    assert!(f(&m["plausibility"]["bone_length_mm"]) < 1.0, "the clip's bones are rigid");
    assert!(m["mpjpe"]["horizons"].as_array().unwrap().iter().all(|h| h["scenes"] == 0), "no recorded future");
    let never = b.join("never");
    let n = never.to_str().unwrap();
    assert_fails(&["eval", "--reference", d, "--generated", d, "--metrics", "kinds", "--out", n], &["--kinds-data"], &never);
    assert_fails(&["eval", "--reference", d, "--generated", d, "--generated-split", "validation", "--out", n], &["no validation sequences"], &never);
    let pan = b.join("pan");
    let scene = Scene::new("G", 30.0, Skeleton::panoptic19(), Array4::zeros((100, 3, 19, 3))).unwrap();
    write_dataset(&Dataset { name: "pan".into(), sequences: vec![Sequence { split: Split::Test, scene }], metadata: Default::default() }, &pan).unwrap();
    assert_fails(&["eval", "--reference", d, "--generated", pan.to_str().unwrap(), "--out", n], &[pan.to_str().unwrap(), "skeleton"], &never);
    std::fs::remove_dir_all(&b).unwrap();
}

/// MuPoTS test split, 1 s observed, to the end of each scene: NDMS and MPJPE of the baselines.
#[test]
fn mupots_test_split_baselines() {
    let Some(mupots) = shared("mupots3d") else { return };
    let b = base("eval-mupots");
    let out = b.join("report");
    let (ok, stdout, err) = socdiff(&[
        "eval",
        "--reference",
        mupots.to_str().unwrap(),
        "--baselines",
        "zero-velocity,constant-velocity,ground-truth",
        "--metrics",
        "ndms,mpjpe,speed",
        "--observe",
        "30",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    println!("{stdout}");
    let r = read_json(&out.join("report.json"));
    assert_eq!(r["reference"]["scenes"].as_array().unwrap().len(), 5);
    let gt = method(&r, "ground-truth");
    assert_eq!(f(&gt["ndms"]["mean"]), 1.0);
    let zv = method(&r, "zero-velocity");
    let cv = method(&r, "constant-velocity");
    assert!(f(&zv["ndms"]["mean"]) < 0.1, "{}", zv["ndms"]["mean"]);
    assert!(f(&cv["ndms"]["mean"]) > f(&zv["ndms"]["mean"]));
    // TS18 has 126 frames: 96 forecast frames reach 3 s (frame 89) — every scene counts.
    for m in [zv, cv] {
        let h = m["mpjpe"]["horizons"].as_array().unwrap();
        assert_eq!(h.iter().map(|h| h["scenes"].as_u64().unwrap()).collect::<Vec<_>>(), [5, 5, 5]);
        let e: Vec<f64> = h.iter().map(|h| f(&h["global"]["mean"])).collect();
        assert!(e[0] > 0.01 && e[0] < 1.0 && e[2] > e[0], "{e:?}");
    }
    // The baselines are deterministic: the values docs/ quotes (mm at 1/2/3 s: zero velocity
    // 255/474/628, constant velocity 277/590/881), so zero velocity is the better one at every
    // horizon and constant velocity drifts off.
    let mm = |m: &Value| -> Vec<f64> { (0..3).map(|i| (f(&m["mpjpe"]["horizons"][i]["global"]["mean"]) * 1e3).round()).collect() };
    assert_eq!((mm(zv), mm(cv)), (vec![255.0, 474.0, 628.0], vec![277.0, 590.0, 881.0]));
    assert_png(&out.join("ndms_over_time.png"));
    std::fs::remove_dir_all(&b).unwrap();
}
