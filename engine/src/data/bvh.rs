//! BVH (Biovision Hierarchy) motion capture: parser, forward kinematics and import to [`Scene`].
//!
//! # Format
//! A BVH file has two sections. `HIERARCHY` declares a tree of joints: `ROOT name { ... }`,
//! nested `JOINT name { ... }` and leaf `End Site { OFFSET x y z }` blocks; every joint has an
//! `OFFSET x y z` (its origin in the parent's frame, in file units) and a
//! `CHANNELS n c1 .. cn` line naming, in order, the values it reads from each motion row
//! (`Xposition`, `Yposition`, `Zposition`, `Xrotation`, `Yrotation`, `Zrotation`, any subset,
//! any order). `MOTION` then gives `Frames: N`, `Frame Time: seconds` and N rows, one per line,
//! holding the channels of all joints in file (depth-first) order.
//!
//! The parser treats the file as untrusted: keywords are case-insensitive, CRLF/LF/CR line ends
//! and any whitespace are accepted, braces may share a line with other statements, nesting is
//! bounded by [`MAX_DEPTH`], memory grows only with what the file actually contains (the
//! `Frames:` header is checked against the rows, never used to preallocate), and every error
//! names the line (1-based) and what is wrong. Frames in messages are numbered from 0.
//!
//! # Forward kinematics
//! Each joint's local transform is a translation followed by a rotation: the translation is
//! the `OFFSET`, except that a position channel *replaces* the offset along its axis (the
//! Blender / bvh-python convention; CMU roots have zero offsets, so there it makes no
//! difference). The rotation is the product of the rotation channels in the order listed,
//! `R = R_c1 · R_c2 · R_c3` (intrinsic rotations, angles in degrees, right-handed). The global
//! transform is `parent_global · local`, so a joint sits at `parent_pos + parent_rot · t`
//! and its children see the rotation `parent_rot · R`. Computed in `f64`, stored as `f32`.
//!
//! # Units and axes
//! BVH is y up in file units. [`BvhImport::scale`] gives metres per unit ([`CMU_SCALE`] for
//! the CMU database, 0.01 for centimetres) and [`UpAxis::Y`] converts y up to the scene's
//! z up with the proper rotation `(x, y, z) ↦ (x, −z, y)` (right-handed, det +1).

use super::rotation::{apply, axis_rotation, mul, IDENTITY, M3};
use super::{scene::Scene, skeleton::Skeleton};
use crate::{bail, Error, Result};
use ndarray::Array4;
use std::collections::HashSet;
use std::fmt;
use std::path::{Path, PathBuf};

/// Metres per CMU unit: CMU offsets are inches × 0.45, so 1 unit = 0.0254 / 0.45 m (CMU FAQ).
pub const CMU_SCALE: f64 = 0.056444;

/// Largest BVH file read (real takes are a few MB).
pub const MAX_FILE_BYTES: u64 = 512 << 20;

/// Deepest joint nesting the parser accepts.
pub const MAX_DEPTH: usize = 256;

/// Largest scene (frames × joints × 3 values) [`Bvh::to_scene`] builds.
const MAX_SCENE_VALUES: usize = 1 << 28;

/// One motion channel of a joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Channel {
    /// Translation along x.
    Xposition,
    /// Translation along y.
    Yposition,
    /// Translation along z.
    Zposition,
    /// Rotation about x, degrees.
    Xrotation,
    /// Rotation about y, degrees.
    Yrotation,
    /// Rotation about z, degrees.
    Zrotation,
}

impl Channel {
    /// All channels, positions first.
    pub const ALL: [Channel; 6] = [Channel::Xposition, Channel::Yposition, Channel::Zposition, Channel::Xrotation, Channel::Yrotation, Channel::Zrotation];

    /// Parses a channel name, case-insensitively (`Xrotation`, `xrotation`, ...).
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.name().eq_ignore_ascii_case(s))
    }

    /// The name as written in BVH files.
    pub fn name(self) -> &'static str {
        ["Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation"][self as usize]
    }

    /// Axis index: 0 for x, 1 for y, 2 for z.
    pub fn axis(self) -> usize {
        self as usize % 3
    }

    /// Whether this is a rotation (else a position) channel.
    pub fn is_rotation(self) -> bool {
        self as usize >= 3
    }
}

impl fmt::Display for Channel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A joint of the BVH hierarchy (or an end site: a leaf with an offset and no channels).
#[derive(Clone, Debug, PartialEq)]
pub struct BvhJoint {
    /// Name from the file; end sites are called `<parent>_end`.
    pub name: String,
    /// Index of the parent joint (always smaller than this joint's index); `None` for a root.
    pub parent: Option<usize>,
    /// Origin in the parent's frame, file units.
    pub offset: [f64; 3],
    /// Channels read from each motion row, in order.
    pub channels: Vec<Channel>,
    /// Whether this is an `End Site`.
    pub is_end_site: bool,
}

/// A parsed BVH file.
#[derive(Clone, Debug, PartialEq)]
pub struct Bvh {
    /// Joints in file (depth-first) order, end sites included.
    pub joints: Vec<BvhJoint>,
    /// Seconds per frame.
    pub frame_time: f64,
    /// Number of frames.
    pub frames: usize,
    /// Channel values, row-major `[frames, total channels]` (joints in order, each joint's
    /// channels in order).
    pub motion: Vec<f64>,
}

/// Up axis of the source coordinates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum UpAxis {
    /// y up (BVH standard): converted to z up with `(x, y, z) ↦ (x, −z, y)`.
    #[default]
    #[cfg_attr(feature = "clap", value(name = "y"))]
    Y,
    /// Already z up: kept as is.
    #[cfg_attr(feature = "clap", value(name = "z"))]
    Z,
}

/// Options for turning a [`Bvh`] into a [`Scene`].
#[derive(Clone, Debug, PartialEq)]
pub struct BvhImport {
    /// Metres per file unit (default 1.0; [`CMU_SCALE`] for CMU, 0.01 for centimetres).
    pub scale: f64,
    /// Ignore `scale` and guess it with [`Bvh::guess_scale`] (default false).
    pub auto_scale: bool,
    /// Up axis of the file (default [`UpAxis::Y`]).
    pub up_axis: UpAxis,
    /// Keep end sites as joints (default false: their bones are dropped too).
    pub include_end_sites: bool,
    /// Names of the left and right body-frame joints (hips). `None` finds them by name, as
    /// [`crate::data::joints`] reads names (`LeftUpLeg`, `LeftHip`, `UpperLeg_L`, `l_hip`,
    /// `thigh.L`, `lfemur`, `LHipJoint`, ..., ignoring case, separators and a `prefix:`).
    pub left_right: Option<(String, String)>,
}

