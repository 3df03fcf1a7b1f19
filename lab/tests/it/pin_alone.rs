//! `pinrender render` from a pin file alone (no `--volume`), and the check that `--pins`
//! belong to `--volume` (the source identity a bake records).

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use pin_format::Metadata;
use pin_volume::{DensitySource, ProceduralSpec, SourceIdentity};

const BIN: &str = env!("CARGO_BIN_EXE_pinrender");
const COSINE: &str = "procedural:cosine:seed=5,freq=4,density=6";
/// The camera of every render here: in front of the unit box, looking at its centre.
const CAMERA: [&str; 4] = [
    "--camera-origin",
    "0.5,0.6,2.6",
    "--camera-target",
    "0.5,0.5,0.5",
];

fn source(scale: f64) -> Box<dyn DensitySource> {
    let mut p: ProceduralSpec = COSINE["procedural:".len()..].parse().unwrap();
    p.density *= scale;
    p.build(pin_volume::DensityScale::ONE).unwrap()
}

/// Bakes the cosine field scaled by `scale` as `pinbake bake` does (identity in the metadata
/// unless `identity` is false; `embed` density voxels per axis, if any).
fn bake(dir: &Path, name: &str, scale: f64, embed: Option<u32>, identity: bool) -> PathBuf {
    let src = source(scale);
    let extra = if identity {
        SourceIdentity::of(src.as_ref(), scale).to_extra()
    } else {
        Vec::new()
    };
    let opts = pinbake::BakeOptions {
        cells: [8; 3],
        density_scale: scale,
        embed_density: embed.map(|n| pinbake::EmbedDensity::Dense([n; 3])),
        majorant: Some([8; 3]),
        metadata: Metadata {
            extra,
            ..Metadata::default()
        },
        ..pinbake::BakeOptions::default()
    };
    let (grid, _) = pinbake::bake(src.as_ref(), &opts, &|_| {}).unwrap();
    let path = dir.join(name);
    grid.write_atomic(&path).unwrap();
    path
}

/// [`bake`] with a sparse, bricked density of `n^3` voxels instead of a dense one.
fn bake_sparse(dir: &Path, name: &str, n: u32) -> PathBuf {
    let src = source(1.0);
    let opts = pinbake::BakeOptions {
        cells: [8; 3],
        embed_density: Some(pinbake::EmbedDensity::Sparse(
            pinbake::sparse_density::SparseDims::Exact([n; 3]),
        )),
        majorant: Some([8; 3]),
        metadata: Metadata {
            extra: SourceIdentity::of(src.as_ref(), 1.0).to_extra(),
            ..Metadata::default()
        },
        ..pinbake::BakeOptions::default()
    };
    let (grid, _) = pinbake::bake(src.as_ref(), &opts, &|_| {}).unwrap();
    let path = dir.join(name);
    grid.write_atomic(&path).unwrap();
    path
}

/// Rewrites every section, table and header checksum of a pin file, so that a planted lie
/// reaches the checks behind them.
fn reseal(b: &mut [u8]) {
    let u32_at = |b: &[u8], at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap());
    let u64_at =
        |b: &[u8], at: usize| u64::from_le_bytes(b[at..at + 8].try_into().unwrap()) as usize;
    let (count, table) = (u32_at(b, 16) as usize, u64_at(b, 24));
    for i in 0..count {
        let e = table + 32 * i;
        let (off, len) = (u64_at(b, e + 8), u64_at(b, e + 16));
        let c = pin_format::checksum(&b[off..off + len]);
        b[e + 24..e + 32].copy_from_slice(&c.to_le_bytes());
    }
    let c = pin_format::checksum(&b[table..table + 32 * count]);
    b[48..56].copy_from_slice(&c.to_le_bytes());
    let c = pin_format::checksum(&b[..56]);
    b[56..64].copy_from_slice(&c.to_le_bytes());
}

