//! Progress bars shared by the commands that train or sample.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use socdiff_engine::checkpoint::LoadedModel;
use socdiff_engine::recipes::{forecast_quality, forecast_scenes, Protocol, QualityProtocol, QualityResult, Runner, SceneForecast};
use socdiff_engine::train::{self, CheckpointSaved, TrainEvent, TrainOptions, TrainSummary};
use socdiff_engine::{Dataset, Result, Scene};
use std::path::Path;

/// The engine's drivers with progress bars, and their lines on stderr.
pub struct WithProgress;

impl Runner for WithProgress {
    fn train(&mut self, dataset: &Dataset, opts: &TrainOptions) -> Result<TrainSummary> {
        train_with_progress(dataset, opts)
    }

    fn forecast(&mut self, model: &LoadedModel, scenes: &[Scene], proto: &Protocol) -> Result<Vec<SceneForecast>> {
        forecast_with_progress(model, scenes, proto)
    }

    fn quality(&mut self, model: &LoadedModel, dataset: &Dataset, path: &Path, proto: &QualityProtocol) -> Result<QualityResult> {
        let bar = denoising((proto.ddim_steps * proto.samples) as u64);
        let result = forecast_quality(model, dataset, path, proto, &mut |i| bar.inc(i.samples.len() as u64));
        bar.finish_and_clear();
        result
    }

    fn say(&mut self, line: &str) {
        eprintln!("{line}");
    }
}

/// Forecasts `scenes` with a progress bar over all denoising steps.
pub fn forecast_with_progress(model: &LoadedModel, scenes: &[Scene], proto: &Protocol) -> Result<Vec<SceneForecast>> {
    let per_sample = proto.request.sampler.steps(model.diffusion.timesteps());
    let mut windows = 0;
    for s in scenes {
        windows += proto.window_starts(s.num_frames())?.len();
    }
    let bar = denoising((per_sample * proto.request.samples * windows) as u64);
    let out = forecast_scenes(model, scenes, proto, &mut |i| {
        bar.set_message(format!("samples {}–{}  {:.3} s/step", i.samples.start + 1, i.samples.end, i.seconds));
        let left = bar.length().unwrap_or(0).saturating_sub(bar.position());
        bar.inc((i.samples.len() as u64).min(left));
    });
    bar.finish_and_clear();
    out
}

/// Turns `bar` into a training bar from `first` to `total` steps (saying so when resuming).
pub fn start_steps(bar: &ProgressBar, first: u64, total: u64) {
    if first > 0 {
        eprintln!("resuming at step {first} of {total}");
    }
    bar.set_length(total);
    bar.set_position(first);
    bar.reset_eta();
    bar.set_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} steps  {per_sec}  ETA {eta}  {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_draw_target(ProgressDrawTarget::stderr());
}

/// Turns `bar` into a training clock over a budget of `minutes` (position: seconds trained).
pub fn start_clock(bar: &ProgressBar, first: u64, minutes: f64) {
    if first > 0 {
        eprintln!("resuming at step {first} within a budget of {minutes} minutes");
    }
    bar.set_length((60.0 * minutes).round() as u64);
    bar.reset_eta();
    bar.set_style(ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} s  left {eta}  {msg}").expect("valid template").progress_chars("=> "));
    bar.set_draw_target(ProgressDrawTarget::stderr());
}

/// A bar over `total` denoising steps.
pub fn denoising(total: u64) -> ProgressBar {
    let bar = ProgressBar::new(total);
    bar.set_style(ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} denoising steps  {msg}  ETA {eta}").expect("valid template"));
    bar
}

/// The training loss smoothed for display (the log keeps every value).
#[derive(Default)]
pub struct SmoothedLoss(Option<f64>);

impl SmoothedLoss {
    /// Adds a step's loss; returns the smoothed value.
    pub fn add(&mut self, loss: f64) -> f64 {
        let v = self.0.map_or(loss, |a| 0.9 * a + 0.1 * loss);
        self.0 = Some(v);
        v
    }
}

/// Trains with a progress bar and one line per validation, checkpoint and note; prints the
/// outcome.
pub fn train_with_progress(dataset: &Dataset, opts: &TrainOptions) -> Result<TrainSummary> {
    let bar = ProgressBar::hidden();
    // Lines above the bar; plain stderr when the bar is hidden (not a terminal).
    let say = |bar: &ProgressBar, line: String| {
        if bar.is_hidden() {
            eprintln!("{line}");
        } else {
            bar.println(line);
        }
    };
    let (mut loss_avg, mut val) = (SmoothedLoss::default(), None::<f32>);
    let summary = train::train(dataset, opts, &mut |event| match event {
        TrainEvent::Started { first_step, total_steps, params, train_windows, val_windows, batches_per_epoch, config, device } => {
            let m = &config.model;
            eprintln!(
                "training {} on {device} ({} train windows in {batches_per_epoch} batches per epoch, {val_windows} validation windows): hidden {}, aggregator {:?}, {params} parameters, window {}, batch {}, seed {}",
                dataset.name, train_windows, m.hidden, m.aggregator, config.window, config.batch, config.seed
            );
            match config.minutes {
                Some(m) => start_clock(&bar, *first_step, m),
                None => start_steps(&bar, *first_step, *total_steps),
            }
        }
        TrainEvent::Step { step, loss, seconds, .. } => {
            // Smoothed loss for display; the log has every value.
            let l = *loss as f64;
            let v = val.map(|v| format!("  val {v:.4}")).unwrap_or_default();
            match opts.config.as_ref().and_then(|c| c.minutes) {
                // A time budget: the bar is the clock, the message the step.
                Some(_) => {
                    bar.set_message(format!("step {step}  loss {:.4}{v}", loss_avg.add(l)));
                    bar.set_position(*seconds as u64);
                }
                None => {
                    bar.set_message(format!("loss {:.4}{v}", loss_avg.add(l)));
                    bar.set_position(*step);
                }
            }
        }
        TrainEvent::Validation { step, loss } => {
            val = Some(*loss);
            say(&bar, format!("step {step}: validation loss {loss:.5}"));
        }
        TrainEvent::Saved(CheckpointSaved { step, path }) => say(&bar, format!("step {step}: saved {}", path.display())),
        TrainEvent::Notice(msg) => say(&bar, format!("note: {msg}")),
    })?;
    bar.finish_and_clear();
    let last = summary.losses.last().map(|l| format!(", last loss {l:.5}")).unwrap_or_default();
    if summary.stopped {
        eprintln!(
            "stopped early at step {} of {}{last}; checkpoint {} (continue with --resume); exit code 3",
            summary.last_step,
            summary.config.steps,
            summary.checkpoint.display()
        );
    } else {
        let why = if summary.out_of_time { " (its time budget is spent)" } else { "" };
        eprintln!("trained steps {}..{}{why}{last}; checkpoint {}", summary.first_step, summary.last_step, summary.checkpoint.display());
    }
    Ok(summary)
}
