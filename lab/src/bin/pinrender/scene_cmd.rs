//! `pinrender render --scene FILE`: a scene file's instances (`docs/scene.md`) rendered on
//! the CPU or the GPU path. The flags the scene can set (camera, sun, sky, albedo, g,
//! bounces) override it when given; the others mean what they mean for one volume.

use std::path::Path;

use anyhow::{Result, anyhow};
use pinlab::Estimator;
use pinrender::render::{
    Budget, DEFAULT_WAVEFRONT_BATCH, RenderSettings, SampleLoop, Scene, render, render_wavefront,
};
use pinrender::scene_media::{self, AssetOptions};
use pinrt::gpu::GpuContext;

use crate::render_cmd::{Job, RenderArgs, outputs, read_reference, render_gpu, write};
use pinrender::front;

pub fn run(a: RenderArgs, path: &Path) -> Result<()> {
    if a.volume.volume.is_some() {
        crate::usage!("--scene names its volumes; --volume cannot be given with it");
    }
    if let Some(flag) = a.volume.read.given().first() {
        crate::usage!("{flag} applies to --volume; a scene sets its assets' reading in the file");
    }
    let budget = a.flags.budget();
    front::flags::check_image(&budget, a.width, a.height)?;
    let scene = scene_media::load_scene(path, &budget)?;
    let spec = match a.estimator {
        Some(Estimator::Core(s)) => s,
        Some(other) => crate::usage!(
            "--scene renders with the renderer's estimators (ratio, delta, residual, rm, pins, \
             pinms, pinres), not {other}"
        ),
        None => scene_media::default_estimator(&scene),
    };
    let job = Job {
        estimator: Estimator::Core(spec),
        look: a.flags.look(Some(&scene)),
    };
    let max_gpu = pinrender::gpu_render::MAX_GPU_BOUNCES;
    if a.backend == "gpu" && job.look.max_bounces > max_gpu {
        // Named where the value came from: the flag, or the scene's own key.
        if a.flags.max_bounces.is_none() {
            anyhow::bail!(
                "{}: max_bounces: {} exceeds the GPU limit of {max_gpu} (--backend gpu)",
                path.display(),
                job.look.max_bounces
            );
        }
        crate::usage!(
            "--max-bounces {} exceeds the GPU limit of {max_gpu} (--backend gpu)",
            job.look.max_bounces
        );
    }
    // The output must replace neither the scene nor an asset.
    let mut inputs: Vec<&Path> = vec![path];
    for asset in &scene.assets {
        inputs.extend(asset.volume.as_deref());
        inputs.extend(asset.pins.as_deref());
    }
    outputs(&a, &inputs)?;
    // Read the reference first: a bad path should not cost a whole render.
    let reference = read_reference(&a)?;
    let opts = AssetOptions {
        estimator: spec,
        pin_cells: a.flags.pin_cells,
        seed: a.flags.seed,
        majorant_bricks: a.majorant_bricks,
        budget,
        allow_mismatched_pins: a.allow_mismatched_pins,
        lookup: a.lookup(),
        named_pins: false,
    };
    let ctx = if a.backend == "gpu" {
        Some(GpuContext::new().map_err(|e| anyhow!("{e}"))?)
    } else {
        None
    };
    let assets = scene_media::open_assets(&scene, &opts)?;
    let (cpu, descs, (lo, hi)) = match &ctx {
        None => {
            let m = scene_media::cpu_media(&scene, &assets, &opts)?;
            let b = m.bounds;
            (Some(m), Vec::new(), b)
        }
        Some(ctx) => {
            let (d, b) = scene_media::gpu_descs(&scene, &assets, &opts, &ctx.limits)?;
            (None, d, b)
        }
    };
    let (origin, target) = scene_media::camera_over(
        a.flags.camera_origin,
        a.flags.camera_target,
        Some(&scene),
        (lo, hi),
    );
    if origin == target {
        crate::usage!("the camera's origin and target are the same point");
    }
    let look = job.look;
    let frame = look.frame((origin, target), a.width, a.height);
    if let Some(ctx) = &ctx {
        let (image, spp, seconds) = render_gpu(&a, &job, ctx, &descs, &frame)?;
        return write(&a, &job, path, &image, spp, seconds, reference.as_ref());
    }
    let media = cpu.expect("a CPU render built its media").media;
    let frame = Scene { media, ..frame };
    let settings = RenderSettings {
        max_bounces: look.max_bounces,
        seed: a.flags.seed,
        budget: match a.seconds {
            Some(s) => Budget::Seconds(s),
            None => Budget::Spp(a.spp),
        },
        threads: a.threads,
    };
    let out = if job.estimator.plan().sample_loop == SampleLoop::Wavefront {
        render_wavefront(&frame, &settings, DEFAULT_WAVEFRONT_BATCH)
    } else {
        render(&frame, &settings)
    }
    .map_err(|e| anyhow!("{e}"))?;
    write(
        &a,
        &job,
        path,
        &out.image,
        out.spp,
        out.seconds,
        reference.as_ref(),
    )
}
