//! CPU cost of chained lookups (docs/sampling.md section 12): ns per batched query for each
//! chain stride and lookup point, on the same random rays through a grid the size of the
//! default bake (20^3 cells x octahedral:16 x 1 pin, 16 MB), in one run so that the ratios
//! hold on a loaded machine. Times are this thread's CPU time (Linux
//! `/proc/thread-self/schedstat`; wall time elsewhere), so that other jobs on a shared machine
//! do not inflate them.
//!
//! `cargo run --release -p pinrt --features testing --example bench_chain [rays]`

use std::hint::black_box;
use std::time::Instant;

use pinrt::testing::random_grid;
use pinrt::{Directions, PinGrid, RayQuery, Rng, SamplerOptions};

/// Rays from inside the unit cube: `t_max` uniform in [0, 1.5] for half of them (distance
/// queries inside the medium), `+inf` (to the box exit, shadow rays) for the other half.
fn rays(n: usize, seed: u32) -> Vec<RayQuery> {
    let mut r = Rng::new(seed);
    (0..n)
        .map(|i| {
            let o = [r.next_f32(), r.next_f32(), r.next_f32()];
            let d = [
                r.next_f32() * 2.0 - 1.0,
                r.next_f32() * 2.0 - 1.0,
                r.next_f32() * 2.0 - 1.0,
            ];
            let t = if i % 2 == 0 {
                r.next_f32() * 1.5
            } else {
                f32::INFINITY
            };
            RayQuery::new(o, d, t)
        })
        .collect()
}

/// This thread's CPU time in seconds, or `None` where the kernel does not report it.
fn thread_cpu_s() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: u64 = s.split_whitespace().next()?.parse().ok()?;
    Some(ns as f64 * 1e-9)
}

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(1_000_000);
    let owned = random_grid(Directions::Octahedral { n: 16 }, [20, 20, 20], 1, false, 1);
    let grid = PinGrid::from_bytes(owned.to_bytes().expect("bytes")).expect("grid");
    let mb = grid.pins_bytes().len() as f64 / 1e6;
    let rays = rays(n, 7);
    println!("grid: 20^3 x 256 directions, {mb:.1} MB of pins; {n} random rays");
    println!("| stride | lookup at | transmittance ns/query | distance ns/query |");
    println!("|---|---|---|---|");
    let mut out_t = vec![0.0f32; n];
    let mut out_d = vec![None; n];
    for (stride, middle) in [
        (32, false),
        (32, true),
        (16, false),
        (8, false),
        (8, true),
        (4, false),
        (2, false),
        (1, false),
    ] {
        let s = grid
            .sampler()
            .expect("sampler")
            .with_options(SamplerOptions {
                spatial_jitter: 1.0,
                directional_jitter: 1.0,
                chain_stride: stride,
                midpoint_lookup: middle,
                ..SamplerOptions::THESIS
            });
        let time = |f: &mut dyn FnMut() -> f64| {
            f(); // warm up
            let (t, c) = (Instant::now(), thread_cpu_s());
            black_box(f());
            let s = match (c, thread_cpu_s()) {
                (Some(a), Some(b)) => b - a,
                _ => t.elapsed().as_secs_f64(),
            };
            s * 1e9 / n as f64
        };
        let t = time(&mut || {
            s.transmittance_batch(&rays, 3, 0, &mut out_t);
            out_t.iter().map(|&x| f64::from(x)).sum()
        });
        let d = time(&mut || {
            s.sample_distance_batch(&rays, 4, 0, &mut out_d);
            out_d.iter().map(|x| f64::from(x.unwrap_or(0.0))).sum()
        });
        let at = if middle { "middle" } else { "start" };
        println!("| {stride} | {at} | {t:.0} | {d:.0} |");
    }
}
