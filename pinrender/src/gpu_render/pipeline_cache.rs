//! The pipeline cache on disk: a `wgpu::PipelineCache` (Vulkan's `VkPipelineCache`) loaded
//! from a file when a store is made and written back after each new compile.
//!
//! The file (`<wgpu::util::pipeline_cache_key>.bin` in the cache directory) is
//!
//! ```text
//! "PINRTPC1" | u32 key length | key | u64 data length | u64 xxh3-64 of data | data
//! ```
//!
//! where `key` names the adapter and driver (vendor, device, driver, driver info) and `data`
//! is `PipelineCache::get_data`. wgpu checks its own header in `data` (vendor, device, the
//! driver's cache UUID) and refuses data of another device with an error rather than an
//! empty cache, and nothing checks the bytes after that header, so the file is only handed to
//! wgpu when its key is this adapter's and its checksum holds: a truncated, corrupt or foreign
//! file is ignored (the pipelines compile from scratch) and replaced by the next good one.
//! Writes go to a file of their own in the directory and are renamed over the old one, so a
//! reader never sees half a file.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

const MAGIC: &[u8; 8] = b"PINRTPC1";
/// A cache larger than this is not read (a pipeline cache of this path tracer is a few MB).
const MAX_FILE_BYTES: u64 = 512 << 20;

/// A pipeline cache and the file it is kept in.
pub(super) struct DiskCache {
    path: PathBuf,
    key: String,
    cache: wgpu::PipelineCache,
    loaded: bool,
    /// Saves one at a time (two renderers may compile at once).
    saving: Mutex<()>,
}

/// The adapter and driver a cache belongs to: wgpu's key (backend, vendor, device) and the
/// driver's name and version; `None` where wgpu keeps no cache for the backend.
pub(super) fn adapter_key(adapter: &wgpu::AdapterInfo) -> Option<String> {
    let base = wgpu::util::pipeline_cache_key(adapter)?;
    Some(format!("{base} {} {}", adapter.driver, adapter.driver_info))
}

/// The file name of `adapter`'s cache: wgpu's key, which is made of letters, digits and `_`.
fn file_name(adapter: &wgpu::AdapterInfo) -> Option<String> {
    let base = wgpu::util::pipeline_cache_key(adapter)?;
    let safe = base.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
    safe.then(|| format!("{base}.bin"))
}

/// The cache data of `bytes` (a whole file), if it is `key`'s and intact.
pub(super) fn parse<'b>(bytes: &'b [u8], key: &str) -> Option<&'b [u8]> {
    let rest = bytes.strip_prefix(MAGIC.as_slice())?;
    let (len, rest) = rest.split_first_chunk::<4>()?;
    let key_len = u32::from_le_bytes(*len) as usize;
    if rest.len() < key_len || &rest[..key_len] != key.as_bytes() {
        return None;
    }
    let rest = &rest[key_len..];
    let (len, rest) = rest.split_first_chunk::<8>()?;
    let (hash, data) = rest.split_first_chunk::<8>()?;
    let ok = u64::from_le_bytes(*len) == data.len() as u64
        && u64::from_le_bytes(*hash) == xxhash_rust::xxh3::xxh3_64(data);
    ok.then_some(data)
}

/// The file's bytes for `data` of `key`'s adapter.
pub(super) fn encode(key: &str, data: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(32 + key.len() + data.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&(key.len() as u32).to_le_bytes());
    out.extend_from_slice(key.as_bytes());
    out.extend_from_slice(&(data.len() as u64).to_le_bytes());
    out.extend_from_slice(&xxhash_rust::xxh3::xxh3_64(data).to_le_bytes());
    out.extend_from_slice(data);
    out
}

/// The bytes of `path` if it is a regular file of at most [`MAX_FILE_BYTES`].
fn read_bounded(path: &Path) -> Option<Vec<u8>> {
    let meta = std::fs::metadata(path).ok()?;
    if !meta.is_file() || meta.len() > MAX_FILE_BYTES {
        return None;
    }
    std::fs::read(path).ok()
}

impl DiskCache {
    /// The cache of `adapter` in `dir`, loaded from its file where that is good; `None` where
    /// wgpu keeps no cache for the adapter's backend.
    pub(super) fn open(
        device: &wgpu::Device,
        adapter: &wgpu::AdapterInfo,
        dir: PathBuf,
    ) -> Option<Self> {
        let key = adapter_key(adapter)?;
        let path = dir.join(file_name(adapter)?);
        let bytes = read_bounded(&path);
        let data = bytes.as_deref().and_then(|b| parse(b, &key));
        let make = |data: Option<&[u8]>| {
            let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
            // SAFETY: `data` is what `PipelineCache::get_data` returned on an adapter with
            // this key (the file's key and checksum say so); wgpu checks its own header
            // again and falls back to an empty cache where the driver changed.
            let cache = unsafe {
                device.create_pipeline_cache(&wgpu::PipelineCacheDescriptor {
                    label: Some("pinrt pipeline cache"),
                    data,
                    fallback: true,
                })
            };
            pollster::block_on(scope.pop()).is_none().then_some(cache)
        };
        let (cache, loaded) = match data.and_then(|d| make(Some(d))) {
            Some(c) => (c, true),
            None => (make(None)?, false),
        };
        Some(Self {
            path,
            key,
            cache,
            loaded,
            saving: Mutex::new(()),
        })
    }

    pub(super) fn path(&self) -> &Path {
        &self.path
    }

    pub(super) fn loaded(&self) -> bool {
        self.loaded
    }

    pub(super) fn cache(&self) -> &wgpu::PipelineCache {
        &self.cache
    }

    /// Writes the cache's data to its file (through a file of its own, renamed over it);
    /// a failure leaves the old file and is otherwise ignored.
    pub(super) fn save(&self) {
        let Some(data) = self.cache.get_data() else {
            return;
        };
        let _one = self.saving.lock();
        let bytes = encode(&self.key, &data);
        // The renderer's own atomic write (temporary file, fsync, rename).
        if let Some(dir) = self.path.parent() {
            let _ = std::fs::create_dir_all(dir);
        }
        let _ = crate::render::write_atomic(&self.path, |out| {
            out.write_all(&bytes)
                .map_err(|e| crate::render::RenderError::Io {
                    path: self.path.clone(),
                    source: e,
                })
        });
    }
}
