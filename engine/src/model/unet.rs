//! The denoiser g(x_t, t) → x̂0: a per-person causal temporal-conv U-Net with a social
//! aggregator at its bottleneck (METHOD.md §3).
//!
//! ```text
//! x [B·P, T', δ] ─ proj 1×1 ─ x0 [T', H] ─ down1 ─ d1 [T'/2, 2H] ─ down2 ─ d2 [T'/4, 2H]
//!   ─ down3 ─ d3 [T'/8, 2H] ─ res1 ─ h1 ─ social Γ (+ merge 1×1) ─ h2 [T'/8, 2H]
//! up3(cat[h2, d3]) → u3 [T'/4, 2H]; up2(cat[u3, d2]) → u2 [T'/2, 2H];
//! up1(cat[u2, d1]) → u1 [T', H]; final_res(cat[u1, x0]) [T', H] ─ to_pose 1×1 ─ [T', δ]
//! ```
//!
//! `T'` is T rounded up to a multiple of 8 by zero frames at the *end*, which the output drops.
//! Down block = causal conv k3 stride 2 → residual block. Up block = causal conv k3 → causal ×2
//! upsampling ([`super::ops::causal_upsample2x`]) → residual block. Residual block =
//! conv k3 → SiLU → LayerNorm → conv k3, FiLM `h·(1 + scale) + shift` with
//! `(scale, shift) = Linear(SiLU(temb))`, plus the input (1×1-projected when widths differ).
//! The `cat[·, ·]` inputs are never stored: the convs that read them take the two parts
//! ([`super::ops::causal_conv1d_cat`], with the up block's upsampling fused in), and the second
//! conv of a residual block normalizes its own input ([`super::ops::silu_layer_norm_conv1d`]),
//! so the graph keeps fewer activations for the backward pass.
//!
//! # Causality
//! A sample at level ℓ (length T'/2^ℓ) with index o only depends on input frames `≤ 2^ℓ·o`:
//! stride-1 convs at a level are causal in that level's index, a stride-2 conv's output o reads
//! level-ℓ samples `≤ 2o`, and the upsampling gives fine sample q coarse samples `≤ ⌊q/2⌋`
//! (`2^{ℓ+1}⌊q/2⌋ ≤ 2^ℓ q`). The aggregator works frame by frame. So output frame t never
//! depends on input frames after t, for every person (tested below).
//!
//! With [`Causality::Lookahead`] each residual block's first conv is centred instead: it reads
//! one sample of its level ahead, `2^ℓ` input frames. Every level has two residual blocks on
//! the path from input to output, so output frame t depends on input frames
//! `≤ t + 2·(1 + 2 + 4 + 8) = t + 30` ([`super::config::LOOKAHEAD_FRAMES`]; reached for t a
//! multiple of 8, tested below). The zero frames that pad T up to T' are then seen by the
//! last frames' outputs.

use super::aggregator::{relative_anchors, Social};
use super::config::{Causality, DenoiserConfig, Placement};
use super::dispatch::Kernels;
use super::layers::{join, Conv, ConvInput, LayerNorm, Linear, ParamInit};
use crate::model::Parameterized;
use crate::{bail, Result};
use candle_core::{DType, Device, Tensor, Var};
use std::collections::BTreeMap;

/// Temporal down-sampling factor of the U-Net (three stride-2 levels).
pub const TIME_FACTOR: usize = 8;

/// Sinusoidal timestep features → Linear → GELU → Linear.
#[derive(Clone)]
struct TimeEmbedding {
    lin1: Linear,
    lin2: Linear,
    fourier_dim: usize,
    max_period: f64,
}

impl TimeEmbedding {
    fn new(init: &mut ParamInit, prefix: &str, cfg: &DenoiserConfig) -> Result<Self> {
        Ok(Self {
            lin1: Linear::new(init, &join(prefix, "lin1"), cfg.fourier_dim, cfg.time_dim, true)?,
            lin2: Linear::new(init, &join(prefix, "lin2"), cfg.time_dim, cfg.time_dim, true)?,
            fourier_dim: cfg.fourier_dim,
            max_period: cfg.fourier_max_period,
        })
    }

    /// `[sin(t·f_k) (half) | cos(t·f_k) (half)]`, `f_k = exp(−k·ln(max_period)/(half − 1))`.
    ///
    /// # Shapes
    /// - returns `[B, fourier_dim]` for `B = t.len()`
    fn sinusoidal(&self, t: &[f64], dtype: DType, device: &Device) -> Result<Tensor> {
        let half = self.fourier_dim / 2;
        let mut v = Vec::with_capacity(t.len() * self.fourier_dim);
        for &ti in t {
            let f = |k: usize| (-(k as f64) * self.max_period.ln() / (half - 1) as f64).exp();
            v.extend((0..half).map(|k| (ti * f(k)).sin()));
            v.extend((0..half).map(|k| (ti * f(k)).cos()));
        }
        Ok(Tensor::from_vec(v, (t.len(), self.fourier_dim), device)?.to_dtype(dtype)?)
    }

    /// # Shapes
    /// - `t`: B diffusion steps; returns `[B, time_dim]`
    fn forward(&self, t: &[f64], dtype: DType, device: &Device) -> Result<Tensor> {
        let x = self.sinusoidal(t, dtype, device)?;
        self.lin2.forward(&self.lin1.forward(&x)?.gelu_erf()?)
    }

    fn detached(&self) -> Self {
        Self { lin1: self.lin1.detached(), lin2: self.lin2.detached(), ..self.clone() }
    }
}

/// conv k3 → SiLU → LayerNorm → conv k3, FiLM from the timestep, plus the (projected) input.
#[derive(Clone)]
struct ResBlock {
    conv1: Conv,
    /// [`Causality::Lookahead`]: `conv1` is centred (reads the sample after its output too).
    centred: bool,
    norm: LayerNorm,
    conv2: Conv,
    film: Linear,
    proj: Option<Conv>,
    kernels: Kernels,
}

impl ResBlock {
    fn new(init: &mut ParamInit, prefix: &str, din: usize, dout: usize, cfg: &DenoiserConfig) -> Result<Self> {
        Ok(Self {
            conv1: Conv::new(init, &join(prefix, "conv1"), din, dout, 3, 1)?,
            centred: cfg.causality == Causality::Lookahead,
            norm: LayerNorm::new(init, &join(prefix, "norm"), dout, cfg.ln_eps)?,
            conv2: Conv::new(init, &join(prefix, "conv2"), dout, dout, 3, 1)?,
            film: Linear::new(init, &join(prefix, "film"), cfg.time_dim, 2 * dout, true)?,
            proj: if din != dout { Some(Conv::new(init, &join(prefix, "proj"), din, dout, 1, 1)?) } else { None },
            kernels: init.kernels(),
        })
    }

    /// # Shapes
    /// - `x`: `[B·P, T, C_in]` at U-Net level `level`, `cond`: the noise levels' embedding (see
    ///   [`Cond`])
    /// - returns `[B·P, T, C_out]`
    fn forward(&self, x: &Tensor, cond: &Cond, prefix: &mut Prefix, level: usize) -> Result<Tensor> {
        self.forward_input(ConvInput::One(x), cond, prefix, level)
    }

    /// [`ResBlock::forward`] of one input or of two side by side (then `C_in` is the sum of
    /// their channels, and the block has a projection).
    fn forward_input(&self, x: ConvInput, cond: &Cond, prefix: &mut Prefix, level: usize) -> Result<Tensor> {
        let h = if self.centred {
            self.conv1.forward_centred(x)?
        } else {
            // Each k3 conv reads the two rows before its first output.
            let (h, kept) = match x {
                ConvInput::One(a) => {
                    let (a, kept) = prefix.context(a, level, 2)?;
                    (self.conv1.forward(&a)?, kept)
                }
                ConvInput::Cat(a, b) => {
                    let ((a, kept), (b, _)) = (prefix.context(a, level, 2)?, prefix.context(b, level, 2)?);
                    (self.conv1.forward_input(ConvInput::Cat(&a, &b))?, kept)
                }
            };
            drop_rows(h, kept)?
        };
        let (h, kept) = prefix.context(&h, level, 2)?;
        let h = drop_rows(self.conv2.forward_normed(&h, &self.norm)?, kept)?;
        let skip = match (&self.proj, x) {
            (Some(p), x) => p.forward_input(x)?,
            (None, ConvInput::One(x)) => x.clone(),
            (None, ConvInput::Cat(..)) => bail!("residual block: two inputs need a projection"),
        };
        // FiLM rows, each shared by a group of consecutive rows of h: one per scene, or one per
        // (sequence, frame) of this level (the FiLM of each distinct level, gathered).
        let film = match cond {
            Cond::Scene(temb) => self.film.forward(temb)?,
            Cond::Frames { temb, rows } => self.film.forward(temb)?.index_select(&rows[level], 0)?,
        };
        Ok(self.kernels.film_residual(&h, &film, &skip)?)
    }

