//! The embedded sparse density (format 1.1 section 5.6a): the source resampled at voxel
//! centres over the grid box, stored only in bricks where it is non-zero.
//!
//! Built brick by brick from the source's own sparse structure: a brick whose box the source
//! bounds by zero ([`Density::max_extinction_in`], a VDB's leaf and tile table) is never
//! sampled, and no dense grid of the box is ever allocated, so the section's memory is the
//! stored bricks' plus one index entry per brick.

use glam::DVec3;
use half::f16;
use pin_format::layout::{DENSITY_F16, EMPTY_BRICK, SparseDensityHeader};
use pin_format::{OwnedSparseDensity, OwnedSparseValues, StreamedSparseDensity, brick_dims};
use rayon::prelude::*;
use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use crate::alloc::{try_filled, try_reserved};
use crate::error::BakeError;
use pin_volume::{Aabb, DensitySource};

/// Brick edge of the sections pinbake writes: 8^3 voxels (1 KiB of f16), the granularity of an
/// OpenVDB leaf.
pub const SPARSE_BRICK: u32 = 8;
/// Voxels along the longest axis when the source has no voxels of its own (analytic fields).
pub const ANALYTIC_VOXELS: u32 = 256;
/// Most voxels per axis of a sparse density (the format's cell limit, far above any volume).
pub const MAX_SPARSE_DIM: u32 = 1 << 16;

/// How many voxels the sparse density has.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SparseDims {
    /// The source's own voxel size over the grid box.
    Source,
    /// The source's voxel size, coarsened (the same factor on every axis) so that no axis has
    /// more than this many voxels.
    Max(u32),
    /// Exactly these voxels per axis.
    Exact([u32; 3]),
}

/// The voxel dims for `spec` over `bbox` of `source`.
pub fn sparse_dims(
    source: &dyn DensitySource,
    bbox: &Aabb,
    spec: SparseDims,
) -> Result<[u32; 3], BakeError> {
    let e = bbox.extent();
    let dims = match spec {
        SparseDims::Exact(d) => d,
        SparseDims::Source | SparseDims::Max(_) => {
            let voxel = source
                .voxel_size()
                .filter(|v| v.is_finite() && v.cmpgt(DVec3::ZERO).all())
                .unwrap_or(DVec3::splat(e.max_element() / f64::from(ANALYTIC_VOXELS)));
            let mut n = (e / voxel).to_array();
            if let SparseDims::Max(m) = spec {
                let longest = n.iter().copied().fold(0.0, f64::max);
                if longest > f64::from(m) {
                    n = n.map(|v| v * f64::from(m) / longest);
                }
            }
            // A box cropped to whole voxels gives integers up to rounding: do not add a voxel
            // for the rounding.
            n.map(|v| ((v - 1e-6).ceil().max(1.0)).min(f64::from(u32::MAX)) as u32)
        }
    };
    if dims.contains(&0) || dims.iter().any(|&d| d > MAX_SPARSE_DIM) {
        return Err(BakeError::Options(format!(
            "sparse density dims {dims:?} must be 1..={MAX_SPARSE_DIM} per axis"
        )));
    }
    Ok(dims)
}

/// What a sparse density of `dims` voxels over `bbox` costs, known before any brick is
/// tested: from the grid's dims and the source's solid boxes
/// ([`DensitySource::solid_boxes`]: a VDB's constant tiles), in time that does not grow with
/// the bricks. A few hundred bytes of VDB can declare a 4096^3 constant root tile, whose
/// sparse copy is 134 M bricks: counting its candidates one by one before checking any
/// budget held gigabytes and ran for minutes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SparseBounds {
    /// Brick slots of the index (a `u32` each, whatever is stored).
    pub slots: u64,
    /// Rows of bricks (fixed y and z): one candidate list each.
    pub rows: u64,
    /// Bricks along a row.
    pub row_len: u64,
    /// Bricks that must be stored: each lies inside a solid box (a lower bound).
    pub min_bricks: u64,
}

/// Bytes of one f16 brick, as stored in the file and the spool.
pub const F16_BRICK_BYTES: u64 = (SPARSE_BRICK as u64).pow(3) * 2;
/// Bytes of one f32 brick, as the renderer's trackers hold them ([`sparse_f32_bricks`]).
pub const F32_BRICK_BYTES: u64 = (SPARSE_BRICK as u64).pow(3) * 4;

/// Smallest value whose f16 is not zero (the smallest subnormal): where the source is at
/// least this, a brick is stored whatever the encoding.
const STORED_FLOOR: f32 = 1.0 / 16_777_216.0;

