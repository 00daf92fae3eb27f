//! One entry point for every source format: a path in, a [`Dataset`] out.
//!
//! | path | read as |
//! |---|---|
//! | a directory with `dataset.json` | dataset directory ([`super::dataset`]) |
//! | `*.bvh` | one person per file ([`super::bvh`]) |
//! | a directory of `*.bvh` (no `dataset.json`) | one train sequence per file, in name order |
//! | `*.pkl` holding `subjects` | a Haggling body file, with its speech file if found ([`super::haggling`]) |
//! | `*.pkl` holding `speechData` | an error: speech annotations hold no poses |

use super::bvh::{import_bvh, BvhImport};
use super::dataset::{read_dataset, Dataset, ReadOptions, Sequence, Split};
use super::haggling;
use super::scene::Scene;
use crate::{Error, Result};
use std::path::{Path, PathBuf};

/// How to read sources.
#[derive(Clone, Debug, Default)]
pub struct ImportOptions {
    /// Dataset directories: ground alignment (`None` = automatic, see [`ReadOptions`]).
    pub align_ground: Option<bool>,
    /// BVH files: units and axes.
    pub bvh: BvhImport,
    /// Haggling body files: the folder holding the speech files of the same names. When `None`,
    /// a sibling folder whose name contains `speech` is searched.
    pub speech_dir: Option<PathBuf>,
    /// Split assigned to scenes from single files.
    pub split: Option<Split>,
    /// How motion arrays (`.npy`, `.npz`) are read; `None` refuses them, saying what they need.
    pub arrays: Option<super::arrays::ArrayImport>,
}

/// Ground alignment of dataset directories ([`ImportOptions::align_ground`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum AlignGround {
    /// Camera-frame data (up axis -y) only; skipped, saying so, without foot joints.
    #[default]
    Auto,
    /// Fit and remove the floor of any dataset.
    On,
    /// Never.
    Off,
}

impl AlignGround {
    /// As [`ImportOptions::align_ground`].
    pub fn option(self) -> Option<bool> {
        match self {
            AlignGround::Auto => None,
            AlignGround::On => Some(true),
            AlignGround::Off => Some(false),
        }
    }
}

/// Metres per BVH file unit: `auto` (guessed from the body height), `cmu` (0.056444) or a
/// positive number.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum BvhScale {
    /// [`super::bvh::Bvh::guess_scale`].
    #[default]
    Auto,
    /// Metres per unit.
    Metres(f64),
}

impl std::str::FromStr for BvhScale {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self> {
        match s {
            "auto" => Ok(Self::Auto),
            "cmu" => Ok(Self::Metres(super::bvh::CMU_SCALE)),
            _ => match s.parse::<f64>() {
                Ok(v) if v.is_finite() && v > 0.0 => Ok(Self::Metres(v)),
                _ => Err(Error::invalid(format!("{s:?} is not a positive number, cmu or auto"))),
            },
        }
    }
}

/// `--align-ground` alone, for commands that read datasets but no other formats.
#[derive(Clone, Debug, Default)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct AlignArgs {
    /// Ground alignment of datasets: auto (camera-frame data only), on or off.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = AlignGround::Auto))]
    pub align_ground: AlignGround,
}

impl AlignArgs {
    /// Import options with this alignment.
    pub fn options(&self) -> ImportOptions {
        ImportOptions { align_ground: self.align_ground.option(), ..Default::default() }
    }
}

/// What a motion array does not say, as command-line options (`data convert`).
#[derive(Clone, Debug, Default)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct ArrayArgs {
    /// Motion arrays (.npy, .npz): the skeleton their joints follow, by name (mupots17, mrt15,
    /// h36m17, smpl22, smpl24, panoptic19, bandai21, cmu31).
    #[cfg_attr(feature = "clap", arg(long, value_name = "NAME"))]
    pub skeleton: Option<String>,
    /// Motion arrays: frames per second.
    #[cfg_attr(feature = "clap", arg(long))]
    pub fps: Option<f64>,
    /// Motion arrays: units of the positions (m, cm, mm, or mrt for MRT's preprocessed MuPoTS).
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub units: Option<super::arrays::Units>,
    /// Motion arrays: the axis that points up (z, y or -y).
    #[cfg_attr(feature = "clap", arg(long, allow_hyphen_values = true))]
    pub up: Option<String>,
}

