//! Volume sources against the real files in data/: raw fixtures, OpenVDB files (valid,
//! level set, damaged) through the isolated worker process.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use glam::{DVec3, IVec3};
use pin_volume::raw::{Endian, RawOptions, RawType, read_raw};
use pin_volume::vdb::{VdbOptions, VdbSource};
use pin_volume::{Density, DensityScale, DensitySource, SourceSpec, open_source};

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../data");

fn data(name: &str) -> PathBuf {
    Path::new(DATA).join(name)
}

fn vdb_opts() -> VdbOptions {
    VdbOptions::with_worker(env!("CARGO_BIN_EXE_pinbake"))
}

fn open_vdb(name: &str, grid: Option<&str>) -> Result<VdbSource, String> {
    let opt = VdbOptions {
        grid: grid.map(str::to_string),
        ..vdb_opts()
    };
    VdbSource::open(&data(name), &opt, DensityScale::ONE).map_err(|e| e.to_string())
}

// ------------------------------------------------------------------------------------------
// Raw
// ------------------------------------------------------------------------------------------

#[test]
fn inviwo_fixtures_read_exactly_in_every_type_and_endianness() {
    let cases = [
        ("testdata.UINT8.raw", RawType::U8, Endian::Little),
        (
            "testdata.UINT16.LittleEndian.raw",
            RawType::U16,
            Endian::Little,
        ),
        ("testdata.UINT16.BigEndian.raw", RawType::U16, Endian::Big),
        (
            "testdata.FLOAT16.LittleEndian.raw",
            RawType::F16,
            Endian::Little,
        ),
        (
            "testdata.FLOAT32.LittleEndian.raw",
            RawType::F32,
            Endian::Little,
        ),
        ("testdata.FLOAT32.BigEndian.raw", RawType::F32, Endian::Big),
        (
            "testdata.FLOAT64.LittleEndian.raw",
            RawType::F64,
            Endian::Little,
        ),
    ];
    for (file, ty, endian) in cases {
        let opt = RawOptions {
            dims: Some([13, 7, 3]),
            voxel_type: Some(ty),
            endian,
            ..Default::default()
        };
        let g = read_raw(
            &data(&format!("inviwo_testdata/{file}")),
            &opt,
            DensityScale::ONE,
        )
        .unwrap();
        for z in 0..3 {
            for y in 0..7 {
                for x in 0..13 {
                    assert_eq!(
                        g.voxel(x, y, z),
                        Some((x + y + z) as f32),
                        "{file} ({x},{y},{z})"
                    );
                    // Voxel centres sample the voxel value.
                    let p = DVec3::new(x as f64 + 0.5, y as f64 + 0.5, z as f64 + 0.5);
                    assert_eq!(g.extinction(p), (x + y + z) as f32, "{file}");
                }
            }
        }
        // The wrong byte order reads different numbers (so the option matters).
        if ty != RawType::U8 {
            let flipped = RawOptions {
                endian: match endian {
                    Endian::Little => Endian::Big,
                    Endian::Big => Endian::Little,
                },
                nan_as_zero: true,
                clamp_negative: true,
                ..opt
            };
            let g2 = read_raw(
                &data(&format!("inviwo_testdata/{file}")),
                &flipped,
                DensityScale::ONE,
            )
            .unwrap();
            assert_ne!(g2.data(), g.data(), "{file}");
        }
    }
}

#[test]
fn hydrogen_atom_infers_dims_and_type_from_its_name() {
    let g = read_raw(
        &data("hydrogen_atom_128x128x128_uint8.raw"),
        &RawOptions::default(),
        DensityScale::ONE,
    )
    .unwrap();
    assert_eq!(g.dims(), [128, 128, 128]);
    assert_eq!(g.max_value(), 250.0);
    let mean = g.data().iter().map(|v| *v as f64).sum::<f64>() / g.data().len() as f64;
    assert!((mean - 2.857).abs() < 0.01, "mean {mean}");
    assert!(g.describe().contains("u8"));
    let occ = g.occupied_bounds().unwrap();
    assert!(occ.is_valid());
}

#[test]
fn water_esp_is_signed_and_needs_clamping() {
    let p = data("water_esp_31x34x33_float32.raw");
    let e = read_raw(&p, &RawOptions::default(), DensityScale::ONE)
        .unwrap_err()
        .to_string();
    assert!(e.contains("negative") && e.contains("water_esp"), "{e}");
    let g = read_raw(
        &p,
        &RawOptions {
            clamp_negative: true,
            ..Default::default()
        },
        DensityScale::ONE,
    )
    .unwrap();
    assert_eq!(g.dims(), [31, 34, 33]);
    assert!((g.max_value() - 71.36).abs() < 0.01);
}

