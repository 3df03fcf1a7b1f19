//! [`RenderError`]: what the render module's functions return. A leaf: every file of the
//! module imports it from here, none through the module's façade.

/// Errors of the render module.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error("invalid {what}: {why}")]
    Invalid { what: &'static str, why: String },
    #[error("I/O error on {path}: {source}")]
    Io {
        path: std::path::PathBuf,
        source: std::io::Error,
    },
    /// An input file refused by the one input rule (`pin_format::input`): the reason,
    /// without the path, which the caller names.
    #[error("{0}")]
    Input(String),
    #[error("EXR: {0}")]
    Exr(String),
    #[error("PNG: {0}")]
    Png(String),
    #[error("thread pool: {0}")]
    ThreadPool(String),
    /// An allocation whose size comes from the settings failed.
    #[error("{what}: out of memory for {bytes} bytes")]
    OutOfMemory { what: &'static str, bytes: u64 },
}
