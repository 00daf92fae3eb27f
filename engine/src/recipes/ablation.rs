//! The paper's ablation tables, reproducibly (`socdiff ablate`).
//!
//! - [`Study::Aggregators`] (Table 7.4): one model per aggregator, same data, seed and
//!   settings; each forecasts the test split and is scored by the one evaluator (NDMS, SSCP
//!   when the scenes carry speech and roles, MPJPE at 1/2/3 s), and trains once more on
//!   leader/follower episodes (the social-channel probe: the follower's root error).
//! - [`Study::Samplers`] (Table 7.7): trained models, several samplers and step counts, same
//!   scenes and seeds.
//!
//! Everything goes to [`Ablation::out`]: one run directory per aggregator (an interrupted
//! ablation continues where it stopped when run again), `report_<name>/report.json` per row,
//! `table.md` and `results.json` with the command, seeds and settings.

use super::{evaluate, leader_follower_probe, ProbeConfig, Protocol, QuickReport, Runner};
use crate::checkpoint::Checkpoint;
use crate::files::{check_output_dir, write_file_atomic, RunLock};
use crate::forecast::{Forecast, SamplerKind};
use crate::metrics::ndms::NdmsConfig;
use crate::model::{Aggregator, DeviceChoice};
use crate::train::{TrainConfig, TrainOptions};
use crate::{bail, Dataset, Error, Result, Scene, Split};
use serde_json::{json, Value};
use std::path::PathBuf;
use std::time::Instant;

/// Which ablation.
#[derive(Clone, Debug)]
pub enum Study {
    /// One model per aggregator, trained with `training` (its `model.aggregator` replaced).
    Aggregators {
        /// Aggregators, one row each.
        aggregators: Vec<Aggregator>,
        /// Everything else of the training runs.
        training: Box<TrainConfig>,
        /// DDIM steps (η = 0) of the forecasts.
        sampling_steps: usize,
        /// Training steps of the leader/follower probe per aggregator (0: no probe).
        probe_steps: usize,
    },
    /// Trained models (run directories or checkpoints) × samplers, one row each.
    Samplers {
        /// The models.
        models: Vec<PathBuf>,
        /// Samplers by name ([`SamplerKind::parse`]).
        samplers: Vec<SamplerKind>,
    },
}

/// An ablation: the study, the forecasts it scores, and where it goes.
#[derive(Clone, Debug)]
pub struct Ablation {
    /// Which ablation.
    pub study: Study,
    /// Output folder: new, empty, or an earlier ablation's (continued).
    pub out: PathBuf,
    /// Where the data came from (for the table and the run directories).
    pub data: String,
    /// The command line that made it (recorded).
    pub command: String,
    /// Observed frames of each forecast.
    pub observe: usize,
    /// Forecast frames.
    pub horizon: usize,
    /// Samples per forecast.
    pub samples: usize,
    /// A forecast window every this many frames of each test scene (0: one per scene).
    pub window_stride: usize,
    /// Seed of training and sampling.
    pub seed: u64,
    /// Motion words of NDMS.
    pub ndms: NdmsConfig,
    /// Where models train and sample.
    pub device: DeviceChoice,
}

/// One row of an ablation table.
#[derive(Clone, Debug)]
pub struct AblationRow {
    /// Row label (aggregator, or model and sampler).
    pub name: String,
    /// Its scores.
    pub report: QuickReport,
    /// Further columns: header and cell.
    pub extra: Vec<(String, String)>,
    /// Its entry of `results.json`.
    pub json: Value,
}

/// What [`run_ablation`] wrote.
#[derive(Clone, Debug)]
pub struct AblationTable {
    /// The rows, in order.
    pub rows: Vec<AblationRow>,
    /// `table.md`.
    pub markdown: String,
    /// The written `table.md`.
    pub path: PathBuf,
}

/// File marking a folder as an ablation's output.
const MARKER: &str = ".socdiff-ablate";

