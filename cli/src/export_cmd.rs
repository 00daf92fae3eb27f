//! `socdiff export`: BVH files per person, JSON arrays, PNG filmstrips.

use crate::data_cmd::SourceArgs;
use crate::view_cmd::{observed, spinner};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use socdiff_engine::data::import;
use socdiff_engine::export::bvh_export::{person_to_bvh, write_scene_bvh, BvhExportOptions, BvhUnits};
use socdiff_engine::export::png::{write_filmstrip, FilmstripOptions};
use socdiff_engine::export::{group_scenes, json, safe_file_name, select_groups, write_dir_atomic, SceneGroup};
use socdiff_engine::files::{check_output_dir, check_output_file, OutputKind};
use socdiff_engine::{Error, Result};
use std::path::{Path, PathBuf};

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Format {
    /// One BVH file per person (fixed skeleton, rotations solved from positions).
    Bvh,
    /// Joint positions as nested arrays, one file per sequence.
    Json,
    /// A filmstrip of --frames frames, one row per sample, one image per scene.
    Png,
}

#[derive(Args)]
pub struct ExportArgs {
    /// Input: dataset directory (forecasts included), .bvh or .pkl.
    input: PathBuf,
    /// Output format.
    #[arg(long, value_enum)]
    format: Format,
    /// Output directory (must not exist or be empty); for json and png also a single .json or
    /// .png file when the input holds one scene (or --sequence picks one).
    #[arg(long)]
    out: PathBuf,
    /// Only this scene: a sequence name or a forecast source (repeatable; default: all).
    #[arg(long = "sequence", value_name = "NAME")]
    sequences: Vec<String>,
    /// Mark frames N and later as forecast (png; overrides the forecast metadata).
    #[arg(long)]
    observed: Option<usize>,
    /// png: frames per filmstrip, evenly spaced from first to last.
    #[arg(long, default_value_t = 6)]
    frames: usize,
    /// png: panel size in pixels, WIDTHxHEIGHT.
    #[arg(long, default_value = "320x360")]
    panel: String,
    /// png: camera azimuth (degrees from +x) and elevation (degrees), AZ,EL.
    #[arg(long, default_value = "-60,20", allow_hyphen_values = true)]
    view: String,
    /// bvh: file units, cm (re-import with --bvh-scale 0.01) or m.
    #[arg(long, value_enum, default_value = "cm")]
    units: BvhUnits,
    /// bvh: root joint (default: pelvis / hips / the joint nearest the hip centre).
    #[arg(long)]
    root: Option<String>,
    /// bvh: add per-joint position channels so that re-importing reproduces the recorded
    /// positions exactly, also where bone lengths vary.
    #[arg(long)]
    stretch: bool,
    /// Replace a single-file --out (.json, .png) when it is an earlier export of the same kind
    /// (never an input or another kind of file).
    #[arg(long)]
    force: bool,
    #[command(flatten)]
    source: SourceArgs,
}

pub fn run(args: ExportArgs) -> Result<()> {
    let opts = args.source.options()?;
    let single = match args.format {
        Format::Json => single_file(&args.out, "json")?.then_some(OutputKind::PositionsJson),
        Format::Png => single_file(&args.out, "png")?.then_some(OutputKind::Png),
        Format::Bvh => None,
    };
    match single {
        Some(kind) => check_output_file(&args.out, &args.source.inputs(&args.input), kind, args.force)?,
        None => check_output_dir(&args.out)?,
    }
    let pb = spinner(format!("reading {}", args.input.display()));
    let groups = import::load(&args.input, &opts)
        .and_then(|ds| group_scenes(&ds, None))
        .and_then(|g| select_groups(g, &args.sequences))
        .and_then(|g| observed(g, args.observed));
    pb.finish_and_clear();
    let groups = groups?;
    match args.format {
        Format::Bvh => export_bvh(&args, &groups),
        Format::Json => export_json(&args, &groups),
        Format::Png => export_png(&args, &groups),
    }
}

/// `Some(true)` when `out` names a file with extension `ext`, `Some(false)` for a directory;
/// an error for another extension.
fn single_file(out: &Path, ext: &str) -> Result<bool> {
    match out.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase) {
        Some(e) if e == ext => Ok(true),
        Some(e) if ["json", "png", "bvh", "html", "txt", "jpg"].contains(&e.as_str()) => {
            Err(Error::format(out, format!("expected a .{ext} file or a directory for --format {ext}")))
        }
        _ => Ok(false),
    }
}

