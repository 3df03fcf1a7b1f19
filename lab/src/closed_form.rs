//! # Closed-form transmittance and distance sampling (`cosine-closed-form`)
//!
//! The estimator of the cosine-noise paper (docs/background.md,
//! sections 4 and 5) for any field whose optical depth along a segment has a closed form:
//! transmittance is `exp(-tau)` evaluated exactly (deterministic, no noise) and a free-flight
//! distance is found by drawing a target optical depth `-ln(1 - u)` and inverting the
//! monotone `tau(t)` with a safeguarded Newton iteration (bisection where the field gives no
//! extinction for the Newton step).
//!
//! **For**: exact references (no Monte Carlo noise in `T`) and as an entry of the
//! error-against-time table on procedural media. pinrt does not depend on pinbake, so the
//! field comes in through [`AnalyticOpticalDepth`]; the CLI implements it for pinbake's
//! `CosineNoise`.
//!
//! **Not for**: fields without a closed-form integral (voxel grids: use the trackers), or
//! fields whose extinction can turn negative (then `tau` is not monotone; the root finder
//! still returns *a* root inside the bracket, but the sampled distribution is not the free
//! flight distribution). Optical depths are clamped at 0 from below.
//!
//! ## Tolerance
//!
//! The root finder stops when `|tau(t) - target| <= ROOT_TOL * max(1, target)` or when the
//! bracket is narrower than `ROOT_TOL` times the segment length, whichever comes first, or
//! after [`MAX_ROOT_ITERS`] iterations (returning the bracket midpoint). With `ROOT_TOL =
//! 1e-10` the sampled optical depth is exact far below f32 resolution of the returned `t`.

use glam::{DVec3, Vec3};
use pinrender::render::{Pcg32, RenderError, TransportEstimator, check_box, clip_box, prepare};
use std::sync::Arc;

/// A medium whose optical depth along a segment has a closed form.
///
/// `optical_depth(o, d, t)` is `integral_0^t sigma_t(o + s d) ds` for a **unit** `d`; the
/// tracker only asks for segments already clipped to `bounds()` and `t >= 0`, so an
/// implementation may (but need not) clip again. It must be non-decreasing in `t` (a
/// non-negative extinction); NaN and negative results are read as 0.
pub trait AnalyticOpticalDepth: Send + Sync {
    /// The world-space box `(min, max)` that holds all of the medium.
    fn bounds(&self) -> ([f64; 3], [f64; 3]);
    /// Optical depth of `o + s d`, `s in [0, t]`, `|d| = 1`.
    fn optical_depth(&self, o: DVec3, d: DVec3, t: f64) -> f64;
    /// The extinction at `p`, if cheap: enables Newton steps (the derivative of `tau`) in
    /// distance sampling. `None` (the default) means bisection only.
    fn extinction(&self, p: DVec3) -> Option<f64> {
        let _ = p;
        None
    }
}

/// Relative tolerance of the distance-sampling root finder (see the module docs).
pub const ROOT_TOL: f64 = 1e-10;
/// Iteration cap of the root finder (bisection alone needs about 34 for `ROOT_TOL`).
pub const MAX_ROOT_ITERS: u32 = 200;

/// Exact transmittance and exact (to [`ROOT_TOL`]) distance sampling for an analytic medium.
pub struct ClosedFormTracker<A: ?Sized> {
    field: Arc<A>,
    lo: [f64; 3],
    hi: [f64; 3],
}

impl<A: AnalyticOpticalDepth + ?Sized> ClosedFormTracker<A> {
    /// Validates the field's box (finite, `min < max` on every axis).
    pub fn new(field: Arc<A>) -> Result<Self, RenderError> {
        let (lo, hi) = field.bounds();
        check_box(&lo, &hi).map_err(|why| RenderError::Invalid {
            what: "analytic field bounds",
            why,
        })?;
        Ok(ClosedFormTracker { field, lo, hi })
    }

    /// `tau` of a clipped segment, cleaned (NaN and negatives are 0, `+inf` stays).
    #[inline]
    fn tau(&self, p0: DVec3, d: DVec3, s: f64) -> f64 {
        let v = self.field.optical_depth(p0, d, s);
        if v > 0.0 { v } else { 0.0 }
    }

