//! `socdiff bench realtime`: what a robot beside people gets — the latency of one forecast of a
//! recorded group (by default 3 persons, 1 s observed, 3 s forecast, K = 8) per sampler setting,
//! as percentiles over repeated calls, and what each setting costs in quality on a test split
//! through the one evaluator ([`super::evaluate`]: MPJPE mean and best of K at 1/2/3 s, NDMS).
//!
//! A forecast's latency is the wall time of the whole call on a warm model: canvas, every
//! denoising step, decoding to positions. Fewer DDIM steps are the lever this measures; at 30 Hz
//! a forecast per camera frame must take at most 33 ms.

use super::{evaluate, forecast_scenes, HorizonError, Protocol};
use crate::checkpoint::LoadedModel;
use crate::data::Scene;
use crate::forecast::{sample_scene, Denoising, Forecast, SamplerKind, Task};
use crate::metrics::NdmsConfig;
use crate::{bail, Result};
use serde::Serialize;
use std::fmt::Write;
use std::time::Instant;

/// What [`run`] measures.
#[derive(Clone, Debug, PartialEq)]
pub struct Realtime {
    /// DDIM step counts to measure, one row each.
    pub steps: Vec<usize>,
    /// Samples K per forecast.
    pub samples: usize,
    /// Observed frames.
    pub observe: usize,
    /// Forecast frames.
    pub horizon: usize,
    /// Timed forecasts per row (after [`Realtime::warmup`] untimed ones).
    pub repeats: usize,
    /// Untimed forecasts first (workspace allocation, caches).
    pub warmup: usize,
    /// Seed of the first forecast (each repeat uses the next).
    pub seed: u64,
    /// Quality windows: one every this many frames of each test scene (`None`: one per scene,
    /// from its start).
    pub window_stride: Option<usize>,
}

impl Default for Realtime {
    fn default() -> Self {
        Self { steps: vec![50, 20, 8, 4], samples: 8, observe: 30, horizon: 90, repeats: 50, warmup: 3, seed: 0, window_stride: Some(15) }
    }
}

/// Latency of one setting, milliseconds.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Latency {
    /// Median.
    pub p50_ms: f64,
    /// 99th percentile (nearest rank).
    pub p99_ms: f64,
    /// Mean.
    pub mean_ms: f64,
    /// Slowest.
    pub max_ms: f64,
    /// Timed forecasts.
    pub repeats: usize,
}

impl Latency {
    /// Percentiles of `seconds` (nearest rank: the smallest value with at least p of them at
    /// or below it).
    pub fn of(seconds: &[f64]) -> Result<Self> {
        if seconds.is_empty() || seconds.iter().any(|s| !s.is_finite()) {
            bail!("latency: no timings, or a non-finite one");
        }
        let mut v: Vec<f64> = seconds.iter().map(|s| s * 1e3).collect();
        v.sort_by(f64::total_cmp);
        let rank = |p: f64| v[((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1];
        Ok(Self { p50_ms: rank(0.5), p99_ms: rank(0.99), mean_ms: v.iter().sum::<f64>() / v.len() as f64, max_ms: v[v.len() - 1], repeats: v.len() })
    }
}

/// Quality of one setting on the test split.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Quality {
    /// Forecast windows of the test scenes.
    pub windows: usize,
    /// MPJPE at 1, 2 and 3 s, metres, with the baselines.
    pub mpjpe: Vec<HorizonError>,
    /// NDMS over the forecast frames.
    pub ndms: f64,
}

/// One row: a model, a DDIM step count, its network calls, latency and quality.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Row {
    /// The model's file (the teacher's, or a distilled student's).
    pub model: String,
    /// A distilled student (sampled with its own calls).
    pub student: bool,
    /// DDIM steps (η = 0).
    pub steps: usize,
    /// Network evaluations per forecast (all K samples in each).
    pub calls: usize,
    /// Latency of one forecast.
    pub latency: Latency,
    /// Quality on the test split, when measured.
    pub quality: Option<Quality>,
}

