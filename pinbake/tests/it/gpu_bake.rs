//! The GPU bake (`BakeBackend::Gpu`, `pinbake bake --backend gpu`) against the CPU bake: the
//! bound docs/gpu.md states, on the bundled volumes and a procedural cloud; the same bytes
//! for any tiling of the pins and any slab budget of the density, and from a sparse source's
//! slabs as from its dense copy; the command line's refusals and a device lost mid-bake.
//! Runs on whatever adapter wgpu finds (Mesa's lavapipe here).

use std::path::PathBuf;
use std::process::Command;

use pin_format::{Directions, EMPTY_CELL, OwnedPinGrid, PinEntry};
use pin_volume::raw::{RawOptions, RawType, read_raw};
use pin_volume::vdb::{VdbOptions, VdbSource};
use pin_volume::{
    DenseGrid, Density, DensityScale, DensitySource, ProceduralSpec, procedural::ProceduralKind,
};
use pinbake::glam::DVec3;
use pinbake::pin::{Field, PinLayout, Placement, field_optical_depths};
use pinbake::{BakeBackend, BakeOptions, GpuBakeOptions, bake, bake_on};

/// The bound (docs/gpu.md "GPU bake"): every interval optical depth of the GPU is within
/// `TAU_REL * max(tau, 1)` of the CPU's, so `|ln t_min_gpu - ln t_min_cpu|` is too...
const TAU_REL: f64 = 1e-4;
/// ...and a mask bit may differ only where the CPU's uniform is within this of the CPU's
/// probability (the f32 probability's error plus the 2^-24 of the truncated uniform).
const P_ABS: f64 = 2e-4;

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(name)
}

/// Every bundled volume as the dense grid the bake marches, and a small procedural cloud.
fn volumes() -> Vec<(String, DenseGrid)> {
    let mut out = Vec::new();
    let opt = VdbOptions::with_worker(env!("CARGO_BIN_EXE_pinbake"));
    for name in [
        "openvdb_smoke1.vdb",
        "gaffer_sphere_density.vdb",
        "oiio_sphere_density.vdb",
    ] {
        let s = VdbSource::open(&data(name), &opt, DensityScale::ONE).unwrap();
        assert!(s.bake_frame().is_none(), "{name}");
        out.push((name.to_string(), s.dense_copy(1 << 30).unwrap()));
    }
    for (name, dims, ty) in [
        ("water_esp_31x34x33_float32.raw", [31, 34, 33], RawType::F32),
        (
            "hydrogen_atom_128x128x128_uint8.raw",
            [128, 128, 128],
            RawType::U8,
        ),
    ] {
        let opt = RawOptions {
            dims: Some(dims),
            voxel_type: Some(ty),
            clamp_negative: true,
            ..Default::default()
        };
        out.push((
            name.to_string(),
            read_raw(&data(name), &opt, DensityScale::ONE).unwrap(),
        ));
    }
    out.push(("procedural cloud".to_string(), cloud(40)));
    out
}

/// A procedural cloud (the benchmark's cosine noise), voxelised at `n`^3.
fn cloud(n: u32) -> DenseGrid {
    let mut spec = ProceduralSpec::new(ProceduralKind::Cosine);
    spec.noise.seed = 5;
    let noise = spec.build_noise().unwrap();
    let b = noise.bounds();
    let h = b.extent() / f64::from(n);
    let mut data = vec![0.0f32; (n * n * n) as usize];
    for (i, out) in data.chunks_mut(n as usize).enumerate() {
        let (y, z) = ((i % n as usize) as f64, (i / n as usize) as f64);
        let start = b.min + DVec3::new(0.5, y + 0.5, z + 0.5) * h;
        noise.extinction_along(start, DVec3::new(h.x, 0.0, 0.0), n as usize, out);
    }
    DenseGrid::new([n; 3], data, h, b.min, "procedural cloud").unwrap()
}

