//! Scenes, skeletons and the importers that read recorded motion into them.
//!
//! Data flow: a source file (dataset directory, Haggling pickle, BVH) → [`Scene`] →
//! [`crate::features`].

pub mod bvh;
pub mod dataset;
pub mod ground;
pub mod haggling;
pub mod import;
pub mod joint_map;
pub mod npy;
pub mod pickle;
pub mod scene;
pub mod skeleton;
pub mod synthetic;

pub use dataset::{Dataset, Split};
pub use scene::{Person, Scene};
pub use skeleton::Skeleton;
