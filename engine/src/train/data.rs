//! Training data: windows cut from the scenes of a split, grouped by person count, and the
//! batches built from them.
//!
//! # Equal P per batch
//! The denoiser takes `[B, P, T, δ]`, so all windows of a batch must have the same number of
//! persons P. Windows are grouped by P (no padding or masking: the aggregators would need a
//! mask, and a padded person would distort the mean). Each epoch shuffles every group, cuts it
//! into batches of `batch` windows (the last one of a group may be smaller, as the reference's
//! DataLoader keeps its last partial batch) and shuffles the list of all batches. The number of
//! batches per epoch is fixed, so step s is batch `s mod n` of epoch `⌊s / n⌋`, and the plan of
//! an epoch depends only on `(seed, epoch)`: resuming needs no saved RNG state. With
//! [`WindowBalance::Sequences`] a group's windows are drawn with replacement instead, as many
//! as it has, each sequence (scene) equally likely and its windows equally likely within it.
//!
//! # A batch
//! For window w (frames `start..start+T` of a scene, persons `w.persons`), every person is
//! anchored at its body frame at frame `start + anchor_offset` (the last observed frame):
//! `x0[b, p]` = standardized anchored features `[T, δ]`, and `anchors[b, p]` =
//! `(root_x, root_y, cos h, sin h)` of that anchor frame in the scene frame, so that the
//! aggregator knows where the others stand.

use crate::checkpoint::config::{AugmentConfig, TrainConfig, WindowBalance};
use crate::data::dataset::Sequence;
use crate::data::joint_map::JointMap;
use crate::data::synthetic::{synthetic_groups, GroupConfig};
use crate::data::{Dataset, Scene, Split};
use crate::features::{fill_short_gaps, training_windows, PoseEncoding, PoseFeatures, Standardization, Window};
use crate::{bail, Result};
use candle_core::{Device, Tensor};
use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use std::collections::BTreeMap;

/// Independent random streams derived from the run's seed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Stream {
    /// Diffusion steps t and noise ε of a training step.
    Step = 1,
    /// Order of the batches of an epoch.
    Epoch = 2,
    /// Augmentation of a training step.
    Augment = 3,
    /// Validation t and noise (the same at every validation).
    Validation = 4,
}

fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The RNG of `stream` at `index` (a step or an epoch) of a run seeded with `seed`: a function
/// of its arguments only, which is what makes a resumed run continue exactly.
pub(crate) fn stream_rng(seed: u64, stream: Stream, index: u64) -> StdRng {
    let s = splitmix64(splitmix64(seed) ^ splitmix64((stream as u64) << 56 ^ index));
    StdRng::seed_from_u64(s)
}

/// At most this many windows measure [`WindowSet::velocity_scales`].
pub const VELOCITY_SCALE_WINDOWS: usize = 2000;

/// Smallest velocity scale (standardized units per frame): a dim that never changes is not
/// divided by zero.
pub const VELOCITY_SCALE_FLOOR: f32 = 1e-3;

/// A batch of training windows.
#[derive(Clone, Debug)]
pub struct Batch {
    /// Standardized anchored features, `[B, P, T, δ]`.
    pub x0: Tensor,
    /// Each person's anchor `(root_x, root_y, cos h, sin h)` in the scene frame, `[B, P, 4]`.
    pub anchors: Tensor,
}

/// Windows of the scenes of one split, grouped by person count.
#[derive(Clone, Debug)]
pub struct WindowSet {
    scenes: Vec<Scene>,
    windows: Vec<Window>,
    /// (P, indices into `windows`), ascending P.
    groups: Vec<(usize, Vec<usize>)>,
    anchor_offset: usize,
    encoding: PoseEncoding,
    balance: WindowBalance,
}

impl WindowSet {
    /// Fills short gaps of every scene and cuts windows as `cfg` says (window, stride, persons,
    /// max_gap). `limit` keeps at most that many windows, evenly spaced. Errors: no scenes, a
    /// window longer than every scene, no window without invalid frames.
    pub fn new(scenes: Vec<Scene>, cfg: &TrainConfig, limit: Option<usize>) -> Result<Self> {
        let scenes: Vec<Scene> = scenes.iter().map(|s| fill_short_gaps(s, cfg.max_gap)).collect();
        let persons = cfg.persons.map(|r| (r.min, r.max));
        let mut windows = training_windows(&scenes, cfg.window, cfg.stride, persons)?;
        if windows.is_empty() {
            let why = match persons {
                Some((lo, _)) => format!("no window of {} frames has at least {lo} persons valid on every frame", cfg.window),
                None => format!("every window of {} frames has a person with invalid frames (try `persons_min`/`persons_max`)", cfg.window),
            };
            bail!("training data: {why}");
        }
        if let Some(n) = limit {
            if n == 0 {
                bail!("training data: window limit must be at least 1");
            }
            if windows.len() > n {
                let len = windows.len();
                windows = (0..n).map(|i| windows[i * len / n].clone()).collect();
            }
        }
        let mut by_p: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for (i, w) in windows.iter().enumerate() {
            by_p.entry(w.persons.len()).or_default().push(i);
        }
        Ok(Self { scenes, windows, groups: by_p.into_iter().collect(), anchor_offset: cfg.anchor_offset(), encoding: cfg.pose, balance: cfg.balance })
    }

    /// Number of windows.
    pub fn len(&self) -> usize {
        self.windows.len()
    }

