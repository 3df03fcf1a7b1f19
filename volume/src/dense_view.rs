//! A borrowed view of a dense f32 voxel array and its world-to-index map: how the renderer's
//! trackers step through a dense grid ([`super::Density::dense_view`]) in index space,
//! one transform per majorant brick instead of one per lookup. [`super::DenseGrid`] owns such
//! an array; the renderer's voxel grids and a sparse source's dense copy offer the same view.

/// A dense f32 voxel array (`x` fastest) behind an axis-aligned world-to-index map:
/// continuous index `u = p * scale - offset` per axis, voxel centres at integers, trilinear
/// between centres, the point clamped to `[0, dims - 1]` (the edge voxels' values beyond the
/// outer centres). That is [`super::DenseGrid`]'s convention and the renderer's voxel grids'; a
/// VDB's dense copy has a zero border, so clamping there reads zero, as the tree does.
#[derive(Clone, Copy, Debug)]
pub struct DenseView<'a> {
    data: &'a [f32],
    map: DenseMap,
}

/// The shape and world-to-index map of a [`DenseView`], computed once (fields keep it next
/// to their array, so a tracker's query takes its view for the price of two copies).
#[derive(Clone, Copy, Debug)]
pub struct DenseMap {
    /// `dims - 1` per axis (f32): the clamp of the point.
    top: [f32; 3],
    /// `max(dims - 2, 0)` per axis (f32): the clamp of the cell's lower corner, so that its
    /// `+ 1` neighbour exists (the fraction then reaches 1 at the last centre).
    hi: [f32; 3],
    /// Element strides of a `+ 1` step per axis; 0 on a one-voxel axis.
    step: [usize; 3],
    /// Element strides of the y and z indices.
    stride: [usize; 2],
    scale: [f64; 3],
    offset: [f64; 3],
}

impl DenseMap {
    /// The grid of `dims` voxels of `spacing` whose box starts at `origin` (voxel `i`'s
    /// centre at `origin + (i + 0.5) spacing`), of `len` values. `None` when `len` is not
    /// `dims[0] * dims[1] * dims[2] >= 1` or the map is not finite and positive.
    pub fn new(len: usize, dims: [u32; 3], origin: [f64; 3], spacing: [f64; 3]) -> Option<Self> {
        let d = dims.map(|v| v as usize);
        let n = d[0].checked_mul(d[1])?.checked_mul(d[2])?;
        if n == 0 || n != len {
            return None;
        }
        if !(0..3).all(|a| origin[a].is_finite() && spacing[a].is_finite() && spacing[a] > 0.0) {
            return None;
        }
        let scale = spacing.map(|s| 1.0 / s);
        let offset = [0, 1, 2].map(|a| origin[a] * scale[a] + 0.5);
        if !(0..3).all(|a| scale[a].is_finite() && offset[a].is_finite()) {
            return None;
        }
        let stride = [d[0], d[0] * d[1]];
        Some(DenseMap {
            top: d.map(|v| (v - 1) as f32),
            hi: d.map(|v| v.saturating_sub(2) as f32),
            step: [
                usize::from(d[0] > 1),
                if d[1] > 1 { stride[0] } else { 0 },
                if d[2] > 1 { stride[1] } else { 0 },
            ],
            stride,
            scale,
            offset,
        })
    }
}

impl<'a> DenseView<'a> {
    /// `data` seen through `map`; `None` when `map` was made for another length.
    #[inline]
    pub fn new(data: &'a [f32], map: DenseMap) -> Option<Self> {
        let n = (map.top[0] as usize + 1) * (map.top[1] as usize + 1) * (map.top[2] as usize + 1);
        (n == data.len()).then_some(DenseView { data, map })
    }

    /// Continuous index of the world point `p` (f64).
    #[inline(always)]
    pub fn index(&self, p: [f64; 3]) -> [f64; 3] {
        let m = &self.map;
        [0, 1, 2].map(|a| p[a] * m.scale[a] - m.offset[a])
    }

    /// Index-space length of the world vector `d` (f64).
    #[inline(always)]
    pub fn index_dir(&self, d: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|a| d[a] * self.map.scale[a])
    }

    /// The element index of the lower corner of `u`'s cell and the fractions, as [`Self::at`]
    /// reads them.
    #[inline(always)]
    fn cell(&self, u: [f32; 3]) -> (usize, [f32; 3]) {
        let m = &self.map;
        // `max` first so that NaN becomes 0 (f32::max returns the non-NaN operand).
        let c = [0, 1, 2].map(|a| u[a].max(0.0).min(m.top[a]));
        let i = [0, 1, 2].map(|a| c[a].min(m.hi[a]) as usize);
        let f = [0, 1, 2].map(|a| c[a] - i[a] as f32);
        (i[0] + i[1] * m.stride[0] + i[2] * m.stride[1], f)
    }

    /// The minimum of [`Self::at`] over the world box `[lo, hi]`: the trilinear value at any
    /// point is a convex combination of the (up to 8) voxels around the point, so the least
    /// of the voxels whose centre cells touch the box is exact (as the
    /// grids' `max_extinction_in` is for the maximum). Only the voxels of the box's own
    /// cells would miss the neighbours that the interpolation near its faces reads, and
    /// could exceed the field there. Negative and NaN values count as 0, as [`Self::at`]
    /// reads them.
    pub fn min_over(&self, lo: [f64; 3], hi: [f64; 3]) -> f32 {
        let m = &self.map;
        let (u0, u1) = (self.index(lo), self.index(hi));
        let mut r0 = [0usize; 3];
        let mut r1 = [0usize; 3];
        for a in 0..3 {
            let top = m.top[a] as f64;
            // `max` before `min`: a NaN bound reads as index 0, as in `cell`.
            let (a0, a1) = (u0[a].max(0.0).min(top), u1[a].max(0.0).min(top));
            r0[a] = a0 as usize;
            r1[a] = (a1 as usize + 1).min(m.top[a] as usize);
        }
        let mut least = f32::INFINITY;
        for z in r0[2]..=r1[2] {
            for y in r0[1]..=r1[1] {
                let row = y * m.stride[0] + z * m.stride[1];
                for &v in &self.data[row + r0[0]..=row + r1[0]] {
                    least = least.min(if v > 0.0 { v } else { 0.0 });
                }
            }
        }
        least
    }

    /// The trilinear value at continuous index `u`, clamped to the grid (NaN reads as index
    /// 0). No libm `floor`: after the clamp the index is non-negative, so `as usize`
    /// truncates to the floor.
    #[inline(always)]
    pub fn at(&self, u: [f32; 3]) -> f32 {
        let (b, f) = self.cell(u);
        let [sx, sy, sz] = self.map.step;
        // One slice bounds check covers the eight loads.
        let v = &self.data[b..=b + sx + sy + sz];
        let c00 = v[0] + (v[sx] - v[0]) * f[0];
        let c10 = v[sy] + (v[sy + sx] - v[sy]) * f[0];
        let c01 = v[sz] + (v[sz + sx] - v[sz]) * f[0];
        let c11 = v[sz + sy] + (v[sz + sy + sx] - v[sz + sy]) * f[0];
        let c0 = c00 + (c10 - c00) * f[1];
        let c1 = c01 + (c11 - c01) * f[1];
        (c0 + (c1 - c0) * f[2]).max(0.0)
    }
}
