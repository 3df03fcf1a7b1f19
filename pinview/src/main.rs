//! `pinview`: an interactive GPU viewer of pin files and volumes (see `docs/viewer.md`).
//!
//! The window is winit (X11) drawing egui through egui-wgpu on the project's wgpu (`shell.rs`);
//! the image is the GPU path tracer's progressive session ([`pinrender::gpu_render::GpuSession`])
//! tone-mapped into a texture that egui shows: on a hardware adapter on the window's device,
//! never read back to draw; on a CPU adapter on a device of the renderer's own, copied over
//! through host memory (`build::Relay`: lavapipe compiles at a pipeline's first dispatch on
//! the device's queue, which would hold the window's frames).
//! Exit codes: 0 success, 1 a bad file, no display or no adapter, 2 usage.

mod app;
mod args;
mod build;
mod clipboard;
mod compare;
mod device;
mod error_view;
mod export;
mod failure_window;
mod gizmos;
mod input_script;
mod look_controls;
mod offscreen;
mod open;
mod pin_overlay;
mod scene_framing;
mod sequence;
mod shell;
mod startup;
mod sun_gizmo;
mod verify;
mod view;

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::{Result, anyhow};
use pin_volume::files::MemoryBudget;

use args::ViewArgs;
use open::Medium;
use pinrender::render::EstimatorSpec;

fn main() -> ExitCode {
    let started = Instant::now();
    let args: Vec<std::ffi::OsString> = std::env::args_os().collect();
    // The isolated OpenVDB reader re-executes this binary (see `pin_volume::vdb`).
    if let Some(code) = pin_volume::vdb::serve_vdb_worker_if_asked(&args) {
        return code;
    }
    pin_cli::run_main("pinview", args, |a: ViewArgs| run(a, started))
}

/// Opens one frame or file as the viewer reads it, within the command's one budget
/// (`--max-memory`): a scene's assets together, a pin file's mapping, a volume's read, its
/// dense copies and the bake the viewer starts in the background, as `pinrender render`
/// charges them.
fn open_medium(path: &Path, a: &ViewArgs, budget: &MemoryBudget) -> Result<Medium> {
    if open::is_scene_file(path) {
        if let Some(flag) = a.read.given().first() {
            pin_cli::usage!(
                "{flag} applies to a volume; the scene {} sets its assets' reading in the file",
                path.display()
            );
        }
        return Medium::open_scene(path, a.estimator, a.flags.seed, budget);
    }
    if open::is_pin_file(path)
        && let Some(flag) = a.read.given().first()
    {
        pin_cli::usage!(
            "{flag} applies to a volume, not to the pin file {}",
            path.display()
        );
    }
    Medium::open(path, &a.read, &a.flags, budget)
}

/// A volume opened without `--density-scale` (one file, not a sequence's frame) is opened
/// again at the scale of its first look ([`pinrender::front::first_look`]), seen from the
/// camera the view starts at; that scale then stands in the flags as if given, so that the
/// copied command, the density-scale slider and the background bake all carry it.
fn at_first_look(
    medium: Medium,
    path: &Path,
    a: &mut ViewArgs,
    sequence: bool,
    budget: &MemoryBudget,
) -> Result<Medium> {
    if !medium.is_volume || sequence || ViewArgs::density_scale_given() {
        return Ok(medium);
    }
    let Some(field) = medium.field() else {
        return Ok(medium);
    };
    let (origin, target) = pinrender::scene_media::camera_over(
        a.flags.camera_origin,
        a.flags.camera_target,
        None,
        medium.bounds,
    );
    let view = std::array::from_fn(|k| target[k] - origin[k]);
    let Some(look) = pinrender::front::first_look::first_look(field.as_ref(), view) else {
        return Ok(medium);
    };
    a.first_look = Some(look);
    if look.scale == 1.0 {
        return Ok(medium);
    }
    a.read.density_scale = pin_volume::DensityScale::new(look.scale).map_err(|e| anyhow!("{e}"))?;
    drop(medium);
    Medium::open(path, &a.read, &a.flags, budget)
}

