//! Checkpoints: one safetensors file holding every tensor of a run and, in its header, the
//! JSON description of the run, written atomically into the run's directory. One file is one
//! atomic unit: a reader sees the old checkpoint or the new one, never a mix.
//!
//! | file | content |
//! |---|---|
//! | `checkpoint.safetensors` | f32 tensors `online.<name>` (weights), `ema.<name>` (averaged weights), `adam.m.<name>`, `adam.v.<name>` (Adam moments); header metadata `format`, `step`, `socdiff_version`, `socdiff_meta` ([`CheckpointMeta`] as JSON) and `crc32` (checksum of every tensor, verified on load) |
//! | `checkpoint.prev.safetensors` | the previous checkpoint, kept until the next one is complete |
//! | `checkpoint.json` | a readable copy of [`CheckpointMeta`] (informative: loading reads the header) |
//! | `train_log.jsonl` | one JSON object per step (`step`, `loss`, `lr`, `seconds`) or validation (`step`, `val_loss`, `seconds`) |
//! | `config.json` | the resolved [`TrainConfig`], written when a fresh run starts |
//!
//! `<name>` is a parameter name of [`Denoiser::named_vars`]. There is no RNG state to save: every
//! random draw of step s comes from an RNG seeded by `(seed, s)` (and the batch order of epoch
//! e by `(seed, e)`), so `step` and `seed` restore it exactly.
//!
//! A save hard-links the current checkpoint to `checkpoint.prev.safetensors`, then writes the
//! new one to a synced temporary file and renames it over the current one: killed at any
//! moment, the directory holds a complete checkpoint. Format version 1 (the JSON sidecar as the
//! description, written as a second file) still loads; there the steps of both files must agree.
//!
//! Loading refuses weights whose checksum differs, and non-finite or absurd values
//! (|w| > [`MAX_ABS_WEIGHT`]).
//!
//! For forecasting, [`Checkpoint::load`] returns a [`LoadedModel`]: the frozen EMA network
//! and everything needed to encode inputs and decode outputs.

pub mod config;

use crate::data::Skeleton;
use crate::diffusion::GaussianDiffusion;
use crate::features::Standardization;
use crate::files::write_file_atomic;
use crate::model::layers::set_var;
use crate::model::Denoiser;
use crate::model::Parameterized;
use crate::{Error, Result};
use config::TrainConfig;
use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

/// Name of the tensor file in a run directory.
pub const TENSORS_FILE: &str = "checkpoint.safetensors";
/// Name of the sidecar in a run directory.
pub const META_FILE: &str = "checkpoint.json";
/// Name of the training log in a run directory.
pub const LOG_FILE: &str = "train_log.jsonl";
/// Name of the config written when a run starts.
pub const CONFIG_FILE: &str = "config.json";
/// `format` of every socdiff checkpoint.
pub const FORMAT: &str = "socdiff-checkpoint";
/// Current `format_version` (2: the description inside the safetensors header; 3: a checksum
/// over the description too).
pub const FORMAT_VERSION: u32 = 3;
/// The previous checkpoint of a run directory, kept while the next one is written.
pub const PREV_TENSORS_FILE: &str = "checkpoint.prev.safetensors";
/// The inference weights of a run's last save (EMA weights and the description; no optimizer
/// state, a quarter of the checkpoint's size): the file to share or bundle. Loads like a
/// checkpoint for forecasting and `train --init`; it cannot be resumed.
pub const MODEL_FILE: &str = "model.safetensors";
/// Largest |weight| a loaded network may hold; larger values mean a corrupt or diverged run.
pub const MAX_ABS_WEIGHT: f32 = 1e4;
/// Header key of the JSON description.
const META_KEY: &str = "socdiff_meta";
/// Header key of the tensors' checksum.
const CHECKSUM_KEY: &str = "crc32";
/// Header key of the checksum over the description and every tensor (format 3 on).
const FULL_CHECKSUM_KEY: &str = "crc32_all";
/// Largest description (header or sidecar) read.
const MAX_META_BYTES: u64 = 64 << 20;
/// Largest checkpoint read.
pub const MAX_CHECKPOINT_BYTES: u64 = 16 << 30;

