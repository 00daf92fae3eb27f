//! SSCP, the social-signal consistency of a haggling triad (METHOD.md §5; REFERENCE.md §5.2):
//! how often the group moves between "who speaks" × "whom the buyer faces" states, compared
//! with real conversations. Only the math lives here: speaking bits and the buyer's role come
//! from annotations (or from classifiers elsewhere).
//!
//! # State of a frame
//! With the speaking bits `L`, `R`, `b` of the left seller, the right seller and the buyer, and
//! `r = 1` when the buyer faces the right seller:
//!
//! ```text
//! state = 2·(L + 2R + 4b) + r ∈ 0..16      names: ",l" ",r" "L,l" "L,r" "R,l" … "LRb,r"
//! ```
//!
//! # Whom the buyer faces
//! The buyer's look direction is the axis between two joints `A → B` in the ground plane,
//! rotated +90° about z: `look = (−(B−A)_y, (B−A)_x)` — for the right-handed z-up frame this
//! is the facing direction when A is the person's left and B its right. A and B are the eyes
//! (`left_eye`, `right_eye`), else the ears, else — for skeletons without either — the hips
//! that define the body frame (then `look` is the body-frame facing, heading + 90°). Each
//! person's position is the nose (else `head`, else `head_top`, else the hip midpoint), in the
//! ground plane. See [`Facing`].
//!
//! Like the reference, each component of the unit look direction is smoothed over time with a
//! Gaussian (σ = 5 frames by default; scipy `gaussian_filter1d`: mode `reflect`, radius
//! `⌊4σ + ½⌋`) and renormalized. Then `att_s = look · unit(pos_s − pos_buyer)` for each
//! seller s, and the buyer faces the right seller unless `att_left > att_right` (an argmax;
//! ties go to the right seller, as in the reference).
//!
//! # Speaking-only states
//! Without attention, the speakers alone give 8 states `L + 2R + 4b` ([`SPEAKING_STATE_NAMES`],
//! the SSCP state halved). [`SpeakingStatistics`] pools their transition counts over speech
//! annotations, e.g. the Haggling speech files ([`SpeakingStatistics::add_speech_file`]).
//!
//! # Transitions and score
//! Per sequence, a 16×16 count matrix of consecutive states `state_t → state_{t+1}` (self-loops
//! included); counts are summed over a set of sequences and divided by their total. The SSCP
//! of a set against a reference set is the Jensen–Shannon distance (natural log,
//! [`super::js_distance`]) between the two flattened 256-entry distributions.

use super::js_distance;
use crate::data::haggling::SpeechFile;
use crate::data::{Scene, Skeleton};
use crate::{bail, Result};
use ndarray::{Array1, Array2, ArrayView2, ArrayView4};

/// Number of SSCP states.
pub const NUM_STATES: usize = 16;

/// Names of the states in index order: speakers (`L`, `R`, `b`), then the seller the buyer
/// faces (`l`, `r`).
pub const STATE_NAMES: [&str; NUM_STATES] =
    [",l", ",r", "L,l", "L,r", "R,l", "R,r", "LR,l", "LR,r", "b,l", "b,r", "Lb,l", "Lb,r", "Rb,l", "Rb,r", "LRb,l", "LRb,r"];

/// State index `2·(L + 2R + 4b) + r` of one frame (module docs).
pub fn state_index(left_speaks: bool, right_speaks: bool, buyer_speaks: bool, faces_right: bool) -> usize {
    2 * (left_speaks as usize + 2 * right_speaks as usize + 4 * buyer_speaks as usize) + faces_right as usize
}

/// Number of speaking-only states.
pub const NUM_SPEAKING_STATES: usize = 8;

/// Names of the speaking-only states in index order (`none`: nobody speaks).
pub const SPEAKING_STATE_NAMES: [&str; NUM_SPEAKING_STATES] = ["none", "L", "R", "LR", "b", "Lb", "Rb", "LRb"];

/// Speaking-only state index `L + 2R + 4b` (module docs).
pub fn speaking_state(left_speaks: bool, right_speaks: bool, buyer_speaks: bool) -> usize {
    left_speaks as usize + 2 * right_speaks as usize + 4 * buyer_speaks as usize
}

/// The three persons of a haggling scene, by index.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Triad {
    /// The seller on the buyer's left.
    pub left: usize,
    /// The seller on the buyer's right.
    pub right: usize,
    /// The buyer.
    pub buyer: usize,
}

impl Triad {
    /// A triad of three distinct persons.
    pub fn new(left: usize, right: usize, buyer: usize) -> Result<Self> {
        if left == right || left == buyer || right == buyer {
            bail!("SSCP triad: persons (left {left}, right {right}, buyer {buyer}) must be distinct");
        }
        Ok(Self { left, right, buyer })
    }