fn opts(jitter: bool) -> BakeOptions {
    BakeOptions {
        cells: [8, 9, 7],
        directions: Directions::Octahedral { n: 4 },
        pins_per_entry: if jitter { 2 } else { 1 },
        jitter_pins: jitter,
        seed: 11,
        threads: Some(2),
        ..BakeOptions::default()
    }
}

/// [`opts`] with fewer cells, for the test that bakes each volume many times over slabs: a
/// lavapipe dispatch costs about its pins times its slabs, and what they check (the same
/// bytes from every slab count, every pin's sums carried across every slab boundary, two
/// tiles of pins under the smallest tile budget) holds pin by pin, so 1920 pins cover it as
/// the 16128 of [`opts`] do, in an eighth of the time.
fn slab_opts() -> BakeOptions {
    BakeOptions {
        cells: [4, 5, 3],
        ..opts(true)
    }
}

fn gpu() -> BakeBackend {
    BakeBackend::Gpu(GpuBakeOptions::default())
}

/// The entry in slot `slot` of cell `cell` (x-fastest linear index).
fn entry(g: &OwnedPinGrid, cell: usize, slot: usize, block: usize) -> PinEntry {
    match &g.cell_index {
        None => g.pins[cell * block + slot],
        Some(index) if index[cell] == EMPTY_CELL => PinEntry::EMPTY,
        Some(index) => g.pins[index[cell] as usize * block + slot],
    }
}

#[derive(Default, Debug)]
struct Agreement {
    pins: usize,
    bits: usize,
    differing_bits: usize,
    max_tau_rel: f64,
    max_bit_margin: f64,
}

/// Compares the GPU bake of `grid` with the CPU's pin by pin, explaining every differing mask
/// bit by the CPU's own optical depths and uniforms. Panics past the bound.
fn compare(name: &str, grid: &DenseGrid, o: &BakeOptions) -> Agreement {
    let (cpu, _) = bake(grid, o, &|_| {}).unwrap();
    let (gpu_grid, _) = bake_on(grid, o, gpu(), &|_| {}).unwrap();
    let (bbox, _) = pinbake::bake::bake_box(grid, o.crop).unwrap();
    let placement = Placement::over(&bbox, o.step);
    let layout = PinLayout {
        dims: o.cells,
        directions: o.directions,
        pins_per_entry: o.pins_per_entry,
        jitter: o.jitter_pins,
        seed: o.seed,
    };
    let block = (o.directions.count() * o.pins_per_entry) as usize;
    let mut a = Agreement::default();
    let [nx, ny, nz] = o.cells;
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let cell = [x, y, z];
                let lin = layout.cell_linear(cell);
                for slot in 0..block as u32 {
                    let (dir, k) = (slot / o.pins_per_entry, slot % o.pins_per_entry);
                    let c = entry(&cpu, lin as usize, slot as usize, block);
                    let g = entry(&gpu_grid, lin as usize, slot as usize, block);
                    let mut rng = layout.rng(lin, dir, k);
                    let (p, w) = layout.line(cell, dir, &mut rng);
                    let taus = field_optical_depths(Field::Grid(grid), &placement, p, w);
                    let tau_max = taus.iter().copied().fold(0.0f64, f64::max);
                    a.pins += 1;
                    // t_min: ln t is -tau_max (both sides clamp an empty pin to 1).
                    let (lc, lg) = (f64::from(c.t_min).ln(), f64::from(g.t_min).ln());
                    let rel = (lc - lg).abs() / tau_max.max(1.0);
                    if rel.is_finite() {
                        // (A t_min that underflows to 0 is held by the absolute clause.)
                        a.max_tau_rel = a.max_tau_rel.max(rel);
                    }
                    assert!(
                        rel <= TAU_REL || (c.t_min - g.t_min).abs() <= 1e-6,
                        "{name}: cell {cell:?} slot {slot}: t_min {} (CPU) vs {} (GPU)",
                        c.t_min,
                        g.t_min
                    );
                    if c == PinEntry::EMPTY || g == PinEntry::EMPTY {
                        // An empty pin on one side only: its optical depth rounds to t = 1
                        // in f32 on the other, where no mask bit can matter.
                        assert!(c == g || tau_max < 1e-6, "{name}: {cell:?} {slot}");
                        continue;
                    }
                    let denom = -(-tau_max).exp_m1();
                    a.bits += 32;
                    for (i, &tau) in taus.iter().enumerate() {
                        let u = rng.next_f64();
                        let bit = 1u32 << (31 - i);
                        if c.mask & bit == g.mask & bit {
                            continue;
                        }
                        let prob = -(-tau).exp_m1() / denom;
                        a.differing_bits += 1;
                        a.max_bit_margin = a.max_bit_margin.max((u - prob).abs());
                        assert!(
                            (u - prob).abs() <= P_ABS,
                            "{name}: cell {cell:?} slot {slot} bit {i}: the CPU draws {u} \
                             against probability {prob}, the GPU's bit differs"
                        );
                    }
                }
            }
        }
    }
    a
}

