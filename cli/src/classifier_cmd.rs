//! `socdiff classifier train|eval|synth|speech-stats`: the speaking and buyer detectors that
//! SSCP uses where scenes lack speech annotations (see `socdiff_engine::classifier`).

use clap::{Args, Subcommand};
use indicatif::ProgressBar;
use socdiff_engine::classifier::{self, ClassifierConfig, NetConfig, SocialSignalClassifiers, TrainEvent, TrainOptions};
use socdiff_engine::data::dataset::write_dataset;
use socdiff_engine::data::haggling;
use socdiff_engine::data::import::{self, ImportOptions};
use socdiff_engine::data::synthetic::triads::{self, SynthConfig};
use socdiff_engine::metrics::sscp::{SpeakingStatistics, SPEAKING_STATE_NAMES};
use socdiff_engine::{Error, Result, Scene, Split};
use std::path::{Path, PathBuf};

#[derive(Subcommand)]
pub enum ClassifierCommand {
    /// Train the speaking and buyer detectors on scenes with a `speaking` signal (and roles);
    /// checkpoint (classifier.safetensors + classifier.json) and log go to --out.
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
    device: crate::DeviceArg,
    /// Output directory of the classifiers.
    #[arg(long)]
    out: PathBuf,
    /// Split of dataset directories to train on.
    #[arg(long, value_enum, default_value = "train")]
    split: Split,
    /// Total optimizer steps (a resumed run continues up to this count) [default: 600].
    #[arg(long)]
    steps: Option<usize>,
    /// Windows per batch [default: 16].
    #[arg(long)]
    batch: Option<usize>,
    /// Frames per window, in training and inference [default: 128].
    #[arg(long)]
    window: Option<usize>,
    /// GRU width per direction (also the embedding and message width) [default: 32].
    #[arg(long)]
    hidden: Option<usize>,
    /// Learning rate [default: 0.003].
    #[arg(long)]
    lr: Option<f64>,
    /// Weight of the buyer loss [default: 1].
    #[arg(long)]
    buyer_weight: Option<f64>,
    /// Seed of initialization and window sampling [default: 0].
    #[arg(long)]
    seed: Option<u64>,
    /// Checkpoint every N steps (and at the end, and on Ctrl-C) [default: 100].
    #[arg(long)]
    save_every: Option<usize>,
    /// Continue the checkpoint in --out (its config is kept; only --steps may change).
    #[arg(long)]
    resume: bool,
}

impl TrainArgs {
    fn config(&self) -> Result<ClassifierConfig> {
        let d = ClassifierConfig::default();
        if self.resume
            && (self.batch.is_some()
                || self.window.is_some()
                || self.hidden.is_some()
                || self.lr.is_some()
                || self.buyer_weight.is_some()
                || self.seed.is_some()
                || self.save_every.is_some())
        {
            return Err(Error::invalid("--resume keeps the checkpoint's configuration: only --steps may be given"));
        }
        let h = self.hidden.unwrap_or(d.net.hidden);
        Ok(ClassifierConfig {
            steps: self.steps.unwrap_or(d.steps),
            batch: self.batch.unwrap_or(d.batch),
            window: self.window.unwrap_or(d.window),
            seed: self.seed.unwrap_or(d.seed),
            save_every: self.save_every.unwrap_or(d.save_every),
            buyer_weight: self.buyer_weight.unwrap_or(d.buyer_weight),
            adam: socdiff_engine::train::AdamConfig { lr: self.lr.unwrap_or(d.adam.lr), ..d.adam.clone() },
            net: NetConfig { embed: h, hidden: h, message: h, ..d.net.clone() },
            ..d
        })
    }
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
    let cfg = args.config()?;
    let scenes = args.data.scenes(args.split)?;
    let opts = TrainOptions {
        out_dir: args.out.clone(),
        resume: args.resume,
        steps: args.steps,
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
        TrainEvent::Saved { step, path } => say(&bar, format!("step {step}: saved {}", path.display())),
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
    if args.per_scene {
        for s in &ev.scenes {
            let buyer = match s.buyer {
                Some((got, want)) => format!("buyer {got} (true {want})"),
                None => "no buyer role".into(),
            };
            println!(
                "{:<28} {:>6} frames  accuracy {:.3}  balanced {:.3}  F1 {:.3}  {buyer}",
                s.name,
                s.frames,
                s.speaking.accuracy(),
                s.speaking.balanced_accuracy(),
                s.speaking.f1()
            );
        }
    }
    let c = &ev.speaking;
    println!("scenes        {} ({} frames)", ev.scenes.len(), ev.scenes.iter().map(|s| s.frames).sum::<usize>());
    println!("speaking      {} labelled person-frames, {:.1} % speaking", c.total(), 100.0 * (1.0 - c.silent_baseline()));
    println!("accuracy      {:.4}   (always silent: {:.4})", c.accuracy(), c.silent_baseline());
    println!("balanced acc  {:.4}", c.balanced_accuracy());
    println!("precision     {:.4}   recall {:.4}   F1 {:.4}", c.precision(), c.recall(), c.f1());
    if ev.buyer_total > 0 {
        println!("buyer         {}/{} scenes   accuracy {:.4}", ev.buyer_correct, ev.buyer_total, ev.buyer_accuracy());
    } else {
        println!("buyer         no scene has a buyer role");
    }
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
    println!("speaking-only states: who of left seller (L), right seller (R) and buyer (b) speaks");
    for (name, frames) in &st.sequences {
        println!("  {name:<32} {frames} frames");
    }
    println!("transitions   {} (frames − 1 per file, pooled)", st.transitions());
    let names = SPEAKING_STATE_NAMES;
    let header: String = names.iter().map(|n| format!("{n:>8}")).collect();
    let occ = st.occupancy_fraction();
    println!("\noccupancy (fraction of frames)\n{header}");
    println!("{}", occ.iter().map(|v| format!("{v:>8.4}")).collect::<String>());
    let print = |title: &str, rows: Vec<Vec<f64>>| {
        println!("\n{title}\n{:>6}{header}", "");
        for (i, row) in rows.iter().enumerate() {
            println!("{:>6}{}", names[i], row.iter().map(|v| format!("{v:>8.4}")).collect::<String>());
        }
    };
    print("transition matrix P(next | current), rows: current state", st.transition_matrix().outer_iter().map(|r| r.to_vec()).collect());
    print("pooled transition distribution C / ΣC (sums to 1)", st.distribution()?.outer_iter().map(|r| r.to_vec()).collect());
    Ok(())
}
