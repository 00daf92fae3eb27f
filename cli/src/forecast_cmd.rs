//! `socdiff forecast` and `socdiff complete`: sampling with a trained denoiser by inpainting
//! (see `socdiff_engine::forecast`), on the forward-only network.

use socdiff_engine::checkpoint::Weights;
use socdiff_engine::data::dataset::write_dataset;
use socdiff_engine::data::import::load_sequence;
use socdiff_engine::data::scene::Scene;
use socdiff_engine::files::{check_output_dir, write_dir_atomic};
use socdiff_engine::forecast::{self, CompleteArgs, ForecastArgs, ForecastOutput, GenerateArgs, InterpolateArgs, Missing, Model, SampleArgs, Task};
use socdiff_engine::Result;

/// `socdiff generate`: whole scenes from noise.
pub fn run_generate(args: GenerateArgs) -> Result<()> {
    let req = args.request()?;
    check_output_dir(&args.output.out)?;
    let model = args.guide.load(&args.model, Weights::Ema, args.output.device.device)?;
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
    let req = args.request()?;
    check_output_dir(&args.out)?;
    let model = args.guide.load(&args.model, args.weights, args.device.device)?;
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
