//! `socdiff view`: one self-contained HTML page that plays any input in the browser.

use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use socdiff_engine::data::import;
use socdiff_engine::data::import::SourceArgs;
use socdiff_engine::export::html::{write_html, ViewOptions};
use socdiff_engine::export::{group_scenes, select_groups, SceneGroup};
use socdiff_engine::files::{check_output_file, OutputKind};
use socdiff_engine::Result;
use std::path::PathBuf;
use std::time::Duration;

#[derive(Args)]
pub struct ViewArgs {
    /// Input: dataset directory (forecasts included), .bvh or .pkl.
    input: PathBuf,
    /// Output HTML file (self-contained: open it in any browser, no network needed).
    #[arg(long)]
    out: PathBuf,
    /// Mark frames N and later as forecast (overrides the forecast metadata of the input).
    #[arg(long)]
    observed: Option<usize>,
    /// Show only this scene: a sequence name or a forecast source (repeatable; default: all).
    #[arg(long = "sequence", value_name = "NAME")]
    sequences: Vec<String>,
    /// Page title (default: the scene names).
    #[arg(long)]
    title: Option<String>,
    /// Start with signal labels (e.g. "speaking") hidden.
    #[arg(long)]
    no_signals: bool,
    /// Replace --out when it is an earlier viewer page (never an input or another kind of file).
    #[arg(long)]
    force: bool,
    #[command(flatten)]
    source: SourceArgs,
}

/// Applies `--observed` to the selected scenes.
pub(crate) fn observed(mut groups: Vec<SceneGroup>, n: Option<usize>) -> Result<Vec<SceneGroup>> {
    if let Some(n) = n {
        for g in &mut groups {
            g.set_observed(n)?;
        }
    }
    Ok(groups)
}

/// A spinner on stderr while `what` runs (drawn only on a terminal).
pub(crate) fn spinner(msg: String) -> ProgressBar {
    let pb = ProgressBar::new_spinner();
    pb.set_style(ProgressStyle::with_template("{spinner} {msg} ({elapsed})").expect("valid template"));
    pb.set_message(msg);
    pb.enable_steady_tick(Duration::from_millis(120));
    pb
}

pub fn run(args: ViewArgs) -> Result<()> {
    let opts = args.source.options();
    check_output_file(&args.out, &args.source.inputs(&args.input), OutputKind::ViewerHtml, args.force)?;
    let pb = spinner(format!("reading {}", args.input.display()));
    let ds = import::load(&args.input, &opts);
    let groups = ds.and_then(|ds| group_scenes(&ds, None)).and_then(|g| select_groups(g, &args.sequences)).and_then(|g| observed(g, args.observed));
    let groups = match groups {
        // A forecast's page opens on the forecast (samples beside the recorded future), not on
        // its observed part alone.
        Ok(mut g) => {
            g.sort_by_key(|g| g.observed_frames >= g.num_frames());
            g
        }
        Err(e) => {
            pb.finish_and_clear();
            return Err(e);
        }
    };
    let frames: usize = groups.iter().map(|g| g.samples.len() * g.num_frames()).sum();
    pb.set_message(format!("encoding {frames} frames"));
    let view = ViewOptions { title: args.title.clone(), show_signals: !args.no_signals, ..Default::default() };
    let stats = write_html(&args.out, &groups, &view);
    pb.finish_and_clear();
    let stats = stats?;
    let persons = groups.iter().map(|g| g.first().num_persons()).max().unwrap_or(0);
    println!(
        "wrote {}: {} scene{}, {} sample{}, {} frames, up to {} persons, {:.2} MB",
        args.out.display(),
        stats.scenes,
        if stats.scenes == 1 { "" } else { "s" },
        stats.samples,
        if stats.samples == 1 { "" } else { "s" },
        frames,
        persons,
        stats.html_bytes as f64 / 1e6
    );
    Ok(())
}