impl SparseBounds {
    pub fn new(source: &dyn DensitySource, bbox: &Aabb, dims: [u32; 3]) -> Self {
        let bdims = brick_dims(dims, SPARSE_BRICK).map(u64::from);
        let geo = Geometry::new(bbox, dims);
        // Boxes of disjoint tiles are disjoint, so the bricks wholly inside one are not
        // inside another: the sum does not count a brick twice.
        let min_bricks = source
            .solid_boxes(STORED_FLOOR)
            .iter()
            .map(|b| geo.bricks_inside(b))
            .fold(0u64, u64::saturating_add);
        Self {
            slots: bdims.iter().product(),
            rows: bdims[1] * bdims[2],
            row_len: bdims[0],
            min_bricks: min_bricks.min(bdims.iter().product()),
        }
    }

    /// Bricks of `brick_bytes` in one fill batch at most ([`Candidates::batches`]).
    fn batch_bricks(&self, brick_bytes: u64) -> u64 {
        let per_batch = (BATCH_BYTES as u64 / brick_bytes.max(1)).max(1);
        per_batch.max(self.row_len).min(self.slots)
    }

    /// Bytes held while the bricks are found and filled, beside those kept: the index, the
    /// candidate lists (a row's list of at most `row_len` brick x, its vector's header), and
    /// one batch of bricks of `brick_bytes`.
    pub fn working_bytes(&self, brick_bytes: u64) -> u64 {
        let lists = self
            .rows
            .saturating_mul(size_of::<Vec<u32>>() as u64)
            .saturating_add(self.slots.saturating_mul(4));
        self.slots
            .saturating_mul(4)
            .saturating_add(lists)
            .saturating_add(self.batch_bricks(brick_bytes).saturating_mul(brick_bytes))
    }
}

/// The bytes [`spool_sparse_density`] holds at its peak for `source` over `bbox` with `dims`
/// voxels ([`SparseBounds::working_bytes`] and the spool's buffer): the bricks themselves go
/// to the spool file, not to memory. For the bake's memory estimate; counted from the dims
/// and the source's tree, never by building the candidates.
pub fn sparse_density_bytes(source: &dyn DensitySource, bbox: &Aabb, dims: [u32; 3]) -> u64 {
    SparseBounds::new(source, bbox, dims)
        .working_bytes(F16_BRICK_BYTES)
        .saturating_add(SPOOL_BUFFER as u64)
}

/// The least bytes the spool of a sparse density must write ([`SparseBounds::min_bricks`]),
/// for the bake's disk check before it starts.
pub fn sparse_density_min_file_bytes(
    source: &dyn DensitySource,
    bbox: &Aabb,
    dims: [u32; 3],
) -> u64 {
    SparseBounds::new(source, bbox, dims)
        .min_bricks
        .saturating_mul(F16_BRICK_BYTES)
}

/// The bytes a sparse f16 density of `source` over `bbox` with `dims` voxels takes in the
/// file, at most: its index and every brick the source does not bound by zero (the
/// candidates a fill samples; a brick whose voxels all read zero is left out after all). For
/// the default asset's choice ([`crate::default_asset`]).
pub fn sparse_density_file_bytes(source: &dyn DensitySource, bbox: &Aabb, dims: [u32; 3]) -> u64 {
    let c = Candidates::new(source, bbox, dims);
    let slots = c.bdims.iter().map(|&d| u64::from(d)).product::<u64>();
    c.count()
        .saturating_mul(F16_BRICK_BYTES)
        .saturating_add(slots.saturating_mul(4))
        .saturating_add(size_of::<SparseDensityHeader>() as u64)
}

/// The sparse f16 density of `source` over `bbox` with `dims` voxels, in memory: the stored
/// bricks and one batch of candidates at the peak.
pub fn bake_sparse_density(
    source: &dyn DensitySource,
    bbox: &Aabb,
    dims: [u32; 3],
) -> Result<OwnedSparseDensity, BakeError> {
    let candidates = Candidates::new(source, bbox, dims);
    let mut values: Vec<f16> = reserved_for(&candidates, "the sparse density bricks")?;
    let index = fill_bricks(
        source,
        &candidates,
        encode_f16,
        BATCH_BYTES,
        &mut |bricks| {
            values.extend_from_slice(bricks);
            Ok(())
        },
    )?;
    values.shrink_to_fit();
    Ok(OwnedSparseDensity {
        header: f16_header(dims, values.len()),
        index,
        values: OwnedSparseValues::F16(values),
    })
}

/// A sparse f16 density whose bricks wait in an unnamed temporary file
/// ([`spool_sparse_density`]) until the pin file is written
/// ([`pin_format::OwnedPinGrid::write_streamed_into`]).
pub struct SparseSpool {
    pub header: SparseDensityHeader,
    pub index: Vec<u32>,
    file: File,
    /// Where the spool lives, for messages.
    dir: PathBuf,
}

