//! End-to-end recipes shared by `socdiff demo`, `socdiff ablate` and the examples: forecast
//! every scene of a test split with a trained model, score the forecasts in one compact report,
//! write the viewer page, the leader/follower probe of the social channel, and the ablation
//! and demo drivers ([`ablation`], [`demo`]), which train and forecast through a [`Runner`].
//!
//! ```text
//! test scenes ──forecast_scenes (observe, horizon, K samples, sampler, seed)──▶ [SceneForecast]
//!             ──evaluate (NDMS database = the reference scenes)──▶ QuickReport ──▶ JSON, table
//! ```
//!
//! # What [`evaluate`] measures
//! Everything through the one evaluator, [`crate::eval::evaluate`] (what `socdiff eval` runs),
//! with the windows' recordings as the scored scenes; [`QuickReport`] is a compact view of its
//! report.
//! - NDMS ([`crate::metrics::ndms`]) of every sample and person over the whole forecast, against
//!   a database of every word of the reference scenes (the test split's recorded motion). The
//!   curve's entry `f` is the word starting `f` frames after the first forecast word, which
//!   starts κ frames before the first forecast frame (the reference's convention); "frames a–b"
//!   means the mean of entries `a..=b`.
//! - MPJPE (all joints, metres) at 1, 2 and 3 s after the last observed frame — mean over the K
//!   samples and best of K, over the persons valid there, averaged over the scenes whose
//!   recording reaches that far — and the same for the zero- and constant-velocity baselines.
//! - Plausibility: bone-length deviation from the observed bones (mm), foot sliding (m/s, also
//!   of the recorded future), mean joint acceleration (m/s², also of the recorded future, both
//!   including the last two observed frames), and the JS distance between the joint-speed
//!   histogram of all forecast frames and that of the recorded futures (one time bin).
//! - SSCP with annotated speech: when every scene has a `speaking` signal and buyer / seller
//!   roles, the transition distribution of the states of the forecasts (their motion, the
//!   recorded speech) against that of the recorded motion, over the forecast frames the
//!   recording covers. (With speech from motion classifiers instead, see `socdiff eval`.)

pub mod ablation;
pub mod demo;
pub mod mrt;
pub mod quality;
pub mod realtime;
pub mod speed;

use crate::checkpoint::{Checkpoint, LoadedModel};
use crate::data::dataset::Sequence;
use crate::data::synthetic::{leader_follower_scene, LeaderFollower};
use crate::data::{Dataset, Scene, Skeleton, Split};
use crate::export::group_scenes;
use crate::export::html::{write_html, ViewOptions};
use crate::features::ground_midpoint;
use crate::forecast::{sample_scene, Denoising, Forecast, ForecastOutput, SamplerKind, StepInfo, Task, Timings};
use crate::metrics::ndms::{NdmsConfig, NdmsDatabase};
use crate::metrics::plausibility::SpeedHistogramConfig;
use crate::metrics::sscp::{SscpConfig, Triad};
use crate::model::DenoiserConfig;
use crate::train::{train, AdamConfig, EmaConfig, TrainConfig, TrainEvent, TrainOptions, TrainSummary};
use crate::{bail, Result};
use ndarray::{s, Array5, Axis};
use serde::Serialize;
use serde_json::Value;
use std::path::Path;

/// How the scenes of a split are forecast.
#[derive(Clone, Debug, PartialEq)]
pub struct Protocol {
    /// Each window's request: observed frames at its start, forecast frames after them,
    /// samples, sampler, conditioning and seed.
    pub request: Forecast,
    /// `None`: one window per scene, at its start. `Some(n)`: a window every `n` frames, as
    /// long as the recording covers the observed frames and `horizon` more.
    pub window_stride: Option<usize>,
    /// Where the network samples (the sampling route of that device).
    pub device: crate::model::DeviceChoice,
}

impl Protocol {
    /// One window per scene from frame 0: `observe` frames observed, `horizon` forecast, K
    /// `samples` by DDIM over `steps` (η = 0) from `seed`.
    pub fn ddim(observe: usize, horizon: usize, samples: usize, steps: usize, seed: u64) -> Self {
        let request = Forecast { observe, horizon, samples, sampler: SamplerKind::Ddim { steps, eta: 0.0 }, seed, ..Default::default() };
        Self { request, window_stride: None, device: Default::default() }
    }

    /// First frames of the forecast windows of a scene of `frames` frames.
    pub fn window_starts(&self, frames: usize) -> Result<Vec<usize>> {
        Ok(match self.window_stride {
            None => vec![0],
            Some(0) => bail!("window stride must be at least 1"),
            Some(k) => (0..).map(|i| i * k).take_while(|&s| s + self.request.observe + self.request.horizon <= frames).collect(),
        })
    }
}

/// The forecast of one window of a recorded scene.
#[derive(Clone, Debug)]
pub struct SceneForecast {
    /// The recording from the window's first frame on (observed frames and as much of the
    /// future as was recorded).
    pub truth: Scene,
    /// The forecast (observed frames + samples).
    pub forecast: ForecastOutput,
}

impl SceneForecast {
    /// Samples as one array.
    ///
    /// # Shapes
    /// - output: `[K, observe + horizon, persons, joints, 3]`.
    pub fn samples(&self) -> Array5<f32> {
        let views: Vec<_> = self.forecast.samples.iter().map(|s| s.positions.view().insert_axis(Axis(0))).collect();
        ndarray::concatenate(Axis(0), &views).expect("samples share one shape")
    }

