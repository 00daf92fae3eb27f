//! Training configuration (METHOD.md §4): every number of a run, saved in its checkpoint.
//!
//! A config is a typed struct: set its fields in code, or read a JSON file that names any
//! subset of them over a base config ([`TrainConfig::read_over`]: nested objects merge field by
//! field, RFC 7386, and an object with a `kind` key, e.g. the aggregator, replaces the base's).

use crate::diffusion::DiffusionConfig;
use crate::model::DenoiserConfig;
use crate::{bail, Error, Result, Split};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::path::Path;

/// How the learning rate moves over a run's steps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum LrSchedule {
    /// The same rate at every step (the paper).
    #[default]
    Constant,
    /// Half a cosine from the rate at the first step to zero at the run's last
    /// (Loshchilov & Hutter 2017, without restarts): a run of fixed length ends annealed
    /// instead of at full rate. The length is the config's `steps`, so a resume that raises
    /// them stretches the rest of the decay.
    Cosine,
}

/// Adam (Kingma & Ba), as PyTorch's `torch.optim.Adam` without weight decay.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AdamConfig {
    /// Learning rate (1e-4): of every step, or the peak of [`AdamConfig::schedule`].
    pub lr: f64,
    /// How the rate moves over the run (constant).
    pub schedule: LrSchedule,
    /// β1, β2: decay of the first and second moment estimates (0.9, 0.99).
    pub betas: [f64; 2],
    /// ε added to the denominator (1e-8).
    pub eps: f64,
    /// Clip the gradient to this global L2 norm before the update (PyTorch's
    /// `clip_grad_norm_`); `null`: no clipping (the reference's choice, REFERENCE.md §3.2).
    pub clip_norm: Option<f64>,
}

impl Default for AdamConfig {
    fn default() -> Self {
        Self { lr: 1e-4, schedule: LrSchedule::Constant, betas: [0.9, 0.99], eps: 1e-8, clip_norm: None }
    }
}

impl AdamConfig {
    /// The learning rate of the update that follows `done` updates of a run of `total`:
    /// `lr`, or `lr · ½(1 + cos(π·done/total))` on the cosine schedule (zero from `total` on).
    pub fn lr_at(&self, done: u64, total: u64) -> f64 {
        match self.schedule {
            LrSchedule::Constant => self.lr,
            LrSchedule::Cosine => {
                let progress = if total == 0 { 1.0 } else { (done as f64 / total as f64).min(1.0) };
                self.lr * 0.5 * (1.0 + (std::f64::consts::PI * progress).cos())
            }
        }
    }
}

/// Exponential moving average of the weights, used for validation and inference.
///
/// After optimizer step `s` (1-based): `s ≤ warmup_steps` → the EMA is a copy of the online
/// weights; otherwise, when `s` is a multiple of `update_every`, `ema ← decay·ema + (1 − decay)·online`.
/// (The reference also ramps the decay as `1 − (1 + s − 100)^(−2/3)` up to 0.995 over the first
/// ≈ 2.9k steps, REFERENCE.md §3.3; we follow the documented intent, a constant decay after the
/// copy phase.)
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EmaConfig {
    /// Weight of the old average per update (0.995).
    pub decay: f64,
    /// Update every this many steps after the warm-up (10).
    pub update_every: usize,
    /// Steps during which the EMA copies the online weights (100).
    pub warmup_steps: usize,
}

impl Default for EmaConfig {
    fn default() -> Self {
        Self { decay: 0.995, update_every: 10, warmup_steps: 100 }
    }
}

/// Range of persons per training group (the config field `persons`, and `mix.group_persons`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PersonRange {
    /// Fewest persons in a training group (≥ 1).
    pub min: usize,
    /// Most persons in a training group (≥ min).
    pub max: usize,
}

