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
//! Scenes with more than one medium are traced the same way. Where the media of an estimator
//! role are instances of one pin grid ([`SharedPins`]), each query is split into one query
//! per medium asked, in the order and with the path draws of `Ctx::transmittance` (every
//! medium met, all in one batch) and `Ctx::distance` (one medium per path and sub-round,
//! since each asks only up to the nearest collision so far), and the queries of all paths
//! and media go through one batch. Other multi-medium queries go through `Ctx`'s product and
//! nearest-collision search one at a time.
//!
//! Where a path needs a transmittance and a distance along the same ray (the camera ray; a
//! vertex's environment ray, which the path then continues along) and one estimator answers
//! both, the two are one query ([`Kind::Both`], `Ctx::transmittance_and_distance`), as in
//! `Ctx::trace`.

use glam::Vec3;
use std::time::Instant;

use super::bounds::{MediaBoxes, MetChunks, RaySlabs};
use super::error::RenderError;
use super::estimator::TransportEstimator;
use super::phase::{hg_phase, sample_hg};
use super::pins::{MemberQuery, SharedPins, SharedScratch, query_rng};
use super::rng::Pcg32;
use super::settings::RenderSettings;
use super::tracer::{
    Ctx, RenderOutput, Scene, Which, average_sums, check_settings, in_pool, pixel_sums, run_budget,
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
    /// Both along one ray ([`Ctx::transmittance_and_distance`]): the camera ray, or a
    /// vertex's environment ray that the path continues along.
    Both,
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
                        let scatters = !(self.albedo <= 0.0 || self.max_bounces == 0);
                        let both = scatters && self.paired(Which::Primary, Which::Primary);
                        return Some(Query {
                            kind: if both {
                                Kind::Both
                            } else {
                                Kind::Transmittance
                            },
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
                        let which = Self::shadow_role(p.depth);
                        let both =
                            p.depth < self.max_bounces && self.paired(which, Which::Secondary);
                        return Some(Query {
                            kind: if both {
                                Kind::Both
                            } else {
                                Kind::Transmittance
                            },
                            which,
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

    /// Takes the answer of a [`Kind::Both`] query: the transmittance's, which moves the
    /// path on to the distance query's stage, then the distance's.
    fn answer_both(&self, p: &mut Path, t: f32, hit: Option<f32>) {
        self.answer(p, t, None);
        self.answer(p, 1.0, hit);
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
    /// are visited, and each round sorts their queries into the six batches in one pass.
    fn trace_tile(&self, paths: &mut [Path], scratch: &mut Scratch, shared: &Shared<'_>) {
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
                self.answer_media(paths, scratch, shared);
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
            for kind in [Kind::Transmittance, Kind::Distance, Kind::Both] {
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
                        Kind::Both => {
                            b.td.clear();
                            b.td.resize(n, (1.0, None));
                            est.transmittance_and_distance_batch(
                                &b.rays,
                                f32::INFINITY,
                                &mut b.rngs,
                                &mut b.td,
                            );
                            for k in 0..n {
                                let p = &mut paths[b.ids[k]];
                                p.rng = b.rngs[k].clone();
                                let (t, hit) = b.td[k];
                                self.answer_both(p, t, hit);
                            }
                        }
                    }
                }
            }
        }
    }
}

/// Per estimator role, the media's pin estimators when they share one grid and options
/// (instances): their queries are batched across paths and media.
type Shared<'a> = [Option<SharedPins<'a>>; 2];

impl Ctx<'_> {
    /// A round's queries of a scene with several media. A role whose media share one pin
    /// grid ([`Shared`]) has its queries split into one query per medium asked, in the
    /// order and with the path draws of [`Ctx::transmittance`] and [`Ctx::distance`], and
    /// answered in batches; every other query goes through those two, one at a time.
    fn answer_media(&self, paths: &mut [Path], scratch: &mut Scratch, shared: &Shared<'_>) {
        let m = &mut scratch.media;
        for r in &mut m.roles {
            r.clear();
        }
        for &(i, q) in &scratch.waiting {
            let p = &mut paths[i];
            let role = q.which as usize;
            match (q.kind, shared[role].is_some()) {
                (Kind::Transmittance, false) => {
                    let t = self.transmittance(q.which, q.o, q.d, &mut p.rng);
                    self.answer(p, t, None);
                }
                (Kind::Distance, false) => {
                    let hit = self.distance(q.which, q.o, q.d, &mut p.rng);
                    self.answer(p, 1.0, hit);
                }
                (Kind::Both, _) => {
                    // Only with one medium (`Ctx::paired`), which never comes here.
                    let (t, hit) = self.transmittance_and_distance(q.which, q.o, q.d, &mut p.rng);
                    self.answer_both(p, t, hit);
                }
                (Kind::Transmittance, true) => {
                    let r = &mut m.roles[role];
                    let first = r.t_queries.len();
                    // `Ctx::transmittance`: every medium whose box the ray meets, in media
                    // order, each drawing its pin generator from the path. The product may
                    // stop early (at 0): the generator after each medium is kept, and the
                    // path takes the one where the product stopped.
                    let mut ask = |member: usize| {
                        r.t_queries.push(MemberQuery {
                            member: member as u32,
                            o: q.o,
                            d: q.d,
                            t_max: f32::INFINITY,
                            rng: query_rng(&mut p.rng),
                        });
                        r.t_after.push(p.rng.clone());
                    };
                    let boxes = &self.boxes[role];
                    match RaySlabs::new(q.o, q.d) {
                        None => (0..self.media.len()).for_each(&mut ask),
                        Some(ray) => boxes.for_each_met(&ray, f32::INFINITY, |j| {
                            ask(j);
                            true
                        }),
                    }
                    r.t_paths.push((i, first..r.t_queries.len()));
                }
                (Kind::Distance, true) => {
                    let mut s = Search::new(i, q.o, q.d);
                    match s.next(&self.boxes[role], self.media.len()) {
                        None => self.answer(p, 1.0, None),
                        Some(member) => {
                            s.asking = member as u32;
                            m.roles[role].searches.push(s);
                        }
                    }
                }
            }
        }
        for (role, r) in m.roles.iter_mut().enumerate() {
            let Some(sp) = &shared[role] else {
                continue;
            };
            r.t_out.clear();
            r.t_out.resize(r.t_queries.len(), 1.0);
            sp.transmittance_batch(&r.t_queries, &mut m.pins, &mut r.t_out);
            // Every path is answered, also one whose ray met no medium (an empty range).
            for (i, range) in r.t_paths.drain(..) {
                let p = &mut paths[i];
                let mut t = 1.0f32;
                for k in range {
                    t *= r.t_out[k];
                    if t == 0.0 {
                        p.rng = r.t_after[k].clone();
                        break;
                    }
                }
                self.answer(p, t, None);
            }
            // `Ctx::distance`, one medium per path and sub-round: each asks up to the
            // nearest collision so far, so a path's next query waits for its last answer.
            while !r.searches.is_empty() {
                r.d_queries.clear();
                for s in &r.searches {
                    r.d_queries.push(MemberQuery {
                        member: s.asking,
                        o: s.o,
                        d: s.d,
                        t_max: s.best,
                        rng: query_rng(&mut paths[s.path].rng),
                    });
                }
                r.d_out.clear();
                r.d_out.resize(r.d_queries.len(), None);
                sp.sample_distance_batch(&r.d_queries, &mut m.pins, &mut r.d_out);
                let mut kept = 0;
                for k in 0..r.searches.len() {
                    let mut s = r.searches[k];
                    if let Some(t) = r.d_out[k]
                        && t < s.best
                    {
                        s.best = t;
                    }
                    match s.next(&self.boxes[role], self.media.len()) {
                        Some(member) => {
                            s.asking = member as u32;
                            r.searches[kept] = s;
                            kept += 1;
                        }
                        None => {
                            let hit = (s.best < f32::INFINITY).then_some(s.best);
                            self.answer(&mut paths[s.path], 1.0, hit);
                        }
                    }
                }
                r.searches.truncate(kept);
            }
        }
    }
}

