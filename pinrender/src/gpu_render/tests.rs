//! CPU/GPU agreement of the path tracer, determinism, input checks, timing.
use super::*;
use crate::render::{
    Budget, MajorantGrid, Medium, Pcg32, PinsEstimator, RenderSettings, TransportEstimator,
    VoxelGrid, render,
};
use pin_format::{Directions, OwnedPinGrid, PinEntry, grid_desc};
use pinrt::Rng;
use std::sync::Arc;
use std::time::Instant;

/// The test binary's one device, opened the first time a test asks: each `GpuContext` compiles
/// pinrt's own pipelines, seconds each on lavapipe, so the tests share one.
pub(super) fn context() -> &'static GpuContext {
    static CONTEXT: std::sync::OnceLock<GpuContext> = std::sync::OnceLock::new();
    CONTEXT.get_or_init(|| {
        GpuContext::new().unwrap_or_else(|e| {
            panic!(
                "GPU render tests need a working wgpu adapter: {e}\n\
                 (this test fails rather than skips so that a missing driver is noticed)"
            )
        })
    })
}

/// The path tracer's pipelines on [`context`]'s device, shared by the tests that do not
/// count compiles (those make a store of their own): a pipeline compiles once per test
/// binary, not once per renderer. A shared pipeline renders the bits of a renderer's own
/// (`a_renderer_of_the_same_layout_takes_the_compiled_pipeline_and_renders_its_own_bits`).
pub(super) fn shared_pipelines() -> &'static Arc<GpuPipelines> {
    static STORE: std::sync::OnceLock<Arc<GpuPipelines>> = std::sync::OnceLock::new();
    STORE.get_or_init(|| {
        let ctx = context();
        GpuPipelines::new(&ctx.device, &ctx.queue, &ctx.limits)
    })
}

/// [`GpuRenderer::with_media`] on the shared device and pipelines.
pub(super) fn shared_renderer(media: &GpuMedia<'_>) -> pinrt::Result<GpuRenderer> {
    GpuRenderer::with_media_in(shared_pipelines(), media)
}

/// [`GpuRenderer::with_media_limited`] on the shared device and pipelines.
fn shared_renderer_limited(media: &GpuMedia<'_>, binding_limit: u64) -> pinrt::Result<GpuRenderer> {
    let store = shared_pipelines();
    let limit = binding_limit.min(pinrt::gpu::binding_limit(&store.limits));
    pollster::block_on(GpuRenderer::create(store, media, limit))
}

/// [`GpuRenderer::new`] on the shared device and pipelines.
fn pins_renderer(grid: &PinGrid) -> GpuRenderer {
    shared_renderer(&GpuMedia::pins_only(grid, None, SamplerOptions::default())).unwrap()
}

/// A blob-shaped pin grid over the world box `[-1, 1]^3`: denser pins towards the centre
/// (more ratio bits, smaller `t_min`), random bits.
pub(super) fn blob_grid(
    cells: u32,
    directions: Directions,
    ppe: u32,
    strength: f32,
) -> OwnedPinGrid {
    let mut rng = Rng::for_query(0xB10B, cells);
    let block = directions.count() * ppe;
    let mut pins = Vec::new();
    for z in 0..cells {
        for y in 0..cells {
            for x in 0..cells {
                let c = [x, y, z].map(|i| (i as f32 + 0.5) / cells as f32 * 2.0 - 1.0);
                let r2 = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
                let rho = 0.05 + 0.95 * (1.0 - r2).max(0.0);
                for _ in 0..block {
                    let t_min = (-strength * rho * (0.5 + rng.next_f32())).exp();
                    let p = 0.3 + 0.6 * rho;
                    let mut mask = 0u32;
                    for b in 0..32 {
                        if rng.next_f32() < p {
                            mask |= 1 << b;
                        }
                    }
                    if t_min >= 1.0 {
                        mask = 0;
                    }
                    pins.push(PinEntry { mask, t_min });
                }
            }
        }
    }
    let mut desc = grid_desc([cells; 3], directions, ppe, u64::from(cells.pow(3)));
    desc.box_min = [-1.0; 3];
    desc.box_max = [1.0; 3];
    desc.source_box_min = [-1.0; 3];
    desc.source_box_max = [1.0; 3];
    OwnedPinGrid {
        desc,
        tile: None,
        cell_index: None,
        pins,
        majorant: None,
        density: None,
        sparse_density: None,
        control: None,
        metadata: None,
    }
}

pub(super) fn load(owned: &OwnedPinGrid) -> Arc<PinGrid> {
    Arc::new(PinGrid::from_bytes(owned.to_bytes().unwrap()).unwrap())
}

pub(super) fn scene(size: u32, albedo: f32, g: f32, max_bounces: u32) -> GpuScene {
    GpuScene {
        camera: Camera {
            origin: [0.4, 0.6, 3.5],
            target: [0.0, 0.0, 0.0],
            vfov_deg: 40.0,
            width: size,
            height: size,
        },
        // Behind the medium as seen from the camera: forward scattering lights it.
        sun: Some(Sun {
            dir: [0.3, 0.5, -1.0],
            radiance: [3.0, 2.5, 2.0],
        }),
        env_radiance: [0.2, 0.3, 0.5],
        albedo,
        g,
        max_bounces,
    }
}

/// A CPU estimator that answers a query pair along one ray as two separate queries (the
/// trait's default), as the GPU path tracer does for every estimator but ratio tracking and
/// the residual ones (and for those with several media): the CPU's one-lookup / one-walk pairs
/// (`TransportEstimator::transmittance_and_distance`) have the same means but a lower
/// per-pixel variance, which the comparisons below would count as a difference.
struct Separate(Arc<dyn TransportEstimator>);

impl TransportEstimator for Separate {
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
        self.0.sample_distance(o, d, t_max, rng)
    }
    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32 {
        self.0.transmittance(o, d, t_max, rng)
    }
    fn name(&self) -> String {
        self.0.name()
    }
    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        self.0.bounds()
    }
}

fn separate(e: Arc<dyn TransportEstimator>) -> Arc<dyn TransportEstimator> {
    Arc::new(Separate(e))
}

fn cpu_render(
    grid: &Arc<PinGrid>,
    scene: &GpuScene,
    spp: u32,
    seed: u64,
    threads: Option<usize>,
) -> (Image, f64) {
    let est: Arc<dyn TransportEstimator> =
        Arc::new(PinsEstimator::new(grid.clone(), None, SamplerOptions::default()).unwrap());
    let settings = RenderSettings {
        max_bounces: scene.max_bounces,
        seed,
        budget: Budget::Spp(spp),
        threads,
    };
    let out = render(
        &scene.to_scene(vec![Medium::single(separate(est))]),
        &settings,
    )
    .unwrap();
    (out.image, out.seconds)
}

/// Per-pixel grey value (mean of the channels).
fn grey(p: [f32; 3]) -> f64 {
    (f64::from(p[0]) + f64::from(p[1]) + f64::from(p[2])) / 3.0
}

/// Mean and variance of the mean of each pixel over independent replicate images, and
/// the same for the image mean.
struct Stats {
    mean: Vec<f64>,
    var_mean: Vec<f64>,
    image_mean: f64,
    image_var_mean: f64,
}

fn stats(images: &[Image]) -> Stats {
    let r = images.len() as f64;
    let n = images[0].rgb.len();
    let mut mean = vec![0.0; n];
    let mut var_mean = vec![0.0; n];
    for i in 0..n {
        let v: Vec<f64> = images.iter().map(|im| grey(im.rgb[i])).collect();
        let m = v.iter().sum::<f64>() / r;
        let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (r - 1.0);
        mean[i] = m;
        var_mean[i] = var / r;
    }
    let means: Vec<f64> = images
        .iter()
        .map(|im| im.rgb.iter().map(|&p| grey(p)).sum::<f64>() / n as f64)
        .collect();
    let im = means.iter().sum::<f64>() / r;
    let iv = means.iter().map(|x| (x - im) * (x - im)).sum::<f64>() / (r - 1.0) / r;
    Stats {
        mean,
        var_mean,
        image_mean: im,
        image_var_mean: iv,
    }
}

/// `replicates` independent renders of `spp` samples on each side; per-pixel z-scores of
/// the difference of the means (variance of each mean estimated from its replicates) and
/// the z-score of the image means: at most `max_exceed` pixels beyond `|z| = z_pixel`.
/// Returns the GPU and CPU statistics.
fn compare(
    name: &str,
    renderer: &GpuRenderer,
    grid: &Arc<PinGrid>,
    scene: &GpuScene,
    replicates: u64,
    spp: u32,
    bounds: (f64, usize),
) -> (Stats, Stats) {
    compare_with(
        name,
        |k| {
            renderer
                .render(scene, EstimatorSpec::Pins, spp, 1000 + k)
                .unwrap()
        },
        |k| cpu_render(grid, scene, spp, 5000 + k, None).0,
        replicates,
        spp,
        bounds,
    )
}

