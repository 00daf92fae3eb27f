//! The social-signal network: a per-frame speaking detector and a buyer detector on one
//! shared encoder (REFERENCE.md §5.3 records the reference's two separate models; this is the
//! small, order-invariant version of their intent).
//!
//! ```text
//! x_p   [T, 6J]  standardized pose + velocity of person p            (inputs.rs)
//! r_pq  [T, 7]   standardized pair features, q ≠ p
//! e_p  = SiLU(Linear(x_p))                                  [T, E]
//! h_p  = BiGRU₁(e_p)                                        [T, 2H]   own motion
//! m_pq = SiLU(Linear_h(h_q) + Linear_r(r_pq))               [T, M]    what q does, seen from p
//! c_p  = [mean_q m_pq, max_q m_pq]                          [T, 2M]   order-invariant (0 if alone)
//! s_p  = BiGRU₂([h_p, c_p])                                 [T, 2H]
//! speaking logit  = Linear(s_p)                             [T]
//! buyer score     = Linear(SiLU(Linear([mean_t s_p, max_t s_p])))   one per person;
//!                   softmax across persons
//! ```
//!
//! Every person is processed with the same weights and the others enter only through the
//! mean and max over q, so permuting the persons permutes the outputs (tested).

use super::gru::BiGru;
use super::inputs::{other, PAIR_DIMS};
use crate::model::layers::{Linear, ParamInit};
use crate::model::{Kernels, Placement};
use crate::{bail, Result};
use candle_core::{DType, Tensor, Var};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Widths of the network.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NetConfig {
    /// Person feature dims (6J; set from the skeleton).
    pub person_dims: usize,
    /// Per-frame embedding width E.
    pub embed: usize,
    /// GRU width H per direction (outputs are 2H).
    pub hidden: usize,
    /// Message width M of the pooling across persons.
    pub message: usize,
}

impl Default for NetConfig {
    fn default() -> Self {
        Self { person_dims: 6 * 19, embed: 32, hidden: 32, message: 32 }
    }
}

impl NetConfig {
    /// Checks that every width is positive.
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [("person_dims", self.person_dims), ("embed", self.embed), ("hidden", self.hidden), ("message", self.message)] {
            if v == 0 {
                bail!("classifier config: {name} must be at least 1");
            }
        }
        Ok(())
    }
}

/// What the network predicts for a batch.
pub struct NetOutput {
    /// Speaking logits `[B, P, T]`.
    pub speaking: Tensor,
    /// Buyer scores (logits of a softmax across persons) `[B, P]`.
    pub buyer: Tensor,
}

/// See the module docs.
#[derive(Clone)]
pub struct SocialSignalNet {
    cfg: NetConfig,
    embed: Linear,
    gru1: BiGru,
    msg_self: Linear,
    msg_pair: Linear,
    gru2: BiGru,
    speak: Linear,
    buyer_hidden: Linear,
    buyer_out: Linear,
    vars: BTreeMap<String, Var>,
    kernels: Kernels,
}

impl SocialSignalNet {
    /// A network with parameters drawn from `seed` (PyTorch-style uniform ±1/√fan_in).
    pub fn new(cfg: NetConfig, seed: u64) -> Result<Self> {
        Self::with_dtype(cfg, seed, DType::F32)
    }

    pub(crate) fn with_dtype(cfg: NetConfig, seed: u64, dtype: DType) -> Result<Self> {
        Self::build(cfg, seed, &Placement::cpu().with_dtype(dtype))
    }

    /// As [`SocialSignalNet::new`] at `placement` (the same parameters from a seed on every
    /// device; the composed kernels off the CPU).
    pub fn build(cfg: NetConfig, seed: u64, placement: &Placement) -> Result<Self> {
        cfg.validate()?;
        let mut init = ParamInit::new(seed, placement.dtype, placement.device.clone()).with_kernels(placement.kernels)?;
        let kernels = init.kernels();
        let (e, h, m) = (cfg.embed, cfg.hidden, cfg.message);
        let embed = Linear::new(&mut init, "embed", cfg.person_dims, e, true)?;
        let gru1 = BiGru::new(&mut init, "gru1", e, h)?;
        let msg_self = Linear::new(&mut init, "message.self", 2 * h, m, true)?;
        let msg_pair = Linear::new(&mut init, "message.pair", PAIR_DIMS, m, false)?;
        let gru2 = BiGru::new(&mut init, "gru2", 2 * h + 2 * m, h)?;
        let speak = Linear::new(&mut init, "speaking", 2 * h, 1, true)?;
        let buyer_hidden = Linear::new(&mut init, "buyer.hidden", 4 * h, h, true)?;
        let buyer_out = Linear::new(&mut init, "buyer.out", h, 1, true)?;
        let vars = init.finish();
        Ok(Self { cfg, embed, gru1, msg_self, msg_pair, gru2, speak, buyer_hidden, buyer_out, vars, kernels })
    }