impl SparseSpool {
    /// The section to stream into a pin file, its bricks read from the start of the spool.
    pub fn streamed(&mut self) -> std::io::Result<StreamedSparseDensity<'_>> {
        self.file.seek(SeekFrom::Start(0))?;
        Ok(StreamedSparseDensity {
            header: self.header,
            index: &self.index,
            values: &mut self.file,
        })
    }

    /// Reads the bricks back into memory (for tests and small grids).
    pub fn into_owned(mut self) -> Result<OwnedSparseDensity, BakeError> {
        let n = self.header.brick_count as usize * (self.header.brick as usize).pow(3);
        let mut values = try_filled("the sparse density bricks", n, f16::ZERO)?;
        self.file
            .seek(SeekFrom::Start(0))
            .and_then(|_| self.file.read_exact(bytemuck::cast_slice_mut(&mut values)))
            .map_err(|source| BakeError::Spool {
                dir: self.dir.clone(),
                source,
            })?;
        Ok(OwnedSparseDensity {
            header: self.header,
            index: self.index,
            values: OwnedSparseValues::F16(values),
        })
    }
}

/// Bytes of the spool's write buffer.
const SPOOL_BUFFER: usize = 1 << 20;

/// [`bake_sparse_density`] with the bricks written, batch by batch, to an unnamed temporary
/// file in `dir` (removed by the system when it is closed, even if the process is killed)
/// instead of held: a production-scale bake then holds its source, the index and one batch,
/// where the bricks alone can outweigh the source (1.5 G voxels of f16).
pub fn spool_sparse_density(
    source: &dyn DensitySource,
    bbox: &Aabb,
    dims: [u32; 3],
    dir: &Path,
) -> Result<SparseSpool, BakeError> {
    let spool_err = |source| BakeError::Spool {
        dir: dir.to_path_buf(),
        source,
    };
    let candidates = Candidates::new(source, bbox, dims);
    // The spool holds at most every candidate, and the output then copies what it holds:
    // refused before the first brick is written, not when the disk is full.
    let need = candidates
        .count()
        .saturating_mul(F16_BRICK_BYTES)
        .saturating_mul(2);
    pin_volume::files::check_free_space(dir, need).map_err(BakeError::Disk)?;
    let file = tempfile::tempfile_in(dir).map_err(spool_err)?;
    let mut out = BufWriter::with_capacity(SPOOL_BUFFER, file);
    let mut stored = 0usize;
    let index = fill_bricks(
        source,
        &candidates,
        encode_f16,
        BATCH_BYTES,
        &mut |bricks| {
            stored += bricks.len();
            out.write_all(bytemuck::cast_slice(bricks))
                .map_err(spool_err)
        },
    )?;
    let file = out.into_inner().map_err(|e| spool_err(e.into_error()))?;
    Ok(SparseSpool {
        header: f16_header(dims, stored),
        index,
        file,
        dir: dir.to_path_buf(),
    })
}

fn encode_f16(v: f32) -> Option<f16> {
    let h = f16::from_f32(v);
    h.is_finite().then_some(h)
}

fn f16_header(dims: [u32; 3], voxels: usize) -> SparseDensityHeader {
    SparseDensityHeader {
        dims,
        encoding: DENSITY_F16,
        brick: SPARSE_BRICK,
        brick_count: (voxels / (SPARSE_BRICK as usize).pow(3)) as u32,
        reserved: [0; 2],
    }
}

/// An empty vector with room for every candidate brick: the address space of the bound,
/// of which only the stored bricks are ever touched (and so resident).
fn reserved_for<T>(candidates: &Candidates, what: &'static str) -> Result<Vec<T>, BakeError> {
    let n = usize::try_from(candidates.count())
        .unwrap_or(usize::MAX)
        .saturating_mul((SPARSE_BRICK as usize).pow(3));
    try_reserved(what, n)
}

