//! PNG filmstrips: `N` frames of a scene side by side, one row per sample, rendered headless
//! (with [`tiny_skia`], anti-aliased) for papers and reports.
//!
//! Every panel uses the same fixed oblique orthographic camera (azimuth and elevation in
//! [`FilmstripOptions`]; z up) and the same scale, so sizes compare across panels. Each column
//! is centred horizontally on the first sample's persons at that frame (the floor grid, 0.5 m
//! squares, moves with the world so motion stays visible); the floor is the lowest valid joint
//! of the group. Persons have the viewer's colours ([`super::person_colour`]), grey shadows on
//! the floor and grey, faint bones where invalid. A bar on top of each panel is blue for
//! observed frames and orange for forecast ones, whose bones are also dashed; each panel is
//! labelled with its time (`t=1.50s`) and, with several samples, the first panel of a row with
//! the sample (`k3`, or `gt` for the ground truth).

use super::{person_colour, SceneGroup};
use crate::data::rotation::{cross, dot, V3};
use crate::files::write_file_atomic;
use crate::{bail, Error, Result};
use std::path::Path;
use tiny_skia::{Color, FillRule, LineCap, Paint, PathBuilder, Pixmap, PixmapPaint, Rect, Stroke, StrokeDash, Transform};

/// How to draw a filmstrip.
#[derive(Clone, Debug, PartialEq)]
pub struct FilmstripOptions {
    /// Frames (columns), evenly spaced from the first to the last frame.
    pub frames: usize,
    /// Panel width, pixels.
    pub panel_width: u32,
    /// Panel height, pixels.
    pub panel_height: u32,
    /// Camera azimuth about z, degrees from +x (the camera looks from this side).
    pub azimuth_deg: f64,
    /// Camera elevation above the floor plane, degrees (0 = side view).
    pub elevation_deg: f64,
}

impl Default for FilmstripOptions {
    fn default() -> Self {
        Self { frames: 6, panel_width: 320, panel_height: 360, azimuth_deg: -60.0, elevation_deg: 20.0 }
    }
}

/// Background of observed panels (white) and of forecast panels (light warm grey).
pub const BACKGROUND: [u8; 3] = [255, 255, 255];
/// Background of forecast panels.
pub const FORECAST_BACKGROUND: [u8; 3] = [255, 248, 238];
/// Top bar colour of observed panels.
pub const OBSERVED_BAR: [u8; 3] = [91, 141, 239];
/// Top bar colour of forecast panels.
pub const FORECAST_BAR: [u8; 3] = [240, 160, 48];

/// A rendered filmstrip.
pub struct Filmstrip {
    /// The image: `frames.len()` columns × `rows` rows of panels.
    pub pixmap: Pixmap,
    /// Frame shown in each column.
    pub frames: Vec<usize>,
    /// Rows (samples).
    pub rows: usize,
}

/// `n` frame indices evenly spaced over `0..frames` (first and last included).
pub fn frame_indices(frames: usize, n: usize) -> Result<Vec<usize>> {
    if n == 0 {
        bail!("`frames` must be at least 1");
    }
    if n > frames {
        bail!("`frames` {n} exceeds the {frames} frames of the scene");
    }
    if n == 1 {
        return Ok(vec![0]);
    }
    Ok((0..n).map(|i| ((i as f64) * (frames - 1) as f64 / (n - 1) as f64).round() as usize).collect())
}

/// A bone on screen: depth, person, end points.
type Segment = (f64, usize, (f32, f32), (f32, f32));

