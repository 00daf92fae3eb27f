//! The options of `socdiff forecast`, `complete`, `generate` and `interpolate` as flags, and
//! the [`Forecast`] request and fitted scene they describe.

use super::model::DEFAULT_DDIM_STEPS;
use super::{ContextInversion, Forecast, Model, SamplerKind};
use crate::checkpoint::Weights;
use crate::data::import::{self, SourceArgs};
use crate::data::scene::Scene;
use crate::model::DeviceArg;
use crate::sample::Conditioning;
use crate::{Error, Result};
use std::path::PathBuf;

/// Options shared by `forecast` and `complete`.
#[derive(Clone, Debug)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct SampleArgs {
    /// Checkpoint: a run directory, its checkpoint.json or checkpoint.safetensors.
    #[cfg_attr(feature = "clap", arg(long))]
    pub model: PathBuf,
    #[cfg_attr(feature = "clap", command(flatten))]
    pub device: DeviceArg,
    /// Weights of the checkpoint: ema (the moving average, usual for inference) or online (the
    /// optimizer's current weights; better early in training, while the average still lags).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "ema"))]
    pub weights: Weights,
    #[cfg_attr(feature = "clap", command(flatten))]
    pub guide: GuideArgs,
    /// Scene: a dataset directory (with --sequence), a .bvh or a Haggling .pkl.
    #[cfg_attr(feature = "clap", arg(long))]
    pub input: PathBuf,
    /// Sequence of a dataset directory (needed when it holds more than one).
    #[cfg_attr(feature = "clap", arg(long, conflicts_with = "split"))]
    pub sequence: Option<String>,
    /// Every scene of this split of the --input dataset (train, test or validation), each into
    /// a folder of its name under --out: one method for `socdiff eval`.
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub split: Option<crate::data::Split>,
    /// Persons of the scene to use, comma-separated indices (default: all).
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ','))]
    pub persons: Option<Vec<usize>>,
    /// Number of samples K.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 8))]
    pub samples: usize,
    /// Sampler: ddim (over --steps) or ddpm (ancestral, all T steps of the model).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "ddim"))]
    pub sampler: SamplerFamily,
    /// DDIM steps [default: 50; a distilled student's own].
    #[cfg_attr(feature = "clap", arg(long))]
    pub steps: Option<usize>,
    /// DDIM η (0: deterministic given the initial noise).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 0.0))]
    pub eta: f64,
    /// How known entries are imposed: replace (clean values) or noised (paper Eq. 7.6).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "replace"))]
    pub conditioning: Conditioning,
    /// Context inversion: gradient steps per denoising step that move the observed frames the
    /// network is shown until its reading of the last --invert-frames matches them (0: off).
    /// Makes the first forecast frame continue the observed motion with small models; costs
    /// about this many forward+backward passes over the observed part per step.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 0))]
    pub invert_context: usize,
    /// Context inversion: step size.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 0.5))]
    pub invert_lr: f32,
    /// Context inversion: observed frames, back from the last, whose reading is matched.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 8))]
    pub invert_frames: usize,
    /// Seed; sample k uses a seed derived from (seed, k), independent of --samples.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 1))]
    pub seed: u64,
    /// Output dataset directory (must not exist or be empty).
    #[cfg_attr(feature = "clap", arg(long))]
    pub out: PathBuf,
    /// Known frames at noise level 0 (clean): auto (when the model was trained with clean frames,
    /// noise `prefix` or `per-frame`), on, or off (every frame at the sampler's level, the
    /// paper's way; an ablation for such models).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = CleanKnown::Auto))]
    pub clean_known: CleanKnown,
    /// When the scene's skeleton differs from the model's: off (refuse, naming the first joint
    /// that differs) or auto (map the scene's joints onto the model's by name, and say how).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = JointMapMode::Off))]
    pub joint_map: JointMapMode,
    #[cfg_attr(feature = "clap", command(flatten))]
    pub source: SourceArgs,
}

/// Autoguidance options of `forecast`, `complete` and `generate` ([`Model::with_guide`]).
#[derive(Clone, Debug, Default)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct GuideArgs {
    /// Autoguidance: a weaker model of the same data (e.g. the same recipe trained a tenth as
    /// long) whose prediction the samples are pushed away from, with weight --guidance.
    #[cfg_attr(feature = "clap", arg(long, value_name = "MODEL"))]
    pub guide: Option<PathBuf>,
    /// Autoguidance weight w ≥ 1: x̂0 = x̂0_guide + w·(x̂0 − x̂0_guide) (1: the model alone).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 2.0, requires = "guide"))]
    pub guidance: f64,
    /// Autoguidance only at noise levels t ≥ LEVEL (0: at every level).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 0, value_name = "LEVEL", requires = "guide"))]
    pub guide_from: usize,
}

