//! Forward-only denoiser for sampling: the network of [`super::unet`] on plain f32 weights,
//! with no autograd, no candle tensors and no allocation per denoising step.
//!
//! [`InferenceNet::new`] copies the weights of a [`Denoiser`] once (the concatenating convs
//! split by input part, so no `cat` is ever materialized). [`InferenceNet::forward`] computes
//! the same x̂0 as [`Denoiser::forward`] (up to f32 rounding, tested ≤ 1e-4):
//!
//! - activations live in a workspace kept between calls (reallocated only when the batch or
//!   canvas size changes), each sequence preceded by [`PAD`] zero frames (and followed by
//!   one, for [`Causality::Lookahead`]'s centred convs), so a causal k3 conv
//!   (stride 1 or 2) is one gemm whose left operand is the input seen as overlapping rows of
//!   `3·C_in` values — no im2col, no padding copy, no per-op zero-filled buffer — or, for
//!   stride 1, Winograd F(2, 3) with two thirds of the multiply-adds ([`K3Conv`]; 1.25–1.34×
//!   faster per denoising step in all but one noisy row, docs/results.md);
//! - work is split into tasks of (sequence, block of frames) run by rayon, each gemm
//!   single-threaded, so both cores stay busy for any person count without oversubscription;
//! - each conv task ends with its fused elementwise epilogue while its rows are in cache:
//!   bias + SiLU + LayerNorm after a residual block's first conv; bias + FiLM + residual (or
//!   the 1×1 projection, accumulated by the same gemm call sequence) after its second.
//!
//! Results are deterministic and do not depend on the thread count or on the other sequences
//! of the batch: task boundaries are fixed per sequence, so sample k of a batch of K is bit for
//! bit sample k computed alone.

use super::aggregator::{relative_anchor_values, REL_DIMS};
use super::config::{Aggregator, Causality, DenoiserConfig};
use super::kernels::{self, gemm_rows, WINO_ALPHA, WINO_G, WINO_M};
use super::ops::{K3Conv, Real};
use super::unet::{clean_prefixes, Denoiser, TIME_FACTOR};
use crate::model::Parameterized;
use crate::{bail, Result};
use candle_core::DType;
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::Mutex;

/// Zero frames before every sequence: the left padding of a causal conv with kernel 3.
const PAD: usize = 2;
/// Most frames per parallel task (large blocks keep the gemms' weight packing cheap).
const MAX_CHUNK: usize = 512;
/// Kernel width of the U-Net's convs.
const KERNEL: usize = 3;

/// The network's parameters by name, as f32 values with their shapes.
struct Params(HashMap<String, (Vec<usize>, Vec<f32>)>);

impl Params {
    fn of(net: &Denoiser) -> Result<Self> {
        let mut map = HashMap::new();
        for (name, var) in net.named_vars() {
            let t = var.as_tensor();
            map.insert(name, (t.dims().to_vec(), t.flatten_all()?.to_dtype(DType::F32)?.to_vec1::<f32>()?));
        }
        Ok(Self(map))
    }

    fn take(&mut self, name: &str, shape: &[usize]) -> Result<Vec<f32>> {
        match self.0.remove(name) {
            Some((s, v)) if s == shape => Ok(v),
            Some((s, _)) => bail!("inference weights: {name} has shape {s:?}, expected {shape:?}"),
            None => bail!("inference weights: parameter {name} is missing"),
        }
    }
}

/// One input part of a convolution: `C_in` channels and the weights, `[K·C_in, C_out]`
/// (tap-major, as the input rows are read), or for a Winograd conv the four transformed taps
/// `[4, C_in, C_out]`.
struct Part {
    cin: usize,
    w: Vec<f32>,
}

/// A causal conv (a per-frame linear layer when `k = 1`) whose input channels come from one or
/// more buffers (the U-Net's concatenations). Stride-1 k3 convs may run as Winograd F(2, 3)
/// ([`K3Conv`]).
struct ConvW {
    k: usize,
    stride: usize,
    cout: usize,
    parts: Vec<Part>,
    bias: Vec<f32>,
    winograd: bool,
    /// Frames the conv reads past its output: 0 (causal) or 1 (centred, stride 1 only; the
    /// frame after a sequence's end reads as zero).
    ahead: usize,
}

impl ConvW {
    /// `{prefix}.weight` `[K, Σ parts, C_out]` split by input part, and `{prefix}.bias`
    /// (zeros when the layer has none).
    fn load(params: &mut Params, prefix: &str, parts: &[usize], cout: usize, k: usize, stride: usize, bias: bool) -> Result<Self> {
        let cin: usize = parts.iter().sum();
        let w = params.take(&format!("{prefix}.weight"), &[k, cin, cout])?;
        let bias = if bias { params.take(&format!("{prefix}.bias"), &[cout])? } else { vec![0.0; cout] };
        let mut out = Vec::with_capacity(parts.len());
        let mut offset = 0;
        for &pc in parts {
            let mut pw = Vec::with_capacity(k * pc * cout);
            for tap in 0..k {
                let rows = (tap * cin + offset) * cout..(tap * cin + offset + pc) * cout;
                pw.extend_from_slice(&w[rows]);
            }
            out.push(Part { cin: pc, w: pw });
            offset += pc;
        }
        Ok(Self { k, stride, cout, parts: out, bias, winograd: false, ahead: 0 })
    }

    /// Replaces the taps `W_k` of every part by `G_i = Σ_k G[i][k]·W_k` (in f64).
    fn transform_to_winograd(&mut self) {
        for part in &mut self.parts {
            let len = part.cin * self.cout;
            let mut w = Vec::with_capacity(WINO_ALPHA * len);
            for g in WINO_G {
                w.extend((0..len).map(|e| (0..KERNEL).map(|k| g[k] * part.w[k * len + e] as f64).sum::<f64>() as f32));
            }
            part.w = w;
        }
        self.winograd = true;
    }

    /// Output rows `r0..r1` of sequence `seq`: `dst = Σ_parts conv(src_part)` (`+= ` with
    /// `accumulate`), without bias.
    ///
    /// # Safety
    /// The views must fit this conv (channels, lengths) and `dst` must not overlap a source.
    unsafe fn rows(&self, srcs: &[View], dst: View, seq: usize, r0: usize, r1: usize, accumulate: bool) {
        debug_assert_eq!(srcs.len(), self.parts.len());
        debug_assert_eq!(dst.c, self.cout);
        if self.winograd {
            assert!(!accumulate, "Winograd convs overwrite their output");
            return self.winograd_rows(srcs, dst, seq, r0, r1);
        }
        for (i, (part, src)) in self.parts.iter().zip(srcs).enumerate() {
            debug_assert_eq!(src.c, part.cin);
            // output o reads frames o·s − (K − 1) + ahead … o·s + ahead: one row of K·C_in
            // values (frame L of a sequence is the next one's padding, or the zero row after
            // the last sequence)
            let first = (r0 * self.stride + 1 + self.ahead) as isize - self.k as isize;
            gemm_rows(
                r1 - r0,
                self.cout,
                self.k * part.cin,
                dst.at(seq, r0 as isize),
                dst.c,
                src.at(seq, first),
                self.stride * src.c,
                part.w.as_ptr(),
                accumulate || i > 0,
            );
        }
    }
}

