//! Forecasting and completion of scenes by inpainting (issue 4): scene ↔ canvas, masks,
//! per-sample seeds, decoding back to world positions, and the output dataset.
//!
//! ```text
//! scene ──encode (each person anchored at the anchor frame)──▶ features [T, P, δ]
//!       ──standardize──▶ known values, mask (Task)  ──inpaint, once per sample k with
//!       seed_k = sample_seed(seed, k)──▶ [T, P, δ] ──unstandardize, decode──▶ world positions
//! ```
//!
//! - Forecast: the canvas is `observe + horizon` frames; frames `< observe` are known for every
//!   person and dim; persons are anchored at frame `observe − 1` (their last observed pose).
//! - Completion: the canvas is the whole scene. `joints=…` leaves those joints unknown on every
//!   frame (and the root dims too when a body-frame joint is missing); `frames=a..b` leaves
//!   frames `a..b` unknown (anchor: frame `a − 1`, or `b` when `a = 0`); `persons=…` leaves those
//!   persons unknown on every frame (anchor: the last frame). Anchors (root and heading at the
//!   anchor frame) always come from the input: a completed person keeps its placement.
//! - Sample `k` draws its random numbers from an RNG seeded with [`sample_seed`]`(seed, k)`, and
//!   samples are batched into model calls that compute each one independently, so sample `k` is
//!   the same bit for bit whatever the number of samples.
//! - Positions of entries that were fully known (joint and root dims) are copied from the input,
//!   so observed frames equal the input bit for bit.

mod args;
pub use args::{CleanKnown, CompleteArgs, ForecastArgs, GenerateArgs, GuideArgs, InterpolateArgs, JointMapMode, SampleArgs, SampledOutput, SamplerFamily};

use crate::data::dataset::{write_dataset, Dataset, Sequence, Split};
use crate::data::scene::Scene;
use crate::data::Skeleton;
use crate::export::ForecastInfo;
use crate::features::{PoseEncoding, PoseFeatures, Standardization, ROOT_DIMS};
use crate::model::{Denoiser, DenoiserConfig, DeviceChoice, K3Conv};
use crate::sample::{inpaint_with_progress, Conditioning, InpaintOptions, Known, SamplingNet, X0Model};
pub use crate::sample::{sample_seed, ContextInversion, StepInfo};
use crate::{bail, Error, Result};
use ndarray::{s, Array2, Array3, Array4, Axis};
use serde::Serialize;
use serde_json::{json, Map, Value};
use socdiff_schedules::{Ddim, Ddpm, NoiseSchedule, Sampler};
use std::ops::Range;
use std::path::Path;
use std::time::Instant;

/// Which part of a scene is unknown, for completion.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Missing {
    /// These joints (skeleton indices) on every frame of every person.
    Joints(Vec<usize>),
    /// These frames of every person.
    Frames(Range<usize>),
    /// These persons (scene indices) on every frame.
    Persons(Vec<usize>),
}

impl Missing {
    /// Parses `joints=NAME|INDEX,…`, `frames=a..b` or `persons=i,…` (joint names from `skeleton`).
    pub fn parse(spec: &str, skeleton: &crate::data::Skeleton) -> Result<Self> {
        let (kind, list) = spec.split_once('=').ok_or_else(|| Error::invalid(format!("`missing` {spec:?}: expected joints=…, frames=a..b or persons=…")))?;
        let items = || list.split(',').map(str::trim).filter(|s| !s.is_empty());
        match kind.trim() {
            "joints" => {
                let mut v = Vec::new();
                for it in items() {
                    let j = match it.parse::<usize>() {
                        Ok(j) => j,
                        Err(_) => skeleton
                            .joint_index(it)
                            .ok_or_else(|| Error::invalid(format!("`missing` joints: skeleton {} has no joint {it:?}", skeleton.name)))?,
                    };
                    v.push(j);
                }
                Ok(Missing::Joints(v))
            }
            "frames" => {
                let (a, b) = list.split_once("..").ok_or_else(|| Error::invalid(format!("`missing` frames={list}: expected a..b")))?;
                let p = |x: &str| x.trim().parse::<usize>().map_err(|_| Error::invalid(format!("`missing` frames={list}: {x:?} is not a frame index")));
                Ok(Missing::Frames(p(a)?..p(b)?))
            }
            "persons" => {
                let v = items()
                    .map(|x| x.parse::<usize>().map_err(|_| Error::invalid(format!("`missing` persons: {x:?} is not a person index"))))
                    .collect::<Result<Vec<_>>>()?;
                Ok(Missing::Persons(v))
            }
            other => bail!("`missing` {other}=…: expected joints, frames or persons"),
        }
    }

    /// The spec as text (`joints=1,2`, `frames=3..9`, `persons=0`).
    pub fn describe(&self) -> String {
        let list = |v: &[usize]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>().join(",");
        match self {
            Missing::Joints(v) => format!("joints={}", list(v)),
            Missing::Frames(r) => format!("frames={}..{}", r.start, r.end),
            Missing::Persons(v) => format!("persons={}", list(v)),
        }
    }
}

/// What to sample.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Task {
    /// Frames `0..observe` known, `horizon` frames after them sampled.
    Forecast {
        /// Observed frames (taken from the start of the scene).
        observe: usize,
        /// Forecast frames.
        horizon: usize,
    },
    /// The scene with a part unknown.
    Complete(Missing),
    /// A whole scene of `frames` frames from noise: only each person's placement (root and
    /// heading) at frame 0 of the scene (the layout) is taken, held at canvas frame `anchor`,
    /// and — for a residual-pose model — the body its motion is measured from.
    Generate {
        /// Frames generated.
        frames: usize,
        /// The frame that has the layout's placement ([`Model::generate_task`]: the model's
        /// anchor frame, where every training window has its persons at their anchors; a
        /// placement elsewhere fights that prior, e.g. frame 0 holds the person still until it).
        anchor: usize,
    },
}

/// Which sampler runs the reverse process. JSON form: `{"kind": "ddpm"}`,
/// `{"kind": "ddim", "steps": 20, "eta": 0.0}`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum SamplerKind {
    /// Ancestral DDPM over all T steps.
    Ddpm,
    /// DDIM over `steps` respaced steps with stochasticity `eta`.
    Ddim {
        /// Number of steps K.
        steps: usize,
        /// η (0 = deterministic).
        eta: f64,
    },
}

impl SamplerKind {
    /// Parses `ddpm` or `ddimN` (DDIM over N steps, η = 0), as [`SamplerKind::name`] writes them.
    pub fn parse(s: &str) -> Result<Self> {
        let bad = || Error::invalid(format!("sampler {s:?}: expected ddpm or ddimN (e.g. ddim20)"));
        if s == "ddpm" {
            return Ok(SamplerKind::Ddpm);
        }
        match s.strip_prefix("ddim").and_then(|n| n.parse::<usize>().ok()) {
            Some(steps) if steps > 0 => Ok(SamplerKind::Ddim { steps, eta: 0.0 }),
            _ => Err(bad()),
        }
    }

    /// `ddpm`, `ddimN`, or `ddimN-etaE` when η ≠ 0.
    pub fn name(&self) -> String {
        match *self {
            SamplerKind::Ddpm => "ddpm".into(),
            SamplerKind::Ddim { steps, eta: 0.0 } => format!("ddim{steps}"),
            SamplerKind::Ddim { steps, eta } => format!("ddim{steps}-eta{eta}"),
        }
    }

    /// Denoising steps per sample over a schedule of `timesteps` levels (all of them for DDPM).
    pub fn steps(&self, timesteps: usize) -> usize {
        match *self {
            SamplerKind::Ddpm => timesteps,
            SamplerKind::Ddim { steps, .. } => steps,
        }
    }

    /// The sampler over `schedule`.
    pub fn build(&self, schedule: &NoiseSchedule) -> Result<Box<dyn Sampler>> {
        Ok(match *self {
            SamplerKind::Ddpm => Box::new(Ddpm::new(schedule)),
            SamplerKind::Ddim { steps, eta } => {
                if steps == 0 {
                    bail!("ddim needs at least 1 step");
                }
                if !(eta.is_finite() && eta >= 0.0) {
                    bail!("ddim eta must be finite and ≥ 0, got {eta}");
                }
                Box::new(Ddim::new(schedule, steps, eta)?)
            }
        })
    }
}

/// Options of [`sample_scene`].
#[derive(Clone, Debug, PartialEq)]
pub struct ForecastOptions {
    /// Number of samples K.
    pub samples: usize,
    /// Sampler.
    pub sampler: SamplerKind,
    /// How known entries are imposed.
    pub conditioning: Conditioning,
    /// Base seed; sample k uses [`sample_seed`]`(seed, k)`.
    pub seed: u64,
    /// Context inversion of the observed frames ([`ContextInversion`]); off by default.
    pub inversion: Option<ContextInversion>,
    /// Known frames at noise level 0 ([`crate::sample::InpaintOptions::clean_known`]): set it
    /// for models trained with clean frames ([`ForecastOptions::for_model`] does).
    pub clean_known: bool,
    /// The features the model was trained on ([`ForecastOptions::for_model`] sets it).
    pub encoding: PoseEncoding,
}

