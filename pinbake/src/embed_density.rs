//! What density a pin file carries for rendering from the file alone (`--embed-density`,
//! Python's `embed_density=`): one value from the flag, through the request and the bake's
//! options, to the section it writes.

use std::str::FromStr;

use glam::DVec3;

use crate::sparse_density::{MAX_SPARSE_DIM, SparseDims};
use pin_volume::DensitySource;

/// Sub-samples per axis at most of the box filter ([`filter_samples`]): a voxel 16 source
/// voxels wide or wider averages 16^3 points of the source's field.
pub const MAX_FILTER_SAMPLES: u32 = 16;

/// Sub-samples per axis of the box filter for embedded voxels of `spacing` over `source`:
/// the source's voxels one embedded voxel spans (rounded up), 1 at or above the source's
/// resolution and for an analytic field (no voxels: sampled at the centre, as before).
pub fn filter_samples(source: &dyn DensitySource, spacing: DVec3) -> [u32; 3] {
    let Some(v) = source
        .voxel_size()
        .filter(|v| v.is_finite() && v.cmpgt(DVec3::ZERO).all())
    else {
        return [1; 3];
    };
    [0, 1, 2].map(|a| {
        let r = spacing[a] / v[a] - 1e-6;
        if r.is_finite() {
            r.ceil().clamp(1.0, f64::from(MAX_FILTER_SAMPLES)) as u32
        } else {
            1
        }
    })
}

/// The embedded voxel centred at `centre` with `spacing`: the source's value there when `sub`
/// is 1 on every axis, else the mean of the source's field at the centres of `sub` equal
/// parts per axis of the voxel, a box filter. On a voxel that covers whole source voxels of
/// an aligned lattice ([`crate::lattice_box`]) those points are the source's voxel centres,
/// and the value is the mean of the source's voxels. Summed in a fixed order, in f64: the
/// same value whatever the threads.
pub fn box_filtered(
    source: &dyn DensitySource,
    centre: DVec3,
    spacing: DVec3,
    sub: [u32; 3],
) -> f32 {
    if sub == [1; 3] {
        return source.extinction(centre);
    }
    let k = sub.map(f64::from);
    let step = spacing / DVec3::new(k[0], k[1], k[2]);
    let first = centre - spacing * 0.5 + step * 0.5;
    let mut row = [0f32; MAX_FILTER_SAMPLES as usize];
    let row = &mut row[..sub[0] as usize];
    let mut sum = 0f64;
    for jz in 0..sub[2] {
        for jy in 0..sub[1] {
            let o = first + DVec3::new(0.0, step.y * f64::from(jy), step.z * f64::from(jz));
            source.extinction_along(o, DVec3::new(step.x, 0.0, 0.0), row.len(), row);
            sum += row.iter().map(|&v| f64::from(v)).sum::<f64>();
        }
    }
    (sum / (k[0] * k[1] * k[2])) as f32
}

/// The embedded density: a dense f16 grid of these voxels per axis (1..=4096, the format's
/// limit), or sparse f16 bricks where the field is non-zero (format 1.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EmbedDensity {
    Dense([u32; 3]),
    Sparse(SparseDims),
    /// The source's own voxels on its lattice, every `factor`^3 of them averaged into one
    /// (box-filtered; 1: the voxels as they are), dense or sparse: the bake box grows to
    /// whole blocks of the lattice ([`crate::lattice_box`]) and the section's dims follow.
    Voxels {
        factor: u32,
        sparse: bool,
    },
}

/// Most source voxels per embedded voxel along an axis (`voxels:F`).
pub const MAX_VOXELS_FACTOR: u32 = 64;

impl EmbedDensity {
    /// The dense grid's voxels per axis, if dense.
    pub fn dense(self) -> Option<[u32; 3]> {
        match self {
            Self::Dense(d) => Some(d),
            Self::Sparse(_) | Self::Voxels { .. } => None,
        }
    }

    /// The sparse bricks' voxel dims, if sparse.
    pub fn sparse(self) -> Option<SparseDims> {
        match self {
            Self::Sparse(s) => Some(s),
            Self::Dense(_) | Self::Voxels { .. } => None,
        }
    }
}

