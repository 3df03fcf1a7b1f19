//! `--offscreen`: the viewer measured where there is no display (a GPU machine without an X
//! server). The same progressive session as the window's, on the adapter the window picks
//! (`pinrender render --backend gpu`'s) with the window's device features, the same passes
//! added in the window's slices and frame budget, and each frame's accumulation tone-mapped
//! into a texture by the same pass, with no window and no egui. Its outputs are the scripted
//! window's: `--screenshot` (the texture read back), `--save` (the accumulation) and the
//! JSON line's fields that mean something without a window.

use std::time::Instant;

use anyhow::{Result, anyhow};
use pinrender::gpu_render::GpuToneMap;

use crate::app::pacing::{FRAME_BUDGET, FramePacer, SLICE};
use crate::app::readouts::{gpu_bytes, samples_per_second};
use crate::app::window::{IMAGE_FORMAT, device_descriptor, image_texture, write_image};
use crate::args::ViewArgs;
use crate::build::{BuildJob, Gpu};
use crate::compare::{self, PassClock};
use crate::export;
use crate::open::{BakeJob, Medium};
use crate::startup::StartupClock;
use crate::view::View;

/// The flags that need a window (or a second session) and are refused with `--offscreen`.
pub fn window_only_flags(a: &ViewArgs) -> Option<&'static str> {
    [
        ("--compare", a.compare.is_some()),
        ("--error-view", a.error_view),
        ("--pin-at", a.pin_at.is_some()),
        ("--grid-overlay", a.grid_overlay),
        ("--window-screenshot", a.window_screenshot.is_some()),
        ("--rebake-scale", a.rebake_scale.is_some()),
        ("--play", a.play),
        ("--input-script", a.input_script.is_some()),
    ]
    .into_iter()
    .find(|(_, given)| *given)
    .map(|(flag, _)| flag)
}

/// The adapter every GPU path opens (`pinrt::gpu::request_adapter`: a hardware GPU first,
/// else a software fallback), with the device the window opens on it.
fn open_device() -> Result<(Gpu, wgpu::AdapterInfo)> {
    let adapter = pollster::block_on(pinrt::gpu::request_adapter()).map_err(|e| anyhow!("{e}"))?;
    let (device, queue) = pollster::block_on(adapter.request_device(&device_descriptor(&adapter)))
        .map_err(|e| anyhow!("opening the GPU device: {e}"))?;
    let info = adapter.get_info();
    Ok((Gpu::new(device, queue, &info, None), info))
}

/// Renders `--frames` passes of `medium` off-screen, writes the outputs asked for and
/// returns the JSON line.
pub fn run(a: &ViewArgs, mut medium: Medium, mut clock: StartupClock) -> Result<serde_json::Value> {
    let passes = a.frames.unwrap_or(1);
    let (gpu, info) = open_device()?;
    clock.marks.window_and_device = clock.now();
    let estimator = a.estimator.unwrap_or_else(|| medium.default_estimator());
    // A volume's pins are baked first where the estimator reads them (the window bakes
    // them in the background and renders that estimator once they are in).
    if estimator.needs_pins() && medium.is_volume && medium.pins().is_none() {
        let mut job = BakeJob::start(&medium, a.preview_bake())?;
        let grid = loop {
            if let Some(done) = job.finished() {
                break done?;
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        };
        medium.set_pins(std::sync::Arc::new(grid));
    }
    let view = View::new(a, &medium, estimator);
    let media = medium.media_job(estimator)?;
    // Nothing to paint meanwhile: the build is waited for.
    let built = BuildJob::spawn(&gpu, media, view.scene(), view.seed, view.exposure, 0)?.wait()?;
    let since = |t: Instant| t.saturating_duration_since(clock.started).as_secs_f64();
    clock.marks.upload = since(built.uploaded);
    clock.marks.pipeline = since(built.compiled);
    let warm_up_s = built
        .warmed
        .saturating_duration_since(built.compiled)
        .as_secs_f64();
    let mut session = built.session;
    let (w, h) = (session.width(), session.height());
    let tone = GpuToneMap::new(&gpu.device, IMAGE_FORMAT);
    let texture = image_texture(&gpu.device, w, h, "pinview off-screen image");
    let target = texture.create_view(&wgpu::TextureViewDescriptor::default());
    // The coarse preview, as the window shows it until the first whole pass.
    let first_preview_s = built.preview.map(|rgba| {
        write_image(&gpu.queue, &texture, w, h, &rgba);
        clock.now()
    });
    // The frames: each adds passes within the window's budget and tone-maps the
    // accumulation, waited for as a presented frame would be.
    let mut pacer = FramePacer::new(Instant::now());
    let mut clock_side = PassClock::default();
    let mut render_seconds = 0.0;
    let mut first_image_s = None;
    while session.passes() < passes {
        pacer.tick(Instant::now());
        let remaining = passes - session.passes();
        clock_side.add(
            &mut session,
            &mut render_seconds,
            FRAME_BUDGET,
            SLICE,
            remaining,
        )?;
        if session.passes() > 0 {
            tone.draw(&session, &target, view.exposure);
            gpu.device
                .poll(wgpu::PollType::wait_indefinitely())
                .map_err(|e| anyhow!("waiting for the tone map: {e}"))?;
            if first_image_s.is_none() {
                let now = clock.now();
                first_image_s = Some(now);
                clock.marks.first_image = now;
            }
        }
    }
    pacer.tick(Instant::now());
    if let Some(path) = &a.screenshot {
        let rgb = export::read_texture_rgb(&gpu.device, &gpu.queue, &texture, w, h)?;
        export::write_png(path, w, h, &rgb)?;
    }
    if let Some(path) = &a.save {
        let image = session.image().map_err(|e| anyhow!("{e}"))?;
        image
            .write_exr(path)
            .map_err(|e| anyhow!("{}: {e}", path.display()))?;
    }
    let ms = compare::ms_per_pass(&session, render_seconds);
    let mut json = serde_json::json!({
        "adapter": info.name,
        "backend": format!("{:?}", info.backend),
        "device_type": format!("{:?}", info.device_type),
        "estimator": estimator.to_string(),
        "width": w,
        "height": h,
        "passes": session.passes(),
        "first_image_s": first_image_s.unwrap_or(0.0),
        "first_image_breakdown": clock.marks.breakdown(),
        "first_preview_s": first_preview_s,
        "warm_up_s": warm_up_s,
        // Off-screen renders the estimator asked for (else the default) from the first
        // image: no interim estimator, no switch.
        "first_image_estimator": first_image_s.map(|_| estimator.to_string()),
        "estimator_switch_s": null,
        "ms_per_pass": ms,
        "pass_time_source": session.pass_time_source().as_str(),
        "frame": null,
        "frame_path": null,
        "frames_played": [],
        "pipelines_compiled": gpu.stores.compiled(),
        "file": medium.path.display().to_string(),
        "samples_per_second": samples_per_second(w, h, ms),
        "gpu_bytes": gpu_bytes(Some(&built.renderer)),
        "longest_frame_gap_ms": pacer.longest_ms(),
        "frames_painted": pacer.frames(),
        "offscreen": true,
        "first_look": crate::open::first_look_json(a.first_look),
        // The batch render of the view rendered, at the passes rendered.
        "command": view.command_line(&medium, session.passes()),
    });
    if let Some(scene) = medium.scene() {
        json["instances"] = scene.instances.len().into();
    }
    Ok(json)
}
