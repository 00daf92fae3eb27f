//! What gets scored: the reference dataset and the methods (forecast directories, plain
//! datasets, built-in baselines), checked against each other.
//!
//! # Forecast directories
//! A directory is a dataset directory (`dataset.json`) or a folder of them (each immediate
//! subdirectory with a `dataset.json`, e.g. one `socdiff forecast` output per scene), read
//! together as one method. A dataset with `forecast` metadata (see [`crate::export`]) gives,
//! per `source`, the samples `k` (`"sample": k`); its input parts and `"ground_truth"`
//! sequences are not scored (the reference is the ground truth). A dataset without forecast
//! metadata is a *plain* dataset: each sequence of the reference split is scored as a
//! one-sample forecast of the reference sequence of the same name, observed for `observe`
//! frames (so ground truth can be scored like a method).
//!
//! Every scored scene must match its reference scene: same joints, fps and persons (after the
//! forecast's own `persons` selection, when its provenance has one), at most as many frames
//! (longer forecasts are an error, or are cropped on request), and observed frames equal to the
//! reference's (within 1 mm).
//!
//! # Baselines
//! Built from the reference split itself: the first `observe` frames of each scene are
//! observed, `horizon` frames (default: to the end of the scene) are forecast by
//! [`crate::metrics::baselines`] (one sample each); `ground-truth` is the recorded future.

use crate::data::dataset::{read_dataset, Dataset, ReadOptions, Sequence, Split};
use crate::data::import::{self, ImportOptions};
use crate::data::{Scene, Skeleton};
use crate::export::ForecastInfo;
use crate::metrics::baselines::{constant_velocity, nearest_continuation, zero_velocity};
use crate::metrics::NdmsDatabase;
use crate::{bail, Error, Result};
use ndarray::{s, Array5, ArrayView4, Axis};
use serde_json::{json, Map, Value};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The reference dataset and the split whose scenes are forecast.
#[derive(Clone, Debug)]
pub struct Reference {
    /// Where it was read from.
    pub path: PathBuf,
    /// The whole dataset (other splits serve as databases, e.g. for nearest continuation).
    pub dataset: Dataset,
    /// The split that is forecast and scored.
    pub split: Split,
}

impl Reference {
    /// Reads `path` (a dataset directory or any importable file) and checks that `split` has
    /// scenes sharing one skeleton and frame rate.
    pub fn load(path: &Path, split: Split) -> Result<Self> {
        Self::load_with(path, split, &ImportOptions::default())
    }

    /// [`Reference::load`] with import options (ground alignment, BVH units, …).
    pub fn load_with(path: &Path, split: Split, opts: &ImportOptions) -> Result<Self> {
        if !path.exists() {
            return Err(Error::io(path, std::io::Error::new(std::io::ErrorKind::NotFound, "reference dataset not found")));
        }
        let dataset = import::load(path, opts)?;
        Self::new(path, dataset, split)
    }

    /// A reference from a dataset in memory (`path` is for messages and provenance).
    pub fn new(path: &Path, dataset: Dataset, split: Split) -> Result<Self> {
        let r = Self { path: path.to_path_buf(), dataset, split };
        let Some(first) = r.scenes().next() else {
            return Err(Error::format(path, format!("dataset {} has no {} sequences", r.dataset.name, split.as_str())));
        };
        for s in r.scenes() {
            if s.skeleton.joints != first.skeleton.joints || (s.fps - first.fps).abs() > 1e-9 {
                return Err(Error::format(
                    path,
                    format!("{} sequences {} and {} differ in skeleton or fps; score one kind at a time", split.as_str(), first.name, s.name),
                ));
            }
        }
        Ok(r)
    }

    /// Scenes of the split, in dataset order.
    pub fn scenes(&self) -> impl Iterator<Item = &Scene> {
        self.dataset.split(self.split)
    }

