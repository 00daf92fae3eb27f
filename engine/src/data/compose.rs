//! Groups composed from recorded scenes (`socdiff data compose`): the persons of several scenes
//! of one or more datasets in one scene, placed on a circle, on a line or where they were
//! recorded, with no two bodies of different scenes closer than a minimum distance.

use super::dataset::Split;
use super::scene::Scene;
use crate::{bail, Result};
use ndarray::s;

/// Where each scene of a composition goes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Placement {
    /// On a circle, neighbouring scenes `spacing` apart (each keeps its own layout and
    /// headings; its first person's first-frame body centre on the circle).
    #[default]
    Circle,
    /// On a line along x, `spacing` apart.
    Line,
    /// Where they were recorded (their coordinates as they are).
    Recorded,
}

/// One scene of a composition and where it came from.
#[derive(Clone, Debug)]
pub struct Part {
    /// The scene (its persons already selected).
    pub scene: Scene,
    /// Its split in its dataset.
    pub split: Split,
}

/// How [`compose`] places its parts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Composition {
    /// Where the scenes go.
    pub placement: Placement,
    /// Metres between neighbouring scenes (circle, line).
    pub spacing: f32,
    /// The closest two bodies of different scenes may come, metres (body centres, horizontally,
    /// on any frame).
    pub min_distance: f32,
    /// Allow scenes of different splits (the result is then in the train split).
    pub mix_splits: bool,
}

impl Default for Composition {
    fn default() -> Self {
        Self { placement: Placement::Circle, spacing: 1.5, min_distance: 0.5, mix_splits: false }
    }
}

/// One scene holding the persons of every part (as long as the shortest), and its split.
/// Errors: parts of different splits (unless allowed), skeletons or frame rates that differ,
/// bodies of different parts closer than the minimum distance (naming them and the frame).
pub fn compose(name: &str, parts: &[Part], how: &Composition) -> Result<(Scene, Split)> {
    if parts.is_empty() {
        bail!("compose {name}: no scenes");
    }
    if !(how.spacing.is_finite() && how.spacing >= 0.0 && how.min_distance.is_finite() && how.min_distance >= 0.0) {
        bail!("compose {name}: `spacing` and `min_distance` must be non-negative metres");
    }
    let split = parts[0].split;
    if let Some(p) = parts.iter().find(|p| p.split != split) {
        if !how.mix_splits {
            bail!(
                "compose {name}: {} is in the {} split, {} in the {} split; mixing splits leaks test motion into training (`mix_splits` allows it)",
                parts[0].scene.name,
                split.as_str(),
                p.scene.name,
                p.split.as_str()
            );
        }
    }
    let split = if parts.iter().all(|p| p.split == split) { split } else { Split::Train };
    let scenes: Vec<Scene> = parts.iter().map(|p| p.scene.clone()).collect();
    let mut scene = match how.placement {
        Placement::Circle => Scene::around_circle(name, &scenes, how.spacing)?,
        Placement::Recorded => Scene::combine(name, &scenes, &vec![[0.0; 3]; scenes.len()])?,
        Placement::Line => {
            let n = scenes.len();
            let offsets: Vec<[f32; 3]> = scenes
                .iter()
                .enumerate()
                .map(|(i, s)| {
                    let (c, _) = body_centre(s, 0, 0);
                    let x = (i as f32 - (n as f32 - 1.0) / 2.0) * how.spacing;
                    [x - c[0], -c[1], 0.0]
                })
                .collect();
            Scene::combine(name, &scenes, &offsets)?
        }
    };
    // Which part each person of the result came from.
    let owner: Vec<usize> = parts.iter().enumerate().flat_map(|(i, p)| std::iter::repeat_n(i, p.scene.num_persons())).collect();
    if let Some((d, f, a, b)) = closest_approach(&scene, &owner) {
        if d < how.min_distance as f64 {
            bail!(
                "compose {name}: person {a} ({}) and person {b} ({}) come within {d:.2} m of each other at frame {f}, closer than {} m: place them farther apart (`spacing`)",
                parts[owner[a]].scene.name,
                parts[owner[b]].scene.name,
                how.min_distance
            );
        }
    }
    scene.metadata.insert("placement".into(), format!("{:?}", how.placement).to_lowercase().into());
    Ok((scene, split))
}

