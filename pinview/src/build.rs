//! Renderers and their sessions built off the window's thread. The media upload, the path
//! tracer's module and above all the estimator's compute pipeline take long (lavapipe
//! compiles a pipeline with LLVM: 0.8 s to 13 s on the build machine; a hardware driver runs
//! its own compiler), so a worker thread builds them on the window's device (wgpu's `Device`
//! and `Queue` are `Send + Sync`) and hands them back through a channel while the window
//! keeps painting the image it had.
//!
//! A driver may compile more at a pipeline's first use: lavapipe compiles the compute
//! shader with LLVM at its first dispatch and the tone map's fragment shader at its first
//! draw (seconds without Mesa's shader cache), on the device's queue, where every other
//! submission to that device waits behind it, the window's frames included. So the worker
//! also renders the first pass of a coarse preview (or, for a small image, one workgroup)
//! and tone-maps it, and on a CPU adapter each renderer gets a device of its own
//! ([`Gpu::own_devices`]): its compiles never stop the window's queue.
//!
//! Pipelines are compiled once per device ([`GpuPipelines`], with the disk cache where the
//! adapter has one): a renderer of another frame of a sequence, another file or the same
//! estimator again is built on a device whose store holds its pipeline, so it only uploads
//! its media; on a CPU adapter that is the own device the estimator's last renderer was
//! built on ([`DeviceStores`]), where the pipeline was compiled and already dispatched, and
//! then no warm-up is needed either.

use std::sync::{Arc, Mutex, mpsc};
use std::time::Instant;

use anyhow::{Result, anyhow};
use pinrender::gpu_render::{GpuPipelines, GpuRenderer, GpuScene, GpuSession, GpuToneMap};
use pinrender::render::EstimatorSpec;

use crate::device::{IMAGE_FORMAT, device_descriptor, image_texture};
use crate::export;
use crate::open::{MediaJob, gpu_media};

/// The device the viewer renders on, with the limits it was opened with.
#[derive(Clone)]
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub limits: wgpu::Limits,
    /// Where each renderer opens a device of its own on this adapter (the window's on a CPU
    /// adapter) instead of rendering on `device`; its image reaches the window through a
    /// [`Relay`].
    pub own_devices: Option<wgpu::Adapter>,
    /// The compiled pipelines of `device` and of the own devices.
    pub stores: Arc<DeviceStores>,
}

impl Gpu {
    /// The viewer's device on `adapter` (`info`): renderers on devices of their own where
    /// `own_devices` (a CPU adapter), pipelines through the disk cache.
    pub fn new(
        device: wgpu::Device,
        queue: wgpu::Queue,
        info: &wgpu::AdapterInfo,
        own_devices: Option<wgpu::Adapter>,
    ) -> Self {
        let limits = device.limits();
        let window = GpuPipelines::with_disk_cache(&device, &queue, &limits, info, None);
        Self {
            device,
            queue,
            limits,
            own_devices,
            stores: Arc::new(DeviceStores {
                info: info.clone(),
                window,
                own: Mutex::new(Vec::new()),
            }),
        }
    }
}

/// Own devices kept for later renderers (each holds its compiled pipelines and tone map).
pub const KEPT_DEVICES: usize = 6;

/// The pipeline stores a viewer builds renderers through: the window device's, and on a CPU
/// adapter the own devices made so far, each with the estimator it was made for, kept once
/// its pipeline has been compiled and dispatched, the latest last (at most [`KEPT_DEVICES`];
/// an older one is dropped once its renderers are).
pub struct DeviceStores {
    info: wgpu::AdapterInfo,
    window: Arc<GpuPipelines>,
    own: Mutex<Vec<OwnDevice>>,
}

struct OwnDevice {
    estimator: EstimatorSpec,
    store: Arc<GpuPipelines>,
    tone: Arc<GpuToneMap>,
}

impl DeviceStores {
    /// Path-tracing pipelines compiled so far on every device (the JSON's
    /// `pipelines_compiled`; the own devices dropped to keep [`KEPT_DEVICES`] no longer count).
    pub fn compiled(&self) -> usize {
        let own = self
            .own
            .lock()
            .map_or(0, |o| o.iter().map(|d| d.store.compiled()).sum::<usize>());
        self.window.compiled() + own
    }

