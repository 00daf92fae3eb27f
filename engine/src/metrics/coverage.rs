//! Coverage and collapse: precision and recall of motion words (Kynkäänniemi et al., NeurIPS
//! 2019, "Improved precision and recall metric for assessing generative models").
//!
//! The real words `R` and the generated words `G` (NDMS words, [`super::ndms`]) each span a
//! manifold: the union of balls around every word with the distance to its k-th nearest other
//! word of the same set as radius. Then
//!
//! ```text
//! precision = |{g ∈ G : ∃ r ∈ R, ‖g − r‖ ≤ ρ_k(r)}| / |G|    (generated motion looks real)
//! recall    = |{r ∈ R : ∃ g ∈ G, ‖r − g‖ ≤ ρ_k(g)}| / |R|    (the real motion is covered)
//! ```
//!
//! A model that collapses onto the commonest motion keeps a high precision and loses recall.
//! Distances are Euclidean over the word's values (positions in the body frame of its first
//! frame, metres), exact and brute force in f64; each set is thinned to at most
//! [`CoverageConfig::max_words`] evenly spaced words first (the cost is quadratic).
//!
//! Words are not independent samples: a word and the word one frame later of the same person
//! are nearly equal, so the k-th neighbour would almost always be the same motion shifted by a
//! frame or two and every radius would shrink to nothing. A word's neighbours for its radius
//! are therefore only words that do not overlap it in time: another track, or the same track
//! at least [`Origin`]'s `exclude` frames away (a word length).

use crate::{bail, Result};
use ndarray::{Array2, ArrayView2, Axis};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Settings of [`precision_recall`].
#[derive(Clone, Debug, PartialEq)]
pub struct CoverageConfig {
    /// k of the k-NN radius (the paper's default 3).
    pub k: usize,
    /// Most words kept of each set (evenly spaced rows; default 3 000).
    pub max_words: usize,
    /// Frames between the starts of the words taken from scored motion (default 5, half a word
    /// at 30 fps).
    pub word_stride: usize,
}

impl Default for CoverageConfig {
    fn default() -> Self {
        Self { k: 3, max_words: 3000, word_stride: 5 }
    }
}

/// Precision and recall of one generated set against a real one.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Coverage {
    /// Fraction of generated words inside the real manifold.
    pub precision: f64,
    /// Fraction of real words inside the generated manifold.
    pub recall: f64,
    /// Real words used (after thinning).
    pub real_words: usize,
    /// Generated words used (after thinning).
    pub generated_words: usize,
    /// k of the radius.
    pub k: usize,
}

/// Where a word comes from: its track (one person of one sequence or sample) and first frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Origin {
    /// Track id (any number unique per track within one set).
    pub track: usize,
    /// First frame of the word in its track.
    pub frame: usize,
}

/// At most `max` of the indices `0..n`, evenly spaced (all of them when `n ≤ max`).
pub fn thin(n: usize, max: usize) -> Vec<usize> {
    if n <= max {
        return (0..n).collect();
    }
    (0..max).map(|i| i * n / max).collect()
}

fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>().sqrt()
}

/// Distance from every row to its k-th nearest row that does not overlap it in time (module
/// docs): rows of another track, or of the same track `exclude` or more frames away.
///
/// # Shapes
/// - `words`: `[n, D]`, `origins`: `[n]`; output `[n]`.
pub fn knn_radii(words: ArrayView2<f64>, origins: &[Origin], exclude: usize, k: usize) -> Result<Vec<f64>> {
    let n = words.nrows();
    if origins.len() != n {
        bail!("k-NN radius: {n} words and {} origins", origins.len());
    }
    if k == 0 {
        bail!("k-NN radius: k must be at least 1");
    }
    let w = words.as_standard_layout();
    let rows: Vec<&[f64]> = w.axis_iter(Axis(0)).map(|r| r.to_slice().expect("standard layout")).collect();
    let far = |i: usize, j: usize| origins[i].track != origins[j].track || origins[i].frame.abs_diff(origins[j].frame) >= exclude;
    (0..n)
        .into_par_iter()
        .map(|i| {
            let mut d: Vec<f64> = (0..n).filter(|&j| j != i && far(i, j)).map(|j| dist(rows[i], rows[j])).collect();
            if d.len() < k {
                bail!("k-NN radius: word {i} has {} words that do not overlap it in time, fewer than k = {k}", d.len());
            }
            let (_, kth, _) = d.select_nth_unstable_by(k - 1, f64::total_cmp);
            Ok(*kth)
        })
        .collect()
}

