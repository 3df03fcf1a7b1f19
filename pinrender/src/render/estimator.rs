//! Free-flight distance sampling and transmittance estimation behind one trait.

use super::error::RenderError;
use super::majorant::{MajorantGrid, MajorantSegment, check_box, clip_box};
use super::rng::Pcg32;
use glam::{DVec3, Vec3};
use pin_volume::{Aabb, DenseView, Density};
use std::sync::Arc;

/// A distance sampler and transmittance estimator for one medium (one instance).
///
/// Rays are `o + t d`; `t` is measured in units of `|d|` (world distance for unit `d`, which
/// the renderer always passes), and both queries consider `t` in `[0, t_max]` (`t_max` may be
/// `+inf`: to the medium's exit). Invalid rays (non-finite `o` or `d`, zero `d`, NaN or
/// non-positive `t_max`) give transmittance 1 and no collision: the medium is skipped, never
/// a panic or a NaN.
///
/// Object safe: the renderer holds `Arc<dyn TransportEstimator>`. An estimator with its own
/// generator (the pin sampler) can seed it per query with `rng.next_u64()`.
pub trait TransportEstimator: Send + Sync {
    /// A collision distance `t < t_max` distributed (for exact estimators) with density
    /// `sigma_t(t) exp(-tau(0, t))`, or `None` (probability `exp(-tau(0, t_max))`).
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32>;
    /// An estimate of `exp(-tau(0, t_max))` (unbiased for the trackers; ray marching is
    /// deterministic and biased by its quadrature).
    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32;
    /// A short label for reports, e.g. `delta-tracking(16x16x16)`.
    fn name(&self) -> String;
    /// A closed world box `(min, max)` outside which this medium has no extinction, or
    /// `None` (the default: unbounded, or unknown).
    ///
    /// The renderer skips the estimator for every query whose segment `[0, t_max]` cannot
    /// meet the box (see `render/bounds.rs`; the box is padded outward first), so an
    /// estimator that returns `Some` must give transmittance 1 and no collision, in
    /// distribution, for such queries. It need not draw the same random numbers: skipping
    /// changes the stream of later queries, not their distribution. With many media (e.g.
    /// instances) this is what keeps a query from paying for every medium it misses.
    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        None
    }

    /// This estimator as `Any`, for a loop that answers some estimator types together (the
    /// wavefront loop answers the queries of several media that share one pin grid in one
    /// batch); `None`, the default, leaves it out of such batches.
    fn as_any(&self) -> Option<&dyn std::any::Any> {
        None
    }

    /// Both queries of one ray: a transmittance estimate over `[0, t_max]` and a sampled
    /// collision, as `(transmittance, distance)`. Each is distributed as from its own method,
    /// but an estimator may take both from shared work (one pin lookup, one majorant walk),
    /// which correlates them. The path tracer asks this where it needs both along one ray
    /// (a camera ray; a vertex's environment ray, along which the path then continues): a
    /// path's score is a sum of the two queries' terms, so its expectation is unchanged.
    /// The default asks [`Self::transmittance`], then [`Self::sample_distance`], with the
    /// same generator: the numbers of two separate queries.
    fn transmittance_and_distance(
        &self,
        o: Vec3,
        d: Vec3,
        t_max: f32,
        rng: &mut Pcg32,
    ) -> (f32, Option<f32>) {
        let t = self.transmittance(o, d, t_max, rng);
        (t, self.sample_distance(o, d, t_max, rng))
    }

    /// [`Self::transmittance_and_distance`] of many rays, as [`Self::transmittance_batch`].
    fn transmittance_and_distance_batch(
        &self,
        rays: &[[Vec3; 2]],
        t_max: f32,
        rngs: &mut [Pcg32],
        out: &mut [(f32, Option<f32>)],
    ) {
        for ((r, rng), o) in rays.iter().zip(rngs.iter_mut()).zip(out.iter_mut()) {
            *o = self.transmittance_and_distance(r[0], r[1], t_max, rng);
        }
    }

    /// Transmittance estimates of many rays `rays[i] = [o, d]` over `[0, t_max]`, ray `i`
    /// drawing from `rngs[i]`: what [`Self::transmittance`] returns for each ray and its
    /// generator, and the generators left as it leaves them (the wavefront renderer relies
    /// on it for images that do not depend on the batch size). The default asks one ray at
    /// a time; an estimator with a batched lookup (pins) overrides it.
    fn transmittance_batch(
        &self,
        rays: &[[Vec3; 2]],
        t_max: f32,
        rngs: &mut [Pcg32],
        out: &mut [f32],
    ) {
        for ((r, rng), o) in rays.iter().zip(rngs.iter_mut()).zip(out.iter_mut()) {
            *o = self.transmittance(r[0], r[1], t_max, rng);
        }
    }

    /// Sampled distances of many rays, as [`Self::transmittance_batch`] for
    /// [`Self::sample_distance`].
    fn sample_distance_batch(
        &self,
        rays: &[[Vec3; 2]],
        t_max: f32,
        rngs: &mut [Pcg32],
        out: &mut [Option<f32>],
    ) {
        for ((r, rng), o) in rays.iter().zip(rngs.iter_mut()).zip(out.iter_mut()) {
            *o = self.sample_distance(r[0], r[1], t_max, rng);
        }
    }
}

/// A validated ray in f64 with unit direction; `scale = |d|` converts back to the caller's t.
#[derive(Clone, Copy)]
pub struct PreparedRay {
    pub o: DVec3,
    pub d: DVec3,
    pub scale: f64,
    pub t_max: f64,
}

/// The ray `o + t d`, `t` in `[0, t_max]`, in f64 with a unit direction, or `None` for an
/// invalid one (non-finite, zero direction, `t_max <= 0`): the first step of every estimator.
#[inline]
pub fn prepare(o: Vec3, d: Vec3, t_max: f32) -> Option<PreparedRay> {
    if !(o.is_finite() && d.is_finite() && t_max > 0.0) {
        return None;
    }
    let d = d.as_dvec3();
    let scale = d.length();
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    Some(PreparedRay {
        o: o.as_dvec3(),
        d: d / scale,
        scale,
        t_max: t_max as f64 * scale,
    })
}

