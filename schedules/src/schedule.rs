//! Variance schedules: β, α, ᾱ, the forward process q(x_t | x_0) and the posterior
//! q(x_{t−1} | x_t, x_0) (REFERENCE.md §3.1).

use std::f64::consts::FRAC_PI_2;

use crate::{check_timesteps, zip_map, Real, ScheduleError, StepCoefficients};

/// Default number of diffusion steps T.
pub const DEFAULT_TIMESTEPS: usize = 1000;
/// Upper clip of the cosine schedule's β (only β_{T−1} reaches it at s = 0.008).
const MAX_BETA: f64 = 0.999;
/// Floor of the posterior variance before its log (σ̃²_0 = 0).
const MIN_VARIANCE: f64 = 1e-20;

/// How β_t is chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BetaSchedule {
    /// Nichol & Dhariwal's cosine schedule (the reference's): ā(x) = cos²(((x/T) + s)/(1 + s)·π/2)
    /// / ā(0) for x = 0..T, β_t = clip(1 − ā(t+1)/ā(t), 0, 0.999).
    Cosine {
        /// Offset keeping β_0 away from 0; 0.008 in the reference.
        s: f64,
    },
    /// β linearly spaced from `beta_start` (t = 0) to `beta_end` (t = T − 1).
    Linear {
        /// β_0.
        beta_start: f64,
        /// β_{T−1}.
        beta_end: f64,
    },
}

impl Default for BetaSchedule {
    /// The reference's cosine schedule, s = 0.008.
    fn default() -> Self {
        Self::Cosine { s: 0.008 }
    }
}

impl BetaSchedule {
    /// DDPM's linear schedule, 1e-4 → 0.02 at T = 1000, both scaled by 1000/T (as lucidrains).
    pub fn ddpm_linear(timesteps: usize) -> Self {
        let scale = 1000.0 / timesteps as f64;
        Self::Linear { beta_start: 1e-4 * scale, beta_end: 0.02 * scale }
    }

    /// The `timesteps` values β_0..β_{T−1}, in `f64`, not yet validated.
    fn betas(self, timesteps: usize) -> Vec<f64> {
        let n = timesteps as f64;
        match self {
            Self::Cosine { s } => {
                let f = |x: usize| (((x as f64 / n) + s) / (1.0 + s) * FRAC_PI_2).cos().powi(2);
                let a: Vec<f64> = (0..=timesteps).map(|x| f(x) / f(0)).collect();
                a.windows(2).map(|w| (1.0 - w[1] / w[0]).clamp(0.0, MAX_BETA)).collect()
            }
            Self::Linear { beta_start, beta_end } => {
                let step = if timesteps > 1 { (beta_end - beta_start) / (n - 1.0) } else { 0.0 };
                (0..timesteps).map(|t| beta_start + step * t as f64).collect()
            }
        }
    }
}

/// Coefficients of q(x_t | x_0) = N(signal·x_0, noise²·I) at one timestep: signal = √ᾱ_t,
/// noise = √(1 − ᾱ_t).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QCoefficients {
    /// √ᾱ_t.
    pub signal: f64,
    /// √(1 − ᾱ_t).
    pub noise: f64,
}

impl QCoefficients {
    /// The coefficients for a given ᾱ (ᾱ = 1: the identity, signal 1, noise 0).
    pub fn from_alpha_bar(alpha_bar: f64) -> Self {
        Self { signal: alpha_bar.sqrt(), noise: (1.0 - alpha_bar).sqrt() }
    }

    /// x_t = √ᾱ·x_0 + √(1 − ᾱ)·ε.
    pub fn q_sample(&self, x0: f64, eps: f64) -> f64 {
        self.signal * x0 + self.noise * eps
    }

    /// ε = (x_t − √ᾱ·x_0)/√(1 − ᾱ).
    pub fn eps_from_x0(&self, x_t: f64, x0: f64) -> f64 {
        (x_t - self.signal * x0) / self.noise
    }

