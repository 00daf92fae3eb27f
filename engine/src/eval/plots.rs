//! PNG plots of a [`Report`]: `plotters` lays the charts out, tiny-skia rasterizes them
//! (anti-aliased, through [`SkiaBackend`]) and encodes the PNG — the same rasterizer as the
//! filmstrips ([`crate::export::png`]).
//!
//! | file | what |
//! |---|---|
//! | `ndms_over_time.png` | NDMS per word vs seconds from the first forecast frame (word start) |
//! | `speed_over_time.png` | mean joint speed per frame step, with the reference's real speed |
//! | `mpjpe_by_horizon.png` | global, root and root-aligned MPJPE per forecast frame up to 1 s past the longest horizon; dots at the horizons |
//! | `speed_js_over_time.png` | JS distance of the joint-speed histograms per time bin |
//! | `sscp_transitions.png` | SSCP transition distributions, reference first, side by side |
//!
//! A plot is written only when some method has its data. Text uses the bundled DejaVu Sans
//! (`assets/fonts`, Bitstream Vera licence), so no system font is needed.

use super::report::{Curve, Report};
use crate::export::person_colour;
use crate::metrics::sscp::{NUM_STATES, STATE_NAMES};
use crate::{Error, Result};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters_backend::{BackendColor, BackendCoord, BackendStyle, DrawingErrorKind};
use std::path::{Path, PathBuf};
use tiny_skia::{FillRule, LineCap, LineJoin, Paint, PathBuilder, Pixmap, PremultipliedColorU8, Rect, Stroke, Transform};

/// The bundled font (DejaVu Sans, licence beside it).
static FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");
const FAMILY: &str = "sans-serif";

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // A valid TrueType file is bundled; a failure would show as missing text, not a panic.
        let _ = plotters::style::register_font(FAMILY, FontStyle::Normal, FONT);
    });
}

fn colour(i: usize) -> RGBColor {
    let [r, g, b] = person_colour(i);
    RGBColor(r, g, b)
}

fn plot_err(name: &str, e: impl std::fmt::Display) -> Error {
    Error::invalid(format!("plot {name}: {e}"))
}

/// A plotters backend drawing on a tiny-skia pixmap. Plotters' integer coordinates name pixels,
/// so shapes are drawn through pixel centres (+0.5); text comes pixel by pixel from plotters'
/// font rasterizer and is blended here.
struct SkiaBackend<'a> {
    pixmap: &'a mut Pixmap,
}

type DrawResult = std::result::Result<(), DrawingErrorKind<std::io::Error>>;

impl SkiaBackend<'_> {
    fn paint(color: BackendColor) -> Paint<'static> {
        let mut paint = Paint { anti_alias: true, ..Default::default() };
        let (r, g, b) = color.rgb;
        paint.set_color_rgba8(r, g, b, (color.alpha.clamp(0.0, 1.0) * 255.0).round() as u8);
        paint
    }

    fn stroke(&mut self, points: &[BackendCoord], style: &impl BackendStyle) {
        let mut pb = PathBuilder::new();
        for (i, &(x, y)) in points.iter().enumerate() {
            let (x, y) = (x as f32 + 0.5, y as f32 + 0.5);
            if i == 0 {
                pb.move_to(x, y);
            } else {
                pb.line_to(x, y);
            }
        }
        if let Some(path) = pb.finish() {
            let stroke = Stroke { width: style.stroke_width().max(1) as f32, line_cap: LineCap::Butt, line_join: LineJoin::Round, ..Default::default() };
            self.pixmap.stroke_path(&path, &Self::paint(style.color()), &stroke, Transform::identity(), None);
        }
    }
}