/// Random rigid motions of each training window about the vertical axis (off by default).
///
/// The anchored features are invariant to them by construction, and so are the relative
/// anchors the aggregator sees (`model::aggregator`), so this changes what the network sees
/// only by rounding; it is kept for parity with the reference's (disabled) option and for
/// inputs that may not be invariant in the future.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AugmentConfig {
    /// Rotate each window by a uniform random angle about z.
    pub rotate: bool,
    /// Translate each window by a uniform random offset in `[−translate, translate]²` metres
    /// (0: off).
    pub translate: f64,
    /// Bodies the network has not seen: each person of each window gets its skeleton scaled
    /// by a factor uniform in `1 ± body_scale` (0: off; 0.1 spans the heights of real adults,
    /// about ±2.5 standard deviations) …
    pub body_scale: f64,
    /// … and each limb (a bone and its left/right counterpart, by joint names) by a further
    /// factor uniform in `1 ± limb_scale` (0: off), independently ([`crate::train::data::BoneScaler`]).
    pub limb_scale: f64,
}

/// A starting configuration of a run (`socdiff train --preset`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Preset {
    /// The recipe that measured best (docs/results.md), at a size that learns in minutes on a
    /// CPU: noise levels `prefix`, pose `residual`, body augmentation ±10 % (limbs ±5 %),
    /// hidden 64, windows of 120 frames (a quarter, 30, observed) at stride 5, batch 16, Adam
    /// 1e-3, 10,000 steps.
    #[default]
    Recommended,
    /// The paper's configuration (METHOD.md §4), GPU-sized: hidden 192, windows of 512 frames
    /// (128 observed) at stride 10, batch 64, uniform noise levels, absolute poses, no
    /// augmentation, Adam 1e-4, EMA 0.995, 13,000 steps.
    Paper,
}

impl Preset {
    /// The configuration this preset starts from.
    pub fn config(self) -> TrainConfig {
        match self {
            Preset::Paper => TrainConfig::default(),
            Preset::Recommended => TrainConfig {
                preset: Some(Preset::Recommended),
                model: DenoiserConfig { hidden: 64, social_dim: 64, ..Default::default() },
                steps: 10_000,
                batch: 16,
                window: 120,
                stride: 5,
                adam: AdamConfig { lr: 1e-3, ..Default::default() },
                noise: NoiseLevels::Prefix,
                pose: crate::features::PoseEncoding::Residual,
                augment: AugmentConfig { body_scale: 0.1, limb_scale: 0.05, ..Default::default() },
                save_every: 200,
                ..TrainConfig::default()
            },
        }
    }
}

/// Everything that defines a training run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// The preset the run started from (`null` in runs from before presets).
    #[serde(default)]
    pub preset: Option<Preset>,
    /// The network. `feature_dims` is set from the data's skeleton (4 + 3J).
    pub model: DenoiserConfig,
    /// The diffusion process (cosine, T = 1000).
    pub diffusion: DiffusionConfig,
    /// Total optimizer steps of the run (13 000 ≈ 50 epochs of the Haggling train set, as the
    /// reference).
    pub steps: usize,
    /// A wall-clock budget: the run ends with a checkpoint once it has trained this many
    /// minutes in all (over every resume), or at `steps`, whichever comes first. `null`: steps
    /// only.
    pub minutes: Option<f64>,
    /// Windows per batch (64). The last batch of each person-count group in an epoch may be
    /// smaller.
    pub batch: usize,
    /// Frames per training window (512).
    pub window: usize,
    /// Frames between the starts of consecutive windows (10).
    pub stride: usize,
    /// Observed frames n_obs: each person is anchored at frame `observed − 1` of the window.
    /// `None`: a quarter of the window (128 for 512 frames), at least 1.
    pub observed: Option<usize>,
    /// Person subsets per window (`None`: all persons of each scene).
    pub persons: Option<PersonRange>,
    /// Optimizer.
    pub adam: AdamConfig,
    /// Weight averaging.
    pub ema: EmaConfig,
    /// Seed of the initialization and of every random draw (batch order, t, noise).
    pub seed: u64,
    /// Save a checkpoint every this many steps (and at the end).
    pub save_every: usize,
    /// Validation loss every this many steps (0: never).
    pub val_every: usize,
    /// At most this many validation windows (evenly spaced over all of them).
    pub val_windows: usize,
    /// Split the validation windows come from (test).
    pub val_split: Split,
    /// Longest gap of invalid frames filled by linear interpolation before cutting windows.
    pub max_gap: usize,
    /// Rotation/translation augmentation (off).
    pub augment: AugmentConfig,
    /// How noise levels are drawn for a window (the paper: one per window).
    pub noise: NoiseLevels,
    /// What the local joints are measured from (the paper: absolute local joints).
    pub pose: crate::features::PoseEncoding,
    /// How an epoch draws its windows (the paper: every window once).
    pub balance: WindowBalance,
    /// Weight λ of the loss's velocity term ([`crate::diffusion::GaussianDiffusion::loss_with_velocity`]:
    /// errors of frame-to-frame changes, per dim on the scale of that dim's changes in the
    /// training windows); 0 turns it off (the paper). Uniform noise levels only.
    pub velocity_loss: f64,
    /// Smallest std of the standardization, in the features' units (metres; the heading's
    /// cosine and sine), 0: off (the paper). A dim that barely moves in the training data (a
    /// body that stands still while its hands wave) is otherwise divided by its tiny std, so
    /// that motion the training data lacks reaches the network many standard deviations
    /// out; with a floor it stays within a few ([`crate::features::Standardization::with_min_std`]).
    pub min_std: f64,
    /// How several data sources become one training set (one source: unused).
    pub mix: MixSettings,
    /// A distillation round (`socdiff distill`): the network learns to take in one sampler
    /// step what its teacher takes in two. `None`: ordinary training.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub distill: Option<DistillRound>,
}