impl Default for ForecastOptions {
    fn default() -> Self {
        Self {
            samples: 1,
            sampler: SamplerKind::Ddim { steps: 50, eta: 0.0 },
            conditioning: Conditioning::Replace,
            seed: 0,
            inversion: None,
            clean_known: false,
            encoding: PoseEncoding::Absolute,
        }
    }
}

impl ForecastOptions {
    /// These options with what the model's training implies: its pose encoding, and known
    /// frames clean at level 0 for a model trained with clean frames (`prefix`, `per-frame`).
    pub fn for_model(self, model: &crate::train::LoadedModel) -> Self {
        Self { clean_known: self.clean_known || model.config.noise.trains_clean_frames(), encoding: model.config.pose, ..self }
    }
}

/// A trained model, ready to forecast and complete scenes: the checkpoint and its
/// forward-only network (the one CPU sampling route).
///
/// ```no_run
/// use socdiff_engine::forecast::{Forecast, Model};
/// let model = Model::load("runs/m1")?;
/// let scene = socdiff_engine::data::import::load_scene("walk.bvh")?;
/// let fc = model.forecast(&scene, Forecast { observe: 120, horizon: 1800, samples: 8, ..Default::default() })?;
/// fc.write("forecast-out".as_ref())?;
/// # Ok::<(), socdiff_engine::Error>(())
/// ```
pub struct Model {
    /// The checkpoint: weights, configuration, standardization, skeleton, frame rate.
    pub checkpoint: crate::train::LoadedModel,
    net: SamplingNet,
    guide: Option<Guide>,
}

/// The guide of a [`Model`] ([`Model::with_guide`], [`crate::sample::Autoguided`]).
struct Guide {
    net: SamplingNet,
    weight: f32,
    from_level: usize,
    provenance: GuideProvenance,
}

/// Which model guided the samples, and how strongly ([`Model::with_guide`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GuideProvenance {
    /// The guiding (weak) model's checkpoint.
    pub model: String,
    /// Its optimizer step.
    pub model_step: u64,
    /// The guidance weight w (1: the model alone).
    pub weight: f64,
    /// Guidance only at noise levels t ≥ this (0: at every level).
    pub from_level: usize,
}

/// `a`, then `frames` frames to be generated (holding `a`'s last pose until then), then
/// `b`: the scene of an in-betweening, completed with `Missing::Frames(a.len..a.len + frames)`.
pub fn transition_scene(a: &Scene, b: &Scene, frames: usize) -> Result<Scene> {
    if frames == 0 {
        bail!("a transition of 0 frames: give at least 1");
    }
    if a.num_persons() != b.num_persons() || a.skeleton.joints != b.skeleton.joints {
        bail!(
            "scenes {} and {} differ in persons ({} and {}) or skeleton; a transition joins the same persons",
            a.name,
            b.name,
            a.num_persons(),
            b.num_persons()
        );
    }
    crate::data::check_size(&format!("transition from {} to {}", a.name, b.name), (a.num_frames() + frames + b.num_frames()) as f64, a.num_persons(), 1)?;
    let last = a.positions.slice(s![a.num_frames() - 1..a.num_frames(), .., .., ..]);
    let hold = ndarray::concatenate(Axis(0), &vec![last; frames]).expect("same pose shape");
    let pos = ndarray::concatenate(Axis(0), &[a.positions.view(), hold.view(), b.positions.view()]).expect("same pose shape");
    Scene::new(format!("{}_then_{}", a.name, b.name), a.fps, a.skeleton.clone(), pos)
}

/// What [`Model::interpolate`] draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Interpolate {
    /// Motions from the first scene to the second, both included (≥ 2).
    pub steps: usize,
    /// Frames of each motion (default: the shorter scene).
    pub frames: Option<usize>,
    /// DDIM steps of the inversion and of the denoising.
    pub ddim_steps: usize,
    /// Fixed-point iterations per inversion step (0: plain DDIM inversion).
    pub refine: usize,
    /// The noise level (timestep, 1 ≤ level < T) the scenes are inverted to and interpolated
    /// at; `None`: T − 1, pure noise (the method of the issue, and of DDIM's own
    /// interpolations). A lower level keeps more of both motions' shape in the mix.
    pub depth: Option<usize>,
}

impl Default for Interpolate {
    fn default() -> Self {
        Self { steps: 8, frames: None, ddim_steps: 50, refine: 0, depth: None }
    }
}

/// What [`Model::interpolate`] made.
#[derive(Clone, Debug)]
pub struct Interpolation {
    /// `<a>_to_<b>`, after the two scenes.
    pub name: String,
    /// The motions, from the reconstruction of the first scene to that of the second.
    pub motions: Vec<Scene>,
    /// Mean joint error (m) of the two endpoint reconstructions against the scenes.
    pub endpoint_error: [f64; 2],
    /// Mean horizontal root (hip midpoint) speed of each motion, m/s.
    pub root_speed: Vec<f64>,
    /// Largest frame-to-frame joint move of each motion, m.
    pub largest_step: Vec<f64>,
    /// Mean root speed and largest frame-to-frame move of the two inputs (over the frames used).
    pub input_root_speed: [f64; 2],
    pub input_largest_step: [f64; 2],
    /// DDIM steps of the inversion and of the denoising.
    pub ddim_steps: usize,
    /// The noise level (timestep) the motions were inverted to and denoised from.
    pub depth: usize,
    /// Fixed-point iterations per inversion step (0: plain DDIM inversion).
    pub refine: usize,
    /// Per endpoint, the largest RMS residual of a refined inversion step in standardized
    /// features (0 when not refined).
    pub inversion_residual: [f64; 2],
    /// Per endpoint, whether the refined inversion was kept (its motion is closer to the input
    /// than the plain one's).
    pub refined: [bool; 2],
    /// The model's checkpoint folder and step.
    pub model: (String, u64),
}

impl Interpolation {
    /// The motions as a dataset (test split, named `<a>_to_<b>`), with the measurements and
    /// where `from` and `to` came from in its metadata (`interpolation`).
    pub fn into_dataset(self, from: &std::path::Path, to: &std::path::Path) -> Dataset {
        let info = serde_json::json!({"from": from.display().to_string(), "to": to.display().to_string(), "steps": self.motions.len(),
            "ddim_steps": self.ddim_steps, "inversion_depth": self.depth, "inversion_refine": self.refine, "inversion_residual": self.inversion_residual, "inversion_refined_kept": self.refined, "model": self.model.0, "model_step": self.model.1,
            "endpoint_error_m": self.endpoint_error, "root_speed_m_s": self.root_speed, "largest_step_m": self.largest_step,
            "input_root_speed_m_s": self.input_root_speed, "input_largest_step_m": self.input_largest_step});
        let metadata = serde_json::Map::from_iter([("interpolation".to_string(), info)]);
        Dataset { name: self.name, sequences: self.motions.into_iter().map(|scene| Sequence { split: Split::Test, scene }).collect(), metadata }
    }
}

/// Spherical interpolation between two noise vectors at weight `w` (linear when parallel).
pub fn slerp(a: &[f32], b: &[f32], w: f64) -> Vec<f32> {
    let dot: f64 = a.iter().zip(b).map(|(&x, &y)| x as f64 * y as f64).sum();
    let (na, nb) = (a.iter().map(|&x| (x as f64).powi(2)).sum::<f64>().sqrt(), b.iter().map(|&x| (x as f64).powi(2)).sum::<f64>().sqrt());
    let omega = (dot / (na * nb).max(1e-30)).clamp(-1.0, 1.0).acos();
    let (ca, cb) = if omega.sin().abs() < 1e-6 { (1.0 - w, w) } else { (((1.0 - w) * omega).sin() / omega.sin(), (w * omega).sin() / omega.sin()) };
    a.iter().zip(b).map(|(&x, &y)| (ca * x as f64 + cb * y as f64) as f32).collect()
}

/// What [`Model::forecast`] samples: frames observed and forecast, samples, sampler.
#[derive(Clone, Debug, PartialEq)]
pub struct Forecast {
    /// Frames observed from the start of the scene.
    pub observe: usize,
    /// Frames forecast after them.
    pub horizon: usize,
    /// Samples K.
    pub samples: usize,
    /// Sampler (default DDIM, 50 steps, η = 0).
    pub sampler: SamplerKind,
    /// How known entries are imposed.
    pub conditioning: Conditioning,
    /// Base seed.
    pub seed: u64,
    /// Context inversion of the observed frames; off by default.
    pub inversion: Option<ContextInversion>,
    /// Known frames at noise level 0: `None` as the model was trained.
    pub clean_known: Option<bool>,
    /// Map the scene's joints onto the model's by name when their layouts differ (else an
    /// error naming the first joint that differs).
    pub map_joints: bool,
}

impl Default for Forecast {
    fn default() -> Self {
        let o = ForecastOptions::default();
        Self {
            observe: 30,
            horizon: 90,
            samples: o.samples,
            sampler: o.sampler,
            conditioning: o.conditioning,
            seed: o.seed,
            inversion: None,
            clean_known: None,
            map_joints: false,
        }
    }
}

