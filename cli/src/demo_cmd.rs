//! `socdiff demo`: the whole pipeline in one command — data → train → forecast → HTML view →
//! evaluation report — on an embedded scene (no downloads) or on a dataset (`--data`).
//!
//! The embedded default is the bundled CMU clip 18_01 (real motion capture, redistributable;
//! `examples/data/ATTRIBUTION.md`) mapped onto the MuPoTS-17 skeleton by joint names and turned
//! into groups of three: each person performs the clip from a random frame, looping with blended
//! joins, placed around a shared centre (`socdiff_engine::data::synthetic`). Seeds 1–4 make the
//! train groups, seed 100 the test group.

use crate::train_cmd::{stop_flag, train_with_progress, EXIT_STOPPED};
use clap::Args;
use serde_json::{json, Value};
use socdiff_engine::data::bvh::{parse_bvh, BvhImport, CMU_SCALE};
use socdiff_engine::data::dataset::{write_dataset, Sequence};
use socdiff_engine::data::import;
use socdiff_engine::data::joint_map::JointMap;
use socdiff_engine::data::synthetic::{synthetic_groups, GroupConfig};
use socdiff_engine::export::write_file_atomic;
use socdiff_engine::files::RunLock;
use socdiff_engine::forecast::SamplerKind;
use socdiff_engine::model::{Aggregator, DenoiserConfig};
use socdiff_engine::recipes::{evaluate, forecast_scenes, write_view, Protocol, SceneForecast};
use socdiff_engine::train::checkpoint::{Checkpoint, LoadedModel};
use socdiff_engine::train::{EmaConfig, TrainConfig, TrainOptions};
use socdiff_engine::{Dataset, Error, Result, Scene, Skeleton, Split};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

/// The bundled CMU clip (subject 18, trial 1; 30 fps, 303 frames).
const CMU_CLIP: &str = include_str!("../../examples/data/cmu_18_01.bvh");

/// Options of `socdiff demo`.
#[derive(Args)]
pub struct DemoArgs {
    #[command(flatten)]
    align: crate::data_cmd::AlignArgs,
    #[command(flatten)]
    device: crate::DeviceArg,
    /// Output folder: data/, model/, forecast/, forecast.html, report.json, report.txt.
    #[arg(long, default_value = "socdiff-demo")]
    out: PathBuf,
    /// Use this dataset instead of the embedded scene: train on its train split, forecast its
    /// test split (a dataset directory with both splits, e.g. ../shared/data/mupots3d).
    #[arg(long)]
    data: Option<PathBuf>,
    /// With --data: forecast only these test sequences (repeatable; default: all).
    #[arg(long)]
    sequence: Vec<String>,
    /// Training steps.
    #[arg(long, default_value_t = 300)]
    steps: usize,
    /// U-Net width.
    #[arg(long, default_value_t = 32)]
    hidden: usize,
    /// Frames per training window.
    #[arg(long, default_value_t = 64)]
    window: usize,
    /// Windows per batch.
    #[arg(long, default_value_t = 8)]
    batch: usize,
    /// Observed frames of each forecast.
    #[arg(long, default_value_t = 60)]
    observe: usize,
    /// Forecast frames.
    #[arg(long, default_value_t = 150)]
    horizon: usize,
    /// Samples per forecast.
    #[arg(long, default_value_t = 4)]
    samples: usize,
    /// DDIM steps.
    #[arg(long, default_value_t = 20)]
    sampling_steps: usize,
    /// Seed of training and sampling.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Continue in an existing --out: resume training if unfinished, then redo the forecast,
    /// view and report.
    #[arg(long)]
    resume: bool,
}

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

/// Forecasts `scenes` with a progress bar over all denoising steps.
pub fn forecast_with_progress(model: &LoadedModel, scenes: &[Scene], proto: &Protocol) -> Result<Vec<SceneForecast>> {
    let per_sample = match proto.opts.sampler {
        SamplerKind::Ddpm => model.diffusion.timesteps(),
        SamplerKind::Ddim { steps, .. } => steps,
    };
    let mut windows = 0;
    for s in scenes {
        windows += proto.window_starts(s.num_frames())?.len();
    }
    let bar = crate::progress::denoising((per_sample * proto.opts.samples * windows) as u64);
    let out = forecast_scenes(model, scenes, proto, &mut |i| {
        bar.set_message(format!("samples {}–{}  {:.3} s/step", i.samples.start + 1, i.samples.end, i.seconds));
        let left = bar.length().unwrap_or(0).saturating_sub(bar.position());
        bar.inc((i.samples.len() as u64).min(left));
    });
    bar.finish_and_clear();
    out
}

