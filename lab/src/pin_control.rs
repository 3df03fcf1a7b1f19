//! `pinurm`: unbiased ray marching around the pins' answer. Pin lookups give the control
//! optical depth of the ray, and the power series of unbiased ray marching
//! ([`crate::comb::series_transmittance`]) corrects `exp(-control)` to the true
//! transmittance with density lookups. The derivation and the measurements are in
//! `docs/final-frames.md`.

use std::sync::Arc;

use glam::Vec3;

use pinrender::render::{
    Density, MajorantGrid, Pcg32, PinsEstimator, PreparedRay, RenderError, TransportEstimator,
    clean, clip_box, prepare,
};

use crate::comb_estimators::Combed;

/// Default comb lookups per longest edge of the majorant box for `pinurm` (the majorant
/// depth rule of [`crate::comb::lookups_for`] raises them in dense media).
pub const PINURM_DEFAULT_LOOKUPS: u32 = 8;

/// Pin queries averaged into the control by default: one answer `t_min^n` is a coarse
/// quantisation of the transmittance (docs/final-frames.md, "Measured"), and a pin query
/// costs far less than a density comb.
pub const PINURM_DEFAULT_PIN_QUERIES: u32 = 8;

/// The pins' answers of one ray are trusted as its control when their optical depths
/// `-ln t` all lie within this range of each other (and none is opaque); otherwise the
/// control is a density comb, as `urm`'s. The series needs a control within about one
/// optical depth of the truth (beyond, its variance grows like `exp(error^2)`), and answers
/// that disagree by more than this say the pins do not resolve the ray.
pub const PINURM_MAX_PIN_SPREAD: f64 = 1.5;

/// Upper bound on [`PinControlledUrm::with_pin_queries`].
pub const PINURM_MAX_PIN_QUERIES: u32 = 1024;

/// Unbiased ray marching whose control optical depth is the pin grid's answer along the
/// ray, for transmittance; delta tracking over the majorants for distances, and ratio
/// tracking's one walk where the path tracer asks both along one ray.
///
/// `urm` spends one of its (on average about 3.4) combs on its control; here the mean of a few
/// pin queries takes its place, and urm's comb only where those answers disagree
/// ([`PINURM_MAX_PIN_SPREAD`]). The series is unbiased for any control that does not
/// depend on the combs that follow it, so the pins' bias does not reach the estimate: it
/// only sets how far the control is from the truth, which is the variance. Measured, the
/// pins are a worse control than urm's comb (`docs/final-frames.md`).
pub struct PinControlledUrm<F: ?Sized = dyn Density> {
    /// The tracker and comb spacing `urm` and `jackknife` share.
    comb: Combed<F>,
    pins: Arc<PinsEstimator>,
    pin_queries: u32,
}

impl<F: Density + ?Sized> PinControlledUrm<F> {
    /// Combs of `lookups` (`1 ..= 2^20`) per longest edge of `majorants`' box over `field`,
    /// controlled by `pins` (placed over the same medium; any placement is unbiased, a
    /// matching one is what makes the control good).
    pub fn new(
        field: Arc<F>,
        majorants: Arc<MajorantGrid>,
        pins: Arc<PinsEstimator>,
        lookups: u32,
    ) -> Result<Self, RenderError> {
        Ok(PinControlledUrm {
            comb: Combed::new(field, majorants, lookups)?,
            pins,
            pin_queries: PINURM_DEFAULT_PIN_QUERIES,
        })
    }

    /// The control from the mean of `n` pin queries (`1 ..= PINURM_MAX_PIN_QUERIES`; each
    /// with its own lookup jitter) instead of [`PINURM_DEFAULT_PIN_QUERIES`].
    pub fn with_pin_queries(mut self, n: u32) -> Result<Self, RenderError> {
        if !(1..=PINURM_MAX_PIN_QUERIES).contains(&n) {
            return Err(RenderError::Invalid {
                what: "pin queries",
                why: format!("{n} pin queries per control must be in 1..={PINURM_MAX_PIN_QUERIES}"),
            });
        }
        self.pin_queries = n;
        Ok(self)
    }

