//! CPU query throughput on a ~26 MB grid (37^3 cells x 16x4 polar directions x 1 pin, the
//! calibration of docs/background.md section 4) with random rays: single queries vs prefetching batches.
//!
//! `cargo run --release -p pinrt --features testing --example bench_queries [rays]`

use std::hint::black_box;
use std::time::Instant;

use pinrt::testing::random_grid;
use pinrt::{Directions, PinGrid, RayQuery, Rng};

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
    let owned = random_grid(Directions::THESIS_DEFAULT, [37, 37, 37], 1, false, 1);
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("bench.pin");
    owned.write_atomic(&path).expect("write grid");
    let grid = PinGrid::open(&path).expect("open grid");
    let mb = grid.pins_bytes().len() as f64 / 1e6;
    let s = grid.sampler().expect("sampler");
    let rays = rays(n, 7);
    println!("grid: 37^3 x 64 directions, {mb:.1} MB of pins, mapped; {n} random rays");

    let time = |name: &str, f: &mut dyn FnMut() -> f64| {
        f(); // warm up (page the grid in)
        let t = Instant::now();
        let acc = f();
        let ns = t.elapsed().as_secs_f64() * 1e9 / n as f64;
        println!("{name:<34} {ns:7.1} ns/query   (checksum {acc:.3})");
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
    let ss = small.sampler().expect("sampler");
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
    let m = n.min(200_000);
    let t = Instant::now();
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
    let ns = t.elapsed().as_secs_f64() * 1e9 / m as f64;
    println!(
        "{:<34} {ns:7.1} ns/query   (checksum {:.3})",
        "ray march 256^3, step 0.015",
        black_box(acc)
    );
}
