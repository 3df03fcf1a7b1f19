//! The C example (`examples/c/pinrt_example.c`) compiled with the system `cc` against the
//! static library, run on a pin file baked from the OpenVDB smoke, and its numbers compared
//! bit for bit with the Rust sampler on the same rays and seed. Then the example runs under
//! valgrind (memcheck), which must report no errors and no definite leaks.
//!
//! The smoke is read by this test binary itself as the isolated OpenVDB reader (`main.rs`).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use pin_volume::{DensitySource, VdbOptions, VdbSource};
use pinbake::{BakeOptions, bake};
use pinrt::{PinGrid, RayQuery};

use crate::common::{compile_c, repo};

const SEED: u32 = 7;
/// Rays for the comparison and the timing (the C side times one call over all of them).
const RAYS: usize = 1 << 18;
/// Rays under valgrind, which runs the code about 50 times slower.
const VALGRIND_RAYS: usize = 2000;

fn bake_smoke(dir: &Path) -> PathBuf {
    let vdb = repo().join("data/openvdb_smoke1.vdb");
    let exe = std::env::current_exe().expect("test executable path");
    let source = VdbSource::open(
        &vdb,
        &VdbOptions::with_worker(exe),
        pin_volume::DensityScale::ONE,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    // Small on purpose (12^3 cells, about 1 MB): the test is about the ABI, not the bake.
    let opts = BakeOptions {
        cells: [12; 3],
        step: 0.02,
        ..BakeOptions::default()
    };
    let (grid, _) = bake(&source as &dyn DensitySource, &opts, &|_| {}).expect("bake");
    let out = dir.join("smoke.pin");
    grid.write_atomic(&out).expect("write smoke.pin");
    out
}

fn compile(dir: &Path) -> PathBuf {
    compile_c(
        "examples/c/pinrt_example.c",
        &["-O2", "-g", "-D_POSIX_C_SOURCE=200809L"],
        dir,
        "pinrt_example",
    )
}

fn f32s(bytes: &[u8]) -> Vec<f32> {
    bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

fn compare_with_rust(exe: &Path, pin: &Path, dir: &Path) {
    let dump = dir.join("dump.bin");
    let out = Command::new(exe)
        .arg(pin)
        .arg(RAYS.to_string())
        .arg(SEED.to_string())
        .arg(&dump)
        .current_dir(dir)
        .output()
        .expect("run the C example");
    let stdout = String::from_utf8_lossy(&out.stdout);
    print!("{stdout}");
    assert!(
        out.status.success(),
        "C example failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains(
            "missing file: status 3, message: does-not-exist.pin: No such file or directory"
        ),
        "the C side did not get the one-line error"
    );
    assert!(stdout.contains(&format!("memory copy differs on 0 of {RAYS} rays")));

    let bytes = std::fs::read(&dump).expect("dump");
    assert_eq!(bytes.len(), RAYS * (32 + 4 + 4), "dump size");
    let (ray_bytes, rest) = bytes.split_at(RAYS * 32);
    let rays: Vec<RayQuery> = bytemuck::pod_collect_to_vec(ray_bytes);
    let c_trans = f32s(&rest[..RAYS * 4]);
    let c_dist = f32s(&rest[RAYS * 4..]);

    let grid = PinGrid::open(pin).expect("open smoke.pin");
    let s = grid.sampler().expect("sampler");
    let mut trans = vec![0f32; RAYS];
    let mut dist = vec![None; RAYS];
    // An untimed pass first, as the C side's memory-copy check runs after its timed calls:
    // the timed passes then compare queries, not first touches of the mapping.
    s.transmittance_batch(&rays, SEED, 0, &mut trans);
    let t0 = Instant::now();
    s.transmittance_batch(&rays, SEED, 0, &mut trans);
    let t1 = Instant::now();
    s.sample_distance_batch(&rays, SEED, 0, &mut dist);
    let t2 = Instant::now();
    let mut hits = 0;
    for i in 0..RAYS {
        assert_eq!(
            c_trans[i].to_bits(),
            trans[i].to_bits(),
            "transmittance of ray {i}"
        );
        let d = dist[i].unwrap_or(f32::INFINITY);
        assert_eq!(c_dist[i].to_bits(), d.to_bits(), "distance of ray {i}");
        hits += usize::from(dist[i].is_some());
    }
    // The rays meet the medium: a comparison of nothing but misses would prove little.
    assert!(
        hits > RAYS / 10 && hits < RAYS,
        "{hits} collisions of {RAYS}"
    );
    // The C side's `PINRT_RENDER_*` and `PINRT_THESIS_*` lookups are the Rust sampler's
    // `SamplerOptions::RENDER` and `THESIS`; the default (NULL options) is the render one.
    let mean_of = |opts: pinrt::SamplerOptions| {
        let mut t = vec![0f32; RAYS];
        grid.sampler()
            .expect("sampler")
            .with_options(opts)
            .transmittance_batch(&rays, SEED, 0, &mut t);
        t.iter().map(|&t| f64::from(t)).sum::<f64>() / RAYS as f64
    };
    let render_mean = mean_of(pinrt::SamplerOptions::RENDER);
    let thesis_mean = mean_of(pinrt::SamplerOptions::THESIS);
    let plain_mean = trans.iter().map(|&t| f64::from(t)).sum::<f64>() / RAYS as f64;
    assert!(
        stdout.contains(&format!(
            "render lookup: mean transmittance {render_mean:.6}\n"
        )),
        "the C side's render lookup is not the Rust sampler's ({render_mean:.6})"
    );
    assert!(
        stdout.contains(&format!(
            "thesis lookup: mean transmittance {thesis_mean:.6}\n"
        )),
        "the C side's thesis lookup is not the Rust sampler's ({thesis_mean:.6})"
    );
    assert_eq!(format!("{render_mean:.6}"), format!("{plain_mean:.6}"));
    assert_ne!(format!("{render_mean:.6}"), format!("{thesis_mean:.6}"));
    let secs = |a: Instant, b: Instant| (b - a).as_secs_f64();
    println!(
        "Rust queries/s transmittance {:.0} distance {:.0}",
        RAYS as f64 / secs(t0, t1),
        RAYS as f64 / secs(t1, t2)
    );
    println!("C and Rust agree bit for bit on {RAYS} rays ({hits} collisions)");
}

fn valgrind(exe: &Path, pin: &Path, dir: &Path) {
    let run = Command::new("valgrind")
        .args([
            "--error-exitcode=99",
            "--leak-check=full",
            "--errors-for-leak-kinds=definite",
            "--quiet",
        ])
        .arg(exe)
        .arg(pin)
        .arg(VALGRIND_RAYS.to_string())
        .arg(SEED.to_string())
        .current_dir(dir)
        .output();
    let out = match run {
        Ok(out) => out,
        Err(e) => panic!(
            "valgrind could not be started ({e}): install it (apt-get install valgrind); \
             this check does not pass without it"
        ),
    };
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "valgrind found errors in the C example (exit {:?}):\n{stderr}",
        out.status.code()
    );
    println!("valgrind memcheck: no errors, no definite leaks ({VALGRIND_RAYS} rays)");
}

/// Bakes the smoke, compiles the C example, compares it with Rust and runs it under valgrind.
pub fn the_c_example_agrees_with_rust_under_valgrind() {
    let dir = tempfile::tempdir().expect("temp dir");
    let pin = bake_smoke(dir.path());
    let exe = compile(dir.path());
    compare_with_rust(&exe, &pin, dir.path());
    valgrind(&exe, &pin, dir.path());
}