impl ConvW {
    /// [`ConvW::rows`] as Winograd F(2, 3): input transform of the part's frames
    /// `r0 − 2 … r1`, four gemms per part (accumulated over parts), output transform.
    ///
    /// # Safety
    /// As [`ConvW::rows`].
    unsafe fn winograd_rows(&self, srcs: &[View], dst: View, seq: usize, r0: usize, r1: usize) {
        let tiles = (r1 - r0).div_ceil(WINO_M);
        let cin_max = self.parts.iter().map(|p| p.cin).max().unwrap_or(0);
        let cout = self.cout;
        let (u_len, m_len) = (WINO_ALPHA * tiles * cin_max, WINO_ALPHA * tiles * cout);
        // The per-thread scratch of the Winograd convs (transformed inputs and products).
        f32::with_scratch(u_len + m_len, |buf| {
            let (u, m) = buf.split_at_mut(u_len);
            for (p, (part, src)) in self.parts.iter().zip(srcs).enumerate() {
                let cin = part.cin;
                debug_assert_eq!(src.c, cin);
                // frames r0 − 2 … r0 + 2·tiles − 1 (shifted by `ahead`: frame L is the zero
                // frame after the sequence), those past it read as zeros
                let end = (r0 + WINO_M * tiles).min(src.l);
                let x = std::slice::from_raw_parts(src.at(seq, (r0 + self.ahead) as isize - 2), (end + 2 - r0) * cin);
                let u = &mut u[..WINO_ALPHA * tiles * cin];
                kernels::winograd_input(u, x, cin, tiles, tiles * cin);
                for i in 0..WINO_ALPHA {
                    gemm_rows(
                        tiles,
                        cout,
                        cin,
                        m.as_mut_ptr().add(i * tiles * cout),
                        cout,
                        u.as_ptr().add(i * tiles * cin),
                        cin,
                        part.w.as_ptr().add(i * cin * cout),
                        p > 0,
                    );
                }
            }
            kernels::winograd_output(dst.rows(seq, r0, r1), &m[..m_len], cout, tiles, tiles * cout, false);
        });
    }
}

/// A small linear layer applied per scene (time MLP, FiLM, relative anchors), in f64.
struct LinW {
    din: usize,
    dout: usize,
    w: Vec<f32>,
    b: Vec<f32>,
}

impl LinW {
    fn load(params: &mut Params, prefix: &str, din: usize, dout: usize, bias: bool) -> Result<Self> {
        let w = params.take(&format!("{prefix}.weight"), &[1, din, dout])?;
        let b = if bias { params.take(&format!("{prefix}.bias"), &[dout])? } else { vec![0.0; dout] };
        Ok(Self { din, dout, w, b })
    }

    fn apply(&self, x: &[f64]) -> Vec<f64> {
        debug_assert_eq!(x.len(), self.din);
        let mut y: Vec<f64> = self.b.iter().map(|&v| v as f64).collect();
        for (i, &xi) in x.iter().enumerate() {
            for (o, &w) in y.iter_mut().zip(&self.w[i * self.dout..(i + 1) * self.dout]) {
                *o += xi * w as f64;
            }
        }
        y
    }
}

fn silu64(x: f64) -> f64 {
    x / (1.0 + (-x).exp())
}

/// conv k3 → SiLU → LayerNorm → conv k3, FiLM, plus the (1×1-projected) input.
struct ResW {
    conv1: ConvW,
    gamma: Vec<f32>,
    beta: Vec<f32>,
    eps: f32,
    conv2: ConvW,
    film: LinW,
    proj: Option<ConvW>,
}

impl ResW {
    fn load(params: &mut Params, prefix: &str, parts: &[usize], dout: usize, cfg: &DenoiserConfig) -> Result<Self> {
        let din: usize = parts.iter().sum();
        Ok(Self {
            conv1: ConvW {
                ahead: usize::from(cfg.causality == Causality::Lookahead),
                ..ConvW::load(params, &format!("{prefix}.conv1"), parts, dout, KERNEL, 1, true)?
            },
            gamma: params.take(&format!("{prefix}.norm.weight"), &[dout])?,
            beta: params.take(&format!("{prefix}.norm.bias"), &[dout])?,
            eps: cfg.ln_eps as f32,
            conv2: ConvW::load(params, &format!("{prefix}.conv2"), &[dout], dout, KERNEL, 1, true)?,
            film: LinW::load(params, &format!("{prefix}.film"), cfg.time_dim, 2 * dout, true)?,
            proj: if din != dout { Some(ConvW::load(params, &format!("{prefix}.proj"), parts, dout, 1, 1, true)?) } else { None },
        })
    }

    /// Per scene `[scale′ | shift′]` (`[B, 2·C_out]`) such that the block's output is
    /// `conv2_nobias(h)·scale′ + shift′ + skip_nobias`: `scale′ = 1 + scale`,
    /// `shift′ = b₂·scale′ + shift (+ b_proj)`.
    fn film_coefficients(&self, temb: &[Vec<f64>]) -> Vec<f32> {
        let c = self.conv2.cout;
        let mut out = Vec::with_capacity(temb.len() * 2 * c);
        for te in temb {
            let f = self.film.apply(te);
            let scale: Vec<f64> = f[..c].iter().map(|s| 1.0 + s).collect();
            out.extend(scale.iter().map(|&s| s as f32));
            for j in 0..c {
                let pb = self.proj.as_ref().map_or(0.0, |p| p.bias[j] as f64);
                out.push((self.conv2.bias[j] as f64 * scale[j] + f[c + j] + pb) as f32);
            }
        }
        out
    }
}

/// Causal conv k3 stride 2 → residual block.
struct DownW {
    conv: ConvW,
    res: ResW,
}

/// Causal conv k3 → causal ×2 upsampling → residual block.
struct UpW {
    conv: ConvW,
    res: ResW,
}

/// The aggregator's weights (see [`super::aggregator`]).
enum SocialW {
    Mean {
        enc: ConvW,
        enc_rel: LinW,
        out: ConvW,
        merge: ConvW,
    },
    Attention {
        heads: usize,
        /// q | k | v in one `[2H, 3S]` projection.
        qkv: ConvW,
        rel1: LinW,
        rel2: LinW,
        out: ConvW,
        merge: ConvW,
    },
}

/// The denoiser g(x_t, t, anchors) → x̂0 for inference only (see the module doc).
pub struct InferenceNet {
    cfg: DenoiserConfig,
    time_lin1: LinW,
    time_lin2: LinW,
    proj: ConvW,
    down: [DownW; 3],
    res1: ResW,
    social: Option<SocialW>,
    /// up3, up2, up1.
    up: [UpW; 3],
    final_res: ResW,
    to_pose: ConvW,
    workspace: Mutex<Option<Workspace>>,
    /// The frozen candle network the weights came from, for input gradients.
    source: Denoiser,
}

impl InferenceNet {
    /// The frozen candle network the weights were copied from.
    pub fn source(&self) -> &Denoiser {
        &self.source
    }

    /// Copies the weights of `net` (f32 or f64) into the inference layout, with Winograd
    /// stride-1 k3 convs.
    pub fn new(net: &Denoiser) -> Result<Self> {
        Self::with_k3_conv(net, K3Conv::default())
    }

    /// [`InferenceNet::new`] with the given algorithm for the stride-1 k3 convs.
    pub fn with_k3_conv(net: &Denoiser, k3: K3Conv) -> Result<Self> {
        let mut fast = Self::load(net)?;
        if k3 == K3Conv::Winograd {
            for conv in fast.k3_stride1_convs() {
                conv.transform_to_winograd();
            }
        }
        Ok(fast)
    }

    /// The stride-1 k3 convs: every residual block's two and the decoder's.
    fn k3_stride1_convs(&mut self) -> Vec<&mut ConvW> {
        let mut res: Vec<&mut ResW> = vec![&mut self.res1, &mut self.final_res];
        let mut convs = Vec::new();
        for d in &mut self.down {
            res.push(&mut d.res);
        }
        for u in &mut self.up {
            convs.push(&mut u.conv);
            res.push(&mut u.res);
        }
        for r in res {
            convs.push(&mut r.conv1);
            convs.push(&mut r.conv2);
        }
        debug_assert!(convs.iter().all(|c| c.k == KERNEL && c.stride == 1));
        convs
    }

