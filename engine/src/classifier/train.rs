//! Training the social-signal classifiers on scenes that carry a `speaking` signal (and, for
//! the buyer detector, the role `buyer`).
//!
//! ```text
//! scenes ─ inputs (inputs.rs) ─ standardization fitted on them
//! for step s in start..steps:
//!     B windows of `window` frames, all with the same person count P, drawn with RNG(seed, s)
//!     loss = BCE(speaking logits, speaking > ½)  over valid frames
//!          + buyer_weight · CE(softmax over persons, buyer)   over windows with a buyer
//!     Adam step (crate::train::Adam); log; checkpoint every save_every steps
//! ```
//!
//! Like the denoiser's trainer, every random draw of step s comes from an RNG seeded by
//! `(seed, s)`, so a checkpoint holds all that is needed to continue exactly (`--resume`).

use super::checkpoint::{self, ClassifierMeta, DataSummary};
pub use super::config::ClassifierConfig;
use super::inputs::{person_dims, scene_inputs, SceneInputs, PAIR_DIMS};
use super::net::SocialSignalNet;
use crate::data::Scene;
use crate::features::Standardization;
use crate::model::Parameterized;
use crate::train::data::{stream_rng, Stream};
pub use crate::train::CheckpointSaved;
use crate::train::{check_uniform, Adam};
use crate::{bail, Error, Result};
use candle_core::{Device, Tensor};
use ndarray::{Array2, Array3, Array4};
use rand::Rng;
use rayon::prelude::*;
use serde_json::json;
use std::io::Write;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

/// Salt mixed into the seed so the classifier's random streams differ from a denoiser run's.
const SEED_SALT: u64 = 0x636c_6173_7369_6669;

/// A training scene: standardized inputs and labels.
pub(crate) struct Prepared {
    /// `[frames, persons, 6J]`, standardized.
    pub(crate) person: Array3<f32>,
    /// `[frames, persons, persons − 1, 7]`, standardized.
    pub(crate) pairs: Array4<f32>,
    /// Speaking labels 0/1 `[frames, persons]`.
    pub(crate) speaking: Array2<f32>,
    /// 1 where the label counts (valid pose) `[frames, persons]`.
    pub(crate) mask: Array2<f32>,
    /// The person with role `buyer`, if exactly one has it.
    pub(crate) buyer: Option<usize>,
}

/// The person with role `buyer`, if exactly one person has it.
pub(crate) fn buyer_of(scene: &Scene) -> Option<usize> {
    let hits: Vec<usize> = scene.persons.iter().enumerate().filter(|(_, p)| p.role.as_deref() == Some("buyer")).map(|(i, _)| i).collect();
    (hits.len() == 1).then(|| hits[0])
}

/// Standardizations of person and pair features fitted over every frame of `inputs`.
pub(crate) fn fit_standardization(inputs: &[SceneInputs]) -> Result<(Standardization, Standardization)> {
    let person = Standardization::fit(inputs.iter().map(|i| i.person.view()))?;
    let with_pairs: Vec<&SceneInputs> = inputs.iter().filter(|i| i.num_persons() > 1).collect();
    let pairs = if with_pairs.is_empty() { Standardization::identity(PAIR_DIMS) } else { Standardization::fit(with_pairs.iter().map(|i| i.pairs.view()))? };
    Ok((person, pairs))
}

/// Inputs of `scene` standardized with `std` (person, pairs).
pub(crate) fn standardized_inputs(scene: &Scene, std: &(Standardization, Standardization)) -> Result<SceneInputs> {
    let mut inp = scene_inputs(scene)?;
    std.0.apply(&mut inp.person)?;
    if inp.num_persons() > 1 {
        std.1.apply(&mut inp.pairs)?;
    }
    Ok(inp)
}

/// Checks a scene for training or evaluation: it has the speaking signal, values finite.
pub(crate) fn speaking_labels(scene: &Scene, signal: &str) -> Result<Array2<f32>> {
    let Some(s) = scene.signals.get(signal) else {
        let have = scene.signals.keys().cloned().collect::<Vec<_>>();
        bail!(
            "scene {} has no {signal:?} signal (signals: {}); the classifiers learn from scenes with speech annotations",
            scene.name,
            if have.is_empty() { "none".to_string() } else { have.join(", ") }
        );
    };
    if let Some(v) = s.iter().find(|v| !v.is_finite()) {
        bail!("scene {}: signal {signal:?} has the value {v}", scene.name);
    }
    Ok(s.mapv(|v| if v > 0.5 { 1.0 } else { 0.0 }))
}

