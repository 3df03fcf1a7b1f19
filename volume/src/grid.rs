//! A dense scalar grid placed in world space by the shared convention of docs/background.md section 2.
//!
//! This is what raw volumes become, and what tests build by hand. A grid of dims `N`, spacing
//! `s` and origin `o` occupies `[o, o + N*s]`; voxel centres sit at `o + (i + 0.5) * s`; values
//! are trilinear between centres, the edge voxel's value holds in the outer half voxel
//! (clamp-to-edge inside the box) and everything outside the box is zero. The baker and the
//! renderer use this one definition so that a pin file lines up with its source exactly.
//!
//! It is not a sparse structure (see the VDB source for that) and does no filtering beyond
//! trilinear interpolation. Values are validated on construction (finite, `>= 0`), so the hot
//! path does no checks beyond the box test.

use glam::DVec3;

use super::{Aabb, Density, DensitySource, SourceError};

/// Dense f32 grid, x fastest, then y, then z (`data[x + nx * (y + ny * z)]`).
#[derive(Clone, Debug)]
pub struct DenseGrid {
    /// Dims and placement, with the index map's folded constants.
    lattice: DenseLattice,
    data: Vec<f32>,
    /// `dims - 1` as f64, the clamp limit of the continuous index.
    max_index: DVec3,
    bounds: Aabb,
    stride_y: usize,
    stride_z: usize,
    max_value: f32,
    occupied: Aabb,
    label: String,
}

impl DenseGrid {
    /// Builds a grid from validated parts. `data.len()` must equal the product of `dims`, every
    /// value must be finite and `>= 0`, `spacing` positive and finite, `origin` finite.
    pub fn new(
        dims: [u32; 3],
        data: Vec<f32>,
        spacing: DVec3,
        origin: DVec3,
        label: impl Into<String>,
    ) -> Result<Self, SourceError> {
        let count = voxel_count(dims)
            .ok_or_else(|| SourceError::InvalidOption(format!("grid dims {dims:?} overflow")))?;
        if dims.contains(&0) {
            return Err(SourceError::InvalidOption(format!(
                "grid dims {dims:?} contain a zero"
            )));
        }
        if data.len() != count {
            return Err(SourceError::InvalidOption(format!(
                "grid dims {dims:?} need {count} values, got {}",
                data.len()
            )));
        }
        if !(spacing.is_finite() && spacing.cmpgt(DVec3::ZERO).all()) {
            return Err(SourceError::InvalidOption(format!(
                "grid spacing must be positive and finite, got {spacing}"
            )));
        }
        if !origin.is_finite() {
            return Err(SourceError::InvalidOption(format!(
                "grid origin must be finite, got {origin}"
            )));
        }
        if let Some(i) = data.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
            let [x, y, z] = unflatten(i, dims);
            return Err(SourceError::InvalidOption(format!(
                "grid value {} at voxel ({x},{y},{z}) is not a finite non-negative number",
                data[i]
            )));
        }
        let n = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
        let max = origin + n * spacing;
        let bounds = Aabb::new(origin, max);
        if !bounds.is_valid() {
            return Err(SourceError::InvalidOption(format!(
                "grid box {origin}..{max} is not finite"
            )));
        }
        let stride_y = dims[0] as usize;
        let stride_z = stride_y * dims[1] as usize;
        let max_value = data.iter().copied().fold(0.0f32, f32::max);
        advise_huge_pages(&data);
        let mut g = Self {
            lattice: DenseLattice::new(dims, spacing, origin),
            data,
            max_index: n - 1.0,
            bounds,
            stride_y,
            stride_z,
            max_value,
            occupied: bounds,
            label: label.into(),
        };
        g.occupied = g.compute_occupied();
        Ok(g)
    }

    pub fn dims(&self) -> [u32; 3] {
        self.lattice.dims
    }
    pub fn data(&self) -> &[f32] {
        &self.data
    }
    pub fn spacing(&self) -> DVec3 {
        self.lattice.spacing
    }
    pub fn origin(&self) -> DVec3 {
        self.lattice.origin
    }
    /// The largest voxel value.
    pub fn max_value(&self) -> f32 {
        self.max_value
    }

    /// The voxel value at integer coordinates (no interpolation); `None` outside the grid.
    pub fn voxel(&self, x: u32, y: u32, z: u32) -> Option<f32> {
        if x < self.lattice.dims[0] && y < self.lattice.dims[1] && z < self.lattice.dims[2] {
            Some(self.data[x as usize + y as usize * self.stride_y + z as usize * self.stride_z])
        } else {
            None
        }
    }

    /// Tight box of non-zero voxels, grown by one voxel on each side (the reach of trilinear
    /// support), clamped to the grid box. A grid of zeros gives a zero-volume box at `min`.
    fn compute_occupied(&self) -> Aabb {
        let [nx, ny, nz] = self.lattice.dims.map(|d| d as usize);
        let mut lo = [usize::MAX; 3];
        let mut hi = [0usize; 3];
        for z in 0..nz {
            for y in 0..ny {
                let row = &self.data[y * self.stride_y + z * self.stride_z..][..nx];
                let (Some(first), Some(last)) = (
                    row.iter().position(|v| *v != 0.0),
                    row.iter().rposition(|v| *v != 0.0),
                ) else {
                    continue;
                };
                lo = [lo[0].min(first), lo[1].min(y), lo[2].min(z)];
                hi = [hi[0].max(last), hi[1].max(y), hi[2].max(z)];
            }
        }
        if lo[0] == usize::MAX {
            return Aabb::new(self.bounds.min, self.bounds.min);
        }
        let lo = DVec3::new(lo[0] as f64, lo[1] as f64, lo[2] as f64) - 1.0;
        let hi = DVec3::new(hi[0] as f64, hi[1] as f64, hi[2] as f64) + 2.0;
        Aabb::new(
            (self.lattice.origin + lo * self.lattice.spacing).max(self.bounds.min),
            (self.lattice.origin + hi * self.lattice.spacing).min(self.bounds.max),
        )
    }

    #[inline(always)]
    fn inside(&self, p: DVec3) -> bool {
        // Written as `>=`/`<=` so that NaN coordinates fall outside.
        p.cmpge(self.bounds.min).all() && p.cmple(self.bounds.max).all()
    }

    /// Trilinear sample of a point already known to be inside the box.
    #[inline(always)]
    fn sample_inside(&self, p: DVec3) -> f32 {
        // Continuous index relative to voxel centres, clamped so the outer half voxel repeats
        // the edge value. `u as usize` truncates; after the clamp u >= 0 so that is floor.
        let u = self
            .lattice
            .index_of(p)
            .max(DVec3::ZERO)
            .min(self.max_index);
        let ix = u.x as usize;
        let iy = u.y as usize;
        let iz = u.z as usize;
        let fx = (u.x - ix as f64) as f32;
        let fy = (u.y - iy as f64) as f32;
        let fz = (u.z - iz as f64) as f32;
        // At the upper edge the neighbour is the voxel itself (offset 0) and the weight is 0.
        let dx = usize::from(ix + 1 < self.lattice.dims[0] as usize);
        let dy = if iy + 1 < self.lattice.dims[1] as usize {
            self.stride_y
        } else {
            0
        };
        let dz = if iz + 1 < self.lattice.dims[2] as usize {
            self.stride_z
        } else {
            0
        };
        let base = ix + iy * self.stride_y + iz * self.stride_z;
        let d = &self.data;
        // Indices are in range by construction (clamped u, dims product == len); the bounds
        // checks stay because they are cheap next to the loads and keep this code safe.
        let c000 = d[base];
        let c100 = d[base + dx];
        let c010 = d[base + dy];
        let c110 = d[base + dx + dy];
        let c001 = d[base + dz];
        let c101 = d[base + dx + dz];
        let c011 = d[base + dy + dz];
        let c111 = d[base + dx + dy + dz];
        let c00 = c000 + (c100 - c000) * fx;
        let c10 = c010 + (c110 - c010) * fx;
        let c01 = c001 + (c101 - c001) * fx;
        let c11 = c011 + (c111 - c011) * fx;
        let c0 = c00 + (c10 - c00) * fy;
        let c1 = c01 + (c11 - c01) * fy;
        // Lerp of non-negative values in this form can round to -0.0 or a tiny negative; the
        // contract says never negative.
        (c0 + (c1 - c0) * fz).max(0.0)
    }
}

