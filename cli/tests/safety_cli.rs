//! Nothing lost, nothing silent: each case found by trying socdiff as a user would (outputs
//! that destroyed inputs, checkpoints broken by interrupts, two writers in one run directory,
//! skeletons that do not fit, oversize arguments, corrupt or absurd input, a dataset that is
//! not MuPoTS-shaped), reproduced as it was found and shown fixed.

mod common;

use common::{assert_fails, cmu_clip, socdiff, tmp};
use socdiff_engine::checkpoint::{Checkpoint, TENSORS_FILE};
use socdiff_engine::data::dataset::{read_dataset, write_dataset, ReadOptions, Sequence};
use socdiff_engine::{Dataset, Skeleton};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_socdiff");

/// The generated upper-body dataset: 8 joints, 2 persons, y up, `hip_joints: null`.
fn upper_body() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/upper_body2")
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `socdiff forecast` of the fixture's `talk3` (20 frames observed, 10 forecast) with `model`
/// into `out`, then `extra`.
fn talk3_forecast(model: &Path, input: &Path, out: &Path, extra: &[&str]) -> Vec<String> {
    let base = ["forecast", "--model", s(model), "--input", s(input), "--sequence", "talk3", "--observe", "20", "--horizon", "10", "--out", s(out)];
    base.iter().chain(extra).map(|x| x.to_string()).collect()
}

/// A tiny model config for fast runs.
fn tiny_config(dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let cfg = dir.join("tiny.json");
    std::fs::write(
        &cfg,
        r#"{"model": {"hidden": 16, "time_dim": 16, "fourier_dim": 8, "social_dim": 16}, "batch": 2, "window": 16, "stride": 8, "val_every": 0}"#,
    )
    .unwrap();
    cfg
}

/// A model trained for 2 steps on the upper-body dataset (once per test binary).
fn upper_body_model() -> &'static PathBuf {
    static M: OnceLock<PathBuf> = OnceLock::new();
    M.get_or_init(|| {
        let root = tmp("safety-model");
        let cfg = tiny_config(&root);
        let run = root.join("run");
        let (ok, _, err) = socdiff(&["train", "--preset", "paper", "--data", s(&upper_body()), "--out", s(&run), "--config", s(&cfg), "--steps", "2"]);
        assert!(ok, "train on the upper-body dataset: {err}");
        run
    })
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

/// Every file under `dir` with its bytes.
fn tree(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(tree(&p));
        } else {
            out.push((p.clone(), std::fs::read(&p).unwrap()));
        }
    }
    out.sort();
    out
}

/// This process's resident memory now (MiB).
fn own_rss_mib() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status.lines().find_map(|l| l.strip_prefix("VmRSS:")).and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok()).map_or(0.0, |kb| kb / 1024.0)
}

/// Runs socdiff: (exit code, stderr, peak RSS in MiB), the RSS from the kernel's accounting
/// of this one child, less this test process's own RSS when it started the child (the kernel
/// counts the spawning process's pages as the child's until it runs the binary).
fn run_measured(args: &[&str]) -> (i32, String, f64) {
    let base = own_rss_mib();
    let err_path = std::env::temp_dir().join(format!("socdiff-safety-err-{}-{:?}", std::process::id(), std::thread::current().id()));
    let child = Command::new(BIN).args(args).stdout(Stdio::null()).stderr(std::fs::File::create(&err_path).unwrap()).spawn().unwrap();
    let pid = child.id() as libc::pid_t;
    let (mut status, mut usage) = (0, unsafe { std::mem::zeroed::<libc::rusage>() });
    // SAFETY: waits for our own child and fills plain-data outputs.
    let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    assert_eq!(r, pid);
    std::mem::forget(child); // reaped above
    let code = if libc::WIFEXITED(status) { libc::WEXITSTATUS(status) } else { -1 };
    let err = std::fs::read_to_string(&err_path).unwrap();
    let _ = std::fs::remove_file(&err_path);
    (code, err, (usage.ru_maxrss as f64 / 1024.0 - base).max(0.0))
}

fn signal(child: &Child, sig: libc::c_int) {
    // SAFETY: sends a signal to our own child.
    unsafe { libc::kill(child.id() as libc::pid_t, sig) };
}

/// One error line containing each of `names`.
fn assert_one_error(err: &str, names: &[&str]) {
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "one error line, got: {err}");
    assert!(lines[0].starts_with("error: "), "{err}");
    for n in names {
        assert!(lines[0].contains(n), "error should name {n:?}: {err}");
    }
}

