//! # Whole-volume single scattering in a homogeneous box (`whole-volume`)
//!
//! The collimated-light paper (docs/background.md, sections 4-6)
//! for an axis-aligned homogeneous box lit by the [`Sun`](pinrender::render::Sun):
//!
//! * **Analytic unoccluded single scattering** along a camera ray. For a point `o + t d` in
//!   the box, the distance `L(t)` to the box exit toward the sun is the minimum over the axes
//!   of linear functions of `t`, so it is piecewise linear with at most three pieces (the
//!   paper's trapezoid segments, found here as the lower envelope of the slab-exit lines
//!   instead of by walking the light-view section). On each piece the integrand
//!   `exp(-sigma (t - t_in)) exp(-sigma L(t))` is `exp(-(A + k s))` with slope
//!   `k = sigma (1 + dL/dt)` (the paper's `sigma c`), integrated in closed form as
//!   `h exprel(-k h)` where [`exprel`]`(x) = expm1(x) / x`, stable as `c -> 0`. The naive
//!   `(1 - exp(-k h)) / k` loses all digits there ([`SunPieces::integral_naive`] is kept for
//!   the test that shows it).
//! * **Whole-volume distance sampling**: `t` drawn with density proportional to that
//!   integrand (a piece by its share of the integral, then an inverted exponential inside
//!   it), with its exact PDF. The ratio estimator `f / pdf` of the unoccluded sun term is
//!   then the constant `I_total`: zero variance; only occlusion (other media between the
//!   point and the sun or the camera) is left to Monte Carlo.
//! * [`render_single_scattering`]: a single-scattering renderer for a homogeneous box with
//!   either plain distance sampling or whole-volume sampling, for the equal-time comparison.
//!
//! **For**: exact single-scattering references for the homogeneous-box scene and a
//! low-variance single-scattering estimator there. **Not for**: heterogeneous media, non-box
//! shapes, multiple scattering, or point lights (the sun must be a delta directional light).
//!
//! ## `render_single_scattering` semantics
//!
//! The box is the only scattering medium (albedo and `g` from the [`Scene`]). `scene.media`
//! are **occluders**: only their transmittance is used (the ratio term `V` of the paper),
//! estimated with their `primary` estimators, on the camera segment up to the scattering
//! point and on the shadow ray. A pixel gets `env * T` (exact box transmittance times the
//! occluders') plus one single-scattering sample: the sun term (next-event estimation) and
//! the environment term (one phase-sampled direction, exact box transmittance), both at the
//! same sampled point. With no occluders this equals the path tracer's `max_bounces = 1`
//! image of a [`HomogeneousBox`](pinrender::render::HomogeneousBox) of the same extinction.

use glam::{DVec3, Vec3};
use pinrender::render::phase::{hg_phase, sample_hg};
use pinrender::render::{
    Budget, Pcg32, RenderError, RenderOutput, RenderSettings, Scene, accumulate, check_box,
    clip_box, exprel,
};
use std::time::Instant;

/// A homogeneous axis-aligned box (the only scattering medium of this module).
#[derive(Clone, Debug)]
pub struct WholeVolumeBox {
    pub min: [f64; 3],
    pub max: [f64; 3],
    /// Extinction per world unit, finite and `>= 0`.
    pub sigma_t: f64,
}

/// One piece of the camera ray: on `[t0, t0 + h]` the integrand is `exp(-(a + k (t - t0)))`.
#[derive(Clone, Copy, Debug, Default)]
struct Piece {
    t0: f64,
    h: f64,
    a: f64,
    k: f64,
    integral: f64,
}

impl Piece {
    /// `integral_0^h exp(-(a + k s)) ds`, factoring out the larger end value so that
    /// `exprel`'s argument is `<= 0` (no overflow for steep rising pieces).
    fn integrate(a: f64, k: f64, h: f64) -> f64 {
        if k >= 0.0 {
            (-a).exp() * h * exprel(-k * h)
        } else {
            (-(a + k * h)).exp() * h * exprel(k * h)
        }
    }
}

