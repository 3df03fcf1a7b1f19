//! The window's options (title, size, the adapter and device), and the textures the
//! tone-map pass draws into and egui shows.

use std::sync::{Arc, Mutex};

use anyhow::Result;
use egui::mutex::RwLock;
use pinrender::gpu_render::{GpuSession, GpuToneMap};

use super::Viewer;
use crate::args::ViewArgs;
use crate::build::Relay;
pub use crate::device::{IMAGE_FORMAT, device_descriptor, image_texture};

/// The window's options: title, size, and the wgpu device opened on the
/// adapter `pinrender render --backend gpu` picks, with the adapter's own limits.
pub fn native_options(a: &ViewArgs) -> crate::shell::WindowOptions {
    let title = format!("pinview - {}", a.file.display());
    let (w, h) = a.size();
    let w = (w as f32 + 360.0).min(1900.0);
    let h = (h as f32 + 24.0).clamp(700.0, 1200.0);
    let setup = egui_wgpu::WgpuSetupCreateNew {
        power_preference: wgpu::PowerPreference::HighPerformance,
        native_adapter_selector: Some(Arc::new(|adapters, _surface| {
            pick_adapter(adapters).ok_or_else(|| {
                "no GPU adapter found. Install a Vulkan driver; without a GPU, Mesa's lavapipe \
                 works: `apt-get install mesa-vulkan-drivers libvulkan1`"
                    .to_string()
            })
        })),
        device_descriptor: Arc::new(device_descriptor),
        ..egui_wgpu::WgpuSetupCreateNew::without_display_handle()
    };
    crate::shell::WindowOptions {
        title,
        inner_size: [w, h],
        wgpu: egui_wgpu::WgpuConfiguration {
            wgpu_setup: egui_wgpu::WgpuSetup::CreateNew(setup),
            // Frames are paced by the render slices, not by the display.
            surface: egui_wgpu::SurfaceConfig {
                present_mode: wgpu::PresentMode::AutoNoVsync,
                ..egui_wgpu::SurfaceConfig::LOW_LATENCY
            },
            ..Default::default()
        },
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
pub struct Target {
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
    pub id: egui::TextureId,
    pub size: (u32, u32),
}

/// The displayed images: the shown estimator's, and the second side's once it has one.
pub struct Images {
    pub main: Target,
    pub compare: Option<Target>,
}

/// Writes RGBA bytes of `width x height` into `texture` (an [`image_texture`]).
pub fn write_image(
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
    width: u32,
    height: u32,
    rgba: &[u8],
) {
    queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        rgba,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(width * 4),
            rows_per_image: Some(height),
        },
        wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
    );
}

/// Draws `session`'s image into `target`: by the window's tone map where the session is on
/// the window's device, else by its `relay` on the session's own device, copied over.
pub fn show(
    tone: &GpuToneMap,
    relay: Option<&mut Relay>,
    session: &GpuSession,
    target: &Target,
    queue: &wgpu::Queue,
    exposure: f32,
) -> Result<()> {
    match relay {
        None => tone.draw(session, &target.view, exposure),
        Some(r) => {
            let rgba = r.image(session, exposure)?;
            write_image(queue, &target.texture, target.size.0, target.size.1, &rgba);
        }
    }
    Ok(())
}

/// Where the window screenshot's callback leaves its result.
pub type ShotResult = Arc<Mutex<Option<Result<(), String>>>>;

impl Viewer {
    pub(super) fn make_target(
        device: &wgpu::Device,
        renderer: &Arc<RwLock<egui_wgpu::Renderer>>,
        width: u32,
        height: u32,
        old: Option<egui::TextureId>,
    ) -> Target {
        let texture = image_texture(device, width, height, "pinview image");
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
}
