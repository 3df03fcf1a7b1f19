//! The CPU path tracer's sample loop in wavefront form: the paths of a tile advance together,
//! and every round the pin (or other) queries they are waiting for are answered through the
//! estimators' batch methods ([`TransportEstimator::transmittance_batch`],
//! [`TransportEstimator::sample_distance_batch`]), so that a pin estimator can answer them
//! with the prefetching, lane-parallel batch API of [`crate::Sampler`].
//!
//! **Same image as [`super::render`], bit for bit, whatever the batch size.** Every path owns
//! its generator (`Pcg32::for_sample`, as in `render`) and asks its queries one after the
//! other in the order of `Ctx::trace`; a batch method must return what the single queries
//! would return for each ray and its generator (the contract of the trait), so which other
//! paths share a round cannot change a path's numbers. Per-pixel sums run in sample order, as
//! in `render`. The tests compare whole images for several batch sizes against `render`.
//!
//! Scenes with more than one medium are traced the same way, but their queries go through
//! `Ctx`'s per-ray product and nearest-collision search (one query at a time): batching pays
//! where one medium answers every query.

use glam::Vec3;
use std::time::Instant;

use super::RenderError;
use super::TransportEstimator;
use super::phase::{hg_phase, sample_hg};
use super::rng::Pcg32;
use super::tracer::{
    Ctx, RenderOutput, RenderSettings, Scene, Which, average_sums, check_settings, in_pool,
    run_budget,
};

/// Where a path is in `Ctx::trace`.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Stage {
    /// Environment through the camera ray (`env * T`).
    CameraT,
    /// The first collision along the camera ray.
    CameraD,
    /// Next-event estimation of the sun at the vertex.
    Sun,
    /// Phase sampling of the continuation, then the environment along it.
    Env,
    /// The next collision along the continuation.
    Next,
    Done,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Kind {
    Transmittance,
    Distance,
}

/// One path of the tile.
#[derive(Clone)]
struct Path {
    rng: Pcg32,
    stage: Stage,
    /// Camera ray, then the current vertex.
    x: Vec3,
    /// Direction that reached `x` (the camera direction before the first vertex).
    dir: Vec3,
    /// Phase-sampled continuation.
    w: Vec3,
    beta: f32,
    depth: u32,
    /// Phase value of the pending sun query.
    ph: f32,
    l: Vec3,
}

/// A query a path waits for.
#[derive(Clone, Copy)]
struct Query {
    kind: Kind,
    which: Which,
    o: Vec3,
    d: Vec3,
}