/// The flags a scene file refuses: what needs one medium (an overlay of its pins, a
/// comparison, the error view, a re-bake), and bounces beyond the GPU's limit.
fn scene_flags(a: &ViewArgs, medium: &Medium) -> Result<()> {
    let one_medium = [
        ("--compare", a.compare.is_some()),
        ("--error-view", a.error_view),
        ("--pin-at", a.pin_at.is_some()),
        ("--grid-overlay", a.grid_overlay),
        ("--rebake-scale", a.rebake_scale.is_some()),
    ];
    if let Some((flag, _)) = one_medium.iter().find(|(_, given)| *given) {
        pin_cli::usage!(
            "{flag} needs one medium, not the scene {}",
            medium.path.display()
        );
    }
    let look = a.flags.look(medium.scene());
    let max_gpu = pinrender::gpu_render::MAX_GPU_BOUNCES;
    if look.max_bounces > max_gpu {
        pin_cli::usage!(
            "--max-bounces {} exceeds the GPU limit of {max_gpu} (the scene {} sets it)",
            look.max_bounces,
            medium.path.display()
        );
    }
    Ok(())
}

fn run(mut a: ViewArgs, started: Instant) -> Result<ExitCode> {
    let mut clock = startup::StartupClock::new(started);
    let max_gpu = pinrender::gpu_render::MAX_GPU_BOUNCES;
    if let Some(n) = a.flags.max_bounces.filter(|&n| n > max_gpu) {
        pin_cli::usage!("--max-bounces {n} exceeds the GPU limit of {max_gpu}");
    }
    // One budget for the command: the image buffers first, as `pinrender render` charges
    // them (one for each side rendering at the view's size: the main view, the compare
    // side, the error view's reference), then the file (its read, copies and bake) within
    // the same budget.
    let budget = a.flags.budget();
    let (w, h) = a.size();
    let images = 1 + u64::from(a.compare.is_some()) + u64::from(a.error_view);
    pinrender::front::flags::check_images(&budget, w, h, images)?;
    let pattern = sequence::pattern(&a.file)?;
    if a.play && a.frames.is_some() && pattern.is_none() {
        pin_cli::usage!(
            "--play needs a frame pattern (sim.####.pin or sim.%04d.pin), not {}",
            a.file.display()
        );
    }
    if a.offscreen {
        if let Some(flag) = offscreen::window_only_flags(&a) {
            pin_cli::usage!("{flag} needs the window; --offscreen renders one view without one");
        }
        if pattern.is_some() {
            pin_cli::usage!(
                "--offscreen renders one file, not the frame pattern {}",
                a.file.display()
            );
        }
    }
    // The file first: a bad one is reported without opening a window.
    let frames = match pattern {
        Some(_) => Some(sequence::list_frames(&a.file)?),
        None => None,
    };
    let first = frames.as_ref().map_or(a.file.clone(), |f| f[0].1.clone());
    let opened = open_medium(&first, &a, &budget)
        .and_then(|m| at_first_look(m, &first, &mut a, frames.is_some(), &budget));
    let medium = match opened {
        Ok(m) => m,
        // Interactive, a refused file is shown in the failure window (and then on stderr).
        Err(e)
            if a.frames.is_none()
                && e.downcast_ref::<pin_cli::UsageError>().is_none()
                && std::env::var_os("DISPLAY").is_some_and(|d| !d.is_empty()) =>
        {
            // Without a window the line still goes to stderr.
            let _ = failure_window::show(&first, &e.to_string());
            return Err(e);
        }
        Err(e) => return Err(e),
    };
    clock.marks.file_open = clock.now();
    if medium.scene().is_some() {
        scene_flags(&a, &medium)?;
    }
    if a.rebake_scale.is_some() && !medium.is_volume {
        pin_cli::usage!(
            "--rebake-scale applies to a volume, not to the pin file {}",
            first.display()
        );
    }
    // The viewer bakes only a volume: a pin file or a scene has its pins already.
    if a.flags.pin_cells.is_some() && !medium.is_volume {
        pin_cli::usage!(
            "--pin-cells applies to a volume the viewer bakes, not to {}",
            first.display()
        );
    }
    for e in a.estimator.into_iter().chain(a.compare) {
        if e.needs_density() && !medium.has_density() {
            return Err(anyhow!(
                "{}: no embedded density, which the {e} estimator needs (bake with \
                 `pinbake bake --embed-density N`, or open the volume)",
                first.display()
            ));
        }
        if e == EstimatorSpec::PinRes && !medium.is_volume && !medium.estimators().contains(&e) {
            return Err(anyhow!(
                "{}: no control section, which pinres reads (bake with `pinbake bake \
                 --embed-control`)",
                first.display()
            ));
        }
    }
    // An output replaces neither the file nor a scene's asset.
    let mut inputs: Vec<&Path> = vec![first.as_path()];
    for asset in medium.scene().iter().flat_map(|s| &s.assets) {
        inputs.extend(asset.volume.as_deref());
        inputs.extend(asset.pins.as_deref());
    }
    // Nor one another (`--screenshot X --save X` wrote one over the other).
    let outputs: Vec<&Path> = [&a.screenshot, &a.save, &a.window_screenshot]
        .into_iter()
        .flatten()
        .map(PathBuf::as_path)
        .collect();
    pin_volume::files::check_outputs(&outputs, &inputs)?;
    if a.offscreen {
        let json = offscreen::run(&a, medium, clock)?;
        if a.json {
            pin_cli::outln!("{json}")?;
        }
        return Ok(ExitCode::SUCCESS);
    }
    // This build opens X11 windows only (winit's x11 backend; XWayland on a Wayland desktop).
    if std::env::var_os("DISPLAY").is_none_or(|d| d.is_empty()) {
        return Err(anyhow!(
            "no display: DISPLAY is not set; pinview needs an X server (under a headless \
             session: `Xvfb :99 & DISPLAY=:99 pinview ...`)"
        ));
    }
    let outcome = Arc::new(Mutex::new(app::Outcome::default()));
    let options = app::native_options(&a);
    let a2 = a.clone();
    let outcome2 = outcome.clone();
    let mut opener_args = a.clone();
    // A scene dropped on the window opens with the one estimator the GPU path has for it,
    // whatever --estimator asked of the first file.
    opener_args.estimator = None;
    let opener: sequence::Opener = Arc::new(move |p: &Path| open_medium(p, &opener_args, &budget));
    let result = shell::run(
        options,
        Box::new(move |cc| {
            let keep = outcome2.clone();
            match app::Viewer::new(cc, a2, medium, frames, opener, clock, outcome2) {
                Ok(viewer) => Ok(Box::new(viewer) as Box<dyn shell::App>),
                Err(e) => {
                    // Reported by `main` as the error itself, not as a window failure.
                    if let Ok(mut o) = keep.lock() {
                        o.error = Some(e.to_string());
                    }
                    Err(e.to_string())
                }
            }
        }),
    );
    let outcome = outcome
        .lock()
        .map_err(|_| anyhow!("the viewer's outcome was poisoned"))?;
    if let Some(e) = &outcome.error {
        return Err(anyhow!("{e}"));
    }
    if let Err(e) = result {
        let line = e.replace('\n', " ");
        return Err(anyhow!("cannot open the viewer window: {line}"));
    }
    if let Some(json) = &outcome.json {
        pin_cli::outln!("{json}")?;
    }
    if a.frames.is_some() && !outcome.finished {
        return Err(anyhow!(
            "the window closed before {} passes were rendered",
            a.frames.unwrap_or(0)
        ));
    }
    Ok(ExitCode::SUCCESS)
}
