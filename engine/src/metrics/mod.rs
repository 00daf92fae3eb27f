//! Metrics for group-motion forecasts (METHOD.md §5).
//!
//! | module | what | unit |
//! |---|---|---|
//! | [`ndms`] | NDMS: nearest real motion word per forecast word, velocity similarity ψ ∈ [0, 1] | – |
//! | [`sscp`] | SSCP: speaking × attention states of a triad, transition matrix, JS distance | – |
//! | [`distance`] | MPJPE (global / root / root-aligned) at horizons, APD, ADE, FDE, MMADE, MMFDE, joint speed | m, m/s |
//! | [`plausibility`] | bone-length deviation, acceleration, jerk, foot sliding, speed-histogram JS distance | mm, m/s², m/s³, m/s |
//! | [`baselines`] | zero velocity, constant velocity, nearest real continuation | m |
//! | [`coverage`] | precision and recall of motion words (k-NN manifolds, Kynkäänniemi et al. 2019) | – |
//! | [`kinds`] | motion-kind classifier (bandai2's five motion kinds) and the JS distance of kind distributions | – |
//! | [`nn`] | exact Euclidean nearest neighbour (f32 gemm screening + f64 re-check) | – |
//!
//! Conventions shared by every module:
//! - positions are f32 metres, z up, as in [`crate::Scene`]; arithmetic is f64;
//! - a forecast is `[K samples, frames, persons, joints, 3]`, ground truth (and any single
//!   sequence) `[frames, persons, joints, 3]`; frame 0 of a forecast array is the first forecast
//!   frame unless a function takes an explicit `first_forecast_frame`;
//! - "hip midpoint" is the 3D midpoint of the skeleton's body-frame joints
//!   ([`crate::Skeleton::left`], [`crate::Skeleton::right`]);
//! - the body frame of a pose is [`crate::features::Anchor::of_pose`]: origin at the hip
//!   midpoint projected on the ground, left→right hip axis along +x, heights kept.
//!
//! # Jensen–Shannon distance
//! [`js_distance`] follows `scipy.spatial.distance.jensenshannon` with its default natural log:
//! `p ← p/Σp`, `q ← q/Σq`, `m = (p + q)/2`,
//! `JS(p, q) = √(½ Σ_i [p_i ln(p_i/m_i) + q_i ln(q_i/m_i)])`, with `0·ln 0 = 0`.
//! It lies in `[0, √ln 2 ≈ 0.8326]`: 0 for identical, √ln 2 for disjoint distributions.

pub mod baselines;
pub mod coverage;
pub mod distance;
pub mod kinds;
pub mod ndms;
pub mod nn;
pub mod plausibility;
pub mod sscp;

pub use baselines::{constant_velocity, nearest_continuation, zero_velocity};
pub use distance::{PoseError, SampleStats, StochasticErrors};
pub use ndms::{NdmsConfig, NdmsCurve, NdmsDatabase, NdmsJoints, NdmsScore};
pub use sscp::{Facing, SscpConfig, Triad};

use crate::{bail, Result};

/// √ln 2: the Jensen–Shannon distance (natural log) of two disjoint distributions.
pub const JS_DISTANCE_MAX: f64 = 0.832_554_611_157_697_8;

/// Jensen–Shannon distance between two histograms (scipy `jensenshannon`, natural log); see
/// the module docs. Both are normalized to sum 1 first.
///
/// # Shapes
/// - `p`, `q`: `[bins]`, non-negative, each with a positive sum.
pub fn js_distance(p: &[f64], q: &[f64]) -> Result<f64> {
    if p.len() != q.len() {
        bail!("js_distance: histograms have {} and {} bins", p.len(), q.len());
    }
    let total = |h: &[f64], name: &str| -> Result<f64> {
        if let Some(v) = h.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
            bail!("js_distance: histogram {name} has entry {v} (entries must be finite and non-negative)");
        }
        let s: f64 = h.iter().sum();
        if s <= 0.0 {
            bail!("js_distance: histogram {name} is empty (sum 0)");
        }
        Ok(s)
    };
    let (sp, sq) = (total(p, "p")?, total(q, "q")?);
    let rel = |x: f64, m: f64| if x > 0.0 { x * (x / m).ln() } else { 0.0 };
    let mut js = 0.0;
    for (&a, &b) in p.iter().zip(q) {
        let (a, b) = (a / sp, b / sq);
        let m = 0.5 * (a + b);
        js += rel(a, m) + rel(b, m);
    }
    Ok((0.5 * js).max(0.0).sqrt())
}

/// Index of the forecast frame `horizon_s` seconds after the last observed frame:
/// `round(horizon_s · fps) − 1` (1 s at 30 fps → index 29). `None` when that is before the first
/// forecast frame or at/after `frames`.
pub fn horizon_frame(horizon_s: f64, fps: f64, frames: usize) -> Option<usize> {
    let i = (horizon_s * fps).round() - 1.0;
    (i.is_finite() && i >= 0.0 && (i as usize) < frames).then_some(i as usize)
}

/// Word length κ for a frame rate: 10 at 30 Hz, `round(fps/3)` otherwise (at least 2, so a word
/// has a velocity).
pub fn word_length_for_fps(fps: f64) -> usize {
    ((fps / 3.0).round() as usize).max(2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn js_distance_known_values() {
        let p = [0.25, 0.25, 0.5, 0.0];
        assert_eq!(js_distance(&p, &p).unwrap(), 0.0);
        // Disjoint supports → √ln 2.
        let d = js_distance(&[1.0, 0.0], &[0.0, 3.0]).unwrap();
        assert!((d - JS_DISTANCE_MAX).abs() < 1e-15 && (d - 2f64.ln().sqrt()).abs() < 1e-15, "{d}");
        // Hand computed: p = (1, 0), q = (½, ½): m = (¾, ¼);
        // KL(p‖m) = ln(4/3), KL(q‖m) = ½ ln(2/3) + ½ ln 2 → JS = √(½(ln 4/3 + ½ ln 4/3)).
        let d = js_distance(&[2.0, 0.0], &[1.0, 1.0]).unwrap();
        let want = (0.5 * (1.5 * (4.0f64 / 3.0).ln())).sqrt();
        assert!((d - want).abs() < 1e-15, "{d} vs {want}");
        assert!(js_distance(&[1.0], &[1.0, 2.0]).is_err());
        assert!(js_distance(&[0.0, 0.0], &[1.0, 2.0]).is_err());
        assert!(js_distance(&[-1.0, 2.0], &[1.0, 2.0]).is_err());
    }

    #[test]
    fn horizons_and_word_length() {
        assert_eq!(horizon_frame(1.0, 30.0, 90), Some(29));
        assert_eq!(horizon_frame(3.0, 30.0, 90), Some(89));
        assert_eq!(horizon_frame(3.0, 30.0, 89), None);
        assert_eq!(horizon_frame(0.0, 30.0, 89), None);
        assert_eq!(word_length_for_fps(30.0), 10);
        assert_eq!(word_length_for_fps(25.0), 8);
        assert_eq!(word_length_for_fps(120.0), 40);
    }
}
