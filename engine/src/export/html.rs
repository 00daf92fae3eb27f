//! A self-contained HTML viewer: one file, no network access when viewed, a small canvas-2D 3D
//! renderer of our own (`viewer/viewer.js`, `viewer/viewer.css`, `viewer/viewer.html`, inlined).
//!
//! The page shows every person's skeleton over a floor grid, with play/pause, a frame slider,
//! speed, orbit (drag), pan (right- or shift-drag), zoom (wheel), per-person colours, observed
//! frames (solid bones, blue marks) distinct from forecast frames (dashed bones, warm panel,
//! orange marks), the samples of a scene side by side or one at a time, a scene selector when
//! several scenes are embedded, and per-person signal labels (e.g. `speaking`).
//!
//! # Embedded data
//! A JSON header (`<script id="socdiff-meta" type="application/json">`) describes the scenes;
//! one binary blob (`<script id="socdiff-data">`, base64 of zlib-compressed bytes, decompressed
//! by the browser's `DecompressionStream`) holds, per sample and 4-byte aligned:
//! - positions as little-endian `i16` `[frames, persons, joints, 3]`, quantized to `step`
//!   metres (1 mm unless the scene spans more than ±32 m) around the scene's `origin`, and
//!   delta-coded over time (each frame minus the previous one, wrapping); a sample whose
//!   observed frames equal the first sample's stores only frames from `start` =
//!   `observed_frames` on,
//! - the validity mask as `u8` `[frames, persons]` when the scene has invalid frames,
//! - each signal as little-endian `f32` `[frames, persons]`.
//!
//! [`read_view_data`] decodes a page back (used by the tests).
//!
//! # Page state for automation
//! `document.body` carries `data-ready` (`1` once drawn), `data-load-ms` (page start to first
//! drawing), `data-frame` (current frame),
//! `data-scenes`, `data-samples`, `data-persons`, `data-painted` (canvas pixels, sampled every
//! 3rd, that differ from the backgrounds) and `data-panel-coloured` (per panel, sampled
//! saturated pixels: the skeletons). The URL hash may hold `autoplay`, `frame=N`, `sample=K`
//! (or `all`), `scene=I` and `speed=X`, joined with `&`.

use super::{person_colour, SceneGroup};
use crate::files::write_file_atomic;
use crate::{bail, Error, Result};
use serde_json::{json, Value};
use std::io::Write as _;
use std::path::Path;

const TEMPLATE: &str = include_str!("viewer/viewer.html");
const CSS: &str = include_str!("viewer/viewer.css");
const JS: &str = include_str!("viewer/viewer.js");

/// Options for the viewer page.
#[derive(Clone, Debug)]
pub struct ViewOptions {
    /// Page title (default: the scene names).
    pub title: Option<String>,
    /// Show signal labels (e.g. `speaking`) above persons initially (default true).
    pub show_signals: bool,
    /// zlib level 0–9 (default 6).
    pub compression: u32,
}

impl Default for ViewOptions {
    fn default() -> Self {
        Self { title: None, show_signals: true, compression: 6 }
    }
}

/// Sizes of a rendered page.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HtmlStats {
    /// Bytes of the whole HTML file.
    pub html_bytes: usize,
    /// Bytes of binary data before compression.
    pub raw_bytes: usize,
    /// Bytes of binary data after compression (before base64).
    pub compressed_bytes: usize,
    /// Scenes embedded.
    pub scenes: usize,
    /// Samples embedded (all scenes).
    pub samples: usize,
    /// Frames × persons × samples embedded (all scenes).
    pub person_frames: usize,
}

/// Quantization of one scene's positions.
struct Quant {
    origin: [f64; 3],
    step: f64,
}

fn quantization(group: &SceneGroup) -> Quant {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for s in &group.samples {
        for v in s.scene.positions.lanes(ndarray::Axis(3)) {
            for k in 0..3 {
                lo[k] = lo[k].min(v[k] as f64);
                hi[k] = hi[k].max(v[k] as f64);
            }
        }
    }
    let origin: [f64; 3] = std::array::from_fn(|k| (0.5 * (lo[k] + hi[k]) * 1000.0).round() / 1000.0);
    let half = (0..3).map(|k| (hi[k] - origin[k]).max(origin[k] - lo[k])).fold(0.0, f64::max);
    let step = if half < 32.0 { 0.001 } else { half / 32000.0 };
    Quant { origin, step }
}

