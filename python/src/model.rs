//! `socdiff._native.Model`: a trained model that forecasts, completes and generates numpy
//! scenes.

use crate::scene::{from_tuple, scene, to_tuple, SkeletonTuple};
use crate::IntoPy;
use clap::ValueEnum;
use ndarray::{Array5, Axis};
use numpy::PyReadonlyArray3;
use numpy::{PyArray5, PyReadonlyArrayDyn, ToPyArray};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use socdiff_engine::checkpoint::Weights;
use socdiff_engine::forecast::{self, CleanKnown, Forecast, ForecastOutput, Missing, SamplerFamily, Task};
use socdiff_engine::sample::Conditioning;
use socdiff_engine::Scene;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

/// A value of an option enum by its CLI name, or a ValueError listing the names.
pub fn choice<T: ValueEnum>(what: &str, value: &str) -> PyResult<T> {
    T::from_str(value, false).map_err(|_| {
        let names: Vec<String> = T::value_variants().iter().filter_map(|v| v.to_possible_value()).map(|p| p.get_name().to_string()).collect();
        PyValueError::new_err(format!("`{what}` {value:?}: expected one of {}", names.join(", ")))
    })
}

/// A trained model (a run directory, its checkpoint or model.safetensors).
#[pyclass(frozen, module = "socdiff._native")]
pub struct Model {
    inner: Arc<forecast::Model>,
}

/// How to sample: the request of every call, without its frames.
struct Sampling {
    samples: usize,
    seed: u64,
    sampler: String,
    steps: Option<usize>,
    eta: f64,
    conditioning: String,
    clean_known: String,
    joint_map: bool,
}

impl Sampling {
    /// The request, at `model`'s own DDIM steps when `steps` is `None`.
    fn request(&self, model: &forecast::Model) -> PyResult<Forecast> {
        let family: SamplerFamily = choice("sampler", &self.sampler)?;
        let clean_known = match choice::<CleanKnown>("clean_known", &self.clean_known)? {
            CleanKnown::Auto => None,
            CleanKnown::On => Some(true),
            CleanKnown::Off => Some(false),
        };
        Ok(Forecast {
            samples: self.samples,
            sampler: family.kind(self.steps.unwrap_or(model.default_steps()), self.eta).py()?,
            conditioning: choice::<Conditioning>("conditioning", &self.conditioning)?,
            seed: self.seed,
            clean_known,
            map_joints: self.joint_map,
            ..Default::default()
        })
    }
}

/// The samples `[K, frames, persons, joints, 3]` and the provenance as JSON.
fn output<'py>(py: Python<'py>, fc: &ForecastOutput) -> PyResult<(Bound<'py, PyArray5<f32>>, String)> {
    let views: Vec<_> = fc.samples.iter().map(|s| s.positions.view().insert_axis(Axis(0))).collect();
    let stacked: Array5<f32> = ndarray::concatenate(Axis(0), &views).map_err(|e| PyValueError::new_err(format!("samples: {e}")))?;
    let provenance = serde_json::to_string(&fc.provenance).map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok((stacked.to_pyarray(py), provenance))
}

impl Model {
    /// `positions` as a scene in `skeleton` (default: the model's) at `fps` (default: the
    /// model's).
    fn input(&self, positions: &PyReadonlyArrayDyn<'_, f32>, skeleton: Option<SkeletonTuple>, fps: Option<f64>, name: &str) -> PyResult<Scene> {
        let m = &self.inner.checkpoint;
        let skeleton = match skeleton {
            Some(t) => from_tuple(t)?,
            None => m.skeleton.clone(),
        };
        scene(name, positions, skeleton, fps.unwrap_or(m.fps))
    }

    fn run<'py>(&self, py: Python<'py>, scene: &Scene, task: &Task, req: &Forecast) -> PyResult<(Bound<'py, PyArray5<f32>>, String)> {
        let fc = py.detach(|| self.inner.sample(scene, task, req, &mut |_| {})).py()?;
        output(py, &fc)
    }
}

#[pymethods]
impl Model {
    /// Loads a model: a run directory, its checkpoint.safetensors / checkpoint.json, or a
    /// model.safetensors; `weights` "ema" or "online".
    #[staticmethod]
    #[pyo3(signature = (path, weights = "ema"))]
    fn load(py: Python<'_>, path: PathBuf, weights: &str) -> PyResult<Self> {
        let weights: Weights = choice("weights", weights)?;
        let inner = py.detach(|| forecast::Model::load_weights(&path, weights)).py()?;
        Ok(Self { inner: Arc::new(inner) })
    }

    /// The model's skeleton as a tuple (name, joints, bones, left, right).
    #[getter]
    fn skeleton(&self) -> SkeletonTuple {
        to_tuple(&self.inner.checkpoint.skeleton)
    }

    /// Frames per second of its training data.
    #[getter]
    fn fps(&self) -> f64 {
        self.inner.checkpoint.fps
    }

    /// Optimizer steps of its training.
    #[getter]
    fn step(&self) -> u64 {
        self.inner.checkpoint.step
    }

    /// The file it was loaded from.
    #[getter]
    fn path(&self) -> String {
        self.inner.checkpoint.path.display().to_string()
    }

