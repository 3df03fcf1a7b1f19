//! A prefiltered level ("mip") of a voxel grid, for marching coarser than the voxels.
//!
//! Measured, not used by bakes: `pinbake bench` reports its integration error beside the
//! bake's (`integration_error_prefiltered`). It makes a bake several times cheaper but its
//! optical depths are further from the exact ones than point samples of the grid itself, on
//! smooth noise and on the smoke alike (docs/performance.md, "The prefiltered level"): the
//! box filter blurs across the ray, and that error does not average out along it.
//!
//! The baker's midpoint rule takes one sample per `step` of world length. On a grid whose
//! voxels are several times smaller than that, point samples of the trilinear field skip most
//! voxels: the sum aliases (it is inaccurate) and every sample touches cold memory far from the
//! last (it is slow). A [`Mip`] is the grid box-filtered to about one voxel per step: each
//! coarse voxel is the volume-weighted mean of the fine voxels it covers (fractional overlaps
//! weigh by their overlap, so any ratio of sizes works and the mip covers exactly the fine
//! grid's box). A midpoint sample of the mip then stands for the voxels around it, and the
//! whole level is small enough to stay in cache.
//!
//! The filter is separable and runs per output z-layer, each layer a fixed sequence of f64
//! sums, so the values do not depend on the thread count. The level is stored with one extra
//! voxel on the high side of every axis (a copy of the edge) so that [`Mip::march_sum`]'s
//! trilinear lookups need no edge tests.

use glam::DVec3;
use rayon::prelude::*;

/// The coarse level was not allocated (its size in bytes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("cannot allocate {bytes} bytes for the prefiltered density")]
pub struct MipAllocError {
    pub bytes: u64,
}

/// A dense, box-filtered copy of a voxel grid, sampled trilinearly between voxel centres with
/// clamp-to-edge (the convention of [`super::DenseGrid`]).
#[derive(Clone, Debug)]
pub struct Mip {
    /// Voxels per axis (without the padding).
    dims: [u32; 3],
    /// `(dims + 1)` per axis, x fastest.
    data: Vec<f32>,
    stride_y: usize,
    stride_z: usize,
    /// World position of the low corner of voxel (0, 0, 0) and the world size of a voxel.
    origin: DVec3,
    spacing: DVec3,
    inv_spacing: DVec3,
    /// `dims - 1`: the clamp of a continuous index.
    max_index: [f32; 3],
}

/// How fine cells of one axis fall into coarse cells: for each fine cell, up to two
/// (coarse cell, weight) pairs, the weight being the overlap over the coarse cell's width.
struct AxisWeights {
    coarse: usize,
    pairs: Vec<[(usize, f64); 2]>,
}

impl AxisWeights {
    fn new(fine: usize, coarse: usize) -> Self {
        // Coarse cell I covers fine coordinates [I * r, (I + 1) * r), r = fine / coarse >= 1,
        // so a fine cell [j, j + 1) meets at most two coarse cells.
        let r = fine as f64 / coarse as f64;
        let pairs = (0..fine)
            .map(|j| {
                let (a, b) = (j as f64, j as f64 + 1.0);
                let first = ((a / r).floor() as usize).min(coarse - 1);
                let edge = (first + 1) as f64 * r;
                if first + 1 < coarse && edge < b {
                    [(first, (edge - a) / r), (first + 1, (b - edge) / r)]
                } else {
                    [(first, 1.0 / r), (first, 0.0)]
                }
            })
            .collect();
        Self { coarse, pairs }
    }
}

