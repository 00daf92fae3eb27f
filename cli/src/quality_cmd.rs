//! `socdiff bench quality`: train the recommended recipe for N minutes of wall time, forecast
//! windows of MuPoTS test (1 s observed, 3 s forecast, K = 8) and score them with the baselines
//! through the one evaluator (`socdiff_engine::recipes::quality`). Resumable: run it again with
//! `--resume` after Ctrl-C; the training time already spent counts, and a larger `--minutes`
//! continues the training.

use crate::train_cmd::{stop_flag, EXIT_STOPPED};
use clap::Args;
use socdiff_engine::recipes::quality::{run_quality_bench, QualityBench, QualityOutcome};
use socdiff_engine::recipes::QualityProtocol;
use socdiff_engine::Result;
use std::path::PathBuf;
use std::process::ExitCode;

/// Options of `socdiff bench quality`.
#[derive(Args)]
pub struct QualityArgs {
    #[command(flatten)]
    device: crate::DeviceArg,
    /// Minutes of training (wall time, over all resumes).
    #[arg(long)]
    minutes: f64,
    /// Output folder: model/ (the run), quality.json, report.json.
    #[arg(long)]
    out: PathBuf,
    /// Dataset with train and test splits.
    #[arg(long, default_value = "../shared/data/mupots3d")]
    data: PathBuf,
    /// Continue an interrupted run in --out.
    #[arg(long)]
    resume: bool,
    /// Noise levels of training (see `socdiff train --noise`).
    #[arg(long, value_enum, default_value = "prefix")]
    noise: socdiff_engine::train::NoiseLevels,
    /// U-Net width.
    #[arg(long, default_value_t = 64)]
    hidden: usize,
    /// Training windows per batch.
    #[arg(long, default_value_t = 16)]
    batch: usize,
    /// Training window (frames).
    #[arg(long, default_value_t = 120)]
    window: usize,
    /// Body-proportion augmentation (see `socdiff train --body-scale`; limbs get half of it;
    /// 0: off). On by default: it measured best (docs/recipes.md §8).
    #[arg(long, default_value_t = 0.1)]
    body_scale: f64,
    /// Pose encoding of training (see `socdiff train --pose`). Residual by default: it measured
    /// best (docs/recipes.md §8).
    #[arg(long, value_enum, default_value = "residual")]
    pose: socdiff_engine::features::PoseEncoding,
    /// Samples per window.
    #[arg(long, default_value_t = 8)]
    samples: usize,
    /// Also score the model after every M minutes of training: the curve of quality against
    /// training time (DIR/at-<minutes>min/quality.json, and "curve" in quality.json).
    #[arg(long, value_name = "M")]
    score_every: Option<f64>,
    /// Pre-training: the first M of the --minutes go to --data mixed with --pretrain-data as
    /// synthetic groups (`socdiff train` with several --data), the rest to fine-tuning on --data
    /// alone. 0: no pre-training.
    #[arg(long, value_name = "M", default_value_t = 0.0)]
    pretrain_minutes: f64,
    /// Single-person sources of the pre-training (dataset folders, BVH files in CMU units, or
    /// folders of them with one joint layout each).
    #[arg(long, num_args = 1.., default_values = [
        "../shared/data/bandai2", "../shared/data/cmu_bvh/131_01.bvh", "../shared/data/cmu_bvh/131_02.bvh",
        "../shared/data/cmu_bvh/131_03.bvh", "../shared/data/cmu_bvh/18_01.bvh",
    ])]
    pretrain_data: Vec<PathBuf>,
    /// Synthetic groups built from the largest pre-training source; the others get as many per
    /// second of motion (at least one).
    #[arg(long, default_value_t = 150)]
    pretrain_groups: usize,
}

/// `socdiff bench quality`.
pub fn run(args: QualityArgs) -> Result<ExitCode> {
    let device = args.device.device;
    let mut config = QualityBench::recipe(args.hidden, args.batch, args.window, args.body_scale);
    (config.noise, config.pose) = (args.noise, args.pose);
    let bench = QualityBench {
        out: args.out.clone(),
        resume: args.resume,
        data: args.data,
        minutes: args.minutes,
        score_every: args.score_every,
        pretrain_minutes: args.pretrain_minutes,
        pretrain_data: args.pretrain_data,
        pretrain_groups: args.pretrain_groups,
        config,
        protocol: QualityProtocol { samples: args.samples, device, ..Default::default() },
        device,
    };
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