impl Ctx<'_> {
    fn start_path(&self, o: Vec3, d: Vec3, rng: Pcg32) -> Path {
        let d = d.normalize_or_zero();
        let stage = if !o.is_finite() || d == Vec3::ZERO {
            Stage::Done
        } else {
            Stage::CameraT
        };
        Path {
            rng,
            stage,
            x: o,
            dir: d,
            w: Vec3::ZERO,
            beta: 0.0,
            depth: 0,
            ph: 0.0,
            l: Vec3::ZERO,
        }
    }

    fn shadow_role(depth: u32) -> Which {
        if depth == 1 {
            Which::Primary
        } else {
            Which::Secondary
        }
    }

    /// Runs the path's local work up to its next query (or its end), as `trace` does.
    fn advance(&self, p: &mut Path) -> Option<Query> {
        loop {
            match p.stage {
                Stage::CameraT => {
                    if self.env.is_some() {
                        return Some(Query {
                            kind: Kind::Transmittance,
                            which: Which::Primary,
                            o: p.x,
                            d: p.dir,
                        });
                    }
                    p.stage = Stage::CameraD;
                }
                Stage::CameraD => {
                    if self.albedo <= 0.0 || self.max_bounces == 0 {
                        p.stage = Stage::Done;
                        continue;
                    }
                    return Some(Query {
                        kind: Kind::Distance,
                        which: Which::Primary,
                        o: p.x,
                        d: p.dir,
                    });
                }
                Stage::Sun => {
                    if let Some((sun_dir, _)) = self.sun {
                        let ph = hg_phase(self.g, p.dir.dot(sun_dir));
                        if ph > 0.0 {
                            p.ph = ph;
                            return Some(Query {
                                kind: Kind::Transmittance,
                                which: Self::shadow_role(p.depth),
                                o: p.x,
                                d: sun_dir,
                            });
                        }
                    }
                    p.w = sample_hg(p.dir, self.g, p.rng.next_f32(), p.rng.next_f32());
                    p.stage = Stage::Env;
                }
                Stage::Env => {
                    if self.env.is_some() {
                        return Some(Query {
                            kind: Kind::Transmittance,
                            which: Self::shadow_role(p.depth),
                            o: p.x,
                            d: p.w,
                        });
                    }
                    p.stage = Stage::Next;
                }
                Stage::Next => {
                    if p.depth >= self.max_bounces {
                        p.stage = Stage::Done;
                        continue;
                    }
                    return Some(Query {
                        kind: Kind::Distance,
                        which: Which::Secondary,
                        o: p.x,
                        d: p.w,
                    });
                }
                Stage::Done => return None,
            }
        }
    }

    /// Takes the answer of the query `advance` returned.
    fn answer(&self, p: &mut Path, t: f32, hit: Option<f32>) {
        match p.stage {
            Stage::CameraT => {
                let env = self.env.unwrap_or(Vec3::ZERO);
                p.l += env * t;
                p.stage = Stage::CameraD;
            }
            Stage::CameraD => match hit {
                None => p.stage = Stage::Done,
                Some(t) => {
                    p.x += p.dir * t;
                    p.beta = self.albedo;
                    p.depth = 1;
                    p.stage = Stage::Sun;
                }
            },
            Stage::Sun => {
                let (_, sun_rad) = self.sun.unwrap_or((Vec3::ZERO, Vec3::ZERO));
                p.l += sun_rad * (p.beta * p.ph * t);
                p.w = sample_hg(p.dir, self.g, p.rng.next_f32(), p.rng.next_f32());
                p.stage = Stage::Env;
            }
            Stage::Env => {
                let env = self.env.unwrap_or(Vec3::ZERO);
                p.l += env * (p.beta * t);
                p.stage = Stage::Next;
            }
            Stage::Next => match hit {
                None => p.stage = Stage::Done,
                Some(t) => {
                    p.x += p.w * t;
                    p.dir = p.w;
                    p.beta *= self.albedo;
                    p.depth += 1;
                    p.stage = Stage::Sun;
                }
            },
            Stage::Done => {}
        }
    }

    fn estimator(&self, which: Which) -> &dyn TransportEstimator {
        let m = &self.media[0];
        match which {
            Which::Primary => &*m.primary,
            Which::Secondary => &*m.secondary,
        }
    }

    /// Advances every path of `paths` to its end, answering each round's queries per
    /// (query kind, estimator role) through the batch methods. Only the paths still running
    /// are visited, and each round sorts their queries into the four batches in one pass.
    fn trace_tile(&self, paths: &mut [Path], scratch: &mut Scratch) {
        scratch.live.clear();
        scratch.live.extend(0..paths.len());
        loop {
            scratch.clear();
            let mut kept = 0;
            for k in 0..scratch.live.len() {
                let i = scratch.live[k];
                if let Some(q) = self.advance(&mut paths[i]) {
                    scratch.waiting.push((i, q));
                    scratch.live[kept] = i;
                    kept += 1;
                }
            }
            scratch.live.truncate(kept);
            if scratch.waiting.is_empty() {
                return;
            }
            if self.media.len() != 1 {
                for &(i, q) in &scratch.waiting {
                    let p = &mut paths[i];
                    match q.kind {
                        Kind::Transmittance => {
                            let t = self.transmittance(q.which, q.o, q.d, &mut p.rng);
                            self.answer(p, t, None);
                        }
                        Kind::Distance => {
                            let hit = self.distance(q.which, q.o, q.d, &mut p.rng);
                            self.answer(p, 1.0, hit);
                        }
                    }
                }
                continue;
            }
            for &(i, q) in &scratch.waiting {
                // The box test of `Ctx::transmittance` / `Ctx::distance`: a ray that misses
                // the medium's box is answered without a query (no draws).
                if !self.single_medium_asked(q.which, q.o, q.d) {
                    self.answer(&mut paths[i], 1.0, None);
                    continue;
                }
                let b = &mut scratch.batches[batch_of(q.kind, q.which)];
                b.ids.push(i);
                b.rays.push([q.o, q.d]);
                b.rngs.push(paths[i].rng.clone());
            }
            for kind in [Kind::Transmittance, Kind::Distance] {
                for which in [Which::Primary, Which::Secondary] {
                    let b = &mut scratch.batches[batch_of(kind, which)];
                    if b.ids.is_empty() {
                        continue;
                    }
                    let est = self.estimator(which);
                    let n = b.ids.len();
                    match kind {
                        Kind::Transmittance => {
                            b.t.clear();
                            b.t.resize(n, 1.0);
                            est.transmittance_batch(&b.rays, f32::INFINITY, &mut b.rngs, &mut b.t);
                            for k in 0..n {
                                let p = &mut paths[b.ids[k]];
                                p.rng = b.rngs[k].clone();
                                self.answer(p, b.t[k], None);
                            }
                        }
                        Kind::Distance => {
                            b.d.clear();
                            b.d.resize(n, None);
                            est.sample_distance_batch(
                                &b.rays,
                                f32::INFINITY,
                                &mut b.rngs,
                                &mut b.d,
                            );
                            for k in 0..n {
                                let p = &mut paths[b.ids[k]];
                                p.rng = b.rngs[k].clone();
                                self.answer(p, 1.0, b.d[k]);
                            }
                        }
                    }
                }
            }
        }
    }
}

