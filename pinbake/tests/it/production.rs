//! The production-scale cloud generator (`scripts/production/cloud.cpp`, written with
//! OpenVDB itself) at a small size, read through the isolated worker: the cloud is billowy
//! (neither empty nor a box), its leaves stay half precision in the parent (at most 2x the
//! file's bytes in memory, which an f32 table would break), and a leaf budget is honoured
//! before the leaves are read. The full sizes are measured
//! by `scripts/scale-bench.sh` (docs/scale.md), not here.
//!
//! Without a C++ compiler or OpenVDB the test fails with the reason, as the compatibility
//! corpus does.

use std::path::{Path, PathBuf};
use std::process::Command;

use pin_volume::vdb::{VdbOptions, VdbSource};
use pin_volume::{DensitySource, SourceError};

const ROOT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/..");

/// Generates `cloud-NAME.vdb` of `dims` with generate.sh under this test's temp dir and
/// returns it with the generator's JSON line.
fn cloud(name: &str, dims: [u32; 3]) -> (PathBuf, serde_json::Value) {
    let tmp = Path::new(env!("CARGO_TARGET_TMPDIR")).join("production-test");
    let script = Path::new(ROOT).join("scripts/production/generate.sh");
    let out = Command::new("bash")
        .arg(&script)
        .args(["custom", name])
        .args(dims.map(|d| d.to_string()))
        .env("CARGO_TARGET_DIR", &tmp)
        // A small cloud: the generator's compile is most of the time, half as long at -O0.
        .env("CLOUD_OPT", "-O0")
        .output()
        .expect("bash runs");
    assert!(
        out.status.success(),
        "the cloud generator failed (it needs g++, libopenvdb-dev and libboost-dev): {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let path = PathBuf::from(String::from_utf8_lossy(&out.stdout).trim().to_string());
    let json = std::fs::read_to_string(path.with_extension("vdb.json")).unwrap();
    (path, serde_json::from_str(&json).unwrap())
}

fn opts() -> VdbOptions {
    VdbOptions::with_worker(env!("CARGO_BIN_EXE_pinbake"))
}

#[test]
fn a_small_production_cloud_reads_in_bounded_memory() {
    let dims = [124, 84, 153];
    let (path, info) = cloud("test", dims);
    let active = info["active_voxels"].as_u64().unwrap();
    let boxed: u64 = dims.iter().map(|&d| u64::from(d)).product();
    // Billowy puffs, not a box and not a speck: a quarter to a half of the box is cloud.
    assert!(
        active > boxed / 5 && active < boxed / 2,
        "{active} active voxels of {boxed}"
    );
    let file_bytes = std::fs::metadata(&path).unwrap().len();
    let source = VdbSource::open(&path, &opts(), pin_volume::DensityScale::ONE).unwrap();
    assert!(
        source.describe().contains("saved as half"),
        "{}",
        source.describe()
    );
    let held = source.memory_bytes();
    assert!(
        held <= 2 * file_bytes,
        "the leaf table holds {held} bytes for a {file_bytes}-byte file"
    );
    let f = source.footprint().unwrap();
    assert_eq!(f.held, held);
    assert!(f.while_opening > held);
    // The tree stores the cloud, not its box.
    assert!(source.stored_voxels() < boxed / 2);

    // A leaf budget below the table is refused as memory, naming the file and the budget.
    let small = VdbOptions {
        max_leaf_bytes: Some(held / 2),
        ..opts()
    };
    match VdbSource::open(&path, &small, pin_volume::DensityScale::ONE) {
        Err(e @ SourceError::Memory { .. }) => {
            let m = e.to_string();
            assert!(
                m.contains("cloud-test.vdb") && m.contains("--max-memory"),
                "{m}"
            );
        }
        Err(e) => panic!("expected a memory refusal, got {e}"),
        Ok(_) => panic!("expected a memory refusal"),
    }
    let enough = VdbOptions {
        max_leaf_bytes: Some(2 * held),
        ..opts()
    };
    let again = VdbSource::open(&path, &enough, pin_volume::DensityScale::ONE).unwrap();
    assert_eq!(again.memory_bytes(), held);
}
