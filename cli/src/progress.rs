//! Progress bars shared by the commands that train or sample.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use socdiff_engine::recipes::{forecast_quality, forecast_scenes, Protocol, QualityProtocol, QualityResult, Runner, SceneForecast};
use socdiff_engine::train::{LoadedModel, TrainOptions, TrainSummary};
use socdiff_engine::{Dataset, Result, Scene};
use std::path::Path;

/// The engine's drivers with progress bars, and their lines on stderr.
pub struct WithProgress;

impl Runner for WithProgress {
    fn train(&mut self, dataset: &Dataset, opts: &TrainOptions) -> Result<TrainSummary> {
        crate::train_cmd::train_with_progress(dataset, opts)
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
    let per_sample = proto.opts.sampler.steps(model.diffusion.timesteps());
    let mut windows = 0;
    for s in scenes {
        windows += proto.window_starts(s.num_frames())?.len();
    }
    let bar = denoising((per_sample * proto.opts.samples * windows) as u64);
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