    /// The triad named by the persons' roles `left_seller`, `right_seller` and `buyer` (as the
    /// Haggling importer sets them).
    pub fn from_roles(scene: &Scene) -> Result<Self> {
        let find = |role: &str| {
            let hits: Vec<usize> = scene.persons.iter().enumerate().filter(|(_, p)| p.role.as_deref() == Some(role)).map(|(i, _)| i).collect();
            match hits.as_slice() {
                [i] => Ok(*i),
                _ => Err(crate::Error::invalid(format!("scene {}: {} persons have role {role:?}, need exactly one", scene.name, hits.len()))),
            }
        };
        Self::new(find("left_seller")?, find("right_seller")?, find("buyer")?)
    }

    /// The triad of a three-person scene whose buyer is `buyer`, the sellers told apart by
    /// geometry: the left seller is the one further to the buyer's left (smaller x in the
    /// buyer's body frame, averaged over the frames).
    pub fn from_buyer(scene: &Scene, buyer: usize) -> Result<Self> {
        if scene.num_persons() != 3 || buyer >= 3 {
            bail!("scene {}: a triad needs 3 persons and a buyer among them (persons {}, buyer {buyer})", scene.name, scene.num_persons());
        }
        let (a, b) = match buyer {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        let (l, r) = (scene.skeleton.left, scene.skeleton.right);
        let mut side = 0.0f64; // Σ_t x_a − x_b in the buyer's body frame
        for t in 0..scene.num_frames() {
            let pose = |p: usize| scene.positions.slice(ndarray::s![t, p, .., ..]);
            let centre = |p: usize| {
                let q = pose(p);
                [0.5 * (q[[l, 0]] + q[[r, 0]]) as f64, 0.5 * (q[[l, 1]] + q[[r, 1]]) as f64]
            };
            let q = pose(buyer);
            // The buyer's left→right hip axis is its body-frame +x.
            let axis = unit([(q[[r, 0]] - q[[l, 0]]) as f64, (q[[r, 1]] - q[[l, 1]]) as f64]);
            let (ca, cb) = (centre(a), centre(b));
            side += axis[0] * (ca[0] - cb[0]) + axis[1] * (ca[1] - cb[1]);
        }
        if side < 0.0 {
            Self::new(a, b, buyer)
        } else {
            Self::new(b, a, buyer)
        }
    }

    fn check(&self, persons: usize, what: &str) -> Result<()> {
        if self.left.max(self.right).max(self.buyer) >= persons {
            bail!("{what}: triad {self:?} out of range for {persons} persons");
        }
        Ok(())
    }
}

/// Where a person is and where they look (module docs).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Facing {
    /// The person's left joint of the look axis (left eye, left ear or left hip).
    pub axis_left: usize,
    /// The person's right joint of the look axis.
    pub axis_right: usize,
    /// Joints whose mean ground position is the person's position (nose, or both hips).
    pub position: Vec<usize>,
}

impl Facing {
    /// The facing joints of a skeleton, by name: eyes, else ears, else the body-frame joints;
    /// position nose, else `head`, else `head_top`, else the hip midpoint.
    pub fn for_skeleton(skeleton: &Skeleton) -> Self {
        use crate::data::joints::{find_part, sided_pair, Part, Side};
        let j = &skeleton.joints;
        let (axis_left, axis_right) = sided_pair(j, Part::Eye).or_else(|| sided_pair(j, Part::Ear)).unwrap_or((skeleton.left, skeleton.right));
        let position = match find_part(j, &[(Part::Nose, Side::Centre), (Part::Head, Side::Centre), (Part::HeadTop, Side::Centre)]) {
            Some(i) => vec![i],
            None => vec![skeleton.left, skeleton.right],
        };
        Self { axis_left, axis_right, position }
    }

    /// Unnormalized look direction in the ground plane.
    ///
    /// # Shapes
    /// - `pose`: `[joints, 3]`.
    pub fn look(&self, pose: ArrayView2<f32>) -> [f64; 2] {
        let ax = pose[[self.axis_right, 0]] as f64 - pose[[self.axis_left, 0]] as f64;
        let ay = pose[[self.axis_right, 1]] as f64 - pose[[self.axis_left, 1]] as f64;
        [-ay, ax]
    }

    /// Position in the ground plane.
    ///
    /// # Shapes
    /// - `pose`: `[joints, 3]`.
    pub fn position(&self, pose: ArrayView2<f32>) -> [f64; 2] {
        let n = self.position.len() as f64;
        let sum = |d: usize| self.position.iter().map(|&j| pose[[j, d]] as f64).sum::<f64>() / n;
        [sum(0), sum(1)]
    }
}

fn unit(v: [f64; 2]) -> [f64; 2] {
    let n = v[0].hypot(v[1]);
    if n > 0.0 {
        [v[0] / n, v[1] / n]
    } else {
        [0.0, 0.0]
    }
}