fn pad4(buf: &mut Vec<u8>) {
    buf.resize(buf.len().next_multiple_of(4), 0);
}

/// Where the camera looks, how far the scene reaches, and the floor height.
#[allow(clippy::needless_range_loop)]
fn framing(group: &SceneGroup) -> ([f64; 3], f64, f64) {
    let s = group.first();
    let (frames, persons, joints) = (s.num_frames(), s.num_persons(), s.num_joints());
    let stride = (frames / 400).max(1);
    let mut floor = f64::INFINITY;
    let (mut c, mut n) = ([0.0f64; 2], 0.0f64);
    for f in (0..frames).step_by(stride) {
        for p in 0..persons {
            if !s.is_valid(f, p) {
                continue;
            }
            for j in 0..joints {
                floor = floor.min(s.positions[[f, p, j, 2]] as f64);
            }
            for k in 0..2 {
                c[k] += 0.5 * (s.positions[[f, p, s.skeleton.left, k]] + s.positions[[f, p, s.skeleton.right, k]]) as f64;
            }
            n += 1.0;
        }
    }
    if n == 0.0 {
        floor = s.positions.iter().skip(2).step_by(3).fold(f64::INFINITY, |m, &z| m.min(z as f64));
        c = [s.positions[[0, 0, 0, 0]] as f64, s.positions[[0, 0, 0, 1]] as f64];
        n = 1.0;
    }
    let c = [c[0] / n.max(1.0), c[1] / n.max(1.0)];
    let mut radius = 1.0f64;
    for sample in &group.samples {
        for f in (0..frames).step_by(stride) {
            for p in 0..persons {
                for j in 0..joints {
                    let x = &sample.scene.positions;
                    radius = radius.max((x[[f, p, j, 0]] as f64 - c[0]).hypot(x[[f, p, j, 1]] as f64 - c[1]));
                }
            }
        }
    }
    ([c[0], c[1], floor + 0.9], radius.min(100.0) + 0.3, floor)
}

/// Appends one scene's binary sections to `buf`; returns its JSON header.
fn encode_group(group: &SceneGroup, buf: &mut Vec<u8>) -> Result<Value> {
    group.check()?;
    let first = group.first();
    let sk = &first.skeleton;
    let (frames, persons, joints) = (first.num_frames(), first.num_persons(), first.num_joints());
    let per_frame = persons * joints * 3;
    let q = quantization(group);
    let quant = |v: f32, k: usize| -> i16 { ((v as f64 - q.origin[k]) / q.step).round().clamp(-32767.0, 32767.0) as i16 };
    let mut samples = Vec::with_capacity(group.samples.len());
    for (i, sample) in group.samples.iter().enumerate() {
        let s = &sample.scene;
        let pos = s.positions.as_standard_layout();
        let flat = pos.as_slice().expect("standard layout");
        let obs = group.observed_frames.min(frames);
        let first_flat = group.samples[0].scene.positions.as_standard_layout();
        let shares = i > 0 && obs > 0 && flat[..obs * per_frame] == first_flat.as_slice().expect("standard layout")[..obs * per_frame];
        let start = if shares { obs } else { 0 };
        pad4(buf);
        let pos_offset = buf.len();
        let mut prev = vec![0i16; per_frame];
        for f in start..frames {
            for i in 0..per_frame {
                let v = quant(flat[f * per_frame + i], i % 3);
                let d = if f == start { v } else { v.wrapping_sub(prev[i]) };
                prev[i] = v;
                buf.extend_from_slice(&d.to_le_bytes());
            }
        }
        let valid = match &s.valid {
            Some(v) if v.iter().any(|&b| !b) => {
                pad4(buf);
                let off = buf.len();
                buf.extend(v.iter().map(|&b| b as u8));
                Value::from(off)
            }
            _ => Value::Null,
        };
        let mut signals = Vec::new();
        for (name, values) in &s.signals {
            pad4(buf);
            let off = buf.len();
            for v in values.iter() {
                buf.extend_from_slice(&v.to_le_bytes());
            }
            let binary = values.iter().all(|&v| v == 0.0 || v == 1.0);
            signals.push(json!({"name": name, "offset": off, "binary": binary}));
        }
        samples.push(json!({
            "label": sample.label,
            "name": s.name,
            "pos": pos_offset,
            "start": start,
            "valid": valid,
            "signals": signals,
        }));
    }
    let (center, radius, floor) = framing(group);
    let colours: Vec<String> = (0..persons)
        .map(|p| {
            let c = person_colour(p);
            format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2])
        })
        .collect();
    Ok(json!({
        "name": group.name,
        "fps": first.fps,
        "frames": frames,
        "observed": group.observed_frames,
        "joints": sk.joints,
        "bones": sk.bones,
        "persons": first.persons,
        "colours": colours,
        "origin": q.origin,
        "step": q.step,
        "center": center,
        "radius": radius,
        "floor": floor,
        "samples": samples,
    }))
}