impl Forecast {
    /// The sampling options for `model`: its pose encoding, and its clean known frames unless
    /// [`Forecast::clean_known`] says.
    pub fn options(&self, model: &crate::train::LoadedModel) -> ForecastOptions {
        let o = ForecastOptions {
            samples: self.samples,
            sampler: self.sampler,
            conditioning: self.conditioning,
            seed: self.seed,
            inversion: self.inversion,
            clean_known: false,
            encoding: PoseEncoding::Absolute,
        }
        .for_model(model);
        ForecastOptions { clean_known: self.clean_known.unwrap_or(o.clean_known), ..o }
    }
}

impl Model {
    /// Loads the EMA weights of the run in `dir`.
    pub fn load(dir: impl AsRef<Path>) -> Result<Self> {
        Self::load_weights(dir, crate::train::checkpoint::Weights::Ema)
    }

    /// Loads the chosen weights of the run in `dir`, to sample on the CPU.
    pub fn load_weights(dir: impl AsRef<Path>, weights: crate::train::checkpoint::Weights) -> Result<Self> {
        Self::load_on(dir, weights, DeviceChoice::Cpu)
    }

    /// Loads the chosen weights of the run in `dir`, to sample on `device` (the sampling route
    /// of that device, [`SamplingNet`]).
    pub fn load_on(dir: impl AsRef<Path>, weights: crate::train::checkpoint::Weights, device: DeviceChoice) -> Result<Self> {
        let checkpoint = crate::train::checkpoint::Checkpoint::load_weights(dir, weights)?;
        let net = SamplingNet::new(&checkpoint.denoiser, &checkpoint.diffusion, &device.resolve()?).map_err(|e| e.in_file(&checkpoint.path))?;
        Ok(Self { checkpoint, net, guide: None })
    }

    /// This model guided by `weak` with weight `weight` ≥ 1 (autoguidance, see [`Guide`]):
    /// every prediction at a noise level t ≥ `from_level` becomes x̂0_weak + w·(x̂0 − x̂0_weak)
    /// (guidance in an interval, Kynkäänniemi et al. 2024: at low noise it would sharpen
    /// frame-to-frame detail into jitter). The two must share what makes
    /// their predictions comparable — skeleton, frame rate, features and their standardization,
    /// noise schedule and anchor frame — and errors name the first that differs. Each may
    /// predict x0, v or edm. Costs one more network call per denoising step.
    pub fn with_guide(mut self, weak: Model, weight: f64, from_level: usize) -> Result<Self> {
        if !(weight.is_finite() && weight >= 1.0) {
            bail!("guidance weight must be finite and ≥ 1 (1: no guidance), got {weight}");
        }
        let (m, w) = (&self.checkpoint, &weak.checkpoint);
        let differs = |what: &str| {
            Error::invalid(format!(
                "guide {}: its {what} differs from the model's ({}); a guide must be a weaker model of the same data",
                w.path.display(),
                m.path.display()
            ))
        };
        if m.skeleton.joints != w.skeleton.joints || m.skeleton.bones != w.skeleton.bones {
            return Err(differs("skeleton"));
        }
        if (m.fps - w.fps).abs() > 1e-9 {
            return Err(differs("frame rate"));
        }
        if m.config.pose != w.config.pose {
            return Err(differs("pose encoding"));
        }
        if m.standardization != w.standardization {
            return Err(differs("feature standardization (train both on the same data and windows)"));
        }
        if m.diffusion.schedule() != w.diffusion.schedule() {
            return Err(differs("noise schedule"));
        }
        if m.config.anchor_offset() != w.config.anchor_offset() {
            return Err(differs("anchor frame (training --observed)"));
        }
        if from_level >= m.diffusion.timesteps() {
            bail!("guidance from noise level {from_level}: the model has levels 0..{}", m.diffusion.timesteps());
        }
        let provenance = GuideProvenance { model: w.path.display().to_string(), model_step: w.step, weight, from_level };
        self.guide = Some(Guide { net: weak.net, weight: weight as f32, from_level, provenance });
        Ok(self)
    }

    /// The guide, when [`Model::with_guide`] set one.
    pub fn guide(&self) -> Option<&GuideProvenance> {
        self.guide.as_ref().map(|g| &g.provenance)
    }

    /// The network samples are drawn with (with the guide folded in, when there is one).
    pub fn net(&self) -> &dyn X0Model {
        self
    }

    /// Where samples are drawn (`cpu`, `cuda:0 f32 composed`).
    pub fn device(&self) -> String {
        self.net.describe()
    }

    /// `scene` in the model's skeleton and frame rate: joints mapped by name when `map_joints`
    /// and the layouts differ (the map is returned), resampled when the frame rates differ.
    /// Errors name the scene and what does not fit.
    pub fn fit_scene(&self, scene: &Scene, map_joints: bool) -> Result<(Scene, Option<crate::data::joint_map::JointMap>)> {
        let m = &self.checkpoint;
        let in_scene = |e: Error| Error::invalid(format!("scene {}: {e}", scene.name));
        let (scene, map) = match crate::train::checkpoint::check_skeleton(&m.meta, &m.path, &scene.skeleton) {
            Ok(()) => (scene.clone(), None),
            Err(e) if !map_joints => return Err(in_scene(e)),
            Err(_) => {
                let map = crate::data::joint_map::JointMap::by_names(&scene.skeleton, &m.skeleton, &[]).map_err(in_scene)?;
                let mut mapped = map.apply(scene).map_err(in_scene)?;
                mapped.skeleton = m.skeleton.clone();
                crate::train::checkpoint::check_skeleton(&m.meta, &m.path, &mapped.skeleton).map_err(in_scene)?;
                (mapped, Some(map))
            }
        };
        let scene = if (scene.fps - m.fps).abs() > 1e-6 * m.fps { scene.resample(m.fps).map_err(in_scene)? } else { scene };
        Ok((scene, map))
    }

    /// Samples `req.samples` futures of `scene`: its first `req.observe` frames (at the model's
    /// frame rate, after [`Model::fit_scene`]) continued by `req.horizon` frames.
    pub fn forecast(&self, scene: &Scene, req: Forecast) -> Result<ForecastOutput> {
        self.sample(scene, &Task::Forecast { observe: req.observe, horizon: req.horizon }, &req, &mut |_| {})
    }

    /// Completes what `missing` says of `scene` (frames, persons or joints).
    pub fn complete(&self, scene: &Scene, missing: Missing, req: Forecast) -> Result<ForecastOutput> {
        self.sample(scene, &Task::Complete(missing), &req, &mut |_| {})
    }

    /// Generates `frames` frames of the persons of `layout` from noise
    /// ([`Model::generate_task`]): each has the layout's root and heading at the model's anchor
    /// frame, its motion is sampled.
    pub fn generate(&self, layout: &Scene, frames: usize, req: Forecast) -> Result<ForecastOutput> {
        self.sample(layout, &self.generate_task(frames), &req, &mut |_| {})
    }

    /// The frame a placement or a motion is anchored at in a canvas of `frames` frames made
    /// from scratch (generation, interpolation): the model's training anchor frame (its
    /// observed frames − 1), or the last frame of a shorter canvas.
    pub fn anchor_frame(&self, frames: usize) -> usize {
        self.checkpoint.config.anchor_offset().min(frames.saturating_sub(1))
    }

    /// [`Task::Generate`] of `frames` frames with the placement at [`Model::anchor_frame`].
    pub fn generate_task(&self, frames: usize) -> Task {
        Task::Generate { frames, anchor: self.anchor_frame(frames) }
    }

    /// A one-frame layout of `persons` persons on a circle facing its centre (1 m apart along
    /// it, radius ≥ 0.8 m), each in the model's mean pose (the mean of its training
    /// features). A residual-pose model has no mean body: give it a recorded layout.
    pub fn circle_layout(&self, persons: usize) -> Result<Scene> {
        let m = &self.checkpoint;
        if persons == 0 {
            bail!("a layout needs at least one person");
        }
        crate::data::check_size("circle layout", 1.0, persons, 1)?;
        if m.config.pose == PoseEncoding::Residual {
            bail!("model {}: a residual-pose model generates around given bodies; give a layout scene", m.path.display());
        }
        let nj = m.skeleton.num_joints();
        let features = &m.standardization.mean;
        if features.len() != ROOT_DIMS + 3 * nj {
            bail!("model {}: standardization of {} dims for {nj} joints", m.path.display(), features.len());
        }
        let mut mean = features.clone();
        mean[..ROOT_DIMS].copy_from_slice(&[0.0, 0.0, 1.0, 0.0]);
        let radius = (persons as f64 / std::f64::consts::TAU).max(0.8);
        let mut pos = Array4::<f32>::zeros((1, persons, nj, 3));
        let mut out = vec![0f32; 3 * nj];
        for p in 0..persons {
            let theta = std::f64::consts::TAU * p as f64 / persons as f64;
            let at = crate::features::Anchor { root: [radius * theta.cos(), radius * theta.sin()], heading: theta + std::f64::consts::FRAC_PI_2 };
            crate::features::decode_frame(&mean, &at, &mut out);
            pos.slice_mut(s![0, p, .., ..]).iter_mut().zip(&out).for_each(|(o, &v)| *o = v);
        }
        Scene::new(format!("circle{persons}"), m.fps, m.skeleton.clone(), pos)
    }

