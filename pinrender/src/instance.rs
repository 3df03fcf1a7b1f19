//! Instances: one asset's medium placed many times by a local-to-world transform each
//! (translation, rotation, non-uniform scale), without copying or rebuilding the asset.
//!
//! Every query of an instance is asked in the asset's own frame: the ray is mapped there
//! (`o_l = A o + b`, `d_l = A d` with `A` the inverse of the transform's linear part), its
//! direction normalised, the segment's length scaled by `|d_l|`, and a sampled distance is
//! mapped back by the same factor. Optical depth is therefore the asset's along the mapped
//! ray: a transform moves, turns and stretches a volume with its extinction carried along
//! (stretched twice as long, a ray through it meets the same optical depth). That is how a
//! pin grid's own `local_to_world` already works (`pinrt::chord::UnitTransform` keeps the
//! ray parameter), so pins and trackers agree on every instance.
//!
//! A pin grid is placed by composing the transforms (its sampler maps rays itself, and the
//! wavefront loop still batches instances that share a grid); every other estimator is
//! wrapped in [`PlacedEstimator`], which shares the asset's estimator, majorants and density
//! between all its instances.

use std::sync::Arc;

use glam::{DVec3, Vec3};
use pinrt::SamplerOptions;

use crate::render::{Medium, Pcg32, PinsEstimator, RenderError, TransportEstimator};

/// `a * b` for row-major 3x4 affine maps (apply `b`, then `a`).
pub fn compose(a: &[f64; 12], b: &[f64; 12]) -> [f64; 12] {
    let mut out = [0.0; 12];
    for i in 0..3 {
        for j in 0..4 {
            let mut v = (0..3).map(|k| a[4 * i + k] * b[4 * k + j]).sum::<f64>();
            if j == 3 {
                v += a[4 * i + 3];
            }
            out[4 * i + j] = v;
        }
    }
    out
}

/// The inverse of a row-major 3x4 affine map, or `None` when it is singular.
pub fn invert(m: &[f64; 12]) -> Option<[f64; 12]> {
    // The inverse the pin sampler's own placement uses (`pinrt::UnitTransform`), so the two
    // agree bit for bit.
    let (det, inv) = pinrt::chord::linear_inverse(m);
    if !(det.is_finite() && det != 0.0) {
        return None;
    }
    let t = [m[3], m[7], m[11]];
    let mut out = [0.0; 12];
    for i in 0..3 {
        out[4 * i..4 * i + 3].copy_from_slice(&inv[i]);
        out[4 * i + 3] = -(inv[i][0] * t[0] + inv[i][1] * t[1] + inv[i][2] * t[2]);
    }
    out.iter().all(|x| x.is_finite()).then_some(out)
}

/// The world box of the local box `(lo, hi)` placed by `m`: the box of its eight corners.
pub fn world_box(m: &[f64; 12], (lo, hi): ([f64; 3], [f64; 3])) -> ([f64; 3], [f64; 3]) {
    let mut out = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for corner in 0..8 {
        let p = [0, 1, 2].map(|k| if corner >> k & 1 == 0 { lo[k] } else { hi[k] });
        for i in 0..3 {
            let w = m[4 * i] * p[0] + m[4 * i + 1] * p[1] + m[4 * i + 2] * p[2] + m[4 * i + 3];
            out.0[i] = out.0[i].min(w);
            out.1[i] = out.1[i].max(w);
        }
    }
    out
}

/// An estimator of the asset's frame answering world queries of one instance.
pub struct PlacedEstimator {
    inner: Arc<dyn TransportEstimator>,
    /// World to the asset's frame, rows `(A_i0, A_i1, A_i2, b_i)`, in f32 as rays are.
    to_local: [[f32; 4]; 3],
    /// The linear part is the identity: directions and lengths are kept as they are, and a
    /// translated instance answers with the asset's own bits along the shifted ray.
    translation_only: bool,
    bounds: Option<([f64; 3], [f64; 3])>,
}

