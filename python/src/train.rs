//! `socdiff.train`: `socdiff train` as a call, with progress events for a callback and Ctrl-C
//! (KeyboardInterrupt) stopping after the current step with a resumable checkpoint.

use crate::model::choice;
use crate::IntoPy;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use socdiff_engine::data::import::SourceArgs;
use socdiff_engine::model::{DeviceChoice, Precision};
use socdiff_engine::train::{resolve_config, train as run_training, Preset, TrainEvent, TrainOptions, TrainOverrides, TrainSources, TrainingData};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

/// A training event as the dict the progress callback receives.
fn event_dict<'py>(py: Python<'py>, event: &TrainEvent) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    match event {
        TrainEvent::Started { first_step, total_steps, params, train_windows, config, device, .. } => {
            d.set_item("kind", "started")?;
            d.set_item("first_step", first_step)?;
            d.set_item("total_steps", total_steps)?;
            d.set_item("params", params)?;
            d.set_item("train_windows", train_windows)?;
            d.set_item("minutes", config.minutes)?;
            d.set_item("device", device)?;
        }
        TrainEvent::Step { step, loss, lr, seconds } => {
            d.set_item("kind", "step")?;
            d.set_item("step", step)?;
            d.set_item("loss", loss)?;
            d.set_item("lr", lr)?;
            d.set_item("seconds", seconds)?;
        }
        TrainEvent::Validation { step, loss } => {
            d.set_item("kind", "validation")?;
            d.set_item("step", step)?;
            d.set_item("loss", loss)?;
        }
        TrainEvent::Saved(saved) => {
            d.set_item("kind", "saved")?;
            d.set_item("step", saved.step)?;
            d.set_item("path", saved.path.display().to_string())?;
        }
        TrainEvent::Notice(msg) => {
            d.set_item("kind", "notice")?;
            d.set_item("message", msg)?;
        }
    }
    Ok(d)
}

/// Trains (or resumes) a run in `out` on `data`. `overrides` are `socdiff train`'s options
/// as arguments (`["--steps", "100", …]`). Returns the summary as a dict; a KeyboardInterrupt
/// or an exception of `progress` stops the run after the current step, saves it, and is raised.
#[allow(clippy::too_many_arguments)]
#[pyfunction]
#[pyo3(signature = (data, out, preset, config, resume, init, force, overrides, device, progress))]
pub fn train<'py>(
    py: Python<'py>,
    data: Vec<PathBuf>,
    out: PathBuf,
    preset: &str,
    config: Option<PathBuf>,
    resume: bool,
    init: Option<PathBuf>,
    force: bool,
    overrides: Vec<String>,
    device: &str,
    progress: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let preset: Preset = choice("preset", preset)?;
    let overrides: TrainOverrides = crate::options::parse("train", &overrides)?;
    let device: DeviceChoice = device.parse().py()?;
    let stop = Arc::new(AtomicBool::new(false));
    let raised: Mutex<Option<PyErr>> = Mutex::new(None);
    let summary = py.detach(|| {
        let cfg = resolve_config(&out, resume, preset, init.as_deref(), config.as_deref(), &overrides)?;
        let TrainingData { dataset, source, notes } = TrainSources { data: data.clone() }.load(&cfg, &SourceArgs::default().options())?;
        let opts = TrainOptions {
            out_dir: out.clone(),
            resume,
            force,
            config: Some(cfg),
            source,
            stop: Some(stop.clone()),
            device,
            precision: Precision::F32,
            init: init.clone(),
        };
        let mut on_event = |event: &TrainEvent| {
            Python::attach(|py| {
                // Signals are checked between steps: Ctrl-C runs Python's handler here.
                let result = py.check_signals().and_then(|()| match &progress {
                    Some(f) => f.call1(py, (event_dict(py, event)?,)).map(drop),
                    None => Ok(()),
                });
                if let Err(e) = result {
                    stop.store(true, Ordering::SeqCst);
                    let mut slot = raised.lock().unwrap_or_else(|p| p.into_inner());
                    slot.get_or_insert(e);
                }
            })
        };
        for n in &notes {
            on_event(&TrainEvent::Notice(n.clone()));
        }
        run_training(&dataset, &opts, &mut on_event)
    });
    if let Some(e) = raised.into_inner().unwrap_or_else(|p| p.into_inner()) {
        // The run saved its checkpoint before returning; the exception says why it stopped.
        summary.py()?;
        return Err(e);
    }
    let s = summary.py()?;
    let d = PyDict::new(py);
    d.set_item("first_step", s.first_step)?;
    d.set_item("last_step", s.last_step)?;
    d.set_item("losses", s.losses)?;
    d.set_item("val_losses", s.val_losses)?;
    d.set_item("stopped", s.stopped)?;
    d.set_item("out_of_time", s.out_of_time)?;
    d.set_item("checkpoint", s.checkpoint.display().to_string())?;
    d.set_item("config", serde_json::to_string(&s.config).unwrap_or_default())?;
    Ok(d)
}
