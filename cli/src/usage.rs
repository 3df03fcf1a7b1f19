//! The command line in, one message line and an exit code out.

use std::ffi::OsString;
use std::process::ExitCode;

/// A value out of its documented range, or flags that contradict each other: the tools exit
/// with code 2 for it (1 is for bad input files).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct UsageError(pub String);

/// Returns a [`UsageError`] (exit code 2) as an `anyhow::Error` from the enclosing function.
#[macro_export]
macro_rules! usage {
    ($($t:tt)*) => {
        return Err(anyhow::Error::new($crate::UsageError(format!($($t)*))))
    };
}

/// Parses the command line; a usage error becomes one line on stderr and exit code 2 (clap's
/// own report spans several lines), while `--help` and `--version` print as usual.
pub fn parse_cli<C: clap::Parser>(tool: &str, args: Vec<OsString>) -> Result<C, ExitCode> {
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
            crate::errln!("{tool}: error: {}", one_line(&e.render().to_string()));
            Err(ExitCode::from(2))
        }
    }
}

/// clap's report without its usage and "for more information" lines, on one line.
fn one_line(report: &str) -> String {
    let lines: Vec<&str> = report
        .lines()
        .map(str::trim)
        .filter(|l| {
            !(l.is_empty() || l.starts_with("Usage:") || l.starts_with("For more information"))
        })
        .collect();
    let line = lines.join(" ");
    line.strip_prefix("error: ").unwrap_or(&line).to_string()
}

/// A tool's `main` after its own early dispatch: installs the signal handlers, parses the
/// command line (`args_os`, since a path need not be UTF-8), runs `run`, and reports an error
/// as `TOOL: error: LINE` with exit code 2 for a [`UsageError`] and 1 for anything else.
pub fn run_main<C: clap::Parser>(
    tool: &str,
    args: Vec<OsString>,
    run: impl FnOnce(C) -> anyhow::Result<ExitCode>,
) -> ExitCode {
    crate::signals::install();
    crate::runtime_dir::ensure_private_runtime_dir();
    let cli = match parse_cli::<C>(tool, args) {
        Ok(c) => c,
        Err(code) => return code,
    };
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            crate::errln!("{tool}: error: {}", crate::error_line(e.as_ref()));
            ExitCode::from(exit_code_of(&e))
        }
    }
}

/// 2 for a usage error (also under added context), 1 otherwise.
fn exit_code_of(e: &anyhow::Error) -> u8 {
    if e.downcast_ref::<UsageError>().is_some() {
        2
    } else {
        1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(clap::Parser, Debug)]
    struct Args {
        #[arg(long, value_parser = crate::parse::parse_bytes)]
        max_memory: Option<u64>,
    }

    #[test]
    fn usage_errors_are_one_line_and_exit_2() {
        let args = |v: &[&str]| v.iter().map(OsString::from).collect::<Vec<_>>();
        assert!(parse_cli::<Args>("t", args(&["t", "--max-memory", "1G"])).is_ok());
        assert_eq!(
            parse_cli::<Args>("t", args(&["t", "--max-memory", "0"])).unwrap_err(),
            ExitCode::from(2)
        );
        let report = "error: invalid value 'x' for '--max-memory'\n\nUsage: t\n\nFor more information, try '--help'.\n";
        assert_eq!(one_line(report), "invalid value 'x' for '--max-memory'");
    }

    #[test]
    fn exit_codes() {
        let usage = anyhow::Error::new(UsageError("bad".into()));
        assert_eq!(exit_code_of(&usage), 2);
        assert_eq!(exit_code_of(&usage.context("while baking")), 2);
        assert_eq!(exit_code_of(&anyhow::anyhow!("a.vdb: truncated")), 1);
    }
}
