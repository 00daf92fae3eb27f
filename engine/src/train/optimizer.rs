//! Adam, gradient clipping and the exponential moving average of the weights, as tensor ops
//! on the parameters' device (no copy to the host per step).
//!
//! Parameters are kept in the sorted order of [`Denoiser::named_vars`] (never a `VarMap`'s
//! random order, CANDLE_NOTES.md trap 5), so their state is saved and restored exactly and
//! every update is reproducible bit for bit on one machine.

use crate::checkpoint::config::{AdamConfig, EmaConfig};
use crate::model::kernels;
#[cfg(test)]
pub(crate) use crate::model::layers::set_var;
pub(crate) use crate::model::layers::var_values;
use crate::model::ops::slice;
use crate::model::Denoiser;
use crate::model::Parameterized;
use crate::{bail, Result};
use candle_core::backprop::GradStore;
use candle_core::{CpuStorage, DType, InplaceOp2, InplaceOp3, Layout, Tensor, Var};
use rayon::prelude::*;

/// A parameter's name with its first and second moments (host copies).
pub type Moments = (String, Vec<f32>, Vec<f32>);

/// Adam as PyTorch's `torch.optim.Adam` (no weight decay, no amsgrad):
///
/// ```text
/// g ← g · min(1, c / (‖g‖ + 1e-6))     (only with clip_norm = c; ‖g‖ over all parameters)
/// m ← β1·m + (1 − β1)·g;   v ← β2·v + (1 − β2)·g²
/// θ ← θ − (lr / (1 − β1^s)) · m / (√v / √(1 − β2^s) + ε)      (s = step count, 1-based)
/// ```
///
/// A parameter without a gradient is skipped (its moments do not move), as in PyTorch. The
/// rate `lr` of update s follows `cfg.schedule` over the run's length
/// ([`Adam::set_run_steps`]; without one it stays at the peak `cfg.lr`).
pub struct Adam {
    cfg: AdamConfig,
    params: Vec<(String, Var)>,
    m: Vec<Tensor>,
    v: Vec<Tensor>,
    steps: u64,
    run_steps: Option<u64>,
}

impl Adam {
    /// Zero moments for `params` (sorted by name, e.g. [`Denoiser::named_vars`]), on their
    /// devices.
    pub fn new(params: Vec<(String, Var)>, cfg: AdamConfig) -> Result<Self> {
        // Two allocations each: the CPU route updates the moments in place.
        let zeros = || params.iter().map(|(_, v)| v.as_tensor().zeros_like()).collect::<candle_core::Result<Vec<_>>>();
        let (m, v) = (zeros()?, zeros()?);
        Ok(Self { cfg, params, m, v, steps: 0, run_steps: None })
    }

    /// Number of updates made so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Sets the run's length in updates, the end of the learning-rate schedule.
    pub fn set_run_steps(&mut self, total: u64) {
        self.run_steps = Some(total);
    }

    /// The learning rate of the next update.
    pub fn lr(&self) -> f64 {
        match self.run_steps {
            Some(total) => self.cfg.lr_at(self.steps, total),
            None => self.cfg.lr,
        }
    }

