//! A Vulkan-style consumer of the committed SPIR-V: `shaders/generated/pin.spv` is handed to
//! the Vulkan driver unmodified (wgpu's SPIR-V passthrough; on CI Mesa lavapipe), with the
//! explicit descriptor layout of `docs/gpu.md`, the pin file's sections as storage buffers and
//! the uniform block from the C ABI's `pinrt_gpu_params`. Every result must equal the CPU
//! sampler's, integers and float bits. No adapter, or one without SPIR-V passthrough, is a
//! failure that says so.

use std::borrow::Cow;
use std::path::Path;

use bytemuck::Zeroable;
use pinrt::testing::random_grid;
use pinrt::{Directions, PinGrid, QueryResult, RayQuery, Rng};
use pinrt_capi::{
    PinrtGpuBuffers, PinrtGpuParams, PinrtGrid, PinrtQueryOptions, PinrtStatus, pinrt_close,
    pinrt_gpu_buffers, pinrt_gpu_params, pinrt_open_memory,
};
use wgpu::util::DeviceExt;

struct Vk {
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

fn spirv_words() -> Vec<u32> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shaders/generated/pin.spv");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(bytes.len() % 4, 0, "SPIR-V is a sequence of words");
    bytes
        .chunks_exact(4)
        .map(|w| u32::from_le_bytes(w.try_into().unwrap()))
        .collect()
}

fn entry(binding: u32, ty: wgpu::BindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty,
        count: None,
    }
}

fn storage(read_only: bool) -> wgpu::BindingType {
    wgpu::BindingType::Buffer {
        ty: wgpu::BufferBindingType::Storage { read_only },
        has_dynamic_offset: false,
        min_binding_size: None,
    }
}

fn vulkan() -> Vk {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
        backends: wgpu::Backends::VULKAN,
        ..wgpu::InstanceDescriptor::new_without_display_handle()
    });
    // A hardware adapter first, then the software fallback (lavapipe), as pinrt::gpu does.
    let request = |fallback| {
        pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: fallback,
            compatible_surface: None,
            apply_limit_buckets: false,
        }))
    };
    let adapter = request(false)
        .or_else(|_| request(true))
        .unwrap_or_else(|e| {
            panic!(
                "no Vulkan adapter ({e}): install a Vulkan driver \
             (without a GPU: apt-get install mesa-vulkan-drivers libvulkan1)"
            )
        });
    let features = wgpu::Features::PASSTHROUGH_SHADERS;
    assert!(
        adapter.features().contains(features),
        "the Vulkan adapter {:?} does not offer SPIR-V passthrough",
        adapter.get_info().name
    );
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("spirv consumer"),
        required_features: features,
        required_limits: adapter.limits(),
        ..Default::default()
    }))
    .expect("request_device");
    // SAFETY: the module is the committed pin.spv, which spirv-val accepts
    // (pinrender/tests/shaders.rs); the layout below matches its declared bindings.
    let module = unsafe {
        device.create_shader_module_passthrough(wgpu::ShaderModuleDescriptorPassthrough {
            label: Some("pin.spv"),
            entry_points: Cow::Owned(vec![wgpu::PassthroughShaderEntryPoint {
                name: "main".into(),
                workgroup_size: (64, 1, 1),
            }]),
            spirv: Some(Cow::Owned(spirv_words())),
            ..Default::default()
        })
    };
    // The binding table of docs/gpu.md.
    let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("pin queries"),
        entries: &[
            entry(
                0,
                wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
            ),
            entry(1, storage(true)),
            entry(2, storage(true)),
            entry(3, storage(true)),
            entry(4, storage(false)),
        ],
    });
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("pin queries"),
        bind_group_layouts: &[Some(&layout)],
        immediate_size: 0,
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some("pin.spv"),
        layout: Some(&pipeline_layout),
        module: &module,
        entry_point: Some("main"),
        compilation_options: Default::default(),
        cache: None,
    });
    Vk {
        device,
        queue,
        pipeline,
        layout,
    }
}

