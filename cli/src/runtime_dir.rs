//! A private `XDG_RUNTIME_DIR` for a tool started without one.
//!
//! Mesa's Vulkan drivers load libwayland while they look for a display, and libwayland
//! prints "error: XDG_RUNTIME_DIR is invalid or not set in the environment." (twice per
//! process) when the variable is missing: every GPU error of a tool run from cron, `env -i`
//! or a container was three lines on stderr, two of them not the tool's. The tools open no
//! Wayland display, so an empty directory of their own answers the library.

/// Sets `XDG_RUNTIME_DIR` to `TMPDIR/pin-runtime-UID` (mode 0700, created if missing) when it
/// is unset or empty; leaves it alone when set, and when that directory cannot be made ours
/// (an existing link, another owner or wider permissions: nothing is set then, and the
/// library's own lines come back). Called by [`crate::run_main`] before the tool starts a
/// thread.
pub fn ensure_private_runtime_dir() {
    #[cfg(unix)]
    {
        use std::os::unix::fs::{DirBuilderExt, MetadataExt};
        if std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|v| !v.is_empty()) {
            return;
        }
        // SAFETY: geteuid has no preconditions.
        let uid = unsafe { libc::geteuid() };
        let dir = std::env::temp_dir().join(format!("pin-runtime-{uid}"));
        let _ = std::fs::DirBuilder::new().mode(0o700).create(&dir);
        let Ok(m) = std::fs::symlink_metadata(&dir) else {
            return;
        };
        if !m.is_dir() || m.uid() != uid || m.mode() & 0o077 != 0 {
            return;
        }
        // SAFETY: called from `run_main` at the start of a tool's `main`, before the tool
        // starts any thread, so nothing reads the environment concurrently.
        unsafe { std::env::set_var("XDG_RUNTIME_DIR", &dir) };
    }
}
