//! Datasets: named scenes with a train/test split, stored as a dataset directory
//! (`dataset.json` + `.npy` files), socdiff's native format.

use super::scene::Scene;
use crate::{bail, Result};
use serde::{Deserialize, Serialize};

/// Which part of a dataset a sequence belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    /// Used to fit models.
    Train,
    /// Held out for evaluation.
    Test,
    /// Held out for model selection.
    Validation,
}

impl Split {
    /// Parses `train`, `test` or `validation`/`val`.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "train" => Ok(Split::Train),
            "test" => Ok(Split::Test),
            "validation" | "val" => Ok(Split::Validation),
            _ => bail!("unknown split {s:?} (expected train, test or validation)"),
        }
    }

    /// Lower-case name, as written in `dataset.json`.
    pub fn as_str(&self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Test => "test",
            Split::Validation => "validation",
        }
    }
}

/// One sequence of a dataset.
#[derive(Clone, Debug, PartialEq)]
pub struct Sequence {
    /// Which split it belongs to.
    pub split: Split,
    /// The motion.
    pub scene: Scene,
}

/// A collection of named scenes with a split.
#[derive(Clone, Debug, PartialEq)]
pub struct Dataset {
    /// Dataset name.
    pub name: String,
    /// Sequences in file order.
    pub sequences: Vec<Sequence>,
    /// Extra top-level fields of `dataset.json` (description, licence, ...), kept on rewrite.
    pub metadata: serde_json::Map<String, serde_json::Value>,
}

impl Dataset {
    /// Scenes of one split.
    pub fn split(&self, split: Split) -> impl Iterator<Item = &Scene> {
        self.sequences.iter().filter(move |s| s.split == split).map(|s| &s.scene)
    }

    /// The scene called `name`.
    pub fn scene(&self, name: &str) -> Result<&Scene> {
        match self.sequences.iter().find(|s| s.scene.name == name) {
            Some(s) => Ok(&s.scene),
            None => bail!(
                "dataset {} has no sequence {name:?} (sequences: {})",
                self.name,
                self.sequences.iter().map(|s| s.scene.name.as_str()).collect::<Vec<_>>().join(", ")
            ),
        }
    }

    /// Total number of frames over all sequences.
    pub fn num_frames(&self) -> usize {
        self.sequences.iter().map(|s| s.scene.num_frames()).sum()
    }
}
