//! `socdiff ablate`: the paper's ablation tables, reproducibly.
//!
//! - `--aggregators none,mean,attention` (Table 7.4): one model per aggregator, same data, seed
//!   and settings; each forecasts the test split and is scored (NDMS, SSCP when the scenes carry
//!   speech and roles, MPJPE at 1/2/3 s), and trains once more on leader/follower episodes (the
//!   social-channel probe: the follower's root error, `socdiff_engine::recipes`).
//! - `--model RUN --samplers ddpm,ddim200,…` (Table 7.7): one model, several samplers and step
//!   counts, same scenes and seeds.
//!
//! Everything goes to `--out`: one run directory per aggregator (an interrupted ablation
//! continues where it stopped when run again), `report_<name>/report.json` per row, `table.md` and
//! `results.json` with the exact command, seeds and settings.

use crate::demo_cmd::{forecast_with_progress, write_report};
use crate::train_cmd::train_with_progress;
use clap::Args;
use serde_json::{json, Value};
use socdiff_engine::data::import;
use socdiff_engine::export::write_file_atomic;
use socdiff_engine::forecast::{ForecastOptions, SamplerKind};
use socdiff_engine::recipes::{evaluate, leader_follower_probe, ProbeConfig, Protocol, QuickReport};
use socdiff_engine::train::checkpoint::Checkpoint;
use socdiff_engine::train::TrainOptions;
use socdiff_engine::{Error, Result, Scene, Split};
use std::path::PathBuf;
use std::time::Instant;

/// Options of `socdiff ablate`.
#[derive(Args)]
pub struct AblateArgs {
    #[command(flatten)]
    align: crate::data_cmd::AlignArgs,
    #[command(flatten)]
    device: crate::DeviceArg,
    /// Dataset: models train on its train split and forecast its test split.
    #[arg(long)]
    data: PathBuf,
    /// Output folder (run directories, reports, table.md, results.json).
    #[arg(long)]
    out: PathBuf,
    /// Aggregator ablation: train one model per aggregator (none, mean, attention).
    #[arg(long, value_delimiter = ',', conflicts_with_all = ["model", "samplers"])]
    aggregators: Vec<String>,
    /// Sampler ablation: the trained model (run directory or checkpoint) to sample with;
    /// repeat to compare models (one row per model and sampler).
    #[arg(long, requires = "samplers")]
    model: Vec<PathBuf>,
    /// Sampler ablation: samplers to compare, e.g. ddpm,ddim200,ddim100,ddim50,ddim20,ddim10.
    #[arg(long, value_delimiter = ',', requires = "model")]
    samplers: Vec<String>,
    /// Training steps per model.
    #[arg(long, default_value_t = 2000)]
    steps: usize,
    /// U-Net width (and social width).
    #[arg(long, default_value_t = 64)]
    hidden: usize,
    /// Frames per training window.
    #[arg(long, default_value_t = 128)]
    window: usize,
    /// Frames between training windows.
    #[arg(long, default_value_t = 4)]
    stride: usize,
    /// Windows per batch.
    #[arg(long, default_value_t = 16)]
    batch: usize,
    /// Learning rate.
    #[arg(long, default_value_t = 1e-4)]
    lr: f64,
    /// Seed of every model's initialization, batches and noise, and of sampling.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Observed frames of each forecast.
    #[arg(long, default_value_t = 60)]
    observe: usize,
    /// Forecast frames.
    #[arg(long, default_value_t = 90)]
    horizon: usize,
    /// Forecast a window every N frames of each test scene (0: one window per scene).
    #[arg(long, default_value_t = 60)]
    window_stride: usize,
    /// Samples per forecast.
    #[arg(long, default_value_t = 4)]
    samples: usize,
    /// DDIM steps of the aggregator ablation's forecasts.
    #[arg(long, default_value_t = 50)]
    sampling_steps: usize,
    /// Joints of NDMS motion words: default (head, shoulders, elbows, wrists, knees, ankles,
    /// found by name), all, or comma-separated names.
    #[arg(long, value_name = "NAMES|all|default", default_value = "default")]
    ndms_joints: String,
    /// Leader/follower probe: training steps per aggregator (0: skip the probe).
    #[arg(long, default_value_t = 400)]
    probe_steps: usize,
}

