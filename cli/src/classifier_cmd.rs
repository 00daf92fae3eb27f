//! `socdiff classifier train|eval|synth|speech-stats`: the speaking and buyer detectors that
//! SSCP uses where scenes lack speech annotations (see `socdiff_engine::classifier`).

use clap::{Args, Subcommand};
use indicatif::ProgressBar;
use socdiff_engine::classifier::{self, ClassifierOverrides, SocialSignalClassifiers, TrainEvent, TrainOptions};
use socdiff_engine::data::dataset::write_dataset;
use socdiff_engine::data::haggling;
use socdiff_engine::data::import::{self, ImportOptions};
use socdiff_engine::data::synthetic::triads::{self, SynthConfig};
use socdiff_engine::metrics::sscp::SpeakingStatistics;
use socdiff_engine::train::CheckpointSaved;
use socdiff_engine::{Result, Scene, Split};
use std::path::{Path, PathBuf};

#[derive(Subcommand)]
pub enum ClassifierCommand {
    /// Train the speaking and buyer detectors on scenes with a `speaking` signal (and roles);
    /// checkpoint (classifier.safetensors + classifier.json) and log go to --out.
    #[command(after_help = socdiff_engine::classifier::ClassifierConfig::describe_defaults())]
    Train(TrainArgs),
    /// Evaluate trained detectors: per-frame speaking accuracy, balanced accuracy, F1, and
    /// buyer accuracy per scene.
    Eval(EvalArgs),
    /// Generate haggling triads to train and test on: real speaking timelines (Haggling speech
    /// files) drive bodies animated with recorded motion (e.g. MuPoTS-3D). Not real recordings.
    Synth(SynthArgs),
    /// Speaking-only states (who of left seller / right seller / buyer speaks) of Haggling
    /// speech files: occupancy, transition matrix and pooled transition distribution.
    SpeechStats(SpeechStatsArgs),
}

/// Where labelled scenes come from.
#[derive(Args)]
pub struct DataArgs {
    /// Scenes: dataset directories (their --split), Haggling body .pkl files (with their speech
    /// files), .bvh; repeat for several.
    #[arg(long, required = true)]
    data: Vec<PathBuf>,
    /// Haggling body files: folder of the matching speech files (default: a sibling folder
    /// whose name contains "speech").
    #[arg(long)]
    speech_dir: Option<PathBuf>,
    #[command(flatten)]
    align: socdiff_engine::data::import::AlignArgs,
}

impl DataArgs {
    /// The scenes of `split` of every dataset directory and every scene of single files.
    fn scenes(&self, split: Split) -> Result<Vec<Scene>> {
        import::load_split(&self.data, split, &ImportOptions { speech_dir: self.speech_dir.clone(), ..self.align.options() })
    }

    fn source(&self) -> String {
        self.data.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
    }
}

#[derive(Args)]
pub struct TrainArgs {
    #[command(flatten)]
    data: DataArgs,
    #[command(flatten)]
    device: socdiff_engine::model::DeviceArg,
    /// Output directory of the classifiers.
    #[arg(long)]
    out: PathBuf,
    /// Split of dataset directories to train on.
    #[arg(long, value_enum, default_value = "train")]
    split: Split,
    #[command(flatten)]
    overrides: ClassifierOverrides,
    /// Continue the checkpoint in --out (its config is kept; only --steps may change).
    #[arg(long)]
    resume: bool,
}

#[derive(Args)]
pub struct EvalArgs {
    /// Classifier directory (from `socdiff classifier train`).
    #[arg(long)]
    model: PathBuf,
    #[command(flatten)]
    data: DataArgs,
    /// Split of dataset directories to evaluate on.
    #[arg(long, value_enum, default_value = "test")]
    split: Split,
    /// Also print one line per scene.
    #[arg(long)]
    per_scene: bool,
}

