//! pin-scene's integration tests: scene files written to a temporary folder and loaded.

mod errors;
mod load;
mod schema;

use std::path::{Path, PathBuf};

/// A folder holding `a.vdb` and `a.pin` (empty files: the scene only checks they exist).
pub fn folder() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("a.vdb"), b"").unwrap();
    std::fs::write(dir.path().join("a.pin"), b"").unwrap();
    dir
}

/// Writes `text` as `scene.json` in `dir` and returns its path.
pub fn write(dir: &Path, text: &str) -> PathBuf {
    let p = dir.join("scene.json");
    std::fs::write(&p, text).unwrap();
    p
}

/// The one-line message that loading `text` gives (it must be refused).
pub fn refusal(text: &str) -> String {
    let dir = folder();
    let p = write(dir.path(), text);
    let e = pin_scene::load(&p, None).expect_err("the scene must be refused");
    let line = e.to_string();
    assert!(!line.contains('\n'), "{line}");
    let prefix = format!("{}: ", p.display());
    line.strip_prefix(&prefix)
        .unwrap_or_else(|| panic!("{line:?} does not start with the file"))
        .to_string()
}
