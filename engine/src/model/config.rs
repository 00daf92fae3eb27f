//! Denoiser configuration (METHOD.md §3): every number of the network is a field here, saved
//! with the checkpoint.

use crate::{bail, Result};
use serde::{Deserialize, Serialize};

/// How persons share information at the U-Net bottleneck (Γ in the paper, METHOD.md §3).
///
/// Every variant is invariant to the order of the persons and works for any number of
/// persons P ≥ 1. JSON form: `{"kind": "none"}`, `{"kind": "mean"}`,
/// `{"kind": "attention", "heads": 4}`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Aggregator {
    /// Γ∅: nothing is shared; every person is denoised on its own (ablation baseline).
    None,
    /// Γ_E: each receiver gets the mean over all persons of a message computed from the
    /// sender's bottleneck encoding and the sender's anchor seen from the receiver.
    Mean,
    /// Γ_attn: multi-head self-attention across persons at each bottleneck frame, with keys
    /// and values that also see the sender's anchor relative to the receiver's.
    Attention {
        /// Number of attention heads; must divide [`DenoiserConfig::social_dim`].
        heads: usize,
    },
}

/// Configuration of [`Denoiser`](super::Denoiser): the causal temporal-conv U-Net g(x_t, t) → x̂0
/// with a social aggregator at its bottleneck.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DenoiserConfig {
    /// δ: feature dims per person and frame, `4 + 3J` (root x, y, cos h, sin h, then the local
    /// joints); 61 for the 19-joint Panoptic skeleton.
    pub feature_dims: usize,
    /// H: width of the first U-Net level; the three lower levels have width 2H.
    pub hidden: usize,
    /// Width of the timestep embedding (output of the time MLP), fed to every FiLM layer.
    pub time_dim: usize,
    /// Width of the sinusoidal timestep features (even; half sines, half cosines).
    pub fourier_dim: usize,
    /// Largest period of the sinusoidal timestep features (10 000 as in Transformers).
    pub fourier_max_period: f64,
    /// How persons share information at the bottleneck.
    pub aggregator: Aggregator,
    /// Width of the social message each person receives from the aggregator (and of the
    /// attention queries, keys and values); ignored by [`Aggregator::None`].
    pub social_dim: usize,
    /// ε of every LayerNorm.
    pub ln_eps: f64,
    /// What the U-Net's output F means (absent in older checkpoints: `x0`).
    #[serde(default)]
    pub output: DenoiserOutput,
}

/// How the network's estimate x̂0 is formed from the U-Net's output F.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DenoiserOutput {
    /// x̂0 = F(x_t, t), METHOD.md §3 as written.
    #[default]
    X0,
    /// x̂0 = √ᾱ_t·x_t + √(1 − ᾱ_t)·F(x_t, t): the input passes through at low noise, so the
    /// network only learns the correction (EDM's skip preconditioning with σ_data = 1, the
    /// standardized scale; the x0 loss is unchanged). A plain x0 network must learn the identity
    /// at small t through its residual branches, which LayerNorm and FiLM make slow; with the
    /// skip it must instead predict the noise at mid t, which the same branches find as hard
    /// (measured on MuPoTS, hidden 64, 1 000 steps: L1 at t = 1 0.008 instead of 0.115, at
    /// t = 300 0.26 instead of 0.12).
    SkipX0,
    /// x̂0 = c·x_t/√ᾱ_t + (1 − c)·F(x_t, t) with c = σ_d²/(σ_t² + σ_d²), σ_t² = (1 − ᾱ_t)/ᾱ_t:
    /// the inverse-variance blend of the input's own estimate x_t/√ᾱ_t (error σ_t) and the
    /// network's (error about σ_d, in standardized units). F is a plain x0 estimate wherever
    /// σ_t ≫ σ_d (t ≳ 150 for σ_d = 0.1), and the input passes through where σ_t ≪ σ_d, so
    /// poses the network has never seen survive the last denoising steps.
    Blend {
        /// σ_d, the network's own error scale in standardized units.
        sigma_data: f64,
    },
}

impl DenoiserOutput {
    /// `(a, b)` of x̂0 = a·x_t + b·F at a step with cumulative signal ᾱ.
    pub fn weights(&self, alpha_bar: f64) -> (f64, f64) {
        match *self {
            Self::X0 => (0.0, 1.0),
            Self::SkipX0 => (alpha_bar.sqrt(), (1.0 - alpha_bar).sqrt()),
            Self::Blend { sigma_data } => {
                let (sd2, st2) = (sigma_data * sigma_data, (1.0 - alpha_bar) / alpha_bar);
                let c = sd2 / (st2 + sd2);
                (c / alpha_bar.sqrt(), 1.0 - c)
            }
        }
    }

    /// Checks the parameters.
    pub fn validate(&self) -> Result<()> {
        if let Self::Blend { sigma_data } = *self {
            if !(sigma_data > 0.0 && sigma_data.is_finite()) {
                bail!("denoiser config: output blend needs sigma_data > 0, got {sigma_data}");
            }
        }
        Ok(())
    }
}

