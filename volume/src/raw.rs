//! Headerless raw volumes: a file that is nothing but `X*Y*Z` voxels, x fastest.
//!
//! The reader turns such a file into a [`DenseGrid`] after checking everything a header would
//! have told us: the byte count must match the dims and type exactly, every value must be
//! finite and non-negative (or be sanitised on request), and the density scale must not
//! overflow f32. Dims and type come from [`RawOptions`] or, when absent, from the file name
//! convention `name_XxYxZ_type.raw` (Open SciVis style).
//!
//! Not for: multi-component volumes, headers with offsets (`.dat`/`.nhdr` descriptors are
//! parsed elsewhere, if at all), signed integer types.

use std::io::Read;
use std::path::Path;

use glam::DVec3;

use super::grid::{DenseGrid, unflatten, voxel_count};
use super::{DensityScale, SourceError};

/// Voxel storage type of a raw file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RawType {
    U8,
    U16,
    F16,
    F32,
    F64,
}

impl RawType {
    pub fn size(self) -> usize {
        match self {
            RawType::U8 => 1,
            RawType::U16 | RawType::F16 => 2,
            RawType::F32 => 4,
            RawType::F64 => 8,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            RawType::U8 => "u8",
            RawType::U16 => "u16",
            RawType::F16 => "f16",
            RawType::F32 => "f32",
            RawType::F64 => "f64",
        }
    }
    /// Parses the type names of the file-name convention (case-insensitive): `uint8`/`u8`,
    /// `uint16`/`u16`, `float16`/`f16`/`half`, `float32`/`f32`/`float`, `float64`/`f64`/`double`.
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s.to_ascii_lowercase().as_str() {
            "uint8" | "u8" => RawType::U8,
            "uint16" | "u16" => RawType::U16,
            "float16" | "f16" | "half" => RawType::F16,
            "float32" | "f32" | "float" => RawType::F32,
            "float64" | "f64" | "double" => RawType::F64,
            _ => return None,
        })
    }
}

/// Byte order of multi-byte voxels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Endian {
    #[default]
    Little,
    Big,
}

/// How to read a raw file. `Default` gives: dims and type from the file name, little endian,
/// spacing 1, origin 0, strict values (negative/NaN/inf are errors), density scale 1.
#[derive(Clone, Debug, PartialEq)]
pub struct RawOptions {
    pub dims: Option<[u32; 3]>,
    pub voxel_type: Option<RawType>,
    pub endian: Endian,
    /// World size of one voxel along each axis.
    pub spacing: [f64; 3],
    /// World position of the grid box's minimum corner (not of the first voxel centre).
    pub origin: [f64; 3],
    /// Negative values become 0 instead of being an error.
    pub clamp_negative: bool,
    /// NaN and +-inf become 0 instead of being an error.
    pub nan_as_zero: bool,
}

impl Default for RawOptions {
    fn default() -> Self {
        Self {
            dims: None,
            voxel_type: None,
            endian: Endian::Little,
            spacing: [1.0; 3],
            origin: [0.0; 3],
            clamp_negative: false,
            nan_as_zero: false,
        }
    }
}

/// Reads dims and type from a name like `hydrogen_atom_128x128x128_uint8.raw`: the last two
/// `_`-separated fields of the stem are `XxYxZ` and the type.
pub fn parse_raw_file_name(path: &Path) -> Option<([u32; 3], RawType)> {
    let stem = path.file_stem()?.to_str()?;
    let mut parts = stem.rsplitn(3, '_');
    let ty = RawType::parse(parts.next()?)?;
    let dims_s = parts.next()?;
    parts.next()?; // a name must precede the dims
    let mut dims = [0u32; 3];
    let mut it = dims_s.split(['x', 'X']);
    for d in &mut dims {
        *d = it.next()?.parse().ok()?;
    }
    if it.next().is_some() {
        return None;
    }
    Some((dims, ty))
}