    /// Forecast frames the recording covers.
    pub fn recorded_future(&self) -> usize {
        let canvas = self.forecast.samples[0].num_frames();
        self.truth.num_frames().min(canvas).saturating_sub(self.forecast.observed_frames)
    }
}

/// Forecasts every window (see [`Protocol::window_stride`]) of every scene with `model`.
/// Scenes (or persons) are used as they are: select persons before. Errors: a scene not longer
/// than `observe` frames, a skeleton or frame rate that differs from the model's.
pub fn forecast_scenes(model: &LoadedModel, scenes: &[Scene], proto: &Protocol, on_step: &mut dyn FnMut(StepInfo)) -> Result<Vec<SceneForecast>> {
    let mut out = Vec::new();
    // The one sampling route of the device (the forward-only twin of the network on the CPU).
    let net = crate::sample::SamplingNet::new(&model.denoiser, &model.diffusion, &proto.device.resolve()?).map_err(|e| e.in_file(&model.path))?;
    let denoising = Denoising::of(model, net.x0_model());
    let (observe, horizon) = (proto.request.observe, proto.request.horizon);
    for scene in scenes {
        crate::checkpoint::check_skeleton(&model.meta, &model.path, &scene.skeleton)?;
        if (scene.fps - model.fps).abs() > 1e-6 * model.fps {
            bail!("scene {} is at {} fps, the model {} at {} fps", scene.name, scene.fps, model.path.display(), model.fps);
        }
        let n = scene.num_frames();
        for start in proto.window_starts(n)? {
            let mut truth = scene.slice_frames(start, n)?;
            if proto.window_stride.is_some() {
                truth.name = format!("{}@{start}", scene.name);
            }
            let input = truth.slice_frames(0, (observe + horizon).min(truth.num_frames()))?;
            let task = Task::Forecast { observe, horizon };
            let forecast =
                sample_scene(&denoising, &input, &task, &proto.request, on_step).map_err(|e| crate::Error::invalid(format!("scene {}: {e}", scene.name)))?;
            out.push(SceneForecast { truth, forecast });
        }
    }
    if out.is_empty() {
        bail!("no scene is long enough for {observe} observed + {horizon} forecast frames");
    }
    Ok(out)
}

/// Error at one horizon (metres), averaged over the scenes whose recording reaches it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HorizonError {
    /// Seconds after the last observed frame.
    pub seconds: f64,
    /// Scenes that reach it.
    pub scenes: usize,
    /// Mean over samples.
    pub mean: Option<f64>,
    /// Best of K.
    pub best: Option<f64>,
    /// Zero-velocity baseline.
    pub zero_velocity: Option<f64>,
    /// Constant-velocity baseline.
    pub constant_velocity: Option<f64>,
}

/// Plausibility of the forecasts, with the recorded future's values where they exist.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Plausibility {
    /// Bone-length deviation from the observed bones, mm.
    pub bone_length_mm: f64,
    /// Horizontal speed of planted feet, m/s.
    pub foot_sliding: Option<f64>,
    /// The same for the recorded future.
    pub foot_sliding_truth: Option<f64>,
    /// Mean joint acceleration, m/s².
    pub acceleration: f64,
    /// The same for the recorded future.
    pub acceleration_truth: Option<f64>,
    /// JS distance of joint-speed histograms: forecasts vs the reference scenes.
    pub speed_js: Option<f64>,
}

/// NDMS summary.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NdmsSummary {
    /// Mean over every scored word of every sample, person and scene.
    pub mean: f64,
    /// Mean of word `f` over samples, persons and scenes (module docs).
    pub per_frame: Vec<f64>,
    /// Means over frame ranges `[a, b]` (inclusive).
    pub ranges: Vec<(usize, usize, f64)>,
    /// Words in the database.
    pub database_words: usize,
    /// Word length κ.
    pub word_length: usize,
}

impl NdmsSummary {
    /// Mean of the curve over entries `a..=b` (NaN entries skipped; NaN if none).
    pub fn range_mean(&self, a: usize, b: usize) -> f64 {
        let v: Vec<f64> = self.per_frame.iter().skip(a).take((b + 1).saturating_sub(a)).copied().filter(|v| !v.is_nan()).collect();
        if v.is_empty() {
            f64::NAN
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    }
}

/// A compact evaluation of forecasts of a test split (module docs).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct QuickReport {
    /// Forecast windows.
    pub scenes: usize,
    /// Samples per window.
    pub samples: usize,
    /// Persons per window (min, max).
    pub persons: (usize, usize),
    /// Observed frames.
    pub observe: usize,
    /// Forecast frames.
    pub horizon: usize,
    /// Frame rate.
    pub fps: f64,
    /// NDMS.
    pub ndms: NdmsSummary,
    /// MPJPE at 1, 2, 3 s.
    pub mpjpe: Vec<HorizonError>,
    /// Plausibility.
    pub plausibility: Plausibility,
    /// SSCP (JS distance) with annotated speech, when every scene has speech and roles.
    pub sscp: Option<f64>,
    /// Seconds per denoising step (mean over windows).
    pub seconds_per_step: f64,
    /// Seconds of sampling per window and sample.
    pub seconds_per_sample: f64,
}

fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// Standard NDMS frame ranges cut to a curve of `len` entries.
fn ndms_ranges(len: usize) -> Vec<(usize, usize)> {
    [(1, 30), (30, 120), (120, 500), (500, 1000), (1000, 1300), (1300, 1800)].into_iter().filter(|&(a, _)| a < len).map(|(a, b)| (a, b.min(len - 1))).collect()
}

