//! A small reference ray marcher (midpoint rule) for benchmarks and comparisons with pins.
//!
//! The density is any function of a point in the box's own space (the space of `bounds`);
//! the ray is given in the same space. The step is `rel_step` times the box's longest edge
//! (the convention of the bake's `step_size`): the segment inside the box is cut into
//! `n = ceil(length / step)` equal sub-steps and the density is evaluated at their midpoints.
//! Negative and NaN densities count as 0. This path is f64: it is a reference, not the
//! pin query path.

use glam::DVec3;

use crate::rng::Rng;

/// An axis-aligned box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MarchBox {
    pub min: DVec3,
    pub max: DVec3,
}

/// Most sub-steps one march takes (bounds the cost of absurd step sizes).
pub const MAX_STEPS: u64 = 1 << 24;

struct Plan {
    t0: f64,
    h: f64,
    n: u64,
    /// `|dir|`: converts parameter steps into lengths.
    speed: f64,
}

fn plan(bounds: &MarchBox, origin: DVec3, dir: DVec3, t_max: f64, rel_step: f64) -> Option<Plan> {
    let speed = dir.length();
    if !(speed > 0.0) || !speed.is_finite() || !origin.is_finite() || t_max.is_nan() {
        return None;
    }
    let (mut lo, mut hi) = (0.0f64, t_max);
    for a in 0..3 {
        let (o, d) = (origin[a], dir[a]);
        if d == 0.0 {
            if o < bounds.min[a] || o > bounds.max[a] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / d;
        let (mut t0, mut t1) = ((bounds.min[a] - o) * inv, (bounds.max[a] - o) * inv);
        if t0 > t1 {
            std::mem::swap(&mut t0, &mut t1);
        }
        lo = lo.max(t0);
        hi = hi.min(t1);
    }
    if !(lo < hi) || !hi.is_finite() {
        return None;
    }
    let edge = (bounds.max - bounds.min).max_element();
    let step = rel_step * edge / speed;
    let len = hi - lo;
    let n = if step > 0.0 && step.is_finite() {
        ((len / step).ceil() as u64).clamp(1, MAX_STEPS)
    } else {
        1
    };
    Some(Plan {
        t0: lo,
        h: len / n as f64,
        n,
        speed,
    })
}

fn sigma(density: &impl Fn(DVec3) -> f32, p: DVec3) -> f64 {
    let s = f64::from(density(p));
    if s > 0.0 { s } else { 0.0 }
}

/// `exp(-tau)` over `[0, t_max]` of the ray, tau by the midpoint rule.
pub fn transmittance(
    density: impl Fn(DVec3) -> f32,
    bounds: &MarchBox,
    origin: DVec3,
    dir: DVec3,
    t_max: f64,
    rel_step: f64,
) -> f64 {
    let Some(p) = plan(bounds, origin, dir, t_max, rel_step) else {
        return 1.0;
    };
    let mut tau = 0.0;
    for i in 0..p.n {
        let t = p.t0 + (i as f64 + 0.5) * p.h;
        tau += sigma(&density, origin + dir * t);
    }
    (-tau * p.h * p.speed).exp()
}

/// A free-flight distance in `[0, t_max]` by inverting the piecewise-constant optical depth of
/// the midpoint rule (exact within each sub-step), or `None` if the ray passes. One draw.
pub fn sample_distance(
    density: impl Fn(DVec3) -> f32,
    bounds: &MarchBox,
    origin: DVec3,
    dir: DVec3,
    t_max: f64,
    rel_step: f64,
    rng: &mut Rng,
) -> Option<f64> {
    let p = plan(bounds, origin, dir, t_max, rel_step)?;
    let xi = f64::from(rng.next_f32());
    let target = -(1.0 - xi).ln();
    let mut tau = 0.0;
    let dl = p.h * p.speed;
    for i in 0..p.n {
        let t = p.t0 + (i as f64 + 0.5) * p.h;
        let step_tau = sigma(&density, origin + dir * t) * dl;
        if tau + step_tau >= target && step_tau > 0.0 {
            let frac = (target - tau) / step_tau;
            return Some(p.t0 + (i as f64 + frac) * p.h);
        }
        tau += step_tau;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    const UNIT: MarchBox = MarchBox {
        min: DVec3::ZERO,
        max: DVec3::ONE,
    };

    #[test]
    fn homogeneous_box_is_exact() {
        let t = transmittance(
            |_| 2.0,
            &UNIT,
            DVec3::new(-1.0, 0.5, 0.5),
            DVec3::X,
            f64::INFINITY,
            0.1,
        );
        assert!((t - (-2.0f64).exp()).abs() < 1e-12);
        // Partial segment, non-normalised direction: t in parameter units.
        let t = transmittance(
            |_| 1.0,
            &UNIT,
            DVec3::new(0.0, 0.5, 0.5),
            DVec3::X * 2.0,
            0.25,
            0.01,
        );
        assert!((t - (-0.5f64).exp()).abs() < 1e-12);
        // Miss, NaN, zero direction.
        assert_eq!(
            transmittance(
                |_| 1.0,
                &UNIT,
                DVec3::new(2.0, 2.0, 2.0),
                DVec3::X,
                9.0,
                0.1
            ),
            1.0
        );
        assert_eq!(
            transmittance(|_| f32::NAN, &UNIT, DVec3::splat(0.5), DVec3::Z, 9.0, 0.1),
            1.0
        );
        assert_eq!(
            transmittance(|_| 1.0, &UNIT, DVec3::splat(0.5), DVec3::ZERO, 9.0, 0.1),
            1.0
        );
    }

    #[test]
    fn distances_follow_exponential() {
        let mut rng = Rng::new(3);
        let n = 100_000;
        let mut sum = 0.0;
        let mut none = 0;
        for _ in 0..n {
            match sample_distance(
                |_| 1.0,
                &UNIT,
                DVec3::new(0.0, 0.5, 0.5),
                DVec3::X,
                f64::INFINITY,
                0.05,
                &mut rng,
            ) {
                Some(d) => {
                    assert!((0.0..=1.0).contains(&d));
                    sum += d;
                }
                None => none += 1,
            }
        }
        let p_none = none as f64 / n as f64;
        assert!((p_none - (-1.0f64).exp()).abs() < 0.01, "{p_none}");
        // E[d | d < 1] for rate 1 = (1 - 2/e) / (1 - 1/e).
        let e = std::f64::consts::E;
        let want = (1.0 - 2.0 / e) / (1.0 - 1.0 / e);
        let got = sum / (n - none) as f64;
        assert!((got - want).abs() < 0.01, "{got} vs {want}");
    }
}
