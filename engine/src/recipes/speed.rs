//! Speed benchmarks (`socdiff bench train|sample`): seconds per training or denoising step and
//! peak memory, on random data and weights — our numbers only. The PyTorch twin is compared in
//! the same run on the same machine by `scripts/bench_vs_torch.sh`, never against figures
//! from another machine. Each job writes its table line by line through `say`.

use crate::data::Skeleton;
use crate::features::{PoseEncoding, PoseFeatures, Standardization};
use crate::forecast::{sample_scene, Denoising, Forecast, ForecastOutput, SamplerKind, StepInfo, Task};
use crate::model::profile::{self, load_average, median_and_range, UsageMeter};
use crate::model::{Aggregator, Denoiser, DenoiserConfig, DeviceArg, K3Conv, Kernels, Precision};
use crate::sample::{inpaint_with_progress, InpaintOptions, Known, SamplingNet, X0Model};
use crate::{bail, features, train, Result};
use ndarray::{Array2, Array3};
use socdiff_schedules::{Ddim, NoiseSchedule};
use std::time::Instant;

/// Seconds per training step (forward, backward, Adam, EMA) on random data, and peak RSS.
#[derive(Clone, Debug)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct TrainSpeed {
    /// U-Net widths to time (comma-separated).
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ',', default_value = "128,256"))]
    pub hidden: Vec<usize>,
    /// Windows per batch.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 16))]
    pub batch: usize,
    /// Persons per window.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 3))]
    pub persons: usize,
    /// Frames per window.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 256))]
    pub frames: usize,
    /// Joints per person (19: Panoptic, δ = 61).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 19))]
    pub joints: usize,
    /// Timed steps per width (after one warm-up step).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 3))]
    pub steps: usize,
    /// Aggregator: none, mean or attention (4 heads).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "mean"))]
    pub aggregator: Aggregator,
    /// Worker threads (default: RAYON_NUM_THREADS, else one per CPU).
    #[cfg_attr(feature = "clap", arg(long))]
    pub threads: Option<usize>,
    /// Also print where a step's time goes: each phase (forward + loss, backward, Adam,
    /// EMA) and each custom op (convolution forward and backward, LayerNorm, SiLU,
    /// upsampling, bmm), per step.
    #[cfg_attr(feature = "clap", arg(long))]
    pub profile: bool,
    #[cfg_attr(feature = "clap", command(flatten))]
    pub device: DeviceArg,
    /// Precision of the convolutions' products: f32, or bf16 (GPUs; f32 master weights and
    /// loss).
    #[cfg_attr(feature = "clap", arg(long, default_value = "f32"))]
    pub precision: Precision,
    /// Algorithms of the CPU kernels' stride-1 k3 convs to time, comma-separated: winograd
    /// (F(2, 3)), direct (one gemm).
    #[cfg_attr(feature = "clap", arg(long, value_enum, value_delimiter = ',', default_value = "winograd", hide_possible_values = true))]
    pub k3_conv: Vec<K3Conv>,
}

/// Seconds per denoising step and peak RSS of forecasting one scene (forward-only network,
/// random weights), and the wall time of whole minute-long forecasts with DDIM and DDPM.
#[derive(Clone, Debug)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct SampleSpeed {
    /// U-Net widths to time (comma-separated).
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ',', default_value = "128,256"))]
    pub hidden: Vec<usize>,
    /// Person counts to time (comma-separated).
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ',', default_value = "3,7"))]
    pub persons: Vec<usize>,
    /// Observed frames of the canvas.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 128))]
    pub observe: usize,
    /// Forecast frames of the canvas (1800 = one minute at 30 fps).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 1800))]
    pub horizon: usize,
    /// Joints per person (19: Panoptic, δ = 61; 17: MuPoTS).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 19))]
    pub joints: usize,
    /// Timed denoising steps per configuration (after one warm-up step).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 5))]
    pub steps: usize,
    /// Aggregator: none, mean or attention (4 heads).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "mean"))]
    pub aggregator: Aggregator,
    /// Widths at which to run whole forecasts (comma-separated).
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ',', default_value = "128"))]
    pub forecast_hidden: Vec<usize>,
    /// Skip the whole forecasts.
    #[cfg_attr(feature = "clap", arg(long))]
    pub no_forecast: bool,
    /// Persons of the whole forecasts.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 3))]
    pub forecast_persons: usize,
    /// DDIM steps of the first whole forecast (η = 0).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 50))]
    pub ddim_steps: usize,
    /// Skip the DDPM forecast (all T = 1000 steps of the default schedule).
    #[cfg_attr(feature = "clap", arg(long))]
    pub no_ddpm: bool,
    /// Algorithms of the CPU route's stride-1 k3 convs to time, comma-separated: winograd
    /// (F(2, 3)), direct (one gemm).
    #[cfg_attr(feature = "clap", arg(long, value_enum, value_delimiter = ',', default_value = "winograd", hide_possible_values = true))]
    pub k3_conv: Vec<K3Conv>,
    /// Worker threads (default: RAYON_NUM_THREADS, else one per CPU).
    #[cfg_attr(feature = "clap", arg(long))]
    pub threads: Option<usize>,
    #[cfg_attr(feature = "clap", command(flatten))]
    pub device: DeviceArg,
}

