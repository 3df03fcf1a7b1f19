//! Statistical tests of the estimators and end-to-end tests of the tracer.

use super::*;
use crate::testing::mean_se;
use glam::{DVec3, Vec3};
use std::sync::Arc;

fn unit_box(sigma: f32) -> Arc<HomogeneousBox> {
    Arc::new(HomogeneousBox::new(Aabb::from_arrays([0.0; 3], [1.0; 3]), sigma).unwrap())
}

/// `|mean - expect| <= 5 standard errors` (or 1e-6 when the estimator is deterministic).
fn assert_z(label: &str, (m, se): (f64, f64), expect: f64) {
    let tol = 5.0 * se + 1e-6;
    assert!(
        (m - expect).abs() <= tol,
        "{label}: mean {m} vs {expect} (se {se})"
    );
}

fn estimators(field: Arc<dyn Density>, dims: [u32; 3]) -> Vec<Box<dyn TransportEstimator>> {
    let maj = Arc::new(MajorantGrid::from_field(&*field, dims).unwrap());
    vec![
        Box::new(DeltaTracking::new(field.clone(), maj.clone())),
        Box::new(RatioTracking::new(field, maj)),
    ]
}

#[test]
fn trackers_transmittance_homogeneous() {
    let sigma = 2.0f32;
    for dims in [[1, 1, 1], [16, 16, 16], [3, 1, 7]] {
        for est in estimators(unit_box(sigma), dims) {
            let mut rng = Pcg32::new(1, 2);
            // Through the box along x (chord 1), with a t_max cut inside (0.5), diagonal from
            // inside, and along a face.
            let cases: [(Vec3, Vec3, f32, f64); 4] = [
                (Vec3::new(-1.0, 0.5, 0.5), Vec3::X, f32::INFINITY, 1.0),
                (Vec3::new(-1.0, 0.3, 0.6), Vec3::X, 1.5, 0.5),
                (
                    Vec3::splat(0.5),
                    Vec3::ONE.normalize(),
                    f32::INFINITY,
                    0.5 * 3f64.sqrt(),
                ),
                (Vec3::new(0.0, 0.0, -2.0), Vec3::Z, f32::INFINITY, 1.0),
            ];
            for (o, d, t_max, len) in cases {
                let r = mean_se(20_000, || est.transmittance(o, d, t_max, &mut rng) as f64);
                assert_z(&est.name(), r, (-(sigma as f64) * len).exp());
            }
        }
    }
}

#[test]
fn trackers_transmittance_heterogeneous() {
    // sigma = 1 + 3 x^2 on the unit box: optical depth 2 along x, 2 |d| / d.x diagonally.
    let field: Arc<dyn Density> = Arc::new(FnField {
        min: [0.0; 3],
        max: [1.0; 3],
        f: |p: Vec3| 1.0 + 3.0 * p.x * p.x,
    });
    let d = Vec3::new(1.0, 0.3, 0.2);
    let len = d.length() as f64;
    let d = d.normalize();
    for dims in [[1, 1, 1], [4, 4, 4], [8, 2, 1]] {
        for est in estimators(field.clone(), dims) {
            let mut rng = Pcg32::new(3, 4);
            let r = mean_se(20_000, || {
                est.transmittance(Vec3::new(-0.5, 0.5, 0.5), Vec3::X, f32::INFINITY, &mut rng)
                    as f64
            });
            assert_z(&est.name(), r, (-2.0f64).exp());
            let o = Vec3::new(0.0, 0.2, 0.3);
            let r = mean_se(20_000, || {
                est.transmittance(o, d, f32::INFINITY, &mut rng) as f64
            });
            assert_z(&est.name(), r, (-2.0 * len).exp());
        }
    }
    // Ray marching: midpoint rule error <= h^2 / 24 * max|sigma''| * length = h^2 / 4.
    for rel in [0.2, 0.05, 0.01] {
        let rm = RayMarching::new(field.clone(), rel).unwrap();
        let mut rng = Pcg32::new(0, 0);
        let t = rm.transmittance(Vec3::new(-0.5, 0.5, 0.5), Vec3::X, f32::INFINITY, &mut rng);
        let exact = (-2.0f64).exp();
        let bound = exact * (rel * rel / 4.0) * 1.01 + 1e-6;
        assert!(
            (t as f64 - exact).abs() <= bound,
            "step {rel}: {t} vs {exact}"
        );
    }
}

#[test]
fn zero_and_loose_majorants() {
    // Empty left half: its brick has majorant 0 and is skipped; a right-half brick with a
    // majorant 5x too large stays unbiased.
    let field: Arc<dyn Density> = Arc::new(FnField {
        min: [0.0; 3],
        max: [1.0; 3],
        f: |p: Vec3| if p.x > 0.5 { 2.0 } else { 0.0 },
    });
    let maj =
        Arc::new(MajorantGrid::from_parts([0.0; 3], [1.0; 3], [2, 1, 1], vec![0.0, 10.0]).unwrap());
    let ests: [Box<dyn TransportEstimator>; 2] = [
        Box::new(DeltaTracking::new(field.clone(), maj.clone())),
        Box::new(RatioTracking::new(field.clone(), maj)),
    ];
    for est in &ests {
        let mut rng = Pcg32::new(5, 6);
        let r = mean_se(20_000, || {
            est.transmittance(Vec3::new(-1.0, 0.5, 0.5), Vec3::X, f32::INFINITY, &mut rng) as f64
        });
        assert_z(&est.name(), r, (-1.0f64).exp());
        for _ in 0..1000 {
            if let Some(t) =
                est.sample_distance(Vec3::new(-1.0, 0.5, 0.5), Vec3::X, f32::INFINITY, &mut rng)
            {
                assert!(
                    (1.5..=2.0).contains(&t),
                    "collision at {t} in the empty half"
                );
            }
        }
    }
    // A majorant below the extinction: ratio tracking keeps its (signed) weights unbiased.
    let maj = Arc::new(MajorantGrid::uniform([0.0; 3], [1.0; 3], 1.0).unwrap());
    let rt = RatioTracking::new(unit_box(2.0), maj);
    let mut rng = Pcg32::new(7, 8);
    let r = mean_se(100_000, || {
        rt.transmittance(Vec3::new(-1.0, 0.5, 0.5), Vec3::X, f32::INFINITY, &mut rng) as f64
    });
    assert_z("ratio, low majorant", r, (-2.0f64).exp());
}

/// Chi-square of sampled distances through the homogeneous unit box (entry at t = 1, exit
/// at t = 2) on 20 equal-width bins plus the no-collision outcome.
#[test]
fn distance_samples_are_exponential() {
    let sigma = 2.0f64;
    let field = unit_box(sigma as f32);
    let maj1 = Arc::new(MajorantGrid::from_field(&*field, [1, 1, 1]).unwrap());
    let maj16 = Arc::new(MajorantGrid::from_field(&*field, [16, 16, 16]).unwrap());
    let ests: Vec<Box<dyn TransportEstimator>> = vec![
        Box::new(DeltaTracking::new(field.clone(), maj1)),
        Box::new(DeltaTracking::new(field.clone(), maj16.clone())),
        Box::new(RatioTracking::new(field.clone(), maj16)),
        Box::new(RayMarching::new(field.clone(), 0.03).unwrap()),
    ];
    let bins = 20;
    let n = 100_000;
    let mut p = vec![0.0; bins + 1];
    for (k, pk) in p.iter_mut().enumerate().take(bins) {
        let (a, b) = (k as f64 / bins as f64, (k + 1) as f64 / bins as f64);
        *pk = (-sigma * a).exp() - (-sigma * b).exp();
    }
    p[bins] = (-sigma).exp();
    // Direction (1, 0.1, 0): the chord through the box is 1.005 long; scale the bins.
    let d = Vec3::new(1.0, 0.1, 0.0).normalize();
    let o = Vec3::new(0.0, 0.4, 0.5) - d; // enters the box at t = 1 on the x = 0 face
    let chord = 1.0 / d.x as f64;
    // Adjust expectations for the longer chord.
    for (k, pk) in p.iter_mut().enumerate().take(bins) {
        let (a, b) = (
            k as f64 / bins as f64 * chord,
            (k + 1) as f64 / bins as f64 * chord,
        );
        *pk = (-sigma * a).exp() - (-sigma * b).exp();
    }
    p[bins] = (-sigma * chord).exp();
    for est in &ests {
        let mut rng = Pcg32::new(11, 12);
        let mut counts = vec![0usize; bins + 1];
        for _ in 0..n {
            match est.sample_distance(o, d, f32::INFINITY, &mut rng) {
                None => counts[bins] += 1,
                Some(t) => {
                    let x = (t as f64 - 1.0) / chord;
                    assert!((-1e-5..=1.0 + 1e-5).contains(&x), "{}: t = {t}", est.name());
                    counts[((x * bins as f64) as usize).min(bins - 1)] += 1;
                }
            }
        }
        let chi2: f64 = counts
            .iter()
            .zip(&p)
            .map(|(&c, &pk)| (c as f64 - n as f64 * pk).powi(2) / (n as f64 * pk))
            .sum();
        // 20 degrees of freedom: the 0.9999 quantile is about 52.4.
        assert!(
            chi2 < 52.4,
            "{}: chi2 {chi2}, counts {counts:?}",
            est.name()
        );
    }
}

