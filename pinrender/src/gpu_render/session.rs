//! A progressive render on the GPU: the accumulation stays on the device, passes are added
//! as time allows, the image is shown through [`super::GpuToneMap`] without a read-back, and
//! read back only when asked ([`GpuSession::image`]).
//!
//! [`GpuRenderer::render`] is a session with `spp` passes read back once, so a viewer that
//! adds `N` passes with seed `S`, however it slices them, holds the same bits as
//! `pinrender render --backend gpu --spp N --seed S`: pass `k` of pixel `p` draws from the
//! generator seeded by `(S, p, k)` and adds into `p`'s Kahan sum, one pass after another, in
//! every slicing.

use std::time::{Duration, Instant};

use wgpu::util::DeviceExt;

use super::pass_timer::{PassTimeSource, PassTimer};
use super::{
    GpuEstimator, GpuRenderError, GpuRenderer, GpuScene, PASSES_PER_SUBMIT, RtParams, WORKGROUP,
    gpu_err,
};
use crate::render::Image;
use pinrt::Error;

/// A progressive render of one scene with one estimator and seed: an accumulation buffer on
/// the device and the number of passes it holds.
pub struct GpuSession {
    pub(super) device: wgpu::Device,
    pub(super) queue: wgpu::Queue,
    pipeline: wgpu::ComputePipeline,
    grid_group: wgpu::BindGroup,
    group: wgpu::BindGroup,
    scene_uniform: wgpu::Buffer,
    pass_uniform: wgpu::Buffer,
    /// Byte stride of one `RtPass` record in `pass_uniform` (the dynamic offset alignment).
    stride: u64,
    accum: wgpu::Buffer,
    width: u32,
    height: u32,
    gx: u32,
    estimator: GpuEstimator,
    seed: u64,
    media: u32,
    /// The renderer's `RtParams.seed.w` (its media hierarchy), for [`GpuSession::reset`].
    bvh: u32,
    /// Whole passes in the accumulation.
    passes: u32,
    /// First row of the pass in progress that is not rendered yet (0: none in progress).
    next_row: u32,
    /// Measured wall time of one image row of one pass, seconds (0: not measured yet).
    row_seconds: f64,
    /// Timestamp queries around each compute pass, where the device has them.
    timer: Option<PassTimer>,
    /// GPU seconds and image rows of the slices [`GpuSession::add_for`] timed with them.
    gpu_seconds: f64,
    gpu_rows: u64,
}

impl std::fmt::Debug for GpuSession {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuSession")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("estimator", &self.estimator)
            .field("passes", &self.passes)
            .finish()
    }
}

impl GpuRenderer {
    /// Starts a progressive render of `scene` with `estimator` and `seed`: an empty
    /// accumulation on the device. The errors of [`GpuRenderer::render`] but `spp == 0`.
    pub fn session(
        &self,
        scene: &GpuScene,
        estimator: impl Into<GpuEstimator>,
        seed: u64,
    ) -> Result<GpuSession, GpuRenderError> {
        let estimator = estimator.into();
        scene.validate()?;
        self.check_estimator(estimator)?;
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
        let limit = pinrt::gpu::binding_limit(&self.limits);
        if accum_size > limit {
            return Err(Error::Gpu(format!(
                "image {w}x{h} needs a {accum_size}-byte accumulation buffer, more than this \
                 device binds ({limit} bytes)"
            ))
            .into());
        }
        let media = u32::try_from(self.caps.len())
            .map_err(|_| Error::Gpu(format!("{} media exceed u32", self.caps.len())))?;
        let params = scene.params(seed, estimator, media, self.bvh);
        Ok(pollster::block_on(async {
            let pipeline = self.pipeline(estimator).await?;
            self.begin(pipeline, &params, estimator, seed, media, w, h, accum_size)
                .await
        })?)
    }

