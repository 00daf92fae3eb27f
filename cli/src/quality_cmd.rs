//! `socdiff bench quality`: train the recommended recipe for N minutes of wall time, forecast
//! windows of MuPoTS test (1 s observed, 3 s forecast, K = 8) and score them with the baselines
//! through the one evaluator (`socdiff_engine::recipes::forecast_quality`). Resumable: run it
//! again with `--resume` after Ctrl-C; the training time already spent counts.

use crate::demo_cmd::forecast_progress;
use crate::train_cmd::{stop_flag, train_with_progress, EXIT_STOPPED};
use clap::Args;
use serde_json::{json, Value};
use socdiff_engine::data::import;
use socdiff_engine::files::{check_output_dir, write_file_atomic, RunLock};
use socdiff_engine::recipes::{forecast_quality, QualityProtocol};
use socdiff_engine::train::checkpoint::Checkpoint;
use socdiff_engine::train::TrainOptions;
use socdiff_engine::{Error, Result};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Options of `socdiff bench quality`.
#[derive(Args)]
pub struct QualityArgs {
    /// Minutes of training (wall time, over all resumes).
    #[arg(long)]
    minutes: f64,
    /// Output folder: model/ (the run), quality.json, report.json.
    #[arg(long)]
    out: PathBuf,
    /// Dataset with train and test splits.
    #[arg(long, default_value = "../shared/data/mupots3d")]
    data: PathBuf,
    /// Continue an interrupted run in --out.
    #[arg(long)]
    resume: bool,
    /// Noise levels of training (see `socdiff train --noise`).
    #[arg(long, default_value = "prefix", value_parser = ["uniform", "prefix", "per-frame", "per-frame-monotone"])]
    noise: String,
    /// U-Net width.
    #[arg(long, default_value_t = 64)]
    hidden: usize,
    /// Body-proportion augmentation (see `socdiff train --body-scale`; limbs get half of it;
    /// 0: off). On by default: it measured best (docs/recipes.md §8).
    #[arg(long, default_value_t = 0.1)]
    body_scale: f64,
    /// Samples per window.
    #[arg(long, default_value_t = 8)]
    samples: usize,
}