#[test]
fn invalid_rays_are_no_medium() {
    let field = unit_box(3.0);
    let maj = Arc::new(MajorantGrid::from_field(&*field, [2, 2, 2]).unwrap());
    let ests: Vec<Box<dyn TransportEstimator>> = vec![
        Box::new(DeltaTracking::new(field.clone(), maj.clone())),
        Box::new(RatioTracking::new(field.clone(), maj)),
        Box::new(RayMarching::new(field.clone(), 0.1).unwrap()),
    ];
    let o = Vec3::new(-1.0, 0.5, 0.5);
    let mut rng = Pcg32::new(1, 1);
    for est in &ests {
        for (o, d, t_max) in [
            (o, Vec3::new(f32::NAN, 0.0, 0.0), f32::INFINITY),
            (o, Vec3::ZERO, f32::INFINITY),
            (o, Vec3::X, f32::NAN),
            (o, Vec3::X, 0.0),
            (o, Vec3::X, -1.0),
            (Vec3::splat(f32::INFINITY), Vec3::X, 1.0),
            (o, Vec3::splat(f32::MAX), 1.0),
        ] {
            assert_eq!(
                est.transmittance(o, d, t_max, &mut rng),
                1.0,
                "{}",
                est.name()
            );
            assert_eq!(est.sample_distance(o, d, t_max, &mut rng), None);
        }
        // Non-unit direction: t in units of |d|. Ray marching is exact here.
        if est.name().starts_with("ray") {
            let t = est.transmittance(o, Vec3::X * 4.0, 0.5, &mut rng);
            assert!((t - (-3.0f32).exp()).abs() < 1e-6);
            let d = est.sample_distance(o, Vec3::X * 4.0, f32::INFINITY, &mut rng);
            assert!(d.is_none_or(|t| (0.25..=0.5).contains(&t)));
        }
    }
    // Ray marching with an absurd step count is capped, and bad steps are errors.
    assert!(RayMarching::new(field.clone(), 0.0).is_err());
    assert!(RayMarching::new(field.clone(), f64::NAN).is_err());
    let rm = RayMarching::new(field, 1e-12).unwrap();
    assert!((rm.transmittance(o, Vec3::X, f32::INFINITY, &mut rng) - (-3.0f32).exp()).abs() < 1e-5);
}

// ---------------------------------------------------------------------------------------
// Tracer
// ---------------------------------------------------------------------------------------

fn camera(w: u32, h: u32, vfov: f32) -> Camera {
    Camera {
        origin: [0.0, 0.0, 5.0],
        target: [0.0, 0.0, 0.0],
        vfov_deg: vfov,
        width: w,
        height: h,
    }
}

fn cube(sigma: f32) -> Arc<HomogeneousBox> {
    Arc::new(HomogeneousBox::new(Aabb::from_arrays([-1.0; 3], [1.0; 3]), sigma).unwrap())
}

fn tracked(
    field: Arc<dyn Density>,
    dims: [u32; 3],
) -> (Arc<dyn TransportEstimator>, Arc<dyn TransportEstimator>) {
    let maj = Arc::new(MajorantGrid::from_field(&*field, dims).unwrap());
    (
        Arc::new(DeltaTracking::new(field.clone(), maj.clone())),
        Arc::new(RatioTracking::new(field, maj)),
    )
}

#[test]
fn albedo_zero_gives_env_times_transmittance() {
    let sigma = 1.5f32;
    let field = cube(sigma);
    let rm: Arc<dyn TransportEstimator> = Arc::new(RayMarching::new(field.clone(), 0.01).unwrap());
    let (delta, _) = tracked(field, [4, 4, 4]);
    let env = [0.5f32, 1.0, 2.0];
    let scene = Scene {
        camera: camera(8, 6, 1e-3),
        sun: Some(Sun {
            dir: [0.3, 1.0, 0.2],
            radiance: [10.0; 3],
        }),
        env_radiance: env,
        albedo: 0.0,
        g: 0.5,
        media: vec![Medium::new(rm, delta)],
    };
    // Narrow field of view: every camera ray crosses the cube along z, chord 2.
    let out = render(
        &scene,
        &RenderSettings {
            max_bounces: 8,
            seed: 3,
            budget: Budget::Spp(2),
            threads: Some(1),
        },
    )
    .unwrap();
    let t = (-2.0 * sigma).exp();
    for p in &out.image.rgb {
        for c in 0..3 {
            assert!((p[c] - env[c] * t).abs() <= 1e-5 * env[c], "{p:?}");
        }
    }
    // Arbitrary rays: the chord from a slab test.
    let mut rng = Pcg32::new(4, 4);
    for _ in 0..200 {
        let o = Vec3::new(0.0, 0.0, 4.0) + (Vec3::new(rng.next_f32(), rng.next_f32(), 0.0) - 0.5);
        let target = (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5) * 2.0;
        let d = (target - o).normalize();
        let mut t0 = f32::NEG_INFINITY;
        let mut t1 = f32::INFINITY;
        for a in 0..3 {
            let (n, f) = ((-1.0 - o[a]) / d[a], (1.0 - o[a]) / d[a]);
            t0 = t0.max(n.min(f));
            t1 = t1.min(n.max(f));
        }
        let l = scene.radiance(o, d, 8, &mut rng);
        let expect = (-(sigma * (t1 - t0.max(0.0)).max(0.0))).exp();
        assert!((l[1] - expect).abs() < 1e-5, "{l:?} vs {expect}");
    }
}

/// Single scattering in a wide slab `y in [0, H]` seen straight down, sun at zenith angle
/// alpha: `L = albedo sigma p(-cos alpha) R (1 - exp(-sigma H k)) / (sigma k)`,
/// `k = 1 + 1 / cos alpha` (the camera path to depth s and the sun path s / cos alpha).
#[test]
fn single_scattering_matches_closed_form() {
    let (sigma, h, albedo, g) = (1.0f32, 1.0f64, 0.8f32, 0.3f32);
    let alpha = 40f64.to_radians();
    let sun_dir = [alpha.sin() as f32, alpha.cos() as f32, 0.0];
    let slab = |s: f32| -> Arc<dyn Density> {
        Arc::new(
            HomogeneousBox::new(Aabb::from_arrays([-20.0, 0.0, -20.0], [20.0, h, 20.0]), s)
                .unwrap(),
        )
    };
    let k = 1.0 + 1.0 / alpha.cos();
    let sd = sigma as f64;
    let phase = phase::hg_phase(g, -(alpha.cos() as f32)) as f64;
    let expect = albedo as f64 * sd * phase * (1.0 - (-sd * h * k).exp()) / (sd * k);
    // One slab with delta/ratio; the same slab as two overlapping half-density instances;
    // ray marching.
    let (d1, r1) = tracked(slab(sigma), [4, 2, 4]);
    let (d2, r2) = tracked(slab(sigma / 2.0), [1, 1, 1]);
    let rm: Arc<dyn TransportEstimator> = Arc::new(RayMarching::new(slab(sigma), 0.001).unwrap());
    let cases: Vec<(&str, Vec<Medium>)> = vec![
        ("delta+ratio", vec![Medium::new(d1.clone(), r1.clone())]),
        ("ratio primary", vec![Medium::single(r1)]),
        (
            "two instances",
            vec![Medium::single(d2), Medium::single(r2)],
        ),
        ("ray marching", vec![Medium::single(rm)]),
    ];
    for (label, media) in cases {
        let scene = Scene {
            camera: camera(1, 1, 30.0),
            sun: Some(Sun {
                dir: sun_dir,
                radiance: [1.0; 3],
            }),
            env_radiance: [0.0; 3],
            albedo,
            g,
            media,
        };
        let mut rng = Pcg32::new(21, 22);
        let r = mean_se(100_000, || {
            scene.radiance(Vec3::new(0.0, 3.0, 0.0), Vec3::NEG_Y, 1, &mut rng)[0] as f64
        });
        assert_z(label, r, expect);
    }
}

