//! The window: the progressive session shown through the tone-map pass, the controls, the
//! readouts, export, and the scripted run (`--frames`). This file holds the viewer's state
//! (each concern's in a struct of its own) and the order of one frame; each concern is a
//! module of its own:
//!
//! * `window`: the window's options, the adapter and device, the displayed textures;
//! * `side`: one side of the image, an estimator's renderer and session built off the
//!   window's thread (`crate::build`) and swapped in when ready, with its pass clock: the
//!   shown estimator, the split view's second estimator and the error view's reference;
//! * `sessions`: which estimator each side wants, and when it is built, swapped in and
//!   restarted;
//! * `pacing`: the passes added each frame within its budget, and the frame-gap meter;
//! * `coarse`: the coarse image drawn at once when the view changes;
//! * `background`: the bake and the re-bake, and dropped files;
//! * `playback`: a sequence's frames and their playback;
//! * `error`: the error view's read-backs and measurements;
//! * `events`: scripted input (`--input-script`) replayed, and what each event took;
//! * `input`: the image, its mouse and keyboard controls and the divider;
//! * `viewport`: the image's size following the window (debounced), or fixed;
//! * `overlays`: the pins, the cell grid and the heat map over the image;
//! * `toasts`: status and save messages over the image for a few seconds;
//! * `panels`: the controls; `readouts`: the figures shown; `export`: the saves and the
//!   batch command; `script`: the scripted run's outputs and its JSON line.

mod background;
mod coarse;
mod error;
mod events;
mod export;
mod input;
mod overlays;
pub mod pacing;
mod panels;
mod playback;
pub mod readouts;
mod script;
mod sessions;
mod side;
mod toasts;
mod viewport;
pub mod window;

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::{Result, anyhow};

use egui::mutex::RwLock;
use pinrender::gpu_render::GpuToneMap;
use pinrender::render::EstimatorSpec;

use crate::args::ViewArgs;
use crate::build::{BuildJob, Gpu};
use crate::error_view::{self, ErrorTrack};
use crate::open::Medium;
use crate::sequence::{Opener, Sequence};
use crate::startup::StartupClock;
use crate::view::View;
use background::Bakes;
use coarse::Coarse;
use export::Export;
use input::Input;
use overlays::Overlays;
use playback::Playback;
use side::Side;
use toasts::Toasts;
use viewport::Viewport;

