//! A bricked voxel grid: [`VoxelGrid`]'s convention and values, stored only where the medium
//! is, behind a top-level index of one `u32` per brick (the pin file's sparse density section,
//! `docs/format.md` 5.6a). What the trackers read when a dense copy would not fit: a 992 x 674
//! x 1225 cloud is 3.3 GB dense in f32 and about its active voxels' worth bricked.
//!
//! Per-brick maxima and minima make [`Density::max_extinction_in`] and
//! [`Density::min_extinction_in`] cost one entry per brick a box touches instead of a voxel,
//! for the majorant grid and residual tracking's control.

use std::sync::Arc;

use glam::DVec3;
use half::f16;
use pin_format::SparseValues;

use super::error::RenderError;
use super::field::VoxelGrid;
use pin_volume::{Aabb, Density, DensitySource};

/// Marks an empty brick in [`BrickGrid`]'s index (the format's `EMPTY_BRICK`).
pub const EMPTY: u32 = u32::MAX;

/// The bits of f16 `+inf`. Above them lie the positive NaNs and every value with the sign
/// bit (negatives, -0, negative NaNs); below them, the finite values `>= +0`, which order as
/// their bits do.
const F16_INF_BITS: u16 = 0x7c00;

/// f16 voxel values read in place from memory that a [`BrickGrid`] does not own (a pin
/// file's mapping): every call returns the same slice.
pub trait SharedHalves: Send + Sync + std::fmt::Debug {
    fn halves(&self) -> &[f16];
}

/// The stored voxels, slot after slot: f16 where they came as f16 (a pin file's f16 sparse
/// section, read in place or copied: every f16 is exactly an f32), else f32.
#[derive(Clone, Debug)]
enum Stored {
    F32(Vec<f32>),
    F16(Vec<f16>),
    Shared(Arc<dyn SharedHalves>),
}

impl Stored {
    fn view(&self) -> SparseValues<'_> {
        match self {
            Stored::F32(v) => SparseValues::F32(v),
            Stored::F16(v) => SparseValues::F16(v),
            Stored::Shared(v) => SparseValues::F16(v.halves()),
        }
    }
}

/// Voxels of `dims` with `spacing` from `origin` (voxel `i`'s centre at `origin + (i + 0.5)
/// spacing`), trilinear between centres, the edge voxel's value in the outer half voxel, 0
/// outside the box: [`VoxelGrid`]'s field exactly. Values live in bricks of `brick^3` (x
/// fastest); empty bricks read 0.
#[derive(Clone, Debug)]
pub struct BrickGrid {
    dims: [u32; 3],
    origin: [f64; 3],
    spacing: [f64; 3],
    max: [f64; 3],
    /// log2 of the brick edge.
    shift: u32,
    brick_dims: [u32; 3],
    index: Vec<u32>,
    values: Stored,
    /// Per stored slot: the largest and smallest cleaned voxel.
    slot_max: Vec<f32>,
    slot_min: Vec<f32>,
}

impl BrickGrid {
    /// Validates and takes the parts: every dim `>= 1`, `brick` a power of two in 1..=64,
    /// one index entry per brick, each [`EMPTY`] or a slot below `values.len() / brick^3`,
    /// `values` whole bricks; finite origin, positive finite spacing. Values are cleaned as
    /// [`VoxelGrid::new`] cleans them (NaN and negatives to 0, `+inf` to `f32::MAX`).
    pub fn new(
        dims: [u32; 3],
        origin: [f64; 3],
        spacing: [f64; 3],
        brick: u32,
        index: Vec<u32>,
        mut values: Vec<f32>,
    ) -> Result<Self, RenderError> {
        for v in &mut values {
            *v = if *v > 0.0 { v.min(f32::MAX) } else { 0.0 };
        }
        Self::build(dims, origin, spacing, brick, index, Stored::F32(values))
    }

