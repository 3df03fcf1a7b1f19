//! The GPU bake (feature `gpu`): every pin's 32 optical depths, t_min and mask bits from a
//! wgpu compute pass (`shaders/bake.wgsl`) over a dense density grid, handed back to the
//! CPU bake's pipeline, which builds and writes the file as it does for its own pins.
//!
//! Split of the work: the CPU computes each pin's chord in f64 (its line from the counter
//! RNG, the unit-cube chord, the interval bases and index step: `pin::chord_samples`, cheap
//! next to the march) and rounds it to f32 where the CPU march rounds it; the GPU marches,
//! sums and draws the mask bits from the same RNG stream. Pins run in dispatches of a bounded
//! number of jobs (the tile budget), each writing fixed slots, so the bytes do not depend on
//! the tiling or the workgroup scheduling. docs/gpu.md states how far they are from the CPU's.
//!
//! The density goes up in z slabs within the slab budget (one slab where it fits): each slab
//! is uploaded (a slice of a dense grid, or built from a sparse source's dense lattice),
//! marched by every pin of a tile and freed, the pins' sums carried between slabs so that the
//! bytes do not depend on the slab count either (the order is bake.wgsl's).

use std::borrow::Cow;
use std::sync::{Arc, Mutex};

use glam::DVec3;
use pin_format::PinEntry;

use std::time::Instant;

use rayon::prelude::*;

use crate::error::BakeError;
use crate::gpu_options::{GpuBakeOptions, GpuBakeTimes};
use crate::pin::{PinLayout, Placement, chord_samples};
use pin_volume::{DenseGrid, DenseLattice, DensitySource};

/// The bake shader.
pub const BAKE_WGSL: &str = include_str!("../../shaders/bake.wgsl");

/// Density bindings the shader declares.
const DENSITY_BINDINGS: usize = 6;
/// Storage bindings the shader declares: jobs, entries, the density's and the carried sums.
const STORAGE_BINDINGS: usize = DENSITY_BINDINGS + 3;
const WORKGROUP: u32 = 64;
/// Pins of the first tile of a bake that can be cancelled: small enough to finish in a
/// fraction of a second on a CPU Vulkan driver at 1e4 steps per pin.
const FIRST_CANCELLABLE_TILE: usize = 1024;
/// Seconds one dispatch of a cancellable bake aims at: a cancel (Python's Ctrl-C) is seen
/// within about this long after the dispatch in flight.
const CANCELLABLE_DISPATCH_S: f64 = 0.2;

/// bake.wgsl's `Params.slab.w` flags.
const CARRIED: u32 = 1;
const ONGOING: u32 = 2;
const WHOLE: u32 = 4;

/// One pin's chord as the shader reads it (`PinJob` in bake.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct PinJob {
    base: [f32; 3],
    /// Samples per interval; 0 for a pin whose chord misses the box (the empty pin).
    steps: u32,
    istep: [f32; 3],
    weight: f32,
    du: [f32; 3],
    counter: u32,
    key: [u32; 2],
    pad: [u32; 2],
}

const JOB_BYTES: u64 = size_of::<PinJob>() as u64;
/// GPU bytes per pin of a dispatch: its job, its entry and the entry's read-back copy.
const PIN_BYTES: u64 = JOB_BYTES + 2 * size_of::<PinEntry>() as u64;
/// GPU bytes per pin carried between slabs: 32 intervals' sum and compensation.
const SUMS_BYTES: u64 = 32 * 8;

#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    dims: [u32; 4],
    stride: [u32; 4],
    step: [u32; 4],
    top: [f32; 4],
    hi: [f32; 4],
    slab: [u32; 4],
}

fn gpu(what: &str, e: impl std::fmt::Display) -> BakeError {
    BakeError::Gpu(format!("{what}: {e}"))
}