impl ArrayArgs {
    /// How to read motion arrays: `None` when no option is given, else all four are needed
    /// (an error names the first missing).
    pub fn import(&self) -> Result<Option<super::arrays::ArrayImport>> {
        if self.skeleton.is_none() && self.fps.is_none() && self.units.is_none() && self.up.is_none() {
            return Ok(None);
        }
        let need = |what: &str| Error::invalid(format!("motion arrays need `skeleton`, `fps`, `units` and `up`: `{what}` is missing"));
        let skeleton = super::skeleton::Skeleton::named(self.skeleton.as_deref().ok_or_else(|| need("skeleton"))?)?;
        let fps = self.fps.ok_or_else(|| need("fps"))?;
        super::scene::check_fps(fps)?;
        let units = self.units.ok_or_else(|| need("units"))?;
        let up = super::ground::UpAxis::parse(self.up.as_deref().ok_or_else(|| need("up"))?)?;
        Ok(Some(super::arrays::ArrayImport { skeleton, fps, units, up }))
    }
}

/// How to read sources of any format, as command-line options.
#[derive(Clone, Debug)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct SourceArgs {
    #[cfg_attr(feature = "clap", command(flatten))]
    pub align: AlignArgs,
    /// BVH: metres per file unit ("cmu" = 0.056444, "auto" guesses from the body height).
    #[cfg_attr(feature = "clap", arg(long, default_value = "auto"))]
    pub bvh_scale: BvhScale,
    /// BVH: up axis of the file (y or z).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "y", hide_possible_values = true))]
    pub bvh_up: super::bvh::UpAxis,
    /// Haggling: folder of the speech files matching the body files.
    #[cfg_attr(feature = "clap", arg(long))]
    pub speech_dir: Option<PathBuf>,
}

impl Default for SourceArgs {
    /// The options' defaults: automatic ground alignment and BVH scale, BVH y up, the speech
    /// folder found by name.
    fn default() -> Self {
        Self { align: AlignArgs { align_ground: AlignGround::Auto }, bvh_scale: BvhScale::Auto, bvh_up: super::bvh::UpAxis::Y, speech_dir: None }
    }
}

impl SourceArgs {
    /// Every path a command reads for `input` (the input and the speech folder), which its
    /// outputs must never replace.
    pub fn inputs<'a>(&'a self, input: &'a Path) -> Vec<&'a Path> {
        std::iter::once(input).chain(self.speech_dir.as_deref()).collect()
    }

    /// The import options.
    pub fn options(&self) -> ImportOptions {
        let (scale, auto_scale) = match self.bvh_scale {
            BvhScale::Auto => (1.0, true),
            BvhScale::Metres(m) => (m, false),
        };
        let bvh = BvhImport { scale, auto_scale, up_axis: self.bvh_up, ..Default::default() };
        ImportOptions { bvh, speech_dir: self.speech_dir.clone(), ..self.align.options() }
    }
}

/// What kind of source a path is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SourceKind {
    /// A directory with `dataset.json`.
    DatasetDir,
    /// A BVH motion-capture file.
    Bvh,
    /// A directory of BVH files without `dataset.json` (e.g. a CMU download).
    BvhDir,
    /// A Python pickle (Haggling body or speech file).
    Pickle,
    /// A motion array: `.npy` or `.npz` ([`super::arrays`]).
    Array,
    /// A directory of motion arrays.
    ArrayDir,
    /// A directory of CMU Panoptic `body3DScene_*.json` frames ([`super::panoptic`]).
    PanopticDir,
}

