//! docs/background.md section 3, table-driven, through every path that can meet each case: the raw
//! reader, the VDB reader, the baker, the CPU sampler, the WGSL sampler (wgpu, lavapipe) and
//! the renderer's trackers. Every case states its expected behaviour as data and every test
//! prints its rows of the cases x paths matrix (`-- --nocapture`; copied into
//! `docs/stability.md`).

use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::common::{Table, assert_distance, assert_transmittance, data, vdb_worker};
use glam::{DVec3, Vec3};
use pin_format::{Directions, OwnedPinGrid, PinEntry, grid_desc};
use pin_tests::{assert_pin_bytes_sane, check_source};
use pin_volume::raw::read_raw;
use pin_volume::{
    Aabb, DenseGrid, DensityScale, DensitySource, HomogeneousBox, RawOptions, RawType, SourceError,
    VdbOptions, VdbSource,
};
use pinbake::{BakeError, BakeOptions, bake};
use pinrender::render::{
    DeltaTracking, MajorantGrid, Pcg32, RatioTracking, RayMarching, TransportEstimator,
};
use pinrt::{PinGrid, QueryResult, Ray, RayQuery, Rng, status};

fn ok_cell(s: impl Into<String>) -> String {
    format!("ok: {}", s.into())
}

// ---------------------------------------------------------------------------------------
// Raw reader
// ---------------------------------------------------------------------------------------

