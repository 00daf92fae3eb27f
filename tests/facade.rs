//! The facade crate exposes the whole data path: import → scene → features → back.

use socdiff::data::import::{load, ImportOptions};
use socdiff::features::PoseFeatures;
use socdiff::schedules::{BetaSchedule, NoiseSchedule};
use std::path::Path;

#[test]
fn bundled_cmu_clip_round_trips_through_features() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/data/cmu_18_01.bvh");
    let mut opts = ImportOptions::default();
    opts.bvh.scale = socdiff::data::bvh::CMU_SCALE;
    let ds = load(&path, &opts).unwrap();
    let scene = &ds.sequences[0].scene;
    assert_eq!((scene.num_frames(), scene.num_persons(), scene.fps), (303, 1, 30.0));
    let feats = PoseFeatures::from_scene(scene, 127).unwrap();
    assert_eq!(feats.dim(), 4 + 3 * scene.num_joints());
    let back = feats.to_positions().unwrap();
    let err = back.iter().zip(scene.positions.iter()).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(err < 1e-5, "round trip error {err} m");
}

#[test]
fn schedules_are_reexported() {
    let s = NoiseSchedule::new(BetaSchedule::default(), 1000).unwrap();
    assert!((s.alpha_bars()[499] - 0.493844).abs() < 1e-5);
}

#[test]
fn the_bundled_pretrained_model_loads_from_its_path_with_its_card() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/groups-mrt15");
    let path = dir.join("model.safetensors");
    assert!(std::fs::metadata(&path).unwrap().len() <= 10 << 20, "bundled weights stay under 10 MB");
    let model = socdiff::checkpoint::Checkpoint::load(&path).unwrap();
    assert_eq!(model.skeleton.joints, socdiff::Skeleton::mrt15().joints);
    assert_eq!(model.fps, 30.0);
    // Inference weights only: nothing to resume.
    assert!(socdiff::checkpoint::Checkpoint::load_weights(&path, socdiff::checkpoint::Weights::Online).is_err());
    let card = std::fs::read_to_string(dir.join("MODEL_CARD.md")).unwrap();
    for needed in ["CC BY-NC 4.0", "socdiff train", "socdiff bench mrt", &format!("step {}", model.step)] {
        assert!(card.contains(needed), "the model card names {needed:?}");
    }
}
