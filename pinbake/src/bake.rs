//! The baker: every pin of the 5D grid (or of one z-slab tile of it), in parallel, into an
//! in-memory [`OwnedPinGrid`] in canonical form.
//!
//! Determinism: each pin's line and mask bits come from a counter RNG keyed on
//! (seed, global cell index, direction * pins_per_entry + pin), and results land in fixed
//! slots, so the bytes do not depend on thread count, scheduling or tiling.

use std::time::Instant;

use glam::DVec3;
use half::f16;
use pin_format::layout::{DENSITY_F16, GRID_FLAG_CROPPED, GRID_FLAG_JITTERED_PINS};
use pin_format::{
    DensityHeader, Directions, EMPTY_CELL, GridShape, MajorantHeader, Metadata, OwnedPinGrid,
    PinEntry, TileDesc, grid_desc,
};
use rayon::prelude::*;

use crate::embed_density::EmbedDensity;
pub use crate::error::BakeError;
pub use crate::gpu_options::{GpuBakeOptions, GpuBakeTimes};
pub use crate::pin::PinLayout;
pub use crate::placement::bake_box;

use crate::alloc::try_filled;
use crate::pin::{Field, Placement, field_optical_depths, make_entry};
use crate::sparse_density::SparseSpool;
use crate::sweep::Sweep;
use pin_volume::{Aabb, DensitySource};

/// One slab of a tiled bake: tile `index` of `count`, split along z.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tile {
    pub index: u32,
    pub count: u32,
}

impl Tile {
    /// Cell layers `[begin, end)` of this tile for a grid `z` layers deep.
    pub fn layers(&self, z: u32) -> (u32, u32) {
        let f = |i: u32| (u64::from(i) * u64::from(z) / u64::from(self.count)) as u32;
        (f(self.index), f(self.index + 1))
    }
}

/// Where a bake computes its pins' entries. Everything else (the box, the sections, the
/// file) is the same code for both.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BakeBackend {
    /// The CPU march in f64 sums (rayon).
    #[default]
    Cpu,
    /// A wgpu compute pass over the dense grid the CPU would march (feature `gpu`; a build
    /// without it refuses). Its entries agree with the CPU's within the bound docs/gpu.md
    /// states, and are the same bytes on one device whatever the tiling.
    Gpu(GpuBakeOptions),
}

/// Everything that decides the bytes of a bake besides the source.
#[derive(Clone, Debug)]
pub struct BakeOptions {
    pub cells: [u32; 3],
    pub directions: Directions,
    pub pins_per_entry: u32,
    /// Ray-marching step relative to the longest edge of the (cropped) box.
    pub step: f64,
    pub seed: u64,
    /// Shrink the box to the region of non-zero density.
    pub crop: bool,
    /// Random point and direction inside each cell per pin (the thesis' bake). Off by default:
    /// pins run through the cell centre and the direction cell's centre, so that the
    /// runtime's one-cell lookup jitter interpolates between pins instead of blurring a second
    /// time (docs/sampling.md section 13).
    pub jitter_pins: bool,
    pub tile: Option<Tile>,
    /// Bricks of the majorant grid per axis; `None` leaves the section out.
    pub majorant: Option<[u32; 3]>,
    /// The embedded f16 density, dense or sparse (format 1.1); `None` leaves it out.
    pub embed_density: Option<EmbedDensity>,
    /// The control section (format 1.1) for residual ratio tracking; `None` leaves it out.
    pub embed_control: Option<crate::control::ControlOptions>,
    /// Worker threads; `None` means rayon's default.
    pub threads: Option<usize>,
    /// Recorded in the metadata; the source's density scale is already applied to values.
    pub density_scale: f64,
    pub metadata: Metadata,
    /// The largest dense copy, in bytes, the bake may make of a sparse source (an
    /// axis-aligned OpenVDB grid, [`DensitySource::dense_copy`]) to march it at the dense
    /// grid's speed; 0 samples the sparse structure. The copy's samples agree with the
    /// sparse ones to a few f32 ulps, not bit for bit (docs/performance.md), so this decides
    /// bytes too.
    pub dense_copy_bytes: u64,
    /// Set by the caller to stop the bake: it is polled between rows of pins, batches of the
    /// layered march and bricks of the control grid, and the bake then returns
    /// [`BakeError::Cancelled`] within a fraction of a second. Not part of the bytes.
    pub cancel: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
}

impl BakeOptions {
    /// Whether [`BakeOptions::cancel`] is set.
    pub fn cancelled(&self) -> bool {
        self.cancel
            .as_ref()
            .is_some_and(|c| c.load(std::sync::atomic::Ordering::Relaxed))
    }

    /// `Err(Cancelled)` when [`BakeOptions::cancel`] is set.
    pub fn check_cancel(&self) -> Result<(), BakeError> {
        if self.cancelled() {
            return Err(BakeError::Cancelled);
        }
        Ok(())
    }
}

/// [`BakeOptions::dense_copy_bytes`] by default: 1 GiB, a 645^3 active box. A fixed figure
/// rather than a share of this machine's memory, so that the bytes of a library bake do not
/// depend on where it runs; `pinbake bake` passes what its `--max-memory` leaves.
pub const DEFAULT_DENSE_COPY_BYTES: u64 = 1 << 30;

impl Default for BakeOptions {
    fn default() -> Self {
        Self {
            cells: [DEFAULT_MAX_CELLS; 3],
            directions: DEFAULT_DIRECTIONS,
            pins_per_entry: 1,
            step: 0.01,
            seed: 0,
            crop: true,
            jitter_pins: false,
            tile: None,
            majorant: Some([16; 3]),
            embed_density: None,
            embed_control: None,
            threads: None,
            density_scale: 1.0,
            metadata: Metadata::default(),
            dense_copy_bytes: DEFAULT_DENSE_COPY_BYTES,
            cancel: None,
        }
    }
}

/// Numbers describing a finished bake.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct BakeStats {
    pub pins: u64,
    pub empty_cells: u64,
    pub covered_cells: u64,
    pub t_min_min: f32,
    pub t_min_max: f32,
    pub t_min_mean: f64,
    pub seconds: f64,
    pub pins_per_s: f64,
    /// Where a GPU bake's time went; `None` for a CPU bake.
    pub gpu: Option<GpuBakeTimes>,
}