pub use window::native_options;
use window::{IMAGE_FORMAT, Images, ShotResult};

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
    /// The displayed images: the shown estimator's and the second side's.
    images: Images,
    medium: Medium,
    /// The first bake of a volume's pins and the re-bakes at another density scale.
    bakes: Bakes,
    /// A sequence's frames and their playback.
    playback: Playback,
    opener: Opener,
    view: View,
    /// The estimator asked for (shown once the medium answers it).
    wanted: EstimatorSpec,
    /// The second estimator asked for (split view).
    compare_wanted: Option<EstimatorSpec>,
    /// The shown estimator's side, the split view's second side and the error view's
    /// reference: each a renderer and session, built off the window's thread.
    main: Side,
    compare: Side,
    reference: Side,
    /// A pin file opened without `--estimator`: the cheapest estimator it answers (pins),
    /// shown at once, and the default it switches to once that renderer is built in
    /// [`Viewer::next`]; `None` once switched, or where there is nothing cheaper.
    interim: Option<(EstimatorSpec, EstimatorSpec)>,
    /// The default estimator's renderer, built while the interim one is shown.
    next: Side,
    /// The estimator of the first image shown, and when the default replaced the interim
    /// one (seconds from the start).
    first_image_estimator: Option<EstimatorSpec>,
    estimator_switch_s: Option<f64>,
    /// Builds no longer wanted whose workers still run (waited for when the window closes).
    retired: Vec<BuildJob>,
    /// Counts the view's changes, so that a session built for an older view is reset.
    generation: u64,
    /// What the pointer and keys did to the view, the image's place and the divider.
    input: Input,
    /// The coarse image drawn at once when the view changes.
    coarse: Coarse,
    /// The image's size following the window's central panel, or fixed by the flags.
    viewport: Viewport,
    /// The pins, the cell grid and the heat map drawn over the image.
    overlays: Overlays,
    /// The longest time between two painted frames.
    pacer: pacing::FramePacer,
    first_image_s: Option<f64>,
    /// When the first coarse preview was shown, and the seconds the first build spent on
    /// its preview pass (or warm-up) after the pipeline was made.
    first_preview_s: Option<f64>,
    warm_up_s: Option<f64>,
    /// Status and save messages, shown as toasts over the image.
    toasts: Toasts,
    /// What the viewer did in place of what was asked (an estimator a frame cannot answer),
    /// each once: shown as the status, and the JSON line's `notes`.
    notes: Vec<String>,
    /// The camera the view opened with where it is not the medium's home (a scene framed
    /// from outside because its own camera stands inside a box): what "reset view" returns to.
    opened_camera: Option<([f64; 3], [f64; 3])>,
    /// The saves and the equivalent batch command.
    export: Export,
    paused: bool,
    /// Scripted input being replayed, and what the last frame drew into the image (heard
    /// by the script once that frame is painted).
    script: Option<events::ScriptedInput>,
    shown: Option<events::Shown>,
    /// A scripted window screenshot asked for: when, and its result once written.
    window_shot: Option<(Instant, ShotResult)>,
    /// The error view: the reference and RMSE plot on, and what was measured against the
    /// reference.
    error_on: bool,
    error: ErrorTrack,
    /// The background check of a pin file's sections (`crate::verify`).
    verify: Option<crate::verify::Verify>,
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
        let wanted = args.estimator.unwrap_or_else(|| initial_estimator(&medium));
        let interim = (args.estimator.is_none() && frames.is_none())
            .then(|| interim_estimator(&medium))
            .flatten()
            .map(|cheap| (cheap, wanted));
        let view = View::new(&args, &medium, wanted);
        let images = Images {
            main: Self::make_target(&gpu.device, &rs.renderer, view.width, view.height, None),
            compare: None,
        };
        let bakes = Bakes::new(&medium, &args)?;
        let playback = Playback::new(frames.map(|f| Sequence::new(f, opener.clone())), args.play);
        let mut viewer = Self {
            clock,
            outcome,
            gpu,
            info,
            egui_renderer: rs.renderer.clone(),
            tone,
            images,
            verify: crate::verify::Verify::start(&medium),
            medium,
            bakes,
            playback,
            opener,
            view,
            wanted,
            compare_wanted: args.compare,
            main: Side::new(0),
            compare: Side::new(0),
            reference: Side::new(error_view::REFERENCE_SEED_XOR),
            interim,
            next: Side::new(0),
            first_image_estimator: None,
            estimator_switch_s: None,
            retired: Vec::new(),
            generation: 0,
            input: Input::default(),
            coarse: Coarse::default(),
            viewport: Viewport::new(!args.size_fixed(), args.flags.budget()),
            overlays: Overlays::new(&args),
            pacer,
            first_image_s: None,
            first_preview_s: None,
            warm_up_s: None,
            toasts: Toasts::default(),
            notes: Vec::new(),
            opened_camera: None,
            export: Export::default(),
            paused: false,
            window_shot: None,
            script: None,
            shown: None,
            error_on: args.error_view,
            error: ErrorTrack::default(),
            args,
        };
        let origin_flag = viewer.args.flags.camera_origin.is_some();
        if let Some(n) =
            crate::scene_framing::open_outside(&mut viewer.view, &viewer.medium, origin_flag)
        {
            viewer.opened_camera = Some((viewer.view.origin, viewer.view.target));
            viewer.note(n);
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
        if let Some(look) = viewer.args.first_look.filter(|l| l.scale != 1.0) {
            viewer.note(crate::open::first_look_note(&look));
        }
        if let Some(scale) = viewer.args.rebake_scale {
            viewer.start_rebake(scale.get())?;
        }
        Ok(viewer)
    }

    /// "reset view" (the button, the `R` key, the scripted `reset`): the camera the view
    /// opened with (framed from outside where the scene's own stands inside a box), else the
    /// medium's home.
    fn reset_view(&mut self) {
        let (o, t) = self.opened_camera.unwrap_or_else(|| self.medium.home());
        self.view.origin = o;
        self.view.target = t;
    }

    /// A note (once): the status line, and the JSON line's `notes`.
    fn note(&mut self, note: String) {
        if !self.notes.contains(&note) {
            self.toasts.say(note.clone());
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
            self.toasts.say(e.to_string());
        }
    }
}

impl Drop for Viewer {
    /// The window closes once every build has ended: a compile still running in the driver
    /// while the process exits could crash it at exit.
    fn drop(&mut self) {
        for side in [
            &mut self.main,
            &mut self.compare,
            &mut self.reference,
            &mut self.next,
        ] {
            side.stop(&mut self.retired);
        }
        for mut job in self.retired.drain(..) {
            job.join();
        }
    }
}

/// `pinrender render`'s default for the input; for a volume, the pins estimator it will
/// have once baked is not assumed: ratio until then.
fn initial_estimator(medium: &Medium) -> EstimatorSpec {
    medium.default_estimator()
}

/// The estimator a pin file is shown with first when its default is another: the cheapest
/// it answers (pins, which read nothing but the pins), while the default's renderer is built.
/// A volume (tracked until its pins are baked) and a scene open with their default.
fn interim_estimator(medium: &Medium) -> Option<EstimatorSpec> {
    let cheap = EstimatorSpec::Pins;
    (!medium.is_volume
        && medium.scene().is_none()
        && medium.default_estimator() != cheap
        && medium.estimators().contains(&cheap))
    .then_some(cheap)
}

impl crate::shell::App for Viewer {
    fn raw_events(&mut self) -> Vec<egui::Event> {
        self.script
            .as_mut()
            .map(events::ScriptedInput::next_pointer_events)
            .unwrap_or_default()
    }

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
        if let Err(e) = self.replay_events(&ctx) {
            self.fail(&ctx, e);
        }
        egui::Panel::left("controls")
            .resizable(false)
            .exact_size(340.0)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| self.controls(ui));
            });
        egui::CentralPanel::default().show(ui, |ui| self.image(ui));
        self.toasts.draw(&ctx);
        // Exposure is the tone map's alone; anything else starts the accumulation again.
        let mut a = before.clone();
        let mut b = self.view.clone();
        a.exposure = 0.0;
        b.exposure = 0.0;
        a.estimator = self.wanted;
        b.estimator = self.wanted;
        if a != b {
            self.input.dirty = true;
            self.input.moving = true;
            self.coarse.due = true;
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