    /// The control optical depth of the ray from the pins: `-ln` of the mean of their
    /// transmittance answers, moved into `[0, majorant depth]`, where the true depth lies (a
    /// clamp towards the truth); `None` when an answer is opaque or the answers' depths
    /// spread over more than [`PINURM_MAX_PIN_SPREAD`]. Each pin query draws its generator
    /// from `rng` as every pin query does. The decision reads the pins alone, so it is
    /// independent of the combs that follow.
    fn control(
        &self,
        o: Vec3,
        d: Vec3,
        t_max: f32,
        maj_depth: f64,
        rng: &mut Pcg32,
    ) -> Option<f64> {
        let (mut sum, mut lo, mut hi) = (0.0f64, f64::INFINITY, 0.0f64);
        for _ in 0..self.pin_queries {
            let t = f64::from(self.pins.transmittance(o, d, t_max, rng));
            sum += t;
            lo = lo.min(t);
            hi = hi.max(t);
        }
        // An opaque (or invalid) answer has no finite depth to agree with.
        if !(lo > 0.0 && hi.is_finite()) {
            return None;
        }
        if hi.ln() - lo.ln() > PINURM_MAX_PIN_SPREAD {
            return None;
        }
        let tau = -(sum / f64::from(self.pin_queries)).ln();
        (!tau.is_nan()).then(|| tau.clamp(0.0, maj_depth))
    }

    /// The estimate over the ray's segment inside the majorant box, with `tail` false for
    /// the truncated series (a mutation the tests catch) and `control` replacing the pins'
    /// control when given (the tests' deliberately wrong controls).
    pub(crate) fn estimate(
        &self,
        r: &PreparedRay,
        (o, d, t_max): (Vec3, Vec3, f32),
        rng: &mut Pcg32,
        tail: bool,
        control: Option<&dyn Fn(f64) -> f64>,
    ) -> f64 {
        let (lo, hi) = self.comb.majorants.bounds();
        let Some((t0, t1)) = clip_box(r.o, r.d, &lo, &hi, 0.0, r.t_max) else {
            return 1.0;
        };
        let len = t1 - t0;
        if !(len > 0.0) {
            return 1.0;
        }
        let maj_depth = self.comb.majorant_depth(r);
        let tau_c = match control {
            Some(f) => Some(f(maj_depth)),
            None => self.control(o, d, t_max, maj_depth, rng),
        };
        let m = crate::comb::lookups_for(len, self.comb.spacing, maj_depth);
        let field = &self.comb.field;
        let mut sigma = |s: f64| clean(field.extinction(r.at(t0 + s).as_dvec3()));
        let mut uniform = || rng.next_f64();
        // Where the pins do not resolve the ray, urm's own control: an independent comb.
        let tau_c = tau_c.unwrap_or_else(|| crate::comb::comb(len, m, uniform(), &mut sigma));
        crate::comb::series_with_tail(tau_c, len, m, &mut sigma, &mut uniform, tail)
    }
}

