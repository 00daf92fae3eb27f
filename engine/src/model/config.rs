//! Denoiser configuration (METHOD.md §3): every number of the network is a field here, saved
//! with the checkpoint.

use super::dispatch::Kernels;
use super::ops::{K3Conv, Precision};
use crate::{bail, Result};
use candle_core::{DType, Device};
use serde::{Deserialize, Serialize};

/// The device a command runs on, as users name it: `cpu`, `cuda` (= `cuda:0`), `cuda:N`, or
/// `auto` (the first GPU when this binary has CUDA and one is present, else the CPU).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DeviceChoice {
    /// The CPU (the default).
    #[default]
    Cpu,
    /// CUDA GPU number N.
    Cuda(usize),
    /// A GPU when there is one.
    Auto,
}

/// `--device` of the commands that run the network.
#[derive(Clone, Copy, Debug, Default)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct DeviceArg {
    /// Where the network runs: cpu, cuda (= cuda:0), cuda:N, or auto (the GPU when this binary
    /// was built with CUDA and one is present, else the CPU).
    #[cfg_attr(feature = "clap", arg(long, default_value = "cpu"))]
    pub device: DeviceChoice,
}

impl std::str::FromStr for DeviceChoice {
    type Err = crate::Error;

    fn from_str(s: &str) -> Result<Self> {
        match s {
            "cpu" => Ok(Self::Cpu),
            "cuda" => Ok(Self::Cuda(0)),
            "auto" => Ok(Self::Auto),
            _ => match s.strip_prefix("cuda:").map(str::parse::<usize>) {
                Some(Ok(n)) => Ok(Self::Cuda(n)),
                _ => bail!("device `{s}` is not one of cpu, cuda, cuda:N, auto"),
            },
        }
    }
}

impl std::fmt::Display for DeviceChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Cpu => write!(f, "cpu"),
            Self::Cuda(n) => write!(f, "cuda:{n}"),
            Self::Auto => write!(f, "auto"),
        }
    }
}

impl DeviceChoice {
    /// Whether this binary was built with CUDA (the `cuda` cargo feature).
    pub const CUDA_BUILT: bool = cfg!(feature = "cuda");

    /// The candle device: an error naming the problem when a GPU is asked for and this
    /// binary has no CUDA, or the GPU cannot be opened.
    pub fn resolve(self) -> Result<Device> {
        match self {
            Self::Cpu => Ok(Device::Cpu),
            Self::Cuda(n) => {
                if !Self::CUDA_BUILT {
                    bail!("device cuda:{n}: this socdiff was built without CUDA (build it with scripts/build-cuda.sh, see docs/gpu.md)");
                }
                // The first line: candle appends a backtrace when RUST_BACKTRACE is set.
                Device::new_cuda(n)
                    .map_err(|e| crate::Error::invalid(format!("device cuda:{n} cannot be opened: {}", e.to_string().lines().next().unwrap_or(""))))
            }
            Self::Auto => {
                Ok(if Self::CUDA_BUILT && candle_core::utils::cuda_is_available() { Device::new_cuda(0).unwrap_or(Device::Cpu) } else { Device::Cpu })
            }
        }
    }

    /// The [`Placement`] of a network on this device at `precision` (f32 master weights).
    pub fn placement(self, precision: Precision) -> Result<Placement> {
        let device = self.resolve()?;
        if device.is_cpu() && precision == Precision::Bf16 {
            bail!("bf16 products are for GPUs: on the CPU they run through slow generic kernels (use f32)");
        }
        Ok(Placement::on(device, precision))
    }
}

/// Where a network's parameters live, their dtype, and which [`Kernels`] it runs.
#[derive(Clone, Debug)]
pub struct Placement {
    /// The candle device of parameters and activations.
    pub device: Device,
    /// Parameter (master) dtype: f32, or f64 for gradient checks.
    pub dtype: DType,
    /// The ops' implementation ([`Kernels::Custom`] on the CPU only).
    pub kernels: Kernels,
}

impl Placement {
    /// f32 on the CPU with the custom kernels (the default everywhere).
    pub fn cpu() -> Self {
        Self { device: Device::Cpu, dtype: DType::F32, kernels: Kernels::CUSTOM }
    }

    /// f32 master weights on `device` with the kernels that suit it: the custom ones on the
    /// CPU in f32, composed ones at `precision` otherwise.
    pub fn on(device: Device, precision: Precision) -> Self {
        let kernels = if device.is_cpu() && precision == Precision::F32 { Kernels::CUSTOM } else { Kernels::Composed(precision) };
        Self { device, dtype: DType::F32, kernels }
    }

    /// These settings with parameters of `dtype`.
    pub fn with_dtype(self, dtype: DType) -> Self {
        Self { dtype, ..self }
    }

    /// These settings with `k3` for the custom kernels' stride-1 k3 convs (composed kernels
    /// have one algorithm, candle's, and are kept).
    pub fn with_k3_conv(self, k3: K3Conv) -> Self {
        match self.kernels {
            Kernels::Custom(_) => Self { kernels: Kernels::Custom(k3), ..self },
            Kernels::Composed(_) => self,
        }
    }

    /// The precision of the convolutions' products.
    pub fn precision(&self) -> Precision {
        match self.kernels {
            Kernels::Custom(_) => Precision::F32,
            Kernels::Composed(p) => p,
        }
    }

