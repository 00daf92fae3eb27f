//! Evaluation of the classifiers on scenes with known speaking signals and roles.
//!
//! - speaking, per valid (frame, person): accuracy, balanced accuracy (mean of the recalls of
//!   both classes, insensitive to how rare speaking is), precision, recall and F1 of the
//!   class "speaks", and the accuracy of always answering "silent" for comparison;
//! - buyer, per scene with exactly one `buyer`: whether the predicted buyer is that person.

use super::train::{buyer_of, speaking_labels};
use super::SocialSignalClassifiers;
use crate::data::Scene;
use crate::{bail, Result};
use serde::Serialize;

/// Confusion counts of per-frame speaking predictions.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct SpeakingCounts {
    /// Speaks, predicted speaking.
    pub true_positive: u64,
    /// Silent, predicted speaking.
    pub false_positive: u64,
    /// Silent, predicted silent.
    pub true_negative: u64,
    /// Speaks, predicted silent.
    pub false_negative: u64,
}

fn ratio(a: u64, b: u64) -> f64 {
    if b == 0 {
        0.0
    } else {
        a as f64 / b as f64
    }
}

impl SpeakingCounts {
    /// Counts `(label, prediction)` pairs.
    pub fn add(&mut self, speaks: bool, predicted: bool) {
        match (speaks, predicted) {
            (true, true) => self.true_positive += 1,
            (false, true) => self.false_positive += 1,
            (false, false) => self.true_negative += 1,
            (true, false) => self.false_negative += 1,
        }
    }

    /// Adds another set of counts.
    pub fn merge(&mut self, o: &SpeakingCounts) {
        self.true_positive += o.true_positive;
        self.false_positive += o.false_positive;
        self.true_negative += o.true_negative;
        self.false_negative += o.false_negative;
    }

    /// Labelled entries.
    pub fn total(&self) -> u64 {
        self.true_positive + self.false_positive + self.true_negative + self.false_negative
    }

    /// Fraction predicted correctly.
    pub fn accuracy(&self) -> f64 {
        ratio(self.true_positive + self.true_negative, self.total())
    }

    /// Recall of "speaks" (true-positive rate).
    pub fn recall(&self) -> f64 {
        ratio(self.true_positive, self.true_positive + self.false_negative)
    }

    /// Precision of "speaks".
    pub fn precision(&self) -> f64 {
        ratio(self.true_positive, self.true_positive + self.false_positive)
    }

    /// Recall of "silent" (true-negative rate).
    pub fn specificity(&self) -> f64 {
        ratio(self.true_negative, self.true_negative + self.false_positive)
    }

    /// Mean of the recalls of both classes.
    pub fn balanced_accuracy(&self) -> f64 {
        0.5 * (self.recall() + self.specificity())
    }

    /// Harmonic mean of precision and recall of "speaks" (0 when both are 0).
    pub fn f1(&self) -> f64 {
        ratio(2 * self.true_positive, 2 * self.true_positive + self.false_positive + self.false_negative)
    }

    /// Accuracy of always answering "silent".
    pub fn silent_baseline(&self) -> f64 {
        ratio(self.true_negative + self.false_positive, self.total())
    }
}

/// Results on one scene.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SceneEvaluation {
    /// Scene name.
    pub name: String,
    /// Frames.
    pub frames: usize,
    /// Speaking counts over valid (frame, person) entries.
    pub speaking: SpeakingCounts,
    /// `(predicted, actual)` buyer, when the scene has exactly one `buyer`.
    pub buyer: Option<(usize, usize)>,
}

/// Results on a set of scenes.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Evaluation {
    /// Per scene.
    pub scenes: Vec<SceneEvaluation>,
    /// Pooled speaking counts.
    pub speaking: SpeakingCounts,
    /// Scenes whose buyer was found.
    pub buyer_correct: usize,
    /// Scenes with a buyer role.
    pub buyer_total: usize,
}

