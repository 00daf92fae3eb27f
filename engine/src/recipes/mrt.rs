//! MRT's MuPoTS-3D benchmark (`socdiff bench mrt`), built as MRT's code builds it (Wang et al.,
//! NeurIPS 2021; jiashunwang/MRT, `mupots3d/preprocess_mupots.py`, `data.py`, `test.py`), so
//! that our numbers stand beside the tables of the multi-person forecasting papers:
//!
//! - every MuPoTS sequence with three persons (TS1–TS20; train and test alike: the models
//!   compared are trained without MuPoTS);
//! - windows of 120 frames (30 fps) starting at frames 0, 15, 30, … while the window fits;
//! - every second frame: frames 0, 2, …, 28 observed (15 at 15 fps), frames 30, 32, …, 118
//!   forecast (45 at 15 fps);
//! - MRT's 15 joints ([`Skeleton::mrt15`]), global coordinates, no alignment;
//! - "1 s / 2 s / 3 s" = the Euclidean joint error averaged over the joints, the persons and
//!   the first 15 / 30 / 45 forecast frames (not the error at that frame), then over windows.
//!
//! Our model runs at 30 fps: it observes frames 0–28 with each odd frame the midpoint of its
//! recorded neighbours, so it is given nothing MRT's 15 observed frames do not hold. Zero
//! velocity holds frame 28; constant velocity continues the step from frame 26 to 28.
//!
//! Units: millimetres, and MRT's units, which are millimetres × 0.017 · 0.1 · 1.8 / 3
//! (= 0.00102; their `preprocess_mupots.py` as it stands; the first version of that file had
//! 0.015, i.e. 0.0009). The translations MRT's preprocessing applies (floor at y = 0, centred in
//! x and z) move the prediction and the truth alike and do not change the error.

use super::{forecast_scenes, Protocol};
use crate::checkpoint::LoadedModel;
use crate::data::{Dataset, Scene, Skeleton};
use crate::forecast::StepInfo;
use crate::{bail, Result};
use ndarray::{Array4, ArrayView4, Axis};
use serde::Serialize;

/// Frames of a window at 30 fps.
pub const WINDOW: usize = 120;
/// Frames between the starts of consecutive windows.
pub const STRIDE: usize = 15;
/// Persons of the scenes MRT tests on.
pub const PERSONS: usize = 3;
/// Last observed frame of a window (the 15th observed frame at 15 fps).
pub const LAST_OBSERVED: usize = 28;
/// Forecast frames scored (at 15 fps): frames 30, 32, …, 118.
pub const PREDICTED: usize = 45;
pub use crate::data::arrays::MRT_UNITS_PER_MM;

/// The 30-fps frame of the `k`-th scored forecast frame (k = 0 … 44).
pub fn scored_frame(k: usize) -> usize {
    LAST_OBSERVED + 2 + 2 * k
}

/// The benchmark's windows: every three-person sequence of `dataset` (every split), 120
/// frames from frame 0 every 15 frames while the window fits, named `SEQUENCE@START`, on
/// `dataset`'s skeleton. Errors: no sequence holds a window.
pub fn windows(dataset: &Dataset) -> Result<Vec<Scene>> {
    let mut out = Vec::new();
    for seq in &dataset.sequences {
        let scene = &seq.scene;
        if scene.num_persons() != PERSONS {
            continue;
        }
        let mut start = 0;
        while start + WINDOW <= scene.num_frames() {
            let mut w = scene.slice_frames(start, start + WINDOW)?;
            w.name = format!("{}@{start}", scene.name);
            out.push(w);
            start += STRIDE;
        }
    }
    if out.is_empty() {
        bail!("dataset {}: no sequence of {PERSONS} persons holds {WINDOW} frames", dataset.name);
    }
    Ok(out)
}

