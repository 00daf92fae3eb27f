//! `socdiff.evaluate`: `socdiff eval` as a call returning its report.

use crate::IntoPy;
use pyo3::prelude::*;
use socdiff_engine::eval::EvalArgs;

/// Runs the evaluation `args` describe (`socdiff eval`'s options as arguments) and returns
/// report.json's text; with `write`, also writes it and the plots to `--out`, as the CLI does.
#[pyfunction]
pub fn evaluate(py: Python<'_>, args: Vec<String>, write: bool) -> PyResult<String> {
    let args: EvalArgs = crate::options::parse("evaluate", &args)?;
    py.detach(|| {
        let job = args.job()?;
        job.check()?;
        if write {
            socdiff_engine::files::check_output_dir(&args.out)?;
        }
        let outcome = job.run(&mut |_| {})?;
        if write {
            outcome.write(&args.out, args.write_baselines.as_deref())?;
        }
        Ok(outcome.report.to_json())
    })
    .py()
}
