//! Gated recurrent unit over frames (PyTorch's `nn.GRU` equations) as a CPU custom op with a
//! hand-written backward pass through time, and the bidirectional layer built on it.
//!
//! candle has no recurrent op, and a GRU unrolled from candle ops builds a graph of ~15 small
//! ops per frame (slow, and every one a place for the gradient traps of CANDLE_NOTES.md). The
//! recurrence here is one op; the input projection `x·W_ih + b_ih` stays a per-frame linear
//! layer ([`crate::model::layers::Linear`], itself a checked custom op).
//!
//! ```text
//! gi = x·W_ih + b_ih                       (outside, all frames at once)
//! gh = h_{t−1}·W_hh + b_hh                 gates in the order [r | z | n], as PyTorch
//! r  = σ(gi_r + gh_r)     z = σ(gi_z + gh_z)
//! n  = tanh(gi_n + r ⊙ gh_n)
//! h_t = (1 − z) ⊙ n + z ⊙ h_{t−1}          h_{−1} = 0
//! ```
//!
//! The reverse direction runs the same recurrence from the last frame to the first.

use crate::model::layers::{join, Linear, ParamInit};
use crate::model::ops::{cpu_kernel, CpuKernel, Real};
use crate::model::Kernels;
use crate::Result;
use candle_core::{CpuStorage, CustomOp3, DType, Layout, Shape, Tensor};
use rayon::prelude::*;

type CResult<T> = candle_core::Result<T>;

/// Sequences per parallel task of the backward pass (fixed, so sums do not depend on the
/// thread count and a training step is reproducible bit for bit).
const SEQS_PER_TASK: usize = 4;

/// The GRU recurrence over all frames of every sequence.
///
/// # Shapes
/// - `gi`: `[N, T, 3H]` input projections (gates `[r | z | n]`);
/// - `w_hh`: `[H, 3H]` (PyTorch's `weight_hh` `[3H, H]` transposed); `b_hh`: `[3H]`;
/// - returns the hidden states `[N, T, H]` (for `reverse`, `h[t]` has seen frames `t..T`).
pub fn gru_recurrence(gi: &Tensor, w_hh: &Tensor, b_hh: &Tensor, reverse: bool) -> CResult<Tensor> {
    gi.contiguous()?.apply_op3(&w_hh.contiguous()?, &b_hh.contiguous()?, GruOp { reverse })
}

/// [`gru_recurrence`] composed from candle built-ins (one small matmul and a few elementwise ops
/// per frame) for devices without the custom op; the backward pass is candle's.
pub fn gru_recurrence_composed(gi: &Tensor, w_hh: &Tensor, b_hh: &Tensor, reverse: bool) -> CResult<Tensor> {
    let (n, t, h) = gru_dims(gi.shape(), w_hh.shape(), b_hh.shape())?;
    let sigmoid = |x: &Tensor| -> CResult<Tensor> { ((x * 0.5)?.tanh()? + 1.0)? * 0.5 };
    let mut prev = Tensor::zeros((n, h), gi.dtype(), gi.device())?;
    let mut states: Vec<Option<Tensor>> = vec![None; t];
    for k in 0..t {
        let f = frame(k, t, reverse);
        let g = gi.narrow(1, f, 1)?.reshape((n, 3 * h))?;
        let gh = prev.matmul(w_hh)?.broadcast_add(b_hh)?;
        let r = sigmoid(&(g.narrow(1, 0, h)? + gh.narrow(1, 0, h)?)?)?;
        let z = sigmoid(&(g.narrow(1, h, h)? + gh.narrow(1, h, h)?)?)?;
        let cand = (g.narrow(1, 2 * h, h)? + (r * gh.narrow(1, 2 * h, h)?)?)?.tanh()?;
        // (1 − z)·n + z·h_{t−1} = n + z·(h_{t−1} − n)
        let next = (&cand + (z * (&prev - &cand)?)?)?;
        states[f] = Some(next.clone());
        prev = next;
    }
    let states: Vec<Tensor> = states.into_iter().map(|s| s.expect("every frame visited")).collect();
    if states.is_empty() {
        return Tensor::zeros((n, 0, h), gi.dtype(), gi.device());
    }
    Tensor::stack(&states, 1)
}