/// [`compare`] for any pair of renderers: `gpu(k)` and `cpu(k)` render replicate `k` (with
/// distinct seeds).
fn compare_with(
    name: &str,
    gpu: impl Fn(u64) -> Image,
    cpu: impl Fn(u64) -> Image,
    replicates: u64,
    spp: u32,
    (z_pixel, max_exceed): (f64, usize),
) -> (Stats, Stats) {
    let gpu: Vec<Image> = (0..replicates).map(gpu).collect();
    let cpu: Vec<Image> = (0..replicates).map(cpu).collect();
    let (g, c) = (stats(&gpu), stats(&cpu));
    let mut exceed = 0;
    let mut max_z = 0.0f64;
    let mut constant_pixels = 0;
    for i in 0..g.mean.len() {
        let diff = g.mean[i] - c.mean[i];
        let var = g.var_mean[i] + c.var_mean[i];
        if var == 0.0 {
            // Rays that miss the medium: both sides give the same constant.
            constant_pixels += 1;
            assert!(
                diff.abs() <= 1e-6 * c.mean[i].abs().max(1e-3),
                "[{name}] pixel {i}: constant values differ: gpu {} cpu {}",
                g.mean[i],
                c.mean[i]
            );
            continue;
        }
        let z = diff / var.sqrt();
        max_z = max_z.max(z.abs());
        if z.abs() > z_pixel {
            exceed += 1;
        }
    }
    let pixel_ratio = g.var_mean.iter().sum::<f64>() / c.var_mean.iter().sum::<f64>();
    let n2 = (g.mean.len() * g.mean.len()) as f64;
    let correlation = g.image_var_mean / (g.var_mean.iter().sum::<f64>() / n2);
    let z_image = (g.image_mean - c.image_mean) / (g.image_var_mean + c.image_var_mean).sqrt();
    eprintln!(
        "[{name}] {} x {spp} spp per side: image mean gpu {:.6} +- {:.6}, cpu {:.6} +- \
         {:.6}, z = {z_image:.2}; pixels: {} ({constant_pixels} constant), |z| > \
         {z_pixel}: {exceed}, max |z| {max_z:.2}; variance ratio gpu/cpu: pixels \
         {pixel_ratio:.3}, image mean {:.2}; gpu image-mean variance / independent-pixel \
         prediction {correlation:.2}",
        replicates,
        g.image_mean,
        g.image_var_mean.sqrt(),
        c.image_mean,
        c.image_var_mean.sqrt(),
        g.mean.len(),
        g.image_var_mean / c.image_var_mean,
    );
    assert!(
        z_image.abs() < 4.0,
        "[{name}] image means differ: z = {z_image}"
    );
    // Same estimator, same per-sample variance.
    assert!(
        (0.8..1.25).contains(&pixel_ratio),
        "[{name}] per-pixel variance ratio gpu/cpu {pixel_ratio}"
    );
    // Independent pixels: the image mean's variance is the sum of the pixels' (a
    // correlated GPU random stream would inflate it).
    assert!(
        correlation < 2.0,
        "[{name}] gpu pixels look correlated: image-mean variance {correlation} x the \
         independent prediction"
    );
    assert!(
        exceed <= max_exceed,
        "[{name}] {exceed} pixels beyond |z| {z_pixel} (allowed {max_exceed})"
    );
    (g, c)
}

#[test]
fn albedo_zero_matches_cpu_transmittance() {
    let owned = blob_grid(4, Directions::Octahedral { n: 4 }, 2, 0.25);
    let grid = &load(&owned);
    let renderer = pins_renderer(grid);
    let sc = scene(32, 0.0, 0.0, 4);
    // 32 replicates x 2 spp = 64 spp per side.
    let (g, _) = compare("albedo 0", &renderer, grid, &sc, 32, 2, (4.5, 3));
    // env * E[T]: never above env, and the medium is visible.
    let env = grey(sc.env_radiance);
    let lo = g.mean.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = g.mean.iter().cloned().fold(0.0, f64::max);
    assert!(hi <= env * (1.0 + 1e-6), "{hi} > env {env}");
    assert!(lo < 0.5 * env, "medium not visible: darkest pixel {lo}");
    // Per channel the image is env * T: the channels are proportional.
    let img = renderer.render(&sc, EstimatorSpec::Pins, 8, 3).unwrap();
    for p in &img.rgb {
        let t = p[0] / sc.env_radiance[0];
        assert!((0.0..=1.0 + 1e-6).contains(&t));
        assert!((p[2] - t * sc.env_radiance[2]).abs() <= 1e-5, "{p:?}");
    }
}

#[test]
fn scattering_matches_cpu() {
    let owned = blob_grid(4, Directions::Octahedral { n: 4 }, 2, 0.25);
    let grid = &load(&owned);
    let renderer = pins_renderer(grid);
    // Sun + environment, forward scattering, 4 bounces.
    let sc = scene(32, 0.9, 0.6, 4);
    let (g, _) = compare(
        "albedo 0.9, g 0.6, 4 bounces",
        &renderer,
        grid,
        &sc,
        32,
        2,
        (4.5, 10),
    );
    // The transmitted environment alone (albedo 0) is darker.
    let g0 = stats(&[
        renderer
            .render(&scene(32, 0.0, 0.6, 4), EstimatorSpec::Pins, 16, 7)
            .unwrap(),
        renderer
            .render(&scene(32, 0.0, 0.6, 4), EstimatorSpec::Pins, 16, 8)
            .unwrap(),
    ]);
    assert!(g.image_mean > g0.image_mean, "scattering must add light");
    // Sun only, backward scattering, single scattering: checks the phase convention.
    let mut sun_only = scene(32, 0.8, -0.5, 1);
    sun_only.env_radiance = [0.0; 3];
    sun_only.sun = Some(Sun {
        dir: [-0.5, 0.2, 1.0],
        radiance: [4.0, 3.0, 2.0],
    });
    compare(
        "sun only, g -0.5, 1 bounce",
        &renderer,
        grid,
        &sun_only,
        32,
        2,
        (4.5, 10),
    );
}

#[test]
fn deterministic_and_checked() {
    let owned = blob_grid(3, Directions::THESIS_DEFAULT, 1, 0.3);
    let grid = &load(&owned);
    let renderer = pins_renderer(grid);
    let sc = scene(32, 0.9, 0.3, 4);
    let a = renderer.render(&sc, EstimatorSpec::Pins, 5, 42).unwrap();
    let b = renderer.render(&sc, EstimatorSpec::Pins, 5, 42).unwrap();
    let bits =
        |im: &Image| -> Vec<u32> { im.rgb.iter().flat_map(|p| p.map(f32::to_bits)).collect() };
    assert_eq!(bits(&a), bits(&b), "same seed, different bits");
    let c = renderer.render(&sc, EstimatorSpec::Pins, 5, 43).unwrap();
    assert_ne!(bits(&a), bits(&c), "the seed must matter");
    // Odd sizes (partial workgroups) and more passes than one submission holds.
    let mut odd = scene(13, 0.9, 0.3, 2);
    odd.camera.height = 7;
    let spp = PASSES_PER_SUBMIT + 44;
    let x = renderer
        .render(&odd, EstimatorSpec::Pins, spp, u64::MAX)
        .unwrap();
    let y = renderer
        .render(&odd, EstimatorSpec::Pins, spp, u64::MAX)
        .unwrap();
    assert_eq!((x.width, x.height, x.rgb.len()), (13, 7, 91));
    assert_eq!(bits(&x), bits(&y));
    assert!(x.rgb.iter().flatten().all(|c| c.is_finite() && *c >= 0.0));

    // Bad input is an error, never a panic.
    let bad = |f: &dyn Fn(&mut GpuScene)| {
        let mut s = scene(8, 0.5, 0.0, 2);
        f(&mut s);
        let r = renderer.render(&s, EstimatorSpec::Pins, 1, 0);
        assert!(matches!(r, Err(GpuRenderError::Invalid(_))), "{r:?}");
    };
    bad(&|s| s.camera.width = 0);
    bad(&|s| s.camera.height = 0);
    bad(&|s| s.camera.origin[0] = f32::NAN);
    bad(&|s| s.camera.target = s.camera.origin);
    bad(&|s| s.camera.vfov_deg = 180.0);
    bad(&|s| s.g = 1.0);
    bad(&|s| s.g = f32::NAN);
    bad(&|s| s.albedo = 1.5);
    bad(&|s| s.env_radiance[1] = -1.0);
    bad(&|s| {
        s.sun = Some(Sun {
            dir: [0.0; 3],
            radiance: [1.0; 3],
        })
    });
    bad(&|s| s.max_bounces = MAX_GPU_BOUNCES + 1);
    assert!(matches!(
        renderer.render(&scene(8, 0.5, 0.0, 2), EstimatorSpec::Pins, 0, 0),
        Err(GpuRenderError::Invalid(_))
    ));
    // No lights: black, not NaN.
    let mut dark = scene(8, 0.5, 0.0, 2);
    dark.sun = None;
    dark.env_radiance = [0.0; 3];
    let img = renderer.render(&dark, EstimatorSpec::Pins, 2, 0).unwrap();
    assert!(img.rgb.iter().flatten().all(|&c| c == 0.0));
}

// ---------------------------------------------------------------------------------------
// Several media, densities, the trackers, ray marching and PinMS
// ---------------------------------------------------------------------------------------

/// Instance translations of the multi-medium tests: overlapping copies of one blob.
const OFFSETS: [[f64; 3]; 3] = [[0.0, 0.0, 0.0], [0.7, 0.25, -0.3], [-0.55, 0.6, 0.45]];

/// A `n^3` voxel blob over `[-1, 1]^3` (peak extinction `sigma`), the project's convention.
fn blob_voxels(n: u32, sigma: f32) -> Vec<f32> {
    let mut v = Vec::with_capacity((n * n * n) as usize);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let c = [x, y, z].map(|i| (i as f32 + 0.5) / n as f32 * 2.0 - 1.0);
                let r2 = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
                let ripple = 1.0 + 0.5 * (7.0 * c[0]).sin() * (5.0 * c[1]).cos();
                v.push(sigma * (1.0 - r2).max(0.0).powi(2) * ripple);
            }
        }
    }
    v
}

/// Both sides of a multi-medium scene: the CPU media per estimator name and the GPU media.
struct MultiScene {
    grid: Arc<PinGrid>,
    fields: Vec<Arc<VoxelGrid>>,
    majorants: Vec<Arc<MajorantGrid>>,
    samplers: Vec<Arc<dyn TransportEstimator>>,
    base: VoxelGrid,
}

impl MultiScene {
    fn new() -> Self {
        let n = 12;
        let values = blob_voxels(n, 6.0);
        let spacing = [2.0 / n as f64; 3];
        let base = VoxelGrid::new([n; 3], [-1.0; 3], spacing, values.clone()).unwrap();
        let owned = blob_grid(4, Directions::Octahedral { n: 4 }, 2, 0.25);
        let grid = &load(&owned);
        let mut fields = Vec::new();
        let mut majorants = Vec::new();
        let mut samplers: Vec<Arc<dyn TransportEstimator>> = Vec::new();
        for off in OFFSETS {
            let origin = [0, 1, 2].map(|a| -1.0 + off[a]);
            let f = Arc::new(VoxelGrid::new([n; 3], origin, spacing, values.clone()).unwrap());
            majorants.push(Arc::new(MajorantGrid::from_field(&*f, [4, 4, 4]).unwrap()));
            fields.push(f);
            let m = translated_identity(off);
            samplers.push(Arc::new(
                PinsEstimator::new(grid.clone(), Some(&m), SamplerOptions::default()).unwrap(),
            ));
        }
        MultiScene {
            grid: grid.clone(),
            fields,
            majorants,
            samplers,
            base,
        }
    }