impl Default for DenoiserConfig {
    fn default() -> Self {
        Self {
            feature_dims: 4 + 3 * 19,
            hidden: 192,
            time_dim: 256,
            fourier_dim: 64,
            fourier_max_period: 10_000.0,
            aggregator: Aggregator::Mean,
            social_dim: 192,
            ln_eps: 1e-5,
            output: DenoiserOutput::X0,
        }
    }
}

impl DenoiserConfig {
    /// Checks that the numbers fit together; names the first field that does not.
    pub fn validate(&self) -> Result<()> {
        self.output.validate()?;
        if self.feature_dims == 0 {
            bail!("denoiser config: feature_dims must be positive");
        }
        if self.hidden == 0 || self.time_dim == 0 {
            bail!("denoiser config: hidden and time_dim must be positive");
        }
        if self.fourier_dim < 4 || !self.fourier_dim.is_multiple_of(2) {
            bail!("denoiser config: fourier_dim must be even and at least 4, got {}", self.fourier_dim);
        }
        if self.fourier_max_period.is_nan() || self.fourier_max_period <= 1.0 {
            bail!("denoiser config: fourier_max_period must be > 1, got {}", self.fourier_max_period);
        }
        if self.ln_eps.is_nan() || self.ln_eps <= 0.0 {
            bail!("denoiser config: ln_eps must be positive, got {}", self.ln_eps);
        }
        match self.aggregator {
            Aggregator::None => {}
            Aggregator::Mean => {
                if self.social_dim == 0 {
                    bail!("denoiser config: social_dim must be positive");
                }
            }
            Aggregator::Attention { heads } => {
                if heads == 0 || self.social_dim == 0 || !self.social_dim.is_multiple_of(heads) {
                    bail!(
                        "denoiser config: social_dim ({}) must be a positive multiple of the attention heads ({heads})",
                        self.social_dim
                    );
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_json_round_trip_and_validation() {
        let cfg = DenoiserConfig { aggregator: Aggregator::Attention { heads: 4 }, ..Default::default() };
        let s = serde_json::to_string(&cfg).unwrap();
        assert!(s.contains(r#""aggregator":{"kind":"attention","heads":4}"#), "{s}");
        let back: DenoiserConfig = serde_json::from_str(&s).unwrap();
        assert_eq!(back, cfg);
        let partial: DenoiserConfig = serde_json::from_str(r#"{"hidden": 64, "aggregator": {"kind": "none"}}"#).unwrap();
        assert_eq!(partial.hidden, 64);
        assert_eq!(partial.aggregator, Aggregator::None);
        assert_eq!(partial.time_dim, 256);
        assert!(DenoiserConfig::default().validate().is_ok());
        let bad = DenoiserConfig { aggregator: Aggregator::Attention { heads: 5 }, ..Default::default() };
        assert!(bad.validate().is_err());
        assert!(DenoiserConfig { fourier_dim: 7, ..Default::default() }.validate().is_err());
    }

    /// The x̂0 = a·x_t + b·F weights of each output kind, on known values; old configs (no
    /// `output` field) read as `x0`; the blend's σ_d must be positive.
    #[test]
    fn output_weights_and_serialization() {
        let ab = 0.64;
        assert_eq!(DenoiserOutput::X0.weights(ab), (0.0, 1.0));
        let (a, b) = DenoiserOutput::SkipX0.weights(ab);
        assert!((a - 0.8).abs() < 1e-12 && (b - 0.6).abs() < 1e-12);
        // σ_t = σ_d where ᾱ = 1/(1 + σ_d²): c = ½.
        let blend = DenoiserOutput::Blend { sigma_data: 0.1 };
        let ab = 1.0 / 1.01;
        let (a, b) = blend.weights(ab);
        assert!((a - 0.5 / ab.sqrt()).abs() < 1e-12 && (b - 0.5).abs() < 1e-12);
        // Clean input: x̂0 = x_t; pure noise: x̂0 = F.
        assert_eq!(blend.weights(1.0), (1.0, 0.0));
        let (a, b) = blend.weights(1e-9);
        assert!(a < 1e-3 && (b - 1.0).abs() < 1e-6);
        let json = serde_json::to_string(&DenoiserConfig { output: blend, ..Default::default() }).unwrap();
        assert!(json.contains(r#""output":{"blend":{"sigma_data":0.1}}"#), "{json}");
        let mut old: serde_json::Value = serde_json::from_str(&json).unwrap();
        old.as_object_mut().unwrap().remove("output");
        assert_eq!(serde_json::from_value::<DenoiserConfig>(old).unwrap().output, DenoiserOutput::X0);
        assert!(DenoiserConfig { output: DenoiserOutput::Blend { sigma_data: 0.0 }, ..Default::default() }.validate().is_err());
    }
}
