//! `socdiff`: the command-line tool. A thin layer over `socdiff-engine`.

mod data_cmd;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// Social Diffusion: forecast how groups of people move together.
#[derive(Parser)]
#[command(name = "socdiff", version, about = "Social Diffusion: forecast how groups of people move together", long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Inspect and convert motion data (dataset directories, BVH, Haggling pickles).
    Data {
        #[command(subcommand)]
        command: data_cmd::DataCommand,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Data { command } => data_cmd::run(command),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