    /// The parameters' names, sorted.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.params.iter().map(|(n, _)| n.as_str())
    }

    /// `(name, m, v)` for every parameter, sorted by name (copied to the host).
    pub fn moments(&self) -> Result<Vec<Moments>> {
        let host = |t: &Tensor| -> Result<Vec<f32>> { Ok(t.flatten_all()?.to_vec1::<f32>()?) };
        self.params.iter().zip(self.m.iter().zip(&self.v)).map(|((n, _), (m, v))| Ok((n.clone(), host(m)?, host(v)?))).collect()
    }

    /// Restores the state saved from [`Adam::moments`] and [`Adam::steps`]; `moments` yields
    /// `(m, v)` per parameter in the same order.
    pub fn restore(&mut self, steps: u64, moments: Vec<(Vec<f32>, Vec<f32>)>) -> Result<()> {
        if moments.len() != self.params.len() {
            bail!("adam: {} saved moments for {} parameters", moments.len(), self.params.len());
        }
        for ((name, var), (m, v)) in self.params.iter().zip(&moments) {
            if m.len() != var.elem_count() || v.len() != var.elem_count() {
                bail!("adam: saved moments of {name} have {} / {} values, the parameter {}", m.len(), v.len(), var.elem_count());
            }
        }
        let mut ms = Vec::with_capacity(moments.len());
        let mut vs = Vec::with_capacity(moments.len());
        for ((_, var), (m, v)) in self.params.iter().zip(moments) {
            ms.push(Tensor::from_vec(m, var.shape(), var.device())?);
            vs.push(Tensor::from_vec(v, var.shape(), var.device())?);
        }
        self.m = ms;
        self.v = vs;
        self.steps = steps;
        Ok(())
    }

    /// The factor `min(1, c / (‖g‖ + 1e-6))` of gradient clipping (PyTorch's
    /// `clip_grad_norm_`), and ‖g‖; `None` without `clip_norm`.
    fn clip_factor(&self, grads: &GradStore) -> Result<Option<(f64, f64)>> {
        let Some(max_norm) = self.cfg.clip_norm else { return Ok(None) };
        let squares =
            self.params.iter().filter_map(|(_, var)| grads.get(var.as_tensor())).map(|g| g.sqr()?.sum_all()).collect::<candle_core::Result<Vec<_>>>()?;
        if squares.is_empty() {
            return Ok(None);
        }
        let norm = Tensor::stack(&squares, 0)?.sum_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?.sqrt();
        Ok(Some(((max_norm / (norm + 1e-6)).min(1.0), norm)))
    }

    /// One update from the gradients of a loss: in place on the CPU (f32), as tensor ops on
    /// other devices; both routes do the same f32 arithmetic in the same order.
    pub fn step(&mut self, grads: &GradStore) -> Result<()> {
        let in_place = self.params.iter().all(|(_, v)| v.device().is_cpu() && v.dtype() == DType::F32);
        self.step_by(grads, in_place)
    }

    fn step_by(&mut self, grads: &GradStore, in_place: bool) -> Result<()> {
        let clip = self.clip_factor(grads)?;
        let lr = self.lr();
        self.steps += 1;
        let s = self.steps as i32;
        let [b1, b2] = self.cfg.betas;
        let bc1 = 1.0 - b1.powi(s);
        let bc2_sqrt = (1.0 - b2.powi(s)).sqrt();
        let step_size = lr / bc1;
        let scale = match clip {
            Some((factor, _)) if factor < 1.0 => Some(factor as f32),
            _ => None,
        };
        for (((_, var), m), v) in self.params.iter().zip(self.m.iter_mut()).zip(self.v.iter_mut()) {
            let Some(g) = grads.get(var.as_tensor()) else { continue };
            if in_place {
                let g = g.contiguous()?;
                m.inplace_op2(&g, &MomentUpdate { decay: b1 as f32, weight: (1.0 - b1) as f32, scale, square: false })?;
                v.inplace_op2(&g, &MomentUpdate { decay: b2 as f32, weight: (1.0 - b2) as f32, scale, square: true })?;
                let update = ParamUpdate { inv_bc2_sqrt: (1.0 / bc2_sqrt) as f32, eps: self.cfg.eps as f32, step_size: step_size as f32 };
                var.as_tensor().inplace_op3(m, v, &update)?;
                continue;
            }
            let g = match clip {
                Some((factor, _)) if factor < 1.0 => (g * factor)?,
                _ => g.clone(),
            };
            *m = (m.affine(b1, 0.0)? + g.affine(1.0 - b1, 0.0)?)?;
            *v = (v.affine(b2, 0.0)? + g.sqr()?.affine(1.0 - b2, 0.0)?)?;
            let denom = v.sqrt()?.affine(1.0 / bc2_sqrt, self.cfg.eps)?;
            var.set(&(var.as_tensor() - (m.div(&denom)? * step_size)?)?)?;
        }
        Ok(())
    }
}

/// Elements per parallel task of the in-place updates.
const UPDATE_CHUNK: usize = 1 << 14;

/// The contiguous f32 values of a CPU storage seen through `layout`, writable.
fn f32_values_mut<'a>(s: &'a mut CpuStorage, l: &Layout, op: &str) -> candle_core::Result<&'a mut [f32]> {
    match (s, l.contiguous_offsets()) {
        (CpuStorage::F32(v), Some((a, b))) => Ok(&mut v[a..b]),
        _ => candle_core::bail!("{op}: f32 contiguous operands only"),
    }
}

/// `m ← decay·m + weight·ĝ` (or `ĝ²` with `square`), ĝ = g·scale when clipped, in place.
struct MomentUpdate {
    decay: f32,
    weight: f32,
    scale: Option<f32>,
    square: bool,
}

