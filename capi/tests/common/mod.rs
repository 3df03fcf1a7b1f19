//! What the C tests share: the repository root and this build's static library.

use std::path::{Path, PathBuf};

pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// `libpinrt_capi.a` of this build: cargo puts it beside (or one level above) this test binary.
pub fn static_lib() -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    let deps = exe.parent().expect("deps dir").to_path_buf();
    let candidates = [
        deps.join("libpinrt_capi.a"),
        deps.parent()
            .map(|p| p.join("libpinrt_capi.a"))
            .unwrap_or_default(),
    ];
    candidates
        .iter()
        .find(|p| p.is_file())
        .unwrap_or_else(|| panic!("libpinrt_capi.a not found in {candidates:?}"))
        .clone()
}
