//! Training the denoiser (METHOD.md §4, REFERENCE.md §3.2–3.3).
//!
//! ```text
//! dataset ─ train split ─ WindowSet (windows grouped by person count)
//!         └ test split ── WindowSet (≤ val_windows windows, validation loss)
//! for step s in start..steps:
//!     batch  = epoch_plan(seed, ⌊s/n⌋)[s mod n]     anchored, standardized x0 [B, P, T, δ] + anchors
//!     t, ε   ~ RNG(seed, s)                          t uniform in 0..T, ε ~ N(0, I)
//!     loss   = mean |g(√ᾱ_t x0 + √(1−ᾱ_t) ε, t) − x0|   (x0 objective, L1, all frames/persons)
//!     Adam step; EMA update (copy until warm-up, then decay every update_every steps)
//!     log {step, loss, lr, seconds}; validation every val_every; checkpoint every save_every
//! ```
//!
//! - [`config`]: [`TrainConfig`] and its parts, layered defaults ← file ← overrides;
//! - [`data`]: [`WindowSet`], batches with equal P, the seeded random streams;
//! - [`optimizer`]: [`Adam`] and [`Ema`];
//! - [`checkpoint`]: [`Checkpoint`] (safetensors + JSON sidecar) and [`LoadedModel`] for
//!   forecasting.
//!
//! # Reproducibility
//! Every random draw is a function of the seed: initialization (seed), the batch order of
//! epoch e (seed, e), t, ε and augmentation of step s (seed, s). A checkpoint therefore only
//! needs the step to continue exactly: N steps + resume + N steps gives the same losses and
//! weights as 2N steps (tested). The custom ops are deterministic (CANDLE_NOTES.md), so this
//! holds bit for bit on one machine.
//!
//! # Safety of files
//! All checks (config values, data, a checkpoint's config and skeleton on resume) run before
//! anything is written, so a failed start leaves the output directory untouched. A fresh run
//! refuses a directory that already holds a checkpoint.

pub mod data;
pub mod distill;
pub mod optimizer;
pub mod overrides;
#[cfg(test)]
pub(crate) mod tests;

use crate::checkpoint::{self, Checkpoint, CheckpointMeta, DataSummary, Weights};
// The run's configuration is recorded in its checkpoint, so it lives there; training is where
// it is written.
pub use crate::checkpoint::config::{
    AdamConfig, AugmentConfig, EmaConfig, LrSchedule, MixSettings, NoiseLevels, PersonRange, Preset, TrainConfig, WindowBalance,
};
pub use data::{Batch, WindowSet};
pub use optimizer::{Adam, Ema};
pub use overrides::{RunOverrides, TrainOverrides, TrainSources, TrainingData};

use crate::data::{Dataset, Scene, Split};
use crate::diffusion::{standard_normal, GaussianDiffusion};
use crate::features::{feature_dim, Standardization};
use crate::model::Parameterized;
use crate::model::{Denoiser, DeviceChoice, Placement, Precision};
use crate::{bail, Error, Result};
use candle_core::Tensor;
use data::{stream_rng, Stream};
use rand::rngs::StdRng;
use rand::Rng;
use serde_json::{json, Value};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

/// The optimizer's state: online network, EMA, Adam, and the diffusion process.
pub struct Learner {
    model: Denoiser,
    ema: Ema,
    adam: Adam,
    diffusion: GaussianDiffusion,
    noise: NoiseLevels,
    observed: usize,
    /// Velocity scales `[δ]` and weight of the loss's velocity term, when on.
    velocity: Option<(Tensor, f64)>,
    /// The teacher of a distillation round: the loss is [`distill::Teacher::loss`].
    teacher: Option<Box<distill::Teacher>>,
}

impl Learner {
    /// A fresh learner at `placement`: network initialized from `cfg.seed`, EMA = copy, zero
    /// Adam moments.
    pub fn new(cfg: &TrainConfig, placement: &Placement) -> Result<Self> {
        let model = Denoiser::build(cfg.model.clone(), cfg.seed, placement)?;
        let ema = Ema::new(&model, cfg.ema.clone())?;
        let adam = Adam::new(model.named_vars(), cfg.adam.clone())?;
        Self::assemble(model, ema, adam, cfg)
    }

    /// The state saved in `ck` (online and EMA weights, Adam moments and step count), at
    /// `placement`.
    pub fn restore(ck: &Checkpoint, placement: &Placement) -> Result<Self> {
        let cfg = &ck.meta.config;
        let model = ck.denoiser_at(Weights::Online, placement)?;
        let ema = Ema::from_model(ck.denoiser_at(Weights::Ema, placement)?, cfg.ema.clone());
        let mut adam = Adam::new(model.named_vars(), cfg.adam.clone())?;
        adam.restore(ck.meta.step, ck.adam_moments(&model)?)?;
        Self::assemble(model, ema, adam, cfg)
    }

    /// A fresh run (step 0, new Adam state) whose online and EMA networks start from `ck`'s
    /// EMA weights, for fine-tuning; `cfg` must describe the same network
    /// ([`init_checkpoint`] checks).
    pub fn initialized(ck: &Checkpoint, cfg: &TrainConfig, placement: &Placement) -> Result<Self> {
        let model = ck.denoiser_at(Weights::Ema, placement)?;
        let ema = Ema::from_model(ck.denoiser_at(Weights::Ema, placement)?, cfg.ema.clone());
        let adam = Adam::new(model.named_vars(), cfg.adam.clone())?;
        Self::assemble(model, ema, adam, cfg)
    }