/// Bytes the sections built after the pins hold at their peak: the sparse density
/// ([`crate::sparse_density::sparse_density_bytes`]) and the control grid (its bricks' three
/// values gathered, then copied into the section's three arrays: 24 bytes per brick). 0 for
/// a section whose size cannot be worked out (the bake then fails with its own error).
pub fn estimate_section_bytes(source: &dyn DensitySource, opts: &BakeOptions) -> u64 {
    let Ok((bbox, _)) = bake_box(source, opts.crop) else {
        return 0;
    };
    let sparse = opts
        .embed_density
        .and_then(EmbedDensity::sparse)
        .map_or(0, |spec| {
            crate::sparse_density::sparse_dims(source, &bbox, spec).map_or(0, |dims| {
                crate::sparse_density::sparse_density_bytes(source, &bbox, dims)
            })
        });
    let control = opts.embed_control.map_or(0, |c| {
        crate::control::control_dims(source, &bbox, &c)
            .map_or(0, |d| d.iter().map(|&x| u64::from(x)).product::<u64>() * 24)
    });
    sparse.saturating_add(control)
}

/// The default direction set. Not the thesis' polar 16x4, whose cap cells put near-axis pins
/// ~29 degrees off the query: octahedral:16 at 20^3 cells beat polar 16x4, polar 8x8,
/// octahedral:8 at 32^3 and polar 32x8 at 20^3 (all about the same bytes) on pins-only renders
/// of volumes nobody tuned for (docs/sampling.md section 11, docs/evaluation.md).
pub const DEFAULT_DIRECTIONS: Directions = Directions::Octahedral { n: 16 };

/// The default spatial cells per axis (fewer where the volume has fewer voxels, see
/// [`default_cells`]): 20^3 cells x 256 directions is about the bytes of the thesis' 32^3 x 64.
pub const DEFAULT_MAX_CELLS: u32 = 20;

/// Spatial cells per axis when the user names none: `max` per axis, but never more cells than
/// the bake box spans voxels along that axis (finer cells than voxels store the same
/// interpolated density many times over and only add bytes; `docs/evaluation.md`, "Bias against bytes"). Analytic sources have
/// no voxels and get `max`.
pub fn default_cells(
    source: &dyn DensitySource,
    crop: bool,
    max: u32,
) -> Result<[u32; 3], BakeError> {
    let (bbox, _) = bake_box(source, crop)?;
    let extent = bbox.extent();
    let max = max.max(1);
    Ok(match source.voxel_size() {
        Some(v) => [0, 1, 2].map(|a| {
            let voxels = extent[a] / v[a];
            // Rounded: a box of whole voxels divides to an integer up to rounding error.
            if voxels.is_finite() && voxels > 0.0 {
                (voxels.round().max(1.0).min(f64::from(max))) as u32
            } else {
                max
            }
        }),
        None => [max; 3],
    })
}

/// Bytes the output of a bake with these options may need at most (dense pins, index,
/// optional sections), for `--max-memory`.
pub fn estimate_output_bytes(opts: &BakeOptions) -> u64 {
    let cells: u64 = opts.cells.iter().map(|&c| u64::from(c)).product();
    let block = u64::from(opts.directions.count()) * u64::from(opts.pins_per_entry) * 8;
    let vol = |d: Option<[u32; 3]>, b: u64| {
        d.map_or(0, |d| d.iter().map(|&x| u64::from(x)).product::<u64>() * b)
    };
    // Dense pins plus the compacted copy, the index, and the optional sections.
    cells
        .saturating_mul(block)
        .saturating_mul(2)
        .saturating_add(cells.saturating_mul(4))
        .saturating_add(vol(opts.majorant, 4))
        .saturating_add(vol(opts.embed_density.and_then(EmbedDensity::dense), 2))
}

/// Bytes that a bake of `source` with `opts` writes to its output's directory at least:
/// the dense sections, whose size the options fix, and twice the sparse density's bricks that
/// the source's solid boxes force it to store (the spool, then the file that copies it);
/// the pins, whose bytes depend on which cells are empty, count nothing. For the disk check
/// before a bake starts, which must not refuse a bake that fits.
pub fn estimate_min_file_bytes(source: &dyn DensitySource, opts: &BakeOptions) -> u64 {
    let vol = |d: Option<[u32; 3]>, b: u64| {
        d.map_or(0, |d| d.iter().map(|&x| u64::from(x)).product::<u64>() * b)
    };
    let sparse = opts
        .embed_density
        .and_then(EmbedDensity::sparse)
        .map_or(0, |spec| {
            bake_box(source, opts.crop).map_or(0, |(bbox, _)| {
                crate::sparse_density::sparse_dims(source, &bbox, spec).map_or(0, |dims| {
                    crate::sparse_density::sparse_density_min_file_bytes(source, &bbox, dims)
                })
            })
        });
    vol(opts.majorant, 4)
        .saturating_add(vol(opts.embed_density.and_then(EmbedDensity::dense), 2))
        .saturating_add(sparse.saturating_mul(2))
}

/// The most bytes a dense copy of a sparse source may take in a bake with `opts`: what
/// [`BakeOptions::dense_copy_bytes`] allows, and no more voxels than
/// [`DENSE_COPY_VOXELS_PER_SAMPLE`] per sample the bake takes. Filling the copy costs one
/// tree lookup per voxel, a sample through the tree a few: a copy larger than that costs
/// more time to fill than it saves, besides its memory (a default bake of a 263 M-voxel
/// cloud takes 90 M samples; its copy would be 2.5 GB of f32, 55% zeros).
pub fn dense_copy_limit(opts: &BakeOptions) -> u64 {
    // At most 1/step samples per pin: the chord is at most the longest box edge long along
    // an axis and sqrt(3) of it on a diagonal; 1/step is the typical chord's count.
    let samples = pin_count(opts) as f64 / opts.step.max(1e-9);
    let by_cost = (samples * DENSE_COPY_VOXELS_PER_SAMPLE * 4.0).min(u64::MAX as f64) as u64;
    opts.dense_copy_bytes.min(by_cost)
}

/// See [`dense_copy_limit`].
pub const DENSE_COPY_VOXELS_PER_SAMPLE: f64 = 4.0;

