//! Minute-long triadic forecasts — the Haggling use case, end to end.
//!
//! Haggling mode (default): import Haggling body + speech pickles, train, forecast 60 s for all
//! three persons from the first 4 s of every test triad, evaluate NDMS over the whole minute and
//! SSCP (annotated speech), and write a viewer page. Without `--body-dir` it first writes
//! generated triads in the dataset's own file format (Python pickles, protocol 2, NumPy arrays;
//! see `socdiff::data::haggling`) so that the whole path runs here; with your copy of the
//! dataset, point `--body-dir`/`--speech-dir` at `panopticDB_body_pkl_hagglingProcessed` and
//! `panopticDB_speech_pkl_hagglingProcessed`.
//!
//! MuPoTS mode (`--mupots DIR --model RUN`): the same forecast (4 s → 60 s) for the 3-person
//! test scenes of MuPoTS-3D with a trained model, and NDMS per frame up to 1,800 frames: does the
//! curve hold over the minute (frames 1,300–1,800 vs 30–120)?
//!
//! ```sh
//! cargo run --release --example haggling_minute -- --out /tmp/haggling-minute
//! cargo run --release --example haggling_minute -- --mupots ../shared/data/mupots3d --model runs/m1 --out /tmp/mupots-minute
//! ```
//! Options: `--steps N` (training, default 1500), `--hidden H` (32), `--samples K` (4),
//! `--ddim N` (50), `--seed S` (1), `--train-triads N` (8), `--test-triads N` (2).

use serde_json::json;
use socdiff::checkpoint::Checkpoint;
use socdiff::data::import::{load, ImportOptions};
use socdiff::data::{Dataset, Scene, Split};
use socdiff::forecast::{Forecast, SamplerKind};
use socdiff::model::{Aggregator, DenoiserConfig};
use socdiff::recipes::{evaluate, forecast_scenes, write_view, Protocol, QuickReport};
use socdiff::train::{train, AdamConfig, TrainConfig, TrainEvent, TrainOptions};
use socdiff::{Error, Result};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Observed frames (4 s at 30 Hz) and forecast frames (60 s).
const OBSERVE: usize = 120;
const HORIZON: usize = 1800;

struct Args {
    out: PathBuf,
    body_dir: Option<PathBuf>,
    speech_dir: Option<PathBuf>,
    mupots: Option<PathBuf>,
    model: Option<PathBuf>,
    steps: usize,
    hidden: usize,
    samples: usize,
    ddim: usize,
    seed: u64,
    train_triads: usize,
    test_triads: usize,
}

fn parse_args() -> Result<Args> {
    let mut a = Args {
        out: std::env::temp_dir().join("socdiff-haggling-minute"),
        body_dir: None,
        speech_dir: None,
        mupots: None,
        model: None,
        steps: 1500,
        hidden: 32,
        samples: 4,
        ddim: 50,
        seed: 1,
        train_triads: 8,
        test_triads: 2,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut val = || it.next().ok_or_else(|| Error::invalid(format!("{flag} needs a value")));
        let num = |v: String| v.parse::<usize>().map_err(|_| Error::invalid(format!("{flag}: {v:?} is not a number")));
        match flag.as_str() {
            "--out" => a.out = val()?.into(),
            "--body-dir" => a.body_dir = Some(val()?.into()),
            "--speech-dir" => a.speech_dir = Some(val()?.into()),
            "--mupots" => a.mupots = Some(val()?.into()),
            "--model" => a.model = Some(val()?.into()),
            "--steps" => a.steps = num(val()?)?,
            "--hidden" => a.hidden = num(val()?)?,
            "--samples" => a.samples = num(val()?)?,
            "--ddim" => a.ddim = num(val()?)?,
            "--seed" => a.seed = num(val()?)? as u64,
            "--train-triads" => a.train_triads = num(val()?)?,
            "--test-triads" => a.test_triads = num(val()?)?,
            _ => return Err(Error::invalid(format!("unknown option {flag} (see the example's doc comment)"))),
        }
    }
    Ok(a)
}