/// What a raw case must give.
enum RawExpect {
    /// Accepted; every voxel equals the given value (bit-exact) when `Some`.
    Ok(Option<f32>),
    /// A `SourceError::Raw` whose message contains the text.
    Err(&'static str),
}

struct RawCase {
    name: &'static str,
    dims: [u32; 3],
    ty: RawType,
    bytes: Vec<u8>,
    /// Changes the options and the density scale (1 unless changed).
    tweak: fn(&mut RawOptions, &mut f64),
    expect: RawExpect,
}

fn f32s(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn raw_cases() -> Vec<RawCase> {
    let none: fn(&mut RawOptions, &mut f64) = |_, _| {};
    let nan0: fn(&mut RawOptions, &mut f64) = |o, _| o.nan_as_zero = true;
    let clamp: fn(&mut RawOptions, &mut f64) = |o, _| o.clamp_negative = true;
    let c = |name, dims, ty, bytes, tweak, expect| RawCase {
        name,
        dims,
        ty,
        bytes,
        tweak,
        expect,
    };
    vec![
        c(
            "NaN",
            [1, 1, 1],
            RawType::F32,
            f32s(&[f32::NAN]),
            none,
            RawExpect::Err("NaN value"),
        ),
        c(
            "NaN, --nan-as-zero",
            [1, 1, 1],
            RawType::F32,
            f32s(&[f32::NAN]),
            nan0,
            RawExpect::Ok(Some(0.0)),
        ),
        c(
            "+inf",
            [1, 1, 1],
            RawType::F32,
            f32s(&[f32::INFINITY]),
            none,
            RawExpect::Err("infinite value"),
        ),
        c(
            "-inf",
            [1, 1, 1],
            RawType::F32,
            f32s(&[f32::NEG_INFINITY]),
            none,
            RawExpect::Err("infinite value"),
        ),
        c(
            "+inf, --nan-as-zero",
            [1, 1, 1],
            RawType::F32,
            f32s(&[f32::INFINITY]),
            nan0,
            RawExpect::Ok(Some(0.0)),
        ),
        c(
            "f16 +inf",
            [1, 1, 1],
            RawType::F16,
            0x7c00u16.to_le_bytes().to_vec(),
            none,
            RawExpect::Err("infinite value"),
        ),
        c(
            "negative",
            [1, 1, 1],
            RawType::F32,
            f32s(&[-1.0]),
            none,
            RawExpect::Err("negative"),
        ),
        c(
            "negative, --clamp-negative",
            [1, 1, 1],
            RawType::F32,
            f32s(&[-1.0]),
            clamp,
            RawExpect::Ok(Some(0.0)),
        ),
        c(
            "-0.0",
            [1, 1, 1],
            RawType::F32,
            f32s(&[-0.0]),
            none,
            RawExpect::Ok(None),
        ),
        c(
            "subnormal f32 1e-40",
            [1, 1, 1],
            RawType::F32,
            f32s(&[1e-40]),
            none,
            RawExpect::Ok(Some(1e-40)),
        ),
        c(
            "subnormal f64 1e-310 (rounds to 0 in f32)",
            [1, 1, 1],
            RawType::F64,
            1e-310f64.to_le_bytes().to_vec(),
            none,
            RawExpect::Ok(Some(0.0)),
        ),
        c(
            "f16 subnormal 2^-24",
            [1, 1, 1],
            RawType::F16,
            1u16.to_le_bytes().to_vec(),
            none,
            RawExpect::Ok(Some(5.960_464_5e-8)),
        ),
        c(
            "empty file, dims 1x1x1",
            [1, 1, 1],
            RawType::F32,
            vec![],
            none,
            RawExpect::Err("size mismatch"),
        ),
        c(
            "zero dim 0x4x4",
            [0, 4, 4],
            RawType::U8,
            vec![],
            none,
            RawExpect::Err("contain a zero"),
        ),
        c(
            "one voxel",
            [1, 1, 1],
            RawType::U8,
            vec![7],
            none,
            RawExpect::Ok(Some(7.0)),
        ),
        c(
            "non-power-of-two 3x5x7",
            [3, 5, 7],
            RawType::U16,
            vec![1; 3 * 5 * 7 * 2],
            none,
            RawExpect::Ok(Some(257.0)),
        ),
        c(
            "anisotropic 1x1x4096",
            [1, 1, 4096],
            RawType::U8,
            vec![3; 4096],
            none,
            RawExpect::Ok(Some(3.0)),
        ),
        c(
            "anisotropic 300x2x1",
            [300, 2, 1],
            RawType::F32,
            f32s(&[0.5; 600]),
            none,
            RawExpect::Ok(Some(0.5)),
        ),
        c(
            "header 65536x65536x1 u8 (2^32 voxels), 16-byte file",
            [65536, 65536, 1],
            RawType::U8,
            vec![0; 16],
            none,
            RawExpect::Err("size mismatch"),
        ),
        c(
            "header 2^20 x 2^20 x 2^20 f64, 16-byte file",
            [1 << 20, 1 << 20, 1 << 20],
            RawType::F64,
            vec![0; 16],
            none,
            RawExpect::Err("size mismatch"),
        ),
        c(
            "header u32::MAX^3 (overflows u64)",
            [u32::MAX; 3],
            RawType::F32,
            vec![0; 16],
            none,
            RawExpect::Err("overflow"),
        ),
        c(
            "value 1e9 x density scale 1e30 (f32 overflow)",
            [1, 1, 1],
            RawType::F32,
            f32s(&[1e9]),
            |_, s| *s = 1e30,
            RawExpect::Err("overflows f32"),
        ),
        c(
            "density scale 1e30",
            [1, 1, 1],
            RawType::U8,
            vec![255],
            |_, s| *s = 1e30,
            RawExpect::Ok(Some(2.55e32)),
        ),
        c(
            "density scale 0",
            [1, 1, 1],
            RawType::F32,
            f32s(&[f32::MAX]),
            |_, s| *s = 0.0,
            RawExpect::Ok(Some(0.0)),
        ),
        c(
            "density scale NaN",
            [1, 1, 1],
            RawType::U8,
            vec![1],
            |_, s| *s = f64::NAN,
            RawExpect::Err("density scale"),
        ),
        c(
            "density scale -1",
            [1, 1, 1],
            RawType::U8,
            vec![1],
            |_, s| *s = -1.0,
            RawExpect::Err("density scale"),
        ),
        c(
            "spacing 0",
            [1, 1, 1],
            RawType::U8,
            vec![1],
            |o, _| o.spacing = [0.0, 1.0, 1.0],
            RawExpect::Err("spacing"),
        ),
        c(
            "origin inf",
            [1, 1, 1],
            RawType::U8,
            vec![1],
            |o, _| o.origin = [f64::INFINITY, 0.0, 0.0],
            RawExpect::Err("origin"),
        ),
    ]
}

#[test]
fn raw_reader_cases() {
    let dir = tempfile::tempdir().unwrap();
    let mut table = Table::new("raw reader", &["case", "expected", "result", "ms"]);
    for (i, case) in raw_cases().into_iter().enumerate() {
        let path = dir.path().join(format!("case{i}.raw"));
        std::fs::write(&path, &case.bytes).unwrap();
        let mut opt = RawOptions {
            dims: Some(case.dims),
            voxel_type: Some(case.ty),
            ..RawOptions::default()
        };
        let mut scale = 1.0;
        (case.tweak)(&mut opt, &mut scale);
        let t = Instant::now();
        let res = DensityScale::new(scale).and_then(|s| read_raw(&path, &opt, s));
        let ms = t.elapsed().as_secs_f64() * 1e3;
        assert!(ms < 5_000.0, "{}: {ms} ms", case.name);
        let (expected, result) = match (&case.expect, res) {
            (RawExpect::Ok(v), Ok(grid)) => {
                assert!(
                    grid.data().iter().all(|x| x.is_finite() && *x >= 0.0),
                    "{}: non-finite or negative value kept",
                    case.name
                );
                if let Some(v) = v {
                    for x in grid.data() {
                        assert_eq!(x.to_bits(), v.to_bits(), "{}: {x} vs {v}", case.name);
                    }
                }
                check_source(&grid);
                // Every accepted grid bakes into a pin file that verifies and holds no NaN.
                assert!(pin_tests::bake_and_verify(&grid));
                let shown = v.map_or("finite >= 0".into(), |v| format!("= {v:e}"));
                (
                    format!("Ok, values {shown}"),
                    ok_cell("accepted, baked, verified"),
                )
            }
            (RawExpect::Err(needle), Err(e)) => {
                let msg = e.to_string();
                // A bad scale is refused before any file is read: the one rule of every
                // surface (`DensityScale::new`), not a fault of the file.
                let scale_case = case.name.starts_with("density scale");
                assert!(
                    matches!(e, SourceError::Raw { .. }) && !scale_case
                        || matches!(e, SourceError::InvalidOption(_)) && scale_case,
                    "{}: wrong error kind {e:?}",
                    case.name
                );
                assert!(
                    msg.contains(needle),
                    "{}: {msg:?} lacks {needle:?}",
                    case.name
                );
                assert!(!msg.contains('\n'));
                (
                    format!("Err(Raw) \"{needle}\""),
                    ok_cell(format!("`{msg}`").replace(dir.path().to_str().unwrap(), "<tmp>")),
                )
            }
            (RawExpect::Ok(_), Err(e)) => panic!("{}: expected Ok, got {e}", case.name),
            (RawExpect::Err(n), Ok(_)) => panic!("{}: expected an error with {n:?}", case.name),
        };
        table.row(vec![case.name.into(), expected, result, format!("{ms:.1}")]);
    }
    table.print();
}

// ---------------------------------------------------------------------------------------
// VDB reader
// ---------------------------------------------------------------------------------------

#[test]
fn vdb_reader_damaged_files() {
    let dir = data("oiio_damaged");
    let mut names: Vec<_> = std::fs::read_dir(&dir)
        .expect("data/oiio_damaged must exist")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "vdb"))
        .collect();
    names.sort();
    assert_eq!(names.len(), 7, "the seven damaged files");
    let mut table = Table::new(
        "VDB reader (isolated worker)",
        &["file", "expected", "result", "ms"],
    );
    let opt = VdbOptions::with_worker(vdb_worker());
    for path in &names {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let t = Instant::now();
        let res = VdbSource::open(path, &opt, DensityScale::ONE);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        assert!(ms < 10_000.0, "{name}: {ms} ms");
        match res {
            Err(e @ SourceError::Vdb { .. }) => {
                let msg = e.to_string();
                assert!(!msg.contains('\n') && msg.contains(&name), "{msg:?}");
                let short = msg.replace(&format!("{}/", dir.display()), "");
                table.row(vec![
                    name,
                    "Err(Vdb), one line".into(),
                    ok_cell(format!("`{short}`")),
                    format!("{ms:.0}"),
                ]);
            }
            other => panic!("{name}: expected a Vdb error, got {other:?}"),
        }
    }
    // A valid file through the same path for contrast: finite, non-negative everywhere.
    let good = data("gaffer_sphere_density.vdb");
    let src = VdbSource::open(&good, &opt, DensityScale::ONE).expect("a valid VDB opens");
    check_source(&src);
    assert!(pin_tests::bake_and_verify(&src));
    table.row(vec![
        "gaffer_sphere_density.vdb (valid)".into(),
        "Ok".into(),
        ok_cell("accepted, baked, verified"),
        "-".into(),
    ]);
    table.print();
}

