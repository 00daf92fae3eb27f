//! Who speaks and who is the buyer, for SSCP ([`crate::metrics::sscp`]).
//!
//! SSCP needs, per frame, the speaking bits of the three persons of a triad and which person
//! is the buyer. [`SignalSource`] says where they come from:
//!
//! - [`SignalSource::Annotations`]: the scene's own speaking signal and person roles (Haggling
//!   speech files). Forecast samples carry no future speech, so only recorded scenes (ground
//!   truth) are scored this way.
//! - [`SignalSource::Computed`]: a function of the motion (e.g. the speaking and buyer
//!   classifiers) that returns per-frame arrays ([`SocialSignals`]); they are turned into
//!   states by [`states_from_signals`].
//! - [`SignalSource::Classified`]: the scene's annotations where present, the rest filled in by
//!   a function of the motion (the trained speaking and buyer classifiers,
//!   `SocialSignalClassifiers::annotate`): recorded scenes keep their speech, forecast samples
//!   (which carry none) are classified.
//!
//! When the signals are unavailable, SSCP is skipped with the reason ([`Availability`]).

use crate::data::{Scene, Skeleton};
use crate::metrics::sscp::{scene_states, sequence_states, SscpConfig, Triad};
use crate::{bail, Result};
use ndarray::{Array2, ArrayView2, ArrayView4};

/// Per-frame social signals of one scene, as a classifier gives them.
///
/// # Shapes
/// - `speaking`: `[frames, persons]`, a person speaks where the value exceeds
///   [`SscpConfig::speaking_threshold`];
/// - `buyer`: `[frames, persons]`, buyer score per frame (see [`states_from_signals`]).
#[derive(Clone, Debug, PartialEq)]
pub struct SocialSignals {
    /// Speaking indicator or probability.
    pub speaking: Array2<f32>,
    /// Buyer score (e.g. logit or probability).
    pub buyer: Array2<f32>,
}

/// A function computing [`SocialSignals`] from a scene's motion.
pub type SignalFn<'a> = &'a (dyn Fn(&Scene) -> Result<SocialSignals> + Sync);

/// A function returning `scene` with its missing speaking signal and roles filled in.
pub type AnnotateFn<'a> = &'a (dyn Fn(&Scene) -> Result<Scene> + Sync);

/// Where SSCP's speaking and buyer information comes from (module docs).
#[derive(Clone, Copy, Default)]
pub enum SignalSource<'a> {
    /// The scene's speaking signal ([`SscpConfig::speaking_signal`]) and person roles.
    #[default]
    Annotations,
    /// Computed from the motion by `compute`, named `name` in the report.
    Computed {
        /// Name for the report (e.g. the classifier checkpoints).
        name: &'a str,
        /// The signals of a scene.
        compute: SignalFn<'a>,
    },
    /// Annotations where present, otherwise what `annotate` adds, named `name` in the report.
    Classified {
        /// Name for the report (e.g. the classifier directory).
        name: &'a str,
        /// The scene with missing signals and roles filled in.
        annotate: AnnotateFn<'a>,
    },
}

/// SSCP states of a scene, or why they cannot be had.
#[derive(Clone, Debug, PartialEq)]
pub enum Availability {
    /// The state of every frame.
    States(Vec<usize>),
    /// SSCP cannot be computed for this scene; the reason.
    Missing(String),
}

impl SignalSource<'_> {
    /// Description for the report.
    pub fn describe(&self, cfg: &SscpConfig) -> String {
        match self {
            SignalSource::Annotations => format!("annotations: scene signal {:?} and person roles", cfg.speaking_signal),
            SignalSource::Computed { name, .. } => format!("computed: {name}"),
            SignalSource::Classified { name, .. } => {
                format!("annotations (scene signal {:?} and person roles) where present, otherwise classifiers: {name}", cfg.speaking_signal)
            }
        }
    }

    /// SSCP states of every frame of `scene` (module docs).
    pub fn states(&self, scene: &Scene, cfg: &SscpConfig) -> Result<Availability> {
        let annotated = matches!(self, SignalSource::Annotations | SignalSource::Classified { .. });
        if annotated && scene.num_persons() != 3 {
            // Before any classifier runs on it.
            return Ok(Availability::Missing(format!("scene {} has {} persons, SSCP needs a triad", scene.name, scene.num_persons())));
        }
        match self {
            SignalSource::Classified { annotate, .. } => SignalSource::Annotations.states(&annotate(scene)?, cfg),
            SignalSource::Annotations => {
                if !scene.signals.contains_key(&cfg.speaking_signal) {
                    return Ok(Availability::Missing(format!(
                        "scene {} has no {:?} signal (a speaking classifier would be needed)",
                        scene.name, cfg.speaking_signal
                    )));
                }
                if let Err(e) = Triad::from_roles(scene) {
                    return Ok(Availability::Missing(format!("{e} (a buyer classifier would be needed)")));
                }
                Ok(Availability::States(scene_states(scene, cfg)?))
            }
            SignalSource::Computed { compute, .. } => {
                let sig = compute(scene)?;
                Ok(Availability::States(states_from_signals(scene.positions.view(), &scene.skeleton, sig.speaking.view(), sig.buyer.view(), cfg)?))
            }
        }
    }
}