#[test]
fn gpu_entries_agree_with_the_cpu_on_every_bundled_volume_and_a_cloud() {
    for (name, grid) in volumes() {
        for jitter in [false, true] {
            let a = compare(&name, &grid, &opts(jitter));
            eprintln!("{name} jitter {jitter}: {a:?}");
            // Few differing bits: each one is a uniform within P_ABS of its probability.
            assert!(
                a.differing_bits as f64 <= 1e-3 * a.bits as f64 + 2.0,
                "{name}: {a:?}"
            );
        }
    }
}

/// Densities at the edges of f32: uniform 1e-30 and subnormal (every optical depth rounds
/// to t = 1 on the CPU, which leaves every cell out), and one voxel of 3e38 in a cloud (its
/// f32 sums overflow). The GPU leaves out exactly what the CPU leaves out (it stored every
/// pin with t_min 0.99999994), and the bound holds (one 3e38 voxel made 3.8% of the bits
/// differ).
#[test]
fn gpu_entries_agree_with_the_cpu_on_extreme_densities() {
    let n = 8u32;
    let uniform = |v: f32, name: &str| {
        let h = DVec3::splat(1.0 / f64::from(n));
        DenseGrid::new([n; 3], vec![v; (n * n * n) as usize], h, DVec3::ZERO, name).unwrap()
    };
    let mut spike = vec![0.5f32; (n * n * n) as usize];
    spike[(3 * n * n + 4 * n + 3) as usize] = 3e38;
    let h = DVec3::splat(1.0 / f64::from(n));
    let cases = [
        ("uniform 1e-30", uniform(1e-30, "tiny")),
        ("uniform 1e-40 (subnormal)", uniform(1e-40, "subnormal")),
        (
            "one voxel of 3e38",
            DenseGrid::new([n; 3], spike, h, DVec3::ZERO, "spike").unwrap(),
        ),
    ];
    for (name, grid) in cases {
        let o = opts(false);
        let (cpu, _) = bake(&grid, &o, &|_| {}).unwrap();
        let (gpu_grid, _) = bake_on(&grid, &o, gpu(), &|_| {}).unwrap();
        // The same cells left out, so the same file layout and size.
        assert_eq!(
            cpu.cell_index, gpu_grid.cell_index,
            "{name}: empty cells differ"
        );
        assert_eq!(cpu.pins.len(), gpu_grid.pins.len(), "{name}");
        assert!(
            gpu_grid.pins.iter().all(|p| p.t_min.is_finite()),
            "{name}: a GPU t_min is not finite"
        );
        let a = compare(name, &grid, &o);
        eprintln!("{name}: {a:?}");
        assert!(
            a.differing_bits as f64 <= 1e-3 * a.bits as f64,
            "{name}: {a:?}"
        );
    }
}

