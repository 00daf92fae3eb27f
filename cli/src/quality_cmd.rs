//! `socdiff bench quality`: train the recommended recipe for N minutes of wall time, forecast
//! windows of MuPoTS test (1 s observed, 3 s forecast, K = 8) and score them with the baselines
//! through the one evaluator (`socdiff_engine::recipes::quality`). Resumable: run it again with
//! `--resume` after Ctrl-C; the training time already spent counts, and a larger `--minutes`
//! continues the training.

use crate::train_cmd::{stop_flag, EXIT_STOPPED};
use socdiff_engine::recipes::quality::{run_quality_bench, QualityArgs, QualityOutcome};
use socdiff_engine::Result;
use std::process::ExitCode;

/// `socdiff bench quality`.
pub fn run(args: QualityArgs) -> Result<ExitCode> {
    let bench = args.bench();
    let QualityOutcome::Done { result, curve } = run_quality_bench(&bench, &stop_flag()?, &mut crate::progress::WithProgress)? else {
        eprintln!("stopped; continue with: socdiff bench quality --minutes {} --out {} --resume", args.minutes, args.out.display());
        return Ok(ExitCode::from(EXIT_STOPPED));
    };
    println!("{}", result.report.table());
    if !result.mrt.is_empty() {
        print!("{}", result.mrt_table());
    }
    let (within, worst) = result.jump_summary();
    println!("first-frame jump ≤ the largest observed move in {within} of {} windows (worst ratio {worst:.2})", result.windows);
    if curve.len() > 1 {
        println!("quality vs training time (ours, mean of K, global MPJPE in mm at 1/2/3 s):");
        for c in &curve {
            let mm = |k: &str| c["ours_mean_m"][k].as_f64().map_or(f64::NAN, |v| v * 1e3);
            println!("  {:>6.1} min  step {:>7}  {:>5.0} {:>5.0} {:>5.0}", c["minutes"].as_f64().unwrap_or(f64::NAN), c["step"], mm("1s"), mm("2s"), mm("3s"));
        }
    }
    println!("wrote {} and report.json", args.out.join("quality.json").display());
    Ok(ExitCode::SUCCESS)
}
