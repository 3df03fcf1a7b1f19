//! The window: the progressive session shown through the tone-map pass, the controls, the
//! readouts, export, and the scripted run (`--frames`). This file holds the viewer's state
//! and the order of one frame; each concern is a module of its own:
//!
//! * `window`: the window's options, the adapter and device, the displayed textures;
//! * `sessions`: the renderers and sessions of the shown estimator, the second side and
//!   the reference, built off the window's thread (`crate::build`) and swapped in when ready;
//! * `pacing`: the passes added each frame within its budget, and the frame-gap meter;
//! * `coarse`: the coarse image drawn at once when the view changes;
//! * `background`: the bake, the re-bake, the sequence and dropped files;
//! * `error`: the error view's read-backs and measurements;
//! * `events`: scripted input (`--input-script`) replayed, and what each event took;
//! * `input`: the image, its mouse and keyboard controls, the overlays and the divider;
//! * `panels`: the controls; `readouts`: the figures shown; `script`: the scripted run's
//!   outputs and its JSON line.

mod background;
mod coarse;
mod error;
mod events;
mod input;
pub mod pacing;
mod panels;
pub mod readouts;
mod script;
mod sessions;
pub mod window;

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::{Result, anyhow};

use egui::mutex::RwLock;
use pinrender::gpu_render::{GpuRenderer, GpuSession, GpuToneMap};
use pinrender::render::EstimatorSpec;

use crate::args::ViewArgs;
use crate::build::{BuildJob, Gpu, Relay};
use crate::compare::{self, CompareSide};
use crate::error_view::{ErrorTrack, Reference};
use crate::open::{BakeJob, Medium, Rebaked};
use crate::pin_overlay::Pick;
use crate::sequence::{Opener, Sequence};
use crate::startup::StartupClock;
use crate::view::View;

pub use window::native_options;
use window::{IMAGE_FORMAT, ShotResult, Target};

/// What the window leaves for `main`: a fatal error, the JSON line, whether a scripted run
/// finished.
#[derive(Default, Debug)]
pub struct Outcome {
    pub error: Option<String>,
    pub json: Option<String>,
    pub finished: bool,
}

