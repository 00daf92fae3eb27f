//! Gaussian diffusion around the [`Denoiser`] (METHOD.md §4, REFERENCE.md §3): the forward
//! process q(x_t | x_0) on tensors and the training loss of the x0 objective.
//!
//! The schedule math (β, ᾱ, posterior, samplers) lives in `socdiff_schedules` as pure `f64`;
//! this module only broadcasts its per-step scalars over batches of tensors.
//!
//! | symbol | meaning | here |
//! |---|---|---|
//! | x_0 | clean, standardized anchored features | `x0: [B, P, T, δ]` |
//! | t | diffusion step per scene, uniform in 0..T | `t: &[usize]`, length B |
//! | ε | N(0, I) noise | `noise`, shape of `x0` |
//! | x_t | √ᾱ_t·x_0 + √(1 − ᾱ_t)·ε | [`GaussianDiffusion::q_sample`] |
//! | x̂0 | g(x_t, t, anchors): the network's output, or √ᾱ_t·x_t − √(1 − ᾱ_t)·v̂ | [`Prediction`] |
//! | L | mean over B, P, T, δ of \|x̂0 − x_0\| (L1, the paper; or its square, L2), all frames, past included | [`GaussianDiffusion::loss`] |

use crate::model::Denoiser;
use crate::{bail, Result};
use candle_core::{DType, Device, Tensor};
use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};
use socdiff_schedules::{BetaSchedule, NoiseSchedule, ScheduleError};

impl From<ScheduleError> for crate::Error {
    fn from(e: ScheduleError) -> Self {
        crate::Error::Invalid(format!("noise schedule: {e}"))
    }
}

/// Which variance schedule β_t to use. JSON: `{"kind": "cosine", "s": 0.008}` or
/// `{"kind": "linear", "beta_start": 1e-4, "beta_end": 0.02}`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ScheduleKind {
    /// Nichol & Dhariwal's cosine schedule (the reference's), offset `s`.
    Cosine {
        /// Offset keeping β_0 away from 0 (0.008).
        s: f64,
    },
    /// β linearly spaced from `beta_start` to `beta_end`.
    Linear {
        /// β_0.
        beta_start: f64,
        /// β_{T−1}.
        beta_end: f64,
    },
}

/// What the network's output stands for (the config field `diffusion.prediction`). The loss and every sampler
/// see x̂0 either way ([`Prediction::x0_from_output_in_place`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Prediction {
    /// The clean signal itself, x̂0 = F (the paper).
    #[default]
    X0,
    /// The velocity v = √ᾱ_t·ε − √(1 − ᾱ_t)·x_0 (Salimans & Ho 2022), x̂0 = √ᾱ_t·x_t −
    /// √(1 − ᾱ_t)·F: at low noise x̂0 is the input plus a small correction, so the model is
    /// close to invertible (exact interpolation endpoints); at high noise it is −F, as x0.
    /// On bandai2 at 30 minutes its samples from noise were far worse (docs/results.md, generation).
    V,
    /// Karras et al. (2022)'s preconditioning in the VP process: x̂0 = c_skip·x_t + c_out·F with
    /// c_skip = σ_d²·√ᾱ/((1 − ᾱ) + σ_d²·ᾱ) and c_out = σ_d·√(1 − ᾱ)/√((1 − ᾱ) + σ_d²·ᾱ),
    /// σ_d = [`DiffusionConfig::sigma_data`]: the input passes through where the noise is below
    /// σ_d and the network predicts the clean signal where it is above (σ_d = 1 is v; σ_d → 0 is
    /// x0). Trained on the error of F against its target, so every level weighs the same.
    Edm,
}

/// How the training loss weighs an error (`train --loss`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum LossNorm {
    /// Mean absolute error (the paper). Its minimizer is the posterior's median per value, not
    /// its mean: where most windows stand still and a few travel, x̂0 at high noise stands still.
    #[default]
    L1,
    /// Mean squared error: the minimizer is E[x0 | x_t], the denoiser DDPM and DDIM assume, so
    /// a minority kind of motion keeps its share of the samples.
    L2,
}

impl LossNorm {
    /// The mean of the norm of `err` over every element (a scalar tensor).
    fn mean(self, err: &Tensor) -> Result<Tensor> {
        Ok(self.elementwise(err)?.mean_all()?)
    }

    /// |err| or err², elementwise.
    fn elementwise(self, err: &Tensor) -> Result<Tensor> {
        Ok(match self {
            LossNorm::L1 => err.abs()?,
            LossNorm::L2 => err.sqr()?,
        })
    }
}

/// What the network is shown of x_t (the config field `diffusion.input_scaling`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum InputScaling {
    /// x_t as it is (the paper).
    #[default]
    None,
    /// x_t times the linear least-squares gain of x0 from x_t for a signal of spread σ_d,
    /// σ_d²·√ᾱ/((1 − ᾱ) + σ_d²·ᾱ): near 1 at low noise, near 0 at high noise. The network's
    /// skip paths are the same at every level; shown this, they carry the input through where
    /// it is mostly signal and hold it back where it is mostly noise.
    Wiener,
}

impl InputScaling {
    /// The factor on x_t at √ᾱ = `signal`, √(1 − ᾱ) = `noise`.
    pub fn gain(self, signal: f64, noise: f64, sigma_data: f64) -> f64 {
        match self {
            InputScaling::None => 1.0,
            InputScaling::Wiener => wiener_gain(signal, noise, sigma_data),
        }
    }

    /// `x_t` as the network is shown it, with `signal` and `noise` broadcastable to it.
    fn apply(self, x_t: &Tensor, signal: &Tensor, noise: &Tensor, sigma_data: f64) -> Result<Tensor> {
        match self {
            InputScaling::None => Ok(x_t.clone()),
            InputScaling::Wiener => Ok(x_t.broadcast_mul(&wiener_gain_tensor(signal, noise, sigma_data)?)?),
        }
    }
}