    /// The weights of `net` in the inference layout, every conv direct.
    fn load(net: &Denoiser) -> Result<Self> {
        let cfg = net.config().clone();
        let mut p = Params::of(net)?;
        let (h, w, d, s) = (cfg.hidden, 2 * cfg.hidden, cfg.feature_dims, cfg.social_dim);
        let down = |p: &mut Params, i: usize, din: usize| -> Result<DownW> {
            Ok(DownW {
                conv: ConvW::load(p, &format!("down{i}.conv"), &[din], w, KERNEL, 2, true)?,
                res: ResW::load(p, &format!("down{i}.res"), &[w], w, &cfg)?,
            })
        };
        let up = |p: &mut Params, i: usize, dout: usize| -> Result<UpW> {
            Ok(UpW {
                conv: ConvW::load(p, &format!("up{i}.conv"), &[w, w], dout, KERNEL, 1, true)?,
                res: ResW::load(p, &format!("up{i}.res"), &[dout], dout, &cfg)?,
            })
        };
        let social = match cfg.aggregator {
            Aggregator::None => None,
            Aggregator::Mean => Some(SocialW::Mean {
                enc: ConvW::load(&mut p, "social.enc", &[w], s, 1, 1, true)?,
                enc_rel: LinW::load(&mut p, "social.enc_rel", REL_DIMS, s, false)?,
                out: ConvW::load(&mut p, "social.out", &[s], s, 1, 1, true)?,
                merge: ConvW::load(&mut p, "social.merge", &[w, s], w, 1, 1, true)?,
            }),
            Aggregator::Attention { heads } => {
                let (q, k, v) = (
                    ConvW::load(&mut p, "social.q", &[w], s, 1, 1, true)?,
                    ConvW::load(&mut p, "social.k", &[w], s, 1, 1, true)?,
                    ConvW::load(&mut p, "social.v", &[w], s, 1, 1, true)?,
                );
                let mut qkv = Vec::with_capacity(w * 3 * s);
                for row in 0..w {
                    for m in [&q, &k, &v] {
                        qkv.extend_from_slice(&m.parts[0].w[row * s..(row + 1) * s]);
                    }
                }
                let bias = [q.bias, k.bias, v.bias].concat();
                Some(SocialW::Attention {
                    heads,
                    qkv: ConvW { k: 1, stride: 1, cout: 3 * s, parts: vec![Part { cin: w, w: qkv }], bias, winograd: false, ahead: 0 },
                    rel1: LinW::load(&mut p, "social.rel1", REL_DIMS, s, true)?,
                    rel2: LinW::load(&mut p, "social.rel2", s, 2 * s, true)?,
                    out: ConvW::load(&mut p, "social.out", &[s], s, 1, 1, true)?,
                    merge: ConvW::load(&mut p, "social.merge", &[w, s], w, 1, 1, true)?,
                })
            }
        };
        let net = Self {
            time_lin1: LinW::load(&mut p, "time_mlp.lin1", cfg.fourier_dim, cfg.time_dim, true)?,
            time_lin2: LinW::load(&mut p, "time_mlp.lin2", cfg.time_dim, cfg.time_dim, true)?,
            proj: ConvW::load(&mut p, "proj", &[d], h, 1, 1, true)?,
            down: [down(&mut p, 1, h)?, down(&mut p, 2, w)?, down(&mut p, 3, w)?],
            res1: ResW::load(&mut p, "res1", &[w], w, &cfg)?,
            social,
            up: [up(&mut p, 3, w)?, up(&mut p, 2, w)?, up(&mut p, 1, h)?],
            final_res: ResW::load(&mut p, "final_res", &[h, h], h, &cfg)?,
            to_pose: ConvW::load(&mut p, "to_pose", &[h], d, 1, 1, true)?,
            workspace: Mutex::new(None),
            source: net.frozen(),
            cfg,
        };
        if let Some(name) = p.0.keys().next() {
            bail!("inference weights: unexpected parameter {name}");
        }
        Ok(net)
    }

    /// The configuration of the network.
    pub fn config(&self) -> &DenoiserConfig {
        &self.cfg
    }

    /// Bytes of the activation workspace for `sequences` (scenes × persons) of `frames` frames.
    pub fn workspace_bytes(&self, sequences: usize, frames: usize) -> usize {
        Workspace::capacities(&self.cfg, sequences, frames.div_ceil(TIME_FACTOR) * TIME_FACTOR, false).iter().sum::<usize>() * 4
    }

    /// Per scene, the leading frames whose activations a call computes apart from the rest
    /// (the prefix cache): the clean frames of a causal network with one level per frame
    /// ([`clean_prefixes`]) — at every U-Net level the split falls on an even row, no Winograd
    /// tile or stride-2 conv straddles it, and the rows before it depend on those frames alone,
    /// bit for bit. A function of the scene's own levels: the arithmetic of a scene never depends
    /// on the batch or on earlier calls.
    fn prefix_splits(&self, t: &[f64], b: usize, p: usize, frames: usize) -> Vec<usize> {
        if self.cfg.causality != Causality::Causal || t.len() != b * p * frames {
            return vec![0; b];
        }
        clean_prefixes(t, b, p, frames)
    }

