//! Result lines on standard output and message lines on standard error.

/// The error of [`outln!`](crate::outln): standard output could not be written.
#[derive(Debug, thiserror::Error)]
#[error("standard output: {0}")]
pub struct StdoutError(pub std::io::Error);

/// `println!` for a tool's results, returning [`StdoutError`] where `println!` panics: a full
/// disk behind a redirection (`> /dev/full`) or any other write error. (A reader that closed
/// a pipe ends the process by SIGPIPE first: [`crate::signals::install`].)
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        writeln!(std::io::stdout().lock(), $($arg)*).map_err($crate::StdoutError)
    }};
}

/// `eprintln!` for a tool's messages, without its panic: a standard error that cannot take
/// the write (`2> /dev/full`) loses the message, and the exit code still says what happened
/// (`eprintln!` panicked there, exit 101, on every error path).
#[macro_export]
macro_rules! errln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr().lock(), $($arg)*);
    }};
}
