//! Social aggregators Γ at the U-Net bottleneck (METHOD.md §3): how each person sees the
//! others' noisy motion.
//!
//! # Relative anchors
//! Each person's input trajectory is expressed relative to its own anchor (root and heading at
//! the last observed frame, METHOD.md §2), so its bottleneck encoding says nothing about where
//! the person stands in the scene. The aggregators therefore also receive, for every ordered
//! pair (receiver i, sender j), the sender's anchor seen from the receiver's:
//!
//! ```text
//! rel_ij = [ Rz(−h_i)·(r_j − r_i) (2) | cos(h_j − h_i), sin(h_j − h_i) (2) ]
//! ```
//!
//! computed from `anchors: [B, P, 4] = (r_x, r_y, cos h, sin h)` in any shared scene frame
//! (a rigid motion of the scene leaves `rel` unchanged). Without anchors every `rel_ij` is the
//! identity `(0, 0, 1, 0)`. `rel_ii` is always the identity.
//!
//! # Γ_E (`mean`)
//! `m_i[t] = W_o · mean_j SiLU(W_h·e_j[t] + W_r·rel_ij + b)`: a one-hidden-layer message from
//! each sender j (its bottleneck encoding `e_j[t]` and its relative anchor, mixed non-linearly
//! so that *what* j does is seen together with *where* j is), averaged over all persons j
//! (the receiver included).
//!
//! # Γ_attn (`attention`)
//! Multi-head attention across persons at each bottleneck frame, with relative-anchor terms in
//! the keys and values: `q_i = W_q e_i`, `k_ij = W_k e_j + ρᵏ_ij`, `v_ij = W_v e_j + ρᵛ_ij`,
//! where `[ρᵏ_ij, ρᵛ_ij] = MLP(rel_ij)` (Linear → SiLU → Linear), `a_ij = softmax_j(q_i·k_ij/√d)`
//! per head, `m_i = W_o Σ_j a_ij v_ij`.
//!
//! Both then concatenate the message to the receiver's own encoding and merge back to the
//! bottleneck width with a 1×1 conv: `e'_i = W_m [e_i | m_i] + b_m`. Every step is symmetric
//! in the persons, so permuting the persons permutes the output, for any P ≥ 1.

use super::config::{Aggregator, DenoiserConfig};
use super::dispatch::Kernels;
use super::layers::{join, Conv, Linear, ParamInit};
use crate::Result;
use candle_core::{DType, Device, Tensor, D};

/// Width of `rel_ij`.
pub const REL_DIMS: usize = 4;

/// `rel_ij` for all pairs (see the module doc).
///
/// # Shapes
/// - `anchors`: `[B, P, 4]` = (r_x, r_y, cos h, sin h), or `None` (identity for every pair)
/// - returns `[B, P, P, 4]` (receiver i, sender j) in `dtype`
pub fn relative_anchors(anchors: Option<&Tensor>, b: usize, p: usize, dtype: DType, device: &Device) -> Result<Tensor> {
    let values = match anchors {
        None => None,
        Some(a) => {
            if a.dims() != [b, p, REL_DIMS] {
                crate::bail!("denoiser: anchors have shape {:?}, expected [{b}, {p}, 4]", a.dims());
            }
            Some(a.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?)
        }
    };
    let rel = relative_anchor_values(values.as_deref(), b, p);
    Ok(Tensor::from_vec(rel, (b, p, p, REL_DIMS), device)?.to_dtype(dtype)?)
}

