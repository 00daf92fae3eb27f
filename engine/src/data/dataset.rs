//! Datasets: named scenes with a train/test split, stored as a dataset directory
//! (`dataset.json` + `.npy` files), socdiff's native format.

use super::scene::Scene;
use crate::{bail, Result};
use serde::{Deserialize, Serialize};

/// Which part of a dataset a sequence belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Split {
    /// Used to fit models.
    Train,
    /// Held out for evaluation.
    Test,
    /// Held out for model selection.
    #[cfg_attr(feature = "clap", value(alias = "val"))]
    Validation,
}

impl Split {
    /// Parses `train`, `test` or `validation`/`val`.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "train" => Ok(Split::Train),
            "test" => Ok(Split::Test),
            "validation" | "val" => Ok(Split::Validation),
            _ => bail!("unknown split {s:?} (expected train, test or validation)"),
        }
    }

    /// Lower-case name, as written in `dataset.json`.
    pub fn as_str(&self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Test => "test",
            Split::Validation => "validation",
        }
    }
}

/// One sequence of a dataset.
#[derive(Clone, Debug, PartialEq)]
pub struct Sequence {
    /// Which split it belongs to.
    pub split: Split,
    /// The motion.
    pub scene: Scene,
}

/// A collection of named scenes with a split.
#[derive(Clone, Debug, PartialEq)]
pub struct Dataset {
    /// Dataset name.
    pub name: String,
    /// Sequences in file order.
    pub sequences: Vec<Sequence>,
    /// Extra top-level fields of `dataset.json` (description, licence, ...), kept on rewrite.
    pub metadata: serde_json::Map<String, serde_json::Value>,
}

impl Dataset {
    /// Scenes of one split.
    pub fn split(&self, split: Split) -> impl Iterator<Item = &Scene> {
        self.sequences.iter().filter(move |s| s.split == split).map(|s| &s.scene)
    }

    /// The scene called `name`.
    pub fn scene(&self, name: &str) -> Result<&Scene> {
        match self.sequences.iter().find(|s| s.scene.name == name) {
            Some(s) => Ok(&s.scene),
            None => bail!(
                "dataset {} has no sequence {name:?} (sequences: {})",
                self.name,
                crate::files::list_some(&self.sequences.iter().map(|s| s.scene.name.as_str()).collect::<Vec<_>>(), 12)
            ),
        }
    }

    /// Total number of frames over all sequences.
    pub fn num_frames(&self) -> usize {
        self.sequences.iter().map(|s| s.scene.num_frames()).sum()
    }