// ---------------------------------------------------------------------------------------
// Baker
// ---------------------------------------------------------------------------------------

/// What every pin of a bake must hold.
#[derive(Clone, Copy, Debug)]
enum PinExpect {
    /// Every pin is `PinEntry::EMPTY` (t_min = 1, mask 0).
    AllEmpty,
    /// Every pin has t_min = 0 exactly and all 32 bits set.
    AllOpaque,
    /// Every pin has all 32 bits set (equal intervals) and t_min in (lo, hi).
    Homogeneous(f32, f32),
}

fn unit_box() -> Aabb {
    Aabb::new(DVec3::ZERO, DVec3::ONE)
}

#[test]
fn baker_cases() {
    let centred = |cells: [u32; 3]| BakeOptions {
        cells,
        directions: Directions::Octahedral { n: 3 },
        step: 0.05,
        jitter_pins: false,
        threads: Some(2),
        majorant: Some([2, 2, 2]),
        ..BakeOptions::default()
    };
    let grid = |dims: [u32; 3], v: f32| -> Box<dyn DensitySource> {
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        Box::new(DenseGrid::new(dims, vec![v; n], DVec3::ONE, DVec3::ZERO, "test").unwrap())
    };
    let scaled_raw = |scale: f64| -> Box<dyn DensitySource> {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("v_4x4x4_u8.raw");
        std::fs::write(&p, (1..=64u8).collect::<Vec<_>>()).unwrap();
        let scale = DensityScale::new(scale).unwrap();
        Box::new(read_raw(&p, &RawOptions::default(), scale).unwrap())
    };
    let hbox = |d: f32| -> Box<dyn DensitySource> {
        Box::new(HomogeneousBox::new(unit_box(), d).unwrap())
    };
    // Unit box, pins through cell centres: chords are between ~0.3 and sqrt(3).
    let cases: Vec<(&str, Box<dyn DensitySource>, BakeOptions, PinExpect)> = vec![
        (
            "tau = 0 everywhere (box density 0)",
            hbox(0.0),
            centred([3, 3, 3]),
            PinExpect::AllEmpty,
        ),
        (
            "tau = 0 everywhere (dense grid of zeros)",
            grid([4, 4, 4], 0.0),
            centred([3, 3, 3]),
            PinExpect::AllEmpty,
        ),
        (
            "tau tiny 1e-30 (t_min rounds to 1 in f32)",
            hbox(1e-30 * 32.0),
            centred([3, 3, 3]),
            PinExpect::AllEmpty,
        ),
        (
            "tau tiny 1e-6 per interval",
            hbox(32e-6),
            centred([3, 3, 3]),
            PinExpect::Homogeneous(0.99999, 1.0),
        ),
        (
            "tau huge 1e6 (t underflows to 0)",
            hbox(1e6 * 32.0 / 0.3),
            centred([3, 3, 3]),
            PinExpect::AllOpaque,
        ),
        (
            "density scale 0",
            scaled_raw(0.0),
            centred([3, 3, 3]),
            PinExpect::AllEmpty,
        ),
        (
            "density scale 1e30",
            scaled_raw(1e30),
            centred([3, 3, 3]),
            PinExpect::AllOpaque,
        ),
        (
            "one-voxel source grid (density 2)",
            grid([1, 1, 1], 2.0),
            centred([3, 3, 3]),
            PinExpect::Homogeneous((-2.0f32 * 1.8 / 32.0).exp(), 1.0),
        ),
        (
            "one-cell pin grid",
            hbox(1.0),
            centred([1, 1, 1]),
            PinExpect::Homogeneous((-1.8f32 / 32.0).exp(), 1.0),
        ),
        (
            "anisotropic source 1x1x4096",
            grid([1, 1, 4096], 1e-3),
            centred([1, 1, 5]),
            PinExpect::Homogeneous(0.0, 1.0),
        ),
        (
            "anisotropic source 300x2x1",
            grid([300, 2, 1], 0.01),
            centred([7, 1, 1]),
            PinExpect::Homogeneous(0.0, 1.0),
        ),
    ];
    let mut table = Table::new("baker", &["case", "expected pins", "result"]);
    for (name, src, opts, expect) in cases {
        let (owned, stats) =
            bake(src.as_ref(), &opts, &|_| {}).unwrap_or_else(|e| panic!("{name}: {e}"));
        let bytes = owned.to_bytes().unwrap();
        assert_pin_bytes_sane(&bytes);
        let pins = &owned.pins;
        let covered = (opts.cells[0] * opts.cells[1] * opts.cells[2]) as usize
            * opts.directions.count() as usize;
        let check = |f: &dyn Fn(&PinEntry) -> bool| pins.iter().all(f);
        let ok = match expect {
            PinExpect::AllEmpty => {
                pins.iter().all(|p| *p == PinEntry::EMPTY) && stats.t_min_min == 1.0
            }
            PinExpect::AllOpaque => {
                pins.len() == covered && check(&|p| p.t_min == 0.0 && p.mask == u32::MAX)
            }
            PinExpect::Homogeneous(lo, hi) => {
                pins.len() == covered
                    && check(&|p| p.mask == u32::MAX && p.t_min > lo && p.t_min < hi)
            }
        };
        assert!(
            ok,
            "{name}: expected {expect:?}, got t_min in [{}, {}], {} pins, first {:?}",
            stats.t_min_min,
            stats.t_min_max,
            pins.len(),
            pins.first()
        );
        table.row(vec![
            name.into(),
            format!("{expect:?}"),
            ok_cell(format!(
                "{} pins stored, t_min in [{:.3e}, {:.3e}], verify() ok",
                pins.len(),
                stats.t_min_min,
                stats.t_min_max
            )),
        ]);
    }
    // Invalid options are errors, not NaN pins.
    for (name, step) in [("step 0", 0.0), ("step NaN", f64::NAN), ("step -1", -1.0)] {
        let opts = BakeOptions {
            step,
            ..centred([2, 2, 2])
        };
        match bake(hbox(1.0).as_ref(), &opts, &|_| {}) {
            Err(BakeError::Options(m)) => table.row(vec![
                name.into(),
                "Err(Options)".into(),
                ok_cell(format!("`{m}`")),
            ]),
            other => panic!("{name}: {other:?}"),
        }
    }
    table.print();
}

