//! The renderer's own density fields (a closure, a dense voxel grid): what the reference
//! estimators march and track besides the baker's sources (the constant box among them). All of them are
//! [`Density`]s, the one density interface of bake and render.

use glam::{DVec3, Vec3};
use pin_volume::{Aabb, DenseMap, DenseView, Density, DensitySource};

/// Whether `p` lies in the closed box `[lo, hi]` (the voxel and bricked grids' box test).
#[inline]
pub(super) fn inside(p: DVec3, lo: &[f64; 3], hi: &[f64; 3]) -> bool {
    let q = p.to_array();
    (0..3).all(|a| q[a] >= lo[a] && q[a] <= hi[a])
}

#[inline]
fn overlaps(lo: &[f64; 3], hi: &[f64; 3], blo: &[f64; 3], bhi: &[f64; 3]) -> bool {
    (0..3).all(|a| lo[a] <= bhi[a] && hi[a] >= blo[a])
}

/// A field given by a closure over a box (0 outside the box). For tests and procedural media.
/// The closure takes f32 points, the renderer's own; it cannot bound itself, so majorant
/// grids over it sample a lattice.
pub struct FnField<F> {
    pub min: [f64; 3],
    pub max: [f64; 3],
    pub f: F,
}

impl<F: Fn(Vec3) -> f32 + Send + Sync> Density for FnField<F> {
    fn bounds(&self) -> Aabb {
        Aabb::from_arrays(self.min, self.max)
    }
    /// The closure at `p` narrowed to f32 (exact for the renderer's points, which are f32).
    #[inline]
    fn extinction(&self, p: DVec3) -> f32 {
        if inside(p, &self.min, &self.max) {
            (self.f)(p.as_vec3())
        } else {
            0.0
        }
    }
    fn max_extinction_in(&self, _region: Aabb) -> f32 {
        f32::INFINITY
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
    /// `values` as the trackers read them ([`Density::dense_view`]); boxed, so that
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
    ) -> Result<Self, super::error::RenderError> {
        let invalid = |why: String| super::error::RenderError::Invalid {
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

impl Density for VoxelGrid {
    fn bounds(&self) -> Aabb {
        Aabb::from_arrays(self.origin, self.max)
    }

    fn extinction(&self, p: DVec3) -> f32 {
        if !inside(p, &self.origin, &self.max) {
            return 0.0;
        }
        self.trilinear(p.to_array()) as f32
    }

    /// The trilinear value at any point is a convex combination of the (up to 8) voxels
    /// around it, so the max over the voxels whose centre cells touch the box is exact.
    fn max_extinction_in(&self, region: Aabb) -> f32 {
        let (lo, hi) = region.to_arrays();
        if !overlaps(&lo, &hi, &self.origin, &self.max) {
            return 0.0;
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
        m
    }

    fn dense_view(&self) -> Option<DenseView<'_>> {
        DenseView::new(&self.values, *self.map.as_deref()?)
    }
}

impl DensitySource for VoxelGrid {
    fn describe(&self) -> String {
        let [x, y, z] = self.dims;
        format!("voxel grid {x}x{y}x{z}")
    }

    fn voxel_size(&self) -> Option<DVec3> {
        Some(DVec3::from(self.spacing))
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
        let e = |x: f32| g.extinction(Vec3::new(x, 0.5, 0.5).as_dvec3());
        assert_eq!(e(0.1), 1.0); // outer half voxel: edge value
        assert_eq!(e(0.5), 1.0); // centre
        assert!((e(1.0) - 2.0).abs() < 1e-6); // halfway between centres
        assert_eq!(e(1.9), 3.0);
        assert_eq!(e(2.1), 0.0); // outside
        assert_eq!(
            g.max_extinction_in(Aabb::from_arrays([0.0; 3], [0.4, 1.0, 1.0])),
            3.0
        ); // conservative
        assert_eq!(
            g.max_extinction_in(Aabb::from_arrays([5.0; 3], [6.0; 3])),
            0.0
        );
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
        assert_eq!(g.extinction(Vec3::new(3.0, 0.5, 0.5).as_dvec3()), f32::MAX);
        assert_eq!(g.extinction(Vec3::new(0.2, 0.5, 0.5).as_dvec3()), 0.0);
    }
}
