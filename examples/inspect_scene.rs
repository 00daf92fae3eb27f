//! Reads any supported input (dataset directory, BVH, Haggling pickle), turns every scene into
//! anchored pose features and back, and prints what it found.
//!
//! `cargo run --release --example inspect_scene -- examples/data/cmu_18_01.bvh`

use socdiff::data::import::{load, ImportOptions};
use socdiff::features::PoseFeatures;

fn main() -> socdiff::Result<()> {
    let path = std::env::args().nth(1).unwrap_or_else(|| "examples/data/cmu_18_01.bvh".into());
    let mut opts = ImportOptions::default();
    opts.bvh.auto_scale = true;
    let ds = load(path.as_ref(), &opts)?;
    for seq in &ds.sequences {
        let s = &seq.scene;
        let anchor = s.num_frames() / 2;
        let features = PoseFeatures::from_scene(s, anchor)?;
        let back = features.to_positions()?;
        let err = back.iter().zip(s.positions.iter()).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        println!(
            "{:<24} {:>6} frames × {} persons × {} joints at {} fps; features δ = {}, round trip {:.1e} m",
            s.name,
            s.num_frames(),
            s.num_persons(),
            s.num_joints(),
            s.fps,
            features.dim(),
            err
        );
    }
    Ok(())
}