    /// Optical depth of `o + s d`, `s in [0, t_max]`, `d` unit, clipped to the box (f64).
    pub fn optical_depth(&self, o: DVec3, d: DVec3, t_max: f64) -> f64 {
        match clip_box(o, d, &self.lo, &self.hi, 0.0, t_max) {
            Some((t0, t1)) => self.tau(o + d * t0, d, t1 - t0),
            None => 0.0,
        }
    }

    /// Solves `tau(p0, d, s) = target` on `[0, len]` given `tau(len) = total > target`.
    /// Safeguarded Newton: a Newton step is taken only when it lands strictly inside the
    /// current bracket, otherwise the bracket is bisected, so the iteration cannot diverge
    /// on the cosine field's inflection points.
    pub fn invert(&self, p0: DVec3, d: DVec3, len: f64, total: f64, target: f64) -> f64 {
        let (mut lo, mut hi) = (0.0f64, len);
        let tol_tau = ROOT_TOL * target.max(1.0);
        let tol_t = ROOT_TOL * len;
        // Start from the homogeneous guess: exact when the field is constant.
        let mut s = if total.is_finite() && total > 0.0 {
            (len * target / total).clamp(0.0, len)
        } else {
            0.5 * len
        };
        for _ in 0..MAX_ROOT_ITERS {
            let f = self.tau(p0, d, s) - target;
            if f.abs() <= tol_tau {
                return s;
            }
            if f < 0.0 {
                lo = s;
            } else {
                hi = s;
            }
            if hi - lo <= tol_t {
                return 0.5 * (lo + hi);
            }
            let newton = match self.field.extinction(p0 + d * s) {
                Some(sig) if sig > 0.0 && sig.is_finite() => s - f / sig,
                _ => f64::NAN,
            };
            s = if newton > lo && newton < hi {
                newton
            } else {
                0.5 * (lo + hi)
            };
        }
        0.5 * (lo + hi)
    }
}