/// The density the GPU bake marches.
pub(crate) enum GpuDensity<'a> {
    /// A dense grid in memory (the source's own or its dense copy): slabs are slices of it.
    Grid(&'a DenseGrid),
    /// A sparse source's dense lattice ([`DensitySource::dense_lattice`]), each slab built
    /// from the source ([`DensitySource::dense_planes`]) in at most `host_bytes`.
    Planes {
        source: &'a dyn DensitySource,
        lattice: DenseLattice,
        host_bytes: u64,
    },
}

impl GpuDensity<'_> {
    fn lattice(&self) -> DenseLattice {
        match self {
            GpuDensity::Grid(g) => g.lattice(),
            GpuDensity::Planes { lattice, .. } => *lattice,
        }
    }

    /// The values of planes `[z0, z1)`.
    fn planes(&self, z0: u32, z1: u32) -> Result<Cow<'_, [f32]>, BakeError> {
        match self {
            GpuDensity::Grid(g) => {
                let [nx, ny, _] = g.dims();
                let plane = nx as usize * ny as usize;
                Ok(Cow::Borrowed(
                    &g.data()[z0 as usize * plane..z1 as usize * plane],
                ))
            }
            GpuDensity::Planes { source, .. } => {
                source.dense_planes(z0, z1).map(Cow::Owned).ok_or_else(|| {
                    BakeError::Gpu(format!(
                        "{}: could not build density planes {z0}..{z1} (out of memory?)",
                        source.describe()
                    ))
                })
            }
        }
    }
}

/// The slabs of a lattice `nz` planes deep: each the lower-corner z range `[lo, hi)` its
/// dispatch sums, holding planes `[lo, hi + 1)` (the halo trilinear reads; 1 plane where
/// `nz` is 1). `per` lower-corner planes each.
fn slab_ranges(nz: u32, per: u32) -> Vec<(u32, u32)> {
    let lowers = nz.saturating_sub(1).max(1);
    let per = per.max(1);
    (0..lowers.div_ceil(per))
        .map(|s| (s * per, (s * per + per).min(lowers)))
        .collect()
}

/// The planes slab `(lo, hi)` holds in a lattice `nz` planes deep.
fn slab_planes(nz: u32, (lo, hi): (u32, u32)) -> (u32, u32) {
    (lo, (hi + 1).min(nz))
}

/// An open device with the bake pipeline compiled.
pub struct GpuBaker {
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipeline: wgpu::ComputePipeline,
    limits: wgpu::Limits,
    adapter: String,
    /// The first error outside an error scope, or the device's loss, as it was reported.
    failure: Arc<Mutex<Option<String>>>,
}

/// A tile's buffers, kept across its slabs.
struct TileBuffers {
    jobs: wgpu::Buffer,
    entries: wgpu::Buffer,
    staging: wgpu::Buffer,
    sums: wgpu::Buffer,
    n: u32,
}

impl GpuBaker {
    /// Finds an adapter (a GPU, else a software fallback such as Mesa's lavapipe), opens a
    /// device with the adapter's limits and compiles the shader.
    pub fn new() -> Result<Self, BakeError> {
        pollster::block_on(Self::new_async())
    }

