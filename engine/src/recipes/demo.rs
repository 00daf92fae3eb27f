//! The whole pipeline in one call (`socdiff demo`): data → model → forecast → HTML view →
//! evaluation report, on an embedded scene (no downloads) or on a dataset. The model is the
//! bundled pretrained one ([`PRETRAINED`], no training), or with [`Demo::train`] a small model
//! trained on the data's train split first.
//!
//! The embedded default is the bundled CMU clip 18_01 (real motion capture, redistributable;
//! `examples/data/ATTRIBUTION.md`) mapped onto the MuPoTS-17 skeleton by joint names and turned
//! into groups of three: each person performs the clip from a random frame, looping with blended
//! joins, placed around a shared centre ([`crate::data::synthetic`]). Seeds 1–4 make the train
//! groups, seed 100 the test group.

use super::{evaluate, write_view, Protocol, Runner};
use crate::checkpoint::Checkpoint;
use crate::data::bvh::{parse_bvh, BvhImport, CMU_SCALE};
use crate::data::dataset::{write_dataset, Sequence};
use crate::data::joint_map::JointMap;
use crate::data::synthetic::{synthetic_groups, GroupConfig};
use crate::files::{write_file_atomic, RunLock};
use crate::model::{Aggregator, DenoiserConfig, DeviceChoice};
use crate::train::{EmaConfig, TrainConfig, TrainOptions};
use crate::{bail, Dataset, Error, Result, Scene, Skeleton, Split};
use serde_json::{json, Value};
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// The bundled CMU clip (subject 18, trial 1; 30 fps, 303 frames).
const CMU_CLIP: &str = include_str!("../../../examples/data/cmu_18_01.bvh");

/// The bundled pretrained model's inference weights (`models/groups-mrt15/model.safetensors`,
/// model card beside it): groups of 2–3 persons on MRT's 15 joints at 30 fps, trained without
/// MuPoTS.
pub const PRETRAINED: &[u8] = include_bytes!("../../../models/groups-mrt15/model.safetensors");

/// Where [`PRETRAINED`] lives in the repository.
pub const PRETRAINED_PATH: &str = "models/groups-mrt15/model.safetensors";

/// File marking a folder as a demo's output.
const MARKER: &str = ".socdiff-demo";

/// The embedded scene as a dataset: 4 train groups and 1 test group of 3 persons.
pub fn embedded_dataset() -> Result<Dataset> {
    let opts = BvhImport { scale: CMU_SCALE, include_end_sites: true, ..Default::default() };
    let clip = parse_bvh(CMU_CLIP)?.to_scene("cmu_18_01", &opts)?;
    let map = JointMap::by_names(&clip.skeleton, &Skeleton::mupots17(), &[])?;
    let clip = map.apply(&clip)?;
    let groups = |seed: u64, count: usize, name: &str| {
        let cfg = GroupConfig { persons_min: 3, persons_max: 3, frames: 300, seed, ..Default::default() };
        synthetic_groups(std::slice::from_ref(&clip), count, name, &cfg)
    };
    let mut sequences: Vec<Sequence> = groups(1, 4, "train")?.into_iter().map(|scene| Sequence { split: Split::Train, scene }).collect();
    sequences.extend(groups(100, 1, "test")?.into_iter().map(|scene| Sequence { split: Split::Test, scene }));
    let mut metadata = serde_json::Map::new();
    metadata.insert("source".into(), "CMU Graphics Lab Motion Capture Database, subject 18 trial 1 (examples/data/ATTRIBUTION.md)".into());
    metadata.insert(
        "construction".into(),
        "the clip mapped onto MuPoTS-17 by joint names; groups of 3 persons, each looping the clip from a random frame around a shared centre".into(),
    );
    Ok(Dataset { name: "cmu-groups".into(), sequences, metadata })
}

