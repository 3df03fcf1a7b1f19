//! The `pinbake` command line: bake, inspect, verify, merge, bench.
//!
//! Exit codes: 0 success, 1 bad input or failed check, 2 usage error. Errors are one line on
//! stderr naming the file and the problem.

mod cmd;

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().collect();
    // Hidden subcommand: the isolated OpenVDB reader (see `pinbake::source::vdb`). It runs
    // before any CLI setup so that the worker does nothing but read the file.
    if args.get(1).map(String::as_str) == Some("__vdb-worker") {
        #[cfg(feature = "vdb")]
        return ExitCode::from(pinbake::source::vdb::worker_main(&args[2..]).clamp(0, 255) as u8);
        #[cfg(not(feature = "vdb"))]
        {
            eprintln!("pinbake: error: this build has no OpenVDB support (cargo feature `vdb`)");
            return ExitCode::from(2);
        }
    }
    let cli = cmd::Cli::parse_from(args);
    match cmd::run(cli) {
        Ok(code) => code,
        Err(e) => {
            let msg = format!("{e:#}").replace(['\n', '\r'], " ");
            eprintln!("pinbake: error: {msg}");
            ExitCode::from(1)
        }
    }
}
