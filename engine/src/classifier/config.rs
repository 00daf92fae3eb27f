//! The configuration of a classifier run (saved in its checkpoint).

use super::net::NetConfig;
use crate::train::AdamConfig;
use crate::{bail, Result};
use serde::{Deserialize, Serialize};

/// Everything a classifier run needs, saved in its checkpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ClassifierConfig {
    /// Total optimizer steps (600).
    pub steps: usize,
    /// Windows per batch (16).
    pub batch: usize,
    /// Frames per training window, and per inference window (128).
    pub window: usize,
    /// Seed of initialization and window sampling (0).
    pub seed: u64,
    /// Checkpoint every this many steps (100; also at the end and on stop).
    pub save_every: usize,
    /// Weight of the buyer loss against the speaking loss (1).
    pub buyer_weight: f64,
    /// Scene signal with the speaking labels (`speaking`; speaks where > 0.5).
    pub speaking_signal: String,
    /// Adam (lr 3e-3: the network is small).
    pub adam: AdamConfig,
    /// Network widths.
    pub net: NetConfig,
}

impl Default for ClassifierConfig {
    fn default() -> Self {
        Self {
            steps: 600,
            batch: 16,
            window: 128,
            seed: 0,
            save_every: 100,
            buyer_weight: 1.0,
            speaking_signal: "speaking".into(),
            adam: AdamConfig { lr: 3e-3, ..Default::default() },
            net: NetConfig::default(),
        }
    }
}

impl ClassifierConfig {
    /// The defaults of a fresh run in one line (`socdiff classifier train --help` shows it).
    pub fn describe_defaults() -> String {
        let d = Self::default();
        format!(
            "Defaults of a fresh run: {} steps, batch {}, window {}, hidden {}, lr {}, buyer weight {}, seed {}, a checkpoint every {} steps.",
            d.steps, d.batch, d.window, d.net.hidden, d.adam.lr, d.buyer_weight, d.seed, d.save_every
        )
    }

    /// Checks the values.
    pub fn validate(&self) -> Result<()> {
        if self.batch == 0 || self.window < 2 || self.save_every == 0 {
            bail!(
                "classifier config: batch and save_every must be at least 1 and window at least 2 (batch {}, window {}, save_every {})",
                self.batch,
                self.window,
                self.save_every
            );
        }
        if !(self.buyer_weight.is_finite() && self.buyer_weight >= 0.0) {
            bail!("classifier config: buyer_weight must be a non-negative number, got {}", self.buyer_weight);
        }
        if !(self.adam.lr.is_finite() && self.adam.lr > 0.0) {
            bail!("classifier config: the learning rate must be positive, got {}", self.adam.lr);
        }
        self.net.validate()
    }
}

/// Settings of a fresh classifier run, field by field (`None`: the default,
/// [`ClassifierConfig::describe_defaults`]).
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct ClassifierOverrides {
    #[cfg_attr(feature = "clap", command(flatten))]
    pub run: crate::train::overrides::RunOverrides,
    /// Weight of the buyer loss [default: 1].
    #[cfg_attr(feature = "clap", arg(long))]
    pub buyer_weight: Option<f64>,
}

impl ClassifierOverrides {
    /// The configuration: the defaults with these fields set. A resumed run keeps its
    /// checkpoint's configuration, so then only `steps` may be given.
    pub fn config(&self, resume: bool) -> Result<ClassifierConfig> {
        let (d, r) = (ClassifierConfig::default(), &self.run);
        let others = [r.batch, r.window, r.hidden, r.save_every].iter().any(Option::is_some);
        if resume && (others || r.lr.is_some() || self.buyer_weight.is_some() || r.seed.is_some()) {
            bail!("`resume` keeps the checkpoint's configuration: only `steps` may be given");
        }
        let h = r.hidden.unwrap_or(d.net.hidden);
        Ok(ClassifierConfig {
            steps: r.steps.unwrap_or(d.steps),
            batch: r.batch.unwrap_or(d.batch),
            window: r.window.unwrap_or(d.window),
            seed: r.seed.unwrap_or(d.seed),
            save_every: r.save_every.unwrap_or(d.save_every),
            buyer_weight: self.buyer_weight.unwrap_or(d.buyer_weight),
            adam: AdamConfig { lr: r.lr.unwrap_or(d.adam.lr), ..d.adam.clone() },
            net: NetConfig { embed: h, hidden: h, message: h, ..d.net.clone() },
            ..d
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::overrides::RunOverrides;
    use crate::train::LrSchedule;

    #[test]
    fn overrides_set_the_rate_and_a_resume_keeps_it() {
        let run = RunOverrides { lr: Some(1e-3), steps: Some(40), ..Default::default() };
        let o = ClassifierOverrides { run, buyer_weight: None };
        let c = o.config(false).unwrap();
        let d = ClassifierConfig::default();
        assert_eq!((c.steps, c.adam.lr, c.adam.schedule, c.adam.betas, c.batch), (40, 1e-3, LrSchedule::Constant, d.adam.betas, d.batch));
        assert_eq!(d.adam.schedule, LrSchedule::Constant);
        let e = o.config(true).unwrap_err().to_string();
        assert!(e.contains("only `steps` may be given"), "{e}");
        let steps_only = ClassifierOverrides { run: RunOverrides { steps: Some(40), ..Default::default() }, buyer_weight: None };
        assert_eq!(steps_only.config(true).unwrap().steps, 40);
    }
}
