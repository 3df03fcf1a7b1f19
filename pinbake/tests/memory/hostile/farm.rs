//! Hostile input to a farm bake split by volume (docs/farm.md, "Splitting the volume"):
//! part files whose counts a bake never writes, part counts beyond the cap, and grid
//! statistics that lie about the volume or were made from another one. Each is one line,
//! the right exit code, bounded memory and time, and no output file.

use std::path::{Path, PathBuf};

use super::{Run, data, expect, run};

const FAST: &[&str] = &["--cells", "6", "--dirs", "octahedral:2", "--step", "0.05"];

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `bake INPUT --part I/N -o OUT` with [`FAST`] and `extra`.
fn part(input: &str, (i, n): (u32, u32), out: &Path, extra: &[&str]) -> Run {
    let spec = format!("{i}/{n}");
    let mut a = vec!["bake", input, "-o", s(out), "--part", &spec];
    a.extend(FAST);
    a.extend(extra);
    run(&a)
}

fn ok(what: &str, r: &Run) {
    assert_eq!(r.code, Some(0), "{what}: {}", r.stderr);
}

/// `pinbake grid-stats` of `input` into `dir/name`: the file's JSON.
fn grid_stats(input: &str, dir: &Path, name: &str) -> (PathBuf, serde_json::Value) {
    let out = dir.join(name);
    ok("grid-stats", &run(&["grid-stats", input, "-o", s(&out)]));
    let v = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    (out, v)
}

fn write_json(path: &Path, v: &serde_json::Value) -> PathBuf {
    std::fs::write(path, serde_json::to_string(v).unwrap()).unwrap();
    path.to_path_buf()
}

/// Rewrites a part file's trailing checksum (xxh3-64 of every byte before it), so that an
/// edit reaches the checks behind it.
fn reseal(b: &mut [u8]) {
    let n = b.len() - 8;
    let sum = xxhash_rust::xxh3::xxh3_64(&b[..n]);
    b[n..].copy_from_slice(&sum.to_le_bytes());
}

/// A part file that declares 2^32 - 1 parts (with a valid checksum) made the merge ask for
/// 64 GiB and abort; now the file's count is checked before anything is sized by it.
#[test]
fn a_part_file_declaring_four_billion_parts_is_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let p0 = d.join("p0.part");
    let p1 = d.join("p1.part");
    ok("part 0", &part("procedural:sphere", (0, 2), &p0, &[]));
    ok("part 1", &part("procedural:sphere", (1, 2), &p1, &[]));
    // Both parts declare the count (magic (8) | version u32 | part index u32 | part count
    // u32), as a bake with that count writes them.
    for count in [u32::MAX, 1025] {
        let lying: Vec<PathBuf> = [&p0, &p1]
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let mut b = std::fs::read(p).unwrap();
                b[16..20].copy_from_slice(&count.to_le_bytes());
                reseal(&mut b);
                let lying = d.join(format!("lying{i}_{count}.part"));
                std::fs::write(&lying, &b).unwrap();
                lying
            })
            .collect();
        let out = d.join("merged.pin");
        let r = run(&["merge", s(&lying[0]), s(&lying[1]), "-o", s(&out)]);
        expect(&format!("merge of {count} parts"), &r, 1, s(&lying[0]));
        assert!(r.stderr.contains(&count.to_string()), "{}", r.stderr);
        assert!(!out.exists());
    }
}

/// `bake --part I/N` wrote a part of any N (2^32 - 1 included): N beyond the cap is a usage
/// error naming the flag, and nothing is written.
#[test]
fn a_part_count_beyond_the_cap_is_a_usage_error() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("p.part");
    for spec in [(1, u32::MAX), (0, 1025)] {
        let r = part("procedural:sphere", spec, &out, &[]);
        expect(&format!("--part {spec:?}"), &r, 2, "--part");
        assert!(r.stderr.contains("1024"), "{}", r.stderr);
        assert!(!out.exists());
    }
    // The cap itself is a part count.
    ok(
        "--part 1023/1024",
        &part("procedural:sphere", (1023, 1024), &out, &[]),
    );
}

/// Statistics whose non-zero box is widened: along z into a part's slab, the part that holds
/// the face refuses (its own leaves do not reach it); along x, a part that holds the box's
/// whole z range refuses, and parts that each hold only some of it bake but do not merge.
/// Each refusal names the statistics file. Before, every part and the merge accepted them
/// and the merged file differed from the monolithic bake.
#[test]
fn a_widened_statistics_box_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let vdb = data("openvdb_smoke1.vdb");
    let vdb = s(&vdb);
    let (_, v) = grid_stats(vdb, d, "stats.json");
    let out = d.join("p.part");
    let widened = |name: &str, corner: usize, axis: usize, by: i64| {
        let mut w = v.clone();
        let c = w["nonzero_box"][corner][axis].as_i64().unwrap();
        w["nonzero_box"][corner][axis] = serde_json::json!(c + by);
        write_json(&d.join(name), &w)
    };
    let up = widened("up.json", 1, 2, 3);
    let r = part(vdb, (1, 2), &out, &["--grid-stats", s(&up)]);
    expect("z face widened, upper part", &r, 1, "up.json");
    assert!(!out.exists());
    let down = widened("down.json", 0, 2, -5);
    let r = part(vdb, (0, 3), &out, &["--grid-stats", s(&down)]);
    expect("z face widened, lower part", &r, 1, "down.json");
    assert!(!out.exists());
    let wide = widened("wide.json", 1, 0, 8);
    let r = part(vdb, (0, 1), &out, &["--grid-stats", s(&wide)]);
    expect("x widened, one part", &r, 1, "wide.json");
    assert!(!out.exists());
    // Two parts each hold some of the box's z range: both bake, the merge refuses.
    let parts: Vec<PathBuf> = (0..2).map(|i| d.join(format!("w{i}.part"))).collect();
    for (i, p) in parts.iter().enumerate() {
        ok(
            "x widened, part of 2",
            &part(vdb, (i as u32, 2), p, &["--grid-stats", s(&wide)]),
        );
    }
    let merged = d.join("m.pin");
    let r = run(&["merge", s(&parts[0]), s(&parts[1]), "-o", s(&merged)]);
    expect("merge of x-widened parts", &r, 1, "do not match the grid");
    assert!(!merged.exists());
}

