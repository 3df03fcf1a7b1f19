//! The VDB loading path as the baker uses it: the input is written to a temp file and opened
//! with `pin_volume::vdb::VdbSource::open`, which runs vdb-rs in the memory- and
//! time-limited worker process (`pinbake __vdb-worker`) and validates the worker's stream in
//! this process. Errors must be one line; an accepted grid must have a finite box and finite,
//! non-negative extinction. A panic in this process is a finding (a worker crash is not: it
//! must come back as an error, and does).
//!
//! The worker is the `pinbake` binary: `PINBAKE_WORKER=/path/to/pinbake`, default
//! `../../target/debug/pinbake` (build it with `cargo build -p pinbake`). libFuzzer sees the
//! coverage of this process only (the stream parser and the guards), not of vdb-rs in the
//! worker.
//!
//! Run: `cd pinbake/fuzz && cargo +nightly fuzz run vdb_guard corpus/vdb_guard`.
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;

fn setup() -> &'static (PathBuf, PathBuf) {
    static S: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    S.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("pinbake-fuzz-vdb-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        let worker = std::env::var_os("PINBAKE_WORKER")
            .map(PathBuf::from)
            .unwrap_or_else(|| pin_tests::target_dir().join("debug/pinbake"));
        assert!(
            worker.exists(),
            "worker {} missing: cargo build -p pinbake",
            worker.display()
        );
        (d, worker)
    })
}

fuzz_target!(|data: &[u8]| {
    let (dir, worker) = setup();
    let _ = pin_tests::fuzz_vdb(data, dir, worker);
});