/// A demo run.
#[derive(Clone, Debug)]
pub struct Demo {
    /// Output folder: data/, model/, forecast/, forecast.html, report.json, report.txt.
    pub out: PathBuf,
    /// Where `dataset` came from (`None`: the embedded scene).
    pub data: Option<PathBuf>,
    /// Forecast only the test sequences of these names (empty: all).
    pub sequences: Vec<String>,
    /// Train a small model on the train split first (`steps`, `hidden`, `window`, `batch`)
    /// instead of forecasting with the bundled pretrained model.
    pub train: bool,
    /// Training steps.
    pub steps: usize,
    /// U-Net width.
    pub hidden: usize,
    /// Frames per training window.
    pub window: usize,
    /// Windows per batch.
    pub batch: usize,
    /// Observed frames of each forecast.
    pub observe: usize,
    /// Forecast frames.
    pub horizon: usize,
    /// Samples per forecast.
    pub samples: usize,
    /// DDIM steps.
    pub sampling_steps: usize,
    /// Seed of training and sampling.
    pub seed: u64,
    /// Continue in an existing `out` (training resumes; forecast, view and report are redone).
    pub resume: bool,
    /// Where the network runs.
    pub device: DeviceChoice,
    /// Set to stop training after the current step (a checkpoint is saved first).
    pub stop: Option<Arc<AtomicBool>>,
}

/// What [`run_demo`] did.
#[derive(Clone, Debug)]
pub struct DemoOutcome {
    /// Training was stopped (by [`Demo::stop`]) before the forecast: continue with `resume`.
    pub stopped: bool,
    /// The report's table (empty when stopped).
    pub table: String,
}

/// Runs the demo on `dataset` (train split for training, test split for forecasts).
pub fn run_demo(dataset: &Dataset, demo: &Demo, runner: &mut dyn Runner) -> Result<DemoOutcome> {
    let d = demo;
    // A device that cannot run is an error before anything is written.
    d.device.resolve()?;
    let out = &d.out;
    if out.exists() && !out.is_dir() {
        return Err(Error::format(out, "exists and is not a directory"));
    }
    let non_empty = out.is_dir() && std::fs::read_dir(out).map_err(|e| Error::io(out, e))?.next().is_some();
    if non_empty && !d.resume {
        return Err(Error::format(out, "exists and is not empty; pass `resume` to continue it, or choose another `out`"));
    }
    // Resuming continues a demo's folder only (it replaces its forecast/, view and report).
    if non_empty && !out.join(MARKER).is_file() && !Checkpoint::exists_in(&out.join("model")) {
        return Err(Error::format(out, "`resume`: is not a socdiff demo folder; refusing to write into it"));
    }
    for (name, v) in [("steps", d.steps), ("samples", d.samples), ("sampling_steps", d.sampling_steps), ("observe", d.observe), ("horizon", d.horizon)] {
        if v == 0 {
            bail!("`{name}` must be at least 1");
        }
    }

    // 1. Data.
    let test: Vec<Scene> = dataset.split(Split::Test).filter(|s| d.sequences.is_empty() || d.sequences.contains(&s.name)).cloned().collect();
    if dataset.split(Split::Train).next().is_none() || test.is_empty() {
        let what = d.data.as_ref().map_or("the embedded scene".to_string(), |p| p.display().to_string());
        let named = if d.sequences.is_empty() { String::new() } else { format!(" (test sequences named {})", d.sequences.join(", ")) };
        bail!("{what}: the demo needs train and test sequences{named}");
    }
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let _lock = RunLock::acquire(out)?;
    write_file_atomic(&out.join(MARKER), b"socdiff demo output\n")?;
    let data_dir = out.join("data");
    if !data_dir.exists() {
        write_dataset(dataset, &data_dir)?;
    }
    let frames: usize = dataset.split(Split::Train).map(|s| s.num_frames() * s.num_persons()).sum();
    runner.say(&format!(
        "1/5 data: {} — {} train / {} test sequences, {frames} train person-frames, {} joints at {} fps → {}",
        dataset.name,
        dataset.split(Split::Train).count(),
        test.len(),
        test[0].num_joints(),
        test[0].fps,
        data_dir.display()
    ));

    // 2. The model: the bundled one, or train (or continue) a small one.
    let model_dir = out.join("model");
    let model = if d.train {
        train_small(dataset, d, &model_dir, runner)?
    } else {
        let path = model_dir.join(crate::checkpoint::MODEL_FILE);
        if !path.is_file() {
            std::fs::create_dir_all(&model_dir).map_err(|e| Error::io(&model_dir, e))?;
            write_file_atomic(&path, PRETRAINED)?;
        }
        let model = Checkpoint::load(&path)?;
        runner.say(&format!("2/5 model: the bundled pretrained model ({PRETRAINED_PATH}, step {}) → {}", model.step, path.display()));
        Some(model)
    };
    let Some(model) = model else {
        return Ok(DemoOutcome { stopped: true, table: String::new() });
    };
    // Scenes on another skeleton go onto the model's by joint names (e.g. MuPoTS-17 onto MRT's 15).
    let test: Vec<Scene> = test.iter().map(|s| Ok(model.fit_scene(s, true)?.0)).collect::<Result<_>>()?;

    // 3. Forecast the test scenes.
    let proto = Protocol { device: d.device, ..Protocol::ddim(d.observe, d.horizon, d.samples, d.sampling_steps, d.seed) };
    let usable: Vec<Scene> = test.iter().filter(|s| s.num_frames() > d.observe).cloned().collect();
    if usable.is_empty() {
        bail!("no test sequence is longer than `observe` {} frames", d.observe);
    }
    runner.say(&format!(
        "3/5 forecast: {} test scene(s), {} samples of {} frames after {} observed, DDIM {} steps",
        usable.len(),
        d.samples,
        d.horizon,
        d.observe,
        d.sampling_steps
    ));
    let runs = runner.forecast(&model, &usable, &proto)?;
    let fc_dir = out.join("forecast");
    if fc_dir.exists() {
        std::fs::remove_dir_all(&fc_dir).map_err(|e| Error::io(&fc_dir, e))?;
    }
    let sequences = runs.iter().flat_map(|x| x.forecast.to_dataset().sequences).collect();
    write_dataset(&Dataset { name: format!("{}_forecast", dataset.name), sequences, metadata: Default::default() }, &fc_dir)?;

    // 4. View.
    let html = out.join("forecast.html");
    write_view(&runs, &html, &format!("socdiff demo: {}", dataset.name))?;
    runner.say(&format!("4/5 view: {} (open it in a browser)", html.display()));

    // 5. Report.
    let report = evaluate(&runs, &test, &Default::default())?;
    let settings = json!({
        "data": d.data.as_ref().map_or("embedded CMU clip groups".to_string(), |p| p.display().to_string()),
        "model": if d.train { model.path.display().to_string() } else { PRETRAINED_PATH.to_string() },
        "train": serde_json::to_value(&model.config).unwrap_or(Value::Null), "observe": d.observe, "horizon": d.horizon, "samples": d.samples,
        "sampler": proto.request.sampler, "seed": d.seed, "model_step": model.step,
    });
    let table = report.write_to(out, settings)?;
    runner.say(&format!("5/5 report: {} and report.txt", out.join("report.json").display()));
    Ok(DemoOutcome { stopped: false, table })
}