#[test]
fn gpu_bytes_do_not_depend_on_the_tiling() {
    let grid = cloud(24);
    let o = BakeOptions {
        majorant: Some([4; 3]),
        ..opts(true)
    };
    let (one, _) = bake_on(&grid, &o, gpu(), &|_| {}).unwrap();
    let (again, _) = bake_on(&grid, &o, gpu(), &|_| {}).unwrap();
    let small = BakeBackend::Gpu(GpuBakeOptions {
        tile_bytes: Some(80 * 333),
        ..GpuBakeOptions::default()
    });
    let calls = std::sync::atomic::AtomicU64::new(0);
    let (tiled, _) = bake_on(&grid, &o, small, &|_| {
        calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    })
    .unwrap();
    let bytes = |g: &OwnedPinGrid| g.to_bytes().unwrap();
    assert_eq!(bytes(&one), bytes(&again));
    assert_eq!(bytes(&one), bytes(&tiled));
    // 8 * 9 * 7 cells x 16 directions x 2 pins in dispatches of 333 pins.
    let pins = 8 * 9 * 7 * 16 * 2u64;
    assert_eq!(
        calls.load(std::sync::atomic::Ordering::Relaxed),
        pins.div_ceil(333)
    );
}

/// A GPU bake of `source` with `o` and a slab budget of `slab_bytes` and pin tile budget of
/// `tile_bytes`: its file's bytes and the slabs it went up in.
fn slabbed_bake(
    source: &dyn DensitySource,
    o: &BakeOptions,
    slab_bytes: Option<u64>,
    tile_bytes: Option<u64>,
) -> (Vec<u8>, u64) {
    let backend = BakeBackend::Gpu(GpuBakeOptions {
        slab_bytes,
        tile_bytes,
        ..GpuBakeOptions::default()
    });
    let (g, stats) = bake_on(source, o, backend, &|_| {}).unwrap();
    (g.to_bytes().unwrap(), stats.gpu.unwrap().slabs)
}

/// Every bundled volume and the cloud: one slab, slabs of two planes (the least), of three,
/// of an odd byte count, and small slabs with small tiles of pins give the same file. Every
/// slab marches every pin, so on these volumes the slabs are `depth / 16` times as thick
/// (about sixteen slabs at the smallest budget); a small cloud takes the least budget itself.
#[test]
fn gpu_bytes_do_not_depend_on_the_slab_count() {
    let o = BakeOptions {
        majorant: Some([4; 3]),
        ..slab_opts()
    };
    let mut cases: Vec<(String, DenseGrid, u64)> = volumes()
        .into_iter()
        .map(|(name, grid)| {
            let k = u64::from(grid.dims()[2]).div_ceil(16);
            (name, grid, k)
        })
        .collect();
    cases.push(("small cloud".to_string(), cloud(12), 1));
    for (name, grid, k) in cases {
        let [nx, ny, nz] = grid.dims();
        let plane = u64::from(nx) * u64::from(ny) * 4;
        let (whole, slabs) = slabbed_bake(&grid, &o, None, None);
        assert_eq!(slabs, 1, "{name}");
        for (budget, tiles) in [
            (2 * k * plane, None),
            (3 * k * plane, None),
            (7 * k * plane + 13, None),
            (5 * k * plane - 1, Some(336 * 1000)),
        ] {
            let (got, slabs) = slabbed_bake(&grid, &o, Some(budget), tiles);
            let planes = budget / plane;
            assert_eq!(
                slabs,
                u64::from(nz - 1).div_ceil(planes - 1),
                "{name}: {budget}"
            );
            assert!(
                whole == got,
                "{name}: slabs of {budget} bytes ({slabs} slabs, tiles {tiles:?}) give other bytes"
            );
        }
    }
}

