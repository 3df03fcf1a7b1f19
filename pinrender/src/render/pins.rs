//! The pin grid as a renderer estimator: `pins` everywhere, or the secondary half of PinMS.

use std::sync::Arc;

use bytemuck::Zeroable;
use glam::Vec3;
use pinrt::{PinGrid, QueryResult, Ray, RayQuery, Rng, Sampler, SamplerOptions, UnitTransform};

use super::error::RenderError;
use super::estimator::TransportEstimator;
use super::rng::Pcg32;

/// A placed pin grid answering the renderer's queries. It shares its grid (an `Arc`, so a
/// scene's instances and the GPU upload read one copy) and keeps the placement and lookup
/// options; each query makes its sampler over the grid, which costs a few copies and no
/// matrix inversion ([`Sampler::with_transform`]).
pub struct PinsEstimator {
    grid: Arc<PinGrid>,
    xf: UnitTransform,
    opts: SamplerOptions,
    /// The row-major 3x4 local-to-world placement (the file's own unless given).
    placement: [f64; 12],
    /// The placed grid's world box (the renderer skips the estimator for rays that miss it).
    bounds: Option<([f64; 3], [f64; 3])>,
}

impl PinsEstimator {
    /// The grid placed by its file's `local_to_world`, or by `local_to_world` when given
    /// (an instance), with the lookup options `opts`.
    pub fn new(
        grid: Arc<PinGrid>,
        local_to_world: Option<&[f64; 12]>,
        opts: SamplerOptions,
    ) -> Result<Self, RenderError> {
        let xf =
            UnitTransform::new(grid.desc(), local_to_world).map_err(|e| RenderError::Invalid {
                what: "pin grid placement",
                why: e.to_string(),
            })?;
        Ok(Self {
            bounds: xf.world_bounds(),
            placement: *local_to_world.unwrap_or(&grid.desc().local_to_world),
            grid,
            xf,
            opts,
        })
    }

    /// The shared grid (for the GPU upload).
    pub fn grid(&self) -> &Arc<PinGrid> {
        &self.grid
    }

    /// The grid's row-major 3x4 local-to-world placement.
    pub fn placement(&self) -> &[f64; 12] {
        &self.placement
    }

    /// A sampler over the grid with this estimator's placement and options.
    pub fn sampler(&self) -> Sampler<'_> {
        Sampler::with_transform(&self.grid, self.xf).with_options(self.opts)
    }
}

/// The batch form of the single queries' seeding: each ray's pin generator from two draws of
/// its path generator, in the order `sample_distance` and `transmittance` draw them. The
/// queries and generators go into `scratch`'s buffers (kept per thread: the wavefront loop
/// asks a batch every round).
fn pin_queries(
    rays: &[[Vec3; 2]],
    t_max: f32,
    rngs: &mut [Pcg32],
    scratch: &mut (Vec<RayQuery>, Vec<Rng>),
) {
    let (q, g) = scratch;
    q.clear();
    q.extend(
        rays.iter()
            .map(|r| RayQuery::new(r[0].to_array(), r[1].to_array(), t_max)),
    );
    g.clear();
    g.extend(rngs.iter_mut().map(query_rng));
}

thread_local! {
    /// [`pin_queries`]' buffers.
    static QUERIES: std::cell::RefCell<(Vec<RayQuery>, Vec<Rng>)> =
        const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
    /// The results of a batch of both queries.
    static RESULTS: std::cell::RefCell<Vec<QueryResult>> =
        const { std::cell::RefCell::new(Vec::new()) };
}