#[derive(Clone, Copy)]
struct GruOp {
    reverse: bool,
}

/// (N, T, H) of a GRU op, checking the shapes.
fn gru_dims(gi: &Shape, w: &Shape, b: &Shape) -> CResult<(usize, usize, usize)> {
    let (n, t, g3) = gi.dims3()?;
    let (h, g3w) = w.dims2()?;
    let g3b = b.dims1()?;
    if g3 != 3 * h || g3w != 3 * h || g3b != 3 * h || h == 0 {
        candle_core::bail!("gru: shapes gi {gi:?}, w_hh {w:?}, b_hh {b:?} do not fit ([N, T, 3H], [H, 3H], [3H])");
    }
    Ok((n, t, h))
}

fn sigmoid<T: Real>(x: T) -> T {
    T::one() / (T::one() + (T::zero() - x).exp_())
}

fn tanh<T: Real>(x: T) -> T {
    let two = T::from_f64(2.0);
    two * sigmoid(two * x) - T::one()
}

/// Frame index of processing step `k` of `t` frames.
fn frame(k: usize, t: usize, reverse: bool) -> usize {
    if reverse {
        t - 1 - k
    } else {
        k
    }
}

/// Runs one sequence: `gi` `[T, 3H]` → `out` `[T, H]`. With `cache` `[T, 4H]`, also keeps
/// `r, z, n, gh_n` of every frame for the backward pass.
fn run_sequence<T: Real>(gi: &[T], w: &[T], b: &[T], h: usize, reverse: bool, out: &mut [T], mut cache: Option<&mut [T]>) {
    let t_len = out.len() / h;
    let g3 = 3 * h;
    let mut gh = vec![T::zero(); g3];
    let mut prev = vec![T::zero(); h];
    for k in 0..t_len {
        let t = frame(k, t_len, reverse);
        gh.copy_from_slice(b);
        for (i, &hp) in prev.iter().enumerate() {
            if hp != T::zero() {
                for (g, &wv) in gh.iter_mut().zip(&w[i * g3..(i + 1) * g3]) {
                    *g += hp * wv;
                }
            }
        }
        let x = &gi[t * g3..(t + 1) * g3];
        let o = &mut out[t * h..(t + 1) * h];
        for j in 0..h {
            let r = sigmoid(x[j] + gh[j]);
            let z = sigmoid(x[h + j] + gh[h + j]);
            let n = tanh(x[2 * h + j] + r * gh[2 * h + j]);
            o[j] = (T::one() - z) * n + z * prev[j];
            if let Some(c) = cache.as_deref_mut() {
                let c = &mut c[t * 4 * h..(t + 1) * 4 * h];
                c[j] = r;
                c[h + j] = z;
                c[2 * h + j] = n;
                c[3 * h + j] = gh[2 * h + j];
            }
        }
        prev.copy_from_slice(o);
    }
}

impl CpuKernel<3> for GruOp {
    type Dims = (usize, usize, usize);

    fn run<T: Real>(&self, [gi, w, b]: [&[T]; 3], (n, t, h): Self::Dims) -> Vec<T> {
        let mut out = vec![T::zero(); n * t * h];
        if t > 0 {
            out.par_chunks_mut(t * h).zip(gi.par_chunks(t * 3 * h)).for_each(|(o, x)| run_sequence(x, w, b, h, self.reverse, o, None));
        }
        out
    }
}