/// A sparse source with no dense copy within the budget: each slab built from the VDB gives
/// the bytes of the GPU bake of its whole dense copy; one that cannot hold two planes is
/// refused naming both sizes.
#[test]
fn a_sparse_source_bakes_slab_by_slab_from_the_source() {
    let opt = VdbOptions::with_worker(env!("CARGO_BIN_EXE_pinbake"));
    for name in ["openvdb_smoke1.vdb", "gaffer_sphere_density.vdb"] {
        let s = VdbSource::open(&data(name), &opt, DensityScale::ONE).unwrap();
        let copy = s.dense_copy(1 << 30).unwrap();
        let [nx, ny, nz] = copy.dims();
        let plane = u64::from(nx) * u64::from(ny) * 4;
        // The default step: samples enough that the whole copy is what the bake marches.
        let base = opts(false);
        assert!(
            pinbake::bake::dense_copy_limit(&base) >= plane * u64::from(nz),
            "{name}: {} {:?} {}",
            pinbake::bake::dense_copy_limit(&base),
            copy.dims(),
            plane * u64::from(nz)
        );
        let (whole, slabs) = slabbed_bake(&s, &base, None, None);
        assert_eq!(slabs, 1, "{name}");
        for (host, gpu) in [
            (3 * plane, None),
            (u64::MAX >> 1, Some(2 * plane)),
            (5 * plane + 7, Some(4 * plane)),
        ] {
            let o = BakeOptions {
                dense_copy_bytes: host.min(plane * u64::from(nz) - 1),
                ..base.clone()
            };
            let (got, slabs) = slabbed_bake(&s, &o, gpu, None);
            assert!(slabs > 1, "{name}: {host} {gpu:?}");
            assert!(
                whole == got,
                "{name}: slabs from the source ({host} host bytes, {gpu:?} GPU) give other bytes"
            );
        }
        let o = BakeOptions {
            dense_copy_bytes: 2 * plane - 1,
            ..base.clone()
        };
        let gpu = BakeBackend::Gpu(GpuBakeOptions::default());
        let err = bake_on(&s, &o, gpu, &|_| {}).unwrap_err().to_string();
        assert!(
            err.contains(&format!("{} bytes", 2 * plane))
                && err.contains(&format!("{} bytes", 2 * plane - 1))
                && !err.contains('\n'),
            "{name}: {err}"
        );
    }
}

fn pinbake() -> Command {
    Command::new(env!("CARGO_BIN_EXE_pinbake"))
}

#[test]
fn the_command_line_bakes_on_the_gpu_and_refuses_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let out = |n: &str| dir.path().join(n);
    let raw = data("water_esp_31x34x33_float32.raw");
    let base = |o: &PathBuf| {
        let mut c = pinbake();
        c.arg("bake")
            .arg(&raw)
            .args(["--clamp-negative", "--cells", "6"])
            .args(["--dirs", "octahedral:4", "-q", "-o"])
            .arg(o);
        c
    };
    // A GPU bake into `o` with `extra` flags, which must succeed.
    let bake_ok = |o: &PathBuf, extra: &[&str]| {
        let st = base(o)
            .args(["--backend", "gpu"])
            .args(extra)
            .output()
            .unwrap();
        assert!(
            st.status.success(),
            "{}",
            String::from_utf8_lossy(&st.stderr)
        );
    };
    let a = out("a.pin");
    bake_ok(&a, &[]);
    let b = out("b.pin");
    bake_ok(&b, &["--gpu-tile-bytes", "4000"]);
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());

    // A budget that holds no pin: one line, exit 1, no file.
    let c = out("c.pin");
    let st = base(&c)
        .args(["--backend", "gpu", "--gpu-tile-bytes", "10"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&st.stderr);
    assert_eq!(st.status.code(), Some(1), "{err}");
    let line = err.lines().find(|l| l.contains("pinbake")).unwrap_or("");
    assert!(line.contains("holds no pin"), "{err}");
    assert!(!c.exists());

    // Slabs of the density: the same file; a slab budget below two planes of 31 x 34 f32
    // (8432 bytes): one line naming both sizes, exit 1, no file.
    let d = out("d.pin");
    bake_ok(&d, &["--gpu-slab-bytes", "20000"]);
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&d).unwrap());
    let st = base(&c)
        .args(["--backend", "gpu", "--gpu-slab-bytes", "8431"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&st.stderr);
    assert_eq!(st.status.code(), Some(1), "{err}");
    let lines: Vec<&str> = err
        .lines()
        .filter(|l| !l.contains("XDG_RUNTIME_DIR"))
        .collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(
        lines[0].contains("8432 bytes") && lines[0].contains("8431 bytes"),
        "{err}"
    );
    assert!(!c.exists());

    // An unknown backend is a usage error.
    let st = base(&c).args(["--backend", "tpu"]).output().unwrap();
    assert_eq!(st.status.code(), Some(2));
}

