//! The one error type of this crate.

use std::fmt;

/// A bad argument to a schedule or sampler.
#[derive(Clone, Debug, PartialEq)]
pub enum ScheduleError {
    /// A schedule or sampler with zero steps (T = 0, K = 0 or an empty timestep list).
    ZeroSteps,
    /// More sampling steps K than diffusion steps T.
    TooManySteps {
        /// Requested K.
        steps: usize,
        /// The schedule's T.
        timesteps: usize,
    },
    /// DDIM η outside [0, 1] (or not finite); η > 1 makes 1 − ᾱ_prev − σ² negative.
    InvalidEta(f64),
    /// An SNR shift that is not finite and > 0.
    InvalidShift(f64),
    /// A β outside (0, 1) or not finite (e.g. a linear schedule scaled for a tiny T).
    InvalidBeta {
        /// Its timestep.
        t: usize,
        /// Its value.
        beta: f64,
    },
    /// A timestep t ≥ T.
    TimestepOutOfRange {
        /// The timestep asked for.
        t: usize,
        /// The schedule's T.
        timesteps: usize,
    },
    /// A timestep list that is not strictly descending.
    NotDescending {
        /// Position of the first entry not below its predecessor.
        index: usize,
    },
    /// A step index i ≥ the sampler's number of steps.
    StepOutOfRange {
        /// The step index asked for.
        i: usize,
        /// The sampler's number of steps.
        steps: usize,
    },
    /// Slices of different lengths.
    LengthMismatch {
        /// The length of the output (or of the first slice).
        expected: usize,
        /// The length found.
        got: usize,
    },
    /// A stochastic step (σ > 0) called without noise z.
    MissingNoise,
}

impl fmt::Display for ScheduleError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::ZeroSteps => write!(f, "a schedule or sampler needs at least one step"),
            Self::TooManySteps { steps, timesteps } => {
                write!(f, "{steps} sampling steps exceed the {timesteps} diffusion steps")
            }
            Self::InvalidEta(eta) => write!(f, "DDIM eta must lie in [0, 1], got {eta}"),
            Self::InvalidShift(shift) => write!(f, "an SNR shift must be finite and > 0, got {shift}"),
            Self::InvalidBeta { t, beta } => write!(f, "beta_{t} = {beta} is outside (0, 1)"),
            Self::TimestepOutOfRange { t, timesteps } => {
                write!(f, "timestep {t} is out of range for {timesteps} diffusion steps")
            }
            Self::NotDescending { index } => {
                write!(f, "timesteps must be strictly descending (entry {index} is not)")
            }
            Self::StepOutOfRange { i, steps } => {
                write!(f, "step index {i} is out of range for a {steps}-step sampler")
            }
            Self::LengthMismatch { expected, got } => {
                write!(f, "slice length {got} does not match {expected}")
            }
            Self::MissingNoise => write!(f, "this step has sigma > 0 and needs noise z"),
        }
    }
}

impl std::error::Error for ScheduleError {}