impl CustomOp3 for GruOp {
    fn name(&self) -> &'static str {
        "gru"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout, s3: &CpuStorage, l3: &Layout) -> CResult<(CpuStorage, Shape)> {
        let (n, t, h) = gru_dims(l1.shape(), l2.shape(), l3.shape())?;
        let out = cpu_kernel(self, "gru", [(s1, l1), (s2, l2), (s3, l3)], (n, t, h))?;
        Ok((out, Shape::from((n, t, h))))
    }

    fn bwd(&self, gi: &Tensor, w: &Tensor, b: &Tensor, _res: &Tensor, g: &Tensor) -> CResult<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let (n, t, h) = gru_dims(gi.shape(), w.shape(), b.shape())?;
        fn run<T: Real>(ins: [&Tensor; 4], dims: (usize, usize, usize), reverse: bool) -> CResult<(Vec<T>, Vec<T>, Vec<T>)> {
            let (n, t, h) = dims;
            let flat = |x: &Tensor| x.flatten_all()?.to_vec1::<T>();
            let (gi, w, b, g) = (flat(ins[0])?, flat(ins[1])?, flat(ins[2])?, flat(ins[3])?);
            let g3 = 3 * h;
            let mut dgi = vec![T::zero(); n * t * g3];
            if n == 0 || t == 0 {
                return Ok((dgi, vec![T::zero(); h * g3], vec![T::zero(); g3]));
            }
            // Each task: SEQS_PER_TASK sequences, writing their dgi and returning partial dW, db.
            let parts: Vec<Vec<T>> = dgi
                .par_chunks_mut(SEQS_PER_TASK * t * g3)
                .enumerate()
                .map(|(task, dgi_chunk)| {
                    let mut acc = vec![T::zero(); h * g3 + g3];
                    let (mut out, mut cache) = (vec![T::zero(); t * h], vec![T::zero(); t * 4 * h]);
                    let (mut dh, mut carry, mut dgh) = (vec![T::zero(); h], vec![T::zero(); h], vec![T::zero(); g3]);
                    for (si, dgi_s) in dgi_chunk.chunks_exact_mut(t * g3).enumerate() {
                        let seq = task * SEQS_PER_TASK + si;
                        run_sequence(&gi[seq * t * g3..(seq + 1) * t * g3], &w, &b, h, reverse, &mut out, Some(&mut cache));
                        let gs = &g[seq * t * h..(seq + 1) * t * h];
                        carry.iter_mut().for_each(|c| *c = T::zero());
                        for k in (0..t).rev() {
                            let tt = frame(k, t, reverse);
                            let prev = (k > 0).then(|| frame(k - 1, t, reverse));
                            let c = &cache[tt * 4 * h..(tt + 1) * 4 * h];
                            for j in 0..h {
                                dh[j] = gs[tt * h + j] + carry[j];
                                let (r, z, nn, ghn) = (c[j], c[h + j], c[2 * h + j], c[3 * h + j]);
                                let hp = prev.map_or(T::zero(), |p| out[p * h + j]);
                                let dn = dh[j] * (T::one() - z);
                                let dz = dh[j] * (hp - nn);
                                let dan = dn * (T::one() - nn * nn);
                                let dr = dan * ghn;
                                let dar = dr * r * (T::one() - r);
                                let daz = dz * z * (T::one() - z);
                                dgh[j] = dar;
                                dgh[h + j] = daz;
                                dgh[2 * h + j] = dan * r;
                                let d = &mut dgi_s[tt * g3..(tt + 1) * g3];
                                d[j] = dar;
                                d[h + j] = daz;
                                d[2 * h + j] = dan;
                                carry[j] = dh[j] * z; // direct path h_{t−1} → h_t
                            }
                            let (dw, db) = acc.split_at_mut(h * g3);
                            for (a, &d) in db.iter_mut().zip(&dgh) {
                                *a += d;
                            }
                            if let Some(p) = prev {
                                for i in 0..h {
                                    let hp = out[p * h + i];
                                    let wi = &w[i * g3..(i + 1) * g3];
                                    let mut back = T::zero();
                                    for ((a, &d), &wv) in dw[i * g3..(i + 1) * g3].iter_mut().zip(&dgh).zip(wi) {
                                        *a += hp * d;
                                        back += wv * d;
                                    }
                                    carry[i] += back;
                                }
                            }
                        }
                    }
                    acc
                })
                .collect();
            let mut sum = vec![T::zero(); h * g3 + g3];
            for p in parts {
                for (s, v) in sum.iter_mut().zip(p) {
                    *s += v;
                }
            }
            let db = sum.split_off(h * g3);
            Ok((dgi, sum, db))
        }
        let g = g.contiguous()?;
        let ins = [gi, w, b, &g];
        let dev = gi.device();
        let (dgi, dw, db) = match gi.dtype() {
            DType::F32 => {
                let (a, b2, c) = run::<f32>(ins, (n, t, h), self.reverse)?;
                (Tensor::from_vec(a, (n, t, 3 * h), dev)?, Tensor::from_vec(b2, (h, 3 * h), dev)?, Tensor::from_vec(c, 3 * h, dev)?)
            }
            DType::F64 => {
                let (a, b2, c) = run::<f64>(ins, (n, t, h), self.reverse)?;
                (Tensor::from_vec(a, (n, t, 3 * h), dev)?, Tensor::from_vec(b2, (h, 3 * h), dev)?, Tensor::from_vec(c, 3 * h, dev)?)
            }
            d => candle_core::bail!("gru-bwd: unsupported dtype {d:?} (f32 or f64 only)"),
        };
        Ok((Some(dgi), Some(dw), Some(db)))
    }
}