/// What the model is given of a window: frames 0–28, each odd frame replaced by the midpoint of
/// its neighbours (module docs), then frame 28 held through frame 118 as a placeholder for the
/// forecast frames (the sampler reads only the first 29).
///
/// # Shapes
/// - `window.positions`: `[120, persons, joints, 3]`; output `[119, persons, joints, 3]`.
pub fn observed_input(window: &Scene) -> Result<Scene> {
    let mut input = window.slice_frames(0, WINDOW - 1)?;
    for f in (1..LAST_OBSERVED).step_by(2) {
        let mid = (&input.positions.index_axis(Axis(0), f - 1) + &input.positions.index_axis(Axis(0), f + 1)) * 0.5;
        input.positions.index_axis_mut(Axis(0), f).assign(&mid);
    }
    let last = input.positions.index_axis(Axis(0), LAST_OBSERVED).to_owned();
    for f in LAST_OBSERVED + 1..WINDOW - 1 {
        input.positions.index_axis_mut(Axis(0), f).assign(&last);
    }
    Ok(input)
}

/// MRT's error of one forecast of one window at 1/2/3 s: the joint error over `joints`, all
/// persons and the first 15/30/45 scored frames ([`scored_frame`]), in the positions' units.
///
/// # Shapes
/// - `forecast`, `truth`: `[≥ 119, persons, joints, 3]`, frames numbered as in the window.
pub fn window_error(forecast: ArrayView4<f32>, truth: ArrayView4<f32>, joints: &[usize]) -> [f64; 3] {
    let persons = truth.shape()[1];
    let (mut out, mut sum) = ([0f64; 3], 0f64);
    for k in 0..PREDICTED {
        let f = scored_frame(k);
        for p in 0..persons {
            for &j in joints {
                let d2: f64 = (0..3).map(|c| f64::from(forecast[[f, p, j, c]] - truth[[f, p, j, c]]).powi(2)).sum();
                sum += d2.sqrt();
            }
        }
        for (h, frames) in [15, 30, 45].into_iter().enumerate() {
            if k + 1 == frames {
                out[h] = sum / (frames * persons * joints.len()) as f64;
            }
        }
    }
    out
}

/// The zero- and constant-velocity forecasts of a window (module docs).
///
/// # Shapes
/// - `window`: `[120, persons, joints, 3]`; outputs the same, scored frames filled.
pub fn baselines(window: ArrayView4<f32>) -> (Array4<f32>, Array4<f32>) {
    let last = window.index_axis(Axis(0), LAST_OBSERVED);
    let step = &last - &window.index_axis(Axis(0), LAST_OBSERVED - 2);
    let (mut zero, mut constant) = (window.to_owned(), window.to_owned());
    for k in 0..PREDICTED {
        let f = scored_frame(k);
        zero.index_axis_mut(Axis(0), f).assign(&last);
        constant.index_axis_mut(Axis(0), f).assign(&(&last + &(&step * (k + 1) as f32)));
    }
    (zero, constant)
}

/// One row of the table: a method's error at 1/2/3 s in millimetres.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MrtRow {
    /// What was scored.
    pub method: String,
    /// Millimetres at 1, 2 and 3 s.
    pub mm: [f64; 3],
}

impl MrtRow {
    /// The same error in MRT's units.
    pub fn mrt_units(&self) -> [f64; 3] {
        self.mm.map(|v| v * MRT_UNITS_PER_MM)
    }
}

/// A published row, in its paper's units.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PublishedRow {
    /// Method and paper.
    pub method: &'static str,
    /// As published at 1, 2 and 3 s (MRT's units); `None` where we could not check the number.
    pub published: [Option<f64>; 3],
}

/// Published rows under this protocol, as printed in their papers (MRT's units), with the
/// numbers we could check against a second source.
pub const PUBLISHED: [PublishedRow; 1] = [PublishedRow { method: "MRT (Wang et al., NeurIPS 2021), as published", published: [Some(0.89), None, None] }];

/// What `socdiff bench mrt` measured.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MrtBench {
    /// Windows scored.
    pub windows: usize,
    /// The sequences they came from.
    pub sequences: Vec<String>,
    /// Samples per window of the model (0: baselines only).
    pub samples: usize,
    /// Rows: the model (mean of K, best of K, the mean of the K samples as one forecast), then
    /// zero and constant velocity.
    pub rows: Vec<MrtRow>,
}

