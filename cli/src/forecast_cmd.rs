//! `socdiff forecast` and `socdiff complete`: sampling with a trained denoiser by inpainting
//! (see `socdiff_engine::forecast`), on the forward-only network.

use socdiff_engine::data::import::SourceArgs;
use clap::{Args, ValueEnum};
use socdiff_engine::data::dataset::write_dataset;
use socdiff_engine::data::import;
use socdiff_engine::data::scene::Scene;
use socdiff_engine::data::{check_size, MAX_SAMPLES};
use socdiff_engine::files::check_output_dir;
use socdiff_engine::forecast::{self, ContextInversion, Forecast, Missing, Model, SamplerKind, Task};
use socdiff_engine::sample::Conditioning;
use socdiff_engine::train::checkpoint::Weights;
use socdiff_engine::{Error, Result};
use std::path::PathBuf;

/// Options shared by `forecast` and `complete`.
#[derive(Args)]
pub struct SampleArgs {
    /// Checkpoint: a run directory, its checkpoint.json or checkpoint.safetensors.
    #[arg(long)]
    model: PathBuf,
    #[command(flatten)]
    device: crate::DeviceArg,
    /// Weights of the checkpoint: ema (the moving average, usual for inference) or online (the
    /// optimizer's current weights; better early in training, while the average still lags).
    #[arg(long, value_enum, default_value = "ema")]
    weights: Weights,
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
    #[arg(long, value_enum, default_value = "ddim")]
    sampler: Sampler,
    /// DDIM steps.
    #[arg(long, default_value_t = 50)]
    steps: usize,
    /// DDIM η (0: deterministic given the initial noise).
    #[arg(long, default_value_t = 0.0)]
    eta: f64,
    /// How known entries are imposed: replace (clean values) or noised (paper Eq. 7.6).
    #[arg(long, value_enum, default_value = "replace")]
    conditioning: Conditioning,
    /// Context inversion: gradient steps per denoising step that move the observed frames the
    /// network is shown until its reading of the last --invert-frames matches them (0: off).
    /// Makes the first forecast frame continue the observed motion with small models; costs
    /// about this many forward+backward passes over the observed part per step.
    #[arg(long, default_value_t = 0)]
    invert_context: usize,
    /// Context inversion: step size.
    #[arg(long, default_value_t = 0.5)]
    invert_lr: f32,
    /// Context inversion: observed frames, back from the last, whose reading is matched.
    #[arg(long, default_value_t = 8)]
    invert_frames: usize,
    /// Seed; sample k uses a seed derived from (seed, k), independent of --samples.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output dataset directory (must not exist or be empty).
    #[arg(long)]
    out: PathBuf,
    /// Known frames at noise level 0 (clean): auto (when the model was trained with clean frames,
    /// `train --noise prefix|per-frame`), on, or off (every frame at the sampler's level, the
    /// paper's way; an ablation for such models).
    #[arg(long, value_enum, default_value_t = CleanKnown::Auto)]
    clean_known: CleanKnown,
    /// When the scene's skeleton differs from the model's: off (refuse, naming the first joint
    /// that differs) or auto (map the scene's joints onto the model's by name, and say how).
    #[arg(long, value_enum, default_value_t = JointMapMode::Off)]
    joint_map: JointMapMode,
    #[command(flatten)]
    source: SourceArgs,
}

/// Whether known frames are shown clean at level 0.
/// The sampler family of `--sampler`.
#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Sampler {
    /// DDIM over --steps respaced steps with stochasticity --eta.
    Ddim,
    /// Ancestral DDPM over all T steps of the model's schedule.
    Ddpm,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum CleanKnown {
    /// As the model was trained.
    Auto,
    /// Always.
    On,
    /// Never.
    Off,
}

/// What to do with a scene whose skeleton is not the model's.
#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum JointMapMode {
    /// Refuse.
    Off,
    /// Map joints by name.
    Auto,
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