/// Bricks of `SPARSE_BRICK` over `bbox` with `dims` voxels whose box the source does not
/// bound by zero, in f32 (the source's own values at the centres): the brick index and the
/// stored voxels, or `None` when they would take more than `max_bytes`. Counted twice, each
/// time before the memory it counts is touched: from the dims and the source's solid boxes
/// ([`SparseBounds`]) before the candidates are listed, then from the candidates before
/// any is filled. For renderers that track a sparse source through an array instead of its
/// tree.
pub fn sparse_f32_bricks(
    source: &dyn DensitySource,
    bbox: &Aabb,
    dims: [u32; 3],
    max_bytes: u64,
) -> Option<(Vec<u32>, Vec<f32>)> {
    let bounds = SparseBounds::new(source, bbox, dims);
    let working = bounds.working_bytes(F32_BRICK_BYTES);
    let least = bounds.min_bricks.saturating_mul(F32_BRICK_BYTES);
    if working.saturating_add(least) > max_bytes {
        return None;
    }
    let candidates = Candidates::new(source, bbox, dims);
    let bytes = candidates.count().saturating_mul(F32_BRICK_BYTES);
    if working.saturating_add(bytes) > max_bytes {
        return None;
    }
    let mut values: Vec<f32> = reserved_for(&candidates, "the bricks").ok()?;
    let index = fill_bricks(
        source,
        &candidates,
        |v| v.is_finite().then_some(v),
        BATCH_BYTES,
        &mut |b| {
            values.extend_from_slice(b);
            Ok(())
        },
    )
    .ok()?;
    values.shrink_to_fit();
    Some((index, values))
}

/// Voxel centres and brick boxes of `dims` voxels over `bbox`, and the box filter's
/// sub-samples per axis ([`crate::box_filter::filter_samples`]; 1: the value at the
/// centre).
struct Geometry {
    min: DVec3,
    spacing: DVec3,
    dims: [u32; 3],
    sub: [u32; 3],
}

impl Geometry {
    fn new(bbox: &Aabb, dims: [u32; 3]) -> Self {
        let e = bbox.extent();
        Self {
            min: bbox.min,
            spacing: DVec3::new(
                e.x / f64::from(dims[0]),
                e.y / f64::from(dims[1]),
                e.z / f64::from(dims[2]),
            ),
            dims,
            sub: [1; 3],
        }
    }

    /// [`Self::new`], each voxel the box-filtered mean of `source` over it.
    fn filtered(source: &dyn DensitySource, bbox: &Aabb, dims: [u32; 3]) -> Self {
        let mut g = Self::new(bbox, dims);
        g.sub = crate::box_filter::filter_samples(source, g.spacing);
        g
    }

    /// The value of voxel `v` of `source`: [`crate::box_filter::box_filtered`].
    fn value(&self, source: &dyn DensitySource, v: [u32; 3]) -> f32 {
        crate::box_filter::box_filtered(source, self.centre(v), self.spacing, self.sub)
    }

    fn centre(&self, v: [u32; 3]) -> DVec3 {
        self.min + (DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64) + 0.5) * self.spacing
    }

    /// Bricks all of whose voxel centres lie in `b` (none if it misses the grid).
    fn bricks_inside(&self, b: &Aabb) -> u64 {
        let per_axis = |a: usize| -> u64 {
            let n = i64::from(self.dims[a]);
            // Voxel i's centre is at min + (i + 0.5) spacing.
            let lo = ((b.min[a] - self.min[a]) / self.spacing[a] - 0.5).ceil();
            let hi = ((b.max[a] - self.min[a]) / self.spacing[a] - 0.5).floor();
            if !(lo.is_finite() && hi.is_finite()) {
                return 0;
            }
            let lo = (lo.max(0.0) as i64).min(n);
            let hi = (hi.min((n - 1) as f64) as i64).max(-1);
            if hi < lo {
                return 0;
            }
            // A brick's voxels run from 8k to min(8k + 7, n - 1).
            let k = i64::from(SPARSE_BRICK);
            let first = (lo + k - 1) / k;
            let last = if hi == n - 1 {
                hi / k
            } else {
                (hi + 1) / k - 1
            };
            (last - first + 1).max(0) as u64
        };
        per_axis(0)
            .saturating_mul(per_axis(1))
            .saturating_mul(per_axis(2))
    }

    /// The box of brick `b` and its voxel range `lo..hi`.
    fn region(&self, b: [u32; 3]) -> (Aabb, [u32; 3], [u32; 3]) {
        let lo = b.map(|c| c * SPARSE_BRICK);
        let hi = [0, 1, 2].map(|a| (lo[a] + SPARSE_BRICK).min(self.dims[a]));
        let at = |v: [u32; 3]| {
            self.min + DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64) * self.spacing
        };
        (Aabb::new(at(lo), at(hi)), lo, hi)
    }
}

/// The bricks of `dims` voxels over `bbox` that the source's bound does not rule out: per row
/// of bricks (fixed y and z, `y` fastest), their x in order. What a fill samples, what the
/// memory checks count.
struct Candidates {
    geo: Geometry,
    bdims: [u32; 3],
    rows: Vec<Vec<u32>>,
}