    /// What `socdiff data inspect` prints: [`Dataset::summary`] as a table (one line per
    /// sequence too with `per_sequence`).
    pub fn report(&self, per_sequence: bool) -> String {
        use std::fmt::Write as _;
        let mut out = String::new();
        let sum = self.summary();
        let sk = &self.sequences[0].scene.skeleton;
        let ((pmin, pmax), invalid, person_frames) = (sum.persons, sum.invalid, sum.person_frames);
        let list = |v: Vec<String>| if v.is_empty() { "none".to_string() } else { v.join(", ") };
        let _ = writeln!(out, "dataset       {}\nsequences     {}", self.name, self.sequences.len());
        let _ = writeln!(out, "split         train {} / test {} / validation {}", sum.splits[0], sum.splits[1], sum.splits[2]);
        let _ = writeln!(out, "frames        {}\nduration      {:.1} s", sum.frames, sum.duration_s);
        let _ = writeln!(out, "fps           {}", list(sum.fps.iter().map(|f| format!("{f}")).collect()));
        let _ = writeln!(out, "persons       {}", if pmin == pmax { format!("{pmin}") } else { format!("{pmin}–{pmax}") });
        let _ = writeln!(out, "joints        {} ({}): {}", sk.num_joints(), sk.name, sk.joints.join(", "));
        let _ = writeln!(out, "body frame    {} / {}", sk.joints[sk.left], sk.joints[sk.right]);
        let _ = writeln!(out, "invalid       {invalid} of {person_frames} person-frames ({:.2} %)", 100.0 * invalid as f64 / person_frames.max(1) as f64);
        let _ = writeln!(out, "signals       {}", list(sum.signals.clone()));
        if !sum.roles.is_empty() {
            let _ = writeln!(out, "roles         {}", sum.roles.join(", "));
        }
        let _ = writeln!(out, "bones (mean ± std over valid frames, mm):");
        for (&(a, b), (mean, std)) in sk.bones.iter().zip(&sum.bones) {
            let _ = writeln!(out, "  {:>16} – {:<16} {:7.1} ± {:5.1}", sk.joints[a], sk.joints[b], mean * 1e3, std * 1e3);
        }
        if per_sequence {
            let _ = writeln!(
                out,
                "{:<28} {:<10} {:>7} {:>7} {:>6} {:>8} {:>8} {:>8}",
                "sequence", "split", "frames", "persons", "fps", "seconds", "invalid", "tilt°"
            );
            for s in &self.sequences {
                let sc = &s.scene;
                let tilt = sc.metadata.get("ground_alignment").and_then(|g| g.get("tilt_deg")).and_then(|t| t.as_f64());
                let tilt = tilt.map_or("-".to_string(), |t| format!("{t:.2}"));
                let (name, split, frames, persons) = (&sc.name, s.split.as_str(), sc.num_frames(), sc.num_persons());
                let _ = writeln!(out, "{name:<28} {split:<10} {frames:>7} {persons:>7} {:>6} {:>8.1} {:>8} {tilt:>8}", sc.fps, sc.duration(), sc.num_invalid());
            }
        }
        out
    }

    /// Counts, rates and bone lengths over every sequence (what `socdiff data inspect` shows).
    pub fn summary(&self) -> DatasetSummary {
        let scenes: Vec<&Scene> = self.sequences.iter().map(|s| &s.scene).collect();
        let mut fps: Vec<f64> = scenes.iter().map(|s| s.fps).collect();
        fps.sort_by(f64::total_cmp);
        fps.dedup();
        let mut signals: Vec<String> = scenes.iter().flat_map(|s| s.signals.keys().cloned()).collect();
        signals.sort();
        signals.dedup();
        // Bone lengths pooled over sequences, each weighted by its valid person-frames.
        let nb = scenes.first().map_or(0, |s| s.skeleton.bones.len());
        let mut acc = vec![(0.0f64, 0.0f64, 0.0f64); nb];
        for s in &scenes {
            let n = (s.num_frames() * s.num_persons() - s.num_invalid()) as f64;
            for (a, (m, sd)) in acc.iter_mut().zip(s.bone_length_stats()) {
                *a = (a.0 + n, a.1 + n * m, a.2 + n * (sd * sd + m * m));
            }
        }
        let bones = acc
            .into_iter()
            .map(|(n, s1, s2)| {
                let m = s1 / n.max(1.0);
                (m, (s2 / n.max(1.0) - m * m).max(0.0).sqrt())
            })
            .collect();
        let count = |split| self.sequences.iter().filter(|s| s.split == split).count();
        DatasetSummary {
            sequences: scenes.len(),
            splits: [count(Split::Train), count(Split::Test), count(Split::Validation)],
            frames: self.num_frames(),
            duration_s: scenes.iter().map(|s| s.duration()).sum(),
            fps,
            persons: (scenes.iter().map(|s| s.num_persons()).min().unwrap_or(0), scenes.iter().map(|s| s.num_persons()).max().unwrap_or(0)),
            invalid: scenes.iter().map(|s| s.num_invalid()).sum(),
            person_frames: scenes.iter().map(|s| s.num_frames() * s.num_persons()).sum(),
            signals,
            roles: scenes.first().map_or_else(Vec::new, |s| s.persons.iter().filter_map(|p| p.role.as_ref().map(|r| format!("{}={r}", p.id))).collect()),
            bones,
        }
    }
}

