//! Progressive distillation (Salimans & Ho, "Progressive Distillation for Fast Sampling of
//! Diffusion Models", ICLR 2022): a trained model becomes a student that samples in N network
//! calls, by rounds that each halve the calls.
//!
//! ```text
//! teacher (2K − 1 calls) ──round──▶ student (K calls), initialized as the teacher
//! per window: known prefix (clean, as in sampling), student step i, t = grid_K[i]
//!     z_t      = √ᾱ_t·x0 + √(1−ᾱ_t)·ε             (unknown frames; known frames clean)
//!     z_mid    = DDIM(z_t → t_mid, teacher(z_t, t))          t_mid = grid_2K−1[2i + 1]
//!     z_next   = DDIM(z_mid → t_next, teacher(z_mid, t_mid))  t_next = grid_K[i + 1] (or x̂0)
//!     x̃        = the x̂0 that takes one DDIM step from z_t to z_next
//!              (the last step, at t = 0: the teacher's own x̂0)
//!     loss     = Σ w·(student(z_t, t) − x̃)² / Σ w,   w = max(SNR_t, 1) on unknown frames
//! ```
//!
//! The grids are the samplers' own ([`respaced_timesteps`]: both ends kept), so a student is
//! sampled like any model, `--steps K`: K − 1 jumps and a last call at t = 0 that refines the
//! motion. The grid of K is every second step of the grid of 2K − 1, so students take 2, 3, 5
//! or 9 calls (one: a single jump from pure noise, distilled from the 2-call grid). The last
//! call is kept because fine motion comes back there: without it, two jumps of the same
//! teacher forecast stiller motion (lower NDMS).
//!
//! Progressive rather than consistency distillation: our samplers are deterministic DDIM
//! chains already, so each round has an exact target (two teacher steps) and needs no extra
//! network or schedule of its own; a round is an ordinary training run ([`super::train`]) with
//! the teacher attached, so it resumes, saves and stops like one.

use super::{train, TrainConfig, TrainEvent, TrainOptions, TrainSummary};
use crate::checkpoint::config::DistillRound;
use crate::checkpoint::{Checkpoint, Weights};
use crate::data::Dataset;
use crate::diffusion::{standard_normal, InputScaling, Prediction};
use crate::model::{Denoiser, DeviceChoice, InferenceNet, Placement};
use crate::train::{Batch, EmaConfig, LrSchedule};
use crate::{bail, Error, Result};
use candle_core::Tensor;
use rand::rngs::StdRng;
use rand::Rng;
use socdiff_schedules::{respaced_timesteps, NoiseSchedule, QCoefficients};
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// The network calls a student may be distilled to.
pub const STUDENT_CALLS: [usize; 5] = [1, 2, 3, 5, 9];

/// Calls of the sampler a student of `calls` calls learns from: 2K − 1 (2 for K = 1).
pub fn teacher_calls_of(calls: usize) -> usize {
    if calls == 1 {
        2
    } else {
        2 * calls - 1
    }
}

/// A round's teacher: its forward-only network and the two grids of the round.
pub struct Teacher {
    net: InferenceNet,
    schedule: NoiseSchedule,
    /// The student's timesteps (K, descending, the last 0 for K ≥ 2).
    student: Vec<usize>,
    /// The teacher's timesteps ([`teacher_calls_of`] K, descending): `student[i] = fine[2i]`.
    fine: Vec<usize>,
    /// Known frames at level 0 (the teacher was trained with clean frames).
    clean_known: bool,
    /// Observed frames of the forecasting setup.
    observed: usize,
}

