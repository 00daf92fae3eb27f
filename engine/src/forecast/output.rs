//! What a forecast made: [`ForecastOutput`] (the input, K samples, the ground truth) and how
//! it was made ([`Provenance`]), written as a dataset.

use super::model::GuideProvenance;
use super::request::SamplerKind;
use super::task::Task;
use crate::data::dataset::{write_dataset, Dataset, Sequence, Split};
use crate::data::scene::Scene;
use crate::features::PoseEncoding;
use crate::sample::Conditioning;
use crate::Result;
use serde::Serialize;
use serde_json::{json, Map, Value};
use std::path::Path;

#[cfg(doc)]
use super::{sample_scene, sample_seed, Model};

/// The result of [`sample_scene`]: the input part, K sample scenes and provenance.
#[derive(Clone, Debug)]
pub struct ForecastOutput {
    /// Name of the forecast scene (the `source` of every sample).
    pub source: String,
    /// The input part (observed frames, or the scene being completed).
    pub input: Scene,
    /// Sample k, `[canvas frames, persons, J, 3]` world positions.
    pub samples: Vec<Scene>,
    /// The recorded frames of the whole canvas, when the scene has them (forecast only): the
    /// ground truth, written with `"ground_truth": true`.
    pub ground_truth: Option<Scene>,
    /// Frames `0..observed_frames` of every sample are observed (0 for joint/person completion).
    pub observed_frames: usize,
    /// Model, sampler, steps, seed, mask, timings.
    pub provenance: Provenance,
}

/// How a forecast was made, written with it (its dataset's `metadata["forecast"]`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Provenance {
    /// Name of the scene sampled.
    pub source: String,
    /// What was sampled (`{"kind": "forecast", "observe", "horizon"}`, `{"kind": "complete",
    /// "missing": "frames=a..b"}` or `{"kind": "generate", "frames"}`).
    #[serde(serialize_with = "task_json")]
    pub task: Task,
    /// The sampler.
    pub sampler: SamplerKind,
    /// Denoising steps per sample.
    pub steps: usize,
    /// How known entries were imposed.
    pub conditioning: Conditioning,
    /// Known frames at noise level 0.
    pub clean_known: bool,
    /// The features the model was trained on.
    pub pose_encoding: PoseEncoding,
    /// Base seed.
    pub seed: u64,
    /// Context inversion of the observed frames, when on.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub context_inversion: Option<crate::sample::ContextInversion>,
    /// The seed of each sample ([`sample_seed`]).
    pub sample_seeds: Vec<u64>,
    /// Samples K.
    pub samples: usize,
    /// Frame every person is anchored at.
    pub anchor_frame: usize,
    /// The known entries of the canvas.
    pub mask: MaskSummary,
    /// Where the time went.
    pub timings: Timings,
    /// The run directory of the model, when a [`Model`] sampled.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub model: Option<String>,
    /// Its optimizer step.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub model_step: Option<u64>,
    /// Which of its weights.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub weights: Option<crate::checkpoint::Weights>,
    /// Where it ran ([`crate::model::Placement::describe`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub device: Option<String>,
    /// The file or directory the scene came from.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub input: Option<String>,
    /// Persons of the scene that were kept, by index (all when absent).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub persons: Option<Vec<usize>>,
    /// Where the placement of generated persons came from.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub layout: Option<String>,
    /// The weaker model that guided the samples, when one did ([`Model::with_guide`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub guide: Option<GuideProvenance>,
}

/// The known entries of a sampling canvas `[frames, persons, dims]`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct MaskSummary {
    /// Canvas frames.
    pub frames: usize,
    /// Persons.
    pub persons: usize,
    /// Feature dims per person and frame.
    pub dims: usize,
    /// Entries copied from the input.
    pub known_entries: usize,
}

/// Seconds spent by [`sample_scene`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Timings {
    /// Everything, from the canvas to the positions.
    pub total_seconds: f64,
    /// The reverse process.
    pub sampling_seconds: f64,
    /// Inside the network.
    pub model_seconds: f64,
    /// Network evaluations (each on a batch of samples).
    pub model_calls: usize,
    /// Samples per evaluation.
    pub samples_per_call: usize,
    /// Sampling seconds per network evaluation.
    pub seconds_per_step: f64,
    /// Sampling seconds per sample and denoising step.
    pub seconds_per_sample_step: f64,
}

fn task_json<S: serde::Serializer>(task: &Task, s: S) -> std::result::Result<S::Ok, S::Error> {
    match task {
        Task::Forecast { observe, horizon } => json!({"kind": "forecast", "observe": observe, "horizon": horizon}),
        Task::Complete(m) => json!({"kind": "complete", "missing": m.describe()}),
        Task::Generate { frames, anchor } => json!({"kind": "generate", "frames": frames, "anchor": anchor}),
    }
    .serialize(s)
}

impl Provenance {
    /// A record of `task` on the scene `source` with only the task and source set (the rest
    /// zero or absent).
    pub fn of(source: &str, task: Task) -> Self {
        Self {
            source: source.to_string(),
            task,
            sampler: SamplerKind::Ddpm,
            steps: 0,
            conditioning: Conditioning::default(),
            clean_known: false,
            pose_encoding: PoseEncoding::default(),
            seed: 0,
            context_inversion: None,
            sample_seeds: Vec::new(),
            samples: 0,
            anchor_frame: 0,
            mask: MaskSummary::default(),
            timings: Timings::default(),
            model: None,
            model_step: None,
            weights: None,
            device: None,
            input: None,
            persons: None,
            layout: None,
            guide: None,
        }
    }
}

impl ForecastOutput {
    /// The forecast as a dataset (test split): the input part, the ground truth (if any), then
    /// the samples; provenance in the dataset metadata under `"forecast"`.
    pub fn to_dataset(&self) -> Dataset {
        let mut sequences = vec![Sequence { split: Split::Test, scene: self.input.clone() }];
        if let Some(gt) = &self.ground_truth {
            sequences.push(Sequence { split: Split::Test, scene: gt.clone() });
        }
        sequences.extend(self.samples.iter().map(|s| Sequence { split: Split::Test, scene: s.clone() }));
        let mut metadata = Map::new();
        metadata.insert("forecast".into(), serde_json::to_value(&self.provenance).unwrap_or(Value::Null));
        Dataset { name: format!("{}_forecast", self.source), sequences, metadata }
    }

    /// Writes [`ForecastOutput::to_dataset`] to `dir` (which must not exist or be empty).
    pub fn write(&self, dir: &Path) -> Result<()> {
        write_dataset(&self.to_dataset(), dir)
    }
}
