//! `socdiff forecast`, `socdiff complete` and `socdiff bench-sample`: sampling with a trained
//! denoiser by inpainting (see `socdiff_engine::forecast`).

use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use socdiff_engine::data::bvh::BvhImport;
use socdiff_engine::data::import::{self, ImportOptions};
use socdiff_engine::data::scene::Scene;
use socdiff_engine::forecast::{self, ForecastOptions, Missing, SamplerKind, Task};
use socdiff_engine::model::{Aggregator, DenoiserConfig};
use socdiff_engine::sample::Conditioning;
use socdiff_engine::train::checkpoint::{check_skeleton, Checkpoint, LoadedModel};
use socdiff_engine::{Error, Result};
use std::path::PathBuf;

/// Options shared by `forecast` and `complete`.
#[derive(Args)]
pub struct SampleArgs {
    /// Checkpoint: a run directory, its checkpoint.json or checkpoint.safetensors.
    #[arg(long)]
    model: PathBuf,
    /// Scene: a dataset directory (with --sequence), a .bvh or a Haggling .pkl.
    #[arg(long)]
    input: PathBuf,
    /// Sequence of a dataset directory (needed when it holds more than one).
    #[arg(long)]
    sequence: Option<String>,
    /// Persons of the scene to use, comma-separated indices (default: all).
    #[arg(long, value_delimiter = ',')]
    persons: Option<Vec<usize>>,
    /// Number of samples K.
    #[arg(long, default_value_t = 8)]
    samples: usize,
    /// Sampler: ddim (over --steps) or ddpm (ancestral, all T steps of the model).
    #[arg(long, default_value = "ddim", value_parser = ["ddim", "ddpm"])]
    sampler: String,
    /// DDIM steps.
    #[arg(long, default_value_t = 50)]
    steps: usize,
    /// DDIM η (0: deterministic given the initial noise).
    #[arg(long, default_value_t = 0.0)]
    eta: f64,
    /// How known entries are imposed: replace (clean values) or noised (paper Eq. 7.6).
    #[arg(long, default_value = "replace", value_parser = ["replace", "noised"])]
    conditioning: String,
    /// Seed; sample k uses a seed derived from (seed, k), independent of --samples.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output dataset directory (must not exist or be empty).
    #[arg(long)]
    out: PathBuf,
    /// BVH input: metres per file unit ("cmu" = 0.056444, "auto" guesses from body height).
    #[arg(long, default_value = "auto")]
    bvh_scale: String,
}

/// Options of `socdiff forecast`.
#[derive(Args)]
pub struct ForecastArgs {
    #[command(flatten)]
    common: SampleArgs,
    /// Observed frames (from the start of the scene); persons are anchored at the last one.
    #[arg(long, default_value_t = 128)]
    observe: usize,
    /// Frames to forecast after the observed ones.
    #[arg(long, default_value_t = 1800)]
    horizon: usize,
}

/// Options of `socdiff complete`.
#[derive(Args)]
pub struct CompleteArgs {
    #[command(flatten)]
    common: SampleArgs,
    /// What is missing: joints=NAME|INDEX,…  frames=a..b  persons=i,…
    #[arg(long)]
    missing: String,
}

/// Options of `socdiff bench-sample`.
#[derive(Args)]
pub struct BenchSampleArgs {
    /// U-Net widths to time (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "128,256")]
    hidden: Vec<usize>,
    /// Person counts to time (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "3,7")]
    persons: Vec<usize>,
    /// Canvas frames (observed + forecast).
    #[arg(long, default_value_t = 1800)]
    frames: usize,
    /// Joints per person (19: Panoptic, δ = 61).
    #[arg(long, default_value_t = 19)]
    joints: usize,
    /// Timed denoising steps per configuration (after one warm-up step).
    #[arg(long, default_value_t = 3)]
    steps: usize,
    /// Aggregator: none, mean or attention (4 heads).
    #[arg(long, default_value = "mean", value_parser = ["none", "mean", "attention"])]
    aggregator: String,
}

impl SampleArgs {
    fn import_options(&self) -> Result<ImportOptions> {
        let mut bvh = BvhImport::default();
        match self.bvh_scale.as_str() {
            "auto" => bvh.auto_scale = true,
            "cmu" => bvh.scale = socdiff_engine::data::bvh::CMU_SCALE,
            s => {
                bvh.scale = s
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite() && *v > 0.0)
                    .ok_or_else(|| Error::invalid(format!("--bvh-scale {s:?} is not a positive number, cmu or auto")))?;
            }
        }
        Ok(ImportOptions { bvh, ..Default::default() })
    }

    fn options(&self) -> Result<ForecastOptions> {
        if self.samples == 0 {
            return Err(Error::invalid("--samples must be at least 1"));
        }
        let sampler = match self.sampler.as_str() {
            "ddpm" => SamplerKind::Ddpm,
            _ => {
                if self.steps == 0 {
                    return Err(Error::invalid("--steps must be at least 1"));
                }
                if !(self.eta.is_finite() && self.eta >= 0.0) {
                    return Err(Error::invalid(format!("--eta must be finite and ≥ 0, got {}", self.eta)));
                }
                SamplerKind::Ddim { steps: self.steps, eta: self.eta }
            }
        };
        let conditioning = if self.conditioning == "noised" { Conditioning::Noised } else { Conditioning::Replace };
        Ok(ForecastOptions { samples: self.samples, sampler, conditioning, seed: self.seed })
    }

    /// The output must be writable: absent or an empty directory.
    fn check_out(&self) -> Result<()> {
        let out = &self.out;
        if out.exists() {
            let empty = out.is_dir() && std::fs::read_dir(out).map_err(|e| Error::io(out, e))?.next().is_none();
            if !empty {
                return Err(Error::format(out, "output exists and is not an empty directory; refusing to overwrite"));
            }
        }
        Ok(())
    }

    /// The scene to sample on: the chosen sequence and persons, at the model's frame rate.
    fn scene(&self, model: &LoadedModel) -> Result<Scene> {
        let ds = import::load(&self.input, &self.import_options()?)?;
        let scene = match &self.sequence {
            Some(name) => ds.scene(name)?.clone(),
            None if ds.sequences.len() == 1 => ds.sequences[0].scene.clone(),
            None => {
                let names: Vec<&str> = ds.sequences.iter().map(|s| s.scene.name.as_str()).collect();
                return Err(Error::invalid(format!(
                    "{} holds {} sequences; pick one with --sequence ({})",
                    self.input.display(),
                    names.len(),
                    names.join(", ")
                )));
            }
        };
        let scene = match &self.persons {
            Some(p) => scene.select_persons(p)?,
            None => scene,
        };
        check_skeleton(&model.meta, &model.path, &scene.skeleton)?;
        if (scene.fps - model.fps).abs() > 1e-6 * model.fps {
            eprintln!("resampling {} from {} fps to the model's {} fps", scene.name, scene.fps, model.fps);
            return scene.resample(model.fps);
        }
        Ok(scene)
    }
}