impl Teacher {
    /// The teacher of `round` for a student configured as `cfg`: same network, same diffusion,
    /// an x̂0-predicting model without input scaling.
    pub fn load(round: &DistillRound, cfg: &TrainConfig) -> Result<Self> {
        let ck = Checkpoint::read(&round.teacher)?;
        let t = &ck.meta.config;
        if t.model != cfg.model || t.diffusion != cfg.diffusion || t.pose != cfg.pose {
            return Err(Error::format(&ck.meta_path, "distill: the teacher's network, diffusion or pose encoding differs from the student's"));
        }
        if t.diffusion.prediction != Prediction::X0 || t.diffusion.input_scaling != InputScaling::None {
            return Err(Error::format(&ck.meta_path, "distill: only models that predict x0 without input scaling can be distilled"));
        }
        if round.calls == 0 || round.calls > 1024 {
            bail!("distill: a round's student takes 1 to 1024 calls, got {}", round.calls);
        }
        let schedule = cfg.diffusion.noise_schedule()?;
        let steps = schedule.timesteps();
        let net = InferenceNet::new(&ck.denoiser_at(Weights::Ema, &Placement::cpu())?)?;
        Ok(Self {
            net,
            student: respaced_timesteps(steps, round.calls)?,
            fine: respaced_timesteps(steps, teacher_calls_of(round.calls))?,
            schedule,
            clean_known: cfg.noise.trains_clean_frames(),
            observed: cfg.observed_frames(),
        })
    }

    /// The distillation loss of `student` on `batch` (levels, steps and ε drawn from `rng`).
    ///
    /// # Shapes
    /// - `batch.x0`: `[B, P, T, δ]`, `batch.anchors`: `[B, P, 4]`; returns a scalar tensor
    pub fn loss(&self, student: &Denoiser, batch: &Batch, rng: &mut StdRng) -> Result<Tensor> {
        let (b, p, nt, d) = batch.x0.dims4()?;
        let x0: Vec<f32> = batch.x0.flatten_all()?.to_dtype(candle_core::DType::F32)?.to_vec1()?;
        let anchors: Vec<f32> = batch.anchors.flatten_all()?.to_dtype(candle_core::DType::F32)?.to_vec1()?;
        // Per window: the known prefix (as `NoiseLevels::Prefix` draws it) and the student step.
        let windows: Vec<(usize, usize)> = (0..b)
            .map(|_| {
                let known = if rng.gen_bool(0.5) { self.observed.min(nt - 1) } else { rng.gen_range(0..nt) };
                (known, rng.gen_range(0..self.student.len()))
            })
            .collect();
        let eps = standard_normal(rng, x0.len());
        let q = |t: Option<usize>| -> Result<QCoefficients> {
            Ok(match t {
                Some(t) => self.schedule.q(t)?,
                None => QCoefficients { signal: 1.0, noise: 0.0 },
            })
        };
        // (from, mid, next) levels of each window's student step; at t = 0 (the refining call)
        // there is no mid: the target is the teacher's x̂0.
        let jumps: Vec<(usize, Option<usize>, Option<usize>)> = windows
            .iter()
            .map(|&(_, i)| match self.student[i] {
                0 => (0, None, None),
                from => (from, Some(self.fine[2 * i + 1]), self.student.get(i + 1).copied()),
            })
            .collect();
        let unknown = |idx: usize| (idx / d) % nt >= windows[idx / (p * nt * d)].0;
        let levels = |level: &dyn Fn(usize) -> usize| -> Vec<f64> {
            (0..b * p * nt)
                .map(|r| {
                    let (w, f) = (r / (p * nt), r % nt);
                    if f < windows[w].0 && self.clean_known {
                        0.0
                    } else {
                        level(w) as f64
                    }
                })
                .collect()
        };
        // z_t: unknown entries noised to the window's level, known ones clean.
        let mut z = x0.clone();
        for (idx, v) in z.iter_mut().enumerate() {
            if unknown(idx) {
                let c = q(Some(jumps[idx / (p * nt * d)].0))?;
                *v = (c.signal * x0[idx] as f64 + c.noise * eps[idx] as f64) as f32;
            }
        }
        let shape = [b, p, nt, d];
        let mut x1 = vec![0.0f32; z.len()];
        let t_from = levels(&|w| jumps[w].0);
        self.net.forward(&z, shape, &t_from, Some(&anchors), &mut x1)?;
        let mut z_mid = x0.clone();
        for (idx, v) in z_mid.iter_mut().enumerate() {
            if let (true, (from, Some(mid), _)) = (unknown(idx), jumps[idx / (p * nt * d)]) {
                *v = ddim_jump(z[idx], x1[idx], q(Some(from))?, q(Some(mid))?);
            }
        }
        let mut x2 = vec![0.0f32; z.len()];
        if jumps.iter().any(|j| j.1.is_some()) {
            self.net.forward(&z_mid, shape, &levels(&|w| jumps[w].1.unwrap_or(0)), Some(&anchors), &mut x2)?;
        }
        // The target, and each entry's weight.
        let (mut target, mut weight) = (x0.clone(), vec![0.0f32; b * p * nt]);
        for (idx, v) in target.iter_mut().enumerate() {
            if unknown(idx) {
                let (from, mid, next) = jumps[idx / (p * nt * d)];
                let c_from = q(Some(from))?;
                *v = match mid {
                    None => x1[idx],
                    Some(mid) => {
                        let (c_mid, c_next) = (q(Some(mid))?, q(next)?);
                        implied_x0(z[idx], ddim_jump(z_mid[idx], x2[idx], c_mid, c_next), c_from, c_next)
                    }
                };
                weight[idx / d] = truncated_snr(c_from) as f32;
            }
        }
        let total: f64 = weight.iter().map(|&w| w as f64).sum::<f64>() * d as f64;
        if total == 0.0 {
            bail!("distill: every frame of the batch is known, nothing to learn");
        }
        let dev = student.device();
        let dtype = student.dtype();
        let steps: Vec<u32> = t_from.iter().map(|&t| t as u32).collect();
        let pred = student.forward(
            &Tensor::from_vec(z, (b, p, nt, d), dev)?.to_dtype(dtype)?,
            &Tensor::from_vec(steps, (b, p, nt), dev)?,
            Some(&Tensor::from_vec(anchors, (b, p, 4), dev)?.to_dtype(dtype)?),
        )?;
        let target = Tensor::from_vec(target, (b, p, nt, d), dev)?.to_dtype(dtype)?;
        let w = Tensor::from_vec(weight, (b, p, nt, 1), dev)?.to_dtype(dtype)?;
        Ok(((pred - target)?.sqr()?.broadcast_mul(&w)?.sum_all()? / total)?)
    }
}