#[test]
fn raw_wrong_size_and_nan_errors() {
    let opt = RawOptions {
        dims: Some([13, 7, 4]),
        voxel_type: Some(RawType::U8),
        ..Default::default()
    };
    let e = read_raw(
        &data("inviwo_testdata/testdata.UINT8.raw"),
        &opt,
        DensityScale::ONE,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("364 bytes") && e.contains("273 bytes"), "{e}");
    assert!(e.contains("testdata.UINT8.raw"), "{e}");

    let dir = tempfile::tempdir().unwrap();
    let mut v = vec![0.5f32; 4 * 5 * 6];
    v[3 + 4 * (4 + 5 * 5)] = f32::NAN;
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    let p = dir.path().join("nan_4x5x6_float32.raw");
    std::fs::write(&p, bytes).unwrap();
    let e = read_raw(&p, &RawOptions::default(), DensityScale::ONE)
        .unwrap_err()
        .to_string();
    assert!(e.contains("NaN") && e.contains("(3,4,5)"), "{e}");
}

// ------------------------------------------------------------------------------------------
// VDB: valid files
// ------------------------------------------------------------------------------------------

/// The world box of an inclusive index box grown by one voxel (trilinear support).
fn world_box(lo: IVec3, hi: IVec3, voxel: f64, t: DVec3) -> (DVec3, DVec3) {
    (
        (lo - 1).as_dvec3() * voxel + t,
        (hi + 1).as_dvec3() * voxel + t,
    )
}

fn assert_close(a: DVec3, b: DVec3, tol: f64) {
    assert!((a - b).abs().max_element() <= tol, "{a} vs {b}");
}

#[test]
fn smoke_half_float_active_mask() {
    let s = open_vdb("openvdb_smoke1.vdb", None).unwrap();
    let d = s.describe();
    assert!(d.contains("density") && d.contains("half"), "{d}");
    let b = s.bounds();
    let vs = 0.476190;
    let t = DVec3::new(-34.0476, -13.0952, -26.4286);
    // Active bbox (1,2,1)-(111,223,112): the non-zero box lies inside it.
    let (lo, hi) = s.index_bounds();
    assert!(lo.cmpge(IVec3::new(1, 2, 1)).all(), "{lo}");
    assert!(hi.cmple(IVec3::new(111, 223, 112)).all(), "{hi}");
    let (wlo, whi) = world_box(lo, hi, vs, t);
    assert_close(b.min, wlo, 1e-3);
    assert_close(b.max, whi, 1e-3);
    // And not much smaller than the recorded active box.
    let (alo, ahi) = world_box(IVec3::new(1, 2, 1), IVec3::new(111, 223, 112), vs, t);
    assert!((b.min - alo).max_element() < 10.0 * vs);
    assert!((ahi - b.max).max_element() < 10.0 * vs);
    let m = s.max_extinction_in(b);
    assert!(m > 0.0 && m.is_finite(), "{m}");
    // Sampled values never exceed the region maximum and some are non-zero.
    let mut nonzero = 0;
    for i in 0..4000 {
        let u = DVec3::new(
            (i % 17) as f64 / 17.0,
            (i % 31) as f64 / 31.0,
            (i % 13) as f64 / 13.0,
        );
        let p = b.min + b.extent() * u;
        let v = s.extinction(p);
        assert!(v >= 0.0 && v <= m);
        nonzero += usize::from(v > 0.0);
    }
    assert!(nonzero > 100, "{nonzero}");
    assert_eq!(s.extinction(b.max + 1.0), 0.0);
}

