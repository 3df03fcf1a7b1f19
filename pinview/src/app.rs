//! The window: the progressive session shown through the tone-map pass, the controls, the
//! readouts, export, and the scripted run (`--frames`).

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Result, anyhow};
use eframe::egui;
use eframe::egui::mutex::RwLock;
use pinrender::gpu_render::{GpuRenderer, GpuSession, GpuToneMap, PassTimeSource};
use pinrender::render::EstimatorSpec;

use crate::args::ViewArgs;
use crate::compare::{self, CompareSide, SideTime, Turn};
use crate::error_view::{self, ErrorTrack, Reference};
use crate::export;
use crate::open::{BakeJob, Medium, PreviewBake, Rebaked, gpu_media};
use crate::pin_overlay::{self, Pick, Projector};
use crate::sequence::{Opener, Sequence};
use crate::startup::StartupClock;
use crate::view::View;

/// Wall time the renderer may take per frame, and per submission within it: the window
/// answers well within 100 ms.
const FRAME_BUDGET: Duration = Duration::from_millis(40);
const SLICE: Duration = Duration::from_millis(20);
/// The texture format of the displayed image (the tone-map pass writes sRGB codes itself).
const IMAGE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

/// What a scene file leaves out: the features that need one medium.
const SCENE_NOTE: &str = "a scene: the pins estimator only (the GPU path's); compare, the \
                          error view, the pin overlay and re-bake need one medium";

/// What the window leaves for `main`: a fatal error, the JSON line, whether a scripted run
/// finished.
#[derive(Default, Debug)]
pub struct Outcome {
    pub error: Option<String>,
    pub json: Option<String>,
    pub finished: bool,
}

/// The window's options: title, size, drag and drop, and the wgpu device opened on the
/// adapter `pinrender render --backend gpu` picks, with the adapter's own limits.
pub fn native_options(a: &ViewArgs) -> eframe::NativeOptions {
    let title = format!("pinview - {}", a.file.display());
    let w = (a.width as f32 + 360.0).min(1900.0);
    let h = (a.height as f32 + 24.0).clamp(700.0, 1200.0);
    let setup = egui_wgpu::WgpuSetupCreateNew {
        power_preference: wgpu::PowerPreference::HighPerformance,
        native_adapter_selector: Some(Arc::new(|adapters, _surface| {
            pick_adapter(adapters).ok_or_else(|| {
                "no GPU adapter found. Install a Vulkan driver; without a GPU, Mesa's lavapipe \
                 works: `apt-get install mesa-vulkan-drivers libvulkan1`"
                    .to_string()
            })
        })),
        device_descriptor: Arc::new(|adapter| wgpu::DeviceDescriptor {
            label: Some("pinview"),
            // Pass times from the GPU's own clock where the adapter can tell them. Not on a
            // CPU adapter: lavapipe stamps a pass when it processes the command, not when its
            // threads finish the dispatch (measured 20x and 220x below the wall time for pins
            // and PinMS), so the wall time is the truer figure there.
            required_features: if adapter.get_info().device_type == wgpu::DeviceType::Cpu {
                wgpu::Features::empty()
            } else {
                adapter.features() & wgpu::Features::TIMESTAMP_QUERY
            },
            required_limits: adapter.limits(),
            ..Default::default()
        }),
        ..egui_wgpu::WgpuSetupCreateNew::without_display_handle()
    };
    eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_title(title)
            .with_inner_size([w, h])
            .with_drag_and_drop(true),
        renderer: eframe::Renderer::Wgpu,
        wgpu_options: egui_wgpu::WgpuConfiguration {
            wgpu_setup: egui_wgpu::WgpuSetup::CreateNew(setup),
            // Frames are paced by the render slices, not by the display.
            surface: egui_wgpu::SurfaceConfig {
                present_mode: wgpu::PresentMode::AutoNoVsync,
                ..egui_wgpu::SurfaceConfig::LOW_LATENCY
            },
            ..Default::default()
        },
        ..Default::default()
    }
}

/// The adapter `pinrt::gpu::GpuContext::new` opens (high performance first, then a software
/// fallback), found among the window's adapters by name and backend, so that the viewer
/// and `pinrender render --backend gpu` run on the same one; else the first.
fn pick_adapter(adapters: &[wgpu::Adapter]) -> Option<wgpu::Adapter> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
    let mut options = wgpu::RequestAdapterOptions {
        power_preference: wgpu::PowerPreference::HighPerformance,
        force_fallback_adapter: false,
        compatible_surface: None,
        apply_limit_buckets: false,
    };
    let reference = pollster::block_on(instance.request_adapter(&options))
        .or_else(|_| {
            options.force_fallback_adapter = true;
            pollster::block_on(instance.request_adapter(&options))
        })
        .ok()
        .map(|a| a.get_info());
    reference
        .and_then(|r| {
            adapters.iter().find(|a| {
                let i = a.get_info();
                i.name == r.name && i.backend == r.backend
            })
        })
        .or_else(|| adapters.first())
        .cloned()
}

/// The displayed image: a texture the tone-map pass draws into and egui shows.
struct Target {
    texture: wgpu::Texture,
    view: wgpu::TextureView,
    id: egui::TextureId,
    size: (u32, u32),
}

/// Where the window screenshot's callback leaves its result.
type ShotResult = Arc<Mutex<Option<Result<(), String>>>>;

