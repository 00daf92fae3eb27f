//! `socdiff train`: train (or resume) a denoiser on a dataset, with a progress bar, a JSONL log
//! and checkpoints in the run directory (see `socdiff_engine::train`).

use crate::data_cmd::SourceArgs;
use clap::Args;
use indicatif::ProgressBar;
use socdiff_engine::data::import;
use socdiff_engine::train::data::{describe_mix, mix_sources, MixConfig};
use socdiff_engine::train::{self, PersonRange, TrainConfig, TrainEvent, TrainOptions, TrainSummary};
use socdiff_engine::{Dataset, Error, Result};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Options of `socdiff train`. Defaults are METHOD.md §4's (batch 64 windows of 512 frames at
/// stride 10, hidden 192, cosine T = 1000, Adam 1e-4, EMA 0.995); see `config.json` of a run
/// for every field.
#[derive(Args)]
pub struct TrainArgs {
    #[command(flatten)]
    device: crate::DeviceArg,
    /// Precision of the convolutions' products: f32, or bf16 (GPUs; f32 master weights and
    /// loss).
    #[arg(long, default_value = "f32", value_parser = crate::parse_engine::<socdiff_engine::model::Precision>)]
    precision: socdiff_engine::model::Precision,
    /// Training data: a dataset directory (train split; validation on the test split), or any
    /// file `socdiff data` reads (.bvh, Haggling .pkl). Repeat to train on several sources: the
    /// first sets the skeleton, fps and validation data; the others' train splits are mapped
    /// onto its skeleton by joint names, and single-person sources become synthetic groups.
    #[arg(long, required = true)]
    data: Vec<PathBuf>,
    /// With several --data: synthetic groups built from each single-person source.
    #[arg(long, default_value_t = 200)]
    synthetic_groups: usize,
    /// With several --data: persons per synthetic group, MIN..MAX (default: the person counts
    /// of the first source's train scenes).
    #[arg(long)]
    group_persons: Option<String>,
    /// With several --data: frames per synthetic group (default: twice the window, at least 300).
    #[arg(long)]
    group_frames: Option<usize>,
    /// With several --data: the first source's train scenes count this many times.
    #[arg(long, default_value_t = 1)]
    repeat_first: usize,
    /// Run directory: checkpoint.safetensors, checkpoint.json, train_log.jsonl, config.json.
    #[arg(long)]
    out: PathBuf,
    /// JSON config file (any subset of the fields of a run's config.json); the options below
    /// override it.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Total optimizer steps of the run (a resumed run continues up to this count).
    #[arg(long)]
    steps: Option<usize>,
    /// Windows per batch.
    #[arg(long)]
    batch: Option<usize>,
    /// Frames per training window.
    #[arg(long)]
    window: Option<usize>,
    /// Frames between window starts.
    #[arg(long)]
    stride: Option<usize>,
    /// Observed frames per window: persons are anchored at the last one (default window/4).
    #[arg(long)]
    observed: Option<usize>,
    /// U-Net width H (also the social width, unless the config sets model.social_dim apart
    /// from model.hidden).
    #[arg(long)]
    hidden: Option<usize>,
    /// How persons share information: none, mean or attention.
    #[arg(long, value_enum)]
    aggregator: Option<socdiff_engine::model::Aggregator>,
    /// Attention heads (with --aggregator attention; default 4).
    #[arg(long)]
    heads: Option<usize>,
    /// Train on person subsets of at least this many persons (with --persons-max).
    #[arg(long)]
    persons_min: Option<usize>,
    /// Train on person subsets of at most this many persons (with --persons-min).
    #[arg(long)]
    persons_max: Option<usize>,
    /// Learning rate.
    #[arg(long)]
    lr: Option<f64>,
    /// Noise levels of a window: uniform (one t per window, the paper), prefix (a clean
    /// prefix, one t after it), per-frame or per-frame-monotone (one t per person and frame,
    /// Diffusion Forcing). Saved in the checkpoint; sampling then gives known frames level 0.
    #[arg(long, value_enum)]
    noise: Option<socdiff_engine::train::NoiseLevels>,
    /// Local joints as they are (absolute, the paper) or as offsets from each person's pose at
    /// the last observed frame (residual: standing still is zero, body proportions are kept).
    #[arg(long, value_enum)]
    pose: Option<socdiff_engine::features::PoseEncoding>,
    /// How an epoch draws its windows: windows (each once, the paper) or sequences (each
    /// sequence equally likely whatever its length, with replacement).
    #[arg(long, value_enum)]
    balance: Option<socdiff_engine::train::WindowBalance>,
    /// Weight of the loss's velocity term: errors of frame-to-frame changes, each dim on the
    /// scale of its changes in the training windows (0: off, the paper; uniform noise only).
    #[arg(long, value_name = "W")]
    velocity_loss: Option<f64>,
    /// Bodies it has not seen: scale each person's skeleton by a factor in 1 ± X per window
    /// (0.1 spans real adults) …
    #[arg(long, value_name = "X")]
    body_scale: Option<f64>,
    /// … and each limb (left and right alike) by a further factor in 1 ± X.
    #[arg(long, value_name = "X")]
    limb_scale: Option<f64>,
    /// Seed of initialization, batch order, timesteps and noise.
    #[arg(long)]
    seed: Option<u64>,
    /// Checkpoint every N steps (and at the end, and on Ctrl-C).
    #[arg(long)]
    save_every: Option<usize>,
    /// Validation loss every N steps (0: never).
    #[arg(long)]
    val_every: Option<usize>,
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

impl TrainArgs {
    /// Sets the fields that options were given for (the rest of `cfg` is kept).
    fn apply(&self, cfg: &mut TrainConfig) -> Result<()> {
        let set = |field: &mut usize, v: Option<usize>| {
            if let Some(v) = v {
                *field = v;
            }
        };
        set(&mut cfg.steps, self.steps);
        set(&mut cfg.batch, self.batch);
        set(&mut cfg.window, self.window);
        set(&mut cfg.stride, self.stride);
        set(&mut cfg.save_every, self.save_every);
        set(&mut cfg.val_every, self.val_every);
        cfg.observed = self.observed.or(cfg.observed);
        cfg.seed = self.seed.unwrap_or(cfg.seed);
        cfg.adam.lr = self.lr.unwrap_or(cfg.adam.lr);
        for (flag, v, field) in [("body-scale", self.body_scale, &mut cfg.augment.body_scale), ("limb-scale", self.limb_scale, &mut cfg.augment.limb_scale)] {
            if let Some(v) = v {
                if !(0.0..0.5).contains(&v) {
                    return Err(Error::invalid(format!("--{flag} {v}: expected a spread in [0, 0.5)")));
                }
                *field = v;
            }
        }
        cfg.pose = self.pose.unwrap_or(cfg.pose);
        cfg.noise = self.noise.unwrap_or(cfg.noise);
        cfg.balance = self.balance.unwrap_or(cfg.balance);
        cfg.velocity_loss = self.velocity_loss.unwrap_or(cfg.velocity_loss);
        match (self.persons_min, self.persons_max) {
            (Some(min), Some(max)) => cfg.persons = Some(PersonRange { min, max }),
            (None, None) => {}
            _ => return Err(Error::invalid("--persons-min and --persons-max go together")),
        }
        if let Some(h) = self.hidden {
            // The social width follows the U-Net width unless it was set apart from it.
            if cfg.model.social_dim == cfg.model.hidden {
                cfg.model.social_dim = h;
            }
            cfg.model.hidden = h;
        }
        match (self.aggregator, self.heads) {
            (Some(agg), heads) => cfg.model.aggregator = heads.map_or(Ok(agg), |h| agg.with_heads(h))?,
            (None, Some(_)) => return Err(Error::invalid("--heads needs --aggregator attention")),
            (None, None) => {}
        }
        cfg.validate()
    }
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

/// Loads every --data source and, with several, mixes them into one training set
/// (`socdiff_engine::train::data::mix_sources`); returns the dataset and a description of the
/// sources for the checkpoint.
fn training_data(args: &TrainArgs, cfg: &TrainConfig) -> Result<(Dataset, String)> {
    let opts = args.source.options()?;
    let sets: Vec<Dataset> = args.data.iter().map(|p| import::load(p, &opts)).collect::<Result<_>>()?;
    if sets.len() == 1 {
        let ds = sets.into_iter().next().expect("one source");
        return Ok((ds, args.data[0].display().to_string()));
    }
    let mut mix = MixConfig { primary_repeat: args.repeat_first, ..MixConfig::for_primary(&sets[0], cfg.window, args.synthetic_groups, cfg.seed) };
    if let Some(spec) = &args.group_persons {
        (mix.groups.persons_min, mix.groups.persons_max) = parse_range(spec)?;
    }
    mix.groups.frames = args.group_frames.unwrap_or(mix.groups.frames);
    let (ds, summary) = mix_sources(&sets, &mix)?;
    for (src, path) in summary.iter().zip(&args.data) {
        eprintln!("data {}: {} ({}), {} train scenes, {} frames", src.name, path.display(), src.kind, src.scenes, src.frames);
        let derived: Vec<&String> = src.joint_map.iter().filter(|l| l.contains("midpoint") || l.contains("body frame")).collect();
        if !src.joint_map.is_empty() {
            eprintln!("  joints mapped by name onto the first source's skeleton: {} copied, {} derived", src.joint_map.len() - derived.len(), derived.len());
        }
        for line in derived {
            eprintln!("  {line}");
        }
    }
    let labels: Vec<String> = args.data.iter().map(|p| p.display().to_string()).collect();
    Ok((ds, describe_mix(&labels, &summary, &mix)))
}

fn parse_range(spec: &str) -> Result<(usize, usize)> {
    let bad = || Error::invalid(format!("--group-persons {spec:?}: expected MIN..MAX (e.g. 2..3) or N"));
    let (a, b) = spec.split_once("..").unwrap_or((spec, spec));
    let (a, b): (usize, usize) = (a.trim().parse().map_err(|_| bad())?, b.trim().trim_start_matches('=').parse().map_err(|_| bad())?);
    if a == 0 || a > b {
        return Err(bad());
    }
    Ok((a, b))
}

pub fn run(args: TrainArgs) -> Result<ExitCode> {
    // Defaults (on --resume the checkpoint's config) ← the --config file ← the options. A
    // resumed mix is rebuilt from the checkpoint's seed and window, so its windows match.
    let mut cfg = args.resume.then(|| train::saved_config(&args.out)).flatten().unwrap_or_default();
    if let Some(path) = &args.config {
        cfg = TrainConfig::read_over(&cfg, path)?;
    }
    args.apply(&mut cfg)?;
    let (dataset, source) = training_data(&args, &cfg)?;
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
        TrainEvent::Saved { step, path } => say(&bar, format!("step {step}: saved {}", path.display())),
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

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use socdiff_engine::model::{Aggregator, DenoiserConfig};

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: TrainArgs,
    }

