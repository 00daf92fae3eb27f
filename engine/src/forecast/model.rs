//! A trained [`Model`]: its checkpoint and its sampling network, and the calls that forecast,
//! complete and generate with it.

use super::canvas::{sample_scene, Denoising};
use super::output::ForecastOutput;
use super::request::Forecast;
use super::task::{Missing, Task};
use crate::checkpoint::{Checkpoint, LoadedModel, Weights};
use crate::data::scene::Scene;
use crate::features::{PoseEncoding, ROOT_DIMS};
use crate::model::DeviceChoice;
use crate::sample::{SamplingNet, StepInfo, X0Model};
use crate::{bail, Error, Result};
use ndarray::{s, Array4};
use serde::Serialize;
use std::path::Path;

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
    pub checkpoint: LoadedModel,
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

/// DDIM steps of a model that was not distilled, when a request names none.
pub const DEFAULT_DDIM_STEPS: usize = 50;

impl Model {
    /// Loads the EMA weights of the run in `dir`.
    pub fn load(dir: impl AsRef<Path>) -> Result<Self> {
        Self::load_weights(dir, Weights::Ema)
    }

    /// Loads the chosen weights of the run in `dir`, to sample on the CPU.
    pub fn load_weights(dir: impl AsRef<Path>, weights: Weights) -> Result<Self> {
        Self::load_on(dir, weights, DeviceChoice::Cpu)
    }

    /// Loads the chosen weights of the run in `dir`, to sample on `device` (the sampling route
    /// of that device, [`SamplingNet`]).
    pub fn load_on(dir: impl AsRef<Path>, weights: Weights, device: DeviceChoice) -> Result<Self> {
        let checkpoint = Checkpoint::load_weights(dir, weights)?;
        let net = SamplingNet::new(&checkpoint.denoiser, &checkpoint.diffusion, &device.resolve()?).map_err(|e| e.in_file(&checkpoint.path))?;
        Ok(Self { checkpoint, net, guide: None })
    }

    /// The DDIM steps it samples with unless told otherwise: a distilled student's own calls,
    /// else [`DEFAULT_DDIM_STEPS`].
    pub fn default_steps(&self) -> usize {
        self.checkpoint.config.distill.as_ref().map_or(DEFAULT_DDIM_STEPS, |d| d.calls)
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
        self.checkpoint.fit_scene(scene, map_joints)
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
    /// [`Model::forecast`] / [`Model::complete`] for any task, reporting each denoising step.
    pub fn sample(&self, scene: &Scene, task: &Task, req: &Forecast, on_step: &mut dyn FnMut(StepInfo)) -> Result<ForecastOutput> {
        let (scene, _) = self.fit_scene(scene, req.map_joints)?;
        let m = &self.checkpoint;
        let mut fc =
            sample_scene(&Denoising::of(m, self.net()), &scene, task, req, on_step).map_err(|e| Error::invalid(format!("scene {}: {e}", scene.name)))?;
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