pub struct Viewer {
    args: ViewArgs,
    /// The process start and where the time to the first image went.
    clock: StartupClock,
    outcome: Arc<Mutex<Outcome>>,
    /// The window's device, on which every renderer is built and rendered.
    gpu: Gpu,
    info: wgpu::AdapterInfo,
    egui_renderer: Arc<RwLock<egui_wgpu::Renderer>>,
    tone: GpuToneMap,
    target: Target,
    medium: Medium,
    bake: Option<BakeJob>,
    sequence: Option<Sequence>,
    opener: Opener,
    view: View,
    /// The estimator asked for (shown once the medium answers it).
    wanted: EstimatorSpec,
    renderer: Option<(EstimatorSpec, GpuRenderer)>,
    session: Option<GpuSession>,
    /// The shown session's tone map on its renderer's own device, where it has one.
    relay: Option<Relay>,
    /// The renderer and session of the estimator to show, being built off the window's
    /// thread; the image shown stays until they are in.
    pending: Option<BuildJob>,
    /// The view changed: the accumulation starts again.
    dirty: bool,
    /// The view changed this frame: a coarse image is drawn at once (`coarse`); and the box
    /// and sun are drawn over the image until the first whole pass of the new view.
    coarse_due: bool,
    moving: bool,
    coarse: Option<coarse::Coarse>,
    /// The coarse image's longer side, following its measured time (`coarse`).
    coarse_side: u32,
    /// Builds no longer wanted whose workers still run (waited for when the window closes).
    retired: Vec<BuildJob>,
    /// Counts the view's changes, so that a session built for an older view is reset.
    generation: u64,
    /// The longest time between two painted frames.
    pacer: pacing::FramePacer,
    first_image_s: Option<f64>,
    /// When the first coarse preview was shown, and the seconds the first build spent on
    /// its preview pass (or warm-up) after the pipeline was made.
    first_preview_s: Option<f64>,
    warm_up_s: Option<f64>,
    /// Wall time spent adding the current session's passes.
    render_seconds: f64,
    /// The first side's current pass time (compare's equal time).
    first_clock: compare::PassClock,
    status: String,
    /// What the viewer did in place of what was asked (an estimator a frame cannot answer),
    /// each once: shown as the status, and the JSON line's `notes`.
    notes: Vec<String>,
    command: String,
    paused: bool,
    /// Playback: when the first image was shown, and when each step of a playing sequence
    /// was taken (`playback_fps`).
    shown_first_at: Option<Instant>,
    play_steps: Vec<Instant>,
    /// The frame numbers shown, in order (a sequence's; the JSON line reports them).
    frames_played: Vec<i64>,
    /// Scripted input being replayed, and what the last frame drew into the image (heard
    /// by the script once that frame is painted).
    script: Option<events::ScriptedInput>,
    shown: Option<events::Shown>,
    /// A scripted window screenshot asked for: when, and its result once written.
    window_shot: Option<(Instant, ShotResult)>,
    /// The second estimator asked for (split view), its side once the medium answers it,
    /// and its displayed image.
    compare_wanted: Option<EstimatorSpec>,
    compare: Option<CompareSide>,
    compare_pending: Option<BuildJob>,
    compare_target: Option<Target>,
    /// Where the divider stands, as a fraction of the image's width (left: the first
    /// estimator).
    split: f32,
    /// The error view: the reference and RMSE plot on, the heat map shown, the reference's
    /// session (where the medium has a density) and what was measured against it.
    error_on: bool,
    heat_on: bool,
    reference: Option<Reference>,
    reference_pending: Option<BuildJob>,
    error: ErrorTrack,
    /// Overlays: the pins of the entry under the cursor (or at a clicked, held pixel), and
    /// the box with its cell grid; the latest pick and the image's rectangle in the window.
    pins_on: bool,
    grid_on: bool,
    held_pixel: Option<[f64; 2]>,
    /// The entry held: picked at `held_pixel` when the hold was taken and kept as the view
    /// moves, so its pins can be seen from the side.
    held: Option<Pick>,
    pick: Option<Pick>,
    image_rect: Option<egui::Rect>,
    /// A volume's density scale as shown, a re-bake at another one (its scale and job), and
    /// the scale of the last re-bake that was swapped in.
    density_scale: f64,
    rebake: Option<(f64, BakeJob<Rebaked>)>,
    /// The last re-bake swapped in: its scale, backend and why the GPU refused (if it did).
    rebaked: Option<(f64, &'static str, Option<String>)>,
}

impl Viewer {
    pub fn new(
        cc: &crate::shell::CreationContext,
        args: ViewArgs,
        medium: Medium,
        frames: Option<Vec<(i64, PathBuf)>>,
        opener: Opener,
        mut clock: StartupClock,
        outcome: Arc<Mutex<Outcome>>,
    ) -> Result<Self> {
        // The window is up: from here on, the time between painted frames is measured.
        let pacer = pacing::FramePacer::new(Instant::now());
        clock.marks.window_and_device = clock.now();
        let rs = cc
            .wgpu_render_state
            .as_ref()
            .ok_or_else(|| anyhow!("the window has no wgpu renderer"))?;
        let info = rs.adapter.get_info();
        let gpu = Gpu::new(
            rs.device.clone(),
            rs.queue.clone(),
            &info,
            // On a CPU adapter a renderer's first dispatch compiles on its device's queue
            // (seconds with lavapipe), which would stop the window's frames: renderers get
            // devices of their own there (`crate::build`).
            (info.device_type == wgpu::DeviceType::Cpu).then(|| rs.adapter.clone()),
        );
        let tone = GpuToneMap::new(&gpu.device, IMAGE_FORMAT);
        let target = Self::make_target(&gpu.device, &rs.renderer, args.width, args.height, None);
        let wanted = args.estimator.unwrap_or_else(|| initial_estimator(&medium));
        let view = View::new(&args, &medium, wanted);
        let bake = if medium.is_volume {
            Some(BakeJob::start(&medium, args.preview_bake())?)
        } else {
            None
        };
        let mut sequence = frames.map(|f| Sequence::new(f, opener.clone()));
        if let Some(s) = &mut sequence {
            s.playing = args.play;
        }
        let mut viewer = Self {
            clock,
            outcome,
            gpu,
            info,
            egui_renderer: rs.renderer.clone(),
            tone,
            target,
            medium,
            bake,
            sequence,
            opener,
            view,
            wanted,
            renderer: None,
            session: None,
            relay: None,
            pending: None,
            retired: Vec::new(),
            dirty: false,
            coarse_due: false,
            moving: false,
            coarse: None,
            coarse_side: crate::build::PREVIEW_SIDE,
            generation: 0,
            pacer,
            first_image_s: None,
            first_preview_s: None,
            warm_up_s: None,
            render_seconds: 0.0,
            first_clock: compare::PassClock::default(),
            status: String::new(),
            notes: Vec::new(),
            command: String::new(),
            paused: false,
            frames_played: Vec::new(),
            shown_first_at: None,
            play_steps: Vec::new(),
            window_shot: None,
            script: None,
            shown: None,
            compare_wanted: args.compare,
            compare: None,
            compare_pending: None,
            compare_target: None,
            split: 0.5,
            error_on: args.error_view,
            heat_on: args.error_view,
            reference: None,
            reference_pending: None,
            error: ErrorTrack::default(),
            pins_on: args.pin_at.is_some(),
            grid_on: args.grid_overlay,
            held_pixel: args.pin_at,
            held: None,
            pick: None,
            image_rect: None,
            density_scale: args.read.density_scale.get(),
            rebake: None,
            rebaked: None,
            args,
        };
        if let Some(s) = &viewer.sequence {
            viewer.frames_played.push(s.frames[s.current].0);
        }
        if let Some(path) = &viewer.args.input_script {
            let events = crate::input_script::read(path)?;
            viewer.check_events(&events)?;
            viewer.script = Some(events::ScriptedInput::new(events));
        }
        // What the medium cannot answer is refused here, before the first frame, as one
        // error line; the upload and the pipeline are built off the window's thread once
        // the window has painted its first frame, while it paints.
        viewer.ensure_session()?;
        if let Some(scale) = viewer.args.rebake_scale {
            viewer.start_rebake(scale.get())?;
        }
        Ok(viewer)
    }

