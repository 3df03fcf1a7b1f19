//! The window shell: one winit window (X11) whose frames egui draws through egui-wgpu on the
//! project's wgpu. It runs an [`App`]'s `ui` once per frame, paints it, carries out the
//! viewport commands the viewer sends (close, screenshot) and wakes the loop when the app
//! or another thread asks for a repaint.
//!
//! Why not eframe: the viewer uses one window and none of eframe's persistence, icons or
//! multi-viewport machinery, and eframe's native build depends on the `image` stack
//! (`image`, `moxcms`, `pxfm`) for window icons, which took longer to compile than egui and
//! the X11 protocol crate together (docs/decisions.md D3).

use std::sync::Arc;
use std::time::{Duration, Instant};

use egui::ViewportId;
use winit::application::ApplicationHandler;
use winit::dpi::LogicalSize;
use winit::event::WindowEvent;
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop, EventLoopProxy};
use winit::window::{Window, WindowId};

/// What an app is given when the window, the adapter and the device are up.
pub struct CreationContext {
    /// The device, queue and egui's renderer of the window.
    pub wgpu_render_state: Option<egui_wgpu::RenderState>,
}

/// A program drawn in the window: its whole user interface, once per frame.
pub trait App {
    fn ui(&mut self, ui: &mut egui::Ui);

    /// Input events the app itself gives its next frame, after the window's own (scripted
    /// pointer input).
    fn raw_events(&mut self) -> Vec<egui::Event> {
        Vec::new()
    }
}

/// The window's title and size and the wgpu setup it opens.
pub struct WindowOptions {
    pub title: String,
    /// Inner size in logical pixels.
    pub inner_size: [f32; 2],
    pub wgpu: egui_wgpu::WgpuConfiguration,
}

/// Builds the app once the window is up; an error ends the run with that line.
pub type AppCreator = Box<dyn FnOnce(&CreationContext) -> Result<Box<dyn App>, String>>;

