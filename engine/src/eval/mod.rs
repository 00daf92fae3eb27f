//! Evaluation of forecasts against a reference dataset (METHOD.md §5): the metrics of
//! [`crate::metrics`] computed for several *methods* at once, with a report (JSON + table) and
//! plots.
//!
//! ```text
//! reference dataset (split) ──┬─▶ NDMS database (words of the reference split)
//!                             ├─▶ baselines (zero / constant velocity, nearest continuation,
//!                             │   ground truth) ─┐
//! forecast directories ───────┴──────────────────┴─▶ methods ──score──▶ Report ─▶ report.json,
//!                                                                             table, PNG plots
//! ```
//!
//! - A [`Method`] is a label and one [`MethodScene`] per forecast reference scene: K sample
//!   scenes of `observed + forecast` frames whose first `observed` frames are the reference's.
//!   Forecast directories ([`crate::forecast::ForecastOutput::write`]), plain dataset directories (each
//!   sequence of the split is scored as a one-sample "forecast" of itself, e.g. ground truth)
//!   and the built-in [`Baseline`]s all become methods ([`inputs`]).
//! - [`score::evaluate`] computes every requested [`Metric`] for every method ([`score`]);
//!   [`report`] turns the result into `report.json` and a text table, [`plots`] into PNGs.
//! - SSCP needs who speaks and who is the buyer: [`signals::SignalSource`] is the hook that
//!   provides them (annotations stored in the scenes now; classifiers later).

pub mod inputs;
pub mod job;
pub mod plots;
pub mod report;
pub mod score;
pub mod signals;

pub use inputs::{Baseline, Method, MethodKind, MethodScene, PastRecording, Reference};
pub use job::{EvalArgs, EvalJob, EvalOutcome};
pub use report::Report;
pub use score::{evaluate, EvalConfig};
pub use signals::SignalSource;

use crate::{bail, Result};

/// One metric that `socdiff eval --metrics` can name (METHOD.md §5; [`crate::metrics`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Metric {
    /// NDMS against the reference database: mean and per-frame curve.
    Ndms,
    /// MPJPE (global, root, root-aligned) at the horizons, mean and best of K.
    Mpjpe,
    /// Average pairwise distance between samples.
    Apd,
    /// Average displacement error (best of K).
    Ade,
    /// Final displacement error (best of K).
    Fde,
    /// Multimodal ADE over similar observations' futures.
    Mmade,
    /// Multimodal FDE.
    Mmfde,
    /// Average joint speed per frame.
    Speed,
    /// Bone-length deviation from the observed part (limb stretch).
    BoneLength,
    /// Mean joint acceleration.
    Acceleration,
    /// Mean joint jerk.
    Jerk,
    /// Horizontal speed of planted ankles.
    FootSliding,
    /// JS distance between the forecast's and the real joint-speed histograms per time bin.
    SpeedJs,
    /// The first forecast frame's largest joint move against the largest frame-to-frame move of
    /// the observed frames: whether the forecast continues the observation without a jump.
    FirstStep,
    /// SSCP (speaking × attention transitions, JS distance), when signals exist.
    Sscp,
    /// Precision and recall of the forecast motion words against the reference split's
    /// ([`crate::metrics::coverage`]).
    Coverage,
    /// JS distance between the motion-kind distributions of the forecasts and of the reference
    /// split ([`crate::metrics::kinds`]); needs a classifier ([`EvalConfig::kinds`]).
    Kinds,
}

impl Metric {
    /// Every metric, in report order.
    pub const ALL: [Metric; 17] = [
        Metric::Ndms,
        Metric::Mpjpe,
        Metric::Apd,
        Metric::Ade,
        Metric::Fde,
        Metric::Mmade,
        Metric::Mmfde,
        Metric::Speed,
        Metric::BoneLength,
        Metric::Acceleration,
        Metric::Jerk,
        Metric::FootSliding,
        Metric::SpeedJs,
        Metric::FirstStep,
        Metric::Sscp,
        Metric::Coverage,
        Metric::Kinds,
    ];

    /// The name used on the command line and in `report.json`.
    pub fn name(self) -> &'static str {
        match self {
            Metric::Ndms => "ndms",
            Metric::Mpjpe => "mpjpe",
            Metric::Apd => "apd",
            Metric::Ade => "ade",
            Metric::Fde => "fde",
            Metric::Mmade => "mmade",
            Metric::Mmfde => "mmfde",
            Metric::Speed => "speed",
            Metric::BoneLength => "bone-length",
            Metric::Acceleration => "acceleration",
            Metric::Jerk => "jerk",
            Metric::FootSliding => "foot-sliding",
            Metric::SpeedJs => "speed-js",
            Metric::FirstStep => "first-step",
            Metric::Sscp => "sscp",
            Metric::Coverage => "coverage",
            Metric::Kinds => "kinds",
        }
    }

    /// Every metric that needs nothing but the reference: all but [`Metric::Kinds`] (which needs
    /// a motion-kind classifier).
    pub fn everything_without_classifier() -> Vec<Metric> {
        Metric::ALL.into_iter().filter(|m| *m != Metric::Kinds).collect()
    }

    /// Parses a comma-separated list of metric names and groups (`all` = every metric but
    /// `kinds`, which needs a motion-kind classifier; `stochastic` = APD,
    /// ADE, FDE, MMADE, MMFDE; `plausibility` = bone-length, acceleration, jerk, foot-sliding,
    /// speed-js, first-step). The result is sorted and without repeats.
    pub fn parse_list(spec: &str) -> Result<Vec<Metric>> {
        let mut out = Vec::new();
        for item in spec.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let lower = item.to_ascii_lowercase().replace('_', "-");
            match lower.as_str() {
                "all" => out.extend(Metric::everything_without_classifier()),
                "stochastic" => out.extend([Metric::Apd, Metric::Ade, Metric::Fde, Metric::Mmade, Metric::Mmfde]),
                "plausibility" => out.extend([Metric::BoneLength, Metric::Acceleration, Metric::Jerk, Metric::FootSliding, Metric::SpeedJs, Metric::FirstStep]),
                name => match Metric::ALL.iter().find(|m| m.name() == name) {
                    Some(m) => out.push(*m),
                    None => bail!(
                        "unknown metric {item:?} (metrics: {}; groups: all (without kinds), stochastic, plausibility)",
                        Metric::ALL.map(Metric::name).join(", ")
                    ),
                },
            }
        }
        if out.is_empty() {
            bail!("no metric given (metrics: {})", Metric::ALL.map(Metric::name).join(", "));
        }
        out.sort();
        out.dedup();
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metric_lists_parse_groups_and_reject_unknown_names() {
        assert_eq!(Metric::parse_list("mpjpe, ndms,ndms").unwrap(), vec![Metric::Ndms, Metric::Mpjpe]);
        assert_eq!(Metric::parse_list("all").unwrap(), Metric::ALL[..16].to_vec());
        assert_eq!(Metric::parse_list("all,kinds").unwrap(), Metric::ALL.to_vec());
        assert_eq!(Metric::parse_list("stochastic").unwrap().len(), 5);
        assert_eq!(Metric::parse_list("plausibility,foot_sliding").unwrap().len(), 6);
        for m in Metric::ALL {
            assert_eq!(Metric::parse_list(m.name()).unwrap(), vec![m]);
        }
        let e = Metric::parse_list("ndms,mpjep").unwrap_err().to_string();
        assert!(e.contains("\"mpjep\"") && e.contains("mpjpe"), "{e}");
        assert!(Metric::parse_list(" , ").is_err());
    }
}
