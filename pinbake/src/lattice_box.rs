//! The bake box on the source's own voxel lattice, for an embedded density that holds the
//! source's voxels.
//!
//! The pin format places an embedded density's voxels over the grid box (centres at
//! `box_min + (i + 0.5) * extent / dims`). A VDB's cropped box runs from the centre of the
//! zero voxel below its lowest stored voxel to the centre of the one above its highest (the
//! reach of its trilinear field): `n + 1` voxels wide for `n` stored, so that no voxel count
//! over it puts the embedded centres on the source's, and the file's field is a resampling of
//! the source's (1.9% 8x8-block error on a 23x10x23 fog VDB, against 0.18% from the VDB).
//! [`LatticeBox`] grows the box outward to whole voxels of the source's lattice, and to a
//! whole number of `factor`-voxel blocks, so that a density of `voxels / factor` per axis has
//! its centres on the source's (factor 1) or each of its voxels covering exactly `factor^3`
//! source voxels (the box filter's blocks). The added rim holds zeros, which the format's
//! trilinear field reads as the source's own fall-off to zero.

use glam::DVec3;

use crate::embed_density::{MAX_DENSE_DIM, MAX_VOXELS_FACTOR};

use pin_volume::{
    Aabb, DenseGrid, DenseLattice, DenseView, Density, DensitySource, Footprint, part_facts,
};

/// A source whose crop box ([`DensitySource::occupied_bounds`]) is its own grown outward to
/// the source's voxel lattice, in blocks of `factor` voxels per axis; everything else is the
/// source's.
pub struct LatticeBox<'a> {
    inner: Inner<'a>,
    bounds: Aabb,
    occupied: Aabb,
    voxels: [u32; 3],
    /// The grown box lies inside the source's own box, and inside the box of the dense grid
    /// it is or copies ([`DensitySource::as_dense_grid`], [`DensitySource::dense_copy`]), so
    /// that a bake may march that grid: a dense grid reads its edge voxel, not zero, in its
    /// outer half voxel, so a box reaching past it must be read through `extinction`.
    dense_inside: bool,
}

/// The source, borrowed (to weigh a choice) or owned (to bake it).
enum Inner<'a> {
    Borrowed(&'a dyn DensitySource),
    Owned(Box<dyn DensitySource + 'a>),
}

/// The lattice of a voxel source: the origin of its voxel boundaries and the voxel size (a
/// dense grid's own, a VDB's dense copy's) and the box that lattice covers, or `None` for an
/// analytic field, a rotated grid (baked in its own frame) or a grid too large to place.
pub fn source_lattice(source: &dyn DensitySource) -> Option<(DVec3, DVec3, Aabb)> {
    if source.bake_frame().is_some() {
        return None;
    }
    let l: DenseLattice = match source.as_dense_grid() {
        Some(g) => g.lattice(),
        None => source.dense_lattice()?,
    };
    let far =
        l.origin + DVec3::new(l.dims[0] as f64, l.dims[1] as f64, l.dims[2] as f64) * l.spacing;
    (l.spacing.is_finite() && l.spacing.cmpgt(DVec3::ZERO).all() && l.origin.is_finite())
        .then_some((l.origin, l.spacing, Aabb::new(l.origin, far)))
}

/// The whole factor `F` at which a dense count of `dims` voxels per axis names the source's
/// own resolution over its bake box (`crop`), `None` where it names none (or the source has no
/// lattice, [`source_lattice`]): the smallest `F` (1..=[`MAX_VOXELS_FACTOR`]) for which every
/// axis's count lies between the source's voxels whose centres lie inside the box and the
/// voxels of the box grown to its lattice ([`LatticeBox`], the rim of zeros included), each
/// divided by `F` and rounded up, and the grown box's dims fit the dense section (4096 per
/// axis). A VDB of `n` stored voxels along an axis thus names its resolution with `n`
/// (`23,10,23` for a 23x10x23 fog VDB) or with the `n + 2` of its lattice box, a dense grid
/// with its own dims: either way the section holds the lattice box's voxels, the source's
/// own (or their box averages over whole blocks of `F`), not a resampling over the box.
pub fn dims_factor(source: &dyn DensitySource, crop: bool, dims: [u32; 3]) -> Option<u32> {
    let (origin, spacing, _) = source_lattice(source)?;
    let (b, _) = crate::placement::bake_box(source, crop).ok()?;
    // Source voxel centres strictly inside the box (a VDB's box ends on the centres of the
    // zero voxels beside its stored ones).
    let first = ((b.min - origin) / spacing - 0.5 + 1e-6).floor() + DVec3::ONE;
    let last = ((b.max - origin) / spacing - 0.5 - 1e-6).ceil() - DVec3::ONE;
    let inside = (last - first + DVec3::ONE).max(DVec3::ONE);
    let (_, _, grown, _) = LatticeBox::grown(source, crop, 1)?;
    if !inside.is_finite() || inside.max_element() > f64::from(u32::MAX) {
        return None;
    }
    let inside = [inside.x as u32, inside.y as u32, inside.z as u32];
    (1..=MAX_VOXELS_FACTOR).find(|&f| {
        (0..3).all(|a| {
            let top = grown[a].div_ceil(f);
            (inside[a].div_ceil(f)..=top).contains(&dims[a]) && top <= MAX_DENSE_DIM
        })
    })
}

impl<'a> LatticeBox<'a> {
    /// `inner` with its crop box (`crop`) or its full box grown to its lattice in blocks of
    /// `factor` voxels; `None` where the source has no lattice ([`source_lattice`]).
    pub fn new(inner: &'a dyn DensitySource, crop: bool, factor: u32) -> Option<Self> {
        Self::of(Inner::Borrowed(inner), crop, factor).ok()
    }

    /// [`Self::new`] owning the source; the source back where it has no lattice.
    pub fn owning(
        inner: Box<dyn DensitySource + 'a>,
        crop: bool,
        factor: u32,
    ) -> Result<Self, Box<dyn DensitySource + 'a>> {
        Self::of(Inner::Owned(inner), crop, factor).map_err(|i| match i {
            Inner::Owned(b) => b,
            Inner::Borrowed(_) => unreachable!("an owned source comes back owned"),
        })
    }

    fn of(inner: Inner<'a>, crop: bool, factor: u32) -> Result<Self, Inner<'a>> {
        match Self::grown(inner.get(), crop, factor) {
            Some((bounds, occupied, voxels, dense_inside)) => Ok(Self {
                inner,
                bounds,
                occupied,
                voxels,
                dense_inside,
            }),
            None => Err(inner),
        }
    }

    /// The source's bounds, the grown box, its voxels and whether it lies inside the dense
    /// grid's box.
    fn grown(
        inner: &dyn DensitySource,
        crop: bool,
        factor: u32,
    ) -> Option<(Aabb, Aabb, [u32; 3], bool)> {
        let (origin, spacing, lattice_box) = source_lattice(inner)?;
        let (b, _) = crate::placement::bake_box(inner, crop).ok()?;
        let f = f64::from(factor.max(1));
        // Index of the lattice boundary at or below min (above max), with a tolerance for a
        // box that is already on the lattice up to rounding.
        let lo = ((b.min - origin) / spacing + 1e-6).floor();
        let hi = ((b.max - origin) / spacing - 1e-6).ceil();
        let n = (hi - lo).max(DVec3::ONE);
        // Whole blocks: the extra voxels go above the box.
        let n = (n / f).ceil() * f;
        if !(n.is_finite() && n.max_element() <= f64::from(u32::MAX)) {
            return None;
        }
        let min = origin + lo * spacing;
        let occupied = Aabb::new(min, min + n * spacing);
        if !occupied.is_valid() {
            return None;
        }
        let bounds = Aabb::new(
            inner.bounds().min.min(occupied.min),
            inner.bounds().max.max(occupied.max),
        );
        let tol = spacing * 1e-6;
        let inside = |outer: Aabb| {
            (occupied.min + tol).cmpge(outer.min).all()
                && (occupied.max - tol).cmple(outer.max).all()
        };
        let dense_inside =
            inside(lattice_box) && (inner.as_dense_grid().is_none() || inside(inner.bounds()));
        Some((
            bounds,
            occupied,
            [n.x as u32, n.y as u32, n.z as u32],
            dense_inside,
        ))
    }

    /// The source's voxels the grown box spans per axis (a multiple of `factor`).
    pub fn voxels(&self) -> [u32; 3] {
        self.voxels
    }

    /// The grown box.
    pub fn bake_box(&self) -> Aabb {
        self.occupied
    }
}

impl Inner<'_> {
    fn get(&self) -> &dyn DensitySource {
        match self {
            Inner::Borrowed(s) => *s,
            Inner::Owned(s) => s.as_ref(),
        }
    }
}