/// σ_d²·√ᾱ/((1 − ᾱ) + σ_d²·ᾱ): the least-squares estimate of x0 from x_t is this times x_t,
/// for x0 of spread σ_d.
fn wiener_gain(signal: f64, noise: f64, sigma_data: f64) -> f64 {
    let d2 = sigma_data * sigma_data;
    d2 * signal / (noise * noise + d2 * signal * signal)
}

/// [`wiener_gain`] elementwise, on tensors of one shape.
fn wiener_gain_tensor(signal: &Tensor, noise: &Tensor, sigma_data: f64) -> Result<Tensor> {
    let d2 = sigma_data * sigma_data;
    Ok((signal * d2)?.div(&(noise.sqr()? + (signal.sqr()? * d2)?)?)?)
}

/// How many consecutive values of a flat `[S, P, T, δ]` buffer of `len` values share each of
/// the `levels` noise levels: one level per scene or one per person and frame.
pub(crate) fn values_per_level(shape: [usize; 4], levels: usize, len: usize) -> Result<usize> {
    let [s, p, f, d] = shape;
    if len != s * p * f * d || (levels != s && levels != s * p * f) || len == 0 {
        bail!("{levels} noise levels for {len} values of shape {shape:?}: one per scene or per person and frame expected");
    }
    Ok(if levels == s { p * f * d } else { d })
}

impl Prediction {
    /// `(c_skip, c_out)` with x̂0 = c_skip·x_t + c_out·F at a level of √ᾱ = `signal`,
    /// √(1 − ᾱ) = `noise`; σ_d = `sigma_data` matters for [`Prediction::Edm`] only.
    pub fn mix(self, signal: f64, noise: f64, sigma_data: f64) -> (f64, f64) {
        match self {
            Prediction::X0 => (0.0, 1.0),
            Prediction::V => (signal, -noise),
            Prediction::Edm => {
                let norm = noise * noise + sigma_data * sigma_data * signal * signal;
                (wiener_gain(signal, noise, sigma_data), sigma_data * noise / norm.sqrt())
            }
        }
    }

    /// The training errors of the network's output `out` for clean `x0` noised with `eps`:
    /// `(objective, x̂0 − x0)`. The objective is the error of what the network predicts: x̂0 − x0
    /// for x0, v̂ − v for v (the loss of Salimans & Ho; an L1 of x̂0 − x0 = −√(1 − ᾱ_t)·(v̂ − v)
    /// would leave the output unconstrained at low noise, where it is scaled to nothing in
    /// training but not in sampling's ε̂), F − F* for edm with F* = (x0 − c_skip·x_t)/c_out.
    ///
    /// # Shapes
    /// - `out`, `x0`, `eps`: `[B, P, T, δ]`; `signal`, `noise`: broadcastable to them
    pub fn errors(self, out: Tensor, x0: &Tensor, eps: &Tensor, signal: &Tensor, noise: &Tensor, sigma_data: f64) -> Result<(Tensor, Tensor)> {
        match self {
            Prediction::X0 => {
                let err = (out - x0)?;
                Ok((err.clone(), err))
            }
            Prediction::V => {
                let v = (eps.broadcast_mul(signal)? - x0.broadcast_mul(noise)?)?;
                let err = (out - v)?;
                let x0_err = err.broadcast_mul(noise)?.neg()?;
                Ok((err, x0_err))
            }
            Prediction::Edm => {
                let skip = wiener_gain_tensor(signal, noise, sigma_data)?;
                // c_out = σ_d·n/√(n² + σ_d²·s²) is 0 on clean frames (no noise), where
                // x0 − c_skip·x_t = 0 too and the frame is left out of the loss: kept off 0
                // against 0/0.
                let norm = (noise.sqr()? + (signal.sqr()? * (sigma_data * sigma_data))?)?;
                let c_out = (noise * sigma_data)?.div(&norm.sqrt()?)?.clamp(1e-12, f64::MAX)?;
                let x0_part = (skip.mul(signal)?.neg()? + 1.0)?;
                let target = (x0.broadcast_mul(&x0_part)? - eps.broadcast_mul(&skip.mul(noise)?)?)?.broadcast_div(&c_out)?;
                let err = (out - target)?;
                let x0_err = err.broadcast_mul(&c_out)?;
                Ok((err, x0_err))
            }
        }
    }

    /// x̂0 from the network's output `out` at the input `x`, on flat f32 buffers, in place on `out`, with one step
    /// per scene (`t.len() = S`) or per person and frame (`t.len() = S·P·T`).
    ///
    /// # Shapes
    /// - `x`, `out`: `[S, P, T, δ]` flattened (`shape`)
    pub fn x0_from_output_in_place(self, schedule: &NoiseSchedule, sigma_data: f64, x: &[f32], shape: [usize; 4], t: &[usize], out: &mut [f32]) -> Result<()> {
        if self == Prediction::X0 {
            return Ok(());
        }
        if out.len() != x.len() {
            bail!("x̂0 from the network's output: {} inputs and {} outputs for shape {shape:?}", x.len(), out.len());
        }
        let rows = values_per_level(shape, t.len(), x.len())?;
        for (k, &tk) in t.iter().enumerate() {
            let q = schedule.q(tk)?;
            let (skip, c_out) = self.mix(q.signal, q.noise, sigma_data);
            let range = k * rows..(k + 1) * rows;
            for (o, &xv) in out[range.clone()].iter_mut().zip(&x[range]) {
                *o = (skip * xv as f64 + c_out * *o as f64) as f32;
            }
        }
        Ok(())
    }
}