/// White furnace: albedo 1, constant environment 1, no sun: every path ends by escaping, so
/// the expected radiance is exactly 1 whatever the medium, phase or estimator mix.
#[test]
fn white_furnace() {
    let field: Arc<dyn Density> = Arc::new(FnField {
        min: [-1.0; 3],
        max: [1.0; 3],
        f: |p: Vec3| 2.0 + 1.5 * (3.0 * p.x).sin() * p.y,
    });
    let (delta, ratio) = tracked(field, [4, 4, 4]);
    let (d2, r2) = tracked(cube(0.7), [1, 1, 1]);
    for (g, media) in [
        (0.6f32, vec![Medium::new(ratio.clone(), delta.clone())]),
        (
            -0.3,
            vec![
                Medium::new(delta.clone(), ratio.clone()),
                Medium::new(r2, d2),
            ],
        ),
    ] {
        let scene = Scene {
            camera: camera(1, 1, 30.0),
            sun: None,
            env_radiance: [1.0; 3],
            albedo: 1.0,
            g,
            media,
        };
        let mut rng = Pcg32::new(31, 32);
        let r = mean_se(20_000, || {
            let o = Vec3::new(0.0, 0.0, 4.0);
            let d = (Vec3::new(rng.next_f32(), rng.next_f32(), 0.0) - 0.5 - o).normalize();
            scene.radiance(o, d, 100_000, &mut rng)[2] as f64
        });
        assert_z("furnace", r, 1.0);
    }
}

fn small_scene() -> Scene {
    let field = cube(2.0);
    let (delta, ratio) = tracked(field, [2, 2, 2]);
    Scene {
        camera: camera(24, 16, 35.0),
        sun: Some(Sun {
            dir: [1.0, 1.0, 0.5],
            radiance: [3.0, 2.0, 1.0],
        }),
        env_radiance: [0.2, 0.3, 0.4],
        albedo: 0.9,
        g: 0.4,
        media: vec![Medium::new(delta, ratio)],
    }
}

#[test]
fn image_independent_of_threads_and_budget() {
    let scene = small_scene();
    let settings = |threads, budget| RenderSettings {
        max_bounces: 4,
        seed: 99,
        budget,
        threads,
    };
    let a = render(&scene, &settings(Some(1), Budget::Spp(3))).unwrap();
    let b = render(&scene, &settings(Some(2), Budget::Spp(3))).unwrap();
    assert_eq!(a.spp, 3);
    assert_eq!(a.image, b.image);
    assert!(
        a.image
            .rgb
            .iter()
            .all(|p| p.iter().all(|c| c.is_finite() && *c >= 0.0))
    );
    // Some pixels see the lit medium, corners see only the environment.
    assert!(a.image.rgb.iter().any(|p| p[0] > 0.25));
    assert_eq!(a.image.get(0, 0), Some([0.2, 0.3, 0.4]));

    // Time budget: stops, and equals an spp render with the spp it reached.
    let start = std::time::Instant::now();
    let t = render(&scene, &settings(Some(2), Budget::Seconds(0.2))).unwrap();
    assert!(start.elapsed().as_secs_f64() < 10.0);
    assert!(t.spp >= 1);
    let s = render(&scene, &settings(None, Budget::Spp(t.spp))).unwrap();
    assert_eq!(t.image, s.image);
    let z = render(&scene, &settings(Some(1), Budget::Seconds(0.0))).unwrap();
    assert_eq!(z.spp, 1);
}

#[test]
fn bad_scenes_are_errors() {
    let base = small_scene();
    let ok = RenderSettings {
        max_bounces: 2,
        seed: 1,
        budget: Budget::Spp(1),
        threads: Some(1),
    };
    let mut bad: Vec<Scene> = Vec::new();
    let mut s = base.clone();
    s.camera.width = 0;
    bad.push(s);
    let mut s = base.clone();
    s.camera.origin[1] = f32::NAN;
    bad.push(s);
    let mut s = base.clone();
    s.camera.target = s.camera.origin;
    bad.push(s);
    let mut s = base.clone();
    s.camera.vfov_deg = 180.0;
    bad.push(s);
    let mut s = base.clone();
    s.g = 1.0;
    bad.push(s);
    let mut s = base.clone();
    s.albedo = f32::NAN;
    bad.push(s);
    let mut s = base.clone();
    s.env_radiance = [-1.0, 0.0, 0.0];
    bad.push(s);
    let mut s = base.clone();
    s.sun = Some(Sun {
        dir: [0.0; 3],
        radiance: [1.0; 3],
    });
    bad.push(s);
    for s in &bad {
        assert!(render(s, &ok).is_err());
    }
    for budget in [
        Budget::Spp(0),
        Budget::Seconds(f64::NAN),
        Budget::Seconds(-1.0),
    ] {
        assert!(
            render(
                &base,
                &RenderSettings {
                    budget,
                    ..ok.clone()
                }
            )
            .is_err()
        );
    }
    assert!(
        render(
            &base,
            &RenderSettings {
                threads: Some(0),
                ..ok.clone()
            }
        )
        .is_err()
    );
    // Straight down: the camera frame falls back to +z as up.
    let mut s = base.clone();
    s.camera.origin = [0.0, 5.0, 0.0];
    assert!(render(&s, &ok).is_ok());
    // Invalid rays give 0, no medium gives the environment.
    let mut rng = Pcg32::new(0, 0);
    assert_eq!(
        base.radiance(Vec3::ZERO, Vec3::splat(f32::NAN), 4, &mut rng),
        [0.0; 3]
    );
    let mut empty = base.clone();
    empty.media.clear();
    assert_eq!(
        empty.radiance(Vec3::ZERO, Vec3::X, 4, &mut rng),
        [0.2, 0.3, 0.4]
    );
}

// ---------------------------------------------------------------------------------------
// Skipping media the ray misses (render/bounds.rs, TransportEstimator::bounds)
// ---------------------------------------------------------------------------------------

/// Delegates to an estimator, counting calls; optionally hides its box (the tracer then
/// asks it for every query, as before boxes existed).
struct Probe {
    inner: Arc<dyn TransportEstimator>,
    hide_bounds: bool,
    calls: std::sync::atomic::AtomicUsize,
}

impl Probe {
    fn new(inner: Arc<dyn TransportEstimator>, hide_bounds: bool) -> Arc<Self> {
        Arc::new(Probe {
            inner,
            hide_bounds,
            calls: Default::default(),
        })
    }
    fn calls(&self) -> usize {
        self.calls.load(std::sync::atomic::Ordering::Relaxed)
    }
}

impl TransportEstimator for Probe {
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
        self.calls
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.inner.sample_distance(o, d, t_max, rng)
    }
    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32 {
        self.calls
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.inner.transmittance(o, d, t_max, rng)
    }
    fn name(&self) -> String {
        self.inner.name()
    }
    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        if self.hide_bounds {
            None
        } else {
            self.inner.bounds()
        }
    }
}

