//! Forecasts from frames as they arrive ([`Stream`]): a robot's camera gives one frame of every
//! tracked person at a time; once the last `observe` frames are in, every new frame gets a
//! forecast of the next `horizon` frames from them.
//!
//! Each forecast samples the window of the last `observe` frames afresh (its cost is the
//! sampler's steps: see `socdiff bench realtime`). Frames are checked as they come: their shape
//! against the model's skeleton and the stream's persons, every value finite, and the time
//! against the model's frame rate — a gap (a frame more than half a frame period late) restarts
//! the window, since the frames before it are no longer the recent past.

use super::{Forecast, ForecastOutput, Model, Task};
use crate::data::Scene;
use crate::{bail, Result};
use ndarray::{s, Array3, Array4, ArrayView3};
use std::ops::Deref;

/// Frames in, a forecast per frame out (module docs).
///
/// ```no_run
/// use socdiff_engine::forecast::{Forecast, Model, SamplerKind, Stream};
/// let model = Model::load("runs/m")?;
/// let req = Forecast { observe: 30, horizon: 90, samples: 8, sampler: SamplerKind::Ddim { steps: 2, eta: 0.0 }, ..Default::default() };
/// let mut stream = Stream::new(&model, 3, req)?;
/// # let frames: Vec<(f64, ndarray::Array3<f32>)> = Vec::new();
/// for (time, frame) in frames {
///     if let Some(fc) = stream.push(time, frame.view())? {
///         // fc.samples[k]: the last 30 frames and the 90 forecast after them.
///     }
/// }
/// # Ok::<(), socdiff_engine::Error>(())
/// ```
pub struct Stream<M: Deref<Target = Model>> {
    model: M,
    request: Forecast,
    persons: usize,
    /// The last `observe` frames, oldest first, `[observe, persons, joints, 3]`.
    window: Array4<f32>,
    /// Frames in the window (up to `observe`).
    filled: usize,
    /// Time of the last frame taken.
    last_time: Option<f64>,
    /// Frames taken since the stream (or its last restart) began.
    taken: u64,
}

impl<M: Deref<Target = Model>> Stream<M> {
    /// A stream of `persons` persons in `model`'s skeleton at its frame rate (`model`: a
    /// `&Model`, or an `Arc<Model>` to own it); `request.observe` frames are kept and each
    /// forecast is `request.horizon` frames (`request`'s sampler, samples and seed; the seed of
    /// the forecast at frame n is `seed + n`).
    pub fn new(model: M, persons: usize, request: Forecast) -> Result<Self> {
        let joints = model.checkpoint.skeleton.num_joints();
        if persons == 0 {
            bail!("stream: `persons` must be at least 1");
        }
        crate::data::check_size("stream window", request.observe as f64, persons, 1)?;
        if request.observe == 0 || request.horizon == 0 {
            bail!("stream: `observe` and `horizon` must be at least 1");
        }
        let window = Array4::zeros((request.observe, persons, joints, 3));
        Ok(Self { model, request, persons, window, filled: 0, last_time: None, taken: 0 })
    }

    /// Persons of every frame.
    pub fn persons(&self) -> usize {
        self.persons
    }

    /// Frames the window still lacks before the first forecast.
    pub fn frames_needed(&self) -> usize {
        self.request.observe - self.filled
    }

    /// Takes the frame observed at `time` seconds, `[persons, joints, 3]` in metres (z up, the
    /// model's skeleton), and returns the forecast from the last `observe` frames once the
    /// window is full. A bad frame is an error and changes nothing; a gap in time restarts the
    /// window with this frame.
    pub fn push(&mut self, time: f64, frame: ArrayView3<f32>) -> Result<Option<ForecastOutput>> {
        let joints = self.model.checkpoint.skeleton.num_joints();
        let (p, j, three) = frame.dim();
        if (p, j, three) != (self.persons, joints, 3) {
            bail!(
                "stream: frame at {time} s has shape [{p}, {j}, {three}], expected [{}, {joints}, 3] ({} persons, skeleton {})",
                self.persons,
                self.persons,
                self.model.checkpoint.skeleton.name
            );
        }
        if let Some((i, v)) = frame.iter().enumerate().find(|(_, v)| !v.is_finite() || v.abs() > crate::data::MAX_ABS_POSITION) {
            let (person, joint) = (i / (3 * joints), (i / 3) % joints);
            bail!(
                "stream: frame at {time} s: position {v} of person {person}, joint {joint} ({}) is not a finite position within ±{} m",
                self.model.checkpoint.skeleton.joints[joint],
                crate::data::MAX_ABS_POSITION
            );
        }
        if !time.is_finite() {
            bail!("stream: frame time {time} is not finite");
        }
        let period = 1.0 / self.model.checkpoint.fps;
        if let Some(last) = self.last_time {
            let dt = time - last;
            if dt < 0.5 * period {
                bail!("stream: frame at {time} s comes {dt:.4} s after the previous one, less than half a frame at {} fps", self.model.checkpoint.fps);
            }
            if dt > 1.5 * period {
                // A gap: the window no longer holds the recent past.
                self.filled = 0;
            }
        }
        self.last_time = Some(time);
        self.taken += 1;
        let n = self.request.observe;
        if self.filled == n {
            // Oldest frame out: shift the window by one frame.
            let rest = self.window.slice(s![1.., .., .., ..]).to_owned();
            self.window.slice_mut(s![..n - 1, .., .., ..]).assign(&rest);
            self.filled -= 1;
        }
        self.window.slice_mut(s![self.filled, .., .., ..]).assign(&frame);
        self.filled += 1;
        if self.filled < n {
            return Ok(None);
        }
        let m = &self.model.checkpoint;
        let scene = Scene::new(format!("stream@{time:.3}s"), m.fps, m.skeleton.clone(), self.window.clone())?;
        let request = Forecast { seed: self.request.seed.wrapping_add(self.taken), ..self.request.clone() };
        let task = Task::Forecast { observe: n, horizon: self.request.horizon };
        self.model.sample(&scene, &task, &request, &mut |_| {}).map(Some)
    }
}