    fn cpu_media(&self, est: EstimatorSpec) -> Vec<Medium> {
        (0..OFFSETS.len())
            .map(|k| {
                let f = self.fields[k].clone();
                let maj = self.majorants[k].clone();
                let ratio: Arc<dyn TransportEstimator> =
                    Arc::new(crate::render::RatioTracking::new(f.clone(), maj.clone()));
                match est {
                    EstimatorSpec::RayMarching { rel_step } => Medium::single(Arc::new(
                        crate::render::RayMarching::new(f, rel_step).unwrap(),
                    )),
                    EstimatorSpec::DeltaTracking => {
                        Medium::single(Arc::new(crate::render::DeltaTracking::new(f, maj)))
                    }
                    EstimatorSpec::RatioTracking => Medium::single(ratio),
                    EstimatorSpec::ResidualRatioTracking { control } => Medium::single(Arc::new(
                        crate::render::ResidualRatioTracking::new(f, maj, control).unwrap(),
                    )),
                    EstimatorSpec::Pins => Medium::single(self.samplers[k].clone()),
                    EstimatorSpec::PinMs => Medium::new(ratio, self.samplers[k].clone()),
                    // pinres reads a control section, which these pins lack
                    // (`residual_estimators_match_cpu` compares it).
                    EstimatorSpec::PinRes => {
                        panic!("{est} has no GPU twin to compare here")
                    }
                }
            })
            .collect()
    }

    fn gpu_media(&self) -> GpuMedia<'_> {
        placed(
            GpuDensity::from_voxel_grid(self.base.clone()).unwrap(),
            &self.majorants,
            Some(&*self.grid),
        )
    }
}

fn translated_identity(off: [f64; 3]) -> [f64; 12] {
    [
        1.0, 0.0, 0.0, off[0], 0.0, 1.0, 0.0, off[1], 0.0, 0.0, 1.0, off[2],
    ]
}

fn cpu_render_media(media: Vec<Medium>, scene: &GpuScene, spp: u32, seed: u64) -> Image {
    let settings = RenderSettings {
        max_bounces: scene.max_bounces,
        seed,
        budget: Budget::Spp(spp),
        threads: None,
    };
    render(&scene.to_scene(media), &settings).unwrap().image
}

#[test]
fn every_estimator_matches_cpu_with_instances() {
    let ms = MultiScene::new();
    let renderer = shared_renderer(&ms.gpu_media()).unwrap();
    assert_eq!(renderer.media_count(), 3);
    let mut sc = scene(24, 0.9, 0.3, 3);
    sc.camera.origin = [0.5, 0.8, 4.5];
    sc.camera.target = [0.05, 0.3, 0.05];
    for est in [
        EstimatorSpec::RayMarching { rel_step: 0.05 },
        EstimatorSpec::DeltaTracking,
        EstimatorSpec::RatioTracking,
        EstimatorSpec::Pins,
        EstimatorSpec::PinMs,
    ] {
        let name = format!("3 instances, {}", est);
        compare_with(
            &name,
            |k| renderer.render(&sc, est, 2, 100 + k).unwrap(),
            |k| cpu_render_media(ms.cpu_media(est), &sc, 2, 900 + k),
            24,
            2,
            (4.5, 4),
        );
    }
    // Transmitted environment only: ray marching is deterministic along each ray, so the
    // two sides differ only by the pixel jitter and f32 (GPU) against f64 (CPU) arithmetic.
    let mut t_only = sc.clone();
    t_only.albedo = 0.0;
    let (g, _) = compare_with(
        "3 instances, rm@0.02, albedo 0",
        |k| {
            renderer
                .render(
                    &t_only,
                    EstimatorSpec::RayMarching { rel_step: 0.02 },
                    2,
                    7 + k,
                )
                .unwrap()
        },
        |k| {
            cpu_render_media(
                ms.cpu_media(EstimatorSpec::RayMarching { rel_step: 0.02 }),
                &t_only,
                2,
                70 + k,
            )
        },
        16,
        2,
        (4.5, 3),
    );
    let env = grey(t_only.env_radiance);
    let dark = g.mean.iter().cloned().fold(f64::INFINITY, f64::min);
    assert!(
        dark < 0.3 * env,
        "the media must be visible: darkest {dark}"
    );
}

/// The closed-form cosine noise on the GPU against the same formula on the CPU (f64).
#[test]
fn cosine_density_matches_cpu() {
    let waves = vec![
        CosineWave {
            w: [40.0, 3.0, -7.0],
            amplitude: 0.5,
            phase: 0.3,
        },
        CosineWave {
            w: [-5.0, 31.0, 12.0],
            amplitude: 0.3,
            phase: 2.0,
        },
        CosineWave {
            w: [0.0, 0.0, 0.0],
            amplitude: 0.2,
            phase: 1.0,
        },
    ];
    let (lo, hi) = ([-1.0, -0.8, -1.0], [1.0, 0.8, 1.0]);
    let density = 3.0f32;
    let gpu_density = GpuDensity::cosine(lo, hi, density, waves.clone()).unwrap();
    let cpu_waves = waves.clone();
    let field = Arc::new(crate::render::FnField {
        min: lo,
        max: hi,
        f: move |p: Vec3| {
            let p = p.as_dvec3();
            let mut s = 1.0f64;
            for w in &cpu_waves {
                let wv = glam::DVec3::from_array(w.w.map(f64::from));
                s += f64::from(w.amplitude) * (wv.dot(p) + f64::from(w.phase)).cos();
            }
            (f64::from(density) * s).max(0.0) as f32
        },
    });
    // Exact majorant: density * (1 + sum |amplitude|).
    let maj = Arc::new(MajorantGrid::uniform(lo, hi, density * 2.0 * 1.0001).unwrap());
    let media = GpuMedia {
        grids: Vec::new(),
        densities: vec![gpu_density],
        media: vec![GpuMedium {
            pins: None,
            density: Some(GpuPlacedDensity {
                density: 0,
                translation: [0.0; 3],
                placement: None,
                majorants: Some(maj.clone()),
                controls: Vec::new(),
            }),
        }],
    };
    let renderer = shared_renderer(&media).unwrap();
    let mut sc = scene(24, 0.85, 0.5, 3);
    sc.camera.origin = [0.9, 0.7, 3.6];
    for (est, cpu) in [
        (
            EstimatorSpec::RayMarching { rel_step: 0.01 },
            Medium::single(Arc::new(
                crate::render::RayMarching::new(field.clone(), 0.01).unwrap(),
            )),
        ),
        (
            // Paired on both sides: one walk for a ray's transmittance and distance.
            EstimatorSpec::RatioTracking,
            Medium::single(Arc::new(crate::render::RatioTracking::new(
                field.clone(),
                maj.clone(),
            ))),
        ),
    ] {
        let name = format!("cosine, {}", est);
        compare_with(
            &name,
            |k| renderer.render(&sc, est, 2, 300 + k).unwrap(),
            |k| cpu_render_media(vec![cpu.clone()], &sc, 2, 3000 + k),
            24,
            2,
            (4.5, 4),
        );
    }
    // Pins are not part of these media: asking for them is an error, not a silent render.
    let r = renderer.render(&sc, EstimatorSpec::PinMs, 1, 0);
    assert!(matches!(r, Err(GpuRenderError::Invalid(_))), "{r:?}");
}

#[test]
fn media_and_estimators_are_checked() {
    let owned = blob_grid(3, Directions::THESIS_DEFAULT, 1, 0.3);
    let grid = &load(&owned);
    let sc = scene(8, 0.5, 0.0, 2);
    // Pins only: every density estimator is refused with the medium named.
    let pins_only = pins_renderer(grid);
    for est in [
        EstimatorSpec::RayMarching { rel_step: 0.1 },
        EstimatorSpec::DeltaTracking,
        EstimatorSpec::RatioTracking,
        EstimatorSpec::PinMs,
    ] {
        match pins_only.render(&sc, est, 1, 0) {
            Err(GpuRenderError::Invalid(e)) => assert!(e.to_string().contains("medium 0"), "{e}"),
            other => panic!("{est:?}: {other:?}"),
        }
    }
    // A density without majorants: ray marching yes, trackers no.
    let base = VoxelGrid::new([2, 2, 2], [-1.0; 3], [1.0; 3], vec![1.0; 8]).unwrap();
    let media = GpuMedia {
        grids: Vec::new(),
        densities: vec![GpuDensity::from_voxel_grid(base).unwrap()],
        media: vec![GpuMedium {
            pins: None,
            density: Some(GpuPlacedDensity {
                density: 0,
                translation: [0.0; 3],
                placement: None,
                majorants: None,
                controls: Vec::new(),
            }),
        }],
    };
    let r = shared_renderer(&media).unwrap();
    assert!(
        r.render(&sc, EstimatorSpec::RayMarching { rel_step: 0.1 }, 1, 0)
            .is_ok()
    );
    assert!(r.render(&sc, EstimatorSpec::DeltaTracking, 1, 0).is_err());
    for bad in [0.0, -0.1, 1.5, f64::NAN] {
        let e = r.render(&sc, EstimatorSpec::RayMarching { rel_step: bad }, 1, 0);
        assert!(matches!(e, Err(GpuRenderError::Invalid(_))), "{bad}: {e:?}");
    }
    // No media at all: the environment, unattenuated.
    let empty = shared_renderer(&GpuMedia::default()).unwrap();
    let img = empty.render(&sc, EstimatorSpec::Pins, 2, 0).unwrap();
    let env = sc.env_radiance;
    assert!(
        img.rgb
            .iter()
            .all(|p| (0..3).all(|c| (p[c] - env[c]).abs() < 1e-6))
    );
    // Dangling indices and non-finite placements are errors at upload.
    let mut bad = media.clone();
    bad.media[0].density.as_mut().unwrap().density = 1;
    assert!(shared_renderer(&bad).is_err());
    let mut bad = media.clone();
    bad.media[0].density.as_mut().unwrap().translation[2] = f64::NAN;
    assert!(shared_renderer(&bad).is_err());
    let mut bad = GpuMedia::pins_only(grid, None, SamplerOptions::default());
    bad.media[0].pins.as_mut().unwrap().grid = 3;
    assert!(shared_renderer(&bad).is_err());
    let mut singular = GpuMedia::pins_only(grid, Some(&[0.0; 12]), SamplerOptions::default());
    assert!(shared_renderer(&singular).is_err());
    singular.media[0].pins.as_mut().unwrap().local_to_world = None;
    assert!(shared_renderer(&singular).is_ok());
    // Densities are validated on construction.
    assert!(GpuDensity::voxels([2, 1, 1], [0.0; 3], [1.0; 3], vec![1.0]).is_err());
    assert!(GpuDensity::voxels([1, 1, 1], [0.0; 3], [0.0; 3], vec![1.0]).is_err());
    assert!(GpuDensity::cosine([0.0; 3], [1.0; 3], f32::NAN, Vec::new()).is_err());
    assert!(GpuDensity::cosine([0.0; 3], [0.0; 3], 1.0, Vec::new()).is_err());
    // NaN, negative and infinite voxels are cleaned as the CPU estimators clean them.
    let d = GpuDensity::voxels(
        [4, 1, 1],
        [0.0; 3],
        [1.0; 3],
        vec![f32::NAN, -1.0, f32::INFINITY, 2.0],
    )
    .unwrap();
    let GpuDensityKind::Voxels(grid) = &d.kind else {
        unreachable!()
    };
    assert_eq!(grid.parts().3, &[0.0, 0.0, f32::MAX, 2.0]);
}

