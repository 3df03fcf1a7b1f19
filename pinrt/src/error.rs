//! The runtime's error type. Every variant names what failed, and file errors name the file.

use std::path::PathBuf;

use pin_format::FormatError;

/// Errors of loading, sampling setup and GPU work.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The file could not be opened, mapped or read.
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The bytes are not a valid pin file (truncated, damaged, unsupported...).
    #[error("{}: {source}", .path.display())]
    Format {
        /// The file, or `<memory>` for [`crate::PinGrid::from_bytes`].
        path: PathBuf,
        #[source]
        source: FormatError,
    },
    /// An optional section (majorant, density) holds values a reader cannot use.
    #[error("{}: {problem}", .path.display())]
    Section { path: PathBuf, problem: String },
    /// The placement transform cannot be inverted or does not fit f32.
    #[error("bad grid transform: {0}")]
    BadTransform(String),
    /// GPU setup or execution failed (no adapter, limits, device lost, mapping...).
    #[error("gpu: {0}")]
    Gpu(String),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
