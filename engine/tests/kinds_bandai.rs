//! The motion-kind classifier on the real bandai2 data (../shared/data/bandai2): trained on its
//! train split, measured on its test split, applied to MuPoTS.

use socdiff_engine::data::dataset::{read_dataset, ReadOptions};
use socdiff_engine::metrics::kinds::{bandai_kind, scene_windows, KindDistribution, KindTraining, MotionKindClassifier};
use socdiff_engine::{Scene, Split};
use std::path::Path;

#[test]
fn bandai_kinds_are_learnt_and_told_apart_on_unseen_clips() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data");
    let dir = data.join("bandai2");
    if !dir.join("dataset.json").exists() {
        socdiff_engine::testing::skip_absent(&dir, "shared bandai2 data");
        return;
    }
    let ds = read_dataset(&dir, &ReadOptions::default()).unwrap();
    let named = |split: Split, every: usize| -> Vec<(&Scene, String)> { ds.split(split).step_by(every).map(|s| (s, bandai_kind(&s.name).unwrap())).collect() };
    let (train_named, test_named) = (named(Split::Train, 3), named(Split::Test, 1));
    let train: Vec<(&Scene, &str)> = train_named.iter().map(|(s, k)| (*s, k.as_str())).collect();
    let t0 = std::time::Instant::now();
    let clf = MotionKindClassifier::train(&train, &KindTraining::default()).unwrap();
    let secs = t0.elapsed().as_secs_f64();
    assert_eq!(clf.labels, ["raise-up", "run", "walk", "walk-turn", "wave"]);
    let test: Vec<(&Scene, &str)> = test_named.iter().map(|(s, k)| (*s, k.as_str())).collect();
    let (acc, windows) = clf.accuracy(&test, 30).unwrap();
    let (train_acc, _) = clf.accuracy(&train, 30).unwrap();
    eprintln!(
        "motion kinds: {} train clips ({} windows, {secs:.1} s), train accuracy {train_acc:.3}; test {} clips, {windows} windows, accuracy {acc:.3}",
        train.len(),
        clf.windows_per_class.iter().sum::<usize>(),
        test.len()
    );
    // Five kinds: chance is 0.2.
    assert!(acc >= 0.8, "test accuracy {acc}");
    // The predicted kind distribution of the test split is near its true one (bandai2's test
    // split holds other styles), walking alone is far from it.
    let mut truth = vec![0; clf.labels.len()];
    for (s, k) in &test {
        truth[clf.labels.iter().position(|l| l == k).unwrap()] += scene_windows(s, 30).unwrap().len();
    }
    let h_test = clf.histogram(&test.iter().map(|(s, _)| *s).collect::<Vec<_>>(), 30).unwrap();
    let walks: Vec<&Scene> = test.iter().filter(|(_, k)| *k == "walk").map(|(s, _)| *s).collect();
    let h_walk = clf.histogram(&walks, 30).unwrap();
    let near = KindDistribution::new(&clf.labels, h_test, truth.clone()).unwrap().js;
    let collapsed = KindDistribution::new(&clf.labels, h_walk, truth).unwrap().js;
    eprintln!("JS predicted vs true test kinds {near:.3}, walks only vs true {collapsed:.3}");
    assert!(near < 0.15 && collapsed > 4.0 * near, "{near} {collapsed}");
    // Applied to MuPoTS (another skeleton, found by joint names): every window gets a kind.
    let mupots = read_dataset(&data.join("mupots3d"), &ReadOptions::default()).unwrap();
    let ms: Vec<&Scene> = mupots.split(Split::Test).collect();
    let h = clf.histogram(&ms, 30).unwrap();
    eprintln!("MuPoTS test kinds: {:?}", clf.labels.iter().zip(&h).collect::<Vec<_>>());
    assert!(h.iter().sum::<usize>() > 50);
}
