//! The ops of [`super::ops`] composed from candle built-ins that every backend has (`narrow`,
//! `cat`, `matmul`, broadcast arithmetic, `silu`), so that the one network definition runs on
//! any candle device. Their backward passes are candle's own; the tests of
//! [`super::ops`] and the network hold them to the custom CPU kernels, value by value and in
//! every gradient.
//!
//! With [`Precision::Bf16`] the convolutions' matrix products run in bf16 (inputs and weights
//! cast down, the product cast back to f32); everything else, the bias, normalization and
//! the loss stay in the master dtype.

use super::ops::{conv_out_len, Precision};
use candle_core::{DType, Tensor, D};

type CResult<T> = candle_core::Result<T>;

/// [`super::ops::causal_conv1d`] as left padding, one strided view per tap, and one matmul
/// over the taps side by side.
///
/// # Shapes
/// - `x`: `[N, T, C_in]`, `w`: `[K, C_in, C_out]`, `b`: `[C_out]`; returns `[N, ⌈T/s⌉, C_out]`
pub(crate) fn causal_conv1d(x: &Tensor, w: &Tensor, b: &Tensor, stride: usize, precision: Precision) -> CResult<Tensor> {
    let (n, t, cin) = x.dims3()?;
    let (k, cin2, cout) = w.dims3()?;
    if stride == 0 || k == 0 || cin != cin2 || b.dims1()? != cout {
        candle_core::bail!("causal_conv1d: x {:?}, weight {:?}, bias {:?}, stride {stride} do not fit", x.dims(), w.dims(), b.dims());
    }
    let to = conv_out_len(t, stride);
    let cols = if k == 1 && stride == 1 {
        x.clone()
    } else {
        // Output o reads padded frames o·s + kk, kk < K: pad K − 1 on the left and enough on
        // the right that every tap has `to` strided frames.
        let padded = x.pad_with_zeros(1, k - 1, stride * to - t)?;
        let taps = (0..k)
            .map(|kk| {
                let tap = padded.narrow(1, kk, stride * to)?;
                if stride == 1 {
                    Ok(tap)
                } else {
                    tap.reshape((n, to, stride, cin))?.narrow(2, 0, 1)?.reshape((n, to, cin))
                }
            })
            .collect::<CResult<Vec<_>>>()?;
        Tensor::cat(&taps, 2)?
    };
    let cols = cols.reshape((n * to, k * cin))?;
    let w = w.reshape((k * cin, cout))?;
    let y = match precision {
        Precision::F32 => cols.matmul(&w)?,
        Precision::Bf16 => cols.to_dtype(DType::BF16)?.matmul(&w.to_dtype(DType::BF16)?)?.to_dtype(x.dtype())?,
    };
    y.broadcast_add(b)?.reshape((n, to, cout))
}

/// [`super::ops::layer_norm`] from means and a square root.
pub(crate) fn layer_norm(x: &Tensor, gamma: &Tensor, beta: &Tensor, eps: f64) -> CResult<Tensor> {
    let mean = x.mean_keepdim(D::Minus1)?;
    let centered = x.broadcast_sub(&mean)?;
    let var = centered.sqr()?.mean_keepdim(D::Minus1)?;
    centered.broadcast_div(&(var + eps)?.sqrt()?)?.broadcast_mul(gamma)?.broadcast_add(beta)
}

/// [`super::ops::film_residual`] as broadcast arithmetic.
///
/// # Shapes
/// - `h`, `skip`: `[G, M, C]`; `film`: `[G, 2C]`; returns `[G, M, C]`
pub(crate) fn film_residual(h: &Tensor, film: &Tensor, skip: &Tensor) -> CResult<Tensor> {
    let c = h.dims().last().copied().unwrap_or(0);
    let rows = h.elem_count().checked_div(c).unwrap_or(0);
    let g = match film.dims() {
        &[g, two_c] if two_c == 2 * c && g > 0 && rows % g == 0 => g,
        d => candle_core::bail!("film-residual: film has shape {d:?}, expected [G, {}] with G dividing the {rows} rows of h {:?}", 2 * c, h.dims()),
    };
    let scale = (film.narrow(1, 0, c)? + 1.0)?.reshape((g, 1, c))?;
    let shift = film.narrow(1, c, c)?.reshape((g, 1, c))?;
    let grouped = (g, rows / g, c);
    (h.reshape(grouped)?.broadcast_mul(&scale)?.broadcast_add(&shift)? + skip.reshape(grouped)?)?.reshape(h.shape())
}

/// [`super::ops::causal_upsample2x`]: even frames average the previous and current coarse
/// sample, odd frames copy the current one.
///
/// # Shapes
/// - `x`: `[N, L, C]`; returns `[N, 2L, C]`
pub(crate) fn causal_upsample2x(x: &Tensor) -> CResult<Tensor> {
    let (n, len, c) = x.dims3()?;
    if len == 0 {
        return x.reshape((n, 0, c));
    }
    let prev = Tensor::cat(&[x.narrow(1, 0, 1)?, x.narrow(1, 0, len - 1)?], 1)?;
    let even = ((prev + x)? * 0.5)?;
    Tensor::stack(&[even, x.clone()], 2)?.reshape((n, 2 * len, c))
}

/// [`super::ops::bmm`] with the transposes made contiguous.
pub(crate) fn bmm(a: &Tensor, b: &Tensor, ta: bool, tb: bool) -> CResult<Tensor> {
    let r = a.rank();
    if r < 2 || b.rank() != r {
        candle_core::bail!("bmm: shapes {:?} and {:?} do not fit", a.dims(), b.dims());
    }
    let a = if ta { a.transpose(r - 2, r - 1)?.contiguous()? } else { a.contiguous()? };
    let b = if tb { b.transpose(r - 2, r - 1)?.contiguous()? } else { b.contiguous()? };
    // candle's matmul takes at most two batch dims: flatten them into one.
    let (ad, bd) = (a.dims().to_vec(), b.dims().to_vec());
    let batch: usize = ad[..r - 2].iter().product();
    let y = a.reshape((batch, ad[r - 2], ad[r - 1]))?.matmul(&b.reshape((batch, bd[r - 2], bd[r - 1]))?)?;
    let mut out = ad[..r - 2].to_vec();
    out.extend([ad[r - 2], bd[r - 1]]);
    y.reshape(out)
}
