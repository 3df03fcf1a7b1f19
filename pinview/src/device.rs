//! The device and image helpers that the window (`app/window.rs`), the off-screen run and
//! the renderers' workers (`build.rs`) share: a leaf, so a worker need not import the UI.

/// The texture format of the displayed image (the tone-map pass writes sRGB codes itself).
pub const IMAGE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

/// The device the viewer opens on `adapter` (the window's and the off-screen run's alike):
/// the adapter's own limits, and timestamp queries where it has them and is not a CPU.
pub fn device_descriptor(adapter: &wgpu::Adapter) -> wgpu::DeviceDescriptor<'static> {
    wgpu::DeviceDescriptor {
        label: Some("pinview"),
        // Pass times from the GPU's own clock where the adapter can tell them. Not on a CPU
        // adapter: lavapipe stamps a pass when it processes the command, not when its threads
        // finish the dispatch (measured 20x and 220x below the wall time for pins and PinMS),
        // so the wall time is the truer figure there.
        //
        // A pipeline cache where the backend keeps one (Vulkan): compiled pipelines go to disk
        // and a later run starts from them (`pinrender::gpu_render::GpuPipelines`).
        required_features: adapter.features()
            & if adapter.get_info().device_type == wgpu::DeviceType::Cpu {
                wgpu::Features::PIPELINE_CACHE
            } else {
                wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::PIPELINE_CACHE
            },
        required_limits: adapter.limits(),
        ..Default::default()
    }
}

/// The texture the accumulation is tone-mapped into: the window shows it through egui, the
/// off-screen mode reads it back, so both images are one format and one usage.
pub fn image_texture(device: &wgpu::Device, width: u32, height: u32, label: &str) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
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
            | wgpu::TextureUsages::COPY_SRC
            | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    })
}