    /// x̂0 = g(x_t, t, anchors), as [`Denoiser::forward`].
    ///
    /// # Shapes
    /// - `x`: `[B, P, T, δ]` flattened (`shape` = `[B, P, T, δ]`, any P ≥ 1, T ≥ 1)
    /// - `t`: B diffusion steps (one per scene), or B·P·T (one per person and frame, `[B, P, T]`)
    /// - `anchors`: `[B, P, 4]` flattened, `(r_x, r_y, cos h, sin h)` per person
    /// - `out`: `[B, P, T, δ]` flattened, overwritten
    pub fn forward(&self, x: &[f32], shape: [usize; 4], t: &[f64], anchors: Option<&[f32]>, out: &mut [f32]) -> Result<()> {
        let [b, p, frames, d] = shape;
        if d != self.cfg.feature_dims {
            bail!("denoiser: input has {d} feature dims, the network {}", self.cfg.feature_dims);
        }
        if b == 0 || p == 0 || frames == 0 {
            bail!("denoiser: empty input {shape:?}");
        }
        let len = b * p * frames * d;
        if x.len() != len || out.len() != len {
            bail!("denoiser: input has {} values and output {}, shape {shape:?} needs {len}", x.len(), out.len());
        }
        if t.len() != b && t.len() != b * p * frames {
            bail!("denoiser: {} timesteps for {b} scenes of {p} persons × {frames} frames (give {b} or {})", t.len(), b * p * frames);
        }
        if let Some(bad) = t.iter().find(|x| !x.is_finite() || **x < 0.0) {
            bail!("denoiser: noise level {bad} is not a finite non-negative number");
        }
        if let Some(a) = anchors {
            if a.len() != b * p * REL_DIMS {
                bail!("denoiser: anchors have {} values, expected [{b}, {p}, 4]", a.len());
            }
        }
        let n = b * p;
        let l0 = frames.div_ceil(TIME_FACTOR) * TIME_FACTOR;
        let splits = self.prefix_splits(t, b, p, frames);
        // A clean prefix worth keeping (an eighth of the canvas or more): every activation in its
        // own buffer, so the rows before the split stay valid for the next call.
        let cached = splits.iter().any(|&s| s > 0 && 8 * s >= frames);
        let mut guard = self.workspace.lock().unwrap_or_else(|e| e.into_inner());
        if guard.as_ref().is_none_or(|ws| ws.key != (n, l0, cached)) {
            *guard = None; // free the old buffers before allocating new ones
            *guard = Some(Workspace::new(&self.cfg, n, l0, cached));
        }
        let ws = guard.as_mut().expect("workspace just built");
        // A scene keeps its rows before the split when its inputs, levels and anchors there are
        // the last call's.
        let keep: Vec<bool> = (0..b).map(|scene| cached && splits[scene] > 0 && ws.prefix_unchanged(scene, splits[scene], x, shape, t, anchors)).collect();
        ws.reused = keep.iter().zip(&splits).map(|(&k, &s)| if k { s } else { 0 }).sum();
        if cached {
            ws.last = Some(LastCall { shape, x: x.to_vec(), t: t.to_vec(), anchors: anchors.map(<[f32]>::to_vec) });
        }
        let regions = Regions { splits, keep, persons: p, l0 };
        let layout = activations(&self.cfg);
        let bufs: Vec<(*mut f32, usize)> = ws.bufs.iter_mut().map(|b| (b.as_mut_ptr(), b.len())).collect();
        let v = |a: usize| {
            let (level, c) = layout[a];
            let l = l0 >> level;
            let (ptr, len) = bufs[if cached { a } else { SHARED[a] }];
            assert!((n * (l + PAD) + 1) * c <= len, "workspace buffer of activation {a} too small for [{n}, {l}, {c}]");
            View { ptr, n, l, c }
        };

        // Conditioning: the embedding (after SiLU) of each distinct level and which one each row
        // of each U-Net level uses (see `Denoiser::forward`), and relative anchors.
        let (levels, rows) = if t.len() == b {
            let rows = (0..4).map(|l| (0..n).flat_map(|seq| std::iter::repeat_n((seq / p) as u32, l0 >> l)).collect()).collect();
            (t.to_vec(), rows)
        } else {
            super::unet::level_rows(t, n, frames, l0)
        };
        let temb = LevelEmbedding { temb: levels.iter().map(|&ti| self.time_embedding(ti)).collect(), rows, l0 };
        let anchors64 = anchors.map(|a| a.iter().map(|&v| v as f64).collect::<Vec<f64>>());
        let rel = relative_anchor_values(anchors64.as_deref(), b, p);

        // Input, zero frames at the end up to T'.
        let xin = v(act::XIN);
        (0..n).into_par_iter().for_each(|seq| {
            // SAFETY: one task per sequence, each writes its own rows.
            let rows = unsafe { xin.rows(seq, 0, l0) };
            rows[..frames * d].copy_from_slice(&x[seq * frames * d..(seq + 1) * frames * d]);
            rows[frames * d..].fill(0.0);
        });
        let x0 = v(act::X0);
        self.linear(&self.proj, &[xin], x0, &regions);

        // Encoder.
        let mut h = x0;
        for (k, dw) in self.down.iter().enumerate() {
            let out = v(act::DOWN_OUT[k]);
            h = self.down(dw, h, v(act::DOWN_CONV[k]), v(act::DOWN_TMP[k]), out, &temb, &regions);
        }
        let d3 = h;
        let mid = v(act::MID);
        self.res_block(&self.res1, &[d3], v(act::MID_TMP), mid, &temb, &regions);
        let social = match &self.social {
            Some(sw) => {
                let out = v(act::SOCIAL);
                self.social(sw, mid, v(act::E), v(act::M), v(act::MSG), out, &rel, b, p, &regions);
                out
            }
            None => mid,
        };

        // Decoder.
        let skips = [v(act::DOWN_OUT[2]), v(act::DOWN_OUT[1]), v(act::DOWN_OUT[0])];
        let mut h = social;
        for (k, uw) in self.up.iter().enumerate() {
            let (coarse, fine) = (v(act::UP_COARSE[k]), v(act::UP_FINE[k]));
            h = self.up(uw, [h, skips[k]], coarse, fine, v(act::UP_TMP[k]), v(act::UP_OUT[k]), &temb, &regions);
        }
        let f = v(act::FINAL);
        self.res_block(&self.final_res, &[h, x0], v(act::FINAL_TMP), f, &temb, &regions);
        let y = v(act::Y);
        self.linear(&self.to_pose, &[f], y, &regions);

        out.par_chunks_mut(frames * d).enumerate().for_each(|(seq, o)| {
            // SAFETY: rows of `y` are only read here.
            o.copy_from_slice(unsafe { y.read(seq, 0, frames) });
        });
        Ok(())
    }

    /// SiLU(lin2(GELU(lin1(sinusoidal(t))))), `[time_dim]`, in f64.
    fn time_embedding(&self, t: f64) -> Vec<f64> {
        let half = self.cfg.fourier_dim / 2;
        let f = |k: usize| (-(k as f64) * self.cfg.fourier_max_period.ln() / (half - 1) as f64).exp();
        let mut feats: Vec<f64> = (0..half).map(|k| (t * f(k)).sin()).collect();
        feats.extend((0..half).map(|k| (t * f(k)).cos()));
        // the reference network computes the features in f64 and rounds them to f32
        let feats: Vec<f64> = feats.iter().map(|&v| v as f32 as f64).collect();
        let gelu = |v: f64| 0.5 * v * (1.0 + candle_core::cpu::erf::erf_f64(v * std::f64::consts::FRAC_1_SQRT_2));
        let hidden: Vec<f64> = self.time_lin1.apply(&feats).into_iter().map(gelu).collect();
        self.time_lin2.apply(&hidden).into_iter().map(silu64).collect()
    }

    /// A per-frame linear layer (1×1 conv) with bias: `dst = conv(srcs) + b`, on the rows
    /// `regions` says.
    fn linear(&self, conv: &ConvW, srcs: &[View], dst: View, regions: &Regions) {
        par_rows(dst, regions, |seq, r0, r1| unsafe {
            conv.rows(srcs, dst, seq, r0, r1, false);
            kernels::add_bias_rows(dst.rows(seq, r0, r1), dst.c, &conv.bias);
        });
    }

    /// Residual block from `x` (one or two parts) into `out`, `tmp` holding the first conv.
    fn res_block(&self, r: &ResW, x: &[View], tmp: View, out: View, temb: &LevelEmbedding, regions: &Regions) {
        let film = r.film_coefficients(&temb.temb);
        let rows = &temb.rows[(temb.l0 / out.l).trailing_zeros() as usize];
        let c = out.c;
        par_rows(tmp, regions, |seq, r0, r1| unsafe {
            r.conv1.rows(x, tmp, seq, r0, r1, false);
            kernels::silu_layer_norm_rows(tmp.rows(seq, r0, r1), c, &r.conv1.bias, &r.gamma, &r.beta, r.eps);
        });
        par_rows(out, regions, |seq, r0, r1| unsafe {
            r.conv2.rows(&[tmp], out, seq, r0, r1, false);
            // Runs of rows with one level share their coefficients.
            let mut a = r0;
            while a < r1 {
                let u = rows[seq * out.l + a] as usize;
                let e = (a..r1).find(|&q| rows[seq * out.l + q] as usize != u).unwrap_or(r1);
                let coef = &film[u * 2 * c..(u + 1) * 2 * c];
                let skip = if r.proj.is_none() { Some(x[0].read(seq, a, e)) } else { None };
                kernels::film_rows(out.rows(seq, a, e), c, &coef[..c], &coef[c..], skip);
                a = e;
            }
            if let Some(proj) = &r.proj {
                proj.rows(x, out, seq, r0, r1, true);
            }
        });
    }

