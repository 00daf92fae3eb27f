//! Parameter store with seeded initialization, and the small layers the denoiser is built
//! from (causal conv, per-frame linear, LayerNorm), each running the [`Kernels`] its network
//! was built with.

use super::dispatch::Kernels;
use crate::Result;
use candle_core::{DType, Device, Tensor, Var};
use rand::rngs::StdRng;
use rand::SeedableRng;
use rand_distr::{Distribution, Uniform};
use std::collections::BTreeMap;

/// A network whose trainable parameters are named [`Var`]s (the denoiser, the classifiers).
pub trait Parameterized {
    /// The parameters by name.
    fn vars(&self) -> &BTreeMap<String, Var>;

    /// Every trainable parameter with its name, sorted by name.
    fn named_vars(&self) -> Vec<(String, Var)> {
        self.vars().iter().map(|(k, v)| (k.clone(), v.clone())).collect()
    }

    /// Number of scalar parameters.
    fn num_params(&self) -> usize {
        self.vars().values().map(|v| v.elem_count()).sum()
    }
}

/// Creates the parameters of a network in construction order from one seeded RNG and keeps
/// them by name (sorted, dot-separated like a PyTorch state dict).
pub(crate) struct ParamInit {
    vars: BTreeMap<String, Var>,
    rng: StdRng,
    dtype: DType,
    device: Device,
    kernels: Kernels,
}

impl ParamInit {
    /// Parameters on `device`, for layers running the kernels that suit it
    /// ([`Kernels::for_device`]).
    pub(crate) fn new(seed: u64, dtype: DType, device: Device) -> Self {
        let kernels = Kernels::for_device(&device);
        Self { vars: BTreeMap::new(), rng: StdRng::seed_from_u64(seed), dtype, device, kernels }
    }

    /// The same parameters for layers running `kernels` (checked against the device).
    pub(crate) fn with_kernels(mut self, kernels: Kernels) -> Result<Self> {
        kernels.check_device(&self.device)?;
        self.kernels = kernels;
        Ok(self)
    }

    pub(crate) fn kernels(&self) -> Kernels {
        self.kernels
    }

    pub(crate) fn dtype(&self) -> DType {
        self.dtype
    }

    pub(crate) fn device(&self) -> &Device {
        &self.device
    }

    fn insert(&mut self, name: String, values: Vec<f64>, shape: &[usize]) -> Result<Tensor> {
        if self.vars.contains_key(&name) {
            crate::bail!("model: parameter {name} defined twice");
        }
        // Cast on the host: every device gets the same values.
        let t = Tensor::from_vec(values, shape, &Device::Cpu)?.to_dtype(self.dtype)?.to_device(&self.device)?;
        let var = Var::from_tensor(&t)?;
        let t = var.as_tensor().clone();
        self.vars.insert(name, var);
        Ok(t)
    }

    /// A parameter drawn uniformly from `[−bound, bound]` (PyTorch's default for conv and
    /// linear layers uses `bound = 1/√fan_in`).
    pub(crate) fn uniform(&mut self, name: String, shape: &[usize], bound: f64) -> Result<Tensor> {
        let n = shape.iter().product();
        let dist = Uniform::new_inclusive(-bound, bound);
        let v = (0..n).map(|_| dist.sample(&mut self.rng)).collect();
        self.insert(name, v, shape)
    }

    /// A parameter filled with `value`.
    pub(crate) fn constant(&mut self, name: String, shape: &[usize], value: f64) -> Result<Tensor> {
        let n = shape.iter().product();
        self.insert(name, vec![value; n], shape)
    }

    /// All parameters, sorted by name.
    pub(crate) fn finish(self) -> BTreeMap<String, Var> {
        self.vars
    }
}

/// Joins a prefix and a name with a dot.
pub(crate) fn join(prefix: &str, name: &str) -> String {
    if prefix.is_empty() {
        name.to_string()
    } else {
        format!("{prefix}.{name}")
    }
}