/// The piecewise-exponential single-scattering integrand along one camera ray (up to four
/// pieces: three slab-exit lines have at most three crossings).
#[derive(Clone, Debug)]
pub struct SunPieces {
    pieces: [Piece; 4],
    n: usize,
    total: f64,
    /// Camera-ray parameter where the ray enters the box (or its origin, if inside).
    pub t_in: f64,
    /// Camera-ray parameter where the ray leaves the box.
    pub t_out: f64,
    sigma: f64,
}

impl WholeVolumeBox {
    /// Validates the box (finite, `min < max`) and the extinction (finite, `>= 0`).
    pub fn new(min: [f64; 3], max: [f64; 3], sigma_t: f64) -> Result<Self, RenderError> {
        check_box(&min, &max).map_err(|why| RenderError::Invalid {
            what: "whole-volume box",
            why,
        })?;
        if !(sigma_t >= 0.0 && sigma_t.is_finite()) {
            return Err(RenderError::Invalid {
                what: "whole-volume box",
                why: format!("extinction {sigma_t} must be finite and >= 0"),
            });
        }
        Ok(WholeVolumeBox { min, max, sigma_t })
    }

    /// Distance from `p` (inside the box) to the box exit along the unit `sun` direction.
    pub fn exit_distance(&self, p: DVec3, sun: DVec3) -> f64 {
        clip_box(p, sun, &self.min, &self.max, 0.0, f64::INFINITY).map_or(0.0, |(_, t1)| t1)
    }

    /// The camera segment inside the box, `(t_in, t_out)`, for unit `d`.
    pub fn chord(&self, o: DVec3, d: DVec3) -> Option<(f64, f64)> {
        clip_box(o, d, &self.min, &self.max, 0.0, f64::INFINITY)
    }

    /// The integrand `exp(-sigma (t - t_in)) exp(-sigma L(t))` along `o + t d` split into
    /// pieces, for unit `d` and unit `sun` (pointing to the sun). `None` when the ray
    /// misses the box or the inputs are not finite.
    pub fn pieces(&self, o: DVec3, d: DVec3, sun: DVec3) -> Option<SunPieces> {
        if !(o.is_finite() && d.is_finite() && sun.is_finite()) || sun == DVec3::ZERO {
            return None;
        }
        let (t_in, t_out) = self.chord(o, d)?;
        // L(t) = min_a (bound_a - o_a - t d_a) / s_a over the axes the sun direction moves
        // along: line a is alpha_a + beta_a t.
        let mut lines = [(0.0f64, 0.0f64); 3];
        let mut nl = 0;
        for a in 0..3 {
            let s = sun[a];
            if s != 0.0 {
                let b = if s > 0.0 { self.max[a] } else { self.min[a] };
                lines[nl] = ((b - o[a]) / s, -d[a] / s);
                nl += 1;
            }
        }
        let lines = &lines[..nl];
        // Breakpoints: crossings of two lines strictly inside the chord.
        let mut cuts = [t_in, t_out, t_out, t_out, t_out];
        let mut nc = 1;
        for i in 0..nl {
            for j in i + 1..nl {
                let db = lines[i].1 - lines[j].1;
                if db != 0.0 {
                    let t = (lines[j].0 - lines[i].0) / db;
                    if t > t_in && t < t_out {
                        cuts[nc] = t;
                        nc += 1;
                    }
                }
            }
        }
        cuts[nc] = t_out;
        nc += 1;
        cuts[..nc].sort_by(f64::total_cmp);
        let sigma = self.sigma_t;
        let mut out = SunPieces {
            pieces: [Piece::default(); 4],
            n: 0,
            total: 0.0,
            t_in,
            t_out,
            sigma,
        };
        for w in cuts[..nc].windows(2) {
            let (t0, t1) = (w[0], w[1]);
            if !(t1 > t0) {
                continue;
            }
            let mid = 0.5 * (t0 + t1);
            let (al, be) = lines
                .iter()
                .copied()
                .min_by(|x, y| (x.0 + x.1 * mid).total_cmp(&(y.0 + y.1 * mid)))?;
            // Rounding can put the envelope a hair below 0 at the exit; the distance is >= 0.
            let l0 = (al + be * t0).max(0.0);
            let a = sigma * ((t0 - t_in) + l0);
            let k = sigma * (1.0 + be);
            let h = t1 - t0;
            let integral = Piece::integrate(a, k, h);
            out.pieces[out.n] = Piece {
                t0,
                h,
                a,
                k,
                integral,
            };
            out.n += 1;
            out.total += integral;
        }
        (out.n > 0).then_some(out)
    }
}

