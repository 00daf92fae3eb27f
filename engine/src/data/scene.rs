//! A scene: the 3D joint positions of every person over time, with what we know about them.

use super::skeleton::Skeleton;
use crate::{bail, Result};
use ndarray::{s, Array2, Array4, ArrayView3, Axis};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Who a person is in a scene: an id from the source and an optional role
/// (e.g. `buyer`, `left_seller`, `right_seller` in Haggling).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Person {
    /// Identifier from the source (Haggling `humanId`, BVH file stem, ...).
    pub id: String,
    /// Social role, when the source names one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub role: Option<String>,
}

/// Multi-person motion.
///
/// # Shapes
/// - `positions`: `[frames, persons, joints, 3]`, metres, z up, right-handed.
/// - `valid`: `[frames, persons]`, `true` where the pose was observed (poses exist everywhere).
/// - each signal: `[frames, persons]` (e.g. `speaking`, 0 or 1).
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    /// Name of the sequence (unique inside a dataset).
    pub name: String,
    /// Frames per second.
    pub fps: f64,
    /// Skeleton of every person.
    pub skeleton: Skeleton,
    /// Joint positions `[frames, persons, joints, 3]`.
    pub positions: Array4<f32>,
    /// Validity mask `[frames, persons]`; `None` means every frame is valid.
    pub valid: Option<Array2<bool>>,
    /// Named per-(frame, person) signals, each `[frames, persons]`.
    pub signals: BTreeMap<String, Array2<f32>>,
    /// One entry per person.
    pub persons: Vec<Person>,
    /// Free-form provenance (source file, removed tilt, ...), kept in `dataset.json`.
    pub metadata: serde_json::Map<String, serde_json::Value>,
}

/// Checks that a frame rate is in (0, [`super::MAX_FPS`]].
pub fn check_fps(fps: f64) -> Result<()> {
    if !(fps.is_finite() && fps > 0.0 && fps <= super::MAX_FPS) {
        bail!("fps must be in (0, {}], got {fps}", super::MAX_FPS);
    }
    Ok(())
}

impl Scene {
    /// Builds a scene, checking shapes against the skeleton. Persons get ids `0..P`.
    pub fn new(name: impl Into<String>, fps: f64, skeleton: Skeleton, positions: Array4<f32>) -> Result<Self> {
        let name = name.into();
        let (frames, persons, joints, three) = positions.dim();
        if three != 3 || joints != skeleton.num_joints() {
            bail!(
                "scene {name}: positions have shape [{frames}, {persons}, {joints}, {three}], expected [frames, persons, {}, 3] for skeleton {}",
                skeleton.num_joints(),
                skeleton.name
            );
        }
        if frames == 0 || persons == 0 {
            bail!("scene {name}: empty ({frames} frames, {persons} persons)");
        }
        check_fps(fps).map_err(|e| crate::Error::invalid(format!("scene {name}: {e}")))?;
        if let Some((i, &v)) = positions.iter().enumerate().find(|(_, v)| !v.is_finite() || v.abs() > super::MAX_ABS_POSITION) {
            let f = i / (persons * joints * 3);
            let p = (i / (joints * 3)) % persons;
            let j = (i / 3) % joints;
            let what = if v.is_finite() { format!("position {v} m, beyond ±{} m,", super::MAX_ABS_POSITION) } else { "non-finite position".into() };
            bail!("scene {name}: {what} at frame {f}, person {p}, joint {} ({})", j, skeleton.joints[j]);
        }
        let persons = (0..persons).map(|p| Person { id: p.to_string(), role: None }).collect();
        Ok(Self { name, fps, skeleton, positions, valid: None, signals: BTreeMap::new(), persons, metadata: Default::default() })
    }

    /// Sets the validity mask `[frames, persons]`.
    pub fn with_valid(mut self, valid: Array2<bool>) -> Result<Self> {
        self.check_per_frame_person("validity mask", valid.dim())?;
        self.valid = Some(valid);
        Ok(self)
    }