/// Body centre (midpoint of the body-frame joints) of person `p` at frame `f`, horizontally,
/// and whether it is valid there.
fn body_centre(s: &Scene, f: usize, p: usize) -> ([f32; 2], bool) {
    let (l, r) = (s.skeleton.left, s.skeleton.right);
    let x = s.positions.slice(s![f, p, .., ..]);
    ([0.5 * (x[[l, 0]] + x[[r, 0]]), 0.5 * (x[[l, 1]] + x[[r, 1]])], s.is_valid(f, p))
}

/// The closest two persons of different owners come, over every frame where both are valid:
/// `(distance, frame, person, person)`; `None` when no such pair exists.
pub fn closest_approach(scene: &Scene, owner: &[usize]) -> Option<(f64, usize, usize, usize)> {
    let mut best: Option<(f64, usize, usize, usize)> = None;
    for f in 0..scene.num_frames() {
        let centres: Vec<([f32; 2], bool)> = (0..scene.num_persons()).map(|p| body_centre(scene, f, p)).collect();
        for a in 0..centres.len() {
            for b in a + 1..centres.len() {
                if owner[a] == owner[b] || !centres[a].1 || !centres[b].1 {
                    continue;
                }
                let d = ((centres[a].0[0] - centres[b].0[0]) as f64).hypot((centres[a].0[1] - centres[b].0[1]) as f64);
                if best.is_none_or(|x| d < x.0) {
                    best = Some((d, f, a, b));
                }
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::test_util::walkers;

    fn part(name: &str, persons: usize, split: Split) -> Part {
        let mut scene = walkers(20, persons, 0.3);
        scene.name = name.into();
        Part { scene, split }
    }

    #[test]
    fn parts_are_placed_and_kept_apart() {
        let parts = [part("a", 3, Split::Test), part("b", 2, Split::Test), part("c", 1, Split::Test)];
        for placement in [Placement::Circle, Placement::Line] {
            let how = Composition { placement, spacing: 8.0, ..Default::default() };
            let (scene, split) = compose("g", &parts, &how).unwrap();
            assert_eq!((scene.num_persons(), scene.num_frames(), split), (6, 20, Split::Test));
            let owner = [0, 0, 0, 1, 1, 2];
            let (d, ..) = closest_approach(&scene, &owner).unwrap();
            assert!(d >= 0.5, "{placement:?}: {d}");
        }
        // On a line: the first persons' first-frame centres 8 m apart along x, centred.
        let how = Composition { placement: Placement::Line, spacing: 8.0, ..Default::default() };
        let (scene, _) = compose("g", &parts, &how).unwrap();
        let xs: Vec<f32> = [0, 3, 5].iter().map(|&p| body_centre(&scene, 0, p).0[0]).collect();
        assert!((xs[0] + 8.0).abs() < 1e-4 && xs[1].abs() < 1e-4 && (xs[2] - 8.0).abs() < 1e-4, "{xs:?}");
        // Recorded places: the walkers of two copies stand on each other.
        let how = Composition { placement: Placement::Recorded, ..Default::default() };
        let e = compose("g", &parts[..2], &how).unwrap_err().to_string();
        assert!(e.contains("person 0 (a)") && e.contains("person 3 (b)") && e.contains("closer than 0.5 m"), "{e}");
        // Splits are not mixed unless asked.
        let mixed = [part("a", 1, Split::Train), part("b", 1, Split::Test)];
        let how = Composition { spacing: 8.0, ..Default::default() };
        let e = compose("g", &mixed, &how).unwrap_err().to_string();
        assert!(e.contains("a is in the train split, b in the test split") && e.contains("mix_splits"), "{e}");
        let (_, split) = compose("g", &mixed, &Composition { mix_splits: true, ..how }).unwrap();
        assert_eq!(split, Split::Train);
    }
}