    fn detached(&self) -> Self {
        Self {
            conv1: self.conv1.detached(),
            centred: self.centred,
            norm: self.norm.detached(),
            conv2: self.conv2.detached(),
            film: self.film.detached(),
            proj: self.proj.as_ref().map(Conv::detached),
            kernels: self.kernels,
        }
    }
}

/// Causal conv k3 stride 2 → residual block.
#[derive(Clone)]
struct Down {
    conv: Conv,
    res: ResBlock,
}

impl Down {
    fn new(init: &mut ParamInit, prefix: &str, din: usize, dout: usize, cfg: &DenoiserConfig) -> Result<Self> {
        Ok(Self { conv: Conv::new(init, &join(prefix, "conv"), din, dout, 3, 2)?, res: ResBlock::new(init, &join(prefix, "res"), dout, dout, cfg)? })
    }

    /// # Shapes
    /// - `x`: `[B·P, T, C_in]` (T even) at level `level`; returns `[B·P, T/2, C_out]`
    fn forward(&self, x: &Tensor, cond: &Cond, prefix: &mut Prefix, level: usize) -> Result<Tensor> {
        // Output o reads rows 2o − 2 … 2o: two kept rows are one output to drop.
        let (x, kept) = prefix.context(x, level, 2)?;
        let h = drop_rows(self.conv.forward(&x)?, kept / 2)?;
        self.res.forward(&h, cond, prefix, level + 1)
    }

    fn detached(&self) -> Self {
        Self { conv: self.conv.detached(), res: self.res.detached() }
    }
}

/// Causal conv k3 (of the input and the encoder's skip side by side) → causal ×2 upsampling →
/// residual block.
#[derive(Clone)]
struct Up {
    conv: Conv,
    res: ResBlock,
}

impl Up {
    fn new(init: &mut ParamInit, prefix: &str, din: usize, dout: usize, cfg: &DenoiserConfig) -> Result<Self> {
        Ok(Self { conv: Conv::new(init, &join(prefix, "conv"), din, dout, 3, 1)?, res: ResBlock::new(init, &join(prefix, "res"), dout, dout, cfg)? })
    }

    /// The block on `x` and the encoder's `skip` side by side.
    ///
    /// # Shapes
    /// - `x`: `[B·P, T, C_x]`, `skip`: `[B·P, T, C_skip]` (C_x + C_skip = C_in) at level
    ///   `level`; returns `[B·P, 2T, C_out]`
    fn forward(&self, x: &Tensor, skip: &Tensor, cond: &Cond, prefix: &mut Prefix, level: usize) -> Result<Tensor> {
        // The first fine row after the kept ones reads the conv's output one coarse row before,
        // which reads two more: four kept rows (an even count keeps the Winograd tiles aligned).
        let ((x, kept), (skip, _)) = (prefix.context(x, level, 4)?, prefix.context(skip, level, 4)?);
        let h = drop_rows(self.conv.forward_cat_upsampled(&x, &skip)?, 2 * kept)?;
        self.res.forward(&h, cond, prefix, level - 1)
    }

    fn detached(&self) -> Self {
        Self { conv: self.conv.detached(), res: self.res.detached() }
    }
}

/// The noise-level conditioning of the residual blocks.
enum Cond {
    /// One level per scene: the embedding `[B, time_dim]` (after SiLU).
    Scene(Tensor),
    /// One level per person and frame: the embeddings of the distinct levels `[U, time_dim]`
    /// (after SiLU) and, for each U-Net level ℓ = 0..=3, which of them each row
    /// `(sequence, r)` computed uses, `[B·P · rows at ℓ]` (u32): the level of input frame
    /// `2^ℓ·r` (the first frame that row may depend on, so causality holds for levels too;
    /// padded frames take the last real frame's level).
    Frames { temb: Tensor, rows: Vec<Tensor> },
}

/// Noise levels of a forward pass, as given: one per scene or one per person and frame.
pub(crate) enum Levels {
    /// `[B]`.
    Scene(Vec<f64>),
    /// `[B, P, T]` flattened.
    Frames(Vec<f64>),
}

impl Levels {
    /// Reads `t` of shape `[B]` or `[B, P, T]` (any numeric dtype).
    pub(crate) fn of(t: &Tensor, [b, p, frames]: [usize; 3]) -> Result<Self> {
        let v = t.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?;
        if let Some(bad) = v.iter().find(|x| !x.is_finite() || **x < 0.0) {
            bail!("denoiser: noise level {bad} is not a finite non-negative number");
        }
        match t.dims() {
            [x] if *x == b => Ok(Levels::Scene(v)),
            [x, y, z] if (*x, *y, *z) == (b, p, frames) => Ok(Levels::Frames(v)),
            dims => bail!("denoiser: timesteps have shape {dims:?}, expected [{b}] (one level per scene) or [{b}, {p}, {frames}] (one per person and frame)"),
        }
    }
}

/// The distinct values of `levels` (sorted) and, for every U-Net level ℓ = 0..=3, the index of
/// the value each row `(sequence, r)` uses: that of frame `min(2^ℓ·r, frames − 1)`.
pub(crate) fn level_rows(levels: &[f64], sequences: usize, frames: usize, padded: usize) -> (Vec<f64>, Vec<Vec<u32>>) {
    let mut uniq: Vec<f64> = levels.to_vec();
    uniq.sort_by(f64::total_cmp);
    uniq.dedup();
    let find = |v: f64| uniq.binary_search_by(|u| u.total_cmp(&v)).expect("a level of the list") as u32;
    let per_frame: Vec<u32> = levels.iter().map(|&v| find(v)).collect();
    let rows = (0..4)
        .map(|l| {
            let len = padded >> l;
            (0..sequences).flat_map(|n| (0..len).map(move |r| (n, (r << l).min(frames - 1)))).map(|(n, f)| per_frame[n * frames + f]).collect()
        })
        .collect();
    (uniq, rows)
}

/// Intermediate tensors of one forward pass, channels last, for tests and inspection.
#[derive(Clone, Debug)]
pub struct Trace {
    /// Input projection, `[B·P, T', H]`.
    pub x0: Tensor,
    /// Encoder levels 1–3, `[B·P, T'/2^ℓ, 2H]`.
    pub down: [Tensor; 3],
    /// Bottleneck residual block output, `[B·P, T'/8, 2H]`.
    pub mid: Tensor,
    /// After the aggregator and merge (equal to `mid` for `none`), `[B·P, T'/8, 2H]`.
    pub social: Tensor,
    /// Decoder levels u3, u2, u1: `[B·P, T'/4, 2H]`, `[B·P, T'/2, 2H]`, `[B·P, T', H]`.
    pub up: [Tensor; 3],
}

/// The denoiser network g(x_t, t, anchors) → x̂0 (METHOD.md §3).
///
/// Parameters live in [`Var`]s named like a PyTorch state dict (`down1.res.conv1.weight`, …);
/// conv weights are stored `[K, C_in, C_out]` and linear weights `[1, in, out]` (channels-last
/// friendly). [`Denoiser::named_vars`] lists them sorted by name.
#[derive(Clone)]
pub struct Denoiser {
    cfg: DenoiserConfig,
    dtype: DType,
    device: Device,
    kernels: Kernels,
    vars: BTreeMap<String, Var>,
    time_mlp: TimeEmbedding,
    proj: Conv,
    down: [Down; 3],
    res1: ResBlock,
    social: Option<Social>,
    up3: Up,
    up2: Up,
    up1: Up,
    final_res: ResBlock,
    to_pose: Conv,
    prefix_cache: PrefixCache,
}

impl Denoiser {
    /// A network with f32 parameters on the CPU, initialized from `seed` (PyTorch-style
    /// uniform ±1/√fan_in for convs and linears, LayerNorm γ = 1, β = 0).
    pub fn new(cfg: DenoiserConfig, seed: u64) -> Result<Self> {
        Self::build(cfg, seed, &Placement::cpu())
    }

    /// As [`Denoiser::new`] with parameters of `dtype` (f32 or f64; f64 for gradient checks).
    pub fn with_dtype(cfg: DenoiserConfig, seed: u64, dtype: DType) -> Result<Self> {
        Self::build(cfg, seed, &Placement::cpu().with_dtype(dtype))
    }

