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
