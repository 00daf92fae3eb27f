//! Forecasting and completion of scenes by inpainting (issue 4): scene ↔ canvas, masks,
//! per-sample seeds, decoding back to world positions, and the output dataset.
//!
//! ```text
//! scene ──encode (each person anchored at the anchor frame)──▶ features [T, P, δ]
//!       ──standardize──▶ known values, mask (Task)  ──inpaint, once per sample k with
//!       seed_k = sample_seed(seed, k)──▶ [T, P, δ] ──unstandardize, decode──▶ world positions
//! ```
//!
//! - Forecast: the canvas is `observe + horizon` frames; frames `< observe` are known for every
//!   person and dim; persons are anchored at frame `observe − 1` (their last observed pose).
//! - Completion: the canvas is the whole scene. `joints=…` leaves those joints unknown on every
//!   frame (and the root dims too when a body-frame joint is missing); `frames=a..b` leaves
//!   frames `a..b` unknown (anchor: frame `a − 1`, or `b` when `a = 0`); `persons=…` leaves those
//!   persons unknown on every frame (anchor: the last frame). Anchors (root and heading at the
//!   anchor frame) always come from the input: a completed person keeps its placement.
//! - Sample `k` draws its random numbers from an RNG seeded with [`sample_seed`]`(seed, k)`, and
//!   samples are batched into model calls that compute each one independently, so sample `k` is
//!   the same bit for bit whatever the number of samples.
//! - Positions of entries that were fully known (joint and root dims) are copied from the input,
//!   so observed frames equal the input bit for bit.
//!
//! Files, in the order of the data flow: [`request`] (what to sample: [`Forecast`], the one
//! options type of a request, and [`SamplerKind`]), [`task`] (which part is known: [`Task`],
//! checked once by [`check_task`]), [`canvas`] (scene ↔ canvas and [`sample_scene`]),
//! [`output`] (the samples and their [`Provenance`]), [`model`] (a trained [`Model`] that runs
//! the above), [`stream`] (a forecast per frame as frames arrive), [`interpolate`] (interpolation and in-betweening), [`args`] (the commands'
//! options).

mod args;
pub mod canvas;
pub mod interpolate;
pub mod model;
pub mod output;
pub mod request;
pub mod stream;
pub mod task;
#[cfg(test)]
mod tests;

pub use crate::sample::{sample_seed, ContextInversion, StepInfo};
pub use args::{
    CleanKnown, CompleteArgs, ForecastArgs, GenerateArgs, GuideArgs, InterpolateArgs, JointMapMode, SampleArgs, SampledOutput, SamplerFamily, StreamFormat,
};
pub use canvas::{sample_scene, task_mask, Canvas, Denoising};
pub use interpolate::{slerp, transition_scene, Interpolate, Interpolation};
pub use model::{GuideProvenance, Model};
pub use output::{ForecastOutput, MaskSummary, Provenance, Timings};
pub use request::{Forecast, SamplerKind};
pub use stream::Stream;
pub use task::{canvas_frames, check_task, Missing, Task};
