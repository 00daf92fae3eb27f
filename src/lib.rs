//! socdiff: Social Diffusion for forecasting the motion of groups of people.
//!
//! This facade re-exports the engine (`socdiff_engine`) and the noise schedules
//! (`socdiff_schedules`, as [`schedules`]) so that library users depend on one crate.
//!
//! ```no_run
//! use socdiff::data::import::{load, ImportOptions};
//! let ds = load("../shared/data/mupots3d".as_ref(), &ImportOptions::default())?;
//! println!("{} sequences, {} frames", ds.sequences.len(), ds.num_frames());
//! # Ok::<(), socdiff::Error>(())
//! ```

pub use socdiff_engine::*;
pub use socdiff_schedules as schedules;