fn mask_of(scene: &Scene) -> Array2<f32> {
    Array2::from_shape_fn((scene.num_frames(), scene.num_persons()), |(f, p)| if scene.is_valid(f, p) { 1.0 } else { 0.0 })
}

/// A batch: tensors for [`SocialSignalNet::forward`] and the losses.
pub(crate) struct Batch {
    /// `[B, P, T, 6J]`.
    pub(crate) person: Tensor,
    /// `[B, P, P − 1, T, 7]`.
    pub(crate) pairs: Tensor,
    /// `[B, P, T]`.
    pub(crate) speaking: Tensor,
    /// `[B, P, T]`.
    pub(crate) mask: Tensor,
    /// One-hot buyer `[B, P]` (zero rows for windows without a buyer).
    pub(crate) buyer: Tensor,
    /// Windows with a buyer.
    pub(crate) buyers: usize,
}

impl Batch {
    /// The batch on `device` (built on the host; one copy per tensor).
    pub(crate) fn into_device(self, device: &candle_core::Device) -> Result<Self> {
        let mv = |t: Tensor| t.to_device(device);
        Ok(Self {
            person: mv(self.person)?,
            pairs: mv(self.pairs)?,
            speaking: mv(self.speaking)?,
            mask: mv(self.mask)?,
            buyer: mv(self.buyer)?,
            buyers: self.buyers,
        })
    }
}

/// Input tensors of windows `(person [F, P, 6J], pairs [F, P, P − 1, 7], start)` of `t` frames,
/// all with the same P: `[B, P, T, 6J]` and `[B, P, P − 1, T, 7]`.
pub(crate) fn input_tensors(windows: &[(&Array3<f32>, &Array4<f32>, usize)], t: usize) -> Result<(Tensor, Tensor)> {
    let Some(first) = windows.first() else { bail!("classifier: no windows") };
    let (_, p, d) = first.0.dim();
    let q = p.saturating_sub(1);
    let b = windows.len();
    let (mut person, mut pairs): (Vec<f32>, Vec<f32>) = (Vec::with_capacity(b * p * t * d), Vec::with_capacity(b * p * q * t * PAIR_DIMS));
    for &(x, r, start) in windows {
        if x.dim().1 != p || x.dim().2 != d || start + t > x.dim().0 {
            bail!("classifier: window {start}..{} of features {:?} does not fit a batch of [{p} persons, {d} dims]", start + t, x.dim());
        }
        for pp in 0..p {
            for f in start..start + t {
                person.extend(x.slice(ndarray::s![f, pp, ..]).iter());
            }
        }
        for pp in 0..p {
            for k in 0..q {
                for f in start..start + t {
                    pairs.extend(r.slice(ndarray::s![f, pp, k, ..]).iter());
                }
            }
        }
    }
    let dev = Device::Cpu;
    Ok((Tensor::from_vec(person, (b, p, t, d), &dev)?, Tensor::from_vec(pairs, vec![b, p, q, t, PAIR_DIMS], &dev)?))
}

/// Builds a batch from `(scene, start)` windows of `t` frames, all scenes with the same
/// person count.
pub(crate) fn make_batch(scenes: &[Prepared], windows: &[(usize, usize)], t: usize) -> Result<Batch> {
    let views: Vec<_> = windows.iter().map(|&(si, start)| (&scenes[si].person, &scenes[si].pairs, start)).collect();
    let (person, pairs) = input_tensors(&views, t)?;
    let (b, p) = (windows.len(), person.dim(1)?);
    let (mut speaking, mut mask, mut buyer): (Vec<f32>, Vec<f32>, Vec<f32>) = (Vec::with_capacity(b * p * t), Vec::with_capacity(b * p * t), vec![0f32; b * p]);
    let mut buyers = 0;
    for (wi, &(si, start)) in windows.iter().enumerate() {
        let s = &scenes[si];
        for pp in 0..p {
            speaking.extend(s.speaking.slice(ndarray::s![start..start + t, pp]).iter());
            mask.extend(s.mask.slice(ndarray::s![start..start + t, pp]).iter());
        }
        if let Some(by) = s.buyer {
            buyer[wi * p + by] = 1.0;
            buyers += 1;
        }
    }
    let dev = Device::Cpu;
    Ok(Batch {
        person,
        pairs,
        speaking: Tensor::from_vec(speaking, (b, p, t), &dev)?,
        mask: Tensor::from_vec(mask, (b, p, t), &dev)?,
        buyer: Tensor::from_vec(buyer, (b, p), &dev)?,
        buyers,
    })
}

