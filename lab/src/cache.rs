//! # Path-space radiance cache (`pinms+cache`)
//!
//! A hash-grid radiance cache for the volumetric path tracer after the adaptive path space
//! filtering thesis (docs/background.md, sections 2.4 and 4.2) and
//! Binder et al.'s hashed cells it builds on:
//!
//! * **Cells**: a vertex position is quantised on a grid whose cell size grows with the
//!   path footprint (level of detail: `level = ceil(log2(footprint / cell_size))`, the
//!   footprint being the path length from the camera times the pixel's angular size times
//!   `footprint_scale`), optionally with one of six direction bins (the cube face of the
//!   propagation direction, for anisotropic phase functions). Cells live in a fixed,
//!   power-of-two open-addressing table: the slot is one hash of the key, a second,
//!   independent 32-bit hash is stored as the **fingerprint**, and linear probing (up to
//!   [`MAX_PROBES`] slots) resolves slot collisions: a probe that meets a different
//!   fingerprint moves on, so two keys that share a slot never share statistics (up to a
//!   2^-32 fingerprint clash). A full probe window drops the sample (counted).
//! * **Statistics**: per cell the sample count, the RGB sum and the second moment of the
//!   mean channel, hence the mean and the standard error of the mean.
//! * **What is cached**: at a scattering vertex with throughput `beta`, the vertex's
//!   *postfix* `P = (everything the path scores from this vertex on) / beta`: the sun and
//!   environment next-event terms and the rest of the path. That is the in-scattered
//!   radiance estimate the thesis stores per cell (eq. 4.14's `f_post`).
//! * **Two passes, deterministic**: a training pass traces `training_spp` uncached paths per
//!   pixel (their own seeds), in parallel per image row, and inserts the postfix samples
//!   row by row in pixel and sample order on one thread, so the table does not depend on
//!   the thread count. The rendering pass then reads the frozen table: at every
//!   **secondary** vertex (depth >= 2) a jittered lookup (the position moved uniformly
//!   within one cell of its level before quantising, Binder's jittered hashing) finds the
//!   cell, and if it has at least `min_samples` samples and its standard error is at most
//!   `max_rel_std_err` times its mean, the path ends there and scores `beta * mean`.
//!
//! The cached render is **biased** (spatial and, with jitter, stochastic filtering of `P`
//! over a cell), like path space filtering itself; what it buys is shorter paths. The
//! training pass counts towards the render's time and time budget.
//!
//! **Not for**: unbiased references; scenes where the bounce limit binds (cached postfixes
//! are not keyed by the bounces left: keep `max_bounces` large, e.g. >= 32); progressive
//! or animated use (no eviction, no exponential moving average: one training pass per
//! render). It differs from the thesis's adaptive path graphs, which terminate when the
//! *accumulated path variance* would exceed a budget and blend with `alpha`: here a path
//! terminates when the *cell* is converged enough, the criterion this project asked for.

use glam::Vec3;
use pinrender::render::{
    Ctx, NoHook, PathVertex, Pcg32, RenderError, RenderOutput, RenderSettings, Scene, VertexHook,
    Which, accumulate, check_settings, in_pool, splitmix64,
};
use rayon::prelude::*;
use std::time::Instant;

/// Largest `capacity_log2` accepted (2^26 cells of 48 bytes: 3 GiB).
pub const MAX_CAPACITY_LOG2: u32 = 26;

/// Options of the radiance cache ([`render_cached`]).
#[derive(Clone, Debug, PartialEq)]
pub struct CacheSettings {
    /// The table holds `2^capacity_log2` cells (1 ..= [`MAX_CAPACITY_LOG2`]).
    pub capacity_log2: u32,
    /// Cell edge at level 0, world units (> 0).
    pub cell_size: f32,
    /// Multiplies the footprint `path length x pixel angle` before the level of detail is
    /// taken; 0 disables the level of detail (every cell at level 0).
    pub footprint_scale: f32,
    /// Key cells also by the cube face of the propagation direction (6 bins).
    pub direction_bins: bool,
    /// Uncached training paths per pixel (>= 1).
    pub training_spp: u32,
    /// Minimum cell sample count before a path may terminate into it (>= 1).
    pub min_samples: u32,
    /// Largest standard error of the cell mean, relative to the mean, for termination.
    pub max_rel_std_err: f32,
    /// Jitter the lookup position within one cell (reduces blocky bias, adds some noise).
    pub jitter: bool,
}