/// Sizes rayon's global pool (before any parallel work of this process).
fn set_threads(threads: Option<usize>) -> Result<()> {
    match threads {
        Some(n) => crate::model::runtime::set_worker_threads(n).map_err(|e| crate::Error::invalid(format!("`threads`: {e}"))),
        None => Ok(()),
    }
}

fn warn_debug(say: &mut dyn FnMut(&str)) {
    if cfg!(debug_assertions) {
        say("note: a debug build; timings are only meaningful with --release");
    }
}

/// The profile of `steps` timed steps: phases, then custom ops, by time; GF/s of the matrix
/// products counted in each (2 flops per multiply-add).
fn profile_table(rows: &[profile::OpTotal], steps: usize, say: &mut dyn FnMut(&str)) {
    if rows.is_empty() {
        return;
    }
    let step: f64 = rows.iter().filter(|r| r.name.starts_with("step: ")).map(|r| r.seconds).sum();
    let mut sorted = rows.to_vec();
    sorted.sort_by(|a, b| b.name.starts_with("step: ").cmp(&a.name.starts_with("step: ")).then(b.seconds.total_cmp(&a.seconds)));
    say(&format!("        {:<26} {:>10} {:>10} {:>8} {:>10} {:>8}", "phase / custom op", "ms/step", "calls/step", "% step", "GF/step", "GF/s"));
    for r in sorted {
        let gf = 2.0 * r.multiply_adds as f64 / 1e9;
        let (gf_step, rate) =
            if r.multiply_adds > 0 { (format!("{:.2}", gf / steps as f64), format!("{:.0}", gf / r.seconds.max(1e-12))) } else { ("".into(), "".into()) };
        say(&format!(
            "        {:<26} {:>10.1} {:>10.1} {:>7.1}% {gf_step:>10} {rate:>8}",
            r.name,
            r.seconds * 1e3 / steps as f64,
            r.calls as f64 / steps as f64,
            100.0 * r.seconds / step.max(1e-12)
        ));
    }
}

/// This machine's f32 matrix-product throughput through the gemm crate on every worker thread:
/// GF/s of the median of five 1536 × 1536 × 1536 products (after one warm-up), the ceiling of
/// a step made of products.
fn product_roof() -> f64 {
    const N: usize = 1536;
    let (a, b) = (vec![0.5f32; N * N], vec![0.25f32; N * N]);
    let mut c = vec![0f32; N * N];
    let threads = crate::model::runtime::worker_threads();
    let mut seconds = Vec::with_capacity(5);
    for i in 0..6 {
        let start = Instant::now();
        // SAFETY: three N × N row-major matrices, c apart from a and b.
        unsafe {
            gemm::gemm(
                N,
                N,
                N,
                c.as_mut_ptr(),
                1,
                N as isize,
                false,
                a.as_ptr(),
                1,
                N as isize,
                b.as_ptr(),
                1,
                N as isize,
                1.0,
                1.0,
                false,
                false,
                false,
                gemm::Parallelism::Rayon(threads),
            );
        }
        if i > 0 {
            seconds.push(start.elapsed().as_secs_f64());
        }
    }
    std::hint::black_box(&c);
    2.0 * (N * N * N) as f64 / median_and_range(&seconds).0 / 1e9
}

/// `x` > 0 with two decimals, or more below 1 so that three significant figures show.
fn three_figures(x: f64) -> String {
    let decimals = (2 - x.log10().floor() as i32).max(2) as usize;
    format!("{x:.decimals$}")
}