/// The batch of a (query kind, estimator role) in [`Scratch::batches`].
#[inline]
fn batch_of(kind: Kind, which: Which) -> usize {
    2 * (kind == Kind::Distance) as usize + which as usize
}

/// One round's queries of one (kind, role), in path order.
#[derive(Default)]
struct Batch {
    ids: Vec<usize>,
    rays: Vec<[Vec3; 2]>,
    rngs: Vec<Pcg32>,
    t: Vec<f32>,
    d: Vec<Option<f32>>,
}

/// Buffers reused across the rounds of a tile.
#[derive(Default)]
struct Scratch {
    /// The paths not yet done, in path order.
    live: Vec<usize>,
    waiting: Vec<(usize, Query)>,
    batches: [Batch; 4],
}

impl Scratch {
    fn clear(&mut self) {
        self.waiting.clear();
        for b in &mut self.batches {
            b.ids.clear();
            b.rays.clear();
            b.rngs.clear();
        }
    }
}

/// Paths per tile of [`render_wavefront`] when the caller has no preference: enough rays per
/// round for the batch API's 32-ray steps to fill after the paths thin out.
pub const DEFAULT_WAVEFRONT_BATCH: usize = 256;

/// [`super::render`] with the paths of each image row traced in tiles of `batch` paths
/// (`batch >= 1`) whose queries are answered in batches. The image, spp and determinism are
/// those of `render` (same seed: the same bits). A radiance cache in `settings` is refused:
/// it has its own sample loop.
pub fn render_wavefront(
    scene: &Scene,
    settings: &RenderSettings,
    batch: usize,
) -> Result<RenderOutput, RenderError> {
    scene.validate()?;
    check_settings(settings)?;
    if batch == 0 {
        return Err(RenderError::Invalid {
            what: "batch",
            why: "0 paths per tile".into(),
        });
    }
    if settings.cache.is_some() {
        return Err(RenderError::Invalid {
            what: "settings",
            why: "the wavefront loop has no radiance cache; use render".into(),
        });
    }
    let start = Instant::now();
    let ctx = scene.ctx(settings.max_bounces);
    let frame = scene.camera.frame()?;
    let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
    let seed = settings.seed;
    // One row's samples `(x, s)` for `s` in `samples`, summed per pixel in sample order.
    let row = |y: usize, acc: &mut [[f64; 3]], samples: std::ops::Range<u32>| {
        let mut scratch = Scratch::default();
        let per_pixel = samples.len();
        let ids: Vec<(usize, u32)> = (0..w)
            .flat_map(|x| samples.clone().map(move |s| (x, s)))
            .collect();
        let mut colors = vec![Vec3::ZERO; ids.len()];
        let mut paths: Vec<Path> = Vec::with_capacity(batch.min(ids.len()));
        for (tile, out) in ids.chunks(batch).zip(colors.chunks_mut(batch)) {
            paths.clear();
            paths.extend(tile.iter().map(|&(x, s)| {
                let mut rng = Pcg32::for_sample(seed, (y * w + x) as u64, s as u64);
                let (jx, jy) = (rng.next_f32(), rng.next_f32());
                let (o, d) = frame.ray(x as f32 + jx, y as f32 + jy);
                ctx.start_path(o, d, rng)
            }));
            ctx.trace_tile(&mut paths, &mut scratch);
            for (c, p) in out.iter_mut().zip(&paths) {
                *c = if p.l.is_finite() { p.l } else { Vec3::ZERO };
            }
        }
        for (x, a) in acc.iter_mut().enumerate() {
            for c in &colors[x * per_pixel..(x + 1) * per_pixel] {
                a[0] += c.x as f64;
                a[1] += c.y as f64;
                a[2] += c.z as f64;
            }
        }
    };
    let mut sums = vec![[0f64; 3]; w * h];
    let spp = in_pool(settings, || {
        run_budget(settings.budget, start, w, &mut sums, row)
    })?;
    Ok(average_sums(scene, &sums, spp, start))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{
        Budget, Camera, FnField, MajorantGrid, Medium, PinsEstimator, RatioTracking, Sun, render,
    };
    use pin_format::Directions;
    use pinrt::PinGrid;
    use pinrt::testing::random_grid;
    use std::sync::Arc;

    fn pins() -> Arc<dyn TransportEstimator> {
        let owned = random_grid(Directions::THESIS_DEFAULT, [6, 5, 4], 2, true, 41);
        let grid = Arc::new(PinGrid::from_bytes(owned.to_bytes().unwrap()).unwrap());
        Arc::new(PinsEstimator::new(grid, None, pinrt::SamplerOptions::default()).unwrap())
    }

    fn scene(media: Vec<Medium>) -> Scene {
        Scene {
            camera: Camera {
                origin: [0.5, 0.5, -2.0],
                target: [0.5, 0.5, 0.5],
                vfov_deg: 40.0,
                width: 13,
                height: 9,
            },
            sun: Some(Sun {
                dir: [0.3, 1.0, -0.2],
                radiance: [2.0, 1.5, 1.0],
            }),
            env_radiance: [0.2, 0.3, 0.4],
            albedo: 0.9,
            g: 0.3,
            media,
        }
    }

    fn settings(budget: Budget) -> RenderSettings {
        RenderSettings {
            max_bounces: 6,
            seed: 77,
            budget,
            threads: Some(2),
            cache: None,
        }
    }

    fn bits(o: &RenderOutput) -> Vec<u32> {
        o.image.rgb.iter().flatten().map(|c| c.to_bits()).collect()
    }

    /// Pins everywhere, PinMS (ratio tracking for primary rays, pins after the first
    /// scattering) and two media: for every batch size the image equals `render`'s, bit for
    /// bit, and is not trivially black.
    #[test]
    fn images_equal_render_for_every_batch_size() {
        let field = Arc::new(FnField {
            min: [0.0; 3],
            max: [1.0; 3],
            f: |p: Vec3| 2.0 + 3.0 * p.x * p.y,
        });
        let maj = Arc::new(MajorantGrid::from_field(&*field, [4; 3]).unwrap());
        let ratio: Arc<dyn TransportEstimator> = Arc::new(RatioTracking::new(field, maj));
        let p = pins();
        for media in [
            vec![Medium::single(p.clone())],
            vec![Medium::new(ratio.clone(), p.clone())],
            vec![
                Medium::single(p.clone()),
                Medium::new(ratio.clone(), p.clone()),
            ],
        ] {
            let sc = scene(media);
            let st = settings(Budget::Spp(3));
            let want = render(&sc, &st).unwrap();
            assert!(want.image.rgb.iter().flatten().any(|&c| c > 0.0));
            for batch in [1, 2, 7, 32, 1000] {
                let got = render_wavefront(&sc, &st, batch).unwrap();
                assert_eq!(got.spp, 3);
                assert_eq!(bits(&got), bits(&want), "batch {batch}");
            }
        }
    }

    /// The comparison above can fail: a path that drops its camera-ray term gives a
    /// different image.
    #[test]
    fn a_changed_path_changes_the_image() {
        let sc = scene(vec![Medium::single(pins())]);
        let st = settings(Budget::Spp(2));
        let want = render(&sc, &st).unwrap();
        let dark = Scene {
            env_radiance: [0.0; 3],
            ..sc
        };
        assert_ne!(bits(&render_wavefront(&dark, &st, 8).unwrap()), bits(&want));
    }

    #[test]
    fn zero_batch_and_a_cache_are_refused() {
        let sc = scene(vec![Medium::single(pins())]);
        assert!(render_wavefront(&sc, &settings(Budget::Spp(1)), 0).is_err());
        let mut st = settings(Budget::Spp(1));
        st.cache = Some(crate::render::CacheSettings::default());
        assert!(render_wavefront(&sc, &st, 4).is_err());
    }
}
