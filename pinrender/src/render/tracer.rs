//! The volumetric path tracer: camera, lights, media instances, the render loop.

use super::bounds::{MISS, MediaBoxes, MetChunks, RaySlabs};
use super::error::RenderError;
use super::estimator::TransportEstimator;
use super::image::Image;
use super::phase::{hg_phase, sample_hg};
use super::rng::Pcg32;
use super::settings::{Budget, RenderSettings};
use glam::Vec3;
use rayon::prelude::*;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Pinhole camera at `origin` looking at `target`, world up `+y` (`+z` when looking straight
/// up or down), vertical field of view in degrees. Pixel `(0, 0)` is the top-left one.
#[derive(Clone, Debug)]
pub struct Camera {
    pub origin: [f32; 3],
    pub target: [f32; 3],
    pub vfov_deg: f32,
    pub width: u32,
    pub height: u32,
}

/// A delta directional light. `dir` points from the scene towards the sun (any length > 0).
/// `radiance` is what a point sees with nothing in between, i.e. the irradiance on a plane
/// perpendicular to `dir`: the single-scattered contribution is `phase * T * radiance`.
#[derive(Clone, Debug)]
pub struct Sun {
    pub dir: [f32; 3],
    pub radiance: [f32; 3],
}

/// One medium instance: the estimators the tracer uses for it. `primary` serves camera rays
/// and the shadow rays of the first scattering vertex (everything single scattering needs),
/// `secondary` everything after the first scattering event. PinMS is
/// `Medium::new(tracker, pins)`, pins everywhere `Medium::single(pins)`.
#[derive(Clone)]
pub struct Medium {
    pub primary: Arc<dyn TransportEstimator>,
    pub secondary: Arc<dyn TransportEstimator>,
}

impl Medium {
    pub fn new(
        primary: Arc<dyn TransportEstimator>,
        secondary: Arc<dyn TransportEstimator>,
    ) -> Self {
        Medium { primary, secondary }
    }
    /// The same estimator for every query.
    pub fn single(estimator: Arc<dyn TransportEstimator>) -> Self {
        Medium {
            primary: estimator.clone(),
            secondary: estimator,
        }
    }
}

/// A scene: media combined additively, a sun, a constant environment, one grey material.
#[derive(Clone)]
pub struct Scene {
    pub camera: Camera,
    pub sun: Option<Sun>,
    /// Constant radiance arriving from every direction of the sphere.
    pub env_radiance: [f32; 3],
    /// Single-scattering albedo in `[0, 1]` (scattering = albedo x extinction), shared by all
    /// instances: with one material the instance a collision came from does not matter.
    pub albedo: f32,
    /// Henyey-Greenstein asymmetry in `(-1, 1)`.
    pub g: f32,
    pub media: Vec<Medium>,
}

/// A finished render.
#[derive(Clone, Debug)]
pub struct RenderOutput {
    pub image: Image,
    /// Samples per pixel reached.
    pub spp: u32,
    /// Wall time of the sampling, seconds.
    pub seconds: f64,
}

fn invalid(what: &'static str, why: String) -> RenderError {
    RenderError::Invalid { what, why }
}

fn finite3(v: &[f32; 3]) -> bool {
    v.iter().all(|c| c.is_finite())
}

fn radiance_ok(v: &[f32; 3]) -> bool {
    v.iter().all(|c| c.is_finite() && *c >= 0.0)
}

/// The camera's validated frame: the rays of its pixels ([`Frame::ray`]).
#[derive(Clone, Copy)]
pub struct Frame {
    o: Vec3,
    f: Vec3,
    r: Vec3,
    u: Vec3,
    tan_half: f32,
    aspect: f32,
    w: f32,
    h: f32,
}

impl Camera {
    /// The validated frame, or an error for a camera `render` refuses.
    pub fn frame(&self) -> Result<Frame, RenderError> {
        let n = (self.width as u64) * (self.height as u64);
        if n == 0 || n > (1 << 31) {
            return Err(invalid(
                "camera",
                format!(
                    "image {}x{}: need 1 ..= 2^31 pixels",
                    self.width, self.height
                ),
            ));
        }
        if !(self.vfov_deg > 0.0 && self.vfov_deg < 180.0) {
            return Err(invalid(
                "camera",
                format!("vfov {} not in (0, 180)", self.vfov_deg),
            ));
        }
        if !finite3(&self.origin) || !finite3(&self.target) {
            return Err(invalid("camera", "non-finite origin or target".into()));
        }
        let o = Vec3::from_array(self.origin);
        let f = (Vec3::from_array(self.target) - o).normalize_or_zero();
        if f == Vec3::ZERO {
            return Err(invalid("camera", "origin and target coincide".into()));
        }
        // Right-handed, y up: right = forward x up. Looking along +-y, use z as up instead.
        let mut r = f.cross(Vec3::Y);
        if r.length_squared() < 1e-12 {
            r = f.cross(Vec3::Z);
        }
        let r = r.normalize();
        let u = r.cross(f);
        Ok(Frame {
            o,
            f,
            r,
            u,
            tan_half: (self.vfov_deg.to_radians() * 0.5).tan(),
            aspect: self.width as f32 / self.height as f32,
            w: self.width as f32,
            h: self.height as f32,
        })
    }
}

impl Frame {
    /// Ray through image position `(px, py)` in pixels from the top-left corner. The
    /// direction is NOT normalised: every caller starts a path with it, and a path's start
    /// normalises its direction once (`camera_segment`, the wavefront loop's `start_path`).
    /// Normalising here as well cost a second square root and division on the path's
    /// critical path, 6% of a pins render (`docs/performance.md`).
    #[inline]
    pub fn ray(&self, px: f32, py: f32) -> (Vec3, Vec3) {
        let sx = (2.0 * px / self.w - 1.0) * self.tan_half * self.aspect;
        let sy = (1.0 - 2.0 * py / self.h) * self.tan_half;
        (self.o, self.f + self.r * sx + self.u * sy)
    }
}

/// The role of an estimator query: [`Medium::primary`] or [`Medium::secondary`].
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Which {
    Primary = 0,
    Secondary = 1,
}

/// The scene in the form the inner loop wants it (sun direction normalised, flags, the
/// media's boxes per estimator role).
pub struct Ctx<'a> {
    pub(crate) media: &'a [Medium],
    /// `boxes[Which as usize]`: the world boxes of the media's primary / secondary
    /// estimators (see [`super::bounds`]).
    pub(crate) boxes: [MediaBoxes; 2],
    pub(crate) sun: Option<(Vec3, Vec3)>,
    pub(crate) env: Option<Vec3>,
    /// The scene's albedo (a path's throughput factor per vertex).
    pub albedo: f32,
    pub(crate) g: f32,
    pub(crate) max_bounces: u32,
    /// One medium whose primary and secondary estimators are the same object: a query
    /// pair along one ray may mix the two roles ([`Ctx::paired`]).
    same_roles: bool,
}

