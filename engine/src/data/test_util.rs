//! Fixtures of the engine's unit tests: shared data, the bundled clip, temporary paths.

use crate::data::dataset::{read_dataset, Dataset, ReadOptions};
use std::path::{Path, PathBuf};

/// MuPoTS from `../shared/data/mupots3d`, or `None` with the reason printed.
pub fn mupots() -> Option<Dataset> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/mupots3d");
    if !dir.join("dataset.json").is_file() {
        crate::testing::skip_absent(&dir, "shared MuPoTS data");
        return None;
    }
    Some(read_dataset(&dir, &ReadOptions::default()).expect("MuPoTS reads"))
}

/// The bundled CMU clip.
pub fn cmu_clip() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/data/cmu_18_01.bvh")
}

/// A fresh temporary directory path (not created).
pub fn tmp(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("socdiff-test-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    let _ = std::fs::remove_file(&d);
    d
}

pub use crate::data::synthetic::walkers;
