//! Field-by-field overrides of a [`TrainConfig`] (the last layer of defaults ← file ←
//! overrides; `socdiff train`'s options) and the training data of one or several sources.

use super::data::{describe_mix, mix_sources, MixConfig};
#[cfg(test)]
use crate::checkpoint::config::PersonRange;
use crate::checkpoint::config::TrainConfig;
use crate::data::import::{self, ImportOptions};
use crate::model::Aggregator;
use crate::{bail, Dataset, Result};
use std::path::PathBuf;

/// The settings every training run has (the denoiser's and the classifiers'), to change field by
/// field; `None` keeps the field.
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct RunOverrides {
    /// Total optimizer steps of the run (a resumed run continues up to this count).
    #[cfg_attr(feature = "clap", arg(long))]
    pub steps: Option<usize>,
    /// Windows per batch.
    #[cfg_attr(feature = "clap", arg(long))]
    pub batch: Option<usize>,
    /// Frames per training window (the classifiers': also per inference window).
    #[cfg_attr(feature = "clap", arg(long))]
    pub window: Option<usize>,
    /// Network width: the U-Net's H (also the social width, unless the config sets
    /// model.social_dim apart from model.hidden); the classifiers' GRU width per direction
    /// (also their embedding and message width).
    #[cfg_attr(feature = "clap", arg(long))]
    pub hidden: Option<usize>,
    /// Learning rate.
    #[cfg_attr(feature = "clap", arg(long))]
    pub lr: Option<f64>,
    /// Seed of initialization, batch order, timesteps and noise.
    #[cfg_attr(feature = "clap", arg(long))]
    pub seed: Option<u64>,
    /// Checkpoint every N steps (and at the end, and on Ctrl-C).
    #[cfg_attr(feature = "clap", arg(long))]
    pub save_every: Option<usize>,
}

/// The most-used settings of a [`TrainConfig`], as `socdiff train`'s options; `None` keeps the
/// field (a resumed run keeps its config). Every other field (noise levels, pose encoding,
/// augmentation, loss, …) is set in a `--config` file (docs/guide.md lists them).
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct TrainOverrides {
    #[cfg_attr(feature = "clap", command(flatten))]
    pub run: RunOverrides,
    /// Train for this many minutes of wall-clock time in all (a resume continues the same
    /// budget), then save and stop; --steps still caps the run.
    #[cfg_attr(feature = "clap", arg(long, value_name = "M"))]
    pub minutes: Option<f64>,
    /// How persons share information: none, mean or attention (`socdiff ablate --aggregators`;
    /// for `train`, the config field `model.aggregator`).
    #[cfg_attr(feature = "clap", arg(skip))]
    pub aggregator: Option<Aggregator>,
    /// Validation loss every N steps (0: never).
    #[cfg_attr(feature = "clap", arg(long))]
    pub val_every: Option<usize>,
}

/// The step cap of a run given only `--minutes`: far beyond what any budget reaches.
pub const MINUTES_STEP_CAP: usize = 10_000_000;

impl TrainOverrides {
    /// Sets the fields that are given (the rest of `cfg` is kept) and validates the result.
    pub fn apply(&self, cfg: &mut TrainConfig) -> Result<()> {
        let set = |field: &mut usize, v: Option<usize>| {
            if let Some(v) = v {
                *field = v;
            }
        };
        let run = &self.run;
        set(&mut cfg.steps, run.steps);
        set(&mut cfg.batch, run.batch);
        set(&mut cfg.window, run.window);
        set(&mut cfg.save_every, run.save_every);
        set(&mut cfg.val_every, self.val_every);
        cfg.seed = run.seed.unwrap_or(cfg.seed);
        if let Some(m) = self.minutes {
            cfg.minutes = Some(m);
            // A time budget is the run's length: the step count only caps it.
            if run.steps.is_none() {
                cfg.steps = cfg.steps.max(MINUTES_STEP_CAP);
            }
        }
        cfg.adam.lr = run.lr.unwrap_or(cfg.adam.lr);
        if let Some(h) = run.hidden {
            // The social width follows the U-Net width unless it was set apart from it.
            if cfg.model.social_dim == cfg.model.hidden {
                cfg.model.social_dim = h;
            }
            cfg.model.hidden = h;
        }
        if let Some(agg) = self.aggregator {
            // Attention keeps the heads a config file gave it.
            cfg.model.aggregator = match (agg, cfg.model.aggregator) {
                (Aggregator::Attention { .. }, Aggregator::Attention { heads }) => Aggregator::Attention { heads },
                (agg, _) => agg,
            };
        }
        cfg.validate()
    }
}