fn slab_box(min: [f64; 3], max: [f64; 3], sigma: f32) -> Arc<dyn Density> {
    Arc::new(HomogeneousBox::new(Aabb::from_arrays(min, max), sigma).unwrap())
}

/// Every estimator's box is where its queries are clipped: rays that miss it get
/// transmittance 1 and no collision (the contract that lets the tracer skip them).
#[test]
fn estimator_bounds_contain_everything_they_see() {
    let field: Arc<dyn Density> = Arc::new(FnField {
        min: [1.0, -2.0, 0.5],
        max: [2.0, 0.0, 3.0],
        f: |p: Vec3| 3.0 + p.x.sin(),
    });
    let maj = Arc::new(MajorantGrid::from_field(&*field, [3, 2, 5]).unwrap());
    let ests: Vec<Arc<dyn TransportEstimator>> = vec![
        Arc::new(RayMarching::new(field.clone(), 0.05).unwrap()),
        Arc::new(DeltaTracking::new(field.clone(), maj.clone())),
        Arc::new(RatioTracking::new(field.clone(), maj)),
    ];
    let mut rng = Pcg32::new(8, 9);
    for est in &ests {
        let (lo, hi) = est.bounds().expect("every built-in estimator has a box");
        assert!((0..3).all(|a| lo[a] < hi[a]), "{}", est.name());
        let boxes = super::bounds::MediaBoxes::new([Some((lo, hi))]);
        let (mut missed, mut met) = (0, 0);
        for _ in 0..8000 {
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 12.0 - 6.0;
            // Half of the rays aimed at a point in or near the box (many graze it), half
            // random.
            let u = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 1.2 - 0.1;
            let aim = DVec3::from(lo) + (DVec3::from(hi) - DVec3::from(lo)) * u;
            let d = if rng.next_f32() < 0.5 {
                aim.as_vec3() - o
            } else {
                Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5
            }
            .normalize_or_zero();
            let t_max = if rng.next_f32() < 0.5 {
                f32::INFINITY
            } else {
                4.0 * rng.next_f32()
            };
            let ray = super::bounds::RaySlabs::new(o, d).unwrap();
            if boxes.entry(0, &ray, t_max).is_some() {
                met += 1;
                continue;
            }
            missed += 1;
            assert_eq!(
                est.transmittance(o, d, t_max, &mut rng),
                1.0,
                "{}",
                est.name()
            );
            assert_eq!(
                est.sample_distance(o, d, t_max, &mut rng),
                None,
                "{}",
                est.name()
            );
        }
        assert!(missed > 1000 && met > 1000, "{missed} / {met}");
    }
}

/// Nearest-collision sampling over media asked in box-entry order with early exit
/// (`Ctx::distance`) follows the exact law of the summed extinction, and the media it
/// skips are really not asked.
#[test]
fn culled_distance_sampling_is_exact() {
    // Along +x from x = -1 at y = z = 0.5: A [0,1] sigma 1, B [0.5,1.5] sigma 2,
    // E (no box, tracked in [2,3]) sigma 1, C [10,11] sigma 0.5; D is beside the ray.
    let (da, ra) = tracked(slab_box([0.0; 3], [1.0; 3], 1.0), [2, 1, 1]);
    let (db, _) = tracked(slab_box([0.5, 0.0, 0.0], [1.5, 1.0, 1.0], 2.0), [1, 1, 1]);
    let (de, re) = tracked(slab_box([2.0, 0.0, 0.0], [3.0, 1.0, 1.0], 1.0), [1, 1, 1]);
    let (dc, rc) = tracked(slab_box([10.0, 0.0, 0.0], [11.0, 1.0, 1.0], 0.5), [1, 1, 1]);
    let (dd, _) = tracked(slab_box([0.0, 5.0, 0.0], [1.0, 6.0, 1.0], 3.0), [1, 1, 1]);
    let pe = Probe::new(de, true);
    let pc = Probe::new(dc, false);
    let pd = Probe::new(dd, false);
    // The far box C sits between A and B in the list: asking in list order and stopping at
    // the first box beyond the nearest collision would miss B's collisions inside A.
    let media = vec![
        Medium::new(ra, da),
        Medium::new(rc, pc.clone()),
        Medium::single(db),
        Medium::new(re, pe.clone()),
        Medium::single(pd.clone()),
    ];
    let scene = Scene {
        camera: camera(1, 1, 30.0),
        sun: None,
        env_radiance: [1.0; 3],
        albedo: 1.0,
        g: 0.0,
        media,
    };
    let ctx = scene.ctx(1);
    // Optical depth from the origin (x = -1) to parameter t.
    let tau = |t: f64| {
        let x = t - 1.0;
        let over = |a: f64, b: f64| (x.min(b) - a).max(0.0);
        over(0.0, 1.0) + 2.0 * over(0.5, 1.5) + over(2.0, 3.0) + 0.5 * over(10.0, 11.0)
    };
    let (o, d) = (Vec3::new(-1.0, 0.5, 0.5), Vec3::X);
    let n = 200_000usize;
    let cuts = [0.5, 1.5, 1.75, 2.0, 2.5, 3.5, 4.0, 11.5, 12.0];
    let mut below = [0usize; 9];
    let (mut none, mut reached_c) = (0usize, 0usize);
    let mut rng = Pcg32::new(41, 42);
    for _ in 0..n {
        let t = ctx.distance(super::tracer::Which::Secondary, o, d, &mut rng);
        match t {
            None => none += 1,
            Some(t) => {
                assert!(t.is_finite() && t >= 0.0);
                for (c, k) in cuts.iter().zip(below.iter_mut()) {
                    *k += (t as f64 <= *c) as usize;
                }
            }
        }
        if t.is_none_or(|t| t >= 10.999) {
            reached_c += 1;
        }
    }
    let z = |k: usize, p: f64| (k as f64 / n as f64 - p) / (p * (1.0 - p) / n as f64).sqrt();
    assert_eq!(below[0], 0, "no collision before the first box");
    for (c, k) in cuts.iter().zip(below).skip(1) {
        let p = 1.0 - (-tau(*c)).exp();
        assert!(
            z(k, p).abs() < 5.0,
            "P(t <= {c}): {} vs {p}",
            k as f64 / n as f64
        );
    }
    let p_none = (-tau(12.0)).exp();
    assert!(
        z(none, p_none).abs() < 5.0,
        "P(none) {} vs {p_none}",
        none as f64 / n as f64
    );
    // D is never met; C (entered at t = 11) is asked exactly when nothing collided before
    // it; E has no box (entry 0, first in the order) and is asked every time.
    assert_eq!(pd.calls(), 0);
    assert_eq!(pc.calls(), reached_c);
    assert!(reached_c > 0 && reached_c < n / 20, "{reached_c}");
    assert_eq!(pe.calls(), n);

    // Transmittance: the product over the media met (ratio tracking for A, E and C, delta
    // tracking for B); D is still never asked.
    let r = mean_se(n, || {
        ctx.transmittance(super::tracer::Which::Primary, o, d, &mut rng) as f64
    });
    assert_z("culled transmittance", r, (-tau(12.0)).exp());
    assert_eq!(pd.calls(), 0);
}

