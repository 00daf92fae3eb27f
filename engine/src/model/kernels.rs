//! f32 kernels of the forward-only denoiser ([`super::infer`]): a row-block gemm, the fused
//! elementwise epilogues that follow a convolution, and a vectorizable `exp`.
//!
//! The crate is built for generic x86-64 (SSE2), so each elementwise kernel is compiled three
//! times — AVX-512, AVX2+FMA and baseline — and picked at run time ([`simd_kernel!`]); `gemm`
//! does the same for its micro-kernels. All kernels work on rows of channels-last activations
//! (`[rows, C]`, row stride given) and are deterministic: no reduction depends on the thread
//! count or on how many rows a call gets.

use gemm::Parallelism;

/// Defines `pub(crate) fn $name(args)` that runs `$body` compiled for the best instruction set
/// of the machine (AVX-512F, AVX2+FMA, or the baseline). The body must be safe code; it may be
/// generic over one float type (`fn name<T: Real>(…)`), each instance multiversioned.
macro_rules! simd_kernel {
    ($(#[$meta:meta])* fn $name:ident $(<$g:ident: $bound:path>)? ($($arg:ident: $ty:ty),* $(,)?) $body:block) => {
        $(#[$meta])*
        #[allow(clippy::too_many_arguments)]
        pub(crate) fn $name $(<$g: $bound>)? ($($arg: $ty),*) {
            #[inline(always)]
            #[allow(clippy::too_many_arguments)]
            fn body $(<$g: $bound>)? ($($arg: $ty),*) $body
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
                #[allow(clippy::too_many_arguments)]
                unsafe fn v4 $(<$g: $bound>)? ($($arg: $ty),*) { body($($arg),*) }
                #[target_feature(enable = "avx2,fma")]
                #[allow(clippy::too_many_arguments)]
                unsafe fn v3 $(<$g: $bound>)? ($($arg: $ty),*) { body($($arg),*) }
                match $crate::model::kernels::simd_level() {
                    // SAFETY: the CPU supports the enabled features (checked at run time).
                    4 => return unsafe { v4($($arg),*) },
                    3 => return unsafe { v3($($arg),*) },
                    _ => {}
                }
            }
            body($($arg),*)
        }
    };
}
pub(crate) use simd_kernel;

/// 4: AVX-512F, 3: AVX2 + FMA, 0: baseline (checked once).
#[cfg(target_arch = "x86_64")]
pub(crate) fn simd_level() -> u8 {
    use std::sync::OnceLock;
    static LEVEL: OnceLock<u8> = OnceLock::new();
    *LEVEL.get_or_init(|| {
        if is_x86_feature_detected!("avx512f") && is_x86_feature_detected!("avx512vl") && is_x86_feature_detected!("fma") {
            4
        } else if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
            3
        } else {
            0
        }
    })
}

/// `dst = lhs·rhs` (or `dst += lhs·rhs` with `accumulate`), single-threaded (callers
/// parallelize over row blocks).
///
/// `lhs` is `m × k` with unit column stride and row stride `lhs_rs` (rows may overlap: a causal
/// conv reads `K` consecutive frames as one row of length `K·C_in`); `rhs` is `k × n`
/// row-major; `dst` is `m × n` with row stride `dst_rs`.
///
/// # Safety
/// The pointers must address valid memory for these sizes and strides, and `dst` must not
/// overlap `lhs` or `rhs`.
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn gemm_rows(m: usize, n: usize, k: usize, dst: *mut f32, dst_rs: usize, lhs: *const f32, lhs_rs: usize, rhs: *const f32, accumulate: bool) {
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        if !accumulate {
            for r in 0..m {
                std::ptr::write_bytes(dst.add(r * dst_rs), 0, n);
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
        1,
        dst_rs as isize,
        accumulate,
        lhs,
        1,
        lhs_rs as isize,
        rhs,
        1,
        n as isize,
        1.0f32,
        1.0f32,
        false,
        false,
        false,
        Parallelism::None,
    )
}

/// e^x for f32, written so that the compiler vectorizes it (no branches, no calls): Cephes'
/// `expf` range reduction and polynomial, relative error ≈ 2e-7; the input is clamped to
/// [−87, 88] (results are then ≈ 1.6e-38 and 1.7e38 instead of 0 and ∞).
#[inline(always)]
pub(crate) fn exp(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const C1: f32 = 0.693_359_4;
    const C2: f32 = -2.121_944_4e-4;
    // adding and subtracting 1.5·2²³ rounds to the nearest integer (|x·log2 e| < 2²²)
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 88.0);
    let shifted = x * LOG2E + ROUND;
    let n = shifted - ROUND;
    // the integer n sits in the low mantissa bits of `shifted` (an `as i32` conversion would
    // saturate and not vectorize)
    let n_int = (shifted.to_bits() as i32).wrapping_sub(ROUND.to_bits() as i32);
    let r = x - n * C1 - n * C2;
    let mut p = 1.987_569_1e-4f32;
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 5e-1; // 0.50000001 in the fit; the same f32
    let e = p * r * r + r + 1.0;
    let scale = f32::from_bits((n_int.wrapping_add(127) as u32) << 23);
    e * scale
}