impl Mip {
    /// Box-filters a fine grid of `fine_dims` voxels covering the world box `[origin,
    /// origin + extent]` to `ceil(extent / step)` voxels per axis (never more than the fine
    /// voxels). `fill_row(y, z, row)` writes the fine voxels `(0..nx, y, z)` into `row`.
    ///
    /// Returns `Ok(None)` when no axis gets coarser: the grid already matches the step and
    /// should be sampled as it is.
    pub fn build(
        fine_dims: [u32; 3],
        origin: DVec3,
        extent: DVec3,
        step: f64,
        fill_row: &(dyn Fn(usize, usize, &mut [f32]) + Sync),
    ) -> Result<Option<Mip>, MipAllocError> {
        let fine = fine_dims.map(|d| d.max(1) as usize);
        let coarse = Self::coarse_dims(fine_dims, extent, step);
        if coarse == fine {
            return Ok(None);
        }
        let weights = [0, 1, 2].map(|a| AxisWeights::new(fine[a], coarse[a]));
        let (px, py, pz) = (coarse[0] + 1, coarse[1] + 1, coarse[2] + 1);
        let layer = px * py;
        let len = layer * pz;
        let mut data = Vec::new();
        data.try_reserve_exact(len).map_err(|_| MipAllocError {
            bytes: len as u64 * 4,
        })?;
        data.resize(len, 0.0f32);

        // Fine z layers per coarse layer, in fine order, with their weights.
        let mut z_sources: Vec<Vec<(usize, f64)>> = vec![Vec::new(); coarse[2]];
        for (z, pairs) in weights[2].pairs.iter().enumerate() {
            for &(cz, w) in pairs {
                if w > 0.0 {
                    z_sources[cz].push((z, w));
                }
            }
        }
        let (wx, wy) = (&weights[0], &weights[1]);
        data[..layer * coarse[2]]
            .par_chunks_mut(layer)
            .zip(z_sources.par_iter())
            .for_each_init(
                || {
                    (
                        vec![0.0f32; fine[0]],
                        vec![0.0f64; wx.coarse],
                        vec![0.0f64; wx.coarse * wy.coarse],
                    )
                },
                |(row, rx, acc), (out, zs)| {
                    acc.fill(0.0);
                    for &(z, wz) in zs {
                        for (y, ypairs) in wy.pairs.iter().enumerate() {
                            fill_row(y, z, row);
                            rx.fill(0.0);
                            for (v, xpairs) in row.iter().zip(&wx.pairs) {
                                let v = f64::from(*v);
                                rx[xpairs[0].0] += xpairs[0].1 * v;
                                rx[xpairs[1].0] += xpairs[1].1 * v;
                            }
                            for &(cy, w) in ypairs {
                                if w > 0.0 {
                                    let w = w * wz;
                                    let dst = &mut acc[cy * wx.coarse..][..wx.coarse];
                                    for (d, s) in dst.iter_mut().zip(rx.iter()) {
                                        *d += w * s;
                                    }
                                }
                            }
                        }
                    }
                    for cy in 0..wy.coarse {
                        let dst = &mut out[cy * px..][..px];
                        for (d, s) in dst.iter_mut().zip(&acc[cy * wx.coarse..][..wx.coarse]) {
                            // Means of non-negative values; the max keeps rounding from
                            // producing -0.0.
                            *d = (*s as f32).max(0.0);
                        }
                        dst[wx.coarse] = dst[wx.coarse - 1];
                    }
                    out.copy_within((wy.coarse - 1) * px..wy.coarse * px, wy.coarse * px);
                },
            );
        data.copy_within(
            layer * (coarse[2] - 1)..layer * coarse[2],
            layer * coarse[2],
        );

        let spacing = DVec3::new(
            extent.x / coarse[0] as f64,
            extent.y / coarse[1] as f64,
            extent.z / coarse[2] as f64,
        );
        Ok(Some(Mip {
            dims: coarse.map(|c| c as u32),
            data,
            stride_y: px,
            stride_z: layer,
            origin,
            spacing,
            inv_spacing: spacing.recip(),
            max_index: coarse.map(|c| (c - 1) as f32),
        }))
    }

