//! The reference path tracer on the GPU (feature `gpu`).
//!
//! [`GpuRenderer`] runs the estimator of [`crate::render`] (`tracer.rs`) in WGSL
//! (`shaders/render.wgsl` appended to `shaders/pin.wgsl`) over a scene's media
//! ([`GpuMedia`]: pin grids, density fields, placed instances), with the transport estimator
//! chosen per render ([`GpuEstimator`]): ray marching, delta tracking, ratio tracking (over
//! each instance's majorant grid, DDA traversal), residual ratio tracking (`residual`,
//! `residual@min`, `pinres`: over a control the CPU estimator builds, [`GpuControl`]),
//! further transmittance kernels that an extension names ([`ShaderKernel`]), pins for
//! everything, or PinMS (ratio tracking for camera rays and single scattering, pins after the
//! first scattering event).
//!
//! * pinhole camera, one uniformly jittered ray per sample inside the pixel (box filter);
//! * the camera ray scores `env * T`, then distance sampling;
//! * at each collision: throughput times albedo, sun next-event estimation
//!   `phase * T(shadow ray) * radiance`, one Henyey-Greenstein direction `w`, `env * T(w)`,
//!   and the path continues along `w`; an escape of the continuation scores nothing;
//!   `max_bounces` scattering events at most; non-finite samples are dropped;
//! * media add: nearest collision over the instances, product of their transmittances.
//!
//! One compute invocation per pixel per pass (workgroups of 8 x 8), one pass per sample; the
//! passes accumulate into a storage buffer with Kahan summation and the image is read back
//! once at the end. The GPU random streams differ from the CPU renderer's, and the GPU
//! trackers and marcher work in f32 where the CPU uses f64, so the two agree statistically
//! (same expected image), not bit for bit; `docs/gpu.md` ("GPU path tracer") states the
//! contract and the tests that check it. A GPU render is deterministic: the same media,
//! scene, estimator, spp and seed give the same image bits.
//!
//! Not supported here: time budgets (the caller loops over passes).

mod media;
mod pass_timer;
mod pipeline_cache;
mod pipelines;
mod session;
mod tone_map;
mod wgsl;

pub use media::{
    CosineWave, GpuControl, GpuDensity, GpuDensityKind, GpuMedia, GpuMedium, GpuPins,
    GpuPlacedDensity, MAX_VALUE_BINDINGS, OTHER_STORAGE_BINDINGS, check_brick_values_fit,
    value_bindings,
};
pub use pass_timer::{PassTimeSource, timestamp_seconds};
pub use pipelines::{GpuPipelines, default_cache_dir};
pub use session::GpuSession;
pub use tone_map::{GpuToneMap, TONE_MAP_WGSL};
pub use wgsl::{RENDER_WGSL, render_wgsl, render_wgsl_with, specialise};

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use wgpu::util::DeviceExt;

use crate::render::phase::G_LIMIT;
use crate::render::{Camera, EstimatorSpec, Image, RenderError, Scene, Sun};
use pinrt::Error;
use pinrt::PinGrid;
use pinrt::SamplerOptions;
use pinrt::gpu::GpuContext;

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

/// What a GPU render needs besides the media: the CPU [`Scene`] without its media plus
/// `max_bounces`.
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
    fn params(&self, seed: u64, estimator: GpuEstimator, media: u32, bvh: u32) -> RtParams {
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
                estimator.rel_step() as f32,
                0.0,
            ],
            size: [c.width, c.height, self.max_bounces, media],
            seed: [
                seed as u32,
                (seed >> 32) as u32,
                estimator.spec().and_then(media::control_slot).unwrap_or(0) as u32,
                bvh,
            ],
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

/// The transport estimator of a GPU render: one of the renderer's estimators
/// ([`EstimatorSpec`]: `rm@STEP`, `delta`, `ratio`, `residual[@min|@mean]`, `pins`, `pinms`,
/// `pinres`), or a further transmittance kernel of `render.wgsl` ([`ShaderKernel`]) that an
/// extension names. An [`EstimatorSpec`] converts into it.
///
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GpuEstimator {
    Spec(EstimatorSpec),
    Kernel(ShaderKernel),
}

/// A transmittance kernel beyond the renderer's own estimators: WGSL of an extension crate
/// that `render.wgsl` takes at its extension region ([`render_wgsl_with`]), chosen by its code
/// in the shader's estimator switch. It reads the density over the majorant box, and distances
/// are delta tracking over the majorants. The extension that names the kernel owns what its
/// code and `rel_step` mean; one code names one kernel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShaderKernel {
    /// The shader's estimator code (above the renderer's own codes).
    pub code: u32,
    /// `RP.material.z`: a step relative to the longest edge of the majorant box, in `(0, 1]`.
    pub rel_step: f64,
    /// The name in messages.
    pub name: &'static str,
    /// Its WGSL: defines `rt_kernel_transmittance(kind, m, o, d) -> f32` over the path
    /// tracer's functions (the lab's is `shaders/lab_combs.wgsl`).
    pub wgsl: &'static str,
}