/// A path's nearest-collision search over several media in the steps of
/// [`Ctx::distance`]: the media whose box the ray meets, per chunk of media in the order of
/// their box entries (tested against the nearest collision so far when the chunk starts,
/// [`MetChunks`]), until a box starts beyond that collision; every medium in media order
/// for a ray the box test cannot reason about.
#[derive(Clone, Copy)]
struct Search {
    path: usize,
    o: Vec3,
    d: Vec3,
    ray: Option<RaySlabs>,
    /// The nearest collision so far.
    best: f32,
    /// The medium being asked.
    asking: u32,
    /// The current chunk's boxes met, and the next of them to ask (`chunks.order[pos]`).
    chunks: MetChunks,
    pos: usize,
}

impl Search {
    fn new(path: usize, o: Vec3, d: Vec3) -> Self {
        Search {
            path,
            o,
            d,
            ray: RaySlabs::new(o, d),
            best: f32::INFINITY,
            asking: 0,
            chunks: MetChunks::new(),
            pos: 0,
        }
    }

    /// The next medium to ask, or `None` when the search is over.
    fn next(&mut self, boxes: &MediaBoxes, media: usize) -> Option<usize> {
        let Some(ray) = &self.ray else {
            let m = self.pos;
            self.pos += 1;
            return (m < media).then_some(m);
        };
        loop {
            let c = &self.chunks;
            if self.pos < c.met {
                let j = c.order[self.pos] as usize;
                // `Ctx::distance` leaves the chunk at the first box beyond the nearest
                // collision.
                if !(c.entry[j] > self.best) {
                    self.pos += 1;
                    return Some(c.start + j);
                }
            }
            if !self.chunks.advance(boxes, ray, self.best) {
                return None;
            }
            self.pos = 0;
        }
    }
}