    /// Scenes of another split (e.g. train, for databases).
    pub fn split_scenes(&self, split: Split) -> Vec<&Scene> {
        self.dataset.split(split).collect()
    }

    /// The split's scene called `name`.
    pub fn scene(&self, name: &str) -> Result<&Scene> {
        self.scenes().find(|s| s.name == name).ok_or_else(|| {
            Error::format(
                &self.path,
                format!(
                    "has no {} sequence {name:?} ({} sequences: {})",
                    self.split.as_str(),
                    self.split.as_str(),
                    self.scenes().map(|s| s.name.as_str()).collect::<Vec<_>>().join(", ")
                ),
            )
        })
    }

    /// Skeleton of every scene of the split.
    pub fn skeleton(&self) -> &Skeleton {
        &self.scenes().next().expect("checked non-empty").skeleton
    }

    /// Frame rate of the split.
    pub fn fps(&self) -> f64 {
        self.scenes().next().expect("checked non-empty").fps
    }

    /// Position of a scene in the split (for ordering).
    fn order(&self, name: &str) -> usize {
        self.scenes().position(|s| s.name == name).unwrap_or(usize::MAX)
    }
}

/// A built-in baseline (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Baseline {
    /// The last observed pose, repeated.
    ZeroVelocity,
    /// Every joint keeps its last velocity.
    ConstantVelocity,
    /// Real motion continued from the nearest database word (another split).
    NearestContinuation,
    /// The recorded future.
    GroundTruth,
}

impl Baseline {
    /// Every baseline, in report order.
    pub const ALL: [Baseline; 4] = [Baseline::ZeroVelocity, Baseline::ConstantVelocity, Baseline::NearestContinuation, Baseline::GroundTruth];

    /// Command-line name and label.
    pub fn name(self) -> &'static str {
        match self {
            Baseline::ZeroVelocity => "zero-velocity",
            Baseline::ConstantVelocity => "constant-velocity",
            Baseline::NearestContinuation => "nearest",
            Baseline::GroundTruth => "ground-truth",
        }
    }

    /// Parses a comma-separated list (`all` for every baseline); sorted, without repeats.
    pub fn parse_list(spec: &str) -> Result<Vec<Baseline>> {
        let mut out = Vec::new();
        for item in spec.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            match item.to_ascii_lowercase().replace('_', "-").as_str() {
                "all" => out.extend(Baseline::ALL),
                "nearest-continuation" => out.push(Baseline::NearestContinuation),
                "gt" => out.push(Baseline::GroundTruth),
                name => match Baseline::ALL.iter().find(|b| b.name() == name) {
                    Some(b) => out.push(*b),
                    None => bail!("unknown baseline {item:?} (baselines: {}, or all)", Baseline::ALL.map(Baseline::name).join(", ")),
                },
            }
        }
        out.sort();
        out.dedup();
        Ok(out)
    }
}

/// Where a method comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum MethodKind {
    /// Forecast directories.
    Forecasts,
    /// Plain dataset directories, each sequence a one-sample forecast of itself.
    Dataset,
    /// A built-in baseline.
    Baseline(Baseline),
    /// Scenes generated from noise (`socdiff generate`), not paired with reference scenes
    /// ([`Method::from_generated`]).
    Generated,
}

impl MethodKind {
    /// Short name for the report.
    pub fn name(&self) -> String {
        match self {
            MethodKind::Forecasts => "forecasts".into(),
            MethodKind::Dataset => "dataset".into(),
            MethodKind::Baseline(b) => format!("baseline:{}", b.name()),
            MethodKind::Generated => "generated".into(),
        }
    }
}

/// One input directory of a method, with its provenance.
#[derive(Clone, Debug, PartialEq)]
pub struct MethodInput {
    /// Dataset directory.
    pub path: PathBuf,
    /// Its dataset name.
    pub dataset: String,
    /// Its dataset metadata (`forecast` provenance: model, sampler, seeds, ...).
    pub metadata: Map<String, Value>,
}