impl Default for CacheSettings {
    fn default() -> Self {
        CacheSettings {
            capacity_log2: 18,
            cell_size: 0.05,
            footprint_scale: 4.0,
            direction_bins: false,
            training_spp: 4,
            min_samples: 16,
            max_rel_std_err: 0.05,
            jitter: true,
        }
    }
}

impl CacheSettings {
    /// Rejects values the cache cannot work with.
    pub fn validate(&self) -> Result<(), RenderError> {
        let bad = |why: String| {
            Err(RenderError::Invalid {
                what: "cache settings",
                why,
            })
        };
        if !(1..=MAX_CAPACITY_LOG2).contains(&self.capacity_log2) {
            return bad(format!(
                "capacity_log2 {} not in 1..=26",
                self.capacity_log2
            ));
        }
        if !(self.cell_size > 0.0 && self.cell_size.is_finite()) {
            return bad(format!("cell size {}", self.cell_size));
        }
        if !(self.footprint_scale >= 0.0 && self.footprint_scale.is_finite()) {
            return bad(format!("footprint scale {}", self.footprint_scale));
        }
        if self.training_spp == 0 || self.min_samples == 0 {
            return bad("training_spp and min_samples must be >= 1".into());
        }
        if !(self.max_rel_std_err >= 0.0) {
            return bad(format!("max_rel_std_err {}", self.max_rel_std_err));
        }
        Ok(())
    }
}

/// Longest linear-probing run, in slots.
pub const MAX_PROBES: usize = 16;
/// Highest level of detail (cell size `cell_size * 2^MAX_LEVEL`).
pub const MAX_LEVEL: i32 = 24;

/// A cell's identity: quantised position at a level of detail, and a direction bin (0 when
/// directions are not binned).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CellKey {
    pub coords: [i64; 3],
    pub level: i32,
    pub dir_bin: u8,
}

impl CellKey {
    /// The two independent hashes: `(slot hash, fingerprint)`; the fingerprint is never 0
    /// (0 marks an empty slot).
    pub fn hashes(&self) -> (u64, u32) {
        let mut h = splitmix64(self.coords[0] as u64 ^ 0x243F_6A88_85A3_08D3);
        h = splitmix64(h ^ self.coords[1] as u64);
        h = splitmix64(h ^ self.coords[2] as u64);
        h = splitmix64(h ^ ((self.level as u32 as u64) << 8 | self.dir_bin as u64));
        // A second chain with other constants, so that slot and fingerprint bits are
        // independent (the fingerprint must separate keys that share a slot).
        let mut f = splitmix64(self.coords[2] as u64 ^ 0x1319_8A2E_0370_7344);
        f = splitmix64(f ^ self.coords[0] as u64 ^ 0xA409_3822_299F_31D0);
        f = splitmix64(f ^ self.coords[1] as u64);
        f = splitmix64(f ^ ((self.dir_bin as u64) << 40 | self.level as u32 as u64));
        let fp = (f >> 32) as u32;
        (h, if fp == 0 { 1 } else { fp })
    }
}

/// Per-cell statistics.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CellStats {
    pub fingerprint: u32,
    pub n: u32,
    pub sum: [f64; 3],
    /// Sum of squares of the mean channel `(r + g + b) / 3`.
    pub sum_y2: f64,
}

impl CellStats {
    pub fn mean(&self) -> [f64; 3] {
        let inv = 1.0 / self.n.max(1) as f64;
        self.sum.map(|s| s * inv)
    }
    /// Mean of the mean channel.
    pub fn mean_y(&self) -> f64 {
        self.sum.iter().sum::<f64>() / (3.0 * self.n.max(1) as f64)
    }
    /// Unbiased sample variance of the mean channel (0 below 2 samples).
    pub fn variance_y(&self) -> f64 {
        if self.n < 2 {
            return 0.0;
        }
        let n = self.n as f64;
        let m = self.mean_y();
        ((self.sum_y2 / n - m * m) * n / (n - 1.0)).max(0.0)
    }
    /// Standard error of the mean channel's mean (infinite below 2 samples).
    pub fn std_err_y(&self) -> f64 {
        if self.n < 2 {
            f64::INFINITY
        } else {
            (self.variance_y() / self.n as f64).sqrt()
        }
    }
}

