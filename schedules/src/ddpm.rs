//! Ancestral DDPM sampling, as the reference (`p_sample_loop_with_input`, REFERENCE.md §3.4).

use crate::sampler::StepTable;
use crate::{NoiseSchedule, QCoefficients, Sampler, ScheduleError};

/// Ancestral sampling, t = k−1..0: x_{t−1} = c1·x̂0 + c2·x_t + σ_t·z with σ_t = exp(½·log σ̃²_t)
/// and z = 0 at t = 0 (see [`NoiseSchedule::posterior`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Ddpm {
    table: StepTable,
}

impl Ddpm {
    /// All T steps of `schedule`, t = T−1..0.
    pub fn new(schedule: &NoiseSchedule) -> Self {
        Self::build(schedule, schedule.timesteps())
    }

    /// Only the last `steps` = k steps, t = k−1..0, started from pure noise as if it were x_{k−1}:
    /// the reference's `n_diffusion_steps = k`. Errors: `ZeroSteps`, `TooManySteps` (k > T).
    pub fn truncated(schedule: &NoiseSchedule, steps: usize) -> Result<Self, ScheduleError> {
        match steps {
            0 => Err(ScheduleError::ZeroSteps),
            k if k > schedule.timesteps() => Err(ScheduleError::TooManySteps { steps: k, timesteps: schedule.timesteps() }),
            k => Ok(Self::build(schedule, k)),
        }
    }

    /// The sampler for t = k−1..0, k ≤ T.
    fn build(schedule: &NoiseSchedule, k: usize) -> Self {
        let timesteps: Vec<usize> = (0..k).rev().collect();
        let posterior = |t| schedule.posterior(t).expect("t < k ≤ T");
        Self {
            table: StepTable {
                steps: timesteps.iter().map(|&t| posterior(t)).collect(),
                q_prev: timesteps.iter().map(|&t| QCoefficients::from_alpha_bar(schedule.alpha_bars_prev()[t])).collect(),
                timesteps,
            },
        }
    }
}

impl Sampler for Ddpm {
    fn table(&self) -> &StepTable {
        &self.table
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn visits_every_step_with_the_posterior() {
        let s = NoiseSchedule::default();
        let ddpm = Ddpm::new(&s);
        assert_eq!(ddpm.timesteps().len(), 1000);
        assert_eq!((ddpm.timesteps()[0], ddpm.timesteps()[999]), (999, 0));
        let c = ddpm.coefficients(499).unwrap(); // t = 500
        assert_eq!((c.x0, c.xt), (s.posterior_mean_coef1()[500], s.posterior_mean_coef2()[500]));
        assert!((c.noise - s.posterior_variance()[500].sqrt()).abs() < 1e-15);
        assert!(ddpm.needs_noise(998).unwrap());
        assert!(!ddpm.needs_noise(999).unwrap()); // t = 0
        assert_eq!(ddpm.coefficients(1000), Err(ScheduleError::StepOutOfRange { i: 1000, steps: 1000 }));
    }

    #[test]
    fn q_prev_is_the_level_of_the_next_sample() {
        let s = NoiseSchedule::default();
        let ddpm = Ddpm::new(&s);
        assert_eq!(ddpm.q_prev(0).unwrap(), s.q(998).unwrap()); // t = 999 lands on 998
        assert_eq!(ddpm.q_prev(999).unwrap(), QCoefficients { signal: 1.0, noise: 0.0 });
        assert!(ddpm.q_prev(1000).is_err());
    }

    #[test]
    fn truncated_runs_the_last_k_steps() {
        let s = NoiseSchedule::default();
        let ddpm = Ddpm::truncated(&s, 3).unwrap();
        assert_eq!(ddpm.timesteps(), &[2, 1, 0]);
        assert_eq!(ddpm.coefficients(0).unwrap(), s.posterior(2).unwrap());
        assert_eq!(Ddpm::truncated(&s, 1000).unwrap(), Ddpm::new(&s));
        assert_eq!(Ddpm::truncated(&s, 0), Err(ScheduleError::ZeroSteps));
        assert_eq!(Ddpm::truncated(&s, 1001), Err(ScheduleError::TooManySteps { steps: 1001, timesteps: 1000 }));
    }

    #[test]
    fn step_checks_its_arguments() {
        let ddpm = Ddpm::new(&NoiseSchedule::default());
        let mut out = [0.0_f32; 2];
        let x = [1.0_f32, 2.0];
        assert_eq!(ddpm.step(0, &x, &x, None, &mut out), Err(ScheduleError::MissingNoise));
        assert!(matches!(ddpm.step(0, &x, &x, Some(&[0.0; 3]), &mut out), Err(ScheduleError::LengthMismatch { expected: 2, got: 3 })));
        // The last step is deterministic: noise may be left out, and is ignored if given.
        ddpm.step(999, &x, &[5.0, 5.0], None, &mut out).unwrap();
        let mut with_noise = [0.0_f32; 2];
        ddpm.step(999, &x, &[5.0, 5.0], Some(&[9.0, 9.0]), &mut with_noise).unwrap();
        assert_eq!(out, with_noise);
        assert!((out[0] - 1.0).abs() < 1e-6 && (out[1] - 2.0).abs() < 1e-6);
    }
}
