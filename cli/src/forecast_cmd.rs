//! `socdiff forecast` and `socdiff complete`: sampling with a trained denoiser by inpainting
//! (see `socdiff_engine::forecast`), on the forward-only network.

use socdiff_engine::checkpoint::Weights;
use socdiff_engine::data::dataset::write_dataset;
use socdiff_engine::data::import::load_sequence;
use socdiff_engine::data::scene::Scene;
use socdiff_engine::files::{check_output_dir, write_dir_atomic};
use socdiff_engine::forecast::stream::{forecast_json_line, parse_json_frame};
use socdiff_engine::forecast::{
    self, CompleteArgs, Forecast, ForecastArgs, ForecastOutput, GenerateArgs, InterpolateArgs, Missing, Model, SampleArgs, Stream, StreamFormat, Task,
};
use socdiff_engine::{Error, Result};

/// `socdiff generate`: whole scenes from noise.
pub fn run_generate(args: GenerateArgs) -> Result<()> {
    args.request()?;
    check_output_dir(&args.output.out)?;
    let model = args.guide.load(&args.model, Weights::Ema, args.output.device.device)?;
    let req = args.request_for(&model)?;
    let layout = match &args.layout {
        Some(path) => model.fit_scene(&load_sequence(path, args.sequence.as_deref(), &args.output.source.options())?, false).map_err(|e| e.in_file(path))?.0,
        None => model.circle_layout(args.persons)?,
    };
    let bar = crate::progress::denoising((req.sampler.steps(model.checkpoint.diffusion.timesteps()) * args.samples) as u64);
    let task = match args.placement_frame {
        Some(anchor) => Task::Generate { frames: args.frames, anchor },
        None => model.generate_task(args.frames),
    };
    let fc = model.sample(&layout, &task, &req, &mut |i| bar.inc(i.samples.len() as u64));
    bar.finish_and_clear();
    let mut fc = fc?;
    fc.provenance.layout = Some(args.layout.as_ref().map_or_else(|| format!("circle of {}", args.persons), |p| p.display().to_string()));
    fc.write(&args.output.out)?;
    println!("{} scenes of {} frames, {} persons → {}", args.samples, args.frames, layout.num_persons(), args.output.out.display());
    Ok(())
}

/// `socdiff interpolate`.
pub fn run_interpolate(args: InterpolateArgs) -> Result<()> {
    check_output_dir(&args.output.out)?;
    let model = Model::load_on(&args.model, Weights::Ema, args.output.device.device)?;
    let a = load_sequence(&args.from, args.from_sequence.as_deref(), &args.output.source.options())?;
    let b = load_sequence(&args.to, args.to_sequence.as_deref(), &args.output.source.options())?;
    if let Some(f) = args.transition {
        let fc = model.transition(&a, &b, f, args.ddim_steps, args.output.seed)?;
        fc.write(&args.output.out)?;
        println!("{} frames of {}, {f} generated, {} frames of {} → {}", a.num_frames(), a.name, b.num_frames(), b.name, args.output.out.display());
        return Ok(());
    }
    let it = model.interpolate(&a, &b, &args.request())?;
    let speeds: Vec<String> = it.root_speed.iter().map(|v| format!("{v:.2}")).collect();
    let steps: Vec<String> = it.largest_step.iter().map(|v| format!("{:.0}", v * 1e3)).collect();
    println!("mean root speed (m/s): {} (inputs {:.2} → {:.2})", speeds.join(" "), it.input_root_speed[0], it.input_root_speed[1]);
    let (s0, s1) = (it.input_largest_step[0] * 1e3, it.input_largest_step[1] * 1e3);
    println!("largest frame-to-frame joint move (mm): {} (inputs {s0:.0} / {s1:.0})", steps.join(" "));
    let (endpoint_error, depth) = (it.endpoint_error, it.depth);
    let refined = match it.refine {
        0 => String::new(),
        n => {
            let kept = |k: bool| if k { "kept" } else { "plain kept" };
            format!(
                "; {n} fixed-point iterations per inversion step, largest step residual {:.2e} / {:.2e} ({} / {})",
                it.inversion_residual[0],
                it.inversion_residual[1],
                kept(it.refined[0]),
                kept(it.refined[1])
            )
        }
    };
    write_dataset(&it.into_dataset(&args.from, &args.to), &args.output.out)?;
    println!(
        "{} motions from {} to {} → {} (inverted to noise level {depth}; endpoints reconstructed within {:.3} / {:.3} m mean joint error{})",
        args.steps,
        a.name,
        b.name,
        args.output.out.display(),
        endpoint_error[0],
        endpoint_error[1],
        refined
    );
    Ok(())
}