impl Default for BvhImport {
    fn default() -> Self {
        Self { scale: 1.0, auto_scale: false, up_axis: UpAxis::Y, include_end_sites: false, left_right: None }
    }
}

/// Reads and parses a BVH file; errors name the file.
pub fn read_bvh(path: impl AsRef<Path>) -> Result<Bvh> {
    let path = path.as_ref();
    let starts_right = |head: &[u8]| {
        let text = String::from_utf8_lossy(head);
        let t = text.trim_start_matches('\u{feff}').trim_start();
        if t.is_empty() || "HIERARCHY".starts_with(&t[..t.len().min(9)]) {
            Ok(())
        } else {
            Err("not a BVH file (it does not start with HIERARCHY)".to_string())
        }
    };
    let bytes = crate::files::read_bounded_checked(path, MAX_FILE_BYTES, "BVH file", &starts_right)?;
    let text = String::from_utf8(bytes).map_err(|_| Error::format(path, "not a BVH file (not UTF-8 text)"))?;
    parse_bvh(&text).map_err(|e| e.in_file(path))
}

/// Reads a BVH file as a one-person scene named after the file stem (also the skeleton name
/// and the person id).
pub fn import_bvh(path: impl AsRef<Path>, opts: &BvhImport) -> Result<Scene> {
    let path = path.as_ref();
    let bvh = read_bvh(path)?;
    let stem = path.file_stem().map_or_else(|| "bvh".to_string(), |s| s.to_string_lossy().into_owned());
    let mut scene = bvh.to_scene(&stem, opts).map_err(|e| e.in_file(path))?;
    scene.persons[0].id = stem;
    scene.metadata.insert("source_file".into(), path.display().to_string().into());
    Ok(scene)
}

/// Reads several BVH files with the same joints and frame rate into one multi-person scene
/// (as long as the shortest file), placed on a circle with neighbours `spacing` metres apart
/// ([`Scene::around_circle`]). Files at different frame rates are an error: resample
/// them first ([`Scene::resample`]) and combine with [`Scene::combine`].
pub fn import_bvh_group(paths: &[PathBuf], opts: &BvhImport, spacing: f32) -> Result<Scene> {
    if paths.is_empty() {
        bail!("BVH group: no files given");
    }
    if !(spacing.is_finite() && spacing >= 0.0) {
        bail!("BVH group: spacing must be a non-negative number of metres, got {spacing}");
    }
    let scenes = paths.iter().map(|p| import_bvh(p, opts)).collect::<Result<Vec<_>>>()?;
    let first = &scenes[0];
    for (s, p) in scenes.iter().zip(paths).skip(1) {
        if s.skeleton.joints != first.skeleton.joints {
            return Err(Error::format(p, format!("joints differ from those of {}", paths[0].display())));
        }
        if (s.fps - first.fps).abs() > 1e-6 {
            let msg = format!("{} fps, but {} is at {} fps: resample (Scene::resample) and use Scene::combine", s.fps, paths[0].display(), first.fps);
            return Err(Error::format(p, msg));
        }
    }
    let name = scenes.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join("+");
    Scene::around_circle(name, &scenes, spacing)
}

/// Parses BVH text. Errors are [`Error::Invalid`] naming the line (add the file with
/// [`Error::in_file`]).
pub fn parse_bvh(text: &str) -> Result<Bvh> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let sep = if text.contains('\n') { '\n' } else { '\r' };
    let mut lines = text.split(sep).enumerate().map(|(i, l)| (i + 1, l.trim()));
    let mut h = Hierarchy::default();
    let mut motion_line = None;
    'lines: for (ln, line) in lines.by_ref() {
        let stmts = statements(line);
        for (k, st) in stmts.iter().enumerate() {
            if h.statement(ln, st)? {
                if k + 1 != stmts.len() || st.len() > 1 {
                    bail!("line {ln}: unexpected text after MOTION");
                }
                motion_line = Some(ln);
                break 'lines;
            }
        }
    }
    let Some(ml) = motion_line else {
        match h.stack.last() {
            Some(&j) => bail!("file ends inside joint {} (missing `}}`)", h.joints[j].name),
            None if h.joints.is_empty() => bail!("no HIERARCHY with a ROOT joint"),
            None => bail!("no MOTION section after the hierarchy"),
        }
    };
    let joints = h.joints;
    let nch: usize = joints.iter().map(|j| j.channels.len()).sum();
    if nch == 0 {
        bail!("line {ml}: the hierarchy has no CHANNELS");
    }
    let mut next = || lines.by_ref().find(|(_, l)| !l.is_empty());
    let (fl, line) = next().ok_or_else(|| Error::invalid(format!("line {ml}: no `Frames:` line after MOTION")))?;
    let frames: usize = header_value(line, "frames")
        .and_then(|v| v.parse().ok())
        .ok_or_else(|| Error::invalid(format!("line {fl}: expected `Frames: <count>`, found `{}`", clip(line))))?;
    let (tl, line) = next().ok_or_else(|| Error::invalid(format!("line {fl}: no `Frame Time:` line after Frames")))?;
    let frame_time: f64 = header_value(line, "frametime")
        .and_then(|v| v.parse().ok())
        .ok_or_else(|| Error::invalid(format!("line {tl}: expected `Frame Time: <seconds>`, found `{}`", clip(line))))?;
    if !(frame_time.is_finite() && frame_time > 0.0) {
        bail!("line {tl}: Frame Time must be a positive number of seconds, got {frame_time}");
    }
    let mut motion = Vec::new();
    let mut n = 0usize;
    for (ln, line) in lines.filter(|(_, l)| !l.is_empty()) {
        if n == frames {
            bail!("line {ln}: more frame rows than `Frames: {frames}` (line {fl}) announces");
        }
        let mut count = 0usize;
        for tok in line.split_whitespace() {
            count += 1;
            if count <= nch {
                match tok.parse::<f64>() {
                    Ok(v) if v.is_finite() => motion.push(v),
                    _ => bail!("line {ln}: frame {n}, value {count}: `{}` is not a finite number", clip(tok)),
                }
            }
        }
        if count != nch {
            bail!("line {ln}: frame {n} has {count} values, expected {nch}");
        }
        n += 1;
    }
    if n < frames {
        bail!("line {fl}: `Frames: {frames}` but only {n} frame rows follow (truncated file?)");
    }
    Ok(Bvh { joints, frame_time, frames, motion })
}

