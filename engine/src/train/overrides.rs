//! Field-by-field overrides of a [`TrainConfig`] (the last layer of defaults ← file ←
//! overrides; `socdiff train`'s options) and the training data of one or several sources.

use super::config::{NoiseLevels, PersonRange, TrainConfig, WindowBalance};
use super::data::{describe_mix, mix_sources, MixConfig};
use crate::data::import::{self, ImportOptions};
use crate::features::PoseEncoding;
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
    /// Learning rate (the peak, with --lr-schedule cosine).
    #[cfg_attr(feature = "clap", arg(long))]
    pub lr: Option<f64>,
    /// How the learning rate moves over --steps: constant (the paper) or cosine (half a cosine
    /// from --lr down to zero at the last step, so a run of known length ends annealed).
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub lr_schedule: Option<super::config::LrSchedule>,
    /// Seed of initialization, batch order, timesteps and noise.
    #[cfg_attr(feature = "clap", arg(long))]
    pub seed: Option<u64>,
    /// Checkpoint every N steps (and at the end, and on Ctrl-C).
    #[cfg_attr(feature = "clap", arg(long))]
    pub save_every: Option<usize>,
}

/// Settings to change in a [`TrainConfig`]; `None` keeps the field (a resumed run keeps its
/// config). Defaults are METHOD.md §4's (batch 64 windows of 512 frames at stride 10, hidden
/// 192, cosine T = 1000, Adam 1e-4, EMA 0.995); see `config.json` of a run for every field.
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct TrainOverrides {
    #[cfg_attr(feature = "clap", command(flatten))]
    pub run: RunOverrides,
    /// Frames between window starts.
    #[cfg_attr(feature = "clap", arg(long))]
    pub stride: Option<usize>,
    /// Observed frames per window: persons are anchored at the last one (default window/4).
    #[cfg_attr(feature = "clap", arg(long))]
    pub observed: Option<usize>,
    /// How persons share information: none, mean or attention.
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub aggregator: Option<Aggregator>,
    /// Attention heads (with --aggregator attention; default 4).
    #[cfg_attr(feature = "clap", arg(long))]
    pub heads: Option<usize>,
    /// Train on person subsets of at least this many persons (with --persons-max).
    #[cfg_attr(feature = "clap", arg(long))]
    pub persons_min: Option<usize>,
    /// Train on person subsets of at most this many persons (with --persons-min).
    #[cfg_attr(feature = "clap", arg(long))]
    pub persons_max: Option<usize>,
    /// Noise levels of a window: uniform (one t per window, the paper), prefix (a clean
    /// prefix, one t after it), per-frame or per-frame-monotone (one t per person and frame,
    /// Diffusion Forcing). Saved in the checkpoint; sampling then gives known frames level 0.
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub noise: Option<NoiseLevels>,
    /// Local joints as they are (absolute, the paper) or as offsets from each person's pose at
    /// the last observed frame (residual: standing still is zero, body proportions are kept).
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub pose: Option<PoseEncoding>,
    /// How an epoch draws its windows: windows (each once, the paper) or sequences (each
    /// sequence equally likely whatever its length, with replacement).
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub balance: Option<WindowBalance>,
    /// Weight of the loss's velocity term: errors of frame-to-frame changes, each dim on the
    /// scale of its changes in the training windows (0: off, the paper; uniform noise only).
    #[cfg_attr(feature = "clap", arg(long, value_name = "W"))]
    pub velocity_loss: Option<f64>,
    /// What the network outputs: x0 (the clean signal, the paper), v (√ᾱ·ε − √(1 − ᾱ)·x0, so
    /// that at low noise the input passes through and only a correction is learned; trained on
    /// the L1 of v̂ − v) or edm (the input passes through below the noise level --sigma-data,
    /// the clean signal is predicted above it). Saved in the checkpoint; sampling turns each
    /// into x̂0.
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub prediction: Option<crate::diffusion::Prediction>,
    /// σ_d of `--prediction edm` and `--input-scaling wiener`: the signal's spread in
    /// standardized units, the noise level below which the input passes through (default 0.5;
    /// edm with 1 is v). Saved in the checkpoint.
    #[cfg_attr(feature = "clap", arg(long, value_name = "S"))]
    pub sigma_data: Option<f64>,
    /// What the network is shown of x_t: none (x_t itself, the paper) or wiener (x_t times the
    /// least-squares gain of x0 for a signal of spread --sigma-data: near 1 at low noise, near 0
    /// at high noise). Saved in the checkpoint.
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub input_scaling: Option<crate::diffusion::InputScaling>,
    /// Noise the schedule as if the data were S times coarser: every signal-to-noise ratio
    /// divided by S² (Hoogeboom et al. 2023), so that a window's slow components (where a
    /// person goes, how fast) are decided over more of the sampling steps (default 1: the
    /// paper's cosine schedule). Saved in the checkpoint.
    #[cfg_attr(feature = "clap", arg(long, value_name = "S"))]
    pub snr_shift: Option<f64>,
    /// How the loss weighs an error: l1 (mean absolute error, the paper; x̂0 learns the
    /// posterior's median) or l2 (mean squared error; x̂0 learns its mean, which DDPM and DDIM
    /// assume). Also the velocity term's norm. Saved in the checkpoint.
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub loss: Option<crate::diffusion::LossNorm>,
    /// Which noisy frames the denoiser reads for frame t: causal (frames ≤ t, the paper) or
    /// lookahead (frames ≤ t + 30: each residual block's first conv centred), for generation
    /// and gap filling. Saved in the checkpoint.
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub causality: Option<crate::model::Causality>,
    /// Bodies it has not seen: scale each person's skeleton by a factor in 1 ± X per window
    /// (0.1 spans real adults) …
    #[cfg_attr(feature = "clap", arg(long, value_name = "X"))]
    pub body_scale: Option<f64>,
    /// … and each limb (left and right alike) by a further factor in 1 ± X.
    #[cfg_attr(feature = "clap", arg(long, value_name = "X"))]
    pub limb_scale: Option<f64>,
    /// Validation loss every N steps (0: never).
    #[cfg_attr(feature = "clap", arg(long))]
    pub val_every: Option<usize>,
}

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
        set(&mut cfg.stride, self.stride);
        set(&mut cfg.save_every, run.save_every);
        set(&mut cfg.val_every, self.val_every);
        cfg.observed = self.observed.or(cfg.observed);
        cfg.seed = run.seed.unwrap_or(cfg.seed);
        cfg.adam.lr = run.lr.unwrap_or(cfg.adam.lr);
        cfg.adam.schedule = run.lr_schedule.unwrap_or(cfg.adam.schedule);
        for (name, v, field) in [("body_scale", self.body_scale, &mut cfg.augment.body_scale), ("limb_scale", self.limb_scale, &mut cfg.augment.limb_scale)] {
            if let Some(v) = v {
                if !(0.0..0.5).contains(&v) {
                    bail!("`{name}` {v}: expected a spread in [0, 0.5)");
                }
                *field = v;
            }
        }
        cfg.pose = self.pose.unwrap_or(cfg.pose);
        cfg.noise = self.noise.unwrap_or(cfg.noise);
        cfg.balance = self.balance.unwrap_or(cfg.balance);
        cfg.velocity_loss = self.velocity_loss.unwrap_or(cfg.velocity_loss);
        cfg.diffusion.prediction = self.prediction.unwrap_or(cfg.diffusion.prediction);
        cfg.diffusion.sigma_data = self.sigma_data.unwrap_or(cfg.diffusion.sigma_data);
        cfg.diffusion.input_scaling = self.input_scaling.unwrap_or(cfg.diffusion.input_scaling);
        cfg.diffusion.snr_shift = self.snr_shift.unwrap_or(cfg.diffusion.snr_shift);
        cfg.diffusion.loss = self.loss.unwrap_or(cfg.diffusion.loss);
        cfg.model.causality = self.causality.unwrap_or(cfg.model.causality);
        match (self.persons_min, self.persons_max) {
            (Some(min), Some(max)) => cfg.persons = Some(PersonRange { min, max }),
            (None, None) => {}
            _ => bail!("`persons_min` and `persons_max` go together"),
        }
        if let Some(h) = run.hidden {
            // The social width follows the U-Net width unless it was set apart from it.
            if cfg.model.social_dim == cfg.model.hidden {
                cfg.model.social_dim = h;
            }
            cfg.model.hidden = h;
        }
        match (self.aggregator, self.heads) {
            (Some(agg), heads) => cfg.model.aggregator = heads.map_or(Ok(agg), |h| agg.with_heads(h))?,
            (None, Some(_)) => bail!("`heads` needs `aggregator` attention"),
            (None, None) => {}
        }
        cfg.validate()
    }
}

