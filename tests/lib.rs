//! Workspace-level integration tests live in `tests/*.rs`.
//!
//! This library holds the fuzz entry points shared by the cargo-fuzz targets in
//! `pinbake/fuzz/` and the corpus replay test (`tests/fuzz_corpus.rs`), so that the bounded
//! CI smoke test runs exactly the code the fuzzer runs. A panic in either is a finding.

use std::path::{Path, PathBuf};
use std::time::Duration;

use glam::DVec3;
use pin_format::{Directions, PinFile};
use pin_volume::raw::read_raw;
use pin_volume::{DensityScale, DensitySource, Endian, RawOptions, RawType, VdbOptions, VdbSource};
use pinbake::{BakeOptions, bake};

/// Length of the option header in front of the voxel bytes of a `raw` fuzz input.
pub const RAW_HEADER: usize = 16;

/// What a fuzz input did (for the replay test's summary); panics never come back as a value.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    /// The reader accepted the input; `baked` says whether a pin file was baked and verified.
    Accepted { voxels: u64, baked: bool },
    /// The reader refused it with this one-line message.
    Refused(String),
    /// The input was too short to carry the options header.
    TooShort,
}

/// Decodes the `raw` fuzz input layout: 16 bytes of options, then the file's bytes.
///
/// | byte | meaning |
/// |---|---|
/// | 0 | voxel type: `% 5` of u8, u16, f16, f32, f64 |
/// | 1 | bit 0 big endian, bit 1 clamp negative, bit 2 NaN as zero, bit 3 dims and type from the file name only, bit 4 dims are full u32 (else u16 % 4097), bits 5-6 density scale 1, 0, 1e30, 1e-30 |
/// | 2 | spacing: `% 4` of 1, 0.5, 1e-20, 1e20 |
/// | 3 | reserved |
/// | 4..16 | dims: three u32 LE (bit 4) or three u16 LE in bytes 4..10 |
/// The options, the density scale and the file name.
pub fn raw_options(header: &[u8; RAW_HEADER]) -> (RawOptions, DensityScale, String) {
    let ty = [
        RawType::U8,
        RawType::U16,
        RawType::F16,
        RawType::F32,
        RawType::F64,
    ][header[0] as usize % 5];
    let flags = header[1];
    let u32_at = |i: usize| u32::from_le_bytes(header[i..i + 4].try_into().unwrap());
    let u16_at = |i: usize| u32::from(u16::from_le_bytes(header[i..i + 2].try_into().unwrap()));
    let dims = if flags & 0x10 != 0 {
        [u32_at(4), u32_at(8), u32_at(12)]
    } else {
        [u16_at(4) % 4097, u16_at(6) % 4097, u16_at(8) % 4097]
    };
    let scale = [
        DensityScale::ONE,
        DensityScale::new(0.0).expect("a valid scale"),
        DensityScale::new(1e30).expect("a valid scale"),
        DensityScale::new(1e-30).expect("a valid scale"),
    ][usize::from((flags >> 5) & 3)];
    let spacing = [1.0, 0.5, 1e-20, 1e20][usize::from(header[2] % 4)];
    let from_name = flags & 0x08 != 0;
    let opt = RawOptions {
        dims: (!from_name).then_some(dims),
        voxel_type: (!from_name).then_some(ty),
        endian: if flags & 1 != 0 {
            Endian::Big
        } else {
            Endian::Little
        },
        spacing: [spacing; 3],
        origin: [0.0; 3],
        clamp_negative: flags & 2 != 0,
        nan_as_zero: flags & 4 != 0,
    };
    let name = if from_name {
        format!("fuzz_{}x{}x{}_{}.raw", dims[0], dims[1], dims[2], ty.name())
    } else {
        "input.raw".to_string()
    };
    (opt, scale, name)
}

/// Builds a `raw` fuzz input (for seed corpora and tests): header fields as documented in
/// [`raw_options`], dims as u32 (flag bit 4 is set).
pub fn raw_input(ty: u8, flags: u8, spacing: u8, dims: [u32; 3], payload: &[u8]) -> Vec<u8> {
    let mut v = vec![ty, flags | 0x10, spacing, 0];
    for d in dims {
        v.extend_from_slice(&d.to_le_bytes());
    }
    v.extend_from_slice(payload);
    v
}

