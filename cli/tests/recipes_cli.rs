//! The recipe commands end to end with tiny models: `socdiff demo` (embedded scene → model →
//! forecast → view → report, and --resume), `socdiff ablate` (aggregators with the leader/follower
//! probe; samplers), `socdiff train` on two sources; error cases (one line, exit ≠ 0, nothing
//! written).

mod common;

use common::{assert_fails, cmu_clip, shared, socdiff, tmp};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Tiny training and sampling settings shared by the demo runs.
const TINY: [&str; 15] =
    ["--steps", "3", "--hidden", "8", "--window", "32", "--batch", "2", "--samples", "2", "--sampling-steps", "2", "--horizon", "90", "--train"];

/// One tiny demo run, shared by the tests that need its data and model.
fn demo_dir() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let out = tmp("demo");
        let mut args: Vec<String> = vec!["demo".into(), "--out".into(), out.display().to_string()];
        args.extend(TINY.iter().map(|s| s.to_string()));
        let (ok, stdout, err) = socdiff(&args);
        assert!(ok, "demo failed: {err}");
        assert!(stdout.contains("NDMS") && stdout.contains("MPJPE"), "{stdout}");
        out
    })
}

fn json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).unwrap()
}

#[test]
fn demo_runs_the_whole_pipeline_and_resumes() {
    let out = demo_dir();
    for f in ["data/dataset.json", "model/checkpoint.json", "forecast/dataset.json", "forecast.html", "report.json", "report.txt"] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let rep = json(&out.join("report.json"));
    // One test group of 3 persons, 2 samples, 60 observed + 90 forecast frames: 91 NDMS words.
    assert_eq!((rep["scenes"].as_u64(), rep["samples"].as_u64(), rep["horizon"].as_u64()), (Some(1), Some(2), Some(90)));
    assert_eq!(rep["persons"], serde_json::json!([3, 3]));
    assert_eq!(rep["ndms"]["per_frame"].as_array().unwrap().len(), 91);
    let ndms = rep["ndms"]["mean"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&ndms), "{ndms}");
    assert!(rep["mpjpe"][2]["mean"].as_f64().unwrap() > 0.0, "3 s is covered by the recorded test group");
    assert_eq!(rep["settings"]["train"]["steps"], 3);
    // An existing output needs --resume; with it, training continues to the new step count.
    let mut args: Vec<String> = vec!["demo".into(), "--out".into(), out.display().to_string()];
    args.extend(TINY.iter().map(|s| s.to_string()));
    let (ok, _, err) = socdiff(&args);
    assert!(!ok && err.lines().count() == 1 && err.contains("--resume"), "{err}");
    args[4] = "5".into(); // --steps 5
    args.push("--resume".into());
    let (ok, _, err) = socdiff(&args);
    assert!(ok, "{err}");
    assert!(err.contains("resuming at step 3 of 5"), "{err}");
    assert_eq!(json(&out.join("report.json"))["settings"]["model_step"], 5);
}

