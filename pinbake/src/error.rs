//! Why a bake fails: one error type for the baker, the part bakes, the sections built after
//! the pins and the library front door, in a module of its own so that everything that can
//! fail a bake names it without reaching up to the baker.

use pin_volume::Aabb;

#[derive(Debug, thiserror::Error)]
pub enum BakeError {
    #[error("invalid bake options: {0}")]
    Options(String),
    #[error("source has an invalid bounding box {0:?}")]
    Bounds(Aabb),
    /// The box or transform the bake would record breaks the placement rule
    /// ([`pin_format::check_placement`]).
    #[error("placement: {0}")]
    Placement(String),
    /// The caller asked the bake to stop (`BakeOptions::cancel`).
    #[error("the bake was cancelled")]
    Cancelled,
    #[error(
        "density {value} at {at:?} does not fit the embedded f16 field; lower --density-scale or drop --embed-density"
    )]
    DensityRange { value: f32, at: [f64; 3] },
    #[error("bake needs about {need} bytes, more than --max-memory {limit}")]
    Memory { need: u64, limit: u64 },
    #[error("cannot allocate {bytes} bytes for {what}")]
    Alloc { what: &'static str, bytes: u64 },
    #[error(transparent)]
    Format(#[from] pin_format::FormatError),
    /// The GPU bake failed: no adapter, a device limit, a lost device.
    #[error("GPU bake: {0}")]
    Gpu(String),
    #[error("thread pool: {0}")]
    Threads(String),
    #[error("cannot write {}: {message}", path.display())]
    Write {
        path: std::path::PathBuf,
        message: String,
    },
    /// Its output or spool would not fit the free space of its directory.
    #[error(transparent)]
    Disk(pin_volume::files::FileError),
    #[error("cannot spool the sparse density's bricks to a temporary file in {dir:?}: {source}")]
    Spool {
        dir: std::path::PathBuf,
        source: std::io::Error,
    },
}