impl<F: Density + ?Sized> TransportEstimator for PinControlledUrm<F> {
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
        self.comb.tracking.sample_distance(o, d, t_max, rng)
    }

    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32 {
        let Some(r) = prepare(o, d, t_max) else {
            return 1.0;
        };
        let t = self.estimate(&r, (o, d, t_max), rng, true, None);
        if t.is_finite() { t as f32 } else { 0.0 }
    }

    /// Ratio tracking's one walk, as `residual` answers pairs: the path scores `env T` and
    /// continues from the collision, and a transmittance from the same tentative collisions
    /// is correlated with that collision, which cancels much of the variance of the sum; an
    /// independent transmittance would not.
    fn transmittance_and_distance(
        &self,
        o: Vec3,
        d: Vec3,
        t_max: f32,
        rng: &mut Pcg32,
    ) -> (f32, Option<f32>) {
        self.comb
            .tracking
            .transmittance_and_distance(o, d, t_max, rng)
    }

    fn name(&self) -> String {
        format!(
            "pinurm@{}({}, {} pin queries)",
            self.comb.lookups,
            self.comb.dims_label(),
            self.pin_queries
        )
    }

    /// The majorant grid's box: combs and tracking are clipped to it.
    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        Some(self.comb.majorants.bounds())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::closed_form::tests::CosNoise;
    use glam::DVec3;
    use pin_format::Directions;
    use pinrender::render::{Aabb, FnField, HomogeneousBox, RatioTracking, VoxelGrid};
    use pinrender::testing::mean_se;
    use pinrt::testing::random_grid;
    use pinrt::{PinGrid, SamplerOptions};

    /// z-test threshold: about 60 z-scores over this file's tests; a two-sided normal tail
    /// of 4.5 sigma is 7e-6 each, so a false alarm has probability below 1e-3 even before
    /// the fixed seeds make the outcome reproducible.
    const Z: f64 = 4.5;

    /// Pins of random masks and minima over the unit cube: a control that knows nothing of
    /// the medium, so the tests show that the series removes whatever error it has.
    fn random_pins(seed: u32) -> Arc<PinsEstimator> {
        let owned = random_grid(Directions::Octahedral { n: 4 }, [4, 4, 4], 1, false, seed);
        let grid = Arc::new(PinGrid::from_bytes(owned.to_bytes().unwrap()).unwrap());
        Arc::new(PinsEstimator::new(grid, None, SamplerOptions::RENDER).unwrap())
    }

    /// Rays from points of the unit cube in directions uniform on the sphere, every third
    /// cut short at `t_max = 0.35`, and one from outside along +x through the whole cube.
    fn rays(n: usize, seed: u64) -> Vec<(Vec3, Vec3, f32)> {
        let mut rng = Pcg32::new(seed, 1);
        let mut out: Vec<(Vec3, Vec3, f32)> = (0..n)
            .map(|k| {
                let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
                let z = 2.0 * rng.next_f32() - 1.0;
                let phi = std::f32::consts::TAU * rng.next_f32();
                let r = (1.0 - z * z).max(0.0).sqrt();
                let t_max = if k % 3 == 2 { 0.35 } else { f32::INFINITY };
                (o, Vec3::new(r * phi.cos(), r * phi.sin(), z), t_max)
            })
            .collect();
        out.push((Vec3::new(-0.5, 0.45, 0.55), Vec3::X, f32::INFINITY));
        out
    }

    /// The optical depth of `(o, d)` over `[0, t_max]` inside `[lo, hi]` by `depth(p0, d,
    /// len)` of the clipped segment.
    fn clipped_depth(
        (o, d, t_max): (Vec3, Vec3, f32),
        lo: [f64; 3],
        hi: [f64; 3],
        depth: &dyn Fn(DVec3, DVec3, f64) -> f64,
    ) -> f64 {
        let (o, d) = (o.as_dvec3(), d.as_dvec3());
        match clip_box(o, d, &lo, &hi, 0.0, t_max as f64) {
            Some((a, b)) => depth(o + d * a, d, b - a),
            None => 0.0,
        }
    }

    /// Which control the estimator uses in a test.
    #[derive(Clone, Copy, Debug)]
    enum Control {
        /// The pins' answer (the estimator as built).
        Pins,
        /// The exact optical depth of the ray.
        Exact,
        /// The ray's majorant optical depth: far from the truth, but legal.
        Majorant,
    }

    /// Per ray, the z-score and standard error of `n` estimates against `exp(-exact)`.
    fn z_scores(
        est: &PinControlledUrm,
        exact: &dyn Fn((Vec3, Vec3, f32)) -> f64,
        control: Control,
        tail: bool,
        n: usize,
    ) -> Vec<(f64, f64)> {
        let mut rng = Pcg32::new(2026, 12);
        rays(8, 41)
            .into_iter()
            .map(|ray| {
                let tau = exact(ray);
                let exact_control = move |_: f64| tau;
                let majorant_control = |maj: f64| maj;
                let given: Option<&dyn Fn(f64) -> f64> = match control {
                    Control::Pins => None,
                    Control::Exact => Some(&exact_control),
                    Control::Majorant => Some(&majorant_control),
                };
                let r = prepare(ray.0, ray.1, ray.2).unwrap();
                let (m, se) = mean_se(n, || est.estimate(&r, ray, &mut rng, tail, given));
                ((m - (-tau).exp()) / se.max(1e-300), se)
            })
            .collect()
    }

    /// The exact optical depth of a test ray.
    type ExactDepth = Box<dyn Fn((Vec3, Vec3, f32)) -> f64>;

    /// The homogeneous box inside the unit cube (so combs over the cube straddle its faces
    /// and have variance), and the cosine-noise cube, against their closed forms.
    fn closed_form_cases() -> Vec<(&'static str, PinControlledUrm, ExactDepth)> {
        let (lo, hi, sigma) = ([0.2, 0.15, 0.25], [0.8, 0.9, 0.7], 3.0);
        let boxf = Arc::new(HomogeneousBox::new(Aabb::from_arrays(lo, hi), sigma as f32).unwrap());
        let box_maj = Arc::new(MajorantGrid::uniform([0.0; 3], [1.0; 3], sigma as f32).unwrap());
        let box_est: PinControlledUrm =
            PinControlledUrm::new(boxf as Arc<dyn Density>, box_maj, random_pins(3), 4).unwrap();
        let box_tau = move |ray| clipped_depth(ray, lo, hi, &|_, _, len| sigma * len);
        let cos = Arc::new(CosNoise::new(8, 16.0, 4.0, 3));
        let cos_maj = Arc::new(MajorantGrid::from_field(&*cos, [4, 4, 4]).unwrap());
        let cos_est: PinControlledUrm =
            PinControlledUrm::new(cos.clone() as Arc<dyn Density>, cos_maj, random_pins(5), 4)
                .unwrap();
        let cos_tau = move |ray| {
            clipped_depth(ray, [0.0; 3], [1.0; 3], &|p0, d, len| {
                cos.optical_depth(p0, d, len)
            })
        };
        vec![
            ("box", box_est, Box::new(box_tau) as ExactDepth),
            ("cosine", cos_est, Box::new(cos_tau) as ExactDepth),
        ]
    }

    /// Unbiased against the closed forms whatever the control: the random pins' answer, the
    /// exact depth and the majorant depth, on nine rays per medium (inside, cut short, from
    /// outside), 20,000 estimates each, fixed seeds. The exact control also has the lowest
    /// standard error on every ray of the cosine cube: the control sets the variance only.
    #[test]
    fn pinurm_is_unbiased_against_closed_forms() {
        for (name, est, exact) in closed_form_cases() {
            let mut se_of = Vec::new();
            for control in [Control::Pins, Control::Exact, Control::Majorant] {
                let z = z_scores(&est, &*exact, control, true, 20_000);
                assert!(
                    z.iter().all(|(z, _)| z.abs() <= Z),
                    "{name}, control {control:?}: z-scores {z:.2?}"
                );
                se_of.push(z.iter().map(|v| v.1).collect::<Vec<_>>());
            }
            if name == "cosine" {
                for (k, (exact_se, maj_se)) in se_of[1].iter().zip(&se_of[2]).enumerate() {
                    assert!(exact_se < maj_se, "ray {k}: {exact_se} vs {maj_se}");
                }
            }
        }
    }

    /// The mutation the z-tests must catch: the series truncated at its always-taken orders
    /// (no roulette over the higher ones). With the majorant depth as the control (where
    /// the higher orders carry weight) the worst |z| exceeds twice the threshold on both
    /// media.
    #[test]
    fn pinurm_z_test_catches_a_truncated_series() {
        for (name, est, exact) in closed_form_cases() {
            let z = z_scores(&est, &*exact, Control::Majorant, false, 20_000);
            let worst = z.iter().fold(0.0f64, |m, (z, _)| m.max(z.abs()));
            assert!(
                worst > 2.0 * Z,
                "truncated pinurm on {name} passes: {z:.2?}"
            );
        }
    }

    /// A voxel grid of random contrast, against ratio tracking's mean at 64 times the
    /// estimates per ray (a 64-spp reference of each ray, unbiased): two-sample z-tests, with
    /// the pins' control; the truncated series with the majorant control fails them.
    #[test]
    fn pinurm_matches_a_ratio_tracking_reference_on_a_voxel_grid() {
        let dims = [9u32, 7, 8];
        let mut g = Pcg32::new(8, 8);
        let values = (0..dims.iter().product::<u32>())
            .map(|i| 0.5 + (i % 5) as f32 * 1.5 + 4.0 * g.next_f32() * g.next_f32())
            .collect();
        let spacing = [1.0 / 9.0, 1.0 / 7.0, 1.0 / 8.0];
        let field = Arc::new(VoxelGrid::new(dims, [0.0; 3], spacing, values).unwrap());
        let maj = Arc::new(MajorantGrid::from_field(&*field, [3, 3, 3]).unwrap());
        let est: PinControlledUrm = PinControlledUrm::new(
            field.clone() as Arc<dyn Density>,
            maj.clone(),
            random_pins(9),
            4,
        )
        .unwrap();
        let ratio = RatioTracking::new(field as Arc<dyn Density>, maj);
        let n = 10_000;
        let z = |control: Control, tail: bool| -> Vec<f64> {
            let mut rng = Pcg32::new(64, 3);
            rays(8, 17)
                .into_iter()
                .map(|ray| {
                    let (rm, rse) = mean_se(64 * n, || {
                        f64::from(ratio.transmittance(ray.0, ray.1, ray.2, &mut rng))
                    });
                    let majorant_control = |maj: f64| maj;
                    let given: Option<&dyn Fn(f64) -> f64> = match control {
                        Control::Majorant => Some(&majorant_control),
                        _ => None,
                    };
                    let r = prepare(ray.0, ray.1, ray.2).unwrap();
                    let (m, se) = mean_se(n, || est.estimate(&r, ray, &mut rng, tail, given));
                    (m - rm) / se.hypot(rse).max(1e-300)
                })
                .collect()
        };
        let good = z(Control::Pins, true);
        assert!(good.iter().all(|z| z.abs() <= Z), "{good:.2?}");
        let bad = z(Control::Majorant, false);
        assert!(
            bad.iter().any(|z| z.abs() > Z),
            "truncated series passes: {bad:.2?}"
        );
    }

    /// With pins baked from the medium itself (a smooth voxel grid, baked by `pinbake`), the
    /// pins resolve most rays and their control is used (not the comb fallback), and the
    /// estimator is unbiased against a fine midpoint rule on every ray (z-tests, 20,000
    /// estimates, fixed seeds). The pins' own answer, `exp(-control)` without the series,
    /// fails the same z-tests: the test can see the bias that the series removes.
    #[test]
    fn pinurm_with_baked_pins_uses_them_and_is_unbiased() {
        use pin_volume::DenseGrid;
        let dims = [16u32, 12, 14];
        let n = dims.iter().product::<u32>() as usize;
        let values: Vec<f32> = (0..n)
            .map(|i| {
                let (x, y, z) = (i % 16, (i / 16) % 12, i / (16 * 12));
                let f = (x as f32 * 0.4).sin() + (y as f32 * 0.3 + z as f32 * 0.2).cos();
                4.0 + 1.5 * f
            })
            .collect();
        let spacing = [1.0 / 16.0; 3];
        let src = DenseGrid::new(
            dims,
            values.clone(),
            DVec3::from(spacing),
            DVec3::ZERO,
            "smooth",
        )
        .unwrap();
        let opts = pinbake::BakeOptions {
            cells: [8, 6, 7],
            directions: Directions::Octahedral { n: 8 },
            threads: Some(2),
            ..pinbake::BakeOptions::default()
        };
        let (owned, _) = pinbake::bake(&src, &opts, &|_| {}).unwrap();
        let grid = Arc::new(PinGrid::from_bytes(owned.to_bytes().unwrap()).unwrap());
        let pins = Arc::new(PinsEstimator::new(grid, None, SamplerOptions::RENDER).unwrap());
        let field = Arc::new(VoxelGrid::new(dims, [0.0; 3], spacing, values).unwrap());
        let maj = Arc::new(MajorantGrid::from_field(&*field, [4, 4, 4]).unwrap());
        let est: PinControlledUrm =
            PinControlledUrm::new(field.clone() as Arc<dyn Density>, maj, pins, 8).unwrap();
        let (lo, hi) = field.bounds().to_arrays();
        let exact = |ray: (Vec3, Vec3, f32)| {
            clipped_depth(ray, lo, hi, &|p0, d, len| {
                let k = 20_000;
                let h = len / k as f64;
                (0..k)
                    .map(|i| {
                        let p = p0 + d * ((i as f64 + 0.5) * h);
                        f64::from(field.extinction(p.as_vec3().as_dvec3())) * h
                    })
                    .sum()
            })
        };
        let mut rng = Pcg32::new(5, 5);
        let (mut resolved, mut asked) = (0, 0);
        let (mut worst_good, mut worst_pins) = (0.0f64, 0.0f64);
        for ray in rays(8, 23) {
            let tau = exact(ray);
            let r = prepare(ray.0, ray.1, ray.2).unwrap();
            let (m, se) = mean_se(20_000, || est.estimate(&r, ray, &mut rng, true, None));
            let z = (m - (-tau).exp()) / se.max(1e-300);
            assert!(
                z.abs() <= Z,
                "ray {ray:?}: mean {m} vs {}, z {z:.2}",
                (-tau).exp()
            );
            worst_good = worst_good.max(z.abs());
            // The pins' answer alone (where they resolve the ray), against the same truth.
            let maj_depth = est.comb.majorant_depth(&r);
            let mut controls = Vec::new();
            for _ in 0..20_000 {
                asked += 1;
                if let Some(c) = est.control(ray.0, ray.1, ray.2, maj_depth, &mut rng) {
                    resolved += 1;
                    controls.push((-c).exp());
                }
            }
            if controls.len() > 1000 {
                let mut it = controls.iter();
                let (pm, pse) = mean_se(controls.len(), || *it.next().unwrap());
                worst_pins = worst_pins.max(((pm - (-tau).exp()) / pse.max(1e-300)).abs());
            }
        }
        assert!(
            resolved * 2 > asked,
            "the pins resolve only {resolved} of {asked} controls"
        );
        assert!(
            worst_pins > Z,
            "the pins' own answer passes (worst |z| {worst_pins:.1}, series {worst_good:.1})"
        );
    }

    /// Bad rays are no medium, and the transmittance is finite and draws nothing for rays
    /// that miss the majorant box; an opaque voxel gives a finite estimate.
    #[test]
    fn pinurm_survives_bad_rays_and_opaque_media() {
        // An opaque box: the baker's box refuses an infinite density, a closure does not.
        let field = Arc::new(FnField {
            min: [0.0; 3],
            max: [1.0; 3],
            f: |_| f32::INFINITY,
        });
        let maj = Arc::new(MajorantGrid::uniform([0.0; 3], [1.0; 3], f32::MAX).unwrap());
        let est: PinControlledUrm =
            PinControlledUrm::new(field as Arc<dyn Density>, maj, random_pins(1), 4).unwrap();
        let mut rng = Pcg32::new(1, 1);
        let o = Vec3::new(-1.0, 0.5, 0.5);
        for (o, d, t_max) in [
            (o, Vec3::ZERO, 1.0),
            (Vec3::NAN, Vec3::X, 1.0),
            (o, Vec3::X, f32::NAN),
            (o, Vec3::X, -1.0),
        ] {
            assert_eq!(est.transmittance(o, d, t_max, &mut rng), 1.0);
            assert_eq!(est.sample_distance(o, d, t_max, &mut rng), None);
        }
        let before = rng.clone().next_u32();
        assert_eq!(est.transmittance(o, Vec3::Y, f32::INFINITY, &mut rng), 1.0);
        assert_eq!(rng.next_u32(), before);
        let t = est.transmittance(o, Vec3::X, f32::INFINITY, &mut rng);
        assert!(t.is_finite() && t.abs() <= 1e-6, "{t}");
        assert!(
            PinControlledUrm::new(
                Arc::new(HomogeneousBox::new(Aabb::from_arrays([0.0; 3], [1.0; 3]), 1.0).unwrap()),
                Arc::new(MajorantGrid::uniform([0.0; 3], [1.0; 3], 1.0).unwrap()),
                random_pins(1),
                0,
            )
            .is_err()
        );
    }
}