/// Runs `ablation` on `dataset` (train split for training, test split for forecasts), writing
/// every run, report and the table under `ablation.out`.
pub fn run_ablation(dataset: &Dataset, ablation: &Ablation, runner: &mut dyn Runner) -> Result<AblationTable> {
    let a = ablation;
    // A device that cannot run is an error before anything is written.
    a.device.resolve()?;
    let test: Vec<Scene> = dataset.split(Split::Test).cloned().collect();
    if test.is_empty() || dataset.split(Split::Train).next().is_none() {
        bail!("dataset {} ({}): an ablation needs train and test sequences", dataset.name, a.data);
    }
    match &a.study {
        Study::Aggregators { aggregators, .. } if aggregators.is_empty() => bail!("`aggregators`: give at least one"),
        Study::Samplers { models, samplers } if models.is_empty() || samplers.is_empty() => bail!("`model` and `samplers`: give at least one of each"),
        _ => {}
    }
    // Into a new or empty folder, or an earlier ablation's (which it continues), never another.
    let out = &a.out;
    if !out.join(MARKER).is_file() {
        check_output_dir(out)?;
    }
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let _lock = RunLock::acquire(out)?;
    write_file_atomic(&out.join(MARKER), b"socdiff ablate output\n")?;
    let proto = |sampler: SamplerKind| Protocol {
        request: Forecast { observe: a.observe, horizon: a.horizon, samples: a.samples, sampler, seed: a.seed, ..Default::default() },
        window_stride: (a.window_stride > 0).then_some(a.window_stride),
        device: a.device,
    };
    // With a window stride, scenes shorter than a window give none (forecast_scenes skips them).
    let usable: Vec<Scene> = test.iter().filter(|s| s.num_frames() > a.observe).cloned().collect();
    let mut settings = json!({
        "command": a.command, "data": a.data, "seed": a.seed,
        "forecast": {"observe": a.observe, "horizon": a.horizon, "samples": a.samples, "window_stride": a.window_stride},
    });
    let report_dir = |name: &str| -> Result<PathBuf> {
        let dir = out.join(format!("report_{}", name.replace(' ', "_")));
        std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        Ok(dir)
    };
    let mut rows = Vec::new();
    match &a.study {
        Study::Aggregators { aggregators, training, sampling_steps, probe_steps } => {
            let ddim = SamplerKind::Ddim { steps: *sampling_steps, eta: 0.0 };
            let t = training;
            settings["train"] = json!({"steps": t.steps, "hidden": t.model.hidden, "window": t.window, "stride": t.stride, "batch": t.batch, "lr": t.adam.lr});
            settings["sampler"] = serde_json::to_value(ddim).unwrap_or(Value::Null);
            settings["probe"] = json!({"steps": probe_steps, "episodes": ProbeConfig::default().train_episodes});
            let pose: Vec<f32> = {
                let s = dataset.split(Split::Train).next().expect("checked");
                // Person 0 at frame 0: [frames, joints, 3] in standard order starts with it.
                s.person(0).iter().take(3 * s.num_joints()).copied().collect()
            };
            for &aggregator in aggregators {
                let agg = aggregator.name();
                let mut config = TrainConfig::clone(training);
                config.model.aggregator = aggregator;
                let dir = out.join(agg);
                runner.say(&format!("== {agg}: training {} steps → {}", config.steps, dir.display()));
                let t0 = Instant::now();
                let opts = TrainOptions {
                    out_dir: dir.clone(),
                    resume: Checkpoint::exists_in(&dir),
                    config: Some(config.clone()),
                    source: a.data.clone(),
                    device: a.device,
                    ..Default::default()
                };
                runner.train(dataset, &opts)?;
                let train_secs = t0.elapsed().as_secs_f64();
                let m = Checkpoint::load(&dir)?;
                let runs = runner.forecast(&m, &usable, &proto(ddim))?;
                let report = evaluate(&runs, &test, &a.ndms)?;
                let mut extra = Vec::new();
                let mut probe_err = None;
                if *probe_steps > 0 {
                    let probe = ProbeConfig { steps: *probe_steps, ..Default::default() };
                    runner.say(&format!("== {agg}: leader/follower probe ({probe_steps} steps)"));
                    let e = leader_follower_probe(&m.skeleton, &pose, m.fps, &config.model, a.seed, &probe, &out.join(format!("probe_{agg}")))?;
                    probe_err = Some(e);
                    extra.push(("follower error (m) ↓".to_string(), cell(e, 3)));
                }
                let mut s = settings.clone();
                s["aggregator"] = serde_json::to_value(aggregator).unwrap_or(Value::Null);
                report.write_to(&report_dir(agg)?, s)?;
                let json =
                    json!({"aggregator": agg, "train_seconds": train_secs, "model_step": m.step, "follower_error_m": probe_err, "report": report.to_json()});
                rows.push(AblationRow { name: agg.to_string(), report, extra, json });
            }
        }
        Study::Samplers { models, samplers } => {
            let mut recorded = Vec::new();
            for path in models {
                let m = Checkpoint::load(path)?;
                recorded.push(json!({"path": m.path.display().to_string(), "step": m.step, "config": serde_json::to_value(&m.config).unwrap_or(Value::Null)}));
                let label = path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
                for kind in samplers {
                    let name = kind.name();
                    let row = if models.len() > 1 { format!("{label} {name}") } else { name.clone() };
                    runner.say(&format!("== {row}"));
                    let runs = runner.forecast(&m, &usable, &proto(*kind))?;
                    let report = evaluate(&runs, &test, &a.ndms)?;
                    let mut s = settings.clone();
                    s["model"] = recorded.last().cloned().unwrap_or(Value::Null);
                    report.write_to(&report_dir(&row)?, s)?;
                    let json = json!({"model": path.display().to_string(), "model_step": m.step, "sampler": name, "report": report.to_json()});
                    rows.push(AblationRow { name: row, report, extra: Vec::new(), json });
                }
            }
            settings["models"] = Value::Array(recorded);
            if samplers.len() > 1 {
                // Relative NDMS against the first sampler (DDPM when listed first), per model.
                for chunk in rows.chunks_mut(samplers.len()) {
                    let base = chunk[0].report.ndms.mean;
                    for r in chunk.iter_mut() {
                        let rel = 100.0 * (r.report.ndms.mean - base) / base;
                        r.extra.push((format!("NDMS vs {}", samplers[0].name()), format!("{rel:+.1} %")));
                    }
                }
            }
            for r in &mut rows {
                r.extra.push(("s per sample".into(), cell(r.report.seconds_per_sample, 2)));
            }
        }
    }
    let markdown = table(&rows, ablation, usable.len());
    let path = out.join("table.md");
    write_file_atomic(&path, markdown.as_bytes())?;
    let results = json!({"settings": settings, "rows": rows.iter().map(|r| r.json.clone()).collect::<Vec<_>>()});
    crate::files::write_json_atomic(&out.join("results.json"), &results)?;
    Ok(AblationTable { rows, markdown, path })
}

