//! `socdiff data inspect|convert`.

use clap::Subcommand;
use socdiff_engine::data::dataset::write_dataset;
use socdiff_engine::data::import::{self, ArrayArgs, ConvertOptions, ImportOptions, SourceArgs, SourceKind};
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
        #[arg(long, value_name = "FPS")]
        resample: Option<f64>,
        #[command(flatten)]
        arrays: ArrayArgs,
        /// Put these sequences (comma-separated names) in the test split.
        #[arg(long, value_delimiter = ',', value_name = "NAMES")]
        test: Vec<String>,
        /// Put every Nth sequence (the Nth, 2Nth, … in input order) in the test split.
        #[arg(long, value_name = "N")]
        test_every: Option<usize>,
        /// Combine the inputs into ONE scene, one input per person (e.g. single-person BVH files).
        #[arg(long)]
        persons_from_files: bool,
        /// Map every sequence onto this named skeleton by joint names (mupots17, mrt15, …; BVH
        /// end sites are read, so a head-top point can be copied); a joint no input has is an
        /// error naming it.
        #[arg(long, value_name = "SKELETON")]
        map_to: Option<String>,
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
    /// Compose one group scene from recorded scenes of one or more datasets: placed on a
    /// circle, a line or as recorded, bodies of different scenes kept apart.
    Compose {
        /// A scene: DATASET:SEQUENCE, or DATASET:SEQUENCE:PERSONS (comma-separated indices).
        /// Repeat for every scene of the group.
        #[arg(long = "scene", value_name = "DATASET:SEQUENCE[:PERSONS]", required = true)]
        scenes: Vec<String>,
        /// Where each scene goes.
        #[arg(long, value_enum, default_value = "circle")]
        placement: socdiff_engine::data::compose::Placement,
        /// Metres between neighbouring scenes (circle, line).
        #[arg(long, default_value_t = 1.5)]
        spacing: f32,
        /// The closest two bodies of different scenes may come on any frame, metres.
        #[arg(long, default_value_t = 0.5)]
        min_distance: f32,
        /// Allow scenes of different splits (the group goes to the train split).
        #[arg(long)]
        mix_splits: bool,
        /// Name of the composed scene (default: the scene names joined by +).
        #[arg(long)]
        name: Option<String>,
        /// Output dataset directory (must not exist or be empty).
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        source: SourceArgs,
    },
}

pub fn run(cmd: DataCommand) -> Result<()> {
    match cmd {
        DataCommand::Compose { scenes, placement, spacing, min_distance, mix_splits, name, out, source } => {
            use socdiff_engine::data::compose::{compose, Composition};
            socdiff_engine::files::check_output_dir(&out)?;
            let opts = source.options();
            let mut parts = Vec::with_capacity(scenes.len());
            for spec in &scenes {
                parts.push(compose_part(spec, &opts)?);
            }
            let name = name.unwrap_or_else(|| parts.iter().map(|p| p.scene.name.as_str()).collect::<Vec<_>>().join("+"));
            let (scene, split) = compose(&name, &parts, &Composition { placement, spacing, min_distance, mix_splits })?;
            let (persons, frames) = (scene.num_persons(), scene.num_frames());
            let dataset = socdiff_engine::Dataset {
                name: name.clone(),
                sequences: vec![socdiff_engine::data::dataset::Sequence { split, scene }],
                metadata: Default::default(),
            };
            write_dataset(&dataset, &out)?;
            println!("wrote {}: {name}, {persons} persons, {frames} frames, {} split", out.display(), split.as_str());
            Ok(())
        }
        DataCommand::Inspect { path, source, sequences } => inspect(&path, &source.options(), sequences),
        DataCommand::Convert { inputs, out, resample, arrays, test, test_every, persons_from_files, map_to, spacing, name, split, source } => {
            let mut opts = ImportOptions { split: Some(split), arrays: arrays.import()?, ..source.options() };
            let map_to = map_to.as_deref().map(socdiff_engine::Skeleton::named).transpose()?;
            opts.bvh.include_end_sites = map_to.is_some();
            let fallback_name = out.file_name().map_or("dataset".into(), |n| n.to_string_lossy().into_owned());
            let how = ConvertOptions { name, fallback_name, fps: resample, persons_from_files, spacing, test, test_every, map_to };
            let dataset = import::convert(&inputs, &opts, &how)?;
            write_dataset(&dataset, &out)?;
            let tests = dataset.split(socdiff_engine::Split::Test).count();
            println!("wrote {}: {} sequences, {} frames ({tests} sequences in the test split)", out.display(), dataset.sequences.len(), dataset.num_frames());
            Ok(())
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

/// One scene of `data compose`: `DATASET:SEQUENCE[:PERSONS]`, its persons selected.
fn compose_part(spec: &str, opts: &ImportOptions) -> Result<socdiff_engine::data::compose::Part> {
    let bad = || socdiff_engine::Error::invalid(format!("`scene` {spec:?}: expected DATASET:SEQUENCE or DATASET:SEQUENCE:PERSONS"));
    let (path, rest) = spec.split_once(':').ok_or_else(bad)?;
    let (sequence, persons) = match rest.split_once(':') {
        Some((s, p)) => (s, Some(p)),
        None => (rest, None),
    };
    if path.is_empty() || sequence.is_empty() {
        return Err(bad());
    }
    let path = Path::new(path);
    let dataset = import::load(path, opts)?;
    let seq = dataset.sequences.iter().find(|s| s.scene.name == sequence).ok_or_else(|| {
        let names: Vec<&str> = dataset.sequences.iter().map(|s| s.scene.name.as_str()).take(10).collect();
        socdiff_engine::Error::format(
            path,
            format!("no sequence {sequence:?} (it has {}{})", names.join(", "), if dataset.sequences.len() > 10 { ", …" } else { "" }),
        )
    })?;
    let scene = match persons {
        Some(list) => {
            let idx: Vec<usize> = list.split(',').map(|x| x.trim().parse::<usize>().map_err(|_| bad())).collect::<Result<_>>()?;
            seq.scene.select_persons(&idx).map_err(|e| e.in_file(path))?
        }
        None => seq.scene.clone(),
    };
    Ok(socdiff_engine::data::compose::Part { scene, split: seq.split })
}