#[derive(Args)]
pub struct SynthArgs {
    #[command(flatten)]
    align: socdiff_engine::data::import::AlignArgs,
    /// Haggling speech files (.pkl) whose timelines drive the generated triads.
    #[arg(required = true)]
    speech: Vec<PathBuf>,
    /// Recorded motion to animate the persons with: a dataset directory (train split for train
    /// scenes, test split for test scenes) or any file `socdiff data` reads.
    #[arg(long)]
    motion: PathBuf,
    /// Output dataset directory (must not exist or be empty).
    #[arg(long)]
    out: PathBuf,
    /// The last N speech files (in the order given) make the test split.
    #[arg(long, default_value_t = 2)]
    test_files: usize,
    /// Frames per generated scene (timelines are cut into pieces this long).
    #[arg(long, default_value_t = 1800)]
    segment: usize,
    /// Generated scenes per timeline piece (other bodies and layouts).
    #[arg(long, default_value_t = 1)]
    variants: usize,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

#[derive(Args)]
pub struct SpeechStatsArgs {
    /// Haggling speech files (.pkl).
    #[arg(required = true)]
    speech: Vec<PathBuf>,
}

pub fn run(cmd: ClassifierCommand) -> Result<()> {
    match cmd {
        ClassifierCommand::Train(a) => train(a),
        ClassifierCommand::Eval(a) => eval(a),
        ClassifierCommand::Synth(a) => synth_data(a),
        ClassifierCommand::SpeechStats(a) => speech_stats(a),
    }
}

fn train(args: TrainArgs) -> Result<()> {
    let cfg = args.overrides.config(args.resume)?;
    let scenes = args.data.scenes(args.split)?;
    let opts = TrainOptions {
        out_dir: args.out.clone(),
        resume: args.resume,
        steps: args.overrides.run.steps,
        config: cfg,
        source: args.data.source(),
        stop: Some(crate::train_cmd::stop_flag()?),
        device: args.device.device,
    };
    let bar = ProgressBar::hidden();
    let say = |bar: &ProgressBar, line: String| if bar.is_hidden() { eprintln!("{line}") } else { bar.println(line) };
    let mut avg = crate::progress::SmoothedLoss::default();
    let summary = classifier::train::train(&scenes, &opts, &mut |event| match event {
        TrainEvent::Started { first_step, total_steps, params, scenes, frames, speaking_fraction, with_buyer, device } => {
            eprintln!(
                "training the speaking and buyer detectors on {scenes} scenes ({frames} frames, {:.1} % of person-frames speaking, {with_buyer} with a buyer): {params} parameters, on {device}",
                100.0 * speaking_fraction
            );
            crate::progress::start_steps(&bar, *first_step, *total_steps);
        }
        TrainEvent::Step { step, loss, .. } => {
            let l = *loss as f64;
            bar.set_message(format!("loss {:.4}", avg.add(l)));
            bar.set_position(*step);
        }
        TrainEvent::Saved(CheckpointSaved { step, path }) => say(&bar, format!("step {step}: saved {}", path.display())),
        TrainEvent::Notice(msg) => say(&bar, format!("note: {msg}")),
    })?;
    bar.finish_and_clear();
    let last = summary.losses.last().map(|l| format!(", last loss {l:.4}")).unwrap_or_default();
    if summary.stopped {
        eprintln!("stopped at step {}{last}; checkpoint {} (continue with --resume)", summary.last_step, summary.checkpoint.display());
    } else {
        eprintln!("trained steps {}..{}{last}; classifiers in {}", summary.first_step, summary.last_step, args.out.display());
    }
    Ok(())
}

fn eval(args: EvalArgs) -> Result<()> {
    let clf = SocialSignalClassifiers::load(&args.model)?;
    let scenes = args.data.scenes(args.split)?;
    let ev = classifier::evaluate(&clf, &scenes)?;
    print!("{}", ev.report(args.per_scene));
    Ok(())
}

fn stem(p: &Path) -> String {
    p.file_stem().map_or_else(|| p.display().to_string(), |s| s.to_string_lossy().into_owned())
}

fn synth_data(args: SynthArgs) -> Result<()> {
    let cfg = SynthConfig { segment_frames: args.segment, variants: args.variants, seed: args.seed };
    let name = args.out.file_name().map_or_else(|| "synth".to_string(), |n| n.to_string_lossy().into_owned());
    let (ds, [train_tracks, test_tracks], notes) =
        triads::generate_from_files(&name, &args.speech, args.test_files, &args.motion, &args.align.options(), &cfg)?;
    for note in notes {
        eprintln!("note: {note}");
    }
    write_dataset(&ds, &args.out)?;
    let count = |s: Split| ds.split(s).count();
    let frames = |s: Split| ds.split(s).map(|x| x.num_frames()).sum::<usize>();
    println!(
        "wrote {}: {} train scenes ({} frames, motion from {train_tracks} tracks), {} test scenes ({} frames, {test_tracks} tracks); generated, not real recordings",
        args.out.display(),
        count(Split::Train),
        frames(Split::Train),
        count(Split::Test),
        frames(Split::Test),
    );
    Ok(())
}

fn speech_stats(args: SpeechStatsArgs) -> Result<()> {
    let mut st = SpeakingStatistics::default();
    for p in &args.speech {
        let sp = haggling::load_speech(p)?;
        st.add_speech_file(stem(p), &sp).map_err(|e| e.in_file(p))?;
    }
    print!("{}", st.report()?);
    Ok(())
}