    /// Down block: `conv` (stride 2) into `a`, residual block (temp `tmp`) into `out`.
    #[allow(clippy::too_many_arguments)]
    fn down(&self, dw: &DownW, x: View, a: View, tmp: View, out: View, temb: &LevelEmbedding, regions: &Regions) -> View {
        self.linear(&dw.conv, &[x], a, regions);
        self.res_block(&dw.res, &[a], tmp, out, temb, regions);
        out
    }

    /// Up block: conv of `x` (two parts) into `coarse`, ×2 upsampling into `fine`, residual
    /// block (temp `tmp`) into `out`.
    #[allow(clippy::too_many_arguments)]
    fn up(&self, uw: &UpW, x: [View; 2], coarse: View, fine: View, tmp: View, out: View, temb: &LevelEmbedding, regions: &Regions) -> View {
        self.linear(&uw.conv, &x, coarse, regions);
        par_rows(fine, regions, |seq, q0, q1| unsafe {
            kernels::upsample2x_rows(fine.rows(seq, q0, q1), coarse.read(seq, 0, coarse.l), fine.c, q0);
        });
        self.res_block(&uw.res, &[fine], tmp, out, temb, regions);
        out
    }

    /// The aggregator and merge at the bottleneck: `mid` → `out` (both `[N, T'/8, 2H]`), with
    /// temps `e` (encodings, or q | k | v), `m` (mean or attention output) and `msg`.
    #[allow(clippy::too_many_arguments)]
    fn social(&self, sw: &SocialW, mid: View, e: View, m: View, msg: View, out: View, rel: &[f64], b: usize, p: usize, regions: &Regions) {
        let s = self.cfg.social_dim;
        let (enc, out_lin, merge) = match sw {
            SocialW::Mean { enc, out, merge, .. } => (enc, out, merge),
            SocialW::Attention { qkv, out, merge, .. } => (qkv, out, merge),
        };
        self.linear(enc, &[mid], e, regions);
        // per (scene, receiver i, sender j): the relative-anchor term
        let rel_terms: Vec<f32> = match sw {
            SocialW::Mean { enc_rel, .. } => rel.chunks_exact(REL_DIMS).flat_map(|r| enc_rel.apply(r)).map(|v| v as f32).collect(),
            SocialW::Attention { rel1, rel2, .. } => {
                rel.chunks_exact(REL_DIMS).flat_map(|r| rel2.apply(&rel1.apply(r).into_iter().map(silu64).collect::<Vec<_>>())).map(|v| v as f32).collect()
            }
        };
        let per_pair = rel_terms.len() / (b * p * p);
        par_rows(out, regions, |seq, r0, r1| unsafe {
            let (scene, i) = (seq / p, seq % p);
            let pair = |j: usize| &rel_terms[((scene * p + i) * p + j) * per_pair..][..per_pair];
            let m_rows = m.rows(seq, r0, r1);
            match sw {
                SocialW::Mean { .. } => {
                    m_rows.fill(0.0);
                    for j in 0..p {
                        kernels::add_silu_rows(m_rows, e.read(scene * p + j, r0, r1), pair(j), s);
                    }
                    let inv = 1.0 / p as f32;
                    m_rows.iter_mut().for_each(|v| *v *= inv);
                }
                SocialW::Attention { heads, .. } => {
                    let dh = s / heads;
                    let scale = 1.0 / (dh as f32).sqrt();
                    let mut logits = vec![0.0f32; p];
                    for (r, m_row) in (r0..r1).zip(m_rows.chunks_exact_mut(s)) {
                        let q_row = &e.read(seq, r, r + 1)[..s];
                        for hd in 0..*heads {
                            let q = &q_row[hd * dh..(hd + 1) * dh];
                            for (j, lg) in logits.iter_mut().enumerate() {
                                let k_row = &e.read(scene * p + j, r, r + 1)[s + hd * dh..s + (hd + 1) * dh];
                                let rk = &pair(j)[hd * dh..(hd + 1) * dh];
                                let (mut content, mut geometric) = (0.0f32, 0.0f32);
                                for ((&qv, &kv), &rv) in q.iter().zip(k_row).zip(rk) {
                                    content += qv * kv;
                                    geometric += qv * rv;
                                }
                                *lg = (content + geometric) * scale;
                            }
                            let max = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                            let mut sum = 0.0f32;
                            for lg in logits.iter_mut() {
                                *lg = (*lg - max).exp();
                                sum += *lg;
                            }
                            let o = &mut m_row[hd * dh..(hd + 1) * dh];
                            o.fill(0.0);
                            for (j, &wj) in logits.iter().enumerate() {
                                let a = wj / sum;
                                let v_row = &e.read(scene * p + j, r, r + 1)[2 * s + hd * dh..2 * s + (hd + 1) * dh];
                                let rv = &pair(j)[s + hd * dh..s + (hd + 1) * dh];
                                for ((ov, &vv), &rvv) in o.iter_mut().zip(v_row).zip(rv) {
                                    *ov += a * vv + a * rvv;
                                }
                            }
                        }
                    }
                }
            }
            out_lin.rows(&[m], msg, seq, r0, r1, false);
            kernels::add_bias_rows(msg.rows(seq, r0, r1), s, &out_lin.bias);
            merge.rows(&[mid, msg], out, seq, r0, r1, false);
            kernels::add_bias_rows(out.rows(seq, r0, r1), out.c, &merge.bias);
        });
    }
}

/// Level embeddings of a forward pass: `temb[u]` for each distinct level u, and for each U-Net
/// level ℓ the level index of every row (`[N · T'/2^ℓ]`).
struct LevelEmbedding {
    temb: Vec<Vec<f64>>,
    rows: Vec<Vec<u32>>,
    l0: usize,
}

/// Frames per task for sequences of `l` frames: at least two tasks per sequence (both cores
/// busy for a single person), at most [`MAX_CHUNK`] frames, equal sizes.
fn chunk_rows(l: usize) -> usize {
    l.div_ceil(l.div_ceil(MAX_CHUNK).max(2)).max(1)
}

/// Which rows of each sequence a forward pass computes, in which blocks: per scene, the split
/// (frames at level 0; `split >> ℓ` rows at level ℓ) before which the rows are computed as one
/// region and after which as another, and whether the rows before it are kept from the last
/// call instead.
struct Regions {
    splits: Vec<usize>,
    keep: Vec<bool>,
    persons: usize,
    l0: usize,
}

impl Regions {
    /// The row ranges of sequence `seq` to compute in an activation of `l` rows.
    fn ranges(&self, seq: usize, l: usize) -> [(usize, usize); 2] {
        let scene = seq / self.persons;
        let split = (self.splits[scene] / (self.l0 / l)).min(l);
        let before = if self.keep[scene] { (0, 0) } else { (0, split) };
        [before, (split, l)]
    }
}

/// Writes `dst`: runs `f(seq, r0, r1)` for every block of [`chunk_rows`] frames of every region
/// of every sequence that `regions` says to compute, in parallel, after zeroing the sequence's
/// padding frames (a buffer may have held another layout before). The blocks depend only on
/// the length and the sequence's split: results do not depend on the number of sequences, on
/// the thread count, or on which rows the last call left.
fn par_rows(dst: View, regions: &Regions, f: impl Fn(usize, usize, usize) + Sync) {
    let mut tasks = Vec::new();
    for seq in 0..dst.n {
        tasks.push((seq, 0, 0)); // the padding
        for (a, e) in regions.ranges(seq, dst.l) {
            let len = chunk_rows(e - a);
            tasks.extend((a..e).step_by(len.max(1)).map(|r0| (seq, r0, (r0 + len).min(e))));
        }
    }
    tasks.into_par_iter().for_each(|(seq, r0, r1)| {
        if r0 == r1 {
            // SAFETY: the padding frames of `seq` (and the row after the last sequence) belong
            // to this task only.
            unsafe { std::ptr::write_bytes(dst.at(seq, -(PAD as isize)), 0, PAD * dst.c) };
            if seq + 1 == dst.n {
                unsafe { std::ptr::write_bytes(dst.at(seq, dst.l as isize), 0, dst.c) };
            }
        } else {
            f(seq, r0, r1);
        }
    });
}

