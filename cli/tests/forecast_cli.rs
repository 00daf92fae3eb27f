//! `socdiff forecast` / `socdiff complete` end to end with a tiny model trained for 2 steps:
//! the output dataset (observed part + samples, provenance), reproducibility by seed, and the
//! error cases (one line, exit ≠ 0, nothing written).

use ndarray::Array4;
use socdiff_engine::data::dataset::{read_dataset, write_dataset, ReadOptions, Sequence};
use socdiff_engine::export::ForecastInfo;
use socdiff_engine::{Dataset, Scene, Skeleton, Split};
mod common;

use common::{assert_fails, socdiff, tmp};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

fn skeleton(joints: usize) -> Skeleton {
    let names: Vec<String> = ["l", "r", "head", "hand"].iter().take(joints).map(|s| s.to_string()).collect();
    let bones = (2..joints).map(|j| (0, j)).collect();
    Skeleton::new(format!("tiny{joints}"), names, bones, 0, 1).unwrap()
}

/// Persons walking on circles; hips 0.2 m apart.
fn scene(name: &str, frames: usize, persons: usize, joints: usize) -> Scene {
    let pos = Array4::from_shape_fn((frames, persons, joints, 3), |(f, p, j, k)| {
        let h = 0.02 * f as f64 + p as f64;
        let (x, y) = (p as f64 + 0.01 * f as f64 * h.cos(), 0.5 * p as f64 + 0.01 * f as f64 * h.sin());
        let off = [-0.1, 0.1, 0.0, 0.05][j];
        match k {
            0 => (x + off * h.cos()) as f32,
            1 => (y + off * h.sin()) as f32,
            _ => [0.9, 0.9, 1.7, 1.2][j] + 0.01 * (f as f32 * 0.3).sin(),
        }
    });
    Scene::new(name, 30.0, skeleton(joints), pos).unwrap()
}

fn write(dir: &Path, seqs: Vec<(Split, Scene)>) {
    let ds = Dataset { name: "d".into(), sequences: seqs.into_iter().map(|(split, scene)| Sequence { split, scene }).collect(), metadata: Default::default() };
    write_dataset(&ds, dir).unwrap();
}

/// (data dir, model run dir), trained once per test binary.
fn fixture() -> &'static (PathBuf, PathBuf) {
    static F: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    F.get_or_init(|| {
        let root = tmp("fixture");
        std::fs::create_dir_all(&root).unwrap();
        let data = root.join("data");
        write(&data, vec![(Split::Train, scene("a", 40, 3, 3)), (Split::Test, scene("b", 30, 3, 3))]);
        let cfg = root.join("cfg.json");
        std::fs::write(
            &cfg,
            r#"{"model": {"hidden": 16, "time_dim": 16, "fourier_dim": 8, "social_dim": 16}, "batch": 2, "window": 16, "stride": 8, "val_every": 0}"#,
        )
        .unwrap();
        let run = root.join("run");
        let (ok, _, err) = socdiff(&[
            "train",
            "--preset",
            "paper",
            "--data",
            data.to_str().unwrap(),
            "--out",
            run.to_str().unwrap(),
            "--config",
            cfg.to_str().unwrap(),
            "--steps",
            "2",
        ]);
        assert!(ok, "train: {err}");
        (data, run)
    })
}

fn read(dir: &Path) -> Dataset {
    read_dataset(dir, &ReadOptions { align_ground: Some(false) }).unwrap()
}