impl<A: AnalyticOpticalDepth + ?Sized> TransportEstimator for ClosedFormTracker<A> {
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
        let r = prepare(o, d, t_max)?;
        // Draw before clipping so that the stream advances the same way on every valid ray.
        let target = rng.next_exp();
        let (t0, t1) = clip_box(r.o, r.d, &self.lo, &self.hi, 0.0, r.t_max)?;
        let p0 = r.o + r.d * t0;
        let len = t1 - t0;
        let total = self.tau(p0, r.d, len);
        if !(total > target) {
            return None;
        }
        let s = self.invert(p0, r.d, len, total, target);
        Some((((t0 + s) / r.scale) as f32).clamp(0.0, t_max))
    }

    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, _rng: &mut Pcg32) -> f32 {
        match prepare(o, d, t_max) {
            Some(r) => (-self.optical_depth(r.o, r.d, r.t_max)).exp() as f32,
            None => 1.0,
        }
    }

    fn name(&self) -> String {
        "cosine-closed-form".into()
    }

    /// The field's box: both queries are clipped to it.
    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        Some((self.lo, self.hi))
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The renderer's cosine-noise cube, here with its closed form as the lab's trait.
    pub(crate) use pinrender::testing::CosNoise;

    impl AnalyticOpticalDepth for CosNoise {
        fn bounds(&self) -> ([f64; 3], [f64; 3]) {
            (self.lo, self.hi)
        }
        /// The fixture's own closed form (the sinc form, no division by `w . d`).
        fn optical_depth(&self, o: DVec3, d: DVec3, t: f64) -> f64 {
            CosNoise::optical_depth(self, o, d, t)
        }
        fn extinction(&self, p: DVec3) -> Option<f64> {
            Some(self.sigma(p))
        }
    }

    /// The same field without the Newton derivative (bisection path).
    struct NoDeriv(Arc<CosNoise>);
    impl AnalyticOpticalDepth for NoDeriv {
        fn bounds(&self) -> ([f64; 3], [f64; 3]) {
            (self.0.lo, self.0.hi)
        }
        fn optical_depth(&self, o: DVec3, d: DVec3, t: f64) -> f64 {
            self.0.optical_depth(o, d, t)
        }
    }

    /// Composite 5-point Gauss-Legendre quadrature of the extinction.
    fn quadrature(f: &CosNoise, o: DVec3, d: DVec3, t: f64, panels: usize) -> f64 {
        const X: [f64; 5] = [
            0.0,
            -0.538_469_310_105_683,
            0.538_469_310_105_683,
            -0.906_179_845_938_664,
            0.906_179_845_938_664,
        ];
        const W: [f64; 5] = [
            0.568_888_888_888_889,
            0.478_628_670_499_366,
            0.478_628_670_499_366,
            0.236_926_885_056_189,
            0.236_926_885_056_189,
        ];
        let h = t / panels as f64;
        let mut acc = 0.0;
        for i in 0..panels {
            let c = (i as f64 + 0.5) * h;
            for k in 0..5 {
                acc += W[k] * 0.5 * h * f.sigma(o + d * (c + 0.5 * h * X[k]));
            }
        }
        acc
    }

    fn rand_dir(rng: &mut Pcg32) -> DVec3 {
        let z = 2.0 * rng.next_f64() - 1.0;
        let phi = std::f64::consts::TAU * rng.next_f64();
        let r = (1.0 - z * z).sqrt();
        DVec3::new(r * phi.cos(), r * phi.sin(), z)
    }

    #[test]
    fn closed_form_matches_quadrature() {
        let f = CosNoise::new(24, 40.0, 3.0, 11);
        let mut rng = Pcg32::new(3, 4);
        let mut worst = 0.0f64;
        for i in 0..300 {
            let o = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64());
            let d = match i % 3 {
                0 => rand_dir(&mut rng),
                // Exactly perpendicular to one wave vector: b = w . d = 0 (up to rounding).
                1 => {
                    let w = f.waves[i % f.waves.len()].0;
                    w.cross(rand_dir(&mut rng)).normalize()
                }
                // Nearly perpendicular: b of order 1e-9 |w|.
                _ => {
                    let w = f.waves[i % f.waves.len()].0;
                    let p = w.cross(rand_dir(&mut rng)).normalize();
                    (p + w.normalize() * 1e-9).normalize()
                }
            };
            let t = 0.05 + 1.5 * rng.next_f64();
            let exact = f.optical_depth(o, d, t);
            let q = quadrature(&f, o, d, t, 400);
            let rel = (exact - q).abs() / q.abs().max(1e-300);
            worst = worst.max(rel);
            assert!(rel < 1e-6, "segment {i}: closed {exact} vs quadrature {q}");
        }
        // Zero-length and degenerate inputs stay finite.
        assert_eq!(f.optical_depth(DVec3::ZERO, DVec3::X, 0.0), 0.0);
        eprintln!("closed form vs quadrature: worst relative error {worst:e}");
    }

    #[test]
    fn transmittance_is_exact_and_clipped() {
        let f = Arc::new(CosNoise::new(8, 10.0, 2.0, 5));
        let tr = ClosedFormTracker::new(f.clone()).unwrap();
        let mut rng = Pcg32::new(0, 0);
        // From outside the box along x: clipped to [1, 2] in t.
        let o = Vec3::new(-1.0, 0.3, 0.6);
        let got = tr.transmittance(o, Vec3::X, f32::INFINITY, &mut rng) as f64;
        let want = (-f.optical_depth(DVec3::new(0.0, 0.3, 0.6), DVec3::X, 1.0)).exp();
        assert!((got - want).abs() < 1e-6 * want);
        // Non-unit direction: t is in units of |d|.
        let got2 = tr.transmittance(o, Vec3::X * 2.0, 0.75, &mut rng) as f64;
        let want2 = (-f.optical_depth(DVec3::new(0.0, 0.3, 0.6), DVec3::X, 0.5)).exp();
        assert!((got2 - want2).abs() < 1e-6 * want2);
        // Invalid rays are no medium; missing the box is transmittance 1.
        assert_eq!(tr.transmittance(Vec3::NAN, Vec3::X, 1.0, &mut rng), 1.0);
        assert_eq!(tr.transmittance(o, Vec3::ZERO, 1.0, &mut rng), 1.0);
        assert_eq!(tr.transmittance(o, Vec3::Y, 10.0, &mut rng), 1.0);
        assert_eq!(tr.sample_distance(o, Vec3::Y, 10.0, &mut rng), None);
        assert!(tr.sample_distance(o, Vec3::X, f32::NAN, &mut rng).is_none());
        // Bad boxes are errors, not panics.
        let mut bad = CosNoise::new(1, 1.0, 1.0, 1);
        bad.hi = [f64::NAN; 3];
        assert!(ClosedFormTracker::new(Arc::new(bad)).is_err());
    }

    /// One-sample Kolmogorov-Smirnov test of the sampled distances against the exact CDF
    /// `F(t) = 1 - exp(-tau(t))` on `[0, L)`, the no-collision outcome being an atom at
    /// `+inf` of mass `exp(-tau(L))`. With an atom the KS test is conservative. Significance
    /// 0.001: critical value `1.949 / sqrt(n)`.
    fn ks(tracker: &dyn TransportEstimator, f: &CosNoise, o: DVec3, d: DVec3, seed: u64) {
        let n = 20_000usize;
        let mut rng = Pcg32::new(seed, 1);
        let mut ts: Vec<f64> = (0..n)
            .filter_map(|_| {
                tracker
                    .sample_distance(o.as_vec3(), d.as_vec3(), f32::INFINITY, &mut rng)
                    .map(|t| t as f64)
            })
            .collect();
        ts.sort_by(f64::total_cmp);
        let (t0, t1) = clip_box(o, d, &f.lo, &f.hi, 0.0, f64::INFINITY).unwrap();
        let p0 = o + d * t0;
        let cdf = |t: f64| 1.0 - (-f.optical_depth(p0, d, (t - t0).max(0.0))).exp();
        let mut dmax = 0.0f64;
        for (i, &t) in ts.iter().enumerate() {
            let c = cdf(t);
            dmax = dmax.max((c - i as f64 / n as f64).abs());
            dmax = dmax.max(((i + 1) as f64 / n as f64 - c).abs());
        }
        // Just below the exit: the collided fraction against 1 - exp(-tau(L)).
        dmax = dmax.max((ts.len() as f64 / n as f64 - cdf(t1)).abs());
        let crit = 1.949 / (n as f64).sqrt();
        assert!(
            dmax < crit,
            "{}: KS D = {dmax} >= {crit} (collided {})",
            tracker.name(),
            ts.len()
        );
    }

    #[test]
    fn distance_samples_follow_the_exact_cdf() {
        let f = Arc::new(CosNoise::new(12, 25.0, 1.5, 9));
        let newton = ClosedFormTracker::new(f.clone()).unwrap();
        let bisect = ClosedFormTracker::new(Arc::new(NoDeriv(f.clone()))).unwrap();
        let rays = [
            (DVec3::new(-0.5, 0.4, 0.5), DVec3::X),
            (DVec3::splat(-0.1), DVec3::ONE.normalize()),
            (
                DVec3::new(0.5, 0.5, 0.5),
                DVec3::new(0.2, -1.0, 0.3).normalize(),
            ),
        ];
        for (i, (o, d)) in rays.into_iter().enumerate() {
            ks(&newton, &f, o, d, 100 + i as u64);
            ks(&bisect, &f, o, d, 200 + i as u64);
        }
    }

    #[test]
    fn root_finder_meets_its_tolerance() {
        let f = Arc::new(CosNoise::new(24, 60.0, 4.0, 2));
        for tracker in [
            &ClosedFormTracker::new(f.clone()).unwrap() as &dyn Inv,
            &ClosedFormTracker::new(Arc::new(NoDeriv(f.clone()))).unwrap(),
        ] {
            let (o, d) = (
                DVec3::new(0.0, 0.2, 0.7),
                DVec3::new(1.0, 0.3, -0.2).normalize(),
            );
            let (t0, t1) = clip_box(o, d, &f.lo, &f.hi, 0.0, f64::INFINITY).unwrap();
            let p0 = o + d * t0;
            let total = f.optical_depth(p0, d, t1 - t0);
            for k in 1..50 {
                let target = total * k as f64 / 50.0;
                let s = tracker.inv(p0, d, t1 - t0, total, target);
                let err = (f.optical_depth(p0, d, s) - target).abs();
                assert!(err <= 10.0 * ROOT_TOL * target.max(1.0) + 1e-12, "{err}");
            }
        }
    }

    trait Inv {
        fn inv(&self, p0: DVec3, d: DVec3, len: f64, total: f64, target: f64) -> f64;
    }
    impl<A: AnalyticOpticalDepth + ?Sized> Inv for ClosedFormTracker<A> {
        fn inv(&self, p0: DVec3, d: DVec3, len: f64, total: f64, target: f64) -> f64 {
            self.invert(p0, d, len, total, target)
        }
    }
}
