//! `socdiff._native`: the engine for Python. Thin: numpy arrays become scenes, engine calls run
//! with the GIL released, engine errors become Python exceptions carrying the engine's message.
//! The Python package (`python/socdiff`) wraps it in typed functions and dataclasses.

mod dataset;
mod eval;
mod metrics;
mod model;
mod options;
mod scene;
mod train;

use pyo3::exceptions::{PyFileExistsError, PyFileNotFoundError, PyOSError, PyPermissionError, PyValueError};
use pyo3::prelude::*;
use socdiff_engine::Error;

/// An engine error as the Python exception of its kind: a file the system refused → OSError
/// (FileNotFoundError, PermissionError, FileExistsError where they apply); a malformed file or
/// an input that cannot be used → ValueError. The message is the engine's, naming the file.
pub(crate) fn py_err(e: Error) -> PyErr {
    let msg = e.to_string();
    match &e {
        Error::Io { source, .. } => match source.kind() {
            std::io::ErrorKind::NotFound => PyFileNotFoundError::new_err(msg),
            std::io::ErrorKind::PermissionDenied => PyPermissionError::new_err(msg),
            std::io::ErrorKind::AlreadyExists => PyFileExistsError::new_err(msg),
            _ => PyOSError::new_err(msg),
        },
        Error::Format { .. } | Error::Invalid(_) => PyValueError::new_err(msg),
    }
}

/// `Result<T, Error>` → `PyResult<T>`.
pub(crate) trait IntoPy<T> {
    fn py(self) -> PyResult<T>;
}

impl<T> IntoPy<T> for socdiff_engine::Result<T> {
    fn py(self) -> PyResult<T> {
        self.map_err(py_err)
    }
}

/// Starts the engine's worker pool with the calling thread as one of its workers, as the CLI
/// does (an op then starts on the caller at once). The package calls it on import from the
/// main thread, which lives as long as the interpreter.
#[pyfunction]
fn start_workers() -> PyResult<()> {
    socdiff_engine::model::runtime::start_workers(None).py()
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    // As the CLI: candle's element-wise ops on the calling thread (its allocator settings are
    // left out: the interpreter's memory is the user's).
    socdiff_engine::model::runtime::elementwise_on_caller();
    m.add_function(wrap_pyfunction!(start_workers, m)?)?;
    m.add_class::<model::Model>()?;
    m.add_class::<model::Stream>()?;
    m.add_class::<metrics::NdmsDatabase>()?;
    m.add_function(wrap_pyfunction!(scene::skeleton, m)?)?;
    m.add_function(wrap_pyfunction!(scene::skeleton_names, m)?)?;
    m.add_function(wrap_pyfunction!(dataset::load_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(dataset::save_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(train::train, m)?)?;
    m.add_function(wrap_pyfunction!(eval::evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(metrics::pose_error_curve, m)?)?;
    m.add_function(wrap_pyfunction!(metrics::mpjpe_at_horizons, m)?)?;
    m.add_function(wrap_pyfunction!(metrics::ade, m)?)?;
    m.add_function(wrap_pyfunction!(metrics::fde, m)?)?;
    m.add_function(wrap_pyfunction!(metrics::apd, m)?)?;
    Ok(())
}