impl Candidates {
    fn new(source: &dyn DensitySource, bbox: &Aabb, dims: [u32; 3]) -> Self {
        let bdims = brick_dims(dims, SPARSE_BRICK);
        let geo = Geometry::filtered(source, bbox, dims);
        let rows = (0..bdims[1] as usize * bdims[2] as usize)
            .into_par_iter()
            .map(|row| {
                let (by, bz) = Self::row_yz(bdims, row);
                // Shrunk to what it holds: the lists take at most what
                // `SparseBounds::working_bytes` counts.
                let mut xs: Vec<u32> = (0..bdims[0])
                    .filter(|&bx| source.max_extinction_in(geo.region([bx, by, bz]).0) > 0.0)
                    .collect();
                xs.shrink_to_fit();
                xs
            })
            .collect();
        Self { geo, bdims, rows }
    }

    /// The brick y and z of row `row`.
    fn row_yz(bdims: [u32; 3], row: usize) -> (u32, u32) {
        (
            (row % bdims[1] as usize) as u32,
            (row / bdims[1] as usize) as u32,
        )
    }

    fn count(&self) -> u64 {
        self.rows.iter().map(|r| r.len() as u64).sum()
    }

    /// Consecutive runs of rows whose candidates take about `batch_bytes` at `brick_bytes`
    /// each (a row is never split, so a batch may exceed it by one row).
    fn batches(
        &self,
        brick_bytes: usize,
        batch_bytes: usize,
    ) -> impl Iterator<Item = std::ops::Range<usize>> + '_ {
        let per_batch = (batch_bytes / brick_bytes.max(1)).max(1);
        let mut start = 0;
        std::iter::from_fn(move || {
            if start >= self.rows.len() {
                return None;
            }
            let (mut end, mut n) = (start, 0usize);
            while end < self.rows.len() && (n == 0 || n + self.rows[end].len() <= per_batch) {
                n += self.rows[end].len();
                end += 1;
            }
            let r = start..end;
            start = end;
            Some(r)
        })
    }
}

/// Candidate bricks' bytes filled at once: the most a fill holds beside the bricks it keeps.
/// Large enough that a batch has hundreds of rows for the threads to share.
const BATCH_BYTES: usize = 64 << 20;

/// Fills the candidates batch by batch ([`Candidates::batches`]), each voxel `encode`d from the
/// source's value at its centre (`None` from `encode` is a value out of the encoding's
/// range), and hands the bricks that hold a non-zero value to `sink` in slot order; returns
/// the index. Memory: one batch of candidates, filled in place in one array and squeezed
/// (one array, not one allocation per brick: small allocations are not given back to the
/// system when freed). The bytes do not depend on the batches or the threads.
fn fill_bricks<T: Copy + Default + PartialEq + Send + Sync>(
    source: &dyn DensitySource,
    candidates: &Candidates,
    encode: impl Fn(f32) -> Option<T> + Sync,
    batch_bytes: usize,
    sink: &mut dyn FnMut(&[T]) -> Result<(), BakeError>,
) -> Result<Vec<u32>, BakeError> {
    let b = SPARSE_BRICK;
    let Candidates { geo, bdims, rows } = candidates;
    let bdims = *bdims;
    let bv = (b as usize).pow(3);
    let zero = T::default();
    let batches: Vec<_> = candidates
        .batches(bv * size_of::<T>(), batch_bytes)
        .collect();
    let largest = batches
        .iter()
        .map(|r| rows[r.clone()].iter().map(Vec::len).sum::<usize>())
        .max()
        .unwrap_or(0);
    let mut buffer = try_filled("a batch of sparse density bricks", largest * bv, zero)?;
    let slots = bdims.iter().map(|&d| d as usize).product::<usize>();
    let mut index = try_filled("the sparse density index", slots, EMPTY_BRICK)?;
    let mut slot = 0usize;
    for batch in batches {
        let n: usize = rows[batch.clone()].iter().map(Vec::len).sum();
        let values = &mut buffer[..n * bv];
        // Bricks cut by the grid's far faces leave voxels unwritten: they must be 0 in every
        // batch, whatever the previous batch left there.
        values.fill(zero);
        // Each row's candidates get consecutive places; rows fill their own slices in
        // parallel and say which of their bricks hold a non-zero value.
        let mut slices = Vec::with_capacity(batch.len());
        let mut rest = &mut *values;
        for xs in &rows[batch.clone()] {
            let (head, tail) = rest.split_at_mut(xs.len() * bv);
            slices.push(head);
            rest = tail;
        }
        let filled: Vec<Result<Vec<bool>, BakeError>> = slices
            .into_par_iter()
            .zip(rows[batch.clone()].par_iter())
            .enumerate()
            .map(|(i, (slice, xs))| {
                let (by, bz) = Candidates::row_yz(bdims, batch.start + i);
                xs.iter()
                    .zip(slice.chunks_exact_mut(bv))
                    .map(|(&bx, brick)| fill_brick(source, geo, [bx, by, bz], brick, &encode))
                    .collect()
            })
            .collect();
        let mut kept = 0usize;
        let mut candidate = 0usize;
        for (row, (r, xs)) in batch
            .clone()
            .zip(filled.into_iter().zip(&rows[batch.clone()]))
        {
            // The first failing row in brick order, so the message does not depend on
            // scheduling.
            for (keep, &bx) in r?.into_iter().zip(xs) {
                if keep {
                    index[row * bdims[0] as usize + bx as usize] = slot as u32;
                    values.copy_within(candidate * bv..(candidate + 1) * bv, kept * bv);
                    kept += 1;
                    slot += 1;
                }
                candidate += 1;
            }
        }
        sink(&values[..kept * bv])?;
    }
    Ok(index)
}