    /// Adds a named signal `[frames, persons]`.
    pub fn with_signal(mut self, name: impl Into<String>, values: Array2<f32>) -> Result<Self> {
        let name = name.into();
        self.check_per_frame_person(&format!("signal {name:?}"), values.dim())?;
        self.signals.insert(name, values);
        Ok(self)
    }

    /// Replaces the person list (ids and roles); its length must equal the person count.
    pub fn with_persons(mut self, persons: Vec<Person>) -> Result<Self> {
        if persons.len() != self.num_persons() {
            bail!("scene {}: {} person entries for {} persons", self.name, persons.len(), self.num_persons());
        }
        self.persons = persons;
        Ok(self)
    }

    fn check_per_frame_person(&self, what: &str, dim: (usize, usize)) -> Result<()> {
        if dim != (self.num_frames(), self.num_persons()) {
            bail!("scene {}: {what} has shape [{}, {}], expected [frames, persons] = [{}, {}]", self.name, dim.0, dim.1, self.num_frames(), self.num_persons());
        }
        Ok(())
    }

    /// Number of frames.
    pub fn num_frames(&self) -> usize {
        self.positions.dim().0
    }

    /// Number of persons.
    pub fn num_persons(&self) -> usize {
        self.positions.dim().1
    }

    /// Number of joints per person.
    pub fn num_joints(&self) -> usize {
        self.positions.dim().2
    }

    /// Duration in seconds.
    pub fn duration(&self) -> f64 {
        self.num_frames() as f64 / self.fps
    }

    /// Whether person `p` is valid at frame `f`.
    pub fn is_valid(&self, f: usize, p: usize) -> bool {
        self.valid.as_ref().is_none_or(|v| v[[f, p]])
    }

    /// Number of invalid (frame, person) entries.
    pub fn num_invalid(&self) -> usize {
        self.valid.as_ref().map_or(0, |v| v.iter().filter(|&&x| !x).count())
    }

