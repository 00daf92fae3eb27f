//! `socdiff`: the command-line tool. A thin layer over `socdiff-engine`.

mod ablate_cmd;
mod bench_cmd;
mod classifier_cmd;
mod data_cmd;
mod demo_cmd;
mod distill_cmd;
mod eval_cmd;
mod export_cmd;
mod forecast_cmd;
mod progress;
mod quality_cmd;
mod reference;
mod train_cmd;
mod view_cmd;

use clap::{Parser, Subcommand};
use socdiff_engine::Result;
use std::process::ExitCode;

/// Social Diffusion: forecast how groups of people move together.
#[derive(Parser)]
#[command(name = "socdiff", version, about = "Social Diffusion: forecast how groups of people move together", long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Load checkpoints that carry no checksum (not written by socdiff, or edited), with a
    /// warning; without this they are refused.
    #[arg(long, global = true)]
    trust_unchecked_checkpoints: bool,
}

#[derive(Subcommand)]
enum Command {
    /// The whole pipeline in one go: data → the bundled pretrained model (or, with --train, a
    /// small model trained on the data) → forecast → HTML view → evaluation report, on an
    /// embedded scene (no downloads) or a dataset (--data).
    Demo(demo_cmd::DemoArgs),
    /// Inspect and convert motion data (dataset directories, BVH, Haggling pickles).
    Data {
        #[command(subcommand)]
        command: data_cmd::DataCommand,
    },
    /// Train a denoiser on a dataset (or continue one with --resume); checkpoints and a JSONL
    /// log go to --out. Ctrl-C or SIGTERM stops after saving (exit code 3).
    Train(train_cmd::TrainArgs),
    /// Distill a trained model into a student that samples in 1, 2, 3, 5 or 9 network calls
    /// (progressive distillation, resumable rounds); the student is an ordinary model.
    Distill(distill_cmd::DistillArgs),
    /// Benchmarks: seconds per training or denoising step, and peak memory.
    Bench {
        #[command(subcommand)]
        command: bench_cmd::BenchCommand,
    },
    /// Write a self-contained HTML page that plays the motion in a browser (skeletons in 3D,
    /// observed vs forecast frames, samples side by side).
    View(view_cmd::ViewArgs),
    /// Export motion: BVH per person, JSON arrays, or PNG filmstrips.
    Export(export_cmd::ExportArgs),
    /// Put a motion on another body's proportions (bone lengths from a scene, a BVH or a
    /// dataset's person): dataset and BVH output.
    Retarget(export_cmd::RetargetArgs),
    /// Forecast a scene: K samples of --horizon frames after its first --observe frames, as a
    /// dataset directory (observed part + samples, provenance in dataset.json).
    Forecast(socdiff_engine::forecast::ForecastArgs),
    /// Complete a scene with missing joints, frames or persons (--missing joints=…|frames=a..b|persons=…).
    Complete(socdiff_engine::forecast::CompleteArgs),
    /// Generate whole scenes from noise: --persons on a circle (or the placement of --layout),
    /// --frames long, K samples.
    Generate(socdiff_engine::forecast::GenerateArgs),
    /// Interpolate between two motions (DDIM inversion, spherical interpolation of the noises),
    /// or in-between them (--transition F).
    Interpolate(socdiff_engine::forecast::InterpolateArgs),
    /// Score forecasts and baselines against a reference dataset (NDMS, MPJPE, APD/ADE/FDE,
    /// plausibility, SSCP): report.json, PNG plots and a table.
    Eval(socdiff_engine::eval::EvalArgs),
    /// Speaking and buyer detectors for SSCP: train, evaluate, generate training triads, and
    /// speaking statistics of Haggling speech files.
    Classifier {
        #[command(subcommand)]
        command: classifier_cmd::ClassifierCommand,
    },
    /// Ablation tables: one model per aggregator (--aggregators none,mean,attention), or
    /// models sampled several ways (--model RUN [--model RUN2] --samplers ddpm,ddim20,…); NDMS,
    /// SSCP, MPJPE, plausibility.
    Ablate(ablate_cmd::AblateArgs),
    /// Print the CLI reference (every command's help) as Markdown: docs/cli.md.
    #[command(hide = true)]
    CliReference,
}