    /// Turns on the loss's velocity term with weight `weight` and per-dim scales `scales`
    /// ([`WindowSet::velocity_scales`]); weight 0 turns it off.
    pub fn set_velocity_loss(&mut self, scales: &[f32], weight: f64) -> Result<()> {
        self.velocity = if weight > 0.0 { Some((Tensor::from_slice(scales, scales.len(), self.model.device())?, weight)) } else { None };
        Ok(())
    }

    /// The learner of `cfg` around its networks and optimizer (no velocity term, no teacher).
    fn assemble(model: Denoiser, ema: Ema, adam: Adam, cfg: &TrainConfig) -> Result<Self> {
        let diffusion = GaussianDiffusion::new(&cfg.diffusion)?;
        Ok(Self { model, ema, adam, diffusion, noise: cfg.noise, observed: cfg.observed_frames(), velocity: None, teacher: None })
    }

    /// Makes every step a distillation step from `teacher` ([`distill`]).
    pub fn set_teacher(&mut self, teacher: distill::Teacher) {
        self.teacher = Some(Box::new(teacher));
    }

    /// Optimizer steps done.
    pub fn step(&self) -> u64 {
        self.adam.steps()
    }

    /// The online network.
    pub fn model(&self) -> &Denoiser {
        &self.model
    }

    /// The EMA network.
    pub fn ema(&self) -> &Denoiser {
        self.ema.model()
    }

    /// The optimizer.
    pub fn adam(&self) -> &Adam {
        &self.adam
    }

    /// Sets the run's length in optimizer steps, the end of the learning-rate schedule.
    pub fn set_run_steps(&mut self, total: u64) {
        self.adam.set_run_steps(total);
    }

    /// The diffusion process.
    pub fn diffusion(&self) -> &GaussianDiffusion {
        &self.diffusion
    }

    /// Draws t (uniform in 0..T, one per window) and then ε ~ N(0, I) from `rng`.
    fn draw(&self, rng: &mut StdRng, x0: &Tensor) -> Result<(Vec<usize>, Tensor)> {
        let t = self.diffusion.sample_timesteps(rng, x0.dim(0)?);
        let noise = Tensor::from_vec(standard_normal(rng, x0.elem_count()), x0.shape(), x0.device())?;
        Ok((t, noise))
    }

    /// The loss of `model` on `batch` with levels drawn as `levels` says (see [`NoiseLevels`]);
    /// `observed`: the observed frames of the forecasting setup.
    fn loss(&self, model: &Denoiser, batch: &Batch, levels: NoiseLevels, observed: usize, rng: &mut StdRng) -> Result<Tensor> {
        if let Some(teacher) = &self.teacher {
            return teacher.loss(model, batch, rng);
        }
        // Batches are built on the host; one copy each to the network's device.
        let x0 = &batch.x0.to_device(model.device())?;
        let anchors = batch.anchors.to_device(model.device())?;
        if levels == NoiseLevels::Uniform {
            let (t, noise) = self.draw(rng, x0)?;
            let velocity = self.velocity.as_ref().map(|(s, w)| (s, *w));
            return self.diffusion.loss_with_velocity(model, x0, Some(&anchors), &t, &noise, velocity);
        }
        let (b, p, nt, _) = x0.dims4()?;
        let steps = self.diffusion.timesteps();
        let mut lv: Vec<Option<usize>> = Vec::with_capacity(b * p * nt);
        for _ in 0..b {
            match levels {
                NoiseLevels::Prefix => {
                    // Half the windows: the forecasting setup; the others: any clean prefix.
                    let clean = if rng.gen_bool(0.5) { observed.min(nt - 1) } else { rng.gen_range(0..nt) };
                    let t = rng.gen_range(0..steps);
                    for _ in 0..p {
                        lv.extend((0..nt).map(|f| (f >= clean).then_some(t)));
                    }
                }
                NoiseLevels::PerFrame { monotone } => {
                    for _ in 0..p {
                        let mut v: Vec<usize> = (0..nt).map(|_| rng.gen_range(0..steps)).collect();
                        if monotone {
                            v.sort_unstable();
                        }
                        lv.extend(v.into_iter().map(Some));
                    }
                }
                NoiseLevels::Uniform => unreachable!("handled above"),
            }
        }
        let noise = Tensor::from_vec(standard_normal(rng, x0.elem_count()), x0.shape(), x0.device())?;
        self.diffusion.loss_per_frame(model, x0, Some(&anchors), &lv, &noise)
    }

    /// One optimizer step on `batch` (levels and ε drawn from `rng` as `cfg.noise` says): loss,
    /// backward, Adam, EMA. Returns the loss before the update. A non-finite loss is an error
    /// and changes nothing.
    pub fn train_step(&mut self, batch: &Batch, rng: &mut StdRng) -> Result<f32> {
        use crate::model::profile::Timer;
        let forward = Timer::start("step: forward + loss");
        let loss = self.loss(&self.model, batch, self.noise, self.observed, rng)?;
        let value = loss.to_scalar::<f32>()?;
        drop(forward);
        if !value.is_finite() {
            bail!("training: the loss is {value} at step {}", self.step() + 1);
        }
        let backward = Timer::start("step: backward");
        let grads = loss.backward()?;
        drop(backward);
        let adam = Timer::start("step: Adam");
        self.adam.step(&grads)?;
        drop(adam);
        let _ema = Timer::start("step: EMA");
        self.ema.update(self.adam.steps(), &self.model)?;
        Ok(value)
    }