/// Samples the task of each scene of `args` (one, or a whole split) and writes it: one output
/// folder, or a folder per scene under it (written whole, or not at all).
fn run_task(args: &SampleArgs, task: impl Fn(&Scene) -> Result<(Task, Option<String>)>) -> Result<()> {
    args.request()?;
    check_output_dir(&args.out)?;
    let model = args.guide.load(&args.model, args.weights, args.device.device)?;
    let req = args.request_for(&model)?;
    let scenes = args.scenes(&model)?;
    if args.split.is_none() {
        let (scene, notes) = &scenes[0];
        let fc = sample_one(args, &model, &req, scene, notes, &task)?;
        fc.write(&args.out)?;
        println!("→ {}", args.out.display());
        return Ok(());
    }
    write_dir_atomic(&args.out, |tmp| {
        for (scene, notes) in &scenes {
            let dir = tmp.join(path_component(&scene.name)?);
            sample_one(args, &model, &req, scene, notes, &task)?.write(&dir)?;
        }
        Ok(())
    })?;
    println!("{} scenes → {}", scenes.len(), args.out.display());
    Ok(())
}

/// `name` as one folder name, or an error naming it.
fn path_component(name: &str) -> Result<&str> {
    let plain = !name.is_empty() && name != "." && name != ".." && !name.contains(['/', '\\']) && !name.chars().any(char::is_control);
    if plain {
        Ok(name)
    } else {
        Err(socdiff_engine::Error::invalid(format!("scene name {name:?} cannot name a folder")))
    }
}

/// One scene's samples, with a progress bar and a summary line.
fn sample_one(
    args: &SampleArgs,
    model: &Model,
    req: &forecast::Forecast,
    scene: &Scene,
    notes: &[String],
    task: &impl Fn(&Scene) -> Result<(Task, Option<String>)>,
) -> Result<ForecastOutput> {
    notes.iter().for_each(|n| eprintln!("{n}"));
    let (task, note) = task(scene)?;
    if let Some(n) = note {
        eprintln!("{n}");
    }
    // Sizes are checked by the engine when it samples; nothing here depends on them.
    let steps_per_sample = req.sampler.steps(model.checkpoint.diffusion.timesteps());
    let bar = crate::progress::denoising((steps_per_sample as u64).saturating_mul(req.samples as u64));
    let fc = model.sample(scene, &task, req, &mut |i| {
        bar.set_message(format!("samples {}–{} of {}  {:.3} s/step", i.samples.start + 1, i.samples.end, req.samples, i.seconds));
        bar.inc(i.samples.len() as u64);
    });
    bar.finish_and_clear();
    let mut fc = fc?;
    fc.provenance.weights = Some(args.weights);
    fc.provenance.input = Some(args.input.display().to_string());
    fc.provenance.persons = args.persons.clone();
    let t = fc.provenance.timings;
    let (total, per, calls, batch) = (t.total_seconds, t.seconds_per_step, t.model_calls, t.samples_per_call);
    println!(
        "{} samples × {} steps of {} ({} frames, {} persons): {calls} denoising steps of {batch} sample(s), {per:.3} s per step, {total:.1} s total",
        req.samples,
        steps_per_sample,
        scene.name,
        fc.samples[0].num_frames(),
        scene.num_persons(),
    );
    Ok(fc)
}

/// `socdiff forecast`.
pub fn run_forecast(args: ForecastArgs) -> Result<()> {
    if let Some(format) = args.stream {
        return run_stream(&args, format);
    }
    run_task(&args.common, |scene| {
        let (horizon, note) = args.horizon_for(scene);
        Ok((Task::Forecast { observe: args.observe, horizon }, note))
    })
}

/// `socdiff complete`.
pub fn run_complete(args: CompleteArgs) -> Result<()> {
    let spec = args.missing.clone();
    run_task(&args.common, |scene| Ok((Task::Complete(Missing::parse(&spec, &scene.skeleton)?), None)))
}

/// Most bytes of one JSON frame line of a stream (a frame of 1,000 persons × 100 joints is
/// about 3 MB).
const MAX_STREAM_LINE: usize = 16 << 20;