    /// As [`Denoiser::new`] at `placement`: a seed gives the same parameters on every device
    /// (drawn and cast on the host, then moved).
    pub fn build(cfg: DenoiserConfig, seed: u64, placement: &Placement) -> Result<Self> {
        cfg.validate()?;
        let dtype = placement.dtype;
        if !matches!(dtype, DType::F32 | DType::F64) {
            bail!("denoiser: dtype {dtype:?} is not supported (f32 or f64)");
        }
        let device = placement.device.clone();
        let mut params = ParamInit::new(seed, dtype, device.clone()).with_kernels(placement.kernels)?;
        let kernels = params.kernels();
        let init = &mut params;
        let (h, w, d) = (cfg.hidden, 2 * cfg.hidden, cfg.feature_dims);
        let time_mlp = TimeEmbedding::new(init, "time_mlp", &cfg)?;
        let proj = Conv::new(init, "proj", d, h, 1, 1)?;
        let down = [Down::new(init, "down1", h, w, &cfg)?, Down::new(init, "down2", w, w, &cfg)?, Down::new(init, "down3", w, w, &cfg)?];
        let res1 = ResBlock::new(init, "res1", w, w, &cfg)?;
        let social = Social::new(init, "social", &cfg, w)?;
        let up3 = Up::new(init, "up3", 2 * w, w, &cfg)?;
        let up2 = Up::new(init, "up2", 2 * w, w, &cfg)?;
        let up1 = Up::new(init, "up1", 2 * w, h, &cfg)?;
        let final_res = ResBlock::new(init, "final_res", 2 * h, h, &cfg)?;
        let to_pose = Conv::new(init, "to_pose", h, d, 1, 1)?;
        Ok(Self {
            cfg,
            dtype,
            device,
            kernels,
            vars: params.finish(),
            time_mlp,
            proj,
            down,
            res1,
            social,
            up3,
            up2,
            up1,
            final_res,
            to_pose,
            prefix_cache: PrefixCache::default(),
        })
    }

    /// A network of the same configuration at `placement` holding these parameters' values
    /// (cast to its dtype): how a checkpoint moves to a GPU and back.
    pub fn to_placement(&self, placement: &Placement) -> Result<Self> {
        let net = Self::build(self.cfg.clone(), 0, placement)?;
        for ((_, to), (_, from)) in net.named_vars().iter().zip(self.named_vars()) {
            to.set(&from.as_tensor().to_device(&placement.device)?.to_dtype(placement.dtype)?)?;
        }
        Ok(net)
    }

    /// Where the parameters live and which kernels run.
    pub fn placement(&self) -> Placement {
        Placement { device: self.device.clone(), dtype: self.dtype, kernels: self.kernels }
    }

    /// The device of the parameters.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// The configuration the network was built from.
    pub fn config(&self) -> &DenoiserConfig {
        &self.cfg
    }

    /// Parameter dtype.
    pub fn dtype(&self) -> DType {
        self.dtype
    }

    /// A copy whose forward builds no autograd graph (for sampling). It shares the parameter
    /// storage, so later updates of the [`Var`]s (e.g. by an optimizer) are seen by the copy.
    pub fn frozen(&self) -> Self {
        Self {
            cfg: self.cfg.clone(),
            dtype: self.dtype,
            device: self.device.clone(),
            kernels: self.kernels,
            vars: self.vars.clone(),
            time_mlp: self.time_mlp.detached(),
            proj: self.proj.detached(),
            down: [self.down[0].detached(), self.down[1].detached(), self.down[2].detached()],
            res1: self.res1.detached(),
            social: self.social.as_ref().map(Social::detached),
            up3: self.up3.detached(),
            up2: self.up2.detached(),
            up1: self.up1.detached(),
            final_res: self.final_res.detached(),
            to_pose: self.to_pose.detached(),
            prefix_cache: PrefixCache::default(),
        }
    }

    /// x̂0 = g(x_t, t) for every person of every scene of the batch.
    ///
    /// `x` holds each person's anchored, standardized features; `t` the diffusion step of each
    /// scene (any numeric dtype); `anchors` optionally each person's anchor
    /// `(r_x, r_y, cos h, sin h)` in a frame shared by the scene, which the aggregator uses to
    /// know where the others are (see [`super::aggregator`]).
    ///
    /// # Shapes
    /// - `x`: `[B, P, T, δ]` (any P ≥ 1, any T ≥ 1), dtype of the network
    /// - `t`: `[B]` (one noise level per scene) or `[B, P, T]` (one per person and frame: FiLM
    ///   per frame; output frame f depends on the levels of frames ≤ f only)
    /// - `anchors`: `[B, P, 4]`
    /// - returns `[B, P, T, δ]`
    pub fn forward(&self, x: &Tensor, t: &Tensor, anchors: Option<&Tensor>) -> Result<Tensor> {
        Ok(self.forward_traced(x, t, anchors)?.0)
    }

    /// [`Denoiser::forward`], also returning the intermediate tensors.
    ///
    /// # Shapes
    /// As [`Denoiser::forward`]; the trace's shapes are listed on [`Trace`].
    pub fn forward_traced(&self, x: &Tensor, t: &Tensor, anchors: Option<&Tensor>) -> Result<(Tensor, Trace)> {
        let [b, p, frames] = self.check_input(x)?;
        self.run(x, Levels::of(t, [b, p, frames])?, anchors, &mut Prefix::Off)
    }

    /// [`Denoiser::forward`] for sampling, computing a clean prefix once: when the first frames
    /// of every person are at level 0 (`t` per person and frame) in a causal network, their rows
    /// at every U-Net level depend on those frames and the anchors alone. A call whose prefix
    /// and anchors are the last call's computes only the frames after it (whole multiples of
    /// 16 frames, so that no stride-2 conv or Winograd tile straddles the split)
    /// and reads the last call's rows before it. Equal to [`Denoiser::forward`] within float
    /// rounding (tested). Use a [`Denoiser::frozen`] network: the kept rows hold no graph then.
    ///
    /// # Shapes
    /// As [`Denoiser::forward`].
    pub fn forward_cached(&self, x: &Tensor, t: &Tensor, anchors: Option<&Tensor>) -> Result<Tensor> {
        let [b, p, frames] = self.check_input(x)?;
        let levels = Levels::of(t, [b, p, frames])?;
        let split = match &levels {
            Levels::Frames(values) if self.cfg.causality == Causality::Causal => clean_prefixes(values, b, p, frames).into_iter().min().unwrap_or(0),
            _ => 0,
        };
        let mut cache = self.prefix_cache.state.lock().unwrap_or_else(|e| e.into_inner());
        cache.reused = 0;
        if split == 0 {
            return Ok(self.run(x, levels, anchors, &mut Prefix::Off)?.0);
        }
        let host = |v: &Tensor| -> Result<Vec<f64>> { Ok(v.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?) };
        let key = PrefixKey { shape: [b, p, split], x: host(&x.narrow(2, 0, split)?)?, anchors: anchors.map(host).transpose()? };
        if let Some(kept) = cache.kept.as_ref().filter(|k| k.key == key) {
            let (rest, _) = self.run(x, levels, anchors, &mut Prefix::Reuse { split, tails: &kept.tails, next: 0 })?;
            let out = Tensor::cat(&[&kept.out, &rest], 2)?;
            cache.reused = split;
            return Ok(out);
        }
        cache.kept = None; // free the old rows before computing new ones
        let mut record = Prefix::Record { split, tails: Vec::new() };
        let (out, _) = self.run(x, levels, anchors, &mut record)?;
        if let Prefix::Record { tails, .. } = record {
            cache.kept = Some(KeptPrefix { key, tails, out: out.narrow(2, 0, split)?.contiguous()? });
        }
        Ok(out)
    }

    /// Input frames the last [`Denoiser::forward_cached`] call took from the one before (0: none).
    pub fn reused_prefix_frames(&self) -> usize {
        self.prefix_cache.state.lock().map_or(0, |c| c.reused)
    }

    /// `[B, P, T]` of an input `[B, P, T, δ]`, or an error naming what is wrong with it.
    fn check_input(&self, x: &Tensor) -> Result<[usize; 3]> {
        let (b, p, frames, d) = match x.dims() {
            &[b, p, t, d] => (b, p, t, d),
            dims => bail!("denoiser: input must be [B, P, T, δ], got {dims:?}"),
        };
        if d != self.cfg.feature_dims {
            bail!("denoiser: input has {d} feature dims, the network {}", self.cfg.feature_dims);
        }
        if b == 0 || p == 0 || frames == 0 {
            bail!("denoiser: empty input {:?}", x.dims());
        }
        if x.dtype() != self.dtype {
            bail!("denoiser: input dtype {:?} differs from the network's {:?}", x.dtype(), self.dtype);
        }
        Ok([b, p, frames])
    }

