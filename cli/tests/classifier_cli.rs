//! `socdiff classifier synth|train|eval|speech-stats` end to end on the real speech files and
//! MuPoTS motion (skipped, saying so, when `../shared/data` is absent), and bad input that must
//! fail with one error line and write nothing.

mod common;

use common::{assert_fails, shared, socdiff, tmp};
use std::path::PathBuf;

fn speech_files() -> Option<Vec<PathBuf>> {
    let dir = shared("haggling_speech")?;
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|e| e == "pkl")).collect();
    v.sort();
    Some(v)
}

fn s(p: &std::path::Path) -> String {
    p.display().to_string()
}

#[test]
fn speech_stats_of_the_real_files() {
    let Some(files) = speech_files() else { return };
    let mut args = vec!["classifier".to_string(), "speech-stats".into()];
    args.extend(files.iter().map(|p| s(p)));
    let (ok, out, err) = socdiff(&args);
    assert!(ok, "{err}");
    // Six files of 1833, 1820, 1781, 1816, 1799 and 1778 entries: Σ(n − 1) = 10821.
    assert!(out.contains("transitions   10821"), "{out}");
    for needle in [
        "170221_haggling_b1_group0        1833 frames",
        "P(next | current)",
        "pooled transition distribution",
        "    none       L       R      LR       b      Lb      Rb     LRb",
    ] {
        assert!(out.contains(needle), "missing {needle:?} in\n{out}");
    }
    // Every row of the transition matrix that is ever left sums to 1 (4 decimals printed).
    let matrix: Vec<Vec<f64>> = out
        .split("P(next | current), rows: current state\n")
        .nth(1)
        .unwrap()
        .lines()
        .skip(1)
        .take(8)
        .map(|l| l.split_whitespace().skip(1).map(|v| v.parse().unwrap()).collect())
        .collect();
    for row in &matrix {
        let sum: f64 = row.iter().sum();
        assert!(sum == 0.0 || (sum - 1.0).abs() < 5e-4, "{row:?}");
    }
}

