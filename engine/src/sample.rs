//! Inpainting: sample the unknown entries of a canvas given the known ones (METHOD.md §4).
//!
//! One entry point, [`inpaint`], for every conditioning task: forecasting is a mask that is
//! true for all dims of all persons on the observed frames; completing missing joints, frames
//! or whole persons are other masks through the same code path.
//!
//! ```text
//! x ← N(0, I);  x[M] ← X_obs (replace only; with noised the known entries start as noise too)
//! for i in 0..K:                           (t_i = sampler.timesteps()[i], descending)
//!     x̂0 = g(x, t_i, anchors)
//!     x  = a_i·x̂0 + b_i·x + σ_i·z          (one reverse step of the sampler)
//!     x[M] ← X_obs                          (replace: the reference's choice)
//!          | √ᾱ_prev·X_obs + √(1−ᾱ_prev)·z' (noised: paper Eq. 7.6)
//! ```
//!
//! The canvas is in the model's space: standardized anchored features `[frames, persons, δ]`
//! (see [`crate::features`]). All samples are denoised in one batch; every random draw comes
//! from one [`StdRng`] seeded by [`InpaintOptions::seed`], so a seed reproduces a sample bit
//! for bit on one machine.

use crate::model::Denoiser;
use crate::{bail, Result};
use candle_core::{Device, Tensor};
use ndarray::{Array4, ArrayView2, ArrayView3};
use rand::rngs::StdRng;
use rand::SeedableRng;
use serde::{Deserialize, Serialize};
use crate::diffusion::standard_normal;
use socdiff_schedules::{QCoefficients, Sampler};

/// How known entries are imposed after each reverse step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Conditioning {
    /// Known entries are set to the clean known values (the reference's conditioning).
    #[default]
    Replace,
    /// Known entries are set to the known values noised to the level of the new sample,
    /// q(x_prev | X_obs) (paper Eq. 7.6).
    Noised,
}

/// Anything that predicts x̂0 from a noisy canvas: the [`Denoiser`], or a stand-in in tests.
pub trait X0Model {
    /// δ, the feature dims per person and frame.
    fn feature_dims(&self) -> usize;

    /// x̂0 = g(x_t, t, anchors).
    ///
    /// # Shapes
    /// - `x`: `[S, P, T, δ]` f32; `t`: `[S]` u32; `anchors`: `[S, P, 4]` f32
    /// - returns `[S, P, T, δ]` f32
    fn predict_x0(&self, x: &Tensor, t: &Tensor, anchors: Option<&Tensor>) -> Result<Tensor>;
}

impl X0Model for Denoiser {
    fn feature_dims(&self) -> usize {
        self.config().feature_dims
    }

    /// Pass a [`Denoiser::frozen`] copy: with trainable weights every step would keep its
    /// autograd graph (CANDLE_NOTES.md trap 6).
    fn predict_x0(&self, x: &Tensor, t: &Tensor, anchors: Option<&Tensor>) -> Result<Tensor> {
        self.forward(x, t, anchors)
    }
}

/// What is known about the canvas.
#[derive(Clone, Copy, Debug)]
pub struct Known<'a> {
    /// Known values (standardized anchored features); entries outside the mask are ignored.
    ///
    /// Shape `[frames, persons, δ]`.
    pub values: ArrayView3<'a, f32>,
    /// `true` where the value is known. Shape `[frames, persons, δ]`.
    pub mask: ArrayView3<'a, bool>,
    /// Each person's anchor `(root_x, root_y, cos h, sin h)` in a frame shared by the scene,
    /// for the social aggregator. Shape `[persons, 4]`.
    pub anchors: Option<ArrayView2<'a, f32>>,
}

/// Options of [`inpaint`].
#[derive(Clone, Debug, PartialEq)]
pub struct InpaintOptions {
    /// Number of samples drawn (one batch).
    pub samples: usize,
    /// How known entries are imposed.
    pub conditioning: Conditioning,
    /// Seed of every random draw (initial noise, step noise).
    pub seed: u64,
}

impl Default for InpaintOptions {
    fn default() -> Self {
        Self { samples: 1, conditioning: Conditioning::Replace, seed: 0 }
    }
}