    /// x_0 = (x_t − √(1 − ᾱ)·ε)/√ᾱ.
    pub fn x0_from_eps(&self, x_t: f64, eps: f64) -> f64 {
        (x_t - self.noise * eps) / self.signal
    }
}

/// A variance schedule over T steps with every derived buffer, all `Vec<f64>` indexed by t.
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseSchedule {
    betas: Vec<f64>,
    alphas: Vec<f64>,
    alpha_bars: Vec<f64>,
    alpha_bars_prev: Vec<f64>,
    posterior_mean_coef1: Vec<f64>,
    posterior_mean_coef2: Vec<f64>,
    posterior_variance: Vec<f64>,
    posterior_log_variance: Vec<f64>,
}

impl Default for NoiseSchedule {
    /// The reference's schedule: cosine, s = 0.008, T = 1000.
    fn default() -> Self {
        Self::new(BetaSchedule::default(), DEFAULT_TIMESTEPS).expect("the default schedule is valid")
    }
}

impl NoiseSchedule {
    /// The schedule `kind` over `timesteps` = T steps.
    ///
    /// Errors: `ZeroSteps` for T = 0, `InvalidBeta` if some β falls outside (0, 1).
    pub fn new(kind: BetaSchedule, timesteps: usize) -> Result<Self, ScheduleError> {
        if timesteps == 0 {
            return Err(ScheduleError::ZeroSteps);
        }
        Self::from_betas(kind.betas(timesteps))
    }

    /// A schedule from explicit β_0..β_{T−1}, each in (0, 1); derives everything else.
    pub fn from_betas(betas: Vec<f64>) -> Result<Self, ScheduleError> {
        if betas.is_empty() {
            return Err(ScheduleError::ZeroSteps);
        }
        if let Some((t, &beta)) = betas.iter().enumerate().find(|(_, &b)| !(b > 0.0 && b < 1.0)) {
            return Err(ScheduleError::InvalidBeta { t, beta });
        }
        // 1. α = 1 − β, ᾱ = cumprod(α), ᾱ_prev = [1, ᾱ[..T−1]].
        let alphas: Vec<f64> = betas.iter().map(|b| 1.0 - b).collect();
        let alpha_bars: Vec<f64> = alphas
            .iter()
            .scan(1.0, |acc, a| {
                *acc *= a;
                Some(*acc)
            })
            .collect();
        let alpha_bars_prev: Vec<f64> = std::iter::once(1.0).chain(alpha_bars[..betas.len() - 1].iter().copied()).collect();
        // 2. Posterior q(x_{t−1} | x_t, x_0) = N(c1·x_0 + c2·x_t, σ̃²·I).
        let n = betas.len();
        let (mut c1, mut c2, mut var) = (Vec::with_capacity(n), Vec::with_capacity(n), Vec::with_capacity(n));
        for t in 0..n {
            let (beta, ab, ab_prev) = (betas[t], alpha_bars[t], alpha_bars_prev[t]);
            c1.push(beta * ab_prev.sqrt() / (1.0 - ab));
            c2.push((1.0 - ab_prev) * alphas[t].sqrt() / (1.0 - ab));
            var.push(beta * (1.0 - ab_prev) / (1.0 - ab));
        }
        let log_var = var.iter().map(|v: &f64| v.max(MIN_VARIANCE).ln()).collect();
        Ok(Self {
            betas,
            alphas,
            alpha_bars,
            alpha_bars_prev,
            posterior_mean_coef1: c1,
            posterior_mean_coef2: c2,
            posterior_variance: var,
            posterior_log_variance: log_var,
        })
    }

    /// The schedule restricted to the kept timesteps (strictly descending, as
    /// [`Sampler::timesteps`](crate::Sampler::timesteps) lists them): its step j is original
    /// step `kept[K−1−j]`, with β'_j = 1 − ᾱ_{kept}/ᾱ_{previous kept} (ᾱ = 1 before the first),
    /// so ᾱ' = cumprod(1 − β') equals ᾱ at the kept steps. DDPM on it is DDIM with η = 1 on
    /// `self` (feed the model the original timestep).
    pub fn respaced(&self, kept: &[usize]) -> Result<Self, ScheduleError> {
        check_timesteps(kept, self.timesteps())?;
        let mut prev = 1.0;
        let betas = kept
            .iter()
            .rev()
            .map(|&t| {
                let beta = 1.0 - self.alpha_bars[t] / prev;
                prev = self.alpha_bars[t];
                beta
            })
            .collect();
        Self::from_betas(betas)
    }