impl GuideArgs {
    /// Loads `model`'s checkpoint with `weights` on `device`, guided when --guide says.
    pub fn load(&self, model: &std::path::Path, weights: Weights, device: crate::model::DeviceChoice) -> Result<Model> {
        let strong = Model::load_on(model, weights, device)?;
        match &self.guide {
            None => Ok(strong),
            Some(path) => strong.with_guide(Model::load_on(path, Weights::Ema, device)?, self.guidance, self.guide_from),
        }
    }
}

/// The sampler family of `--sampler`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum SamplerFamily {
    /// DDIM over --steps respaced steps with stochasticity --eta.
    Ddim,
    /// Ancestral DDPM over all T steps of the model's schedule.
    Ddpm,
}

impl SamplerFamily {
    /// The sampler of `--sampler`, `--steps` and `--eta`; errors name bad values.
    pub fn kind(self, steps: usize, eta: f64) -> Result<SamplerKind> {
        match self {
            SamplerFamily::Ddpm => Ok(SamplerKind::Ddpm),
            SamplerFamily::Ddim => {
                if steps == 0 {
                    return Err(Error::invalid("`steps` must be at least 1"));
                }
                if !(eta.is_finite() && eta >= 0.0) {
                    return Err(Error::invalid(format!("`eta` must be finite and ≥ 0, got {eta}")));
                }
                Ok(SamplerKind::Ddim { steps, eta })
            }
        }
    }
}

/// Whether known frames are shown clean at level 0.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum CleanKnown {
    /// As the model was trained.
    Auto,
    /// Always.
    On,
    /// Never.
    Off,
}

/// What to do with a scene whose skeleton is not the model's.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum JointMapMode {
    /// Refuse.
    Off,
    /// Map joints by name.
    Auto,
}

/// Most gradient steps of context inversion per denoising step.
pub const MAX_INVERSION_STEPS: usize = 1000;

/// Options of `socdiff forecast`.
#[derive(Clone, Debug)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct ForecastArgs {
    #[cfg_attr(feature = "clap", command(flatten))]
    pub common: SampleArgs,
    /// Observed frames (from the start of the scene); persons are anchored at the last one.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 128))]
    pub observe: usize,
    /// Frames to forecast after the observed ones. The forecast stops where the recording
    /// does (saying so) unless --past-end.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 1800))]
    pub horizon: usize,
    /// Forecast all --horizon frames even past the end of the recording (there is then no
    /// recorded future to score those frames against).
    #[cfg_attr(feature = "clap", arg(long))]
    pub past_end: bool,
    /// Stream: frames arrive on --input (a pipe, a file, or - for standard input) in the model's
    /// skeleton, metres, z up, and each frame after the first --observe gets a forecast, one JSON
    /// line on --out (- for standard output) with its --horizon frames. json: a line per frame,
    /// {"time": seconds, "positions": [[[x, y, z], …joints], …persons]}; f32: raw little-endian
    /// float32 frames of --stream-persons × joints × 3, one per 1/fps s. A bad frame gets an
    /// {"error"} line and the stream goes on.
    #[cfg_attr(feature = "clap", arg(long, value_enum, value_name = "FORMAT"))]
    pub stream: Option<StreamFormat>,
    /// Stream f32: persons per frame.
    #[cfg_attr(feature = "clap", arg(long, value_name = "N", requires = "stream"))]
    pub stream_persons: Option<usize>,
}

/// How `forecast --stream` reads frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum StreamFormat {
    /// A JSON object per line: `{"time": seconds, "positions": [persons][joints][3]}`.
    Json,
    /// Raw little-endian float32 frames `[persons, joints, 3]`, at the model's frame rate.
    F32,
}

impl ForecastArgs {
    /// The horizon of a forecast of `scene`: --horizon, or up to the end of the recording
    /// without --past-end (with a note saying so when that is shorter).
    pub fn horizon_for(&self, scene: &Scene) -> (usize, Option<String>) {
        let recorded = scene.num_frames().saturating_sub(self.observe);
        // A request beyond the limits stays as asked, for the check to refuse it.
        let absurd = self.observe as f64 + self.horizon as f64 > crate::data::MAX_FRAMES as f64;
        if self.past_end || absurd || recorded >= self.horizon || recorded == 0 {
            return (self.horizon, None);
        }
        let note = format!(
            "{}: the recording ends {recorded} frames after the {} observed: forecasting {recorded} frames, not {} (--past-end forecasts past it)",
            scene.name, self.observe, self.horizon
        );
        (recorded, Some(note))
    }
}