/// A number with `digits` decimals, or a dash when it is not finite.
fn cell(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "–".into()
    }
}

/// `table.md`: one line per row, then what was forecast and the command.
fn table(rows: &[AblationRow], a: &Ablation, sequences: usize) -> String {
    let with_sscp = rows.iter().any(|r| r.report.sscp.is_some());
    let mut head = vec!["", "NDMS ↑", "NDMS 30–120", "NDMS last"];
    if with_sscp {
        head.push("SSCP ↓");
    }
    head.extend(["MPJPE 1 s", "2 s", "3 s", "best-of-K 3 s", "bone dev. mm", "foot slide m/s", "speed JS"]);
    let mut head: Vec<String> = head.into_iter().map(String::from).collect();
    head.extend(rows.first().map(|r| r.extra.iter().map(|e| e.0.clone()).collect::<Vec<_>>()).unwrap_or_default());
    let mut md = format!("| {} |\n", head.join(" | "));
    md += &format!("|{}\n", "---|".repeat(head.len()));
    let or_dash = |v: Option<f64>, d: usize| v.map_or("–".into(), |v| cell(v, d));
    for r in rows {
        let rep = &r.report;
        let last = rep.ndms.ranges.last().map_or(f64::NAN, |x| x.2);
        let mut cells = vec![r.name.clone(), cell(rep.ndms.mean, 4), cell(rep.ndms.range_mean(30, 120), 4), cell(last, 4)];
        if with_sscp {
            cells.push(or_dash(rep.sscp, 4));
        }
        cells.extend(rep.mpjpe.iter().map(|h| or_dash(h.mean, 3)));
        cells.push(or_dash(rep.mpjpe[2].best, 3));
        let p = &rep.plausibility;
        cells.extend([cell(p.bone_length_mm, 1), or_dash(p.foot_sliding, 3), or_dash(p.speed_js, 3)]);
        cells.extend(r.extra.iter().map(|e| e.1.clone()));
        md += &format!("| {} |\n", cells.join(" | "));
    }
    let r0 = &rows[0].report;
    let last = r0.ndms.ranges.last().map_or((0, 0), |x| (x.0, x.1));
    md += &format!(
        "\n{} forecast windows ({}–{} persons) from {sequences} test sequences of {}: {} observed + {} forecast frames, {} samples each; \"NDMS last\" = frames {}–{}. MPJPE in metres (mean of K). Seed {}.\n\nCommand: `{}`\n",
        r0.scenes, r0.persons.0, r0.persons.1, a.data, r0.observe, r0.horizon, r0.samples, last.0, last.1, a.seed, a.command
    );
    md
}
