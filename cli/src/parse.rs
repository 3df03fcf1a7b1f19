//! `clap` value parsers for the generic flag types both tools share. A value outside its
//! range is a usage error (exit 2) before any work starts; the ranges of the baker's own
//! flags (`--step`, `--spacing`, `--origin`, `--threads`) are the library's
//! (`pinbake::limits`), parsed with these.

use crate::num;

fn parse_f64(s: &str) -> Result<f64, String> {
    s.trim().parse::<f64>().map_err(|e| format!("'{s}': {e}"))
}

/// V or X,Y,Z, all finite.
pub fn parse_f64x3(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s.split(',').map(parse_f64).collect::<Result<_, _>>()?;
    let out = match v.as_slice() {
        [n] => [*n; 3],
        [x, y, z] => [*x, *y, *z],
        _ => return Err("expected V or X,Y,Z".into()),
    };
    if out.iter().any(|x| !x.is_finite()) {
        return Err("values must be finite".into());
    }
    Ok(out)
}

/// Any finite value.
pub fn parse_finite(s: &str) -> Result<f64, String> {
    let v = parse_f64(s)?;
    if !v.is_finite() {
        return Err(format!("{} must be finite", num(v)));
    }
    Ok(v)
}

/// A finite value >= 0 (radiances, `--exposure`, `--density-scale`).
pub fn parse_nonneg(s: &str) -> Result<f64, String> {
    let v = parse_f64(s)?;
    if !(v.is_finite() && v >= 0.0) {
        return Err(format!("{} must be finite and >= 0", num(v)));
    }
    Ok(v)
}

/// `N` or `X,Y,Z` (also `XxYxZ`) counts, each at least 1.
pub fn parse_u32x3(s: &str) -> Result<[u32; 3], String> {
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

/// A byte size with an optional K/M/G/T suffix (powers of 1024): `300M`, `1.5G`.
pub fn parse_bytes(s: &str) -> Result<u64, String> {
    let s = s.trim();
    let (num, mult) = match s.chars().last() {
        Some('K' | 'k') => (&s[..s.len() - 1], 1u64 << 10),
        Some('M' | 'm') => (&s[..s.len() - 1], 1 << 20),
        Some('G' | 'g') => (&s[..s.len() - 1], 1 << 30),
        Some('T' | 't') => (&s[..s.len() - 1], 1 << 40),
        _ => (s, 1),
    };
    let n: f64 = num.trim().parse().map_err(|e| format!("'{s}': {e}"))?;
    let bytes = n * mult as f64;
    if !(bytes.is_finite() && bytes >= 1.0 && bytes < 2f64.powi(63)) {
        return Err(format!("'{s}' is not a size between 1 byte and 8 EiB"));
    }
    Ok(bytes as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges() {
        assert!(parse_nonneg("nan").is_err());
        assert!(parse_nonneg("-1").is_err());
        assert_eq!(
            parse_nonneg("1e309").unwrap_err(),
            "inf must be finite and >= 0"
        );
        assert!(parse_finite("inf").is_err());
        assert_eq!(parse_f64x3("0.5,1,2"), Ok([0.5, 1.0, 2.0]));
        assert_eq!(parse_f64x3("2"), Ok([2.0; 3]));
        assert!(parse_f64x3("1,2").is_err());
        assert_eq!(parse_u32x3("4"), Ok([4; 3]));
        assert_eq!(parse_u32x3("2,3,4"), Ok([2, 3, 4]));
        assert_eq!(parse_u32x3("4x5x6"), Ok([4, 5, 6]));
        assert!(parse_u32x3("0").is_err());
        assert!(parse_u32x3("2,0,4").is_err());
        assert!(parse_u32x3("2,3").is_err());
        assert_eq!(parse_bytes("1.5K"), Ok(1536));
        assert_eq!(parse_bytes("300M"), Ok(300 << 20));
        assert_eq!(parse_bytes("2T"), Ok(2 << 40));
        for bad in ["", "0", "-1G", "nanG", "infK", "1e30G", "x", "9E"] {
            assert!(parse_bytes(bad).is_err(), "{bad}");
        }
    }
}