impl PlacedEstimator {
    /// `inner` (which answers in the asset's frame) placed by `local_to_world`.
    pub fn new(
        inner: Arc<dyn TransportEstimator>,
        local_to_world: &[f64; 12],
    ) -> Result<Self, RenderError> {
        let invalid = |why: String| RenderError::Invalid {
            what: "instance transform",
            why,
        };
        let inv = invert(local_to_world).ok_or_else(|| invalid("it is singular".into()))?;
        let mut to_local = [[0.0f32; 4]; 3];
        for (i, row) in to_local.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = inv[4 * i + j] as f32;
                if !v.is_finite() {
                    return Err(invalid("its inverse overflows f32".into()));
                }
            }
        }
        Ok(PlacedEstimator {
            translation_only: is_translation(local_to_world),
            bounds: inner.bounds().map(|b| world_box(local_to_world, b)),
            inner,
            to_local,
        })
    }

    /// The ray in the asset's frame, unit direction, and the factor `|d_l|` from world to
    /// local lengths; `None` when the mapped direction is degenerate in f32.
    fn local(&self, o: Vec3, d: Vec3) -> Option<(Vec3, Vec3, f32)> {
        let r = &self.to_local;
        if self.translation_only {
            return Some((o + Vec3::new(r[0][3], r[1][3], r[2][3]), d, 1.0));
        }
        let row = |i: usize| Vec3::new(r[i][0], r[i][1], r[i][2]);
        let o_l = Vec3::new(
            row(0).dot(o) + r[0][3],
            row(1).dot(o) + r[1][3],
            row(2).dot(o) + r[2][3],
        );
        let d_l = Vec3::new(row(0).dot(d), row(1).dot(d), row(2).dot(d));
        let k = d_l.length();
        (k > 0.0 && k.is_finite()).then(|| (o_l, d_l / k, k))
    }

    /// A local distance mapped back to the world, kept below `t_max` (rounding must not
    /// place a collision at or past the segment's end).
    fn back(t_local: f32, k: f32, t_max: f32) -> f32 {
        (t_local / k).min(f32_before(t_max))
    }
}

/// The largest f32 below `x` (for a positive finite `x`), `x` otherwise.
fn f32_before(x: f32) -> f32 {
    if x.is_finite() && x > 0.0 {
        f32::from_bits(x.to_bits() - 1)
    } else {
        x
    }
}

impl TransportEstimator for PlacedEstimator {
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
        let (o_l, d_l, k) = self.local(o, d)?;
        self.inner
            .sample_distance(o_l, d_l, t_max * k, rng)
            .map(|t| Self::back(t, k, t_max))
    }

    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32 {
        match self.local(o, d) {
            Some((o_l, d_l, k)) => self.inner.transmittance(o_l, d_l, t_max * k, rng),
            None => 1.0,
        }
    }

    fn transmittance_and_distance(
        &self,
        o: Vec3,
        d: Vec3,
        t_max: f32,
        rng: &mut Pcg32,
    ) -> (f32, Option<f32>) {
        match self.local(o, d) {
            Some((o_l, d_l, k)) => {
                let (t, dist) = self
                    .inner
                    .transmittance_and_distance(o_l, d_l, t_max * k, rng);
                (t, dist.map(|x| Self::back(x, k, t_max)))
            }
            None => (1.0, None),
        }
    }

    fn name(&self) -> String {
        format!("{} (placed)", self.inner.name())
    }

    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        self.bounds
    }
}

/// One estimator of an asset's medium placed by `local_to_world`: a pin grid by composing
/// its placement (so that it stays a pin grid for the wavefront loop's batches), anything
/// else wrapped in a [`PlacedEstimator`].
pub fn place_estimator(
    e: &Arc<dyn TransportEstimator>,
    local_to_world: &[f64; 12],
    lookup: SamplerOptions,
) -> Result<Arc<dyn TransportEstimator>, RenderError> {
    Ok(
        match e.as_any().and_then(|a| a.downcast_ref::<PinsEstimator>()) {
            Some(p) => Arc::new(PinsEstimator::new(
                p.grid().clone(),
                Some(&compose(local_to_world, p.placement())),
                lookup,
            )?),
            None => Arc::new(PlacedEstimator::new(e.clone(), local_to_world)?),
        },
    )
}

/// An asset's medium (built once, in the asset's frame) placed as one instance.
pub fn place_medium(
    asset: &Medium,
    local_to_world: &[f64; 12],
    lookup: SamplerOptions,
) -> Result<Medium, RenderError> {
    if *local_to_world == pin_format::IDENTITY_LOCAL_TO_WORLD {
        return Ok(Medium::new(asset.primary.clone(), asset.secondary.clone()));
    }
    let primary = place_estimator(&asset.primary, local_to_world, lookup)?;
    let secondary = if Arc::ptr_eq(&asset.primary, &asset.secondary) {
        primary.clone()
    } else {
        place_estimator(&asset.secondary, local_to_world, lookup)?
    };
    Ok(Medium::new(primary, secondary))
}

/// Whether `m` only translates (its linear part is exactly the identity).
pub fn is_translation(m: &[f64; 12]) -> bool {
    let id = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let l = [m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]];
    l == id
}