impl PreparedRay {
    /// World distance back to the caller's parameter, strictly inside `[0, t_max]`.
    #[inline]
    pub fn to_t(self, t_world: f64, t_max: f32) -> f32 {
        ((t_world / self.scale) as f32).clamp(0.0, t_max)
    }
    #[inline]
    pub fn at(&self, t: f64) -> Vec3 {
        (self.o + self.d * t).as_vec3()
    }
}

/// Extinction as the estimators use it: NaN and negative values are 0, `+inf` is kept
/// (opaque).
#[inline]
pub fn clean(sigma: f32) -> f64 {
    if sigma > 0.0 { sigma as f64 } else { 0.0 }
}

/// Safety valve for trackers: after this many tentative collisions in one query the tracker
/// stops (delta: no collision; ratio: the current weight). Only reachable with majorants
/// absurdly larger than the extinction (e.g. a supplied grid of 1e30 over thin smoke).
pub const MAX_TRACKING_STEPS: u32 = 1 << 22;

/// Safety valve for ray marching: the step is widened so a query takes at most this many.
pub const MAX_MARCH_STEPS: f64 = (1u64 << 24) as f64;

// ---------------------------------------------------------------------------------------
// Ray marching
// ---------------------------------------------------------------------------------------

/// Ray marching with a fixed step relative to the box's longest edge; midpoint rule.
///
/// Steps start at the segment start (the box entry or the ray origin) and the last one is
/// shortened to end exactly at the segment end. Transmittance is `exp(-sum sigma(mid) h)`,
/// deterministic. Distance sampling draws a target optical depth `-ln(1 - u)` and inverts
/// the piecewise-linear accumulated depth (constant extinction inside a step), so a
/// homogeneous medium is sampled exactly.
pub struct RayMarching<F: ?Sized = dyn Density> {
    field: Arc<F>,
    lo: [f64; 3],
    hi: [f64; 3],
    rel_step: f64,
    step: f64,
}

impl<F: Density + ?Sized> RayMarching<F> {
    /// `rel_step` in `(0, 1]` times the longest edge of `field.bounds()` is the step.
    pub fn new(field: Arc<F>, rel_step: f64) -> Result<Self, RenderError> {
        let (lo, hi) = field.bounds().to_arrays();
        check_box(&lo, &hi).map_err(|why| RenderError::Invalid {
            what: "field bounds",
            why,
        })?;
        if !(rel_step > 0.0 && rel_step <= 1.0) {
            return Err(RenderError::Invalid {
                what: "ray marching step",
                why: format!("relative step {rel_step} must be in (0, 1]"),
            });
        }
        let longest = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        Ok(RayMarching {
            field,
            lo,
            hi,
            rel_step,
            step: rel_step * longest,
        })
    }

    /// Walks the steps; `visit(t_start, h, sigma)` returns true to stop.
    #[inline]
    fn march(&self, r: &PreparedRay, mut visit: impl FnMut(f64, f64, f64) -> bool) {
        let Some((t0, t1)) = clip_box(r.o, r.d, &self.lo, &self.hi, 0.0, r.t_max) else {
            return;
        };
        let len = t1 - t0;
        let h = self.step.max(len / MAX_MARCH_STEPS);
        let n = (len / h).ceil().max(1.0) as u64;
        for i in 0..n {
            let a = t0 + i as f64 * h;
            let b = if i + 1 == n { t1 } else { (a + h).min(t1) };
            if b <= a {
                continue;
            }
            let sigma = clean(self.field.extinction(r.at(0.5 * (a + b)).as_dvec3()));
            if visit(a, b - a, sigma) {
                return;
            }
        }
    }
}

impl<F: Density + ?Sized> TransportEstimator for RayMarching<F> {
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
        let r = prepare(o, d, t_max)?;
        let target = rng.next_exp();
        let mut tau = 0.0;
        let mut hit = None;
        self.march(&r, |a, h, sigma| {
            let dt = sigma * h;
            if tau + dt >= target && sigma > 0.0 {
                // Linear interpolation of the depth inside the step.
                hit = Some((a + (target - tau) / sigma).min(a + h));
                return true;
            }
            tau += dt;
            false
        });
        hit.map(|t| r.to_t(t, t_max))
    }

    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, _rng: &mut Pcg32) -> f32 {
        let Some(r) = prepare(o, d, t_max) else {
            return 1.0;
        };
        let mut tau = 0.0;
        self.march(&r, |_, h, sigma| {
            tau += sigma * h;
            tau == f64::INFINITY
        });
        (-tau).exp() as f32
    }

    fn name(&self) -> String {
        format!("ray-marching(step={})", self.rel_step)
    }

    /// The field's box: marching is clipped to it.
    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        Some((self.lo, self.hi))
    }
}

// ---------------------------------------------------------------------------------------
// Trackers over a majorant grid
// ---------------------------------------------------------------------------------------

/// How [`Tracker::walk`] ended.
enum Walk<R> {
    /// `visit` stopped it with this value.
    Stopped(R),
    /// It left the last brick.
    Passed,
    /// It took `MAX_TRACKING_STEPS` tentative collisions.
    StepLimit,
}

/// Shared state of the trackers: a field and a majorant grid over (at least) its support.
pub(crate) struct Tracker<F: ?Sized> {
    pub(crate) majorants: Arc<MajorantGrid>,
    pub(crate) field: Arc<F>,
    /// The field has a [`DenseView`] and the majorant box lies inside the field's box, so
    /// every tentative collision (inside the majorant box) reads the array directly.
    dense: bool,
}

/// How [`Tracker::walk_with`] reads the extinction at a tentative collision.
trait Lookup {
    /// A new majorant segment starts at world distance `t0` along the ray.
    fn segment(&mut self, r: &PreparedRay, t0: f64);
    /// The extinction at world distance `t` (inside the current segment).
    fn at(&self, r: &PreparedRay, t: f64) -> f32;
}