/// One direction of a GRU layer: input projection and recurrence. Parameters
/// `{prefix}.ih.weight` `[1, I, 3H]`, `{prefix}.ih.bias` `[3H]`, `{prefix}.hh.weight` `[H, 3H]`
/// and `{prefix}.hh.bias` `[3H]`, uniform ±1/√H for the recurrence (PyTorch's init).
#[derive(Clone)]
struct GruDirection {
    input: Linear,
    w_hh: Tensor,
    b_hh: Tensor,
    reverse: bool,
    kernels: Kernels,
}

impl GruDirection {
    fn new(init: &mut ParamInit, prefix: &str, din: usize, hidden: usize, reverse: bool) -> Result<Self> {
        let input = Linear::new(init, &join(prefix, "ih"), din, 3 * hidden, true)?;
        let bound = 1.0 / (hidden as f64).sqrt();
        let w_hh = init.uniform(join(prefix, "hh.weight"), &[hidden, 3 * hidden], bound)?;
        let b_hh = init.uniform(join(prefix, "hh.bias"), &[3 * hidden], bound)?;
        Ok(Self { input, w_hh, b_hh, reverse, kernels: init.kernels() })
    }

    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let gi = self.input.forward(x)?;
        Ok(match self.kernels {
            Kernels::Custom(_) => gru_recurrence(&gi, &self.w_hh, &self.b_hh, self.reverse)?,
            Kernels::Composed(_) => gru_recurrence_composed(&gi, &self.w_hh, &self.b_hh, self.reverse)?,
        })
    }

    fn detached(&self) -> Self {
        Self { input: self.input.detached(), w_hh: self.w_hh.detach(), b_hh: self.b_hh.detach(), ..*self }
    }
}

/// Bidirectional GRU layer: forward and reverse GRUs of width H, outputs concatenated.
/// Parameters under `{prefix}.fwd.*` and `{prefix}.bwd.*` (see `GruDirection`).
#[derive(Clone)]
pub(crate) struct BiGru {
    fwd: GruDirection,
    bwd: GruDirection,
}

impl BiGru {
    pub(crate) fn new(init: &mut ParamInit, prefix: &str, din: usize, hidden: usize) -> Result<Self> {
        Ok(Self {
            fwd: GruDirection::new(init, &join(prefix, "fwd"), din, hidden, false)?,
            bwd: GruDirection::new(init, &join(prefix, "bwd"), din, hidden, true)?,
        })
    }