/// Reads a raw file into a dense grid, every value multiplied by `scale`; see the module docs
/// for the checks.
pub fn read_raw(
    path: &Path,
    opt: &RawOptions,
    scale: DensityScale,
) -> Result<DenseGrid, SourceError> {
    let err = |m: String| SourceError::raw(path, m);
    let inferred = parse_raw_file_name(path);
    let dims = opt.dims.or(inferred.map(|i| i.0)).ok_or_else(|| {
        err("no dims given and the file name does not follow name_XxYxZ_type.raw".into())
    })?;
    let ty = opt.voxel_type.or(inferred.map(|i| i.1)).ok_or_else(|| {
        err("no voxel type given and the file name does not follow name_XxYxZ_type.raw".into())
    })?;
    if dims.contains(&0) {
        return Err(err(format!(
            "dims {}x{}x{} contain a zero",
            dims[0], dims[1], dims[2]
        )));
    }
    let spacing = DVec3::from_array(opt.spacing);
    let origin = DVec3::from_array(opt.origin);
    if !(spacing.is_finite() && spacing.cmpgt(DVec3::ZERO).all()) {
        return Err(err(format!(
            "spacing must be positive and finite, got {spacing}"
        )));
    }
    if !origin.is_finite() {
        return Err(err(format!("origin must be finite, got {origin}")));
    }

    // All size arithmetic is checked and happens before any allocation: a header asking for
    // 2^31+ voxels with a small file must be a message, not an allocation.
    let count = voxel_count(dims);
    let expected = count.and_then(|c| c.checked_mul(ty.size()));
    let (mut file, actual) = crate::files::open_input(path).map_err(SourceError::from_file)?;
    let (Some(count), Some(expected)) = (count, expected) else {
        return Err(err(format!(
            "dims {}x{}x{} of {} overflow the address space (file has {actual} bytes)",
            dims[0],
            dims[1],
            dims[2],
            ty.name()
        )));
    };
    if expected as u64 != actual {
        return Err(err(format!(
            "size mismatch: {}x{}x{} {} voxels need {expected} bytes, the file has {actual} bytes",
            dims[0],
            dims[1],
            dims[2],
            ty.name()
        )));
    }

    let mut data: Vec<f32> = Vec::new();
    data.try_reserve_exact(count).map_err(|_| {
        err(format!(
            "cannot allocate {count} voxels ({} MiB)",
            count.saturating_mul(4) >> 20
        ))
    })?;

    // Convert in chunks so peak memory is the f32 grid plus one chunk, not the file twice.
    const CHUNK_VOXELS: usize = 1 << 18;
    let mut buf = vec![0u8; CHUNK_VOXELS * ty.size()];
    let mut done = 0usize;
    while done < count {
        let n = (count - done).min(CHUNK_VOXELS);
        let bytes = &mut buf[..n * ty.size()];
        file.read_exact(bytes).map_err(|e| {
            err(format!(
                "read failed after {done} of {count} voxels (file changed while reading?): {e}"
            ))
        })?;
        for (k, b) in bytes.chunks_exact(ty.size()).enumerate() {
            let v = decode(b, ty, opt.endian);
            let i = done + k;
            let v = sanitise(v, opt).map_err(|what| {
                let [x, y, z] = unflatten(i, dims);
                err(format!("{what} value {v} at voxel ({x},{y},{z})"))
            })?;
            let s = scale.apply(v).ok_or_else(|| {
                let [x, y, z] = unflatten(i, dims);
                err(format!(
                    "value {v} at voxel ({x},{y},{z}) times density scale {scale} overflows f32"
                ))
            })?;
            data.push(s);
        }
        done += n;
    }

    let endian = match (ty.size(), opt.endian) {
        (1, _) => "",
        (_, Endian::Little) => " le",
        (_, Endian::Big) => " be",
    };
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
    let label = format!(
        "raw {}{endian} {}",
        ty.name(),
        name.unwrap_or_else(|| path.display().to_string())
    );
    DenseGrid::new(dims, data, spacing, origin, label).map_err(|e| err(e.to_string()))
}