/// Renders `group` (see the module docs).
pub fn render_filmstrip(group: &SceneGroup, opts: &FilmstripOptions) -> Result<Filmstrip> {
    group.check()?;
    let first = group.first();
    let frames = frame_indices(group.num_frames(), opts.frames)?;
    if !(16..=4096).contains(&opts.panel_width) || !(16..=4096).contains(&opts.panel_height) {
        bail!("panel size {}×{} must be 16 to 4096 pixels each way", opts.panel_width, opts.panel_height);
    }
    let rows = group.samples.len();
    let (pw, ph) = (opts.panel_width, opts.panel_height);
    let (width, height) = (pw as u64 * frames.len() as u64, ph as u64 * rows as u64);
    if width * height > 200_000_000 {
        bail!("filmstrip of {width}×{height} pixels is too large; use fewer frames or smaller panels");
    }
    let (a, e) = (opts.azimuth_deg.to_radians(), opts.elevation_deg.to_radians());
    let d: V3 = [e.cos() * a.cos(), e.cos() * a.sin(), e.sin()];
    let right: V3 = {
        let r = [-d[1], d[0], 0.0];
        let n = (r[0] * r[0] + r[1] * r[1]).sqrt().max(1e-12);
        [r[0] / n, r[1] / n, 0.0]
    };
    let up = cross(d, right);
    let (np, nj) = (first.num_persons(), first.num_joints());
    let (l, r) = (first.skeleton.left, first.skeleton.right);
    let pos = |s: usize, f: usize, p: usize, j: usize| -> V3 { std::array::from_fn(|k| group.samples[s].scene.positions[[f, p, j, k]] as f64) };
    // Floor, per-column centres, projected extent.
    let mut floor = f64::INFINITY;
    for s in &group.samples {
        for &f in &frames {
            for p in 0..np {
                if s.scene.is_valid(f, p) {
                    for j in 0..nj {
                        floor = floor.min(s.scene.positions[[f, p, j, 2]] as f64);
                    }
                }
            }
        }
    }
    if !floor.is_finite() {
        floor = 0.0;
    }
    let centres: Vec<V3> = frames
        .iter()
        .map(|&f| {
            let (mut c, mut n) = ([0.0; 3], 0.0);
            for p in 0..np {
                if first.is_valid(f, p) || (0..np).all(|q| !first.is_valid(f, q)) {
                    let (pl, pr) = (pos(0, f, p, l), pos(0, f, p, r));
                    c[0] += 0.5 * (pl[0] + pr[0]);
                    c[1] += 0.5 * (pl[1] + pr[1]);
                    n += 1.0;
                }
            }
            [c[0] / n, c[1] / n, floor]
        })
        .collect();
    let (mut umin, mut umax, mut vmin, mut vmax) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    let mut radius = 0.5f64;
    for s in 0..rows {
        for (col, &f) in frames.iter().enumerate() {
            for p in 0..np {
                for j in 0..nj {
                    let x = pos(s, f, p, j);
                    let q = [x[0] - centres[col][0], x[1] - centres[col][1], x[2] - floor];
                    let (u, v) = (dot(q, right), dot(q, up));
                    (umin, umax, vmin, vmax) = (umin.min(u), umax.max(u), vmin.min(v), vmax.max(v));
                    radius = radius.max(q[0].hypot(q[1]));
                }
            }
        }
    }
    // The grid reaches beyond the panel edges (panels clip it); the scale fits the persons.
    let grid_r = radius + 3.0;
    let (umin, umax) = (umin - 0.25, umax + 0.25);
    let (vmin, vmax) = (vmin - 0.1, vmax + 0.1);
    let s = ph as f64 / 360.0;
    let header = (18.0 * s).round();
    let margin = 8.0 * s;
    let k = ((pw as f64 - 2.0 * margin) / (umax - umin).max(1e-6)).min((ph as f64 - header - 2.0 * margin) / (vmax - vmin).max(1e-6));
    let (uc, vc) = (0.5 * (umin + umax), 0.5 * (vmin + vmax));
    let (ox, oy) = (pw as f64 / 2.0, header + (ph as f64 - header) / 2.0);

    let mut out = Pixmap::new(width as u32, height as u32).ok_or_else(|| Error::invalid("cannot allocate the filmstrip"))?;
    let mut panel = Pixmap::new(pw, ph).expect("size checked");
    let bones = &first.skeleton.bones;
    for (row, sample) in group.samples.iter().enumerate() {
        for (col, &f) in frames.iter().enumerate() {
            let c = centres[col];
            let project = |x: V3| -> (f32, f32, f64) {
                let q = [x[0] - c[0], x[1] - c[1], x[2] - floor];
                ((ox + k * (dot(q, right) - uc)) as f32, (oy - k * (dot(q, up) - vc)) as f32, dot(q, d))
            };
            let forecast = f >= group.observed_frames;
            let bg = if forecast { FORECAST_BACKGROUND } else { BACKGROUND };
            panel.fill(Color::from_rgba8(bg[0], bg[1], bg[2], 255));
            let mut paint = Paint { anti_alias: true, ..Default::default() };
            // Floor grid.
            paint.set_color_rgba8(218, 220, 224, 255);
            let grid_stroke = Stroke { width: (1.0 * s) as f32, ..Default::default() };
            let mut pb = PathBuilder::new();
            let step = 0.5;
            let lo = |cc: f64| ((cc - grid_r) / step).ceil() as i64;
            let hi = |cc: f64| ((cc + grid_r) / step).floor() as i64;
            for i in lo(c[0])..=hi(c[0]) {
                let x = i as f64 * step;
                let (a, b) = (project([x, c[1] - grid_r, floor]), project([x, c[1] + grid_r, floor]));
                pb.move_to(a.0, a.1);
                pb.line_to(b.0, b.1);
            }
            for i in lo(c[1])..=hi(c[1]) {
                let y = i as f64 * step;
                let (a, b) = (project([c[0] - grid_r, y, floor]), project([c[0] + grid_r, y, floor]));
                pb.move_to(a.0, a.1);
                pb.line_to(b.0, b.1);
            }
            if let Some(path) = pb.finish() {
                panel.stroke_path(&path, &paint, &grid_stroke, Transform::identity(), None);
            }
            // Shadows.
            paint.set_color_rgba8(200, 202, 206, 255);
            let shadow = Stroke { width: (3.0 * s) as f32, line_cap: LineCap::Round, ..Default::default() };
            let mut pb = PathBuilder::new();
            for p in 0..np {
                for &(ja, jb) in bones {
                    let (mut xa, mut xb) = (pos(row, f, p, ja), pos(row, f, p, jb));
                    (xa[2], xb[2]) = (floor, floor);
                    let (a, b) = (project(xa), project(xb));
                    pb.move_to(a.0, a.1);
                    pb.line_to(b.0, b.1);
                }
            }
            if let Some(path) = pb.finish() {
                panel.stroke_path(&path, &paint, &shadow, Transform::identity(), None);
            }
            // Bones, far to near.
            let mut segs: Vec<Segment> = Vec::with_capacity(np * bones.len());
            for p in 0..np {
                for &(ja, jb) in bones {
                    let (a, b) = (project(pos(row, f, p, ja)), project(pos(row, f, p, jb)));
                    segs.push((0.5 * (a.2 + b.2), p, (a.0, a.1), (b.0, b.1)));
                }
            }
            segs.sort_by(|x, y| x.0.total_cmp(&y.0));
            let width = (3.2 * s) as f32;
            let mut bone = Stroke { width, line_cap: LineCap::Round, ..Default::default() };
            if forecast {
                bone.dash = StrokeDash::new(vec![7.0 * s as f32, 4.5 * s as f32], 0.0);
                bone.line_cap = LineCap::Butt;
            }
            for (_, p, a, b) in &segs {
                let col = if sample.scene.is_valid(f, *p) { person_colour(*p) } else { [150, 150, 150] };
                let alpha = if sample.scene.is_valid(f, *p) { 255 } else { 110 };
                paint.set_color_rgba8(col[0], col[1], col[2], alpha);
                let mut pb = PathBuilder::new();
                pb.move_to(a.0, a.1);
                pb.line_to(b.0, b.1);
                if let Some(path) = pb.finish() {
                    panel.stroke_path(&path, &paint, &bone, Transform::identity(), None);
                }
            }
            for p in 0..np {
                let col = if sample.scene.is_valid(f, p) { person_colour(p) } else { [150, 150, 150] };
                paint.set_color_rgba8((col[0] as f32 * 0.7) as u8, (col[1] as f32 * 0.7) as u8, (col[2] as f32 * 0.7) as u8, 255);
                for j in 0..nj {
                    let (x, y, _) = project(pos(row, f, p, j));
                    if let Some(circle) = PathBuilder::from_circle(x, y, (2.2 * s) as f32) {
                        panel.fill_path(&circle, &paint, FillRule::Winding, Transform::identity(), None);
                    }
                }
            }
            // Top bar, labels, right and bottom edges.
            let bar = if forecast { FORECAST_BAR } else { OBSERVED_BAR };
            paint.set_color_rgba8(bar[0], bar[1], bar[2], 255);
            if let Some(rect) = Rect::from_xywh(0.0, 0.0, pw as f32, (4.0 * s) as f32) {
                panel.fill_rect(rect, &paint, Transform::identity(), None);
            }
            let px = (2.0 * s).round().max(1.0) as f32;
            let mut label = format!("t={:.2}s", f as f64 / first.fps);
            if col == 0 && rows > 1 {
                label = match sample.label.strip_prefix("sample ") {
                    Some(k) => format!("k{k} {label}"),
                    None if sample.label == "ground truth" => format!("gt {label}"),
                    None => format!("{row} {label}"),
                };
            }
            draw_text(&mut panel, &label, (5.0 * s) as f32, (6.0 * s) as f32, px, [60, 60, 60]);
            paint.set_color_rgba8(200, 200, 200, 255);
            for rect in [Rect::from_xywh(pw as f32 - 1.0, 0.0, 1.0, ph as f32), Rect::from_xywh(0.0, ph as f32 - 1.0, pw as f32, 1.0)].into_iter().flatten() {
                panel.fill_rect(rect, &paint, Transform::identity(), None);
            }
            out.draw_pixmap((col as u32 * pw) as i32, (row as u32 * ph) as i32, panel.as_ref(), &PixmapPaint::default(), Transform::identity(), None);
        }
    }
    Ok(Filmstrip { pixmap: out, frames, rows })
}