#[test]
fn arnold_three_density_grids_by_index() {
    let e = open_vdb("arnold_grids_3x_density.vdb", None).unwrap_err();
    assert!(e.contains("density#0, density#1, density#2"), "{e}");
    assert!(e.contains("arnold_grids_3x_density.vdb"), "{e}");
    let expect = [
        (DVec3::new(4.0, 0.0, 0.0), IVec3::splat(-5), IVec3::splat(5)),
        (
            DVec3::new(2.0, 0.0, 0.0),
            IVec3::new(-9, -13, -9),
            IVec3::new(9, 5, 12),
        ),
        (DVec3::ZERO, IVec3::splat(-5), IVec3::splat(5)),
    ];
    let mut boxes = Vec::new();
    for (k, (t, alo, ahi)) in expect.iter().enumerate() {
        let s = open_vdb("arnold_grids_3x_density.vdb", Some(&format!("density#{k}"))).unwrap();
        let (lo, hi) = s.index_bounds();
        assert!(
            lo.cmpge(*alo).all() && hi.cmple(*ahi).all(),
            "grid {k}: {lo} {hi}"
        );
        let (wlo, whi) = world_box(lo, hi, 0.1, *t);
        assert_close(s.bounds().min, wlo, 1e-6);
        assert_close(s.bounds().max, whi, 1e-6);
        assert!(s.max_extinction_in(s.bounds()) > 0.0);
        boxes.push(s.bounds());
    }
    assert_ne!(boxes[0], boxes[1]);
    assert_ne!(boxes[0], boxes[2]);
}

#[test]
fn gaffer_version_223_blosc() {
    let s = open_vdb("gaffer_sphere_density.vdb", None).unwrap();
    let (lo, hi) = s.index_bounds();
    assert!(lo.cmpge(IVec3::new(-5, -4, -5)).all() && hi.cmple(IVec3::new(5, 4, 5)).all());
    let (wlo, whi) = world_box(lo, hi, 0.2, DVec3::new(0.0, 2.0, 0.0));
    assert_close(s.bounds().min, wlo, 1e-6);
    assert_close(s.bounds().max, whi, 1e-6);
    assert!(s.extinction(DVec3::new(0.0, 2.0, 0.0)) > 0.0);
}

#[test]
fn oiio_sphere_and_density_scale() {
    let s = open_vdb("oiio_sphere_density.vdb", None).unwrap();
    let c = s.extinction(DVec3::ZERO);
    assert!(c > 0.0);
    let (lo, hi) = s.index_bounds();
    assert!(lo.cmpge(IVec3::splat(-12)).all() && hi.cmple(IVec3::splat(12)).all());
    let twice = VdbSource::open(
        &data("oiio_sphere_density.vdb"),
        &vdb_opts(),
        DensityScale::new(2.0).unwrap(),
    )
    .unwrap();
    assert_eq!(twice.extinction(DVec3::ZERO), 2.0 * c);
    let huge = VdbSource::open(
        &data("oiio_sphere_density.vdb"),
        &vdb_opts(),
        DensityScale::new(1e30).unwrap(),
    );
    // Either representable or a clear overflow error naming a voxel.
    if let Err(e) = huge {
        assert!(e.to_string().contains("overflows"), "{e}");
    }
    let zero = VdbSource::open(
        &data("oiio_sphere_density.vdb"),
        &vdb_opts(),
        DensityScale::new(0.0).unwrap(),
    );
    assert!(zero.unwrap_err().to_string().contains("zero"));
    // Through the generic entry point as well.
    let b = open_source(
        &SourceSpec::Vdb(data("oiio_sphere_density.vdb"), vdb_opts()),
        DensityScale::ONE,
    )
    .unwrap();
    assert_eq!(b.extinction(DVec3::ZERO), c);
}

#[test]
fn level_set_is_refused_then_converted() {
    let e = open_vdb("openvdb_sphere_levelset.vdb", None).unwrap_err();
    assert!(
        e.contains("level set") && e.contains("--levelset-to-fog"),
        "{e}"
    );
    let s = VdbSource::open(
        &data("openvdb_sphere_levelset.vdb"),
        &VdbOptions {
            levelset_to_fog: true,
            ..vdb_opts()
        },
        DensityScale::ONE,
    )
    .unwrap();
    // Radius about 3 world units (60 voxels of 0.05): inside is 1, outside 0, and the deep
    // interior (tiles, not leaves) is filled.
    assert_eq!(s.extinction(DVec3::ZERO), 1.0);
    assert_eq!(s.extinction(DVec3::new(1.5, -1.0, 0.5)), 1.0);
    assert_eq!(s.extinction(DVec3::new(2.9, 2.9, 0.0)), 0.0);
    assert_eq!(s.extinction(DVec3::new(0.0, 0.0, 3.2)), 0.0);
    let b = s.bounds();
    assert!(
        b.max.x > 2.8 && b.max.x < 3.3 && b.min.x < -2.8 && b.min.x > -3.3,
        "{b:?}"
    );
    // Volume check: fraction of inside samples on a lattice ~ sphere / cube.
    let r = 3.0;
    let n = 24;
    let mut inside = 0;
    for i in 0..n * n * n {
        let u = DVec3::new((i % n) as f64, ((i / n) % n) as f64, (i / (n * n)) as f64);
        let p = (u + 0.5) / n as f64 * 2.0 * r - r;
        inside += usize::from(s.extinction(p) > 0.5);
    }
    let frac = inside as f64 / (n * n * n) as f64;
    assert!((frac - std::f64::consts::PI / 6.0).abs() < 0.05, "{frac}");
}