impl TransportEstimator for PinsEstimator {
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
        // Two draws of the path generator seed the query, as the GPU seeds its queries.
        let mut r = query_rng(rng);
        self.sampler()
            .sample_distance(&Ray::new(o.to_array(), d.to_array()), t_max, &mut r)
    }
    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32 {
        let mut r = query_rng(rng);
        self.sampler()
            .transmittance(&Ray::new(o.to_array(), d.to_array()), t_max, &mut r)
    }
    fn transmittance_batch(
        &self,
        rays: &[[Vec3; 2]],
        t_max: f32,
        rngs: &mut [Pcg32],
        out: &mut [f32],
    ) {
        QUERIES.with_borrow_mut(|s| {
            pin_queries(rays, t_max, rngs, s);
            self.sampler().transmittance_batch_rngs(&s.0, &mut s.1, out);
        });
    }
    fn sample_distance_batch(
        &self,
        rays: &[[Vec3; 2]],
        t_max: f32,
        rngs: &mut [Pcg32],
        out: &mut [Option<f32>],
    ) {
        QUERIES.with_borrow_mut(|s| {
            pin_queries(rays, t_max, rngs, s);
            self.sampler()
                .sample_distance_batch_rngs(&s.0, &mut s.1, out);
        });
    }
    /// One lookup for both ([`Sampler::query`]): the transmittance of the participating
    /// intervals and a collision among them, from one pin and one set of draws.
    fn transmittance_and_distance(
        &self,
        o: Vec3,
        d: Vec3,
        t_max: f32,
        rng: &mut Pcg32,
    ) -> (f32, Option<f32>) {
        let mut r = query_rng(rng);
        let q = self
            .sampler()
            .query(&Ray::new(o.to_array(), d.to_array()), t_max, &mut r);
        (q.transmittance, q.collision())
    }
    fn transmittance_and_distance_batch(
        &self,
        rays: &[[Vec3; 2]],
        t_max: f32,
        rngs: &mut [Pcg32],
        out: &mut [(f32, Option<f32>)],
    ) {
        QUERIES.with_borrow_mut(|s| {
            pin_queries(rays, t_max, rngs, s);
            RESULTS.with_borrow_mut(|res| {
                res.clear();
                res.resize(rays.len(), QueryResult::zeroed());
                self.sampler().query_batch_rngs(&s.0, &mut s.1, res);
                for (o, q) in out.iter_mut().zip(res.iter()) {
                    *o = (q.transmittance, q.collision());
                }
            });
        });
    }
    fn name(&self) -> String {
        "pins".into()
    }
    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        self.bounds
    }
    fn as_any(&self) -> Option<&dyn std::any::Any> {
        Some(self)
    }
}

/// The unit-cube map that leaves a ray as it is: `1 x + 0 y + 0 z + 0` per row.
const IDENTITY: UnitTransform = UnitTransform {
    rows: [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
    ],
};

/// Several media's pin estimators over one grid with one set of lookup options (the
/// instances of an asset, each placed by its own transform), asked together: each query is
/// taken into its member's unit cube here, with the member's own `UnitTransform`, and the
/// whole batch goes through one sampler whose map is the identity. So queries of different
/// instances share one call of the lane-parallel, prefetching batch API instead of paying
/// for a sampler and a single query each.
///
/// **The same bits as each member's own query.** The sampler computes `1 u + 0 v + 0 w +
/// 0` per coordinate of the unit-cube ray, which is `u` exactly for every finite `u` except
/// `-0.0` (it gives `+0.0`). A query with a negative zero among its six unit-cube
/// coordinates is therefore answered by its member's own sampler, one at a time; every other
/// query reaches the chord, the lookup and the resolve with the bits the member's sampler
/// would have computed.
pub(crate) struct SharedPins<'a> {
    sampler: Sampler<'a>,
    members: Vec<&'a PinsEstimator>,
}

/// One query of a [`SharedPins`] batch: member `member` (its index among the media), the
/// world ray `o + t d` over `[0, t_max]`, and the pin generator the query draws from (seeded
/// from the path as the single query seeds it).
#[derive(Clone, Copy)]
pub(crate) struct MemberQuery {
    pub member: u32,
    pub o: Vec3,
    pub d: Vec3,
    pub t_max: f32,
    pub rng: Rng,
}

/// Buffers of [`SharedPins`]' batches (kept by the caller across rounds).
#[derive(Default)]
pub(crate) struct SharedScratch {
    /// Unit-cube queries, their generators, and the index of each in the caller's list.
    rays: Vec<RayQuery>,
    rngs: Vec<Rng>,
    ids: Vec<usize>,
    t: Vec<f32>,
    d: Vec<Option<f32>>,
}

/// Whether `x` is `-0.0`, which the identity map would turn into `+0.0`.
#[inline(always)]
fn negative_zero(x: f32) -> bool {
    x.to_bits() == 0x8000_0000
}

