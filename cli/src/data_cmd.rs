//! `socdiff data inspect|convert`.

use clap::Subcommand;
use socdiff_engine::data::dataset::write_dataset;
use socdiff_engine::data::import::{self, ConvertOptions, ImportOptions, SourceArgs, SourceKind};
use socdiff_engine::data::{haggling, pickle};
use socdiff_engine::Result;
use std::path::{Path, PathBuf};

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
        /// Split of the scenes read from single files (BVH, pickles): train, test or validation
        /// (dataset directories keep theirs).
        #[arg(long, value_enum, default_value = "train")]
        split: socdiff_engine::Split,
        #[command(flatten)]
        source: SourceArgs,
    },
}

pub fn run(cmd: DataCommand) -> Result<()> {
    match cmd {
        DataCommand::Inspect { path, source, sequences } => inspect(&path, &source.options(), sequences),
        DataCommand::Convert { inputs, out, fps, persons_from_files, spacing, name, split, source } => {
            convert(&inputs, &out, fps, persons_from_files, spacing, name, &ImportOptions { split: Some(split), ..source.options() })
        }
    }
}

fn inspect(path: &Path, opts: &ImportOptions, per_sequence: bool) -> Result<()> {
    if import::source_kind(path)? == SourceKind::Pickle {
        let value = pickle::read_pickle(path)?;
        if value.get("speechData").is_some() {
            emit(&haggling::load_speech(path)?.report(path));
            return Ok(());
        }
    }
    emit(&import::load(path, opts)?.report(per_sequence));
    Ok(())
}

/// Prints a report; a closed pipe (`| head`) is not an error.
fn emit(text: &str) {
    use std::io::Write as _;
    let _ = std::io::stdout().lock().write_all(text.as_bytes());
}

fn convert(inputs: &[PathBuf], out: &Path, fps: Option<f64>, persons_from_files: bool, spacing: f32, name: Option<String>, opts: &ImportOptions) -> Result<()> {
    let fallback_name = out.file_name().map_or("dataset".into(), |n| n.to_string_lossy().into_owned());
    let dataset = import::convert(inputs, opts, &ConvertOptions { name, fallback_name, fps, persons_from_files, spacing })?;
    write_dataset(&dataset, out)?;
    println!("wrote {}: {} sequences, {} frames", out.display(), dataset.sequences.len(), dataset.num_frames());
    Ok(())
}
