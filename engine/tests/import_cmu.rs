//! The importer on the real CMU BVH clips in ../shared/data/cmu_bvh (a folder of .bvh files
//! without dataset.json).

use socdiff_engine::data::bvh::{BvhImport, CMU_SCALE};
use socdiff_engine::data::import::{self, ImportOptions, SourceKind};
use socdiff_engine::Split;
use std::path::Path;

#[test]
fn a_folder_of_bvh_files_is_one_train_sequence_per_file() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/cmu_bvh");
    if !dir.join("131_01.bvh").exists() {
        socdiff_engine::testing::skip_absent(&dir, "shared CMU BVH data");
        return;
    }
    let opts = ImportOptions { bvh: BvhImport { scale: CMU_SCALE, ..Default::default() }, ..Default::default() };
    // The shared folder mixes two joint layouts (131_* name joints `LeftHip`, 18_01 `lfemur`).
    assert_eq!(import::source_kind(&dir).unwrap(), SourceKind::BvhDir);
    let err = import::load(&dir, &opts).unwrap_err().to_string();
    assert!(err.contains("18_01.bvh") && err.contains("one joint layout"), "{err}");
    // Subject 131's three clips share one layout: a folder of them is a dataset.
    let tmp = std::env::temp_dir().join(format!("socdiff-cmu131-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    for f in ["131_01.bvh", "131_02.bvh", "131_03.bvh"] {
        std::fs::copy(dir.join(f), tmp.join(f)).unwrap();
    }
    std::fs::write(tmp.join("notes.txt"), "not motion").unwrap();
    let ds = import::load(&tmp, &opts);
    let single = import::load(&tmp.join("131_02.bvh"), &opts);
    std::fs::remove_dir_all(&tmp).ok();
    let (ds, single) = (ds.unwrap(), single.unwrap());
    assert!(ds.name.starts_with("socdiff-cmu131-"));
    let names: Vec<&str> = ds.sequences.iter().map(|s| s.scene.name.as_str()).collect();
    assert_eq!(names, ["131_01", "131_02", "131_03"]);
    assert!(ds.sequences.iter().all(|s| s.split == Split::Train && s.scene.num_persons() == 1 && s.scene.skeleton.name == ds.name));
    // Frame counts from ../shared/data/README.md (120 fps): 994, 1,247 and 1,102 frames.
    let frames: Vec<usize> = ds.sequences.iter().map(|s| s.scene.num_frames()).collect();
    assert_eq!(frames, [994, 1247, 1102]);
    // Each file is read as the single-file importer reads it.
    assert_eq!(single.sequences[0].scene.positions, ds.sequences[1].scene.positions);
}

#[test]
fn a_folder_without_dataset_json_or_bvh_files_is_refused_by_name() {
    let dir = std::env::temp_dir().join(format!("socdiff-empty-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let err = import::source_kind(&dir).unwrap_err().to_string();
    std::fs::remove_dir_all(&dir).ok();
    assert!(err.contains(&dir.display().to_string()) && err.contains("no dataset.json, .bvh, .npy, .npz or body3DScene_*.json files"), "{err}");
}
