//! Social-signal classifiers for SSCP (METHOD.md §5, REFERENCE.md §5.3): who speaks on every
//! frame, and which of three persons is the buyer, learnt from motion.
//!
//! SSCP needs speaking indicators and the buyer's role. Recorded scenes may carry them (the
//! Haggling speech files); forecasts do not. The reference's two checkpoints are not
//! published and it has no training code, so socdiff trains and evaluates its own:
//!
//! ```text
//! scenes with `speaking` + roles ─ inputs.rs (body-frame pose, velocity, pair cues)
//!                                ─ net.rs (BiGRU encoder, mean/max pooling across persons)
//!                                      ├─ speaking logit per person and frame
//!                                      └─ buyer score per person, softmax across persons
//! train.rs: BCE + cross-entropy, Adam; checkpoint.rs: safetensors + JSON sidecar
//! eval.rs: per-frame accuracy, balanced accuracy, F1; buyer accuracy per scene
//! crate::data::synthetic::triads: generated triads (real speaking timelines, bodies from real
//!           motion) to train and measure on where no real scene has both bodies and speech
//! ```
//!
//! [`SocialSignalClassifiers`] is what the SSCP evaluation calls:
//! `SocialSignalClassifiers::load(dir)?.predict(&scene)?` gives the speaking probability
//! `[frames, persons]` and the buyer; [`SocialSignalClassifiers::annotate`] fills in a scene's
//! missing `speaking` signal and roles so that [`crate::metrics::sscp::scene_states`] can run.
//!
//! Differences to the reference, on purpose: one shared encoder for both tasks (the reference
//! has a 7.6M-parameter speech GRU and a 7M-parameter buyer CNN), the buyer detector is
//! order-invariant instead of checking three clockwise arrangements, inputs are z-scored and
//! include velocities and who-looks-at-whom cues, and inference runs in overlapping windows of
//! the training length rather than over the whole sequence at once.

pub mod checkpoint;
pub mod config;
pub mod eval;
pub mod gru;
pub mod inputs;
pub mod net;
pub mod train;

pub use checkpoint::{ClassifierCheckpoint, ClassifierMeta};
pub use config::ClassifierOverrides;
pub use eval::{evaluate, Evaluation, SpeakingCounts};
pub use net::{NetConfig, SocialSignalNet};
pub use train::{ClassifierConfig, TrainEvent, TrainOptions, TrainSummary};

use crate::data::{Person, Scene};
use crate::metrics::sscp::Triad;
use crate::{bail, Result};
use ndarray::Array2;
use std::path::{Path, PathBuf};

/// Windows per forward pass at inference.
const INFERENCE_BATCH: usize = 16;

/// What the classifiers say about a scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Prediction {
    /// Probability that each person speaks, `[frames, persons]`.
    pub speaking_probability: Array2<f32>,
    /// Probability that each person is the buyer, `[persons]` (softmax across persons, averaged
    /// over the windows).
    pub buyer_probability: Vec<f32>,
    /// The most likely buyer.
    pub buyer: usize,
}

impl Prediction {
    /// Speaking indicators (1 where the probability exceeds ½), `[frames, persons]`.
    pub fn speaking(&self) -> Array2<f32> {
        self.speaking_probability.mapv(|p| if p > 0.5 { 1.0 } else { 0.0 })
    }
}

/// Trained classifiers, ready for inference.
#[derive(Clone)]
pub struct SocialSignalClassifiers {
    net: SocialSignalNet,
    meta: ClassifierMeta,
    path: PathBuf,
}

/// Start frames of windows of `w` frames covering `n` frames with half-window overlap (one
/// window of `n` frames when `n ≤ w`).
fn window_starts(n: usize, w: usize) -> Vec<usize> {
    if n <= w {
        return vec![0];
    }
    let step = (w / 2).max(1);
    let mut starts: Vec<usize> = (0..=n - w).step_by(step).collect();
    if *starts.last().expect("n > w") != n - w {
        starts.push(n - w);
    }
    starts
}

