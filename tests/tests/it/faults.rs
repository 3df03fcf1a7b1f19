//! Faults: many threads on one mapped grid, and a pin file truncated under a loaded grid.

use glam::DVec3;
use pin_format::Directions;
use pin_volume::{Aabb, CosineNoise, procedural::CosineParams};
use pinbake::{BakeOptions, bake};
use pinrt::{PinGrid, QueryResult, RayQuery, Rng};

fn baked_file(dir: &std::path::Path) -> std::path::PathBuf {
    let unit = Aabb::new(DVec3::ZERO, DVec3::ONE);
    let noise = CosineNoise::new(
        unit,
        &CosineParams {
            seed: 1,
            density: 2.0,
            ..CosineParams::default()
        },
        "c",
    )
    .unwrap();
    let opts = BakeOptions {
        cells: [5, 5, 5],
        directions: Directions::Octahedral { n: 4 },
        step: 0.02,
        threads: Some(2),
        ..BakeOptions::default()
    };
    let (owned, _) = bake(&noise, &opts, &|_| {}).unwrap();
    let path = dir.join("grid.pin");
    owned.write_atomic(&path).unwrap();
    path
}

fn rays(n: usize) -> Vec<RayQuery> {
    let mut g = Rng::for_query(42, 0);
    (0..n)
        .map(|_| {
            let o = [g.next_f32(), g.next_f32(), g.next_f32()];
            let d = [g.next_f32() - 0.5, g.next_f32() - 0.5, g.next_f32() - 0.5];
            RayQuery::new(
                o,
                d,
                if g.next_f32() < 0.5 {
                    f32::INFINITY
                } else {
                    g.next_f32()
                },
            )
        })
        .collect()
}

/// 5(b), cross-crate: four threads sampling one memory-mapped baked grid give the bytes one
/// thread gives (pinrt's own `tests::threads_agree_with_one_thread_on_a_mapped_grid` does the
/// same on a random grid).
#[test]
fn threads_on_one_mapped_grid_agree_with_one_thread() {
    let dir = tempfile::tempdir().unwrap();
    let grid = PinGrid::open(baked_file(dir.path())).unwrap();
    assert!(grid.is_mapped());
    let s = grid.sampler().unwrap();
    let rs = rays(40_000);
    let mut one = vec![bytemuck::Zeroable::zeroed(); rs.len()];
    s.query_batch(&rs, 9, 0, &mut one);
    let mut many: Vec<QueryResult> = vec![bytemuck::Zeroable::zeroed(); rs.len()];
    let chunk = rs.len() / 4;
    std::thread::scope(|sc| {
        for (i, (r, o)) in rs.chunks(chunk).zip(many.chunks_mut(chunk)).enumerate() {
            let s = &s;
            sc.spawn(move || s.query_batch(r, 9, (i * chunk) as u32, o));
        }
    });
    assert_eq!(
        bytemuck::cast_slice::<_, u8>(&one),
        bytemuck::cast_slice::<_, u8>(&many)
    );
}

/// 5(c): a grid loaded with `read_into_memory` keeps answering, with the same bytes, after
/// another process truncates the file; a fresh open of the truncated file is a clean error.
/// (A *mapped* grid would take SIGBUS on touching the lost pages: not exercised here.)
#[test]
fn read_into_memory_is_immune_to_truncation() {
    let dir = tempfile::tempdir().unwrap();
    let path = baked_file(dir.path());
    let grid = PinGrid::read_into_memory(&path).unwrap();
    assert!(!grid.is_mapped());
    let s = grid.sampler().unwrap();
    let rs = rays(5_000);
    let mut before = vec![bytemuck::Zeroable::zeroed(); rs.len()];
    s.query_batch(&rs, 3, 0, &mut before);
    // Truncate the file under the loaded grid (what a concurrent re-bake without the atomic
    // rename would do).
    std::fs::OpenOptions::new()
        .write(true)
        .open(&path)
        .unwrap()
        .set_len(100)
        .unwrap();
    let mut after: Vec<QueryResult> = vec![bytemuck::Zeroable::zeroed(); rs.len()];
    s.query_batch(&rs, 3, 0, &mut after);
    assert_eq!(
        bytemuck::cast_slice::<_, u8>(&before),
        bytemuck::cast_slice::<_, u8>(&after)
    );
    grid.verify().expect("the in-memory copy still verifies");
    let e = PinGrid::open(&path).expect_err("a truncated file must not open");
    let m = e.to_string();
    assert!(!m.contains('\n') && m.contains("grid.pin"), "{m}");
    let e = PinGrid::read_into_memory(&path).expect_err("nor read");
    eprintln!("truncated file: open -> {m}; read_into_memory -> {e}");
}