impl<'a> SharedPins<'a> {
    /// The shared form of `estimators` (one per medium, in media order): `Some` when there
    /// are at least two and every one is a pin estimator over the same grid (the same
    /// `Arc`) with the same lookup options.
    pub(crate) fn new(
        estimators: impl IntoIterator<Item = &'a dyn TransportEstimator>,
    ) -> Option<Self> {
        let members = estimators
            .into_iter()
            .map(|e| e.as_any()?.downcast_ref::<PinsEstimator>())
            .collect::<Option<Vec<&PinsEstimator>>>()?;
        let first = *members.first()?;
        let same = members
            .iter()
            .all(|m| Arc::ptr_eq(&m.grid, &first.grid) && m.opts == first.opts);
        (members.len() >= 2 && same).then(|| SharedPins {
            sampler: Sampler::with_transform(&first.grid, IDENTITY).with_options(first.opts),
            members,
        })
    }

    /// Puts each query into `s.rays` in its member's unit cube, or answers it at once by
    /// `single` when it has a negative zero there.
    fn gather(
        &self,
        queries: &[MemberQuery],
        s: &mut SharedScratch,
        mut single: impl FnMut(usize, &Sampler<'_>, &Ray, f32, &mut Rng),
    ) {
        s.rays.clear();
        s.rngs.clear();
        s.ids.clear();
        for (k, q) in queries.iter().enumerate() {
            let m = self.members[q.member as usize];
            let o = m.xf.point(q.o.to_array());
            let d = m.xf.vector(q.d.to_array());
            if o.iter().chain(&d).any(|&x| negative_zero(x)) {
                let mut rng = q.rng;
                single(
                    k,
                    &m.sampler(),
                    &Ray::new(q.o.to_array(), q.d.to_array()),
                    q.t_max,
                    &mut rng,
                );
                continue;
            }
            s.rays.push(RayQuery::new(o, d, q.t_max));
            s.rngs.push(q.rng);
            s.ids.push(k);
        }
    }

    /// `out[k]`: what member `queries[k].member`'s sampler returns for the transmittance of
    /// query `k` with its generator.
    pub(crate) fn transmittance_batch(
        &self,
        queries: &[MemberQuery],
        s: &mut SharedScratch,
        out: &mut [f32],
    ) {
        debug_assert_eq!(queries.len(), out.len());
        self.gather(queries, s, |k, sampler, ray, t_max, rng| {
            out[k] = sampler.transmittance(ray, t_max, rng)
        });
        s.t.clear();
        s.t.resize(s.rays.len(), 1.0);
        self.sampler
            .transmittance_batch_rngs(&s.rays, &mut s.rngs, &mut s.t);
        for (&k, &t) in s.ids.iter().zip(&s.t) {
            out[k] = t;
        }
    }

    /// `out[k]`: what member `queries[k].member`'s sampler returns for a sampled distance
    /// of query `k` with its generator.
    pub(crate) fn sample_distance_batch(
        &self,
        queries: &[MemberQuery],
        s: &mut SharedScratch,
        out: &mut [Option<f32>],
    ) {
        debug_assert_eq!(queries.len(), out.len());
        self.gather(queries, s, |k, sampler, ray, t_max, rng| {
            out[k] = sampler.sample_distance(ray, t_max, rng)
        });
        s.d.clear();
        s.d.resize(s.rays.len(), None);
        self.sampler
            .sample_distance_batch_rngs(&s.rays, &mut s.rngs, &mut s.d);
        for (&k, &d) in s.ids.iter().zip(&s.d) {
            out[k] = d;
        }
    }
}

/// The pin generator of a query, drawn from its path's generator as
/// [`PinsEstimator::transmittance`] and [`PinsEstimator::sample_distance`] draw it.
#[inline]
pub(crate) fn query_rng(path: &mut Pcg32) -> Rng {
    Rng::for_query(path.next_u32(), path.next_u32())
}

#[cfg(test)]
mod tests {
    use super::*;
    use pinrt::testing::random_grid;

    /// A random sparse grid of the thesis' directions, 2 pins per entry, loaded from its bytes.
    fn sparse_grid(dims: [u32; 3], seed: u32) -> Arc<PinGrid> {
        let owned = random_grid(pin_format::Directions::THESIS_DEFAULT, dims, 2, true, seed);
        Arc::new(PinGrid::from_bytes(owned.to_bytes().unwrap()).unwrap())
    }

