//! `socdiff data inspect|convert`.

use clap::{Args, Subcommand};
use socdiff_engine::data::bvh::{self, BvhImport};
use socdiff_engine::data::dataset::write_dataset;
use socdiff_engine::data::import::{self, ConvertOptions, ImportOptions, SourceKind};
use socdiff_engine::data::{haggling, pickle};
use socdiff_engine::{Dataset, Error, Result, Split};
use std::path::{Path, PathBuf};

/// `writeln!` into a `String` (infallible).
macro_rules! wl {
    ($out:expr, $($arg:tt)*) => {{
        use std::fmt::Write as _;
        let _ = writeln!($out, $($arg)*);
    }};
}

#[derive(Subcommand)]
pub enum DataCommand {
    /// Print what a dataset directory, BVH file or pickle holds: sequences, frames, persons,
    /// fps, duration, joints, bone lengths, invalid frames, signals.
    Inspect {
        /// Dataset directory, .bvh or .pkl.
        path: PathBuf,
        #[command(flatten)]
        source: SourceArgs,
        /// Print one line per sequence.
        #[arg(long)]
        sequences: bool,
    },
    /// Convert any supported input to a dataset directory (socdiff's native format).
    Convert {
        /// Inputs: dataset directories, .bvh files, Haggling body .pkl files.
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Output dataset directory (must not exist or be empty).
        #[arg(long)]
        out: PathBuf,
        /// Resample every sequence to this frame rate (linear interpolation).
        #[arg(long)]
        fps: Option<f64>,
        /// Combine the inputs into ONE scene, one input per person (e.g. single-person BVH files).
        #[arg(long)]
        persons_from_files: bool,
        /// Distance between neighbouring persons with --persons-from-files, metres.
        #[arg(long, default_value_t = 1.5)]
        spacing: f32,
        /// Dataset name (default: the input dataset's name, else the output directory's name).
        #[arg(long)]
        name: Option<String>,
        #[command(flatten)]
        source: SourceArgs,
    },
}

/// Ground alignment of dataset directories.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum AlignGround {
    /// Camera-frame data (up axis -y) only; skipped, saying so, without foot joints.
    Auto,
    /// Fit and remove the floor of any dataset.
    On,
    /// Never.
    Off,
}

impl AlignGround {
    /// As [`ImportOptions::align_ground`].
    pub(crate) fn option(self) -> Option<bool> {
        match self {
            AlignGround::Auto => None,
            AlignGround::On => Some(true),
            AlignGround::Off => Some(false),
        }
    }
}

/// `--align-ground` alone, for commands that read datasets but no other formats.
#[derive(Args, Clone)]
pub struct AlignArgs {
    /// Ground alignment of datasets: auto (camera-frame data only), on or off.
    #[arg(long, value_enum, default_value_t = AlignGround::Auto)]
    pub align_ground: AlignGround,
}

impl AlignArgs {
    /// Import options with this alignment.
    pub(crate) fn options(&self) -> ImportOptions {
        ImportOptions { align_ground: self.align_ground.option(), ..Default::default() }
    }
}

/// Options for reading sources.
#[derive(Args, Clone)]
pub struct SourceArgs {
    /// Ground alignment of datasets: auto (camera-frame data only), on or off.
    #[arg(long, value_enum, default_value_t = AlignGround::Auto)]
    align_ground: AlignGround,
    /// BVH: metres per file unit ("cmu" = 0.056444, "auto" guesses from the body height).
    #[arg(long, default_value = "auto")]
    bvh_scale: String,
    /// BVH: up axis of the file (y or z).
    #[arg(long, default_value = "y")]
    bvh_up: String,
    /// Haggling: folder of the speech files matching the body files.
    #[arg(long)]
    speech_dir: Option<PathBuf>,
    /// Split for scenes read from single files (train, test, validation).
    #[arg(long, value_enum, default_value = "train")]
    split: Split,
}

impl SourceArgs {
    /// Every path a command reads for `input` (the input and the speech folder), which its
    /// outputs must never replace.
    pub(crate) fn inputs<'a>(&'a self, input: &'a std::path::Path) -> Vec<&'a std::path::Path> {
        std::iter::once(input).chain(self.speech_dir.as_deref()).collect()
    }

    pub(crate) fn options(&self) -> Result<ImportOptions> {
        let align_ground = self.align_ground.option();
        let mut bvh = BvhImport::default();
        match self.bvh_scale.as_str() {
            "auto" => bvh.auto_scale = true,
            "cmu" => (bvh.scale, bvh.auto_scale) = (bvh::CMU_SCALE, false),
            s => {
                bvh.scale = s
                    .parse()
                    .ok()
                    .filter(|v: &f64| v.is_finite() && *v > 0.0)
                    .ok_or_else(|| Error::invalid(format!("--bvh-scale {s:?} is not a positive number, cmu or auto")))?;
                bvh.auto_scale = false;
            }
        }
        bvh.up_axis = match self.bvh_up.as_str() {
            "y" => bvh::UpAxis::Y,
            "z" => bvh::UpAxis::Z,
            s => return Err(Error::invalid(format!("--bvh-up {s:?}: expected y or z"))),
        };
        Ok(ImportOptions { align_ground, bvh, speech_dir: self.speech_dir.clone(), split: Some(self.split) })
    }
}