impl SampleArgs {
    /// The request, without its frames (the task says them).
    fn request(&self) -> Result<Forecast> {
        if self.samples == 0 || self.samples > MAX_SAMPLES {
            return Err(Error::invalid(format!("--samples must be in 1..={MAX_SAMPLES}, got {}", self.samples)));
        }
        let sampler = match self.sampler {
            Sampler::Ddpm => SamplerKind::Ddpm,
            Sampler::Ddim => {
                if self.steps == 0 {
                    return Err(Error::invalid("--steps must be at least 1"));
                }
                if !(self.eta.is_finite() && self.eta >= 0.0) {
                    return Err(Error::invalid(format!("--eta must be finite and ≥ 0, got {}", self.eta)));
                }
                SamplerKind::Ddim { steps: self.steps, eta: self.eta }
            }
        };
        let inversion = match self.invert_context {
            0 => None,
            steps => {
                if !(self.invert_lr > 0.0 && self.invert_lr.is_finite()) || self.invert_frames == 0 {
                    return Err(Error::invalid("--invert-lr must be positive and --invert-frames at least 1"));
                }
                Some(ContextInversion { steps, lr: self.invert_lr, frames: self.invert_frames })
            }
        };
        let clean_known = match self.clean_known {
            CleanKnown::Auto => None,
            CleanKnown::On => Some(true),
            CleanKnown::Off => Some(false),
        };
        Ok(Forecast {
            samples: self.samples,
            sampler,
            conditioning: self.conditioning,
            seed: self.seed,
            inversion,
            clean_known,
            map_joints: self.joint_map == JointMapMode::Auto,
            ..Default::default()
        })
    }

    /// The scene to sample on: the chosen sequence and persons, in the model's skeleton (mapped
    /// by names with --joint-map auto) and frame rate.
    fn scene(&self, model: &Model) -> Result<Scene> {
        let scene = load_sequence(&self.input, self.sequence.as_deref(), &self.source)?;
        let scene = match &self.persons {
            Some(p) => scene.select_persons(p)?,
            None => scene,
        };
        let m = &model.checkpoint;
        let (fitted, map) = model.fit_scene(&scene, self.joint_map == JointMapMode::Auto).map_err(|e| e.in_file(&self.input))?;
        if let Some(map) = map {
            eprintln!("--joint-map auto: {} joints of {} mapped onto the model's {} by name:", map.target.num_joints(), scene.skeleton.name, m.skeleton.name);
            for line in map.describe().iter().filter(|l| !is_identity(l)) {
                eprintln!("  {line}");
            }
        }
        if (scene.fps - fitted.fps).abs() > 1e-9 {
            eprintln!("resampled {} from {} fps to the model's {} fps", scene.name, scene.fps, m.fps);
        }
        Ok(fitted)
    }
}

/// The sequence `name` of the dataset at `input`, or its only one.
/// One sequence of `input` (`import::load_sequence` with the source flags).
pub fn load_sequence(input: &std::path::Path, name: Option<&str>, source: &SourceArgs) -> Result<Scene> {
    import::load_sequence(input, name, &source.options())
}

/// Options of `socdiff generate`.
#[derive(Args)]
pub struct GenerateArgs {
    /// Checkpoint: a run directory, its checkpoint.json or checkpoint.safetensors.
    #[arg(long)]
    model: PathBuf,
    /// Persons, on a circle facing its centre in the model's mean pose (without --layout).
    #[arg(long, default_value_t = 3)]
    persons: usize,
    /// Frames to generate.
    #[arg(long)]
    frames: usize,
    /// Number of scenes K.
    #[arg(long, default_value_t = 8)]
    samples: usize,
    /// Take the persons' roots and headings (and, for a residual-pose model, their bodies)
    /// from frame 0 of this scene (placed at --placement-frame): a dataset directory (with
    /// --sequence), a .bvh or a .pkl.
    #[arg(long)]
    layout: Option<PathBuf>,
    /// Sequence of the --layout dataset.
    #[arg(long, requires = "layout")]
    sequence: Option<String>,
    /// Frame that has the placement. Default: the model's anchor frame (training --observed − 1),
    /// where every training window has its persons at their anchors; 0 holds the persons
    /// near their placement until then.
    #[arg(long)]
    placement_frame: Option<usize>,
    /// DDIM steps.
    #[arg(long, default_value_t = 50)]
    steps: usize,
    #[command(flatten)]
    output: SampledOutput,
}