    /// The own device the last renderer of `estimator` was built on, if one is kept.
    fn own_for(&self, estimator: EstimatorSpec) -> Option<(Arc<GpuPipelines>, Arc<GpuToneMap>)> {
        let own = self.own.lock().ok()?;
        own.iter()
            .rev()
            .find(|d| d.estimator == estimator)
            .map(|d| (d.store.clone(), d.tone.clone()))
    }

    /// Keeps a new own device for later renderers of `estimator`.
    fn keep(&self, estimator: EstimatorSpec, store: Arc<GpuPipelines>, tone: Arc<GpuToneMap>) {
        if let Ok(mut own) = self.own.lock() {
            own.push(OwnDevice {
                estimator,
                store,
                tone,
            });
            let over = own.len().saturating_sub(KEPT_DEVICES);
            own.drain(..over);
        }
    }
}

/// The longest side of the coarse preview, in pixels: about 1/16 of a 512 x 512 pass.
pub const PREVIEW_SIDE: u32 = 128;

/// A renderer of one estimator's media and an empty session of it.
pub struct Built {
    pub renderer: GpuRenderer,
    pub session: GpuSession,
    /// The tone map on the renderer's own device, where it has one.
    pub relay: Option<Relay>,
    /// The coarse preview: one pass of the view at a fraction of its size (never added to
    /// the session), tone-mapped and scaled up to the session's size by repeating pixels,
    /// as RGBA bytes; `None` where the image is at most [`PREVIEW_SIDE`] pixels a side.
    pub preview: Option<Vec<u8>>,
    /// When the media were uploaded (with the path tracer's module), when the pipeline
    /// and the session were made, and when the preview (or the warm-up) was rendered.
    pub uploaded: Instant,
    pub compiled: Instant,
    pub warmed: Instant,
    /// The view's generation the session was started with: one that arrives for an older
    /// view is reset to the current one (a buffer clear, nothing compiled again).
    pub generation: u64,
}

/// A renderer and session being built on a worker thread. Dropping the job leaves the
/// worker to finish (a pipeline compile cannot be stopped) and drops what it built; the
/// window keeps a job it no longer wants until then ([`BuildJob::is_finished`]) and waits
/// for the rest when it closes ([`BuildJob::join`]), so that no compile is still running in
/// the driver while the process exits.
pub struct BuildJob {
    pub estimator: EstimatorSpec,
    rx: mpsc::Receiver<Result<Built>>,
    worker: Option<std::thread::JoinHandle<()>>,
}

impl BuildJob {
    /// Starts building `media`'s renderer on `gpu` and a session of `scene` with `seed`.
    pub fn spawn(
        gpu: &Gpu,
        media: MediaJob,
        scene: GpuScene,
        seed: u64,
        exposure: f32,
        generation: u64,
    ) -> Result<Self> {
        let (tx, rx) = mpsc::channel();
        let gpu = gpu.clone();
        let estimator = media.estimator;
        let worker = std::thread::Builder::new()
            .name(format!("pinview build {estimator}"))
            .spawn(move || {
                // The window may have moved on: then nobody receives, and that is fine.
                let _ = tx.send(build(&gpu, &media, &scene, seed, exposure, generation));
            })?;
        Ok(Self {
            estimator,
            rx,
            worker: Some(worker),
        })
    }

    /// The result once the worker has finished (then `Some` once).
    pub fn poll(&mut self) -> Option<Result<Built>> {
        match self.rx.try_recv() {
            Ok(r) => Some(r),
            Err(mpsc::TryRecvError::Empty) => None,
            Err(mpsc::TryRecvError::Disconnected) => Some(Err(anyhow!(
                "building the {} renderer failed: its thread ended without a result",
                self.estimator
            ))),
        }
    }

    /// Whether the worker has ended.
    pub fn is_finished(&self) -> bool {
        self.worker.as_ref().is_none_or(|w| w.is_finished())
    }

    /// Waits for the worker to end, dropping what it built.
    pub fn join(&mut self) {
        if let Some(w) = self.worker.take() {
            // A worker that panicked has nothing left running: nothing to report here.
            let _ = w.join();
        }
    }