    /// The device of the parameters.
    pub fn device(&self) -> &candle_core::Device {
        self.vars.values().next().map_or(&candle_core::Device::Cpu, |v| v.device())
    }

    /// The configuration.
    pub fn config(&self) -> &NetConfig {
        &self.cfg
    }

    /// A copy whose forward builds no autograd graph (for inference).
    pub fn frozen(&self) -> Self {
        Self {
            cfg: self.cfg.clone(),
            embed: self.embed.detached(),
            gru1: self.gru1.detached(),
            msg_self: self.msg_self.detached(),
            msg_pair: self.msg_pair.detached(),
            gru2: self.gru2.detached(),
            speak: self.speak.detached(),
            buyer_hidden: self.buyer_hidden.detached(),
            buyer_out: self.buyer_out.detached(),
            vars: self.vars.clone(),
            kernels: self.kernels,
        }
    }

    /// # Shapes
    /// - `person`: `[B, P, T, 6J]`; `pairs`: `[B, P, P − 1, T, 7]` (others in the slot order of
    ///   [`other`]); both standardized.
    /// - output: speaking logits `[B, P, T]`, buyer scores `[B, P]`.
    pub fn forward(&self, person: &Tensor, pairs: &Tensor) -> Result<NetOutput> {
        let (b, p, t, d) = person.dims4()?;
        if d != self.cfg.person_dims || t == 0 || p == 0 {
            bail!("classifier: person features have shape [{b}, {p}, {t}, {d}], expected [B, P ≥ 1, T ≥ 1, {}]", self.cfg.person_dims);
        }
        let want = [b, p, p - 1, t, PAIR_DIMS];
        if pairs.dims() != want {
            bail!("classifier: pair features have shape {:?}, expected {want:?}", pairs.dims());
        }
        let x = person.reshape((b * p, t, d))?;
        let e = self.kernels.silu(&self.embed.forward(&x)?)?;
        let h1 = self.gru1.forward(&e)?; // [BP, T, 2H]
        let pooled = if p > 1 {
            let own = self.msg_self.forward(&h1)?.reshape((b, p, t, self.cfg.message))?;
            let rel = self.msg_pair.forward(&pairs.contiguous()?)?; // [B, P, P−1, T, M]
            pool_messages(self.kernels, &own, &rel)?.reshape((b * p, t, 2 * self.cfg.message))?
        } else {
            Tensor::zeros((b * p, t, 2 * self.cfg.message), x.dtype(), x.device())?
        };
        let s = self.gru2.forward(&Tensor::cat(&[&h1, &pooled], 2)?)?; // [BP, T, 2H]
        let speaking = self.speak.forward(&s)?.reshape((b, p, t))?;
        let summary = Tensor::cat(&[s.mean(1)?, s.max(1)?], 1)?; // [BP, 4H]
        let buyer = self.buyer_out.forward(&self.kernels.silu(&self.buyer_hidden.forward(&summary)?)?)?.reshape((b, p))?;
        Ok(NetOutput { speaking, buyer })
    }
}