impl From<EstimatorSpec> for GpuEstimator {
    fn from(spec: EstimatorSpec) -> Self {
        GpuEstimator::Spec(spec)
    }
}

/// Estimator codes of `render.wgsl`.
const EST_MARCH: u32 = 0;
const EST_DELTA: u32 = 1;
const EST_RATIO: u32 = 2;
const EST_PINS: u32 = 3;
const EST_RESIDUAL: u32 = 6;
/// The codes the renderer's own estimators take; a [`ShaderKernel`] takes another.
const OWN_CODES: [u32; 5] = [EST_MARCH, EST_DELTA, EST_RATIO, EST_PINS, EST_RESIDUAL];

impl GpuEstimator {
    /// Parses the names the CLI uses ([`EstimatorSpec`]'s `FromStr`; `None` for a bad name
    /// or parameter).
    pub fn parse(name: &str) -> Option<Self> {
        name.parse::<EstimatorSpec>().ok().map(Self::Spec)
    }

    /// The name [`GpuEstimator::parse`] reads (a kernel's own name).
    pub fn name(self) -> String {
        match self {
            Self::Spec(s) => s.to_string(),
            Self::Kernel(k) => k.name.to_string(),
        }
    }

    /// (primary, secondary) codes.
    fn kinds(self) -> (u32, u32) {
        match self {
            Self::Kernel(k) => (k.code, k.code),
            Self::Spec(s) => match s {
                EstimatorSpec::RayMarching { .. } => (EST_MARCH, EST_MARCH),
                EstimatorSpec::DeltaTracking => (EST_DELTA, EST_DELTA),
                EstimatorSpec::RatioTracking => (EST_RATIO, EST_RATIO),
                EstimatorSpec::Pins => (EST_PINS, EST_PINS),
                EstimatorSpec::PinMs => (EST_RATIO, EST_PINS),
                EstimatorSpec::ResidualRatioTracking { .. } | EstimatorSpec::PinRes => {
                    (EST_RESIDUAL, EST_RESIDUAL)
                }
            },
        }
    }

    /// `RP.material.z`: the march step, or a kernel's, relative to the longest edge.
    fn rel_step(self) -> f64 {
        match self {
            Self::Spec(EstimatorSpec::RayMarching { rel_step }) => rel_step,
            Self::Kernel(k) => k.rel_step,
            Self::Spec(_) => 0.0,
        }
    }

    /// The renderer's estimator, if it is one.
    pub fn spec(self) -> Option<EstimatorSpec> {
        match self {
            Self::Spec(s) => Some(s),
            Self::Kernel(_) => None,
        }
    }

    /// Whether this estimator queries pin grids (every medium then needs one).
    pub fn uses_pins(self) -> bool {
        self.needs().pins
    }

    /// Whether this estimator tracks over majorant grids (every medium then needs one).
    pub fn uses_majorants(self) -> bool {
        self.needs().majorants
    }

    /// What every medium must have for this estimator. `pinres` reads the bake's control
    /// section, not the pins: on the GPU it needs the control (built on the CPU from the
    /// section, [`GpuControl`]), not the pin grid.
    fn needs(self) -> media::Caps {
        let mut controls = [false; media::CONTROL_SLOTS];
        let Some(spec) = self.spec() else {
            return media::Caps {
                pins: false,
                density: true,
                majorants: true,
                controls,
            };
        };
        if let Some(slot) = media::control_slot(spec) {
            controls[slot] = true;
        }
        let plan = spec.plan();
        media::Caps {
            pins: plan.queries_pins,
            density: plan.density,
            majorants: plan.majorants,
            controls,
        }
    }

    fn validate(self) -> Result<(), RenderError> {
        let rel_step = match self {
            Self::Spec(EstimatorSpec::RayMarching { rel_step }) => rel_step,
            Self::Kernel(k) => {
                if OWN_CODES.contains(&k.code) {
                    return Err(RenderError::Invalid {
                        what: "shader kernel",
                        why: format!("{}: code {} is a built-in estimator's", k.name, k.code),
                    });
                }
                k.rel_step
            }
            Self::Spec(_) => return Ok(()),
        };
        if !(rel_step > 0.0 && rel_step <= 1.0) {
            return Err(RenderError::Invalid {
                what: "ray marching step",
                why: format!("relative step {rel_step} must be in (0, 1]"),
            });
        }
        Ok(())
    }
}