/// Whether a buyer at `buyer` looking along `look` faces the right seller (module docs: the
/// right one unless the left one has the strictly larger `look · unit(seller − buyer)`).
pub fn faces_right_seller(buyer: [f64; 2], look: [f64; 2], left: [f64; 2], right: [f64; 2]) -> bool {
    let att = |s: [f64; 2]| {
        let d = unit([s[0] - buyer[0], s[1] - buyer[1]]);
        look[0] * d[0] + look[1] * d[1]
    };
    // Ties go to the right seller, as in the reference.
    att(left).partial_cmp(&att(right)) != Some(std::cmp::Ordering::Greater)
}

/// scipy `gaussian_filter1d(x, sigma)` with mode `reflect` and truncate 4 (σ ≤ 0: a copy).
pub fn gaussian_smooth(x: &[f64], sigma: f64) -> Vec<f64> {
    if sigma.is_nan() || sigma <= 0.0 || x.is_empty() {
        return x.to_vec();
    }
    let radius = (4.0 * sigma + 0.5) as i64;
    let w: Vec<f64> = (-radius..=radius).map(|i| (-0.5 * (i as f64 / sigma).powi(2)).exp()).collect();
    let total: f64 = w.iter().sum();
    let n = x.len() as i64;
    // reflect: (d c b a | a b c d | d c b a), repeated.
    let at = |i: i64| {
        let m = i.rem_euclid(2 * n);
        x[if m < n { m } else { 2 * n - 1 - m } as usize]
    };
    (0..n).map(|t| (-radius..=radius).zip(&w).map(|(i, wi)| wi * at(t + i)).sum::<f64>() / total).collect()
}

/// SSCP settings.
#[derive(Clone, Debug, PartialEq)]
pub struct SscpConfig {
    /// Scene signal holding the speaking indicator (default `speaking`).
    pub speaking_signal: String,
    /// A person speaks where the signal exceeds this (default 0.5).
    pub speaking_threshold: f32,
    /// σ in frames of the Gaussian smoothing of the look direction (default 5; 0: none).
    pub smoothing_sigma: f64,
}

impl Default for SscpConfig {
    fn default() -> Self {
        Self { speaking_signal: "speaking".into(), speaking_threshold: 0.5, smoothing_sigma: 5.0 }
    }
}

/// Per frame: whether the buyer faces the right seller (module docs).
///
/// # Shapes
/// - `positions`: `[frames, persons, joints, 3]`; output `[frames]`.
pub fn attention(positions: ArrayView4<f32>, triad: &Triad, facing: &Facing, smoothing_sigma: f64) -> Result<Vec<bool>> {
    let (f, p, j, three) = positions.dim();
    if three != 3 || f == 0 {
        bail!("SSCP attention: positions have shape [{f}, {p}, {j}, {three}], expected [frames ≥ 1, persons, joints, 3]");
    }
    triad.check(p, "SSCP attention")?;
    if facing.position.is_empty() || facing.position.iter().chain([&facing.axis_left, &facing.axis_right]).any(|&i| i >= j) {
        bail!("SSCP attention: facing joints {facing:?} out of range for {j} joints");
    }
    let pose = |t: usize, who: usize| positions.slice(ndarray::s![t, who, .., ..]);
    let looks: Vec<[f64; 2]> = (0..f).map(|t| unit(facing.look(pose(t, triad.buyer)))).collect();
    let lx = gaussian_smooth(&looks.iter().map(|l| l[0]).collect::<Vec<_>>(), smoothing_sigma);
    let ly = gaussian_smooth(&looks.iter().map(|l| l[1]).collect::<Vec<_>>(), smoothing_sigma);
    Ok((0..f)
        .map(|t| {
            let look = unit([lx[t], ly[t]]);
            faces_right_seller(facing.position(pose(t, triad.buyer)), look, facing.position(pose(t, triad.left)), facing.position(pose(t, triad.right)))
        })
        .collect())
}

/// State of every frame from speaking indicators and attention.
///
/// # Shapes
/// - `speaking`: `[frames, persons]` (speaks where `> threshold`); `faces_right`: `[frames]`;
///   output `[frames]`.
pub fn states(speaking: ArrayView2<f32>, faces_right: &[bool], triad: &Triad, threshold: f32) -> Result<Vec<usize>> {
    let (f, p) = speaking.dim();
    if f != faces_right.len() {
        bail!("SSCP states: speaking has {f} frames, attention {}", faces_right.len());
    }
    triad.check(p, "SSCP states")?;
    Ok((0..f)
        .map(|t| {
            let s = |who: usize| speaking[[t, who]] > threshold;
            state_index(s(triad.left), s(triad.right), s(triad.buyer), faces_right[t])
        })
        .collect())
}

/// States of a motion sequence (e.g. a forecast) with its speaking indicators.
///
/// # Shapes
/// - `positions`: `[frames, persons, joints, 3]` on `skeleton`; `speaking`: `[frames, persons]`;
///   output `[frames]`.
pub fn sequence_states(positions: ArrayView4<f32>, skeleton: &Skeleton, speaking: ArrayView2<f32>, triad: &Triad, cfg: &SscpConfig) -> Result<Vec<usize>> {
    let att = attention(positions, triad, &Facing::for_skeleton(skeleton), cfg.smoothing_sigma)?;
    states(speaking, &att, triad, cfg.speaking_threshold)
}