#[inline]
fn decode(b: &[u8], ty: RawType, endian: Endian) -> f64 {
    macro_rules! num {
        ($t:ty, $n:literal) => {{
            let mut a = [0u8; $n];
            a.copy_from_slice(b);
            match endian {
                Endian::Little => <$t>::from_le_bytes(a),
                Endian::Big => <$t>::from_be_bytes(a),
            }
        }};
    }
    match ty {
        RawType::U8 => b[0] as f64,
        RawType::U16 => num!(u16, 2) as f64,
        RawType::F16 => half::f16::from_bits(num!(u16, 2)).to_f64(),
        RawType::F32 => num!(f32, 4) as f64,
        RawType::F64 => num!(f64, 8),
    }
}

/// Applies the NaN and negative policies; `Err` names the problem.
#[inline]
fn sanitise(v: f64, opt: &RawOptions) -> Result<f64, &'static str> {
    if !v.is_finite() {
        return if opt.nan_as_zero {
            Ok(0.0)
        } else if v.is_nan() {
            Err("NaN")
        } else {
            Err("infinite")
        };
    }
    if v < 0.0 {
        return if opt.clamp_negative {
            Ok(0.0)
        } else {
            Err("negative")
        };
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::super::Density;
    use super::*;
    use std::io::Write;

    fn write(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
        let p = dir.join(name);
        std::fs::File::create(&p).unwrap().write_all(bytes).unwrap();
        p
    }

    fn f32s(v: &[f32]) -> Vec<u8> {
        v.iter().flat_map(|x| x.to_le_bytes()).collect()
    }

    #[test]
    fn file_name_convention() {
        let p = Path::new("/x/hydrogen_atom_128x128x128_uint8.raw");
        assert_eq!(parse_raw_file_name(p), Some(([128; 3], RawType::U8)));
        let p = Path::new("water_esp_31x34x33_float32.raw");
        assert_eq!(parse_raw_file_name(p), Some(([31, 34, 33], RawType::F32)));
        for (t, ty) in [
            ("u16", RawType::U16),
            ("half", RawType::F16),
            ("double", RawType::F64),
            ("float", RawType::F32),
        ] {
            let n = format!("a_2x3x4_{t}.raw");
            assert_eq!(parse_raw_file_name(Path::new(&n)), Some(([2, 3, 4], ty)));
        }
        assert_eq!(parse_raw_file_name(Path::new("a_2x3_u8.raw")), None);
        assert_eq!(parse_raw_file_name(Path::new("2x3x4_u8.raw")), None);
        assert_eq!(parse_raw_file_name(Path::new("a_2x3x4x5_u8.raw")), None);
        assert_eq!(parse_raw_file_name(Path::new("a_2x3x4_i8.raw")), None);
        assert_eq!(
            parse_raw_file_name(Path::new("a_99999999999x3x4_u8.raw")),
            None
        );
    }

    #[test]
    fn size_mismatch_and_huge_dims() {
        let d = tempfile::tempdir().unwrap();
        let p = write(d.path(), "v_2x2x2_u8.raw", &[1; 7]);
        let e = read_raw(&p, &RawOptions::default(), DensityScale::ONE)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("need 8 bytes") && e.contains("has 7 bytes"),
            "{e}"
        );
        assert!(e.contains("v_2x2x2_u8.raw"), "{e}");
        // 2^33 voxels requested against a 7 byte file: an error, no allocation.
        let opt = RawOptions {
            dims: Some([2048, 2048, 2048]),
            voxel_type: Some(RawType::F32),
            ..Default::default()
        };
        let e = read_raw(&p, &opt, DensityScale::ONE)
            .unwrap_err()
            .to_string();
        assert!(e.contains("34359738368 bytes"), "{e}");
        let opt = RawOptions {
            dims: Some([u32::MAX; 3]),
            voxel_type: Some(RawType::F64),
            ..Default::default()
        };
        let e = read_raw(&p, &opt, DensityScale::ONE)
            .unwrap_err()
            .to_string();
        assert!(e.contains("overflow"), "{e}");
        assert!(!e.contains('\n'));
    }

    #[test]
    fn nan_inf_negative_policies() {
        let d = tempfile::tempdir().unwrap();
        let mut v = vec![1.0f32; 2 * 3 * 4];
        v[1 + 2 * (2 + 3 * 3)] = f32::NAN; // voxel (1,2,3)
        let p = write(d.path(), "n_2x3x4_f32.raw", &f32s(&v));
        let e = read_raw(&p, &RawOptions::default(), DensityScale::ONE)
            .unwrap_err()
            .to_string();
        assert!(e.contains("NaN") && e.contains("(1,2,3)"), "{e}");
        let ok = read_raw(
            &p,
            &RawOptions {
                nan_as_zero: true,
                ..Default::default()
            },
            DensityScale::ONE,
        )
        .unwrap();
        assert_eq!(ok.voxel(1, 2, 3), Some(0.0));

        v[1 + 2 * (2 + 3 * 3)] = f32::NEG_INFINITY;
        let p = write(d.path(), "i_2x3x4_f32.raw", &f32s(&v));
        let e = read_raw(&p, &RawOptions::default(), DensityScale::ONE)
            .unwrap_err()
            .to_string();
        assert!(e.contains("infinite") && e.contains("(1,2,3)"), "{e}");

        v[1 + 2 * (2 + 3 * 3)] = 1.0;
        v[2 * 3] = -0.5; // voxel (0,0,1)
        let p = write(d.path(), "g_2x3x4_f32.raw", &f32s(&v));
        let e = read_raw(&p, &RawOptions::default(), DensityScale::ONE)
            .unwrap_err()
            .to_string();
        assert!(e.contains("negative") && e.contains("(0,0,1)"), "{e}");
        let ok = read_raw(
            &p,
            &RawOptions {
                clamp_negative: true,
                ..Default::default()
            },
            DensityScale::ONE,
        )
        .unwrap();
        assert_eq!(ok.voxel(0, 0, 1), Some(0.0));
    }

    #[test]
    fn subnormals_and_density_scale_extremes() {
        let d = tempfile::tempdir().unwrap();
        let sub = f32::from_bits(1); // smallest subnormal
        let p = write(d.path(), "s_2x1x1_f32.raw", &f32s(&[sub, 1e30]));
        let g = read_raw(&p, &RawOptions::default(), DensityScale::ONE).unwrap();
        assert_eq!(g.voxel(0, 0, 0), Some(sub));
        let opts = RawOptions::default();
        let g = read_raw(&p, &opts, DensityScale::new(0.0).unwrap()).unwrap();
        assert_eq!(g.max_value(), 0.0);
        let big = DensityScale::new(1e30).unwrap();
        let e = read_raw(&p, &opts, big).unwrap_err().to_string();
        assert!(e.contains("overflows") && e.contains("(1,0,0)"), "{e}");
        let p = write(d.path(), "t_2x1x1_f32.raw", &f32s(&[1e-30, 2.0]));
        let g = read_raw(&p, &opts, big).unwrap();
        assert!((g.voxel(0, 0, 0).unwrap() - 1.0).abs() < 1e-6);
        assert_eq!(g.voxel(1, 0, 0), Some(2e30));
        // A negative scale cannot be made: the one rule of every surface.
        assert!(DensityScale::new(-1.0).is_err());
    }

    #[test]
    fn big_endian_and_placement() {
        let d = tempfile::tempdir().unwrap();
        let bytes: Vec<u8> = [1u16, 2, 3, 4]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        let p = write(d.path(), "anything.bin", &bytes);
        let opt = RawOptions {
            dims: Some([4, 1, 1]),
            voxel_type: Some(RawType::U16),
            endian: Endian::Big,
            spacing: [2.0, 1.0, 1.0],
            origin: [10.0, 0.0, 0.0],
            ..Default::default()
        };
        let g = read_raw(&p, &opt, DensityScale::ONE).unwrap();
        assert_eq!(g.data(), &[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(g.bounds().min.x, 10.0);
        assert_eq!(g.bounds().max.x, 18.0);
        assert_eq!(g.extinction(DVec3::new(13.0, 0.5, 0.5)), 2.0);
        // No name convention and no options: a clear error.
        let e = read_raw(&p, &RawOptions::default(), DensityScale::ONE)
            .unwrap_err()
            .to_string();
        assert!(e.contains("no dims"), "{e}");
    }
}