/// Detects the kind of source at `path`, or an error naming it.
pub fn source_kind(path: &Path) -> Result<SourceKind> {
    if path.is_dir() {
        if path.join("dataset.json").is_file() {
            return Ok(SourceKind::DatasetDir);
        }
        if !bvh_files(path)?.is_empty() {
            return Ok(SourceKind::BvhDir);
        }
        if !super::panoptic::frame_files(path)?.is_empty() {
            return Ok(SourceKind::PanopticDir);
        }
        if !super::arrays::array_files(path)?.is_empty() {
            return Ok(SourceKind::ArrayDir);
        }
        return Err(Error::format(path, "directory has no dataset.json, .bvh, .npy, .npz or body3DScene_*.json files"));
    }
    if !path.exists() {
        return Err(Error::io(path, std::io::Error::new(std::io::ErrorKind::NotFound, "no such file or directory")));
    }
    match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("bvh") => Ok(SourceKind::Bvh),
        Some("pkl" | "pickle") => Ok(SourceKind::Pickle),
        Some("npy" | "npz") => Ok(SourceKind::Array),
        Some("json") if path.file_name().is_some_and(|n| n == "dataset.json") => Ok(SourceKind::DatasetDir),
        _ => Err(Error::format(path, "unknown input format (expected a dataset directory, .bvh, .pkl, .npy or .npz)")),
    }
}

/// One sequence of a source: the one named `name`, or the only one. Errors name the file and,
/// for a source of several sequences without a name, list them.
pub fn load_sequence(path: &Path, name: Option<&str>, opts: &ImportOptions) -> Result<Scene> {
    let mut ds = load(path, opts)?;
    match name {
        Some(name) => Ok(ds.scene(name).map_err(|e| e.in_file(path))?.clone()),
        None if ds.sequences.len() == 1 => Ok(ds.sequences.remove(0).scene),
        None => {
            let names: Vec<&str> = ds.sequences.iter().map(|s| s.scene.name.as_str()).collect();
            Err(Error::format(path, format!("holds {} sequences; name one (`sequence`): {}", names.len(), crate::files::list_some(&names, 12))))
        }
    }
}

/// The scenes of `split` of every dataset directory in `paths`, and the scene of every single
/// file; a source that gives none is an error naming it.
pub fn load_split(paths: &[PathBuf], split: Split, opts: &ImportOptions) -> Result<Vec<Scene>> {
    let mut out = Vec::new();
    for path in paths {
        let from_dir = source_kind(path)? == SourceKind::DatasetDir;
        let before = out.len();
        out.extend(load(path, opts)?.sequences.into_iter().filter(|s| !from_dir || s.split == split).map(|s| s.scene));
        if out.len() == before {
            return Err(Error::format(path, format!("no {} sequences", split.as_str())));
        }
    }
    Ok(out)
}

/// How [`convert`] builds one dataset from several sources.
#[derive(Clone, Debug, Default)]
pub struct ConvertOptions {
    /// Name of the dataset (default: that of a single dataset directory, else `fallback_name`).
    pub name: Option<String>,
    /// The name when nothing else names it (e.g. the output folder's).
    pub fallback_name: String,
    /// Resample every sequence to this frame rate.
    pub fps: Option<f64>,
    /// The inputs are the persons of one scene ([`load_group`]), `spacing` metres apart.
    pub persons_from_files: bool,
    /// Spacing of [`ConvertOptions::persons_from_files`].
    pub spacing: f32,
    /// Sequences (by name) that go to the test split.
    pub test: Vec<String>,
    /// Every Nth sequence (1-based: the Nth, 2Nth, …) goes to the test split.
    pub test_every: Option<usize>,
    /// Map every sequence onto this skeleton by joint names ([`JointMap::by_names`]); joints
    /// no input has are derived from the inputs already on it, else an error naming them.
    pub map_to: Option<super::skeleton::Skeleton>,
}