/// One deterministic DDIM step of an entry from level `from` (value `z`) to level `to` with the
/// model's x̂0: `√ᾱ_to·x̂0 + √(1−ᾱ_to)·(z − √ᾱ_from·x̂0)/√(1−ᾱ_from)`.
fn ddim_jump(z: f32, x0: f32, from: QCoefficients, to: QCoefficients) -> f32 {
    let eps = (z as f64 - from.signal * x0 as f64) / from.noise;
    (to.signal * x0 as f64 + to.noise * eps) as f32
}

/// The x̂0 whose DDIM step takes `z` at level `from` to `z_next` at level `to` (the inverse of
/// [`ddim_jump`] in x̂0); `z_next` itself when `to` is clean.
fn implied_x0(z: f32, z_next: f32, from: QCoefficients, to: QCoefficients) -> f32 {
    let ratio = to.noise / from.noise;
    ((z_next as f64 - ratio * z as f64) / (to.signal - ratio * from.signal)) as f32
}

/// max(SNR, 1): the x̂0 error's weight (Salimans & Ho's "truncated SNR").
fn truncated_snr(c: QCoefficients) -> f64 {
    (c.signal * c.signal / (c.noise * c.noise)).max(1.0)
}

/// How to run [`distill`].
#[derive(Clone, Debug)]
pub struct DistillOptions {
    /// The trained model to distill (a run directory or checkpoint).
    pub teacher: PathBuf,
    /// Network calls of the final student ([`STUDENT_CALLS`]).
    pub calls: usize,
    /// Calls of the sampler the first round distills: `calls` doubled less one, once or more
    /// (2 → 3 → 5 → 9 → 17 → 33 → 65; 1 → 2).
    pub teacher_calls: usize,
    /// Optimizer steps per round.
    pub round_steps: usize,
    /// Learning rate of each round (a half cosine down to 0 over the round).
    pub lr: f64,
    /// Windows per batch (default: the teacher's).
    pub batch: Option<usize>,
    /// The student's run directory; the rounds before the last train in `rounds/` inside it.
    pub out_dir: PathBuf,
    /// Continue the rounds found in `out_dir`.
    pub resume: bool,
    /// Where the data came from (recorded in each round's checkpoint).
    pub source: String,
    /// Set to stop after the current step (a checkpoint is saved).
    pub stop: Option<Arc<AtomicBool>>,
    /// Device the students train on.
    pub device: DeviceChoice,
}