/// docs/background.md section 3 on the GPU path tracer: an empty medium (extinction 0, majorant 0), an
/// opaque one (extinction 1e30, majorant 1e30) and NaN / infinite voxels give finite images
/// with the expected transmittance for every estimator.
#[test]
fn stiff_media_stay_finite() {
    let mut sc = scene(16, 0.0, 0.0, 3);
    sc.camera.origin = [0.0, 0.0, 4.0];
    sc.camera.target = [0.0, 0.0, 0.0];
    sc.camera.vfov_deg = 20.0; // every pixel's ray crosses the box [-1, 1]^3
    let env = sc.env_radiance;
    let estimators = [
        EstimatorSpec::RayMarching { rel_step: 0.05 },
        EstimatorSpec::DeltaTracking,
        EstimatorSpec::RatioTracking,
    ];
    for (label, value, expect_t) in [
        ("empty", 0.0f32, 1.0f32),
        ("opaque 1e30", 1e30, 0.0),
        ("infinite", f32::INFINITY, 0.0),
        ("NaN", f32::NAN, 1.0),
    ] {
        let grid = VoxelGrid::new([2, 2, 2], [-1.0; 3], [1.0; 3], vec![value; 8]).unwrap();
        let maj = Arc::new(MajorantGrid::from_field(&grid, [2, 2, 2]).unwrap());
        let media = GpuMedia {
            grids: Vec::new(),
            densities: vec![GpuDensity::from_voxel_grid(grid.clone()).unwrap()],
            media: vec![GpuMedium {
                pins: None,
                density: Some(GpuPlacedDensity {
                    density: 0,
                    translation: [0.0; 3],
                    placement: None,
                    majorants: Some(maj),
                    controls: Vec::new(),
                }),
            }],
        };
        let r = shared_renderer(&media).unwrap();
        let grid = Arc::new(grid);
        let maj = media.media[0]
            .density
            .as_ref()
            .unwrap()
            .majorants
            .clone()
            .unwrap();
        for est in estimators {
            // Transmitted environment: exactly env * T, on both backends.
            let cpu_est: Arc<dyn TransportEstimator> = match est {
                EstimatorSpec::RayMarching { rel_step } => {
                    Arc::new(crate::render::RayMarching::new(grid.clone(), rel_step).unwrap())
                }
                EstimatorSpec::DeltaTracking => {
                    Arc::new(crate::render::DeltaTracking::new(grid.clone(), maj.clone()))
                }
                _ => Arc::new(crate::render::RatioTracking::new(grid.clone(), maj.clone())),
            };
            let cpu = cpu_render_media(vec![Medium::single(cpu_est)], &sc, 4, 1);
            let img = r.render(&sc, est, 4, 1).unwrap();
            for p in &cpu.rgb {
                for c in 0..3 {
                    assert!(
                        (p[c] - env[c] * expect_t).abs() <= 1e-6,
                        "[{label}, {}, cpu] pixel {p:?}, expected T = {expect_t}",
                        est
                    );
                }
            }
            for p in &img.rgb {
                for c in 0..3 {
                    assert!(
                        (p[c] - env[c] * expect_t).abs() <= 1e-6,
                        "[{label}, {}] pixel {p:?}, expected T = {expect_t}",
                        est
                    );
                }
            }
            // With scattering: finite and non-negative (an opaque box still scatters sun
            // light back from its surface).
            let mut lit = sc.clone();
            lit.albedo = 0.9;
            let img = r.render(&lit, est, 4, 2).unwrap();
            assert!(
                img.rgb.iter().flatten().all(|c| c.is_finite() && *c >= 0.0),
                "[{label}, {}] non-finite or negative pixel",
                est
            );
        }
    }
}

// ---------------------------------------------------------------------------------------
// Bricked densities
// ---------------------------------------------------------------------------------------

/// The multi-medium tests' blob at 24^3 (values rounded to f16 when `f16`), dense and in
/// bricks of 4 (the corner bricks are empty).
fn blob_bricks(f16: bool) -> (VoxelGrid, Arc<crate::render::BrickGrid>) {
    let n = 24;
    let mut values = blob_voxels(n, 6.0);
    if f16 {
        for v in &mut values {
            *v = half::f16::from_f32(*v).to_f32();
        }
    }
    let dense = VoxelGrid::new([n; 3], [-1.0; 3], [2.0 / n as f64; 3], values).unwrap();
    let mut bricks = crate::render::BrickGrid::from_voxels(&dense, 4).unwrap();
    if f16 {
        // Stored as f16, as a pin file's sparse section is read.
        let (dims, _, _) = bricks.shape();
        let ((origin, spacing), (index, values)) = (bricks.placement(), bricks.parts());
        let halves = (0..values.len())
            .map(|i| half::f16::from_f32(values.get(i).unwrap()))
            .collect();
        bricks =
            crate::render::BrickGrid::new_f16(dims, origin, spacing, 4, index.to_vec(), halves)
                .unwrap();
        assert!(matches!(bricks.parts().1, pin_format::SparseValues::F16(_)));
    }
    let bricks = Arc::new(bricks);
    let (_, _, stored) = bricks.shape();
    assert!(stored < 216, "some bricks must be empty");
    (dense, bricks)
}

/// `density` at [`OFFSETS`] with `majorants`, and the blob pin grid when `pins`.
fn placed<'g>(
    density: GpuDensity,
    majorants: &[Arc<MajorantGrid>],
    pins: Option<&'g PinGrid>,
) -> GpuMedia<'g> {
    GpuMedia {
        grids: pins.into_iter().collect(),
        densities: vec![density],
        media: (0..OFFSETS.len())
            .map(|k| GpuMedium {
                pins: pins.map(|_| GpuPins {
                    grid: 0,
                    local_to_world: Some(translated_identity(OFFSETS[k])),
                    options: SamplerOptions::default(),
                }),
                density: Some(GpuPlacedDensity {
                    density: 0,
                    translation: OFFSETS[k],
                    placement: None,
                    majorants: Some(majorants[k].clone()),
                    controls: Vec::new(),
                }),
            })
            .collect(),
    }
}

/// World-space majorants of `field`'s blob at each of [`OFFSETS`].
fn placed_majorants(dense: &VoxelGrid) -> Vec<Arc<MajorantGrid>> {
    let (dims, origin, spacing, values) = dense.parts();
    OFFSETS
        .iter()
        .map(|off| {
            let o = [0, 1, 2].map(|a| origin[a] + off[a]);
            let g = VoxelGrid::new(dims, o, spacing, values.to_vec()).unwrap();
            Arc::new(MajorantGrid::from_field(&g, [4, 4, 4]).unwrap())
        })
        .collect()
}

/// Many instances are walked by the media hierarchy, with the bits of the linear scan: the
/// media a ray meets, and the order they are asked in, are the scan's (24 overlapping and
/// scattered blobs with pins, densities and majorants; pins, and the trackers' transmittance
/// and shrinking nearest-collision search).
#[test]
fn the_media_hierarchy_renders_the_linear_scans_bits() {
    let n = 8;
    let values = blob_voxels(n, 5.0);
    let spacing = [2.0 / n as f64; 3];
    let base = VoxelGrid::new([n; 3], [-1.0; 3], spacing, values.clone()).unwrap();
    let grid = load(&blob_grid(4, Directions::Octahedral { n: 4 }, 1, 0.25));
    let mut rng = Rng::for_query(0x5CA7, 24);
    let offsets: Vec<[f64; 3]> = (0..24)
        .map(|_| [6.0, 1.5, 3.0].map(|w| f64::from(rng.next_f32() - 0.5) * w))
        .collect();
    let majorants: Vec<Arc<MajorantGrid>> = offsets
        .iter()
        .map(|off| {
            let o = [0, 1, 2].map(|a| -1.0 + off[a]);
            let g = VoxelGrid::new([n; 3], o, spacing, values.clone()).unwrap();
            Arc::new(MajorantGrid::from_field(&g, [2, 2, 2]).unwrap())
        })
        .collect();
    let media = GpuMedia {
        grids: vec![&*grid],
        densities: vec![GpuDensity::from_voxel_grid(base).unwrap()],
        media: offsets
            .iter()
            .zip(&majorants)
            .map(|(off, maj)| GpuMedium {
                pins: Some(GpuPins {
                    grid: 0,
                    local_to_world: Some(translated_identity(*off)),
                    options: SamplerOptions::default(),
                }),
                density: Some(GpuPlacedDensity {
                    density: 0,
                    translation: *off,
                    placement: None,
                    majorants: Some(maj.clone()),
                    controls: Vec::new(),
                }),
            })
            .collect(),
    };
    let walked = shared_renderer(&media).unwrap();
    assert!(walked.has_bvh(), "24 media are walked by the hierarchy");
    let scanned = shared_renderer(&media).unwrap().without_bvh();
    let mut sc = scene(24, 0.9, 0.3, 2);
    sc.camera.origin = [1.0, 2.0, 8.0];
    sc.camera.target = [0.0, 0.0, 0.0];
    sc.camera.vfov_deg = 50.0;
    for est in [
        EstimatorSpec::DeltaTracking,
        EstimatorSpec::RatioTracking,
        EstimatorSpec::Pins,
    ] {
        let a = walked.render(&sc, est, 2, 7).unwrap();
        let b = scanned.render(&sc, est, 2, 7).unwrap();
        assert!(grey(a.rgb[a.rgb.len() / 2]) > 0.0 || a.rgb.iter().any(|p| p[0] > 0.0));
        assert_eq!(
            image_bits(&a),
            image_bits(&b),
            "{est}: the walk differs from the scan"
        );
    }
}

