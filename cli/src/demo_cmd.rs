//! `socdiff demo`: the whole pipeline in one command — data → train → forecast → HTML view →
//! evaluation report — on an embedded scene (no downloads) or on a dataset (`--data`); see
//! `socdiff_engine::recipes::demo`.

use crate::train_cmd::{stop_flag, EXIT_STOPPED};
use clap::Args;
use socdiff_engine::data::import;
use socdiff_engine::recipes::demo::{embedded_dataset, run_demo, Demo};
use socdiff_engine::Result;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

/// Options of `socdiff demo`.
#[derive(Args)]
pub struct DemoArgs {
    #[command(flatten)]
    align: socdiff_engine::data::import::AlignArgs,
    #[command(flatten)]
    device: socdiff_engine::model::DeviceArg,
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
    /// Train a small model on the data first (--steps, --hidden, --window, --batch) instead of
    /// forecasting with the bundled pretrained model.
    #[arg(long)]
    train: bool,
    /// Training steps (with --train).
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

/// `socdiff demo`.
pub fn run(args: DemoArgs) -> Result<ExitCode> {
    let started = Instant::now();
    let demo = Demo {
        out: args.out,
        data: args.data,
        sequences: args.sequence,
        train: args.train,
        steps: args.steps,
        hidden: args.hidden,
        window: args.window,
        batch: args.batch,
        observe: args.observe,
        horizon: args.horizon,
        samples: args.samples,
        sampling_steps: args.sampling_steps,
        seed: args.seed,
        resume: args.resume,
        device: args.device.device,
        stop: Some(stop_flag()?),
    };
    demo.device.resolve()?;
    let dataset = match &demo.data {
        Some(dir) => import::load(dir, &args.align.options())?,
        None => embedded_dataset()?,
    };
    let outcome = run_demo(&dataset, &demo, &mut crate::progress::WithProgress)?;
    if outcome.stopped {
        eprintln!("demo stopped during training; continue with: socdiff demo --out {} --resume", demo.out.display());
        return Ok(ExitCode::from(EXIT_STOPPED));
    }
    println!("{}", outcome.table);
    println!("done in {:.0} s: {}", started.elapsed().as_secs_f64(), demo.out.display());
    Ok(ExitCode::SUCCESS)
}