/// One row of the table.
struct Row {
    name: String,
    report: QuickReport,
    extra: Vec<(String, String)>,
    json: Value,
}

fn parse_sampler(s: &str) -> Result<SamplerKind> {
    let bad = || Error::invalid(format!("--samplers: {s:?} is not ddpm or ddimN (e.g. ddim20)"));
    if s == "ddpm" {
        return Ok(SamplerKind::Ddpm);
    }
    let n: usize = s.strip_prefix("ddim").ok_or_else(bad)?.parse().map_err(|_| bad())?;
    if n == 0 {
        return Err(bad());
    }
    Ok(SamplerKind::Ddim { steps: n, eta: 0.0 })
}

fn fmt(v: f64, d: usize) -> String {
    if v.is_finite() {
        format!("{v:.d$}")
    } else {
        "–".into()
    }
}

/// `socdiff ablate`.
pub fn run(args: AblateArgs) -> Result<()> {
    // A device that cannot run is an error before anything is written.
    args.device.device.resolve()?;
    let ndms = socdiff_engine::metrics::NdmsConfig { joints: socdiff_engine::metrics::NdmsJoints::parse(&args.ndms_joints)?, ..Default::default() };
    if args.aggregators.is_empty() && args.samplers.is_empty() {
        return Err(Error::invalid("socdiff ablate: give --aggregators none,mean,attention, or --model RUN with --samplers ddpm,ddim20,…"));
    }
    for a in &args.aggregators {
        if !["none", "mean", "attention"].contains(&a.as_str()) {
            return Err(Error::invalid(format!("--aggregators: {a:?} is not none, mean or attention")));
        }
    }
    let samplers: Vec<(String, SamplerKind)> = args.samplers.iter().map(|s| Ok((s.clone(), parse_sampler(s)?))).collect::<Result<_>>()?;
    let dataset = import::load(&args.data, &args.align.options())?;
    let test: Vec<Scene> = dataset.split(Split::Test).cloned().collect();
    if test.is_empty() || dataset.split(Split::Train).next().is_none() {
        return Err(Error::format(&args.data, "needs train and test sequences"));
    }
    // Into a new or empty folder, or an earlier ablation's (which it continues), never another.
    const MARKER: &str = ".socdiff-ablate";
    let ours = args.out.join(MARKER).is_file();
    if !ours {
        socdiff_engine::files::check_output_dir(&args.out)?;
    }
    std::fs::create_dir_all(&args.out).map_err(|e| Error::io(&args.out, e))?;
    let _lock = socdiff_engine::files::RunLock::acquire(&args.out)?;
    socdiff_engine::files::write_file_atomic(&args.out.join(MARKER), b"socdiff ablate output\n")?;
    let command: Vec<String> = std::env::args().collect();
    let proto = |sampler: SamplerKind| Protocol {
        observe: args.observe,
        horizon: args.horizon,
        opts: ForecastOptions { samples: args.samples, sampler, seed: args.seed, ..Default::default() },
        window_stride: (args.window_stride > 0).then_some(args.window_stride),
        device: args.device.device,
    };
    // With a window stride, scenes shorter than a window give none (forecast_scenes skips them).
    let usable: Vec<Scene> = test.iter().filter(|s| s.num_frames() > args.observe).cloned().collect();
    let mut rows = Vec::new();
    let mut settings = json!({
        "command": command.join(" "), "data": args.data.display().to_string(), "seed": args.seed,
        "forecast": {"observe": args.observe, "horizon": args.horizon, "samples": args.samples, "window_stride": args.window_stride},
    });

    if !args.aggregators.is_empty() {
        let ddim = SamplerKind::Ddim { steps: args.sampling_steps, eta: 0.0 };
        settings["train"] =
            json!({"steps": args.steps, "hidden": args.hidden, "window": args.window, "stride": args.stride, "batch": args.batch, "lr": args.lr});
        settings["sampler"] = json!({"kind": "ddim", "steps": args.sampling_steps, "eta": 0.0});
        settings["probe"] = json!({"steps": args.probe_steps, "episodes": ProbeConfig::default().train_episodes});
        let pose: Vec<f32> = {
            let s = dataset.split(Split::Train).next().expect("checked");
            // Person 0 at frame 0: [frames, joints, 3] in standard order starts with it.
            s.person(0).iter().take(3 * s.num_joints()).copied().collect()
        };
        for agg in &args.aggregators {
            let model = if agg == "attention" {
                json!({"hidden": args.hidden, "social_dim": args.hidden, "aggregator": {"kind": "attention", "heads": 4}})
            } else {
                json!({"hidden": args.hidden, "social_dim": args.hidden, "aggregator": {"kind": agg}})
            };
            let dir = args.out.join(agg);
            let resume = Checkpoint::exists_in(&dir);
            let patch = json!({"model": model, "steps": args.steps, "window": args.window, "stride": args.stride, "batch": args.batch,
                               "adam": {"lr": args.lr}, "seed": args.seed, "save_every": 250, "val_every": 0});
            eprintln!("== {agg}: training {} steps → {}", args.steps, dir.display());
            let t0 = Instant::now();
            let opts = TrainOptions {
                out_dir: dir.clone(),
                resume,
                patches: vec![if resume { json!({"steps": args.steps}) } else { patch }],
                source: args.data.display().to_string(),
                stop: None,
                force: false,
                device: args.device.device,
                ..Default::default()
            };
            train_with_progress(&dataset, &opts)?;
            let train_secs = t0.elapsed().as_secs_f64();
            let m = Checkpoint::load(&dir)?;
            let runs = forecast_with_progress(&m, &usable, &proto(ddim))?;
            let report = evaluate(&runs, &test, &ndms)?;
            let mut extra = Vec::new();
            let mut probe_err = None;
            if args.probe_steps > 0 {
                let probe = ProbeConfig { steps: args.probe_steps, ..Default::default() };
                eprintln!("== {agg}: leader/follower probe ({} steps)", args.probe_steps);
                let e = leader_follower_probe(&m.skeleton, &pose, m.fps, &model, args.seed, &probe, &args.out.join(format!("probe_{agg}")))?;
                probe_err = Some(e);
                extra.push(("follower error (m) ↓".to_string(), fmt(e, 3)));
            }
            let mut s = settings.clone();
            s["aggregator"] = model.clone();
            let rdir = args.out.join(format!("report_{agg}"));
            std::fs::create_dir_all(&rdir).map_err(|e| Error::io(&rdir, e))?;
            write_report(&rdir, &report, s)?;
            let json = json!({"aggregator": agg, "train_seconds": train_secs, "model_step": m.step, "follower_error_m": probe_err, "report": report.to_json()});
            rows.push(Row { name: agg.clone(), report, extra, json });
        }
    } else {
        let mut models = Vec::new();
        for path in &args.model {
            let m = Checkpoint::load(path)?;
            models.push(json!({"path": m.path.display().to_string(), "step": m.step, "config": serde_json::to_value(&m.config).unwrap_or(Value::Null)}));
            let label = path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
            for (name, kind) in &samplers {
                let row = if args.model.len() > 1 { format!("{label} {name}") } else { name.clone() };
                eprintln!("== {row}");
                let runs = forecast_with_progress(&m, &usable, &proto(*kind))?;
                let report = evaluate(&runs, &test, &ndms)?;
                let dir = args.out.join(format!("report_{}", row.replace(' ', "_")));
                std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
                let mut s = settings.clone();
                s["model"] = models.last().cloned().unwrap_or(Value::Null);
                write_report(&dir, &report, s)?;
                let json = json!({"model": path.display().to_string(), "model_step": m.step, "sampler": name, "report": report.to_json()});
                rows.push(Row { name: row, report, extra: Vec::new(), json });
            }
        }
        settings["models"] = Value::Array(models);
        if samplers.len() > 1 {
            // Relative NDMS against the first sampler (DDPM when listed first), per model.
            let per_model = samplers.len();
            for chunk in rows.chunks_mut(per_model) {
                let base = chunk[0].report.ndms.mean;
                for r in chunk.iter_mut() {
                    let rel = 100.0 * (r.report.ndms.mean - base) / base;
                    r.extra.push((format!("NDMS vs {}", samplers[0].0), format!("{rel:+.1} %")));
                }
            }
        }
        for r in &mut rows {
            r.extra.push(("s per sample".into(), fmt(r.report.seconds_per_sample, 2)));
        }
    }

    // The table.
    let with_sscp = rows.iter().any(|r| r.report.sscp.is_some());
    let mut head = vec!["", "NDMS ↑", "NDMS 30–120", "NDMS last"];
    if with_sscp {
        head.push("SSCP ↓");
    }
    head.extend(["MPJPE 1 s", "2 s", "3 s", "best-of-K 3 s", "bone dev. mm", "foot slide m/s", "speed JS"]);
    let extra_heads: Vec<String> = rows.first().map(|r| r.extra.iter().map(|e| e.0.clone()).collect()).unwrap_or_default();
    let mut md = format!("| {} | {} |\n", head.join(" | "), extra_heads.join(" | "));
    md += &format!("|{}\n", "---|".repeat(head.len() + extra_heads.len()));
    for r in &rows {
        let rep = &r.report;
        let last = rep.ndms.ranges.last().map_or(f64::NAN, |x| x.2);
        let mut cells = vec![r.name.clone(), fmt(rep.ndms.mean, 4), fmt(rep.ndms.range_mean(30, 120), 4), fmt(last, 4)];
        if with_sscp {
            cells.push(rep.sscp.map_or("–".into(), |v| fmt(v, 4)));
        }
        for h in &rep.mpjpe {
            cells.push(h.mean.map_or("–".into(), |v| fmt(v, 3)));
        }
        cells.push(rep.mpjpe[2].best.map_or("–".into(), |v| fmt(v, 3)));
        let p = &rep.plausibility;
        cells.extend([fmt(p.bone_length_mm, 1), p.foot_sliding.map_or("–".into(), |v| fmt(v, 3)), p.speed_js.map_or("–".into(), |v| fmt(v, 3))]);
        cells.extend(r.extra.iter().map(|e| e.1.clone()));
        md += &format!("| {} |\n", cells.join(" | "));
    }
    let r0 = &rows[0].report;
    md += &format!(
        "\n{} forecast windows ({}–{} persons) from {} test sequences of {}: {} observed + {} forecast frames, {} samples each; \"NDMS last\" = frames {}–{}. MPJPE in metres (mean of K). Seed {}.\n\nCommand: `{}`\n",
        r0.scenes,
        r0.persons.0,
        r0.persons.1,
        usable.len(),
        args.data.display(),
        r0.observe,
        r0.horizon,
        r0.samples,
        r0.ndms.ranges.last().map_or(0, |x| x.0),
        r0.ndms.ranges.last().map_or(0, |x| x.1),
        args.seed,
        command.join(" ")
    );
    write_file_atomic(&args.out.join("table.md"), md.as_bytes())?;
    let results = json!({"settings": settings, "rows": rows.iter().map(|r| r.json.clone()).collect::<Vec<_>>()});
    let text = serde_json::to_string_pretty(&results).map_err(|e| Error::invalid(e.to_string()))?;
    write_file_atomic(&args.out.join("results.json"), text.as_bytes())?;
    println!("{md}");
    eprintln!("wrote {} and results.json", args.out.join("table.md").display());
    Ok(())
}
