//! End-to-end tests of training: exact resume, checkpoints, errors that leave files alone,
//! Ctrl-C, and the social channel (leader/follower) through the inpainting sampler.

use super::*;
use crate::checkpoint::Weights;
use crate::data::dataset::Sequence;
use crate::data::Skeleton;
use crate::model::Parameterized;
use crate::model::{Aggregator, DenoiserConfig};

use ndarray::Array4;
use rand::{Rng, SeedableRng};
use std::collections::BTreeMap;

/// A 3-joint skeleton (left hip, right hip, head): δ = 13.
pub(crate) fn tiny_skeleton() -> Skeleton {
    Skeleton::new("tiny", vec!["l".into(), "r".into(), "head".into()], vec![(0, 2), (1, 2)], 0, 1).unwrap()
}

/// Persons of the tiny skeleton walking on circles ([`crate::data::synthetic::circle_walkers`],
/// phase `seed`), hips 0.2 m apart, head bobbing.
pub(crate) fn walking_scene(name: &str, frames: usize, persons: usize, seed: u64) -> Scene {
    let body = |f: usize, _p: usize, out: &mut [f32]| out.copy_from_slice(&[-0.1, 0.0, 0.9, 0.1, 0.0, 0.9, 0.0, 0.0, 1.7 + 0.02 * (f as f32 * 0.3).sin()]);
    let mut scene = crate::data::synthetic::circle_walkers(&tiny_skeleton(), frames, persons, 30.0, seed as f32, body).unwrap();
    scene.name = name.into();
    scene
}

pub(crate) fn dataset(name: &str, seqs: Vec<(Split, Scene)>) -> Dataset {
    Dataset { name: name.into(), sequences: seqs.into_iter().map(|(split, scene)| Sequence { split, scene }).collect(), metadata: Default::default() }
}

/// A unique empty temp directory path (not created).
pub(crate) fn temp_dir(tag: &str) -> PathBuf {
    static N: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = N.fetch_add(1, Ordering::SeqCst);
    let d = std::env::temp_dir().join(format!("socdiff-train-{tag}-{}-{n}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Two train scenes (P = 3 and P = 2) and one test scene.
fn small_dataset() -> Dataset {
    dataset(
        "small",
        vec![(Split::Train, walking_scene("w1", 48, 3, 1)), (Split::Train, walking_scene("w2", 40, 2, 2)), (Split::Test, walking_scene("t1", 32, 2, 3))],
    )
}

/// A tiny run: hidden 16, windows of 16 frames; 9 + 7 windows → 5 batches per epoch.
fn tiny(steps: usize) -> TrainConfig {
    TrainConfig {
        model: DenoiserConfig {
            hidden: 16,
            time_dim: 16,
            fourier_dim: 8,
            social_dim: 16,
            aggregator: Aggregator::Attention { heads: 2 },
            ..Default::default()
        },
        steps,
        batch: 4,
        window: 16,
        stride: 4,
        seed: 3,
        ema: EmaConfig { decay: 0.9, update_every: 2, warmup_steps: 2 },
        save_every: 3,
        val_every: 2,
        val_windows: 6,
        ..Default::default()
    }
}

/// The config of the checkpoint in `dir` continued up to `steps`.
fn resumed(dir: &Path, steps: usize) -> Option<TrainConfig> {
    Some(TrainConfig { steps, ..Checkpoint::read_meta(dir).unwrap().config })
}

fn opts(dir: &Path, resume: bool, config: Option<TrainConfig>) -> TrainOptions {
    TrainOptions { out_dir: dir.to_path_buf(), resume, config, source: "test".into(), stop: None, force: false, ..Default::default() }
}

fn run(ds: &Dataset, dir: &Path, resume: bool, config: Option<TrainConfig>) -> Result<TrainSummary> {
    train(ds, &opts(dir, resume, config), &mut |_| {})
}

/// Every file of a directory with its bytes.
fn snapshot(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), std::fs::read(&p).unwrap()))
        .collect()
}

/// Loss lines of a training log without the wall-clock seconds.
fn log_losses(dir: &Path) -> Vec<String> {
    std::fs::read_to_string(dir.join(checkpoint::LOG_FILE))
        .unwrap()
        .lines()
        .map(|l| {
            let mut v: Value = serde_json::from_str(l).unwrap();
            v.as_object_mut().unwrap().remove("seconds");
            v.to_string()
        })
        .collect()
}

#[test]
fn resume_continues_exactly() {
    let ds = small_dataset();
    let (a, b) = (temp_dir("straight"), temp_dir("split"));
    let full = run(&ds, &a, false, Some(tiny(8))).unwrap();
    assert_eq!((full.first_step, full.last_step, full.losses.len()), (0, 8, 8));
    assert_eq!(full.val_losses.iter().map(|v| v.0).collect::<Vec<_>>(), vec![2, 4, 6, 8]);
    let half = run(&ds, &b, false, Some(tiny(4))).unwrap();
    assert_eq!(half.last_step, 4);
    // Only the step count changes on resume; the rest comes from the checkpoint.
    let rest = run(&ds, &b, true, resumed(&b, 8)).unwrap();
    assert_eq!((rest.first_step, rest.last_step), (4, 8));
    let joined: Vec<f32> = half.losses.iter().chain(&rest.losses).copied().collect();
    println!("losses, 8 steps: {:?}", full.losses);
    assert_eq!(joined, full.losses, "4 + resume + 4 steps must give the losses of 8 steps");
    let joined_val: Vec<(u64, f32)> = half.val_losses.iter().chain(&rest.val_losses).copied().collect();
    assert_eq!(joined_val, full.val_losses);
    assert_eq!(log_losses(&a), log_losses(&b));

    // Same online weights, EMA and Adam moments.
    let (ca, cb) = (Checkpoint::read(&a).unwrap(), Checkpoint::read(&b).unwrap());
    assert_eq!(ca.meta.step, 8);
    let (ta, tb) = (ca.tensors(), cb.tensors());
    assert_eq!(ta.len(), tb.len());
    assert!(ta.iter().any(|t| t.0.starts_with(checkpoint::PREFIX_ADAM_V)));
    let mut worst = 0.0f32;
    for ((na, sa, va), (nb, sb, vb)) in ta.iter().zip(&tb) {
        assert_eq!((na, sa), (nb, sb));
        for (x, y) in va.iter().zip(vb.iter()) {
            worst = worst.max((x - y).abs());
        }
    }
    println!("resume: max |Δ| over all {} tensors = {worst:e}", ta.len());
    assert!(worst <= 1e-6, "weights differ by {worst}");
    // The weights moved, and the EMA differs from the online weights after the warm-up.
    let first = |c: &Checkpoint, prefix: &str| c.tensors().into_iter().find(|t| t.0.starts_with(prefix)).unwrap().2.to_vec();
    assert_ne!(first(&ca, checkpoint::PREFIX_ONLINE), first(&ca, checkpoint::PREFIX_EMA));
    let init = Denoiser::new(ca.meta.config.model.clone(), 3).unwrap();
    assert_ne!(optimizer::var_values(&init.named_vars()[0].1).unwrap(), first(&ca, checkpoint::PREFIX_ONLINE));
    // Resuming a finished run does nothing and keeps the checkpoint.
    let again = run(&ds, &b, true, None).unwrap();
    assert_eq!((again.first_step, again.last_step, again.losses.len()), (8, 8, 0));
    for d in [a, b] {
        std::fs::remove_dir_all(d).unwrap();
    }
}

