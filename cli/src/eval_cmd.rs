//! `socdiff eval`: score forecasts and baselines against a reference dataset; writes
//! `report.json`, PNG plots and prints a table (see `socdiff_engine::eval`).

use socdiff_engine::data::import::AlignArgs;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use socdiff_engine::eval::score::Progress;
use socdiff_engine::eval::{Baseline, EvalConfig, EvalJob, Metric, PastRecording};
use socdiff_engine::files::check_output_dir;
use socdiff_engine::metrics::{NdmsConfig, NdmsJoints};
use socdiff_engine::{Error, Result, Split};
use std::path::PathBuf;

#[derive(Args)]
pub struct EvalArgs {
    /// Reference dataset (ground truth): a dataset directory.
    #[arg(long)]
    reference: PathBuf,
    /// Split of the reference that is forecast and scored.
    #[arg(long, value_enum, default_value = "test")]
    split: Split,
    /// Forecasts to score: DIR or LABEL=DIR (repeatable, or comma-separated). DIR is a forecast
    /// directory (`socdiff forecast --out`), a folder of them, or a plain dataset directory
    /// (its sequences of --split are scored as one-sample forecasts, e.g. ground truth). The
    /// same LABEL twice merges directories into one method.
    #[arg(long = "forecasts", value_name = "[LABEL=]DIR", value_delimiter = ',')]
    forecasts: Vec<String>,
    /// Generated scenes to score (`socdiff generate --out`): DIR or LABEL=DIR (repeatable, or
    /// comma-separated). Every sequence is a sample with no recorded future: NDMS from frame 0,
    /// APD, plausibility (bones against the generated start), coverage and kinds.
    #[arg(long = "generated", value_name = "[LABEL=]DIR", value_delimiter = ',')]
    generated: Vec<String>,
    /// Only this split of the --generated directories (e.g. a dataset's train split scored
    /// against --split's motion words: the real-motion level).
    #[arg(long, value_enum, value_name = "SPLIT")]
    generated_split: Option<Split>,
    /// Labelled single-person motion (bandai2: kinds from the sequence names) to train the
    /// motion-kind classifier of the `kinds` metric on (its train split); adds `kinds` to
    /// --metrics all.
    #[arg(long, value_name = "DIR")]
    kinds_data: Option<PathBuf>,
    /// Built-in baselines on the reference split: zero-velocity, constant-velocity, nearest
    /// (real motion continued from the --continuation-split), ground-truth, or all.
    #[arg(long, value_name = "LIST")]
    baselines: Option<String>,
    /// Observed frames of baselines and plain datasets.
    #[arg(long, default_value_t = 30)]
    observe: usize,
    /// Forecast frames of baselines: a number, or "all" (to the end of each scene).
    #[arg(long, default_value = "all")]
    horizon: String,
    /// Metrics (comma-separated): ndms, mpjpe, apd, ade, fde, mmade, mmfde, speed, bone-length,
    /// acceleration, jerk, foot-sliding, speed-js, sscp, coverage, kinds (needs --kinds-data);
    /// groups: all (kinds only with --kinds-data), stochastic, plausibility.
    #[arg(long, default_value = "all")]
    metrics: String,
    /// Output directory for report.json and the plots (must not exist or be empty).
    #[arg(long)]
    out: PathBuf,
    /// Also write each baseline as a forecast directory DIR/NAME (viewable with socdiff view).
    #[arg(long, value_name = "DIR")]
    write_baselines: Option<PathBuf>,
    /// Split of the reference whose motion the nearest-continuation baseline continues.
    #[arg(long, value_enum, default_value = "train")]
    continuation_split: Split,
    /// Split whose motion words form the NDMS database (default: --split, as METHOD.md §5).
    #[arg(long, value_enum)]
    ndms_database: Option<Split>,
    /// MPJPE horizons in seconds (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    horizons: Vec<f64>,
    /// Seconds of forecast scored by APD, ADE, FDE, MMADE and MMFDE.
    #[arg(long, default_value_t = 3.0)]
    stochastic_horizon: f64,
    /// Body-frame pose distance (m) under which another observation's future counts for
    /// MMADE/MMFDE.
    #[arg(long, default_value_t = 0.5)]
    mm_threshold: f64,
    /// Cut forecasts that run past the end of their reference scene instead of failing.
    #[arg(long, conflicts_with = "score_past_recording")]
    crop: bool,
    /// Score forecasts that run past the end of their reference scene whole (a minute from a
    /// short recording): pose errors on the recorded part, NDMS and plausibility on every frame.
    #[arg(long)]
    score_past_recording: bool,
    /// Joints of NDMS motion words (and of the nearest-continuation search): default (head,
    /// shoulders, elbows, wrists, knees, ankles, found by name), all, or comma-separated names.
    #[arg(long, value_name = "NAMES|all|default", default_value = "default")]
    ndms_joints: String,
    #[command(flatten)]
    align: AlignArgs,
    /// Speaking and buyer classifiers (`socdiff classifier train --out DIR`): SSCP uses a scene's
    /// own speaking signal and roles where present and classifies the rest (forecast samples).
    #[arg(long, value_name = "DIR")]
    classifiers: Option<PathBuf>,
}

/// `(label, dir)` of one `--forecasts` value.
fn parse_forecast(spec: &str) -> Result<(String, PathBuf)> {
    let (label, dir) = match spec.split_once('=') {
        Some((l, d)) if !l.trim().is_empty() && !d.trim().is_empty() => (l.trim().to_string(), PathBuf::from(d.trim())),
        Some(_) => return Err(Error::invalid(format!("--forecasts {spec:?}: expected DIR or LABEL=DIR"))),
        None => {
            let dir = PathBuf::from(spec.trim());
            let label = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| spec.trim().to_string());
            (label, dir)
        }
    };
    Ok((label, dir))
}

