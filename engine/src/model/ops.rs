//! CPU tensor ops with hand-written backward passes, for the channels-last layout
//! `[sequences, frames, channels]` the denoiser uses everywhere.
//!
//! candle 0.11.1's own `conv1d` has wrong gradients on CPU, its LayerNorm and softmax have no
//! backward at all, and its batched matmul is wrong for some transposed operands
//! (`shared/docs/CANDLE_NOTES.md`). Every op here is a candle `CustomOp` whose backward is
//! itself a (gradient-free) custom op, and each one has a finite-difference gradient check below.
//!
//! [`super::dispatch::Kernels`] picks between these and the composed ops.
//!
//! | op | forward | backward |
//! |---|---|---|
//! | [`causal_conv1d`] | `y[o] = b + Σ_k x[o·s + k − (K−1)]·W[k]` (left padding only) | gemm on row-offset views, no im2col; stride-1 k3 as Winograd F(2, 3) ([`K3Conv`]) |
//! | [`causal_conv1d_cat`] | the same over two inputs' channels side by side (not stored), optionally then upsampled | the same, the input gradient split |
//! | [`layer_norm`] | `(x − μ)/√(σ² + ε)·γ + β` over channels | one pass per row |
//! | [`silu`] | `x·σ(x)` | `σ(x)(1 + x(1 − σ(x)))` |
//! | [`silu_layer_norm`] | the two above in one pass (the residual blocks') | one pass per row |
//! | [`silu_layer_norm_conv1d`] | a conv of that, the normalized activation not stored | recomputes it |
//! | [`causal_upsample2x`] | `y[2o] = ½(x[o−1] + x[o])`, `y[2o+1] = x[o]` (`x[−1] := x[0]`) | transpose of that |
//! | [`bmm`] | `C[g] = op(A[g])·op(B[g])`, `op` = identity or transpose | two more `bmm`s |
//!
//! Inputs may have any layout (the wrappers make them contiguous); f32 and f64 are supported.
//! All kernels are deterministic: parallel reductions (weight and bias gradients) use a fixed
//! split that does not depend on the thread count, so a training step is reproducible bit for
//! bit on one machine.

use super::kernels;
use candle_core::backend::BackendStorage;
use candle_core::{CpuStorage, CustomOp1, CustomOp2, CustomOp3, DType, Layout, Shape, Tensor, WithDType};
use gemm::Parallelism;
use rayon::prelude::*;

type CResult<T> = candle_core::Result<T>;

/// Frames per parallel task.
const BLOCK: usize = 128;
/// Number of partial sums of a parallel reduction (independent of the thread count).
const REDUCE_GROUPS: usize = 8;
/// Output rows per partial sum of a conv's weight gradient (2 to [`REDUCE_GROUPS`] of them).
const ROWS_PER_REDUCE_GROUP: usize = 1024;
/// Elements per parallel task when the partial sums are added.
const REDUCE_CHUNK: usize = 16 * 1024;

/// Precision of the convolutions' matrix products on the composed path.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Precision {
    /// Everything in the network's dtype.
    #[default]
    F32,
    /// bf16 matmuls inside the convolutions and linear layers, f32 weights, activations,
    /// normalization and loss (mixed precision).
    Bf16,
}

impl std::str::FromStr for Precision {
    type Err = crate::Error;

    fn from_str(s: &str) -> crate::Result<Self> {
        match s {
            "f32" | "fp32" => Ok(Precision::F32),
            "bf16" => Ok(Precision::Bf16),
            _ => crate::bail!("precision `{s}` is not one of f32, bf16"),
        }
    }
}

/// How the CPU kernels compute the U-Net's stride-1 kernel-3 convolutions (the residual
/// blocks' and the decoder's: 80 % of the multiply-adds at H = 128), in training (forward,
/// input and weight gradients) and in the forward-only sampler. The two differ by rounding.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum K3Conv {
    /// Winograd F(2, 3): four gemms of inner size C_in per two frames, two thirds of the
    /// direct conv's multiply-adds, plus input and output transforms.
    #[default]
    Winograd,
    /// One gemm over the overlapping input rows, inner size 3·C_in.
    Direct,
}

impl K3Conv {
    /// The name users type.
    pub fn name(self) -> &'static str {
        match self {
            Self::Winograd => "winograd",
            Self::Direct => "direct",
        }
    }
}

/// The float types the kernels support (f32, f64).
pub(crate) trait Real: WithDType + kernels::SumFloat {
    /// e^x (f32: [`kernels::exp`], which vectorizes).
    fn exp_(self) -> Self;
    fn sqrt_(self) -> Self;
    /// Runs `f` on this thread's scratch buffer of `len` values (contents unspecified).
    fn with_scratch<R>(len: usize, f: impl FnOnce(&mut [Self]) -> R) -> R;
    /// [`kernels::winograd_input_any`] (vectorized for f32).
    fn winograd_input(u: &mut [Self], x: &[Self], c: usize, tiles: usize, plane: usize);
    /// [`kernels::winograd_output_any`] (vectorized for f32).
    fn winograd_output(y: &mut [Self], m: &[Self], c: usize, tiles: usize, plane: usize, add: bool);
    /// [`kernels::winograd_grad_any`] (vectorized for f32).
    fn winograd_grad(v: &mut [Self], dy: &[Self], c: usize, tiles: usize, plane: usize);
}

thread_local! {
    static SCRATCH_F32: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
    static SCRATCH_F64: std::cell::RefCell<Vec<f64>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// [`Real::with_scratch`] on the thread-local buffer `key`, grown to `len` when shorter.
fn with_scratch_in<T: Copy + Default + 'static, R>(
    key: &'static std::thread::LocalKey<std::cell::RefCell<Vec<T>>>,
    len: usize,
    f: impl FnOnce(&mut [T]) -> R,
) -> R {
    key.with_borrow_mut(|buf| {
        if buf.len() < len {
            buf.resize(len, T::default());
        }
        f(&mut buf[..len])
    })
}

/// `impl Real` for a float type: its scratch buffer and its Winograd transforms.
macro_rules! impl_real {
    ($t:ty, $exp:expr, $scratch:ident, $input:path, $output:path, $grad:path) => {
        impl Real for $t {
            #[inline(always)]
            fn exp_(self) -> Self {
                $exp(self)
            }
            #[inline(always)]
            fn sqrt_(self) -> Self {
                self.sqrt()
            }
            fn with_scratch<R>(len: usize, f: impl FnOnce(&mut [Self]) -> R) -> R {
                with_scratch_in(&$scratch, len, f)
            }
            fn winograd_input(u: &mut [Self], x: &[Self], c: usize, tiles: usize, plane: usize) {
                $input(u, x, c, tiles, plane)
            }
            fn winograd_output(y: &mut [Self], m: &[Self], c: usize, tiles: usize, plane: usize, add: bool) {
                $output(y, m, c, tiles, plane, add)
            }
            fn winograd_grad(v: &mut [Self], dy: &[Self], c: usize, tiles: usize, plane: usize) {
                $grad(v, dy, c, tiles, plane)
            }
        }
    };
}

// f32 uses the vectorizable exp of the kernels (relative error ≈ 2e-7), f64 the library's.
impl_real!(f32, kernels::exp, SCRATCH_F32, kernels::winograd_input, kernels::winograd_output, kernels::winograd_grad);
impl_real!(f64, f64::exp, SCRATCH_F64, kernels::winograd_input_any, kernels::winograd_output_any, kernels::winograd_grad_any);

/// Winograd F(2, 3) ([`kernels`]) for the stride-1 kernel-3 convs, forward and input
/// gradient: the transformed taps `[4, len]` of three taps `[3, len]` (tap k at k·len), in f64.
fn winograd_taps<T: Real>(taps: &[T], len: usize) -> Vec<T> {
    let mut out = vec![T::zero(); kernels::WINO_ALPHA * len];
    out.par_chunks_mut(len).zip(kernels::WINO_G.par_iter()).for_each(|(dst, g)| {
        for (e, d) in dst.iter_mut().enumerate() {
            *d = T::from_f64((0..3).map(|k| g[k] * taps[k * len + e].to_f64()).sum());
        }
    });
    out
}

/// `dst[r] (+)= Σ_{k<3} src[r + k]·W_k` for the rows r of each segment's `dst` (`[rows,
/// C_out]`), with `wt` the transformed taps ([`winograd_taps`] of W `[3, C_in, C_out]`). A
/// segment's `src` (`[frames, C_in]`) must hold at least 2·⌈rows/2⌉ + 1 frames; frames past its
/// end read as zeros (only the discarded second output of an odd last tile can see them). The
/// tiles of all segments (runs of rows of several sequences) share one gemm per Winograd plane,
/// so short sequences still make tall products and the weights are packed once per task.
fn winograd_k3<T: Real>(segments: &mut [(&mut [T], &[T])], cin: usize, cout: usize, wt: &[T], add: bool) {
    let tiles_of = |dst: &[T]| (dst.len() / cout).div_ceil(kernels::WINO_M);
    let tiles: usize = segments.iter().map(|(dst, _)| tiles_of(dst)).sum();
    if tiles == 0 {
        return;
    }
    let (u_len, m_len) = (kernels::WINO_ALPHA * tiles * cin, kernels::WINO_ALPHA * tiles * cout);
    T::with_scratch(u_len + m_len, |buf| {
        let (u, m) = buf.split_at_mut(u_len);
        let mut at = 0;
        for (dst, src) in segments.iter() {
            let n = tiles_of(dst);
            T::winograd_input(&mut u[at * cin..], src, cin, n, tiles * cin);
            at += n;
        }
        for i in 0..kernels::WINO_ALPHA {
            let mi = &mut m[i * tiles * cout..(i + 1) * tiles * cout];
            // SAFETY: u_i is [tiles, C_in], wt_i is [C_in, C_out], mi is [tiles, C_out].
            unsafe {
                gemm_into(tiles, cout, cin, mi.as_mut_ptr(), cout, 1, u.as_ptr().add(i * tiles * cin), cin, 1, wt.as_ptr().add(i * cin * cout), cout, 1, false)
            };
        }
        at = 0;
        for (dst, _) in segments.iter_mut() {
            let n = tiles_of(dst);
            T::winograd_output(dst, &m[at * cout..], cout, n, tiles * cout, add);
            at += n;
        }
    })
}

/// Rows per parallel task of a conv over `rows` rows of all sequences (fixed by the shape:
/// about eight tasks, 128 to 512 rows each).
fn conv_task_rows(rows: usize) -> usize {
    rows.div_ceil(8).clamp(128, 512).next_multiple_of(2)
}

/// The runs of rows `rows` of each sequence (of `len` rows) that fall in the flat rows
/// `r0..r1`: `(sequence, lo, hi)`.
fn sequence_runs(r0: usize, r1: usize, len: usize, rows: std::ops::Range<usize>) -> Vec<(usize, usize, usize)> {
    (r0 / len..r1.div_ceil(len))
        .filter_map(|seq| {
            let lo = r0.saturating_sub(seq * len).max(rows.start);
            let hi = (r1 - seq * len).min(rows.end);
            (lo < hi).then_some((seq, lo, hi))
        })
        .collect()
}

/// Splits `slab` (the flat rows `r0..` of `[rows, c]`, in order) into the sub-slices of `runs`
/// (`(sequence, lo, hi)` with flat rows `sequence·len + lo .. sequence·len + hi`, increasing).
fn run_slices<'a, T>(mut slab: &'a mut [T], r0: usize, c: usize, len: usize, runs: &[(usize, usize, usize)]) -> Vec<&'a mut [T]> {
    let mut at = r0;
    let mut out = Vec::with_capacity(runs.len());
    for &(seq, lo, hi) in runs {
        let rest = std::mem::take(&mut slab);
        let (_, rest) = rest.split_at_mut((seq * len + lo - at) * c);
        let (run, rest) = rest.split_at_mut((hi - lo) * c);
        out.push(run);
        slab = rest;
        at = seq * len + hi;
    }
    out
}

/// `dst[r] = init + Σ_k src[r − lead + k]·W_k` (or `dst[r] = Σ_k …` without `init`, other
/// rows untouched) for the rows `rows` of every sequence, with `wt` the transformed taps of W
/// `[3, C_src, C_dst]`: the stride-1 k3 conv (lead 2) and its input gradient (lead 0). Tasks of
/// rows of several sequences ([`conv_task_rows`]), each one [`winograd_k3`] over all its runs;
/// with `init`, every row of a task starts as `init` (the edge rows are added later).
///
/// # Shapes
/// - `dst`: `[N, len, C_dst]`, `src`: `[N, src_len, C_src]`
#[allow(clippy::too_many_arguments)]
fn winograd_conv_rows<T: Real>(
    dst: &mut [T],
    src: &[T],
    (n, len, src_len): (usize, usize, usize),
    (c_dst, c_src): (usize, usize),
    rows: std::ops::Range<usize>,
    lead: usize,
    wt: &[T],
    init: Option<&[T]>,
) {
    let per = conv_task_rows(n * len);
    dst.par_chunks_mut(per * c_dst).enumerate().for_each(|(task, slab)| {
        if let Some(init) = init {
            for row in slab.chunks_exact_mut(c_dst) {
                row.copy_from_slice(init);
            }
        }
        let r0 = task * per;
        let runs = sequence_runs(r0, r0 + slab.len() / c_dst, len, rows.clone());
        let dsts = run_slices(slab, r0, c_dst, len, &runs);
        let mut segments: Vec<(&mut [T], &[T])> = dsts
            .into_iter()
            .zip(&runs)
            .map(|(d, &(seq, lo, hi))| {
                // a run's tiles read src rows lo − lead … lo − lead + 2·tiles + 1 (those past
                // the sequence read as zeros)
                let first = lo - lead;
                let end = (first + kernels::WINO_M * (hi - lo).div_ceil(kernels::WINO_M) + 2).min(src_len);
                (d, &src[(seq * src_len + first) * c_src..(seq * src_len + end) * c_src])
            })
            .collect();
        winograd_k3(&mut segments, c_src, c_dst, wt, init.is_some());
    });
}