/// SSCP states from per-frame speaking and buyer arrays — the hook for classifiers.
///
/// The buyer is the person whose score is the largest on the most frames (ties: the lowest
/// index); the sellers are the two others in ascending index order, the first called "left"
/// (the reference's index-based convention, REFERENCE.md §5.2).
///
/// # Shapes
/// - `positions`: `[frames, 3, joints, 3]` on `skeleton`; `speaking`, `buyer`: `[frames, 3]`;
///   output `[frames]`.
pub fn states_from_signals(
    positions: ArrayView4<f32>,
    skeleton: &Skeleton,
    speaking: ArrayView2<f32>,
    buyer: ArrayView2<f32>,
    cfg: &SscpConfig,
) -> Result<Vec<usize>> {
    let (f, p, _, _) = positions.dim();
    if p != 3 {
        bail!("SSCP: {p} persons, a triad needs 3");
    }
    if speaking.dim() != (f, p) || buyer.dim() != (f, p) {
        bail!("SSCP: speaking and buyer signals have shapes {:?} and {:?}, expected [{f}, {p}]", speaking.dim(), buyer.dim());
    }
    let mut votes = [0usize; 3];
    for row in buyer.rows() {
        let best = (0..3).fold(0, |b, i| if row[i] > row[b] { i } else { b });
        votes[best] += 1;
    }
    let b = (0..3).fold(0, |best, i| if votes[i] > votes[best] { i } else { best });
    let sellers: Vec<usize> = (0..3).filter(|&i| i != b).collect();
    let triad = Triad::new(sellers[0], sellers[1], b)?;
    sequence_states(positions, skeleton, speaking, &triad, cfg)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::test_util::walkers;
    use crate::data::Person;
    use crate::metrics::sscp::state_index;

    #[test]
    fn computed_and_annotated_signals_give_the_same_states() {
        let f = 30;
        let speaking = Array2::from_shape_fn((f, 3), |(t, p)| if (t / 10) % 3 == p { 1.0 } else { 0.0 });
        let roles = ["left_seller", "right_seller", "buyer"];
        let scene = walkers(f, 3, 0.4)
            .with_signal("speaking", speaking.clone())
            .unwrap()
            .with_persons(roles.iter().enumerate().map(|(i, r)| Person { id: i.to_string(), role: Some(r.to_string()) }).collect())
            .unwrap();
        let cfg = SscpConfig::default();
        let Availability::States(a) = SignalSource::Annotations.states(&scene, &cfg).unwrap() else { panic!("annotated") };
        // Buyer score: person 2 wins most frames.
        let buyer = Array2::from_shape_fn((f, 3), |(t, p)| if p == 2 || (p == 0 && t < 5) { 1.0 } else { 0.0 });
        let compute = |s: &Scene| Ok(SocialSignals { speaking: s.signals["speaking"].clone(), buyer: buyer.clone() });
        let src = SignalSource::Computed { name: "test", compute: &compute };
        assert_eq!(src.states(&scene, &cfg).unwrap(), Availability::States(a.clone()));
        // Frame 0: left seller (0) speaks; frame 25: buyer speaks.
        assert_eq!(a[0] & !1, state_index(true, false, false, false));
        assert_eq!(a[25] & !1, state_index(false, false, true, false));
        // Without the signal or the roles: skipped with a reason.
        let bare = walkers(f, 3, 0.4);
        let Availability::Missing(why) = SignalSource::Annotations.states(&bare, &cfg).unwrap() else { panic!("no signal") };
        assert!(why.contains("\"speaking\""), "{why}");
        assert!(states_from_signals(bare.positions.view(), &bare.skeleton, speaking.view(), buyer.slice(ndarray::s![..3, ..]), &cfg).is_err());
    }

    /// `Classified` keeps a scene's own annotations and fills in only what is missing.
    #[test]
    fn classified_uses_annotations_first_and_fills_in_the_rest() {
        let f = 30;
        let speaking = Array2::from_shape_fn((f, 3), |(t, p)| if (t / 10) % 3 == p { 1.0 } else { 0.0 });
        let roles = ["left_seller", "right_seller", "buyer"];
        let with_roles =
            |s: Scene| s.with_persons(roles.iter().enumerate().map(|(i, r)| Person { id: i.to_string(), role: Some(r.to_string()) }).collect()).unwrap();
        let annotated = with_roles(walkers(f, 3, 0.4).with_signal("speaking", speaking.clone()).unwrap());
        let cfg = SscpConfig::default();
        let Availability::States(truth) = SignalSource::Annotations.states(&annotated, &cfg).unwrap() else { panic!("annotated") };
        // A "classifier" that says nobody speaks and knows the roles.
        let calls = std::sync::atomic::AtomicUsize::new(0);
        let annotate = |s: &Scene| {
            calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let out = if s.signals.contains_key("speaking") { s.clone() } else { s.clone().with_signal("speaking", Array2::zeros((s.num_frames(), 3)))? };
            Ok(if Triad::from_roles(&out).is_ok() { out } else { with_roles(out) })
        };
        let src = SignalSource::Classified { name: "test", annotate: &annotate };
        assert_eq!(src.states(&annotated, &cfg).unwrap(), Availability::States(truth.clone()), "annotations kept");
        let Availability::States(silent) = src.states(&walkers(f, 3, 0.4), &cfg).unwrap() else { panic!("filled in") };
        assert!(silent.iter().all(|&st| st & !1 == state_index(false, false, false, false)), "{silent:?}");
        assert_ne!(silent, truth);
        assert_eq!(calls.load(std::sync::atomic::Ordering::Relaxed), 2);
        assert!(src.describe(&cfg).contains("classifiers: test"));
        // Not a triad: skipped, the classifier is not asked.
        let Availability::Missing(why) = src.states(&walkers(f, 2, 0.4), &cfg).unwrap() else { panic!("pair") };
        assert!(why.contains("2 persons"), "{why}");
    }
}