/// `socdiff demo`.
pub fn run(args: DemoArgs) -> Result<ExitCode> {
    // A device that cannot run is an error before anything is written.
    args.device.device.resolve()?;
    let started = Instant::now();
    let out = &args.out;
    let non_empty = out.is_dir() && std::fs::read_dir(out).map_err(|e| Error::io(out, e))?.next().is_some();
    if out.exists() && !out.is_dir() {
        return Err(Error::format(out, "exists and is not a directory"));
    }
    if non_empty && !args.resume {
        return Err(Error::format(out, "exists and is not empty; pass --resume to continue it, or choose another --out"));
    }
    // --resume continues a demo's folder only (it replaces its forecast/, view and report).
    const MARKER: &str = ".socdiff-demo";
    if non_empty && !out.join(MARKER).is_file() && !Checkpoint::exists_in(&out.join("model")) {
        return Err(Error::format(out, "--resume: is not a socdiff demo folder; refusing to write into it"));
    }
    for (name, v) in [
        ("--steps", args.steps),
        ("--samples", args.samples),
        ("--sampling-steps", args.sampling_steps),
        ("--observe", args.observe),
        ("--horizon", args.horizon),
    ] {
        if v == 0 {
            return Err(Error::invalid(format!("{name} must be at least 1")));
        }
    }

    // 1. Data.
    let dataset = match &args.data {
        Some(dir) => import::load(dir, &args.align.options())?,
        None => embedded_dataset()?,
    };
    let test: Vec<Scene> = dataset.split(Split::Test).filter(|s| args.sequence.is_empty() || args.sequence.contains(&s.name)).cloned().collect();
    if dataset.split(Split::Train).next().is_none() || test.is_empty() {
        let what = args.data.as_ref().map_or("the embedded scene".to_string(), |d| d.display().to_string());
        return Err(Error::invalid(format!(
            "{what}: the demo needs train and test sequences{}",
            if args.sequence.is_empty() { String::new() } else { format!(" (test sequences named {})", args.sequence.join(", ")) }
        )));
    }
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let _lock = RunLock::acquire(out)?;
    write_file_atomic(&out.join(MARKER), b"socdiff demo output\n")?;
    let data_dir = out.join("data");
    if !data_dir.exists() {
        write_dataset(&dataset, &data_dir)?;
    }
    let frames: usize = dataset.split(Split::Train).map(|s| s.num_frames() * s.num_persons()).sum();
    eprintln!(
        "1/5 data: {} — {} train / {} test sequences, {frames} train person-frames, {} joints at {} fps → {}",
        dataset.name,
        dataset.split(Split::Train).count(),
        test.len(),
        test[0].num_joints(),
        test[0].fps,
        data_dir.display()
    );

    // 2. Train (or continue).
    let model_dir = out.join("model");
    let config = TrainConfig {
        steps: args.steps,
        batch: args.batch,
        window: args.window,
        stride: 4,
        seed: args.seed,
        model: DenoiserConfig { hidden: args.hidden, social_dim: args.hidden, aggregator: Aggregator::Mean, ..Default::default() },
        save_every: 100,
        val_every: 100,
        val_windows: 32,
        ema: EmaConfig { warmup_steps: 50, ..Default::default() },
        ..Default::default()
    };
    eprintln!(
        "2/5 train: {} steps, hidden {}, window {}, batch {}, seed {} → {}",
        args.steps,
        args.hidden,
        args.window,
        args.batch,
        args.seed,
        model_dir.display()
    );
    let opts = TrainOptions {
        out_dir: model_dir.clone(),
        resume: Checkpoint::exists_in(&model_dir),
        force: false,
        config: Some(config),
        source: dataset.name.clone(),
        stop: Some(stop_flag()?),
        device: args.device.device,
        ..Default::default()
    };
    if train_with_progress(&dataset, &opts)?.stopped {
        eprintln!("demo stopped during training; continue with: socdiff demo --out {} --resume", out.display());
        return Ok(ExitCode::from(EXIT_STOPPED));
    }

    // 3. Forecast the test scenes.
    let model = Checkpoint::load(&model_dir)?;
    let proto = Protocol { device: args.device.device, ..Protocol::ddim(args.observe, args.horizon, args.samples, args.sampling_steps, args.seed) };
    let usable: Vec<Scene> = test.iter().filter(|s| s.num_frames() > args.observe).cloned().collect();
    if usable.is_empty() {
        return Err(Error::invalid(format!("no test sequence is longer than --observe {} frames", args.observe)));
    }
    eprintln!(
        "3/5 forecast: {} test scene(s), {} samples of {} frames after {} observed, DDIM {} steps",
        usable.len(),
        args.samples,
        args.horizon,
        args.observe,
        args.sampling_steps
    );
    let runs = forecast_with_progress(&model, &usable, &proto)?;
    let fc_dir = out.join("forecast");
    if fc_dir.exists() {
        std::fs::remove_dir_all(&fc_dir).map_err(|e| Error::io(&fc_dir, e))?;
    }
    let mut sequences = Vec::new();
    for x in &runs {
        sequences.extend(x.forecast.to_dataset().sequences);
    }
    write_dataset(&Dataset { name: format!("{}_forecast", dataset.name), sequences, metadata: Default::default() }, &fc_dir)?;

    // 4. View.
    let html = out.join("forecast.html");
    write_view(&runs, &html, &format!("socdiff demo: {}", dataset.name))?;
    eprintln!("4/5 view: {} (open it in a browser)", html.display());

    // 5. Report.
    let report = evaluate(&runs, &test, &Default::default())?;
    let settings = json!({
        "data": args.data.as_ref().map_or("embedded CMU clip groups".to_string(), |d| d.display().to_string()),
        "train": serde_json::to_value(&model.config).unwrap_or(Value::Null), "observe": args.observe, "horizon": args.horizon, "samples": args.samples,
        "sampler": {"kind": "ddim", "steps": args.sampling_steps, "eta": 0.0}, "seed": args.seed,
        "model_step": model.step,
    });
    let table = report.write_to(out, settings)?;
    eprintln!("5/5 report: {} and report.txt", out.join("report.json").display());
    println!("{table}");
    println!("done in {:.0} s: {}", started.elapsed().as_secs_f64(), out.display());
    Ok(ExitCode::SUCCESS)
}