/// Most Winograd tiles of the weight gradient transformed before their products are summed
/// (one gemm per plane over all of them: few passes over the accumulator, bounded scratch).
const WINO_GROUP_TILES: usize = 512;

/// Adds the Winograd products `P_i += U_iᵀ·V_i` of the full rows `lo..o1` of the `pending`
/// (input, gradient) sequences to `acc` (`[4, C_in, C_out]` first), and empties `pending`.
#[allow(clippy::type_complexity)]
fn winograd_weight_sums<T: Real>(pending: &mut Vec<(&[T], &[T], usize, usize)>, acc: &mut [T], (t, cin, cout): (usize, usize, usize)) {
    let tiles: usize = pending.iter().map(|&(_, _, lo, o1)| (o1 - lo).div_ceil(kernels::WINO_M)).sum();
    if tiles == 0 {
        return;
    }
    let (u_len, v_len) = (kernels::WINO_ALPHA * tiles * cin, kernels::WINO_ALPHA * tiles * cout);
    T::with_scratch(u_len + v_len, |buf| {
        let (u, v) = buf.split_at_mut(u_len);
        let mut at = 0;
        for &(x_seq, g_seq, lo, o1) in pending.iter() {
            let n_tiles = (o1 - lo).div_ceil(kernels::WINO_M);
            let end = (lo + kernels::WINO_M * n_tiles).min(t);
            T::winograd_input(&mut u[at * cin..], &x_seq[(lo - 2) * cin..end * cin], cin, n_tiles, tiles * cin);
            T::winograd_grad(&mut v[at * cout..], &g_seq[lo * cout..o1 * cout], cout, n_tiles, tiles * cout);
            at += n_tiles;
        }
        for i in 0..kernels::WINO_ALPHA {
            // SAFETY: P_i [C_in, C_out] += U_iᵀ ([tiles, C_in] read transposed)·V_i [tiles, C_out].
            unsafe {
                gemm_into(
                    cin,
                    cout,
                    tiles,
                    acc.as_mut_ptr().add(i * cin * cout),
                    cout,
                    1,
                    u.as_ptr().add(i * tiles * cin),
                    1,
                    cin,
                    v.as_ptr().add(i * tiles * cout),
                    cout,
                    1,
                    true,
                );
            }
        }
    });
    pending.clear();
}

/// The contiguous elements of a CPU storage seen through `layout`.
pub(crate) fn slice<'a, T: WithDType>(s: &'a CpuStorage, layout: &Layout, op: &str) -> CResult<&'a [T]> {
    match layout.contiguous_offsets() {
        Some((a, b)) => Ok(&s.as_slice::<T>()?[a..b]),
        None => candle_core::bail!("{op}: input must be contiguous"),
    }
}

pub(crate) fn storage<T: WithDType>(v: Vec<T>) -> CpuStorage {
    T::to_cpu_storage_owned(v)
}

/// The CPU body of a custom op: its contiguous operands as slices of one float type → its
/// output; `Dims` is what it needs besides them (sizes read from the layouts, settings).
pub(crate) trait CpuKernel<const N: usize> {
    type Dims: Copy;
    fn run<T: Real>(&self, operands: [&[T]; N], dims: Self::Dims) -> Vec<T>;
}

/// Runs `kernel` on the operands (f32 or f64, contiguous; `name` in errors).
pub(crate) fn cpu_kernel<K: CpuKernel<N>, const N: usize>(kernel: &K, name: &str, operands: [(&CpuStorage, &Layout); N], dims: K::Dims) -> CResult<CpuStorage> {
    fn typed<T: Real, K: CpuKernel<N>, const N: usize>(kernel: &K, name: &str, operands: [(&CpuStorage, &Layout); N], dims: K::Dims) -> CResult<CpuStorage> {
        let mut xs: [&[T]; N] = [&[]; N];
        for (x, (s, l)) in xs.iter_mut().zip(operands) {
            *x = slice::<T>(s, l, name)?;
        }
        Ok(storage(kernel.run(xs, dims)))
    }
    match operands.first().map(|o| o.0.dtype()) {
        Some(DType::F32) => typed::<f32, K, N>(kernel, name, operands, dims),
        Some(DType::F64) => typed::<f64, K, N>(kernel, name, operands, dims),
        d => candle_core::bail!("{name}: unsupported dtype {d:?} (f32 or f64 only)"),
    }
}

fn ceil_div(a: usize, b: usize) -> usize {
    a.div_ceil(b)
}

/// `dst := dst + lhs·rhs` on strided matrices (`dst := lhs·rhs` without `accumulate`: no need to
/// zero it first), single-threaded (callers parallelize).
///
/// # Safety
/// Every pointer must address valid memory for the given sizes and strides, `dst` must not
/// alias the operands, and `T` must be f32 or f64.
#[allow(clippy::too_many_arguments)]
unsafe fn gemm_into<T: Real>(
    m: usize,
    n: usize,
    k: usize,
    dst: *mut T,
    dst_rs: usize,
    dst_cs: usize,
    lhs: *const T,
    lhs_rs: usize,
    lhs_cs: usize,
    rhs: *const T,
    rhs_rs: usize,
    rhs_cs: usize,
    accumulate: bool,
) {
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        if !accumulate {
            for r in 0..m {
                for c in 0..n {
                    *dst.add(r * dst_rs + c * dst_cs) = T::zero();
                }
            }
        }
        return;
    }
    super::profile::count_products(m, n, k);
    gemm::gemm(
        m,
        n,
        k,
        dst,
        dst_cs as isize,
        dst_rs as isize,
        accumulate,
        lhs,
        lhs_cs as isize,
        lhs_rs as isize,
        rhs,
        rhs_cs as isize,
        rhs_rs as isize,
        T::from_f64(1.0),
        T::from_f64(1.0),
        false,
        false,
        false,
        Parallelism::None,
    )
}

/// Items per group when `n` items are split into at most `groups` fixed groups.
fn reduce_group_len(n: usize, groups: usize) -> usize {
    ceil_div(n.max(1), groups.min(n.max(1)).max(1))
}

/// Sums `f(range, acc)` over `0..n` split into at most `groups` fixed ranges (≤
/// [`REDUCE_GROUPS`]), in parallel, then adds the partial sums in order: deterministic for any
/// thread count.
fn det_par_sum<T: Real>(n: usize, groups: usize, len: usize, f: impl Fn(std::ops::Range<usize>, &mut [T]) + Sync) -> Vec<T> {
    let per = reduce_group_len(n, groups);
    let groups = n.max(1).div_ceil(per);
    let parts: Vec<Vec<T>> = (0..groups)
        .into_par_iter()
        .map(|g| {
            let mut acc = vec![T::zero(); len];
            let r = (g * per).min(n)..((g + 1) * per).min(n);
            if !r.is_empty() {
                f(r, &mut acc);
            }
            acc
        })
        .collect();
    sum_in_order(parts, len)
}

/// The element-wise sum of partial sums of `len` values, added in their order (chunks of
/// elements in parallel).
fn sum_in_order<T: Real>(parts: Vec<Vec<T>>, len: usize) -> Vec<T> {
    let mut it = parts.into_iter();
    let mut out = it.next().unwrap_or_else(|| vec![T::zero(); len]);
    let rest: Vec<Vec<T>> = it.collect();
    out.par_chunks_mut(REDUCE_CHUNK).enumerate().for_each(|(c, dst)| {
        let range = c * REDUCE_CHUNK..c * REDUCE_CHUNK + dst.len();
        for p in &rest {
            for (o, &v) in dst.iter_mut().zip(&p[range.clone()]) {
                *o += v;
            }
        }
    });
    out
}

// ---------------------------------------------------------------------------------------------
// Causal convolution
// ---------------------------------------------------------------------------------------------

/// Output length of a causal convolution with `stride` over `t` frames: ⌈t / stride⌉.
pub fn conv_out_len(t: usize, stride: usize) -> usize {
    ceil_div(t, stride)
}

/// Causal 1-D convolution, channels last, with bias.
///
/// `y[n, o, :] = b + Σ_{k<K} x[n, o·s + k − (K−1), :]·W[k]`, terms with a negative frame index
/// being zero (left padding only): output `o` sees input frames `≤ o·s`. With `K = 1, s = 1`
/// this is a per-frame linear layer.
///
/// # Shapes
/// - `x`: `[N, T, C_in]`
/// - `w`: `[K, C_in, C_out]` (PyTorch's Conv1d weight `[C_out, C_in, K]` permuted (2, 1, 0))
/// - `b`: `[C_out]`
/// - returns `[N, ⌈T/s⌉, C_out]`
pub fn causal_conv1d(x: &Tensor, w: &Tensor, b: &Tensor, stride: usize) -> CResult<Tensor> {
    causal_conv1d_with(x, w, b, stride, K3Conv::default())
}

/// [`causal_conv1d`] with the given algorithm for stride-1 k3 convs (forward and gradients).
pub fn causal_conv1d_with(x: &Tensor, w: &Tensor, b: &Tensor, stride: usize, k3: K3Conv) -> CResult<Tensor> {
    if stride == 0 {
        candle_core::bail!("causal_conv1d: stride must be positive");
    }
    x.contiguous()?.apply_op3(&w.contiguous()?, &b.contiguous()?, CausalConv { stride, winograd: k3 == K3Conv::Winograd })
}

struct CausalConv {
    stride: usize,
    /// Winograd F(2, 3) when the conv is stride-1 k3.
    winograd: bool,
}

/// Checks the shapes of a convolution; returns (N, T, C_in, K, C_out).
fn conv_dims(x: &Shape, w: &Shape, b: &Shape) -> CResult<(usize, usize, usize, usize, usize)> {
    let (n, t, cin) = x.dims3()?;
    let (k, cin2, cout) = w.dims3()?;
    let cout2 = b.dims1()?;
    if cin != cin2 || cout != cout2 || k == 0 {
        candle_core::bail!("causal_conv1d: x {x:?}, weight {w:?}, bias {b:?} do not fit");
    }
    Ok((n, t, cin, k, cout))
}

impl CustomOp3 for CausalConv {
    fn name(&self) -> &'static str {
        "causal-conv1d"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout, s3: &CpuStorage, l3: &Layout) -> CResult<(CpuStorage, Shape)> {
        let _timer = super::profile::Timer::start(self.name());
        let (n, t, cin, k, cout) = conv_dims(l1.shape(), l2.shape(), l3.shape())?;
        let s = self.stride;
        let out = cpu_kernel(self, "causal-conv1d", [(s1, l1), (s2, l2), (s3, l3)], ((n, t, cin, k, cout), s, self.winograd))?;
        Ok((out, Shape::from((n, conv_out_len(t, s), cout))))
    }

    fn bwd(&self, x: &Tensor, w: &Tensor, b: &Tensor, _res: &Tensor, g: &Tensor) -> CResult<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let (_, t, cin) = x.dims3()?;
        let (k, _, cout) = w.dims3()?;
        let g = g.contiguous()?;
        let winograd = self.winograd;
        let dx = if x.track_op() { Some(g.apply_op2_no_bwd(w, &ConvBwdInput { stride: self.stride, t, winograd })?) } else { None };
        let (dw, db) = if w.track_op() || b.track_op() {
            let flat = x.apply_op2_no_bwd(&g, &ConvBwdParams { stride: self.stride, k, winograd })?;
            let dw = flat.narrow(0, 0, k * cin * cout)?.reshape((k, cin, cout))?;
            let db = flat.narrow(0, k * cin * cout, cout)?;
            (Some(dw), Some(db))
        } else {
            (None, None)
        };
        Ok((dx, dw, db))
    }
}

impl CpuKernel<3> for CausalConv {
    type Dims = ((usize, usize, usize, usize, usize), usize, bool);

    fn run<T: Real>(&self, [x, w, b]: [&[T]; 3], (d, s, wino): Self::Dims) -> Vec<T> {
        conv_fwd(x, w, b, d, s, wino)
    }
}

// Channels last, the K input frames one output reads are one contiguous run of K·C_in values, so
// every row whose taps all lie inside the sequence is one row of a single gemm with inner size
// K·C_in (rows overlap in memory; no im2col copy). The first ⌈(K−1)/s⌉ outputs of a sequence,
// whose early taps fall into the left padding, are gathered from all sequences into one small
// zero-padded matrix and done by one more gemm, so the weights are packed once per call, not
// once per sequence and tap. Stride-1 k3 convs run as Winograd F(2, 3) by default
// ([`K3Conv`]): forward and input gradient are k3 correlations (the input gradient one over the
// output gradient with the flipped, transposed taps), and the weight gradient is the transpose of
// the algorithm, P_i = Σ_tiles (Bᵀd)_iᵀ·(A·dy)_i and dW_k = Σ_i G[i][k]·P_i, with the tiles of
// many sequences in one gemm per plane. Two thirds of the multiply-adds; a training step at
// H = 256 took 2.62–2.77 s against 3.06–3.12 s direct (docs/results.md, speed).