/// Everything [`run`] measured.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RealtimeBench {
    /// The model's file.
    pub model: String,
    /// Its optimizer step.
    pub model_step: u64,
    /// The scene timed, and its persons.
    pub scene: String,
    /// Persons forecast.
    pub persons: usize,
    /// Observed and forecast frames, samples K, frames per second.
    pub observe: usize,
    /// Forecast frames.
    pub horizon: usize,
    /// Samples K.
    pub samples: usize,
    /// Frame rate of the model.
    pub fps: f64,
    /// Worker threads.
    pub threads: usize,
    /// One row per step count of the model, then one per student.
    pub rows: Vec<Row>,
}

/// Times forecasts of `cfg.observe` frames of `scene` (in the model's skeleton and frame rate;
/// the window moves one frame per forecast) for each step count of `cfg`, then for each of
/// `students` (distilled models of the same skeleton) at its own calls; and, when `test` is not
/// empty, scores the same setting on the windows of every test scene
/// ([`Realtime::window_stride`]). `on_row` hears each row as it is done.
pub fn run(
    model: &LoadedModel,
    students: &[LoadedModel],
    scene: &Scene,
    test: &[Scene],
    cfg: &Realtime,
    on_row: &mut dyn FnMut(&Row),
) -> Result<RealtimeBench> {
    if cfg.steps.is_empty() || cfg.steps.contains(&0) {
        bail!("`steps`: give one or more step counts of at least 1");
    }
    if cfg.repeats == 0 || cfg.repeats > 100_000 || cfg.warmup > 100_000 {
        bail!("`repeats` must be 1..=100000 and `warmup` at most 100000");
    }
    let (observe, horizon) = (cfg.observe, cfg.horizon);
    if scene.num_frames() < observe {
        bail!("scene {} has {} frames, fewer than the {observe} observed", scene.name, scene.num_frames());
    }
    let mut settings: Vec<(&LoadedModel, usize)> = cfg.steps.iter().map(|&s| (model, s)).collect();
    for st in students {
        let Some(round) = &st.config.distill else {
            bail!("{}: not a distilled student (`socdiff distill` makes one)", st.path.display());
        };
        if st.skeleton.joints != model.skeleton.joints || (st.fps - model.fps).abs() > 1e-9 {
            bail!("{}: its skeleton or frame rate differs from the model's", st.path.display());
        }
        settings.push((st, round.calls));
    }
    // Each forecast observes the window one frame later than the last, as in a stream: no two
    // consecutive forecasts share their observed frames (nor the network's work on them).
    let starts = (scene.num_frames() - observe + 1).min(cfg.warmup + cfg.repeats);
    let inputs: Vec<Scene> = (0..starts).map(|s| scene.slice_frames(s, s + observe)).collect::<Result<_>>()?;
    let task = Task::Forecast { observe, horizon };
    let mut rows = Vec::with_capacity(settings.len());
    for (m, steps) in settings {
        let net = crate::sample::SamplingNet::new(&m.denoiser, &m.diffusion, &crate::model::DeviceChoice::Cpu.resolve()?).map_err(|e| e.in_file(&m.path))?;
        let denoising = Denoising::of(m, net.x0_model());
        let request =
            |seed: u64| Forecast { observe, horizon, samples: cfg.samples, sampler: SamplerKind::Ddim { steps, eta: 0.0 }, seed, ..Default::default() };
        let mut seconds = Vec::with_capacity(cfg.repeats);
        let mut calls = 0;
        for r in 0..cfg.warmup + cfg.repeats {
            let input = &inputs[r % inputs.len()];
            let start = Instant::now();
            let fc = sample_scene(&denoising, input, &task, &request(cfg.seed + r as u64), &mut |_| {})?;
            let elapsed = start.elapsed().as_secs_f64();
            calls = fc.provenance.timings.model_calls;
            if r >= cfg.warmup {
                seconds.push(elapsed);
            }
        }
        let quality = if test.is_empty() {
            None
        } else {
            let proto = Protocol { request: request(cfg.seed), window_stride: cfg.window_stride, device: Default::default() };
            let runs = forecast_scenes(m, test, &proto, &mut |_| {})?;
            let report = evaluate(&runs, test, &NdmsConfig::default())?;
            Some(Quality { windows: runs.len(), mpjpe: report.mpjpe, ndms: report.ndms.mean })
        };
        let row = Row { model: m.path.display().to_string(), student: m.config.distill.is_some(), steps, calls, latency: Latency::of(&seconds)?, quality };
        on_row(&row);
        rows.push(row);
    }
    Ok(RealtimeBench {
        model: model.path.display().to_string(),
        model_step: model.step,
        scene: scene.name.clone(),
        persons: scene.num_persons(),
        observe,
        horizon,
        samples: cfg.samples,
        fps: model.fps,
        threads: crate::model::runtime::worker_threads(),
        rows,
    })
}