/// A conv's input: one tensor `[N, T, C]`, or two `[N, T, C_a]`, `[N, T, C_b]` read as their
/// channels side by side (the U-Net's skip connections; the concatenation is never stored).
#[derive(Clone, Copy)]
pub(crate) enum ConvInput<'a> {
    One(&'a Tensor),
    Cat(&'a Tensor, &'a Tensor),
}

/// Causal 1-D convolution with bias ([`super::ops::causal_conv1d`]); parameters `{prefix}.weight`
/// `[K, C_in, C_out]` and `{prefix}.bias` `[C_out]`, uniform ±1/√(C_in·K).
#[derive(Clone)]
pub(crate) struct Conv {
    weight: Tensor,
    bias: Tensor,
    stride: usize,
    kernels: Kernels,
}

impl Conv {
    pub(crate) fn new(init: &mut ParamInit, prefix: &str, cin: usize, cout: usize, kernel: usize, stride: usize) -> Result<Self> {
        let bound = 1.0 / ((cin * kernel) as f64).sqrt();
        let weight = init.uniform(join(prefix, "weight"), &[kernel, cin, cout], bound)?;
        let bias = init.uniform(join(prefix, "bias"), &[cout], bound)?;
        Ok(Self { weight, bias, stride, kernels: init.kernels() })
    }

    /// # Shapes
    /// - `x`: `[N, T, C_in]`; returns `[N, ⌈T/stride⌉, C_out]`.
    pub(crate) fn forward(&self, x: &Tensor) -> Result<Tensor> {
        Ok(self.kernels.conv1d(x, &self.weight, &self.bias, self.stride)?)
    }

    /// The conv of `input`, one tensor or two side by side.
    pub(crate) fn forward_input(&self, input: ConvInput) -> Result<Tensor> {
        match input {
            ConvInput::One(x) => self.forward(x),
            ConvInput::Cat(a, b) => Ok(self.kernels.conv1d_cat(a, b, &self.weight, &self.bias, self.stride, false)?),
        }
    }

    /// The conv of `input` centred instead of causal: output `o` reads `o − 1, o, o + 1` (a
    /// zero frame after the end), i.e. the causal conv of the input shifted one frame earlier.
    ///
    /// # Shapes
    /// - each input part `[N, T, C]`; returns `[N, T, C_out]` (stride 1 only).
    pub(crate) fn forward_centred(&self, input: ConvInput) -> Result<Tensor> {
        if self.stride != 1 {
            crate::bail!("centred conv: stride {} (only stride 1 is centred)", self.stride);
        }
        let ahead = |x: &Tensor| x.pad_with_zeros(1, 0, 1);
        let (y, t) = match input {
            ConvInput::One(x) => (self.forward(&ahead(x)?)?, x.dim(1)?),
            ConvInput::Cat(a, b) => (self.forward_input(ConvInput::Cat(&ahead(a)?, &ahead(b)?))?, a.dim(1)?),
        };
        Ok(y.narrow(1, 1, t)?.contiguous()?)
    }

    /// The conv of `norm`'s `LayerNorm(SiLU(x))`, with no copy of the normalized activation
    /// kept for the gradients (the residual block's second conv).
    ///
    /// # Shapes
    /// - `x`: `[N, T, C_in]`; returns `[N, ⌈T/stride⌉, C_out]`.
    pub(crate) fn forward_normed(&self, x: &Tensor, norm: &LayerNorm) -> Result<Tensor> {
        Ok(self.kernels.silu_layer_norm_conv1d(x, &norm.gamma, &norm.beta, norm.eps, &self.weight, &self.bias, self.stride)?)
    }