/// First output row whose K taps all read real frames: ⌈(K − 1)/s⌉ (capped at `to`).
fn first_full_row(k: usize, s: usize, to: usize) -> usize {
    ceil_div(k - 1, s).min(to)
}

/// The first `edge` output rows of every sequence as im2col rows, `[N·edge, K·C_in]`: row
/// (seq, o) holds input frames o·s − (K−1) ..= o·s, zeros for the frames before 0.
fn edge_rows<T: Real>(x: &[T], (n, t, cin, k, _): (usize, usize, usize, usize, usize), s: usize, edge: usize) -> Vec<T> {
    let mut rows = vec![T::zero(); n * edge * k * cin];
    for (r, row) in rows.chunks_exact_mut(k * cin).enumerate() {
        let (seq, o) = (r / edge, r % edge);
        for (kk, dst) in row.chunks_exact_mut(cin).enumerate() {
            if let Some(i) = (o * s + kk).checked_sub(k - 1) {
                dst.copy_from_slice(&x[(seq * t + i) * cin..(seq * t + i + 1) * cin]);
            }
        }
    }
    rows
}

/// `lhs·rhs` for `lhs` `[m, k]` and `rhs` `[k, n]`, both row-major, split into row blocks run in
/// parallel (each row's sums do not depend on the split).
fn par_matmul<T: Real>(lhs: &[T], rhs: &[T], m: usize, k: usize, n: usize) -> Vec<T> {
    let mut out = vec![T::zero(); m * n];
    if out.is_empty() {
        return out;
    }
    const ROWS: usize = 32;
    out.par_chunks_mut(ROWS * n).enumerate().for_each(|(blk, dst)| {
        let rows = dst.len() / n;
        // SAFETY: rows blk·ROWS .. + rows of lhs ([m, k]); rhs is [k, n]; dst is [rows, n].
        unsafe { gemm_into(rows, n, k, dst.as_mut_ptr(), n, 1, lhs.as_ptr().add(blk * ROWS * k), k, 1, rhs.as_ptr(), n, 1, true) };
    });
    out
}

fn conv_fwd<T: Real>(x: &[T], w: &[T], b: &[T], dims: (usize, usize, usize, usize, usize), s: usize, winograd: bool) -> Vec<T> {
    let (n, t, cin, k, cout) = dims;
    let to = conv_out_len(t, s);
    let mut out = vec![T::zero(); n * to * cout];
    if out.is_empty() {
        return out;
    }
    let full = first_full_row(k, s, to);
    if winograd && k == 3 && s == 1 {
        let wt = winograd_taps(w, cin * cout);
        // Full rows: out[o] += Σ_k x[o − 2 + k]·W_k, after the bias.
        winograd_conv_rows(&mut out, x, (n, to, t), (cout, cin), full..to, 2, &wt, Some(b));
    } else {
        out.par_chunks_mut(to * cout).enumerate().for_each(|(seq, out_seq)| {
            let x_seq = &x[seq * t * cin..(seq + 1) * t * cin];
            out_seq.par_chunks_mut(BLOCK * cout).enumerate().for_each(|(blk, out_blk)| {
                let o0 = blk * BLOCK;
                let o1 = o0 + out_blk.len() / cout;
                for row in out_blk.chunks_exact_mut(cout) {
                    row.copy_from_slice(b);
                }
                // Full rows: out[o] += x[o·s − (K−1) .. o·s + 1] (K·C_in values) · W as [K·C_in, C_out].
                let lo = o0.max(full);
                if lo < o1 {
                    // SAFETY: input frames lo·s − (K−1) ..= (o1 − 1)·s lie in [0, t).
                    unsafe {
                        gemm_into(
                            o1 - lo,
                            cout,
                            k * cin,
                            out_blk.as_mut_ptr().add((lo - o0) * cout),
                            cout,
                            1,
                            x_seq.as_ptr().add((lo * s + 1 - k) * cin),
                            s * cin,
                            1,
                            w.as_ptr(),
                            cout,
                            1,
                            true,
                        );
                    }
                }
            });
        });
    }
    // The edge rows of all sequences: one gemm over their zero-padded im2col rows.
    if full > 0 {
        let edge = par_matmul(&edge_rows(x, dims, s, full), w, n * full, k * cin, cout);
        for (r, row) in edge.chunks_exact(cout).enumerate() {
            let (seq, o) = (r / full, r % full);
            for (d, &v) in out[(seq * to + o) * cout..(seq * to + o + 1) * cout].iter_mut().zip(row) {
                *d += v;
            }
        }
    }
    out
}

/// dx of [`causal_conv1d`]: args (g `[N, To, C_out]`, W `[K, C_in, C_out]`) → `[N, T, C_in]`.
struct ConvBwdInput {
    stride: usize,
    t: usize,
    winograd: bool,
}

impl CustomOp2 for ConvBwdInput {
    fn name(&self) -> &'static str {
        "causal-conv1d-bwd-input"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> CResult<(CpuStorage, Shape)> {
        let _timer = super::profile::Timer::start(self.name());
        let (n, to, cout) = l1.shape().dims3()?;
        let (k, cin, cout2) = l2.shape().dims3()?;
        if cout != cout2 || to != conv_out_len(self.t, self.stride) {
            candle_core::bail!("causal-conv1d-bwd-input: bad shapes");
        }
        let (s, t) = (self.stride, self.t);
        let out = cpu_kernel(self, "causal-conv1d-bwd-input", [(s1, l1), (s2, l2)], ((n, t, cin, k, cout), s, self.winograd))?;
        Ok((out, Shape::from((n, t, cin))))
    }
}

impl CpuKernel<2> for ConvBwdInput {
    type Dims = ((usize, usize, usize, usize, usize), usize, bool);

    fn run<T: Real>(&self, [g, w]: [&[T]; 2], (d, s, wino): Self::Dims) -> Vec<T> {
        conv_bwd_input(g, w, d, s, wino)
    }
}

/// The input gradient by phase. Input row i = s·m + r (phase r < s) is read by the outputs
/// m + j, j = j0 ..< j0 + taps, through tap r + K − 1 − j·s, so
/// dx[s·m + r] = Σ_j g[m + j]·W[r + K − 1 − j·s]ᵀ: one gemm whose left rows are `taps`
/// consecutive gradient rows (one contiguous run of taps·C_out values) against the phase's
/// stacked, transposed taps `[taps·C_out, C_in]`.
struct InputPhase<T> {
    r: usize,
    j0: usize,
    taps: usize,
    /// Input rows of this phase: s·m + r < T.
    rows: usize,
    /// Rows m < full read all their taps from outputs < T_out; the rest are the tail.
    full: usize,
    w: Vec<T>,
}

impl<T: Real> InputPhase<T> {
    fn new(w: &[T], (t, cin, k, cout): (usize, usize, usize, usize), s: usize, to: usize, r: usize) -> Self {
        let j0 = usize::from(r > 0);
        let taps = ((r + k - 1) / s + 1).saturating_sub(j0);
        let rows = (t - r).div_ceil(s);
        let full = rows.min((to + 1).saturating_sub(j0 + taps));
        let kks: Vec<usize> = (j0..j0 + taps).map(|j| r + k - 1 - j * s).collect();
        Self { r, j0, taps, rows, full, w: transposed_taps(w, &kks, cin, cout) }
    }
}

/// The taps `kks` of W (`[K, C_in, C_out]`) transposed and stacked, `[kks.len()·C_out, C_in]`
/// with block q = W[kks[q]]ᵀ, transposed in tiles (a plain loop's strided writes cost as much
/// as the gemm at T = 32).
fn transposed_taps<T: Real>(w: &[T], kks: &[usize], cin: usize, cout: usize) -> Vec<T> {
    const TILE: usize = 32;
    let mut out = vec![T::zero(); kks.len() * cout * cin];
    if out.is_empty() {
        return out;
    }
    out.par_chunks_mut(TILE * cin).enumerate().for_each(|(blk, rows)| {
        for ci0 in (0..cin).step_by(TILE) {
            let ci1 = (ci0 + TILE).min(cin);
            for (dr, row) in rows.chunks_exact_mut(cin).enumerate() {
                let r = blk * TILE + dr;
                let src = kks[r / cout] * cin * cout + r % cout;
                for ci in ci0..ci1 {
                    row[ci] = w[src + ci * cout];
                }
            }
        }
    });
    out
}

fn conv_bwd_input<T: Real>(g: &[T], w: &[T], (n, t, cin, k, cout): (usize, usize, usize, usize, usize), s: usize, winograd: bool) -> Vec<T> {
    let to = conv_out_len(t, s);
    let mut dx = vec![T::zero(); n * t * cin];
    if dx.is_empty() || to == 0 {
        return dx;
    }
    let phases: Vec<InputPhase<T>> = (0..s.min(t)).map(|r| InputPhase::new(w, (t, cin, k, cout), s, to, r)).filter(|p| p.taps > 0).collect();
    if winograd && k == 3 && s == 1 {
        // Stride 1, K = 3: dx[i] = Σ_j g[i + j]·W[2 − j]ᵀ is a kernel-3 correlation too, over
        // the rows whose taps all fall before T_out, in tasks of rows of several sequences.
        let wt = winograd_taps(&phases[0].w, cout * cin);
        winograd_conv_rows(&mut dx, g, (n, t, to), (cin, cout), 0..phases[0].full, 0, &wt, None);
    } else {
        // Full rows, by sequence and block of input rows (a multiple of s, so phases align).
        let block = BLOCK.div_ceil(s) * s;
        dx.par_chunks_mut(t * cin).enumerate().for_each(|(seq, dx_seq)| {
            let g_seq = &g[seq * to * cout..(seq + 1) * to * cout];
            dx_seq.par_chunks_mut(block * cin).enumerate().for_each(|(blk, dx_blk)| {
                let i0 = blk * block;
                let i1 = i0 + dx_blk.len() / cin;
                for p in &phases {
                    let m_lo = i0 / s;
                    let m_hi = i1.saturating_sub(p.r).div_ceil(s).min(p.full);
                    if m_lo >= m_hi {
                        continue;
                    }
                    // SAFETY: gradient rows m_lo + j0 ..< m_hi + j0 + taps − 1 ≤ T_out; destination rows
                    // s·m + r − i0 < i1 − i0, row stride s·C_in; p.w is [taps·C_out, C_in].
                    unsafe {
                        gemm_into(
                            m_hi - m_lo,
                            cin,
                            p.taps * cout,
                            dx_blk.as_mut_ptr().add((s * m_lo + p.r - i0) * cin),
                            s * cin,
                            1,
                            g_seq.as_ptr().add((m_lo + p.j0) * cout),
                            cout,
                            1,
                            p.w.as_ptr(),
                            cin,
                            1,
                            true,
                        );
                    }
                }
            });
        });
    }
    // The tail rows of every phase (their last taps fall past T_out), gathered from all
    // sequences with zero rows for the missing outputs: one gemm per phase.
    for p in &phases {
        let tail = p.rows - p.full;
        if tail == 0 {
            continue;
        }
        let width = p.taps * cout;
        let mut lhs = vec![T::zero(); n * tail * width];
        for (row, dst) in lhs.chunks_exact_mut(width).enumerate() {
            let (seq, m) = (row / tail, p.full + row % tail);
            let first = m + p.j0;
            let avail = to.saturating_sub(first).min(p.taps);
            if avail == 0 {
                continue;
            }
            dst[..avail * cout].copy_from_slice(&g[(seq * to + first) * cout..(seq * to + first + avail) * cout]);
        }
        let tail_dx = par_matmul(&lhs, &p.w, n * tail, width, cin);
        for (row, src) in tail_dx.chunks_exact(cin).enumerate() {
            let (seq, m) = (row / tail, p.full + row % tail);
            let i = s * m + p.r;
            dx[(seq * t + i) * cin..(seq * t + i + 1) * cin].copy_from_slice(src);
        }
    }
    dx
}

/// dW and db of [`causal_conv1d`]: args (x `[N, T, C_in]`, g `[N, To, C_out]`) → flat
/// `[K·C_in·C_out + C_out]` (dW then db).
struct ConvBwdParams {
    stride: usize,
    k: usize,
    winograd: bool,
}

impl CustomOp2 for ConvBwdParams {
    fn name(&self) -> &'static str {
        "causal-conv1d-bwd-params"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> CResult<(CpuStorage, Shape)> {
        let _timer = super::profile::Timer::start(self.name());
        let (n, t, cin) = l1.shape().dims3()?;
        let (n2, to, cout) = l2.shape().dims3()?;
        if n != n2 || to != conv_out_len(t, self.stride) {
            candle_core::bail!("causal-conv1d-bwd-params: bad shapes");
        }
        let (s, k) = (self.stride, self.k);
        let out = cpu_kernel(self, "causal-conv1d-bwd-params", [(s1, l1), (s2, l2)], ((n, t, cin, k, cout), s, self.winograd))?;
        Ok((out, Shape::from(k * cin * cout + cout)))
    }
}

impl CpuKernel<2> for ConvBwdParams {
    type Dims = ((usize, usize, usize, usize, usize), usize, bool);

    fn run<T: Real>(&self, [x, g]: [&[T]; 2], (d, s, wino): Self::Dims) -> Vec<T> {
        conv_bwd_params(x, g, d, s, wino)
    }
}