    /// Voxels per axis of the level [`Mip::build`] makes: `ceil(extent / step)`, at least 1
    /// and never more than the fine voxels.
    pub fn coarse_dims(fine_dims: [u32; 3], extent: DVec3, step: f64) -> [usize; 3] {
        [0, 1, 2].map(|a| {
            let fine = fine_dims[a].max(1) as usize;
            let want = (extent[a] / step).ceil();
            if want.is_finite() && want >= 1.0 {
                (want.min(fine as f64) as usize).max(1)
            } else {
                fine
            }
        })
    }

    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }
    pub fn spacing(&self) -> DVec3 {
        self.spacing
    }
    /// Bytes held by the level.
    pub fn bytes(&self) -> u64 {
        self.data.len() as u64 * 4
    }

    /// Continuous index (voxel centres at integers) of a world point, in f64.
    #[inline]
    pub fn index_of(&self, p: DVec3) -> DVec3 {
        (p - self.origin) * self.inv_spacing - 0.5
    }

    /// World direction to index direction.
    #[inline]
    pub fn index_dir(&self, d: DVec3) -> DVec3 {
        d * self.inv_spacing
    }

    /// Trilinear value at a world point (clamp-to-edge outside the box): the reference the
    /// marching path is tested against.
    pub fn value_at(&self, p: DVec3) -> f32 {
        let u = self.index_of(p);
        self.sample([u.x as f32, u.y as f32, u.z as f32])
    }

    #[inline(always)]
    fn sample(&self, u: [f32; 3]) -> f32 {
        // `max` first so that NaN becomes 0 (f32::max returns the non-NaN operand).
        let cx = u[0].max(0.0).min(self.max_index[0]);
        let cy = u[1].max(0.0).min(self.max_index[1]);
        let cz = u[2].max(0.0).min(self.max_index[2]);
        let (ix, iy, iz) = (cx as usize, cy as usize, cz as usize);
        let (fx, fy, fz) = (cx - ix as f32, cy - iy as f32, cz - iz as f32);
        let base = ix + iy * self.stride_y + iz * self.stride_z;
        // The padding makes `+ 1` on every axis valid for any clamped index; one slice bounds
        // check covers all eight loads.
        let (sy, sz) = (self.stride_y, self.stride_z);
        let c = &self.data[base..base + sz + sy + 2];
        let c00 = c[0] + (c[1] - c[0]) * fx;
        let c10 = c[sy] + (c[sy + 1] - c[sy]) * fx;
        let c01 = c[sz] + (c[sz + 1] - c[sz]) * fx;
        let c11 = c[sz + sy] + (c[sz + sy + 1] - c[sz + sy]) * fx;
        let c0 = c00 + (c10 - c00) * fy;
        let c1 = c01 + (c11 - c01) * fy;
        (c0 + (c1 - c0) * fz).max(0.0)
    }

    /// Sum of the trilinear values at the continuous indices `u0 + j * du`, `j < n`.
    ///
    /// The index advances in f32 from a base the caller computes in f64 (one transform per
    /// run, none per sample); `j * du` rather than a running sum keeps the error of sample
    /// `j` at a few f32 ulps of the index instead of growing with `j`. Values are summed in
    /// f64 in sample order, so the result is deterministic.
    #[inline]
    pub fn march_sum(&self, u0: [f32; 3], du: [f32; 3], n: usize) -> f64 {
        const LANES: usize = 8;
        let mut sum = 0.0f64;
        let mut j = 0usize;
        let mut vals = [0.0f32; LANES];
        while j < n {
            let m = (n - j).min(LANES);
            for (l, v) in vals.iter_mut().enumerate().take(m) {
                let t = (j + l) as f32;
                *v = self.sample([u0[0] + t * du[0], u0[1] + t * du[1], u0[2] + t * du[2]]);
            }
            for v in &vals[..m] {
                sum += f64::from(*v);
            }
            j += m;
        }
        sum
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dense_fill(dims: [u32; 3], data: &[f32]) -> impl Fn(usize, usize, &mut [f32]) + Sync + '_ {
        let (nx, ny) = (dims[0] as usize, dims[1] as usize);
        move |y, z, row: &mut [f32]| row.copy_from_slice(&data[(y + ny * z) * nx..][..nx])
    }

    #[test]
    fn axis_weights_partition_every_fine_cell() {
        for (fine, coarse) in [(10, 3), (512, 98), (7, 7), (5, 1), (100, 99)] {
            let w = AxisWeights::new(fine, coarse);
            let mut per_coarse = vec![0.0f64; coarse];
            for p in &w.pairs {
                // Each fine cell is split in full (weights times the coarse width sum to 1).
                let r = fine as f64 / coarse as f64;
                assert!(
                    ((p[0].1 + p[1].1) * r - 1.0).abs() < 1e-12,
                    "{fine}/{coarse}"
                );
                per_coarse[p[0].0] += p[0].1;
                per_coarse[p[1].0] += p[1].1;
            }
            // And each coarse cell's weights sum to 1 (a mean).
            for s in per_coarse {
                assert!((s - 1.0).abs() < 1e-9, "{fine}/{coarse}: {s}");
            }
        }
    }

    #[test]
    fn mip_is_the_volume_weighted_mean() {
        // 6x4x3 fine voxels of value x + 10 y + 100 z over a box 6x4x3 world units, to 2x2x1
        // (step 3, 2, 3): coarse voxel (i, j, 0) is the mean of fine x in [3i, 3i + 3), y in
        // [2j, 2j + 2), all z.
        let dims = [6u32, 4, 3];
        let data: Vec<f32> = (0..72)
            .map(|i| (i % 6 + 10 * ((i / 6) % 4) + 100 * (i / 24)) as f32)
            .collect();
        let fill = dense_fill(dims, &data);
        let mip = Mip::build(dims, DVec3::ZERO, DVec3::new(6.0, 4.0, 3.0), 3.0, &fill)
            .unwrap()
            .unwrap();
        assert_eq!(mip.dims(), [2, 2, 1]);
        for (i, j) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let want = (3 * i) as f32 + 1.0 + 10.0 * ((2 * j) as f32 + 0.5) + 100.0;
            let centre = DVec3::new(3.0 * i as f64 + 1.5, 2.0 * j as f64 + 1.0, 1.5);
            assert!((mip.value_at(centre) - want).abs() < 1e-4, "{i} {j}");
        }
        // Clamp-to-edge beyond the outer centres, and a mean in between.
        assert_eq!(
            mip.value_at(DVec3::new(-5.0, 1.0, 1.5)),
            mip.value_at(DVec3::new(1.5, 1.0, 1.5))
        );
        let mid = mip.value_at(DVec3::new(3.0, 1.0, 1.5));
        assert!((mid - (106.0 + 109.0) / 2.0).abs() < 1e-4, "{mid}");
        // A step no coarser than the voxels builds nothing.
        assert!(
            Mip::build(dims, DVec3::ZERO, DVec3::new(6.0, 4.0, 3.0), 1.0, &fill)
                .unwrap()
                .is_none()
        );
    }

    #[test]
    fn mean_is_preserved_for_fractional_ratios() {
        // 17^3 fine voxels to ceil(17 / 5) = 4 per axis: the total mass (mean times volume) is
        // kept exactly up to rounding, whatever the partial overlaps.
        let dims = [17u32; 3];
        let data: Vec<f32> = (0..17 * 17 * 17)
            .map(|i| ((i * 7919) % 101) as f32 / 10.0)
            .collect();
        let fill = dense_fill(dims, &data);
        let mip = Mip::build(dims, DVec3::ZERO, DVec3::splat(17.0), 5.0, &fill)
            .unwrap()
            .unwrap();
        assert_eq!(mip.dims(), [4; 3]);
        let fine_mean = data.iter().map(|v| f64::from(*v)).sum::<f64>() / data.len() as f64;
        let mut coarse_sum = 0.0;
        for z in 0..4 {
            for y in 0..4 {
                for x in 0..4 {
                    let c = (DVec3::new(x as f64, y as f64, z as f64) + 0.5) * mip.spacing();
                    coarse_sum += f64::from(mip.value_at(c));
                }
            }
        }
        assert!((coarse_sum / 64.0 - fine_mean).abs() < 1e-5 * fine_mean);
    }

    #[test]
    fn march_sum_matches_point_samples() {
        let dims = [20u32, 9, 13];
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        let data: Vec<f32> = (0..n).map(|i| ((i * 31) % 17) as f32).collect();
        let fill = dense_fill(dims, &data);
        let mip = Mip::build(
            dims,
            DVec3::new(-1.0, 2.0, 0.5),
            DVec3::new(2.0, 0.9, 1.3),
            0.25,
            &fill,
        )
        .unwrap()
        .unwrap();
        let p = DVec3::new(-0.9, 2.1, 0.6);
        let d = DVec3::new(0.013, 0.004, 0.009);
        let (u0, du) = (mip.index_of(p), mip.index_dir(d));
        let f = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32];
        let got = mip.march_sum(f(u0), f(du), 150);
        let want: f64 = (0..150)
            .map(|j| f64::from(mip.value_at(p + d * j as f64)))
            .sum();
        assert!((got - want).abs() < 1e-4 * want.max(1.0), "{got} vs {want}");
        // NaN and far-away indices clamp instead of reading out of bounds.
        let _ = mip.march_sum([f32::NAN, 1e30, -1e30], [1e20, f32::NAN, 0.0], 9);
    }
}