    /// The conv of `a` and `b` side by side, then ×2 causal upsampling (the decoder's step up,
    /// with no copy of the concatenation or of the conv's output kept for the gradients).
    ///
    /// # Shapes
    /// - `a`: `[N, T, C_a]`, `b`: `[N, T, C_b]`; returns `[N, 2⌈T/stride⌉, C_out]`
    pub(crate) fn forward_cat_upsampled(&self, a: &Tensor, b: &Tensor) -> Result<Tensor> {
        Ok(self.kernels.conv1d_cat(a, b, &self.weight, &self.bias, self.stride, true)?)
    }

    pub(crate) fn detached(&self) -> Self {
        Self { weight: self.weight.detach(), bias: self.bias.detach(), ..*self }
    }
}

/// Linear layer on the last dim of a tensor of any rank (a 1×1 causal conv, so candle's
/// batched matmul is never used); parameters `{prefix}.weight` `[1, in, out]` and
/// `{prefix}.bias` `[out]`, uniform ±1/√in. Without bias, a constant zero bias is used.
#[derive(Clone)]
pub(crate) struct Linear {
    weight: Tensor,
    bias: Tensor,
    kernels: Kernels,
}

impl Linear {
    pub(crate) fn new(init: &mut ParamInit, prefix: &str, din: usize, dout: usize, bias: bool) -> Result<Self> {
        let bound = 1.0 / (din as f64).sqrt();
        let weight = init.uniform(join(prefix, "weight"), &[1, din, dout], bound)?;
        let bias = if bias { init.uniform(join(prefix, "bias"), &[dout], bound)? } else { Tensor::zeros(dout, init.dtype(), init.device())? };
        Ok(Self { weight, bias, kernels: init.kernels() })
    }

    /// # Shapes
    /// - `x`: `[…, in]`; returns `[…, out]`.
    pub(crate) fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let dims = x.dims();
        let din = *dims.last().unwrap_or(&0);
        let rows = x.elem_count() / din.max(1);
        let y = self.kernels.conv1d(&x.reshape((1, rows, din))?, &self.weight, &self.bias, 1)?;
        let mut out = dims.to_vec();
        *out.last_mut().expect("rank ≥ 1") = self.bias.dims1()?;
        Ok(y.reshape(out)?)
    }

    pub(crate) fn detached(&self) -> Self {
        Self { weight: self.weight.detach(), bias: self.bias.detach(), kernels: self.kernels }
    }
}

/// LayerNorm over the last dim of a SiLU's output, the residual blocks' `LayerNorm(SiLU(h))`,
/// applied by the conv that reads it ([`Conv::forward_normed`]); parameters `{prefix}.weight`
/// (γ = 1) and `{prefix}.bias` (β = 0).
#[derive(Clone)]
pub(crate) struct LayerNorm {
    gamma: Tensor,
    beta: Tensor,
    eps: f64,
}

impl LayerNorm {
    pub(crate) fn new(init: &mut ParamInit, prefix: &str, dim: usize, eps: f64) -> Result<Self> {
        let gamma = init.constant(join(prefix, "weight"), &[dim], 1.0)?;
        let beta = init.constant(join(prefix, "bias"), &[dim], 0.0)?;
        Ok(Self { gamma, beta, eps })
    }

    pub(crate) fn detached(&self) -> Self {
        Self { gamma: self.gamma.detach(), beta: self.beta.detach(), ..*self }
    }
}

/// The values of a parameter as a flat `Vec<f32>` (copied to the host).
pub(crate) fn var_values(var: &Var) -> Result<Vec<f32>> {
    if var.dtype() != DType::F32 {
        crate::bail!("training supports f32 parameters only, got {:?}", var.dtype());
    }
    Ok(var.as_tensor().flatten_all()?.to_vec1::<f32>()?)
}

/// Overwrites a parameter with `values` (same element count), on its device.
pub(crate) fn set_var(var: &Var, values: Vec<f32>) -> Result<()> {
    if values.len() != var.elem_count() {
        crate::bail!("parameter of shape {:?} cannot take {} values", var.dims(), values.len());
    }
    let t = Tensor::from_vec(values, var.shape(), var.device())?;
    Ok(var.set(&t)?)
}