/// Generate triads from the real speech files and MuPoTS motion, train tiny detectors, resume,
/// evaluate.
#[test]
fn synth_train_resume_eval() {
    let (Some(files), Some(mupots)) = (speech_files(), shared("mupots3d")) else { return };
    let (data, model) = (tmp("clf-data"), tmp("clf-model"));
    let mut args = vec!["classifier".to_string(), "synth".into()];
    args.extend(files.iter().map(|p| s(p)));
    args.extend(["--motion".into(), s(&mupots), "--out".into(), s(&data), "--segment".into(), "300".into(), "--test-files".into(), "1".into()]);
    let (ok, out, err) = socdiff(&args);
    assert!(ok, "{err}");
    // 5 train files and 1 test file of ~1800 frames, cut into 300-frame scenes.
    assert!(out.contains("30 train scenes") && out.contains("6 test scenes") && out.contains("not real recordings"), "{out}");

    let train = |steps: &str, extra: &[&str]| {
        let mut a = vec!["classifier", "train", "--data", data.to_str().unwrap(), "--out", model.to_str().unwrap(), "--steps", steps];
        a.extend_from_slice(extra);
        socdiff(&a)
    };
    let (ok, _, err) = train("4", &["--hidden", "8", "--window", "32", "--batch", "4", "--save-every", "2"]);
    assert!(ok, "{err}");
    assert!(err.contains("training the speaking and buyer detectors on 30 scenes") && err.contains("trained steps 0..4"), "{err}");
    // A second fresh run into the same directory is refused; resume continues.
    let (ok, _, err) = train("6", &["--hidden", "8"]);
    assert!(!ok && err.contains("already holds a classifier checkpoint"), "{err}");
    let (ok, _, err) = train("6", &["--resume", "--hidden", "8"]);
    assert!(!ok && err.contains("only --steps"), "{err}");
    let (ok, _, err) = train("6", &["--resume"]);
    assert!(ok && err.contains("resuming at step 4 of 6") && err.contains("trained steps 4..6"), "{err}");

    let (ok, out, err) = socdiff(&["classifier", "eval", "--model", model.to_str().unwrap(), "--data", data.to_str().unwrap(), "--per-scene"]);
    assert!(ok, "{err}");
    for needle in ["scenes        6 (", "accuracy      0.", "balanced acc  0.", "F1 0.", "buyer         "] {
        assert!(out.contains(needle), "missing {needle:?} in\n{out}");
    }
    assert_eq!(out.lines().filter(|l| l.starts_with("test_")).count(), 6, "{out}");
    // Evaluating on the train split works too; on a split the dataset lacks it fails.
    let (ok, _, err) = socdiff(&["classifier", "eval", "--model", model.to_str().unwrap(), "--data", data.to_str().unwrap(), "--split", "validation"]);
    assert!(!ok && err.contains("no validation sequences"), "{err}");

    // SSCP in `socdiff eval`: ground truth keeps its speech (distance 0 to itself); the
    // zero-velocity forecasts carry none and are classified; without classifiers they are skipped.
    let report = tmp("clf-eval");
    let eval = |extra: &[&str]| {
        std::fs::remove_dir_all(&report).ok();
        let mut a = vec![
            "eval",
            "--reference",
            data.to_str().unwrap(),
            "--baselines",
            "zero-velocity,ground-truth",
            "--metrics",
            "sscp",
            "--observe",
            "60",
            "--out",
            report.to_str().unwrap(),
        ];
        a.extend_from_slice(extra);
        let (ok, _, err) = socdiff(&a);
        assert!(ok, "{err}");
        let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(report.join("report.json")).unwrap()).unwrap();
        json
    };
    let sscp = |json: &serde_json::Value, label: &str| json["methods"].as_array().unwrap().iter().find(|m| m["label"] == label).unwrap()["sscp"].clone();
    let with = eval(&["--classifiers", model.to_str().unwrap()]);
    assert_eq!(sscp(&with, "ground-truth")["value"].as_f64(), Some(0.0), "{with}");
    let zv = sscp(&with, "zero-velocity")["value"].as_f64().unwrap();
    assert!(zv > 0.0 && zv <= std::f64::consts::LN_2.sqrt() + 1e-9, "{zv}");
    assert!(with.to_string().contains("otherwise classifiers"), "{with}");
    let without = eval(&[]);
    assert!(sscp(&without, "zero-velocity")["skipped"].as_str().unwrap().contains("speaking"), "{without}");
    assert_eq!(sscp(&without, "ground-truth")["value"].as_f64(), Some(0.0));
    std::fs::remove_dir_all(&report).ok();
    for d in [data, model] {
        std::fs::remove_dir_all(d).ok();
    }
}

#[test]
fn bad_input_fails_with_one_line_and_writes_nothing() {
    let base = tmp("clf-bad");
    std::fs::create_dir_all(&base).unwrap();
    let out = base.join("out");
    let missing = base.join("missing");
    let o = s(&out);
    let m = s(&missing);
    assert_fails(&["classifier", "train", "--data", &m, "--out", &o], &[&m], &out);
    assert_fails(&["classifier", "eval", "--model", &m, "--data", &m], &["classifier.json"], &out);
    assert_fails(&["classifier", "speech-stats", &m], &[&m], &out);
    let not_speech = base.join("bad.pkl");
    std::fs::write(&not_speech, b"not a pickle").unwrap();
    assert_fails(&["classifier", "speech-stats", &s(&not_speech)], &["bad.pkl"], &out);
    assert_fails(&["classifier", "synth", &s(&not_speech), "--motion", &m, "--out", &o, "--test-files", "1"], &["--test-files 1"], &out);
    assert_fails(&["classifier", "synth", &s(&not_speech), &s(&not_speech), "--motion", &m, "--out", &o, "--test-files", "1"], &["bad.pkl"], &out);
    // A dataset without speaking signals: training names the scene and the signal.
    let (ok, _, err) = socdiff(&["data", "convert", common::cmu_clip().to_str().unwrap(), "--out", base.join("cmu").to_str().unwrap()]);
    assert!(ok, "{err}");
    assert_fails(&["classifier", "train", "--data", base.join("cmu").to_str().unwrap(), "--out", &o], &["speaking"], &out);
    if let Some(files) = speech_files() {
        // A speech file is no training data (it holds no poses).
        assert_fails(&["classifier", "train", "--data", &s(&files[0]), "--out", &o], &[files[0].file_name().unwrap().to_str().unwrap()], &out);
    }
    std::fs::remove_dir_all(&base).ok();
}