// ------------------------------------------------------------------------------------------
// VDB: damaged files and the isolation
// ------------------------------------------------------------------------------------------

#[test]
fn every_damaged_file_is_a_quick_one_line_error() {
    let expect = [
        // A 200,000^3 box in the metadata around an empty tree: the sparse reader has no
        // reason to fear the box (OpenVDB writes valid grids that large), only the tree.
        ("bad-bbox-bomb.vdb", "no active voxels"),
        ("bad-bbox-empty.vdb", "no active voxels"),
        ("bad-bbox-huge.vdb", "out-of-range"),
        ("bad-bbox-inverted.vdb", "inverted"),
        ("bad-bbox-overflow.vdb", "out-of-range"),
        ("bad-bbox-roundup.vdb", "out-of-range"),
        ("truncated.vdb", "truncated"),
    ];
    for (file, what) in expect {
        let t = Instant::now();
        let e = open_vdb(&format!("oiio_damaged/{file}"), None).unwrap_err();
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "{file} took {:?}",
            t.elapsed()
        );
        assert!(e.contains(file) && e.contains(what), "{file}: {e}");
        assert!(!e.contains('\n'), "{e}");
    }
}

#[test]
fn mutated_files_never_take_the_parent_down() {
    // Deterministic byte corruption of a valid file: every outcome is Ok or an Err, quickly.
    let src = std::fs::read(data("gaffer_sphere_density.vdb")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut state = 0x1234_5678_9abc_def0u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let mut errors = 0;
    for case in 0..24 {
        let mut bytes = src.clone();
        for _ in 0..(1 + case % 4) {
            let i = (next() % bytes.len() as u64) as usize;
            bytes[i] = next() as u8;
        }
        if case % 6 == 5 {
            bytes.truncate((next() % bytes.len() as u64) as usize);
        }
        let p = dir.path().join(format!("m{case}.vdb"));
        std::fs::write(&p, &bytes).unwrap();
        let opt = VdbOptions {
            timeout: Duration::from_secs(20),
            ..vdb_opts()
        };
        let t = Instant::now();
        match VdbSource::open(&p, &opt, DensityScale::ONE) {
            Ok(s) => assert!(s.bounds().is_valid()),
            Err(e) => {
                errors += 1;
                let e = e.to_string();
                assert!(
                    e.contains(&format!("m{case}.vdb")) && !e.contains('\n'),
                    "{e}"
                );
            }
        }
        assert!(t.elapsed() < Duration::from_secs(25));
    }
    // Most mutations land in the data, which vdb-rs does not checksum; just make sure the
    // test exercised the error path at all.
    assert!(errors > 0);
}

#[cfg(unix)]
fn script(dir: &Path, name: &str, body: &str) -> PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let p = dir.join(name);
    std::fs::write(&p, format!("#!/bin/sh\n{body}\n")).unwrap();
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
    p
}

#[cfg(unix)]
#[test]
fn worker_crash_timeout_and_memory_limit_become_errors() {
    let dir = tempfile::tempdir().unwrap();
    let file = data("oiio_sphere_density.vdb");
    let crash = script(dir.path(), "crash.sh", "kill -SEGV $$");
    let e = VdbSource::open(&file, &VdbOptions::with_worker(crash), DensityScale::ONE)
        .unwrap_err()
        .to_string();
    assert!(e.contains("crashed (signal 11)"), "{e}");

    let slow = script(dir.path(), "slow.sh", "exec sleep 30");
    let opt = VdbOptions {
        timeout: Duration::from_millis(300),
        ..VdbOptions::with_worker(slow)
    };
    let t = Instant::now();
    let e = VdbSource::open(&file, &opt, DensityScale::ONE)
        .unwrap_err()
        .to_string();
    assert!(e.contains("timed out"), "{e}");
    assert!(t.elapsed() < Duration::from_secs(5));

    let garbage = script(dir.path(), "garbage.sh", "echo hello");
    let e = VdbSource::open(&file, &VdbOptions::with_worker(garbage), DensityScale::ONE)
        .unwrap_err()
        .to_string();
    assert!(e.contains("worker stream"), "{e}");

    let missing = VdbOptions::with_worker(dir.path().join("nope"));
    let e = VdbSource::open(&file, &missing, DensityScale::ONE)
        .unwrap_err()
        .to_string();
    assert!(e.contains("cannot start"), "{e}");

    // The smoke needs more than 6 MiB of address space in the worker (about 5.4 MiB
    // resident: the worker streams the leaves, so its libraries and buffers are most of it).
    let opt = VdbOptions {
        memory_limit: Some(6 << 20),
        ..vdb_opts()
    };
    let e = VdbSource::open(&data("openvdb_smoke1.vdb"), &opt, DensityScale::ONE)
        .unwrap_err()
        .to_string();
    assert!(e.contains("needs more than 6 MiB"), "{e}");
}

