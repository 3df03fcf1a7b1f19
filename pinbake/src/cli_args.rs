//! Command-line plumbing shared by the `pinbake` and `pinrender` binaries (feature `cli`).

use std::process::ExitCode;

/// Parses the command line; a usage error becomes one line on stderr and exit code 2 (clap's
/// own report spans several lines), while `--help` and `--version` print as usual.
pub fn parse_cli<C: clap::Parser>(
    tool: &str,
    args: Vec<std::ffi::OsString>,
) -> Result<C, ExitCode> {
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