/// Through [`Density::extinction`] at the f32 world point.
struct PointLookup<'a, F: ?Sized>(&'a F);

impl<F: Density + ?Sized> Lookup for PointLookup<'_, F> {
    #[inline(always)]
    fn segment(&mut self, _: &PreparedRay, _: f64) {}
    #[inline(always)]
    fn at(&self, r: &PreparedRay, t: f64) -> f32 {
        self.0.extinction(r.at(t).as_dvec3())
    }
}

/// Through a [`DenseView`] in f32 index space: one f64 world-to-index transform per
/// majorant segment (`u0` at the segment's start), then `u0 + du (t - t0)` per lookup. The
/// offset from the segment start is at most a brick long, so the f32 index stays within a
/// few ulps of the f64 one (about 1e-5 voxels on a 512-voxel axis).
struct DenseLookup<'a> {
    view: DenseView<'a>,
    du: [f32; 3],
    u0: [f32; 3],
    t0: f64,
}

impl<'a> DenseLookup<'a> {
    fn new(view: DenseView<'a>, r: &PreparedRay) -> Self {
        DenseLookup {
            du: view.index_dir(r.d.to_array()).map(|v| v as f32),
            view,
            u0: [0.0; 3],
            t0: 0.0,
        }
    }
}

impl Lookup for DenseLookup<'_> {
    #[inline(always)]
    fn segment(&mut self, r: &PreparedRay, t0: f64) {
        self.t0 = t0;
        self.u0 = self
            .view
            .index((r.o + r.d * t0).to_array())
            .map(|v| v as f32);
    }
    #[inline(always)]
    fn at(&self, _: &PreparedRay, t: f64) -> f32 {
        let s = (t - self.t0) as f32;
        self.view.at([0, 1, 2].map(|a| self.u0[a] + self.du[a] * s))
    }
}

impl<F: Density + ?Sized> Tracker<F> {
    /// The one majorant-stepping loop under delta and ratio tracking, reading the field
    /// through its dense array where it has one ([`Tracker::dense`]).
    #[inline]
    fn walk<R>(
        &self,
        r: &PreparedRay,
        rng: &mut Pcg32,
        visit: impl FnMut(f64, f64, f64, f64, &mut Pcg32) -> Option<R>,
    ) -> Walk<R> {
        let segments = self.majorants.segments(r.o, r.d, 0.0, r.t_max);
        self.walk_segments(segments, r, rng, visit)
    }

    /// [`Tracker::walk`] over other segments of the ray than its own majorant grid's, in
    /// order along the ray, each segment's `majorant` the rate of its tentative collisions
    /// (residual ratio tracking walks the residual majorants of a grid of the same bricks).
    #[inline]
    fn walk_segments<R>(
        &self,
        segments: impl Iterator<Item = MajorantSegment>,
        r: &PreparedRay,
        rng: &mut Pcg32,
        visit: impl FnMut(f64, f64, f64, f64, &mut Pcg32) -> Option<R>,
    ) -> Walk<R> {
        if self.dense
            && let Some(view) = self.field.dense_view()
        {
            return self.walk_with(segments, r, rng, DenseLookup::new(view, r), visit);
        }
        self.walk_with(segments, r, rng, PointLookup(&*self.field), visit)
    }

    /// The majorant-stepping loop: exponential steps at each brick segment's majorant (a
    /// piecewise constant majorant: the leftover majorant optical depth carries into the
    /// next brick; bricks of majorant 0 are skipped). At each tentative collision
    /// `visit(t, sigma, majorant, 1 / majorant, rng)` decides; `Some` stops the walk with its
    /// value. The random draws are, in order: one exponential, then per tentative collision
    /// one exponential before `visit` and whatever `visit` draws.
    #[inline(always)]
    fn walk_with<R, L: Lookup>(
        &self,
        segments: impl Iterator<Item = MajorantSegment>,
        r: &PreparedRay,
        rng: &mut Pcg32,
        mut lookup: L,
        mut visit: impl FnMut(f64, f64, f64, f64, &mut Pcg32) -> Option<R>,
    ) -> Walk<R> {
        let mut steps = 0u32;
        // Majorant optical depth left to the next tentative collision, carried across brick
        // boundaries (equivalent to resampling there, by memorylessness, but one logarithm
        // per tentative collision instead of one per brick).
        let mut tau = rng.next_exp();
        for seg in segments {
            if !(seg.majorant > 0.0) {
                continue;
            }
            let maj = seg.majorant as f64;
            let inv = 1.0 / maj;
            let mut t = seg.t0;
            if t + tau * inv >= seg.t1 {
                // No tentative collision in this brick: no index transform either.
                tau = (tau - (seg.t1 - t) * maj).max(0.0);
                continue;
            }
            lookup.segment(r, seg.t0);
            loop {
                let t_next = t + tau * inv;
                if t_next >= seg.t1 {
                    tau = (tau - (seg.t1 - t) * maj).max(0.0);
                    break;
                }
                t = t_next;
                tau = rng.next_exp();
                let sigma = clean(lookup.at(r, t));
                if let Some(v) = visit(t, sigma, maj, inv, rng) {
                    return Walk::Stopped(v);
                }
                steps += 1;
                if steps >= MAX_TRACKING_STEPS {
                    return Walk::StepLimit;
                }
            }
        }
        Walk::Passed
    }

    /// Delta tracking over [`Tracker::walk`]: a tentative collision is accepted with
    /// probability `sigma / majorant` (clamped to 1 where a supplied majorant is too small).
    #[inline]
    pub(crate) fn delta(&self, r: &PreparedRay, rng: &mut Pcg32) -> Option<f64> {
        match self.walk(r, rng, |t, sigma, maj, _, rng| {
            (rng.next_f64() * maj < sigma).then_some(t)
        }) {
            Walk::Stopped(t) => Some(t),
            Walk::Passed | Walk::StepLimit => None,
        }
    }

