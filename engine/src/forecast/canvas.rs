//! A scene turned into a canvas of standardized features with a known-value mask, sampled by
//! inpainting, and turned back into scenes ([`sample_scene`]).

use super::output::{ForecastOutput, MaskSummary, Provenance, Timings};
use super::request::Forecast;
use super::task::{canvas_frames, check_task, Missing, Task};
use crate::checkpoint::LoadedModel;
use crate::data::scene::Scene;
use crate::export::ForecastInfo;
use crate::features::{PoseEncoding, PoseFeatures, Standardization, ROOT_DIMS};
use crate::sample::{inpaint_with_progress, sample_seed, InpaintOptions, Known, StepInfo, X0Model};
use crate::{bail, Result};
use ndarray::{s, Array2, Array3, Array4, Axis};
use socdiff_schedules::NoiseSchedule;
use std::time::Instant;

/// A trained network and what its samples mean: the noise schedule it was trained on, the
/// standardization of its features, how they encode a pose, and whether it was trained with
/// clean known frames (then known frames sit at noise level 0 unless a request says otherwise).
#[derive(Clone, Copy)]
pub struct Denoising<'a> {
    /// The network (a frozen sampling route).
    pub net: &'a dyn X0Model,
    /// Its noise schedule.
    pub schedule: &'a NoiseSchedule,
    /// Its feature standardization.
    pub standardization: &'a Standardization,
    /// Its pose encoding.
    pub encoding: PoseEncoding,
    /// Trained with clean frames (`prefix`, `per-frame` noise).
    pub clean_known: bool,
}

impl<'a> Denoising<'a> {
    /// `net` sampling for the checkpoint `model`.
    pub fn of(model: &'a LoadedModel, net: &'a dyn X0Model) -> Self {
        Self {
            net,
            schedule: model.diffusion.schedule(),
            standardization: &model.standardization,
            encoding: model.config.pose,
            clean_known: model.config.noise.trains_clean_frames(),
        }
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

/// Builds the canvas of `task` on `scene`, standardized with `std`. The task must have passed
/// [`check_task`] ([`sample_scene`] checks it).
pub(super) fn build_canvas(scene: &Scene, task: &Task, std: &Standardization, encoding: PoseEncoding) -> Result<Canvas> {
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

/// Samples `req.samples` completions of `task` on `scene` with `model`, reporting each
/// denoising step to `on_step`. The request is checked here, once ([`check_task`]); known
/// frames are clean as `req.clean_known` says, else as the model was trained.
pub fn sample_scene(model: &Denoising, scene: &Scene, task: &Task, req: &Forecast, on_step: &mut dyn FnMut(StepInfo)) -> Result<ForecastOutput> {
    check_task(scene, task, req.samples)?;
    let (schedule, std, encoding) = (model.schedule, model.standardization, model.encoding);
    let clean_known = req.clean_known.unwrap_or(model.clean_known);
    let start = Instant::now();
    let canvas = build_canvas(scene, task, std, encoding)?;
    let sampler = req.sampler.build(schedule)?;
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
    let seeds: Vec<u64> = (0..req.samples).map(|k| sample_seed(req.seed, k)).collect();
    let mut model_seconds = 0.0;
    let mut model_calls = 0usize;
    let t0 = Instant::now();
    let inpaint_opts = InpaintOptions { samples: req.samples, conditioning: req.conditioning, seed: req.seed, inversion: req.inversion, clean_known };
    let out = inpaint_with_progress(model.net, sampler.as_ref(), &known, &inpaint_opts, &mut |i| {
        model_seconds += i.seconds;
        model_calls += 1;
        on_step(i)
    })?;
    let sampling_seconds = t0.elapsed().as_secs_f64();
    let mut samples = Vec::with_capacity(req.samples);
    for k in 0..req.samples {
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
    let sample_steps = (steps * req.samples) as f64;
    let prov = Provenance {
        sampler: req.sampler,
        steps,
        conditioning: req.conditioning,
        clean_known,
        pose_encoding: encoding,
        seed: req.seed,
        context_inversion: req.inversion,
        sample_seeds: seeds,
        samples: req.samples,
        anchor_frame: canvas.anchor_frame,
        mask: MaskSummary { frames: nf, persons: np, dims: dim, known_entries: canvas.mask.iter().filter(|&&m| m).count() },
        timings: Timings {
            total_seconds: total,
            sampling_seconds,
            model_seconds,
            model_calls,
            samples_per_call: req.samples.div_ceil((model_calls / steps.max(1)).max(1)),
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