    /// `req.steps` motions between scenes `a` and `b` (same persons and skeleton; the first
    /// `req.frames` frames of each, default the shorter length): each is mapped by
    /// deterministic DDIM inversion over `req.ddim_steps` steps to the noise level `req.depth`
    /// (default T − 1, pure noise), the two are interpolated spherically and the placements
    /// (root, heading, and a residual model's bodies) linearly, and each is denoised with DDIM,
    /// η = 0, from that level. `req.refine` > 0 corrects each inversion step by up to that many
    /// fixed-point iterations ([`crate::sample::ddim_invert`]), kept for an endpoint whose
    /// motion it brings closer to the input. Motion 0 and motion `steps − 1` are the
    /// reconstructions of `a` and `b`; [`Interpolation::endpoint_error`] says how close.
    pub fn interpolate(&self, a: &Scene, b: &Scene, req: &Interpolate) -> Result<Interpolation> {
        let Interpolate { steps, frames, ddim_steps, refine, depth } = *req;
        let m = &self.checkpoint;
        let (a, _) = self.fit_scene(a, false)?;
        let (b, _) = self.fit_scene(b, false)?;
        if steps < 2 {
            bail!("interpolating with {steps} steps: need at least 2 (the two endpoints)");
        }
        if a.num_persons() != b.num_persons() {
            bail!("scenes {} and {} have {} and {} persons; interpolation needs the same persons", a.name, b.name, a.num_persons(), b.num_persons());
        }
        let nf = frames.unwrap_or(a.num_frames().min(b.num_frames()));
        if nf < 2 || nf > a.num_frames() || nf > b.num_frames() {
            bail!(
                "interpolating {nf} frames: need 2 ≤ frames ≤ {} ({} has {}, {} has {})",
                a.num_frames().min(b.num_frames()),
                a.name,
                a.num_frames(),
                b.name,
                b.num_frames()
            );
        }
        crate::data::check_size(&format!("interpolation of {} and {}", a.name, b.name), nf as f64, a.num_persons(), steps)?;
        let np = a.num_persons();
        let persons: Vec<usize> = (0..np).collect();
        // Standardized features in the network's layout, and the placement they are relative to.
        let encode = |s: &Scene| -> Result<(Vec<f32>, PoseFeatures)> {
            let mut f = PoseFeatures::encode_as(s, 0..nf, &persons, self.anchor_frame(nf), m.config.pose)?;
            m.standardization.apply(&mut f.data)?;
            // [T, P, δ] → [1, P, T, δ]
            let x = f.data.view().permuted_axes([1, 0, 2]).as_standard_layout().iter().copied().collect();
            Ok((x, f))
        };
        let ((xa, fa), (xb, fb)) = (encode(&a)?, encode(&b)?);
        let dim = m.standardization.dim();
        let shape = [1, np, nf, dim];
        let anchor_rows = |an: &[crate::features::Anchor]| -> Vec<f32> {
            an.iter().flat_map(|q| [q.root[0] as f32, q.root[1] as f32, q.heading.cos() as f32, q.heading.sin() as f32]).collect()
        };
        let schedule = m.diffusion.schedule();
        let top = depth.unwrap_or(schedule.timesteps() - 1);
        if top == 0 || top >= schedule.timesteps() {
            bail!("interpolating at noise level {top}: need 1 ≤ level ≤ {} (the model's T − 1)", schedule.timesteps() - 1);
        }
        if ddim_steps > top + 1 {
            bail!("interpolating with {ddim_steps} DDIM steps up to noise level {top}: at most {} steps", top + 1);
        }
        let sampler = Ddim::with_timesteps(schedule, socdiff_schedules::respaced_timesteps(top + 1, ddim_steps)?, 0.0)?;
        // Motion k of the interpolation, denoised from the noise `z`.
        let motion = |z: Vec<f32>, k: usize| -> Result<Scene> {
            let w = k as f64 / (steps - 1) as f64;
            let anchors: Vec<crate::features::Anchor> = fa
                .anchors
                .iter()
                .zip(&fb.anchors)
                .map(|(p, q)| {
                    let dh = (q.heading - p.heading + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
                    crate::features::Anchor {
                        root: [p.root[0] + w * (q.root[0] - p.root[0]), p.root[1] + w * (q.root[1] - p.root[1])],
                        heading: p.heading + w * dh,
                    }
                })
                .collect();
            let offsets = match (&fa.offsets, &fb.offsets) {
                (Some(oa), Some(ob)) => Some(oa * (1.0 - w as f32) + ob * w as f32),
                _ => None,
            };
            let x = crate::sample::ddim_denoise(self.net(), &sampler, z, shape, Some(&anchor_rows(&anchors)))?;
            let mut data = Array3::from_shape_vec((np, nf, dim), x).expect("shape").permuted_axes([1, 0, 2]).as_standard_layout().into_owned();
            m.standardization.invert(&mut data)?;
            let pos = PoseFeatures::with_encoding(data, anchors, offsets)?.to_positions()?;
            Scene::new(format!("{}_to_{}_{k:02}", a.name, b.name,), m.fps, m.skeleton.clone(), pos)
        };
        // MPJPE over every frame (the evaluator's pose error, one sample).
        let err = |x: &Scene, y: &Scene| -> Result<f64> {
            let (l, r) = (y.skeleton.left, y.skeleton.right);
            let e = crate::metrics::distance::pose_error_curve(
                x.positions.view().insert_axis(Axis(0)),
                y.positions.slice(s![..nf, .., .., ..]),
                l,
                r,
                crate::metrics::distance::PoseError::Global,
            )?;
            Ok(e.mean().unwrap_or(f64::NAN))
        };
        // An endpoint's noise and its motion. A refined inversion is kept only where its motion
        // is closer to the input than the plain one's: a model whose prediction at low noise does
        // not pass its input through (x0 prediction) may have no exact inverse, and the
        // refinement can then drift.
        let invert = |x: &[f32], f: &PoseFeatures, input: &Scene, k: usize| -> Result<(Vec<f32>, Scene, f64, bool)> {
            let anchors = anchor_rows(&f.anchors);
            let plain = crate::sample::ddim_invert(self.net(), schedule, &sampler, x, shape, Some(&anchors), 0)?;
            let plain_motion = motion(plain.noise.clone(), k)?;
            if refine == 0 {
                return Ok((plain.noise, plain_motion, 0.0, false));
            }
            let refined = crate::sample::ddim_invert(self.net(), schedule, &sampler, x, shape, Some(&anchors), refine)?;
            let refined_motion = motion(refined.noise.clone(), k)?;
            let residual = refined.residuals.iter().copied().fold(0.0, f64::max);
            Ok(if err(&refined_motion, input)? <= err(&plain_motion, input)? {
                (refined.noise, refined_motion, residual, true)
            } else {
                (plain.noise, plain_motion, residual, false)
            })
        };
        let (za, first, ra, ka) = invert(&xa, &fa, &a, 0)?;
        let (zb, last, rb, kb) = invert(&xb, &fb, &b, steps - 1)?;
        let (inversion_residual, refined) = ([ra, rb], [ka, kb]);
        let mut motions = Vec::with_capacity(steps);
        motions.push(first);
        for k in 1..steps - 1 {
            motions.push(motion(slerp(&za, &zb, k as f64 / (steps - 1) as f64), k)?);
        }
        motions.push(last);
        let endpoint_error = [err(&motions[0], &a)?, err(&motions[steps - 1], &b)?];
        use crate::metrics::distance::{largest_frame_step, mean_root_speed};
        let speed = |s: &Scene| mean_root_speed(s.positions.slice(s![..nf, .., .., ..]), s.skeleton.left, s.skeleton.right, s.fps);
        let step = |s: &Scene| largest_frame_step(s.positions.slice(s![..nf, .., .., ..]));
        Ok(Interpolation {
            root_speed: motions.iter().map(speed).collect::<Result<_>>()?,
            largest_step: motions.iter().map(step).collect(),
            input_root_speed: [speed(&a)?, speed(&b)?],
            input_largest_step: [step(&a), step(&b)],
            motions,
            endpoint_error,
            ddim_steps,
            depth: top,
            refine,
            inversion_residual,
            refined,
            model: (m.path.display().to_string(), m.step),
            name: format!("{}_to_{}", a.name, b.name),
        })
    }

    /// `a`'s motion, then `frames` generated frames (DDIM, η = 0, `ddim_steps` steps, `seed`),
    /// then `b`'s ([`transition_scene`] completed through [`Model::sample`]).
    pub fn transition(&self, a: &Scene, b: &Scene, frames: usize, ddim_steps: usize, seed: u64) -> Result<ForecastOutput> {
        let (a, _) = self.fit_scene(a, false)?;
        let (b, _) = self.fit_scene(b, false)?;
        let scene = transition_scene(&a, &b, frames)?;
        let task = Task::Complete(Missing::Frames(a.num_frames()..a.num_frames() + frames));
        let req = Forecast { samples: 1, sampler: SamplerKind::Ddim { steps: ddim_steps, eta: 0.0 }, seed, ..Default::default() };
        self.sample(&scene, &task, &req, &mut |_| {})
    }

    /// [`Model::forecast`] / [`Model::complete`] for any task, reporting each denoising step.
    pub fn sample(&self, scene: &Scene, task: &Task, req: &Forecast, on_step: &mut dyn FnMut(StepInfo)) -> Result<ForecastOutput> {
        let (scene, _) = self.fit_scene(scene, req.map_joints)?;
        let m = &self.checkpoint;
        let mut fc = sample_scene(self.net(), m.diffusion.schedule(), &m.standardization, &scene, task, &req.options(m), on_step)
            .map_err(|e| Error::invalid(format!("scene {}: {e}", scene.name)))?;
        fc.provenance.model = Some(m.path.display().to_string());
        fc.provenance.model_step = Some(m.step);
        fc.provenance.device = Some(self.device());
        fc.provenance.guide = self.guide().cloned();
        Ok(fc)
    }
}

impl Model {
    /// `f` applied to the network samples are drawn with: the sampling net, or the sampling
    /// net guided by the guide's ([`crate::sample::Autoguided`]).
    fn with_route<R>(&self, f: impl FnOnce(&dyn X0Model) -> R) -> R {
        match &self.guide {
            None => f(&self.net),
            Some(g) => f(&crate::sample::Autoguided { model: &self.net, weak: &g.net, weight: g.weight, from_level: g.from_level }),
        }
    }
}

impl X0Model for Model {
    fn feature_dims(&self) -> usize {
        self.net.feature_dims()
    }