pub struct Viewer {
    args: ViewArgs,
    /// The process start and where the time to the first image went.
    clock: StartupClock,
    outcome: Arc<Mutex<Outcome>>,
    device: wgpu::Device,
    queue: wgpu::Queue,
    limits: wgpu::Limits,
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
    /// The view changed: the accumulation starts again.
    dirty: bool,
    first_image_s: Option<f64>,
    /// Wall time spent adding the current session's passes.
    render_seconds: f64,
    /// The first side's current pass time (compare's equal time).
    first_clock: compare::PassClock,
    status: String,
    command: String,
    paused: bool,
    /// The frame numbers shown, in order (a sequence's; the JSON line reports them).
    frames_played: Vec<u64>,
    /// A scripted window screenshot asked for: when, and its result once written.
    window_shot: Option<(Instant, ShotResult)>,
    /// The second estimator asked for (split view), its side once the medium answers it,
    /// and its displayed image.
    compare_wanted: Option<EstimatorSpec>,
    compare: Option<CompareSide>,
    compare_target: Option<Target>,
    /// Where the divider stands, as a fraction of the image's width (left: the first
    /// estimator).
    split: f32,
    /// The error view: the reference and RMSE plot on, the heat map shown, the reference's
    /// session (where the medium has a density) and what was measured against it.
    error_on: bool,
    heat_on: bool,
    reference: Option<Reference>,
    error: ErrorTrack,
    /// Overlays: the pins of the entry under the cursor (or at a clicked, held pixel), and
    /// the box with its cell grid; the latest pick and the image's rectangle in the window.
    pins_on: bool,
    grid_on: bool,
    held_pixel: Option<[f64; 2]>,
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
        cc: &eframe::CreationContext<'_>,
        args: ViewArgs,
        medium: Medium,
        frames: Option<Vec<(u64, PathBuf)>>,
        opener: Opener,
        mut clock: StartupClock,
        outcome: Arc<Mutex<Outcome>>,
    ) -> Result<Self> {
        clock.marks.window_and_device = clock.now();
        let rs = cc
            .wgpu_render_state
            .as_ref()
            .ok_or_else(|| anyhow!("the window has no wgpu renderer"))?;
        let device = rs.device.clone();
        let queue = rs.queue.clone();
        let limits = device.limits();
        let info = rs.adapter.get_info();
        let tone = GpuToneMap::new(&device, IMAGE_FORMAT);
        let target = Self::make_target(&device, &rs.renderer, args.width, args.height, None);
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
            device,
            queue,
            limits,
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
            dirty: false,
            first_image_s: None,
            render_seconds: 0.0,
            first_clock: compare::PassClock::default(),
            status: String::new(),
            command: String::new(),
            paused: false,
            frames_played: Vec::new(),
            window_shot: None,
            compare_wanted: args.compare,
            compare: None,
            compare_target: None,
            split: 0.5,
            error_on: args.error_view,
            heat_on: args.error_view,
            reference: None,
            error: ErrorTrack::default(),
            pins_on: args.pin_at.is_some(),
            grid_on: args.grid_overlay,
            held_pixel: args.pin_at,
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
        // Compile and upload before the window shows, so that a bad file or estimator is one
        // error line, and the first frame renders at once.
        viewer.ensure_session()?;
        if let Some(scale) = viewer.args.rebake_scale {
            viewer.start_rebake(scale.get())?;
        }
        Ok(viewer)
    }

    fn make_target(
        device: &wgpu::Device,
        renderer: &Arc<RwLock<egui_wgpu::Renderer>>,
        width: u32,
        height: u32,
        old: Option<egui::TextureId>,
    ) -> Target {
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("pinview image"),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: IMAGE_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        let mut r = renderer.write();
        let id = match old {
            Some(id) => {
                r.update_egui_texture_from_wgpu_texture(
                    device,
                    &view,
                    wgpu::FilterMode::Nearest,
                    id,
                );
                id
            }
            None => r.register_native_texture(device, &view, wgpu::FilterMode::Nearest),
        };
        Target {
            texture,
            view,
            id,
            size: (width, height),
        }
    }

    /// The estimator shown now: the one asked for once the medium answers it, else the
    /// medium's default (ratio while a volume's pins bake).
    fn estimator_now(&self) -> EstimatorSpec {
        if self.medium.estimators().contains(&self.wanted) {
            self.wanted
        } else {
            self.medium.default_estimator()
        }
    }

    /// Uploads the medium for the current estimator (when it changed) and starts or resets
    /// the session (when the view changed).
    fn ensure_session(&mut self) -> Result<()> {
        let est = self.estimator_now();
        self.view.estimator = est;
        // The second side starts again with the first, so both have spent equal time.
        let mut restart = self.dirty;
        if self.renderer.as_ref().is_none_or(|(e, _)| *e != est) {
            self.session = None;
            self.renderer = None;
            let descs = self.medium.descs(est, &self.limits)?;
            let media = gpu_media(&descs, est)?;
            let r = GpuRenderer::with_media_on(&self.device, &self.queue, &self.limits, &media)
                .map_err(|e| anyhow!("{}: {e}", self.medium.path.display()))?;
            self.renderer = Some((est, r));
            if self.clock.marks.upload == 0.0 {
                self.clock.marks.upload = self.clock.now();
            }
        }
        let scene = self.view.scene();
        let size = (self.view.width, self.view.height);
        match &mut self.session {
            Some(s) if (s.width(), s.height()) == size => {
                if self.dirty {
                    s.reset(&scene, self.view.seed)
                        .map_err(|e| anyhow!("{e}"))?;
                    self.render_seconds = 0.0;
                    self.first_clock = compare::PassClock::default();
                }
            }
            _ => {
                let (_, r) = self
                    .renderer
                    .as_ref()
                    .ok_or_else(|| anyhow!("no renderer"))?;
                self.session = Some(
                    r.session(&scene, est, self.view.seed)
                        .map_err(|e| anyhow!("{e}"))?,
                );
                restart = true;
                if self.clock.marks.pipeline == 0.0 {
                    self.clock.marks.pipeline = self.clock.now();
                }
                self.render_seconds = 0.0;
                self.first_clock = compare::PassClock::default();
                if self.target.size != size {
                    self.target = Self::make_target(
                        &self.device,
                        &self.egui_renderer,
                        size.0,
                        size.1,
                        Some(self.target.id),
                    );
                }
            }
        }
        self.dirty = false;
        if restart {
            self.error.clear(0);
        }
        self.ensure_compare(restart)?;
        self.ensure_reference(restart)
    }

    /// Starts the reference when the error view is on and the medium has a density, and
    /// restarts it with the first side.
    fn ensure_reference(&mut self, restart: bool) -> Result<()> {
        if !self.error_on || error_view::no_reference_reason(&self.medium).is_some() {
            self.reference = None;
            return Ok(());
        }
        let scene = self.view.scene();
        let seed = self.view.seed;
        match &mut self.reference {
            Some(r) => {
                if restart {
                    r.reset(&scene, seed)?;
                    self.error = ErrorTrack::default();
                }
            }
            None => {
                self.reference = Some(Reference::start(
                    &self.device,
                    &self.queue,
                    &self.limits,
                    &mut self.medium,
                    &scene,
                    seed,
                )?);
                self.error = ErrorTrack::default();
            }
        }
        Ok(())
    }

    /// Whether a scripted run's reference holds whole passes, at least one (or there is
    /// none to wait for).
    fn reference_done(&self) -> bool {
        match &self.reference {
            _ if !self.error_on => true,
            None => error_view::no_reference_reason(&self.medium).is_some(),
            Some(r) => r.session.passes() > 0 && r.session.next_row() == 0,
        }
    }

    /// Whether the interactive window reads the error back this frame.
    fn error_due(&self) -> bool {
        self.error_on
            && self.args.frames.is_none()
            && self
                .reference
                .as_ref()
                .is_some_and(|r| r.session.passes() > 0)
            && self
                .error
                .last
                .is_none_or(|t| t.elapsed() >= error_view::ERROR_PERIOD)
    }

    /// Reads the accumulations back (at most once per [`error_view::ERROR_PERIOD`], or now
    /// with `now`) and measures each side against the reference: RMSE, plot point, heat map.
    fn update_error(&mut self, ctx: &egui::Context, now: bool) -> Result<()> {
        let Some(r) = &self.reference else {
            return Ok(());
        };
        if r.session.passes() == 0
            || (!now
                && self
                    .error
                    .last
                    .is_some_and(|t| t.elapsed() < error_view::ERROR_PERIOD))
        {
            return Ok(());
        }
        let started = Instant::now();
        self.error.last = Some(started);
        let reference = error_view::read_mean(&self.device, &self.queue, &r.session)?;
        self.error.reference_passes = r.session.passes();
        let sides = [
            self.session
                .as_ref()
                .map(|s| (s, self.first_clock.seconds())),
            self.compare.as_ref().map(|c| (&c.session, c.seconds())),
        ];
        for (k, side) in sides.into_iter().enumerate() {
            let Some((session, seconds)) = side.filter(|(s, _)| s.passes() > 0) else {
                continue;
            };
            let estimate = error_view::read_mean(&self.device, &self.queue, session)?;
            let e = error_view::rmse(&estimate, &reference);
            self.error.rmse[k] = Some(e);
            self.error.points[k].push([seconds, e]);
            let rgb = error_view::heat_map(&estimate, &reference, self.view.exposure);
            let size = [session.width() as usize, session.height() as usize];
            let image = egui::ColorImage::from_rgb(size, &rgb);
            match &mut self.error.textures[k] {
                Some(t) => t.set(image, egui::TextureOptions::NEAREST),
                None => {
                    self.error.textures[k] = Some(ctx.load_texture(
                        format!("pinview error {k}"),
                        image,
                        egui::TextureOptions::NEAREST,
                    ));
                }
            }
            self.error.heat[k] = Some(rgb);
        }
        self.error.update_seconds = started.elapsed().as_secs_f64();
        Ok(())
    }

    /// Starts the second side when one is asked for and the medium answers it (a volume's
    /// pins estimators once baked), and restarts it with the first.
    fn ensure_compare(&mut self, restart: bool) -> Result<()> {
        let Some(est) = self
            .compare_wanted
            .filter(|e| self.medium.scene().is_none() && self.medium.estimators().contains(e))
        else {
            self.compare = None;
            return Ok(());
        };
        let scene = self.view.scene();
        let seed = self.view.seed;
        match &mut self.compare {
            Some(c) if c.estimator == est => {
                if restart {
                    c.reset(&scene, seed)?;
                }
            }
            _ => {
                self.compare = None;
                self.error.clear(1);
                self.compare = Some(CompareSide::start(
                    &self.device,
                    &self.queue,
                    &self.limits,
                    &mut self.medium,
                    est,
                    &scene,
                    seed,
                )?);
            }
        }
        let size = (self.view.width, self.view.height);
        if self.compare_target.as_ref().is_none_or(|t| t.size != size) {
            let old = self.compare_target.as_ref().map(|t| t.id);
            self.compare_target = Some(Self::make_target(
                &self.device,
                &self.egui_renderer,
                size.0,
                size.1,
                old,
            ));
        }
        Ok(())
    }

    /// Replaces the medium (a frame of a sequence, a dropped file, finished pins).
    fn set_medium(&mut self, medium: Medium) {
        self.medium = medium;
        self.renderer = None;
        self.session = None;
        self.compare = None;
        self.reference = None;
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

    /// Re-bakes the shown volume at density scale `scale` on the GPU in the background; the
    /// current medium stays on screen until the new one is ready.
    fn start_rebake(&mut self, scale: f64) -> Result<()> {
        let mut read = self.args.read.clone();
        read.density_scale =
            pinbake::source::DensityScale::new(scale).map_err(|e| anyhow!("{e}"))?;
        let args = pinrender::volume::VolumeArgs {
            volume: Some(self.medium.path.clone()),
            read,
        };
        let bake = PreviewBake {
            seed: self.view.seed,
            ..self.args.preview_bake()
        };
        let job = BakeJob::rebake(self.medium.path.clone(), args, bake)?;
        self.rebake = Some((scale, job));
        Ok(())
    }

    /// Background work: the bake, the re-bake, the sequence, dropped files.
    fn poll_background(&mut self, ctx: &egui::Context) -> Result<()> {
        if let Some((scale, job)) = &mut self.rebake
            && let Some(done) = job.finished()
        {
            let scale = *scale;
            self.rebake = None;
            match done {
                Ok(done) => {
                    // The first bake of the old scale is of no use any more.
                    self.bake = None;
                    self.set_medium(done.medium);
                    self.density_scale = scale;
                    if self.args.estimator.is_none() {
                        self.wanted = self.medium.default_estimator();
                    }
                    self.status = match &done.gpu_refused {
                        None => format!("re-baked on the GPU at density scale {scale}"),
                        Some(why) => {
                            format!("re-baked on the CPU at density scale {scale} ({why})")
                        }
                    };
                    self.rebaked = Some((scale, done.backend, done.gpu_refused));
                }
                Err(e) => {
                    if self.args.frames.is_some() {
                        return Err(e);
                    }
                    self.status = format!("re-bake failed: {e}");
                }
            }
        }
        if let Some(job) = &mut self.bake
            && let Some(done) = job.finished()
        {
            self.bake = None;
            match done {
                Ok(grid) => {
                    self.medium.set_pins(Arc::new(grid));
                    if self.args.estimator.is_none() {
                        self.wanted = self.medium.default_estimator();
                    }
                    self.status = "pins baked: every estimator is available".into();
                }
                Err(e) => {
                    if self.wanted.needs_pins() {
                        return Err(anyhow!("{}: baking pins: {e}", self.medium.path.display()));
                    }
                    self.status = format!("baking pins failed: {e}");
                }
            }
        }
        let frame_passes = self.args.frame_passes;
        let done = self.session.as_ref().map_or(0, |s| s.passes());
        // A scripted run plays the sequence once and stops on its last frame.
        let scripted = self.args.frames.is_some();
        let next = match &self.sequence {
            Some(s)
                if s.playing
                    && !self.paused
                    && done >= frame_passes
                    && s.len() > 1
                    && !(scripted && s.current + 1 == s.len()) =>
            {
                Some((s.current + 1) % s.len())
            }
            _ => None,
        };
        if let Some(i) = next {
            self.go_to_frame(i)?;
        }
        let dropped: Vec<PathBuf> = ctx.input(|i| {
            i.raw
                .dropped_files
                .iter()
                .map(|f| f.path().to_path_buf())
                .collect()
        });
        if let Some(path) = dropped.into_iter().next() {
            match (self.opener)(&path) {
                Ok(m) => {
                    let (o, t) = m.home();
                    self.bake = if m.is_volume {
                        BakeJob::start(
                            &m,
                            PreviewBake {
                                seed: self.view.seed,
                                ..self.args.preview_bake()
                            },
                        )
                        .ok()
                    } else {
                        None
                    };
                    self.sequence = None;
                    self.set_medium(m);
                    self.view.origin = o;
                    self.view.target = t;
                    self.status = format!("opened {}", path.display());
                }
                // A scene's messages name the file and the JSON path themselves.
                Err(e) if crate::open::is_scene_file(&path) => self.status = e.to_string(),
                Err(e) => self.status = format!("{}: {e}", path.display()),
            }
        }
        Ok(())
    }

    fn go_to_frame(&mut self, i: usize) -> Result<()> {
        let Some(s) = &mut self.sequence else {
            return Ok(());
        };
        let m = s.go_to(i)?;
        self.frames_played.push(s.frames[s.current].0);
        self.set_medium(m);
        Ok(())
    }

    /// Adds passes for this frame and draws the accumulation into the texture.
    fn render(&mut self) -> Result<()> {
        self.ensure_session()?;
        let limit = match self.args.frames {
            Some(n) => {
                // A scripted run renders only the estimator it asked for.
                if self.estimator_now() != self.wanted {
                    return Ok(());
                }
                n
            }
            None => u32::MAX,
        };
        // A scripted re-bake renders its passes on the new pins.
        if self.args.frames.is_some() && self.args.rebake_scale.is_some() && self.rebaked.is_none()
        {
            return Ok(());
        }
        // A scripted comparison waits for its second estimator (a volume's pins).
        if self.args.frames.is_some()
            && self.compare_wanted.is_some()
            && self.compare.as_ref().map(|c| c.estimator) != self.compare_wanted
        {
            return Ok(());
        }
        // A frame that reads the error back (tens of milliseconds at 512 x 512 on lavapipe)
        // renders one slice and no reference: the window still answers within 100 ms.
        let error_due = self.error_due();
        let Some(session) = &mut self.session else {
            return Ok(());
        };
        // The window screenshot shows the passes the other outputs hold.
        let running = !(self.paused && self.sequence.is_none()) && self.window_shot.is_none();
        let remaining = if running {
            limit.saturating_sub(session.passes())
        } else {
            0
        };
        let first = SideTime {
            seconds: self.first_clock.seconds(),
            pass_seconds: self.first_clock.pass_seconds,
            remaining,
            in_progress: session.next_row() != 0,
        };
        let turn = match &self.compare {
            None => Turn::First(remaining),
            Some(c) => compare::next_turn(
                first,
                SideTime {
                    seconds: c.seconds(),
                    pass_seconds: c.clock.pass_seconds,
                    remaining: if running { u32::MAX } else { 0 },
                    in_progress: c.session.next_row() != 0,
                },
            ),
        };
        let budget = if error_due { SLICE } else { FRAME_BUDGET };
        let t = Instant::now();
        match turn {
            Turn::First(n) if n > 0 => {
                self.first_clock
                    .add(session, &mut self.render_seconds, budget, SLICE, n)?;
            }
            Turn::Second(n) => {
                if let Some(c) = &mut self.compare {
                    c.add(budget, SLICE, n)?;
                }
            }
            _ => {}
        }
        // The reference gets what is left of the frame's budget (at least one slice), the
        // whole frame when the shown sides add nothing; a scripted run stops it on whole
        // passes once the shown sides are done.
        if let Some(r) = &mut self.reference
            && running
            && !error_due
        {
            let idle = turn == Turn::Neither || matches!(turn, Turn::First(0));
            let max = if self.args.frames.is_some() && idle {
                u32::from(r.session.passes() == 0 || r.session.next_row() != 0)
            } else {
                u32::MAX
            };
            let budget = if idle {
                FRAME_BUDGET
            } else {
                FRAME_BUDGET.saturating_sub(t.elapsed())
            };
            if max > 0 {
                r.session
                    .add_for(budget, SLICE, max)
                    .map_err(|e| anyhow!("{e}"))?;
            }
        }
        if let (Some(c), Some(target)) = (&self.compare, &self.compare_target)
            && c.session.passes() > 0
        {
            self.tone.draw(&c.session, &target.view, self.view.exposure);
        }
        // After a reset the old image stays up until the first new pass is in: no black
        // frames while a long pass renders in bands.
        if session.passes() > 0 {
            self.tone
                .draw(session, &self.target.view, self.view.exposure);
        }
        if session.passes() > 0 && self.first_image_s.is_none() {
            let now = self.clock.now();
            self.first_image_s = Some(now);
            self.clock.marks.first_image = now;
        }
        Ok(())
    }

    /// Milliseconds per pass: the GPU's timestamps where the session has them, else the wall
    /// time spent rendering over the passes rendered.
    fn ms_per_pass(&self) -> f64 {
        self.session
            .as_ref()
            .map_or(0.0, |s| compare::ms_per_pass(s, self.render_seconds))
    }

    /// The first side's time: its passes at its current pass time ([`compare::PassClock`]).
    fn seconds(&self) -> f64 {
        self.session
            .as_ref()
            .map_or(0.0, |_| self.first_clock.seconds())
    }

    /// Whether a scripted comparison has its second side at the nearest equal time, with
    /// whole passes (or no comparison was asked for).
    fn compare_done(&self) -> bool {
        let Some(want) = self.compare_wanted else {
            return true;
        };
        let Some(c) = &self.compare else {
            return false;
        };
        let Some(s) = &self.session else {
            return false;
        };
        let first = SideTime {
            seconds: self.seconds(),
            pass_seconds: self.first_clock.pass_seconds,
            remaining: 0,
            in_progress: s.next_row() != 0,
        };
        let second = SideTime {
            seconds: c.seconds(),
            pass_seconds: c.clock.pass_seconds,
            remaining: u32::MAX,
            in_progress: c.session.next_row() != 0,
        };
        c.estimator == want
            && c.session.passes() > 0
            && compare::next_turn(first, second) == Turn::Neither
    }

    /// The entry under image pixel `(x, y)` (its centre at `x + 0.5`), where the medium has
    /// pins and the ray enters the box.
    fn pick_at(&self, x: f64, y: f64) -> Option<Pick> {
        let grid = self.medium.pins()?;
        let proj = Projector::new(&self.view)?;
        let (o, d) = proj.ray(x + 0.5, y + 0.5);
        pin_overlay::pick(grid, o, d)
    }

    /// The column where the second side's image starts.
    fn split_column(&self, width: u32) -> u32 {
        ((self.split.clamp(0.0, 1.0) * width as f32).round() as u32).min(width)
    }

    fn pass_time_source(&self) -> PassTimeSource {
        self.session
            .as_ref()
            .map_or(PassTimeSource::Wall, |s| s.pass_time_source())
    }

    /// The scripted run's end: outputs, the JSON line, close.
    fn finish_script(&mut self, ctx: &egui::Context) -> Result<()> {
        let Some(n) = self.args.frames else {
            return Ok(());
        };
        let passes = self.session.as_ref().map_or(0, |s| s.passes());
        if passes < n
            || (self.args.rebake_scale.is_some() && self.rebaked.is_none())
            || self.estimator_now() != self.wanted
            || !self.compare_done()
            || !self.reference_done()
        {
            return Ok(());
        }
        // The error of the final images, whatever the read-back period.
        if self.error_on {
            self.update_error(ctx, true)?;
        }
        if self
            .sequence
            .as_ref()
            .is_some_and(|s| s.playing && s.current + 1 < s.len())
        {
            return Ok(());
        }
        let (w, h) = self.target.size;
        if let Some(path) = &self.args.screenshot {
            let heat = |k: usize| self.error.heat[k].clone().filter(|_| self.heat_on);
            let mut rgb = match heat(0) {
                Some(rgb) => rgb,
                None => {
                    export::read_texture_rgb(&self.device, &self.queue, &self.target.texture, w, h)?
                }
            };
            // Split view: the second estimator's image right of the divider, as shown.
            if let Some(t) = &self.compare_target {
                let right = match heat(1) {
                    Some(rgb) => rgb,
                    None => export::read_texture_rgb(&self.device, &self.queue, &t.texture, w, h)?,
                };
                let x0 = self.split_column(w) as usize;
                let row = w as usize * 3;
                for y in 0..h as usize {
                    let span = y * row + x0 * 3..(y + 1) * row;
                    rgb[span.clone()].copy_from_slice(&right[span]);
                }
            }
            export::write_png(path, w, h, &rgb)?;
        }
        if let Some(path) = &self.args.save {
            let session = self.session.as_mut().ok_or_else(|| anyhow!("no session"))?;
            let image = session.image().map_err(|e| anyhow!("{e}"))?;
            image
                .write_exr(path)
                .map_err(|e| anyhow!("{}: {e}", path.display()))?;
        }
        let frame = self.sequence.as_ref().map(|s| &s.frames[s.current]);
        let mut json = serde_json::json!({
            "adapter": self.info.name,
            "backend": format!("{:?}", self.info.backend),
            "device_type": format!("{:?}", self.info.device_type),
            "estimator": self.view.estimator.to_string(),
            "width": w,
            "height": h,
            "passes": passes,
            "first_image_s": self.first_image_s.unwrap_or(0.0),
            "first_image_breakdown": self.clock.marks.breakdown(),
            "ms_per_pass": self.ms_per_pass(),
            "pass_time_source": self.pass_time_source().as_str(),
            "frame": frame.map(|f| f.0),
            "frame_path": frame.map(|f| f.1.display().to_string()),
            "frames_played": self.frames_played,
            "file": self.medium.path.display().to_string(),
        });
        if let Some(scene) = self.medium.scene() {
            json["instances"] = scene.instances.len().into();
        }
        if let Some((scale, backend, why)) = &self.rebaked {
            json["rebake"] = serde_json::json!({
                "density_scale": scale,
                "backend": backend,
                "gpu_refused": why,
            });
        }
        if let Some([x, y]) = self.args.pin_at {
            json["pin"] = match self.pick_at(x, y) {
                Some(p) => serde_json::json!({
                    "pixel": [x, y],
                    "cell": p.cell,
                    "direction": p.direction,
                    "reversed": p.reversed,
                    "pins": p.pins.iter().map(|q| serde_json::json!({
                        "t_min": q.entry.t_min,
                        "mask": q.entry.mask,
                    })).collect::<Vec<_>>(),
                }),
                None => serde_json::Value::Null,
            };
        }
        if self.args.window_screenshot.is_some()
            && let Some(r) = self.image_rect
        {
            let k = ctx.pixels_per_point();
            json["window_image_rect"] =
                serde_json::json!([r.min.x * k, r.min.y * k, r.max.x * k, r.max.y * k]);
        }
        if self.error_on {
            json["error"] = match (
                &self.reference,
                error_view::no_reference_reason(&self.medium),
            ) {
                (Some(r), _) => serde_json::json!({
                    "reference": "ratio",
                    "reference_passes": r.session.passes(),
                    "reference_seed": r.session.seed(),
                    "rmse": self.error.rmse[0],
                    "compare_rmse": self.error.rmse[1],
                    "points": self.error.points[0].len(),
                    "update_ms": 1e3 * self.error.update_seconds,
                }),
                (None, why) => serde_json::json!({ "reference": null, "why": why }),
            };
        }
        if let Some(c) = &self.compare {
            json["compare"] = serde_json::json!({
                "estimator": c.estimator.to_string(),
                "passes": c.session.passes(),
                "ms_per_pass": c.ms_per_pass(),
                "pass_time_source": c.session.pass_time_source().as_str(),
                "seconds": c.seconds(),
                "first_seconds": self.seconds(),
                "clock_ms_per_pass": 1e3 * c.clock.pass_seconds,
                "first_clock_ms_per_pass": 1e3 * self.first_clock.pass_seconds,
                "split_column": self.split_column(w),
            });
        }
        if let Ok(mut o) = self.outcome.lock() {
            if self.args.json {
                o.json = Some(json.to_string());
            }
            o.finished = true;
        }
        self.args.frames = None;
        if let Some(path) = self.args.window_screenshot.clone() {
            // The next frame is captured whole; the window closes once it is written.
            let done = Arc::new(Mutex::new(None));
            let slot = done.clone();
            ctx.send_viewport_cmd(egui::ViewportCommand::Screenshot(
                egui::ScreenshotCallback::new(move |image| {
                    let [w, h] = image.size;
                    let rgb: Vec<u8> = image
                        .pixels
                        .iter()
                        .flat_map(|c| [c.r(), c.g(), c.b()])
                        .collect();
                    let r = export::write_png(&path, w as u32, h as u32, &rgb)
                        .map_err(|e| e.to_string());
                    if let Ok(mut s) = slot.lock() {
                        *s = Some(r);
                    }
                }),
            ));
            self.window_shot = Some((Instant::now(), done));
            return Ok(());
        }
        ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        Ok(())
    }

    /// Closes the window once a scripted window screenshot is written (or has failed).
    fn finish_window_shot(&mut self, ctx: &egui::Context) -> Result<()> {
        let Some((asked, done)) = &self.window_shot else {
            return Ok(());
        };
        let result = done.lock().ok().and_then(|mut d| d.take());
        match result {
            Some(Ok(())) => {}
            Some(Err(e)) => return Err(anyhow!(e)),
            None if asked.elapsed() > Duration::from_secs(20) => {
                return Err(anyhow!("the window screenshot did not arrive within 20 s"));
            }
            None => return Ok(()),
        }
        self.window_shot = None;
        ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        Ok(())
    }

    fn controls(&mut self, ui: &mut egui::Ui) {
        ui.heading("pinview");
        ui.label(self.medium.path.display().to_string());
        if let Some(job) = &self.bake {
            ui.add(egui::ProgressBar::new(job.progress()).text("baking pins"));
        }
        if self.medium.is_volume && self.sequence.is_none() {
            let mut scale = self.density_scale;
            let r = ui.add(
                egui::Slider::new(&mut scale, 0.01..=100.0)
                    .logarithmic(true)
                    .text("density scale"),
            );
            if r.changed() {
                self.density_scale = scale;
            }
            // A re-bake when the slider is let go (or typed in), not on every step of a drag.
            let settled = r.drag_stopped() || (r.changed() && !r.dragged());
            let baking = self.rebake.as_ref().map(|(s, _)| *s);
            if settled
                && baking != Some(self.density_scale)
                && let Err(e) = self.start_rebake(self.density_scale)
            {
                self.status = e.to_string();
            }
            if let Some((s, job)) = &self.rebake {
                ui.add(
                    egui::ProgressBar::new(job.progress())
                        .text(format!("re-baking on the GPU at {s:.3}")),
                );
            }
        }
        let mut go_to = None;
        if let Some(s) = &mut self.sequence {
            ui.separator();
            ui.label(format!(
                "frame {} ({} of {})",
                s.frames[s.current].0,
                s.current + 1,
                s.len()
            ));
            ui.horizontal(|ui| {
                if ui
                    .button(if s.playing { "pause" } else { "play" })
                    .clicked()
                {
                    s.playing = !s.playing;
                }
                if ui.button("<").clicked() {
                    go_to = Some((s.current + s.len() - 1) % s.len());
                }
                if ui.button(">").clicked() {
                    go_to = Some((s.current + 1) % s.len());
                }
            });
            let mut at = s.current;
            if ui
                .add(egui::Slider::new(&mut at, 0..=s.len() - 1).text("scrub"))
                .changed()
            {
                go_to = Some(at);
            }
        }
        if let Some(i) = go_to
            && let Err(e) = self.go_to_frame(i)
        {
            self.status = e.to_string();
        }
        ui.separator();
        let available = self.medium.estimators();
        egui::ComboBox::from_label("estimator")
            .selected_text(self.view.estimator.to_string())
            .show_ui(ui, |ui| {
                for e in &available {
                    ui.selectable_value(&mut self.wanted, *e, e.to_string());
                }
            });
        if self.medium.scene().is_some() {
            self.compare_wanted = None;
            ui.label(SCENE_NOTE);
        } else {
            self.compare_controls(ui, &available);
        }
        let v = &mut self.view;
        ui.add(egui::Slider::new(&mut v.look.fov, 5.0..=120.0).text("fov"));
        ui.add(egui::Slider::new(&mut v.look.albedo, 0.0..=1.0).text("albedo"));
        ui.add(egui::Slider::new(&mut v.look.g, -0.95..=0.95).text("g"));
        ui.add(egui::Slider::new(&mut v.look.max_bounces, 0..=64).text("bounces"));
        ui.add(egui::Slider::new(&mut v.look.sun_radiance, 0.0..=20.0).text("sun radiance"));
        ui.add(egui::Slider::new(&mut v.look.env_radiance, 0.0..=5.0).text("sky radiance"));
        ui.add(
            egui::Slider::new(&mut v.exposure, 0.05..=20.0)
                .logarithmic(true)
                .text("exposure"),
        );
        ui.label(format!(
            "sun direction {:.2}, {:.2}, {:.2} (ctrl-drag the image)",
            v.look.sun_dir[0], v.look.sun_dir[1], v.look.sun_dir[2]
        ));
        ui.horizontal(|ui| {
            if ui.button("reset view").clicked() {
                let (o, t) = self.medium.home();
                self.view.origin = o;
                self.view.target = t;
            }
            if ui
                .button(if self.paused { "resume" } else { "pause" })
                .clicked()
            {
                self.paused = !self.paused;
            }
        });
        ui.separator();
        self.overlay_controls(ui);
        ui.separator();
        self.error_controls(ui);
        ui.separator();
        self.readouts(ui);
        ui.separator();
        self.export(ui);
        if !self.status.is_empty() {
            ui.separator();
            ui.label(egui::RichText::new(&self.status).color(egui::Color32::YELLOW));
        }
    }

    /// The second estimator's menu (split view).
    fn compare_controls(&mut self, ui: &mut egui::Ui, available: &[EstimatorSpec]) {
        egui::ComboBox::from_label("compare with")
            .selected_text(
                self.compare_wanted
                    .map_or("none".to_string(), |e| e.to_string()),
            )
            .show_ui(ui, |ui| {
                ui.selectable_value(&mut self.compare_wanted, None, "none");
                for e in available {
                    ui.selectable_value(&mut self.compare_wanted, Some(*e), e.to_string());
                }
            });
        if let Some(e) = self.compare_wanted
            && !available.contains(&e)
        {
            ui.label(format!("{e}: not answered by this file (yet)"));
        }
    }

    /// The overlays' toggles and the picked entry's readout.
    fn overlay_controls(&mut self, ui: &mut egui::Ui) {
        if self.medium.scene().is_some() {
            self.pins_on = false;
            self.grid_on = false;
            ui.label("pins under the cursor and the cell grid: one medium only, not a scene");
            return;
        }
        ui.checkbox(&mut self.pins_on, "pins under the cursor (click holds)");
        ui.checkbox(&mut self.grid_on, "box and cell grid");
        if self.medium.pins().is_none() && (self.pins_on || self.grid_on) {
            ui.label("no pins yet (the bake is running)");
            return;
        }
        if !self.pins_on {
            return;
        }
        match &self.pick {
            Some(p) => {
                for line in pin_overlay::describe(p) {
                    ui.label(egui::RichText::new(line).monospace().size(10.0));
                }
            }
            None => {
                ui.label("the cursor's ray misses the box");
            }
        }
    }

    /// The error view's toggles, the reference's state and the RMSE-against-time plot.
    fn error_controls(&mut self, ui: &mut egui::Ui) {
        if self.medium.scene().is_some() {
            self.error_on = false;
            self.heat_on = false;
            ui.label("error view: one medium only, not a scene");
            return;
        }
        ui.checkbox(&mut self.error_on, "reference and RMSE plot");
        if !self.error_on {
            self.heat_on = false;
            return;
        }
        ui.checkbox(&mut self.heat_on, "error view (|estimate - reference|)");
        if let Some(why) = error_view::no_reference_reason(&self.medium) {
            ui.label(egui::RichText::new(why).color(egui::Color32::YELLOW));
            return;
        }
        let passes = self.reference.as_ref().map_or(0, |r| r.session.passes());
        ui.label(format!(
            "reference: ratio tracking, {passes} passes (itself noisy; read every {} ms, \
             {:.1} ms a read)",
            error_view::ERROR_PERIOD.as_millis(),
            1e3 * self.error.update_seconds
        ));
        let names = [
            Some(self.view.estimator),
            self.compare.as_ref().map(|c| c.estimator),
        ];
        for (k, name) in names.iter().enumerate() {
            if let (Some(n), Some(e)) = (name, self.error.rmse[k]) {
                ui.label(format!("RMSE {n}: {e:.4e}"));
            }
        }
        let points = &self.error.points;
        egui_plot::Plot::new("pinview rmse")
            .height(160.0)
            .x_axis_label("seconds")
            .y_axis_label("RMSE")
            .legend(egui_plot::Legend::default())
            .show(ui, |plot| {
                for (k, name) in names.iter().enumerate() {
                    if let Some(n) = name {
                        plot.line(egui_plot::Line::new(n.to_string(), points[k].clone()));
                    }
                }
            });
    }

    fn readouts(&self, ui: &mut egui::Ui) {
        ui.label(format!(
            "adapter: {} ({:?}, {:?})",
            self.info.name, self.info.backend, self.info.device_type
        ));
        if self.info.device_type == wgpu::DeviceType::Cpu {
            ui.label(
                egui::RichText::new("a CPU adapter: figures are not GPU speed")
                    .color(egui::Color32::LIGHT_RED),
            );
        }
        let passes = self.session.as_ref().map_or(0, |s| s.passes());
        let ms = self.ms_per_pass();
        let pixels = f64::from(self.view.width) * f64::from(self.view.height);
        ui.label(format!("spp {passes}"));
        ui.label(format!(
            "{ms:.2} ms per pass ({})",
            match self.pass_time_source() {
                PassTimeSource::GpuTimestamps => "GPU timestamps",
                PassTimeSource::Wall => "wall time",
            }
        ));
        if ms > 0.0 {
            ui.label(format!("{:.3e} samples/s", pixels / (ms * 1e-3)));
        }
        if let Some(t) = self.first_image_s {
            ui.label(format!("first image after {t:.3} s"));
        }
        if let Some(c) = &self.compare {
            ui.label(format!(
                "compare {}: spp {}, {:.2} ms per pass; {:.3} s vs {:.3} s",
                c.estimator,
                c.session.passes(),
                c.ms_per_pass(),
                c.seconds(),
                self.seconds(),
            ));
        }
        if let Some((_, r)) = &self.renderer {
            ui.label("GPU bytes:");
            for (name, bytes) in r.section_bytes() {
                ui.label(format!("  {name}: {bytes}"));
            }
        }
    }

    fn export(&mut self, ui: &mut egui::Ui) {
        let passes = self.session.as_ref().map_or(0, |s| s.passes());
        ui.horizontal(|ui| {
            if ui.button("save PNG").clicked() {
                let (w, h) = self.target.size;
                let path = PathBuf::from(format!("pinview-{passes}spp.png"));
                self.status = match export::read_texture_rgb(
                    &self.device,
                    &self.queue,
                    &self.target.texture,
                    w,
                    h,
                )
                .and_then(|rgb| export::write_png(&path, w, h, &rgb))
                {
                    Ok(()) => format!("wrote {}", path.display()),
                    Err(e) => e.to_string(),
                };
            }
            if ui.button("save EXR").clicked()
                && let Some(s) = &mut self.session
            {
                let path = PathBuf::from(format!("pinview-{passes}spp.exr"));
                self.status = match s
                    .image()
                    .map_err(|e| anyhow!("{e}"))
                    .and_then(|i| i.write_exr(&path).map_err(|e| anyhow!("{e}")))
                {
                    Ok(()) => format!("wrote {}", path.display()),
                    Err(e) => e.to_string(),
                };
            }
            if ui.button("copy command").clicked() {
                self.command =
                    self.view
                        .command_line(self.medium.input_flag(), &self.medium.path, passes);
                ui.ctx().copy_text(self.command.clone());
            }
        });
        if !self.command.is_empty() {
            ui.add(
                egui::TextEdit::multiline(&mut self.command.as_str())
                    .desired_rows(4)
                    .font(egui::TextStyle::Monospace),
            );
        }
    }

    /// The image with its mouse controls.
    fn image(&mut self, ui: &mut egui::Ui) {
        let (w, h) = self.target.size;
        let avail = ui.available_size();
        let scale = (avail.x / w as f32)
            .min(avail.y / h as f32)
            .clamp(0.05, 1.0);
        let size = egui::vec2(w as f32 * scale, h as f32 * scale);
        let response = ui.add(
            egui::Image::new(egui::load::SizedTexture::new(self.target.id, size))
                .sense(egui::Sense::click_and_drag()),
        );
        if self.heat_on
            && let Some(t) = &self.error.textures[0]
        {
            ui.painter().image(
                t.id(),
                response.rect,
                egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0)),
                egui::Color32::WHITE,
            );
        }
        let divider_dragged = self.split_view(ui, response.rect);
        self.image_rect = Some(response.rect);
        self.overlays(ui, &response);
        let d = if divider_dragged {
            egui::Vec2::ZERO
        } else {
            response.drag_delta()
        };
        let (ctrl, shift) = ui.input(|i| (i.modifiers.ctrl, i.modifiers.shift));
        let k = 0.01;
        if d != egui::Vec2::ZERO {
            if ctrl {
                self.view.turn_sun(f64::from(d.x) * k, f64::from(-d.y) * k);
            } else if response.dragged_by(egui::PointerButton::Secondary) || shift {
                self.view.pan(
                    f64::from(d.x) / f64::from(size.x),
                    f64::from(d.y) / f64::from(size.y),
                );
            } else {
                self.view.orbit(f64::from(-d.x) * k, f64::from(d.y) * k);
            }
        }
        if response.hovered() {
            let scroll = ui.input(|i| i.smooth_scroll_delta.y);
            if scroll != 0.0 {
                self.view.zoom((-f64::from(scroll) * 0.002).exp());
            }
        }
    }

    /// The pins under the cursor (or at the held pixel: a click holds or releases it) and the
    /// box with its cell grid, projected through the view's camera.
    fn overlays(&mut self, ui: &egui::Ui, response: &egui::Response) {
        let rect = response.rect;
        let (w, h) = (f64::from(self.view.width), f64::from(self.view.height));
        let to_pixel = |p: egui::Pos2| {
            [
                (f64::from((p.x - rect.left()) / rect.width().max(1.0)) * w).floor(),
                (f64::from((p.y - rect.top()) / rect.height().max(1.0)) * h).floor(),
            ]
        };
        if self.pins_on && response.clicked() {
            self.held_pixel = match self.held_pixel {
                Some(_) => None,
                None => response.interact_pointer_pos().map(to_pixel),
            };
        }
        let (Some(grid), Some(proj)) = (self.medium.pins().cloned(), Projector::new(&self.view))
        else {
            self.pick = None;
            return;
        };
        let to_screen = |p: [f64; 2]| {
            egui::pos2(
                rect.left() + (p[0] / w) as f32 * rect.width(),
                rect.top() + (p[1] / h) as f32 * rect.height(),
            )
        };
        let painter = ui.painter_at(rect);
        if self.grid_on {
            pin_overlay::draw_grid(&painter, &proj, &to_screen, &grid);
        }
        if !self.pins_on {
            self.pick = None;
            return;
        }
        let pixel = self
            .held_pixel
            .or_else(|| response.hover_pos().map(to_pixel));
        self.pick = pixel.and_then(|[x, y]| self.pick_at(x, y));
        if let Some(p) = &self.pick {
            pin_overlay::draw_pins(&painter, &proj, &to_screen, p);
        }
    }

    /// The second estimator's image right of the divider, the divider (dragged to move it),
    /// and each side's label: estimator, spp and seconds spent. Returns whether the divider
    /// is being dragged.
    fn split_view(&mut self, ui: &mut egui::Ui, rect: egui::Rect) -> bool {
        let (Some(c), Some(target)) = (&self.compare, &self.compare_target) else {
            return false;
        };
        let x = rect.left() + self.split * rect.width();
        let painter = ui.painter_at(rect);
        let right = egui::Rect::from_min_max(egui::pos2(x, rect.top()), rect.max);
        let right_id = match &self.error.textures[1] {
            Some(t) if self.heat_on => t.id(),
            _ => target.id,
        };
        painter.image(
            right_id,
            right,
            egui::Rect::from_min_max(egui::pos2(self.split, 0.0), egui::pos2(1.0, 1.0)),
            egui::Color32::WHITE,
        );
        painter.line_segment(
            [egui::pos2(x, rect.top()), egui::pos2(x, rect.bottom())],
            egui::Stroke::new(2.0, egui::Color32::WHITE),
        );
        let label = |est: EstimatorSpec, passes: u32, seconds: f64| {
            format!("{est}  {passes} spp  {seconds:.2} s")
        };
        let first = self.session.as_ref().map_or(0, |s| s.passes());
        let texts = [
            (
                label(self.view.estimator, first, self.seconds()),
                egui::pos2(rect.left() + 4.0, rect.top() + 4.0),
                egui::Align2::LEFT_TOP,
            ),
            (
                label(c.estimator, c.session.passes(), c.seconds()),
                // Bottom right: the two labels never overlap on a narrow image.
                egui::pos2(rect.right() - 4.0, rect.bottom() - 4.0),
                egui::Align2::RIGHT_BOTTOM,
            ),
        ];
        for (text, at, align) in texts {
            let galley =
                painter.layout_no_wrap(text, egui::FontId::monospace(12.0), egui::Color32::WHITE);
            let r = align.anchor_size(at, galley.size());
            painter.rect_filled(r.expand(2.0), 2.0, egui::Color32::from_black_alpha(160));
            painter.galley(r.min, galley, egui::Color32::WHITE);
        }
        let handle = egui::Rect::from_center_size(
            egui::pos2(x, rect.center().y),
            egui::vec2(12.0, rect.height()),
        );
        let r = ui.interact(
            handle,
            ui.make_persistent_id("pinview divider"),
            egui::Sense::drag(),
        );
        if r.hovered() || r.dragged() {
            ui.ctx().set_cursor_icon(egui::CursorIcon::ResizeHorizontal);
        }
        if r.dragged() {
            self.split = (self.split + r.drag_delta().x / rect.width().max(1.0)).clamp(0.0, 1.0);
        }
        r.dragged()
    }

    fn keys(&mut self, ctx: &egui::Context) {
        use egui::Key;
        let pressed = |k: Key| ctx.input(|i| i.key_pressed(k));
        if ctx.egui_wants_keyboard_input() {
            return;
        }
        let step = 0.08;
        if pressed(Key::ArrowLeft) {
            self.view.orbit(-step, 0.0);
        }
        if pressed(Key::ArrowRight) {
            self.view.orbit(step, 0.0);
        }
        if pressed(Key::ArrowUp) {
            self.view.orbit(0.0, step);
        }
        if pressed(Key::ArrowDown) {
            self.view.orbit(0.0, -step);
        }
        if pressed(Key::Plus) || pressed(Key::Equals) {
            self.view.zoom(0.9);
        }
        if pressed(Key::Minus) {
            self.view.zoom(1.1);
        }
        if pressed(Key::R) {
            let (o, t) = self.medium.home();
            self.view.origin = o;
            self.view.target = t;
        }
        if let Some(s) = &mut self.sequence {
            if pressed(Key::Space) {
                s.playing = !s.playing;
            }
            let n = s.len();
            let step_to = if pressed(Key::Period) {
                Some((s.current + 1) % n)
            } else if pressed(Key::Comma) {
                Some((s.current + n - 1) % n)
            } else {
                None
            };
            if let Some(i) = step_to
                && let Err(e) = self.go_to_frame(i)
            {
                self.status = e.to_string();
            }
        }
    }
}

/// `pinrender render`'s default for the input; for a volume, the pins estimator it will
/// have once baked is not assumed: ratio until then.
fn initial_estimator(medium: &Medium) -> EstimatorSpec {
    medium.default_estimator()
}

impl eframe::App for Viewer {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        if let Err(e) = self.poll_background(&ctx) {
            self.fail(&ctx, e);
        }
        let before = self.view.clone();
        let scripted = self.args.frames.is_some();
        if !scripted {
            self.keys(&ctx);
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
        }
        if let Err(e) = self.render() {
            self.fail(&ctx, e);
        }
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
        ctx.request_repaint();
    }
}