#[test]
fn a_sparse_density_renders_alone_like_the_dense_one_and_a_lying_index_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let dense = bake(d, "dense.pin", 1.0, Some(32), true);
    let sparse = bake_sparse(d, "sparse.pin", 32);
    let reference = d.join("ref.exr");
    let r = reference.to_str().unwrap();
    let mut args = vec!["--pins", dense.to_str().unwrap(), "--estimator", "ratio"];
    args.extend(["--spp", "64"]);
    args.extend(CAMERA);
    args.extend(["--out", r]);
    expect(&render(&args), 0, "rendered");
    // The same f16 voxels bricked: the trackers see the same field, so the images agree to
    // the noise of two 64-spp renders (seeds are equal, so mostly far better).
    for est in ["ratio", "pinms"] {
        let out = d.join(format!("s-{est}.exr"));
        let mut args = vec!["--pins", sparse.to_str().unwrap(), "--estimator", est];
        args.extend(["--spp", "64"]);
        args.extend(CAMERA);
        args.extend(["--out", out.to_str().unwrap(), "--reference", r]);
        let e = mean_error(&render(&args));
        assert!(e.abs() < 0.01, "{est}: sparse vs dense mean error {e}");
    }
    // The trackers read the sparse section's f16 values in place, from the file's mapping.
    let grid = std::sync::Arc::new(pinrt::PinGrid::open(&sparse).unwrap());
    let medium = pinrender::volume::pin_file_medium(&sparse, &grid).unwrap();
    let bricks = medium.bricks.expect("bricks");
    let pin_format::SparseValues::F16(values) = bricks.parts().1 else {
        panic!("the f16 values were widened");
    };
    let mapped = grid.bytes().as_ptr_range();
    assert!(
        mapped.contains(&values.as_ptr().cast()),
        "the values were copied"
    );
    // The memory check of a pin file alone is 3x its length (mapped; a dense section is
    // widened to f32), not the 8x of a VDB: a budget between the two renders, one below
    // refuses.
    let len = std::fs::metadata(&sparse).unwrap().len();
    for (budget, code, needle) in [(len * 4, 0, "rendered"), (len * 2, 1, "reading")] {
        let out = d.join("budget.exr");
        let budget = budget.to_string();
        let mut args = vec!["--pins", sparse.to_str().unwrap(), "--estimator", "ratio"];
        args.extend(["--spp", "1", "--max-memory", &budget]);
        args.extend(CAMERA);
        args.extend(["--out", out.to_str().unwrap()]);
        expect(&render(&args), code, needle);
    }
    // A brick index entry past the stored bricks (checksums resealed): one line naming the
    // file and the section.
    let mut b = std::fs::read(&sparse).unwrap();
    let u64_at = |at: usize| u64::from_le_bytes(b[at..at + 8].try_into().unwrap()) as usize;
    let (count, table) = (
        u32::from_le_bytes(b[16..20].try_into().unwrap()) as usize,
        u64_at(24),
    );
    let off = (0..count)
        .map(|i| table + 32 * i)
        .find(|&e| u32::from_le_bytes(b[e..e + 4].try_into().unwrap()) == 8)
        .map(|e| u64_at(e + 8))
        .expect("a sparse density section");
    let stored = u32::from_le_bytes(b[off + 20..off + 24].try_into().unwrap());
    let entries = off + 32;
    let first = (0..)
        .map(|i| entries + 4 * i)
        .find(|&at| u32::from_le_bytes(b[at..at + 4].try_into().unwrap()) != u32::MAX)
        .unwrap();
    b[first..first + 4].copy_from_slice(&(stored + 3).to_le_bytes());
    reseal(&mut b);
    let lying = d.join("lying.pin");
    std::fs::write(&lying, &b).unwrap();
    let out = d.join("never.exr");
    let r = render(&[
        "--pins",
        lying.to_str().unwrap(),
        "--estimator",
        "ratio",
        "--out",
        out.to_str().unwrap(),
    ]);
    expect(&r, 1, "lying.pin");
    assert!(stderr(&r).contains("slot"), "{}", stderr(&r));
    assert!(!out.exists());
}

