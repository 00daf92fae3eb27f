//! `socdiff bench quality`: train the recommended recipe for N minutes of wall time, forecast
//! windows of MuPoTS test (1 s observed, 3 s forecast, K = 8) and score them with the baselines
//! through the one evaluator (`socdiff_engine::recipes::forecast_quality`). Resumable: run it
//! again with `--resume` after Ctrl-C; the training time already spent counts, and a larger
//! `--minutes` continues the training.

use crate::train_cmd::{stop_flag, train_with_progress, EXIT_STOPPED};
use clap::Args;
use serde_json::{json, Value};
use socdiff_engine::data::bvh::{BvhImport, CMU_SCALE};
use socdiff_engine::data::import::{self, ImportOptions};
use socdiff_engine::files::{check_output_dir, write_file_atomic, RunLock};
use socdiff_engine::model::{Aggregator, DenoiserConfig};
use socdiff_engine::recipes::{forecast_quality, QualityProtocol, QualityResult};
use socdiff_engine::train::checkpoint::Checkpoint;
use socdiff_engine::train::data::{describe_mix, mix_sources, MixConfig};
use socdiff_engine::train::{AdamConfig, AugmentConfig, TrainConfig, TrainOptions};
use socdiff_engine::Dataset;
use socdiff_engine::{Error, Result};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Seconds within which a training budget counts as spent (the deadline stops a step later or
/// earlier).
const SPENT_TOLERANCE_S: f64 = 1.0;

/// Options of `socdiff bench quality`.
#[derive(Args)]
pub struct QualityArgs {
    #[command(flatten)]
    device: crate::DeviceArg,
    /// Minutes of training (wall time, over all resumes).
    #[arg(long)]
    minutes: f64,
    /// Output folder: model/ (the run), quality.json, report.json.
    #[arg(long)]
    out: PathBuf,
    /// Dataset with train and test splits.
    #[arg(long, default_value = "../shared/data/mupots3d")]
    data: PathBuf,
    /// Continue an interrupted run in --out.
    #[arg(long)]
    resume: bool,
    /// Noise levels of training (see `socdiff train --noise`).
    #[arg(long, value_enum, default_value = "prefix")]
    noise: socdiff_engine::train::NoiseLevels,
    /// U-Net width.
    #[arg(long, default_value_t = 64)]
    hidden: usize,
    /// Training windows per batch.
    #[arg(long, default_value_t = 16)]
    batch: usize,
    /// Training window (frames).
    #[arg(long, default_value_t = 120)]
    window: usize,
    /// Body-proportion augmentation (see `socdiff train --body-scale`; limbs get half of it;
    /// 0: off). On by default: it measured best (docs/recipes.md §8).
    #[arg(long, default_value_t = 0.1)]
    body_scale: f64,
    /// Pose encoding of training (see `socdiff train --pose`). Residual by default: it measured
    /// best (docs/recipes.md §8).
    #[arg(long, value_enum, default_value = "residual")]
    pose: socdiff_engine::features::PoseEncoding,
    /// Samples per window.
    #[arg(long, default_value_t = 8)]
    samples: usize,
    /// Also score the model after every M minutes of training: the curve of quality against
    /// training time (DIR/at-<minutes>min/quality.json, and "curve" in quality.json).
    #[arg(long, value_name = "M")]
    score_every: Option<f64>,
    /// Pre-training: the first M of the --minutes go to --data mixed with --pretrain-data as
    /// synthetic groups (`socdiff train` with several --data), the rest to fine-tuning on --data
    /// alone. 0: no pre-training.
    #[arg(long, value_name = "M", default_value_t = 0.0)]
    pretrain_minutes: f64,
    /// Single-person sources of the pre-training (dataset folders, BVH files in CMU units, or
    /// folders of them with one joint layout each).
    #[arg(long, num_args = 1.., default_values = [
        "../shared/data/bandai2", "../shared/data/cmu_bvh/131_01.bvh", "../shared/data/cmu_bvh/131_02.bvh",
        "../shared/data/cmu_bvh/131_03.bvh", "../shared/data/cmu_bvh/18_01.bvh",
    ])]
    pretrain_data: Vec<PathBuf>,
    /// Synthetic groups built from the largest pre-training source; the others get as many per
    /// second of motion (at least one).
    #[arg(long, default_value_t = 150)]
    pretrain_groups: usize,
}

