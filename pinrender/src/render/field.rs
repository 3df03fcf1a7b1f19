//! Density fields: what the reference estimators march and track.

use glam::Vec3;

/// An extinction field over a world-space box.
///
/// Positions are `f32` ([`Vec3`]): the renderer's rays, the pin runtime's queries and the WGSL
/// path all work in f32, so the reference sees exactly the sample points the others would, and
/// the hot loops convert nothing. f32 resolves positions to about 1e-7 of their magnitude,
/// far below a voxel for volumes placed near the origin (keep world coordinates within a
/// few thousand voxel sizes of it). Boxes and the DDA use f64, where robustness matters.
///
/// Contract: `extinction` is finite and `>= 0` inside the box and 0 outside it (estimators
/// never look outside; they also treat NaN and negative values as 0 and `+inf` as opaque).
pub trait DensityField: Send + Sync {
    /// The world-space box `(min, max)` that holds all of the medium.
    fn bounds(&self) -> ([f64; 3], [f64; 3]);
    /// Extinction coefficient (per world unit) at `p`.
    fn extinction(&self, p: Vec3) -> f32;
    /// An exact upper bound of the extinction over the closed box `[lo, hi]`, if the field
    /// can give one cheaply. [`crate::render::MajorantGrid::from_field`] uses it instead of
    /// conservative point sampling.
    fn max_extinction(&self, lo: [f64; 3], hi: [f64; 3]) -> Option<f32> {
        let _ = (lo, hi);
        None
    }
    /// An exact lower bound of the extinction over the closed box `[lo, hi]`, if the field
    /// can give one cheaply (residual ratio tracking's control; see
    /// [`crate::render::ResidualRatioTracking`]). The default: 0 where the box reaches
    /// outside [`Self::bounds`] (the extinction is 0 there), else through the
    /// [`Self::dense_view`] if there is one ([`DenseView::min_over`]), else `None`.
    fn min_extinction(&self, lo: [f64; 3], hi: [f64; 3]) -> Option<f32> {
        let (flo, fhi) = self.bounds();
        if !(0..3).all(|a| lo[a] >= flo[a] && hi[a] <= fhi[a]) {
            return Some(0.0);
        }
        self.dense_view().map(|v| v.min_over(lo, hi))
    }
    /// The field as a dense voxel array, when it is one: inside [`Self::bounds`],
    /// `extinction(p)` must equal [`DenseView::at`] of [`DenseView::index`]`(p)` up to the
    /// rounding of the index to f32. The trackers then step through the array in f32 index
    /// space (one world-to-index transform per majorant brick, not per lookup) instead of
    /// calling `extinction` per tentative collision. `None` (the default): no such array.
    fn dense_view(&self) -> Option<DenseView<'_>> {
        None
    }
}

/// A dense f32 voxel array (`x` fastest) behind an axis-aligned world-to-index map:
/// continuous index `u = p * scale - offset` per axis, voxel centres at integers, trilinear
/// between centres, the point clamped to `[0, dims - 1]` (the edge voxels' values beyond the
/// outer centres). That is [`VoxelGrid`]'s convention and pinbake's `DenseGrid`'s; a
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
    /// of the voxels whose centre cells touch the box is exact (as
    /// [`VoxelGrid::max_extinction`] is for the maximum). Only the voxels of the box's own
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

#[inline]
fn inside(p: Vec3, lo: &[f64; 3], hi: &[f64; 3]) -> bool {
    let q = [p.x as f64, p.y as f64, p.z as f64];
    (0..3).all(|a| q[a] >= lo[a] && q[a] <= hi[a])
}

#[inline]
fn overlaps(lo: &[f64; 3], hi: &[f64; 3], blo: &[f64; 3], bhi: &[f64; 3]) -> bool {
    (0..3).all(|a| lo[a] <= bhi[a] && hi[a] >= blo[a])
}

/// A box of constant extinction (closed box; 0 outside).
#[derive(Clone, Debug)]
pub struct HomogeneousBox {
    pub min: [f64; 3],
    pub max: [f64; 3],
    pub sigma_t: f32,
}

impl DensityField for HomogeneousBox {
    fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        (self.min, self.max)
    }
    #[inline]
    fn extinction(&self, p: Vec3) -> f32 {
        if inside(p, &self.min, &self.max) {
            self.sigma_t
        } else {
            0.0
        }
    }
    fn max_extinction(&self, lo: [f64; 3], hi: [f64; 3]) -> Option<f32> {
        Some(if overlaps(&lo, &hi, &self.min, &self.max) {
            self.sigma_t.max(0.0)
        } else {
            0.0
        })
    }
    /// `sigma_t` where `[lo, hi]` lies inside the box, 0 where it reaches outside.
    fn min_extinction(&self, lo: [f64; 3], hi: [f64; 3]) -> Option<f32> {
        let inside = (0..3).all(|a| lo[a] >= self.min[a] && hi[a] <= self.max[a]);
        Some(if inside { self.sigma_t.max(0.0) } else { 0.0 })
    }
}