/// Statistics of another VDB: refused by its size, or, relabelled with this file's size and
/// hash, by what the part reads; the line names the statistics file.
#[test]
fn statistics_of_another_vdb_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let vdb = data("openvdb_smoke1.vdb");
    let vdb = s(&vdb);
    let other = data("gaffer_sphere_density.vdb");
    let (mine, own) = grid_stats(vdb, d, "mine.json");
    let (theirs, mut v) = grid_stats(s(&other), d, "theirs.json");
    let out = d.join("p.part");
    let r = part(vdb, (0, 2), &out, &["--grid-stats", s(&theirs)]);
    expect("another file's statistics", &r, 1, "theirs.json");
    for key in ["file_bytes", "file_xxh3", "grid"] {
        v[key] = own[key].clone();
    }
    let relabelled = write_json(&d.join("relabelled.json"), &v);
    let r = part(vdb, (1, 2), &out, &["--grid-stats", s(&relabelled)]);
    expect("relabelled statistics", &r, 1, "relabelled.json");
    // Only the hash differs (the same size): the content hash names the other file.
    let mut h = own.clone();
    h["file_xxh3"] = serde_json::json!("0".repeat(32));
    let hashed = write_json(&d.join("hashed.json"), &h);
    let r = part(vdb, (0, 2), &out, &["--grid-stats", s(&hashed)]);
    expect("another hash", &r, 1, "hashed.json");
    assert!(!out.exists());
    ok(
        "own statistics",
        &part(vdb, (0, 2), &out, &["--grid-stats", s(&mine)]),
    );
}

/// Parts baked with two different statistics (here, one raises the largest value, which a
/// part of another slab cannot check) do not merge, and parts all baked with statistics
/// that overstate the largest value or the negative values do not either.
#[test]
fn parts_of_different_statistics_do_not_merge() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let vdb = data("openvdb_smoke1.vdb");
    let vdb = s(&vdb);
    let (good, v) = grid_stats(vdb, d, "good.json");
    let mut raised = v.clone();
    raised["max_value"] = serde_json::json!(v["max_value"].as_f64().unwrap() * 2.0);
    let raised = write_json(&d.join("raised.json"), &raised);
    let mut negative = v.clone();
    negative["negative_values"] = serde_json::json!(v["negative_values"].as_u64().unwrap() + 3);
    let negative = write_json(&d.join("negative.json"), &negative);
    let bake = |name: &str, i: u32, stats: &Path| {
        let p = d.join(name);
        ok(name, &part(vdb, (i, 2), &p, &["--grid-stats", s(stats)]));
        p
    };
    let g0 = bake("g0.part", 0, &good);
    let g1 = bake("g1.part", 1, &good);
    let r1 = bake("r1.part", 1, &raised);
    let r0 = bake("r0.part", 0, &raised);
    let n0 = bake("n0.part", 0, &negative);
    let n1 = bake("n1.part", 1, &negative);
    let merged = d.join("m.pin");
    let merge = |a: &Path, b: &Path| run(&["merge", s(a), s(b), "-o", s(&merged)]);
    ok("good parts", &merge(&g0, &g1));
    std::fs::remove_file(&merged).unwrap();
    let r = merge(&g0, &r1);
    expect("two statistics", &r, 1, "grid statistics");
    assert!(r.stderr.contains("r1.part"), "{}", r.stderr);
    expect("raised largest value", &merge(&r0, &r1), 1, "do not match");
    expect("raised negatives", &merge(&n0, &n1), 1, "negative values");
    assert!(!merged.exists());
}

/// The statistics pass holds the reader's topology: `--max-memory` caps it, and a pass that
/// needs more is one line, exit 1, no statistics file.
#[test]
fn a_statistics_pass_beyond_its_memory_is_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("stats.json");
    let vdb = data("openvdb_smoke1.vdb");
    let r = run(&["grid-stats", s(&vdb), "-o", s(&out), "--max-memory", "4M"]);
    expect("grid-stats --max-memory 4M", &r, 1, "memory");
    assert!(!out.exists());
    ok(
        "grid-stats --max-memory 1G",
        &run(&["grid-stats", s(&vdb), "-o", s(&out), "--max-memory", "1G"]),
    );
    assert!(out.exists());
}