fn say_roof(say: &mut dyn FnMut(&str)) {
    say(&format!("f32 product roof of this machine: {:.0} GF/s (1536³ gemm, {} threads)", product_roof(), crate::model::runtime::worker_threads()));
}

impl TrainSpeed {
    /// Times every width × k3 algorithm; the table goes to `say`, notes to `note`.
    pub fn run(&self, say: &mut dyn FnMut(&str), note: &mut dyn FnMut(&str)) -> Result<()> {
        set_threads(self.threads)?;
        let placement = self.device.device.placement(self.precision)?;
        let d = features::feature_dim(self.joints);
        warn_debug(note);
        if !matches!(placement.kernels, Kernels::Custom(_)) && self.k3_conv.iter().any(|&k| k != K3Conv::default()) {
            bail!("`k3_conv` chooses among the CPU kernels' algorithms; composed kernels run candle's conv");
        }
        let (batch, persons, frames, steps) = (self.batch, self.persons, self.frames, self.steps);
        say(&format!(
            "training step: {batch} windows × {persons} persons × {frames} frames (δ = {d}), aggregator {}, forward + backward + Adam + EMA, on {}",
            self.aggregator.name(),
            placement.describe()
        ));
        say(&format!(
            "{:>6}  {:>10}  {:>8}  {:>9}  {:>16}  {:>10}  {:>9}  {:>7}  {:>10}",
            "hidden", "params", "k3 conv", "s/step", "min–max", "CPU s/step", "peak RSS", "threads", "last loss"
        ));
        for &h in &self.hidden {
            if h == 0 {
                bail!("`hidden`: widths must be positive");
            }
            for &k3 in &self.k3_conv {
                let cfg = DenoiserConfig { feature_dims: d, hidden: h, social_dim: h, aggregator: self.aggregator, ..Default::default() };
                let meter = UsageMeter::start();
                if self.profile {
                    profile::enable();
                }
                let t = train::time_train_steps(&cfg, batch, persons, frames, steps, &placement.clone().with_k3_conv(k3))?;
                let profiled = if self.profile { profile::take() } else { Vec::new() };
                let usage = meter.read();
                let (cpu, peak) = (usage.cpu_seconds / (steps + 1) as f64, usage.peak_gb());
                let (median, lo, hi) = median_and_range(&t.seconds);
                let last = t.losses.last().copied().unwrap_or(f32::NAN);
                let range = format!("{lo:.3}–{hi:.3}");
                say(&format!("{h:>6}  {:>10}  {:>8}  {median:>9.3}  {range:>16}  {cpu:>10.3}  {peak:>9}  {:>7}  {last:>10.6}", t.params, k3.name(), t.threads));
                profile_table(&profiled, steps, say);
            }
        }
        say("s/step: median of the timed steps; CPU s/step: CPU time of all threads per step, warm-up included (≈ threads × s/step when the cores are free); peak RSS: VmHWM of this process during that width (* = not resettable, the peak of the whole process); last loss: of the last timed step (seeded: compare precisions after the same steps)");
        if self.profile {
            say_roof(say);
        }
        say(&format!("load average (1 min) at the end: {}", load_average()));
        Ok(())
    }
}

