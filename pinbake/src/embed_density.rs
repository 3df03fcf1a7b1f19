//! What density a pin file carries for rendering from the file alone (`--embed-density`,
//! Python's `embed_density=`): one value from the flag, through the request and the bake's
//! options, to the section it writes.

use std::str::FromStr;

use crate::sparse_density::{MAX_SPARSE_DIM, SparseDims};

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

/// Most voxels per axis of the dense section (the format's limit).
pub const MAX_DENSE_DIM: u32 = 4096;

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
            if v.iter().any(|&d| d > MAX_DENSE_DIM) {
                return Err(format!("{v:?}: at most {MAX_DENSE_DIM} per axis"));
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