impl SunPieces {
    /// `integral_{t_in}^{t_out} exp(-sigma (t - t_in)) exp(-sigma L(t)) dt` (stable form).
    pub fn integral(&self) -> f64 {
        self.total
    }

    /// The same with the naive per-piece `exp(-a) (1 - exp(-k h)) / k` (and `h exp(-a)` only
    /// when `k` is exactly 0): what breaks as the slope `c -> 0`. For tests and docs only.
    pub fn integral_naive(&self) -> f64 {
        self.pieces[..self.n]
            .iter()
            .map(|p| {
                if p.k == 0.0 {
                    p.h * (-p.a).exp()
                } else {
                    (-p.a).exp() * (1.0 - (-p.k * p.h).exp()) / p.k
                }
            })
            .sum()
    }

    /// Number of pieces (1 to 4).
    pub fn len(&self) -> usize {
        self.n
    }

    /// Always false: a `SunPieces` has at least one piece.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// The integrand at camera-ray parameter `t` (0 outside `[t_in, t_out]`).
    pub fn integrand(&self, t: f64) -> f64 {
        if !(t >= self.t_in && t <= self.t_out) {
            return 0.0;
        }
        let p = self.pieces[..self.n]
            .iter()
            .rev()
            .find(|p| t >= p.t0)
            .unwrap_or(&self.pieces[0]);
        (-(p.a + p.k * (t - p.t0))).exp()
    }

    /// Density of [`SunPieces::sample`] at `t`.
    pub fn pdf(&self, t: f64) -> f64 {
        if self.total > 0.0 {
            self.integrand(t) / self.total
        } else {
            0.0
        }
    }

    /// Whole-volume distance sample from one uniform `u in [0, 1)`: a piece by its share of
    /// the integral, then `u` rescaled to that piece (the paper's eq. 10) and the piece's
    /// exponential inverted. Returns `(t, pdf(t))`; `None` if the integral is 0.
    pub fn sample(&self, u: f64) -> Option<(f64, f64)> {
        if !(self.total > 0.0) || !self.total.is_finite() {
            return None;
        }
        let target = u.clamp(0.0, 1.0) * self.total;
        let mut acc = 0.0;
        let mut idx = self.n - 1;
        for (i, p) in self.pieces[..self.n].iter().enumerate() {
            if target < acc + p.integral || i + 1 == self.n {
                idx = i;
                break;
            }
            acc += p.integral;
        }
        let p = self.pieces[idx];
        let v = if p.integral > 0.0 {
            ((target - acc) / p.integral).clamp(0.0, 1.0)
        } else {
            0.5
        };
        let s = p.h * invert_exponential(v, -p.k * p.h);
        let t = (p.t0 + s).clamp(p.t0, p.t0 + p.h);
        Some((t, (-(p.a + p.k * (t - p.t0))).exp() / self.total))
    }

    /// The box extinction the pieces were built with.
    pub fn sigma(&self) -> f64 {
        self.sigma
    }
}

/// The fraction `y in [0, 1]` of a piece where the CDF of the density proportional to
/// `exp(x y)` on `[0, 1]` reaches `v`: `y = log1p(v expm1(x)) / x`, stable as `x -> 0` (then
/// `y -> v`) and, for large positive `x` where `expm1` overflows, rewritten as
/// `1 + ln(v + (1 - v) exp(-x)) / x`.
#[inline]
fn invert_exponential(v: f64, x: f64) -> f64 {
    let y = if x == 0.0 {
        v
    } else if x <= 1.0 {
        (v * x.exp_m1()).ln_1p() / x
    } else {
        1.0 + (v + (1.0 - v) * (-x).exp()).ln() / x
    };
    if y.is_nan() { v } else { y.clamp(0.0, 1.0) }
}