    /// The loss of `model` (use a frozen network) on `batch`, without gradients.
    pub fn eval_loss(&self, model: &Denoiser, batch: &Batch, rng: &mut StdRng) -> Result<f32> {
        Ok(self.loss(model, batch, self.noise, self.observed, rng)?.to_scalar::<f32>()?)
    }
}

/// How to run [`train`].
#[derive(Clone, Debug, Default)]
pub struct TrainOptions {
    /// Run directory: checkpoint, sidecar, log, config.
    pub out_dir: PathBuf,
    /// Continue the checkpoint in `out_dir`. A run directory whose run stopped before its first
    /// checkpoint starts over.
    pub resume: bool,
    /// Start over in a run directory that holds an earlier run's checkpoint (its checkpoint,
    /// log and config are replaced).
    pub force: bool,
    /// The run's configuration (`model.feature_dims` is set from the data). `None`: the
    /// defaults, or with `resume` the checkpoint's own (a run restarted before its first save:
    /// its `config.json`). A resumed run may differ from its checkpoint only in
    /// [`crate::checkpoint::config::RESUMABLE_FIELDS`] (e.g. more `steps`).
    pub config: Option<TrainConfig>,
    /// Where the data came from (recorded in the checkpoint).
    pub source: String,
    /// Set to stop after the current step (Ctrl-C); a checkpoint is saved first.
    pub stop: Option<Arc<AtomicBool>>,
    /// Device to train on (recorded in the checkpoint; any device resumes any checkpoint).
    pub device: DeviceChoice,
    /// Precision of the convolutions' products (bf16 on GPUs only).
    pub precision: Precision,
    /// Start from this checkpoint's inference (EMA) weights and its feature standardization,
    /// with a fresh optimizer at step 0 (fine-tuning). Its skeleton, frame rate, network and
    /// pose encoding must be the run's. Not with `resume`.
    pub init: Option<PathBuf>,
}

/// What [`train`] reports while it runs.
#[derive(Clone, Debug)]
pub enum TrainEvent {
    /// Training starts (or resumes) at `first_step`.
    Started {
        /// Steps already done.
        first_step: u64,
        /// Total steps of the run.
        total_steps: u64,
        /// Scalar parameters of the network.
        params: usize,
        /// Training windows.
        train_windows: usize,
        /// Validation windows (0: no validation).
        val_windows: usize,
        /// Batches per epoch.
        batches_per_epoch: usize,
        /// The resolved configuration.
        config: Box<TrainConfig>,
        /// Where it runs ([`Placement::describe`]).
        device: String,
    },
    /// A step finished.
    Step {
        /// Steps done (1-based).
        step: u64,
        /// Its loss.
        loss: f32,
        /// Learning rate.
        lr: f64,
        /// Training seconds so far (over all resumes).
        seconds: f64,
    },
    /// A validation loss (EMA weights) after `step`.
    Validation {
        /// Steps done.
        step: u64,
        /// Mean loss over the validation windows.
        loss: f32,
    },
    /// A checkpoint was written.
    Saved(CheckpointSaved),
    /// Something the user should know (no validation data, data changed since the checkpoint…).
    Notice(String),
}

/// A checkpoint that a training run (the denoiser's or the classifiers') wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct CheckpointSaved {
    /// Steps done.
    pub step: u64,
    /// The safetensors file.
    pub path: PathBuf,
}

/// What a call of [`train`] (or of the classifiers' `train`, with their config `C`) did.
#[derive(Clone, Debug)]
pub struct TrainSummary<C = TrainConfig> {
    /// The resolved configuration.
    pub config: C,
    /// Step the call started from.
    pub first_step: u64,
    /// Steps done when it returned.
    pub last_step: u64,
    /// Loss of every step of this call.
    pub losses: Vec<f32>,
    /// Validation losses `(step, loss)` of this call (none for the classifiers).
    pub val_losses: Vec<(u64, f32)>,
    /// Stopped early by the stop flag.
    pub stopped: bool,
    /// Ended because its time budget ([`TrainConfig::minutes`]) was spent.
    pub out_of_time: bool,
    /// The checkpoint's safetensors file.
    pub checkpoint: PathBuf,
}

impl<C> TrainSummary<C> {
    /// A call that starts at `first_step` and checkpoints to `checkpoint`, nothing done yet.
    pub fn starting(config: C, first_step: u64, checkpoint: PathBuf) -> Self {
        Self { config, first_step, last_step: first_step, losses: Vec::new(), val_losses: Vec::new(), stopped: false, out_of_time: false, checkpoint }
    }
}

/// The scenes of `split` (copies).
fn split_scenes(dataset: &Dataset, split: Split) -> Vec<Scene> {
    dataset.split(split).cloned().collect()
}

/// Checks that `scenes` share one skeleton layout (joint count, body-frame joints) and frame rate.
pub(crate) fn check_uniform<'a>(scenes: impl IntoIterator<Item = &'a Scene>, what: &str) -> Result<()> {
    let mut it = scenes.into_iter();
    let Some(first) = it.next() else { return Ok(()) };
    for s in it {
        if s.skeleton.num_joints() != first.skeleton.num_joints() || (s.skeleton.left, s.skeleton.right) != (first.skeleton.left, first.skeleton.right) {
            bail!(
                "{what}: sequence {} has skeleton {} ({} joints) but {} has {} ({} joints); train on one skeleton",
                s.name,
                s.skeleton.name,
                s.skeleton.num_joints(),
                first.name,
                first.skeleton.name,
                first.skeleton.num_joints()
            );
        }
        if (s.fps - first.fps).abs() > 1e-6 * first.fps {
            bail!("{what}: sequence {} is at {} fps but {} at {} fps; resample them to one rate first", s.name, s.fps, first.name, first.fps);
        }
    }
    Ok(())
}