    /// [`BrickGrid::new`] for f16 values, kept as f16 (read back exactly as their f32). They
    /// are cleaned the same way: NaN and negatives to 0; a grid with a `+inf`, which reads
    /// as `f32::MAX`, is widened to f32.
    pub fn new_f16(
        dims: [u32; 3],
        origin: [f64; 3],
        spacing: [f64; 3],
        brick: u32,
        index: Vec<u32>,
        mut values: Vec<f16>,
    ) -> Result<Self, RenderError> {
        if values.iter().any(|v| v.to_bits() == F16_INF_BITS) {
            let wide = values.iter().map(|v| v.to_f32()).collect();
            return Self::new(dims, origin, spacing, brick, index, wide);
        }
        for v in &mut values {
            if v.to_bits() > F16_INF_BITS {
                *v = f16::ZERO;
            }
        }
        Self::build(dims, origin, spacing, brick, index, Stored::F16(values))
    }

    /// [`BrickGrid::new_f16`] over values read in place: kept shared where they are clean
    /// already (every value `+0` to the largest finite f16), else copied and cleaned.
    pub fn from_shared_f16(
        dims: [u32; 3],
        origin: [f64; 3],
        spacing: [f64; 3],
        brick: u32,
        index: Vec<u32>,
        values: Arc<dyn SharedHalves>,
    ) -> Result<Self, RenderError> {
        let grid = Self::build(
            dims,
            origin,
            spacing,
            brick,
            index,
            Stored::Shared(values.clone()),
        )?;
        // The bricks' maxima come from the largest bit pattern of each brick, and every value
        // that needs cleaning (+inf, NaN, anything with the sign bit) has larger bits than
        // every clean one: the values are clean exactly where every maximum is finite and
        // `>= +0`. So the pass that finds the maxima is also the test, with no pass of its own.
        if grid
            .slot_max
            .iter()
            .all(|m| m.is_finite() && m.is_sign_positive())
        {
            return Ok(grid);
        }
        let Self { index, .. } = grid;
        Self::new_f16(
            dims,
            origin,
            spacing,
            brick,
            index,
            values.halves().to_vec(),
        )
    }

    /// Validates the parts around cleaned values.
    fn build(
        dims: [u32; 3],
        origin: [f64; 3],
        spacing: [f64; 3],
        brick: u32,
        index: Vec<u32>,
        values: Stored,
    ) -> Result<Self, RenderError> {
        let invalid = |why: String| RenderError::Invalid {
            what: "bricked grid",
            why,
        };
        if dims.contains(&0) || !(brick.is_power_of_two() && brick <= 64) {
            return Err(invalid(format!("dims {dims:?}, brick {brick}")));
        }
        if !origin.iter().all(|v| v.is_finite())
            || !spacing.iter().all(|v| v.is_finite() && *v > 0.0)
        {
            return Err(invalid(format!("origin {origin:?} / spacing {spacing:?}")));
        }
        let brick_dims = dims.map(|d| d.div_ceil(brick));
        let bricks = brick_dims
            .iter()
            .try_fold(1usize, |acc, &d| acc.checked_mul(d as usize))
            .ok_or_else(|| invalid(format!("dims {dims:?} overflow")))?;
        let bv = (brick as usize).pow(3);
        if index.len() != bricks || !values.view().len().is_multiple_of(bv) {
            return Err(invalid(format!(
                "{} index entries for {bricks} bricks, {} values for bricks of {bv}",
                index.len(),
                values.view().len()
            )));
        }
        let slots = values.view().len() / bv;
        if let Some(i) = index
            .iter()
            .position(|&s| s != EMPTY && s as usize >= slots)
        {
            return Err(invalid(format!(
                "brick {i} points at slot {} of {slots}",
                index[i]
            )));
        }
        let range = |b: &mut dyn Iterator<Item = f32>| {
            b.fold((0.0f32, f32::INFINITY), |(hi, lo), v| {
                (hi.max(v), lo.min(v))
            })
        };
        let (slot_max, slot_min) = match values.view() {
            SparseValues::F32(v) => v
                .chunks_exact(bv)
                .map(|b| range(&mut b.iter().copied()))
                .unzip(),
            // Clean f16 values order as their bits do ([`F16_INF_BITS`]); shared values not
            // yet known clean are told by these maxima (`from_shared_f16`).
            SparseValues::F16(v) => v
                .chunks_exact(bv)
                .map(|b| {
                    let (hi, lo) = b.iter().fold((0u16, u16::MAX), |(hi, lo), h| {
                        (hi.max(h.to_bits()), lo.min(h.to_bits()))
                    });
                    let f = |bits: u16| f16::from_bits(bits).to_f32();
                    (f(hi), f(lo))
                })
                .unzip(),
        };
        let max = [0, 1, 2].map(|a| origin[a] + f64::from(dims[a]) * spacing[a]);
        Ok(Self {
            dims,
            origin,
            spacing,
            max,
            shift: brick.trailing_zeros(),
            brick_dims,
            index,
            values,
            slot_max,
            slot_min,
        })
    }