    async fn new_async() -> Result<Self, BakeError> {
        // Vulkan, Metal and DX12, not OpenGL: the compute paths need no GL fallback, and
        // loading libEGL for one crashed about one process in 30 at exit (its destructor
        // frees while a driver thread exits). `WGPU_BACKEND` still chooses.
        let instance = wgpu::Instance::new(
            wgpu::InstanceDescriptor {
                backends: wgpu::Backends::PRIMARY,
                ..wgpu::InstanceDescriptor::new_without_display_handle()
            }
            .with_env(),
        );
        let mut options = wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            apply_limit_buckets: false,
        };
        let adapter = match instance.request_adapter(&options).await {
            Ok(a) => a,
            Err(first) => {
                options.force_fallback_adapter = true;
                instance.request_adapter(&options).await.map_err(|e| {
                    BakeError::Gpu(format!(
                        "no GPU adapter found ({first}; software fallback: {e}); install a \
                         Vulkan driver (without a GPU, Mesa's lavapipe: mesa-vulkan-drivers)"
                    ))
                })?
            }
        };
        let info = adapter.get_info();
        let limits = adapter.limits();
        if (limits.max_storage_buffers_per_shader_stage as usize) < STORAGE_BINDINGS {
            return Err(BakeError::Gpu(format!(
                "the device binds {} storage buffers per stage, the bake needs \
                 {STORAGE_BINDINGS}",
                limits.max_storage_buffers_per_shader_stage,
            )));
        }
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("pinbake"),
                required_features: wgpu::Features::empty(),
                required_limits: limits.clone(),
                ..Default::default()
            })
            .await
            .map_err(|e| gpu("request_device", e))?;
        // wgpu's default for an error outside a scope, or a lost device, is a panic or
        // nothing: both are recorded and end the bake with one line instead.
        let failure = Arc::new(Mutex::new(None));
        let f = failure.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            record(&f, format!("GPU error: {e}"));
        }));
        let f = failure.clone();
        device.set_device_lost_callback(move |reason, message| {
            let why = if message.trim().is_empty() {
                String::new()
            } else {
                format!(": {message}")
            };
            record(&f, format!("the GPU device was lost ({reason:?}){why}"));
        });
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("bake.wgsl"),
            source: wgpu::ShaderSource::Wgsl(BAKE_WGSL.into()),
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("bake"),
            layout: None,
            module: &module,
            entry_point: Some("bake"),
            compilation_options: Default::default(),
            cache: None,
        });
        if let Some(e) = scope.pop().await {
            return Err(gpu("compiling shaders/bake.wgsl", e));
        }
        Ok(Self {
            device,
            queue,
            pipeline,
            limits,
            adapter: format!("{} ({:?})", info.name, info.backend),
            failure,
        })
    }

    /// The adapter's name and backend.
    pub fn describe(&self) -> &str {
        &self.adapter
    }

    /// The error recorded outside a scope or the device's loss, if any.
    fn check_failure(&self) -> Result<(), BakeError> {
        match self.failure.lock().map(|f| f.clone()) {
            Ok(None) => Ok(()),
            Ok(Some(m)) => Err(BakeError::Gpu(m)),
            Err(_) => Err(BakeError::Gpu("a GPU error handler panicked".into())),
        }
    }

    /// The most bytes one storage binding may hold on this device.
    fn binding_limit(&self) -> u64 {
        self.limits
            .max_storage_buffer_binding_size
            .min(self.limits.max_buffer_size)
    }

    /// Voxels per density binding.
    fn per_binding(&self) -> u64 {
        (self.binding_limit() / 4).min(u64::from(u32::MAX))
    }

    /// Pins per dispatch under `opts`' budget and the device's limits, with or without the
    /// sums carried between slabs.
    pub(crate) fn pins_per_dispatch(&self, opts: &GpuBakeOptions, slabbed: bool) -> u64 {
        let (pin, widest) = if slabbed {
            (PIN_BYTES + SUMS_BYTES, SUMS_BYTES)
        } else {
            (PIN_BYTES, JOB_BYTES)
        };
        let budget = opts.tile_bytes.unwrap_or(u64::MAX) / pin;
        let binding = self.binding_limit() / widest;
        let groups = u64::from(self.limits.max_compute_workgroups_per_dimension.max(1));
        let threads = groups * groups * u64::from(WORKGROUP);
        budget.min(binding).min(threads).min(u64::from(u32::MAX))
    }

    /// The slabs `density` goes up in under `opts`' slab budget, the device's six density
    /// bindings, u32 indices and (built from a source) the host budget; the one-line refusal
    /// naming the sizes where one slab of two planes does not fit.
    fn slabs(
        &self,
        density: &GpuDensity<'_>,
        opts: &GpuBakeOptions,
    ) -> Result<Vec<(u32, u32)>, BakeError> {
        let [nx, ny, nz] = density.lattice().dims;
        let plane = u64::from(nx) * u64::from(ny);
        let device = self.per_binding() * DENSITY_BINDINGS as u64 * 4;
        let mut caps = vec![(device, "what this device binds for it (6 storage buffers)")];
        if let Some(b) = opts.slab_bytes {
            caps.push((b, "the GPU slab budget (--gpu-slab-bytes)"));
        }
        if let GpuDensity::Planes { host_bytes, .. } = density {
            caps.push((
                *host_bytes,
                "the memory budget for a dense copy (what --max-memory leaves)",
            ));
        }
        caps.push((u64::from(u32::MAX) * 4, "u32 indices"));
        let (cap, what) = caps.into_iter().min_by_key(|c| c.0).unwrap_or((0, ""));
        let fit = cap / 4 / plane.max(1);
        let least = u64::from(nz.min(2));
        if fit < least {
            return Err(BakeError::Gpu(format!(
                "one slab of the density grid {:?} ({least} planes of {nx}x{ny} f32, {} bytes) \
                 exceeds {what}: {cap} bytes",
                [nx, ny, nz],
                least * plane * 4
            )));
        }
        let per = if fit >= u64::from(nz) {
            nz
        } else {
            (fit - 1) as u32
        };
        Ok(slab_ranges(nz, per))
    }

    /// A buffer holding `data` (a multiple of 4 bytes). Written through the queue rather than
    /// mapped at creation: on a lost device wgpu panics reading a mapping back, while a write
    /// is an error the scopes catch.
    fn buffer_with(&self, label: &str, data: &[u8], usage: wgpu::BufferUsages) -> wgpu::Buffer {
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: (data.len() as u64).max(4),
            usage: usage | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        self.queue.write_buffer(&buffer, 0, data);
        buffer
    }

    /// One slab's planes in [`DENSITY_BINDINGS`] buffers of `chunk` voxels each.
    fn upload_slab(&self, data: &[f32], chunk: usize) -> Vec<wgpu::Buffer> {
        (0..DENSITY_BINDINGS)
            .map(|b| {
                let part = data.chunks(chunk).nth(b).unwrap_or(&[0.0]);
                self.buffer_with(
                    "density",
                    bytemuck::cast_slice(part),
                    wgpu::BufferUsages::STORAGE,
                )
            })
            .collect()
    }

    /// The planes of `slab` built (or sliced) and uploaded, inside error scopes.
    fn slab_buffers(
        &self,
        density: &GpuDensity<'_>,
        nz: u32,
        slab: (u32, u32),
        chunk: usize,
        times: &mut GpuBakeTimes,
    ) -> Result<Vec<wgpu::Buffer>, BakeError> {
        let uploading = Instant::now();
        let (z0, z1) = slab_planes(nz, slab);
        let data = density.planes(z0, z1)?;
        let buffers = self.scoped("uploading the density", || self.upload_slab(&data, chunk))?;
        times.upload_s += uploading.elapsed().as_secs_f64();
        Ok(buffers)
    }

    /// `f` inside out-of-memory and validation scopes: its errors, any recorded outside a
    /// scope and a lost device are one line.
    fn scoped<T>(&self, what: &str, f: impl FnOnce() -> T) -> Result<T, BakeError> {
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let out = f();
        let (v, o) = pollster::block_on(async { (scope.pop().await, oom.pop().await) });
        if v.is_some() || o.is_some() {
            // A lost device first: the errors after it are its consequences, and wgpu tells
            // of the loss when it is polled.
            let _ = self.device.poll(wgpu::PollType::Poll);
        }
        self.check_failure()?;
        if let Some(e) = v {
            return Err(gpu(what, e));
        }
        if let Some(e) = o {
            return Err(gpu(&format!("{what}: out of GPU memory"), e));
        }
        Ok(out)
    }

    /// The entries of the pins in `dense`, in the CPU bake's slot order: `block_len` slots per
    /// covered cell, cells in x-fastest order from layer `z_begin`, slot `dir * ppe + k`.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn bake_entries(
        &self,
        density: &GpuDensity<'_>,
        placement: &Placement,
        layout: &PinLayout,
        z_begin: u32,
        block_len: usize,
        dense: &mut [PinEntry],
        opts: &GpuBakeOptions,
        progress: &(dyn Fn(u64) + Sync),
        (cancellable, cancelled): (bool, &(dyn Fn() -> bool + Sync)),
        times: &mut GpuBakeTimes,
    ) -> Result<(), BakeError> {
        let lattice = density.lattice();
        let [nx, ny, nz] = lattice.dims;
        let slabs = self.slabs(density, opts)?;
        times.slabs = slabs.len() as u64;
        let slabbed = slabs.len() > 1;
        // Fits: the slab check bounds a slab, two planes at least, by u32 indices.
        let stride_y = nx;
        let stride_z = nx * ny;
        let per = self.pins_per_dispatch(opts, slabbed) as usize;
        if per == 0 {
            return Err(BakeError::Gpu(format!(
                "a GPU tile budget of {} bytes holds no pin ({} bytes each)",
                opts.tile_bytes.unwrap_or(0),
                if slabbed {
                    PIN_BYTES + SUMS_BYTES
                } else {
                    PIN_BYTES
                }
            )));
        }
        let chunk = self.per_binding() as usize;
        let params = Params {
            dims: [nx, ny, nz, chunk as u32],
            stride: [stride_y, stride_z, 0, 0],
            step: [
                u32::from(nx > 1),
                if ny > 1 { stride_y } else { 0 },
                if nz > 1 { stride_z } else { 0 },
                0,
            ],
            top: [nx, ny, nz, 1].map(|d| d.saturating_sub(1) as f32),
            hi: [nx, ny, nz, 2].map(|d| d.saturating_sub(2) as f32),
            slab: [0; 4],
        };
        // One slab stays on the device for every tile of pins; several go up per tile.
        let whole = if slabbed {
            None
        } else {
            Some(self.slab_buffers(density, nz, slabs[0], chunk, times)?)
        };
        let nx_cells = layout.dims[0] as usize;
        let ppe = layout.pins_per_entry;
        let mut jobs = Vec::with_capacity(per.min(dense.len()));
        // A dispatch cannot be stopped once submitted, so a bake that can be cancelled
        // (`cancellable`: a host such as Python polls for Ctrl-C) runs tiles that take about
        // `CANCELLABLE_DISPATCH_S` each: the first small, the next sized from the time per
        // pin measured so far. Each pin's job depends on its slot alone, so the tiles'
        // sizes do not change the bytes.
        let mut tile_pins = if cancellable {
            per.min(FIRST_CANCELLABLE_TILE)
        } else {
            per
        };
        let mut first = 0usize;
        while first < dense.len() {
            if cancelled() {
                return Err(BakeError::Cancelled);
            }
            let n = tile_pins.min(dense.len() - first);
            let out = &mut dense[first..first + n];
            let tile_started = Instant::now();
            jobs.clear();
            let preparing = Instant::now();
            // Each job depends on its slot alone, so the order (and the bytes) is the same on
            // any number of threads.
            jobs.par_extend((first..first + out.len()).into_par_iter().map(|n| {
                let (cell_i, slot) = (n / block_len, (n % block_len) as u32);
                let (dir, k) = (slot / ppe, slot % ppe);
                let x = (cell_i % nx_cells) as u32;
                let row = cell_i / nx_cells;
                let y = (row % layout.dims[1] as usize) as u32;
                let z = (row / layout.dims[1] as usize) as u32 + z_begin;
                job(&lattice, placement, layout, [x, y, z], dir, k)
            }));
            times.jobs_s += preparing.elapsed().as_secs_f64();
            let dispatching = Instant::now();
            let tile = self.scoped("the pins' buffers", || self.tile_buffers(&jobs, slabbed))?;
            times.dispatch_s += dispatching.elapsed().as_secs_f64();
            for (s, &slab) in slabs.iter().enumerate() {
                if cancelled() {
                    return Err(BakeError::Cancelled);
                }
                let uploaded;
                let buffers = match &whole {
                    Some(w) => w,
                    None => {
                        uploaded = self.slab_buffers(density, nz, slab, chunk, times)?;
                        &uploaded
                    }
                };
                let dispatching = Instant::now();
                let last = s + 1 == slabs.len();
                let mut p = params;
                let flags = if s > 0 { CARRIED } else { 0 }
                    | if last { 0 } else { ONGOING }
                    | if slabbed { 0 } else { WHOLE };
                p.slab = [slab.0, slab.1, 0, flags];
                self.dispatch(&p, &tile, buffers, last)?;
                times.dispatch_s += dispatching.elapsed().as_secs_f64();
                times.dispatches += 1;
                if whole.is_none() {
                    for b in buffers {
                        b.destroy();
                    }
                }
                if opts.lose_device_after == Some(times.dispatches) {
                    self.device.destroy();
                }
            }
            let dispatching = Instant::now();
            out.copy_from_slice(&self.read_back(&tile)?);
            times.dispatch_s += dispatching.elapsed().as_secs_f64();
            progress(out.len() as u64);
            first += n;
            if cancellable {
                let took = tile_started.elapsed().as_secs_f64().max(1e-6);
                let next = (n as f64 * CANCELLABLE_DISPATCH_S / took).clamp(1.0, 4.0 * n as f64);
                tile_pins = (next as usize).clamp(1, per);
            }
        }
        Ok(())
    }

    /// A tile's jobs uploaded, its entries, their read-back copy and (with several slabs)
    /// its carried sums.
    fn tile_buffers(&self, jobs: &[PinJob], slabbed: bool) -> TileBuffers {
        let dev = &self.device;
        let n = jobs.len() as u32;
        let size = u64::from(n) * size_of::<PinEntry>() as u64;
        let storage = |label, size, usage| {
            dev.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        TileBuffers {
            jobs: self.buffer_with(
                "pin jobs",
                bytemuck::cast_slice(jobs),
                wgpu::BufferUsages::STORAGE,
            ),
            entries: storage(
                "pin entries",
                size,
                wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            ),
            staging: storage(
                "pin entries read-back",
                size,
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            ),
            sums: storage(
                "carried sums",
                if slabbed {
                    u64::from(n) * SUMS_BYTES
                } else {
                    8
                },
                wgpu::BufferUsages::STORAGE,
            ),
            n,
        }
    }

    /// One dispatch of a tile over one slab, waited for; the last copies the entries out.
    fn dispatch(
        &self,
        params: &Params,
        tile: &TileBuffers,
        density: &[wgpu::Buffer],
        last: bool,
    ) -> Result<(), BakeError> {
        let dev = &self.device;
        let n = tile.n;
        let groups = n.div_ceil(WORKGROUP);
        let gx = groups.clamp(1, self.limits.max_compute_workgroups_per_dimension.max(1));
        let gy = groups.div_ceil(gx).max(1);
        let mut p = *params;
        p.stride[2] = n;
        p.stride[3] = gx * WORKGROUP;
        self.scoped("dispatch", || {
            let uniform = self.buffer_with(
                "bake params",
                bytemuck::bytes_of(&p),
                wgpu::BufferUsages::UNIFORM,
            );
            let mut entries_list = vec![
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: uniform.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: tile.jobs.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: tile.entries.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 9,
                    resource: tile.sums.as_entire_binding(),
                },
            ];
            for (i, d) in density.iter().enumerate() {
                entries_list.push(wgpu::BindGroupEntry {
                    binding: 3 + i as u32,
                    resource: d.as_entire_binding(),
                });
            }
            let bind = dev.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("bake"),
                layout: &self.pipeline.get_bind_group_layout(0),
                entries: &entries_list,
            });
            let mut enc = dev.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("bake"),
            });
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("bake"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &bind, &[]);
                pass.dispatch_workgroups(gx, gy, 1);
            }
            if last {
                enc.copy_buffer_to_buffer(&tile.entries, 0, &tile.staging, 0, tile.staging.size());
            }
            self.queue.submit([enc.finish()]);
        })?;
        // Waited for, so that a slab's buffers are free before the next one goes up.
        dev.poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| gpu("device lost or stalled", e))?;
        self.check_failure()
    }

    /// The entries of a tile whose last slab has run.
    fn read_back(&self, tile: &TileBuffers) -> Result<Vec<PinEntry>, BakeError> {
        let (tx, rx) = std::sync::mpsc::channel();
        self.scoped("read-back", || {
            tile.staging
                .slice(..)
                .map_async(wgpu::MapMode::Read, move |r| {
                    let _ = tx.send(r);
                })
        })?;
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| gpu("device lost or stalled", e))?;
        self.check_failure()?;
        rx.recv()
            .map_err(|e| gpu("read-back", e))?
            .map_err(|e| gpu("read-back", e))?;
        let view = tile
            .staging
            .slice(..)
            .get_mapped_range()
            .map_err(|e| gpu("read-back", e))?;
        let out = bytemuck::pod_collect_to_vec::<u8, PinEntry>(&view);
        drop(view);
        tile.staging.unmap();
        Ok(out)
    }
}

