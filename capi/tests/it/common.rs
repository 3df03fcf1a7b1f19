//! What the C tests share: the repository root and this build's static library.

use std::path::{Path, PathBuf};
use std::process::Command;

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

/// Compiles the C program `source` (relative to the repository) with the system `cc`,
/// `-Wall -Wextra -Werror` and `flags`, against `pinrt.h` and this build's static library,
/// into `dir/name`; panics with the file's name when it does not compile.
pub fn compile_c(source: &str, flags: &[&str], dir: &Path, name: &str) -> PathBuf {
    let exe = dir.join(name);
    let st = Command::new("cc")
        .args(["-std=c11", "-Wall", "-Wextra", "-Werror"])
        .args(flags)
        .arg("-I")
        .arg(repo().join("capi/include"))
        .arg(repo().join(source))
        .arg(static_lib())
        .args(["-lpthread", "-ldl", "-lm", "-o"])
        .arg(&exe)
        .status()
        .expect("the system C compiler `cc` is required (apt package gcc or clang)");
    assert!(st.success(), "cc failed on {source}");
    exe
}