/// Outcome of [`RadianceCache::insert`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Insert {
    /// Added to an existing cell with the same fingerprint.
    Existing,
    /// Claimed an empty slot.
    New,
    /// The probe window held only other cells: sample dropped.
    Full,
}

/// Counters of a cache (for reports and tests).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CacheCounters {
    pub inserted: u64,
    pub dropped: u64,
    pub cells: u64,
    /// Probes that met an occupied slot with another fingerprint (collisions detected).
    pub fingerprint_mismatches: u64,
}

/// The hash table. Built single-threaded (deterministic), read concurrently.
#[derive(Clone, Debug)]
pub struct RadianceCache {
    cells: Vec<CellStats>,
    mask: usize,
    counters: CacheCounters,
}

impl RadianceCache {
    /// An empty table of `2^capacity_log2` cells.
    pub fn new(capacity_log2: u32) -> Result<Self, RenderError> {
        if !(1..=MAX_CAPACITY_LOG2).contains(&capacity_log2) {
            return Err(RenderError::Invalid {
                what: "cache capacity",
                why: format!("capacity_log2 {capacity_log2} not in 1..=26"),
            });
        }
        let n = 1usize << capacity_log2;
        Ok(RadianceCache {
            cells: vec![CellStats::default(); n],
            mask: n - 1,
            counters: CacheCounters::default(),
        })
    }

    pub fn capacity(&self) -> usize {
        self.cells.len()
    }

    pub fn counters(&self) -> CacheCounters {
        self.counters
    }

    /// Adds one RGB sample to the cell of `key`. Non-finite samples are ignored (reported
    /// as dropped) so a stray NaN cannot poison a cell.
    pub fn insert(&mut self, key: &CellKey, value: [f64; 3]) -> Insert {
        if !value.iter().all(|v| v.is_finite()) {
            self.counters.dropped += 1;
            return Insert::Full;
        }
        let (h, fp) = key.hashes();
        let y = (value[0] + value[1] + value[2]) / 3.0;
        for i in 0..MAX_PROBES.min(self.cells.len()) {
            let slot = (h as usize).wrapping_add(i) & self.mask;
            let c = &mut self.cells[slot];
            let kind = if c.fingerprint == fp {
                Insert::Existing
            } else if c.fingerprint == 0 {
                c.fingerprint = fp;
                self.counters.cells += 1;
                Insert::New
            } else {
                self.counters.fingerprint_mismatches += 1;
                continue;
            };
            c.n += 1;
            for (s, v) in c.sum.iter_mut().zip(value) {
                *s += v;
            }
            c.sum_y2 += y * y;
            self.counters.inserted += 1;
            return kind;
        }
        self.counters.dropped += 1;
        Insert::Full
    }

    /// The statistics of `key`'s cell, if present (never another key's: fingerprints are
    /// compared along the probe sequence).
    pub fn get(&self, key: &CellKey) -> Option<&CellStats> {
        let (h, fp) = key.hashes();
        for i in 0..MAX_PROBES.min(self.cells.len()) {
            let c = &self.cells[(h as usize).wrapping_add(i) & self.mask];
            if c.fingerprint == fp {
                return Some(c);
            }
            if c.fingerprint == 0 {
                return None;
            }
        }
        None
    }
}

/// Key computation for one render: cell size, level of detail, direction bins.
#[derive(Clone, Copy, Debug)]
pub struct Keyer {
    cell: f64,
    /// Footprint per unit path length (pixel angle x footprint_scale).
    spread: f64,
    dirs: bool,
}

impl Keyer {
    /// `pixel_angle`: the angular size of a pixel in radians.
    pub fn new(settings: &CacheSettings, pixel_angle: f64) -> Self {
        Keyer {
            cell: settings.cell_size as f64,
            spread: settings.footprint_scale as f64 * pixel_angle,
            dirs: settings.direction_bins,
        }
    }

    /// Level of detail for a vertex at path length `path_len` from the camera.
    #[inline]
    pub fn level(&self, path_len: f64) -> i32 {
        let fp = path_len * self.spread;
        if fp > self.cell {
            ((fp / self.cell).log2().ceil() as i32).clamp(0, MAX_LEVEL)
        } else {
            0
        }
    }

    /// Cell size at `level`.
    #[inline]
    pub fn size(&self, level: i32) -> f64 {
        self.cell * (2f64).powi(level)
    }