/// One role's share of a round in [`Ctx::answer_media`].
#[derive(Default)]
struct RoleQueries {
    /// Transmittance: one query per (path, medium met), the path's generator after each,
    /// each path's range of them, the answers.
    t_queries: Vec<MemberQuery>,
    t_after: Vec<Pcg32>,
    t_paths: Vec<(usize, std::ops::Range<usize>)>,
    t_out: Vec<f32>,
    /// Distance: the searches still running, one query each per sub-round, the answers.
    searches: Vec<Search>,
    d_queries: Vec<MemberQuery>,
    d_out: Vec<Option<f32>>,
}

impl RoleQueries {
    fn clear(&mut self) {
        self.t_queries.clear();
        self.t_after.clear();
        self.t_paths.clear();
        self.searches.clear();
    }
}

/// [`Ctx::answer_media`]'s buffers.
#[derive(Default)]
struct MediaScratch {
    roles: [RoleQueries; 2],
    pins: SharedScratch,
}

/// The batch of a (query kind, estimator role) in [`Scratch::batches`].
#[inline]
fn batch_of(kind: Kind, which: Which) -> usize {
    2 * kind as usize + which as usize
}

/// One round's queries of one (kind, role), in path order.
#[derive(Default)]
struct Batch {
    ids: Vec<usize>,
    rays: Vec<[Vec3; 2]>,
    rngs: Vec<Pcg32>,
    t: Vec<f32>,
    d: Vec<Option<f32>>,
    td: Vec<(f32, Option<f32>)>,
}

/// Buffers reused across the rounds of a tile.
#[derive(Default)]
struct Scratch {
    /// The paths not yet done, in path order.
    live: Vec<usize>,
    waiting: Vec<(usize, Query)>,
    batches: [Batch; 6],
    media: MediaScratch,
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

/// The most paths one image row holds at once in [`render_wavefront`] (more when the row is
/// wider: one sample of every pixel).
pub const ROW_CHUNK_PATHS: usize = 1 << 16;

/// Bytes one worker thread of [`render_wavefront`] holds for an image row `width` pixels
/// wide: the ids, colours and paths of one chunk, whatever the samples per pixel (for
/// memory budgets).
pub fn row_scratch_bytes(width: usize, batch: usize) -> u64 {
    let paths = ROW_CHUNK_PATHS.max(width) as u64;
    let per_path = (std::mem::size_of::<(usize, u32)>() + std::mem::size_of::<Vec3>()) as u64;
    paths * per_path + (batch.min(ROW_CHUNK_PATHS.max(width)) * std::mem::size_of::<Path>()) as u64
}

/// [`super::render`] with the paths of each image row traced in tiles of `batch` paths
/// (`batch >= 1`) whose queries are answered in batches. The image, spp and determinism are
/// those of `render` (same seed: the same bits).
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
    let start = Instant::now();
    render_wavefront_in(
        scene,
        settings,
        batch,
        &scene.ctx(settings.max_bounces),
        start,
    )
}

