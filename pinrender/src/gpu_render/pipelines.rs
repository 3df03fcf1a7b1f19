//! The path tracer's compiled pipelines, shared by every renderer on one device.
//!
//! A pipeline depends on the estimator (its primary and secondary kernel codes: the WGSL
//! module, specialised to them by [`super::wgsl::specialise`], and two pipeline-overridable
//! constants), on whether there is one medium or several and whether some density is bricked
//! (constants too), and on the number of brick-value bindings (the bind group layouts and the
//! module). None of that depends on the values in the media, so a renderer of another frame
//! of a sequence, another file of the same layout or another scene on the same device takes
//! the pipeline an earlier renderer compiled: [`GpuPipelines`] holds them, keyed by
//! ([`LayoutKey`], [`PipelineKey`]), with the bind group layouts every renderer of a layout
//! binds its buffers through.
//!
//! Where the device has `Features::PIPELINE_CACHE` (Vulkan), the pipelines are created
//! through a `wgpu::PipelineCache` loaded from disk ([`super::pipeline_cache`]) and the
//! cache's data is written back after each new compile, so a later process starts warm.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use pinrt::Error;

use super::pipeline_cache::DiskCache;
use super::{
    RtParams, gpu_err, media, render_wgsl, render_wgsl_with, storage_entry, uniform_entry,
    wgsl::specialise,
};

/// What the bind group layouts depend on: the number of storage bindings of brick values (at
/// least 1).
pub(super) type LayoutKey = usize;

/// What one compute pipeline of a layout depends on beyond it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(super) struct PipelineKey {
    pub primary: u32,
    pub secondary: u32,
    pub one_medium: bool,
    pub bricked: bool,
}

/// The bind group layouts and pipeline layout of one [`LayoutKey`], with the pipelines
/// compiled for it.
pub(super) struct LayoutSet {
    pub grid_layout: wgpu::BindGroupLayout,
    pub render_layout: wgpu::BindGroupLayout,
    layout: wgpu::PipelineLayout,
    value_count: usize,
    pipelines: Mutex<HashMap<PipelineKey, wgpu::ComputePipeline>>,
}

impl LayoutSet {
    pub(super) fn has(&self, key: PipelineKey) -> bool {
        self.pipelines.lock().is_ok_and(|p| p.contains_key(&key))
    }
}

/// The compiled path-tracing pipelines of one device, shared by the renderers made on it
/// ([`super::GpuRenderer::with_media_in`]): each pipeline is compiled once per device and
/// process, and once per adapter and driver across processes where the disk cache is on
/// ([`GpuPipelines::with_disk_cache`]).
pub struct GpuPipelines {
    pub(super) device: wgpu::Device,
    pub(super) queue: wgpu::Queue,
    pub(super) limits: wgpu::Limits,
    disk: Option<DiskCache>,
    layouts: Mutex<HashMap<LayoutKey, Arc<LayoutSet>>>,
    compiled: AtomicUsize,
    /// Whether modules are specialised to their pipeline's estimators (always, but in the
    /// test that checks the specialisation against the full text).
    specialised: bool,
}

impl std::fmt::Debug for GpuPipelines {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuPipelines")
            .field("compiled", &self.compiled())
            .field("disk_cache", &self.disk_cache_path())
            .finish()
    }
}

fn poisoned<T>(_: T) -> Error {
    Error::Gpu("pipeline store poisoned".into())
}