/// Options of `socdiff complete`.
#[derive(Clone, Debug)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct CompleteArgs {
    #[cfg_attr(feature = "clap", command(flatten))]
    pub common: SampleArgs,
    /// What is missing: joints=NAME|INDEX,…  frames=a..b  persons=i,…
    #[cfg_attr(feature = "clap", arg(long))]
    pub missing: String,
}

impl SampleArgs {
    /// The request, without its frames (the task says them); errors name bad values.
    pub fn request(&self) -> Result<Forecast> {
        let sampler = self.sampler.kind(self.steps.unwrap_or(DEFAULT_DDIM_STEPS), self.eta)?;
        let inversion = match self.invert_context {
            0 => None,
            steps => {
                if !(self.invert_lr > 0.0 && self.invert_lr.is_finite()) || self.invert_frames == 0 {
                    return Err(Error::invalid("`invert_lr` must be positive and `invert_frames` at least 1"));
                }
                if steps > MAX_INVERSION_STEPS || self.invert_frames > crate::data::MAX_FRAMES {
                    return Err(Error::invalid(format!("`invert_context` {steps} is more than the {MAX_INVERSION_STEPS} steps allowed")));
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

    /// [`SampleArgs::request`] with `model`'s own DDIM steps when --steps is not given.
    pub fn request_for(&self, model: &Model) -> Result<Forecast> {
        let req = self.request()?;
        Ok(Forecast { sampler: self.sampler.kind(self.steps.unwrap_or(model.default_steps()), self.eta)?, ..req })
    }

    /// The scenes to sample on, each with notes for the user: the chosen sequence, or every
    /// scene of --split, with the chosen persons, in the model's skeleton (mapped by names with
    /// --joint-map auto) and frame rate.
    pub fn scenes(&self, model: &Model) -> Result<Vec<(Scene, Vec<String>)>> {
        let Some(split) = self.split else {
            let scene = import::load_sequence(&self.input, self.sequence.as_deref(), &self.source.options())?;
            return Ok(vec![self.fit(model, scene)?]);
        };
        let dataset = import::load(&self.input, &self.source.options())?;
        let scenes: Vec<Scene> = dataset.split(split).cloned().collect();
        if scenes.is_empty() {
            return Err(Error::invalid(format!("{}: no scene in the {} split", self.input.display(), split.as_str())));
        }
        scenes.into_iter().map(|s| self.fit(model, s)).collect()
    }

    /// `scene` with the chosen persons, fitted to the model.
    fn fit(&self, model: &Model, scene: Scene) -> Result<(Scene, Vec<String>)> {
        let mut notes = Vec::new();
        let scene = match &self.persons {
            Some(p) => scene.select_persons(p)?,
            None => scene,
        };
        let m = &model.checkpoint;
        let (fitted, map) = model.fit_scene(&scene, self.joint_map == JointMapMode::Auto).map_err(|e| e.in_file(&self.input))?;
        if let Some(map) = map {
            notes.push(format!(
                "--joint-map auto: {} joints of {} mapped onto the model's {} by name:",
                map.target.num_joints(),
                scene.skeleton.name,
                m.skeleton.name
            ));
            notes.extend(map.describe().iter().filter(|l| !is_identity(l)).map(|l| format!("  {l}")));
        }
        if (scene.fps - fitted.fps).abs() > 1e-9 {
            notes.push(format!("resampled {} from {} fps to the model's {} fps", scene.name, scene.fps, m.fps));
        }
        Ok((fitted, notes))
    }
}

/// Options of `socdiff generate`.
#[derive(Clone, Debug)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct GenerateArgs {
    /// Checkpoint: a run directory, its checkpoint.json or checkpoint.safetensors.
    #[cfg_attr(feature = "clap", arg(long))]
    pub model: PathBuf,
    /// Persons, on a circle facing its centre in the model's mean pose (without --layout).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 3))]
    pub persons: usize,
    /// Frames to generate.
    #[cfg_attr(feature = "clap", arg(long))]
    pub frames: usize,
    /// Number of scenes K.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 8))]
    pub samples: usize,
    /// Take the persons' roots and headings (and, for a residual-pose model, their bodies)
    /// from frame 0 of this scene (placed at --placement-frame): a dataset directory (with
    /// --sequence), a .bvh or a .pkl.
    #[cfg_attr(feature = "clap", arg(long))]
    pub layout: Option<PathBuf>,
    /// Sequence of the --layout dataset.
    #[cfg_attr(feature = "clap", arg(long, requires = "layout"))]
    pub sequence: Option<String>,
    #[cfg_attr(feature = "clap", command(flatten))]
    pub guide: GuideArgs,
    /// Frame that has the placement. Default: the model's anchor frame (training --observed − 1),
    /// where every training window has its persons at their anchors; 0 holds the persons
    /// near their placement until then.
    #[cfg_attr(feature = "clap", arg(long))]
    pub placement_frame: Option<usize>,
    /// Sampler: ddim (over --steps) or ddpm (ancestral, all T steps of the model).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "ddim"))]
    pub sampler: SamplerFamily,
    /// DDIM steps [default: 50; a distilled student's own].
    #[cfg_attr(feature = "clap", arg(long))]
    pub steps: Option<usize>,
    /// DDIM η (0: deterministic given the initial noise; 1: as stochastic as DDPM).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 0.0))]
    pub eta: f64,
    #[cfg_attr(feature = "clap", command(flatten))]
    pub output: SampledOutput,
}

impl GenerateArgs {
    /// What to draw, for [`crate::forecast::Model::sample`] with a generation task; errors name
    /// bad values.
    pub fn request(&self) -> Result<Forecast> {
        Ok(Forecast {
            samples: self.samples,
            sampler: self.sampler.kind(self.steps.unwrap_or(DEFAULT_DDIM_STEPS), self.eta)?,
            seed: self.output.seed,
            ..Default::default()
        })
    }

    /// [`GenerateArgs::request`] with `model`'s own DDIM steps when --steps is not given.
    pub fn request_for(&self, model: &Model) -> Result<Forecast> {
        Ok(Forecast { sampler: self.sampler.kind(self.steps.unwrap_or(model.default_steps()), self.eta)?, ..self.request()? })
    }
}

/// Seed, output directory, device and import options of `generate` and `interpolate`.
#[derive(Clone, Debug)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct SampledOutput {
    #[cfg_attr(feature = "clap", command(flatten))]
    pub device: DeviceArg,
    /// Seed; sample k uses a seed derived from (seed, k).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 1))]
    pub seed: u64,
    /// Output dataset directory (must not exist or be empty).
    #[cfg_attr(feature = "clap", arg(long))]
    pub out: PathBuf,
    #[cfg_attr(feature = "clap", command(flatten))]
    pub source: SourceArgs,
}

/// Options of `socdiff interpolate`.
#[derive(Clone, Debug)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct InterpolateArgs {
    /// Checkpoint: a run directory, its checkpoint.json or checkpoint.safetensors.
    #[cfg_attr(feature = "clap", arg(long))]
    pub model: PathBuf,
    /// First motion: a dataset directory (with --from-sequence), a .bvh or a .pkl.
    #[cfg_attr(feature = "clap", arg(long))]
    pub from: PathBuf,
    /// Sequence of the --from dataset.
    #[cfg_attr(feature = "clap", arg(long))]
    pub from_sequence: Option<String>,
    /// Second motion, with as many persons.
    #[cfg_attr(feature = "clap", arg(long))]
    pub to: PathBuf,
    /// Sequence of the --to dataset.
    #[cfg_attr(feature = "clap", arg(long))]
    pub to_sequence: Option<String>,
    /// Motions from the first to the second, both included (≥ 2).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 8))]
    pub steps: usize,
    /// Frames of each motion (default: the shorter input).
    #[cfg_attr(feature = "clap", arg(long))]
    pub frames: Option<usize>,
    /// Instead: the first motion, then this many generated frames, then the second (an
    /// in-betweening through the completion path).
    #[cfg_attr(feature = "clap", arg(long, value_name = "F"))]
    pub transition: Option<usize>,
    /// DDIM steps of inversion and denoising.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 50))]
    pub ddim_steps: usize,
    /// Fixed-point iterations per inversion step, so that denoising gives the inputs back
    /// (0: plain DDIM inversion; each iteration is one more network call per step).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 0, value_name = "N"))]
    pub refine_inversion: usize,
    /// Noise level (timestep, 1 ≤ LEVEL < T) the motions are inverted to, mixed at and denoised
    /// from (default T − 1, pure noise). Lower keeps more of both motions' shape in the mix.
    #[cfg_attr(feature = "clap", arg(long, value_name = "LEVEL"))]
    pub invert_to: Option<usize>,
    #[cfg_attr(feature = "clap", command(flatten))]
    pub output: SampledOutput,
}

impl InterpolateArgs {
    /// What to draw, for [`crate::forecast::Model::interpolate`].
    pub fn request(&self) -> crate::forecast::Interpolate {
        crate::forecast::Interpolate {
            steps: self.steps,
            frames: self.frames,
            ddim_steps: self.ddim_steps,
            refine: self.refine_inversion,
            depth: self.invert_to,
        }
    }
}

/// Whether a joint-map line says "x ← x".
fn is_identity(line: &str) -> bool {
    line.split_once(" ← ").is_some_and(|(a, b)| a == b)
}