fn main() {
    if let Err(e) = parse_args().and_then(|a| if a.mupots.is_some() { mupots_minute(&a) } else { haggling_minute(&a) }) {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

/// The forecast protocol of both modes: 4 s observed, 60 s forecast, one window per scene.
fn protocol(a: &Args) -> Protocol {
    Protocol {
        request: Forecast {
            observe: OBSERVE,
            horizon: HORIZON,
            samples: a.samples,
            sampler: SamplerKind::Ddim { steps: a.ddim, eta: 0.0 },
            seed: a.seed,
            ..Default::default()
        },
        window_stride: None,
        device: Default::default(),
    }
}

/// Table 7.3's frames, the two comparison ranges, and the report.
fn print_minute(report: &QuickReport) {
    let n = &report.ndms;
    let frames = [1, 5, 10, 15, 20, 25, 30, 60, 120, 250, 500, 750, 1000, 1300, 1800];
    println!("NDMS per forecast frame (word f starts f − 10 frames after the first forecast frame):");
    println!("  {}", frames.iter().filter(|&&f| f < n.per_frame.len()).map(|&f| format!("{f}: {:.3}", n.per_frame[f])).collect::<Vec<_>>().join("  "));
    let (early, late) = (n.range_mean(30, 120), n.range_mean(1300, 1800));
    println!("NDMS frames 30–120: {early:.4}   frames 1300–1800: {late:.4}   ratio late/early: {:.3}", late / early);
    println!("(paper, Haggling: Social Diffusion holds ≈ 0.226 flat; MRT decays from 0.215 to 0.047)");
    println!("{}", report.table());
}

fn write_outputs(dir: &Path, report: &QuickReport, extra: serde_json::Value) -> Result<()> {
    let mut v = report.to_json();
    v["settings"] = extra;
    let text = serde_json::to_string_pretty(&v).map_err(|e| Error::invalid(e.to_string()))?;
    std::fs::write(dir.join("report.json"), text).map_err(|e| Error::io(dir.join("report.json"), e))?;
    let csv: String = std::iter::once("frame,ndms\n".to_string()).chain(report.ndms.per_frame.iter().enumerate().map(|(f, v)| format!("{f},{v}\n"))).collect();
    std::fs::write(dir.join("ndms_per_frame.csv"), csv).map_err(|e| Error::io(dir.join("ndms_per_frame.csv"), e))
}

/// MuPoTS mode: a trained model, the 3-person test scenes, 60 s from 4 s.
fn mupots_minute(a: &Args) -> Result<()> {
    let data = a.mupots.as_ref().expect("mupots mode");
    let model_dir = a
        .model
        .as_ref()
        .ok_or_else(|| Error::invalid("--mupots needs --model RUN (a model trained on MuPoTS, e.g. `socdiff train --data ../shared/data/mupots3d`)"))?;
    let ds = load(data, &ImportOptions::default())?;
    let test: Vec<Scene> = ds.split(Split::Test).filter(|s| s.num_persons() == 3 && s.num_frames() > OBSERVE).cloned().collect();
    if test.is_empty() {
        return Err(Error::invalid(format!("{}: no 3-person test scene longer than {OBSERVE} frames", data.display())));
    }
    let model = Checkpoint::load(model_dir)?;
    println!(
        "model {} (step {}, hidden {}, {:?}); {} test scenes: {}",
        model.path.display(),
        model.step,
        model.config.model.hidden,
        model.config.model.aggregator,
        test.len(),
        test.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(", ")
    );
    let t0 = Instant::now();
    let runs = forecast_scenes(&model, &test, &protocol(a), &mut |_| {})?;
    let report = evaluate(&runs, &test, &Default::default())?;
    println!("forecast and scored in {:.0} s", t0.elapsed().as_secs_f64());
    std::fs::create_dir_all(&a.out).map_err(|e| Error::io(&a.out, e))?;
    write_view(&runs, &a.out.join("forecast.html"), "MuPoTS: 60 s from 4 s")?;
    write_outputs(
        &a.out,
        &report,
        json!({"data": data.display().to_string(), "model": model.path.display().to_string(), "model_step": model.step, "observe": OBSERVE, "horizon": HORIZON, "samples": a.samples, "ddim": a.ddim, "seed": a.seed}),
    )?;
    print_minute(&report);
    println!("wrote {}/report.json, ndms_per_frame.csv, forecast.html", a.out.display());
    Ok(())
}

/// Haggling mode.
fn haggling_minute(a: &Args) -> Result<()> {
    std::fs::create_dir_all(&a.out).map_err(|e| Error::io(&a.out, e))?;
    let (body_dir, speech_dir) = match (&a.body_dir, &a.speech_dir) {
        (Some(b), s) => (b.clone(), s.clone()),
        (None, _) => {
            let (b, s) = (a.out.join("panopticDB_body_pkl_hagglingProcessed"), a.out.join("panopticDB_speech_pkl_hagglingProcessed"));
            let n = a.train_triads + a.test_triads;
            println!("writing {n} generated triads (Haggling pickle format, {} frames each) to {}", generated::FRAMES, a.out.display());
            generated::write_triads(&b, &s, n, a.seed)?;
            (b, Some(s))
        }
    };
    // 1. Import: every body file with its speech file (roles and the `speaking` signal).
    let mut files: Vec<PathBuf> = std::fs::read_dir(&body_dir)
        .map_err(|e| Error::io(&body_dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "pkl"))
        .collect();
    files.sort();
    if files.len() < 2 {
        return Err(Error::format(&body_dir, "needs at least two body .pkl files (train and test)"));
    }
    let n_test = a.test_triads.clamp(1, files.len() - 1);
    let opts = ImportOptions { speech_dir: speech_dir.clone(), ..Default::default() };
    let mut sequences = Vec::new();
    for (i, f) in files.iter().enumerate() {
        let scene = load(f, &opts)?.sequences.remove(0).scene;
        let split = if i + n_test >= files.len() { Split::Test } else { Split::Train };
        sequences.push(socdiff::data::dataset::Sequence { split, scene });
    }
    let ds = Dataset { name: "haggling".into(), sequences, metadata: Default::default() };
    let test: Vec<Scene> = ds.split(Split::Test).cloned().collect();
    println!(
        "imported {} triads ({} train, {} test); speech: {}",
        files.len(),
        files.len() - n_test,
        n_test,
        if test.iter().all(|s| s.signals.contains_key("speaking")) { "yes" } else { "no" }
    );

    // 2. Train (continues an unfinished run in OUT/model).
    let model_dir = a.out.join("model");
    let config = TrainConfig {
        steps: a.steps,
        model: DenoiserConfig { hidden: a.hidden, social_dim: a.hidden, aggregator: Aggregator::Mean, ..Default::default() },
        window: 256,
        stride: 8,
        batch: 8,
        seed: a.seed,
        adam: AdamConfig { lr: 5e-4, ..Default::default() },
        save_every: 250,
        val_every: 0,
        ..Default::default()
    };
    let t0 = Instant::now();
    let opts = TrainOptions {
        out_dir: model_dir.clone(),
        resume: Checkpoint::exists_in(&model_dir),
        config: Some(config.clone()),
        source: body_dir.display().to_string(),
        stop: None,
        force: false,
        ..Default::default()
    };
    let mut last = 0;
    train(&ds, &opts, &mut |e| {
        if let TrainEvent::Step { step, loss, .. } = e {
            if *step == 1 || step % 250 == 0 {
                println!("  step {step}: loss {loss:.4} ({:.0} s)", t0.elapsed().as_secs_f64());
            }
            last = *step;
        }
    })?;
    println!("trained to step {last} in {:.0} s", t0.elapsed().as_secs_f64());

    // 3. Forecast 60 s from 4 s, all three persons; 4. evaluate; 5. view.
    let model = Checkpoint::load(&model_dir)?;
    let t1 = Instant::now();
    let runs = forecast_scenes(&model, &test, &protocol(a), &mut |_| {})?;
    let report = evaluate(&runs, &test, &Default::default())?;
    println!("forecast {} triads × {} samples × {HORIZON} frames and scored in {:.0} s", test.len(), a.samples, t1.elapsed().as_secs_f64());
    write_view(&runs, &a.out.join("forecast.html"), "Haggling: 60 s from 4 s")?;
    write_outputs(
        &a.out,
        &report,
        json!({"body_dir": body_dir.display().to_string(), "train": config, "observe": OBSERVE, "horizon": HORIZON, "samples": a.samples, "ddim": a.ddim, "seed": a.seed}),
    )?;
    print_minute(&report);
    println!("wrote {}/report.json, ndms_per_frame.csv, forecast.html", a.out.display());
    Ok(())
}

/// Generated Haggling triads, written in the dataset's file format.
mod generated {
    use socdiff::{Error, Result};
    use std::f64::consts::PI;
    use std::path::Path;

    /// Frames per generated triad: 4 s observed + 60 s forecast + a margin.
    pub const FRAMES: usize = 2000;

    /// Panoptic-19 standing pose, metres, facing +y (the person's left is −x), z up.
    const TEMPLATE: [[f64; 3]; 19] = [
        [0.0, 0.0, 1.45],
        [0.0, 0.10, 1.58],
        [0.0, 0.0, 0.95],
        [-0.18, 0.0, 1.42],
        [-0.20, 0.0, 1.15],
        [-0.20, 0.02, 0.90],
        [-0.10, 0.0, 0.93],
        [-0.10, 0.02, 0.50],
        [-0.10, 0.0, 0.08],
        [0.18, 0.0, 1.42],
        [0.20, 0.0, 1.15],
        [0.20, 0.02, 0.90],
        [0.10, 0.0, 0.93],
        [0.10, 0.02, 0.50],
        [0.10, 0.0, 0.08],
        [-0.035, 0.08, 1.63],
        [-0.075, 0.0, 1.60],
        [0.035, 0.08, 1.63],
        [0.075, 0.0, 1.60],
    ];

    /// A small deterministic generator (splitmix64), so the example needs no extra crates.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        }
        fn range(&mut self, a: f64, b: f64) -> f64 {
            a + (b - a) * self.next()
        }
    }

    /// Who speaks on each frame: turns of 1–5 s (buyer 40 %, each seller 25 %, nobody 10 %).
    fn speech(rng: &mut Rng, frames: usize) -> Vec<[bool; 3]> {
        let mut out = Vec::with_capacity(frames);
        while out.len() < frames {
            let len = rng.range(30.0, 150.0) as usize;
            let u = rng.next();
            let who = if u < 0.4 {
                Some(0)
            } else if u < 0.65 {
                Some(1)
            } else if u < 0.9 {
                Some(2)
            } else {
                None
            };
            for _ in 0..len {
                out.push(std::array::from_fn(|p| Some(p) == who));
            }
        }
        out.truncate(frames);
        out
    }

    /// Poses of the triad (buyer, left seller, right seller) in world metres, z up:
    /// `[frames][person][joint]`. Torsos and heads turn (smoothly) to whom they attend: the
    /// buyer to the speaking seller, or to a chosen seller while speaking; sellers to the buyer,
    /// or to the other seller when that one speaks. Speakers gesture with both arms; everyone
    /// sways and drifts a little.
    fn motion(rng: &mut Rng, talk: &[[bool; 3]]) -> Vec<[[[f64; 3]; 19]; 3]> {
        let places = [[0.0, -1.2], [-0.9, 0.5], [0.9, 0.5]];
        let yaw_to = |from: [f64; 2], to: [f64; 2]| (to[1] - from[1]).atan2(to[0] - from[0]) - PI / 2.0;
        let mut yaw: [f64; 3] = std::array::from_fn(|p| yaw_to(places[p], [0.0, 0.0]));
        let mut root = places;
        let (freq, phase): ([f64; 3], [f64; 3]) = (std::array::from_fn(|_| rng.range(0.6, 1.4)), std::array::from_fn(|_| rng.range(0.0, 2.0 * PI)));
        let mut buyer_focus = 1;
        let mut out = Vec::with_capacity(talk.len());
        for (t, speaking) in talk.iter().enumerate() {
            let time = t as f64 / 30.0;
            if t % 90 == 0 && rng.next() < 0.3 {
                buyer_focus = 3 - buyer_focus;
            }
            let mut frame = [[[0.0; 3]; 19]; 3];
            for p in 0..3 {
                let target = match p {
                    0 if speaking[1] => 1,
                    0 if speaking[2] => 2,
                    0 => buyer_focus,
                    _ if speaking[3 - p] => 3 - p,
                    _ => 0,
                };
                // Bodies turn half way, heads the rest (first-order lag, ~0.3 s).
                let want = yaw_to(root[p], root[target]);
                let err = (want - yaw[p] + PI).rem_euclid(2.0 * PI) - PI;
                yaw[p] += err / 9.0;
                for (k, r) in root[p].iter_mut().enumerate() {
                    *r += 0.002 * (rng.next() - 0.5) + 0.001 * (places[p][k] - *r);
                }
                let head_extra = 0.5 * err;
                let gesture = if speaking[p] { 0.25 * (0.5 + 0.5 * (2.0 * PI * freq[p] * time + phase[p]).sin()) } else { 0.02 };
                let sway = 0.02 * (2.0 * PI * 0.3 * time + phase[p]).sin();
                for (j, tpl) in TEMPLATE.iter().enumerate() {
                    let mut v = *tpl;
                    match j {
                        4 | 10 => v[1] += 0.4 * gesture,
                        5 | 11 => {
                            v[1] += gesture;
                            v[2] += 0.8 * gesture;
                        }
                        _ => {}
                    }
                    if j <= 5 || (9..=11).contains(&j) || j >= 15 {
                        v[0] += sway;
                    }
                    // Head joints (nose, eyes, ears) turn further, about the neck's vertical axis
                    // (the template's origin).
                    let a = if j == 1 || j >= 15 { yaw[p] + head_extra } else { yaw[p] };
                    let (s, c) = a.sin_cos();
                    frame[p][j] = [root[p][0] + c * v[0] - s * v[1], root[p][1] + s * v[0] + c * v[1], v[2]];
                }
            }
            out.push(frame);
        }
        out
    }

    /// Writes `n` triads as `group{i}.pkl` body and speech files.
    pub fn write_triads(body_dir: &Path, speech_dir: &Path, n: usize, seed: u64) -> Result<()> {
        for d in [body_dir, speech_dir] {
            std::fs::create_dir_all(d).map_err(|e| Error::io(d, e))?;
        }
        for i in 0..n {
            let mut rng = Rng(seed.wrapping_mul(1000).wrapping_add(i as u64));
            let talk = speech(&mut rng, FRAMES);
            let poses = motion(&mut rng, &talk);
            let (buyer, left, right) = (10 * i as i64 + 1, 10 * i as i64 + 2, 10 * i as i64 + 3);
            let winner = if rng.next() < 0.5 { left } else { right };
            let loser = if winner == left { right } else { left };
            let start = 100;
            let ids = [(buyer, 0usize), (winner, if winner == left { 1 } else { 2 }), (loser, if winner == left { 2 } else { 1 })];
            let header = |w: &mut pickle::Writer| {
                w.key_int("startFrame", start);
                w.key_int("buyerId", buyer);
                w.key_int_list("sellerIds", &[left.min(right), left.max(right)]);
                w.key_int("winnerId", winner);
                w.key_int("leftSellerId", left);
                w.key_int("rightSellerId", right);
            };
            // Body: subjects in buyer, winner, loser order; joints19 [57, frames] in Panoptic
            // centimetres, y down: (x, y, z)_panoptic = 100·(x, −z, y)_world.
            let mut w = pickle::Writer::new();
            w.begin_dict();
            header(&mut w);
            w.key("subjects");
            w.begin_list();
            for &(hid, p) in &ids {
                w.begin_dict();
                w.key_int("humanId", hid);
                let mut joints = vec![0.0; 57 * FRAMES];
                for (t, frame) in poses.iter().enumerate() {
                    for (j, q) in frame[p].iter().enumerate() {
                        let panoptic = [100.0 * q[0], -100.0 * q[2], 100.0 * q[1]];
                        for k in 0..3 {
                            joints[(3 * j + k) * FRAMES + t] = panoptic[k];
                        }
                    }
                }
                w.key("joints19");
                w.array_f64(&[57, FRAMES], &joints);
                w.key("scores");
                w.array_f64(&[19, FRAMES], &vec![1.0; 19 * FRAMES]);
                w.end_dict();
            }
            w.end_list();
            w.end_dict();
            let path = body_dir.join(format!("group{i}.pkl"));
            std::fs::write(&path, w.finish()).map_err(|e| Error::io(&path, e))?;
            // Speech: indicator of endFrame − startFrame + 1 = frames + 1 entries per person.
            let mut w = pickle::Writer::new();
            w.begin_dict();
            header(&mut w);
            w.key_int("endFrame", start + FRAMES as i64);
            w.key("speechData");
            w.begin_list();
            for &(hid, p) in &ids {
                w.begin_dict();
                w.key_int("humanId", hid);
                let ind: Vec<f64> = (0..=FRAMES).map(|t| if talk[t.min(FRAMES - 1)][p] { 1.0 } else { 0.0 }).collect();
                w.key("indicator");
                w.array_f64(&[FRAMES + 1], &ind);
                w.end_dict();
            }
            w.end_list();
            w.end_dict();
            let path = speech_dir.join(format!("group{i}.pkl"));
            std::fs::write(&path, w.finish()).map_err(|e| Error::io(&path, e))?;
        }
        Ok(())
    }

    /// A minimal pickle writer (protocol 2, as Python 3 writes it): dicts, lists, ints, strings
    /// and float64 NumPy arrays (`numpy.core.multiarray._reconstruct` + BUILD, bytes through
    /// `_codecs.encode`).
    mod pickle {
        pub struct Writer(Vec<u8>);

        impl Writer {
            pub fn new() -> Self {
                Writer(vec![0x80, 2])
            }
            pub fn finish(mut self) -> Vec<u8> {
                self.0.push(b'.');
                self.0
            }
            fn str(&mut self, s: &str) {
                self.0.push(b'X');
                self.0.extend((s.len() as u32).to_le_bytes());
                self.0.extend(s.as_bytes());
            }
            fn int(&mut self, v: i64) {
                self.0.push(b'J');
                self.0.extend((v as i32).to_le_bytes());
            }
            fn global(&mut self, module: &str, name: &str) {
                self.0.push(b'c');
                self.0.extend(format!("{module}\n{name}\n").as_bytes());
            }
            /// `_codecs.encode(latin-1 text, 'latin1')` → bytes.
            fn bytes(&mut self, b: &[u8]) {
                self.global("_codecs", "encode");
                let text: String = b.iter().map(|&c| c as char).collect();
                self.str(&text);
                self.str("latin1");
                self.0.extend([0x86, b'R']);
            }
            pub fn begin_dict(&mut self) {
                self.0.extend([b'}', b'(']);
            }
            pub fn end_dict(&mut self) {
                self.0.push(b'u');
            }
            pub fn begin_list(&mut self) {
                self.0.extend([b']', b'(']);
            }
            pub fn end_list(&mut self) {
                self.0.push(b'e');
            }
            pub fn key(&mut self, k: &str) {
                self.str(k);
            }
            pub fn key_int(&mut self, k: &str, v: i64) {
                self.str(k);
                self.int(v);
            }
            pub fn key_int_list(&mut self, k: &str, v: &[i64]) {
                self.str(k);
                self.begin_list();
                for &x in v {
                    self.int(x);
                }
                self.end_list();
            }
            /// A C-order float64 array of `shape`.
            pub fn array_f64(&mut self, shape: &[usize], data: &[f64]) {
                self.global("numpy.core.multiarray", "_reconstruct");
                self.global("numpy", "ndarray");
                self.int(0);
                self.0.push(0x85);
                self.bytes(b"b");
                self.0.extend([0x87, b'R']);
                // State: (1, shape, dtype('<f8'), False, raw bytes).
                self.0.push(b'(');
                self.int(1);
                self.0.push(b'(');
                for &d in shape {
                    self.int(d as i64);
                }
                self.0.push(b't');
                self.global("numpy", "dtype");
                self.str("f8");
                self.0.extend([0x89, 0x88, 0x87, b'R']);
                self.0.push(b'(');
                self.int(3);
                self.str("<");
                self.0.extend([b'N', b'N', b'N']);
                self.int(-1);
                self.int(-1);
                self.int(0);
                self.0.extend([b't', b'b']);
                self.0.push(0x89);
                let raw: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
                self.bytes(&raw);
                self.0.extend([b't', b'b']);
            }
        }
    }
}