/// Keeps the log lines of steps ≤ `step` (a resumed run rewrites what followed its checkpoint).
fn truncate_log(path: &Path, step: u64) -> Result<()> {
    let Ok(text) = std::fs::read_to_string(path) else { return Ok(()) };
    let kept: String = text
        .lines()
        .filter(|l| serde_json::from_str::<Value>(l).ok().and_then(|v| v["step"].as_u64()).is_some_and(|s| s <= step))
        .map(|l| format!("{l}\n"))
        .collect();
    crate::files::write_file_atomic(path, kept.as_bytes())
}

/// The validation windows: at the training window length, or, when every validation sequence
/// is shorter (MuPoTS test: 501 frames vs 512), at the longest multiple of 8 that fits — the
/// network is fully convolutional, so a shorter window measures the same objective.
/// Returns the shortened length when it had to shorten.
fn validation_windows(scenes: Vec<Scene>, cfg: &TrainConfig) -> Result<(WindowSet, Option<usize>)> {
    let longest = scenes.iter().map(Scene::num_frames).max().unwrap_or(0);
    if longest >= cfg.window {
        return Ok((WindowSet::new(scenes, cfg, Some(cfg.val_windows))?, None));
    }
    let len = longest / 8 * 8;
    if len <= cfg.anchor_offset() + 1 {
        bail!("every sequence ({longest} frames at most) is shorter than the {}-frame window and the {} observed frames", cfg.window, cfg.observed_frames());
    }
    let short = TrainConfig { window: len, observed: Some(cfg.observed_frames()), ..cfg.clone() };
    Ok((WindowSet::new(scenes, &short, Some(cfg.val_windows))?, Some(len)))
}

/// Mean loss of the EMA network over the validation windows, with the same t and ε every time.
fn validation_loss(learner: &Learner, val: &WindowSet, std: &Standardization, cfg: &TrainConfig) -> Result<f32> {
    let ema = learner.ema().frozen();
    let mut rng = stream_rng(cfg.seed, Stream::Validation, 0);
    let (mut sum, mut n) = (0.0f64, 0usize);
    for idx in val.ordered_plan(cfg.batch) {
        let batch = val.batch(&idx, std, &AugmentConfig::default(), &mut rng)?;
        sum += learner.eval_loss(&ema, &batch, &mut rng)? as f64 * idx.len() as f64;
        n += idx.len();
    }
    Ok((sum / n.max(1) as f64) as f32)
}

/// Trains (or resumes) a model on the train split of `dataset`, writing checkpoints, the log
/// and the config into `opts.out_dir`, and reporting progress through `on_event`.
///
/// Errors before anything is written: bad config values, no train sequences, mixed skeletons
/// or frame rates, a window longer than every sequence, no usable window, a fresh run into a
/// directory holding a checkpoint, and on resume a missing/foreign checkpoint, a skeleton or fps
/// that differs from the checkpoint's, or overrides of fields that an exact resume cannot
/// change (see [`crate::checkpoint::config::RESUMABLE_FIELDS`]).
pub fn train(dataset: &Dataset, opts: &TrainOptions, on_event: &mut dyn FnMut(&TrainEvent)) -> Result<TrainSummary> {
    let out = &opts.out_dir;
    if (out.exists() || out.is_symlink()) && !out.is_dir() {
        return Err(Error::format(out, "exists and is not a directory"));
    }
    if opts.resume && !out.is_dir() {
        bail!("`resume`: {} does not exist", out.display());
    }
    let created = !out.exists();
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let lock = crate::files::RunLock::acquire(out);
    let result = lock.and_then(|_lock| train_locked(dataset, opts, on_event));
    if result.is_err() && created {
        // A failed start leaves nothing behind in a directory it made.
        let only_lock = std::fs::read_dir(out).map(|d| d.flatten().all(|e| e.file_name() == crate::files::LOCK_FILE)).unwrap_or(false);
        if only_lock {
            let _ = std::fs::remove_dir_all(out);
        }
    }
    result
}

/// What a run directory holds, looked at under its lock.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum RunDir {
    /// Nothing but (maybe) the lock.
    Empty,
    /// A socdiff run (marker or checkpoint present); `checkpoint`: a checkpoint to continue.
    Run { checkpoint: bool },
    /// Files socdiff did not write.
    Foreign,
}

/// A step whose loss is this many times the lowest of the run so far (or not finite) stops it.
pub const DIVERGED_FACTOR: f64 = 1000.0;

