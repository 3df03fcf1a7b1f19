//! The pin grid file format, version 1: the on-disk layout, a streaming atomic writer
//! (feature `writer`, default; readers such as pinrt build without it and without its
//! tempfile dependency), a zero-copy reader over `&[u8]`, and validation.
//!
//! What it is for: anything that produces or consumes `.pin` files. A pin file holds a 5D grid
//! (3D cells x hemisphere directions) of precomputed transmittance "pins": a 32-bit ratio mask
//! and a minimum interval transmittance per pin, plus optional sparse index, majorant grid,
//! embedded density and provenance. The byte-level specification is `docs/format.md`.
//!
//! What it is not for: baking (see `pinbake`), sampling or GPU upload (see `pinrt`). It has no
//! knowledge of volumes, renderers or wgpu, and depends only on small, well-kept crates.
//!
//! ```
//! use pin_format::{OwnedPinGrid, PinEntry, PinFile, Directions, grid_desc};
//! let dirs = Directions::Octahedral { n: 2 };
//! let grid = OwnedPinGrid {
//!     desc: grid_desc([1, 1, 1], dirs, 1, 1),
//!     tile: None,
//!     cell_index: None,
//!     pins: vec![PinEntry { mask: 0x8000_0001, t_min: 0.5 }; 4],
//!     majorant: None,
//!     density: None,
//!     sparse_density: None,
//!     control: None,
//!     metadata: None,
//! };
//! let bytes = grid.to_bytes().unwrap();
//! let file = PinFile::parse(&bytes).unwrap();   // O(1): no bulk data touched
//! file.verify().unwrap();                        // O(n): every checksum and value
//! assert_eq!(file.entry([0, 0, 0], 3, 0).t_min, 0.5);
//! ```

#[cfg(target_endian = "big")]
compile_error!("pin files are little-endian and read in place; big-endian hosts are not supported");

mod checked;
mod checksum;
mod control;
mod directions;
mod error;
pub mod input;
pub mod layout;
mod metadata;
mod owned;
mod placement;
mod reader;
mod shape;
mod sparse;
pub mod text;
#[cfg(feature = "writer")]
mod writer;

pub use checksum::checksum;
pub use control::{ControlView, OwnedControl};
pub use directions::{Directions, MAX_DIRECTIONS, atan2_turns, octahedral_uv};
pub use error::{FormatError, Result};
pub use layout::{
    ControlHeader, DensityHeader, EMPTY_CELL, FileHeader, GridDesc, MajorantHeader, PinEntry,
    SectionEntry, SectionKind, SparseDensityHeader, TileDesc,
};
pub use metadata::{MAX_METADATA_BYTES, Metadata};
#[cfg(feature = "writer")]
pub use owned::StreamedSparseDensity;
pub use owned::{OwnedPinGrid, grid_desc};
pub use placement::{
    IDENTITY_LOCAL_TO_WORLD, MAX_PLACEMENT_COORD, MIN_PLACEMENT_EXTENT, MIN_RELATIVE_EXTENT,
    MIN_TRANSFORM_CONDITION, check_placement, transform_condition,
};
pub use reader::{DensityView, MajorantView, PinFile};
pub use shape::{GridShape, MAX_CELLS, MAX_DIM, MAX_PINS_PER_ENTRY};
pub use sparse::{
    OwnedSparseDensity, OwnedSparseValues, SparseDensityView, SparseValues, brick_dims,
};
#[cfg(feature = "writer")]
pub use writer::{AtomicPinFile, PinFileWriter};

/// The smallest ray-marching step, relative to the longest box edge, that a bake records or a
/// renderer marches: below it a pin or a ray takes 10^5+ steps per edge (one bound for
/// `pinbake` and `pinrender`).
pub const MIN_REL_STEP: f64 = 1e-5;
