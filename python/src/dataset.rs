//! Datasets ⇄ Python: `load_dataset` reads any source the CLI reads; `save_dataset` writes a
//! dataset directory.

use crate::scene::{array4, from_tuple, to_tuple, SkeletonTuple};
use crate::IntoPy;
use ndarray::{Array2, Ix2};
use numpy::{PyArray2, PyArray4, PyReadonlyArrayDyn, PyUntypedArrayMethods, ToPyArray};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use socdiff_engine::data::dataset::{write_dataset, Sequence};
use socdiff_engine::data::import::{self, ImportOptions};
use socdiff_engine::data::Person;
use socdiff_engine::{Dataset, Scene, Split};
use std::collections::BTreeMap;
use std::path::PathBuf;

fn json_map(text: &str, what: &str) -> PyResult<serde_json::Map<String, serde_json::Value>> {
    match serde_json::from_str(text) {
        Ok(serde_json::Value::Object(m)) => Ok(m),
        _ => Err(PyValueError::new_err(format!("{what}: expected a JSON object"))),
    }
}

/// One sequence of a Python dataset, as `save_dataset` receives it.
#[derive(FromPyObject)]
#[pyo3(from_item_all)]
pub struct PySequence<'py> {
    name: String,
    split: String,
    fps: f64,
    skeleton: SkeletonTuple,
    positions: PyReadonlyArrayDyn<'py, f32>,
    valid: Option<PyReadonlyArrayDyn<'py, bool>>,
    signals: BTreeMap<String, PyReadonlyArrayDyn<'py, f32>>,
    persons: Vec<(String, Option<String>)>,
    metadata: String,
}

fn array2<T: Clone + numpy::Element>(a: &PyReadonlyArrayDyn<'_, T>, what: &str) -> PyResult<Array2<T>> {
    if a.ndim() != 2 {
        return Err(PyValueError::new_err(format!("{what}: shape {:?}, expected [frames, persons]", a.shape())));
    }
    Ok(a.as_array().into_dimensionality::<Ix2>().map_err(|e| PyValueError::new_err(e.to_string()))?.to_owned())
}

impl PySequence<'_> {
    fn sequence(&self) -> PyResult<Sequence> {
        let at = |e: PyErr| PyValueError::new_err(format!("sequence {:?}: {e}", self.name));
        let split = Split::parse(&self.split).py().map_err(at)?;
        let positions = array4(&self.positions, "positions", "[frames, persons, joints, 3]").map_err(at)?;
        let mut scene = Scene::new(&self.name, self.fps, from_tuple(self.skeleton.clone())?, positions).py()?;
        if let Some(v) = &self.valid {
            scene = scene.with_valid(array2(v, "valid").map_err(at)?).py()?;
        }
        for (name, values) in &self.signals {
            scene = scene.with_signal(name, array2(values, &format!("signal {name:?}")).map_err(at)?).py()?;
        }
        let persons = self.persons.iter().map(|(id, role)| Person { id: id.clone(), role: role.clone() }).collect();
        scene = scene.with_persons(persons).py()?;
        scene.metadata = json_map(&self.metadata, &format!("sequence {:?} metadata", self.name))?;
        Ok(Sequence { split, scene })
    }
}

/// Reads a dataset directory, or any file or folder `socdiff data convert` reads, with the
/// CLI's default import options: a dict of name, metadata (JSON) and sequences.
#[pyfunction]
pub fn load_dataset(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyDict>> {
    let ds = py.detach(|| import::load(&path, &ImportOptions::default())).py()?;
    let out = PyDict::new(py);
    out.set_item("name", &ds.name)?;
    out.set_item("metadata", serde_json::to_string(&ds.metadata).unwrap_or_else(|_| "{}".into()))?;
    let mut sequences = Vec::with_capacity(ds.sequences.len());
    for seq in &ds.sequences {
        let s = &seq.scene;
        let d = PyDict::new(py);
        d.set_item("name", &s.name)?;
        d.set_item("split", seq.split.as_str())?;
        d.set_item("fps", s.fps)?;
        d.set_item("skeleton", to_tuple(&s.skeleton))?;
        let positions: Bound<'_, PyArray4<f32>> = s.positions.to_pyarray(py);
        d.set_item("positions", positions)?;
        let valid: Option<Bound<'_, PyArray2<bool>>> = s.valid.as_ref().map(|v| v.to_pyarray(py));
        d.set_item("valid", valid)?;
        let signals = PyDict::new(py);
        for (name, values) in &s.signals {
            signals.set_item(name, values.to_pyarray(py))?;
        }
        d.set_item("signals", signals)?;
        let persons: Vec<(String, Option<String>)> = s.persons.iter().map(|p| (p.id.clone(), p.role.clone())).collect();
        d.set_item("persons", persons)?;
        d.set_item("metadata", serde_json::to_string(&s.metadata).unwrap_or_else(|_| "{}".into()))?;
        sequences.push(d);
    }
    out.set_item("sequences", sequences)?;
    Ok(out)
}

/// Writes a dataset directory at `path` (which must not exist or be empty): written whole or
/// not at all.
#[pyfunction]
pub fn save_dataset(py: Python<'_>, path: PathBuf, name: String, metadata: &str, sequences: Vec<PySequence<'_>>) -> PyResult<()> {
    let sequences = sequences.iter().map(PySequence::sequence).collect::<PyResult<Vec<_>>>()?;
    let dataset = Dataset { name, sequences, metadata: json_map(metadata, "dataset metadata")? };
    py.detach(|| write_dataset(&dataset, &path)).py()
}
