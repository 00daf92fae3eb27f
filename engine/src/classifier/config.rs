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
