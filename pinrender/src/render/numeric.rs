//! Numerics shared by the renderer and its extensions: a leaf of the module.

/// `expm1(x) / x`, with the limit 1 at 0. Accurate to a few ulp for all `x` where the
/// result is finite (`expm1` carries the cancellation; the division is exact to 1 ulp).
#[inline]
pub fn exprel(x: f64) -> f64 {
    if x.abs() < 1e-8 {
        // Second-order series: the next term, x^2/6, is below 1e-16 here.
        1.0 + 0.5 * x
    } else {
        x.exp_m1() / x
    }
}
