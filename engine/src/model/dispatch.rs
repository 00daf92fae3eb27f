//! [`Kernels`]: which implementation of the ops a network runs — the custom CPU kernels of
//! [`super::ops`] or the same ops composed from candle built-ins ([`super::composed`]) — one
//! call per op for the network to make.

use super::composed;
use super::ops::{
    bmm, causal_conv1d_cat, causal_conv1d_with, causal_upsample2x, film_residual, layer_norm, silu, silu_layer_norm, silu_layer_norm_conv1d, K3Conv, Precision,
};
use candle_core::Tensor;

type CResult<T> = candle_core::Result<T>;

#[cfg(doc)]
use super::ops::causal_conv1d;

/// Which implementation of the ops a network runs. One network definition, two kernel sets:
/// the custom CPU kernels of this module, or the same ops composed from candle built-ins
/// ([`super::composed`]) that run on every candle device (CUDA included).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernels {
    /// The custom ops of this module (CPU only; the fast path there), with the given algorithm
    /// for stride-1 k3 convs.
    Custom(K3Conv),
    /// Candle built-ins, at the given precision of the convolutions' products.
    Composed(Precision),
}

impl Kernels {
    /// The custom kernels with Winograd k3 convs (the CPU default).
    pub const CUSTOM: Self = Kernels::Custom(K3Conv::Winograd);

    /// The custom kernels on the CPU, composed ones (f32) elsewhere.
    pub fn for_device(device: &candle_core::Device) -> Self {
        if device.is_cpu() {
            Kernels::CUSTOM
        } else {
            Kernels::Composed(Precision::F32)
        }
    }

    /// An error when these kernels cannot run on `device`.
    pub fn check_device(self, device: &candle_core::Device) -> CResult<()> {
        if matches!(self, Kernels::Custom(_)) && !device.is_cpu() {
            candle_core::bail!("the custom kernels run on the CPU only, the network is on {device:?}");
        }
        Ok(())
    }

    /// [`causal_conv1d`].
    pub fn conv1d(self, x: &Tensor, w: &Tensor, b: &Tensor, stride: usize) -> CResult<Tensor> {
        match self {
            Kernels::Custom(k3) => causal_conv1d_with(x, w, b, stride, k3),
            Kernels::Composed(p) => composed::causal_conv1d(x, w, b, stride, p),
        }
    }

    /// [`causal_conv1d_cat`].
    pub fn conv1d_cat(self, a: &Tensor, b: &Tensor, w: &Tensor, bias: &Tensor, stride: usize, upsample: bool) -> CResult<Tensor> {
        match self {
            Kernels::Custom(k3) => causal_conv1d_cat(a, b, w, bias, stride, upsample, k3),
            Kernels::Composed(p) => {
                let y = composed::causal_conv1d(&Tensor::cat(&[a, b], 2)?, w, bias, stride, p)?;
                if upsample {
                    composed::causal_upsample2x(&y)
                } else {
                    Ok(y)
                }
            }
        }
    }

    /// [`silu_layer_norm_conv1d`].
    #[allow(clippy::too_many_arguments)]
    pub fn silu_layer_norm_conv1d(self, h: &Tensor, gamma: &Tensor, beta: &Tensor, eps: f64, w: &Tensor, b: &Tensor, stride: usize) -> CResult<Tensor> {
        match self {
            Kernels::Custom(k3) => silu_layer_norm_conv1d(h, gamma, beta, eps, w, b, stride, k3),
            Kernels::Composed(p) => composed::causal_conv1d(&composed::layer_norm(&h.silu()?, gamma, beta, eps)?, w, b, stride, p),
        }
    }

    /// [`layer_norm`].
    pub fn layer_norm(self, x: &Tensor, gamma: &Tensor, beta: &Tensor, eps: f64) -> CResult<Tensor> {
        match self {
            Kernels::Custom(_) => layer_norm(x, gamma, beta, eps),
            Kernels::Composed(_) => composed::layer_norm(x, gamma, beta, eps),
        }
    }

    /// [`silu_layer_norm`].
    pub fn silu_layer_norm(self, x: &Tensor, gamma: &Tensor, beta: &Tensor, eps: f64) -> CResult<Tensor> {
        match self {
            Kernels::Custom(_) => silu_layer_norm(x, gamma, beta, eps),
            Kernels::Composed(_) => composed::layer_norm(&x.silu()?, gamma, beta, eps),
        }
    }

    /// [`silu`].
    pub fn silu(self, x: &Tensor) -> CResult<Tensor> {
        match self {
            Kernels::Custom(_) => silu(x),
            Kernels::Composed(_) => x.silu(),
        }
    }

    /// [`film_residual`].
    pub fn film_residual(self, h: &Tensor, film: &Tensor, skip: &Tensor) -> CResult<Tensor> {
        match self {
            Kernels::Custom(_) => film_residual(h, film, skip),
            Kernels::Composed(_) => composed::film_residual(h, film, skip),
        }
    }

    /// [`causal_upsample2x`].
    pub fn upsample2x(self, x: &Tensor) -> CResult<Tensor> {
        match self {
            Kernels::Custom(_) => causal_upsample2x(x),
            Kernels::Composed(_) => composed::causal_upsample2x(x),
        }
    }