    /// The key of position `x` (optionally jittered by `u` in `[0,1)^3` within one cell),
    /// propagation direction `dir`, path length `path_len`. `None` for non-finite input or
    /// coordinates beyond the i64 range.
    pub fn key(
        &self,
        x: Vec3,
        dir: Vec3,
        path_len: f64,
        jitter: Option<[f64; 3]>,
    ) -> Option<CellKey> {
        let level = self.level(path_len);
        let s = self.size(level);
        let mut coords = [0i64; 3];
        for a in 0..3 {
            let j = jitter.map_or(0.0, |u| (u[a] - 0.5) * s);
            let q = ((x[a] as f64 + j) / s).floor();
            if !(q.abs() < 9.0e18) {
                return None;
            }
            coords[a] = q as i64;
        }
        let dir_bin = if self.dirs { cube_face(dir) } else { 0 };
        Some(CellKey {
            coords,
            level,
            dir_bin,
        })
    }
}

/// The cube face (0..6) a direction points through.
#[inline]
fn cube_face(d: Vec3) -> u8 {
    let a = d.abs();
    if a.x >= a.y && a.x >= a.z {
        (d.x < 0.0) as u8
    } else if a.y >= a.z {
        2 + (d.y < 0.0) as u8
    } else {
        4 + (d.z < 0.0) as u8
    }
}

/// One scattering vertex of a training path.
#[derive(Clone, Copy)]
struct Vertex {
    x: Vec3,
    dir: Vec3,
    path_len: f64,
    beta: f32,
    l_before: Vec3,
}

/// What [`walk`] does with the cache.
enum Mode<'a> {
    /// Plain path (the tracer's estimator); vertices recorded for training if a Vec given.
    Plain(Option<&'a mut Vec<Vertex>>),
    /// Terminate into the frozen cache at secondary vertices.
    Lookup(&'a RadianceCache, &'a Keyer, &'a CacheSettings),
}

impl VertexHook for Mode<'_> {
    fn at_vertex(&mut self, v: &PathVertex, l: Vec3, rng: &mut Pcg32) -> Option<Vec3> {
        match self {
            Mode::Plain(Some(rec)) => rec.push(Vertex {
                x: v.x,
                dir: v.dir,
                path_len: v.path_len,
                beta: v.beta,
                l_before: l,
            }),
            Mode::Lookup(cache, keyer, cs) if v.depth >= 2 => {
                let jitter = cs
                    .jitter
                    .then(|| [rng.next_f64(), rng.next_f64(), rng.next_f64()]);
                if let Some(c) = keyer
                    .key(v.x, v.dir, v.path_len, jitter)
                    .and_then(|k| cache.get(&k))
                {
                    let m = c.mean_y();
                    if c.n >= cs.min_samples && c.std_err_y() <= cs.max_rel_std_err as f64 * m.abs()
                    {
                        let mean = c.mean();
                        return Some(
                            Vec3::new(mean[0] as f32, mean[1] as f32, mean[2] as f32) * v.beta,
                        );
                    }
                }
            }
            _ => {}
        }
        None
    }
}

/// A camera path: the tracer's camera segment and path loop with the given cache mode. The
/// vertices' radiance is summed apart from the camera segment's (`l_before` of a recorded
/// vertex counts from the first vertex).
fn camera_path(ctx: &Ctx<'_>, o: Vec3, d: Vec3, rng: &mut Pcg32, mut mode: Mode<'_>) -> Vec3 {
    let (l, hit) = ctx.camera_segment(o, d, rng);
    let Some((x, d, t)) = hit else {
        return l;
    };
    l + ctx.walk(
        Vec3::ZERO,
        x,
        d,
        ctx.albedo,
        t as f64,
        Which::Primary,
        rng,
        &mut mode,
    )
}

/// One sample of the postfix `P` at a vertex `x` reached along `dir` (throughput 1, all
/// segments with the `secondary` estimators): what the cache averages per cell. For
/// brute-force references.
pub fn vertex_radiance(
    scene: &Scene,
    x: Vec3,
    dir: Vec3,
    max_bounces: u32,
    rng: &mut Pcg32,
) -> [f32; 3] {
    let ctx = scene.ctx(max_bounces);
    let dir = dir.normalize_or_zero();
    if !x.is_finite() || dir == Vec3::ZERO || max_bounces == 0 {
        return [0.0; 3];
    }
    let l = ctx.walk(
        Vec3::ZERO,
        x,
        dir,
        1.0,
        0.0,
        Which::Secondary,
        rng,
        &mut NoHook,
    );
    if l.is_finite() {
        l.to_array()
    } else {
        [0.0; 3]
    }
}