/// [`relative_anchors`] on plain values.
///
/// # Shapes
/// - `anchors`: `[B, P, 4]` flattened (length checked by the caller), or `None`
/// - returns `[B, P, P, 4]` flattened (receiver i, sender j)
pub(crate) fn relative_anchor_values(anchors: Option<&[f64]>, b: usize, p: usize) -> Vec<f64> {
    let mut rel = Vec::with_capacity(b * p * p * REL_DIMS);
    match anchors {
        None => {
            for _ in 0..b * p * p {
                rel.extend([0.0, 0.0, 1.0, 0.0]);
            }
        }
        Some(a) => {
            for scene in a.chunks_exact(p * REL_DIMS) {
                for ai in scene.chunks_exact(REL_DIMS) {
                    let (xi, yi, ci, si) = (ai[0], ai[1], ai[2], ai[3]);
                    for aj in scene.chunks_exact(REL_DIMS) {
                        let (dx, dy) = (aj[0] - xi, aj[1] - yi);
                        let (cj, sj) = (aj[2], aj[3]);
                        rel.extend([ci * dx + si * dy, -si * dx + ci * dy, cj * ci + sj * si, sj * ci - cj * si]);
                    }
                }
            }
        }
    }
    rel
}

/// A social aggregator with its merge layer.
#[derive(Clone)]
pub(crate) enum Social {
    Mean(MeanAgg),
    Attention(AttentionAgg),
}

impl Social {
    /// `None` for [`Aggregator::None`]. `width` is the bottleneck width (2H).
    pub(crate) fn new(init: &mut ParamInit, prefix: &str, cfg: &DenoiserConfig, width: usize) -> Result<Option<Self>> {
        let s = cfg.social_dim;
        Ok(match cfg.aggregator {
            Aggregator::None => None,
            Aggregator::Mean => Some(Social::Mean(MeanAgg {
                kernels: init.kernels(),
                enc: Linear::new(init, &join(prefix, "enc"), width, s, true)?,
                enc_rel: Linear::new(init, &join(prefix, "enc_rel"), REL_DIMS, s, false)?,
                out: Linear::new(init, &join(prefix, "out"), s, s, true)?,
                merge: Conv::new(init, &join(prefix, "merge"), width + s, width, 1, 1)?,
            })),
            Aggregator::Attention { heads } => Some(Social::Attention(AttentionAgg {
                kernels: init.kernels(),
                heads,
                q: Linear::new(init, &join(prefix, "q"), width, s, true)?,
                k: Linear::new(init, &join(prefix, "k"), width, s, true)?,
                v: Linear::new(init, &join(prefix, "v"), width, s, true)?,
                rel1: Linear::new(init, &join(prefix, "rel1"), REL_DIMS, s, true)?,
                rel2: Linear::new(init, &join(prefix, "rel2"), s, 2 * s, true)?,
                out: Linear::new(init, &join(prefix, "out"), s, s, true)?,
                merge: Conv::new(init, &join(prefix, "merge"), width + s, width, 1, 1)?,
            })),
        })
    }

    /// # Shapes
    /// - `h`: `[B·P, T, C]` bottleneck encodings (person-major within each scene)
    /// - `rel`: `[B, P, P, 4]` from [`relative_anchors`]
    /// - returns `[B·P, T, C]`
    pub(crate) fn forward(&self, h: &Tensor, rel: &Tensor, b: usize, p: usize) -> Result<Tensor> {
        let (msg, merge) = match self {
            Social::Mean(m) => (m.message(h, rel, b, p)?, &m.merge),
            Social::Attention(a) => (a.message(h, rel, b, p)?, &a.merge),
        };
        merge.forward(&Tensor::cat(&[h, &msg], 2)?)
    }

    pub(crate) fn detached(&self) -> Self {
        match self {
            Social::Mean(m) => Social::Mean(MeanAgg {
                kernels: m.kernels,
                enc: m.enc.detached(),
                enc_rel: m.enc_rel.detached(),
                out: m.out.detached(),
                merge: m.merge.detached(),
            }),
            Social::Attention(a) => Social::Attention(AttentionAgg {
                kernels: a.kernels,
                heads: a.heads,
                q: a.q.detached(),
                k: a.k.detached(),
                v: a.v.detached(),
                rel1: a.rel1.detached(),
                rel2: a.rel2.detached(),
                out: a.out.detached(),
                merge: a.merge.detached(),
            }),
        }
    }
}

/// Γ_E: mean over senders of a one-hidden-layer message.
#[derive(Clone)]
pub(crate) struct MeanAgg {
    kernels: Kernels,
    enc: Linear,
    enc_rel: Linear,
    out: Linear,
    merge: Conv,
}