/// One round of progressive distillation (Salimans & Ho, ICLR 2022): a student that samples
/// with `calls` DDIM steps learns to land where two steps of its `teacher`, sampled with
/// 2·calls − 1, land (`crate::train::distill`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DistillRound {
    /// Network calls of the student's sampler (N).
    pub calls: usize,
    /// The teacher's checkpoint.
    pub teacher: std::path::PathBuf,
}

/// How several `--data` sources are mixed into one training set
/// ([`crate::train::data::mix_sources`]): the first source's train scenes as they are, every
/// single-person source as synthetic groups.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MixSettings {
    /// Synthetic groups built from each single-person source (200).
    pub synthetic_groups: usize,
    /// Persons per synthetic group; `null`: the person counts of the first source's train
    /// scenes.
    pub group_persons: Option<PersonRange>,
    /// Frames per synthetic group; `null`: twice the window, at least 300.
    pub group_frames: Option<usize>,
    /// How many times the first source's train scenes count (1).
    pub repeat_first: usize,
}

impl Default for MixSettings {
    fn default() -> Self {
        Self { synthetic_groups: 200, group_persons: None, group_frames: None, repeat_first: 1 }
    }
}

/// How an epoch draws its windows (the config field `balance`). Either way an epoch has the same batches
/// per person count, so steps, epochs and resuming are unchanged.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum WindowBalance {
    /// Every window once, shuffled (the paper): a long sequence weighs as many windows as it
    /// has, so long takes (bandai2's waves and walks) crowd out short ones (its runs).
    #[default]
    Windows,
    /// As many draws as windows, with replacement, each sequence equally likely (its windows
    /// share its weight): every take counts the same whatever its length.
    Sequences,
}

/// How training draws the noise levels of a window `[P, T]`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum NoiseLevels {
    /// One t for the whole window, every frame in the loss (the paper; kept for ablations).
    #[default]
    Uniform,
    /// A clean prefix (t = 0, left out of the loss) of L frames, one t after it: L is the
    /// observed frames in half of the windows (the forecasting setup), uniform in
    /// `0..window` in the others (other completion tasks, and none at all).
    Prefix,
    /// One t per person and frame, as in Diffusion Forcing (Chen et al., NeurIPS 2024):
    /// independent, or with `monotone` non-decreasing along time; every frame in the loss.
    PerFrame {
        /// Sort each person's levels along time.
        #[serde(default)]
        monotone: bool,
    },
}

#[cfg(feature = "clap")]
impl clap::ValueEnum for NoiseLevels {
    fn value_variants<'a>() -> &'a [Self] {
        &[NoiseLevels::Uniform, NoiseLevels::Prefix, NoiseLevels::PerFrame { monotone: false }, NoiseLevels::PerFrame { monotone: true }]
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        Some(clap::builder::PossibleValue::new(self.name()))
    }
}