/// [`Dataset::summary`].
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetSummary {
    /// Sequences.
    pub sequences: usize,
    /// Sequences in the train, test and validation splits.
    pub splits: [usize; 3],
    /// Frames over all sequences.
    pub frames: usize,
    /// Seconds over all sequences.
    pub duration_s: f64,
    /// The distinct frame rates, ascending.
    pub fps: Vec<f64>,
    /// Fewest and most persons of a sequence.
    pub persons: (usize, usize),
    /// Invalid person-frames, of `person_frames`.
    pub invalid: usize,
    /// Person-frames over all sequences.
    pub person_frames: usize,
    /// Names of the per-frame signals of any sequence.
    pub signals: Vec<String>,
    /// `id=role` of the first sequence's persons that have a role.
    pub roles: Vec<String>,
    /// Mean and standard deviation of each bone's length (skeleton order) over the valid frames
    /// of every sequence, metres.
    pub bones: Vec<(f64, f64)>,
}

// ---------------------------------------------------------------------------------------------
// Dataset directories: `dataset.json` + `.npy` files.

use super::ground::{align_ground, UpAxis};
use super::npy::{read_npy, write_npy_f32, write_npy_u8};
use super::scene::Person;
use super::skeleton::Skeleton;
use crate::Error;
use ndarray::{Array2, Array4};
use serde_json::{Map, Value};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Options for [`read_dataset`].
#[derive(Clone, Debug, Default)]
pub struct ReadOptions {
    /// Fit and remove the floor plane per sequence. `None` (default): on for camera-frame data
    /// (`up_axis` `-y`; skipped, and recorded in the sequence's `ground_alignment`, when the
    /// skeleton has no foot joints), off otherwise. `Some(true)` aligns any data.
    pub align_ground: Option<bool>,
}

/// A joint given by index or by name in `dataset.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(untagged)]
enum JointRef {
    Index(usize),
    Name(String),
}

#[derive(Clone, Debug, Serialize, Deserialize)]
struct BodyFrameJson {
    left: JointRef,
    right: JointRef,
}

#[derive(Debug, Serialize, Deserialize)]
struct DatasetJson {
    name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    skeleton: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fps: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    units: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    up_axis: Option<String>,
    joints: Vec<String>,
    bones: Vec<(JointRef, JointRef)>,
    /// Absent or null: inferred from the joint names (hips, else shoulders).
    #[serde(default)]
    hip_joints: Option<BodyFrameJson>,
    sequences: Vec<SequenceJson>,
    #[serde(flatten)]
    extra: Map<String, Value>,
}

#[derive(Debug, Serialize, Deserialize)]
struct SequenceJson {
    name: String,
    split: String,
    file: String,
    frames: usize,
    persons: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fps: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    valid_file: Option<String>,
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    signals: BTreeMap<String, String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    person_info: Option<Vec<Person>>,
    #[serde(flatten)]
    extra: Map<String, Value>,
}

/// Top-level keys that describe the source layout; they are not carried into a rewritten dataset.
const SOURCE_LAYOUT_KEYS: [&str; 3] = ["array_layout", "coordinate_frame", "units_evidence"];

impl JointRef {
    fn resolve(&self, joints: &[String], path: &Path, what: &str) -> Result<usize> {
        match self {
            JointRef::Index(i) if *i < joints.len() => Ok(*i),
            JointRef::Index(i) => Err(Error::format(path, format!("{what}: joint index {i} out of range ({} joints)", joints.len()))),
            JointRef::Name(n) => joints.iter().position(|j| j == n).ok_or_else(|| Error::format(path, format!("{what}: unknown joint {n:?}"))),
        }
    }
}

fn units_scale(units: Option<&str>, path: &Path) -> Result<f32> {
    match units.unwrap_or("metres") {
        "metres" | "meters" | "m" => Ok(1.0),
        "centimetres" | "centimeters" | "cm" => Ok(0.01),
        "millimetres" | "millimeters" | "mm" => Ok(0.001),
        u => Err(Error::format(path, format!("unknown units {u:?} (expected metres, cm or mm)"))),
    }
}

/// Largest `dataset.json` read.
pub const MAX_DATASET_JSON_BYTES: u64 = 64 << 20;
/// Most sequences a dataset may name.
pub const MAX_SEQUENCES: usize = 20_000;