    /// Waits for the worker (a run with nothing to paint meanwhile).
    pub fn wait(mut self) -> Result<Built> {
        let built = self.rx.recv().map_err(|_| {
            anyhow!(
                "building the {} renderer failed: its thread ended without a result",
                self.estimator
            )
        });
        self.join();
        built?
    }
}

/// The media of `media` uploaded to `gpu` (or to a device of its own), the estimator's
/// pipeline compiled, an empty session of `scene` started, and the pipeline's first
/// dispatch and the tone map's first draw made (the preview): all that a first pass needs.
fn build(
    gpu: &Gpu,
    media: &MediaJob,
    scene: &GpuScene,
    seed: u64,
    exposure: f32,
    generation: u64,
) -> Result<Built> {
    let est = media.estimator;
    // An own device has the adapter's limits, as the window's.
    let descs = media.descs(&gpu.limits)?;
    let packed = gpu_media(&descs, est)?;
    let upload = |store: &Arc<GpuPipelines>| {
        GpuRenderer::with_media_in(store, &packed)
            .map_err(|e| anyhow!("{}: {e}", media.path.display()))
    };
    // The renderer, on an own device its tone map, and the own device to keep once its
    // pipeline has been dispatched (the warm-up below).
    let (renderer, tone, to_keep) = match &gpu.own_devices {
        None => (upload(&gpu.stores.window)?, None, None),
        Some(adapter) => {
            // A kept device is taken only where its pipeline for these media is compiled
            // (and dispatched: devices are kept after their warm-up): a compile there would
            // stop every queue submission of the renderers on it, and the window reads their
            // images from it.
            let kept = gpu.stores.own_for(est).and_then(|(store, tone)| {
                let r = upload(&store).ok()?;
                r.is_compiled(est).then_some((r, tone))
            });
            match kept {
                Some((r, tone)) => (r, Some(tone), None),
                None => {
                    let own = open_device(adapter, &gpu.stores.info)?;
                    let tone = Arc::new(GpuToneMap::new(own.device(), IMAGE_FORMAT));
                    (upload(&own)?, Some(tone.clone()), Some((own, tone)))
                }
            }
        }
    };
    let uploaded = Instant::now();
    // Compiled before on this device, and then dispatched and tone-mapped there by the
    // warm-up of the build that compiled it.
    let warm = renderer.is_compiled(est);
    let session = renderer
        .session(scene, est, seed)
        .map_err(|e| anyhow!("{e}"))?;
    let compiled = Instant::now();
    let mut relay = tone.map(Relay::with_tone);
    let preview = if warm {
        None
    } else {
        warm_up(&renderer, &mut relay, scene, est, seed, exposure)?
    };
    if let Some((store, tone)) = to_keep {
        gpu.stores.keep(est, store, tone);
    }
    Ok(Built {
        renderer,
        session,
        relay,
        preview,
        uploaded,
        compiled,
        warmed: Instant::now(),
        generation,
    })
}

/// A device of its own on `adapter`, as the window's is opened, with its pipeline store.
fn open_device(adapter: &wgpu::Adapter, info: &wgpu::AdapterInfo) -> Result<Arc<GpuPipelines>> {
    let (device, queue) = pollster::block_on(adapter.request_device(&device_descriptor(adapter)))
        .map_err(|e| anyhow!("opening a GPU device: {e}"))?;
    let limits = device.limits();
    Ok(GpuPipelines::with_disk_cache(
        &device, &queue, &limits, info, None,
    ))
}

/// The preview's size for an image of `width x height`: each side divided by the least
/// whole factor that brings the longer to at most [`PREVIEW_SIDE`] (`None`: factor 1).
pub fn preview_size(width: u32, height: u32) -> Option<(u32, u32, u32)> {
    scaled_size(width, height, PREVIEW_SIDE)
}

/// [`preview_size`] for a longer side of at most `side` (at least 1).
pub fn scaled_size(width: u32, height: u32, side: u32) -> Option<(u32, u32, u32)> {
    let f = width.max(height).div_ceil(side.max(1));
    (f > 1).then(|| (width.div_ceil(f), height.div_ceil(f), f))
}