impl Evaluation {
    /// What `socdiff classifier eval` prints: the pooled counts (one line per scene first with
    /// `per_scene`).
    pub fn report(&self, per_scene: bool) -> String {
        use std::fmt::Write as _;
        let mut out = String::new();
        for s in self.scenes.iter().filter(|_| per_scene) {
            let buyer = s.buyer.map_or("no buyer role".into(), |(got, want)| format!("buyer {got} (true {want})"));
            let c = &s.speaking;
            let _ = writeln!(
                out,
                "{:<28} {:>6} frames  accuracy {:.3}  balanced {:.3}  F1 {:.3}  {buyer}",
                s.name,
                s.frames,
                c.accuracy(),
                c.balanced_accuracy(),
                c.f1()
            );
        }
        let c = &self.speaking;
        let _ = writeln!(out, "scenes        {} ({} frames)", self.scenes.len(), self.scenes.iter().map(|s| s.frames).sum::<usize>());
        let _ = writeln!(out, "speaking      {} labelled person-frames, {:.1} % speaking", c.total(), 100.0 * (1.0 - c.silent_baseline()));
        let _ = writeln!(out, "accuracy      {:.4}   (always silent: {:.4})", c.accuracy(), c.silent_baseline());
        let _ = writeln!(out, "balanced acc  {:.4}", c.balanced_accuracy());
        let _ = writeln!(out, "precision     {:.4}   recall {:.4}   F1 {:.4}", c.precision(), c.recall(), c.f1());
        match self.buyer_total {
            0 => out.push_str("buyer         no scene has a buyer role\n"),
            n => _ = writeln!(out, "buyer         {}/{n} scenes   accuracy {:.4}", self.buyer_correct, self.buyer_accuracy()),
        }
        out
    }

    /// Fraction of scenes with a buyer role whose buyer was found (0 if none).
    pub fn buyer_accuracy(&self) -> f64 {
        ratio(self.buyer_correct as u64, self.buyer_total as u64)
    }
}

/// Runs the classifiers on every scene and compares with its speaking signal and buyer role.
/// Errors when a scene lacks the speaking signal or does not fit the classifiers.
pub fn evaluate(clf: &SocialSignalClassifiers, scenes: &[Scene]) -> Result<Evaluation> {
    if scenes.is_empty() {
        bail!("classifier evaluation: no scenes");
    }
    let signal = &clf.meta().config.speaking_signal;
    let mut ev = Evaluation::default();
    for scene in scenes {
        let labels = speaking_labels(scene, signal)?;
        let pred = clf.predict(scene)?;
        let mut counts = SpeakingCounts::default();
        for ((f, p), &y) in labels.indexed_iter() {
            if scene.is_valid(f, p) {
                counts.add(y > 0.5, pred.speaking_probability[[f, p]] > 0.5);
            }
        }
        let buyer = buyer_of(scene).map(|b| (pred.buyer, b));
        if let Some((got, want)) = buyer {
            ev.buyer_total += 1;
            ev.buyer_correct += usize::from(got == want);
        }
        ev.speaking.merge(&counts);
        ev.scenes.push(SceneEvaluation { name: scene.name.clone(), frames: scene.num_frames(), speaking: counts, buyer });
    }
    Ok(ev)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_give_known_scores() {
        let mut c = SpeakingCounts::default();
        // 3 TP, 1 FP, 4 TN, 2 FN.
        for (y, p, n) in [(true, true, 3), (false, true, 1), (false, false, 4), (true, false, 2)] {
            for _ in 0..n {
                c.add(y, p);
            }
        }
        assert_eq!(c.total(), 10);
        assert_eq!(c.accuracy(), 0.7);
        assert_eq!(c.recall(), 0.6);
        assert_eq!(c.precision(), 0.75);
        assert_eq!(c.specificity(), 0.8);
        assert!((c.balanced_accuracy() - 0.7).abs() < 1e-15);
        assert!((c.f1() - 2.0 * 0.75 * 0.6 / 1.35).abs() < 1e-15);
        assert_eq!(c.silent_baseline(), 0.5);
        assert_eq!(SpeakingCounts::default().f1(), 0.0);
    }
}
