//! The `pinbake` command line: bake, inspect, verify, merge, bench.
//!
//! Exit codes: 0 success, 1 bad input or failed check, 2 usage error. Errors are one line on
//! stderr naming the file and the problem.

mod cmd;

use std::ffi::OsString;
use std::process::ExitCode;

fn main() -> ExitCode {
    // `args_os`: a path need not be UTF-8 (`std::env::args` panics on one).
    let args: Vec<OsString> = std::env::args_os().collect();
    // Hidden subcommand: the isolated OpenVDB reader (see `pin_volume::vdb`). It runs
    // before any CLI setup so that the worker does nothing but read the file.
    #[cfg(feature = "vdb")]
    if let Some(code) = pin_volume::vdb::serve_vdb_worker_if_asked(&args) {
        return code;
    }
    #[cfg(not(feature = "vdb"))]
    if args
        .get(1)
        .is_some_and(|a| a == pin_volume::VDB_WORKER_SUBCOMMAND)
    {
        pin_cli::errln!("pinbake: error: this build has no OpenVDB support (cargo feature `vdb`)");
        return ExitCode::from(2);
    }
    // Partial output files are unlinked on SIGINT, SIGTERM and SIGHUP.
    pin_volume::files::watch_partial_files(pin_cli::signals::track);
    pin_cli::run_main("pinbake", args, cmd::run)
}
