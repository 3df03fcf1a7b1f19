//! The embedded sparse density (format 1.1 section 5.6a): the source resampled at voxel
//! centres over the grid box, stored only in bricks where it is non-zero.
//!
//! Built brick by brick from the source's own sparse structure: a brick whose box the source
//! bounds by zero ([`DensitySource::max_extinction_in`], a VDB's leaf and tile table) is never
//! sampled, and no dense grid of the box is ever allocated, so the section's memory is the
//! stored bricks' plus one index entry per brick.

use glam::DVec3;
use half::f16;
use pin_format::layout::{DENSITY_F16, EMPTY_BRICK, SparseDensityHeader};
use pin_format::{OwnedSparseDensity, OwnedSparseValues, brick_dims};
use rayon::prelude::*;

use crate::bake::BakeError;
use crate::source::{Aabb, DensitySource};

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

/// The bytes [`bake_sparse_density`] holds at its peak for `source` over `bbox` with `dims`
/// voxels: the index and every brick the source's bound does not rule out (counted with the
/// same test the fill makes, which fills them all before it drops those that are all zero).
/// For the bake's memory estimate.
pub fn sparse_density_bytes(source: &dyn DensitySource, bbox: &Aabb, dims: [u32; 3]) -> u64 {
    let c = Candidates::new(source, bbox, dims);
    let slots: u64 = c.bdims.iter().map(|&d| u64::from(d)).product();
    let brick = u64::from(SPARSE_BRICK).pow(3) * 2;
    slots
        .saturating_mul(4)
        .saturating_add(c.count().saturating_mul(brick))
}

/// The sparse f16 density of `source` over `bbox` with `dims` voxels.
pub fn bake_sparse_density(
    source: &dyn DensitySource,
    bbox: &Aabb,
    dims: [u32; 3],
) -> Result<OwnedSparseDensity, BakeError> {
    let (index, values) = fill_bricks(source, &Candidates::new(source, bbox, dims), |v| {
        let h = f16::from_f32(v);
        h.is_finite().then_some(h)
    })?;
    Ok(OwnedSparseDensity {
        header: SparseDensityHeader {
            dims,
            encoding: DENSITY_F16,
            brick: SPARSE_BRICK,
            brick_count: (values.len() / (SPARSE_BRICK as usize).pow(3)) as u32,
            reserved: [0; 2],
        },
        index,
        values: OwnedSparseValues::F16(values),
    })
}

/// Bricks of `SPARSE_BRICK` over `bbox` with `dims` voxels whose box the source does not
/// bound by zero, in f32 (the source's own values at the centres): the brick index and the
/// stored voxels, or `None` when they would take more than `max_bytes` (counted from the
/// source's bounds before anything is sampled). For renderers that track a sparse source
/// through an array instead of its tree.
pub fn sparse_f32_bricks(
    source: &dyn DensitySource,
    bbox: &Aabb,
    dims: [u32; 3],
    max_bytes: u64,
) -> Option<(Vec<u32>, Vec<f32>)> {
    let candidates = Candidates::new(source, bbox, dims);
    let bytes = candidates
        .count()
        .saturating_mul(u64::from(SPARSE_BRICK).pow(3) * 4);
    if bytes > max_bytes {
        return None;
    }
    fill_bricks(source, &candidates, |v| v.is_finite().then_some(v)).ok()
}

/// Voxel centres and brick boxes of `dims` voxels over `bbox`.
struct Geometry {
    min: DVec3,
    spacing: DVec3,
    dims: [u32; 3],
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
        }
    }

    fn centre(&self, v: [u32; 3]) -> DVec3 {
        self.min + (DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64) + 0.5) * self.spacing
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
        let geo = Geometry::new(bbox, dims);
        let rows = (0..bdims[1] as usize * bdims[2] as usize)
            .into_par_iter()
            .map(|row| {
                let (by, bz) = Self::row_yz(bdims, row);
                (0..bdims[0])
                    .filter(|&bx| source.max_extinction_in(geo.region([bx, by, bz]).0) > 0.0)
                    .collect()
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
}

/// The index and the stored bricks (canonical slot order), each voxel `encode`d from the
/// source's value at its centre; `None` from `encode` is a value out of the encoding's range.
///
/// Memory: the bricks the source's bound does not rule out (the candidates) are filled in
/// place in one array, then the all-zero ones are squeezed out. So the bricks are held once,
/// not once per brick allocation and again in the array (small allocations are not given
/// back to the system when freed, which put a bake's peak at twice the bricks).
fn fill_bricks<T: Copy + Default + PartialEq + Send + Sync>(
    source: &dyn DensitySource,
    candidates: &Candidates,
    encode: impl Fn(f32) -> Option<T> + Sync,
) -> Result<(Vec<u32>, Vec<T>), BakeError> {
    let b = SPARSE_BRICK;
    let Candidates {
        geo,
        bdims,
        rows: candidates,
    } = candidates;
    let bdims = *bdims;
    let bv = (b as usize).pow(3);
    let zero = T::default();
    let total: usize = candidates.iter().map(Vec::len).sum();
    let mut values = crate::bake::try_filled("the sparse density bricks", total * bv, zero)?;
    // Each row's candidates get consecutive slots; rows fill their own slices in parallel
    // and say which of their bricks hold a non-zero value.
    let mut slices = Vec::with_capacity(candidates.len());
    let mut rest = values.as_mut_slice();
    for c in candidates {
        let (head, tail) = rest.split_at_mut(c.len() * bv);
        slices.push(head);
        rest = tail;
    }
    let filled: Vec<Result<Vec<bool>, BakeError>> = slices
        .into_par_iter()
        .zip(candidates.par_iter())
        .enumerate()
        .map(|(row, (slice, xs))| {
            let (by, bz) = Candidates::row_yz(bdims, row);
            xs.iter()
                .zip(slice.chunks_exact_mut(bv))
                .map(|(&bx, brick)| {
                    let (_, lo, hi) = geo.region([bx, by, bz]);
                    let mut any = false;
                    for z in lo[2]..hi[2] {
                        for y in lo[1]..hi[1] {
                            for x in lo[0]..hi[0] {
                                let p = geo.centre([x, y, z]);
                                let v = source.extinction(p);
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
                })
                .collect()
        })
        .collect();
    let bricks = bdims.iter().map(|&d| d as usize).product::<usize>();
    let mut index = crate::bake::try_filled("the sparse density index", bricks, EMPTY_BRICK)?;
    let (mut slot, mut candidate) = (0usize, 0usize);
    for (row, (r, xs)) in filled.into_iter().zip(candidates).enumerate() {
        // The first failing row in brick order, so the message does not depend on scheduling.
        for (keep, &bx) in r?.into_iter().zip(xs) {
            if keep {
                index[row * bdims[0] as usize + bx as usize] = slot as u32;
                values.copy_within(candidate * bv..(candidate + 1) * bv, slot * bv);
                slot += 1;
            }
            candidate += 1;
        }
    }
    values.truncate(slot * bv);
    values.shrink_to_fit();
    Ok((index, values))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::source::procedural::HomogeneousBox;

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