/// The angular size of one pixel of the scene's camera (vertical), radians.
fn pixel_angle(scene: &Scene) -> f64 {
    let c = &scene.camera;
    2.0 * (c.vfov_deg as f64 * 0.5).to_radians().tan() / c.height.max(1) as f64
}

/// Seed of the training pass: distinct from every render seed's sample streams.
fn training_seed(seed: u64) -> u64 {
    splitmix64(seed ^ 0x7261_6469_616E_6365)
}

/// The training pass: `training_spp` uncached camera paths per pixel; every vertex's
/// postfix inserted in pixel, sample, vertex order on one thread (deterministic for any
/// thread count). Rows are traced in parallel in batches to bound memory.
pub fn train_cache(
    scene: &Scene,
    settings: &RenderSettings,
    cs: &CacheSettings,
) -> Result<RadianceCache, RenderError> {
    scene.validate()?;
    cs.validate()?;
    check_settings(settings)?;
    let frame = scene.camera.frame()?;
    let ctx = scene.ctx(settings.max_bounces);
    let keyer = Keyer::new(cs, pixel_angle(scene));
    let mut cache = RadianceCache::new(cs.capacity_log2)?;
    let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
    let seed = training_seed(settings.seed);
    let row = |y: usize| -> Vec<(CellKey, [f64; 3])> {
        let mut out = Vec::new();
        let mut verts = Vec::new();
        for x in 0..w {
            for s in 0..cs.training_spp {
                let mut rng = Pcg32::for_sample(seed, (y * w + x) as u64, s as u64);
                let (jx, jy) = (rng.next_f32(), rng.next_f32());
                let (o, d) = frame.ray(x as f32 + jx, y as f32 + jy);
                verts.clear();
                let l_end = camera_path(&ctx, o, d, &mut rng, Mode::Plain(Some(&mut verts)));
                if !l_end.is_finite() {
                    continue;
                }
                // The camera term scored before the first vertex is in every l_before, so
                // the differences are exactly the scores from each vertex on.
                for v in &verts {
                    if !(v.beta > 0.0) {
                        continue;
                    }
                    let p = (l_end - v.l_before) / v.beta;
                    if let Some(k) = keyer.key(v.x, v.dir, v.path_len, None) {
                        out.push((k, [p.x as f64, p.y as f64, p.z as f64]));
                    }
                }
            }
        }
        out
    };
    const BATCH: usize = 64;
    for y0 in (0..h).step_by(BATCH) {
        let rows: Vec<Vec<(CellKey, [f64; 3])>> = in_pool(settings, || {
            (y0..(y0 + BATCH).min(h)).into_par_iter().map(row).collect()
        })?;
        for r in rows {
            for (k, v) in r {
                cache.insert(&k, v);
            }
        }
    }
    Ok(cache)
}

/// `pinrender::render::render` with the radiance cache `cs`: training pass, then the
/// rendering pass with termination into the cache. The training time is part of
/// `RenderOutput::seconds` and of a `Budget::Seconds` budget.
pub fn render_cached(
    scene: &Scene,
    settings: &RenderSettings,
    cs: &CacheSettings,
) -> Result<RenderOutput, RenderError> {
    let start = Instant::now();
    let cache = train_cache(scene, settings, cs)?;
    render_with_cache(scene, settings, cs, &cache, start)
}