/// The diffusion process: schedule, number of steps and what the network predicts. Saved with
/// every checkpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DiffusionConfig {
    /// T, the number of diffusion steps (1000).
    pub timesteps: usize,
    /// The variance schedule (cosine, s = 0.008).
    pub schedule: ScheduleKind,
    /// What the network's output stands for (x0, the paper).
    pub prediction: Prediction,
    /// σ_d of [`Prediction::Edm`] and [`InputScaling::Wiener`]: the spread of the signal in
    /// standardized units, the noise level below which the input is passed through (0.5).
    pub sigma_data: f64,
    /// What the network is shown of x_t (as it is, the paper).
    pub input_scaling: InputScaling,
    /// Every signal-to-noise ratio of the schedule divided by its square (1: the paper;
    /// [`NoiseSchedule::snr_shifted`]).
    pub snr_shift: f64,
    /// How the training loss weighs an error (L1, the paper).
    pub loss: LossNorm,
}

impl Default for DiffusionConfig {
    fn default() -> Self {
        Self {
            timesteps: socdiff_schedules::DEFAULT_TIMESTEPS,
            schedule: ScheduleKind::Cosine { s: 0.008 },
            prediction: Prediction::X0,
            sigma_data: 0.5,
            input_scaling: InputScaling::None,
            snr_shift: 1.0,
            loss: LossNorm::L1,
        }
    }
}

impl DiffusionConfig {
    /// The noise schedule this config describes (errors for T = 0 or β outside (0, 1)).
    pub fn noise_schedule(&self) -> Result<NoiseSchedule> {
        let kind = match self.schedule {
            ScheduleKind::Cosine { s } => {
                if !(s.is_finite() && s >= 0.0) {
                    bail!("diffusion config: cosine offset s must be finite and ≥ 0, got {s}");
                }
                BetaSchedule::Cosine { s }
            }
            ScheduleKind::Linear { beta_start, beta_end } => BetaSchedule::Linear { beta_start, beta_end },
        };
        if self.timesteps == 0 {
            bail!("diffusion config: timesteps must be at least 1");
        }
        if !(self.sigma_data.is_finite() && self.sigma_data > 0.0) {
            bail!("diffusion config: sigma_data must be finite and > 0, got {}", self.sigma_data);
        }
        if !(self.snr_shift.is_finite() && self.snr_shift > 0.0) {
            bail!("diffusion config: snr_shift must be finite and > 0, got {}", self.snr_shift);
        }
        Ok(NoiseSchedule::new(kind, self.timesteps)?.snr_shifted(self.snr_shift)?)
    }
}

/// Gaussian diffusion with the x0 objective: forward noising and the training loss (L1, the
/// paper's, or L2: [`LossNorm`]).
#[derive(Clone, Debug)]
pub struct GaussianDiffusion {
    config: DiffusionConfig,
    schedule: NoiseSchedule,
}

impl GaussianDiffusion {
    /// Builds the schedule of `config`.
    pub fn new(config: &DiffusionConfig) -> Result<Self> {
        Ok(Self { config: config.clone(), schedule: config.noise_schedule()? })
    }

    /// The configuration.
    pub fn config(&self) -> &DiffusionConfig {
        &self.config
    }

    /// The noise schedule (for samplers).
    pub fn schedule(&self) -> &NoiseSchedule {
        &self.schedule
    }

    /// T.
    pub fn timesteps(&self) -> usize {
        self.schedule.timesteps()
    }

    /// `b` steps drawn uniformly from 0..T.
    pub fn sample_timesteps(&self, rng: &mut impl Rng, b: usize) -> Vec<usize> {
        (0..b).map(|_| rng.gen_range(0..self.timesteps())).collect()
    }

    /// Per-scene `(√ᾱ_t, √(1 − ᾱ_t))` as two `[B, 1, …, 1]` tensors of rank `rank`.
    fn coefficients(&self, t: &[usize], rank: usize, dtype: DType, device: &Device) -> Result<(Tensor, Tensor)> {
        let mut signal = Vec::with_capacity(t.len());
        let mut noise = Vec::with_capacity(t.len());
        for &ti in t {
            let q = self.schedule.q(ti)?;
            signal.push(q.signal);
            noise.push(q.noise);
        }
        let mut shape = vec![1; rank];
        shape[0] = t.len();
        let s = Tensor::from_vec(signal, shape.clone(), device)?.to_dtype(dtype)?;
        let n = Tensor::from_vec(noise, shape, device)?.to_dtype(dtype)?;
        Ok((s, n))
    }

    /// x_t = √ᾱ_t·x_0 + √(1 − ᾱ_t)·ε, with one step per scene.
    ///
    /// # Shapes
    /// - `x0`, `noise`: `[B, …]` (any rank ≥ 1, e.g. `[B, P, T, δ]`)
    /// - `t`: B steps, each < T
    /// - returns the shape of `x0`
    pub fn q_sample(&self, x0: &Tensor, t: &[usize], noise: &Tensor) -> Result<Tensor> {
        Ok(self.q_sample_with_coefficients(x0, t, noise)?.0)
    }

    /// [`GaussianDiffusion::q_sample`] and the coefficients it used, `(x_t, √ᾱ_t, √(1 − ᾱ_t))`.
    fn q_sample_with_coefficients(&self, x0: &Tensor, t: &[usize], noise: &Tensor) -> Result<(Tensor, Tensor, Tensor)> {
        if x0.dims() != noise.dims() {
            bail!("q_sample: x0 {:?} and noise {:?} differ in shape", x0.dims(), noise.dims());
        }
        if x0.rank() == 0 || x0.dim(0)? != t.len() {
            bail!("q_sample: {} timesteps for x0 of shape {:?}", t.len(), x0.dims());
        }
        let (s, n) = self.coefficients(t, x0.rank(), x0.dtype(), x0.device())?;
        Ok(((x0.broadcast_mul(&s)? + noise.broadcast_mul(&n)?)?, s, n))
    }