/// Prefixes of the tensor groups in the safetensors file.
pub const PREFIX_ONLINE: &str = "online.";
/// EMA weights.
pub const PREFIX_EMA: &str = "ema.";
/// Adam first moments.
pub const PREFIX_ADAM_M: &str = "adam.m.";
/// Adam second moments.
pub const PREFIX_ADAM_V: &str = "adam.v.";

/// Which weights to load.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Weights {
    /// The exponential moving average (for inference).
    #[default]
    Ema,
    /// The optimizer's current weights.
    Online,
}

/// What the run was trained on.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DataSummary {
    /// The `--data` path (or a description).
    pub source: String,
    /// Number of training windows.
    pub train_windows: usize,
    /// Number of validation windows (0: no validation).
    pub val_windows: usize,
    /// Training windows per person count.
    pub windows_by_persons: BTreeMap<String, usize>,
    /// Digest of the training windows (see `WindowSet::fingerprint`).
    pub fingerprint: String,
}

/// The JSON sidecar of a checkpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointMeta {
    /// Always [`FORMAT`].
    pub format: String,
    /// [`FORMAT_VERSION`] when written.
    pub format_version: u32,
    /// Version of socdiff that wrote it.
    pub socdiff_version: String,
    /// Optimizer steps done.
    pub step: u64,
    /// The run's seed (also in `config.seed`).
    pub seed: u64,
    /// How random state is restored (informative).
    pub rng: String,
    /// Wall-clock seconds of training so far, over all resumes.
    pub elapsed_seconds: f64,
    /// Training loss of the last step.
    pub loss: Option<f64>,
    /// Last validation loss.
    pub val_loss: Option<f64>,
    /// Frame rate of the training data.
    pub fps: f64,
    /// Skeleton of the training data.
    pub skeleton: Skeleton,
    /// Feature standardization fitted on the training windows.
    pub standardization: Standardization,
    /// The run's configuration.
    pub config: TrainConfig,
    /// What it was trained on.
    pub data: DataSummary,
    /// File name of the safetensors file, relative to the sidecar.
    pub tensors: String,
    /// Where the last training call ran ([`crate::model::Placement::describe`], e.g.
    /// `cuda:0 bf16 composed`); weights are stored in f32 whatever it was, so any device
    /// loads them. Empty in checkpoints written before it was recorded.
    #[serde(default)]
    pub device: String,
    /// The checkpoint the run started from (`socdiff train --init`) and its step; `None` for
    /// a run from random weights.
    #[serde(default)]
    pub init: Option<String>,
}

impl LoadedModel {
    /// `scene` in the model's skeleton and frame rate: joints mapped by name when `map_joints`
    /// and the layouts differ (the map is returned), resampled when the frame rates differ.
    /// Errors name the scene and what does not fit.
    pub fn fit_scene(&self, scene: &crate::data::Scene, map_joints: bool) -> Result<(crate::data::Scene, Option<crate::data::joint_map::JointMap>)> {
        let in_scene = |e: Error| Error::invalid(format!("scene {}: {e}", scene.name));
        let (scene, map) = match check_skeleton(&self.meta, &self.path, &scene.skeleton) {
            Ok(()) => (scene.clone(), None),
            Err(e) if !map_joints => return Err(in_scene(e)),
            Err(_) => {
                let map = crate::data::joint_map::JointMap::by_names(&scene.skeleton, &self.skeleton, &[]).map_err(in_scene)?;
                let mut mapped = map.apply(scene).map_err(in_scene)?;
                mapped.skeleton = self.skeleton.clone();
                check_skeleton(&self.meta, &self.path, &mapped.skeleton).map_err(in_scene)?;
                (mapped, Some(map))
            }
        };
        let scene = if (scene.fps - self.fps).abs() > 1e-6 * self.fps { scene.resample(self.fps).map_err(in_scene)? } else { scene };
        Ok((scene, map))
    }
}

/// How a checkpoint's random state is restored, as written into [`CheckpointMeta::rng`].
pub const RNG_NOTE: &str = "StdRng per (seed, stream, step or epoch); restored from seed and step";