/// Fills brick `at` from the source; whether any voxel is not zero.
fn fill_brick<T: Copy + Default + PartialEq>(
    source: &dyn DensitySource,
    geo: &Geometry,
    at: [u32; 3],
    brick: &mut [T],
    encode: &impl Fn(f32) -> Option<T>,
) -> Result<bool, BakeError> {
    let b = SPARSE_BRICK;
    let zero = T::default();
    let (_, lo, hi) = geo.region(at);
    let mut any = false;
    for z in lo[2]..hi[2] {
        for y in lo[1]..hi[1] {
            for x in lo[0]..hi[0] {
                let p = geo.centre([x, y, z]);
                let v = geo.value(source, [x, y, z]);
                let Some(h) = encode(v) else {
                    return Err(BakeError::DensityRange {
                        value: v,
                        at: p.to_array(),
                    });
                };
                let l = (x - lo[0]) + b * ((y - lo[1]) + b * (z - lo[2]));
                brick[l as usize] = h;
                any |= h != zero;
            }
        }
    }
    Ok(any)
}

#[cfg(test)]
mod tests {
    use super::*;
    use pin_volume::Density;
    use pin_volume::grid::DenseGrid;
    use pin_volume::procedural::HomogeneousBox;

    #[test]
    fn only_bricks_with_density_are_stored_and_values_match_the_source() {
        let inner = Aabb::new(DVec3::splat(0.25), DVec3::splat(0.5));
        let src = HomogeneousBox::new(inner, 2.0).unwrap();
        let bbox = Aabb::new(DVec3::ZERO, DVec3::ONE);
        let dims = [40, 40, 40];
        let s = bake_sparse_density(&src, &bbox, dims).unwrap();
        let view = s.view().unwrap();
        assert_eq!(view.brick_dims, [5, 5, 5]);
        // The box covers voxels 10..20 per axis: bricks 1 and 2 on each axis.
        assert_eq!(s.header.brick_count, 8);
        for z in 0..40 {
            for y in 0..40 {
                for x in 0..40 {
                    let p = (DVec3::new(x as f64, y as f64, z as f64) + 0.5) / 40.0;
                    let want = f16::from_f32(src.extinction(p)).to_f32();
                    assert_eq!(view.get([x, y, z]), Some(want), "{x} {y} {z}");
                }
            }
        }
    }

    /// A grid with scattered clusters of density, not a multiple of the brick on any axis:
    /// its bound admits bricks next to a cluster whose own voxels are all zero, so a fill
    /// drops candidates, and the bricks on the far faces are partly outside the grid.
    fn clustered() -> (DenseGrid, Aabb, [u32; 3]) {
        let dims = [37, 29, 45];
        let data = (0..37 * 29 * 45)
            .map(|i: u32| {
                let (x, y, z) = (i % 37, (i / 37) % 29, i / (37 * 29));
                let h = (x / 5).wrapping_mul(73_856_093)
                    ^ (y / 5).wrapping_mul(19_349_663)
                    ^ (z / 5).wrapping_mul(83_492_791);
                if h % 7 == 0 && (x + y + z) % 3 != 0 {
                    0.5 + (i % 11) as f32
                } else {
                    0.0
                }
            })
            .collect();
        let g = DenseGrid::new(dims, data, DVec3::ONE, DVec3::ZERO, "clusters").unwrap();
        let bbox = g.bounds();
        (g, bbox, dims)
    }