/// The filmstrip of `group` as PNG bytes.
pub fn filmstrip_png(group: &SceneGroup, opts: &FilmstripOptions) -> Result<Vec<u8>> {
    let strip = render_filmstrip(group, opts)?;
    strip.pixmap.encode_png().map_err(|e| Error::invalid(format!("scene {}: PNG encoding failed: {e}", group.name)))
}

/// Writes the filmstrip of `group` to `path` (atomically).
pub fn write_filmstrip(group: &SceneGroup, path: &Path, opts: &FilmstripOptions) -> Result<()> {
    write_file_atomic(path, &filmstrip_png(group, opts)?)
}

/// Reads a PNG file as `(width, height, RGB bytes)`, for checking rendered images (filmstrips,
/// browser screenshots). Errors name the file.
pub fn read_png_rgb(path: &Path) -> Result<(u32, u32, Vec<u8>)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let img = Pixmap::decode_png(&bytes).map_err(|e| Error::format(path, format!("not a readable PNG: {e}")))?;
    let rgb = img
        .pixels()
        .iter()
        .flat_map(|p| {
            let c = p.demultiply();
            [c.red(), c.green(), c.blue()]
        })
        .collect();
    Ok((img.width(), img.height(), rgb))
}

/// 5×7 glyphs (rows top to bottom, bit 4 = leftmost column) for labels.
fn glyph(c: char) -> [u8; 7] {
    match c {
        '0' => [14, 17, 19, 21, 25, 17, 14],
        '1' => [4, 12, 4, 4, 4, 4, 14],
        '2' => [14, 17, 1, 2, 4, 8, 31],
        '3' => [31, 2, 4, 2, 1, 17, 14],
        '4' => [2, 6, 10, 18, 31, 2, 2],
        '5' => [31, 16, 30, 1, 1, 17, 14],
        '6' => [6, 8, 16, 30, 17, 17, 14],
        '7' => [31, 1, 2, 4, 8, 8, 8],
        '8' => [14, 17, 17, 14, 17, 17, 14],
        '9' => [14, 17, 17, 15, 1, 2, 12],
        '.' => [0, 0, 0, 0, 0, 12, 12],
        's' => [0, 0, 14, 16, 14, 1, 30],
        't' => [8, 8, 28, 8, 8, 9, 6],
        '=' => [0, 0, 31, 0, 31, 0, 0],
        '+' => [0, 4, 4, 31, 4, 4, 0],
        '-' => [0, 0, 0, 31, 0, 0, 0],
        'g' => [0, 15, 17, 17, 15, 1, 14],
        'k' => [16, 16, 18, 20, 24, 20, 18],
        _ => [0; 7],
    }
}

