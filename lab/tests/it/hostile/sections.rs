//! Pin files whose sections a render reads (sparse density, dense density, majorant,
//! control): a damaged payload whose values stay in range is refused by the CPU and the GPU
//! render with one line naming the file (once) and the section; a file that carries both
//! densities renders the same one on both backends; the camera and phase flags' ranges are
//! usage errors naming the flag.

use std::path::{Path, PathBuf};

use half::f16;
use pin_format::layout::DENSITY_F16;
use pin_format::{
    DensityHeader, Directions, MajorantHeader, OwnedControl, OwnedPinGrid, OwnedSparseDensity,
    OwnedSparseValues, PinEntry, PinFile, SectionKind, SparseDensityHeader, grid_desc,
};

use super::{Run, expect, run};

/// Voxels per axis of the embedded densities; bricks of 4, all stored.
const N: u32 = 8;

/// A pin file over the unit box (one cell, one direction cell, an empty pin) with the
/// sections given: a dense density of `dense`, a sparse density of `sparse`, a majorant and
/// a control section (2^3 bricks) that bound both.
fn pin_file(dense: Option<f32>, sparse: Option<f32>) -> OwnedPinGrid {
    let voxels = (N * N * N) as usize;
    let bound = dense.unwrap_or(0.0).max(sparse.unwrap_or(0.0)) * 2.0 + 1.0;
    OwnedPinGrid {
        desc: grid_desc([1, 1, 1], Directions::Octahedral { n: 1 }, 1, 1),
        tile: None,
        cell_index: None,
        pins: vec![PinEntry::EMPTY; 1],
        majorant: Some((
            MajorantHeader {
                dims: [2; 3],
                reserved: 0,
            },
            vec![bound; 8],
        )),
        density: dense.map(|v| {
            (
                DensityHeader {
                    dims: [N; 3],
                    encoding: DENSITY_F16,
                },
                vec![f16::from_f32(v); voxels],
            )
        }),
        sparse_density: sparse.map(|v| OwnedSparseDensity {
            header: SparseDensityHeader {
                dims: [N; 3],
                encoding: DENSITY_F16,
                brick: 4,
                brick_count: 8,
                reserved: [0; 2],
            },
            index: (0..8).collect(),
            values: OwnedSparseValues::F16(vec![f16::from_f32(v); voxels]),
        }),
        control: Some(OwnedControl {
            dims: [2; 3],
            control: vec![1.0; 8],
            residual: vec![bound; 8],
            majorant: vec![bound; 8],
        }),
        metadata: None,
    }
}

fn write(grid: &OwnedPinGrid, path: &Path) -> Vec<u8> {
    let bytes = grid.to_bytes().unwrap();
    std::fs::write(path, &bytes).unwrap();
    bytes
}

/// `bytes` with the low byte of the last value of `kind` flipped in its lowest bit: a
/// value a few ulps away, in range (finite, `>= 0`, the control's rules kept).
fn damaged(bytes: &[u8], kind: SectionKind) -> Vec<u8> {
    let file = PinFile::parse(bytes).unwrap();
    let s = file
        .sections()
        .iter()
        .find(|s| s.kind == kind as u32)
        .unwrap();
    let elem = match kind {
        SectionKind::Density | SectionKind::SparseDensity => 2,
        _ => 4,
    };
    let mut out = bytes.to_vec();
    out[(s.offset + s.length) as usize - elem] ^= 0x01;
    // The damage is what verify reports, and nothing parse sees.
    let e = PinFile::parse(&out)
        .unwrap()
        .verify()
        .unwrap_err()
        .to_string();
    assert!(e.contains("checksum") && e.contains(kind.name()), "{e}");
    out
}

fn render_pins(pins: &Path, estimator: &str, backend: &str, out: &Path, home: &Path) -> Run {
    run(
        &[
            "render",
            "--pins",
            pins.to_str().unwrap(),
            "--estimator",
            estimator,
            "--backend",
            backend,
            "--width",
            "8",
            "--height",
            "8",
            "--spp",
            "1",
            "--threads",
            "1",
            "--out",
            out.to_str().unwrap(),
        ],
        home,
    )
}

/// One error line naming `path` exactly once.
fn names_path_once(name: &str, r: &Run, path: &Path) {
    let err = r.stderr();
    assert_eq!(
        err.matches(path.to_str().unwrap()).count(),
        1,
        "{name}: the path not exactly once: {err}"
    );
}