/// Writes `dir/checkpoint.safetensors` (the online and EMA weights and Adam's moments),
/// `dir/model.safetensors` (the EMA weights alone) and `dir/checkpoint.json`, each through a
/// temp file and a rename. Returns the checkpoint's path.
pub(crate) fn save_checkpoint(dir: &Path, meta: &CheckpointMeta, online: &Denoiser, ema: &Denoiser, adam: &Adam) -> Result<PathBuf> {
    use crate::checkpoint::{
        f32_le_bytes, write_checkpoint_file, TensorBytes, FORMAT, MODEL_FILE, PREFIX_ADAM_M, PREFIX_ADAM_V, PREFIX_EMA, PREFIX_ONLINE, PREV_TENSORS_FILE,
    };
    let mut tensors: Vec<TensorBytes> = Vec::new();
    let mut push = |name: String, shape: Vec<usize>, values: &[f32]| tensors.push((name, shape, f32_le_bytes(values)));
    let online_vars = online.named_vars();
    for (name, var) in &online_vars {
        push(format!("{PREFIX_ONLINE}{name}"), var.dims().to_vec(), &optimizer::var_values(var)?);
    }
    for (name, var) in ema.named_vars() {
        push(format!("{PREFIX_EMA}{name}"), var.dims().to_vec(), &optimizer::var_values(&var)?);
    }
    for ((name, m, v), (_, var)) in adam.moments()?.into_iter().zip(&online_vars) {
        push(format!("{PREFIX_ADAM_M}{name}"), var.dims().to_vec(), &m);
        push(format!("{PREFIX_ADAM_V}{name}"), var.dims().to_vec(), &v);
    }
    let tensors_path = dir.join(&meta.tensors);
    write_checkpoint_file(&tensors_path, &tensors, FORMAT, meta.step, meta, Some(&dir.join(PREV_TENSORS_FILE)))?;
    // The inference weights alone, for sharing (their own description names their file).
    let inference: Vec<TensorBytes> = tensors.into_iter().filter(|(n, _, _)| n.starts_with(PREFIX_EMA)).collect();
    let model_meta = CheckpointMeta { tensors: MODEL_FILE.into(), ..meta.clone() };
    write_checkpoint_file(&dir.join(MODEL_FILE), &inference, FORMAT, meta.step, &model_meta, None)?;
    // The readable copy; loading reads the header.
    let text = serde_json::to_string_pretty(meta).map_err(|e| Error::format(dir.join(checkpoint::META_FILE), e.to_string()))?;
    crate::files::write_file_atomic(&dir.join(checkpoint::META_FILE), text.as_bytes())?;
    Ok(tensors_path)
}

/// Reads the checkpoint a run starts from (`init`) and checks that it fits the run: the data's
/// skeleton and frame rate, and the run's network and pose encoding. Errors name the file and
/// what differs.
fn init_checkpoint(path: &Path, cfg: &TrainConfig, skeleton: &crate::data::Skeleton, fps: f64) -> Result<Checkpoint> {
    let ck = Checkpoint::read(path)?;
    let from = ck.tensors_path.clone();
    crate::checkpoint::check_skeleton(&ck.meta, &from, skeleton)?;
    if (ck.meta.fps - fps).abs() > 1e-6 * fps {
        return Err(Error::format(&from, format!("`init`: the model was trained at {} fps, the data is at {fps} fps", ck.meta.fps)));
    }
    let (theirs, ours) = (&ck.meta.config.model, &cfg.model);
    if theirs != ours {
        return Err(Error::format(
            &from,
            format!(
                "`init`: its network (hidden {}, social {}, aggregator {:?}, {:?}) differs from this run's (hidden {}, social {}, aggregator {:?}, {:?}): train with the network settings of its config (its model section)",
                theirs.hidden, theirs.social_dim, theirs.aggregator, theirs.causality, ours.hidden, ours.social_dim, ours.aggregator, ours.causality
            ),
        ));
    }
    if ck.meta.config.pose != cfg.pose {
        return Err(Error::format(&from, format!("`init`: its pose encoding is {:?}, this run's {:?}", ck.meta.config.pose, cfg.pose)));
    }
    Ok(ck)
}

/// Marks a directory as a socdiff training run (written when a run starts).
pub const RUN_MARKER: &str = ".socdiff-run";

impl RunDir {
    fn of(dir: &Path) -> Result<Self> {
        let checkpoint = Checkpoint::exists_in(dir);
        if checkpoint || dir.join(RUN_MARKER).is_file() {
            return Ok(RunDir::Run { checkpoint });
        }
        let others = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?.flatten().any(|e| e.file_name() != crate::files::LOCK_FILE);
        Ok(if others { RunDir::Foreign } else { RunDir::Empty })
    }
}

