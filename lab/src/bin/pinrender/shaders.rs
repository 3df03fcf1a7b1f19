//! `pinrender shaders --out DIR`: `shaders/pin.wgsl` translated by naga into the shading
//! languages of other renderers: SPIR-V (Vulkan), GLSL 450 compute (OpenGL / Vulkan GLSL
//! toolchains), HLSL shader model 5.1 (D3D12) and MSL 2.0 (Metal). The copies committed under
//! `shaders/generated/` are written by this command; `tests/shaders.rs` fails when they are
//! stale and validates them with spirv-val and glslangValidator. How a renderer binds the
//! buffers is in `docs/gpu.md`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, anyhow};
use clap::Args;
use naga::back::{glsl, hlsl, msl, spv};
use naga::valid::{Capabilities, ValidationFlags, Validator};
use naga::{ResourceBinding, ShaderStage};

#[derive(Args, Debug)]
pub struct ShadersArgs {
    /// Directory to write pin.spv, pin.comp (GLSL 450), pin.hlsl and pin.metal into (created
    /// if missing).
    #[arg(long)]
    pub out: PathBuf,
}

/// The entry point of `pin.wgsl` (one invocation per ray, workgroups of 64).
const ENTRY: &str = "main";
/// Buffers of `pin.wgsl`, all in group 0: 0 parameters (uniform), 1 pins, 2 cell index, 3 rays
/// (read-only storage), 4 results (read-write storage).
const BINDINGS: u32 = 5;

/// The translated sources, by file name.
pub fn translate(wgsl: &str) -> Result<Vec<(&'static str, Vec<u8>)>> {
    let module = naga::front::wgsl::parse_str(wgsl)
        .map_err(|e| anyhow!("pin.wgsl: {}", e.emit_to_string(wgsl)))?;
    // Every backend below writes from this validated module: HLSL and MSL have no validator
    // on this machine, so naga's own validation is what they pass.
    let info = Validator::new(ValidationFlags::all(), Capabilities::empty())
        .validate(&module)
        .map_err(|e| anyhow!("pin.wgsl: {}", e.emit_to_string(wgsl)))?;
    let binding = |b: u32| ResourceBinding {
        group: 0,
        binding: b,
    };

    let spv_opts = spv::Options {
        // SPIR-V 1.0 loads on every Vulkan 1.0+ driver.
        lang_version: (1, 0),
        ..spv::Options::default()
    };
    let spv_pipe = spv::PipelineOptions {
        shader_stage: ShaderStage::Compute,
        entry_point: ENTRY.into(),
    };
    let words = spv::write_vec(&module, &info, &spv_opts, Some(&spv_pipe)).context("SPIR-V")?;
    let spirv: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();

    // GLSL keeps the WGSL binding numbers (`layout(binding = N)`), so one table serves both.
    let glsl_opts = glsl::Options {
        version: glsl::Version::Desktop(450),
        writer_flags: glsl::WriterFlags::empty(),
        binding_map: (0..BINDINGS).map(|b| (binding(b), b as u8)).collect(),
        zero_initialize_workgroup_memory: true,
    };
    let glsl_pipe = glsl::PipelineOptions {
        shader_stage: ShaderStage::Compute,
        entry_point: ENTRY.into(),
        multiview: None,
    };
    let mut glsl_src = String::new();
    glsl::Writer::new(
        &mut glsl_src,
        &module,
        &info,
        &glsl_opts,
        &glsl_pipe,
        naga::proc::BoundsCheckPolicies::default(),
    )
    .context("GLSL")?
    .write()
    .context("GLSL")?;

    // D3D registers: b0 (constants), t1..t3 (SRVs), u4 (UAV), all in space 0: each binding
    // keeps its number, with the register class its access needs.
    let hlsl_map: BTreeMap<ResourceBinding, hlsl::BindTarget> = (0..BINDINGS)
        .map(|b| {
            (
                binding(b),
                hlsl::BindTarget {
                    space: 0,
                    register: b,
                    ..hlsl::BindTarget::default()
                },
            )
        })
        .collect();
    let hlsl_opts = hlsl::Options {
        shader_model: hlsl::ShaderModel::V5_1,
        binding_map: hlsl_map,
        fake_missing_bindings: false,
        ..hlsl::Options::default()
    };
    let hlsl_pipe = hlsl::PipelineOptions {
        entry_point: Some((ShaderStage::Compute, ENTRY.into())),
    };
    let mut hlsl_src = String::new();
    hlsl::Writer::new(&mut hlsl_src, &hlsl_opts, &hlsl_pipe)
        .write(&module, &info, None)
        .context("HLSL")?;

    // Metal buffer slots: [[buffer(N)]] for binding N, and slot 5 for the array lengths
    // naga's bounds checks read (the runtime-sized arrays of bindings 1-4, in bytes).
    let msl_resources = msl::EntryPointResources {
        resources: (0..BINDINGS)
            .map(|b| {
                (
                    binding(b),
                    msl::BindTarget {
                        buffer: Some(b as u8),
                        mutable: b == 4,
                        ..msl::BindTarget::default()
                    },
                )
            })
            .collect(),
        immediates_buffer: None,
        sizes_buffer: Some(BINDINGS as u8),
    };
    let msl_opts = msl::Options {
        lang_version: (2, 0),
        per_entry_point_map: [(ENTRY.to_string(), msl_resources)].into(),
        fake_missing_bindings: false,
        ..msl::Options::default()
    };
    let msl_pipe = msl::PipelineOptions {
        entry_point: Some((ShaderStage::Compute, ENTRY.into())),
        ..msl::PipelineOptions::default()
    };
    let (msl_src, _) = msl::write_string(&module, &info, &msl_opts, &msl_pipe).context("MSL")?;

    Ok(vec![
        ("pin.spv", spirv),
        ("pin.comp", glsl_src.into_bytes()),
        ("pin.hlsl", hlsl_src.into_bytes()),
        ("pin.metal", msl_src.into_bytes()),
    ])
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> Result<()> {
    let path = dir.join(name);
    std::fs::write(&path, bytes).with_context(|| format!("{}", path.display()))
}

pub fn run(args: ShadersArgs) -> Result<()> {
    std::fs::create_dir_all(&args.out).with_context(|| format!("{}", args.out.display()))?;
    for (name, bytes) in translate(pinrt::PIN_WGSL)? {
        write(&args.out, name, &bytes)?;
        pin_cli::outln!("{}", args.out.join(name).display())?;
    }
    Ok(())
}