/// Hierarchy parser state.
#[derive(Default)]
struct Hierarchy {
    joints: Vec<BvhJoint>,
    names: HashSet<String>,
    /// Joints whose `{` is open.
    stack: Vec<usize>,
    /// Joint declared, waiting for its `{`.
    pending: Option<usize>,
    /// Per joint: OFFSET seen, CHANNELS seen.
    seen: Vec<(bool, bool)>,
    header: bool,
}

impl Hierarchy {
    /// Handles one statement (a keyword with the rest of its line, or a brace); returns true at
    /// `MOTION`.
    fn statement(&mut self, ln: usize, st: &[&str]) -> Result<bool> {
        let kw = st[0].to_ascii_uppercase();
        if let Some(j) = self.pending {
            if kw != "{" {
                bail!("line {ln}: expected `{{` after joint {}, found `{}`", self.joints[j].name, clip(st[0]));
            }
        }
        let top = self.stack.last().copied();
        match kw.as_str() {
            "HIERARCHY" if !self.header && st.len() == 1 => self.header = true,
            _ if !self.header => bail!("line {ln}: expected HIERARCHY, found `{}`", clip(st[0])),
            "ROOT" | "JOINT" => {
                let parent = match (kw.as_str(), top) {
                    ("ROOT", None) => None,
                    ("JOINT", Some(p)) if !self.joints[p].is_end_site => Some(p),
                    ("ROOT", Some(p)) => bail!("line {ln}: ROOT inside joint {}", self.joints[p].name),
                    ("JOINT", Some(_)) => bail!("line {ln}: an End Site cannot have children"),
                    _ => bail!("line {ln}: JOINT outside a ROOT block"),
                };
                let name = st[1..].join(" ");
                if name.is_empty() {
                    bail!("line {ln}: {kw} without a name");
                }
                if self.names.contains(&name) {
                    bail!("line {ln}: joint name {name:?} appears twice");
                }
                self.push(name, parent, false);
            }
            "END" => {
                let p = match top {
                    Some(p) if !self.joints[p].is_end_site => p,
                    _ => bail!("line {ln}: End Site outside a joint"),
                };
                // `<parent>_end`, else `<parent>_end<index>`, else the first free `_<k>` suffix.
                let base = format!("{}_end", self.joints[p].name);
                let mut name = base.clone();
                if self.names.contains(&name) {
                    name = format!("{base}{}", self.joints.len());
                }
                for k in 2.. {
                    if !self.names.contains(&name) {
                        break;
                    }
                    name = format!("{base}_{k}");
                }
                self.push(name, Some(p), true);
            }
            "{" => {
                let Some(j) = self.pending.take() else { bail!("line {ln}: unexpected `{{`") };
                if self.stack.len() >= MAX_DEPTH {
                    bail!("line {ln}: joints nested deeper than {MAX_DEPTH}");
                }
                self.stack.push(j);
            }
            "}" => {
                let Some(j) = self.stack.pop() else { bail!("line {ln}: unmatched `}}`") };
                if !self.seen[j].0 {
                    bail!("line {ln}: joint {} has no OFFSET", self.joints[j].name);
                }
            }
            "OFFSET" => {
                let Some(j) = top else { bail!("line {ln}: OFFSET outside a joint") };
                if std::mem::replace(&mut self.seen[j].0, true) {
                    bail!("line {ln}: second OFFSET for joint {}", self.joints[j].name);
                }
                if st.len() != 4 {
                    bail!("line {ln}: OFFSET needs 3 numbers, found {}", st.len() - 1);
                }
                for (k, tok) in st[1..].iter().enumerate() {
                    match tok.parse::<f64>() {
                        Ok(v) if v.is_finite() => self.joints[j].offset[k] = v,
                        _ => bail!("line {ln}: OFFSET value `{}` is not a finite number", clip(tok)),
                    }
                }
            }
            "CHANNELS" => {
                let j = match top {
                    Some(j) if !self.joints[j].is_end_site => j,
                    Some(_) => bail!("line {ln}: an End Site has no CHANNELS"),
                    None => bail!("line {ln}: CHANNELS outside a joint"),
                };
                if std::mem::replace(&mut self.seen[j].1, true) {
                    bail!("line {ln}: second CHANNELS for joint {}", self.joints[j].name);
                }
                let Some(count) = st.get(1).and_then(|s| s.parse::<usize>().ok()) else {
                    bail!("line {ln}: CHANNELS needs a count, found `{}`", clip(st.get(1).unwrap_or(&"")));
                };
                let names = &st[2..];
                if count != names.len() {
                    bail!("line {ln}: CHANNELS count {count} but {} channel names", names.len());
                }
                for s in names {
                    let Some(c) = Channel::parse(s) else { bail!("line {ln}: unknown channel {}", clip(s)) };
                    if self.joints[j].channels.contains(&c) {
                        bail!("line {ln}: channel {c} listed twice");
                    }
                    self.joints[j].channels.push(c);
                }
            }
            "MOTION" => {
                if let Some(j) = top {
                    bail!("line {ln}: MOTION inside joint {} (missing `}}`)", self.joints[j].name);
                }
                if self.joints.is_empty() {
                    bail!("line {ln}: MOTION before any ROOT joint");
                }
                return Ok(true);
            }
            _ => bail!("line {ln}: unexpected `{}`", clip(st[0])),
        }
        Ok(false)
    }

    fn push(&mut self, name: String, parent: Option<usize>, is_end_site: bool) {
        self.names.insert(name.clone());
        self.pending = Some(self.joints.len());
        self.joints.push(BvhJoint { name, parent, offset: [0.0; 3], channels: Vec::new(), is_end_site });
        self.seen.push((false, false));
    }
}

