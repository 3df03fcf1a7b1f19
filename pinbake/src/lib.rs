//! `pinbake`: reads a density volume and bakes it into a pin grid file.
//!
//! What it is for: asset pipelines. The volume crate (`pin_volume`) turns OpenVDB and NanoVDB
//! grids, headerless raw grids and procedural fields into one `DensitySource` interface; [`bake`]
//! ray-marches every pin of the 5D grid in one pass and produces a canonical
//! [`pin_format::OwnedPinGrid`]; [`merge`] joins the z-slab tiles of a farm bake into the
//! same bytes a single bake writes.
//! [`plan::bake_to_file`] is the front door for a bake to a file: option ranges, the output
//! rule, the memory budget, the choice of grid, the bake, the atomic write and the summary,
//! in one place for the binary, Python and Rust callers.
//! The `pinbake` binary (feature `cli`) wraps all of it.
//!
//! What it is not for: reading pin files at render time (that is `pinrt`, which never needs
//! this crate) or defining the file layout (that is `pin-format`).

/// The vector library of the public API (`pin_volume::Aabb`, `DensitySource` positions), so
/// users name the same version of its types without a direct dependency.
pub use glam;

pub mod alloc;
pub mod asset_choice;
pub mod bake;
pub mod box_filter;
pub mod choose;
#[cfg(feature = "cli")]
pub mod cli_args;
pub mod control;
pub mod default_asset;
pub mod embed_density;
pub mod error;
pub mod frames;
#[cfg(feature = "gpu")]
pub mod gpu_bake;
pub mod gpu_options;
pub mod lattice_box;
pub mod limits;
pub mod merge;
pub mod part;
pub mod part_file;
pub mod pin;
pub mod placement;
pub mod plan;
pub mod rng;
pub mod sparse_density;
pub mod summary;
mod sweep;

pub use bake::{
    BakeBackend, BakeOptions, BakeStats, GpuBakeOptions, GpuBakeTimes, Tile, bake, bake_on,
};
pub use embed_density::EmbedDensity;
pub use error::BakeError;
pub use merge::{MergeError, merge_tiles};
pub use part::{Part, PartData, PartError, bake_part, merge_parts};
pub use plan::{
    BakeInput, BakeRequest, Baked, BakedPart, PlanError, bake_part_to_file, bake_to_file,
};