    /// Ratio tracking over [`Tracker::walk`]: the product of `1 - sigma / majorant` over the
    /// tentative collisions, unbiased for any positive majorant (weights can turn negative
    /// where a supplied majorant is too small; they are not clamped, which would bias).
    /// Russian roulette below |T| = 0.1 (survival probability |T| / 0.1, weight divided by
    /// it) keeps dense media cheap without bias.
    #[inline]
    fn ratio(&self, r: &PreparedRay, rng: &mut Pcg32) -> f32 {
        let mut tr = 1.0f64;
        let walk = self.walk(r, rng, |_, sigma, _, inv, rng| {
            ratio_step(&mut tr, sigma, inv, rng)
        });
        match walk {
            Walk::Stopped(v) => v,
            Walk::Passed | Walk::StepLimit => tr as f32,
        }
    }

    /// Ratio tracking's transmittance and delta tracking's collision from one walk: at each
    /// tentative collision, until a collision is accepted, delta tracking's acceptance draw,
    /// then ratio tracking's step ([`ratio_step`]) until its weight is final. The walk ends
    /// when both are decided. Each follows its own tracker's rules over the same tentative
    /// collisions (a Poisson process of the majorant, whichever query reads it), so each has
    /// its own tracker's distribution; they are correlated, which a sum of their terms
    /// does not mind (`TransportEstimator::transmittance_and_distance`).
    #[inline]
    pub(crate) fn ratio_and_delta(&self, r: &PreparedRay, rng: &mut Pcg32) -> (f32, Option<f64>) {
        let mut tr = 1.0f64;
        let mut ratio: Option<f32> = None;
        let mut hit: Option<f64> = None;
        let walk = self.walk(r, rng, |t, sigma, maj, inv, rng| {
            if hit.is_none() && rng.next_f64() * maj < sigma {
                hit = Some(t);
            }
            if ratio.is_none() {
                ratio = ratio_step(&mut tr, sigma, inv, rng);
            }
            (hit.is_some() && ratio.is_some()).then_some(())
        });
        match walk {
            Walk::Stopped(()) => (ratio.unwrap_or(0.0), hit),
            Walk::Passed | Walk::StepLimit => (ratio.unwrap_or(tr as f32), hit),
        }
    }

    /// [`Self::ratio_and_delta`] for a query ray: what `transmittance_and_distance` answers
    /// for every estimator that pairs ratio tracking's transmittance with delta tracking's
    /// collision (ratio, residual).
    pub(crate) fn ratio_and_delta_query(
        &self,
        o: Vec3,
        d: Vec3,
        t_max: f32,
        rng: &mut Pcg32,
    ) -> (f32, Option<f32>) {
        match prepare(o, d, t_max) {
            Some(r) => {
                let (t, hit) = self.ratio_and_delta(&r, rng);
                (t, hit.map(|h| r.to_t(h, t_max)))
            }
            None => (1.0, None),
        }
    }

    pub(crate) fn new(field: Arc<F>, majorants: Arc<MajorantGrid>) -> Self {
        // Outside the field's box the extinction is 0 while the clamped array reads its edge
        // voxels, so the array serves only majorant boxes inside the field's box (rays are
        // clipped to the majorant box; a tentative collision may round past its face by an
        // ulp, where either value is right).
        let (flo, fhi) = field.bounds().to_arrays();
        let (mlo, mhi) = majorants.bounds();
        let dense =
            field.dense_view().is_some() && (0..3).all(|a| mlo[a] >= flo[a] && mhi[a] <= fhi[a]);
        Tracker {
            majorants,
            field,
            dense,
        }
    }

    pub(crate) fn dims_label(&self) -> String {
        let d = self.majorants.dims();
        format!("{}x{}x{}", d[0], d[1], d[2])
    }
}

/// One tentative collision of ratio tracking: the weight `tr` times `1 - sigma / majorant`;
/// `Some(0)` ends the query (an opaque medium, or Russian roulette, which below |T| = 0.1
/// keeps the weight with probability |T| / 0.1 and divides it by that).
#[inline(always)]
fn ratio_step(tr: &mut f64, sigma: f64, inv: f64, rng: &mut Pcg32) -> Option<f32> {
    const RR: f64 = 0.1;
    *tr *= 1.0 - sigma * inv;
    if *tr == 0.0 || tr.is_nan() {
        // sigma = +inf gives -inf or NaN: an opaque medium.
        return Some(0.0);
    }
    if tr.abs() < RR {
        let p = tr.abs() / RR;
        if rng.next_f64() >= p {
            return Some(0.0);
        }
        *tr /= p;
    }
    None
}

/// Delta tracking for both queries (transmittance is the 0/1 indicator of passing).
pub struct DeltaTracking<F: ?Sized = dyn Density>(Tracker<F>);

/// Ratio tracking for transmittance, delta tracking for distances.
pub struct RatioTracking<F: ?Sized = dyn Density>(Tracker<F>);

impl<F: Density + ?Sized> DeltaTracking<F> {
    /// The majorant grid's box bounds the tracking; it should cover the field's support.
    pub fn new(field: Arc<F>, majorants: Arc<MajorantGrid>) -> Self {
        DeltaTracking(Tracker::new(field, majorants))
    }
}

impl<F: Density + ?Sized> RatioTracking<F> {
    /// The majorant grid's box bounds the tracking; it should cover the field's support.
    pub fn new(field: Arc<F>, majorants: Arc<MajorantGrid>) -> Self {
        RatioTracking(Tracker::new(field, majorants))
    }
}

impl<F: Density + ?Sized> TransportEstimator for DeltaTracking<F> {
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
        let r = prepare(o, d, t_max)?;
        self.0.delta(&r, rng).map(|t| r.to_t(t, t_max))
    }
    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32 {
        match prepare(o, d, t_max) {
            Some(r) if self.0.delta(&r, rng).is_some() => 0.0,
            _ => 1.0,
        }
    }
    fn name(&self) -> String {
        format!("delta-tracking({})", self.0.dims_label())
    }
    /// The majorant grid's box: tracking is clipped to it.
    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        Some(self.0.majorants.bounds())
    }
}