    /// A short description for logs and provenance: `cpu f32 custom`, `cuda:0 bf16 composed`.
    pub fn describe(&self) -> String {
        let device = match &self.device {
            Device::Cpu => "cpu".to_string(),
            Device::Cuda(_) => match self.device.location() {
                candle_core::DeviceLocation::Cuda { gpu_id } => format!("cuda:{gpu_id}"),
                other => format!("{other:?}"),
            },
            other => format!("{:?}", other.location()),
        };
        let precision = match self.precision() {
            Precision::F32 => format!("{:?}", self.dtype).to_lowercase(),
            Precision::Bf16 => "bf16".to_string(),
        };
        let kernels = match self.kernels {
            Kernels::Custom(K3Conv::Winograd) => "custom",
            Kernels::Custom(K3Conv::Direct) => "custom, direct k3 convs",
            Kernels::Composed(_) => "composed",
        };
        format!("{device} {precision} {kernels}")
    }
}

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

impl Aggregator {
    /// Attention heads when none are given (as the reference).
    pub const DEFAULT_HEADS: usize = 4;

    /// `none`, `mean` or `attention` (the JSON `kind`).
    pub fn name(&self) -> &'static str {
        match self {
            Aggregator::None => "none",
            Aggregator::Mean => "mean",
            Aggregator::Attention { .. } => "attention",
        }
    }

    /// The same kind with `heads` attention heads (an error for the kinds without heads).
    pub fn with_heads(self, heads: usize) -> crate::Result<Self> {
        match self {
            Aggregator::Attention { .. } => Ok(Aggregator::Attention { heads }),
            other => crate::bail!("`heads` {heads}: the {} aggregator has no attention heads", other.name()),
        }
    }
}

/// Parsed from its name; attention gets [`Aggregator::DEFAULT_HEADS`].
#[cfg(feature = "clap")]
impl clap::ValueEnum for Aggregator {
    fn value_variants<'a>() -> &'a [Self] {
        &[Aggregator::None, Aggregator::Mean, Aggregator::Attention { heads: Aggregator::DEFAULT_HEADS }]
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        Some(clap::builder::PossibleValue::new(self.name()))
    }
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
    /// Which input frames an output frame may see: only earlier ones (causal, the paper) or
    /// also [`LOOKAHEAD_FRAMES`] later ones (lookahead).
    pub causality: Causality,
}

/// Widest network level, social message, time embedding or Fourier feature set a config may ask
/// for (hidden 1024 is about 250 million parameters, 4 GB with the optimizer's state).
pub const MAX_WIDTH: usize = 1024;
/// Most feature dims per person (4 + 3 · 1,000 joints).
pub const MAX_FEATURE_DIMS: usize = 3004;
/// Most attention heads.
pub const MAX_HEADS: usize = 64;

/// How far ahead a [`Causality::Lookahead`] network sees: each residual block's first conv is
/// centred, one sample ahead at its level (levels 0, 1, 2, 3 have 2, 2, 2, 2 such blocks on the
/// path from input to output: 2·(1 + 2 + 4 + 8) input frames).
pub const LOOKAHEAD_FRAMES: usize = 30;

/// Which input frames the denoiser's output frame t depends on.
///
/// The paper's network is causal, so a forecast's first frames never wait for later ones and
/// context inversion can work on the observed prefix alone. A denoiser that generates whole
/// scenes or fills gaps gains from seeing where the motion goes: with `lookahead`, x̂0 at frame
/// t is computed from the noisy frames up to t + [`LOOKAHEAD_FRAMES`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Causality {
    /// Output frame t depends on input frames ≤ t (the paper).
    #[default]
    Causal,
    /// Output frame t depends on input frames ≤ t + [`LOOKAHEAD_FRAMES`]: each residual block's
    /// first conv reads the samples before, at and after its output.
    Lookahead,
}

impl Causality {
    /// Input frames after an output frame that the output may depend on.
    pub fn frames_ahead(self) -> usize {
        match self {
            Causality::Causal => 0,
            Causality::Lookahead => LOOKAHEAD_FRAMES,
        }
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
            causality: Causality::Causal,
        }
    }
}

impl DenoiserConfig {
    /// Checks that the numbers fit together; names the first field that does not.
    pub fn validate(&self) -> Result<()> {
        if self.feature_dims == 0 {
            bail!("denoiser config: feature_dims must be positive");
        }
        // Sizes are bounded before anything is built: a checkpoint's header or a command line
        // may ask for any width.
        for (name, v, max) in [
            ("feature_dims", self.feature_dims, MAX_FEATURE_DIMS),
            ("hidden", self.hidden, MAX_WIDTH),
            ("social_dim", self.social_dim, MAX_WIDTH),
            ("time_dim", self.time_dim, MAX_WIDTH),
            ("fourier_dim", self.fourier_dim, MAX_WIDTH),
        ] {
            if v > max {
                bail!("denoiser config: {name} {v} is more than the {max} allowed");
            }
        }
        if let Aggregator::Attention { heads } = self.aggregator {
            if heads > MAX_HEADS {
                bail!("denoiser config: {heads} attention heads is more than the {MAX_HEADS} allowed");
            }
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
                    bail!("denoiser config: social_dim ({}) must be a positive multiple of the attention heads ({heads})", self.social_dim);
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
        assert_eq!(partial.causality, Causality::Causal, "checkpoints from before the option are the paper's causal network");
        let ahead = serde_json::to_string(&DenoiserConfig { causality: Causality::Lookahead, ..Default::default() }).unwrap();
        assert!(ahead.contains(r#""causality":"lookahead""#), "{ahead}");
        assert!(DenoiserConfig::default().validate().is_ok());
        let bad = DenoiserConfig { aggregator: Aggregator::Attention { heads: 5 }, ..Default::default() };
        assert!(bad.validate().is_err());
        assert!(DenoiserConfig { fourier_dim: 7, ..Default::default() }.validate().is_err());
    }
}
