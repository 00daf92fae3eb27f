//! A robot's view: a recorded MuPoTS-3D scene replayed at its 30 fps as a camera would deliver
//! it, one frame of every person at a time, through [`socdiff::forecast::Stream`]; once a second
//! has arrived, every new frame gets 8 futures of 3 s. Frame n arrives n/30 s after the start;
//! the example reports each forecast's latency and whether any forecast was still running when
//! the next frame arrived (it falls behind).
//!
//! ```sh
//! cargo run --release --example stream_mupots -- [--model models/groups-mrt15/model.safetensors] \
//!     [--data ../shared/data/mupots3d] [--sequence TS16] [--steps N] [--samples 8]
//! ```
//!
//! `--steps` defaults to the model's own: a distilled student's calls (`socdiff distill`), else
//! 2 (DDIM with two steps, the most a teacher takes in a frame period on two cores).

use socdiff::forecast::{Forecast, Model, SamplerKind, Stream};
use socdiff::recipes::realtime::Latency;
use socdiff::Result;
use std::time::{Duration, Instant};

fn arg(name: &str, default: &str) -> String {
    let args: Vec<String> = std::env::args().collect();
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1).cloned()).unwrap_or_else(|| default.to_string())
}

fn number(name: &str, default: &str) -> Result<usize> {
    arg(name, default).parse().map_err(|_| socdiff::Error::invalid(format!("{name}: expected a number")))
}

fn main() {
    if let Err(e) = run() {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<()> {
    let model = Model::load(arg("--model", "models/groups-mrt15/model.safetensors"))?;
    let data = arg("--data", "../shared/data/mupots3d");
    let dataset = socdiff::data::import::load(data.as_ref(), &Default::default())?;
    // The recording on the model's skeleton and frame rate (joints mapped by name).
    let scene = model.fit_scene(dataset.scene(&arg("--sequence", "TS16"))?, true)?.0;
    let own = if model.checkpoint.config.distill.is_some() { model.default_steps() } else { 2 };
    let (steps, samples) = (number("--steps", &own.to_string())?, number("--samples", "8")?);
    let req = Forecast { observe: 30, horizon: 90, samples, sampler: SamplerKind::Ddim { steps, eta: 0.0 }, ..Default::default() };
    let mut stream = Stream::new(&model, scene.num_persons(), req)?;
    let period = 1.0 / scene.fps;
    let (mut latencies, mut late) = (Vec::new(), 0usize);
    let start = Instant::now();
    for f in 0..scene.num_frames() {
        // Wait for frame f to "arrive"; a forecast still running when it did made us late.
        let arrives = Duration::from_secs_f64(f as f64 * period);
        match arrives.checked_sub(start.elapsed()) {
            Some(wait) => std::thread::sleep(wait),
            None if f > 0 => late += 1,
            None => {}
        }
        let began = Instant::now();
        let frame = scene.positions.slice(ndarray::s![f, .., .., ..]);
        if stream.push(f as f64 * period, frame)?.is_some() {
            latencies.push(began.elapsed().as_secs_f64());
        }
    }
    let l = Latency::of(&latencies)?;
    println!(
        "{}: {} frames of {} persons at {} fps replayed in {:.1} s; {} forecasts of {samples} × 90 frames (DDIM {steps})",
        scene.name,
        scene.num_frames(),
        scene.num_persons(),
        scene.fps,
        start.elapsed().as_secs_f64(),
        latencies.len()
    );
    println!("latency p50 {:.1} ms, p99 {:.1} ms, max {:.1} ms (a frame every {:.1} ms)", l.p50_ms, l.p99_ms, l.max_ms, period * 1e3);
    println!(
        "{}",
        if late == 0 { "kept up: every forecast was done before the next frame arrived".to_string() } else { format!("fell behind on {late} frames") }
    );
    Ok(())
}