/// A pipeline compiled from the text specialised to its estimators renders the bits of one
/// compiled from the whole text: PinMS with one medium (ratio tracking, its paired walk and
/// pins: the most cases kept, each dispatch pruned), pins with several (one case left in
/// each dispatch). Each whole-text pipeline costs a second or more of CPU on lavapipe, so
/// these two stand for the rest.
#[test]
fn specialised_pipelines_render_the_whole_texts_bits() {
    let ctx = context();
    let whole = GpuPipelines::unspecialised(&ctx.device, &ctx.queue, &ctx.limits);
    let grid = load(&blob_grid(4, Directions::Octahedral { n: 4 }, 2, 0.25));
    let (dense, _) = blob_bricks(false);
    let majorants = Arc::new(MajorantGrid::from_field(&dense, [2, 2, 2]).unwrap());
    let one = GpuMedia {
        grids: vec![&*grid],
        densities: vec![GpuDensity::from_voxel_grid(dense).unwrap()],
        media: vec![GpuMedium {
            pins: Some(GpuPins {
                grid: 0,
                local_to_world: None,
                options: SamplerOptions::default(),
            }),
            density: Some(GpuPlacedDensity {
                density: 0,
                translation: [0.0; 3],
                placement: None,
                majorants: Some(majorants),
                controls: Vec::new(),
            }),
        }],
    };
    let ms = MultiScene::new();
    let several = ms.gpu_media();
    let mut sc = scene(16, 0.9, 0.3, 3);
    sc.camera.origin = [0.5, 0.8, 4.5];
    sc.camera.target = [0.05, 0.3, 0.05];
    let cases = [
        (&one, EstimatorSpec::PinMs),
        (&several, EstimatorSpec::Pins),
    ];
    for (media, est) in cases {
        let specialised = shared_renderer(media).unwrap();
        let full = GpuRenderer::with_media_in(&whole, media).unwrap();
        let want = image_bits(&full.render(&sc, est, 2, 31).unwrap());
        assert!(want.iter().any(|&b| b != 0), "{est}: an empty image");
        let got = image_bits(&specialised.render(&sc, est, 2, 31).unwrap());
        assert!(
            want == got,
            "{est}, {} media: the bits differ",
            media.media.len()
        );
    }
}

fn image_bits(im: &Image) -> Vec<u32> {
    im.rgb.iter().flat_map(|p| p.map(f32::to_bits)).collect()
}

/// A bricked density renders the bits of its dense expansion with every GPU estimator (the
/// shader reads the same eight voxels and does the same f32 arithmetic), f32 and f16 bricks,
/// whole or split over several value bindings; a split that does not fit is one error.
#[test]
fn bricked_density_renders_the_dense_bits_whole_or_split() {
    let ctx = context();
    let owned = blob_grid(4, Directions::Octahedral { n: 4 }, 2, 0.25);
    let grid = load(&owned);
    let mut sc = scene(24, 0.9, 0.3, 3);
    sc.camera.origin = [0.5, 0.8, 4.5];
    sc.camera.target = [0.05, 0.3, 0.05];
    for f16 in [false, true] {
        let (dense, bricks) = blob_bricks(f16);
        let maj = placed_majorants(&dense);
        let gd = GpuDensity::from_voxel_grid(dense.clone()).unwrap();
        let gb = GpuDensity::from_bricks(bricks.clone()).unwrap();
        assert_eq!(gd.bounds, gb.bounds);
        let dense_r = shared_renderer(&placed(gd.clone(), &maj, Some(&grid))).unwrap();
        let brick_r = shared_renderer(&placed(gb.clone(), &maj, Some(&grid))).unwrap();
        assert_eq!((dense_r.brick_bindings(), brick_r.brick_bindings()), (0, 1));
        // Split over as many bindings as the device gives the brick values (26 on lavapipe),
        // whole bricks in each, with room for the other buffers (the largest is the density
        // data; they are smaller without pins). The f32 bricks then take more bindings than
        // the shader file's sixteen, so the generated shader runs.
        let (_, brick, stored) = bricks.shape();
        let brick_bytes = u64::from(brick).pow(3) * if f16 { 2 } else { 4 };
        let total = brick_bytes * stored as u64;
        let available = value_bindings(&ctx.limits);
        let others = media::pack(&placed(gb.clone(), &maj, None), u64::MAX, available)
            .unwrap()
            .data
            .len() as u64
            * 4;
        let per_binding = (stored as u64)
            .div_ceil(available as u64)
            .max(others.div_ceil(brick_bytes));
        let limit = brick_bytes * per_binding;
        let dense_np = shared_renderer(&placed(gd, &maj, None)).unwrap();
        let split = shared_renderer_limited(&placed(gb.clone(), &maj, None), limit).unwrap();
        assert_eq!(
            split.brick_bindings() as u64,
            (stored as u64).div_ceil(per_binding)
        );
        if !f16 && available >= 24 {
            assert!(
                split.brick_bindings() > 16,
                "{} bindings",
                split.brick_bindings()
            );
        }
        // Every estimator on the f32 bricks; the f16 ones and the splits share the code
        // below the value fetch, so one estimator each (each pipeline costs seconds to
        // compile on lavapipe): ratio tracking on the f16 bricks, ray marching (it reads the
        // most voxels) on the splits.
        let all = [
            EstimatorSpec::RayMarching { rel_step: 0.05 },
            EstimatorSpec::DeltaTracking,
            EstimatorSpec::RatioTracking,
            EstimatorSpec::PinMs,
        ];
        let whole: &[EstimatorSpec] = if f16 { &all[2..3] } else { &all };
        for &est in whole {
            let want = image_bits(&dense_r.render(&sc, est, 2, 77).unwrap());
            let got = image_bits(&brick_r.render(&sc, est, 2, 77).unwrap());
            assert!(want == got, "f16 {f16}, {}: bricked bits differ", est);
        }
        let est = all[0];
        let want = image_bits(&dense_np.render(&sc, est, 2, 78).unwrap());
        let got = image_bits(&split.render(&sc, est, 2, 78).unwrap());
        assert!(want == got, "f16 {f16}, {}: split bits differ", est);
        if !f16 {
            // No stored brick at all: the bricked path still runs (and reads 0), the
            // environment comes through unattenuated.
            let zeros =
                VoxelGrid::new([24; 3], [-1.0; 3], [2.0 / 24.0; 3], vec![0.0; 24 * 24 * 24]);
            let empty =
                Arc::new(crate::render::BrickGrid::from_voxels(&zeros.unwrap(), 4).unwrap());
            assert_eq!(empty.shape().2, 0);
            let d = GpuDensity::from_bricks(empty).unwrap();
            let r = shared_renderer(&placed(d, &maj, None)).unwrap();
            assert_eq!(r.brick_bindings(), 0);
            let mut t_only = sc.clone();
            t_only.albedo = 0.0;
            let img = r
                .render(&t_only, EstimatorSpec::RatioTracking, 1, 5)
                .unwrap();
            let env = t_only.env_radiance;
            assert!(
                img.rgb
                    .iter()
                    .all(|p| (0..3).all(|c| (p[c] - env[c]).abs() < 1e-6))
            );
        }
        // Whole bricks per binding: with one binding fewer than the split uses, the same
        // bricks and binding size are refused in one line.
        let fewer = split.brick_bindings() - 1;
        let e = media::pack(&placed(gb, &maj, None), limit, fewer)
            .err()
            .expect("one binding too few")
            .to_string();
        assert!(
            e.contains(&format!("{total} bytes of brick values"))
                && e.contains(&format!("{fewer} storage bindings of {limit} bytes"))
                && !e.contains('\n'),
            "{e}"
        );
    }
}

/// The GPU path tracer over bricks against the CPU one over the same [`BrickGrid`]s (f16
/// values, three instances): the same expected image, per pixel and overall.
#[test]
fn bricked_density_matches_cpu() {
    let (_, bricks) = blob_bricks(true);
    let (dims, brick, _) = bricks.shape();
    let ((origin, spacing), (index, values)) = (bricks.placement(), bricks.parts());
    let fields: Vec<Arc<crate::render::BrickGrid>> = OFFSETS
        .iter()
        .map(|off| {
            let o = [0, 1, 2].map(|a| origin[a] + off[a]);
            let g = crate::render::BrickGrid::new(
                dims,
                o,
                spacing,
                brick,
                index.to_vec(),
                (0..values.len()).map(|i| values.get(i).unwrap()).collect(),
            );
            Arc::new(g.unwrap())
        })
        .collect();
    let maj: Vec<Arc<MajorantGrid>> = fields
        .iter()
        .map(|f| Arc::new(MajorantGrid::from_field(&**f, [4, 4, 4]).unwrap()))
        .collect();
    let gb = GpuDensity::from_bricks(bricks.clone()).unwrap();
    let renderer = shared_renderer(&placed(gb, &maj, None)).unwrap();
    let mut sc = scene(24, 0.9, 0.3, 3);
    sc.camera.origin = [0.5, 0.8, 4.5];
    sc.camera.target = [0.05, 0.3, 0.05];
    for est in [
        EstimatorSpec::RayMarching { rel_step: 0.05 },
        EstimatorSpec::RatioTracking,
    ] {
        let cpu = |k: u64| {
            let media = (0..OFFSETS.len())
                .map(|i| {
                    let e: Arc<dyn TransportEstimator> = match est {
                        EstimatorSpec::RatioTracking => Arc::new(
                            crate::render::RatioTracking::new(fields[i].clone(), maj[i].clone()),
                        ),
                        _ => Arc::new(
                            crate::render::RayMarching::new(fields[i].clone(), 0.05).unwrap(),
                        ),
                    };
                    Medium::single(separate(e))
                })
                .collect();
            cpu_render_media(media, &sc, 2, 4000 + k)
        };
        compare_with(
            &format!("bricks, {}", est),
            |k| renderer.render(&sc, est, 2, 400 + k).unwrap(),
            cpu,
            24,
            2,
            (4.5, 4),
        );
    }
}

