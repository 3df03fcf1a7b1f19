//! Renderers and their sessions built off the window's thread. The media upload, the path
//! tracer's module and above all the estimator's compute pipeline take long (lavapipe
//! compiles a pipeline with LLVM: 0.8 s to 13 s on the build machine; a hardware driver runs
//! its own compiler), so a worker thread builds them on the window's device (wgpu's `Device`
//! and `Queue` are `Send + Sync`) and hands them back through a channel while the window
//! keeps painting the image it had.

use std::sync::mpsc;
use std::time::Instant;

use anyhow::{Result, anyhow};
use pinrender::gpu_render::{GpuRenderer, GpuScene, GpuSession};
use pinrender::render::EstimatorSpec;

use crate::open::{MediaJob, gpu_media};

/// The device the viewer renders on, with the limits it was opened with.
#[derive(Clone)]
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub limits: wgpu::Limits,
}

/// A renderer of one estimator's media and an empty session of it.
pub struct Built {
    pub renderer: GpuRenderer,
    pub session: GpuSession,
    /// When the media were uploaded (with the path tracer's module) and when the pipeline
    /// and the session were made.
    pub uploaded: Instant,
    pub compiled: Instant,
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
        generation: u64,
    ) -> Result<Self> {
        let (tx, rx) = mpsc::channel();
        let gpu = gpu.clone();
        let estimator = media.estimator;
        let worker = std::thread::Builder::new()
            .name(format!("pinview build {estimator}"))
            .spawn(move || {
                // The window may have moved on: then nobody receives, and that is fine.
                let _ = tx.send(build(&gpu, &media, &scene, seed, generation));
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

/// The media of `media` uploaded to `gpu`, the estimator's pipeline compiled and an empty
/// session of `scene` started: all that a first pass needs.
fn build(
    gpu: &Gpu,
    media: &MediaJob,
    scene: &GpuScene,
    seed: u64,
    generation: u64,
) -> Result<Built> {
    let est = media.estimator;
    let descs = media.descs(&gpu.limits)?;
    let packed = gpu_media(&descs, est)?;
    let renderer = GpuRenderer::with_media_on(&gpu.device, &gpu.queue, &gpu.limits, &packed)
        .map_err(|e| anyhow!("{}: {e}", media.path.display()))?;
    let uploaded = Instant::now();
    let session = renderer
        .session(scene, est, seed)
        .map_err(|e| anyhow!("{e}"))?;
    Ok(Built {
        renderer,
        session,
        uploaded,
        compiled: Instant::now(),
        generation,
    })
}