/// The training data: one source, or several mixed into one training set ([`mix_sources`], as
/// the config's `mix` says).
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct TrainSources {
    /// Training data: a dataset directory (train split; validation on the test split), or any
    /// file `socdiff data` reads (.bvh, Haggling .pkl). Repeat to train on several sources: the
    /// first sets the skeleton, fps and validation data; the others' train splits are mapped
    /// onto its skeleton by joint names, and single-person sources become synthetic groups.
    #[cfg_attr(feature = "clap", arg(long, required = true))]
    pub data: Vec<PathBuf>,
}

/// What [`TrainSources::load`] made.
pub struct TrainingData {
    /// The training set.
    pub dataset: Dataset,
    /// The sources, for the checkpoint.
    pub source: String,
    /// What became of each source (several sources only), for the user.
    pub notes: Vec<String>,
}

impl TrainSources {
    /// Loads every source and, with several, mixes them ([`mix_sources`], the groups drawn from
    /// `cfg`'s seed and window, so a resumed mix is rebuilt with the same windows).
    pub fn load(&self, cfg: &TrainConfig, opts: &ImportOptions) -> Result<TrainingData> {
        if self.data.is_empty() {
            bail!("training: no data sources");
        }
        let sets: Vec<Dataset> = self.data.iter().map(|p| import::load(p, opts)).collect::<Result<_>>()?;
        if sets.len() == 1 {
            let dataset = sets.into_iter().next().expect("one source");
            return Ok(TrainingData { dataset, source: self.data[0].display().to_string(), notes: Vec::new() });
        }
        let m = &cfg.mix;
        let mut mix = MixConfig { primary_repeat: m.repeat_first, ..MixConfig::for_primary(&sets[0], cfg.window, m.synthetic_groups, cfg.seed) };
        if let Some(r) = m.group_persons {
            (mix.groups.persons_min, mix.groups.persons_max) = (r.min, r.max);
        }
        mix.groups.frames = m.group_frames.unwrap_or(mix.groups.frames);
        let (dataset, summary) = mix_sources(&sets, &mix)?;
        let mut notes = Vec::new();
        for (src, path) in summary.iter().zip(&self.data) {
            notes.push(format!("data {}: {} ({}), {} train scenes, {} frames", src.name, path.display(), src.kind, src.scenes, src.frames));
            let derived: Vec<&String> = src.joint_map.iter().filter(|l| l.contains("midpoint") || l.contains("body frame")).collect();
            if !src.joint_map.is_empty() {
                notes.push(format!(
                    "  joints mapped by name onto the first source's skeleton: {} copied, {} derived",
                    src.joint_map.len() - derived.len(),
                    derived.len()
                ));
            }
            notes.extend(derived.into_iter().map(|l| format!("  {l}")));
        }
        let labels: Vec<String> = self.data.iter().map(|p| p.display().to_string()).collect();
        Ok(TrainingData { dataset, source: describe_mix(&labels, &summary, &mix), notes })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::DenoiserConfig;

    #[test]
    fn overrides_set_their_fields_only() {
        let a = TrainOverrides {
            run: RunOverrides { steps: Some(5), hidden: Some(32), lr: Some(0.001), ..Default::default() },
            aggregator: Some(Aggregator::Attention { heads: Aggregator::DEFAULT_HEADS }),
            val_every: Some(7),
            minutes: None,
        };
        let base = TrainConfig { batch: 7, ..TrainConfig::default() };
        let mut cfg = base.clone();
        a.apply(&mut cfg).unwrap();
        let m = &cfg.model;
        assert_eq!((cfg.steps, cfg.batch, cfg.val_every, cfg.adam.lr), (5, 7, 7, 0.001));
        assert_eq!(cfg.adam, crate::train::AdamConfig { lr: 0.001, ..base.adam.clone() });
        assert_eq!((m.hidden, m.social_dim, m.aggregator), (32, 32, Aggregator::Attention { heads: Aggregator::DEFAULT_HEADS }));
        // A social width set apart from the U-Net width (say by a config file) is kept, and so
        // are the attention heads a config file gave.
        let mut apart = TrainConfig {
            model: DenoiserConfig { social_dim: 64, aggregator: Aggregator::Attention { heads: 2 }, ..Default::default() },
            ..TrainConfig::default()
        };
        a.apply(&mut apart).unwrap();
        assert_eq!((apart.model.hidden, apart.model.social_dim, apart.model.aggregator), (32, 64, Aggregator::Attention { heads: 2 }));
        // Nothing given: nothing changes (a resumed run keeps its config).
        let mut same = base.clone();
        TrainOverrides::default().apply(&mut same).unwrap();
        assert_eq!(same, base);
        let err = |o: TrainOverrides| o.apply(&mut base.clone()).unwrap_err().to_string();
        assert!(err(TrainOverrides { run: RunOverrides { batch: Some(0), ..Default::default() }, ..Default::default() }).contains("batch must be at least 1"));
        let mut none = base.clone();
        TrainOverrides { aggregator: Some(Aggregator::None), ..Default::default() }.apply(&mut none).unwrap();
        assert_eq!(none.model.aggregator, Aggregator::None);
    }

    /// The settings that are no flags are config-file fields, each setting only itself.
    #[test]
    fn config_fields_set_what_the_flags_do_not() {
        use crate::diffusion::{LossNorm, Prediction};
        use serde_json::json;
        let base = TrainConfig::default();
        let with = |v: serde_json::Value| base.with_json(&v).unwrap();
        let squared = with(json!({"diffusion": {"loss": "l2"}}));
        assert_eq!(squared, TrainConfig { diffusion: crate::diffusion::DiffusionConfig { loss: LossNorm::L2, ..base.diffusion.clone() }, ..base.clone() });
        assert_eq!(with(json!({"diffusion": {"prediction": "v"}})).diffusion.prediction, Prediction::V);
        assert_eq!(with(json!({"diffusion": {"snr_shift": 3.0}})).diffusion.snr_shift, 3.0);
        assert!(base.with_json(&json!({"diffusion": {"snr_shift": 0.0}})).unwrap_err().to_string().contains("snr_shift must be finite and > 0"));
        let ahead = with(json!({"model": {"causality": "lookahead"}}));
        assert_eq!((ahead.model.causality, ahead.model.causality.frames_ahead()), (crate::model::Causality::Lookahead, 30));
        assert_eq!(TrainConfig { model: base.model.clone(), ..ahead }, base, "only the model's causality changes");
        let cosine = with(json!({"adam": {"schedule": "cosine"}}));
        assert_eq!(cosine.adam, crate::train::AdamConfig { schedule: crate::train::LrSchedule::Cosine, ..base.adam.clone() });
        let mix = with(json!({"mix": {"synthetic_groups": 50, "group_persons": {"min": 2, "max": 3}, "repeat_first": 2}}));
        assert_eq!(
            (mix.mix.synthetic_groups, mix.mix.group_persons, mix.mix.group_frames, mix.mix.repeat_first),
            (50, Some(PersonRange { min: 2, max: 3 }), None, 2)
        );
        assert!(base.with_json(&json!({"augment": {"body_scale": 0.7}})).unwrap_err().to_string().contains("body_scale"));
    }
}