impl SocialSignalClassifiers {
    /// Loads a classifier directory (or its `classifier.json`) written by `socdiff classifier
    /// train`. Errors name the file that is missing or broken.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let ck = ClassifierCheckpoint::read(path.as_ref())?;
        let net = ck.network()?.frozen();
        Ok(Self { net, meta: ck.meta, path: ck.meta_path })
    }

    /// The sidecar (config, skeleton, fps, training data).
    pub fn meta(&self) -> &ClassifierMeta {
        &self.meta
    }

    /// Checks that a scene fits: same skeleton (joint names, body-frame joints) and frame rate as
    /// the training data.
    pub fn check_scene(&self, scene: &Scene) -> Result<()> {
        let m = &self.meta;
        if m.skeleton.joints != scene.skeleton.joints || (m.skeleton.left, m.skeleton.right) != (scene.skeleton.left, scene.skeleton.right) {
            bail!(
                "scene {}: skeleton {} ({} joints) differs from the classifiers' {} ({} joints, {})",
                scene.name,
                scene.skeleton.name,
                scene.num_joints(),
                m.skeleton.name,
                m.skeleton.num_joints(),
                self.path.display()
            );
        }
        if (m.fps - scene.fps).abs() > 1e-6 * m.fps {
            bail!(
                "scene {} is at {} fps, the classifiers ({}) at {} fps: resample it to {} fps first",
                scene.name,
                scene.fps,
                self.path.display(),
                m.fps,
                m.fps
            );
        }
        Ok(())
    }

    /// Speaking probabilities and the buyer of `scene` (any number of frames ≥ 2 and persons
    /// ≥ 1; the buyer is meaningful for triads). Overlapping windows of the training length are
    /// averaged (logits per frame, buyer probabilities per window).
    pub fn predict(&self, scene: &Scene) -> Result<Prediction> {
        self.check_scene(scene)?;
        let std = (self.meta.person_standardization.clone(), self.meta.pair_standardization.clone());
        let inp = train::standardized_inputs(scene, &std)?;
        let (n, p) = (inp.num_frames(), inp.num_persons());
        let w = self.meta.config.window.min(n);
        let starts = window_starts(n, w);
        let mut logit_sum = Array2::<f64>::zeros((n, p));
        let mut cover = vec![0.0f64; n];
        let mut buyer_sum = vec![0.0f64; p];
        for chunk in starts.chunks(INFERENCE_BATCH) {
            let views: Vec<_> = chunk.iter().map(|&s| (&inp.person, &inp.pairs, s)).collect();
            let (person, pairs) = train::input_tensors(&views, w)?;
            let out = self.net.forward(&person, &pairs)?;
            let logits: Vec<Vec<Vec<f32>>> = out.speaking.to_vec3()?;
            let scores: Vec<Vec<f32>> = out.buyer.to_vec2()?;
            for (k, &s) in chunk.iter().enumerate() {
                for t in 0..w {
                    cover[s + t] += 1.0;
                    for pp in 0..p {
                        logit_sum[[s + t, pp]] += logits[k][pp][t] as f64;
                    }
                }
                let max = scores[k].iter().copied().fold(f32::NEG_INFINITY, f32::max) as f64;
                let e: Vec<f64> = scores[k].iter().map(|&v| (v as f64 - max).exp()).collect();
                let z: f64 = e.iter().sum();
                for (b, v) in buyer_sum.iter_mut().zip(&e) {
                    *b += v / z;
                }
            }
        }
        let speaking_probability = Array2::from_shape_fn((n, p), |(t, pp)| (1.0 / (1.0 + (-logit_sum[[t, pp]] / cover[t]).exp())) as f32);
        let buyer_probability: Vec<f32> = buyer_sum.iter().map(|v| (v / starts.len() as f64) as f32).collect();
        let buyer = buyer_probability.iter().enumerate().fold(0, |best, (i, &v)| if v > buyer_probability[best] { i } else { best });
        Ok(Prediction { speaking_probability, buyer_probability, buyer })
    }

    /// `scene` with what SSCP needs filled in where it is missing: the speaking signal (named
    /// as in the training config, 0/1) and, for a triad without a `buyer` role, the roles
    /// `buyer` (predicted), `left_seller` and `right_seller` (by geometry,
    /// [`Triad::from_buyer`]). What the scene already has is kept.
    pub fn annotate(&self, scene: &Scene) -> Result<Scene> {
        let signal = &self.meta.config.speaking_signal;
        let has_roles = Triad::from_roles(scene).is_ok();
        if scene.signals.contains_key(signal) && has_roles {
            return Ok(scene.clone());
        }
        let pred = self.predict(scene)?;
        let mut out = scene.clone();
        if !scene.signals.contains_key(signal) {
            out = out.with_signal(signal.clone(), pred.speaking())?;
        }
        if !has_roles && scene.num_persons() == 3 {
            let triad = Triad::from_buyer(scene, pred.buyer)?;
            let persons = (0..3)
                .map(|i| {
                    let role = if i == triad.buyer {
                        "buyer"
                    } else if i == triad.left {
                        "left_seller"
                    } else {
                        "right_seller"
                    };
                    Person { id: scene.persons[i].id.clone(), role: Some(role.into()) }
                })
                .collect();
            out = out.with_persons(persons)?;
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests;