impl Scene {
    /// Every check `render` makes on the scene (not on the settings).
    pub fn validate(&self) -> Result<(), RenderError> {
        self.camera.frame()?;
        if let Some(sun) = &self.sun {
            let d = Vec3::from_array(sun.dir);
            if !d.is_finite() || d.length_squared() == 0.0 || !d.normalize().is_finite() {
                return Err(invalid("sun", format!("direction {:?}", sun.dir)));
            }
            if !radiance_ok(&sun.radiance) {
                return Err(invalid("sun", format!("radiance {:?}", sun.radiance)));
            }
        }
        if !radiance_ok(&self.env_radiance) {
            return Err(invalid(
                "environment",
                format!("radiance {:?}", self.env_radiance),
            ));
        }
        if !(0.0..=1.0).contains(&self.albedo) {
            return Err(invalid("albedo", format!("{} not in [0, 1]", self.albedo)));
        }
        if !(self.g > -1.0 && self.g < 1.0) {
            return Err(invalid("phase", format!("g = {} not in (-1, 1)", self.g)));
        }
        Ok(())
    }

    /// The scene as the path loop reads it ([`Ctx::walk`]), for paths of up to
    /// `max_bounces` scattering events.
    pub fn ctx(&self, max_bounces: u32) -> Ctx<'_> {
        let sun = self.sun.as_ref().and_then(|s| {
            let d = Vec3::from_array(s.dir).normalize_or_zero();
            let r = Vec3::from_array(s.radiance);
            (d != Vec3::ZERO && radiance_ok(&s.radiance) && r != Vec3::ZERO).then_some((d, r))
        });
        let env = Vec3::from_array(self.env_radiance);
        let env = (radiance_ok(&self.env_radiance) && env != Vec3::ZERO).then_some(env);
        let boxes =
            |which: Which| MediaBoxes::new(self.media.iter().map(|m| Ctx::est(m, which).bounds()));
        Ctx {
            media: &self.media,
            boxes: [boxes(Which::Primary), boxes(Which::Secondary)],
            sun,
            env,
            albedo: if self.albedo.is_nan() {
                0.0
            } else {
                self.albedo.clamp(0.0, 1.0)
            },
            g: self.g,
            max_bounces,
            same_roles: match &self.media[..] {
                [m] => std::ptr::addr_eq(Arc::as_ptr(&m.primary), Arc::as_ptr(&m.secondary)),
                _ => false,
            },
        }
    }

    /// [`Scene::ctx`] with the media's boxes scanned chunk by chunk, never through the
    /// hierarchy (the tests' reference).
    #[cfg(test)]
    pub(crate) fn ctx_linear(&self, max_bounces: u32) -> Ctx<'_> {
        let mut ctx = self.ctx(max_bounces);
        ctx.boxes = [Which::Primary, Which::Secondary]
            .map(|w| MediaBoxes::linear(self.media.iter().map(|m| Ctx::est(m, w).bounds())));
        ctx
    }

    /// Radiance arriving at `o` from direction `-d` (one path sample). For tests and for
    /// callers with their own sample loop. Invalid rays give 0; out-of-range scene values
    /// are clamped (use [`Scene::validate`] to reject them instead).
    pub fn radiance(&self, o: Vec3, d: Vec3, max_bounces: u32, rng: &mut Pcg32) -> [f32; 3] {
        let c = self.ctx(max_bounces).trace(o, d, rng);
        if c.is_finite() {
            c.to_array()
        } else {
            [0.0; 3]
        }
    }
}