    /// The forward pass over the frames `prefix` says: all of them, or those from its split on
    /// (then the output and the trace hold those frames only).
    fn run(&self, x: &Tensor, levels: Levels, anchors: Option<&Tensor>, prefix: &mut Prefix) -> Result<(Tensor, Trace)> {
        let (b, p, frames, d) = x.dims4()?;
        let rel = relative_anchors(anchors, b, p, self.dtype, &self.device)?;
        let padded = frames.div_ceil(TIME_FACTOR) * TIME_FACTOR;
        let first = match prefix {
            Prefix::Reuse { split, .. } => *split,
            _ => 0,
        };
        let x = if padded > frames { x.pad_with_zeros(2, 0, padded - frames)? } else { x.clone() };
        let x = x.reshape((b * p, padded, d))?.narrow(1, first, padded - first)?;

        let temb = match levels {
            Levels::Scene(steps) => Cond::Scene(self.kernels.silu(&self.time_mlp.forward(&steps, self.dtype, &self.device)?)?), // [B, time_dim]
            Levels::Frames(values) => {
                let (uniq, rows) = level_rows(&values, b * p, frames, padded);
                let temb = self.kernels.silu(&self.time_mlp.forward(&uniq, self.dtype, &self.device)?)?; // [U, time_dim]
                let rows = rows
                    .into_iter()
                    .enumerate()
                    .map(|(level, r)| {
                        // The rows computed: from the split's row at this level on.
                        let (len, skip) = (padded >> level, first >> level);
                        let r: Vec<u32> = r.chunks(len).flat_map(|seq| seq[skip..].iter().copied()).collect();
                        let n = r.len();
                        Tensor::from_vec(r, n, &self.device)
                    })
                    .collect::<candle_core::Result<Vec<_>>>()?;
                Cond::Frames { temb, rows }
            }
        };
        let x0 = self.proj.forward(&x)?; // [B·P, T', H]
        let d1 = self.down[0].forward(&x0, &temb, prefix, 0)?; // [B·P, T'/2, 2H]
        let d2 = self.down[1].forward(&d1, &temb, prefix, 1)?; // [B·P, T'/4, 2H]
        let d3 = self.down[2].forward(&d2, &temb, prefix, 2)?; // [B·P, T'/8, 2H]
        let mid = self.res1.forward(&d3, &temb, prefix, 3)?;
        let social = match &self.social {
            Some(s) => s.forward(&mid, &rel, b, p)?,
            None => mid.clone(),
        };
        let u3 = self.up3.forward(&social, &d3, &temb, prefix, 3)?; // [B·P, T'/4, 2H]
        let u2 = self.up2.forward(&u3, &d2, &temb, prefix, 2)?; // [B·P, T'/2, 2H]
        let u1 = self.up1.forward(&u2, &d1, &temb, prefix, 1)?; // [B·P, T', H]
        let f = self.final_res.forward_input(ConvInput::Cat(&u1, &x0), &temb, prefix, 0)?; // [B·P, T', H]
        let out = self.to_pose.forward(&f)?.reshape((b, p, padded - first, d))?;
        let out = if padded > frames { out.narrow(2, 0, frames - first)?.contiguous()? } else { out };
        let trace = Trace { x0, down: [d1, d2, d3], mid, social, up: [u3, u2, u1] };
        Ok((out, trace))
    }
}

/// Frames of a clean prefix are split off in multiples of this: 2^3 levels × an even row (a
/// Winograd tile) at the coarsest.
const PREFIX_ALIGN: usize = 2 * TIME_FACTOR;

/// Per scene, the clean prefix a forward pass may compute once ([`Denoiser::forward_cached`],
/// [`super::InferenceNet::forward`]): the leading frames at level 0 for every person of the
/// scene, rounded down to a multiple of [`PREFIX_ALIGN`].
///
/// # Shapes
/// - `levels`: `[B, P, T]` flattened; returns B values.
pub(crate) fn clean_prefixes(levels: &[f64], b: usize, p: usize, frames: usize) -> Vec<usize> {
    let clean = |seq: usize| levels[seq * frames..(seq + 1) * frames].iter().take_while(|&&v| v == 0.0).count();
    (0..b).map(|scene| (scene * p..(scene + 1) * p).map(clean).min().unwrap_or(0) / PREFIX_ALIGN * PREFIX_ALIGN).collect()
}

/// What a forward pass does with the frames before a split (the prefix cache).
enum Prefix<'a> {
    /// Every frame is computed and nothing is kept.
    Off,
    /// Every frame is computed; `tails` gets, conv by conv, the rows of its input just before
    /// the split at its level.
    Record { split: usize, tails: Vec<Tensor> },
    /// Only the frames from `split` on are computed; each conv reads the rows `tails` kept.
    Reuse { split: usize, tails: &'a [Tensor], next: usize },
}

impl Prefix<'_> {
    /// The input of a causal conv at U-Net level `level` that reads `rows` rows before its first
    /// output (at most the split's rows at that level), and how many of them are kept rows put
    /// in front of `x` (whose outputs the caller drops).
    ///
    /// # Shapes
    /// - `x`: `[N, L, C]`; returns `[N, kept + L, C]`.
    fn context(&mut self, x: &Tensor, level: usize, rows: usize) -> Result<(Tensor, usize)> {
        match self {
            Prefix::Off => Ok((x.clone(), 0)),
            Prefix::Record { split, tails } => {
                let at = *split >> level;
                let r = rows.min(at);
                tails.push(x.narrow(1, at - r, r)?.contiguous()?);
                Ok((x.clone(), 0))
            }
            Prefix::Reuse { tails, next, .. } => {
                let Some(tail) = tails.get(*next) else { bail!("prefix cache: the kept rows end at conv {next}") };
                *next += 1;
                Ok((Tensor::cat(&[tail, x], 1)?, tail.dim(1)?))
            }
        }
    }
}

/// `y` without its first `rows` rows (frames).
///
/// # Shapes
/// - `y`: `[N, L, C]`; returns `[N, L − rows, C]`.
fn drop_rows(y: Tensor, rows: usize) -> Result<Tensor> {
    if rows == 0 {
        return Ok(y);
    }
    let l = y.dim(1)?;
    Ok(y.narrow(1, rows, l - rows)?.contiguous()?)
}

/// The last clean prefix of a network's [`Denoiser::forward_cached`] calls. A copy of a network
/// starts with an empty one.
#[derive(Default)]
struct PrefixCache {
    state: std::sync::Mutex<CacheState>,
}

impl Clone for PrefixCache {
    fn clone(&self) -> Self {
        Self::default()
    }
}

#[derive(Default)]
struct CacheState {
    kept: Option<KeptPrefix>,
    /// Input frames the last call took from the one before.
    reused: usize,
}

/// A clean prefix's inputs, the rows its convs read back, and its output.
struct KeptPrefix {
    key: PrefixKey,
    tails: Vec<Tensor>,
    /// `[B, P, split, δ]`.
    out: Tensor,
}

/// What a prefix's rows depend on: the batch, the split, the prefix's input frames and the
/// anchors.
#[derive(PartialEq)]
struct PrefixKey {
    shape: [usize; 3],
    x: Vec<f64>,
    anchors: Option<Vec<f64>>,
}