/// On the GPU a sparse-only pin file renders as the dense section of the same bake does (the
/// same f16 voxels; at this size through their dense expansion, above one storage binding
/// through the bricks, which `gpu_render`'s tests compare with the dense path).
#[test]
fn a_sparse_density_renders_on_the_gpu_with_the_dense_sections_bits() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let dense = bake(d, "dense.pin", 1.0, Some(32), true);
    let sparse = bake_sparse(d, "sparse.pin", 32);
    for est in ["ratio", "pinms"] {
        let mut images = Vec::new();
        for (name, pins) in [("d", &dense), ("s", &sparse)] {
            let out = d.join(format!("gpu-{name}-{est}.exr"));
            let mut args = vec!["--pins", pins.to_str().unwrap(), "--estimator", est];
            args.extend(["--spp", "8", "--backend", "gpu"]);
            args.extend(CAMERA);
            args.extend(["--out", out.to_str().unwrap()]);
            expect(&render(&args), 0, "rendered");
            images.push(std::fs::read(&out).unwrap());
        }
        assert!(images[0] == images[1], "{est}: the bricked image differs");
    }
}

/// `pinres` renders from a pin file alone on the GPU (its control section, its dense density
/// section): the image mean agrees with the CPU's within 2% at 64 spp (the per-pixel
/// statistics are tested in `pinrender::gpu_render`), and a file without a control section
/// is refused on the GPU as on the CPU, with one line.
#[test]
fn pinres_renders_from_a_pin_file_on_the_gpu() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let src = source(1.0);
    let opts = pinbake::BakeOptions {
        cells: [8; 3],
        embed_density: Some(pinbake::EmbedDensity::Dense([32; 3])),
        embed_control: Some(pinbake::control::ControlOptions::default()),
        majorant: Some([8; 3]),
        ..pinbake::BakeOptions::default()
    };
    let (grid, _) = pinbake::bake(src.as_ref(), &opts, &|_| {}).unwrap();
    let with = d.join("control.pin");
    grid.write_atomic(&with).unwrap();
    let mut means = Vec::new();
    for backend in ["cpu", "gpu"] {
        let out = d.join(format!("{backend}.exr"));
        let mut args = vec!["--pins", with.to_str().unwrap(), "--estimator", "pinres"];
        args.extend(["--spp", "64", "--albedo", "0.8", "--backend", backend]);
        args.extend(CAMERA);
        args.extend(["--out", out.to_str().unwrap()]);
        expect(&render(&args), 0, "rendered");
        let img = pinrender::render::Image::read_exr(&out).unwrap();
        let grey = img
            .rgb
            .iter()
            .map(|p| p.iter().map(|&c| f64::from(c)).sum::<f64>() / 3.0);
        means.push(grey.sum::<f64>() / img.rgb.len() as f64);
    }
    let rel = (means[1] - means[0]).abs() / means[0];
    eprintln!(
        "pinres from a pin file: image mean cpu {} gpu {} (rel {rel})",
        means[0], means[1]
    );
    assert!(
        means[0] > 0.01 && rel < 0.02,
        "cpu {} gpu {} (rel {rel})",
        means[0],
        means[1]
    );
    let without = bake(d, "plain.pin", 1.0, Some(32), true);
    for backend in ["cpu", "gpu"] {
        let out = d.join(format!("refused-{backend}.exr"));
        let mut args = vec!["--pins", without.to_str().unwrap(), "--estimator", "pinres"];
        args.extend(["--backend", backend, "--out", out.to_str().unwrap()]);
        expect(&render(&args), 1, "no control section");
        assert!(!out.exists());
    }
}

