//! `shaders/generated/` holds `pinrender shaders`'s translations of `shaders/pin.wgsl`; these
//! tests fail when the committed copies are stale (rerun
//! `pinrender shaders --out shaders/generated`), and validate the SPIR-V with `spirv-val` and
//! the GLSL with `glslangValidator`. A missing validator is a failure naming its apt package:
//! CI installs both.

use std::path::{Path, PathBuf};
use std::process::Command;

const FILES: [&str; 4] = ["pin.spv", "pin.comp", "pin.hlsl", "pin.metal"];

fn generated() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shaders/generated")
}

/// Fresh translations in a temp dir (kept alive by the returned guard).
fn fresh() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_pinrender"))
        .args(["shaders", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "pinrender shaders failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    dir
}

#[test]
fn committed_translations_are_current() {
    let dir = fresh();
    for name in FILES {
        let new = std::fs::read(dir.path().join(name)).unwrap();
        let old = std::fs::read(generated().join(name)).unwrap_or_default();
        assert!(
            new == old,
            "shaders/generated/{name} is stale: run `cargo run --release --features cli -p pinrender \
             --bin pinrender -- shaders --out shaders/generated` and commit the result"
        );
    }
}

/// Runs a validator; a missing one fails with the package that provides it.
fn validate(tool: &str, package: &str, args: &[&str], file: &Path) {
    let out = match Command::new(tool).args(args).arg(file).output() {
        Ok(out) => out,
        Err(e) => panic!(
            "{tool} is not installed ({e}); install it with `apt-get install {package}`: \
             this validation does not pass without it"
        ),
    };
    assert!(
        out.status.success(),
        "{tool} rejects {}:\n{}{}",
        file.display(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn spirv_passes_spirv_val() {
    let dir = fresh();
    let spv = dir.path().join("pin.spv");
    // The rules of the oldest target the module claims (SPIR-V 1.0 in Vulkan 1.0), plus the
    // block layout rules of storage buffers.
    validate(
        "spirv-val",
        "spirv-tools",
        &["--target-env", "vulkan1.0"],
        &spv,
    );
    validate(
        "spirv-val",
        "spirv-tools",
        &["--target-env", "vulkan1.2"],
        &spv,
    );
}

#[test]
fn glsl_passes_glslang_for_opengl_and_vulkan() {
    let dir = fresh();
    let comp = dir.path().join("pin.comp");
    // OpenGL GLSL 450 semantics, then the same source compiled to SPIR-V for Vulkan.
    validate("glslangValidator", "glslang-tools", &[], &comp);
    let spv = dir.path().join("from_glsl.spv");
    let spv_arg = spv.to_str().unwrap().to_string();
    validate(
        "glslangValidator",
        "glslang-tools",
        &["-V", "--target-env", "vulkan1.0", "-o", &spv_arg],
        &comp,
    );
    validate("spirv-val", "spirv-tools", &[], &spv);
}

#[test]
fn a_broken_module_is_caught_by_the_validator() {
    // The validation above can fail: a truncated SPIR-V module is rejected.
    let dir = fresh();
    let spv = std::fs::read(dir.path().join("pin.spv")).unwrap();
    let broken = dir.path().join("broken.spv");
    std::fs::write(&broken, &spv[..spv.len() / 2]).unwrap();
    let st = Command::new("spirv-val")
        .arg(&broken)
        .status()
        .expect("spirv-val (apt-get install spirv-tools)");
    assert!(!st.success(), "spirv-val accepted a truncated module");
}

/// The lab's kernels compile into the path tracer at its extension region, for every count of
/// brick value bindings the renderer uses, and the region is really replaced (the file's own
/// placeholder is gone, so a kernel code reaches the lab's function).
#[test]
fn the_lab_kernels_join_the_path_tracer() {
    use pinrender::gpu_render::{RENDER_WGSL, render_wgsl_with};
    assert!(RENDER_WGSL.contains("// extension kernels {\n"));
    for n in [1, 16, 26] {
        let text = render_wgsl_with(n, pinlab::estimator::COMBS_WGSL);
        assert!(text.contains("fn rt_comb_transmittance"));
        assert_eq!(text.matches("fn rt_kernel_transmittance").count(), 1);
        let module = naga::front::wgsl::parse_str(&text).unwrap_or_else(|e| panic!("{n}: {e}"));
        naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::all(),
        )
        .validate(&module)
        .unwrap_or_else(|e| panic!("{n}: {e:?}"));
    }
}