/// What [`Method::from_dirs`] does with forecasts that run past the end of their reference.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PastRecording {
    /// An error naming the files (a user's mix-up is not scored silently).
    #[default]
    Refuse,
    /// Cut them to the recording.
    Crop,
    /// Score them whole ([`MethodScene`]): pose errors on the recorded part.
    Score,
}

/// The forecasts of one reference scene. Samples may run past the end of the reference (a
/// minute forecast from a short recording): metrics that need the recorded future (MPJPE, ADE,
/// FDE, the speed histogram's reference) use its recorded frames, the others every frame.
/// Forecast directories longer than the reference are refused unless cropped
/// ([`Method::from_dirs`]), so that a user's mix-up is not scored silently.
#[derive(Clone, Debug)]
pub struct MethodScene {
    /// The reference scene (all its frames; persons as forecast).
    pub reference: Scene,
    /// Frames `0..observed` are observed (equal to the reference's).
    pub observed: usize,
    /// K ≥ 1 samples, each `[observed + forecast frames, persons, joints, 3]`, all the same shape.
    pub samples: Vec<Scene>,
}

impl MethodScene {
    /// Frames per sample (observed + forecast).
    pub fn frames(&self) -> usize {
        self.samples[0].num_frames()
    }

    /// Forecast frames per sample.
    pub fn forecast_frames(&self) -> usize {
        self.frames() - self.observed
    }

    /// Forecast frames that the reference has recorded.
    pub fn recorded_forecast_frames(&self) -> usize {
        self.frames().min(self.reference.num_frames()).saturating_sub(self.observed)
    }

    /// Name of the reference scene.
    pub fn name(&self) -> &str {
        &self.reference.name
    }

    /// The samples stacked.
    ///
    /// # Shapes
    /// - output `[K, frames, persons, joints, 3]`.
    pub fn stacked(&self) -> Array5<f32> {
        let views: Vec<_> = self.samples.iter().map(|s| s.positions.view()).collect();
        ndarray::stack(Axis(0), &views).expect("samples share one shape (checked)")
    }

    /// The reference over the sample frames it has recorded.
    ///
    /// # Shapes
    /// - output `[observed + recorded forecast frames, persons, joints, 3]`.
    pub fn truth(&self) -> ArrayView4<'_, f32> {
        self.reference.positions.slice(s![..self.observed + self.recorded_forecast_frames(), .., .., ..])
    }

    /// Checks the samples against the reference (module docs); `what` names the input.
    fn check(&self, what: &str, past: PastRecording) -> Result<()> {
        let r = &self.reference;
        let Some(first) = self.samples.first() else { bail!("{what}: scene {} has no samples", r.name) };
        for s in &self.samples {
            if s.skeleton.joints != r.skeleton.joints {
                bail!(
                    "{what}: sequence {} has skeleton {} ({} joints), the reference scene {} has {} ({} joints)",
                    s.name,
                    s.skeleton.name,
                    s.num_joints(),
                    r.name,
                    r.skeleton.name,
                    r.num_joints()
                );
            }
            if (s.fps - r.fps).abs() > 1e-6 * r.fps {
                bail!("{what}: sequence {} is at {} fps, the reference scene {} at {} fps", s.name, s.fps, r.name, r.fps);
            }
            if s.num_persons() != r.num_persons() {
                bail!("{what}: sequence {} has {} persons, the reference scene {} has {}", s.name, s.num_persons(), r.name, r.num_persons());
            }
            if s.num_frames() != first.num_frames() {
                bail!("{what}: samples {} and {} of {} differ in length ({} vs {} frames)", first.name, s.name, r.name, first.num_frames(), s.num_frames());
            }
            if s.num_frames() > r.num_frames() && past != PastRecording::Score {
                bail!(
                    "{what}: sequence {} has {} frames, longer than the reference scene {} ({} frames); forecast at most {} frames after the {} observed, or crop",
                    s.name,
                    s.num_frames(),
                    r.name,
                    r.num_frames(),
                    r.num_frames().saturating_sub(self.observed),
                    self.observed
                );
            }
            if let Some(i) = s.positions.iter().position(|v| !v.is_finite()) {
                let per_frame = s.num_persons() * s.num_joints() * 3;
                bail!("{what}: sequence {} has a non-finite position at frame {}", s.name, i / per_frame);
            }
            let n = self.observed;
            let diff =
                s.positions.slice(s![..n, .., .., ..]).iter().zip(r.positions.slice(s![..n, .., .., ..]).iter()).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
            if diff > 1e-3 {
                bail!(
                    "{what}: the {n} observed frames of {} differ from the reference scene {} by up to {:.3} m (a forecast of another scene or coordinate frame?)",
                    s.name,
                    r.name,
                    diff
                );
            }
        }
        if self.observed == 0 || self.observed >= first.num_frames() {
            bail!("{what}: scene {} has {} observed of {} frames: nothing observed or nothing forecast", r.name, self.observed, first.num_frames());
        }
        Ok(())
    }
}