    /// Poses of one person, `[frames, joints, 3]`.
    pub fn person(&self, p: usize) -> ArrayView3<'_, f32> {
        self.positions.index_axis(Axis(1), p)
    }

    /// Per-bone length mean and standard deviation (population) over valid frames, in metres.
    pub fn bone_length_stats(&self) -> Vec<(f64, f64)> {
        self.skeleton
            .bones
            .iter()
            .map(|&(a, b)| {
                let (mut n, mut sum, mut sum2) = (0usize, 0.0f64, 0.0f64);
                for f in 0..self.num_frames() {
                    for p in 0..self.num_persons() {
                        if !self.is_valid(f, p) {
                            continue;
                        }
                        let pa = self.positions.slice(s![f, p, a, ..]);
                        let pb = self.positions.slice(s![f, p, b, ..]);
                        let d = (0..3).map(|k| (pa[k] as f64 - pb[k] as f64).powi(2)).sum::<f64>().sqrt();
                        n += 1;
                        sum += d;
                        sum2 += d * d;
                    }
                }
                let n = n.max(1) as f64;
                let mean = sum / n;
                (mean, (sum2 / n - mean * mean).max(0.0).sqrt())
            })
            .collect()
    }

    /// Keeps only the given persons, in the given order.
    pub fn select_persons(&self, persons: &[usize]) -> Result<Self> {
        if persons.is_empty() {
            bail!("scene {}: no persons selected", self.name);
        }
        if let Some(&p) = persons.iter().find(|&&p| p >= self.num_persons()) {
            bail!("scene {}: person {p} out of range (scene has {} persons)", self.name, self.num_persons());
        }
        if let Some((i, &p)) = persons.iter().enumerate().find(|&(i, p)| persons[..i].contains(p)) {
            bail!("scene {}: person {p} selected twice (at {} and {i})", self.name, persons.iter().position(|&q| q == p).unwrap_or(0));
        }
        let mut out = self.clone();
        out.positions = self.positions.select(Axis(1), persons);
        out.valid = self.valid.as_ref().map(|v| v.select(Axis(1), persons));
        for (k, v) in &self.signals {
            out.signals.insert(k.clone(), v.select(Axis(1), persons));
        }
        out.persons = persons.iter().map(|&p| self.persons[p].clone()).collect();
        Ok(out)
    }

    /// Frames `start..end` of the scene.
    pub fn slice_frames(&self, start: usize, end: usize) -> Result<Self> {
        if start >= end || end > self.num_frames() {
            bail!("scene {}: frame range {start}..{end} is not inside 0..{}", self.name, self.num_frames());
        }
        let mut out = self.clone();
        out.positions = self.positions.slice(s![start..end, .., .., ..]).to_owned();
        out.valid = self.valid.as_ref().map(|v| v.slice(s![start..end, ..]).to_owned());
        for (k, v) in &self.signals {
            out.signals.insert(k.clone(), v.slice(s![start..end, ..]).to_owned());
        }
        Ok(out)
    }

    /// Applies `x ↦ R·x + t` to every joint (R row-major 3×3).
    pub fn transform(&mut self, rotation: [[f64; 3]; 3], translation: [f64; 3]) {
        for mut v in self.positions.lanes_mut(Axis(3)) {
            let y = super::rotation::add(super::rotation::apply(&rotation, [v[0] as f64, v[1] as f64, v[2] as f64]), translation);
            for (out, y) in v.iter_mut().zip(y) {
                *out = y as f32;
            }
        }
    }

    /// Resamples to `fps` by linear interpolation in time. Validity is kept only where both
    /// neighbouring source frames are valid; signals are interpolated linearly.
    pub fn resample(&self, fps: f64) -> Result<Self> {
        check_fps(fps).map_err(|e| crate::Error::invalid(format!("scene {}: target {e}", self.name)))?;
        let n_src = self.num_frames();
        let n_dst_f = ((n_src - 1) as f64) * fps / self.fps + 1.0;
        let (_, persons, joints, _) = self.positions.dim();
        super::check_size(&format!("scene {} resampled to {fps} fps", self.name), n_dst_f, persons, 1)?;
        let n_dst = n_dst_f.floor() as usize;
        let mut positions = Array4::<f32>::zeros((n_dst, persons, joints, 3));
        let mut valid = self.valid.as_ref().map(|_| Array2::from_elem((n_dst, persons), true));
        let mut signals: BTreeMap<String, Array2<f32>> = self.signals.keys().map(|k| (k.clone(), Array2::zeros((n_dst, persons)))).collect();
        for f in 0..n_dst {
            let x = f as f64 * self.fps / fps;
            let i0 = (x.floor() as usize).min(n_src - 1);
            let i1 = (i0 + 1).min(n_src - 1);
            let w = (x - i0 as f64) as f32;
            let a = self.positions.slice(s![i0, .., .., ..]);
            let b = self.positions.slice(s![i1, .., .., ..]);
            positions.slice_mut(s![f, .., .., ..]).assign(&(&a * (1.0 - w) + &b * w));
            if let (Some(dst), Some(src)) = (valid.as_mut(), self.valid.as_ref()) {
                for p in 0..persons {
                    dst[[f, p]] = src[[i0, p]] && (w == 0.0 || src[[i1, p]]);
                }
            }
            for (k, v) in &self.signals {
                let out = signals.get_mut(k).expect("same keys");
                for p in 0..persons {
                    out[[f, p]] = v[[i0, p]] * (1.0 - w) + v[[i1, p]] * w;
                }
            }
        }
        let mut out = self.clone();
        out.fps = fps;
        out.positions = positions;
        out.valid = valid;
        out.signals = signals;
        Ok(out)
    }

    /// Places several scenes with the same skeleton and frame rate side by side as one scene
    /// (persons concatenated; the result is as long as the shortest input). `offsets[i]` is added
    /// to every joint of scene `i` — this is how single-person mocap becomes group data.
    pub fn combine(name: impl Into<String>, scenes: &[Scene], offsets: &[[f32; 3]]) -> Result<Self> {
        let name = name.into();
        if scenes.is_empty() {
            bail!("combine {name}: no scenes");
        }
        if offsets.len() != scenes.len() {
            bail!("combine {name}: {} offsets for {} scenes", offsets.len(), scenes.len());
        }
        let first = &scenes[0];
        for s in scenes {
            if s.skeleton.joints != first.skeleton.joints {
                bail!("combine {name}: scene {} has skeleton {}, scene {} has {}", s.name, s.skeleton.name, first.name, first.skeleton.name);
            }
            if (s.fps - first.fps).abs() > 1e-6 {
                bail!("combine {name}: scene {} is at {} fps, scene {} at {} fps (resample first)", s.name, s.fps, first.name, first.fps);
            }
        }
        let frames = scenes.iter().map(|s| s.num_frames()).min().expect("non-empty");
        let parts: Vec<Array4<f32>> = scenes
            .iter()
            .zip(offsets)
            .map(|(s, o)| {
                let mut x = s.positions.slice(s![..frames, .., .., ..]).to_owned();
                for mut v in x.lanes_mut(Axis(3)) {
                    for k in 0..3 {
                        v[k] += o[k];
                    }
                }
                x
            })
            .collect();
        let views: Vec<_> = parts.iter().map(|a| a.view()).collect();
        let positions = ndarray::concatenate(Axis(1), &views).map_err(|e| crate::Error::invalid(e.to_string()))?;
        let mut out = Scene::new(name, first.fps, first.skeleton.clone(), positions)?;
        if scenes.iter().any(|s| s.valid.is_some()) {
            let masks: Vec<Array2<bool>> = scenes
                .iter()
                .map(|s| match &s.valid {
                    Some(v) => v.slice(s![..frames, ..]).to_owned(),
                    None => Array2::from_elem((frames, s.num_persons()), true),
                })
                .collect();
            let views: Vec<_> = masks.iter().map(|a| a.view()).collect();
            out.valid = Some(ndarray::concatenate(Axis(1), &views).map_err(|e| crate::Error::invalid(e.to_string()))?);
        }
        out.persons = scenes
            .iter()
            .flat_map(|s| {
                s.persons
                    .iter()
                    .map(move |p| Person { id: if s.num_persons() == 1 { s.name.clone() } else { format!("{}/{}", s.name, p.id) }, role: p.role.clone() })
            })
            .collect();
        out.metadata.insert("combined_from".into(), serde_json::Value::from(scenes.iter().map(|s| s.name.clone()).collect::<Vec<_>>()));
        Ok(out)
    }
}