/// A forecasting mask: every dim of every person known on frames `< observed`.
///
/// # Shapes
/// - returns `[frames, persons, dims]`
pub fn forecast_mask(frames: usize, persons: usize, dims: usize, observed: usize) -> ndarray::Array3<bool> {
    ndarray::Array3::from_shape_fn((frames, persons, dims), |(f, _, _)| f < observed)
}

/// Samples the unknown entries of the canvas with `sampler` (DDPM, or DDIM over any K steps),
/// imposing the known entries after every reverse step (see the module doc).
///
/// # Shapes
/// - `known.values`, `known.mask`: `[T, P, δ]`; `known.anchors`: `[P, 4]`
/// - returns `[samples, T, P, δ]` (known entries equal `known.values` exactly)
pub fn inpaint(model: &dyn X0Model, sampler: &dyn Sampler, known: &Known, opts: &InpaintOptions) -> Result<Array4<f32>> {
    let (nt, np, nd) = known.values.dim();
    if known.mask.dim() != (nt, np, nd) {
        bail!("inpaint: mask {:?} and known values {:?} differ in shape", known.mask.shape(), known.values.shape());
    }
    if nt == 0 || np == 0 {
        bail!("inpaint: empty canvas {:?}", known.values.shape());
    }
    if nd != model.feature_dims() {
        bail!("inpaint: canvas has {nd} feature dims, the model {}", model.feature_dims());
    }
    if opts.samples == 0 {
        bail!("inpaint: samples must be at least 1");
    }
    if let Some(a) = known.anchors {
        if a.dim() != (np, 4) {
            bail!("inpaint: anchors have shape {:?}, expected [{np}, 4]", a.shape());
        }
    }
    let steps = sampler.timesteps();
    if steps.is_empty() {
        bail!("inpaint: the sampler has no steps");
    }
    let ns = opts.samples;
    let per = np * nt * nd;
    let device = Device::Cpu;

    // Known values and mask in the model's layout [P, T, δ].
    let mut obs = vec![0f32; per];
    let mut mask = vec![false; per];
    for p in 0..np {
        for f in 0..nt {
            for d in 0..nd {
                let k = (p * nt + f) * nd + d;
                mask[k] = known.mask[[f, p, d]];
                obs[k] = if mask[k] { known.values[[f, p, d]] } else { 0.0 };
            }
        }
    }
    if let Some(k) = mask.iter().zip(&obs).position(|(&m, v)| m && !v.is_finite()) {
        bail!("inpaint: known value at person {}, frame {}, dim {} is not finite", k / (nt * nd), (k / nd) % nt, k % nd);
    }
    let anchors = match known.anchors {
        Some(a) => {
            let one: Vec<f32> = a.iter().copied().collect();
            let all: Vec<f32> = (0..ns).flat_map(|_| one.iter().copied()).collect();
            Some(Tensor::from_vec(all, (ns, np, 4), &device)?)
        }
        None => None,
    };

    let mut rng = StdRng::seed_from_u64(opts.seed);
    let mut x = standard_normal(&mut rng, ns * per);
    let impose = |x: &mut [f32], level: Option<QCoefficients>, rng: &mut StdRng| {
        let z = match level {
            Some(_) => standard_normal(rng, ns * per),
            None => Vec::new(),
        };
        for (s, xs) in x.chunks_exact_mut(per).enumerate() {
            for k in 0..per {
                if mask[k] {
                    xs[k] = match level {
                        None => obs[k],
                        Some(q) => q.q_sample(obs[k] as f64, z[s * per + k] as f64) as f32,
                    };
                }
            }
        }
    };
    // The first canvas: N(0, I) everywhere; with `replace` the known entries are the clean
    // known values right away (as the reference), with `noised` they start as noise too.
    if opts.conditioning == Conditioning::Replace {
        impose(&mut x, None, &mut rng);
    }

    let mut next = vec![0f32; ns * per];
    for (i, &t) in steps.iter().enumerate() {
        let xt = Tensor::from_vec(x.clone(), (ns, np, nt, nd), &device)?;
        let tt = Tensor::from_vec(vec![t as u32; ns], ns, &device)?;
        let x0 = model.predict_x0(&xt, &tt, anchors.as_ref())?;
        if x0.dims() != [ns, np, nt, nd] {
            bail!("inpaint: the model returned shape {:?}, expected [{ns}, {np}, {nt}, {nd}]", x0.dims());
        }
        let x0 = x0.to_dtype(candle_core::DType::F32)?.flatten_all()?.to_vec1::<f32>()?;
        let c = sampler.coefficients(i)?;
        let z = if c.needs_noise() { Some(standard_normal(&mut rng, ns * per)) } else { None };
        c.apply(&x0, &x, z.as_deref(), &mut next)?;
        std::mem::swap(&mut x, &mut next);
        let level = match opts.conditioning {
            Conditioning::Replace => None,
            Conditioning::Noised => Some(sampler.q_prev(i)?),
        };
        impose(&mut x, level, &mut rng);
    }

    // Back to [S, T, P, δ].
    let mut out = Array4::<f32>::zeros((ns, nt, np, nd));
    for s in 0..ns {
        for p in 0..np {
            for f in 0..nt {
                for d in 0..nd {
                    out[[s, f, p, d]] = x[s * per + (p * nt + f) * nd + d];
                }
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{Array2, Array3};
    use socdiff_schedules::{Ddim, Ddpm, NoiseSchedule};
    use std::cell::RefCell;

    /// x̂0 = 0.5·x_t + 0.1·(d + 1), recording every input.
    struct Dummy {
        dims: usize,
        seen: RefCell<Vec<(Vec<f32>, Vec<u32>)>>,
    }

    impl X0Model for Dummy {
        fn feature_dims(&self) -> usize {
            self.dims
        }
        fn predict_x0(&self, x: &Tensor, t: &Tensor, _anchors: Option<&Tensor>) -> Result<Tensor> {
            let v = x.flatten_all()?.to_vec1::<f32>()?;
            self.seen.borrow_mut().push((v.clone(), t.to_vec1::<u32>()?));
            let d = self.dims;
            let out: Vec<f32> = v.iter().enumerate().map(|(k, &x)| 0.5 * x + 0.1 * ((k % d) as f32 + 1.0)).collect();
            Ok(Tensor::from_vec(out, x.dims(), x.device())?)
        }
    }

    fn canvas() -> (Array3<f32>, Array3<bool>) {
        let (t, p, d) = (9, 2, 3);
        let values = Array3::from_shape_fn((t, p, d), |(f, q, k)| f as f32 * 0.1 - q as f32 + k as f32 * 0.01);
        let mut mask = forecast_mask(t, p, d, 4);
        mask[[6, 1, 2]] = true; // a single known entry in the future
        (values, mask)
    }

    #[test]
    fn replace_keeps_known_entries_at_every_step_and_is_reproducible() {
        let (values, mask) = canvas();
        let anchors = Array2::from_shape_fn((2, 4), |(p, k)| (p * 4 + k) as f32);
        let known = Known { values: values.view(), mask: mask.view(), anchors: Some(anchors.view()) };
        let sampler = Ddim::new(&NoiseSchedule::default(), 10, 0.5).unwrap();
        let model = Dummy { dims: 3, seen: RefCell::new(vec![]) };
        let opts = InpaintOptions { samples: 2, conditioning: Conditioning::Replace, seed: 7 };
        let out = inpaint(&model, &sampler, &known, &opts).unwrap();
        assert_eq!(out.dim(), (2, 9, 2, 3));
        // The model saw the clean known values at every step, and the sampler's timesteps.
        let seen = model.seen.borrow();
        assert_eq!(seen.len(), 10);
        for (i, (x, t)) in seen.iter().enumerate() {
            assert_eq!(t, &vec![sampler.timesteps()[i] as u32; 2]);
            for s in 0..2 {
                for (f, p, d) in [(0, 0, 0), (3, 1, 2), (6, 1, 2)] {
                    assert_eq!(x[s * 54 + (p * 9 + f) * 3 + d], values[[f, p, d]], "step {i}");
                }
            }
        }
        for ((s, f, p, d), &v) in out.indexed_iter() {
            if mask[[f, p, d]] {
                assert_eq!(v, values[[f, p, d]], "sample {s}");
            }
        }
        // Golden: sum and mean of the output (fixed seed, deterministic dummy).
        let sum: f64 = out.iter().map(|&v| v as f64).sum();
        println!("replace: sum {sum:.6}, mean {:.6}", sum / out.len() as f64);
        assert!((sum - GOLDEN_REPLACE_SUM).abs() < 1e-5, "sum {sum}");
        // Same seed → same bits; another seed → different unknown entries.
        let again = inpaint(&Dummy { dims: 3, seen: RefCell::new(vec![]) }, &sampler, &known, &opts).unwrap();
        assert_eq!(again, out);
        let other = inpaint(&Dummy { dims: 3, seen: RefCell::new(vec![]) }, &sampler, &known, &InpaintOptions { seed: 8, ..opts.clone() }).unwrap();
        assert_ne!(other, out);
        // The two samples of one batch differ.
        assert_ne!(out.index_axis(ndarray::Axis(0), 0), out.index_axis(ndarray::Axis(0), 1));
    }

    #[test]
    fn deterministic_ddim_ends_at_the_model_prediction() {
        // η = 0: the last DDIM step returns x̂0, so with x̂0 = 0.5·x + c the unknown entries end at
        // 0.5·x_prev + c for the canvas x_prev of the last step.
        let (values, mask) = canvas();
        let known = Known { values: values.view(), mask: mask.view(), anchors: None };
        let sampler = Ddim::new(&NoiseSchedule::default(), 5, 0.0).unwrap();
        let model = Dummy { dims: 3, seen: RefCell::new(vec![]) };
        let out = inpaint(&model, &sampler, &known, &InpaintOptions::default()).unwrap();
        let seen = model.seen.borrow();
        let last = &seen.last().unwrap().0;
        for ((_, f, p, d), &v) in out.indexed_iter() {
            if !mask[[f, p, d]] {
                let want = 0.5 * last[(p * 9 + f) * 3 + d] + 0.1 * (d as f32 + 1.0);
                assert!((v - want).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn noised_conditioning_noises_known_entries_until_the_end() {
        let (values, mask) = canvas();
        let known = Known { values: values.view(), mask: mask.view(), anchors: None };
        let sampler = Ddpm::truncated(&NoiseSchedule::default(), 20).unwrap();
        let model = Dummy { dims: 3, seen: RefCell::new(vec![]) };
        let opts = InpaintOptions { samples: 1, conditioning: Conditioning::Noised, seed: 3 };
        let out = inpaint(&model, &sampler, &known, &opts).unwrap();
        let seen = model.seen.borrow();
        // Intermediate canvases hold noised known values; the result holds them exactly.
        assert_ne!(seen[5].0[0], values[[0, 0, 0]]);
        for ((_, f, p, d), &v) in out.indexed_iter() {
            if mask[[f, p, d]] {
                assert_eq!(v, values[[f, p, d]]);
            }
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let (values, mask) = canvas();
        let sampler = Ddim::new(&NoiseSchedule::default(), 3, 0.0).unwrap();
        let model = Dummy { dims: 3, seen: RefCell::new(vec![]) };
        let err = |k: &Known, o: &InpaintOptions| inpaint(&model, &sampler, k, o).unwrap_err().to_string();
        let opts = InpaintOptions::default();
        let small = Array3::from_elem((9, 2, 2), false);
        assert!(err(&Known { values: values.view(), mask: small.view(), anchors: None }, &opts).contains("differ in shape"));
        let wide = Array3::zeros((9, 2, 4));
        let wmask = Array3::from_elem((9, 2, 4), false);
        assert!(err(&Known { values: wide.view(), mask: wmask.view(), anchors: None }, &opts).contains("4 feature dims"));
        let anchors = Array2::zeros((3, 4));
        assert!(err(&Known { values: values.view(), mask: mask.view(), anchors: Some(anchors.view()) }, &opts).contains("anchors"));
        let known = Known { values: values.view(), mask: mask.view(), anchors: None };
        assert!(err(&known, &InpaintOptions { samples: 0, ..opts.clone() }).contains("samples"));
        let mut nan = values.clone();
        nan[[2, 1, 0]] = f32::NAN;
        assert!(err(&Known { values: nan.view(), mask: mask.view(), anchors: None }, &opts).contains("person 1, frame 2, dim 0"));
    }

    const GOLDEN_REPLACE_SUM: f64 = 2.702_053_7;
}
