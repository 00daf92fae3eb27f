//! DDIM sampling (Song et al. 2021, Eq. 12) over a respaced subset of K ≤ T timesteps.

use crate::sampler::StepTable;
use crate::{check_timesteps, NoiseSchedule, QCoefficients, Sampler, ScheduleError, StepCoefficients};

/// K of T timesteps, descending, evenly spaced with both ends kept (diffusers' "linspace"
/// spacing): t_j = round(j·(T−1)/(K−1)) for j = K−1..0, halves rounded up. So the first step
/// starts from pure noise at T−1 and the last is t = 0; K = T keeps every step, and K = 1 is the
/// single jump [T−1] → x̂0.
///
/// Errors: `ZeroSteps` for K = 0, `TooManySteps` for K > T.
pub fn respaced_timesteps(timesteps: usize, steps: usize) -> Result<Vec<usize>, ScheduleError> {
    match steps {
        0 => Err(ScheduleError::ZeroSteps),
        k if k > timesteps => Err(ScheduleError::TooManySteps { steps: k, timesteps }),
        1 => Ok(vec![timesteps - 1]),
        k => Ok((0..k).rev().map(|j| (2 * j * (timesteps - 1) + k - 1) / (2 * (k - 1))).collect()),
    }
}

/// DDIM: from x_t and x̂0, with ᾱ_prev the ᾱ of the next kept step (1 after the last),
/// 1. ε̂ = (x_t − √ᾱ_t·x̂0)/√(1 − ᾱ_t);
/// 2. σ = η·√((1 − ᾱ_prev)/(1 − ᾱ_t))·√(1 − ᾱ_t/ᾱ_prev);
/// 3. x_prev = √ᾱ_prev·x̂0 + √(1 − ᾱ_prev − σ²)·ε̂ + σ·z.
///
/// η = 0 is deterministic; η = 1 with K = T is ancestral DDPM. The last step always returns x̂0.
#[derive(Clone, Debug, PartialEq)]
pub struct Ddim {
    eta: f64,
    table: StepTable,
}

impl Ddim {
    /// K = `steps` evenly spaced timesteps of `schedule` ([`respaced_timesteps`]), stochasticity η.
    ///
    /// Errors: `ZeroSteps`, `TooManySteps` (K > T), `InvalidEta` (η outside [0, 1]).
    pub fn new(schedule: &NoiseSchedule, steps: usize, eta: f64) -> Result<Self, ScheduleError> {
        Self::with_timesteps(schedule, respaced_timesteps(schedule.timesteps(), steps)?, eta)
    }

    /// Any subset of timesteps, strictly descending, each < T.
    ///
    /// Errors: `ZeroSteps`, `TimestepOutOfRange`, `NotDescending`, `InvalidEta`.
    pub fn with_timesteps(schedule: &NoiseSchedule, timesteps: Vec<usize>, eta: f64) -> Result<Self, ScheduleError> {
        if !(0.0..=1.0).contains(&eta) {
            return Err(ScheduleError::InvalidEta(eta));
        }
        check_timesteps(&timesteps, schedule.timesteps())?;
        let ab = schedule.alpha_bars();
        let ab_prevs: Vec<f64> = timesteps.iter().skip(1).map(|&t| ab[t]).chain(std::iter::once(1.0)).collect();
        let steps = timesteps
            .iter()
            .zip(&ab_prevs)
            .map(|(&t, &ab_prev)| {
                let ab_t = ab[t];
                let sigma = eta * ((1.0 - ab_prev) / (1.0 - ab_t)).sqrt() * (1.0 - ab_t / ab_prev).sqrt();
                // Weight of ε̂; ≥ 0 for η ≤ 1 analytically, clamped against rounding.
                let dir = (1.0 - ab_prev - sigma * sigma).max(0.0).sqrt();
                // Substituting ε̂ of step 1 into step 3 makes the step linear in x̂0 and x_t.
                let eps_per_xt = 1.0 / (1.0 - ab_t).sqrt();
                StepCoefficients { x0: ab_prev.sqrt() - dir * ab_t.sqrt() * eps_per_xt, xt: dir * eps_per_xt, noise: sigma }
            })
            .collect();
        let q_prev = ab_prevs.into_iter().map(QCoefficients::from_alpha_bar).collect();
        Ok(Self { eta, table: StepTable { timesteps, steps, q_prev } })
    }

    /// η, the stochasticity (0: deterministic DDIM, 1: DDPM-like).
    pub fn eta(&self) -> f64 {
        self.eta
    }
}

