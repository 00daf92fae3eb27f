//! Classifier checkpoints: a directory with one safetensors file and a JSON sidecar, both
//! written atomically (temp file + rename), as the denoiser's ([`crate::checkpoint`]).
//!
//! | file | content |
//! |---|---|
//! | `classifier.safetensors` | f32 tensors `weights.<name>`, `adam.m.<name>`, `adam.v.<name>`; header `format` = `socdiff-classifier`, `step` |
//! | `classifier.json` | [`ClassifierMeta`]: config, skeleton, fps, feature standardizations, step, data summary |
//! | `train_log.jsonl` | one JSON object per step: `step`, `loss`, `speaking_loss`, `buyer_loss`, `seconds` |
//!
//! The tensors are written first, then the sidecar; both carry the step, and reading refuses a
//! pair whose steps differ.

use super::config::ClassifierConfig;
use super::net::SocialSignalNet;
use crate::checkpoint::{f32_le_bytes, header_meta, read_f32_safetensors, write_checkpoint_file};
use crate::data::Skeleton;
use crate::features::Standardization;
use crate::model::layers::{set_var, var_values};
use crate::model::Parameterized;
use crate::train::Adam;
use crate::{bail, Error, Result};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Tensor file in a classifier directory.
pub const TENSORS_FILE: &str = "classifier.safetensors";
/// Sidecar in a classifier directory.
pub const META_FILE: &str = "classifier.json";
/// Training log in a classifier directory.
pub const LOG_FILE: &str = "train_log.jsonl";
/// `format` of a classifier checkpoint (sidecar and safetensors header).
pub const FORMAT: &str = "socdiff-classifier";
/// Current `format_version`.
pub const FORMAT_VERSION: u32 = 1;

const PREFIX_WEIGHTS: &str = "weights.";
const PREFIX_ADAM_M: &str = "adam.m.";
const PREFIX_ADAM_V: &str = "adam.v.";

/// What the classifiers were trained on.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DataSummary {
    /// The `--data` path(s).
    pub source: String,
    /// Scenes used.
    pub scenes: usize,
    /// Frames over those scenes.
    pub frames: usize,
    /// Fraction of labelled person-frames that speak.
    pub speaking_fraction: f64,
    /// Scenes with one `buyer`.
    pub with_buyer: usize,
}

/// The JSON sidecar of a classifier checkpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClassifierMeta {
    /// Always [`FORMAT`].
    pub format: String,
    /// [`FORMAT_VERSION`] when written.
    pub format_version: u32,
    /// Version of socdiff that wrote it.
    pub socdiff_version: String,
    /// Optimizer steps done.
    pub step: u64,
    /// Wall-clock seconds of training, over all resumes.
    pub elapsed_seconds: f64,
    /// Loss of the last step.
    pub loss: Option<f64>,
    /// Frame rate of the training data (inputs must have it).
    pub fps: f64,
    /// Skeleton of the training data (inputs must have it).
    pub skeleton: Skeleton,
    /// Standardization of the person features `[6J]`.
    pub person_standardization: Standardization,
    /// Standardization of the pair features `[7]`.
    pub pair_standardization: Standardization,
    /// Configuration of the run.
    pub config: ClassifierConfig,
    /// What it was trained on.
    pub data: DataSummary,
    /// File name of the safetensors file, relative to the sidecar.
    pub tensors: String,
}

impl ClassifierMeta {
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        step: u64,
        elapsed_seconds: f64,
        loss: Option<f64>,
        fps: f64,
        skeleton: Skeleton,
        std: (Standardization, Standardization),
        config: ClassifierConfig,
        data: DataSummary,
    ) -> Self {
        Self {
            format: FORMAT.into(),
            format_version: FORMAT_VERSION,
            socdiff_version: env!("CARGO_PKG_VERSION").into(),
            step,
            elapsed_seconds,
            loss,
            fps,
            skeleton,
            person_standardization: std.0,
            pair_standardization: std.1,
            config,
            data,
            tensors: TENSORS_FILE.into(),
        }
    }
}

