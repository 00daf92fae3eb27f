//! Inpainting: sample the unknown entries of a canvas given the known ones (METHOD.md §4).
//!
//! One entry point, [`inpaint`], for every conditioning task: forecasting is a mask that is
//! true for all dims of all persons on the observed frames; completing missing joints, frames
//! or whole persons are other masks through the same code path.
//!
//! ```text
//! x ← N(0, I);  x[M] ← X_obs (replace only; with noised the known entries start as noise too)
//! for i in 0..K:                           (t_i = sampler.timesteps()[i], descending)
//!     x̂0 = g(x, t_i, anchors)
//!     x  = a_i·x̂0 + b_i·x + σ_i·z          (one reverse step of the sampler)
//!     x[M] ← X_obs                          (replace: the reference's choice)
//!          | √ᾱ_prev·X_obs + √(1−ᾱ_prev)·z' (noised: paper Eq. 7.6)
//! ```
//!
//! The canvas is in the model's space: standardized anchored features `[frames, persons, δ]`
//! (see [`crate::features`]). Samples are denoised together, as many per model call as
//! [`X0Model::max_batch`] allows. Sample s draws every random number (initial noise, step
//! noise, noised known values) from its own [`StdRng`] seeded by
//! [`sample_seed`]`(seed, s)`, and the model computes each scene of a batch independently, so a
//! seed reproduces sample s bit for bit on one machine, whatever the number of samples.

use crate::diffusion::{standard_normal, GaussianDiffusion, InputScaling, Prediction};
use crate::model::{Denoiser, InferenceNet, K3Conv};
use crate::{bail, Result};
use candle_core::{Device, Tensor};
use ndarray::{Array4, ArrayView2, ArrayView3};
use rand::rngs::StdRng;
use rand::SeedableRng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use socdiff_schedules::{NoiseSchedule, Sampler};
use std::ops::Range;
use std::time::Instant;

/// How known entries are imposed after each reverse step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Conditioning {
    /// Known entries are set to the clean known values (the reference's conditioning).
    #[default]
    Replace,
    /// Known entries are set to the known values noised to the level of the new sample,
    /// q(x_prev | X_obs) (paper Eq. 7.6).
    Noised,
}

/// Anything that predicts x̂0 from a noisy canvas: the [`InferenceNet`] (sampling), the
/// [`Denoiser`] (reference), or a stand-in in tests.
pub trait X0Model {
    /// δ, the feature dims per person and frame.
    fn feature_dims(&self) -> usize;

    /// The most scenes of `persons` × `frames` one [`X0Model::predict_x0`] call should take
    /// (a memory bound); at least 1.
    fn max_batch(&self, persons: usize, frames: usize) -> usize {
        let _ = (persons, frames);
        usize::MAX
    }

    /// Input frames after an output frame that the output may depend on (0: causal).
    fn frames_ahead(&self) -> usize {
        0
    }

    /// x̂0 = g(x_t, t, anchors).
    ///
    /// # Shapes
    /// - `x`: `[S, P, T, δ]` flattened (`shape` = `[S, P, T, δ]`)
    /// - `t`: S diffusion steps (one per scene), or S·P·T (one per person and frame, `[S, P, T]`;
    ///   for models trained with clean frames, see [`InpaintOptions::clean_known`])
    /// - `anchors`: `[S, P, 4]` flattened
    /// - `out`: `[S, P, T, δ]` flattened, overwritten
    fn predict_x0(&self, x: &[f32], shape: [usize; 4], t: &[usize], anchors: Option<&[f32]>, out: &mut [f32]) -> Result<()>;

    /// ∇ₓ Σ w·(g(x, t) − target)² for one scene (`shape[0] = 1`, `weight` of 0s and 1s, all
    /// three in the layout of `x`), for [`ContextInversion`]; `None` when the model cannot
    /// differentiate its input.
    fn input_gradient(&self, x: &[f32], shape: [usize; 4], t: usize, anchors: Option<&[f32]>, target: &[f32], weight: &[f32]) -> Result<Option<Vec<f32>>> {
        let _ = (x, shape, t, anchors, target, weight);
        Ok(None)
    }
}

/// The candle tensors of a [`X0Model`] call: x `[S, P, T, δ]` and anchors `[S, P, 4]` in the
/// network's dtype, t as u32.
fn candle_inputs(net: &Denoiser, x: &[f32], shape: [usize; 4], t: &[usize], anchors: Option<&[f32]>) -> Result<(Tensor, Tensor, Option<Tensor>)> {
    let device = net.device();
    let xt = Tensor::from_slice(x, shape.as_slice(), device)?.to_dtype(net.dtype())?;
    let steps: Vec<u32> = t.iter().map(|&v| v as u32).collect();
    let tt = if t.len() == shape[0] { Tensor::from_vec(steps, t.len(), device)? } else { Tensor::from_vec(steps, (shape[0], shape[1], shape[2]), device)? };
    let at = match anchors {
        Some(a) => Some(Tensor::from_slice(a, (shape[0], shape[1], 4), device)?.to_dtype(net.dtype())?),
        None => None,
    };
    Ok((xt, tt, at))
}

/// Context inversion, for forecasting with `replace` conditioning: before every model call,
/// `steps` gradient steps (size `lr`) move the observed prefix the network is shown so that its
/// own x̂0 of the last `frames` observed frames matches the observation. A causal network
/// forecasts from its reading of the past; a small model reads an unusual observed pose as a
/// typical one and starts the forecast there — a jump at the first forecast frame. The
/// output keeps the clean observed values; the network only sees the moved ones.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ContextInversion {
    /// Gradient steps per denoising step.
    pub steps: usize,
    /// Step size (standardized units per unit of gradient).
    pub lr: f32,
    /// Observed frames, counted back from the last one, whose reconstruction is matched.
    pub frames: usize,
}

impl Default for ContextInversion {
    fn default() -> Self {
        Self { steps: 6, lr: 0.5, frames: 8 }
    }
}

/// Workspace memory [`InferenceNet`] may use per call: batches of samples are sized to fit.
pub const BATCH_WORKSPACE_BYTES: usize = 256 << 20;

/// Activation memory a [`Denoiser`] on a GPU may use per call.
pub const DEVICE_BATCH_BYTES: usize = 16 << 30;

/// The sampling network of a device, one route each: the forward-only [`InferenceNet`] on the
/// CPU, the frozen [`Denoiser`] (composed kernels) on a GPU. Both hold the same weights; either
/// way the network's output becomes x̂0 as the model's [`Prediction`] says.
pub struct SamplingNet {
    route: SamplingRoute,
    prediction: Prediction,
    input_scaling: InputScaling,
    sigma_data: f64,
    schedule: NoiseSchedule,
}

/// Where a [`SamplingNet`] runs.
pub enum SamplingRoute {
    /// The CPU route.
    Cpu(Box<InferenceNet>),
    /// A GPU (or any other candle device) route.
    Device(Box<Denoiser>),
}

impl SamplingNet {
    /// The route of `device` for the weights of `net`, trained with `diffusion`.
    pub fn new(net: &Denoiser, diffusion: &GaussianDiffusion, device: &Device) -> Result<Self> {
        Self::with_k3_conv(net, diffusion, device, K3Conv::default())
    }

    /// [`SamplingNet::new`] with the CPU route's algorithm for stride-1 k3 convs (a GPU's
    /// route has one algorithm, candle's).
    pub fn with_k3_conv(net: &Denoiser, diffusion: &GaussianDiffusion, device: &Device, k3: K3Conv) -> Result<Self> {
        let route = if device.is_cpu() {
            let cpu = if net.device().is_cpu() { net.clone() } else { net.to_placement(&crate::model::Placement::cpu())? };
            SamplingRoute::Cpu(Box::new(InferenceNet::with_k3_conv(&cpu, k3)?))
        } else {
            SamplingRoute::Device(Box::new(net.to_placement(&crate::model::Placement::on(device.clone(), crate::model::Precision::F32))?.frozen()))
        };
        let c = diffusion.config();
        Ok(Self { route, prediction: c.prediction, input_scaling: c.input_scaling, sigma_data: c.sigma_data, schedule: diffusion.schedule().clone() })
    }

    /// The route as a model of x̂0.
    pub fn x0_model(&self) -> &dyn X0Model {
        self
    }

    /// Where it runs.
    pub fn route(&self) -> &SamplingRoute {
        &self.route
    }

    /// The network's raw output, x̂0 or v as [`Prediction`] says.
    fn network(&self) -> &dyn X0Model {
        match &self.route {
            SamplingRoute::Cpu(n) => n.as_ref(),
            SamplingRoute::Device(n) => n.as_ref(),
        }
    }

    /// Where it runs ([`SamplingNet::describe_route`]).
    pub fn describe(&self) -> String {
        match &self.route {
            SamplingRoute::Cpu(_) => Self::describe_route(&Device::Cpu),
            SamplingRoute::Device(n) => Self::describe_route(n.device()),
        }
    }

    /// The route of `device` in words: `cpu`, or the GPU's placement
    /// ([`crate::model::Placement::describe`], e.g. `cuda:0 f32 composed`).
    pub fn describe_route(device: &Device) -> String {
        if device.is_cpu() {
            "cpu".to_string()
        } else {
            crate::model::Placement::on(device.clone(), crate::model::Precision::F32).describe()
        }
    }
}

/// Autoguidance (Karras et al. 2024, "Guiding a diffusion model with a bad version of
/// itself"): `model` pushed away from a weaker model of the same data (trained for fewer
/// steps, or smaller), x̂0 = x̂0_weak + w·(x̂0 − x̂0_weak), at noise levels t ≥ `from_level`
/// only (guidance in an interval, Kynkäänniemi et al. 2024: at low noise it would sharpen
/// frame-to-frame detail into jitter). Without a condition to drop, this is the guidance an
/// unconditional generator has: the weak model makes the same errors more strongly (the
/// mean-seeking blur of a short training), so extrapolating away from it undoes some of them.
pub struct Autoguided<'a> {
    /// The model.
    pub model: &'a dyn X0Model,
    /// The weaker model.
    pub weak: &'a dyn X0Model,
    /// w (1: the model alone).
    pub weight: f32,
    /// The lowest guided noise level.
    pub from_level: usize,
}