    /// Whether there are no windows (never, after [`WindowSet::new`]).
    pub fn is_empty(&self) -> bool {
        self.windows.is_empty()
    }

    /// The windows.
    pub fn windows(&self) -> &[Window] {
        &self.windows
    }

    /// The (gap-filled) scenes the windows index.
    pub fn scenes(&self) -> &[Scene] {
        &self.scenes
    }

    /// Number of windows per person count P.
    pub fn counts_by_persons(&self) -> BTreeMap<usize, usize> {
        self.groups.iter().map(|(p, w)| (*p, w.len())).collect()
    }

    /// Per-dim standardization over every training window (anchored representation).
    pub fn fit_standardization(&self) -> Result<Standardization> {
        Standardization::fit_windows(&self.scenes, &self.windows, self.anchor_offset, self.encoding)
    }

    /// The scale of each feature dim's frame-to-frame change: the root mean square of
    /// `x[f + 1] − x[f]` of the features standardized with `std`, over at most
    /// [`VELOCITY_SCALE_WINDOWS`] windows evenly spaced, floored at [`VELOCITY_SCALE_FLOOR`].
    ///
    /// # Shapes
    /// - returns `[δ]`
    pub fn velocity_scales(&self, std: &Standardization) -> Result<Vec<f32>> {
        let n = self.windows.len().min(VELOCITY_SCALE_WINDOWS);
        let dim = std.dim();
        let (sum, count) = (0..n)
            .into_par_iter()
            .map(|i| -> Result<(Vec<f64>, usize)> {
                let w = &self.windows[i * self.windows.len() / n];
                let mut x = crate::features::window_features(&self.scenes[w.scene], w, self.anchor_offset, self.encoding)?;
                std.apply(&mut x)?;
                let mut acc = vec![0f64; dim];
                let frames = x.len_of(ndarray::Axis(0));
                for f in 1..frames {
                    for p in 0..x.len_of(ndarray::Axis(1)) {
                        for (d, a) in acc.iter_mut().enumerate() {
                            *a += ((x[[f, p, d]] - x[[f - 1, p, d]]) as f64).powi(2);
                        }
                    }
                }
                Ok((acc, (frames.saturating_sub(1)) * x.len_of(ndarray::Axis(1))))
            })
            .try_reduce(|| (vec![0f64; dim], 0), |(a, n), (b, m)| Ok((a.iter().zip(&b).map(|(x, y)| x + y).collect(), n + m)))?;
        if count == 0 {
            bail!("training data: windows of one frame have no frame-to-frame change");
        }
        Ok(sum.iter().map(|s| ((s / count as f64).sqrt() as f32).max(VELOCITY_SCALE_FLOOR)).collect())
    }

    /// Batches per epoch at `batch` windows per batch.
    pub fn batches_per_epoch(&self, batch: usize) -> usize {
        self.groups.iter().map(|(_, w)| w.len().div_ceil(batch)).sum()
    }

    /// The batches (window indices) of epoch `epoch`, shuffled as described in the module doc.
    pub fn epoch_plan(&self, seed: u64, epoch: u64, batch: usize) -> Vec<Vec<usize>> {
        let mut rng = stream_rng(seed, Stream::Epoch, epoch);
        let mut plan = Vec::with_capacity(self.batches_per_epoch(batch));
        for (_, group) in &self.groups {
            let mut g = match self.balance {
                WindowBalance::Windows => group.clone(),
                WindowBalance::Sequences => self.draw_by_sequence(group, &mut rng),
            };
            g.shuffle(&mut rng);
            plan.extend(g.chunks(batch).map(|c| c.to_vec()));
        }
        plan.shuffle(&mut rng);
        plan
    }

    /// `group.len()` windows of `group` drawn with replacement, each with probability
    /// 1 / (sequences in the group · windows of its sequence in the group).
    fn draw_by_sequence(&self, group: &[usize], rng: &mut StdRng) -> Vec<usize> {
        let mut per_scene: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for &i in group {
            per_scene.entry(self.windows[i].scene).or_default().push(i);
        }
        let scenes: Vec<&Vec<usize>> = per_scene.values().collect();
        (0..group.len())
            .map(|_| {
                let s = scenes[rng.gen_range(0..scenes.len())];
                s[rng.gen_range(0..s.len())]
            })
            .collect()
    }

    /// The batches of a pass over all windows in order (validation): each group cut into
    /// batches of `batch`.
    pub fn ordered_plan(&self, batch: usize) -> Vec<Vec<usize>> {
        self.groups.iter().flat_map(|(_, g)| g.chunks(batch).map(|c| c.to_vec()).collect::<Vec<_>>()).collect()
    }

    /// A digest of the windows (scene names, lengths, window starts and persons), recorded in
    /// checkpoints so that a resume on different data can be noticed.
    pub fn fingerprint(&self) -> String {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |bytes: &[u8]| {
            for &b in bytes {
                h ^= b as u64;
                h = h.wrapping_mul(0x0100_0000_01b3);
            }
        };
        for s in &self.scenes {
            eat(s.name.as_bytes());
            eat(&(s.num_frames() as u64).to_le_bytes());
            eat(&(s.num_persons() as u64).to_le_bytes());
        }
        for w in &self.windows {
            eat(&[w.scene as u8, (w.scene >> 8) as u8]);
            eat(&(w.start as u64).to_le_bytes());
            for &p in &w.persons {
                eat(&[p as u8]);
            }
        }
        format!("{h:016x}")
    }