/// `socdiff forecast --stream`: frames from --input as they arrive, a forecast per frame on
/// --out as a JSON line (see [`socdiff_engine::forecast::Stream`]).
fn run_stream(args: &ForecastArgs, format: StreamFormat) -> Result<()> {
    use std::io::{BufRead, Read, Write};
    let common = &args.common;
    if common.split.is_some() || common.sequence.is_some() || common.persons.is_some() {
        return Err(Error::invalid("`stream` reads frames from `input`: `split`, `sequence` and `persons` do not apply"));
    }
    if let Some(p) = args.stream_persons {
        // Checked before the frame buffer is sized from it.
        socdiff_engine::data::check_size("`stream_persons`", 1.0, p, 1)?;
    }
    common.request()?;
    let model = common.guide.load(&common.model, common.weights, common.device.device)?;
    let req = common.request_for(&model)?;
    let joints = model.checkpoint.skeleton.num_joints();
    let mut input: Box<dyn BufRead> = if common.input.as_os_str() == "-" {
        Box::new(std::io::stdin().lock())
    } else {
        Box::new(std::io::BufReader::new(std::fs::File::open(&common.input).map_err(|e| Error::io(&common.input, e))?))
    };
    let mut output: Box<dyn Write> = if common.out.as_os_str() == "-" {
        Box::new(std::io::stdout().lock())
    } else {
        // A new file only: nothing that exists is replaced.
        let file = std::fs::OpenOptions::new().write(true).create_new(true).open(&common.out).map_err(|e| Error::io(&common.out, e))?;
        Box::new(std::io::BufWriter::new(file))
    };
    let mut stream: Option<Stream<&Model>> = None;
    let persons = args.stream_persons;
    if format == StreamFormat::F32 && persons.is_none_or(|p| p == 0) {
        return Err(Error::invalid("`stream` f32 needs `stream_persons` (at least 1)"));
    }
    let request = Forecast { observe: args.observe, horizon: args.horizon, ..req };
    let say = |output: &mut Box<dyn Write>, line: String| -> Result<()> {
        writeln!(output, "{line}").and_then(|()| output.flush()).map_err(|e| Error::io(&common.out, e))
    };
    let period = 1.0 / model.checkpoint.fps;
    let mut line = String::new();
    let mut raw = vec![0u8; 4 * persons.unwrap_or(0) * joints * 3];
    for frame_index in 0u64.. {
        let frame = match format {
            StreamFormat::Json => {
                line.clear();
                let n = (&mut input).take(MAX_STREAM_LINE as u64 + 1).read_line(&mut line).map_err(|e| Error::io(&common.input, e))?;
                if n == 0 {
                    break;
                }
                if n > MAX_STREAM_LINE {
                    return Err(Error::format(&common.input, format!("a frame line is longer than {MAX_STREAM_LINE} bytes")));
                }
                if line.trim().is_empty() {
                    continue;
                }
                // The first frame sets the persons of the stream.
                let p = stream.as_ref().map_or_else(|| count_persons(&line), |s| Some(s.persons()));
                p.ok_or_else(|| Error::invalid("stream: the first frame line has no persons")).and_then(|p| parse_json_frame(&line, p, joints))
            }
            StreamFormat::F32 => {
                match input.read_exact(&mut raw) {
                    Ok(()) => {}
                    Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => break,
                    Err(e) => return Err(Error::io(&common.input, e)),
                }
                let values: Vec<f32> = raw.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
                let shape = (persons.unwrap_or(1), joints, 3);
                Ok((frame_index as f64 * period, ndarray::Array3::from_shape_vec(shape, values).expect("sized to the shape")))
            }
        };
        let result = frame.and_then(|(time, positions)| {
            if stream.is_none() {
                stream = Some(Stream::new(&model, positions.dim().0, request.clone())?);
            }
            let s = stream.as_mut().expect("made above");
            Ok(s.push(time, positions.view())?.map(|fc| forecast_json_line(&fc, time, frame_index)))
        });
        match result {
            Ok(Some(forecast)) => say(&mut output, forecast)?,
            Ok(None) => {}
            Err(e) => say(&mut output, serde_json::json!({"frame": frame_index, "error": e.to_string()}).to_string())?,
        }
    }
    Ok(())
}

/// Persons of a JSON frame line (the length of its `positions`), if it parses.
fn count_persons(line: &str) -> Option<usize> {
    let v: serde_json::Value = serde_json::from_str(line).ok()?;
    v.get("positions")?.as_array().map(Vec::len).filter(|&p| p > 0)
}