    /// [`bmm`].
    pub fn bmm(self, a: &Tensor, b: &Tensor, ta: bool, tb: bool) -> CResult<Tensor> {
        match self {
            Kernels::Custom(_) => bmm(a, b, ta, tb),
            Kernels::Composed(_) => composed::bmm(a, b, ta, tb),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ops::tests::rand_t;
    use candle_core::Var;
    use rand::rngs::StdRng;
    use rand::SeedableRng;

    /// Every composed op (any device) against its custom kernel, in value and in the gradient
    /// of every input, over the shapes the network meets (odd lengths, one frame, strides).
    #[test]
    fn composed_ops_match_the_custom_kernels() {
        let composed = Kernels::Composed(Precision::F32);
        type Op = Box<dyn Fn(Kernels, &[Tensor]) -> CResult<Tensor>>;
        let cases: Vec<(&str, Vec<Vec<usize>>, Op)> = vec![
            ("conv k3 s1", vec![vec![2, 9, 3], vec![3, 3, 4], vec![4]], Box::new(|k, x| k.conv1d(&x[0], &x[1], &x[2], 1))),
            ("conv k3 s2 odd", vec![vec![2, 9, 3], vec![3, 3, 4], vec![4]], Box::new(|k, x| k.conv1d(&x[0], &x[1], &x[2], 2))),
            ("conv k3 s2 T=1", vec![vec![2, 1, 3], vec![3, 3, 4], vec![4]], Box::new(|k, x| k.conv1d(&x[0], &x[1], &x[2], 2))),
            ("conv 1x1", vec![vec![1, 7, 5], vec![1, 5, 2], vec![2]], Box::new(|k, x| k.conv1d(&x[0], &x[1], &x[2], 1))),
            ("layer norm", vec![vec![3, 5, 6], vec![6], vec![6]], Box::new(|k, x| k.layer_norm(&x[0], &x[1], &x[2], 1e-5))),
            ("silu", vec![vec![4, 6]], Box::new(|k, x| k.silu(&(&x[0] * 3.0)?))),
            ("silu layer norm", vec![vec![3, 5, 6], vec![6], vec![6]], Box::new(|k, x| k.silu_layer_norm(&(&x[0] * 3.0)?, &x[1], &x[2], 1e-5))),
            ("film", vec![vec![2, 5, 3], vec![2, 6], vec![2, 5, 3]], Box::new(|k, x| k.film_residual(&x[0], &x[1], &x[2]))),
            (
                "conv of two, 1x1",
                vec![vec![2, 7, 3], vec![2, 7, 2], vec![1, 5, 4], vec![4]],
                Box::new(|k, x| k.conv1d_cat(&x[0], &x[1], &x[2], &x[3], 1, false)),
            ),
            (
                "conv of two, upsampled",
                vec![vec![2, 9, 3], vec![2, 9, 2], vec![3, 5, 4], vec![4]],
                Box::new(|k, x| k.conv1d_cat(&x[0], &x[1], &x[2], &x[3], 1, true)),
            ),
            (
                "conv of silu layer norm",
                vec![vec![2, 9, 4], vec![4], vec![4], vec![3, 4, 3], vec![3]],
                Box::new(|k, x| k.silu_layer_norm_conv1d(&(&x[0] * 3.0)?, &x[1], &x[2], 1e-5, &x[3], &x[4], 1)),
            ),
            ("upsample", vec![vec![2, 5, 3], vec![1]], Box::new(|k, x| k.upsample2x(&x[0]))),
            ("upsample L=1", vec![vec![2, 1, 3], vec![1]], Box::new(|k, x| k.upsample2x(&x[0]))),
            ("bmm tb", vec![vec![2, 3, 2, 5, 4], vec![2, 3, 2, 6, 4]], Box::new(|k, x| k.bmm(&x[0], &x[1], false, true))),
            ("bmm ta", vec![vec![2, 3, 4, 5], vec![2, 3, 4, 6]], Box::new(|k, x| k.bmm(&x[0], &x[1], true, false))),
        ];
        let mut rng = StdRng::seed_from_u64(17);
        for (name, shapes, op) in &cases {
            let inputs: Vec<Var> = shapes.iter().map(|s| Var::from_tensor(&rand_t(&mut rng, s)).unwrap()).collect();
            let ts: Vec<Tensor> = inputs.iter().map(|v| v.as_tensor().clone()).collect();
            let (a, b) = (op(Kernels::CUSTOM, &ts).unwrap(), op(composed, &ts).unwrap());
            assert_eq!(a.dims(), b.dims(), "{name}");
            let r = rand_t(&mut rng, a.dims());
            let diff = |x: &Tensor, y: &Tensor| (x - y).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f64>().unwrap();
            assert!(diff(&a, &b) < 1e-12, "{name}: values differ by {}", diff(&a, &b));
            let (ga, gb) = ((&a * &r).unwrap().sum_all().unwrap().backward().unwrap(), (&b * &r).unwrap().sum_all().unwrap().backward().unwrap());
            for (i, v) in inputs.iter().enumerate() {
                match (ga.get(v), gb.get(v)) {
                    (Some(x), Some(y)) => assert!(diff(x, y) < 1e-12, "{name}: gradient of input {i} differs by {}", diff(x, y)),
                    (None, None) => {}
                    (x, y) => panic!("{name}: input {i} has a gradient on one path only ({} / {})", x.is_some(), y.is_some()),
                }
            }
        }
    }
}