    /// The pin file's sparse density placed at `origin` with `spacing` (its box mapped to the
    /// world by a positive scale and a translation), its values at their own precision (f16
    /// or f32; either reads back exactly).
    pub fn from_sparse(
        s: &pinrt::SparseDensity<'_>,
        origin: [f64; 3],
        spacing: [f64; 3],
    ) -> Result<Self, RenderError> {
        let (dims, brick, index) = (s.dims(), s.brick(), s.index().to_vec());
        match s.values() {
            SparseValues::F16(v) => Self::new_f16(dims, origin, spacing, brick, index, v.to_vec()),
            SparseValues::F32(v) => Self::new(dims, origin, spacing, brick, index, v.to_vec()),
        }
    }

    /// The same field as `grid`, bricked in bricks of `brick` (empty bricks: all zero).
    pub fn from_voxels(grid: &VoxelGrid, brick: u32) -> Result<Self, RenderError> {
        let (dims, origin, spacing, data) = grid.parts();
        let b = brick.max(1);
        let bd = dims.map(|d| d.div_ceil(b));
        let bv = (b as usize).pow(3);
        let mut index = Vec::with_capacity((bd[0] * bd[1] * bd[2]) as usize);
        let mut values = Vec::new();
        let at = |x: u32, y: u32, z: u32| {
            data[x as usize + dims[0] as usize * (y as usize + dims[1] as usize * z as usize)]
        };
        let mut brick_buf = vec![0.0f32; bv];
        for bz in 0..bd[2] {
            for by in 0..bd[1] {
                for bx in 0..bd[0] {
                    brick_buf.fill(0.0);
                    let mut any = false;
                    for lz in 0..b {
                        for ly in 0..b {
                            for lx in 0..b {
                                let [x, y, z] = [bx * b + lx, by * b + ly, bz * b + lz];
                                if x < dims[0] && y < dims[1] && z < dims[2] {
                                    let v = at(x, y, z);
                                    brick_buf[(lx + b * (ly + b * lz)) as usize] = v;
                                    any |= v != 0.0;
                                }
                            }
                        }
                    }
                    if any {
                        index.push((values.len() / bv) as u32);
                        values.extend_from_slice(&brick_buf);
                    } else {
                        index.push(EMPTY);
                    }
                }
            }
        }
        Self::new(dims, origin, spacing, b, index, values)
    }

    /// The same field as a dense [`VoxelGrid`] (for consumers of dense arrays; the GPU's
    /// bricked copy is checked against it), when it has at most `max_voxels` voxels.
    pub fn to_voxels(&self, max_voxels: u64) -> Option<VoxelGrid> {
        let d = self.dims.map(|v| v as usize);
        let n = d[0].checked_mul(d[1])?.checked_mul(d[2])?;
        if n as u64 > max_voxels {
            return None;
        }
        let mut values = Vec::new();
        values.try_reserve_exact(n).ok()?;
        for z in 0..d[2] {
            for y in 0..d[1] {
                for x in 0..d[0] {
                    values.push(self.at(x, y, z));
                }
            }
        }
        VoxelGrid::new(self.dims, self.origin, self.spacing, values).ok()
    }