fn conv_bwd_params<T: Real>(x: &[T], g: &[T], dims: (usize, usize, usize, usize, usize), s: usize, winograd: bool) -> Vec<T> {
    let (n, t, cin, k, cout) = dims;
    let to = conv_out_len(t, s);
    let blocks = ceil_div(to, BLOCK);
    let wlen = k * cin * cout;
    let full = first_full_row(k, s, to);
    // Winograd: the full rows' sums are the products P_i = Σ_tiles U_iᵀ·V_i (U = Bᵀd of the
    // input, V = A·dy of the gradient), dW_k = Σ_i G[i][k]·P_i afterwards. The edge rows of
    // all sequences are one more gemm at the end, either way.
    let wino = winograd && k == 3 && s == 1;
    let acc_len = if wino { kernels::WINO_ALPHA * cin * cout } else { wlen };
    // Fewer partial sums for fewer rows: each group's products stay long (a short inner size
    // makes every gemm call stream the whole accumulator), and the partials to zero and add
    // up are fewer at the deep levels, where the accumulators are largest.
    let groups = (n * to).div_ceil(ROWS_PER_REDUCE_GROUP).clamp(2, REDUCE_GROUPS);
    let sums = det_par_sum(n * blocks, groups, acc_len + cout, |tasks, acc: &mut [T]| {
        let (mut pending, mut pending_tiles) = (Vec::new(), 0);
        for task in tasks {
            let (seq, blk) = (task / blocks, task % blocks);
            let (o0, o1) = (blk * BLOCK, ((blk + 1) * BLOCK).min(to));
            let x_seq = &x[seq * t * cin..(seq + 1) * t * cin];
            let g_seq = &g[seq * to * cout..(seq + 1) * to * cout];
            let lo = o0.max(full);
            if wino {
                if lo < o1 {
                    pending.push((x_seq, g_seq, lo, o1));
                    pending_tiles += (o1 - lo).div_ceil(kernels::WINO_M);
                    if pending_tiles >= WINO_GROUP_TILES {
                        winograd_weight_sums(&mut pending, acc, (t, cin, cout));
                        pending_tiles = 0;
                    }
                }
            } else {
                // Full rows: dW as [K·C_in, C_out] += Xᵀ·G, X's row o being the K·C_in input values
                // x[o·s − (K−1) .. o·s + 1].
                if lo < o1 {
                    // SAFETY: input frames lo·s − (K−1) ..= (o1 − 1)·s lie in [0, t).
                    unsafe {
                        gemm_into(
                            k * cin,
                            cout,
                            o1 - lo,
                            acc.as_mut_ptr(),
                            cout,
                            1,
                            x_seq.as_ptr().add((lo * s + 1 - k) * cin),
                            1,
                            s * cin,
                            g_seq.as_ptr().add(lo * cout),
                            cout,
                            1,
                            true,
                        );
                    }
                }
            }
            let db = &mut acc[acc_len..];
            for row in g_seq[o0 * cout..o1 * cout].chunks_exact(cout) {
                for (d, &v) in db.iter_mut().zip(row) {
                    *d += v;
                }
            }
        }
        winograd_weight_sums(&mut pending, acc, (t, cin, cout));
    });
    let mut out = if wino {
        let len = cin * cout;
        let mut out = vec![T::zero(); wlen + cout];
        out[wlen..].copy_from_slice(&sums[acc_len..]);
        out[..wlen].par_chunks_mut(len).enumerate().for_each(|(kk, dst)| {
            for (e, d) in dst.iter_mut().enumerate() {
                *d = T::from_f64((0..kernels::WINO_ALPHA).map(|i| kernels::WINO_G[i][kk] * sums[i * len + e].to_f64()).sum());
            }
        });
        out
    } else {
        sums
    };
    let dw = &mut out[..wlen];
    // The edge rows of all sequences: dW += Eᵀ·G_edge over their zero-padded im2col rows.
    if full > 0 {
        let edge = edge_rows(x, dims, s, full);
        let mut g_edge = Vec::with_capacity(n * full * cout);
        for seq in 0..n {
            g_edge.extend_from_slice(&g[seq * to * cout..(seq * to + full) * cout]);
        }
        // SAFETY: edge is [N·full, K·C_in] read transposed, g_edge [N·full, C_out], dw [K·C_in, C_out].
        unsafe { gemm_into(k * cin, cout, n * full, dw.as_mut_ptr(), cout, 1, edge.as_ptr(), 1, k * cin, g_edge.as_ptr(), cout, 1, true) };
    }
    out
}

/// [`causal_conv1d`] of the channel concatenation `[a, b]` (`[N, T, C_a + C_b]`, the U-Net's
/// skip connections) without keeping it, then [`causal_upsample2x`] when `upsample` (the
/// decoder's), without keeping the conv's output either: the concatenation is built for the
/// product and dropped, and rebuilt for the weight gradient, so the graph
/// holds `a` and `b` (kept anyway) and the result. The weights travel packed with the bias as one operand.
///
/// # Shapes
/// - `a`: `[N, T, C_a]`, `b`: `[N, T, C_b]`
/// - `w`: `[K, C_a + C_b, C_out]`, `bias`: `[C_out]`
/// - returns `[N, ⌈T/s⌉, C_out]`, or `[N, 2⌈T/s⌉, C_out]` with `upsample`
pub fn causal_conv1d_cat(a: &Tensor, b: &Tensor, w: &Tensor, bias: &Tensor, stride: usize, upsample: bool, k3: K3Conv) -> CResult<Tensor> {
    let ((n, t, ca), (n2, t2, cb)) = (a.dims3()?, b.dims3()?);
    let (k, cin, cout) = w.dims3()?;
    if stride == 0 || k == 0 || n != n2 || t != t2 || ca + cb != cin || bias.dims1()? != cout {
        candle_core::bail!("causal_conv1d_cat: a {:?}, b {:?}, weight {:?}, bias {:?}, stride {stride} do not fit", a.dims(), b.dims(), w.dims(), bias.dims());
    }
    let packed = Tensor::cat(&[&w.reshape((k * cin, cout))?, &bias.reshape((1, cout))?], 0)?;
    a.contiguous()?.apply_op3(&b.contiguous()?, &packed, CatConv { stride, k, upsample, winograd: k3 == K3Conv::Winograd })
}

/// [`causal_conv1d_cat`]: args (a, b, W and bias packed `[K·C_in + 1, C_out]`).
struct CatConv {
    stride: usize,
    k: usize,
    upsample: bool,
    winograd: bool,
}

/// The rows of `a` (`[rows, C_a]`) and `b` (`[rows, C_b]`) side by side, `[rows, C_a + C_b]`.
fn concat_channels<T: Real>(a: &[T], b: &[T], rows: usize, ca: usize, cb: usize) -> Vec<T> {
    let c = ca + cb;
    let mut out = vec![T::zero(); rows * c];
    out.par_chunks_mut(BLOCK * c).enumerate().for_each(|(blk, dst)| {
        for (r, row) in dst.chunks_exact_mut(c).enumerate() {
            let i = blk * BLOCK + r;
            row[..ca].copy_from_slice(&a[i * ca..(i + 1) * ca]);
            row[ca..].copy_from_slice(&b[i * cb..(i + 1) * cb]);
        }
    });
    out
}

impl CustomOp3 for CatConv {
    fn name(&self) -> &'static str {
        // timed with the plain convs: the same kernels
        "causal-conv1d"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout, s3: &CpuStorage, l3: &Layout) -> CResult<(CpuStorage, Shape)> {
        let _timer = super::profile::Timer::start(self.name());
        let ((n, t, ca), (_, _, cb), (_, cout)) = (l1.shape().dims3()?, l2.shape().dims3()?, l3.shape().dims2()?);
        let s = self.stride;
        let out = cpu_kernel(self, "causal-conv1d", [(s1, l1), (s2, l2), (s3, l3)], ((n, t, ca + cb, self.k, cout), ca, s, self.winograd))?;
        let to = conv_out_len(t, s);
        if self.upsample {
            let up = cpu_kernel(&Upsample2x, "causal-upsample2x", [(&out, &Layout::contiguous((n, to, cout)))], (to, cout))?;
            return Ok((up, Shape::from((n, 2 * to, cout))));
        }
        Ok((out, Shape::from((n, to, cout))))
    }

    fn bwd(&self, a: &Tensor, b: &Tensor, packed: &Tensor, _res: &Tensor, g: &Tensor) -> CResult<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let ((_, t, ca), (_, _, cb), (_, cout)) = (a.dims3()?, b.dims3()?, packed.dims2()?);
        let (k, cin, winograd) = (self.k, ca + cb, self.winograd);
        let g = if self.upsample { g.contiguous()?.apply_op1_no_bwd(&Upsample2xBwd)? } else { g.contiguous()? };
        let (da, db) = if a.track_op() || b.track_op() {
            let w = packed.narrow(0, 0, k * cin)?.reshape((k, cin, cout))?;
            let dx = g.apply_op2_no_bwd(&w, &ConvBwdInput { stride: self.stride, t, winograd })?;
            (Some(dx.narrow(2, 0, ca)?), Some(dx.narrow(2, ca, cb)?))
        } else {
            (None, None)
        };
        let dpacked = if packed.track_op() {
            // the concatenation again, for this product only; dW then db is the packed layout
            let x = Tensor::cat(&[&a.detach(), &b.detach()], 2)?;
            let flat = x.apply_op2_no_bwd(&g, &ConvBwdParams { stride: self.stride, k, winograd })?;
            Some(flat.reshape((k * cin + 1, cout))?)
        } else {
            None
        };
        Ok((da, db, dpacked))
    }
}

impl CpuKernel<3> for CatConv {
    type Dims = ((usize, usize, usize, usize, usize), usize, usize, bool);

    fn run<T: Real>(&self, [a, b, packed]: [&[T]; 3], (d, ca, s, wino): Self::Dims) -> Vec<T> {
        let (n, t, cin, k, _) = d;
        let x = concat_channels(a, b, n * t, ca, cin - ca);
        let (w, bias) = packed.split_at(k * cin * d.4);
        conv_fwd(&x, w, bias, d, s, wino)
    }
}

// ---------------------------------------------------------------------------------------------
// LayerNorm over the last (channel) dim
// ---------------------------------------------------------------------------------------------

/// LayerNorm over the last dim: `(x − μ)/√(σ² + ε)·γ + β`, μ and σ² (population variance) per
/// row.
///
/// # Shapes
/// - `x`: `[…, C]`; `gamma`, `beta`: `[C]`; returns the shape of `x`.
pub fn layer_norm(x: &Tensor, gamma: &Tensor, beta: &Tensor, eps: f64) -> CResult<Tensor> {
    x.contiguous()?.apply_op3(&gamma.contiguous()?, &beta.contiguous()?, LayerNormOp { eps, silu: false })
}

/// [`layer_norm`] of [`silu`]`(x)` as one op: the SiLU output is never stored (the backward
/// recomputes it per row), which saves the residual block a pass over its activation in each
/// direction and an autograd node (a zero-filled gradient and an add in candle's backward). Bit
/// for bit the two ops in sequence.
///
/// # Shapes
/// - `x`: `[…, C]`; `gamma`, `beta`: `[C]`; returns the shape of `x`.
pub fn silu_layer_norm(x: &Tensor, gamma: &Tensor, beta: &Tensor, eps: f64) -> CResult<Tensor> {
    x.contiguous()?.apply_op3(&gamma.contiguous()?, &beta.contiguous()?, LayerNormOp { eps, silu: true })
}

/// LayerNorm, of `silu(x)` instead of `x` with `silu`.
struct LayerNormOp {
    eps: f64,
    silu: bool,
}

fn ln_dims(x: &Shape, gamma: &Shape, beta: &Shape) -> CResult<(usize, usize)> {
    let c = x.dims().last().copied().unwrap_or(0);
    if c == 0 || gamma.dims1()? != c || beta.dims1()? != c {
        candle_core::bail!("layer_norm: x {x:?}, gamma {gamma:?}, beta {beta:?} do not fit");
    }
    Ok((x.elem_count() / c, c))
}

/// Mean and 1/√(var + ε) of one row (two passes, for accuracy; 16 interleaved partial sums,
/// the forward-only network's order).
#[inline(always)]
fn row_stats<T: Real>(row: &[T], eps: T) -> (T, T) {
    let inv_c = T::one() / T::from_f64(row.len() as f64);
    let mean = kernels::sum16(row) * inv_c;
    let var = kernels::sum_sq_dev16(row, mean) * inv_c;
    (mean, T::one() / (var + eps).sqrt_())
}

impl CustomOp3 for LayerNormOp {
    fn name(&self) -> &'static str {
        if self.silu {
            "silu-layer-norm"
        } else {
            "layer-norm"
        }
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout, s3: &CpuStorage, l3: &Layout) -> CResult<(CpuStorage, Shape)> {
        let _timer = super::profile::Timer::start(self.name());
        let (_, c) = ln_dims(l1.shape(), l2.shape(), l3.shape())?;
        let out = cpu_kernel(self, self.name(), [(s1, l1), (s2, l2), (s3, l3)], (c, self.eps))?;
        Ok((out, l1.shape().clone()))
    }

    fn bwd(&self, x: &Tensor, gamma: &Tensor, beta: &Tensor, _res: &Tensor, g: &Tensor) -> CResult<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let c = gamma.dims1()?;
        let m = x.elem_count() / c;
        let flat = x.apply_op3_no_bwd(gamma, &g.contiguous()?, &LayerNormBwd { eps: self.eps, silu: self.silu })?;
        let dx = flat.narrow(0, 0, m * c)?.reshape(x.shape())?;
        let dgamma = flat.narrow(0, m * c, c)?;
        let dbeta = flat.narrow(0, m * c + c, c)?;
        let _ = beta;
        Ok((Some(dx), Some(dgamma), Some(dbeta)))
    }
}