/// A labelled set of forecasts of reference scenes.
#[derive(Clone, Debug)]
pub struct Method {
    /// Label in the report, table and plots.
    pub label: String,
    /// Where it comes from.
    pub kind: MethodKind,
    /// Input directories (empty for baselines).
    pub inputs: Vec<MethodInput>,
    /// Settings that produced it (baselines: observe, horizon, database).
    pub settings: Map<String, Value>,
    /// One entry per forecast reference scene, in reference order.
    pub scenes: Vec<MethodScene>,
}

/// The dataset directories in `path`: itself, or its immediate subdirectories holding a
/// `dataset.json` (sorted by name).
fn dataset_dirs(path: &Path) -> Result<Vec<PathBuf>> {
    if !path.exists() {
        return Err(Error::io(path, std::io::Error::new(std::io::ErrorKind::NotFound, "forecast directory not found")));
    }
    if !path.is_dir() {
        return Err(Error::format(path, "is not a directory (expected a forecast or dataset directory)"));
    }
    if path.join("dataset.json").is_file() {
        return Ok(vec![path.to_path_buf()]);
    }
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(|e| Error::io(path, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("dataset.json").is_file())
        .collect();
    dirs.sort();
    if dirs.is_empty() {
        return Err(Error::format(path, "holds no dataset.json, neither itself nor in a subdirectory"));
    }
    Ok(dirs)
}

/// Persons selected by a forecast (`"forecast": {"persons": [..]}` in the dataset metadata).
fn forecast_persons(ds: &Dataset, dir: &Path) -> Result<Option<Vec<usize>>> {
    let Some(p) = ds.metadata.get("forecast").and_then(|f| f.get("persons")) else { return Ok(None) };
    let v = p.as_array().and_then(|a| a.iter().map(|x| x.as_u64().map(|x| x as usize)).collect::<Option<Vec<_>>>());
    v.map(Some).ok_or_else(|| Error::format(dir.join("dataset.json"), "\"forecast\".\"persons\" is not a list of person indices"))
}

impl Method {
    /// Reads a method from forecast or plain dataset directories (module docs). `observe` is
    /// the observed-frame count of plain datasets; `crop` cuts forecasts longer than their
    /// reference scene instead of failing.
    pub fn from_dirs(label: &str, paths: &[PathBuf], reference: &Reference, observe: usize, past: PastRecording) -> Result<Self> {
        let mut inputs = Vec::new();
        let mut scenes: Vec<MethodScene> = Vec::new();
        let mut kinds = Vec::new();
        for path in paths {
            for dir in dataset_dirs(path)? {
                let ds = read_dataset(&dir, &ReadOptions::default())?;
                let what = dir.display().to_string();
                let persons = forecast_persons(&ds, &dir)?;
                let reference_scene = |name: &str| -> Result<Scene> {
                    let r = reference.scene(name).map_err(|e| Error::format(&dir, format!("forecasts scene {name:?}, but {e}")))?;
                    match &persons {
                        Some(p) => r.select_persons(p).map_err(|e| e.in_file(&dir)),
                        None => Ok(r.clone()),
                    }
                };
                let infos: Vec<(Option<ForecastInfo>, &Scene)> =
                    ds.sequences.iter().map(|s| Ok((ForecastInfo::from_scene(&s.scene).map_err(|e| e.in_file(&dir))?, &s.scene))).collect::<Result<_>>()?;
                let mut found = Vec::new();
                if infos.iter().any(|(i, _)| i.is_some()) {
                    kinds.push(MethodKind::Forecasts);
                    // source → (observed, samples by k)
                    let mut groups: BTreeMap<String, (usize, BTreeMap<usize, Scene>)> = BTreeMap::new();
                    for (info, scene) in &infos {
                        let Some(info) = info else { continue };
                        let Some(k) = info.sample else { continue };
                        let g = groups.entry(info.source.clone()).or_insert_with(|| (info.observed_frames, BTreeMap::new()));
                        if g.0 != info.observed_frames {
                            return Err(Error::format(&dir, format!("samples of {} have {} and {} observed frames", info.source, g.0, info.observed_frames)));
                        }
                        if g.1.insert(k, (*scene).clone()).is_some() {
                            return Err(Error::format(&dir, format!("{} has sample {k} twice", info.source)));
                        }
                    }
                    if groups.is_empty() {
                        return Err(Error::format(&dir, "has forecast metadata but no samples (only ground truth)"));
                    }
                    for (source, (observed, samples)) in groups {
                        found.push(MethodScene { reference: reference_scene(&source)?, observed, samples: samples.into_values().collect() });
                    }
                } else {
                    kinds.push(MethodKind::Dataset);
                    for seq in ds.sequences.iter().filter(|q| q.split == reference.split) {
                        found.push(MethodScene { reference: reference_scene(&seq.scene.name)?, observed: observe, samples: vec![seq.scene.clone()] });
                    }
                    if found.is_empty() {
                        return Err(Error::format(&dir, format!("holds no {} sequences and no forecasts", reference.split.as_str())));
                    }
                }
                for mut sc in found {
                    if past == PastRecording::Crop && sc.frames() > sc.reference.num_frames() {
                        let n = sc.reference.num_frames();
                        sc.samples = sc.samples.iter().map(|s| s.slice_frames(0, n)).collect::<Result<_>>()?;
                    }
                    sc.check(&what, past)?;
                    if scenes.iter().any(|o| o.name() == sc.name()) {
                        bail!("method {label}: scene {} is forecast twice (second time in {what})", sc.name());
                    }
                    scenes.push(sc);
                }
                inputs.push(MethodInput { path: dir.clone(), dataset: ds.name.clone(), metadata: ds.metadata.clone() });
            }
        }
        kinds.dedup();
        let kind = if kinds.len() == 1 { kinds.remove(0) } else { MethodKind::Forecasts };
        scenes.sort_by_key(|s| reference.order(s.name()));
        Ok(Self { label: label.to_string(), kind, inputs, settings: Map::new(), scenes })
    }

    /// Scenes generated from noise in a dataset directory (every sequence, any split; only the
    /// samples of a forecast directory such as `socdiff generate` writes), scored
    /// without a recorded future: sequences of one shape are the K samples of one method scene,
    /// whose first `lead` frames (the NDMS word lead, so that NDMS's first word starts at frame
    /// 0) count as observed and are also the scene's "reference" — the generated body at its
    /// start, against which bone lengths are compared. Metrics that need a recorded future
    /// (MPJPE, ADE, FDE, MMADE, MMFDE, the speed histogram) have nothing to score.
    /// `split`: only that split's sequences (real motion scored as if generated, e.g. a train
    /// split against the test split's words: the real-motion level); `None`: every sequence.
    /// Errors: a skeleton or frame rate other than the reference's, sequences not longer than
    /// `lead`, naming the directory and the sequence.
    pub fn from_generated(label: &str, path: &Path, reference: &Reference, lead: usize, split: Option<Split>) -> Result<Self> {
        let ds = read_dataset(path, &ReadOptions::default())?;
        let sk = reference.skeleton();
        let mut groups: BTreeMap<(usize, usize), Vec<Scene>> = BTreeMap::new();
        // A `socdiff generate` directory also holds its layout: only its samples are scored.
        let samples: Vec<bool> = ds
            .sequences
            .iter()
            .map(|q| Ok(ForecastInfo::from_scene(&q.scene).map_err(|e| e.in_file(path))?.is_some_and(|i| i.sample.is_some())))
            .collect::<Result<_>>()?;
        let any_samples = samples.contains(&true);
        for (seq, _) in ds.sequences.iter().zip(&samples).filter(|(q, &is)| (!any_samples || is) && split.is_none_or(|sp| q.split == sp)) {
            let s = &seq.scene;
            if s.skeleton.joints != sk.joints {
                return Err(Error::format(
                    path,
                    format!(
                        "sequence {} has skeleton {} ({} joints), the reference {} ({} joints)",
                        s.name,
                        s.skeleton.name,
                        s.num_joints(),
                        sk.name,
                        sk.joints.len()
                    ),
                ));
            }
            if (s.fps - reference.fps()).abs() > 1e-6 * reference.fps() {
                return Err(Error::format(path, format!("sequence {} is at {} fps, the reference at {} fps", s.name, s.fps, reference.fps())));
            }
            if s.num_frames() <= lead {
                return Err(Error::format(path, format!("sequence {} has {} frames; scoring generated motion needs more than {lead}", s.name, s.num_frames())));
            }
            groups.entry((s.num_persons(), s.num_frames())).or_default().push(s.clone());
        }
        if groups.is_empty() {
            return Err(Error::format(path, format!("holds no {}sequences", split.map_or(String::new(), |s| format!("{} ", s.as_str())))));
        }
        let scenes = groups
            .into_values()
            .map(|samples| {
                let mut start = samples[0].slice_frames(0, lead)?;
                start.name = format!("{} ({} samples)", samples[0].name, samples.len());
                Ok(MethodScene { reference: start, observed: lead, samples })
            })
            .collect::<Result<_>>()?;
        let input = MethodInput { path: path.to_path_buf(), dataset: ds.name.clone(), metadata: ds.metadata.clone() };
        Ok(Self { label: label.to_string(), kind: MethodKind::Generated, inputs: vec![input], settings: Map::new(), scenes })
    }

    /// A baseline forecast of every scene of the reference split: `observe` frames observed,
    /// `horizon` frames forecast (`None`: to the end of each scene). `database` is needed by
    /// [`Baseline::NearestContinuation`] (words of another split).
    pub fn baseline(b: Baseline, reference: &Reference, observe: usize, horizon: Option<usize>, database: Option<&NdmsDatabase>) -> Result<Self> {
        let mut scenes = Vec::new();
        for r in reference.scenes() {
            let nf = r.num_frames();
            if observe == 0 || observe >= nf {
                bail!("`observe` {observe}: scene {} has {nf} frames; need 1 ≤ observe < frames", r.name);
            }
            let h = match horizon {
                Some(h) if observe + h > nf => bail!(
                    "`horizon` {h}: scene {} has only {} frames after the {observe} observed (use a shorter horizon or `horizon` all)",
                    r.name,
                    nf - observe
                ),
                Some(0) => bail!("`horizon` must be at least 1"),
                Some(h) => h,
                None => nf - observe,
            };
            let obs = r.positions.slice(s![..observe, .., .., ..]);
            let future = match b {
                Baseline::ZeroVelocity => zero_velocity(obs, h)?,
                Baseline::ConstantVelocity => constant_velocity(obs, h)?,
                Baseline::NearestContinuation => {
                    let Some(db) = database else { bail!("nearest-continuation baseline: no database given") };
                    nearest_continuation(db, obs, h)?
                }
                Baseline::GroundTruth => r.positions.slice(s![observe..observe + h, .., .., ..]).to_owned(),
            };
            let sample = if b == Baseline::GroundTruth {
                r.slice_frames(0, observe + h)?
            } else {
                let pos = ndarray::concatenate(Axis(0), &[obs, future.view()]).expect("same pose shape");
                Scene::new(format!("{}_{}", r.name, b.name()), r.fps, r.skeleton.clone(), pos)?.with_persons(r.persons.clone())?
            };
            let sc = MethodScene { reference: r.clone(), observed: observe, samples: vec![sample] };
            sc.check(b.name(), PastRecording::Refuse)?;
            scenes.push(sc);
        }
        let mut settings = Map::new();
        settings.insert("observe".into(), observe.into());
        settings.insert("horizon".into(), horizon.map_or_else(|| "to the end of each scene".into(), Value::from));
        if let (Baseline::NearestContinuation, Some(db)) = (b, database) {
            settings.insert(
                "database".into(),
                json!({"words": db.num_words(), "word_length": db.word_length(), "note": "words of the continuation split (not the scored split)"}),
            );
        }
        Ok(Self { label: b.name().to_string(), kind: MethodKind::Baseline(b), inputs: Vec::new(), settings, scenes })
    }

    /// Total number of samples over all scenes.
    pub fn num_samples(&self) -> usize {
        self.scenes.iter().map(|s| s.samples.len()).sum()
    }

    /// The method as a forecast dataset (viewable with `socdiff view`, readable back with
    /// [`Method::from_dirs`]): per scene its observed part (`NAME_input`), the ground truth over
    /// the same frames (`NAME_gt`) and the samples (`NAME_sKK`), all in the test split.
    pub fn to_dataset(&self) -> Result<Dataset> {
        let mut sequences = Vec::new();
        for sc in &self.scenes {
            let r = &sc.reference;
            let mut input = r.slice_frames(0, sc.observed)?;
            input.name = format!("{}_input", r.name);
            sequences.push(Sequence { split: Split::Test, scene: input });
            let mut gt = r.slice_frames(0, sc.frames())?;
            gt.name = format!("{}_gt", r.name);
            ForecastInfo { observed_frames: sc.observed, sample: None, source: r.name.clone() }.insert_into(&mut gt.metadata);
            sequences.push(Sequence { split: Split::Test, scene: gt });
            for (k, s) in sc.samples.iter().enumerate() {
                let mut s = s.clone();
                s.name = format!("{}_s{k:02}", r.name);
                ForecastInfo { observed_frames: sc.observed, sample: Some(k), source: r.name.clone() }.insert_into(&mut s.metadata);
                sequences.push(Sequence { split: Split::Test, scene: s });
            }
        }
        let mut prov = self.settings.clone();
        prov.insert("method".into(), self.label.clone().into());
        prov.insert("kind".into(), self.kind.name().into());
        let mut metadata = Map::new();
        metadata.insert("forecast".into(), Value::Object(prov));
        Ok(Dataset { name: format!("{}_forecasts", self.label), sequences, metadata })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::dataset::write_dataset;
    use crate::data::test_util::{tmp, walkers};

    pub(crate) fn reference(frames: usize) -> Reference {
        let sequences = (0..3)
            .map(|i| {
                let mut s = walkers(frames + 10 * i, 2 + i % 2, i as f32 * 0.7);
                s.name = format!("S{i}");
                Sequence { split: if i == 2 { Split::Train } else { Split::Test }, scene: s }
            })
            .collect();
        Reference::new(Path::new("ref"), Dataset { name: "toy".into(), sequences, metadata: Map::new() }, Split::Test).unwrap()
    }

    #[test]
    fn baselines_round_trip_through_forecast_directories() {
        let r = reference(60);
        let cv = Method::baseline(Baseline::ConstantVelocity, &r, 20, None, None).unwrap();
        assert_eq!(cv.scenes.len(), 2);
        assert_eq!((cv.scenes[0].observed, cv.scenes[0].forecast_frames(), cv.scenes[1].forecast_frames()), (20, 40, 50));
        let dir = tmp("eval-roundtrip");
        write_dataset(&cv.to_dataset().unwrap(), &dir).unwrap();
        let back = Method::from_dirs("cv", std::slice::from_ref(&dir), &r, 5, PastRecording::Refuse).unwrap();
        assert_eq!(back.kind, MethodKind::Forecasts);
        assert_eq!(back.scenes.len(), 2);
        for (a, b) in cv.scenes.iter().zip(&back.scenes) {
            assert_eq!((a.name(), a.observed), (b.name(), b.observed));
            assert_eq!(a.stacked(), b.stacked());
        }
        let gt = Method::baseline(Baseline::GroundTruth, &r, 20, Some(30), None).unwrap();
        assert_eq!(gt.scenes[0].samples[0].positions, r.scene("S0").unwrap().positions.slice(s![..50, .., .., ..]));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn plain_datasets_and_bad_inputs() {
        let r = reference(60);
        let dir = tmp("eval-plain");
        write_dataset(&r.dataset, &dir).unwrap();
        let gt = Method::from_dirs("gt", std::slice::from_ref(&dir), &r, 15, PastRecording::Refuse).unwrap();
        assert_eq!(gt.kind, MethodKind::Dataset);
        assert_eq!(gt.scenes.iter().map(|s| (s.name(), s.observed, s.frames())).collect::<Vec<_>>(), [("S0", 15, 60), ("S1", 15, 70)]);
        let e = |dirs: &[PathBuf]| Method::from_dirs("x", dirs, &r, 15, PastRecording::Refuse).unwrap_err().to_string();
        assert!(e(&[dir.join("missing")]).contains("not found"));
        // Another scene's motion under a reference name: observed frames differ.
        let mut other = r.dataset.clone();
        other.sequences[0].scene.positions.mapv_inplace(|v| v + 0.5);
        let bad = tmp("eval-plain-bad");
        write_dataset(&other, &bad).unwrap();
        assert!(e(std::slice::from_ref(&bad)).contains("differ from the reference scene S0"));
        // Longer than the reference: an error, or cropped.
        let long = Method::baseline(Baseline::ZeroVelocity, &reference(80), 20, None, None).unwrap();
        let ldir = tmp("eval-long");
        write_dataset(&long.to_dataset().unwrap(), &ldir).unwrap();
        let msg = e(std::slice::from_ref(&ldir));
        assert!(msg.contains("longer than the reference scene S0"), "{msg}");
        let cropped = Method::from_dirs("zv", std::slice::from_ref(&ldir), &r, 15, PastRecording::Crop).unwrap();
        assert_eq!(cropped.scenes[0].frames(), 60);
        let whole = Method::from_dirs("zv", std::slice::from_ref(&ldir), &r, 15, PastRecording::Score).unwrap();
        assert_eq!((whole.scenes[0].frames(), whole.scenes[0].recorded_forecast_frames()), (80, 40));
        assert!(Method::baseline(Baseline::ZeroVelocity, &r, 20, Some(45), None).unwrap_err().to_string().contains("`horizon` 45"));
        for d in [dir, bad, ldir] {
            std::fs::remove_dir_all(d).unwrap();
        }
        assert_eq!(Baseline::parse_list("gt,zero-velocity,all").unwrap(), Baseline::ALL.to_vec());
        assert!(Baseline::parse_list("random").is_err());
    }
}
