//! The reference path tracer on the GPU, pins for every query (features `gpu` + `render`).
//!
//! [`GpuRenderer`] runs the estimator of [`crate::render`] (`tracer.rs`) in WGSL
//! (`shaders/render.wgsl` appended to `shaders/pin.wgsl`) for one pin grid that answers every
//! distance and transmittance query, i.e. the CPU render of
//! `Scene { media: vec![Medium::single(pins)], .. }`:
//!
//! * pinhole camera, one uniformly jittered ray per sample inside the pixel (box filter);
//! * the camera ray scores `env * T` (a pin transmittance estimate), then distance sampling;
//! * at each collision: throughput times albedo, sun next-event estimation
//!   `phase * T(shadow ray) * radiance`, one Henyey-Greenstein direction `w`, `env * T(w)`,
//!   and the path continues along `w`; an escape of the continuation scores nothing;
//!   `max_bounces` scattering events at most; non-finite samples are dropped.
//!
//! One compute invocation per pixel per pass (workgroups of 8 x 8), one pass per sample; the
//! passes accumulate into a storage buffer with Kahan summation and the image is read back
//! once at the end. The GPU random streams differ from the CPU renderer's, so the two agree
//! statistically (same expected image), not bit for bit; `docs/gpu.md` ("GPU path tracer")
//! states the contract and the tests that check it. A GPU render is deterministic: the same
//! grid, scene, spp and seed give the same image bits.
//!
//! Not supported here (use the CPU renderer): several media instances, PinMS (a tracker for
//! primary rays), the radiance cache, time budgets.

use std::sync::mpsc;

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use wgpu::util::DeviceExt;

use crate::chord::UnitTransform;
use crate::error::Error;
use crate::gpu::GpuContext;
use crate::loader::PinGrid;
use crate::render::phase::G_LIMIT;
use crate::render::{Camera, Image, RenderError, Scene, Sun};
use crate::sampler::SamplerOptions;

/// The WGSL of the GPU path tracer: the pin sampler followed by `shaders/render.wgsl`
/// (entry point `render_main`).
pub const RENDER_WGSL: &str = concat!(
    include_str!("../../shaders/pin.wgsl"),
    include_str!("../../shaders/render.wgsl")
);

/// Workgroup size of `render_main` (x, y), in pixels.
pub const WORKGROUP: [u32; 2] = [8, 8];

/// Largest `max_bounces` the GPU accepts. The loop is bounded by it, and a GPU invocation
/// that runs for minutes (an opaque medium with albedo 1) would trip a driver watchdog on
/// hardware; deeper paths are an error, not a silent truncation.
pub const MAX_GPU_BOUNCES: u32 = 1024;

/// Passes recorded per command buffer (bounds the per-pass uniform buffer).
const PASSES_PER_SUBMIT: u32 = 256;

