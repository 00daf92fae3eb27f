//! One evaluation run as a library call — what `socdiff eval` does: read the reference, turn
//! forecast directories, generated datasets and baselines into methods, score them through
//! [`super::evaluate`], and write `report.json`, the plots and (optionally) the baselines.

use super::plots::write_plots;
use super::score::Progress;
use super::{evaluate, Baseline, EvalConfig, Method, MethodKind, Metric, PastRecording, Reference, Report, SignalSource};
use crate::classifier::SocialSignalClassifiers;
use crate::data::dataset::write_dataset;
use crate::data::import::{self, ImportOptions};
use crate::data::Scene;
use crate::export::{safe_file_name, write_dir_atomic};
use crate::metrics::kinds::{KindTraining, MotionKindClassifier};
use crate::metrics::NdmsConfig;
use crate::metrics::{NdmsDatabase, NdmsJoints};
use crate::{bail, Error, Result, Split};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// What to evaluate and how.
#[derive(Clone, Debug)]
pub struct EvalJob {
    /// Reference dataset (any importable source).
    pub reference: PathBuf,
    /// The reference split that is scored.
    pub split: Split,
    /// How the reference is read.
    pub import: ImportOptions,
    /// Forecast directories by label (several directories under one label are one method).
    pub forecasts: Vec<(String, Vec<PathBuf>)>,
    /// Generated datasets by label (scored on the unconditional metrics).
    pub generated: Vec<(String, PathBuf)>,
    /// The split of the generated datasets that is scored (`None`: all).
    pub generated_split: Option<Split>,
    /// Built-in baselines.
    pub baselines: Vec<Baseline>,
    /// The nearest continuation was asked for by name (not through `all`): when it cannot run
    /// on this skeleton that is an error, not a note.
    pub nearest_named: bool,
    /// Observed frames of the baselines and of dataset directories.
    pub observe: usize,
    /// Forecast frames of the baselines (`None`: to the end of each scene).
    pub horizon: Option<usize>,
    /// Split the nearest continuation searches; never the scored split.
    pub continuation_split: Split,
    /// Forecasts that run past the end of their reference.
    pub past: PastRecording,
    /// Labelled motion to train the motion-kind classifier on (for [`Metric::Kinds`]).
    pub kinds_data: Option<PathBuf>,
    /// Speech/buyer classifiers for SSCP (`None`: the scenes' own annotations).
    pub classifiers: Option<PathBuf>,
    /// Metrics and their settings.
    pub config: EvalConfig,
}

