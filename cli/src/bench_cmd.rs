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
    /// Latency for a robot: percentiles (p50, p99) of whole forecasts of a recorded group (3
    /// persons, 1 s observed, 3 s forecast, K = 8) per DDIM step count, and each setting's
    /// quality on the test split (MPJPE mean and best of K at 1/2/3 s, NDMS).
    Realtime(RealtimeArgs),
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
        BenchCommand::Realtime(args) => args.run()?,
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

#[derive(clap::Args)]
pub struct RealtimeArgs {
    /// A trained model (checkpoint, run directory or model.safetensors).
    #[arg(long)]
    model: std::path::PathBuf,
    /// Dataset whose test split is scored; its scene --sequence is the one timed.
    #[arg(long, default_value = "../shared/data/mupots3d")]
    data: std::path::PathBuf,
    /// The scene timed (its persons are all forecast).
    #[arg(long, default_value = "TS16")]
    sequence: String,
    /// DDIM step counts, one row each (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "50,20,8,4")]
    steps: Vec<usize>,
    /// Samples K per forecast.
    #[arg(long, default_value_t = 8)]
    samples: usize,
    /// Observed frames.
    #[arg(long, default_value_t = 30)]
    observe: usize,
    /// Forecast frames.
    #[arg(long, default_value_t = 90)]
    horizon: usize,
    /// Timed forecasts per row (after 3 untimed ones).
    #[arg(long, default_value_t = 50)]
    repeats: usize,
    /// Distilled students of --model (`socdiff distill`), comma-separated: one row each, at
    /// its own calls.
    #[arg(long, value_delimiter = ',', value_name = "MODEL")]
    students: Vec<std::path::PathBuf>,
    /// Time only: no forecasts of the test split.
    #[arg(long)]
    no_quality: bool,
    /// Quality on a window every N frames of each test scene (MRT's 15 on MuPoTS: 93 windows
    /// of 1 s + 3 s); 0: one window per scene, from its start.
    #[arg(long, default_value_t = 15)]
    window_stride: usize,
    /// Worker threads (default: every CPU).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Also write every number to DIR/realtime.json (DIR must not exist or be empty).
    #[arg(long, value_name = "DIR")]
    out: Option<std::path::PathBuf>,
}

impl RealtimeArgs {
    fn run(self) -> Result<()> {
        use socdiff_engine::recipes::realtime::{self, Realtime};
        if let Some(out) = &self.out {
            socdiff_engine::files::check_output_dir(out)?;
        }
        let model = socdiff_engine::checkpoint::Checkpoint::load(&self.model)?;
        let students: Vec<_> = self.students.iter().map(socdiff_engine::checkpoint::Checkpoint::load).collect::<Result<_>>()?;
        let dataset = socdiff_engine::data::import::load(&self.data, &Default::default())?;
        // Scenes on another skeleton or frame rate go onto the model's by joint names.
        let fit = |s: &socdiff_engine::Scene| model.fit_scene(s, true).map(|(s, _)| s).map_err(|e| e.in_file(&self.data));
        let scene = fit(dataset.scene(&self.sequence).map_err(|e| e.in_file(&self.data))?)?;
        let test: Vec<socdiff_engine::Scene> =
            if self.no_quality { Vec::new() } else { dataset.split(socdiff_engine::Split::Test).map(fit).collect::<Result<_>>()? };
        let cfg = Realtime {
            steps: self.steps,
            samples: self.samples,
            observe: self.observe,
            horizon: self.horizon,
            repeats: self.repeats,
            window_stride: (self.window_stride > 0).then_some(self.window_stride),
            ..Default::default()
        };
        let bench = realtime::run(&model, &students, &scene, &test, &cfg, &mut |row| {
            let who = if row.student { "student, " } else { "" };
            eprintln!("{who}{} steps: p50 {:.1} ms, p99 {:.1} ms", row.steps, row.latency.p50_ms, row.latency.p99_ms)
        })?;
        print!("{}", bench.table());
        if let Some(out) = &self.out {
            std::fs::create_dir_all(out).map_err(|e| socdiff_engine::Error::io(out, e))?;
            socdiff_engine::files::write_json_atomic(&out.join("realtime.json"), &bench.to_json())?;
        }
        Ok(())
    }
}