/// The training data: one source, or several mixed into one training set ([`mix_sources`]).
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct TrainSources {
    /// Training data: a dataset directory (train split; validation on the test split), or any
    /// file `socdiff data` reads (.bvh, Haggling .pkl). Repeat to train on several sources: the
    /// first sets the skeleton, fps and validation data; the others' train splits are mapped
    /// onto its skeleton by joint names, and single-person sources become synthetic groups.
    #[cfg_attr(feature = "clap", arg(long, required = true))]
    pub data: Vec<PathBuf>,
    /// With several --data: synthetic groups built from each single-person source.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 200))]
    pub synthetic_groups: usize,
    /// With several --data: persons per synthetic group, MIN..MAX or N (default: the person
    /// counts of the first source's train scenes).
    #[cfg_attr(feature = "clap", arg(long, value_parser = parse_person_range))]
    pub group_persons: Option<PersonRange>,
    /// With several --data: frames per synthetic group (default: twice the window, at least 300).
    #[cfg_attr(feature = "clap", arg(long))]
    pub group_frames: Option<usize>,
    /// With several --data: the first source's train scenes count this many times.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 1))]
    pub repeat_first: usize,
}

/// `MIN..MAX` (also `MIN..=MAX`) or `N`, with 1 ≤ MIN ≤ MAX.
pub fn parse_person_range(spec: &str) -> std::result::Result<PersonRange, String> {
    let bad = || format!("{spec:?}: expected MIN..MAX (e.g. 2..3) or N");
    let (a, b) = spec.split_once("..").unwrap_or((spec, spec));
    let (min, max): (usize, usize) = (a.trim().parse().map_err(|_| bad())?, b.trim().trim_start_matches('=').parse().map_err(|_| bad())?);
    if min == 0 || min > max {
        return Err(bad());
    }
    Ok(PersonRange { min, max })
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
        let mut mix = MixConfig { primary_repeat: self.repeat_first, ..MixConfig::for_primary(&sets[0], cfg.window, self.synthetic_groups, cfg.seed) };
        if let Some(r) = self.group_persons {
            (mix.groups.persons_min, mix.groups.persons_max) = (r.min, r.max);
        }
        mix.groups.frames = self.group_frames.unwrap_or(mix.groups.frames);
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
            run: RunOverrides { steps: Some(5), hidden: Some(32), lr: Some(0.001), lr_schedule: Some(crate::train::LrSchedule::Cosine), ..Default::default() },
            aggregator: Some(Aggregator::Attention { heads: Aggregator::DEFAULT_HEADS }),
            persons_min: Some(2),
            persons_max: Some(3),
            ..Default::default()
        };
        let base = TrainConfig { batch: 7, ..TrainConfig::default() };
        let mut cfg = base.clone();
        a.apply(&mut cfg).unwrap();
        let m = &cfg.model;
        assert_eq!((cfg.steps, cfg.batch, cfg.persons, cfg.adam.lr), (5, 7, Some(PersonRange { min: 2, max: 3 }), 0.001));
        assert_eq!(cfg.adam, crate::train::AdamConfig { lr: 0.001, schedule: crate::train::LrSchedule::Cosine, ..base.adam.clone() });
        assert_eq!((m.hidden, m.social_dim, m.aggregator), (32, 32, Aggregator::Attention { heads: Aggregator::DEFAULT_HEADS }));
        // A social width set apart from the U-Net width (say by a config file) is kept.
        let mut apart = TrainConfig { model: DenoiserConfig { social_dim: 64, ..Default::default() }, ..TrainConfig::default() };
        a.apply(&mut apart).unwrap();
        assert_eq!((apart.model.hidden, apart.model.social_dim), (32, 64));
        // Nothing given: nothing changes (a resumed run keeps its config).
        let mut same = base.clone();
        TrainOverrides::default().apply(&mut same).unwrap();
        assert_eq!(same, base);
        let err = |o: TrainOverrides| o.apply(&mut base.clone()).unwrap_err().to_string();
        assert!(err(TrainOverrides { persons_min: Some(2), ..Default::default() }).contains("go together"));
        assert!(err(TrainOverrides { heads: Some(2), ..Default::default() }).contains("`aggregator` attention"));
        assert!(err(TrainOverrides { body_scale: Some(0.7), ..Default::default() }).contains("`body_scale` 0.7"));
        assert!(err(TrainOverrides { run: RunOverrides { batch: Some(0), ..Default::default() }, ..Default::default() }).contains("batch must be at least 1"));
        let mut none = base.clone();
        TrainOverrides { aggregator: Some(Aggregator::None), ..Default::default() }.apply(&mut none).unwrap();
        assert_eq!(none.model.aggregator, Aggregator::None);
        let mut v = base.clone();
        TrainOverrides { prediction: Some(crate::diffusion::Prediction::V), ..Default::default() }.apply(&mut v).unwrap();
        assert_eq!((v.diffusion.prediction, TrainConfig { diffusion: v.diffusion.clone(), ..base.clone() }), (crate::diffusion::Prediction::V, v.clone()));
        let mut squared = base.clone();
        TrainOverrides { loss: Some(crate::diffusion::LossNorm::L2), ..Default::default() }.apply(&mut squared).unwrap();
        let only_loss =
            TrainConfig { diffusion: crate::diffusion::DiffusionConfig { loss: crate::diffusion::LossNorm::L2, ..base.diffusion.clone() }, ..base.clone() };
        assert_eq!(squared, only_loss);
        let mut shifted = base.clone();
        TrainOverrides { snr_shift: Some(3.0), ..Default::default() }.apply(&mut shifted).unwrap();
        assert_eq!(shifted.diffusion.snr_shift, 3.0);
        assert!(err(TrainOverrides { snr_shift: Some(0.0), ..Default::default() }).contains("snr_shift must be finite and > 0"));
        let mut ahead = base.clone();
        TrainOverrides { causality: Some(crate::model::Causality::Lookahead), ..Default::default() }.apply(&mut ahead).unwrap();
        assert_eq!((ahead.model.causality, ahead.model.causality.frames_ahead()), (crate::model::Causality::Lookahead, 30));
        assert_eq!(TrainConfig { model: base.model.clone(), ..ahead }, base, "only the model's causality changes");
    }

    #[test]
    fn person_ranges_parse_or_say_what_is_expected() {
        assert_eq!(parse_person_range("2..3"), Ok(PersonRange { min: 2, max: 3 }));
        assert_eq!(parse_person_range("2..=4"), Ok(PersonRange { min: 2, max: 4 }));
        assert_eq!(parse_person_range(" 3 "), Ok(PersonRange { min: 3, max: 3 }));
        for bad in ["0..2", "3..2", "a", "2..x"] {
            assert!(parse_person_range(bad).unwrap_err().contains("expected MIN..MAX"), "{bad}");
        }
    }
}