    #[allow(clippy::too_many_arguments)]
    async fn begin(
        &self,
        pipeline: wgpu::ComputePipeline,
        params: &RtParams,
        estimator: GpuEstimator,
        seed: u64,
        media: u32,
        width: u32,
        height: u32,
        accum_size: u64,
    ) -> pinrt::Result<GpuSession> {
        let dev = &self.device;
        let scope = dev.push_error_scope(wgpu::ErrorFilter::Validation);
        let scene_uniform = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("render scene params"),
            contents: bytemuck::bytes_of(params),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        });
        // Zero-initialised by wgpu.
        let accum = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("render accumulation"),
            size: accum_size,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let stride = u64::from(self.limits.min_uniform_buffer_offset_alignment).max(16);
        let pass_uniform = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("render pass indices"),
            size: stride * u64::from(PASSES_PER_SUBMIT),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let group = dev.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("render scene"),
            layout: &self.set.render_layout,
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
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: self.grids.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: self.records.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: self.data.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 6,
                    resource: self.grid0.as_entire_binding(),
                },
            ]
            .into_iter()
            .chain(
                self.bricks
                    .iter()
                    .zip(7..)
                    .map(|(b, binding)| wgpu::BindGroupEntry {
                        binding,
                        resource: b.as_entire_binding(),
                    }),
            )
            .collect::<Vec<_>>(),
        });
        if let Some(e) = scope.pop().await {
            return Err(gpu_err("starting a render session", e));
        }
        Ok(GpuSession {
            device: self.device.clone(),
            queue: self.queue.clone(),
            pipeline,
            grid_group: self.grid_group.clone(),
            group,
            scene_uniform,
            pass_uniform,
            stride,
            accum,
            width,
            height,
            gx: width.div_ceil(WORKGROUP[0]),
            estimator,
            seed,
            media,
            bvh: self.bvh,
            passes: 0,
            next_row: 0,
            row_seconds: 0.0,
            timer: PassTimer::new(&self.device, &self.queue),
            gpu_seconds: 0.0,
            gpu_rows: 0,
        })
    }
}