#[test]
fn missing_file_and_non_vdb_file() {
    let e = open_vdb("does_not_exist.vdb", None).unwrap_err();
    assert!(e.contains("does_not_exist.vdb"), "{e}");
    let e = open_vdb("hydrogen_atom_128x128x128_uint8.raw", None).unwrap_err();
    assert!(e.contains("not an OpenVDB file"), "{e}");
}

// ------------------------------------------------------------------------------------------
// The dense copy a bake marches instead of the sparse tree.

/// The smoke's dense copy holds the same field as the tree: every voxel value bit for bit,
/// and everywhere the same corners and weights up to the f64 rounding of the continuous
/// index (the two compute it in a different order): a few f32 ulps of the largest value.
/// Its box covers the source's, and a budget below its size refuses it.
#[test]
fn smoke_dense_copy_is_the_same_field() {
    let smoke = open_vdb("openvdb_smoke1.vdb", None).unwrap();
    let copy = smoke
        .dense_copy(u64::MAX)
        .expect("an axis-aligned grid has a copy");
    let (lo, hi) = smoke.index_bounds();
    let n = (hi - lo + 3).as_uvec3();
    assert_eq!(copy.dims(), n.to_array(), "one zero voxel beyond each side");
    let bytes = u64::from(n.x) * u64::from(n.y) * u64::from(n.z) * 4;
    assert!(smoke.dense_copy(bytes - 1).is_none());
    assert!(smoke.dense_copy(bytes).is_some());
    let (b, c) = (smoke.bounds(), copy.bounds());
    assert!(
        c.min.cmple(b.min).all() && c.max.cmpge(b.max).all(),
        "{b:?} in {c:?}"
    );

    let mut rng = pinbake::rng::CounterRng::new(5, 0, 0);
    let mut centres = 0;
    for _ in 0..200_000 {
        let f = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64());
        let i = (lo - 1).as_dvec3() + f * (hi - lo + 2).as_dvec3();
        let v = IVec3::new(i.x.round() as i32, i.y.round() as i32, i.z.round() as i32);
        // The stored values are the tree's, bit for bit (no mirrored axis here).
        let j = (v - (lo - 1)).as_uvec3();
        assert_eq!(
            copy.voxel(j.x, j.y, j.z).map(f32::to_bits),
            Some(smoke.voxel(v).to_bits()),
            "voxel {v}"
        );
        centres += usize::from(smoke.voxel(v) > 0.0);
        let p = smoke.index_to_world(i);
        let (a, b) = (copy.extinction(p), smoke.extinction(p));
        assert!(
            (a - b).abs() <= 4.0 * f32::EPSILON * copy.max_value(),
            "index {i}: copy {a}, tree {b}"
        );
    }
    assert!(
        centres > 10_000,
        "too few occupied voxels sampled: {centres}"
    );

    // The bake's integration error (256 fixed pins against the 16x supersampled tree) is
    // the same marching the copy as marching the tree.
    use pinbake::pin::{Field, Placement, integration_error_of};
    let (bbox, _) = pinbake::bake::bake_box(&smoke, true).unwrap();
    let placement = Placement::over(&bbox, 0.01);
    let tree = integration_error_of(Field::of(&smoke), &smoke, &placement, 256, 16, 1);
    let dense = integration_error_of(Field::Grid(&copy), &smoke, &placement, 256, 16, 1);
    println!("smoke integration error: tree {tree:?}, dense copy {dense:?}");
    let (a, b) = (dense.mean_abs_transmittance, tree.mean_abs_transmittance);
    assert!((a - b).abs() <= 1e-3 * b, "{dense:?} vs {tree:?}");
}

