//! The command-line kit of the workspace's binaries (`pinbake`, `pinrender`): what makes a
//! tool behave like a Unix tool, and nothing about volumes or pins.
//!
//! * [`outln!`] and [`errln!`]: result and message lines that never panic on a closed or
//!   full stream;
//! * [`run_main`]: parse the command line, run, and turn the outcome into one message line
//!   and an exit code (0 success, 1 bad input or failed check, 2 usage error: [`UsageError`],
//!   raised with [`usage!`]);
//! * [`parse`]: `clap` value parsers for the generic flag types (sizes, finite floats,
//!   triples);
//! * [`signals`]: the handlers that end the process quietly on SIGPIPE and remove the
//!   registered partial output file on SIGINT, SIGTERM, SIGHUP;
//! * [`runtime_dir`]: a private `XDG_RUNTIME_DIR` when none is set, so that a GPU error is
//!   the tool's one line, without the Wayland library's.
//!
//! What it is not for: the rules a library applies to files and memory (inputs must be
//! regular files, outputs must not replace inputs, the memory budget) live with the library
//! that applies them (`pin_volume::files`, `pin_format::input`), so that the Python extension and
//! the C ABI follow them too; the flags of one tool live in that tool.

pub mod output;
pub mod parse;
pub mod runtime_dir;
pub mod signals;
mod usage;

pub use output::StdoutError;
pub use pin_format::text::{error_line, num};
pub use usage::{UsageError, parse_cli, run_main};