impl Scene {
    /// Combines scenes into one group scene (see [`Scene::combine`]), shifting each horizontally
    /// so that its first person's first-frame body centre (midpoint of the body-frame joints)
    /// lies on a circle: scene `i` at angle `2πi/n` from +x, neighbours `spacing` metres apart
    /// (two scenes: `spacing` apart along x; one scene: centred at the origin). Orientations
    /// and heights are kept.
    pub fn around_circle(name: impl Into<String>, scenes: &[Scene], spacing: f32) -> Result<Self> {
        let name = name.into();
        if !(spacing.is_finite() && spacing >= 0.0) {
            bail!("group {name}: spacing must be a non-negative number of metres, got {spacing}");
        }
        let n = scenes.len();
        let radius = if n <= 1 { 0.0 } else { spacing as f64 / (2.0 * (std::f64::consts::PI / n as f64).sin()) };
        let offsets: Vec<[f32; 3]> = scenes
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let a = std::f64::consts::TAU * i as f64 / n as f64;
                let (l, r) = (s.skeleton.left, s.skeleton.right);
                let centre = |k: usize| 0.5 * (s.positions[[0, 0, l, k]] + s.positions[[0, 0, r, k]]);
                [(radius * a.cos()) as f32 - centre(0), (radius * a.sin()) as f32 - centre(1), 0.0]
            })
            .collect();
        let mut out = Scene::combine(name, scenes, &offsets)?;
        out.metadata.insert("group_spacing_m".into(), (spacing as f64).into());
        Ok(out)
    }
}