impl InplaceOp2 for MomentUpdate {
    fn name(&self) -> &'static str {
        "adam-moment"
    }

    fn cpu_fwd(&self, dst: &mut CpuStorage, dst_l: &Layout, g: &CpuStorage, g_l: &Layout) -> candle_core::Result<()> {
        let (m, g) = (f32_values_mut(dst, dst_l, self.name())?, slice::<f32>(g, g_l, self.name())?);
        if m.len() != g.len() {
            candle_core::bail!("adam-moment: {} moments for {} gradients", m.len(), g.len());
        }
        let (decay, weight, scale, square) = (self.decay, self.weight, self.scale, self.square);
        m.par_chunks_mut(UPDATE_CHUNK).zip(g.par_chunks(UPDATE_CHUNK)).for_each(|(m, g)| moment_rows(m, g, decay, weight, scale, square));
        Ok(())
    }
}

/// `θ ← θ − step_size·m / (√v·inv_bc2_sqrt + ε)`, in place.
struct ParamUpdate {
    inv_bc2_sqrt: f32,
    eps: f32,
    step_size: f32,
}

impl InplaceOp3 for ParamUpdate {
    fn name(&self) -> &'static str {
        "adam-update"
    }

    fn cpu_fwd(&self, dst: &mut CpuStorage, dst_l: &Layout, m: &CpuStorage, m_l: &Layout, v: &CpuStorage, v_l: &Layout) -> candle_core::Result<()> {
        let (theta, m, v) = (f32_values_mut(dst, dst_l, self.name())?, slice::<f32>(m, m_l, self.name())?, slice::<f32>(v, v_l, self.name())?);
        if theta.len() != m.len() || theta.len() != v.len() {
            candle_core::bail!("adam-update: {} parameters, {} / {} moments", theta.len(), m.len(), v.len());
        }
        let (inv_bc2_sqrt, eps, step_size) = (self.inv_bc2_sqrt, self.eps, self.step_size);
        theta
            .par_chunks_mut(UPDATE_CHUNK)
            .zip(m.par_chunks(UPDATE_CHUNK).zip(v.par_chunks(UPDATE_CHUNK)))
            .for_each(|(theta, (m, v))| param_rows(theta, m, v, inv_bc2_sqrt, eps, step_size));
        Ok(())
    }
}

kernels::simd_kernel! {
    /// [`MomentUpdate`] on one chunk: one loop per case, branch-free inside, so each vectorizes.
    fn moment_rows(m: &mut [f32], g: &[f32], decay: f32, weight: f32, scale: Option<f32>, square: bool) {
        match (scale, square) {
            (None, false) => m.iter_mut().zip(g).for_each(|(m, &g)| *m = *m * decay + g * weight),
            (None, true) => m.iter_mut().zip(g).for_each(|(m, &g)| *m = *m * decay + g * g * weight),
            (Some(s), false) => m.iter_mut().zip(g).for_each(|(m, &g)| *m = *m * decay + g * s * weight),
            (Some(s), true) => m.iter_mut().zip(g).for_each(|(m, &g)| {
                let g = g * s;
                *m = *m * decay + g * g * weight
            }),
        }
    }
}

kernels::simd_kernel! {
    /// [`ParamUpdate`] on one chunk.
    fn param_rows(theta: &mut [f32], m: &[f32], v: &[f32], inv_bc2_sqrt: f32, eps: f32, step_size: f32) {
        for ((p, &m), &v) in theta.iter_mut().zip(m).zip(v) {
            *p -= m / (v.sqrt() * inv_bc2_sqrt + eps) * step_size;
        }
    }
}

/// Exponential moving average of a [`Denoiser`]'s weights (see [`EmaConfig`]), held in a
/// second network of the same configuration and placement.
pub struct Ema {
    cfg: EmaConfig,
    model: Denoiser,
}

impl Ema {
    /// An average that starts as a copy of `online`.
    pub fn new(online: &Denoiser, cfg: EmaConfig) -> Result<Self> {
        Ok(Self { cfg, model: online.to_placement(&online.placement())? })
    }

    /// An average held in `model` (e.g. restored from a checkpoint).
    pub fn from_model(model: Denoiser, cfg: EmaConfig) -> Self {
        Self { cfg, model }
    }

    /// The averaged network (trainable [`Var`]s; use [`Denoiser::frozen`] to run it).
    pub fn model(&self) -> &Denoiser {
        &self.model
    }