    /// A shared batch answers every query as its member's own sampler does (same results,
    /// same generator states), for translated and scaled members, random rays and rays
    /// whose unit-cube form has negative zeros (answered one at a time).
    #[test]
    fn shared_batch_answers_as_each_member() {
        let grid = sparse_grid([5, 4, 6], 11);
        // The render's lookup: jitter, middle, start inside, the nearest-line search.
        let opts = SamplerOptions::RENDER;
        let l2w = grid.desc().local_to_world;
        let mut placed = Vec::new();
        for k in 0..4 {
            let mut m = l2w;
            m[3] += 0.3 * k as f64;
            m[7] -= 0.2 * k as f64;
            if k == 3 {
                // A scaled member: its map is not a translation of the others'.
                m[0] *= 1.5;
            }
            // The unshifted member keeps the file's placement, whose map has a `-0.0`
            // offset: an origin with x = -0.0 stays -0.0 in its unit cube.
            let m = if k == 0 { None } else { Some(m) };
            placed.push(PinsEstimator::new(grid.clone(), m.as_ref(), opts).unwrap());
        }
        let dyns: Vec<&dyn TransportEstimator> = placed.iter().map(|p| p as _).collect();
        let shared = SharedPins::new(dyns.iter().copied()).expect("one grid, one set of options");
        let mut g = Pcg32::new(17, 3);
        let mut queries = Vec::new();
        for k in 0..600u32 {
            let mut p = || Vec3::new(g.next_f32(), g.next_f32(), g.next_f32());
            let o = p() * 3.0 - 1.0;
            let d = (p() - o).normalize_or(Vec3::Z);
            let t_max = if k % 3 == 0 {
                f32::INFINITY
            } else {
                4.0 * g.next_f32()
            };
            let rng = Rng::for_query(k, 99);
            queries.push(MemberQuery {
                member: k % 4,
                o,
                d,
                t_max,
                rng,
            });
        }
        // Negative zeros in member 0's unit cube: the origin's x, the direction's x.
        let mut zeros = 0;
        for (o, d) in [
            ([-0.0, -0.5, -0.25], [0.4, 0.5, 0.7]),
            ([0.5, 0.5, -1.0], [-0.0, -0.6, 0.8]),
            ([-0.0, -0.3, -2.0], [-0.0, -0.6, 0.8]),
            ([0.3, 0.7, 2.0], [-0.0, -0.0, -1.0]),
        ] {
            let (o, d) = (Vec3::from(o), Vec3::from(d));
            let xf = &placed[0].xf;
            let unit = xf
                .point(o.to_array())
                .into_iter()
                .chain(xf.vector(d.to_array()));
            zeros += unit.filter(|&x| negative_zero(x)).count();
            for k in 0..50 {
                let rng = Rng::for_query(1000 + k, 7);
                queries.push(MemberQuery {
                    member: 0,
                    o,
                    d,
                    t_max: f32::INFINITY,
                    rng,
                });
            }
        }
        assert!(zeros >= 4, "{zeros} negative zeros");
        let mut s = SharedScratch::default();
        let mut t = vec![0.0; queries.len()];
        let mut hit = vec![None; queries.len()];
        shared.transmittance_batch(&queries, &mut s, &mut t);
        shared.sample_distance_batch(&queries, &mut s, &mut hit);
        let (mut met, mut hits) = (0, 0);
        for (k, q) in queries.iter().enumerate() {
            let sampler = placed[q.member as usize].sampler();
            let ray = Ray::new(q.o.to_array(), q.d.to_array());
            let (mut a, mut b) = (q.rng, q.rng);
            assert_eq!(
                t[k].to_bits(),
                sampler.transmittance(&ray, q.t_max, &mut a).to_bits(),
                "{k}"
            );
            assert_eq!(
                hit[k],
                sampler.sample_distance(&ray, q.t_max, &mut b),
                "{k}"
            );
            met += usize::from(t[k] != 1.0);
            hits += usize::from(hit[k].is_some());
        }
        // Not only misses: most rays meet a grid, many collide.
        assert!(met > 200 && hits > 100, "{met} met, {hits} hits");
    }