/// Seed, output directory, device and import options of `generate` and `interpolate`.
#[derive(Args)]
pub struct SampledOutput {
    #[command(flatten)]
    device: crate::DeviceArg,
    /// Seed; sample k uses a seed derived from (seed, k).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output dataset directory (must not exist or be empty).
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    source: SourceArgs,
}

/// `socdiff generate`: whole scenes from noise.
pub fn run_generate(args: GenerateArgs) -> Result<()> {
    if args.samples == 0 || args.samples > MAX_SAMPLES {
        return Err(Error::invalid(format!("--samples must be in 1..={MAX_SAMPLES}, got {}", args.samples)));
    }
    check_output_dir(&args.output.out)?;
    let model = Model::load_on(&args.model, Weights::Ema, args.output.device.device)?;
    let layout = match &args.layout {
        Some(path) => model.fit_scene(&load_sequence(path, args.sequence.as_deref(), &args.output.source)?, false).map_err(|e| e.in_file(path))?.0,
        None => model.circle_layout(args.persons)?,
    };
    check_size(&format!("generation of {}", layout.name), args.frames as f64, layout.num_persons(), args.samples)?;
    let req = Forecast { samples: args.samples, sampler: SamplerKind::Ddim { steps: args.steps, eta: 0.0 }, seed: args.output.seed, ..Default::default() };
    let bar = crate::progress::denoising((args.steps * args.samples) as u64);
    let task = match args.placement_frame {
        Some(anchor) => Task::Generate { frames: args.frames, anchor },
        None => model.generate_task(args.frames),
    };
    let fc = model.sample(&layout, &task, &req, &mut |i| bar.inc(i.samples.len() as u64));
    bar.finish_and_clear();
    let mut fc = fc?;
    fc.provenance.layout = Some(args.layout.as_ref().map_or_else(|| format!("circle of {}", args.persons), |p| p.display().to_string()));
    fc.write(&args.output.out)?;
    println!("{} scenes of {} frames, {} persons → {}", args.samples, args.frames, layout.num_persons(), args.output.out.display());
    Ok(())
}

/// Options of `socdiff interpolate`.
#[derive(Args)]
pub struct InterpolateArgs {
    /// Checkpoint: a run directory, its checkpoint.json or checkpoint.safetensors.
    #[arg(long)]
    model: PathBuf,
    /// First motion: a dataset directory (with --from-sequence), a .bvh or a .pkl.
    #[arg(long)]
    from: PathBuf,
    /// Sequence of the --from dataset.
    #[arg(long)]
    from_sequence: Option<String>,
    /// Second motion, with as many persons.
    #[arg(long)]
    to: PathBuf,
    /// Sequence of the --to dataset.
    #[arg(long)]
    to_sequence: Option<String>,
    /// Motions from the first to the second, both included (≥ 2).
    #[arg(long, default_value_t = 8)]
    steps: usize,
    /// Frames of each motion (default: the shorter input).
    #[arg(long)]
    frames: Option<usize>,
    /// Instead: the first motion, then this many generated frames, then the second (an
    /// in-betweening through the completion path).
    #[arg(long, value_name = "F")]
    transition: Option<usize>,
    /// DDIM steps of inversion and denoising.
    #[arg(long, default_value_t = 50)]
    ddim_steps: usize,
    #[command(flatten)]
    output: SampledOutput,
}

