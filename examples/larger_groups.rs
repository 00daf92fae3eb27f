//! Larger groups than in training: a model trained on MuPoTS's 2–3-person scenes forecasts a
//! 7-person scene built from real recordings — MuPoTS test scenes TS16 and TS17 (3 persons
//! each) and person 0 of TS19, placed side by side on a circle (`Scene::around_circle`, neighbours
//! 5 m apart, each scene's own layout kept) — and, for comparison, TS16 alone. It reports NDMS,
//! MPJPE and plausibility for 3 vs 7 persons, and the seconds per denoising step: the `mean`
//! aggregator costs O(P), so the step time should grow about linearly, 7/3 ≈ 2.3×.
//!
//! ```sh
//! cargo run --release --example larger_groups -- --model runs/m1 [--mupots ../shared/data/mupots3d] [--out DIR]
//! ```
//! Without `--model` it first trains a small model (hidden 32, 800 steps, windows of 128 frames)
//! on MuPoTS's train split into `OUT/model` (a few minutes on 2 cores).
//! Options: `--samples K` (4), `--ddim N` (50), `--observe N` (60), `--horizon N` (1800), `--seed S` (1).

use serde_json::json;
use socdiff::checkpoint::Checkpoint;
use socdiff::data::import::{load, ImportOptions};
use socdiff::data::{Scene, Split};
use socdiff::forecast::{Forecast, SamplerKind};
use socdiff::model::{Aggregator, DenoiserConfig};
use socdiff::recipes::{evaluate, forecast_scenes, write_view, Protocol, QuickReport};
use socdiff::train::{train, AdamConfig, TrainConfig, TrainOptions};
use socdiff::{Error, Result};
use std::path::PathBuf;
use std::time::Instant;

fn main() {
    if let Err(e) = run() {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<()> {
    let mut mupots = PathBuf::from("../shared/data/mupots3d");
    let mut out = std::env::temp_dir().join("socdiff-larger-groups");
    let mut model_dir: Option<PathBuf> = None;
    let (mut samples, mut ddim, mut observe, mut horizon, mut seed) = (4usize, 50usize, 60usize, 1800usize, 1u64);
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let val = it.next().ok_or_else(|| Error::invalid(format!("{flag} needs a value")))?;
        let num = || val.parse::<usize>().map_err(|_| Error::invalid(format!("{flag}: {val:?} is not a number")));
        match flag.as_str() {
            "--mupots" => mupots = val.into(),
            "--out" => out = val.into(),
            "--model" => model_dir = Some(val.into()),
            "--samples" => samples = num()?,
            "--ddim" => ddim = num()?,
            "--observe" => observe = num()?,
            "--horizon" => horizon = num()?,
            "--seed" => seed = num()? as u64,
            _ => return Err(Error::invalid(format!("unknown option {flag} (see the example's doc comment)"))),
        }
    }
    let ds = load(&mupots, &ImportOptions::default())?;
    std::fs::create_dir_all(&out).map_err(|e| Error::io(&out, e))?;
    let model_dir = match model_dir {
        Some(m) => m,
        None => {
            let dir = out.join("model");
            let config = TrainConfig {
                steps: 800,
                model: DenoiserConfig { hidden: 32, social_dim: 32, aggregator: Aggregator::Mean, ..Default::default() },
                window: 128,
                stride: 4,
                batch: 16,
                seed,
                adam: AdamConfig { lr: 5e-4, ..Default::default() },
                save_every: 200,
                val_every: 0,
                ..Default::default()
            };
            println!("training a small model on {} (2–3 persons) → {}", mupots.display(), dir.display());
            let opts = TrainOptions {
                out_dir: dir.clone(),
                resume: Checkpoint::exists_in(&dir),
                config: Some(config),
                source: mupots.display().to_string(),
                stop: None,
                force: false,
                ..Default::default()
            };
            train(&ds, &opts, &mut |_| {})?;
            dir
        }
    };
    let model = Checkpoint::load(&model_dir)?;
    let trained_persons: Vec<&String> = model.meta.data.windows_by_persons.keys().collect();

    // The scenes: TS16 (3 persons) and TS16 + TS17 + TS19's person 0 (7 persons).
    let test: Vec<Scene> = ds.split(Split::Test).cloned().collect();
    let get = |name: &str| ds.scene(name).cloned();
    let (ts16, ts17, ts19) = (get("TS16")?, get("TS17")?, get("TS19")?);
    let seven = Scene::around_circle("TS16+TS17+TS19p0", &[ts16.clone(), ts17, ts19.select_persons(&[0])?], 5.0)?;
    let three = ts16.slice_frames(0, seven.num_frames())?;
    println!(
        "model {} (step {}, hidden {}, {:?}, trained on windows of {} persons); scenes: {} (3 persons), {} (7 persons), {} frames",
        model.path.display(),
        model.step,
        model.config.model.hidden,
        model.config.model.aggregator,
        trained_persons.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(", "),
        three.name,
        seven.name,
        seven.num_frames()
    );
    let proto = Protocol {
        request: Forecast { observe, horizon, samples, sampler: SamplerKind::Ddim { steps: ddim, eta: 0.0 }, seed, ..Default::default() },
        window_stride: None,
        device: Default::default(),
    };
    let mut reports: Vec<(usize, QuickReport)> = Vec::new();
    for scene in [&three, &seven] {
        let t0 = Instant::now();
        let runs = forecast_scenes(&model, std::slice::from_ref(scene), &proto, &mut |_| {})?;
        let rep = evaluate(&runs, &test, &Default::default())?;
        println!("\n== {} persons ({:.0} s)\n{}", scene.num_persons(), t0.elapsed().as_secs_f64(), rep.table());
        write_view(&runs, &out.join(format!("forecast_{}p.html", scene.num_persons())), &format!("{} persons", scene.num_persons()))?;
        reports.push((scene.num_persons(), rep));
    }
    let (r3, r7) = (&reports[0].1, &reports[1].1);
    let per = |r: &QuickReport, p: usize| r.seconds_per_step / p as f64;
    println!("\n| persons | NDMS ↑ | MPJPE 1 s | MPJPE 3 s | bone dev. mm | s per step | s per step per person |");
    println!("|---|---|---|---|---|---|---|");
    for (p, r) in &reports {
        let m = |i: usize| r.mpjpe[i].mean.map_or("–".into(), |v| format!("{v:.3}"));
        println!("| {p} | {:.4} | {} | {} | {:.1} | {:.4} | {:.4} |", r.ndms.mean, m(0), m(2), r.plausibility.bone_length_mm, r.seconds_per_step, per(r, *p));
    }
    println!(
        "step time 7 vs 3 persons: {:.2}× (linear in persons: {:.2}×); NDMS 7 vs 3 persons: {:+.1} %",
        r7.seconds_per_step / r3.seconds_per_step,
        7.0 / 3.0,
        100.0 * (r7.ndms.mean - r3.ndms.mean) / r3.ndms.mean
    );
    let v = json!({"three": r3.to_json(), "seven": r7.to_json(), "model": model.path.display().to_string(), "model_step": model.step,
                   "observe": observe, "horizon": horizon, "samples": samples, "ddim": ddim, "seed": seed});
    let path = out.join("report.json");
    std::fs::write(&path, serde_json::to_string_pretty(&v).unwrap_or_default()).map_err(|e| Error::io(&path, e))?;
    println!("wrote {}, forecast_3p.html, forecast_7p.html", path.display());
    Ok(())
}