impl MeanAgg {
    /// # Shapes
    /// - `h`: `[B·P, T, C]`, `rel`: `[B, P, P, 4]`; returns `[B·P, T, S]`.
    fn message(&self, h: &Tensor, rel: &Tensor, b: usize, p: usize) -> Result<Tensor> {
        let t = h.dim(1)?;
        let e = self.enc.forward(h)?; // [B·P, T, S]
        let s = e.dim(2)?;
        let e = e.reshape((b, 1, p, t, s))?; // sender j
        let r = self.enc_rel.forward(rel)?.reshape((b, p, p, 1, s))?; // (i, j)
        let pre = e.broadcast_add(&r)?; // [B, P_i, P_j, T, S]
        let m = (self.kernels.silu(&pre)?.sum(2)? / p as f64)?; // [B, P_i, T, S]
        self.out.forward(&m.reshape((b * p, t, s))?)
    }
}

/// Γ_attn: multi-head attention across persons with relative-anchor keys and values.
#[derive(Clone)]
pub(crate) struct AttentionAgg {
    kernels: Kernels,
    heads: usize,
    q: Linear,
    k: Linear,
    v: Linear,
    rel1: Linear,
    rel2: Linear,
    out: Linear,
    merge: Conv,
}

impl AttentionAgg {
    /// # Shapes
    /// - `h`: `[B·P, T, C]`, `rel`: `[B, P, P, 4]`; returns `[B·P, T, S]`.
    fn message(&self, h: &Tensor, rel: &Tensor, b: usize, p: usize) -> Result<Tensor> {
        let t = h.dim(1)?;
        let nh = self.heads;
        // [B·P, T, S] → [B, T, heads, P, dh]: groups (b, t, head), rows = persons
        let per_frame = |x: Tensor| -> Result<Tensor> {
            let s = x.dim(2)?;
            Ok(x.reshape((b, p, t, nh, s / nh))?.permute((0, 2, 3, 1, 4))?.contiguous()?)
        };
        let q = self.q.forward(h)?;
        let s = q.dim(2)?;
        let dh = s / nh;
        let q = per_frame(q)?;
        let kh = per_frame(self.k.forward(h)?)?;
        let vh = per_frame(self.v.forward(h)?)?;
        // relative-anchor terms, [B, P_i, P_j, 2S] → [B, P_i, heads, P_j, dh] each
        let e = self.rel2.forward(&self.kernels.silu(&self.rel1.forward(rel)?)?)?;
        let per_pair = |x: Tensor| -> Result<Tensor> { Ok(x.reshape((b, p, p, nh, dh))?.permute((0, 1, 3, 2, 4))?.contiguous()?) };
        let rk = per_pair(e.narrow(3, 0, s)?)?;
        let rv = per_pair(e.narrow(3, s, s)?)?;
        // logits[b, t, head, i, j] = q_i·(W_k e_j + ρᵏ_ij) / √dh
        let content = self.kernels.bmm(&q, &kh, false, true)?; // [B, T, heads, P_i, P_j]
        let q_by_person = q.permute((0, 3, 2, 1, 4))?.contiguous()?; // [B, P_i, heads, T, dh]
        let geometric = self.kernels.bmm(&q_by_person, &rk, false, true)?; // [B, P_i, heads, T, P_j]
        let geometric = geometric.permute((0, 3, 2, 1, 4))?; // [B, T, heads, P_i, P_j]
        let logits = ((content + geometric)? / (dh as f64).sqrt())?;
        // softmax over senders j (composed: every step has a backward)
        let max = logits.max_keepdim(D::Minus1)?.detach();
        let w = logits.broadcast_sub(&max)?.exp()?;
        let a = w.broadcast_div(&w.sum_keepdim(D::Minus1)?)?; // [B, T, heads, P_i, P_j]
        let out = self.kernels.bmm(&a, &vh, false, false)?; // [B, T, heads, P_i, dh]
        let a_by_person = a.permute((0, 3, 2, 1, 4))?.contiguous()?; // [B, P_i, heads, T, P_j]
        let out_rel = self.kernels.bmm(&a_by_person, &rv, false, false)?.permute((0, 3, 2, 1, 4))?; // [B, T, heads, P_i, dh]
        let out = (out + out_rel)?.permute((0, 3, 1, 2, 4))?.contiguous()?.reshape((b * p, t, s))?;
        self.out.forward(&out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Denoiser;
    use candle_core::IndexOp;

    fn anchors(v: &[[f64; 3]]) -> Tensor {
        // (x, y, heading) → (x, y, cos, sin)
        let flat: Vec<f64> = v.iter().flat_map(|a| [a[0], a[1], a[2].cos(), a[2].sin()]).collect();
        Tensor::from_vec(flat, (1, v.len(), 4), &Device::Cpu).unwrap()
    }

    #[test]
    fn relative_anchors_known_values() {
        use std::f64::consts::FRAC_PI_2;
        // person 0 at the origin facing heading 90°, person 1 at (0, 2) with heading 0
        let r = relative_anchors(Some(&anchors(&[[0.0, 0.0, FRAC_PI_2], [0.0, 2.0, 0.0]])), 1, 2, DType::F64, &Device::Cpu)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1::<f64>()
            .unwrap();
        let want: Vec<f64> = [
            [0.0, 0.0, 1.0, 0.0],  // 0 seen from 0: identity
            [2.0, 0.0, 0.0, -1.0], // 1 seen from 0: Rz(−90°)·(0, 2) = (2, 0), heading 0 − 90°
            [0.0, -2.0, 0.0, 1.0], // 0 seen from 1: (0, −2), heading 90° − 0
            [0.0, 0.0, 1.0, 0.0],  // 1 seen from 1: identity
        ]
        .concat();
        for (a, b) in r.iter().zip(&want) {
            assert!((a - b).abs() < 1e-12, "{r:?}");
        }
        let none = relative_anchors(None, 2, 3, DType::F32, &Device::Cpu).unwrap();
        assert_eq!(none.dims(), [2, 3, 3, 4]);
        assert_eq!(none.i((1, 2, 0)).unwrap().to_vec1::<f32>().unwrap(), vec![0.0, 0.0, 1.0, 0.0]);
    }

    /// Moving the whole scene rigidly in the ground plane changes no `rel`, hence no output.
    #[test]
    fn rigid_motion_of_the_scene_changes_nothing() {
        let a = [[0.3, -1.0, 0.2], [2.0, 1.5, -2.5], [-1.2, 0.4, 1.9]];
        let (c, s, tx, ty) = (0.7f64.cos(), 0.7f64.sin(), 4.0, -3.0);
        let moved: Vec<[f64; 3]> = a.iter().map(|p| [c * p[0] - s * p[1] + tx, s * p[0] + c * p[1] + ty, p[2] + 0.7]).collect();
        let r1 = relative_anchors(Some(&anchors(&a)), 1, 3, DType::F64, &Device::Cpu).unwrap();
        let r2 = relative_anchors(Some(&anchors(&moved)), 1, 3, DType::F64, &Device::Cpu).unwrap();
        let d = (r1 - r2).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f64>().unwrap();
        assert!(d < 1e-12, "{d}");

        let cfg = DenoiserConfig { feature_dims: 7, hidden: 8, time_dim: 16, fourier_dim: 8, social_dim: 8, ..Default::default() };
        let net = Denoiser::with_dtype(cfg, 1, DType::F64).unwrap();
        let x = Tensor::arange(0.0f64, 168.0, &Device::Cpu).unwrap().sin().unwrap().reshape((1, 3, 8, 7)).unwrap();
        let t = Tensor::new(&[10u32], &Device::Cpu).unwrap();
        let o1 = net.forward(&x, &t, Some(&anchors(&a))).unwrap();
        let o2 = net.forward(&x, &t, Some(&anchors(&moved))).unwrap();
        let d = (o1 - o2).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f64>().unwrap();
        assert!(d < 1e-12, "{d}");
    }
}
