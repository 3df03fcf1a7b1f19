//! Shows a [`GpuSession`]'s accumulation without reading it back: a full-screen triangle
//! whose fragment shader divides the Kahan sum by the passes and tone-maps it as
//! [`crate::render::tone_map`] does for `pinrender render`'s PNG (exposure, Reinhard, the
//! sRGB transfer function, rounded to 8 bits), into a texture the caller displays.

use wgpu::util::DeviceExt;

use super::GpuSession;

/// The tone-map shader (`vs_main`, `fs_main`).
pub const TONE_MAP_WGSL: &str = include_str!("tone_map.wgsl");

/// The tone-map pipeline for one target format. The format must not be an sRGB one: the
/// shader writes the sRGB-encoded 8-bit value itself (`Rgba8Unorm` or `Bgra8Unorm`).
#[derive(Debug)]
pub struct GpuToneMap {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
}

/// `ToneParams` of `tone_map.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ToneParams {
    size: [u32; 4],
    scale: [f32; 4],
}

impl GpuToneMap {
    /// Compiles the pipeline for targets of `format`.
    pub fn new(device: &wgpu::Device, format: wgpu::TextureFormat) -> Self {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("tone_map.wgsl"),
            source: wgpu::ShaderSource::Wgsl(TONE_MAP_WGSL.into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("tone map"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage { read_only: true },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("tone map"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("tone map"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_main"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        Self { pipeline, layout }
    }

    /// Draws `session`'s mean image, tone-mapped at `exposure`, into `target` (a view of a
    /// texture of the session's size) and submits it. Before the first pass it draws black.
    pub fn draw(&self, session: &GpuSession, target: &wgpu::TextureView, exposure: f32) {
        let device = &session.device;
        // Rows above the band in progress hold one sample more than the whole passes.
        let inv = |n: u32| if n > 0 { 1.0 / n as f32 } else { 0.0 };
        let params = ToneParams {
            size: [session.width(), session.height(), session.next_row(), 0],
            scale: [
                inv(session.passes()),
                exposure,
                inv(session.passes() + 1),
                0.0,
            ],
        };
        let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("tone map params"),
            contents: bytemuck::bytes_of(&params),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("tone map"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: uniform.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: session.accumulation().as_entire_binding(),
                },
            ],
        });
        let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("tone map"),
        });
        {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("tone map"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: target,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &group, &[]);
            pass.draw(0..3, 0..1);
        }
        session.queue.submit([enc.finish()]);
    }
}