/// Scores `runs` against the `reference` scenes (the NDMS database, with words of
/// `ndms.joints`) through the one evaluator, [`crate::eval::evaluate`]; see the module docs.
pub fn evaluate(runs: &[SceneForecast], reference: &[Scene], ndms: &NdmsConfig) -> Result<QuickReport> {
    use crate::eval::{Baseline, EvalConfig, Method, MethodKind, MethodScene, Metric, Reference, SignalSource};
    let Some(first) = runs.first() else { bail!("evaluate: no forecasts") };
    let fps = first.truth.fps;
    let observe = first.forecast.observed_frames;
    if let Some(x) = runs.iter().find(|x| x.forecast.observed_frames != observe) {
        bail!("evaluate: windows observe {observe} and {} frames ({})", x.forecast.observed_frames, x.truth.name);
    }
    // Scored split: the windows' recordings; NDMS database: the reference scenes.
    let sequences = runs
        .iter()
        .map(|x| Sequence { split: Split::Test, scene: x.truth.clone() })
        .chain(reference.iter().map(|s| Sequence { split: Split::Train, scene: s.clone() }))
        .collect();
    let windows = Dataset { name: "forecast windows".into(), sequences, metadata: Default::default() };
    let refset = Reference::new(Path::new("(recipe windows)"), windows, Split::Test)?;
    let method = |label: &str, kind: MethodKind, scenes: Vec<MethodScene>| Method {
        label: label.into(),
        kind,
        inputs: Vec::new(),
        settings: Default::default(),
        scenes,
    };
    let ours = method(
        "ours",
        MethodKind::Forecasts,
        runs.iter().map(|x| MethodScene { reference: x.truth.clone(), observed: observe, samples: x.forecast.samples.clone() }).collect(),
    );
    // The baselines and the recorded future, over each window's recorded frames.
    let mut methods = vec![ours];
    for b in [Baseline::ZeroVelocity, Baseline::ConstantVelocity, Baseline::GroundTruth] {
        methods.push(Method::baseline(b, &refset, observe, None, None)?);
    }
    let metrics = vec![Metric::Ndms, Metric::Mpjpe, Metric::BoneLength, Metric::FootSliding, Metric::Acceleration, Metric::SpeedJs];
    // One time bin over every forecast frame.
    let speed_histogram = SpeedHistogramConfig { time_bin_s: 1e9, ..Default::default() };
    let cfg = EvalConfig { metrics, ndms: ndms.clone(), ndms_database: Some(Split::Train), speed_histogram, ..Default::default() };
    let report = crate::eval::evaluate(&refset, &methods, &cfg, SignalSource::Annotations, &mut |_| {})?;
    let [ours, zero, constant, recorded] = [0, 1, 2, 3].map(|i| &report.methods[i]);

    // SSCP with the recorded speech: the forecasts' motion over the frames the recording covers.
    let with_speech = runs.iter().all(|x| x.truth.signals.contains_key(&SscpConfig::default().speaking_signal) && Triad::from_roles(&x.truth).is_ok());
    let sscp = if with_speech {
        let mut scenes = Vec::new();
        for x in runs.iter().filter(|x| x.recorded_future() > 0) {
            let end = observe + x.recorded_future();
            let truth = x.truth.slice_frames(0, end)?;
            let samples = x
                .forecast
                .samples
                .iter()
                .map(|s| {
                    let mut c = s.slice_frames(0, end)?;
                    c.signals = truth.signals.clone();
                    c.with_persons(truth.persons.clone())
                })
                .collect::<Result<Vec<_>>>()?;
            scenes.push(MethodScene { reference: truth, observed: observe, samples });
        }
        let cfg = EvalConfig { metrics: vec![Metric::Sscp], ..Default::default() };
        let r = crate::eval::evaluate(&refset, &[method("ours", MethodKind::Forecasts, scenes)], &cfg, SignalSource::Annotations, &mut |_| {})?;
        r.methods[0].sscp.as_ref().and_then(|s| s.value)
    } else {
        None
    };

    let nd = ours.ndms.as_ref().ok_or_else(|| crate::Error::invalid("evaluate: the evaluator returned no NDMS"))?;
    let db = &report.settings["ndms"];
    let mut ndms_summary = NdmsSummary {
        mean: nd.mean,
        per_frame: nd.per_frame.values.clone(),
        ranges: Vec::new(),
        database_words: db["database"]["words"].as_u64().unwrap_or(0) as usize,
        word_length: db["word_length"].as_u64().unwrap_or(0) as usize,
    };
    ndms_summary.ranges = ndms_ranges(ndms_summary.per_frame.len()).into_iter().map(|(a, b)| (a, b, ndms_summary.range_mean(a, b))).collect();
    let at = |m: &crate::eval::report::MethodReport, i: usize| m.mpjpe.as_ref().and_then(|p| p.horizons.get(i)).and_then(|h| h.global);
    let mpjpe = cfg
        .horizons_s
        .iter()
        .enumerate()
        .map(|(i, &h)| HorizonError {
            seconds: h,
            scenes: ours.mpjpe.as_ref().map_or(0, |p| p.horizons[i].scenes),
            mean: at(ours, i).map(|s| s.mean),
            best: at(ours, i).map(|s| s.best),
            zero_velocity: at(zero, i).map(|s| s.mean),
            constant_velocity: at(constant, i).map(|s| s.mean),
        })
        .collect();
    let (pl, rec) = (ours.plausibility.clone().unwrap_or_default(), recorded.plausibility.clone().unwrap_or_default());
    let timings = |key: fn(&Timings) -> f64, per_sample: bool| {
        let v: Vec<f64> = runs.iter().map(|x| key(&x.forecast.provenance.timings) / if per_sample { x.forecast.samples.len() as f64 } else { 1.0 }).collect();
        mean(&v).unwrap_or(f64::NAN)
    };
    let persons = runs.iter().map(|x| x.truth.num_persons());
    Ok(QuickReport {
        scenes: runs.len(),
        samples: first.forecast.samples.len(),
        persons: (persons.clone().min().unwrap_or(0), persons.max().unwrap_or(0)),
        observe,
        horizon: first.forecast.samples[0].num_frames() - observe,
        fps,
        ndms: ndms_summary,
        mpjpe,
        plausibility: Plausibility {
            bone_length_mm: pl.bone_length_mm.unwrap_or(f64::NAN),
            foot_sliding: pl.foot_sliding_m_s.flatten(),
            foot_sliding_truth: rec.foot_sliding_m_s.flatten(),
            acceleration: pl.acceleration_m_s2.unwrap_or(f64::NAN),
            acceleration_truth: rec.acceleration_m_s2,
            speed_js: pl.speed_js_mean,
        },
        sscp,
        seconds_per_step: timings(|t| t.seconds_per_step, false),
        seconds_per_sample: timings(|t| t.sampling_seconds, true),
    })
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("–".into(), |x| format!("{x:.digits$}"))
}