impl Default for DistillOptions {
    fn default() -> Self {
        Self {
            teacher: PathBuf::new(),
            calls: 2,
            teacher_calls: 33,
            round_steps: 2000,
            lr: 2e-4,
            batch: None,
            out_dir: PathBuf::new(),
            resume: false,
            source: String::new(),
            stop: None,
            device: DeviceChoice::Cpu,
        }
    }
}

/// One round of a [`distill`] run: where it trains and how.
#[derive(Clone, Debug)]
pub struct Round {
    /// Calls of the round's teacher ([`teacher_calls_of`] `calls`).
    pub teacher_calls: usize,
    /// Calls of its student.
    pub calls: usize,
    /// The training run of the round.
    pub options: TrainOptions,
}

/// The rounds of `opts`, first to last, each a training run: its teacher is the previous
/// round's student (the first's, `opts.teacher`), its student starts from its teacher's weights
/// (or, on `resume`, from its own checkpoint). Checks everything before anything is written.
pub fn rounds(opts: &DistillOptions) -> Result<Vec<Round>> {
    if !STUDENT_CALLS.contains(&opts.calls) {
        bail!("distill: `steps` must be 1, 2, 3, 5 or 9, got {}", opts.calls);
    }
    // The calls from the student up, each round's teacher the next.
    let mut chain = vec![opts.calls];
    while chain.len() < 12 && *chain.last().expect("non-empty") < opts.teacher_calls {
        chain.push(teacher_calls_of(*chain.last().expect("non-empty")));
    }
    if chain.len() < 2 || *chain.last().expect("non-empty") != opts.teacher_calls {
        let mut valid = vec![teacher_calls_of(opts.calls)];
        while valid.len() < 6 {
            valid.push(teacher_calls_of(*valid.last().expect("non-empty")));
        }
        let valid: Vec<String> = valid.iter().map(|c| c.to_string()).collect();
        bail!(
            "distill: `teacher_steps` must be one of {}… for {} steps (each round halves the jumps), got {}",
            valid.join(", "),
            opts.calls,
            opts.teacher_calls
        );
    }
    if opts.round_steps == 0 || !(opts.lr.is_finite() && opts.lr > 0.0) {
        bail!("distill: `round_steps` must be at least 1 and `lr` positive");
    }
    let ck = Checkpoint::read_meta(&opts.teacher)?;
    let teacher_meta = Checkpoint::paths(&opts.teacher).0;
    if ck.config.distill.is_some() {
        return Err(Error::format(&teacher_meta, "distill: this model is already a distilled student; distill from the model it came from"));
    }
    if ck.config.diffusion.prediction != Prediction::X0 || ck.config.diffusion.input_scaling != InputScaling::None {
        return Err(Error::format(&teacher_meta, "distill: only models that predict x0 without input scaling can be distilled"));
    }
    // The teacher is read again by every resumed round: keep an absolute path.
    let teacher = std::path::absolute(&opts.teacher).map_err(|e| Error::io(&opts.teacher, e))?;
    if opts.out_dir.exists() && !opts.resume {
        let used = std::fs::read_dir(&opts.out_dir).map_err(|e| Error::io(&opts.out_dir, e))?.flatten().next().is_some();
        if used {
            bail!("{} is not empty: pass `resume` to continue its rounds, or choose a new `out`", opts.out_dir.display());
        }
    }
    let out = std::path::absolute(&opts.out_dir).map_err(|e| Error::io(&opts.out_dir, e))?;
    let mut from = teacher;
    let mut list = Vec::new();
    for pair in chain.windows(2).rev() {
        let (student, calls) = (pair[0], pair[1]);
        let dir = if student == opts.calls { out.clone() } else { out.join("rounds").join(format!("calls-{student}")) };
        let cfg = TrainConfig {
            steps: opts.round_steps,
            minutes: None,
            batch: opts.batch.unwrap_or(ck.config.batch),
            adam: crate::train::AdamConfig { lr: opts.lr, schedule: LrSchedule::Cosine, ..ck.config.adam.clone() },
            // A short average: a round is a few hundred steps.
            ema: EmaConfig { decay: 0.99, update_every: 1, warmup_steps: 0 },
            save_every: opts.round_steps.clamp(1, 100),
            val_every: 0,
            velocity_loss: 0.0,
            distill: Some(DistillRound { calls: student, teacher: from.clone() }),
            ..ck.config.clone()
        };
        let resume = opts.resume && Checkpoint::exists_in(&dir);
        let options = TrainOptions {
            out_dir: dir.clone(),
            resume,
            config: Some(cfg),
            source: opts.source.clone(),
            stop: opts.stop.clone(),
            device: opts.device,
            init: (!resume).then(|| from.clone()),
            ..Default::default()
        };
        list.push(Round { teacher_calls: calls, calls: student, options });
        from = dir;
    }
    Ok(list)
}