    #[test]
    fn batches_and_the_spool_give_the_bytes_of_one_fill() {
        let (g, bbox, dims) = clustered();
        let c = Candidates::new(&g, &bbox, dims);
        let fill = |batch_bytes| {
            let (mut values, mut batches) = (Vec::new(), 0);
            let index = fill_bricks(&g, &c, encode_f16, batch_bytes, &mut |b| {
                values.extend_from_slice(b);
                batches += 1;
                Ok(())
            })
            .unwrap();
            (index, values, batches)
        };
        let (index, values, one) = fill(usize::MAX);
        assert_eq!(one, 1);
        let stored = values.len() as u64 / 512;
        assert!(
            stored > 4 && stored < c.count(),
            "{stored} stored of {} candidates: the test needs both kinds",
            c.count()
        );
        // One brick per batch, and a few rows per batch.
        for batch_bytes in [1, 5 * 1024, 16 * 1024] {
            let (i, v, n) = fill(batch_bytes);
            assert!(n > 3, "{n} batches of {batch_bytes} bytes");
            assert_eq!(i, index, "index, batches of {batch_bytes} bytes");
            assert_eq!(v, values, "bricks, batches of {batch_bytes} bytes");
        }
        let in_memory = bake_sparse_density(&g, &bbox, dims).unwrap();
        assert_eq!(in_memory.index, index);
        assert_eq!(in_memory.values, OwnedSparseValues::F16(values));
        let dir = tempfile::tempdir().unwrap();
        let spool = spool_sparse_density(&g, &bbox, dims, dir.path()).unwrap();
        // The spool has no name: nothing is left in the directory.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        assert_eq!(spool.into_owned().unwrap(), in_memory);
    }

    #[test]
    fn a_spooled_bake_writes_the_bytes_of_the_in_memory_bake() {
        use crate::bake::{BakeOptions, bake, bake_spooled};
        use pin_format::{Directions, PinFileWriter};
        let (g, _, _) = clustered();
        let opts = BakeOptions {
            cells: [5, 4, 6],
            directions: Directions::Octahedral { n: 4 },
            embed_density: Some(crate::EmbedDensity::Sparse(SparseDims::Source)),
            embed_control: Some(crate::control::ControlOptions::default()),
            ..BakeOptions::default()
        };
        let (grid, _) = bake(&g, &opts, &|_| {}).unwrap();
        assert!(grid.sparse_density.is_some());
        let want = grid.to_bytes().unwrap();
        let dir = tempfile::tempdir().unwrap();
        let (bare, spool, _) = bake_spooled(&g, &opts, &|_| {}, dir.path()).unwrap();
        assert!(bare.sparse_density.is_none());
        let mut spool = spool.expect("the options embed a sparse density");
        let mut w = PinFileWriter::new(std::io::Cursor::new(Vec::new())).unwrap();
        bare.write_streamed_into(&mut w, spool.streamed().unwrap())
            .unwrap();
        assert!(w.finish().unwrap().into_inner() == want);
        // Written twice from one spool (a retry re-reads it from the start).
        let mut w = PinFileWriter::new(std::io::Cursor::new(Vec::new())).unwrap();
        bare.write_streamed_into(&mut w, spool.streamed().unwrap())
            .unwrap();
        assert!(w.finish().unwrap().into_inner() == want);
        // Without a sparse density there is no spool and the same grid.
        let plain = BakeOptions {
            embed_density: None,
            ..opts
        };
        let (g2, spool, _) = bake_spooled(&g, &plain, &|_| {}, dir.path()).unwrap();
        assert!(spool.is_none());
        assert_eq!(g2, bake(&g, &plain, &|_| {}).unwrap().0);
    }

    #[test]
    fn a_spool_in_a_missing_directory_is_an_error_naming_it() {
        let (g, bbox, dims) = clustered();
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("gone");
        let Err(e) = spool_sparse_density(&g, &bbox, dims, &missing) else {
            panic!("a spool in a missing directory");
        };
        assert!(e.to_string().contains("gone"), "{e}");
    }

    /// A box that says it is solid: the lower bound of [`SparseBounds`] through the same
    /// trait method a VDB's tiles answer.
    struct SolidBox(HomogeneousBox, Aabb);

    impl Density for SolidBox {
        fn bounds(&self) -> Aabb {
            self.0.bounds()
        }
        fn extinction(&self, p: DVec3) -> f32 {
            self.0.extinction(p)
        }
        fn max_extinction_in(&self, region: Aabb) -> f32 {
            self.0.max_extinction_in(region)
        }
    }

    impl DensitySource for SolidBox {
        fn solid_boxes(&self, floor: f32) -> Vec<Aabb> {
            if self.0.extinction(self.1.min) >= floor {
                vec![self.1]
            } else {
                Vec::new()
            }
        }
    }