    /// Builds the batch of windows `indices` (all with the same P): features anchored at each
    /// window's anchor frame and standardized with `std`, and the anchors, optionally moved by
    /// a random rigid motion per window (`augment`, drawn from `rng` in window order).
    ///
    /// # Shapes
    /// - returns `x0: [B, P, T, δ]`, `anchors: [B, P, 4]` with B = `indices.len()`
    pub fn batch(&self, indices: &[usize], std: &Standardization, augment: &AugmentConfig, rng: &mut StdRng) -> Result<Batch> {
        let Some(&first) = indices.first() else { bail!("training data: empty batch") };
        let np = self.windows[first].persons.len();
        if let Some(&i) = indices.iter().find(|&&i| self.windows[i].persons.len() != np) {
            bail!("training data: window {i} has {} persons, the batch {np}", self.windows[i].persons.len());
        }
        // Rigid motion per window, drawn sequentially for determinism.
        let moves: Vec<(f64, [f64; 2])> = indices
            .iter()
            .map(|_| {
                let theta = if augment.rotate { rng.gen_range(-std::f64::consts::PI..std::f64::consts::PI) } else { 0.0 };
                let a = augment.translate;
                let d = if a > 0.0 { [rng.gen_range(-a..=a), rng.gen_range(-a..=a)] } else { [0.0, 0.0] };
                (theta, d)
            })
            .collect();
        // Body proportions per window and person, also drawn sequentially.
        let scaler = (augment.body_scale > 0.0 || augment.limb_scale > 0.0).then(|| BoneScaler::new(&self.scenes[self.windows[first].scene].skeleton));
        let bodies: Vec<Option<Vec<Vec<f32>>>> = indices.iter().map(|_| scaler.as_ref().map(|sc| (0..np).map(|_| sc.draw(augment, rng)).collect())).collect();
        let per_window: Vec<(Vec<f32>, Vec<f32>)> = indices
            .par_iter()
            .zip(moves.par_iter().zip(bodies.par_iter()))
            .map(|(&i, (&(theta, d), body))| -> Result<(Vec<f32>, Vec<f32>)> {
                let w = &self.windows[i];
                let scene = &self.scenes[w.scene];
                let mut f = match (body, &scaler) {
                    (Some(factors), Some(sc)) => {
                        let frames = w.frames();
                        let mut part = scene.slice_frames(frames.start, frames.end)?.select_persons(&w.persons)?;
                        sc.apply(&mut part, factors);
                        let all: Vec<usize> = (0..w.persons.len()).collect();
                        PoseFeatures::encode_as(&part, 0..frames.len(), &all, self.anchor_offset, self.encoding)?
                    }
                    _ => PoseFeatures::encode_as(scene, w.frames(), &w.persons, w.start + self.anchor_offset, self.encoding)?,
                };
                std.apply(&mut f.data)?;
                let (nt, np, nd) = f.data.dim();
                // [T, P, δ] → [P, T, δ]
                let x: Vec<f32> = f.data.permuted_axes([1, 0, 2]).as_standard_layout().iter().copied().collect();
                debug_assert_eq!(x.len(), nt * np * nd);
                let (s, c) = theta.sin_cos();
                let mut a = Vec::with_capacity(np * 4);
                for an in &f.anchors {
                    let [x0, y0] = an.root;
                    a.extend([(c * x0 - s * y0 + d[0]) as f32, (s * x0 + c * y0 + d[1]) as f32]);
                    let h = an.heading + theta;
                    a.extend([h.cos() as f32, h.sin() as f32]);
                }
                Ok((x, a))
            })
            .collect::<Result<_>>()?;
        let (b, nt, nd) = (indices.len(), self.windows[first].length, std.dim());
        let mut x = Vec::with_capacity(b * np * nt * nd);
        let mut a = Vec::with_capacity(b * np * 4);
        for (xi, ai) in per_window {
            x.extend(xi);
            a.extend(ai);
        }
        Ok(Batch { x0: Tensor::from_vec(x, (b, np, nt, nd), &Device::Cpu)?, anchors: Tensor::from_vec(a, (b, np, 4), &Device::Cpu)? })
    }
}

/// Scales the bones of a skeleton (body-proportion augmentation, [`AugmentConfig::body_scale`]):
/// forward kinematics over the bones from the left body-frame joint, each bone's vector scaled
/// by its factor, then each frame moved back so that the midpoint of the body-frame joints keeps
/// its ground position and the lowest foot joint its height (without feet: the midpoint its
/// height), so the person stays where it was, on the floor.
#[derive(Clone, Debug)]
pub struct BoneScaler {
    /// `(parent, child, limb)` in the order of a walk from the root.
    edges: Vec<(usize, usize, usize)>,
    limbs: usize,
    feet: Vec<usize>,
    hips: (usize, usize),
}

