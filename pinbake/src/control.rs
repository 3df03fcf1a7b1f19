//! The control section (format 1.1, docs/format.md section 5.8): per brick of a grid over the
//! bake's box, a control extinction `c`, a residual majorant `m` and a majorant `M`, which
//! residual ratio tracking reads (`pinrender`'s `pinres`, docs/final-frames.md).
//!
//! Built from the full-resolution source, brick by brick: `M` is the source's own bound
//! ([`Density::max_extinction_in`]), and a brick it bounds by zero is empty (`c = m = M =
//! 0`, the only brick with `m = 0`). Elsewhere a midpoint lattice of `lattice^3` points gives
//! `c`, the mean of the extinction weighted by `exp(-2 thickness sigma edge)` (a brick that is
//! optically thick weighs its thin parts, where a ray keeps its transmittance, the most), and
//! `m = floor` times the largest residual `max(M - c, c - least sample)`. Any `c` and any
//! `m > 0` give an unbiased estimator; these set its variance. The rule and its constants were
//! chosen by measurement (docs/final-frames.md): bricks of 4 voxels, `thickness` 1, `floor` 1.

use glam::DVec3;
use pin_format::OwnedControl;
use rayon::prelude::*;

use crate::alloc::try_filled;
use crate::error::BakeError;
use pin_volume::{Aabb, DensitySource};

/// The least source voxels per brick edge of the default control grid ([`ControlDims::Auto`]).
pub const DEFAULT_CONTROL_EDGE: u32 = 4;
/// Bricks along the longest axis that the default control grid aims for: a volume with more
/// than `4 x 64` voxels along it gets bricks of more than 4 voxels ([`auto_control_edge`]).
pub const CONTROL_BRICKS_LONGEST: u32 = 64;
/// The largest brick edge, in source voxels.
pub const MAX_CONTROL_EDGE: u32 = 64;
/// Most bricks of a control grid: 2^21 (128^3), 48 MiB while it is built and about 20 s of
/// sampling at 4^3 lattice points per brick. An analytic field has 256 voxels along its
/// longest axis, so `--embed-control 1` asks for 256^3 bricks there, which ran for 170 s;
/// such a grid is refused before the bake starts ([`check_control`]), naming the smallest
/// brick edge that fits. The default edge stays far below it (about 64 bricks along the
/// longest axis).
pub const MAX_CONTROL_BRICKS: u64 = 1 << 21;

/// How many bricks the control grid has.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ControlDims {
    /// The default: bricks of [`auto_control_edge`] source voxels per edge, which grows with
    /// the volume's resolution so that a ray crosses about as many bricks in any volume.
    Auto,
    /// Bricks of this many source voxels per edge (the voxel size of
    /// [`crate::sparse_density::sparse_dims`]: the source's own, or the box over 256 for an
    /// analytic field).
    Edge(u32),
    /// Exactly these bricks per axis.
    Exact([u32; 3]),
}

/// The rule that turns a brick's samples into its control and residual majorant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlOptions {
    pub dims: ControlDims,
    /// Midpoint lattice points per brick edge.
    pub lattice: u32,
    /// The weights `exp(-2 thickness sigma edge)`; 0 makes `c` the plain mean.
    pub thickness: f64,
    /// `m = floor max(M - c, c - least sample)`, in `(0, 1]`: with 1, every weight
    /// `1 - (sigma - c) / m` of a sampled extinction lies in `[0, 2]`; below 1 the weights
    /// may leave it (fewer lookups, more variance).
    pub floor: f64,
}

impl Default for ControlOptions {
    fn default() -> Self {
        Self {
            dims: ControlDims::Auto,
            lattice: 4,
            thickness: 1.0,
            floor: 1.0,
        }
    }
}