    #[test]
    fn bricks_inside_a_box_are_counted_exactly() {
        let bbox = Aabb::new(DVec3::ZERO, DVec3::new(37.0, 29.0, 45.0));
        let dims = [37, 29, 45];
        let geo = Geometry::new(&bbox, dims);
        let bdims = brick_dims(dims, SPARSE_BRICK);
        let mut rng = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng % 10_000) as f64 / 10_000.0
        };
        let mut nonzero = 0;
        for _ in 0..300 {
            let a = DVec3::new(
                next() * 50.0 - 5.0,
                next() * 40.0 - 5.0,
                next() * 60.0 - 5.0,
            );
            let b = a + DVec3::new(next() * 40.0, next() * 40.0, next() * 40.0);
            let solid = Aabb::new(a, b);
            let mut want = 0u64;
            for bz in 0..bdims[2] {
                for by in 0..bdims[1] {
                    for bx in 0..bdims[0] {
                        let (_, lo, hi) = geo.region([bx, by, bz]);
                        let inside = (lo[2]..hi[2]).all(|z| {
                            (lo[1]..hi[1]).all(|y| {
                                (lo[0]..hi[0]).all(|x| {
                                    let c = geo.centre([x, y, z]);
                                    c.cmpge(solid.min).all() && c.cmple(solid.max).all()
                                })
                            })
                        });
                        want += u64::from(inside);
                    }
                }
            }
            assert_eq!(geo.bricks_inside(&solid), want, "{solid:?}");
            nonzero += usize::from(want > 0);
        }
        assert!(
            nonzero > 30,
            "{nonzero} boxes held a brick: the test needs both kinds"
        );
    }

    #[test]
    fn bounds_hold_what_a_fill_stores_and_holds() {
        let bbox = Aabb::new(DVec3::ZERO, DVec3::ONE);
        let dims = [70, 50, 90];
        let inner = Aabb::new(DVec3::new(0.1, 0.2, 0.05), DVec3::new(0.8, 0.7, 0.9));
        let src = SolidBox(HomogeneousBox::new(inner, 2.0).unwrap(), inner);
        let bounds = SparseBounds::new(&src, &bbox, dims);
        let stored = bake_sparse_density(&src, &bbox, dims)
            .unwrap()
            .header
            .brick_count as u64;
        // A lower bound that leaves out only the bricks that the box's faces cut (two
        // thirds of them on a box 6 to 9 bricks across).
        assert!(bounds.min_bricks <= stored, "{bounds:?} vs {stored}");
        assert!(bounds.min_bricks * 3 >= stored, "{bounds:?} vs {stored}");
        let c = Candidates::new(&src, &bbox, dims);
        let lists: u64 = c
            .rows
            .iter()
            .map(|r| r.capacity() as u64 * 4 + size_of::<Vec<u32>>() as u64)
            .sum();
        assert!(lists + bounds.slots * 4 <= bounds.working_bytes(F16_BRICK_BYTES));
        assert_eq!(bounds.slots, 9 * 7 * 12);
        // Too small a floor for f16 says nothing is solid.
        let faint = SolidBox(HomogeneousBox::new(inner, 1e-9).unwrap(), inner);
        assert_eq!(SparseBounds::new(&faint, &bbox, dims).min_bricks, 0);
    }

    #[test]
    fn f32_bricks_are_refused_before_they_are_listed() {
        let bbox = Aabb::new(DVec3::ZERO, DVec3::ONE);
        let dims = [64, 64, 64];
        let src = SolidBox(HomogeneousBox::new(bbox, 1.0).unwrap(), bbox);
        let bounds = SparseBounds::new(&src, &bbox, dims);
        assert_eq!(bounds.min_bricks, 512);
        let need = bounds.working_bytes(F32_BRICK_BYTES) + 512 * F32_BRICK_BYTES;
        assert!(sparse_f32_bricks(&src, &bbox, dims, need - 1).is_none());
        let (index, values) = sparse_f32_bricks(&src, &bbox, dims, need).unwrap();
        assert_eq!((index.len(), values.len()), (512, 512 * 512));
    }

    #[test]
    fn dims_follow_the_voxels_or_the_cap() {
        let src =
            HomogeneousBox::new(Aabb::new(DVec3::ZERO, DVec3::new(2.0, 1.0, 1.0)), 1.0).unwrap();
        let bbox = Aabb::new(DVec3::ZERO, DVec3::new(2.0, 1.0, 1.0));
        assert_eq!(
            sparse_dims(&src, &bbox, SparseDims::Source).unwrap(),
            [256, 128, 128]
        );
        assert_eq!(
            sparse_dims(&src, &bbox, SparseDims::Max(64)).unwrap(),
            [64, 32, 32]
        );
        assert_eq!(
            sparse_dims(&src, &bbox, SparseDims::Exact([3, 4, 5])).unwrap(),
            [3, 4, 5]
        );
        assert!(sparse_dims(&src, &bbox, SparseDims::Exact([0, 4, 5])).is_err());
    }
}