/// A field given by a closure over a box (0 outside the box). For tests and procedural media.
pub struct FnField<F> {
    pub min: [f64; 3],
    pub max: [f64; 3],
    pub f: F,
}

impl<F: Fn(Vec3) -> f32 + Send + Sync> DensityField for FnField<F> {
    fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        (self.min, self.max)
    }
    #[inline]
    fn extinction(&self, p: Vec3) -> f32 {
        if inside(p, &self.min, &self.max) {
            (self.f)(p)
        } else {
            0.0
        }
    }
}

/// A dense voxel grid in the project's shared convention (docs/background.md section 2, Mitsuba's grid
/// volume): dims `N`, spacing `s`, origin `o` occupy `[o, o + N s]`, voxel centres at
/// `o + (i + 0.5) s`, trilinear between centres, the edge voxel's value in the outer half voxel,
/// 0 outside. Values are `x` fastest, then `y`, then `z`.
#[derive(Clone, Debug)]
pub struct VoxelGrid {
    dims: [usize; 3],
    origin: [f64; 3],
    spacing: [f64; 3],
    values: Vec<f32>,
    max: [f64; 3],
    /// `values` as the trackers read them ([`DensityField::dense_view`]); boxed, so that
    /// the grid stays small where it is moved around by value.
    map: Option<Box<DenseMap>>,
}

impl VoxelGrid {
    /// Validates dims (all >= 1, product = `values.len()`), finite origin and positive finite
    /// spacing. Values are cleaned once here, as the estimators read extinction: NaN and
    /// negatives become 0 and `+inf` (opaque) becomes `f32::MAX`, so that trilinear
    /// interpolation never forms `inf - inf` (a NaN that would read as empty space). The GPU
    /// copy (`pinrender::gpu_render::GpuDensity`) cleans the same way.
    pub fn new(
        dims: [u32; 3],
        origin: [f64; 3],
        spacing: [f64; 3],
        values: Vec<f32>,
    ) -> Result<Self, super::RenderError> {
        let invalid = |why: String| super::RenderError::Invalid {
            what: "voxel grid",
            why,
        };
        let d = dims.map(|v| v as usize);
        let n = d[0]
            .checked_mul(d[1])
            .and_then(|v| v.checked_mul(d[2]))
            .ok_or_else(|| invalid(format!("dims {dims:?} overflow")))?;
        if n == 0 || n != values.len() {
            return Err(invalid(format!(
                "dims {dims:?} need {n} values (>= 1), got {}",
                values.len()
            )));
        }
        if !origin.iter().all(|v| v.is_finite())
            || !spacing.iter().all(|v| v.is_finite() && *v > 0.0)
        {
            return Err(invalid(format!("origin {origin:?} / spacing {spacing:?}")));
        }
        let max = [0, 1, 2].map(|a| origin[a] + d[a] as f64 * spacing[a]);
        let values: Vec<f32> = values
            .into_iter()
            .map(|v| if v > 0.0 { v.min(f32::MAX) } else { 0.0 })
            .collect();
        Ok(VoxelGrid {
            map: DenseMap::new(values.len(), dims, origin, spacing).map(Box::new),
            dims: d,
            origin,
            spacing,
            values,
            max,
        })
    }

    /// Dims, origin, spacing and the cleaned values (`x` fastest).
    pub fn parts(&self) -> ([u32; 3], [f64; 3], [f64; 3], &[f32]) {
        (
            self.dims.map(|d| d as u32),
            self.origin,
            self.spacing,
            &self.values,
        )
    }

    #[inline]
    fn at(&self, x: usize, y: usize, z: usize) -> f32 {
        self.values[x + self.dims[0] * (y + self.dims[1] * z)]
    }

    /// The trilinear value at `q` (in f64), clamped to the grid: the edge voxel's value in
    /// and beyond the outer half voxel. Callers test the box.
    pub(crate) fn trilinear(&self, q: [f64; 3]) -> f64 {
        let dims = self.dims.map(|d| d as u32);
        trilinear(q, self.origin, self.spacing, dims, |x, y, z| {
            self.at(x, y, z)
        })
    }
}