/// A model loaded for inference.
#[derive(Clone)]
pub struct LoadedModel {
    /// The network, frozen (its forward builds no autograd graph).
    pub denoiser: Denoiser,
    /// Which weights `denoiser` holds.
    pub weights: Weights,
    /// The diffusion process it was trained with.
    pub diffusion: GaussianDiffusion,
    /// The training configuration (window, observed frames, …).
    pub config: TrainConfig,
    /// Feature standardization: apply to inputs, invert on outputs.
    pub standardization: Standardization,
    /// Skeleton the model was trained on.
    pub skeleton: Skeleton,
    /// Frame rate of the training data.
    pub fps: f64,
    /// Optimizer steps of the checkpoint.
    pub step: u64,
    /// The whole sidecar.
    pub meta: CheckpointMeta,
    /// The safetensors file it was read from.
    pub path: PathBuf,
}

/// A checkpoint read from disk: the sidecar and every tensor.
pub struct Checkpoint {
    /// The sidecar.
    pub meta: CheckpointMeta,
    /// Path of the sidecar.
    pub meta_path: PathBuf,
    /// Path of the safetensors file.
    pub tensors_path: PathBuf,
    tensors: HashMap<String, (Vec<usize>, Vec<f32>)>,
}

impl Checkpoint {
    /// `(sidecar, safetensors)` paths for a run directory, a `.json` sidecar or a
    /// `.safetensors` file.
    pub fn paths(path: &Path) -> (PathBuf, PathBuf) {
        if path.is_dir() {
            return (path.join(META_FILE), path.join(TENSORS_FILE));
        }
        match path.extension().and_then(|e| e.to_str()) {
            Some("safetensors") => (path.with_extension("json"), path.to_path_buf()),
            _ => (path.to_path_buf(), path.with_extension("safetensors")),
        }
    }

    /// Whether `dir` holds (part of) a checkpoint.
    pub fn exists_in(dir: &Path) -> bool {
        dir.join(META_FILE).exists() || dir.join(TENSORS_FILE).exists()
    }

    /// Reads the description only (the safetensors header, or a format-1 sidecar; cheap);
    /// errors name the file.
    pub fn read_meta(path: &Path) -> Result<CheckpointMeta> {
        Ok(Self::read_meta_from(path)?.0)
    }

    /// The description and the file it was read from.
    fn read_meta_from(path: &Path) -> Result<(CheckpointMeta, PathBuf)> {
        let (meta_path, tensors_path) = Self::paths(path);
        let (meta, from): (CheckpointMeta, PathBuf) = match header_meta(&tensors_path)? {
            Some(text) => {
                let meta = serde_json::from_str(&text).map_err(|e| Error::format(&tensors_path, format!("not a socdiff checkpoint description: {e}")))?;
                (meta, tensors_path)
            }
            None => {
                let bytes = crate::files::read_bounded(&meta_path, MAX_META_BYTES, "checkpoint description")?;
                let meta = serde_json::from_slice(&bytes).map_err(|e| Error::format(&meta_path, format!("not a socdiff checkpoint sidecar: {e}")))?;
                (meta, meta_path)
            }
        };
        if meta.format != FORMAT {
            return Err(Error::format(&from, format!("format is {:?}, not {FORMAT:?}", meta.format)));
        }
        if meta.format_version > FORMAT_VERSION {
            return Err(Error::format(
                &from,
                format!("checkpoint format version {} is newer than this socdiff supports ({FORMAT_VERSION})", meta.format_version),
            ));
        }
        meta.config.validate().map_err(|e| e.in_file(&from))?;
        if meta.standardization.dim() != meta.config.model.feature_dims {
            return Err(Error::format(&from, format!("standardization has {} dims, the model {}", meta.standardization.dim(), meta.config.model.feature_dims)));
        }
        if !(meta.fps.is_finite() && meta.fps > 0.0 && meta.fps <= crate::data::MAX_FPS) {
            return Err(Error::format(&from, format!("fps {} is outside (0, {}]", meta.fps, crate::data::MAX_FPS)));
        }
        Ok((meta, from))
    }