impl X0Model for Autoguided<'_> {
    fn feature_dims(&self) -> usize {
        self.model.feature_dims()
    }

    fn max_batch(&self, persons: usize, frames: usize) -> usize {
        self.model.max_batch(persons, frames).min(self.weak.max_batch(persons, frames))
    }

    fn frames_ahead(&self) -> usize {
        self.model.frames_ahead().max(self.weak.frames_ahead())
    }

    fn predict_x0(&self, x: &[f32], shape: [usize; 4], t: &[usize], anchors: Option<&[f32]>, out: &mut [f32]) -> Result<()> {
        self.model.predict_x0(x, shape, t, anchors, out)?;
        if t.iter().all(|&tk| tk < self.from_level) {
            return Ok(());
        }
        let mut weak = vec![0f32; out.len()];
        self.weak.predict_x0(x, shape, t, anchors, &mut weak)?;
        let rows = crate::diffusion::values_per_level(shape, t.len(), x.len())?;
        for ((o, w), &tk) in out.chunks_mut(rows).zip(weak.chunks(rows)).zip(t) {
            if tk >= self.from_level {
                o.iter_mut().zip(w).for_each(|(o, w)| *o = w + self.weight * (*o - w));
            }
        }
        Ok(())
    }

    /// g = w·a + (1 − w)·b, so ∇ Σ ω(g − y)² = w·Jaᵀr + (1 − w)·Jbᵀr with r = 2ω(g − y): each
    /// model's own gradient against the target that leaves it the residual g − y.
    fn input_gradient(&self, x: &[f32], shape: [usize; 4], t: usize, anchors: Option<&[f32]>, target: &[f32], weight: &[f32]) -> Result<Option<Vec<f32>>> {
        if t < self.from_level {
            return self.model.input_gradient(x, shape, t, anchors, target, weight);
        }
        let (mut strong, mut weak) = (vec![0f32; x.len()], vec![0f32; x.len()]);
        self.model.predict_x0(x, shape, &[t], anchors, &mut strong)?;
        self.weak.predict_x0(x, shape, &[t], anchors, &mut weak)?;
        let residual: Vec<f32> = strong.iter().zip(&weak).zip(target).map(|((a, b), y)| b + self.weight * (a - b) - y).collect();
        let leaving = |own: &[f32]| -> Vec<f32> { own.iter().zip(&residual).map(|(o, r)| o - r).collect() };
        let (Some(ga), Some(gb)) = (
            self.model.input_gradient(x, shape, t, anchors, &leaving(&strong), weight)?,
            self.weak.input_gradient(x, shape, t, anchors, &leaving(&weak), weight)?,
        ) else {
            return Ok(None);
        };
        Ok(Some(ga.iter().zip(&gb).map(|(a, b)| self.weight * a + (1.0 - self.weight) * b).collect()))
    }
}

impl X0Model for SamplingNet {
    fn feature_dims(&self) -> usize {
        self.network().feature_dims()
    }

    fn max_batch(&self, persons: usize, frames: usize) -> usize {
        self.network().max_batch(persons, frames)
    }

    fn frames_ahead(&self) -> usize {
        self.network().frames_ahead()
    }

    fn predict_x0(&self, x: &[f32], shape: [usize; 4], t: &[usize], anchors: Option<&[f32]>, out: &mut [f32]) -> Result<()> {
        if self.input_scaling == InputScaling::None {
            self.network().predict_x0(x, shape, t, anchors, out)?;
        } else {
            let rows = crate::diffusion::values_per_level(shape, t.len(), x.len())?;
            let mut shown = x.to_vec();
            for (chunk, &tk) in shown.chunks_mut(rows).zip(t) {
                let q = self.schedule.q(tk)?;
                let gain = self.input_scaling.gain(q.signal, q.noise, self.sigma_data) as f32;
                chunk.iter_mut().for_each(|v| *v *= gain);
            }
            self.network().predict_x0(&shown, shape, t, anchors, out)?;
        }
        self.prediction.x0_from_output_in_place(&self.schedule, self.sigma_data, x, shape, t, out)
    }

    fn input_gradient(&self, x: &[f32], shape: [usize; 4], t: usize, anchors: Option<&[f32]>, target: &[f32], weight: &[f32]) -> Result<Option<Vec<f32>>> {
        let denoiser = match &self.route {
            SamplingRoute::Cpu(n) => n.source(),
            SamplingRoute::Device(n) => n.as_ref(),
        };
        let q = self.schedule.q(t)?;
        let skip = match self.prediction {
            Prediction::X0 => None,
            p => Some(p.mix(q.signal, q.noise, self.sigma_data)),
        };
        let gain = self.input_scaling.gain(q.signal, q.noise, self.sigma_data);
        denoiser_input_gradient(denoiser, x, shape, t, anchors, target, weight, skip, gain).map(Some)
    }
}

impl X0Model for InferenceNet {
    fn feature_dims(&self) -> usize {
        self.config().feature_dims
    }

    fn max_batch(&self, persons: usize, frames: usize) -> usize {
        (BATCH_WORKSPACE_BYTES / self.workspace_bytes(persons, frames).max(1)).max(1)
    }

    fn frames_ahead(&self) -> usize {
        self.config().causality.frames_ahead()
    }

    fn predict_x0(&self, x: &[f32], shape: [usize; 4], t: &[usize], anchors: Option<&[f32]>, out: &mut [f32]) -> Result<()> {
        let t: Vec<f64> = t.iter().map(|&v| v as f64).collect();
        self.forward(x, shape, &t, anchors, out)
    }

    /// Through the candle network the weights came from (forward-only has no backward).
    fn input_gradient(&self, x: &[f32], shape: [usize; 4], t: usize, anchors: Option<&[f32]>, target: &[f32], weight: &[f32]) -> Result<Option<Vec<f32>>> {
        self.source().input_gradient(x, shape, t, anchors, target, weight)
    }
}

impl X0Model for Denoiser {
    fn feature_dims(&self) -> usize {
        self.config().feature_dims
    }

    fn frames_ahead(&self) -> usize {
        self.config().causality.frames_ahead()
    }

    /// The candle network, computing a clean known prefix once per forecast
    /// ([`Denoiser::forward_cached`]). Pass a [`Denoiser::frozen`] copy: with trainable weights
    /// every step would keep its autograd graph (CANDLE_NOTES.md trap 6). On the CPU one sample per call
    /// (sampling there uses [`InferenceNet`], several times faster); on a GPU as many as
    /// [`DEVICE_BATCH_BYTES`] of activations allow.
    fn max_batch(&self, persons: usize, frames: usize) -> usize {
        if self.device().is_cpu() {
            return 1;
        }
        // Live activations of one scene without a graph: about 40 tensors of H floats per
        // person-frame at full rate (the skips), in f32.
        let per_scene = persons * frames.div_ceil(crate::model::TIME_FACTOR) * crate::model::TIME_FACTOR * self.config().hidden * 40 * 4;
        (DEVICE_BATCH_BYTES / per_scene.max(1)).max(1)
    }

    fn predict_x0(&self, x: &[f32], shape: [usize; 4], t: &[usize], anchors: Option<&[f32]>, out: &mut [f32]) -> Result<()> {
        let (xt, tt, at) = candle_inputs(self, x, shape, t, anchors)?;
        let y = self.forward_cached(&xt, &tt, at.as_ref())?;
        if y.dims() != shape {
            bail!("denoiser returned shape {:?}, expected {shape:?}", y.dims());
        }
        out.copy_from_slice(&y.to_dtype(candle_core::DType::F32)?.flatten_all()?.to_vec1::<f32>()?);
        Ok(())
    }

    fn input_gradient(&self, x: &[f32], shape: [usize; 4], t: usize, anchors: Option<&[f32]>, target: &[f32], weight: &[f32]) -> Result<Option<Vec<f32>>> {
        denoiser_input_gradient(self, x, shape, t, anchors, target, weight, None, 1.0).map(Some)
    }
}

/// [`X0Model::input_gradient`] through `net`, whose output F is x̂0 (`skip = None`) or mixed
/// with the input, x̂0 = c_skip·x + c_out·F for `skip = Some((c_skip, c_out))`
/// ([`Prediction::mix`]), from the input shown times `input_gain` ([`InputScaling::gain`]).
#[allow(clippy::too_many_arguments)]
fn denoiser_input_gradient(
    net: &Denoiser,
    x: &[f32],
    shape: [usize; 4],
    t: usize,
    anchors: Option<&[f32]>,
    target: &[f32],
    weight: &[f32],
    skip: Option<(f64, f64)>,
    input_gain: f64,
) -> Result<Vec<f32>> {
    if shape[0] != 1 || target.len() != x.len() || weight.len() != x.len() {
        bail!("input_gradient: one scene with target and weight of its size expected, got shape {shape:?}");
    }
    let (xt, tt, at) = candle_inputs(net, x, shape, &[t], anchors)?;
    let xv = candle_core::Var::from_tensor(&xt)?;
    let mut y = net.forward(&(xv.as_tensor() * input_gain)?, &tt, at.as_ref())?;
    if let Some((c_skip, c_out)) = skip {
        y = ((xv.as_tensor() * c_skip)? + (y * c_out)?)?;
    }
    let on_device = |v: &[f32]| -> Result<Tensor> { Ok(Tensor::from_slice(v, shape.as_slice(), net.device())?.to_dtype(net.dtype())?) };
    let (target, weight) = (on_device(target)?, on_device(weight)?);
    let loss = ((y - target)? * weight)?.sqr()?.sum_all()?;
    let grads = loss.backward()?;
    let g = grads.get(xv.as_tensor()).ok_or_else(|| crate::Error::invalid("input_gradient: no gradient reached the input"))?;
    Ok(g.to_dtype(candle_core::DType::F32)?.flatten_all()?.to_vec1::<f32>()?)
}