fn gpu_err(what: &str, e: impl std::fmt::Display) -> Error {
    Error::Gpu(format!("{what}: {e}"))
}

/// A scene's media on the GPU with the compiled path-tracing pipeline.
pub struct GpuRenderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    limits: wgpu::Limits,
    /// The device's pipelines, shared with the other renderers made through the same store.
    store: Arc<GpuPipelines>,
    /// This renderer's layouts and module (its number of brick-value bindings) in `store`.
    set: Arc<pipelines::LayoutSet>,
    grid_group: wgpu::BindGroup,
    grids: wgpu::Buffer,
    records: wgpu::Buffer,
    data: wgpu::Buffer,
    /// Brick values (`rt_bricks0..`), dummies where unused.
    bricks: Vec<wgpu::Buffer>,
    /// How many of `bricks` hold values.
    brick_bindings: usize,
    /// Some density is bricked (`RT_BRICKS`; it may have no stored brick at all).
    bricked: bool,
    /// Medium 0's grid parameters as a uniform (`rt_grid0`).
    grid0: wgpu::Buffer,
    caps: Vec<media::Caps>,
    /// `RtParams.seed.w`: where the media hierarchy's nodes start in the data buffer (its
    /// node count the word before); 0 scans every medium.
    bvh: u32,
    pin_bytes: u64,
    /// Bytes of each uploaded section, for a viewer's readout.
    section_bytes: Vec<(&'static str, u64)>,
}

impl std::fmt::Debug for GpuRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuRenderer")
            .field("media", &self.caps.len())
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

#[cfg(test)]
impl GpuRenderer {
    /// Whether the media are walked by a hierarchy.
    pub(crate) fn has_bvh(&self) -> bool {
        self.bvh != 0
    }

    /// The same renderer asking every medium in turn (the hierarchy's reference).
    pub(crate) fn without_bvh(mut self) -> Self {
        self.bvh = 0;
        self
    }
}

impl GpuRenderer {
    /// Uploads `grid` (placed by the file's `local_to_world`, with the default lookup,
    /// [`SamplerOptions::RENDER`]) as the only medium, for [`GpuEstimator::Pins`], and
    /// compiles the path tracer.
    pub fn new(ctx: &GpuContext, grid: &PinGrid) -> pinrt::Result<Self> {
        Self::with_options(ctx, grid, None, SamplerOptions::default())
    }

    /// One pin grid as the only medium, with an optional `local_to_world` override and lookup
    /// options (as [`pinrt::gpu::GpuPinGrid::upload_with`]).
    pub fn with_options(
        ctx: &GpuContext,
        grid: &PinGrid,
        local_to_world: Option<&[f64; 12]>,
        options: SamplerOptions,
    ) -> pinrt::Result<Self> {
        Self::with_media(ctx, &GpuMedia::pins_only(grid, local_to_world, options))
    }

    /// Uploads a scene's media (pin grids, densities, majorants, instances) and compiles the
    /// path tracer. Errors: an index out of range, a placement that is not invertible, a
    /// buffer larger than the device binds, a GPU failure.
    pub fn with_media(ctx: &GpuContext, media: &GpuMedia<'_>) -> pinrt::Result<Self> {
        Self::with_media_limited(ctx, media, pinrt::gpu::binding_limit(&ctx.limits))
    }

    /// [`GpuRenderer::with_media`] with at most `binding_limit` bytes per storage binding
    /// (the device's own limit if smaller): what a device with smaller bindings would do,
    /// e.g. split brick values over more of them, or refuse.
    pub fn with_media_limited(
        ctx: &GpuContext,
        media: &GpuMedia<'_>,
        binding_limit: u64,
    ) -> pinrt::Result<Self> {
        let limit = binding_limit.min(pinrt::gpu::binding_limit(&ctx.limits));
        let store = GpuPipelines::new(&ctx.device, &ctx.queue, &ctx.limits);
        pollster::block_on(Self::create(&store, media, limit))
    }

    /// [`GpuRenderer::with_media`] on a device the caller opened (a viewer's, which also
    /// presents to a window): `limits` are the limits the device was created with. Its
    /// pipelines are its own; [`GpuRenderer::with_media_in`] shares them.
    pub fn with_media_on(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        limits: &wgpu::Limits,
        media: &GpuMedia<'_>,
    ) -> pinrt::Result<Self> {
        Self::with_media_in(&GpuPipelines::new(device, queue, limits), media)
    }

