//! `socdiff train`: train (or resume) a denoiser on a dataset, with a progress bar, a JSONL log
//! and checkpoints in the run directory (see `socdiff_engine::train`).

use clap::Args;
use indicatif::ProgressBar;
use socdiff_engine::data::import::SourceArgs;
use socdiff_engine::train::{self, CheckpointSaved, TrainConfig, TrainEvent, TrainOptions, TrainOverrides, TrainSources, TrainSummary, TrainingData};
use socdiff_engine::{Dataset, Error, Result};
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
    /// JSON config file (any subset of the fields of a run's config.json); the options below
    /// override it.
    #[arg(long)]
    config: Option<PathBuf>,
    #[command(flatten)]
    overrides: TrainOverrides,
    /// Continue the checkpoint in --out exactly (its config is kept; only --steps,
    /// --save-every and --val-every may change).
    #[arg(long)]
    resume: bool,
    /// Start over in an --out that holds an earlier run's checkpoint (its checkpoint, log and
    /// config are replaced; nothing else in the directory is touched).
    #[arg(long, conflicts_with = "resume")]
    force: bool,
    #[command(flatten)]
    source: SourceArgs,
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
    // Defaults (on --resume the checkpoint's config) ← the --config file ← the options. A
    // resumed mix is rebuilt from the checkpoint's seed and window, so its windows match.
    let mut cfg = args.resume.then(|| train::saved_config(&args.out)).flatten().unwrap_or_default();
    if let Some(path) = &args.config {
        cfg = TrainConfig::read_over(&cfg, path)?;
    }
    args.overrides.apply(&mut cfg)?;
    let TrainingData { dataset, source, notes } = args.sources.load(&cfg, &args.source.options())?;
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
    };
    let summary = train_with_progress(&dataset, &opts)?;
    Ok(if summary.stopped { ExitCode::from(EXIT_STOPPED) } else { ExitCode::SUCCESS })
}

/// Trains with a progress bar and one line per validation, checkpoint and note; prints the
/// outcome.
pub fn train_with_progress(dataset: &Dataset, opts: &TrainOptions) -> Result<TrainSummary> {
    let bar = ProgressBar::hidden();
    // Lines above the bar; plain stderr when the bar is hidden (not a terminal).
    let say = |bar: &ProgressBar, line: String| {
        if bar.is_hidden() {
            eprintln!("{line}");
        } else {
            bar.println(line);
        }
    };
    let (mut loss_avg, mut val) = (crate::progress::SmoothedLoss::default(), None::<f32>);
    let summary = train::train(dataset, opts, &mut |event| match event {
        TrainEvent::Started { first_step, total_steps, params, train_windows, val_windows, batches_per_epoch, config, device } => {
            let m = &config.model;
            eprintln!(
                "training {} on {device} ({} train windows in {batches_per_epoch} batches per epoch, {val_windows} validation windows): hidden {}, aggregator {:?}, {params} parameters, window {}, batch {}, seed {}",
                dataset.name, train_windows, m.hidden, m.aggregator, config.window, config.batch, config.seed
            );
            crate::progress::start_steps(&bar, *first_step, *total_steps);
        }
        TrainEvent::Step { step, loss, .. } => {
            // Smoothed loss for display; the log has every value.
            let l = *loss as f64;
            let v = val.map(|v| format!("  val {v:.4}")).unwrap_or_default();
            bar.set_message(format!("loss {:.4}{v}", loss_avg.add(l)));
            bar.set_position(*step);
        }
        TrainEvent::Validation { step, loss } => {
            val = Some(*loss);
            say(&bar, format!("step {step}: validation loss {loss:.5}"));
        }
        TrainEvent::Saved(CheckpointSaved { step, path }) => say(&bar, format!("step {step}: saved {}", path.display())),
        TrainEvent::Notice(msg) => say(&bar, format!("note: {msg}")),
    })?;
    bar.finish_and_clear();
    let last = summary.losses.last().map(|l| format!(", last loss {l:.5}")).unwrap_or_default();
    if summary.stopped {
        eprintln!(
            "stopped early at step {} of {}{last}; checkpoint {} (continue with --resume); exit code 3",
            summary.last_step,
            summary.config.steps,
            summary.checkpoint.display()
        );
    } else {
        eprintln!("trained steps {}..{}{last}; checkpoint {}", summary.first_step, summary.last_step, summary.checkpoint.display());
    }
    Ok(summary)
}
