//! Per-query cost of the CPU trackers, the figures behind the tracker tables of
//! `docs/companions.md` and the cost comparisons in `pinrender::render`:
//!
//! * `unit_box/*`: delta and ratio tracking of transmittance through a homogeneous unit box
//!   (extinction 1) over a 1^3 and a 16^3 majorant grid;
//! * `cosine/*`: the closed-form cosine-noise tracker (`pinlab::ClosedFormTracker`) against
//!   delta and ratio tracking over a 16^3 majorant grid of the same field, transmittance and
//!   distance sampling, on the four fields of the companions table.
//!
//! `cargo bench -p pin-benches --bench trackers` runs criterion; each iteration answers
//! [`RAYS`] queries, so criterion's throughput line is queries per second. A filter picks
//! groups, e.g. `cargo bench -p pin-benches --bench trackers -- cosine`.

use std::hint::black_box;
use std::sync::Arc;
use std::time::Duration;

use criterion::{Criterion, Throughput};
use glam::{DVec3, Vec3};
use pinlab::{AnalyticOpticalDepth, ClosedFormTracker};
use pinrender::render::{
    Aabb, DeltaTracking, HomogeneousBox, MajorantGrid, Pcg32, RatioTracking, TransportEstimator,
};
use pinrender::testing::CosNoise;

/// Queries per criterion iteration.
const RAYS: usize = 1024;

/// The renderer's cosine-noise fixture with its closed form, as the lab's trait.
struct CosineDepth(Arc<CosNoise>);

impl AnalyticOpticalDepth for CosineDepth {
    fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        (self.0.lo, self.0.hi)
    }
    fn optical_depth(&self, o: DVec3, d: DVec3, t: f64) -> f64 {
        self.0.optical_depth(o, d, t)
    }
    fn extinction(&self, p: DVec3) -> Option<f64> {
        Some(self.0.sigma(p))
    }
}

/// A uniform direction (Marsaglia's method on the unit disc).
fn direction(rng: &mut Pcg32) -> Vec3 {
    loop {
        let (a, b) = (2.0 * rng.next_f32() - 1.0, 2.0 * rng.next_f32() - 1.0);
        let s = a * a + b * b;
        if s < 1.0 && s > 0.0 {
            let r = 2.0 * (1.0 - s).sqrt();
            return Vec3::new(a * r, b * r, 1.0 - 2.0 * s);
        }
    }
}

/// Rays from uniform points of the unit cube in uniform directions.
fn rays_inside(seed: u64) -> Vec<(Vec3, Vec3)> {
    let mut rng = Pcg32::new(seed, 1);
    (0..RAYS)
        .map(|_| {
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            (o, direction(&mut rng))
        })
        .collect()
}

/// Transmittance (or a distance sample) of every ray, summed so nothing is optimised away.
fn answer_all(est: &dyn TransportEstimator, rays: &[(Vec3, Vec3)], distance: bool) -> f32 {
    let mut rng = Pcg32::new(9, 9);
    let mut acc = 0.0f32;
    for &(o, d) in rays {
        acc += if distance {
            est.sample_distance(o, d, f32::INFINITY, &mut rng)
                .unwrap_or(-1.0)
        } else {
            est.transmittance(o, d, f32::INFINITY, &mut rng)
        };
    }
    acc
}

fn unit_box(c: &mut Criterion) {
    let field = Arc::new(HomogeneousBox::new(Aabb::from_arrays([0.0; 3], [1.0; 3]), 1.0).unwrap());
    // Rays entering the box through its z = 0 face from below.
    let mut rng = Pcg32::new(1, 1);
    let rays: Vec<(Vec3, Vec3)> = (0..RAYS)
        .map(|_| {
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), -1.0);
            let d = (Vec3::new(rng.next_f32(), rng.next_f32(), 1.0) - o + Vec3::Z).normalize();
            (o, d)
        })
        .collect();
    let mut group = c.benchmark_group("unit_box");
    group.throughput(Throughput::Elements(RAYS as u64));
    for dims in [1u32, 16] {
        let maj = Arc::new(MajorantGrid::from_field(&*field, [dims; 3]).unwrap());
        let delta = DeltaTracking::new(field.clone(), maj.clone());
        let ratio = RatioTracking::new(field.clone(), maj);
        group.bench_function(format!("delta_transmittance/majorant_{dims}"), |b| {
            b.iter(|| black_box(answer_all(&delta, &rays, false)))
        });
        group.bench_function(format!("ratio_transmittance/majorant_{dims}"), |b| {
            b.iter(|| black_box(answer_all(&ratio, &rays, false)))
        });
    }
    group.finish();
}

fn cosine(c: &mut Criterion) {
    let rays = rays_inside(5);
    let mut group = c.benchmark_group("cosine");
    group.throughput(Throughput::Elements(RAYS as u64));
    // (waves, |w|, density): the rows of the companions table.
    for (k, freq, density) in [
        (24usize, 20.0, 2.0),
        (24, 80.0, 2.0),
        (48, 160.0, 2.0),
        (24, 80.0, 20.0),
    ] {
        let noise = Arc::new(CosNoise::new(k, freq, density, 1));
        let maj = Arc::new(MajorantGrid::from_field(&*noise, [16; 3]).unwrap());
        let closed = ClosedFormTracker::new(Arc::new(CosineDepth(noise.clone()))).unwrap();
        let delta = DeltaTracking::new(noise.clone(), maj.clone());
        let ratio = RatioTracking::new(noise, maj);
        let field = format!("k{k}_w{freq}_d{density}");
        let estimators: [(&str, &dyn TransportEstimator); 3] = [
            ("closed_form", &closed),
            ("delta", &delta),
            ("ratio", &ratio),
        ];
        for (name, est) in estimators {
            group.bench_function(format!("{name}_transmittance/{field}"), |b| {
                b.iter(|| black_box(answer_all(est, &rays, false)))
            });
            if name != "ratio" {
                group.bench_function(format!("{name}_distance/{field}"), |b| {
                    b.iter(|| black_box(answer_all(est, &rays, true)))
                });
            }
        }
    }
    group.finish();
}

fn main() {
    let mut c = Criterion::default()
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2))
        .configure_from_args();
    unit_box(&mut c);
    cosine(&mut c);
    c.final_summary();
}