impl BoneScaler {
    /// The walk over `skeleton`'s bones; a bone's limb is the pair of joint names without side
    /// words, so that left and right counterparts share one factor.
    pub fn new(skeleton: &crate::data::Skeleton) -> Self {
        let key = |j: usize| crate::data::joints::parse_joint_name(&skeleton.joints[j]).1;
        let mut names: Vec<(String, String)> = Vec::new();
        let mut seen = vec![false; skeleton.num_joints()];
        let mut queue = std::collections::VecDeque::from([skeleton.left]);
        seen[skeleton.left] = true;
        let mut edges = Vec::new();
        while let Some(j) = queue.pop_front() {
            for &(a, b) in &skeleton.bones {
                let next = if a == j {
                    b
                } else if b == j {
                    a
                } else {
                    continue;
                };
                if seen[next] {
                    continue;
                }
                seen[next] = true;
                let name = (key(j.min(next)), key(j.max(next)));
                let limb = names.iter().position(|n| *n == name).unwrap_or_else(|| {
                    names.push(name);
                    names.len() - 1
                });
                edges.push((j, next, limb));
                queue.push_back(next);
            }
        }
        Self { edges, limbs: names.len(), feet: skeleton.foot_joints(), hips: (skeleton.left, skeleton.right) }
    }

    /// One factor per limb: a body factor uniform in `1 ± body_scale` times a limb factor
    /// uniform in `1 ± limb_scale`.
    pub fn draw(&self, augment: &AugmentConfig, rng: &mut StdRng) -> Vec<f32> {
        let u = |rng: &mut StdRng, a: f64| if a > 0.0 { rng.gen_range(1.0 - a..=1.0 + a) } else { 1.0 };
        let body = u(rng, augment.body_scale);
        (0..self.limbs).map(|_| (body * u(rng, augment.limb_scale)) as f32).collect()
    }