    fn parse(extra: &[&str]) -> TrainArgs {
        let mut argv = vec!["socdiff", "--data", "d", "--out", "o"];
        argv.extend_from_slice(extra);
        Cli::try_parse_from(argv).unwrap().args
    }

    #[test]
    fn options_set_their_fields_only() {
        let a = parse(&["--steps", "5", "--hidden", "32", "--aggregator", "attention", "--persons-min", "2", "--persons-max", "3", "--lr", "0.001"]);
        let base = TrainConfig { batch: 7, ..TrainConfig::default() };
        let mut cfg = base.clone();
        a.apply(&mut cfg).unwrap();
        let m = &cfg.model;
        assert_eq!((cfg.steps, cfg.batch, cfg.persons, cfg.adam.lr), (5, 7, Some(PersonRange { min: 2, max: 3 }), 0.001));
        assert_eq!((m.hidden, m.social_dim, m.aggregator), (32, 32, Aggregator::Attention { heads: Aggregator::DEFAULT_HEADS }));
        // A social width set apart from the U-Net width (say by a config file) is kept.
        let mut apart = TrainConfig { model: DenoiserConfig { social_dim: 64, ..Default::default() }, ..TrainConfig::default() };
        a.apply(&mut apart).unwrap();
        assert_eq!((apart.model.hidden, apart.model.social_dim), (32, 64));
        // Nothing given: nothing changes (a resumed run keeps its config).
        let mut same = base.clone();
        parse(&["--resume"]).apply(&mut same).unwrap();
        assert_eq!(same, base);
        let err = |extra: &[&str]| parse(extra).apply(&mut base.clone()).unwrap_err().to_string();
        assert!(err(&["--persons-min", "2"]).contains("go together"));
        assert!(err(&["--heads", "2"]).contains("--aggregator attention"));
        assert!(err(&["--body-scale", "0.7"]).contains("--body-scale 0.7"));
        assert!(err(&["--batch", "0"]).contains("batch must be at least 1"));
        let mut none = base.clone();
        parse(&["--aggregator", "none"]).apply(&mut none).unwrap();
        assert_eq!(none.model.aggregator, Aggregator::None);
    }
}