/// A scene of many overlapping media plus far-away ones renders the same expectation with
/// and without the boxes (the boxes hidden: every medium asked for every query), for the
/// trackers, ray marching and a PinMS-like primary/secondary split; and skipping does ask
/// fewer media.
#[test]
fn culling_keeps_radiance_unbiased() {
    let blob = |c: Vec3, sigma: f32| -> Arc<dyn Density> {
        let lo = (c - 0.5).as_dvec3().to_array();
        let hi = (c + 0.5).as_dvec3().to_array();
        Arc::new(FnField {
            min: lo,
            max: hi,
            f: move |p: Vec3| {
                let r2 = ((p - c) * 2.0).length_squared();
                if r2 < 1.0 { sigma * (1.0 - r2) } else { 0.0 }
            },
        })
    };
    let mut centres = Vec::new();
    for i in 0..3 {
        for j in 0..3 {
            centres.push(Vec3::new(
                i as f32 * 0.6 - 0.6,
                j as f32 * 0.6 - 0.6,
                0.3 * (i + j) as f32 - 0.6,
            ));
        }
    }
    // Two media far off to the side and one behind the camera.
    centres.push(Vec3::new(30.0, 0.0, 0.0));
    centres.push(Vec3::new(0.0, -40.0, 3.0));
    centres.push(Vec3::new(0.0, 0.0, 20.0));
    let build = |hide: bool, kind: &str| -> (Scene, Vec<Arc<Probe>>) {
        let mut probes = Vec::new();
        let media = centres
            .iter()
            .enumerate()
            .map(|(k, &c)| {
                let field = blob(c, 4.0 + k as f32 * 0.5);
                let (delta, ratio) = tracked(field.clone(), [2, 2, 2]);
                let (p, s): (Arc<dyn TransportEstimator>, Arc<dyn TransportEstimator>) = match kind
                {
                    "trackers" => (ratio, delta),
                    "marching" => {
                        let rm: Arc<dyn TransportEstimator> =
                            Arc::new(RayMarching::new(field, 0.05).unwrap());
                        (rm.clone(), rm)
                    }
                    _ => unreachable!(),
                };
                let (p, s) = (Probe::new(p, hide), Probe::new(s, hide));
                probes.push(p.clone());
                probes.push(s.clone());
                Medium::new(p, s)
            })
            .collect();
        let scene = Scene {
            camera: camera(1, 1, 30.0),
            sun: Some(Sun {
                dir: [0.3, 1.0, 0.4],
                radiance: [2.0; 3],
            }),
            env_radiance: [0.3; 3],
            albedo: 0.9,
            g: 0.3,
            media,
        };
        (scene, probes)
    };
    let calls = |p: &[Arc<Probe>]| p.iter().map(|p| p.calls()).sum::<usize>();
    let rays = [
        (Vec3::new(0.1, 0.2, 5.0), Vec3::new(-0.02, -0.03, -1.0)),
        (Vec3::new(-3.0, 0.9, 0.2), Vec3::new(1.0, -0.1, 0.05)),
        (Vec3::new(0.0, 3.0, 0.0), Vec3::new(0.05, -1.0, 0.02)),
    ];
    let n = 20_000;
    for kind in ["trackers", "marching"] {
        let (culled, pc) = build(false, kind);
        let (full, pf) = build(true, kind);
        for (k, (o, d)) in rays.iter().enumerate() {
            let d = d.normalize();
            let mut rng = Pcg32::new(100 + k as u64, 1);
            let a = mean_se(n, || culled.radiance(*o, d, 6, &mut rng)[0] as f64);
            let mut rng = Pcg32::new(200 + k as u64, 1);
            let b = mean_se(n, || full.radiance(*o, d, 6, &mut rng)[0] as f64);
            let se = (a.1 * a.1 + b.1 * b.1).sqrt();
            assert!(a.0 > 0.01, "{kind} ray {k}: {a:?}");
            assert!(
                (a.0 - b.0).abs() <= 5.0 * se + 1e-6,
                "{kind} ray {k}: culled {a:?} vs every medium {b:?}"
            );
        }
        // Skipping asks fewer media; the far ones (the last three: probes 18..24) only for
        // the rare secondary rays aimed at them, whereas without boxes every query asks
        // every medium.
        assert!(
            calls(&pc) * 4 < calls(&pf) * 3,
            "{kind}: {} calls with boxes, {} without",
            calls(&pc),
            calls(&pf)
        );
        for (c, f) in pc[18..].iter().zip(&pf[18..]) {
            assert!(
                c.calls() * 50 < f.calls(),
                "{kind}: a far medium was asked {} times with boxes, {} without",
                c.calls(),
                f.calls()
            );
        }
    }
}

/// With many media (box tests, entry sorting) the image still does not depend on the
/// thread count.
#[test]
fn many_media_image_independent_of_threads() {
    let mut media = Vec::new();
    for k in 0..70 {
        // More media than one chunk of box tests.
        let c = Vec3::new(
            (k % 5) as f32 * 0.4 - 0.8,
            ((k / 5) % 4) as f32 * 0.4 - 0.6,
            (k / 20) as f32 * 0.4 - 0.6,
        );
        let (lo, hi) = ((c - 0.3).as_dvec3(), (c + 0.3).as_dvec3());
        let (delta, ratio) = tracked(slab_box(lo.to_array(), hi.to_array(), 0.8), [1, 1, 1]);
        media.push(Medium::new(ratio, delta));
    }
    let scene = Scene {
        media,
        ..small_scene()
    };
    let settings = |threads| RenderSettings {
        max_bounces: 4,
        seed: 5,
        budget: Budget::Spp(2),
        threads,
    };
    let a = render(&scene, &settings(Some(1))).unwrap();
    let b = render(&scene, &settings(Some(2))).unwrap();
    assert_eq!(a.image, b.image);
    assert!(a.image.rgb.iter().any(|p| p[0] > 0.25));
}

// ---------------------------------------------------------------------------------------
// Residual ratio tracking
// ---------------------------------------------------------------------------------------

/// A ray `(o, d, t_max)` and its exact transmittance.
type ExactRay = (Vec3, Vec3, f32, f64);

/// Rays through [`unit_box`] of extinction `sigma` with their exact transmittance: along an
/// axis through the whole box, half of it, along the diagonal from the centre, and from
/// below along z.
fn unit_box_rays(sigma: f32) -> [ExactRay; 4] {
    let s = sigma as f64;
    [
        (
            Vec3::new(-1.0, 0.5, 0.5),
            Vec3::X,
            f32::INFINITY,
            (-s).exp(),
        ),
        (Vec3::new(-1.0, 0.3, 0.6), Vec3::X, 1.5, (-s * 0.5).exp()),
        (
            Vec3::splat(0.5),
            Vec3::ONE.normalize(),
            f32::INFINITY,
            (-s * 0.5 * 3f64.sqrt()).exp(),
        ),
        (
            Vec3::new(0.3, 0.4, -2.0),
            Vec3::Z,
            f32::INFINITY,
            (-s).exp(),
        ),
    ]
}

/// `|mean - exact| / standard error` of `n` residual-ratio-tracking estimates per ray
/// (fixed seed), each estimate `exp(-depth_scale x control depth) x residual weight` from
/// the estimator's one walk: `depth_scale = 1` is the estimator itself (checked against its
/// `transmittance`, draw for draw), any other value a mutation that miscounts the control's
/// optical depth against the residual that the walk subtracted.
fn residual_z(
    est: &ResidualRatioTracking,
    rays: &[ExactRay],
    n: usize,
    seed: u64,
    depth_scale: f64,
) -> Vec<f64> {
    use super::estimator::prepare;
    rays.iter()
        .enumerate()
        .map(|(k, &(o, d, t_max, exact))| {
            let r = prepare(o, d, t_max).unwrap();
            let mut rng = Pcg32::new(seed, k as u64);
            let mut check = Pcg32::new(seed, k as u64);
            let (m, se) = mean_se(n, || {
                let t = est
                    .residual_walk(&r, &mut rng)
                    .map_or(0.0, |(depth, w)| (-depth_scale * depth).exp() * w);
                if depth_scale == 1.0 {
                    let own = est.transmittance(o, d, t_max, &mut check) as f64;
                    assert!((own - t).abs() <= 1e-6 * (1.0 + t.abs()), "{own} vs {t}");
                }
                t
            });
            (m - exact).abs() / (se + 1e-9)
        })
        .collect()
}

fn residual_both(field: Arc<dyn Density>, maj: &Arc<MajorantGrid>) -> Vec<ResidualRatioTracking> {
    [ResidualControl::Min, ResidualControl::Mean]
        .map(|c| ResidualRatioTracking::new(field.clone(), maj.clone(), c).unwrap())
        .into()
}