impl CpuKernel<3> for LayerNormOp {
    type Dims = (usize, f64);

    fn run<T: Real>(&self, [x, gamma, beta]: [&[T]; 3], (c, eps): Self::Dims) -> Vec<T> {
        let eps = T::from_f64(eps);
        let mut y = vec![T::zero(); x.len()];
        y.par_chunks_mut(BLOCK * c).zip(x.par_chunks(BLOCK * c)).for_each(|(yb, xb)| layer_norm_rows(yb, xb, c, gamma, beta, eps, self.silu));
        y
    }
}

kernels::simd_kernel! {
    /// LayerNorm of the rows of `x` (of `silu(x)` with `silu`) into `y`, both `[rows, c]`.
    fn layer_norm_rows<T: Real>(y: &mut [T], x: &[T], c: usize, gamma: &[T], beta: &[T], eps: T, silu: bool) {
        for (yr, xr) in y.chunks_exact_mut(c).zip(x.chunks_exact(c)) {
            if silu {
                for (y, &x) in yr.iter_mut().zip(xr) {
                    *y = x * sigmoid(x);
                }
            } else {
                yr.copy_from_slice(xr);
            }
            let (mean, rstd) = row_stats(yr, eps);
            for ((y, &g), &b) in yr.iter_mut().zip(gamma).zip(beta) {
                *y = (*y - mean) * rstd * g + b;
            }
        }
    }
}

/// Backward of [`layer_norm`] (and of [`silu_layer_norm`] with `silu`): args (x, γ, g) → flat
/// `[M·C + C + C]` (dx, dγ, dβ).
///
/// With s the normalized input (x, or silu(x)), ŝ = (s − μ)·r and d = g·γ:
/// `ds = r·(d − mean(d) − ŝ·mean(d·ŝ))`, `dγ = Σ g·ŝ`, `dβ = Σ g` (sums over rows), and
/// `dx = ds·σ(x)(1 + x(1 − σ(x)))` after a SiLU. One pass: each fixed group of rows writes its
/// dx and its partial parameter sums, which are added in group order ([`det_par_sum`]'s
/// split).
struct LayerNormBwd {
    eps: f64,
    silu: bool,
}

impl CustomOp3 for LayerNormBwd {
    fn name(&self) -> &'static str {
        if self.silu {
            "silu-layer-norm-bwd"
        } else {
            "layer-norm-bwd"
        }
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout, s3: &CpuStorage, l3: &Layout) -> CResult<(CpuStorage, Shape)> {
        let _timer = super::profile::Timer::start(self.name());
        let (m, c) = ln_dims(l1.shape(), l2.shape(), l2.shape())?;
        if l3.shape() != l1.shape() {
            candle_core::bail!("{}: gradient shape differs from input", self.name());
        }
        let out = cpu_kernel(self, self.name(), [(s1, l1), (s2, l2), (s3, l3)], (m, c, self.eps))?;
        Ok((out, Shape::from(m * c + 2 * c)))
    }
}

impl CpuKernel<3> for LayerNormBwd {
    type Dims = (usize, usize, f64);

    fn run<T: Real>(&self, [x, gamma, g]: [&[T]; 3], (m, c, eps): Self::Dims) -> Vec<T> {
        let eps = T::from_f64(eps);
        let silu = self.silu;
        let mut out = vec![T::zero(); m * c + 2 * c];
        let (dx, params) = out.split_at_mut(m * c);
        let group = reduce_group_len(ceil_div(m, BLOCK), REDUCE_GROUPS) * BLOCK * c;
        let parts: Vec<Vec<T>> = dx
            .par_chunks_mut(group)
            .zip(x.par_chunks(group))
            .zip(g.par_chunks(group))
            .map(|((dg, xg), gg)| {
                let mut acc = vec![T::zero(); 2 * c];
                let mut row = vec![T::zero(); if silu { 2 * c } else { 0 }];
                layer_norm_bwd_rows(dg, xg, gg, c, gamma, eps, silu, &mut acc, &mut row);
                acc
            })
            .collect();
        params.copy_from_slice(&sum_in_order(parts, 2 * c));
        out
    }
}

kernels::simd_kernel! {
    /// [`LayerNormBwd`] on the rows of one group: writes `dx`, adds the rows' `[dγ | dβ]` terms
    /// to `acc` in row order; `row` is scratch of `2c` values with `silu` (SiLU and sigmoid).
    fn layer_norm_bwd_rows<T: Real>(dx: &mut [T], x: &[T], g: &[T], c: usize, gamma: &[T], eps: T, silu: bool, acc: &mut [T], row: &mut [T]) {
        let cf = T::from_f64(c as f64);
        let (s, sg) = row.split_at_mut(row.len() / 2);
        let (dgamma, dbeta) = acc.split_at_mut(c);
        for ((dr, xr), gr) in dx.chunks_exact_mut(c).zip(x.chunks_exact(c)).zip(g.chunks_exact(c)) {
            let sr: &[T] = if silu {
                for ((s, sg), &x) in s.iter_mut().zip(sg.iter_mut()).zip(xr) {
                    *sg = sigmoid(x);
                    *s = x * *sg;
                }
                s
            } else {
                xr
            };
            let (mean, rstd) = row_stats(sr, eps);
            let (mut sd, mut sdx) = (T::zero(), T::zero());
            for ((&s, &g), &gm) in sr.iter().zip(gr).zip(gamma) {
                let d = g * gm;
                sd += d;
                sdx += d * ((s - mean) * rstd);
            }
            let (md, mdx) = (sd / cf, sdx / cf);
            for (j, d) in dr.iter_mut().enumerate() {
                let xh = (sr[j] - mean) * rstd;
                *d = rstd * (gr[j] * gamma[j] - md - xh * mdx);
                dgamma[j] += gr[j] * xh;
                dbeta[j] += gr[j];
            }
            if silu {
                for ((d, &sg), &x) in dr.iter_mut().zip(sg.iter()).zip(xr) {
                    *d = *d * sg * (T::one() + x * (T::one() - sg));
                }
            }
        }
    }
}

/// [`causal_conv1d`] of [`silu_layer_norm`]`(h)` (the residual block's second conv and the
/// normalization before it) without keeping the normalized activation: the forward drops it
/// after the product, the backward recomputes it (one elementwise pass) for the weight
/// gradient. The same kernels in the same order as the two ops in sequence, so bit for bit
/// their values and gradients, with one activation fewer held for the backward.
///
/// # Shapes
/// - `h`: `[N, T, C_in]`; `gamma`, `beta`: `[C_in]`; `w`: `[K, C_in, C_out]`; `b`: `[C_out]`
/// - returns `[N, ⌈T/s⌉, C_out]`
#[allow(clippy::too_many_arguments)]
pub fn silu_layer_norm_conv1d(h: &Tensor, gamma: &Tensor, beta: &Tensor, eps: f64, w: &Tensor, b: &Tensor, stride: usize, k3: K3Conv) -> CResult<Tensor> {
    let (_, _, cin) = h.dims3()?;
    let (k, cin2, cout) = w.dims3()?;
    if stride == 0 || k == 0 || cin != cin2 || gamma.dims1()? != cin || beta.dims1()? != cin || b.dims1()? != cout {
        candle_core::bail!(
            "silu_layer_norm_conv1d: h {:?}, gamma {:?}, beta {:?}, weight {:?}, bias {:?}, stride {stride} do not fit",
            h.dims(),
            gamma.dims(),
            beta.dims(),
            w.dims(),
            b.dims()
        );
    }
    // γ, β and the bias as one small operand (a custom op takes three)
    let small = Tensor::cat(&[gamma, beta, b], 0)?;
    h.contiguous()?.apply_op3(&w.contiguous()?, &small, NormConv { eps, stride, winograd: k3 == K3Conv::Winograd })
}

/// [`silu_layer_norm_conv1d`]: args (h, W, `[γ | β | bias]`).
struct NormConv {
    eps: f64,
    stride: usize,
    winograd: bool,
}

impl CustomOp3 for NormConv {
    fn name(&self) -> &'static str {
        "causal-conv1d"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout, s3: &CpuStorage, l3: &Layout) -> CResult<(CpuStorage, Shape)> {
        let (n, t, cin) = l1.shape().dims3()?;
        let (k, _, cout) = l2.shape().dims3()?;
        let s = self.stride;
        let out = cpu_kernel(self, "causal-conv1d", [(s1, l1), (s2, l2), (s3, l3)], ((n, t, cin, k, cout), s, self.winograd))?;
        Ok((out, Shape::from((n, conv_out_len(t, s), cout))))
    }

    fn bwd(&self, h: &Tensor, w: &Tensor, small: &Tensor, _res: &Tensor, g: &Tensor) -> CResult<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let (_, t, cin) = h.dims3()?;
        let (k, _, cout) = w.dims3()?;
        let (gamma, beta) = (small.narrow(0, 0, cin)?, small.narrow(0, cin, cin)?);
        let g = g.contiguous()?;
        let normed = h.apply_op3_no_bwd(&gamma, &beta, &LayerNormOp { eps: self.eps, silu: true })?;
        let (dw, db) = {
            let flat = normed.apply_op2_no_bwd(&g, &ConvBwdParams { stride: self.stride, k, winograd: self.winograd })?;
            (flat.narrow(0, 0, k * cin * cout)?.reshape((k, cin, cout))?, flat.narrow(0, k * cin * cout, cout)?)
        };
        drop(normed);
        let dnormed = g.apply_op2_no_bwd(w, &ConvBwdInput { stride: self.stride, t, winograd: self.winograd })?;
        let m = h.elem_count() / cin;
        let flat = h.apply_op3_no_bwd(&gamma, &dnormed, &LayerNormBwd { eps: self.eps, silu: true })?;
        let dh = flat.narrow(0, 0, m * cin)?.reshape(h.shape())?;
        let dsmall = Tensor::cat(&[&flat.narrow(0, m * cin, 2 * cin)?, &db], 0)?;
        Ok((Some(dh), Some(dw), Some(dsmall)))
    }
}

impl CpuKernel<3> for NormConv {
    type Dims = ((usize, usize, usize, usize, usize), usize, bool);

    fn run<T: Real>(&self, [h, w, small]: [&[T]; 3], (d, s, wino): Self::Dims) -> Vec<T> {
        let cin = d.2;
        let (gamma, rest) = small.split_at(cin);
        let (beta, bias) = rest.split_at(cin);
        let normed = {
            let _timer = super::profile::Timer::start("silu-layer-norm");
            LayerNormOp { eps: self.eps, silu: true }.run([h, gamma, beta], (cin, self.eps))
        };
        let _timer = super::profile::Timer::start("causal-conv1d");
        conv_fwd(&normed, w, bias, d, s, wino)
    }
}

// ---------------------------------------------------------------------------------------------
// FiLM + residual
// ---------------------------------------------------------------------------------------------

/// FiLM and the residual add in one pass: `h·(1 + a) + b + skip` with `[a | b] = film` per
/// group of rows. Fused because candle's broadcast product and its backward (a broadcast, a
/// product and a sum over the broadcast rows) each walk the whole activation again.
///
/// # Shapes
/// - `h`, `skip`: `[…, C]`, their `G·M` rows of C in G groups of M consecutive rows that share
///   one FiLM row (e.g. `[G, M, C]`, or `[N, T, C]` with one group per scene of `N·T/G` rows,
///   so the network needs no reshape nodes around it); `film`: `[G, 2C]`; returns h's shape.
pub fn film_residual(h: &Tensor, film: &Tensor, skip: &Tensor) -> CResult<Tensor> {
    h.contiguous()?.apply_op3(&film.contiguous()?, &skip.contiguous()?, FilmResidual)
}

struct FilmResidual;

/// (G, M, C) of h `[…, C]` (G·M rows) and film `[G, 2C]`.
fn film_dims(h: &Shape, film: &Shape, op: &str) -> CResult<(usize, usize, usize)> {
    let c = h.dims().last().copied().unwrap_or(0);
    let rows = h.elem_count().checked_div(c).unwrap_or(0);
    match film.dims() {
        &[g, two_c] if two_c == 2 * c && g > 0 && rows % g == 0 => Ok((g, rows / g, c)),
        d => candle_core::bail!("{op}: film has shape {d:?}, expected [G, {}] with G dividing the {rows} rows of h {:?}", 2 * c, h.dims()),
    }
}

