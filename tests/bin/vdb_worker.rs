//! The isolated OpenVDB reader process for this crate's tests (see `Cargo.toml`).
use std::process::ExitCode;

fn main() -> ExitCode {
    let args: Vec<std::ffi::OsString> = std::env::args_os().collect();
    if args
        .get(1)
        .is_none_or(|a| a != pinbake::source::vdb::WORKER_SUBCOMMAND)
    {
        eprintln!(
            "usage: pin-tests-vdb-worker {} <file> <grid-selector> <mode>",
            pinbake::source::vdb::WORKER_SUBCOMMAND
        );
        return ExitCode::from(2);
    }
    ExitCode::from(pinbake::source::vdb::worker_main(&args[2..]).clamp(0, 255) as u8)
}