/// `socdiff bench quality`.
pub fn run(args: QualityArgs) -> Result<ExitCode> {
    if !(args.minutes.is_finite() && args.minutes > 0.0) {
        return Err(Error::invalid(format!("--minutes {}: expected a positive number", args.minutes)));
    }
    let out = &args.out;
    if !args.resume {
        check_output_dir(out)?;
    } else if !Checkpoint::exists_in(&out.join("model")) && out.exists() && !out.join("model").exists() {
        return Err(Error::format(out, "--resume: holds no bench quality run (no model/)"));
    }
    let noise = socdiff_engine::train::NoiseLevels::parse(&args.noise)?;
    let dataset = import::load(&args.data, &Default::default())?;
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let _lock = RunLock::acquire(out)?;

    // 1. Train until the time budget is spent.
    let model_dir = out.join("model");
    let patch = json!({
        "steps": 1_000_000_000u64, "batch": 16, "window": 120, "observed": 30, "stride": 5, "seed": 0,
        "model": {"hidden": args.hidden, "social_dim": args.hidden, "aggregator": {"kind": "mean"}},
        "adam": {"lr": 1e-3}, "noise": serde_json::to_value(noise).unwrap_or(Value::Null),
        "augment": {"body_scale": args.body_scale, "limb_scale": args.body_scale / 2.0},
        "save_every": 200, "val_every": 0,
    });
    let resume = Checkpoint::exists_in(&model_dir);
    let spent = if resume { Checkpoint::read_meta(&model_dir)?.elapsed_seconds } else { 0.0 };
    let budget = args.minutes * 60.0;
    // Written when the time ran out: the wall budget includes loading, the model's clock not.
    let done_marker = out.join(".budget-spent");
    let spent = if done_marker.is_file() { spent.max(budget) } else { spent };
    let stop = stop_flag()?;
    let deadline = Arc::new(AtomicBool::new(false));
    if spent < budget {
        let (flag, hit) = (stop.clone(), deadline.clone());
        let left = Duration::from_secs_f64(budget - spent);
        std::thread::spawn(move || {
            std::thread::sleep(left);
            hit.store(true, Ordering::SeqCst);
            flag.store(true, Ordering::SeqCst);
        });
        eprintln!("1/3 train: {:.1} of {:.1} minutes left → {}", (budget - spent) / 60.0, args.minutes, model_dir.display());
        let patches = if resume { vec![] } else { vec![patch.clone()] };
        let opts =
            TrainOptions { out_dir: model_dir.clone(), resume, force: false, patches, source: args.data.display().to_string(), stop: Some(stop.clone()) };
        let summary = train_with_progress(&dataset, &opts)?;
        if summary.stopped && !deadline.load(Ordering::SeqCst) {
            eprintln!("stopped; continue with: socdiff bench quality --minutes {} --out {} --resume", args.minutes, out.display());
            return Ok(ExitCode::from(EXIT_STOPPED));
        }
        write_file_atomic(&done_marker, format!("{}\n", args.minutes).as_bytes())?;
        eprintln!("the {:.1} minutes of training are spent", args.minutes);
    } else {
        eprintln!("1/3 train: the {:.1} minutes are spent ({:.1} min trained)", args.minutes, spent / 60.0);
    }

    // 2. Forecast the test windows; 3. score them.
    let model = Checkpoint::load(&model_dir)?;
    let proto = QualityProtocol { samples: args.samples, ..Default::default() };
    eprintln!(
        "2/3 forecast: windows of {} observed + {} forecast frames every {} frames of the test scenes, {} samples, DDIM {}",
        proto.observe, proto.horizon, proto.stride, proto.samples, proto.ddim_steps
    );
    let bar = forecast_progress((proto.ddim_steps * proto.samples) as u64);
    let result = forecast_quality(&model, &dataset, &args.data, &proto, &mut |i| {
        bar.inc(i.samples.len() as u64);
    });
    bar.finish_and_clear();
    let result = result?;
    eprintln!("3/3 score: {} windows through the evaluator", result.windows);

    let mut methods = serde_json::Map::new();
    for m in &result.report.methods {
        let mut by = serde_json::Map::new();
        if let Some(mp) = &m.mpjpe {
            for h in &mp.horizons {
                by.insert(format!("{}s", h.horizon_s), json!({"global": h.global, "root": h.root, "root_aligned": h.root_aligned}));
            }
        }
        methods.insert(m.label.clone(), json!({"mpjpe_m": by, "ndms": m.ndms.as_ref().map(|n| n.mean)}));
    }
    let worst = result.jumps.iter().map(|j| j.jump / j.observed.max(1e-9)).fold(0.0, f64::max);
    let within = result.jumps.iter().filter(|j| j.jump <= j.observed).count();
    let quality = json!({
        "protocol": {"ours": {"fps": model.fps, "observe": proto.observe, "horizon": proto.horizon, "samples": proto.samples,
            "ddim_steps": proto.ddim_steps, "window_stride": proto.stride, "windows": result.windows, "seed": proto.seed,
            "methods": methods, "first_frame_jump": {"windows_within_observed": within, "worst_ratio": worst, "per_window": result.jumps}},
            "mrt": {"fps": 15, "observe": 15, "predict": 45, "joints": socdiff_engine::recipes::MRT_JOINTS, "windows": result.windows,
                "metric": "mean joint error (m) over the first 15/30/45 predicted frames, keyed 1s/2s/3s",
                "methods": result.mrt.iter().map(|r| (r.method.clone(), json!({"mean": {"1s": r.mean[0], "2s": r.mean[1], "3s": r.mean[2]}, "best": {"1s": r.best[0], "2s": r.best[1], "3s": r.best[2]}}))).collect::<serde_json::Map<_, _>>()}},
        "training": {"minutes": args.minutes, "trained_seconds": model.meta.elapsed_seconds, "step": model.step, "config": model.config},
        "data": args.data.display().to_string(),
    });
    let text = serde_json::to_string_pretty(&quality).map_err(|e| Error::invalid(e.to_string()))?;
    write_file_atomic(&out.join("quality.json"), text.as_bytes())?;
    let text = serde_json::to_string_pretty(&result.report).map_err(|e| Error::invalid(e.to_string()))?;
    write_file_atomic(&out.join("report.json"), text.as_bytes())?;
    println!("{}", result.report.table());
    if !result.mrt.is_empty() {
        println!("MRT's protocol (15 fps, 15 observed / 45 predicted, 15 joints; mean error over the first 1/2/3 s, mm; mean of K / best of K):");
        for r in &result.mrt {
            println!(
                "  {:18} {:>5.0} {:>5.0} {:>5.0}   {:>5.0} {:>5.0} {:>5.0}",
                r.method,
                r.mean[0] * 1e3,
                r.mean[1] * 1e3,
                r.mean[2] * 1e3,
                r.best[0] * 1e3,
                r.best[1] * 1e3,
                r.best[2] * 1e3
            );
        }
    }
    println!(
        "first-frame jump ≤ the largest observed move in {within} of {} windows (worst ratio {worst:.2}); model step {} after {:.1} min",
        result.windows,
        model.step,
        model.meta.elapsed_seconds / 60.0
    );
    println!("wrote {} and report.json", out.join("quality.json").display());
    Ok(ExitCode::SUCCESS)
}
