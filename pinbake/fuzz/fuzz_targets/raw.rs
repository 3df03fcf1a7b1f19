//! The headerless raw reader: 16 bytes of options (type, endianness, sanitising flags,
//! density scale, spacing, dims up to u32) then the file's bytes, written to a temp file and
//! read with `pin_volume::raw::read_raw`. An accepted grid must hold only finite,
//! non-negative values and (up to 4096 voxels) bake into a pin file that verifies.
//! Layout: `pin_tests::raw_options`. Any panic is a finding.
//!
//! Run: `cd pinbake/fuzz && cargo +nightly fuzz run raw corpus/raw` (seeds in `corpus/raw/`).
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;

fn scratch() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("pinbake-fuzz-raw-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    })
}

fuzz_target!(|data: &[u8]| {
    let _ = pin_tests::fuzz_raw(data, scratch());
});