/// Draws `text` with the 5×7 font, each font pixel `px` pixels wide, top-left at (x, y).
fn draw_text(pixmap: &mut Pixmap, text: &str, x: f32, y: f32, px: f32, rgb: [u8; 3]) {
    let mut paint = Paint::default();
    paint.set_color_rgba8(rgb[0], rgb[1], rgb[2], 255);
    let mut pb = PathBuilder::new();
    for (i, c) in text.chars().enumerate() {
        let gx = x + i as f32 * 6.0 * px;
        for (r, bits) in glyph(c).iter().enumerate() {
            for col in 0..5 {
                if bits & (16 >> col) != 0 {
                    if let Some(rect) = Rect::from_xywh(gx + col as f32 * px, y + r as f32 * px, px, px) {
                        pb.push_rect(rect);
                    }
                }
            }
        }
    }
    if let Some(path) = pb.finish() {
        pixmap.fill_path(&path, &paint, FillRule::Winding, Transform::identity(), None);
    }
}

#[cfg(test)]
mod tests {
    use super::super::{group_scenes, ForecastInfo, Sample, SceneGroup};
    use super::*;
    use crate::data::test_util::{mupots, tmp, walkers};

    /// Pixels of panel (row, col) that differ from both backgrounds, and those of `rgb`.
    fn panel_counts(img: &Pixmap, pw: u32, ph: u32, row: u32, col: u32, rgb: [u8; 3]) -> (usize, usize) {
        let (mut drawn, mut colour) = (0, 0);
        for y in row * ph + 20..(row + 1) * ph - 1 {
            for x in col * pw..(col + 1) * pw - 1 {
                let p = img.pixel(x, y).unwrap().demultiply();
                let c = [p.red(), p.green(), p.blue()];
                if c != BACKGROUND && c != FORECAST_BACKGROUND {
                    drawn += 1;
                }
                if c.iter().zip(&rgb).all(|(a, b)| (*a as i32 - *b as i32).abs() <= 2) {
                    colour += 1;
                }
            }
        }
        (drawn, colour)
    }