    /// The training loss: mean over every element of |x̂0 − x_0| (x0 prediction, the reference's
    /// objective) or of |v̂ − v| (v prediction), L1 (or its square with [`LossNorm::L2`]) over
    /// all frames and persons, observed frames included, as the reference ([`Prediction::errors`]).
    ///
    /// # Shapes
    /// - `x0`, `noise`: `[B, P, T, δ]`; `anchors`: `[B, P, 4]`; `t`: B steps
    /// - returns a scalar tensor (differentiable with respect to the model's parameters)
    pub fn loss(&self, model: &Denoiser, x0: &Tensor, anchors: Option<&Tensor>, t: &[usize], noise: &Tensor) -> Result<Tensor> {
        self.loss_with_velocity(model, x0, anchors, t, noise, None)
    }

    /// [`GaussianDiffusion::loss`] plus, with `velocity = (scales, λ)`, the velocity term
    /// `λ · mean |(Δx̂0 − Δx0) / σ_Δ|` over consecutive frames, `Δx[f] = x[f + 1] − x[f]` and
    /// `σ_Δ = scales` per dim: errors measured on the scale of each dim's frame-to-frame change,
    /// so frame-to-frame noise in a dim that moves slowly relative to its spread (the root) costs
    /// what it costs in a velocity representation.
    ///
    /// # Shapes
    /// - `scales`: `[δ]`; the rest as [`GaussianDiffusion::loss`]
    pub fn loss_with_velocity(
        &self,
        model: &Denoiser,
        x0: &Tensor,
        anchors: Option<&Tensor>,
        t: &[usize],
        noise: &Tensor,
        velocity: Option<(&Tensor, f64)>,
    ) -> Result<Tensor> {
        let (x_t, signal, noise_c) = self.q_sample_with_coefficients(x0, t, noise)?;
        let steps = Tensor::from_vec(t.iter().map(|&v| v as u32).collect::<Vec<u32>>(), t.len(), x0.device())?;
        let shown = self.config.input_scaling.apply(&x_t, &signal, &noise_c, self.config.sigma_data)?;
        let (objective, err) = self.config.prediction.errors(model.forward(&shown, &steps, anchors)?, x0, noise, &signal, &noise_c, self.config.sigma_data)?;
        let loss = self.config.loss.mean(&objective)?;
        let frames = x0.dim(2)?;
        match velocity {
            Some((scales, weight)) if weight > 0.0 && frames > 1 => {
                if scales.dims() != [x0.dim(3)?] {
                    bail!("loss: velocity scales of shape {:?} for x0 of shape {:?}", scales.dims(), x0.dims());
                }
                let d_err = (err.narrow(2, 1, frames - 1)? - err.narrow(2, 0, frames - 1)?)?;
                let term = self.config.loss.mean(&d_err.broadcast_div(scales)?)?;
                Ok((loss + (term * weight)?)?)
            }
            _ => Ok(loss),
        }
    }
}

impl GaussianDiffusion {
    /// The training loss with one noise level per person and frame: `levels[b, p, f]` is a
    /// diffusion step, or `None` for a clean frame (x_t = x_0, shown at level 0 and left out of
    /// the loss). Mean of |g(x_t, levels) − x_0| over the noised frames.
    ///
    /// # Shapes
    /// - `x0`, `noise`: `[B, P, T, δ]`; `anchors`: `[B, P, 4]`; `levels`: `[B, P, T]` flattened
    /// - returns a scalar tensor
    pub fn loss_per_frame(&self, model: &Denoiser, x0: &Tensor, anchors: Option<&Tensor>, levels: &[Option<usize>], noise: &Tensor) -> Result<Tensor> {
        let (b, p, t, d) = x0.dims4()?;
        if levels.len() != b * p * t || noise.dims() != x0.dims() {
            bail!("loss: {} levels and noise {:?} for x0 of shape {:?}", levels.len(), noise.dims(), x0.dims());
        }
        let (mut signal, mut noise_c, mut weight, mut steps) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for l in levels {
            match l {
                None => {
                    signal.push(1.0);
                    noise_c.push(0.0);
                    weight.push(0.0f32);
                    steps.push(0u32);
                }
                Some(ti) => {
                    let q = self.schedule.q(*ti)?;
                    signal.push(q.signal);
                    noise_c.push(q.noise);
                    weight.push(1.0);
                    steps.push(*ti as u32);
                }
            }
        }
        let counted: f32 = weight.iter().sum();
        if counted == 0.0 {
            bail!("loss: every frame is clean, nothing to learn");
        }
        let dev = x0.device();
        let s = Tensor::from_vec(signal, (b, p, t, 1), dev)?.to_dtype(x0.dtype())?;
        let n = Tensor::from_vec(noise_c, (b, p, t, 1), dev)?.to_dtype(x0.dtype())?;
        let w = Tensor::from_vec(weight, (b, p, t, 1), dev)?.to_dtype(x0.dtype())?;
        let x_t = (x0.broadcast_mul(&s)? + noise.broadcast_mul(&n)?)?;
        let shown = self.config.input_scaling.apply(&x_t, &s, &n, self.config.sigma_data)?;
        let pred = model.forward(&shown, &Tensor::from_vec(steps, (b, p, t), dev)?, anchors)?;
        let (objective, _) = self.config.prediction.errors(pred, x0, noise, &s, &n, self.config.sigma_data)?;
        Ok((self.config.loss.elementwise(&objective)?.broadcast_mul(&w)?.sum_all()? / (counted as f64 * d as f64))?)
    }
}