/// The translation part of `m`.
pub fn translation(m: &[f64; 12]) -> DVec3 {
    DVec3::new(m[3], m[7], m[11])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{Aabb, Density, HomogeneousBox, MajorantGrid, RatioTracking};

    fn trs(t: [f64; 3], deg_z: f64, s: [f64; 3]) -> [f64; 12] {
        let (sin, cos) = deg_z.to_radians().sin_cos();
        [
            cos * s[0],
            -sin * s[1],
            0.0,
            t[0],
            sin * s[0],
            cos * s[1],
            0.0,
            t[1],
            0.0,
            0.0,
            s[2],
            t[2],
        ]
    }

    #[test]
    fn compose_and_invert_are_the_maps() {
        let a = trs([1.0, 2.0, 3.0], 30.0, [2.0, 0.5, 3.0]);
        let b = trs([-4.0, 0.0, 1.0], -75.0, [1.5, 1.0, 0.25]);
        let ab = compose(&a, &b);
        let apply = |m: &[f64; 12], p: [f64; 3]| {
            [0, 1, 2]
                .map(|i| m[4 * i] * p[0] + m[4 * i + 1] * p[1] + m[4 * i + 2] * p[2] + m[4 * i + 3])
        };
        let p = [0.3, -1.7, 2.2];
        let want = apply(&a, apply(&b, p));
        let got = apply(&ab, p);
        let back = apply(&invert(&ab).unwrap(), got);
        for k in 0..3 {
            assert!((want[k] - got[k]).abs() < 1e-12);
            assert!((back[k] - p[k]).abs() < 1e-12);
        }
        let mut singular = a;
        singular[10] = 0.0;
        assert!(invert(&singular).is_none());
        assert!(is_translation(&trs([5.0, 6.0, 7.0], 0.0, [1.0; 3])));
        assert!(!is_translation(&a));
    }

    /// A unit cube of extinction 2 stretched 3x along x, turned 90 degrees about z (so the
    /// stretched axis runs along world y) and moved: a ray along world y through it crosses
    /// 3 units of world length and the cube's unit of optical depth 2: T = exp(-2).
    #[test]
    fn a_stretched_turned_instance_keeps_its_optical_depth() {
        let field: Arc<dyn Density> =
            Arc::new(HomogeneousBox::new(Aabb::new(DVec3::ZERO, DVec3::ONE), 2.0).unwrap());
        let majorants = Arc::new(MajorantGrid::from_field(&*field, [2; 3]).unwrap());
        let inner: Arc<dyn TransportEstimator> = Arc::new(RatioTracking::new(field, majorants));
        let m = trs([10.0, 20.0, 30.0], 90.0, [3.0, 1.0, 1.0]);
        let placed = PlacedEstimator::new(inner, &m).unwrap();
        let (lo, hi) = placed.bounds().unwrap();
        // x in [9, 10], y in [20, 23], z in [30, 31].
        let want = ([9.0, 20.0, 30.0], [10.0, 23.0, 31.0]);
        for k in 0..3 {
            assert!((lo[k] - want.0[k]).abs() < 1e-12 && (hi[k] - want.1[k]).abs() < 1e-12);
        }
        let o = Vec3::new(9.5, 15.0, 30.5);
        let d = Vec3::Y;
        let mut rng = Pcg32::new(7, 1);
        let n = 20_000;
        let (mut sum_t, mut sum_t2, mut hits, mut sum_dist) = (0.0f64, 0.0f64, 0u32, 0.0f64);
        for _ in 0..n {
            let t = f64::from(placed.transmittance(o, d, 100.0, &mut rng));
            sum_t += t;
            sum_t2 += t * t;
            if let Some(t) = placed.sample_distance(o, d, 100.0, &mut rng) {
                assert!((5.0..8.0).contains(&t), "{t}");
                hits += 1;
                sum_dist += f64::from(t - 5.0);
            }
        }
        // Ratio tracking is unbiased: within 5 standard errors of exp(-2) (its sample
        // variance; a placement that lost the stretch would give exp(-2/3) or exp(-6)).
        let mean_t = sum_t / f64::from(n);
        let se = ((sum_t2 / f64::from(n) - mean_t * mean_t) / f64::from(n)).sqrt();
        assert!(se < 0.01, "{se}");
        assert!(
            (mean_t - (-2.0f64).exp()).abs() < 5.0 * se + 1e-6,
            "{mean_t} +- {se}"
        );
        // Delta tracking's collisions: P(hit) = 1 - e^-2 (binomial sd 0.0023 at n = 20,000,
        // 5 sd allowed), and the world depth of a hit is 3x the local one, whose mean given
        // a hit in [0, 1] at rate 2 is (1 - 3e^-2) / (2 (1 - e^-2)) = 0.3435.
        let p = 1.0 - (-2.0f64).exp();
        let frac = f64::from(hits) / f64::from(n);
        assert!(
            (frac - p).abs() < 5.0 * (p * (1.0 - p) / f64::from(n)).sqrt(),
            "{frac}"
        );
        let mean_local = (1.0 - 3.0 * (-2.0f64).exp()) / (2.0 * p);
        let sd_local = 0.29 / f64::from(hits).sqrt();
        let mean = sum_dist / f64::from(hits) / 3.0;
        assert!(
            (mean - mean_local).abs() < 5.0 * sd_local,
            "{mean} vs {mean_local}"
        );
    }
}