    /// # Shapes
    /// - `x`: `[N, T, I]`; returns `[N, T, 2H]` (forward states, then reverse states).
    pub(crate) fn forward(&self, x: &Tensor) -> Result<Tensor> {
        Ok(Tensor::cat(&[self.fwd.forward(x)?, self.bwd.forward(x)?], 2)?)
    }

    pub(crate) fn detached(&self) -> Self {
        Self { fwd: self.fwd.detached(), bwd: self.bwd.detached() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ops::tests::grad_check;
    use candle_core::Device;

    /// The recurrence by the textbook formulas, one frame at a time, in f64.
    fn reference(gi: &[f64], w: &[f64], b: &[f64], n: usize, t: usize, h: usize, reverse: bool) -> Vec<f64> {
        let sig = |x: f64| 1.0 / (1.0 + (-x).exp());
        let mut out = vec![0.0; n * t * h];
        for s in 0..n {
            let mut prev = vec![0.0; h];
            let order: Vec<usize> = if reverse { (0..t).rev().collect() } else { (0..t).collect() };
            for tt in order {
                let x = &gi[(s * t + tt) * 3 * h..][..3 * h];
                let gh: Vec<f64> = (0..3 * h).map(|j| b[j] + (0..h).map(|i| prev[i] * w[i * 3 * h + j]).sum::<f64>()).collect();
                let mut cur = vec![0.0; h];
                for j in 0..h {
                    let r = sig(x[j] + gh[j]);
                    let z = sig(x[h + j] + gh[h + j]);
                    let nn = (x[2 * h + j] + r * gh[2 * h + j]).tanh();
                    cur[j] = (1.0 - z) * nn + z * prev[j];
                }
                out[(s * t + tt) * h..][..h].copy_from_slice(&cur);
                prev = cur;
            }
        }
        out
    }

    /// The composed recurrence (any device) against the custom op: values and every gradient.
    #[test]
    fn composed_gru_matches_the_custom_op() {
        use candle_core::Var;
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(8);
        let (n, t, h) = (2, 6, 3);
        let mut r = |shape: &[usize]| {
            Var::from_tensor(
                &Tensor::from_vec((0..shape.iter().product()).map(|_| rng.gen_range(-1.5..1.5)).collect::<Vec<f64>>(), shape, &Device::Cpu).unwrap(),
            )
            .unwrap()
        };
        let (gi, w, b) = (r(&[n, t, 3 * h]), r(&[h, 3 * h]), r(&[3 * h]));
        for reverse in [false, true] {
            let a = gru_recurrence(gi.as_tensor(), w.as_tensor(), b.as_tensor(), reverse).unwrap();
            let c = gru_recurrence_composed(gi.as_tensor(), w.as_tensor(), b.as_tensor(), reverse).unwrap();
            let diff = |x: &Tensor, y: &Tensor| (x - y).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f64>().unwrap();
            assert!(diff(&a, &c) < 1e-12, "reverse {reverse}: {}", diff(&a, &c));
            let weights = Tensor::arange(0.0f64, (n * t * h) as f64, &Device::Cpu).unwrap().reshape((n, t, h)).unwrap().sin().unwrap();
            let (ga, gc) = ((&a * &weights).unwrap().sum_all().unwrap().backward().unwrap(), (&c * &weights).unwrap().sum_all().unwrap().backward().unwrap());
            for v in [&gi, &w, &b] {
                let d = diff(ga.get(v).unwrap(), gc.get(v).unwrap());
                assert!(d < 1e-10, "reverse {reverse}: gradient differs by {d}");
            }
        }
    }

    #[test]
    fn gru_matches_the_textbook_recurrence() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let (n, t, h) = (3, 7, 4);
        let mut r = |k: usize| (0..k).map(|_| rng.gen_range(-1.5..1.5)).collect::<Vec<f64>>();
        let (gi, w, b) = (r(n * t * 3 * h), r(h * 3 * h), r(3 * h));
        let dev = Device::Cpu;
        for reverse in [false, true] {
            let out = gru_recurrence(
                &Tensor::from_vec(gi.clone(), (n, t, 3 * h), &dev).unwrap(),
                &Tensor::from_vec(w.clone(), (h, 3 * h), &dev).unwrap(),
                &Tensor::from_vec(b.clone(), 3 * h, &dev).unwrap(),
                reverse,
            )
            .unwrap();
            let got: Vec<f64> = out.flatten_all().unwrap().to_vec1().unwrap();
            let want = reference(&gi, &w, &b, n, t, h, reverse);
            for (g, w) in got.iter().zip(&want) {
                assert!((g - w).abs() < 1e-12, "reverse {reverse}: {g} vs {w}");
            }
        }
        // A reverse GRU's last frame has seen only itself: h = (1 − z)·n from h_{−1} = 0.
        let bad = gru_recurrence(
            &Tensor::zeros((1, 2, 6), DType::F64, &dev).unwrap(),
            &Tensor::zeros((2, 5), DType::F64, &dev).unwrap(),
            &Tensor::zeros(6, DType::F64, &dev).unwrap(),
            false,
        );
        assert!(bad.is_err());
    }

    #[test]
    fn gru_gradient_matches_finite_differences() {
        // More sequences than one backward task holds, and long enough to carry gradient far.
        for (n, t, h, reverse) in [(1, 1, 3, false), (6, 9, 4, false), (6, 9, 4, true), (2, 40, 2, true)] {
            let err = grad_check(&[&[n, t, 3 * h], &[h, 3 * h], &[3 * h]], |x| gru_recurrence(&x[0], &x[1], &x[2], reverse));
            eprintln!("gru N={n} T={t} H={h} reverse {reverse}: relative error {err:.2e}");
            assert!(err < 1e-6, "N={n} T={t} H={h} reverse {reverse}: relative error {err}");
        }
    }

    #[test]
    fn bigru_gradient_reaches_every_parameter() {
        let mut init = ParamInit::new(5, DType::F64, Device::Cpu);
        let gru = BiGru::new(&mut init, "g", 3, 4).unwrap();
        let vars = init.finish();
        assert_eq!(vars.len(), 8);
        let x = Tensor::rand(-1.0f64, 1.0, (2, 6, 3), &Device::Cpu).unwrap();
        let y = gru.forward(&x).unwrap();
        assert_eq!(y.dims(), &[2, 6, 8]);
        let grads = y.sqr().unwrap().sum_all().unwrap().backward().unwrap();
        for (name, v) in &vars {
            let g: Vec<f64> = grads.get(v).unwrap_or_else(|| panic!("{name}: no gradient")).flatten_all().unwrap().to_vec1().unwrap();
            assert!(g.iter().all(|x| x.is_finite()) && g.iter().any(|&x| x != 0.0), "{name}: {g:?}");
        }
        // Bidirectional: the first output frame of the reverse half depends on the last input.
        let mut x2: Vec<f64> = x.flatten_all().unwrap().to_vec1().unwrap();
        x2[5 * 3] += 0.5;
        let y2 = gru.forward(&Tensor::from_vec(x2, (2, 6, 3), &Device::Cpu).unwrap()).unwrap();
        let d = (y2 - &y).unwrap().abs().unwrap();
        let first_fwd: f64 = d.narrow(1, 0, 1).unwrap().narrow(2, 0, 4).unwrap().sum_all().unwrap().to_scalar().unwrap();
        let first_bwd: f64 = d.narrow(1, 0, 1).unwrap().narrow(2, 4, 4).unwrap().sum_all().unwrap().to_scalar().unwrap();
        assert_eq!(first_fwd, 0.0);
        assert!(first_bwd > 0.0);
    }
}