/// In a homogeneous box tiled by the majorant bricks every brick's control is the
/// extinction and its residual majorant 0, so each estimate is `exp(-sigma L)` exactly, with
/// no lookup; over a wider grid (bricks half outside the box: control below the extinction
/// inside, above it outside for the mean) it is a z-test against the same closed form. The
/// control's depth miscounted by 10% (the mutation) fails both wherever a control is not 0.
#[test]
fn residual_ratio_tracking_matches_the_box() {
    let sigma = 2.0f32;
    let field: Arc<dyn Density> = unit_box(sigma);
    let rays = unit_box_rays(sigma);
    for dims in [[1, 1, 1], [16, 16, 16], [3, 1, 7]] {
        let maj = Arc::new(MajorantGrid::from_field(&*field, dims).unwrap());
        for est in residual_both(field.clone(), &maj) {
            assert!(est.controls().1.iter().all(|&m| m == 0.0), "{}", est.name());
            let mut rng = Pcg32::new(1, 2);
            for &(o, d, t_max, exact) in &rays {
                for _ in 0..100 {
                    let t = est.transmittance(o, d, t_max, &mut rng) as f64;
                    assert!((t - exact).abs() <= 1e-6, "{}: {t} vs {exact}", est.name());
                }
            }
            let bad = residual_z(&est, &rays, 100, 3, 1.1);
            assert!(bad.iter().all(|&z| z > 5.0), "{bad:?}");
        }
    }
    // Bricks of [-1, 2]^3 in 3^3 straddle nothing, in 4^3 every one straddles a face.
    for dims in [[3, 3, 3], [4, 4, 4]] {
        let maj = Arc::new(
            MajorantGrid::from_parts([-1.0; 3], [2.0; 3], dims, {
                let n = (dims[0] * dims[1] * dims[2]) as usize;
                vec![sigma; n]
            })
            .unwrap(),
        );
        for est in residual_both(field.clone(), &maj) {
            let good = residual_z(&est, &rays, 20_000, 5, 1.0);
            assert!(good.iter().all(|&z| z < 5.0), "{}: {good:?}", est.name());
            // With every brick straddling a face, the minimum control is 0 everywhere and
            // there is no control depth to miscount.
            if est.controls().0.iter().any(|&c| c > 0.0) {
                let bad = residual_z(&est, &rays, 20_000, 5, 1.1);
                assert!(bad.iter().any(|&z| z > 5.0), "{}: {bad:?}", est.name());
            }
        }
    }
}

/// Rays through a field's box: from outside, from inside, cut short inside, grazing.
fn cube_rays(exact: impl Fn(Vec3, Vec3, f32) -> f64) -> Vec<ExactRay> {
    let mut rays = vec![
        (Vec3::new(-0.5, 0.5, 0.5), Vec3::X, f32::INFINITY),
        (
            Vec3::new(0.1, 0.2, 0.3),
            Vec3::new(1.0, 0.8, 0.6).normalize(),
            f32::INFINITY,
        ),
        (
            Vec3::new(0.7, 0.4, 0.5),
            Vec3::new(-0.3, 1.0, -0.5).normalize(),
            0.4,
        ),
        (Vec3::new(0.5, 1.5, 0.0), -Vec3::Y, f32::INFINITY),
    ];
    let mut rng = Pcg32::new(17, 1);
    for _ in 0..4 {
        let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        let d = Vec3::new(
            rng.next_f32() - 0.5,
            rng.next_f32() - 0.5,
            rng.next_f32() - 0.5,
        );
        rays.push((o, d.normalize(), f32::INFINITY));
    }
    rays.into_iter()
        .map(|(o, d, t)| (o, d, t, exact(o, d, t)))
        .collect()
}

/// On the cosine cube (closed-form optical depth), both controls over 8^3 bricks: the mean
/// of 40,000 estimates per ray is within 5 standard errors of the closed form on every ray.
/// Two mutations: the control's depth counted 10% high fails on some ray; controls all 10%
/// high but consistently used (given through `with_controls`) still pass, as the derivation
/// says (any control is unbiased; a residual below 0 only adds variance).
#[test]
fn residual_ratio_tracking_is_unbiased_on_the_cosine_cube() {
    use crate::testing::CosNoise;
    let noise = Arc::new(CosNoise::new(8, 10.0, 3.0, 5));
    let exact = |o: Vec3, d: Vec3, t_max: f32| {
        let (o, d) = (o.as_dvec3(), d.as_dvec3());
        let (lo, hi) = (noise.lo, noise.hi);
        match super::majorant::clip_box(o, d, &lo, &hi, 0.0, t_max as f64) {
            Some((t0, t1)) => (-noise.optical_depth(o + d * t0, d, t1 - t0)).exp(),
            None => 1.0,
        }
    };
    let rays = cube_rays(exact);
    let field: Arc<dyn Density> = noise.clone();
    let maj = Arc::new(MajorantGrid::from_field(&*field, [8, 8, 8]).unwrap());
    for est in residual_both(field.clone(), &maj) {
        let good = residual_z(&est, &rays, 40_000, 7, 1.0);
        assert!(good.iter().all(|&z| z < 5.0), "{}: {good:?}", est.name());
        let bad = residual_z(&est, &rays, 40_000, 7, 1.1);
        assert!(bad.iter().any(|&z| z > 5.0), "{}: {bad:?}", est.name());
        let (controls, _) = est.controls();
        let high: Vec<f32> = controls.iter().map(|c| 1.1 * c).collect();
        let residual: Vec<f32> = maj
            .values()
            .iter()
            .zip(&high)
            .map(|(&m, &c)| (m - c).max(c).max(1e-3))
            .collect();
        let high = ResidualRatioTracking::with_controls(field.clone(), maj.clone(), high, residual)
            .unwrap();
        let z = residual_z(&high, &rays, 40_000, 7, 1.0);
        assert!(z.iter().all(|&z| z < 5.0), "{}: {z:?}", high.name());
    }
}

/// A 9x7x8 voxel grid with large contrast (values 0.05 ..= 4), through the trackers'
/// dense path.
fn contrast_grid() -> VoxelGrid {
    let dims = [9u32, 7, 8];
    let mut rng = Pcg32::new(23, 5);
    let n = (dims[0] * dims[1] * dims[2]) as usize;
    let values = (0..n)
        .map(|i| 0.05 + (i % 9) as f32 * 0.3 + rng.next_f32() * 1.5)
        .collect();
    VoxelGrid::new(dims, [-0.2, 0.1, 0.0], [0.15, 0.2, 0.12], values).unwrap()
}

/// The least voxel a brick's trilinear field reads bounds the field from below (20,000
/// random points in random boxes, and at the corners of every brick of a 4x3x3 grid);
/// the least voxel whose centre lies in the box (the mutation, which leaves out the
/// neighbours that the interpolation near the faces reads) exceeds the field somewhere.
#[test]
fn voxel_minimum_bounds_the_trilinear_field() {
    let g = contrast_grid();
    let view = g.dense_view().unwrap();
    let (lo, hi) = g.bounds().to_arrays();
    let (dims, origin, spacing, values) = g.parts();
    let own_cells_min = |blo: [f64; 3], bhi: [f64; 3]| {
        let mut m = f32::INFINITY;
        for (i, &v) in values.iter().enumerate() {
            let x = [
                i % dims[0] as usize,
                (i / dims[0] as usize) % dims[1] as usize,
                i / (dims[0] * dims[1]) as usize,
            ];
            let c = [0, 1, 2].map(|a| origin[a] + (x[a] as f64 + 0.5) * spacing[a]);
            if (0..3).all(|a| c[a] >= blo[a] && c[a] <= bhi[a]) {
                m = m.min(v);
            }
        }
        m
    };
    let mut rng = Pcg32::new(8, 8);
    let mut mutant_exceeds = false;
    for _ in 0..200 {
        let a = [0, 1, 2].map(|k| lo[k] + (hi[k] - lo[k]) * rng.next_f64());
        let b = [0, 1, 2].map(|k| lo[k] + (hi[k] - lo[k]) * rng.next_f64());
        let blo = [0, 1, 2].map(|k| a[k].min(b[k]));
        let bhi = [0, 1, 2].map(|k| a[k].max(b[k]));
        let least = g.min_extinction_in(Aabb::from_arrays(blo, bhi)).unwrap();
        assert_eq!(least, view.min_over(blo, bhi));
        let mutant = own_cells_min(blo, bhi);
        for _ in 0..100 {
            let p = [0, 1, 2].map(|k| (blo[k] + (bhi[k] - blo[k]) * rng.next_f64()) as f32);
            let e = g.extinction(Vec3::from_array(p).as_dvec3());
            assert!(e >= least - 1e-5, "{p:?}: {e} < {least}");
            mutant_exceeds |= e < mutant - 1e-5;
        }
    }
    assert!(mutant_exceeds);
    // A box reaching outside the grid has minimum 0 (the extinction there).
    assert_eq!(
        g.min_extinction_in(Aabb::from_arrays([-1.0; 3], [0.0; 3])),
        Some(0.0)
    );
}