    /// Scales every frame of person p of `scene` by `factors[p]` (one factor per limb).
    pub fn apply(&self, scene: &mut Scene, factors: &[Vec<f32>]) {
        let (nf, np, nj, _) = scene.positions.dim();
        for (p, f) in factors.iter().enumerate().take(np) {
            for t in 0..nf {
                let orig: Vec<[f32; 3]> = (0..nj).map(|j| std::array::from_fn(|k| scene.positions[[t, p, j, k]])).collect();
                let mut new = orig.clone();
                for &(a, b, limb) in &self.edges {
                    new[b] = std::array::from_fn(|k| new[a][k] + f[limb] * (orig[b][k] - orig[a][k]));
                }
                let mid = |v: &[[f32; 3]], k: usize| 0.5 * (v[self.hips.0][k] + v[self.hips.1][k]);
                let low = |v: &[[f32; 3]]| self.feet.iter().map(|&j| v[j][2]).fold(f32::INFINITY, f32::min);
                let dz = if self.feet.is_empty() { mid(&orig, 2) - mid(&new, 2) } else { low(&orig) - low(&new) };
                let shift = [mid(&orig, 0) - mid(&new, 0), mid(&orig, 1) - mid(&new, 1), dz];
                for (j, v) in new.iter().enumerate() {
                    for k in 0..3 {
                        scene.positions[[t, p, j, k]] = v[k] + shift[k];
                    }
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Mixed sources: several datasets → one training set.
// ---------------------------------------------------------------------------------------------

/// How several datasets become one training set ([`mix_sources`]).
#[derive(Clone, Debug, PartialEq)]
pub struct MixConfig {
    /// Synthetic groups built from each single-person source.
    pub groups_per_source: usize,
    /// How the synthetic groups are built (persons, frames, placement; source `i` uses seed
    /// `groups.seed + i`).
    pub groups: GroupConfig,
    /// The primary source's train scenes appear this many times, weighting real multi-person
    /// motion against the other sources (1: once).
    pub primary_repeat: usize,
    /// Scale each single-person source's group count by its seconds of train motion over the
    /// largest single-person source's (at least one group), so that a few clips are not drawn
    /// as often as a large dataset; false: `groups_per_source` for every source.
    pub groups_by_frames: bool,
}

impl Default for MixConfig {
    fn default() -> Self {
        Self { groups_per_source: 200, groups: GroupConfig::default(), primary_repeat: 1, groups_by_frames: false }
    }
}

impl MixConfig {
    /// The defaults for training windows of `window` frames on `primary`: synthetic groups of
    /// the person counts of its train scenes ([`train_person_range`]), twice the window long
    /// (at least 300 frames), from `seed`; `groups_per_source` groups per single-person source.
    pub fn for_primary(primary: &Dataset, window: usize, groups_per_source: usize, seed: u64) -> MixConfig {
        let (persons_min, persons_max) = train_person_range(primary);
        let groups = GroupConfig { persons_min, persons_max, frames: (2 * window).max(300), seed, ..Default::default() };
        MixConfig { groups_per_source, groups, ..Default::default() }
    }
}

/// What [`mix_sources`] made of one source.
#[derive(Clone, Debug, PartialEq)]
pub struct MixedSource {
    /// Dataset name.
    pub name: String,
    /// `primary`, `multi-person` or `synthetic groups`.
    pub kind: &'static str,
    /// Train scenes it contributes.
    pub scenes: usize,
    /// Frames of those scenes (person-frames are frames × persons).
    pub frames: usize,
    /// How its joints were mapped onto the primary skeleton (empty: same skeleton).
    pub joint_map: Vec<String>,
}

/// The person counts of `primary`'s train scenes, `(fewest, most)` (`(1, 1)` without any): the
/// group sizes that synthetic groups mixed into it should have.
pub fn train_person_range(primary: &Dataset) -> (usize, usize) {
    let persons: Vec<usize> = primary.split(Split::Train).map(|s| s.num_persons()).collect();
    (persons.iter().copied().min().unwrap_or(1), persons.iter().copied().max().unwrap_or(1))
}

/// One line describing a mix for a checkpoint's source: each source as
/// `LABEL (kind: N scenes, F frames)` joined by ` + `, then the groups' sizes and seed.
pub fn describe_mix(labels: &[String], summary: &[MixedSource], cfg: &MixConfig) -> String {
    let parts: Vec<String> = summary.iter().zip(labels).map(|(s, l)| format!("{l} ({}: {} scenes, {} frames)", s.kind, s.scenes, s.frames)).collect();
    let g = &cfg.groups;
    format!("{}; synthetic groups of {}–{} persons × {} frames, seed {}", parts.join(" + "), g.persons_min, g.persons_max, g.frames, g.seed)
}

/// One training dataset from several. The first (primary) source sets the skeleton, the frame
/// rate and the validation data (its test split), and its train scenes are used as they are
/// (`primary_repeat` times). Every other source contributes its train split only: poses mapped
/// onto the primary skeleton by joint names ([`JointMap::by_names`], derived joints fitted on
/// the primary's train scenes), resampled to the primary frame rate; a source whose train scenes
/// all hold one person becomes `groups_per_source` synthetic groups
/// ([`crate::data::synthetic`]), any other source adds its scenes as they are (names prefixed by
/// the source's). Errors: no sources, a source without train scenes, a joint that cannot be
/// mapped.
pub fn mix_sources(sources: &[Dataset], cfg: &MixConfig) -> Result<(Dataset, Vec<MixedSource>)> {
    let Some(primary) = sources.first() else { bail!("mixed training: no data sources") };
    if cfg.primary_repeat == 0 {
        bail!("mixed training: the primary source must appear at least once (repeat ≥ 1)");
    }
    let train_of = |d: &Dataset| -> Result<Vec<Scene>> {
        let v: Vec<Scene> = d.split(Split::Train).cloned().collect();
        if v.is_empty() {
            bail!("mixed training: dataset {} has no train sequences", d.name);
        }
        Ok(v)
    };
    let primary_train = train_of(primary)?;
    let target = primary_train[0].skeleton.clone();
    let fps = primary_train[0].fps;
    let frames = |v: &[Scene]| v.iter().map(|s| s.num_frames()).sum::<usize>();

    let mut sequences = Vec::new();
    for seq in &primary.sequences {
        let copies = if seq.split == Split::Train { cfg.primary_repeat } else { 1 };
        for k in 0..copies {
            let mut scene = seq.scene.clone();
            if k > 0 {
                scene.name = format!("{}#{}", scene.name, k + 1);
            }
            sequences.push(Sequence { split: seq.split, scene });
        }
    }
    let mut summary = vec![MixedSource {
        name: primary.name.clone(),
        kind: "primary",
        scenes: primary_train.len() * cfg.primary_repeat,
        frames: frames(&primary_train) * cfg.primary_repeat,
        joint_map: Vec::new(),
    }];
    let fit: Vec<&Scene> = primary_train.iter().collect();
    let single_seconds = |d: &Dataset| -> Option<f64> {
        let v: Vec<&Scene> = d.split(Split::Train).collect();
        (!v.is_empty() && v.iter().all(|s| s.num_persons() == 1)).then(|| v.iter().map(|s| s.num_frames() as f64 / s.fps).sum())
    };
    let largest = sources.iter().skip(1).filter_map(single_seconds).fold(0.0, f64::max);
    for (i, source) in sources.iter().enumerate().skip(1) {
        let scenes = train_of(source)?;
        let group_count = match (cfg.groups_by_frames, single_seconds(source)) {
            (true, Some(seconds)) if largest > 0.0 => ((cfg.groups_per_source as f64 * seconds / largest).ceil() as usize).max(1),
            _ => cfg.groups_per_source,
        };
        let skeleton = &scenes[0].skeleton;
        let map = if skeleton.joints == target.joints { None } else { Some(JointMap::by_names(skeleton, &target, &fit)?) };
        let mapped: Vec<Scene> = scenes
            .iter()
            .map(|s| {
                let s = match &map {
                    Some(m) => m.apply(s)?,
                    None => s.clone(),
                };
                if (s.fps - fps).abs() > 1e-6 * fps {
                    s.resample(fps)
                } else {
                    Ok(s)
                }
            })
            .collect::<Result<_>>()?;
        let single = mapped.iter().all(|s| s.num_persons() == 1);
        let added: Vec<Scene> = if single {
            let groups = GroupConfig { seed: cfg.groups.seed.wrapping_add(i as u64), ..cfg.groups.clone() };
            synthetic_groups(&mapped, group_count, &format!("{}_group", source.name), &groups)?
        } else {
            mapped
                .into_iter()
                .map(|mut s| {
                    s.name = format!("{}/{}", source.name, s.name);
                    s
                })
                .collect()
        };
        summary.push(MixedSource {
            name: source.name.clone(),
            kind: if single { "synthetic groups" } else { "multi-person" },
            scenes: added.len(),
            frames: frames(&added),
            joint_map: map.map(|m| m.describe()).unwrap_or_default(),
        });
        sequences.extend(added.into_iter().map(|scene| Sequence { split: Split::Train, scene }));
    }
    let name = sources.iter().map(|d| d.name.as_str()).collect::<Vec<_>>().join("+");
    let mut metadata = primary.metadata.clone();
    metadata.insert("mixed_sources".into(), sources.iter().map(|d| d.name.clone()).collect::<Vec<_>>().into());
    Ok((Dataset { name, sequences, metadata }, summary))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::checkpoint::config::PersonRange;
    use crate::train::tests::walking_scene;
    use ndarray::Array2;

    fn cfg(window: usize, stride: usize, persons: Option<PersonRange>) -> TrainConfig {
        TrainConfig { window, stride, persons, observed: Some(window / 2), ..Default::default() }
    }

    /// Balancing by sequence: a 10-window take and a 1-window take are drawn equally often
    /// (the short one's window in 50 % of the draws instead of 1 in 11), with as many batches
    /// per epoch as before and a plan that depends only on (seed, epoch).
    #[test]
    fn sequence_balance_draws_every_take_equally() {
        let scenes = vec![walking_scene("long", 88, 1, 1), walking_scene("short", 16, 1, 2)];
        let plain = WindowSet::new(scenes.clone(), &cfg(16, 8, None), None).unwrap();
        let balanced = WindowSet::new(scenes, &TrainConfig { balance: WindowBalance::Sequences, ..cfg(16, 8, None) }, None).unwrap();
        assert_eq!((plain.len(), balanced.batches_per_epoch(4)), (11, plain.batches_per_epoch(4)));
        let short = plain.windows().iter().position(|w| w.scene == 1).unwrap();
        let share = |set: &WindowSet| {
            let draws: Vec<usize> = (0..200).flat_map(|e| set.epoch_plan(3, e, 4).into_iter().flatten()).collect();
            assert_eq!(draws.len(), 200 * 11);
            draws.iter().filter(|&&i| i == short).count() as f64 / draws.len() as f64
        };
        assert!((share(&plain) - 1.0 / 11.0).abs() < 1e-12);
        let b = share(&balanced);
        assert!((b - 0.5).abs() < 0.05, "short take drawn in {b} of the draws");
        assert_eq!(balanced.epoch_plan(3, 5, 4), balanced.epoch_plan(3, 5, 4));
        let json = serde_json::to_value(TrainConfig { balance: WindowBalance::Sequences, ..Default::default() }).unwrap();
        assert_eq!(json["balance"], "sequences");
    }

    /// Velocity scales: the RMS frame-to-frame change of each standardized dim, here over the
    /// two windows of one scene computed directly from their features; a dim that never
    /// changes gets the floor; a velocity loss with other noise levels is refused.
    #[test]
    fn velocity_scales_are_the_rms_frame_change() {
        let scene = walking_scene("w", 24, 1, 4);
        let set = WindowSet::new(vec![scene], &cfg(16, 8, None), None).unwrap();
        let std = set.fit_standardization().unwrap();
        let got = set.velocity_scales(&std).unwrap();
        let dim = std.dim();
        let (mut sum, mut n) = (vec![0f64; dim], 0usize);
        for w in set.windows() {
            let mut x = PoseFeatures::encode_as(&set.scenes()[0], w.frames(), &w.persons, w.start + 7, PoseEncoding::Absolute).unwrap().data;
            std.apply(&mut x).unwrap();
            for f in 1..16 {
                for (d, s) in sum.iter_mut().enumerate() {
                    *s += ((x[[f, 0, d]] - x[[f - 1, 0, d]]) as f64).powi(2);
                }
                n += 1;
            }
        }
        for d in 0..dim {
            let want = ((sum[d] / n as f64).sqrt() as f32).max(VELOCITY_SCALE_FLOOR);
            assert!((got[d] - want).abs() <= 1e-5 * want.max(1.0), "dim {d}: {} vs {want}", got[d]);
        }
        assert!(got.iter().all(|&v| v >= VELOCITY_SCALE_FLOOR));
        // A circle walker's root moves every frame.
        assert!(got[1].max(got[0]) > 10.0 * VELOCITY_SCALE_FLOOR, "{:?}", &got[..4]);
        let bad = TrainConfig { velocity_loss: 1.0, noise: crate::train::NoiseLevels::Prefix, ..cfg(16, 8, None) };
        assert!(bad.validate().unwrap_err().to_string().contains("uniform"));
        assert!(TrainConfig { velocity_loss: -1.0, ..cfg(16, 8, None) }.validate().is_err());
    }

    #[test]
    fn groups_plans_and_batches() {
        let scenes = vec![walking_scene("a", 40, 3, 1), walking_scene("b", 30, 2, 2)];
        // window 16, stride 8: a → starts 0, 8, 16, 24 (4 windows, P = 3); b → 0, 8 (2 windows, P = 2).
        let set = WindowSet::new(scenes.clone(), &cfg(16, 8, None), None).unwrap();
        assert_eq!(set.counts_by_persons(), BTreeMap::from([(2, 2), (3, 4)]));
        assert_eq!(set.batches_per_epoch(2), 1 + 2);
        let plan = set.epoch_plan(7, 0, 2);
        assert_eq!(plan.len(), 3);
        let mut all: Vec<usize> = plan.iter().flatten().copied().collect();
        all.sort();
        assert_eq!(all, (0..6).collect::<Vec<_>>());
        for b in &plan {
            let p = set.windows()[b[0]].persons.len();
            assert!(b.iter().all(|&i| set.windows()[i].persons.len() == p), "mixed P in {b:?}");
        }
        assert_eq!(plan, set.epoch_plan(7, 0, 2), "plan depends only on (seed, epoch)");
        assert!((1..20).any(|e| set.epoch_plan(7, e, 2) != plan));

        // A batch: anchored at frame 8 of each window → x0[.., .., 7] is the anchor frame.
        let std = Standardization::identity(13);
        let mut rng = StdRng::seed_from_u64(0);
        let b = set.batch(&[0, 2], &std, &AugmentConfig::default(), &mut rng).unwrap();
        assert_eq!(b.x0.dims(), &[2, 3, 16, 13]);
        assert_eq!(b.anchors.dims(), &[2, 3, 4]);
        let x0: Vec<f32> = b.x0.flatten_all().unwrap().to_vec1().unwrap();
        let at = |bi: usize, p: usize, t: usize, d: usize| x0[((bi * 3 + p) * 16 + t) * 13 + d];
        for p in 0..3 {
            assert_eq!([at(1, p, 7, 0), at(1, p, 7, 1), at(1, p, 7, 2), at(1, p, 7, 3)], [0.0, 0.0, 1.0, 0.0]);
        }
        let an: Vec<f32> = b.anchors.flatten_all().unwrap().to_vec1().unwrap();
        let want = crate::features::body_frame(&set.scenes()[0], 16 + 7, 1).unwrap();
        // anchors[1, 1] (window index 2, person 1) is at (1·3 + 1)·4 = 16.
        assert!((an[16] as f64 - want.root[0]).abs() < 1e-6 && (an[18] as f64 - want.heading.cos()).abs() < 1e-6);
        assert!(set.batch(&[0, 4], &std, &AugmentConfig::default(), &mut rng).unwrap_err().to_string().contains("persons"));

        // Augmentation moves anchors rigidly: pairwise relative anchors are unchanged.
        let aug = AugmentConfig { rotate: true, translate: 2.0, ..Default::default() };
        let moved = set.batch(&[0, 2], &std, &aug, &mut rng).unwrap();
        assert_eq!(moved.x0.flatten_all().unwrap().to_vec1::<f32>().unwrap(), x0);
        let r0 = crate::model::relative_anchors(Some(&b.anchors), 2, 3, candle_core::DType::F32, &Device::Cpu).unwrap();
        let r1 = crate::model::relative_anchors(Some(&moved.anchors), 2, 3, candle_core::DType::F32, &Device::Cpu).unwrap();
        let d = (r0 - r1).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap();
        assert!(d < 1e-5, "{d}");
        assert_ne!(moved.anchors.flatten_all().unwrap().to_vec1::<f32>().unwrap(), an);

        // Person subsets and limits.
        let sub = WindowSet::new(scenes.clone(), &cfg(16, 8, Some(PersonRange { min: 2, max: 2 })), None).unwrap();
        assert_eq!(sub.counts_by_persons(), BTreeMap::from([(2, 4 * 3 + 2)]));
        let lim = WindowSet::new(scenes, &cfg(16, 8, Some(PersonRange { min: 2, max: 2 })), Some(4)).unwrap();
        assert_eq!(lim.len(), 4);
    }

    #[test]
    fn data_errors_are_clear() {
        let scenes = vec![walking_scene("a", 20, 2, 1)];
        let e = WindowSet::new(scenes.clone(), &cfg(32, 4, None), None).unwrap_err().to_string();
        assert!(e.contains("longer than every sequence"), "{e}");
        let e = WindowSet::new(vec![], &cfg(8, 4, None), None).unwrap_err().to_string();
        assert!(e.contains("no scenes"), "{e}");
        let mut valid = Array2::from_elem((20, 2), true);
        for f in 0..20 {
            valid[[f, 1]] = f % 3 != 0;
        }
        let gappy = scenes[0].clone().with_valid(valid).unwrap();
        let e = WindowSet::new(vec![gappy.clone()], &TrainConfig { max_gap: 0, ..cfg(8, 4, None) }, None).unwrap_err().to_string();
        assert!(e.contains("invalid frames"), "{e}");
        // With gap filling (default 10 frames) the windows come back, except the first: a gap at
        // the start of a sequence is never filled.
        assert_eq!(WindowSet::new(vec![gappy], &cfg(8, 4, None), None).unwrap().len(), 3);
    }

    #[test]
    fn mixed_sources_map_joints_and_build_groups() {
        use crate::data::test_util::walkers;
        use crate::data::Skeleton;
        let ds = |name: &str, seqs: Vec<(Split, Scene)>| Dataset {
            name: name.into(),
            sequences: seqs.into_iter().map(|(split, scene)| Sequence { split, scene }).collect(),
            metadata: Default::default(),
        };
        let primary = ds("real", vec![(Split::Train, walkers(50, 3, 0.0)), (Split::Test, walkers(40, 2, 1.0))]);
        // A single-person source on the bandai skeleton at 60 fps: hips, legs and head placed
        // like the walkers' (the joint map copies them by meaning, derives the head top).
        let w = walkers(80, 1, 2.0);
        let m = Skeleton::mupots17();
        let b = crate::data::Skeleton::bandai21();
        let from = [
            ("Hips", "pelvis"),
            ("Spine", "spine"),
            ("Chest", "spine"),
            ("Neck", "neck"),
            ("Head", "head"),
            ("Shoulder_L", "left_shoulder"),
            ("UpperArm_L", "left_shoulder"),
            ("LowerArm_L", "left_elbow"),
            ("Hand_L", "left_wrist"),
            ("Shoulder_R", "right_shoulder"),
            ("UpperArm_R", "right_shoulder"),
            ("LowerArm_R", "right_elbow"),
            ("Hand_R", "right_wrist"),
            ("UpperLeg_L", "left_hip"),
            ("LowerLeg_L", "left_knee"),
            ("Foot_L", "left_ankle"),
            ("Toes_L", "left_ankle"),
            ("UpperLeg_R", "right_hip"),
            ("LowerLeg_R", "right_knee"),
            ("Foot_R", "right_ankle"),
            ("Toes_R", "right_ankle"),
        ];
        let pos = ndarray::Array4::from_shape_fn((80, 1, 21, 3), |(f, p, j, k)| {
            assert_eq!(b.joints[j], from[j].0);
            w.positions[[f, p, m.joint_index(from[j].1).unwrap(), k]]
        });
        let clip = Scene::new("clip", 60.0, b, pos).unwrap();
        let single = ds("single", vec![(Split::Train, clip.clone()), (Split::Test, clip)]);
        let cfg = MixConfig { groups_per_source: 4, groups: GroupConfig { frames: 30, ..Default::default() }, primary_repeat: 2, groups_by_frames: false };
        let (mixed, summary) = mix_sources(&[primary.clone(), single.clone()], &cfg).unwrap();
        assert_eq!(mixed.name, "real+single");
        let train: Vec<&Scene> = mixed.split(Split::Train).collect();
        assert_eq!(train.len(), 2 + 4);
        assert_eq!((train[0].name.as_str(), train[1].name.as_str()), ("walkers", "walkers#2"));
        assert_eq!(mixed.split(Split::Test).count(), 1, "validation comes from the primary only");
        for g in &train[2..] {
            assert_eq!(g.skeleton, m);
            assert_eq!((g.fps, g.num_frames()), (30.0, 30));
            assert!((2..=3).contains(&g.num_persons()));
        }
        assert_eq!(summary.len(), 2);
        assert_eq!((summary[0].kind, summary[0].scenes, summary[0].frames), ("primary", 2, 100));
        assert_eq!((summary[1].kind, summary[1].scenes, summary[1].frames), ("synthetic groups", 4, 120));
        assert!(summary[1].joint_map.iter().any(|l| l.starts_with("head_top ← Head +")), "{:?}", summary[1].joint_map);
        assert_eq!(train_person_range(&primary), (3, 3));
        let d = MixConfig::for_primary(&primary, 128, 7, 5);
        assert_eq!((d.groups.persons_min, d.groups.persons_max, d.groups.frames, d.groups.seed, d.groups_per_source), (3, 3, 300, 5, 7));
        assert_eq!((d.primary_repeat, d.groups_by_frames), (1, false));
        assert_eq!(MixConfig::for_primary(&primary, 512, 7, 5).groups.frames, 1024);
        assert_eq!(
            describe_mix(&["real".into(), "single".into()], &summary, &cfg),
            format!(
                "real (primary: 2 scenes, 100 frames) + single (synthetic groups: 4 scenes, 120 frames); synthetic groups of 2–3 persons × 30 frames, seed {}",
                cfg.groups.seed
            )
        );
        // The mix trains: windows of every group, one skeleton.
        let set = WindowSet::new(train.iter().map(|s| (*s).clone()).collect(), &cfg_of(16, 8), None).unwrap();
        assert!(set.len() >= 4 * 2 + 2 * 5, "{}", set.len());
        // Same config, same mix (the fingerprint of a resumed run matches).
        assert_eq!(mix_sources(&[primary.clone(), single.clone()], &cfg).unwrap().0.sequences[5].scene, mixed.sequences[5].scene);
        // Weighted by seconds of motion: a source with half the seconds gets half the groups.
        let half = ds("half", vec![(Split::Train, single.sequences[0].scene.slice_frames(0, 40).unwrap())]);
        let by_frames = MixConfig { groups_by_frames: true, ..cfg.clone() };
        let (_, summary) = mix_sources(&[primary.clone(), single.clone(), half.clone()], &by_frames).unwrap();
        assert_eq!((summary[1].scenes, summary[2].scenes), (4, 2));
        let (_, summary) = mix_sources(&[primary.clone(), single.clone(), half], &cfg).unwrap();
        assert_eq!((summary[1].scenes, summary[2].scenes), (4, 4));
        // Errors name the problem.
        assert!(mix_sources(&[], &cfg).unwrap_err().to_string().contains("no data sources"));
        let no_train = ds("t", vec![(Split::Test, walkers(10, 1, 0.0))]);
        assert!(mix_sources(&[primary, no_train], &cfg).unwrap_err().to_string().contains("dataset t has no train sequences"));
    }

    fn cfg_of(window: usize, stride: usize) -> TrainConfig {
        cfg(window, stride, None)
    }

    #[test]
    fn stream_rngs_are_independent_and_stable() {
        let a: u64 = stream_rng(1, Stream::Step, 5).gen();
        assert_eq!(a, stream_rng(1, Stream::Step, 5).gen::<u64>());
        assert_ne!(a, stream_rng(1, Stream::Step, 6).gen::<u64>());
        assert_ne!(a, stream_rng(2, Stream::Step, 5).gen::<u64>());
        assert_ne!(a, stream_rng(1, Stream::Augment, 5).gen::<u64>());
    }
}