impl<F: Density + ?Sized> TransportEstimator for RatioTracking<F> {
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
        let r = prepare(o, d, t_max)?;
        self.0.delta(&r, rng).map(|t| r.to_t(t, t_max))
    }
    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32 {
        match prepare(o, d, t_max) {
            Some(r) => self.0.ratio(&r, rng),
            None => 1.0,
        }
    }
    /// One walk for both (`Tracker::ratio_and_delta`).
    fn transmittance_and_distance(
        &self,
        o: Vec3,
        d: Vec3,
        t_max: f32,
        rng: &mut Pcg32,
    ) -> (f32, Option<f32>) {
        self.0.ratio_and_delta_query(o, d, t_max, rng)
    }
    fn name(&self) -> String {
        format!("ratio-tracking({})", self.0.dims_label())
    }
    /// The majorant grid's box: tracking is clipped to it.
    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        Some(self.0.majorants.bounds())
    }
}

// ---------------------------------------------------------------------------------------
// Residual ratio tracking (transmittance), delta tracking (distances)
// ---------------------------------------------------------------------------------------

/// The control extinction per brick of [`ResidualRatioTracking`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResidualControl {
    /// The least extinction in the brick ([`Density::min_extinction_in`], exact for voxel
    /// grids: the least of the voxels that the trilinear field reads there), so that the
    /// residual is never negative; fields without an exact minimum take the least of a
    /// lattice of points spanning the brick.
    Min,
    /// The mean extinction over the brick (midpoint lattice of 8^3 points), the control that
    /// minimises the integral of the squared residual over the brick; the residual majorant
    /// then bounds the residual on both sides (`max(majorant - control, control - min)`).
    Mean,
}

impl ResidualControl {
    /// The name `residual@NAME` parses.
    pub fn name(self) -> &'static str {
        match self {
            ResidualControl::Min => "min",
            ResidualControl::Mean => "mean",
        }
    }
}

/// Residual ratio tracking (Novák, Selle and Jarosz 2014) for transmittance, delta
/// tracking over the full majorants for distances.
///
/// Each brick of the majorant grid has a constant control extinction `c` and a residual
/// majorant `m_r`. Writing `sigma = c + (sigma - c)`, `exp(-tau) = exp(-int c) exp(-int
/// (sigma - c))`: the first factor is exact (a sum over the bricks the ray crosses, in the
/// one majorant walk), and the second is ratio tracking of the residual `sigma - c` against
/// `m_r`: the product of `1 - (sigma - c) / m_r` over tentative collisions at rate `m_r`.
/// For a Poisson process of rate `m_r`, `E[prod (1 - f(t_i) / m_r)] = exp(-int f)` for any
/// bounded `f` of either sign, so the estimator is unbiased for any control; its relative
/// variance is `exp(int (sigma - c)^2 / m_r) - 1` (same expectation formula for the
/// squared product) at `int m_r` lookups, which is what the control shrinks. Bricks whose
/// residual majorant is 0 (homogeneous or empty) cost no lookups at all.
///
/// Russian roulette acts on the whole weight `exp(-int_0^t c) x residual weight` below 0.1,
/// as ratio tracking's does on its weight, so that a query stops once a dense control has
/// made the transmittance small, not only once the residual has.
pub struct ResidualRatioTracking<F: ?Sized = dyn Density> {
    /// The field and the full majorants (delta tracking for distances).
    tracker: Tracker<F>,
    /// The residual majorants, over the same bricks as the tracker's grid.
    residual: MajorantGrid,
    /// The control extinction per brick, laid out as the grids' values.
    controls: Vec<f32>,
    /// What the controls are (for the name); `None` when given by the caller.
    control: Option<ResidualControl>,
}

/// The control and residual majorant of every brick of `majorants` over `field`.
fn residual_controls<F: Density + ?Sized>(
    field: &F,
    majorants: &MajorantGrid,
    control: ResidualControl,
) -> (Vec<f32>, Vec<f32>) {
    let dims = majorants.dims();
    let n = majorants.values().len();
    let (mut controls, mut residual) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let mut k = 0;
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let maj = majorants.values()[k];
                k += 1;
                let (lo, hi) = majorants.brick_bounds([x, y, z]);
                // A point `f` (per axis, in [0, 1]) of the brick, as an f32 world point.
                let at = |f: [f64; 3]| {
                    let p = [0, 1, 2].map(|a| (lo[a] + (hi[a] - lo[a]) * f[a]) as f32);
                    clean(field.extinction(Vec3::from_array(p).as_dvec3()))
                };
                let least = field
                    .min_extinction_in(Aabb::from_arrays(lo, hi))
                    .map_or_else(
                        || {
                            const K: u32 = 5;
                            (0..K * K * K)
                                .map(|c| {
                                    let i = [c % K, (c / K) % K, c / (K * K)];
                                    at(i.map(|v| v as f64 / (K - 1) as f64))
                                })
                                .fold(f64::INFINITY, f64::min)
                        },
                        clean,
                    );
                let c = match control {
                    ResidualControl::Min => least,
                    ResidualControl::Mean => {
                        const K: u32 = 8;
                        let sum: f64 = (0..K * K * K)
                            .map(|c| {
                                let i = [c % K, (c / K) % K, c / (K * K)];
                                at(i.map(|v| (v as f64 + 0.5) / K as f64))
                            })
                            .sum();
                        sum / (K * K * K) as f64
                    }
                };
                // Never above the brick's majorant (ratio tracking skips a brick of majorant
                // 0, so this one does too), and finite: an opaque brick's control is
                // f32::MAX, whose depth over any length gives transmittance 0.
                let c = (c.min(maj as f64) as f32).min(f32::MAX);
                let below = (c as f64 - least.min(c as f64)) as f32;
                controls.push(c);
                residual.push((maj - c).max(below).max(0.0));
            }
        }
    }
    (controls, residual)
}