/// What is known about the canvas.
#[derive(Clone, Copy, Debug)]
pub struct Known<'a> {
    /// Known values (standardized anchored features); entries outside the mask are ignored.
    ///
    /// Shape `[frames, persons, δ]`.
    pub values: ArrayView3<'a, f32>,
    /// `true` where the value is known. Shape `[frames, persons, δ]`.
    pub mask: ArrayView3<'a, bool>,
    /// Each person's anchor `(root_x, root_y, cos h, sin h)` in a frame shared by the scene,
    /// for the social aggregator. Shape `[persons, 4]`.
    pub anchors: Option<ArrayView2<'a, f32>>,
}

/// Options of [`inpaint`].
#[derive(Clone, Debug, PartialEq)]
pub struct InpaintOptions {
    /// Number of samples drawn.
    pub samples: usize,
    /// How known entries are imposed.
    pub conditioning: Conditioning,
    /// Base seed: sample s draws from an RNG seeded by [`sample_seed`]`(seed, s)`.
    pub seed: u64,
    /// Context inversion (with `replace`, when the known entries start with whole frames).
    pub inversion: Option<ContextInversion>,
    /// Show the network the fully known person-frames (all δ dims known) clean at noise level
    /// 0, beside the sampler's level on the rest, and keep them clean under any conditioning:
    /// for models trained with clean frames ([`crate::checkpoint::config::NoiseLevels::trains_clean_frames`]).
    /// Off: every frame at the sampler's level (the paper).
    pub clean_known: bool,
}

impl Default for InpaintOptions {
    fn default() -> Self {
        Self { samples: 1, conditioning: Conditioning::Replace, seed: 0, inversion: None, clean_known: false }
    }
}

