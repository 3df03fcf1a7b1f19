//! The isolated OpenVDB reader process for this crate's tests (see `Cargo.toml`).
use std::process::ExitCode;

fn main() -> ExitCode {
    let args: Vec<std::ffi::OsString> = std::env::args_os().collect();
    if let Some(code) = pin_volume::vdb::serve_vdb_worker_if_asked(&args) {
        return code;
    }
    eprintln!(
        "usage: pin-tests-vdb-worker {} <file> <grid-selector> <mode>",
        pin_volume::vdb::WORKER_SUBCOMMAND
    );
    ExitCode::from(2)
}