/// The keys `dataset.json` knows at its top level and in a sequence; other keys are free
/// metadata, unless they are one or two letters from a known key (a misspelling).
const DATASET_KEYS: [&str; 9] = ["name", "skeleton", "fps", "units", "up_axis", "joints", "bones", "hip_joints", "sequences"];
const SEQUENCE_KEYS: [&str; 10] = ["name", "split", "file", "frames", "persons", "fps", "valid_file", "signals", "person_info", "ground_alignment"];

/// An error naming the first of `keys` that is a misspelling of one of `known` (within two
/// edits, and not itself known).
fn misspelled_key<'a>(keys: impl Iterator<Item = &'a String>, known: &[&str]) -> Result<()> {
    for key in keys {
        // One edit in a key of 5 letters or more, two in one of 8 or more: short keys of free
        // metadata ("take", "style") are too near the known ones by chance.
        let near = |k: &str| match edit_distance(key, k) {
            1 => key.len() >= 5,
            2 => key.len() >= 8,
            _ => false,
        };
        if let Some(k) = known.iter().find(|k| key.as_str() != **k && near(k)) {
            bail!("unknown key {key:?}: did you mean {k:?}?");
        }
    }
    Ok(())
}

/// Levenshtein distance between two short strings.
fn edit_distance(a: &str, b: &str) -> usize {
    let (a, b): (Vec<char>, Vec<char>) = (a.chars().collect(), b.chars().collect());
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.iter().enumerate() {
        let mut prev = row[0];
        row[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let cur = row[j + 1];
            row[j + 1] = (prev + usize::from(ca != cb)).min(row[j] + 1).min(cur + 1);
            prev = cur;
        }
    }
    row[b.len()]
}