const B64: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

fn base64(data: &[u8]) -> String {
    let mut out = String::with_capacity(data.len().div_ceil(3) * 4);
    for chunk in data.chunks(3) {
        let b = [chunk[0], *chunk.get(1).unwrap_or(&0), *chunk.get(2).unwrap_or(&0)];
        let n = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        for i in 0..4 {
            if i <= chunk.len() {
                out.push(B64[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

fn unbase64(text: &str) -> Result<Vec<u8>> {
    let mut lut = [255u8; 256];
    for (i, &c) in B64.iter().enumerate() {
        lut[c as usize] = i as u8;
    }
    let bytes: Vec<u8> = text.bytes().filter(|b| !b.is_ascii_whitespace()).collect();
    let mut out = Vec::with_capacity(bytes.len() / 4 * 3);
    for chunk in bytes.chunks(4) {
        let mut n = 0u32;
        let mut valid = 0usize;
        for (i, &c) in chunk.iter().enumerate() {
            if c == b'=' {
                break;
            }
            let v = lut[c as usize];
            if v == 255 {
                bail!("viewer data: invalid base64 character {:?}", c as char);
            }
            n |= (v as u32) << (18 - 6 * i);
            valid += 1;
        }
        for i in 0..valid.saturating_sub(1) {
            out.push((n >> (16 - 8 * i)) as u8);
        }
    }
    Ok(out)
}

fn escape_html(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// Fills `{{KEY}}` placeholders of the template (only the template is scanned).
fn fill(template: &str, values: &[(&str, &str)]) -> String {
    let extra: usize = values.iter().map(|(_, v)| v.len()).sum();
    let mut out = String::with_capacity(template.len() + extra);
    let mut rest = template;
    while let Some(i) = rest.find("{{") {
        out.push_str(&rest[..i]);
        let after = &rest[i + 2..];
        match after.find("}}").and_then(|j| values.iter().find(|(k, _)| *k == &after[..j]).map(|(_, v)| (j, v))) {
            Some((j, v)) => {
                out.push_str(v);
                rest = &after[j + 2..];
            }
            None => {
                out.push_str("{{");
                rest = after;
            }
        }
    }
    out.push_str(rest);
    out
}

/// Renders the viewer page for `groups` (see the module docs).
pub fn render_html(groups: &[SceneGroup], opts: &ViewOptions) -> Result<(String, HtmlStats)> {
    if groups.is_empty() {
        bail!("nothing to view: no scenes");
    }
    if opts.compression > 9 {
        bail!("compression level {} is not 0–9", opts.compression);
    }
    let mut buf = Vec::new();
    let mut scenes = Vec::with_capacity(groups.len());
    for g in groups {
        scenes.push(encode_group(g, &mut buf)?);
    }
    let raw_bytes = buf.len();
    let mut enc = flate2::write::ZlibEncoder::new(Vec::with_capacity(raw_bytes / 3), flate2::Compression::new(opts.compression));
    enc.write_all(&buf).map_err(|e| Error::invalid(format!("compressing viewer data: {e}")))?;
    let compressed = enc.finish().map_err(|e| Error::invalid(format!("compressing viewer data: {e}")))?;
    drop(buf);
    let title = opts.title.clone().unwrap_or_else(|| {
        let names: Vec<&str> = groups.iter().map(|g| g.name.as_str()).collect();
        if names.len() <= 3 {
            format!("socdiff · {}", names.join(", "))
        } else {
            format!("socdiff · {} scenes", names.len())
        }
    });
    let meta = json!({
        "version": 1,
        "title": title,
        "encoding": "zlib; i16 positions delta-coded over time",
        "raw_bytes": raw_bytes,
        "show_signals": opts.show_signals,
        "scenes": scenes,
    });
    // `<` is escaped so that no name can close the script element.
    let meta_text = serde_json::to_string(&meta).map_err(|e| Error::invalid(e.to_string()))?.replace('<', "\\u003c");
    let blob = base64(&compressed);
    let title_html = escape_html(&title);
    let html =
        fill(TEMPLATE, &[("TITLE", &title_html), ("VERSION", env!("CARGO_PKG_VERSION")), ("CSS", CSS), ("JS", JS), ("META", &meta_text), ("DATA", &blob)]);
    let stats = HtmlStats {
        html_bytes: html.len(),
        raw_bytes,
        compressed_bytes: compressed.len(),
        scenes: groups.len(),
        samples: groups.iter().map(|g| g.samples.len()).sum(),
        person_frames: groups.iter().map(|g| g.samples.len() * g.num_frames() * g.first().num_persons()).sum(),
    };
    Ok((html, stats))
}

/// Writes the viewer page for `groups` to `path` (atomically).
pub fn write_html(path: &Path, groups: &[SceneGroup], opts: &ViewOptions) -> Result<HtmlStats> {
    let (html, stats) = render_html(groups, opts)?;
    write_file_atomic(path, html.as_bytes())?;
    Ok(stats)
}

/// One sample decoded from a viewer page.
#[derive(Clone, Debug, PartialEq)]
pub struct DecodedSample {
    /// Label shown in the page.
    pub label: String,
    /// Positions `[frames, persons, joints, 3]`, metres (quantized).
    pub positions: ndarray::Array4<f32>,
    /// Validity mask, when embedded.
    pub valid: Option<ndarray::Array2<bool>>,
    /// Signals by name.
    pub signals: std::collections::BTreeMap<String, ndarray::Array2<f32>>,
}

/// One scene decoded from a viewer page.
#[derive(Clone, Debug, PartialEq)]
pub struct DecodedScene {
    /// Scene name.
    pub name: String,
    /// Observed frames.
    pub observed_frames: usize,
    /// Joint names.
    pub joints: Vec<String>,
    /// Quantization step, metres.
    pub step: f64,
    /// The samples.
    pub samples: Vec<DecodedSample>,
}

/// Decodes the data embedded in a viewer page written by [`render_html`].
pub fn read_view_data(html: &str) -> Result<Vec<DecodedScene>> {
    let section = |id: &str| -> Result<&str> {
        let open = format!("id=\"{id}\">");
        let start = html.find(&open).ok_or_else(|| Error::invalid(format!("viewer page has no {id} element")))? + open.len();
        let len = html[start..].find("</script>").ok_or_else(|| Error::invalid(format!("viewer page: {id} is not closed")))?;
        Ok(&html[start..start + len])
    };
    let meta: Value = serde_json::from_str(section("socdiff-meta")?).map_err(|e| Error::invalid(format!("viewer meta: {e}")))?;
    let compressed = unbase64(section("socdiff-data")?)?;
    let mut buf = Vec::new();
    std::io::Read::read_to_end(&mut flate2::read::ZlibDecoder::new(&compressed[..]), &mut buf)
        .map_err(|e| Error::invalid(format!("viewer data does not decompress: {e}")))?;
    let bad = || Error::invalid("viewer meta is malformed");
    let num = |v: &Value| v.as_u64().map(|x| x as usize).ok_or_else(bad);
    let mut out = Vec::new();
    for sc in meta["scenes"].as_array().ok_or_else(bad)? {
        let frames = num(&sc["frames"])?;
        let persons = sc["persons"].as_array().ok_or_else(bad)?.len();
        let joints: Vec<String> = serde_json::from_value(sc["joints"].clone()).map_err(|_| bad())?;
        let step = sc["step"].as_f64().ok_or_else(bad)?;
        let origin: [f64; 3] = serde_json::from_value(sc["origin"].clone()).map_err(|_| bad())?;
        let per_frame = persons * joints.len() * 3;
        let mut samples: Vec<DecodedSample> = Vec::new();
        let mut first_q: Vec<i16> = Vec::new();
        for sm in sc["samples"].as_array().ok_or_else(bad)? {
            let (off, start) = (num(&sm["pos"])?, num(&sm["start"])?);
            let mut q = vec![0i16; frames * per_frame];
            q[..start * per_frame].copy_from_slice(first_q.get(..start * per_frame).ok_or_else(bad)?);
            let stored = (frames - start) * per_frame;
            let bytes = buf.get(off..off + 2 * stored).ok_or_else(bad)?;
            for i in 0..stored {
                let d = i16::from_le_bytes([bytes[2 * i], bytes[2 * i + 1]]);
                let at = start * per_frame + i;
                q[at] = if i < per_frame { d } else { q[at - per_frame].wrapping_add(d) };
            }
            if first_q.is_empty() {
                first_q = q.clone();
            }
            let positions = ndarray::Array4::from_shape_fn((frames, persons, joints.len(), 3), |(f, p, j, k)| {
                (origin[k] + step * q[((f * persons + p) * joints.len() + j) * 3 + k] as f64) as f32
            });
            let valid = match &sm["valid"] {
                Value::Null => None,
                v => {
                    let o = num(v)?;
                    let b = buf.get(o..o + frames * persons).ok_or_else(bad)?;
                    Some(ndarray::Array2::from_shape_fn((frames, persons), |(f, p)| b[f * persons + p] != 0))
                }
            };
            let mut signals = std::collections::BTreeMap::new();
            for g in sm["signals"].as_array().ok_or_else(bad)? {
                let o = num(&g["offset"])?;
                let b = buf.get(o..o + 4 * frames * persons).ok_or_else(bad)?;
                let a = ndarray::Array2::from_shape_fn((frames, persons), |(f, p)| {
                    let i = 4 * (f * persons + p);
                    f32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]])
                });
                signals.insert(g["name"].as_str().ok_or_else(bad)?.to_string(), a);
            }
            samples.push(DecodedSample { label: sm["label"].as_str().unwrap_or("").to_string(), positions, valid, signals });
        }
        out.push(DecodedScene { name: sc["name"].as_str().ok_or_else(bad)?.to_string(), observed_frames: num(&sc["observed"])?, joints, step, samples });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::super::{group_scenes, ForecastInfo, Sample, SceneGroup};
    use super::*;
    use crate::data::dataset::{Dataset, Sequence, Split};
    use crate::data::test_util::{mupots, tmp, walkers};
    use crate::Scene;
    use ndarray::{s, Array2, Array4};

    fn max_abs_diff(a: &Array4<f32>, b: &Array4<f32>) -> f32 {
        a.iter().zip(b.iter()).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
    }

    #[test]
    fn base64_round_trips() {
        for n in 0..10 {
            let data: Vec<u8> = (0..n * 7 + n % 3).map(|i| (i * 37 % 256) as u8).collect();
            assert_eq!(unbase64(&base64(&data)).unwrap(), data);
        }
        assert_eq!(base64(b"Man"), "TWFu");
        assert_eq!(base64(b"Ma"), "TWE=");
        assert_eq!(base64(b"M"), "TQ==");
        assert_eq!(fill("a{{X}}b{{Y}}{{Z}}", &[("X", "{{Y}}"), ("Y", "2")]), "a{{Y}}b2{{Z}}");
    }

    /// A forecast group: `k` samples sharing the first `obs` frames of `base`, diverging after.
    fn forecast_group(base: &Scene, obs: usize, k: usize) -> SceneGroup {
        let mut seqs = Vec::new();
        for i in 0..k {
            let mut s = base.clone();
            s.name = format!("{}_s{i}", base.name);
            let (frames, persons, joints, _) = s.positions.dim();
            for f in obs..frames {
                for p in 0..persons {
                    let drift = (f - obs) as f32 * 0.004 * (i as f32 - 0.5 * k as f32) * ((p % 3) as f32 - 1.0);
                    for j in 0..joints {
                        s.positions[[f, p, j, 0]] += drift;
                        s.positions[[f, p, j, 1]] += 0.5 * drift;
                    }
                }
            }
            ForecastInfo { observed_frames: obs, sample: Some(i), source: base.name.clone() }.insert_into(&mut s.metadata);
            seqs.push(Sequence { split: Split::Test, scene: s });
        }
        group_scenes(&Dataset { name: "fc".into(), sequences: seqs, metadata: Default::default() }, None).unwrap().remove(0)
    }

    #[test]
    fn page_embeds_every_person_and_sample() {
        let mut base = walkers(120, 3, 0.2);
        base.valid = Some(Array2::from_shape_fn((120, 3), |(f, p)| !(p == 2 && (30..40).contains(&f))));
        let base = base.with_signal("speaking", Array2::from_shape_fn((120, 3), |(f, p)| ((f / 20 + p) % 2) as f32)).unwrap();
        let group = forecast_group(&base, 50, 4);
        let other = SceneGroup::single(walkers(40, 2, 1.0), Some(30)).unwrap();
        let dir = tmp("html");
        let path = dir.join("view.html");
        let stats = write_html(&path, &[group.clone(), other.clone()], &ViewOptions::default()).unwrap();
        let html = std::fs::read_to_string(&path).unwrap();
        assert_eq!(stats.html_bytes, html.len());
        assert_eq!((stats.scenes, stats.samples, stats.person_frames), (2, 5, 4 * 120 * 3 + 40 * 2));
        assert!(!html.contains("http://") && !html.contains("https://"), "no network references");
        assert!(!html.contains("{{"), "all placeholders filled");
        let decoded = read_view_data(&html).unwrap();
        assert_eq!(decoded.len(), 2);
        let d = &decoded[0];
        assert_eq!((d.name.as_str(), d.observed_frames, d.samples.len()), ("walkers", 50, 4));
        assert_eq!(d.joints, base.skeleton.joints);
        let mut worst = 0.0f32;
        for (ds, gs) in d.samples.iter().zip(&group.samples) {
            assert_eq!(ds.label, gs.label);
            assert_eq!(ds.positions.dim(), (120, 3, 17, 3));
            worst = worst.max(max_abs_diff(&ds.positions, &gs.scene.positions));
            assert_eq!(ds.valid.as_ref(), gs.scene.valid.as_ref());
            assert_eq!(ds.signals["speaking"], gs.scene.signals["speaking"]);
        }
        println!("decoded max position error {:.3} mm (step {} m); {stats:?}", worst * 1000.0, d.step);
        assert!(worst <= 0.0005 + 1e-6, "quantization error {worst}");
        // Samples 1..3 share the observed frames with sample 0: stored once.
        let meta_start = html.find("id=\"socdiff-meta\">").unwrap();
        assert!(html[meta_start..].contains("\"start\":50"));
        assert_eq!(decoded[1].samples[0].positions.slice(s![.., 1, .., ..]).dim(), (40usize, 17usize, 3usize));
        assert!(max_abs_diff(&decoded[1].samples[0].positions, &other.samples[0].scene.positions) <= 0.0005 + 1e-6);
        // Names cannot break out of the script element.
        let mut evil = walkers(5, 1, 0.0);
        evil.name = "</script><b>x".into();
        let (h, _) = render_html(&[SceneGroup::single(evil, None).unwrap()], &ViewOptions::default()).unwrap();
        assert!(!h.contains("</script><b>"));
        assert_eq!(read_view_data(&h).unwrap()[0].name, "</script><b>x");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// 7 persons × 2,000 frames × 8 samples from real motion when available.
    fn big_group() -> (SceneGroup, &'static str) {
        let (frames, persons, k, obs) = (2000, 7, 8, 500);
        // Persons: real MuPoTS people (ping-pong looped to 2,000 frames), else synthetic walkers.
        let (source, tracks): (&str, Vec<Array4<f32>>) = match mupots() {
            Some(ds) => {
                let mut tracks = Vec::new();
                'outer: for seq in &ds.sequences {
                    for p in 0..seq.scene.num_persons() {
                        tracks.push(seq.scene.positions.slice(s![.., p..p + 1, .., ..]).to_owned());
                        if tracks.len() == persons + k {
                            break 'outer;
                        }
                    }
                }
                ("MuPoTS persons", tracks)
            }
            None => ("synthetic walkers", (0..persons + k).map(|i| walkers(300, 1, i as f32).positions).collect()),
        };
        let looped = |t: &Array4<f32>, shift: usize, dx: f32| -> Array4<f32> {
            let n = t.dim().0;
            Array4::from_shape_fn((frames, 1, t.dim().2, 3), |(f, _, j, c)| {
                let g = (f + shift) % (2 * n - 2);
                let g = if g < n { g } else { 2 * n - 2 - g };
                t[[g, 0, j, c]] + if c == 0 { dx } else { 0.0 }
            })
        };
        let sk = crate::Skeleton::mupots17();
        let mut samples = Vec::new();
        for i in 0..k {
            let mut parts = Vec::new();
            for p in 0..persons {
                // The forecast continues with another real track for each sample.
                let obs_part = looped(&tracks[p], 0, p as f32 * 1.2);
                let fc_part = looped(&tracks[(p + i) % tracks.len()], 37 * i, p as f32 * 1.2);
                let mut x = obs_part.clone();
                if i > 0 {
                    x.slice_mut(s![obs.., .., .., ..]).assign(&fc_part.slice(s![obs.., .., .., ..]));
                }
                parts.push(x);
            }
            let views: Vec<_> = parts.iter().map(|a| a.view()).collect();
            let pos = ndarray::concatenate(ndarray::Axis(1), &views).unwrap();
            let scene = Scene::new("big", 30.0, sk.clone(), pos).unwrap();
            samples.push(Sample { label: format!("sample {i}"), scene });
        }
        (SceneGroup { name: "big".into(), observed_frames: obs, samples }, source)
    }

    #[test]
    fn page_for_7_persons_2000_frames_8_samples_is_compact() {
        let (group, source) = big_group();
        let t = std::time::Instant::now();
        let (html, stats) = render_html(std::slice::from_ref(&group), &ViewOptions::default()).unwrap();
        let secs = t.elapsed().as_secs_f64();
        let decoded = read_view_data(&html).unwrap();
        assert_eq!(decoded[0].samples.len(), 8);
        for (d, g) in decoded[0].samples.iter().zip(&group.samples) {
            assert!(max_abs_diff(&d.positions, &g.scene.positions) <= 0.0005 + 1e-6);
        }
        let values = 7 * 2000 * 8 * 17 * 3;
        println!(
            "7 persons × 2000 frames × 8 samples ({source}, 17 joints): HTML {:.2} MB ({:.2} bytes per value); int16 data {:.2} MB, \
             zlib {:.2} MB; as JSON numbers it would be ~{:.0} MB; rendered in {secs:.2} s",
            stats.html_bytes as f64 / 1e6,
            stats.html_bytes as f64 / values as f64,
            stats.raw_bytes as f64 / 1e6,
            stats.compressed_bytes as f64 / 1e6,
            values as f64 * 7.0 / 1e6,
        );
        assert!(stats.html_bytes < 8_000_000, "{} bytes", stats.html_bytes);
        // SOCDIFF_KEEP_HTML=path keeps the page, to try it in a browser.
        if let Some(p) = std::env::var_os("SOCDIFF_KEEP_HTML") {
            std::fs::write(p, &html).unwrap();
        }
    }
}