/// SiLU, `x·σ(x)`, with [`exp`].
#[inline(always)]
pub(crate) fn silu(x: f32) -> f32 {
    x / (1.0 + exp(-x))
}

/// The arithmetic the row reductions need (f32 and f64).
pub(crate) trait SumFloat: Copy + Default + std::ops::AddAssign + std::ops::Sub<Output = Self> + std::ops::Mul<Output = Self> + std::iter::Sum {}

impl<T: Copy + Default + std::ops::AddAssign + std::ops::Sub<Output = T> + std::ops::Mul<Output = T> + std::iter::Sum> SumFloat for T {}

/// Σ row in 16 interleaved partial sums (vectorizable, fixed order).
#[inline(always)]
pub(crate) fn sum16<T: SumFloat>(row: &[T]) -> T {
    let mut acc = [T::default(); 16];
    let mut chunks = row.chunks_exact(16);
    for ch in &mut chunks {
        for (a, &v) in acc.iter_mut().zip(ch) {
            *a += v;
        }
    }
    let mut s = chunks.remainder().iter().copied().sum::<T>();
    for a in acc {
        s += a;
    }
    s
}

/// Σ (row − mean)² in 16 interleaved partial sums.
#[inline(always)]
pub(crate) fn sum_sq_dev16<T: SumFloat>(row: &[T], mean: T) -> T {
    let mut acc = [T::default(); 16];
    let mut chunks = row.chunks_exact(16);
    for ch in &mut chunks {
        for (a, &v) in acc.iter_mut().zip(ch) {
            *a += (v - mean) * (v - mean);
        }
    }
    let mut s = chunks.remainder().iter().map(|&v| (v - mean) * (v - mean)).sum::<T>();
    for a in acc {
        s += a;
    }
    s
}

simd_kernel! {
    /// Per row of `rows` (`[m, c]`, contiguous rows): `v = SiLU(x + bias)`, then LayerNorm over
    /// the row, `(v − μ)/√(σ² + ε)·γ + β` (two-pass mean and variance).
    fn silu_layer_norm_rows(rows: &mut [f32], c: usize, bias: &[f32], gamma: &[f32], beta: &[f32], eps: f32) {
        let inv_c = 1.0 / c as f32;
        for row in rows.chunks_exact_mut(c) {
            for (v, &b) in row.iter_mut().zip(bias) {
                *v = silu(*v + b);
            }
            let mean = sum16(row) * inv_c;
            let rstd = 1.0 / (sum_sq_dev16(row, mean) * inv_c + eps).sqrt();
            for ((v, &g), &b) in row.iter_mut().zip(gamma).zip(beta) {
                *v = (*v - mean) * rstd * g + b;
            }
        }
    }
}

simd_kernel! {
    /// Per row of `rows` (`[m, c]`): `row += bias`.
    fn add_bias_rows(rows: &mut [f32], c: usize, bias: &[f32]) {
        for row in rows.chunks_exact_mut(c) {
            for (v, &b) in row.iter_mut().zip(bias) {
                *v += b;
            }
        }
    }
}

simd_kernel! {
    /// FiLM and residual per row: `row = row·scale + shift (+ skip row)`; `skip` has the
    /// layout of `rows` when given.
    fn film_rows(rows: &mut [f32], c: usize, scale: &[f32], shift: &[f32], skip: Option<&[f32]>) {
        match skip {
            Some(skip) => {
                for (row, s) in rows.chunks_exact_mut(c).zip(skip.chunks_exact(c)) {
                    for (((v, &a), &b), &x) in row.iter_mut().zip(scale).zip(shift).zip(s) {
                        *v = *v * a + b + x;
                    }
                }
            }
            None => {
                for row in rows.chunks_exact_mut(c) {
                    for ((v, &a), &b) in row.iter_mut().zip(scale).zip(shift) {
                        *v = *v * a + b;
                    }
                }
            }
        }
    }
}

