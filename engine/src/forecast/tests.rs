//! Tests of forecasting: seeds, observed frames, equivariance, long forecasts, generation,
//! completion.

use super::*;
use crate::data::scene::Scene;
use crate::data::test_util::walkers;
use crate::export::ForecastInfo;
use crate::features::{PoseEncoding, PoseFeatures, Standardization, ROOT_DIMS};
use crate::model::{Aggregator, Denoiser, DenoiserConfig, InferenceNet};
use crate::sample::{Conditioning, X0Model};
use crate::Result;
use ndarray::s;
use socdiff_schedules::NoiseSchedule;

fn tiny_model() -> InferenceNet {
    let cfg = DenoiserConfig {
        feature_dims: 4 + 3 * 17,
        hidden: 16,
        time_dim: 16,
        fourier_dim: 8,
        social_dim: 16,
        aggregator: Aggregator::Mean,
        ..Default::default()
    };
    InferenceNet::new(&Denoiser::new(cfg, 5).unwrap()).unwrap()
}

fn std_of(scene: &Scene) -> Standardization {
    let f = PoseFeatures::from_scene(scene, scene.num_frames() / 2).unwrap();
    Standardization::fit([f.data.view()]).unwrap()
}

/// [`sample_scene`] with `net` on the default schedule, trained without clean frames.
fn sample(
    net: &dyn X0Model,
    std: &Standardization,
    encoding: PoseEncoding,
    scene: &Scene,
    task: &Task,
    req: &Forecast,
    on_step: &mut dyn FnMut(StepInfo),
) -> Result<ForecastOutput> {
    let schedule = NoiseSchedule::default();
    sample_scene(&Denoising { net, schedule: &schedule, standardization: std, encoding, clean_known: false }, scene, task, req, on_step)
}

fn run(model: &InferenceNet, scene: &Scene, task: &Task, samples: usize, seed: u64) -> ForecastOutput {
    let req = Forecast { samples, sampler: SamplerKind::Ddim { steps: 4, eta: 0.5 }, seed, ..Default::default() };
    sample(model, &std_of(&walkers(40, 3, 0.0)), PoseEncoding::Absolute, scene, task, &req, &mut |_| {}).unwrap()
}

#[test]
fn sampler_names_round_trip() {
    for (name, kind) in
        [("ddpm", SamplerKind::Ddpm), ("ddim20", SamplerKind::Ddim { steps: 20, eta: 0.0 }), ("ddim1", SamplerKind::Ddim { steps: 1, eta: 0.0 })]
    {
        assert_eq!(SamplerKind::parse(name).unwrap(), kind);
        assert_eq!(kind.name(), name);
    }
    assert_eq!(SamplerKind::Ddim { steps: 10, eta: 0.5 }.name(), "ddim10-eta0.5");
    for bad in ["ddim0", "ddim", "ddimx", "dpm", ""] {
        assert!(SamplerKind::parse(bad).unwrap_err().to_string().contains("ddpm or ddimN"), "{bad}");
    }
    let json = serde_json::to_value(SamplerKind::Ddim { steps: 20, eta: 0.0 }).unwrap();
    assert_eq!(json, serde_json::json!({"kind": "ddim", "steps": 20, "eta": 0.0}));
    assert_eq!(serde_json::to_value(SamplerKind::Ddpm).unwrap(), serde_json::json!({"kind": "ddpm"}));
}

#[test]
fn seeds_reproduce_bit_for_bit_and_sample_k_is_independent_of_k() {
    let m = tiny_model();
    let scene = walkers(20, 3, 0.3);
    let task = Task::Forecast { observe: 8, horizon: 12 };
    let a = run(&m, &scene, &task, 3, 11);
    let b = run(&m, &scene, &task, 3, 11);
    assert_eq!(a.samples.len(), 3);
    for (x, y) in a.samples.iter().zip(&b.samples) {
        assert_eq!(x.positions, y.positions);
    }
    assert_eq!(a.samples[0].positions.dim(), (20, 3, 17, 3));
    assert_ne!(a.samples[0].positions, a.samples[1].positions);
    let one = run(&m, &scene, &task, 1, 11);
    assert_eq!(one.samples[0].positions, a.samples[0].positions);
    let other = run(&m, &scene, &task, 1, 12);
    assert_ne!(other.samples[0].positions, a.samples[0].positions);
    assert_ne!(sample_seed(1, 0), sample_seed(1, 1));
    assert_ne!(sample_seed(1, 0), sample_seed(2, 0));
}