/// A bake marches the dense copy (`BakeOptions::dense_copy_bytes`) to about the same bytes as
/// the tree: the copy's f32 index steps (`DenseGrid::march_runs`) move each sample by ~1e-7
/// voxel, so a pin's optical depths differ in the last digits: most entries' `t_min` moves
/// by a few f32 ulps, and a mask bit flips only where its draw falls in the sliver between
/// the two ratios. Measured: the printed counts (`--nocapture`), docs/performance.md.
#[test]
fn smoke_bake_through_the_dense_copy_matches_the_tree() {
    use pin_format::Directions;
    let smoke = open_vdb("openvdb_smoke1.vdb", None).unwrap();
    let opts = pinbake::BakeOptions {
        cells: [8, 12, 8],
        directions: Directions::Octahedral { n: 8 },
        threads: Some(2),
        ..pinbake::BakeOptions::default()
    };
    let (dense, _) = pinbake::bake(&smoke, &opts, &|_| {}).unwrap();
    let tree_opts = pinbake::BakeOptions {
        dense_copy_bytes: 0,
        ..opts.clone()
    };
    let (tree, _) = pinbake::bake(&smoke, &tree_opts, &|_| {}).unwrap();
    assert_eq!(dense.cell_index, tree.cell_index);
    assert_eq!(dense.pins.len(), tree.pins.len());
    // t_min = exp(-tau_max): the difference of the logs is the optical depths' difference.
    let (mut entries, mut bits, mut worst) = (0usize, 0u32, 0.0f64);
    for (a, b) in dense.pins.iter().zip(&tree.pins) {
        if a != b {
            entries += 1;
        }
        bits += (a.mask ^ b.mask).count_ones();
        let (ta, tb) = (-f64::from(a.t_min).ln(), -f64::from(b.t_min).ln());
        worst = worst.max((ta - tb).abs() / (1.0 + tb));
    }
    let n = dense.pins.len();
    println!(
        "smoke, {n} pins: {entries} entries differ, {bits} of {} mask bits, largest \
         |tau_max difference| / (1 + tau_max) {worst:e}",
        n * 32
    );
    assert!(worst < 3e-5, "tau_max moved by {worst:e}");
    assert!(bits as usize * 10_000 < n * 32, "{bits} mask bits differ");
}

/// The renderer's dense cache changes where the corners come from, not a bit of any sample:
/// point samples and batched lines through the smoke, inside, on and outside the box, give
/// the same bits with and without it; a budget below its size leaves the tree.
#[test]
fn smoke_dense_cache_samples_the_same_bits() {
    let tree = open_vdb("openvdb_smoke1.vdb", None).unwrap();
    let (lo, hi) = tree.index_bounds();
    let n = (hi - lo + 3).as_uvec3();
    let bytes = u64::from(n.x) * u64::from(n.y) * u64::from(n.z) * 4;
    let refused = open_vdb("openvdb_smoke1.vdb", None)
        .unwrap()
        .with_dense_cache(bytes - 1);
    assert!(!refused.has_dense_cache());
    let cached = open_vdb("openvdb_smoke1.vdb", None)
        .unwrap()
        .with_dense_cache(bytes);
    assert!(cached.has_dense_cache());
    let b = tree.bounds();
    let mut rng = pinbake::rng::CounterRng::new(9, 0, 0);
    let mut nonzero = 0;
    let (mut a, mut c) = ([0.0f32; 64], [0.0f32; 64]);
    for k in 0..100_000 {
        // Points over a box 10% larger than the source's, and every 16th one on a voxel
        // centre or a box face.
        let f = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 1.2 - 0.1;
        let mut p = b.min + f * b.extent();
        if k % 16 == 0 {
            p = tree.index_to_world(tree.world_to_index(p).round());
        } else if k % 16 == 1 {
            p.x = b.max.x;
        }
        let (x, y) = (tree.extinction(p), cached.extinction(p));
        assert_eq!(x.to_bits(), y.to_bits(), "{p}: tree {x}, cached {y}");
        nonzero += usize::from(x > 0.0);
        if k % 100 == 0 {
            let step = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) - 0.5;
            tree.extinction_along(p, step, 64, &mut a);
            cached.extinction_along(p, step, 64, &mut c);
            assert_eq!(a.map(f32::to_bits), c.map(f32::to_bits), "line from {p}");
        }
    }
    assert!(nonzero > 10_000, "too few samples in the smoke: {nonzero}");
}