    /// A note (once): the status line, and the JSON line's `notes`.
    fn note(&mut self, note: String) {
        if !self.notes.contains(&note) {
            self.status.clone_from(&note);
            self.notes.push(note);
        }
    }

    fn fail(&mut self, ctx: &egui::Context, e: anyhow::Error) {
        if self.args.frames.is_some() {
            if let Ok(mut o) = self.outcome.lock() {
                o.error = Some(e.to_string());
            }
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        } else {
            self.status = e.to_string();
        }
    }
}

impl Drop for Viewer {
    /// The window closes once every build has ended: a compile still running in the driver
    /// while the process exits could crash it at exit.
    fn drop(&mut self) {
        let pending = [
            self.pending.take(),
            self.compare_pending.take(),
            self.reference_pending.take(),
        ];
        for mut job in self.retired.drain(..).chain(pending.into_iter().flatten()) {
            job.join();
        }
    }
}

/// `pinrender render`'s default for the input; for a volume, the pins estimator it will
/// have once baked is not assumed: ratio until then.
fn initial_estimator(medium: &Medium) -> EstimatorSpec {
    medium.default_estimator()
}

impl crate::shell::App for Viewer {
    fn ui(&mut self, ui: &mut egui::Ui) {
        let now = Instant::now();
        self.pacer.tick(now);
        self.note_painted(now);
        self.prune_retired();
        let ctx = ui.ctx().clone();
        if let Err(e) = self.poll_background(&ctx) {
            self.fail(&ctx, e);
        }
        let before = self.view.clone();
        let scripted = self.args.frames.is_some();
        if !scripted {
            self.keys(&ctx);
        }
        if let Err(e) = self.replay_events() {
            self.fail(&ctx, e);
        }
        egui::Panel::left("controls")
            .resizable(false)
            .exact_size(340.0)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| self.controls(ui));
            });
        egui::CentralPanel::default().show(ui, |ui| self.image(ui));
        // Exposure is the tone map's alone; anything else starts the accumulation again.
        let mut a = before.clone();
        let mut b = self.view.clone();
        a.exposure = 0.0;
        b.exposure = 0.0;
        a.estimator = self.wanted;
        b.estimator = self.wanted;
        if a != b {
            self.dirty = true;
            self.coarse_due = true;
            self.moving = true;
        }
        let busy = match self.render() {
            Ok(busy) => busy,
            Err(e) => {
                self.fail(&ctx, e);
                true
            }
        };
        if self.error_on
            && self.args.frames.is_none()
            && let Err(e) = self.update_error(&ctx, false)
        {
            self.fail(&ctx, e);
        }
        if let Err(e) = self.finish_script(&ctx) {
            self.fail(&ctx, e);
        }
        if let Err(e) = self.finish_window_shot(&ctx) {
            if let Ok(mut o) = self.outcome.lock() {
                o.error = Some(e.to_string());
            }
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
        // A frame that rendered asks for the next at once; one with nothing to render (paused,
        // or waiting for a build) asks again after `IDLE_REPAINT`, leaving the cores to the
        // builds; input wakes the window at once either way.
        if busy {
            ctx.request_repaint();
        } else {
            ctx.request_repaint_after(pacing::IDLE_REPAINT);
        }
    }
}