impl Density for LatticeBox<'_> {
    fn bounds(&self) -> Aabb {
        self.bounds
    }
    fn extinction(&self, p: DVec3) -> f32 {
        self.inner.get().extinction(p)
    }
    fn max_extinction_in(&self, region: Aabb) -> f32 {
        self.inner.get().max_extinction_in(region)
    }
    fn min_extinction_in(&self, region: Aabb) -> Option<f32> {
        self.inner.get().min_extinction_in(region)
    }
    fn dense_view(&self) -> Option<DenseView<'_>> {
        // The view answers for the source's box; this one may be larger.
        (self.bounds == self.inner.get().bounds())
            .then(|| self.inner.get().dense_view())
            .flatten()
    }
}

impl DensitySource for LatticeBox<'_> {
    fn describe(&self) -> String {
        self.inner.get().describe()
    }
    fn extinction_along(&self, origin: DVec3, step: DVec3, n: usize, out: &mut [f32]) {
        self.inner.get().extinction_along(origin, step, n, out)
    }
    fn occupied_bounds(&self) -> Option<Aabb> {
        Some(self.occupied)
    }
    fn voxel_size(&self) -> Option<DVec3> {
        self.inner.get().voxel_size()
    }
    fn solid_boxes(&self, floor: f32) -> Vec<Aabb> {
        self.inner.get().solid_boxes(floor)
    }
    // No bake frame: a source with one has no lattice here (`source_lattice`).
    fn part_slab(&self) -> Option<[f64; 2]> {
        self.inner.get().part_slab()
    }
    fn part_facts(&self) -> Option<part_facts::PartFacts> {
        self.inner.get().part_facts()
    }
    fn as_dense_grid(&self) -> Option<&DenseGrid> {
        if !self.dense_inside {
            return None;
        }
        self.inner.get().as_dense_grid()
    }
    fn dense_copy(&self, max_bytes: u64) -> Option<DenseGrid> {
        if !self.dense_inside {
            return None;
        }
        self.inner.get().dense_copy(max_bytes)
    }
    fn dense_lattice(&self) -> Option<DenseLattice> {
        if !self.dense_inside {
            return None;
        }
        self.inner.get().dense_lattice()
    }
    fn dense_planes(&self, z_begin: u32, z_end: u32) -> Option<Vec<f32>> {
        if !self.dense_inside {
            return None;
        }
        self.inner.get().dense_planes(z_begin, z_end)
    }
    fn footprint(&self) -> Option<Footprint> {
        self.inner.get().footprint()
    }
    fn dense_copy_size(&self) -> Option<u64> {
        if !self.dense_inside {
            return None;
        }
        self.inner.get().dense_copy_size()
    }
}