#[test]
fn outputs_never_destroy_their_inputs_or_foreign_files() {
    let root = tmp("safety-outputs");
    let a = root.join("A");
    copy_dir(&upper_body(), &a);
    let before = tree(&a);
    // `view A --out A/dataset.json` and `export A --format json --out A/dataset.json`.
    for args in [
        vec!["view", s(&a), "--out", "A/dataset.json"],
        vec!["export", s(&a), "--format", "json", "--sequence", "talk1", "--out", "A/dataset.json"],
        vec!["view", s(&a), "--force", "--out", "A/dataset.json"],
    ] {
        let args: Vec<String> = args.iter().map(|x| x.replace("A/dataset.json", s(&a.join("dataset.json")))).collect();
        let (ok, _, err) = socdiff(&args);
        assert!(!ok, "{args:?} must fail");
        assert_one_error(&err, &["dataset.json", "is an input of this command"]);
    }
    assert_eq!(tree(&a), before, "dataset A changed");
    // `view x.bvh --out x.bvh`.
    let bvh = root.join("x.bvh");
    std::fs::copy(cmu_clip(), &bvh).unwrap();
    let clip = std::fs::read(&bvh).unwrap();
    let (ok, _, err) = socdiff(&["view", s(&bvh), "--out", s(&bvh), "--force"]);
    assert!(!ok);
    assert_one_error(&err, &["x.bvh", "is an input"]);
    assert_eq!(std::fs::read(&bvh).unwrap(), clip);
    // An earlier page is replaced only with --force; a foreign file never.
    let page = root.join("v.html");
    assert!(socdiff(&["view", s(&a), "--out", s(&page)]).0);
    let (ok, _, err) = socdiff(&["view", s(&a), "--out", s(&page)]);
    assert!(!ok);
    assert_one_error(&err, &["v.html", "--force"]);
    assert!(socdiff(&["view", s(&a), "--out", s(&page), "--force"]).0);
    let notes = root.join("notes.html");
    std::fs::write(&notes, "<html>mine</html>").unwrap();
    let (ok, _, err) = socdiff(&["view", s(&a), "--out", s(&notes), "--force"]);
    assert!(!ok);
    assert_one_error(&err, &["notes.html", "is not a socdiff viewer page"]);
    assert_eq!(std::fs::read_to_string(&notes).unwrap(), "<html>mine</html>");
    // `train --out DIR` into a directory that is not a run.
    let mine = root.join("mine");
    std::fs::create_dir_all(&mine).unwrap();
    std::fs::write(mine.join("config.json"), "my config").unwrap();
    std::fs::write(mine.join("train_log.jsonl"), "my log").unwrap();
    let cfg = tiny_config(&root);
    let (ok, _, err) = socdiff(&["train", "--preset", "paper", "--data", s(&a), "--out", s(&mine), "--config", s(&cfg), "--steps", "1"]);
    assert!(!ok);
    assert!(err.contains("not a socdiff run directory"), "{err}");
    assert_eq!(std::fs::read_to_string(mine.join("config.json")).unwrap(), "my config");
    assert_eq!(std::fs::read_to_string(mine.join("train_log.jsonl")).unwrap(), "my log");
    // `demo --resume` into it (the demo replaces its own forecast/ on resume).
    std::fs::create_dir_all(mine.join("forecast")).unwrap();
    std::fs::write(mine.join("forecast/mine.txt"), "mine").unwrap();
    let (ok, _, err) = socdiff(&["demo", "--out", s(&mine), "--resume"]);
    assert!(!ok);
    assert!(err.contains("is not a socdiff demo folder"), "{err}");
    assert_eq!(std::fs::read_to_string(mine.join("forecast/mine.txt")).unwrap(), "mine");
    std::fs::remove_dir_all(&root).unwrap();
}

/// A small deterministic generator for the interrupt trials.
struct Lcg(u64);

impl Lcg {
    fn next(&mut self, n: u64) -> u64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 33) % n
    }
}