#[test]
fn damaged_sections_that_stay_in_range_are_refused_by_every_render() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A: dense density (the only one, so it is read); B: sparse density.
    let dense = write(&pin_file(Some(2.0), None), &d.join("dense.pin"));
    let sparse = write(&pin_file(None, Some(2.0)), &d.join("sparse.pin"));
    let cases: [(&str, &[u8], SectionKind, &str); 4] = [
        ("sparse", &sparse, SectionKind::SparseDensity, "ratio"),
        ("dense", &dense, SectionKind::Density, "ratio"),
        ("dense", &dense, SectionKind::Majorant, "ratio"),
        ("dense", &dense, SectionKind::Control, "pinres"),
    ];
    // The undamaged files render, so that each refusal below is the damage's: once per file,
    // estimator and backend (the density and majorant cases share the dense file and ratio
    // tracking; each GPU render is a process that compiles its pipelines).
    let mut rendered = std::collections::BTreeSet::new();
    for (file, clean, _, estimator) in cases {
        if !rendered.insert((file, estimator)) {
            continue;
        }
        let clean_path = d.join(format!("clean-{file}.pin"));
        std::fs::write(&clean_path, clean).unwrap();
        for backend in ["cpu", "gpu"] {
            let case = format!("clean {file} {estimator} {backend}");
            let out = d.join(format!("clean-{file}-{estimator}-{backend}.png"));
            let r = render_pins(&clean_path, estimator, backend, &out, d);
            assert_eq!(r.out.status.code(), Some(0), "{case}: {}", r.stderr());
            assert!(out.exists(), "{case}");
        }
    }
    for (_, clean, kind, estimator) in cases {
        let name = kind.name();
        let path = d.join(format!("damaged-{name}.pin"));
        std::fs::write(&path, damaged(clean, kind)).unwrap();
        for backend in ["cpu", "gpu"] {
            let case = format!("{name} {estimator} {backend}");
            let out = d.join(format!("{name}-{backend}.png"));
            let r = render_pins(&path, estimator, backend, &out, d);
            expect(
                &case,
                &r,
                1,
                &format!("checksum mismatch in section '{name}'"),
            );
            names_path_once(&case, &r, &path);
            assert!(!out.exists(), "{case}: wrote an image");
        }
    }
}

/// A file with both densities, made to differ: the dense one empty, the sparse one opaque.
/// Both backends render the sparse one: with albedo 0 and no sun, the centre pixel (whose
/// ray crosses the box) is black, where the empty medium would show the environment.
#[test]
fn a_file_with_both_densities_renders_the_sparse_one_on_cpu_and_gpu() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let both = d.join("both.pin");
    write(&pin_file(Some(0.0), Some(2000.0)), &both);
    for backend in ["cpu", "gpu"] {
        let out = d.join(format!("both-{backend}.exr"));
        let r = run(
            &[
                "render",
                "--pins",
                both.to_str().unwrap(),
                "--estimator",
                "ratio",
                "--backend",
                backend,
                "--width",
                "9",
                "--height",
                "9",
                "--spp",
                "4",
                "--albedo",
                "0",
                "--sun-radiance",
                "0",
                "--env-radiance",
                "1",
                "--camera-origin",
                "0.5,0.5,3",
                "--camera-target",
                "0.5,0.5,0.5",
                "--out",
                out.to_str().unwrap(),
            ],
            d,
        );
        assert_eq!(r.out.status.code(), Some(0), "{backend}: {}", r.stderr());
        let img = pinrender::render::Image::read_exr(&out).unwrap();
        let centre = img.rgb[4 * 9 + 4];
        let corner = img.rgb[0];
        assert!(
            centre.iter().all(|&c| c < 1e-3),
            "{backend}: centre {centre:?}: not the opaque sparse density"
        );
        assert!(
            corner.iter().all(|&c| (c - 1.0).abs() < 1e-3),
            "{backend}: corner {corner:?}: not the environment"
        );
    }
}

#[test]
fn camera_and_phase_ranges_are_usage_errors_naming_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("o.png");
    let cases: &[(&[&str], &str)] = &[
        (&["--fov", "0"], "--fov"),
        (&["--fov", "180"], "--fov"),
        (&["--g", "2"], "--g"),
        (&["--g", "-1"], "--g"),
        (&["--albedo", "1.5"], "--albedo"),
        (&["--sun-dir", "0,0,0"], "--sun-dir"),
        (&["--sun-dir", "1e-300"], "--sun-dir"),
        (
            &["--backend", "gpu", "--max-bounces", "100000"],
            "--max-bounces",
        ),
    ];
    for (extra, flag) in cases {
        let mut args = vec![
            "render",
            "--volume",
            "procedural:box",
            "--width",
            "512",
            "--height",
            "512",
            "--spp",
            "100000",
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend(*extra);
        let r = run(&args, d);
        expect(&format!("{extra:?}"), &r, 2, flag);
        assert!(!out.exists());
    }
    // Negative values are values, not flags.
    let args = [
        "render",
        "--volume",
        "procedural:box",
        "--width",
        "4",
        "--height",
        "4",
        "--spp",
        "1",
        "--g",
        "-0.5",
        "--sun-dir",
        "-1,0.5,0",
        "--camera-origin",
        "-2,0.5,0.5",
        "--camera-target",
        "-0.5,0.5,0.5",
        "--out",
        out.to_str().unwrap(),
    ];
    let r = run(&args, d);
    assert_eq!(r.out.status.code(), Some(0), "{}", r.stderr());
    std::fs::remove_file(&out).unwrap();
    // The GPU's limit is named.
    let r = run(
        &[
            "render",
            "--volume",
            "procedural:box",
            "--backend",
            "gpu",
            "--max-bounces",
            "1025",
            "--out",
            out.to_str().unwrap(),
        ],
        d,
    );
    expect("--max-bounces 1025", &r, 2, "1024");
}

#[test]
fn a_truncated_pin_file_is_named_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let bytes = pin_file(Some(1.0), None).to_bytes().unwrap();
    let path: PathBuf = d.join("cut.pin");
    std::fs::write(&path, &bytes[..bytes.len() - 7]).unwrap();
    let out = d.join("o.png");
    for estimator in ["ratio", "pins"] {
        let r = render_pins(&path, estimator, "cpu", &out, d);
        expect(estimator, &r, 1, "truncated");
        names_path_once(estimator, &r, &path);
    }
}
