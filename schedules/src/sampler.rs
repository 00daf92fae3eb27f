//! The common sampler interface: one reverse step x_t → x_prev from the model's x̂0.

use crate::{check_len, QCoefficients, Real, ScheduleError};

/// One reverse step as three scalars: x_prev = x0·x̂0 + xt·x_t + noise·z.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepCoefficients {
    /// a, the weight on the model's x̂0.
    pub x0: f64,
    /// b, the weight on the current sample x_t.
    pub xt: f64,
    /// σ, the standard deviation of the fresh noise z (0: deterministic step).
    pub noise: f64,
}

impl StepCoefficients {
    /// Whether this step draws noise (σ > 0).
    pub fn needs_noise(&self) -> bool {
        self.noise > 0.0
    }

    /// `out = x0·x0_pred + xt·x_t + noise·z`, elementwise.
    ///
    /// `noise` must be `Some` when [`needs_noise`](Self::needs_noise) (else `MissingNoise`) and
    /// is ignored otherwise; every slice given must have `out`'s length.
    pub fn apply<F: Real>(&self, x0_pred: &[F], x_t: &[F], noise: Option<&[F]>, out: &mut [F]) -> Result<(), ScheduleError> {
        check_len(out.len(), x0_pred.len())?;
        check_len(out.len(), x_t.len())?;
        if let Some(z) = noise {
            check_len(out.len(), z.len())?;
        }
        let z = match noise {
            _ if !self.needs_noise() => None,
            Some(z) => Some(z),
            None => return Err(ScheduleError::MissingNoise),
        };
        for (k, o) in out.iter_mut().enumerate() {
            let mut v = self.x0 * x0_pred[k].to_f64() + self.xt * x_t[k].to_f64();
            if let Some(z) = z {
                v += self.noise * z[k].to_f64();
            }
            *o = F::from_f64(v);
        }
        Ok(())
    }
}

/// A reverse-process sampler over a fixed list of timesteps; step i goes from
/// `timesteps()[i]` to `timesteps()[i + 1]`, and the last step to the clean sample.
///
/// ```text
/// for i in 0..timesteps().len():
///     x̂0 = model(x, timesteps()[i])
///     z  = N(0, I) if needs_noise(i)
///     step(i, x̂0, x, z, out); x = out
///     (noised conditioning: out[known] = q_prev(i).q_sample(x_obs, fresh z))
/// ```
pub trait Sampler {
    /// The sampler's per-step tables.
    fn table(&self) -> &StepTable;

    /// The timesteps visited, strictly descending (the model's t input at each step).
    fn timesteps(&self) -> &[usize] {
        &self.table().timesteps
    }

    /// The coefficients of step i. Errors: `StepOutOfRange` for i ≥ `timesteps().len()`.
    fn coefficients(&self, i: usize) -> Result<StepCoefficients, ScheduleError> {
        step_entry(&self.table().steps, i)
    }

    /// q(x_prev | x_0) for the sample step i returns: √ᾱ_prev and √(1 − ᾱ_prev), the identity
    /// (1, 0) after the last step. The paper's conditioning (Eq. 7.6) sets the known entries of
    /// that sample to `q_sample(x_obs, z)`, i.e. the known values noised to the level of x_prev.
    fn q_prev(&self, i: usize) -> Result<QCoefficients, ScheduleError> {
        step_entry(&self.table().q_prev, i)
    }

    /// Whether step i draws noise z.
    fn needs_noise(&self, i: usize) -> Result<bool, ScheduleError> {
        Ok(self.coefficients(i)?.needs_noise())
    }

    /// `out` = x_prev from the model's `x0_pred` at `x_t` (see [`StepCoefficients::apply`]).
    fn step(&self, i: usize, x0_pred: &[f32], x_t: &[f32], noise: Option<&[f32]>, out: &mut [f32]) -> Result<(), ScheduleError> {
        self.coefficients(i)?.apply(x0_pred, x_t, noise, out)
    }
}

/// What a sampler precomputes: per step i, its timestep, its coefficients and q(x_prev | x_0).
#[derive(Clone, Debug, PartialEq)]
pub struct StepTable {
    /// Timesteps visited, strictly descending.
    pub timesteps: Vec<usize>,
    /// Coefficients of each step.
    pub steps: Vec<StepCoefficients>,
    /// √ᾱ_prev and √(1 − ᾱ_prev) of each step.
    pub q_prev: Vec<QCoefficients>,
}

/// Element `i` of a sampler's per-step table, or `StepOutOfRange`.
pub(crate) fn step_entry<T: Copy>(table: &[T], i: usize) -> Result<T, ScheduleError> {
    table.get(i).copied().ok_or(ScheduleError::StepOutOfRange { i, steps: table.len() })
}