impl<F: Density + ?Sized> ResidualRatioTracking<F> {
    /// Controls of kind `control` per brick of `majorants`, computed here from the field
    /// alone (a load-time pass over the bricks).
    pub fn new(
        field: Arc<F>,
        majorants: Arc<MajorantGrid>,
        control: ResidualControl,
    ) -> Result<Self, RenderError> {
        let (controls, residual) = residual_controls(&*field, &majorants, control);
        let mut est = Self::with_controls(field, majorants, controls, residual)?;
        est.control = Some(control);
        Ok(est)
    }

    /// Given controls and residual majorants per brick of `majorants` (its layout; finite
    /// and `>= 0`). Any controls give an unbiased estimator; they only set its variance.
    pub fn with_controls(
        field: Arc<F>,
        majorants: Arc<MajorantGrid>,
        controls: Vec<f32>,
        residual: Vec<f32>,
    ) -> Result<Self, RenderError> {
        let (lo, hi) = majorants.bounds();
        if controls.len() != majorants.values().len()
            || controls.iter().any(|c| !(c.is_finite() && *c >= 0.0))
        {
            return Err(RenderError::Invalid {
                what: "residual controls",
                why: format!(
                    "need {} finite values >= 0, one per majorant brick",
                    majorants.values().len()
                ),
            });
        }
        let residual = MajorantGrid::from_parts(lo, hi, majorants.dims(), residual)?;
        Ok(ResidualRatioTracking {
            tracker: Tracker::new(field, majorants),
            residual,
            controls,
            control: None,
        })
    }

    /// Given controls and residual majorants on a grid of their own (`residual`, its layout),
    /// with `majorants` (any grid over the field's support) for distances and paired
    /// queries. The residual's walk reads the field's dense array only when both grids lie
    /// inside the field's box.
    pub fn with_residual_grid(
        field: Arc<F>,
        majorants: Arc<MajorantGrid>,
        residual: MajorantGrid,
        controls: Vec<f32>,
    ) -> Result<Self, RenderError> {
        if controls.len() != residual.values().len()
            || controls.iter().any(|c| !(c.is_finite() && *c >= 0.0))
        {
            return Err(RenderError::Invalid {
                what: "residual controls",
                why: format!(
                    "need {} finite values >= 0, one per residual brick",
                    residual.values().len()
                ),
            });
        }
        let mut tracker = Tracker::new(field, majorants);
        let (flo, fhi) = tracker.field.bounds().to_arrays();
        let (rlo, rhi) = residual.bounds();
        tracker.dense &= (0..3).all(|a| rlo[a] >= flo[a] && rhi[a] <= fhi[a]);
        Ok(ResidualRatioTracking {
            tracker,
            residual,
            controls,
            control: None,
        })
    }

    /// The controls and residual majorants per brick (the grids' layout).
    pub fn controls(&self) -> (&[f32], &[f32]) {
        (&self.controls, self.residual.values())
    }

    /// The residual majorants' grid (the controls' layout) and the majorants that its
    /// distances and paired queries track: what the GPU path tracer uploads.
    pub fn grids(&self) -> (&MajorantGrid, &Arc<MajorantGrid>) {
        (&self.residual, &self.tracker.majorants)
    }

    #[inline(always)]
    fn control_of(&self, brick: [u32; 3]) -> f64 {
        let d = self.residual.dims();
        let i = brick[0] as usize
            + d[0] as usize * (brick[1] as usize + d[1] as usize * brick[2] as usize);
        self.controls[i] as f64
    }

    /// The control's optical depth over the ray's segment, alone.
    fn control_depth(&self, r: &PreparedRay) -> f64 {
        self.residual
            .segments(r.o, r.d, 0.0, r.t_max)
            .map(|seg| self.control_of(seg.brick) * (seg.t1 - seg.t0).max(0.0))
            .sum()
    }

    /// One walk over the residual majorants: `(control depth, residual weight)` whose
    /// product `exp(-depth) weight` is the estimate, or `None` when the walk ended in
    /// transmittance 0 (roulette, or an opaque extinction).
    #[inline]
    pub(crate) fn residual_walk(&self, r: &PreparedRay, rng: &mut Pcg32) -> Option<(f64, f64)> {
        // The segment being walked: its control, and `tau_c(t) = offset + control t` inside
        // it; `depth` is the control depth to the end of the segments pulled so far. Cells:
        // the segment stream sets them and the tentative collisions read them.
        let control = std::cell::Cell::new(0.0f64);
        let offset = std::cell::Cell::new(0.0f64);
        let depth = std::cell::Cell::new(0.0f64);
        let segments = self
            .residual
            .segments(r.o, r.d, 0.0, r.t_max)
            .inspect(|seg| {
                let c = self.control_of(seg.brick);
                let before = depth.get();
                control.set(c);
                offset.set(before - c * seg.t0);
                depth.set(before + c * (seg.t1 - seg.t0).max(0.0));
            });
        let mut tr = 1.0f64;
        let walk = self
            .tracker
            .walk_segments(segments, r, rng, |t, sigma, _, inv, rng| {
                let c = control.get();
                residual_step(&mut tr, sigma - c, inv, offset.get() + c * t, rng)
            });
        match walk {
            Walk::Stopped(()) => None,
            Walk::Passed => Some((depth.get(), tr)),
            // The walk stopped before the end: the rest of the control depth by itself.
            Walk::StepLimit => Some((self.control_depth(r), tr)),
        }
    }
}

/// One tentative collision of residual ratio tracking: the weight `tr` times `1 - residual
/// / residual majorant` (`residual` may be negative, with a control above the extinction;
/// that keeps the expectation, so it is not clamped); `Some(())` ends the query with
/// transmittance 0 (an opaque extinction, or Russian roulette, which below a whole weight
/// `|exp(-control_depth) tr|` of 0.1 keeps the weight with probability `whole / 0.1` and
/// divides it by that).
#[inline(always)]
fn residual_step(
    tr: &mut f64,
    residual: f64,
    inv: f64,
    control_depth: f64,
    rng: &mut Pcg32,
) -> Option<()> {
    const RR: f64 = 0.1;
    *tr *= 1.0 - residual * inv;
    if *tr == 0.0 || !tr.is_finite() {
        return Some(());
    }
    let whole = tr.abs() * (-control_depth).exp();
    if whole < RR {
        let p = whole / RR;
        if rng.next_f64() >= p {
            return Some(());
        }
        *tr /= p;
    }
    None
}

