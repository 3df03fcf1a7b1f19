//! The documented ranges of the command-line flags both binaries share, as `clap` value
//! parsers: a value outside them is a usage error (exit 2) before any work starts. Each bound
//! says why it is there; see `docs/stability.md`, "Hostile use".

/// A float for messages: plain when short, scientific otherwise (1e308 is not 309 digits).
pub fn num(x: f64) -> String {
    let plain = format!("{x}");
    if plain.len() <= 12 {
        plain
    } else {
        format!("{x:e}")
    }
}

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

/// A finite value >= 0 (radiances, `--exposure`).
pub fn parse_nonneg(s: &str) -> Result<f64, String> {
    let v = parse_f64(s)?;
    if !(v.is_finite() && v >= 0.0) {
        return Err(format!("{} must be finite and >= 0", num(v)));
    }
    Ok(v)
}

/// `--density-scale`: finite and >= 0.
pub fn parse_density_scale(s: &str) -> Result<f64, String> {
    parse_nonneg(s)
}

/// Smallest relative ray-marching step (`pin_format::MIN_REL_STEP`, shared with the renderer):
/// below it a pin or a ray takes 10^5+ steps per box edge and a bake or render runs for hours
/// (`--step 1e-12` ran for minutes on 4^3 cells).
pub use pin_format::MIN_REL_STEP;

/// A relative step (fraction of the longest box edge) in [`MIN_REL_STEP`], 1].
pub fn check_rel_step(v: f64) -> Result<f64, String> {
    if !(MIN_REL_STEP..=1.0).contains(&v) {
        return Err(format!("{} must be in [1e-5, 1]", num(v)));
    }
    Ok(v)
}

/// `--step`: see [`check_rel_step`].
pub fn parse_step(s: &str) -> Result<f64, String> {
    check_rel_step(parse_f64(s)?)
}

/// `--spacing`: voxel sizes far outside [1e-9, 1e9] push box coordinates to where f32
/// positions and squared lengths lose all precision or overflow (`--spacing 1e153` made a
/// pin take 0.5 s instead of microseconds).
pub fn parse_spacing(s: &str) -> Result<[f64; 3], String> {
    check_spacing(parse_f64x3(s)?)
}

/// A voxel size in [1e-9, 1e9] on every axis: see [`parse_spacing`].
pub fn check_spacing(v: [f64; 3]) -> Result<[f64; 3], String> {
    if v.iter().any(|x| !(1e-9..=1e9).contains(x)) {
        return Err(format!("{} must be in [1e-9, 1e9]", v.map(num).join(",")));
    }
    Ok(v)
}

/// `--origin`: within +-1e12, for the same reason.
pub fn parse_origin(s: &str) -> Result<[f64; 3], String> {
    check_origin(parse_f64x3(s)?)
}

/// A position within +-1e12 on every axis (finite): see [`parse_origin`].
pub fn check_origin(v: [f64; 3]) -> Result<[f64; 3], String> {
    if v.iter().any(|x| !(x.abs() <= 1e12)) {
        return Err(format!("{} must be within +-1e12", v.map(num).join(",")));
    }
    Ok(v)
}

/// Upper bound of `--threads`: more workers than this only cost memory and start-up time
/// (`--threads 10000` spent its time spawning threads).
pub fn max_threads() -> usize {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    (64 * cores).min(4096)
}

/// `--threads N`: 1 ..= [`max_threads`].
pub fn parse_threads(s: &str) -> Result<usize, String> {
    let n: usize = s.trim().parse().map_err(|e| format!("'{s}': {e}"))?;
    let max = max_threads();
    if !(1..=max).contains(&n) {
        return Err(format!(
            "{n} is not in 1..={max} (64 per core, at most 4096)"
        ));
    }
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges() {
        assert_eq!(num(1e308), "1e308");
        assert_eq!(num(0.25), "0.25");
        assert!(parse_step("0").is_err());
        assert!(parse_step("1e-12").is_err());
        assert!(parse_step("nan").is_err());
        assert_eq!(parse_step("0.01"), Ok(0.01));
        assert!(parse_density_scale("nan").is_err());
        assert!(parse_density_scale("-1").is_err());
        assert_eq!(
            parse_density_scale("1e309").unwrap_err(),
            "inf must be finite and >= 0"
        );
        assert!(parse_spacing("1e153").unwrap_err().contains("1e153"));
        assert_eq!(parse_spacing("0.5,1,2"), Ok([0.5, 1.0, 2.0]));
        assert!(parse_origin("1e13,0,0").is_err());
        assert!(parse_threads("0").is_err());
        assert!(parse_threads("10000").is_err());
        assert_eq!(parse_threads("1"), Ok(1));
    }
}
