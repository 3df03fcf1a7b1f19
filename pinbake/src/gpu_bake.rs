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

use glam::DVec3;
use pin_format::PinEntry;
use wgpu::util::DeviceExt;

use std::time::Instant;

use rayon::prelude::*;

use crate::bake::{GpuBakeOptions, GpuBakeTimes};
use crate::error::BakeError;
use crate::pin::{PinLayout, Placement, chord_samples};
use crate::source::DenseGrid;

/// The bake shader.
pub const BAKE_WGSL: &str = include_str!("../../shaders/bake.wgsl");

/// Density bindings the shader declares.
const DENSITY_BINDINGS: usize = 6;
const WORKGROUP: u32 = 64;

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

#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    dims: [u32; 4],
    stride: [u32; 4],
    step: [u32; 4],
    top: [f32; 4],
    hi: [f32; 4],
}

fn gpu(what: &str, e: impl std::fmt::Display) -> BakeError {
    BakeError::Gpu(format!("{what}: {e}"))
}

/// An open device with the bake pipeline compiled.
pub struct GpuBaker {
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipeline: wgpu::ComputePipeline,
    limits: wgpu::Limits,
    adapter: String,
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
        if (limits.max_storage_buffers_per_shader_stage as usize) < DENSITY_BINDINGS + 2 {
            return Err(BakeError::Gpu(format!(
                "the device binds {} storage buffers per stage, the bake needs {}",
                limits.max_storage_buffers_per_shader_stage,
                DENSITY_BINDINGS + 2
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
        })
    }

    /// The adapter's name and backend.
    pub fn describe(&self) -> &str {
        &self.adapter
    }

    /// The most bytes one storage binding may hold on this device.
    fn binding_limit(&self) -> u64 {
        self.limits
            .max_storage_buffer_binding_size
            .min(self.limits.max_buffer_size)
    }

    /// Pins per dispatch under `opts`' budget and the device's limits.
    pub(crate) fn pins_per_dispatch(&self, opts: &GpuBakeOptions) -> u64 {
        let budget = opts.tile_bytes.unwrap_or(u64::MAX) / PIN_BYTES;
        let binding = self.binding_limit() / JOB_BYTES;
        let groups = u64::from(self.limits.max_compute_workgroups_per_dimension.max(1));
        let threads = groups * groups * u64::from(WORKGROUP);
        budget.min(binding).min(threads).min(u64::from(u32::MAX))
    }

    /// The density in [`DENSITY_BINDINGS`] buffers, or the one-line refusal naming the sizes.
    fn upload_density(&self, grid: &DenseGrid) -> Result<(Vec<wgpu::Buffer>, u32), BakeError> {
        let data = grid.data();
        let per_binding = (self.binding_limit() / 4).min(u64::from(u32::MAX));
        let bytes = size_of_val(data) as u64;
        if data.len() as u64 > per_binding * DENSITY_BINDINGS as u64 || per_binding == 0 {
            return Err(BakeError::Gpu(format!(
                "the density grid {:?} is {bytes} bytes, more than this device binds for it \
                 ({DENSITY_BINDINGS} storage buffers of {} bytes)",
                grid.dims(),
                per_binding * 4
            )));
        }
        let chunk = per_binding as usize;
        let mut buffers = Vec::with_capacity(DENSITY_BINDINGS);
        for b in 0..DENSITY_BINDINGS {
            let part = data.chunks(chunk).nth(b).unwrap_or(&[0.0]);
            buffers.push(
                self.device
                    .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                        label: Some("density"),
                        contents: bytemuck::cast_slice(part),
                        usage: wgpu::BufferUsages::STORAGE,
                    }),
            );
        }
        Ok((buffers, chunk as u32))
    }

    /// The entries of the pins in `dense`, in the CPU bake's slot order: `block_len` slots per
    /// covered cell, cells in x-fastest order from layer `z_begin`, slot `dir * ppe + k`.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn bake_entries(
        &self,
        grid: &DenseGrid,
        placement: &Placement,
        layout: &PinLayout,
        z_begin: u32,
        block_len: usize,
        dense: &mut [PinEntry],
        opts: &GpuBakeOptions,
        progress: &(dyn Fn(u64) + Sync),
        cancelled: &(dyn Fn() -> bool + Sync),
        times: &mut GpuBakeTimes,
    ) -> Result<(), BakeError> {
        let uploading = Instant::now();
        let (density, chunk) = self.upload_density(grid)?;
        times.upload_s += uploading.elapsed().as_secs_f64();
        let [nx, ny, nz] = grid.dims();
        let stride_y = nx;
        let stride_z = nx.checked_mul(ny).ok_or_else(|| {
            BakeError::Gpu(format!(
                "the density grid {:?} exceeds u32 indices",
                grid.dims()
            ))
        })?;
        if u64::from(stride_z) * u64::from(nz) > u64::from(u32::MAX) {
            return Err(BakeError::Gpu(format!(
                "the density grid {:?} has more voxels than u32 indices reach",
                grid.dims()
            )));
        }
        let per = self.pins_per_dispatch(opts) as usize;
        if per == 0 {
            return Err(BakeError::Gpu(format!(
                "a GPU tile budget of {} bytes holds no pin ({PIN_BYTES} bytes each)",
                opts.tile_bytes.unwrap_or(0)
            )));
        }
        let params = Params {
            dims: [nx, ny, nz, chunk],
            stride: [stride_y, stride_z, 0, 0],
            step: [
                u32::from(nx > 1),
                if ny > 1 { stride_y } else { 0 },
                if nz > 1 { stride_z } else { 0 },
                0,
            ],
            top: [nx, ny, nz, 1].map(|d| d.saturating_sub(1) as f32),
            hi: [nx, ny, nz, 2].map(|d| d.saturating_sub(2) as f32),
        };
        let nx_cells = layout.dims[0] as usize;
        let ppe = layout.pins_per_entry;
        let mut jobs = Vec::with_capacity(per.min(dense.len()));
        for (t, out) in dense.chunks_mut(per).enumerate() {
            if cancelled() {
                return Err(BakeError::Cancelled);
            }
            jobs.clear();
            let first = t * per;
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
                job(grid, placement, layout, [x, y, z], dir, k)
            }));
            times.jobs_s += preparing.elapsed().as_secs_f64();
            let dispatching = Instant::now();
            let got = pollster::block_on(self.dispatch(&params, &density, &jobs))?;
            times.dispatch_s += dispatching.elapsed().as_secs_f64();
            times.dispatches += 1;
            out.copy_from_slice(&got);
            progress(out.len() as u64);
        }
        Ok(())
    }

    async fn dispatch(
        &self,
        params: &Params,
        density: &[wgpu::Buffer],
        jobs: &[PinJob],
    ) -> Result<Vec<PinEntry>, BakeError> {
        let dev = &self.device;
        let n = jobs.len() as u32;
        let groups = n.div_ceil(WORKGROUP);
        let gx = groups.clamp(1, self.limits.max_compute_workgroups_per_dimension.max(1));
        let gy = groups.div_ceil(gx).max(1);
        let mut p = *params;
        p.stride[2] = n;
        p.stride[3] = gx * WORKGROUP;
        let oom = dev.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let scope = dev.push_error_scope(wgpu::ErrorFilter::Validation);
        let uniform = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bake params"),
            contents: bytemuck::bytes_of(&p),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let job_buf = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("pin jobs"),
            contents: bytemuck::cast_slice(jobs),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let size = u64::from(n) * size_of::<PinEntry>() as u64;
        let entries = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("pin entries"),
            size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let staging = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("pin entries read-back"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut entries_list = vec![
            wgpu::BindGroupEntry {
                binding: 0,
                resource: uniform.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: job_buf.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: entries.as_entire_binding(),
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
        enc.copy_buffer_to_buffer(&entries, 0, &staging, 0, size);
        self.queue.submit([enc.finish()]);
        let (tx, rx) = std::sync::mpsc::channel();
        staging.slice(..).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        dev.poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| gpu("device lost or stalled", e))?;
        if let Some(e) = scope.pop().await {
            return Err(gpu("dispatch", e));
        }
        if let Some(e) = oom.pop().await {
            return Err(gpu("out of GPU memory", e));
        }
        rx.recv()
            .map_err(|e| gpu("read-back", e))?
            .map_err(|e| gpu("read-back", e))?;
        let view = staging
            .slice(..)
            .get_mapped_range()
            .map_err(|e| gpu("read-back", e))?;
        let out = bytemuck::pod_collect_to_vec::<u8, PinEntry>(&view);
        drop(view);
        staging.unmap();
        Ok(out)
    }
}

/// Pin `(cell, dir, k)`'s job: the chord and RNG state the CPU march would use, rounded to
/// f32 where it rounds them (`pin::field_optical_depths`' whole-pin grid path).
pub(crate) fn job(
    grid: &DenseGrid,
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
        assert_eq!(size_of::<Params>(), 80);
    }
}