/// `trials` seeded interrupts of `train --save-every 1` (kill -9, double Ctrl-C, SIGTERM) at
/// random moments, each continuing the run of the last; after every one the run directory
/// must hold a complete checkpoint (or none yet) and the next `--resume` must start.
fn interrupt_trials(trials: usize, seed: u64) {
    let root = tmp(&format!("safety-trials-{seed}"));
    let cfg = tiny_config(&root);
    let run = root.join("run");
    let mut rng = Lcg(seed);
    let data = upper_body();
    let mut last_step = 0u64;
    let (mut kills, mut doubles, mut terms) = (0, 0, 0);
    for trial in 0..trials {
        let mut args = vec!["train", "--data", s(&data), "--out", s(&run), "--config", s(&cfg), "--steps", "1000000", "--save-every", "1"];
        args.extend(if run.exists() { ["--resume"].as_slice() } else { ["--preset", "paper"].as_slice() });
        let mut child = Command::new(BIN).args(&args).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
        std::thread::sleep(Duration::from_millis(150 + rng.next(900)));
        if let Some(status) = child.try_wait().unwrap() {
            let out = child.wait_with_output().unwrap();
            panic!("trial {trial}: train exited by itself ({status}): {}", String::from_utf8_lossy(&out.stderr));
        }
        let mode = rng.next(3);
        match mode {
            0 => {
                signal(&child, libc::SIGKILL);
                kills += 1;
            }
            1 => {
                signal(&child, libc::SIGINT);
                std::thread::sleep(Duration::from_millis(100 + rng.next(150)));
                signal(&child, libc::SIGINT);
                doubles += 1;
            }
            _ => {
                signal(&child, libc::SIGTERM);
                terms += 1;
            }
        }
        let out = child.wait_with_output().unwrap();
        if mode == 2 {
            // One SIGTERM saves and stops with the distinct code.
            assert_eq!(out.status.code(), Some(3), "trial {trial}: SIGTERM: {}", String::from_utf8_lossy(&out.stderr));
        }
        if Checkpoint::exists_in(&run) {
            let ck = Checkpoint::read(&run).unwrap_or_else(|e| panic!("trial {trial} (mode {mode}): the run is not resumable: {e}"));
            assert!(ck.meta.step >= last_step, "trial {trial}: step went back from {last_step} to {}", ck.meta.step);
            last_step = ck.meta.step;
        }
    }
    // And it finishes.
    let steps = (last_step + 1).to_string();
    let (ok, _, err) = socdiff(&["train", "--data", s(&upper_body()), "--out", s(&run), "--resume", "--steps", &steps]);
    assert!(ok, "final resume: {err}");
    assert_eq!(Checkpoint::read(&run).unwrap().meta.step, last_step + 1);
    println!("{trials} trials ({kills} kill -9, {doubles} double Ctrl-C, {terms} SIGTERM): resumable every time, reached step {last_step}");
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn interrupted_training_always_leaves_a_resumable_run() {
    interrupt_trials(20, 1);
}

/// The full 200 trials (about 4 minutes).
#[test]
#[ignore]
fn interrupted_training_always_leaves_a_resumable_run_200() {
    interrupt_trials(200, 2);
}

#[test]
fn a_second_writer_of_a_run_directory_is_refused() {
    let root = tmp("safety-lock");
    let cfg = tiny_config(&root);
    let run = root.join("run");
    let data = upper_body();
    let mut first = Command::new(BIN)
        .args(["train", "--preset", "paper", "--data", s(&data), "--out", s(&run), "--config", s(&cfg), "--steps", "1000000", "--save-every", "5"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while !run.join(TENSORS_FILE).exists() {
        assert!(start.elapsed() < Duration::from_secs(60), "no checkpoint after 60 s");
        std::thread::sleep(Duration::from_millis(50));
    }
    let pid = first.id().to_string();
    for extra in [vec!["--preset", "paper"], vec!["--resume"], vec!["--preset", "paper", "--force"]] {
        let mut args = vec!["train", "--data", s(&data), "--out", s(&run), "--config", s(&cfg), "--steps", "3"];
        args.extend(extra);
        let (ok, _, err) = socdiff(&args);
        assert!(!ok, "a second writer must be refused");
        assert!(err.contains("is being written by process") && err.contains(&pid), "{err}");
    }
    signal(&first, libc::SIGINT);
    let status = first.wait().unwrap();
    assert_eq!(status.code(), Some(3), "stopped early: exit code 3");
    Checkpoint::read(&run).unwrap();
    std::fs::remove_dir_all(&root).unwrap();
}

/// The upper-body dataset with its skeleton changed by `edit` (names and data move together).
fn variant(dir: &Path, edit: impl Fn(&Skeleton) -> (Skeleton, Vec<usize>)) {
    let ds = read_dataset(&upper_body(), &ReadOptions::default()).unwrap();
    let mut sequences = Vec::new();
    for seq in ds.sequences {
        let (skeleton, order) = edit(&seq.scene.skeleton);
        let mut scene = seq.scene.clone();
        scene.positions = seq.scene.positions.select(ndarray::Axis(2), &order);
        scene.skeleton = skeleton;
        sequences.push(Sequence { split: seq.split, scene });
    }
    write_dataset(&Dataset { name: "variant".into(), sequences, metadata: Default::default() }, dir).unwrap();
}

#[test]
fn skeletons_are_checked_by_joint_names_and_mapped_on_request() {
    let model = upper_body_model();
    let root = tmp("safety-skeleton");
    std::fs::create_dir_all(&root).unwrap();
    // Arms swapped: names and data moved together.
    let swapped = root.join("swapped");
    variant(&swapped, |sk| {
        let order = vec![0, 1, 5, 6, 7, 2, 3, 4];
        let joints = order.iter().map(|&j| sk.joints[j].clone()).collect();
        let at = |j: usize| order.iter().position(|&o| o == j).unwrap();
        let bones = sk.bones.iter().map(|&(a, b)| (at(a), at(b))).collect();
        (Skeleton::new("swapped", joints, bones, at(sk.left), at(sk.right)).unwrap(), order)
    });
    let out = root.join("fc");
    let args = |input: &Path, extra: &[&str]| talk3_forecast(model, input, &out, &[&["--samples", "1", "--steps", "2"], extra].concat());
    let (ok, _, err) = socdiff(&args(&swapped, &[]));
    assert!(!ok);
    assert_one_error(&err, &["checkpoint.safetensors", "joint 2 is \"left_shoulder\"", "\"right_shoulder\"", "--joint-map auto"]);
    assert!(!out.exists());
    let (ok, _, err) = socdiff(&args(&swapped, &["--joint-map", "auto"]));
    assert!(ok, "--joint-map auto: {err}");
    assert!(err.contains("left_shoulder ← left_shoulder") || err.contains("mapped onto the model's"), "{err}");
    let fc = read_dataset(&out, &ReadOptions { align_ground: Some(false) }).unwrap();
    assert_eq!(fc.sequences[0].scene.skeleton.joints, read_dataset(&upper_body(), &ReadOptions::default()).unwrap().sequences[0].scene.skeleton.joints);
    std::fs::remove_dir_all(&out).unwrap();
    // A renamed joint.
    let renamed = root.join("renamed");
    variant(&renamed, |sk| {
        let mut r = sk.clone();
        r.joints[0] = "skull".into();
        (r, (0..sk.num_joints()).collect())
    });
    let (ok, _, err) = socdiff(&args(&renamed, &[]));
    assert!(!ok);
    assert_one_error(&err, &["joint 0 is \"head\"", "\"skull\""]);
    assert!(!out.exists());
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn oversize_arguments_fail_in_one_line_before_allocating() {
    let model = upper_body_model();
    let root = tmp("safety-sizes");
    std::fs::create_dir_all(&root).unwrap();
    let out = root.join("out");
    let zero_bvh = root.join("zero.bvh");
    let zero_pkl = root.join("zero.pkl");
    std::os::unix::fs::symlink("/dev/zero", &zero_bvh).unwrap();
    std::os::unix::fs::symlink("/dev/zero", &zero_pkl).unwrap();
    let (data, page) = (upper_body(), root.join("z.html"));
    let fc = |flag: &str, v: &'static str| -> Vec<&str> {
        let pick = |f: &str, default: &'static str| if flag == f { v } else { default };
        vec![
            "forecast",
            "--model",
            s(model),
            "--input",
            s(&data),
            "--sequence",
            "talk3",
            "--observe",
            "20",
            "--horizon",
            pick("--horizon", "10"),
            "--samples",
            pick("--samples", "1"),
            "--out",
            s(&out),
        ]
    };
    let cases: Vec<(Vec<&str>, Vec<&str>)> = vec![
        (fc("--horizon", "18446744073709551615"), vec!["frames is more than"]),
        (fc("--horizon", "4611686018427387904"), vec!["frames is more than"]),
        (fc("--horizon", "1000000000"), vec!["frames is more than"]),
        (fc("--samples", "100000000"), vec!["--samples"]),
        (vec!["data", "convert", s(&data), "--resample", "1e12", "--out", s(&out)], vec!["fps must be in (0, 1000]"]),
        (vec!["view", s(&zero_bvh), "--out", s(&page)], vec!["zero.bvh", "not a BVH file"]),
        (vec!["data", "inspect", s(&zero_pkl)], vec!["zero.pkl", "not a pickle"]),
    ];
    for (args, names) in cases {
        let (code, err, rss) = run_measured(&args);
        assert_eq!(code, 1, "{args:?}: {err}");
        assert_one_error(&err, &names);
        assert!(rss < 100.0, "{args:?}: peak RSS {rss:.1} MiB");
        assert!(!out.exists());
        println!("{:?}: {rss:.1} MiB, {}", &args[..2], err.trim());
    }
    std::fs::remove_dir_all(&root).unwrap();
}

/// A copy of the upper-body dataset with `dataset.json` edited by `edit`.
fn edited(root: &Path, name: &str, edit: impl Fn(&mut serde_json::Value)) -> PathBuf {
    let dir = root.join(name);
    copy_dir(&upper_body(), &dir);
    let path = dir.join("dataset.json");
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    edit(&mut v);
    std::fs::write(&path, serde_json::to_string(&v).unwrap()).unwrap();
    dir
}

#[test]
fn corrupt_and_absurd_input_is_refused_not_used() {
    let root = tmp("safety-absurd");
    std::fs::create_dir_all(&root).unwrap();
    // Weights corrupted on disk (16 values set to 1e6).
    let run = root.join("run");
    copy_dir(upper_body_model(), &run);
    let st = run.join(TENSORS_FILE);
    let mut bytes = std::fs::read(&st).unwrap();
    let header = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    for k in 0..16 {
        let at = 8 + header + 4 * (131 * k + 7);
        bytes[at..at + 4].copy_from_slice(&1e6f32.to_le_bytes());
    }
    std::fs::write(&st, &bytes).unwrap();
    let out = root.join("fc");
    let (ok, _, err) = socdiff(&talk3_forecast(&run, &upper_body(), &out, &["--samples", "1"]));
    assert!(!ok);
    assert_one_error(&err, &["checkpoint.safetensors", "checksum mismatch"]);
    assert!(!out.exists());

    // Positions × 1e30.
    let huge = root.join("huge");
    copy_dir(&upper_body(), &huge);
    let npy = huge.join("test/talk3.npy");
    let mut b = std::fs::read(&npy).unwrap();
    let start = b.len() - 240 * 2 * 8 * 3 * 4;
    for c in b[start..].chunks_exact_mut(4) {
        let v = f32::from_le_bytes(c.try_into().unwrap()) * 1e30;
        c.copy_from_slice(&v.to_le_bytes());
    }
    std::fs::write(&npy, b).unwrap();
    let inspect = |dir: &Path| socdiff(&["data", "inspect", s(dir)]);
    let (ok, _, err) = inspect(&huge);
    assert!(!ok);
    assert_one_error(&err, &["talk3.npy", "beyond ±1000 m", "frame 0", "person 0"]);
    // fps 1e308.
    let fast = edited(&root, "fast", |v| v["fps"] = serde_json::json!(1e308));
    let (ok, _, err) = inspect(&fast);
    assert!(!ok);
    assert_one_error(&err, &["dataset.json", "fps must be in (0, 1000]"]);
    // A file outside the dataset, by `..` and by a symlink.
    let escape = edited(&root, "escape", |v| v["sequences"][0]["file"] = serde_json::json!("../../../../etc/passwd"));
    let (ok, _, err) = inspect(&escape);
    assert!(!ok);
    assert_one_error(&err, &["dataset.json", "../../../../etc/passwd", "not a relative path inside the dataset directory"]);
    let linked = edited(&root, "linked", |v| v["sequences"][0]["file"] = serde_json::json!("train/link.npy"));
    std::os::unix::fs::symlink("/etc/passwd", linked.join("train/link.npy")).unwrap();
    let (ok, _, err) = inspect(&linked);
    assert!(!ok);
    assert_one_error(&err, &["dataset.json", "leads outside the dataset directory"]);
    // Two sequences with one name.
    let twice = edited(&root, "twice", |v| v["sequences"][1]["name"] = serde_json::json!("talk1"));
    let (ok, _, err) = inspect(&twice);
    assert!(!ok);
    assert_one_error(&err, &["dataset.json", "two sequences are named \"talk1\""]);
    // No hips and no shoulders to infer the body frame from.
    let headless = edited(&root, "headless", |v| {
        v["joints"] = serde_json::json!(["head", "neck", "a", "b", "c", "d", "e", "f"]);
        v["bones"] = serde_json::json!([["neck", "head"]]);
    });
    let (ok, _, err) = inspect(&headless);
    assert!(!ok);
    assert_one_error(&err, &["dataset.json", "\"hip_joints\" is not given", "\"left\": NAME"]);
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn an_upper_body_dataset_without_hips_imports_trains_forecasts_and_is_scored() {
    let data = upper_body();
    let (ok, stdout, err) = socdiff(&["data", "inspect", s(&data)]);
    assert!(ok, "{err}");
    assert!(stdout.contains("left_shoulder / right_shoulder") && stdout.contains("8 (upper_body2)"), "{stdout}");
    let model = upper_body_model();
    let root = tmp("safety-upper");
    std::fs::create_dir_all(&root).unwrap();
    let fc = root.join("fc");
    let (ok, _, err) = socdiff(&[
        "forecast",
        "--model",
        s(model),
        "--input",
        s(&data),
        "--sequence",
        "talk3",
        "--observe",
        "30",
        "--horizon",
        "60",
        "--samples",
        "2",
        "--steps",
        "3",
        "--out",
        s(&fc),
    ]);
    assert!(ok, "forecast: {err}");
    // Scored with no hand edits: what needs the default NDMS joints is skipped, saying so.
    let rep = root.join("rep");
    let (ok, stdout, err) = socdiff(&["eval", "--reference", s(&data), "--baselines", "all", "--forecasts", &format!("m={}", s(&fc)), "--out", s(&rep)]);
    assert!(ok, "eval: {err}");
    assert!(err.contains("NDMS skipped") && err.contains("coverage (motion words) skipped") && err.contains("nearest-continuation baseline skipped"), "{err}");
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(rep.join("report.json")).unwrap()).unwrap();
    let labels: Vec<&str> = report["methods"].as_array().unwrap().iter().map(|m| m["label"].as_str().unwrap_or("")).collect();
    assert!(labels.contains(&"m") && labels.contains(&"zero-velocity") && labels.contains(&"ground-truth"), "{labels:?} / {stdout}");
    // With every joint as NDMS joints, NDMS and the nearest continuation run too.
    let rep2 = root.join("rep2");
    let (ok, stdout, err) = socdiff(&["eval", "--reference", s(&data), "--baselines", "all", "--ndms-joints", "all", "--out", s(&rep2)]);
    assert!(ok, "eval --ndms-joints all: {err}");
    assert!(stdout.contains("nearest") && stdout.contains("NDMS"), "{stdout}");
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn demo_stops_on_ctrl_c_and_resumes() {
    let root = tmp("safety-demo");
    let out = root.join("demo");
    let child = Command::new(BIN)
        .args(["demo", "--train", "--out", s(&out), "--steps", "1000000", "--hidden", "16"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while !out.join("model/.socdiff-run").exists() {
        assert!(start.elapsed() < Duration::from_secs(120), "demo training did not start");
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(500));
    signal(&child, libc::SIGINT);
    let done = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&done.stderr);
    assert_eq!(done.status.code(), Some(3), "{err}");
    assert!(err.contains("--resume"), "{err}");
    let step = Checkpoint::read(&out.join("model")).unwrap().meta.step;
    assert!(step >= 1);
    let (ok, _, err) = socdiff(&["demo", "--train", "--out", s(&out), "--resume", "--steps", &step.to_string(), "--hidden", "16"]);
    assert!(ok, "demo --resume: {err}");
    assert!(out.join("report.json").is_file() && out.join("forecast.html").is_file());
    std::fs::remove_dir_all(&root).unwrap();
}

/// A GPU asked of a binary built without CUDA, an unknown device, or bf16 on the CPU: one
/// error line saying what to do, and nothing written.
#[test]
fn devices_that_cannot_run_are_one_clear_error() {
    let root = tmp("safety-device");
    let cfg = tiny_config(&root);
    let run = root.join("run");
    if !cfg!(feature = "cuda") {
        assert_fails(
            &["train", "--preset", "paper", "--data", s(&upper_body()), "--out", s(&run), "--config", s(&cfg), "--steps", "2", "--device", "cuda"],
            &["cuda:0", "built without CUDA", "scripts/build-cuda.sh"],
            &run,
        );
        let out = root.join("fc");
        assert_fails(&talk3_forecast(upper_body_model(), &upper_body(), &out, &["--device", "cuda:1"]), &["cuda:1", "built without CUDA"], &out);
    }
    assert_fails(
        &["train", "--preset", "paper", "--data", s(&upper_body()), "--out", s(&run), "--config", s(&cfg), "--steps", "2", "--precision", "bf16"],
        &["bf16"],
        &run,
    );
    let (ok, _, err) = socdiff(&["bench", "train", "--device", "tpu", "--hidden", "8", "--steps", "1"]);
    assert!(!ok && err.contains("cpu, cuda, cuda:N, auto"), "{err}");
    // auto without a GPU is the CPU, and says so.
    let (ok, outp, err) = socdiff(&["bench", "train", "--device", "auto", "--hidden", "8", "--batch", "1", "--persons", "1", "--frames", "16", "--steps", "1"]);
    assert!(ok, "{err}");
    if !cfg!(feature = "cuda") {
        assert!(outp.contains("on cpu f32 custom"), "{outp}");
    }
}

/// A sequence name becomes file names: one that would leave the output (`../`), hide (empty),
/// drive the terminal (ESC) or overflow a path is refused where the dataset is read, by every
/// command, and shown escaped.
#[test]
fn names_that_would_leave_the_output_are_refused_where_they_are_read() {
    let long = "n".repeat(100_000);
    for (name, problem) in
        [("../../../victim", "path separator"), ("", "is empty"), ("a\u{1b}[2Jb", "control character"), (long.as_str(), "longer than 200 bytes")]
    {
        let data = edited(&tmp("safety-names"), "data", |v| v["sequences"][2]["name"] = name.into());
        let root = data.parent().unwrap();
        let out = root.join("out");
        let (ok, _, err) = socdiff(&["data", "convert", s(&data), "--out", s(&out)]);
        assert!(!ok && err.contains("dataset.json") && err.contains(problem), "{name:?}: {err}");
        assert!(!err.contains('\u{1b}') && err.len() < 2000, "escaped and short: {err:?}");
        assert!(!out.exists() && !root.join("victim.npy").exists() && !root.parent().unwrap().join("victim.npy").exists());
        let fc = root.join("fc");
        let (ok, _, err) = socdiff(&[
            "forecast",
            "--model",
            s(upper_body_model()),
            "--input",
            s(&data),
            "--sequence",
            name,
            "--observe",
            "20",
            "--horizon",
            "5",
            "--out",
            s(&fc),
        ]);
        assert!(!ok && err.contains(problem) && !fc.exists(), "{err}");
    }
    // A misspelled key is named with the one meant; other keys stay free metadata.
    let data = edited(&tmp("safety-keys"), "data", |v| {
        v["hip_jgints"] = serde_json::json!({"left": "left_shoulder", "right": "right_shoulder"});
        v["recorded_by"] = "someone".into();
    });
    let out = data.parent().unwrap().join("out");
    assert_fails(&["data", "convert", s(&data), "--out", s(&out)], &["dataset.json", "unknown key \"hip_jgints\"", "did you mean \"hip_joints\""], &out);
    // Every sequence has its own file.
    let data = edited(&tmp("safety-files"), "data", |v| v["sequences"][1]["file"] = v["sequences"][0]["file"].clone());
    let out = data.parent().unwrap().join("out");
    assert_fails(&["data", "inspect", s(&data)], &["dataset.json", "names the file"], &out);
}

/// A lock file that is a symbolic link is refused, and the file it points to is untouched.
#[test]
fn a_lock_that_is_a_symbolic_link_is_refused() {
    let root = tmp("safety-symlink-lock");
    let cfg = tiny_config(&root);
    let run = root.join("run");
    let (ok, _, err) = socdiff(&["train", "--preset", "paper", "--data", s(&upper_body()), "--out", s(&run), "--config", s(&cfg), "--steps", "1"]);
    assert!(ok, "{err}");
    let victim = root.join("victim.txt");
    std::fs::write(&victim, "keep me").unwrap();
    let lock = run.join(".socdiff-lock");
    let _ = std::fs::remove_file(&lock);
    std::os::unix::fs::symlink(&victim, &lock).unwrap();
    let (ok, _, err) = socdiff(&["train", "--data", s(&upper_body()), "--out", s(&run), "--resume", "--steps", "2"]);
    assert!(!ok && err.contains(".socdiff-lock") && err.contains("not a regular file"), "{err}");
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
}

/// `(header JSON, tensor data)` of a safetensors file.
fn split_safetensors(bytes: &[u8]) -> (serde_json::Value, Vec<u8>) {
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    (serde_json::from_slice(&bytes[8..8 + n]).unwrap(), bytes[8 + n..].to_vec())
}

fn join_safetensors(header: &serde_json::Value, data: &[u8]) -> Vec<u8> {
    let mut text = serde_json::to_string(header).unwrap();
    while !text.len().is_multiple_of(8) {
        text.push(' ');
    }
    let mut out = (text.len() as u64).to_le_bytes().to_vec();
    out.extend(text.as_bytes());
    out.extend(data);
    out
}

/// A checkpoint is verified whole before anything in it is used: its description (model sizes
/// included) and every tensor under one checksum that must be there; sizes from its header are
/// bounded; the file must be as long as its header says; a format-1 description names its
/// tensors file beside it.
#[test]
fn checkpoints_are_verified_whole_before_they_are_used() {
    let model = upper_body_model();
    let original = std::fs::read(model.join(TENSORS_FILE)).unwrap();
    let root = tmp("safety-checkpoints");
    std::fs::create_dir_all(&root).unwrap();
    let forecast = |m: &Path| talk3_forecast(m, &upper_body(), &root.join("fc"), &[]);
    let mutant = |name: &str, edit: &dyn Fn(&mut serde_json::Value, &mut Vec<u8>)| -> PathBuf {
        let (mut header, mut data) = split_safetensors(&original);
        edit(&mut header, &mut data);
        let path = root.join(format!("{name}.safetensors"));
        std::fs::write(&path, join_safetensors(&header, &data)).unwrap();
        path
    };
    fn with_meta(f: impl Fn(&mut serde_json::Value)) -> impl Fn(&mut serde_json::Value, &mut Vec<u8>) {
        move |h, _| {
            let mut meta: serde_json::Value = serde_json::from_str(h["__metadata__"]["socdiff_meta"].as_str().unwrap()).unwrap();
            f(&mut meta);
            h["__metadata__"]["socdiff_meta"] = serde_json::to_string(&meta).unwrap().into();
        }
    }
    let cases: Vec<(PathBuf, Vec<&str>)> = vec![
        (
            mutant("huge", &with_meta(|m| m["config"]["model"]["hidden"] = 1_000_000.into())),
            vec!["huge.safetensors", "hidden 1000000 is more than the 1024 allowed"],
        ),
        (mutant("described", &with_meta(|m| m["fps"] = 25.0.into())), vec!["described.safetensors", "checksum mismatch over the description"]),
        (
            mutant("unsummed", &|h, _| {
                let meta = h["__metadata__"].as_object_mut().unwrap();
                meta.remove("crc32");
                meta.remove("crc32_all");
            }),
            vec!["unsummed.safetensors", "has no checksum"],
        ),
        (mutant("flipped", &|_, d| d[100] ^= 1), vec!["flipped.safetensors", "checksum mismatch"]),
    ];
    for (path, names) in cases {
        let (code, err, rss) = run_measured(&forecast(&path).iter().map(String::as_str).collect::<Vec<_>>());
        assert_eq!(code, 1, "{path:?}: {err}");
        assert_one_error(&err, &names);
        assert!(rss < 1024.0, "{path:?}: peak RSS {rss:.1} MiB");
    }
    // A checkpoint without checksums loads when the user says to trust it, with a warning.
    let unsummed = mutant("trusted", &|h, _| {
        let meta = h["__metadata__"].as_object_mut().unwrap();
        meta.remove("crc32");
        meta.remove("crc32_all");
    });
    let mut args = forecast(&unsummed);
    args.push("--trust-unchecked-checkpoints".into());
    let (ok, _, err) = socdiff(&args);
    assert!(ok && err.contains("warning") && err.contains("trusted.safetensors") && err.contains("no checksum"), "{err}");
    std::fs::remove_dir_all(root.join("fc")).unwrap();
    // A sparse file of 2 GB holding the checkpoint at its start: refused by its length.
    let sparse = root.join("sparse.safetensors");
    std::fs::write(&sparse, &original).unwrap();
    std::fs::OpenOptions::new().write(true).open(&sparse).unwrap().set_len(2 << 30).unwrap();
    let (code, err, rss) = run_measured(&forecast(&sparse).iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(code, 1, "{err}");
    assert_one_error(&err, &["sparse.safetensors", "the file holds"]);
    assert!(rss < 1024.0, "peak RSS {rss:.1} MiB");
    // A format-1 description whose tensors file is a device.
    let old = root.join("old");
    std::fs::create_dir_all(&old).unwrap();
    let mut meta: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(model.join("checkpoint.json")).unwrap()).unwrap();
    meta["format_version"] = 1.into();
    meta["tensors"] = "/dev/zero".into();
    std::fs::write(old.join("checkpoint.json"), serde_json::to_string(&meta).unwrap()).unwrap();
    let (code, err, _) = run_measured(&forecast(&old.join("checkpoint.json")).iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(code, 1, "{err}");
    assert_one_error(&err, &["checkpoint.json", "tensors file \"/dev/zero\""]);
    // Training with an absurd width is refused before anything is built.
    let run = root.join("wide");
    assert_fails(
        &["train", "--preset", "paper", "--data", s(&upper_body()), "--out", s(&run), "--hidden", "1000000000"],
        &["hidden 1000000000 is more than the 1024 allowed"],
        &run,
    );
}

/// Reads are bounded before they allocate, loops by their limits, and pipes are refused
/// before they are opened.
#[test]
fn reads_and_loops_are_bounded() {
    let root = tmp("safety-bounds");
    std::fs::create_dir_all(&root).unwrap();
    // A 1 GB dataset.json (sparse).
    let big = root.join("big");
    std::fs::create_dir_all(&big).unwrap();
    std::fs::File::create(big.join("dataset.json")).unwrap().set_len(1 << 30).unwrap();
    let (code, err, rss) = run_measured(&["data", "inspect", s(&big)]);
    assert_eq!(code, 1, "{err}");
    assert_one_error(&err, &["dataset.json", "more than the 64 MiB"]);
    assert!(rss < 1024.0, "peak RSS {rss:.1} MiB");
    // A sequence of 3,000,000 frames, and 60,000 sequences.
    let long = edited(&tmp("safety-long"), "data", |v| v["sequences"][0]["frames"] = 3_000_000.into());
    let (code, err, rss) = run_measured(&["data", "inspect", s(&long)]);
    assert_eq!(code, 1, "{err}");
    assert_one_error(&err, &["dataset.json", "frames is more than"]);
    assert!(rss < 1024.0, "peak RSS {rss:.1} MiB");
    // Written as text: a JSON value of 60,000 sequences would swell this test process, whose
    // memory the children's accounting starts from.
    let many = edited(&tmp("safety-many"), "data", |v| v["sequences"] = serde_json::json!([]));
    let fixture: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(upper_body().join("dataset.json")).unwrap()).unwrap();
    let first = serde_json::to_string(&fixture["sequences"][0]).unwrap();
    let seqs: Vec<String> = (0..60_000).map(|i| first.replacen("\"talk1\"", &format!("\"s{i}\""), 1)).collect();
    let text = std::fs::read_to_string(many.join("dataset.json")).unwrap().replace("\"sequences\":[]", &format!("\"sequences\":[{}]", seqs.join(",")));
    std::fs::write(many.join("dataset.json"), text).unwrap();
    let (code, err, _) = run_measured(&["data", "inspect", s(&many)]);
    assert_eq!(code, 1, "{err}");
    assert_one_error(&err, &["dataset.json", "60000 sequences"]);
    // A FIFO in place of a BVH file: refused at once, never opened.
    let fifo = root.join("motion.bvh");
    let c = std::ffi::CString::new(s(&fifo)).unwrap();
    // SAFETY: creates a FIFO at a path of ours.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let started = Instant::now();
    let (code, err, _) = run_measured(&["data", "inspect", s(&fifo)]);
    assert!(started.elapsed() < Duration::from_secs(10));
    assert_eq!(code, 1, "{err}");
    assert_one_error(&err, &["motion.bvh", "pipe, socket or device"]);
    // … and in place of a checkpoint.
    let run = root.join("fifo-run");
    std::fs::create_dir_all(&run).unwrap();
    let c = std::ffi::CString::new(s(&run.join(TENSORS_FILE))).unwrap();
    // SAFETY: creates a FIFO at a path of ours.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let started = Instant::now();
    let (code, err, _) = run_measured(&talk3_forecast(&run, &upper_body(), &root.join("fc"), &[]).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(started.elapsed() < Duration::from_secs(10));
    assert_eq!(code, 1, "{err}");
    assert_one_error(&err, &[TENSORS_FILE, "pipe, socket or device"]);
    // A BVH of 20,000 joints and no hips: an error that lists a few of them, not all.
    let mut bvh = String::from("HIERARCHY\nROOT j0\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\n");
    for j in 1..20_000 {
        bvh += &format!(" JOINT j{j}\n {{\n OFFSET 0 1 0\n CHANNELS 0\n }}\n");
    }
    bvh += "}\nMOTION\nFrames: 1\nFrame Time: 0.033333\n0 0 0\n";
    let wide = root.join("wide.bvh");
    std::fs::write(&wide, bvh).unwrap();
    let (code, err, _) = run_measured(&["data", "inspect", s(&wide)]);
    assert_eq!(code, 1, "{err}");
    assert_one_error(&err, &["wide.bvh", "and 19988 more"]);
    assert!(err.len() < 1000, "{} bytes of error", err.len());
    // Context inversion and persons by their limits.
    let (out, data) = (root.join("out"), upper_body());
    let args = |extra: &[&str]| talk3_forecast(upper_body_model(), &data, &out, extra);
    assert_fails(&args(&["--invert-context", "4294967297"]), &["--invert-context 4294967297 is more than the 1000"], &out);
    assert_fails(&args(&["--persons", "0,0"]), &["person 0 selected twice"], &out);
}

/// A run whose loss explodes stops with the last good checkpoint kept.
#[test]
fn a_diverging_run_stops_and_keeps_its_last_good_checkpoint() {
    let root = tmp("safety-diverge");
    let cfg = tiny_config(&root);
    let run = root.join("run");
    let (ok, _, err) = socdiff(&[
        "train",
        "--preset",
        "paper",
        "--data",
        s(&upper_body()),
        "--out",
        s(&run),
        "--config",
        s(&cfg),
        "--steps",
        "300",
        "--save-every",
        "1",
        "--lr",
        "2.5",
    ]);
    assert!(!ok && err.contains("training diverged at step") && err.contains("is kept"), "{err}");
    let kept = Checkpoint::load(&run).unwrap();
    assert!(kept.step >= 1 && kept.meta.loss.is_some_and(|l| l.is_finite()), "{:?}", kept.meta.loss);
}

/// Every file under `dir` (paths only).
fn listing(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let p = e.path();
        if p.is_dir() && !p.is_symlink() {
            out.extend(listing(&p));
        }
        out.push(p);
    }
    out.sort();
    out
}

/// Seeded random mutants of a checkpoint (its description, its tensor table, its data, with and
/// without the checksums, its length) and of sequence names: each command ends with exit code 1
/// and one error line naming the file (or, for a name that is fine, succeeds), never panics or
/// aborts, allocates no more than 1 GiB and writes nothing outside its output.
#[test]
fn random_mutants_of_checkpoints_and_names_fail_cleanly() {
    let model = upper_body_model();
    let original = std::fs::read(model.join(TENSORS_FILE)).unwrap();
    let root = tmp("safety-mutants");
    std::fs::create_dir_all(&root).unwrap();
    let mut rng = Lcg(2024);
    let numbers = [0u64, 1, 7, 1 << 20, 1 << 31, 1 << 40, u64::MAX >> 1];
    for trial in 0..24 {
        let (mut header, mut data) = split_safetensors(&original);
        let kind = rng.next(6);
        match kind {
            // A number of the description: a model size, the window, the step or the fps.
            0 => {
                let mut meta: serde_json::Value = serde_json::from_str(header["__metadata__"]["socdiff_meta"].as_str().unwrap()).unwrap();
                let field =
                    ["/config/model/hidden", "/config/model/time_dim", "/config/model/feature_dims", "/config/window", "/step", "/fps"][rng.next(6) as usize];
                *meta.pointer_mut(field).unwrap() = numbers[rng.next(numbers.len() as u64) as usize].into();
                header["__metadata__"]["socdiff_meta"] = serde_json::to_string(&meta).unwrap().into();
            }
            // The tensor table: a shape or an offset.
            1 => {
                let names: Vec<String> = header.as_object().unwrap().keys().filter(|k| *k != "__metadata__").cloned().collect();
                let t = &mut header[names[rng.next(names.len() as u64) as usize].as_str()];
                let n = numbers[rng.next(numbers.len() as u64) as usize];
                if rng.next(2) == 0 {
                    t["shape"][0] = n.into()
                } else {
                    t["data_offsets"][1] = n.into()
                }
            }
            // The data, with or without the checksums.
            2 | 3 => {
                let at = rng.next(data.len() as u64) as usize;
                data[at] ^= 1 << rng.next(8);
                if kind == 3 {
                    let meta = header["__metadata__"].as_object_mut().unwrap();
                    meta.remove("crc32");
                    meta.remove("crc32_all");
                }
            }
            // Cut short, or grown.
            4 => data.truncate(rng.next(data.len() as u64) as usize),
            _ => data.extend(std::iter::repeat_n(7u8, 1 + rng.next(4096) as usize)),
        }
        let path = root.join(format!("mutant{trial}.safetensors"));
        std::fs::write(&path, join_safetensors(&header, &data)).unwrap();
        let out = root.join("out");
        let args = talk3_forecast(&path, &upper_body(), &out, &[]);
        let (code, err, rss) = run_measured(&args.iter().map(String::as_str).collect::<Vec<_>>());
        assert_eq!(code, 1, "trial {trial} (mutation {kind}): {err}");
        assert_one_error(&err, &[&format!("mutant{trial}.safetensors")]);
        assert!(rss < 1024.0 && !out.exists(), "trial {trial}: peak RSS {rss:.1} MiB");
    }
    // Names drawn from separators, dots, control characters and letters, up to 300 long.
    let alphabet: Vec<char> = "ab/\\.\u{1b}\u{0}\n é".chars().collect();
    for trial in 0..16 {
        let len = rng.next(if trial % 4 == 0 { 300 } else { 6 }) as usize;
        let name: String = (0..len).map(|_| alphabet[rng.next(alphabet.len() as u64) as usize]).collect();
        let data = edited(&root, &format!("names{trial}"), |v| v["sequences"][0]["name"] = name.clone().into());
        let before = listing(&root);
        let out = root.join(format!("converted{trial}"));
        let (code, err, rss) = run_measured(&["data", "convert", s(&data), "--out", s(&out)]);
        assert!(rss < 1024.0 && (code == 0 || code == 1), "trial {trial} {name:?}: exit {code}, {rss:.1} MiB: {err}");
        if code == 1 {
            assert_one_error(&err, &["dataset.json"]);
            assert!(!err.contains('\u{1b}') && !out.exists(), "{err:?}");
        }
        let after = listing(&root);
        let new: Vec<&PathBuf> = after.iter().filter(|p| !before.contains(p)).collect();
        assert!(new.iter().all(|p| p.starts_with(&out)), "trial {trial} {name:?} wrote outside its output: {new:?}");
    }
}