/// One dispatch over `rays`, fed exactly as a C renderer would from the C ABI.
fn run(
    vk: &Vk,
    grid: *const PinrtGrid,
    rays: &[RayQuery],
    seed: u32,
    first: u32,
) -> Vec<QueryResult> {
    let mut params = PinrtGpuParams::default();
    let mut bufs = PinrtGpuBuffers {
        pins: std::ptr::null(),
        pins_bytes: 0,
        cell_index: std::ptr::null(),
        cell_index_bytes: 0,
    };
    // SAFETY: `grid` is open; out pointers are valid.
    unsafe {
        let opts: *const PinrtQueryOptions = std::ptr::null();
        assert_eq!(pinrt_gpu_params(grid, opts, &mut params), PinrtStatus::Ok);
        assert_eq!(pinrt_gpu_buffers(grid, &mut bufs), PinrtStatus::Ok);
    }
    // SAFETY: valid while the grid is open (it is, for the whole call).
    let pins = unsafe { std::slice::from_raw_parts(bufs.pins, bufs.pins_bytes) };
    let index: &[u8] = if bufs.cell_index.is_null() {
        &[0u8; 8]
    } else {
        // SAFETY: as above.
        unsafe { std::slice::from_raw_parts(bufs.cell_index, bufs.cell_index_bytes) }
    };
    let n = rays.len() as u32;
    let groups = n.div_ceil(64);
    params.run = [seed, first, n, groups * 64];
    let dev = &vk.device;
    let init = |label, contents: &[u8], usage| {
        dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents,
            usage,
        })
    };
    let uniform = init(
        "params",
        bytemuck::bytes_of(&params),
        wgpu::BufferUsages::UNIFORM,
    );
    let pin_buf = init("pins", pins, wgpu::BufferUsages::STORAGE);
    let index_buf = init("cell index", index, wgpu::BufferUsages::STORAGE);
    let ray_buf = init(
        "rays",
        bytemuck::cast_slice(rays),
        wgpu::BufferUsages::STORAGE,
    );
    let size = u64::from(n) * 32;
    let results = dev.create_buffer(&wgpu::BufferDescriptor {
        label: Some("results"),
        size,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let staging = dev.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let bind = dev.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("pin queries"),
        layout: &vk.layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: uniform.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: pin_buf.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: index_buf.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: ray_buf.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 4,
                resource: results.as_entire_binding(),
            },
        ],
    });
    let mut enc = dev.create_command_encoder(&Default::default());
    {
        let mut pass = enc.begin_compute_pass(&Default::default());
        pass.set_pipeline(&vk.pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.dispatch_workgroups(groups, 1, 1);
    }
    enc.copy_buffer_to_buffer(&results, 0, &staging, 0, size);
    vk.queue.submit([enc.finish()]);
    let (tx, rx) = std::sync::mpsc::channel();
    staging
        .slice(..)
        .map_async(wgpu::MapMode::Read, move |r| tx.send(r).unwrap());
    dev.poll(wgpu::PollType::wait_indefinitely()).expect("poll");
    rx.recv().unwrap().expect("map readback");
    let view = staging.slice(..).get_mapped_range().expect("mapped range");
    let out = bytemuck::pod_collect_to_vec::<u8, QueryResult>(&view);
    drop(view);
    staging.unmap();
    out
}

/// Rays from around the unit box through it, a few invalid, mixed segment ends.
fn rays(n: usize) -> Vec<RayQuery> {
    let mut rng = Rng::for_query(77, 3);
    (0..n)
        .map(|i| {
            let mut u = || rng.next_f32() * 3.0 - 1.0;
            let o = [u(), u(), u()];
            let t = [u() * 0.4 + 0.3, u() * 0.4 + 0.3, u() * 0.4 + 0.3];
            let mut d = [t[0] - o[0], t[1] - o[1], t[2] - o[2]];
            if i % 101 == 0 {
                d = [0.0; 3];
            }
            let t_max = if i % 4 == 0 { u().abs() } else { f32::INFINITY };
            RayQuery::new(o, d, t_max)
        })
        .collect()
}

pub fn committed_spirv_reproduces_the_cpu_sampler() {
    let vk = vulkan();
    for (name, sparse) in [("dense", false), ("sparse", true)] {
        let bytes = random_grid(Directions::Octahedral { n: 6 }, [7, 5, 6], 3, sparse, 5)
            .to_bytes()
            .unwrap();
        let mut g = std::ptr::null_mut();
        // SAFETY: valid buffer and out pointer.
        let st = unsafe { pinrt_open_memory(bytes.as_ptr(), bytes.len(), &mut g) };
        assert_eq!(st, PinrtStatus::Ok);
        let reference = PinGrid::from_bytes(bytes.clone()).unwrap();
        let rays = rays(20_000);
        let (seed, first) = (1234, 99);
        let gpu = run(&vk, g, &rays, seed, first);
        let mut cpu = vec![QueryResult::zeroed(); rays.len()];
        reference
            .sampler()
            .unwrap()
            .query_batch(&rays, seed, first, &mut cpu);
        let mismatches = gpu
            .iter()
            .zip(&cpu)
            .filter(|(a, b)| bytemuck::bytes_of(*a) != bytemuck::bytes_of(*b))
            .count();
        let resolved = cpu.iter().filter(|r| r.status == pinrt::status::OK).count();
        let hits = cpu.iter().filter(|r| r.hit != 0).count();
        println!(
            "{name}: {} rays, {resolved} resolved, {hits} collisions, {mismatches} results differ",
            rays.len()
        );
        assert!(
            resolved > rays.len() / 4 && hits > 0,
            "too few rays meet the grid"
        );
        assert_eq!(mismatches, 0, "pin.spv disagrees with the CPU sampler");
        // SAFETY: opened above.
        unsafe { pinrt_close(g) };
    }
}
