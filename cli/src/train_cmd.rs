//! `socdiff train`: train (or resume) a denoiser on a dataset, with a progress bar, a JSONL log
//! and checkpoints in the run directory (see `socdiff_engine::train`).

use crate::data_cmd::SourceArgs;
use clap::Args;
use indicatif::ProgressBar;
use serde_json::{json, Map, Value};
use socdiff_engine::data::import;
use socdiff_engine::data::synthetic::GroupConfig;
use socdiff_engine::train::checkpoint::Checkpoint;
use socdiff_engine::train::data::{describe_mix, mix_sources, train_person_range, MixConfig};
use socdiff_engine::train::{self, TrainConfig, TrainEvent, TrainOptions, TrainSummary};
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
    /// U-Net width H (also the social width, unless the config file sets model.social_dim).
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
    /// The command-line overrides as a JSON patch (only options that were given).
    fn patch(&self, file: Option<&Value>) -> Result<Value> {
        let mut p = Map::new();
        let mut put = |k: &str, v: Value| {
            p.insert(k.to_string(), v);
        };
        if let Some(v) = self.steps {
            put("steps", json!(v));
        }
        if let Some(v) = self.batch {
            put("batch", json!(v));
        }
        if let Some(v) = self.window {
            put("window", json!(v));
        }
        if let Some(v) = self.stride {
            put("stride", json!(v));
        }
        if let Some(v) = self.observed {
            put("observed", json!(v));
        }
        if let Some(v) = self.seed {
            put("seed", json!(v));
        }
        if let Some(v) = self.save_every {
            put("save_every", json!(v));
        }
        if let Some(v) = self.val_every {
            put("val_every", json!(v));
        }
        if let Some(v) = self.lr {
            put("adam", json!({ "lr": v }));
        }
        let mut augment = Map::new();
        for (k, v) in [("body_scale", self.body_scale), ("limb_scale", self.limb_scale)] {
            if let Some(v) = v {
                if !(0.0..0.5).contains(&v) {
                    return Err(Error::invalid(format!("--{} {v}: expected a spread in [0, 0.5)", k.replace('_', "-"))));
                }
                augment.insert(k.into(), json!(v));
            }
        }
        if !augment.is_empty() {
            put("augment", Value::Object(augment));
        }
        if let Some(pose) = self.pose {
            put("pose", serde_json::to_value(pose).map_err(|e| Error::invalid(e.to_string()))?);
        }
        if let Some(levels) = self.noise {
            put("noise", serde_json::to_value(levels).map_err(|e| Error::invalid(e.to_string()))?);
        }
        match (self.persons_min, self.persons_max) {
            (Some(a), Some(b)) => put("persons", json!({"min": a, "max": b})),
            (None, None) => {}
            _ => return Err(Error::invalid("--persons-min and --persons-max go together")),
        }
        let mut model = Map::new();
        if let Some(h) = self.hidden {
            model.insert("hidden".into(), json!(h));
            let file_sets_social = file.and_then(|f| f.pointer("/model/social_dim")).is_some();
            if !file_sets_social {
                model.insert("social_dim".into(), json!(h));
            }
        }
        match (self.aggregator, self.heads) {
            (Some(agg), heads) => {
                let agg = heads.map_or(Ok(agg), |h| agg.with_heads(h))?;
                model.insert("aggregator".into(), serde_json::to_value(agg).map_err(|e| Error::invalid(e.to_string()))?);
            }
            (None, Some(_)) => return Err(Error::invalid("--heads needs --aggregator attention")),
            (None, None) => {}
        }
        if !model.is_empty() {
            put("model", Value::Object(model));
        }
        Ok(Value::Object(p))
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
    let (lo, hi) = match &args.group_persons {
        Some(spec) => parse_range(spec)?,
        None => train_person_range(&sets[0]),
    };
    let frames = args.group_frames.unwrap_or((2 * cfg.window).max(300));
    let mix = MixConfig {
        groups_per_source: args.synthetic_groups,
        groups: GroupConfig { persons_min: lo, persons_max: hi, frames, seed: cfg.seed, ..Default::default() },
        primary_repeat: args.repeat_first,
        groups_by_frames: false,
    };
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
    let file = match &args.config {
        Some(path) => Some(TrainConfig::read_patch(path)?),
        None => None,
    };
    let mut patches: Vec<Value> = file.iter().cloned().collect();
    patches.push(args.patch(file.as_ref())?);
    // A resumed mix is rebuilt from the checkpoint's seed and window, so its windows match.
    let base = if args.resume { Checkpoint::read_meta(&args.out).map(|m| m.config).unwrap_or_default() } else { TrainConfig::default() };
    let cfg = TrainConfig::resolve(&base, &patches)?;
    let (dataset, source) = training_data(&args, &cfg)?;
    let opts = TrainOptions {
        out_dir: args.out.clone(),
        resume: args.resume,
        force: args.force,
        patches,
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
    fn options_become_a_json_patch() {
        let a = parse(&["--steps", "5", "--hidden", "32", "--aggregator", "attention", "--persons-min", "2", "--persons-max", "3", "--lr", "0.001"]);
        let p = a.patch(None).unwrap();
        assert_eq!(
            p,
            json!({"steps": 5, "persons": {"min": 2, "max": 3}, "adam": {"lr": 0.001},
                   "model": {"hidden": 32, "social_dim": 32, "aggregator": {"kind": "attention", "heads": 4}}})
        );
        // A config file that sets the social width keeps it.
        let file = json!({"model": {"social_dim": 64}});
        assert_eq!(a.patch(Some(&file)).unwrap()["model"].get("social_dim"), None);
        let cfg = TrainConfig::resolve(&TrainConfig::default(), &[file.clone(), a.patch(Some(&file)).unwrap()]).unwrap();
        assert_eq!((cfg.model.hidden, cfg.model.social_dim, cfg.steps), (32, 64, 5));
        // Nothing given: an empty patch (a resumed run keeps its config).
        assert_eq!(parse(&["--resume"]).patch(None).unwrap(), json!({}));
        assert!(parse(&["--persons-min", "2"]).patch(None).unwrap_err().to_string().contains("go together"));
        assert!(parse(&["--heads", "2"]).patch(None).unwrap_err().to_string().contains("--aggregator attention"));
        assert_eq!(parse(&["--aggregator", "none"]).patch(None).unwrap(), json!({"model": {"aggregator": {"kind": "none"}}}));
    }
}