#[derive(Clone, Debug)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
/// `socdiff eval`'s options: an [`EvalJob`] as flags ([`EvalArgs::job`]), and where the report goes.
pub struct EvalArgs {
    /// Reference dataset (ground truth): a dataset directory.
    #[cfg_attr(feature = "clap", arg(long))]
    pub reference: PathBuf,
    /// Split of the reference that is forecast and scored.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "test"))]
    pub split: Split,
    /// Forecasts to score: DIR or LABEL=DIR (repeatable, or comma-separated). DIR is a forecast
    /// directory (`socdiff forecast --out`), a folder of them, or a plain dataset directory
    /// (its sequences of --split are scored as one-sample forecasts, e.g. ground truth). The
    /// same LABEL twice merges directories into one method.
    #[cfg_attr(feature = "clap", arg(long = "forecasts", value_name = "[LABEL=]DIR", value_delimiter = ','))]
    pub forecasts: Vec<String>,
    /// Generated scenes to score (`socdiff generate --out`): DIR or LABEL=DIR (repeatable, or
    /// comma-separated). Every sequence is a sample with no recorded future: NDMS from frame 0,
    /// APD, plausibility (bones against the generated start), coverage and kinds.
    #[cfg_attr(feature = "clap", arg(long = "generated", value_name = "[LABEL=]DIR", value_delimiter = ','))]
    pub generated: Vec<String>,
    /// Only this split of the --generated directories (e.g. a dataset's train split scored
    /// against --split's motion words: the real-motion level).
    #[cfg_attr(feature = "clap", arg(long, value_enum, value_name = "SPLIT"))]
    pub generated_split: Option<Split>,
    /// Labelled single-person motion (bandai2: kinds from the sequence names) to train the
    /// motion-kind classifier of the `kinds` metric on (its train split); adds `kinds` to
    /// --metrics all.
    #[cfg_attr(feature = "clap", arg(long, value_name = "DIR"))]
    pub kinds_data: Option<PathBuf>,
    /// Built-in baselines on the reference split: zero-velocity, constant-velocity, nearest
    /// (real motion continued from the --continuation-split), ground-truth, or all.
    #[cfg_attr(feature = "clap", arg(long, value_name = "LIST"))]
    pub baselines: Option<String>,
    /// Observed frames of baselines and plain datasets.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 30))]
    pub observe: usize,
    /// Forecast frames of baselines: a number, or "all" (to the end of each scene).
    #[cfg_attr(feature = "clap", arg(long, default_value = "all"))]
    pub horizon: String,
    /// Metrics (comma-separated): ndms, mpjpe, apd, ade, fde, mmade, mmfde, speed, bone-length,
    /// acceleration, jerk, foot-sliding, speed-js, sscp, coverage, kinds (needs --kinds-data);
    /// groups: all (kinds only with --kinds-data), stochastic, plausibility.
    #[cfg_attr(feature = "clap", arg(long, default_value = "all"))]
    pub metrics: String,
    /// Output directory for report.json and the plots (must not exist or be empty).
    #[cfg_attr(feature = "clap", arg(long))]
    pub out: PathBuf,
    /// Also write each baseline as a forecast directory DIR/NAME (viewable with socdiff view).
    #[cfg_attr(feature = "clap", arg(long, value_name = "DIR"))]
    pub write_baselines: Option<PathBuf>,
    /// Split of the reference whose motion the nearest-continuation baseline continues.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "train"))]
    pub continuation_split: Split,
    /// Split whose motion words form the NDMS database (default: --split, as METHOD.md §5).
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub ndms_database: Option<Split>,
    /// MPJPE horizons in seconds (comma-separated).
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ',', default_value = "1,2,3"))]
    pub horizons: Vec<f64>,
    /// Seconds of forecast scored by APD, ADE, FDE, MMADE and MMFDE.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 3.0))]
    pub stochastic_horizon: f64,
    /// Body-frame pose distance (m) under which another observation's future counts for
    /// MMADE/MMFDE.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 0.5))]
    pub mm_threshold: f64,
    /// Cut forecasts that run past the end of their reference scene instead of failing.
    #[cfg_attr(feature = "clap", arg(long, conflicts_with = "score_past_recording"))]
    pub crop: bool,
    /// Score forecasts that run past the end of their reference scene whole (a minute from a
    /// short recording): pose errors on the recorded part, NDMS and plausibility on every frame.
    #[cfg_attr(feature = "clap", arg(long))]
    pub score_past_recording: bool,
    /// Joints of NDMS motion words (and of the nearest-continuation search): default (head,
    /// shoulders, elbows, wrists, knees, ankles, found by name), all, or comma-separated names.
    #[cfg_attr(feature = "clap", arg(long, value_name = "NAMES|all|default", default_value = "default"))]
    pub ndms_joints: String,
    #[cfg_attr(feature = "clap", command(flatten))]
    pub align: crate::data::import::AlignArgs,
    /// Speaking and buyer classifiers (`socdiff classifier train --out DIR`): SSCP uses a scene's
    /// own speaking signal and roles where present and classifies the rest (forecast samples).
    #[cfg_attr(feature = "clap", arg(long, value_name = "DIR"))]
    pub classifiers: Option<PathBuf>,
}