// ---------------------------------------------------------------------------------------
// Residual ratio tracking: residual, residual@min, pinres
// ---------------------------------------------------------------------------------------

/// The GPU's residual estimators (one WGSL walk; the controls differ).
const RESIDUALS: [EstimatorSpec; 3] = [
    EstimatorSpec::ResidualRatioTracking {
        control: crate::render::ResidualControl::Mean,
    },
    EstimatorSpec::ResidualRatioTracking {
        control: crate::render::ResidualControl::Min,
    },
    EstimatorSpec::PinRes,
];

/// The multi-medium tests' three blob instances as the renderers' medium descriptions (one
/// shared GPU density), with the blob pin grid carrying a control section baked from the
/// blob's voxels (6^3 bricks of 2 voxels, the baker's default rule otherwise).
fn residual_descs(ms: &MultiScene) -> Vec<crate::medium::MediumDesc> {
    use pinbake::control::{ControlDims, ControlOptions, bake_control};
    let mut owned = blob_grid(4, Directions::Octahedral { n: 4 }, 2, 0.25);
    let opts = ControlOptions {
        dims: ControlDims::Exact([6; 3]),
        ..ControlOptions::default()
    };
    let bbox = crate::render::Density::bounds(&ms.base);
    owned.control = Some(bake_control(&ms.base, &bbox, &opts).unwrap());
    let grid = load(&owned);
    let gpu = Arc::new(GpuDensity::from_voxel_grid(ms.base.clone()).unwrap());
    (0..OFFSETS.len())
        .map(|k| crate::medium::MediumDesc {
            field: Some(ms.fields[k].clone()),
            majorants: Some(ms.majorants[k].clone()),
            majorant_bricks: 4,
            pins: Some(crate::medium::PlacedPins {
                grid: grid.clone(),
                local_to_world: Some(translated_identity(OFFSETS[k])),
            }),
            gpu_density: Some(gpu.clone()),
            translation: OFFSETS[k],
            placement: None,
        })
        .collect()
}

/// `residual`, `residual@min` and `pinres` against their CPU estimators, over three
/// instances (no pairs: with several media each query is its own) and over one (where the
/// CPU answers a transmittance and a distance along one ray with ratio tracking's one walk,
/// and the GPU must too: the per-pixel variance ratio checks that).
#[test]
fn residual_estimators_match_cpu() {
    let ctx = context();
    let ms = MultiScene::new();
    let descs = residual_descs(&ms);
    let mut sc = scene(24, 0.9, 0.3, 3);
    sc.camera.origin = [0.5, 0.8, 4.5];
    sc.camera.target = [0.05, 0.3, 0.05];
    let lookup = SamplerOptions::default();
    // One medium: the environment alone, deep paths, where the pairs' correlation matters.
    let mut env_only = sc.clone();
    env_only.sun = None;
    env_only.albedo = 0.95;
    env_only.max_bounces = 8;
    for (label, media, sc) in [
        ("3 instances", &descs[..], &sc),
        ("1 medium, environment", &descs[..1], &env_only),
    ] {
        let gpu_media =
            crate::medium::gpu_media_for(media, &RESIDUALS.map(GpuEstimator::from), lookup)
                .unwrap();
        // pinres reads the control section, not the pins.
        assert!(gpu_media.grids.is_empty());
        let renderer = shared_renderer(&gpu_media).unwrap();
        for est in RESIDUALS {
            let cpu: Vec<Medium> = media
                .iter()
                .map(|d| d.cpu_medium(est, lookup).unwrap())
                .collect();
            compare_with(
                &format!("{label}, {}", est),
                |k| renderer.render(sc, est, 2, 100 + k).unwrap(),
                |k| cpu_render_media(cpu.clone(), sc, 2, 900 + k),
                24,
                2,
                (4.5, 4),
            );
        }
    }
    // Without its control a medium cannot answer: a one-line refusal naming the medium.
    let only_mean = crate::medium::gpu_media_for(&descs, &[RESIDUALS[0].into()], lookup).unwrap();
    let renderer = shared_renderer(&only_mean).unwrap();
    for est in &RESIDUALS[1..] {
        match renderer.render(&sc, *est, 1, 0) {
            Err(GpuRenderError::Invalid(e)) => {
                let e = e.to_string();
                assert!(
                    e.contains("residual control") && e.contains("medium 0"),
                    "{e}"
                );
            }
            other => panic!("{est}: {other:?}"),
        }
    }
    // The controls share the density data binding: a device whose bindings cannot hold
    // them refuses the media with one line naming the sizes.
    let small =
        crate::medium::gpu_media_for(&descs, &RESIDUALS.map(GpuEstimator::from), lookup).unwrap();
    let plain =
        crate::medium::gpu_media_for(&descs, &[EstimatorSpec::RatioTracking.into()], lookup)
            .unwrap();
    let plain_bytes = media::pack(&plain, u64::MAX, MAX_VALUE_BINDINGS)
        .unwrap()
        .data
        .len() as u64
        * 4;
    match GpuRenderer::with_media_limited(ctx, &small, plain_bytes) {
        Err(e) => assert!(e.to_string().contains("the density data"), "{e}"),
        Ok(_) => panic!("the controls must not fit the plain media's data binding"),
    }
}

/// The albedo-0 image of the cosine cube (amplitudes summing below 1, so the field is
/// never clamped at 0): per pixel `env * E[T]`, with `T` in closed form along 16 x 16
/// midpoint sub-pixel rays of the GPU's camera (the pixel jitter averages over the pixel).
fn cosine_pixel_expectations(
    sc: &GpuScene,
    (lo, hi): ([f64; 3], [f64; 3]),
    density: f64,
    waves: &[CosineWave],
) -> Vec<f64> {
    use glam::DVec3;
    let c = &sc.camera;
    let o = DVec3::from_array(c.origin.map(f64::from));
    let f = (DVec3::from_array(c.target.map(f64::from)) - o).normalize();
    let r = f.cross(DVec3::Y).normalize();
    let u = r.cross(f);
    let tan_half = (f64::from(c.vfov_deg).to_radians() * 0.5).tan();
    let (w, h) = (f64::from(c.width), f64::from(c.height));
    let aspect = w / h;
    let depth = |d: DVec3| -> f64 {
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for a in 0..3 {
            let (n, m) = ((lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]);
            t0 = t0.max(n.min(m));
            t1 = t1.min(n.max(m));
        }
        if !(t0 < t1) {
            return 0.0;
        }
        let len = t1 - t0;
        let mut tau = len;
        for wave in waves {
            let wv = DVec3::from_array(wave.w.map(f64::from));
            let (a, ph) = (f64::from(wave.amplitude), f64::from(wave.phase));
            let wd = wv.dot(d);
            let at = |t: f64| wv.dot(o + d * t) + ph;
            tau += if wd.abs() > 1e-9 {
                a * (at(t1).sin() - at(t0).sin()) / wd
            } else {
                a * at(t0).cos() * len
            };
        }
        density * tau
    };
    let env = grey(sc.env_radiance);
    const SUB: u32 = 16;
    let mut out = Vec::with_capacity((c.width * c.height) as usize);
    for py in 0..c.height {
        for px in 0..c.width {
            let mut sum = 0.0;
            for sy in 0..SUB {
                for sx in 0..SUB {
                    let x = f64::from(px) + (f64::from(sx) + 0.5) / f64::from(SUB);
                    let y = f64::from(py) + (f64::from(sy) + 0.5) / f64::from(SUB);
                    let a = (2.0 * x / w - 1.0) * tan_half * aspect;
                    let b = (1.0 - 2.0 * y / h) * tan_half;
                    sum += (-depth((f + r * a + u * b).normalize())).exp();
                }
            }
            out.push(env * sum / f64::from(SUB * SUB));
        }
    }
    out
}