// ---------------------------------------------------------------------------------------
// Ray cases: CPU sampler, WGSL sampler, trackers
// ---------------------------------------------------------------------------------------

/// The expected result of a ray case on a homogeneous grid (every interval the same).
#[derive(Clone, Copy, Debug, PartialEq)]
enum RayExpect {
    /// Status OK; the segment covers exactly `intervals` whole intervals of the chord (so the
    /// pin transmittance is `t_min ^ intervals`, deterministic) and has world length `len`.
    Full {
        intervals: u32,
        len: f32,
        t0: f32,
        t1: f32,
    },
    /// Status OK with partial intervals: pin transmittance random in
    /// `[t_min ^ max_intervals, 1]`, segment `[t0, t1]`.
    Partial {
        max_intervals: u32,
        len: f32,
        t0: f32,
        t1: f32,
    },
    /// No chord or empty segment: T = 1, no collision, status MISS.
    Miss,
    /// Invalid input: T = 1, no collision, status INVALID.
    Invalid,
}

struct RayCase {
    name: &'static str,
    o: [f32; 3],
    d: [f32; 3],
    t_max: f32,
    expect: RayExpect,
}

const S3: f32 = 1.732_050_8;

fn ray_cases() -> Vec<RayCase> {
    use RayExpect::*;
    let full = |t0: f32, t1: f32, len: f32| Full {
        intervals: 32,
        len,
        t0,
        t1,
    };
    let r = |name, o, d, t_max, expect| RayCase {
        name,
        o,
        d,
        t_max,
        expect,
    };
    let inf = f32::INFINITY;
    let h = std::f32::consts::FRAC_1_SQRT_2;
    vec![
        r(
            "axis +x through the centre",
            [-1.0, 0.5, 0.5],
            [1.0, 0.0, 0.0],
            inf,
            full(1.0, 2.0, 1.0),
        ),
        r(
            "axis -x",
            [2.0, 0.5, 0.5],
            [-1.0, 0.0, 0.0],
            inf,
            full(1.0, 2.0, 1.0),
        ),
        r(
            "axis +y",
            [0.5, -1.0, 0.5],
            [0.0, 1.0, 0.0],
            inf,
            full(1.0, 2.0, 1.0),
        ),
        r(
            "axis +z (polar pole)",
            [0.5, 0.5, -1.0],
            [0.0, 0.0, 1.0],
            inf,
            full(1.0, 2.0, 1.0),
        ),
        r(
            "axis -z (pole, reversed mask)",
            [0.5, 0.5, 2.0],
            [0.0, 0.0, -1.0],
            inf,
            full(1.0, 2.0, 1.0),
        ),
        r(
            "d.z = +0 (z = 0 plane)",
            [-1.0, 0.5, 0.5],
            [1.0, 0.0, 0.0],
            inf,
            full(1.0, 2.0, 1.0),
        ),
        r(
            "d.z = -0 (z = 0 plane)",
            [-1.0, 0.5, 0.5],
            [1.0, 0.0, -0.0],
            inf,
            full(1.0, 2.0, 1.0),
        ),
        r(
            "d.z = +1e-30",
            [-1.0, 0.5, 0.5],
            [1.0, 0.0, 1e-30],
            inf,
            full(1.0, 2.0, 1.0),
        ),
        r(
            "d.z = -1e-30",
            [-1.0, 0.5, 0.5],
            [1.0, 0.0, -1e-30],
            inf,
            full(1.0, 2.0, 1.0),
        ),
        r(
            "grazing face y = 0",
            [-1.0, 0.0, 0.5],
            [1.0, 0.0, 0.0],
            inf,
            full(1.0, 2.0, 1.0),
        ),
        r(
            "grazing face y = 1",
            [-1.0, 1.0, 0.5],
            [1.0, 0.0, 0.0],
            inf,
            full(1.0, 2.0, 1.0),
        ),
        r(
            "grazing edge y = z = 0",
            [-1.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            inf,
            full(1.0, 2.0, 1.0),
        ),
        r(
            "just outside face y = -1e-7",
            [-1.0, -1e-7, 0.5],
            [1.0, 0.0, 0.0],
            inf,
            Miss,
        ),
        r(
            "touching a corner only",
            [0.0, 2.0, 2.0],
            [1.0, -1.0, -1.0],
            inf,
            Miss,
        ),
        r(
            "main diagonal corner to corner",
            [-1.0, -1.0, -1.0],
            [1.0, 1.0, 1.0],
            inf,
            full(1.0, 2.0, S3),
        ),
        r(
            "start inside (centre), +x",
            [0.5, 0.5, 0.5],
            [1.0, 0.0, 0.0],
            inf,
            Full {
                intervals: 16,
                len: 0.5,
                t0: 0.0,
                t1: 0.5,
            },
        ),
        r(
            "start inside, t_max = 0.3 (partial)",
            [0.5, 0.5, 0.5],
            [1.0, 0.0, 0.0],
            0.3,
            Partial {
                max_intervals: 10,
                len: 0.3,
                t0: 0.0,
                t1: 0.3,
            },
        ),
        r(
            "start on face x = 0, inward",
            [0.0, 0.5, 0.5],
            [1.0, 0.0, 0.0],
            inf,
            full(0.0, 1.0, 1.0),
        ),
        r(
            "start on face x = 0, outward",
            [0.0, 0.5, 0.5],
            [-1.0, 0.0, 0.0],
            inf,
            Miss,
        ),
        r(
            "start on edge, along the face",
            [0.0, 0.0, 0.5],
            [1.0, 0.0, 0.0],
            inf,
            full(0.0, 1.0, 1.0),
        ),
        r(
            "start on corner, diagonal in",
            [0.0, 0.0, 0.0],
            [1.0, 1.0, 1.0],
            inf,
            full(0.0, 1.0, S3),
        ),
        r(
            "start on corner, diagonal out",
            [0.0, 0.0, 0.0],
            [-1.0, -1.0, -1.0],
            inf,
            Miss,
        ),
        r(
            "octahedral seam x = 0 (d = (0, 1, 1)/sqrt2)",
            [0.5, -0.5, -0.5],
            [0.0, h, h],
            inf,
            full(0.5 / h, 1.5 / h, std::f32::consts::SQRT_2),
        ),
        r(
            "octahedral seam y = 0 (d = (-1, 0, 1)/sqrt2)",
            [1.5, 0.5, -0.5],
            [-h, 0.0, h],
            inf,
            full(0.5 / h, 1.5 / h, std::f32::consts::SQRT_2),
        ),
        r(
            "octahedral rim z = 0, d = (1, 1, 0)",
            [-0.5, -0.5, 0.5],
            [1.0, 1.0, 0.0],
            inf,
            full(0.5, 1.5, std::f32::consts::SQRT_2),
        ),
        r(
            "t_max = 0 (zero-length segment)",
            [-1.0, 0.5, 0.5],
            [1.0, 0.0, 0.0],
            0.0,
            Miss,
        ),
        r("t_max = -0.0", [0.5, 0.5, 0.5], [1.0, 0.0, 0.0], -0.0, Miss),
        r("t_max = -1", [-1.0, 0.5, 0.5], [1.0, 0.0, 0.0], -1.0, Miss),
        r(
            "t_max = -inf",
            [-1.0, 0.5, 0.5],
            [1.0, 0.0, 0.0],
            -inf,
            Miss,
        ),
        r(
            "t_max = +inf (infinite segment)",
            [-1.0, 0.5, 0.5],
            [1.0, 0.0, 0.0],
            inf,
            full(1.0, 2.0, 1.0),
        ),
        r(
            "t_max = 1e30",
            [-1.0, 0.5, 0.5],
            [1.0, 0.0, 0.0],
            1e30,
            full(1.0, 2.0, 1.0),
        ),
        r(
            "t_max = f32::MAX",
            [-1.0, 0.5, 0.5],
            [1.0, 0.0, 0.0],
            f32::MAX,
            full(1.0, 2.0, 1.0),
        ),
        r(
            "t_max = 1e-45 (subnormal), from inside",
            [0.5, 0.5, 0.5],
            [1.0, 0.0, 0.0],
            1e-45,
            Partial {
                max_intervals: 1,
                len: 1e-45,
                t0: 0.0,
                t1: 1e-45,
            },
        ),
        r(
            "chord behind the origin",
            [2.0, 0.5, 0.5],
            [1.0, 0.0, 0.0],
            inf,
            Miss,
        ),
        r(
            "miss beside the box",
            [-1.0, 2.0, 0.5],
            [1.0, 0.0, 0.0],
            inf,
            Miss,
        ),
        r(
            "direction (0, 0, 0)",
            [0.5, 0.5, 0.5],
            [0.0, 0.0, 0.0],
            inf,
            Invalid,
        ),
        r(
            "direction NaN",
            [0.5, 0.5, 0.5],
            [f32::NAN, 0.0, 1.0],
            inf,
            Invalid,
        ),
        r(
            "direction +inf",
            [0.5, 0.5, 0.5],
            [f32::INFINITY, 0.0, 0.0],
            inf,
            Invalid,
        ),
        r(
            "origin NaN",
            [f32::NAN, 0.5, 0.5],
            [1.0, 0.0, 0.0],
            inf,
            Invalid,
        ),
        r(
            "origin -inf",
            [f32::NEG_INFINITY, 0.5, 0.5],
            [1.0, 0.0, 0.0],
            inf,
            Invalid,
        ),
        r(
            "t_max NaN",
            [-1.0, 0.5, 0.5],
            [1.0, 0.0, 0.0],
            f32::NAN,
            Invalid,
        ),
        r(
            "huge direction scale 1e30",
            [-1.0, 0.5, 0.5],
            [1e30, 0.0, 0.0],
            inf,
            full(1e-30, 2e-30, 1.0),
        ),
        r(
            "tiny direction scale 1e-30",
            [-1.0, 0.5, 0.5],
            [1e-30, 0.0, 0.0],
            inf,
            full(1e30, 2e30, 1.0),
        ),
    ]
}

/// A homogeneous pin grid: every entry `(mask, t_min)`, 2x2x2 cells, given directions.
fn homogeneous_grid(dirs: Directions, entry: PinEntry) -> PinGrid {
    let cells = 8usize;
    let owned = OwnedPinGrid {
        desc: grid_desc([2, 2, 2], dirs, 1, cells as u64),
        tile: None,
        cell_index: None,
        pins: vec![entry; cells * dirs.count() as usize],
        majorant: None,
        density: None,
        sparse_density: None,
        control: None,
        metadata: None,
    };
    PinGrid::from_bytes(owned.to_bytes().unwrap()).unwrap()
}

/// The pin grids every ray case runs on: `(label, directions, t_min)`.
fn pin_grids() -> Vec<(String, PinGrid, f32)> {
    let mut v = Vec::new();
    for dirs in [Directions::THESIS_DEFAULT, Directions::Octahedral { n: 4 }] {
        for t in [0.9f32, 0.0, 1e-40, 1.0] {
            let entry = if t >= 1.0 {
                PinEntry::EMPTY
            } else {
                PinEntry {
                    mask: u32::MAX,
                    t_min: t,
                }
            };
            let label = match dirs {
                Directions::Polar { .. } => format!("polar 16x4, t_min {t:e}"),
                Directions::Octahedral { n } => format!("oct {n}x{n}, t_min {t:e}"),
            };
            v.push((label, homogeneous_grid(dirs, entry), t));
        }
    }
    v
}

fn powi_f32(t: f32, n: u32) -> f32 {
    pinrt::mask::pow_int(t, n)
}

/// Checks one pin query result against a case. Returns a short description.
fn check_pin_result(case: &RayCase, t_min: f32, r: &QueryResult, path: &str) -> String {
    let what = format!("{path}: {} (t_min {t_min:e})", case.name);
    assert_transmittance(r.transmittance, &what);
    assert_distance(r.distance, &what);
    assert_eq!(
        r.hit != 0,
        r.distance.is_finite(),
        "{what}: hit flag vs distance {r:?}"
    );
    match case.expect {
        RayExpect::Miss | RayExpect::Invalid => {
            let st = if case.expect == RayExpect::Miss {
                status::MISS
            } else {
                status::INVALID
            };
            assert_eq!(r.status, st, "{what}: {r:?}");
            assert_eq!((r.transmittance, r.hit), (1.0, 0), "{what}: {r:?}");
            format!(
                "T=1, {}",
                if st == status::MISS {
                    "MISS"
                } else {
                    "INVALID"
                }
            )
        }
        RayExpect::Full {
            intervals, t0, t1, ..
        }
        | RayExpect::Partial {
            max_intervals: intervals,
            t0,
            t1,
            ..
        } => {
            assert_eq!(r.status, status::OK, "{what}: {r:?}");
            let full = matches!(case.expect, RayExpect::Full { .. });
            if t_min >= 1.0 {
                assert_eq!((r.transmittance, r.hit), (1.0, 0), "{what}: {r:?}");
            } else if full {
                assert_eq!(r.popcount, intervals, "{what}: {r:?}");
                let want = powi_f32(t_min, intervals);
                assert_eq!(
                    r.transmittance.to_bits(),
                    want.to_bits(),
                    "{what}: {r:?} vs {want}"
                );
            } else {
                assert!(r.popcount <= intervals, "{what}: {r:?}");
            }
            if r.hit != 0 {
                let tol = 1e-6 * t1.abs().max(t0.abs());
                assert!(
                    r.distance >= t0 - tol && r.distance <= t1 + tol,
                    "{what}: distance {} outside [{t0}, {t1}]",
                    r.distance
                );
            } else if full && t_min < 2f32.powi(-33) && t_min < 1.0 {
                panic!("{what}: t_min {t_min} and full intervals must collide: {r:?}");
            }
            if full {
                format!("T=t^{intervals}")
            } else {
                "T in range".into()
            }
        }
    }
}

fn queries(cases: &[RayCase]) -> Vec<RayQuery> {
    cases
        .iter()
        .map(|c| RayQuery::new(c.o, c.d, c.t_max))
        .collect()
}

const REPEATS: u32 = 64;

#[test]
fn cpu_sampler_cases() {
    let cases = ray_cases();
    let grids = pin_grids();
    let mut table = Table::new(
        "CPU sampler (`Sampler::query`, `query_batch`)",
        &["case", "expected", "result over 8 grids x 64 seeds"],
    );
    let mut cells: Vec<String> = vec![String::new(); cases.len()];
    for (label, grid, t_min) in &grids {
        let s = grid.sampler().unwrap();
        for (ci, case) in cases.iter().enumerate() {
            let ray = Ray::new(case.o, case.d);
            for seed in 0..REPEATS {
                let mut rng = Rng::for_query(seed, ci as u32);
                let r = s.query(&ray, case.t_max, &mut rng);
                let c = check_pin_result(case, *t_min, &r, label);
                if seed == 0 && cells[ci].is_empty() {
                    cells[ci] = c;
                }
                // The single-purpose calls agree with `query` for the same generator.
                let mut r1 = Rng::for_query(seed, ci as u32);
                assert_eq!(
                    s.transmittance(&ray, case.t_max, &mut r1).to_bits(),
                    r.transmittance.to_bits()
                );
            }
        }
        // Batches give the same bits as single queries.
        let qs = queries(&cases);
        let mut out = vec![QueryResult::default_miss(); qs.len()];
        s.query_batch(&qs, 99, 0, &mut out);
        for (i, (q, b)) in qs.iter().zip(&out).enumerate() {
            let mut rng = Rng::for_query(99, i as u32);
            let single = s.query(&q.ray(), q.t_max, &mut rng);
            assert_eq!(
                bytemuck_bytes(&single),
                bytemuck_bytes(b),
                "{label}: {}",
                cases[i].name
            );
        }
    }
    // d.z = +0 and -0 give identical results.
    let (_, g, _) = &grids[0];
    let s = g.sampler().unwrap();
    for seed in 0..256 {
        let a = s.query(
            &Ray::new([0.2, 0.3, 0.4], [1.0, 0.5, 0.0]),
            3.0,
            &mut Rng::for_query(seed, 1),
        );
        let b = s.query(
            &Ray::new([0.2, 0.3, 0.4], [1.0, 0.5, -0.0]),
            3.0,
            &mut Rng::for_query(seed, 1),
        );
        assert_eq!(bytemuck_bytes(&a), bytemuck_bytes(&b));
    }
    for (c, cell) in cases.iter().zip(cells) {
        table.row(vec![c.name.into(), expect_label(&c.expect), ok_cell(cell)]);
    }
    table.print();
}

trait DefaultMiss {
    fn default_miss() -> Self;
}
impl DefaultMiss for QueryResult {
    fn default_miss() -> Self {
        bytemuck::Zeroable::zeroed()
    }
}

fn bytemuck_bytes(r: &QueryResult) -> [u8; 32] {
    let mut b = [0u8; 32];
    b.copy_from_slice(bytemuck::bytes_of(r));
    b
}

fn expect_label(e: &RayExpect) -> String {
    match e {
        RayExpect::Full { intervals, len, .. } => format!(
            "OK, {intervals} whole intervals, T_pin = t_min^{intervals}, T_track = exp(-sigma*{len})"
        ),
        RayExpect::Partial {
            max_intervals, len, ..
        } => format!("OK, partial, popcount <= {max_intervals}, T_track = exp(-sigma*{len:e})"),
        RayExpect::Miss => "MISS: T = 1, no collision".into(),
        RayExpect::Invalid => "INVALID: T = 1, no collision".into(),
    }
}

#[test]
fn gpu_sampler_cases() {
    let ctx = pinrt::gpu::GpuContext::new()
        .unwrap_or_else(|e| panic!("no GPU adapter (install mesa-vulkan-drivers): {e}"));
    eprintln!("adapter: {}", ctx.describe());
    let cases = ray_cases();
    let qs = queries(&cases);
    let mut table = Table::new(
        &format!("WGSL sampler ({})", ctx.describe()),
        &[
            "grid",
            "queries",
            "integer mismatches",
            "float mismatches",
            "result",
        ],
    );
    for (label, grid, t_min) in pin_grids() {
        let gpu = pinrt::gpu::GpuPinGrid::upload(&ctx, &grid).unwrap();
        let s = grid.sampler().unwrap();
        // Every case REPEATS times with different query indices.
        let rays: Vec<RayQuery> = (0..REPEATS).flat_map(|_| qs.iter().copied()).collect();
        let g = gpu.run_queries(&rays, 5, 0).unwrap();
        let mut c = vec![QueryResult::default_miss(); rays.len()];
        s.query_batch(&rays, 5, 0, &mut c);
        let a = pinrt::gpu::Agreement::compare(&c, &g);
        for (i, r) in g.iter().enumerate() {
            check_pin_result(&cases[i % cases.len()], t_min, r, &format!("gpu {label}"));
        }
        let int_mis = c
            .iter()
            .zip(&g)
            .filter(|(x, y)| {
                (
                    x.hit,
                    x.entry,
                    x.popcount,
                    x.interval,
                    x.status,
                    x.rng_state,
                ) != (
                    y.hit,
                    y.entry,
                    y.popcount,
                    y.interval,
                    y.status,
                    y.rng_state,
                )
            })
            .count();
        let float_mis = c
            .iter()
            .zip(&g)
            .filter(|(x, y)| {
                x.transmittance.to_bits() != y.transmittance.to_bits()
                    || x.distance.to_bits() != y.distance.to_bits()
            })
            .count();
        assert_eq!((int_mis, float_mis), (0, 0), "{label}: {a:?}");
        table.row(vec![
            label,
            rays.len().to_string(),
            int_mis.to_string(),
            float_mis.to_string(),
            ok_cell("every case as expected, bit-identical to CPU"),
        ]);
    }
    table.print();
}

/// The trackers on the same rays: a homogeneous unit box of extinction `sigma`.
#[test]
fn tracker_cases() {
    let sigma = 1.5f32;
    let field = Arc::new(
        pinrender::render::HomogeneousBox::new(
            pinrender::render::Aabb::from_arrays([0.0; 3], [1.0; 3]),
            sigma,
        )
        .unwrap(),
    );
    let empty = Arc::new(
        pinrender::render::HomogeneousBox::new(
            pinrender::render::Aabb::from_arrays([0.0; 3], [1.0; 3]),
            0.0,
        )
        .unwrap(),
    );
    let maj = Arc::new(MajorantGrid::uniform([0.0; 3], [1.0; 3], sigma).unwrap());
    let maj_loose = Arc::new(MajorantGrid::uniform([0.0; 3], [1.0; 3], 4.0 * sigma).unwrap());
    let maj0 = Arc::new(MajorantGrid::uniform([0.0; 3], [1.0; 3], 0.0).unwrap());
    type Est = Box<dyn TransportEstimator>;
    let estimators: Vec<(&str, Est, f32, bool)> = vec![
        (
            "ray marching 0.01",
            Box::new(RayMarching::new(field.clone(), 0.01).unwrap()),
            sigma,
            false,
        ),
        (
            "delta tracking",
            Box::new(DeltaTracking::new(field.clone(), maj.clone())),
            sigma,
            true,
        ),
        (
            "ratio tracking (majorant 4 sigma)",
            Box::new(RatioTracking::new(field.clone(), maj_loose.clone())),
            sigma,
            true,
        ),
        (
            "delta tracking, majorant 0, empty medium",
            Box::new(DeltaTracking::new(empty.clone(), maj0.clone())),
            0.0,
            true,
        ),
        (
            "ratio tracking, majorant 0, empty medium",
            Box::new(RatioTracking::new(empty.clone(), maj0.clone())),
            0.0,
            true,
        ),
    ];
    let cases = ray_cases();
    let mut table = Table::new(
        "renderer trackers (homogeneous unit box, sigma = 1.5)",
        &[
            "case",
            "ray marching",
            "delta",
            "ratio",
            "majorant 0 (delta, ratio)",
        ],
    );
    let mut rows: Vec<Vec<String>> = cases.iter().map(|c| vec![c.name.to_string()]).collect();
    let n = 4000u64;
    for (label, est, s, stochastic) in &estimators {
        for (ci, case) in cases.iter().enumerate() {
            let (o, d) = (Vec3::from(case.o), Vec3::from(case.d));
            let what = format!("{label}: {}", case.name);
            let reps = if *stochastic { n } else { 1 };
            let (mut sum_t, mut hits) = (0.0f64, 0u64);
            let t = Instant::now();
            for k in 0..reps {
                let mut rng = Pcg32::new(k, ci as u64);
                let tr = est.transmittance(o, d, case.t_max, &mut rng);
                assert_transmittance(tr, &what);
                sum_t += f64::from(tr);
                let dist = est.sample_distance(o, d, case.t_max, &mut rng);
                if let Some(x) = dist {
                    assert_distance(x, &what);
                    assert!(x.is_finite() && x <= case.t_max, "{what}: distance {x}");
                    hits += 1;
                }
            }
            assert!(t.elapsed() < Duration::from_secs(20), "{what}: too slow");
            let mean = sum_t / reps as f64;
            let cell = match case.expect {
                RayExpect::Miss | RayExpect::Invalid => {
                    assert_eq!((mean, hits), (1.0, 0), "{what}");
                    "T=1, none".to_string()
                }
                RayExpect::Full { len, t0, t1, .. } | RayExpect::Partial { len, t0, t1, .. } => {
                    // Lengths in units of |d|: the trackers take t in units of |d| too.
                    let _ = (t0, t1);
                    let want = (-(f64::from(*s)) * f64::from(len)).exp();
                    if *stochastic {
                        let sd = (want * (1.0 - want) / reps as f64).sqrt().max(1e-12);
                        let z = (mean - want) / sd;
                        // Ratio tracking's estimate is not Bernoulli; its sd is below the
                        // Bernoulli one, so |z| < 5 against it is conservative.
                        assert!(z.abs() < 5.0, "{what}: mean T {mean} vs {want} (z {z:.2})");
                        let pz = (hits as f64 / reps as f64 - (1.0 - want)) / sd;
                        assert!(
                            pz.abs() < 5.0,
                            "{what}: P(collision) {} vs {} (z {pz:.2})",
                            hits as f64 / reps as f64,
                            1.0 - want
                        );
                        format!("E[T]={mean:.4} (exact {want:.4})")
                    } else {
                        assert!(
                            (mean - want).abs() < 1e-4 * want.max(1e-30) + 1e-6,
                            "{what}: {mean} vs {want}"
                        );
                        format!("T={mean:.5}")
                    }
                }
            };
            let col = match *label {
                l if l.starts_with("ray") => 1,
                l if l.starts_with("delta tracking,") || l.starts_with("ratio tracking,") => 4,
                l if l.starts_with("delta") => 2,
                _ => 3,
            };
            while rows[ci].len() <= col {
                rows[ci].push(String::new());
            }
            if rows[ci][col].is_empty() {
                rows[ci][col] = ok_cell(cell);
            } else {
                rows[ci][col] = format!("{} / {}", rows[ci][col], cell);
            }
        }
    }
    // A majorant of 0 over a non-empty medium violates the bound: documented behaviour is
    // "no tentative collisions": T = 1, no collision, finite (biased, never NaN).
    let d0 = DeltaTracking::new(field.clone(), maj0.clone());
    let r0 = RatioTracking::new(field.clone(), maj0.clone());
    let mut rng = Pcg32::new(1, 1);
    let (o, d) = (Vec3::new(-1.0, 0.5, 0.5), Vec3::X);
    let td = d0.transmittance(o, d, f32::INFINITY, &mut rng);
    let tr = r0.transmittance(o, d, f32::INFINITY, &mut rng);
    assert_transmittance(td, "delta, majorant 0 under sigma 1.5");
    assert_transmittance(tr, "ratio, majorant 0 under sigma 1.5");
    assert!(
        d0.sample_distance(o, d, f32::INFINITY, &mut rng)
            .is_none_or(|x| x.is_finite())
    );
    eprintln!("majorant 0 under a medium of sigma 1.5: delta T = {td}, ratio T = {tr}");
    for r in rows {
        table.row(r);
    }
    table.print();
}