/// States of a scene: triad from the persons' roles, speaking from the scene's signal.
pub fn scene_states(scene: &Scene, cfg: &SscpConfig) -> Result<Vec<usize>> {
    let triad = Triad::from_roles(scene)?;
    let Some(speaking) = scene.signals.get(&cfg.speaking_signal) else {
        bail!("scene {}: no signal {:?} (signals: {})", scene.name, cfg.speaking_signal, scene.signals.keys().cloned().collect::<Vec<_>>().join(", "));
    };
    sequence_states(scene.positions.view(), &scene.skeleton, speaking.view(), &triad, cfg)
}

/// Speaking-only state of every frame.
///
/// # Shapes
/// - `speaking`: `[frames, persons]` (speaks where `> threshold`); output `[frames]`.
pub fn speaking_states(speaking: ArrayView2<f32>, triad: &Triad, threshold: f32) -> Result<Vec<usize>> {
    triad.check(speaking.ncols(), "SSCP speaking states")?;
    Ok(speaking.outer_iter().map(|row| speaking_state(row[triad.left] > threshold, row[triad.right] > threshold, row[triad.buyer] > threshold)).collect())
}

/// Speaking-only states of every annotated entry of a Haggling speech file (roles from its
/// `leftSellerId`, `rightSellerId` and `buyerId`).
pub fn speech_file_states(speech: &SpeechFile) -> Result<Vec<usize>> {
    let get = |id: i64, role: &str| {
        speech.speaker(id).map(|s| &s.indicator).ok_or_else(|| crate::Error::invalid(format!("speech file: no speaker with humanId {id} ({role})")))
    };
    let (l, r, b) = (get(speech.left_seller_id, "left seller")?, get(speech.right_seller_id, "right seller")?, get(speech.buyer_id, "buyer")?);
    if l.len() != r.len() || l.len() != b.len() {
        bail!("speech file: indicators of {}, {} and {} entries", l.len(), r.len(), b.len());
    }
    Ok((0..l.len()).map(|t| speaking_state(l[t] > 0.5, r[t] > 0.5, b[t] > 0.5)).collect())
}

/// Transition statistics of the speaking-only states, pooled over sequences.
#[derive(Clone, Debug, PartialEq)]
pub struct SpeakingStatistics {
    /// Pooled transition counts `[8, 8]`, `C[a, b] = #{t : state_t = a, state_{t+1} = b}`.
    pub counts: Array2<f64>,
    /// Frames spent in each state `[8]` (every frame, the last one of a sequence included).
    pub occupancy: Array1<f64>,
    /// `(name, frames)` of every sequence added.
    pub sequences: Vec<(String, usize)>,
}

impl Default for SpeakingStatistics {
    fn default() -> Self {
        Self { counts: Array2::zeros((NUM_SPEAKING_STATES, NUM_SPEAKING_STATES)), occupancy: Array1::zeros(NUM_SPEAKING_STATES), sequences: Vec::new() }
    }
}

impl SpeakingStatistics {
    /// What `socdiff classifier speech-stats` prints: the files, occupancy, transition matrix
    /// and pooled transition distribution.
    pub fn report(&self) -> Result<String> {
        use std::fmt::Write as _;
        let mut out = String::from("speaking-only states: who of left seller (L), right seller (R) and buyer (b) speaks\n");
        for (name, frames) in &self.sequences {
            let _ = writeln!(out, "  {name:<32} {frames} frames");
        }
        let _ = writeln!(out, "transitions   {} (frames − 1 per file, pooled)", self.transitions());
        let row = |values: &[f64]| values.iter().map(|v| format!("{v:>8.4}")).collect::<String>();
        let header: String = SPEAKING_STATE_NAMES.iter().map(|n| format!("{n:>8}")).collect();
        let _ = writeln!(out, "\noccupancy (fraction of frames)\n{header}\n{}", row(&self.occupancy_fraction().to_vec()));
        let matrices = [
            ("transition matrix P(next | current), rows: current state", self.transition_matrix()),
            ("pooled transition distribution C / ΣC (sums to 1)", self.distribution()?),
        ];
        for (title, m) in matrices {
            let _ = writeln!(out, "\n{title}\n{:>6}{header}", "");
            for (name, r) in SPEAKING_STATE_NAMES.iter().zip(m.outer_iter()) {
                let _ = writeln!(out, "{name:>6}{}", row(&r.to_vec()));
            }
        }
        Ok(out)
    }

    /// Adds one sequence of speaking-only states.
    pub fn add(&mut self, name: impl Into<String>, states: &[usize]) -> Result<()> {
        let c = count_transitions(states, NUM_SPEAKING_STATES)?;
        self.counts += &c;
        for &s in states {
            self.occupancy[s] += 1.0;
        }
        self.sequences.push((name.into(), states.len()));
        Ok(())
    }