    /// The same schedule seen at a resolution `shift` times coarser (Hoogeboom et al. 2023,
    /// "simple diffusion"): every signal-to-noise ratio ᾱ/(1 − ᾱ) divided by shift², i.e.
    /// ᾱ'_t = ᾱ_t / (ᾱ_t + shift²·(1 − ᾱ_t)), with β'_t = 1 − ᾱ'_t/ᾱ'_{t−1}. A long sequence
    /// averages the noise over many frames, so its slow components (where a person goes, how
    /// fast) stay readable up to high noise levels; `shift` > 1 noises them as much as a short
    /// window's. `shift` = 1 returns the schedule unchanged.
    ///
    /// Errors: `InvalidShift` (not finite or ≤ 0).
    pub fn snr_shifted(&self, shift: f64) -> Result<Self, ScheduleError> {
        if !(shift.is_finite() && shift > 0.0) {
            return Err(ScheduleError::InvalidShift(shift));
        }
        if shift == 1.0 {
            return Ok(self.clone());
        }
        let s2 = shift * shift;
        let mut prev = 1.0;
        let betas = self
            .alpha_bars
            .iter()
            .map(|&ab| {
                let shifted = ab / (ab + s2 * (1.0 - ab));
                let beta = 1.0 - shifted / prev;
                prev = shifted;
                beta
            })
            .collect();
        Self::from_betas(betas)
    }

    /// T, the number of diffusion steps.
    pub fn timesteps(&self) -> usize {
        self.betas.len()
    }

    /// β_t.
    pub fn betas(&self) -> &[f64] {
        &self.betas
    }

    /// α_t = 1 − β_t.
    pub fn alphas(&self) -> &[f64] {
        &self.alphas
    }

    /// ᾱ_t = α_0·…·α_t.
    pub fn alpha_bars(&self) -> &[f64] {
        &self.alpha_bars
    }

    /// ᾱ_{t−1}, with ᾱ_{−1} = 1.
    pub fn alpha_bars_prev(&self) -> &[f64] {
        &self.alpha_bars_prev
    }

    /// c1 = β_t·√ᾱ_{t−1}/(1 − ᾱ_t), the posterior mean's weight on x_0.
    pub fn posterior_mean_coef1(&self) -> &[f64] {
        &self.posterior_mean_coef1
    }

    /// c2 = (1 − ᾱ_{t−1})·√α_t/(1 − ᾱ_t), the posterior mean's weight on x_t.
    pub fn posterior_mean_coef2(&self) -> &[f64] {
        &self.posterior_mean_coef2
    }

    /// σ̃²_t = β_t·(1 − ᾱ_{t−1})/(1 − ᾱ_t) (0 at t = 0).
    pub fn posterior_variance(&self) -> &[f64] {
        &self.posterior_variance
    }

    /// ln max(σ̃²_t, 1e-20).
    pub fn posterior_log_variance(&self) -> &[f64] {
        &self.posterior_log_variance
    }

    /// `Err(TimestepOutOfRange)` unless t < T.
    fn check_t(&self, t: usize) -> Result<(), ScheduleError> {
        if t < self.timesteps() {
            Ok(())
        } else {
            Err(ScheduleError::TimestepOutOfRange { t, timesteps: self.timesteps() })
        }
    }

    /// The scalar coefficients of q(x_t | x_0): √ᾱ_t and √(1 − ᾱ_t).
    pub fn q(&self, t: usize) -> Result<QCoefficients, ScheduleError> {
        self.check_t(t)?;
        Ok(QCoefficients::from_alpha_bar(self.alpha_bars[t]))
    }

