//! The quality benchmark (`socdiff bench quality`): train the recommended recipe for a budget
//! of wall time, forecast windows of the test split and score them with the baselines through
//! the one evaluator ([`super::forecast_quality`]). Resumable: the training time already spent
//! counts, and a larger budget continues the training.
//!
//! ```text
//! out/model/           the training run (a resumable checkpoint)
//! out/.budget-spent    the largest budget (minutes) already trained
//! out/at-<M>min/       quality.json of the intermediate scores (`score_every`)
//! out/quality.json     every number, keyed by protocol, method and horizon (+ "curve")
//! out/report.json      the evaluator's report of the last score
//! ```

use super::{QualityProtocol, QualityResult, Runner};
use crate::checkpoint::Checkpoint;
use crate::data::bvh::{BvhImport, CMU_SCALE};
use crate::data::import::{self, ImportOptions};
use crate::files::{check_output_dir, write_file_atomic, write_json_atomic, RunLock};
use crate::model::{DenoiserConfig, DeviceChoice};
use crate::train::data::{describe_mix, mix_sources, MixConfig};
use crate::train::{AugmentConfig, Preset, TrainConfig, TrainOptions};
use crate::{Dataset, Error, Result};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// `socdiff bench quality`'s options ([`QualityArgs::bench`]).
#[derive(Clone, Debug)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct QualityArgs {
    #[cfg_attr(feature = "clap", command(flatten))]
    pub device: crate::model::DeviceArg,
    /// Minutes of training (wall time, over all resumes).
    #[cfg_attr(feature = "clap", arg(long))]
    pub minutes: f64,
    /// Output folder: model/ (the run), quality.json, report.json.
    #[cfg_attr(feature = "clap", arg(long))]
    pub out: PathBuf,
    /// Dataset with train and test splits.
    #[cfg_attr(feature = "clap", arg(long, default_value = "../shared/data/mupots3d"))]
    pub data: PathBuf,
    /// Continue an interrupted run in --out.
    #[cfg_attr(feature = "clap", arg(long))]
    pub resume: bool,
    /// Noise levels of training (the config field `noise`: uniform, prefix, per-frame or
    /// per-frame-monotone).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "prefix"))]
    pub noise: crate::train::NoiseLevels,
    /// U-Net width.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 64))]
    pub hidden: usize,
    /// Training windows per batch.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 16))]
    pub batch: usize,
    /// Training window (frames).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 120))]
    pub window: usize,
    /// Body-proportion augmentation (the config field `augment.body_scale`; limbs get half of
    /// it; 0: off). On by default: it measured best (docs/results.md).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 0.1))]
    pub body_scale: f64,
    /// Pose encoding of training (the config field `pose`). Residual by default: it measured
    /// best (docs/results.md).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "residual"))]
    pub pose: crate::features::PoseEncoding,
    /// Samples per window.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 8))]
    pub samples: usize,
    /// Also score the model after every M minutes of training: the curve of quality against
    /// training time (DIR/at-<minutes>min/quality.json, and "curve" in quality.json).
    #[cfg_attr(feature = "clap", arg(long, value_name = "M"))]
    pub score_every: Option<f64>,
    /// Pre-training: the first M of the --minutes go to --data mixed with --pretrain-data as
    /// synthetic groups (`socdiff train` with several --data), the rest to fine-tuning on --data
    /// alone. 0: no pre-training.
    #[cfg_attr(feature = "clap", arg(long, value_name = "M", default_value_t = 0.0))]
    pub pretrain_minutes: f64,
    /// Single-person sources of the pre-training (dataset folders, BVH files in CMU units, or
    /// folders of them with one joint layout each).
    #[cfg_attr(feature = "clap", arg(long, num_args = 1.., default_values = [
        "../shared/data/bandai2", "../shared/data/cmu_bvh/131_01.bvh", "../shared/data/cmu_bvh/131_02.bvh",
        "../shared/data/cmu_bvh/131_03.bvh", "../shared/data/cmu_bvh/18_01.bvh",
    ]))]
    pub pretrain_data: Vec<PathBuf>,
    /// Synthetic groups built from the largest pre-training source; the others get as many per
    /// second of motion (at least one).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 150))]
    pub pretrain_groups: usize,
}

