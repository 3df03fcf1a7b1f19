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
    // Hidden subcommand: the isolated OpenVDB reader (see `pinbake::source::vdb`). It runs
    // before any CLI setup so that the worker does nothing but read the file.
    if args.get(1).is_some_and(|a| a == "__vdb-worker") {
        #[cfg(feature = "vdb")]
        return ExitCode::from(pinbake::source::vdb::worker_main(&args[2..]).clamp(0, 255) as u8);
        #[cfg(not(feature = "vdb"))]
        {
            eprintln!("pinbake: error: this build has no OpenVDB support (cargo feature `vdb`)");
            return ExitCode::from(2);
        }
    }
    let cli = match parse_cli::<cmd::Cli>("pinbake", args) {
        Ok(c) => c,
        Err(code) => return code,
    };
    match cmd::run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("pinbake: error: {}", pinbake::files::error_line(e.as_ref()));
            if e.downcast_ref::<cmd::UsageError>().is_some() {
                ExitCode::from(2)
            } else {
                ExitCode::from(1)
            }
        }
    }
}

/// Parses the command line; a usage error becomes one line on stderr and exit code 2 (clap's
/// own report spans several lines), while `--help` and `--version` print as usual.
fn parse_cli<C: clap::Parser>(tool: &str, args: Vec<std::ffi::OsString>) -> Result<C, ExitCode> {
    use clap::error::ErrorKind;
    match C::try_parse_from(args) {
        Ok(c) => Ok(c),
        Err(e)
            if matches!(
                e.kind(),
                ErrorKind::DisplayHelp
                    | ErrorKind::DisplayVersion
                    | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
            ) =>
        {
            let _ = e.print();
            Err(ExitCode::from(if e.use_stderr() { 2 } else { 0 }))
        }
        Err(e) => {
            let text = e.render().to_string();
            let line: Vec<&str> = text
                .lines()
                .map(str::trim)
                .filter(|l| {
                    !(l.is_empty()
                        || l.starts_with("Usage:")
                        || l.starts_with("For more information"))
                })
                .collect();
            let line = line.join(" ");
            eprintln!(
                "{tool}: error: {}",
                line.strip_prefix("error: ").unwrap_or(&line)
            );
            Err(ExitCode::from(2))
        }
    }
}
