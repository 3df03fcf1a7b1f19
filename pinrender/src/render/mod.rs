//! # Reference volumetric path tracer
//!
//! A small, CPU-parallel, deterministic path tracer for grey participating media, used to
//! *see* what an estimator does and to *measure* it: error (RMSE, relative MSE) against run
//! time, per estimator, on the same scene (docs/background.md section 2, docs/evaluation.md). Every transport query
//! goes through the object-safe [`TransportEstimator`] trait, so ray marching, delta and
//! ratio tracking (here) and the pin estimators (plugged in from outside) are compared
//! under exactly the same path tracer.
//!
//! **Not for**: production rendering. There are no surfaces, no refractive boundaries, no
//! emission inside the medium, no spectral media (grey extinction and albedo; lights may be
//! RGB), no importance sampling of the environment and no adaptive sampling. It is not
//! tuned for speed beyond what makes equal-time comparisons meaningful.
//!
//! ## Conventions
//!
//! * World space is right-handed with `+y` up; distances are world units; extinction is per
//!   world unit.
//! * [`Camera`]: pinhole at `origin` looking at `target`, vertical field of view in degrees,
//!   `width x height` pixels, pixel `(0, 0)` top left, one uniformly jittered ray per sample
//!   inside the pixel (box filter).
//! * [`Sun`]: a delta directional light; `dir` points **from the scene towards the sun**;
//!   its `radiance` is the unoccluded irradiance perpendicular to `dir`. It is never seen
//!   directly (a delta light has no solid angle), only through next-event estimation.
//! * Environment: a constant radiance over the whole sphere (`env_radiance`); camera rays
//!   that leave the media see it attenuated by the media's transmittance.
//! * Medium: no refractive boundary (the box is not a surface), scattering = `albedo x
//!   extinction`, Henyey-Greenstein phase with parameter `g` (`cos theta` between the
//!   propagation directions before and after scattering: `g > 0` is forward), see
//!   [`phase`].
//! * Instances: [`Scene::media`] holds any number of possibly overlapping media whose
//!   extinctions add: distance sampling takes the nearest collision over the instances,
//!   transmittance is the product of the instances' estimates. A medium whose estimator
//!   declares a world box ([`TransportEstimator::bounds`]; all built-in estimators do) is
//!   asked only by queries whose segment meets that box (a vectorised slab test over all
//!   boxes per query, boxes padded outward); distance sampling asks the media met in the
//!   order of their box entries and stops at the first box that starts beyond the nearest
//!   collision so far. A skipped medium contributes transmittance 1 and no collision, so
//!   this changes no expectation, only which random numbers later media draw. On the
//!   64-instance evaluation scene a query meets 7 to 9 of the 64 boxes.
//! * `max_bounces` counts scattering events: 0 renders only the transmitted environment,
//!   1 single scattering.
//!
//! ## Estimator
//!
//! Per sample: the camera ray scores `env * T` (a transmittance estimate, not the 0/1
//! escape), then distance sampling finds the first collision. At each collision the
//! throughput is multiplied by the albedo (weighting, not absorption roulette), the sun
//! contributes `phase * T(shadow ray to the media exit) * radiance`, a direction `w` is
//! sampled from the phase function, the environment contributes `T(w) * env` (phase pdf and
//! value cancel) and the path continues along `w` with distance sampling; an escape of that
//! continuation scores nothing because `E[T(w)] = P(escape)` was already scored. All this is
//! unbiased for unbiased transmittance estimates and exact distance sampling; see
//! `tracer.rs`.
//!
//! The camera ray's `T` and first collision, and a vertex's `T(w)` and the collision of its
//! continuation along `w`, are two queries along one ray. With one medium whose estimator
//! serves both, they are asked together
//! ([`TransportEstimator::transmittance_and_distance`]): pins answer both from one lookup,
//! ratio tracking from one majorant walk (delta tracking's acceptance draws on the same
//! tentative collisions). Each keeps its distribution, so the sum a path scores keeps its
//! expectation; the two are correlated, which lowered the per-pixel variance of a cosine
//! medium's ratio-tracking render by about 30% (the GPU's separate queries had 1.40 times
//! the CPU's).
//!
//! ## Plugging in pins / PinMS
//!
//! Each [`Medium`] has two estimators: `primary` for camera rays and for the shadow rays of
//! the first scattering vertex (everything single scattering uses) and `secondary` for all
//! later segments and shadow rays. So PinMS is `Medium::new(tracker, pins)` and pins
//! everywhere `Medium::single(pins)`. A pin estimator implements [`TransportEstimator`]
//! (rays are f32, `t` in units of `|d|`, the renderer passes unit directions and
//! `t_max = inf` or the nearest collision so far), may seed its own generator per query
//! from [`Pcg32::next_u64`], and should return its sampler's
//! [`Sampler::world_bounds`](pinrt::Sampler::world_bounds) from `bounds()` so that rays
//! missing the placed grid never reach it.
//!
//! ## Extending it
//!
//! Research estimators and sample loops live outside this crate (the `pinlab` crate): an
//! estimator implements [`TransportEstimator`] (over [`prepare`]d rays, a [`DeltaTracking`] for
//! its distances if it likes), and a loop that does more at each scattering vertex (a
//! path-space cache) runs the tracer's own walk through [`Scene::ctx`], [`Ctx::walk`] and a
//! [`VertexHook`], inside [`accumulate`] so that it keeps `render`'s determinism and budgets.
//!
//! ## Determinism
//!
//! Sample `s` of pixel `p` draws from `Pcg32::for_sample(seed, p, s)` only; pixel sums are
//! accumulated in f64 in sample order. Which media a query asks, and in which order, is a
//! function of the ray and the draws so far. The image does not depend on the thread count,
//! and a time-budget render that reached `n` spp equals an `n` spp render.
//!
//! ## Failure behaviour
//!
//! Invalid scenes and settings (zero-size image, NaN camera, `g` outside `(-1, 1)`, albedo
//! outside `[0, 1]`, negative or non-finite radiance, zero spp) are [`RenderError`]s. At the
//! query level nothing panics: invalid rays are "no medium" (transmittance 1, no
//! collision), NaN and negative extinction count as 0 and `+inf` as opaque, non-finite path
//! samples are dropped.