/// The brick dims of `opts` over `bbox` of `source`.
pub fn control_dims(
    source: &dyn DensitySource,
    bbox: &Aabb,
    opts: &ControlOptions,
) -> Result<[u32; 3], BakeError> {
    let voxels = || Ok::<_, BakeError>(box_voxels(source, bbox));
    let dims = match opts.dims {
        ControlDims::Exact(d) => d,
        ControlDims::Edge(0) => {
            return Err(BakeError::Options(
                "control brick edge must be at least 1 voxel".into(),
            ));
        }
        ControlDims::Edge(edge) => voxels()?.map(|v| v.div_ceil(edge)),
        ControlDims::Auto => {
            let voxels = voxels()?;
            let edge = auto_control_edge(voxels);
            voxels.map(|v| v.div_ceil(edge))
        }
    };
    let n = bricks(dims);
    if !dims.contains(&0) && n <= MAX_CONTROL_BRICKS {
        return Ok(dims);
    }
    let [x, y, z] = dims;
    let hint = match opts.dims {
        ControlDims::Exact(_) => String::new(),
        _ => {
            let v = box_voxels(source, bbox);
            match (1..=MAX_CONTROL_EDGE)
                .find(|&e| bricks(v.map(|d| d.div_ceil(e))) <= MAX_CONTROL_BRICKS)
            {
                Some(e) => format!("; a brick edge of at least {e} voxels fits"),
                None => String::new(),
            }
        }
    };
    Err(BakeError::Options(format!(
        "the control grid would have {x}x{y}x{z} bricks, more than the {MAX_CONTROL_BRICKS} (128^3) a bake builds{hint}"
    )))
}

/// Bricks of a grid of `dims` (saturating).
fn bricks(dims: [u32; 3]) -> u64 {
    dims.iter()
        .fold(1u64, |acc, &d| acc.saturating_mul(u64::from(d)))
}

/// The source voxels `bbox` spans per axis (at least 1): the source's voxel size, or the box
/// over [`crate::sparse_density::ANALYTIC_VOXELS`] for an analytic field, as the sparse
/// density counts them, but without that section's per-axis limit: a control grid of a
/// 1x1x100000 volume has 1x1x1563 bricks of 64 voxels, within its own bound.
fn box_voxels(source: &dyn DensitySource, bbox: &Aabb) -> [u32; 3] {
    let e = bbox.extent();
    let voxel = source
        .voxel_size()
        .filter(|v| v.is_finite() && v.cmpgt(DVec3::ZERO).all())
        .unwrap_or(DVec3::splat(
            e.max_element() / f64::from(crate::sparse_density::ANALYTIC_VOXELS),
        ));
    // A box cropped to whole voxels gives integers up to rounding: no voxel for the rounding.
    (e / voxel)
        .to_array()
        .map(|v| ((v - 1e-6).ceil().max(1.0)).min(f64::from(u32::MAX)) as u32)
}

/// The control grid a bake of `source` with `opts` would build, checked before the bake
/// starts (its brick count, [`MAX_CONTROL_BRICKS`]): the bake computes it only after the
/// pins, minutes in.
pub fn check_control(
    source: &dyn DensitySource,
    crop: bool,
    opts: &ControlOptions,
) -> Result<[u32; 3], BakeError> {
    let frame = source.bake_frame();
    let local: &dyn DensitySource = frame.as_ref().map_or(source, |(l, _)| l.as_ref());
    let (bbox, _) = crate::placement::bake_box(local, crop)?;
    control_dims(local, &bbox, opts)
}

/// The brick edge of the default control grid for a bake box of `voxels` source voxels:
/// [`DEFAULT_CONTROL_EDGE`] voxels, or coarser so that the longest axis has about
/// [`CONTROL_BRICKS_LONGEST`] bricks. Measured (docs/final-frames.md, "The resolution"): a
/// shadow ray pays one DDA step per brick it crosses, so the best edge per CPU second was 4
/// voxels on volumes of 128 to 256 voxels per axis and 16 or more on a 1225-voxel cloud,
/// where 4-voxel bricks made every query 9 times slower.
pub fn auto_control_edge(voxels: [u32; 3]) -> u32 {
    let longest = voxels.iter().copied().max().unwrap_or(1);
    longest
        .div_ceil(CONTROL_BRICKS_LONGEST)
        .clamp(DEFAULT_CONTROL_EDGE, MAX_CONTROL_EDGE)
}