/// The data of one stretch of training and its description for the checkpoint.
struct Stage {
    dataset: Dataset,
    source: String,
}

/// `socdiff bench quality`.
pub fn run(args: QualityArgs) -> Result<ExitCode> {
    // A device that cannot run is an error before anything is written.
    args.device.device.resolve()?;
    if !(args.minutes.is_finite() && args.minutes > 0.0) {
        return Err(Error::invalid(format!("--minutes {}: expected a positive number", args.minutes)));
    }
    if let Some(m) = args.score_every {
        if !(m.is_finite() && m > 0.0) {
            return Err(Error::invalid(format!("--score-every {m}: expected a positive number of minutes")));
        }
    }
    if !(args.pretrain_minutes.is_finite() && args.pretrain_minutes >= 0.0 && args.pretrain_minutes < args.minutes) {
        return Err(Error::invalid(format!("--pretrain-minutes {}: expected 0 or more, below --minutes {}", args.pretrain_minutes, args.minutes)));
    }
    let out = &args.out;
    if !args.resume {
        check_output_dir(out)?;
    } else if !Checkpoint::exists_in(&out.join("model")) && out.exists() && !out.join("model").exists() {
        return Err(Error::format(out, "--resume: holds no bench quality run (no model/)"));
    }
    let dataset = import::load(&args.data, &Default::default())?;
    let main = Stage { dataset, source: args.data.display().to_string() };
    let mut pretrain = None;
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let _lock = RunLock::acquire(out)?;
    // Training stops at the time budget, not at a step count.
    let config = TrainConfig {
        steps: 1_000_000_000,
        batch: args.batch,
        window: args.window,
        observed: Some(30),
        stride: 5,
        seed: 0,
        model: DenoiserConfig { hidden: args.hidden, social_dim: args.hidden, aggregator: Aggregator::Mean, ..Default::default() },
        adam: AdamConfig { lr: 1e-3, ..Default::default() },
        noise: args.noise,
        pose: args.pose,
        augment: AugmentConfig { body_scale: args.body_scale, limb_scale: args.body_scale / 2.0, ..Default::default() },
        save_every: 200,
        val_every: 0,
        ..Default::default()
    };
    let stop = stop_flag()?;
    let mut targets: Vec<f64> = match args.score_every {
        Some(m) => (1..).map(|i| i as f64 * m).take_while(|&t| t < args.minutes - 1e-9).collect(),
        None => Vec::new(),
    };
    targets.push(args.minutes);
    let proto = QualityProtocol { samples: args.samples, device: args.device.device, ..Default::default() };
    let mut curve = Vec::new();
    for (i, &target) in targets.iter().enumerate() {
        if !train_to(target, &args, &config, &main, &mut pretrain, &stop)? {
            eprintln!("stopped; continue with: socdiff bench quality --minutes {} --out {} --resume", args.minutes, out.display());
            return Ok(ExitCode::from(EXIT_STOPPED));
        }
        let last = i + 1 == targets.len();
        let dir = if last { out.clone() } else { out.join(format!("at-{target}min")) };
        let (quality, result) = match (last, read_quality(&dir)?) {
            (false, Some(q)) => (q, None),
            _ => {
                let (q, r) = score(&args, &main.dataset, &proto, target)?;
                if !last {
                    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
                    write_json(&dir.join("quality.json"), &q)?;
                }
                (q, Some(r))
            }
        };
        curve.push(curve_point(&quality));
        if last {
            let mut quality = quality;
            if curve.len() > 1 {
                quality["curve"] = Value::Array(curve.clone());
            }
            write_json(&out.join("quality.json"), &quality)?;
            let result = result.expect("the last point is always scored");
            write_json(&out.join("report.json"), &serde_json::to_value(&result.report).map_err(|e| Error::invalid(e.to_string()))?)?;
            println!("{}", result.report.table());
            if !result.mrt.is_empty() {
                print!("{}", result.mrt_table());
            }
            let (within, worst) = result.jump_summary();
            println!("first-frame jump ≤ the largest observed move in {within} of {} windows (worst ratio {worst:.2})", result.windows);
            if curve.len() > 1 {
                println!("quality vs training time (ours, mean of K, global MPJPE in mm at 1/2/3 s):");
                for c in &curve {
                    let mm = |k: &str| c["ours_mean_m"][k].as_f64().map_or(f64::NAN, |v| v * 1e3);
                    println!(
                        "  {:>6.1} min  step {:>7}  {:>5.0} {:>5.0} {:>5.0}",
                        c["minutes"].as_f64().unwrap_or(f64::NAN),
                        c["step"],
                        mm("1s"),
                        mm("2s"),
                        mm("3s")
                    );
                }
            }
            println!("wrote {} and report.json", out.join("quality.json").display());
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// Trains the run in `args.out/model` until `minutes` of training are spent — the first
/// `--pretrain-minutes` on the pre-training mix — false when the user stopped it (Ctrl-C).
/// `.budget-spent` holds the largest budget already spent.
fn train_to(minutes: f64, args: &QualityArgs, config: &TrainConfig, main: &Stage, pretrain: &mut Option<Stage>, stop: &Arc<AtomicBool>) -> Result<bool> {
    let done_marker = args.out.join(".budget-spent");
    let spent_budget = std::fs::read_to_string(&done_marker).ok().and_then(|t| t.trim().parse::<f64>().ok()).unwrap_or(0.0);
    if spent_budget >= minutes {
        eprintln!("train: the {minutes:.1} minutes are spent");
        return Ok(true);
    }
    let pre = args.pretrain_minutes.min(minutes);
    if pre > 0.0 && trained_seconds(args)? < pre * 60.0 - SPENT_TOLERANCE_S {
        if pretrain.is_none() {
            *pretrain = Some(pretrain_stage(args, &main.dataset)?);
        }
        if !train_stage(pre, args, config, pretrain.as_ref().expect("built above"), "pre-training", stop)? {
            return Ok(false);
        }
    }
    if !train_stage(minutes, args, config, main, if pre > 0.0 { "fine-tuning" } else { "train" }, stop)? {
        return Ok(false);
    }
    write_file_atomic(&done_marker, format!("{minutes}\n").as_bytes())?;
    Ok(true)
}

/// Seconds of training in the run's checkpoint (0 before the first).
fn trained_seconds(args: &QualityArgs) -> Result<f64> {
    let model_dir = args.out.join("model");
    Ok(if Checkpoint::exists_in(&model_dir) { Checkpoint::read_meta(&model_dir)?.elapsed_seconds } else { 0.0 })
}

/// Trains on `stage` until the checkpoint holds `minutes` of training; false when the user
/// stopped it.
fn train_stage(minutes: f64, args: &QualityArgs, config: &TrainConfig, stage: &Stage, what: &str, stop: &Arc<AtomicBool>) -> Result<bool> {
    let model_dir = args.out.join("model");
    let resume = Checkpoint::exists_in(&model_dir);
    let spent = trained_seconds(args)?;
    let budget = minutes * 60.0;
    if spent >= budget - SPENT_TOLERANCE_S {
        return Ok(true);
    }
    if stop.load(Ordering::SeqCst) {
        return Ok(false);
    }
    let deadline = Arc::new(AtomicBool::new(false));
    let (flag, hit) = (stop.clone(), deadline.clone());
    let left = Duration::from_secs_f64(budget - spent);
    std::thread::spawn(move || {
        std::thread::sleep(left);
        hit.store(true, Ordering::SeqCst);
        flag.store(true, Ordering::SeqCst);
    });
    eprintln!("{what}: {:.1} minutes until {minutes:.1} → {} on {}", (budget - spent) / 60.0, model_dir.display(), stage.source);
    let opts = TrainOptions {
        out_dir: model_dir,
        resume,
        force: false,
        // A resumed stage keeps its checkpoint's config.
        config: (!resume).then(|| config.clone()),
        source: stage.source.clone(),
        stop: Some(stop.clone()),
        device: args.device.device,
        ..Default::default()
    };
    let summary = train_with_progress(&stage.dataset, &opts)?;
    if summary.stopped && !deadline.load(Ordering::SeqCst) {
        return Ok(false);
    }
    // The deadline set the shared stop flag: clear it for the next stretch.
    stop.store(false, Ordering::SeqCst);
    Ok(true)
}

/// --data mixed with every --pretrain-data source as synthetic groups of --data's group sizes
/// (`mix_sources`; BVH folders are read in CMU units).
fn pretrain_stage(args: &QualityArgs, primary: &Dataset) -> Result<Stage> {
    let opts = ImportOptions { bvh: BvhImport { scale: CMU_SCALE, ..Default::default() }, ..Default::default() };
    let mut sets = vec![primary.clone()];
    for path in &args.pretrain_data {
        sets.push(import::load(path, &opts)?);
    }
    let mix = MixConfig { groups_by_frames: true, ..MixConfig::for_primary(primary, args.window, args.pretrain_groups, 0) };
    let (dataset, summary) = mix_sources(&sets, &mix)?;
    let labels: Vec<String> = summary.iter().map(|s| s.name.clone()).collect();
    let source = format!("pre-training mix: {}", describe_mix(&labels, &summary, &mix));
    eprintln!("{source}");
    for s in summary.iter().filter(|s| !s.joint_map.is_empty()) {
        eprintln!("  {} joints: {}", s.name, s.joint_map.join("; "));
    }
    Ok(Stage { dataset, source })
}

/// Forecasts and scores the current checkpoint: quality.json's value and the result.
fn score(args: &QualityArgs, dataset: &Dataset, proto: &QualityProtocol, minutes: f64) -> Result<(Value, QualityResult)> {
    let model = Checkpoint::load(args.out.join("model"))?;
    eprintln!(
        "forecast ({minutes} min, step {}): windows of {} observed + {} forecast frames every {} frames of the test scenes, {} samples, DDIM {}",
        model.step, proto.observe, proto.horizon, proto.stride, proto.samples, proto.ddim_steps
    );
    let bar = crate::progress::denoising((proto.ddim_steps * proto.samples) as u64);
    let result = forecast_quality(&model, dataset, &args.data, proto, &mut |i| {
        bar.inc(i.samples.len() as u64);
    });
    bar.finish_and_clear();
    let result = result?;
    eprintln!("score: {} windows through the evaluator", result.windows);
    let mut quality = result.to_json(&model, proto);
    quality["training"]["minutes"] = json!(minutes);
    quality["data"] = json!(args.data.display().to_string());
    Ok((quality, result))
}

/// One point of the quality curve from a quality.json value.
fn curve_point(q: &Value) -> Value {
    let ours = &q["protocol"]["ours"]["methods"]["ours"]["mpjpe_m"];
    let mrt = &q["protocol"]["mrt"]["methods"]["ours"]["mean"];
    let first = &q["protocol"]["ours"]["first_frame_jump"];
    json!({
        "minutes": q["training"]["minutes"], "step": q["training"]["step"],
        "ours_mean_m": {"1s": ours["1s"]["global"]["mean"], "2s": ours["2s"]["global"]["mean"], "3s": ours["3s"]["global"]["mean"]},
        "mrt_mean_m": mrt, "first_frame_jump_within": first["windows_within_observed"],
    })
}

fn read_quality(dir: &std::path::Path) -> Result<Option<Value>> {
    let path = dir.join("quality.json");
    match std::fs::read_to_string(&path) {
        Ok(t) => serde_json::from_str(&t).map(Some).map_err(|e| Error::format(&path, format!("not JSON: {e}"))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(Error::io(&path, e)),
    }
}

fn write_json(path: &std::path::Path, v: &Value) -> Result<()> {
    let text = serde_json::to_string_pretty(v).map_err(|e| Error::invalid(e.to_string()))?;
    write_file_atomic(path, text.as_bytes())
}