/// Reads a dataset directory: `dir/dataset.json` and the `.npy` files it names.
///
/// Positions are converted to metres and z up; camera-frame data is ground-aligned per
/// sequence unless `opts` says otherwise (see [`ReadOptions`]). The `sha1` fields of source
/// datasets are not verified and not kept.
pub fn read_dataset(dir: &Path, opts: &ReadOptions) -> Result<Dataset> {
    let json_path = dir.join("dataset.json");
    let bytes = crate::files::read_bounded(&json_path, MAX_DATASET_JSON_BYTES, "dataset.json")?;
    let mut meta: DatasetJson = serde_json::from_slice(&bytes).map_err(|e| Error::format(&json_path, format!("not a socdiff dataset.json: {e}")))?;
    misspelled_key(meta.extra.keys(), &DATASET_KEYS).map_err(|e| e.in_file(&json_path))?;
    if meta.sequences.len() > MAX_SEQUENCES {
        return Err(Error::format(&json_path, format!("{} sequences: more than the {MAX_SEQUENCES} a dataset may have", meta.sequences.len())));
    }
    let mut total = 0f64;
    let mut files = std::collections::BTreeSet::new();
    for (i, s) in meta.sequences.iter().enumerate() {
        if !files.insert(s.file.as_str()) {
            return Err(Error::format(
                &json_path,
                format!("sequences[{i}] ({:?}) names the file {:?} of an earlier sequence; each sequence has its own", s.name, s.file),
            ));
        }
        crate::files::check_name(&format!("sequences[{i}]: name"), &s.name).map_err(|e| e.in_file(&json_path))?;
        misspelled_key(s.extra.keys(), &SEQUENCE_KEYS).map_err(|e| Error::format(&json_path, format!("sequence {:?}: {e}", s.name)))?;
        crate::data::check_size(&format!("sequence {:?}", s.name), s.frames as f64, s.persons, 1).map_err(|e| e.in_file(&json_path))?;
        total += s.frames as f64 * s.persons as f64;
    }
    if total > crate::data::MAX_DATASET_PERSON_FRAMES {
        return Err(Error::format(
            &json_path,
            format!("{total:.3e} person-frames in all: more than the {:.0e} a dataset may hold", crate::data::MAX_DATASET_PERSON_FRAMES),
        ));
    }
    let joints = std::mem::take(&mut meta.joints);
    let bones = meta
        .bones
        .iter()
        .enumerate()
        .map(|(i, (a, b))| {
            let what = format!("bones[{i}]");
            Ok((a.resolve(&joints, &json_path, &what)?, b.resolve(&joints, &json_path, &what)?))
        })
        .collect::<Result<Vec<_>>>()?;
    let (left, right) = match &meta.hip_joints {
        Some(h) => (h.left.resolve(&joints, &json_path, "hip_joints.left")?, h.right.resolve(&joints, &json_path, "hip_joints.right")?),
        None => super::joints::body_frame_from_names(&joints).ok_or_else(|| {
            Error::format(
                &json_path,
                format!(
                    "\"hip_joints\" is not given and no left/right hip or shoulder joints were found by name among {}; set \"hip_joints\": {{\"left\": NAME, \"right\": NAME}} (the two joints that give a person's facing direction)",
                    crate::files::list_some(&joints, 12)
                ),
            )
        })?,
    };
    let skeleton_name = meta.skeleton.clone().unwrap_or_else(|| meta.name.clone());
    let skeleton = Skeleton::new(skeleton_name, joints, bones, left, right).map_err(|e| e.in_file(&json_path))?;
    let up = UpAxis::parse(meta.up_axis.as_deref().unwrap_or("z")).map_err(|e| e.in_file(&json_path))?;
    let scale = units_scale(meta.units.as_deref(), &json_path)?;
    // Automatic: only camera-frame data (y down) needs its floor found.
    let align = opts.align_ground.unwrap_or(up == UpAxis::NegY);
    let has_feet = !skeleton.foot_joints().is_empty();
    if meta.sequences.is_empty() {
        return Err(Error::format(&json_path, "no sequences"));
    }
    let mut names = std::collections::BTreeSet::new();
    if let Some(dup) = meta.sequences.iter().find(|s| !names.insert(s.name.as_str())) {
        return Err(Error::format(&json_path, format!("two sequences are named {:?}; sequence names must be unique", dup.name)));
    }
    let canonical_dir = dir.canonicalize().map_err(|e| Error::io(dir, e))?;
    let mut sequences = Vec::with_capacity(meta.sequences.len());
    for (i, seq) in meta.sequences.iter_mut().enumerate() {
        let split = Split::parse(&seq.split).map_err(|e| Error::format(&json_path, format!("sequences[{i}] ({}): {e}", seq.name)))?;
        let fps = seq.fps.or(meta.fps).ok_or_else(|| Error::format(&json_path, format!("sequence {}: no fps given", seq.name)))?;
        crate::data::scene::check_fps(fps).map_err(|e| Error::format(&json_path, format!("sequence {}: {e}", seq.name)))?;
        let mut scene = read_sequence(dir, &canonical_dir, seq, fps, scale, &skeleton)?;
        if up != UpAxis::Z {
            scene.transform(up.to_z_up(), [0.0; 3]);
        }
        seq.extra.remove("sha1");
        scene.metadata = std::mem::take(&mut seq.extra);
        if align && !has_feet && opts.align_ground.is_none() {
            scene.metadata.insert("ground_alignment".into(), "skipped: the skeleton has no foot joints (ankle/foot/toe) to fit the floor to".into());
        } else if align {
            align_ground(&mut scene).map_err(|e| e.in_file(&json_path))?;
        }
        sequences.push(Sequence { split, scene });
    }
    let mut metadata = meta.extra;
    for k in SOURCE_LAYOUT_KEYS {
        metadata.remove(k);
    }
    Ok(Dataset { name: meta.name, sequences, metadata })
}