/// The voxel lattice of a dense grid without its values: dims and placement, and the
/// grid's world-to-index arithmetic to the bit. What a bake that reads a sparse source's dense
/// copy plane by plane ([`super::DensitySource::dense_planes`]) places its samples by.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DenseLattice {
    pub dims: [u32; 3],
    pub spacing: DVec3,
    pub origin: DVec3,
    /// `1 / spacing`: `extinction` is called ~1e8 times per bake, so it multiplies.
    inv_spacing: DVec3,
    /// `origin / spacing + 0.5`, folded so that the continuous index is one fused expression.
    index_offset: DVec3,
}

impl DenseLattice {
    /// The lattice of `dims` voxels of `spacing` from `origin` (as [`DenseGrid::new`] takes
    /// them; not validated: its sources pass the parts they build a grid from).
    pub fn new(dims: [u32; 3], spacing: DVec3, origin: DVec3) -> Self {
        let inv_spacing = spacing.recip();
        Self {
            dims,
            spacing,
            origin,
            inv_spacing,
            index_offset: origin * inv_spacing + 0.5,
        }
    }

    /// [`DenseGrid::index_of`].
    #[inline]
    pub fn index_of(&self, p: DVec3) -> DVec3 {
        p * self.inv_spacing - self.index_offset
    }

    /// [`DenseGrid::index_dir`].
    #[inline]
    pub fn index_dir(&self, d: DVec3) -> DVec3 {
        d * self.inv_spacing
    }
}

impl DenseGrid {
    /// The grid's lattice: its dims and placement, without the values.
    pub fn lattice(&self) -> DenseLattice {
        self.lattice
    }

