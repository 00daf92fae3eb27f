//! `socdiff bench quality|mrt|train|sample` (see `socdiff_engine::recipes::speed`,
//! `socdiff_engine::recipes::quality` and `socdiff_engine::recipes::mrt`).

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
    /// MRT's MuPoTS-3D benchmark (the protocol of the multi-person forecasting papers): every
    /// three-person sequence, 120-frame windows every 15 frames, 15 frames observed and 45
    /// forecast at 15 fps, 15 joints, mean error over the first 1/2/3 s, in mm and MRT's units;
    /// the model (mean and best of K, the samples' mean), zero and constant velocity, and the
    /// published rows.
    Mrt(MrtArgs),
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
        BenchCommand::Mrt(args) => args.run()?,
        BenchCommand::Train(job) => job.run(print, note)?,
        BenchCommand::Sample(job) => job.run(print, note)?,
    }
    Ok(ExitCode::SUCCESS)
}

#[derive(clap::Args)]
pub struct MrtArgs {
    /// A trained model at 30 fps (checkpoint or run directory); without it, the baselines only.
    #[arg(long)]
    model: Option<std::path::PathBuf>,
    /// MuPoTS-3D as a dataset directory (17 joints, every sequence TS1–TS20).
    #[arg(long, default_value = "../shared/data/mupots3d")]
    data: std::path::PathBuf,
    /// Samples per window.
    #[arg(long, default_value_t = 8)]
    samples: usize,
    /// DDIM steps per sample (as `forecast --steps`).
    #[arg(long, default_value_t = 50)]
    steps: usize,
    /// Seed of the samples.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Also write every number to DIR/mrt.json (DIR must not exist or be empty).
    #[arg(long, value_name = "DIR")]
    out: Option<std::path::PathBuf>,
    #[command(flatten)]
    device: socdiff_engine::model::DeviceArg,
}

impl MrtArgs {
    fn run(self) -> Result<()> {
        use socdiff_engine::recipes::{mrt, Protocol};
        if let Some(out) = &self.out {
            socdiff_engine::files::check_output_dir(out)?;
        }
        let dataset = socdiff_engine::data::import::load(&self.data, &Default::default())?;
        let model = self.model.as_ref().map(socdiff_engine::checkpoint::Checkpoint::load).transpose()?;
        let proto = Protocol { device: self.device.device, ..Protocol::ddim(0, 0, self.samples, self.steps, self.seed) };
        let windows = if model.is_some() { mrt::windows(&dataset)?.len() } else { 0 };
        let bar = crate::progress::denoising((windows * self.samples * self.steps) as u64);
        let bench = mrt::run(&dataset, model.as_ref(), &proto, &mut |i| bar.inc(i.samples.len() as u64))?;
        bar.finish_and_clear();
        print!("{}", bench.table());
        if let Some(out) = &self.out {
            std::fs::create_dir_all(out).map_err(|e| socdiff_engine::Error::io(out, e))?;
            socdiff_engine::files::write_json_atomic(&out.join("mrt.json"), &bench.to_json())?;
        }
        Ok(())
    }
}