    /// Adds every annotated entry of a Haggling speech file ([`speech_file_states`]).
    pub fn add_speech_file(&mut self, name: impl Into<String>, speech: &SpeechFile) -> Result<()> {
        self.add(name, &speech_file_states(speech)?)
    }

    /// Total number of transitions (Σ frames − 1 over the sequences).
    pub fn transitions(&self) -> f64 {
        self.counts.sum()
    }

    /// Pooled transition distribution `C / ΣC` `[8, 8]` (the speaking-only analogue of
    /// [`transition_distribution`]).
    pub fn distribution(&self) -> Result<Array2<f64>> {
        let total = self.transitions();
        if total <= 0.0 {
            bail!("speaking statistics: no transitions in {} sequence(s)", self.sequences.len());
        }
        Ok(&self.counts / total)
    }

    /// Transition matrix `P[a, b] = C[a, b] / Σ_b C[a, b]` `[8, 8]`: each row of a state that is
    /// ever left sums to 1; rows of states never seen (or only at a sequence end) are 0.
    pub fn transition_matrix(&self) -> Array2<f64> {
        let mut p = self.counts.clone();
        for mut row in p.rows_mut() {
            let n = row.sum();
            if n > 0.0 {
                row /= n;
            }
        }
        p
    }

    /// Fraction of frames in each state `[8]`.
    pub fn occupancy_fraction(&self) -> Array1<f64> {
        let n = self.occupancy.sum();
        if n > 0.0 {
            &self.occupancy / n
        } else {
            self.occupancy.clone()
        }
    }
}

/// `C[a, b] = #{t : state_t = a, state_{t+1} = b}` over `n` states.
fn count_transitions(states: &[usize], n: usize) -> Result<Array2<f64>> {
    if let Some(s) = states.iter().find(|&&s| s >= n) {
        bail!("SSCP: state {s} out of range 0..{n}");
    }
    let mut c = Array2::zeros((n, n));
    for w in states.windows(2) {
        c[[w[0], w[1]]] += 1.0;
    }
    Ok(c)
}

/// Transition counts `C[a, b] = #{t : state_t = a, state_{t+1} = b}`.
///
/// # Shapes
/// - `states`: `[frames]`, each `< 16`; output `[16, 16]`.
pub fn transition_counts(states: &[usize]) -> Result<Array2<f64>> {
    count_transitions(states, NUM_STATES)
}

/// Pooled, normalized transition distribution of a set of sequences (sums to 1).
///
/// # Shapes
/// - each of `counts`: `[16, 16]`; output `[16, 16]`.
pub fn transition_distribution(counts: &[Array2<f64>]) -> Result<Array2<f64>> {
    let mut sum = Array2::<f64>::zeros((NUM_STATES, NUM_STATES));
    for c in counts {
        if c.dim() != (NUM_STATES, NUM_STATES) {
            bail!("SSCP: a count matrix has shape {:?}, expected [16, 16]", c.dim());
        }
        sum += c;
    }
    let total = sum.sum();
    if total.is_nan() || total <= 0.0 {
        bail!("SSCP: no transitions in {} sequence(s)", counts.len());
    }
    Ok(sum / total)
}