impl DensityField for VoxelGrid {
    fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        (self.origin, self.max)
    }

    fn extinction(&self, p: Vec3) -> f32 {
        if !inside(p, &self.origin, &self.max) {
            return 0.0;
        }
        self.trilinear([p.x as f64, p.y as f64, p.z as f64]) as f32
    }

    /// The trilinear value at any point is a convex combination of the (up to 8) voxels
    /// around it, so the max over the voxels whose centre cells touch the box is exact.
    fn max_extinction(&self, lo: [f64; 3], hi: [f64; 3]) -> Option<f32> {
        if !overlaps(&lo, &hi, &self.origin, &self.max) {
            return Some(0.0);
        }
        let mut r0 = [0usize; 3];
        let mut r1 = [0usize; 3];
        for a in 0..3 {
            let n = self.dims[a] as f64;
            let u0 = ((lo[a] - self.origin[a]) / self.spacing[a] - 0.5).clamp(0.0, n - 1.0);
            let u1 = ((hi[a] - self.origin[a]) / self.spacing[a] - 0.5).clamp(0.0, n - 1.0);
            r0[a] = u0.floor() as usize;
            r1[a] = (u1.floor() as usize + 1).min(self.dims[a] - 1);
        }
        let mut m = 0.0f32;
        for z in r0[2]..=r1[2] {
            for y in r0[1]..=r1[1] {
                for x in r0[0]..=r1[0] {
                    let v = self.at(x, y, z);
                    // NaN and negatives count as 0 (as in the estimators); +inf stays.
                    if v > m {
                        m = v;
                    }
                }
            }
        }
        Some(m)
    }

    fn dense_view(&self) -> Option<DenseView<'_>> {
        DenseView::new(&self.values, *self.map.as_deref()?)
    }
}

/// The trilinear value at `q` (f64 index, f64 lerps) of a voxel array read through `at`,
/// clamped to the grid: the edge voxel's value in and beyond the outer half voxel. One
/// function for [`VoxelGrid`] and the bricked grid, so that the two agree bit for bit.
#[inline]
pub(crate) fn trilinear(
    q: [f64; 3],
    origin: [f64; 3],
    spacing: [f64; 3],
    dims: [u32; 3],
    at: impl Fn(usize, usize, usize) -> f32,
) -> f64 {
    let mut i0 = [0usize; 3];
    let mut i1 = [0usize; 3];
    let mut f = [0f64; 3];
    for a in 0..3 {
        // Continuous index relative to voxel centres; clamping the integer part gives
        // the edge voxel's value in the outer half voxel.
        let u = (q[a] - origin[a]) / spacing[a] - 0.5;
        let u = u.clamp(0.0, f64::from(dims[a]) - 1.0);
        let fl = u.floor();
        i0[a] = fl as usize;
        i1[a] = (i0[a] + 1).min(dims[a] as usize - 1);
        f[a] = u - fl;
    }
    let lerp = |a: f32, b: f32, t: f64| a as f64 + (b as f64 - a as f64) * t;
    let c00 = lerp(at(i0[0], i0[1], i0[2]), at(i1[0], i0[1], i0[2]), f[0]);
    let c10 = lerp(at(i0[0], i1[1], i0[2]), at(i1[0], i1[1], i0[2]), f[0]);
    let c01 = lerp(at(i0[0], i0[1], i1[2]), at(i1[0], i0[1], i1[2]), f[0]);
    let c11 = lerp(at(i0[0], i1[1], i1[2]), at(i1[0], i1[1], i1[2]), f[0]);
    let c0 = c00 + (c10 - c00) * f[1];
    let c1 = c01 + (c11 - c01) * f[1];
    c0 + (c1 - c0) * f[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn voxel_grid_convention() {
        // 2x1x1: values 1 and 3, spacing 1, origin 0: box [0,2]x[0,1]x[0,1].
        let g = VoxelGrid::new([2, 1, 1], [0.0; 3], [1.0; 3], vec![1.0, 3.0]).unwrap();
        let e = |x: f32| g.extinction(Vec3::new(x, 0.5, 0.5));
        assert_eq!(e(0.1), 1.0); // outer half voxel: edge value
        assert_eq!(e(0.5), 1.0); // centre
        assert!((e(1.0) - 2.0).abs() < 1e-6); // halfway between centres
        assert_eq!(e(1.9), 3.0);
        assert_eq!(e(2.1), 0.0); // outside
        assert_eq!(g.max_extinction([0.0; 3], [0.4, 1.0, 1.0]), Some(3.0)); // conservative
        assert_eq!(g.max_extinction([5.0; 3], [6.0; 3]), Some(0.0));
        assert!(VoxelGrid::new([0, 1, 1], [0.0; 3], [1.0; 3], vec![]).is_err());
        assert!(VoxelGrid::new([1, 1, 1], [0.0; 3], [0.0; 3], vec![1.0]).is_err());
        // Cleaned on construction: an infinite voxel stays opaque under interpolation.
        let g = VoxelGrid::new(
            [4, 1, 1],
            [0.0; 3],
            [1.0; 3],
            vec![f32::NAN, -2.0, f32::INFINITY, f32::INFINITY],
        )
        .unwrap();
        assert_eq!(g.parts().3, &[0.0, 0.0, f32::MAX, f32::MAX]);
        assert_eq!(g.extinction(Vec3::new(3.0, 0.5, 0.5)), f32::MAX);
        assert_eq!(g.extinction(Vec3::new(0.2, 0.5, 0.5)), 0.0);
    }
}
