//! How a model denoises, level by level: for recorded windows noised to level t, the error of
//! its x̂0 and how rough x̂0 is (RMS frame-to-frame change, standardized units) against the
//! clean window; then DDIM (50 steps, η = 0) from pure noise with nothing known, one
//! person, and what its scenes look like (median root speed, largest frame-to-frame joint
//! move). With a second model, DDIM from noise is also run switching to it below a level
//! (the first model above, the second below), to tell which levels make a sample rough.
//!
//! `cargo run --release --example denoising_by_level -- RUN DATASET SEQ[,SEQ…] [LOW_NOISE_RUN]`
//! e.g. `… -- runs/bandai-30-v ../shared/data/bandai2 dataset-2_walk_normal_001,dataset-2_run_active_001`

use ndarray::Array3;
use rand::rngs::StdRng;
use rand::SeedableRng;
use socdiff::data::import::{load_sequence, ImportOptions};
use socdiff::diffusion::standard_normal;
use socdiff::features::{Anchor, PoseFeatures};
use socdiff::forecast::Model;
use socdiff::metrics::distance::{largest_frame_step, mean_root_speed};
use socdiff::sample::X0Model;
use socdiff::schedules::{Ddim, Sampler};
use socdiff::{bail, Result};

/// Frames of every window (bandai2's shortest runs have 68).
const FRAMES: usize = 64;
/// Scenes drawn from noise per row.
const SCENES: usize = 16;
/// Placement of the one person: at the origin, facing +x.
const AT_ORIGIN: [f32; 4] = [0.0, 0.0, 1.0, 0.0];

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        bail!("usage: denoising_by_level RUN DATASET SEQ[,SEQ…] [LOW_NOISE_RUN]");
    }
    let model = Model::load(&args[0])?;
    let low = args.get(3).map(Model::load).transpose()?;
    let m = &model.checkpoint;
    let dim = m.standardization.dim();
    let shape = [1, 1, FRAMES, dim];

    // Clean windows: frames 0..64 of each sequence, standardized, `[T, δ]` flattened.
    let mut windows = Vec::new();
    for name in args[2].split(',') {
        let scene = load_sequence(args[1].as_ref(), Some(name), &ImportOptions::default())?;
        let mut f = PoseFeatures::encode_as(&scene, 0..FRAMES, &[0], model.anchor_frame(FRAMES), m.config.pose)?;
        m.standardization.apply(&mut f.data)?;
        windows.push(f.data.iter().copied().collect::<Vec<f32>>());
    }
    let rough = |x: &[f32]| roughness(x, dim);
    let schedule = m.diffusion.schedule();
    println!(
        "recorded windows noised to level t (4 noise draws each); inputs' roughness {:.3}",
        windows.iter().map(|w| rough(w)).sum::<f64>() / windows.len() as f64
    );
    println!("{:>5} {:>7} {:>11} {:>11}", "t", "√ᾱ", "x̂0 RMS err", "x̂0 rough");
    for t in [999, 900, 800, 600, 400, 200, 100, 50, 20, 0] {
        let q = schedule.q(t)?;
        let (mut err, mut rg, mut n) = (0.0, 0.0, 0.0);
        let mut x0_hat = vec![0f32; FRAMES * dim];
        for (w, x0) in windows.iter().enumerate() {
            for draw in 0..4 {
                let eps = standard_normal(&mut StdRng::seed_from_u64(100 * w as u64 + draw), x0.len());
                let xt: Vec<f32> = x0.iter().zip(&eps).map(|(&a, &e)| (q.signal * a as f64 + q.noise * e as f64) as f32).collect();
                model.net().predict_x0(&xt, shape, &[t], Some(&AT_ORIGIN), &mut x0_hat)?;
                err += x0_hat.iter().zip(x0).map(|(a, b)| ((a - b) as f64).powi(2)).sum::<f64>() / x0.len() as f64;
                rg += rough(&x0_hat);
                n += 1.0;
            }
        }
        println!("{t:>5} {:>7.4} {:>11.3} {:>11.3}", q.signal, (err / n).sqrt(), rg / n);
    }

    let sampler = Ddim::new(schedule, 50, 0.0)?;
    let switches: Vec<usize> = if low.is_some() { vec![1000, 600, 400, 200, 100, 0] } else { vec![0] };
    println!("\nDDIM 50 from N(0, I), {SCENES} scenes of {FRAMES} frames, one person");
    for below in switches {
        let (mut speeds, mut moves, mut rg) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..SCENES {
            let mut x = standard_normal(&mut StdRng::seed_from_u64(k as u64), FRAMES * dim);
            let (mut x0_hat, mut next) = (vec![0f32; x.len()], vec![0f32; x.len()]);
            for (i, &t) in sampler.timesteps().iter().enumerate() {
                let net: &dyn X0Model = match &low {
                    Some(low) if t < below => low.net(),
                    _ => model.net(),
                };
                net.predict_x0(&x, shape, &[t], Some(&AT_ORIGIN), &mut x0_hat)?;
                sampler.coefficients(i)?.apply(&x0_hat, &x, None, &mut next)?;
                std::mem::swap(&mut x, &mut next);
            }
            rg.push(rough(&x));
            let mut data = Array3::from_shape_vec((1, FRAMES, dim), x).expect("shape").permuted_axes([1, 0, 2]).as_standard_layout().into_owned();
            m.standardization.invert(&mut data)?;
            let pos = PoseFeatures::with_encoding(data, vec![Anchor { root: [0.0, 0.0], heading: 0.0 }], None)?.to_positions()?;
            speeds.push(mean_root_speed(pos.view(), m.skeleton.left, m.skeleton.right, m.fps)?);
            moves.push(1e3 * largest_frame_step(pos.view()));
        }
        let label = match &low {
            Some(_) => format!("second model below t = {below}"),
            None => "this model".into(),
        };
        println!("{label:<28} root speed {:.2} m/s, largest move {:.0} mm, roughness {:.3} (medians)", median(speeds), median(moves), median(rg));
    }
    Ok(())
}

/// RMS frame-to-frame change of `[T, δ]` features.
fn roughness(x: &[f32], dim: usize) -> f64 {
    let steps = x.len() / dim - 1;
    let sum: f64 = (dim..x.len()).map(|k| ((x[k] - x[k - dim]) as f64).powi(2)).sum();
    (sum / (steps * dim) as f64).sqrt()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}