impl DrawingBackend for SkiaBackend<'_> {
    type ErrorType = std::io::Error;

    fn get_size(&self) -> (u32, u32) {
        (self.pixmap.width(), self.pixmap.height())
    }

    fn ensure_prepared(&mut self) -> DrawResult {
        Ok(())
    }

    fn present(&mut self) -> DrawResult {
        Ok(())
    }

    fn draw_pixel(&mut self, (x, y): BackendCoord, color: BackendColor) -> DrawResult {
        let (w, h) = self.get_size();
        if x < 0 || y < 0 || x as u32 >= w || y as u32 >= h || color.alpha <= 0.0 {
            return Ok(());
        }
        // The canvas is opaque: blend straight colours and keep alpha 255.
        let a = color.alpha.min(1.0);
        let px = &mut self.pixmap.pixels_mut()[(y as u32 * w + x as u32) as usize];
        let mix = |src: u8, dst: u8| (src as f64 * a + dst as f64 * (1.0 - a)).round() as u8;
        let (r, g, b) = color.rgb;
        *px = PremultipliedColorU8::from_rgba(mix(r, px.red()), mix(g, px.green()), mix(b, px.blue()), 255).expect("opaque");
        Ok(())
    }

    fn draw_line<S: BackendStyle>(&mut self, from: BackendCoord, to: BackendCoord, style: &S) -> DrawResult {
        self.stroke(&[from, to], style);
        Ok(())
    }

    fn draw_rect<S: BackendStyle>(&mut self, (x0, y0): BackendCoord, (x1, y1): BackendCoord, style: &S, fill: bool) -> DrawResult {
        if fill {
            let (l, t, r, b) = (x0.min(x1), y0.min(y1), x0.max(x1), y0.max(y1));
            if let Some(rect) = Rect::from_ltrb(l as f32, t as f32, r as f32 + 1.0, b as f32 + 1.0) {
                self.pixmap.fill_rect(rect, &Self::paint(style.color()), Transform::identity(), None);
            }
        } else {
            self.stroke(&[(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)], style);
        }
        Ok(())
    }

    fn draw_path<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(&mut self, path: I, style: &S) -> DrawResult {
        self.stroke(&path.into_iter().collect::<Vec<_>>(), style);
        Ok(())
    }

    fn draw_circle<S: BackendStyle>(&mut self, (x, y): BackendCoord, radius: u32, style: &S, fill: bool) -> DrawResult {
        if let Some(circle) = PathBuilder::from_circle(x as f32 + 0.5, y as f32 + 0.5, radius.max(1) as f32) {
            let paint = Self::paint(style.color());
            if fill {
                self.pixmap.fill_path(&circle, &paint, FillRule::Winding, Transform::identity(), None);
            } else {
                let stroke = Stroke { width: style.stroke_width().max(1) as f32, ..Default::default() };
                self.pixmap.stroke_path(&circle, &paint, &stroke, Transform::identity(), None);
            }
        }
        Ok(())
    }

    fn fill_polygon<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(&mut self, vert: I, style: &S) -> DrawResult {
        let mut pb = PathBuilder::new();
        for (i, (x, y)) in vert.into_iter().enumerate() {
            let (x, y) = (x as f32 + 0.5, y as f32 + 0.5);
            if i == 0 {
                pb.move_to(x, y);
            } else {
                pb.line_to(x, y);
            }
        }
        pb.close();
        if let Some(path) = pb.finish() {
            self.pixmap.fill_path(&path, &Self::paint(style.color()), FillRule::Winding, Transform::identity(), None);
        }
        Ok(())
    }
}

/// Renders `draw` on a white `width × height` canvas and returns the PNG bytes.
fn render(name: &str, width: u32, height: u32, draw: impl FnOnce(&DrawingArea<SkiaBackend, Shift>) -> Result<()>) -> Result<Vec<u8>> {
    register_font();
    let mut pixmap = Pixmap::new(width, height).ok_or_else(|| plot_err(name, "empty image"))?;
    pixmap.fill(tiny_skia::Color::WHITE);
    {
        let root = SkiaBackend { pixmap: &mut pixmap }.into_drawing_area();
        draw(&root)?;
        root.present().map_err(|e| plot_err(name, e))?;
    }
    pixmap.encode_png().map_err(|e| plot_err(name, e))
}