/// Progress on stderr: a spinner with the current stage, then a bar once NDMS scoring starts.
#[derive(Default)]
struct Bars {
    spinner: Option<ProgressBar>,
    bar: Option<ProgressBar>,
}

impl Bars {
    fn update(&mut self, p: &Progress) {
        if p.total > 1 {
            if let Some(s) = self.spinner.take() {
                s.finish_and_clear();
            }
            let bar = self.bar.get_or_insert_with(|| {
                let b = ProgressBar::new(p.total as u64);
                b.set_style(ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} samples  {msg}  ETA {eta}").expect("valid template"));
                b
            });
            bar.set_length(p.total as u64);
            bar.set_position(p.done as u64);
            bar.set_message(p.stage.clone());
        } else if let Some(b) = &self.bar {
            b.set_message(p.stage.clone());
        } else {
            let s = self.spinner.get_or_insert_with(|| {
                let s = ProgressBar::new_spinner();
                s.set_style(ProgressStyle::with_template("{spinner} {msg} ({elapsed})").expect("valid template"));
                s.enable_steady_tick(std::time::Duration::from_millis(120));
                s
            });
            s.set_message(p.stage.clone());
        }
    }

    fn finish(&mut self) {
        for b in [self.spinner.take(), self.bar.take()].into_iter().flatten() {
            b.finish_and_clear();
        }
    }
}

pub fn run(args: EvalArgs) -> Result<()> {
    // Everything that can be checked cheaply first: nothing is computed for a bad command.
    let mut metrics = Metric::parse_list(&args.metrics)?;
    if args.kinds_data.is_some() && args.metrics.split(',').any(|m| m.trim() == "all") && !metrics.contains(&Metric::Kinds) {
        metrics.push(Metric::Kinds);
    }
    let baselines = match &args.baselines {
        Some(b) => Baseline::parse_list(b)?,
        None => Vec::new(),
    };
    let horizon = match args.horizon.as_str() {
        "all" => None,
        h => Some(
            h.parse::<usize>()
                .ok()
                .filter(|&h| h > 0)
                .ok_or_else(|| Error::invalid(format!("--horizon {h:?}: expected a positive number of frames or all")))?,
        ),
    };
    let mut forecasts: Vec<(String, Vec<PathBuf>)> = Vec::new();
    for spec in args.forecasts.iter().filter(|s| !s.trim().is_empty()) {
        let (label, dir) = parse_forecast(spec)?;
        match forecasts.iter_mut().find(|(l, _)| *l == label) {
            Some((_, dirs)) => dirs.push(dir),
            None => forecasts.push((label, vec![dir])),
        }
    }
    let job = EvalJob {
        reference: args.reference.clone(),
        split: args.split,
        import: args.align.options(),
        forecasts,
        generated: args.generated.iter().filter(|s| !s.trim().is_empty()).map(|s| parse_forecast(s)).collect::<Result<_>>()?,
        generated_split: args.generated_split,
        nearest_named: args.baselines.as_deref().is_some_and(|b| b.split(',').any(|x| x.trim() == "nearest")),
        baselines,
        observe: args.observe,
        horizon,
        continuation_split: args.continuation_split,
        past: match (args.crop, args.score_past_recording) {
            (true, _) => PastRecording::Crop,
            (_, true) => PastRecording::Score,
            _ => PastRecording::Refuse,
        },
        kinds_data: args.kinds_data.clone(),
        classifiers: args.classifiers.clone(),
        config: EvalConfig {
            metrics,
            horizons_s: args.horizons.clone(),
            ndms_database: args.ndms_database,
            ndms: NdmsConfig { joints: NdmsJoints::parse(&args.ndms_joints)?, ..Default::default() },
            stochastic_horizon_s: args.stochastic_horizon,
            multimodal_threshold: args.mm_threshold,
            ..Default::default()
        },
    };
    job.check()?;
    check_output_dir(&args.out)?;
    if let Some(w) = &args.write_baselines {
        if job.baselines.is_empty() {
            return Err(Error::invalid("--write-baselines needs --baselines"));
        }
        check_output_dir(w)?;
    }
    let mut bars = Bars::default();
    let outcome = job.run(&mut |p| bars.update(p));
    bars.finish();
    let mut outcome = outcome?;
    for note in &outcome.notes {
        eprintln!("note: {note}");
    }
    outcome.report.provenance.insert("command".into(), std::env::args().collect::<Vec<_>>().join(" ").into());
    let plots = outcome.write(&args.out, args.write_baselines.as_deref())?;
    let report = &outcome.report;
    print!("{}", report.table());
    if let Some(n) = report.methods.iter().filter_map(|m| m.ndms.as_ref()).map(|n| (n.words, n.seconds)).reduce(|a, b| (a.0 + b.0, a.1 + b.1)) {
        let words = report.settings.get("ndms").and_then(|s| s["database"]["words"].as_u64()).unwrap_or(0);
        let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
        println!("\nNDMS: {} query words against {words} database words in {:.2} s ({threads} threads)", n.0, n.1);
    }
    let names: Vec<String> = plots.iter().filter_map(|p| p.file_name()).map(|n| n.to_string_lossy().into_owned()).collect();
    println!("\nwrote {}: report.json, {}", args.out.display(), names.join(", "));
    if let Some(w) = &args.write_baselines {
        println!("wrote {}: {} baseline forecast directories", w.display(), job.baselines.len());
    }
    Ok(())
}