    /// Continuous index (voxel centres at integers) of a world point.
    #[inline]
    pub fn index_of(&self, p: DVec3) -> DVec3 {
        self.lattice.index_of(p)
    }

    /// World direction to index direction.
    #[inline]
    pub fn index_dir(&self, d: DVec3) -> DVec3 {
        self.lattice.index_dir(d)
    }

    /// Samples `js` of the run from `u0` stepping `du`, appended to `out`: the values
    /// [`Self::march_runs`] adds for that run, bit for bit (sample `j` at `u0 + j * du` in
    /// f32, as every lane and the one-by-one march compute it). A farm part stores them and
    /// the merge adds them in the march's order.
    pub fn run_samples(
        &self,
        u0: [f32; 3],
        du: [f32; 3],
        js: std::ops::Range<usize>,
        out: &mut Vec<f32>,
    ) {
        let cells = self.cells();
        for j in js {
            let t = j as f32;
            let (b, f) = cells.locate([u0[0] + t * du[0], u0[1] + t * du[1], u0[2] + t * du[2]]);
            out.push(cells.interpolate(b, f));
        }
    }

    /// Sums of the trilinear values over consecutive runs of samples: run `r` is the `n`
    /// continuous indices `u0[r] + j * du`, `j < n`, and its sum lands in `sums[r]`. The
    /// caller knows the runs lie inside the box (the baker's chords do; a point outside is
    /// clamped to the edge value instead of reading zero).
    ///
    /// The marching counterpart of [`Density::extinction_along`]: the index advances in
    /// f32 from one f64 base per run (no world-to-index transform and no box test per sample;
    /// `j * du` rather than a running sum keeps sample `j` within a few f32 ulps). It works in
    /// two passes over blocks of samples: the first computes every sample's cell and weights
    /// and prefetches the cell's cache lines, the second loads and interpolates. A bake's
    /// samples land all over a grid far larger than the caches, so one sample at a time waits
    /// on memory once per sample; the prefetches let a whole block's misses overlap. Values
    /// are summed in f64 in sample order, so the result is deterministic.
    pub fn march_runs(&self, u0: &[[f32; 3]], du: [f32; 3], n: usize, sums: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        if u0.len() >= RUN_LANES && std::arch::is_x86_feature_detected!("avx2") {
            let whole = u0.len() / RUN_LANES * RUN_LANES;
            // SAFETY: AVX2 is present (checked just above).
            unsafe { self.march_run_lanes_avx2(&u0[..whole], du, n, &mut sums[..whole]) };
            self.march_runs_one_by_one(&u0[whole..], du, n, &mut sums[whole..]);
            return;
        }
        self.march_runs_one_by_one(u0, du, n, sums);
    }

