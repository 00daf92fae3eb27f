//! What a request samples: [`Forecast`] and the sampler ([`SamplerKind`]).

use crate::sample::{Conditioning, ContextInversion};
use crate::{bail, Error, Result};
use serde::Serialize;
use socdiff_schedules::{Ddim, Ddpm, NoiseSchedule, Sampler};

#[cfg(doc)]
use super::{sample_scene, Model};

/// Which sampler runs the reverse process. JSON form: `{"kind": "ddpm"}`,
/// `{"kind": "ddim", "steps": 20, "eta": 0.0}`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum SamplerKind {
    /// Ancestral DDPM over all T steps.
    Ddpm,
    /// DDIM over `steps` respaced steps with stochasticity `eta`.
    Ddim {
        /// Number of steps K.
        steps: usize,
        /// η (0 = deterministic).
        eta: f64,
    },
}

impl SamplerKind {
    /// Parses `ddpm` or `ddimN` (DDIM over N steps, η = 0), as [`SamplerKind::name`] writes them.
    pub fn parse(s: &str) -> Result<Self> {
        let bad = || Error::invalid(format!("sampler {s:?}: expected ddpm or ddimN (e.g. ddim20)"));
        if s == "ddpm" {
            return Ok(SamplerKind::Ddpm);
        }
        match s.strip_prefix("ddim").and_then(|n| n.parse::<usize>().ok()) {
            Some(steps) if steps > 0 => Ok(SamplerKind::Ddim { steps, eta: 0.0 }),
            _ => Err(bad()),
        }
    }

    /// `ddpm`, `ddimN`, or `ddimN-etaE` when η ≠ 0.
    pub fn name(&self) -> String {
        match *self {
            SamplerKind::Ddpm => "ddpm".into(),
            SamplerKind::Ddim { steps, eta: 0.0 } => format!("ddim{steps}"),
            SamplerKind::Ddim { steps, eta } => format!("ddim{steps}-eta{eta}"),
        }
    }

    /// Denoising steps per sample over a schedule of `timesteps` levels (all of them for DDPM).
    pub fn steps(&self, timesteps: usize) -> usize {
        match *self {
            SamplerKind::Ddpm => timesteps,
            SamplerKind::Ddim { steps, .. } => steps,
        }
    }

    /// The sampler over `schedule`.
    pub fn build(&self, schedule: &NoiseSchedule) -> Result<Box<dyn Sampler>> {
        Ok(match *self {
            SamplerKind::Ddpm => Box::new(Ddpm::new(schedule)),
            SamplerKind::Ddim { steps, eta } => {
                if steps == 0 {
                    bail!("ddim needs at least 1 step");
                }
                if !(eta.is_finite() && eta >= 0.0) {
                    bail!("ddim eta must be finite and ≥ 0, got {eta}");
                }
                Box::new(Ddim::new(schedule, steps, eta)?)
            }
        })
    }
}

/// What [`Model::forecast`] samples — frames observed and forecast, samples, sampler, seed —
/// the one options type of a request, from the command line or a library call down to
/// [`sample_scene`]. Its frames are read by [`Model::forecast`]; completion and generation
/// take theirs from their [`crate::forecast::Task`].
#[derive(Clone, Debug, PartialEq)]
pub struct Forecast {
    /// Frames observed from the start of the scene.
    pub observe: usize,
    /// Frames forecast after them.
    pub horizon: usize,
    /// Samples K.
    pub samples: usize,
    /// Sampler (default DDIM, 50 steps, η = 0).
    pub sampler: SamplerKind,
    /// How known entries are imposed.
    pub conditioning: Conditioning,
    /// Base seed.
    pub seed: u64,
    /// Context inversion of the observed frames; off by default.
    pub inversion: Option<ContextInversion>,
    /// Known frames at noise level 0: `None` as the model was trained.
    pub clean_known: Option<bool>,
    /// Map the scene's joints onto the model's by name when their layouts differ (else an
    /// error naming the first joint that differs).
    pub map_joints: bool,
}

impl Default for Forecast {
    fn default() -> Self {
        Self {
            observe: 30,
            horizon: 90,
            samples: 1,
            sampler: SamplerKind::Ddim { steps: 50, eta: 0.0 },
            conditioning: Conditioning::Replace,
            seed: 0,
            inversion: None,
            clean_known: None,
            map_joints: false,
        }
    }
}