/// Which distance sampling [`render_single_scattering`] uses for the scattering point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SingleScatterSampling {
    /// Classic distance sampling: `t - t_in ~ Exp(sigma)` in the box (escapes score no
    /// single scattering); the sun term is `albedo phase E exp(-sigma L) V`.
    Distance,
    /// Whole-volume sampling: `t` proportional to the unoccluded sun integrand; the sun term
    /// is `albedo sigma phase E I_total V`.
    WholeVolume,
}

/// Transmittance of the occluders (`scene.media`, primary estimators) along a segment.
fn occluders(scene: &Scene, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32 {
    let mut t = 1.0f32;
    for m in &scene.media {
        t *= m.primary.transmittance(o, d, t_max, rng);
        if t == 0.0 {
            break;
        }
    }
    t
}

/// One pixel sample of [`render_single_scattering`] (see the module docs for what it
/// estimates). Public for tests and callers with their own loops; invalid rays give 0.
pub fn single_scattering_sample(
    scene: &Scene,
    medium: &WholeVolumeBox,
    sampling: SingleScatterSampling,
    o: Vec3,
    d: Vec3,
    rng: &mut Pcg32,
) -> [f32; 3] {
    let d = d.normalize_or_zero();
    if !o.is_finite() || d == Vec3::ZERO {
        return [0.0; 3];
    }
    let (od, dd) = (o.as_dvec3(), d.as_dvec3());
    let sigma = medium.sigma_t;
    let env = Vec3::from_array(scene.env_radiance);
    let albedo = scene.albedo.clamp(0.0, 1.0) as f64;
    let sun = scene.sun.as_ref().and_then(|s| {
        let dir = Vec3::from_array(s.dir).normalize_or_zero();
        (dir != Vec3::ZERO).then(|| (dir, Vec3::from_array(s.radiance)))
    });
    let Some((t_in, t_out)) = medium.chord(od, dd) else {
        return (env * occluders(scene, o, d, f32::INFINITY, rng)).to_array();
    };
    let mut l = env * ((-sigma * (t_out - t_in)).exp() as f32);
    if env != Vec3::ZERO {
        l *= occluders(scene, o, d, f32::INFINITY, rng);
    }
    if albedo <= 0.0 || sigma <= 0.0 {
        return l.to_array();
    }
    // The scattering point and the weight `integrand_without_sun / pdf` of the environment
    // term (`albedo sigma exp(-sigma (t - t_in)) / pdf(t)`), plus the sun term's weight.
    let pieces = sun.and_then(|(s, _)| medium.pieces(od, dd, s.as_dvec3()));
    let u = rng.next_f64();
    let (t, env_w, sun_w) = match (sampling, &pieces) {
        (SingleScatterSampling::WholeVolume, Some(p)) => {
            let Some((t, pdf)) = p.sample(u) else {
                return l.to_array();
            };
            let env_w = albedo * sigma * (-sigma * (t - t_in)).exp() / pdf;
            (t, env_w, albedo * sigma * p.integral())
        }
        // Distance sampling (also the fallback without a sun, where the whole-volume
        // density is undefined).
        _ => {
            let s = -(1.0 - u).ln() / sigma;
            if !(t_in + s < t_out) {
                return l.to_array();
            }
            let t = t_in + s;
            let x = od + dd * t;
            let sun_w = sun.map_or(0.0, |(s, _)| {
                albedo * (-sigma * medium.exit_distance(x, s.as_dvec3())).exp()
            });
            (t, albedo, sun_w)
        }
    };
    let x = o + d * t as f32;
    let cam_v = if scene.media.is_empty() {
        1.0
    } else {
        occluders(scene, o, d, t as f32, rng)
    };
    if let Some((s, rad)) = sun {
        let ph = hg_phase(scene.g, d.dot(s)) as f64;
        if ph > 0.0 && sun_w > 0.0 {
            let v = occluders(scene, x, s, f32::INFINITY, rng);
            l += rad * ((sun_w * ph) as f32 * v * cam_v);
        }
    }
    if env != Vec3::ZERO {
        let w = sample_hg(d, scene.g, rng.next_f32(), rng.next_f32());
        let tr_box = (-sigma * medium.exit_distance(x.as_dvec3(), w.as_dvec3())).exp();
        let v = occluders(scene, x, w, f32::INFINITY, rng);
        l += env * ((env_w * tr_box) as f32 * v * cam_v);
    }
    l.to_array()
}

/// Renders the single scattering of the homogeneous box `medium` (see the module docs) with
/// the chosen distance sampling. Same sample loop, seeds, determinism and budget semantics
/// as [`render`](pinrender::render::render); `settings.max_bounces` is ignored
/// (this is single scattering by construction).
pub fn render_single_scattering(
    scene: &Scene,
    medium: &WholeVolumeBox,
    sampling: SingleScatterSampling,
    settings: &RenderSettings,
) -> Result<RenderOutput, RenderError> {
    scene.validate()?;
    WholeVolumeBox::new(medium.min, medium.max, medium.sigma_t)?;
    if let Budget::Spp(0) = settings.budget {
        return Err(RenderError::Invalid {
            what: "budget",
            why: "0 samples per pixel".into(),
        });
    }
    accumulate(scene, settings, Instant::now(), |o, d, rng| {
        Vec3::from_array(single_scattering_sample(scene, medium, sampling, o, d, rng))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::closed_form::{AnalyticOpticalDepth, ClosedFormTracker};
    use pinrender::render::{
        Aabb, Camera, DeltaTracking, HomogeneousBox, MajorantGrid, Medium, RatioTracking, Sun, rmse,
    };
    use std::sync::Arc;

    fn unit() -> WholeVolumeBox {
        WholeVolumeBox::new([0.0; 3], [1.0, 0.6, 0.8], 2.0).unwrap()
    }

    /// Fine composite Simpson of the integrand by brute force (exit distances per point).
    fn brute(b: &WholeVolumeBox, o: DVec3, d: DVec3, s: DVec3, n: usize) -> f64 {
        let Some((t0, t1)) = b.chord(o, d) else {
            return 0.0;
        };
        let f = |t: f64| {
            let x = o + d * t;
            (-b.sigma_t * ((t - t0) + b.exit_distance(x, s))).exp()
        };
        let h = (t1 - t0) / n as f64;
        let mut acc = f(t0) + f(t1);
        for i in 1..n {
            acc += f(t0 + i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
        }
        acc * h / 3.0
    }

    fn rand_dir(rng: &mut Pcg32) -> DVec3 {
        let z = 2.0 * rng.next_f64() - 1.0;
        let phi = std::f64::consts::TAU * rng.next_f64();
        let r = (1.0 - z * z).sqrt();
        DVec3::new(r * phi.cos(), r * phi.sin(), z)
    }

    #[test]
    fn analytic_integral_matches_quadrature() {
        let b = unit();
        let mut rng = Pcg32::new(1, 1);
        let mut multi = 0;
        for i in 0..200 {
            let o = if i % 2 == 0 {
                DVec3::new(rng.next_f64(), 0.6 * rng.next_f64(), 0.8 * rng.next_f64())
            } else {
                DVec3::new(-1.0, 0.3, 0.4) + rand_dir(&mut rng) * 0.2
            };
            let d = if i % 2 == 0 {
                rand_dir(&mut rng)
            } else {
                (DVec3::new(0.5, 0.3, 0.4) - o).normalize()
            };
            let s = rand_dir(&mut rng);
            let Some(p) = b.pieces(o, d, s) else { continue };
            multi += (p.len() > 1) as usize;
            // Simpson's error is dominated by the kinks of L(t) (slope jumps up to ~400 where
            // the sun grazes a face): O(h^2 jump), below 1e-8 relative with 200000 panels.
            let q = brute(&b, o, d, s, 200_000);
            let rel = (p.integral() - q).abs() / q;
            assert!(
                rel < 1e-7,
                "ray {i}: {} vs {q} ({} pieces)",
                p.integral(),
                p.len()
            );
        }
        assert!(multi > 50, "too few multi-piece rays: {multi}");
        // Axis-parallel sun (two zero components) and camera ray along the sun (c = 0).
        let o = DVec3::new(0.5, 0.3, 0.4);
        for (d, s) in [
            (DVec3::X, DVec3::Y),
            (DVec3::Y, DVec3::Y),
            (DVec3::NEG_Y, DVec3::Y),
        ] {
            let p = b.pieces(o, d, s).unwrap();
            let q = brute(&b, o, d, s, 20_000);
            assert!((p.integral() - q).abs() < 1e-9 * q, "{d} {s}");
        }
        // Misses and bad input are None, not panics.
        assert!(
            b.pieces(DVec3::new(5.0, 5.0, 5.0), DVec3::X, DVec3::Y)
                .is_none()
        );
        assert!(b.pieces(o, DVec3::NAN, DVec3::Y).is_none());
        assert!(b.pieces(o, DVec3::X, DVec3::ZERO).is_none());
        assert!(WholeVolumeBox::new([0.0; 3], [1.0; 3], f64::NAN).is_err());
        assert!(WholeVolumeBox::new([0.0; 3], [0.0; 3], 1.0).is_err());
    }

    /// The naive `(1 - exp(-k h)) / k` against the stable `h exprel(-k h)` as the slope
    /// `c = k / sigma` goes to 0. Prints the table quoted in docs/evaluation.md.
    #[test]
    fn naive_form_breaks_as_slope_vanishes() {
        let (sigma, h) = (2.0f64, 1.0f64);
        eprintln!("| c | naive (1-e^(-kh))/k | stable h*exprel(-kh) | rel. error naive |");
        eprintln!("|---|---|---|---|");
        let mut worst_small = 0.0f64;
        for e in 0..=16 {
            let c = 10f64.powi(-e);
            let k = sigma * c;
            let x = -k * h;
            // Reference: the Taylor series of exprel, converged for |x| <= 2e-3, else
            // expm1/x (the division by x is exact enough).
            let reference = if x.abs() < 2e-3 {
                h * (1.0 + x / 2.0 + x * x / 6.0 + x * x * x / 24.0 + x.powi(4) / 120.0)
            } else {
                h * x.exp_m1() / x
            };
            let naive = (1.0 - (-k * h).exp()) / k;
            let stable = h * exprel(x);
            let rn = (naive - reference).abs() / reference;
            let rs = (stable - reference).abs() / reference;
            eprintln!("| 1e-{e} | {naive:.17e} | {stable:.17e} | {rn:.1e} |");
            assert!(rs < 4e-16, "stable form off at c = {c}: {rs}");
            if e >= 8 {
                worst_small = worst_small.max(rn);
            }
        }
        assert!(
            worst_small > 1e-3,
            "the naive form should break: {worst_small}"
        );
        // Whole rays with the camera looking almost straight at the sun (c ~ angle).
        let b = unit();
        let o = DVec3::new(0.5, 0.01, 0.4);
        for e in [4, 8, 12] {
            let eps = 10f64.powi(-e);
            let s = DVec3::new(eps, 1.0, 0.0).normalize();
            let p = b.pieces(o, DVec3::Y, s).unwrap();
            let q = brute(&b, o, DVec3::Y, s, 2000);
            let (rs, rn) = (
                (p.integral() - q).abs() / q,
                (p.integral_naive() - q).abs() / q,
            );
            eprintln!("camera along the sun, tilt 1e-{e}: stable {rs:.1e}, naive {rn:.1e}");
            assert!(rs < 1e-9);
        }
    }

    /// KS test of whole-volume samples against the CDF from the integrand (numerically
    /// integrated), significance 0.001, on rays with 1, 2 and 3 pieces.
    #[test]
    fn whole_volume_samples_follow_their_pdf() {
        let b = unit();
        let mut rng = Pcg32::new(4, 4);
        let mut tested = [false; 4];
        for _ in 0..400 {
            let o = DVec3::new(rng.next_f64(), 0.6 * rng.next_f64(), 0.8 * rng.next_f64());
            let (d, s) = (rand_dir(&mut rng), rand_dir(&mut rng));
            let Some(p) = b.pieces(o, d, s) else { continue };
            if tested[p.len() - 1] {
                continue;
            }
            tested[p.len() - 1] = true;
            let n = 20_000;
            let mut ts: Vec<f64> = (0..n)
                .map(|_| p.sample(rng.next_f64()).unwrap().0)
                .collect();
            ts.sort_by(f64::total_cmp);
            // CDF by trapezoid on a fine grid, then interpolated.
            let m = 200_000;
            let h = (p.t_out - p.t_in) / m as f64;
            let mut cdf = vec![0.0; m + 1];
            for i in 1..=m {
                let (a, c) = (p.t_in + (i - 1) as f64 * h, p.t_in + i as f64 * h);
                cdf[i] = cdf[i - 1] + 0.5 * h * (p.pdf(a) + p.pdf(c));
            }
            let f = |t: f64| {
                let u = ((t - p.t_in) / h).clamp(0.0, m as f64 - 1e-9);
                let i = u.floor() as usize;
                cdf[i] + (cdf[i + 1] - cdf[i]) * (u - i as f64)
            };
            let mut dmax = 0.0f64;
            for (i, &t) in ts.iter().enumerate() {
                let c = f(t);
                dmax = dmax.max((c - i as f64 / n as f64).abs());
                dmax = dmax.max(((i + 1) as f64 / n as f64 - c).abs());
            }
            assert!(
                dmax < 1.949 / (n as f64).sqrt(),
                "{} pieces: D = {dmax}",
                p.len()
            );
            // The reported pdf matches the integrand's normalisation.
            assert!((cdf[m] - 1.0).abs() < 1e-5, "pdf integrates to {}", cdf[m]);
        }
        assert!(tested[0] && tested[1] && tested[2], "{tested:?}");
        // Sampling helper edge cases.
        assert_eq!(invert_exponential(0.3, 0.0), 0.3);
        assert!((invert_exponential(0.3, 1e-12) - 0.3).abs() < 1e-12);
        assert!(invert_exponential(0.5, 800.0) <= 1.0);
        assert!(invert_exponential(0.5, -800.0) >= 0.0);
    }

    fn scene(media: Vec<Medium>, env: f32) -> Scene {
        Scene {
            camera: Camera {
                origin: [0.5, 0.4, 3.0],
                target: [0.5, 0.3, 0.4],
                vfov_deg: 35.0,
                width: 12,
                height: 10,
            },
            sun: Some(Sun {
                dir: [0.4, 0.8, 0.3],
                radiance: [3.0, 2.0, 1.0],
            }),
            env_radiance: [env; 3],
            albedo: 0.8,
            g: 0.4,
            media,
        }
    }

    fn settings(spp: u32, seed: u64) -> RenderSettings {
        RenderSettings {
            max_bounces: 1,
            seed,
            budget: Budget::Spp(spp),
            threads: None,
        }
    }

    /// Without occluders the whole-volume sun term is exact per sample: it must equal the
    /// path tracer's single scattering (max_bounces = 1, delta + ratio tracking on a
    /// `HomogeneousBox`) within the tracer's confidence bound, pixel by pixel.
    #[test]
    fn matches_the_path_tracer_single_scattering() {
        let b = unit();
        let hb = Arc::new(
            HomogeneousBox::new(Aabb::from_arrays(b.min, b.max), b.sigma_t as f32).unwrap(),
        );
        let maj = Arc::new(MajorantGrid::from_field(&*hb, [1, 1, 1]).unwrap());
        let tracked = Medium::new(
            Arc::new(DeltaTracking::new(hb.clone(), maj.clone())),
            Arc::new(RatioTracking::new(hb, maj)),
        );
        for env in [0.0f32, 0.5] {
            let pt_scene = scene(vec![tracked.clone()], env);
            let wv_scene = scene(vec![], env);
            let frame = wv_scene.camera.frame().unwrap();
            for (px, py) in [(6.0, 5.0), (2.5, 7.5), (9.5, 2.5)] {
                let (o, d) = frame.ray(px, py);
                let mut rng = Pcg32::new(7, 7);
                let n = 100_000;
                let (mut s, mut s2) = (0.0, 0.0);
                for _ in 0..n {
                    let v = pt_scene.radiance(o, d, 1, &mut rng)[0] as f64;
                    s += v;
                    s2 += v * v;
                }
                let m = s / n as f64;
                let se = ((s2 / n as f64 - m * m) / n as f64).sqrt();
                for sampling in [
                    SingleScatterSampling::WholeVolume,
                    SingleScatterSampling::Distance,
                ] {
                    let (mut w, mut w2) = (0.0, 0.0);
                    let nw = 20_000;
                    for _ in 0..nw {
                        let v = single_scattering_sample(&wv_scene, &b, sampling, o, d, &mut rng)[0]
                            as f64;
                        w += v;
                        w2 += v * v;
                    }
                    let mw = w / nw as f64;
                    let sew = ((w2 / nw as f64 - mw * mw) / nw as f64).max(0.0).sqrt();
                    let tol = 5.0 * (se * se + sew * sew).sqrt() + 1e-6;
                    assert!(
                        (mw - m).abs() <= tol,
                        "{sampling:?} env {env} pixel ({px},{py}): {mw} vs tracer {m} +- {se}"
                    );
                    if sampling == SingleScatterSampling::WholeVolume && env == 0.0 {
                        // The sun term is exact: zero variance up to f32 rounding.
                        assert!(sew < 1e-6 * mw.max(1e-6), "se {sew}");
                    }
                }
            }
        }
    }

    /// An analytic homogeneous occluder box (deterministic transmittance), so that the
    /// variance comparison measures the sampling of the scattering point only.
    struct Slab {
        lo: [f64; 3],
        hi: [f64; 3],
        sigma: f64,
    }
    impl AnalyticOpticalDepth for Slab {
        fn bounds(&self) -> ([f64; 3], [f64; 3]) {
            (self.lo, self.hi)
        }
        fn optical_depth(&self, o: DVec3, d: DVec3, t: f64) -> f64 {
            clip_box(o, d, &self.lo, &self.hi, 0.0, t).map_or(0.0, |(a, b)| self.sigma * (b - a))
        }
    }

    fn occluded_scene() -> Scene {
        // A dense bar above the box, between it and the sun: crepuscular shadow inside.
        let bar = Slab {
            lo: [0.35, 0.9, -0.5],
            hi: [0.6, 1.0, 1.5],
            sigma: 30.0,
        };
        let occ = Medium::single(Arc::new(ClosedFormTracker::new(Arc::new(bar)).unwrap()));
        let mut s = scene(vec![occ], 0.0);
        s.camera.width = 24;
        s.camera.height = 20;
        s
    }

    #[test]
    fn whole_volume_beats_distance_sampling_at_equal_spp() {
        let s = occluded_scene();
        let b = WholeVolumeBox::new([0.0; 3], [1.0, 0.6, 0.8], 4.0).unwrap();
        let reference = render_single_scattering(
            &s,
            &b,
            SingleScatterSampling::WholeVolume,
            &settings(4096, 1),
        )
        .unwrap();
        let mut mse = [0.0; 2];
        for (i, sampling) in [
            SingleScatterSampling::Distance,
            SingleScatterSampling::WholeVolume,
        ]
        .into_iter()
        .enumerate()
        {
            let out = render_single_scattering(&s, &b, sampling, &settings(16, 2)).unwrap();
            mse[i] = rmse(&out.image, &reference.image).unwrap().powi(2);
        }
        // Unbiasedness across strategies: a high-spp distance-sampling render agrees.
        let ds_ref =
            render_single_scattering(&s, &b, SingleScatterSampling::Distance, &settings(4096, 3))
                .unwrap();
        let diff = rmse(&ds_ref.image, &reference.image).unwrap().powi(2);
        // Expected MSE of the DS reference is its variance: mse[0] * 16 / 4096.
        assert!(
            diff < 3.0 * mse[0] * 16.0 / 4096.0 + 1e-12,
            "{diff} vs {}",
            mse[0]
        );
        eprintln!(
            "MSE at 16 spp: distance {:.3e}, whole-volume {:.3e}, ratio {:.1}",
            mse[0],
            mse[1],
            mse[0] / mse[1]
        );
        assert!(mse[0] > 1.5 * mse[1], "{mse:?}");
    }
}