#[test]
fn observed_frames_equal_the_input_exactly() {
    let m = tiny_model();
    let scene = walkers(30, 2, 1.0);
    for (cond, encoding) in
        [(Conditioning::Replace, PoseEncoding::Absolute), (Conditioning::Noised, PoseEncoding::Absolute), (Conditioning::Replace, PoseEncoding::Residual)]
    {
        let req = Forecast { samples: 2, sampler: SamplerKind::Ddim { steps: 3, eta: 1.0 }, conditioning: cond, seed: 1, ..Default::default() };
        let fc = sample(&m, &std_of(&scene), encoding, &scene, &Task::Forecast { observe: 10, horizon: 25 }, &req, &mut |_| {}).unwrap();
        assert_eq!(fc.input.positions, scene.positions.slice(s![..10, .., .., ..]));
        for smp in &fc.samples {
            assert_eq!(smp.positions.dim().0, 35);
            assert_eq!(smp.positions.slice(s![..10, .., .., ..]), fc.input.positions);
            assert!(smp.positions.iter().all(|v| v.is_finite()));
            let info = ForecastInfo::from_scene(smp).unwrap().unwrap();
            assert_eq!((info.observed_frames, info.source.as_str()), (10, "walkers"));
        }
    }
}

#[test]
fn forecast_is_equivariant_to_rigid_motion_of_the_scene() {
    let m = tiny_model();
    let scene = walkers(16, 3, 0.5);
    let task = Task::Forecast { observe: 6, horizon: 10 };
    let base = run(&m, &scene, &task, 1, 4);
    let (th, t): (f64, [f64; 3]) = (0.7, [3.0, -2.0, 0.0]);
    let rot = [[th.cos(), -th.sin(), 0.0], [th.sin(), th.cos(), 0.0], [0.0, 0.0, 1.0]];
    let mut moved = scene.clone();
    moved.transform(rot, t);
    let out = run(&m, &moved, &task, 1, 4);
    let mut want = base.samples[0].clone();
    want.transform(rot, t);
    let err = want.positions.iter().zip(out.samples[0].positions.iter()).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
    println!("equivariance: max |Δ| = {err:.2e} m");
    assert!(err < 1e-4, "max error {err}");
    // The forecast moved at all (the model is not ignoring its input).
    assert!(base.samples[0].positions.slice(s![6.., .., .., ..]).iter().any(|v| v.abs() > 1e-3));
}

#[test]
fn minute_long_forecast_of_seven_persons_in_one_pass() {
    // 128 observed + 1800 forecast frames at 30 Hz, 7 persons (the network takes any P).
    let m = tiny_model();
    let scene = walkers(130, 7, 0.1);
    let req = Forecast { samples: 1, sampler: SamplerKind::Ddim { steps: 2, eta: 0.0 }, seed: 9, ..Default::default() };
    let mut calls = 0;
    let fc = sample(&m, &std_of(&scene), PoseEncoding::Absolute, &scene, &Task::Forecast { observe: 128, horizon: 1800 }, &req, &mut |i| {
        assert_eq!((i.samples, i.step, i.steps), (0..1, calls, 2));
        calls += 1;
    })
    .unwrap();
    assert_eq!(calls, 2);
    assert_eq!(fc.samples[0].positions.dim(), (1928, 7, 17, 3));
    assert!(fc.samples[0].positions.iter().all(|v| v.is_finite()));
    assert!(fc.ground_truth.is_none(), "the scene has no recorded future");
    // With a recorded future, the ground truth is written too and the viewer groups it.
    let long = walkers(40, 2, 0.0);
    let fc = sample(&m, &std_of(&long), PoseEncoding::Absolute, &long, &Task::Forecast { observe: 10, horizon: 30 }, &req, &mut |_| {}).unwrap();
    let gt = fc.ground_truth.as_ref().unwrap();
    assert_eq!(ForecastInfo::from_scene(gt).unwrap().unwrap().sample, None);
    let ds = fc.to_dataset();
    assert_eq!(ds.sequences.len(), 3);
    let groups = crate::export::group_scenes(&ds, None).unwrap();
    assert!(groups.iter().any(|g| g.samples.len() == 2 && g.observed_frames == 10));
}

/// x̂0 = one fixed standardized pose per person on every frame (a model of standing still).
struct StandStill(Vec<f32>);