/// The GPU's residual ratio tracking is unbiased: the albedo-0 image of a cosine cube
/// against its closed form, per pixel and for the image mean (z-tests from the replicates'
/// variance, fixed seeds), with both load-time controls. Mutation: the control's depth
/// counted 10% high in the walk (`depth + 1.1 * c * ...` in `rt_track`) fails it.
#[test]
fn residual_on_gpu_matches_the_cosine_closed_form() {
    let waves = vec![
        CosineWave {
            w: [9.0, 3.0, -7.0],
            amplitude: 0.5,
            phase: 0.3,
        },
        CosineWave {
            w: [-5.0, 11.0, 4.0],
            amplitude: 0.3,
            phase: 2.0,
        },
    ];
    let (lo, hi) = ([-1.0, -0.8, -1.0], [1.0, 0.8, 1.0]);
    let density = 0.5f32;
    let cpu_waves = waves.clone();
    let field: Arc<dyn crate::render::Density> = Arc::new(crate::render::FnField {
        min: lo,
        max: hi,
        f: move |p: Vec3| {
            let p = p.as_dvec3();
            let mut s = 1.0f64;
            for w in &cpu_waves {
                let wv = glam::DVec3::from_array(w.w.map(f64::from));
                s += f64::from(w.amplitude) * (wv.dot(p) + f64::from(w.phase)).cos();
            }
            (f64::from(density) * s).max(0.0) as f32
        },
    });
    // Bound: density * (1 + sum |amplitude|), on 4^3 bricks (each gets its own control).
    let bound = density * 1.8 * 1.0001;
    let maj = Arc::new(MajorantGrid::from_parts(lo, hi, [4; 3], vec![bound; 64]).unwrap());
    let desc = crate::medium::MediumDesc {
        field: Some(field),
        majorants: Some(maj),
        majorant_bricks: 4,
        pins: None,
        gpu_density: Some(Arc::new(
            GpuDensity::cosine(lo, hi, density, waves.clone()).unwrap(),
        )),
        translation: [0.0; 3],
        placement: None,
    };
    let ests = &RESIDUALS[..2];
    let media = crate::medium::gpu_media_for(
        std::slice::from_ref(&desc),
        &ests
            .iter()
            .map(|&e| e.into())
            .collect::<Vec<GpuEstimator>>(),
        SamplerOptions::default(),
    )
    .unwrap();
    let renderer = shared_renderer(&media).unwrap();
    // Every pixel's rays cross the cube (no pixel that only a corner grazes).
    let mut sc = scene(24, 0.0, 0.0, 0);
    sc.camera.origin = [0.3, 0.2, 4.0];
    sc.camera.vfov_deg = 18.0;
    let expected = cosine_pixel_expectations(&sc, (lo, hi), f64::from(density), &waves);
    let exp_mean = expected.iter().sum::<f64>() / expected.len() as f64;
    for est in ests {
        let images: Vec<Image> = (0..32)
            .map(|k| renderer.render(&sc, *est, 4, 700 + k).unwrap())
            .collect();
        let s = stats(&images);
        let (mut exceed, mut max_z, mut constant) = (0, 0.0f64, 0);
        for (i, e) in expected.iter().enumerate() {
            if s.var_mean[i].sqrt() <= 1e-9 {
                // Every sample of the pixel gave the same value (the replicates' variance is
                // 0 up to the rounding of their f64 mean): rays that miss the cube, or a
                // pixel that the cube's corner grazes, where no sample met a thin chord's
                // collision. No z there; the grazed part bounds the difference.
                constant += 1;
                assert!(
                    (s.mean[i] - e).abs() <= 2e-3 * grey(sc.env_radiance),
                    "[{est}] pixel {i}: {} vs {e}",
                    s.mean[i]
                );
                continue;
            }
            let z = (s.mean[i] - e) / s.var_mean[i].sqrt();
            max_z = max_z.max(z.abs());
            if z.abs() > 4.5 {
                exceed += 1;
            }
        }
        let z_image = (s.image_mean - exp_mean) / s.image_var_mean.sqrt();
        eprintln!(
            "[cosine closed form, {est}] 32 x 4 spp: image mean gpu {:.6} +- {:.6}, closed \
             form {exp_mean:.6}, z = {z_image:.2}; pixels beyond 4.5: {exceed} of {} \
             ({constant} constant), max |z| {max_z:.2}",
            s.image_mean,
            s.image_var_mean.sqrt(),
            expected.len()
        );
        assert!(z_image.abs() < 4.0, "[{est}] image mean z = {z_image}");
        assert!(exceed <= 3, "[{est}] {exceed} pixels beyond |z| 4.5");
        // The cube is in view and attenuates.
        assert!(
            expected.iter().cloned().fold(f64::INFINITY, f64::min) < 0.5 * grey(sc.env_radiance)
        );
    }
}

fn bits_of(im: &Image) -> Vec<u32> {
    im.rgb.iter().flat_map(|p| p.map(f32::to_bits)).collect()
}

#[test]
fn session_slices_give_the_batch_render_bits() {
    let owned = blob_grid(3, Directions::THESIS_DEFAULT, 1, 0.3);
    let grid = &load(&owned);
    let renderer = pins_renderer(grid);
    // Odd size: partial workgroups and a last band shorter than the others.
    let mut sc = scene(13, 0.9, 0.3, 3);
    sc.camera.height = 21;
    let batch = renderer.render(&sc, EstimatorSpec::Pins, 7, 9).unwrap();

    // One pass at a time.
    let mut one = renderer.session(&sc, EstimatorSpec::Pins, 9).unwrap();
    for _ in 0..7 {
        one.add_passes(1).unwrap();
    }
    assert_eq!(one.passes(), 7);
    assert_eq!(bits_of(&one.image().unwrap()), bits_of(&batch));

    // Bands of 8 rows (a zero slice asks for the smallest), capped at 7 passes.
    let mut banded = renderer.session(&sc, EstimatorSpec::Pins, 9).unwrap();
    let mut calls = 0;
    while banded.passes() < 7 {
        let long = std::time::Duration::from_secs(30);
        banded
            .add_for(long, std::time::Duration::ZERO, 7 - banded.passes())
            .unwrap();
        calls += 1;
        assert!(calls < 100, "add_for makes no progress");
    }
    assert_eq!(banded.passes(), 7, "add_for must not pass its cap");
    assert_eq!(bits_of(&banded.image().unwrap()), bits_of(&batch));

    // A pass left in progress (one band) is finished before the read-back.
    let mut partial = renderer.session(&sc, EstimatorSpec::Pins, 9).unwrap();
    partial.add_passes(6).unwrap();
    partial
        .add_for(std::time::Duration::ZERO, std::time::Duration::ZERO, 1)
        .unwrap();
    assert_eq!(bits_of(&partial.image().unwrap()), bits_of(&batch));
    assert!(
        renderer
            .session(&sc, EstimatorSpec::Pins, 9)
            .unwrap()
            .image()
            .is_err()
    );

    // Reset: another view from an empty accumulation, the same bits as its batch render.
    let mut moved = sc.clone();
    moved.sun = Some(Sun {
        dir: [-0.7, 0.2, 0.4],
        radiance: [5.0, 5.0, 5.0],
    });
    let moved_batch = renderer.render(&moved, EstimatorSpec::Pins, 3, 4).unwrap();
    assert_ne!(bits_of(&moved_batch), bits_of(&batch));
    one.reset(&moved, 4).unwrap();
    assert_eq!(one.passes(), 0);
    one.add_passes(3).unwrap();
    assert_eq!(bits_of(&one.image().unwrap()), bits_of(&moved_batch));
    let mut other_size = moved.clone();
    other_size.camera.width = 14;
    assert!(one.reset(&other_size, 4).is_err());
    let mut bad = moved.clone();
    bad.g = 2.0;
    assert!(matches!(
        one.reset(&bad, 4),
        Err(GpuRenderError::Invalid(_))
    ));
}

/// Reads an `Rgba8Unorm` texture back as RGB bytes.
fn read_rgb(ctx: &GpuContext, texture: &wgpu::Texture, w: u32, h: u32) -> Vec<u8> {
    let padded = (w * 4).div_ceil(256) * 256;
    let buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size: u64::from(padded * h),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut enc = ctx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
    enc.copy_texture_to_buffer(
        texture.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &buffer,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(padded),
                rows_per_image: Some(h),
            },
        },
        wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        },
    );
    ctx.queue.submit([enc.finish()]);
    buffer.slice(..).map_async(wgpu::MapMode::Read, |_| {});
    ctx.device
        .poll(wgpu::PollType::wait_indefinitely())
        .unwrap();
    let view = buffer.slice(..).get_mapped_range().unwrap();
    (0..h as usize)
        .flat_map(|y| {
            view[y * padded as usize..y * padded as usize + 4 * w as usize]
                .chunks_exact(4)
                .flat_map(|p| [p[0], p[1], p[2]])
                .collect::<Vec<_>>()
        })
        .collect()
}

#[test]
fn tone_map_pass_shows_what_the_png_holds() {
    let ctx = context();
    let owned = blob_grid(3, Directions::THESIS_DEFAULT, 1, 0.3);
    let grid = &load(&owned);
    let renderer = pins_renderer(grid);
    let sc = scene(24, 0.9, 0.3, 3);
    let mut session = renderer.session(&sc, EstimatorSpec::Pins, 5).unwrap();
    session.add_passes(4).unwrap();
    let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: None,
        size: wgpu::Extent3d {
            width: 24,
            height: 24,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba8Unorm,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    });
    let view = texture.create_view(&Default::default());
    let tone = GpuToneMap::new(&ctx.device, wgpu::TextureFormat::Rgba8Unorm);
    for exposure in [1.0f32, 4.0] {
        tone.draw(&session, &view, exposure);
        let shown = read_rgb(ctx, &texture, 24, 24);
        let image = session.image().unwrap();
        let png: Vec<u8> = image
            .rgb
            .iter()
            .flat_map(|p| p.map(|c| crate::render::tone_map(c, exposure)))
            .collect();
        assert_eq!(shown.len(), png.len());
        let diffs: Vec<i32> = shown
            .iter()
            .zip(&png)
            .map(|(&a, &b)| i32::from(a) - i32::from(b))
            .collect();
        let worst = diffs.iter().map(|d| d.abs()).max().unwrap();
        let off = diffs.iter().filter(|&&d| d != 0).count();
        // The mean and the sRGB curve in f32 on the GPU, f64/f32 on the CPU: a rare code
        // one step away where a value sits on a rounding boundary.
        assert!(worst <= 1, "exposure {exposure}: a code {worst} steps off");
        assert!(
            off * 50 <= diffs.len(),
            "exposure {exposure}: {off} codes off"
        );
        assert!(png.iter().any(|&c| c > 20), "the image must not be black");
    }
    // A pass in progress (one band of 8 rows): those rows show 5 samples, the others 4.
    let four = session.image().unwrap();
    session
        .add_for(std::time::Duration::ZERO, std::time::Duration::ZERO, 1)
        .unwrap();
    assert_eq!((session.passes(), session.next_row()), (4, 8));
    let five = renderer.render(&sc, EstimatorSpec::Pins, 5, 5).unwrap();
    tone.draw(&session, &view, 1.0);
    let shown = read_rgb(ctx, &texture, 24, 24);
    let mut worst = 0;
    for (i, &code) in shown.iter().enumerate() {
        let (pixel, channel) = (i / 3, i % 3);
        let source = if pixel / 24 < 8 { &five } else { &four };
        let want = crate::render::tone_map(source.rgb[pixel][channel], 1.0);
        worst = worst.max((i32::from(code) - i32::from(want)).abs());
    }
    assert!(
        worst <= 1,
        "the band in progress is shown {worst} codes off"
    );
}