impl MrtBench {
    /// The table: mm and MRT's units at 1/2/3 s, then the published rows.
    pub fn table(&self) -> String {
        let mut t = format!(
            "MRT's MuPoTS-3D protocol: {} windows of {} three-person sequences; 15 frames observed, 45 forecast at 15 fps; 15 joints; \
             mean error over the first 1/2/3 s\n{:44} {:>6} {:>6} {:>6}   {:>5} {:>5} {:>5}\n",
            self.windows,
            self.sequences.len(),
            "method",
            "1 s mm",
            "2 s",
            "3 s",
            "1 s",
            "2 s",
            "3 s (MRT units)"
        );
        for r in &self.rows {
            let u = r.mrt_units();
            t += &format!("{:44} {:>6.0} {:>6.0} {:>6.0}   {:>5.2} {:>5.2} {:>5.2}\n", r.method, r.mm[0], r.mm[1], r.mm[2], u[0], u[1], u[2]);
        }
        for p in &PUBLISHED {
            let v = p.published.map(|v| v.map_or("–".to_string(), |v| format!("{v:.2}")));
            t += &format!("{:44} {:>6} {:>6} {:>6}   {:>5} {:>5} {:>5}\n", p.method, "", "", "", v[0], v[1], v[2]);
        }
        t
    }

    /// Every number, keyed by method (`mrt.json`).
    pub fn to_json(&self) -> serde_json::Value {
        let rows: Vec<serde_json::Value> = self
            .rows
            .iter()
            .map(|r| serde_json::json!({"method": r.method, "mm": {"1s": r.mm[0], "2s": r.mm[1], "3s": r.mm[2]}, "mrt_units": r.mrt_units()}))
            .collect();
        serde_json::json!({
            "protocol": {"windows": self.windows, "sequences": self.sequences, "window_frames": WINDOW, "stride": STRIDE,
                "observed_frames_15fps": 15, "forecast_frames_15fps": PREDICTED, "joints": Skeleton::mrt15().joints,
                "mrt_units_per_mm": MRT_UNITS_PER_MM, "samples": self.samples},
            "rows": rows,
            "published": PUBLISHED,
        })
    }
}

/// Mean of per-window errors.
fn mean_rows(per_window: &[[f64; 3]]) -> [f64; 3] {
    let n = per_window.len().max(1) as f64;
    [0, 1, 2].map(|h| per_window.iter().map(|e| e[h]).sum::<f64>() / n)
}

/// Indices of MRT's 15 joints in `skeleton`, by name. Errors: a joint it lacks.
fn mrt_joints(skeleton: &Skeleton) -> Result<Vec<usize>> {
    Skeleton::mrt15().joints.iter().map(|n| skeleton.require_joint(n)).collect()
}