impl<F: Density + ?Sized> TransportEstimator for ResidualRatioTracking<F> {
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
        let r = prepare(o, d, t_max)?;
        self.tracker.delta(&r, rng).map(|t| r.to_t(t, t_max))
    }
    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32 {
        let Some(r) = prepare(o, d, t_max) else {
            return 1.0;
        };
        match self.residual_walk(&r, rng) {
            Some((depth, tr)) => {
                let t = (-depth).exp() * tr;
                // 0 x inf (a roulette survivor's huge weight past an opaque control) is 0.
                if t.is_finite() { t as f32 } else { 0.0 }
            }
            None => 0.0,
        }
    }
    /// Ratio tracking's one walk (`Tracker::ratio_and_delta`), not the residual one: where
    /// the path tracer asks both along one ray, the path scores `env T` and then continues
    /// from the collision, and ratio tracking's transmittance from the same tentative
    /// collisions as the collision is correlated with it (near `1 - collided` in a dense
    /// medium), which cancels most of the variance of the sum; the residual estimate,
    /// independent of the collision, lowered the transmittance's variance but raised the
    /// sum's.
    fn transmittance_and_distance(
        &self,
        o: Vec3,
        d: Vec3,
        t_max: f32,
        rng: &mut Pcg32,
    ) -> (f32, Option<f32>) {
        self.tracker.ratio_and_delta_query(o, d, t_max, rng)
    }
    fn name(&self) -> String {
        let control = self.control.map_or("given", ResidualControl::name);
        format!(
            "residual-ratio-tracking@{control}({})",
            self.tracker.dims_label()
        )
    }
    /// The majorant grid's box: tracking is clipped to it.
    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        Some(self.tracker.majorants.bounds())
    }
}

#[cfg(test)]
mod dense_tests {
    use super::*;
    use crate::render::field::VoxelGrid;
    use pin_volume::DenseMap;

    /// A 7x5x6 grid, a ramp along x with random contrast on top (values 0.2 ..= 3.4).
    fn grid() -> VoxelGrid {
        let dims = [7u32, 5, 6];
        let mut rng = Pcg32::new(11, 3);
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        let values = (0..n)
            .map(|i| 0.2 + (i % 7) as f32 * 0.4 + rng.next_f32() * 0.8)
            .collect();
        VoxelGrid::new(dims, [-0.3, 0.1, 0.2], [0.2, 0.25, 0.15], values).unwrap()
    }

    /// The grid's extinction with the dense array read through a map shifted by half a voxel
    /// along x: a deliberately wrong lookup, to show that the test below can fail.
    struct Shifted(VoxelGrid);

