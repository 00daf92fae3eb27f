//! `socdiff.metrics`: the engine's metrics on numpy arrays (the functions `socdiff eval` uses).

use crate::scene::{array4, from_tuple, SkeletonTuple};
use crate::IntoPy;
use ndarray::{Array5, Ix5};
use numpy::{PyArray1, PyArray2, PyReadonlyArrayDyn, PyUntypedArrayMethods, ToPyArray};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use socdiff_engine::metrics::{self, NdmsConfig, NdmsJoints, PoseError};
use socdiff_engine::Scene;

fn forecasts5(a: &PyReadonlyArrayDyn<'_, f32>) -> PyResult<Array5<f32>> {
    let shape = a.shape();
    if shape.len() != 5 || shape[4] != 3 {
        return Err(PyValueError::new_err(format!("forecasts: shape {shape:?}, expected [samples, frames, persons, joints, 3]")));
    }
    a.as_array().into_dimensionality::<Ix5>().map(|v| v.to_owned()).map_err(|e| PyValueError::new_err(e.to_string()))
}

fn kind(name: &str) -> PyResult<PoseError> {
    match name {
        "global" => Ok(PoseError::Global),
        "root" => Ok(PoseError::Root),
        "root_aligned" => Ok(PoseError::RootAligned),
        other => Err(PyValueError::new_err(format!("`kind` {other:?}: expected global, root or root_aligned"))),
    }
}

/// Per-sample, per-frame pose error `[K, frames]` in metres.
#[pyfunction]
pub fn pose_error_curve<'py>(
    py: Python<'py>,
    forecasts: PyReadonlyArrayDyn<'py, f32>,
    truth: PyReadonlyArrayDyn<'py, f32>,
    left: usize,
    right: usize,
    kind_name: &str,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let (f, t, k) = (forecasts5(&forecasts)?, array4(&truth, "truth", "[frames, persons, joints, 3]")?, kind(kind_name)?);
    let curve = py.detach(|| metrics::distance::pose_error_curve(f.view(), t.view(), left, right, k)).py()?;
    Ok(curve.to_pyarray(py))
}

/// Mean and best of K pose error at horizons in seconds (None past the forecast).
#[allow(clippy::too_many_arguments)]
#[pyfunction]
pub fn mpjpe_at_horizons(
    py: Python<'_>,
    forecasts: PyReadonlyArrayDyn<'_, f32>,
    truth: PyReadonlyArrayDyn<'_, f32>,
    left: usize,
    right: usize,
    fps: f64,
    horizons: Vec<f64>,
    kind_name: &str,
) -> PyResult<Vec<Option<(f64, f64)>>> {
    let (f, t, k) = (forecasts5(&forecasts)?, array4(&truth, "truth", "[frames, persons, joints, 3]")?, kind(kind_name)?);
    if !(fps.is_finite() && fps > 0.0) {
        return Err(PyValueError::new_err(format!("`fps` must be positive, got {fps}")));
    }
    let stats = py.detach(|| metrics::distance::mpjpe_at_horizons(f.view(), t.view(), left, right, fps, &horizons, k)).py()?;
    Ok(stats.into_iter().map(|s| s.map(|s| (s.mean, s.best))).collect())
}

/// ADE: the best sample's mean displacement.
#[pyfunction]
pub fn ade(py: Python<'_>, forecasts: PyReadonlyArrayDyn<'_, f32>, truth: PyReadonlyArrayDyn<'_, f32>) -> PyResult<f64> {
    let (f, t) = (forecasts5(&forecasts)?, array4(&truth, "truth", "[frames, persons, joints, 3]")?);
    py.detach(|| metrics::distance::ade(f.view(), t.view())).py()
}

/// FDE: the best sample's displacement at the last frame.
#[pyfunction]
pub fn fde(py: Python<'_>, forecasts: PyReadonlyArrayDyn<'_, f32>, truth: PyReadonlyArrayDyn<'_, f32>) -> PyResult<f64> {
    let (f, t) = (forecasts5(&forecasts)?, array4(&truth, "truth", "[frames, persons, joints, 3]")?);
    py.detach(|| metrics::distance::fde(f.view(), t.view())).py()
}

/// APD: the average pairwise distance between samples.
#[pyfunction]
pub fn apd(py: Python<'_>, forecasts: PyReadonlyArrayDyn<'_, f32>) -> PyResult<f64> {
    let f = forecasts5(&forecasts)?;
    py.detach(|| metrics::distance::apd(f.view())).py()
}

/// The NDMS reference database: every motion word of a set of scenes.
#[pyclass(frozen, module = "socdiff._native")]
pub struct NdmsDatabase {
    inner: metrics::NdmsDatabase,
}

#[pymethods]
impl NdmsDatabase {
    /// Builds the database of `scenes` (name, fps, skeleton, positions), one skeleton and frame
    /// rate; `joints` "default", "all" or comma-separated names.
    #[new]
    fn new(py: Python<'_>, scenes: Vec<(String, f64, SkeletonTuple, PyReadonlyArrayDyn<'_, f32>)>, joints: &str) -> PyResult<Self> {
        let scenes: Vec<Scene> = scenes
            .into_iter()
            .map(|(name, fps, skeleton, positions)| crate::scene::scene(&name, &positions, from_tuple(skeleton)?, fps))
            .collect::<PyResult<_>>()?;
        let cfg = NdmsConfig { joints: NdmsJoints::parse(joints).py()?, ..Default::default() };
        let inner = py.detach(|| metrics::NdmsDatabase::build(&scenes.iter().collect::<Vec<_>>(), &cfg)).py()?;
        Ok(Self { inner })
    }

    /// Motion words in the database.
    #[getter]
    fn words(&self) -> usize {
        self.inner.num_words()
    }

    /// NDMS of every sample and person of `forecasts` `[K, frames, persons, joints, 3]` whose
    /// forecast starts at `first_forecast_frame`: the mean and the per-word curve.
    fn score<'py>(&self, py: Python<'py>, forecasts: PyReadonlyArrayDyn<'py, f32>, first_forecast_frame: usize) -> PyResult<(f64, Bound<'py, PyArray1<f64>>)> {
        let f = forecasts5(&forecasts)?;
        let score = py.detach(|| self.inner.score_forecasts(f.view(), first_forecast_frame)).py()?;
        Ok((score.mean, score.per_frame.to_pyarray(py)))
    }
}