/// Splits a line into statements: runs of whitespace-separated words, with `{` and `}` as
/// statements of their own.
fn statements(line: &str) -> Vec<Vec<&str>> {
    let mut out = Vec::new();
    let mut cur = Vec::new();
    for tok in line.split_whitespace() {
        let mut rest = tok;
        while !rest.is_empty() {
            match rest.find(['{', '}']) {
                Some(0) => {
                    if !cur.is_empty() {
                        out.push(std::mem::take(&mut cur));
                    }
                    out.push(vec![&rest[..1]]);
                    rest = &rest[1..];
                }
                Some(i) => {
                    cur.push(&rest[..i]);
                    rest = &rest[i..];
                }
                None => {
                    cur.push(rest);
                    rest = "";
                }
            }
        }
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    out
}

/// The value of a `Key: value` header line whose key, without spaces and ignoring case, is `key`.
fn header_value<'a>(line: &'a str, key: &str) -> Option<&'a str> {
    let (k, v) = line.split_once(':')?;
    k.split_whitespace().collect::<String>().eq_ignore_ascii_case(key).then(|| v.trim())
}

/// At most 40 characters of `s`, for error messages.
fn clip(s: &str) -> String {
    match s.char_indices().nth(40) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s.to_string(),
    }
}

impl Bvh {
    /// Channels per frame (all joints).
    pub fn num_channels(&self) -> usize {
        self.joints.iter().map(|j| j.channels.len()).sum()
    }

    /// Frames per second, `1 / frame_time`, rounded to an integer when within 1e-3 of one
    /// (CMU's `0.0083333` gives 120).
    pub fn fps(&self) -> f64 {
        let fps = 1.0 / self.frame_time;
        if (fps - fps.round()).abs() < 1e-3 && fps.round() > 0.0 {
            fps.round()
        } else {
            fps
        }
    }

    /// Index of the joint called `name` (exact match).
    pub fn joint_index(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.name == name)
    }

    /// Global positions of every joint (end sites included) at `frame`, file units and axes.
    pub fn forward_kinematics(&self, frame: usize) -> Result<Vec<[f64; 3]>> {
        let nch = self.check()?;
        if frame >= self.frames {
            bail!("BVH frame {frame} out of range (0..{})", self.frames);
        }
        let mut pos = vec![[0.0; 3]; self.joints.len()];
        let mut rot = vec![IDENTITY; self.joints.len()];
        self.fk_into(&self.motion[frame * nch..(frame + 1) * nch], &mut pos, &mut rot);
        Ok(pos)
    }

    /// Guesses metres per file unit from the standing height (extent along the up axis, end
    /// sites included) in the first frame: 1000–2500 → mm (0.001), 100–250 → cm (0.01),
    /// 55–90 → inches (0.0254), 20–45 → CMU units ([`CMU_SCALE`]; CMU subjects measure 25–27
    /// units from head end site to toe), 1–2.5 → metres (1.0).
    pub fn guess_scale(&self, up: UpAxis) -> Result<f64> {
        if self.frames == 0 {
            bail!("BVH has no frames to guess its unit from");
        }
        let axis = if up == UpAxis::Y { 1 } else { 2 };
        let pos = self.forward_kinematics(0)?;
        let (lo, hi) = pos.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| (lo.min(p[axis]), hi.max(p[axis])));
        let height = hi - lo;
        const UNITS: [(f64, f64, f64); 5] = [(1000.0, 2500.0, 0.001), (100.0, 250.0, 0.01), (55.0, 90.0, 0.0254), (20.0, 45.0, CMU_SCALE), (1.0, 2.5, 1.0)];
        match UNITS.iter().find(|u| (u.0..=u.1).contains(&height)) {
            Some(u) => Ok(u.2),
            None => bail!("cannot guess the BVH unit from a first-frame height of {height} file units; set BvhImport::scale"),
        }
    }

    /// Converts to a one-person [`Scene`] named `name` (also the skeleton name). Bones are the
    /// (parent, child) pairs among the kept joints. Zero-offset joints that coincide with their
    /// parent (CMU's `LHipJoint`, `RHipJoint`) are kept: they are real joints of the file.
    pub fn to_scene(&self, name: &str, opts: &BvhImport) -> Result<Scene> {
        let nch = self.check()?;
        if self.frames == 0 {
            bail!("BVH {name}: no frames");
        }
        let kept: Vec<usize> = (0..self.joints.len()).filter(|&j| opts.include_end_sites || !self.joints[j].is_end_site).collect();
        let mut index = vec![usize::MAX; self.joints.len()];
        for (k, &j) in kept.iter().enumerate() {
            index[j] = k;
        }
        let names: Vec<String> = kept.iter().map(|&j| self.joints[j].name.clone()).collect();
        let bones = kept.iter().filter_map(|&j| self.joints[j].parent.filter(|&p| index[p] != usize::MAX).map(|p| (index[p], index[j]))).collect();
        let (left, right) = body_frame_joints(&names, opts)?;
        let skeleton = Skeleton::new(name, names, bones, left, right)?;
        let scale = if opts.auto_scale { self.guess_scale(opts.up_axis)? } else { opts.scale };
        if !(scale.is_finite() && scale > 0.0) {
            bail!("BVH {name}: scale must be a positive number of metres per unit, got {scale}");
        }
        let size = self.frames.checked_mul(kept.len() * 3).filter(|&s| s <= MAX_SCENE_VALUES);
        if size.is_none() {
            bail!("BVH {name}: {} frames × {} joints is too large a scene", self.frames, kept.len());
        }
        let mut positions = Array4::<f32>::zeros((self.frames, 1, kept.len(), 3));
        let mut pos = vec![[0.0; 3]; self.joints.len()];
        let mut rot = vec![IDENTITY; self.joints.len()];
        for (f, row) in self.motion.chunks_exact(nch).enumerate() {
            self.fk_into(row, &mut pos, &mut rot);
            for (k, &j) in kept.iter().enumerate() {
                let [x, y, z] = pos[j];
                let p = if opts.up_axis == UpAxis::Y { [x, -z, y] } else { [x, y, z] };
                for a in 0..3 {
                    positions[[f, 0, k, a]] = (p[a] * scale) as f32;
                }
            }
        }
        let mut scene = Scene::new(name, self.fps(), skeleton, positions)?;
        let meta: [(&str, serde_json::Value); 4] = [
            ("source", "bvh".into()),
            ("bvh_scale", scale.into()),
            ("bvh_up_axis", if opts.up_axis == UpAxis::Y { "y" } else { "z" }.into()),
            ("bvh_frame_time", self.frame_time.into()),
        ];
        scene.metadata.extend(meta.into_iter().map(|(k, v)| (k.to_string(), v)));
        Ok(scene)
    }

    /// Checks what the parser guarantees (the fields are public): parents precede children and
    /// `motion` is `[frames, channels]`. Returns the channel count.
    fn check(&self) -> Result<usize> {
        for (j, joint) in self.joints.iter().enumerate() {
            if joint.parent.is_some_and(|p| p >= j) {
                bail!("BVH joint {} does not come after its parent", joint.name);
            }
        }
        let nch = self.num_channels();
        if nch == 0 || self.frames.checked_mul(nch) != Some(self.motion.len()) {
            bail!("BVH motion has {} values, expected {} frames × {nch} channels", self.motion.len(), self.frames);
        }
        Ok(nch)
    }

    /// Forward kinematics of one motion row into `pos` (global positions) and `rot` (global
    /// rotations); see the module docs for the convention.
    fn fk_into(&self, row: &[f64], pos: &mut [[f64; 3]], rot: &mut [M3]) {
        let mut values = row.iter();
        for (j, joint) in self.joints.iter().enumerate() {
            let mut t = joint.offset;
            let mut r = IDENTITY;
            for (&c, &v) in joint.channels.iter().zip(values.by_ref()) {
                if c.is_rotation() {
                    r = mul(&r, &axis_rotation(c.axis(), v));
                } else {
                    t[c.axis()] = v;
                }
            }
            (pos[j], rot[j]) = match joint.parent {
                Some(p) => {
                    let d = apply(&rot[p], t);
                    ([pos[p][0] + d[0], pos[p][1] + d[1], pos[p][2] + d[2]], mul(&rot[p], &r))
                }
                None => (t, r),
            };
        }
    }
}