fn run_task(args: &SampleArgs, task: impl FnOnce(&Scene) -> Result<Task>) -> Result<()> {
    let opts = args.options()?;
    args.check_out()?;
    let model = Checkpoint::load(&args.model)?;
    let scene = args.scene(&model)?;
    let task = task(&scene)?;
    forecast::check_task(&scene, &task)?;
    let steps_per_sample = match opts.sampler {
        SamplerKind::Ddpm => model.diffusion.timesteps(),
        SamplerKind::Ddim { steps, .. } => steps,
    };
    let bar = ProgressBar::new((steps_per_sample * opts.samples) as u64);
    bar.set_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} denoising steps  {msg}  ETA {eta}").expect("valid template"),
    );
    let mut model_seconds = 0.0;
    let fc = forecast::sample_scene(&model.denoiser, model.diffusion.schedule(), &model.standardization, &scene, &task, &opts, &mut |i| {
        model_seconds += i.seconds;
        bar.set_message(format!("sample {}/{}  {:.3} s/step", i.sample + 1, opts.samples, i.seconds));
        bar.inc(1);
    })?;
    bar.finish_and_clear();
    let mut fc = fc;
    fc.provenance.insert("model".into(), model.path.display().to_string().into());
    fc.provenance.insert("model_step".into(), model.step.into());
    fc.provenance.insert("input".into(), args.input.display().to_string().into());
    if let Some(p) = &args.persons {
        fc.provenance.insert("persons".into(), p.clone().into());
    }
    let t = &fc.provenance["timings"];
    let total = t["total_seconds"].as_f64().unwrap_or(0.0);
    let per = t["seconds_per_step"].as_f64().unwrap_or(0.0);
    fc.write(&args.out)?;
    println!(
        "{} samples × {} steps of {} ({} frames, {} persons): {:.3} s per step, {:.1} s total → {}",
        opts.samples,
        steps_per_sample,
        scene.name,
        fc.samples[0].num_frames(),
        scene.num_persons(),
        per,
        total,
        args.out.display()
    );
    Ok(())
}

/// `socdiff forecast`.
pub fn run_forecast(args: ForecastArgs) -> Result<()> {
    let (observe, horizon) = (args.observe, args.horizon);
    run_task(&args.common, |_| Ok(Task::Forecast { observe, horizon }))
}

/// `socdiff complete`.
pub fn run_complete(args: CompleteArgs) -> Result<()> {
    let spec = args.missing.clone();
    run_task(&args.common, |scene| Ok(Task::Complete(Missing::parse(&spec, &scene.skeleton)?)))
}

/// Peak resident set in bytes (Linux `VmHWM`).
fn peak_rss() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = text.lines().find(|l| l.starts_with("VmHWM"))?;
    Some(line.split_whitespace().nth(1)?.parse::<u64>().ok()? * 1024)
}

/// PyTorch reference on the project's 2-core machine: (hidden, persons, seconds per step).
const PYTORCH: [(usize, usize, &str); 4] = [(128, 3, "0.155–0.185 s"), (128, 7, "0.35 s"), (256, 3, "0.50 s"), (256, 7, "1.12–1.18 s")];

/// `socdiff bench-sample`: seconds per denoising step (forecast inpainting, 1 scene) and peak
/// RSS, on a random frozen network.
pub fn run_bench(args: BenchSampleArgs) -> Result<()> {
    let agg = match args.aggregator.as_str() {
        "none" => Aggregator::None,
        "mean" => Aggregator::Mean,
        _ => Aggregator::Attention { heads: 4 },
    };
    let dim = socdiff_engine::features::feature_dim(args.joints);
    println!("denoising step: 1 scene × {} frames, δ = {dim}, aggregator {}, {} timed steps", args.frames, args.aggregator, args.steps);
    for &h in &args.hidden {
        let cfg = DenoiserConfig { feature_dims: dim, hidden: h, social_dim: h, aggregator: agg, ..Default::default() };
        for &p in &args.persons {
            let per = forecast::time_sample_steps(&cfg, p, args.frames, args.steps)?;
            let reference = PYTORCH.iter().find(|r| r.0 == h && r.1 == p).map(|r| r.2).unwrap_or("—");
            let rss = peak_rss().map(|b| format!("{:.2} GB", b as f64 / 1e9)).unwrap_or_else(|| "n/a".into());
            println!("hidden {h:>4}, {p} persons: {per:.3} s/step, peak RSS {rss} (PyTorch: {reference})");
        }
    }
    Ok(())
}