/// Opens the window and runs `create`'s app until the window is closed or the app sends
/// [`egui::ViewportCommand::Close`]. Errors: no display or event loop, no adapter or device
/// for the window, or the app's own creation error.
pub fn run(options: WindowOptions, create: AppCreator) -> Result<(), String> {
    let event_loop = EventLoop::<Wake>::with_user_event()
        .build()
        .map_err(|e| format!("cannot start the window's event loop: {e}"))?;
    let mut shell = Shell {
        options,
        create: Some(create),
        proxy: event_loop.create_proxy(),
        running: None,
        error: None,
        next_repaint: None,
    };
    event_loop
        .run_app(&mut shell)
        .map_err(|e| format!("the window's event loop failed: {e}"))?;
    match shell.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// A repaint asked for from outside a frame (another thread, or egui between frames).
#[derive(Clone, Copy, Debug)]
struct Wake {
    delay: Duration,
}

struct Shell {
    options: WindowOptions,
    create: Option<AppCreator>,
    proxy: EventLoopProxy<Wake>,
    running: Option<Running>,
    error: Option<String>,
    /// When the next frame is due, if one is asked for.
    next_repaint: Option<Instant>,
}

struct Running {
    window: Arc<Window>,
    egui_ctx: egui::Context,
    state: egui_winit::State,
    painter: egui_wgpu::winit::Painter,
    viewport_info: egui::ViewportInfo,
    app: Box<dyn App>,
}

impl Shell {
    fn start(&mut self, event_loop: &ActiveEventLoop) -> Result<(), String> {
        let attributes = Window::default_attributes()
            .with_title(self.options.title.clone())
            .with_inner_size(LogicalSize::new(
                f64::from(self.options.inner_size[0]),
                f64::from(self.options.inner_size[1]),
            ));
        let window = Arc::new(
            event_loop
                .create_window(attributes)
                .map_err(|e| format!("cannot open a window: {e}"))?,
        );
        let egui_ctx = egui::Context::default();
        // One window: any viewport an app might open is drawn inside it.
        egui_ctx.set_embed_viewports(true);
        // Two passes where egui asks for one more (a layout that changed size), as eframe does.
        egui_ctx.options_mut(|o| o.max_passes = std::num::NonZeroUsize::MIN.saturating_add(1));
        let proxy = self.proxy.clone();
        egui_ctx.set_request_repaint_callback(move |info| {
            // The loop may have ended; a lost wake-up is then harmless.
            let _ = proxy.send_event(Wake { delay: info.delay });
        });
        let mut painter = pollster::block_on(egui_wgpu::winit::Painter::new(
            egui_ctx.clone(),
            self.options.wgpu.clone(),
            false,
            egui_wgpu::RendererOptions::default(),
        ));
        pollster::block_on(painter.set_window(ViewportId::ROOT, Some(window.clone())))
            .map_err(window_error)?;
        let render_state = painter.render_state();
        let state = egui_winit::State::new(
            egui_ctx.clone(),
            ViewportId::ROOT,
            event_loop,
            Some(window.scale_factor() as f32),
            // The same look on every desktop: egui's default (dark) theme.
            None,
            painter.max_texture_side(),
        );
        let mut viewport_info = egui::ViewportInfo::default();
        egui_winit::update_viewport_info(&mut viewport_info, &egui_ctx, &window, true);
        let create = self
            .create
            .take()
            .ok_or_else(|| "the window was started twice".to_string())?;
        let app = create(&CreationContext {
            wgpu_render_state: render_state,
        })?;
        window.request_redraw();
        self.running = Some(Running {
            window,
            egui_ctx,
            state,
            painter,
            viewport_info,
            app,
        });
        Ok(())
    }

    /// Runs the app's frame and paints it; returns whether the window is to close.
    fn frame(&mut self) -> bool {
        let Some(r) = &mut self.running else {
            return false;
        };
        egui_winit::update_viewport_info(&mut r.viewport_info, &r.egui_ctx, &r.window, false);
        let mut raw_input = r.state.take_egui_input(&r.window);
        raw_input
            .viewports
            .insert(ViewportId::ROOT, r.viewport_info.clone());
        let app = &mut r.app;
        raw_input.events.extend(app.raw_events());
        let mut output = r.egui_ctx.run_ui(raw_input, |ui| app.ui(ui));
        r.state
            .handle_platform_output(&r.window, std::mem::take(&mut output.platform_output));
        let mut close = false;
        let mut shots = Vec::new();
        let mut delay = Duration::MAX;
        for (id, viewport) in std::mem::take(&mut output.viewport_output) {
            if id != ViewportId::ROOT {
                continue;
            }
            delay = viewport.repaint_delay;
            for command in viewport.commands {
                match command {
                    egui::ViewportCommand::Close => close = true,
                    egui::ViewportCommand::Screenshot(callback) => shots.push(callback),
                    _ => {}
                }
            }
        }
        let primitives = r
            .egui_ctx
            .tessellate(std::mem::take(&mut output.shapes), output.pixels_per_point);
        r.painter.paint_and_update_textures(
            ViewportId::ROOT,
            output.pixels_per_point,
            [0.0, 0.0, 0.0, 1.0],
            &primitives,
            &mut output.textures_delta,
            shots,
            &r.window,
        );
        self.schedule(delay);
        close
    }

    /// Asks for a frame after `delay` (the earliest request wins).
    fn schedule(&mut self, delay: Duration) {
        if let Some(at) = Instant::now().checked_add(delay) {
            self.next_repaint = Some(self.next_repaint.map_or(at, |t| t.min(at)));
        }
    }

    fn exit(&mut self, event_loop: &ActiveEventLoop) {
        if let Some(mut r) = self.running.take() {
            // The app goes first: it may wait for work on the device the painter holds.
            drop(r.app);
            r.painter.destroy();
        }
        event_loop.exit();
    }
}

impl ApplicationHandler<Wake> for Shell {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.running.is_some() || self.create.is_none() {
            return;
        }
        if let Err(e) = self.start(event_loop) {
            self.error = Some(e);
            self.exit(event_loop);
        }
    }

    fn user_event(&mut self, _: &ActiveEventLoop, wake: Wake) {
        self.schedule(wake.delay);
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        let Some(r) = &mut self.running else {
            return;
        };
        match &event {
            WindowEvent::CloseRequested | WindowEvent::Destroyed => {
                self.exit(event_loop);
                return;
            }
            WindowEvent::Resized(size) => {
                if let (Some(w), Some(h)) = (
                    std::num::NonZeroU32::new(size.width),
                    std::num::NonZeroU32::new(size.height),
                ) {
                    r.painter.on_window_resized(ViewportId::ROOT, w, h);
                }
            }
            WindowEvent::RedrawRequested => {
                self.next_repaint = None;
                if self.frame() {
                    self.exit(event_loop);
                }
                return;
            }
            _ => {}
        }
        let response = r.state.on_window_event(&r.window, &event);
        if response.repaint {
            r.window.request_redraw();
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        let Some(r) = &self.running else {
            return;
        };
        match self.next_repaint {
            Some(at) if at <= Instant::now() => {
                self.next_repaint = None;
                r.window.request_redraw();
                event_loop.set_control_flow(ControlFlow::Wait);
            }
            Some(at) => event_loop.set_control_flow(ControlFlow::WaitUntil(at)),
            None => event_loop.set_control_flow(ControlFlow::Wait),
        }
    }
}

/// The window's GPU failure as a line that says what to do: egui-wgpu's own words for a
/// surface without formats ("There was no valid format for the surface at all") mean that
/// no Vulkan driver can present to this display.
fn window_error(e: egui_wgpu::WgpuError) -> String {
    match e {
        egui_wgpu::WgpuError::NoSurfaceFormatsAvailable => NO_SURFACE_FORMAT.to_string(),
        e => format!("cannot draw into the window: {e}"),
    }
}

const NO_SURFACE_FORMAT: &str = "cannot draw into the window: no GPU driver can present to \
     this display (no surface format). Install a Vulkan driver; without a GPU, Mesa's \
     lavapipe works: `apt-get install mesa-vulkan-drivers libvulkan1`";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_surface_without_formats_is_one_line_that_says_what_to_do() {
        let line = window_error(egui_wgpu::WgpuError::NoSurfaceFormatsAvailable);
        assert!(!line.contains('\n'), "{line}");
        assert!(!line.contains("There was no valid format"), "{line}");
        assert!(line.contains("mesa-vulkan-drivers"), "{line}");
    }
}