    /// Reads a checkpoint (a run directory, its sidecar or its safetensors file). Errors name
    /// the file that is missing, truncated, foreign, corrupt or inconsistent.
    pub fn read(path: &Path) -> Result<Self> {
        let (meta, from) = Self::read_meta_from(path)?;
        let (meta_path, default_tensors) = Self::paths(path);
        let embedded = from == default_tensors;
        let tensors_path = if embedded || path.extension().is_some_and(|e| e == "safetensors") {
            default_tensors
        } else {
            // A format-1 description names its tensors file beside it: one plain file name.
            crate::files::check_name("tensors file", &meta.tensors).map_err(|e| e.in_file(&meta_path))?;
            meta_path.parent().unwrap_or(Path::new(".")).join(&meta.tensors)
        };
        let (info, tensors) = read_f32_safetensors(&tensors_path, FORMAT, "socdiff checkpoint", meta.format_version < 2)?;
        let step: Option<u64> = info.get("step").and_then(|s| s.parse().ok());
        if step != Some(meta.step) {
            return Err(Error::format(
                &tensors_path,
                format!(
                    "holds step {} but {} says step {}: the last save was interrupted; restore both files from a backup",
                    info.get("step").map_or("?", String::as_str),
                    meta_path.display(),
                    meta.step
                ),
            ));
        }
        for (name, (_, values)) in &tensors {
            let weight = name.starts_with(PREFIX_ONLINE) || name.starts_with(PREFIX_EMA);
            if let Some(v) = values.iter().find(|v| !v.is_finite() || (weight && v.abs() > MAX_ABS_WEIGHT)) {
                return Err(Error::format(
                    &tensors_path,
                    format!("tensor {name} holds {v} (weights must be finite and within ±{MAX_ABS_WEIGHT:e}): the checkpoint is corrupt or the run diverged"),
                ));
            }
        }
        let meta_path = if embedded { tensors_path.clone() } else { meta_path };
        Ok(Self { meta, meta_path, tensors_path, tensors })
    }

    /// Loads the EMA weights for inference (see [`Checkpoint::load_weights`]).
    pub fn load(path: impl AsRef<Path>) -> Result<LoadedModel> {
        Self::load_weights(path, Weights::Ema)
    }

    /// Loads `weights` as a frozen network with everything needed to use it.
    pub fn load_weights(path: impl AsRef<Path>, weights: Weights) -> Result<LoadedModel> {
        let ck = Self::read(path.as_ref())?;
        let denoiser = ck.denoiser(weights)?.frozen();
        let diffusion = GaussianDiffusion::new(&ck.meta.config.diffusion).map_err(|e| e.in_file(&ck.meta_path))?;
        let m = ck.meta.clone();
        Ok(LoadedModel {
            denoiser,
            weights,
            diffusion,
            config: m.config.clone(),
            standardization: m.standardization.clone(),
            skeleton: m.skeleton.clone(),
            fps: m.fps,
            step: m.step,
            meta: m,
            path: ck.tensors_path,
        })
    }

    /// Every tensor: `(name, shape, values)`, sorted by name.
    pub fn tensors(&self) -> Vec<(&str, &[usize], &[f32])> {
        let mut v: Vec<_> = self.tensors.iter().map(|(n, (s, x))| (n.as_str(), s.as_slice(), x.as_slice())).collect();
        v.sort_by(|a, b| a.0.cmp(b.0));
        v
    }

    /// Values of tensor `name`, checked against `shape`.
    fn tensor(&self, name: &str, shape: &[usize]) -> Result<&[f32]> {
        match self.tensors.get(name) {
            None => Err(Error::format(&self.tensors_path, format!("missing tensor {name} (the config in {} needs it)", self.meta_path.display()))),
            Some((s, _)) if s.as_slice() != shape => {
                Err(Error::format(&self.tensors_path, format!("tensor {name} has shape {s:?}, the config gives {shape:?}")))
            }
            Some((_, v)) => Ok(v),
        }
    }