/// Whether `dir` holds (part of) a classifier checkpoint.
pub fn exists_in(dir: &Path) -> bool {
    dir.join(META_FILE).exists() || dir.join(TENSORS_FILE).exists()
}

/// `(sidecar, tensors)` paths for a classifier directory or its sidecar (a `.json` file).
fn paths(path: &Path) -> (PathBuf, PathBuf) {
    if path.extension().is_some_and(|e| e == "json") && !path.is_dir() {
        (path.to_path_buf(), path.with_extension("safetensors"))
    } else {
        (path.join(META_FILE), path.join(TENSORS_FILE))
    }
}

/// A classifier checkpoint read from disk.
pub struct ClassifierCheckpoint {
    /// The sidecar.
    pub meta: ClassifierMeta,
    /// Path of the sidecar.
    pub meta_path: PathBuf,
    /// Path of the safetensors file.
    pub tensors_path: PathBuf,
    tensors: HashMap<String, (Vec<usize>, Vec<f32>)>,
}

impl ClassifierCheckpoint {
    /// Reads a checkpoint (its directory or sidecar). Errors name the file that is missing,
    /// truncated, foreign or inconsistent.
    pub fn read(path: &Path) -> Result<Self> {
        let (sidecar, tensors_file) = paths(path);
        // The description is in the safetensors header (format 2) or, before, the sidecar.
        let (text, meta_path) = match header_meta(&tensors_file)? {
            Some(text) => (text, tensors_file.clone()),
            None => (std::fs::read_to_string(&sidecar).map_err(|e| Error::io(&sidecar, e))?, sidecar),
        };
        let meta: ClassifierMeta = serde_json::from_str(&text).map_err(|e| Error::format(&meta_path, format!("not a socdiff classifier description: {e}")))?;
        if meta.format != FORMAT {
            return Err(Error::format(&meta_path, format!("format is {:?}, not {FORMAT:?}", meta.format)));
        }
        if meta.format_version > FORMAT_VERSION {
            return Err(Error::format(
                &meta_path,
                format!("classifier format version {} is newer than this socdiff supports ({FORMAT_VERSION})", meta.format_version),
            ));
        }
        meta.config.validate().map_err(|e| e.in_file(&meta_path))?;
        let joints = meta.skeleton.num_joints();
        if meta.config.net.person_dims != super::inputs::person_dims(joints)
            || meta.person_standardization.dim() != meta.config.net.person_dims
            || meta.pair_standardization.dim() != super::inputs::PAIR_DIMS
        {
            return Err(Error::format(&meta_path, "feature dimensions of the config, skeleton and standardizations disagree"));
        }
        if !(meta.fps.is_finite() && meta.fps > 0.0) {
            return Err(Error::format(&meta_path, format!("fps {} is not positive", meta.fps)));
        }
        let tensors_path = meta_path.parent().unwrap_or(Path::new(".")).join(&meta.tensors);
        let (info, tensors) = read_f32_safetensors(&tensors_path, FORMAT, "socdiff classifier", false)?;
        if info.get("step").and_then(|s| s.parse::<u64>().ok()) != Some(meta.step) {
            return Err(Error::format(
                &tensors_path,
                format!(
                    "holds step {} but {} says step {}: the last save was interrupted; retrain or restore both files",
                    info.get("step").map_or("?", String::as_str),
                    meta_path.display(),
                    meta.step
                ),
            ));
        }
        Ok(Self { meta, meta_path, tensors_path, tensors })
    }

    fn tensor(&self, name: &str, shape: &[usize]) -> Result<&[f32]> {
        match self.tensors.get(name) {
            None => Err(Error::format(&self.tensors_path, format!("missing tensor {name}"))),
            Some((s, _)) if s.as_slice() != shape => {
                Err(Error::format(&self.tensors_path, format!("tensor {name} has shape {s:?}, the config gives {shape:?}")))
            }
            Some((_, v)) if v.iter().any(|x| !x.is_finite()) => Err(Error::format(&self.tensors_path, format!("tensor {name} holds non-finite values"))),
            Some((_, v)) => Ok(v),
        }
    }

