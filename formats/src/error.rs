//! The reader's and writer's error type.

use crate::layout::SectionKind;

/// Everything that can be wrong with a pin file. Each variant renders as one line.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FormatError {
    #[error("not a pin file (bad magic bytes)")]
    BadMagic,
    #[error("file too short: {len} bytes, need at least {need}")]
    TooShort { len: u64, need: u64 },
    #[error("unsupported format version {major}.{minor} (this reader understands {supported}.x)")]
    UnsupportedVersion {
        major: u16,
        minor: u16,
        supported: u16,
    },
    #[error("header checksum mismatch (header damaged)")]
    HeaderChecksum,
    #[error("truncated or extended: header says {expected} bytes, file has {actual}")]
    SizeMismatch { expected: u64, actual: u64 },
    #[error("bad header: {0}")]
    BadHeader(&'static str),
    #[error("section table checksum mismatch (table damaged)")]
    TableChecksum,
    #[error("section #{index} ({kind}): {problem}")]
    BadSection {
        index: usize,
        kind: String,
        problem: String,
    },
    #[error("unknown required section kind {kind}; a newer reader is needed")]
    UnknownRequiredSection { kind: u32 },
    #[error("missing required section '{}'", .0.name())]
    MissingSection(SectionKind),
    #[error("duplicate section '{}'", .0.name())]
    DuplicateSection(SectionKind),
    #[error("invalid grid description: {0}")]
    BadGrid(String),
    #[error("checksum mismatch in section '{kind}' at offset {offset} (data damaged)")]
    SectionChecksum { kind: String, offset: u64 },
    #[error("buffer is not aligned to {0} bytes; copy it into an aligned buffer first")]
    Misaligned(usize),
    #[error("invalid data in section '{}': {}", .0.name(), .1)]
    BadData(SectionKind, String),
    #[error("metadata could not be decoded: {0}")]
    BadMetadata(String),
    #[error("i/o error: {0}")]
    Io(#[from] std::io::Error),
    #[error("invalid value for writing: {0}")]
    InvalidInput(String),
}

pub type Result<T, E = FormatError> = std::result::Result<T, E>;
