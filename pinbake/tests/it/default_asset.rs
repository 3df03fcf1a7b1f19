//! The default asset (`pinbake::default_asset`): a bake with no grid flags is no larger than
//! its source (plus 64 KiB), `--max-bytes` bounds it, the embedded density holds the
//! source's own voxels at its resolution and their box average below it, and the bytes do
//! not depend on the threads.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use pin_volume::SourceSpec;
use pinbake::glam::DVec3;

const BIN: &str = env!("CARGO_BIN_EXE_pinbake");
const ALLOWANCE: u64 = pinbake::default_asset::ALLOWANCE;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(name)
}

fn pinbake(args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .stdin(Stdio::null())
        .output()
        .expect("run pinbake")
}

/// `pinbake bake INPUT -o OUT --json EXTRA...`, which must succeed: its summary.
fn bake(input: &Path, out: &Path, extra: &[&str]) -> serde_json::Value {
    let mut args = vec![
        "bake",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--json",
    ];
    args.extend_from_slice(extra);
    let o = pinbake(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

/// A raw f32 grid of `dims` voxels, `value(x, y, z)` each, named by the raw convention.
fn write_raw(
    dir: &Path,
    name: &str,
    dims: [usize; 3],
    value: impl Fn(usize, usize, usize) -> f32,
) -> PathBuf {
    let path = dir.join(format!(
        "{name}_{}x{}x{}_float32.raw",
        dims[0], dims[1], dims[2]
    ));
    let mut bytes = Vec::new();
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                bytes.extend_from_slice(&value(x, y, z).to_le_bytes());
            }
        }
    }
    std::fs::write(&path, bytes).unwrap();
    path
}

/// A few Gaussian puffs in a tiny grid.
fn puffs(n: [usize; 3]) -> impl Fn(usize, usize, usize) -> f32 {
    move |x, y, z| {
        let p = [x, y, z]
            .iter()
            .zip(n)
            .map(|(&c, n)| (c as f64 + 0.5) / n as f64)
            .collect::<Vec<_>>();
        let bump = |c: [f64; 3], s: f64, peak: f64| {
            let r2: f64 = (0..3).map(|a| (p[a] - c[a]).powi(2)).sum();
            peak * (-r2 / (2.0 * s * s)).exp()
        };
        (bump([0.4, 0.5, 0.45], 0.15, 30.0) + bump([0.7, 0.3, 0.6], 0.07, 50.0)) as f32
    }
}

#[test]
fn a_bake_with_no_flags_is_no_larger_than_its_source() {
    let dir = tempfile::tempdir().unwrap();
    let raw = write_raw(dir.path(), "puffs", [19, 17, 21], puffs([19, 17, 21]));
    for input in [
        data("gaffer_sphere_density.vdb"),
        data("oiio_sphere_density.vdb"),
        raw,
    ] {
        let out = dir.path().join("default.pin");
        let v = bake(&input, &out, &[]);
        let source = std::fs::metadata(&input).unwrap().len();
        let bytes = std::fs::metadata(&out).unwrap().len();
        assert!(
            bytes <= source + ALLOWANCE,
            "{}: {bytes} bytes from a {source}-byte source",
            input.display()
        );
        // The choice and every alternative it weighed, with their predicted errors.
        let a = &v["choice"]["asset"];
        assert_eq!(a["max_bytes"], source + ALLOWANCE, "{a}");
        assert_eq!(
            a["target_error"],
            pinbake::default_asset::DEFAULT_ASSET_TARGET
        );
        assert!(a["chosen"]["representation"] != "pins", "{a}");
        let alts = a["alternatives"].as_array().unwrap();
        assert!(alts.iter().any(|x| x["representation"] == "pins"), "{a}");
        assert!(
            alts.iter()
                .all(|x| x["predicted_error"].as_f64().unwrap() > 0.0),
            "{a}"
        );
        assert!(alts.contains(&a["chosen"]), "{a}");
        assert!(a["reason"].as_str().is_some_and(|r| !r.is_empty()));
        // A density travels in the file: its box is on the source's voxels.
        let bytes = std::fs::read(&out).unwrap();
        let f = pin_format::PinFile::parse(&bytes).unwrap();
        assert!(f.density().is_some() || f.sparse_density().is_some());
    }
}