/// Errors of a GPU render: an invalid scene or settings (the same checks and messages as
/// the CPU renderer), or a GPU failure.
#[derive(Debug, thiserror::Error)]
pub enum GpuRenderError {
    #[error(transparent)]
    Invalid(#[from] RenderError),
    #[error(transparent)]
    Gpu(#[from] Error),
}

/// What a GPU render needs besides the grid: the CPU [`Scene`] without its media (the pin
/// grid of the [`GpuRenderer`] is the one medium) plus `max_bounces`.
#[derive(Clone, Debug)]
pub struct GpuScene {
    pub camera: Camera,
    pub sun: Option<Sun>,
    /// Constant radiance arriving from every direction of the sphere.
    pub env_radiance: [f32; 3],
    /// Single-scattering albedo in `[0, 1]`.
    pub albedo: f32,
    /// Henyey-Greenstein asymmetry in `(-1, 1)`.
    pub g: f32,
    /// Maximum number of scattering events (0: transmitted environment only), at most
    /// [`MAX_GPU_BOUNCES`].
    pub max_bounces: u32,
}

impl GpuScene {
    /// The GPU view of a CPU scene (its media are ignored).
    pub fn from_scene(scene: &Scene, max_bounces: u32) -> Self {
        GpuScene {
            camera: scene.camera.clone(),
            sun: scene.sun.clone(),
            env_radiance: scene.env_radiance,
            albedo: scene.albedo,
            g: scene.g,
            max_bounces,
        }
    }

    /// The CPU scene with `media` (for comparisons).
    pub fn to_scene(&self, media: Vec<crate::render::Medium>) -> Scene {
        Scene {
            camera: self.camera.clone(),
            sun: self.sun.clone(),
            env_radiance: self.env_radiance,
            albedo: self.albedo,
            g: self.g,
            media,
        }
    }

    /// Every check [`GpuRenderer::render`] makes on the scene: [`Scene::validate`] plus the
    /// bounce limit.
    pub fn validate(&self) -> Result<(), RenderError> {
        self.to_scene(Vec::new()).validate()?;
        if self.max_bounces > MAX_GPU_BOUNCES {
            return Err(RenderError::Invalid {
                what: "max_bounces",
                why: format!(
                    "{} exceeds the GPU limit {MAX_GPU_BOUNCES}",
                    self.max_bounces
                ),
            });
        }
        Ok(())
    }

    /// The uniform block (the scene in the form `render_main` reads it), after `validate`.
    fn params(&self, seed: u64) -> RtParams {
        // The camera frame exactly as tracer.rs builds it.
        let c = &self.camera;
        let o = Vec3::from_array(c.origin);
        let f = (Vec3::from_array(c.target) - o).normalize_or_zero();
        let mut r = f.cross(Vec3::Y);
        if r.length_squared() < 1e-12 {
            r = f.cross(Vec3::Z);
        }
        let r = r.normalize();
        let u = r.cross(f);
        let tan_half = (c.vfov_deg.to_radians() * 0.5).tan();
        let aspect = c.width as f32 / c.height as f32;
        // Lights as the CPU's `Scene::ctx` keeps them: a zero sun or environment is absent.
        let sun = self.sun.as_ref().and_then(|s| {
            let d = Vec3::from_array(s.dir).normalize_or_zero();
            let rad = Vec3::from_array(s.radiance);
            (d != Vec3::ZERO && rad != Vec3::ZERO).then_some((d, rad))
        });
        let (sun_dir, sun_rad) = match sun {
            Some((d, rad)) => ([d.x, d.y, d.z, 1.0], [rad.x, rad.y, rad.z, 0.0]),
            None => ([0.0; 4], [0.0; 4]),
        };
        let e = self.env_radiance;
        let has_env = if Vec3::from_array(e) != Vec3::ZERO {
            1.0
        } else {
            0.0
        };
        let g_limit = G_LIMIT as f32;
        RtParams {
            cam_o: [o.x, o.y, o.z, tan_half],
            cam_f: [f.x, f.y, f.z, aspect],
            cam_r: [r.x, r.y, r.z, c.width as f32],
            cam_u: [u.x, u.y, u.z, c.height as f32],
            sun_dir,
            sun_rad,
            env: [e[0], e[1], e[2], has_env],
            material: [
                self.albedo.clamp(0.0, 1.0),
                self.g.clamp(-g_limit, g_limit),
                0.0,
                0.0,
            ],
            size: [c.width, c.height, self.max_bounces, 0],
            seed: [seed as u32, (seed >> 32) as u32, 0, 0],
        }
    }
}

/// `RtParams` of `render.wgsl` (160 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct RtParams {
    cam_o: [f32; 4],
    cam_f: [f32; 4],
    cam_r: [f32; 4],
    cam_u: [f32; 4],
    sun_dir: [f32; 4],
    sun_rad: [f32; 4],
    env: [f32; 4],
    material: [f32; 4],
    size: [u32; 4],
    seed: [u32; 4],
}

/// `Params` of `pin.wgsl` (128 bytes): the grid's placement and shape; `run` is unused by
/// the path tracer.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GridParams {
    rows: [[f32; 4]; 3],
    jitter: [f32; 4],
    dims: [u32; 4],
    grid: [u32; 4],
    dirs: [u32; 4],
    run: [u32; 4],
}

fn gpu_err(what: &str, e: impl std::fmt::Display) -> Error {
    Error::Gpu(format!("{what}: {e}"))
}

/// A pin grid on the GPU with the compiled path-tracing pipeline.
pub struct GpuRenderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    limits: wgpu::Limits,
    pipeline: wgpu::ComputePipeline,
    grid_group: wgpu::BindGroup,
    render_layout: wgpu::BindGroupLayout,
    pin_bytes: u64,
}

impl std::fmt::Debug for GpuRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuRenderer")
            .field("pin_bytes", &self.pin_bytes)
            .finish()
    }
}

fn uniform_entry(binding: u32, dynamic: bool, size: u64) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: dynamic,
            min_binding_size: wgpu::BufferSize::new(size),
        },
        count: None,
    }
}

fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

