//! What part of a scene is known and what is sampled: [`Task`], [`Missing`], and the one
//! check of a request against its scene ([`check_task`]).

use crate::data::scene::Scene;
use crate::{bail, Error, Result};
use std::ops::Range;

/// Which part of a scene is unknown, for completion.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Missing {
    /// These joints (skeleton indices) on every frame of every person.
    Joints(Vec<usize>),
    /// These frames of every person.
    Frames(Range<usize>),
    /// These persons (scene indices) on every frame.
    Persons(Vec<usize>),
}

impl Missing {
    /// Parses `joints=NAME|INDEX,…`, `frames=a..b` or `persons=i,…` (joint names from `skeleton`).
    pub fn parse(spec: &str, skeleton: &crate::data::Skeleton) -> Result<Self> {
        let (kind, list) = spec.split_once('=').ok_or_else(|| Error::invalid(format!("`missing` {spec:?}: expected joints=…, frames=a..b or persons=…")))?;
        let items = || list.split(',').map(str::trim).filter(|s| !s.is_empty());
        match kind.trim() {
            "joints" => {
                let mut v = Vec::new();
                for it in items() {
                    let j = match it.parse::<usize>() {
                        Ok(j) => j,
                        Err(_) => skeleton
                            .joint_index(it)
                            .ok_or_else(|| Error::invalid(format!("`missing` joints: skeleton {} has no joint {it:?}", skeleton.name)))?,
                    };
                    v.push(j);
                }
                Ok(Missing::Joints(v))
            }
            "frames" => {
                let (a, b) = list.split_once("..").ok_or_else(|| Error::invalid(format!("`missing` frames={list}: expected a..b")))?;
                let p = |x: &str| x.trim().parse::<usize>().map_err(|_| Error::invalid(format!("`missing` frames={list}: {x:?} is not a frame index")));
                Ok(Missing::Frames(p(a)?..p(b)?))
            }
            "persons" => {
                let v = items()
                    .map(|x| x.parse::<usize>().map_err(|_| Error::invalid(format!("`missing` persons: {x:?} is not a person index"))))
                    .collect::<Result<Vec<_>>>()?;
                Ok(Missing::Persons(v))
            }
            other => bail!("`missing` {other}=…: expected joints, frames or persons"),
        }
    }

    /// The spec as text (`joints=1,2`, `frames=3..9`, `persons=0`).
    pub fn describe(&self) -> String {
        let list = |v: &[usize]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>().join(",");
        match self {
            Missing::Joints(v) => format!("joints={}", list(v)),
            Missing::Frames(r) => format!("frames={}..{}", r.start, r.end),
            Missing::Persons(v) => format!("persons={}", list(v)),
        }
    }
}

/// What to sample.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Task {
    /// Frames `0..observe` known, `horizon` frames after them sampled.
    Forecast {
        /// Observed frames (taken from the start of the scene).
        observe: usize,
        /// Forecast frames.
        horizon: usize,
    },
    /// The scene with a part unknown.
    Complete(Missing),
    /// A whole scene of `frames` frames from noise: only each person's placement (root and
    /// heading) at frame 0 of the scene (the layout) is taken, held at canvas frame `anchor`,
    /// and — for a residual-pose model — the body its motion is measured from.
    Generate {
        /// Frames generated.
        frames: usize,
        /// The frame that has the layout's placement ([`Model::generate_task`]: the model's
        /// anchor frame, where every training window has its persons at their anchors; a
        /// placement elsewhere fights that prior, e.g. frame 0 holds the person still until it).
        anchor: usize,
    },
}

/// Checks a request of `samples` samples of `task` on `scene`, once, before anything is
/// allocated: the task's frames, persons and joints against the scene, and the size of the
/// whole canvas ([`crate::data::check_size`]). The error says what is wrong.
pub fn check_task(scene: &Scene, task: &Task, samples: usize) -> Result<()> {
    if samples == 0 || samples > crate::data::MAX_SAMPLES {
        bail!("`samples` must be in 1..={}, got {samples}", crate::data::MAX_SAMPLES);
    }
    let (nf, np, nj) = (scene.num_frames(), scene.num_persons(), scene.num_joints());
    match task {
        Task::Forecast { observe, horizon } => {
            if *observe == 0 {
                bail!("`observe` must be at least 1");
            }
            if *observe > nf {
                bail!("`observe` {observe} is more than the scene length ({nf} frames in {})", scene.name);
            }
            if *horizon == 0 {
                bail!("`horizon` must be at least 1");
            }
        }
        Task::Complete(Missing::Frames(r)) => {
            if r.start >= r.end || r.end > nf {
                bail!("`missing` frames={}..{}: not a non-empty part of 0..{nf} ({})", r.start, r.end, scene.name);
            }
            if r.start == 0 && r.end == nf {
                bail!("`missing` frames={}..{}: every frame missing, nothing to complete from", r.start, r.end);
            }
        }
        Task::Complete(Missing::Persons(v)) => {
            if v.is_empty() {
                bail!("`missing` persons=: no persons given");
            }
            if let Some(p) = v.iter().find(|&&p| p >= np) {
                bail!("`missing` persons: person {p} out of range ({} has {np} persons)", scene.name);
            }
            if (0..np).all(|p| v.contains(&p)) {
                bail!("`missing` persons: every person missing, nothing to complete from");
            }
        }
        Task::Complete(Missing::Joints(v)) => {
            if v.is_empty() {
                bail!("`missing` joints=: no joints given");
            }
            if let Some(j) = v.iter().find(|&&j| j >= nj) {
                bail!("`missing` joints: joint {j} out of range (skeleton {} has {nj} joints)", scene.skeleton.name);
            }
        }
        Task::Generate { frames, anchor } => {
            if *frames < 2 {
                bail!("generating {frames} frames: need at least 2");
            }
            if anchor >= frames {
                bail!("generating {frames} frames with the placement at frame {anchor}: it must be one of them");
            }
        }
    }
    let what = match task {
        Task::Generate { .. } => format!("generation from the layout of {}", scene.name),
        _ => format!("forecast of {}", scene.name),
    };
    crate::data::check_size(&what, canvas_frames(scene, task) as f64, np, samples)
}

/// Frames of the canvas of `task` on `scene`: observed + forecast frames, or the scene's.
pub fn canvas_frames(scene: &Scene, task: &Task) -> usize {
    match task {
        Task::Forecast { observe, horizon } => observe.saturating_add(*horizon),
        Task::Complete(_) => scene.num_frames(),
        Task::Generate { frames, .. } => *frames,
    }
}