impl Ctx<'_> {
    pub(crate) fn est(m: &Medium, which: Which) -> &dyn TransportEstimator {
        match which {
            Which::Primary => &*m.primary,
            Which::Secondary => &*m.secondary,
        }
    }

    /// Product of the instances' transmittances (additive extinction). Media whose box the
    /// ray misses are skipped (their transmittance is 1).
    #[inline]
    pub(crate) fn transmittance(&self, which: Which, o: Vec3, d: Vec3, rng: &mut Pcg32) -> f32 {
        let media = self.media;
        let boxes = &self.boxes[which as usize];
        debug_assert_eq!(boxes.len(), media.len());
        let mut t = 1.0f32;
        let Some(ray) = RaySlabs::new(o, d) else {
            // Not a ray the box test reasons about: every medium decides for itself.
            for m in media {
                t *= Self::est(m, which).transmittance(o, d, f32::INFINITY, rng);
                if t == 0.0 {
                    break;
                }
            }
            return t;
        };
        boxes.for_each_met(&ray, f32::INFINITY, |i| {
            t *= Self::est(&media[i], which).transmittance(o, d, f32::INFINITY, rng);
            t != 0.0
        });
        t
    }

    /// With one medium: whether `transmittance` / `distance` ask its estimator for the ray
    /// `o + t d` (not when the ray misses the medium's box). For the wavefront loop, which
    /// asks the estimator itself.
    pub(crate) fn single_medium_asked(&self, which: Which, o: Vec3, d: Vec3) -> bool {
        debug_assert_eq!(self.media.len(), 1);
        // Every scattering vertex lies in the medium's box: no slab test for its rays. (A
        // finite `o` strictly inside; `RaySlabs::new` still refuses a bad `d`, and then the
        // estimator is asked too.)
        if self.boxes[which as usize].strictly_inside(0, o) {
            return true;
        }
        let Some(ray) = RaySlabs::new(o, d) else {
            return true;
        };
        self.boxes[which as usize].entry_of(0, &ray, f32::INFINITY) != MISS
    }

    /// Whether a transmittance query of role `t_role` and a distance query of role `d_role`
    /// along one ray go to [`Ctx::transmittance_and_distance`]: with one medium, whose
    /// estimator for both roles is the same. (With several media the product and the
    /// nearest-collision search ask different media over different segments.)
    #[inline]
    pub(crate) fn paired(&self, t_role: Which, d_role: Which) -> bool {
        self.media.len() == 1 && (t_role == d_role || self.same_roles)
    }

    /// The one medium's [`TransportEstimator::transmittance_and_distance`] for the ray
    /// `o + t d` (a [`Ctx::paired`] pair of roles), after the box test of
    /// `transmittance` and `distance`: a ray that misses the box draws nothing.
    #[inline]
    pub(crate) fn transmittance_and_distance(
        &self,
        t_role: Which,
        o: Vec3,
        d: Vec3,
        rng: &mut Pcg32,
    ) -> (f32, Option<f32>) {
        if !self.single_medium_asked(t_role, o, d) {
            return (1.0, None);
        }
        Self::est(&self.media[0], t_role).transmittance_and_distance(o, d, f32::INFINITY, rng)
    }

    /// Nearest collision over the instances. Each later instance only searches up to the
    /// nearest collision so far: whether and where it collides before that point has the
    /// same distribution as in an untruncated search, which is all the minimum needs, and
    /// it holds in any order. So the media whose box the ray meets are asked in the order of
    /// their box entries (per chunk of `CHUNK` media, [`MetChunks`]), and each chunk's search
    /// stops at the first box that starts beyond the nearest collision so far.
    #[inline]
    pub(crate) fn distance(&self, which: Which, o: Vec3, d: Vec3, rng: &mut Pcg32) -> Option<f32> {
        let media = self.media;
        let boxes = &self.boxes[which as usize];
        debug_assert_eq!(boxes.len(), media.len());
        let mut best = f32::INFINITY;
        let mut sample = |m: &Medium, best: &mut f32| {
            if let Some(t) = Self::est(m, which).sample_distance(o, d, *best, rng)
                && t < *best
            {
                *best = t;
            }
        };
        let Some(ray) = RaySlabs::new(o, d) else {
            for m in media {
                sample(m, &mut best);
            }
            return (best < f32::INFINITY).then_some(best);
        };
        let mut chunks = MetChunks::new();
        while chunks.advance(boxes, &ray, best) {
            for &j in &chunks.order[..chunks.met] {
                if chunks.entry[j as usize] > best {
                    break;
                }
                sample(&media[chunks.start + j as usize], &mut best);
            }
        }
        (best < f32::INFINITY).then_some(best)
    }

    /// One path. Escapes are scored by transmittance estimates rather than by the 0/1
    /// outcome of distance sampling: at the camera, `env * T(camera ray)`; at each vertex,
    /// `env * T(w)` along the phase-sampled direction `w` that the path then continues in
    /// (phase pdf and phase value cancel). The continuation scores nothing when it escapes,
    /// since `E[T] = P(escape)` already paid for that. The sun is a delta light: it is seen
    /// only through next-event estimation, `phase * T * radiance`. Scattering weights the
    /// throughput by the albedo (no roulette); `max_bounces` vertices at most.
    pub fn trace(&self, o: Vec3, d: Vec3, rng: &mut Pcg32) -> Vec3 {
        let (l, hit) = self.camera_segment(o, d, rng);
        match hit {
            None => l,
            Some((x, d, t)) => self.walk(
                l,
                x,
                d,
                self.albedo,
                t as f64,
                Which::Primary,
                rng,
                &mut NoHook,
            ),
        }
    }

    /// The camera segment of a path: the environment seen through it, and the first
    /// scattering vertex `(x, d, t)` along the normalised direction `d` (`None`: the path
    /// ends here).
    pub fn camera_segment(
        &self,
        o: Vec3,
        d: Vec3,
        rng: &mut Pcg32,
    ) -> (Vec3, Option<(Vec3, Vec3, f32)>) {
        let mut l = Vec3::ZERO;
        let d = d.normalize_or_zero();
        if !o.is_finite() || d == Vec3::ZERO {
            return (l, None);
        }
        let scatters = !(self.albedo <= 0.0 || self.max_bounces == 0);
        if let Some(env) = self.env {
            if scatters && self.paired(Which::Primary, Which::Primary) {
                let (tr, hit) = self.transmittance_and_distance(Which::Primary, o, d, rng);
                l += env * tr;
                return (l, hit.map(|t| (o + d * t, d, t)));
            }
            l += env * self.transmittance(Which::Primary, o, d, rng);
        }
        if !scatters {
            return (l, None);
        }
        let Some(t) = self.distance(Which::Primary, o, d, rng) else {
            return (l, None);
        };
        (l, Some((o + d * t, d, t)))
    }

    /// The path loop, the one every path of this module runs: from vertex `x` (depth 1)
    /// reached along `dir` with throughput `beta` after `path_len` world units, adding to
    /// `l` what each vertex scores. `first` is the estimator of the first vertex's shadow
    /// and environment rays (primary from the camera, secondary for a vertex's postfix).
    /// `hook` sees each vertex before its estimators run and may end the path there (the
    /// a path-space cache).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub fn walk<H: VertexHook>(
        &self,
        mut l: Vec3,
        mut x: Vec3,
        mut dir: Vec3,
        mut beta: f32,
        mut path_len: f64,
        first: Which,
        rng: &mut Pcg32,
        hook: &mut H,
    ) -> Vec3 {
        let mut depth = 1u32;
        loop {
            let v = PathVertex {
                depth,
                x,
                dir,
                path_len,
                beta,
            };
            if let Some(rest) = hook.at_vertex(&v, l, rng) {
                return l + rest;
            }
            let shadow = if depth == 1 { first } else { Which::Secondary };
            if let Some((sun_dir, sun_rad)) = self.sun {
                let ph = hg_phase(self.g, dir.dot(sun_dir));
                if ph > 0.0 {
                    let tr = self.transmittance(shadow, x, sun_dir, rng);
                    l += sun_rad * (beta * ph * tr);
                }
            }
            let w = sample_hg(dir, self.g, rng.next_f32(), rng.next_f32());
            let last = depth >= self.max_bounces;
            let hit = match self.env {
                Some(env) if !last && self.paired(shadow, Which::Secondary) => {
                    let (tr, hit) = self.transmittance_and_distance(shadow, x, w, rng);
                    l += env * (beta * tr);
                    hit
                }
                env => {
                    if let Some(env) = env {
                        l += env * (beta * self.transmittance(shadow, x, w, rng));
                    }
                    if last {
                        break;
                    }
                    self.distance(Which::Secondary, x, w, rng)
                }
            };
            let Some(t) = hit else {
                break;
            };
            x += w * t;
            path_len += t as f64;
            dir = w;
            beta *= self.albedo;
            depth += 1;
        }
        l
    }
}