/// Removes temporary files of interrupted writes (`.NAME.tmp-PID`) from a run directory.
fn remove_stale_temps(dir: &Path) {
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if name.starts_with('.') && name.contains(".tmp-") {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// The config the run in `dir` was started with: its checkpoint's, or for a run that stopped
/// before its first save, its `config.json`; `None` when it has neither (or they do not read).
/// The base of a resumed run's config.
pub fn saved_config(dir: &Path) -> Option<TrainConfig> {
    match Checkpoint::read_meta(dir) {
        Ok(meta) => Some(meta.config),
        Err(_) => std::fs::read_to_string(dir.join(checkpoint::CONFIG_FILE)).ok().and_then(|t| serde_json::from_str(&t).ok()),
    }
}

/// A run's configuration as `socdiff train` resolves it, layer over layer: the `preset` (on
/// `resume`, the configuration saved in `out`) ← an `init` model's network and pose encoding ←
/// the JSON `config_file` (any subset of the fields) ← the `overrides`.
pub fn resolve_config(
    out: &Path,
    resume: bool,
    preset: Preset,
    init: Option<&Path>,
    config_file: Option<&Path>,
    overrides: &TrainOverrides,
) -> Result<TrainConfig> {
    let mut cfg = resume.then(|| saved_config(out)).flatten().unwrap_or_else(|| preset.config());
    if let Some(init) = init {
        let meta = Checkpoint::read_meta(init)?;
        (cfg.model, cfg.pose) = (meta.config.model, meta.config.pose);
    }
    if let Some(path) = config_file {
        cfg = TrainConfig::read_over(&cfg, path)?;
    }
    overrides.apply(&mut cfg)?;
    Ok(cfg)
}

fn train_locked(dataset: &Dataset, opts: &TrainOptions, on_event: &mut dyn FnMut(&TrainEvent)) -> Result<TrainSummary> {
    let out = &opts.out_dir;
    let state = RunDir::of(out)?;
    if state == RunDir::Foreign {
        return Err(Error::format(out, "is not empty and is not a socdiff run directory; refusing to write into it (choose a new or empty `out`)"));
    }
    let has_checkpoint = state == RunDir::Run { checkpoint: true };
    // A run killed before its first save is started over, with its own config as the base.
    let restart = opts.resume && !has_checkpoint && state != RunDir::Empty;
    let mut early_notices = Vec::new();
    if restart {
        early_notices.push(format!("{} holds no checkpoint yet (the run stopped before its first save): starting it over", out.display()));
    }
    let train_scenes = split_scenes(dataset, Split::Train);
    if train_scenes.is_empty() {
        let splits: Vec<String> = dataset.sequences.iter().map(|s| s.split.as_str().to_string()).collect();
        bail!(
            "dataset {} has no train sequences to train on ({} sequences{})",
            dataset.name,
            dataset.sequences.len(),
            if splits.is_empty() { String::new() } else { format!(": {}", splits.join(", ")) }
        );
    }
    check_uniform(&train_scenes, &format!("dataset {}", dataset.name))?;
    let skeleton = train_scenes[0].skeleton.clone();
    let fps = train_scenes[0].fps;

    // Config and, on resume, the checkpoint.
    let (cfg, resumed) = if opts.resume && !restart {
        if !has_checkpoint {
            bail!("`resume`: {} holds no checkpoint ({} / {})", out.display(), checkpoint::META_FILE, checkpoint::TENSORS_FILE);
        }
        let ck = Checkpoint::read(out)?;
        let mut cfg = opts.config.clone().unwrap_or_else(|| ck.meta.config.clone());
        cfg.model.feature_dims = ck.meta.config.model.feature_dims;
        cfg.validate()?;
        let changed = cfg.frozen_differences(&ck.meta.config);
        if !changed.is_empty() {
            bail!(
                "`resume`: {} differ(s) from the checkpoint's config in {} (an exact continuation cannot change them; only {} may change): drop those options or train into a new `out`",
                changed.join(", "),
                ck.meta_path.display(),
                crate::checkpoint::config::RESUMABLE_FIELDS.join(", ")
            );
        }
        checkpoint::check_skeleton(&ck.meta, &ck.meta_path, &skeleton)?;
        if (ck.meta.fps - fps).abs() > 1e-6 * fps {
            return Err(Error::format(&ck.meta_path, format!("the model was trained at {} fps, the data is at {fps} fps", ck.meta.fps)));
        }
        (cfg, Some(ck))
    } else {
        if has_checkpoint && !opts.force {
            let step = Checkpoint::read_meta(out).map(|m| format!(" at step {}", m.step)).unwrap_or_default();
            bail!("{} already holds a checkpoint{step}: pass `resume` to continue it, `force` to start over, or choose another `out`", out.display());
        }
        let mut cfg = match (&opts.config, restart) {
            (Some(c), _) => c.clone(),
            (None, true) => saved_config(out).unwrap_or_default(),
            (None, false) => TrainConfig::default(),
        };
        cfg.model.feature_dims = feature_dim(skeleton.num_joints());
        cfg.validate()?;
        (cfg, None)
    };
    let init = match (&opts.init, &resumed) {
        (None, _) => None,
        (Some(_), Some(_)) => bail!("`init` starts a new run from a model's weights; it cannot be combined with `resume`"),
        (Some(path), None) => Some(init_checkpoint(path, &cfg, &skeleton, fps)?),
    };

    let placement = opts.device.placement(opts.precision)?;
    let train_set = WindowSet::new(train_scenes, &cfg, None).map_err(|e| Error::invalid(format!("dataset {} (train split): {e}", dataset.name)))?;
    let mut notices = early_notices;
    let val_set = if cfg.val_every == 0 {
        None
    } else {
        let scenes = split_scenes(dataset, cfg.val_split);
        let what = format!("{} split", cfg.val_split.as_str());
        if scenes.is_empty() {
            notices.push(format!("no validation: dataset {} has no {what} sequences", dataset.name));
            None
        } else {
            check_uniform(train_set.scenes().iter().take(1).chain(&scenes), &format!("dataset {} (train and {what})", dataset.name))?;
            match validation_windows(scenes, &cfg) {
                Ok((v, None)) => Some(v),
                Ok((v, Some(len))) => {
                    notices.push(format!(
                        "validation on {what} windows of {len} frames: every {what} sequence is shorter than the {}-frame training window",
                        cfg.window
                    ));
                    Some(v)
                }
                Err(e) => {
                    notices.push(format!("no validation: {what}: {e}"));
                    None
                }
            }
        }
    };

    let (mut learner, std, base_seconds) = match &resumed {
        Some(ck) => {
            if ck.meta.data.fingerprint != train_set.fingerprint() {
                notices.push(format!(
                    "the training windows differ from those of the checkpoint ({} windows then, {} now): the continuation is not the run it would have been",
                    ck.meta.data.train_windows,
                    train_set.len()
                ));
            }
            (Learner::restore(ck, &placement)?, ck.meta.standardization.clone(), ck.meta.elapsed_seconds)
        }
        None => match &init {
            Some(ck) => (Learner::initialized(ck, &cfg, &placement)?, ck.meta.standardization.clone(), 0.0),
            None => (Learner::new(&cfg, &placement)?, train_set.fit_standardization()?.with_min_std(cfg.min_std), 0.0),
        },
    };
    let init_source = init.as_ref().map(|ck| format!("{} (step {})", ck.tensors_path.display(), ck.meta.step));
    drop(init);
    if let Some(round) = &cfg.distill {
        learner.set_teacher(distill::Teacher::load(round, &cfg)?);
    }
    if cfg.velocity_loss > 0.0 {
        // A function of the windows and the standardization: a resumed run gets the same.
        learner.set_velocity_loss(&train_set.velocity_scales(&std)?, cfg.velocity_loss)?;
    }
    let data_summary = DataSummary {
        source: opts.source.clone(),
        train_windows: train_set.len(),
        val_windows: val_set.as_ref().map_or(0, |v| v.len()),
        windows_by_persons: train_set.counts_by_persons().into_iter().map(|(p, n)| (p.to_string(), n)).collect(),
        fingerprint: train_set.fingerprint(),
    };
    let resumed_step = resumed.as_ref().map(|ck| ck.meta.step);
    drop(resumed);

    // Everything checked: write.
    let continuing = resumed_step.is_some();
    remove_stale_temps(out);
    if !continuing {
        for f in [checkpoint::TENSORS_FILE, checkpoint::PREV_TENSORS_FILE, checkpoint::MODEL_FILE, checkpoint::META_FILE] {
            let _ = std::fs::remove_file(out.join(f));
        }
    }
    crate::files::write_file_atomic(&out.join(RUN_MARKER), b"socdiff training run\n")?;
    let log_path = out.join(checkpoint::LOG_FILE);
    if continuing {
        truncate_log(&log_path, learner.step())?;
    } else {
        crate::files::write_json_atomic(&out.join(checkpoint::CONFIG_FILE), &cfg)?;
        let _ = std::fs::remove_file(&log_path);
    }
    let mut log = std::io::BufWriter::new(crate::files::open_append(&log_path).map_err(|e| Error::io(&log_path, e))?);
    for n in notices {
        on_event(&TrainEvent::Notice(n));
    }

    let first_step = learner.step();
    let total = cfg.steps as u64;
    learner.set_run_steps(total);
    let per_epoch = train_set.batches_per_epoch(cfg.batch) as u64;
    on_event(&TrainEvent::Started {
        first_step,
        total_steps: total,
        params: learner.model().num_params(),
        train_windows: train_set.len(),
        val_windows: data_summary.val_windows,
        batches_per_epoch: per_epoch as usize,
        config: Box::new(cfg.clone()),
        device: placement.describe(),
    });

    let started = Instant::now();
    let seconds = || base_seconds + started.elapsed().as_secs_f64();
    let mut summary = TrainSummary::starting(cfg.clone(), first_step, out.join(checkpoint::TENSORS_FILE));
    let mut saved_at = if continuing { Some(first_step) } else { None };
    let (mut last_loss, mut last_val) = (None, None);
    let mut lowest = f64::INFINITY;
    let mut plan: Option<(u64, Vec<Vec<usize>>)> = None;
    let write_log = |log: &mut std::io::BufWriter<std::fs::File>, v: Value| -> Result<()> { writeln!(log, "{v}").map_err(|e| Error::io(&log_path, e)) };

    let save = |learner: &Learner, log: &mut std::io::BufWriter<std::fs::File>, last_loss: Option<f64>, last_val: Option<f64>| -> Result<PathBuf> {
        log.flush().map_err(|e| Error::io(&log_path, e))?;
        let meta = CheckpointMeta {
            format: checkpoint::FORMAT.into(),
            format_version: checkpoint::FORMAT_VERSION,
            socdiff_version: env!("CARGO_PKG_VERSION").into(),
            step: learner.step(),
            seed: cfg.seed,
            rng: checkpoint::RNG_NOTE.into(),
            elapsed_seconds: seconds(),
            loss: last_loss,
            val_loss: last_val,
            fps,
            skeleton: skeleton.clone(),
            standardization: std.clone(),
            config: cfg.clone(),
            data: data_summary.clone(),
            tensors: checkpoint::TENSORS_FILE.into(),
            device: placement.describe(),
            init: init_source.clone(),
        };
        save_checkpoint(out, &meta, learner.model(), learner.ema(), learner.adam())
    };

    for s in first_step..total {
        if cfg.minutes.is_some_and(|m| seconds() >= 60.0 * m) {
            // A resume after the budget was spent: nothing more to train.
            summary.out_of_time = true;
            break;
        }
        let (epoch, k) = (s / per_epoch, (s % per_epoch) as usize);
        if plan.as_ref().map(|p| p.0) != Some(epoch) {
            plan = Some((epoch, train_set.epoch_plan(cfg.seed, epoch, cfg.batch)));
        }
        let idx = &plan.as_ref().expect("plan").1[k];
        let mut aug_rng = stream_rng(cfg.seed, Stream::Augment, s);
        let batch = train_set.batch(idx, &std, &cfg.augment, &mut aug_rng)?;
        let mut rng = stream_rng(cfg.seed, Stream::Step, s);
        let lr = learner.adam().lr(); // this step's rate, logged beside its loss
        let loss = learner.train_step(&batch, &mut rng)?;
        let step = learner.step();
        // A run that diverges stops before it saves: the last checkpoint stays the last good one.
        lowest = lowest.min(loss as f64);
        // A distillation round starts near zero loss (the student is its teacher): only a
        // non-finite loss stops it.
        let diverged = cfg.distill.is_none() && loss as f64 > DIVERGED_FACTOR * lowest.max(1e-6);
        if !loss.is_finite() || diverged {
            let kept = saved_at.map_or("none was saved".to_string(), |s| format!("the checkpoint of step {s} is kept"));
            bail!("training diverged at step {step}: loss {loss} (the lowest so far was {lowest:.4}); {kept}; a lower learning rate (--lr) may help");
        }
        summary.losses.push(loss);
        last_loss = Some(loss as f64);
        let secs = seconds();
        write_log(&mut log, json!({"step": step, "loss": loss, "lr": lr, "seconds": secs}))?;
        on_event(&TrainEvent::Step { step, loss, lr, seconds: secs });

        if let Some(val) = &val_set {
            if step.is_multiple_of(cfg.val_every as u64) {
                let v = validation_loss(&learner, val, &std, &cfg)?;
                last_val = Some(v as f64);
                summary.val_losses.push((step, v));
                write_log(&mut log, json!({"step": step, "val_loss": v, "seconds": seconds()}))?;
                on_event(&TrainEvent::Validation { step, loss: v });
            }
        }
        let stop = opts.stop.as_ref().is_some_and(|f| f.load(Ordering::SeqCst));
        let out_of_time = cfg.minutes.is_some_and(|m| seconds() >= 60.0 * m);
        if step.is_multiple_of(cfg.save_every as u64) || step == total || stop || out_of_time {
            let path = save(&learner, &mut log, last_loss, last_val)?;
            saved_at = Some(step);
            on_event(&TrainEvent::Saved(CheckpointSaved { step, path }));
        }
        summary.last_step = step;
        if stop {
            summary.stopped = true;
            break;
        }
        if out_of_time {
            summary.out_of_time = true;
            break;
        }
    }
    if saved_at != Some(learner.step()) {
        // Nothing to do (resumed at the end), or a fresh run of zero steps: save anyway.
        let path = save(&learner, &mut log, last_loss, last_val)?;
        on_event(&TrainEvent::Saved(CheckpointSaved { step: learner.step(), path }));
    }
    log.flush().map_err(|e| Error::io(&log_path, e))?;
    Ok(summary)
}

/// Timing of training steps on random data (`socdiff bench train`).
#[derive(Clone, Debug)]
pub struct StepTiming {
    /// Seconds of each timed step (after one untimed warm-up step).
    pub seconds: Vec<f64>,
    /// Scalar parameters of the network.
    pub params: usize,
    /// Threads of the compute pool.
    pub threads: usize,
    /// The loss of every timed step (to compare precisions after the same steps).
    pub losses: Vec<f32>,
    /// Where the steps ran ([`Placement::describe`]).
    pub device: String,
}

/// Times full training steps (batch build excluded: forward, backward, Adam, EMA) of a network
/// configured by `model` on a random batch `[batch, persons, frames, δ]` with random anchors:
/// one warm-up step, then `steps` timed ones, at `placement` (each step waits for the device to
/// finish). Seeded, so runs are comparable. When [`crate::model::profile`] is collecting, it
/// starts over after the warm-up, so it covers the timed steps only.
pub fn time_train_steps(
    model: &crate::model::DenoiserConfig,
    batch: usize,
    persons: usize,
    frames: usize,
    steps: usize,
    placement: &Placement,
) -> Result<StepTiming> {
    use rand::{Rng, SeedableRng};
    if batch == 0 || persons == 0 || frames == 0 || steps == 0 {
        bail!("bench: batch, persons, frames and steps must be at least 1");
    }
    let cfg = TrainConfig { model: model.clone(), ..Default::default() };
    cfg.model.validate()?;
    let mut learner = Learner::new(&cfg, placement)?;
    let mut rng = StdRng::seed_from_u64(1);
    let d = model.feature_dims;
    let x0 = Tensor::from_vec(standard_normal(&mut rng, batch * persons * frames * d), (batch, persons, frames, d), &candle_core::Device::Cpu)?;
    let mut a = Vec::with_capacity(batch * persons * 4);
    for _ in 0..batch * persons {
        let h: f32 = rng.gen_range(-3.0..3.0);
        a.extend([rng.gen_range(-3.0..3.0), rng.gen_range(-3.0..3.0), h.cos(), h.sin()]);
    }
    let anchors = Tensor::from_vec(a, (batch, persons, 4), &candle_core::Device::Cpu)?;
    let b = Batch { x0, anchors };
    learner.train_step(&b, &mut rng)?;
    placement.device.synchronize()?;
    if crate::model::profile::enabled() {
        // the profile covers the timed steps only (the warm-up touches fresh memory first)
        crate::model::profile::enable();
    }
    let (mut seconds, mut losses) = (Vec::with_capacity(steps), Vec::with_capacity(steps));
    for _ in 0..steps {
        let start = Instant::now();
        losses.push(learner.train_step(&b, &mut rng)?);
        placement.device.synchronize()?;
        seconds.push(start.elapsed().as_secs_f64());
    }
    Ok(StepTiming { seconds, params: learner.model().num_params(), threads: rayon::current_num_threads(), losses, device: placement.describe() })
}