    /// Voxels per axis, brick edge, stored bricks.
    pub fn shape(&self) -> ([u32; 3], u32, usize) {
        (self.dims, 1 << self.shift, self.slot_max.len())
    }

    /// Origin and spacing of the voxels.
    pub fn placement(&self) -> ([f64; 3], [f64; 3]) {
        (self.origin, self.spacing)
    }

    /// Brick index (x fastest; slot or [`EMPTY`]) and the stored voxels, slot after slot (f16
    /// where they came as f16, [`BrickGrid::new_f16`]).
    pub fn parts(&self) -> (&[u32], SparseValues<'_>) {
        (&self.index, self.values.view())
    }

    #[inline(always)]
    fn slot(&self, b: [usize; 3]) -> u32 {
        let [nx, ny, _] = self.brick_dims.map(|v| v as usize);
        self.index[b[0] + nx * (b[1] + ny * b[2])]
    }

    /// The trilinear value at `q` (in f64), clamped to the grid as [`VoxelGrid`]'s: the
    /// edge voxel's value in and beyond the outer half voxel. Callers test the box. The
    /// values are looked up once per call, not per voxel.
    pub(crate) fn trilinear(&self, q: [f64; 3]) -> f64 {
        let (o, sp, d) = (self.origin, self.spacing, self.dims);
        match self.values.view() {
            SparseValues::F32(v) => {
                super::field::trilinear(q, o, sp, d, |x, y, z| self.voxel_in(v, x, y, z))
            }
            SparseValues::F16(v) => {
                super::field::trilinear(q, o, sp, d, |x, y, z| self.voxel_in(v, x, y, z))
            }
        }
    }

    /// Voxel `(x, y, z)` (in range).
    fn at(&self, x: usize, y: usize, z: usize) -> f32 {
        match self.values.view() {
            SparseValues::F32(v) => self.voxel_in(v, x, y, z),
            SparseValues::F16(v) => self.voxel_in(v, x, y, z),
        }
    }

    /// Voxel `(x, y, z)` (in range) of the stored `values`.
    #[inline(always)]
    fn voxel_in<T: Copy>(&self, values: &[T], x: usize, y: usize, z: usize) -> f32
    where
        f32: From<T>,
    {
        let s = self.shift;
        let slot = self.slot([x >> s, y >> s, z >> s]);
        if slot == EMPTY {
            return 0.0;
        }
        let m = (1usize << s) - 1;
        let local = (x & m) | ((y & m) << s) | ((z & m) << (2 * s));
        f32::from(values[((slot as usize) << (3 * s)) | local])
    }

    /// The voxel ranges whose centre cells touch `[lo, hi]` (as [`VoxelGrid`]'s maximum).
    fn voxel_range(&self, lo: [f64; 3], hi: [f64; 3]) -> ([usize; 3], [usize; 3]) {
        let mut r0 = [0usize; 3];
        let mut r1 = [0usize; 3];
        for a in 0..3 {
            let n = f64::from(self.dims[a]);
            let u0 = ((lo[a] - self.origin[a]) / self.spacing[a] - 0.5).clamp(0.0, n - 1.0);
            let u1 = ((hi[a] - self.origin[a]) / self.spacing[a] - 0.5).clamp(0.0, n - 1.0);
            r0[a] = u0.floor() as usize;
            r1[a] = (u1.floor() as usize + 1).min(self.dims[a] as usize - 1);
        }
        (r0, r1)
    }

