//! The recipe building blocks through the facade: the bundled CMU clip mapped onto MuPoTS-17 by
//! joint names, synthetic groups around a centre, a tiny model trained on them, forecasts of a
//! held-out group scored by the compact report, and the leader/follower probe.

use socdiff::checkpoint::Checkpoint;
use socdiff::data::bvh::{import_bvh, BvhImport, CMU_SCALE};
use socdiff::data::dataset::Sequence;
use socdiff::data::joint_map::JointMap;
use socdiff::data::synthetic::{synthetic_groups, GroupConfig};
use socdiff::forecast::{Forecast, SamplerKind};
use socdiff::model::DenoiserConfig;
use socdiff::recipes::{evaluate, forecast_scenes, leader_follower_probe, ProbeConfig, Protocol};
use socdiff::train::{train, TrainConfig, TrainOptions};
use socdiff::{Dataset, Skeleton, Split};
use std::path::Path;

#[test]
fn cmu_groups_train_forecast_and_score() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/data/cmu_18_01.bvh");
    let clip = import_bvh(&path, &BvhImport { scale: CMU_SCALE, include_end_sites: true, ..Default::default() }).unwrap();
    let map = JointMap::by_names(&clip.skeleton, &Skeleton::mupots17(), &[]).unwrap();
    assert!(map.is_exact(), "every MuPoTS joint has a CMU counterpart");
    let clip = map.apply(&clip).unwrap();
    let groups = |seed: u64, n: usize| synthetic_groups(std::slice::from_ref(&clip), n, "g", &GroupConfig { frames: 120, seed, ..Default::default() }).unwrap();
    let mut sequences: Vec<Sequence> = groups(1, 2).into_iter().map(|scene| Sequence { split: Split::Train, scene }).collect();
    let test = groups(2, 1);
    sequences.push(Sequence { split: Split::Test, scene: test[0].clone() });
    let ds = Dataset { name: "cmu-groups".into(), sequences, metadata: Default::default() };

    let dir = std::env::temp_dir().join(format!("socdiff-facade-recipes-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let net = DenoiserConfig { hidden: 8, social_dim: 8, time_dim: 16, fourier_dim: 8, ..Default::default() };
    let config = TrainConfig { steps: 2, batch: 2, window: 32, stride: 8, val_every: 0, model: net.clone(), ..Default::default() };
    let opts =
        TrainOptions { out_dir: dir.join("model"), resume: false, config: Some(config), source: "test".into(), stop: None, force: false, ..Default::default() };
    train(&ds, &opts, &mut |_| {}).unwrap();
    let model = Checkpoint::load(dir.join("model")).unwrap();

    let proto = Protocol {
        request: Forecast { observe: 30, horizon: 60, samples: 2, sampler: SamplerKind::Ddim { steps: 2, eta: 0.0 }, seed: 1, ..Default::default() },
        window_stride: Some(30),
        device: Default::default(),
    };
    let runs = forecast_scenes(&model, &test, &proto, &mut |_| {}).unwrap();
    // Windows at 0 and 30 fit in 120 frames (30 + 60 each); the one at 60 does not.
    assert_eq!(runs.len(), 2);
    assert_eq!(runs[1].truth.name, format!("{}@30", test[0].name));
    let rep = evaluate(&runs, &test, &Default::default()).unwrap();
    assert_eq!((rep.scenes, rep.samples, rep.observe, rep.horizon), (2, 2, 30, 60));
    assert_eq!(rep.ndms.per_frame.len(), 61);
    assert!(rep.ndms.mean > 0.0 && rep.ndms.mean <= 1.0);
    // 1 s and 2 s lie inside the 60 recorded forecast frames, 3 s does not.
    assert_eq!(rep.mpjpe.iter().map(|h| h.scenes).collect::<Vec<_>>(), vec![2, 2, 0]);
    assert!(rep.mpjpe[2].mean.is_none() && rep.mpjpe[0].mean.unwrap() > 0.0);

    // The probe trains its own model (same network settings) on leader/follower episodes.
    let pose: Vec<f32> = test[0].person(0).iter().take(3 * 17).copied().collect();
    let probe = ProbeConfig { train_episodes: 8, test_episodes: 2, steps: 2, batch: 4, ddim_steps: 2, ..Default::default() };
    let err = leader_follower_probe(&model.skeleton, &pose, 30.0, &net, 1, &probe, &dir.join("probe")).unwrap();
    assert!(err.is_finite() && err > 0.0, "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}