/// An activation `[N, PAD + L, C]` inside a workspace buffer: N sequences of L frames, each
/// preceded by `PAD` zero frames, and one zero frame after the last (so every sequence is
/// followed by a zero frame, which a centred conv reads). A raw view: tasks write disjoint rows
/// of it in parallel.
#[derive(Clone, Copy)]
struct View {
    ptr: *mut f32,
    n: usize,
    l: usize,
    c: usize,
}

// SAFETY: a View is a pointer into a workspace buffer that outlives every parallel phase; the
// phases write disjoint rows.
unsafe impl Send for View {}
unsafe impl Sync for View {}

impl View {
    /// Frame `row` (`−PAD ≤ row ≤ L`) of sequence `seq`.
    fn at(&self, seq: usize, row: isize) -> *mut f32 {
        let offset = ((seq * (self.l + PAD) + PAD) as isize + row) * self.c as isize;
        // SAFETY: inside the buffer for the rows the views are used with (checked at creation).
        unsafe { self.ptr.offset(offset) }
    }

    /// Frames `r0..r1` of sequence `seq`, `[r1 − r0, C]`.
    ///
    /// # Safety
    /// No other task may access these rows while the slice lives.
    #[allow(clippy::mut_from_ref)]
    unsafe fn rows(&self, seq: usize, r0: usize, r1: usize) -> &mut [f32] {
        debug_assert!(seq < self.n && r0 <= r1 && r1 <= self.l);
        std::slice::from_raw_parts_mut(self.at(seq, r0 as isize), (r1 - r0) * self.c)
    }

    /// Frames `r0..r1` of sequence `seq` to read.
    ///
    /// # Safety
    /// No task may write these rows while the slice lives.
    unsafe fn read(&self, seq: usize, r0: usize, r1: usize) -> &[f32] {
        debug_assert!(seq < self.n && r0 <= r1 && r1 <= self.l);
        std::slice::from_raw_parts(self.at(seq, r0 as isize), (r1 - r0) * self.c)
    }
}

// Workspace buffers (see `InferenceNet::forward` for who uses which).
const XIN: usize = 0;
const X0: usize = 1;
const P0: usize = 2;
const P1: usize = 3;
const P2: usize = 4;
const D1: usize = 5;
const Q0: usize = 6;
const Q1: usize = 7;
const Q2: usize = 8;
const D2: usize = 9;
const R0: usize = 10;
const R1: usize = 11;
const R2: usize = 12;
const D3: usize = 13;
const E: usize = 14;
const M: usize = 15;
const MSG: usize = 16;
const OUT: usize = 17;
const BUFFERS: usize = 18;

/// The activations of a forward pass, by index into [`activations`].
mod act {
    pub const XIN: usize = 0;
    pub const X0: usize = 1;
    pub const DOWN_CONV: [usize; 3] = [2, 3, 4];
    pub const DOWN_TMP: [usize; 3] = [5, 6, 7];
    pub const DOWN_OUT: [usize; 3] = [8, 9, 10];
    pub const MID_TMP: usize = 11;
    pub const MID: usize = 12;
    pub const E: usize = 13;
    pub const M: usize = 14;
    pub const MSG: usize = 15;
    pub const SOCIAL: usize = 16;
    /// up3, up2, up1.
    pub const UP_COARSE: [usize; 3] = [17, 18, 19];
    pub const UP_FINE: [usize; 3] = [20, 21, 22];
    pub const UP_TMP: [usize; 3] = [23, 24, 25];
    pub const UP_OUT: [usize; 3] = [26, 27, 28];
    pub const FINAL_TMP: usize = 29;
    pub const FINAL: usize = 30;
    pub const Y: usize = 31;
    pub const COUNT: usize = 32;
}

/// The shared buffer of each activation: activations that are never alive together share one.
const SHARED: [usize; act::COUNT] =
    [XIN, X0, P0, Q0, R0, P1, Q1, R1, D1, D2, D3, R0, R1, E, M, MSG, R2, R0, Q0, P1, Q0, P0, P0, Q1, P1, P1, Q2, P2, P2, P0, P1, OUT];

/// (U-Net level ℓ, channels) of each activation (`[N, T'/2^ℓ, C]`).
fn activations(cfg: &DenoiserConfig) -> [(usize, usize); act::COUNT] {
    let (h, w, d, s) = (cfg.hidden, 2 * cfg.hidden, cfg.feature_dims, cfg.social_dim);
    let e_width = if matches!(cfg.aggregator, Aggregator::Attention { .. }) { 3 * s } else { s };
    let mut out = [(0, 0); act::COUNT];
    out[act::XIN] = (0, d);
    out[act::X0] = (0, h);
    for k in 0..3 {
        for a in [act::DOWN_CONV[k], act::DOWN_TMP[k], act::DOWN_OUT[k]] {
            out[a] = (k + 1, w);
        }
        // up3 and up2 keep 2H channels, up1 goes to H
        let width = if k == 2 { h } else { w };
        out[act::UP_COARSE[k]] = (3 - k, width);
        for a in [act::UP_FINE[k], act::UP_TMP[k], act::UP_OUT[k]] {
            out[a] = (2 - k, width);
        }
    }
    out[act::MID_TMP] = (3, w);
    out[act::MID] = (3, w);
    out[act::E] = (3, e_width);
    out[act::M] = (3, s);
    out[act::MSG] = (3, s);
    out[act::SOCIAL] = (3, w);
    out[act::FINAL_TMP] = (0, h);
    out[act::FINAL] = (0, h);
    out[act::Y] = (0, d);
    out
}

/// The inputs of the last forward pass of a prefix-caching workspace.
struct LastCall {
    shape: [usize; 4],
    x: Vec<f32>,
    t: Vec<f64>,
    anchors: Option<Vec<f32>>,
}

/// Activation buffers for one (sequences, padded frames, layout) size, reused across calls. In
/// the prefix-caching layout every activation has its own buffer, so the rows a call leaves
/// stay valid for the next.
struct Workspace {
    key: (usize, usize, bool),
    bufs: Vec<Vec<f32>>,
    last: Option<LastCall>,
    /// Frames (summed over scenes) the last call took from the call before it.
    reused: usize,
}

impl Workspace {
    /// Floats per buffer: the largest layout each one holds.
    fn capacities(cfg: &DenoiserConfig, n: usize, l0: usize, cached: bool) -> Vec<usize> {
        let cap = |(level, c): (usize, usize)| (n * ((l0 >> level) + PAD) + 1) * c;
        let social = |a: usize| (a == act::E || a == act::M || a == act::MSG || a == act::SOCIAL) && cfg.aggregator == Aggregator::None;
        let layout = activations(cfg);
        if cached {
            return (0..act::COUNT).map(|a| if social(a) { 0 } else { cap(layout[a]) }).collect();
        }
        let mut caps = vec![0; BUFFERS];
        for a in (0..act::COUNT).filter(|&a| !social(a)) {
            caps[SHARED[a]] = caps[SHARED[a]].max(cap(layout[a]));
        }
        caps
    }

