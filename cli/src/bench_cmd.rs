//! `socdiff bench train`: seconds per training step and peak memory, beside the PyTorch
//! reference timings measured on the project's 2-core machine (CANDLE_NOTES.md).

use clap::Subcommand;
use socdiff_engine::model::{Aggregator, DenoiserConfig};
use socdiff_engine::{features, train, Error, Result};

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Seconds per training step (forward, backward, Adam, EMA) on random data, and peak RSS.
    Train {
        /// U-Net widths to time (comma-separated).
        #[arg(long, value_delimiter = ',', default_value = "128,256")]
        hidden: Vec<usize>,
        /// Windows per batch.
        #[arg(long, default_value_t = 16)]
        batch: usize,
        /// Persons per window.
        #[arg(long, default_value_t = 3)]
        persons: usize,
        /// Frames per window.
        #[arg(long, default_value_t = 256)]
        frames: usize,
        /// Joints per person (19: Panoptic, δ = 61).
        #[arg(long, default_value_t = 19)]
        joints: usize,
        /// Timed steps per width (after one warm-up step).
        #[arg(long, default_value_t = 3)]
        steps: usize,
        /// Aggregator: none, mean or attention (4 heads).
        #[arg(long, default_value = "mean", value_parser = ["none", "mean", "attention"])]
        aggregator: String,
    },
}

/// PyTorch 2 eager on the same 2-core machine, same U-Net and batch (CANDLE_NOTES.md):
/// (hidden, seconds per step, peak RSS).
const PYTORCH: [(usize, &str, &str); 2] = [(128, "1.27–1.35 s", "1.25 GB"), (256, "4.12 s", "1.84 GB")];

/// A `/proc/self/status` field in bytes (Linux), e.g. `VmHWM` (peak resident set).
fn status_bytes(field: &str) -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = text.lines().find(|l| l.starts_with(field))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Resets the peak RSS to the current RSS (Linux ≥ 4.0; best effort).
fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

pub fn run(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Train { hidden, batch, persons, frames, joints, steps, aggregator } => {
            let agg = match aggregator.as_str() {
                "none" => Aggregator::None,
                "mean" => Aggregator::Mean,
                _ => Aggregator::Attention { heads: 4 },
            };
            let d = features::feature_dim(joints);
            if cfg!(debug_assertions) {
                eprintln!("note: a debug build; timings are only meaningful with --release");
            }
            println!(
                "training step: {batch} windows × {persons} persons × {frames} frames (δ = {d}), aggregator {aggregator}, forward + backward + Adam + EMA"
            );
            println!("{:>6}  {:>10}  {:>9}  {:>16}  {:>9}  {:>10}  PyTorch eager, same 2-core machine", "hidden", "params", "s/step", "min–max", "peak RSS", "threads");
            for h in hidden {
                if h == 0 {
                    return Err(Error::invalid("--hidden: widths must be positive"));
                }
                let cfg = DenoiserConfig { feature_dims: d, hidden: h, social_dim: h, aggregator: agg, ..Default::default() };
                let resettable = reset_peak_rss();
                let t = train::time_train_steps(&cfg, batch, persons, frames, steps)?;
                let peak = status_bytes("VmHWM").map_or("?".to_string(), |b| format!("{:.2} GB{}", b as f64 / 1e9, if resettable { "" } else { "*" }));
                let mut s = t.seconds.clone();
                s.sort_by(f64::total_cmp);
                let median = s[s.len() / 2];
                let reference = PYTORCH.iter().find(|r| r.0 == h).map_or("–".to_string(), |r| format!("{} ({})", r.1, r.2));
                println!(
                    "{h:>6}  {:>10}  {median:>9.3}  {:>16}  {peak:>9}  {:>10}  {reference}",
                    t.params,
                    format!("{:.3}–{:.3}", s[0], s[s.len() - 1]),
                    t.threads
                );
            }
            println!("s/step: median of the timed steps; peak RSS: VmHWM of this process during that width (* = not resettable, the peak of the whole process)");
            Ok(())
        }
    }
}