/// `n` draws of N(0, 1) as f32.
pub fn standard_normal(rng: &mut impl Rng, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng.sample::<f32, _>(StandardNormal)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Aggregator, DenoiserConfig};
    use rand::rngs::StdRng;
    use rand::SeedableRng;

    /// A small mean-aggregator network (parameters from `net_seed`) and a draw of x0 and ε of
    /// shape `[b, p, t, k]` from `rng`.
    fn tiny_net_and_draw(k: usize, net_seed: u64, rng: &mut StdRng, (b, p, t): (usize, usize, usize)) -> (Denoiser, Tensor, Tensor) {
        let cfg =
            DenoiserConfig { feature_dims: k, hidden: 8, time_dim: 16, fourier_dim: 8, social_dim: 8, aggregator: Aggregator::Mean, ..Default::default() };
        let net = Denoiser::new(cfg, net_seed).unwrap();
        let x0 = Tensor::from_vec(standard_normal(rng, b * p * t * k), (b, p, t, k), &Device::Cpu).unwrap();
        let eps = Tensor::from_vec(standard_normal(rng, b * p * t * k), (b, p, t, k), &Device::Cpu).unwrap();
        (net, x0, eps)
    }

    /// One level per frame equal to the scene's level is the per-scene loss; clean frames are
    /// shown exactly (x_t = x_0 at level 0) and left out of the mean, computed here by hand.
    #[test]
    fn per_frame_loss_matches_the_scene_loss_and_leaves_clean_frames_out() {
        let d = GaussianDiffusion::new(&DiffusionConfig::default()).unwrap();
        let (b, p, t) = (2, 2, 9);
        let (net, x0, eps) = tiny_net_and_draw(7, 1, &mut StdRng::seed_from_u64(5), (b, p, t));
        let scene = d.loss(&net, &x0, None, &[40, 700], &eps).unwrap().to_scalar::<f32>().unwrap();
        let levels: Vec<Option<usize>> = (0..b * p * t).map(|i| Some(if i < p * t { 40 } else { 700 })).collect();
        let frames = d.loss_per_frame(&net, &x0, None, &levels, &eps).unwrap().to_scalar::<f32>().unwrap();
        assert!((scene - frames).abs() < 1e-6, "{scene} vs {frames}");
        // The first 3 frames clean: by hand, the mean over the other frames.
        let levels: Vec<Option<usize>> = (0..b * p * t).map(|i| if i % t < 3 { None } else { Some(300) }).collect();
        let got = d.loss_per_frame(&net, &x0, None, &levels, &eps).unwrap().to_scalar::<f32>().unwrap();
        let q = d.schedule.q(300).unwrap();
        let (xv, ev) = (x0.flatten_all().unwrap().to_vec1::<f32>().unwrap(), eps.flatten_all().unwrap().to_vec1::<f32>().unwrap());
        let x_t: Vec<f32> =
            xv.iter().zip(&ev).enumerate().map(|(k, (&x, &e))| if (k / 7) % t < 3 { x } else { (q.signal * x as f64 + q.noise * e as f64) as f32 }).collect();
        let lv: Vec<u32> = (0..b * p * t).map(|i| if i % t < 3 { 0 } else { 300 }).collect();
        let pred = net
            .forward(&Tensor::from_vec(x_t, (b, p, t, 7), &Device::Cpu).unwrap(), &Tensor::from_vec(lv, (b, p, t), &Device::Cpu).unwrap(), None)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        let kept: Vec<f64> = (0..xv.len()).filter(|k| (k / 7) % t >= 3).map(|k| (pred[k] - xv[k]).abs() as f64).collect();
        let want = kept.iter().sum::<f64>() / kept.len() as f64;
        assert!((got as f64 - want).abs() < 1e-6, "{got} vs {want}");
        let all_clean = vec![None; b * p * t];
        assert!(d.loss_per_frame(&net, &x0, None, &all_clean, &eps).unwrap_err().to_string().contains("every frame is clean"));
    }

    #[test]
    fn q_sample_matches_schedule_per_scene() {
        let d = GaussianDiffusion::new(&DiffusionConfig::default()).unwrap();
        assert_eq!(d.timesteps(), 1000);
        // Reference values (REFERENCE.md §3.1): ᾱ_0 = 0.99995874, ᾱ_499 = 0.493844.
        let x0 = Tensor::from_vec(vec![1.0f32, 2.0, -1.0, 0.5], (2, 2), &Device::Cpu).unwrap();
        let eps = Tensor::from_vec(vec![0.5f32, -1.0, 2.0, 1.0], (2, 2), &Device::Cpu).unwrap();
        let x_t = d.q_sample(&x0, &[0, 499], &eps).unwrap().to_vec2::<f32>().unwrap();
        let (a0, a1) = (0.99995874f64, 0.493844f64);
        let want = [
            [a0.sqrt() * 1.0 + (1.0 - a0).sqrt() * 0.5, a0.sqrt() * 2.0 - (1.0 - a0).sqrt()],
            [-a1.sqrt() + (1.0 - a1).sqrt() * 2.0, a1.sqrt() * 0.5 + (1.0 - a1).sqrt()],
        ];
        for i in 0..2 {
            for j in 0..2 {
                assert!((x_t[i][j] as f64 - want[i][j]).abs() < 2e-6, "{i},{j}: {} vs {}", x_t[i][j], want[i][j]);
            }
        }
        assert!(d.q_sample(&x0, &[0], &eps).unwrap_err().to_string().contains("1 timesteps"));
        assert!(d.q_sample(&x0, &[0, 1000], &eps).is_err());
        let bad = DiffusionConfig { timesteps: 0, ..Default::default() };
        assert!(GaussianDiffusion::new(&bad).unwrap_err().to_string().contains("timesteps"));
    }

    /// `--loss l2`: the scene loss, its velocity term and the per-frame loss are means of squared
    /// errors, by hand; L1 of the same network and draw is the mean absolute error.
    #[test]
    fn l2_loss_is_the_mean_square_of_each_term() {
        let l1 = GaussianDiffusion::new(&DiffusionConfig::default()).unwrap();
        let l2 = GaussianDiffusion::new(&DiffusionConfig { loss: LossNorm::L2, ..Default::default() }).unwrap();
        let (b, p, t, k) = (2, 2, 8, 5);
        let (net, x0, eps) = tiny_net_and_draw(k, 3, &mut StdRng::seed_from_u64(9), (b, p, t));
        let steps = [120, 850];
        let x_t = l2.q_sample(&x0, &steps, &eps).unwrap();
        let tt = Tensor::from_vec(steps.iter().map(|&v| v as u32).collect::<Vec<_>>(), b, &Device::Cpu).unwrap();
        let pred = net.forward(&x_t, &tt, None).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let x0v = x0.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let e: Vec<f64> = pred.iter().zip(&x0v).map(|(a, b)| (a - b) as f64).collect();
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let squares: Vec<f64> = e.iter().map(|v| v * v).collect();
        let absolutes: Vec<f64> = e.iter().map(|v| v.abs()).collect();
        let got2 = l2.loss(&net, &x0, None, &steps, &eps).unwrap().to_scalar::<f32>().unwrap() as f64;
        let got1 = l1.loss(&net, &x0, None, &steps, &eps).unwrap().to_scalar::<f32>().unwrap() as f64;
        assert!((got2 - mean(&squares)).abs() < 1e-5 * mean(&squares), "{got2} vs {}", mean(&squares));
        assert!((got1 - mean(&absolutes)).abs() < 1e-5 * mean(&absolutes), "{got1} vs {}", mean(&absolutes));
        // The velocity term squares too: λ · mean of (Δe / σ_d)².
        let scales = [0.2f32, 0.5, 1.0, 2.0, 0.1];
        let st = Tensor::from_slice(&scales, k, &Device::Cpu).unwrap();
        let with = l2.loss_with_velocity(&net, &x0, None, &steps, &eps, Some((&st, 0.25))).unwrap().to_scalar::<f32>().unwrap() as f64;
        let mut dv = Vec::new();
        for i in 0..b * p {
            for f in 0..t - 1 {
                for (d, &s) in scales.iter().enumerate() {
                    dv.push(((e[(i * t + f + 1) * k + d] - e[(i * t + f) * k + d]) / s as f64).powi(2));
                }
            }
        }
        let want = mean(&squares) + 0.25 * mean(&dv);
        assert!((with - want).abs() < 1e-5 * want, "{with} vs {want}");
        // One level per frame, equal to each scene's level: the same mean of squares.
        let levels: Vec<Option<usize>> = (0..b * p * t).map(|i| Some(steps[i / (p * t)])).collect();
        let per_frame = l2.loss_per_frame(&net, &x0, None, &levels, &eps).unwrap().to_scalar::<f32>().unwrap() as f64;
        assert!((per_frame - mean(&squares)).abs() < 1e-5 * mean(&squares), "{per_frame} vs {}", mean(&squares));
        // Old configs, written before the field, read as L1.
        let mut old = serde_json::to_value(DiffusionConfig::default()).unwrap();
        old.as_object_mut().unwrap().remove("loss");
        assert_eq!(serde_json::from_value::<DiffusionConfig>(old).unwrap().loss, LossNorm::L1);
        assert_eq!(serde_json::to_value(LossNorm::L2).unwrap(), serde_json::json!("l2"));
    }

    #[test]
    fn loss_is_l1_of_the_x0_prediction() {
        let d = GaussianDiffusion::new(&DiffusionConfig::default()).unwrap();
        let mut rng = StdRng::seed_from_u64(4);
        let (b, p, t, k) = (2, 3, 10, 7);
        let (net, x0, eps) = tiny_net_and_draw(k, 1, &mut rng, (b, p, t));
        let steps = d.sample_timesteps(&mut rng, b);
        let loss = d.loss(&net, &x0, None, &steps, &eps).unwrap().to_scalar::<f32>().unwrap();
        let x_t = d.q_sample(&x0, &steps, &eps).unwrap();
        let tt = Tensor::from_vec(steps.iter().map(|&v| v as u32).collect::<Vec<_>>(), b, &Device::Cpu).unwrap();
        let pred = net.forward(&x_t, &tt, None).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let x0v = x0.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let want = pred.iter().zip(&x0v).map(|(a, b)| (a - b).abs() as f64).sum::<f64>() / pred.len() as f64;
        assert!((loss as f64 - want).abs() < 1e-5, "{loss} vs {want}");
        // The velocity term, by hand: λ · mean over (b, p, f < t − 1, d) of |Δe / σ_d|.
        let scales: Vec<f32> = (0..k).map(|d| 0.1 + 0.2 * d as f32).collect();
        let st = Tensor::from_slice(&scales, k, &Device::Cpu).unwrap();
        let with = d.loss_with_velocity(&net, &x0, None, &steps, &eps, Some((&st, 0.5))).unwrap().to_scalar::<f32>().unwrap();
        let e = |i: usize, f: usize, dd: usize| (pred[(i * t + f) * k + dd] - x0v[(i * t + f) * k + dd]) as f64;
        let mut sum = 0.0;
        for i in 0..b * p {
            for f in 0..t - 1 {
                for (dd, &scale) in scales.iter().enumerate() {
                    sum += ((e(i, f + 1, dd) - e(i, f, dd)) / scale as f64).abs();
                }
            }
        }
        let want_v = want + 0.5 * sum / (b * p * (t - 1) * k) as f64;
        assert!((with as f64 - want_v).abs() < 1e-4 * want_v, "{with} vs {want_v}");
        let off = d.loss_with_velocity(&net, &x0, None, &steps, &eps, Some((&st, 0.0))).unwrap().to_scalar::<f32>().unwrap();
        assert_eq!(off, loss);
        let bad = Tensor::from_slice(&scales[..3], 3, &Device::Cpu).unwrap();
        assert!(d.loss_with_velocity(&net, &x0, None, &steps, &eps, Some((&bad, 1.0))).unwrap_err().to_string().contains("velocity scales"));
        // v prediction, by hand from the schedule's ᾱ, per scene and per frame: the loss of v̂,
        // and x̂0 = √ᾱ_t·x_t − √(1 − ᾱ_t)·F from the flat-buffer conversion.
        let dv = GaussianDiffusion::new(&DiffusionConfig { prediction: Prediction::V, ..Default::default() }).unwrap();
        let xt = x_t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let per = b * p * t * k / b;
        let x0_hat: Vec<f64> = (0..pred.len())
            .map(|i| {
                let ab = d.schedule.alpha_bars()[steps[i / per]];
                ab.sqrt() * xt[i] as f64 - (1.0 - ab).sqrt() * pred[i] as f64
            })
            .collect();
        // The loss is the L1 of v̂ − v, v = √ᾱ_t·ε − √(1 − ᾱ_t)·x0.
        let epsv = eps.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let want_v = (0..pred.len())
            .map(|i| {
                let ab = d.schedule.alpha_bars()[steps[i / per]];
                (pred[i] as f64 - (ab.sqrt() * epsv[i] as f64 - (1.0 - ab).sqrt() * x0v[i] as f64)).abs()
            })
            .sum::<f64>()
            / pred.len() as f64;
        let got_v = dv.loss(&net, &x0, None, &steps, &eps).unwrap().to_scalar::<f32>().unwrap() as f64;
        assert!((got_v - want_v).abs() < 1e-5 * want_v.max(1.0), "{got_v} vs {want_v}");
        let levels: Vec<Option<usize>> = (0..b * p * t).map(|i| Some(steps[i / (p * t)])).collect();
        let got_f = dv.loss_per_frame(&net, &x0, None, &levels, &eps).unwrap().to_scalar::<f32>().unwrap() as f64;
        assert!((got_f - want_v).abs() < 1e-5 * want_v.max(1.0), "{got_f} vs {want_v}");
        let mut flat = pred.clone();
        Prediction::V.x0_from_output_in_place(&d.schedule, 0.5, &xt, [b, p, t, k], &steps, &mut flat).unwrap();
        assert!(flat.iter().zip(&x0_hat).all(|(a, b)| (*a as f64 - b).abs() < 1e-5));
        let per_frame: Vec<usize> = (0..b * p * t).map(|i| steps[i / (p * t)]).collect();
        let mut flat = pred.clone();
        Prediction::V.x0_from_output_in_place(&d.schedule, 0.5, &xt, [b, p, t, k], &per_frame, &mut flat).unwrap();
        assert!(flat.iter().zip(&x0_hat).all(|(a, b)| (*a as f64 - b).abs() < 1e-5));
        let mut same = pred.clone();
        Prediction::X0.x0_from_output_in_place(&d.schedule, 0.5, &xt, [b, p, t, k], &steps, &mut same).unwrap();
        assert_eq!(same, pred);
        assert!(Prediction::V.x0_from_output_in_place(&d.schedule, 0.5, &xt, [b, p, t, k], &steps[..1], &mut flat).is_err());
    }

    /// EDM preconditioning: the mix by hand (σ_d = 1 is v up to F's sign, σ_d → 0 is x0); the
    /// training target F* is the output that gives x̂0 = x0 exactly, the x0 error of any output
    /// is c_skip·x_t + c_out·F − x0, and a clean frame (no noise) has a finite, zero objective.
    #[test]
    fn edm_mix_target_and_conversion_by_hand() {
        let (s, n) = (0.6, 0.8);
        // σ_d = 0.5: ‖·‖² = 0.64 + 0.25·0.36 = 0.73.
        let (skip, out) = Prediction::Edm.mix(s, n, 0.5);
        assert!((skip - 0.25 * 0.6 / 0.73).abs() < 1e-12 && (out - 0.4 / 0.73f64.sqrt()).abs() < 1e-12, "{skip} {out}");
        let (skip1, out1) = Prediction::Edm.mix(s, n, 1.0);
        assert!((skip1 - s).abs() < 1e-12 && (out1 - n).abs() < 1e-12);
        assert_eq!(Prediction::V.mix(s, n, 0.5), (s, -n));
        let (skip0, out0) = Prediction::Edm.mix(s, n, 1e-9);
        assert!(skip0.abs() < 1e-12 && (out0 - 1e-9).abs() < 1e-12); // x0, scaled by σ_d
        assert_eq!(Prediction::Edm.mix(1.0, 0.0, 0.5), (1.0, 0.0)); // no noise: the input itself

        let dev = Device::Cpu;
        let (b, k) = (3, 5);
        let x0v: Vec<f32> = (0..b * k).map(|i| (i as f32 * 0.7).sin()).collect();
        let epsv: Vec<f32> = (0..b * k).map(|i| (i as f32 * 1.3).cos()).collect();
        // Per scene: two noisy levels and a clean one.
        let (sig, noi) = ([0.9f64, 0.3, 1.0], [(1.0 - 0.81f64).sqrt(), (1.0 - 0.09f64).sqrt(), 0.0]);
        let t4 = |v: &[f32], shape: (usize, usize, usize, usize)| Tensor::from_slice(v, shape, &dev).unwrap();
        let (x0, eps) = (t4(&x0v, (b, 1, 1, k)), t4(&epsv, (b, 1, 1, k)));
        let sf: Vec<f32> = sig.iter().map(|&v| v as f32).collect();
        let nf: Vec<f32> = noi.iter().map(|&v| v as f32).collect();
        let (st, nt) = (t4(&sf, (b, 1, 1, 1)), t4(&nf, (b, 1, 1, 1)));
        let zero = Tensor::zeros((b, 1, 1, k), DType::F32, &dev).unwrap();
        let (objective, x0_err) = Prediction::Edm.errors(zero, &x0, &eps, &st, &nt, 0.5).unwrap();
        let (objective, x0_err) = (objective.flatten_all().unwrap().to_vec1::<f32>().unwrap(), x0_err.flatten_all().unwrap().to_vec1::<f32>().unwrap());
        for i in 0..b * k {
            let (sc, ns) = (sig[i / k], noi[i / k]);
            let (skip, out) = Prediction::Edm.mix(sc, ns, 0.5);
            let xt = sc * x0v[i] as f64 + ns * epsv[i] as f64;
            // Output 0: objective −F*, and F* recovers x0.
            let target = -objective[i] as f64;
            assert!(target.is_finite(), "scene {}", i / k);
            assert!((skip * xt + out * target - x0v[i] as f64).abs() < 1e-5, "scene {}: F* misses x0", i / k);
            assert!((x0_err[i] as f64 - (skip * xt - x0v[i] as f64)).abs() < 1e-5, "scene {}", i / k);
        }
        assert!(objective[2 * k..].iter().all(|&v| v == 0.0), "{:?}", &objective[2 * k..]);
        // The flat-buffer conversion: x̂0 = c_skip·x_t + c_out·F at the schedule's levels.
        let d = GaussianDiffusion::new(&DiffusionConfig::default()).unwrap();
        let (steps, per) = ([10usize, 500, 990], k);
        let xt: Vec<f32> = (0..b * k).map(|i| (i as f32 * 0.4).cos()).collect();
        let f: Vec<f32> = (0..b * k).map(|i| (i as f32 * 0.9).sin()).collect();
        let mut flat = f.clone();
        Prediction::Edm.x0_from_output_in_place(&d.schedule, 0.5, &xt, [b, 1, 1, k], &steps, &mut flat).unwrap();
        for i in 0..b * k {
            let ab = d.schedule.alpha_bars()[steps[i / per]];
            let (skip, out) = Prediction::Edm.mix(ab.sqrt(), (1.0 - ab).sqrt(), 0.5);
            assert!((flat[i] as f64 - (skip * xt[i] as f64 + out * f[i] as f64)).abs() < 1e-5);
        }
        let bad = DiffusionConfig { sigma_data: 0.0, ..Default::default() };
        assert!(GaussianDiffusion::new(&bad).unwrap_err().to_string().contains("sigma_data"));
    }

    /// Wiener input scaling: the gain by hand; the network is shown gain·x_t in training (per
    /// scene and per frame, a clean frame unscaled) and in sampling, where x̂0 is the network's
    /// output on the scaled input.
    #[test]
    fn wiener_input_scaling_by_hand() {
        let (s, n) = (0.6, 0.8);
        assert!((InputScaling::Wiener.gain(s, n, 0.5) - 0.25 * 0.6 / 0.73).abs() < 1e-12);
        assert_eq!(InputScaling::None.gain(s, n, 0.5), 1.0);
        assert_eq!(InputScaling::Wiener.gain(1.0, 0.0, 0.5), 1.0);
        assert_eq!(InputScaling::Wiener.gain(0.0, 1.0, 0.5), 0.0);

        let cfg =
            DenoiserConfig { feature_dims: 7, hidden: 8, time_dim: 16, fourier_dim: 8, social_dim: 8, aggregator: Aggregator::Mean, ..Default::default() };
        let net = Denoiser::new(cfg, 1).unwrap();
        let d = GaussianDiffusion::new(&DiffusionConfig { input_scaling: InputScaling::Wiener, sigma_data: 0.7, ..Default::default() }).unwrap();
        let mut rng = StdRng::seed_from_u64(5);
        let (b, p, t, k) = (2, 2, 8, 7);
        let x0 = Tensor::from_vec(standard_normal(&mut rng, b * p * t * k), (b, p, t, k), &Device::Cpu).unwrap();
        let eps = Tensor::from_vec(standard_normal(&mut rng, b * p * t * k), (b, p, t, k), &Device::Cpu).unwrap();
        let steps = [100usize, 700];
        let x_t = d.q_sample(&x0, &steps, &eps).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let per = p * t * k;
        let shown: Vec<f32> = x_t
            .iter()
            .enumerate()
            .map(|(i, &v)| {
                let q = d.schedule.q(steps[i / per]).unwrap();
                (InputScaling::Wiener.gain(q.signal, q.noise, 0.7) * v as f64) as f32
            })
            .collect();
        let tt = Tensor::from_vec(steps.iter().map(|&v| v as u32).collect::<Vec<_>>(), b, &Device::Cpu).unwrap();
        let pred =
            net.forward(&Tensor::from_slice(&shown, (b, p, t, k), &Device::Cpu).unwrap(), &tt, None).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let x0v = x0.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let want = pred.iter().zip(&x0v).map(|(a, b)| (a - b).abs() as f64).sum::<f64>() / pred.len() as f64;
        let got = d.loss(&net, &x0, None, &steps, &eps).unwrap().to_scalar::<f32>().unwrap() as f64;
        assert!((got - want).abs() < 1e-5, "{got} vs {want}");
        let levels: Vec<Option<usize>> = (0..b * p * t).map(|i| Some(steps[i / (p * t)])).collect();
        let got_f = d.loss_per_frame(&net, &x0, None, &levels, &eps).unwrap().to_scalar::<f32>().unwrap() as f64;
        assert!((got_f - want).abs() < 1e-5, "{got_f} vs {want}");
        // Sampling shows the network the same scaled input.
        let sampling = crate::sample::SamplingNet::new(&net, &d, &Device::Cpu).unwrap();
        let mut out = vec![0f32; x_t.len()];
        crate::sample::X0Model::predict_x0(&sampling, &x_t, [b, p, t, k], &steps, None, &mut out).unwrap();
        assert!(out.iter().zip(&pred).all(|(a, b)| (a - b).abs() < 1e-4), "sampling and training show the network different inputs");
    }
}