/// The control section of `source` over `bbox`.
pub fn bake_control(
    source: &dyn DensitySource,
    bbox: &Aabb,
    opts: &ControlOptions,
) -> Result<OwnedControl, BakeError> {
    bake_control_cancellable(source, bbox, opts, &|| false)
}

/// [`bake_control`], polling `cancelled` between bricks: once it answers true the remaining
/// bricks are skipped and the result is [`BakeError::Cancelled`].
pub fn bake_control_cancellable(
    source: &dyn DensitySource,
    bbox: &Aabb,
    opts: &ControlOptions,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Result<OwnedControl, BakeError> {
    if !(opts.lattice >= 1
        && opts.thickness >= 0.0
        && opts.thickness.is_finite()
        && opts.floor > 0.0
        && opts.floor <= 1.0)
    {
        return Err(BakeError::Options(format!(
            "control options {opts:?}: lattice >= 1, thickness >= 0, floor in (0, 1]"
        )));
    }
    let dims = control_dims(source, bbox, opts)?;
    let n = dims.iter().map(|&d| d as usize).product::<usize>();
    let mut bricks = try_filled("the control grid", n, [0.0f32; 3])?;
    let e = bbox.extent();
    let size = DVec3::new(
        e.x / f64::from(dims[0]),
        e.y / f64::from(dims[1]),
        e.z / f64::from(dims[2]),
    );
    let edge = (size.x * size.y * size.z).cbrt();
    bricks.par_iter_mut().enumerate().for_each(|(i, out)| {
        if cancelled() {
            return;
        }
        let (nx, ny) = (dims[0] as usize, dims[1] as usize);
        let c = [i % nx, (i / nx) % ny, i / (nx * ny)].map(|v| v as f64);
        let lo = bbox.min + DVec3::new(c[0], c[1], c[2]) * size;
        let region = Aabb::new(lo, lo + size);
        *out = brick_control(source, region, edge, opts);
    });
    if cancelled() {
        return Err(BakeError::Cancelled);
    }
    let mut out = OwnedControl {
        dims,
        control: Vec::with_capacity(n),
        residual: Vec::with_capacity(n),
        majorant: Vec::with_capacity(n),
    };
    for [c, m, mx] in bricks {
        out.control.push(c);
        out.residual.push(m);
        out.majorant.push(mx);
    }
    Ok(out)
}

/// `[c, m, M]` of one brick (see the module's documentation).
fn brick_control(
    source: &dyn DensitySource,
    region: Aabb,
    edge: f64,
    o: &ControlOptions,
) -> [f32; 3] {
    let big = source.max_extinction_in(region);
    if !(big > 0.0) {
        return [0.0; 3];
    }
    let big = big.min(f32::MAX);
    let k = o.lattice;
    let e = region.extent();
    let mut samples = Vec::with_capacity((k * k * k) as usize);
    for z in 0..k {
        for y in 0..k {
            for x in 0..k {
                let f = |i: u32| (f64::from(i) + 0.5) / f64::from(k);
                let p = region.min + DVec3::new(f(x), f(y), f(z)) * e;
                let s = source.extinction(p);
                samples.push(if s > 0.0 { f64::from(s.min(big)) } else { 0.0 });
            }
        }
    }
    let w = |s: f64| (-2.0 * o.thickness * s * edge).exp();
    let (mut sw, mut sws) = (0.0, 0.0);
    for &s in &samples {
        sw += w(s);
        sws += w(s) * s;
    }
    // All weights underflow only in a brick that is opaque everywhere sampled: its least.
    let c = if sw > 0.0 {
        sws / sw
    } else {
        samples.iter().copied().fold(f64::INFINITY, f64::min)
    };
    let c = (c.min(f64::from(big)) as f32).max(0.0);
    let least = samples.iter().copied().fold(f64::INFINITY, f64::min);
    let c64 = f64::from(c);
    let spread = (f64::from(big) - c64)
        .max(c64 - least)
        .max(1e-3 * f64::from(big));
    let m = o.floor * spread;
    [c, (m as f32).clamp(f32::MIN_POSITIVE, f32::MAX), big]
}

#[cfg(test)]
mod tests {
    use super::*;
    use pin_volume::ProceduralSpec;

    fn sphere() -> Box<dyn DensitySource> {
        "sphere:radius=0.3,density=3"
            .parse::<ProceduralSpec>()
            .unwrap()
            .build(pin_volume::DensityScale::ONE)
            .unwrap()
    }

    /// The section keeps its rules (what verify checks) on a sphere whose corners are empty,
    /// empty bricks are exactly the ones the source bounds by zero, and the bytes do not
    /// depend on the thread count.
    #[test]
    fn control_is_valid_empty_where_bounded_by_zero_and_deterministic() {
        let src = sphere();
        let bbox = src.bounds();
        let opts = ControlOptions {
            dims: ControlDims::Exact([9, 7, 8]),
            ..ControlOptions::default()
        };
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| bake_control(&*src, &bbox, &opts).unwrap())
        };
        let c = run(1);
        assert_eq!(c, run(3));
        let bytes = c.to_bytes().unwrap();
        pin_format::ControlView::parse(&bytes)
            .unwrap()
            .check_values()
            .unwrap();
        let mut empty = 0;
        for i in 0..c.control.len() {
            assert_eq!(c.residual[i] == 0.0, c.majorant[i] == 0.0, "brick {i}");
            empty += usize::from(c.majorant[i] == 0.0);
        }
        assert!(empty > 0 && empty < c.control.len());
    }

    /// The default edge keeps 4 voxels up to 256 along the longest axis, then aims at 64
    /// bricks along it, within 4..=64 voxels.
    #[test]
    fn auto_edge_grows_with_the_longest_axis() {
        for (voxels, edge) in [
            ([1, 1, 1], 4),
            ([112, 223, 113], 4),
            ([256, 256, 256], 4),
            ([257, 10, 10], 5),
            ([992, 674, 1225], 20),
            ([1790, 1216, 2210], 35),
            ([5000, 5000, 100_000], 64),
        ] {
            assert_eq!(auto_control_edge(voxels), edge, "{voxels:?}");
        }
        let src = sphere();
        let bbox = src.bounds();
        let auto = control_dims(&*src, &bbox, &ControlOptions::default()).unwrap();
        let four = ControlOptions {
            dims: ControlDims::Edge(DEFAULT_CONTROL_EDGE),
            ..ControlOptions::default()
        };
        assert_eq!(auto, control_dims(&*src, &bbox, &four).unwrap());
    }

    /// Bad options are errors, not panics: an edge of 0, a floor outside (0, 1], a negative
    /// thickness, and more bricks than the limit.
    #[test]
    fn bad_control_options_are_errors() {
        let src = sphere();
        let bbox = src.bounds();
        for opts in [
            ControlOptions {
                dims: ControlDims::Edge(0),
                ..ControlOptions::default()
            },
            ControlOptions {
                floor: 0.0,
                ..ControlOptions::default()
            },
            ControlOptions {
                floor: 1.5,
                ..ControlOptions::default()
            },
            ControlOptions {
                thickness: -1.0,
                ..ControlOptions::default()
            },
            ControlOptions {
                dims: ControlDims::Exact([1 << 10, 1 << 10, 1 << 8]),
                ..ControlOptions::default()
            },
        ] {
            assert!(bake_control(&*src, &bbox, &opts).is_err(), "{opts:?}");
        }
    }
}
