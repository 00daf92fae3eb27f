//! `socdiff bench train` and `socdiff bench sample`: seconds per training or denoising step and
//! peak memory — our numbers only. The PyTorch twin is compared in the same session on the same
//! machine by `scripts/bench_vs_torch.sh`, never against figures from another machine.

use clap::Subcommand;
use socdiff_engine::forecast::{self, SamplerKind};
use socdiff_engine::model::profile::{load_average, median_and_range, UsageMeter};
use socdiff_engine::model::{Aggregator, DenoiserConfig, K3Conv, Kernels, Precision};
use socdiff_engine::{features, train, Error, Result};
use std::time::Instant;

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Forecasting quality: train the recommended recipe for --minutes, forecast MuPoTS test
    /// windows (1 s observed, 3 s forecast, K = 8) and score them with the baselines (MPJPE at
    /// 1/2/3 s, NDMS, first-frame jump); quality.json keyed by protocol, method and horizon.
    Quality(crate::quality_cmd::QualityArgs),
    /// Seconds per training step (forward, backward, Adam, EMA) on random data, and peak RSS.
    Train {
        /// U-Net widths to time (comma-separated).
        #[arg(long, value_delimiter = ',', default_value = "128,256")]
        hidden: Vec<usize>,
        /// Windows per batch.
        #[arg(long, default_value_t = 16)]
        batch: usize,
        /// Persons per window.
        #[arg(long, default_value_t = 3)]
        persons: usize,
        /// Frames per window.
        #[arg(long, default_value_t = 256)]
        frames: usize,
        /// Joints per person (19: Panoptic, δ = 61).
        #[arg(long, default_value_t = 19)]
        joints: usize,
        /// Timed steps per width (after one warm-up step).
        #[arg(long, default_value_t = 3)]
        steps: usize,
        /// Aggregator: none, mean or attention (4 heads).
        #[arg(long, value_enum, default_value = "mean")]
        aggregator: Aggregator,
        /// Worker threads (default: RAYON_NUM_THREADS, else one per CPU).
        #[arg(long)]
        threads: Option<usize>,
        /// Also print where a step's time goes: each phase (forward + loss, backward, Adam,
        /// EMA) and each custom op (convolution forward and backward, LayerNorm, SiLU,
        /// upsampling, bmm), per step.
        #[arg(long)]
        profile: bool,
        #[command(flatten)]
        device: crate::DeviceArg,
        /// Precision of the convolutions' products: f32, or bf16 (GPUs; f32 master weights and
        /// loss).
        #[arg(long, default_value = "f32", value_parser = crate::parse_engine::<Precision>)]
        precision: Precision,
        /// Algorithms of the CPU kernels' stride-1 k3 convs to time, comma-separated: winograd
        /// (F(2, 3)), direct (one gemm).
        #[arg(long, value_enum, value_delimiter = ',', default_value = "winograd", hide_possible_values = true)]
        k3_conv: Vec<K3Conv>,
    },
    /// Seconds per denoising step and peak RSS of forecasting one scene (forward-only network,
    /// random weights), and the wall time of whole minute-long forecasts with DDIM and DDPM.
    Sample {
        /// U-Net widths to time (comma-separated).
        #[arg(long, value_delimiter = ',', default_value = "128,256")]
        hidden: Vec<usize>,
        /// Person counts to time (comma-separated).
        #[arg(long, value_delimiter = ',', default_value = "3,7")]
        persons: Vec<usize>,
        /// Observed frames of the canvas.
        #[arg(long, default_value_t = 128)]
        observe: usize,
        /// Forecast frames of the canvas (1800 = one minute at 30 fps).
        #[arg(long, default_value_t = 1800)]
        horizon: usize,
        /// Joints per person (19: Panoptic, δ = 61; 17: MuPoTS).
        #[arg(long, default_value_t = 19)]
        joints: usize,
        /// Timed denoising steps per configuration (after one warm-up step).
        #[arg(long, default_value_t = 5)]
        steps: usize,
        /// Aggregator: none, mean or attention (4 heads).
        #[arg(long, value_enum, default_value = "mean")]
        aggregator: Aggregator,
        /// Widths at which to run whole forecasts (comma-separated).
        #[arg(long, value_delimiter = ',', default_value = "128")]
        forecast_hidden: Vec<usize>,
        /// Skip the whole forecasts.
        #[arg(long)]
        no_forecast: bool,
        /// Persons of the whole forecasts.
        #[arg(long, default_value_t = 3)]
        forecast_persons: usize,
        /// DDIM steps of the first whole forecast (η = 0).
        #[arg(long, default_value_t = 50)]
        ddim_steps: usize,
        /// Skip the DDPM forecast (all T = 1000 steps of the default schedule).
        #[arg(long)]
        no_ddpm: bool,
        /// Algorithms of the CPU route's stride-1 k3 convs to time, comma-separated: winograd
        /// (F(2, 3)), direct (one gemm).
        #[arg(long, value_enum, value_delimiter = ',', default_value = "winograd", hide_possible_values = true)]
        k3_conv: Vec<K3Conv>,
        /// Worker threads (default: RAYON_NUM_THREADS, else one per CPU).
        #[arg(long)]
        threads: Option<usize>,
        #[command(flatten)]
        device: crate::DeviceArg,
    },
}

