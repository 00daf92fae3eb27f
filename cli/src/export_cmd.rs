//! `socdiff export`: BVH files per person, JSON arrays, PNG filmstrips.

use crate::view_cmd::{observed, spinner};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use socdiff_engine::data::import;
use socdiff_engine::data::import::SourceArgs;
use socdiff_engine::export::bvh_export::{BvhExportOptions, BvhUnits};
use socdiff_engine::export::output::{export_groups, write_dataset_with_bvh, ExportFormat};
use socdiff_engine::export::png::FilmstripOptions;
use socdiff_engine::export::{group_scenes, select_groups};
use socdiff_engine::files::{check_output_dir, check_output_file};
use socdiff_engine::{Error, Result};
use std::path::PathBuf;

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
    let opts = args.source.options();
    let format = match args.format {
        Format::Bvh => ExportFormat::Bvh(BvhExportOptions { units: args.units, root: args.root.clone(), stretch: args.stretch }),
        Format::Json => ExportFormat::Json,
        Format::Png => {
            let (panel_width, panel_height) = parse_pair::<u32>(&args.panel, 'x', "--panel", "WIDTHxHEIGHT, e.g. 320x360")?;
            let (azimuth_deg, elevation_deg) = parse_pair::<f64>(&args.view, ',', "--view", "AZIMUTH,ELEVATION in degrees, e.g. -60,20")?;
            ExportFormat::Png(FilmstripOptions { frames: args.frames, panel_width, panel_height, azimuth_deg, elevation_deg })
        }
    };
    match format.single_file_kind(&args.out)? {
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
    let pb = ProgressBar::new(0);
    pb.set_style(ProgressStyle::with_template("{bar:40} {pos}/{len} ({eta})").expect("valid template"));
    let written = export_groups(&groups, &format, &args.out, &mut |done, total| {
        pb.set_length(total);
        pb.set_position(done);
    });
    pb.finish_and_clear();
    let e = written.map_err(|e| e.in_file(&args.input))?;
    let out = args.out.display();
    match &format {
        ExportFormat::Bvh(opts) => {
            let max = e.bvh.iter().map(|b| b.max_error_m).fold(0.0, f64::max);
            let mean = e.bvh.iter().map(|b| b.mean_error_m).sum::<f64>() / e.bvh.len().max(1) as f64;
            let units = if opts.units == BvhUnits::Metres { "metres" } else { "centimetres" };
            let root = e.bvh.first().map_or("-", |b| b.root.as_str());
            let plural = if e.items == 1 { "" } else { "s" };
            println!(
                "wrote {out}: {} BVH files ({} sequence{plural}, {units}, root {root}); re-import error max {:.3} cm, mean {:.3} cm",
                e.files,
                e.items,
                max * 100.0,
                mean * 100.0
            );
            if max > 0.02 && !opts.stretch {
                println!("note: bone lengths of this data vary; --stretch writes per-joint offsets that reproduce it exactly");
            }
        }
        ExportFormat::Json if e.single_file => println!("wrote {out}: {} frames × {} persons", groups[0].num_frames(), groups[0].first().num_persons()),
        ExportFormat::Json => println!("wrote {out}: {} JSON files", e.files),
        ExportFormat::Png(o) if e.single_file => println!("wrote {out}: {} frames × {} samples", o.frames, groups[0].samples.len()),
        ExportFormat::Png(o) => println!("wrote {out}: {} filmstrips of {} frames", e.files, o.frames),
    }
    Ok(())
}

fn parse_pair<T: std::str::FromStr>(s: &str, sep: char, flag: &str, what: &str) -> Result<(T, T)> {
    let parsed = s.split_once(sep).and_then(|(a, b)| Some((a.trim().parse().ok()?, b.trim().parse().ok()?)));
    parsed.ok_or_else(|| Error::invalid(format!("{flag} {s:?}: expected {what}")))
}

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
    use socdiff_engine::data::retarget::{body_on, retarget};
    check_output_dir(&args.out)?;
    let opts = args.source.options();
    let motion = import::load_sequence(&args.motion, args.motion_sequence.as_deref(), &opts)?;
    let body = import::load_sequence(&args.body, args.body_sequence.as_deref(), &opts)?;
    let (body, lengths) = body_on(&body, &motion, args.body_person).map_err(|e| e.in_file(&args.body))?;
    let r = retarget(&motion, &lengths).map_err(|e| e.in_file(&args.motion))?;
    let ratios = r.leg_ratio.iter().map(|v| format!("{v:.3}")).collect::<Vec<_>>().join(", ");
    let ds = r.into_dataset(&args.motion, &args.body, &body.name, args.body_person, &lengths);
    let bvhs = write_dataset_with_bvh(&ds, &args.out, &BvhExportOptions::default())?;
    let (m, out) = (&motion, args.out.display());
    println!(
        "{} ({} persons, {} frames) on the bones of {} person {} (leg ratio {ratios}) → {out} and {} BVH files",
        m.name,
        m.num_persons(),
        m.num_frames(),
        body.name,
        args.body_person,
        bvhs.len()
    );
    Ok(())
}
