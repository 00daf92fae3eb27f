//! Scenes, skeletons and the importers that read recorded motion into them.
//!
//! Data flow: a source file (dataset directory, Haggling pickle, BVH) → [`Scene`] →
//! [`crate::features`].

pub mod arrays;
pub mod body;
pub mod bvh;
pub mod compose;
pub mod dataset;
pub mod ground;
pub mod haggling;
pub mod import;
pub mod joint_map;
pub mod joints;
pub mod npy;
pub mod panoptic;
pub mod pickle;
pub mod retarget;
pub mod rotation;
pub mod scene;
pub mod skeleton;
pub mod synthetic;
#[cfg(test)]
pub(crate) mod test_util;

/// Highest frame rate accepted anywhere (motion capture runs at up to a few hundred fps).
pub const MAX_FPS: f64 = 1000.0;
/// Largest |coordinate| of a joint position, metres: anything farther is a unit or file error.
pub const MAX_ABS_POSITION: f32 = 1000.0;

/// Most frames of one scene or sampling canvas (9 h at 30 fps).
pub const MAX_FRAMES: usize = 1_000_000;
/// Most frames × persons a dataset may hold in all (about 2 GB of 17-joint positions).
pub const MAX_DATASET_PERSON_FRAMES: f64 = 1e7;
/// Most persons of one scene.
pub const MAX_PERSONS: usize = 1_000;
/// Most samples of one forecast.
pub const MAX_SAMPLES: usize = 10_000;
/// Most frames × persons × samples of one output (about 4 GB of poses at 17 joints).
pub const MAX_PERSON_FRAMES: f64 = 2e7;

/// Checks `frames` (a float, so that overflowing arithmetic of the caller shows as a huge
/// value), `persons` and `samples` of something about to be allocated against the limits above;
/// the error names `what`. Call it before allocating.
pub fn check_size(what: &str, frames: f64, persons: usize, samples: usize) -> crate::Result<()> {
    let total = frames * persons as f64 * samples as f64;
    if !(frames.is_finite() && frames <= MAX_FRAMES as f64) {
        crate::bail!("{what}: {frames} frames is more than the {MAX_FRAMES} allowed");
    }
    if persons > MAX_PERSONS {
        crate::bail!("{what}: {persons} persons is more than the {MAX_PERSONS} allowed");
    }
    if samples > MAX_SAMPLES {
        crate::bail!("{what}: {samples} samples is more than the {MAX_SAMPLES} allowed");
    }
    if total > MAX_PERSON_FRAMES {
        crate::bail!(
            "{what}: {frames} frames × {persons} persons × {samples} samples = {total:.3e} person-frames, more than the {MAX_PERSON_FRAMES:.0e} allowed"
        );
    }
    Ok(())
}

pub use dataset::{Dataset, Split};
pub use scene::{Person, Scene};
pub use skeleton::Skeleton;