/// Mean binary cross-entropy with logits over the entries where `mask` is 1:
/// `softplus(z) − y·z`, with `softplus(z) = max(z, 0) + ln(1 + e^{−|z|})` (no overflow).
///
/// # Shapes
/// - `logits`, `targets`, `mask`: the same shape; returns a scalar.
pub fn bce_with_logits(logits: &Tensor, targets: &Tensor, mask: &Tensor) -> Result<Tensor> {
    let n = mask.sum_all()?.to_dtype(candle_core::DType::F64)?.to_scalar::<f64>()?;
    if n <= 0.0 {
        bail!("bce: no labelled entries");
    }
    let softplus = (logits.relu()? + (logits.abs()?.neg()?.exp()? + 1.0)?.log()?)?;
    let per = (softplus - (targets * logits)?)?;
    Ok(((per * mask)?.sum_all()? / n)?)
}

/// Mean cross-entropy of a softmax across persons, `−ln softmax(scores)[buyer]`, over the rows
/// of `onehot` that hold a 1 (`rows` of them).
///
/// # Shapes
/// - `scores`, `onehot`: `[B, P]`; returns a scalar.
pub fn softmax_cross_entropy(scores: &Tensor, onehot: &Tensor, rows: usize) -> Result<Tensor> {
    if rows == 0 {
        bail!("cross-entropy: no labelled rows");
    }
    // Shift by the (constant) row maximum for stability; the gradient is unchanged.
    let shifted = scores.broadcast_sub(&scores.max_keepdim(1)?.detach())?;
    let log_p = shifted.broadcast_sub(&shifted.exp()?.sum_keepdim(1)?.log()?)?;
    Ok(((log_p * onehot)?.sum_all()?.neg()? / rows as f64)?)
}

/// How to run [`train`].
#[derive(Clone, Debug, Default)]
pub struct TrainOptions {
    /// Output directory (checkpoint, sidecar, log).
    pub out_dir: PathBuf,
    /// Continue the checkpoint in `out_dir` up to `steps` (if given).
    pub resume: bool,
    /// The configuration of a fresh run (ignored on resume except `steps`).
    pub config: ClassifierConfig,
    /// On resume: a new total step count.
    pub steps: Option<usize>,
    /// Where the data came from (recorded in the checkpoint).
    pub source: String,
    /// Set to stop after the current step (a checkpoint is saved first).
    pub stop: Option<Arc<AtomicBool>>,
    /// Device to train on (composed kernels off the CPU; checkpoints load anywhere).
    pub device: crate::model::DeviceChoice,
}

/// What [`train`] reports while it runs.
#[derive(Clone, Debug)]
pub enum TrainEvent {
    /// Training starts (or resumes) at `first_step`.
    Started {
        /// Steps already done.
        first_step: u64,
        /// Total steps of the run.
        total_steps: u64,
        /// Scalar parameters.
        params: usize,
        /// Scenes and frames used.
        scenes: usize,
        /// Frames over those scenes.
        frames: usize,
        /// Fraction of labelled person-frames that speak.
        speaking_fraction: f64,
        /// Scenes with a buyer role.
        with_buyer: usize,
        /// Where it runs ([`crate::model::Placement::describe`]).
        device: String,
    },
    /// A step finished.
    Step {
        /// Steps done (1-based).
        step: u64,
        /// Total loss.
        loss: f32,
        /// Speaking (BCE) part.
        speaking_loss: f32,
        /// Buyer (cross-entropy) part, if the batch had buyers.
        buyer_loss: Option<f32>,
    },
    /// A checkpoint was written.
    Saved(CheckpointSaved),
    /// Something the user should know.
    Notice(String),
}

/// What a call of [`train`] did.
pub type TrainSummary = crate::train::TrainSummary<ClassifierConfig>;