impl QuickReport {
    /// The report as JSON.
    pub fn to_json(&self) -> Value {
        serde_json::to_value(self).unwrap_or(Value::Null)
    }

    /// Writes `report.json` (the report, with `settings`) and `report.txt` ([`QuickReport::table`])
    /// to `dir`; returns the table.
    pub fn write_to(&self, dir: &Path, settings: Value) -> Result<String> {
        let mut json = self.to_json();
        json["settings"] = settings;
        crate::files::write_json_atomic(&dir.join("report.json"), &json)?;
        let table = self.table();
        crate::files::write_file_atomic(&dir.join("report.txt"), table.as_bytes())?;
        Ok(table)
    }

    /// A plain-text table of the report.
    pub fn table(&self) -> String {
        let mut t = String::new();
        let secs = |f: usize| f as f64 / self.fps;
        t += &format!(
            "{} forecast window(s) of {}–{} persons, {} samples each: {} observed frames ({:.1} s) → {} forecast frames ({:.1} s)\n",
            self.scenes,
            self.persons.0,
            self.persons.1,
            self.samples,
            self.observe,
            secs(self.observe),
            self.horizon,
            secs(self.horizon)
        );
        t += &format!("NDMS ↑ (exact NN over {} real words, κ = {}): mean {:.3}\n", self.ndms.database_words, self.ndms.word_length, self.ndms.mean);
        t += &format!("  frames {}\n", self.ndms.ranges.iter().map(|(a, b, v)| format!("{a}–{b}: {v:.3}")).collect::<Vec<_>>().join(", "));
        t += "MPJPE ↓ (m)       1 s     2 s     3 s\n";
        let row = |name: &str, f: &dyn Fn(&HorizonError) -> Option<f64>| {
            format!("  {name:<15}{}\n", self.mpjpe.iter().map(|h| format!("{:>8}", opt(f(h), 3))).collect::<String>())
        };
        t += &row("mean of K", &|h| h.mean);
        t += &row("best of K", &|h| h.best);
        t += &row("zero velocity", &|h| h.zero_velocity);
        t += &row("const velocity", &|h| h.constant_velocity);
        t += &format!("  (scenes reaching each horizon: {})\n", self.mpjpe.iter().map(|h| h.scenes.to_string()).collect::<Vec<_>>().join(" / "));
        let p = &self.plausibility;
        t += &format!(
            "Plausibility: bone-length deviation {:.1} mm, foot sliding {} m/s (recorded {}), acceleration {:.2} m/s² (recorded {}), speed-histogram JS {}\n",
            p.bone_length_mm,
            opt(p.foot_sliding, 3),
            opt(p.foot_sliding_truth, 3),
            p.acceleration,
            opt(p.acceleration_truth, 2),
            opt(p.speed_js, 3)
        );
        if let Some(v) = self.sscp {
            t += &format!("SSCP ↓ (JS distance, annotated speech): {v:.4}\n");
        }
        t += &format!("Sampling: {:.4} s per denoising step, {:.3} s per sample\n", self.seconds_per_step, self.seconds_per_sample);
        t
    }
}

/// Writes one viewer page holding the recorded future (where it exists) and every sample of
/// every window.
pub fn write_view(runs: &[SceneForecast], path: &Path, title: &str) -> Result<()> {
    let mut sequences = Vec::new();
    for x in runs {
        let fc = &x.forecast;
        if let Some(gt) = &fc.ground_truth {
            sequences.push(Sequence { split: Split::Test, scene: gt.clone() });
        }
        sequences.extend(fc.samples.iter().map(|s| Sequence { split: Split::Test, scene: s.clone() }));
    }
    let ds = Dataset { name: title.into(), sequences, metadata: Default::default() };
    let groups = group_scenes(&ds, None)?;
    write_html(path, &groups, &ViewOptions { title: Some(title.into()), ..Default::default() })?;
    Ok(())
}

