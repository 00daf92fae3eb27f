//! `socdiff view` end to end, checked in a real browser: the page is opened in headless
//! Chromium, which must draw skeletons on the canvas, advance the frame counter after Play is
//! pressed, and save a screenshot. Without Chromium (set SOCDIFF_CHROMIUM to its path, or have
//! `chromium` on PATH) the browser checks are skipped, saying so.

use ndarray::Array2;
use socdiff_engine::data::bvh::{import_bvh, BvhImport, CMU_SCALE};
use socdiff_engine::data::dataset::{write_dataset, Sequence};
use socdiff_engine::export::png::read_png_rgb;
use socdiff_engine::export::ForecastInfo;
use socdiff_engine::{Dataset, Scene, Split};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
mod common;

use common::{assert_fails, cmu_clip, socdiff, tmp};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// A forecast dataset: the CMU clip as 3 persons on a circle (time-shifted), observed for 150
/// frames, and 4 samples whose futures differ; persons take turns "speaking".
fn forecast_dataset(dir: &Path) -> (usize, usize, usize) {
    let clip = import_bvh(cmu_clip(), &BvhImport { scale: CMU_SCALE, ..Default::default() }).unwrap();
    let frames = 240;
    let parts: Vec<Scene> = (0..3).map(|p| clip.slice_frames(p * 20, p * 20 + frames).unwrap()).collect();
    let group = Scene::around_circle("clip3", &parts, 1.6).unwrap();
    let speaking = Array2::from_shape_fn((frames, 3), |(f, p)| ((f / 40) % 3 == p) as u8 as f32);
    let mut sequences = Vec::new();
    for k in 0..4 {
        let mut s = group.clone().with_signal("speaking", speaking.clone()).unwrap();
        s.name = format!("clip3_s{k}");
        for f in 150..frames {
            for p in 0..3 {
                for j in 0..s.num_joints() {
                    s.positions[[f, p, j, 0]] += (f - 150) as f32 * 0.006 * (k as f32 - 1.5);
                    s.positions[[f, p, j, 1]] += (f - 150) as f32 * 0.004 * (p as f32 - 1.0);
                }
            }
        }
        ForecastInfo { observed_frames: 150, sample: Some(k), source: "clip3".into() }.insert_into(&mut s.metadata);
        sequences.push(Sequence { split: Split::Test, scene: s });
    }
    write_dataset(&Dataset { name: "forecast".into(), sequences, metadata: Default::default() }, dir).unwrap();
    (frames, 3, 4)
}

fn chromium() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("SOCDIFF_CHROMIUM") {
        return Some(PathBuf::from(p));
    }
    let path = std::env::var_os("PATH")?;
    for name in ["chromium", "chromium-browser", "google-chrome", "google-chrome-stable"] {
        for dir in std::env::split_paths(&path) {
            let p = dir.join(name);
            if p.is_file() {
                return Some(p);
            }
        }
    }
    None
}