/// `(label, dir)` of one `forecasts` value.
fn parse_forecast(spec: &str) -> Result<(String, PathBuf)> {
    let (label, dir) = match spec.split_once('=') {
        Some((l, d)) if !l.trim().is_empty() && !d.trim().is_empty() => (l.trim().to_string(), PathBuf::from(d.trim())),
        Some(_) => return Err(Error::invalid(format!("`forecasts` {spec:?}: expected DIR or LABEL=DIR"))),
        None => {
            let dir = PathBuf::from(spec.trim());
            let label = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| spec.trim().to_string());
            (label, dir)
        }
    };
    crate::files::check_name("`forecasts` label", &label)?;
    Ok((label, dir))
}

impl EvalArgs {
    /// The job these options describe (not yet [`EvalJob::check`]ed).
    pub fn job(&self) -> Result<EvalJob> {
        // Everything that can be checked cheaply first: nothing is computed for a bad command.
        let mut metrics = Metric::parse_list(&self.metrics)?;
        if self.kinds_data.is_some() && self.metrics.split(',').any(|m| m.trim() == "all") && !metrics.contains(&Metric::Kinds) {
            metrics.push(Metric::Kinds);
        }
        let baselines = match &self.baselines {
            Some(b) => Baseline::parse_list(b)?,
            None => Vec::new(),
        };
        let horizon = match self.horizon.as_str() {
            "all" => None,
            h => Some(
                h.parse::<usize>()
                    .ok()
                    .filter(|&h| h > 0)
                    .ok_or_else(|| Error::invalid(format!("`horizon` {h:?}: expected a positive number of frames or all")))?,
            ),
        };
        let mut forecasts: Vec<(String, Vec<PathBuf>)> = Vec::new();
        for spec in self.forecasts.iter().filter(|s| !s.trim().is_empty()) {
            let (label, dir) = parse_forecast(spec)?;
            match forecasts.iter_mut().find(|(l, _)| *l == label) {
                Some((_, dirs)) => dirs.push(dir),
                None => forecasts.push((label, vec![dir])),
            }
        }
        Ok(EvalJob {
            reference: self.reference.clone(),
            split: self.split,
            import: self.align.options(),
            forecasts,
            generated: self.generated.iter().filter(|s| !s.trim().is_empty()).map(|s| parse_forecast(s)).collect::<Result<_>>()?,
            generated_split: self.generated_split,
            nearest_named: self.baselines.as_deref().is_some_and(|b| b.split(',').any(|x| x.trim() == "nearest")),
            baselines,
            observe: self.observe,
            horizon,
            continuation_split: self.continuation_split,
            past: match (self.crop, self.score_past_recording) {
                (true, _) => PastRecording::Crop,
                (_, true) => PastRecording::Score,
                _ => PastRecording::Refuse,
            },
            kinds_data: self.kinds_data.clone(),
            classifiers: self.classifiers.clone(),
            config: EvalConfig {
                metrics,
                horizons_s: self.horizons.clone(),
                ndms_database: self.ndms_database,
                ndms: NdmsConfig { joints: NdmsJoints::parse(&self.ndms_joints)?, ..Default::default() },
                stochastic_horizon_s: self.stochastic_horizon,
                multimodal_threshold: self.mm_threshold,
                ..Default::default()
            },
        })
    }
}

/// The scored methods, the report and the notes about what was skipped.
pub struct EvalOutcome {
    /// Every method, forecasts first, then generated datasets, then baselines.
    pub methods: Vec<Method>,
    /// The report (`report.json`, [`Report::table`]).
    pub report: Report,
    /// Metrics or baselines skipped, and why.
    pub notes: Vec<String>,
}

impl EvalJob {
    /// The checks that need no data: something to evaluate, labels that are not baselines, the
    /// motion-kind data for [`Metric::Kinds`], the nearest continuation off the scored split.
    pub fn check(&self) -> Result<()> {
        if self.forecasts.is_empty() && self.baselines.is_empty() && self.generated.is_empty() {
            bail!("nothing to evaluate: give `forecasts`, `generated` and/or `baselines`");
        }
        if let Some(b) = self.baselines.iter().find(|b| self.forecasts.iter().any(|(l, _)| l == b.name())) {
            bail!("`forecasts` label {:?} is also a baseline; pick another label", b.name());
        }
        if self.config.metrics.contains(&Metric::Kinds) && self.kinds_data.is_none() {
            bail!("`metrics` kinds needs `kinds_data` (labelled motion, e.g. ../shared/data/bandai2)");
        }
        if self.baselines.contains(&Baseline::NearestContinuation) && self.continuation_split == self.split {
            bail!("`continuation_split` {} is the scored split: the nearest continuation would copy the ground truth", self.split.as_str());
        }
        Ok(())
    }