/// One frame of a JSON-lines stream: `{"time": seconds, "positions": [[[x, y, z], …joints],
/// …persons]}` (`persons` and `joints` given), or an error naming what is wrong.
pub fn parse_json_frame(line: &str, persons: usize, joints: usize) -> Result<(f64, Array3<f32>)> {
    #[derive(serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Frame {
        time: f64,
        positions: Vec<Vec<[f32; 3]>>,
    }
    let f: Frame = serde_json::from_str(line).map_err(|e| crate::Error::invalid(format!("stream: a frame line is not {{\"time\", \"positions\"}}: {e}")))?;
    let (p, j) = (f.positions.len(), f.positions.first().map_or(0, Vec::len));
    if p != persons || f.positions.iter().any(|v| v.len() != joints) {
        bail!("stream: frame at {} s has {p} persons of {j} joints, expected {persons} of {joints}", f.time);
    }
    let flat: Vec<f32> = f.positions.iter().flatten().flatten().copied().collect();
    Ok((f.time, Array3::from_shape_vec((persons, joints, 3), flat).map_err(|e| crate::Error::invalid(e.to_string()))?))
}

/// The forecast frames of `fc` (after the observed ones) as one JSON line: `{"time", "frame",
/// "observe", "horizon", "samples": [K][horizon][persons][joints][3]}`, millimetre precision.
pub fn forecast_json_line(fc: &ForecastOutput, time: f64, frame: u64) -> String {
    let observe = fc.observed_frames;
    let mut s = format!(
        "{{\"time\":{time},\"frame\":{frame},\"observe\":{observe},\"horizon\":{},\"samples\":[",
        fc.samples.first().map_or(0, |x| x.num_frames() - observe)
    );
    for (k, sample) in fc.samples.iter().enumerate() {
        s.push_str(if k == 0 { "[" } else { ",[" });
        for (t, f) in sample.positions.outer_iter().skip(observe).enumerate() {
            s.push_str(if t == 0 { "[" } else { ",[" });
            for (p, person) in f.outer_iter().enumerate() {
                s.push_str(if p == 0 { "[" } else { ",[" });
                let joints: Vec<String> = person.outer_iter().map(|x| format!("[{:.4},{:.4},{:.4}]", x[0], x[1], x[2])).collect();
                s.push_str(&joints.join(","));
                s.push(']');
            }
            s.push(']');
        }
        s.push(']');
    }
    s.push_str("]}");
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::test_util::walkers;
    use crate::forecast::SamplerKind;

    fn bundled() -> Model {
        Model::load(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/groups-mrt15/model.safetensors")).unwrap()
    }

    #[test]
    fn a_forecast_per_frame_once_the_window_is_full() {
        let model = bundled();
        // Two walkers on the model's 15 joints at its 30 fps.
        let scene = model.fit_scene(&walkers(12, 2, 0.4), true).unwrap().0;
        let req = Forecast { observe: 8, horizon: 6, samples: 2, sampler: SamplerKind::Ddim { steps: 2, eta: 0.0 }, seed: 5, ..Default::default() };
        let mut stream = Stream::new(&model, 2, req.clone()).unwrap();
        let dt = 1.0 / 30.0;
        for f in 0..7 {
            assert!(stream.push(f as f64 * dt, scene.positions.slice(s![f, .., .., ..])).unwrap().is_none());
        }
        assert_eq!(stream.frames_needed(), 1);
        let fc = stream.push(7.0 * dt, scene.positions.slice(s![7, .., .., ..])).unwrap().unwrap();
        assert_eq!(fc.samples.len(), 2);
        assert_eq!(fc.samples[0].positions.dim(), (14, 2, 15, 3));
        assert_eq!(fc.samples[1].positions.slice(s![..8, .., .., ..]), scene.positions.slice(s![..8, .., .., ..]));
        // The same as forecasting the window as a scene, with the seed of the 8th frame.
        let window = scene.slice_frames(0, 8).unwrap();
        let direct = model.sample(&window, &Task::Forecast { observe: 8, horizon: 6 }, &Forecast { seed: 5 + 8, ..req.clone() }, &mut |_| {}).unwrap();
        assert_eq!(fc.samples[0].positions, direct.samples[0].positions);
        // The next frame slides the window by one.
        let fc = stream.push(8.0 * dt, scene.positions.slice(s![8, .., .., ..])).unwrap().unwrap();
        assert_eq!(fc.samples[0].positions.slice(s![..8, .., .., ..]), scene.positions.slice(s![1..9, .., .., ..]));
    }

    #[test]
    fn bad_frames_are_errors_and_a_gap_restarts_the_window() {
        let model = bundled();
        let req = Forecast { observe: 4, horizon: 2, samples: 1, sampler: SamplerKind::Ddim { steps: 1, eta: 0.0 }, ..Default::default() };
        let mut stream = Stream::new(&model, 2, req).unwrap();
        let scene = model.fit_scene(&walkers(12, 2, 0.4), true).unwrap().0;
        let frame = |f: usize| scene.positions.slice(s![f, .., .., ..]).to_owned();
        let dt = 1.0 / 30.0;
        stream.push(0.0, frame(0).view()).unwrap();
        stream.push(dt, frame(1).view()).unwrap();
        assert_eq!(stream.frames_needed(), 2);
        // Wrong joint count, wrong persons, NaN, too early: errors that change nothing.
        let e = stream.push(2.0 * dt, Array3::<f32>::zeros((2, 17, 3)).view()).unwrap_err().to_string();
        assert!(e.contains("[2, 17, 3], expected [2, 15, 3]"), "{e}");
        let e = stream.push(2.0 * dt, Array3::<f32>::zeros((3, 15, 3)).view()).unwrap_err().to_string();
        assert!(e.contains("expected [2, 15, 3] (2 persons"), "{e}");
        let mut nan = frame(2);
        nan[[1, 8, 2]] = f32::NAN;
        let e = stream.push(2.0 * dt, nan.view()).unwrap_err().to_string();
        assert!(e.contains("person 1, joint 8 (head_top)") && e.contains("finite"), "{e}");
        let e = stream.push(1.2 * dt, frame(2).view()).unwrap_err().to_string();
        assert!(e.contains("less than half a frame"), "{e}");
        let e = stream.push(f64::NAN, frame(2).view()).unwrap_err().to_string();
        assert!(e.contains("not finite"), "{e}");
        assert_eq!(stream.frames_needed(), 2);
        // A gap of three frame periods: the window starts again from this frame.
        assert!(stream.push(4.0 * dt, frame(4).view()).unwrap().is_none());
        assert_eq!(stream.frames_needed(), 3);
        for f in 5..7 {
            assert!(stream.push(f as f64 * dt, frame(f).view()).unwrap().is_none());
        }
        assert!(stream.push(7.0 * dt, frame(7).view()).unwrap().is_some());
        assert!(Stream::new(&model, 0, Forecast::default()).is_err());
    }

    #[test]
    fn json_frames_and_forecast_lines() {
        let (t, f) = parse_json_frame(r#"{"time": 0.5, "positions": [[[1, 2, 3], [4, 5, 6]]]}"#, 1, 2).unwrap();
        assert_eq!((t, f.into_raw_vec_and_offset().0), (0.5, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]));
        let e = parse_json_frame(r#"{"time": 0.5, "positions": [[[1, 2, 3]]]}"#, 1, 2).unwrap_err().to_string();
        assert!(e.contains("1 persons of 1 joints, expected 1 of 2"), "{e}");
        assert!(parse_json_frame(r#"{"time": 0.5, "positions": [[[1, 2]]]}"#, 1, 1).is_err());
        assert!(parse_json_frame(r#"{"t": 0.5, "positions": []}"#, 1, 1).unwrap_err().to_string().contains("time"));
        // A forecast line holds the frames after the observed ones, and parses as JSON.
        let model = bundled();
        let scene = model.fit_scene(&walkers(6, 1, 0.4), true).unwrap().0;
        let req = Forecast { observe: 4, horizon: 3, samples: 2, sampler: SamplerKind::Ddim { steps: 1, eta: 0.0 }, ..Default::default() };
        let fc = model.forecast(&scene.slice_frames(0, 4).unwrap(), req).unwrap();
        let v: serde_json::Value = serde_json::from_str(&forecast_json_line(&fc, 0.1, 4)).unwrap();
        assert_eq!((v["observe"].as_u64(), v["horizon"].as_u64(), v["frame"].as_u64()), (Some(4), Some(3), Some(4)));
        let samples = v["samples"].as_array().unwrap();
        assert_eq!((samples.len(), samples[0].as_array().unwrap().len(), samples[0][0][0].as_array().unwrap().len()), (2, 3, 15));
        let x = samples[1][2][0][14][2].as_f64().unwrap();
        assert!((x - fc.samples[1].positions[[6, 0, 14, 2]] as f64).abs() < 1e-4);
    }
}
