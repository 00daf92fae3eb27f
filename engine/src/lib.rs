//! socdiff engine: Social Diffusion (Tanke et al., ICCV 2023) for forecasting the motion of
//! groups of people.
//!
//! Modules follow the data flow: [`data`] (scenes, skeletons, importers) → [`features`]
//! (per-person pose features and standardization) → model → diffusion → sampling → metrics →
//! export.

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