    /// The ancestral (DDPM) step at t as x_{t−1} = c1·x̂0 + c2·x_t + σ_t·z, with
    /// σ_t = exp(½·log σ̃²_t) and σ_0 = 0 (no noise on the last step).
    pub fn posterior(&self, t: usize) -> Result<StepCoefficients, ScheduleError> {
        self.check_t(t)?;
        let noise = if t == 0 { 0.0 } else { (0.5 * self.posterior_log_variance[t]).exp() };
        Ok(StepCoefficients { x0: self.posterior_mean_coef1[t], xt: self.posterior_mean_coef2[t], noise })
    }

    /// `out = √ᾱ_t·x0 + √(1 − ᾱ_t)·noise`, elementwise: a draw of x_t given x_0.
    pub fn q_sample<F: Real>(&self, t: usize, x0: &[F], noise: &[F], out: &mut [F]) -> Result<(), ScheduleError> {
        let q = self.q(t)?;
        zip_map(x0, noise, out, |x0, z| q.q_sample(x0, z))
    }

    /// `out = ε = (x_t − √ᾱ_t·x0)/√(1 − ᾱ_t)`, elementwise.
    pub fn eps_from_x0<F: Real>(&self, t: usize, x_t: &[F], x0: &[F], out: &mut [F]) -> Result<(), ScheduleError> {
        let q = self.q(t)?;
        zip_map(x_t, x0, out, |x_t, x0| q.eps_from_x0(x_t, x0))
    }