/// A scattering vertex of [`Ctx::walk`], before its estimators run.
pub struct PathVertex {
    /// 1 for the first scattering vertex.
    pub depth: u32,
    pub x: Vec3,
    /// The direction the path arrived along.
    pub dir: Vec3,
    /// World units travelled from the walk's start (the camera, for camera paths).
    pub path_len: f64,
    pub beta: f32,
}

/// What a path does at each vertex besides scoring it (a path-space cache records vertices
/// for training, or ends the path in a converged cell).
pub trait VertexHook {
    /// `l`: what the walk has scored so far. `Some(r)`: end the path, the walk returning
    /// `l + r`.
    fn at_vertex(&mut self, v: &PathVertex, l: Vec3, rng: &mut Pcg32) -> Option<Vec3>;
}

/// The plain path: no hook (compiled away).
pub struct NoHook;

impl VertexHook for NoHook {
    #[inline(always)]
    fn at_vertex(&mut self, _: &PathVertex, _: Vec3, _: &mut Pcg32) -> Option<Vec3> {
        None
    }
}

/// Checks the settings and runs the sample loop of [`render`] with `trace(o, d, rng)` as
/// the per-sample radiance (after the two pixel-jitter draws). `start` is when the
/// render's clock started (earlier than now when a pre-pass, e.g. cache training, counts
/// towards the time budget). Shared by the other entry points of the module so that they
/// keep `render`'s determinism and budget semantics.
pub fn accumulate<T>(
    scene: &Scene,
    settings: &RenderSettings,
    start: Instant,
    trace: T,
) -> Result<RenderOutput, RenderError>
where
    T: Fn(Vec3, Vec3, &mut Pcg32) -> Vec3 + Sync,
{
    let frame = scene.camera.frame()?;
    check_settings(settings)?;
    let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
    let seed = settings.seed;
    let sample = |x: usize, y: usize, s: u32| -> Vec3 {
        let mut rng = Pcg32::for_sample(seed, (y * w + x) as u64, s as u64);
        let (jx, jy) = (rng.next_f32(), rng.next_f32());
        let (o, d) = frame.ray(x as f32 + jx, y as f32 + jy);
        let c = trace(o, d, &mut rng);
        if c.is_finite() { c } else { Vec3::ZERO }
    };
    let row = |y: usize, acc: &mut [[f64; 3]], samples: std::ops::Range<u32>| {
        for (x, a) in acc.iter_mut().enumerate() {
            for s in samples.clone() {
                let c = sample(x, y, s);
                a[0] += c.x as f64;
                a[1] += c.y as f64;
                a[2] += c.z as f64;
            }
        }
    };
    let mut sums = pixel_sums(w * h)?;
    let spp = in_pool(settings, || {
        run_budget(settings.budget, start, w, &mut sums, row)
    })?;
    Ok(average_sums(scene, &sums, spp, start))
}