/// Residual ratio tracking through the dense array of a voxel grid (both controls, 4x3x3
/// bricks, 40,000 estimates per ray): within 5 standard errors of `exp(-depth)` by a fine
/// midpoint rule on every ray.
#[test]
fn residual_ratio_tracking_is_unbiased_on_a_voxel_grid() {
    let g = Arc::new(contrast_grid());
    let (lo, hi) = g.bounds().to_arrays();
    let exact = |o: Vec3, d: Vec3, t_max: f32| {
        let (od, dd) = (o.as_dvec3(), d.as_dvec3());
        let Some((t0, t1)) = super::majorant::clip_box(od, dd, &lo, &hi, 0.0, t_max as f64) else {
            return 1.0;
        };
        let n = 100_000;
        let h = (t1 - t0) / n as f64;
        let depth: f64 = (0..n)
            .map(|i| {
                g.extinction((od + dd * (t0 + (i as f64 + 0.5) * h)).as_vec3().as_dvec3()) as f64
                    * h
            })
            .sum();
        (-depth).exp()
    };
    // The grid's box is [-0.2, 1.15] x [0.1, 1.5] x [0, 0.96]: the cube rays, shifted in.
    let rays: Vec<ExactRay> = cube_rays(|_, _, _| 0.0)
        .into_iter()
        .map(|(o, d, t, _)| {
            let o = o * Vec3::new(1.35, 1.4, 0.96) + Vec3::new(-0.2, 0.1, 0.0);
            (o, d, t, exact(o, d, t))
        })
        .collect();
    let field: Arc<dyn Density> = g.clone();
    let maj = Arc::new(MajorantGrid::from_field(&*field, [4, 3, 3]).unwrap());
    for est in residual_both(field, &maj) {
        let z = residual_z(&est, &rays, 40_000, 9, 1.0);
        assert!(z.iter().all(|&z| z < 5.0), "{}: {z:?}", est.name());
    }
}

/// Where both queries run along one ray, residual ratio tracking answers with ratio
/// tracking's one walk (transmittance correlated with the collision), draw for draw.
#[test]
fn residual_pairs_are_ratio_trackings_one_walk() {
    let g: Arc<dyn Density> = Arc::new(contrast_grid());
    let maj = Arc::new(MajorantGrid::from_field(&*g, [4, 3, 3]).unwrap());
    let ratio = RatioTracking::new(g.clone(), maj.clone());
    for est in residual_both(g, &maj) {
        let (mut a, mut b) = (Pcg32::new(4, 1), Pcg32::new(4, 1));
        for (o, d, t_max, _) in cube_rays(|_, _, _| 0.0) {
            for _ in 0..200 {
                assert_eq!(
                    est.transmittance_and_distance(o, d, t_max, &mut a),
                    ratio.transmittance_and_distance(o, d, t_max, &mut b)
                );
            }
        }
    }
}

/// A renderer's field as a baker's source over the box `[lo, hi]` (the field's own bounds
/// for the extinction), so that `pinbake::control::bake_control` computes the control of
/// exactly the field the estimator reads.
#[cfg(feature = "cli")]
struct FieldSource {
    field: Arc<dyn Density>,
    lo: [f64; 3],
    hi: [f64; 3],
}

#[cfg(feature = "cli")]
impl pin_volume::Density for FieldSource {
    fn bounds(&self) -> pin_volume::Aabb {
        pin_volume::Aabb::new(DVec3::from(self.lo), DVec3::from(self.hi))
    }
    fn extinction(&self, p: DVec3) -> f32 {
        self.field.extinction(p.as_vec3().as_dvec3())
    }
    fn max_extinction_in(&self, r: pin_volume::Aabb) -> f32 {
        self.field.max_extinction_in(r).min(f32::MAX)
    }
}

/// Baked into a control (`pinbake::control::bake_control`) by the tests below.
#[cfg(feature = "cli")]
impl pin_volume::DensitySource for FieldSource {
    fn describe(&self) -> String {
        "test field".into()
    }
}

/// `pinres` over `field`: the control `pinbake` bakes for it over `[lo, hi]` with `dims`
/// bricks, and, with `wrong_m`, the mutation that stores a residual majorant of 0 in every
/// brick (the walk then skips the residual: the estimate is `exp(-int c)`).
#[cfg(feature = "cli")]
fn baked_pinres(
    field: Arc<dyn Density>,
    (lo, hi): ([f64; 3], [f64; 3]),
    dims: [u32; 3],
    wrong_m: bool,
) -> BakedResidualTracking {
    let src = FieldSource {
        field: field.clone(),
        lo,
        hi,
    };
    let opts = pinbake::control::ControlOptions {
        dims: pinbake::control::ControlDims::Exact(dims),
        ..pinbake::control::ControlOptions::default()
    };
    let c = pinbake::control::bake_control(&src, &src.bounds_box(), &opts).unwrap();
    let residual = if wrong_m {
        vec![0.0; c.residual.len()]
    } else {
        c.residual
    };
    BakedResidualTracking::new(
        field,
        (lo, hi),
        c.dims,
        c.control,
        residual,
        c.majorant,
        None,
    )
    .unwrap()
}

#[cfg(feature = "cli")]
impl FieldSource {
    fn bounds_box(&self) -> pin_volume::Aabb {
        pin_volume::Density::bounds(self)
    }
}

/// `pinres` against closed forms, with the control `pinbake` bakes (fixed seeds, 40,000
/// estimates per ray, 5 standard errors): a homogeneous box inside a wider control grid
/// (bricks straddle its faces, so controls lie between 0 and the extinction and residuals
/// have both signs), and the cosine-noise cube. Each estimate is also the estimator's own
/// `transmittance`, draw for draw (`residual_z`). Two mutations must fail: the control's
/// depth dropped (`exp(-int c)` left out), and residual majorants of 0 (the wrong `m`).
#[cfg(feature = "cli")]
#[test]
fn pinres_is_unbiased_against_closed_forms() {
    use crate::testing::CosNoise;
    let sigma = 2.0f32;
    let boxed: Arc<dyn Density> = unit_box(sigma);
    let box_rays = unit_box_rays(sigma).to_vec();
    let noise = Arc::new(CosNoise::new(8, 10.0, 3.0, 5));
    let exact = |o: Vec3, d: Vec3, t_max: f32| {
        let (o, d) = (o.as_dvec3(), d.as_dvec3());
        match super::majorant::clip_box(o, d, &noise.lo, &noise.hi, 0.0, t_max as f64) {
            Some((t0, t1)) => (-noise.optical_depth(o + d * t0, d, t1 - t0)).exp(),
            None => 1.0,
        }
    };
    type Case = (
        Arc<dyn Density>,
        ([f64; 3], [f64; 3]),
        [u32; 3],
        Vec<ExactRay>,
    );
    let cases: Vec<Case> = vec![
        (boxed.clone(), ([-0.3; 3], [1.4; 3]), [5, 4, 7], box_rays),
        (
            noise.clone(),
            (noise.lo, noise.hi),
            [12, 12, 12],
            cube_rays(exact),
        ),
    ];
    for (field, bounds, dims, rays) in cases {
        let est = baked_pinres(field.clone(), bounds, dims, false);
        let (controls, residual) = est.controls();
        assert!(controls.iter().any(|&c| c > 0.0) && residual.iter().any(|&m| m > 0.0));
        let good = residual_z(est.tracking(), &rays, 40_000, 11, 1.0);
        assert!(good.iter().all(|&z| z < 5.0), "{}: {good:?}", est.name());
        let dropped = residual_z(est.tracking(), &rays, 40_000, 11, 0.0);
        assert!(dropped.iter().any(|&z| z > 5.0), "{dropped:?}");
        let wrong_m = baked_pinres(field, bounds, dims, true);
        let bad = residual_z(wrong_m.tracking(), &rays, 40_000, 11, 1.0);
        assert!(bad.iter().any(|&z| z > 5.0), "{bad:?}");
    }
}