/// `dir/name` for a file named in `dataset.json`, which must stay inside the dataset directory:
/// a relative path without `..`, not leading out through a symlink.
fn dataset_file(dir: &Path, canonical_dir: &Path, name: &str, what: &str) -> Result<PathBuf> {
    let json_path = dir.join("dataset.json");
    let rel = Path::new(name);
    let escapes = rel.is_absolute() || rel.components().any(|c| !matches!(c, std::path::Component::Normal(_) | std::path::Component::CurDir));
    if escapes || name.is_empty() {
        return Err(Error::format(&json_path, format!("{what} {name:?} is not a relative path inside the dataset directory")));
    }
    let path = dir.join(rel);
    if let Ok(real) = path.canonicalize() {
        if !real.starts_with(canonical_dir) {
            return Err(Error::format(&json_path, format!("{what} {name:?} leads outside the dataset directory (to {})", real.display())));
        }
    }
    Ok(path)
}

fn read_sequence(dir: &Path, canonical_dir: &Path, seq: &SequenceJson, fps: f64, scale: f32, skeleton: &Skeleton) -> Result<Scene> {
    let (frames, persons, joints) = (seq.frames, seq.persons, skeleton.num_joints());
    let what = format!("sequence {}: file", seq.name);
    let path = dataset_file(dir, canonical_dir, &seq.file, &what)?;
    let arr = read_npy(&path)?;
    arr.expect_shape(&path, "positions", &[Some(frames), Some(persons), Some(joints), Some(3)])?;
    let mut positions = Array4::from_shape_vec((frames, persons, joints, 3), arr.into_f32(&path)?).expect("shape checked");
    if scale != 1.0 {
        positions.mapv_inplace(|v| v * scale);
    }
    let mut scene = Scene::new(seq.name.clone(), fps, skeleton.clone(), positions).map_err(|e| e.in_file(&path))?;
    if let Some(valid_file) = &seq.valid_file {
        let path = dataset_file(dir, canonical_dir, valid_file, &format!("sequence {}: valid_file", seq.name))?;
        let arr = read_npy(&path)?;
        arr.expect_shape(&path, "validity mask", &[Some(frames), Some(persons)])?;
        let valid = Array2::from_shape_vec((frames, persons), arr.into_u8(&path)?).expect("shape checked").mapv(|v| v != 0);
        scene = scene.with_valid(valid)?;
    }
    for (name, file) in &seq.signals {
        let path = dataset_file(dir, canonical_dir, file, &format!("sequence {}: signal {name:?}", seq.name))?;
        let arr = read_npy(&path)?;
        arr.expect_shape(&path, &format!("signal {name:?}"), &[Some(frames), Some(persons)])?;
        let values = Array2::from_shape_vec((frames, persons), arr.into_f32(&path)?).expect("shape checked");
        if values.iter().any(|v| !v.is_finite()) {
            return Err(Error::format(&path, format!("signal {name:?} has non-finite values")));
        }
        scene = scene.with_signal(name.clone(), values)?;
    }
    if let Some(info) = &seq.person_info {
        scene = scene.with_persons(info.clone()).map_err(|e| e.in_file(dir.join("dataset.json")))?;
    }
    Ok(scene)
}

/// Writes `dataset` as a dataset directory at `dir` (socdiff's native format: metres, z up).
///
/// The directory is written under a temporary name and renamed into place, so a failure leaves
/// nothing behind. An existing non-empty `dir` is an error: nothing is overwritten.
pub fn write_dataset(dataset: &Dataset, dir: &Path) -> Result<()> {
    write_dataset_with(dataset, dir, |_| Ok(()))
}

/// [`write_dataset`], with `extra` writing more files into the directory before it is renamed
/// into place (a failure of either leaves nothing behind).
pub fn write_dataset_with(dataset: &Dataset, dir: &Path, extra: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let Some(first) = dataset.sequences.first() else {
        bail!("dataset {}: no sequences to write", dataset.name);
    };
    let skeleton = &first.scene.skeleton;
    for s in &dataset.sequences {
        if s.scene.skeleton != *skeleton {
            bail!(
                "dataset {}: sequence {} has skeleton {}, sequence {} has {} (one dataset directory holds one skeleton)",
                dataset.name,
                s.scene.name,
                s.scene.skeleton.name,
                first.scene.name,
                skeleton.name
            );
        }
    }
    crate::files::write_dir_atomic(dir, |tmp| write_into(dataset, skeleton, tmp).and_then(|()| extra(tmp)))
}