/// `scene` with a fourth joint (a second head marker).
fn with_extra_joint(scene: &Scene) -> Scene {
    let (f, p, _, _) = scene.positions.dim();
    let pos = Array4::from_shape_fn((f, p, 4, 3), |(a, b, j, k)| scene.positions[[a, b, j.min(2), k]] + if j == 3 { 0.1 } else { 0.0 });
    let sk = Skeleton::new("tiny4", vec!["l".into(), "r".into(), "head".into(), "top".into()], vec![(0, 2), (1, 2), (2, 3)], 0, 1).unwrap();
    Scene::new(scene.name.clone(), scene.fps, sk, pos).unwrap()
}

#[test]
fn bad_starts_are_clear_errors_and_write_nothing() {
    let ds = small_dataset();
    let dir = temp_dir("errors");
    let err = |ds: &Dataset, resume: bool, config: Option<TrainConfig>| run(ds, &dir, resume, config).unwrap_err().to_string();

    // Nothing to train on, data that does not fit, bad config values: no directory is created.
    let e = err(&dataset("empty", vec![]), false, Some(tiny(2)));
    assert!(e.contains("dataset empty has no train sequences"), "{e}");
    let e = err(&dataset("only-test", vec![(Split::Test, walking_scene("t", 40, 2, 1))]), false, Some(tiny(2)));
    assert!(e.contains("no train sequences") && e.contains("test"), "{e}");
    let e = err(&ds, false, Some(TrainConfig { window: 100, ..tiny(2) }));
    assert!(e.contains("longer than every sequence") && e.contains("48 frames"), "{e}");
    let e = err(&ds, false, Some(TrainConfig { batch: 0, ..tiny(2) }));
    assert!(e.contains("batch must be at least 1"), "{e}");
    let mixed = dataset("mixed", vec![(Split::Train, walking_scene("a", 40, 2, 1)), (Split::Train, with_extra_joint(&walking_scene("b", 40, 2, 2)))]);
    let e = err(&mixed, false, Some(tiny(2)));
    assert!(e.contains("one skeleton"), "{e}");
    assert!(!dir.exists(), "a failed start created {}", dir.display());
    let e = err(&ds, true, None);
    assert!(e.contains("`resume`") && e.contains("does not exist"), "{e}");
    std::fs::create_dir_all(&dir).unwrap();
    let e = err(&ds, true, None);
    assert!(e.contains("holds no checkpoint"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();

    // A real run, then every bad start leaves its files byte for byte.
    run(&ds, &dir, false, Some(tiny(2))).unwrap();
    let before = snapshot(&dir);
    assert!(before.contains_key(checkpoint::META_FILE) && before.contains_key(checkpoint::TENSORS_FILE) && before.contains_key(checkpoint::LOG_FILE));
    let e = err(&ds, false, Some(tiny(4)));
    assert!(e.contains("already holds a checkpoint at step 2") && e.contains("`resume`"), "{e}");
    let mut changed = resumed(&dir, 4).unwrap();
    (changed.model.hidden, changed.window) = (8, 8);
    let e = err(&ds, true, Some(changed));
    assert!(e.contains("model.hidden") && e.contains("window") && e.contains("checkpoint.safetensors"), "{e}");
    let other = dataset("four", vec![(Split::Train, with_extra_joint(&walking_scene("a", 40, 2, 1)))]);
    let e = err(&other, true, resumed(&dir, 4));
    assert!(e.contains("checkpoint.safetensors") && e.contains("3 joints") && e.contains("4 joints") && e.contains("no joint \"top\""), "{e}");
    let mut slow = small_dataset();
    for s in &mut slow.sequences {
        s.scene.fps = 25.0;
    }
    let e = err(&slow, true, resumed(&dir, 4));
    assert!(e.contains("30 fps") && e.contains("25 fps"), "{e}");
    let e = err(&ds, true, Some(TrainConfig { batch: 0, ..resumed(&dir, 4).unwrap() }));
    assert!(e.contains("batch"), "{e}");
    assert_eq!(snapshot(&dir), before, "a failed start changed the run directory");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `min_std` raises the stds a run fits below it to it, dim by dim, and the checkpoint records
/// the floored standardization that sampling then uses.
#[test]
fn min_std_floors_the_recorded_standardization() {
    let ds = small_dataset();
    let (plain, floored) = (temp_dir("std-plain"), temp_dir("std-floored"));
    run(&ds, &plain, false, Some(tiny(1))).unwrap();
    run(&ds, &floored, false, Some(TrainConfig { min_std: 0.2, ..tiny(1) })).unwrap();
    let (a, b) = (Checkpoint::load(&plain).unwrap().standardization, Checkpoint::load(&floored).unwrap().standardization);
    assert_eq!(a.mean, b.mean);
    assert!(a.std.iter().any(|&s| s < 0.2) && a.std.iter().any(|&s| s > 0.2), "{:?}", a.std);
    for (i, (x, y)) in a.std.iter().zip(&b.std).enumerate() {
        assert_eq!(*y, x.max(0.2), "dim {i}");
    }
    for bad in [-0.1, 1.5, f64::NAN] {
        let e = TrainConfig { min_std: bad, ..tiny(1) }.validate().unwrap_err().to_string();
        assert!(e.contains("min_std"), "{e}");
    }
    std::fs::remove_dir_all(&plain).unwrap();
    std::fs::remove_dir_all(&floored).unwrap();
}

#[test]
fn checkpoint_loads_for_inference_and_corruption_is_named() {
    let ds = small_dataset();
    let dir = temp_dir("load");
    run(&ds, &dir, false, Some(tiny(3))).unwrap();
    let m = Checkpoint::load(&dir).unwrap();
    assert_eq!((m.step, m.weights, m.fps, m.config.window, m.config.anchor_offset()), (3, Weights::Ema, 30.0, 16, 3));
    assert_eq!(m.skeleton, tiny_skeleton());
    assert_eq!(m.standardization.dim(), 13);
    assert_eq!(m.diffusion.timesteps(), 1000);
    assert_eq!(m.meta.socdiff_version, env!("CARGO_PKG_VERSION"));
    assert_eq!(m.meta.data.windows_by_persons, BTreeMap::from([("2".to_string(), 7), ("3".to_string(), 9)]));
    let ck = Checkpoint::read(&dir).unwrap();
    for (name, var) in m.denoiser.named_vars() {
        let want = ck.tensors().into_iter().find(|t| t.0 == format!("ema.{name}")).unwrap().2.to_vec();
        assert_eq!(optimizer::var_values(&var).unwrap(), want, "{name}");
    }
    // The frozen network runs; the online weights differ from the EMA (warm-up 2, step 3 is odd).
    let x = Tensor::zeros((1, 2, 16, 13), candle_core::DType::F32, &candle_core::Device::Cpu).unwrap();
    let t = Tensor::new(&[10u32], &candle_core::Device::Cpu).unwrap();
    let y = m.denoiser.forward(&x, &t, None).unwrap();
    assert_eq!(y.dims(), &[1, 2, 16, 13]);
    let online = Checkpoint::load_weights(dir.join(checkpoint::TENSORS_FILE), Weights::Online).unwrap();
    let d = (online.denoiser.forward(&x, &t, None).unwrap() - &y).unwrap().abs().unwrap().sum_all().unwrap().to_scalar::<f32>().unwrap();
    assert!(d > 0.0);
    assert_eq!(Checkpoint::load(dir.join(checkpoint::META_FILE)).unwrap().step, 3);

    // A truncated safetensors file: the error names it.
    let st = dir.join(checkpoint::TENSORS_FILE);
    let bytes = std::fs::read(&st).unwrap();
    std::fs::write(&st, &bytes[..bytes.len() / 2]).unwrap();
    let e = Checkpoint::load(&dir).err().unwrap().to_string();
    assert!(e.contains(&st.display().to_string()) && e.contains("truncated"), "{e}");
    // A foreign safetensors file (no socdiff header).
    let foreign =
        safetensors::tensor::serialize([("w", safetensors::tensor::TensorView::new(safetensors::tensor::Dtype::F32, vec![1], &[0u8; 4]).unwrap())], None)
            .unwrap();
    std::fs::write(&st, foreign).unwrap();
    let e = Checkpoint::load(&dir).err().unwrap().to_string();
    assert!(e.contains(&st.display().to_string()) && e.contains("not a socdiff checkpoint"), "{e}");
    // The readable sidecar is informative: edited or missing, the header decides.
    std::fs::write(&st, &bytes).unwrap();
    let meta_path = dir.join(checkpoint::META_FILE);
    let text = std::fs::read_to_string(&meta_path).unwrap();
    std::fs::write(&meta_path, text.replace("\"step\": 3", "\"step\": 6")).unwrap();
    assert_eq!(Checkpoint::load(&dir).unwrap().step, 3);
    std::fs::remove_file(&meta_path).unwrap();
    assert_eq!(Checkpoint::load(&dir).unwrap().step, 3);
    // Weights corrupted on disk (16 values set to 1e6): the checksum refuses them.
    let mut bad = bytes.clone();
    let header = u64::from_le_bytes(bad[..8].try_into().unwrap()) as usize;
    for k in 0..16 {
        let at = 8 + header + 4 * (97 * k + 5);
        bad[at..at + 4].copy_from_slice(&1e6f32.to_le_bytes());
    }
    std::fs::write(&st, &bad).unwrap();
    let e = Checkpoint::load(&dir).err().unwrap().to_string();
    assert!(e.contains(&st.display().to_string()) && e.contains("checksum mismatch") && e.contains("corrupt"), "{e}");
    std::fs::write(&st, &bytes).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn absurd_weights_are_refused_even_with_a_valid_checksum() {
    let ds = small_dataset();
    let dir = temp_dir("absurd");
    run(&ds, &dir, false, Some(tiny(2))).unwrap();
    let ck = Checkpoint::read(&dir).unwrap();
    let online = ck.denoiser(Weights::Online).unwrap();
    let ema = Ema::from_model(ck.denoiser(Weights::Ema).unwrap(), ck.meta.config.ema.clone());
    let (name, var) = ema.model().named_vars().into_iter().next().unwrap();
    let mut v = optimizer::var_values(&var).unwrap();
    v[0] = 1e6;
    optimizer::set_var(&var, v).unwrap();
    let mut adam = Adam::new(online.named_vars(), ck.meta.config.adam.clone()).unwrap();
    adam.restore(ck.meta.step, ck.adam_moments(&online).unwrap()).unwrap();
    super::save_checkpoint(&dir, &ck.meta, &online, ema.model(), &adam).unwrap();
    let e = Checkpoint::load(&dir).err().unwrap().to_string();
    assert!(e.contains(&format!("tensor ema.{name} holds 1000000")) && e.contains("diverged"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_save_keeps_the_previous_checkpoint_and_format_1_still_loads() {
    let ds = small_dataset();
    let dir = temp_dir("prev");
    run(&ds, &dir, false, Some(tiny(6))).unwrap(); // saves at 3 and 6
    assert_eq!(Checkpoint::read_meta(&dir).unwrap().step, 6);
    assert_eq!(Checkpoint::read_meta(&dir.join(checkpoint::PREV_TENSORS_FILE)).unwrap().step, 3);
    assert_eq!(Checkpoint::load(dir.join(checkpoint::PREV_TENSORS_FILE)).unwrap().step, 3);
    let names: Vec<String> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert!(!names.iter().any(|n| n.contains(".tmp-")), "temporary files left: {names:?}");

    // Format 1: the description only in the sidecar, the safetensors header without it.
    let ck = Checkpoint::read(&dir).unwrap();
    let st = dir.join(checkpoint::TENSORS_FILE);
    let bytes = std::fs::read(&st).unwrap();
    let old = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let info = std::collections::HashMap::from([("format".to_string(), checkpoint::FORMAT.to_string()), ("step".to_string(), "6".to_string())]);
    let v1 = safetensors::tensor::serialize(old.tensors(), Some(info)).unwrap();
    std::fs::write(&st, v1).unwrap();
    let mut meta = serde_json::to_value(&ck.meta).unwrap();
    meta["format_version"] = json!(1);
    std::fs::write(dir.join(checkpoint::META_FILE), serde_json::to_string(&meta).unwrap()).unwrap();
    let m = Checkpoint::load(&dir).unwrap();
    assert_eq!((m.step, m.meta.format_version), (6, 1));
    // …where a pair from different saves is still refused.
    meta["step"] = json!(9);
    std::fs::write(dir.join(checkpoint::META_FILE), serde_json::to_string(&meta).unwrap()).unwrap();
    assert!(Checkpoint::load(&dir).err().unwrap().to_string().contains("interrupted"));
    meta["step"] = json!(6);
    std::fs::write(dir.join(checkpoint::META_FILE), serde_json::to_string(&meta).unwrap()).unwrap();
    // A format-1 run resumes, and its next save is format 2.
    let rest = run(&ds, &dir, true, resumed(&dir, 7)).unwrap();
    assert_eq!(rest.last_step, 7);
    assert_eq!(Checkpoint::read_meta(&st).unwrap().format_version, checkpoint::FORMAT_VERSION);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A v- or edm-predicting run trains (with uniform and per-frame levels), resumes exactly, is
/// recorded in the checkpoint and samples through its route; a diffusion config written before the
/// field existed reads as x0, and a resume may not switch the prediction.
#[test]
fn v_prediction_trains_resumes_exactly_and_is_recorded() {
    use crate::diffusion::{DiffusionConfig, Prediction};
    let ds = small_dataset();
    let runs = [
        ("uniform", NoiseLevels::Uniform, Prediction::V),
        ("per-frame", NoiseLevels::PerFrame { monotone: false }, Prediction::V),
        ("edm-uniform", NoiseLevels::Uniform, Prediction::Edm),
        ("edm-per-frame", NoiseLevels::PerFrame { monotone: false }, Prediction::Edm),
    ];
    for (name, noise, prediction) in runs {
        let v = |steps: usize| TrainConfig { noise, diffusion: DiffusionConfig { prediction, ..Default::default() }, ..tiny(steps) };
        let (a, b) = (temp_dir(&format!("v-{name}-a")), temp_dir(&format!("v-{name}-b")));
        let full = run(&ds, &a, false, Some(v(4))).unwrap();
        let x0 = run(&ds, &temp_dir(&format!("x0-{name}")), false, Some(TrainConfig { noise, ..tiny(4) })).unwrap();
        run(&ds, &b, false, Some(v(2))).unwrap();
        let rest = run(&ds, &b, true, resumed(&b, 4)).unwrap();
        assert_eq!(&full.losses[2..], &rest.losses[..], "{name}: resume is not exact");
        assert!(full.losses.iter().all(|l| l.is_finite() && *l > 0.0), "{name}: {:?}", full.losses);
        // The same seed and draws, another objective: other losses.
        assert_ne!(full.losses, x0.losses, "{name}");
        let m = Checkpoint::load(&a).unwrap();
        assert_eq!(m.diffusion.config().prediction, prediction);
        let net = crate::sample::SamplingNet::new(&m.denoiser, &m.diffusion, &candle_core::Device::Cpu).unwrap();
        let shape = [1, 1, 8, m.denoiser.config().feature_dims];
        let x: Vec<f32> = (0..shape.iter().product::<usize>()).map(|i| (i as f32 * 0.3).sin()).collect();
        let mut out = vec![0f32; x.len()];
        crate::sample::X0Model::predict_x0(&net, &x, shape, &[0], None, &mut out).unwrap();
        // At t = 0 (√(1 − ᾱ_0) = 0.0064) x̂0 is the input up to a small correction.
        let worst = x.iter().zip(&out).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(worst < 0.1, "{name}: x̂0 at t = 0 is {worst} from the input");
        let switched = TrainConfig { diffusion: DiffusionConfig::default(), ..resumed(&b, 6).unwrap() };
        assert!(run(&ds, &b, true, Some(switched)).is_err(), "{name}: a resume switched the prediction");
        for d in [a, b, temp_dir(&format!("x0-{name}"))] {
            let _ = std::fs::remove_dir_all(d);
        }
    }
    let mut old = serde_json::to_value(DiffusionConfig::default()).unwrap();
    old.as_object_mut().unwrap().remove("prediction");
    old.as_object_mut().unwrap().remove("sigma_data");
    old.as_object_mut().unwrap().remove("input_scaling");
    old.as_object_mut().unwrap().remove("snr_shift");
    let old: DiffusionConfig = serde_json::from_value(old).unwrap();
    assert_eq!((old.prediction, old.sigma_data, old.input_scaling, old.snr_shift), (Prediction::X0, 0.5, crate::diffusion::InputScaling::None, 1.0));
}

/// A run on the SNR-shifted schedule trains, resumes exactly and loads with the shifted
/// schedule; a resume may not switch the shift.
#[test]
fn snr_shifted_schedule_trains_resumes_exactly_and_is_recorded() {
    use crate::diffusion::DiffusionConfig;
    let ds = small_dataset();
    let shifted = |steps: usize| TrainConfig { diffusion: DiffusionConfig { snr_shift: 2.0, ..Default::default() }, ..tiny(steps) };
    let (a, b, plain) = (temp_dir("shift-a"), temp_dir("shift-b"), temp_dir("shift-plain"));
    let full = run(&ds, &a, false, Some(shifted(4))).unwrap();
    let unshifted = run(&ds, &plain, false, Some(tiny(4))).unwrap();
    run(&ds, &b, false, Some(shifted(2))).unwrap();
    let rest = run(&ds, &b, true, resumed(&b, 4)).unwrap();
    assert_eq!(&full.losses[2..], &rest.losses[..], "resume is not exact");
    // The same draws of t and ε, noised to other levels: other losses.
    assert_ne!(full.losses, unshifted.losses);
    let m = Checkpoint::load(&a).unwrap();
    let expected = socdiff_schedules::NoiseSchedule::default().snr_shifted(2.0).unwrap();
    assert_eq!((m.diffusion.config().snr_shift, m.diffusion.schedule()), (2.0, &expected));
    let switched = TrainConfig { diffusion: DiffusionConfig::default(), ..resumed(&b, 6).unwrap() };
    assert!(run(&ds, &b, true, Some(switched)).is_err(), "a resume switched the shift");
    for d in [a, b, plain] {
        let _ = std::fs::remove_dir_all(d);
    }
}

/// Every noise-level mode trains, resumes exactly (N + resume + N = 2N steps) and is recorded
/// in the checkpoint; a config written before the field existed reads as `uniform`.
#[test]
fn noise_level_modes_train_resume_exactly_and_are_recorded() {
    let ds = small_dataset();
    let mut finals = Vec::new();
    for (name, mode) in [
        ("uniform", NoiseLevels::Uniform),
        ("prefix", NoiseLevels::Prefix),
        ("per-frame", NoiseLevels::PerFrame { monotone: false }),
        ("monotone", NoiseLevels::PerFrame { monotone: true }),
    ] {
        let (a, b) = (temp_dir(&format!("noise-{name}-a")), temp_dir(&format!("noise-{name}-b")));
        let full = run(&ds, &a, false, Some(TrainConfig { noise: mode, ..tiny(4) })).unwrap();
        run(&ds, &b, false, Some(TrainConfig { noise: mode, ..tiny(2) })).unwrap();
        let rest = run(&ds, &b, true, resumed(&b, 4)).unwrap();
        assert_eq!(&full.losses[2..], &rest.losses[..], "{name}: resume is not exact");
        assert!(full.losses.iter().all(|l| l.is_finite() && *l > 0.0), "{name}: {:?}", full.losses);
        let m = Checkpoint::load(&a).unwrap();
        assert_eq!(m.config.noise, mode);
        assert_eq!(m.config.noise.trains_clean_frames(), mode != NoiseLevels::Uniform);
        finals.push(full.losses);
        std::fs::remove_dir_all(&a).unwrap();
        std::fs::remove_dir_all(&b).unwrap();
    }
    // Same seed and data: the modes draw different levels, so the losses differ.
    assert!(finals.windows(2).all(|w| w[0] != w[1]), "{finals:?}");
    let mut old = serde_json::to_value(TrainConfig::default()).unwrap();
    old.as_object_mut().unwrap().remove("noise");
    let cfg: TrainConfig = serde_json::from_value(old).unwrap();
    assert_eq!(cfg.noise, NoiseLevels::Uniform);
    assert_eq!(NoiseLevels::parse("per-frame-monotone").unwrap(), NoiseLevels::PerFrame { monotone: true });
    assert!(NoiseLevels::parse("gaussian").unwrap_err().to_string().contains("uniform, prefix"));
}

#[test]
fn run_directories_are_locked_and_foreign_directories_refused() {
    let ds = small_dataset();
    // A directory with someone else's files.
    let dir = temp_dir("foreign");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("config.json"), "my own config").unwrap();
    let e = run(&ds, &dir, false, Some(tiny(2))).err().unwrap().to_string();
    assert!(e.contains("not a socdiff run directory"), "{e}");
    assert_eq!(std::fs::read_to_string(dir.join("config.json")).unwrap(), "my own config");
    // A run directory held by another writer.
    let run_dir = temp_dir("locked");
    std::fs::create_dir_all(&run_dir).unwrap();
    let lock = crate::files::RunLock::acquire(&run_dir).unwrap();
    let e = run(&ds, &run_dir, false, Some(tiny(2))).err().unwrap().to_string();
    assert!(e.contains("is being written by process"), "{e}");
    drop(lock);
    run(&ds, &run_dir, false, Some(tiny(2))).unwrap();
    // --force starts over; without it a checkpoint is kept.
    assert!(run(&ds, &run_dir, false, Some(tiny(3))).is_err());
    let o = TrainOptions { force: true, ..opts(&run_dir, false, Some(tiny(3))) };
    let s = train(&ds, &o, &mut |_| {}).unwrap();
    assert_eq!((s.first_step, s.last_step), (0, 3));
    // A run that died before its first save (marker and config, no checkpoint) starts over on
    // --resume, from its own config.
    for f in [checkpoint::TENSORS_FILE, checkpoint::PREV_TENSORS_FILE, checkpoint::META_FILE] {
        let _ = std::fs::remove_file(run_dir.join(f));
    }
    let mut notes = Vec::new();
    let s = train(&ds, &opts(&run_dir, true, None), &mut |e| notes.push(format!("{e:?}"))).unwrap();
    assert_eq!((s.first_step, s.last_step, s.config.model.hidden), (0, 3, 16));
    assert!(notes.iter().any(|n| n.contains("starting it over")), "{notes:?}");
    std::fs::remove_dir_all(&dir).unwrap();
    std::fs::remove_dir_all(&run_dir).unwrap();
}

/// A fresh run of `config` into `dir` whose stop flag is raised after step `after` (as a Ctrl-C
/// during the next step would be), with every event it reported.
fn run_stopped_after(ds: &Dataset, dir: &Path, config: TrainConfig, after: u64) -> (TrainSummary, Vec<String>) {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    let mut events = Vec::new();
    let o = TrainOptions { stop: Some(stop), ..opts(dir, false, Some(config)) };
    let s = train(ds, &o, &mut |e| {
        if matches!(e, TrainEvent::Step { step, .. } if *step == after) {
            flag.store(true, Ordering::SeqCst);
        }
        events.push(format!("{e:?}"));
    })
    .unwrap();
    (s, events)
}

#[test]
fn stop_flag_saves_then_resume_finishes() {
    let ds = small_dataset();
    let dir = temp_dir("stop");
    let (s, events) = run_stopped_after(&ds, &dir, TrainConfig { save_every: 100, ..tiny(6) }, 2);
    assert!(s.stopped);
    assert_eq!(s.last_step, 2);
    assert!(events.iter().any(|e| e.starts_with("Saved(CheckpointSaved { step: 2")), "{events:?}");
    assert_eq!(Checkpoint::read_meta(&dir).unwrap().step, 2);
    let rest = run(&ds, &dir, true, None).unwrap();
    assert_eq!((rest.first_step, rest.last_step, rest.stopped), (2, 6, false));
    // The log holds each step once.
    let steps: Vec<u64> =
        log_losses(&dir).iter().filter(|l| l.contains("\"loss\"")).map(|l| serde_json::from_str::<Value>(l).unwrap()["step"].as_u64().unwrap()).collect();
    assert_eq!(steps, (1..=6).collect::<Vec<_>>());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// On the cosine schedule the log's rate is ½(1 + cos(π·s/S))·lr before update s + 1 of S, a
/// stop and resume continues the schedule exactly, and the run's last update has a rate near 0.
#[test]
fn cosine_schedule_is_logged_and_resumes_exactly() {
    use crate::checkpoint::config::LrSchedule;
    let ds = small_dataset();
    let cosine = TrainConfig { adam: AdamConfig { lr: 1e-3, schedule: LrSchedule::Cosine, ..Default::default() }, save_every: 100, ..tiny(6) };
    let (a, b, flat) = (temp_dir("cos-a"), temp_dir("cos-b"), temp_dir("cos-flat"));
    let full = run(&ds, &a, false, Some(cosine.clone())).unwrap();
    let constant = run(&ds, &flat, false, Some(TrainConfig { adam: AdamConfig { lr: 1e-3, ..Default::default() }, ..cosine.clone() })).unwrap();
    // The first update has the same rate; the later ones are slower, so the losses part.
    assert_eq!(full.losses[..2], constant.losses[..2]);
    assert_ne!(full.losses[2..], constant.losses[2..]);
    let rates: Vec<f64> = std::fs::read_to_string(a.join(checkpoint::LOG_FILE))
        .unwrap()
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).unwrap()["lr"].as_f64())
        .collect();
    let expected: Vec<f64> = (0..6).map(|s| 1e-3 * 0.5 * (1.0 + (std::f64::consts::PI * s as f64 / 6.0).cos())).collect();
    assert_eq!(rates.len(), 6);
    for (got, want) in rates.iter().zip(&expected) {
        assert!((got - want).abs() < 1e-15, "rates {rates:?}, expected {expected:?}");
    }
    // Stopped after step 2 (the schedule still spans 6), then resumed: the same 6 steps.
    let (half, _) = run_stopped_after(&ds, &b, cosine, 2);
    let rest = run(&ds, &b, true, None).unwrap();
    let joined: Vec<f32> = half.losses.iter().chain(&rest.losses).copied().collect();
    assert_eq!(joined, full.losses, "2 + resume + 4 steps must give the losses of 6 on the same schedule");
    assert_eq!(log_losses(&a), log_losses(&b));
    for d in [a, b, flat] {
        std::fs::remove_dir_all(d).unwrap();
    }
}

// ---------------------------------------------------------------------------------------------
// Social channel: a follower repeats a leader's motion with a lag.
// ---------------------------------------------------------------------------------------------

/// One episode of `window` frames ([`crate::data::synthetic::leader_follower_scene`], 1 m/s,
/// 1.5 m apart) on the tiny skeleton: the follower's observed past (standing still) says nothing
/// about where or when it will go, the leader's says both. The leader is taller (head 1.8 m vs
/// 1.5 m), so each person can tell its role from its own pose.
fn leader_follower_scene(name: &str, window: usize, observed: usize, lag: usize, seed: u64) -> Scene {
    use crate::data::synthetic::LeaderFollower;
    let [leader, follower] = [1.8, 1.5].map(|head| [-0.1, 0.0, 0.9, 0.1, 0.0, 0.9, 0.0, 0.0, head]);
    let lf = LeaderFollower { frames: window, observed, lag, speed: 1.0 / 30.0, spacing: 1.5 };
    crate::data::synthetic::leader_follower_scene(&tiny_skeleton(), [&leader, &follower], 30.0, &lf, name, seed).unwrap()
}

/// Knobs of the social-channel experiment.
struct SocialTask {
    window: usize,
    observed: usize,
    lag: usize,
    train_scenes: usize,
    test_scenes: usize,
    steps: usize,
    hidden: usize,
    batch: usize,
    lr: f64,
    ddim_steps: usize,
    samples: usize,
}

/// Trains one model per aggregator on leader/follower episodes and returns, per aggregator,
/// the mean error (metres) of the follower's root over the forecast frames, forecast by DDIM
/// (η = 0, `replace`) inpainting of every unobserved frame of both persons.
fn social_errors(task: &SocialTask, aggregators: &[(&str, Aggregator)]) -> Vec<(String, f64)> {
    use crate::features::PoseFeatures;
    use crate::sample::{forecast_mask, inpaint, InpaintOptions, Known};
    let episode = |name: String, seed: u64| leader_follower_scene(&name, task.window, task.observed, task.lag, seed);
    let mut seqs: Vec<(Split, Scene)> = (0..task.train_scenes).map(|i| (Split::Train, episode(format!("train{i}"), 100 + i as u64))).collect();
    let test: Vec<Scene> = (0..task.test_scenes).map(|i| episode(format!("test{i}"), 900_000 + i as u64)).collect();
    seqs.extend(test.iter().map(|s| (Split::Test, s.clone())));
    let ds = dataset("leader-follower", seqs);
    let mut out = Vec::new();
    for (name, agg) in aggregators {
        let dir = temp_dir(&format!("social-{name}"));
        let h = task.hidden;
        let config = TrainConfig {
            model: DenoiserConfig { hidden: h, time_dim: 2 * h, fourier_dim: 16, social_dim: h, aggregator: *agg, ..Default::default() },
            steps: task.steps,
            batch: task.batch,
            window: task.window,
            stride: task.window,
            observed: Some(task.observed),
            seed: 1,
            adam: AdamConfig { lr: task.lr, ..Default::default() },
            ema: EmaConfig { warmup_steps: task.steps, ..Default::default() },
            save_every: task.steps,
            val_every: 0,
            ..Default::default()
        };
        let started = Instant::now();
        let summary = run(&ds, &dir, false, Some(config)).unwrap();
        let train_secs = started.elapsed().as_secs_f64();
        let m = Checkpoint::load(&dir).unwrap();
        let sampler = socdiff_schedules::Ddim::new(m.diffusion.schedule(), task.ddim_steps, 0.0).unwrap();
        let (mut err, mut n) = (0.0f64, 0usize);
        for (i, scene) in test.iter().enumerate() {
            let feats = PoseFeatures::encode(scene, 0..task.window, &[0, 1], task.observed - 1).unwrap();
            let mut known = feats.data.clone();
            m.standardization.apply(&mut known).unwrap();
            let mask = forecast_mask(task.window, 2, 13, task.observed);
            let anchors = ndarray::Array2::from_shape_fn((2, 4), |(p, k)| {
                let a = feats.anchors[p];
                [a.root[0], a.root[1], a.heading.cos(), a.heading.sin()][k] as f32
            });
            let k = Known { values: known.view(), mask: mask.view(), anchors: Some(anchors.view()) };
            let opts = InpaintOptions { samples: task.samples, seed: i as u64, ..Default::default() };
            let mut x = inpaint(&m.denoiser, &sampler, &k, &opts).unwrap();
            m.standardization.invert(&mut x).unwrap();
            for smp in 0..task.samples {
                for f in task.observed..task.window {
                    let (dx, dy) = (x[[smp, f, 1, 0]] - feats.data[[f, 1, 0]], x[[smp, f, 1, 1]] - feats.data[[f, 1, 1]]);
                    err += (dx as f64).hypot(dy as f64);
                    n += 1;
                }
            }
        }
        let err = err / n as f64;
        let tail = summary.losses.iter().rev().take(50).sum::<f32>() / 50f32.min(summary.losses.len() as f32);
        println!(
            "social channel, {name}: follower root error {err:.4} m over {} forecast frames; loss (last 50 steps) {tail:.4}; training {train_secs:.1} s",
            task.window - task.observed
        );
        out.push((name.to_string(), err));
        std::fs::remove_dir_all(&dir).unwrap();
    }
    out
}

fn env_or(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

const AGGREGATORS: [(&str, Aggregator); 3] = [("none", Aggregator::None), ("mean", Aggregator::Mean), ("attention", Aggregator::Attention { heads: 2 })];

fn aggregators(names: &[&str]) -> Vec<(&'static str, Aggregator)> {
    let only = std::env::var("SOCIAL_ONLY").ok();
    AGGREGATORS.iter().filter(|(n, _)| names.contains(n) && only.as_deref().is_none_or(|o| o.split(',').any(|x| x == *n))).map(|(n, a)| (*n, *a)).collect()
}

/// The required check (METHOD.md §3): `mean` and `attention` see the leader, `none` does not.
#[test]
#[ignore = "trains three models (minutes); the default suite runs social_channel_quick"]
fn social_channel_mean_and_attention_beat_none() {
    let task = SocialTask {
        window: env_or("SOCIAL_WINDOW", 64),
        observed: env_or("SOCIAL_OBSERVED", 32),
        lag: env_or("SOCIAL_LAG", 16),
        train_scenes: env_or("SOCIAL_TRAIN", 512),
        test_scenes: env_or("SOCIAL_TEST", 32),
        steps: env_or("SOCIAL_STEPS", 1500),
        hidden: env_or("SOCIAL_HIDDEN", 32),
        batch: env_or("SOCIAL_BATCH", 16),
        lr: std::env::var("SOCIAL_LR").ok().and_then(|v| v.parse().ok()).unwrap_or(2e-3),
        ddim_steps: env_or("SOCIAL_DDIM", 25),
        samples: env_or("SOCIAL_SAMPLES", 2),
    };
    let errs = social_errors(&task, &aggregators(&["none", "mean", "attention"]));
    let none = errs[0].1;
    for (name, e) in &errs[1..] {
        println!("social channel: none / {name} = {:.2}", none / e);
        assert!(none / e > 3.0, "{name}: error {e:.4} m vs none {none:.4} m");
    }
}

/// A quicker version of [`social_channel_mean_and_attention_beat_none`] for the default suite
/// (≈ 30 s): hidden 16, 400 steps, one sample per test episode, and the bar of 3× (measured on
/// the project machine: none 0.43–0.50 m, mean 0.10–0.11 m (3.9–4.9×), attention 0.08 m (5.4–5.9×)).
#[test]
fn social_channel_quick() {
    let task = SocialTask {
        window: env_or("SOCIAL_WINDOW", 64),
        observed: env_or("SOCIAL_OBSERVED", 32),
        lag: env_or("SOCIAL_LAG", 16),
        train_scenes: env_or("SOCIAL_TRAIN", 512),
        test_scenes: 16,
        steps: env_or("SOCIAL_STEPS", 400),
        hidden: 16,
        batch: 16,
        lr: 2e-3,
        ddim_steps: env_or("SOCIAL_DDIM", 20),
        samples: 1,
    };
    let errs = social_errors(&task, &aggregators(&["none", "mean", "attention"]));
    let none = errs[0].1;
    for (name, e) in &errs[1..] {
        println!("social channel (quick): none / {name} = {:.2}", none / e);
        assert!(none / e >= 3.0, "{name}: error {e:.4} m vs none {none:.4} m");
    }
}

#[test]
fn validation_shortens_windows_to_fit_short_test_sequences() {
    // Test scene of 21 frames, training window 24: validation runs on 16-frame windows.
    let ds = dataset("short-test", vec![(Split::Train, walking_scene("w1", 48, 2, 1)), (Split::Test, walking_scene("t1", 21, 2, 3))]);
    let dir = temp_dir("short-val");
    let mut notices = Vec::new();
    let short = TrainConfig { window: 24, observed: Some(6), val_every: 1, ..tiny(2) };
    let summary = train(&ds, &opts(&dir, false, Some(short.clone())), &mut |e| {
        if let TrainEvent::Notice(n) = e {
            notices.push(n.clone());
        }
    })
    .unwrap();
    assert_eq!(summary.val_losses.len(), 2);
    assert!(summary.val_losses.iter().all(|(_, l)| l.is_finite() && *l > 0.0));
    assert!(notices.iter().any(|n| n.contains("windows of 16 frames")), "{notices:?}");
    // A test split too short even for the observed frames gives no validation, with a notice.
    let ds = dataset("tiny-test", vec![(Split::Train, walking_scene("w1", 48, 2, 1)), (Split::Test, walking_scene("t1", 7, 2, 3))]);
    let dir = temp_dir("no-val");
    let summary = run(&ds, &dir, false, Some(short)).unwrap();
    assert!(summary.val_losses.is_empty());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Body-proportion augmentation: every bone scaled by its limb's factor (left and right alike),
/// the body-frame midpoint kept on its ground position and the lowest foot on its height; a
/// factor of 1 changes nothing; the draws are seeded.
#[test]
fn bone_scaling_scales_each_limb_and_keeps_the_person_in_place() {
    let sk = Skeleton::mupots17();
    let mut rng = StdRng::seed_from_u64(3);
    let pos = Array4::from_shape_fn((4, 2, 17, 3), |(_, _, j, k)| if k == 2 { 0.05 * j as f32 + rng.gen_range(0.0..0.1) } else { rng.gen_range(-0.5..0.5) });
    let scene = Scene::new("s", 30.0, sk.clone(), pos).unwrap();
    let scaler = data::BoneScaler::new(&sk);
    let aug = AugmentConfig { body_scale: 0.1, limb_scale: 0.05, ..Default::default() };
    let factors: Vec<Vec<f32>> = (0..2).map(|_| scaler.draw(&aug, &mut stream_rng(1, Stream::Augment, 0))).collect();
    assert_eq!(factors[0], scaler.draw(&aug, &mut stream_rng(1, Stream::Augment, 0)), "seeded");
    assert!(factors[0].iter().all(|f| (0.9 * 0.95..=1.1 * 1.05).contains(f)), "{:?}", factors[0]);
    let mut scaled = scene.clone();
    scaler.apply(&mut scaled, &factors);
    let len = |s: &Scene, t: usize, p: usize, (a, b): (usize, usize)| {
        (0..3).map(|k| (s.positions[[t, p, a, k]] - s.positions[[t, p, b, k]]).powi(2)).sum::<f32>().sqrt()
    };
    let ratio = |name_a: &str, name_b: &str| {
        let (a, b) = (sk.joint_index(name_a).unwrap(), sk.joint_index(name_b).unwrap());
        len(&scaled, 2, 0, (a, b)) / len(&scene, 2, 0, (a, b))
    };
    // Left and right counterparts share one factor; other limbs have their own.
    assert!((ratio("left_knee", "left_ankle") - ratio("right_knee", "right_ankle")).abs() < 1e-5);
    assert!((ratio("left_elbow", "left_wrist") - ratio("right_elbow", "right_wrist")).abs() < 1e-5);
    assert!((ratio("left_knee", "left_ankle") - ratio("left_elbow", "left_wrist")).abs() > 1e-4);
    for &(a, b) in &sk.bones {
        let r = len(&scaled, 1, 1, (a, b)) / len(&scene, 1, 1, (a, b));
        assert!(factors[1].iter().any(|f| (f - r).abs() < 1e-4), "bone {a}–{b}: ratio {r} is no limb factor");
    }
    let feet = sk.foot_joints();
    for t in 0..4 {
        for p in 0..2 {
            for k in 0..2 {
                let mid = |s: &Scene| 0.5 * (s.positions[[t, p, sk.left, k]] + s.positions[[t, p, sk.right, k]]);
                assert!((mid(&scene) - mid(&scaled)).abs() < 1e-5);
            }
            let low = |s: &Scene| feet.iter().map(|&j| s.positions[[t, p, j, 2]]).fold(f32::INFINITY, f32::min);
            assert!((low(&scene) - low(&scaled)).abs() < 1e-5);
        }
    }
    let mut same = scene.clone();
    scaler.apply(&mut same, &[vec![1.0; factors[0].len()], vec![1.0; factors[0].len()]]);
    assert!(same.positions.iter().zip(scene.positions.iter()).all(|(a, b)| (a - b).abs() < 1e-6));
    // Training with it runs and stays reproducible.
    let ds = small_dataset();
    let (a, b) = (temp_dir("bones-a"), temp_dir("bones-b"));
    let scaled = TrainConfig { augment: AugmentConfig { body_scale: 0.1, limb_scale: 0.05, ..Default::default() }, ..tiny(3) };
    let x = run(&ds, &a, false, Some(scaled.clone())).unwrap();
    let y = run(&ds, &b, false, Some(scaled)).unwrap();
    let plain = run(&ds, &temp_dir("bones-c"), false, Some(tiny(3))).unwrap();
    assert_eq!(x.losses, y.losses);
    assert_ne!(x.losses, plain.losses);
}

/// The training step on the composed kernels (the route every GPU takes) follows the custom
/// CPU kernels step by step: same seeded batch, levels and noise, losses within 1e-4 after 8
/// Adam + EMA updates (the kernels differ only in rounding), for every aggregator.
#[test]
fn training_on_composed_kernels_follows_the_custom_kernels() {
    use crate::model::{Kernels, Placement, Precision};
    for aggregator in [Aggregator::None, Aggregator::Mean, Aggregator::Attention { heads: 2 }] {
        let cfg = DenoiserConfig { feature_dims: 13, hidden: 16, time_dim: 16, fourier_dim: 8, social_dim: 16, aggregator, ..Default::default() };
        let composed = Placement { kernels: Kernels::Composed(Precision::F32), ..Placement::cpu() };
        let a = time_train_steps(&cfg, 3, 2, 24, 8, &Placement::cpu()).unwrap();
        let b = time_train_steps(&cfg, 3, 2, 24, 8, &composed).unwrap();
        assert_eq!((a.device.as_str(), b.device.as_str()), ("cpu f32 custom", "cpu f32 composed"));
        for (step, (x, y)) in a.losses.iter().zip(&b.losses).enumerate() {
            let d = ((x - y) / x).abs();
            assert!(d < 1e-4, "{aggregator:?} step {step}: custom {x} vs composed {y}");
        }
        // The losses moved: the steps trained something.
        assert!(a.losses[0] != a.losses[7], "{aggregator:?}: {:?}", a.losses);
    }
}

/// A checkpoint records where it was trained and loads at any placement with the same weights.
#[test]
fn checkpoints_record_the_device_and_load_at_any_placement() {
    use crate::model::{Kernels, Placement, Precision};
    let dir = temp_dir("device");
    run(&small_dataset(), &dir, false, Some(tiny(3))).unwrap();
    let ck = Checkpoint::read(&dir).unwrap();
    assert_eq!(ck.meta.device, "cpu f32 custom");
    let composed = Placement { kernels: Kernels::Composed(Precision::F32), ..Placement::cpu() };
    let (a, b) = (ck.denoiser(Weights::Ema).unwrap(), ck.denoiser_at(Weights::Ema, &composed).unwrap());
    assert_eq!(b.placement().describe(), "cpu f32 composed");
    for ((n, x), (_, y)) in a.named_vars().iter().zip(b.named_vars()) {
        assert_eq!(optimizer::var_values(x).unwrap(), optimizer::var_values(&y).unwrap(), "{n}");
    }
    // Sidecars written before the device was recorded still load.
    let meta_path = dir.join(checkpoint::META_FILE);
    let mut meta: Value = serde_json::from_str(&std::fs::read_to_string(&meta_path).unwrap()).unwrap();
    meta.as_object_mut().unwrap().remove("device");
    assert_eq!(serde_json::from_value::<CheckpointMeta>(meta).unwrap().device, "");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn devices_parse_and_a_gpu_without_cuda_is_a_clear_error() {
    use crate::model::DeviceChoice;
    for (text, want) in [("cpu", DeviceChoice::Cpu), ("cuda", DeviceChoice::Cuda(0)), ("cuda:3", DeviceChoice::Cuda(3)), ("auto", DeviceChoice::Auto)] {
        let got: DeviceChoice = text.parse().unwrap();
        assert_eq!(got, want);
        assert_eq!(got.to_string().parse::<DeviceChoice>().unwrap(), want);
    }
    for bad in ["gpu", "cuda:", "cuda:x", "CPU"] {
        assert!(bad.parse::<DeviceChoice>().unwrap_err().to_string().contains("cpu, cuda, cuda:N, auto"), "{bad}");
    }
    if !DeviceChoice::CUDA_BUILT {
        let e = DeviceChoice::Cuda(0).resolve().unwrap_err().to_string();
        assert!(e.contains("built without CUDA") && e.contains("scripts/build-cuda.sh"), "{e}");
        assert!(DeviceChoice::Auto.resolve().unwrap().is_cpu());
    }
    let e = DeviceChoice::Cpu.placement(crate::model::Precision::Bf16).unwrap_err().to_string();
    assert!(e.contains("bf16"), "{e}");
}

#[test]
fn init_starts_from_a_models_inference_weights_and_refuses_what_does_not_fit() {
    let ds = small_dataset();
    let src = temp_dir("init-src");
    run(&ds, &src, false, Some(tiny(3))).unwrap();
    // The inference file: the EMA weights alone, the checkpoint's description and step.
    let model = Checkpoint::read(&src.join(checkpoint::MODEL_FILE)).unwrap();
    let full = Checkpoint::read(&src).unwrap();
    assert_eq!(model.meta.step, 3);
    assert!(model.tensors().iter().all(|(n, _, _)| n.starts_with(checkpoint::PREFIX_EMA)));
    let ema_full: Vec<_> = full.tensors().into_iter().filter(|(n, _, _)| n.starts_with(checkpoint::PREFIX_EMA)).collect();
    assert_eq!(model.tensors(), ema_full);
    assert!(Checkpoint::load_weights(src.join(checkpoint::MODEL_FILE), Weights::Online).is_err(), "no online weights to resume from");

    // At step 0 a fine-tuning learner holds the source's EMA weights, online and EMA alike.
    let learner = Learner::initialized(&model, &tiny(3), &crate::model::Placement::cpu()).unwrap();
    assert_eq!(learner.step(), 0);
    let want = model.denoiser(Weights::Ema).unwrap();
    let values = |net: &Denoiser| -> Vec<Vec<f32>> { net.named_vars().iter().map(|(_, v)| optimizer::var_values(v).unwrap()).collect() };
    assert_eq!(values(learner.model()), values(&want));
    assert_eq!(values(learner.ema()), values(&want));

    // Through `train`: recorded in the checkpoint, the source's feature scaling kept.
    let tuned = temp_dir("init-tuned");
    let with_init = |dir: &Path, cfg: TrainConfig, data: &Dataset| {
        train(data, &TrainOptions { init: Some(src.join(checkpoint::MODEL_FILE)), ..opts(dir, false, Some(cfg)) }, &mut |_| {})
    };
    with_init(&tuned, tiny(2), &ds).unwrap();
    let meta = Checkpoint::read_meta(&tuned).unwrap();
    assert_eq!(meta.step, 2);
    assert!(meta.init.as_deref().is_some_and(|s| s.ends_with("model.safetensors (step 3)")), "{:?}", meta.init);
    assert_eq!(meta.standardization, model.meta.standardization);

    // Another width, or data on another skeleton: one error naming the model file, nothing written.
    let wider = TrainConfig { model: DenoiserConfig { hidden: 32, ..tiny(2).model }, ..tiny(2) };
    let bad = temp_dir("init-bad");
    let e = with_init(&bad, wider, &ds).unwrap_err().to_string();
    assert!(e.contains("model.safetensors") && e.contains("hidden 16") && e.contains("hidden 32"), "{e}");
    let other = Skeleton::new("other", vec!["a".into(), "b".into(), "head".into()], vec![(0, 2), (1, 2)], 0, 1).unwrap();
    let mut moved = walking_scene("w", 40, 2, 1);
    moved.skeleton = other;
    let e = with_init(&bad, tiny(2), &dataset("other", vec![(Split::Train, moved)])).unwrap_err().to_string();
    assert!(e.contains("model.safetensors") && e.contains("does not fit"), "{e}");
    assert!(!bad.join(checkpoint::TENSORS_FILE).exists());
    for d in [src, tuned, bad] {
        let _ = std::fs::remove_dir_all(d);
    }
}
