//! `socdiff train`: train (or resume) a denoiser on a dataset, with a progress bar, a JSONL log
//! and checkpoints in the run directory (see `socdiff_engine::train`).

use clap::Args;
use socdiff_engine::data::import::SourceArgs;
use socdiff_engine::train::{self, TrainOptions, TrainOverrides, TrainSources, TrainingData};
use socdiff_engine::{Error, Result};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Options of `socdiff train`.
#[derive(Args)]
pub struct TrainArgs {
    #[command(flatten)]
    device: socdiff_engine::model::DeviceArg,
    /// Precision of the convolutions' products: f32, or bf16 (GPUs; f32 master weights and
    /// loss).
    #[arg(long, default_value = "f32")]
    precision: socdiff_engine::model::Precision,
    #[command(flatten)]
    sources: TrainSources,
    /// Run directory: checkpoint.safetensors, checkpoint.json, train_log.jsonl, config.json.
    #[arg(long)]
    out: PathBuf,
    /// Starting configuration: recommended (the recipe that measured best, sized for a CPU) or
    /// paper (the paper's configuration, sized for a GPU); a --config file and the options
    /// below change it.
    #[arg(long, value_enum, default_value = "recommended", conflicts_with = "resume")]
    preset: train::Preset,
    /// JSON config file (any subset of the fields of a run's config.json); the options below
    /// override it.
    #[arg(long)]
    config: Option<PathBuf>,
    #[command(flatten)]
    overrides: TrainOverrides,
    /// Continue the checkpoint in --out exactly (its config is kept; only --steps, --minutes,
    /// --save-every and --val-every may change).
    #[arg(long)]
    resume: bool,
    /// Start from this model's weights (a run directory or checkpoint file; its network, pose
    /// encoding and feature scaling are kept), with a fresh optimizer at step 0: fine-tuning on
    /// --data.
    #[arg(long, value_name = "MODEL", conflicts_with = "resume")]
    init: Option<PathBuf>,
    /// Start over in an --out that holds an earlier run's checkpoint (its checkpoint, log and
    /// config are replaced; nothing else in the directory is touched).
    #[arg(long, conflicts_with = "resume")]
    force: bool,
}

/// Exit code of a run stopped early by Ctrl-C or SIGTERM (after saving its checkpoint).
pub const EXIT_STOPPED: u8 = 3;

/// Installs the Ctrl-C / SIGTERM / SIGHUP handler: the first signal asks the run to stop after
/// the current step (it saves a checkpoint first); a second one quits at once. Quitting during a
/// save is safe: a checkpoint is one file renamed into place, so the last complete one stays.
pub(crate) fn stop_flag() -> Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    let first = std::sync::Mutex::new(None::<std::time::Instant>);
    ctrlc::set_handler(move || {
        let mut at = first.lock().unwrap_or_else(|e| e.into_inner());
        match *at {
            // One signal delivered twice (to the process and its group, as `timeout` does) is
            // one request, not two.
            Some(t) if t.elapsed() < std::time::Duration::from_millis(100) => {}
            Some(_) => {
                eprintln!("\nsecond stop signal: quitting now (the last complete checkpoint is kept)");
                std::process::exit(130);
            }
            None => {
                *at = Some(std::time::Instant::now());
                flag.store(true, Ordering::SeqCst);
                eprintln!("\nstop signal: stopping after this step and saving a checkpoint (send again to quit now)");
            }
        }
    })
    .map_err(|e| Error::invalid(format!("cannot install the Ctrl-C handler: {e}")))?;
    Ok(stop)
}

pub fn run(args: TrainArgs) -> Result<ExitCode> {
    // A resumed mix is rebuilt from the checkpoint's seed and window, so its windows match.
    let cfg = train::resolve_config(&args.out, args.resume, args.preset, args.init.as_deref(), args.config.as_deref(), &args.overrides)?;
    // Sources read with the default import options; other units, axes or alignments go through
    // `socdiff data convert` first.
    let TrainingData { dataset, source, notes } = args.sources.load(&cfg, &SourceArgs::default().options())?;
    notes.iter().for_each(|n| eprintln!("{n}"));
    let opts = TrainOptions {
        out_dir: args.out.clone(),
        resume: args.resume,
        force: args.force,
        config: Some(cfg),
        source,
        stop: Some(stop_flag()?),
        device: args.device.device,
        precision: args.precision,
        init: args.init.clone(),
    };
    let summary = crate::progress::train_with_progress(&dataset, &opts)?;
    Ok(if summary.stopped { ExitCode::from(EXIT_STOPPED) } else { ExitCode::SUCCESS })
}