/// Pins a bake computes: every direction and pin of every cell of its tile (of the whole grid
/// without one).
pub fn pin_count(opts: &BakeOptions) -> u64 {
    let cells: u64 = match opts.tile {
        None => opts.cells.iter().map(|&c| u64::from(c)).product(),
        Some(t) => {
            let (a, b) = t.layers(opts.cells[2]);
            u64::from(opts.cells[0]) * u64::from(opts.cells[1]) * u64::from(b.saturating_sub(a))
        }
    };
    cells
        .saturating_mul(u64::from(opts.directions.count()))
        .saturating_mul(u64::from(opts.pins_per_entry))
}

/// Working memory a bake may hold beside its source and [`estimate_output_bytes`]: the layered
/// march's per-pin state for large dense grids (a fixed bound, ~110 MB at most).
pub fn estimate_working_bytes(opts: &BakeOptions) -> u64 {
    crate::sweep::working_set_bytes(pin_count(opts))
}

/// Bakes `source` with `opts`. `progress` is called with the number of pins just finished.
pub fn bake(
    source: &dyn DensitySource,
    opts: &BakeOptions,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<(OwnedPinGrid, BakeStats), BakeError> {
    bake_with_sweep(source, opts, Some(Sweep::default()), progress)
}

/// [`bake`] with its entries computed by `backend`: the library's way to bake a source into
/// an in-memory grid on the GPU (`BakeBackend::Gpu`), `progress` called per dispatch.
pub fn bake_on(
    source: &dyn DensitySource,
    opts: &BakeOptions,
    backend: BakeBackend,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<(OwnedPinGrid, BakeStats), BakeError> {
    let (grid, _, stats) = bake_outputs(
        source,
        opts,
        Some(Sweep::default()),
        progress,
        None,
        backend,
    )?;
    Ok((grid, stats))
}

/// [`bake`], with an embedded sparse density's bricks spooled to an unnamed temporary file in
/// `spool_dir` instead of held in the grid: the grid comes back without them
/// (`sparse_density` is `None`) and the spool, when the options embed one, is written with
/// [`pin_format::OwnedPinGrid::write_streamed_into`]. The file's bytes are [`bake`]'s.
pub fn bake_spooled(
    source: &dyn DensitySource,
    opts: &BakeOptions,
    progress: &(dyn Fn(u64) + Sync),
    spool_dir: &std::path::Path,
) -> Result<(OwnedPinGrid, Option<SparseSpool>, BakeStats), BakeError> {
    bake_spooled_on(source, opts, BakeBackend::Cpu, progress, spool_dir)
}

/// [`bake_spooled`] with its entries computed by `backend`.
pub fn bake_spooled_on(
    source: &dyn DensitySource,
    opts: &BakeOptions,
    backend: BakeBackend,
    progress: &(dyn Fn(u64) + Sync),
    spool_dir: &std::path::Path,
) -> Result<(OwnedPinGrid, Option<SparseSpool>, BakeStats), BakeError> {
    bake_outputs(
        source,
        opts,
        Some(Sweep::default()),
        progress,
        Some(spool_dir),
        backend,
    )
}

/// [`bake`], marching a dense grid by layers cut as `sweep` says, or pin by pin with `None`
/// (the order the layered sweep must reproduce to the bit; tests compare the two).
pub(crate) fn bake_with_sweep(
    source: &dyn DensitySource,
    opts: &BakeOptions,
    sweep: Option<Sweep>,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<(OwnedPinGrid, BakeStats), BakeError> {
    let (grid, _, stats) = bake_outputs(source, opts, sweep, progress, None, BakeBackend::Cpu)?;
    Ok((grid, stats))
}

fn bake_outputs(
    source: &dyn DensitySource,
    opts: &BakeOptions,
    sweep: Option<Sweep>,
    progress: &(dyn Fn(u64) + Sync),
    spool_dir: Option<&std::path::Path>,
    backend: BakeBackend,
) -> Result<(OwnedPinGrid, Option<SparseSpool>, BakeStats), BakeError> {
    check_step(opts)?;
    // Without the feature the refusal comes before any work.
    #[cfg(not(feature = "gpu"))]
    if let BakeBackend::Gpu(_) = backend {
        return Err(BakeError::Gpu(
            "this build has no GPU bake (cargo feature `gpu`); use the CPU backend".into(),
        ));
    }
    // Refused before any work, with the rule's own message, whoever calls.
    crate::placement::check_source_placement(source, opts.crop)?;
    let pool = thread_pool(opts)?;
    match source.bake_frame() {
        None => pool.install(|| bake_in_pool(source, opts, sweep, progress, spool_dir, backend)),
        Some((local, local_to_world)) => {
            let (mut grid, spool, stats) = pool.install(|| {
                bake_in_pool(local.as_ref(), opts, sweep, progress, spool_dir, backend)
            })?;
            grid.desc.local_to_world = local_to_world;
            Ok((grid, spool, stats))
        }
    }
}

/// The box a bake of `source` with `opts` covers and its grid description, as the file
/// records it (`stored_cells` and `local_to_world` still to be filled in).
pub(crate) fn grid_description(
    source: &dyn DensitySource,
    opts: &BakeOptions,
) -> Result<(Aabb, pin_format::GridDesc), BakeError> {
    let (bbox, cropped) = bake_box(source, opts.crop)?;
    let source_box = source.bounds();
    let mut desc = grid_desc(opts.cells, opts.directions, opts.pins_per_entry, 0);
    desc.box_min = bbox.min.to_array();
    desc.box_max = bbox.max.to_array();
    desc.source_box_min = source_box.min.to_array();
    desc.source_box_max = source_box.max.to_array();
    desc.step_size = opts.step;
    desc.density_scale = opts.density_scale;
    desc.seed = opts.seed;
    desc.flags = if cropped { GRID_FLAG_CROPPED } else { 0 }
        | if opts.jitter_pins {
            GRID_FLAG_JITTERED_PINS
        } else {
            0
        };
    Ok((bbox, desc))
}

/// The pool a bake with `opts` runs in.
pub(crate) fn thread_pool(opts: &BakeOptions) -> Result<rayon::ThreadPool, BakeError> {
    let mut b = rayon::ThreadPoolBuilder::new();
    if let Some(t) = opts.threads {
        b = b.num_threads(t.max(1));
    }
    b.build().map_err(|e| BakeError::Threads(e.to_string()))
}

/// The step must be a positive finite number.
pub(crate) fn check_step(opts: &BakeOptions) -> Result<(), BakeError> {
    if !(opts.step > 0.0 && opts.step.is_finite()) {
        return Err(BakeError::Options(format!(
            "step {} must be positive",
            opts.step
        )));
    }
    Ok(())
}

fn bake_in_pool(
    source: &dyn DensitySource,
    opts: &BakeOptions,
    sweep: Option<Sweep>,
    progress: &(dyn Fn(u64) + Sync),
    spool_dir: Option<&std::path::Path>,
    backend: BakeBackend,
) -> Result<(OwnedPinGrid, Option<SparseSpool>, BakeStats), BakeError> {
    let started = Instant::now();
    let (bbox, desc) = grid_description(source, opts)?;
    let tile = match opts.tile {
        None => None,
        Some(t) => {
            if t.count == 0 || t.index >= t.count {
                return Err(BakeError::Options(format!(
                    "tile {}/{} out of range",
                    t.index, t.count
                )));
            }
            let (z_begin, z_end) = t.layers(opts.cells[2]);
            if z_begin >= z_end {
                return Err(BakeError::Options(format!(
                    "tile {}/{} has no cell layers: the grid is only {} cells deep",
                    t.index, t.count, opts.cells[2]
                )));
            }
            Some(TileDesc {
                tile_index: t.index,
                tile_count: t.count,
                z_begin,
                z_end,
            })
        }
    };
    let shape = GridShape::new(&desc, tile.as_ref()).map_err(BakeError::Format)?;
    let placement = Placement::over(&bbox, opts.step);
    // A sparse source that fits the budget is copied once into a dense grid and marched on
    // its voxels: a tree walk per sample costs several times a dense load (the smoke's
    // default bake: docs/performance.md).
    let copy = match source.as_dense_grid() {
        Some(_) => None,
        None => source.dense_copy(dense_copy_limit(opts)),
    };
    let field = copy.as_ref().map_or(Field::of(source), Field::Grid);
    let layout = PinLayout {
        dims: opts.cells,
        directions: opts.directions,
        pins_per_entry: opts.pins_per_entry,
        jitter: opts.jitter_pins,
        seed: opts.seed,
    };

    let block_len = shape.block_len as usize;
    let covered = shape.covered_cells as usize;
    let (nx, ny) = (opts.cells[0] as usize, opts.cells[1] as usize);
    let mut dense = try_filled(
        "the pins",
        covered.saturating_mul(block_len),
        PinEntry::EMPTY,
    )?;
    let dirs = opts.directions.count();
    let ppe = opts.pins_per_entry;
    let mut gpu_times = None;
    match (field, sweep) {
        // The GPU replaces only this step: the entries of every pin, in the same slots.
        _ if backend != BakeBackend::Cpu => {
            gpu_times = gpu_entries(
                field,
                source,
                (&placement, &layout),
                (shape.z_begin, block_len),
                &mut dense,
                backend,
                progress,
                opts,
            )?
        }
        // A dense grid by layers of the grid: the samples of many pins in one slab at a time
        // hit the caches, where pin after pin each sample waited on memory (crate::sweep).
        (Field::Grid(grid), Some(sweep)) if size_of_val(grid.data()) >= sweep.min_grid_bytes => {
            crate::sweep::bake_grid(
                grid,
                &placement,
                &layout,
                (nx, ny, shape.z_begin),
                block_len,
                &mut dense,
                sweep,
                progress,
                &|| opts.cancelled(),
            )
        }
        // One task per x-row of cells, direction-major inside: consecutive pins are then
        // nearly parallel lines a cell apart. The slots (and so the bytes) are the same in any
        // order.
        _ => dense
            .par_chunks_mut(block_len * nx)
            .enumerate()
            .for_each(|(row, blocks)| {
                let (y, z) = ((row % ny) as u32, (row / ny) as u32 + shape.z_begin);
                for dir in 0..dirs {
                    // Polled per direction: a row of long pins takes seconds.
                    if opts.cancelled() {
                        return;
                    }
                    for k in 0..ppe {
                        let slot = (dir * ppe + k) as usize;
                        for (x, block) in blocks.chunks_mut(block_len).enumerate() {
                            let cell = [x as u32, y, z];
                            let mut rng = layout.rng(layout.cell_linear(cell), dir, k);
                            let (p, w) = layout.line(cell, dir, &mut rng);
                            let taus = field_optical_depths(field, &placement, p, w);
                            block[slot] = make_entry(&taus, &mut rng);
                        }
                    }
                }
                progress((block_len * nx) as u64);
            }),
    }

    opts.check_cancel()?;
    let majorant = opts
        .majorant
        .map(|dims| bake_majorant(source, &bbox, dims))
        .transpose()?;
    let density = opts
        .embed_density
        .and_then(EmbedDensity::dense)
        .map(|dims| bake_density(source, &bbox, dims))
        .transpose()?;
    let (mut sparse, mut spool) = (None, None);
    if let Some(spec) = opts.embed_density.and_then(EmbedDensity::sparse) {
        let dims = crate::sparse_density::sparse_dims(source, &bbox, spec)?;
        match spool_dir {
            None => {
                sparse = Some(crate::sparse_density::bake_sparse_density(
                    source, &bbox, dims,
                )?)
            }
            Some(dir) => {
                spool = Some(crate::sparse_density::spool_sparse_density(
                    source, &bbox, dims, dir,
                )?)
            }
        }
    }

    let (mut grid, mut stats) = finish(
        desc,
        tile,
        dense,
        (majorant, density),
        opts.metadata.clone(),
        block_len,
        started,
    )?;
    stats.gpu = gpu_times;
    let control = opts
        .embed_control
        .map(|c| crate::control::bake_control_cancellable(source, &bbox, &c, &|| opts.cancelled()))
        .transpose()?;
    opts.check_cancel()?;
    if sparse.is_some() || control.is_some() {
        grid.sparse_density = sparse;
        grid.control = control;
        grid.validate()?;
    }
    if let Some(s) = &spool {
        pin_format::SparseDensityView::check_index(&s.header, &s.index)?;
    }
    Ok((grid, spool, stats))
}

/// The entries of `dense` from the GPU bake of `field`, which must be a dense grid (the
/// source's own or its dense copy within the budget).
#[allow(clippy::too_many_arguments)]
fn gpu_entries(
    field: Field<'_>,
    source: &dyn DensitySource,
    (placement, layout): (&Placement, &PinLayout),
    (z_begin, block_len): (u32, usize),
    dense: &mut [PinEntry],
    backend: BakeBackend,
    progress: &(dyn Fn(u64) + Sync),
    opts: &BakeOptions,
) -> Result<Option<GpuBakeTimes>, BakeError> {
    #[cfg(feature = "gpu")]
    {
        let BakeBackend::Gpu(gpu) = backend else {
            return Ok(None);
        };
        // A dense grid (the source's own or its dense copy) goes up in slices of itself; a
        // sparse source without a copy within the budget builds each slab of its dense grid.
        let density = match (field, source.dense_lattice()) {
            (Field::Grid(grid), _) => crate::gpu_bake::GpuDensity::Grid(grid),
            (_, Some(lattice)) => crate::gpu_bake::GpuDensity::Planes {
                source,
                lattice,
                host_bytes: opts.dense_copy_bytes,
            },
            _ => {
                return Err(BakeError::Gpu(format!(
                    "the GPU bake marches a voxel grid and {} has none (an analytic field, or \
                     a rotated grid); use the CPU backend",
                    source.describe(),
                )));
            }
        };
        let opened = Instant::now();
        let baker = crate::gpu_bake::GpuBaker::new()?;
        let mut times = GpuBakeTimes {
            device_s: opened.elapsed().as_secs_f64(),
            adapter: baker.describe().to_string(),
            ..GpuBakeTimes::default()
        };
        baker.bake_entries(
            &density,
            placement,
            layout,
            z_begin,
            block_len,
            dense,
            &gpu,
            progress,
            (opts.cancel.is_some(), &|| opts.cancelled()),
            &mut times,
        )?;
        Ok(Some(times))
    }
    #[cfg(not(feature = "gpu"))]
    {
        let _ = (field, source, placement, layout, z_begin, block_len, dense);
        let _ = (backend, progress, opts);
        Err(BakeError::Gpu(
            "this build has no GPU bake (cargo feature `gpu`); use the CPU backend".into(),
        ))
    }
}

/// The grid from every pin of the bake (`dense`, `block_len` pins per covered cell, in cell
/// order): compacted (empty cells keep only their index entry), with its sections, validated,
/// and its statistics. The last step of a bake and of a merge of parts.
#[allow(clippy::type_complexity)]
pub(crate) fn finish(
    mut desc: pin_format::GridDesc,
    tile: Option<TileDesc>,
    dense: Vec<PinEntry>,
    (majorant, density): (
        Option<(MajorantHeader, Vec<f32>)>,
        Option<(DensityHeader, Vec<f16>)>,
    ),
    metadata: Metadata,
    block_len: usize,
    started: Instant,
) -> Result<(OwnedPinGrid, BakeStats), BakeError> {
    let covered = dense.len() / block_len.max(1);
    // Compact: empty cells keep only their index entry.
    let mut index = try_filled("the cell index", covered, 0u32)?;
    index.clear();
    // Sized in a first pass so that the compacted copy is one fallible allocation.
    let stored_blocks = dense
        .par_chunks(block_len)
        .filter(|b| !b.iter().all(PinEntry::is_empty))
        .count();
    let mut pins = try_filled(
        "the stored pins",
        stored_blocks * block_len,
        PinEntry::EMPTY,
    )?;
    pins.clear();
    let mut stored = 0u32;
    for block in dense.chunks(block_len) {
        if block.iter().all(PinEntry::is_empty) {
            index.push(EMPTY_CELL);
        } else {
            index.push(stored);
            stored += 1;
            pins.extend_from_slice(block);
        }
    }
    drop(dense);
    desc.stored_cells = u64::from(stored);

    let mut stats = BakeStats {
        pins: pins.len() as u64,
        empty_cells: covered as u64 - u64::from(stored),
        covered_cells: covered as u64,
        ..Default::default()
    };
    let total_pins = (covered * block_len) as f64;
    let (mut lo, mut hi, mut sum) = (f32::INFINITY, f32::NEG_INFINITY, 0.0f64);
    for p in &pins {
        lo = lo.min(p.t_min);
        hi = hi.max(p.t_min);
        sum += f64::from(p.t_min);
    }
    // Pins of empty cells are not stored but count as t_min = 1.
    let empty_pins = total_pins - pins.len() as f64;
    if empty_pins > 0.0 || pins.is_empty() {
        lo = lo.min(1.0);
        hi = hi.max(1.0);
        sum += empty_pins;
    }
    stats.t_min_min = lo;
    stats.t_min_max = hi;
    stats.t_min_mean = if total_pins > 0.0 {
        sum / total_pins
    } else {
        1.0
    };
    stats.seconds = started.elapsed().as_secs_f64();
    stats.pins_per_s = total_pins / stats.seconds.max(1e-9);

    let grid = OwnedPinGrid {
        desc,
        tile,
        cell_index: Some(index),
        pins,
        majorant,
        density,
        sparse_density: None,
        control: None,
        metadata: Some(metadata),
    };
    grid.validate()?;
    Ok((grid, stats))
}

fn cell_box(bbox: &Aabb, dims: [u32; 3], c: [u32; 3]) -> Aabb {
    let e = bbox.extent();
    let f = |a: usize, i: u32| bbox.min[a] + e[a] * f64::from(i) / f64::from(dims[a]);
    Aabb::new(
        DVec3::new(f(0, c[0]), f(1, c[1]), f(2, c[2])),
        DVec3::new(f(0, c[0] + 1), f(1, c[1] + 1), f(2, c[2] + 1)),
    )
}

fn check_dims(what: &str, dims: [u32; 3]) -> Result<usize, BakeError> {
    if dims.contains(&0) || dims.iter().any(|&d| d > 4096) {
        return Err(BakeError::Options(format!(
            "{what} dims {dims:?} must be 1..=4096 per axis"
        )));
    }
    Ok(dims.iter().map(|&d| d as usize).product())
}

pub(crate) fn bake_majorant(
    source: &dyn DensitySource,
    bbox: &Aabb,
    dims: [u32; 3],
) -> Result<(MajorantHeader, Vec<f32>), BakeError> {
    let n = check_dims("majorant", dims)?;
    let mut values = try_filled("the majorant grid", n, 0.0f32)?;
    values.par_iter_mut().enumerate().for_each(|(i, v)| {
        let c = unflatten(i, dims);
        *v = source.max_extinction_in(cell_box(bbox, dims, c));
    });
    Ok((MajorantHeader { dims, reserved: 0 }, values))
}

fn bake_density(
    source: &dyn DensitySource,
    bbox: &Aabb,
    dims: [u32; 3],
) -> Result<(DensityHeader, Vec<f16>), BakeError> {
    let n = check_dims("density", dims)?;
    let e = bbox.extent();
    // Filled in place: collecting a `Result` (tens of bytes) per 2-byte voxel first made the
    // peak many times the grid (7.6 GB for a 268 MB field).
    let centre = |i: usize| {
        let c = unflatten(i, dims);
        DVec3::new(
            bbox.min.x + e.x * (f64::from(c[0]) + 0.5) / f64::from(dims[0]),
            bbox.min.y + e.y * (f64::from(c[1]) + 0.5) / f64::from(dims[1]),
            bbox.min.z + e.z * (f64::from(c[2]) + 0.5) / f64::from(dims[2]),
        )
    };
    // Below the source's resolution, each voxel is the mean of the source over it.
    let spacing = e / DVec3::new(dims[0].into(), dims[1].into(), dims[2].into());
    let sub = crate::box_filter::filter_samples(source, spacing);
    let value = |i: usize| crate::box_filter::box_filtered(source, centre(i), spacing, sub);
    let mut values = try_filled("the embedded density", n, f16::ZERO)?;
    values
        .par_iter_mut()
        .enumerate()
        .for_each(|(i, out)| *out = f16::from_f32(value(i)));
    // The first bad voxel in index order, so the message does not depend on scheduling.
    if let Some(i) = values.iter().position(|h| !h.is_finite()) {
        let p = centre(i);
        return Err(BakeError::DensityRange {
            value: value(i),
            at: p.to_array(),
        });
    }
    Ok((
        DensityHeader {
            dims,
            encoding: DENSITY_F16,
        },
        values,
    ))
}

fn unflatten(i: usize, dims: [u32; 3]) -> [u32; 3] {
    let (nx, ny) = (dims[0] as usize, dims[1] as usize);
    [
        (i % nx) as u32,
        ((i / nx) % ny) as u32,
        (i / (nx * ny)) as u32,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pin::{interval_optical_depths, unit_cube_chord};
    use crate::rng::CounterRng;
    use pin_format::PinFile;
    use pin_volume::Density;
    use pin_volume::procedural::HomogeneousBox;

    fn homogeneous(sigma: f32) -> HomogeneousBox {
        HomogeneousBox::new(
            Aabb::new(DVec3::new(-1.0, 0.0, 2.0), DVec3::new(1.0, 0.5, 3.0)),
            sigma,
        )
        .unwrap()
    }

    fn small_opts() -> BakeOptions {
        BakeOptions {
            cells: [4, 3, 5],
            directions: Directions::Octahedral { n: 3 },
            pins_per_entry: 2,
            majorant: Some([2, 2, 2]),
            embed_density: Some(EmbedDensity::Dense([3, 3, 3])),
            ..BakeOptions::default()
        }
    }

    #[test]
    fn default_cells_never_exceed_voxels() {
        use pin_volume::DenseGrid;
        // The case that found it: a 31x34x33 grid with density everywhere.
        let dims = [31u32, 34, 33];
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        let spacing = DVec3::new(0.5, 2.0, 1.0);
        let g = DenseGrid::new(dims, vec![1.0; n], spacing, DVec3::ZERO, "t").unwrap();
        assert_eq!(default_cells(&g, true, 32).unwrap(), [31, 32, 32]);
        assert_eq!(default_cells(&g, false, 16).unwrap(), [16, 16, 16]);
        assert_eq!(default_cells(&g, false, 0).unwrap(), [1, 1, 1]);
        // Cropping to 5 occupied voxels along x leaves 7 (one voxel of margin each side).
        let mut data = vec![0.0; n];
        for z in 0..33 {
            for y in 0..34 {
                for x in 10..15 {
                    data[x + 31 * (y + 34 * z)] = 1.0;
                }
            }
        }
        let g = DenseGrid::new(dims, data, spacing, DVec3::ZERO, "t").unwrap();
        assert_eq!(default_cells(&g, true, 32).unwrap(), [7, 32, 32]);
        assert_eq!(default_cells(&g, false, 32).unwrap(), [31, 32, 32]);
        // An analytic field has no voxels.
        assert_eq!(default_cells(&homogeneous(1.0), true, 32).unwrap(), [32; 3]);
    }

    #[test]
    fn working_bytes_grow_with_the_pins_up_to_one_batch() {
        let small = small_opts();
        let pins = 4 * 3 * 5 * u64::from(small.directions.count()) * 2;
        let per_pin = estimate_working_bytes(&small) / pins;
        assert!(per_pin > 48 && estimate_working_bytes(&small) == pins * per_pin);
        // The default bake has 20^3 x 256 pins, more than a batch: the bound stops growing.
        let big = BakeOptions::default();
        let huge = BakeOptions {
            cells: [64; 3],
            ..BakeOptions::default()
        };
        assert_eq!(estimate_working_bytes(&big), estimate_working_bytes(&huge));
        assert!(estimate_working_bytes(&huge) < 200 << 20);
    }

    /// The dense copy may hold at most 4 voxels per sample the bake takes, and never more
    /// than the options allow.
    #[test]
    fn the_dense_copy_is_capped_by_the_samples() {
        let opts = BakeOptions {
            cells: [4, 4, 4],
            directions: Directions::Octahedral { n: 2 },
            step: 0.05,
            ..BakeOptions::default()
        };
        let pins = pin_count(&opts);
        assert_eq!(pins, 64 * 4);
        let samples = pins as f64 / 0.05;
        assert_eq!(dense_copy_limit(&opts), (samples * 4.0 * 4.0) as u64);
        let tight = BakeOptions {
            dense_copy_bytes: 1000,
            ..opts.clone()
        };
        assert_eq!(dense_copy_limit(&tight), 1000);
        // A tile takes its own pins' samples only.
        let tile = BakeOptions {
            tile: Some(Tile { index: 0, count: 2 }),
            ..opts
        };
        assert_eq!(dense_copy_limit(&tile), (samples / 2.0 * 16.0) as u64);
    }

    #[test]
    fn homogeneous_box_matches_closed_form() {
        // Every interval of a chord through a homogeneous box has tau = sigma * world length,
        // and the midpoint rule is exact for a constant integrand.
        // Both pin placements: the default (cell centres) and the thesis' jittered pins.
        let src = homogeneous(3.0);
        for jitter_pins in [false, true] {
            let opts = BakeOptions {
                majorant: None,
                jitter_pins,
                ..small_opts()
            };
            let (grid, _) = bake(&src, &opts, &|_| {}).unwrap();
            let layout = PinLayout {
                dims: opts.cells,
                directions: opts.directions,
                pins_per_entry: opts.pins_per_entry,
                jitter: jitter_pins,
                seed: opts.seed,
            };
            let extent = DVec3::new(2.0, 0.5, 1.0);
            let bytes = grid.to_bytes().unwrap();
            let file = PinFile::parse(&bytes).unwrap();
            assert_eq!(
                file.desc().flags & GRID_FLAG_JITTERED_PINS != 0,
                jitter_pins,
                "the flag records the placement"
            );
            let mut checked = 0;
            for z in 0..5 {
                for y in 0..3 {
                    for x in 0..4 {
                        let cell = [x, y, z];
                        for dir in 0..9 {
                            for k in 0..2 {
                                let mut rng = layout.rng(layout.cell_linear(cell), dir, k);
                                let (p, w) = layout.line(cell, dir, &mut rng);
                                if !jitter_pins {
                                    let centre = DVec3::new(
                                        (f64::from(x) + 0.5) / 4.0,
                                        (f64::from(y) + 0.5) / 3.0,
                                        (f64::from(z) + 0.5) / 5.0,
                                    );
                                    assert_eq!(p, centre);
                                    assert_eq!(
                                        w,
                                        DVec3::from(
                                            opts.directions.direction_in_cell(dir, 0.5, 0.5)
                                        )
                                    );
                                }
                                let (s0, s1) = unit_cube_chord(p, w).unwrap();
                                let len = (s1 - s0) / 32.0 * (w * extent).length();
                                let want = (-3.0 * len).exp() as f32;
                                let e = file.entry(cell, dir, k);
                                assert!(
                                    (e.t_min - want).abs() <= 2e-6 * want.max(1e-30),
                                    "{cell:?} {dir} {k}: {} vs {want}",
                                    e.t_min
                                );
                                // Equal intervals: every ratio is 1, so every bit is set.
                                if want < 1.0 {
                                    assert_eq!(e.mask, u32::MAX);
                                }
                                checked += 1;
                            }
                        }
                    }
                }
            }
            assert_eq!(checked, 4 * 3 * 5 * 9 * 2);
        }
    }

    #[test]
    fn same_bytes_for_any_thread_count() {
        let src = homogeneous(0.7);
        let mut outs = Vec::new();
        for threads in [1, 2, 3] {
            let opts = BakeOptions {
                threads: Some(threads),
                seed: 99,
                ..small_opts()
            };
            outs.push(bake(&src, &opts, &|_| {}).unwrap().0.to_bytes().unwrap());
        }
        assert_eq!(outs[0], outs[1]);
        assert_eq!(outs[0], outs[2]);
    }

    #[test]
    fn dense_grid_bakes_the_same_bytes_for_any_thread_count() {
        // The marched grid path (and the x-row task order) is thread-independent too.
        use pin_volume::DenseGrid;
        let dims = [12u32, 9, 10];
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        let data: Vec<f32> = (0..n).map(|i| ((i * 31) % 13) as f32 * 0.4).collect();
        let g = DenseGrid::new(dims, data, DVec3::splat(0.25), DVec3::ZERO, "t").unwrap();
        let mut outs = Vec::new();
        for threads in [1, 2, 3] {
            let opts = BakeOptions {
                threads: Some(threads),
                seed: 7,
                ..small_opts()
            };
            outs.push(bake(&g, &opts, &|_| {}).unwrap().0.to_bytes().unwrap());
        }
        assert_eq!(outs[0], outs[1]);
        assert_eq!(outs[0], outs[2]);
    }

    #[test]
    fn tiles_merge_into_the_monolithic_bytes() {
        let src = homogeneous(0.7);
        let whole = bake(&src, &small_opts(), &|_| {}).unwrap().0;
        for count in [1, 2, 3, 5] {
            let tiles: Vec<Vec<u8>> = (0..count)
                .rev()
                .map(|index| {
                    let opts = BakeOptions {
                        tile: Some(Tile { index, count }),
                        ..small_opts()
                    };
                    bake(&src, &opts, &|_| {}).unwrap().0.to_bytes().unwrap()
                })
                .collect();
            let parsed: Vec<(String, PinFile<'_>)> = tiles
                .iter()
                .enumerate()
                .map(|(i, b)| (format!("t{i}"), PinFile::parse(b).unwrap()))
                .collect();
            let merged = crate::merge_tiles(&parsed).unwrap();
            assert_eq!(merged.to_bytes().unwrap(), whole.to_bytes().unwrap());
        }
        // More tiles than layers is refused.
        let opts = BakeOptions {
            tile: Some(Tile { index: 0, count: 7 }),
            ..small_opts()
        };
        assert!(matches!(
            bake(&src, &opts, &|_| {}),
            Err(BakeError::Options(_))
        ));
    }

    #[test]
    fn merge_rejects_gaps_and_mismatches() {
        let src = homogeneous(0.7);
        let tile = |index, count, seed| {
            let opts = BakeOptions {
                tile: Some(Tile { index, count }),
                seed,
                ..small_opts()
            };
            bake(&src, &opts, &|_| {}).unwrap().0.to_bytes().unwrap()
        };
        let (a, b, c) = (tile(0, 3, 1), tile(2, 3, 1), tile(1, 3, 2));
        let pa = PinFile::parse(&a).unwrap();
        let pb = PinFile::parse(&b).unwrap();
        let pc = PinFile::parse(&c).unwrap();
        let gap = [("a".to_string(), pa.clone()), ("b".to_string(), pb.clone())];
        assert!(matches!(
            crate::merge_tiles(&gap),
            Err(crate::MergeError::Coverage(_))
        ));
        let mixed = [
            ("a".to_string(), pa),
            ("c".to_string(), pc),
            ("b".to_string(), pb),
        ];
        assert!(matches!(
            crate::merge_tiles(&mixed),
            Err(crate::MergeError::Mismatch { .. })
        ));
    }

    #[test]
    fn empty_and_extreme_densities() {
        // Zero density: every cell empty, no pins stored, file still valid.
        let zero = homogeneous(0.0);
        let (g, stats) = bake(&zero, &small_opts(), &|_| {}).unwrap();
        assert_eq!(g.pins.len(), 0);
        assert_eq!(stats.empty_cells, stats.covered_cells);
        let bytes = g.to_bytes().unwrap();
        PinFile::parse(&bytes).unwrap().verify().unwrap();
        // Tiny density: t_min rounds to 1 in f32, so pins are empty, never NaN.
        let (g, _) = bake(&homogeneous(1e-30), &small_opts(), &|_| {}).unwrap();
        assert!(g.pins.iter().all(|p| p.t_min.is_finite()));
        // Huge density: t underflows to 0; masks are all ones, t_min exactly 0.
        let opts = BakeOptions {
            embed_density: None,
            ..small_opts()
        };
        let (g, _) = bake(&homogeneous(1e6), &opts, &|_| {}).unwrap();
        assert!(g.pins.iter().all(|p| p.t_min == 0.0 && p.mask == u32::MAX));
        let bytes = g.to_bytes().unwrap();
        PinFile::parse(&bytes).unwrap().verify().unwrap();
        // ...but 1e6 does not fit the f16 density field: a clear error.
        assert!(matches!(
            bake(&homogeneous(1e6), &small_opts(), &|_| {}),
            Err(BakeError::DensityRange { .. })
        ));
    }

    /// A field whose interval optical depths differ, so mask bits are genuinely random.
    struct Ramp;
    impl Density for Ramp {
        fn bounds(&self) -> Aabb {
            Aabb::new(DVec3::ZERO, DVec3::ONE)
        }
        fn extinction(&self, p: DVec3) -> f32 {
            if (0.0..=1.0).contains(&p.x)
                && (0.0..=1.0).contains(&p.y)
                && (0.0..=1.0).contains(&p.z)
            {
                (4.0 * p.x * p.x) as f32
            } else {
                0.0
            }
        }
        fn max_extinction_in(&self, _: Aabb) -> f32 {
            4.0
        }
    }

    impl DensitySource for Ramp {
        fn describe(&self) -> String {
            "ramp".into()
        }
    }

    #[test]
    fn mask_bit_frequencies_match_ratios() {
        // One pin, many seeds: bit i is set with probability (1 - t_i) / (1 - t_min).
        let placement = Placement {
            box_min: DVec3::ZERO,
            extent: DVec3::ONE,
            step: 0.001,
        };
        let p = DVec3::new(0.5, 0.5, 0.5);
        let w = DVec3::new(0.9, 0.1, 0.3).normalize();
        let taus = interval_optical_depths(&Ramp, &placement, p, w);
        let tau_max = taus.iter().copied().fold(0.0, f64::max);
        let n = 20_000u32;
        let mut counts = [0u32; 32];
        for seed in 0..n {
            let mut rng = CounterRng::new(u64::from(seed), 0, 0);
            let e = make_entry(&taus, &mut rng);
            for (i, c) in counts.iter_mut().enumerate() {
                *c += (e.mask >> (31 - i)) & 1;
            }
        }
        let mut worst = 0.0f64;
        for i in 0..32 {
            let q = (-taus[i]).exp_m1() / (-tau_max).exp_m1();
            let freq = f64::from(counts[i]) / f64::from(n);
            let sd = (q * (1.0 - q) / f64::from(n)).sqrt();
            if sd > 0.0 {
                worst = worst.max(((freq - q) / sd).abs());
            } else {
                assert_eq!(freq, q, "bit {i}");
            }
        }
        // 32 z-scores; |z| < 4.5 for all has family-wise false-alarm rate ~2e-4.
        assert!(worst < 4.5, "worst z {worst}");
    }
}

/// Where a bake's source came from, as its file records it: the front ends (the CLI, the
/// Python binding) fill this in and [`bake_metadata`] does the rest, so two front ends given
/// the same inputs write the same bytes.
#[derive(Clone, Debug)]
pub struct Provenance {
    /// File name (not path) of the source, or its procedural description.
    pub source_name: String,
    /// Hex xxh3-128 of the source file's bytes (empty for procedural and in-memory sources).
    pub source_hash: String,
    pub seed: u64,
    pub step: f64,
    pub density_scale: f64,
    pub crop: bool,
}

/// The metadata a bake of `source` with `cells` and `directions` writes: the provenance, the
/// tool, the bake's layout and the source's identity (what `pinrender` checks `--pins` against
/// its `--volume` with). A timestamp is recorded only when `SOURCE_DATE_EPOCH` pins one (the
/// reproducible-builds convention), so bakes are byte-identical by default.
pub fn bake_metadata(
    source: &dyn DensitySource,
    prov: Provenance,
    cells: [u32; 3],
    directions: Directions,
) -> Metadata {
    let (kind, res) = directions.to_desc();
    let mut extra = vec![
        ("cells".into(), format!("{cells:?}")),
        ("crop".into(), prov.crop.to_string()),
        ("directions".into(), format!("{kind}:{}x{}", res[0], res[1])),
    ];
    extra.extend(pin_volume::SourceIdentity::of(source, prov.density_scale).to_extra());
    extra.sort();
    Metadata {
        tool: "pinbake".into(),
        tool_version: env!("CARGO_PKG_VERSION").into(),
        source_name: prov.source_name,
        source_hash: prov.source_hash,
        source_description: source.describe(),
        seed: prov.seed,
        step_size: prov.step,
        density_scale: prov.density_scale,
        bake_unix_time: std::env::var("SOURCE_DATE_EPOCH")
            .ok()
            .and_then(|s| s.parse().ok()),
        extra,
    }
}