#[test]
fn max_bytes_bounds_the_default_and_refuses_what_cannot_fit() {
    let dir = tempfile::tempdir().unwrap();
    let input = data("openvdb_smoke1.vdb");
    let out = dir.path().join("small.pin");
    let v = bake(&input, &out, &["--max-bytes", "48K", "--threads", "2"]);
    let bytes = std::fs::metadata(&out).unwrap().len();
    assert!(bytes <= 48 << 10, "{bytes}");
    assert_eq!(v["choice"]["asset"]["max_bytes"], 48 << 10);
    // A larger budget: a finer density, never a coarser one.
    let big = dir.path().join("big.pin");
    let w = bake(
        &input,
        &big,
        &["--max-bytes", "400K", "--target-error", "0.001"],
    );
    assert!(std::fs::metadata(&big).unwrap().len() <= 400 << 10);
    assert!(
        w["choice"]["asset"]["chosen"]["factor"].as_u64()
            < v["choice"]["asset"]["chosen"]["factor"].as_u64(),
        "{w} {v}"
    );
    // Nothing fits in 1 KiB; named parameters predicted larger than the budget are refused.
    for extra in [
        &["--max-bytes", "1K"][..],
        &[
            "--max-bytes",
            "10K",
            "--cells",
            "20",
            "--dirs",
            "octahedral:16",
        ],
    ] {
        let no = dir.path().join("no.pin");
        let mut args = vec!["bake", input.to_str().unwrap(), "-o", no.to_str().unwrap()];
        args.extend_from_slice(extra);
        let o = pinbake(&args);
        assert_eq!(o.status.code(), Some(2), "{extra:?}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("--max-bytes"), "{err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(!no.exists());
    }
}

#[test]
fn the_default_bake_is_the_same_bytes_for_any_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let input = data("openvdb_smoke1.vdb");
    let (a, b) = (dir.path().join("a.pin"), dir.path().join("b.pin"));
    bake(&input, &a, &["--threads", "1"]);
    bake(&input, &b, &["--threads", "3"]);
    assert!(std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap());
}

/// The format's field of a voxel section over `[lo, hi]` (pinrt's `Density::extinction`):
/// trilinear between centres, the edge voxel in the outer half voxel, 0 outside.
fn format_field(
    dims: [u32; 3],
    lo: [f64; 3],
    hi: [f64; 3],
    at: impl Fn([u32; 3]) -> f32,
    p: DVec3,
) -> f32 {
    if !(0..3).all(|a| p[a] >= lo[a] && p[a] <= hi[a]) {
        return 0.0;
    }
    let mut i0 = [0u32; 3];
    let mut i1 = [0u32; 3];
    let mut f = [0f64; 3];
    for a in 0..3 {
        let n = f64::from(dims[a]);
        let u = ((p[a] - lo[a]) / ((hi[a] - lo[a]) / n) - 0.5).clamp(0.0, n - 1.0);
        i0[a] = u.floor() as u32;
        i1[a] = (i0[a] + 1).min(dims[a] - 1);
        f[a] = u - u.floor();
    }
    let mut sum = 0.0;
    for c in 0..8 {
        let pick = |a: usize| {
            if c >> a & 1 == 1 {
                (i1[a], f[a])
            } else {
                (i0[a], 1.0 - f[a])
            }
        };
        let (x, wx) = pick(0);
        let (y, wy) = pick(1);
        let (z, wz) = pick(2);
        sum += wx * wy * wz * f64::from(at([x, y, z]));
    }
    sum as f32
}

/// At the source's resolution the file's density is the source: its field, read as the
/// format reads it, is the VDB's trilinear field at any point, up to f16 rounding (resampled
/// over the cropped box, as before, it differed by a good part of a voxel's value). Dense
/// counts name that resolution too: the sphere's 11x9x11 stored voxels, or the 13x11x13 of
/// its lattice box.
#[test]
fn the_source_voxels_embedded_reproduce_the_source() {
    let dir = tempfile::tempdir().unwrap();
    let input = data("gaffer_sphere_density.vdb");
    let spec = SourceSpec::Vdb(input.clone(), pin_volume::vdb::VdbOptions::with_worker(BIN));
    let source = pin_volume::open_source(&spec, pin_volume::DensityScale::ONE).unwrap();
    for (flag, sparse) in [
        ("sparse", true),
        ("voxels", false),
        ("sparse-voxels", true),
        ("11,9,11", false),
        ("13,11,13", false),
    ] {
        let out = dir.path().join(format!("{flag}.pin"));
        bake(
            &input,
            &out,
            &[
                "--embed-density",
                flag,
                "--cells",
                "2",
                "--dirs",
                "octahedral:1",
            ],
        );
        let bytes = std::fs::read(&out).unwrap();
        let f = pin_format::PinFile::parse(&bytes).unwrap();
        let d = f.desc();
        let (lo, hi) = (d.box_min, d.box_max);
        let field = |p: DVec3| match sparse {
            true => {
                let s = f.sparse_density().unwrap();
                format_field(s.header.dims, lo, hi, |v| s.get(v).unwrap_or(0.0), p)
            }
            false => {
                let s = f.density().unwrap();
                let [nx, ny, _] = s.dims.map(|n| n as usize);
                format_field(
                    s.dims,
                    lo,
                    hi,
                    |v| {
                        s.values[v[0] as usize + nx * (v[1] as usize + ny * v[2] as usize)].to_f32()
                    },
                    p,
                )
            }
        };
        let b = source.bounds();
        let mut worst = 0f32;
        let mut peak = 0f32;
        // A fixed lattice of points that falls between the voxel centres.
        for i in 0..4000u32 {
            let t = DVec3::new(
                (f64::from(i % 17) + 0.37) / 17.0,
                (f64::from((i / 17) % 15) + 0.61) / 15.0,
                (f64::from(i / 255) + 0.13) / 16.0,
            );
            let p = b.min + (b.max - b.min) * t;
            let (want, got) = (source.extinction(p), field(p));
            worst = worst.max((want - got).abs());
            peak = peak.max(want);
        }
        assert!(peak > 0.0);
        assert!(worst <= peak * 2e-3, "{flag}: off by {worst} of {peak}");
    }
}

/// Below the source's resolution each embedded voxel is the mean of the source voxels it
/// covers: on a grid of whole blocks, exactly the box average (to f16).
#[test]
fn a_coarser_density_is_the_box_average_of_the_source() {
    let dir = tempfile::tempdir().unwrap();
    let n = [8usize, 6, 4];
    let value = |x: usize, y: usize, z: usize| (1 + x + 3 * y * y + 7 * z + (x * y) % 5) as f32;
    let input = write_raw(dir.path(), "ramp", n, value);
    for (flag, dims) in [
        ("voxels:2", [4u32, 3, 2]),
        ("4,3,2", [4, 3, 2]),
        ("sparse-voxels:2", [4, 3, 2]),
    ] {
        let out = dir.path().join("coarse.pin");
        bake(
            &input,
            &out,
            &[
                "--embed-density",
                flag,
                "--cells",
                "2",
                "--dirs",
                "octahedral:1",
            ],
        );
        let bytes = std::fs::read(&out).unwrap();
        let f = pin_format::PinFile::parse(&bytes).unwrap();
        let get = |v: [u32; 3]| -> f32 {
            match f.density() {
                Some(d) => {
                    assert_eq!(d.dims, dims, "{flag}");
                    d.values[(v[0] + dims[0] * (v[1] + dims[1] * v[2])) as usize].to_f32()
                }
                None => {
                    let s = f.sparse_density().unwrap();
                    assert_eq!(s.header.dims, dims, "{flag}");
                    s.get(v).unwrap()
                }
            }
        };
        for z in 0..2 {
            for y in 0..3 {
                for x in 0..4 {
                    let mut sum = 0.0;
                    for (dx, dy, dz) in (0..8).map(|c| (c & 1, c >> 1 & 1, c >> 2 & 1)) {
                        sum += value(2 * x + dx, 2 * y + dy, 2 * z + dz);
                    }
                    let want = half::f16::from_f32(sum / 8.0).to_f32();
                    let got = get([x as u32, y as u32, z as u32]);
                    assert_eq!(got, want, "{flag} voxel {x},{y},{z}");
                }
            }
        }
    }
}

/// `pinbake bake INPUT --embed-density FLAG` (2^3 cells x octahedral:1) to `out`: the file.
fn embed(input: &Path, out: &Path, flag: &str, extra: &[&str]) -> Vec<u8> {
    let mut args = vec![
        "--embed-density",
        flag,
        "--cells",
        "2",
        "--dirs",
        "octahedral:1",
    ];
    args.extend_from_slice(extra);
    bake(input, out, &args);
    std::fs::read(out).unwrap()
}

/// Dense counts that name the source's resolution, or a whole F of it, embed the source's
/// voxels on its lattice: the same file as `voxels:F`, for any thread count and as tiles
/// merged; counts that name no whole F are resampled over the cropped box as before.
#[test]
fn dense_counts_at_the_source_resolution_embed_its_voxels() {
    let dir = tempfile::tempdir().unwrap();
    let input = data("gaffer_sphere_density.vdb");
    let out = |n: &str| dir.path().join(n);
    for (counts, voxels) in [
        ("11,9,11", "voxels"),
        ("6,5,6", "voxels:2"),
        ("7,6,7", "voxels:2"),
    ] {
        let want = embed(&input, &out("v.pin"), voxels, &[]);
        for threads in ["1", "3"] {
            let got = embed(&input, &out("d.pin"), counts, &["--threads", threads]);
            assert!(
                got == want,
                "{counts} ({threads} threads) differs from {voxels}"
            );
        }
        // Tiles of the bake merged: the monolithic file.
        let tiles: Vec<PathBuf> = (0..2).map(|i| out(&format!("t{i}.pin"))).collect();
        for (i, t) in tiles.iter().enumerate() {
            embed(&input, t, counts, &["--tile", &format!("{i}/2")]);
        }
        let merged = out("m.pin");
        let mut args = vec!["merge".to_string()];
        args.extend(tiles.iter().map(|t| t.to_str().unwrap().to_string()));
        args.extend(["-o".into(), merged.to_str().unwrap().into()]);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = pinbake(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(
            std::fs::read(&merged).unwrap() == want,
            "{counts}: tiles merged"
        );
    }
    // Counts between resolutions: a grid over the cropped box (the VDB's own box), as before.
    let bytes = embed(&input, &out("r.pin"), "10,9,11", &[]);
    let f = pin_format::PinFile::parse(&bytes).unwrap();
    assert_eq!(f.density().unwrap().dims, [10, 9, 11]);
    let spec = SourceSpec::Vdb(input.clone(), pin_volume::vdb::VdbOptions::with_worker(BIN));
    let source = pin_volume::open_source(&spec, pin_volume::DensityScale::ONE).unwrap();
    let b = source.bounds();
    let d = f.desc();
    for a in 0..3 {
        assert!(
            (d.box_min[a] - b.min[a]).abs() < 1e-6,
            "{:?} {b:?}",
            d.box_min
        );
        assert!(
            (d.box_max[a] - b.max[a]).abs() < 1e-6,
            "{:?} {b:?}",
            d.box_max
        );
    }
}
