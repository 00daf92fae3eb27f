//! `socdiff distill`: a trained model → a student that samples in 1, 2, 3, 5 or 9 network calls,
//! by rounds of progressive distillation (see `socdiff_engine::train::distill`).

use clap::Args;
use socdiff_engine::checkpoint::Checkpoint;
use socdiff_engine::data::import::SourceArgs;
use socdiff_engine::train::distill::{self, DistillOptions};
use socdiff_engine::train::{TrainSources, TrainingData};
use socdiff_engine::Result;
use std::path::PathBuf;
use std::process::ExitCode;

/// Options of `socdiff distill`.
#[derive(Args)]
pub struct DistillArgs {
    /// The trained model to distill: a run directory or checkpoint (x0-predicting).
    #[arg(long, value_name = "MODEL")]
    teacher: PathBuf,
    /// Network calls of the student's sampler: 1, 2, 3, 5 or 9 (K − 1 jumps and a last call
    /// at noise level 0, as `forecast --steps K` samples; 1: a single jump).
    #[arg(long, default_value_t = 2)]
    steps: usize,
    /// DDIM steps of the teacher's sampler that the first round distills; each round halves
    /// the jumps (33 → 17 → 9 → 5 → 3 → 2 → 1).
    #[arg(long, default_value_t = 33)]
    teacher_steps: usize,
    /// Optimizer steps per round.
    #[arg(long, default_value_t = 2000)]
    round_steps: usize,
    /// Learning rate of each round (a half cosine down to 0 over the round).
    #[arg(long, default_value_t = 2e-4)]
    lr: f64,
    /// Windows per batch (default: the teacher's).
    #[arg(long)]
    batch: Option<usize>,
    #[command(flatten)]
    sources: TrainSources,
    /// The student's run directory (`--model DIR` samples with its own calls); the earlier
    /// rounds train in DIR/rounds/.
    #[arg(long)]
    out: PathBuf,
    /// Continue the rounds in --out (finished rounds are kept, a stopped one resumes).
    #[arg(long)]
    resume: bool,
    #[command(flatten)]
    device: socdiff_engine::model::DeviceArg,
}

pub fn run(args: DistillArgs) -> Result<ExitCode> {
    let teacher = Checkpoint::read_meta(&args.teacher)?;
    let TrainingData { dataset, source, notes } = args.sources.load(&teacher.config, &SourceArgs::default().options())?;
    notes.iter().for_each(|n| eprintln!("{n}"));
    let opts = DistillOptions {
        teacher: args.teacher.clone(),
        calls: args.steps,
        teacher_calls: args.teacher_steps,
        round_steps: args.round_steps,
        lr: args.lr,
        batch: args.batch,
        out_dir: args.out.clone(),
        resume: args.resume,
        source,
        stop: Some(crate::train_cmd::stop_flag()?),
        device: args.device.device,
    };
    let rounds = distill::prepare(&opts)?;
    let n = rounds.len();
    for (k, round) in rounds.iter().enumerate() {
        if distill::round_done(round) {
            eprintln!("round {} of {n} ({} → {} calls) is done", k + 1, round.teacher_calls, round.calls);
            continue;
        }
        eprintln!("{}", round.describe(k, n));
        let summary = crate::progress::train_with_progress(&dataset, &round.options)?;
        if summary.stopped {
            eprintln!("stopped: continue with the same command and --resume");
            return Ok(ExitCode::from(crate::train_cmd::EXIT_STOPPED));
        }
    }
    println!("student ({} calls) → {}   sample with: socdiff forecast --model {} …", args.steps, args.out.display(), args.out.display());
    Ok(ExitCode::SUCCESS)
}