/// The `raw` fuzz target: writes the payload to a file in `scratch`, reads it with
/// [`read_raw`], and for an accepted grid checks that every value and sample is finite and
/// `>= 0`, then (for grids up to 4096 voxels) bakes a 2x2x2 pin grid and checks that it
/// verifies and holds no NaN or infinity.
pub fn fuzz_raw(data: &[u8], scratch: &Path) -> Outcome {
    let Some(header) = data.first_chunk::<RAW_HEADER>() else {
        return Outcome::TooShort;
    };
    let (opt, scale, name) = raw_options(header);
    let path = scratch.join(name);
    std::fs::write(&path, &data[RAW_HEADER..]).expect("scratch file");
    let res = read_raw(&path, &opt, scale);
    let _ = std::fs::remove_file(&path);
    let grid = match res {
        Ok(g) => g,
        Err(e) => {
            let msg = e.to_string();
            assert!(!msg.contains('\n'), "multi-line error: {msg:?}");
            return Outcome::Refused(msg);
        }
    };
    let voxels = grid.data().len() as u64;
    assert!(
        grid.data().iter().all(|v| v.is_finite() && *v >= 0.0),
        "a raw grid kept a NaN, infinite or negative value"
    );
    check_source(&grid);
    let baked = voxels <= 4096 && bake_and_verify(&grid);
    Outcome::Accepted { voxels, baked }
}

/// Extinction at the box corners, centre and a few outside points: finite and `>= 0`.
pub fn check_source(src: &dyn DensitySource) {
    let b = src.bounds();
    assert!(b.is_valid(), "invalid bounds {b:?}");
    let e = b.extent();
    for i in 0..=4 {
        for j in 0..=4 {
            for k in 0..=4 {
                let f = DVec3::new(i as f64, j as f64, k as f64) * 0.25;
                let p = b.min + e * f;
                let v = src.extinction(p);
                assert!(v.is_finite() && v >= 0.0, "extinction {v} at {p}");
            }
        }
    }
    let outside = src.extinction(b.max + e);
    assert!(outside == 0.0, "extinction {outside} outside the box");
    let m = src.max_extinction_in(b);
    assert!(m >= 0.0 && !m.is_nan(), "max extinction {m}");
}

/// Bakes a 2x2x2 grid with one octahedral direction cell, serialises it and verifies it.
/// Returns false when the bake refuses the source's placement (a box too small or too far
/// for f32 queries) with a one-line message; panics on any other failure or on a
/// non-finite `t_min`; returns true.
pub fn bake_and_verify(src: &dyn DensitySource) -> bool {
    let opts = BakeOptions {
        cells: [2, 2, 2],
        directions: Directions::Octahedral { n: 2 },
        step: 0.2,
        threads: Some(1),
        majorant: Some([1, 1, 1]),
        ..BakeOptions::default()
    };
    let owned = match bake(src, &opts, &|_| {}) {
        Ok((owned, _)) => owned,
        Err(pinbake::BakeError::Placement(msg)) => {
            assert!(!msg.contains('\n'), "multi-line error: {msg:?}");
            return false;
        }
        Err(e) => panic!("a valid source must bake: {e:?}"),
    };
    let bytes = owned.to_bytes().expect("serialise");
    assert_pin_bytes_sane(&bytes);
    true
}

/// A pin file's bytes parse, `verify()` and hold only `t_min` in `[0, 1]` (no NaN or inf).
pub fn assert_pin_bytes_sane(bytes: &[u8]) {
    let mut words = vec![0u64; bytes.len().div_ceil(8)];
    let buf = &mut bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..bytes.len()];
    buf.copy_from_slice(bytes);
    let file = PinFile::parse(buf).expect("parse");
    file.verify().expect("verify");
    for p in file.pins() {
        assert!(
            p.t_min.is_finite() && (0.0..=1.0).contains(&p.t_min),
            "t_min {} escaped into a pin file",
            p.t_min
        );
        assert!(
            p.t_min < 1.0 || p.mask == 0,
            "t_min 1 with mask {:#x}",
            p.mask
        );
    }
    if let Some(m) = file.majorant() {
        for v in m.values {
            assert!(v.is_finite() && *v >= 0.0, "majorant {v}");
        }
    }
}

/// The `vdb_guard` fuzz target: writes `data` to `scratch/input.vdb` and opens it with
/// [`VdbSource::open`] through the isolated worker `worker`. Errors must be one line; an
/// accepted grid must have a finite box and finite, non-negative extinction everywhere
/// sampled.
pub fn fuzz_vdb(data: &[u8], scratch: &Path, worker: &Path) -> Outcome {
    let path = scratch.join("input.vdb");
    std::fs::write(&path, data).expect("scratch file");
    let opt = VdbOptions {
        timeout: Duration::from_secs(20),
        ..VdbOptions::with_worker(worker)
    };
    let res = VdbSource::open(&path, &opt, DensityScale::ONE);
    let _ = std::fs::remove_file(&path);
    match res {
        Ok(src) => {
            check_source(&src);
            let (lo, hi) = src.index_bounds();
            let voxels = (0..3)
                .map(|a| (i64::from(hi[a]) - i64::from(lo[a]) + 1).max(0) as u64)
                .product();
            Outcome::Accepted {
                voxels,
                baked: false,
            }
        }
        Err(e) => {
            let msg = e.to_string();
            assert!(!msg.contains('\n'), "multi-line error: {msg:?}");
            Outcome::Refused(msg)
        }
    }
}

/// The workspace's target directory (for locating built binaries from outside cargo).
pub fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../target"))
}