/// How a driver trains, forecasts and reports: silently through the engine by default; the CLI
/// passes one with progress bars.
pub trait Runner {
    /// Trains as [`train`] does.
    fn train(&mut self, dataset: &Dataset, opts: &TrainOptions) -> Result<TrainSummary> {
        train(dataset, opts, &mut |_| {})
    }

    /// Forecasts as [`forecast_scenes`] does.
    fn forecast(&mut self, model: &LoadedModel, scenes: &[Scene], proto: &Protocol) -> Result<Vec<SceneForecast>> {
        forecast_scenes(model, scenes, proto, &mut |_| {})
    }

    /// Forecasts and scores as [`forecast_quality`] does.
    fn quality(&mut self, model: &LoadedModel, dataset: &Dataset, path: &Path, proto: &QualityProtocol) -> Result<QualityResult> {
        forecast_quality(model, dataset, path, proto, &mut |_| {})
    }

    /// A line about what happens next.
    fn say(&mut self, _line: &str) {}
}

/// The engine's own [`Runner`], without output.
pub struct Quiet;

impl Runner for Quiet {}

/// Settings of the leader/follower probe ([`leader_follower_probe`]).
#[derive(Clone, Debug, PartialEq)]
pub struct ProbeConfig {
    /// Episode shape.
    pub episode: LeaderFollower,
    /// Training episodes.
    pub train_episodes: usize,
    /// Test episodes.
    pub test_episodes: usize,
    /// Optimizer steps.
    pub steps: usize,
    /// Windows per batch.
    pub batch: usize,
    /// Learning rate.
    pub lr: f64,
    /// DDIM steps of the probe's forecasts.
    pub ddim_steps: usize,
}

impl Default for ProbeConfig {
    fn default() -> Self {
        Self { episode: LeaderFollower::default(), train_episodes: 512, test_episodes: 16, steps: 400, batch: 16, lr: 2e-3, ddim_steps: 20 }
    }
}