    /// [`GpuRenderer::with_media`] on the device of `store`, taking the pipelines compiled
    /// there before (for an earlier frame, file or scene of the same layout) and adding the
    /// ones it compiles: the media are uploaded, nothing is compiled that `store` has.
    pub fn with_media_in(store: &Arc<GpuPipelines>, media: &GpuMedia<'_>) -> pinrt::Result<Self> {
        let limit = pinrt::gpu::binding_limit(&store.limits);
        pollster::block_on(Self::create(store, media, limit))
    }

    /// The pipeline store this renderer compiles into and takes its pipelines from.
    pub fn pipelines(&self) -> &Arc<GpuPipelines> {
        &self.store
    }

    /// Whether the pipeline `estimator` renders with is compiled already (a session of it
    /// starts without a compile).
    pub fn is_compiled(&self, estimator: impl Into<GpuEstimator>) -> bool {
        self.set.has(self.pipeline_key(estimator.into()))
    }

    async fn create(
        store: &Arc<GpuPipelines>,
        media: &GpuMedia<'_>,
        limit: u64,
    ) -> pinrt::Result<Self> {
        let (device, queue, limits) = (&store.device, &store.queue, &store.limits);
        // Group 0: pins and cell indices; group 1: accumulation, grid parameters, media,
        // data and the brick values.
        let available = value_bindings(limits);
        if available == 0 {
            return Err(Error::Gpu(format!(
                "the path tracer binds at least {} storage buffers in one shader stage; \
                 this device binds {}",
                OTHER_STORAGE_BINDINGS + 1,
                limits.max_storage_buffers_per_shader_stage
            )));
        }
        let packed = media::pack(media, limit, available)?;
        // As many value bindings as the bricks fill (one, unused, without bricks).
        let value_count = packed.bricks.bindings().max(1);

        let dev = device;
        let scope = dev.push_error_scope(wgpu::ErrorFilter::Validation);
        // wgpu refuses zero-sized bindings: an absent section binds a small dummy.
        let dummy = [0u8; 512];
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
        let pins = storage("render pins", &packed.pins);
        let index = storage("render cell index", &packed.index);
        let grids = storage(
            "render grid parameters",
            bytemuck::cast_slice(&packed.grid_params),
        );
        let records = storage("render media", bytemuck::cast_slice(&packed.records));
        let data = storage("render density data", bytemuck::cast_slice(&packed.data));
        // Brick values are written straight into each mapped buffer (no second copy of the
        // bricks in memory).
        let mut bricks = Vec::with_capacity(value_count);
        for k in 0..value_count {
            let b = &packed.bricks;
            let start = k as u64 * b.cap_words;
            let words = b.total_words.saturating_sub(start).min(b.cap_words);
            if words == 0 {
                bricks.push(storage("render brick values (unused)", &[]));
                continue;
            }
            let buffer = dev.create_buffer(&wgpu::BufferDescriptor {
                label: Some("render brick values"),
                size: words * 4,
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: true,
            });
            {
                let mut view = buffer
                    .slice(..)
                    .get_mapped_range_mut()
                    .map_err(|e| gpu_err("mapping the brick values", e))?;
                // Through a small staging chunk: the mapping is write-only.
                const CHUNK: u64 = 1 << 20;
                let mut chunk = vec![0u32; CHUNK.min(words) as usize];
                let mut at = 0;
                while at < words {
                    let n = CHUNK.min(words - at) as usize;
                    // Zeros between two grids' bricks (alignment).
                    chunk[..n].fill(0);
                    b.fill(start + at, &mut chunk[..n]);
                    let bytes = (at * 4) as usize..((at + n as u64) * 4) as usize;
                    view.slice(bytes)
                        .copy_from_slice(bytemuck::cast_slice(&chunk[..n]));
                    at += n as u64;
                }
            }
            buffer.unmap();
            bricks.push(buffer);
        }
        let grid0 = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("render grid 0"),
            contents: bytemuck::bytes_of(
                &packed
                    .grid_params
                    .first()
                    .copied()
                    .unwrap_or_else(media::GridParams::zeroed),
            ),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        // pin.wgsl's own uniform (binding 0) is not read by the path tracer.
        let grid_uniform = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("render grid params (unused)"),
            contents: &[0u8; size_of::<media::GridParams>()],
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let set = store.layout_set(value_count).await?;
        let grid_group = dev.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("render grid"),
            layout: &set.grid_layout,
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
        if let Some(e) = scope.pop().await {
            return Err(gpu_err("uploading the media", e));
        }
        let section_bytes = vec![
            ("pins", packed.pins.len() as u64),
            ("cell index", packed.index.len() as u64),
            ("grid parameters", grids.size()),
            ("media", records.size()),
            ("density, majorants and controls", data.size()),
            (
                "brick values",
                bricks
                    .iter()
                    .take(packed.bricks.bindings())
                    .map(|b| b.size())
                    .sum(),
            ),
        ];
        Ok(Self {
            device: device.clone(),
            queue: queue.clone(),
            limits: limits.clone(),
            store: store.clone(),
            set,
            grid_group,
            grids,
            records,
            data,
            bricks,
            brick_bindings: packed.bricks.bindings(),
            bricked: !packed.bricks.grids.is_empty(),
            grid0,
            section_bytes,
            caps: packed.caps,
            bvh: packed.bvh,
            pin_bytes: packed.pins.len() as u64,
        })
    }