/// The rendering pass over an already trained cache (for tests and for reusing a cache
/// across renders of the same scene). `start` is when the render's clock started.
pub fn render_with_cache(
    scene: &Scene,
    settings: &RenderSettings,
    cs: &CacheSettings,
    cache: &RadianceCache,
    start: Instant,
) -> Result<RenderOutput, RenderError> {
    scene.validate()?;
    cs.validate()?;
    let ctx = scene.ctx(settings.max_bounces);
    let keyer = Keyer::new(cs, pixel_angle(scene));
    accumulate(scene, settings, start, |o, d, rng| {
        camera_path(&ctx, o, d, rng, Mode::Lookup(cache, &keyer, cs))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use pinrender::render::{
        Aabb, Budget, Camera, DeltaTracking, HomogeneousBox, Image, MajorantGrid, Medium,
        RatioTracking, Sun,
    };
    use std::sync::Arc;

    /// A homogeneous box `[-0.5, 0.6]^3` (centre 0.05: the level-0 cell `[0, 0.1)^3` of a
    /// 0.1 grid is centred on it), multiple scattering, sun and sky.
    fn box_scene(size: u32) -> Scene {
        let hb =
            Arc::new(HomogeneousBox::new(Aabb::from_arrays([-0.5; 3], [0.6; 3]), 6.0).unwrap());
        let maj = Arc::new(MajorantGrid::from_field(&*hb, [1, 1, 1]).unwrap());
        Scene {
            camera: Camera {
                origin: [0.05, 0.3, 3.0],
                target: [0.05, 0.05, 0.05],
                vfov_deg: 30.0,
                width: size,
                height: size,
            },
            sun: Some(Sun {
                dir: [0.3, 1.0, 0.4],
                radiance: [2.0, 1.8, 1.5],
            }),
            env_radiance: [0.3, 0.4, 0.5],
            albedo: 0.9,
            g: 0.0,
            media: vec![Medium::new(
                Arc::new(DeltaTracking::new(hb.clone(), maj.clone())),
                Arc::new(RatioTracking::new(hb, maj)),
            )],
        }
    }

    /// The settings of the tests' renders, with the cache to render with.
    fn settings(
        spp: u32,
        threads: Option<usize>,
        cache: Option<CacheSettings>,
    ) -> (RenderSettings, Option<CacheSettings>) {
        let st = RenderSettings {
            max_bounces: 64,
            seed: 5,
            budget: Budget::Spp(spp),
            threads,
        };
        (st, cache)
    }

    /// `render_cached` with a cache, the plain renderer without.
    fn render(
        scene: &Scene,
        (st, cache): &(RenderSettings, Option<CacheSettings>),
    ) -> Result<RenderOutput, RenderError> {
        match cache {
            Some(cs) => render_cached(scene, st, cs),
            None => pinrender::render::render(scene, st),
        }
    }

    #[test]
    fn fingerprints_detect_collisions_in_a_tiny_table() {
        // Two slots: almost every pair of keys shares a slot.
        let mut c = RadianceCache::new(1).unwrap();
        let keys: Vec<CellKey> = (0..40)
            .map(|i| CellKey {
                coords: [i, -i, 3 * i],
                level: 0,
                dir_bin: 0,
            })
            .collect();
        assert_eq!(c.insert(&keys[0], [1.0; 3]), Insert::New);
        assert_eq!(c.insert(&keys[1], [2.0; 3]), Insert::New);
        // The table is full: every other key collides, is told apart by its fingerprint,
        // and is dropped, never merged into a foreign cell.
        for k in &keys[2..] {
            assert_eq!(c.insert(k, [100.0; 3]), Insert::Full);
            assert!(c.get(k).is_none());
        }
        assert_eq!(c.insert(&keys[0], [3.0; 3]), Insert::Existing);
        let s0 = c.get(&keys[0]).unwrap();
        assert_eq!((s0.n, s0.mean()), (2, [2.0; 3]));
        assert_eq!(c.get(&keys[1]).unwrap().mean(), [2.0; 3]);
        let k = c.counters();
        assert_eq!((k.cells, k.inserted, k.dropped), (2, 3, 38));
        assert!(k.fingerprint_mismatches >= 38);
        // All 40 fingerprints are distinct (what makes the detection work).
        let mut fps: Vec<u32> = keys.iter().map(|k| k.hashes().1).collect();
        fps.sort();
        fps.dedup();
        assert_eq!(fps.len(), 40);
        // Non-finite samples never enter a cell.
        assert_eq!(c.insert(&keys[0], [f64::NAN, 0.0, 0.0]), Insert::Full);
        assert_eq!(c.get(&keys[0]).unwrap().n, 2);
        assert!(RadianceCache::new(0).is_err() && RadianceCache::new(40).is_err());
    }

    #[test]
    fn keys_levels_and_validation() {
        let cs = CacheSettings {
            cell_size: 0.1,
            footprint_scale: 1.0,
            direction_bins: true,
            ..CacheSettings::default()
        };
        let k = Keyer::new(&cs, 0.01);
        assert_eq!(k.level(1.0), 0); // footprint 0.01 < cell
        assert_eq!(k.level(10.0), 0); // footprint 0.1 = cell
        assert_eq!(k.level(20.0), 1);
        assert_eq!(k.level(1e30), MAX_LEVEL);
        let a = k
            .key(Vec3::new(0.05, -0.05, 0.15), Vec3::NEG_Z, 1.0, None)
            .unwrap();
        assert_eq!((a.coords, a.level, a.dir_bin), ([0, -1, 1], 0, 5));
        assert!(k.key(Vec3::NAN, Vec3::X, 1.0, None).is_none());
        assert!(k.key(Vec3::splat(1e30), Vec3::X, 1.0, None).is_none());
        for bad in [
            CacheSettings {
                capacity_log2: 0,
                ..CacheSettings::default()
            },
            CacheSettings {
                cell_size: f32::NAN,
                ..CacheSettings::default()
            },
            CacheSettings {
                training_spp: 0,
                ..CacheSettings::default()
            },
            CacheSettings {
                max_rel_std_err: f32::NAN,
                ..CacheSettings::default()
            },
        ] {
            assert!(render(&box_scene(4), &settings(1, Some(1), Some(bad))).is_err());
        }
    }

    /// The cell around the box centre (where the postfix has zero gradient by symmetry) is
    /// within its own standard error of a brute-force reference: the mean of `P` at
    /// uniform points of that cell, many paths each.
    #[test]
    fn cache_cell_matches_brute_force() {
        let scene = box_scene(24);
        let cs = CacheSettings {
            cell_size: 0.1,
            footprint_scale: 0.0,
            training_spp: 160,
            ..CacheSettings::default()
        };
        let (st, _) = settings(1, None, Some(cs.clone()));
        let cache = train_cache(&scene, &st, &cs).unwrap();
        let key = CellKey {
            coords: [0; 3],
            level: 0,
            dir_bin: 0,
        };
        let cell = *cache.get(&key).expect("centre cell trained");
        assert!(cell.n > 200, "only {} samples", cell.n);
        let mut rng = Pcg32::new(77, 1);
        let n = 40_000;
        let (mut s, mut s2) = (0.0, 0.0);
        for _ in 0..n {
            let x = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 0.1;
            let z = 2.0 * rng.next_f32() - 1.0;
            let phi = std::f32::consts::TAU * rng.next_f32();
            let r = (1.0 - z * z).max(0.0).sqrt();
            let d = Vec3::new(r * phi.cos(), r * phi.sin(), z);
            let p = vertex_radiance(&scene, x, d, 64, &mut rng);
            let y = (p[0] + p[1] + p[2]) as f64 / 3.0;
            s += y;
            s2 += y * y;
        }
        let m = s / n as f64;
        let se = ((s2 / n as f64 - m * m) / n as f64).sqrt();
        let tol = 4.0 * (cell.std_err_y().powi(2) + se * se).sqrt();
        eprintln!(
            "centre cell: cache {:.5} +- {:.5} (n = {}), brute force {m:.5} +- {se:.5}",
            cell.mean_y(),
            cell.std_err_y(),
            cell.n
        );
        assert!((cell.mean_y() - m).abs() <= tol, "{} vs {m}", cell.mean_y());
    }

    #[test]
    fn cached_render_is_independent_of_threads() {
        let scene = box_scene(16);
        let cs = CacheSettings {
            training_spp: 4,
            min_samples: 4,
            max_rel_std_err: 0.2,
            ..CacheSettings::default()
        };
        let a = render(&scene, &settings(4, Some(1), Some(cs.clone()))).unwrap();
        let b = render(&scene, &settings(4, Some(2), Some(cs.clone()))).unwrap();
        let c = render(&scene, &settings(4, None, Some(cs))).unwrap();
        assert_eq!(a.image, b.image);
        assert_eq!(a.image, c.image);
        // The cache changes the image (paths do terminate into it) but not grossly.
        let plain = render(&scene, &settings(4, Some(1), None)).unwrap();
        assert_ne!(plain.image, a.image);
        let mean =
            |im: &Image| im.rgb.iter().map(|p| p[0] as f64).sum::<f64>() / im.rgb.len() as f64;
        let (pm, cm) = (mean(&plain.image), mean(&a.image));
        assert!((pm - cm).abs() < 0.1 * pm, "plain {pm} cached {cm}");
    }
}