    /// Called after optimizer step `step` (1-based): copies during the warm-up, then averages
    /// every `update_every` steps (`ema ← ema − (1 − decay)·(ema − online)`). Returns whether
    /// the average changed.
    pub fn update(&mut self, step: u64, online: &Denoiser) -> Result<bool> {
        let pairs: Vec<(Var, Var)> = self.model.named_vars().into_iter().map(|(_, v)| v).zip(online.named_vars().into_iter().map(|(_, v)| v)).collect();
        if step <= self.cfg.warmup_steps as u64 {
            for (e, o) in &pairs {
                e.set(o.as_tensor())?;
            }
            return Ok(true);
        }
        if !step.is_multiple_of(self.cfg.update_every as u64) {
            return Ok(false);
        }
        let w = 1.0 - self.cfg.decay;
        for (e, o) in &pairs {
            let ev = e.as_tensor();
            e.set(&(ev - ((ev - o.as_tensor())? * w)?)?)?;
        }
        Ok(true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Aggregator, DenoiserConfig};
    use candle_core::Device;

    #[test]
    fn adam_matches_pytorch_formula() {
        // Two parameters θ0 = (1, −2) with loss Σθ² (g = 2θ): three updates by hand, at a
        // constant rate and on a cosine schedule over a run of 3 updates.
        use crate::checkpoint::config::LrSchedule;
        for schedule in [LrSchedule::Constant, LrSchedule::Cosine] {
            let var = Var::from_tensor(&Tensor::new(&[1.0f32, -2.0], &Device::Cpu).unwrap()).unwrap();
            let cfg = AdamConfig { lr: 0.1, schedule, betas: [0.9, 0.99], eps: 1e-8, clip_norm: None };
            let mut adam = Adam::new(vec![("w".into(), var.clone())], cfg.clone()).unwrap();
            adam.set_run_steps(3);
            let (mut theta, mut m, mut v) = ([1.0f64, -2.0], [0.0f64; 2], [0.0f64; 2]);
            for s in 1..=3 {
                // Update s follows s − 1 updates: ½(1 + cos(π(s − 1)/3)) = 1, ¾, ¼ of the peak.
                let lr = match schedule {
                    LrSchedule::Constant => 0.1,
                    LrSchedule::Cosine => 0.1 * [1.0, 0.75, 0.25][s as usize - 1],
                };
                assert!((adam.lr() - lr).abs() < 1e-12, "{schedule:?} update {s}: rate {}", adam.lr());
                let loss = var.as_tensor().sqr().unwrap().sum_all().unwrap();
                adam.step(&loss.backward().unwrap()).unwrap();
                for k in 0..2 {
                    let g = 2.0 * theta[k];
                    m[k] = 0.9 * m[k] + 0.1 * g;
                    v[k] = 0.99 * v[k] + 0.01 * g * g;
                    let denom = v[k].sqrt() / (1.0 - 0.99f64.powi(s)).sqrt() + 1e-8;
                    theta[k] -= lr / (1.0 - 0.9f64.powi(s)) * m[k] / denom;
                }
                let got = var_values(&var).unwrap();
                for k in 0..2 {
                    assert!((got[k] as f64 - theta[k]).abs() < 1e-6, "{schedule:?} step {s}: {got:?} vs {theta:?}");
                }
            }
            assert_eq!(adam.steps(), 3);
            assert_eq!(adam.lr(), if schedule == LrSchedule::Cosine { 0.0 } else { 0.1 });
            let (_, m0, v0) = adam.moments().unwrap().remove(0);
            assert!((m0[0] as f64 - m[0]).abs() < 1e-5 && (v0[1] as f64 - v[1]).abs() < 1e-4);
        }
    }

    /// With clip_norm the gradient is scaled by c/(‖g‖ + 1e-6) when its norm exceeds c: the
    /// first Adam step moves θ by lr·ĝ/(|ĝ| + ε′) per entry, so it is measured on m instead.
    #[test]
    fn gradient_clipping_scales_by_the_global_norm() {
        let a = Var::from_tensor(&Tensor::new(&[3.0f32], &Device::Cpu).unwrap()).unwrap();
        let b = Var::from_tensor(&Tensor::new(&[4.0f32], &Device::Cpu).unwrap()).unwrap();
        let params = vec![("a".to_string(), a.clone()), ("b".to_string(), b.clone())];
        // loss = a·3 + b·4 → g = (3, 4), ‖g‖ = 5
        let loss = || ((a.as_tensor() * 3.0).unwrap() + (b.as_tensor() * 4.0).unwrap()).unwrap().sum_all().unwrap();
        for (clip, want_scale) in [(None, 1.0), (Some(10.0), 1.0), (Some(1.0), 1.0 / (5.0 + 1e-6))] {
            let mut adam = Adam::new(params.clone(), AdamConfig { clip_norm: clip, ..Default::default() }).unwrap();
            let grads = loss().backward().unwrap();
            if let Some((factor, norm)) = adam.clip_factor(&grads).unwrap() {
                assert!((norm - 5.0).abs() < 1e-6, "{norm}");
                assert!((factor - want_scale).abs() < 1e-9, "{factor}");
            }
            adam.step(&grads).unwrap();
            let m = adam.moments().unwrap();
            // m = (1 − β1)·scale·g
            assert!((m[0].1[0] as f64 - 0.1 * want_scale * 3.0).abs() < 1e-6, "{clip:?}: {:?}", m[0].1);
            assert!((m[1].1[0] as f64 - 0.1 * want_scale * 4.0).abs() < 1e-6, "{clip:?}: {:?}", m[1].1);
        }
    }

    /// The in-place CPU route and the tensor-op route give the same bits, with and without
    /// clipping, over several steps.
    #[test]
    fn adam_routes_agree_bit_for_bit() {
        for clip in [None, Some(0.5)] {
            let start: Vec<f32> = (0..40_000).map(|i| ((i * 37 % 101) as f32 - 50.0) * 0.01).collect();
            let run = |in_place: bool| -> (Vec<f32>, Vec<Moments>) {
                let var = Var::from_tensor(&Tensor::new(start.as_slice(), &Device::Cpu).unwrap()).unwrap();
                let mut adam = Adam::new(vec![("w".into(), var.clone())], AdamConfig { lr: 0.01, clip_norm: clip, ..Default::default() }).unwrap();
                for _ in 0..4 {
                    let loss = (var.as_tensor().sqr().unwrap().sum_all().unwrap() + var.as_tensor().sin().unwrap().sum_all().unwrap()).unwrap();
                    adam.step_by(&loss.backward().unwrap(), in_place).unwrap();
                }
                (var_values(&var).unwrap(), adam.moments().unwrap())
            };
            let (a, b) = (run(true), run(false));
            assert!(a.0 != start, "{clip:?}: the parameters moved");
            assert!(a.0.iter().zip(&b.0).all(|(x, y)| x.to_bits() == y.to_bits()), "{clip:?}: parameters differ");
            assert!(a.1[0].1.iter().zip(&b.1[0].1).all(|(x, y)| x.to_bits() == y.to_bits()), "{clip:?}: m differs");
            assert!(a.1[0].2.iter().zip(&b.1[0].2).all(|(x, y)| x.to_bits() == y.to_bits()), "{clip:?}: v differs");
        }
    }

    #[test]
    fn ema_copies_during_warmup_then_decays() {
        let cfg =
            DenoiserConfig { feature_dims: 7, hidden: 8, time_dim: 16, fourier_dim: 8, social_dim: 8, aggregator: Aggregator::None, ..Default::default() };
        let online = Denoiser::new(cfg, 5).unwrap();
        let mut ema = Ema::new(&online, EmaConfig { decay: 0.9, update_every: 2, warmup_steps: 3 }).unwrap();
        let first = |d: &Denoiser| var_values(&d.named_vars()[0].1).unwrap();
        assert_eq!(first(ema.model()), first(&online));
        let shift = |d: &Denoiser, by: f32| {
            for (_, v) in d.named_vars() {
                let x: Vec<f32> = var_values(&v).unwrap().iter().map(|a| a + by).collect();
                set_var(&v, x).unwrap();
            }
        };
        shift(&online, 1.0);
        assert!(ema.update(3, &online).unwrap()); // warm-up: copy
        assert_eq!(first(ema.model()), first(&online));
        let before = first(ema.model());
        shift(&online, 1.0);
        assert!(!ema.update(5, &online).unwrap()); // odd step: nothing
        assert_eq!(first(ema.model()), before);
        assert!(ema.update(6, &online).unwrap()); // 0.9·ema + 0.1·(ema + 1) = ema + 0.1
        for (a, b) in first(ema.model()).iter().zip(&before) {
            assert!((a - b - 0.1).abs() < 1e-6);
        }
    }
}