    /// Its training configuration as JSON.
    #[getter]
    fn config_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.inner.checkpoint.config).map_err(|e| PyValueError::new_err(e.to_string()))
    }

    /// Samples futures: the first `observe` frames of `positions` continued by `horizon`.
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (positions, skeleton, fps, name, observe, horizon, samples, seed, sampler, steps, eta, conditioning, clean_known, joint_map))]
    fn forecast<'py>(
        &self,
        py: Python<'py>,
        positions: PyReadonlyArrayDyn<'py, f32>,
        skeleton: Option<SkeletonTuple>,
        fps: Option<f64>,
        name: &str,
        observe: usize,
        horizon: usize,
        samples: usize,
        seed: u64,
        sampler: String,
        steps: Option<usize>,
        eta: f64,
        conditioning: String,
        clean_known: String,
        joint_map: bool,
    ) -> PyResult<(Bound<'py, PyArray5<f32>>, String)> {
        let req = Sampling { samples, seed, sampler, steps, eta, conditioning, clean_known, joint_map }.request(&self.inner)?;
        let scene = self.input(&positions, skeleton, fps, name)?;
        self.run(py, &scene, &Task::Forecast { observe, horizon }, &Forecast { observe, horizon, ..req })
    }

    /// Completes what `missing` names (`joints=…`, `frames=a..b`, `persons=…`).
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (positions, missing, skeleton, fps, name, samples, seed, sampler, steps, eta, conditioning, clean_known, joint_map))]
    fn complete<'py>(
        &self,
        py: Python<'py>,
        positions: PyReadonlyArrayDyn<'py, f32>,
        missing: &str,
        skeleton: Option<SkeletonTuple>,
        fps: Option<f64>,
        name: &str,
        samples: usize,
        seed: u64,
        sampler: String,
        steps: Option<usize>,
        eta: f64,
        conditioning: String,
        clean_known: String,
        joint_map: bool,
    ) -> PyResult<(Bound<'py, PyArray5<f32>>, String)> {
        let req = Sampling { samples, seed, sampler, steps, eta, conditioning, clean_known, joint_map }.request(&self.inner)?;
        let scene = self.input(&positions, skeleton, fps, name)?;
        // The missing part is named in the model's skeleton, which the scene is fitted to.
        let (fitted, _) = self.inner.fit_scene(&scene, joint_map).py()?;
        let missing = Missing::parse(missing, &fitted.skeleton).py()?;
        self.run(py, &fitted, &Task::Complete(missing), &req)
    }

    /// A stream of `persons` persons: a forecast per pushed frame once `observe` are in.
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (persons, observe, horizon, samples, seed, sampler, steps, eta))]
    fn stream(
        &self,
        persons: usize,
        observe: usize,
        horizon: usize,
        samples: usize,
        seed: u64,
        sampler: String,
        steps: Option<usize>,
        eta: f64,
    ) -> PyResult<Stream> {
        let sampling = Sampling { samples, seed, sampler, steps, eta, conditioning: "replace".into(), clean_known: "auto".into(), joint_map: false };
        let req = Forecast { observe, horizon, ..sampling.request(&self.inner)? };
        let inner = forecast::Stream::new(self.inner.clone(), persons, req).py()?;
        Ok(Stream { inner: Mutex::new(inner) })
    }

    /// Generates `frames` frames of `persons` persons from noise (placed on a circle in the
    /// model's mean pose), or of the persons of `layout` (placed where they stand in its first
    /// frame).
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (frames, persons, layout, skeleton, fps, samples, seed, sampler, steps, eta))]
    fn generate<'py>(
        &self,
        py: Python<'py>,
        frames: usize,
        persons: usize,
        layout: Option<PyReadonlyArrayDyn<'py, f32>>,
        skeleton: Option<SkeletonTuple>,
        fps: Option<f64>,
        samples: usize,
        seed: u64,
        sampler: String,
        steps: Option<usize>,
        eta: f64,
    ) -> PyResult<(Bound<'py, PyArray5<f32>>, String)> {
        let req = Sampling { samples, seed, sampler, steps, eta, conditioning: "replace".into(), clean_known: "auto".into(), joint_map: skeleton.is_some() }
            .request(&self.inner)?;
        let scene = match layout {
            Some(l) => self.inner.fit_scene(&self.input(&l, skeleton, fps, "layout")?, req.map_joints).py()?.0,
            None => self.inner.circle_layout(persons).py()?,
        };
        self.run(py, &scene, &self.inner.generate_task(frames), &req)
    }
}

/// Frames in, a forecast per frame out (`socdiff::forecast::Stream`).
#[pyclass(frozen, module = "socdiff._native")]
pub struct Stream {
    inner: Mutex<forecast::Stream<Arc<forecast::Model>>>,
}

#[pymethods]
impl Stream {
    /// Takes the frame `[persons, joints, 3]` observed at `time` seconds; returns the forecast
    /// (samples, provenance JSON) once the window is full, else None.
    #[allow(clippy::type_complexity)]
    fn push<'py>(&self, py: Python<'py>, time: f64, frame: PyReadonlyArray3<'py, f32>) -> PyResult<Option<(Bound<'py, PyArray5<f32>>, String)>> {
        let frame = frame.as_array().to_owned();
        let fc = py.detach(|| self.inner.lock().unwrap_or_else(|p| p.into_inner()).push(time, frame.view())).py()?;
        fc.map(|fc| output(py, &fc)).transpose()
    }

    /// Frames the window still lacks before the first forecast.
    #[getter]
    fn frames_needed(&self) -> usize {
        self.inner.lock().unwrap_or_else(|p| p.into_inner()).frames_needed()
    }
}
