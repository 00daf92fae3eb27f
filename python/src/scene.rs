//! numpy arrays ⇄ scenes, and skeletons as plain tuples.

use crate::IntoPy;
use ndarray::{Array4, Ix4};
use numpy::{PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use socdiff_engine::data::skeleton::NAMED_SKELETONS;
use socdiff_engine::{Scene, Skeleton};

/// A skeleton as Python sees it: (name, joint names, bones as (parent, child), left and right
/// body-frame joints).
pub type SkeletonTuple = (String, Vec<String>, Vec<(usize, usize)>, usize, usize);

pub fn to_tuple(s: &Skeleton) -> SkeletonTuple {
    (s.name.clone(), s.joints.clone(), s.bones.clone(), s.left, s.right)
}

pub fn from_tuple(t: SkeletonTuple) -> PyResult<Skeleton> {
    Skeleton::new(t.0, t.1, t.2, t.3, t.4).py()
}

/// The named skeleton `name` (mupots17, mrt15, …).
#[pyfunction]
pub fn skeleton(name: &str) -> PyResult<SkeletonTuple> {
    Ok(to_tuple(&Skeleton::named(name).py()?))
}

/// The names of the named skeletons.
#[pyfunction]
pub fn skeleton_names() -> Vec<&'static str> {
    NAMED_SKELETONS.to_vec()
}

/// `array` (float32) as `[a, b, c, 3]`, or a ValueError saying what `what` should be.
pub fn array4(array: &PyReadonlyArrayDyn<'_, f32>, what: &str, layout: &str) -> PyResult<Array4<f32>> {
    let shape = array.shape();
    if shape.len() != 4 || shape[3] != 3 {
        return Err(PyValueError::new_err(format!("{what}: shape {shape:?}, expected {layout}")));
    }
    Ok(array.as_array().into_dimensionality::<Ix4>().map_err(|e| PyValueError::new_err(format!("{what}: {e}")))?.to_owned())
}

/// A scene of `positions` `[frames, persons, joints, 3]` (metres, z up).
pub fn scene(name: &str, positions: &PyReadonlyArrayDyn<'_, f32>, skeleton: Skeleton, fps: f64) -> PyResult<Scene> {
    let positions = array4(positions, "positions", "[frames, persons, joints, 3]")?;
    Scene::new(name, fps, skeleton, positions).py()
}
