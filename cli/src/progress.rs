//! Progress bars shared by the commands that train or sample.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use socdiff_engine::recipes::ablation::Runner;
use socdiff_engine::recipes::{Protocol, SceneForecast};
use socdiff_engine::train::{LoadedModel, TrainOptions, TrainSummary};
use socdiff_engine::{Dataset, Result, Scene};

/// The engine's drivers with progress bars, and their lines on stderr.
pub struct WithProgress;

impl Runner for WithProgress {
    fn train(&mut self, dataset: &Dataset, opts: &TrainOptions) -> Result<TrainSummary> {
        crate::train_cmd::train_with_progress(dataset, opts)
    }

    fn forecast(&mut self, model: &LoadedModel, scenes: &[Scene], proto: &Protocol) -> Result<Vec<SceneForecast>> {
        crate::demo_cmd::forecast_with_progress(model, scenes, proto)
    }

    fn say(&mut self, line: &str) {
        eprintln!("{line}");
    }
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