impl Sampler for Ddim {
    fn table(&self) -> &StepTable {
        &self.table
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Ddpm;

    #[test]
    fn respacing_convention() {
        let ts = respaced_timesteps(1000, 50).unwrap();
        assert_eq!(ts.len(), 50);
        assert_eq!((ts[0], ts[1], ts[48], ts[49]), (999, 979, 20, 0)); // 49·999/49, 48·999/49 = 978.61…
        assert!(ts.windows(2).all(|w| w[0] > w[1]));
        assert_eq!(respaced_timesteps(10, 4).unwrap(), vec![9, 6, 3, 0]);
        assert_eq!(respaced_timesteps(10, 3).unwrap(), vec![9, 5, 0]); // 4.5 rounds up
        assert_eq!(respaced_timesteps(7, 7).unwrap(), vec![6, 5, 4, 3, 2, 1, 0]);
        assert_eq!(respaced_timesteps(1000, 1).unwrap(), vec![999]);
        assert_eq!(respaced_timesteps(1000, 0), Err(ScheduleError::ZeroSteps));
        assert_eq!(respaced_timesteps(1000, 1001), Err(ScheduleError::TooManySteps { steps: 1001, timesteps: 1000 }));
    }

    #[test]
    fn full_ddim_with_eta_one_is_ddpm() {
        let s = NoiseSchedule::default();
        let (ddim, ddpm) = (Ddim::new(&s, 1000, 1.0).unwrap(), Ddpm::new(&s));
        assert_eq!(ddim.timesteps(), ddpm.timesteps());
        let x0 = [0.7_f32, -1.3, 0.0, 2.5];
        let x_t = [-0.4_f32, 1.9, 0.8, -2.2];
        let z = [1.1_f32, -0.6, 0.3, -1.7];
        for i in 0..1000 {
            let (a, b) = (ddim.coefficients(i).unwrap(), ddpm.coefficients(i).unwrap());
            for (u, v) in [(a.x0, b.x0), (a.xt, b.xt), (a.noise, b.noise)] {
                assert!((u - v).abs() <= 1e-9 * v.abs().max(1e-3), "i={i}: {a:?} vs {b:?}");
            }
            assert_eq!(ddim.q_prev(i).unwrap(), ddpm.q_prev(i).unwrap());
            let (mut out_a, mut out_b) = ([0.0_f32; 4], [0.0_f32; 4]);
            ddim.step(i, &x0, &x_t, Some(&z), &mut out_a).unwrap();
            ddpm.step(i, &x0, &x_t, Some(&z), &mut out_b).unwrap();
            for k in 0..4 {
                assert!((out_a[k] - out_b[k]).abs() < 1e-6, "i={i}");
            }
        }
    }

    #[test]
    fn respaced_ddim_with_eta_one_is_ddpm_on_the_respaced_schedule() {
        let s = NoiseSchedule::default();
        let ddim = Ddim::new(&s, 50, 1.0).unwrap();
        let ddpm = Ddpm::new(&s.respaced(ddim.timesteps()).unwrap());
        for i in 0..50 {
            let (a, b) = (ddim.coefficients(i).unwrap(), ddpm.coefficients(i).unwrap());
            for (u, v) in [(a.x0, b.x0), (a.xt, b.xt), (a.noise, b.noise)] {
                assert!((u - v).abs() <= 1e-9 * v.abs().max(1e-3), "i={i}: {a:?} vs {b:?}");
            }
        }
    }

    #[test]
    fn eta_zero_is_deterministic_and_ends_at_x0() {
        let s = NoiseSchedule::default();
        let ddim = Ddim::new(&s, 50, 0.0).unwrap();
        assert_eq!(ddim.eta(), 0.0);
        assert!((0..50).all(|i| !ddim.needs_noise(i).unwrap()));
        let last = ddim.coefficients(49).unwrap();
        assert_eq!(last, StepCoefficients { x0: 1.0, xt: 0.0, noise: 0.0 });
        // Step 0: t = 999 → 979; x̂0 and x_t weights of √ᾱ_979·x̂0 + √(1−ᾱ_979)·ε̂.
        let (ab_t, ab_prev) = (s.alpha_bars()[999], s.alpha_bars()[979]);
        let c = ddim.coefficients(0).unwrap();
        let xt = ((1.0 - ab_prev) / (1.0 - ab_t)).sqrt();
        assert!((c.xt - xt).abs() < 1e-12);
        assert!((c.x0 - (ab_prev.sqrt() - xt * ab_t.sqrt())).abs() < 1e-12);
        assert_eq!(ddim.q_prev(0).unwrap(), s.q(979).unwrap());
        assert_eq!(ddim.q_prev(49).unwrap(), QCoefficients { signal: 1.0, noise: 0.0 });
    }

    #[test]
    fn bad_arguments_are_errors() {
        use ScheduleError::*;
        let s = NoiseSchedule::default();
        assert_eq!(Ddim::new(&s, 0, 0.0), Err(ZeroSteps));
        assert_eq!(Ddim::new(&s, 1001, 0.0), Err(TooManySteps { steps: 1001, timesteps: 1000 }));
        assert_eq!(Ddim::new(&s, 50, -0.1), Err(InvalidEta(-0.1)));
        assert_eq!(Ddim::new(&s, 50, 1.5), Err(InvalidEta(1.5)));
        assert!(matches!(Ddim::new(&s, 50, f64::NAN), Err(InvalidEta(_))));
        assert_eq!(Ddim::with_timesteps(&s, vec![], 0.0), Err(ZeroSteps));
        assert_eq!(Ddim::with_timesteps(&s, vec![10, 20, 0], 0.0), Err(NotDescending { index: 1 }));
        assert_eq!(Ddim::with_timesteps(&s, vec![1000, 0], 0.0), Err(TimestepOutOfRange { t: 1000, timesteps: 1000 }));
        let ddim = Ddim::with_timesteps(&s, vec![500, 20], 0.5).unwrap();
        assert_eq!(ddim.coefficients(2), Err(StepOutOfRange { i: 2, steps: 2 }));
        let mut out = [0.0_f32; 2];
        assert_eq!(ddim.step(0, &[0.0; 2], &[0.0; 2], None, &mut out), Err(MissingNoise));
        assert!(matches!(ddim.step(0, &[0.0; 2], &[0.0; 3], None, &mut out), Err(LengthMismatch { expected: 2, got: 3 })));
    }
}
