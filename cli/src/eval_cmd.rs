//! `socdiff eval`: score forecasts and baselines against a reference dataset; writes
//! `report.json`, PNG plots and prints a table (see `socdiff_engine::eval`).

use indicatif::{ProgressBar, ProgressStyle};
use socdiff_engine::eval::score::Progress;
use socdiff_engine::eval::EvalArgs;
use socdiff_engine::files::check_output_dir;
use socdiff_engine::{Error, Result};

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
    let job = args.job()?;
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