impl CustomOp3 for FilmResidual {
    fn name(&self) -> &'static str {
        "film-residual"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout, s3: &CpuStorage, l3: &Layout) -> CResult<(CpuStorage, Shape)> {
        let _timer = super::profile::Timer::start(self.name());
        let (_, m, c) = film_dims(l1.shape(), l2.shape(), "film-residual")?;
        if l3.shape() != l1.shape() {
            candle_core::bail!("film-residual: skip has shape {:?}, h {:?}", l3.shape().dims(), l1.shape().dims());
        }
        let out = cpu_kernel(self, "film-residual", [(s1, l1), (s2, l2), (s3, l3)], ((m, c),))?;
        Ok((out, l1.shape().clone()))
    }

    fn bwd(&self, h: &Tensor, film: &Tensor, skip: &Tensor, _res: &Tensor, g: &Tensor) -> CResult<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let g = g.contiguous()?;
        let dh = if h.track_op() { Some(g.apply_op2_no_bwd(film, &FilmBwdInput)?) } else { None };
        let dfilm = if film.track_op() { Some(h.apply_op2_no_bwd(&g, &FilmBwdFilm { groups: film.dim(0)? })?) } else { None };
        let dskip = if skip.track_op() { Some(g) } else { None };
        Ok((dh, dfilm, dskip))
    }
}

impl CpuKernel<3> for FilmResidual {
    type Dims = ((usize, usize),);

    fn run<T: Real>(&self, [h, film, skip]: [&[T]; 3], ((m, c),): Self::Dims) -> Vec<T> {
        let mut y = vec![T::zero(); h.len()];
        y.par_chunks_mut(m * c).zip(h.par_chunks(m * c)).zip(skip.par_chunks(m * c)).zip(film.par_chunks(2 * c)).for_each(|(((yg, hg), sg), f)| {
            let (a, b) = f.split_at(c);
            for ((yr, hr), sr) in yg.chunks_exact_mut(c).zip(hg.chunks_exact(c)).zip(sg.chunks_exact(c)) {
                for i in 0..c {
                    // The unfused order: (h · (a + 1) + b) + skip.
                    yr[i] = hr[i] * (a[i] + T::one()) + b[i] + sr[i];
                }
            }
        });
        y
    }
}

/// Backward of [`film_residual`] for `h`: args (g `[G, M, C]`, film `[G, 2C]`) → `g·(1 + a)`.
struct FilmBwdInput;

impl CustomOp2 for FilmBwdInput {
    fn name(&self) -> &'static str {
        "film-residual-bwd-input"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> CResult<(CpuStorage, Shape)> {
        let _timer = super::profile::Timer::start(self.name());
        let (_, m, c) = film_dims(l1.shape(), l2.shape(), "film-residual-bwd-input")?;
        Ok((cpu_kernel(self, "film-residual-bwd-input", [(s1, l1), (s2, l2)], ((m, c),))?, l1.shape().clone()))
    }
}

impl CpuKernel<2> for FilmBwdInput {
    type Dims = ((usize, usize),);

    fn run<T: Real>(&self, [g, film]: [&[T]; 2], ((m, c),): Self::Dims) -> Vec<T> {
        let mut d = vec![T::zero(); g.len()];
        d.par_chunks_mut(m * c).zip(g.par_chunks(m * c)).zip(film.par_chunks(2 * c)).for_each(|((dg, gg), f)| {
            for (dr, gr) in dg.chunks_exact_mut(c).zip(gg.chunks_exact(c)) {
                for i in 0..c {
                    dr[i] = gr[i] * (f[i] + T::one());
                }
            }
        });
        d
    }
}

/// Backward of [`film_residual`] for `film`: args (h, g, both G groups of M rows of C) →
/// `[Σ_m g·h | Σ_m g]`, `[G, 2C]`.
struct FilmBwdFilm {
    groups: usize,
}

impl CustomOp2 for FilmBwdFilm {
    fn name(&self) -> &'static str {
        "film-residual-bwd-film"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> CResult<(CpuStorage, Shape)> {
        let _timer = super::profile::Timer::start(self.name());
        let (g, m, c) = film_dims(l1.shape(), &Shape::from((self.groups, 2 * l1.shape().dims().last().copied().unwrap_or(0))), self.name())?;
        if l2.shape() != l1.shape() {
            candle_core::bail!("film-residual-bwd-film: gradient shape differs from h");
        }
        Ok((cpu_kernel(self, "film-residual-bwd-film", [(s1, l1), (s2, l2)], ((m, c),))?, Shape::from((g, 2 * c))))
    }
}

impl CpuKernel<2> for FilmBwdFilm {
    type Dims = ((usize, usize),);

    fn run<T: Real>(&self, [h, g]: [&[T]; 2], ((m, c),): Self::Dims) -> Vec<T> {
        let groups = h.len() / (m * c).max(1);
        let mut d = vec![T::zero(); groups * 2 * c];
        d.par_chunks_mut(2 * c).zip(h.par_chunks(m * c)).zip(g.par_chunks(m * c)).for_each(|((dg, hg), gg)| {
            let (da, db) = dg.split_at_mut(c);
            for (hr, gr) in hg.chunks_exact(c).zip(gg.chunks_exact(c)) {
                for i in 0..c {
                    da[i] += gr[i] * hr[i];
                    db[i] += gr[i];
                }
            }
        });
        d
    }
}

// ---------------------------------------------------------------------------------------------
// SiLU
// ---------------------------------------------------------------------------------------------

/// SiLU (swish): `x·σ(x)`, elementwise.
///
/// # Shapes
/// - `x`: any; returns the same shape.
pub fn silu(x: &Tensor) -> CResult<Tensor> {
    x.contiguous()?.apply_op1(SiluOp)
}

struct SiluOp;

#[inline(always)]
fn sigmoid<T: Real>(x: T) -> T {
    T::one() / (T::one() + (T::zero() - x).exp_())
}

impl CustomOp1 for SiluOp {
    fn name(&self) -> &'static str {
        "silu"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> CResult<(CpuStorage, Shape)> {
        let _timer = super::profile::Timer::start(self.name());
        Ok((cpu_kernel(self, "silu", [(s, l)], ())?, l.shape().clone()))
    }

    fn bwd(&self, x: &Tensor, _res: &Tensor, g: &Tensor) -> CResult<Option<Tensor>> {
        Ok(Some(x.apply_op2_no_bwd(&g.contiguous()?, &SiluBwd)?))
    }
}

impl CpuKernel<1> for SiluOp {
    type Dims = ();

    fn run<T: Real>(&self, [x]: [&[T]; 1], (): Self::Dims) -> Vec<T> {
        let mut y = vec![T::zero(); x.len()];
        y.par_chunks_mut(1 << 14).zip(x.par_chunks(1 << 14)).for_each(|(yb, xb)| {
            for (y, &x) in yb.iter_mut().zip(xb) {
                *y = x * sigmoid(x);
            }
        });
        y
    }
}

/// Backward of [`silu`]: args (x, g) → `g·σ(x)(1 + x(1 − σ(x)))`.
struct SiluBwd;

impl CustomOp2 for SiluBwd {
    fn name(&self) -> &'static str {
        "silu-bwd"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> CResult<(CpuStorage, Shape)> {
        let _timer = super::profile::Timer::start(self.name());
        if l1.shape() != l2.shape() {
            candle_core::bail!("silu-bwd: gradient shape differs from input");
        }
        Ok((cpu_kernel(self, "silu-bwd", [(s1, l1), (s2, l2)], ())?, l1.shape().clone()))
    }
}

impl CpuKernel<2> for SiluBwd {
    type Dims = ();

    fn run<T: Real>(&self, [x, g]: [&[T]; 2], (): Self::Dims) -> Vec<T> {
        let mut d = vec![T::zero(); x.len()];
        d.par_chunks_mut(1 << 14).zip(x.par_chunks(1 << 14)).zip(g.par_chunks(1 << 14)).for_each(|((db, xb), gb)| {
            for ((d, &x), &g) in db.iter_mut().zip(xb).zip(gb) {
                let sg = sigmoid(x);
                *d = g * sg * (T::one() + x * (T::one() - sg));
            }
        });
        d
    }
}

// ---------------------------------------------------------------------------------------------
// Causal ×2 linear upsampling
// ---------------------------------------------------------------------------------------------

/// Causal ×2 linear upsampling along frames.
///
/// Coarse sample `o` of a causal stride-2 encoder has seen fine frames `≤ 2o`. Placing it at
/// fine position `2o + 1` and interpolating linearly between neighbours gives
/// `y[2o] = ½(x[o−1] + x[o])` and `y[2o+1] = x[o]` (with `x[−1] := x[0]`): fine frame `t` only
/// uses coarse samples `≤ ⌊t/2⌋`, which have seen fine frames `≤ t`. (PyTorch's
/// `align_corners=False` upsampling instead reads `x[o+1]` for `y[2o+1]`: one sample ahead.)
///
/// # Shapes
/// - `x`: `[N, L, C]`; returns `[N, 2L, C]`.
pub fn causal_upsample2x(x: &Tensor) -> CResult<Tensor> {
    x.contiguous()?.apply_op1(Upsample2x)
}

struct Upsample2x;

impl CustomOp1 for Upsample2x {
    fn name(&self) -> &'static str {
        "causal-upsample2x"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> CResult<(CpuStorage, Shape)> {
        let _timer = super::profile::Timer::start(self.name());
        let (n, len, c) = l.shape().dims3()?;
        Ok((cpu_kernel(self, "causal-upsample2x", [(s, l)], (len, c))?, Shape::from((n, 2 * len, c))))
    }

    fn bwd(&self, _x: &Tensor, _res: &Tensor, g: &Tensor) -> CResult<Option<Tensor>> {
        Ok(Some(g.contiguous()?.apply_op1_no_bwd(&Upsample2xBwd)?))
    }
}

impl CpuKernel<1> for Upsample2x {
    type Dims = (usize, usize);

    fn run<T: Real>(&self, [x]: [&[T]; 1], (len, c): Self::Dims) -> Vec<T> {
        let mut y = vec![T::zero(); 2 * x.len()];
        if y.is_empty() {
            return y;
        }
        let half = T::from_f64(0.5);
        y.par_chunks_mut(2 * len * c).zip(x.par_chunks(len * c)).for_each(|(ys, xs)| {
            for o in 0..len {
                let prev = &xs[o.saturating_sub(1) * c..(o.saturating_sub(1) + 1) * c];
                let cur = &xs[o * c..(o + 1) * c];
                let (even, odd) = ys[2 * o * c..(2 * o + 2) * c].split_at_mut(c);
                for j in 0..c {
                    even[j] = half * (prev[j] + cur[j]);
                    odd[j] = cur[j];
                }
            }
        });
        y
    }
}

/// Backward of [`causal_upsample2x`]: `[N, 2L, C]` → `[N, L, C]`,
/// `dx[o] = g[2o+1] + ½g[2o] + ½g[2o+2]` (the last term only for `o + 1 < L`; `dx[0]` also gets
/// `½g[0]` from `x[−1] := x[0]`).
struct Upsample2xBwd;

impl CustomOp1 for Upsample2xBwd {
    fn name(&self) -> &'static str {
        "causal-upsample2x-bwd"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> CResult<(CpuStorage, Shape)> {
        let _timer = super::profile::Timer::start(self.name());
        let (n, len2, c) = l.shape().dims3()?;
        if len2 % 2 != 0 {
            candle_core::bail!("causal-upsample2x-bwd: odd gradient length {len2}");
        }
        let len = len2 / 2;
        Ok((cpu_kernel(self, "causal-upsample2x-bwd", [(s, l)], (len, c))?, Shape::from((n, len, c))))
    }
}

impl CpuKernel<1> for Upsample2xBwd {
    type Dims = (usize, usize);

    fn run<T: Real>(&self, [g]: [&[T]; 1], (len, c): Self::Dims) -> Vec<T> {
        let mut dx = vec![T::zero(); g.len() / 2];
        if dx.is_empty() {
            return dx;
        }
        let half = T::from_f64(0.5);
        dx.par_chunks_mut(len * c).zip(g.par_chunks(2 * len * c)).for_each(|(ds, gs)| {
            for o in 0..len {
                let p = o.saturating_sub(1);
                for j in 0..c {
                    let ge = half * gs[2 * o * c + j];
                    ds[o * c + j] += gs[(2 * o + 1) * c + j] + ge;
                    ds[p * c + j] += ge;
                }
            }
        });
        dx
    }
}

// ---------------------------------------------------------------------------------------------
// Small batched matmul
// ---------------------------------------------------------------------------------------------

/// Batched matrix product `C[g] = op_a(A[g])·op_b(B[g])` with `op` = transpose when `ta`/`tb`
/// is set; all leading dims are batch dims. Plain loops: meant for the small matrices of
/// attention across persons, not for big products.
///
/// # Shapes
/// - `a`: `[…, m, k]` (`[…, k, m]` if `ta`), `b`: `[…, k, n]` (`[…, n, k]` if `tb`), same
///   leading dims; returns `[…, m, n]`.
pub fn bmm(a: &Tensor, b: &Tensor, ta: bool, tb: bool) -> CResult<Tensor> {
    a.contiguous()?.apply_op2(&b.contiguous()?, Bmm { ta, tb })
}

#[derive(Clone, Copy)]
struct Bmm {
    ta: bool,
    tb: bool,
}