    fn max_batch(&self, persons: usize, frames: usize) -> usize {
        self.with_route(|n| n.max_batch(persons, frames))
    }

    fn frames_ahead(&self) -> usize {
        self.with_route(|n| n.frames_ahead())
    }

    fn predict_x0(&self, x: &[f32], shape: [usize; 4], t: &[usize], anchors: Option<&[f32]>, out: &mut [f32]) -> Result<()> {
        self.with_route(|n| n.predict_x0(x, shape, t, anchors, out))
    }

    fn input_gradient(&self, x: &[f32], shape: [usize; 4], t: usize, anchors: Option<&[f32]>, target: &[f32], weight: &[f32]) -> Result<Option<Vec<f32>>> {
        self.with_route(|n| n.input_gradient(x, shape, t, anchors, target, weight))
    }
}

/// The known-value mask of a task in feature space (`δ = 4 + 3J`).
///
/// # Shapes
/// - returns `[frames, persons, 4 + 3·joints]` (`frames` = observe + horizon for a forecast)
pub fn task_mask(task: &Task, frames: usize, persons: usize, joints: usize, body_joints: (usize, usize)) -> Array3<bool> {
    let dim = ROOT_DIMS + 3 * joints;
    match task {
        Task::Forecast { observe, .. } => crate::sample::forecast_mask(frames, persons, dim, *observe),
        Task::Complete(Missing::Frames(r)) => Array3::from_shape_fn((frames, persons, dim), |(f, _, _)| !r.contains(&f)),
        Task::Complete(Missing::Persons(v)) => Array3::from_shape_fn((frames, persons, dim), |(_, p, _)| !v.contains(&p)),
        Task::Complete(Missing::Joints(v)) => {
            let root_missing = v.contains(&body_joints.0) || v.contains(&body_joints.1);
            Array3::from_shape_fn((frames, persons, dim), |(_, _, d)| if d < ROOT_DIMS { !root_missing } else { !v.contains(&((d - ROOT_DIMS) / 3)) })
        }
        Task::Generate { anchor, .. } => Array3::from_shape_fn((frames, persons, dim), |(f, _, d)| f == *anchor && d < ROOT_DIMS),
    }
}

/// A scene turned into a canvas.
#[derive(Clone, Debug)]
pub struct Canvas {
    /// Standardized anchored features, zero where unknown. `[frames, persons, δ]`.
    pub values: Array3<f32>,
    /// Known entries. `[frames, persons, δ]`.
    pub mask: Array3<bool>,
    /// Each person's anchor (world frame).
    pub anchors: Vec<crate::features::Anchor>,
    /// Residual encoding: each person's local joints at the anchor frame, `[persons, 3J]`.
    pub offsets: Option<Array2<f32>>,
    /// The scene frame the persons are anchored at.
    pub anchor_frame: usize,
    /// The input part the canvas was built from (frames `0..observe` for a forecast, the whole
    /// scene for a completion).
    pub input: Scene,
}

impl Canvas {
    /// Anchors as `(root_x, root_y, cos h, sin h)`. `[persons, 4]`.
    pub fn anchor_array(&self) -> Array2<f32> {
        let mut a = Array2::zeros((self.anchors.len(), 4));
        for (p, an) in self.anchors.iter().enumerate() {
            a[[p, 0]] = an.root[0] as f32;
            a[[p, 1]] = an.root[1] as f32;
            a[[p, 2]] = an.heading.cos() as f32;
            a[[p, 3]] = an.heading.sin() as f32;
        }
        a
    }
}

/// Checks a task against a scene; the error says what is wrong.
pub fn check_task(scene: &Scene, task: &Task) -> Result<()> {
    let (nf, np, nj) = (scene.num_frames(), scene.num_persons(), scene.num_joints());
    match task {
        Task::Forecast { observe, horizon } => {
            if *observe == 0 {
                bail!("`observe` must be at least 1");
            }
            if *observe >= nf {
                bail!("`observe` {observe} must be less than the scene length ({nf} frames in {})", scene.name);
            }
            if *horizon == 0 {
                bail!("`horizon` must be at least 1");
            }
            crate::data::check_size(&format!("forecast of {}", scene.name), *observe as f64 + *horizon as f64, np, 1)?;
        }
        Task::Complete(Missing::Frames(r)) => {
            if r.start >= r.end || r.end > nf {
                bail!("`missing` frames={}..{}: not a non-empty part of 0..{nf} ({})", r.start, r.end, scene.name);
            }
            if r.start == 0 && r.end == nf {
                bail!("`missing` frames={}..{}: every frame missing, nothing to complete from", r.start, r.end);
            }
        }
        Task::Complete(Missing::Persons(v)) => {
            if v.is_empty() {
                bail!("`missing` persons=: no persons given");
            }
            if let Some(p) = v.iter().find(|&&p| p >= np) {
                bail!("`missing` persons: person {p} out of range ({} has {np} persons)", scene.name);
            }
            if (0..np).all(|p| v.contains(&p)) {
                bail!("`missing` persons: every person missing, nothing to complete from");
            }
        }
        Task::Complete(Missing::Joints(v)) => {
            if v.is_empty() {
                bail!("`missing` joints=: no joints given");
            }
            if let Some(j) = v.iter().find(|&&j| j >= nj) {
                bail!("`missing` joints: joint {j} out of range (skeleton {} has {nj} joints)", scene.skeleton.name);
            }
        }
        Task::Generate { frames, anchor } => {
            if *frames < 2 {
                bail!("generating {frames} frames: need at least 2");
            }
            if anchor >= frames {
                bail!("generating {frames} frames with the placement at frame {anchor}: it must be one of them");
            }
            crate::data::check_size(&format!("generation from the layout of {}", scene.name), *frames as f64, np, 1)?;
        }
    }
    Ok(())
}

/// Frames of the canvas of `task` on `scene`: observed + forecast frames, or the scene's.
pub fn canvas_frames(scene: &Scene, task: &Task) -> usize {
    match task {
        Task::Forecast { observe, horizon } => observe.saturating_add(*horizon),
        Task::Complete(_) => scene.num_frames(),
        Task::Generate { frames, .. } => *frames,
    }
}

/// Builds the canvas of `task` on `scene`, standardized with `std`.
pub fn build_canvas(scene: &Scene, task: &Task, std: &Standardization, encoding: PoseEncoding) -> Result<Canvas> {
    check_task(scene, task)?;
    let (nf, np, nj) = (scene.num_frames(), scene.num_persons(), scene.num_joints());
    let persons: Vec<usize> = (0..np).collect();
    let frames = canvas_frames(scene, task);
    // The input, the canvas frame its first frame goes to, and the canvas's anchor frame (a
    // generated canvas holds the layout's frame 0 at its anchor frame).
    let (input, first_row, anchor_frame) = match task {
        Task::Forecast { observe, .. } => (scene.slice_frames(0, *observe)?, 0, observe - 1),
        Task::Complete(Missing::Frames(r)) => (scene.clone(), 0, if r.start > 0 { r.start - 1 } else { r.end }),
        Task::Complete(_) => (scene.clone(), 0, nf - 1),
        Task::Generate { anchor, .. } => (scene.slice_frames(0, 1)?, *anchor, *anchor),
    };
    let feats = PoseFeatures::encode_as(&input, 0..input.num_frames(), &persons, anchor_frame - first_row, encoding)?;
    let dim = feats.dim();
    if std.dim() != dim {
        bail!("the model's standardization has {} dims, the scene's features {dim}", std.dim());
    }
    let mut known = feats.data;
    std.apply(&mut known)?;
    let mask = task_mask(task, frames, np, nj, (scene.skeleton.left, scene.skeleton.right));
    let mut values = Array3::<f32>::zeros((frames, np, dim));
    values.slice_mut(s![first_row..first_row + input.num_frames(), .., ..]).assign(&known);
    values.zip_mut_with(&mask, |v, &m| {
        if !m {
            *v = 0.0
        }
    });
    Ok(Canvas { values, mask, anchors: feats.anchors, offsets: feats.offsets, anchor_frame, input })
}

/// The result of [`sample_scene`]: the input part, K sample scenes and provenance.
#[derive(Clone, Debug)]
pub struct ForecastOutput {
    /// Name of the forecast scene (the `source` of every sample).
    pub source: String,
    /// The input part (observed frames, or the scene being completed).
    pub input: Scene,
    /// Sample k, `[canvas frames, persons, J, 3]` world positions.
    pub samples: Vec<Scene>,
    /// The recorded frames of the whole canvas, when the scene has them (forecast only): the
    /// ground truth, written with `"ground_truth": true`.
    pub ground_truth: Option<Scene>,
    /// Frames `0..observed_frames` of every sample are observed (0 for joint/person completion).
    pub observed_frames: usize,
    /// Model, sampler, steps, seed, mask, timings.
    pub provenance: Provenance,
}

/// How a forecast was made, written with it (its dataset's `metadata["forecast"]`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Provenance {
    /// Name of the scene sampled.
    pub source: String,
    /// What was sampled (`{"kind": "forecast", "observe", "horizon"}`, `{"kind": "complete",
    /// "missing": "frames=a..b"}` or `{"kind": "generate", "frames"}`).
    #[serde(serialize_with = "task_json")]
    pub task: Task,
    /// The sampler.
    pub sampler: SamplerKind,
    /// Denoising steps per sample.
    pub steps: usize,
    /// How known entries were imposed.
    pub conditioning: Conditioning,
    /// Known frames at noise level 0.
    pub clean_known: bool,
    /// The features the model was trained on.
    pub pose_encoding: PoseEncoding,
    /// Base seed.
    pub seed: u64,
    /// Context inversion of the observed frames, when on.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub context_inversion: Option<crate::sample::ContextInversion>,
    /// The seed of each sample ([`sample_seed`]).
    pub sample_seeds: Vec<u64>,
    /// Samples K.
    pub samples: usize,
    /// Frame every person is anchored at.
    pub anchor_frame: usize,
    /// The known entries of the canvas.
    pub mask: MaskSummary,
    /// Where the time went.
    pub timings: Timings,
    /// The run directory of the model, when a [`Model`] sampled.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub model: Option<String>,
    /// Its optimizer step.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub model_step: Option<u64>,
    /// Which of its weights.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub weights: Option<crate::train::Weights>,
    /// Where it ran ([`crate::model::Placement::describe`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub device: Option<String>,
    /// The file or directory the scene came from.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub input: Option<String>,
    /// Persons of the scene that were kept, by index (all when absent).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub persons: Option<Vec<usize>>,
    /// Where the placement of generated persons came from.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub layout: Option<String>,
    /// The weaker model that guided the samples, when one did ([`Model::with_guide`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub guide: Option<GuideProvenance>,
}