fn write_into(dataset: &Dataset, skeleton: &Skeleton, dir: &Path) -> Result<()> {
    let fps = dataset.sequences[0].scene.fps;
    let mut sequences = Vec::with_capacity(dataset.sequences.len());
    for seq in &dataset.sequences {
        let s = &seq.scene;
        crate::files::check_name("sequence", &s.name)?;
        let split = seq.split.as_str();
        let sub = dir.join(split);
        std::fs::create_dir_all(&sub).map_err(|e| Error::io(&sub, e))?;
        let file = format!("{split}/{}.npy", s.name);
        let (f, p, j, _) = s.positions.dim();
        let positions: Vec<f32> = s.positions.iter().copied().collect();
        write_npy_f32(&dir.join(&file), &[f, p, j, 3], &positions)?;
        let valid_file = match &s.valid {
            Some(v) => {
                let name = format!("{split}/{}_valid.npy", s.name);
                write_npy_u8(&dir.join(&name), &[f, p], &v.iter().map(|&b| b as u8).collect::<Vec<_>>())?;
                Some(name)
            }
            None => None,
        };
        let mut signals = BTreeMap::new();
        for (k, v) in &s.signals {
            let name = format!("{split}/{}_{k}.npy", s.name);
            write_npy_f32(&dir.join(&name), &[f, p], &v.iter().copied().collect::<Vec<_>>())?;
            signals.insert(k.clone(), name);
        }
        sequences.push(SequenceJson {
            name: s.name.clone(),
            split: split.into(),
            file,
            frames: f,
            persons: p,
            fps: (s.fps != fps).then_some(s.fps),
            valid_file,
            signals,
            person_info: Some(s.persons.clone()),
            extra: s.metadata.clone(),
        });
    }
    let json = DatasetJson {
        name: dataset.name.clone(),
        skeleton: Some(skeleton.name.clone()),
        fps: Some(fps),
        units: Some("metres".into()),
        up_axis: Some("z".into()),
        joints: skeleton.joints.clone(),
        bones: skeleton.bones.iter().map(|&(a, b)| (JointRef::Index(a), JointRef::Index(b))).collect(),
        hip_joints: Some(BodyFrameJson { left: JointRef::Index(skeleton.left), right: JointRef::Index(skeleton.right) }),
        sequences,
        extra: dataset.metadata.clone(),
    };
    let path = dir.join("dataset.json");
    let text = serde_json::to_string_pretty(&json).map_err(|e| Error::format(&path, e.to_string()))?;
    std::fs::write(&path, text).map_err(|e| Error::io(&path, e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::synthetic::walkers;

    #[test]
    fn summary_pools_sequences() {
        // Two scenes in which one bone has known constant lengths: 0.2 m on 3·10 person-frames
        // and 0.5 m on 1·30; pooled mean (6 + 15) / 60 = 0.35, std 0.15.
        let mut a = walkers(10, 3, 0.0);
        let mut b = walkers(30, 1, 1.0);
        let (j0, j1) = a.skeleton.bones[0];
        for (s, len) in [(&mut a, 0.2f32), (&mut b, 0.5)] {
            for f in 0..s.num_frames() {
                for p in 0..s.num_persons() {
                    for k in 0..3 {
                        s.positions[[f, p, j1, k]] = s.positions[[f, p, j0, k]] + if k == 2 { len } else { 0.0 };
                    }
                }
            }
        }
        let ds = Dataset {
            name: "d".into(),
            sequences: vec![Sequence { split: Split::Train, scene: a }, Sequence { split: Split::Test, scene: b }],
            metadata: Default::default(),
        };
        let sum = ds.summary();
        assert_eq!((sum.sequences, sum.splits, sum.frames, sum.persons, sum.person_frames), (2, [1, 1, 0], 40, (1, 3), 60));
        assert_eq!((sum.fps.clone(), sum.invalid), (vec![30.0], 0));
        let (mean, std) = sum.bones[0];
        assert!((mean - 0.35).abs() < 1e-6 && (std - 0.15).abs() < 1e-5, "{mean} {std}");
    }
}