impl GpuPipelines {
    /// An empty store for `device` (opened with `limits`), with no disk cache.
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue, limits: &wgpu::Limits) -> Arc<Self> {
        Arc::new(Self {
            device: device.clone(),
            queue: queue.clone(),
            limits: limits.clone(),
            disk: None,
            layouts: Mutex::new(HashMap::new()),
            compiled: AtomicUsize::new(0),
            specialised: true,
        })
    }

    /// [`GpuPipelines::new`] compiling the full text for every pipeline, as before the
    /// specialisation: what the specialised pipelines are checked against.
    #[cfg(test)]
    pub(super) fn unspecialised(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        limits: &wgpu::Limits,
    ) -> Arc<Self> {
        let mut store = Self::new(device, queue, limits);
        Arc::get_mut(&mut store).expect("just made").specialised = false;
        store
    }

    /// An empty store for `device` whose pipelines go through a pipeline cache kept on disk
    /// in `dir` (the default, [`default_cache_dir`], where `None`), in a file named by the
    /// adapter and driver (`wgpu::util::pipeline_cache_key`). Where the device lacks
    /// `Features::PIPELINE_CACHE` (it was not asked for, or the backend has none) or the
    /// adapter has no key, it is [`GpuPipelines::new`]. A cache file that is unreadable,
    /// corrupt or another adapter's is ignored (the pipelines compile from scratch and a
    /// good file replaces it).
    pub fn with_disk_cache(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        limits: &wgpu::Limits,
        adapter: &wgpu::AdapterInfo,
        dir: Option<PathBuf>,
    ) -> Arc<Self> {
        let disk = device
            .features()
            .contains(wgpu::Features::PIPELINE_CACHE)
            .then(|| dir.or_else(default_cache_dir))
            .flatten()
            .and_then(|dir| DiskCache::open(device, adapter, dir));
        Arc::new(Self {
            device: device.clone(),
            queue: queue.clone(),
            limits: limits.clone(),
            disk,
            layouts: Mutex::new(HashMap::new()),
            compiled: AtomicUsize::new(0),
            specialised: true,
        })
    }

    /// The device the pipelines are compiled on.
    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    /// The file the pipeline cache is kept in, where there is one.
    pub fn disk_cache_path(&self) -> Option<&std::path::Path> {
        self.disk.as_ref().map(|d| d.path())
    }

    /// Whether the pipeline cache was loaded from a file this process did not write (a warm
    /// start).
    pub fn disk_cache_loaded(&self) -> bool {
        self.disk.as_ref().is_some_and(|d| d.loaded())
    }

    /// Compute pipelines created so far through this store (each one compile).
    pub fn compiled(&self) -> usize {
        self.compiled.load(Ordering::Relaxed)
    }

    /// The layouts of `value_count` brick-value bindings, made the first time.
    pub(super) async fn layout_set(&self, value_count: usize) -> pinrt::Result<Arc<LayoutSet>> {
        if let Some(s) = self.layouts.lock().map_err(poisoned)?.get(&value_count) {
            return Ok(s.clone());
        }
        let dev = &self.device;
        let scope = dev.push_error_scope(wgpu::ErrorFilter::Validation);
        let grid_layout = dev.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("render grid"),
            entries: &[
                uniform_entry(0, false, size_of::<media::GridParams>() as u64),
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
                storage_entry(3, true),
                storage_entry(4, true),
                storage_entry(5, true),
                uniform_entry(6, false, size_of::<media::GridParams>() as u64),
            ]
            .into_iter()
            // 7..: the brick values.
            .chain((0..value_count as u32).map(|k| storage_entry(7 + k, true)))
            .collect::<Vec<_>>(),
        });
        let layout = dev.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("render"),
            bind_group_layouts: &[Some(&grid_layout), Some(&render_layout)],
            immediate_size: 0,
        });
        if let Some(e) = scope.pop().await {
            return Err(gpu_err("making the path tracer's bind group layouts", e));
        }
        let set = Arc::new(LayoutSet {
            grid_layout,
            render_layout,
            layout,
            value_count,
            pipelines: Mutex::new(HashMap::new()),
        });
        // Two threads may both have made one; the first in is kept, so that every renderer
        // of this layout binds through the same layouts.
        Ok(self
            .layouts
            .lock()
            .map_err(poisoned)?
            .entry(value_count)
            .or_insert(set)
            .clone())
    }

    /// The pipeline of `key` in `set`, compiled the first time it is asked for from the path
    /// tracer's WGSL (with a [`super::ShaderKernel`]'s `kernel` WGSL at its extension region)
    /// specialised to the key's estimators, in a module of its own.
    pub(super) async fn pipeline(
        &self,
        set: &LayoutSet,
        key: PipelineKey,
        kernel: Option<(&'static str, &'static str)>,
    ) -> pinrt::Result<wgpu::ComputePipeline> {
        if let Some(p) = set.pipelines.lock().map_err(poisoned)?.get(&key) {
            return Ok(p.clone());
        }
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let flag = |b: bool| if b { 1.0 } else { 0.0 };
        let constants = [
            ("RT_PRIMARY", f64::from(key.primary)),
            ("RT_SECONDARY", f64::from(key.secondary)),
            ("RT_ONE_MEDIUM", flag(key.one_medium)),
            ("RT_BRICKS", flag(key.bricked)),
        ];
        let (label, text) = match kernel {
            Some((name, wgsl)) => (name, render_wgsl_with(set.value_count, wgsl)),
            None => ("pin.wgsl + render.wgsl", render_wgsl(set.value_count)),
        };
        let text = if self.specialised {
            specialise(&text, &[key.primary, key.secondary])
        } else {
            text
        };
        let module = self
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(text.into()),
            });
        let pipeline = self
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some("render"),
                layout: Some(&set.layout),
                module: &module,
                entry_point: Some("render_main"),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: &constants,
                    ..Default::default()
                },
                cache: self.disk.as_ref().map(|d| d.cache()),
            });
        if let Some(e) = scope.pop().await {
            return Err(gpu_err("compiling shaders/render.wgsl", e));
        }
        self.compiled.fetch_add(1, Ordering::Relaxed);
        if let Some(d) = &self.disk {
            // A cache that cannot be written costs the next process a compile, nothing more.
            d.save();
        }
        // Two threads may both have compiled it; either copy will do.
        set.pipelines
            .lock()
            .map_err(poisoned)?
            .insert(key, pipeline.clone());
        Ok(pipeline)
    }
}

/// Where the pipeline caches are kept: `$PINRT_PIPELINE_CACHE` where set (`off`: nowhere,
/// no disk cache), else `$XDG_CACHE_HOME/pinrt/pipelines`, else `~/.cache/pinrt/pipelines`
/// (`None` without any of these variables).
pub fn default_cache_dir() -> Option<PathBuf> {
    let nonempty = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty());
    if let Some(v) = nonempty("PINRT_PIPELINE_CACHE") {
        return (v != "off").then(|| PathBuf::from(v));
    }
    let base = nonempty("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| nonempty("HOME").map(|h| PathBuf::from(h).join(".cache")))?;
    Some(base.join("pinrt").join("pipelines"))
}