    /// Folds `f` over the slots of the bricks holding voxels `r0..=r1` (`None` for empty).
    fn fold_bricks(
        &self,
        (r0, r1): ([usize; 3], [usize; 3]),
        init: f32,
        f: impl Fn(f32, Option<usize>) -> f32,
    ) -> f32 {
        let s = self.shift;
        let mut acc = init;
        for bz in r0[2] >> s..=r1[2] >> s {
            for by in r0[1] >> s..=r1[1] >> s {
                for bx in r0[0] >> s..=r1[0] >> s {
                    let slot = self.slot([bx, by, bz]);
                    acc = f(acc, (slot != EMPTY).then_some(slot as usize));
                }
            }
        }
        acc
    }
}

impl Density for BrickGrid {
    fn bounds(&self) -> Aabb {
        Aabb::from_arrays(self.origin, self.max)
    }

    /// [`VoxelGrid`]'s arithmetic (f64 index, f64 lerps), so the two agree bit for bit.
    fn extinction(&self, p: DVec3) -> f32 {
        if !super::field::inside(p, &self.origin, &self.max) {
            return 0.0;
        }
        self.trilinear(p.to_array()) as f32
    }

    /// The largest brick maximum over the bricks of the voxels whose centre cells touch the
    /// box: an upper bound (exact to the brick), one lookup per brick.
    fn max_extinction_in(&self, region: Aabb) -> f32 {
        let (lo, hi) = region.to_arrays();
        if !(0..3).all(|a| lo[a] <= self.max[a] && hi[a] >= self.origin[a]) {
            return 0.0;
        }
        let r = self.voxel_range(lo, hi);
        self.fold_bricks(r, 0.0, |m, s| s.map_or(m, |s| m.max(self.slot_max[s])))
    }

    /// The least brick minimum likewise (0 as soon as an empty brick is touched), or 0 where
    /// the box reaches outside the grid.
    fn min_extinction_in(&self, region: Aabb) -> Option<f32> {
        let (lo, hi) = region.to_arrays();
        if !(0..3).all(|a| lo[a] >= self.origin[a] && hi[a] <= self.max[a]) {
            return Some(0.0);
        }
        let r = self.voxel_range(lo, hi);
        Some(self.fold_bricks(r, f32::INFINITY, |m, s| {
            s.map_or(0.0, |s| m.min(self.slot_min[s]))
        }))
    }
}

impl DensitySource for BrickGrid {
    fn describe(&self) -> String {
        let [x, y, z] = self.dims;
        format!("bricked grid {x}x{y}x{z}")
    }

