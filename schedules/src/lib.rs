//! Noise schedules and samplers for socdiff: pure `f64` math, no tensors.
//!
//! Follows METHOD.md §4 and REFERENCE.md §3 (the reference's `GaussianDiffusion`, adapted from
//! lucidrains' `denoising-diffusion-pytorch`), with the network predicting x̂0:
//!
//! - [`NoiseSchedule`]: the cosine (default, s = 0.008, T = 1000) or linear variance schedule,
//!   the forward process q(x_t | x_0) and the posterior q(x_{t−1} | x_t, x_0).
//! - [`Sampler`]: one reverse step x_t → x_prev from the model's x̂0, implemented by [`Ddpm`]
//!   (ancestral, every step) and [`Ddim`] (any K ≤ T respaced steps, stochasticity η).
//!
//! Every reverse step is linear, x_prev = a·x̂0 + b·x_t + σ·z, so samplers hand out the three
//! scalars ([`StepCoefficients`]) and a tensor engine can apply them in one fused operation; the
//! slice functions here do the same per element on `&[f32]` or `&[f64]` (see [`Real`]).
//! Bad arguments (0 steps, K > T, η outside [0, 1], mismatched lengths, …) return a
//! [`ScheduleError`]; nothing here panics on user input.
//!
//! # Notation
//!
//! Timesteps are zero-based: code `t = 0..T−1` is paper step t + 1, and `t = 0` is the least
//! noisy. "prev" is the step a reverse step lands on (t − 1 for DDPM, the next kept step for
//! DDIM), with ᾱ_prev = 1 after the last step.
//!
//! | symbol | meaning | code |
//! |---|---|---|
//! | T | number of diffusion steps | [`NoiseSchedule::timesteps`] |
//! | β_t | variance added at step t | [`NoiseSchedule::betas`] |
//! | α_t | 1 − β_t | [`NoiseSchedule::alphas`] |
//! | ᾱ_t | ∏_{s ≤ t} α_s | [`NoiseSchedule::alpha_bars`] |
//! | ᾱ_{t−1} | ᾱ shifted by one, ᾱ_{−1} = 1 | [`NoiseSchedule::alpha_bars_prev`] |
//! | √ᾱ_t, √(1 − ᾱ_t) | q(x_t \| x_0) = N(√ᾱ_t·x_0, (1 − ᾱ_t)·I) | [`QCoefficients`]`{ signal, noise }` |
//! | c1, c2 | posterior mean c1·x_0 + c2·x_t | [`NoiseSchedule::posterior_mean_coef1`], [`…coef2`](NoiseSchedule::posterior_mean_coef2) |
//! | σ̃²_t | posterior variance β_t(1 − ᾱ_{t−1})/(1 − ᾱ_t) | [`NoiseSchedule::posterior_variance`] |
//! | log σ̃²_t | its log, clamped at 1e-20 | [`NoiseSchedule::posterior_log_variance`] |
//! | x_t, x̂0, ε̂, z | noisy sample, model's x_0, implied noise, fresh N(0, I) | `x_t`, `x0_pred`, `eps`, `noise` |
//! | K, η | DDIM steps and stochasticity | [`Ddim::new`] |
//! | a, b, σ | x_prev = a·x̂0 + b·x_t + σ·z | [`StepCoefficients`]`{ x0, xt, noise }` |
//!
//! # Example: a sampling loop
//!
//! ```
//! use socdiff_schedules::{Ddim, NoiseSchedule, Sampler};
//!
//! let schedule = NoiseSchedule::default(); // cosine, T = 1000
//! let sampler = Ddim::new(&schedule, 50, 0.0)?; // deterministic DDIM, 50 steps
//! let target = [0.25_f32, -0.5, 1.0];
//! let mut x = vec![1.0_f32, -1.0, 0.5]; // x_T, normally N(0, I)
//! let mut out = vec![0.0_f32; x.len()];
//! for i in 0..sampler.timesteps().len() {
//!     let x0_pred = target; // the network g(x_t, t = sampler.timesteps()[i]) goes here
//!     sampler.step(i, &x0_pred, &x, None, &mut out)?; // η = 0 needs no noise
//!     std::mem::swap(&mut x, &mut out);
//! }
//! assert_eq!(x, target);
//! # Ok::<(), socdiff_schedules::ScheduleError>(())
//! ```

mod ddim;
mod ddpm;
mod error;
mod sampler;
mod schedule;

pub use ddim::{respaced_timesteps, Ddim};
pub use ddpm::Ddpm;
pub use error::ScheduleError;
pub use sampler::{Sampler, StepCoefficients, StepTable};
pub use schedule::{BetaSchedule, NoiseSchedule, QCoefficients, DEFAULT_TIMESTEPS};

/// A sample element the slice functions accept (`f32` or `f64`); math is done in `f64`.
pub trait Real: Copy {
    /// Widens to `f64`.
    fn to_f64(self) -> f64;
    /// Rounds from `f64`.
    fn from_f64(v: f64) -> Self;
}

impl Real for f32 {
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
    fn from_f64(v: f64) -> Self {
        v as f32
    }
}

impl Real for f64 {
    fn to_f64(self) -> f64 {
        self
    }
    fn from_f64(v: f64) -> Self {
        v
    }
}

/// `Err(LengthMismatch)` unless `got == expected`.
fn check_len(expected: usize, got: usize) -> Result<(), ScheduleError> {
    if got == expected {
        Ok(())
    } else {
        Err(ScheduleError::LengthMismatch { expected, got })
    }
}

/// `out[k] = f(a[k], b[k])` in `f64`, after checking that all three lengths agree.
fn zip_map<F: Real>(a: &[F], b: &[F], out: &mut [F], f: impl Fn(f64, f64) -> f64) -> Result<(), ScheduleError> {
    check_len(out.len(), a.len())?;
    check_len(out.len(), b.len())?;
    for ((o, &a), &b) in out.iter_mut().zip(a).zip(b) {
        *o = F::from_f64(f(a.to_f64(), b.to_f64()));
    }
    Ok(())
}

/// Checks a sampler's timestep list: non-empty, each `< timesteps`, strictly descending.
fn check_timesteps(kept: &[usize], timesteps: usize) -> Result<(), ScheduleError> {
    if kept.is_empty() {
        return Err(ScheduleError::ZeroSteps);
    }
    if let Some(&t) = kept.iter().find(|&&t| t >= timesteps) {
        return Err(ScheduleError::TimestepOutOfRange { t, timesteps });
    }
    match kept.windows(2).position(|w| w[0] <= w[1]) {
        Some(index) => Err(ScheduleError::NotDescending { index: index + 1 }),
        None => Ok(()),
    }
}
