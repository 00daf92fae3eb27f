//! socdiff: Social Diffusion for forecasting the motion of groups of people.
//!
//! This facade is what a library user needs of the engine (`socdiff_engine`): at the top the
//! model, scenes, datasets and a forecast request; below, the modules of the pipeline — data
//! and its importers, training, forecasting, evaluation, metrics, export — and the noise
//! schedules (`socdiff_schedules`, as [`schedules`]). The engine's kernels, sampler internals
//! and file plumbing stay behind it.
//!
//! ```no_run
//! use socdiff::data::import::{load, ImportOptions};
//! let ds = load("../shared/data/mupots3d".as_ref(), &ImportOptions::default())?;
//! println!("{} sequences, {} frames", ds.sequences.len(), ds.num_frames());
//! # Ok::<(), socdiff::Error>(())
//! ```

//! Forecasting in five lines: load a trained run, read a scene, sample eight one-minute futures
//! (here a tiny model trained on the bundled CMU clip in the hidden lines):
//!
//! ```
//! # let clip = "examples/data/cmu_18_01.bvh";
//! # let dir = std::env::temp_dir().join(format!("socdiff-doc-model-{}", std::process::id()));
//! # let _ = std::fs::remove_dir_all(&dir);
//! # let data = socdiff::data::import::load(clip.as_ref(), &Default::default())?;
//! # let model = socdiff::model::DenoiserConfig { hidden: 8, social_dim: 8, time_dim: 16, fourier_dim: 8, ..Default::default() };
//! # let config = socdiff::train::TrainConfig { steps: 2, batch: 2, window: 32, stride: 16, val_every: 0, model, ..Default::default() };
//! # let opts = socdiff::train::TrainOptions { out_dir: dir.clone(), config: Some(config), source: clip.into(), ..Default::default() };
//! # socdiff::train::train(&data, &opts, &mut |_| {})?;
//! let model = socdiff::Model::load(&dir)?;
//! let scene = socdiff::data::import::load_scene(clip)?;
//! let fc = model.forecast(&scene, socdiff::Forecast { observe: 120, horizon: 1800, samples: 8, ..Default::default() })?;
//! assert_eq!((fc.samples.len(), fc.samples[0].num_frames()), (8, 1920));
//! assert_eq!(fc.samples[0].positions.slice(ndarray::s![..120, .., .., ..]), scene.positions.slice(ndarray::s![..120, .., .., ..]));
//! # std::fs::remove_dir_all(&dir)?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub use socdiff_engine::data::{Dataset, Person, Scene, Skeleton, Split};
pub use socdiff_engine::forecast::{Forecast, ForecastOutput, Model};
pub use socdiff_engine::{checkpoint, classifier, eval, export, features, forecast, metrics, recipes, train};
pub use socdiff_engine::{Error, Result};
pub use socdiff_schedules as schedules;

/// Scenes, datasets, skeletons and their importers.
pub mod data {
    pub use socdiff_engine::data::{bvh, dataset, haggling, import, joint_map, joints, retarget, synthetic};
    pub use socdiff_engine::data::{Dataset, Person, Scene, Skeleton, Split};
}

/// The denoiser's configuration (the network itself is built by training and loaded by
/// [`Model`]).
pub mod model {
    pub use socdiff_engine::model::{Aggregator, Causality, DenoiserConfig, DeviceChoice, Precision};
}