fn progress(total: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(total);
    pb.set_style(ProgressStyle::with_template("{bar:40} {pos}/{len} {msg} ({eta})").expect("valid template"));
    pb.set_message(what.to_string());
    pb
}

fn export_bvh(args: &ExportArgs, groups: &[SceneGroup]) -> Result<()> {
    if single_file(&args.out, "bvh")? {
        return Err(Error::format(&args.out, "--format bvh writes a directory (one file per person); give a directory"));
    }
    let opts = BvhExportOptions { units: args.units, root: args.root.clone(), stretch: args.stretch };
    let scenes: Vec<_> = groups.iter().flat_map(|g| g.samples.iter().map(|s| &s.scene)).collect();
    let total: u64 = scenes.iter().map(|s| (s.num_frames() * s.num_persons()) as u64).sum();
    let pb = progress(total, "person-frames");
    let result = write_dir_atomic(&args.out, |dir| {
        let mut all = Vec::new();
        for s in &scenes {
            let frames = s.num_frames() as u64;
            all.extend(write_scene_bvh(s, dir, &opts, &mut |_| pb.inc(frames))?);
        }
        Ok(all)
    });
    pb.finish_and_clear();
    let files = result?;
    let max = files.iter().map(|e| e.max_error_m).fold(0.0, f64::max);
    let mean = files.iter().map(|e| e.mean_error_m).sum::<f64>() / files.len().max(1) as f64;
    println!(
        "wrote {}: {} BVH files ({} sequence{}, {}, root {}); re-import error max {:.3} cm, mean {:.3} cm",
        args.out.display(),
        files.len(),
        scenes.len(),
        if scenes.len() == 1 { "" } else { "s" },
        if args.units == BvhUnits::Metres { "metres" } else { "centimetres" },
        files.first().map_or("-", |e| e.root.as_str()),
        max * 100.0,
        mean * 100.0
    );
    if max > 0.02 && !args.stretch {
        println!("note: bone lengths of this data vary; --stretch writes per-joint offsets that reproduce it exactly");
    }
    Ok(())
}

fn export_json(args: &ExportArgs, groups: &[SceneGroup]) -> Result<()> {
    let scenes: Vec<_> = groups.iter().flat_map(|g| g.samples.iter().map(|s| &s.scene)).collect();
    if single_file(&args.out, "json")? {
        if scenes.len() != 1 {
            return Err(Error::format(&args.input, format!("holds {} sequences; pick one with --sequence NAME or give a directory as --out", scenes.len())));
        }
        json::write_json(scenes[0], &args.out)?;
        println!("wrote {}: {} frames × {} persons", args.out.display(), scenes[0].num_frames(), scenes[0].num_persons());
        return Ok(());
    }
    let pb = progress(scenes.len() as u64, "sequences");
    let result = write_dir_atomic(&args.out, |dir| {
        for s in &scenes {
            let text = json::scene_to_json(s)?;
            let path = dir.join(format!("{}.json", safe_file_name(&s.name)));
            std::fs::write(&path, text).map_err(|e| Error::io(&path, e))?;
            pb.inc(1);
        }
        Ok(())
    });
    pb.finish_and_clear();
    result?;
    println!("wrote {}: {} JSON files", args.out.display(), scenes.len());
    Ok(())
}

fn parse_pair<T: std::str::FromStr>(s: &str, sep: char, flag: &str, what: &str) -> Result<(T, T)> {
    let parsed = s.split_once(sep).and_then(|(a, b)| Some((a.trim().parse().ok()?, b.trim().parse().ok()?)));
    parsed.ok_or_else(|| Error::invalid(format!("{flag} {s:?}: expected {what}")))
}

