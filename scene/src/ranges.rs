//! The ranges of the scene's values, one rule for the scene file and `pinrender render`'s
//! flags (which parse with these). Each returns the value or a phrase for a message.

use pin_format::text::num as flag_num;

/// A number for the transform's messages: scientific below 1e-3 and from 1e6 up (`1e-9`,
/// `2e12`), as the placement rule writes them, else [`pin_format::text::num`].
pub(crate) fn num(x: f64) -> String {
    if x != 0.0 && x.is_finite() && !(1e-3..1e6).contains(&x.abs()) {
        format!("{x:e}")
    } else {
        pin_format::text::num(x)
    }
}

/// Field of view in degrees, in (0, 180) as the f32 the camera holds.
pub fn fov(v: f64) -> Result<f64, String> {
    let f = v as f32;
    if !(f > 0.0 && f < 180.0) {
        return Err(format!("{} must be in (0, 180) degrees", flag_num(v)));
    }
    Ok(v)
}

/// Single-scattering albedo in [0, 1].
pub fn albedo(v: f64) -> Result<f64, String> {
    if !(0.0..=1.0).contains(&v) {
        return Err(format!("{} must be in [0, 1]", flag_num(v)));
    }
    Ok(v)
}

/// The Henyey-Greenstein asymmetry in (-1, 1), as the f32 the scene holds.
pub fn hg_g(v: f64) -> Result<f64, String> {
    let f = v as f32;
    if !(f > -1.0 && f < 1.0) {
        return Err(format!("{} must be in (-1, 1)", flag_num(v)));
    }
    Ok(v)
}

/// A radiance: finite and not negative, as the f32 the renderer holds (1e308 would be
/// infinite there).
pub fn radiance(v: f64) -> Result<f64, String> {
    if !(v.is_finite() && v >= 0.0) {
        return Err(format!("{} must be finite and >= 0", flag_num(v)));
    }
    if v > f64::from(f32::MAX) {
        return Err(format!(
            "{} is beyond f32 ({:e}), where the renderer holds radiance",
            flag_num(v),
            f32::MAX
        ));
    }
    Ok(v)
}

/// A direction whose f32 form the renderer can normalise (finite, not zero).
pub fn direction(v: [f64; 3]) -> Result<[f64; 3], String> {
    // As glam's `is_finite`, `length_squared` and `normalize` (`d * length().recip()`), and
    // a squared length that does not overflow (beyond it the unit vector rounds to zero).
    let f = v.map(|x| x as f32);
    let len2 = f.iter().map(|x| x * x).sum::<f32>();
    let inv = len2.sqrt().recip();
    let ok = f.iter().all(|x| x.is_finite())
        && len2 > 0.0
        && len2.is_finite()
        && f.iter().all(|x| (x * inv).is_finite());
    if !ok {
        return Err(format!(
            "{},{},{} is not a direction (zero, or too small or large to normalise)",
            flag_num(v[0]),
            flag_num(v[1]),
            flag_num(v[2])
        ));
    }
    Ok(v)
}

/// A position within +-1e12 on every axis (finite): beyond it f32 positions lose all
/// precision ([`pin_format::MAX_PLACEMENT_COORD`]).
pub fn position(v: [f64; 3]) -> Result<[f64; 3], String> {
    if v.iter()
        .any(|x| !(x.abs() <= pin_format::MAX_PLACEMENT_COORD))
    {
        return Err(format!(
            "{},{},{} must be within +-{}",
            flag_num(v[0]),
            flag_num(v[1]),
            flag_num(v[2]),
            flag_num(pin_format::MAX_PLACEMENT_COORD)
        ));
    }
    Ok(v)
}

/// A density scale: positive and finite.
pub fn density_scale(v: f64) -> Result<f64, String> {
    if !(v > 0.0 && v.is_finite()) {
        return Err(format!("{} must be positive and finite", flag_num(v)));
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounds_are_the_flags() {
        assert!(fov(40.0).is_ok() && fov(0.0).is_err() && fov(180.0).is_err());
        assert!(fov(f64::NAN).is_err());
        assert!(albedo(1.0).is_ok() && albedo(1.01).is_err() && albedo(f64::NAN).is_err());
        assert!(hg_g(-0.99).is_ok() && hg_g(1.0).is_err() && hg_g(-1.0).is_err());
        assert!(radiance(0.0).is_ok() && radiance(-1e-9).is_err());
        assert!(radiance(f64::INFINITY).is_err());
        assert!(direction([0.0, 1.0, 0.0]).is_ok() && direction([0.0; 3]).is_err());
        assert!(direction([1e300, 0.0, 0.0]).is_err());
        assert!(direction([1e-30, 0.0, 0.0]).is_err());
        assert!(direction([1e20, 0.0, 0.0]).is_err(), "normalises to zero");
        assert!(position([1e12, 0.0, -1e12]).is_ok() && position([1.1e12, 0.0, 0.0]).is_err());
        assert!(density_scale(0.5).is_ok() && density_scale(0.0).is_err());
    }
}
