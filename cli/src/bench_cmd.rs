//! `socdiff bench quality|train|sample` (see `socdiff_engine::recipes::speed` and
//! `socdiff_engine::recipes::quality`).

use clap::Subcommand;
use socdiff_engine::recipes::speed::{SampleSpeed, TrainSpeed};
use socdiff_engine::Result;
use std::process::ExitCode;

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Forecasting quality: train the recommended recipe for --minutes, forecast MuPoTS test
    /// windows (1 s observed, 3 s forecast, K = 8) and score them with the baselines (MPJPE at
    /// 1/2/3 s, NDMS, first-frame jump); quality.json keyed by protocol, method and horizon.
    Quality(socdiff_engine::recipes::quality::QualityArgs),
    /// Seconds per training step (forward, backward, Adam, EMA) on random data, and peak RSS.
    Train(TrainSpeed),
    /// Seconds per denoising step and peak RSS of forecasting one scene (forward-only network,
    /// random weights), and the wall time of whole minute-long forecasts with DDIM and DDPM.
    Sample(SampleSpeed),
}

pub fn run(cmd: BenchCommand) -> Result<ExitCode> {
    let (print, note) = (&mut |line: &str| println!("{line}"), &mut |line: &str| eprintln!("{line}"));
    match cmd {
        BenchCommand::Quality(args) => return crate::quality_cmd::run(args),
        BenchCommand::Train(job) => job.run(print, note)?,
        BenchCommand::Sample(job) => job.run(print, note)?,
    }
    Ok(ExitCode::SUCCESS)
}