impl NoiseLevels {
    /// The name [`NoiseLevels::parse`] reads.
    pub fn name(&self) -> &'static str {
        match self {
            NoiseLevels::Uniform => "uniform",
            NoiseLevels::Prefix => "prefix",
            NoiseLevels::PerFrame { monotone: false } => "per-frame",
            NoiseLevels::PerFrame { monotone: true } => "per-frame-monotone",
        }
    }

    /// Parses `uniform`, `prefix`, `per-frame` or `per-frame-monotone`.
    pub fn parse(s: &str) -> crate::Result<Self> {
        match s {
            "uniform" => Ok(NoiseLevels::Uniform),
            "prefix" => Ok(NoiseLevels::Prefix),
            "per-frame" => Ok(NoiseLevels::PerFrame { monotone: false }),
            "per-frame-monotone" => Ok(NoiseLevels::PerFrame { monotone: true }),
            _ => crate::bail!("unknown noise levels {s:?} (uniform, prefix, per-frame or per-frame-monotone)"),
        }
    }

    /// Whether the network saw clean frames (level 0) beside noisy ones in training, so that
    /// sampling should give known frames level 0 rather than the sampler's level.
    pub fn trains_clean_frames(&self) -> bool {
        !matches!(self, NoiseLevels::Uniform)
    }
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            preset: Some(Preset::Paper),
            model: DenoiserConfig::default(),
            diffusion: DiffusionConfig::default(),
            steps: 13_000,
            minutes: None,
            batch: 64,
            window: 512,
            stride: 10,
            observed: None,
            persons: None,
            adam: AdamConfig::default(),
            ema: EmaConfig::default(),
            seed: 0,
            save_every: 1000,
            noise: NoiseLevels::Uniform,
            pose: crate::features::PoseEncoding::Absolute,
            balance: WindowBalance::Windows,
            velocity_loss: 0.0,
            min_std: 0.0,
            val_every: 500,
            val_windows: 256,
            val_split: Split::Test,
            max_gap: crate::features::DEFAULT_MAX_GAP,
            augment: AugmentConfig::default(),
            mix: MixSettings::default(),
            distill: None,
        }
    }
}

/// Fields that a resumed run may change; any other difference from the checkpoint's config is
/// an error (it would break the exact continuation).
pub const RESUMABLE_FIELDS: [&str; 5] = ["steps", "minutes", "save_every", "val_every", "val_windows"];

impl TrainConfig {
    /// n_obs: the observed frames (anchor frame = n_obs − 1).
    pub fn observed_frames(&self) -> usize {
        self.observed.unwrap_or((self.window / 4).max(1))
    }

    /// Index of the anchor frame inside a window.
    pub fn anchor_offset(&self) -> usize {
        self.observed_frames().saturating_sub(1)
    }

    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<()> {
        let pos = |name: &str, v: usize| -> Result<()> {
            if v == 0 {
                bail!("train config: {name} must be at least 1");
            }
            Ok(())
        };
        pos("steps", self.steps)?;
        if let Some(m) = self.minutes {
            if !(m.is_finite() && m > 0.0) {
                bail!("train config: minutes must be positive, got {m}");
            }
        }
        pos("batch", self.batch)?;
        pos("window", self.window)?;
        pos("stride", self.stride)?;
        pos("save_every", self.save_every)?;
        pos("ema.update_every", self.ema.update_every)?;
        let n_obs = self.observed_frames();
        if n_obs == 0 || n_obs > self.window {
            bail!("train config: observed ({n_obs}) must be between 1 and the window ({})", self.window);
        }
        if let Some(r) = self.persons {
            if r.min == 0 || r.min > r.max {
                bail!("train config: persons range {}..={} must satisfy 1 ≤ min ≤ max", r.min, r.max);
            }
        }
        if !(self.velocity_loss.is_finite() && self.velocity_loss >= 0.0) {
            bail!("train config: velocity_loss must be finite and ≥ 0, got {}", self.velocity_loss);
        }
        if self.velocity_loss > 0.0 && self.noise != NoiseLevels::Uniform {
            bail!("train config: velocity_loss needs uniform noise levels (noise is {})", self.noise.name());
        }
        if !(0.0..=1.0).contains(&self.min_std) {
            bail!("train config: min_std {}: expected a floor in [0, 1]", self.min_std);
        }
        let a = &self.adam;
        if !(a.lr.is_finite() && a.lr > 0.0) {
            bail!("train config: adam.lr must be positive, got {}", a.lr);
        }
        if !a.betas.iter().all(|b| (0.0..1.0).contains(b)) {
            bail!("train config: adam.betas must lie in [0, 1), got {:?}", a.betas);
        }
        if !(a.eps.is_finite() && a.eps > 0.0) {
            bail!("train config: adam.eps must be positive, got {}", a.eps);
        }
        if !(0.0..=1.0).contains(&self.ema.decay) {
            bail!("train config: ema.decay must lie in [0, 1], got {}", self.ema.decay);
        }
        if !(self.augment.translate.is_finite() && self.augment.translate >= 0.0) {
            bail!("train config: augment.translate must be ≥ 0 metres, got {}", self.augment.translate);
        }
        for (name, v) in [("augment.body_scale", self.augment.body_scale), ("augment.limb_scale", self.augment.limb_scale)] {
            if !(0.0..0.5).contains(&v) {
                bail!("train config: {name} {v}: expected a spread in [0, 0.5)");
            }
        }
        if let Some(r) = self.mix.group_persons {
            if r.min == 0 || r.min > r.max {
                bail!("train config: mix.group_persons {}..={} must satisfy 1 ≤ min ≤ max", r.min, r.max);
            }
        }
        self.diffusion.noise_schedule()?;
        self.model.validate()
    }