/// The per-pixel sums of an image of `pixels` pixels, zeroed, allocated fallibly (the size
/// comes from the camera settings).
pub(crate) fn pixel_sums(pixels: usize) -> Result<Vec<[f64; 3]>, RenderError> {
    let mut sums = Vec::new();
    sums.try_reserve_exact(pixels)
        .map_err(|_| RenderError::OutOfMemory {
            what: "the image's per-pixel sums",
            bytes: (pixels as u64).saturating_mul(24),
        })?;
    sums.resize(pixels, [0f64; 3]);
    Ok(sums)
}

/// The sample loop of [`render`] and the wavefront loop: `row(y, sums of row y, samples)`
/// adds samples `samples` of every pixel of image row `y` to their sums, in sample order,
/// rows in parallel. `Spp(n)` asks each row once for `0..n`; `Seconds` asks pass after pass
/// (`pass..pass + 1`) until the time since `start` is spent. Returns the samples per pixel
/// reached. Both loops share it so that their budgets and determinism cannot drift apart.
pub(crate) fn run_budget(
    budget: Budget,
    start: Instant,
    width: usize,
    sums: &mut [[f64; 3]],
    row: impl Fn(usize, &mut [[f64; 3]], std::ops::Range<u32>) + Sync,
) -> u32 {
    match budget {
        Budget::Spp(spp) => {
            sums.par_chunks_mut(width)
                .enumerate()
                .for_each(|(y, acc)| row(y, acc, 0..spp));
            spp
        }
        Budget::Seconds(secs) => {
            let budget = Duration::from_secs_f64(secs.min(1e9));
            let mut pass = 0u32;
            loop {
                sums.par_chunks_mut(width)
                    .enumerate()
                    .for_each(|(y, acc)| row(y, acc, pass..pass + 1));
                pass += 1;
                if start.elapsed() >= budget || pass == u32::MAX {
                    break pass;
                }
            }
        }
    }
}

