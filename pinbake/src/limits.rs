//! The documented ranges of the baker's values, checked by the library front door
//! ([`crate::plan::BakeRequest::validate`]) for every caller, and by the command line's value
//! parsers ([`crate::cli_args`]) before any work starts. Each bound says why it is there; see
//! `docs/stability.md`, "Hostile use".

use pin_format::text::num;

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

/// A voxel size in [1e-9, 1e9] on every axis: sizes far outside it push box coordinates to
/// where f32 positions and squared lengths lose all precision or overflow (`--spacing
/// 1e153` made a pin take 0.5 s instead of microseconds).
pub fn check_spacing(v: [f64; 3]) -> Result<[f64; 3], String> {
    if v.iter().any(|x| !(1e-9..=1e9).contains(x)) {
        return Err(format!("{} must be in [1e-9, 1e9]", v.map(num).join(",")));
    }
    Ok(v)
}

/// A position within +-1e12 on every axis (finite), for the same reason as
/// [`check_spacing`].
pub fn check_origin(v: [f64; 3]) -> Result<[f64; 3], String> {
    if v.iter().any(|x| !(x.abs() <= 1e12)) {
        return Err(format!("{} must be within +-1e12", v.map(num).join(",")));
    }
    Ok(v)
}

/// Upper bound of worker threads: more than this only cost memory and start-up time
/// (`--threads 10000` spent its time spawning threads).
pub fn max_threads() -> usize {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    (64 * cores).min(4096)
}

/// A worker-thread count in 1 ..= [`max_threads`].
pub fn check_threads(n: usize) -> Result<usize, String> {
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
        assert!(check_rel_step(0.0).is_err());
        assert!(check_rel_step(1e-12).is_err());
        assert!(check_rel_step(f64::NAN).is_err());
        assert_eq!(check_rel_step(0.01), Ok(0.01));
        assert!(
            check_spacing([1e153, 1.0, 1.0])
                .unwrap_err()
                .contains("1e153")
        );
        assert_eq!(check_spacing([0.5, 1.0, 2.0]), Ok([0.5, 1.0, 2.0]));
        assert!(check_origin([1e13, 0.0, 0.0]).is_err());
        assert!(check_origin([f64::NAN, 0.0, 0.0]).is_err());
        assert!(check_threads(0).is_err());
        assert!(check_threads(10000).is_err());
        assert_eq!(check_threads(1), Ok(1));
    }
}