fn export_png(args: &ExportArgs, groups: &[SceneGroup]) -> Result<()> {
    let (panel_width, panel_height) = parse_pair::<u32>(&args.panel, 'x', "--panel", "WIDTHxHEIGHT, e.g. 320x360")?;
    let (azimuth_deg, elevation_deg) = parse_pair::<f64>(&args.view, ',', "--view", "AZIMUTH,ELEVATION in degrees, e.g. -60,20")?;
    let opts = FilmstripOptions { frames: args.frames, panel_width, panel_height, azimuth_deg, elevation_deg };
    if single_file(&args.out, "png")? {
        if groups.len() != 1 {
            return Err(Error::format(&args.input, format!("holds {} scenes; pick one with --sequence NAME or give a directory as --out", groups.len())));
        }
        write_filmstrip(&groups[0], &args.out, &opts)?;
        println!("wrote {}: {} frames × {} samples", args.out.display(), opts.frames, groups[0].samples.len());
        return Ok(());
    }
    let pb = progress(groups.len() as u64, "scenes");
    let result = write_dir_atomic(&args.out, |dir| {
        for g in groups {
            let bytes = socdiff_engine::export::png::filmstrip_png(g, &opts)?;
            let path = dir.join(format!("{}.png", safe_file_name(&g.name)));
            std::fs::write(&path, bytes).map_err(|e| Error::io(&path, e))?;
            pb.inc(1);
        }
        Ok(())
    });
    pb.finish_and_clear();
    result?;
    println!("wrote {}: {} filmstrips of {} frames", args.out.display(), groups.len(), opts.frames);
    Ok(())
}

/// Options of `socdiff retarget`.
#[derive(Args)]
pub struct RetargetArgs {
    /// The motion: a dataset directory (with --motion-sequence), a .bvh or a .pkl.
    #[arg(long)]
    motion: PathBuf,
    /// Sequence of the --motion dataset.
    #[arg(long)]
    motion_sequence: Option<String>,
    /// The body whose bone lengths the motion takes (its joints mapped onto the motion's by
    /// name): a dataset directory (with --body-sequence), a .bvh or a .pkl.
    #[arg(long)]
    body: PathBuf,
    /// Sequence of the --body dataset.
    #[arg(long)]
    body_sequence: Option<String>,
    /// Person of the body scene.
    #[arg(long, default_value_t = 0)]
    body_person: usize,
    /// Output directory: the retargeted scene as a dataset, and one BVH per person in bvh/.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    source: SourceArgs,
}

/// `socdiff retarget`.
pub fn run_retarget(args: RetargetArgs) -> Result<()> {
    use socdiff_engine::data::dataset::{write_dataset, Sequence};
    use socdiff_engine::data::retarget::{body_on, retarget};
    check_output_dir(&args.out)?;
    let motion = crate::forecast_cmd::load_sequence(&args.motion, args.motion_sequence.as_deref(), &args.source)?;
    let body = crate::forecast_cmd::load_sequence(&args.body, args.body_sequence.as_deref(), &args.source)?;
    let (body, lengths) = body_on(&body, &motion, args.body_person).map_err(|e| e.in_file(&args.body))?;
    let r = retarget(&motion, &lengths).map_err(|e| e.in_file(&args.motion))?;
    let mut metadata = serde_json::Map::new();
    metadata.insert(
        "retarget".into(),
        serde_json::json!({"motion": args.motion.display().to_string(), "body": args.body.display().to_string(), "body_scene": body.name,
            "body_person": args.body_person, "bone_lengths_m": lengths, "leg_ratio": r.leg_ratio}),
    );
    // Every BVH text first, so that a failure writes nothing.
    let opts = BvhExportOptions::default();
    let bvhs = (0..r.scene.num_persons()).map(|p| person_to_bvh(&r.scene, p, &opts)).collect::<Result<Vec<_>>>()?;
    let ds = socdiff_engine::Dataset {
        name: r.scene.name.clone(),
        sequences: vec![Sequence { split: socdiff_engine::Split::Test, scene: r.scene.clone() }],
        metadata,
    };
    write_dataset(&ds, &args.out)?;
    let dir = args.out.join("bvh");
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    for b in &bvhs {
        socdiff_engine::files::write_file_atomic(&dir.join(&b.file_name), b.text.as_bytes())?;
    }
    println!(
        "{} ({} persons, {} frames) on the bones of {} person {} (leg ratio {}) → {} and {} BVH files",
        motion.name,
        motion.num_persons(),
        motion.num_frames(),
        body.name,
        args.body_person,
        r.leg_ratio.iter().map(|v| format!("{v:.3}")).collect::<Vec<_>>().join(", "),
        args.out.display(),
        bvhs.len()
    );
    Ok(())
}