/// (batch, m, k, n) of a [`Bmm`] and the output shape.
fn bmm_dims(op: Bmm, a: &Shape, b: &Shape) -> CResult<(usize, usize, usize, usize, Shape)> {
    let (ad, bd) = (a.dims(), b.dims());
    if ad.len() < 2 || ad.len() != bd.len() || ad[..ad.len() - 2] != bd[..bd.len() - 2] {
        candle_core::bail!("bmm: shapes {a:?} and {b:?} do not fit");
    }
    let r = ad.len();
    let (m, k) = if op.ta { (ad[r - 1], ad[r - 2]) } else { (ad[r - 2], ad[r - 1]) };
    let (k2, n) = if op.tb { (bd[r - 1], bd[r - 2]) } else { (bd[r - 2], bd[r - 1]) };
    if k != k2 {
        candle_core::bail!("bmm: inner dims differ ({a:?}, {b:?}, ta {}, tb {})", op.ta, op.tb);
    }
    let batch = ad[..r - 2].iter().product();
    let mut out = ad[..r - 2].to_vec();
    out.extend([m, n]);
    Ok((batch, m, k, n, Shape::from(out)))
}

impl CustomOp2 for Bmm {
    fn name(&self) -> &'static str {
        "bmm"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> CResult<(CpuStorage, Shape)> {
        let _timer = super::profile::Timer::start(self.name());
        let (batch, m, k, n, shape) = bmm_dims(*self, l1.shape(), l2.shape())?;
        let out = cpu_kernel(self, "bmm", [(s1, l1), (s2, l2)], ((batch, m, k, n), *self))?;
        Ok((out, shape))
    }

    fn bwd(&self, a: &Tensor, b: &Tensor, _res: &Tensor, g: &Tensor) -> CResult<(Option<Tensor>, Option<Tensor>)> {
        let g = g.contiguous()?;
        let op = |ta, tb| Bmm { ta, tb };
        // C = op(A)·op(B); see the table in the module doc of candle's matmul backward.
        let (da, db) = match (self.ta, self.tb) {
            (false, false) => (g.apply_op2_no_bwd(b, &op(false, true))?, a.apply_op2_no_bwd(&g, &op(true, false))?),
            (false, true) => (g.apply_op2_no_bwd(b, &op(false, false))?, g.apply_op2_no_bwd(a, &op(true, false))?),
            (true, false) => (b.apply_op2_no_bwd(&g, &op(false, true))?, a.apply_op2_no_bwd(&g, &op(false, false))?),
            (true, true) => (b.apply_op2_no_bwd(&g, &op(true, true))?, g.apply_op2_no_bwd(a, &op(true, true))?),
        };
        Ok((Some(da), Some(db)))
    }
}

impl CpuKernel<2> for Bmm {
    type Dims = ((usize, usize, usize, usize), Bmm);