impl X0Model for StandStill {
    fn feature_dims(&self) -> usize {
        self.0.len() / 3
    }
    fn predict_x0(&self, _x: &[f32], shape: [usize; 4], _t: &[usize], _anchors: Option<&[f32]>, out: &mut [f32]) -> Result<()> {
        let [b, p, t, d] = shape;
        for (i, o) in out.chunks_exact_mut(d).enumerate() {
            let person = i / t % p;
            o.copy_from_slice(&self.0[person * d..][..d]);
            debug_assert!(i < b * p * t);
        }
        Ok(())
    }
}

/// Generation: N frames per sample, only the placement at the anchor frame known (the
/// anchors). With a model that predicts the layout's own pose, every generated frame is the
/// layout, so placement, encoding and decoding line up wherever the anchor frame is; a
/// random network gives finite scenes; fewer than 2 frames, or an anchor frame outside
/// them, is an error.
#[test]
fn generation_keeps_the_layout_placement_and_samples_the_rest() {
    let layout = walkers(1, 3, 0.7);
    let std = std_of(&walkers(40, 3, 0.0));
    let mut pose = PoseFeatures::encode(&layout, 0..1, &[0, 1, 2], 0).unwrap().data;
    std.apply(&mut pose).unwrap();
    let still = StandStill(pose.iter().copied().collect());
    for anchor in [0, 29] {
        let task = Task::Generate { frames: 40, anchor };
        let mask = task_mask(&task, 40, 3, 17, (layout.skeleton.left, layout.skeleton.right));
        assert_eq!(mask.iter().filter(|&&k| k).count(), 3 * ROOT_DIMS);
        assert!((0..3).all(|p| (0..ROOT_DIMS).all(|d| mask[[anchor, p, d]])));
        let req = Forecast { samples: 2, seed: 4, ..Default::default() };
        let fc = sample(&still, &std, PoseEncoding::Absolute, &layout, &task, &req, &mut |_| {}).unwrap();
        assert_eq!((fc.samples.len(), fc.observed_frames, fc.provenance.anchor_frame), (2, 0, anchor));
        for smp in &fc.samples {
            assert_eq!(smp.num_frames(), 40);
            for f in [0, anchor, 39] {
                let d = smp.positions.slice(s![f, .., .., ..]).iter().zip(layout.positions.iter()).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
                assert!(d < 1e-4, "anchor {anchor}, frame {f}: {d} m from the layout");
            }
        }
        let task_json = &serde_json::to_value(&fc.provenance).unwrap()["task"];
        assert_eq!((task_json["kind"].as_str(), task_json["anchor"].as_u64()), (Some("generate"), Some(anchor as u64)));
        let fc = run(&tiny_model(), &layout, &task, 2, 4);
        assert!(fc.samples.iter().all(|s| s.num_frames() == 40 && s.positions.iter().all(|v| v.is_finite())));
    }
    assert!(check_task(&layout, &Task::Generate { frames: 1, anchor: 0 }, 1).unwrap_err().to_string().contains("at least 2"));
    assert!(check_task(&layout, &Task::Generate { frames: 10, anchor: 10 }, 1).unwrap_err().to_string().contains("must be one of them"));
}

