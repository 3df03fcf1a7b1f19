//! The pin grid as a renderer estimator: `pins` everywhere, or the secondary half of PinMS.

use std::sync::Arc;

use glam::Vec3;
use pinrt::{PinGrid, Ray, RayQuery, Rng, Sampler, SamplerOptions, UnitTransform};

use super::{Pcg32, RenderError, TransportEstimator};

/// A placed pin grid answering the renderer's queries. It shares its grid (an `Arc`, so a
/// scene's instances and the GPU upload read one copy) and keeps the placement and lookup
/// options; each query makes its sampler over the grid, which costs a few copies and no
/// matrix inversion ([`Sampler::with_transform`]).
pub struct PinsEstimator {
    grid: Arc<PinGrid>,
    xf: UnitTransform,
    opts: SamplerOptions,
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
            grid,
            xf,
            opts,
        })
    }

    /// The shared grid (for the GPU upload).
    pub fn grid(&self) -> &Arc<PinGrid> {
        &self.grid
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
    g.extend(
        rngs.iter_mut()
            .map(|rng| Rng::for_query(rng.next_u32(), rng.next_u32())),
    );
}

thread_local! {
    /// [`pin_queries`]' buffers.
    static QUERIES: std::cell::RefCell<(Vec<RayQuery>, Vec<Rng>)> =
        const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
}

impl TransportEstimator for PinsEstimator {
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
        // Two draws of the path generator seed the query, as the GPU seeds its queries.
        let mut r = Rng::for_query(rng.next_u32(), rng.next_u32());
        self.sampler()
            .sample_distance(&Ray::new(o.to_array(), d.to_array()), t_max, &mut r)
    }
    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32 {
        let mut r = Rng::for_query(rng.next_u32(), rng.next_u32());
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
    fn name(&self) -> String {
        "pins".into()
    }
    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        self.bounds
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pinrt::testing::random_grid;

    /// The estimator answers exactly as a sampler borrowed from the grid with the same
    /// placement and options, single and batched, and draws the same path numbers.
    #[test]
    fn answers_as_the_borrowed_sampler() {
        let owned = random_grid(
            pin_format::Directions::THESIS_DEFAULT,
            [4, 3, 5],
            2,
            true,
            7,
        );
        let grid = Arc::new(PinGrid::from_bytes(owned.to_bytes().unwrap()).unwrap());
        let opts = SamplerOptions {
            spatial_jitter: 1.0,
            ..SamplerOptions::default()
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