    /// [`Self::march_run_lanes`] compiled for AVX2 (no FMA: the products and sums must be
    /// rounded as the one-by-one march rounds them).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn march_run_lanes_avx2(
        &self,
        u0: &[[f32; 3]],
        du: [f32; 3],
        n: usize,
        sums: &mut [f64],
    ) {
        self.march_run_lanes(u0, du, n, sums);
    }

    /// [`Self::march_runs`] for runs in groups of [`RUN_LANES`] (`u0.len()` a multiple of
    /// it), sample `j` of every run of a group at once. Why: all runs of a pin have the same
    /// sample count and step, so the lanes need no masking, and the group's locating is
    /// straight-line arithmetic the compiler vectorises; the one-by-one march also adds every
    /// value to one f64 sum, a chain of dependent adds, where here each lane has its own.
    /// The values are the same: lane `r` takes the points `u0[r] + j * du` in the order
    /// `j = 0, 1, ..`, rounded the same way, and adds them to `sums[r]` in that order.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn march_run_lanes(&self, u0: &[[f32; 3]], du: [f32; 3], n: usize, sums: &mut [f64]) {
        // Samples of each lane located and prefetched before any is read, as one by one.
        const K: usize = 16;
        const L: usize = RUN_LANES;
        let cells = self.cells();
        let vector = LocateX8::new(&cells);
        for (g, s) in u0.chunks_exact(L).zip(sums.chunks_exact_mut(L)) {
            let b: [[f32; L]; 3] = std::array::from_fn(|a| std::array::from_fn(|l| g[l][a]));
            let mut acc: [f64; L] = std::array::from_fn(|l| s[l]);
            let mut j0 = 0;
            while j0 < n {
                let k = (n - j0).min(K);
                let mut base = [[0usize; L]; K];
                let mut frac = [[[0.0f32; 3]; L]; K];
                for (jj, (bs, fs)) in base.iter_mut().zip(frac.iter_mut()).take(k).enumerate() {
                    let t = (j0 + jj) as f32;
                    if let Some(v) = vector {
                        // SAFETY: `vector` is only set where AVX2 is present.
                        unsafe { v.locate(&b, t, du, bs, fs) };
                        for &i in bs.iter() {
                            cells.prefetch(i);
                        }
                        continue;
                    }
                    // A grid of more than 2^31 voxels: the same arithmetic, lane by lane.
                    for l in 0..L {
                        let u = [
                            b[0][l] + t * du[0],
                            b[1][l] + t * du[1],
                            b[2][l] + t * du[2],
                        ];
                        (bs[l], fs[l]) = cells.locate(u);
                        cells.prefetch(bs[l]);
                    }
                }
                for (bs, fs) in base.iter().zip(frac.iter()).take(k) {
                    for l in 0..L {
                        acc[l] += f64::from(cells.interpolate(bs[l], fs[l]));
                    }
                }
                j0 += k;
            }
            s.copy_from_slice(&acc);
        }
    }

    /// [`Self::march_runs`] one run after another.
    fn march_runs_one_by_one(&self, u0: &[[f32; 3]], du: [f32; 3], n: usize, sums: &mut [f64]) {
        const BLOCK: usize = 128;
        let cells = self.cells();
        let mut base = [0usize; BLOCK];
        let mut frac = [[0.0f32; 3]; BLOCK];
        if n == 0 {
            return;
        }
        let total = u0.len() * n;
        let mut m0 = 0;
        // Run and sample within the run of the next sample, for each pass (counters, not a
        // division per sample).
        let (mut r1, mut j1) = (0usize, 0usize);
        let (mut r2, mut j2) = (0usize, 0usize);
        while m0 < total {
            let len = (total - m0).min(BLOCK);
            for (b, f) in base.iter_mut().zip(frac.iter_mut()).take(len) {
                let (r, t) = (r1, j1 as f32);
                j1 += 1;
                if j1 == n {
                    (r1, j1) = (r1 + 1, 0);
                }
                let u = u0[r];
                (*b, *f) = cells.locate([u[0] + t * du[0], u[1] + t * du[1], u[2] + t * du[2]]);
                cells.prefetch(*b);
            }
            for (b, f) in base.iter().zip(frac.iter()).take(len) {
                sums[r2] += f64::from(cells.interpolate(*b, *f));
                j2 += 1;
                if j2 == n {
                    (r2, j2) = (r2 + 1, 0);
                }
            }
            m0 += len;
        }
    }

    /// The grid's trilinear lookup by continuous index, for marching loops.
    pub fn cells(&self) -> Cells<'_> {
        let [nx, ny, nz] = self.lattice.dims.map(|d| d as usize);
        Cells {
            data: &self.data,
            hi: [nx, ny, nz].map(|d| d.saturating_sub(2) as f32),
            top: [nx, ny, nz].map(|d| (d - 1) as f32),
            stride: [self.stride_y, self.stride_z],
            step: [
                usize::from(nx > 1),
                if ny > 1 { self.stride_y } else { 0 },
                if nz > 1 { self.stride_z } else { 0 },
            ],
        }
    }
}

/// Runs [`DenseGrid::march_runs`] marches side by side (8 f32 lanes of AVX2).
#[cfg(target_arch = "x86_64")]
const RUN_LANES: usize = 8;

/// [`Cells::locate`] for 8 samples in AVX2 registers, where the grid's linear indices fit
/// in an `i32` (vector integer products are 32-bit). Every lane computes what the scalar
/// code computes: the same products and sums (no FMA), `max(u, 0)` giving 0 for NaN as
/// `f32::max` does, truncation of a non-negative value as `as usize`.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
struct LocateX8 {
    top: [f32; 3],
    hi: [f32; 3],
    stride: [i32; 2],
}

#[cfg(target_arch = "x86_64")]
impl LocateX8 {
    fn new(cells: &Cells<'_>) -> Option<Self> {
        if !std::arch::is_x86_feature_detected!("avx2") || cells.data.len() > i32::MAX as usize {
            return None;
        }
        Some(Self {
            top: cells.top,
            hi: cells.hi,
            stride: [
                i32::try_from(cells.stride[0]).ok()?,
                i32::try_from(cells.stride[1]).ok()?,
            ],
        })
    }