    /// The (trainable) network with the saved weights.
    pub fn network(&self) -> Result<SocialSignalNet> {
        self.network_at(&crate::model::Placement::cpu())
    }

    /// [`Self::network`] at `placement` (the file holds f32 values).
    pub fn network_at(&self, placement: &crate::model::Placement) -> Result<SocialSignalNet> {
        let net = SocialSignalNet::build(self.meta.config.net.clone(), self.meta.config.seed, placement).map_err(|e| e.in_file(&self.meta_path))?;
        for (name, var) in net.named_vars() {
            set_var(&var, self.tensor(&format!("{PREFIX_WEIGHTS}{name}"), var.dims())?.to_vec())?;
        }
        Ok(net)
    }

    /// Adam moments `(m, v)` for the parameters of `net`, in its order.
    pub(crate) fn adam_moments(&self, net: &SocialSignalNet) -> Result<Vec<(Vec<f32>, Vec<f32>)>> {
        net.named_vars()
            .iter()
            .map(|(name, var)| {
                Ok((self.tensor(&format!("{PREFIX_ADAM_M}{name}"), var.dims())?.to_vec(), self.tensor(&format!("{PREFIX_ADAM_V}{name}"), var.dims())?.to_vec()))
            })
            .collect()
    }

    /// Checks that data with `skeleton` at `fps` fits the classifiers; errors name the sidecar.
    pub fn check_data(&self, skeleton: &Skeleton, fps: f64) -> Result<()> {
        let m = &self.meta;
        if m.skeleton.joints != skeleton.joints || (m.skeleton.left, m.skeleton.right) != (skeleton.left, skeleton.right) {
            return Err(Error::format(
                &self.meta_path,
                format!(
                    "the classifiers were trained on skeleton {} ({} joints), the data has skeleton {} ({} joints)",
                    m.skeleton.name,
                    m.skeleton.num_joints(),
                    skeleton.name,
                    skeleton.num_joints()
                ),
            ));
        }
        if (m.fps - fps).abs() > 1e-6 * m.fps {
            return Err(Error::format(
                &self.meta_path,
                format!("the classifiers were trained at {} fps, the data is at {fps} fps (resample it to {} fps first)", m.fps, m.fps),
            ));
        }
        Ok(())
    }
}

/// Writes `dir/classifier.safetensors` then `dir/classifier.json`, each atomically. Returns the
/// safetensors path.
pub(crate) fn write(dir: &Path, meta: &ClassifierMeta, net: &SocialSignalNet, adam: &Adam) -> Result<PathBuf> {
    let vars = net.named_vars();
    if vars.iter().map(|(n, _)| n.as_str()).ne(adam.names()) {
        bail!("classifier checkpoint: the optimizer's parameters are not the network's");
    }
    let mut tensors = Vec::with_capacity(3 * vars.len());
    for (name, var) in &vars {
        tensors.push((format!("{PREFIX_WEIGHTS}{name}"), var.dims().to_vec(), f32_le_bytes(&var_values(var)?)));
    }
    for ((name, m, v), (_, var)) in adam.moments()?.into_iter().zip(&vars) {
        tensors.push((format!("{PREFIX_ADAM_M}{name}"), var.dims().to_vec(), f32_le_bytes(&m)));
        tensors.push((format!("{PREFIX_ADAM_V}{name}"), var.dims().to_vec(), f32_le_bytes(&v)));
    }
    let tensors_path = dir.join(&meta.tensors);
    write_checkpoint_file(&tensors_path, &tensors, FORMAT, meta.step, meta, None)?;
    let text = serde_json::to_string_pretty(meta).map_err(|e| Error::format(dir.join(META_FILE), e.to_string()))?;
    crate::files::write_file_atomic(&dir.join(META_FILE), text.as_bytes())?;
    Ok(tensors_path)
}