    /// This config with the fields that the JSON object `fields` names replaced (nested objects
    /// field by field), validated. Errors name the offending key (unknown fields are rejected).
    pub fn with_json(&self, fields: &Value) -> Result<TrainConfig> {
        if !fields.is_object() {
            bail!("train config: expected a JSON object, got {fields}");
        }
        let mut v = serde_json::to_value(self).map_err(|e| Error::invalid(format!("train config: {e}")))?;
        merge(&mut v, fields);
        let cfg: TrainConfig = serde_json::from_value(v).map_err(|e| Error::invalid(format!("train config: {e}")))?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Reads a JSON config file (any subset of the fields of a run's `config.json`) over
    /// `base`; errors name the file.
    pub fn read_over(base: &TrainConfig, path: &Path) -> Result<TrainConfig> {
        let bytes = crate::files::read_bounded(path, 1 << 20, "train config")?;
        let v: Value = serde_json::from_slice(&bytes).map_err(|e| Error::format(path, format!("not JSON: {e}")))?;
        if !v.is_object() {
            return Err(Error::format(path, "a train config must be a JSON object"));
        }
        base.with_json(&v).map_err(|e| e.in_file(path))
    }

    /// Names of the top-level fields (and `model.*`, `adam.*`, … subfields) where `self`
    /// differs from `other`, ignoring [`RESUMABLE_FIELDS`].
    pub fn frozen_differences(&self, other: &TrainConfig) -> Vec<String> {
        let (a, b) = (serde_json::to_value(self).unwrap_or(Value::Null), serde_json::to_value(other).unwrap_or(Value::Null));
        let mut out = Vec::new();
        diff("", &a, &b, &mut out);
        out.retain(|k| !RESUMABLE_FIELDS.contains(&k.as_str()));
        out
    }
}

/// RFC 7386 merge patch, except that an object carrying `kind` replaces the target.
fn merge(target: &mut Value, patch: &Value) {
    match patch {
        Value::Object(p) if !p.contains_key("kind") => {
            if !target.is_object() {
                *target = Value::Object(Default::default());
            }
            let t = target.as_object_mut().expect("object");
            for (k, v) in p {
                if v.is_null() {
                    t.insert(k.clone(), Value::Null);
                } else {
                    merge(t.entry(k.clone()).or_insert(Value::Null), v);
                }
            }
        }
        _ => *target = patch.clone(),
    }
}

fn diff(prefix: &str, a: &Value, b: &Value, out: &mut Vec<String>) {
    match (a, b) {
        (Value::Object(x), Value::Object(y)) if !x.contains_key("kind") => {
            let keys: std::collections::BTreeSet<&String> = x.keys().chain(y.keys()).collect();
            for k in keys {
                let name = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
                diff(&name, x.get(k).unwrap_or(&Value::Null), y.get(k).unwrap_or(&Value::Null), out);
            }
        }
        _ if a != b => out.push(prefix.to_string()),
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Aggregator;
    use serde_json::json;

    #[test]
    fn defaults_follow_the_method() {
        let c = TrainConfig::default();
        assert_eq!((c.batch, c.window, c.stride, c.observed_frames(), c.anchor_offset()), (64, 512, 10, 128, 127));
        assert_eq!(c.adam, AdamConfig { lr: 1e-4, schedule: LrSchedule::Constant, betas: [0.9, 0.99], eps: 1e-8, clip_norm: None });
        assert_eq!(c.ema, EmaConfig { decay: 0.995, update_every: 10, warmup_steps: 100 });
        assert_eq!(c.diffusion.timesteps, 1000);
        assert!(c.validate().is_ok());
        // observed scales with short windows.
        let short = TrainConfig { window: 64, ..c.clone() };
        assert_eq!(short.observed_frames(), 16);
        assert_eq!(TrainConfig { window: 2, ..c }.observed_frames(), 1);
    }

    /// `--preset paper` is the paper's configuration field by field (METHOD.md §4, the paper's
    /// network: hidden 192, mean aggregator, causal; x0, L1, cosine T = 1000), and the
    /// recommended preset is the recipe of docs/results.md.
    #[test]
    fn presets_are_the_paper_and_the_recommended_recipe() {
        let p = Preset::Paper.config();
        assert_eq!(p.preset, Some(Preset::Paper));
        assert_eq!((p.steps, p.batch, p.window, p.stride, p.observed_frames(), p.minutes), (13_000, 64, 512, 10, 128, None));
        assert_eq!(
            (p.noise, p.pose, p.balance, p.velocity_loss, p.persons),
            (NoiseLevels::Uniform, crate::features::PoseEncoding::Absolute, WindowBalance::Windows, 0.0, None)
        );
        assert_eq!(p.augment, AugmentConfig { rotate: false, translate: 0.0, body_scale: 0.0, limb_scale: 0.0 });
        assert_eq!(p.adam, AdamConfig { lr: 1e-4, schedule: LrSchedule::Constant, betas: [0.9, 0.99], eps: 1e-8, clip_norm: None });
        assert_eq!(p.ema, EmaConfig { decay: 0.995, update_every: 10, warmup_steps: 100 });
        let m = &p.model;
        assert_eq!((m.hidden, m.social_dim, m.aggregator, m.causality), (192, 192, Aggregator::Mean, crate::model::Causality::Causal));
        let d = &p.diffusion;
        assert_eq!(
            (d.timesteps, d.prediction, d.loss, d.input_scaling, d.snr_shift),
            (1000, crate::diffusion::Prediction::X0, crate::diffusion::LossNorm::L1, crate::diffusion::InputScaling::None, 1.0)
        );
        let r = Preset::Recommended.config();
        assert_eq!(r.preset, Some(Preset::Recommended));
        assert_eq!(
            (r.model.hidden, r.model.social_dim, r.window, r.observed_frames(), r.stride, r.batch, r.adam.lr, r.steps),
            (64, 64, 120, 30, 5, 16, 1e-3, 10_000)
        );
        assert_eq!((r.noise, r.pose, r.augment.body_scale, r.augment.limb_scale), (NoiseLevels::Prefix, crate::features::PoseEncoding::Residual, 0.1, 0.05));
        // Everything else as the paper.
        let same = TrainConfig {
            preset: p.preset,
            model: p.model.clone(),
            steps: p.steps,
            batch: p.batch,
            window: p.window,
            stride: p.stride,
            adam: p.adam.clone(),
            noise: p.noise,
            pose: p.pose,
            augment: p.augment.clone(),
            save_every: p.save_every,
            ..r.clone()
        };
        assert_eq!(same, p);
        r.validate().unwrap();
        // The preset is recorded; runs from before presets read none.
        let v = serde_json::to_value(&r).unwrap();
        assert_eq!(v["preset"], "recommended");
        let mut old = serde_json::to_value(&p).unwrap();
        old.as_object_mut().unwrap().remove("preset");
        assert_eq!(serde_json::from_value::<TrainConfig>(old).unwrap().preset, None);
    }

    #[test]
    fn cosine_schedule_halves_at_mid_run_and_ends_at_zero() {
        let constant = AdamConfig { lr: 2e-3, ..Default::default() };
        assert_eq!((constant.lr_at(0, 100), constant.lr_at(99, 100), constant.lr_at(500, 100)), (2e-3, 2e-3, 2e-3));
        let cosine = AdamConfig { schedule: LrSchedule::Cosine, ..constant };
        // ½(1 + cos π·p) at p = 0, ¼, ½, ¾, 1 and past the end: 1, (2 + √2)/4, ½, (2 − √2)/4, 0, 0.
        let expected = [(0, 1.0), (25, (2.0 + 2f64.sqrt()) / 4.0), (50, 0.5), (75, (2.0 - 2f64.sqrt()) / 4.0), (100, 0.0), (130, 0.0)];
        for (done, factor) in expected {
            assert!((cosine.lr_at(done, 100) - 2e-3 * factor).abs() < 1e-15, "after {done} of 100: {}", cosine.lr_at(done, 100));
        }
        // The field is saved by name, and a config written before it existed reads constant.
        assert_eq!(serde_json::to_value(&cosine).unwrap()["schedule"], "cosine");
        let old: AdamConfig = serde_json::from_value(json!({"lr": 1e-3, "betas": [0.9, 0.99], "eps": 1e-8, "clip_norm": null})).unwrap();
        assert_eq!(old.schedule, LrSchedule::Constant);
    }

    #[test]
    fn layers_merge_and_bad_values_are_named() {
        let base = TrainConfig::default();
        let file = json!({"batch": 8, "model": {"hidden": 32, "aggregator": {"kind": "attention", "heads": 4}}, "adam": {"lr": 3e-4}});
        let cli = json!({"steps": 10, "model": {"aggregator": {"kind": "none"}}});
        let c = base.with_json(&file).unwrap().with_json(&cli).unwrap();
        assert_eq!((c.batch, c.steps, c.model.hidden, c.model.aggregator), (8, 10, 32, Aggregator::None));
        assert_eq!(c.adam.lr, 3e-4);
        assert_eq!(c.adam.betas, [0.9, 0.99]);
        let err = |p: Value| base.with_json(&p).unwrap_err().to_string();
        assert!(err(json!({"batch": 0})).contains("batch must be at least 1"));
        assert!(err(json!({"bacth": 4})).contains("unknown field `bacth`"));
        assert!(err(json!({"window": 16, "observed": 17})).contains("observed (17)"));
        assert!(err(json!({"adam": {"lr": -1.0}})).contains("adam.lr"));
        assert!(err(json!({"persons": {"min": 3, "max": 2}})).contains("persons range"));
        assert!(err(json!({"model": {"hidden": 0}})).contains("hidden"));
        assert!(err(json!({"diffusion": {"timesteps": 0}})).contains("timesteps"));
        assert!(err(json!({"ema": {"decay": 1.5}})).contains("ema.decay"));
        // Differences that would break an exact resume are listed.
        let d = c.frozen_differences(&TrainConfig { steps: 99, save_every: 3, ..c.clone() });
        assert!(d.is_empty(), "{d:?}");
        let d = c.frozen_differences(&TrainConfig { batch: 9, model: DenoiserConfig { hidden: 8, ..c.model.clone() }, ..c.clone() });
        assert_eq!(d, vec!["batch".to_string(), "model.hidden".to_string()]);
    }

    #[test]
    fn a_file_is_read_over_its_base_and_errors_name_it() {
        let dir = std::env::temp_dir().join(format!("socdiff-config-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("config.json");
        let base = TrainConfig { steps: 7, batch: 3, ..TrainConfig::default() };
        std::fs::write(&path, r#"{"batch": 8, "ema": {"decay": 0.9}}"#).unwrap();
        let c = TrainConfig::read_over(&base, &path).unwrap();
        // Named fields replaced, the rest (even inside `ema`) kept from the base.
        assert_eq!((c.steps, c.batch, c.ema.decay, c.ema.update_every), (7, 8, 0.9, 10));
        std::fs::write(&path, r#"{"bacth": 8}"#).unwrap();
        let e = TrainConfig::read_over(&base, &path).unwrap_err().to_string();
        assert!(e.contains("config.json") && e.contains("unknown field `bacth`"), "{e}");
        std::fs::write(&path, "[1]").unwrap();
        assert!(TrainConfig::read_over(&base, &path).unwrap_err().to_string().contains("must be a JSON object"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