    /// Sample `t` of the 8 runs whose first samples are `b` (per axis, per lane).
    #[target_feature(enable = "avx2")]
    unsafe fn locate(
        &self,
        b: &[[f32; RUN_LANES]; 3],
        t: f32,
        du: [f32; 3],
        base: &mut [usize; RUN_LANES],
        frac: &mut [[f32; 3]; RUN_LANES],
    ) {
        use std::arch::x86_64::*;
        let tt = _mm256_set1_ps(t);
        let mut idx = [_mm256_setzero_si256(); 3];
        let mut fr = [_mm256_setzero_ps(); 3];
        for a in 0..3 {
            // SAFETY: `b[a]` is 8 f32s; unaligned loads.
            let u = _mm256_add_ps(
                unsafe { _mm256_loadu_ps(b[a].as_ptr()) },
                _mm256_mul_ps(tt, _mm256_set1_ps(du[a])),
            );
            // `_mm256_max_ps(u, 0)` returns its second operand where `u` is NaN.
            let c = _mm256_min_ps(
                _mm256_max_ps(u, _mm256_setzero_ps()),
                _mm256_set1_ps(self.top[a]),
            );
            let i = _mm256_cvttps_epi32(_mm256_min_ps(c, _mm256_set1_ps(self.hi[a])));
            fr[a] = _mm256_sub_ps(c, _mm256_cvtepi32_ps(i));
            idx[a] = i;
        }
        let lin = _mm256_add_epi32(
            idx[0],
            _mm256_add_epi32(
                _mm256_mullo_epi32(idx[1], _mm256_set1_epi32(self.stride[0])),
                _mm256_mullo_epi32(idx[2], _mm256_set1_epi32(self.stride[1])),
            ),
        );
        let mut li = [0i32; RUN_LANES];
        let mut f = [[0.0f32; RUN_LANES]; 3];
        // SAFETY: 8-element arrays; unaligned stores.
        unsafe {
            _mm256_storeu_si256(li.as_mut_ptr().cast(), lin);
            for a in 0..3 {
                _mm256_storeu_ps(f[a].as_mut_ptr(), fr[a]);
            }
        }
        for l in 0..RUN_LANES {
            // Non-negative: the indices were clamped to the grid, which fits an i32.
            base[l] = li[l] as usize;
            frac[l] = [f[0][l], f[1][l], f[2][l]];
        }
    }
}

/// A dense grid's trilinear lookup by continuous index (voxel centres at integers), split
/// into locating a sample's cell, prefetching it and interpolating it, so that a marching
/// loop can locate and prefetch a block of samples before it reads any: the loads of a whole
/// block then overlap instead of waiting on memory one sample at a time.
#[derive(Clone, Copy)]
pub struct Cells<'a> {
    data: &'a [f32],
    /// The lower corner of a cell is clamped to `dims - 2` and the fraction then reaches 1 at
    /// the last centre, so the `+ 1` neighbour always exists...
    hi: [f32; 3],
    /// ...and the index itself to `[0, dims - 1]` (clamp-to-edge in the outer half voxel).
    top: [f32; 3],
    stride: [usize; 2],
    /// Offsets of the `+ 1` neighbour along x, y, z: 0 on a one-voxel axis, which has none.
    step: [usize; 3],
}

impl Cells<'_> {
    /// The linear index of the lower corner of the cell holding continuous index `c` and the
    /// fractions within it. Indices outside the grid (the caller's runs should not leave it)
    /// clamp to its edge, NaN to 0.
    #[inline(always)]
    pub fn locate(&self, c: [f32; 3]) -> (usize, [f32; 3]) {
        // `max` first so that NaN becomes 0 (f32::max returns the non-NaN operand).
        let cx = c[0].max(0.0).min(self.top[0]);
        let cy = c[1].max(0.0).min(self.top[1]);
        let cz = c[2].max(0.0).min(self.top[2]);
        // Non-negative after the clamp, so `as usize` is floor (`f32::floor` is a libm call
        // on baseline x86-64, a third of the time here).
        let (ix, iy, iz) = (
            cx.min(self.hi[0]) as usize,
            cy.min(self.hi[1]) as usize,
            cz.min(self.hi[2]) as usize,
        );
        (
            ix + iy * self.stride[0] + iz * self.stride[1],
            [cx - ix as f32, cy - iy as f32, cz - iz as f32],
        )
    }

    /// Asks for the four cache lines the cell at `b` reads (x neighbours share a line or the
    /// next one, which the hardware fetches with it).
    #[inline(always)]
    pub fn prefetch(&self, b: usize) {
        let [_, sy, sz] = self.step;
        prefetch(self.data, b);
        prefetch(self.data, b + sy);
        prefetch(self.data, b + sz);
        prefetch(self.data, b + sy + sz);
    }

    /// The trilinear value of the cell at `b` with fractions `f`, never negative.
    #[inline(always)]
    pub fn interpolate(&self, b: usize, f: [f32; 3]) -> f32 {
        let [sx, sy, sz] = self.step;
        let [fx, fy, fz] = f;
        // One slice bounds check covers the eight loads.
        let c = &self.data[b..=b + sx + sy + sz];
        let c00 = c[0] + (c[sx] - c[0]) * fx;
        let c10 = c[sy] + (c[sy + sx] - c[sy]) * fx;
        let c01 = c[sz] + (c[sz + sx] - c[sz]) * fx;
        let c11 = c[sz + sy] + (c[sz + sy + sx] - c[sz + sy]) * fx;
        let c0 = c00 + (c10 - c00) * fy;
        let c1 = c01 + (c11 - c01) * fy;
        (c0 + (c1 - c0) * fz).max(0.0)
    }
}