/// One dataset from `inputs` (see [`ConvertOptions`]); sequence names must be unique.
pub fn convert(inputs: &[PathBuf], opts: &ImportOptions, how: &ConvertOptions) -> Result<Dataset> {
    let mut dataset = Dataset { name: how.fallback_name.clone(), sequences: Vec::new(), metadata: Default::default() };
    if how.persons_from_files {
        let scene = load_group(inputs, opts, how.spacing)?;
        dataset.sequences.push(Sequence { split: opts.split.unwrap_or(Split::Train), scene });
    } else {
        for input in inputs {
            let ds = load(input, opts)?;
            if inputs.len() == 1 && source_kind(input)? == SourceKind::DatasetDir {
                dataset.name = ds.name;
                dataset.metadata = ds.metadata;
            }
            dataset.sequences.extend(ds.sequences);
        }
    }
    if let Some(name) = &how.name {
        dataset.name = name.clone();
    }
    if let Some(fps) = how.fps {
        for s in &mut dataset.sequences {
            s.scene = s.scene.resample(fps)?;
        }
    }
    if let Some(target) = &how.map_to {
        map_sequences(&mut dataset, target)?;
    }
    let mut names: Vec<&str> = dataset.sequences.iter().map(|s| s.scene.name.as_str()).collect();
    names.sort();
    if let Some(w) = names.windows(2).find(|w| w[0] == w[1]) {
        return Err(Error::invalid(format!("two input sequences are both named {:?}; convert them separately", w[0])));
    }
    if let Some(missing) = how.test.iter().find(|t| !names.contains(&t.as_str())) {
        return Err(Error::invalid(format!("`test` names {missing:?}, which is no input sequence")));
    }
    match how.test_every {
        Some(0) => return Err(Error::invalid("`test_every` must be at least 1")),
        Some(n) => dataset.sequences.iter_mut().skip(n - 1).step_by(n).for_each(|s| s.split = Split::Test),
        None => {}
    }
    for s in &mut dataset.sequences {
        if how.test.contains(&s.scene.name) {
            s.split = Split::Test;
        }
    }
    Ok(dataset)
}

/// Maps every sequence of `dataset` onto `target` by joint names; the sequences already on it
/// are the fitting scenes of derived joints.
fn map_sequences(dataset: &mut Dataset, target: &super::skeleton::Skeleton) -> Result<()> {
    use super::joint_map::JointMap;
    let fit: Vec<Scene> = dataset.sequences.iter().filter(|s| s.scene.skeleton.joints == target.joints).map(|s| s.scene.clone()).collect();
    let fit: Vec<&Scene> = fit.iter().collect();
    for s in &mut dataset.sequences {
        if s.scene.skeleton.joints != target.joints {
            let map = JointMap::by_names(&s.scene.skeleton, target, &fit).map_err(|e| Error::invalid(format!("sequence {}: {e}", s.scene.name)))?;
            s.scene = map.apply(&s.scene)?;
        }
        s.scene.skeleton = target.clone();
    }
    Ok(())
}

/// Reads any supported source as a dataset. Single files become one-sequence datasets whose
/// split is `opts.split` (default train).
pub fn load(path: &Path, opts: &ImportOptions) -> Result<Dataset> {
    let kind = source_kind(path)?;
    if kind == SourceKind::DatasetDir {
        let dir = if path.is_dir() { path } else { path.parent().unwrap_or(Path::new(".")) };
        return read_dataset(dir, &ReadOptions { align_ground: opts.align_ground });
    }
    if kind == SourceKind::BvhDir {
        let split = opts.split.unwrap_or(Split::Train);
        let name = path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
        let mut sequences = Vec::new();
        for file in bvh_files(path)? {
            let mut scene = import_bvh(&file, &opts.bvh)?;
            // One skeleton per dataset: the files share the folder's name for their layout.
            scene.skeleton.name.clone_from(&name);
            if let Some(first) = sequences.first().map(|s: &Sequence| &s.scene.skeleton) {
                if *first != scene.skeleton {
                    return Err(Error::format(&file, format!("its joints differ from {}'s: a BVH folder needs one joint layout", sequences[0].scene.name)));
                }
            }
            sequences.push(Sequence { split, scene });
        }
        return Ok(Dataset { name, sequences, metadata: Default::default() });
    }
    let split = opts.split.unwrap_or(Split::Train);
    let folder_name = || path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
    match kind {
        SourceKind::Array | SourceKind::ArrayDir => {
            let how = opts
                .arrays
                .as_ref()
                .ok_or_else(|| Error::format(path, "a motion array holds no skeleton, frame rate or units: give them (`skeleton`, `fps`, `units`, `up`)"))?;
            let files = if kind == SourceKind::Array { vec![path.to_path_buf()] } else { super::arrays::array_files(path)? };
            let mut sequences = Vec::new();
            for file in files {
                sequences.extend(super::arrays::read_array_file(&file, how)?.into_iter().map(|scene| Sequence { split, scene }));
            }
            let name = if kind == SourceKind::Array { sequences[0].scene.name.clone() } else { folder_name() };
            return Ok(Dataset { name, sequences, metadata: Default::default() });
        }
        SourceKind::PanopticDir => {
            let scene = super::panoptic::read_panoptic_dir(path)?;
            return Ok(Dataset { name: folder_name(), sequences: vec![Sequence { split, scene }], metadata: Default::default() });
        }
        _ => {}
    }
    let scene = load_scene_file(path, kind, opts)?;
    let name = scene.name.clone();
    Ok(Dataset { name, sequences: vec![Sequence { split: opts.split.unwrap_or(Split::Train), scene }], metadata: Default::default() })
}