impl QualityArgs {
    /// The benchmark these options describe.
    pub fn bench(&self) -> QualityBench {
        let device = self.device.device;
        let mut config = QualityBench::recipe(self.hidden, self.batch, self.window, self.body_scale);
        (config.noise, config.pose) = (self.noise, self.pose);
        QualityBench {
            out: self.out.clone(),
            resume: self.resume,
            data: self.data.clone(),
            minutes: self.minutes,
            score_every: self.score_every,
            pretrain_minutes: self.pretrain_minutes,
            pretrain_data: self.pretrain_data.clone(),
            pretrain_groups: self.pretrain_groups,
            config,
            protocol: QualityProtocol { samples: self.samples, device, ..Default::default() },
            device,
        }
    }
}

/// Seconds within which a training budget counts as spent (the deadline stops a step later or
/// earlier).
const SPENT_TOLERANCE_S: f64 = 1.0;

/// One quality benchmark.
#[derive(Clone, Debug)]
pub struct QualityBench {
    /// Output folder (see the module docs).
    pub out: PathBuf,
    /// Continue an interrupted run in `out`.
    pub resume: bool,
    /// Dataset with train and test splits.
    pub data: PathBuf,
    /// Minutes of training (wall time, over all resumes).
    pub minutes: f64,
    /// Also score after every this many minutes (the quality curve).
    pub score_every: Option<f64>,
    /// The first this many of `minutes` train on `data` mixed with `pretrain_data` as
    /// synthetic groups, the rest fine-tune on `data` alone (0: no pre-training).
    pub pretrain_minutes: f64,
    /// Single-person sources of the pre-training (BVH in CMU units).
    pub pretrain_data: Vec<PathBuf>,
    /// Synthetic groups from the largest pre-training source.
    pub pretrain_groups: usize,
    /// The training recipe ([`QualityBench::recipe`]); its steps are not a limit, the budget is.
    pub config: TrainConfig,
    /// How the model is forecast and scored.
    pub protocol: QualityProtocol,
    /// Where the network trains (the protocol says where it samples).
    pub device: DeviceChoice,
}

impl QualityBench {
    /// The recommended recipe ([`Preset::Recommended`]) at `hidden`, `batch`, `window` and
    /// body-proportion augmentation `body_scale` (limbs half of it); it stops at the time
    /// budget, not at a step count.
    pub fn recipe(hidden: usize, batch: usize, window: usize, body_scale: f64) -> TrainConfig {
        let base = Preset::Recommended.config();
        TrainConfig {
            steps: 1_000_000_000,
            batch,
            window,
            observed: Some(30),
            model: DenoiserConfig { hidden, social_dim: hidden, ..base.model.clone() },
            augment: AugmentConfig { body_scale, limb_scale: body_scale / 2.0, ..base.augment.clone() },
            val_every: 0,
            ..base
        }
    }

    fn model_dir(&self) -> PathBuf {
        self.out.join("model")
    }

    /// Seconds of training in the run's checkpoint (0 before the first).
    fn trained_seconds(&self) -> Result<f64> {
        let dir = self.model_dir();
        Ok(if Checkpoint::exists_in(&dir) { Checkpoint::read_meta(&dir)?.elapsed_seconds } else { 0.0 })
    }
}

/// How a quality benchmark ended.
pub enum QualityOutcome {
    /// `stop` was set (Ctrl-C); rerun with `resume` to continue.
    Stopped,
    /// Trained and scored.
    Done {
        /// The last score (also in `out/report.json`).
        result: Box<QualityResult>,
        /// One point per score: minutes, step, our mean MPJPE at 1/2/3 s (`ours_mean_m`), MRT's.
        curve: Vec<Value>,
    },
}

/// The data of one stretch of training and its description for the checkpoint.
struct Stage {
    dataset: Dataset,
    source: String,
}