/// Fraction of `queries` rows within `radii[j]` of some row `j` of `manifold`.
fn inside(queries: ArrayView2<f64>, manifold: ArrayView2<f64>, radii: &[f64]) -> f64 {
    let (q, m) = (queries.as_standard_layout(), manifold.as_standard_layout());
    let mrows: Vec<&[f64]> = m.axis_iter(Axis(0)).map(|r| r.to_slice().expect("standard layout")).collect();
    let qrows: Vec<&[f64]> = q.axis_iter(Axis(0)).map(|r| r.to_slice().expect("standard layout")).collect();
    let hits = qrows.par_iter().filter(|row| mrows.iter().zip(radii).any(|(r, &rad)| dist(row, r) <= rad)).count();
    hits as f64 / q.nrows() as f64
}

/// One set of words with their origins.
#[derive(Clone, Copy, Debug)]
pub struct Words<'a> {
    /// `[n, D]`.
    pub values: ArrayView2<'a, f64>,
    /// `[n]`.
    pub origins: &'a [Origin],
}

/// One set of words, thinned to [`CoverageConfig::max_words`], with every word's k-NN radius
/// (module docs): built once per set, so a reference serves any number of generated sets.
#[derive(Clone, Debug)]
pub struct Manifold {
    values: Array2<f64>,
    radii: Vec<f64>,
    k: usize,
}

impl Manifold {
    /// Thins `words` to `cfg.max_words` rows and measures their radii; `exclude`: frames within
    /// which a word of the same track overlaps (the word length). `what` names the set in errors.
    ///
    /// # Shapes
    /// - `words.values`: `[n, D]`, finite.
    pub fn new(words: Words, exclude: usize, cfg: &CoverageConfig, what: &str) -> Result<Self> {
        if cfg.max_words <= cfg.k {
            bail!("coverage: max_words {} must exceed k = {}", cfg.max_words, cfg.k);
        }
        if words.values.iter().any(|v| !v.is_finite()) {
            bail!("coverage: {what} words hold non-finite values");
        }
        let rows = thin(words.values.nrows(), cfg.max_words);
        let values = words.values.select(Axis(0), &rows);
        let origins: Vec<Origin> = rows.iter().map(|&i| words.origins[i]).collect();
        let radii = knn_radii(values.view(), &origins, exclude, cfg.k).map_err(|e| crate::Error::invalid(format!("coverage, {what} words: {e}")))?;
        Ok(Self { values, radii, k: cfg.k })
    }

    /// Words kept.
    pub fn len(&self) -> usize {
        self.values.nrows()
    }