impl GpuSession {
    /// Whole passes (samples per pixel) in the accumulation.
    pub fn passes(&self) -> u32 {
        self.passes
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    pub fn estimator(&self) -> GpuEstimator {
        self.estimator
    }

    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// The device the session renders on (its renderer's), for work on its accumulation.
    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    /// The queue of [`GpuSession::device`].
    pub fn queue(&self) -> &wgpu::Queue {
        &self.queue
    }

    /// The accumulation buffer: two `vec4<f32>` per pixel (Kahan sum, compensation), x
    /// fastest; divide by [`GpuSession::passes`] for the mean.
    pub fn accumulation(&self) -> &wgpu::Buffer {
        &self.accum
    }

    /// The first row of the pass in progress that is not rendered yet (0: no pass in
    /// progress); the rows above it hold one sample more than [`GpuSession::passes`].
    pub fn next_row(&self) -> u32 {
        self.next_row
    }

    /// The measured time of one whole pass in seconds (0 before the first
    /// [`GpuSession::add_for`]): the mean GPU time of the passes timed so far where the
    /// device has timestamp queries, else the latest wall-time estimate
    /// ([`GpuSession::pass_time_source`] says which).
    pub fn pass_seconds(&self) -> f64 {
        match self.pass_time_source() {
            PassTimeSource::GpuTimestamps => {
                self.gpu_seconds / self.gpu_rows as f64 * f64::from(self.height)
            }
            PassTimeSource::Wall => self.row_seconds * f64::from(self.height),
        }
    }

    /// Where [`GpuSession::pass_seconds`] comes from: GPU timestamps once a slice was timed
    /// with them, wall time otherwise.
    pub fn pass_time_source(&self) -> PassTimeSource {
        if self.gpu_rows > 0 {
            PassTimeSource::GpuTimestamps
        } else {
            PassTimeSource::Wall
        }
    }

    /// Starts again from an empty accumulation with `scene` (same image size, estimator and
    /// media) and `seed`: what a viewer does when the camera, the light or the material
    /// changes. Pins and densities stay where they are; nothing is re-uploaded but the
    /// scene's uniform block.
    pub fn reset(&mut self, scene: &GpuScene, seed: u64) -> Result<(), GpuRenderError> {
        scene.validate()?;
        if (scene.camera.width, scene.camera.height) != (self.width, self.height) {
            return Err(Error::Gpu(format!(
                "a session of {}x{} cannot reset to {}x{}; start a new one",
                self.width, self.height, scene.camera.width, scene.camera.height
            ))
            .into());
        }
        let params = scene.params(seed, self.estimator, self.media, self.bvh);
        self.queue
            .write_buffer(&self.scene_uniform, 0, bytemuck::bytes_of(&params));
        let mut enc = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("render reset"),
            });
        enc.clear_buffer(&self.accum, 0, None);
        self.queue.submit([enc.finish()]);
        self.seed = seed;
        self.passes = 0;
        self.next_row = 0;
        self.gpu_seconds = 0.0;
        self.gpu_rows = 0;
        Ok(())
    }

    /// Records and submits dispatches, each `(pass index, first row, rows)`, in order, in
    /// one command buffer (at most [`PASSES_PER_SUBMIT`]).
    fn submit(&self, dispatches: &[(u32, u32, u32)]) -> pinrt::Result<()> {
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let mut records = vec![0u8; (self.stride * dispatches.len() as u64) as usize];
        for (k, &(pass, row0, _)) in dispatches.iter().enumerate() {
            let at = (self.stride * k as u64) as usize;
            records[at..at + 4].copy_from_slice(&pass.to_le_bytes());
            records[at + 4..at + 8].copy_from_slice(&row0.to_le_bytes());
        }
        // Queued writes land before the next submission, after the ones already submitted.
        self.queue.write_buffer(&self.pass_uniform, 0, &records);
        let mut enc = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("render passes"),
            });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("render passes"),
                timestamp_writes: self.timer.as_ref().map(PassTimer::writes),
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &self.grid_group, &[]);
            for (k, &(_, _, rows)) in dispatches.iter().enumerate() {
                pass.set_bind_group(1, &self.group, &[(self.stride * k as u64) as u32]);
                pass.dispatch_workgroups(self.gx, rows.div_ceil(WORKGROUP[1]), 1);
            }
        }
        if let Some(timer) = &self.timer {
            timer.resolve(&mut enc);
        }
        self.queue.submit([enc.finish()]);
        match pollster::block_on(scope.pop()) {
            Some(e) => Err(gpu_err("render dispatch", e)),
            None => Ok(()),
        }
    }

    /// Adds `n` whole passes (after finishing a pass in progress), submitted in batches of
    /// [`PASSES_PER_SUBMIT`] without waiting for them: what a batch render does.
    pub fn add_passes(&mut self, n: u32) -> pinrt::Result<()> {
        if self.next_row != 0 {
            self.submit(&[(self.passes, self.next_row, self.height - self.next_row)])?;
            self.next_row = 0;
            self.passes += 1;
        }
        let mut done = 0u32;
        while done < n {
            let count = (n - done).min(PASSES_PER_SUBMIT);
            let dispatches: Vec<_> = (0..count)
                .map(|k| (self.passes + done + k, 0, self.height))
                .collect();
            self.submit(&dispatches)?;
            done += count;
        }
        self.passes += n;
        Ok(())
    }

    /// Renders for about `budget` of wall time, at most `max_passes` whole passes (a pass in
    /// progress finishes first), and returns the whole passes added. Work is
    /// submitted in slices of whole passes or of bands of rows of one pass, each sized from
    /// the measured time per row to take about `slice` (at least one band of 8 rows), and
    /// waited for before the next: a window that calls this once per frame keeps answering.
    /// A pass may stay unfinished between calls; it is finished first the next time.
    pub fn add_for(
        &mut self,
        budget: Duration,
        slice: Duration,
        max_passes: u32,
    ) -> pinrt::Result<u32> {
        let start = Instant::now();
        let before = self.passes;
        let band = WORKGROUP[1];
        while self.passes - before < max_passes {
            // Rows this slice should cover, from the measured time per row (one band to
            // measure it first).
            let want = if self.row_seconds > 0.0 {
                (slice.as_secs_f64() / self.row_seconds).max(1.0) as u64
            } else {
                u64::from(band)
            };
            let mut dispatches = Vec::new();
            let mut rows_done = 0u64;
            if self.next_row == 0 && want >= u64::from(self.height) {
                // Whole passes.
                let count = (want / u64::from(self.height))
                    .min(u64::from(PASSES_PER_SUBMIT))
                    .min(u64::from(max_passes - (self.passes - before)));
                for k in 0..count as u32 {
                    dispatches.push((self.passes + k, 0, self.height));
                }
                rows_done = count * u64::from(self.height);
            } else {
                let rows = (want.div_ceil(u64::from(band)) * u64::from(band))
                    .min(u64::from(self.height - self.next_row)) as u32;
                dispatches.push((self.passes, self.next_row, rows));
                rows_done += u64::from(rows);
            }
            let t = Instant::now();
            self.submit(&dispatches)?;
            self.device
                .poll(wgpu::PollType::wait_indefinitely())
                .map_err(|e| gpu_err("poll", e))?;
            let per_row = t.elapsed().as_secs_f64() / rows_done as f64;
            // The slicing keeps using wall time (what the window waits for); the readout
            // uses the GPU's own time where the device tells it.
            if let Some(timer) = &self.timer
                && let Some(seconds) = timer.read(&self.device).map_err(Error::Gpu)?
            {
                self.gpu_seconds += seconds;
                self.gpu_rows += rows_done;
            }
            self.row_seconds = if self.row_seconds > 0.0 {
                0.5 * (self.row_seconds + per_row)
            } else {
                per_row
            };
            if dispatches[0].2 == self.height && self.next_row == 0 {
                self.passes += dispatches.len() as u32;
            } else {
                self.next_row += dispatches[0].2;
                if self.next_row >= self.height {
                    self.next_row = 0;
                    self.passes += 1;
                }
            }
            let next = self.row_seconds * want.min(u64::from(self.height)) as f64;
            if start.elapsed().as_secs_f64() + next > budget.as_secs_f64() {
                break;
            }
        }
        Ok(self.passes - before)
    }

    /// Reads the accumulation back as the mean image of the whole passes (an error before
    /// the first pass; a pass in progress would be counted partly, so it is finished first).
    pub fn image(&mut self) -> pinrt::Result<Image> {
        if self.next_row != 0 {
            self.add_passes(0)?;
        }
        if self.passes == 0 {
            return Err(Error::Gpu("no pass rendered yet".into()));
        }
        let dev = &self.device;
        let scope = dev.push_error_scope(wgpu::ErrorFilter::Validation);
        let size = self.accum.size();
        let staging = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("render readback"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = dev.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("render readback"),
        });
        enc.copy_buffer_to_buffer(&self.accum, 0, &staging, 0, size);
        self.queue.submit([enc.finish()]);
        let sums: Vec<[f32; 8]> = pollster::block_on(pinrt::gpu::read_back(
            dev,
            &staging,
            scope,
            "render dispatch",
        ))?;
        let inv = 1.0 / f64::from(self.passes);
        let rgb = sums
            .iter()
            .map(|s| {
                // Kahan: the compensation holds what the running sum over-counted.
                std::array::from_fn(|c| ((f64::from(s[c]) - f64::from(s[4 + c])) * inv) as f32)
            })
            .collect();
        Ok(Image {
            width: self.width,
            height: self.height,
            rgb,
        })
    }
}