    /// Both queries of one ray from one lookup: single and batched, the answer is the
    /// sampler's `query` (one pin generator from two path draws), whose transmittance and
    /// collision are, without chained lookups, those of the separate queries seeded alike.
    #[test]
    fn both_queries_from_one_lookup() {
        let grid = sparse_grid([4, 3, 5], 8);
        for opts in [
            SamplerOptions::THESIS,
            SamplerOptions {
                spatial_jitter: 1.0,
                directional_jitter: 1.0,
                chain_stride: 32,
                midpoint_lookup: true,
                start_inside: true,
                nearest_line: 0,
            },
            SamplerOptions::RENDER,
        ] {
            let est = PinsEstimator::new(grid.clone(), None, opts).unwrap();
            let mut g = Pcg32::new(5, 6);
            let mut rays = Vec::new();
            for _ in 0..300 {
                let mut p = || Vec3::new(g.next_f32(), g.next_f32(), g.next_f32());
                let o = p() * 3.0 - 1.0;
                let d = (p() - o).normalize_or(Vec3::Z);
                rays.push([o, d]);
            }
            let mut rngs: Vec<Pcg32> = (0..rays.len() as u64).map(|i| Pcg32::new(i, 2)).collect();
            let mut batch = vec![(0.0, None); rays.len()];
            est.transmittance_and_distance_batch(&rays, f32::INFINITY, &mut rngs, &mut batch);
            let (mut met, mut hits) = (0, 0);
            for (i, r) in rays.iter().enumerate() {
                let mut p = Pcg32::new(i as u64, 2);
                let (mut a, mut b) = (p.clone(), p.clone());
                let (t, hit) = est.transmittance_and_distance(r[0], r[1], f32::INFINITY, &mut p);
                assert_eq!(
                    (t.to_bits(), hit),
                    (batch[i].0.to_bits(), batch[i].1),
                    "{i}"
                );
                assert_eq!(p.next_u32(), rngs[i].next_u32());
                assert_eq!(
                    t.to_bits(),
                    est.transmittance(r[0], r[1], f32::INFINITY, &mut a)
                        .to_bits()
                );
                assert_eq!(hit, est.sample_distance(r[0], r[1], f32::INFINITY, &mut b));
                met += usize::from(t != 1.0);
                hits += usize::from(hit.is_some());
            }
            assert!(met > 50 && hits > 20, "{met} met, {hits} hits");
        }
    }

    /// The estimator answers exactly as a sampler borrowed from the grid with the same
    /// placement and options, single and batched, and draws the same path numbers.
    #[test]
    fn answers_as_the_borrowed_sampler() {
        let grid = sparse_grid([4, 3, 5], 7);
        let opts = SamplerOptions {
            spatial_jitter: 1.0,
            ..SamplerOptions::THESIS
        };
        let mut m = grid.desc().local_to_world;
        m[3] += 0.25;
        let est = PinsEstimator::new(grid.clone(), Some(&m), opts).unwrap();
        let reference = Sampler::with_local_to_world(&grid, &m)
            .unwrap()
            .with_options(opts);
        assert_eq!(est.bounds(), reference.world_bounds());
        let mut seed = Pcg32::new(3, 1);
        let mut rays = Vec::new();
        for _ in 0..64 {
            // From around the placed box towards a point inside it: most rays meet the grid.
            let (lo, hi) = est.bounds().unwrap();
            let (lo, hi) = (
                Vec3::from(lo.map(|v| v as f32)),
                Vec3::from(hi.map(|v| v as f32)),
            );
            let mut point = || Vec3::new(seed.next_f32(), seed.next_f32(), seed.next_f32());
            let o = lo + (hi - lo) * (point() * 3.0 - 1.0);
            let d = (lo + (hi - lo) * point() - o).normalize_or(Vec3::X);
            rays.push([o, d]);
        }
        let (mut a, mut b) = (Pcg32::new(9, 2), Pcg32::new(9, 2));
        let mut differing = 0;
        for r in &rays {
            let t = est.transmittance(r[0], r[1], 4.0, &mut a);
            let mut g = Rng::for_query(b.next_u32(), b.next_u32());
            let want =
                reference.transmittance(&Ray::new(r[0].to_array(), r[1].to_array()), 4.0, &mut g);
            assert_eq!(t.to_bits(), want.to_bits());
            differing += usize::from(t != 1.0);
        }
        // Many answers are not 1: the comparison is not only between misses.
        assert!(differing > 16, "{differing} of 64 rays met the grid");
        let mut rngs: Vec<Pcg32> = (0..rays.len() as u64).map(|i| Pcg32::new(i, 5)).collect();
        let mut batch = vec![None; rays.len()];
        est.sample_distance_batch(&rays, f32::INFINITY, &mut rngs, &mut batch);
        for (i, r) in rays.iter().enumerate() {
            let mut p = Pcg32::new(i as u64, 5);
            let want = est.sample_distance(r[0], r[1], f32::INFINITY, &mut p);
            assert_eq!(batch[i], want);
            assert_eq!(p.next_u32(), rngs[i].next_u32());
        }
    }
}