    /// True when no word is kept.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Precision and recall of `generated` against `real` (module docs).
pub fn precision_recall(real: &Manifold, generated: &Manifold) -> Result<Coverage> {
    if real.values.ncols() != generated.values.ncols() {
        bail!("coverage: real words have {} values, generated words {}", real.values.ncols(), generated.values.ncols());
    }
    if real.k != generated.k {
        bail!("coverage: radii at k = {} (real) and k = {} (generated)", real.k, generated.k);
    }
    Ok(Coverage {
        precision: inside(generated.values.view(), real.values.view(), &real.radii),
        recall: inside(real.values.view(), generated.values.view(), &generated.radii),
        real_words: real.len(),
        generated_words: generated.len(),
        k: real.k,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn col(v: &[f64]) -> Array2<f64> {
        Array2::from_shape_vec((v.len(), 1), v.to_vec()).unwrap()
    }

    /// Every word its own track: no temporal exclusion.
    fn apart(n: usize) -> Vec<Origin> {
        (0..n).map(|track| Origin { track, frame: 0 }).collect()
    }

    fn pr(real: &Array2<f64>, gen: &Array2<f64>, cfg: &CoverageConfig) -> Result<Coverage> {
        let (ro, go) = (apart(real.nrows()), apart(gen.nrows()));
        let real = Manifold::new(Words { values: real.view(), origins: &ro }, 1, cfg, "real")?;
        precision_recall(&real, &Manifold::new(Words { values: gen.view(), origins: &go }, 1, cfg, "generated")?)
    }

    #[test]
    fn radii_are_the_kth_neighbour_distance() {
        // 0, 1, 3, 7: nearest others 1, 1, 2, 4; second nearest 3, 2, 3, 6.
        let w = col(&[0.0, 1.0, 3.0, 7.0]);
        assert_eq!(knn_radii(w.view(), &apart(4), 1, 1).unwrap(), [1.0, 1.0, 2.0, 4.0]);
        assert_eq!(knn_radii(w.view(), &apart(4), 1, 2).unwrap(), [3.0, 2.0, 3.0, 6.0]);
        assert!(knn_radii(w.view(), &apart(4), 1, 4).unwrap_err().to_string().contains("fewer than k = 4"));
    }

    #[test]
    fn overlapping_words_of_one_track_are_not_neighbours() {
        // One track, words at frames 0..4 with values 0, 0.1, 0.2, 5, 5.1; exclusion 2 frames:
        // word 0's admissible neighbours are frames 2, 3, 4 → nearest 0.2.
        let w = col(&[0.0, 0.1, 0.2, 5.0, 5.1]);
        let one: Vec<Origin> = (0..5).map(|frame| Origin { track: 0, frame }).collect();
        let r = knn_radii(w.view(), &one, 2, 1).unwrap();
        let want = [0.2, 4.9, 0.2, 4.9, 4.9];
        assert!(r.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-12), "{r:?}");
        // Without exclusion (1 frame: only the word itself) the neighbours are one frame away.
        let r1 = knn_radii(w.view(), &one, 1, 1).unwrap();
        assert!((r1[0] - 0.1).abs() < 1e-12 && (r1[4] - 0.1).abs() < 1e-12, "{r1:?}");
    }

    #[test]
    fn worked_example_by_hand() {
        // Real 0..3 (radii 1 at k = 1); generated {0.5, 10} (radii 9.5 each).
        // Precision: 0.5 lies within 1 of 0 and of 1; 10 lies within no real ball → 1/2.
        // Recall: every real point is within 9.5 of 0.5 → 4/4.
        let cfg = CoverageConfig { k: 1, max_words: 100, ..Default::default() };
        let c = pr(&col(&[0.0, 1.0, 2.0, 3.0]), &col(&[0.5, 10.0]), &cfg).unwrap();
        assert_eq!((c.precision, c.recall, c.real_words, c.generated_words), (0.5, 1.0, 4, 2));
    }

    #[test]
    fn a_collapsed_set_keeps_precision_and_loses_recall() {
        // Real: two clusters in 2-D; generated: all inside the first cluster.
        let mut real = Vec::new();
        for i in 0..20 {
            let a = i as f64 * 0.3;
            real.extend([a.cos() * 0.1, a.sin() * 0.1]);
            real.extend([5.0 + a.cos() * 0.1, a.sin() * 0.1]);
        }
        let real = Array2::from_shape_vec((40, 2), real).unwrap();
        // Generated: the first cluster's words, moved by 1 mm.
        let gen = Array2::from_shape_fn((20, 2), |(i, d)| real[[2 * i, d]] + 0.001);
        let cfg = CoverageConfig::default();
        let c = pr(&real, &gen, &cfg).unwrap();
        assert_eq!(c.precision, 1.0);
        assert_eq!(c.recall, 0.5, "{c:?}");
        // The same set against itself: every word lies in its own ball.
        let s = pr(&real, &real, &cfg).unwrap();
        assert_eq!((s.precision, s.recall), (1.0, 1.0));
    }

    #[test]
    fn thinning_is_even_and_bounded() {
        assert_eq!(thin(5, 10), [0, 1, 2, 3, 4]);
        assert_eq!(thin(10, 4), [0, 2, 5, 7]);
        let c = CoverageConfig { k: 1, max_words: 3, ..Default::default() };
        let r = pr(&col(&[0.0, 1.0, 2.0, 3.0, 4.0, 5.0]), &col(&[0.0, 1.0, 2.0, 3.0]), &c).unwrap();
        assert_eq!((r.real_words, r.generated_words), (3, 3));
        assert!(pr(&col(&[0.0, 1.0]), &Array2::zeros((2, 2)), &c).unwrap_err().to_string().contains("1 values"));
    }
}