    /// Reads everything and scores it; `on_progress` hears what is being done.
    pub fn run(&self, on_progress: &mut dyn FnMut(&Progress)) -> Result<EvalOutcome> {
        self.check()?;
        let stage = |what: String, on_progress: &mut dyn FnMut(&Progress)| on_progress(&Progress { stage: what, done: 0, total: 1 });
        stage(format!("reading {}", self.reference.display()), on_progress);
        let reference = Reference::load_with(&self.reference, self.split, &self.import)?;
        let (mut baselines, mut cfg, mut notes) = (self.baselines.clone(), self.config.clone(), Vec::new());
        // A skeleton without the default NDMS joints (say an upper body): with the default
        // joints, NDMS and the nearest continuation (found by motion words) are skipped, saying
        // so; joints that were asked for must resolve.
        if let Err(e) = cfg.ndms.joints.resolve(reference.skeleton()) {
            if cfg.ndms.joints != NdmsJoints::Default || self.nearest_named {
                return Err(Error::invalid(format!("{e} (`ndms_joints`)")));
            }
            if baselines.contains(&Baseline::NearestContinuation) {
                notes.push(format!("nearest-continuation baseline skipped: {e} (`ndms_joints`)"));
                baselines.retain(|b| *b != Baseline::NearestContinuation);
            }
            for (m, what) in [(Metric::Ndms, "NDMS"), (Metric::Coverage, "coverage (motion words)")] {
                if cfg.metrics.contains(&m) {
                    notes.push(format!("{what} skipped: {e} (`ndms_joints`)"));
                    cfg.metrics.retain(|x| *x != m);
                }
            }
        }
        let mut methods = Vec::new();
        for (label, dirs) in &self.forecasts {
            stage(format!("reading {label}"), on_progress);
            methods.push(Method::from_dirs(label, dirs, &reference, self.observe, self.past)?);
        }
        let lead = cfg.ndms.word_length.unwrap_or_else(|| crate::metrics::word_length_for_fps(reference.fps()));
        for (label, dir) in &self.generated {
            stage(format!("reading {label}"), on_progress);
            methods.push(Method::from_generated(label, dir, &reference, lead, self.generated_split)?);
        }
        let continuation_db = if baselines.contains(&Baseline::NearestContinuation) {
            let scenes = reference.split_scenes(self.continuation_split);
            if scenes.is_empty() {
                let split = self.continuation_split.as_str();
                return Err(Error::format(&self.reference, format!("has no {split} sequences for the nearest-continuation baseline (`continuation_split`)")));
            }
            stage(format!("building the {} database for nearest continuation", self.continuation_split.as_str()), on_progress);
            Some(NdmsDatabase::build(&scenes, &cfg.ndms).map_err(|e| Error::invalid(format!("{e} (`ndms_joints`)")))?)
        } else {
            None
        };
        for b in &baselines {
            stage(format!("baseline {}", b.name()), on_progress);
            let mut m = Method::baseline(*b, &reference, self.observe, self.horizon, continuation_db.as_ref())?;
            if *b == Baseline::NearestContinuation {
                m.settings.insert("continuation_split".into(), self.continuation_split.as_str().into());
            }
            methods.push(m);
        }
        if let Some(dir) = &self.kinds_data {
            if cfg.metrics.contains(&Metric::Kinds) {
                stage(format!("training the motion-kind classifier on {}", dir.display()), on_progress);
                let ds = import::load(dir, &Default::default())?;
                let clf = MotionKindClassifier::train_on_names(&ds, Split::Train, &KindTraining::default()).map_err(|e| e.in_file(dir))?;
                cfg.kinds = Some(Arc::new(clf));
            }
        }
        let classifiers = self.classifiers.as_ref().map(SocialSignalClassifiers::load).transpose()?;
        let annotate = classifiers.as_ref().map(|c| move |s: &Scene| c.annotate(s));
        let name = self.classifiers.as_ref().map(|p| p.display().to_string()).unwrap_or_default();
        let signals = match &annotate {
            Some(f) => SignalSource::Classified { name: &name, annotate: f },
            None => SignalSource::Annotations,
        };
        let mut report = evaluate(&reference, &methods, &cfg, signals, &mut |p| on_progress(p))?;
        let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
        report.provenance.insert("created_unix_s".into(), now.into());
        report.settings.insert("observe_baselines_and_datasets".into(), self.observe.into());
        report.settings.insert("horizon_baselines".into(), self.horizon.map_or("all".to_string(), |h| h.to_string()).into());
        report.settings.insert("crop".into(), (self.past == PastRecording::Crop).into());
        report.settings.insert("score_past_recording".into(), (self.past == PastRecording::Score).into());
        Ok(EvalOutcome { methods, report, notes })
    }
}