/// [`render_wavefront`] after its checks, with the scene's [`Ctx`] given (the tests render
/// with the linear box scan through it) and the render's start time.
pub(crate) fn render_wavefront_in(
    scene: &Scene,
    settings: &RenderSettings,
    batch: usize,
    ctx: &Ctx<'_>,
    start: Instant,
) -> Result<RenderOutput, RenderError> {
    let shared: Shared<'_> = [Which::Primary, Which::Secondary]
        .map(|which| SharedPins::new(scene.media.iter().map(|m| Ctx::est(m, which))));
    let frame = scene.camera.frame()?;
    let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
    let seed = settings.seed;
    // One row's samples `(x, s)` for `s` in `samples`, summed per pixel in sample order. The
    // samples go in chunks of at most `ROW_CHUNK_PATHS` paths (at least one per pixel), so
    // the row's buffers do not grow with the samples per pixel (`--spp 4294967295` asked for
    // 100 GB at once); per pixel the sums still run in sample order, so the bits are the same.
    let per_chunk = (ROW_CHUNK_PATHS / w.max(1)).max(1) as u32;
    let row = |y: usize, acc: &mut [[f64; 3]], samples: std::ops::Range<u32>| {
        let mut scratch = Scratch::default();
        let mut ids: Vec<(usize, u32)> = Vec::new();
        let mut colors: Vec<Vec3> = Vec::new();
        let mut paths: Vec<Path> = Vec::new();
        let mut chunk_start = samples.start;
        while chunk_start < samples.end {
            let chunk = chunk_start..chunk_start.saturating_add(per_chunk).min(samples.end);
            chunk_start = chunk.end;
            let per_pixel = chunk.len();
            ids.clear();
            ids.extend((0..w).flat_map(|x| chunk.clone().map(move |s| (x, s))));
            colors.clear();
            colors.resize(ids.len(), Vec3::ZERO);
            for (tile, out) in ids.chunks(batch).zip(colors.chunks_mut(batch)) {
                paths.clear();
                paths.extend(tile.iter().map(|&(x, s)| {
                    let mut rng = Pcg32::for_sample(seed, (y * w + x) as u64, s as u64);
                    let (jx, jy) = (rng.next_f32(), rng.next_f32());
                    let (o, d) = frame.ray(x as f32 + jx, y as f32 + jy);
                    ctx.start_path(o, d, rng)
                }));
                ctx.trace_tile(&mut paths, &mut scratch, &shared);
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
        }
    };
    let mut sums = pixel_sums(w * h)?;
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

    /// `n` instances of one pin grid, each placed by its own translation (a jittered
    /// lattice around the camera's target), with lookup options `opts`.
    fn instances(n: usize, opts: pinrt::SamplerOptions) -> Vec<Arc<dyn TransportEstimator>> {
        let owned = random_grid(Directions::THESIS_DEFAULT, [6, 5, 4], 2, true, 43);
        let grid = Arc::new(PinGrid::from_bytes(owned.to_bytes().unwrap()).unwrap());
        let l2w = grid.desc().local_to_world;
        let mut g = Pcg32::new(5, 9);
        (0..n)
            .map(|i| {
                let mut m = l2w;
                let cell = [i % 4, (i / 4) % 4, i / 16].map(|c| c as f64 * 0.3 - 0.45);
                for (a, c) in cell.iter().enumerate() {
                    m[4 * a + 3] += c + 0.1 * g.next_f32() as f64;
                }
                Arc::new(PinsEstimator::new(grid.clone(), Some(&m), opts).unwrap())
                    as Arc<dyn TransportEstimator>
            })
            .collect()
    }

    /// Instances that share one pin grid are answered in batches across paths and media
    /// (`Ctx::answer_media`): for pins everywhere and for PinMS, with and without lookup
    /// jitter, with more media than one chunk of box tests (70 > `CHUNK`), and next to a
    /// medium with another grid (no sharing: one query at a time), the image equals
    /// `render`'s bit for bit at every batch size.
    #[test]
    fn shared_instances_equal_render_for_every_batch_size() {
        let field = Arc::new(FnField {
            min: [-0.5; 3],
            max: [1.5; 3],
            f: |p: Vec3| 1.0 + p.x * p.x,
        });
        let maj = Arc::new(MajorantGrid::from_field(&*field, [4; 3]).unwrap());
        let ratio: Arc<dyn TransportEstimator> = Arc::new(RatioTracking::new(field, maj));
        let jitter = pinrt::SamplerOptions {
            spatial_jitter: 1.0,
            directional_jitter: 1.0,
            chain_stride: 32,
            midpoint_lookup: true,
            start_inside: true,
            nearest_line: 0,
        };
        let chained = pinrt::SamplerOptions {
            chain_stride: 8,
            ..jitter
        };
        let cases: Vec<(&str, Vec<Medium>)> = vec![
            (
                "pins, 9 instances",
                instances(9, pinrt::SamplerOptions::THESIS)
                    .into_iter()
                    .map(Medium::single)
                    .collect(),
            ),
            (
                "pins, 70 instances, jitter",
                instances(70, jitter)
                    .into_iter()
                    .map(Medium::single)
                    .collect(),
            ),
            (
                "pins, 20 instances, the render's lookup",
                instances(20, pinrt::SamplerOptions::RENDER)
                    .into_iter()
                    .map(Medium::single)
                    .collect(),
            ),
            (
                "pinms, 12 instances, chained",
                instances(12, chained)
                    .into_iter()
                    .map(|p| Medium::new(ratio.clone(), p))
                    .collect(),
            ),
            ("pins, 6 instances and another grid", {
                let mut m: Vec<Medium> = instances(6, jitter)
                    .into_iter()
                    .map(Medium::single)
                    .collect();
                m.insert(2, Medium::single(pins()));
                m
            }),
        ];
        for (name, media) in cases {
            let sc = scene(media);
            let shared = [Which::Primary, Which::Secondary]
                .map(|w| SharedPins::new(sc.media.iter().map(|m| Ctx::est(m, w))).is_some());
            let want_shared = !name.contains("another");
            assert_eq!(shared[1], want_shared, "{name}");
            assert_eq!(
                shared[0],
                want_shared && !name.starts_with("pinms"),
                "{name}"
            );
            let st = settings(Budget::Spp(2));
            let want = render(&sc, &st).unwrap();
            let lit = want
                .image
                .rgb
                .iter()
                .flatten()
                .filter(|&&c| c > 0.0)
                .count();
            assert!(lit > 100, "{name}: {lit} lit channels");
            for batch in [1, 3, 32, 1000] {
                let got = render_wavefront(&sc, &st, batch).unwrap();
                assert_eq!(bits(&got), bits(&want), "{name}, batch {batch}");
            }
        }
    }

    /// Scenes of hundreds of media query their boxes through the hierarchy (`bvh.rs`): the
    /// images equal those of the linear scan bit for bit, for the path loop and the
    /// wavefront loop, for shared pin instances (pins, PinMS) and for ratio tracking placed
    /// by turned and stretched transforms (one query at a time).
    #[test]
    fn the_hierarchy_renders_the_linear_scans_bits() {
        let field = Arc::new(FnField {
            min: [-0.5; 3],
            max: [1.5; 3],
            f: |p: Vec3| 1.0 + p.x * p.x,
        });
        let maj = Arc::new(MajorantGrid::from_field(&*field, [4; 3]).unwrap());
        let ratio: Arc<dyn TransportEstimator> = Arc::new(RatioTracking::new(field, maj));
        let mut g = Pcg32::new(21, 3);
        let placed: Vec<Medium> = (0..150)
            .map(|i| {
                let (a, s) = (g.next_f64() * 6.0, 0.1 + 0.2 * g.next_f64());
                let (c, sn) = (a.cos() * s, a.sin() * s);
                let t = [i % 5, (i / 5) % 5, i / 25].map(|k| k as f64 * 0.25 - 0.4);
                let m = [c, -sn, 0.0, t[0], sn, c, 0.0, t[1], 0.0, 0.0, 0.7 * s, t[2]];
                let est = crate::instance::PlacedEstimator::new(ratio.clone(), &m).unwrap();
                Medium::single(Arc::new(est))
            })
            .collect();
        let cases: Vec<(&str, Vec<Medium>)> = vec![
            (
                "pins, 300 instances",
                instances(300, pinrt::SamplerOptions::RENDER)
                    .into_iter()
                    .map(Medium::single)
                    .collect(),
            ),
            (
                "pinms, 200 instances",
                instances(200, pinrt::SamplerOptions::THESIS)
                    .into_iter()
                    .map(|p| Medium::new(ratio.clone(), p))
                    .collect(),
            ),
            ("ratio, 150 turned and stretched instances", placed),
        ];
        for (name, media) in cases {
            let sc = scene(media);
            let st = settings(Budget::Spp(2));
            let (tree, linear) = (sc.ctx(st.max_bounces), sc.ctx_linear(st.max_bounces));
            assert!(tree.boxes.iter().all(|b| b.has_tree()), "{name}");
            assert!(!linear.boxes.iter().any(|b| b.has_tree()), "{name}");
            let want = crate::render::render_in(&sc, &st, &linear).unwrap();
            let lit = want
                .image
                .rgb
                .iter()
                .flatten()
                .filter(|&&c| c > 0.0)
                .count();
            assert!(lit > 100, "{name}: {lit} lit channels");
            assert_eq!(bits(&render(&sc, &st).unwrap()), bits(&want), "{name}");
            for batch in [1, 64] {
                let got = render_wavefront(&sc, &st, batch).unwrap();
                assert_eq!(bits(&got), bits(&want), "{name}, batch {batch}");
                let lin = render_wavefront_in(&sc, &st, batch, &linear, Instant::now()).unwrap();
                assert_eq!(bits(&lin), bits(&want), "{name}, batch {batch}, linear");
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
    fn zero_batch_is_refused() {
        let sc = scene(vec![Medium::single(pins())]);
        assert!(render_wavefront(&sc, &settings(Budget::Spp(1)), 0).is_err());
    }
}