    fn run<T: Real>(&self, [a, b]: [&[T]; 2], (d, op): Self::Dims) -> Vec<T> {
        let (batch, m, k, n) = d;
        // element (i, p) of op(A) and (p, j) of op(B)
        let (a_rs, a_cs) = if op.ta { (1, m) } else { (k, 1) };
        let (b_rs, b_cs) = if op.tb { (1, k) } else { (n, 1) };
        let mut c = vec![T::zero(); batch * m * n];
        if c.is_empty() {
            return c;
        }
        let per = ceil_div(4096, (m * n).max(1)).max(1);
        c.par_chunks_mut(per * m * n).enumerate().for_each(|(chunk, cs)| {
            for (gi, cg) in cs.chunks_exact_mut(m * n).enumerate() {
                let g = chunk * per + gi;
                let (ag, bg) = (&a[g * m * k..(g + 1) * m * k], &b[g * k * n..(g + 1) * k * n]);
                for i in 0..m {
                    for p in 0..k {
                        let av = ag[i * a_rs + p * a_cs];
                        let row = &mut cg[i * n..(i + 1) * n];
                        for (j, cv) in row.iter_mut().enumerate() {
                            *cv += av * bg[p * b_rs + j * b_cs];
                        }
                    }
                }
            }
        });
        c
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use candle_core::{Device, Var};
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    pub(crate) fn rand_t(rng: &mut StdRng, shape: &[usize]) -> Tensor {
        let n: usize = shape.iter().product();
        let v: Vec<f64> = (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect();
        Tensor::from_vec(v, shape, &Device::Cpu).unwrap()
    }

    /// Max relative error between the analytic gradient of `Σ f(inputs)·r` (r random) with
    /// respect to every input and central finite differences at a sample of entries.
    pub(crate) fn grad_check(shapes: &[&[usize]], f: impl Fn(&[Tensor]) -> CResult<Tensor>) -> f64 {
        let mut rng = StdRng::seed_from_u64(7);
        let vars: Vec<Var> = shapes.iter().map(|s| Var::from_tensor(&rand_t(&mut rng, s)).unwrap()).collect();
        let inputs: Vec<Tensor> = vars.iter().map(|v| v.as_tensor().clone()).collect();
        let out = f(&inputs).unwrap();
        let r = rand_t(&mut rng, out.dims());
        let loss = |ins: &[Tensor]| -> f64 { (f(ins).unwrap() * &r).unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap() };
        let grads = (out * &r).unwrap().sum_all().unwrap().backward().unwrap();
        let mut worst = 0.0f64;
        for (vi, v) in vars.iter().enumerate() {
            let g: Vec<f64> = grads.get(v).expect("no gradient").flatten_all().unwrap().to_vec1().unwrap();
            let base: Vec<f64> = v.as_tensor().flatten_all().unwrap().to_vec1().unwrap();
            let (mut num_v, mut ana_v) = (vec![], vec![]);
            for idx in (0..base.len()).step_by((base.len() / 40).max(1)) {
                let h = 1e-6;
                let at = |delta: f64| {
                    let mut p = base.clone();
                    p[idx] += delta;
                    let mut ins: Vec<Tensor> = inputs.iter().map(|t| t.detach()).collect();
                    ins[vi] = Tensor::from_vec(p, v.shape(), &Device::Cpu).unwrap();
                    loss(&ins)
                };
                num_v.push((at(h) - at(-h)) / (2.0 * h));
                ana_v.push(g[idx]);
            }
            let scale = ana_v.iter().map(|x| x.abs()).fold(1e-12, f64::max);
            for (a, n) in ana_v.iter().zip(&num_v) {
                worst = worst.max((a - n).abs() / scale);
            }
        }
        worst
    }

    #[test]
    fn conv_stride1_gradient_matches_finite_differences() {
        for t in [1, 5, 130, 300] {
            let err = grad_check(&[&[2, t, 3], &[3, 3, 4], &[4]], |x| causal_conv1d(&x[0], &x[1], &x[2], 1));
            eprintln!("conv stride 1, T={t}: relative error {err:.2e}");
            assert!(err < 1e-6, "T={t}: relative error {err}");
        }
        let err = grad_check(&[&[2, 7, 3], &[1, 3, 5], &[5]], |x| causal_conv1d(&x[0], &x[1], &x[2], 1));
        eprintln!("conv 1x1: relative error {err:.2e}");
        assert!(err < 1e-6, "1x1: relative error {err}");
    }

    #[test]
    fn conv_stride2_gradient_matches_finite_differences() {
        for t in [1, 2, 7, 8, 259, 300] {
            let err = grad_check(&[&[2, t, 3], &[3, 3, 4], &[4]], |x| causal_conv1d(&x[0], &x[1], &x[2], 2));
            eprintln!("conv stride 2, T={t}: relative error {err:.2e}");
            assert!(err < 1e-6, "T={t}: relative error {err}");
        }
    }

    /// Both conv gradients against direct loops, at sizes that cross the 128-frame blocks, the
    /// 32-wide transpose tiles, odd Winograd tiles and the weight gradient's tile groups (the
    /// finite-difference checks use 3 × 4 channels).
    #[test]
    fn conv_gradients_match_direct_loops_across_blocks_and_tiles() {
        let mut rng = StdRng::seed_from_u64(11);
        let cases = [
            (150, 1, 3, 33, 70),
            (133, 1, 3, 5, 7),
            (3, 1, 3, 2, 3),
            (4, 1, 3, 3, 2),
            (4200, 1, 3, 3, 4),
            (150, 2, 3, 40, 35),
            (131, 1, 1, 65, 34),
            (2, 1, 3, 5, 6),
            (1, 2, 3, 4, 5),
            (9, 2, 3, 3, 4),
            (260, 2, 3, 6, 7),
            (11, 3, 2, 3, 4),
            (17, 3, 5, 4, 3),
            (4, 2, 1, 3, 2),
        ];
        for (t, s, k, cin, cout) in cases {
            let n = 2;
            let to = conv_out_len(t, s);
            let rand = |rng: &mut StdRng, len: usize| -> Vec<f64> { (0..len).map(|_| rng.gen_range(-1.0..1.0)).collect() };
            let (x, w, g) = (rand(&mut rng, n * t * cin), rand(&mut rng, k * cin * cout), rand(&mut rng, n * to * cout));
            let kks: Vec<usize> = (0..k).rev().collect();
            let flip = transposed_taps(&w, &kks, cin, cout);
            for j in 0..k {
                for ci in 0..cin {
                    for c in 0..cout {
                        assert_eq!(flip[(j * cout + c) * cin + ci], w[((k - 1 - j) * cin + ci) * cout + c]);
                    }
                }
            }
            let mut dx_ref = vec![0.0; n * t * cin];
            let mut dp_ref = vec![0.0; k * cin * cout + cout];
            for seq in 0..n {
                for o in 0..to {
                    for co in 0..cout {
                        let gv = g[(seq * to + o) * cout + co];
                        dp_ref[k * cin * cout + co] += gv;
                        for kk in 0..k {
                            let Some(i) = (o * s + kk).checked_sub(k - 1) else { continue };
                            for ci in 0..cin {
                                dx_ref[(seq * t + i) * cin + ci] += gv * w[(kk * cin + ci) * cout + co];
                                dp_ref[(kk * cin + ci) * cout + co] += gv * x[(seq * t + i) * cin + ci];
                            }
                        }
                    }
                }
            }
            for winograd in [true, false] {
                let dx = conv_bwd_input(&g, &w, (n, t, cin, k, cout), s, winograd);
                let dp = conv_bwd_params(&x, &g, (n, t, cin, k, cout), s, winograd);
                for (got, want) in dx.iter().zip(&dx_ref).chain(dp.iter().zip(&dp_ref)) {
                    assert!((got - want).abs() < 1e-9, "t {t} s {s} k {k} winograd {winograd}: {got} vs {want}");
                }
            }
        }
    }

    /// The conv of two inputs' channels side by side (and upsampled) equals the conv of their
    /// concatenation (then upsampled), bit for bit in values and in every gradient, and passes
    /// a finite-difference check.
    #[test]
    fn conv_over_two_inputs_is_the_conv_of_their_concatenation() {
        let mut rng = StdRng::seed_from_u64(5);
        let cases = [
            (300, 1, 3, 5, 7, 6, false),
            (9, 2, 3, 4, 3, 5, false),
            (131, 1, 1, 6, 2, 3, false),
            (1, 1, 3, 2, 2, 2, false),
            (150, 1, 3, 4, 5, 3, true),
            (7, 2, 3, 3, 2, 4, true),
        ];
        for ((t, s, k, ca, cb, cout, up), k3) in cases.into_iter().flat_map(|c| [K3Conv::Winograd, K3Conv::Direct].map(|k3| (c, k3))) {
            for dtype in [DType::F32, DType::F64] {
                let v = |rng: &mut StdRng, shape: &[usize]| Var::from_tensor(&rand_t(rng, shape).to_dtype(dtype).unwrap()).unwrap();
                let (a, b, w, bias) = (v(&mut rng, &[3, t, ca]), v(&mut rng, &[3, t, cb]), v(&mut rng, &[k, ca + cb, cout]), v(&mut rng, &[cout]));
                let r = rand_t(&mut rng, &[3, conv_out_len(t, s) << usize::from(up), cout]).to_dtype(dtype).unwrap();
                let split = causal_conv1d_cat(&a, &b, &w, &bias, s, up, k3).unwrap();
                let joined = causal_conv1d_with(&Tensor::cat(&[a.as_tensor(), b.as_tensor()], 2).unwrap(), &w, &bias, s, k3).unwrap();
                let joined = if up { causal_upsample2x(&joined).unwrap() } else { joined };
                let flat = |x: &Tensor| x.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
                assert_eq!(flat(&split), flat(&joined), "t {t} s {s} k {k} {k3:?} {dtype:?}: values");
                let gs = (split * &r).unwrap().sum_all().unwrap().backward().unwrap();
                let gj = (joined * &r).unwrap().sum_all().unwrap().backward().unwrap();
                for (name, x) in [("a", &a), ("b", &b), ("w", &w), ("bias", &bias)] {
                    assert_eq!(flat(gs.get(x).unwrap()), flat(gj.get(x).unwrap()), "t {t} s {s} k {k} {k3:?} {dtype:?}: gradient of {name}");
                }
            }
        }
        for up in [false, true] {
            let err = grad_check(&[&[2, 130, 2], &[2, 130, 3], &[3, 5, 4], &[4]], |x| causal_conv1d_cat(&x[0], &x[1], &x[2], &x[3], 1, up, K3Conv::Winograd));
            assert!(err < 1e-6, "upsample {up}: relative error {err}");
        }
        let bad = causal_conv1d_cat(
            &rand_t(&mut rng, &[2, 5, 2]),
            &rand_t(&mut rng, &[2, 4, 3]),
            &rand_t(&mut rng, &[3, 5, 4]),
            &rand_t(&mut rng, &[4]),
            1,
            false,
            K3Conv::Winograd,
        );
        assert!(bad.unwrap_err().to_string().contains("do not fit"));
    }

    /// The conv of a SiLU-LayerNorm equals the two ops in sequence bit for bit, in values and
    /// in every gradient, and passes a finite-difference check.
    #[test]
    fn conv_of_silu_layer_norm_is_the_two_ops_in_sequence() {
        let mut rng = StdRng::seed_from_u64(6);
        let cases = [(300, 1, 3, 6, 5), (9, 2, 3, 4, 3), (17, 1, 1, 5, 2), (1, 1, 3, 3, 3)];
        for ((t, s, k, cin, cout), k3) in cases.into_iter().flat_map(|c| [K3Conv::Winograd, K3Conv::Direct].map(|k3| (c, k3))) {
            for dtype in [DType::F32, DType::F64] {
                let v = |rng: &mut StdRng, shape: &[usize]| Var::from_tensor(&(rand_t(rng, shape) * 3.0).unwrap().to_dtype(dtype).unwrap()).unwrap();
                let (h, gamma, beta, w, b) =
                    (v(&mut rng, &[2, t, cin]), v(&mut rng, &[cin]), v(&mut rng, &[cin]), v(&mut rng, &[k, cin, cout]), v(&mut rng, &[cout]));
                let r = rand_t(&mut rng, &[2, conv_out_len(t, s), cout]).to_dtype(dtype).unwrap();
                let fused = silu_layer_norm_conv1d(&h, &gamma, &beta, 1e-5, &w, &b, s, k3).unwrap();
                let apart = causal_conv1d_with(&silu_layer_norm(&h, &gamma, &beta, 1e-5).unwrap(), &w, &b, s, k3).unwrap();
                let flat = |x: &Tensor| x.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
                assert_eq!(flat(&fused), flat(&apart), "t {t} s {s} k {k} {k3:?} {dtype:?}: values");
                let gf = (fused * &r).unwrap().sum_all().unwrap().backward().unwrap();
                let ga = (apart * &r).unwrap().sum_all().unwrap().backward().unwrap();
                for (name, x) in [("h", &h), ("gamma", &gamma), ("beta", &beta), ("w", &w), ("b", &b)] {
                    assert_eq!(flat(gf.get(x).unwrap()), flat(ga.get(x).unwrap()), "t {t} s {s} k {k} {k3:?} {dtype:?}: gradient of {name}");
                }
            }
        }
        let err =
            grad_check(&[&[2, 130, 4], &[4], &[4], &[3, 4, 3], &[3]], |x| silu_layer_norm_conv1d(&x[0], &x[1], &x[2], 1e-5, &x[3], &x[4], 1, K3Conv::Winograd));
        assert!(err < 1e-6, "relative error {err}");
        let bad = silu_layer_norm_conv1d(
            &rand_t(&mut rng, &[2, 5, 4]),
            &rand_t(&mut rng, &[3]),
            &rand_t(&mut rng, &[4]),
            1e-5,
            &rand_t(&mut rng, &[3, 4, 2]),
            &rand_t(&mut rng, &[2]),
            1,
            K3Conv::Winograd,
        );
        assert!(bad.unwrap_err().to_string().contains("do not fit"));
    }

    /// The conv against a direct triple loop, including causality: output o reads inputs ≤ o·s.
    #[test]
    fn conv_matches_direct_loop() {
        let mut rng = StdRng::seed_from_u64(3);
        for (t, s, k) in [(9, 1, 3), (9, 2, 3), (10, 2, 3), (260, 2, 3), (5, 1, 1), (17, 3, 5), (1, 2, 3), (2, 1, 3), (300, 1, 3)] {
            let (n, cin, cout) = (2, 3, 4);
            let (x, w, b) = (rand_t(&mut rng, &[n, t, cin]), rand_t(&mut rng, &[k, cin, cout]), rand_t(&mut rng, &[cout]));
            for k3 in [K3Conv::Winograd, K3Conv::Direct] {
                let y: Vec<f64> = causal_conv1d_with(&x, &w, &b, s, k3).unwrap().flatten_all().unwrap().to_vec1().unwrap();
                let (xv, wv, bv): (Vec<f64>, Vec<f64>, Vec<f64>) =
                    (x.flatten_all().unwrap().to_vec1().unwrap(), w.flatten_all().unwrap().to_vec1().unwrap(), b.to_vec1().unwrap());
                let to = conv_out_len(t, s);
                for seq in 0..n {
                    for o in 0..to {
                        for co in 0..cout {
                            let mut acc = bv[co];
                            for kk in 0..k {
                                let i = (o * s + kk) as isize - (k as isize - 1);
                                if i < 0 {
                                    continue;
                                }
                                for ci in 0..cin {
                                    acc += xv[(seq * t + i as usize) * cin + ci] * wv[(kk * cin + ci) * cout + co];
                                }
                            }
                            let got = y[(seq * to + o) * cout + co];
                            assert!((got - acc).abs() < 1e-12, "t {t} s {s} o {o} {k3:?}: {got} vs {acc}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn layer_norm_gradient_matches_finite_differences() {
        let err = grad_check(&[&[3, 150, 6], &[6], &[6]], |x| layer_norm(&x[0], &x[1], &x[2], 1e-5));
        eprintln!("layer norm: relative error {err:.2e}");
        assert!(err < 1e-6, "relative error {err}");
        // forward: zero mean, unit variance rows with γ = 1, β = 0
        let mut rng = StdRng::seed_from_u64(1);
        let x = ((rand_t(&mut rng, &[4, 8]) * 3.0).unwrap() + 1.0).unwrap();
        let y = layer_norm(&x, &Tensor::ones(8, DType::F64, &Device::Cpu).unwrap(), &Tensor::zeros(8, DType::F64, &Device::Cpu).unwrap(), 0.0).unwrap();
        for row in y.to_vec2::<f64>().unwrap() {
            let mean = row.iter().sum::<f64>() / 8.0;
            let var = row.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / 8.0;
            assert!(mean.abs() < 1e-12 && (var - 1.0).abs() < 1e-12, "{mean} {var}");
        }
    }

    /// The fused op is the two ops in sequence, bit for bit in f32 (values and every
    /// gradient), over enough rows for several reduction groups, and its gradient checks out.
    #[test]
    fn silu_layer_norm_is_silu_then_layer_norm() {
        let err = grad_check(&[&[2, 700, 6], &[6], &[6]], |x| silu_layer_norm(&(&x[0] * 3.0)?, &x[1], &x[2], 1e-5));
        eprintln!("silu layer norm: relative error {err:.2e}");
        assert!(err < 1e-6, "relative error {err}");
        let mut rng = StdRng::seed_from_u64(5);
        let var = |shape: &[usize], rng: &mut StdRng| Var::from_tensor(&(rand_t(rng, shape) * 2.0).unwrap().to_dtype(DType::F32).unwrap()).unwrap();
        let (x, gamma, beta) = (var(&[3, 500, 20], &mut rng), var(&[20], &mut rng), var(&[20], &mut rng));
        let r = rand_t(&mut rng, &[3, 500, 20]).to_dtype(DType::F32).unwrap();
        let fused = silu_layer_norm(x.as_tensor(), gamma.as_tensor(), beta.as_tensor(), 1e-5).unwrap();
        let apart = layer_norm(&silu(x.as_tensor()).unwrap(), gamma.as_tensor(), beta.as_tensor(), 1e-5).unwrap();
        let bits = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&fused), bits(&apart));
        let (gf, ga) = ((&fused * &r).unwrap().sum_all().unwrap().backward().unwrap(), (&apart * &r).unwrap().sum_all().unwrap().backward().unwrap());
        for (name, v) in [("x", &x), ("gamma", &gamma), ("beta", &beta)] {
            assert_eq!(bits(gf.get(v).unwrap()), bits(ga.get(v).unwrap()), "gradient of {name}");
        }
    }

    #[test]
    fn film_residual_gradient_and_values() {
        for (g, m, c) in [(2, 5, 3), (6, 1, 4)] {
            let err = grad_check(&[&[g, m, c], &[g, 2 * c], &[g, m, c]], |x| film_residual(&x[0], &x[1], &x[2]));
            eprintln!("film-residual [{g}, {m}, {c}]: relative error {err:.2e}");
            assert!(err < 1e-6, "relative error {err}");
        }
        // Against the unfused candle expression, bit for bit in f32.
        let mut rng = StdRng::seed_from_u64(4);
        let f32t = |shape: &[usize], rng: &mut StdRng| rand_t(rng, shape).to_dtype(DType::F32).unwrap();
        let (h, film, skip) = (f32t(&[3, 4, 5], &mut rng), f32t(&[3, 10], &mut rng), f32t(&[3, 4, 5], &mut rng));
        let scale = (film.narrow(1, 0, 5).unwrap() + 1.0).unwrap().reshape((3, 1, 5)).unwrap();
        let shift = film.narrow(1, 5, 5).unwrap().reshape((3, 1, 5)).unwrap();
        let want = (h.broadcast_mul(&scale).unwrap().broadcast_add(&shift).unwrap() + &skip).unwrap();
        let got = film_residual(&h, &film, &skip).unwrap();
        assert_eq!(got.flatten_all().unwrap().to_vec1::<f32>().unwrap(), want.flatten_all().unwrap().to_vec1::<f32>().unwrap());
        assert!(film_residual(&h, &film.narrow(1, 0, 8).unwrap(), &skip).unwrap_err().to_string().contains("expected [G, 10]"));
        // Groups of rows across a leading dimension: h [3, 4, 5] as 6 groups of 2 rows, the
        // same as the [6, 2, 5] view.
        let film6 = f32t(&[6, 10], &mut rng);
        let grouped = film_residual(&h.reshape((6, 2, 5)).unwrap(), &film6, &skip.reshape((6, 2, 5)).unwrap()).unwrap();
        let flat = film_residual(&h, &film6, &skip).unwrap();
        assert_eq!(flat.dims(), &[3, 4, 5]);
        assert_eq!(flat.flatten_all().unwrap().to_vec1::<f32>().unwrap(), grouped.flatten_all().unwrap().to_vec1::<f32>().unwrap());
        assert!(film_residual(&h, &f32t(&[5, 10], &mut rng), &skip).unwrap_err().to_string().contains("G dividing the 12 rows"));
    }

    #[test]
    fn silu_gradient_matches_finite_differences() {
        let err = grad_check(&[&[5, 7]], |x| silu(&(&x[0] * 4.0)?));
        eprintln!("silu: relative error {err:.2e}");
        assert!(err < 1e-6, "relative error {err}");
        let y = silu(&Tensor::new(&[0.0f64, 1.0, -2.0], &Device::Cpu).unwrap()).unwrap().to_vec1::<f64>().unwrap();
        let want = [0.0, 1.0 / (1.0 + (-1.0f64).exp()), -2.0 / (1.0 + 2.0f64.exp())];
        for (a, b) in y.iter().zip(want) {
            assert!((a - b).abs() < 1e-15);
        }
    }

    #[test]
    fn upsample_gradient_and_values() {
        for len in [1, 2, 5] {
            let err = grad_check(&[&[2, len, 3]], |x| causal_upsample2x(&x[0]));
            eprintln!("upsample L={len}: relative error {err:.2e}");
            assert!(err < 1e-6, "L={len}: relative error {err}");
        }
        let x = Tensor::new(&[1.0f64, 3.0, 7.0], &Device::Cpu).unwrap().reshape((1, 3, 1)).unwrap();
        let y = causal_upsample2x(&x).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
        assert_eq!(y, vec![1.0, 1.0, 2.0, 3.0, 5.0, 7.0]);
    }

    #[test]
    fn bmm_gradient_and_values() {
        for (ta, tb) in [(false, false), (false, true), (true, false), (true, true)] {
            let sa: &[usize] = if ta { &[2, 3, 4, 5] } else { &[2, 3, 5, 4] };
            let sb: &[usize] = if tb { &[2, 3, 6, 4] } else { &[2, 3, 4, 6] };
            let err = grad_check(&[sa, sb], |x| bmm(&x[0], &x[1], ta, tb));
            eprintln!("bmm ta {ta} tb {tb}: relative error {err:.2e}");
            assert!(err < 1e-6, "ta {ta} tb {tb}: relative error {err}");
            let mut rng = StdRng::seed_from_u64(9);
            let (a, b) = (rand_t(&mut rng, sa), rand_t(&mut rng, sb));
            let (a2, b2) = (if ta { a.transpose(2, 3).unwrap() } else { a.clone() }, if tb { b.transpose(2, 3).unwrap() } else { b.clone() });
            let want = a2.contiguous().unwrap().matmul(&b2.contiguous().unwrap()).unwrap();
            let got = bmm(&a, &b, ta, tb).unwrap();
            let d = (got - want).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f64>().unwrap();
            assert!(d < 1e-12, "{d}");
        }
    }

    #[test]
    fn ops_accept_f32_and_reject_ints() {
        let x = Tensor::ones((2, 5, 3), DType::F32, &Device::Cpu).unwrap();
        let w = Tensor::ones((3, 3, 2), DType::F32, &Device::Cpu).unwrap();
        let b = Tensor::zeros(2, DType::F32, &Device::Cpu).unwrap();
        let y = causal_conv1d(&x, &w, &b, 1).unwrap().to_vec3::<f32>().unwrap();
        assert_eq!(y[0].iter().map(|r| r[0]).collect::<Vec<_>>(), vec![3.0, 6.0, 9.0, 9.0, 9.0]);
        assert!(silu(&Tensor::ones(3, DType::U32, &Device::Cpu).unwrap()).is_err());
    }
}
