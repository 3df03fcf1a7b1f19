//! Pipelines compiled once per device (`GpuPipelines`) and the pipeline cache on disk.
use super::pipeline_cache;
use super::tests::{blob_grid, context, load, scene};
use super::*;
use crate::render::EstimatorSpec;
use pin_format::Directions;

fn pins_bits(r: &GpuRenderer) -> Vec<[f32; 3]> {
    r.render(&scene(16, 0.8, 0.3, 3), EstimatorSpec::Pins, 2, 5)
        .unwrap()
        .rgb
}

#[test]
fn a_renderer_of_the_same_layout_takes_the_compiled_pipeline_and_renders_its_own_bits() {
    let ctx = context();
    let store = GpuPipelines::new(&ctx.device, &ctx.queue, &ctx.limits);
    let frame = |strength: f32| load(&blob_grid(4, Directions::Octahedral { n: 4 }, 2, strength));
    let (a, b) = (frame(0.25), frame(2.0));
    let first =
        GpuRenderer::with_media_in(&store, &GpuMedia::pins_only(&a, None, Default::default()))
            .unwrap();
    assert!(!first.is_compiled(EstimatorSpec::Pins));
    let bits_a = pins_bits(&first);
    assert_eq!(store.compiled(), 1);
    // The next frame: another grid of the same layout, nothing compiled.
    let second =
        GpuRenderer::with_media_in(&store, &GpuMedia::pins_only(&b, None, Default::default()))
            .unwrap();
    assert!(second.is_compiled(EstimatorSpec::Pins));
    let bits_b = pins_bits(&second);
    assert_eq!(store.compiled(), 1, "the second frame compiled a pipeline");
    // Its image is its own media's: the bits of a renderer that compiled for itself.
    assert!(bits_a != bits_b, "the frames differ, so must their images");
    let fresh = GpuRenderer::new(ctx, &b).unwrap();
    assert!(
        pins_bits(&fresh) == bits_b,
        "a shared pipeline changed the bits"
    );
    // Another estimator compiles once more.
    first
        .render(&scene(8, 0.5, 0.0, 1), EstimatorSpec::PinMs, 1, 1)
        .unwrap_err();
    assert_eq!(
        store.compiled(),
        1,
        "an estimator the media cannot answer compiles nothing"
    );
}

#[test]
fn the_cache_file_holds_its_adapters_data_intact() {
    let data = b"some driver bytes".to_vec();
    let file = pipeline_cache::encode("vulkan 1 2 drv 1.0", &data);
    assert_eq!(
        pipeline_cache::parse(&file, "vulkan 1 2 drv 1.0"),
        Some(&data[..])
    );
    // Another adapter's or driver's, truncated, a flipped bit, trailing bytes: refused.
    assert_eq!(pipeline_cache::parse(&file, "vulkan 1 2 drv 1.1"), None);
    for cut in [0, 7, 12, file.len() - 1] {
        assert_eq!(
            pipeline_cache::parse(&file[..cut], "vulkan 1 2 drv 1.0"),
            None,
            "{cut}"
        );
    }
    let mut flipped = file.clone();
    *flipped.last_mut().unwrap() ^= 1;
    assert_eq!(pipeline_cache::parse(&flipped, "vulkan 1 2 drv 1.0"), None);
    let mut longer = file.clone();
    longer.push(0);
    assert_eq!(pipeline_cache::parse(&longer, "vulkan 1 2 drv 1.0"), None);
}

/// A device with `Features::PIPELINE_CACHE` where the adapter has it.
fn cache_device() -> Option<(wgpu::Device, wgpu::Queue, wgpu::AdapterInfo)> {
    let adapter = pollster::block_on(pinrt::gpu::request_adapter()).unwrap();
    let features = adapter.features() & wgpu::Features::PIPELINE_CACHE;
    if features.is_empty() {
        return None;
    }
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        required_features: features,
        required_limits: adapter.limits(),
        ..Default::default()
    }))
    .unwrap();
    Some((device, queue, adapter.get_info()))
}

#[test]
fn a_corrupt_or_foreign_pipeline_cache_is_ignored_and_replaced() {
    let Some((device, queue, info)) = cache_device() else {
        // Only Vulkan keeps a pipeline cache (lavapipe here does).
        assert_ne!(context().adapter_info.backend, wgpu::Backend::Vulkan);
        return;
    };
    let limits = device.limits();
    let dir = tempfile::tempdir().unwrap();
    let grid = load(&blob_grid(4, Directions::Octahedral { n: 4 }, 2, 0.5));
    let media = GpuMedia::pins_only(&grid, None, Default::default());
    let render =
        |store: &Arc<GpuPipelines>| pins_bits(&GpuRenderer::with_media_in(store, &media).unwrap());
    // Cold: nothing on disk; the compile writes the file.
    let cold =
        GpuPipelines::with_disk_cache(&device, &queue, &limits, &info, Some(dir.path().into()));
    let path = cold
        .disk_cache_path()
        .expect("a cache file for a Vulkan adapter")
        .to_path_buf();
    assert!(!cold.disk_cache_loaded());
    let bits = render(&cold);
    let key = pipeline_cache::adapter_key(&info).unwrap();
    let written = std::fs::read(&path).unwrap();
    assert!(
        pipeline_cache::parse(&written, &key).is_some(),
        "the file is not a good cache"
    );
    // Warm: the file is loaded, the bits are the same.
    let warm =
        GpuPipelines::with_disk_cache(&device, &queue, &limits, &info, Some(dir.path().into()));
    assert!(warm.disk_cache_loaded());
    assert!(render(&warm) == bits);
    // Garbage, a truncated file, another adapter's data, an empty file: each ignored; and
    // wgpu's data with its tail overwritten behind a good envelope. The render is the same
    // and the file is replaced by a good one.
    let mut body = pipeline_cache::parse(&written, &key).unwrap().to_vec();
    let n = body.len();
    body[n.saturating_sub(8)..].fill(0xAB);
    let garbage_body = pipeline_cache::encode(&key, &body);
    let bad: Vec<(&str, Vec<u8>)> = vec![
        ("garbage", vec![0x5A; 4096]),
        ("truncated", written[..written.len() / 2].to_vec()),
        (
            "foreign",
            pipeline_cache::encode("wgpu_pipeline_cache_vulkan_4318_9999 nvidia 1", b"x"),
        ),
        ("empty", Vec::new()),
        // Handed to wgpu and the driver, which check their own headers.
        ("bad body", garbage_body),
    ];
    for (what, bytes) in bad {
        std::fs::write(&path, &bytes).unwrap();
        let store =
            GpuPipelines::with_disk_cache(&device, &queue, &limits, &info, Some(dir.path().into()));
        assert!(
            what == "bad body" || !store.disk_cache_loaded(),
            "{what}: loaded"
        );
        assert!(render(&store) == bits, "{what}: other bits");
        let now = std::fs::read(&path).unwrap();
        assert!(
            pipeline_cache::parse(&now, &key).is_some(),
            "{what}: not replaced"
        );
    }
    // A directory that cannot be written: no cache file, the render all the same.
    let blocked = dir.path().join("blocked");
    std::fs::write(&blocked, b"a file where the directory would be").unwrap();
    let store =
        GpuPipelines::with_disk_cache(&device, &queue, &limits, &info, Some(blocked.clone()));
    assert!(render(&store) == bits);
    assert!(blocked.is_file());
    // No leftover temporary files.
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    assert!(names.iter().all(|n| !n.contains(".tmp")), "{names:?}");
}