/// Makes the driver compile what a first pass uses, here rather than at the window's first
/// pass: one pass of the coarse preview (returned, scaled up), or for a small image one
/// workgroup of 8 x 8 pixels, each in a session of its own that is then dropped, and its tone
/// map; waited for.
fn warm_up(
    renderer: &GpuRenderer,
    relay: &mut Option<Relay>,
    scene: &GpuScene,
    est: EstimatorSpec,
    seed: u64,
    exposure: f32,
) -> Result<Option<Vec<u8>>> {
    let (w, h) = (scene.camera.width, scene.camera.height);
    let preview = preview_size(w, h);
    let mut small = scene.clone();
    (small.camera.width, small.camera.height) = match preview {
        Some((pw, ph, _)) => (pw, ph),
        None => (w.min(8), h.min(8)),
    };
    let mut session = renderer
        .session(&small, est, seed)
        .map_err(|e| anyhow!("{e}"))?;
    session.add_passes(1).map_err(|e| anyhow!("{e}"))?;
    let rgba = match relay {
        Some(r) => r.image(&session, exposure)?,
        None => Relay::new(session.device()).image(&session, exposure)?,
    };
    Ok(preview.map(|(pw, ph, f)| upscale(&rgba, pw, ph, f, w, h)))
}

/// `rgba` of `pw x ph` scaled up by `f` (each pixel repeated) and cut to `w x h`.
pub fn upscale(rgba: &[u8], pw: u32, ph: u32, f: u32, w: u32, h: u32) -> Vec<u8> {
    let mut out = Vec::with_capacity((w * h * 4) as usize);
    for y in 0..h {
        let sy = (y / f).min(ph - 1);
        for x in 0..w {
            let sx = (x / f).min(pw - 1);
            let at = ((sy * pw + sx) * 4) as usize;
            out.extend_from_slice(&rgba[at..at + 4]);
        }
    }
    out
}

/// The tone map on a renderer's own device: the session's image is tone-mapped there into a
/// texture, read back and written into the window's texture (on a CPU adapter both are
/// host memory: about a millisecond per 512 x 512 image).
pub struct Relay {
    tone: Arc<GpuToneMap>,
    texture: Option<(wgpu::Texture, (u32, u32))>,
}

impl Relay {
    pub fn new(device: &wgpu::Device) -> Self {
        Self::with_tone(Arc::new(GpuToneMap::new(device, IMAGE_FORMAT)))
    }

    /// A relay drawing with a tone map of the session's device made before.
    pub fn with_tone(tone: Arc<GpuToneMap>) -> Self {
        Self {
            tone,
            texture: None,
        }
    }

    /// `session`'s image tone-mapped at `exposure` (as the window's tone map draws it), as
    /// RGBA bytes.
    pub fn image(&mut self, session: &GpuSession, exposure: f32) -> Result<Vec<u8>> {
        let size = (session.width(), session.height());
        if self.texture.as_ref().is_some_and(|(_, s)| *s != size) {
            self.texture = None;
        }
        let (texture, _) = self.texture.get_or_insert_with(|| {
            let t = image_texture(session.device(), size.0, size.1, "pinview relay image");
            (t, size)
        });
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        self.tone.draw(session, &view, exposure);
        export::read_texture_rgba(session.device(), session.queue(), texture, size.0, size.1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_preview_is_at_most_its_side_and_covers_the_image() {
        assert_eq!(preview_size(48, 40), None);
        assert_eq!(preview_size(128, 100), None);
        assert_eq!(preview_size(512, 512), Some((128, 128, 4)));
        assert_eq!(preview_size(1920, 1080), Some((128, 72, 15)));
        assert_eq!(preview_size(130, 7), Some((65, 4, 2)));
        let rgba: Vec<u8> = (0..2 * 2 * 4).map(|v| v as u8).collect();
        let up = upscale(&rgba, 2, 2, 2, 3, 4);
        assert_eq!(up.len(), 3 * 4 * 4);
        // Row 0: pixels (0,0) (0,0) (1,0); row 3: (0,1) (0,1) (1,1).
        assert_eq!(&up[0..4], &rgba[0..4]);
        assert_eq!(&up[8..12], &rgba[4..8]);
        assert_eq!(&up[36..40], &rgba[8..12]);
        assert_eq!(&up[44..48], &rgba[12..16]);
    }
}