/// Trains (or continues) the demo's small model in `model_dir`; `None` when stopped.
fn train_small(dataset: &Dataset, d: &Demo, model_dir: &std::path::Path, runner: &mut dyn Runner) -> Result<Option<crate::checkpoint::LoadedModel>> {
    let config = TrainConfig {
        steps: d.steps,
        batch: d.batch,
        window: d.window,
        stride: 4,
        seed: d.seed,
        model: DenoiserConfig { hidden: d.hidden, social_dim: d.hidden, aggregator: Aggregator::Mean, ..Default::default() },
        save_every: 100,
        val_every: 100,
        val_windows: 32,
        ema: EmaConfig { warmup_steps: 50, ..Default::default() },
        ..Default::default()
    };
    runner.say(&format!(
        "2/5 train: {} steps, hidden {}, window {}, batch {}, seed {} → {}",
        d.steps,
        d.hidden,
        d.window,
        d.batch,
        d.seed,
        model_dir.display()
    ));
    let opts = TrainOptions {
        out_dir: model_dir.to_path_buf(),
        resume: Checkpoint::exists_in(model_dir),
        config: Some(config),
        source: dataset.name.clone(),
        stop: d.stop.clone(),
        device: d.device,
        ..Default::default()
    };
    if runner.train(dataset, &opts)?.stopped {
        return Ok(None);
    }
    Ok(Some(Checkpoint::load(model_dir)?))
}
