//! Between two motions: [`Model::interpolate`] (DDIM inversion of both, spherical
//! interpolation of the noises) and [`Model::transition`] (in-betweening by completion).

use super::model::Model;
use super::output::ForecastOutput;
use super::request::{Forecast, SamplerKind};
use super::task::{Missing, Task};
use crate::data::dataset::{Dataset, Sequence, Split};
use crate::data::scene::Scene;
use crate::features::PoseFeatures;
use crate::{bail, Result};
use ndarray::{s, Array3, Axis};
use socdiff_schedules::Ddim;

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

impl Model {
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
}