#[test]
fn forecast_writes_observed_part_and_samples_reproducibly() {
    let (data, run) = fixture();
    let out = tmp("ok");
    let args = |o: &Path, seed: &str, k: &str| {
        socdiff(&[
            "forecast",
            "--model",
            run.to_str().unwrap(),
            "--input",
            data.to_str().unwrap(),
            "--sequence",
            "b",
            "--observe",
            "8",
            "--horizon",
            "20",
            "--samples",
            k,
            "--sampler",
            "ddim",
            "--steps",
            "3",
            "--eta",
            "0.5",
            "--seed",
            seed,
            "--out",
            o.to_str().unwrap(),
        ])
    };
    let (ok, stdout, err) = args(&out, "1", "2");
    assert!(ok, "{err}");
    assert!(stdout.contains("s per step"), "{stdout}");
    let ds = read(&out);
    // The observed part, the recorded future (b has 30 ≥ 8 + 20 frames), 2 samples.
    assert_eq!(ds.sequences.len(), 4);
    let input = &ds.sequences[0].scene;
    let src = read(data);
    let b = src.scene("b").unwrap();
    assert_eq!(input.positions, b.positions.slice(ndarray::s![..8, .., .., ..]));
    let gt = ForecastInfo::from_scene(&ds.sequences[1].scene).unwrap().unwrap();
    assert_eq!(gt, ForecastInfo { observed_frames: 8, sample: None, source: "b".into() });
    assert_eq!(ds.sequences[1].scene.positions, b.positions.slice(ndarray::s![..28, .., .., ..]));
    for (k, s) in ds.sequences[2..].iter().enumerate() {
        let info = ForecastInfo::from_scene(&s.scene).unwrap().unwrap();
        assert_eq!(info, ForecastInfo { observed_frames: 8, sample: Some(k), source: "b".into() });
        assert_eq!(s.scene.num_frames(), 28);
        assert_eq!(s.scene.positions.slice(ndarray::s![..8, .., .., ..]), input.positions);
    }
    let prov = &ds.metadata["forecast"];
    assert_eq!(prov["seed"], 1);
    assert_eq!(prov["sampler"]["kind"], "ddim");
    assert_eq!(prov["steps"], 3);
    assert!(prov["model"].as_str().unwrap().contains("run"));
    assert!(prov["timings"]["seconds_per_step"].as_f64().unwrap() > 0.0);
    assert_eq!(prov["weights"], "ema");
    // Same seed → same samples; sample 0 is the same with K = 1.
    let again = tmp("again");
    assert!(args(&again, "1", "1").0);
    assert_eq!(read(&again).sequences[2].scene.positions, ds.sequences[2].scene.positions);
    // Completion of missing frames through the same path.
    let comp = tmp("complete");
    let (ok, _, err) = socdiff(&[
        "complete",
        "--model",
        run.to_str().unwrap(),
        "--input",
        data.to_str().unwrap(),
        "--sequence",
        "b",
        "--missing",
        "frames=10..20",
        "--samples",
        "1",
        "--steps",
        "2",
        "--out",
        comp.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let c = read(&comp);
    // A short forecast of b with `extra` options into `o`.
    let short = |extra: &[&str], o: &Path| {
        let (m, d, o) = (run.to_str().unwrap(), data.to_str().unwrap(), o.to_str().unwrap());
        let mut a =
            vec!["forecast", "--model", m, "--input", d, "--sequence", "b", "--observe", "8", "--horizon", "4", "--samples", "1", "--steps", "2", "--out", o];
        a.extend_from_slice(extra);
        socdiff(&a)
    };
    // The optimizer's weights instead of the moving average, recorded in the provenance.
    let online = tmp("online");
    let (ok, _, err) = short(&["--weights", "online"], &online);
    assert!(ok, "{err}");
    assert_eq!(read(&online).metadata["forecast"]["weights"], "online");
    let _ = std::fs::remove_dir_all(&online);
    // Context inversion of the observed frames, recorded in the provenance.
    let (ok, _, err) = short(&["--invert-context", "2"], &online);
    assert!(ok, "{err}");
    let inv = &read(&online).metadata["forecast"]["context_inversion"];
    assert_eq!((inv["steps"].as_u64(), inv["frames"].as_u64()), (Some(2), Some(8)), "{inv}");
    assert_eq!(read(&online).sequences[0].scene.positions, input.positions);
    let _ = std::fs::remove_dir_all(&online);
    assert_eq!(c.sequences[1].scene.positions.slice(ndarray::s![..10, .., .., ..]), b.positions.slice(ndarray::s![..10, .., .., ..]));
    for d in [out, again, comp] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn forecast_errors_are_one_line_and_write_nothing() {
    let (data, run) = fixture();
    let dir = tmp("errors");
    std::fs::create_dir_all(&dir).unwrap();
    let other = dir.join("other");
    write(&other, vec![(Split::Test, scene("four", 30, 2, 4))]);
    let out = dir.join("out");
    let (m, d, o) = (run.to_str().unwrap(), data.to_str().unwrap(), other.to_str().unwrap());
    let cases: Vec<(Vec<&str>, Vec<&str>)> = vec![
        (vec!["forecast", "--model", m, "--input", d, "--sequence", "b", "--observe", "31", "--horizon", "5"], vec!["--observe 31", "30 frames"]),
        (vec!["forecast", "--model", m, "--input", d, "--sequence", "b", "--observe", "8", "--horizon", "0"], vec!["--horizon"]),
        (
            vec!["forecast", "--model", m, "--input", d, "--sequence", "b", "--observe", "8", "--horizon", "4", "--invert-context", "3", "--invert-lr", "0"],
            vec!["--invert-lr"],
        ),
        (
            vec!["forecast", "--model", m, "--input", d, "--sequence", "b", "--persons", "0,5", "--observe", "8", "--horizon", "4"],
            vec!["person 5", "out of range"],
        ),
        (vec!["forecast", "--model", m, "--input", o, "--observe", "8", "--horizon", "4"], vec!["skeleton", "4 joints"]),
        (vec!["forecast", "--model", m, "--input", d, "--observe", "8", "--horizon", "4"], vec!["--sequence", "a, b"]),
        (vec!["complete", "--model", m, "--input", d, "--sequence", "b", "--missing", "persons=3"], vec!["person 3", "out of range"]),
        (vec!["complete", "--model", m, "--input", d, "--sequence", "b", "--missing", "legs=1"], vec!["--missing"]),
    ];
    for (mut args, names) in cases {
        args.extend(["--samples", "1", "--steps", "2", "--out", out.to_str().unwrap()]);
        assert_fails(&args, &names, &out);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `socdiff generate`: K scenes of N frames from noise, persons on a circle or placed as in a
/// layout scene (its frame 0 root and heading, at the model's anchor frame or at
/// --placement-frame), reproducible by seed, viewable; bad input fails in one line and writes
/// nothing.
#[test]
fn generate_writes_whole_scenes_from_noise() {
    let (data, run) = fixture();
    let (out, again) = (tmp("gen"), tmp("gen-again"));
    let gen = |o: &Path, extra: &[&str]| {
        let mut a = vec!["generate", "--model", run.to_str().unwrap(), "--frames", "24", "--samples", "2", "--steps", "3", "--out", o.to_str().unwrap()];
        a.extend_from_slice(extra);
        socdiff(&a)
    };
    let (ok, stdout, err) = gen(&out, &["--persons", "4"]);
    assert!(ok, "{err}");
    assert!(stdout.contains("2 scenes of 24 frames, 4 persons"), "{stdout}");
    let ds = read(&out);
    let samples: Vec<&Scene> =
        ds.sequences.iter().map(|s| &s.scene).filter(|s| ForecastInfo::from_scene(s).unwrap().is_some_and(|i| i.sample.is_some())).collect();
    assert_eq!(samples.len(), 2);
    assert!(samples.iter().all(|s| s.num_frames() == 24 && s.num_persons() == 4 && s.positions.iter().all(|v| v.is_finite())));
    assert_eq!(ds.metadata["forecast"]["task"]["kind"], "generate", "{:?}", ds.metadata);
    let (ok, _, err) = gen(&again, &["--persons", "4"]);
    assert!(ok, "{err}");
    let twice = read(&again);
    assert_eq!(
        twice.sequences.iter().map(|s| s.scene.positions.clone()).collect::<Vec<_>>(),
        ds.sequences.iter().map(|s| s.scene.positions.clone()).collect::<Vec<_>>()
    );
    // The placement sits at the model's anchor frame (training observed − 1), recorded.
    let anchor = ds.metadata["forecast"]["task"]["anchor"].as_u64().unwrap() as usize;
    assert_eq!(ds.metadata["forecast"]["anchor_frame"].as_u64(), Some(anchor as u64));
    assert!(anchor > 0 && anchor < 24, "anchor frame {anchor}");
    // A layout: the persons of test scene b, placed as at its frame 0, at the anchor frame or
    // at the one --placement-frame names (the placement's 4 root dims per person known there;
    // that the decoded pose lands on it is the engine's generation test, with a model that
    // predicts the layout, since this 2-step model's local hips are not yet centred).
    let laid = tmp("gen-layout");
    for (extra, at) in [(&[][..], anchor), (&["--placement-frame", "0"][..], 0)] {
        let _ = std::fs::remove_dir_all(&laid);
        let mut a = vec!["--layout", data.to_str().unwrap(), "--sequence", "b"];
        a.extend_from_slice(extra);
        let (ok, stdout, err) = gen(&laid, &a);
        assert!(ok, "{err}");
        assert!(stdout.contains("3 persons"), "{stdout}");
        let got = read(&laid);
        let f = &got.metadata["forecast"];
        assert_eq!(
            (f["anchor_frame"].as_u64(), f["task"]["anchor"].as_u64(), f["mask"]["known_entries"].as_u64()),
            (Some(at as u64), Some(at as u64), Some(12))
        );
    }
    let page = tmp("gen-view.html");
    let (ok, _, err) = socdiff(&["view", out.to_str().unwrap(), "--out", page.to_str().unwrap()]);
    assert!(ok, "view: {err}");
    // In a folder of its own: the check for left-over temporary files must not see other
    // tests' atomic writes in the shared temp folder.
    let never = tmp("gen-never-dir").join("never");
    std::fs::create_dir_all(never.parent().unwrap()).unwrap();
    for (extra, msg) in [
        (&["--frames", "1"][..], "at least 2"),
        (&["--samples", "0"][..], "--samples"),
        (&["--persons", "0"][..], "at least one person"),
        (&["--placement-frame", "24"][..], "must be one of them"),
    ] {
        let mut a = vec!["generate", "--model", run.to_str().unwrap(), "--steps", "2", "--out", never.to_str().unwrap()];
        if extra[0] != "--frames" {
            a.extend_from_slice(&["--frames", "24"]);
        }
        a.extend_from_slice(extra);
        assert_fails(&a, &[msg], &never);
    }
    for d in [out, again, laid] {
        std::fs::remove_dir_all(d).unwrap();
    }
    let _ = std::fs::remove_file(page);
}

/// `generate --guide` (autoguidance): a guide identical to the model changes nothing, bit for
/// bit (x̂0_weak + w·0); a guide trained fewer steps on the same data changes the samples and is
/// recorded; a guide of other data, a weight below 1 and a level past T fail in one line.
#[test]
fn generate_with_a_guide() {
    let (data, run) = fixture();
    let root = tmp("guide");
    std::fs::create_dir_all(&root).unwrap();
    let cfg = root.join("cfg.json");
    std::fs::write(
        &cfg,
        r#"{"model": {"hidden": 16, "time_dim": 16, "fourier_dim": 8, "social_dim": 16}, "batch": 2, "window": 16, "stride": 8, "val_every": 0}"#,
    )
    .unwrap();
    let train = |data: &Path, out: &Path, steps: &str| {
        let (ok, _, err) = socdiff(&[
            "train",
            "--preset",
            "paper",
            "--data",
            data.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--config",
            cfg.to_str().unwrap(),
            "--steps",
            steps,
        ]);
        assert!(ok, "train: {err}");
    };
    let (shorter, other_data, other) = (root.join("shorter"), root.join("other-data"), root.join("other"));
    train(data, &shorter, "1");
    write(&other_data, vec![(Split::Train, scene("c", 60, 2, 3)), (Split::Test, scene("d", 30, 2, 3))]);
    train(&other_data, &other, "1");
    let gen = |name: &str, extra: &[&str]| {
        let o = root.join(name);
        let mut a = vec![
            "generate",
            "--model",
            run.to_str().unwrap(),
            "--frames",
            "24",
            "--samples",
            "2",
            "--steps",
            "3",
            "--persons",
            "2",
            "--out",
            o.to_str().unwrap(),
        ];
        a.extend_from_slice(extra);
        let (ok, _, err) = socdiff(&a);
        assert!(ok, "{err}");
        read(&o)
    };
    let positions = |d: &Dataset| d.sequences.iter().map(|s| s.scene.positions.clone()).collect::<Vec<_>>();
    let plain = gen("plain", &[]);
    let itself = gen("itself", &["--guide", run.to_str().unwrap(), "--guidance", "3"]);
    assert_eq!(positions(&itself), positions(&plain));
    let guided = gen("guided", &["--guide", shorter.to_str().unwrap(), "--guidance", "3", "--guide-from", "100"]);
    assert_ne!(positions(&guided), positions(&plain));
    assert!(guided.sequences.iter().all(|s| s.scene.positions.iter().all(|v| v.is_finite())));
    let g = &guided.metadata["forecast"]["guide"];
    assert_eq!((g["weight"].as_f64(), g["from_level"].as_u64(), g["model_step"].as_u64()), (Some(3.0), Some(100), Some(1)), "{g}");
    assert!(g["model"].as_str().unwrap().contains("shorter"), "{g}");
    assert!(plain.metadata["forecast"].get("guide").is_none());
    let never = root.join("never-dir").join("never");
    std::fs::create_dir_all(never.parent().unwrap()).unwrap();
    for (guide, extra, msg) in [
        (&other, &[][..], "standardization"),
        (&shorter, &["--guidance", "0.5"][..], "guidance weight"),
        (&shorter, &["--guide-from", "1000"][..], "noise level 1000"),
    ] {
        let mut a = vec![
            "generate",
            "--model",
            run.to_str().unwrap(),
            "--frames",
            "24",
            "--steps",
            "2",
            "--guide",
            guide.to_str().unwrap(),
            "--out",
            never.to_str().unwrap(),
        ];
        a.extend_from_slice(extra);
        assert_fails(&a, &[msg], &never);
    }
    std::fs::remove_dir_all(root).unwrap();
}

/// `socdiff interpolate`: S motions between two scenes (endpoint errors in the metadata), an
/// in-betweening with --transition (the two motions kept, F frames generated between), and bad
/// input (S < 2, more frames than the scenes, other person counts) in one line with nothing
/// written.
#[test]
fn interpolate_between_two_motions() {
    let (data, run) = fixture();
    let d = data.to_str().unwrap();
    let base = |o: &Path| {
        vec![
            "interpolate",
            "--model",
            run.to_str().unwrap(),
            "--from",
            d,
            "--from-sequence",
            "a",
            "--to",
            d,
            "--to-sequence",
            "b",
            "--ddim-steps",
            "4",
            "--out",
            o.to_str().unwrap(),
        ]
        .into_iter()
        .map(String::from)
        .collect::<Vec<_>>()
    };
    let out = tmp("interp");
    let mut a = base(&out);
    a.extend(["--steps", "3"].map(String::from));
    let (ok, stdout, err) = socdiff(&a);
    assert!(ok, "{err}");
    assert!(stdout.contains("3 motions from a to b"), "{stdout}");
    let ds = read(&out);
    assert_eq!(ds.sequences.len(), 3);
    assert!(ds.sequences.iter().all(|s| s.scene.num_frames() == 30 && s.scene.num_persons() == 3 && s.scene.positions.iter().all(|v| v.is_finite())));
    let e = ds.metadata["interpolation"]["endpoint_error_m"].as_array().unwrap();
    assert!(e.iter().all(|v| v.as_f64().is_some_and(|v| v.is_finite() && v >= 0.0)), "{e:?}");
    assert_eq!(ds.metadata["interpolation"]["inversion_refine"], 0);
    assert_eq!(ds.metadata["interpolation"]["inversion_depth"], 999); // T − 1: pure noise
    assert!(stdout.contains("inverted to noise level 999"), "{stdout}");
    // Inverted part of the way: recorded, and the motions are still finite scenes.
    let shallow = tmp("interp-shallow");
    let mut a = base(&shallow);
    a.extend(["--steps", "3", "--invert-to", "40"].map(String::from));
    let (ok, stdout, err) = socdiff(&a);
    assert!(ok, "{err}");
    assert!(stdout.contains("inverted to noise level 40"), "{stdout}");
    let sh = read(&shallow);
    assert_eq!(sh.metadata["interpolation"]["inversion_depth"], 40);
    assert!(sh.sequences.len() == 3 && sh.sequences.iter().all(|s| s.scene.positions.iter().all(|v| v.is_finite())));
    // A refined inversion records its iterations and residuals, and an endpoint whose plain
    // inversion denoises closer keeps it: the same endpoint error as the plain run (this
    // two-step model's predictions barely depend on their input; the engine's sample tests
    // measure the refinement on a model that can be inverted).
    let refined = tmp("interp-refined");
    let mut a = base(&refined);
    a.extend(["--steps", "2", "--refine-inversion", "8"].map(String::from));
    let (ok, stdout, err) = socdiff(&a);
    assert!(ok, "{err}");
    assert!(stdout.contains("8 fixed-point iterations per inversion step"), "{stdout}");
    let info = &read(&refined).metadata["interpolation"];
    assert_eq!(info["inversion_refine"], 8);
    assert!(info["inversion_refined_kept"].as_array().is_some_and(|k| k.len() == 2 && k.iter().all(|v| v.is_boolean())), "{info}");
    let residual: Vec<f64> = info["inversion_residual"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert!(residual.len() == 2 && residual.iter().all(|r| r.is_finite() && *r > 0.0), "{residual:?}");
    for (i, kept) in info["inversion_refined_kept"].as_array().unwrap().iter().enumerate() {
        if kept == false {
            assert_eq!(info["endpoint_error_m"][i], e[i], "endpoint {i}");
        }
    }
    let tr = tmp("interp-transition");
    let mut a = base(&tr);
    a.extend(["--transition", "5"].map(String::from));
    let (ok, _, err) = socdiff(&a);
    assert!(ok, "{err}");
    let ds = read(&tr);
    let s = ds.sequences.iter().map(|s| &s.scene).find(|s| ForecastInfo::from_scene(s).unwrap().is_some_and(|i| i.sample.is_some())).unwrap();
    let (sa, sb) = (scene("a", 40, 3, 3), scene("b", 30, 3, 3));
    assert_eq!(s.num_frames(), 75);
    let close = |x: ndarray::ArrayView4<f32>, y: ndarray::ArrayView4<f32>| x.iter().zip(y.iter()).all(|(p, q)| (p - q).abs() < 1e-4);
    assert!(close(s.positions.slice(ndarray::s![..40, .., .., ..]), sa.positions.view()));
    assert!(close(s.positions.slice(ndarray::s![45.., .., .., ..]), sb.positions.view()));
    // In a folder of its own: the check for left-over temporary files must not see other
    // tests' atomic writes in the shared temp folder.
    let never = tmp("interp-never-dir").join("never");
    std::fs::create_dir_all(never.parent().unwrap()).unwrap();
    for (extra, msg) in [
        (&["--steps", "1"][..], "at least 2"),
        (&["--frames", "35"][..], "frames ≤ 30"),
        (&["--invert-to", "0"][..], "noise level 0: need 1 ≤ level ≤ 999"),
        (&["--invert-to", "1000"][..], "noise level 1000"),
        (&["--invert-to", "2"][..], "4 DDIM steps up to noise level 2: at most 3 steps"),
    ] {
        let mut a = base(&never);
        a.extend(extra.iter().map(|s| s.to_string()));
        assert_fails(&a, &[msg], &never);
    }
    let two = tmp("interp-two");
    write(&two, vec![(Split::Test, scene("c", 30, 2, 3))]);
    let mut a = base(&never);
    let i = a.iter().position(|x| x == "--to").unwrap();
    a[i + 1] = two.to_str().unwrap().into();
    a[i + 3] = "c".into();
    assert_fails(&a, &["3 and 2 persons"], &never);
    for dir in [out, shallow, refined, tr, two] {
        std::fs::remove_dir_all(dir).unwrap();
    }
}

/// `--split test` forecasts every test scene into one folder that `eval` reads as one method;
/// the horizon stops where each recording does (saying so) unless `--past-end`.
#[test]
fn a_whole_split_is_forecast_into_one_folder_and_stops_at_the_recording() {
    let (data, run) = fixture();
    let (d, m) = (data.to_str().unwrap(), run.to_str().unwrap());
    // `forecast --split test` of 8 observed + 40 forecast frames into `out`, then `extra`.
    let split = |out: &Path, extra: &[&str]| {
        let mut args = vec!["forecast", "--model", m, "--input", d, "--split", "test", "--observe", "8", "--horizon", "40", "--samples", "1", "--steps", "2"];
        args.extend_from_slice(extra);
        args.extend(["--out", out.to_str().unwrap()]);
        args.iter().map(|a| a.to_string()).collect::<Vec<String>>()
    };
    let fc = tmp("split");
    let (ok, _, err) = socdiff(&split(&fc, &[]));
    assert!(ok, "{err}");
    // b has 30 frames: 22 forecast frames are recorded.
    assert!(err.contains("b: the recording ends 22 frames after the 8 observed: forecasting 22 frames, not 40"), "{err}");
    let b = read(&fc.join("b"));
    assert_eq!(b.sequences.last().unwrap().scene.num_frames(), 30);
    assert!(!fc.join("a").exists(), "only the test split");
    let rep = tmp("split-eval");
    let method = format!("m={}", fc.display());
    let (ok, _, err) =
        socdiff(&["eval", "--reference", d, "--split", "test", "--observe", "8", "--forecasts", &method, "--metrics", "mpjpe", "--out", rep.to_str().unwrap()]);
    assert!(ok, "eval reads the folder as one method: {err}");
    // Past the end when asked.
    let past = tmp("split-past");
    let (ok, _, err) = socdiff(&split(&past, &["--past-end"]));
    assert!(ok && !err.contains("the recording ends"), "{err}");
    assert_eq!(read(&past.join("b")).sequences.last().unwrap().scene.num_frames(), 48);
    // A split with no scene, and --split with --sequence, are errors.
    let none = tmp("split-none").join("out");
    let mut args = split(&none, &[]);
    args[6] = "validation".into();
    assert_fails(&args, &["no scene in the validation split"], &none);
    assert_fails(&split(&none, &["--sequence", "b"]), &["--sequence"], &none);
}

#[test]
fn a_stream_of_json_frames_gets_a_forecast_per_frame() {
    use std::io::Write;
    let Some(mupots) = common::shared("mupots3d") else { return };
    let model_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/groups-mrt15/model.safetensors");
    let model = socdiff_engine::checkpoint::Checkpoint::load(&model_path).unwrap();
    let data = socdiff_engine::data::import::load(&mupots, &Default::default()).unwrap();
    let scene = model.fit_scene(data.scene("TS16").unwrap(), true).unwrap().0;
    let frame_line = |f: usize, time: f64| {
        let persons: Vec<Vec<[f32; 3]>> = (0..3).map(|p| (0..15).map(|j| std::array::from_fn(|k| scene.positions[[f, p, j, k]])).collect()).collect();
        serde_json::json!({"time": time, "positions": persons}).to_string()
    };
    // 12 frames at 30 fps; frame 6 has 14 joints (an error line), then the stream goes on.
    let mut lines: Vec<String> = (0..12).map(|f| frame_line(f, f as f64 / 30.0)).collect();
    let short = |n: usize| vec![[0.0f32, 0.0, 1.0]; n];
    lines[6] = serde_json::json!({"time": 0.2, "positions": [short(14), short(15), short(15)]}).to_string();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_socdiff"))
        .args(["forecast", "--model", model_path.to_str().unwrap(), "--stream", "json", "--input", "-", "--out", "-"])
        .args(["--observe", "4", "--horizon", "5", "--samples", "2", "--steps", "1"])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    child.stdin.take().unwrap().write_all((lines.join("\n") + "\n").as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let replies: Vec<serde_json::Value> = String::from_utf8(out.stdout).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    // Frames 3, 4, 5 forecast; frame 6 is refused, so frame 7 comes after a gap and starts the
    // window again: 10 and 11 forecast.
    let frames: Vec<u64> = replies.iter().map(|r| r["frame"].as_u64().unwrap()).collect();
    assert_eq!(frames, [3, 4, 5, 6, 10, 11]);
    assert!(replies[3]["error"].as_str().unwrap().contains("14 joints, expected 3 of 15"), "{}", replies[3]);
    assert_eq!(replies[3]["frame"], 6);
    assert!(replies.iter().filter(|r| r.get("samples").is_some()).count() == 5);
    let first = &replies[0]["samples"];
    assert_eq!((first.as_array().unwrap().len(), first[0].as_array().unwrap().len(), first[0][0].as_array().unwrap().len()), (2, 5, 3));

    // Raw float32 frames: the same scene, frames 3 and 4 forecast; without the person count,
    // one error.
    let raw: Vec<u8> = scene.positions.slice(ndarray::s![..5, .., .., ..]).iter().flat_map(|v| v.to_le_bytes()).collect();
    let run = |extra: &[&str]| {
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_socdiff"))
            .args(["forecast", "--model", model_path.to_str().unwrap(), "--stream", "f32", "--input", "-", "--out", "-"])
            .args(["--observe", "4", "--horizon", "5", "--samples", "1", "--steps", "1"])
            .args(extra)
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let _ = child.stdin.take().unwrap().write_all(&raw);
        child.wait_with_output().unwrap()
    };
    let out = run(&["--stream-persons", "3"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let frames: Vec<u64> =
        String::from_utf8(out.stdout).unwrap().lines().map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["frame"].as_u64().unwrap()).collect();
    assert_eq!(frames, [3, 4]);
    for (extra, says) in [
        (&[][..], "--stream-persons"),
        (&["--stream-persons", "100000000"][..], "persons"),
        (&["--stream-persons", "3", "--sequence", "TS16"][..], "--sequence"),
    ] {
        let out = run(extra);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(says) && out.stdout.is_empty(), "{extra:?}: {err}");
    }
}

/// `socdiff distill` makes a student in rounds (3 → 2 → 1 calls) that `forecast` takes as any
/// model and samples with its own calls; a second run refuses the used --out unless --resume,
/// which finds every round done; bad options are one error that writes nothing.
#[test]
fn distill_makes_a_student_that_forecasts_with_its_own_steps() {
    let (data, run) = fixture();
    let student = tmp("student");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let distill = |extra: &[&str]| {
        let mut a = vec!["distill".to_string(), "--teacher".into(), s(run), "--data".into(), s(data), "--out".into(), s(&student)];
        a.extend(["--steps", "1", "--teacher-steps", "3", "--round-steps", "3"].iter().map(|v| v.to_string()));
        a.extend(extra.iter().map(|v| v.to_string()));
        socdiff(&a)
    };
    let (ok, stdout, err) = distill(&[]);
    assert!(ok, "{err}");
    assert!(stdout.contains("student (1 calls)"), "{stdout}");
    assert!(err.contains("round 1 of 2: 3 → 2 calls") && err.contains("round 2 of 2: 2 → 1 calls"), "{err}");
    assert!(student.join("rounds/calls-2/model.safetensors").is_file() && student.join("model.safetensors").is_file());
    let (ok, _, err) = distill(&[]);
    assert!(!ok && err.contains("resume"), "{err}");
    let (ok, _, err) = distill(&["--resume"]);
    assert!(ok && err.matches("is done").count() == 2, "{err}");

    let out = tmp("student-forecast");
    let (ok, _, err) = socdiff(&[
        "forecast",
        "--model",
        &s(&student),
        "--input",
        &s(data),
        "--sequence",
        "b",
        "--observe",
        "8",
        "--horizon",
        "20",
        "--samples",
        "2",
        "--out",
        &s(&out),
    ]);
    assert!(ok, "{err}");
    let prov = &read(&out).metadata["forecast"];
    assert_eq!((prov["sampler"]["kind"].as_str(), prov["steps"].as_u64()), (Some("ddim"), Some(1)), "{prov}");

    let bad = tmp("student-bad");
    let o = s(&bad);
    for (flags, names) in [
        (vec!["--steps", "4"], vec!["1, 2, 3, 5 or 9"]),
        (vec!["--steps", "2", "--teacher-steps", "6"], vec!["one of 3, 5, 9"]),
        (vec!["--round-steps", "0"], vec!["round"]),
    ] {
        let mut a = vec!["distill", "--teacher", run.to_str().unwrap(), "--data", data.to_str().unwrap(), "--out", &o];
        a.extend(flags);
        assert_fails(&a, &names, &bad);
    }
    let mut a = vec!["distill", "--teacher", student.to_str().unwrap(), "--data", data.to_str().unwrap(), "--out", &o];
    a.extend(["--steps", "1", "--teacher-steps", "2"]);
    assert_fails(&a, &["already a distilled student"], &bad);
}