    /// A (trainable) network holding `weights`.
    pub fn denoiser(&self, weights: Weights) -> Result<Denoiser> {
        self.denoiser_at(weights, &crate::model::Placement::cpu())
    }

    /// [`Checkpoint::denoiser`] at `placement` (any device; the file holds f32 values).
    pub fn denoiser_at(&self, weights: Weights, placement: &crate::model::Placement) -> Result<Denoiser> {
        let prefix = match weights {
            Weights::Ema => PREFIX_EMA,
            Weights::Online => PREFIX_ONLINE,
        };
        let net = Denoiser::build(self.meta.config.model.clone(), self.meta.seed, placement).map_err(|e| e.in_file(&self.meta_path))?;
        for (name, var) in net.named_vars() {
            let v = self.tensor(&format!("{prefix}{name}"), var.dims())?;
            set_var(&var, v.to_vec())?;
        }
        Ok(net)
    }

    /// Adam moments `(m, v)` for the parameters `names`, in that order.
    pub(crate) fn adam_moments(&self, net: &Denoiser) -> Result<Vec<(Vec<f32>, Vec<f32>)>> {
        net.named_vars()
            .iter()
            .map(|(name, var)| {
                let m = self.tensor(&format!("{PREFIX_ADAM_M}{name}"), var.dims())?.to_vec();
                let v = self.tensor(&format!("{PREFIX_ADAM_V}{name}"), var.dims())?.to_vec();
                Ok((m, v))
            })
            .collect()
    }
}

/// Writes a checkpoint as one safetensors file, atomically: header metadata `format`, `step`, `socdiff_version`, the JSON description `meta` and the tensors'
/// checksum. With `prev`, the file it replaces is first hard-linked there, so the previous
/// checkpoint stays complete until the new one is in place.
pub(crate) fn write_checkpoint_file(path: &Path, tensors: &[TensorBytes], format: &str, step: u64, meta: &impl Serialize, prev: Option<&Path>) -> Result<()> {
    let text = serde_json::to_string(meta).map_err(|e| Error::format(path, e.to_string()))?;
    let checksum = tensors_checksum(tensors.iter().map(|(n, s, b)| (n.as_str(), s.as_slice(), b.as_slice())));
    let full = full_checksum(&text, checksum);
    let info = HashMap::from([
        ("format".to_string(), format.to_string()),
        ("step".to_string(), step.to_string()),
        ("socdiff_version".to_string(), env!("CARGO_PKG_VERSION").to_string()),
        (META_KEY.to_string(), text),
        (CHECKSUM_KEY.to_string(), format!("{checksum:08x}")),
        (FULL_CHECKSUM_KEY.to_string(), format!("{full:08x}")),
    ]);
    let views = tensors
        .iter()
        .map(|(n, shape, b)| Ok((n.as_str(), TensorView::new(Dtype::F32, shape.clone(), b).map_err(|e| Error::format(path, format!("tensor {n}: {e}")))?)))
        .collect::<Result<Vec<_>>>()?;
    let data = safetensors::tensor::serialize(views, Some(info)).map_err(|e| Error::format(path, e.to_string()))?;
    // The current checkpoint stays complete under its own name until the new one replaces it.
    if let (Some(prev), true) = (prev, path.is_file()) {
        let prev_tmp = crate::files::temp_sibling(prev)?;
        let _ = std::fs::remove_file(&prev_tmp);
        std::fs::hard_link(path, &prev_tmp)
            .or_else(|_| std::fs::copy(path, &prev_tmp).map(|_| ()))
            .and_then(|_| std::fs::rename(&prev_tmp, prev))
            .map_err(|e| Error::io(prev, e))?;
    }
    write_file_atomic(path, &data)?;
    crate::files::sync_dir(path.parent().unwrap_or(Path::new(".")));
    Ok(())
}