fn render(args: &[&str]) -> Output {
    Command::new(BIN)
        .arg("render")
        .args(["--width", "24", "--height", "24", "--threads", "1"])
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .stdin(Stdio::null())
        .output()
        .expect("run pinrender")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn expect(o: &Output, code: i32, needle: &str) {
    let e = stderr(o);
    assert_eq!(o.status.code(), Some(code), "{e}");
    if code != 0 {
        assert_eq!(e.trim_end().lines().count(), 1, "one line: {e}");
    }
    assert!(e.contains(needle), "expected '{needle}' in: {e}");
}

/// `mean_error` of a render against `reference` (printed on stdout).
fn mean_error(o: &Output) -> f64 {
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", stderr(o));
    out.split_whitespace()
        .skip_while(|w| *w != "mean_error")
        .nth(1)
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no mean_error in {out}"))
}

#[test]
fn every_estimator_renders_from_the_pin_file_alone_and_agrees_with_the_volume() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let pins = bake(d, "c.pin", 1.0, Some(32), true);
    let p = pins.to_str().unwrap();
    // The volume's camera frames the source box; the pin file's frames its (cropped) grid
    // box: one explicit camera for both.
    let reference = d.join("ref.exr");
    let r = reference.to_str().unwrap();
    let mut args = vec!["--volume", COSINE, "--estimator", "ratio", "--spp", "64"];
    args.extend(CAMERA);
    args.extend(["--out", r]);
    expect(&render(&args), 0, "rendered");
    // The pin estimators carry the pin model's bias; the source-free trackers only the f16
    // copy's at 32^3. At 64 spp on 24^2 pixels the image mean's noise is ~1e-3.
    for (est, bound) in [
        ("ratio", 0.01),
        ("delta", 0.01),
        ("rm@0.01", 0.01),
        ("pinms", 0.03),
        ("pins", 0.06),
    ] {
        let out = d.join(format!("{est}.exr"));
        let mut args = vec!["--pins", p, "--estimator", est, "--spp", "64"];
        args.extend(CAMERA);
        args.extend(["--out", out.to_str().unwrap(), "--reference", r]);
        let e = mean_error(&render(&args));
        assert!(
            e.abs() < bound,
            "{est}: mean error {e} against the volume's render"
        );
    }
    // The mutation the comparison must catch: pins of twice the density.
    let dense = bake(d, "dense.pin", 2.0, Some(32), true);
    let out = d.join("dense.exr");
    let mut args = vec!["--pins", dense.to_str().unwrap(), "--estimator", "ratio"];
    args.extend(["--spp", "64"]);
    args.extend(CAMERA);
    args.extend(["--out", out.to_str().unwrap(), "--reference", r]);
    let e = mean_error(&render(&args));
    assert!(e.abs() > 0.05, "twice the density went unnoticed: {e}");
}

#[test]
fn missing_density_mismatched_and_old_pins() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("o.exr");
    let o = out.to_str().unwrap();
    let bare = bake(d, "bare.pin", 1.0, None, true);
    let b = bare.to_str().unwrap();
    // Pins need nothing else; the trackers need the embedded density.
    expect(
        &render(&["--pins", b, "--estimator", "pins", "--spp", "1", "--out", o]),
        0,
        "rendered",
    );
    for est in ["pinms", "ratio", "delta", "rm@0.05"] {
        let r = render(&["--pins", b, "--estimator", est, "--out", o]);
        expect(&r, 1, "no embedded density");
        assert!(stderr(&r).contains("bare.pin"));
    }
    // Volume flags without a volume are usage errors.
    expect(
        &render(&["--pins", b, "--density-scale", "2", "--out", o]),
        2,
        "--density-scale",
    );
    // Pins of another density scale (another content too), then of another field.
    let scaled = bake(d, "scaled.pin", 2.0, None, true);
    let s = scaled.to_str().unwrap();
    let args = [
        "--volume",
        COSINE,
        "--pins",
        s,
        "--estimator",
        "pins",
        "--spp",
        "1",
    ];
    let r = render(&[&args[..], &["--out", o]].concat());
    expect(&r, 1, "density scale 2.0 vs 1.0");
    assert!(stderr(&r).contains("scaled.pin") && stderr(&r).contains(COSINE));
    assert!(stderr(&r).contains("--allow-mismatched-pins"));
    let r = render(&[&args[..], &["--allow-mismatched-pins", "--out", o]].concat());
    expect(&r, 0, "rendering anyway");
    let box_args = [
        "--volume",
        "procedural:box",
        "--pins",
        b,
        "--estimator",
        "pinms",
    ];
    expect(
        &render(&[&box_args[..], &["--out", o]].concat()),
        1,
        "density content",
    );
    // The matching volume passes silently; a file without identity passes with a warning.
    let args = [
        "--volume",
        COSINE,
        "--pins",
        b,
        "--estimator",
        "pins",
        "--spp",
        "1",
    ];
    let r = render(&[&args[..], &["--out", o]].concat());
    expect(&r, 0, "rendered");
    assert!(!stderr(&r).contains("warning"), "{}", stderr(&r));
    let old = bake(d, "old.pin", 2.0, None, false);
    let args = [
        "--volume",
        COSINE,
        "--pins",
        old.to_str().unwrap(),
        "--estimator",
        "pins",
    ];
    let r = render(&[&args[..], &["--spp", "1", "--out", o]].concat());
    expect(&r, 0, "records no source identity");
}