impl Scene {
    /// The root joint of person `person`: `name` if given, else by name (pelvis, hips,
    /// ...), else the joint closest on average to the midpoint of the body-frame joints.
    pub fn root_joint(&self, person: usize, name: Option<&str>) -> Result<usize> {
        let scene = self;
        let sk = &scene.skeleton;
        if let Some(n) = name {
            return sk.require_joint(n);
        }
        if let Some(j) = super::joints::find_part(&sk.joints, &[(super::joints::Part::Pelvis, super::joints::Side::Centre)]) {
            return Ok(j);
        }
        let frames = scene.num_frames();
        let stride = (frames / 200).max(1);
        let mut dist = vec![0.0f64; sk.num_joints()];
        for f in (0..frames).step_by(stride) {
            let x = |j: usize, k: usize| scene.positions[[f, person, j, k]] as f64;
            for (j, d) in dist.iter_mut().enumerate() {
                *d += (0..3).map(|k| (x(j, k) - 0.5 * (x(sk.left, k) + x(sk.right, k))).powi(2)).sum::<f64>().sqrt();
            }
        }
        Ok((0..sk.num_joints()).min_by(|&a, &b| dist[a].total_cmp(&dist[b])).expect("skeletons have joints"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn toy(frames: usize, persons: usize) -> Scene {
        let sk = Skeleton::mupots17();
        let pos = Array4::from_shape_fn((frames, persons, 17, 3), |(f, p, j, k)| (f * 100 + p * 10 + j) as f32 + k as f32 * 0.1);
        Scene::new("toy", 30.0, sk, pos).unwrap()
    }

    #[test]
    fn shapes_are_checked() {
        let sk = Skeleton::mupots17();
        assert!(Scene::new("x", 30.0, sk.clone(), Array4::zeros((4, 2, 16, 3))).is_err());
        assert!(Scene::new("x", 30.0, sk.clone(), Array4::zeros((0, 2, 17, 3))).is_err());
        let mut nan = Array4::zeros((4, 2, 17, 3));
        nan[[2, 1, 5, 0]] = f32::NAN;
        let e = Scene::new("x", 30.0, sk, nan).unwrap_err().to_string();
        assert!(e.contains("frame 2, person 1, joint 5"), "{e}");
        assert!(toy(4, 2).with_signal("speaking", Array2::zeros((4, 3))).is_err());
    }

    #[test]
    fn resample_halves_and_interpolates() {
        let s = toy(5, 1);
        let r = s.resample(15.0).unwrap();
        assert_eq!(r.num_frames(), 3);
        assert_eq!(r.positions[[1, 0, 0, 0]], s.positions[[2, 0, 0, 0]]);
        let u = s.resample(60.0).unwrap();
        assert_eq!(u.num_frames(), 9);
        assert!((u.positions[[1, 0, 3, 0]] - 53.0).abs() < 1e-4);
    }

    #[test]
    fn combine_and_select() {
        let a = toy(5, 1);
        let b = toy(4, 2);
        let c = Scene::combine("ab", &[a.clone(), b], &[[0.0; 3], [1.0, 0.0, 0.0]]).unwrap();
        assert_eq!(c.positions.dim(), (4, 3, 17, 3));
        assert_eq!(c.positions[[3, 1, 0, 0]], 301.0 + 10.0 * 0.0);
        let sel = c.select_persons(&[2, 0]).unwrap();
        assert_eq!(sel.positions[[0, 1, 4, 2]], a.positions[[0, 0, 4, 2]]);
        assert!(c.select_persons(&[3]).is_err());
    }
}