pub fn run(cmd: DataCommand) -> Result<()> {
    match cmd {
        DataCommand::Inspect { path, source, sequences } => inspect(&path, &source.options()?, sequences),
        DataCommand::Convert { inputs, out, fps, persons_from_files, spacing, name, source } => {
            convert(&inputs, &out, fps, persons_from_files, spacing, name, &source.options()?)
        }
    }
}

fn inspect(path: &Path, opts: &ImportOptions, per_sequence: bool) -> Result<()> {
    if import::source_kind(path)? == SourceKind::Pickle {
        let value = pickle::read_pickle(path)?;
        if value.get("speechData").is_some() {
            return inspect_speech(path);
        }
    }
    let ds = import::load(path, opts)?;
    print_dataset(&ds, per_sequence);
    Ok(())
}

fn inspect_speech(path: &Path) -> Result<()> {
    let s = haggling::load_speech(path)?;
    let mut out = String::new();
    wl!(out, "{}: Haggling speech annotations (no poses)", path.display());
    wl!(out, "frames        {}..{} ({} frames)", s.start_frame, s.end_frame, s.end_frame - s.start_frame + 1);
    wl!(out, "buyer         {}", s.buyer_id);
    wl!(out, "sellers       {:?} (left {}, right {})", s.seller_ids, s.left_seller_id, s.right_seller_id);
    for sp in &s.speakers {
        let speaking = sp.indicator.iter().filter(|&&v| v > 0.5).count();
        wl!(
            out,
            "person {:>4}  {} indicator values, speaking {:.1} % of frames",
            sp.human_id,
            sp.indicator.len(),
            100.0 * speaking as f64 / sp.indicator.len().max(1) as f64
        );
    }
    emit(&out);
    Ok(())
}

fn print_dataset(ds: &Dataset, per_sequence: bool) {
    let mut out = String::new();
    let sum = ds.summary();
    let sk = &ds.sequences[0].scene.skeleton;
    let (frames, duration, fps, (pmin, pmax), invalid, person_frames, signals) =
        (sum.frames, sum.duration_s, &sum.fps, sum.persons, sum.invalid, sum.person_frames, &sum.signals);
    wl!(out, "dataset       {}", ds.name);
    wl!(out, "sequences     {}", ds.sequences.len());
    wl!(out, "split         train {} / test {} / validation {}", sum.splits[0], sum.splits[1], sum.splits[2]);
    wl!(out, "frames        {frames}");
    wl!(out, "duration      {duration:.1} s");
    wl!(out, "fps           {}", fps.iter().map(|f| format!("{f}")).collect::<Vec<_>>().join(", "));
    wl!(out, "persons       {}", if pmin == pmax { format!("{pmin}") } else { format!("{pmin}–{pmax}") });
    wl!(out, "joints        {} ({}): {}", sk.num_joints(), sk.name, sk.joints.join(", "));
    wl!(out, "body frame    {} / {}", sk.joints[sk.left], sk.joints[sk.right]);
    wl!(out, "invalid       {invalid} of {person_frames} person-frames ({:.2} %)", 100.0 * invalid as f64 / person_frames.max(1) as f64);
    wl!(out, "signals       {}", if signals.is_empty() { "none".to_string() } else { signals.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(", ") });
    if !sum.roles.is_empty() {
        wl!(out, "roles         {}", sum.roles.join(", "));
    }
    wl!(out, "bones (mean ± std over valid frames, mm):");
    for (&(a, b), (mean, std)) in sk.bones.iter().zip(&sum.bones) {
        wl!(out, "  {:>16} – {:<16} {:7.1} ± {:5.1}", sk.joints[a], sk.joints[b], mean * 1e3, std * 1e3);
    }
    if per_sequence {
        wl!(out, "{:<28} {:<10} {:>7} {:>7} {:>6} {:>8} {:>8} {:>8}", "sequence", "split", "frames", "persons", "fps", "seconds", "invalid", "tilt°");
        for s in &ds.sequences {
            let sc = &s.scene;
            let tilt =
                sc.metadata.get("ground_alignment").and_then(|g| g.get("tilt_deg")).and_then(|t| t.as_f64()).map_or("-".to_string(), |t| format!("{t:.2}"));
            wl!(
                out,
                "{:<28} {:<10} {:>7} {:>7} {:>6} {:>8.1} {:>8} {:>8}",
                sc.name,
                s.split.as_str(),
                sc.num_frames(),
                sc.num_persons(),
                sc.fps,
                sc.duration(),
                sc.num_invalid(),
                tilt
            );
        }
    }
    emit(&out);
}

/// Prints a report; a closed pipe (`| head`) is not an error.
fn emit(text: &str) {
    use std::io::Write as _;
    let _ = std::io::stdout().lock().write_all(text.as_bytes());
}

/// Bone-length mean and std pooled over scenes, weighted by their valid person-frames.
fn convert(inputs: &[PathBuf], out: &Path, fps: Option<f64>, persons_from_files: bool, spacing: f32, name: Option<String>, opts: &ImportOptions) -> Result<()> {
    let fallback_name = out.file_name().map_or("dataset".into(), |n| n.to_string_lossy().into_owned());
    let dataset = import::convert(inputs, opts, &ConvertOptions { name, fallback_name, fps, persons_from_files, spacing })?;
    write_dataset(&dataset, out)?;
    println!("wrote {}: {} sequences, {} frames", out.display(), dataset.sequences.len(), dataset.num_frames());
    Ok(())
}