/// The profile of `steps` steps (warm-up included): phases, then custom ops, by time.
fn print_profile(rows: &[(&'static str, f64, u64)], steps: usize) {
    if rows.is_empty() {
        return;
    }
    let step: f64 = rows.iter().filter(|r| r.0.starts_with("step: ")).map(|r| r.1).sum();
    let mut sorted = rows.to_vec();
    sorted.sort_by(|a, b| b.0.starts_with("step: ").cmp(&a.0.starts_with("step: ")).then(b.1.total_cmp(&a.1)));
    println!("        {:<26} {:>10} {:>10} {:>8}", "phase / custom op", "ms/step", "calls/step", "% step");
    for (name, secs, calls) in sorted {
        println!("        {name:<26} {:>10.1} {:>10.1} {:>7.1}%", secs * 1e3 / steps as f64, calls as f64 / steps as f64, 100.0 * secs / step.max(1e-12));
    }
}

pub fn run(cmd: BenchCommand) -> Result<std::process::ExitCode> {
    if let BenchCommand::Quality(args) = cmd {
        return crate::quality_cmd::run(args);
    }
    run_speed(cmd).map(|()| std::process::ExitCode::SUCCESS)
}

/// Sizes rayon's global pool (before any parallel work of this process).
fn set_threads(threads: Option<usize>) -> Result<()> {
    match threads {
        Some(n) => socdiff_engine::model::runtime::set_worker_threads(n).map_err(|e| Error::invalid(format!("--threads: {e}"))),
        None => Ok(()),
    }
}

fn run_speed(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Quality(_) => unreachable!("handled by run"),
        BenchCommand::Train { hidden, batch, persons, frames, joints, steps, aggregator: agg, threads, profile, device, precision, k3_conv } => {
            set_threads(threads)?;
            let placement = device.device.placement(precision)?;
            let d = features::feature_dim(joints);
            if cfg!(debug_assertions) {
                eprintln!("note: a debug build; timings are only meaningful with --release");
            }
            if !matches!(placement.kernels, Kernels::Custom(_)) && k3_conv.iter().any(|&k| k != K3Conv::default()) {
                return Err(Error::invalid("--k3-conv chooses among the CPU kernels' algorithms; composed kernels run candle's conv"));
            }
            println!(
                "training step: {batch} windows × {persons} persons × {frames} frames (δ = {d}), aggregator {}, forward + backward + Adam + EMA, on {}",
                agg.name(),
                placement.describe()
            );
            println!(
                "{:>6}  {:>10}  {:>8}  {:>9}  {:>16}  {:>10}  {:>9}  {:>7}  {:>10}",
                "hidden", "params", "k3 conv", "s/step", "min–max", "CPU s/step", "peak RSS", "threads", "last loss"
            );
            for h in hidden {
                if h == 0 {
                    return Err(Error::invalid("--hidden: widths must be positive"));
                }
                for &k3 in &k3_conv {
                    let cfg = DenoiserConfig { feature_dims: d, hidden: h, social_dim: h, aggregator: agg, ..Default::default() };
                    let meter = UsageMeter::start();
                    if profile {
                        socdiff_engine::model::profile::enable();
                    }
                    let t = train::time_train_steps(&cfg, batch, persons, frames, steps, &placement.clone().with_k3_conv(k3))?;
                    let profiled = if profile { socdiff_engine::model::profile::take() } else { Vec::new() };
                    let usage = meter.read();
                    let (cpu, peak) = (usage.cpu_seconds / (steps + 1) as f64, usage.peak_gb());
                    let (median, lo, hi) = median_and_range(&t.seconds);
                    let last = t.losses.last().copied().unwrap_or(f32::NAN);
                    println!(
                        "{h:>6}  {:>10}  {:>8}  {median:>9.3}  {:>16}  {cpu:>10.3}  {peak:>9}  {:>7}  {last:>10.6}",
                        t.params,
                        k3.name(),
                        format!("{lo:.3}–{hi:.3}"),
                        t.threads
                    );
                    print_profile(&profiled, steps + 1);
                }
            }
            println!("s/step: median of the timed steps; CPU s/step: CPU time of all threads per step, warm-up included (≈ threads × s/step when the cores are free); peak RSS: VmHWM of this process during that width (* = not resettable, the peak of the whole process); last loss: of the last timed step (seeded: compare precisions after the same steps)");
            println!("load average (1 min) at the end: {}", load_average());
            Ok(())
        }
        BenchCommand::Sample {
            hidden,
            persons,
            observe,
            horizon,
            joints,
            steps,
            aggregator: agg,
            forecast_hidden,
            no_forecast,
            forecast_persons,
            ddim_steps,
            no_ddpm,
            k3_conv,
            threads,
            device,
        } => {
            set_threads(threads)?;
            let device = device.device.resolve()?;
            let d = features::feature_dim(joints);
            if cfg!(debug_assertions) {
                eprintln!("note: a debug build; timings are only meaningful with --release");
            }
            if hidden.iter().chain(&forecast_hidden).any(|&h| h == 0) || persons.contains(&0) {
                return Err(Error::invalid("--hidden and --persons must be positive"));
            }
            let config = |h: usize| DenoiserConfig { feature_dims: d, hidden: h, social_dim: h, aggregator: agg, ..Default::default() };
            println!(
                "denoising step: 1 scene × ({observe} observed + {horizon} forecast) frames, δ = {d}, aggregator {}, {steps} timed steps, on {}, {} threads",
                agg.name(),
                socdiff_engine::sample::SamplingNet::describe_route(&device),
                socdiff_engine::model::runtime::worker_threads()
            );
            if !device.is_cpu() && k3_conv.iter().any(|&k| k != K3Conv::default()) {
                return Err(Error::invalid("--k3-conv chooses among the CPU route's algorithms; on a GPU candle's conv runs"));
            }
            println!("{:>6}  {:>7}  {:>8}  {:>8}  {:>13}  {:>10}  {:>8}", "hidden", "persons", "k3 conv", "s/step", "min–max", "CPU s/step", "peak RSS");
            for &h in &hidden {
                for &p in &persons {
                    for &k3 in &k3_conv {
                        let net = forecast::random_sampling_net(&config(h), 0, &device, k3)?;
                        let meter = UsageMeter::start();
                        let t = forecast::time_sample_steps(net.x0_model(), p, observe, horizon, steps)?;
                        let usage = meter.read();
                        let (cpu, peak) = (usage.cpu_seconds / (steps + 1) as f64, usage.peak_gb());
                        let (median, lo, hi) = median_and_range(&t);
                        println!("{h:>6}  {p:>7}  {:>8}  {median:>8.3}  {:>13}  {cpu:>10.3}  {peak:>8}", k3.name(), format!("{lo:.3}–{hi:.3}"));
                    }
                }
            }
            println!("s/step: median over the timed steps (model call + sampler update); CPU s/step: CPU time of all threads per step (≈ 2 × s/step when both cores are free); peak RSS: VmHWM while sampling (* = not resettable)");
            println!("load average (1 min): {}", load_average());
            if no_forecast {
                return Ok(());
            }
            let skeleton = forecast::bench_skeleton(joints)?;
            let mut samplers = vec![SamplerKind::Ddim { steps: ddim_steps, eta: 0.0 }];
            if !no_ddpm {
                samplers.push(SamplerKind::Ddpm);
            }
            println!(
                "\nwhole forecast: {forecast_persons} persons, {observe} observed → {horizon} frames ({:.0} s at 30 fps), 1 sample, synthetic scene, as `socdiff forecast` runs it",
                horizon as f64 / 30.0
            );
            for &h in &forecast_hidden {
                let net = forecast::random_sampling_net(&config(h), 0, &device, K3Conv::default())?;
                for &sampler in &samplers {
                    let name = match sampler {
                        SamplerKind::Ddim { steps, .. } => format!("DDIM-{steps}"),
                        SamplerKind::Ddpm => "DDPM-1000".to_string(),
                    };
                    let start = Instant::now();
                    let mut last_report = Instant::now();
                    let fc = forecast::time_forecast(net.x0_model(), &skeleton, forecast_persons, observe, horizon, sampler, &mut |i| {
                        if last_report.elapsed().as_secs_f64() > 30.0 {
                            eprintln!("  {name}: step {}/{}", i.step + 1, i.steps);
                            last_report = Instant::now();
                        }
                    })?;
                    let wall = start.elapsed().as_secs_f64();
                    let (per, calls) = (fc.provenance.timings.seconds_per_step, fc.provenance.timings.model_calls);
                    println!("hidden {h:>4}, {name:>9}: {wall:.1} s wall ({calls} denoising steps, {per:.3} s/step; load average {})", load_average());
                }
            }
            Ok(())
        }
    }
}