    #[test]
    fn frame_indices_are_even_and_checked() {
        assert_eq!(frame_indices(11, 3).unwrap(), [0, 5, 10]);
        assert_eq!(frame_indices(303, 6).unwrap(), [0, 60, 121, 181, 242, 302]);
        assert_eq!(frame_indices(5, 1).unwrap(), [0]);
        assert!(frame_indices(5, 6).unwrap_err().to_string().contains("`frames` 6 exceeds the 5 frames"));
        assert!(frame_indices(5, 0).is_err());
    }

    #[test]
    fn filmstrip_of_forecast_samples_has_every_panel_drawn() {
        let base = walkers(90, 3, 0.0);
        let mut samples = Vec::new();
        for k in 0..3 {
            let mut s = base.clone();
            // Samples diverge after frame 45.
            for f in 45..90 {
                for p in 0..3 {
                    for j in 0..17 {
                        s.positions[[f, p, j, 0]] += (f - 45) as f32 * 0.01 * k as f32;
                    }
                }
            }
            s.name = format!("walk_s{k}");
            ForecastInfo { observed_frames: 45, sample: Some(k), source: "walk".into() }.insert_into(&mut s.metadata);
            samples.push(Sample { label: String::new(), scene: s });
        }
        let ds = crate::Dataset {
            name: "fc".into(),
            sequences: samples.into_iter().map(|s| crate::data::dataset::Sequence { split: crate::Split::Test, scene: s.scene }).collect(),
            metadata: Default::default(),
        };
        let group = group_scenes(&ds, None).unwrap().remove(0);
        let opts = FilmstripOptions { frames: 4, panel_width: 200, panel_height: 240, ..Default::default() };
        let dir = tmp("png");
        let path = dir.join("walk.png");
        write_filmstrip(&group, &path, &opts).unwrap();
        let img = Pixmap::load_png(&path).unwrap();
        assert_eq!((img.width(), img.height()), (800, 720));
        let frames = frame_indices(90, 4).unwrap();
        for row in 0..3 {
            for (col, &f) in frames.iter().enumerate() {
                let (drawn, blue) = panel_counts(&img, 200, 240, row, col as u32, person_colour(0));
                let (_, red) = panel_counts(&img, 200, 240, row, col as u32, person_colour(1));
                let bar = img.pixel(col as u32 * 200 + 100, row * 240 + 1).unwrap().demultiply();
                let want = if f >= 45 { FORECAST_BAR } else { OBSERVED_BAR };
                assert_eq!([bar.red(), bar.green(), bar.blue()], want, "bar of panel ({row}, {col})");
                println!("panel ({row}, {col}) frame {f}: {drawn} drawn pixels, {blue} of person 0's colour, {red} of person 1's");
                assert!(drawn > 2000 && blue > 20 && red > 20, "panel ({row}, {col}) is nearly blank");
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn filmstrip_of_mupots_scene() {
        let Some(ds) = mupots() else { return };
        let g = SceneGroup::single(ds.scene("TS16").unwrap().clone(), Some(200)).unwrap();
        let opts = FilmstripOptions { frames: 5, ..Default::default() };
        let strip = render_filmstrip(&g, &opts).unwrap();
        assert_eq!((strip.pixmap.width(), strip.pixmap.height(), strip.rows), (1600, 360, 1));
        for col in 0..5 {
            let (drawn, _) = panel_counts(&strip.pixmap, 320, 360, 0, col, [0, 0, 0]);
            assert!(drawn > 3000, "panel {col}: {drawn}");
        }
        let dir = tmp("png-mupots");
        write_filmstrip(&g, &dir.join("ts16.png"), &opts).unwrap();
        println!("TS16 filmstrip: {} bytes", std::fs::metadata(dir.join("ts16.png")).unwrap().len());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
