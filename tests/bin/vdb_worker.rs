//! The isolated OpenVDB reader process for this crate's tests (see `Cargo.toml`).
use std::process::ExitCode;

fn main() -> ExitCode {
    let args: Vec<std::ffi::OsString> = std::env::args_os().collect();
    if let Some(code) = pinbake::source::vdb::serve_vdb_worker_if_asked(&args) {
        return code;
    }
    eprintln!(
        "usage: pin-tests-vdb-worker {} <file> <grid-selector> <mode>",
        pinbake::source::vdb::WORKER_SUBCOMMAND
    );
    ExitCode::from(2)
}