impl GpuRenderer {
    /// Uploads `grid` (placed by the file's `local_to_world`, no lookup jitter) and compiles
    /// the path tracer.
    pub fn new(ctx: &GpuContext, grid: &PinGrid) -> crate::Result<Self> {
        Self::with_options(ctx, grid, None, SamplerOptions::default())
    }

    /// Uploads with an optional `local_to_world` override and lookup options (as
    /// [`crate::gpu::GpuPinGrid::upload_with`]).
    pub fn with_options(
        ctx: &GpuContext,
        grid: &PinGrid,
        local_to_world: Option<&[f64; 12]>,
        options: SamplerOptions,
    ) -> crate::Result<Self> {
        pollster::block_on(Self::create(ctx, grid, local_to_world, options))
    }

    async fn create(
        ctx: &GpuContext,
        grid: &PinGrid,
        local_to_world: Option<&[f64; 12]>,
        options: SamplerOptions,
    ) -> crate::Result<Self> {
        let xf = UnitTransform::new(grid.desc(), local_to_world)?;
        let limit = ctx
            .limits
            .max_storage_buffer_binding_size
            .min(ctx.limits.max_buffer_size);
        let check = |what: &str, len: usize| -> crate::Result<()> {
            if len as u64 > limit {
                return Err(Error::Gpu(format!(
                    "{what} is {len} bytes, more than this device binds in one storage buffer \
                     ({limit} bytes); use a coarser grid or a device with larger limits"
                )));
            }
            Ok(())
        };
        let pins_bytes = grid.pins_bytes();
        check("the pin section", pins_bytes.len())?;
        let index_bytes = grid.cell_index_bytes();
        if let Some(b) = index_bytes {
            check("the cell index", b.len())?;
        }
        let s = grid.shape();
        let block_len = u32::try_from(s.block_len)
            .map_err(|_| Error::Gpu("block length exceeds u32".into()))?;
        let stored = u32::try_from(grid.desc().stored_cells)
            .map_err(|_| Error::Gpu("stored cells exceed u32".into()))?;
        let (kind, res) = s.directions.to_desc();
        let on = |x: f32| if x > 0.0 && x.is_finite() { x } else { 0.0 };
        let grid_params = GridParams {
            rows: xf.rows,
            jitter: [
                on(options.spatial_jitter),
                on(options.directional_jitter),
                0.0,
                0.0,
            ],
            dims: [s.dims[0], s.dims[1], s.dims[2], s.z_begin],
            grid: [s.z_end, s.pins_per_entry, block_len, stored],
            dirs: [kind, res[0], res[1], u32::from(index_bytes.is_some())],
            run: [0; 4],
        };

        let dev = &ctx.device;
        let scope = dev.push_error_scope(wgpu::ErrorFilter::Validation);
        let dummy = [0u8; 8];
        let storage = |label: &str, contents: &[u8]| {
            dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: if contents.is_empty() {
                    &dummy
                } else {
                    contents
                },
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        let pins = storage("render pins", pins_bytes);
        let index = storage("render cell index", index_bytes.unwrap_or(&[]));
        let grid_uniform = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("render grid params"),
            contents: bytemuck::bytes_of(&grid_params),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let grid_layout = dev.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("render grid"),
            entries: &[
                uniform_entry(0, false, size_of::<GridParams>() as u64),
                storage_entry(1, true),
                storage_entry(2, true),
            ],
        });
        let render_layout = dev.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("render scene"),
            entries: &[
                uniform_entry(0, false, size_of::<RtParams>() as u64),
                uniform_entry(1, true, 16),
                storage_entry(2, false),
            ],
        });
        let grid_group = dev.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("render grid"),
            layout: &grid_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: grid_uniform.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: pins.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: index.as_entire_binding(),
                },
            ],
        });
        let layout = dev.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("render"),
            bind_group_layouts: &[Some(&grid_layout), Some(&render_layout)],
            immediate_size: 0,
        });
        let module = dev.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("pin.wgsl + render.wgsl"),
            source: wgpu::ShaderSource::Wgsl(RENDER_WGSL.into()),
        });
        let pipeline = dev.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("render"),
            layout: Some(&layout),
            module: &module,
            entry_point: Some("render_main"),
            compilation_options: Default::default(),
            cache: None,
        });
        if let Some(e) = scope.pop().await {
            return Err(gpu_err("compiling shaders/render.wgsl", e));
        }
        Ok(Self {
            device: ctx.device.clone(),
            queue: ctx.queue.clone(),
            limits: ctx.limits.clone(),
            pipeline,
            grid_group,
            render_layout,
            pin_bytes: pins_bytes.len() as u64,
        })
    }

    /// Renders `spp` samples per pixel (one pass each) with seed `seed`. The same inputs give
    /// the same image bits. Errors: an invalid scene (the CPU renderer's checks: zero-size
    /// image, NaN camera, `g` outside `(-1, 1)`, albedo outside `[0, 1]`, bad radiance),
    /// `spp == 0`, `max_bounces > MAX_GPU_BOUNCES`, an image too large for one dispatch or
    /// one storage buffer, or a GPU failure.
    pub fn render(&self, scene: &GpuScene, spp: u32, seed: u64) -> Result<Image, GpuRenderError> {
        scene.validate()?;
        if spp == 0 {
            return Err(RenderError::Invalid {
                what: "budget",
                why: "0 samples per pixel".into(),
            }
            .into());
        }
        let (w, h) = (scene.camera.width, scene.camera.height);
        let gx = w.div_ceil(WORKGROUP[0]);
        let gy = h.div_ceil(WORKGROUP[1]);
        let max_groups = self.limits.max_compute_workgroups_per_dimension;
        if gx > max_groups || gy > max_groups {
            return Err(Error::Gpu(format!(
                "image {w}x{h} needs {gx}x{gy} workgroups, more than this device dispatches \
                 ({max_groups} per dimension)"
            ))
            .into());
        }
        let pixels = u64::from(w) * u64::from(h);
        let accum_size = pixels * 32;
        let limit = self
            .limits
            .max_storage_buffer_binding_size
            .min(self.limits.max_buffer_size);
        if accum_size > limit {
            return Err(Error::Gpu(format!(
                "image {w}x{h} needs a {accum_size}-byte accumulation buffer, more than this \
                 device binds ({limit} bytes)"
            ))
            .into());
        }
        let params = scene.params(seed);
        Ok(pollster::block_on(
            self.run(&params, gx, gy, spp, accum_size, w, h),
        )?)
    }

    #[allow(clippy::too_many_arguments)]
    async fn run(
        &self,
        params: &RtParams,
        gx: u32,
        gy: u32,
        spp: u32,
        accum_size: u64,
        width: u32,
        height: u32,
    ) -> crate::Result<Image> {
        let dev = &self.device;
        let scope = dev.push_error_scope(wgpu::ErrorFilter::Validation);
        let scene_uniform = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("render scene params"),
            contents: bytemuck::bytes_of(params),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        // Zero-initialised by wgpu.
        let accum = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("render accumulation"),
            size: accum_size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let stride = u64::from(self.limits.min_uniform_buffer_offset_alignment).max(16);
        let mut first = 0u32;
        while first < spp {
            let count = (spp - first).min(PASSES_PER_SUBMIT);
            let mut pass_data = vec![0u8; (stride * u64::from(count)) as usize];
            for k in 0..count {
                let at = (stride * u64::from(k)) as usize;
                pass_data[at..at + 4].copy_from_slice(&(first + k).to_le_bytes());
            }
            let pass_uniform = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("render pass indices"),
                contents: &pass_data,
                usage: wgpu::BufferUsages::UNIFORM,
            });
            let group = dev.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("render scene"),
                layout: &self.render_layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: scene_uniform.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                            buffer: &pass_uniform,
                            offset: 0,
                            size: wgpu::BufferSize::new(16),
                        }),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: accum.as_entire_binding(),
                    },
                ],
            });
            let mut enc = dev.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("render passes"),
            });
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("render passes"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &self.grid_group, &[]);
                for k in 0..count {
                    pass.set_bind_group(1, &group, &[(stride * u64::from(k)) as u32]);
                    pass.dispatch_workgroups(gx, gy, 1);
                }
            }
            self.queue.submit([enc.finish()]);
            first += count;
        }
        let staging = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("render readback"),
            size: accum_size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = dev.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("render readback"),
        });
        enc.copy_buffer_to_buffer(&accum, 0, &staging, 0, accum_size);
        self.queue.submit([enc.finish()]);
        let (tx, rx) = mpsc::channel();
        staging.slice(..).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        dev.poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| gpu_err("poll", e))?;
        if let Some(e) = scope.pop().await {
            return Err(gpu_err("render dispatch", e));
        }
        rx.recv()
            .map_err(|e| gpu_err("readback", e))?
            .map_err(|e| gpu_err("readback", e))?;
        let view = staging
            .slice(..)
            .get_mapped_range()
            .map_err(|e| gpu_err("readback", e))?;
        let sums = bytemuck::pod_collect_to_vec::<u8, [f32; 8]>(&view);
        drop(view);
        staging.unmap();
        let inv = 1.0 / f64::from(spp);
        let rgb = sums
            .iter()
            .map(|s| {
                // Kahan: the compensation holds what the running sum over-counted.
                std::array::from_fn(|c| ((f64::from(s[c]) - f64::from(s[4 + c])) * inv) as f32)
            })
            .collect();
        Ok(Image { width, height, rgb })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{Budget, Medium, Pcg32, RenderSettings, TransportEstimator, render};
    use crate::{Ray, Rng, Sampler};
    use pin_format::{Directions, OwnedPinGrid, PinEntry, grid_desc};
    use std::sync::Arc;
    use std::time::Instant;

    fn context() -> GpuContext {
        GpuContext::new().unwrap_or_else(|e| {
            panic!(
                "GPU render tests need a working wgpu adapter: {e}\n\
                 (this test fails rather than skips so that a missing driver is noticed)"
            )
        })
    }

    /// The pin estimator for the CPU renderer: each query is seeded from two draws of the
    /// path generator, `Rng::for_query(a, b)`, as the GPU seeds its queries.
    struct PinsEstimator {
        sampler: Sampler<'static>,
    }

    impl TransportEstimator for PinsEstimator {
        fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
            let (a, b) = (rng.next_u32(), rng.next_u32());
            let ray = Ray::new(o.to_array(), d.to_array());
            self.sampler
                .sample_distance(&ray, t_max, &mut Rng::for_query(a, b))
        }
        fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32 {
            let (a, b) = (rng.next_u32(), rng.next_u32());
            let ray = Ray::new(o.to_array(), d.to_array());
            self.sampler
                .transmittance(&ray, t_max, &mut Rng::for_query(a, b))
        }
        fn name(&self) -> String {
            "pins".into()
        }
    }

    /// A blob-shaped pin grid over the world box `[-1, 1]^3`: denser pins towards the centre
    /// (more ratio bits, smaller `t_min`), random bits.
    fn blob_grid(cells: u32, directions: Directions, ppe: u32, strength: f32) -> OwnedPinGrid {
        let mut rng = Rng::for_query(0xB10B, cells);
        let block = directions.count() * ppe;
        let mut pins = Vec::new();
        for z in 0..cells {
            for y in 0..cells {
                for x in 0..cells {
                    let c = [x, y, z].map(|i| (i as f32 + 0.5) / cells as f32 * 2.0 - 1.0);
                    let r2 = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
                    let rho = 0.05 + 0.95 * (1.0 - r2).max(0.0);
                    for _ in 0..block {
                        let t_min = (-strength * rho * (0.5 + rng.next_f32())).exp();
                        let p = 0.3 + 0.6 * rho;
                        let mut mask = 0u32;
                        for b in 0..32 {
                            if rng.next_f32() < p {
                                mask |= 1 << b;
                            }
                        }
                        if t_min >= 1.0 {
                            mask = 0;
                        }
                        pins.push(PinEntry { mask, t_min });
                    }
                }
            }
        }
        let mut desc = grid_desc([cells; 3], directions, ppe, u64::from(cells.pow(3)));
        desc.box_min = [-1.0; 3];
        desc.box_max = [1.0; 3];
        desc.source_box_min = [-1.0; 3];
        desc.source_box_max = [1.0; 3];
        OwnedPinGrid {
            desc,
            tile: None,
            cell_index: None,
            pins,
            majorant: None,
            density: None,
            metadata: None,
        }
    }

    fn load(owned: &OwnedPinGrid) -> &'static PinGrid {
        // Leaked: the CPU estimator needs a 'static sampler; a test grid is small.
        Box::leak(Box::new(
            PinGrid::from_bytes(owned.to_bytes().unwrap()).unwrap(),
        ))
    }

    fn scene(size: u32, albedo: f32, g: f32, max_bounces: u32) -> GpuScene {
        GpuScene {
            camera: Camera {
                origin: [0.4, 0.6, 3.5],
                target: [0.0, 0.0, 0.0],
                vfov_deg: 40.0,
                width: size,
                height: size,
            },
            // Behind the medium as seen from the camera: forward scattering lights it.
            sun: Some(Sun {
                dir: [0.3, 0.5, -1.0],
                radiance: [3.0, 2.5, 2.0],
            }),
            env_radiance: [0.2, 0.3, 0.5],
            albedo,
            g,
            max_bounces,
        }
    }

    fn cpu_render(
        grid: &'static PinGrid,
        scene: &GpuScene,
        spp: u32,
        seed: u64,
        threads: Option<usize>,
    ) -> (Image, f64) {
        let est: Arc<dyn TransportEstimator> = Arc::new(PinsEstimator {
            sampler: grid.sampler().unwrap(),
        });
        let settings = RenderSettings {
            max_bounces: scene.max_bounces,
            seed,
            budget: Budget::Spp(spp),
            threads,
            cache: None,
        };
        let out = render(&scene.to_scene(vec![Medium::single(est)]), &settings).unwrap();
        (out.image, out.seconds)
    }

    /// Per-pixel grey value (mean of the channels).
    fn grey(p: [f32; 3]) -> f64 {
        (f64::from(p[0]) + f64::from(p[1]) + f64::from(p[2])) / 3.0
    }

    /// Mean and variance of the mean of each pixel over independent replicate images, and
    /// the same for the image mean.
    struct Stats {
        mean: Vec<f64>,
        var_mean: Vec<f64>,
        image_mean: f64,
        image_var_mean: f64,
    }

    fn stats(images: &[Image]) -> Stats {
        let r = images.len() as f64;
        let n = images[0].rgb.len();
        let mut mean = vec![0.0; n];
        let mut var_mean = vec![0.0; n];
        for i in 0..n {
            let v: Vec<f64> = images.iter().map(|im| grey(im.rgb[i])).collect();
            let m = v.iter().sum::<f64>() / r;
            let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (r - 1.0);
            mean[i] = m;
            var_mean[i] = var / r;
        }
        let means: Vec<f64> = images
            .iter()
            .map(|im| im.rgb.iter().map(|&p| grey(p)).sum::<f64>() / n as f64)
            .collect();
        let im = means.iter().sum::<f64>() / r;
        let iv = means.iter().map(|x| (x - im) * (x - im)).sum::<f64>() / (r - 1.0) / r;
        Stats {
            mean,
            var_mean,
            image_mean: im,
            image_var_mean: iv,
        }
    }

    /// `replicates` independent renders of `spp` samples on each side; per-pixel z-scores of
    /// the difference of the means (variance of each mean estimated from its replicates) and
    /// the z-score of the image means: at most `max_exceed` pixels beyond `|z| = z_pixel`.
    /// Returns the GPU and CPU statistics.
    fn compare(
        name: &str,
        renderer: &GpuRenderer,
        grid: &'static PinGrid,
        scene: &GpuScene,
        replicates: u64,
        spp: u32,
        (z_pixel, max_exceed): (f64, usize),
    ) -> (Stats, Stats) {
        let gpu: Vec<Image> = (0..replicates)
            .map(|k| renderer.render(scene, spp, 1000 + k).unwrap())
            .collect();
        let cpu: Vec<Image> = (0..replicates)
            .map(|k| cpu_render(grid, scene, spp, 5000 + k, None).0)
            .collect();
        let (g, c) = (stats(&gpu), stats(&cpu));
        let mut exceed = 0;
        let mut max_z = 0.0f64;
        let mut constant_pixels = 0;
        for i in 0..g.mean.len() {
            let diff = g.mean[i] - c.mean[i];
            let var = g.var_mean[i] + c.var_mean[i];
            if var == 0.0 {
                // Rays that miss the medium: both sides give the same constant.
                constant_pixels += 1;
                assert!(
                    diff.abs() <= 1e-6 * c.mean[i].abs().max(1e-3),
                    "[{name}] pixel {i}: constant values differ: gpu {} cpu {}",
                    g.mean[i],
                    c.mean[i]
                );
                continue;
            }
            let z = diff / var.sqrt();
            max_z = max_z.max(z.abs());
            if z.abs() > z_pixel {
                exceed += 1;
            }
        }
        let pixel_ratio = g.var_mean.iter().sum::<f64>() / c.var_mean.iter().sum::<f64>();
        let n2 = (g.mean.len() * g.mean.len()) as f64;
        let correlation = g.image_var_mean / (g.var_mean.iter().sum::<f64>() / n2);
        let z_image = (g.image_mean - c.image_mean) / (g.image_var_mean + c.image_var_mean).sqrt();
        eprintln!(
            "[{name}] {} x {spp} spp per side: image mean gpu {:.6} +- {:.6}, cpu {:.6} +- \
             {:.6}, z = {z_image:.2}; pixels: {} ({constant_pixels} constant), |z| > \
             {z_pixel}: {exceed}, max |z| {max_z:.2}; variance ratio gpu/cpu: pixels \
             {pixel_ratio:.3}, image mean {:.2}; gpu image-mean variance / independent-pixel \
             prediction {correlation:.2}",
            replicates,
            g.image_mean,
            g.image_var_mean.sqrt(),
            c.image_mean,
            c.image_var_mean.sqrt(),
            g.mean.len(),
            g.image_var_mean / c.image_var_mean,
        );
        assert!(
            z_image.abs() < 4.0,
            "[{name}] image means differ: z = {z_image}"
        );
        // Same estimator, same per-sample variance.
        assert!(
            (0.8..1.25).contains(&pixel_ratio),
            "[{name}] per-pixel variance ratio gpu/cpu {pixel_ratio}"
        );
        // Independent pixels: the image mean's variance is the sum of the pixels' (a
        // correlated GPU random stream would inflate it).
        assert!(
            correlation < 2.0,
            "[{name}] gpu pixels look correlated: image-mean variance {correlation} x the \
             independent prediction"
        );
        assert!(
            exceed <= max_exceed,
            "[{name}] {exceed} pixels beyond |z| {z_pixel} (allowed {max_exceed})"
        );
        (g, c)
    }

    #[test]
    fn albedo_zero_matches_cpu_transmittance() {
        let ctx = context();
        let owned = blob_grid(4, Directions::Octahedral { n: 4 }, 2, 0.25);
        let grid = load(&owned);
        let renderer = GpuRenderer::new(&ctx, grid).unwrap();
        let sc = scene(32, 0.0, 0.0, 4);
        // 32 replicates x 2 spp = 64 spp per side.
        let (g, _) = compare("albedo 0", &renderer, grid, &sc, 32, 2, (4.5, 3));
        // env * E[T]: never above env, and the medium is visible.
        let env = grey(sc.env_radiance);
        let lo = g.mean.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = g.mean.iter().cloned().fold(0.0, f64::max);
        assert!(hi <= env * (1.0 + 1e-6), "{hi} > env {env}");
        assert!(lo < 0.5 * env, "medium not visible: darkest pixel {lo}");
        // Per channel the image is env * T: the channels are proportional.
        let img = renderer.render(&sc, 8, 3).unwrap();
        for p in &img.rgb {
            let t = p[0] / sc.env_radiance[0];
            assert!((0.0..=1.0 + 1e-6).contains(&t));
            assert!((p[2] - t * sc.env_radiance[2]).abs() <= 1e-5, "{p:?}");
        }
    }

    #[test]
    fn scattering_matches_cpu() {
        let ctx = context();
        let owned = blob_grid(4, Directions::Octahedral { n: 4 }, 2, 0.25);
        let grid = load(&owned);
        let renderer = GpuRenderer::new(&ctx, grid).unwrap();
        // Sun + environment, forward scattering, 4 bounces.
        let sc = scene(32, 0.9, 0.6, 4);
        let (g, _) = compare(
            "albedo 0.9, g 0.6, 4 bounces",
            &renderer,
            grid,
            &sc,
            32,
            2,
            (4.5, 10),
        );
        // The transmitted environment alone (albedo 0) is darker.
        let g0 = stats(&[
            renderer.render(&scene(32, 0.0, 0.6, 4), 16, 7).unwrap(),
            renderer.render(&scene(32, 0.0, 0.6, 4), 16, 8).unwrap(),
        ]);
        assert!(g.image_mean > g0.image_mean, "scattering must add light");
        // Sun only, backward scattering, single scattering: checks the phase convention.
        let mut sun_only = scene(32, 0.8, -0.5, 1);
        sun_only.env_radiance = [0.0; 3];
        sun_only.sun = Some(Sun {
            dir: [-0.5, 0.2, 1.0],
            radiance: [4.0, 3.0, 2.0],
        });
        compare(
            "sun only, g -0.5, 1 bounce",
            &renderer,
            grid,
            &sun_only,
            32,
            2,
            (4.5, 10),
        );
    }

    #[test]
    fn deterministic_and_checked() {
        let ctx = context();
        let owned = blob_grid(3, Directions::THESIS_DEFAULT, 1, 0.3);
        let grid = load(&owned);
        let renderer = GpuRenderer::new(&ctx, grid).unwrap();
        let sc = scene(32, 0.9, 0.3, 4);
        let a = renderer.render(&sc, 5, 42).unwrap();
        let b = renderer.render(&sc, 5, 42).unwrap();
        let bits =
            |im: &Image| -> Vec<u32> { im.rgb.iter().flat_map(|p| p.map(f32::to_bits)).collect() };
        assert_eq!(bits(&a), bits(&b), "same seed, different bits");
        let c = renderer.render(&sc, 5, 43).unwrap();
        assert_ne!(bits(&a), bits(&c), "the seed must matter");
        // Odd sizes (partial workgroups) and more passes than one submission holds.
        let mut odd = scene(13, 0.9, 0.3, 2);
        odd.camera.height = 7;
        let spp = PASSES_PER_SUBMIT + 44;
        let x = renderer.render(&odd, spp, u64::MAX).unwrap();
        let y = renderer.render(&odd, spp, u64::MAX).unwrap();
        assert_eq!((x.width, x.height, x.rgb.len()), (13, 7, 91));
        assert_eq!(bits(&x), bits(&y));
        assert!(x.rgb.iter().flatten().all(|c| c.is_finite() && *c >= 0.0));

        // Bad input is an error, never a panic.
        let bad = |f: &dyn Fn(&mut GpuScene)| {
            let mut s = scene(8, 0.5, 0.0, 2);
            f(&mut s);
            let r = renderer.render(&s, 1, 0);
            assert!(matches!(r, Err(GpuRenderError::Invalid(_))), "{r:?}");
        };
        bad(&|s| s.camera.width = 0);
        bad(&|s| s.camera.height = 0);
        bad(&|s| s.camera.origin[0] = f32::NAN);
        bad(&|s| s.camera.target = s.camera.origin);
        bad(&|s| s.camera.vfov_deg = 180.0);
        bad(&|s| s.g = 1.0);
        bad(&|s| s.g = f32::NAN);
        bad(&|s| s.albedo = 1.5);
        bad(&|s| s.env_radiance[1] = -1.0);
        bad(&|s| {
            s.sun = Some(Sun {
                dir: [0.0; 3],
                radiance: [1.0; 3],
            })
        });
        bad(&|s| s.max_bounces = MAX_GPU_BOUNCES + 1);
        assert!(matches!(
            renderer.render(&scene(8, 0.5, 0.0, 2), 0, 0),
            Err(GpuRenderError::Invalid(_))
        ));
        // No lights: black, not NaN.
        let mut dark = scene(8, 0.5, 0.0, 2);
        dark.sun = None;
        dark.env_radiance = [0.0; 3];
        let img = renderer.render(&dark, 2, 0).unwrap();
        assert!(img.rgb.iter().flatten().all(|&c| c == 0.0));
    }

    /// Timing for docs/gpu.md: `cargo test -p pinrt --features render
    /// gpu_render::tests::measure -- --ignored --nocapture`.
    #[test]
    #[ignore = "timing run for docs/gpu.md"]
    fn measure() {
        let ctx = context();
        let owned = blob_grid(16, Directions::Octahedral { n: 8 }, 1, 0.25);
        let grid = load(&owned);
        eprintln!(
            "adapter: {}; grid 16^3 x octahedral 8x8 x 1 pin = {} bytes",
            ctx.describe(),
            grid.pins_bytes().len()
        );
        let t = Instant::now();
        let renderer = GpuRenderer::new(&ctx, grid).unwrap();
        eprintln!(
            "GpuRenderer::new (upload + shader compile): {:.3} s",
            t.elapsed().as_secs_f64()
        );
        for (label, sc) in [
            ("albedo 0 (env * T)", scene(128, 0.0, 0.6, 4)),
            (
                "albedo 0.9, g 0.6, 4 bounces, sun + env",
                scene(128, 0.9, 0.6, 4),
            ),
        ] {
            renderer.render(&sc, 1, 0).unwrap(); // warm-up
            let best = |f: &dyn Fn() -> Image| {
                (0..5)
                    .map(|_| {
                        let t = Instant::now();
                        let im = f();
                        (t.elapsed().as_secs_f64(), im)
                    })
                    .min_by(|a, b| a.0.total_cmp(&b.0))
                    .unwrap()
            };
            let (tg, gi) = best(&|| renderer.render(&sc, 16, 1).unwrap());
            let (t1, c1) = best(&|| cpu_render(grid, &sc, 16, 1, Some(1)).0);
            let (t2, _) = best(&|| cpu_render(grid, &sc, 16, 1, Some(2)).0);
            let mean =
                |im: &Image| im.rgb.iter().map(|&p| grey(p)).sum::<f64>() / im.rgb.len() as f64;
            eprintln!(
                "[{label}] 128x128 x 16 spp (best of 5): gpu {tg:.3} s, cpu 1 thread {t1:.3} s, \
                 cpu 2 threads {t2:.3} s; image mean gpu {:.7} cpu {:.7}",
                mean(&gi),
                mean(&c1)
            );
        }
    }
}
