//! The denoising network of Social Diffusion (Tanke et al., "Social Diffusion: Long-term
//! Multiple Human Motion Anticipation", ICCV 2023), as specified in METHOD.md §3.
//!
//! - [`config`]: [`DenoiserConfig`] and the [`Aggregator`] choice (Γ∅, Γ_E, Γ_attn);
//! - [`unet`]: [`Denoiser`], the per-person causal temporal-conv U-Net g(x_t, t) → x̂0;
//! - [`aggregator`]: how persons share their bottleneck encodings, with relative anchors;
//! - [`infer`]: [`InferenceNet`], the forward-only f32 network for sampling (plain weights,
//!   reused buffers, fused elementwise work), built from a trained [`Denoiser`];
//! - [`runtime`]: process settings for CPU work (worker threads, allocator, candle's pools);
//! - [`dispatch`]: [`Kernels`], which implementation of the ops a network runs;
//! - [`ops`]: the CPU custom ops with hand-written backward passes (causal conv via `gemm`,
//!   LayerNorm, SiLU, causal ×2 upsampling, small batched matmul), because candle 0.11.1's
//!   own conv, LayerNorm and softmax have wrong or missing gradients
//!   (`shared/docs/CANDLE_NOTES.md`); the same ops composed from candle built-ins run on every
//!   other device (CUDA).
//!
//! Layout is channels last everywhere: `[batch·persons, frames, channels]`. Parameters are
//! initialized from a seeded [`rand::rngs::StdRng`], so a seed gives the same network on every
//! run; [`Denoiser::named_vars`] lists them sorted by state-dict-like names.

pub mod aggregator;
mod composed;
pub mod config;
pub mod dispatch;
pub mod infer;
pub(crate) mod kernels;
pub(crate) mod layers;
pub mod ops;
pub mod profile;
pub mod runtime;
pub mod unet;

pub use aggregator::relative_anchors;
pub use config::{Aggregator, Causality, DenoiserConfig, DeviceArg, DeviceChoice, Placement, LOOKAHEAD_FRAMES};
pub use dispatch::Kernels;
pub use infer::InferenceNet;
pub use layers::Parameterized;
pub use ops::{K3Conv, Precision};
pub use unet::{Denoiser, Trace, TIME_FACTOR};

impl From<candle_core::Error> for crate::Error {
    fn from(e: candle_core::Error) -> Self {
        crate::Error::Invalid(format!("tensor op: {e}"))
    }
}
