//! End-to-end tests of the classifiers: training on generated triads, evaluation, checkpoints,
//! resume, inference API and input errors. Networks and data are tiny so that this runs in
//! seconds.

use super::*;
use crate::data::synthetic::triads::{generate_dataset, MotionLibrary, SpeakingTimeline, SynthConfig};
use crate::data::Split;
use crate::metrics::sscp::{self, SscpConfig};
use crate::model::Parameterized;
use std::path::PathBuf;

fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("socdiff-clf-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Generated triads: 18 train and 12 test scenes of 300 frames (procedural motion and
/// timelines, test timelines and bodies unseen in training).
fn toy_data() -> (Vec<Scene>, Vec<Scene>) {
    let (train_lib, test_lib) = (MotionLibrary::procedural(8, 11), MotionLibrary::procedural(3, 12));
    let tls: Vec<SpeakingTimeline> = (0..10).map(|s| SpeakingTimeline::procedural(900, 100 + s)).collect();
    let ds = generate_dataset("toy", &tls[..6], &train_lib, &tls[6..], &test_lib, &SynthConfig { segment_frames: 300, variants: 1, seed: 1 }).unwrap();
    (ds.split(Split::Train).cloned().collect(), ds.split(Split::Test).cloned().collect())
}

fn tiny_config(steps: usize) -> ClassifierConfig {
    ClassifierConfig {
        steps,
        batch: 8,
        window: 64,
        seed: 3,
        save_every: 1000,
        adam: crate::train::AdamConfig { lr: 3e-3, ..Default::default() },
        net: NetConfig { embed: 12, hidden: 12, message: 8, ..Default::default() },
        ..Default::default()
    }
}

fn run(scenes: &[Scene], out: &Path, cfg: ClassifierConfig, resume: bool, steps: Option<usize>) -> Result<TrainSummary> {
    let opts = TrainOptions { out_dir: out.to_path_buf(), resume, config: cfg, steps, source: "toy".into(), stop: None, device: Default::default() };
    train::train(scenes, &opts, &mut |_| {})
}

/// Trains for a few seconds: the loss falls, speaking is detected far better than chance
/// (balanced accuracy) on held-out generated scenes, and the buyer is found.
#[test]
fn training_learns_speaking_and_buyer_on_generated_triads() {
    let (train_scenes, test_scenes) = toy_data();
    let out = temp_dir("learn");
    let started = std::time::Instant::now();
    let summary = run(&train_scenes, &out, tiny_config(150), false, None).unwrap();
    eprintln!("150 steps in {:.1} s", started.elapsed().as_secs_f64());
    let first: f32 = summary.losses[..10].iter().sum::<f32>() / 10.0;
    let last: f32 = summary.losses[summary.losses.len() - 10..].iter().sum::<f32>() / 10.0;
    assert!(last < 0.7 * first, "loss {first} → {last}");
    let clf = SocialSignalClassifiers::load(&out).unwrap();
    let ev = evaluate(&clf, &test_scenes).unwrap();
    let s = &ev.speaking;
    eprintln!(
        "toy test: accuracy {:.3} (silent baseline {:.3}), balanced {:.3}, F1 {:.3}, buyer {}/{}",
        s.accuracy(),
        s.silent_baseline(),
        s.balanced_accuracy(),
        s.f1(),
        ev.buyer_correct,
        ev.buyer_total
    );
    assert_eq!(s.total(), 12 * 300 * 3);
    assert!(s.balanced_accuracy() > 0.75 && s.accuracy() > s.silent_baseline() + 0.1, "{s:?}");
    // Guessing finds the buyer in 10 or more of 12 scenes with probability 5.5e-4.
    assert_eq!(ev.buyer_total, 12);
    assert!(ev.buyer_correct >= 10, "buyer {}/{}", ev.buyer_correct, ev.buyer_total);

    // The inference API: probabilities in [0, 1], buyer probabilities sum to 1, annotate fills in
    // what SSCP needs and SSCP states follow.
    let scene = &test_scenes[0];
    let pred = clf.predict(scene).unwrap();
    assert_eq!(pred.speaking_probability.dim(), (300, 3));
    assert!(pred.speaking_probability.iter().all(|p| (0.0..=1.0).contains(p)));
    assert!((pred.buyer_probability.iter().sum::<f32>() - 1.0).abs() < 1e-5);
    let mut bare = scene.clone();
    bare.signals.clear();
    for p in bare.persons.iter_mut() {
        p.role = None;
    }
    let annotated = clf.annotate(&bare).unwrap();
    assert_eq!(annotated.signals["speaking"], pred.speaking());
    let triad = sscp::Triad::from_roles(&annotated).unwrap();
    assert_eq!(triad.buyer, pred.buyer);
    assert_eq!(sscp::scene_states(&annotated, &SscpConfig::default()).unwrap().len(), 300);
    assert_eq!(clf.annotate(scene).unwrap(), *scene, "a scene with signals and roles is kept");
    // Shorter than a window, and a single person: still works.
    let short = scene.slice_frames(0, 20).unwrap();
    assert_eq!(clf.predict(&short).unwrap().speaking_probability.dim(), (20, 3));
    let alone = scene.select_persons(&[1]).unwrap();
    assert_eq!(clf.predict(&alone).unwrap().buyer, 0);
    std::fs::remove_dir_all(&out).ok();
}

/// N steps, then resume to 2N, give the same weights as 2N steps at once; the checkpoint
/// reloads to identical predictions.
#[test]
fn resume_continues_exactly_and_checkpoints_round_trip() {
    let (train_scenes, test_scenes) = toy_data();
    let (a, b) = (temp_dir("resume-a"), temp_dir("resume-b"));
    let cfg = ClassifierConfig { save_every: 3, ..tiny_config(6) };
    run(&train_scenes[..3], &a, cfg.clone(), false, None).unwrap();
    run(&train_scenes[..3], &b, ClassifierConfig { steps: 3, ..cfg.clone() }, false, None).unwrap();
    let e = run(&train_scenes[..3], &b, cfg.clone(), false, None).unwrap_err().to_string();
    assert!(e.contains("already holds a classifier checkpoint"), "{e}");
    let s = run(&train_scenes[..3], &b, cfg.clone(), true, Some(6)).unwrap();
    assert_eq!((s.first_step, s.last_step), (3, 6));
    let (ca, cb) = (ClassifierCheckpoint::read(&a).unwrap(), ClassifierCheckpoint::read(&b).unwrap());
    assert_eq!(ca.meta.step, 6);
    for ((n1, v1), (n2, v2)) in ca.network().unwrap().named_vars().iter().zip(cb.network().unwrap().named_vars().iter()) {
        assert_eq!(n1, n2);
        assert_eq!(v1.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap(), v2.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap(), "{n1}");
    }
    let log = std::fs::read_to_string(b.join(checkpoint::LOG_FILE)).unwrap();
    assert_eq!(log.lines().count(), 6);
    // Loading twice gives the same predictions.
    let (p1, p2) = (SocialSignalClassifiers::load(&a).unwrap(), SocialSignalClassifiers::load(a.join(checkpoint::META_FILE)).unwrap());
    assert_eq!(p1.predict(&test_scenes[0]).unwrap(), p2.predict(&test_scenes[0]).unwrap());
    for d in [a, b] {
        std::fs::remove_dir_all(d).ok();
    }
}

/// Bad inputs: one-line errors naming the scene or file, and nothing written.
#[test]
fn bad_inputs_are_clear_errors_and_write_nothing() {
    let (train_scenes, _) = toy_data();
    let out = temp_dir("bad");
    let cfg = tiny_config(2);
    // No speaking signal.
    let mut unlabelled = train_scenes[0].clone();
    unlabelled.signals.clear();
    let e = run(&[unlabelled], &out, cfg.clone(), false, None).unwrap_err().to_string();
    assert!(e.contains(&train_scenes[0].name) && e.contains("speaking"), "{e}");
    // NaN labels.
    let mut nan = train_scenes[0].clone();
    nan.signals.get_mut("speaking").unwrap()[[5, 1]] = f32::NAN;
    assert!(run(&[nan], &out, cfg.clone(), false, None).unwrap_err().to_string().contains("NaN"));
    // A window longer than every scene; mixed frame rates; resume without a checkpoint.
    let e = run(&train_scenes[..1], &out, ClassifierConfig { window: 5000, ..cfg.clone() }, false, None).unwrap_err().to_string();
    assert!(e.contains("5000") && e.contains("`window`"), "{e}");
    let mut fast = train_scenes[1].clone();
    fast.fps = 60.0;
    assert!(run(&[train_scenes[0].clone(), fast], &out, cfg.clone(), false, None).unwrap_err().to_string().contains("fps"));
    assert!(run(&train_scenes[..1], &out, cfg.clone(), true, None).unwrap_err().to_string().contains("no classifier checkpoint"));
    assert!(!out.exists(), "nothing may be written on a failed start");

    // Broken checkpoints.
    run(&train_scenes[..1], &out, cfg, false, None).unwrap();
    let st = out.join(checkpoint::TENSORS_FILE);
    let bytes = std::fs::read(&st).unwrap();
    std::fs::write(&st, &bytes[..bytes.len() / 2]).unwrap();
    let e = SocialSignalClassifiers::load(&out).err().unwrap().to_string();
    assert!(e.contains(&st.display().to_string()) && e.contains("truncated"), "{e}");
    std::fs::write(&st, &bytes).unwrap();
    // The description is in the safetensors header: the readable classifier.json is informative.
    let meta = out.join(checkpoint::META_FILE);
    let text = std::fs::read_to_string(&meta).unwrap();
    std::fs::write(&meta, "{}").unwrap();
    assert_eq!(SocialSignalClassifiers::load(&out).unwrap().meta().step, 2);
    std::fs::write(&meta, &text).unwrap();
    // Corrupted weights: the checksum names the file.
    let mut bad = bytes.clone();
    let at = bad.len() - 64;
    bad[at..at + 4].copy_from_slice(&1e6f32.to_le_bytes());
    std::fs::write(&st, &bad).unwrap();
    let e = SocialSignalClassifiers::load(&out).err().unwrap().to_string();
    assert!(e.contains(&st.display().to_string()) && e.contains("checksum mismatch"), "{e}");
    std::fs::write(&st, &bytes).unwrap();
    assert!(matches!(SocialSignalClassifiers::load(out.join("missing")), Err(crate::Error::Io { .. })));
    // A scene on another skeleton or frame rate.
    let clf = SocialSignalClassifiers::load(&out).unwrap();
    let mupots = Scene::new("m", 30.0, crate::data::Skeleton::mupots17(), ndarray::Array4::zeros((4, 3, 17, 3))).unwrap();
    assert!(clf.predict(&mupots).unwrap_err().to_string().contains("skeleton"));
    let mut slow = train_scenes[0].clone();
    slow.fps = 25.0;
    assert!(clf.predict(&slow).unwrap_err().to_string().contains("25 fps"));
    std::fs::remove_dir_all(&out).ok();
}

/// Windows cover every frame with half overlap.
#[test]
fn inference_windows_cover_the_sequence() {
    assert_eq!(window_starts(10, 64), vec![0]);
    assert_eq!(window_starts(64, 64), vec![0]);
    assert_eq!(window_starts(100, 64), vec![0, 32, 36]);
    assert_eq!(window_starts(128, 64), vec![0, 32, 64]);
}