/// Slerp: the endpoints, unit norm kept between orthogonal unit vectors, and the linear
/// case for parallel ones.
#[test]
fn slerp_known_values() {
    let (a, b) = ([1.0f32, 0.0], [0.0f32, 1.0]);
    assert_eq!(slerp(&a, &b, 0.0), a.to_vec());
    assert!(slerp(&a, &b, 1.0).iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-7));
    let h = slerp(&a, &b, 0.5);
    assert!((h[0] - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-6 && (h[1] - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-6);
    assert_eq!(slerp(&a, &[2.0, 0.0], 0.25), vec![1.25, 0.0]);
}

/// A transition scene: a, then F frames holding a's last pose, then b; mismatches refused.
#[test]
fn transition_scenes_join_two_motions() {
    let (a, b) = (walkers(10, 2, 0.1), walkers(7, 2, 0.9));
    let t = transition_scene(&a, &b, 5).unwrap();
    assert_eq!(t.num_frames(), 22);
    assert_eq!(t.positions.slice(s![12, .., .., ..]), a.positions.slice(s![9, .., .., ..]));
    assert_eq!(t.positions.slice(s![15.., .., .., ..]), b.positions);
    assert!(transition_scene(&a, &b, 0).is_err());
    assert!(transition_scene(&a, &walkers(7, 3, 0.9), 5).unwrap_err().to_string().contains("differ in persons"));
}

#[test]
fn masks_of_each_completion_kind() {
    let sk = crate::data::Skeleton::mupots17();
    let (l, r) = (sk.left, sk.right);
    let m = task_mask(&Task::Forecast { observe: 3, horizon: 2 }, 5, 2, 17, (l, r));
    assert_eq!(m.dim(), (5, 2, 55));
    assert!(m.slice(s![..3, .., ..]).iter().all(|&x| x) && m.slice(s![3.., .., ..]).iter().all(|&x| !x));
    let m = task_mask(&Task::Complete(Missing::Frames(1..3)), 5, 2, 17, (l, r));
    for ((f, _, _), &x) in m.indexed_iter() {
        assert_eq!(x, !(1..3).contains(&f));
    }
    let m = task_mask(&Task::Complete(Missing::Persons(vec![1])), 5, 3, 17, (l, r));
    for ((_, p, _), &x) in m.indexed_iter() {
        assert_eq!(x, p != 1);
    }
    let head = sk.joint_index("head").unwrap_or(0);
    let j = if head == l || head == r { 0 } else { head };
    let m = task_mask(&Task::Complete(Missing::Joints(vec![j])), 5, 2, 17, (l, r));
    for ((_, _, d), &x) in m.indexed_iter() {
        assert_eq!(x, !(d >= 4 && (d - 4) / 3 == j), "dim {d}");
    }
    // A missing body-frame joint makes the root dims unknown too.
    let m = task_mask(&Task::Complete(Missing::Joints(vec![l])), 5, 2, 17, (l, r));
    assert!(!m[[0, 0, 0]] && !m[[4, 1, 3]] && !m[[0, 0, 4 + 3 * l]]);
    assert_eq!(Missing::parse("frames=2..7", &sk).unwrap(), Missing::Frames(2..7));
    assert_eq!(Missing::parse("persons=0,2", &sk).unwrap(), Missing::Persons(vec![0, 2]));
    assert_eq!(Missing::parse(&format!("joints={},3", sk.joints[1]), &sk).unwrap(), Missing::Joints(vec![1, 3]));
    assert!(Missing::parse("legs=1", &sk).is_err());
    assert!(Missing::parse("joints=nose_tip", &sk).is_err());
}

#[test]
fn completion_keeps_known_entries_and_checks_its_task() {
    let m = tiny_model();
    let scene = walkers(16, 3, 0.2);
    let fc = run(&m, &scene, &Task::Complete(Missing::Frames(5..9)), 1, 2);
    let out = &fc.samples[0].positions;
    assert_eq!(out.dim(), scene.positions.dim());
    for f in (0..5).chain(9..16) {
        assert_eq!(out.slice(s![f, .., .., ..]), scene.positions.slice(s![f, .., .., ..]));
    }
    assert_ne!(out.slice(s![6, .., .., ..]), scene.positions.slice(s![6, .., .., ..]));
    let fc = run(&m, &scene, &Task::Complete(Missing::Persons(vec![1])), 1, 2);
    let out = &fc.samples[0].positions;
    assert_eq!(out.slice(s![.., 0, .., ..]), scene.positions.slice(s![.., 0, .., ..]));
    assert_ne!(out.slice(s![.., 1, .., ..]), scene.positions.slice(s![.., 1, .., ..]));
    let fc = run(&m, &scene, &Task::Complete(Missing::Joints(vec![0])), 1, 2);
    let out = &fc.samples[0].positions;
    assert_eq!(out.slice(s![.., .., 1.., ..]), scene.positions.slice(s![.., .., 1.., ..]));
    assert_ne!(out.slice(s![.., .., 0, ..]), scene.positions.slice(s![.., .., 0, ..]));
    let e = |t: Task| check_task(&scene, &t, 1).unwrap_err().to_string();
    assert!(e(Task::Forecast { observe: 17, horizon: 5 }).contains("more than the scene length"));
    // The observed frames alone are enough (a robot has no future to show).
    assert!(check_task(&scene, &Task::Forecast { observe: 16, horizon: 5 }, 1).is_ok());
    assert!(e(Task::Forecast { observe: 4, horizon: 0 }).contains("horizon"));
    assert!(e(Task::Complete(Missing::Persons(vec![3]))).contains("out of range"));
    assert!(e(Task::Complete(Missing::Frames(0..16))).contains("every frame"));
}
