//! The GPU bake's settings and timings: a leaf that the bake's options (`bake.rs`) and the GPU
//! bake (`gpu_bake.rs`, feature `gpu`) both name, so neither imports the other for them.

/// The GPU bake's settings, none of which changes the bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GpuBakeOptions {
    /// The most GPU bytes one dispatch's pins may take (jobs, entries and read-back); `None`
    /// takes what the device binds in one storage buffer. Smaller budgets give more
    /// dispatches and the same bytes.
    pub tile_bytes: Option<u64>,
    /// The most bytes of density one dispatch binds: the grid goes to the GPU in slabs of
    /// whole z-planes (with the one plane above that trilinear reads), each uploaded, marched
    /// and freed in turn. A sparse source without a dense copy within
    /// [`crate::BakeOptions::dense_copy_bytes`] builds each slab from the source, within that budget
    /// too. `None` takes what the device binds in the shader's six density bindings. Any
    /// budget gives the same bytes; one that cannot hold two planes is refused.
    pub slab_bytes: Option<u64>,
    /// Destroys the device after this many dispatches: how the tests provoke a device lost
    /// in the middle of a bake.
    #[doc(hidden)]
    pub lose_device_after: Option<u64>,
}

/// Seconds of a GPU bake's steps, summed over its dispatches. Their sum is part of
/// [`crate::BakeStats::seconds`], which also holds the box, the sections and the compaction.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct GpuBakeTimes {
    /// Finding the adapter, opening the device and compiling `shaders/bake.wgsl`.
    pub device_s: f64,
    /// Copying the density into GPU buffers, and building its slabs from a sparse source
    /// where it has no dense copy.
    pub upload_s: f64,
    /// The CPU's part: every pin's chord and random state (in parallel).
    pub jobs_s: f64,
    /// From submitting each dispatch to its entries read back: the march on the GPU, the
    /// jobs' upload and the entries' read-back.
    pub dispatch_s: f64,
    /// Dispatches run (more than one when the tile budget or the device's limits split the
    /// pins, or the slab budget the density: one per slab of each tile of pins).
    pub dispatches: u64,
    /// Slabs the density went to the GPU in (1 when it fits the slab budget whole).
    pub slabs: u64,
    /// The adapter's name and backend.
    pub adapter: String,
}