/// A hint that `data[i]` will be read soon (no effect where the target has no prefetch, or
/// when `i` is out of range). Into the L2 (`_MM_HINT_T1`), not the L1: the march has many
/// more lines in flight than the L1's miss buffers hold, and prefetches into the L1 stalled
/// on them (docs/performance.md, "Prefetching into L2": 16.2 -> 9.8 CPU-s at 512^3).
#[inline(always)]
fn prefetch(data: &[f32], i: usize) {
    #[cfg(target_arch = "x86_64")]
    if let Some(v) = data.get(i) {
        use std::arch::x86_64::{_MM_HINT_T1, _mm_prefetch};
        // SAFETY: a prefetch never faults and reads nothing architecturally; the pointer is
        // a valid element of `data` anyway.
        unsafe { _mm_prefetch::<_MM_HINT_T1>((v as *const f32).cast::<i8>()) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (data, i);
}

impl Density for DenseGrid {
    fn bounds(&self) -> Aabb {
        self.bounds
    }

    #[inline]
    fn extinction(&self, p: DVec3) -> f32 {
        if self.inside(p) {
            self.sample_inside(p)
        } else {
            0.0
        }
    }

    fn max_extinction_in(&self, region: Aabb) -> f32 {
        let lo = region.min.max(self.bounds.min);
        let hi = region.max.min(self.bounds.max);
        // NaN regions fail these comparisons and report zero.
        if !(lo.cmple(hi).all()) {
            return 0.0;
        }
        // A voxel influences continuous indices within one voxel of its centre; take every
        // voxel whose influence touches [lo, hi], rounded outwards.
        let ulo = self.lattice.index_of(lo).floor();
        let uhi = self.lattice.index_of(hi).ceil();
        let clamp = |v: f64, n: u32| v.clamp(0.0, (n - 1) as f64) as usize;
        let (x0, x1) = (
            clamp(ulo.x, self.lattice.dims[0]),
            clamp(uhi.x, self.lattice.dims[0]),
        );
        let (y0, y1) = (
            clamp(ulo.y, self.lattice.dims[1]),
            clamp(uhi.y, self.lattice.dims[1]),
        );
        let (z0, z1) = (
            clamp(ulo.z, self.lattice.dims[2]),
            clamp(uhi.z, self.lattice.dims[2]),
        );
        let whole = x0 == 0
            && y0 == 0
            && z0 == 0
            && x1 + 1 == self.lattice.dims[0] as usize
            && y1 + 1 == self.lattice.dims[1] as usize
            && z1 + 1 == self.lattice.dims[2] as usize;
        if whole {
            return self.max_value;
        }
        let mut m = 0.0f32;
        for z in z0..=z1 {
            for y in y0..=y1 {
                let row = &self.data[y * self.stride_y + z * self.stride_z..];
                m = row[x0..=x1].iter().copied().fold(m, f32::max);
            }
        }
        m
    }
}

impl DensitySource for DenseGrid {
    fn describe(&self) -> String {
        let [x, y, z] = self.lattice.dims;
        format!("{} {x}x{y}x{z}", self.label)
    }
    fn extinction_along(&self, origin: DVec3, step: DVec3, n: usize, out: &mut [f32]) {
        for (i, o) in out.iter_mut().take(n).enumerate() {
            let p = origin + step * i as f64;
            *o = if self.inside(p) {
                self.sample_inside(p)
            } else {
                0.0
            };
        }
    }

    fn as_dense_grid(&self) -> Option<&DenseGrid> {
        Some(self)
    }

    fn occupied_bounds(&self) -> Option<Aabb> {
        Some(self.occupied)
    }

    fn voxel_size(&self) -> Option<DVec3> {
        Some(self.lattice.spacing)
    }
}

/// Asks Linux to back a large grid with 2 MiB pages. A bake's samples land all over the grid,
/// so with 4 KiB pages nearly every voxel load of a grid far larger than the TLB's reach
/// (a 512^3 grid is 512 MiB) also walks the page table; 2 MiB pages cut the bake's time
/// several-fold there. Best effort: the kernel may refuse (THP off, no contiguous memory)
/// and nothing changes but the speed.
fn advise_huge_pages(data: &[f32]) {
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        let start = data.as_ptr() as usize;
        let end = start + std::mem::size_of_val(data);
        let (lo, hi) = (start.next_multiple_of(HUGE), end / HUGE * HUGE);
        if hi >= lo + 16 * HUGE {
            // SAFETY: madvise only changes how the kernel backs these pages, which lie
            // inside `data`'s allocation (rounded inwards to whole huge pages); their contents
            // are kept. MADV_COLLAPSE (Linux 6.1) makes the change now rather than whenever
            // khugepaged gets to it; older kernels answer EINVAL, which is ignored.
            unsafe {
                libc::madvise(lo as *mut libc::c_void, hi - lo, libc::MADV_HUGEPAGE);
                libc::madvise(lo as *mut libc::c_void, hi - lo, libc::MADV_COLLAPSE);
            }
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = data;
}

/// Product of the dims as a `usize`, `None` on overflow.
pub(crate) fn voxel_count(dims: [u32; 3]) -> Option<usize> {
    (dims[0] as usize)
        .checked_mul(dims[1] as usize)?
        .checked_mul(dims[2] as usize)
}

/// Linear index to (x, y, z) for x-fastest layout.
pub(crate) fn unflatten(i: usize, dims: [u32; 3]) -> [usize; 3] {
    let nx = (dims[0] as usize).max(1);
    let ny = (dims[1] as usize).max(1);
    [i % nx, (i / nx) % ny, i / (nx * ny)]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(dims: [u32; 3]) -> DenseGrid {
        let mut data = Vec::new();
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    data.push((x + 10 * y + 100 * z) as f32);
                }
            }
        }
        DenseGrid::new(dims, data, DVec3::ONE, DVec3::ZERO, "test").unwrap()
    }

    #[test]
    fn voxel_centres_hit_exact_values() {
        let g = ramp([4, 3, 2]);
        for z in 0..2 {
            for y in 0..3 {
                for x in 0..4 {
                    let p = DVec3::new(x as f64 + 0.5, y as f64 + 0.5, z as f64 + 0.5);
                    assert_eq!(g.extinction(p), (x + 10 * y + 100 * z) as f32);
                }
            }
        }
    }

    #[test]
    fn trilinear_between_centres_and_clamped_in_outer_half_voxel() {
        let g = ramp([4, 3, 2]);
        // Halfway between x=1 and x=2 centres.
        assert!((g.extinction(DVec3::new(2.0, 0.5, 0.5)) - 1.5).abs() < 1e-6);
        // Outer half voxel repeats the edge value.
        assert_eq!(g.extinction(DVec3::new(0.1, 0.5, 0.5)), 0.0 + 0.0);
        assert_eq!(g.extinction(DVec3::new(3.9, 0.5, 0.5)), 3.0);
        assert_eq!(g.extinction(DVec3::new(4.0, 3.0, 2.0)), 3.0 + 20.0 + 100.0);
        // Outside the box: zero, NaN too.
        assert_eq!(g.extinction(DVec3::new(4.0001, 0.5, 0.5)), 0.0);
        assert_eq!(g.extinction(DVec3::new(-1e-9, 0.5, 0.5)), 0.0);
        assert_eq!(g.extinction(DVec3::new(f64::NAN, 0.5, 0.5)), 0.0);
    }

    #[test]
    fn spacing_and_origin_place_the_box() {
        let data = vec![1.0; 8];
        let g = DenseGrid::new(
            [2, 2, 2],
            data,
            DVec3::new(0.5, 1.0, 2.0),
            DVec3::new(-1.0, 0.0, 1.0),
            "t",
        )
        .unwrap();
        assert_eq!(g.bounds().min, DVec3::new(-1.0, 0.0, 1.0));
        assert_eq!(g.bounds().max, DVec3::new(0.0, 2.0, 5.0));
        assert_eq!(g.extinction(DVec3::new(-0.5, 1.0, 3.0)), 1.0);
    }

    #[test]
    fn one_voxel_and_anisotropic_grids() {
        let g = DenseGrid::new([1, 1, 1], vec![2.5], DVec3::ONE, DVec3::ZERO, "t").unwrap();
        assert_eq!(g.extinction(DVec3::splat(0.0)), 2.5);
        assert_eq!(g.extinction(DVec3::splat(1.0)), 2.5);
        assert_eq!(g.extinction(DVec3::splat(0.3)), 2.5);
        let g = ramp([1000, 1, 2]);
        assert_eq!(g.extinction(DVec3::new(999.5, 0.5, 1.5)), 1099.0);
    }

    #[test]
    fn rejects_bad_values() {
        assert!(DenseGrid::new([1, 1, 1], vec![-1.0], DVec3::ONE, DVec3::ZERO, "t").is_err());
        assert!(DenseGrid::new([1, 1, 1], vec![f32::NAN], DVec3::ONE, DVec3::ZERO, "t").is_err());
        assert!(DenseGrid::new([1, 1, 2], vec![0.0], DVec3::ONE, DVec3::ZERO, "t").is_err());
        assert!(DenseGrid::new([0, 1, 1], vec![], DVec3::ONE, DVec3::ZERO, "t").is_err());
        assert!(DenseGrid::new([1, 1, 1], vec![1.0], DVec3::ZERO, DVec3::ZERO, "t").is_err());
    }

    #[test]
    fn occupied_and_max_in_region() {
        let mut data = vec![0.0; 10 * 10 * 10];
        data[5 + 10 * (4 + 10 * 3)] = 7.0;
        let g = DenseGrid::new([10, 10, 10], data, DVec3::ONE, DVec3::ZERO, "t").unwrap();
        let o = g.occupied_bounds().unwrap();
        assert_eq!(o.min, DVec3::new(4.0, 3.0, 2.0));
        assert_eq!(o.max, DVec3::new(7.0, 6.0, 5.0));
        // Everything non-zero lies inside the occupied box.
        for i in 0..2000 {
            let p = DVec3::new(
                (i % 13) as f64 * 0.77,
                (i % 7) as f64 * 1.41,
                (i % 11) as f64 * 0.9,
            );
            if g.extinction(p) > 0.0 {
                assert!(p.cmpge(o.min).all() && p.cmple(o.max).all(), "{p}");
            }
        }
        // Regions that touch the voxel's support see it; ones that do not, do not.
        let r = |a: f64, b: f64| Aabb::new(DVec3::new(a, 4.5, 3.5), DVec3::new(b, 4.5, 3.5));
        assert_eq!(g.max_extinction_in(r(6.4, 6.45)), 7.0);
        assert_eq!(g.max_extinction_in(r(0.0, 4.0)), 0.0);
        assert!(g.extinction(DVec3::new(6.4, 4.5, 3.5)) > 0.0);
        assert_eq!(g.max_extinction_in(g.bounds()), 7.0);
        // Conservative: sampled max inside a region never exceeds the bound.
        for k in 0..50 {
            let a = k as f64 * 0.19;
            let reg = Aabb::new(DVec3::splat(a), DVec3::splat(a + 0.6));
            let bound = g.max_extinction_in(reg);
            for j in 0..=6 {
                let p = DVec3::splat(a + 0.1 * j as f64);
                assert!(g.extinction(p) <= bound);
            }
        }
        let empty = DenseGrid::new([2, 2, 2], vec![0.0; 8], DVec3::ONE, DVec3::ZERO, "t").unwrap();
        assert!(!empty.occupied_bounds().unwrap().is_valid());
    }

    #[test]
    fn march_runs_match_point_samples() {
        // Runs inside the box, touching its faces (clamp-to-edge), on grids with a one-voxel
        // axis too; more samples than one prefetch block.
        for dims in [[5u32, 6, 7], [9, 1, 4], [1, 1, 1]] {
            let g = ramp(dims);
            let ext = g.bounds().extent();
            let n = 57;
            let du_world = DVec3::new(0.012, 0.007, -0.011) * ext;
            let starts: Vec<DVec3> = (0..4)
                .map(|r| DVec3::new(0.05 + 0.08 * r as f64, 0.2, 0.95) * ext)
                .collect();
            let f = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32];
            let u0: Vec<[f32; 3]> = starts.iter().map(|p| f(g.index_of(*p))).collect();
            let mut sums = vec![0.0f64; 4];
            g.march_runs(&u0, f(g.index_dir(du_world)), n, &mut sums);
            for (r, p) in starts.iter().enumerate() {
                let want: f64 = (0..n)
                    .map(|j| f64::from(g.extinction(*p + du_world * j as f64)))
                    .sum();
                assert!(
                    (sums[r] - want).abs() <= 1e-5 * want.max(1.0),
                    "{dims:?} run {r}: {} vs {want}",
                    sums[r]
                );
            }
        }
        // Indices far outside or NaN clamp instead of reading out of bounds.
        let g = ramp([3, 3, 3]);
        let mut s = [0.0];
        g.march_runs(
            &[[f32::NAN, 1e30, -1e30]],
            [1e20, f32::NAN, 0.0],
            300,
            &mut s,
        );
        assert!(s[0].is_finite());
    }

    #[test]
    fn runs_in_lanes_are_the_runs_one_by_one_to_the_bit() {
        // Groups of 8 runs (and a remainder of 3) on grids with detail at every voxel and
        // with one-voxel axes; starts inside, on the faces, far outside and NaN; more samples
        // than one block of the lanes. Where AVX2 is absent both sides are the same code.
        let mut seed = 7u64;
        let mut next = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 40) as f32 / (1u64 << 24) as f32
        };
        for dims in [[23u32, 17, 29], [9, 1, 4], [1, 1, 1], [2, 2, 2]] {
            let n_vox = (dims[0] * dims[1] * dims[2]) as usize;
            let data: Vec<f32> = (0..n_vox)
                .map(|i| ((i * 7919) % 97) as f32 / 13.0)
                .collect();
            let g = DenseGrid::new(dims, data, DVec3::ONE, DVec3::ZERO, "t").unwrap();
            let top = dims.map(|d| d as f32);
            let mut u0: Vec<[f32; 3]> = (0..19)
                .map(|_| [next() * top[0], next() * top[1], next() * top[2]])
                .collect();
            u0.extend([
                [0.0, 0.0, 0.0],
                top,
                [-3.0, top[1] + 5.0, 0.5],
                [f32::NAN, 1.0, 1.0],
                [1e30, -1e30, f32::NAN],
            ]);
            for du in [
                [0.013f32, -0.021, 0.37],
                [0.0, 0.0, 0.0],
                [-0.5, 0.25, 1e-7],
            ] {
                for n in [1, 16, 17, 57] {
                    let mut lanes = vec![0.25f64; u0.len()];
                    let mut one = lanes.clone();
                    g.march_runs(&u0, du, n, &mut lanes);
                    g.march_runs_one_by_one(&u0, du, n, &mut one);
                    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&lanes), bits(&one), "{dims:?} {du:?} {n}");
                }
            }
        }
    }

    #[test]
    fn batched_matches_single() {
        let g = ramp([5, 6, 7]);
        let mut out = vec![0.0; 40];
        let o = DVec3::new(-0.3, 0.2, 0.1);
        let s = DVec3::new(0.17, 0.19, 0.23);
        g.extinction_along(o, s, 40, &mut out);
        for (i, v) in out.iter().enumerate() {
            assert_eq!(*v, g.extinction(o + s * i as f64));
        }
    }
}