impl EvalOutcome {
    /// Writes `report.json` and the plots into the new directory `out`, and the baselines'
    /// forecasts (one forecast directory each) into the new directory `baselines`; both are
    /// written whole or not at all. Returns the plots written.
    pub fn write(&self, out: &Path, baselines: Option<&Path>) -> Result<Vec<PathBuf>> {
        let plots = write_dir_atomic(out, |dir| {
            let path = dir.join("report.json");
            std::fs::write(&path, self.report.to_json()).map_err(|e| Error::io(&path, e))?;
            write_plots(&self.report, dir)
        })?;
        if let Some(w) = baselines {
            write_dir_atomic(w, |dir| {
                for m in self.methods.iter().filter(|m| matches!(m.kind, MethodKind::Baseline(_))) {
                    write_dataset(&m.to_dataset()?, &dir.join(safe_file_name(&m.label)))?;
                }
                Ok(())
            })?;
        }
        Ok(plots)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn job() -> EvalJob {
        EvalJob {
            reference: PathBuf::from("ref"),
            split: Split::Test,
            import: Default::default(),
            forecasts: Vec::new(),
            generated: Vec::new(),
            generated_split: None,
            baselines: vec![Baseline::ZeroVelocity],
            nearest_named: false,
            observe: 30,
            horizon: None,
            continuation_split: Split::Train,
            past: PastRecording::Refuse,
            kinds_data: None,
            classifiers: None,
            config: EvalConfig::default(),
        }
    }

    #[test]
    fn checks_refuse_jobs_that_would_mislead() {
        assert!(job().check().is_ok());
        let err = |j: EvalJob| j.check().unwrap_err().to_string();
        assert!(err(EvalJob { baselines: vec![], ..job() }).contains("nothing to evaluate"));
        let copy = EvalJob { baselines: vec![Baseline::NearestContinuation], continuation_split: Split::Test, ..job() };
        assert!(err(copy.clone()).contains("would copy the ground truth"), "{}", err(copy));
        assert!(EvalJob { baselines: vec![Baseline::NearestContinuation], ..job() }.check().is_ok());
        let clash = EvalJob { forecasts: vec![("zero-velocity".into(), vec![PathBuf::from("f")])], ..job() };
        assert!(err(clash).contains("also a baseline"));
        let kinds = EvalJob { config: EvalConfig { metrics: vec![Metric::Kinds], ..Default::default() }, ..job() };
        assert!(err(kinds).contains("`kinds_data`"));
        // run() makes the same checks before reading anything (the reference does not exist).
        let Err(e) = EvalJob { baselines: vec![], ..job() }.run(&mut |_| {}) else { panic!("ran") };
        assert!(e.to_string().contains("nothing to evaluate"), "{e}");
    }
}