/// Runs `bench` (see the module docs); `stop` ends it early (and is used for the deadline).
pub fn run_quality_bench(bench: &QualityBench, stop: &Arc<AtomicBool>, runner: &mut dyn Runner) -> Result<QualityOutcome> {
    // A device that cannot run is an error before anything is written.
    bench.device.resolve()?;
    if !(bench.minutes.is_finite() && bench.minutes > 0.0) {
        return Err(Error::invalid(format!("`minutes` {}: expected a positive number", bench.minutes)));
    }
    if let Some(m) = bench.score_every {
        if !(m.is_finite() && m > 0.0) {
            return Err(Error::invalid(format!("`score_every` {m}: expected a positive number of minutes")));
        }
    }
    if !(bench.pretrain_minutes.is_finite() && bench.pretrain_minutes >= 0.0 && bench.pretrain_minutes < bench.minutes) {
        return Err(Error::invalid(format!("`pretrain_minutes` {}: expected 0 or more, below `minutes` {}", bench.pretrain_minutes, bench.minutes)));
    }
    let out = &bench.out;
    if !bench.resume {
        check_output_dir(out)?;
    } else if !Checkpoint::exists_in(&bench.model_dir()) && out.exists() && !bench.model_dir().exists() {
        return Err(Error::format(out, "`resume`: holds no bench quality run (no model/)"));
    }
    let main = Stage { dataset: import::load(&bench.data, &Default::default())?, source: bench.data.display().to_string() };
    let mut pretrain = None;
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let _lock = RunLock::acquire(out)?;
    let mut targets: Vec<f64> = match bench.score_every {
        Some(m) => (1..).map(|i| i as f64 * m).take_while(|&t| t < bench.minutes - 1e-9).collect(),
        None => Vec::new(),
    };
    targets.push(bench.minutes);
    let mut curve = Vec::new();
    for (i, &target) in targets.iter().enumerate() {
        if !train_to(bench, target, &main, &mut pretrain, stop, runner)? {
            return Ok(QualityOutcome::Stopped);
        }
        let last = i + 1 == targets.len();
        let dir = if last { out.clone() } else { out.join(format!("at-{target}min")) };
        let (mut quality, result) = match (last, read_quality(&dir)?) {
            (false, Some(q)) => (q, None),
            _ => {
                let (q, r) = score(bench, &main.dataset, target, runner)?;
                if !last {
                    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
                    write_json_atomic(&dir.join("quality.json"), &q)?;
                }
                (q, Some(r))
            }
        };
        curve.push(curve_point(&quality));
        if last {
            if curve.len() > 1 {
                quality["curve"] = Value::Array(curve.clone());
            }
            write_json_atomic(&out.join("quality.json"), &quality)?;
            let result = result.expect("the last point is always scored");
            write_json_atomic(&out.join("report.json"), &result.report)?;
            return Ok(QualityOutcome::Done { result: Box::new(result), curve });
        }
    }
    unreachable!("the last target returns")
}

/// Trains until `minutes` of training are spent — the first `pretrain_minutes` on the
/// pre-training mix — false when stopped. `.budget-spent` holds the largest budget spent.
fn train_to(bench: &QualityBench, minutes: f64, main: &Stage, pretrain: &mut Option<Stage>, stop: &Arc<AtomicBool>, runner: &mut dyn Runner) -> Result<bool> {
    let done_marker = bench.out.join(".budget-spent");
    let spent_budget = std::fs::read_to_string(&done_marker).ok().and_then(|t| t.trim().parse::<f64>().ok()).unwrap_or(0.0);
    if spent_budget >= minutes {
        runner.say(&format!("train: the {minutes:.1} minutes are spent"));
        return Ok(true);
    }
    let pre = bench.pretrain_minutes.min(minutes);
    if pre > 0.0 && bench.trained_seconds()? < pre * 60.0 - SPENT_TOLERANCE_S {
        if pretrain.is_none() {
            *pretrain = Some(pretrain_stage(bench, &main.dataset, runner)?);
        }
        if !train_stage(bench, pre, pretrain.as_ref().expect("built above"), "pre-training", stop, runner)? {
            return Ok(false);
        }
    }
    if !train_stage(bench, minutes, main, if pre > 0.0 { "fine-tuning" } else { "train" }, stop, runner)? {
        return Ok(false);
    }
    write_file_atomic(&done_marker, format!("{minutes}\n").as_bytes())?;
    Ok(true)
}