/// Messages to every person from each of the others, pooled by mean and max:
/// `m_pq = SiLU(own_q + rel_pq)`, returns `[mean_q m_pq, max_q m_pq]`.
///
/// # Shapes
/// - `own`: `[B, P, T, M]`; `rel`: `[B, P, P − 1, T, M]` (P ≥ 2); returns `[B, P, T, 2M]`.
pub(crate) fn pool_messages(kernels: Kernels, own: &Tensor, rel: &Tensor) -> Result<Tensor> {
    let (b, p, t, m) = own.dims4()?;
    let idx: Vec<u32> = (0..p).flat_map(|pp| (0..p - 1).map(move |k| other(pp, k) as u32)).collect();
    let idx = Tensor::from_vec(idx, p * (p - 1), own.device())?;
    let gathered = own.index_select(&idx, 1)?.reshape((b, p, p - 1, t, m))?;
    let msg = kernels.silu(&(gathered + rel)?)?;
    Ok(Tensor::cat(&[msg.mean(2)?, msg.max(2)?], 3)?)
}

impl crate::model::Parameterized for SocialSignalNet {
    fn vars(&self) -> &BTreeMap<String, Var> {
        &self.vars
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ops::tests::grad_check;
    use crate::model::Parameterized;
    use candle_core::Device;

    /// The network on the composed kernels (the GPU route) against the custom ones: outputs
    /// and every parameter's gradient, from one seed.
    #[test]
    fn composed_and_custom_kernels_agree() {
        let cfg = NetConfig { person_dims: 6, embed: 8, hidden: 8, message: 8 };
        let composed = Placement { kernels: Kernels::Composed(crate::model::Precision::F32), ..Placement::cpu() };
        let (a, c) = (SocialSignalNet::new(cfg.clone(), 4).unwrap(), SocialSignalNet::build(cfg, 4, &composed).unwrap());
        let (x, pr) = rand_inputs(2, 3, 9, 6, 5);
        let (oa, oc) = (a.forward(&x, &pr).unwrap(), c.forward(&x, &pr).unwrap());
        let diff = |x: &Tensor, y: &Tensor| (x - y).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap();
        assert!(diff(&oa.speaking, &oc.speaking) < 1e-5 && diff(&oa.buyer, &oc.buyer) < 1e-5);
        let loss = |o: &NetOutput| (o.speaking.sum_all().unwrap() + o.buyer.sqr().unwrap().sum_all().unwrap()).unwrap();
        let (ga, gc) = (loss(&oa).backward().unwrap(), loss(&oc).backward().unwrap());
        for ((name, va), (_, vc)) in a.named_vars().iter().zip(c.named_vars()) {
            let (x, y) = (ga.get(va).unwrap(), gc.get(&vc).unwrap());
            let scale = x.abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap().max(1e-6);
            assert!(diff(x, y) / scale < 1e-4, "{name}: relative gradient difference {}", diff(x, y) / scale);
        }
    }

    #[test]
    fn message_pooling_gradient_matches_finite_differences() {
        for p in [2, 3, 4] {
            let err = grad_check(&[&[2, p, 5, 3], &[2, p, p - 1, 5, 3]], |x| {
                pool_messages(Kernels::CUSTOM, &x[0], &x[1]).map_err(|e| candle_core::Error::Msg(e.to_string()))
            });
            eprintln!("message pooling P={p}: relative error {err:.2e}");
            assert!(err < 1e-6, "P={p}: {err}");
        }
    }

    fn rand_inputs(b: usize, p: usize, t: usize, d: usize, seed: u64) -> (Tensor, Tensor) {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let mut r = |n: usize| (0..n).map(|_| rng.gen_range(-1.0f32..1.0)).collect::<Vec<_>>();
        let x = Tensor::from_vec(r(b * p * t * d), (b, p, t, d), &Device::Cpu).unwrap();
        let pr = Tensor::from_vec(r(b * p * (p - 1) * t * PAIR_DIMS), (b, p, p - 1, t, PAIR_DIMS), &Device::Cpu).unwrap();
        (x, pr)
    }

    #[test]
    fn every_parameter_gets_a_finite_nonzero_gradient() {
        let cfg = NetConfig { person_dims: 12, embed: 6, hidden: 5, message: 4 };
        let net = SocialSignalNet::new(cfg, 1).unwrap();
        let (x, pr) = rand_inputs(2, 3, 7, 12, 2);
        let out = net.forward(&x, &pr).unwrap();
        assert_eq!((out.speaking.dims(), out.buyer.dims()), (&[2, 3, 7][..], &[2, 3][..]));
        let loss = (out.speaking.sqr().unwrap().sum_all().unwrap() + out.buyer.sqr().unwrap().sum_all().unwrap()).unwrap();
        let grads = loss.backward().unwrap();
        let vars = net.named_vars();
        assert_eq!(vars.len(), 2 + 8 + 2 + 1 + 8 + 2 + 2 + 2);
        for (name, v) in &vars {
            let g: Vec<f32> = grads.get(v).unwrap_or_else(|| panic!("{name}: no gradient")).flatten_all().unwrap().to_vec1().unwrap();
            assert!(g.iter().all(|x| x.is_finite()) && g.iter().any(|&x| x != 0.0), "{name}: {g:?}");
        }
        assert_eq!(net.num_params(), vars.iter().map(|(_, v)| v.elem_count()).sum::<usize>());
        // Frozen: same outputs, no graph.
        let f = net.frozen().forward(&x, &pr).unwrap();
        assert_eq!(f.speaking.flatten_all().unwrap().to_vec1::<f32>().unwrap(), out.speaking.flatten_all().unwrap().to_vec1::<f32>().unwrap());
        assert!(f.speaking.sum_all().unwrap().backward().unwrap().get(&vars[0].1).is_none());
    }

    #[test]
    fn permuting_persons_permutes_the_outputs() {
        let cfg = NetConfig { person_dims: 12, embed: 6, hidden: 5, message: 4 };
        let net = SocialSignalNet::new(cfg, 3).unwrap();
        let (x, pr) = rand_inputs(1, 3, 6, 12, 4);
        let out = net.forward(&x, &pr).unwrap();
        // New order: persons (2, 0, 1). Person features are reindexed; pair slots too (slot k of
        // new person a holds the pair (old p, old q) of the same two people).
        let perm = [2usize, 0, 1];
        let xs = x.to_dtype(DType::F32).unwrap();
        let xv: Vec<f32> = xs.flatten_all().unwrap().to_vec1().unwrap();
        let pv: Vec<f32> = pr.flatten_all().unwrap().to_vec1().unwrap();
        let (t, d) = (6, 12);
        let mut x2 = vec![0.0f32; xv.len()];
        let mut p2 = vec![0.0f32; pv.len()];
        for (a, &old_a) in perm.iter().enumerate() {
            x2[a * t * d..(a + 1) * t * d].copy_from_slice(&xv[old_a * t * d..(old_a + 1) * t * d]);
            for k in 0..2 {
                let old_q = perm[other(a, k)];
                let old_k = (0..2).find(|&kk| other(old_a, kk) == old_q).unwrap();
                let n = t * PAIR_DIMS;
                p2[(a * 2 + k) * n..][..n].copy_from_slice(&pv[(old_a * 2 + old_k) * n..][..n]);
            }
        }
        let out2 = net
            .forward(&Tensor::from_vec(x2, (1, 3, t, d), &Device::Cpu).unwrap(), &Tensor::from_vec(p2, (1, 3, 2, t, PAIR_DIMS), &Device::Cpu).unwrap())
            .unwrap();
        let s1: Vec<Vec<f32>> = out.speaking.squeeze(0).unwrap().to_vec2().unwrap();
        let s2: Vec<Vec<f32>> = out2.speaking.squeeze(0).unwrap().to_vec2().unwrap();
        let b1: Vec<f32> = out.buyer.squeeze(0).unwrap().to_vec1().unwrap();
        let b2: Vec<f32> = out2.buyer.squeeze(0).unwrap().to_vec1().unwrap();
        for (a, &old_a) in perm.iter().enumerate() {
            for (u, v) in s2[a].iter().zip(&s1[old_a]) {
                assert!((u - v).abs() < 1e-5, "{u} vs {v}");
            }
            assert!((b2[a] - b1[old_a]).abs() < 1e-5);
        }
        // One person alone works (no others to pool), and bad shapes are errors.
        let (x1, _) = rand_inputs(1, 2, 4, 12, 5);
        let alone = x1.narrow(1, 0, 1).unwrap();
        let none = Tensor::zeros((1, 1, 0, 4, PAIR_DIMS), DType::F32, &Device::Cpu).unwrap();
        assert_eq!(net.forward(&alone, &none).unwrap().speaking.dims(), &[1, 1, 4]);
        assert!(net.forward(&x, &none).is_err());
    }
}