    impl Density for Shifted {
        fn bounds(&self) -> Aabb {
            self.0.bounds()
        }
        fn extinction(&self, p: DVec3) -> f32 {
            self.0.extinction(p)
        }
        fn max_extinction_in(&self, region: Aabb) -> f32 {
            self.0.max_extinction_in(region)
        }
        fn dense_view(&self) -> Option<DenseView<'_>> {
            let (dims, origin, spacing, values) = self.0.parts();
            let shifted = [origin[0] + 0.5 * spacing[0], origin[1], origin[2]];
            DenseView::new(values, DenseMap::new(values.len(), dims, shifted, spacing)?)
        }
    }

    /// Optical depth of the unit-direction ray `o + t d`, `t` in `[t0, t1]`, by the midpoint
    /// rule with `n` steps of the field's point extinction (error far below the tests' bounds:
    /// the trilinear field is piecewise smooth and `n` large).
    fn depth(field: &dyn Density, o: Vec3, d: Vec3, t0: f64, t1: f64, n: usize) -> f64 {
        let h = (t1 - t0) / n as f64;
        (0..n)
            .map(|i| {
                let t = t0 + (i as f64 + 0.5) * h;
                let p = o.as_dvec3() + d.as_dvec3() * t;
                field.extinction(p.as_vec3().as_dvec3()) as f64 * h
            })
            .sum()
    }

    #[test]
    fn dense_view_reads_the_field() {
        let g = grid();
        let view = g.dense_view().unwrap();
        let (lo, hi) = g.bounds().to_arrays();
        let mut rng = Pcg32::new(4, 4);
        for _ in 0..20_000 {
            let p = [0, 1, 2].map(|a| lo[a] + (hi[a] - lo[a]) * rng.next_f64());
            let u = view.index(p).map(|v| v as f32);
            let want = g.extinction(Vec3::from(p.map(|v| v as f32)).as_dvec3());
            let got = view.at(u);
            assert!((got - want).abs() <= 1e-4, "{p:?}: {got} vs {want}");
        }
        // A point outside the box is clamped to the edge (the tracker never asks there).
        assert!(view.at([-5.0, f32::NAN, 1e9]) >= 0.0);
        // The tracker takes the dense path only when the majorants lie inside the field.
        let field = Arc::new(g);
        let inside = Arc::new(MajorantGrid::from_field(&*field, [3, 2, 2]).unwrap());
        assert!(Tracker::new(field.clone(), inside).dense);
        let wider = Arc::new(MajorantGrid::uniform([-1.0; 3], [2.0; 3], 20.0).unwrap());
        assert!(!Tracker::new(field, wider).dense);
    }

    /// Ratio and delta tracking through the dense array: the mean transmittance is within
    /// five standard errors of `exp(-depth)`, for rays in three directions (fixed seeds); the
    /// same test of the half-voxel-shifted lookup fails on at least one ray.
    #[test]
    fn trackers_through_the_array_are_unbiased() {
        let g = grid();
        let rays = [
            (Vec3::new(-1.0, 0.6, 0.6), Vec3::X),
            (
                Vec3::new(-0.3, 0.1, 0.2),
                Vec3::new(1.4, 1.25, 0.9).normalize(),
            ),
            (
                Vec3::new(1.2, 1.5, 0.3),
                Vec3::new(-1.0, -0.7, 0.4).normalize(),
            ),
        ];
        let z = |field: Arc<dyn Density>, seed: u64| -> Vec<f64> {
            let maj = Arc::new(MajorantGrid::from_field(&*field, [3, 2, 2]).unwrap());
            let ests: [Box<dyn TransportEstimator>; 2] = [
                Box::new(RatioTracking::new(field.clone(), maj.clone())),
                Box::new(DeltaTracking::new(field.clone(), maj)),
            ];
            let mut out = Vec::new();
            for est in &ests {
                for (k, (o, d)) in rays.iter().enumerate() {
                    let (lo, hi) = field.bounds().to_arrays();
                    let (t0, t1) =
                        clip_box(o.as_dvec3(), d.as_dvec3(), &lo, &hi, 0.0, f64::INFINITY).unwrap();
                    let exact = (-depth(&g, *o, *d, t0, t1, 200_000)).exp();
                    let mut rng = Pcg32::new(seed, k as u64);
                    let n = 40_000;
                    let (mut s, mut s2) = (0.0, 0.0);
                    for _ in 0..n {
                        let x = est.transmittance(*o, *d, f32::INFINITY, &mut rng) as f64;
                        s += x;
                        s2 += x * x;
                    }
                    let m = s / n as f64;
                    let se = ((s2 / n as f64 - m * m).max(0.0) / (n - 1) as f64).sqrt();
                    out.push((m - exact).abs() / (se + 1e-9));
                }
            }
            out
        };
        let good = z(Arc::new(grid()), 21);
        assert!(good.iter().all(|&v| v < 5.0), "{good:?}");
        let bad = z(Arc::new(Shifted(grid())), 21);
        assert!(bad.iter().any(|&v| v > 5.0), "{bad:?}");
    }

    /// Ratio tracking's transmittance and delta tracking's collision from one walk
    /// (`RatioTracking::transmittance_and_distance`), as statistics over 40,000 pairs per
    /// ray (fixed seeds), on rays that cross the grid, start inside it, or end early: the
    /// mean transmittance, the fraction without collision and the fraction colliding before
    /// the segment's middle are each within five standard errors of `exp(-depth)`,
    /// `exp(-depth)` and `1 - exp(-depth to the middle)`. A walk that ends when ratio
    /// tracking is done (as its own query does), losing the later collisions, fails.
    #[test]
    fn ratio_and_delta_from_one_walk_are_unbiased() {
        let g = Arc::new(grid());
        let maj = Arc::new(MajorantGrid::from_field(&*g, [3, 2, 2]).unwrap());
        let est = RatioTracking::new(g.clone() as Arc<dyn Density>, maj);
        let rays = [
            (Vec3::new(-1.0, 0.6, 0.6), Vec3::X, f32::INFINITY),
            (
                Vec3::new(0.4, 0.5, 0.6),
                Vec3::new(-1.0, 0.7, 0.4).normalize(),
                f32::INFINITY,
            ),
            (
                Vec3::new(1.2, 1.5, 0.3),
                Vec3::new(-1.0, -0.7, 0.4).normalize(),
                1.6,
            ),
        ];
        // z-scores of (mean T, P(no collision), P(collision before the middle)) per ray.
        let z = |lose_late_hits: bool| -> Vec<f64> {
            let mut out = Vec::new();
            for (k, &(o, d, t_max)) in rays.iter().enumerate() {
                let (lo, hi) = g.bounds().to_arrays();
                let (t0, t1) =
                    clip_box(o.as_dvec3(), d.as_dvec3(), &lo, &hi, 0.0, t_max as f64).unwrap();
                let tau = depth(&*g, o, d, t0, t1, 200_000);
                let mid = 0.5 * (t0 + t1);
                let tau_mid = depth(&*g, o, d, t0, mid, 200_000);
                let r = prepare(o, d, t_max).unwrap();
                let mut rng = Pcg32::new(33, k as u64);
                let n = 40_000;
                let (mut s, mut s2, mut none, mut early) = (0.0, 0.0, 0usize, 0usize);
                for _ in 0..n {
                    let (t, hit) = if lose_late_hits {
                        // The mutation: ratio tracking's own walk, which stops at its
                        // roulette, with the acceptance draws of delta tracking inside it.
                        let mut tr = 1.0f64;
                        let mut hit = None;
                        let w = est.0.walk(&r, &mut rng, |t, sigma, maj, inv, rng| {
                            if hit.is_none() && rng.next_f64() * maj < sigma {
                                hit = Some(t);
                            }
                            ratio_step(&mut tr, sigma, inv, rng)
                        });
                        let t = match w {
                            Walk::Stopped(v) => v,
                            _ => tr as f32,
                        };
                        (t, hit.map(|h| r.to_t(h, t_max)))
                    } else {
                        est.transmittance_and_distance(o, d, t_max, &mut rng)
                    };
                    let t = t as f64;
                    s += t;
                    s2 += t * t;
                    match hit {
                        None => none += 1,
                        Some(h) => early += usize::from((h as f64) < mid),
                    }
                }
                let nf = n as f64;
                let m = s / nf;
                let se = ((s2 / nf - m * m).max(0.0) / (nf - 1.0)).sqrt();
                out.push((m - (-tau).exp()).abs() / (se + 1e-9));
                for (count, p) in [(none, (-tau).exp()), (early, 1.0 - (-tau_mid).exp())] {
                    let f = count as f64 / nf;
                    let se = (p * (1.0 - p) / nf).sqrt();
                    out.push((f - p).abs() / (se + 1e-9));
                }
            }
            out
        };
        let good = z(false);
        assert!(good.iter().all(|&v| v < 5.0), "{good:?}");
        let bad = z(true);
        assert!(bad.iter().any(|&v| v > 5.0), "{bad:?}");
    }
}