/// Trains on `stage` until the checkpoint holds `minutes` of training; false when stopped.
fn train_stage(bench: &QualityBench, minutes: f64, stage: &Stage, what: &str, stop: &Arc<AtomicBool>, runner: &mut dyn Runner) -> Result<bool> {
    let model_dir = bench.model_dir();
    let resume = Checkpoint::exists_in(&model_dir);
    let spent = bench.trained_seconds()?;
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
    runner.say(&format!("{what}: {:.1} minutes until {minutes:.1} → {} on {}", (budget - spent) / 60.0, model_dir.display(), stage.source));
    let opts = TrainOptions {
        out_dir: model_dir,
        resume,
        force: false,
        // A resumed stage keeps its checkpoint's config.
        config: (!resume).then(|| bench.config.clone()),
        source: stage.source.clone(),
        stop: Some(stop.clone()),
        device: bench.device,
        ..Default::default()
    };
    let summary = runner.train(&stage.dataset, &opts)?;
    if summary.stopped && !deadline.load(Ordering::SeqCst) {
        return Ok(false);
    }
    // The deadline set the shared stop flag: clear it for the next stretch.
    stop.store(false, Ordering::SeqCst);
    Ok(true)
}

/// `data` mixed with every pre-training source as synthetic groups of its group sizes
/// (`mix_sources`; BVH is read in CMU units).
fn pretrain_stage(bench: &QualityBench, primary: &Dataset, runner: &mut dyn Runner) -> Result<Stage> {
    let opts = ImportOptions { bvh: BvhImport { scale: CMU_SCALE, ..Default::default() }, ..Default::default() };
    let mut sets = vec![primary.clone()];
    for path in &bench.pretrain_data {
        sets.push(import::load(path, &opts)?);
    }
    let mix = MixConfig { groups_by_frames: true, ..MixConfig::for_primary(primary, bench.config.window, bench.pretrain_groups, 0) };
    let (dataset, summary) = mix_sources(&sets, &mix)?;
    let labels: Vec<String> = summary.iter().map(|s| s.name.clone()).collect();
    let source = format!("pre-training mix: {}", describe_mix(&labels, &summary, &mix));
    runner.say(&source);
    for s in summary.iter().filter(|s| !s.joint_map.is_empty()) {
        runner.say(&format!("  {} joints: {}", s.name, s.joint_map.join("; ")));
    }
    Ok(Stage { dataset, source })
}

/// Forecasts and scores the current checkpoint: quality.json's value and the result.
fn score(bench: &QualityBench, dataset: &Dataset, minutes: f64, runner: &mut dyn Runner) -> Result<(Value, QualityResult)> {
    let model = Checkpoint::load(bench.model_dir())?;
    let proto = &bench.protocol;
    runner.say(&format!(
        "forecast ({minutes} min, step {}): windows of {} observed + {} forecast frames every {} frames of the test scenes, {} samples, DDIM {}",
        model.step, proto.observe, proto.horizon, proto.stride, proto.samples, proto.ddim_steps
    ));
    let result = runner.quality(&model, dataset, &bench.data, proto)?;
    runner.say(&format!("score: {} windows through the evaluator", result.windows));
    let mut quality = result.to_json(&model, proto);
    quality["training"]["minutes"] = json!(minutes);
    quality["data"] = json!(bench.data.display().to_string());
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

fn read_quality(dir: &Path) -> Result<Option<Value>> {
    let path = dir.join("quality.json");
    match std::fs::read_to_string(&path) {
        Ok(t) => serde_json::from_str(&t).map(Some).map_err(|e| Error::format(&path, format!("not JSON: {e}"))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(Error::io(&path, e)),
    }
}
