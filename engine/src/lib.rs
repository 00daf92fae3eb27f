//! socdiff engine: Social Diffusion (Tanke et al., ICCV 2023) for forecasting the motion of
//! groups of people.
//!
//! Modules follow the data flow: [`data`] (scenes, skeletons, importers) → [`features`]
//! (per-person pose features and standardization) → model → diffusion → sampling → metrics →
//! export.
//!
//! Each job's options are one type, used by library callers and by the command line alike:
//! with the `clap` feature (the `socdiff` binary turns it on) they derive `clap::Args`
//! ([`train::TrainOverrides`], [`train::TrainSources`], [`eval::EvalArgs`],
//! [`forecast::ForecastArgs`], [`recipes::speed::TrainSpeed`], [`data::import::SourceArgs`], …)
//! and their doc comments are the options' help.

pub mod checkpoint;
pub mod classifier;
pub mod data;
pub mod diffusion;
pub mod error;
pub mod eval;
pub mod export;
pub mod features;
pub mod files;
pub mod forecast;
pub mod metrics;
pub mod model;
pub mod recipes;
pub mod sample;
pub mod testing;
pub mod train;

pub use data::{Dataset, Person, Scene, Skeleton, Split};
pub use error::{Error, Result};
