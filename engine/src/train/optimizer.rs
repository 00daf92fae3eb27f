//! Adam and the exponential moving average of the weights.
//!
//! Both work on plain `Vec<f32>` copies of the parameters in the sorted order of
//! [`Denoiser::named_vars`] (never a `VarMap`'s random order, CANDLE_NOTES.md trap 5), so their
//! state is saved and restored exactly and every update is reproducible bit for bit.

use super::config::{AdamConfig, EmaConfig};
use crate::model::Denoiser;
use crate::{bail, Result};
use candle_core::backprop::GradStore;
use candle_core::{DType, Tensor, Var};
use rayon::prelude::*;

/// The values of a parameter as a flat `Vec<f32>`.
pub(crate) fn var_values(var: &Var) -> Result<Vec<f32>> {
    if var.dtype() != DType::F32 {
        bail!("training supports f32 parameters only, got {:?}", var.dtype());
    }
    Ok(var.as_tensor().flatten_all()?.to_vec1::<f32>()?)
}

/// Overwrites a parameter with `values` (same element count).
pub(crate) fn set_var(var: &Var, values: Vec<f32>) -> Result<()> {
    if values.len() != var.elem_count() {
        bail!("parameter of shape {:?} cannot take {} values", var.dims(), values.len());
    }
    let t = Tensor::from_vec(values, var.shape(), var.device())?;
    Ok(var.set(&t)?)
}

/// Adam as PyTorch's `torch.optim.Adam` (no weight decay, no amsgrad):
///
/// ```text
/// m ← β1·m + (1 − β1)·g;   v ← β2·v + (1 − β2)·g²
/// θ ← θ − (lr / (1 − β1^s)) · m / (√v / √(1 − β2^s) + ε)      (s = step count, 1-based)
/// ```
///
/// A parameter without a gradient is skipped (its moments do not move), as in PyTorch.
pub struct Adam {
    cfg: AdamConfig,
    params: Vec<(String, Var)>,
    m: Vec<Vec<f32>>,
    v: Vec<Vec<f32>>,
    steps: u64,
}

impl Adam {
    /// Zero moments for `params` (sorted by name, e.g. [`Denoiser::named_vars`]).
    pub fn new(params: Vec<(String, Var)>, cfg: AdamConfig) -> Self {
        let m = params.iter().map(|(_, v)| vec![0.0; v.elem_count()]).collect();
        let v = params.iter().map(|(_, v)| vec![0.0; v.elem_count()]).collect();
        Self { cfg, params, m, v, steps: 0 }
    }

    /// Number of updates made so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// The learning rate of the next update (constant).
    pub fn lr(&self) -> f64 {
        self.cfg.lr
    }

    /// `(name, m, v)` for every parameter, sorted by name.
    pub fn moments(&self) -> impl Iterator<Item = (&str, &[f32], &[f32])> {
        self.params.iter().zip(self.m.iter().zip(&self.v)).map(|((n, _), (m, v))| (n.as_str(), m.as_slice(), v.as_slice()))
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
        let (m, v) = moments.into_iter().unzip();
        self.m = m;
        self.v = v;
        self.steps = steps;
        Ok(())
    }

    /// One update from the gradients of a loss.
    pub fn step(&mut self, grads: &GradStore) -> Result<()> {
        self.steps += 1;
        let s = self.steps as i32;
        let [b1, b2] = self.cfg.betas;
        let bc1 = 1.0 - b1.powi(s);
        let bc2_sqrt = (1.0 - b2.powi(s)).sqrt();
        let step_size = (self.cfg.lr / bc1) as f32;
        let (b1f, b2f, eps) = (b1 as f32, b2 as f32, self.cfg.eps as f32);
        let bc2_sqrt = bc2_sqrt as f32;
        let mut work = Vec::with_capacity(self.params.len());
        for (((_, var), m), v) in self.params.iter().zip(self.m.iter_mut()).zip(self.v.iter_mut()) {
            if let Some(g) = grads.get(var.as_tensor()) {
                work.push((var, m, v, g.flatten_all()?.to_vec1::<f32>()?));
            }
        }
        work.into_par_iter().try_for_each(|(var, m, v, g)| -> Result<()> {
            let mut p = var_values(var)?;
            for k in 0..p.len() {
                let gk = g[k];
                m[k] = b1f * m[k] + (1.0 - b1f) * gk;
                v[k] = b2f * v[k] + (1.0 - b2f) * gk * gk;
                let denom = v[k].sqrt() / bc2_sqrt + eps;
                p[k] -= step_size * m[k] / denom;
            }
            set_var(var, p)
        })
    }
}

/// Exponential moving average of a [`Denoiser`]'s weights (see [`EmaConfig`]), held in a
/// second network of the same configuration.
pub struct Ema {
    cfg: EmaConfig,
    model: Denoiser,
}

impl Ema {
    /// An average that starts as a copy of `online`.
    pub fn new(online: &Denoiser, cfg: EmaConfig) -> Result<Self> {
        let model = Denoiser::new(online.config().clone(), 0)?;
        for ((_, e), (_, o)) in model.named_vars().iter().zip(online.named_vars().iter()) {
            e.set(o.as_tensor())?;
        }
        Ok(Self { cfg, model })
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
    /// every `update_every` steps. Returns whether the average changed.
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
        let w = (1.0 - self.cfg.decay) as f32;
        pairs.par_iter().try_for_each(|(e, o)| -> Result<()> {
            let mut ev = var_values(e)?;
            let ov = var_values(o)?;
            for (a, b) in ev.iter_mut().zip(&ov) {
                *a -= w * (*a - b);
            }
            set_var(e, ev)
        })?;
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
        // One scalar parameter θ0 = 1 with loss θ² (g = 2θ): three updates by hand.
        let var = Var::from_tensor(&Tensor::new(&[1.0f32, -2.0], &Device::Cpu).unwrap()).unwrap();
        let cfg = AdamConfig { lr: 0.1, betas: [0.9, 0.99], eps: 1e-8 };
        let mut adam = Adam::new(vec![("w".into(), var.clone())], cfg.clone());
        let (mut theta, mut m, mut v) = ([1.0f64, -2.0], [0.0f64; 2], [0.0f64; 2]);
        for s in 1..=3 {
            let loss = var.as_tensor().sqr().unwrap().sum_all().unwrap();
            adam.step(&loss.backward().unwrap()).unwrap();
            for k in 0..2 {
                let g = 2.0 * theta[k];
                m[k] = 0.9 * m[k] + 0.1 * g;
                v[k] = 0.99 * v[k] + 0.01 * g * g;
                let denom = v[k].sqrt() / (1.0 - 0.99f64.powi(s)).sqrt() + 1e-8;
                theta[k] -= 0.1 / (1.0 - 0.9f64.powi(s)) * m[k] / denom;
            }
            let got = var_values(&var).unwrap();
            for k in 0..2 {
                assert!((got[k] as f64 - theta[k]).abs() < 1e-6, "step {s}: {got:?} vs {theta:?}");
            }
        }
        assert_eq!(adam.steps(), 3);
        let (_, m0, v0) = adam.moments().next().unwrap();
        assert!((m0[0] as f64 - m[0]).abs() < 1e-5 && (v0[1] as f64 - v[1]).abs() < 1e-4);
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