/// Runs headless Chromium on `url` with `extra` arguments; returns stdout. A fresh profile
/// directory each time; killed after 120 s.
fn run_chromium(bin: &Path, url: &str, extra: &[String]) -> String {
    static RUNS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let profile = tmp(&format!("profile-{}", RUNS.fetch_add(1, std::sync::atomic::Ordering::Relaxed)));
    std::fs::create_dir_all(&profile).unwrap();
    let mut cmd = Command::new(bin);
    cmd.args([
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--hide-scrollbars",
        "--force-device-scale-factor=1",
        "--window-size=1280,800",
    ])
    .arg(format!("--user-data-dir={}", profile.display()))
    .args(extra)
    .arg(url)
    .stdout(Stdio::piped())
    .stderr(Stdio::null());
    let mut child = cmd.spawn().expect("chromium starts");
    let start = Instant::now();
    let mut stdout = child.stdout.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        std::io::Read::read_to_string(&mut stdout, &mut s).ok();
        s
    });
    loop {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        if start.elapsed() > Duration::from_secs(120) {
            child.kill().ok();
            child.wait().ok();
            panic!("chromium did not finish within 120 s");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let out = reader.join().unwrap();
    let _ = std::fs::remove_dir_all(&profile);
    out
}

/// The `data-*` attributes of `<body>` in a DOM dump.
fn body_data(dom: &str) -> BTreeMap<String, String> {
    let start = dom.find("<body").unwrap_or_else(|| panic!("no <body> in DOM dump: {}", &dom[..dom.len().min(400)]));
    let tag = &dom[start..start + dom[start..].find('>').unwrap()];
    let mut out = BTreeMap::new();
    let mut rest = tag;
    while let Some(i) = rest.find("data-") {
        rest = &rest[i + 5..];
        let eq = rest.find("=\"").unwrap();
        let key = rest[..eq].to_string();
        let end = rest[eq + 2..].find('"').unwrap();
        out.insert(key, rest[eq + 2..eq + 2 + end].to_string());
        rest = &rest[eq + 2 + end..];
    }
    out
}

#[test]
fn view_forecast_dataset_in_headless_chromium() {
    let dir = tmp("forecast");
    let (frames, persons, samples) = forecast_dataset(&dir);
    let page = dir.with_extension("html");
    let (ok, stdout, err) = socdiff(&["view", dir.to_str().unwrap(), "--out", page.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(stdout.contains("1 scene, 4 samples, 960 frames, up to 3 persons"), "{stdout}");
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(!html.contains("src=\"http") && !html.contains("href=\"http"), "no network resources");
    let decoded = socdiff_engine::export::html::read_view_data(&html).unwrap();
    assert_eq!(decoded[0].samples.len(), samples);
    assert_eq!(decoded[0].samples[2].positions.dim().0, frames);
    assert_eq!(decoded[0].samples[3].signals["speaking"].dim(), (frames, persons));

    let Some(bin) = chromium() else {
        eprintln!("skipping the browser checks: no chromium on PATH (set SOCDIFF_CHROMIUM to use another)");
        std::fs::remove_dir_all(&dir).unwrap();
        return;
    };
    let url = format!("file://{}", page.canonicalize().unwrap().display());
    let budget = |ms: u32| format!("--virtual-time-budget={ms}");

    // Loaded, paused at frame 0: every sample's panel shows coloured skeletons.
    let dom = run_chromium(&bin, &format!("{url}#frame=0"), &[budget(3000), "--dump-dom".into()]);
    let d = body_data(&dom);
    println!("paused: {d:?}");
    assert_eq!(d.get("ready").map(String::as_str), Some("1"), "page did not finish loading: {d:?} {}", d.get("error").cloned().unwrap_or_default());
    assert_eq!(d["frame"], "0");
    assert_eq!((d["samples"].as_str(), d["persons"].as_str()), ("4", "3"));
    let painted: usize = d["painted"].parse().unwrap();
    let panels: Vec<usize> = d["panel-coloured"].split(',').map(|v| v.parse().unwrap()).collect();
    assert!(painted > 2000, "canvas is nearly blank: {painted}");
    assert_eq!(panels.len(), samples, "one panel per sample");
    assert!(panels.iter().all(|&n| n > 100), "a panel has no skeletons: {panels:?}");

    // Pressing Play (via #autoplay, which clicks the button) advances the frame counter:
    // about 3 s × 30 fps in 3 s of virtual time.
    let dom = run_chromium(&bin, &format!("{url}#autoplay"), &[budget(3000), "--dump-dom".into()]);
    let d = body_data(&dom);
    println!("after play: {d:?}");
    let frame: usize = d["frame"].parse().unwrap();
    assert_eq!(d.get("playing").map(String::as_str), Some("1"));
    assert!((30..frames).contains(&frame), "frame counter after 3 s of play: {frame}");

    // Screenshot of a forecast frame with all samples side by side.
    let shot = Path::new(env!("CARGO_TARGET_TMPDIR")).join("socdiff_view_screenshot.png");
    let _ = std::fs::remove_file(&shot);
    run_chromium(&bin, &format!("{url}#frame=200"), &[budget(3000), format!("--screenshot={}", shot.display())]);
    let (w, h, rgb) = read_png_rgb(&shot).unwrap();
    assert_eq!((w, h), (1280, 800));
    let px = |i: usize| [rgb[3 * i], rgb[3 * i + 1], rgb[3 * i + 2]];
    let saturated = (0..(w * h) as usize)
        .filter(|&i| {
            let c = px(i);
            c.iter().max().unwrap() - c.iter().min().unwrap() > 70
        })
        .count();
    let orange = (0..(w * h) as usize).filter(|&i| px(i) == [240, 160, 48]).count();
    let distinct: std::collections::BTreeSet<[u8; 3]> = (0..(w * h) as usize).step_by(7).map(px).collect();
    println!("screenshot {} ({w}×{h}): {saturated} saturated pixels, {orange} forecast-orange pixels, {} colours", shot.display(), distinct.len());
    assert!(saturated > 3000, "screenshot shows no skeletons");
    assert!(orange > 200, "forecast frames are marked in orange");
    std::fs::remove_dir_all(&dir).unwrap();
    std::fs::remove_file(&page).unwrap();
}

#[test]
fn view_errors_are_one_line_and_write_nothing() {
    let dir = tmp("errors");
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("page.html");
    let cases: Vec<(Vec<String>, Vec<&str>)> = vec![
        (vec!["view".into(), "/nonexistent/motion.bvh".into()], vec!["/nonexistent/motion.bvh", "no such file"]),
        (vec!["view".into(), cmu_clip().display().to_string(), "--observed".into(), "999".into()], vec!["--observed 999", "303 frames"]),
        (vec!["view".into(), cmu_clip().display().to_string(), "--sequence".into(), "nope".into()], vec!["nope", "cmu_18_01"]),
    ];
    let bad = dir.join("broken.bvh");
    std::fs::write(&bad, "HIERARCHY\nROOT hip\n{\n  OFFSET 0 0 0\n").unwrap();
    let mut cases = cases;
    cases.push((vec!["view".into(), bad.display().to_string()], vec!["broken.bvh", "missing `}`"]));
    for (mut args, names) in cases {
        args.extend(["--out".to_string(), out.display().to_string()]);
        assert_fails(&args, &names, &out);
    }
    // A plain BVH with --observed: frames 200.. are forecast.
    let (ok, stdout, err) = socdiff(&["view", cmu_clip().to_str().unwrap(), "--observed", "200", "--out", out.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(stdout.contains("1 scene, 1 sample, 303 frames"), "{stdout}");
    let decoded = socdiff_engine::export::html::read_view_data(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(decoded[0].observed_frames, 200);
    std::fs::remove_dir_all(&dir).unwrap();
}