#[test]
fn demo_forecasts_with_the_bundled_model_without_training() {
    let out = tmp("demo-pretrained");
    let (ok, stdout, err) = socdiff(&["demo", "--out", out.to_str().unwrap(), "--samples", "2", "--sampling-steps", "5"]);
    assert!(ok, "{err}");
    assert!(err.contains("bundled pretrained model") && !err.contains("2/5 train"), "{err}");
    assert!(stdout.contains("MPJPE"), "{stdout}");
    // The model's file, nothing trained; the scene went onto its 15 joints.
    assert!(out.join("model/model.safetensors").is_file() && !out.join("model/checkpoint.json").exists());
    let rep = json(&out.join("report.json"));
    assert_eq!(rep["settings"]["model"], "models/groups-mrt15/model.safetensors");
    let fc = json(&out.join("forecast/dataset.json"));
    assert_eq!(fc["joints"].as_array().unwrap().len(), 15);
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn demo_errors_are_one_line_and_write_nothing() {
    let out = tmp("demo-bad");
    assert_fails(&["demo", "--out", out.to_str().unwrap(), "--data", "/nonexistent/dataset"], &["/nonexistent/dataset"], &out);
    assert_fails(&["demo", "--out", out.to_str().unwrap(), "--samples", "0"], &["--samples"], &out);
    // A single BVH file has no test split.
    assert_fails(&["demo", "--out", out.to_str().unwrap(), "--data", cmu_clip().to_str().unwrap()], &["train and test"], &out);
}

#[test]
fn ablate_aggregators_and_samplers_make_tables() {
    let demo = demo_dir();
    let data = demo.join("data");
    let out = tmp("ablate-agg");
    let common = ["--samples", "1", "--observe", "30", "--horizon", "30", "--window-stride", "0", "--seed", "3"];
    let mut args: Vec<&str> = vec!["ablate", "--data", data.to_str().unwrap(), "--out", out.to_str().unwrap(), "--aggregators", "none,mean"];
    args.extend(["--steps", "2", "--hidden", "8", "--window", "32", "--batch", "2", "--sampling-steps", "2", "--probe-steps", "2"]);
    args.extend(common);
    let (ok, stdout, err) = socdiff(&args);
    assert!(ok, "{err}");
    let table = std::fs::read_to_string(out.join("table.md")).unwrap();
    assert_eq!(table, stdout.trim_end_matches('\n').to_string() + "\n", "printed table = table.md");
    // The table renders: header, separator and rows have the same number of cells.
    let rows: Vec<&str> = table.lines().take_while(|l| l.starts_with('|')).collect();
    assert!(rows.len() >= 3 && rows.iter().all(|l| l.matches('|').count() == rows[0].matches('|').count()), "{table}");
    for want in ["| none |", "| mean |", "NDMS ↑", "MPJPE 1 s", "follower error (m) ↓", "--seed 3"] {
        assert!(table.contains(want), "{want} missing from:\n{table}");
    }
    let res = json(&out.join("results.json"));
    assert_eq!(res["rows"].as_array().unwrap().len(), 2);
    assert!(res["rows"][0]["follower_error_m"].as_f64().unwrap() > 0.0);
    assert!(out.join("none/checkpoint.json").is_file() && out.join("report_mean/report.json").is_file());

    // Samplers on the demo's model: one row each, NDMS relative to the first.
    let out = tmp("ablate-samplers");
    let model = demo.join("model");
    let mut args: Vec<&str> = vec!["ablate", "--data", data.to_str().unwrap(), "--out", out.to_str().unwrap(), "--model", model.to_str().unwrap()];
    args.extend(["--samplers", "ddim3,ddim2"]);
    args.extend(common);
    let (ok, stdout, err) = socdiff(&args);
    assert!(ok, "{err}");
    assert!(stdout.contains("| ddim3 |") && stdout.contains("| ddim2 |") && stdout.contains("NDMS vs ddim3") && stdout.contains("+0.0 %"), "{stdout}");
    let bad = tmp("ablate-bad");
    assert_fails(&["ablate", "--data", data.to_str().unwrap(), "--out", bad.to_str().unwrap(), "--aggregators", "max"], &["max"], &bad);
    assert_fails(
        &["ablate", "--data", data.to_str().unwrap(), "--out", bad.to_str().unwrap(), "--model", model.to_str().unwrap(), "--samplers", "ddim0"],
        &["ddim0"],
        &bad,
    );
}

#[test]
fn train_on_two_sources_maps_joints_and_builds_groups() {
    let demo = demo_dir();
    let out = tmp("train-mix");
    let data = demo.join("data");
    let clip = cmu_clip();
    // The mix settings are config fields.
    let cfg = tmp("train-mix-config.json");
    std::fs::write(&cfg, r#"{"mix": {"synthetic_groups": 3, "group_frames": 40}}"#).unwrap();
    let bad_cfg = tmp("train-mix-bad-config.json");
    std::fs::write(&bad_cfg, r#"{"mix": {"synthetic_groups": 3, "group_frames": 40, "group_persons": {"min": 3, "max": 2}}}"#).unwrap();
    let flags = "train --preset paper --steps 2 --hidden 8 --window 32 --batch 2 --val-every 0";
    let mut args: Vec<&str> = flags.split(' ').collect();
    args.extend(["--config", cfg.to_str().unwrap()]);
    args.extend(["--data", data.to_str().unwrap(), "--data", clip.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    let (ok, _, err) = socdiff(&args);
    assert!(ok, "{err}");
    // The BVH has no head-top point: derived from the head, fitted on the first source.
    assert!(err.contains("(synthetic groups), 3 train scenes, 120 frames"), "{err}");
    assert!(err.contains("head_top ← head +"), "{err}");
    let meta = json(&out.join("checkpoint.json"));
    let source = meta["data"]["source"].as_str().unwrap();
    assert!(source.contains("synthetic groups of 3–3 persons × 40 frames"), "{source}");
    let bad = tmp("train-mix-bad");
    *args.last_mut().unwrap() = bad.to_str().unwrap();
    let at = args.iter().position(|a| *a == "--config").unwrap() + 1;
    args[at] = bad_cfg.to_str().unwrap();
    assert_fails(&args, &["mix.group_persons", "train-mix-bad-config.json"], &bad);
}

/// bandai2 (98 MB) stays out of the default suite (shared/data/README.md).
#[test]
#[ignore = "reads bandai2 (98 MB); run with --ignored"]
fn mupots_and_bandai_mix_when_the_shared_data_is_here() {
    let (Some(mupots), Some(bandai)) = (shared("mupots3d"), shared("bandai2")) else { return };
    let out = tmp("train-mupots-bandai");
    let cfg = tmp("train-mupots-bandai-config.json");
    std::fs::write(&cfg, r#"{"mix": {"synthetic_groups": 4}}"#).unwrap();
    let mut args: Vec<&str> = "train --preset paper --steps 1 --hidden 8 --window 64 --batch 2 --val-every 0".split(' ').collect();
    args.extend(["--config", cfg.to_str().unwrap(), "--data", mupots.to_str().unwrap(), "--data", bandai.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    let (ok, _, err) = socdiff(&args);
    assert!(ok, "{err}");
    assert!(err.contains("bandai2 (synthetic groups), 4 train scenes, 1200 frames"), "{err}");
    assert!(err.contains("16 copied, 1 derived") && err.contains("head_top ← Head +"), "{err}");
}

/// `socdiff bench quality` end to end on MuPoTS with a tiny budget: the time budget stops
/// training, the test windows are forecast and scored with the baselines under both
/// protocols, and quality.json holds every number keyed by protocol, method and horizon; a
/// second call with --resume does not train again.
#[test]
fn bench_quality_trains_forecasts_and_scores_both_protocols() {
    let Some(data) = common::shared("mupots3d") else { return };
    let out = tmp("bench-quality");
    let args = |extra: &[&str]| {
        let mut v = vec!["bench", "quality", "--hidden", "16", "--samples", "1", "--data", data.to_str().unwrap(), "--out", out.to_str().unwrap()];
        if !extra.contains(&"--minutes") {
            v.extend_from_slice(&["--minutes", "0.05"]);
        }
        v.extend_from_slice(extra);
        v.into_iter().map(String::from).collect::<Vec<_>>()
    };
    let (ok, stdout, err) = socdiff(&args(&[]));
    assert!(ok, "{err}");
    assert!(stdout.contains("MRT's protocol") && stdout.contains("zero-velocity"), "{stdout}");
    let q = json(&out.join("quality.json"));
    for m in ["ours", "zero-velocity", "constant-velocity", "nearest"] {
        for h in ["1s", "2s", "3s"] {
            let g = &q["protocol"]["ours"]["methods"][m]["mpjpe_m"][h]["global"];
            assert!(g["mean"].as_f64().is_some_and(|v| v > 0.0 && v < 2.0), "{m} {h}: {g}");
            let r = &q["protocol"]["mrt"]["methods"][m]["mean"][h];
            assert!(r.as_f64().is_some_and(|v| v > 0.0 && v < 2.0), "MRT {m} {h}: {r}");
        }
    }
    let windows = q["protocol"]["ours"]["windows"].as_u64().unwrap();
    assert!(windows > 20, "{windows} windows");
    assert_eq!(q["protocol"]["ours"]["first_frame_jump"]["per_window"].as_array().unwrap().len() as u64, windows);
    assert_eq!(q["training"]["config"]["noise"]["kind"], "prefix");
    assert_eq!(q["training"]["config"]["pose"], "residual");
    let step = q["training"]["step"].as_u64().unwrap();
    // Resumed with the budget spent: no more training, the same model.
    let (ok, _, err) = socdiff(&args(&["--resume"]));
    assert!(ok, "{err}");
    assert!(err.contains("minutes are spent"), "{err}");
    assert_eq!(json(&out.join("quality.json"))["training"]["step"].as_u64().unwrap(), step);
    // A larger budget continues the training; --score-every scores the model on the way (the
    // 0.05-minute model is the one trained above) and the curve lists both points.
    let (ok, stdout, err) = socdiff(&args(&["--resume", "--minutes", "0.1", "--score-every", "0.05"]));
    assert!(ok, "{err}");
    assert!(stdout.contains("quality vs training time"), "{stdout}");
    let q = json(&out.join("quality.json"));
    assert!(q["training"]["step"].as_u64().unwrap() > step);
    let curve = q["curve"].as_array().unwrap();
    assert_eq!(curve.len(), 2);
    assert_eq!(curve[0]["step"].as_u64().unwrap(), step);
    assert_eq!(json(&out.join("at-0.05min/quality.json"))["training"]["step"].as_u64().unwrap(), step);
    // A second run into the same folder without --resume is refused.
    let (ok, _, err) = socdiff(&args(&[]));
    assert!(!ok && err.contains("not empty"), "{err}");
    std::fs::remove_dir_all(&out).unwrap();
}

/// `socdiff bench sample` and `bench train` time one row per width (person count) and k3
/// algorithm, refuse an algorithm they do not know, and train to the same loss with either.
#[test]
fn bench_times_both_k3_algorithms() {
    let args = |k3: &str| -> Vec<String> {
        [
            "bench",
            "sample",
            "--hidden",
            "8",
            "--persons",
            "1,2",
            "--observe",
            "4",
            "--horizon",
            "12",
            "--steps",
            "1",
            "--no-forecast",
            "--threads",
            "1",
            "--k3-conv",
            k3,
        ]
        .map(String::from)
        .to_vec()
    };
    let (ok, stdout, err) = socdiff(&args("winograd,direct"));
    assert!(ok, "{err}");
    let mut gf = std::collections::HashMap::new();
    for p in [1, 2] {
        for k3 in ["winograd", "direct"] {
            let row = stdout.lines().find(|l| l.split_whitespace().take(3).eq(["8".to_string(), p.to_string(), k3.to_string()].iter().map(String::as_str)));
            let cols: Vec<&str> = row.unwrap_or_else(|| panic!("no row for {p} persons, {k3}: {stdout}")).split_whitespace().collect();
            let s_per_step: f64 = cols[3].parse().unwrap();
            // Three decimals: a step of this tiny net can print as 0.000.
            assert!((0.0..10.0).contains(&s_per_step), "{s_per_step}");
            // hidden persons k3 s/step min–max CPU peak "GB" GF/step GF/s
            gf.insert((p, k3), cols[8].parse::<f64>().unwrap());
        }
    }
    // The products counted: Winograd F(2, 3) runs fewer than one gemm per conv; a second
    // person doubles the per-person U-Net's (the aggregator's are few).
    for p in [1, 2] {
        assert!(gf[&(p, "winograd")] < gf[&(p, "direct")] && gf[&(p, "winograd")] > 0.0, "{gf:?}");
    }
    let ratio = gf[&(2, "direct")] / gf[&(1, "direct")];
    assert!((1.8..2.3).contains(&ratio), "{gf:?}");
    assert!(stdout.contains("f32 product roof of this machine:"), "{stdout}");
    let (ok, _, err) = socdiff(&args("fft"));
    assert!(!ok && err.contains("fft") && err.contains("winograd"), "{err}");
    // Training: both algorithms give the same seeded loss up to rounding.
    let train = [
        "bench",
        "train",
        "--hidden",
        "8",
        "--batch",
        "1",
        "--persons",
        "2",
        "--frames",
        "16",
        "--steps",
        "1",
        "--threads",
        "1",
        "--k3-conv",
        "winograd,direct",
    ];
    let (ok, stdout, err) = socdiff(&train);
    assert!(ok, "{err}");
    let loss = |k3: &str| -> f64 {
        let row = stdout.lines().find(|l| l.split_whitespace().nth(2) == Some(k3) && l.starts_with("     8"));
        row.unwrap_or_else(|| panic!("no {k3} row: {stdout}")).split_whitespace().last().unwrap().parse().unwrap()
    };
    let (w, d) = (loss("winograd"), loss("direct"));
    assert!(w.is_finite() && w > 0.0 && (w - d).abs() < 1e-4 * w, "winograd {w}, direct {d}");
}

#[test]
fn bench_mrt_prints_mrts_protocol_and_writes_its_numbers() {
    let Some(data) = shared("mupots3d") else { return };
    let out = tmp("bench-mrt");
    let (ok, table, err) = socdiff(&["bench", "mrt", "--data", data.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(ok, "{err}");
    // 209 windows of the nine three-person sequences; zero velocity 121/202/269 mm, which
    // tests/mrt_protocol.rs computes independently.
    assert!(table.contains("209 windows of 9 three-person sequences"), "{table}");
    let row = table.lines().find(|l| l.starts_with("zero velocity")).unwrap();
    let cells: Vec<&str> = row.split_whitespace().skip(2).collect();
    assert_eq!(&cells[..3], ["121", "202", "269"], "{row}");
    assert!(table.contains("as published"), "{table}");
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("mrt.json")).unwrap()).unwrap();
    assert_eq!(json["protocol"]["windows"], 209);
    assert_eq!(json["rows"][0]["method"], "zero velocity");
    // An --out that holds files is refused before any work.
    let (ok, _, err) = socdiff(&["bench", "mrt", "--data", data.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(!ok && err.contains("not empty"), "{err}");
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn bench_realtime_times_forecasts_and_scores_each_setting() {
    let Some(data) = shared("mupots3d") else { return };
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/groups-mrt15/model.safetensors");
    let out = tmp("bench-realtime");
    let args = |steps: &str| {
        let mut a: Vec<String> = ["bench", "realtime", "--model", model.to_str().unwrap(), "--data", data.to_str().unwrap()].map(String::from).to_vec();
        a.extend(["--steps", steps, "--repeats", "3", "--out", out.to_str().unwrap()].map(String::from));
        a
    };
    let (ok, table, err) = socdiff(&args("2,1"));
    assert!(ok, "{err}");
    assert!(table.contains("TS16: 3 persons, 30 observed + 90 forecast frames at 30 fps, K = 8"), "{table}");
    // A window every 15 frames of the five test scenes (501, 401, 126, 431 and 501 frames).
    assert!(table.contains("baselines on the same 93 test windows"), "{table}");
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("realtime.json")).unwrap()).unwrap();
    let rows = json["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    for (row, steps) in rows.iter().zip([2, 1]) {
        assert_eq!((row["steps"].as_u64(), row["calls"].as_u64()), (Some(steps), Some(steps)));
        let l = &row["latency"];
        assert_eq!(l["repeats"], 3);
        let (p50, p99) = (l["p50_ms"].as_f64().unwrap(), l["p99_ms"].as_f64().unwrap());
        assert!(p50 > 0.0 && p50 <= p99 && p99 <= l["max_ms"].as_f64().unwrap(), "{l}");
        let q = &row["quality"];
        assert_eq!(q["windows"], 93);
        assert!(q["mpjpe"][0]["mean"].as_f64().is_some_and(|v| v > 0.0 && v < 2.0), "{q}");
        assert!(q["ndms"].as_f64().is_some_and(|v| v > 0.0 && v <= 1.0), "{q}");
    }
    std::fs::remove_dir_all(&out).unwrap();
    // One window per scene, from its start.
    let mut one = args("1");
    one.extend(["--window-stride", "0"].map(String::from));
    let (ok, table, err) = socdiff(&one);
    assert!(ok && table.contains("baselines on the same 5 test windows"), "{err}{table}");
    std::fs::remove_dir_all(&out).unwrap();
    let (ok, _, err) = socdiff(&args("0"));
    assert!(!ok && err.contains("steps"), "{err}");
}
