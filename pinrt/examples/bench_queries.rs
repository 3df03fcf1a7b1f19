//! CPU query throughput on a ~26 MB grid (37^3 cells x 16x4 polar directions x 1 pin, the
//! calibration of docs/background.md section 4) with random rays: single queries vs prefetching batches.
//!
//! `cargo run --release -p pinrt --features testing --example bench_queries [rays] [cells] [only]`
//!
//! `only` runs just the rows whose name contains it (e.g. `"transmittance, batched (32)"`), so
//! that `perf record` of the example profiles one kind of query.
//! `cells` (default 37) sets the grid's cells per axis: 80 gives a 262 MB grid, far larger
//! than a last-level cache. Times are the thread's CPU time per query (`CLOCK_THREAD_CPUTIME_ID`),
//! so that a machine shared with other work still gives comparable figures; wall time is
//! printed beside them.

use std::hint::black_box;
use std::time::Instant;

use pinrt::testing::random_grid;
use pinrt::{Directions, PinGrid, RayQuery, Rng, SamplerOptions};

/// CPU time of the calling thread, seconds.
fn thread_cpu_s() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; the clock id is a constant Linux knows.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    assert_eq!(rc, 0, "clock_gettime(CLOCK_THREAD_CPUTIME_ID)");
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

fn rays(n: usize, seed: u32) -> Vec<RayQuery> {
    let mut r = Rng::new(seed);
    (0..n)
        .map(|_| {
            let o = [r.next_f32(), r.next_f32(), r.next_f32()];
            let d = [
                r.next_f32() * 2.0 - 1.0,
                r.next_f32() * 2.0 - 1.0,
                r.next_f32() * 2.0 - 1.0,
            ];
            RayQuery::new(o, d, r.next_f32() * 1.5)
        })
        .collect()
}

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(2_000_000);
    let cells: u32 = std::env::args()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(37);
    let owned = random_grid(Directions::THESIS_DEFAULT, [cells; 3], 1, false, 1);
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("bench.pin");
    owned.write_atomic(&path).expect("write grid");
    let grid = PinGrid::open(&path).expect("open grid");
    let mb = grid.pins_bytes().len() as f64 / 1e6;
    // The thesis' lookup: the calibration's model, one cell read per query without jitter.
    let s = grid
        .sampler()
        .expect("sampler")
        .with_options(SamplerOptions::THESIS);
    let rays = rays(n, 7);
    println!("grid: {cells}^3 x 64 directions, {mb:.1} MB of pins, mapped; {n} random rays");

    let only = std::env::args().nth(3).unwrap_or_default();
    let time = |name: &str, f: &mut dyn FnMut() -> f64| {
        if !name.contains(only.as_str()) {
            return;
        }
        f(); // warm up (page the grid in)
        let t = Instant::now();
        let c = thread_cpu_s();
        let acc = f();
        let ns = (thread_cpu_s() - c) * 1e9 / n as f64;
        let wall = t.elapsed().as_secs_f64() * 1e9 / n as f64;
        println!("{name:<34} {ns:7.1} ns/query CPU ({wall:7.1} wall)   (checksum {acc:.3})");
    };
    time("transmittance, single", &mut || {
        let mut rng = Rng::new(1);
        let mut acc = 0.0f64;
        for q in &rays {
            acc += f64::from(s.transmittance(&q.ray(), q.t_max, &mut rng));
        }
        black_box(acc)
    });
    time("distance, single", &mut || {
        let mut rng = Rng::new(2);
        let mut acc = 0.0f64;
        for q in &rays {
            acc += f64::from(
                s.sample_distance(&q.ray(), q.t_max, &mut rng)
                    .unwrap_or(0.0),
            );
        }
        black_box(acc)
    });
    let mut out_t = vec![0.0f32; n];
    let mut out_d = vec![None; n];
    time("transmittance, batched (32)", &mut || {
        s.transmittance_batch(&rays, 3, 0, &mut out_t);
        black_box(out_t.iter().map(|&x| f64::from(x)).sum())
    });
    time("distance, batched (32)", &mut || {
        s.sample_distance_batch(&rays, 4, 0, &mut out_d);
        black_box(out_d.iter().map(|x| f64::from(x.unwrap_or(0.0))).sum())
    });

    // Compute floor: the same queries on a 4 KB grid that stays in L1.
    let small = random_grid(Directions::THESIS_DEFAULT, [2, 2, 2], 1, false, 1);
    let small = PinGrid::from_bytes(small.to_bytes().expect("bytes")).expect("grid");
    let ss = small
        .sampler()
        .expect("sampler")
        .with_options(SamplerOptions::THESIS);
    time("transmittance, batched, 4 KB grid", &mut || {
        ss.transmittance_batch(&rays, 3, 0, &mut out_t);
        black_box(out_t.iter().map(|&x| f64::from(x)).sum())
    });
    time("distance, batched, 4 KB grid", &mut || {
        ss.sample_distance_batch(&rays, 4, 0, &mut out_d);
        black_box(out_d.iter().map(|x| f64::from(x.unwrap_or(0.0))).sum())
    });

    // Reference: ray marching a 256^3 f32 volume (nearest voxel) at step 0.015.
    let res = 256usize;
    let vol: Vec<f32> = (0..res * res * res).map(|i| (i % 7) as f32 * 0.3).collect();
    let bounds = pinrt::march::MarchBox {
        min: glam::DVec3::ZERO,
        max: glam::DVec3::ONE,
    };
    let density = |p: glam::DVec3| {
        let c = |x: f64| ((x * res as f64) as usize).min(res - 1);
        vol[c(p.x) + res * (c(p.y) + res * c(p.z))]
    };
    if !"ray march 256^3, step 0.015".contains(only.as_str()) {
        return;
    }
    let m = n.min(200_000);
    let c = thread_cpu_s();
    let mut acc = 0.0;
    for q in &rays[..m] {
        acc += pinrt::march::transmittance(
            density,
            &bounds,
            glam::DVec3::from_array(q.origin.map(f64::from)),
            glam::DVec3::from_array(q.dir.map(f64::from)),
            f64::from(q.t_max),
            0.015,
        );
    }
    let ns = (thread_cpu_s() - c) * 1e9 / m as f64;
    println!(
        "{:<34} {ns:7.1} ns/query CPU   (checksum {:.3})",
        "ray march 256^3, step 0.015",
        black_box(acc)
    );
}