/// Runs the benchmark on `dataset` (MuPoTS-3D on its 17 joints, metres): the baselines, and
/// with `model` its `proto.request.samples` forecasts of every window (the request's observe
/// and horizon are set here). Errors: a model not at 30 fps or whose joints cannot be mapped
/// from the dataset's by name.
pub fn run(dataset: &Dataset, model: Option<&LoadedModel>, proto: &Protocol, on_step: &mut dyn FnMut(StepInfo)) -> Result<MrtBench> {
    let windows = windows(dataset)?;
    let mut sequences: Vec<String> = windows.iter().map(|w| w.name.split('@').next().unwrap_or_default().to_string()).collect();
    sequences.dedup();
    let joints = mrt_joints(&windows[0].skeleton)?;
    let (mut zero, mut constant) = (Vec::new(), Vec::new());
    for w in &windows {
        let (z, c) = baselines(w.positions.view());
        zero.push(window_error(z.view(), w.positions.view(), &joints));
        constant.push(window_error(c.view(), w.positions.view(), &joints));
    }
    let mut rows = Vec::new();
    let mut samples = 0;
    if let Some(model) = model {
        if (model.fps - 30.0).abs() > 1e-6 {
            bail!("{}: MRT's protocol needs a 30 fps model, this one is at {} fps", model.path.display(), model.fps);
        }
        let on_model: Vec<Scene> = windows.iter().map(|w| Ok(model.fit_scene(w, true)?.0)).collect::<Result<_>>()?;
        let mjoints = mrt_joints(&on_model[0].skeleton)?;
        let truth_of = |i: usize| on_model[i].positions.view();
        let inputs: Vec<Scene> = on_model.iter().map(observed_input).collect::<Result<_>>()?;
        let mut request = proto.request.clone();
        (request.observe, request.horizon) = (LAST_OBSERVED + 1, WINDOW - 1 - LAST_OBSERVED);
        let runs = forecast_scenes(model, &inputs, &Protocol { request, window_stride: None, device: proto.device }, on_step)?;
        let (mut mean, mut best, mut point) = (Vec::new(), Vec::new(), Vec::new());
        for (i, r) in runs.iter().enumerate() {
            let per: Vec<[f64; 3]> = r.forecast.samples.iter().map(|s| window_error(s.positions.view(), truth_of(i), &mjoints)).collect();
            mean.push(mean_rows(&per));
            best.push([0, 1, 2].map(|h| per.iter().map(|e| e[h]).fold(f64::INFINITY, f64::min)));
            let all = r.samples();
            let avg = all.mean_axis(Axis(0)).expect("at least one sample");
            point.push(window_error(avg.view(), truth_of(i), &mjoints));
        }
        samples = runs[0].forecast.samples.len();
        let k = samples;
        rows.push(MrtRow { method: format!("socdiff, mean of {k} samples"), mm: mean_rows(&mean).map(|v| v * 1e3) });
        rows.push(MrtRow { method: format!("socdiff, best of {k}"), mm: mean_rows(&best).map(|v| v * 1e3) });
        rows.push(MrtRow { method: format!("socdiff, mean of the {k} samples as one forecast"), mm: mean_rows(&point).map(|v| v * 1e3) });
    }
    rows.push(MrtRow { method: "zero velocity".into(), mm: mean_rows(&zero).map(|v| v * 1e3) });
    rows.push(MrtRow { method: "constant velocity".into(), mm: mean_rows(&constant).map(|v| v * 1e3) });
    Ok(MrtBench { windows: windows.len(), sequences, samples, rows })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn window(persons: usize, joints: usize, at: impl Fn(usize, usize, usize, usize) -> f32) -> Array4<f32> {
        Array4::from_shape_fn((WINDOW, persons, joints, 3), |(f, p, j, c)| at(f, p, j, c))
    }

    #[test]
    fn a_walk_at_constant_speed_is_forecast_exactly_by_constant_velocity() {
        // Every joint moves 1 cm per 30-fps frame along x.
        let w = window(3, 15, |f, p, j, c| if c == 0 { 0.01 * f as f32 + p as f32 } else { 0.1 * j as f32 });
        let joints: Vec<usize> = (0..15).collect();
        let (zero, constant) = baselines(w.view());
        let e = window_error(constant.view(), w.view(), &joints);
        assert!(e.iter().all(|v| v.abs() < 1e-5), "{e:?}");
        // Zero velocity: frame 30 + 2k is 2k + 2 frames past frame 28, 0.02 (k + 1) m off; the
        // mean over k < n is 0.01 (n + 1).
        let e = window_error(zero.view(), w.view(), &joints);
        for (got, n) in e.iter().zip([15.0, 30.0, 45.0]) {
            assert!((got - 0.01 * (n + 1.0)).abs() < 1e-5, "{e:?}");
        }
    }

    #[test]
    fn observed_input_holds_only_the_even_frames() {
        let w = window(1, 2, |f, _, _, _| ((f * f) % 7) as f32);
        let sc = Scene::new("w", 30.0, Skeleton::new("s", vec!["a".into(), "b".into()], vec![], 0, 1).unwrap(), w.clone()).unwrap();
        let input = observed_input(&sc).unwrap();
        assert_eq!(input.num_frames(), 119);
        for f in 0..119 {
            let want = match f {
                29.. => w[[28, 0, 0, 0]],
                _ if f % 2 == 0 => w[[f, 0, 0, 0]],
                _ => (w[[f - 1, 0, 0, 0]] + w[[f + 1, 0, 0, 0]]) / 2.0,
            };
            assert_eq!(input.positions[[f, 0, 1, 2]], want, "frame {f}");
        }
    }

    #[test]
    fn units_follow_mrt_preprocessing() {
        assert!((MRT_UNITS_PER_MM - 0.00102).abs() < 1e-12);
        let r = MrtRow { method: "x".into(), mm: [1000.0, 500.0, 0.0] };
        assert!((r.mrt_units()[0] - 1.02).abs() < 1e-9 && (r.mrt_units()[1] - 0.51).abs() < 1e-9);
        assert_eq!(scored_frame(0), 30);
        assert_eq!(scored_frame(44), 118);
    }
}