impl crate::model::Parameterized for Denoiser {
    fn vars(&self) -> &BTreeMap<String, Var> {
        &self.vars
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::config::{Aggregator, LOOKAHEAD_FRAMES};
    use candle_core::IndexOp;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    const AGGREGATORS: [Aggregator; 3] = [Aggregator::None, Aggregator::Mean, Aggregator::Attention { heads: 2 }];
    /// Both kernel sets run on the CPU: the tests that define the network hold both.
    const KERNELS: [Kernels; 3] = [Kernels::CUSTOM, Kernels::Custom(crate::model::K3Conv::Direct), Kernels::Composed(crate::model::Precision::F32)];

    fn net_with(cfg: DenoiserConfig, seed: u64, dtype: DType, kernels: Kernels) -> Denoiser {
        Denoiser::build(cfg, seed, &Placement { device: Device::Cpu, dtype, kernels }).unwrap()
    }

    fn tiny(aggregator: Aggregator) -> DenoiserConfig {
        DenoiserConfig { feature_dims: 7, hidden: 8, time_dim: 16, fourier_dim: 8, social_dim: 8, aggregator, ..Default::default() }
    }

    fn rand_t(rng: &mut StdRng, shape: &[usize], dtype: DType) -> Tensor {
        let n: usize = shape.iter().product();
        let v: Vec<f64> = (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect();
        Tensor::from_vec(v, shape, &Device::Cpu).unwrap().to_dtype(dtype).unwrap()
    }

    /// Random anchors `[B, P, 4]` with unit (cos, sin) and roots within ±3 m.
    fn rand_anchors(rng: &mut StdRng, b: usize, p: usize) -> Tensor {
        let mut v = vec![];
        for _ in 0..b * p {
            let a: f64 = rng.gen_range(-3.0..3.0);
            v.extend([rng.gen_range(-3.0..3.0), rng.gen_range(-3.0..3.0), a.cos(), a.sin()]);
        }
        Tensor::from_vec(v, (b, p, 4), &Device::Cpu).unwrap().to_dtype(DType::F32).unwrap()
    }

    fn steps(b: usize) -> Tensor {
        Tensor::from_vec((0..b as u32).map(|i| 17 + 400 * i).collect::<Vec<u32>>(), b, &Device::Cpu).unwrap()
    }

    fn max_abs_diff(a: &Tensor, b: &Tensor) -> f64 {
        (a - b).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_dtype(DType::F64).unwrap().to_scalar::<f64>().unwrap()
    }

    #[test]
    fn every_parameter_gets_a_finite_nonzero_gradient() {
        let mut rng = StdRng::seed_from_u64(1);
        for agg in AGGREGATORS {
            let net = Denoiser::new(tiny(agg), 3).unwrap();
            let (b, p, t) = (2, 3, 16);
            let x = rand_t(&mut rng, &[b, p, t, 7], DType::F32);
            let target = rand_t(&mut rng, &[b, p, t, 7], DType::F32);
            let anchors = rand_anchors(&mut rng, b, p);
            let out = net.forward(&x, &steps(b), Some(&anchors)).unwrap();
            let loss = (out - &target).unwrap().abs().unwrap().mean_all().unwrap();
            let grads = loss.backward().unwrap();
            let vars = net.named_vars();
            assert!(vars.windows(2).all(|w| w[0].0 < w[1].0), "names not sorted");
            for (name, var) in &vars {
                let g = grads.get(var).unwrap_or_else(|| panic!("{agg:?}: no gradient for {name}"));
                assert_eq!(g.dims(), var.dims(), "{name}");
                let v: Vec<f32> = g.flatten_all().unwrap().to_vec1().unwrap();
                assert!(v.iter().all(|x| x.is_finite()), "{agg:?}: non-finite gradient for {name}");
                let norm = v.iter().map(|x| x.abs()).sum::<f32>();
                assert!(norm > 0.0, "{agg:?}: zero gradient for {name}");
            }
            let social = vars.iter().filter(|(n, _)| n.starts_with("social.")).count();
            match agg {
                Aggregator::None => assert_eq!(social, 0),
                Aggregator::Mean => assert_eq!(social, 7),
                Aggregator::Attention { .. } => assert_eq!(social, 14),
            }
        }
    }

    /// End-to-end check of the composed backward: analytic gradients of Σ out·r with respect to
    /// sampled parameters and inputs against central differences, in f64.
    #[test]
    fn network_gradient_matches_finite_differences() {
        let mut rng = StdRng::seed_from_u64(2);
        for (agg, kernels) in AGGREGATORS.into_iter().flat_map(|a| KERNELS.map(|k| (a, k))) {
            let net = net_with(tiny(agg), 5, DType::F64, kernels);
            let (b, p, t) = (2, 3, 11);
            let xv = candle_core::Var::from_tensor(&rand_t(&mut rng, &[b, p, t, 7], DType::F64)).unwrap();
            let anchors = rand_anchors(&mut rng, b, p);
            let r = rand_t(&mut rng, &[b, p, t, 7], DType::F64);
            let loss =
                |x: &Tensor| -> f64 { (net.forward(x, &steps(b), Some(&anchors)).unwrap() * &r).unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap() };
            let grads = (net.forward(xv.as_tensor(), &steps(b), Some(&anchors)).unwrap() * &r).unwrap().sum_all().unwrap().backward().unwrap();
            let mut targets: Vec<(String, candle_core::Var)> = net.named_vars();
            targets.push(("input".into(), xv.clone()));
            targets.retain(|(n, _)| n.ends_with("weight") || n == "input");
            let worst = central_difference_error(&mut rng, &targets, &grads, || loss(xv.as_tensor()), &format!("{agg:?} {kernels:?}"));
            eprintln!("{agg:?} {kernels:?}: worst relative gradient error {worst:.2e}");
        }
    }

    /// The largest error, relative to the largest analytic gradient of its variable, of three
    /// random entries of each variable's gradient against central differences of `loss` (f64);
    /// asserts each < 1e-5.
    fn central_difference_error(
        rng: &mut StdRng,
        targets: &[(String, candle_core::Var)],
        grads: &candle_core::backprop::GradStore,
        loss: impl Fn() -> f64,
        label: &str,
    ) -> f64 {
        let mut worst = 0.0f64;
        for (name, var) in targets {
            let g: Vec<f64> = grads.get(var).unwrap().flatten_all().unwrap().to_vec1().unwrap();
            let base = var.as_tensor().flatten_all().unwrap().to_vec1::<f64>().unwrap();
            let scale = g.iter().map(|v| v.abs()).fold(1e-12, f64::max);
            for _ in 0..3 {
                let idx = rng.gen_range(0..base.len());
                let h = 1e-5;
                let mut num = 0.0;
                for (sign, delta) in [(1.0, h), (-1.0, -h)] {
                    let mut p = base.clone();
                    p[idx] += delta;
                    var.set(&Tensor::from_vec(p, var.shape(), &Device::Cpu).unwrap()).unwrap();
                    num += sign * loss();
                }
                var.set(&Tensor::from_vec(base.clone(), var.shape(), &Device::Cpu).unwrap()).unwrap();
                num /= 2.0 * h;
                let err = (num - g[idx]).abs() / scale;
                assert!(err < 1e-5, "{label} {name}[{idx}]: analytic {} numeric {num}", g[idx]);
                worst = worst.max(err);
            }
        }
        worst
    }

    #[test]
    fn outputs_before_t_ignore_inputs_from_t_on() {
        let mut rng = StdRng::seed_from_u64(4);
        for (agg, kernels) in AGGREGATORS.into_iter().flat_map(|a| KERNELS.map(|k| (a, k))) {
            let net = net_with(tiny(agg), 6, DType::F32, kernels);
            let (b, p, t) = (1, 3, 37);
            let x = rand_t(&mut rng, &[b, p, t, 7], DType::F32);
            let anchors = rand_anchors(&mut rng, b, p);
            let (out, trace) = net.forward_traced(&x, &steps(b), Some(&anchors)).unwrap();
            for t0 in 1..t {
                let tail = rand_t(&mut rng, &[b, p, t - t0, 7], DType::F32);
                let x2 = Tensor::cat(&[&x.narrow(2, 0, t0).unwrap(), &tail], 2).unwrap();
                let (out2, trace2) = net.forward_traced(&x2, &steps(b), Some(&anchors)).unwrap();
                let before = max_abs_diff(&out.narrow(2, 0, t0).unwrap(), &out2.narrow(2, 0, t0).unwrap());
                assert_eq!(before, 0.0, "{agg:?} {kernels:?}: output before {t0} changed by {before}");
                let at = max_abs_diff(&out.narrow(2, t0, 1).unwrap(), &out2.narrow(2, t0, 1).unwrap());
                assert!(at > 1e-4, "{agg:?}: output at {t0} did not react ({at})");
                // every level: sample o of level ℓ has seen input frames ≤ 2^ℓ·o only
                let levels = [
                    (&trace.x0, &trace2.x0, 0),
                    (&trace.down[0], &trace2.down[0], 1),
                    (&trace.down[1], &trace2.down[1], 2),
                    (&trace.down[2], &trace2.down[2], 3),
                    (&trace.mid, &trace2.mid, 3),
                    (&trace.social, &trace2.social, 3),
                    (&trace.up[0], &trace2.up[0], 2),
                    (&trace.up[1], &trace2.up[1], 1),
                    (&trace.up[2], &trace2.up[2], 0),
                ];
                for (i, (a, c, level)) in levels.into_iter().enumerate() {
                    let keep = (t0 - 1) / (1 << level) + 1; // samples o with 2^ℓ·o < t0
                    let d = max_abs_diff(&a.narrow(1, 0, keep).unwrap(), &c.narrow(1, 0, keep).unwrap());
                    assert_eq!(d, 0.0, "{agg:?}: trace {i} (level {level}) changed before {t0}");
                }
            }
        }
    }

    /// A lookahead network's output frame t0 depends on input frames up to t0 + 30 exactly (for
    /// t0 a multiple of 8) and on none after, with every kernel set, in values and gradients;
    /// its gradients match finite differences.
    #[test]
    fn lookahead_sees_thirty_frames_ahead_and_no_further() {
        let mut rng = StdRng::seed_from_u64(41);
        let cfg = DenoiserConfig { causality: Causality::Lookahead, ..tiny(Aggregator::Attention { heads: 2 }) };
        let (b, p, t) = (1, 2, 80);
        for kernels in KERNELS {
            let net = net_with(cfg.clone(), 7, DType::F32, kernels);
            let x = candle_core::Var::from_tensor(&rand_t(&mut rng, &[b, p, t, 7], DType::F32)).unwrap();
            let out = net.forward(x.as_tensor(), &steps(b), None).unwrap();
            for t0 in [0, 5, 8, 16, 33, 48, 79] {
                let g = out.narrow(2, t0, 1).unwrap().sum_all().unwrap().backward().unwrap();
                let gx = g.get(&x).unwrap().abs().unwrap().sum((0, 1, 3)).unwrap().to_vec1::<f32>().unwrap();
                let last = gx.iter().rposition(|&v| v > 0.0).unwrap();
                assert!(last <= t0 + LOOKAHEAD_FRAMES, "{kernels:?} t0 {t0}: depends on frame {last}");
                if t0 % 8 == 0 && t0 + LOOKAHEAD_FRAMES < t {
                    assert_eq!(last, t0 + LOOKAHEAD_FRAMES, "{kernels:?} t0 {t0}");
                }
                assert!(last > t0 || t0 == t - 1, "{kernels:?} t0 {t0}: sees nothing ahead");
            }
            // the same in values: changing frames from t0 + 31 on leaves outputs ≤ t0 unchanged
            let t0 = 24;
            let tail = rand_t(&mut rng, &[b, p, t - t0 - 31, 7], DType::F32);
            let x2 = Tensor::cat(&[&x.as_tensor().narrow(2, 0, t0 + 31).unwrap(), &tail], 2).unwrap();
            let out2 = net.forward(&x2, &steps(b), None).unwrap();
            assert_eq!(max_abs_diff(&out.narrow(2, 0, t0 + 1).unwrap(), &out2.narrow(2, 0, t0 + 1).unwrap()), 0.0, "{kernels:?}");
        }
        // gradients of every weight and of the input against central differences (f64)
        for kernels in KERNELS {
            let net = net_with(cfg.clone(), 5, DType::F64, kernels);
            let xv = candle_core::Var::from_tensor(&rand_t(&mut rng, &[1, 2, 11, 7], DType::F64)).unwrap();
            let r = rand_t(&mut rng, &[1, 2, 11, 7], DType::F64);
            let loss = |x: &Tensor| -> f64 { (net.forward(x, &steps(1), None).unwrap() * &r).unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap() };
            let grads = (net.forward(xv.as_tensor(), &steps(1), None).unwrap() * &r).unwrap().sum_all().unwrap().backward().unwrap();
            let mut targets: Vec<(String, candle_core::Var)> = net.named_vars().into_iter().filter(|(n, _)| n.ends_with("conv1.weight")).collect();
            targets.push(("input".into(), xv.clone()));
            central_difference_error(&mut rng, &targets, &grads, || loss(xv.as_tensor()), &format!("lookahead {kernels:?}"));
        }
    }

    /// The same check through autograd: ∂out[t0]/∂x is zero for every input frame after t0.
    #[test]
    fn output_gradient_vanishes_for_later_input_frames() {
        let mut rng = StdRng::seed_from_u64(5);
        let net = Denoiser::new(tiny(Aggregator::Attention { heads: 2 }), 7).unwrap();
        let (b, p, t) = (1, 2, 24);
        let x = candle_core::Var::from_tensor(&rand_t(&mut rng, &[b, p, t, 7], DType::F32)).unwrap();
        let out = net.forward(x.as_tensor(), &steps(b), None).unwrap();
        for t0 in [0, 3, 8, 15, 22] {
            let g = out.narrow(2, t0, 1).unwrap().sum_all().unwrap().backward().unwrap();
            let gx = g.get(&x).unwrap().abs().unwrap().sum((0, 1, 3)).unwrap().to_vec1::<f32>().unwrap();
            assert!(gx[t0 + 1..].iter().all(|&v| v == 0.0), "t0 {t0}: {gx:?}");
            assert!(gx[t0] > 0.0, "t0 {t0}: {gx:?}");
        }
    }

    #[test]
    fn permuting_persons_permutes_outputs() {
        let mut rng = StdRng::seed_from_u64(8);
        for (agg, kernels) in AGGREGATORS.into_iter().flat_map(|a| KERNELS.map(|k| (a, k))) {
            let net = net_with(tiny(agg), 9, DType::F32, kernels);
            let (b, p, t) = (2, 4, 13);
            let x = rand_t(&mut rng, &[b, p, t, 7], DType::F32);
            let anchors = rand_anchors(&mut rng, b, p);
            let out = net.forward(&x, &steps(b), Some(&anchors)).unwrap();
            let perm = Tensor::new(&[2u32, 0, 3, 1], &Device::Cpu).unwrap();
            let out_p = net.forward(&x.index_select(&perm, 1).unwrap(), &steps(b), Some(&anchors.index_select(&perm, 1).unwrap())).unwrap();
            let d = max_abs_diff(&out.index_select(&perm, 1).unwrap(), &out_p);
            eprintln!("{agg:?} {kernels:?}: permutation difference {d:.2e}");
            assert!(d < 1e-5, "{agg:?} {kernels:?}: {d}");
        }
    }

    /// Random levels `[B, P, T]` in 0..1000 (u32).
    fn frame_levels(rng: &mut StdRng, b: usize, p: usize, t: usize) -> Vec<u32> {
        (0..b * p * t).map(|_| rng.gen_range(0..1000u32)).collect()
    }

    fn levels_tensor(v: &[u32], b: usize, p: usize, t: usize) -> Tensor {
        Tensor::from_vec(v.to_vec(), (b, p, t), &Device::Cpu).unwrap()
    }

    /// A level per frame equal to the scene's level is the scalar case: same output, and the
    /// same gradient for every parameter (the per-frame path's gather has its own backward).
    #[test]
    fn per_frame_levels_equal_to_the_scene_level_are_the_scalar_case() {
        let mut rng = StdRng::seed_from_u64(21);
        for agg in AGGREGATORS {
            let net = Denoiser::new(tiny(agg), 4).unwrap();
            let (b, p, t) = (2, 3, 13);
            let x = rand_t(&mut rng, &[b, p, t, 7], DType::F32);
            let target = rand_t(&mut rng, &[b, p, t, 7], DType::F32);
            let anchors = rand_anchors(&mut rng, b, p);
            let scalar = steps(b);
            let per_frame: Vec<u32> = scalar.to_vec1::<u32>().unwrap().iter().flat_map(|&s| std::iter::repeat_n(s, p * t)).collect();
            let a = net.forward(&x, &scalar, Some(&anchors)).unwrap();
            let bb = net.forward(&x, &levels_tensor(&per_frame, b, p, t), Some(&anchors)).unwrap();
            assert!(max_abs_diff(&a, &bb) < 1e-6, "{agg:?}: {}", max_abs_diff(&a, &bb));
            let ga = (a - &target).unwrap().abs().unwrap().mean_all().unwrap().backward().unwrap();
            let gb = (bb - &target).unwrap().abs().unwrap().mean_all().unwrap().backward().unwrap();
            for (name, var) in net.named_vars() {
                let (u, v) = (ga.get(&var).unwrap(), gb.get(&var).unwrap());
                let scale = u.abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap().max(1e-6) as f64;
                let d = max_abs_diff(u, v) / scale;
                assert!(d < 1e-5, "{agg:?} {name}: relative gradient difference {d:.2e}");
            }
        }
    }

    /// Causality holds for levels too: a level changed at frame s (of any person) changes no
    /// output before s, of any person; and the output at s does change.
    #[test]
    fn a_level_changed_at_frame_s_changes_no_output_before_s() {
        let mut rng = StdRng::seed_from_u64(22);
        for (agg, kernels) in AGGREGATORS.into_iter().flat_map(|a| KERNELS.map(|k| (a, k))) {
            let net = net_with(tiny(agg), 6, DType::F32, kernels);
            let (b, p, t) = (1, 3, 21);
            let x = rand_t(&mut rng, &[b, p, t, 7], DType::F32);
            let anchors = rand_anchors(&mut rng, b, p);
            let levels = frame_levels(&mut rng, b, p, t);
            let base = net.forward(&x, &levels_tensor(&levels, b, p, t), Some(&anchors)).unwrap();
            for s in [1, 5, 8, 16, 20] {
                let mut changed = levels.clone();
                for f in s..t {
                    changed[t + f] = (changed[t + f] + 500) % 1000; // person 1, frames ≥ s
                }
                let out = net.forward(&x, &levels_tensor(&changed, b, p, t), Some(&anchors)).unwrap();
                let before = max_abs_diff(&base.narrow(2, 0, s).unwrap(), &out.narrow(2, 0, s).unwrap());
                assert_eq!(before, 0.0, "{agg:?}: a level at frame {s} changed an earlier output by {before}");
                let at = max_abs_diff(&base.narrow(2, s, 1).unwrap().i((.., 1)).unwrap(), &out.narrow(2, s, 1).unwrap().i((.., 1)).unwrap());
                assert!(at > 0.0, "{agg:?}: the level at frame {s} changed nothing at {s}");
            }
        }
    }

    #[test]
    fn permuting_persons_permutes_outputs_with_per_frame_levels() {
        let mut rng = StdRng::seed_from_u64(23);
        for agg in AGGREGATORS {
            let net = Denoiser::new(tiny(agg), 9).unwrap();
            let (b, p, t) = (2, 4, 13);
            let x = rand_t(&mut rng, &[b, p, t, 7], DType::F32);
            let anchors = rand_anchors(&mut rng, b, p);
            let lv = levels_tensor(&frame_levels(&mut rng, b, p, t), b, p, t);
            let out = net.forward(&x, &lv, Some(&anchors)).unwrap();
            let perm = Tensor::new(&[2u32, 0, 3, 1], &Device::Cpu).unwrap();
            let out_p =
                net.forward(&x.index_select(&perm, 1).unwrap(), &lv.index_select(&perm, 1).unwrap(), Some(&anchors.index_select(&perm, 1).unwrap())).unwrap();
            let d = max_abs_diff(&out.index_select(&perm, 1).unwrap(), &out_p);
            assert!(d < 1e-5, "{agg:?}: {d}");
        }
    }

    /// The composed kernels (any device) against the custom CPU kernels: the same network
    /// from one seed gives the same output and the same gradient for every parameter and the
    /// input, with levels per scene and per frame, for every aggregator (f64, so that the
    /// comparison measures the kernels, not rounding).
    #[test]
    fn composed_and_custom_kernels_agree_in_forward_and_every_gradient() {
        let mut rng = StdRng::seed_from_u64(31);
        let composed = Kernels::Composed(crate::model::Precision::F32);
        for agg in AGGREGATORS {
            let (custom_net, composed_net) = (net_with(tiny(agg), 12, DType::F64, Kernels::CUSTOM), net_with(tiny(agg), 12, DType::F64, composed));
            let (b, p, t) = (2, 3, 19);
            let x = rand_t(&mut rng, &[b, p, t, 7], DType::F64);
            let r = rand_t(&mut rng, &[b, p, t, 7], DType::F64);
            let anchors = rand_anchors(&mut rng, b, p).to_dtype(DType::F64).unwrap();
            for levels in [steps(b), levels_tensor(&frame_levels(&mut rng, b, p, t), b, p, t)] {
                let run = |net: &Denoiser| {
                    let xv = candle_core::Var::from_tensor(&x).unwrap();
                    let out = net.forward(xv.as_tensor(), &levels, Some(&anchors)).unwrap();
                    let grads = (&out * &r).unwrap().sum_all().unwrap().backward().unwrap();
                    let mut g: Vec<(String, Tensor)> = net.named_vars().into_iter().map(|(n, v)| (n, grads.get(&v).unwrap().clone())).collect();
                    g.push(("input".into(), grads.get(xv.as_tensor()).unwrap().clone()));
                    (out, g)
                };
                let ((out_a, grads_a), (out_b, grads_b)) = (run(&custom_net), run(&composed_net));
                let rel = |a: &Tensor, b: &Tensor| max_abs_diff(a, b) / max_abs_diff(a, &a.zeros_like().unwrap()).max(1e-12);
                let d = rel(&out_a, &out_b);
                assert!(d < 1e-10, "{agg:?}: outputs differ by {d:.2e} (relative)");
                let mut worst = 0.0f64;
                for ((name, ga), (_, gb)) in grads_a.iter().zip(&grads_b) {
                    let d = rel(ga, gb);
                    assert!(d < 1e-5, "{agg:?} {name}: gradients differ by {d:.2e} (relative)");
                    worst = worst.max(d);
                }
                eprintln!("{agg:?}, levels {:?}: output {d:.1e}, worst gradient {worst:.1e}", levels.dims());
            }
        }
    }

    /// bf16 products (f32 master weights) stay close to f32 and still get every gradient.
    #[test]
    fn bf16_products_stay_close_to_f32() {
        let mut rng = StdRng::seed_from_u64(32);
        let cfg = tiny(Aggregator::Attention { heads: 2 });
        let f32_net = net_with(cfg.clone(), 13, DType::F32, Kernels::CUSTOM);
        let bf16_net = net_with(cfg, 13, DType::F32, Kernels::Composed(crate::model::Precision::Bf16));
        let (b, p, t) = (2, 2, 24);
        let x = rand_t(&mut rng, &[b, p, t, 7], DType::F32);
        let anchors = rand_anchors(&mut rng, b, p);
        let (a, c) = (f32_net.forward(&x, &steps(b), Some(&anchors)).unwrap(), bf16_net.forward(&x, &steps(b), Some(&anchors)).unwrap());
        assert_eq!(c.dtype(), DType::F32);
        let scale = max_abs_diff(&a, &a.zeros_like().unwrap());
        let d = max_abs_diff(&a, &c) / scale;
        eprintln!("bf16 vs f32: largest difference {d:.2e} of the largest output");
        assert!(d > 0.0 && d < 0.05, "bf16 output differs by {d} (relative)");
        let grads = c.abs().unwrap().mean_all().unwrap().backward().unwrap();
        for (name, var) in bf16_net.named_vars() {
            let g = grads.get(&var).unwrap_or_else(|| panic!("no gradient for {name}"));
            assert_eq!(g.dtype(), DType::F32, "{name}");
            assert!(g.abs().unwrap().sum_all().unwrap().to_scalar::<f32>().unwrap() > 0.0, "zero gradient for {name}");
        }
    }

    /// A network moved to another placement computes the same function.
    #[test]
    fn a_network_moved_between_placements_keeps_its_weights() {
        let mut rng = StdRng::seed_from_u64(33);
        let net = Denoiser::new(tiny(Aggregator::Mean), 14).unwrap();
        let moved = net.to_placement(&Placement { device: Device::Cpu, dtype: DType::F32, kernels: Kernels::Composed(crate::model::Precision::F32) }).unwrap();
        assert_eq!(moved.placement().describe(), "cpu f32 composed");
        assert_eq!(net.placement().describe(), "cpu f32 custom");
        let x = rand_t(&mut rng, &[1, 2, 16, 7], DType::F32);
        let d = max_abs_diff(&net.forward(&x, &steps(1), None).unwrap(), &moved.forward(&x, &steps(1), None).unwrap());
        assert!(d < 1e-5, "{d}");
        let err = Denoiser::build(tiny(Aggregator::Mean), 1, &Placement { device: Device::Cpu, dtype: DType::BF16, kernels: Kernels::CUSTOM }).err().unwrap();
        assert!(err.to_string().contains("not supported"), "{err}");
    }

    #[test]
    fn any_number_of_persons_and_frames() {
        let mut rng = StdRng::seed_from_u64(10);
        for agg in AGGREGATORS {
            let net = Denoiser::new(tiny(agg), 11).unwrap();
            for p in [1, 2, 3, 7] {
                for t in [1, 13, 37, 64] {
                    let x = rand_t(&mut rng, &[2, p, t, 7], DType::F32);
                    let anchors = rand_anchors(&mut rng, 2, p);
                    let out = net.forward(&x, &steps(2), Some(&anchors)).unwrap();
                    assert_eq!(out.dims(), [2, p, t, 7]);
                    let v: Vec<f32> = out.flatten_all().unwrap().to_vec1().unwrap();
                    assert!(v.iter().all(|x| x.is_finite()));
                    assert!(v.iter().any(|&x| x != 0.0));
                }
            }
            // padding is internal: T = 13 gives the first 13 frames of any 16-frame extension
            let x = rand_t(&mut rng, &[1, 3, 16, 7], DType::F32);
            let full = net.forward(&x, &steps(1), None).unwrap();
            let short = net.forward(&x.narrow(2, 0, 13).unwrap(), &steps(1), None).unwrap();
            assert_eq!(max_abs_diff(&full.narrow(2, 0, 13).unwrap(), &short), 0.0);
        }
    }

    #[test]
    fn none_aggregator_keeps_persons_independent_and_others_do_not() {
        let mut rng = StdRng::seed_from_u64(12);
        for agg in AGGREGATORS {
            let net = Denoiser::new(tiny(agg), 13).unwrap();
            let (b, p, t) = (1, 3, 24);
            let x = rand_t(&mut rng, &[b, p, t, 7], DType::F32);
            let anchors = rand_anchors(&mut rng, b, p);
            let out = net.forward(&x, &steps(b), Some(&anchors)).unwrap();
            // change persons 1 and 2 (motion and anchors); person 0 keeps its input
            let x2 = Tensor::cat(&[&x.i((.., 0..1)).unwrap(), &rand_t(&mut rng, &[b, 2, t, 7], DType::F32)], 1).unwrap();
            let anchors2 = Tensor::cat(&[&anchors.i((.., 0..1)).unwrap(), &rand_anchors(&mut rng, b, 2)], 1).unwrap();
            let out2 = net.forward(&x2, &steps(b), Some(&anchors2)).unwrap();
            let d = max_abs_diff(&out.i((.., 0)).unwrap(), &out2.i((.., 0)).unwrap());
            // only the anchors of the others change
            let out3 = net.forward(&x, &steps(b), Some(&anchors2)).unwrap();
            let da = max_abs_diff(&out.i((.., 0)).unwrap(), &out3.i((.., 0)).unwrap());
            // person 0 alone
            let alone = net.forward(&x.i((.., 0..1)).unwrap(), &steps(b), Some(&anchors.i((.., 0..1)).unwrap())).unwrap();
            let dl = max_abs_diff(&out.i((.., 0..1)).unwrap(), &alone);
            eprintln!("{agg:?}: others' motion moves person 0 by {d:.2e}, their anchors by {da:.2e}, alone {dl:.2e}");
            match agg {
                Aggregator::None => {
                    assert_eq!(d, 0.0);
                    assert_eq!(da, 0.0);
                    assert!(dl < 1e-6, "{dl}");
                }
                _ => {
                    assert!(d > 1e-3, "{agg:?}: person 0 does not see the others' motion ({d})");
                    assert!(da > 1e-3, "{agg:?}: person 0 does not see the others' anchors ({da})");
                    assert!(dl > 1e-3, "{agg:?}: {dl}");
                }
            }
        }
    }

    #[test]
    fn seeded_initialization_and_parameter_count() {
        let a = Denoiser::new(tiny(Aggregator::Mean), 42).unwrap();
        let b = Denoiser::new(tiny(Aggregator::Mean), 42).unwrap();
        let c = Denoiser::new(tiny(Aggregator::Mean), 43).unwrap();
        let (va, vb, vc) = (a.named_vars(), b.named_vars(), c.named_vars());
        let w = |v: &[(String, candle_core::Var)], i: usize| v[i].1.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let idx = va.iter().position(|(n, _)| n == "down1.res.conv1.weight").unwrap();
        assert_eq!(w(&va, idx), w(&vb, idx));
        assert_ne!(w(&va, idx), w(&vc, idx));
        let bound = 1.0 / (8.0f32 * 2.0 * 3.0).sqrt(); // fan_in = 2H·K = 16·3
        assert!(w(&va, idx).iter().all(|v| v.abs() <= bound));
        let ln = va.iter().find(|(n, _)| n == "res1.norm.weight").unwrap();
        assert!(ln.1.flatten_all().unwrap().to_vec1::<f32>().unwrap().iter().all(|&v| v == 1.0));

        let counts: Vec<usize> = [Aggregator::None, Aggregator::Mean, Aggregator::Attention { heads: 4 }]
            .into_iter()
            .map(|aggregator| Denoiser::new(DenoiserConfig { aggregator, ..Default::default() }, 0).unwrap().num_params())
            .collect();
        eprintln!("parameters at H = 192 (none, mean, attention): {counts:?}");
        assert_eq!(counts, vec![10_753_661, 11_086_973, 11_309_117]);
    }

    #[test]
    fn gradients_are_bitwise_reproducible() {
        let mut rng = StdRng::seed_from_u64(14);
        let net = Denoiser::new(tiny(Aggregator::Attention { heads: 2 }), 15).unwrap();
        let x = rand_t(&mut rng, &[3, 2, 300, 7], DType::F32);
        let run = || {
            let g = net.forward(&x, &steps(3), None).unwrap().abs().unwrap().mean_all().unwrap().backward().unwrap();
            net.named_vars().iter().map(|(_, v)| g.get(v).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap()).collect::<Vec<_>>()
        };
        assert_eq!(run(), run());
    }

    #[test]
    fn frozen_copy_builds_no_graph_and_matches() {
        let mut rng = StdRng::seed_from_u64(16);
        let net = Denoiser::new(tiny(Aggregator::Mean), 17).unwrap();
        let frozen = net.frozen();
        let x = rand_t(&mut rng, &[1, 2, 16, 7], DType::F32);
        let a = net.forward(&x, &steps(1), None).unwrap();
        let b = frozen.forward(&x, &steps(1), None).unwrap();
        assert!(a.track_op() && !b.track_op());
        assert_eq!(max_abs_diff(&a, &b), 0.0);
        // an update of the Vars is seen by the frozen copy
        let (_, v) = &net.named_vars()[0];
        v.set(&(v.as_tensor() + 0.5).unwrap()).unwrap();
        let c = frozen.forward(&x, &steps(1), None).unwrap();
        assert!(max_abs_diff(&b, &c) > 0.0);
    }

    /// With a clean known prefix (level 0), a call that shares it with the last one computes
    /// only the frames after it and gives what the uncached network gives; a changed prefix
    /// frame or anchor, a network that looks ahead, or one level per scene recomputes all.
    #[test]
    fn the_clean_prefix_is_computed_once_and_changes_nothing() {
        let mut rng = StdRng::seed_from_u64(12);
        for (agg, kernels) in AGGREGATORS.into_iter().flat_map(|a| KERNELS.map(|k| (a, k))) {
            let net = net_with(tiny(agg), 4, DType::F32, kernels).frozen();
            for (b, p, t, known) in [(2, 3, 120, 30), (1, 2, 61, 17), (1, 1, 45, 44)] {
                let split = known / 16 * 16;
                let anchors = rand_anchors(&mut rng, b, p);
                let prefix = rand_t(&mut rng, &[b, p, known, 7], DType::F32);
                let canvas = |rng: &mut StdRng| Tensor::cat(&[&prefix, &rand_t(rng, &[b, p, t - known, 7], DType::F32)], 2).unwrap();
                let levels = |level: u32| {
                    let v: Vec<u32> = (0..b * p * t).map(|i| if i % t < known { 0 } else { level }).collect();
                    Tensor::from_vec(v, (b, p, t), &Device::Cpu).unwrap()
                };
                for (step, level) in [999, 749, 2].into_iter().enumerate() {
                    let x = canvas(&mut rng);
                    let out = net.forward_cached(&x, &levels(level), Some(&anchors)).unwrap();
                    assert_eq!(net.reused_prefix_frames(), if step == 0 { 0 } else { split }, "{agg:?} {kernels:?} [{b}, {p}, {t}] step {step}");
                    let d = max_abs_diff(&out, &net.forward(&x, &levels(level), Some(&anchors)).unwrap());
                    assert!(d <= 1e-5, "{agg:?} {kernels:?} [{b}, {p}, {t}] step {step}: cached − uncached = {d}");
                }
                // A changed prefix frame, or other anchors: everything again, still equal.
                let x = canvas(&mut rng);
                let changed = (x.i((.., .., ..split / 2, ..)).unwrap() + 0.5).unwrap();
                let x = Tensor::cat(&[&changed, &x.i((.., .., split / 2.., ..)).unwrap()], 2).unwrap();
                let other = rand_anchors(&mut rng, b, p);
                for a in [&anchors, &other] {
                    let out = net.forward_cached(&x, &levels(300), Some(a)).unwrap();
                    assert_eq!(net.reused_prefix_frames(), 0, "{agg:?} {kernels:?}");
                    assert!(max_abs_diff(&out, &net.forward(&x, &levels(300), Some(a)).unwrap()) <= 1e-5);
                }
            }
        }
        // One level per scene, or a network that reads ahead: nothing kept.
        let x = rand_t(&mut rng, &[1, 2, 40, 7], DType::F32);
        let ahead = Denoiser::new(DenoiserConfig { causality: Causality::Lookahead, ..tiny(Aggregator::Mean) }, 4).unwrap().frozen();
        let clean = Tensor::from_vec((0..80u32).map(|i| if i % 40 < 32 { 0 } else { 500 }).collect::<Vec<_>>(), (1, 2, 40), &Device::Cpu).unwrap();
        for _ in 0..2 {
            let net = Denoiser::new(tiny(Aggregator::Mean), 4).unwrap().frozen();
            net.forward_cached(&x, &steps(1), None).unwrap();
            assert_eq!(net.reused_prefix_frames(), 0);
            let out = ahead.forward_cached(&x, &clean, None).unwrap();
            assert_eq!(ahead.reused_prefix_frames(), 0);
            assert!(max_abs_diff(&out, &ahead.forward(&x, &clean, None).unwrap()) == 0.0);
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let net = Denoiser::new(tiny(Aggregator::Mean), 0).unwrap();
        let x = Tensor::zeros((1, 2, 8, 7), DType::F32, &Device::Cpu).unwrap();
        assert!(net.forward(&x, &steps(1), None).is_ok());
        assert!(net.forward(&x.narrow(3, 0, 6).unwrap(), &steps(1), None).is_err());
        assert!(net.forward(&x, &steps(2), None).is_err());
        assert!(net.forward(&x.to_dtype(DType::F64).unwrap(), &steps(1), None).is_err());
        let bad_anchors = Tensor::zeros((1, 3, 4), DType::F32, &Device::Cpu).unwrap();
        assert!(net.forward(&x, &steps(1), Some(&bad_anchors)).is_err());
    }

    /// Timing of one training step (forward + L1 backward), 16 windows × 3 persons × 256
    /// frames at H = 128, the setting of CANDLE_NOTES.md. Run with
    /// `cargo test --release -p socdiff-engine --lib bench_training_step -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn bench_training_step() {
        let mut rng = StdRng::seed_from_u64(18);
        for agg in [Aggregator::None, Aggregator::Mean, Aggregator::Attention { heads: 4 }] {
            let cfg = DenoiserConfig { hidden: 128, social_dim: 128, aggregator: agg, ..Default::default() };
            let net = Denoiser::new(cfg, 0).unwrap();
            let x = rand_t(&mut rng, &[16, 3, 256, 61], DType::F32);
            let anchors = rand_anchors(&mut rng, 16, 3);
            let mut times = vec![];
            for _ in 0..3 {
                let start = std::time::Instant::now();
                let out = net.forward(&x, &steps(16), Some(&anchors)).unwrap();
                let g = (out - &x).unwrap().abs().unwrap().mean_all().unwrap().backward().unwrap();
                assert!(g.get(&net.named_vars()[0].1).is_some());
                times.push(start.elapsed().as_secs_f64());
            }
            let frozen = net.frozen();
            let x1 = rand_t(&mut rng, &[1, 3, 1800, 61], DType::F32);
            let start = std::time::Instant::now();
            frozen.forward(&x1, &steps(1), None).unwrap();
            let sample = start.elapsed().as_secs_f64();
            eprintln!("{agg:?}: training step {times:.3?} s; one denoising step 1×3×1800: {sample:.3} s");
        }
    }
}