/// The seed of sample `k` for base seed `seed` (splitmix64 of both): independent of the number
/// of samples.
pub fn sample_seed(seed: u64, k: usize) -> u64 {
    let mut z = seed ^ (k as u64).wrapping_add(1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A forecasting mask: every dim of every person known on frames `< observed`.
///
/// # Shapes
/// - returns `[frames, persons, dims]`
pub fn forecast_mask(frames: usize, persons: usize, dims: usize, observed: usize) -> ndarray::Array3<bool> {
    ndarray::Array3::from_shape_fn((frames, persons, dims), |(f, _, _)| f < observed)
}

/// One model call of [`inpaint_with_progress`].
#[derive(Clone, Debug)]
pub struct StepInfo {
    /// The samples denoised together by this call.
    pub samples: Range<usize>,
    /// Step index (0-based) and number of steps of the sampler.
    pub step: usize,
    /// Steps per sample.
    pub steps: usize,
    /// Seconds of the model call.
    pub seconds: f64,
}

/// Samples the unknown entries of the canvas with `sampler` (DDPM, or DDIM over any K steps),
/// imposing the known entries after every reverse step (see the module doc).
///
/// # Shapes
/// - `known.values`, `known.mask`: `[T, P, δ]`; `known.anchors`: `[P, 4]`
/// - returns `[samples, T, P, δ]` (known entries equal `known.values` exactly)
pub fn inpaint(model: &dyn X0Model, sampler: &dyn Sampler, known: &Known, opts: &InpaintOptions) -> Result<Array4<f32>> {
    inpaint_with_progress(model, sampler, known, opts, &mut |_| {})
}

/// [`inpaint`], reporting every model call to `on_step`.
pub fn inpaint_with_progress(
    model: &dyn X0Model,
    sampler: &dyn Sampler,
    known: &Known,
    opts: &InpaintOptions,
    on_step: &mut dyn FnMut(StepInfo),
) -> Result<Array4<f32>> {
    let (nt, np, nd) = known.values.dim();
    if known.mask.dim() != (nt, np, nd) {
        bail!("inpaint: mask {:?} and known values {:?} differ in shape", known.mask.shape(), known.values.shape());
    }
    if nt == 0 || np == 0 {
        bail!("inpaint: empty canvas {:?}", known.values.shape());
    }
    if nd != model.feature_dims() {
        bail!("inpaint: canvas has {nd} feature dims, the model {}", model.feature_dims());
    }
    if opts.samples == 0 {
        bail!("inpaint: samples must be at least 1");
    }
    if let Some(a) = known.anchors {
        if a.dim() != (np, 4) {
            bail!("inpaint: anchors have shape {:?}, expected [{np}, 4]", a.shape());
        }
    }
    if sampler.timesteps().is_empty() {
        bail!("inpaint: the sampler has no steps");
    }
    let ahead = model.frames_ahead();
    if opts.inversion.is_some() && ahead > 0 {
        bail!("context inversion works on the observed frames alone and needs a causal model; this one sees {ahead} frames ahead (trained with `causality` lookahead)");
    }
    let per = np * nt * nd;

    // Known values and mask in the model's layout [P, T, δ].
    let mut canvas = Canvas { obs: vec![0f32; per], known: Vec::new(), clean: Vec::new(), clean_frames: Vec::new() };
    for p in 0..np {
        for f in 0..nt {
            for d in 0..nd {
                let k = (p * nt + f) * nd + d;
                if known.mask[[f, p, d]] {
                    let v = known.values[[f, p, d]];
                    if !v.is_finite() {
                        bail!("inpaint: known value at person {p}, frame {f}, dim {d} is not finite");
                    }
                    canvas.obs[k] = v;
                    canvas.known.push(k);
                }
            }
        }
    }
    if opts.clean_known {
        // Whole known person-frames: level 0, always clean.
        canvas.clean_frames = (0..np * nt).map(|pf| (0..nd).all(|d| known.mask[[pf % nt, pf / nt, d]])).collect();
        let (clean, rest): (Vec<usize>, Vec<usize>) = canvas.known.iter().partition(|&&k| canvas.clean_frames[k / nd]);
        (canvas.clean, canvas.known) = (clean, rest);
    }
    let anchors: Option<Vec<f32>> = known.anchors.map(|a| a.iter().copied().collect());

    let batch = model.max_batch(np, nt).clamp(1, opts.samples);
    // The inversion's offsets depend on the step only, not on the samples: later batches
    // replay those of the first.
    let mut prefix = match (opts.inversion, opts.conditioning) {
        (Some(inv), Conditioning::Replace) => KnownPrefix::new(&canvas, [np, nt, nd], inv, batch < opts.samples),
        _ => None,
    };
    let mut out = Array4::<f32>::zeros((opts.samples, nt, np, nd));
    for first in (0..opts.samples).step_by(batch) {
        let samples = first..(first + batch).min(opts.samples);
        let batch_anchors: Option<Vec<f32>> = anchors.as_ref().map(|a| a.repeat(samples.len()));
        let x = reverse_process(model, sampler, &canvas, prefix.as_mut(), batch_anchors.as_deref(), [np, nt, nd], samples.clone(), opts, None, on_step)?;
        // back to [S, T, P, δ]
        for (s, xs) in samples.zip(x.chunks_exact(per)) {
            for p in 0..np {
                for f in 0..nt {
                    for d in 0..nd {
                        out[[s, f, p, d]] = xs[(p * nt + f) * nd + d];
                    }
                }
            }
        }
    }
    Ok(out)
}

/// The known part of a canvas in the model's layout `[P, T, δ]`.
struct Canvas {
    /// Known values (0 elsewhere).
    obs: Vec<f32>,
    /// Flat indices of the known entries that follow the conditioning, ascending.
    known: Vec<usize>,
    /// With [`InpaintOptions::clean_known`]: flat indices of the entries of whole known
    /// person-frames (always clean), and which person-frames `[P, T]` those are.
    clean: Vec<usize>,
    clean_frames: Vec<bool>,
}

impl Canvas {
    /// The noise level of every person-frame `[P, T]` of one sample at sampler step t: 0 on
    /// clean frames; `None` when there are none (one level per scene).
    fn levels(&self, t: usize) -> Option<Vec<usize>> {
        (!self.clean.is_empty()).then(|| self.clean_frames.iter().map(|&c| if c { 0 } else { t }).collect())
    }

    /// Sets the known entries of one sample: the clean values, or `q.q_sample(value, z)` with
    /// one fresh draw of `rng` per known entry; entries of clean frames are always clean.
    fn impose(&self, x: &mut [f32], level: Option<socdiff_schedules::QCoefficients>, rng: &mut StdRng) {
        self.clean.iter().for_each(|&k| x[k] = self.obs[k]);
        match level {
            None => self.known.iter().for_each(|&k| x[k] = self.obs[k]),
            Some(q) => {
                let z = standard_normal(rng, self.known.len());
                for (&k, &zk) in self.known.iter().zip(&z) {
                    x[k] = q.q_sample(self.obs[k] as f64, zk as f64) as f32;
                }
            }
        }
    }
}

/// The frames `0..len` known for every person and dim, with the offsets of context inversion.
struct KnownPrefix {
    inv: ContextInversion,
    /// [P, T, δ] of the canvas, and the prefix length L.
    dims: [usize; 3],
    len: usize,
    /// Known values, offsets and loss weights on the prefix, `[P, L, δ]`.
    target: Vec<f32>,
    delta: Vec<f32>,
    weight: Vec<f32>,
    /// The offsets of every step so far, when several batches of samples replay them.
    history: Option<Vec<Vec<f32>>>,
}

impl KnownPrefix {
    /// `None` when no whole frame is known, or every frame is. `keep`: remember the offsets of
    /// every step for [`KnownPrefix::advance`] to replay.
    fn new(canvas: &Canvas, [np, nt, nd]: [usize; 3], inv: ContextInversion, keep: bool) -> Option<Self> {
        let mut known = vec![false; np * nt * nd];
        canvas.known.iter().for_each(|&k| known[k] = true);
        let len = (0..nt).take_while(|&f| (0..np).all(|p| known[(p * nt + f) * nd..(p * nt + f + 1) * nd].iter().all(|&k| k))).count();
        if len == 0 || len == nt || inv.steps == 0 {
            return None;
        }
        let n = np * len * nd;
        let (mut target, mut weight) = (vec![0f32; n], vec![0f32; n]);
        for p in 0..np {
            for f in 0..len {
                for d in 0..nd {
                    let k = (p * len + f) * nd + d;
                    target[k] = canvas.obs[(p * nt + f) * nd + d];
                    weight[k] = if f + inv.frames >= len { 1.0 } else { 0.0 };
                }
            }
        }
        Some(Self { inv, dims: [np, nt, nd], len, target, delta: vec![0f32; n], weight, history: keep.then(Vec::new) })
    }

    /// Sets the offsets of sampler step `step` at noise level t: replayed when a previous batch
    /// computed them, otherwise by [`KnownPrefix::invert`] from those of the step before.
    fn advance(&mut self, step: usize, model: &dyn X0Model, t: usize, anchors: Option<&[f32]>) -> Result<()> {
        if step == 0 {
            self.delta.fill(0.0);
        }
        if let Some(d) = self.history.as_ref().and_then(|h| h.get(step)) {
            self.delta.copy_from_slice(d);
            return Ok(());
        }
        self.invert(model, t, anchors)?;
        if let Some(h) = self.history.as_mut() {
            h.push(self.delta.clone());
        }
        Ok(())
    }

    /// `inv.steps` gradient steps at noise level t on the prefix alone (the network is causal:
    /// later frames cannot change its reading of these).
    fn invert(&mut self, model: &dyn X0Model, t: usize, anchors: Option<&[f32]>) -> Result<()> {
        let [np, _, nd] = self.dims;
        for _ in 0..self.inv.steps {
            let shown: Vec<f32> = self.target.iter().zip(&self.delta).map(|(a, b)| a + b).collect();
            let g = model
                .input_gradient(&shown, [1, np, self.len, nd], t, anchors, &self.target, &self.weight)?
                .ok_or_else(|| crate::Error::invalid("context inversion needs a model that can differentiate its input"))?;
            self.delta.iter_mut().zip(&g).for_each(|(d, g)| *d -= self.inv.lr * g);
        }
        Ok(())
    }

    /// Writes the shown prefix (known values + offsets) into one sample `[P, T, δ]`.
    fn show(&self, xs: &mut [f32]) {
        let [np, nt, nd] = self.dims;
        for p in 0..np {
            let row = (p * self.len) * nd..(p * self.len + self.len) * nd;
            let dst = &mut xs[(p * nt) * nd..(p * nt + self.len) * nd];
            for ((x, a), b) in dst.iter_mut().zip(&self.target[row.clone()]).zip(&self.delta[row]) {
                *x = a + b;
            }
        }
    }
}

/// The whole reverse process for one batch of samples, from `start` (`[S, P, T, δ]`) or from
/// noise drawn by each sample's seed; returns `[S, P, T, δ]` flattened. `anchors`: `[S, P, 4]`.
#[allow(clippy::too_many_arguments)]
fn reverse_process(
    model: &dyn X0Model,
    sampler: &dyn Sampler,
    canvas: &Canvas,
    mut prefix: Option<&mut KnownPrefix>,
    batch_anchors: Option<&[f32]>,
    [np, nt, nd]: [usize; 3],
    samples: Range<usize>,
    opts: &InpaintOptions,
    start: Option<Vec<f32>>,
    on_step: &mut dyn FnMut(StepInfo),
) -> Result<Vec<f32>> {
    let ns = samples.len();
    let per = np * nt * nd;
    let steps = sampler.timesteps();
    let mut rngs: Vec<StdRng> = samples.clone().map(|s| StdRng::seed_from_u64(sample_seed(opts.seed, s))).collect();
    // Every sample of a batch has the canvas's anchors `[P, 4]`.
    let anchors = batch_anchors.map(|a| &a[..np * 4]);

    // The first canvas: N(0, I) everywhere; with `replace` the known entries are the clean
    // known values right away (as the reference), with `noised` they start as noise too.
    let start_is_noise = start.is_none();
    let mut x = start.unwrap_or_else(|| vec![0f32; ns * per]);
    x.par_chunks_mut(per).zip(rngs.par_iter_mut()).for_each(|(xs, rng)| {
        if start_is_noise {
            xs.copy_from_slice(&standard_normal(rng, per));
        }
        if opts.conditioning == Conditioning::Replace {
            canvas.impose(xs, None, rng);
        } else {
            canvas.clean.iter().for_each(|&k| xs[k] = canvas.obs[k]);
        }
    });
    let mut x0 = vec![0f32; ns * per];
    let mut next = vec![0f32; ns * per];
    for (i, &t) in steps.iter().enumerate() {
        if let Some(pf) = prefix.as_deref_mut() {
            pf.advance(i, model, t, anchors)?;
            x.par_chunks_mut(per).for_each(|xs| pf.show(xs));
        }
        let t0 = Instant::now();
        let levels = match canvas.levels(t) {
            Some(per_sample) => per_sample.repeat(ns),
            None => vec![t; ns],
        };
        model.predict_x0(&x, [ns, np, nt, nd], &levels, batch_anchors, &mut x0)?;
        on_step(StepInfo { samples: samples.clone(), step: i, steps: steps.len(), seconds: t0.elapsed().as_secs_f64() });
        let c = sampler.coefficients(i)?;
        let level = match opts.conditioning {
            Conditioning::Replace => None,
            Conditioning::Noised => Some(sampler.q_prev(i)?),
        };
        next.par_chunks_mut(per).zip(x.par_chunks(per).zip(x0.par_chunks(per))).zip(rngs.par_iter_mut()).try_for_each(
            |((out, (xs, x0s)), rng)| -> Result<()> {
                let z = if c.needs_noise() { Some(standard_normal(rng, per)) } else { None };
                c.apply(x0s, xs, z.as_deref(), out)?;
                canvas.impose(out, level, rng);
                Ok(())
            },
        )?;
        std::mem::swap(&mut x, &mut next);
    }
    Ok(x)
}

/// Deterministic DDIM inversion (η = 0): clean features `x0` carried up `sampler`'s timesteps
/// (of `schedule`), smallest first, with the model's own predictions, x_s = √ᾱ_s·x̂0 +
/// √(1 − ᾱ_s)·ε̂ with ε̂ = (x_t − √ᾱ_t·x̂0)/√(1 − ᾱ_t) from each step t to the next s; returns
/// x at the largest timestep (noise when it is T − 1), which [`ddim_denoise`] with the same
/// sampler takes back close to `x0`.
///
/// With `refine = 0` this is the plain inversion of Song et al. (x̂0 = g(x_t, t), predicted
/// where the step starts, so the round trip is only approximate). With `refine = n > 0` each
/// step is then corrected by up to n fixed-point iterations towards the x_s whose DDIM
/// denoising step gives back x_t exactly (x̂0 = g(x_s, s), as the denoiser will predict it;
/// Pan et al. 2023, Garibi et al. 2024), and x at t = 0 is first moved until g(x, 0) = `x0`
/// (the denoiser's last step returns g's prediction). Each iteration costs one model call;
/// one whose residual grows is undone and the next tries half the step.
///
/// # Shapes
/// - `x0`: `[B, P, T, δ]` flattened (`shape`); `anchors`: `[B, P, 4]`.
pub fn ddim_invert(
    model: &dyn X0Model,
    schedule: &NoiseSchedule,
    sampler: &dyn Sampler,
    x0: &[f32],
    shape: [usize; 4],
    anchors: Option<&[f32]>,
    refine: usize,
) -> Result<Inversion> {
    check_shape(x0, shape)?;
    let mut ts = sampler.timesteps().to_vec();
    if ts.first().is_some_and(|&t| t >= schedule.timesteps()) {
        bail!("ddim_invert: the sampler's timesteps reach {} of a {}-step schedule", ts[0], schedule.timesteps());
    }
    ts.reverse();
    let ab = schedule.alpha_bars();
    let mut x = x0.to_vec();
    let mut x0_hat = vec![0f32; x.len()];
    let mut residuals = Vec::new();
    // t = 0: the denoiser's output is g(x, 0) itself, so x moves by the residual x0 − g(x, 0).
    if refine > 0 {
        let r = fixed_point(model, &mut x, &mut x0_hat, shape, ts[0], anchors, refine, |_, p, k| x0[k] as f64 - p as f64, 1.0)?;
        residuals.push(r);
    }
    for w in ts.windows(2) {
        let (a, a_next) = (ab[w[0]], ab[w[1]]);
        let x_t = x.clone();
        model.predict_x0(&x, shape, &vec![w[0]; shape[0]], anchors, &mut x0_hat)?;
        // x_s from the prediction `p` at the start (plain) or at x_s itself (refined).
        let up = |x_t: f32, p: f32| -> f64 {
            let eps = (x_t as f64 - a.sqrt() * p as f64) / (1.0 - a).sqrt();
            a_next.sqrt() * p as f64 + (1.0 - a_next).sqrt() * eps
        };
        for ((v, &xt), &p) in x.iter_mut().zip(&x_t).zip(&x0_hat) {
            *v = up(xt, p) as f32;
        }
        if refine > 0 {
            // R = x_t − D(x_s), D the DDIM step down from s: up(x_t, g(x_s, s)) − x_s = r·R with
            // r = √(1 − ᾱ_s)/√(1 − ᾱ_t). The first gain √(ᾱ_s/ᾱ_t) is the ε-space fixed point
            // x_s ← √(ᾱ_s/ᾱ_t)·x_t + c·ε̂(x_s) of Garibi et al.
            let ratio = ((1.0 - a_next) / (1.0 - a)).sqrt();
            let gain = (a_next / a).sqrt();
            let res = fixed_point(model, &mut x, &mut x0_hat, shape, w[1], anchors, refine, |xs, p, k| (up(x_t[k], p) - xs as f64) / ratio, gain)?;
            residuals.push(res);
        }
    }
    Ok(Inversion { noise: x, residuals })
}

/// The noise of a [`ddim_invert`] and how exactly its steps invert.
#[derive(Clone, Debug)]
pub struct Inversion {
    /// `[B, P, T, δ]` flattened, at the last timestep.
    pub noise: Vec<f32>,
    /// Per refined step (t = 0 first), the RMS of what its DDIM denoising step misses by,
    /// after the refinement (empty when not refined).
    pub residuals: Vec<f64>,
}

/// Up to `iterations` moves x += gain·R(x) towards R = 0, each measured by one more model call
/// (value k of R is `residual(x_k, g_k, k)` with g = g(x, t)). A move that makes the RMS
/// residual grow is undone and the gain halved; after one that shrinks it, the gain becomes
/// the secant estimate ⟨Δ, Δ⟩/⟨Δ, R_before − R_after⟩ (Barzilai & Borwein 1988) of the
/// inverse Jacobian along the move Δ. Returns the RMS residual of the x it leaves.
#[allow(clippy::too_many_arguments)]
fn fixed_point(
    model: &dyn X0Model,
    x: &mut [f32],
    pred: &mut [f32],
    shape: [usize; 4],
    t: usize,
    anchors: Option<&[f32]>,
    iterations: usize,
    residual: impl Fn(f32, f32, usize) -> f64,
    mut gain: f64,
) -> Result<f64> {
    let mut measure = |x: &[f32]| -> Result<(Vec<f64>, f64)> {
        model.predict_x0(x, shape, &vec![t; shape[0]], anchors, pred)?;
        let r: Vec<f64> = x.iter().zip(pred.iter()).enumerate().map(|(k, (&v, &p))| residual(v, p, k)).collect();
        let rms = (r.iter().map(|v| v * v).sum::<f64>() / r.len() as f64).sqrt();
        Ok((r, rms))
    };
    let (mut r, mut rms) = measure(x)?;
    let mut trial = vec![0f32; x.len()];
    for _ in 0..iterations {
        if rms == 0.0 {
            break;
        }
        for ((n, &v), &d) in trial.iter_mut().zip(x.iter()).zip(&r) {
            *n = (v as f64 + gain * d) as f32;
        }
        let (r_new, rms_new) = measure(&trial)?;
        if rms_new < rms {
            let (mut dd, mut dr) = (0.0, 0.0);
            for ((&n, &v), (&a, &b)) in trial.iter().zip(x.iter()).zip(r.iter().zip(&r_new)) {
                let step = n as f64 - v as f64;
                dd += step * step;
                dr += step * (a - b);
            }
            if dr > 0.0 {
                gain = (dd / dr).clamp(gain / 8.0, gain * 8.0);
            }
            x.copy_from_slice(&trial);
            (r, rms) = (r_new, rms_new);
        } else {
            gain *= 0.5;
        }
    }
    Ok(rms)
}

/// DDIM sampling from a given noise `x` (no known entries), as `sampler`'s steps say.
///
/// # Shapes
/// - `x`: `[B, P, T, δ]` flattened (`shape`); `anchors`: `[B, P, 4]`.
pub fn ddim_denoise(model: &dyn X0Model, sampler: &dyn Sampler, x: Vec<f32>, shape: [usize; 4], anchors: Option<&[f32]>) -> Result<Vec<f32>> {
    check_shape(&x, shape)?;
    for i in 0..sampler.timesteps().len() {
        if sampler.coefficients(i)?.needs_noise() {
            bail!("ddim_denoise: step {i} draws noise; use a deterministic sampler (DDIM, η = 0)");
        }
    }
    let [ns, np, nt, nd] = shape;
    if let Some(a) = anchors {
        if a.len() != ns * np * 4 {
            bail!("ddim_denoise: {} anchor values for {ns} × {np} persons", a.len());
        }
    }
    // The inpainting reverse process with nothing known.
    let canvas = Canvas { obs: vec![0f32; np * nt * nd], known: Vec::new(), clean: Vec::new(), clean_frames: Vec::new() };
    let opts = InpaintOptions { samples: ns, ..Default::default() };
    reverse_process(model, sampler, &canvas, None, anchors, [np, nt, nd], 0..ns, &opts, Some(x), &mut |_| {})
}

fn check_shape(x: &[f32], shape: [usize; 4]) -> Result<()> {
    if x.len() != shape.iter().product::<usize>() || shape.contains(&0) {
        bail!("features of {} values for shape {shape:?}", x.len());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{Array2, Array3};
    use socdiff_schedules::{Ddim, Ddpm, NoiseSchedule};
    use std::cell::RefCell;

    /// x̂0 = 0.5·x_t + 0.1·(d + 1), recording every input; at most `batch` scenes per call.
    struct Dummy {
        dims: usize,
        batch: usize,
        seen: RefCell<Vec<(Vec<f32>, Vec<usize>)>>,
    }

    fn dummy(dims: usize) -> Dummy {
        Dummy { dims, batch: usize::MAX, seen: RefCell::new(vec![]) }
    }

    impl X0Model for Dummy {
        fn feature_dims(&self) -> usize {
            self.dims
        }
        fn max_batch(&self, _persons: usize, _frames: usize) -> usize {
            self.batch
        }
        fn predict_x0(&self, x: &[f32], shape: [usize; 4], t: &[usize], _anchors: Option<&[f32]>, out: &mut [f32]) -> Result<()> {
            assert!(shape[0] <= self.batch && shape[3] == self.dims && (t.len() == shape[0] || t.len() == shape[0] * shape[1] * shape[2]));
            self.seen.borrow_mut().push((x.to_vec(), t.to_vec()));
            let d = self.dims;
            for (k, (o, &v)) in out.iter_mut().zip(x).enumerate() {
                *o = 0.5 * v + 0.1 * ((k % d) as f32 + 1.0);
            }
            Ok(())
        }
    }

    /// x̂0 = a·x² per value, with its exact input gradient.
    struct Square(f32);

    impl X0Model for Square {
        fn feature_dims(&self) -> usize {
            2
        }
        fn predict_x0(&self, x: &[f32], _shape: [usize; 4], _t: &[usize], _anchors: Option<&[f32]>, out: &mut [f32]) -> Result<()> {
            out.iter_mut().zip(x).for_each(|(o, v)| *o = self.0 * v * v);
            Ok(())
        }
        fn input_gradient(
            &self,
            x: &[f32],
            _shape: [usize; 4],
            _t: usize,
            _anchors: Option<&[f32]>,
            target: &[f32],
            weight: &[f32],
        ) -> Result<Option<Vec<f32>>> {
            Ok(Some(x.iter().zip(target).zip(weight).map(|((v, y), w)| 2.0 * w * (self.0 * v * v - y) * 2.0 * self.0 * v).collect()))
        }
    }

    /// With a = x² and b = x²/4, w = 3: g = b + 3(a − b) = 2.5·x² at levels ≥ 500 (per scene and
    /// per frame), a below; the gradient of Σ ω(g − y)² is 2ω(2.5x² − y)·5x there (by hand), the
    /// model's own below.
    #[test]
    fn autoguidance_extrapolates_away_from_the_weak_model_above_its_level() {
        let (strong, weak) = (Square(1.0), Square(0.25));
        let guided = Autoguided { model: &strong, weak: &weak, weight: 3.0, from_level: 500 };
        let shape = [2, 1, 3, 2];
        let x: Vec<f32> = (0..12).map(|i| 0.3 * i as f32 - 1.4).collect();
        let mut out = vec![0f32; 12];
        guided.predict_x0(&x, shape, &[600, 100], None, &mut out).unwrap();
        for (k, (o, v)) in out.iter().zip(&x).enumerate() {
            let want = if k < 6 { 2.5 * v * v } else { v * v };
            assert!((o - want).abs() < 1e-5, "scene level: value {k}: {o} vs {want}");
        }
        let per_frame = [999, 0, 500, 499, 700, 1];
        guided.predict_x0(&x, shape, &per_frame, None, &mut out).unwrap();
        for (k, (o, v)) in out.iter().zip(&x).enumerate() {
            let want = if per_frame[k / 2] >= 500 { 2.5 * v * v } else { v * v };
            assert!((o - want).abs() < 1e-5, "frame level: value {k}: {o} vs {want}");
        }
        let one = [1, 1, 3, 2];
        let (xs, y) = (&x[..6], [0.2f32, -0.1, 0.7, 1.3, 0.0, 0.4]);
        let w = [1.0f32, 0.0, 1.0, 1.0, 0.0, 1.0];
        let g = guided.input_gradient(xs, one, 800, None, &y, &w).unwrap().unwrap();
        for k in 0..6 {
            let want = 2.0 * w[k] * (2.5 * xs[k] * xs[k] - y[k]) * 5.0 * xs[k];
            assert!((g[k] - want).abs() < 1e-4 * want.abs().max(1.0), "gradient {k}: {} vs {want}", g[k]);
        }
        let below = guided.input_gradient(xs, one, 10, None, &y, &w).unwrap().unwrap();
        assert_eq!(below, strong.input_gradient(xs, one, 10, None, &y, &w).unwrap().unwrap());
        // A weak model that cannot differentiate: no gradient, so context inversion says so.
        let blind = Autoguided { model: &strong, weak: &Oracle(vec![0.0; 6]), weight: 2.0, from_level: 0 };
        assert!(blind.input_gradient(xs, one, 10, None, &y, &w).unwrap().is_none());
    }

    /// x̂0 = a fixed target, whatever the input (an oracle of one clean sample).
    struct Oracle(Vec<f32>);

    impl X0Model for Oracle {
        fn feature_dims(&self) -> usize {
            3
        }
        fn predict_x0(&self, _x: &[f32], _shape: [usize; 4], _t: &[usize], _anchors: Option<&[f32]>, out: &mut [f32]) -> Result<()> {
            out.copy_from_slice(&self.0);
            Ok(())
        }
    }

    /// DDIM inversion with an oracle: ε̂ keeps its value at the start, where x0 stands for x at
    /// t = 0, e = (1 − √ᾱ_0)/√(1 − ᾱ_0)·x0, so the noise at the last of K steps (t = 999) is
    /// √ᾱ_999·x0 + √(1 − ᾱ_999)·e, and denoising it over the same steps returns x0; a sampler
    /// that draws noise and a wrong shape are refused.
    #[test]
    fn ddim_inversion_and_denoising_round_trip_with_an_oracle() {
        let x0: Vec<f32> = (0..2 * 5 * 3).map(|i| (i as f32 * 0.37).sin()).collect();
        let shape = [1, 2, 5, 3];
        let oracle = Oracle(x0.clone());
        let schedule = NoiseSchedule::default();
        let (a0, e) = (schedule.alpha_bars()[0], |a0: f64| (1.0 - a0.sqrt()) / (1.0 - a0).sqrt());
        // Up to pure noise (t = 999) and part of the way (t = 399, 10 steps).
        let partial = Ddim::with_timesteps(&schedule, socdiff_schedules::respaced_timesteps(400, 10).unwrap(), 0.0).unwrap();
        for (sampler, top) in [(Ddim::new(&schedule, 20, 0.0).unwrap(), 999), (partial, 399)] {
            assert_eq!(sampler.timesteps()[0], top);
            let z = ddim_invert(&oracle, &schedule, &sampler, &x0, shape, None, 0).unwrap().noise;
            let a_top = schedule.alpha_bars()[top];
            assert!(z.iter().zip(&x0).all(|(z, &x)| (*z as f64 - (a_top.sqrt() + (1.0 - a_top).sqrt() * e(a0)) * x as f64).abs() < 1e-5));
            let back = ddim_denoise(&oracle, &sampler, z, shape, None).unwrap();
            assert!(back.iter().zip(&x0).all(|(a, b)| (a - b).abs() < 1e-5), "top {top}");
        }
        let z = vec![0.5f32; x0.len()];
        assert!(ddim_denoise(&oracle, &Ddim::new(&schedule, 20, 1.0).unwrap(), z, shape, None).unwrap_err().to_string().contains("draws noise"));
        let sampler = Ddim::new(&schedule, 20, 0.0).unwrap();
        assert!(ddim_invert(&oracle, &schedule, &sampler, &x0[1..], shape, None, 0).is_err());
        let longer = Ddim::new(&NoiseSchedule::new(socdiff_schedules::BetaSchedule::Cosine { s: 0.008 }, 2000).unwrap(), 20, 0.0).unwrap();
        assert!(ddim_invert(&oracle, &schedule, &longer, &x0, shape, None, 0).unwrap_err().to_string().contains("1999 of a 1000-step"));
    }

    /// With a model whose prediction depends on its input (x̂0 = 0.5·x_t + 0.1·(d + 1)) the
    /// plain inversion is only approximate; refined by fixed-point iterations, denoising gives
    /// x0 back to within f32 rounding, and every refined step reports its small residual.
    #[test]
    fn refined_inversion_is_undone_by_denoising() {
        let x0: Vec<f32> = (0..2 * 6 * 3).map(|i| (i as f32 * 0.53).cos()).collect();
        let shape = [1, 2, 6, 3];
        let model = dummy(3);
        let schedule = NoiseSchedule::default();
        let sampler = Ddim::new(&schedule, 20, 0.0).unwrap();
        let round_trip = |refine: usize| {
            let inv = ddim_invert(&model, &schedule, &sampler, &x0, shape, None, refine).unwrap();
            let back = ddim_denoise(&model, &sampler, inv.noise.clone(), shape, None).unwrap();
            (back.iter().zip(&x0).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max), inv)
        };
        let (plain, inv) = round_trip(0);
        assert!(plain > 0.05 && inv.residuals.is_empty(), "plain inversion error {plain}");
        let (refined, inv) = round_trip(30);
        assert!(refined < 1e-4, "refined inversion error {refined} (plain {plain})");
        assert_eq!(inv.residuals.len(), 20); // t = 0 and the 19 steps up
        assert!(inv.residuals.iter().all(|&r| r < 1e-5), "{:?}", inv.residuals);
        // One iteration already helps.
        assert!(round_trip(1).0 < plain);
    }

    /// The GPU route (a frozen `Denoiser` on the composed kernels, here on the CPU) draws the
    /// same forecasts as the CPU route (`InferenceNet`) from one seed, with and without clean
    /// known frames (computed once by both): the two sampling routes hold one network.
    #[test]
    fn the_device_route_samples_what_the_cpu_route_samples() {
        use crate::model::{DenoiserConfig, Kernels, Placement, Precision};
        let cfg = DenoiserConfig { feature_dims: 5, hidden: 8, time_dim: 16, fourier_dim: 8, social_dim: 8, ..Default::default() };
        let net = Denoiser::new(cfg, 3).unwrap();
        let diffusion = GaussianDiffusion::new(&Default::default()).unwrap();
        let cpu = SamplingNet::new(&net, &diffusion, &Device::Cpu).unwrap();
        assert!(matches!(cpu.route(), SamplingRoute::Cpu(_)) && cpu.describe() == "cpu");
        let composed = net.to_placement(&Placement { kernels: Kernels::Composed(Precision::F32), ..Placement::cpu() }).unwrap().frozen();
        let (nt, np, nd) = (40, 2, 5);
        let values = Array3::from_shape_fn((nt, np, nd), |(f, p, d)| ((f as f32) * 0.1 + p as f32 + d as f32).sin());
        let mask = forecast_mask(nt, np, nd, 16);
        let anchors = ndarray::Array2::from_shape_fn((np, 4), |(p, k)| [p as f32, 0.0, 1.0, 0.0][k]);
        let known = Known { values: values.view(), mask: mask.view(), anchors: Some(anchors.view()) };
        let sampler = socdiff_schedules::Ddim::new(&NoiseSchedule::default(), 10, 0.0).unwrap();
        /// The frames the network's calls took from the call before, summed.
        struct Reuse<'a>(&'a Denoiser, std::sync::atomic::AtomicUsize);
        impl X0Model for Reuse<'_> {
            fn feature_dims(&self) -> usize {
                self.0.feature_dims()
            }
            fn max_batch(&self, persons: usize, frames: usize) -> usize {
                self.0.max_batch(persons, frames)
            }
            fn predict_x0(&self, x: &[f32], shape: [usize; 4], t: &[usize], anchors: Option<&[f32]>, out: &mut [f32]) -> Result<()> {
                self.0.predict_x0(x, shape, t, anchors, out)?;
                self.1.fetch_add(self.0.reused_prefix_frames(), std::sync::atomic::Ordering::Relaxed);
                Ok(())
            }
        }
        for clean_known in [false, true] {
            let opts = InpaintOptions { samples: 3, seed: 4, clean_known, ..Default::default() };
            let a = inpaint(cpu.x0_model(), &sampler, &known, &opts).unwrap();
            let counted = Reuse(&composed, Default::default());
            let b = inpaint(&counted, &sampler, &known, &opts).unwrap();
            let d = (&a - &b).iter().fold(0f32, |m, v| m.max(v.abs()));
            assert!(d < 1e-4, "routes differ by {d} (clean known frames: {clean_known})");
            assert!(a.iter().any(|v| v.abs() > 0.1));
            // One sample per call, 10 calls each: the first computes the 16 known frames, the
            // next 8 take them, the last (every frame clean) has another prefix.
            assert_eq!(counted.1.into_inner(), if clean_known { 3 * 8 * 16 } else { 0 });
        }
    }

    /// A v-predicting model's sampling net gives x̂0 = √ᾱ_t·x − √(1 − ᾱ_t)·F (F the network's
    /// output, here from the composed candle network) for one step per scene or per frame, and
    /// its input gradient (context inversion) is that of the converted output: a central
    /// difference of Σ w·(x̂0 − target)² agrees.
    #[test]
    fn a_v_model_samples_from_its_converted_output() {
        use crate::diffusion::DiffusionConfig;
        use crate::model::{DenoiserConfig, Kernels, Placement, Precision};
        let cfg = DenoiserConfig { feature_dims: 3, hidden: 8, time_dim: 16, fourier_dim: 8, social_dim: 8, ..Default::default() };
        let net = Denoiser::new(cfg, 6).unwrap();
        let diffusion = GaussianDiffusion::new(&DiffusionConfig { prediction: Prediction::V, ..Default::default() }).unwrap();
        let v = SamplingNet::new(&net, &diffusion, &Device::Cpu).unwrap();
        let composed = net.to_placement(&Placement { kernels: Kernels::Composed(Precision::F32), ..Placement::cpu() }).unwrap().frozen();
        let shape = [2, 2, 12, 3];
        let n = shape.iter().product::<usize>();
        let x: Vec<f32> = (0..n).map(|i| (i as f32 * 0.37).sin()).collect();
        let ab = diffusion.schedule().alpha_bars();
        for t in [vec![3, 700], (0..2 * 2 * 12).map(|i| (i * 41) % 1000).collect::<Vec<usize>>()] {
            let (mut raw, mut got) = (vec![0f32; n], vec![0f32; n]);
            composed.predict_x0(&x, shape, &t, None, &mut raw).unwrap();
            v.predict_x0(&x, shape, &t, None, &mut got).unwrap();
            let per = n / t.len();
            for i in 0..n {
                let a = ab[t[i / per]];
                let want = a.sqrt() * x[i] as f64 - (1.0 - a).sqrt() * raw[i] as f64;
                assert!((got[i] as f64 - want).abs() < 1e-4, "element {i}: {} vs {want}", got[i]);
            }
        }
        let one = [1, 2, 12, 3];
        let m = one.iter().product::<usize>();
        let (x1, target) = (&x[..m], (0..m).map(|i| (i as f32 * 0.11).cos()).collect::<Vec<f32>>());
        let weight: Vec<f32> = (0..m).map(|i| if i % 3 == 0 { 0.0 } else { 1.0 }).collect();
        let t = 200;
        let g = v.input_gradient(x1, one, t, None, &target, &weight).unwrap().unwrap();
        let loss = |x: &[f32]| {
            let mut out = vec![0f32; m];
            v.predict_x0(x, one, &[t], None, &mut out).unwrap();
            out.iter().zip(&target).zip(&weight).map(|((o, tg), w)| (w * (o - tg)).powi(2) as f64).sum::<f64>()
        };
        for k in [0, 7, 31, 70] {
            let h = 1e-2;
            let (mut up, mut down) = (x1.to_vec(), x1.to_vec());
            up[k] += h;
            down[k] -= h;
            let fd = (loss(&up) - loss(&down)) / (2.0 * h as f64);
            assert!((g[k] as f64 - fd).abs() < 2e-2 * fd.abs().max(1.0), "∂/∂x[{k}]: {} vs {fd}", g[k]);
        }
    }

    /// Context inversion moves what the network is shown of the observed prefix so that its
    /// reading of the last frames gets closer to the observation, keeps the clean values in the
    /// output, and says so when the model cannot differentiate its input.
    #[test]
    fn context_inversion_reduces_the_reconstruction_error_of_the_prefix() {
        use crate::model::{DenoiserConfig, InferenceNet};
        let cfg = DenoiserConfig { feature_dims: 3, hidden: 8, time_dim: 16, fourier_dim: 8, social_dim: 8, ..Default::default() };
        let net = InferenceNet::new(&Denoiser::new(cfg.clone(), 2).unwrap()).unwrap();
        let (nt, np, nd, nobs) = (24, 2, 3, 16);
        let values = Array3::from_shape_fn((nt, np, nd), |(f, p, d)| ((f as f32) * 0.2 + p as f32 + d as f32 * 0.5).sin());
        let mask = forecast_mask(nt, np, nd, nobs);
        let mut canvas = Canvas { obs: vec![0f32; np * nt * nd], known: vec![], clean: vec![], clean_frames: vec![] };
        for p in 0..np {
            for f in 0..nobs {
                for d in 0..nd {
                    let k = (p * nt + f) * nd + d;
                    canvas.obs[k] = values[[f, p, d]];
                    canvas.known.push(k);
                }
            }
        }
        let inv = ContextInversion { steps: 1, lr: 0.05, frames: 4 };
        let mut pf = KnownPrefix::new(&canvas, [np, nt, nd], inv, false).unwrap();
        assert_eq!(pf.len, nobs);
        assert_eq!(pf.weight.iter().filter(|&&w| w > 0.0).count(), np * 4 * nd);
        let loss = |pf: &KnownPrefix| {
            let shown: Vec<f32> = pf.target.iter().zip(&pf.delta).map(|(a, b)| a + b).collect();
            let mut out = vec![0f32; shown.len()];
            net.predict_x0(&shown, [1, np, nobs, nd], &[10], None, &mut out).unwrap();
            out.iter().zip(&pf.target).zip(&pf.weight).map(|((o, t), w)| (w * (o - t) * (o - t)) as f64).sum::<f64>()
        };
        let before = loss(&pf);
        for _ in 0..20 {
            pf.invert(&net, 10, None).unwrap();
        }
        let after = loss(&pf);
        assert!(after < 0.5 * before, "{before} -> {after}");
        // Frames outside the matched window move too (they feed it), the shown prefix is
        // target + delta, and the output keeps the clean known values.
        assert!(pf.delta.iter().any(|&d| d != 0.0));
        let known = Known { values: values.view(), mask: mask.view(), anchors: None };
        let sampler = Ddim::new(&NoiseSchedule::default(), 3, 0.0).unwrap();
        let opts = InpaintOptions { samples: 1, conditioning: Conditioning::Replace, seed: 1, inversion: Some(inv), clean_known: false };
        let out = inpaint(&net, &sampler, &known, &opts).unwrap();
        for ((_, f, p, d), &v) in out.indexed_iter() {
            if f < nobs {
                assert_eq!(v, values[[f, p, d]]);
            }
        }
        let plain = inpaint(&net, &sampler, &known, &InpaintOptions { inversion: None, ..opts.clone() }).unwrap();
        assert_ne!(out, plain, "the forecast follows the shown prefix");
        let err = inpaint(&dummy(3), &sampler, &known, &opts).unwrap_err().to_string();
        assert!(err.contains("differentiate"), "{err}");
        // A lookahead network would read the forecast frames too: refused, it still inpaints.
        let ahead = InferenceNet::new(&Denoiser::new(DenoiserConfig { causality: crate::model::Causality::Lookahead, ..cfg }, 2).unwrap()).unwrap();
        let err = inpaint(&ahead, &sampler, &known, &opts).unwrap_err().to_string();
        assert!(err.contains("needs a causal model") && err.contains("30 frames ahead"), "{err}");
        assert!(inpaint(&ahead, &sampler, &known, &InpaintOptions { inversion: None, ..opts.clone() }).is_ok());
        // One sample per call: later batches replay the first batch's offsets, so every sample
        // is the same as when all are denoised together.
        struct OnePerCall<'a>(&'a InferenceNet);
        impl X0Model for OnePerCall<'_> {
            fn feature_dims(&self) -> usize {
                self.0.feature_dims()
            }
            fn max_batch(&self, _persons: usize, _frames: usize) -> usize {
                1
            }
            fn predict_x0(&self, x: &[f32], shape: [usize; 4], t: &[usize], anchors: Option<&[f32]>, out: &mut [f32]) -> Result<()> {
                self.0.predict_x0(x, shape, t, anchors, out)
            }
            fn input_gradient(
                &self,
                x: &[f32],
                shape: [usize; 4],
                t: usize,
                anchors: Option<&[f32]>,
                target: &[f32],
                weight: &[f32],
            ) -> Result<Option<Vec<f32>>> {
                self.0.input_gradient(x, shape, t, anchors, target, weight)
            }
        }
        let three = InpaintOptions { samples: 3, ..opts.clone() };
        assert_eq!(inpaint(&OnePerCall(&net), &sampler, &known, &three).unwrap(), inpaint(&net, &sampler, &known, &three).unwrap());
    }

    fn canvas() -> (Array3<f32>, Array3<bool>) {
        let (t, p, d) = (9, 2, 3);
        let values = Array3::from_shape_fn((t, p, d), |(f, q, k)| f as f32 * 0.1 - q as f32 + k as f32 * 0.01);
        let mut mask = forecast_mask(t, p, d, 4);
        mask[[6, 1, 2]] = true; // a single known entry in the future
        (values, mask)
    }

    #[test]
    fn replace_keeps_known_entries_at_every_step_and_is_reproducible() {
        let (values, mask) = canvas();
        let anchors = Array2::from_shape_fn((2, 4), |(p, k)| (p * 4 + k) as f32);
        let known = Known { values: values.view(), mask: mask.view(), anchors: Some(anchors.view()) };
        let sampler = Ddim::new(&NoiseSchedule::default(), 10, 0.5).unwrap();
        let model = dummy(3);
        let opts = InpaintOptions { samples: 2, conditioning: Conditioning::Replace, seed: 7, inversion: None, clean_known: false };
        let out = inpaint(&model, &sampler, &known, &opts).unwrap();
        assert_eq!(out.dim(), (2, 9, 2, 3));
        // The model saw the clean known values at every step, and the sampler's timesteps.
        let seen = model.seen.borrow();
        assert_eq!(seen.len(), 10);
        for (i, (x, t)) in seen.iter().enumerate() {
            assert_eq!(t, &vec![sampler.timesteps()[i]; 2]);
            for s in 0..2 {
                for (f, p, d) in [(0, 0, 0), (3, 1, 2), (6, 1, 2)] {
                    assert_eq!(x[s * 54 + (p * 9 + f) * 3 + d], values[[f, p, d]], "step {i}");
                }
            }
        }
        for ((s, f, p, d), &v) in out.indexed_iter() {
            if mask[[f, p, d]] {
                assert_eq!(v, values[[f, p, d]], "sample {s}");
            }
        }
        // The sum of the output against an independent f64 DDIM.
        let sum: f64 = out.iter().map(|&v| v as f64).sum();
        let want = reference_replace_sum(&values, &mask, 10, 0.5, 7, 2);
        assert!((sum - want).abs() < 1e-4, "sum {sum} vs {want}");
        // Same seed → same bits; another seed → different unknown entries.
        let again = inpaint(&dummy(3), &sampler, &known, &opts).unwrap();
        assert_eq!(again, out);
        let other = inpaint(&dummy(3), &sampler, &known, &InpaintOptions { seed: 8, ..opts.clone() }).unwrap();
        assert_ne!(other, out);
        // The two samples of one batch differ.
        assert_ne!(out.index_axis(ndarray::Axis(0), 0), out.index_axis(ndarray::Axis(0), 1));
    }

    #[test]
    fn deterministic_ddim_ends_at_the_model_prediction() {
        // η = 0: the last DDIM step returns x̂0, so with x̂0 = 0.5·x + c the unknown entries end at
        // 0.5·x_prev + c for the canvas x_prev of the last step.
        let (values, mask) = canvas();
        let known = Known { values: values.view(), mask: mask.view(), anchors: None };
        let sampler = Ddim::new(&NoiseSchedule::default(), 5, 0.0).unwrap();
        let model = dummy(3);
        let out = inpaint(&model, &sampler, &known, &InpaintOptions::default()).unwrap();
        let seen = model.seen.borrow();
        let last = &seen.last().unwrap().0;
        for ((_, f, p, d), &v) in out.indexed_iter() {
            if !mask[[f, p, d]] {
                let want = 0.5 * last[(p * 9 + f) * 3 + d] + 0.1 * (d as f32 + 1.0);
                assert!((v - want).abs() < 1e-6);
            }
        }
    }

    /// Noised conditioning: at step i + 1 the model sees every known entry at the level of that
    /// step, √ᾱ·x + √(1 − ᾱ)·z, with z the sample's seeded normals drawn in canvas order after
    /// the first canvas (DDIM η = 0 draws nothing else); ᾱ from the cosine formula itself,
    /// ᾱ_t = f(t + 1)/f(0), f(u) = cos²((u/T + s)/(1 + s)·π/2). The result holds them exactly.
    #[test]
    fn noised_conditioning_noises_known_entries_until_the_end() {
        let (values, mask) = canvas();
        let (nt, np, nd) = values.dim();
        let known = Known { values: values.view(), mask: mask.view(), anchors: None };
        let sampler = Ddim::new(&NoiseSchedule::default(), 5, 0.0).unwrap();
        let model = dummy(3);
        let opts = InpaintOptions { samples: 1, conditioning: Conditioning::Noised, seed: 3, inversion: None, clean_known: false };
        let out = inpaint(&model, &sampler, &known, &opts).unwrap();
        let seen = model.seen.borrow();
        let f = |u: f64| (((u / 1000.0) + 0.008) / 1.008 * std::f64::consts::FRAC_PI_2).cos().powi(2);
        // Known entries in canvas order [person, frame, dim].
        let idx: Vec<(usize, (usize, usize, usize))> =
            (0..np).flat_map(|p| (0..nt).flat_map(move |t| (0..nd).map(move |d| (t, p, d)))).enumerate().filter(|(_, (t, p, d))| mask[[*t, *p, *d]]).collect();
        let mut rng = StdRng::seed_from_u64(sample_seed(3, 0));
        let _first_canvas = standard_normal(&mut rng, nt * np * nd);
        for i in 0..sampler.timesteps().len() - 1 {
            let z = standard_normal(&mut rng, idx.len());
            let t = sampler.timesteps()[i + 1];
            let ab = f(t as f64 + 1.0) / f(0.0);
            for ((k, (ft, p, d)), zk) in idx.iter().zip(&z) {
                let want = ab.sqrt() * values[[*ft, *p, *d]] as f64 + (1.0 - ab).sqrt() * *zk as f64;
                let got = seen[i + 1].0[*k] as f64;
                assert!((got - want).abs() < 1e-5, "step {i}, entry {k}: {got} vs {want}");
            }
        }
        for ((_, f, p, d), &v) in out.indexed_iter() {
            if mask[[f, p, d]] {
                assert_eq!(v, values[[f, p, d]]);
            }
        }
    }

    /// With `clean_known`, the model sees level 0 on the whole known person-frames (frames 0–3
    /// of both persons) and the sampler's level elsewhere — also on frame 6 of person 1, known in
    /// one dim only — and those frames stay clean at every step, even with noised conditioning.
    #[test]
    fn clean_known_frames_get_level_zero_and_stay_clean() {
        let (values, mask) = canvas();
        let (nt, np, nd) = values.dim();
        let known = Known { values: values.view(), mask: mask.view(), anchors: None };
        let sampler = Ddim::new(&NoiseSchedule::default(), 5, 0.0).unwrap();
        let model = dummy(3);
        let opts = InpaintOptions { samples: 2, conditioning: Conditioning::Noised, seed: 3, inversion: None, clean_known: true };
        inpaint(&model, &sampler, &known, &opts).unwrap();
        let seen = model.seen.borrow();
        assert_eq!(seen.len(), 5);
        for (call, (x, t)) in seen.iter().enumerate() {
            let step = sampler.timesteps()[call];
            assert_eq!(t.len(), 2 * np * nt, "one level per sample, person and frame");
            for s in 0..2 {
                for p in 0..np {
                    for f in 0..nt {
                        let want = if f < 4 { 0 } else { step };
                        assert_eq!(t[(s * np + p) * nt + f], want, "call {call}, sample {s}, person {p}, frame {f}");
                        for d in 0..nd {
                            let v = x[((s * np + p) * nt + f) * nd + d];
                            if f < 4 {
                                assert_eq!(v, values[[f, p, d]], "a clean frame was changed");
                            }
                        }
                    }
                }
            }
            // The partly known frame follows the noised conditioning after the first step.
            if call > 0 {
                assert_ne!(x[((np + 1) * nt + 6) * nd + 2], values[[6, 1, 2]]);
            }
        }
        // Off: one level per sample, as the paper.
        let model = dummy(3);
        inpaint(&model, &sampler, &known, &InpaintOptions { clean_known: false, ..opts }).unwrap();
        assert!(model.seen.borrow().iter().all(|(_, t)| t.len() == 2));
    }

    /// Sample s is the same bit for bit whatever the number of samples and the batch size,
    /// for DDPM (noise every step) and noised conditioning (noise for the known entries).
    #[test]
    fn sample_s_does_not_depend_on_the_number_of_samples_or_the_batch() {
        let (values, mask) = canvas();
        let known = Known { values: values.view(), mask: mask.view(), anchors: None };
        let sampler = Ddpm::truncated(&NoiseSchedule::default(), 12).unwrap();
        for conditioning in [Conditioning::Replace, Conditioning::Noised] {
            let opts = |samples| InpaintOptions { samples, conditioning, seed: 5, inversion: None, clean_known: false };
            let all = inpaint(&dummy(3), &sampler, &known, &opts(5)).unwrap();
            let one_by_one = inpaint(&Dummy { batch: 1, ..dummy(3) }, &sampler, &known, &opts(5)).unwrap();
            let pairs = Dummy { batch: 2, ..dummy(3) };
            let in_pairs = inpaint(&pairs, &sampler, &known, &opts(5)).unwrap();
            assert_eq!(pairs.seen.borrow().len(), 3 * 12, "5 samples in batches of 2: 3 batches × 12 steps");
            let first_two = inpaint(&dummy(3), &sampler, &known, &opts(2)).unwrap();
            assert_eq!(all, one_by_one);
            assert_eq!(all, in_pairs);
            assert_eq!(all.slice(ndarray::s![..2, .., .., ..]), first_two);
            assert_ne!(all.index_axis(ndarray::Axis(0), 3), all.index_axis(ndarray::Axis(0), 4));
        }
        let mut calls = vec![];
        inpaint_with_progress(&Dummy { batch: 2, ..dummy(3) }, &sampler, &known, &InpaintOptions { samples: 3, ..Default::default() }, &mut |i| {
            calls.push((i.samples, i.step, i.steps))
        })
        .unwrap();
        assert_eq!(calls.len(), 24);
        assert_eq!(calls[0], (0..2, 0, 12));
        assert_eq!(calls[23], (2..3, 11, 12));
        assert_ne!(sample_seed(1, 0), sample_seed(1, 1));
        assert_ne!(sample_seed(1, 0), sample_seed(2, 0));
    }

    #[test]
    fn bad_inputs_are_errors() {
        let (values, mask) = canvas();
        let sampler = Ddim::new(&NoiseSchedule::default(), 3, 0.0).unwrap();
        let model = dummy(3);
        let err = |k: &Known, o: &InpaintOptions| inpaint(&model, &sampler, k, o).unwrap_err().to_string();
        let opts = InpaintOptions::default();
        let small = Array3::from_elem((9, 2, 2), false);
        assert!(err(&Known { values: values.view(), mask: small.view(), anchors: None }, &opts).contains("differ in shape"));
        let wide = Array3::zeros((9, 2, 4));
        let wmask = Array3::from_elem((9, 2, 4), false);
        assert!(err(&Known { values: wide.view(), mask: wmask.view(), anchors: None }, &opts).contains("4 feature dims"));
        let anchors = Array2::zeros((3, 4));
        assert!(err(&Known { values: values.view(), mask: mask.view(), anchors: Some(anchors.view()) }, &opts).contains("anchors"));
        let known = Known { values: values.view(), mask: mask.view(), anchors: None };
        assert!(err(&known, &InpaintOptions { samples: 0, ..opts.clone() }).contains("samples"));
        let mut nan = values.clone();
        nan[[2, 1, 0]] = f32::NAN;
        assert!(err(&Known { values: nan.view(), mask: mask.view(), anchors: None }, &opts).contains("person 1, frame 2, dim 0"));
    }

    /// The output sum of `replace_keeps_known_entries_…` computed independently: DDIM written
    /// out in f64 from its paper form (ε̂ from x̂0, σ from η, x_prev), ᾱ from the cosine
    /// formula with β clipped at 0.999, the same seeded normals (sample s: StdRng(sample_seed(7,
    /// s)), the first canvas, then one draw per step with σ > 0), known entries replaced.
    fn reference_replace_sum(values: &Array3<f32>, mask: &Array3<bool>, steps: usize, eta: f64, seed: u64, samples: usize) -> f64 {
        let (nt, np, nd) = values.dim();
        let per = nt * np * nd;
        let f = |u: f64| (((u / 1000.0) + 0.008) / 1.008 * std::f64::consts::FRAC_PI_2).cos().powi(2);
        let mut ab = Vec::with_capacity(1000);
        let mut prod = 1.0;
        for t in 0..1000 {
            prod *= 1.0 - (1.0 - f(t as f64 + 1.0) / f(t as f64)).min(0.999);
            ab.push(prod);
        }
        let ts: Vec<usize> = (0..steps).rev().map(|j| (2 * j * 999 + steps - 1) / (2 * (steps - 1))).collect();
        // Canvas order [person, frame, dim].
        let at = |k: usize| (k / nd % nt, k / (nd * nt), k % nd);
        let impose = |x: &mut [f64]| {
            for (k, v) in x.iter_mut().enumerate() {
                let (t, p, d) = at(k);
                if mask[[t, p, d]] {
                    *v = values[[t, p, d]] as f64;
                }
            }
        };
        let mut sum = 0.0;
        for smp in 0..samples {
            let mut rng = StdRng::seed_from_u64(sample_seed(seed, smp));
            let mut x: Vec<f64> = standard_normal(&mut rng, per).into_iter().map(f64::from).collect();
            impose(&mut x);
            for (i, &t) in ts.iter().enumerate() {
                let (a, a_prev) = (ab[t], if i + 1 < ts.len() { ab[ts[i + 1]] } else { 1.0 });
                let sigma = eta * ((1.0 - a_prev) / (1.0 - a)).sqrt() * (1.0 - a / a_prev).sqrt();
                let z: Vec<f64> = if sigma > 0.0 { standard_normal(&mut rng, per).into_iter().map(f64::from).collect() } else { vec![0.0; per] };
                for (k, v) in x.iter_mut().enumerate() {
                    let x0 = 0.5 * *v + 0.1 * (at(k).2 as f64 + 1.0);
                    let eps = (*v - a.sqrt() * x0) / (1.0 - a).sqrt();
                    *v = a_prev.sqrt() * x0 + (1.0 - a_prev - sigma * sigma).max(0.0).sqrt() * eps + sigma * z[k];
                }
                impose(&mut x);
            }
            sum += x.iter().sum::<f64>();
        }
        sum
    }
}