impl SampleSpeed {
    /// Times every width × person count × k3 algorithm, then the whole forecasts; the table
    /// goes to `say`, a line every 30 s of a long forecast to `progress`.
    pub fn run(&self, say: &mut dyn FnMut(&str), progress: &mut dyn FnMut(&str)) -> Result<()> {
        set_threads(self.threads)?;
        let device = self.device.device.resolve()?;
        let (d, observe, horizon, steps) = (features::feature_dim(self.joints), self.observe, self.horizon, self.steps);
        warn_debug(progress);
        if self.hidden.iter().chain(&self.forecast_hidden).any(|&h| h == 0) || self.persons.contains(&0) {
            bail!("`hidden` and `persons` must be positive");
        }
        let config = |h: usize| DenoiserConfig { feature_dims: d, hidden: h, social_dim: h, aggregator: self.aggregator, ..Default::default() };
        say(&format!(
            "denoising step: 1 scene × ({observe} observed + {horizon} forecast) frames, δ = {d}, aggregator {}, {steps} timed steps, on {}, {} threads",
            self.aggregator.name(),
            crate::sample::SamplingNet::describe_route(&device),
            crate::model::runtime::worker_threads()
        ));
        if !device.is_cpu() && self.k3_conv.iter().any(|&k| k != K3Conv::default()) {
            bail!("`k3_conv` chooses among the CPU route's algorithms; on a GPU candle's conv runs");
        }
        say(&format!(
            "{:>6}  {:>7}  {:>8}  {:>8}  {:>13}  {:>10}  {:>8}  {:>7}  {:>6}",
            "hidden", "persons", "k3 conv", "s/step", "min–max", "CPU s/step", "peak RSS", "GF/step", "GF/s"
        ));
        for &h in &self.hidden {
            for &p in &self.persons {
                for &k3 in &self.k3_conv {
                    let net = random_sampling_net(&config(h), 0, &device, k3)?;
                    let meter = UsageMeter::start();
                    profile::enable();
                    let t = time_sample_steps(net.x0_model(), p, observe, horizon, steps);
                    // the warm-up step's products are counted too: steps + 1 model calls
                    let gf = 2.0 * profile::multiply_adds() as f64 / 1e9 / (steps + 1) as f64;
                    profile::take();
                    let t = t?;
                    let usage = meter.read();
                    let (cpu, peak) = (usage.cpu_seconds / (steps + 1) as f64, usage.peak_gb());
                    let (median, lo, hi) = median_and_range(&t);
                    let range = format!("{lo:.3}–{hi:.3}");
                    // (products on a GPU are candle's, not counted)
                    let (gf_step, rate) = if gf > 0.0 { (three_figures(gf), format!("{:.0}", gf / median)) } else { ("–".into(), "–".into()) };
                    say(&format!("{h:>6}  {p:>7}  {:>8}  {median:>8.3}  {range:>13}  {cpu:>10.3}  {peak:>8}  {gf_step:>7}  {rate:>6}", k3.name()));
                }
            }
        }
        say("s/step: median over the timed steps (model call + sampler update); CPU s/step: CPU time of all threads per step (≈ 2 × s/step when both cores are free); peak RSS: VmHWM while sampling (* = not resettable); GF/step: flops of the matrix products a model call runs (2 per multiply-add, Winograd counted as run); GF/s: GF/step over s/step");
        if device.is_cpu() {
            say_roof(say);
        }
        say(&format!("load average (1 min): {}", load_average()));
        if self.no_forecast {
            return Ok(());
        }
        let skeleton = bench_skeleton(self.joints)?;
        let mut samplers = vec![SamplerKind::Ddim { steps: self.ddim_steps, eta: 0.0 }];
        if !self.no_ddpm {
            samplers.push(SamplerKind::Ddpm);
        }
        let persons = self.forecast_persons;
        say(&format!(
            "\nwhole forecast: {persons} persons, {observe} observed → {horizon} frames ({:.0} s at 30 fps), 1 sample, synthetic scene, as `socdiff forecast` runs it",
            horizon as f64 / 30.0
        ));
        for &h in &self.forecast_hidden {
            let net = random_sampling_net(&config(h), 0, &device, K3Conv::default())?;
            for &sampler in &samplers {
                let name = match sampler {
                    SamplerKind::Ddim { steps, .. } => format!("DDIM-{steps}"),
                    SamplerKind::Ddpm => "DDPM-1000".to_string(),
                };
                let (start, mut last_report) = (Instant::now(), Instant::now());
                let fc = time_forecast(net.x0_model(), &skeleton, persons, observe, horizon, sampler, &mut |i| {
                    if last_report.elapsed().as_secs_f64() > 30.0 {
                        progress(&format!("  {name}: step {}/{}", i.step + 1, i.steps));
                        last_report = Instant::now();
                    }
                })?;
                let wall = start.elapsed().as_secs_f64();
                let (per, calls) = (fc.provenance.timings.seconds_per_step, fc.provenance.timings.model_calls);
                say(&format!("hidden {h:>4}, {name:>9}: {wall:.1} s wall ({calls} denoising steps, {per:.3} s/step; load average {})", load_average()));
            }
        }
        Ok(())
    }
}

/// A network with random weights (seeded) for benchmarks, as the sampling route of `device`
/// runs it (on the CPU the inference layout with `k3` for its stride-1 k3 convs; the candle
/// parameters it was built from are freed), with the default diffusion (x0 prediction).
pub fn random_sampling_net(cfg: &DenoiserConfig, seed: u64, device: &candle_core::Device, k3: K3Conv) -> Result<SamplingNet> {
    let diffusion = crate::diffusion::GaussianDiffusion::new(&crate::diffusion::DiffusionConfig::default())?;
    SamplingNet::with_k3_conv(&Denoiser::new(cfg.clone(), seed)?, &diffusion, device, k3)
}