/// [`rounds`], after marking the student's directory as a run: it is the last round's run
/// directory and holds the earlier rounds in `rounds/`.
pub fn prepare(opts: &DistillOptions) -> Result<Vec<Round>> {
    let list = rounds(opts)?;
    if let Some(last) = list.last() {
        let dir = &last.options.out_dir;
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        crate::files::write_file_atomic(&dir.join(super::RUN_MARKER), b"socdiff training run\n")?;
    }
    Ok(list)
}

impl Round {
    /// "round k of n: 2K − 1 → K calls, into DIR" (`k` from 0).
    pub fn describe(&self, k: usize, n: usize) -> String {
        format!("round {} of {n}: {} → {} calls, into {}", k + 1, self.teacher_calls, self.calls, self.options.out_dir.display())
    }
}

/// Whether `round`'s run directory already holds its last step.
pub fn round_done(round: &Round) -> bool {
    Checkpoint::read_meta(&round.options.out_dir).is_ok_and(|m| m.step >= round.options.config.as_ref().map_or(0, |c| c.steps as u64))
}

/// Runs the rounds of `opts` ([`rounds`]), skipping those already done, reporting each
/// round's training as [`train`] does (a notice names the round first). Stops after a round
/// that was stopped.
pub fn distill(dataset: &Dataset, opts: &DistillOptions, on_event: &mut dyn FnMut(&TrainEvent)) -> Result<Vec<TrainSummary>> {
    let list = prepare(opts)?;
    let n = list.len();
    let mut out = Vec::new();
    for (k, round) in list.into_iter().enumerate() {
        if round_done(&round) {
            on_event(&TrainEvent::Notice(format!("round {} of {n} ({} → {} calls) is done", k + 1, round.teacher_calls, round.calls)));
            continue;
        }
        std::fs::create_dir_all(&round.options.out_dir).map_err(|e| Error::io(&round.options.out_dir, e))?;
        on_event(&TrainEvent::Notice(round.describe(k, n)));
        let summary = train(dataset, &round.options, on_event)?;
        let stopped = summary.stopped;
        out.push(summary);
        if stopped {
            break;
        }
    }
    Ok(out)
}