/// `pinres` against ratio tracking on a voxel grid, through the dense array (fixed seeds):
/// two-sample z-tests of the mean transmittance, 40,000 `pinres` estimates against 160,000
/// ratio-tracking ones per ray, within 5 combined standard errors on every ray; the wrong `m`
/// (residual majorants of 0) fails on some ray. Its distances and paired queries track the
/// baked majorants, which bound the field: the fraction of rays without a collision matches
/// ratio tracking's transmittance too.
#[cfg(feature = "cli")]
#[test]
fn pinres_matches_ratio_tracking_on_a_voxel_grid() {
    let g = Arc::new(contrast_grid());
    let field: Arc<dyn Density> = g.clone();
    let (lo, hi) = g.bounds().to_arrays();
    let maj = Arc::new(MajorantGrid::from_field(&*field, [4, 3, 3]).unwrap());
    let ratio = RatioTracking::new(field.clone(), maj);
    let rays: Vec<(Vec3, Vec3, f32)> = cube_rays(|_, _, _| 0.0)
        .into_iter()
        .map(|(o, d, t, _)| {
            (
                o * Vec3::new(1.35, 1.4, 0.96) + Vec3::new(-0.2, 0.1, 0.0),
                d,
                t,
            )
        })
        .collect();
    let z = |est: &dyn TransportEstimator, seed: u64| -> Vec<f64> {
        rays.iter()
            .enumerate()
            .flat_map(|(k, &(o, d, t_max))| {
                let mut a = Pcg32::new(seed, k as u64);
                let mut b = Pcg32::new(seed + 1, k as u64);
                let mut c = Pcg32::new(seed + 2, k as u64);
                let want = mean_se(160_000, || ratio.transmittance(o, d, t_max, &mut b) as f64);
                let got = mean_se(40_000, || est.transmittance(o, d, t_max, &mut a) as f64);
                let passed = mean_se(40_000, || {
                    f64::from(u8::from(est.sample_distance(o, d, t_max, &mut c).is_none()))
                });
                [got, passed].map(|(m, se)| (m - want.0).abs() / (se.hypot(want.1) + 1e-9))
            })
            .collect()
    };
    let est = baked_pinres(field.clone(), (lo, hi), [6, 5, 5], false);
    let good = z(&est, 13);
    assert!(good.iter().all(|&v| v < 5.0), "{good:?}");
    let wrong_m = baked_pinres(field, (lo, hi), [6, 5, 5], true);
    let bad = z(&wrong_m, 13);
    assert!(bad.iter().any(|&v| v > 5.0), "{bad:?}");
}

/// A one-cell pin grid over the unit box with no pins, carrying `control` (the section
/// `pinres` reads) when given.
fn unit_pin_grid(control: Option<pin_format::OwnedControl>) -> pinrt::PinGrid {
    use pin_format::{Directions, OwnedPinGrid, PinEntry, grid_desc};
    let mut desc = grid_desc([1; 3], Directions::Octahedral { n: 1 }, 1, 1);
    desc.box_min = [0.0; 3];
    desc.box_max = [1.0; 3];
    let owned = OwnedPinGrid {
        desc,
        tile: None,
        cell_index: None,
        pins: vec![PinEntry::EMPTY],
        majorant: None,
        density: None,
        sparse_density: None,
        control,
        metadata: None,
    };
    pinrt::PinGrid::from_bytes(owned.to_bytes().unwrap()).unwrap()
}

/// `pinres` from a pin grid's control section: placed by the grid's translation, refused
/// without the section or with a rotated placement, and the same estimator as from the
/// section's values directly, draw for draw.
#[test]
fn pinres_reads_the_control_section() {
    use pin_format::OwnedControl;
    let field: Arc<dyn Density> = unit_box(1.5);
    let control = OwnedControl {
        dims: [2, 1, 1],
        control: vec![1.0, 1.5],
        residual: vec![0.5, 0.5],
        majorant: vec![1.5, 1.5],
    };
    let plain = unit_pin_grid(None);
    let e = BakedResidualTracking::from_grid(field.clone(), &plain, None, None).err();
    assert!(e.is_some_and(|e| e.to_string().contains("--embed-control")));
    let grid = unit_pin_grid(Some(control.clone()));
    let shifted = [1.0, 0.0, 0.0, 0.25, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
    let est = BakedResidualTracking::from_grid(field.clone(), &grid, Some(&shifted), None).unwrap();
    assert_eq!(est.bounds(), Some(([0.25, 0.0, 0.0], [1.25, 1.0, 1.0])));
    let direct = BakedResidualTracking::new(
        field.clone(),
        ([0.25, 0.0, 0.0], [1.25, 1.0, 1.0]),
        control.dims,
        control.control,
        control.residual,
        control.majorant,
        None,
    )
    .unwrap();
    let (mut a, mut b) = (Pcg32::new(3, 3), Pcg32::new(3, 3));
    for (o, d, t_max, _) in cube_rays(|_, _, _| 0.0) {
        assert_eq!(
            est.transmittance(o, d, t_max, &mut a),
            direct.transmittance(o, d, t_max, &mut b)
        );
        assert_eq!(
            est.transmittance_and_distance(o, d, t_max, &mut a),
            direct.transmittance_and_distance(o, d, t_max, &mut b)
        );
    }
    let rotated = [0.0, -1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
    assert!(BakedResidualTracking::from_grid(field, &grid, Some(&rotated), None).is_err());
}

/// A control section that does not fit the field it is rendered with (an "empty" brick where
/// the field is not 0, a majorant below the field): `from_grid` raises them from the field's
/// own bound, and the estimate stays unbiased (z-test, fixed seed, 40,000 estimates); the
/// section's values used as they are (the mutation, through `new`) are biased.
#[test]
fn pinres_fits_the_section_to_the_field() {
    use pin_format::OwnedControl;
    let sigma = 1.5f32;
    let field: Arc<dyn Density> = unit_box(sigma);
    // Brick 0 claims to be empty; brick 1's majorant is below the field.
    let control = OwnedControl {
        dims: [2, 1, 1],
        control: vec![0.0, 1.0],
        residual: vec![0.0, 0.5],
        majorant: vec![0.0, 1.0],
    };
    let grid = unit_pin_grid(Some(control.clone()));
    let fitted = BakedResidualTracking::from_grid(field.clone(), &grid, None, None).unwrap();
    let (_, residual) = fitted.controls();
    assert_eq!(residual, &[sigma, 0.5]);
    let as_is = BakedResidualTracking::new(
        field,
        ([0.0; 3], [1.0; 3]),
        control.dims,
        control.control,
        control.residual,
        control.majorant,
        None,
    )
    .unwrap();
    let (o, d) = (Vec3::new(-0.5, 0.5, 0.5), Vec3::X);
    let exact = (-(sigma as f64)).exp();
    let z = |est: &BakedResidualTracking, seed: u64| {
        let mut rng = Pcg32::new(seed, 1);
        let (m, se) = mean_se(40_000, || {
            est.transmittance(o, d, f32::INFINITY, &mut rng) as f64
        });
        (m - exact).abs() / (se + 1e-9)
    };
    assert!(z(&fitted, 5) < 5.0);
    assert!(z(&as_is, 5) > 5.0);
    // Distances over the raised majorants: the fraction of rays without a collision.
    let mut rng = Pcg32::new(6, 1);
    let (m, se) = mean_se(40_000, || {
        f64::from(u8::from(
            fitted
                .sample_distance(o, d, f32::INFINITY, &mut rng)
                .is_none(),
        ))
    });
    assert!((m - exact).abs() <= 5.0 * se, "{m} vs {exact} ({se})");
}
