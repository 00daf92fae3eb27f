//! Support for tests that read the shared real data (`../shared/data`).

use std::path::Path;

/// Says that a test skips because `path` (shared data) is absent — or, when the environment
/// sets `SOCDIFF_REQUIRE_DATA=1` (CI, where the data is always there), fails the test instead,
/// so that a missing folder can never pass as a skip.
pub fn skip_absent(path: &Path, what: &str) {
    if std::env::var_os("SOCDIFF_REQUIRE_DATA").is_some_and(|v| v == "1") {
        panic!("{} is absent ({what}) and SOCDIFF_REQUIRE_DATA=1: the test needs it", path.display());
    }
    eprintln!("skipping: {} is absent ({what})", path.display());
}