/// SSCP: Jensen–Shannon distance (natural log) between two transition distributions.
///
/// # Shapes
/// - `reference`, `other`: `[16, 16]`.
pub fn sscp_distance(reference: &Array2<f64>, other: &Array2<f64>) -> Result<f64> {
    if reference.dim() != (NUM_STATES, NUM_STATES) || other.dim() != (NUM_STATES, NUM_STATES) {
        bail!("SSCP: distributions have shapes {:?} and {:?}, expected [16, 16]", reference.dim(), other.dim());
    }
    js_distance(&reference.iter().copied().collect::<Vec<_>>(), &other.iter().copied().collect::<Vec<_>>())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::data::Person;
    use crate::metrics::JS_DISTANCE_MAX;
    use ndarray::{Array2, Array4};

    #[test]
    fn state_indices_match_names() {
        for (i, want) in STATE_NAMES.iter().enumerate() {
            let (l, r, b, fr) = (i & 2 != 0, i & 4 != 0, i & 8 != 0, i & 1 != 0);
            assert_eq!(state_index(l, r, b, fr), i);
            let name = format!("{}{}{},{}", if l { "L" } else { "" }, if r { "R" } else { "" }, if b { "b" } else { "" }, if fr { "r" } else { "l" });
            assert_eq!(*want, name);
        }
        assert_eq!(state_index(true, false, true, true), 11);
    }

    /// States 0 → 1 → 1 → 5 → 0 → 1: transitions (0,1) twice, (1,1), (1,5), (5,0) once each.
    #[test]
    fn hand_built_sequence_gives_known_matrix() {
        let c = transition_counts(&[0, 1, 1, 5, 0, 1]).unwrap();
        let mut want = Array2::<f64>::zeros((16, 16));
        want[[0, 1]] = 2.0;
        want[[1, 1]] = 1.0;
        want[[1, 5]] = 1.0;
        want[[5, 0]] = 1.0;
        assert_eq!(c, want);
        let d = transition_distribution(&[c.clone(), transition_counts(&[3, 3, 3]).unwrap()]).unwrap();
        assert_eq!(d[[0, 1]], 2.0 / 7.0);
        assert_eq!(d[[3, 3]], 2.0 / 7.0);
        assert!((d.sum() - 1.0).abs() < 1e-15);
        assert!(transition_counts(&[16]).is_err());
        assert!(transition_distribution(&[transition_counts(&[4]).unwrap()]).is_err());
    }

    #[test]
    fn sscp_distance_extremes() {
        let a = transition_distribution(&[transition_counts(&[0, 1, 1, 5, 0]).unwrap()]).unwrap();
        assert_eq!(sscp_distance(&a, &a).unwrap(), 0.0);
        let b = transition_distribution(&[transition_counts(&[7, 7, 9]).unwrap()]).unwrap();
        let d = sscp_distance(&a, &b).unwrap();
        assert!((d - JS_DISTANCE_MAX).abs() < 1e-15, "{d}");
        assert!((d - 0.832_554_611_157_697_7).abs() < 1e-12);
    }

    /// A Panoptic-19 pose standing at `at`, facing the ground direction `phi` (radians).
    fn panoptic_pose(at: [f32; 2], phi: f32) -> Vec<[f32; 3]> {
        panoptic_pose_with(at, phi, 0.0, 0.0)
    }

    /// [`panoptic_pose`] with the head (nose, eyes, ears) turned by `head_yaw` radians to the
    /// left and the right wrist raised by `wrist_lift` metres.
    pub(crate) fn panoptic_pose_with(at: [f32; 2], phi: f32, head_yaw: f32, wrist_lift: f32) -> Vec<[f32; 3]> {
        // Body coordinates: x to the person's right, y forward, z up; `turn` rotates the head.
        let place = |x: f32, y: f32, z: f32, turn: f32| {
            let (s, c) = (phi + turn).sin_cos();
            [at[0] + x * s + y * c, at[1] - x * c + y * s, z]
        };
        let (body, head) = (|x, y, z| place(x, y, z, 0.0), |x, y, z| place(x, y, z, head_yaw));
        let sk = Skeleton::panoptic19();
        sk.joints
            .iter()
            .map(|n| match n.as_str() {
                "nose" => head(0.0, 0.1, 1.6),
                "left_eye" => head(-0.03, 0.08, 1.65),
                "right_eye" => head(0.03, 0.08, 1.65),
                "left_ear" => head(-0.07, 0.0, 1.63),
                "right_ear" => head(0.07, 0.0, 1.63),
                "right_wrist" => body(0.15, 0.0, 1.0 + wrist_lift),
                n if n.starts_with("left") => body(-0.15, 0.0, 1.0),
                n if n.starts_with("right") => body(0.15, 0.0, 1.0),
                _ => body(0.0, 0.0, 1.3),
            })
            .collect()
    }

    fn triad_scene(buyer_phi: &[f32], skeleton: Skeleton) -> Scene {
        let f = buyer_phi.len();
        let nj = skeleton.num_joints();
        // Buyer at the origin; left seller at (−2, 2), right seller at (2, 2) (seen from a buyer
        // facing +y, the left seller is on the left).
        let places = [([-2.0f32, 2.0], -std::f32::consts::FRAC_PI_4), ([2.0, 2.0], std::f32::consts::PI + 0.7), ([0.0, 0.0], 0.0)];
        let mut pos = Array4::<f32>::zeros((f, 3, nj, 3));
        for t in 0..f {
            for (p, &(at, phi)) in places.iter().enumerate() {
                let phi = if p == 2 { buyer_phi[t] } else { phi };
                let pose = panoptic_pose(at, phi);
                for j in 0..nj {
                    let src = if skeleton.name == "panoptic19" {
                        pose[j]
                    } else {
                        // MuPoTS: reuse the Panoptic hips for its hips, the nose for its head.
                        let pan = Skeleton::panoptic19();
                        let name = &skeleton.joints[j];
                        pan.joint_index(name).map(|i| pose[i]).unwrap_or(pose[1])
                    };
                    for d in 0..3 {
                        pos[[t, p, j, d]] = src[d];
                    }
                }
            }
        }
        let roles = ["left_seller", "right_seller", "buyer"];
        Scene::new("triad", 30.0, skeleton, pos)
            .unwrap()
            .with_persons(roles.iter().enumerate().map(|(i, r)| Person { id: i.to_string(), role: Some(r.to_string()) }).collect())
            .unwrap()
    }

    /// The buyer's facing angle φ (0 = +x) sweeps: toward the right seller (φ = 45°) → right;
    /// toward the left seller (135°) → left; on Panoptic (eyes) and MuPoTS (hips) alike.
    #[test]
    fn attention_follows_the_buyers_face() {
        let deg = |d: f32| d.to_radians();
        let phis = [deg(45.0), deg(135.0), deg(10.0), deg(170.0), deg(80.0), deg(100.0)];
        let want = [true, false, true, false, true, false];
        for sk in [Skeleton::panoptic19(), Skeleton::mupots17()] {
            let scene = triad_scene(&phis, sk);
            let triad = Triad::from_roles(&scene).unwrap();
            assert_eq!(triad, Triad { left: 0, right: 1, buyer: 2 });
            let facing = Facing::for_skeleton(&scene.skeleton);
            let att = attention(scene.positions.view(), &triad, &facing, 0.0).unwrap();
            assert_eq!(att, want, "{}", scene.skeleton.name);
        }
        let f = Facing::for_skeleton(&Skeleton::panoptic19());
        assert_eq!((f.axis_left, f.axis_right, f.position.clone()), (15, 17, vec![1]));
        let f = Facing::for_skeleton(&Skeleton::mupots17());
        assert_eq!((f.axis_left, f.axis_right, f.position.clone()), (11, 8, vec![16]));
        // Direct: looking along +x from the origin, sellers at (1, 1) and (1, −1).
        assert!(faces_right_seller([0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [1.0, -0.9]));
        assert!(!faces_right_seller([0.0, 0.0], [1.0, 0.0], [1.0, 0.9], [1.0, -1.0]));
    }

    #[test]
    fn scene_states_combine_speech_and_attention() {
        let deg = |d: f32| d.to_radians();
        let scene = triad_scene(&[deg(45.0), deg(135.0), deg(135.0)], Skeleton::panoptic19());
        // Frame 0: left seller speaks; 1: buyer and right seller; 2: nobody.
        let speaking = ndarray::array![[1.0f32, 0.0, 0.0], [0.0, 1.0, 1.0], [0.0, 0.0, 0.0]];
        let scene = scene.with_signal("speaking", speaking).unwrap();
        let cfg = SscpConfig { smoothing_sigma: 0.0, ..Default::default() };
        let s = scene_states(&scene, &cfg).unwrap();
        assert_eq!(s, vec![3, 12, 0]);
        assert_eq!([STATE_NAMES[3], STATE_NAMES[12], STATE_NAMES[0]], ["L,r", "Rb,l", ",l"]);
        let mut bare = scene.clone();
        bare.signals.clear();
        assert!(scene_states(&bare, &cfg).unwrap_err().to_string().contains("speaking"));
    }

    /// The buyer's body faces the left seller but its head turns to the right seller: attention
    /// follows the face (eye axis), not the hips.
    #[test]
    fn attention_follows_the_face_not_the_body() {
        let deg = |d: f32| d.to_radians();
        let mut scene = triad_scene(&[deg(135.0), deg(135.0)], Skeleton::panoptic19());
        for t in 0..2 {
            let pose = panoptic_pose_with([0.0, 0.0], deg(135.0), if t == 0 { deg(-90.0) } else { 0.0 }, 0.0);
            for (j, xyz) in pose.iter().enumerate() {
                for (d, &v) in xyz.iter().enumerate() {
                    scene.positions[[t, 2, j, d]] = v;
                }
            }
        }
        let triad = Triad::from_roles(&scene).unwrap();
        let att = attention(scene.positions.view(), &triad, &Facing::for_skeleton(&scene.skeleton), 0.0).unwrap();
        assert_eq!(att, vec![true, false]);
    }

    #[test]
    fn triad_from_buyer_tells_left_from_right_by_geometry() {
        let scene = triad_scene(&[0.9, 1.2, 1.5], Skeleton::panoptic19());
        assert_eq!(Triad::from_buyer(&scene, 2).unwrap(), Triad { left: 0, right: 1, buyer: 2 });
        // Persons reordered (buyer first, then right, then left seller).
        let re = scene.select_persons(&[2, 1, 0]).unwrap();
        assert_eq!(Triad::from_buyer(&re, 0).unwrap(), Triad { left: 2, right: 1, buyer: 0 });
        assert!(Triad::from_buyer(&scene, 3).is_err());
        assert!(Triad::from_buyer(&scene.select_persons(&[0, 1]).unwrap(), 0).is_err());
    }

    #[test]
    fn speaking_states_and_statistics_of_a_hand_built_timeline() {
        for (i, name) in STATE_NAMES.iter().enumerate() {
            let (l, r, b) = (i & 2 != 0, i & 4 != 0, i & 8 != 0);
            assert_eq!(2 * speaking_state(l, r, b) + (i & 1), i);
            assert_eq!(SPEAKING_STATE_NAMES[speaking_state(l, r, b)].trim_start_matches("none"), name.split(',').next().unwrap());
        }
        // Persons (buyer, left, right): frames none, L, L, Lb, b.
        let speaking = ndarray::array![[0.0f32, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, 0.0, 0.0]];
        let triad = Triad::new(1, 2, 0).unwrap();
        let states = speaking_states(speaking.view(), &triad, 0.5).unwrap();
        assert_eq!(states, vec![0, 1, 1, 5, 4]);
        let mut st = SpeakingStatistics::default();
        st.add("a", &states).unwrap();
        st.add("b", &[4, 4]).unwrap();
        assert_eq!(st.transitions(), 5.0);
        let d = st.distribution().unwrap();
        assert_eq!((d[[0, 1]], d[[1, 1]], d[[1, 5]], d[[5, 4]], d[[4, 4]]), (0.2, 0.2, 0.2, 0.2, 0.2));
        let p = st.transition_matrix();
        assert_eq!((p[[1, 1]], p[[1, 5]], p[[4, 4]], p[[7, 7]]), (0.5, 0.5, 1.0, 0.0));
        assert_eq!(st.occupancy.to_vec(), vec![1.0, 2.0, 0.0, 0.0, 3.0, 1.0, 0.0, 0.0]);
        assert!(st.add("bad", &[8]).is_err());
        assert!(SpeakingStatistics::default().distribution().is_err());
    }

    /// The six real Haggling speech files: one transition per pair of consecutive annotated
    /// frames, rows of the transition matrix sum to 1, the distribution sums to 1; the pooled
    /// statistics are printed.
    #[test]
    fn speaking_statistics_of_the_real_speech_files() {
        let dir = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/haggling_speech"));
        if !dir.is_dir() {
            crate::testing::skip_absent(dir, "real Haggling speech files");
            return;
        }
        let mut files: Vec<_> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|e| e == "pkl")).collect();
        files.sort();
        assert_eq!(files.len(), 6);
        let mut st = SpeakingStatistics::default();
        let mut want_transitions = 0.0;
        for f in &files {
            let sp = crate::data::haggling::load_speech(f).unwrap();
            let before = st.transitions();
            st.add_speech_file(f.file_stem().unwrap().to_string_lossy(), &sp).unwrap();
            let n = sp.num_entries();
            assert_eq!(st.transitions() - before, (n - 1) as f64, "{}", f.display());
            assert_eq!(n as i64, sp.end_frame - sp.start_frame + 1);
            want_transitions += (n - 1) as f64;
        }
        assert_eq!(st.transitions(), want_transitions);
        assert_eq!(st.occupancy.sum(), want_transitions + 6.0);
        let d = st.distribution().unwrap();
        assert!((d.sum() - 1.0).abs() < 1e-12);
        let p = st.transition_matrix();
        for (a, row) in p.rows().into_iter().enumerate() {
            if st.counts.row(a).sum() > 0.0 {
                assert!((row.sum() - 1.0).abs() < 1e-12, "row {a}");
            }
        }
        // Real conversations: nobody-speaks and single-speaker states dominate and persist.
        let occ = st.occupancy_fraction();
        assert!(occ[0] + occ[1] + occ[2] + occ[4] > 0.8, "{occ:?}");
        for s in [0, 1, 2, 4] {
            assert!(p[[s, s]] > 0.9, "state {} persists: {}", SPEAKING_STATE_NAMES[s], p[[s, s]]);
        }
        eprintln!("speaking-only transitions over {} files, {} transitions:", files.len(), st.transitions());
        eprintln!("occupancy {:?}", occ.iter().map(|v| format!("{v:.4}")).collect::<Vec<_>>());
        eprintln!("P(next | current):\n{:.4}", p);
    }

    #[test]
    fn gaussian_smoothing_matches_scipy_semantics() {
        let c = vec![0.7; 9];
        assert!(gaussian_smooth(&c, 5.0).iter().all(|v| (v - 0.7).abs() < 1e-15));
        // σ = 0.5: radius 2, weights e^{-2·i²}; at the left edge reflect gives x[-1] = x[0],
        // x[-2] = x[1]. For x = (1, 0, 0, 0, 0): y0 = (w0 + w1)/W (x[0] and x[-1]) + w2·x[1]=0.
        let x = [1.0, 0.0, 0.0, 0.0, 0.0];
        let w: Vec<f64> = (0..3).map(|i| (-2.0 * (i * i) as f64).exp()).collect();
        let total = w[0] + 2.0 * w[1] + 2.0 * w[2];
        let y = gaussian_smooth(&x, 0.5);
        assert!((y[0] - (w[0] + w[1]) / total).abs() < 1e-15);
        assert!((y[1] - (w[1] + w[2]) / total).abs() < 1e-15); // x[0] at offset −1, x[-1] = x[0] at −2
        assert!((y[2] - w[2] / total).abs() < 1e-15);
        assert_eq!(y[3], 0.0);
        assert!((y.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }
}