/// The known entries of a sampling canvas `[frames, persons, dims]`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct MaskSummary {
    /// Canvas frames.
    pub frames: usize,
    /// Persons.
    pub persons: usize,
    /// Feature dims per person and frame.
    pub dims: usize,
    /// Entries copied from the input.
    pub known_entries: usize,
}

/// Seconds spent by [`sample_scene`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Timings {
    /// Everything, from the canvas to the positions.
    pub total_seconds: f64,
    /// The reverse process.
    pub sampling_seconds: f64,
    /// Inside the network.
    pub model_seconds: f64,
    /// Network evaluations (each on a batch of samples).
    pub model_calls: usize,
    /// Samples per evaluation.
    pub samples_per_call: usize,
    /// Sampling seconds per network evaluation.
    pub seconds_per_step: f64,
    /// Sampling seconds per sample and denoising step.
    pub seconds_per_sample_step: f64,
}

fn task_json<S: serde::Serializer>(task: &Task, s: S) -> std::result::Result<S::Ok, S::Error> {
    match task {
        Task::Forecast { observe, horizon } => json!({"kind": "forecast", "observe": observe, "horizon": horizon}),
        Task::Complete(m) => json!({"kind": "complete", "missing": m.describe()}),
        Task::Generate { frames, anchor } => json!({"kind": "generate", "frames": frames, "anchor": anchor}),
    }
    .serialize(s)
}

impl Provenance {
    /// A record of `task` on the scene `source` with only the task and source set (the rest
    /// zero or absent).
    pub fn of(source: &str, task: Task) -> Self {
        Self {
            source: source.to_string(),
            task,
            sampler: SamplerKind::Ddpm,
            steps: 0,
            conditioning: Conditioning::default(),
            clean_known: false,
            pose_encoding: PoseEncoding::default(),
            seed: 0,
            context_inversion: None,
            sample_seeds: Vec::new(),
            samples: 0,
            anchor_frame: 0,
            mask: MaskSummary::default(),
            timings: Timings::default(),
            model: None,
            model_step: None,
            weights: None,
            device: None,
            input: None,
            persons: None,
            layout: None,
            guide: None,
        }
    }
}

/// Samples `opts.samples` completions of `task` on `scene` with `model` (a frozen network) and
/// the diffusion `schedule`, reporting each denoising step to `on_step`.
pub fn sample_scene(
    model: &dyn X0Model,
    schedule: &NoiseSchedule,
    std: &Standardization,
    scene: &Scene,
    task: &Task,
    opts: &ForecastOptions,
    on_step: &mut dyn FnMut(StepInfo),
) -> Result<ForecastOutput> {
    check_task(scene, task)?;
    crate::data::check_size(&format!("forecast of {}", scene.name), canvas_frames(scene, task) as f64, scene.num_persons(), opts.samples)?;
    if opts.samples == 0 {
        bail!("`samples` must be at least 1");
    }
    let start = Instant::now();
    let canvas = build_canvas(scene, task, std, opts.encoding)?;
    let sampler = opts.sampler.build(schedule)?;
    let anchors = canvas.anchor_array();
    let known = Known { values: canvas.values.view(), mask: canvas.mask.view(), anchors: Some(anchors.view()) };
    let steps = sampler.timesteps().len();
    let (nf, np, dim) = canvas.values.dim();
    let nj = scene.num_joints();
    // Entries (frame, person, joint) copied from the input: joint and root dims all known.
    let copy = Array3::from_shape_fn((canvas.input.num_frames(), np, nj), |(f, p, j)| {
        (0..ROOT_DIMS).chain(ROOT_DIMS + 3 * j..ROOT_DIMS + 3 * j + 3).all(|d| canvas.mask[[f, p, d]])
    });
    let observed_frames = match task {
        Task::Forecast { observe, .. } => *observe,
        Task::Complete(Missing::Frames(r)) => r.start,
        Task::Complete(_) | Task::Generate { .. } => 0,
    };
    let seeds: Vec<u64> = (0..opts.samples).map(|k| sample_seed(opts.seed, k)).collect();
    let mut model_seconds = 0.0;
    let mut model_calls = 0usize;
    let t0 = Instant::now();
    let inpaint_opts =
        InpaintOptions { samples: opts.samples, conditioning: opts.conditioning, seed: opts.seed, inversion: opts.inversion, clean_known: opts.clean_known };
    let out = inpaint_with_progress(model, sampler.as_ref(), &known, &inpaint_opts, &mut |i| {
        model_seconds += i.seconds;
        model_calls += 1;
        on_step(i)
    })?;
    let sampling_seconds = t0.elapsed().as_secs_f64();
    let mut samples = Vec::with_capacity(opts.samples);
    for k in 0..opts.samples {
        let mut data = out.index_axis(Axis(0), k).to_owned();
        std.invert(&mut data)?;
        debug_assert_eq!(data.dim(), (nf, np, dim));
        let mut pos: Array4<f32> = PoseFeatures::with_encoding(data, canvas.anchors.clone(), canvas.offsets.clone())?.to_positions()?;
        for ((f, p, j), &c) in copy.indexed_iter() {
            if c {
                for x in 0..3 {
                    pos[[f, p, j, x]] = canvas.input.positions[[f, p, j, x]];
                }
            }
        }
        let mut sc = Scene::new(format!("{}_s{k:02}", scene.name), scene.fps, scene.skeleton.clone(), pos)?.with_persons(scene.persons.clone())?;
        ForecastInfo { observed_frames, sample: Some(k), source: scene.name.clone() }.insert_into(&mut sc.metadata);
        samples.push(sc);
    }
    let total = start.elapsed().as_secs_f64();
    let sample_steps = (steps * opts.samples) as f64;
    let prov = Provenance {
        sampler: opts.sampler,
        steps,
        conditioning: opts.conditioning,
        clean_known: opts.clean_known,
        pose_encoding: opts.encoding,
        seed: opts.seed,
        context_inversion: opts.inversion,
        sample_seeds: seeds,
        samples: opts.samples,
        anchor_frame: canvas.anchor_frame,
        mask: MaskSummary { frames: nf, persons: np, dims: dim, known_entries: canvas.mask.iter().filter(|&&m| m).count() },
        timings: Timings {
            total_seconds: total,
            sampling_seconds,
            model_seconds,
            model_calls,
            samples_per_call: opts.samples.div_ceil((model_calls / steps.max(1)).max(1)),
            seconds_per_step: sampling_seconds / model_calls.max(1) as f64,
            seconds_per_sample_step: sampling_seconds / sample_steps,
        },
        ..Provenance::of(&scene.name, task.clone())
    };
    let mut input = canvas.input.clone();
    input.name = format!("{}_input", scene.name);
    let ground_truth = match task {
        Task::Forecast { .. } if scene.num_frames() >= nf => {
            let mut gt = scene.slice_frames(0, nf)?;
            gt.name = format!("{}_gt", scene.name);
            ForecastInfo { observed_frames, sample: None, source: scene.name.clone() }.insert_into(&mut gt.metadata);
            Some(gt)
        }
        _ => None,
    };
    Ok(ForecastOutput { source: scene.name.clone(), input, samples, ground_truth, observed_frames, provenance: prov })
}

