//! Helpers shared by the CLI tests: run the binary, temp folders, data paths, and the check
//! that bad input fails with one error line and writes nothing.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

/// Runs `socdiff ARGS`: (success, stdout, stderr).
pub fn socdiff<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_socdiff")).args(args).output().expect("runs");
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into_owned(), String::from_utf8_lossy(&out.stderr).into_owned())
}

/// A fresh (removed) path in the temp folder, unique per test binary run.
pub fn tmp(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("socdiff-cli-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// The bundled CMU clip.
pub fn cmu_clip() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/data/cmu_18_01.bvh")
}

/// `../shared/data/REL`, or `None` (saying so) when it is absent.
pub fn shared(rel: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data").join(rel);
    if p.exists() {
        Some(p)
    } else {
        socdiff_engine::testing::skip_absent(&p, "shared data");
        None
    }
}

/// Runs a command that must fail: exactly one `error: ` line naming each of `names`, `out` not
/// written, and no temporary file left beside it.
pub fn assert_fails<S: AsRef<std::ffi::OsStr> + std::fmt::Debug>(args: &[S], names: &[&str], out: &Path) {
    let (ok, _, err) = socdiff(args);
    assert!(!ok, "{args:?} should fail");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "one error line for {args:?}, got: {err}");
    assert!(lines[0].starts_with("error: "), "{err}");
    for n in names {
        assert!(lines[0].contains(n), "error should name {n:?}: {err}");
    }
    assert!(!out.exists(), "{} must not be written for {args:?}", out.display());
    let parent = out.parent().expect("output has a parent");
    let leftovers: Vec<_> =
        std::fs::read_dir(parent).map(|d| d.filter_map(|e| e.ok()).filter(|e| e.file_name().to_string_lossy().contains(".tmp")).collect()).unwrap_or_default();
    assert!(leftovers.is_empty(), "temporary output left: {leftovers:?}");
}