    /// `out = x_0 = (x_t − √(1 − ᾱ_t)·eps)/√ᾱ_t`, elementwise.
    pub fn x0_from_eps<F: Real>(&self, t: usize, x_t: &[F], eps: &[F], out: &mut [F]) -> Result<(), ScheduleError> {
        let q = self.q(t)?;
        zip_map(x_t, eps, out, |x_t, eps| q.x0_from_eps(x_t, eps))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// |a − b| ≤ rel·|b|.
    fn assert_rel(a: f64, b: f64, rel: f64) {
        assert!((a - b).abs() <= rel * b.abs(), "{a} vs {b} (rel tol {rel})");
    }

    #[test]
    fn cosine_matches_reference_values() {
        // REFERENCE.md §3.1.
        let s = NoiseSchedule::default();
        assert_eq!(s.timesteps(), 1000);
        assert_rel(s.betas()[0], 4.128e-5, 1e-3);
        // The reference prints float32 buffers, which resolve 6e-8 near 1.
        assert!((s.alpha_bars()[0] - 0.99995874).abs() < 5e-8);
        assert_rel(s.alpha_bars()[499], 0.493844, 1e-5);
        assert_rel(s.alpha_bars()[999], 2.43e-9, 1e-2);
    }

    #[test]
    fn cosine_clips_only_the_last_beta() {
        let s = NoiseSchedule::default();
        assert_eq!(s.betas()[999], 0.999);
        assert!(s.betas()[..999].iter().all(|&b| b > 0.0 && b < 0.999));
        // β_998 = 0.74999939 in a float64 Python evaluation of the same formula.
        assert_rel(s.betas()[998], 0.7499993929011166, 1e-12);
    }

    #[test]
    fn snr_shift_divides_every_snr_by_its_square() {
        let base = NoiseSchedule::default();
        let shifted = base.snr_shifted(2.0).unwrap();
        let snr = |ab: f64| ab / (1.0 - ab);
        for t in 0..1000 {
            assert_rel(snr(shifted.alpha_bars()[t]), snr(base.alpha_bars()[t]) / 4.0, 1e-9);
        }
        // float64 Python, from the cosine formula: ᾱ/(ᾱ + 4(1 − ᾱ)) at t = 0, 499, 998.
        assert_rel(shifted.alpha_bars()[0], 0.9998348835508258, 1e-12);
        assert_rel(shifted.alpha_bars()[499], 0.19608879267500526, 1e-9);
        assert_rel(shifted.alpha_bars()[998], 6.071928328061069e-07, 1e-6);
        assert!(shifted.betas().iter().all(|&b| b > 0.0 && b < 1.0));
        // shift < 1 cleans, 1 is the identity; the two shifts undo each other
        assert_eq!(base.snr_shifted(1.0).unwrap(), base);
        let back = shifted.snr_shifted(0.5).unwrap();
        for t in 0..999 {
            assert_rel(back.alpha_bars()[t], base.alpha_bars()[t], 1e-9);
        }
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(base.snr_shifted(bad), Err(ScheduleError::InvalidShift(_))), "{bad}");
        }
    }

    #[test]
    fn derived_buffers_are_consistent() {
        let s = NoiseSchedule::default();
        assert_eq!(s.alpha_bars_prev()[0], 1.0);
        for t in 1..1000 {
            assert_eq!(s.alpha_bars_prev()[t], s.alpha_bars()[t - 1]);
            assert_rel(s.alpha_bars()[t], s.alpha_bars()[t - 1] * s.alphas()[t], 1e-15);
            assert_eq!(s.alphas()[t], 1.0 - s.betas()[t]);
        }
    }

    #[test]
    fn posterior_known_values() {
        // Oracles: the formulas of REFERENCE.md §3.1 evaluated in float64 Python.
        let s = NoiseSchedule::default();
        let var = [
            (1, 2.178949614569182e-05, -10.734082532465003),
            (10, 7.867762336998671e-05, -9.450151771178401),
            (500, 0.0031460051254634824, -5.761621845147288),
            (999, 0.9989975760881921, -0.0010029266746731796),
        ];
        for (t, v, log_v) in var {
            assert_rel(s.posterior_variance()[t], v, 1e-9);
            assert_rel(s.posterior_log_variance()[t], log_v, 1e-9);
        }
        assert_eq!(s.posterior_variance()[0], 0.0);
        assert_rel(s.posterior_log_variance()[0], 1e-20_f64.ln(), 1e-15);
        let coefs =
            [(1, 0.5277814093344871, 0.47221859042675934), (500, 0.004367866899526324, 0.9953562794552251), (999, 0.0015568917154901694, 0.03162269987413465)];
        for (t, c1, c2) in coefs {
            assert_rel(s.posterior_mean_coef1()[t], c1, 1e-9);
            assert_rel(s.posterior_mean_coef2()[t], c2, 1e-9);
        }
        // t = 0: c1 = β_0/(1 − ᾱ_0) = 1 up to rounding, c2 = 0 exactly, no noise.
        let p0 = s.posterior(0).unwrap();
        assert!((p0.x0 - 1.0).abs() < 1e-10);
        assert_eq!((p0.xt, p0.noise), (0.0, 0.0));
        assert_rel(s.posterior(500).unwrap().noise, 0.0031460051254634824_f64.sqrt(), 1e-9);
    }

    #[test]
    fn linear_schedule_endpoints() {
        let s = NoiseSchedule::new(BetaSchedule::ddpm_linear(1000), 1000).unwrap();
        assert_rel(s.betas()[0], 1e-4, 1e-12);
        assert_rel(s.betas()[999], 0.02, 1e-12);
        assert_rel(s.betas()[500], 1e-4 + 0.0199 * 500.0 / 999.0, 1e-12);
        // ᾱ_999 of DDPM's linear schedule (float64 Python).
        assert_rel(s.alpha_bars()[999], 4.0358297653756754e-05, 1e-9);
        // Scaled by 1000/T.
        let s = NoiseSchedule::new(BetaSchedule::ddpm_linear(250), 250).unwrap();
        assert_rel(s.betas()[0], 4e-4, 1e-12);
        assert_rel(s.betas()[249], 0.08, 1e-12);
    }

    #[test]
    fn x0_eps_round_trip() {
        let s = NoiseSchedule::default();
        let x0 = [0.3_f64, -1.2, 2.0, 0.0];
        let eps = [1.0_f64, 0.5, -0.7, -2.0];
        let (mut x_t, mut eps_back, mut x0_back) = ([0.0; 4], [0.0; 4], [0.0; 4]);
        for t in [0, 1, 499, 998] {
            s.q_sample(t, &x0, &eps, &mut x_t).unwrap();
            s.eps_from_x0(t, &x_t, &x0, &mut eps_back).unwrap();
            s.x0_from_eps(t, &x_t, &eps, &mut x0_back).unwrap();
            for k in 0..4 {
                assert!((eps_back[k] - eps[k]).abs() < 1e-9, "t={t}");
                assert!((x0_back[k] - x0[k]).abs() < 1e-9, "t={t}");
            }
        }
        // f32 slices, t = 499: x_t = √ᾱ·x0 + √(1 − ᾱ)·ε with ᾱ_499 = 0.49384359.
        let (x0, eps) = ([1.0_f32, -2.0], [0.5_f32, 0.25]);
        let mut x_t = [0.0_f32; 2];
        s.q_sample(499, &x0, &eps, &mut x_t).unwrap();
        let (a, b) = (0.49384359044063775_f64.sqrt(), (1.0 - 0.49384359044063775_f64).sqrt());
        assert!((f64::from(x_t[0]) - (a + 0.5 * b)).abs() < 1e-6);
        assert!((f64::from(x_t[1]) - (-2.0 * a + 0.25 * b)).abs() < 1e-6);
        let mut back = [0.0_f32; 2];
        s.x0_from_eps(499, &x_t, &eps, &mut back).unwrap();
        assert!((back[0] - 1.0).abs() < 1e-6 && (back[1] + 2.0).abs() < 1e-6);
    }

    #[test]
    fn respaced_schedule_keeps_alpha_bars() {
        let s = NoiseSchedule::default();
        let kept = [999, 700, 420, 100, 37, 0];
        let r = s.respaced(&kept).unwrap();
        assert_eq!(r.timesteps(), kept.len());
        for (j, &t) in kept.iter().rev().enumerate() {
            // 1 − β' loses digits where β' ≈ 1 (ᾱ_999/ᾱ_700 ≈ 1e-8).
            assert_rel(r.alpha_bars()[j], s.alpha_bars()[t], 1e-7);
        }
        // Keeping every step gives the schedule back.
        let all: Vec<usize> = (0..1000).rev().collect();
        let r = s.respaced(&all).unwrap();
        for t in 0..1000 {
            assert_rel(r.betas()[t], s.betas()[t], 1e-9);
            assert_rel(r.alpha_bars()[t], s.alpha_bars()[t], 1e-12);
        }
    }

    #[test]
    fn bad_arguments_are_errors() {
        use ScheduleError::*;
        assert_eq!(NoiseSchedule::new(BetaSchedule::default(), 0), Err(ZeroSteps));
        assert_eq!(NoiseSchedule::from_betas(vec![]), Err(ZeroSteps));
        // 1000/T scaling pushes β past 1 for T = 10.
        let err = NoiseSchedule::new(BetaSchedule::ddpm_linear(10), 10).unwrap_err();
        assert!(matches!(err, InvalidBeta { t: 5, .. }), "{err}");
        let err = NoiseSchedule::from_betas(vec![0.1, 0.0]).unwrap_err();
        assert_eq!(err, InvalidBeta { t: 1, beta: 0.0 });
        assert!(NoiseSchedule::new(BetaSchedule::Cosine { s: f64::NAN }, 10).is_err());
        let s = NoiseSchedule::default();
        assert_eq!(s.q(1000), Err(TimestepOutOfRange { t: 1000, timesteps: 1000 }));
        assert!(s.posterior(1000).is_err());
        let mut out = [0.0_f32; 3];
        let err = s.q_sample(3, &[1.0; 3], &[1.0; 2], &mut out).unwrap_err();
        assert_eq!(err, LengthMismatch { expected: 3, got: 2 });
        assert!(s.eps_from_x0(3, &[1.0_f32; 4], &[1.0; 4], &mut out).is_err());
        assert_eq!(s.respaced(&[5, 5, 0]), Err(NotDescending { index: 1 }));
        assert!(matches!(s.respaced(&[1000, 0]), Err(TimestepOutOfRange { .. })));
        assert_eq!(s.respaced(&[]), Err(ZeroSteps));
        assert_eq!(err.to_string(), "slice length 2 does not match 3");
    }
}