mod baked_control;
mod bounds;
mod bricks;
pub(crate) mod bvh;
mod error;
mod estimator;
mod field;
mod image;
mod majorant;
mod numeric;
pub mod phase;
mod pins;
mod plan;
mod rng;
mod settings;
mod slab;
mod spec;
mod tracer;
mod wavefront;

#[cfg(test)]
mod tests;

pub use baked_control::BakedResidualTracking;
pub use bricks::{BrickGrid, SharedHalves};
pub use error::RenderError;
pub use estimator::{
    DeltaTracking, MAX_MARCH_STEPS, MAX_TRACKING_STEPS, PreparedRay, RatioTracking, RayMarching,
    ResidualControl, ResidualRatioTracking, TransportEstimator, clean, prepare,
};
pub use field::{FnField, VoxelGrid};
#[cfg(feature = "gpu")]
pub(crate) use image::write_atomic;
pub use image::{Image, RELATIVE_MSE_EPS, block_bias, relative_mse, rmse, tone_map};
pub use majorant::{Dda, MajorantGrid, MajorantSegment, check_box, clip_box};
pub use numeric::exprel;
/// The one density interface and the dense view, from the baker's sources: the renderer
/// tracks what the baker bakes.
pub use pin_volume::{Aabb, DenseMap, DenseView, Density, HomogeneousBox};
pub use pins::PinsEstimator;
pub use plan::{RenderPlan, SampleLoop};
pub use rng::{Pcg32, splitmix64};
pub use settings::{Budget, RenderSettings};
pub use spec::{
    ESTIMATOR_SYNTAX, ESTIMATORS, EstimatorInfo, EstimatorSpec, MIN_REL_STEP,
    RESIDUAL_DEFAULT_CONTROL,
};
pub use tracer::{
    Camera, Ctx, Frame, Medium, NoHook, PathVertex, RenderOutput, Scene, Sun, VertexHook, Which,
    accumulate, check_settings, in_pool,
};
pub use wavefront::{
    DEFAULT_WAVEFRONT_BATCH, ROW_CHUNK_PATHS, render_wavefront, row_scratch_bytes,
};

/// The one entry point of the CPU path tracer: the sample loop of `tracer.rs` over every
/// path. Render `scene`. Sample `s` of pixel `(x, y)` uses `Pcg32::for_sample(seed, y * width + x,
/// s)` (two draws for the jitter inside the pixel, then the path), and per-pixel sums run
/// in sample order, so the image is the same for any thread count and a time-budget render
/// that reached `n` spp equals an `Spp(n)` render. Non-finite samples (possible only with
/// a misbehaving plug-in estimator) are dropped.
pub fn render(scene: &Scene, settings: &RenderSettings) -> Result<RenderOutput, RenderError> {
    scene.validate()?;
    render_in(scene, settings, &scene.ctx(settings.max_bounces))
}

/// [`render`] of a validated scene with its [`Ctx`] given (the tests render with the linear
/// box scan through it).
pub(crate) fn render_in(
    scene: &Scene,
    settings: &RenderSettings,
    ctx: &Ctx<'_>,
) -> Result<RenderOutput, RenderError> {
    tracer::accumulate(scene, settings, std::time::Instant::now(), |o, d, rng| {
        ctx.trace(o, d, rng)
    })
}