/// The image of `spp` samples per pixel from their per-pixel sums, with the time since `start`:
/// the end of [`render`] and of the wavefront loop.
pub(crate) fn average_sums(
    scene: &Scene,
    sums: &[[f64; 3]],
    spp: u32,
    start: Instant,
) -> RenderOutput {
    let seconds = start.elapsed().as_secs_f64();
    let inv = 1.0 / spp as f64;
    let rgb = sums.iter().map(|s| s.map(|c| (c * inv) as f32)).collect();
    RenderOutput {
        image: Image {
            width: scene.camera.width,
            height: scene.camera.height,
            rgb,
        },
        spp,
        seconds,
    }
}

/// The budget and thread checks of [`render`].
pub fn check_settings(settings: &RenderSettings) -> Result<(), RenderError> {
    match settings.budget {
        Budget::Spp(0) => return Err(invalid("budget", "0 samples per pixel".into())),
        Budget::Seconds(s) if !(s >= 0.0 && s.is_finite()) => {
            return Err(invalid("budget", format!("{s} seconds")));
        }
        _ => {}
    }
    if settings.threads == Some(0) {
        return Err(invalid("threads", "0 threads".into()));
    }
    Ok(())
}

/// Runs `f` in a private pool of `settings.threads` workers, or in rayon's global pool.
pub fn in_pool<R: Send>(
    settings: &RenderSettings,
    f: impl FnOnce() -> R + Send,
) -> Result<R, RenderError> {
    match settings.threads {
        Some(n) => Ok(rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .map_err(|e| RenderError::ThreadPool(e.to_string()))?
            .install(f)),
        None => Ok(f()),
    }
}