    fn voxel_size(&self) -> Option<DVec3> {
        Some(DVec3::from(self.spacing))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn cloud(dims: [u32; 3]) -> VoxelGrid {
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        let values = (0..n)
            .map(|i| {
                let [x, y, z] = [
                    i as u32 % dims[0],
                    (i as u32 / dims[0]) % dims[1],
                    i as u32 / (dims[0] * dims[1]),
                ];
                // Empty bricks and a blob with sharp edges.
                if x < 9 || (y + z) % 17 < 3 {
                    0.0
                } else {
                    ((x * 7 + y * 3 + z) % 13) as f32 * 0.5
                }
            })
            .collect();
        VoxelGrid::new(dims, [-1.0, 0.5, 2.0], [0.25, 0.5, 0.125], values).unwrap()
    }

    #[test]
    fn bricked_reads_what_the_dense_grid_reads() {
        let dense = cloud([29, 17, 33]);
        let bricked = BrickGrid::from_voxels(&dense, 8).unwrap();
        assert!(bricked.shape().2 < 4 * 3 * 5, "some bricks are empty");
        assert_eq!(bricked.bounds(), dense.bounds());
        let (lo, hi) = dense.bounds().to_arrays();
        let mut rng = crate::render::rng::Pcg32::new(7, 1);
        for _ in 0..20000 {
            let p = Vec3::from_array(
                [0, 1, 2]
                    .map(|a| (lo[a] - 0.3 + (hi[a] - lo[a] + 0.6) * rng.next_f32() as f64) as f32),
            );
            assert_eq!(
                bricked.extinction(p.as_dvec3()),
                dense.extinction(p.as_dvec3()),
                "{p}"
            );
        }
        for _ in 0..2000 {
            let a = [0, 1, 2].map(|k| lo[k] + (hi[k] - lo[k]) * rng.next_f32() as f64);
            let b = [0, 1, 2].map(|k| a[k] + (hi[k] - a[k]) * rng.next_f32() as f64 * 0.3);
            let exact = dense.max_extinction_in(Aabb::from_arrays(a, b));
            let bound = bricked.max_extinction_in(Aabb::from_arrays(a, b));
            assert!(bound >= exact, "{a:?} {b:?}");
            let low = bricked.min_extinction_in(Aabb::from_arrays(a, b)).unwrap();
            let dmin = dense.dense_view().unwrap().min_over(a, b);
            assert!(low <= dmin, "{a:?} {b:?}: {low} > {dmin}");
        }
        let back = bricked.to_voxels(1 << 20).unwrap();
        assert_eq!(back.parts().3, dense.parts().3);
        assert!(bricked.to_voxels(100).is_none());
        // The whole box: exact, the largest voxel.
        let all = dense.parts().3.iter().copied().fold(0.0, f32::max);
        assert_eq!(bricked.max_extinction_in(Aabb::from_arrays(lo, hi)), all);
    }

    /// f16 values kept as f16 read back what the same values widened to f32 read, bit for
    /// bit (field, brick bounds), at half the bytes; cleaning as the f32 path cleans.
    #[test]
    fn f16_storage_reads_what_f32_storage_reads() {
        let dense = cloud([29, 17, 33]);
        let wide = BrickGrid::from_voxels(&dense, 8).unwrap();
        let (dims, brick, _) = wide.shape();
        let ((origin, spacing), (index, values)) = (wide.placement(), wide.parts());
        let halves: Vec<f16> = (0..values.len())
            .map(|i| f16::from_f32(values.get(i).unwrap()))
            .collect();
        let narrow =
            BrickGrid::new_f16(dims, origin, spacing, brick, index.to_vec(), halves.clone())
                .unwrap();
        assert!(matches!(narrow.parts().1, SparseValues::F16(_)));
        // The cloud's values are multiples of 0.5 below 6.5: exactly f16.
        let widened = halves.iter().map(|h| h.to_f32()).collect();
        let wide = BrickGrid::new(dims, origin, spacing, brick, index.to_vec(), widened).unwrap();
        let (lo, hi) = dense.bounds().to_arrays();
        let mut rng = crate::render::rng::Pcg32::new(9, 1);
        for _ in 0..20000 {
            let p = [0, 1, 2].map(|a| lo[a] - 0.3 + (hi[a] - lo[a] + 0.6) * rng.next_f32() as f64);
            let p = DVec3::from_array(p);
            assert_eq!(
                narrow.extinction(p).to_bits(),
                wide.extinction(p).to_bits(),
                "{p}"
            );
        }
        for _ in 0..2000 {
            let a = [0, 1, 2].map(|k| lo[k] + (hi[k] - lo[k]) * rng.next_f32() as f64);
            let b = [0, 1, 2].map(|k| a[k] + (hi[k] - a[k]) * rng.next_f32() as f64 * 0.3);
            let r = Aabb::from_arrays(a, b);
            assert_eq!(narrow.max_extinction_in(r), wide.max_extinction_in(r));
            assert_eq!(narrow.min_extinction_in(r), wide.min_extinction_in(r));
        }
        assert_eq!(
            narrow.to_voxels(1 << 20).unwrap().parts().3,
            wide.to_voxels(1 << 20).unwrap().parts().3
        );
        // Cleaning: NaN and negatives read 0; a +inf reads f32::MAX (the grid widens).
        let odd = |v: f16| {
            let mut vals = vec![f16::from_f32(2.0); 8];
            vals[3] = v;
            BrickGrid::new_f16([2, 2, 2], [0.0; 3], [1.0; 3], 2, vec![0], vals).unwrap()
        };
        assert_eq!(odd(f16::NAN).at(1, 1, 0), 0.0);
        assert_eq!(odd(f16::from_f32(-3.0)).at(1, 1, 0), 0.0);
        assert_eq!(odd(f16::from_f32(-0.0)).at(1, 1, 0).to_bits(), 0);
        let inf = odd(f16::INFINITY);
        assert_eq!(inf.at(1, 1, 0), f32::MAX);
        assert!(matches!(inf.parts().1, SparseValues::F32(_)));
    }

    /// Values shared from elsewhere read in place (the same slice, no copy) and read what a
    /// copy reads; shared values that need cleaning are copied and cleaned instead.
    #[test]
    fn shared_f16_reads_in_place_what_a_copy_reads() {
        #[derive(Debug)]
        struct Held(Vec<f16>);
        impl SharedHalves for Held {
            fn halves(&self) -> &[f16] {
                &self.0
            }
        }
        let dense = cloud([29, 17, 33]);
        let wide = BrickGrid::from_voxels(&dense, 8).unwrap();
        let (dims, brick, _) = wide.shape();
        let ((origin, spacing), (index, values)) = (wide.placement(), wide.parts());
        let halves: Vec<f16> = (0..values.len())
            .map(|i| f16::from_f32(values.get(i).unwrap()))
            .collect();
        let held = Arc::new(Held(halves.clone()));
        let at = held.0.as_ptr();
        let shared =
            BrickGrid::from_shared_f16(dims, origin, spacing, brick, index.to_vec(), held).unwrap();
        let copied =
            BrickGrid::new_f16(dims, origin, spacing, brick, index.to_vec(), halves.clone())
                .unwrap();
        match shared.parts().1 {
            SparseValues::F16(v) => assert_eq!(v.as_ptr(), at, "read in place"),
            SparseValues::F32(_) => panic!("widened"),
        }
        let (lo, hi) = dense.bounds().to_arrays();
        let mut rng = crate::render::rng::Pcg32::new(11, 1);
        for _ in 0..20000 {
            let p = [0, 1, 2].map(|a| lo[a] - 0.3 + (hi[a] - lo[a] + 0.6) * rng.next_f32() as f64);
            let p = DVec3::from_array(p);
            assert_eq!(
                shared.extinction(p).to_bits(),
                copied.extinction(p).to_bits()
            );
        }
        let r = Aabb::from_arrays(lo, hi);
        assert_eq!(shared.max_extinction_in(r), copied.max_extinction_in(r));
        // A negative zero and a NaN: copied and cleaned, read as +0.
        let mut dirty = halves;
        let first = dirty.iter().position(|v| v.to_f32() > 0.0).unwrap();
        dirty[first] = f16::NAN;
        dirty[first + 1] = f16::from_f32(-0.0);
        let at = dirty.as_ptr();
        let held = Arc::new(Held(dirty));
        let g =
            BrickGrid::from_shared_f16(dims, origin, spacing, brick, index.to_vec(), held).unwrap();
        match g.parts().1 {
            SparseValues::F16(v) => {
                assert_ne!(v.as_ptr(), at, "copied");
                assert_eq!((v[first].to_bits(), v[first + 1].to_bits()), (0, 0));
            }
            SparseValues::F32(_) => panic!("widened"),
        }
    }

    #[test]
    fn refuses_parts_it_cannot_trust() {
        let ok = |index: Vec<u32>, values: Vec<f32>| {
            BrickGrid::new([3, 1, 1], [0.0; 3], [1.0; 3], 2, index, values)
        };
        assert!(ok(vec![EMPTY, 0], vec![1.0; 8]).is_ok());
        assert!(ok(vec![EMPTY, 1], vec![1.0; 8]).is_err());
        assert!(ok(vec![EMPTY], vec![1.0; 8]).is_err());
        assert!(ok(vec![EMPTY, 0], vec![1.0; 7]).is_err());
        assert!(BrickGrid::new([3, 1, 1], [0.0; 3], [1.0; 3], 3, vec![0], vec![0.0; 27]).is_err());
    }
}
