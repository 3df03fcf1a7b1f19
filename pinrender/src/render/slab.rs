//! The ray/box slab test, a leaf under the media's boxes (`bounds.rs`) and their hierarchy
//! (`bvh.rs`): the chunk of boxes tested at once, the miss value, a ray prepared for many
//! tests and the test of one box.

use glam::Vec3;

/// Boxes tested per call of [`super::bounds::MediaBoxes::entries`] (the tracer's stack buffer).
pub(crate) const CHUNK: usize = 64;

/// [`super::bounds::MediaBoxes::entries`]' value for a box the segment misses.
pub(crate) const MISS: f32 = f32::INFINITY;

/// Where the segment `[0, t_max]` of `ray` enters the box `[lo, hi]` (0 if it starts
/// inside), or [`MISS`]: the body of [`super::bounds::MediaBoxes::entries`]' loop.
#[inline(always)]
pub(crate) fn slab_entry(lo: [f32; 3], hi: [f32; 3], ray: &RaySlabs, t_max: f32) -> f32 {
    let mut t_near = 0.0f32;
    let mut t_far = t_max;
    for a in 0..3 {
        // Slab axes: the usual parameters. Parallel axes (inv = +-inf): -inf/+inf inside the
        // slab, both +inf (or both -inf) outside it: a miss. NaN arises only as `0 * inf`,
        // an origin exactly on a padded face of a parallel slab, i.e. outside the
        // estimator's own box, where either answer is right. The compare-and-select min/max
        // (x86 minps/maxps) keep the loop vectorised.
        let t0 = (lo[a] - ray.o[a]) * ray.inv[a];
        let t1 = (hi[a] - ray.o[a]) * ray.inv[a];
        let (near, far) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
        t_near = if near > t_near { near } else { t_near };
        t_far = if far < t_far { far } else { t_far };
    }
    if t_near <= t_far && t_near < MISS {
        t_near
    } else {
        MISS
    }
}

/// A ray prepared for many box tests: origin and per-axis reciprocal direction (`+-inf` on
/// a parallel axis).
#[derive(Clone, Copy, Debug)]
pub(crate) struct RaySlabs {
    o: [f32; 3],
    inv: [f32; 3],
}

impl RaySlabs {
    /// `None` for a ray the test cannot reason about (non-finite origin or direction, zero
    /// direction): the caller then asks every medium, whose estimators treat such rays
    /// themselves.
    #[inline]
    pub(crate) fn new(o: Vec3, d: Vec3) -> Option<Self> {
        if !(o.is_finite() && d.is_finite()) || d == Vec3::ZERO {
            return None;
        }
        // 1 / +-0 is +-inf; 1 / subnormal overflows to +-inf: both parallel.
        let inv = d.to_array().map(|c| 1.0 / c);
        Some(RaySlabs {
            o: o.to_array(),
            inv,
        })
    }
}