/// The one scene of a BVH or pickle file, or of a dataset directory holding one sequence
/// (default import options). More sequences: an error listing them ([`load_sequence`]).
pub fn load_scene(path: impl AsRef<Path>) -> Result<Scene> {
    load_sequence(path.as_ref(), None, &ImportOptions::default())
}

fn load_scene_file(path: &Path, kind: SourceKind, opts: &ImportOptions) -> Result<Scene> {
    match kind {
        SourceKind::Bvh => import_bvh(path, &opts.bvh),
        SourceKind::Pickle => {
            let speech = find_speech_file(path, opts.speech_dir.as_deref());
            haggling::scene_from_files(path, speech.as_deref())
        }
        SourceKind::DatasetDir | SourceKind::BvhDir | SourceKind::Array | SourceKind::ArrayDir | SourceKind::PanopticDir => unreachable!("handled by load"),
    }
}

/// The `.bvh` files directly in `dir`, sorted by name.
fn bvh_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.extension().is_some_and(|e| e.eq_ignore_ascii_case("bvh")))
        .collect();
    files.sort();
    Ok(files)
}

/// The speech file for a Haggling body file: same file name in `speech_dir`, or in a sibling
/// folder whose name contains `speech`.
pub fn find_speech_file(body: &Path, speech_dir: Option<&Path>) -> Option<PathBuf> {
    let name = body.file_name()?;
    if let Some(dir) = speech_dir {
        let p = dir.join(name);
        return p.is_file().then_some(p);
    }
    let parent = body.parent()?.parent()?;
    std::fs::read_dir(parent)
        .ok()?
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| p.is_dir() && p.file_name().is_some_and(|n| n.to_string_lossy().contains("speech")))
        .map(|d| d.join(name))
        .find(|p| p.is_file() && p != body)
}

/// Reads several files of any format as the persons of one scene, placed on a circle with
/// neighbours `spacing` metres apart ([`Scene::around_circle`]).
pub fn load_group(paths: &[PathBuf], opts: &ImportOptions, spacing: f32) -> Result<Scene> {
    let mut scenes = Vec::with_capacity(paths.len());
    for p in paths {
        let ds = load(p, opts)?;
        if ds.sequences.len() != 1 {
            return Err(Error::format(
                p,
                format!(
                    "holds {} sequences, and each input is one person of the group; compose groups of recorded scenes with `socdiff data compose`",
                    ds.sequences.len()
                ),
            ));
        }
        scenes.extend(ds.sequences.into_iter().map(|s| s.scene));
    }
    if scenes.is_empty() {
        return Err(Error::invalid("no input files"));
    }
    let name = scenes.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join("+");
    let group = Scene::around_circle(name, &scenes, spacing)?;
    // Each input is one person: bodies of different inputs must stay apart on every frame.
    let owner: Vec<usize> = scenes.iter().enumerate().flat_map(|(i, s)| std::iter::repeat_n(i, s.num_persons())).collect();
    if let Some((d, f, a, b)) = super::compose::closest_approach(&group, &owner) {
        if d < super::compose::Composition::default().min_distance as f64 {
            return Err(Error::invalid(format!(
                "{} and {} come within {d:.2} m of each other at frame {f} at a spacing of {spacing} m: give a larger `spacing`",
                scenes[owner[a]].name, scenes[owner[b]].name
            )));
        }
    }
    Ok(group)
}
