//! The runtime's error type. Every variant names what failed, and file errors name the file.

use std::path::PathBuf;

use pin_format::FormatError;

/// Errors of loading, sampling setup and GPU work.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The file is not a regular file, could not be opened or read, or does not fit in
    /// memory (`pin_format::input`: the one rule every reader follows).
    #[error(transparent)]
    Input(pin_format::input::InputError),
    /// The file could not be mapped.
    #[error("{}: {source}", pin_format::input::quoted(.path))]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The bytes are not a valid pin file (truncated, damaged, unsupported...).
    #[error("{}: {source}", pin_format::input::quoted(.path))]
    Format {
        /// The file, or `<memory>` for [`crate::PinGrid::from_bytes`].
        path: PathBuf,
        #[source]
        source: FormatError,
    },
    /// An optional section holds values a reader cannot use. The section accessors
    /// (`PinGrid::majorants` and the others) report a damaged or invalid section as
    /// [`Error::Format`] instead (its checksum and values are checked in one pass); this
    /// variant stays for callers that match on it.
    #[error("{}: {problem}", pin_format::input::quoted(.path))]
    Section { path: PathBuf, problem: String },
    /// The placement transform cannot be inverted or does not fit f32.
    #[error("bad grid transform: {0}")]
    BadTransform(String),
    /// GPU setup or execution failed (no adapter, limits, device lost, mapping...).
    #[error("gpu: {0}")]
    Gpu(String),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