simd_kernel! {
    /// One sender's term of the mean aggregator, per row: `acc_row += SiLU(e_row + r)`
    /// (`acc`, `e`: `[m, c]`; `r`: `[c]`).
    fn add_silu_rows(acc: &mut [f32], e: &[f32], r: &[f32], c: usize) {
        for (a_row, e_row) in acc.chunks_exact_mut(c).zip(e.chunks_exact(c)) {
            for ((a, &x), &y) in a_row.iter_mut().zip(e_row).zip(r) {
                *a += silu(x + y);
            }
        }
    }
}

simd_kernel! {
    /// Causal ×2 linear upsampling of frames `q0..q1` of the fine output (one sequence):
    /// `y[2o] = ½(x[o−1] + x[o])`, `y[2o+1] = x[o]`, `x[−1] := x[0]`. `x` is the whole coarse
    /// sequence `[L, c]`, `y` the output rows `[q1 − q0, c]`.
    fn upsample2x_rows(y: &mut [f32], x: &[f32], c: usize, q0: usize) {
        for (i, out) in y.chunks_exact_mut(c).enumerate() {
            let q = q0 + i;
            let o = q / 2;
            let cur = &x[o * c..(o + 1) * c];
            if q % 2 == 1 {
                out.copy_from_slice(cur);
            } else {
                let p = o.saturating_sub(1);
                let prev = &x[p * c..(p + 1) * c];
                for ((v, &a), &b) in out.iter_mut().zip(prev).zip(cur) {
                    *v = 0.5 * (a + b);
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Winograd F(2, 3): two outputs of a kernel-3 correlation from four inputs with four products
// instead of six (Lavin & Gray 2016). For channel vectors the products become four gemms of
// [tiles, C_in]·[C_in, C_out]: two thirds of the multiply-adds of the direct k3 conv.
//
//   y_r = Σ_k d_{r+k}·g_k (r < 2)  =  Aᵀ[(Bᵀ d) ⊙ (G g)]
//   Bᵀ d = (d0 − d2, d1 + d2, d2 − d1, d1 − d3),  G g = (g0, ½(g0 + g1 + g2), ½(g0 − g1 + g2), g2)
//   y0 = m0 + m1 + m2,  y1 = m1 − m2 − m3
//
// Unlike the larger F(4, 3), each output only involves products of its own three inputs (y0
// never sees d3), so the conv stays exactly causal in floating point.
// ---------------------------------------------------------------------------------------------

/// Outputs per Winograd tile.
pub(crate) const WINO_M: usize = 2;
/// Inputs (and products) per Winograd tile.
pub(crate) const WINO_ALPHA: usize = 4;

/// G of F(2, 3): the four transformed taps `G_i = Σ_k G[i][k]·g_k`.
pub(crate) const WINO_G: [[f64; 3]; WINO_ALPHA] = [[1.0, 0.0, 0.0], [0.5, 0.5, 0.5], [0.5, -0.5, 0.5], [0.0, 0.0, 1.0]];

/// Input transform `u_i = (Bᵀ d)_i` of `tiles` tiles, for any float type. Tile j reads frames
/// `2j … 2j + 3` of `x` (`[rows, c]`, rows ≥ 2·tiles + 1; frames ≥ rows are zero); `u` holds
/// four planes `[tiles, c]`, `plane` (≥ tiles·c) values apart.
#[inline(always)]
pub(crate) fn winograd_input_any<T: Copy + std::ops::Add<Output = T> + std::ops::Sub<Output = T>>(u: &mut [T], x: &[T], c: usize, tiles: usize, plane: usize) {
    let rows = x.len() / c;
    let (u0, rest) = u.split_at_mut(plane);
    let (u1, rest) = rest.split_at_mut(plane);
    let (u2, u3) = rest.split_at_mut(plane);
    for j in 0..tiles {
        let t = j * c..(j + 1) * c;
        let (d0, d1, d2) = (&x[2 * j * c..][..c], &x[(2 * j + 1) * c..][..c], &x[(2 * j + 2) * c..][..c]);
        let (o0, o1, o2, o3) = (&mut u0[t.clone()], &mut u1[t.clone()], &mut u2[t.clone()], &mut u3[t]);
        for ((((o0, o1), o2), (&a, &b)), &c2) in o0.iter_mut().zip(o1.iter_mut()).zip(o2.iter_mut()).zip(d0.iter().zip(d1)).zip(d2) {
            *o0 = a - c2;
            *o1 = b + c2;
            *o2 = c2 - b;
        }
        if 2 * j + 3 < rows {
            let d3 = &x[(2 * j + 3) * c..][..c];
            for ((o, &b), &e) in o3.iter_mut().zip(d1).zip(d3) {
                *o = b - e;
            }
        } else {
            o3.copy_from_slice(d1);
        }
    }
}

/// Output transform `y = Aᵀ m` (or `y += Aᵀ m` with `add`) of the products `m`
/// (`[4, tiles, c]`, consecutive planes `plane` values apart) into the frames `y`
/// (`[rows ≤ 2·tiles, c]`), for any float type.
#[inline(always)]
pub(crate) fn winograd_output_any<T: Copy + std::ops::Add<Output = T> + std::ops::Sub<Output = T>>(
    y: &mut [T],
    m: &[T],
    c: usize,
    tiles: usize,
    plane: usize,
    add: bool,
) {
    debug_assert!(y.len() <= 2 * tiles * c && tiles * c <= plane);
    let (m0, rest) = m.split_at(plane);
    let (m1, rest) = rest.split_at(plane);
    let (m2, m3) = rest.split_at(plane);
    for (j, out) in y.chunks_mut(2 * c).enumerate() {
        let t = j * c..(j + 1) * c;
        let (a0, a1, a2, a3) = (&m0[t.clone()], &m1[t.clone()], &m2[t.clone()], &m3[t]);
        let (y0, y1) = out.split_at_mut(c);
        if add {
            for (((y, &p), &q), &r) in y0.iter_mut().zip(a0).zip(a1).zip(a2) {
                *y = *y + (p + q + r);
            }
            for (((y, &q), &r), &s) in y1.iter_mut().zip(a1).zip(a2).zip(a3) {
                *y = *y + (q - r - s);
            }
        } else {
            for (((y, &p), &q), &r) in y0.iter_mut().zip(a0).zip(a1).zip(a2) {
                *y = p + q + r;
            }
            for (((y, &q), &r), &s) in y1.iter_mut().zip(a1).zip(a2).zip(a3) {
                *y = q - r - s;
            }
        }
    }
}

/// Gradient transform `v = A·dy` (the transpose of the output transform, for the weight
/// gradient) of `tiles` tiles of output gradients `dy` (`[rows ≤ 2·tiles, c]`; a missing
/// second row of the last tile is zero) into `v` (four planes `[tiles, c]`, `plane` values
/// apart), for any float type.
#[inline(always)]
pub(crate) fn winograd_grad_any<T: Copy + Default + std::ops::Add<Output = T> + std::ops::Sub<Output = T>>(
    v: &mut [T],
    dy: &[T],
    c: usize,
    tiles: usize,
    plane: usize,
) {
    let (v0, rest) = v.split_at_mut(plane);
    let (v1, rest) = rest.split_at_mut(plane);
    let (v2, v3) = rest.split_at_mut(plane);
    for (j, rows) in dy.chunks(2 * c).enumerate().take(tiles) {
        let t = j * c..(j + 1) * c;
        let (o0, o1, o2, o3) = (&mut v0[t.clone()], &mut v1[t.clone()], &mut v2[t.clone()], &mut v3[t]);
        let (a, b) = rows.split_at(c);
        o0.copy_from_slice(a);
        if b.is_empty() {
            o1.copy_from_slice(a);
            o2.copy_from_slice(a);
            o3.fill(T::default());
            continue;
        }
        for ((((o1, o2), o3), &a), &b) in o1.iter_mut().zip(o2.iter_mut()).zip(o3.iter_mut()).zip(a).zip(b) {
            *o1 = a + b;
            *o2 = a - b;
            *o3 = T::default() - b;
        }
    }
}

simd_kernel! {
    /// [`winograd_grad_any`] for f32, vectorized for the machine.
    fn winograd_grad(v: &mut [f32], dy: &[f32], c: usize, tiles: usize, plane: usize) {
        winograd_grad_any(v, dy, c, tiles, plane)
    }
}

simd_kernel! {
    /// [`winograd_input_any`] for f32, vectorized for the machine.
    fn winograd_input(u: &mut [f32], x: &[f32], c: usize, tiles: usize, plane: usize) {
        winograd_input_any(u, x, c, tiles, plane)
    }
}

simd_kernel! {
    /// [`winograd_output_any`] for f32, vectorized for the machine.
    fn winograd_output(y: &mut [f32], m: &[f32], c: usize, tiles: usize, plane: usize, add: bool) {
        winograd_output_any(y, m, c, tiles, plane, add)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_and_silu_match_std() {
        let mut worst = 0.0f64;
        for i in -2000..=2000 {
            let x = i as f32 * 0.043;
            let (got, want) = (exp(x) as f64, (x as f64).exp());
            worst = worst.max((got - want).abs() / want);
        }
        assert!(worst < 4e-7, "exp relative error {worst}");
        assert_eq!(exp(0.0), 1.0);
        assert!(exp(-200.0) < 1e-37 && exp(-200.0) >= 0.0 && exp(200.0).is_finite());
        for x in [-100.0f32, -20.0, -1.5, 0.0, 0.3, 4.0, 50.0] {
            let want = x as f64 / (1.0 + (-x as f64).exp());
            assert!((silu(x) as f64 - want).abs() < 1e-6 * (1.0 + want.abs()), "{x}");
        }
    }

    /// F(2, 3) through the three transforms equals the direct correlation, including a last
    /// tile that runs past the input (zeros) and a partial output tile.
    #[test]
    fn winograd_matches_direct_correlation() {
        let (c, rows) = (3usize, 11usize);
        let x: Vec<f32> = (0..rows * c).map(|i| ((i * 13 % 17) as f32 - 8.0) * 0.25).collect();
        let g = [0.5f64, -1.25, 0.75];
        let tiles = (rows - 2).div_ceil(WINO_M); // outputs 0..rows−2 read frames o … o+2
        let mut u = vec![f32::NAN; WINO_ALPHA * tiles * c];
        winograd_input(&mut u, &x, c, tiles, tiles * c);
        // one channel in, one out per channel: products are u_i · (G g)_i
        let gw: Vec<f32> = WINO_G.iter().map(|row| (0..3).map(|k| row[k] * g[k]).sum::<f64>() as f32).collect();
        let m: Vec<f32> = u.iter().enumerate().map(|(i, &v)| v * gw[i / (tiles * c)]).collect();
        let outputs = rows - 2;
        let mut y = vec![f32::NAN; outputs * c];
        winograd_output(&mut y, &m, c, tiles, tiles * c, false);
        for o in 0..outputs {
            for k in 0..c {
                let want: f64 = (0..3).map(|t| x[(o + t) * c + k] as f64 * g[t]).sum();
                assert!((y[o * c + k] as f64 - want).abs() < 1e-5, "output {o} channel {k}: {} vs {want}", y[o * c + k]);
            }
        }
    }

    #[test]
    fn fused_rows_match_plain_loops() {
        let c = 5;
        let x: Vec<f32> = (0..3 * c).map(|i| ((i * 7 % 11) as f32 - 5.0) * 0.3).collect();
        let bias: Vec<f32> = (0..c).map(|j| j as f32 * 0.1).collect();
        let gamma: Vec<f32> = (0..c).map(|j| 1.0 + j as f32 * 0.2).collect();
        let beta: Vec<f32> = (0..c).map(|j| -(j as f32) * 0.05).collect();
        let mut y = x.clone();
        silu_layer_norm_rows(&mut y, c, &bias, &gamma, &beta, 1e-5);
        for r in 0..3 {
            let v: Vec<f64> = (0..c)
                .map(|j| {
                    let a = (x[r * c + j] + bias[j]) as f64;
                    a / (1.0 + (-a).exp())
                })
                .collect();
            let mean = v.iter().sum::<f64>() / c as f64;
            let var = v.iter().map(|a| (a - mean).powi(2)).sum::<f64>() / c as f64;
            for j in 0..c {
                let want = (v[j] - mean) / (var + 1e-5).sqrt() * gamma[j] as f64 + beta[j] as f64;
                assert!((y[r * c + j] as f64 - want).abs() < 1e-5, "row {r} ch {j}");
            }
        }
        let mut z = x.clone();
        film_rows(&mut z, c, &gamma, &beta, Some(&y));
        for k in 0..3 * c {
            assert!((z[k] - (x[k] * gamma[k % c] + beta[k % c] + y[k])).abs() < 1e-6);
        }
        let coarse = [1.0f32, 3.0, 7.0];
        let mut fine = [0.0f32; 4];
        upsample2x_rows(&mut fine, &coarse, 1, 2);
        assert_eq!(fine, [2.0, 3.0, 5.0, 7.0]);
        upsample2x_rows(&mut fine[..2], &coarse, 1, 0);
        assert_eq!(fine[..2], [1.0, 1.0]);
    }
}