/// `sparse`, `sparse:N`, `sparse:X,Y,Z`, dense `N` / `X,Y,Z`, or `voxels[:F]` /
/// `sparse-voxels[:F]` (the flag's text).
impl FromStr for EmbedDensity {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let t = s.trim();
        for (prefix, sparse) in [("sparse-voxels", true), ("voxels", false)] {
            let Some(rest) = t.strip_prefix(prefix) else {
                continue;
            };
            let factor = match rest.strip_prefix(':') {
                None if rest.is_empty() => 1,
                Some(f) => f
                    .trim()
                    .parse::<u32>()
                    .ok()
                    .filter(|f| (1..=MAX_VOXELS_FACTOR).contains(f))
                    .ok_or_else(|| {
                        format!("'{s}': F must be a whole number in 1..={MAX_VOXELS_FACTOR}")
                    })?,
                None => return Err(format!("'{s}': expected {prefix} or {prefix}:F")),
            };
            return Ok(Self::Voxels { factor, sparse });
        }
        let Some(rest) = t.strip_prefix("sparse") else {
            let v = parse_counts(t)?;
            if v.iter().any(|&d| d > 4096) {
                return Err(format!("{v:?}: at most 4096 per axis"));
            }
            return Ok(Self::Dense(v));
        };
        let dims = match rest.strip_prefix(':') {
            None if rest.is_empty() => SparseDims::Source,
            None => return Err(format!("'{s}': expected sparse, sparse:N or sparse:X,Y,Z")),
            Some(d) if !d.contains(',') => {
                let n: u32 = d.trim().parse().map_err(|e| format!("'{s}': {e}"))?;
                if !(1..=MAX_SPARSE_DIM).contains(&n) {
                    return Err(format!("'{s}': N must be in 1..={MAX_SPARSE_DIM}"));
                }
                SparseDims::Max(n)
            }
            Some(d) => {
                let v = parse_counts(d)?;
                if v.iter().any(|&n| !(1..=MAX_SPARSE_DIM).contains(&n)) {
                    return Err(format!("'{s}': each axis must be in 1..={MAX_SPARSE_DIM}"));
                }
                SparseDims::Exact(v)
            }
        };
        Ok(Self::Sparse(dims))
    }
}

/// `N` or `X,Y,Z` (or `XxYxZ`), each at least 1: the command line's count triples.
fn parse_counts(s: &str) -> Result<[u32; 3], String> {
    let v: Vec<u32> = s
        .split([',', 'x'])
        .map(|p| p.trim().parse::<u32>().map_err(|e| format!("'{p}': {e}")))
        .collect::<Result<_, _>>()?;
    let out = match v.as_slice() {
        [n] => [*n; 3],
        [x, y, z] => [*x, *y, *z],
        _ => return Err("expected N or X,Y,Z".into()),
    };
    if out.contains(&0) {
        return Err("every count must be at least 1".into());
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_flag_text_parses_to_one_value() {
        let p = |s: &str| s.parse::<EmbedDensity>();
        assert_eq!(p("64"), Ok(EmbedDensity::Dense([64; 3])));
        assert_eq!(p("8,16,32"), Ok(EmbedDensity::Dense([8, 16, 32])));
        assert_eq!(p("sparse"), Ok(EmbedDensity::Sparse(SparseDims::Source)));
        assert_eq!(
            p("sparse:128"),
            Ok(EmbedDensity::Sparse(SparseDims::Max(128)))
        );
        assert_eq!(
            p("sparse:4,5,6"),
            Ok(EmbedDensity::Sparse(SparseDims::Exact([4, 5, 6])))
        );
        for bad in [
            "0",
            "4097",
            "1,2",
            "sparsely",
            "sparse:0",
            "sparse:1,2,0",
            "",
        ] {
            assert!(p(bad).is_err(), "{bad}");
        }
        assert_eq!(
            p("voxels"),
            Ok(EmbedDensity::Voxels {
                factor: 1,
                sparse: false
            })
        );
        assert_eq!(
            p("sparse-voxels:4"),
            Ok(EmbedDensity::Voxels {
                factor: 4,
                sparse: true
            })
        );
        for bad in ["voxels:0", "voxels:65", "voxels4", "sparse-voxels:x"] {
            assert!(p(bad).is_err(), "{bad}");
        }
        assert_eq!(p("64").unwrap().dense(), Some([64; 3]));
        assert_eq!(p("sparse").unwrap().dense(), None);
    }
}