/// The social-channel probe: trains a model with the network config `model` (its
/// `feature_dims` is set from `skeleton`) and `seed` on leader/follower episodes made from `pose` (one
/// pose of `skeleton`, [`leader_follower_scene`]) in `run_dir`, forecasts the test episodes
/// (DDIM, η = 0, one sample each) and returns the mean ground distance (m) between the
/// follower's forecast and recorded root over the forecast frames. A model that uses the
/// other persons (`mean`, `attention`) gets it far lower than `none`.
pub fn leader_follower_probe(
    skeleton: &Skeleton,
    pose: &[f32],
    fps: f64,
    model: &DenoiserConfig,
    seed: u64,
    probe: &ProbeConfig,
    run_dir: &Path,
) -> Result<f64> {
    let ep = &probe.episode;
    // The follower stands 10 % lower, so each person can tell its role from its own pose.
    let lower: Vec<f32> = pose.chunks(3).flat_map(|q| [q[0], q[1], 0.9 * q[2]]).collect();
    let episode = |name: String, s: u64| leader_follower_scene(skeleton, [pose, &lower], fps, ep, &name, s);
    let mut sequences = Vec::new();
    for i in 0..probe.train_episodes {
        sequences.push(Sequence { split: Split::Train, scene: episode(format!("train{i}"), 100 + i as u64)? });
    }
    let test: Vec<Scene> = (0..probe.test_episodes).map(|i| episode(format!("test{i}"), 900_000 + i as u64)).collect::<Result<_>>()?;
    let ds = Dataset { name: "leader-follower".into(), sequences, metadata: Default::default() };
    let config = TrainConfig {
        model: model.clone(),
        steps: probe.steps,
        batch: probe.batch,
        window: ep.frames,
        stride: ep.frames,
        observed: Some(ep.observed),
        seed,
        adam: AdamConfig { lr: probe.lr, ..Default::default() },
        ema: EmaConfig { warmup_steps: probe.steps, ..Default::default() },
        save_every: probe.steps,
        val_every: 0,
        ..Default::default()
    };
    if !Checkpoint::exists_in(run_dir) || Checkpoint::read_meta(run_dir)?.step < probe.steps as u64 {
        let opts = TrainOptions {
            out_dir: run_dir.to_path_buf(),
            resume: Checkpoint::exists_in(run_dir),
            config: Some(config),
            source: "leader/follower probe".into(),
            force: false,
            ..Default::default()
        };
        train(&ds, &opts, &mut |_: &TrainEvent| {})?;
    }
    let m = Checkpoint::load(run_dir)?;
    let proto = Protocol {
        request: Forecast {
            observe: ep.observed,
            horizon: ep.frames - ep.observed,
            samples: 1,
            sampler: SamplerKind::Ddim { steps: probe.ddim_steps, eta: 0.0 },
            seed,
            ..Default::default()
        },
        window_stride: None,
        device: Default::default(),
    };
    let runs = forecast_scenes(&m, &test, &proto, &mut |_| {})?;
    let (mut sum, mut n) = (0.0, 0usize);
    for x in &runs {
        let smp = &x.forecast.samples[0];
        for f in ep.observed..ep.frames {
            // The root of a forecast pose even if its hips collapsed.
            let root = |sc: &Scene| {
                let pose: Vec<f32> = sc.positions.slice(s![f, 1, .., ..]).iter().copied().collect();
                ground_midpoint(&pose, sc.skeleton.left, sc.skeleton.right)
            };
            let (a, b) = (root(smp), root(&x.truth));
            sum += (a[0] - b[0]).hypot(a[1] - b[1]);
            n += 1;
        }
    }
    Ok(sum / n.max(1) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::test_util::walkers;
    use crate::forecast::Provenance;

    /// A "forecast" whose samples are the recording itself and the recording shifted by `shift` m
    /// along x.
    fn perfect(scene: &Scene, observe: usize, shift: f32) -> SceneForecast {
        let mut samples = Vec::new();
        for (k, d) in [0.0, shift].into_iter().enumerate() {
            let mut s = scene.clone();
            s.name = format!("{}_s{k:02}", scene.name);
            s.positions.slice_mut(s![.., .., .., 0]).mapv_inplace(|v| v + d);
            crate::export::ForecastInfo { observed_frames: observe, sample: Some(k), source: scene.name.clone() }.insert_into(&mut s.metadata);
            samples.push(s);
        }
        let timings = Timings { seconds_per_step: 0.5, sampling_seconds: 4.0, ..Default::default() };
        let provenance = Provenance { timings, ..Provenance::of(&scene.name, Task::Forecast { observe, horizon: scene.num_frames() - observe }) };
        let mut gt = scene.clone();
        crate::export::ForecastInfo { observed_frames: observe, sample: None, source: scene.name.clone() }.insert_into(&mut gt.metadata);
        let forecast = ForecastOutput {
            source: scene.name.clone(),
            input: scene.slice_frames(0, observe).unwrap(),
            samples,
            ground_truth: Some(gt),
            observed_frames: observe,
            provenance,
        };
        SceneForecast { truth: scene.clone(), forecast }
    }

    #[test]
    fn a_forecast_equal_to_the_recording_scores_perfectly() {
        let scene = walkers(150, 3, 0.4);
        let x = perfect(&scene, 30, 0.1);
        assert_eq!(x.recorded_future(), 120);
        let rep = evaluate(std::slice::from_ref(&x), std::slice::from_ref(&scene), &NdmsConfig::default()).unwrap();
        assert_eq!((rep.scenes, rep.samples, rep.persons, rep.observe, rep.horizon), (1, 2, (3, 3), 30, 120));
        // Sample 0 is the recording: MPJPE 0 (best of K), sample 1 is 0.1 m off everywhere.
        for h in &rep.mpjpe[..3] {
            assert_eq!(h.scenes, 1);
            assert!(h.best.unwrap().abs() < 1e-9 && (h.mean.unwrap() - 0.05).abs() < 1e-6, "{h:?}");
            assert!(h.zero_velocity.unwrap() > 0.01, "walkers move");
        }
        assert!(rep.mpjpe[2].seconds == 3.0);
        // Every word of sample 0 has itself in the database (ψ = 1); sample 1 is the same motion
        // shifted, and words are translation-invariant: NDMS 1 on every word.
        assert!((rep.ndms.mean - 1.0).abs() < 1e-6, "{}", rep.ndms.mean);
        assert_eq!(rep.ndms.per_frame.len(), 120 + 1);
        assert_eq!(rep.ndms.ranges[0], (1, 30, rep.ndms.range_mean(1, 30)));
        assert!(rep.plausibility.bone_length_mm < 1e-3, "{:?}", rep.plausibility);
        assert!((rep.plausibility.acceleration_truth.unwrap() - rep.plausibility.acceleration).abs() < 1e-6);
        assert_eq!(rep.sscp, None, "no speech");
        assert_eq!((rep.seconds_per_step, rep.seconds_per_sample), (0.5, 2.0));
        assert!(rep.table().contains("NDMS") && rep.to_json()["ndms"]["mean"].as_f64().is_some());
        let dir = std::env::temp_dir().join(format!("socdiff-recipes-view-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        write_view(&[x], &dir.join("v.html"), "perfect").unwrap();
        let decoded = crate::export::html::read_view_data(&std::fs::read_to_string(dir.join("v.html")).unwrap()).unwrap();
        assert_eq!(decoded[0].samples.len(), 3, "ground truth + 2 samples");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

// ---------------------------------------------------------------------------------------------
// Forecasting quality (`socdiff bench quality`): windows of the test split, forecast by the
// model, scored with the baselines through the one evaluator.
// ---------------------------------------------------------------------------------------------

/// The protocol of [`forecast_quality`]: at the data's frame rate (30 fps for MuPoTS), `observe`
/// frames observed (1 s), `horizon` forecast (3 s), K samples, windows every `stride` frames of
/// each test scene (the first at frame 0).
#[derive(Clone, Debug, PartialEq)]
pub struct QualityProtocol {
    /// Observed frames.
    pub observe: usize,
    /// Forecast frames.
    pub horizon: usize,
    /// Samples K.
    pub samples: usize,
    /// DDIM steps (η = 0).
    pub ddim_steps: usize,
    /// Frames between window starts.
    pub stride: usize,
    /// Sampling seed.
    pub seed: u64,
    /// Where the network samples.
    pub device: crate::model::DeviceChoice,
}

impl Default for QualityProtocol {
    fn default() -> Self {
        Self { observe: 30, horizon: 90, samples: 8, ddim_steps: 50, stride: 15, seed: 1, device: Default::default() }
    }
}

/// The largest joint move from the last observed frame to the first forecast frame (over the
/// samples) against the largest frame-to-frame move of the observed frames, metres.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FirstFrameJump {
    /// Window `scene@start`.
    pub window: String,
    /// Largest first-frame move of any sample.
    pub jump: f64,
    /// Largest observed move.
    pub observed: f64,
}

/// MRT's protocol (Wang et al., NeurIPS 2021, as their `test.py` computes it) on the same
/// windows: frames taken every other frame (30 → 15 fps), 15 observed and 45 predicted, 15 of
/// the MuPoTS-17 joints ([`crate::data::Skeleton::mrt15`]), and "1/2/3 s" = the mean joint error over the first
/// 15/30/45 predicted frames (not the error at that frame), global coordinates, averaged over
/// persons, then windows. Metres (MRT's units: [`mrt::MRT_UNITS_PER_MM`]). `socdiff bench mrt`
/// ([`mrt`]) is the protocol itself, on MRT's windows.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MrtRow {
    /// Method label.
    pub method: String,
    /// 1/2/3 s, mean over the K samples.
    pub mean: [f64; 3],
    /// 1/2/3 s, best of the K samples (per window).
    pub best: [f64; 3],
}

/// MRT's metric for one method (see [`MrtRow`]): `observe` frames of 30 fps observed, the
/// predicted frames `observe, observe + 2, …` scored. `None` when a joint is missing.
fn mrt_row(method: &crate::eval::Method, observe: usize) -> Option<MrtRow> {
    let sk = &method.scenes.first()?.reference.skeleton;
    let joints: Vec<usize> = crate::data::Skeleton::mrt15().joints.iter().map(|n| sk.joint_index(n)).collect::<Option<_>>()?;
    let (mut mean, mut best, mut n) = ([0f64; 3], [0f64; 3], 0usize);
    for ms in &method.scenes {
        let truth = &ms.reference.positions;
        // Per sample: the mean error over the first 15/30/45 predicted frames at 15 fps.
        let per_sample: Vec<[f64; 3]> = ms
            .samples
            .iter()
            .map(|s| {
                let mut acc = [0f64; 3];
                let mut sum = 0f64;
                for k in 0..45 {
                    let f = observe + 2 * k;
                    let mut e = 0f64;
                    for p in 0..s.num_persons() {
                        for &j in &joints {
                            let d: f64 = (0..3).map(|c| (s.positions[[f, p, j, c]] - truth[[f, p, j, c]]) as f64).map(|v| v * v).sum();
                            e += d.sqrt();
                        }
                    }
                    sum += e / (s.num_persons() * joints.len()) as f64;
                    for (h, frames) in [15, 30, 45].into_iter().enumerate() {
                        if k + 1 == frames {
                            acc[h] = sum / frames as f64;
                        }
                    }
                }
                acc
            })
            .collect();
        for h in 0..3 {
            mean[h] += per_sample.iter().map(|a| a[h]).sum::<f64>() / per_sample.len() as f64;
            best[h] += per_sample.iter().map(|a| a[h]).fold(f64::INFINITY, f64::min);
        }
        n += 1;
    }
    (n > 0).then(|| MrtRow { method: method.label.clone(), mean: mean.map(|v| v / n as f64), best: best.map(|v| v / n as f64) })
}

/// What [`forecast_quality`] measured.
pub struct QualityResult {
    /// The evaluator's report: the model (`ours`) and the baselines zero velocity, constant
    /// velocity and nearest continuation (from the train split), MPJPE at 1/2/3 s and NDMS.
    pub report: crate::eval::Report,
    /// One entry per window.
    pub jumps: Vec<FirstFrameJump>,
    /// MRT's protocol on the same windows and methods (needs `observe` ≥ 29 and `horizon` ≥ 90
    /// frames at 30 fps and MRT's 15 joints; empty otherwise).
    pub mrt: Vec<MrtRow>,
    /// Windows scored.
    pub windows: usize,
}

impl QualityResult {
    /// Windows whose first forecast frame moves no more than their largest observed move, and
    /// the worst ratio of the two.
    pub fn jump_summary(&self) -> (usize, f64) {
        let worst = self.jumps.iter().map(|j| j.jump / j.observed.max(1e-9)).fold(0.0, f64::max);
        (self.jumps.iter().filter(|j| j.jump <= j.observed).count(), worst)
    }

    /// Every number keyed by protocol (`ours`, `mrt`), method and horizon, with the protocol's
    /// settings and the model's training (`quality.json` of `socdiff bench quality`).
    pub fn to_json(&self, model: &LoadedModel, proto: &QualityProtocol) -> serde_json::Value {
        use serde_json::json;
        let mut methods = serde_json::Map::new();
        for m in &self.report.methods {
            let mut by = serde_json::Map::new();
            if let Some(mp) = &m.mpjpe {
                for h in &mp.horizons {
                    by.insert(format!("{}s", h.horizon_s), json!({"global": h.global, "root": h.root, "root_aligned": h.root_aligned}));
                }
            }
            methods.insert(m.label.clone(), json!({"mpjpe_m": by, "ndms": m.ndms.as_ref().map(|n| n.mean)}));
        }
        let (within, worst) = self.jump_summary();
        let mrt: serde_json::Map<String, serde_json::Value> = self
            .mrt
            .iter()
            .map(|r| {
                let by = |v: &[f64; 3]| json!({"1s": v[0], "2s": v[1], "3s": v[2]});
                (r.method.clone(), json!({"mean": by(&r.mean), "best": by(&r.best)}))
            })
            .collect();
        json!({
            "protocol": {
                "ours": {"fps": model.fps, "observe": proto.observe, "horizon": proto.horizon, "samples": proto.samples,
                    "ddim_steps": proto.ddim_steps, "window_stride": proto.stride, "windows": self.windows, "seed": proto.seed,
                    "methods": methods, "first_frame_jump": {"windows_within_observed": within, "worst_ratio": worst, "per_window": self.jumps}},
                "mrt": {"fps": 15, "observe": 15, "predict": 45, "joints": crate::data::Skeleton::mrt15().joints, "windows": self.windows,
                    "metric": "mean joint error (m) over the first 15/30/45 predicted frames, keyed 1s/2s/3s", "methods": mrt},
            },
            "training": {"trained_seconds": model.meta.elapsed_seconds, "step": model.step, "config": model.config},
        })
    }

    /// MRT's protocol as a text table (mm, mean of K / best of K).
    pub fn mrt_table(&self) -> String {
        let mut t =
            String::from("MRT's protocol (15 fps, 15 observed / 45 predicted, 15 joints; mean error over the first 1/2/3 s, mm; mean of K / best of K):\n");
        for r in &self.mrt {
            let mm = |v: f64| v * 1e3;
            t += &format!(
                "  {:18} {:>5.0} {:>5.0} {:>5.0}   {:>5.0} {:>5.0} {:>5.0}\n",
                r.method,
                mm(r.mean[0]),
                mm(r.mean[1]),
                mm(r.mean[2]),
                mm(r.best[0]),
                mm(r.best[1]),
                mm(r.best[2])
            );
        }
        t
    }
}

/// Forecasts windows of the test split of `dataset` with `model` as `proto` says, and scores
/// them with the baselines through [`crate::eval::evaluate`].
pub fn forecast_quality(
    model: &LoadedModel,
    dataset: &Dataset,
    path: &Path,
    proto: &QualityProtocol,
    on_step: &mut dyn FnMut(StepInfo),
) -> Result<QualityResult> {
    use crate::eval::{Baseline, EvalConfig, Method, MethodKind, MethodScene, Metric, Reference, SignalSource};
    let len = proto.observe + proto.horizon;
    let mut windows = Vec::new();
    for s in dataset.split(Split::Test) {
        let mut start = 0;
        while start + len <= s.num_frames() {
            let mut w = s.slice_frames(start, start + len)?;
            w.name = format!("{}@{start}", s.name);
            windows.push(w);
            start += proto.stride.max(1);
        }
    }
    if windows.is_empty() {
        bail!("dataset {}: no test sequence has {len} frames ({} observed + {} forecast)", dataset.name, proto.observe, proto.horizon);
    }
    let train: Vec<Scene> = dataset.split(Split::Train).cloned().collect();
    let sequences = windows
        .iter()
        .map(|w| Sequence { split: Split::Test, scene: w.clone() })
        .chain(train.iter().map(|s| Sequence { split: Split::Train, scene: s.clone() }))
        .collect();
    let reference = Reference::new(path, Dataset { name: format!("{} (windows)", dataset.name), sequences, metadata: Default::default() }, Split::Test)?;
    let fc = Protocol { device: proto.device, ..Protocol::ddim(proto.observe, proto.horizon, proto.samples, proto.ddim_steps, proto.seed) };
    let runs = forecast_scenes(model, &windows, &fc, on_step)?;
    let jumps = runs
        .iter()
        .map(|r| FirstFrameJump {
            window: r.truth.name.clone(),
            jump: r
                .forecast
                .samples
                .iter()
                .map(|s| crate::metrics::distance::largest_joint_move(s.positions.view(), proto.observe - 1, proto.observe))
                .fold(0.0, f64::max),
            observed: crate::metrics::distance::largest_frame_step(r.truth.positions.slice(ndarray::s![..proto.observe, .., .., ..])),
        })
        .collect();
    let mut settings = serde_json::Map::new();
    settings.insert("model".into(), model.path.display().to_string().into());
    settings.insert("model_step".into(), model.step.into());
    settings.insert("noise".into(), serde_json::to_value(model.config.noise).unwrap_or_default());
    settings.insert("pose".into(), serde_json::to_value(model.config.pose).unwrap_or_default());
    let ours = Method {
        label: "ours".into(),
        kind: MethodKind::Forecasts,
        inputs: Vec::new(),
        settings,
        scenes: runs.iter().map(|r| MethodScene { reference: r.truth.clone(), observed: proto.observe, samples: r.forecast.samples.clone() }).collect(),
    };
    let refs: Vec<&Scene> = train.iter().collect();
    let db = NdmsDatabase::build(&refs, &NdmsConfig::default())?;
    let mut methods = vec![ours];
    for b in [Baseline::ZeroVelocity, Baseline::ConstantVelocity, Baseline::NearestContinuation] {
        methods.push(Method::baseline(b, &reference, proto.observe, Some(proto.horizon), Some(&db))?);
    }
    let cfg = EvalConfig { metrics: vec![Metric::Mpjpe, Metric::Ndms], ..Default::default() };
    let report = crate::eval::evaluate(&reference, &methods, &cfg, SignalSource::Annotations, &mut |_| {})?;
    let mrt =
        if proto.horizon >= 89 && (model.fps - 30.0).abs() < 1e-6 { methods.iter().filter_map(|m| mrt_row(m, proto.observe)).collect() } else { Vec::new() };
    Ok(QualityResult { report, jumps, windows: windows.len(), mrt })
}