/// The skeleton with `joints` joints (17: MuPoTS, 19: Panoptic) for synthetic benchmark scenes.
pub fn bench_skeleton(joints: usize) -> Result<Skeleton> {
    match joints {
        17 => Ok(Skeleton::mupots17()),
        19 => Ok(Skeleton::panoptic19()),
        j => bail!("bench: no built-in skeleton with {j} joints (17 or 19)"),
    }
}

/// Seconds per denoising step (model call plus sampler update) of forecast inpainting on one
/// synthetic scene of `persons` × (`observe` + `horizon`) frames: DDIM over `steps` + 1 steps,
/// the first (which allocates the workspace) not counted.
pub fn time_sample_steps(model: &dyn X0Model, persons: usize, observe: usize, horizon: usize, steps: usize) -> Result<Vec<f64>> {
    if steps == 0 || persons == 0 || observe == 0 || horizon == 0 {
        bail!("bench: steps, persons, observed and forecast frames must be at least 1");
    }
    let (frames, dim) = (observe + horizon, model.feature_dims());
    let values = Array3::<f32>::from_shape_fn((frames, persons, dim), |(f, q, d)| ((f + 3 * q + d) as f32 * 0.01).sin());
    let mask = crate::sample::forecast_mask(frames, persons, dim, observe);
    let anchors = Array2::<f32>::from_shape_fn((persons, 4), |(q, k)| [q as f32, 0.5 * q as f32, 1.0, 0.0][k]);
    let known = Known { values: values.view(), mask: mask.view(), anchors: Some(anchors.view()) };
    let sampler = Ddim::new(&NoiseSchedule::default(), steps + 1, 0.0)?;
    let mut marks = Vec::with_capacity(steps + 1);
    inpaint_with_progress(model, &sampler, &known, &InpaintOptions::default(), &mut |_| marks.push(Instant::now()))?;
    Ok(marks.windows(2).map(|w| (w[1] - w[0]).as_secs_f64()).collect())
}

/// A whole forecast (1 sample, `sampler`) of `horizon` frames after `observe` frames of a
/// synthetic scene of `persons` persons, as `socdiff forecast` runs it (canvas, sampling,
/// decoding); returns the forecast, whose provenance holds the timings.
pub fn time_forecast(
    model: &dyn X0Model,
    skeleton: &Skeleton,
    persons: usize,
    observe: usize,
    horizon: usize,
    sampler: SamplerKind,
    on_step: &mut dyn FnMut(StepInfo),
) -> Result<ForecastOutput> {
    // one frame more than observed: a forecast needs the scene to go on after them
    use rand::{Rng, SeedableRng};
    // Each joint at a fixed random offset from the root, swaying a little.
    let mut rng = rand::rngs::StdRng::seed_from_u64(1);
    let nj = skeleton.num_joints();
    let offsets: Vec<[f32; 3]> = (0..persons * nj).map(|_| [rng.gen_range(-0.3..0.3), rng.gen_range(-0.3..0.3), rng.gen_range(0.0..1.8)]).collect();
    let body = |f: usize, p: usize, out: &mut [f32]| {
        for (j, o) in out.chunks_exact_mut(3).enumerate() {
            let [x, y, z] = offsets[p * nj + j];
            o.copy_from_slice(&[x + 0.05 * (0.2 * f as f32 + j as f32).sin(), y, z]);
        }
    };
    let scene = crate::data::synthetic::circle_walkers(skeleton, observe + 1, persons, 30.0, 0.0, body)?;
    if crate::features::feature_dim(skeleton.num_joints()) != model.feature_dims() {
        bail!("bench: skeleton {} does not fit a model of {} feature dims", skeleton.name, model.feature_dims());
    }
    let feats = PoseFeatures::from_scene(&scene, observe - 1)?;
    let std = Standardization::fit([feats.data.view()])?;
    let schedule = NoiseSchedule::default();
    let denoising = Denoising { net: model, schedule: &schedule, standardization: &std, encoding: PoseEncoding::Absolute, clean_known: false };
    let req = Forecast { observe, horizon, samples: 1, sampler, seed: 1, ..Default::default() };
    sample_scene(&denoising, &scene, &Task::Forecast { observe, horizon }, &req, on_step)
}