    /// What `estimator`'s pipeline depends on beyond this renderer's layout.
    fn pipeline_key(&self, estimator: GpuEstimator) -> pipelines::PipelineKey {
        let (primary, secondary) = estimator.kinds();
        pipelines::PipelineKey {
            primary,
            secondary,
            one_medium: self.caps.len() == 1,
            bricked: self.bricked,
        }
    }

    /// The pipeline of an estimator pair, compiled (from the WGSL specialised to the pair,
    /// with its pipeline-overridable constants) the first time the store is asked for it. A
    /// kernel's WGSL joins the path tracer's at its extension region.
    async fn pipeline(&self, estimator: GpuEstimator) -> pinrt::Result<wgpu::ComputePipeline> {
        let kernel = match estimator {
            GpuEstimator::Kernel(k) => Some((k.name, k.wgsl)),
            GpuEstimator::Spec(_) => None,
        };
        self.store
            .pipeline(&self.set, self.pipeline_key(estimator), kernel)
            .await
    }

    /// Number of media instances.
    pub fn media_count(&self) -> usize {
        self.caps.len()
    }

    /// Number of storage bindings that hold brick values (0 without bricked densities, at
    /// most [`value_bindings`] of the device).
    pub fn brick_bindings(&self) -> usize {
        self.brick_bindings
    }

    /// Checks that every medium has what `estimator` queries.
    fn check_estimator(&self, estimator: GpuEstimator) -> Result<(), RenderError> {
        estimator.validate()?;
        let need = estimator.needs();
        for (i, c) in self.caps.iter().enumerate() {
            let control = (0..media::CONTROL_SLOTS).any(|k| need.controls[k] && !c.controls[k]);
            let missing = [
                (need.pins && !c.pins, "a pin grid"),
                (need.density && !c.density, "a density"),
                (need.majorants && !c.majorants, "a majorant grid"),
                (control, "its residual control"),
            ];
            if let Some((_, what)) = missing.iter().find(|(m, _)| *m) {
                return Err(RenderError::Invalid {
                    what: "estimator",
                    why: format!(
                        "{} needs {what} on every medium; medium {i} has none",
                        estimator.name()
                    ),
                });
            }
        }
        Ok(())
    }

    /// Bytes of each section this renderer uploaded (pins, cell index, grid parameters,
    /// media records, density data, brick values), in that order.
    pub fn section_bytes(&self) -> &[(&'static str, u64)] {
        &self.section_bytes
    }

    /// Renders `spp` samples per pixel (one pass each) with `estimator` and seed `seed`. The
    /// same inputs give the same image bits. Errors: an invalid scene (the CPU renderer's
    /// checks: zero-size image, NaN camera, `g` outside `(-1, 1)`, albedo outside `[0, 1]`,
    /// bad radiance), an estimator that needs what some medium lacks (pins, a density,
    /// majorants) or a ray-marching step outside `(0, 1]`, `spp == 0`, `max_bounces > MAX_GPU_BOUNCES`, an image too large for one dispatch or
    /// one storage buffer, or a GPU failure.
    ///
    /// It is a [`GpuSession`] with `spp` passes, read back once: a viewer that adds the same
    /// passes one at a time accumulates the same bits.
    pub fn render(
        &self,
        scene: &GpuScene,
        estimator: impl Into<GpuEstimator>,
        spp: u32,
        seed: u64,
    ) -> Result<Image, GpuRenderError> {
        let estimator = estimator.into();
        if spp == 0 {
            scene.validate()?;
            self.check_estimator(estimator)?;
            return Err(RenderError::Invalid {
                what: "budget",
                why: "0 samples per pixel".into(),
            }
            .into());
        }
        let mut session = self.session(scene, estimator, seed)?;
        session.add_passes(spp)?;
        Ok(session.image()?)
    }
}

#[cfg(test)]
mod pipeline_tests;
#[cfg(test)]
mod tests;