/// The adapter `GpuContext::new` opens, with a device that has timestamp queries where the
/// adapter offers them (what the viewer requests), and whether it got them.
fn timestamp_device() -> (wgpu::Device, wgpu::Queue, wgpu::Limits, bool) {
    let ctx = context();
    pollster::block_on(async {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
        let adapters = instance.enumerate_adapters(wgpu::Backends::all()).await;
        let adapter = adapters
            .into_iter()
            .find(|a| {
                let i = a.get_info();
                i.name == ctx.adapter_info.name && i.backend == ctx.adapter_info.backend
            })
            .expect("the adapter GpuContext::new opened");
        let features = adapter.features() & wgpu::Features::TIMESTAMP_QUERY;
        let limits = adapter.limits();
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("timestamps"),
                required_features: features,
                required_limits: limits.clone(),
                ..Default::default()
            })
            .await
            .unwrap();
        (device, queue, limits, !features.is_empty())
    })
}

#[test]
fn pass_times_come_from_gpu_timestamps_where_the_device_has_them() {
    let owned = blob_grid(3, Directions::THESIS_DEFAULT, 1, 0.3);
    let grid = &load(&owned);
    let sc = scene(16, 0.9, 0.3, 3);
    let long = std::time::Duration::from_secs(30);

    // A device opened without the feature: wall time.
    let ctx = context();
    let plain = pins_renderer(grid);
    let mut wall = plain.session(&sc, EstimatorSpec::Pins, 2).unwrap();
    assert_eq!(wall.pass_time_source(), PassTimeSource::Wall);
    wall.add_for(long, long, 3).unwrap();
    assert_eq!(wall.pass_time_source(), PassTimeSource::Wall);
    assert!(wall.pass_seconds() > 0.0);

    // The same adapter with timestamp queries requested where it has them.
    let (device, queue, limits, has) = timestamp_device();
    let media = GpuMedia::pins_only(grid, None, SamplerOptions::default());
    let timed_renderer = GpuRenderer::with_media_on(&device, &queue, &limits, &media).unwrap();
    let mut timed = timed_renderer.session(&sc, EstimatorSpec::Pins, 2).unwrap();
    // Nothing timed yet: no GPU figure to report.
    assert_eq!(timed.pass_time_source(), PassTimeSource::Wall);
    let t = Instant::now();
    timed.add_for(long, long, 3).unwrap();
    let wall_seconds = t.elapsed().as_secs_f64();
    let want = if has {
        PassTimeSource::GpuTimestamps
    } else {
        PassTimeSource::Wall
    };
    assert_eq!(
        timed.pass_time_source(),
        want,
        "adapter {}",
        ctx.adapter_info.name
    );
    let seconds = timed.pass_seconds();
    assert!(seconds.is_finite() && seconds > 0.0, "{seconds}");
    // The GPU's time of the passes lies within the wall time around their submissions
    // and waits.
    assert!(
        3.0 * seconds <= wall_seconds,
        "3 passes of {seconds} s in {wall_seconds} s of wall time"
    );
    // Timing changes no bits.
    assert_eq!(timed.passes(), 3);
    assert_eq!(
        bits_of(&timed.image().unwrap()),
        bits_of(&plain.render(&sc, EstimatorSpec::Pins, 3, 2).unwrap())
    );
    // A reset forgets the timings of the old view.
    timed.reset(&sc, 2).unwrap();
    assert_eq!(timed.pass_time_source(), PassTimeSource::Wall);
}

// ---------------------------------------------------------------------------------------
// Instances placed by any affine map (a scene file's): every density query in the asset's
// frame
// ---------------------------------------------------------------------------------------

/// `T * Rz * Ry * Rx * S` (degrees): the scene file's own composition.
fn trs(translate: [f64; 3], rotate_deg: [f64; 3], scale: [f64; 3]) -> [f64; 12] {
    pin_scene::compose_trs(&pin_scene::Trs {
        translate,
        rotate_deg,
        scale,
    })
}

/// Turned and non-uniformly stretched instances of the multi-medium tests' blob (one
/// of them mirrored, one a pure translation).
fn placed_transforms() -> [[f64; 12]; 3] {
    [
        trs([0.1, 0.0, 0.0], [20.0, 35.0, -10.0], [1.6, 0.7, 1.0]),
        trs([0.8, 0.35, -0.4], [0.0, 90.0, 30.0], [0.6, 1.3, -0.9]),
        trs([-0.7, 0.5, 0.4], [0.0; 3], [1.0; 3]),
    ]
}

/// The blob as one asset (its field, majorants, GPU copy and a pin grid with a control
/// section, all in the asset's frame, each shared) placed by `transforms`.
fn placed_descs(ms: &MultiScene, transforms: &[[f64; 12]]) -> Vec<crate::medium::MediumDesc> {
    let mut local = residual_descs(ms).swap_remove(0);
    let field: Arc<dyn crate::render::Density> = Arc::new(ms.base.clone());
    local.majorants = Some(Arc::new(MajorantGrid::from_field(&*field, [4; 3]).unwrap()));
    local.field = Some(field);
    local.translation = [0.0; 3];
    local.pins.as_mut().unwrap().local_to_world = None;
    transforms
        .iter()
        .map(|m| crate::medium::MediumDesc {
            placement: Some(*m),
            ..local.clone()
        })
        .collect()
}

/// Every query path on instances turned, stretched per axis and mirrored (one a pure
/// translation) against the CPU's `instance::PlacedEstimator` over the same asset: three
/// overlapping instances, and one instance alone (where ratio and residual tracking answer a
/// transmittance and a distance from one walk), the environment only with deep paths. PinMS
/// and pinres are pairs of these paths (ratio and pins; residual with a baked control), each
/// a pipeline of seconds on lavapipe: `every_estimator_matches_cpu_with_instances` and
/// `residual_estimators_match_cpu` render them on instances.
#[test]
fn affine_instances_match_cpu_with_every_estimator() {
    let ms = MultiScene::new();
    let descs = placed_descs(&ms, &placed_transforms());
    let lookup = SamplerOptions::default();
    let mut sc = scene(20, 0.9, 0.3, 3);
    sc.camera.origin = [0.5, 0.9, 5.0];
    sc.camera.target = [0.05, 0.3, 0.05];
    sc.camera.vfov_deg = 48.0;
    let mut env_only = sc.clone();
    env_only.sun = None;
    env_only.albedo = 0.95;
    env_only.max_bounces = 8;
    let residual = EstimatorSpec::ResidualRatioTracking {
        control: crate::render::ResidualControl::Mean,
    };
    let every = [
        EstimatorSpec::RayMarching { rel_step: 0.05 },
        EstimatorSpec::DeltaTracking,
        EstimatorSpec::RatioTracking,
        residual,
        EstimatorSpec::Pins,
    ];
    let cases: [(
        &str,
        &[crate::medium::MediumDesc],
        &GpuScene,
        &[EstimatorSpec],
    ); 2] = [
        ("3 affine instances", &descs[..], &sc, &every),
        (
            "1 affine instance, environment",
            &descs[1..2],
            &env_only,
            &[EstimatorSpec::RatioTracking, residual],
        ),
    ];
    for (label, media, sc, ests) in cases {
        let gpu: Vec<GpuEstimator> = ests.iter().map(|&e| e.into()).collect();
        let gpu_media = crate::medium::gpu_media_for(media, &gpu, lookup).unwrap();
        // One asset: one density, one pin grid, uploaded once for every instance.
        assert_eq!(gpu_media.densities.len(), 1);
        assert!(gpu_media.grids.len() <= 1);
        let renderer = shared_renderer(&gpu_media).unwrap();
        for &est in ests {
            let cpu: Vec<Medium> = media
                .iter()
                .map(|d| d.cpu_medium(est, lookup).unwrap())
                .collect();
            let (g, _) = compare_with(
                &format!("{label}, {est}"),
                |k| renderer.render(sc, est, 2, 100 + k).unwrap(),
                |k| cpu_render_media(cpu.clone(), sc, 2, 900 + k),
                24,
                2,
                (4.5, 4),
            );
            // The blob's density is visible (the test pin grid is a faint random one).
            let env = grey(sc.env_radiance);
            let dark = g.mean.iter().cloned().fold(f64::INFINITY, f64::min);
            assert!(
                dark < 0.8 * env || est == EstimatorSpec::Pins,
                "{label}, {est}: the media must be visible ({dark} of {env})"
            );
        }
    }
}

/// Per instance the GPU holds its record, its pin parameters and its share of the media
/// hierarchy: an asset's density, majorants and controls are uploaded once however many
/// instances place it.
#[test]
fn an_assets_instances_share_one_upload() {
    let ms = MultiScene::new();
    let transforms = placed_transforms();
    let ests = [
        EstimatorSpec::RatioTracking.into(),
        EstimatorSpec::ResidualRatioTracking {
            control: crate::render::ResidualControl::Mean,
        }
        .into(),
        EstimatorSpec::PinRes.into(),
        EstimatorSpec::PinMs.into(),
    ];
    let bytes = |n: usize| {
        let all: Vec<[f64; 12]> = (0..n)
            .map(|i| {
                let mut m = transforms[i % 3];
                m[3] += (i / 3) as f64 * 3.0;
                m
            })
            .collect();
        let descs = placed_descs(&ms, &all);
        let media = crate::medium::gpu_media_for(&descs, &ests, SamplerOptions::default()).unwrap();
        let p = media::pack(&media, u64::MAX, MAX_VALUE_BINDINGS).unwrap();
        assert_eq!(p.records.len(), n);
        (
            p.data.len() * 4,
            p.records.len() * size_of::<media::MediumRecord>()
                + p.grid_params.len() * size_of::<media::GridParams>(),
        )
    };
    let (data_16, per_16) = bytes(16);
    let (data_4096, per_4096) = bytes(4096);
    assert_eq!(per_4096, 4096 * (288 + 128));
    assert_eq!(per_16 * 256, per_4096);
    // Beyond the per-instance records, the data grows only by the hierarchy's nodes (at most
    // two of 32 bytes per instance).
    let growth = (data_4096 - data_16) as f64 / (4096.0 - 16.0);
    eprintln!(
        "density data: {data_16} bytes for 16 instances, {data_4096} for 4096 ({growth:.1} per \
         instance); records and pin parameters {per_4096} bytes"
    );
    assert!(growth <= 64.0, "{growth} bytes of data per instance");
}