/// CRC-32 over every tensor in name order: name, shape (u64 LE) and data bytes.
fn tensors_checksum<'a>(tensors: impl Iterator<Item = (&'a str, &'a [usize], &'a [u8])>) -> u32 {
    let mut sorted: Vec<_> = tensors.collect();
    sorted.sort_by(|a, b| a.0.cmp(b.0));
    let mut h = crc32fast::Hasher::new();
    for (name, shape, bytes) in sorted {
        h.update(name.as_bytes());
        h.update(&[0]);
        for d in shape {
            h.update(&(*d as u64).to_le_bytes());
        }
        h.update(bytes);
    }
    h.finalize()
}

/// Whether checkpoints without a checksum are loaded (with a warning) instead of refused.
static TRUST_UNCHECKED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Loads checkpoints that carry no checksum (with a warning on stderr) when `trust` is set; by
/// default they are refused. For files of one's own that socdiff did not write.
pub fn trust_unchecked(trust: bool) {
    TRUST_UNCHECKED.store(trust, std::sync::atomic::Ordering::Relaxed);
}

/// CRC-32 over a checkpoint's description and its tensors' checksum: any change to either,
/// the model's sizes included, is caught before the weights are used.
fn full_checksum(description: &str, tensors: u32) -> u32 {
    let mut h = crc32fast::Hasher::new();
    h.update(description.as_bytes());
    h.update(&tensors.to_le_bytes());
    h.finalize()
}

/// The bytes of tensor data the header of the safetensors file at `path` states (the largest
/// end offset), read from the header alone; errors name the file.
fn stated_data_bytes(path: &Path) -> Result<(u64, u64)> {
    use std::io::Read;
    let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let size = f.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut len = [0u8; 8];
    f.read_exact(&mut len).map_err(|_| Error::format(path, "not a complete safetensors file (truncated or corrupt)"))?;
    let n = u64::from_le_bytes(len);
    if n > MAX_META_BYTES || n + 8 > size {
        return Err(Error::format(path, format!("not a complete safetensors file (a header of {n} bytes in a file of {size})")));
    }
    let mut header = vec![0u8; n as usize];
    f.read_exact(&mut header).map_err(|e| Error::io(path, e))?;
    let json: serde_json::Value = serde_json::from_slice(&header).map_err(|e| Error::format(path, format!("not a safetensors header: {e}")))?;
    let ends = json.as_object().into_iter().flatten().filter(|(k, _)| k.as_str() != "__metadata__").filter_map(|(_, v)| v["data_offsets"][1].as_u64());
    Ok((8 + n, ends.max().unwrap_or(0)))
}

/// The JSON description in the header of the safetensors file at `path` (reading only the
/// header); `None` when the file is missing or has none (format 1).
pub(crate) fn header_meta(path: &Path) -> Result<Option<String>> {
    use std::io::Read;
    if !path.exists() {
        return Ok(None);
    }
    crate::files::check_readable(path, "socdiff checkpoint")?;
    let Ok(mut f) = std::fs::File::open(path) else { return Ok(None) };
    let mut len = [0u8; 8];
    if f.read_exact(&mut len).is_err() {
        return Err(Error::format(path, "not a complete safetensors file (truncated or corrupt)"));
    }
    let n = u64::from_le_bytes(len);
    let size = f.metadata().map_err(|e| Error::io(path, e))?.len();
    if n > 100 << 20 || n + 8 > size {
        return Err(Error::format(path, format!("not a complete safetensors file (truncated or corrupt: a header of {n} bytes in a file of {size})")));
    }
    let mut header = vec![0u8; n as usize];
    f.read_exact(&mut header).map_err(|e| Error::io(path, e))?;
    let json: serde_json::Value = serde_json::from_slice(&header).map_err(|e| Error::format(path, format!("not a safetensors header: {e}")))?;
    Ok(json.pointer(&format!("/__metadata__/{META_KEY}")).and_then(|v| v.as_str()).map(str::to_string))
}

/// One f32 tensor to write: name, shape, and its values as little-endian bytes
/// ([`f32_le_bytes`]), the layout safetensors stores, so a save holds each value once.
pub(crate) type TensorBytes = (String, Vec<usize>, Vec<u8>);