/// `--frames` bakes a sequence on the GPU: each frame is the bytes of that frame's own GPU bake.
#[test]
fn a_sequence_bakes_on_the_gpu_frame_by_frame() {
    let dir = tempfile::tempdir().unwrap();
    let raw = data("water_esp_31x34x33_float32.raw");
    for f in ["w.0001.raw", "w.0002.raw"] {
        std::fs::copy(&raw, dir.path().join(f)).unwrap();
    }
    let flags = [
        "--dims",
        "31,34,33",
        "--type",
        "f32",
        "--clamp-negative",
        "--cells",
        "4",
        "--dirs",
        "octahedral:4",
        "--backend",
        "gpu",
        "-q",
    ];
    let run = |args: &[&str]| {
        let o = pinbake()
            .current_dir(dir.path())
            .arg("bake")
            .args(args)
            .args(flags)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    run(&["w.####.raw", "--frames", "1-2", "-o", "g.####.pin"]);
    for f in ["0001", "0002"] {
        let single = format!("single.{f}.pin");
        run(&[&format!("w.{f}.raw"), "-o", &single]);
        let read = |n: &str| std::fs::read(dir.path().join(n)).unwrap();
        assert_eq!(read(&format!("g.{f}.pin")), read(&single), "frame {f}");
    }
}

/// No adapter (`WGPU_BACKEND` names a backend this machine lacks): one line naming the
/// problem, exit 1, no output.
#[test]
fn no_adapter_is_one_line_and_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("never.pin");
    let o = pinbake()
        .env(
            "WGPU_BACKEND",
            if cfg!(target_os = "macos") {
                "dx12"
            } else {
                "metal"
            },
        )
        .arg("bake")
        .arg(data("water_esp_31x34x33_float32.raw"))
        .args([
            "--clamp-negative",
            "--cells",
            "4",
            "--backend",
            "gpu",
            "-q",
            "-o",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let lines: Vec<&str> = err
        .lines()
        .filter(|l| !l.contains("XDG_RUNTIME_DIR"))
        .collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].contains("no GPU adapter found"), "{err}");
    assert!(!out.exists());
}

/// A device lost in the middle of a bake (destroyed after its first slab's dispatch): one
/// line, exit 1, no output, and an existing output file left as it was.
#[test]
fn a_device_lost_mid_bake_is_one_line_and_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let kept = dir.path().join("kept.pin");
    std::fs::write(&kept, b"not replaced").unwrap();
    let fresh = dir.path().join("fresh.pin");
    for out in [&kept, &fresh] {
        let o = pinbake()
            .arg("bake")
            .arg(data("water_esp_31x34x33_float32.raw"))
            .args(["--clamp-negative", "--cells", "4", "--backend", "gpu", "-q"])
            .args([
                "--gpu-slab-bytes",
                "20000",
                "--gpu-lose-device-after",
                "1",
                "-o",
            ])
            .arg(out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        let lines: Vec<&str> = err
            .lines()
            .filter(|l| !l.contains("XDG_RUNTIME_DIR"))
            .collect();
        assert_eq!(lines.len(), 1, "{err}");
        assert!(lines[0].contains("the GPU device was lost"), "{err}");
    }
    assert_eq!(std::fs::read(&kept).unwrap(), b"not replaced");
    assert!(!fresh.exists());
    let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(names.len(), 1, "{names:?}");
}