/// Trains (or resumes) the classifiers on `scenes`, writing checkpoints and a JSONL log into
/// `opts.out_dir`. Every check (labels, skeletons, frame rates, window length, an existing
/// checkpoint) happens before anything is written.
pub fn train(scenes: &[Scene], opts: &TrainOptions, on_event: &mut dyn FnMut(&TrainEvent)) -> Result<TrainSummary> {
    let out = &opts.out_dir;
    if scenes.is_empty() {
        bail!("classifier training: no scenes");
    }
    check_uniform(scenes, "classifier training data")?;
    let skeleton = scenes[0].skeleton.clone();
    let fps = scenes[0].fps;

    let resumed = if opts.resume {
        if !checkpoint::exists_in(out) {
            bail!("`resume`: {} holds no classifier checkpoint ({} / {})", out.display(), checkpoint::META_FILE, checkpoint::TENSORS_FILE);
        }
        let ck = checkpoint::ClassifierCheckpoint::read(out)?;
        ck.check_data(&skeleton, fps)?;
        Some(ck)
    } else {
        if checkpoint::exists_in(out) {
            bail!("{} already holds a classifier checkpoint: pass `resume` to continue it, or choose another `out`", out.display());
        }
        None
    };
    let mut cfg = match &resumed {
        Some(ck) => ck.meta.config.clone(),
        None => {
            let mut c = opts.config.clone();
            c.net.person_dims = person_dims(skeleton.num_joints());
            c
        }
    };
    if let Some(s) = opts.steps {
        cfg.steps = s;
    }
    cfg.validate()?;

    // Labels and inputs of every scene.
    let mut notices = Vec::new();
    let labels = scenes.iter().map(|s| speaking_labels(s, &cfg.speaking_signal)).collect::<Result<Vec<_>>>()?;
    let usable: Vec<usize> = (0..scenes.len()).filter(|&i| scenes[i].num_frames() >= cfg.window).collect();
    if usable.is_empty() {
        let longest = scenes.iter().map(|s| s.num_frames()).max().unwrap_or(0);
        bail!("classifier training: the window of {} frames is longer than every scene (longest {longest} frames); pass a smaller `window`", cfg.window);
    }
    if usable.len() < scenes.len() {
        notices.push(format!("{} scene(s) shorter than the window of {} frames are left out", scenes.len() - usable.len(), cfg.window));
    }
    let raw: Vec<SceneInputs> = usable.par_iter().map(|&i| scene_inputs(&scenes[i])).collect::<Result<Vec<_>>>()?;
    let std = match &resumed {
        Some(ck) => (ck.meta.person_standardization.clone(), ck.meta.pair_standardization.clone()),
        None => fit_standardization(&raw)?,
    };
    let prepared: Vec<Prepared> = usable
        .iter()
        .zip(raw)
        .map(|(&i, mut inp)| {
            std.0.apply(&mut inp.person)?;
            if inp.num_persons() > 1 {
                std.1.apply(&mut inp.pairs)?;
            }
            Ok(Prepared { person: inp.person, pairs: inp.pairs, speaking: labels[i].clone(), mask: mask_of(&scenes[i]), buyer: buyer_of(&scenes[i]) })
        })
        .collect::<Result<Vec<_>>>()?;
    let frames: usize = prepared.iter().map(|p| p.person.dim().0).sum();
    let labelled: f64 = prepared.iter().map(|p| p.mask.sum() as f64).sum();
    let speaking_fraction = prepared.iter().map(|p| (&p.speaking * &p.mask).sum() as f64).sum::<f64>() / labelled.max(1.0);
    let with_buyer = prepared.iter().filter(|p| p.buyer.is_some()).count();
    if with_buyer == 0 && cfg.buyer_weight > 0.0 {
        notices.push("no scene has exactly one person with role \"buyer\": the buyer detector is not trained".into());
    }
    // Window starts grouped by person count: (P, [(scene, number of starts)]).
    let mut groups: Vec<(usize, Vec<(usize, usize)>)> = Vec::new();
    for (i, p) in prepared.iter().enumerate() {
        let np = p.person.dim().1;
        let starts = p.person.dim().0 - cfg.window + 1;
        match groups.iter_mut().find(|g| g.0 == np) {
            Some(g) => g.1.push((i, starts)),
            None => groups.push((np, vec![(i, starts)])),
        }
    }
    let group_weight: Vec<usize> = groups.iter().map(|g| g.1.iter().map(|s| s.1).sum()).collect();
    let total_weight: usize = group_weight.iter().sum();

    let placement = opts.device.placement(crate::model::Precision::F32)?;
    let net = match &resumed {
        Some(ck) => ck.network_at(&placement)?,
        None => SocialSignalNet::build(cfg.net.clone(), cfg.seed, &placement)?,
    };
    let mut adam = Adam::new(net.named_vars(), cfg.adam.clone())?;
    adam.set_run_steps(cfg.steps as u64);
    let base_seconds = resumed.as_ref().map_or(0.0, |ck| ck.meta.elapsed_seconds);
    if let Some(ck) = &resumed {
        adam.restore(ck.meta.step, ck.adam_moments(&net)?)?;
    }
    let data = DataSummary { source: opts.source.clone(), scenes: prepared.len(), frames, speaking_fraction, with_buyer };
    drop(resumed);

    // Everything checked: write.
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let log_path = out.join(checkpoint::LOG_FILE);
    if !opts.resume {
        let _ = std::fs::remove_file(&log_path);
    }
    let mut log = std::io::BufWriter::new(crate::files::open_append(&log_path).map_err(|e| Error::io(&log_path, e))?);
    for n in notices {
        on_event(&TrainEvent::Notice(n));
    }
    let first_step = adam.steps();
    on_event(&TrainEvent::Started {
        first_step,
        total_steps: cfg.steps as u64,
        params: net.num_params(),
        scenes: prepared.len(),
        frames,
        speaking_fraction,
        with_buyer,
        device: placement.describe(),
    });

    let started = Instant::now();
    let mut summary = TrainSummary::starting(cfg.clone(), first_step, out.join(checkpoint::TENSORS_FILE));
    let mut last_loss = None;
    let mut saved_at = if opts.resume { Some(first_step) } else { None };
    let save = |net: &SocialSignalNet, adam: &Adam, log: &mut std::io::BufWriter<std::fs::File>, loss: Option<f64>| -> Result<PathBuf> {
        log.flush().map_err(|e| Error::io(&log_path, e))?;
        let meta = ClassifierMeta::new(
            adam.steps(),
            base_seconds + started.elapsed().as_secs_f64(),
            loss,
            fps,
            skeleton.clone(),
            std.clone(),
            cfg.clone(),
            data.clone(),
        );
        checkpoint::write(out, &meta, net, adam)
    };
    for s in first_step..cfg.steps as u64 {
        let mut rng = stream_rng(cfg.seed ^ SEED_SALT, Stream::Step, s);
        let mut pick = rng.gen_range(0..total_weight);
        let g = group_weight
            .iter()
            .position(|&w| {
                if pick < w {
                    true
                } else {
                    pick -= w;
                    false
                }
            })
            .expect("weights cover the range");
        let group = &groups[g].1;
        let windows: Vec<(usize, usize)> = (0..cfg.batch)
            .map(|_| {
                let mut k = rng.gen_range(0..group_weight[g]);
                let &(scene, starts) = group
                    .iter()
                    .find(|&&(_, n)| {
                        if k < n {
                            true
                        } else {
                            k -= n;
                            false
                        }
                    })
                    .expect("weights cover the range");
                (scene, rng.gen_range(0..starts))
            })
            .collect();
        let batch = make_batch(&prepared, &windows, cfg.window)?.into_device(&placement.device)?;
        let outp = net.forward(&batch.person, &batch.pairs)?;
        let speaking_loss = bce_with_logits(&outp.speaking, &batch.speaking, &batch.mask)?;
        let (loss, buyer_loss) = if batch.buyers > 0 && cfg.buyer_weight > 0.0 && groups[g].0 > 1 {
            let bl = softmax_cross_entropy(&outp.buyer, &batch.buyer, batch.buyers)?;
            ((&speaking_loss + (&bl * cfg.buyer_weight)?)?, Some(bl.to_scalar::<f32>()?))
        } else {
            (speaking_loss.clone(), None)
        };
        let value = loss.to_scalar::<f32>()?;
        if !value.is_finite() {
            bail!("classifier training: the loss is {value} at step {}", s + 1);
        }
        adam.step(&loss.backward()?)?;
        let step = adam.steps();
        let sl = speaking_loss.to_scalar::<f32>()?;
        summary.losses.push(value);
        last_loss = Some(value as f64);
        writeln!(
            log,
            "{}",
            json!({"step": step, "loss": value, "speaking_loss": sl, "buyer_loss": buyer_loss, "seconds": base_seconds + started.elapsed().as_secs_f64()})
        )
        .map_err(|e| Error::io(&log_path, e))?;
        on_event(&TrainEvent::Step { step, loss: value, speaking_loss: sl, buyer_loss });
        let stop = opts.stop.as_ref().is_some_and(|f| f.load(Ordering::SeqCst));
        if step.is_multiple_of(cfg.save_every as u64) || step == cfg.steps as u64 || stop {
            let path = save(&net, &adam, &mut log, last_loss)?;
            saved_at = Some(step);
            on_event(&TrainEvent::Saved(CheckpointSaved { step, path }));
        }
        summary.last_step = step;
        if stop {
            summary.stopped = true;
            break;
        }
    }
    if saved_at != Some(adam.steps()) {
        let path = save(&net, &adam, &mut log, last_loss)?;
        on_event(&TrainEvent::Saved(CheckpointSaved { step: adam.steps(), path }));
    }
    log.flush().map_err(|e| Error::io(&log_path, e))?;
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ops::tests::grad_check;

    #[test]
    fn losses_have_known_values_and_gradients() {
        let dev = Device::Cpu;
        // BCE: z = 0 → ln 2 for any target; z = 2, y = 1 → ln(1 + e^{−2}); masked entries ignored.
        let z = Tensor::new(&[0.0f64, 2.0, -3.0, 50.0], &dev).unwrap();
        let y = Tensor::new(&[1.0f64, 1.0, 0.0, 0.0], &dev).unwrap();
        let m = Tensor::new(&[1.0f64, 1.0, 1.0, 0.0], &dev).unwrap();
        let l: f64 = bce_with_logits(&z, &y, &m).unwrap().to_scalar().unwrap();
        let want = (2f64.ln() + (1.0 + (-2f64).exp()).ln() + (1.0 + (-3f64).exp()).ln()) / 3.0;
        assert!((l - want).abs() < 1e-12, "{l} vs {want}");
        // Large logits do not overflow.
        let big = Tensor::new(&[1000.0f64, -1000.0], &dev).unwrap();
        let l: f64 =
            bce_with_logits(&big, &Tensor::new(&[0.0f64, 1.0], &dev).unwrap(), &Tensor::new(&[1.0f64, 1.0], &dev).unwrap()).unwrap().to_scalar().unwrap();
        assert!((l - 1000.0).abs() < 1e-9);
        // Cross-entropy: equal scores → ln P; row without a buyer ignored.
        let s = Tensor::new(&[[0.5f64, 0.5, 0.5], [9.0, 1.0, -2.0]], &dev).unwrap();
        let oh = Tensor::new(&[[0.0f64, 1.0, 0.0], [0.0, 0.0, 0.0]], &dev).unwrap();
        let l: f64 = softmax_cross_entropy(&s, &oh, 1).unwrap().to_scalar().unwrap();
        assert!((l - 3f64.ln()).abs() < 1e-12);
        assert!(softmax_cross_entropy(&s, &oh, 0).is_err());
        assert!(bce_with_logits(&z, &y, &Tensor::zeros(4, candle_core::DType::F64, &dev).unwrap()).is_err());

        let targets = Tensor::new(&[[1.0f64, 0.0, 1.0], [0.0, 0.0, 1.0]], &dev).unwrap();
        let mask = Tensor::new(&[[1.0f64, 1.0, 0.0], [1.0, 1.0, 1.0]], &dev).unwrap();
        let err = grad_check(&[&[2, 3]], |x| bce_with_logits(&(&x[0] * 3.0)?, &targets, &mask).map_err(|e| candle_core::Error::Msg(e.to_string())));
        assert!(err < 1e-6, "bce: {err}");
        let onehot = Tensor::new(&[[0.0f64, 0.0, 1.0], [1.0, 0.0, 0.0]], &dev).unwrap();
        let err = grad_check(&[&[2, 3]], |x| softmax_cross_entropy(&(&x[0] * 3.0)?, &onehot, 2).map_err(|e| candle_core::Error::Msg(e.to_string())));
        assert!(err < 1e-6, "cross-entropy: {err}");
    }
}