/// `values` as little-endian bytes.
pub(crate) fn f32_le_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Reads a safetensors file of f32 tensors whose header metadata has `"format": format` (`what`
/// names such a file in errors): `(metadata, name → (shape, values))`. The file must be a
/// regular file exactly as long as its header states, and carry its checksum (over the
/// description too, from format 3 on) unless `legacy` (format 1, which had none). Errors name
/// the file (missing, truncated, foreign, another dtype, altered).
#[allow(clippy::type_complexity)]
pub(crate) fn read_f32_safetensors(
    path: &Path,
    format: &str,
    what: &str,
    legacy: bool,
) -> Result<(HashMap<String, String>, HashMap<String, (Vec<usize>, Vec<f32>)>)> {
    crate::files::check_readable(path, what)?;
    let (header_end, data) = stated_data_bytes(path)?;
    let size = std::fs::metadata(path).map_err(|e| Error::io(path, e))?.len();
    if header_end + data != size {
        return Err(Error::format(
            path,
            format!("its header states {} bytes of tensors, the file holds {}: truncated, padded or altered", data, size.saturating_sub(header_end)),
        ));
    }
    let bytes = crate::files::read_bounded(path, MAX_CHECKPOINT_BYTES, what)?;
    let st = SafeTensors::deserialize(&bytes).map_err(|e| Error::format(path, format!("not a complete safetensors file (truncated or corrupt): {e}")))?;
    let (_, header) = SafeTensors::read_metadata(&bytes).map_err(|e| Error::format(path, e.to_string()))?;
    let info = header.metadata().clone().unwrap_or_default();
    if info.get("format").map(String::as_str) != Some(format) {
        return Err(Error::format(path, format!("not a {what} (no \"format\": \"{format}\" in its header)")));
    }
    let views = st.tensors();
    let prev = path.with_file_name(PREV_TENSORS_FILE);
    let hint = if prev.is_file() && prev != path { format!("; {} holds the previous checkpoint", prev.display()) } else { String::new() };
    let computed = tensors_checksum(views.iter().map(|(n, v)| (n.as_str(), v.shape(), v.data())));
    match (info.get(FULL_CHECKSUM_KEY), info.get(CHECKSUM_KEY)) {
        (Some(stored), _) => {
            let full = full_checksum(info.get(META_KEY).map_or("", String::as_str), computed);
            if u32::from_str_radix(stored, 16).ok() != Some(full) {
                return Err(Error::format(
                    path,
                    format!(
                        "checksum mismatch over the description and weights (stored {stored}, computed {full:08x}): the checkpoint is corrupt or altered{hint}"
                    ),
                ));
            }
        }
        (None, Some(stored)) => {
            if u32::from_str_radix(stored, 16).ok() != Some(computed) {
                return Err(Error::format(path, format!("checksum mismatch (stored crc32 {stored}, computed {computed:08x}): the weights are corrupt{hint}")));
            }
        }
        (None, None) if legacy => {}
        (None, None) if TRUST_UNCHECKED.load(std::sync::atomic::Ordering::Relaxed) => {
            eprintln!("warning: {}: has no checksum; loaded as --trust-unchecked-checkpoints asks", path.display());
        }
        (None, None) => {
            return Err(Error::format(
                path,
                format!("has no checksum: not a {what} as socdiff writes it, or altered (--trust-unchecked-checkpoints loads it anyway)"),
            ))
        }
    }
    let mut tensors = HashMap::new();
    for (name, view) in views {
        if view.dtype() != Dtype::F32 {
            return Err(Error::format(path, format!("tensor {name} has dtype {:?}, expected F32", view.dtype())));
        }
        let values: Vec<f32> = view.data().chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        tensors.insert(name, (view.shape().to_vec(), values));
    }
    Ok((info, tensors))
}

/// Checks that data with skeleton `skeleton` fits a checkpoint's model: the same joints by name
/// and order, the same body-frame joints and the same bones. The error names the checkpoint
/// file and the first joint (or bone) that differs.
pub fn check_skeleton(meta: &CheckpointMeta, meta_path: &Path, skeleton: &Skeleton) -> Result<()> {
    meta.skeleton.check_same_layout(skeleton).map_err(|e| Error::format(meta_path, format!("the model does not fit the data: {e}")))
}
