//! Full sampling loops with deterministic dummy models (STYLE.md: a golden sum/mean per sampler).
//!
//! Noise comes from a 64-bit LCG mapped to uniform noise on [−√3, √3) (unit variance, no
//! transcendental functions), so every run is bit-for-bit reproducible without `rand`.

use socdiff_schedules::{Ddim, Ddpm, NoiseSchedule, Sampler};

/// Number of sample elements.
const N: usize = 64;

/// Knuth's MMIX LCG.
struct Lcg(u64);

impl Lcg {
    /// Uniform on [0, 1) from the top 53 bits.
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }

    /// N zero-mean, unit-variance values.
    fn noise(&mut self) -> Vec<f32> {
        (0..N).map(|_| ((2.0 * self.uniform() - 1.0) * 3f64.sqrt()) as f32).collect()
    }
}

/// A dummy denoiser: x̂0 = clamp(0.5·x_t + 0.25, −1, 1) (the offset keeps sums away from 0).
fn shrink(x_t: &[f32], _t: usize) -> Vec<f32> {
    x_t.iter().map(|v| (0.5 * v + 0.25).clamp(-1.0, 1.0)).collect()
}

/// The fixed target of the "perfect" dummy model: k·0.03 − 1 for k = 0..N.
fn target() -> Vec<f32> {
    (0..N).map(|k| k as f32 * 0.03 - 1.0).collect()
}

/// Runs `sampler` from x_T = LCG noise (seed 42) with `model`, drawing z only when needed.
fn sample(sampler: &dyn Sampler, model: impl Fn(&[f32], usize) -> Vec<f32>) -> Vec<f32> {
    let mut rng = Lcg(42);
    let mut x = rng.noise();
    let mut out = vec![0.0; N];
    for (i, &t) in sampler.timesteps().iter().enumerate() {
        let x0_pred = model(&x, t);
        let z = if sampler.needs_noise(i).unwrap() { Some(rng.noise()) } else { None };
        sampler.step(i, &x0_pred, &x, z.as_deref(), &mut out).unwrap();
        std::mem::swap(&mut x, &mut out);
    }
    x
}

/// (sum, mean) in f64.
fn sum_mean(x: &[f32]) -> (f64, f64) {
    let sum: f64 = x.iter().map(|&v| f64::from(v)).sum();
    (sum, sum / x.len() as f64)
}

/// Asserts the golden (sum, mean) to 1e-6 relative (room for libm's last-bit differences in cos).
fn assert_golden(x: &[f32], sum: f64, mean: f64) {
    let (s, m) = sum_mean(x);
    println!("sum = {s:?}, mean = {m:?}");
    assert!(x.iter().all(|v| v.is_finite()));
    assert!((s - sum).abs() <= 1e-6 * sum.abs(), "sum {s:?} vs golden {sum:?}");
    assert!((m - mean).abs() <= 1e-6 * mean.abs(), "mean {m:?} vs golden {mean:?}");
}

// Golden values: printed by the first run of these tests (`cargo test -p socdiff-schedules
// --test sampling -- --nocapture`) and hard-coded; they pin the whole loop, not an oracle. As a
// sanity check, x̂0 = 0.5·x_t + 0.25 has the fixed point x = 0.5, and the means land near it.

#[test]
fn ddpm_1000_shrink_model_golden() {
    let x = sample(&Ddpm::new(&NoiseSchedule::default()), shrink);
    assert_golden(&x, 31.782558739185333, 0.49660248029977083);
}

#[test]
fn ddim_50_shrink_model_golden() {
    let s = NoiseSchedule::default();
    let x = sample(&Ddim::new(&s, 50, 0.0).unwrap(), shrink);
    assert_golden(&x, 29.93290302157402, 0.46770160971209407);
    let x = sample(&Ddim::new(&s, 50, 0.5).unwrap(), shrink);
    assert_golden(&x, 31.20043659210205, 0.48750682175159454);
}

#[test]
fn ddim_with_a_perfect_model_ends_exactly_at_the_target() {
    // The last DDIM step has ᾱ_prev = 1, so σ = 0, √(1 − ᾱ_prev − σ²) = 0 and x_0 = 1·x̂0 + 0·x_t.
    let s = NoiseSchedule::default();
    for (k, eta) in [(50, 0.0), (7, 0.0), (50, 0.5), (1000, 1.0)] {
        let x = sample(&Ddim::new(&s, k, eta).unwrap(), |_, _| target());
        assert_eq!(x, target(), "K = {k}, eta = {eta}");
    }
}

#[test]
fn ddpm_with_a_perfect_model_ends_at_the_target() {
    // At t = 0: ᾱ_prev = 1 so c2 = (1 − 1)·√α_0/(1 − ᾱ_0) = 0 and σ_0 = 0 exactly, while
    // c1 = β_0/(1 − ᾱ_0) = β_0/(1 − (1 − β_0)) = 1 up to ~1e-12, which f32 rounding absorbs.
    let x = sample(&Ddpm::new(&NoiseSchedule::default()), |_, _| target());
    assert_eq!(x, target());
}

#[test]
fn noised_conditioning_keeps_known_entries_on_the_forward_process() {
    // Paper Eq. 7.6: after each step the first half (known) is set to q(x_prev | x_obs).
    let s = NoiseSchedule::default();
    let sampler = Ddim::new(&s, 50, 0.5).unwrap();
    let obs = target();
    let known = N / 2;
    let mut rng = Lcg(7);
    let mut x = rng.noise();
    let mut out = vec![0.0; N];
    for (i, &t) in sampler.timesteps().iter().enumerate() {
        let x0_pred = shrink(&x, t);
        let z = if sampler.needs_noise(i).unwrap() { Some(rng.noise()) } else { None };
        sampler.step(i, &x0_pred, &x, z.as_deref(), &mut out).unwrap();
        let (q, z_known) = (sampler.q_prev(i).unwrap(), rng.noise());
        for k in 0..known {
            out[k] = q.q_sample(f64::from(obs[k]), f64::from(z_known[k])) as f32;
        }
        std::mem::swap(&mut x, &mut out);
        if i == 0 {
            // Landed on t = 979: known entries are √ᾱ_979·x_obs + √(1 − ᾱ_979)·z.
            let ab = s.alpha_bars()[979];
            let expect = ab.sqrt() * f64::from(obs[3]) + (1.0 - ab).sqrt() * f64::from(z_known[3]);
            assert!((f64::from(x[3]) - expect).abs() < 1e-6);
        }
    }
    assert_eq!(x[..known], obs[..known]); // q(x_0 | x_obs) is x_obs itself
    assert_golden(&x[known..], 15.501690477132797, 0.4844278274103999);
}
