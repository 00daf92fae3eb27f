//! `socdiff export --format bvh|json|png` end to end: files that read back to the input, and
//! bad input that gives one error line naming the file, a non-zero exit and no output.

use socdiff_engine::data::bvh::{import_bvh, BvhImport, CMU_SCALE};
use socdiff_engine::export::json::read_json;
use socdiff_engine::export::png::read_png_rgb;
mod common;

use common::{assert_fails, cmu_clip, shared, socdiff, tmp};
use std::path::PathBuf;

fn max_error(a: &socdiff_engine::Scene, pa: usize, b: &socdiff_engine::Scene) -> f64 {
    let mut worst = 0.0f64;
    for (j, name) in a.skeleton.joints.iter().enumerate() {
        let jb = b.skeleton.require_joint(name).unwrap();
        for f in 0..a.num_frames() {
            if !a.is_valid(f, pa) {
                continue;
            }
            let d = (0..3).map(|k| (a.positions[[f, pa, j, k]] - b.positions[[f, 0, jb, k]]) as f64).map(|x| x * x).sum::<f64>().sqrt();
            worst = worst.max(d);
        }
    }
    worst
}

#[test]
fn bvh_export_of_the_cmu_clip_reimports_within_2_cm() {
    let out = tmp("bvh-cmu");
    let (ok, stdout, err) = socdiff(&["export", cmu_clip().to_str().unwrap(), "--format", "bvh", "--out", out.to_str().unwrap(), "--bvh-scale", "cmu"]);
    assert!(ok, "{err}");
    assert!(stdout.contains("1 BVH files (1 sequence, centimetres, root hip)"), "{stdout}");
    let original = import_bvh(cmu_clip(), &BvhImport { scale: CMU_SCALE, ..Default::default() }).unwrap();
    let back = import_bvh(out.join("cmu_18_01.bvh"), &BvhImport { scale: 0.01, ..Default::default() }).unwrap();
    assert_eq!((back.num_frames(), back.num_joints(), back.fps), (303, 31, 30.0));
    let e = max_error(&original, 0, &back);
    println!("CMU 18_01 via the CLI: re-import max error {:.2e} cm; {stdout}", e * 100.0);
    assert!(e < 0.02);
    // The exported file is itself a valid input: `data inspect` reads it with --bvh-scale auto.
    let (ok, info, err) = socdiff(&["data", "inspect", out.join("cmu_18_01.bvh").to_str().unwrap()]);
    assert!(ok && info.contains("frames        303"), "{info}{err}");
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn bvh_export_of_mupots_fixed_and_stretch() {
    let Some(dir) = shared("mupots3d") else { return };
    let (fixed, exact) = (tmp("bvh-ts16"), tmp("bvh-ts16-stretch"));
    let d = dir.to_str().unwrap();
    let (ok, out1, err) = socdiff(&["export", d, "--format", "bvh", "--sequence", "TS16", "--out", fixed.to_str().unwrap()]);
    assert!(ok, "{err}");
    let (ok, out2, err) = socdiff(&["export", d, "--format", "bvh", "--sequence", "TS16", "--stretch", "--out", exact.to_str().unwrap()]);
    assert!(ok, "{err}");
    println!("{out1}{out2}");
    let ds = socdiff_engine::data::import::load(&dir, &Default::default()).unwrap();
    let ts16 = ds.scene("TS16").unwrap();
    for p in 0..3 {
        let name = format!("TS16_{p}.bvh");
        let opts = BvhImport { scale: 0.01, ..Default::default() };
        let e_fixed = max_error(ts16, p, &import_bvh(fixed.join(&name), &opts).unwrap());
        let e_exact = max_error(ts16, p, &import_bvh(exact.join(&name), &opts).unwrap());
        println!("TS16 person {p}: fixed skeleton max error {:.2} cm, --stretch {:.5} cm", e_fixed * 100.0, e_exact * 100.0);
        assert!(e_fixed < 0.12, "fixed skeleton: {e_fixed}");
        assert!(e_exact < 0.0001, "stretch: {e_exact}");
    }
    std::fs::remove_dir_all(&fixed).unwrap();
    std::fs::remove_dir_all(&exact).unwrap();
}

#[test]
fn json_and_png_exports() {
    let dir = tmp("json-png");
    std::fs::create_dir_all(&dir).unwrap();
    let clip = cmu_clip();
    let json = dir.join("clip.json");
    let (ok, stdout, err) = socdiff(&["export", clip.to_str().unwrap(), "--format", "json", "--out", json.to_str().unwrap(), "--bvh-scale", "cmu"]);
    assert!(ok, "{err}");
    assert!(stdout.contains("303 frames × 1 persons"), "{stdout}");
    let back = read_json(&json).unwrap();
    let original = import_bvh(&clip, &BvhImport { scale: CMU_SCALE, ..Default::default() }).unwrap();
    assert_eq!(back.positions, original.positions, "JSON round trip is exact");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!((v["frames"].as_u64(), v["fps"].as_f64(), v["joints"].as_array().map(|a| a.len())), (Some(303), Some(30.0), Some(31)));

    let png = dir.join("clip.png");
    let (ok, stdout, err) = socdiff(&[
        "export",
        clip.to_str().unwrap(),
        "--format",
        "png",
        "--out",
        png.to_str().unwrap(),
        "--frames",
        "5",
        "--panel",
        "200x240",
        "--observed",
        "150",
    ]);
    assert!(ok, "{err}");
    assert!(stdout.contains("5 frames × 1 samples"), "{stdout}");
    let (w, h, rgb) = read_png_rgb(&png).unwrap();
    assert_eq!((w, h), (1000, 240));
    for col in 0..5usize {
        let blue =
            (0..240usize).flat_map(|y| (col * 200..col * 200 + 199).map(move |x| y * 1000 + x)).filter(|&i| rgb[3 * i] < 90 && rgb[3 * i + 2] > 150).count();
        // Frames 0, 75 observed (blue bar); 151, 226, 302 forecast (orange bar).
        let bar = &rgb[3 * (col * 200 + 100)..3 * (col * 200 + 100) + 3];
        let want: &[u8] = if col < 2 { &[91, 141, 239] } else { &[240, 160, 48] };
        println!("panel {col}: {blue} skeleton-blue pixels, bar {bar:?}");
        assert!(blue > 300, "panel {col} is empty");
        assert_eq!(bar, want);
    }

    if let Some(m) = shared("mupots3d") {
        let out = dir.join("mupots_json");
        let (ok, stdout, err) = socdiff(&["export", m.to_str().unwrap(), "--format", "json", "--out", out.to_str().unwrap()]);
        assert!(ok && stdout.contains("20 JSON files"), "{stdout}{err}");
        assert_eq!(read_json(&out.join("TS15.json")).unwrap().num_invalid(), 116);
        let out = dir.join("mupots_png");
        let (ok, stdout, err) = socdiff(&["export", m.to_str().unwrap(), "--format", "png", "--frames", "4", "--out", out.to_str().unwrap()]);
        assert!(ok && stdout.contains("20 filmstrips of 4 frames"), "{stdout}{err}");
        assert_eq!(read_png_rgb(&out.join("TS7.png")).unwrap().0, 1280);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn export_errors_are_one_line_and_write_nothing() {
    let dir = tmp("errors");
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("broken.bvh");
    std::fs::write(&bad, "HIERARCHY\nROOT hip\n{\n  OFFSET 0 0 0\n  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n}\nMOTION\nFrames: 2\nFrame Time: 0.04\n0 0 0 0 0 0\n0 0\n").unwrap();
    let full = dir.join("full");
    std::fs::create_dir_all(&full).unwrap();
    std::fs::write(full.join("keep.txt"), "x").unwrap();
    let clip = cmu_clip().display().to_string();
    let s = |v: &[&str]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>();
    let out = dir.join("out");
    let o = out.display().to_string();
    let cases: Vec<(Vec<String>, Vec<&str>, PathBuf)> = vec![
        (s(&["export", "/nonexistent/x.bvh", "--format", "bvh", "--out", &o]), vec!["/nonexistent/x.bvh"], out.clone()),
        (s(&["export", bad.to_str().unwrap(), "--format", "bvh", "--out", &o]), vec!["broken.bvh", "line 11"], out.clone()),
        (s(&["export", &clip, "--format", "bvh", "--out", full.to_str().unwrap()]), vec!["full", "not empty"], dir.join("none")),
        (s(&["export", &clip, "--format", "bvh", "--out", &o, "--root", "tail"]), vec!["tail"], out.clone()),
        (s(&["export", &clip, "--format", "png", "--out", &o, "--frames", "400"]), vec!["--frames 400", "303 frames"], out.clone()),
        (s(&["export", &clip, "--format", "png", "--out", &format!("{o}.json")]), vec!["out.json", ".png"], dir.join("out.json")),
        (s(&["export", &clip, "--format", "png", "--out", &o, "--panel", "big"]), vec!["--panel", "WIDTHxHEIGHT"], out.clone()),
        (s(&["export", &clip, "--format", "json", "--out", &format!("{o}.json"), "--sequence", "x"]), vec!["\"x\"", "cmu_18_01"], dir.join("out.json")),
    ];
    for (args, names, must_not_exist) in cases {
        assert_fails(&args, &names, &must_not_exist);
    }
    assert_eq!(std::fs::read_to_string(full.join("keep.txt")).unwrap(), "x", "existing output untouched");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `socdiff retarget` of the three persons of MuPoTS TS16 onto a bandai2 body and onto the CMU
/// clip's body: on every frame every bone has the target's length within 1 mm and the source's
/// direction within 1° (so the angles between bones are the source's), no foot is below the
/// floor, and one BVH per person is written; a body whose joints cannot be mapped fails in one
/// line and writes nothing.
#[test]
fn retarget_mupots_onto_bandai2_and_cmu_bodies() {
    let (Some(mupots), Some(bandai)) = (shared("mupots3d"), shared("bandai2")) else { return };
    let source = socdiff_engine::data::import::load(&mupots, &Default::default()).unwrap().scene("TS16").unwrap().clone();
    let cmu = cmu_clip();
    for (tag, body) in
        [("bandai", vec!["--body", bandai.to_str().unwrap(), "--body-sequence", "dataset-2_walk_active_001"]), ("cmu", vec!["--body", cmu.to_str().unwrap()])]
    {
        let out = tmp(&format!("retarget-{tag}"));
        let mut a = vec!["retarget", "--motion", mupots.to_str().unwrap(), "--motion-sequence", "TS16", "--out", out.to_str().unwrap()];
        a.extend(body);
        let (ok, stdout, err) = socdiff(&a);
        assert!(ok, "{tag}: {err}");
        assert!(stdout.contains("3 BVH files"), "{stdout}");
        let ds = socdiff_engine::data::dataset::read_dataset(&out, &Default::default()).unwrap();
        let r = &ds.sequences[0].scene;
        let lengths: Vec<f64> = ds.metadata["retarget"]["bone_lengths_m"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        let x = |s: &socdiff_engine::Scene, f: usize, p: usize, j: usize| -> [f64; 3] { std::array::from_fn(|k| s.positions[[f, p, j, k]] as f64) };
        let (mut worst_len, mut worst_deg) = (0f64, 0f64);
        for f in 0..r.num_frames() {
            for p in 0..3 {
                for (i, &(a, b)) in r.skeleton.bones.iter().enumerate() {
                    let (u, v, nu, nv) = (x(&source, f, p, a), x(&source, f, p, b), x(r, f, p, a), x(r, f, p, b));
                    let (d, nd): ([f64; 3], [f64; 3]) = (std::array::from_fn(|k| v[k] - u[k]), std::array::from_fn(|k| nv[k] - nu[k]));
                    let (l, nl) = (d.iter().map(|c| c * c).sum::<f64>().sqrt(), nd.iter().map(|c| c * c).sum::<f64>().sqrt());
                    worst_len = worst_len.max((nl - lengths[i]).abs());
                    let cos = (0..3).map(|k| d[k] * nd[k]).sum::<f64>() / (l * nl);
                    worst_deg = worst_deg.max(cos.clamp(-1.0, 1.0).acos().to_degrees());
                }
                for j in r.skeleton.foot_joints() {
                    assert!(r.positions[[f, p, j, 2]] >= -1e-4, "{tag}: frame {f}, person {p}: foot below the floor");
                }
            }
        }
        println!("{tag}: bone length error ≤ {:.2e} m, direction ≤ {worst_deg:.2e}°", worst_len);
        assert!(worst_len < 1e-3 && worst_deg < 1.0, "{tag}: {worst_len} m, {worst_deg}°");
        assert_eq!(std::fs::read_dir(out.join("bvh")).unwrap().count(), 3);
        std::fs::remove_dir_all(&out).unwrap();
    }
    // An upper-body skeleton has no legs to map MuPoTS's onto.
    let never = tmp("retarget-never");
    let upper = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/upper_body2");
    assert_fails(
        &[
            "retarget",
            "--motion",
            mupots.to_str().unwrap(),
            "--motion-sequence",
            "TS16",
            "--body",
            upper.to_str().unwrap(),
            "--body-sequence",
            "talk1",
            "--out",
            never.to_str().unwrap(),
        ],
        &["upper_body2"],
        &never,
    );
}