/// The student steps a model samples with by default: a student's own calls, else `None`.
pub fn student_calls(cfg: &TrainConfig) -> Option<usize> {
    cfg.distill.as_ref().map(|d| d.calls)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::Split;
    use crate::train::tests::{dataset, temp_dir, walking_scene};
    use std::path::Path;

    fn c(t: usize) -> QCoefficients {
        NoiseSchedule::default().q(t).unwrap()
    }

    /// DDIM with one x̂0 is consistent: two jumps with the same x̂0 land where one lands, so
    /// the implied x̂0 of two such jumps is that x̂0; and the implied x̂0 inverts a jump.
    #[test]
    fn targets_invert_ddim_jumps() {
        let clean = QCoefficients { signal: 1.0, noise: 0.0 };
        for (from, mid, next) in [(c(999), c(749), Some(c(499))), (c(499), c(249), None), (c(124), c(62), Some(c(0)))] {
            let to = next.unwrap_or(clean);
            for (z, x0) in [(0.7f32, -1.2f32), (-2.0, 0.3), (0.0, 1.0)] {
                let two = ddim_jump(ddim_jump(z, x0, from, mid), x0, mid, to);
                let one = ddim_jump(z, x0, from, to);
                assert!((two - one).abs() < 1e-5, "{two} vs {one}");
                assert!((implied_x0(z, two, from, to) - x0).abs() < 1e-4);
            }
        }
        assert_eq!(truncated_snr(c(999)), 1.0);
        assert!((truncated_snr(c(100)) - c(100).signal.powi(2) / c(100).noise.powi(2)).abs() < 1e-9);
    }

    fn tiny_teacher(dir: &Path, ds: &Dataset) {
        let cfg = TrainConfig {
            model: crate::model::DenoiserConfig { hidden: 8, time_dim: 16, fourier_dim: 8, social_dim: 8, ..Default::default() },
            steps: 30,
            batch: 4,
            window: 16,
            stride: 4,
            save_every: 30,
            val_every: 0,
            noise: crate::train::NoiseLevels::Prefix,
            ..Default::default()
        };
        let opts = TrainOptions { out_dir: dir.to_path_buf(), config: Some(cfg), source: "test".into(), ..Default::default() };
        train(ds, &opts, &mut |_| {}).unwrap();
    }

    /// A student at step 0 is its teacher (the one-step output equal to the teacher's network);
    /// rounds nest, the loss falls, a stopped run resumes, and bad options are errors that
    /// write nothing.
    #[test]
    fn rounds_start_from_the_teacher_and_the_loss_falls() {
        let ds = dataset("walk", vec![(Split::Train, walking_scene("w1", 64, 2, 1)), (Split::Train, walking_scene("w2", 64, 3, 2))]);
        let root = temp_dir("distill");
        let teacher_dir = root.join("teacher");
        tiny_teacher(&teacher_dir, &ds);
        let out = root.join("student");
        let opts =
            DistillOptions { teacher: teacher_dir.clone(), calls: 2, teacher_calls: 5, round_steps: 40, lr: 1e-3, out_dir: out.clone(), ..Default::default() };
        let list = rounds(&opts).unwrap();
        assert_eq!(list.iter().map(|r| (r.teacher_calls, r.calls)).collect::<Vec<_>>(), vec![(5, 3), (3, 2)]);
        let chain = rounds(&DistillOptions { calls: 1, teacher_calls: 33, ..opts.clone() }).unwrap();
        assert_eq!(chain.iter().map(|r| r.calls).collect::<Vec<_>>(), vec![17, 9, 5, 3, 2, 1]);
        assert_eq!(list[0].options.init.as_deref(), Some(std::path::absolute(&teacher_dir).unwrap().as_path()));
        assert_eq!(list[1].options.init.as_deref(), Some(std::path::absolute(out.join("rounds/calls-3")).unwrap().as_path()));
        assert_eq!(list[1].options.out_dir, std::path::absolute(&out).unwrap());

        // Step 0: the student's network is the teacher's.
        let cfg = list[0].options.config.clone().unwrap();
        let teacher = Teacher::load(cfg.distill.as_ref().unwrap(), &cfg).unwrap();
        let student = Checkpoint::read(&teacher_dir).unwrap().denoiser_at(Weights::Ema, &Placement::cpu()).unwrap();
        let (b, p, nt, d) = (1, 2, 16, cfg.model.feature_dims);
        let x: Vec<f32> = (0..b * p * nt * d).map(|i| ((i * 37 % 101) as f32 / 50.0) - 1.0).collect();
        let levels: Vec<f64> = (0..b * p * nt).map(|r| if r % nt < 4 { 0.0 } else { 749.0 }).collect();
        let anchors = vec![0.0, 0.0, 1.0, 0.0, 1.0, 0.5, 0.0, 1.0];
        let mut want = vec![0.0f32; x.len()];
        teacher.net.forward(&x, [b, p, nt, d], &levels, Some(&anchors), &mut want).unwrap();
        let got = student
            .forward(
                &Tensor::from_vec(x.clone(), (b, p, nt, d), &candle_core::Device::Cpu).unwrap(),
                &Tensor::from_vec(levels.iter().map(|&t| t as u32).collect::<Vec<_>>(), (b, p, nt), &candle_core::Device::Cpu).unwrap(),
                Some(&Tensor::from_vec(anchors, (b, p, 4), &candle_core::Device::Cpu).unwrap()),
            )
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        let diff = got.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(diff < 1e-4, "student at step 0 differs from its teacher by {diff}");

        // Stop the first round after 10 steps, then resume everything.
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let stopping = DistillOptions { stop: Some(stop.clone()), ..opts.clone() };
        let summaries = distill(&ds, &stopping, &mut |e| {
            if matches!(e, TrainEvent::Step { step: 10, .. }) {
                flag.store(true, std::sync::atomic::Ordering::SeqCst);
            }
        })
        .unwrap();
        assert_eq!((summaries.len(), summaries[0].stopped, summaries[0].last_step), (1, true, 10));
        assert!(!Checkpoint::exists_in(&out), "the last round has not started");
        assert!(distill(&ds, &opts, &mut |_| {}).unwrap_err().to_string().contains("resume"));
        let summaries = distill(&ds, &DistillOptions { resume: true, ..opts.clone() }, &mut |_| {}).unwrap();
        assert_eq!(summaries.iter().map(|s| (s.first_step, s.last_step)).collect::<Vec<_>>(), vec![(10, 40), (0, 40)]);
        for s in &summaries {
            let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
            let (first, last) = (mean(&s.losses[..8]), mean(&s.losses[s.losses.len() - 8..]));
            assert!(last < first, "loss did not fall: {first} → {last}");
        }
        // The student records its calls and teacher; a further resume has nothing to do.
        let meta = Checkpoint::read_meta(&out).unwrap();
        assert_eq!(meta.config.distill.as_ref().map(|d| d.calls), Some(2));
        assert_eq!(student_calls(&meta.config), Some(2));
        assert!(distill(&ds, &DistillOptions { resume: true, ..opts.clone() }, &mut |_| {}).unwrap().is_empty());

        // Bad options.
        let e = |o: DistillOptions| rounds(&o).unwrap_err().to_string();
        assert!(e(DistillOptions { calls: 4, ..opts.clone() }).contains("1, 2, 3, 5 or 9"));
        assert!(e(DistillOptions { teacher_calls: 6, ..opts.clone() }).contains("one of 3, 5, 9, 17, 33, 65…"));
        assert!(e(DistillOptions { teacher_calls: 2, ..opts.clone() }).contains("one of"));
        assert!(e(DistillOptions { teacher: out.clone(), out_dir: root.join("again"), ..opts.clone() }).contains("already a distilled student"));
        assert!(e(DistillOptions { teacher: root.join("missing"), out_dir: root.join("again"), ..opts.clone() }).contains("missing"));
        assert!(!root.join("again").exists());
        let _ = std::fs::remove_dir_all(&root);
    }
}