/// `socdiff interpolate`.
pub fn run_interpolate(args: InterpolateArgs) -> Result<()> {
    check_output_dir(&args.output.out)?;
    let model = Model::load_on(&args.model, Weights::Ema, args.output.device.device)?;
    let a = load_sequence(&args.from, args.from_sequence.as_deref(), &args.output.source)?;
    let b = load_sequence(&args.to, args.to_sequence.as_deref(), &args.output.source)?;
    if let Some(f) = args.transition {
        let fc = model.transition(&a, &b, f, args.ddim_steps, args.output.seed)?;
        fc.write(&args.output.out)?;
        println!("{} frames of {}, {f} generated, {} frames of {} → {}", a.num_frames(), a.name, b.num_frames(), b.name, args.output.out.display());
        return Ok(());
    }
    let it = model.interpolate(&a, &b, args.steps, args.frames, args.ddim_steps)?;
    let speeds: Vec<String> = it.root_speed.iter().map(|v| format!("{v:.2}")).collect();
    let steps: Vec<String> = it.largest_step.iter().map(|v| format!("{:.0}", v * 1e3)).collect();
    println!("mean root speed (m/s): {} (inputs {:.2} → {:.2})", speeds.join(" "), it.input_root_speed[0], it.input_root_speed[1]);
    let (s0, s1) = (it.input_largest_step[0] * 1e3, it.input_largest_step[1] * 1e3);
    println!("largest frame-to-frame joint move (mm): {} (inputs {s0:.0} / {s1:.0})", steps.join(" "));
    let endpoint_error = it.endpoint_error;
    write_dataset(&it.into_dataset(&args.from, &args.to), &args.output.out)?;
    println!(
        "{} motions from {} to {} → {} (endpoints reconstructed within {:.3} / {:.3} m mean joint error)",
        args.steps,
        a.name,
        b.name,
        args.output.out.display(),
        endpoint_error[0],
        endpoint_error[1]
    );
    Ok(())
}

/// Whether a joint-map line says "x ← x".
fn is_identity(line: &str) -> bool {
    line.split_once(" ← ").is_some_and(|(a, b)| a == b)
}

fn run_task(args: &SampleArgs, task: impl FnOnce(&Scene) -> Result<Task>) -> Result<()> {
    let req = args.request()?;
    check_output_dir(&args.out)?;
    let model = Model::load_on(&args.model, args.weights, args.device.device)?;
    let scene = args.scene(&model)?;
    let task = task(&scene)?;
    forecast::check_task(&scene, &task)?;
    check_size(&format!("forecast of {}", scene.name), forecast::canvas_frames(&scene, &task) as f64, scene.num_persons(), req.samples)?;
    let steps_per_sample = match req.sampler {
        SamplerKind::Ddpm => model.checkpoint.diffusion.timesteps(),
        SamplerKind::Ddim { steps, .. } => steps,
    };
    let batch = model.net().max_batch(scene.num_persons(), forecast::canvas_frames(&scene, &task)).min(req.samples);
    let bar = crate::progress::denoising((steps_per_sample * req.samples) as u64);
    if batch > 1 {
        bar.println(format!("{} samples, {batch} per model call", req.samples));
    }
    let fc = model.sample(&scene, &task, &req, &mut |i| {
        bar.set_message(format!("samples {}–{} of {}  {:.3} s/step", i.samples.start + 1, i.samples.end, req.samples, i.seconds));
        bar.inc(i.samples.len() as u64);
    });
    bar.finish_and_clear();
    let mut fc = fc?;
    fc.provenance.weights = Some(args.weights);
    fc.provenance.input = Some(args.input.display().to_string());
    fc.provenance.persons = args.persons.clone();
    let t = fc.provenance.timings;
    let (total, per, calls) = (t.total_seconds, t.seconds_per_step, t.model_calls);
    fc.write(&args.out)?;
    println!(
        "{} samples × {} steps of {} ({} frames, {} persons): {calls} denoising steps of {batch} sample(s), {per:.3} s per step, {total:.1} s total → {}",
        req.samples,
        steps_per_sample,
        scene.name,
        fc.samples[0].num_frames(),
        scene.num_persons(),
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