/// Finds the left and right body-frame joints among `names` (see [`BvhImport::left_right`]).
fn body_frame_joints(names: &[String], opts: &BvhImport) -> Result<(usize, usize)> {
    if let Some((l, r)) = &opts.left_right {
        let find = |n: &String| {
            names
                .iter()
                .position(|j| j.eq_ignore_ascii_case(n))
                .ok_or_else(|| Error::invalid(format!("body-frame joint {n:?} not found (joints: {})", crate::files::list_some(names, 12))))
        };
        return Ok((find(l)?, find(r)?));
    }
    // The hips by the joint vocabulary; a name with a prefix before its last `_`
    // (`Character1_LeftUpLeg`) is read by what follows it.
    let unprefixed: Vec<String> = names.iter().map(|n| n.rsplit_once('_').map_or(n.as_str(), |(_, tail)| tail).to_string()).collect();
    if let Some((a, b)) =
        super::joints::sided_pair(names, super::joints::Part::Hip).or_else(|| super::joints::sided_pair(&unprefixed, super::joints::Part::Hip))
    {
        if a != b {
            return Ok((a, b));
        }
    }
    bail!("no left/right hip joints found by name (joints: {}); pass them with BvhImport::left_right", crate::files::list_some(names, 12))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{rngs::StdRng, Rng, SeedableRng};

    const CMU_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/cmu_bvh");
    const FIXTURE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/bvh/other_source.bvh");

    /// Path of a CMU file, or `None` (with the reason printed) when the data is absent.
    fn cmu(stem: &str) -> Option<PathBuf> {
        let p = Path::new(CMU_DIR).join(format!("{stem}.bvh"));
        if p.exists() {
            Some(p)
        } else {
            crate::testing::skip_absent(&p, "shared CMU BVH data");
            None
        }
    }

    fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
        (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
    }

    fn at(s: &Scene, f: usize, joint: &str) -> [f64; 3] {
        let j = s.skeleton.require_joint(joint).unwrap();
        std::array::from_fn(|k| s.positions[[f, 0, j, k]] as f64)
    }

    fn assert_near(got: [f64; 3], want: [f64; 3], what: &str) {
        assert!(dist(&got, &want) < 1e-5, "{what}: got {got:?}, want {want:?}");
    }

    #[test]
    fn cmu_headers_match_files() {
        for (stem, frames, fps) in [("131_01", 994, 120.0), ("131_02", 1247, 120.0), ("131_03", 1102, 120.0), ("18_01", 303, 30.0)] {
            let Some(path) = cmu(stem) else { return };
            let text = std::fs::read_to_string(&path).unwrap();
            let header = |key: &str| text.lines().find_map(|l| header_value(l.trim(), key)).unwrap().to_string();
            let b = parse_bvh(&text).unwrap();
            assert_eq!(b.frames, header("frames").parse::<usize>().unwrap());
            assert_eq!(b.frame_time, header("frametime").parse::<f64>().unwrap());
            assert_eq!((b.frames, b.fps()), (frames, fps), "{stem}");
            assert_eq!(b.joints.len(), 38, "{stem}: 31 joints + 7 end sites");
            assert_eq!(b.num_channels(), 96);
            assert_eq!(b.motion.len(), frames * 96);
            assert_eq!(b.joints[0].channels[..3], [Channel::Xposition, Channel::Yposition, Channel::Zposition]);
            assert_eq!(b.guess_scale(UpAxis::Y).unwrap(), CMU_SCALE, "{stem}");
            let s = b.to_scene(stem, &BvhImport { scale: CMU_SCALE, ..Default::default() }).unwrap();
            let lr = (s.skeleton.joints[s.skeleton.left].as_str(), s.skeleton.joints[s.skeleton.right].as_str());
            assert_eq!(lr, if stem == "18_01" { ("lfemur", "rfemur") } else { ("LeftHip", "RightHip") });
        }
    }

    #[test]
    fn cmu_bone_lengths_are_constant() {
        let opts = BvhImport { include_end_sites: true, ..Default::default() };
        for stem in ["131_01", "131_02", "131_03", "18_01"] {
            let Some(path) = cmu(stem) else { return };
            let b = read_bvh(&path).unwrap();
            let s = b.to_scene(stem, &opts).unwrap();
            let mut worst = 0.0f64;
            for &(p, c) in &s.skeleton.bones {
                let child = &b.joints[b.joint_index(&s.skeleton.joints[c]).unwrap()];
                let rest = dist(&child.offset, &[0.0; 3]);
                if rest < 1e-9 || child.channels.iter().any(|c| !c.is_rotation()) {
                    continue;
                }
                for f in 0..s.num_frames() {
                    let len = dist(&at(&s, f, &s.skeleton.joints[p]), &at(&s, f, &s.skeleton.joints[c]));
                    worst = worst.max((len - rest).abs() / rest);
                }
            }
            println!("{stem}: max relative bone-length deviation {worst:.2e}");
            assert!(worst < 1e-4, "{stem}: {worst}");
        }
    }

    #[test]
    fn cmu_131_01_is_a_plausible_person() {
        let Some(path) = cmu("131_01") else { return };
        let opts = BvhImport { scale: CMU_SCALE, include_end_sites: true, ..Default::default() };
        let s = import_bvh(&path, &opts).unwrap();
        assert_eq!(read_bvh(&path).unwrap().guess_scale(UpAxis::Y).unwrap(), CMU_SCALE);
        let feet = s.skeleton.foot_joints();
        let z = |f: usize, j: usize| s.positions[[f, 0, j, 2]];
        let lowest = |f: usize| feet.iter().map(|&j| z(f, j)).fold(f32::INFINITY, f32::min);
        let head_top = s.skeleton.require_joint("Head_end").unwrap();
        let head = s.skeleton.require_joint("Head").unwrap();
        // Head end site (top of the head) to the lowest foot joint, first 10 frames.
        let height = (0..10).map(|f| z(f, head_top) - lowest(f)).sum::<f32>() / 10.0;
        println!("131_01 standing height {height:.3} m");
        assert!((1.4..=2.1).contains(&height), "{height}");
        let upright = (0..s.num_frames()).filter(|&f| feet.iter().all(|&j| z(f, head) > z(f, j))).count();
        assert!(upright as f64 > 0.99 * s.num_frames() as f64, "{upright}");
        let root = |f: usize| at(&s, f, "Hips");
        let speed = (1..s.num_frames()).map(|f| dist(&root(f), &root(f - 1)) * s.fps).fold(0.0, f64::max);
        println!("131_01 max root speed {speed:.2} m/s");
        assert!(speed < 10.0, "{speed}");
        assert_eq!(s.skeleton.joints[s.skeleton.left], "LeftHip");
        assert_eq!(s.skeleton.joints[s.skeleton.right], "RightHip");
        assert_eq!(s.persons[0].id, "131_01");
    }

    #[test]
    fn other_source_fixture_imports_with_known_positions() {
        let opts = BvhImport { auto_scale: true, include_end_sites: true, ..Default::default() };
        let s = import_bvh(FIXTURE, &opts).unwrap();
        assert_eq!(s.metadata["bvh_scale"], 0.01, "cm guessed from a 165 cm height");
        assert_eq!((s.num_frames(), s.num_joints(), s.fps), (4, 22, 30.0));
        assert_eq!(s.skeleton.name, "other_source");
        assert_eq!((s.skeleton.joints[s.skeleton.left].as_str(), s.skeleton.joints[s.skeleton.right].as_str()), ("UpperLeg_L", "UpperLeg_R"));
        // Frame 0, rest pose: hips at 95 cm, head top at 165 cm, left toe 10 cm left, 12 cm forward.
        assert_near(at(&s, 0, "Head_end"), [0.0, 0.0, 1.65], "f0 head top");
        assert_near(at(&s, 0, "Foot_L_end"), [0.10, -0.12, 0.0], "f0 left toe");
        // Frame 1: hips Zrotation 90 maps child offsets (x, y, z) to (-y, x, z) in the file:
        // left hip (10,-5,0) -> (5,10,0), head top (0,70,0) -> (-70,0,0) above the hips.
        assert_near(at(&s, 1, "UpperLeg_L"), [0.05, 0.0, 1.05], "f1 left hip");
        assert_near(at(&s, 1, "Head_end"), [-0.70, 0.0, 0.95], "f1 head top");
        // Frame 2: hips at (10, 95, 20); UpperLeg_L X=90 (ZXY joint) puts the knee at (20,90,-22);
        // LowerLeg_L X=90, Z=90 in XYZ order: Rx(90)·Rz(90)·(0,-43,0) = (43,0,0), kept by the
        // parent's Rx(90): ankle (63,90,-22); toe (0,-5,12) turned by Rx(180)·Rz(90): (68,90,-34).
        assert_near(at(&s, 2, "LowerLeg_L"), [0.20, 0.22, 0.90], "f2 left knee");
        assert_near(at(&s, 2, "Foot_L"), [0.63, 0.22, 0.90], "f2 left ankle");
        assert_near(at(&s, 2, "Foot_L_end"), [0.68, 0.34, 0.90], "f2 left toe");
        // Frame 3: Spine's Yposition 12 replaces its offset 10.
        assert_near(at(&s, 3, "Head_end"), [0.0, 0.0, 1.67], "f3 head top");
        let no_ends = import_bvh(FIXTURE, &BvhImport { scale: 0.01, ..Default::default() }).unwrap();
        assert_eq!((no_ends.num_joints(), no_ends.skeleton.bones.len()), (17, 16));
    }

    #[test]
    fn fk_rotation_order_matters() {
        let chain = |order: &str, angles: &str| {
            format!(
                "HIERARCHY\nROOT A\n{{\n OFFSET 9 9 9\n CHANNELS 6 Xposition Yposition Zposition {order}\n JOINT B\n {{\n  OFFSET 0 1 0\n  CHANNELS 1 Yrotation\n  End Site {{ OFFSET 0 0 1 }}\n }}\n}}\nMOTION\nFrames: 1\nFrame Time: 0.01\n1 2 3 {angles} 90\n"
            )
        };
        // A at (1,2,3) (position channels replace OFFSET 9 9 9) with X=90, Y=0, Z=90; B: Y=90.
        // XYZ: Rx·Ry·Rz·(0,1,0) = Rx·(-1,0,0) = (-1,0,0); end: Rx·Rz·Ry(90)·(0,0,1) = Rx·Rz·(1,0,0) = (0,0,1).
        // ZXY: Rz·Rx·Ry·(0,1,0) = Rz·(0,0,1) = (0,0,1);   end: Rz·Rx·(1,0,0) = (0,1,0).
        const XYZ: &str = "Xrotation Yrotation Zrotation";
        const ZXY: &str = "Zrotation Xrotation Yrotation";
        for (order, angles, b, end) in [(XYZ, "90 0 90", [0.0, 2.0, 3.0], [0.0, 2.0, 4.0]), (ZXY, "90 90 0", [1.0, 2.0, 4.0], [1.0, 3.0, 4.0])] {
            let bvh = parse_bvh(&chain(order, angles)).unwrap();
            let p = bvh.forward_kinematics(0).unwrap();
            assert_near(p[0], [1.0, 2.0, 3.0], order);
            assert_near(p[1], b, order);
            assert_near(p[2], end, order);
        }
        // y up → z up is the rotation (x, y, z) ↦ (x, −z, y).
        let bvh = parse_bvh(&chain(ZXY, "90 90 0")).unwrap();
        let opts = BvhImport { include_end_sites: true, left_right: Some(("b".into(), "B_end".into())), ..Default::default() };
        let s = bvh.to_scene("chain", &opts).unwrap();
        assert_near(at(&s, 0, "B_end"), [1.0, -4.0, 3.0], "z up");
        assert_eq!(s.skeleton.bones, vec![(0, 1), (1, 2)]);
        assert!(bvh.to_scene("chain", &BvhImport::default()).unwrap_err().to_string().contains("left_right"));
    }

    #[test]
    fn group_import_places_persons_apart() {
        let (Some(a), Some(b), Some(c)) = (cmu("131_01"), cmu("131_02"), cmu("18_01")) else { return };
        let opts = BvhImport { scale: CMU_SCALE, ..Default::default() };
        let g = import_bvh_group(&[a.clone(), b], &opts, 2.0).unwrap();
        assert_eq!(g.positions.dim(), (994, 2, 31, 3));
        assert_eq!(g.name, "131_01+131_02");
        assert_eq!(g.persons.iter().map(|p| p.id.as_str()).collect::<Vec<_>>(), ["131_01", "131_02"]);
        let (l, r) = (g.skeleton.left, g.skeleton.right);
        // Body centre: midpoint of the hips on the ground.
        let root =
            |p: usize| -> [f64; 3] { std::array::from_fn(|k| if k == 2 { 0.0 } else { 0.5 * (g.positions[[0, p, l, k]] + g.positions[[0, p, r, k]]) as f64 }) };
        let d = dist(&root(0), &root(1));
        println!("first-frame body-centre distance {d:.4} m (spacing 2.0)");
        assert!((d - 2.0).abs() < 1e-4, "{d}");
        assert!((root(0)[0] - 1.0).abs() < 1e-5 && (root(1)[0] + 1.0).abs() < 1e-5);
        let single = import_bvh(&a, &opts).unwrap();
        assert_eq!(g.positions[[500, 0, 5, 2]], single.positions[[500, 0, 5, 2]], "heights unchanged");
        // 18_01 uses the ASF joint names (hip, lfemur, ...): a different skeleton.
        let e = import_bvh_group(&[a, c], &opts, 2.0).unwrap_err().to_string();
        assert!(e.contains("18_01") && e.contains("joints differ"), "{e}");
    }

    #[test]
    fn group_import_of_fixtures() {
        let opts = BvhImport { scale: 0.01, ..Default::default() };
        let slow = std::env::temp_dir().join(format!("socdiff_bvh_25fps_{}.bvh", std::process::id()));
        std::fs::write(&slow, std::fs::read_to_string(FIXTURE).unwrap().replace("Frame Time: 0.0333333", "Frame Time: 0.04")).unwrap();
        let e = import_bvh_group(&[FIXTURE.into(), slow.clone()], &opts, 1.5).unwrap_err().to_string();
        std::fs::remove_file(&slow).ok();
        assert!(e.contains("25 fps") && e.contains("resample"), "{e}");
        // Three persons on a circle with neighbours 1.5 m apart; heights untouched.
        let g = import_bvh_group(&[FIXTURE.into(), FIXTURE.into(), FIXTURE.into()], &opts, 1.5).unwrap();
        assert_eq!(g.positions.dim(), (4, 3, 17, 3));
        let root = |p: usize| -> [f64; 3] { std::array::from_fn(|k| g.positions[[0, p, 0, k]] as f64) };
        for (p, q) in [(0, 1), (1, 2), (2, 0)] {
            assert!((dist(&root(p), &root(q)) - 1.5).abs() < 1e-5);
        }
        assert!((root(0)[2] - 0.95).abs() < 1e-6);
        assert!(import_bvh_group(&[], &opts, 1.0).is_err());
    }

    #[test]
    fn malformed_files_name_the_line() {
        let good = "HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n  JOINT Knee\n  {\n    OFFSET 0 -1 0\n    CHANNELS 1 Xrotation\n    End Site\n    {\n      OFFSET 0 -1 0\n    }\n  }\n}\nMOTION\nFrames: 2\nFrame Time: 0.04\n0 1 0 0 0 0 10\n0 1 0 0 0 0 20\n";
        let b = parse_bvh(good).unwrap();
        assert_eq!((b.frames, b.fps(), b.joints.len()), (2, 25.0, 3));
        assert!(parse_bvh(&good.replace('\n', "\r\n").to_lowercase().replace("end site", "END SITE")).is_ok());
        let cases: &[(String, &[&str])] = &[
            (good.replace("CHANNELS 1", "CHANNELS 2"), &["line 9:", "CHANNELS count 2 but 1 channel names"]),
            (good.replace("1 Xrotation", "1 Wrotation"), &["line 9:", "unknown channel Wrotation"]),
            (good.replace("0 0 0 0 10\n", "0 0 0 10\n"), &["line 19:", "frame 0 has 6 values, expected 7"]),
            (good.replace("0 0 0 0 20\n", "0 0"), &["line 20:", "frame 1 has 4 values"]),
            (good.replace("Frames: 2", "Frames: 3"), &["line 17:", "only 2 frame rows"]),
            (good.replace("Frames: 2", "Frames: 1"), &["line 20:", "more frame rows"]),
            (good.replace("0 0 0 0 20", "0 0 0 0 nan"), &["line 20:", "not a finite number"]),
            (good.replace("0 0 0 0 20", "0 0 0 0 1e999"), &["line 20:", "not a finite number"]),
            (good.replace("Frames: 2", "Frames: 1000000000000"), &["line 17:", "only 2 frame rows"]),
            (good.replace("Frames: 2", "Frames: 99999999999999999999999"), &["line 17:", "Frames:"]),
            (good.replace("Frame Time: 0.04", "Frame Time: 0"), &["line 18:", "positive"]),
            (good.replace("OFFSET 0 -1 0\n    CH", "OFFSET 0 -1\n    CH"), &["line 8:", "3 numbers"]),
            (good.replace("  }\n}\n", "  }\n"), &["line 15:", "MOTION inside joint Hips"]),
            (good.replace("JOINT Knee", "JOINT Hips"), &["line 6:", "appears twice"]),
            (good.replace("MOTION", "MOTON"), &["line 16:", "unexpected `MOTON`"]),
            (good[..good.find("MOTION").unwrap()].to_string(), &["no MOTION"]),
            (good.replace("JOINT Knee\n  {", "JOINT Knee\n  OFFSET"), &["line 7:", "expected `{`"]),
            (format!("HIERARCHY\nROOT a\n{}", (0..300).map(|i| format!("{{ JOINT j{i} ")).collect::<String>()), &["line 3:", "nested deeper than 256"]),
        ];
        for (text, want) in cases {
            let e = parse_bvh(text).unwrap_err().to_string();
            for w in *want {
                assert!(e.contains(w), "expected {w:?} in {e:?}");
            }
        }
        let e = read_bvh("/nonexistent/x.bvh").unwrap_err().to_string();
        assert!(e.contains("/nonexistent/x.bvh"), "{e}");
    }

    #[test]
    fn fuzzed_inputs_never_panic() {
        let mut bases = vec![std::fs::read_to_string(FIXTURE).unwrap()];
        if let Some(p) = cmu("131_01") {
            // Header + 20 frames, with a matching Frames: line.
            let text = std::fs::read_to_string(p).unwrap();
            let lines: Vec<&str> = text.split('\n').take(207).collect();
            bases.push(lines.join("\n").replace("Frames: 994", "Frames: 20"));
        }
        for b in &bases {
            assert!(parse_bvh(b).is_ok());
        }
        const ODD: [&str; 9] = ["1000000000000", "1e308", "-1", "nan", "inf", "99999999999999999999999", "0", "{", "}"];
        let mut rng = StdRng::seed_from_u64(0xb5d);
        let (mut parsed, n) = (0, 6000);
        for i in 0..n {
            let mut bytes = bases[i % bases.len()].as_bytes().to_vec();
            for _ in 0..if rng.gen_bool(0.7) { 1 } else { rng.gen_range(2..=3) } {
                let len = bytes.len().max(1);
                match rng.gen_range(0..9) {
                    0 => {
                        let k = rng.gen_range(0..len);
                        let v = *b"{}\n \r:-.e09abXZ".get(rng.gen_range(0..20)).unwrap_or(&rng.gen());
                        if k < bytes.len() {
                            bytes[k] = v;
                        }
                    }
                    1 => bytes.truncate(rng.gen_range(0..len)),
                    2..=4 => {
                        let mut lines: Vec<Vec<u8>> = bytes.split(|&b| b == b'\n').map(|l| l.to_vec()).collect();
                        let k = rng.gen_range(0..lines.len());
                        match rng.gen_range(0..4) {
                            0 => lines.insert(k, lines[k].clone()),
                            1 => drop(lines.remove(k)),
                            2 => {
                                let other = rng.gen_range(0..lines.len());
                                lines.swap(k, other)
                            }
                            _ => {
                                // Replace one word of the line with an odd value.
                                let line = String::from_utf8_lossy(&lines[k]).into_owned();
                                let mut words: Vec<&str> = line.split_whitespace().collect();
                                if !words.is_empty() {
                                    let w = rng.gen_range(0..words.len());
                                    words[w] = ODD[rng.gen_range(0..ODD.len())];
                                }
                                lines[k] = words.join(" ").into_bytes();
                            }
                        }
                        bytes = lines.join(&b'\n');
                    }
                    5 => {
                        let at = rng.gen_range(0..len).min(bytes.len());
                        let deep: String = (0..rng.gen_range(1..400)).map(|i| format!("JOINT j{i} {{ ")).collect();
                        drop(bytes.splice(at..at, deep.into_bytes()));
                    }
                    6 | 7 => {
                        // Keep the structure: replace one number with a random finite value.
                        let s = String::from_utf8_lossy(&bytes).into_owned();
                        let starts: Vec<usize> =
                            s.match_indices(' ').map(|(i, _)| i + 1).filter(|&i| s[i..].starts_with(|c: char| c.is_ascii_digit() || c == '-')).collect();
                        if let Some(&i) = starts.get(rng.gen_range(0..starts.len().max(1))) {
                            let end = s[i..].find(char::is_whitespace).map_or(s.len(), |e| i + e);
                            let v = (rng.gen::<f64>() - 0.5) * 10f64.powi(rng.gen_range(-3..300));
                            bytes = format!("{}{v}{}", &s[..i], &s[end..]).into_bytes();
                        }
                    }
                    _ => {
                        let s = String::from_utf8_lossy(&bytes).into_owned();
                        bytes = s.replacen("Frames: ", &format!("Frames: {}", ODD[rng.gen_range(0..3)]), 1).into_bytes();
                    }
                }
            }
            let text = String::from_utf8_lossy(&bytes);
            if let Ok(b) = parse_bvh(&text) {
                parsed += 1;
                let _ = b.to_scene("fuzz", &BvhImport { auto_scale: true, ..Default::default() });
            }
        }
        println!("fuzz: {parsed} of {n} mutated files parsed");
    }
}