    fn new(cfg: &DenoiserConfig, n: usize, l0: usize, cached: bool) -> Self {
        let bufs = Self::capacities(cfg, n, l0, cached).iter().map(|&c| vec![0.0f32; c]).collect();
        Self { key: (n, l0, cached), bufs, last: None, reused: 0 }
    }

    /// Whether scene `scene`'s first `split` frames (inputs and levels of every person) and its
    /// anchors equal the last call's, in a call of the same shape.
    fn prefix_unchanged(&self, scene: usize, split: usize, x: &[f32], shape: [usize; 4], t: &[f64], anchors: Option<&[f32]>) -> bool {
        let Some(last) = &self.last else { return false };
        let [_, p, frames, d] = shape;
        if last.shape != shape || last.t.len() != t.len() {
            return false;
        }
        let same_anchors = match (anchors, &last.anchors) {
            (None, None) => true,
            (Some(a), Some(l)) => a[scene * p * REL_DIMS..(scene + 1) * p * REL_DIMS] == l[scene * p * REL_DIMS..(scene + 1) * p * REL_DIMS],
            _ => false,
        };
        same_anchors
            && (scene * p..(scene + 1) * p).all(|seq| {
                let (r, e) = (seq * frames, seq * frames * d);
                t[r..r + split] == last.t[r..r + split] && x[e..e + split * d] == last.x[e..e + split * d]
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Tensor};
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    fn tiny(aggregator: Aggregator) -> DenoiserConfig {
        DenoiserConfig { feature_dims: 7, hidden: 8, time_dim: 16, fourier_dim: 8, social_dim: 8, aggregator, ..Default::default() }
    }

    const AGGREGATORS: [Aggregator; 3] = [Aggregator::None, Aggregator::Mean, Aggregator::Attention { heads: 2 }];

    fn rand_vec(rng: &mut StdRng, n: usize, scale: f32) -> Vec<f32> {
        (0..n).map(|_| rng.gen_range(-scale..scale)).collect()
    }

    fn rand_anchors(rng: &mut StdRng, b: usize, p: usize) -> Vec<f32> {
        (0..b * p)
            .flat_map(|_| {
                let a: f32 = rng.gen_range(-3.0..3.0);
                [rng.gen_range(-3.0..3.0), rng.gen_range(-3.0..3.0), a.cos(), a.sin()]
            })
            .collect()
    }

    /// The candle network's output for the same input.
    fn reference(net: &Denoiser, x: &[f32], shape: [usize; 4], t: &[f64], anchors: Option<&[f32]>) -> Vec<f32> {
        let xt = Tensor::from_vec(x.to_vec(), shape.to_vec(), &Device::Cpu).unwrap();
        let tt = if t.len() == shape[0] {
            Tensor::from_vec(t.to_vec(), t.len(), &Device::Cpu).unwrap()
        } else {
            Tensor::from_vec(t.to_vec(), (shape[0], shape[1], shape[2]), &Device::Cpu).unwrap()
        };
        let at = anchors.map(|a| Tensor::from_vec(a.to_vec(), (shape[0], shape[1], 4), &Device::Cpu).unwrap());
        net.forward(&xt, &tt, at.as_ref()).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap()
    }

    fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
        a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
    }

    /// Same output as the candle network, for every aggregator, causal and with lookahead, and
    /// several P and T (frames that are and are not multiples of 8, lengths crossing the task
    /// blocks), on one workspace reused across calls of different sizes.
    #[test]
    fn matches_the_candle_network() {
        let mut rng = StdRng::seed_from_u64(1);
        for (agg, causality) in AGGREGATORS.into_iter().flat_map(|a| [(a, Causality::Causal), (a, Causality::Lookahead)]) {
            let cfg = DenoiserConfig {
                feature_dims: 13,
                hidden: 16,
                time_dim: 32,
                fourier_dim: 16,
                social_dim: 16,
                aggregator: agg,
                causality,
                ..Default::default()
            };
            let net = Denoiser::new(cfg, 2).unwrap().frozen();
            for k3 in [K3Conv::Winograd, K3Conv::Direct] {
                let fast = InferenceNet::with_k3_conv(&net, k3).unwrap();
                let mut worst = 0.0f32;
                for (b, p, t) in [(1, 1, 1), (1, 3, 13), (2, 2, 64), (1, 7, 37), (2, 3, 301), (1, 2, 1100)] {
                    let shape = [b, p, t, 13];
                    let x = rand_vec(&mut rng, b * p * t * 13, 2.0);
                    let steps: Vec<f64> = (0..b).map(|i| (17 + 400 * i) as f64).collect();
                    let anchors = rand_anchors(&mut rng, b, p);
                    for a in [Some(anchors.as_slice()), None] {
                        let want = reference(&net, &x, shape, &steps, a);
                        let mut got = vec![f32::NAN; x.len()];
                        fast.forward(&x, shape, &steps, a, &mut got).unwrap();
                        let d = max_abs_diff(&got, &want);
                        assert!(d <= 1e-4, "{agg:?} {causality:?} {k3:?} {shape:?}: max |Δ| = {d}");
                        worst = worst.max(d);
                    }
                }
                eprintln!("{agg:?}, {causality:?}, {k3:?}: worst |inference − candle| = {worst:.2e}");
            }
        }
    }

    /// One noise level per person and frame (the clean observed frames of a model trained with
    /// per-frame levels) gives what the candle network gives.
    #[test]
    fn per_frame_levels_match_the_candle_network() {
        let mut rng = StdRng::seed_from_u64(5);
        for agg in AGGREGATORS {
            let cfg = DenoiserConfig { feature_dims: 13, hidden: 16, time_dim: 32, fourier_dim: 16, social_dim: 16, aggregator: agg, ..Default::default() };
            let net = Denoiser::new(cfg, 2).unwrap().frozen();
            let fast = InferenceNet::new(&net).unwrap();
            for (b, p, t) in [(1, 3, 13), (2, 2, 64), (1, 2, 301)] {
                let shape = [b, p, t, 13];
                let x = rand_vec(&mut rng, b * p * t * 13, 2.0);
                // A clean prefix of 0s, then one level per scene, and a few random frames.
                let mut levels: Vec<f64> = (0..b * p * t).map(|i| if i % t < t / 3 { 0.0 } else { (300 + 200 * (i / (p * t))) as f64 }).collect();
                for _ in 0..5 {
                    let k = rng.gen_range(0..levels.len());
                    levels[k] = rng.gen_range(0..1000) as f64;
                }
                let anchors = rand_anchors(&mut rng, b, p);
                let want = reference(&net, &x, shape, &levels, Some(&anchors));
                let mut got = vec![f32::NAN; x.len()];
                fast.forward(&x, shape, &levels, Some(&anchors), &mut got).unwrap();
                let d = max_abs_diff(&got, &want);
                assert!(d <= 1e-4, "{agg:?} {shape:?}: max |Δ| = {d}");
            }
        }
    }

    /// Output frames before t0 ignore input frames from t0 on; permuting persons permutes the
    /// output; a scene's output does not depend on the other scenes of the batch, bit for bit.
    #[test]
    fn causal_permutation_equivariant_and_batch_independent() {
        let mut rng = StdRng::seed_from_u64(3);
        for (agg, k3) in AGGREGATORS.into_iter().flat_map(|a| [(a, K3Conv::Winograd), (a, K3Conv::Direct)]) {
            let net = InferenceNet::with_k3_conv(&Denoiser::new(tiny(agg), 4).unwrap(), k3).unwrap();
            let (p, t, d) = (3, 150, 7);
            let shape = [1, p, t, d];
            let x = rand_vec(&mut rng, p * t * d, 1.0);
            let anchors = rand_anchors(&mut rng, 1, p);
            let mut out = vec![0.0; x.len()];
            net.forward(&x, shape, &[30.0], Some(&anchors), &mut out).unwrap();
            for t0 in [1, 7, 8, 64, 129, 149] {
                let mut x2 = x.clone();
                for q in 0..p {
                    for v in &mut x2[(q * t + t0) * d..(q + 1) * t * d] {
                        *v = rng.gen_range(-1.0..1.0);
                    }
                }
                let mut out2 = vec![0.0; x.len()];
                net.forward(&x2, shape, &[30.0], Some(&anchors), &mut out2).unwrap();
                for q in 0..p {
                    let before = q * t * d..(q * t + t0) * d;
                    assert_eq!(out[before.clone()], out2[before], "{agg:?}: person {q} before {t0} changed");
                    let at = (q * t + t0) * d..(q * t + t0 + 1) * d;
                    assert!(max_abs_diff(&out[at.clone()], &out2[at]) > 1e-4, "{agg:?}: frame {t0} did not react");
                }
            }
            // persons permuted
            let perm = [2, 0, 1];
            let permute = |v: &[f32], per: usize| -> Vec<f32> { perm.iter().flat_map(|&q| v[q * per..(q + 1) * per].to_vec()).collect() };
            let mut out_p = vec![0.0; x.len()];
            net.forward(&permute(&x, t * d), shape, &[30.0], Some(&permute(&anchors, 4)), &mut out_p).unwrap();
            let dp = max_abs_diff(&permute(&out, t * d), &out_p);
            assert!(dp < 1e-5, "{agg:?}: permutation difference {dp}");
            // batched with another scene at another step: the first scene is unchanged
            let other = rand_vec(&mut rng, p * t * d, 1.0);
            let both = [x.clone(), other].concat();
            let anchors2 = [anchors.clone(), rand_anchors(&mut rng, 1, p)].concat();
            let mut out_b = vec![0.0; both.len()];
            net.forward(&both, [2, p, t, d], &[30.0, 900.0], Some(&anchors2), &mut out_b).unwrap();
            assert_eq!(out_b[..x.len()], out[..], "{agg:?}: batching changed the first scene");
        }
    }

    /// Frames the last forward pass took from the one before (the prefix cache).
    fn reused(net: &InferenceNet) -> usize {
        net.workspace.lock().unwrap().as_ref().map_or(0, |ws| ws.reused)
    }

    /// With a clean known prefix (level 0), a call that shares it with the last one keeps the
    /// rows over it (its whole multiples of 16 frames) and gives what a fresh network gives, bit
    /// for bit, and what the candle network gives; a changed prefix frame or anchor recomputes
    /// that scene.
    #[test]
    fn the_clean_prefix_is_computed_once_and_changes_nothing() {
        let mut rng = StdRng::seed_from_u64(11);
        for (agg, k3) in AGGREGATORS.into_iter().flat_map(|a| [(a, K3Conv::Winograd), (a, K3Conv::Direct)]) {
            let cfg = DenoiserConfig { feature_dims: 13, hidden: 16, time_dim: 32, fourier_dim: 16, social_dim: 16, aggregator: agg, ..Default::default() };
            let net = Denoiser::new(cfg, 2).unwrap().frozen();
            let cached = InferenceNet::with_k3_conv(&net, k3).unwrap();
            for (b, p, t, known) in [(2, 3, 120, 30), (1, 2, 61, 9), (1, 2, 1100, 300)] {
                let shape = [b, p, t, 13];
                let split = known / 16 * 16;
                let anchors = rand_anchors(&mut rng, b, p);
                let prefix = rand_vec(&mut rng, b * p * known * 13, 2.0);
                let canvas = |rng: &mut StdRng| -> Vec<f32> {
                    let mut x = rand_vec(rng, b * p * t * 13, 2.0);
                    for seq in 0..b * p {
                        x[seq * t * 13..(seq * t + known) * 13].copy_from_slice(&prefix[seq * known * 13..(seq + 1) * known * 13]);
                    }
                    x
                };
                let levels = |level: f64| -> Vec<f64> { (0..b * p * t).map(|i| if i % t < known { 0.0 } else { level }).collect() };
                let fresh = |x: &[f32], level: f64, anchors: &[f32]| -> Vec<f32> {
                    let mut want = vec![0.0f32; x.len()];
                    InferenceNet::with_k3_conv(&net, k3).unwrap().forward(x, shape, &levels(level), Some(anchors), &mut want).unwrap();
                    want
                };
                let mut out = vec![0.0f32; b * p * t * 13];
                for (step, level) in [999.0, 749.0, 499.0, 2.0].into_iter().enumerate() {
                    let x = canvas(&mut rng);
                    cached.forward(&x, shape, &levels(level), Some(&anchors), &mut out).unwrap();
                    assert_eq!(reused(&cached), if step == 0 { 0 } else { b * split }, "{agg:?} {k3:?} {shape:?} step {step}");
                    assert!(out == fresh(&x, level, &anchors), "{agg:?} {k3:?} {shape:?} step {step}: cached ≠ fresh");
                    let r = max_abs_diff(&out, &reference(&net, &x, shape, &levels(level), Some(&anchors)));
                    assert!(r <= 1e-4, "{agg:?} {k3:?} {shape:?} step {step}: cached − candle = {r}");
                }
                // A changed prefix frame of scene 0: that scene is computed anew.
                let mut x = canvas(&mut rng);
                x[(t + known / 2) * 13 + 4] += 0.5;
                cached.forward(&x, shape, &levels(300.0), Some(&anchors), &mut out).unwrap();
                assert_eq!(reused(&cached), if known / 2 < split { (b - 1) * split } else { b * split });
                assert!(out == fresh(&x, 300.0, &anchors), "changed prefix");
                // Other anchors: everything again.
                let other = rand_anchors(&mut rng, b, p);
                cached.forward(&x, shape, &levels(300.0), Some(&other), &mut out).unwrap();
                assert_eq!(reused(&cached), 0);
                assert!(out == fresh(&x, 300.0, &other), "other anchors");
            }
            // No clean prefix, or one level per scene: nothing kept.
            let x = rand_vec(&mut rng, 2 * 40 * 13, 1.0);
            let mut out = vec![0.0f32; x.len()];
            for _ in 0..2 {
                cached.forward(&x, [1, 2, 40, 13], &[500.0], None, &mut out).unwrap();
                assert_eq!(reused(&cached), 0);
                cached.forward(&x, [1, 2, 40, 13], &vec![500.0; 80], None, &mut out).unwrap();
                assert_eq!(reused(&cached), 0);
            }
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let net = InferenceNet::new(&Denoiser::new(tiny(Aggregator::Mean), 0).unwrap()).unwrap();
        let x = vec![0.0f32; 2 * 8 * 7];
        let mut out = vec![0.0f32; x.len()];
        assert!(net.forward(&x, [1, 2, 8, 7], &[1.0], None, &mut out).is_ok());
        let e = |r: Result<()>| r.unwrap_err().to_string();
        assert!(e(net.forward(&x, [1, 2, 8, 6], &[1.0], None, &mut out)).contains("feature dims"));
        assert!(e(net.forward(&x, [1, 2, 9, 7], &[1.0], None, &mut out)).contains("values"));
        assert!(e(net.forward(&x, [1, 2, 8, 7], &[1.0, 2.0], None, &mut out)).contains("timesteps"));
        assert!(e(net.forward(&x, [1, 2, 8, 7], &[1.0], Some(&[0.0; 4]), &mut out)).contains("anchors"));
        assert!(e(net.forward(&[], [0, 2, 8, 7], &[], None, &mut [])).contains("empty"));
    }
}