impl ForecastOutput {
    /// The forecast as a dataset (test split): the input part, the ground truth (if any), then
    /// the samples; provenance in the dataset metadata under `"forecast"`.
    pub fn to_dataset(&self) -> Dataset {
        let mut sequences = vec![Sequence { split: Split::Test, scene: self.input.clone() }];
        if let Some(gt) = &self.ground_truth {
            sequences.push(Sequence { split: Split::Test, scene: gt.clone() });
        }
        sequences.extend(self.samples.iter().map(|s| Sequence { split: Split::Test, scene: s.clone() }));
        let mut metadata = Map::new();
        metadata.insert("forecast".into(), serde_json::to_value(&self.provenance).unwrap_or(Value::Null));
        Dataset { name: format!("{}_forecast", self.source), sequences, metadata }
    }

    /// Writes [`ForecastOutput::to_dataset`] to `dir` (which must not exist or be empty).
    pub fn write(&self, dir: &Path) -> Result<()> {
        write_dataset(&self.to_dataset(), dir)
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
    let opts = ForecastOptions {
        samples: 1,
        sampler,
        conditioning: Conditioning::Replace,
        seed: 1,
        inversion: None,
        clean_known: false,
        encoding: PoseEncoding::Absolute,
    };
    sample_scene(model, &NoiseSchedule::default(), &std, &scene, &Task::Forecast { observe, horizon }, &opts, on_step)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::test_util::walkers;
    use crate::model::{Aggregator, InferenceNet};

    fn tiny_model() -> InferenceNet {
        let cfg = DenoiserConfig {
            feature_dims: 4 + 3 * 17,
            hidden: 16,
            time_dim: 16,
            fourier_dim: 8,
            social_dim: 16,
            aggregator: Aggregator::Mean,
            ..Default::default()
        };
        InferenceNet::new(&Denoiser::new(cfg, 5).unwrap()).unwrap()
    }

    fn std_of(scene: &Scene) -> Standardization {
        let f = PoseFeatures::from_scene(scene, scene.num_frames() / 2).unwrap();
        Standardization::fit([f.data.view()]).unwrap()
    }

    fn run(model: &InferenceNet, scene: &Scene, task: &Task, samples: usize, seed: u64) -> ForecastOutput {
        let schedule = NoiseSchedule::default();
        let opts = ForecastOptions {
            samples,
            sampler: SamplerKind::Ddim { steps: 4, eta: 0.5 },
            conditioning: Conditioning::Replace,
            seed,
            inversion: None,
            clean_known: false,
            encoding: PoseEncoding::Absolute,
        };
        sample_scene(model, &schedule, &std_of(&walkers(40, 3, 0.0)), scene, task, &opts, &mut |_| {}).unwrap()
    }

    #[test]
    fn sampler_names_round_trip() {
        for (name, kind) in
            [("ddpm", SamplerKind::Ddpm), ("ddim20", SamplerKind::Ddim { steps: 20, eta: 0.0 }), ("ddim1", SamplerKind::Ddim { steps: 1, eta: 0.0 })]
        {
            assert_eq!(SamplerKind::parse(name).unwrap(), kind);
            assert_eq!(kind.name(), name);
        }
        assert_eq!(SamplerKind::Ddim { steps: 10, eta: 0.5 }.name(), "ddim10-eta0.5");
        for bad in ["ddim0", "ddim", "ddimx", "dpm", ""] {
            assert!(SamplerKind::parse(bad).unwrap_err().to_string().contains("ddpm or ddimN"), "{bad}");
        }
        let json = serde_json::to_value(SamplerKind::Ddim { steps: 20, eta: 0.0 }).unwrap();
        assert_eq!(json, serde_json::json!({"kind": "ddim", "steps": 20, "eta": 0.0}));
        assert_eq!(serde_json::to_value(SamplerKind::Ddpm).unwrap(), serde_json::json!({"kind": "ddpm"}));
    }

    #[test]
    fn seeds_reproduce_bit_for_bit_and_sample_k_is_independent_of_k() {
        let m = tiny_model();
        let scene = walkers(20, 3, 0.3);
        let task = Task::Forecast { observe: 8, horizon: 12 };
        let a = run(&m, &scene, &task, 3, 11);
        let b = run(&m, &scene, &task, 3, 11);
        assert_eq!(a.samples.len(), 3);
        for (x, y) in a.samples.iter().zip(&b.samples) {
            assert_eq!(x.positions, y.positions);
        }
        assert_eq!(a.samples[0].positions.dim(), (20, 3, 17, 3));
        assert_ne!(a.samples[0].positions, a.samples[1].positions);
        let one = run(&m, &scene, &task, 1, 11);
        assert_eq!(one.samples[0].positions, a.samples[0].positions);
        let other = run(&m, &scene, &task, 1, 12);
        assert_ne!(other.samples[0].positions, a.samples[0].positions);
        assert_ne!(sample_seed(1, 0), sample_seed(1, 1));
        assert_ne!(sample_seed(1, 0), sample_seed(2, 0));
    }

    #[test]
    fn observed_frames_equal_the_input_exactly() {
        let m = tiny_model();
        let scene = walkers(30, 2, 1.0);
        for (cond, encoding) in
            [(Conditioning::Replace, PoseEncoding::Absolute), (Conditioning::Noised, PoseEncoding::Absolute), (Conditioning::Replace, PoseEncoding::Residual)]
        {
            let schedule = NoiseSchedule::default();
            let opts = ForecastOptions {
                samples: 2,
                sampler: SamplerKind::Ddim { steps: 3, eta: 1.0 },
                conditioning: cond,
                seed: 1,
                inversion: None,
                clean_known: false,
                encoding,
            };
            let fc = sample_scene(&m, &schedule, &std_of(&scene), &scene, &Task::Forecast { observe: 10, horizon: 25 }, &opts, &mut |_| {}).unwrap();
            assert_eq!(fc.input.positions, scene.positions.slice(s![..10, .., .., ..]));
            for smp in &fc.samples {
                assert_eq!(smp.positions.dim().0, 35);
                assert_eq!(smp.positions.slice(s![..10, .., .., ..]), fc.input.positions);
                assert!(smp.positions.iter().all(|v| v.is_finite()));
                let info = ForecastInfo::from_scene(smp).unwrap().unwrap();
                assert_eq!((info.observed_frames, info.source.as_str()), (10, "walkers"));
            }
        }
    }

    #[test]
    fn forecast_is_equivariant_to_rigid_motion_of_the_scene() {
        let m = tiny_model();
        let scene = walkers(16, 3, 0.5);
        let task = Task::Forecast { observe: 6, horizon: 10 };
        let base = run(&m, &scene, &task, 1, 4);
        let (th, t): (f64, [f64; 3]) = (0.7, [3.0, -2.0, 0.0]);
        let rot = [[th.cos(), -th.sin(), 0.0], [th.sin(), th.cos(), 0.0], [0.0, 0.0, 1.0]];
        let mut moved = scene.clone();
        moved.transform(rot, t);
        let out = run(&m, &moved, &task, 1, 4);
        let mut want = base.samples[0].clone();
        want.transform(rot, t);
        let err = want.positions.iter().zip(out.samples[0].positions.iter()).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        println!("equivariance: max |Δ| = {err:.2e} m");
        assert!(err < 1e-4, "max error {err}");
        // The forecast moved at all (the model is not ignoring its input).
        assert!(base.samples[0].positions.slice(s![6.., .., .., ..]).iter().any(|v| v.abs() > 1e-3));
    }

    #[test]
    fn minute_long_forecast_of_seven_persons_in_one_pass() {
        // 128 observed + 1800 forecast frames at 30 Hz, 7 persons (the network takes any P).
        let m = tiny_model();
        let scene = walkers(130, 7, 0.1);
        let schedule = NoiseSchedule::default();
        let opts = ForecastOptions {
            samples: 1,
            sampler: SamplerKind::Ddim { steps: 2, eta: 0.0 },
            conditioning: Conditioning::Replace,
            seed: 9,
            inversion: None,
            clean_known: false,
            encoding: PoseEncoding::Absolute,
        };
        let mut calls = 0;
        let fc = sample_scene(&m, &schedule, &std_of(&scene), &scene, &Task::Forecast { observe: 128, horizon: 1800 }, &opts, &mut |i| {
            assert_eq!((i.samples, i.step, i.steps), (0..1, calls, 2));
            calls += 1;
        })
        .unwrap();
        assert_eq!(calls, 2);
        assert_eq!(fc.samples[0].positions.dim(), (1928, 7, 17, 3));
        assert!(fc.samples[0].positions.iter().all(|v| v.is_finite()));
        assert!(fc.ground_truth.is_none(), "the scene has no recorded future");
        // With a recorded future, the ground truth is written too and the viewer groups it.
        let long = walkers(40, 2, 0.0);
        let fc = sample_scene(&m, &schedule, &std_of(&long), &long, &Task::Forecast { observe: 10, horizon: 30 }, &opts, &mut |_| {}).unwrap();
        let gt = fc.ground_truth.as_ref().unwrap();
        assert_eq!(ForecastInfo::from_scene(gt).unwrap().unwrap().sample, None);
        let ds = fc.to_dataset();
        assert_eq!(ds.sequences.len(), 3);
        let groups = crate::export::group_scenes(&ds, None).unwrap();
        assert!(groups.iter().any(|g| g.samples.len() == 2 && g.observed_frames == 10));
    }

    /// x̂0 = one fixed standardized pose per person on every frame (a model of standing still).
    struct StandStill(Vec<f32>);

    impl X0Model for StandStill {
        fn feature_dims(&self) -> usize {
            self.0.len() / 3
        }
        fn predict_x0(&self, _x: &[f32], shape: [usize; 4], _t: &[usize], _anchors: Option<&[f32]>, out: &mut [f32]) -> Result<()> {
            let [b, p, t, d] = shape;
            for (i, o) in out.chunks_exact_mut(d).enumerate() {
                let person = i / t % p;
                o.copy_from_slice(&self.0[person * d..][..d]);
                debug_assert!(i < b * p * t);
            }
            Ok(())
        }
    }

    /// Generation: N frames per sample, only the placement at the anchor frame known (the
    /// anchors). With a model that predicts the layout's own pose, every generated frame is the
    /// layout, so placement, encoding and decoding line up wherever the anchor frame is; a
    /// random network gives finite scenes; fewer than 2 frames, or an anchor frame outside
    /// them, is an error.
    #[test]
    fn generation_keeps_the_layout_placement_and_samples_the_rest() {
        let layout = walkers(1, 3, 0.7);
        let std = std_of(&walkers(40, 3, 0.0));
        let mut pose = PoseFeatures::encode(&layout, 0..1, &[0, 1, 2], 0).unwrap().data;
        std.apply(&mut pose).unwrap();
        let still = StandStill(pose.iter().copied().collect());
        for anchor in [0, 29] {
            let task = Task::Generate { frames: 40, anchor };
            let mask = task_mask(&task, 40, 3, 17, (layout.skeleton.left, layout.skeleton.right));
            assert_eq!(mask.iter().filter(|&&k| k).count(), 3 * ROOT_DIMS);
            assert!((0..3).all(|p| (0..ROOT_DIMS).all(|d| mask[[anchor, p, d]])));
            let opts = ForecastOptions { samples: 2, seed: 4, ..Default::default() };
            let fc = sample_scene(&still, &NoiseSchedule::default(), &std, &layout, &task, &opts, &mut |_| {}).unwrap();
            assert_eq!((fc.samples.len(), fc.observed_frames, fc.provenance.anchor_frame), (2, 0, anchor));
            for smp in &fc.samples {
                assert_eq!(smp.num_frames(), 40);
                for f in [0, anchor, 39] {
                    let d = smp.positions.slice(s![f, .., .., ..]).iter().zip(layout.positions.iter()).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
                    assert!(d < 1e-4, "anchor {anchor}, frame {f}: {d} m from the layout");
                }
            }
            let task_json = &serde_json::to_value(&fc.provenance).unwrap()["task"];
            assert_eq!((task_json["kind"].as_str(), task_json["anchor"].as_u64()), (Some("generate"), Some(anchor as u64)));
            let fc = run(&tiny_model(), &layout, &task, 2, 4);
            assert!(fc.samples.iter().all(|s| s.num_frames() == 40 && s.positions.iter().all(|v| v.is_finite())));
        }
        assert!(check_task(&layout, &Task::Generate { frames: 1, anchor: 0 }).unwrap_err().to_string().contains("at least 2"));
        assert!(check_task(&layout, &Task::Generate { frames: 10, anchor: 10 }).unwrap_err().to_string().contains("must be one of them"));
    }

    /// Slerp: the endpoints, unit norm kept between orthogonal unit vectors, and the linear
    /// case for parallel ones.
    #[test]
    fn slerp_known_values() {
        let (a, b) = ([1.0f32, 0.0], [0.0f32, 1.0]);
        assert_eq!(slerp(&a, &b, 0.0), a.to_vec());
        assert!(slerp(&a, &b, 1.0).iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-7));
        let h = slerp(&a, &b, 0.5);
        assert!((h[0] - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-6 && (h[1] - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-6);
        assert_eq!(slerp(&a, &[2.0, 0.0], 0.25), vec![1.25, 0.0]);
    }

    /// A transition scene: a, then F frames holding a's last pose, then b; mismatches refused.
    #[test]
    fn transition_scenes_join_two_motions() {
        let (a, b) = (walkers(10, 2, 0.1), walkers(7, 2, 0.9));
        let t = transition_scene(&a, &b, 5).unwrap();
        assert_eq!(t.num_frames(), 22);
        assert_eq!(t.positions.slice(s![12, .., .., ..]), a.positions.slice(s![9, .., .., ..]));
        assert_eq!(t.positions.slice(s![15.., .., .., ..]), b.positions);
        assert!(transition_scene(&a, &b, 0).is_err());
        assert!(transition_scene(&a, &walkers(7, 3, 0.9), 5).unwrap_err().to_string().contains("differ in persons"));
    }

    #[test]
    fn masks_of_each_completion_kind() {
        let sk = crate::data::Skeleton::mupots17();
        let (l, r) = (sk.left, sk.right);
        let m = task_mask(&Task::Forecast { observe: 3, horizon: 2 }, 5, 2, 17, (l, r));
        assert_eq!(m.dim(), (5, 2, 55));
        assert!(m.slice(s![..3, .., ..]).iter().all(|&x| x) && m.slice(s![3.., .., ..]).iter().all(|&x| !x));
        let m = task_mask(&Task::Complete(Missing::Frames(1..3)), 5, 2, 17, (l, r));
        for ((f, _, _), &x) in m.indexed_iter() {
            assert_eq!(x, !(1..3).contains(&f));
        }
        let m = task_mask(&Task::Complete(Missing::Persons(vec![1])), 5, 3, 17, (l, r));
        for ((_, p, _), &x) in m.indexed_iter() {
            assert_eq!(x, p != 1);
        }
        let head = sk.joint_index("head").unwrap_or(0);
        let j = if head == l || head == r { 0 } else { head };
        let m = task_mask(&Task::Complete(Missing::Joints(vec![j])), 5, 2, 17, (l, r));
        for ((_, _, d), &x) in m.indexed_iter() {
            assert_eq!(x, !(d >= 4 && (d - 4) / 3 == j), "dim {d}");
        }
        // A missing body-frame joint makes the root dims unknown too.
        let m = task_mask(&Task::Complete(Missing::Joints(vec![l])), 5, 2, 17, (l, r));
        assert!(!m[[0, 0, 0]] && !m[[4, 1, 3]] && !m[[0, 0, 4 + 3 * l]]);
        assert_eq!(Missing::parse("frames=2..7", &sk).unwrap(), Missing::Frames(2..7));
        assert_eq!(Missing::parse("persons=0,2", &sk).unwrap(), Missing::Persons(vec![0, 2]));
        assert_eq!(Missing::parse(&format!("joints={},3", sk.joints[1]), &sk).unwrap(), Missing::Joints(vec![1, 3]));
        assert!(Missing::parse("legs=1", &sk).is_err());
        assert!(Missing::parse("joints=nose_tip", &sk).is_err());
    }

    #[test]
    fn completion_keeps_known_entries_and_checks_its_task() {
        let m = tiny_model();
        let scene = walkers(16, 3, 0.2);
        let fc = run(&m, &scene, &Task::Complete(Missing::Frames(5..9)), 1, 2);
        let out = &fc.samples[0].positions;
        assert_eq!(out.dim(), scene.positions.dim());
        for f in (0..5).chain(9..16) {
            assert_eq!(out.slice(s![f, .., .., ..]), scene.positions.slice(s![f, .., .., ..]));
        }
        assert_ne!(out.slice(s![6, .., .., ..]), scene.positions.slice(s![6, .., .., ..]));
        let fc = run(&m, &scene, &Task::Complete(Missing::Persons(vec![1])), 1, 2);
        let out = &fc.samples[0].positions;
        assert_eq!(out.slice(s![.., 0, .., ..]), scene.positions.slice(s![.., 0, .., ..]));
        assert_ne!(out.slice(s![.., 1, .., ..]), scene.positions.slice(s![.., 1, .., ..]));
        let fc = run(&m, &scene, &Task::Complete(Missing::Joints(vec![0])), 1, 2);
        let out = &fc.samples[0].positions;
        assert_eq!(out.slice(s![.., .., 1.., ..]), scene.positions.slice(s![.., .., 1.., ..]));
        assert_ne!(out.slice(s![.., .., 0, ..]), scene.positions.slice(s![.., .., 0, ..]));
        let e = |t: Task| check_task(&scene, &t).unwrap_err().to_string();
        assert!(e(Task::Forecast { observe: 16, horizon: 5 }).contains("less than the scene length"));
        assert!(e(Task::Forecast { observe: 4, horizon: 0 }).contains("horizon"));
        assert!(e(Task::Complete(Missing::Persons(vec![3]))).contains("out of range"));
        assert!(e(Task::Complete(Missing::Frames(0..16))).contains("every frame"));
    }
}