impl RealtimeBench {
    /// The table: one row per step count.
    pub fn table(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{}: {} persons, {} observed + {} forecast frames at {} fps, K = {}, {} threads; model {} (step {})",
            self.scene, self.persons, self.observe, self.horizon, self.fps, self.samples, self.threads, self.model, self.model_step
        );
        let _ = writeln!(
            s,
            "{:>8} {:>6} {:>6} {:>9} {:>9} {:>9}   {:>23} {:>23} {:>7}",
            "model", "steps", "calls", "p50 ms", "p99 ms", "mean ms", "MPJPE mean 1/2/3 s mm", "best of K 1/2/3 s mm", "NDMS"
        );
        let mm = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{:.0}", v * 1e3));
        let three = |q: &Quality, f: &dyn Fn(&HorizonError) -> Option<f64>| q.mpjpe.iter().map(|h| mm(f(h))).collect::<Vec<_>>().join("/");
        for r in &self.rows {
            let l = &r.latency;
            let (mean, best, ndms) = match &r.quality {
                Some(q) => (three(q, &|h| h.mean), three(q, &|h| h.best), format!("{:.3}", q.ndms)),
                None => ("–".into(), "–".into(), "–".into()),
            };
            let who = if r.student { "student" } else { "model" };
            let _ =
                writeln!(s, "{who:>8} {:>6} {:>6} {:>9.1} {:>9.1} {:>9.1}   {mean:>23} {best:>23} {ndms:>7}", r.steps, r.calls, l.p50_ms, l.p99_ms, l.mean_ms);
        }
        for r in self.rows.iter().filter(|r| r.student) {
            let _ = writeln!(s, "student of {} calls: {}", r.steps, r.model);
        }
        if let Some(q) = self.rows.iter().find_map(|r| r.quality.as_ref()) {
            let zv = q.mpjpe.iter().map(|h| mm(h.zero_velocity)).collect::<Vec<_>>().join("/");
            let cv = q.mpjpe.iter().map(|h| mm(h.constant_velocity)).collect::<Vec<_>>().join("/");
            let _ = writeln!(s, "baselines on the same {} test windows: zero velocity {zv} mm, constant velocity {cv} mm", q.windows);
        }
        s
    }

    /// Every number, as JSON.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::to_value(self).unwrap_or(serde_json::Value::Null)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_are_nearest_rank() {
        // 1..=100 ms: the median is the 50th value, p99 the 99th.
        let s: Vec<f64> = (1..=100).rev().map(|v| v as f64 * 1e-3).collect();
        let l = Latency::of(&s).unwrap();
        assert!((l.p50_ms - 50.0).abs() < 1e-9 && (l.p99_ms - 99.0).abs() < 1e-9 && (l.max_ms - 100.0).abs() < 1e-9, "{l:?}");
        assert!((l.mean_ms - 50.5).abs() < 1e-9);
        // Three values: p50 is the second, p99 the third.
        let l = Latency::of(&[0.003, 0.001, 0.002]).unwrap();
        assert_eq!((l.p50_ms, l.p99_ms, l.repeats), (2.0, 3.0, 3));
        assert!(Latency::of(&[]).is_err() && Latency::of(&[f64::NAN]).is_err());
    }
}
