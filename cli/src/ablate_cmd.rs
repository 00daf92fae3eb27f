//! `socdiff ablate`: the paper's ablation tables (`socdiff_engine::recipes::ablation`).
//!
//! - `--aggregators none,mean,attention` (Table 7.4): one model per aggregator, same data, seed
//!   and settings, scored on the test split, plus the leader/follower probe.
//! - `--model RUN --samplers ddpm,ddim200,…` (Table 7.7): one model, several samplers.
//!
//! Everything goes to `--out` (an interrupted ablation continues when run again): run
//! directories, `report_<name>/report.json` per row, `table.md` and `results.json`.

use clap::Args;
use socdiff_engine::data::import;
use socdiff_engine::forecast::SamplerKind;
use socdiff_engine::metrics::{NdmsConfig, NdmsJoints};
use socdiff_engine::model::{Aggregator, DenoiserConfig};
use socdiff_engine::recipes::ablation::{run_ablation, Ablation, Study};
use socdiff_engine::train::{AdamConfig, TrainConfig};
use socdiff_engine::{Error, Result};
use std::path::PathBuf;

/// Options of `socdiff ablate`.
#[derive(Args)]
pub struct AblateArgs {
    #[command(flatten)]
    align: socdiff_engine::data::import::AlignArgs,
    #[command(flatten)]
    device: socdiff_engine::model::DeviceArg,
    /// Dataset: models train on its train split and forecast its test split.
    #[arg(long)]
    data: PathBuf,
    /// Output folder (run directories, reports, table.md, results.json).
    #[arg(long)]
    out: PathBuf,
    /// Aggregator ablation: train one model per aggregator (none, mean, attention).
    #[arg(long, value_enum, value_delimiter = ',', conflicts_with_all = ["model", "samplers"])]
    aggregators: Vec<Aggregator>,
    /// Sampler ablation: the trained model (run directory or checkpoint) to sample with;
    /// repeat to compare models (one row per model and sampler).
    #[arg(long, requires = "samplers")]
    model: Vec<PathBuf>,
    /// Sampler ablation: samplers to compare, e.g. ddpm,ddim200,ddim100,ddim50,ddim20,ddim10.
    #[arg(long, value_delimiter = ',', requires = "model", value_parser = SamplerKind::parse)]
    samplers: Vec<SamplerKind>,
    /// Training steps per model.
    #[arg(long, default_value_t = 2000)]
    steps: usize,
    /// U-Net width (and social width).
    #[arg(long, default_value_t = 64)]
    hidden: usize,
    /// Frames per training window.
    #[arg(long, default_value_t = 128)]
    window: usize,
    /// Frames between training windows.
    #[arg(long, default_value_t = 4)]
    stride: usize,
    /// Windows per batch.
    #[arg(long, default_value_t = 16)]
    batch: usize,
    /// Learning rate.
    #[arg(long, default_value_t = 1e-4)]
    lr: f64,
    /// Seed of every model's initialization, batches and noise, and of sampling.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Observed frames of each forecast.
    #[arg(long, default_value_t = 60)]
    observe: usize,
    /// Forecast frames.
    #[arg(long, default_value_t = 90)]
    horizon: usize,
    /// Forecast a window every N frames of each test scene (0: one window per scene).
    #[arg(long, default_value_t = 60)]
    window_stride: usize,
    /// Samples per forecast.
    #[arg(long, default_value_t = 4)]
    samples: usize,
    /// DDIM steps of the aggregator ablation's forecasts.
    #[arg(long, default_value_t = 50)]
    sampling_steps: usize,
    /// Joints of NDMS motion words: default (head, shoulders, elbows, wrists, knees, ankles,
    /// found by name), all, or comma-separated names.
    #[arg(long, value_name = "NAMES|all|default", default_value = "default")]
    ndms_joints: String,
    /// Leader/follower probe: training steps per aggregator (0: skip the probe).
    #[arg(long, default_value_t = 400)]
    probe_steps: usize,
}

/// `socdiff ablate`.
pub fn run(args: AblateArgs) -> Result<()> {
    let ndms = NdmsConfig { joints: NdmsJoints::parse(&args.ndms_joints)?, ..Default::default() };
    let study = if !args.aggregators.is_empty() {
        let training = TrainConfig {
            model: DenoiserConfig { hidden: args.hidden, social_dim: args.hidden, ..Default::default() },
            steps: args.steps,
            window: args.window,
            stride: args.stride,
            batch: args.batch,
            adam: AdamConfig { lr: args.lr, ..Default::default() },
            seed: args.seed,
            save_every: 250,
            val_every: 0,
            ..Default::default()
        };
        Study::Aggregators { aggregators: args.aggregators, training: Box::new(training), sampling_steps: args.sampling_steps, probe_steps: args.probe_steps }
    } else if !args.samplers.is_empty() {
        Study::Samplers { models: args.model, samplers: args.samplers }
    } else {
        return Err(Error::invalid("socdiff ablate: give --aggregators none,mean,attention, or --model RUN with --samplers ddpm,ddim20,…"));
    };
    let ablation = Ablation {
        study,
        out: args.out,
        data: args.data.display().to_string(),
        command: std::env::args().collect::<Vec<_>>().join(" "),
        observe: args.observe,
        horizon: args.horizon,
        samples: args.samples,
        window_stride: args.window_stride,
        seed: args.seed,
        ndms,
        device: args.device.device,
    };
    ablation.device.resolve()?;
    let dataset = import::load(&args.data, &args.align.options())?;
    let table = run_ablation(&dataset, &ablation, &mut crate::progress::WithProgress)?;
    println!("{}", table.markdown);
    eprintln!("wrote {} and results.json", table.path.display());
    Ok(())
}