/// Range of the finite values, padded by 5% (and never empty).
fn value_range(values: impl Iterator<Item = f64>, floor_zero: bool) -> (f64, f64) {
    let (mut lo, mut hi) = values.filter(|v| v.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    if !lo.is_finite() {
        (lo, hi) = (0.0, 1.0);
    }
    if floor_zero {
        lo = lo.min(0.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-6);
    (if floor_zero && lo >= 0.0 { lo } else { lo - pad }, hi + pad)
}

/// One named line of a plot.
struct Line {
    label: String,
    points: Vec<(f64, f64)>,
    colour: RGBColor,
    dashed: bool,
}

/// A line chart in `area` with a legend.
/// Layout of a [`line_chart`].
struct Chart<'a> {
    name: &'a str,
    title: &'a str,
    x_desc: &'a str,
    y_desc: &'a str,
    /// Only points with x below this are drawn (and scale the axes).
    x_max: f64,
    legend: SeriesLabelPosition,
}

impl<'a> Chart<'a> {
    /// A chart over the whole time range with the legend at `legend`.
    fn over_time(name: &'a str, title: &'a str, x_desc: &'a str, y_desc: &'a str, legend: SeriesLabelPosition) -> Self {
        Self { name, title, x_desc, y_desc, x_max: f64::INFINITY, legend }
    }
}

/// Tick labels with as many decimals as the axis span needs.
fn tick(span: f64) -> impl Fn(&f64) -> String {
    let digits = if span >= 20.0 {
        0
    } else if span >= 2.0 {
        1
    } else {
        2
    };
    move |v| format!("{v:.digits$}")
}

/// A line chart in `area` with a legend.
fn line_chart(area: &DrawingArea<SkiaBackend, Shift>, c: &Chart, lines: &[Line], dots: &[(RGBColor, Vec<(f64, f64)>)], y_zero: bool) -> Result<()> {
    let name = c.name;
    let err = |e| plot_err(name, e);
    let keep = |p: &&(f64, f64)| p.0 <= c.x_max;
    let all = || lines.iter().flat_map(|l| l.points.iter()).chain(dots.iter().flat_map(|d| d.1.iter())).filter(keep);
    let (x0, x1) = value_range(all().map(|p| p.0), false);
    let (y0, y1) = value_range(all().map(|p| p.1), y_zero);
    let (xf, yf) = (tick(x1 - x0), tick(y1 - y0));
    let mut chart = ChartBuilder::on(area)
        .caption(c.title, (FAMILY, 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(64)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(c.x_desc)
        .y_desc(c.y_desc)
        .x_label_formatter(&xf)
        .y_label_formatter(&yf)
        .label_style((FAMILY, 13))
        .axis_desc_style((FAMILY, 15))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(err)?;
    for l in lines {
        let lc = l.colour;
        let style = ShapeStyle { color: lc.to_rgba(), filled: false, stroke_width: 2 };
        let legend = move |(x, y): (i32, i32)| PathElement::new(vec![(x, y), (x + 20, y)], ShapeStyle { color: lc.to_rgba(), filled: false, stroke_width: 2 });
        if l.dashed {
            chart.draw_series(DashedLineSeries::new(l.points.iter().filter(keep).copied(), 6, 4, style)).map_err(err)?.label(l.label.as_str()).legend(legend);
        } else {
            chart.draw_series(LineSeries::new(l.points.iter().filter(keep).copied(), style)).map_err(err)?.label(l.label.as_str()).legend(legend);
        }
    }
    for (colour, pts) in dots {
        let colour = *colour;
        chart.draw_series(pts.iter().filter(keep).map(|&p| Circle::new(p, 4, colour.filled()))).map_err(err)?;
    }
    if !lines.is_empty() {
        chart
            .configure_series_labels()
            .position(c.legend.clone())
            .label_font((FAMILY, 13))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(err)?;
    }
    Ok(())
}

/// Lines of one curve per method (methods without it are skipped, keeping their colour).
fn method_lines(report: &Report, curve: impl Fn(&super::report::MethodReport) -> Option<&Curve>, scale: f64) -> Vec<Line> {
    let fps = report.reference.fps;
    report
        .methods
        .iter()
        .enumerate()
        .filter_map(|(i, m)| {
            let c = curve(m)?;
            Some(Line { label: m.label.clone(), points: c.points(fps).into_iter().map(|(x, y)| (x, y * scale)).collect(), colour: colour(i), dashed: false })
        })
        .filter(|l| !l.points.is_empty())
        .collect()
}

/// NDMS over time.
pub fn ndms_plot(report: &Report) -> Result<Option<Vec<u8>>> {
    let lines = method_lines(report, |m| m.ndms.as_ref().map(|n| &n.per_frame), 1.0);
    if lines.is_empty() {
        return Ok(None);
    }
    let title = format!("NDMS over time ({} {})", report.reference.dataset, report.reference.split);
    let chart = Chart::over_time("ndms_over_time", &title, "seconds from the first forecast frame (word start)", "NDMS", SeriesLabelPosition::MiddleRight);
    render(chart.name, 1000, 560, |root| line_chart(root, &chart, &lines, &[], true)).map(Some)
}

/// Joint speed over time, with the reference's real speed dashed.
pub fn speed_plot(report: &Report) -> Result<Option<Vec<u8>>> {
    let mut lines = method_lines(report, |m| m.speed.as_ref().map(|s| &s.per_frame), 1.0);
    if lines.is_empty() {
        return Ok(None);
    }
    if let Some(c) = &report.reference_speed {
        lines.push(Line { label: "reference (real)".into(), points: c.points(report.reference.fps), colour: BLACK, dashed: true });
    }
    let title = format!("Mean joint speed ({} {})", report.reference.dataset, report.reference.split);
    let chart = Chart::over_time("speed_over_time", &title, "seconds from the first forecast frame", "m/s", SeriesLabelPosition::UpperRight);
    render(chart.name, 1000, 560, |root| line_chart(root, &chart, &lines, &[], true)).map(Some)
}

/// Picks one per-frame curve of an MPJPE report.
type CurveOf = fn(&super::report::MpjpeReport) -> &Curve;
/// Picks the matching value at a horizon (mean over K).
type ValueAt = fn(&super::report::HorizonReport) -> Option<f64>;
/// Draws one plot: PNG bytes, or `None` without data.
type PlotFn = fn(&Report) -> Result<Option<Vec<u8>>>;

/// MPJPE per forecast frame (three panels), dots at the horizons (mean over K).
pub fn mpjpe_plot(report: &Report) -> Result<Option<Vec<u8>>> {
    if report.methods.iter().all(|m| m.mpjpe.is_none()) {
        return Ok(None);
    }
    let panels: [(&str, CurveOf, ValueAt); 3] = [
        ("MPJPE, all joints", |p| &p.global_per_frame, |h| h.global.map(|s| s.mean)),
        ("root (hip midpoint)", |p| &p.root_per_frame, |h| h.root.map(|s| s.mean)),
        ("root-aligned pose", |p| &p.root_aligned_per_frame, |h| h.root_aligned.map(|s| s.mean)),
    ];
    // Short-horizon errors: up to 1 s past the longest horizon.
    let x_max = report.methods.iter().filter_map(|m| m.mpjpe.as_ref()).flat_map(|p| p.horizons.iter().map(|h| h.horizon_s)).fold(0.0, f64::max) + 1.0;
    render("mpjpe_by_horizon", 1500, 520, |root| {
        for (area, (title, curve, at)) in root.split_evenly((1, 3)).iter().zip(panels) {
            let lines = method_lines(report, |m| m.mpjpe.as_ref().map(curve), 1000.0);
            let dots: Vec<(RGBColor, Vec<(f64, f64)>)> = report
                .methods
                .iter()
                .enumerate()
                .filter_map(|(i, m)| {
                    let p = m.mpjpe.as_ref()?;
                    Some((colour(i), p.horizons.iter().filter_map(|h| Some((h.horizon_s, at(h)? * 1000.0))).collect()))
                })
                .collect();
            let chart = Chart { name: "mpjpe_by_horizon", title, x_desc: "horizon (s)", y_desc: "mm", x_max, legend: SeriesLabelPosition::UpperLeft };
            line_chart(area, &chart, &lines, &dots, true)?;
        }
        Ok(())
    })
    .map(Some)
}

/// Speed-histogram JS distance per time bin.
pub fn speed_js_plot(report: &Report) -> Result<Option<Vec<u8>>> {
    let bin_s = report.settings.get("speed_histogram").and_then(|h| h.get("time_bin_s")).and_then(|v| v.as_f64()).unwrap_or(1.0);
    let lines: Vec<Line> = report
        .methods
        .iter()
        .enumerate()
        .filter_map(|(i, m)| {
            let bins = m.plausibility.as_ref()?.speed_js_per_bin.as_ref()?;
            let points: Vec<(f64, f64)> = bins.iter().enumerate().filter_map(|(b, v)| Some((b as f64 * bin_s, (*v)?))).collect();
            (!points.is_empty()).then(|| Line { label: m.label.clone(), points, colour: colour(i), dashed: false })
        })
        .collect();
    if lines.is_empty() {
        return Ok(None);
    }
    let chart = Chart::over_time(
        "speed_js_over_time",
        "Joint-speed distribution vs real data (JS distance)",
        "time bin start (s after the last observed frame)",
        "JS distance",
        SeriesLabelPosition::UpperRight,
    );
    render(chart.name, 1000, 560, |root| line_chart(root, &chart, &lines, &[], true)).map(Some)
}

/// SSCP transition distributions side by side: the reference, then each scored method.
pub fn sscp_plot(report: &Report) -> Result<Option<Vec<u8>>> {
    let mut panels: Vec<(String, &Vec<Vec<f64>>)> = Vec::new();
    for m in &report.methods {
        if let Some(s) = &m.sscp {
            if let (Some(t), Some(r)) = (&s.transitions, &s.reference_transitions) {
                if panels.is_empty() {
                    panels.push(("reference".into(), r));
                }
                panels.push((format!("{} (SSCP {:.3})", m.label, s.value.unwrap_or(f64::NAN)), t));
            }
        }
    }
    if panels.is_empty() {
        return Ok(None);
    }
    let max = panels.iter().flat_map(|p| p.1.iter().flatten()).fold(0f64, |a, &b| a.max(b)).max(1e-12);
    let name = "sscp_transitions";
    let err = |e| plot_err(name, e);
    render(name, 430 * panels.len() as u32, 470, |root| {
        for (area, (title, m)) in root.split_evenly((1, panels.len())).iter().zip(&panels) {
            let mut chart = ChartBuilder::on(area)
                .caption(title, (FAMILY, 16))
                .margin(8)
                .x_label_area_size(44)
                .y_label_area_size(44)
                .build_cartesian_2d(0i32..NUM_STATES as i32, 0i32..NUM_STATES as i32)
                .map_err(err)?;
            let label = |v: &i32| if (0..NUM_STATES as i32).contains(v) { STATE_NAMES[*v as usize].to_string() } else { String::new() };
            chart
                .configure_mesh()
                .disable_mesh()
                .x_labels(NUM_STATES)
                .y_labels(NUM_STATES)
                .x_label_formatter(&label)
                .y_label_formatter(&|v| label(&(NUM_STATES as i32 - 1 - v)))
                .x_label_style((FAMILY, 9).into_font().transform(FontTransform::Rotate90))
                .y_label_style((FAMILY, 9))
                .x_desc("to state")
                .y_desc("from state")
                .axis_desc_style((FAMILY, 12))
                .draw()
                .map_err(err)?;
            chart
                .draw_series((0..NUM_STATES).flat_map(|a| (0..NUM_STATES).map(move |b| (a, b))).map(|(a, b)| {
                    // sqrt scale: rare transitions stay visible.
                    let t = (m[a][b] / max).sqrt();
                    let shade = |full: f64| (255.0 - t * (255.0 - full)).round() as u8;
                    let y = (NUM_STATES - 1 - a) as i32;
                    Rectangle::new([(b as i32, y), (b as i32 + 1, y + 1)], RGBColor(shade(8.0), shade(48.0), shade(107.0)).filled())
                }))
                .map_err(err)?;
        }
        Ok(())
    })
    .map(Some)
}

/// Writes every plot that has data into `dir`; returns the files written.
pub fn write_plots(report: &Report, dir: &Path) -> Result<Vec<PathBuf>> {
    let plots: [(&str, PlotFn); 5] = [
        ("ndms_over_time.png", ndms_plot),
        ("speed_over_time.png", speed_plot),
        ("mpjpe_by_horizon.png", mpjpe_plot),
        ("speed_js_over_time.png", speed_js_plot),
        ("sscp_transitions.png", sscp_plot),
    ];
    let mut out = Vec::new();
    for (file, plot) in plots {
        if let Some(bytes) = plot(report)? {
            let path = dir.join(file);
            std::fs::write(&path, bytes).map_err(|e| Error::io(&path, e))?;
            out.push(path);
        }
    }
    Ok(out)
}
