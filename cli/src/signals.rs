//! Ending quietly on a closed pipe, and unlinking the partial output file when interrupted.
//!
//! A signal handler may only call async-signal-safe functions: it reads one pointer to a
//! NUL-terminated path (tracked before the file is written to), calls `unlink`, and re-raises
//! the signal with the default action so the exit status still says "killed by SIGINT".
//! Tracked paths are leaked on purpose: freeing one while a handler on another thread reads
//! it would be a use-after-free, and a process tracks a handful at most.
//!
//! Only binaries install these: a library that took over SIGINT would take Ctrl-C away from
//! its host (Python's `KeyboardInterrupt`). The baker's library announces its partial files
//! through `pin_volume::files::watch_partial_files`, which a binary points at [`track`].

use std::path::Path;
#[cfg(unix)]
use std::sync::atomic::{AtomicBool, AtomicPtr, Ordering};

#[cfg(unix)]
static PARTIAL: AtomicPtr<libc::c_char> = AtomicPtr::new(std::ptr::null_mut());
#[cfg(unix)]
static INSTALLED: AtomicBool = AtomicBool::new(false);

#[cfg(unix)]
extern "C" fn on_signal(sig: libc::c_int) {
    let p = PARTIAL.load(Ordering::SeqCst);
    // SAFETY: unlink and raise are async-signal-safe; `p` is null or a leaked C string.
    unsafe {
        if !p.is_null() {
            libc::unlink(p);
        }
        // SA_RESETHAND restored the default action on entry; the re-raised signal is
        // delivered when the handler returns.
        libc::raise(sig);
    }
}

/// Installs the handlers (once per process) for SIGINT, SIGTERM, SIGHUP and SIGPIPE.
///
/// SIGPIPE: a reader that closed our stdout early (`... --json | head -c 100`). Rust's
/// runtime ignores it, so the next `println!` would panic ("failed printing to stdout");
/// handled here, the process ends at that write, quietly, as other Unix filters do, and takes
/// its partial file with it. The tools write to no other pipe (the VDB worker's parent only
/// reads from its child), so no other write raises it.
pub fn install() {
    #[cfg(unix)]
    if !INSTALLED.swap(true, Ordering::SeqCst) {
        for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP, libc::SIGPIPE] {
            // SAFETY: a zeroed sigaction is valid; the handler only makes async-signal-safe
            // calls.
            unsafe {
                let mut sa: libc::sigaction = std::mem::zeroed();
                sa.sa_sigaction = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
                sa.sa_flags = libc::SA_RESETHAND;
                libc::sigemptyset(&mut sa.sa_mask);
                libc::sigaction(sig, &sa, std::ptr::null_mut());
            }
        }
    }
}

/// Tracks `path` as the file to unlink on a signal (replacing any earlier one), or tracks
/// nothing for `None`, and installs the handlers.
pub fn track(path: Option<&Path>) {
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStrExt;
        install();
        let c = path.and_then(|p| std::ffi::CString::new(p.as_os_str().as_bytes()).ok());
        PARTIAL.store(
            c.map_or(std::ptr::null_mut(), std::ffi::CString::into_raw),
            Ordering::SeqCst,
        );
    }
    #[cfg(not(unix))]
    let _ = path;
}