fn main() -> ExitCode {
    socdiff_engine::model::runtime::tune_process();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if !e.use_stderr() => e.exit(), // --help, --version
        Err(e) => {
            eprintln!("{}", one_line(&e.render().to_string()));
            return ExitCode::from(2);
        }
    };
    socdiff_engine::checkpoint::trust_unchecked(cli.trust_unchecked_checkpoints);
    // The worker pool, with this thread in it (`bench --threads N` sizes it).
    let threads = match &cli.command {
        Command::Bench { command: bench_cmd::BenchCommand::Train(job) } => job.threads,
        Command::Bench { command: bench_cmd::BenchCommand::Sample(job) } => job.threads,
        Command::Bench { command: bench_cmd::BenchCommand::Realtime(job) } => job.threads,
        _ => None,
    };
    if let Err(e) = socdiff_engine::model::runtime::start_workers(threads) {
        eprintln!("error: {}", settings_as_flags(&format!("`threads`: {e}")));
        return ExitCode::FAILURE;
    }
    let done = |r: Result<()>| r.map(|()| ExitCode::SUCCESS);
    let result = match cli.command {
        Command::Demo(args) => demo_cmd::run(args),
        Command::Data { command } => done(data_cmd::run(command)),
        Command::Train(args) => train_cmd::run(args),
        Command::Distill(args) => distill_cmd::run(args),
        Command::Bench { command } => bench_cmd::run(command),
        Command::View(args) => done(view_cmd::run(args)),
        Command::Export(args) => done(export_cmd::run(args)),
        Command::Retarget(args) => done(export_cmd::run_retarget(args)),
        Command::Forecast(args) => done(forecast_cmd::run_forecast(args)),
        Command::Complete(args) => done(forecast_cmd::run_complete(args)),
        Command::Generate(args) => done(forecast_cmd::run_generate(args)),
        Command::Interpolate(args) => done(forecast_cmd::run_interpolate(args)),
        Command::Eval(args) => done(eval_cmd::run(args)),
        Command::Classifier { command } => done(classifier_cmd::run(command)),
        Command::Ablate(args) => done(ablate_cmd::run(args)),
        Command::CliReference => {
            print!("{}", reference::markdown());
            Ok(ExitCode::SUCCESS)
        }
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", settings_as_flags(&e.to_string()));
            ExitCode::FAILURE
        }
    }
}

/// A clap error on one line (its value list and tip included), as every other error is.
fn one_line(rendered: &str) -> String {
    let parts: Vec<&str> = rendered.lines().map(str::trim).filter(|l| !l.is_empty() && !l.starts_with("For more information")).collect();
    parts.join(" ")
}

/// Engine messages name the settings they are about by field name in backticks (`` `observe` ``,
/// `` `persons_min` ``); on the command line those settings are flags, so a backticked name that
/// is a long option of some command is shown as that flag (`--observe`, `--save-every`).
fn settings_as_flags(msg: &str) -> String {
    use clap::CommandFactory;
    fn longs(cmd: &clap::Command, out: &mut std::collections::HashSet<String>) {
        out.extend(cmd.get_arguments().filter_map(|a| a.get_long()).map(str::to_string));
        for sub in cmd.get_subcommands() {
            longs(sub, out);
        }
    }
    let mut flags = std::collections::HashSet::new();
    longs(&Cli::command(), &mut flags);
    let mut out = String::with_capacity(msg.len());
    let mut rest = msg;
    while let Some(open) = rest.find('`') {
        let Some(len) = rest[open + 1..].find('`') else { break };
        let name = &rest[open + 1..open + 1 + len];
        let flag = name.replace('_', "-");
        out.push_str(&rest[..open]);
        if !name.is_empty() && name.bytes().all(|b| b.is_ascii_lowercase() || b == b'_') && flags.contains(&flag) {
            out.push_str("--");
            out.push_str(&flag);
        } else {
            out.push_str(&rest[open..open + len + 2]);
        }
        rest = &rest[open + len + 2..];
    }
    out.push_str(rest);
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn parse_errors_are_one_line() {
        use clap::Parser;
        let e = super::Cli::try_parse_from(["socdiff", "ablate", "--data", "d", "--out", "o", "--aggregators", "max"]).err().unwrap();
        let line = super::one_line(&e.render().to_string());
        assert!(line.starts_with("error: invalid value 'max'") && line.contains("none, mean, attention") && !line.contains('\n'), "{line}");
    }

    #[test]
    fn settings_named_by_the_engine_are_shown_as_flags() {
        let shown = super::settings_as_flags("`observe` 130 must be less than 40; `save_every` and `val_every` go together; `head` is a joint; a `lone");
        assert_eq!(shown, "--observe 130 must be less than 40; --save-every and --val-every go together; `head` is a joint; a `lone");
    }
}