/// Keeps the first failure: later ones are its consequences.
fn record(failure: &Mutex<Option<String>>, message: String) {
    if let Ok(mut f) = failure.lock() {
        f.get_or_insert(pin_volume::one_line(&message));
    }
}

/// Pin `(cell, dir, k)`'s job: the chord and RNG state the CPU march would use, rounded to
/// f32 where it rounds them (`pin::field_optical_depths`' whole-pin grid path).
pub(crate) fn job(
    grid: &DenseLattice,
    placement: &Placement,
    layout: &PinLayout,
    cell: [u32; 3],
    dir: u32,
    k: u32,
) -> PinJob {
    let mut rng = layout.rng(layout.cell_linear(cell), dir, k);
    let (p, w) = layout.line(cell, dir, &mut rng);
    let (key, counter) = rng.state();
    let f32x3 = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32];
    let mut job = PinJob {
        base: [0.0; 3],
        steps: 0,
        istep: [0.0; 3],
        weight: 0.0,
        du: [0.0; 3],
        counter: counter as u32,
        key: [key as u32, (key >> 32) as u32],
        pad: [0; 2],
    };
    if let Some(cs) = chord_samples(placement, p, w) {
        let (ua, ub) = (grid.index_of(cs.origin), grid.index_dir(cs.world_dir));
        let du = ub * cs.h;
        job.base = f32x3(ua + ub * cs.s0 + du * 0.5);
        job.istep = f32x3(ub * cs.ds);
        job.du = f32x3(du);
        job.steps = cs.steps as u32;
        job.weight = cs.weight as f32;
    }
    job
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_job_layout_is_the_shaders() {
        // PinJob in bake.wgsl: vec3 + u32, vec3 + f32, vec3 + u32, vec2 key, vec2 pad.
        assert_eq!(JOB_BYTES, 64);
        assert_eq!(size_of::<Params>(), 96);
    }

    #[test]
    fn slabs_cover_every_lower_corner_once() {
        for nz in [1, 2, 3, 7, 33, 128] {
            for per in [1, 2, 5, 200] {
                let s = slab_ranges(nz, per);
                let lowers = nz.saturating_sub(1).max(1);
                assert_eq!(s.first().map(|r| r.0), Some(0));
                assert_eq!(s.last().map(|r| r.1), Some(lowers));
                assert!(s.windows(2).all(|w| w[0].1 == w[1].0));
                for &r in &s {
                    let (a, b) = slab_planes(nz, r);
                    assert!(b <= nz && a < b && b - a <= per + 1, "{nz} {per} {r:?}");
                }
            }
        }
    }
}
