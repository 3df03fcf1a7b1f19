//! `pinrender eval --bytes`: image error against the bytes of the file a user ships.
//!
//! For each scene: the converged ratio-tracking reference of the full-resolution source
//! volume (the eval's reference, cached the same way), then, for each [`Representation`], a
//! ladder of bakes: each rung is baked, written to a file and measured by that file's size
//! (what a user would ship), then rendered from the file alone (no `--volume`) with the
//! representation's estimator at a fixed sample count, and compared with the reference:
//! mean relative error and 8x8-block relative error ([`block_bias`]), and RMSE. The source
//! file itself, rendered with ratio tracking at the same samples, is a reference point of its
//! own (its error is the noise floor of that sample count).
//!
//! Outputs (in `--out`), a contract: `bytes.csv` (header [`BYTES_HEADER`]), `bytes.png`
//! (block error against bytes, log-log, one curve per representation, one panel per scene)
//! and `bytes.md` (the tables and which representation wins at which size).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, anyhow};
use pin_volume::DensitySource;
use pinbake::sparse_density::SparseDims;
use pinbake::{BakeOptions, EmbedDensity};
use pinrender::medium::MediumDesc;
use pinrender::render::{
    Budget, DEFAULT_WAVEFRONT_BATCH, EstimatorSpec, Image, Medium, RatioTracking, SampleLoop,
    TransportEstimator, block_bias, render, render_wavefront, rmse,
};
use pinrender::volume::OpenedMedium;
use pinrt::{Directions, SamplerOptions};

use super::scenes::{self, EvalScene, Sizes};
use super::{EvalArgs, LOOKUP, pass_seed, scene_with, settings};

/// The CSV's name and header (a contract that scripts rely on).
pub const BYTES_CSV: &str = "bytes.csv";
pub const BYTES_HEADER: &str =
    "scene,representation,bytes,mean_error,block8_error,rmse,seconds_per_spp";
pub const BYTES_PNG: &str = "bytes.png";
pub const BYTES_MD: &str = "bytes.md";

/// The scenes `--bytes` runs without `--scenes`: the bundled volumes (the production cloud
/// with `--scenes production`).
pub const BYTES_SCENES: [&str; 2] = ["smoke", "hydrogen"];
/// The quick run's scene.
pub const QUICK_BYTES_SCENES: [&str; 1] = ["smoke"];
/// The scenes whose one medium is a volume file (a source with voxels, and a file size).
pub const VOLUME_SCENES: [&str; 3] = ["smoke", "hydrogen", "production"];

/// How many samples, the image size and the reference's samples of a run.
#[derive(Clone, Copy, Debug)]
pub struct BytesSizes {
    pub image: u32,
    /// Samples per pixel of every representation's render.
    pub spp: u32,
    /// Samples per pixel of the reference.
    pub ref_spp: u32,
    pub max_bounces: u32,
    /// Longest-axis voxels of the density ladders (capped at the source's own).
    pub voxels: &'static [u32],
    /// Spatial cells per axis of the pin ladders.
    pub cells: &'static [u32],
    /// Octahedral direction sets (n x n) of the pins-alone representations.
    pub octahedral: &'static [u32],
}

impl BytesSizes {
    /// 128 px, 128 spp against a reference of 1024: a block error floor of about 0.3% on
    /// the bundled volumes, at a cost a shared 2-core machine affords.
    pub fn full() -> Self {
        Self {
            image: 128,
            spp: 128,
            ref_spp: 1024,
            max_bounces: 8,
            voxels: &[16, 32, 64, 128],
            cells: &[4, 8, 16, 24],
            octahedral: &[4, 8, 16],
        }
    }

    /// What the main job runs: 32 px, three rungs per ladder.
    pub fn quick() -> Self {
        Self {
            image: 32,
            spp: 32,
            ref_spp: 512,
            max_bounces: 4,
            voxels: &[8, 16, 32],
            cells: &[4, 8, 16],
            octahedral: &[8],
        }
    }
}

/// The embedded density of the density ladders.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Density {
    /// Dense f16 voxels, this many on the longest axis.
    Dense,
    /// Sparse f16 bricks, this many voxels on the longest axis.
    Sparse,
}

/// One way of spending bytes: what its files hold, rendered from the file alone with
/// `estimator`. Its rungs differ in one size (cells, or density voxels) and grow with it.
struct Representation {
    name: String,
    estimator: EstimatorSpec,
    rungs: Vec<BakeOptions>,
    /// A pin-format experiment applied to the baked grid before it is written
    /// (`--pin-variants`); its bytes are then the file's size less what the variant's format
    /// would save.
    variant: Option<PinVariant>,
    /// The pins' lookup options (`pinrender render`'s defaults but for the lookup
    /// experiments).
    lookup: SamplerOptions,
}

/// Pins-per-byte experiments measured in memory, before any format change: the entries are
/// changed as the candidate format would store them, the file keeps today's layout, and the
/// row's bytes are those of the candidate format (`projected` in the name).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PinVariant {
    /// `t_min` as 16 bits: the f16 of its optical depth `-ln t_min` (entries of 6 bytes).
    TauF16,
    /// `t_min` as 8 bits: its optical depth on a log scale of 254 steps over
    /// [[`TAU_LO`], [`TAU_HI`]], 0 for T = 1 and 255 for T = 0 (entries of 5 bytes).
    TauU8,
    /// Entries whose whole chord has T >= 1 - [`NEAR_ONE`] left out (read as empty), with a
    /// presence bit per entry of each stored cell.
    DropNearOne,
}

/// The 8-bit optical depth scale's ends.
pub const TAU_LO: f64 = 1e-4;
pub const TAU_HI: f64 = 50.0;
/// How close to T = 1 an entry's `t_min` must be to be left out.
pub const NEAR_ONE: f32 = 1e-3;

impl PinVariant {
    /// Changes `grid`'s entries as the variant's format would store them; the bytes that
    /// format saves against today's.
    fn apply(self, grid: &mut pin_format::OwnedPinGrid) -> u64 {
        let n = grid.pins.len() as u64;
        match self {
            PinVariant::TauF16 => {
                for p in &mut grid.pins {
                    p.t_min = requantize(p.t_min, p.mask, |tau| half::f16::from_f64(tau).to_f64());
                }
                2 * n
            }
            PinVariant::TauU8 => {
                for p in &mut grid.pins {
                    p.t_min = requantize(p.t_min, p.mask, tau_u8);
                }
                3 * n
            }
            PinVariant::DropNearOne => {
                let mut dropped = 0u64;
                for p in &mut grid.pins {
                    if p.t_min >= 1.0 - NEAR_ONE {
                        *p = pin_format::PinEntry::EMPTY;
                        dropped += 1;
                    }
                }
                // The presence bits: one per stored entry.
                (8 * dropped).saturating_sub(n.div_ceil(8))
            }
        }
    }
}

/// `t_min` through `quantize` of its optical depth, keeping T = 0 and T = 1 exact and an
/// entry with interval bits below 1 (the format's rule: `t_min == 1` only with mask 0).
fn requantize(t_min: f32, mask: u32, quantize: impl Fn(f64) -> f64) -> f32 {
    if t_min <= 0.0 || t_min >= 1.0 {
        return t_min;
    }
    let t = (-quantize(-f64::from(t_min).ln())).exp() as f32;
    if mask != 0 && t >= 1.0 {
        1.0 - f32::EPSILON / 2.0
    } else {
        t.clamp(0.0, 1.0)
    }
}

/// The 8-bit code's optical depth nearest (on the log scale) to `tau`.
fn tau_u8(tau: f64) -> f64 {
    let steps = 254.0;
    let span = (TAU_HI / TAU_LO).ln();
    let code = ((tau.clamp(TAU_LO, TAU_HI) / TAU_LO).ln() / span * (steps - 1.0)).round();
    TAU_LO * (code / (steps - 1.0) * span).exp()
}

/// One measured rung.
#[derive(Clone, Debug)]
pub struct BytesRow {
    pub scene: String,
    pub representation: String,
    pub bytes: u64,
    pub mean_error: f64,
    pub block8_error: f64,
    pub rmse: f64,
    pub seconds_per_spp: f64,
}

/// The representation of the source file itself (ratio tracking of the full volume).
pub const SOURCE_FILE: &str = "source file (ratio)";

/// The density voxels per axis for `longest` voxels on the longest axis of `extent`.
fn dims_for(extent: [f64; 3], longest: u32) -> [u32; 3] {
    let max = extent.iter().cloned().fold(0.0f64, f64::max).max(1e-30);
    extent.map(|e| ((e / max * f64::from(longest)).round() as u32).clamp(1, 4096))
}

/// The source's own voxels on its occupied box's longest axis (`None`: no voxels).
fn source_longest(src: &dyn DensitySource) -> Option<(u32, [f64; 3])> {
    let b = src.occupied_bounds().unwrap_or_else(|| src.bounds());
    let extent = (b.max - b.min).to_array();
    let v = src.voxel_size()?.to_array();
    let n = (0..3)
        .map(|a| (extent[a] / v[a]).round())
        .fold(0.0f64, f64::max);
    Some(((n as u32).clamp(1, 4096), extent))
}

/// The representations a run measures. Adding one (another density form, a pin variant) is
/// one entry here.
fn representations(src: &dyn DensitySource, s: &BytesSizes, a: &EvalArgs) -> Vec<Representation> {
    let base = BakeOptions {
        seed: a.seed,
        threads: a.threads,
        ..BakeOptions::default()
    };
    let oct = |n: u32| Directions::Octahedral { n };
    let pins = |cells: u32, n: u32| BakeOptions {
        cells: [cells; 3],
        directions: oct(n),
        ..base.clone()
    };
    // The density ladders: the sizes below the source's own, then the source's own.
    let (own, extent) = source_longest(src).unwrap_or((64, [1.0; 3]));
    let mut voxels: Vec<u32> = s.voxels.iter().copied().filter(|&n| n < own).collect();
    if s.voxels.iter().any(|&n| n >= own) {
        voxels.push(own);
    }
    // A density file: the smallest pin grid beside it (2^3 cells, one direction cell).
    let density = |kind: Density, n: u32, with: BakeOptions| BakeOptions {
        embed_density: Some(match kind {
            Density::Dense => EmbedDensity::Dense(dims_for(extent, n)),
            Density::Sparse => EmbedDensity::Sparse(SparseDims::Max(n)),
        }),
        ..with
    };
    let tiny = pins(2, 1);
    let mut out: Vec<Representation> = s
        .octahedral
        .iter()
        .map(|&n| Representation {
            name: format!("pins oct:{n}"),
            estimator: EstimatorSpec::Pins,
            rungs: s.cells.iter().map(|&c| pins(c, n)).collect(),
            variant: None,
            lookup: LOOKUP,
        })
        .collect();
    for (kind, name) in [
        (Density::Dense, "dense f16"),
        (Density::Sparse, "sparse f16"),
    ] {
        out.push(Representation {
            name: format!("{name} (ratio)"),
            estimator: EstimatorSpec::RatioTracking,
            rungs: voxels
                .iter()
                .map(|&n| density(kind, n, tiny.clone()))
                .collect(),
            variant: None,
            lookup: LOOKUP,
        });
    }
    // PinMS reads both: the dense ladder beside a pin grid of 8^3 cells x octahedral:8.
    out.push(Representation {
        name: "dense f16 + pins c8 oct:8 (pinms)".into(),
        estimator: EstimatorSpec::PinMs,
        rungs: voxels
            .iter()
            .map(|&n| density(Density::Dense, n, pins(8, 8)))
            .collect(),
        variant: None,
        lookup: LOOKUP,
    });
    if a.pin_variants {
        // The pins-per-byte experiments, each on the octahedral:8 pins-alone ladder.
        let ladder = |ppe: u32| -> Vec<BakeOptions> {
            s.cells
                .iter()
                .map(|&c| BakeOptions {
                    pins_per_entry: ppe,
                    ..pins(c, 8)
                })
                .collect()
        };
        for (name, variant) in [
            ("t_min f16 tau", PinVariant::TauF16),
            ("t_min u8 log-tau", PinVariant::TauU8),
            ("near-1 entries left out", PinVariant::DropNearOne),
        ] {
            out.push(Representation {
                name: format!("pins oct:8 {name} (projected)"),
                estimator: EstimatorSpec::Pins,
                rungs: ladder(1),
                variant: Some(variant),
                lookup: LOOKUP,
            });
        }
        // Lookups: one cell of jitter (the default) is, in expectation, the linear blend of
        // the neighbouring cells' and direction cells' answers (a filtered lookup); no jitter
        // is the nearest cell's answer, two cells a wider blend.
        for (name, jitter) in [("nearest (no jitter)", 0.0), ("jitter 2 cells", 2.0)] {
            out.push(Representation {
                name: format!("pins oct:8 {name}"),
                estimator: EstimatorSpec::Pins,
                rungs: ladder(1),
                variant: None,
                lookup: SamplerOptions {
                    spatial_jitter: jitter,
                    directional_jitter: jitter,
                    ..LOOKUP
                },
            });
        }
        out.push(Representation {
            name: "pins oct:8 x4 per entry".into(),
            estimator: EstimatorSpec::Pins,
            rungs: ladder(4),
            variant: None,
            lookup: LOOKUP,
        });
    }
    out
}

/// `pinrender eval --bytes`.
pub fn run(a: &EvalArgs, scene_names: &[String], production: &Path) -> Result<()> {
    let started = Instant::now();
    let mut s = if a.quick {
        BytesSizes::quick()
    } else {
        BytesSizes::full()
    };
    if let Some(n) = a.size {
        s.image = n;
    }
    if let Some(r) = a.ref_spp {
        s.ref_spp = r;
    }
    for name in scene_names {
        if !VOLUME_SCENES.contains(&name.as_str()) {
            crate::usage!(
                "--bytes: scene '{name}' is not a volume file (--bytes scenes: {})",
                VOLUME_SCENES.join(", ")
            );
        }
    }
    let mut rows: Vec<BytesRow> = Vec::new();
    let mut notes: Vec<String> = Vec::new();
    for name in scene_names {
        pin_cli::errln!("== bytes: scene {name}");
        let (r, note) =
            scene_rows(name, a, &s, production).with_context(|| format!("scene {name}"))?;
        rows.extend(r);
        notes.push(note);
        // What we have after every scene, so an interrupted run leaves usable output.
        write_csv(&a.out.join(BYTES_CSV), &rows)?;
    }
    let names = representation_names(&rows);
    let points = |scene: &str, name: &str| -> Vec<(f64, f64)> {
        rows.iter()
            .filter(|r| r.scene == scene && r.representation == name)
            .map(|r| (r.bytes as f64, r.block8_error))
            .collect()
    };
    super::plot::bytes_chart(&a.out.join(BYTES_PNG), scene_names, &names, &points)?;
    let md = markdown(
        (&rows, &notes, scene_names),
        &s,
        a,
        started.elapsed().as_secs_f64(),
    );
    let path = a.out.join(BYTES_MD);
    std::fs::write(&path, md).with_context(|| format!("writing {}", path.display()))?;
    pin_cli::errln!(
        "eval --bytes done in {:.1} s -> {}",
        started.elapsed().as_secs_f64(),
        path.display()
    );
    Ok(())
}

/// The file a scene's volume is read from (its bytes are the source's reference point).
fn source_file(name: &str, production: &Path) -> Result<PathBuf> {
    match name {
        "smoke" => crate::data::path("openvdb_smoke1.vdb"),
        "hydrogen" => crate::data::path("hydrogen_atom_128x128x128_uint8.raw"),
        _ => Ok(production.to_path_buf()),
    }
}

/// Every rung of every representation of one scene, and the scene's line for the report.
fn scene_rows(
    name: &str,
    a: &EvalArgs,
    s: &BytesSizes,
    production: &Path,
) -> Result<(Vec<BytesRow>, String)> {
    let sizes = Sizes {
        image: s.image,
        pin_cells: 8,
        ref_spp: s.ref_spp,
        max_bounces: s.max_bounces,
        cache_training_spp: 1,
    };
    let mut es = scenes::build(name, &sizes, production)?;
    // The reference at the run's own samples (the scenes scale theirs by their cost).
    es.ref_spp = s.ref_spp;
    let src = es
        .bake_sources
        .first()
        .cloned()
        .ok_or_else(|| anyhow!("no volume"))?;
    let (reference, noise, _) = super::reference(&es, a)?;
    let mut rows = Vec::new();
    let row = |representation: &str, bytes: u64, img: &Image, seconds: f64| -> Result<BytesRow> {
        let (mean, block) = block_bias(img, &reference, 8).map_err(|e| anyhow!("{e}"))?;
        let rmse = rmse(img, &reference).map_err(|e| anyhow!("{e}"))?;
        let r = BytesRow {
            scene: name.to_string(),
            representation: representation.to_string(),
            bytes,
            mean_error: mean,
            block8_error: block,
            rmse,
            seconds_per_spp: seconds / f64::from(s.spp),
        };
        pin_cli::errln!(
            "  {:<36} {:>11} B  mean {:+.4}  block8 {:.4}  rmse {:.5}  {:.4} s/spp",
            r.representation,
            r.bytes,
            r.mean_error,
            r.block8_error,
            r.rmse,
            r.seconds_per_spp
        );
        Ok(r)
    };
    // The source file itself: ratio tracking of the full-resolution volume at the same samples
    // (the noise floor of this sample count).
    let file = source_file(name, production)?;
    let file_bytes = std::fs::metadata(&file)
        .with_context(|| file.display().to_string())?
        .len();
    let media = es
        .instances
        .iter()
        .map(|i| -> Result<Medium> {
            let f = i.field().map_err(|e| anyhow!("{e}"))?;
            let m = i.majorants().map_err(|e| anyhow!("{e}"))?;
            let local =
                Medium::single(Arc::new(RatioTracking::new(f, m)) as Arc<dyn TransportEstimator>);
            i.place(local, LOOKUP).map_err(|e| anyhow!("{e}"))
        })
        .collect::<Result<_>>()?;
    let (img, seconds) = render_spp(&es, media, EstimatorSpec::RatioTracking, a, s.spp)?;
    rows.push(row(SOURCE_FILE, file_bytes, &img, seconds)?);

    let dir = a.out.join("cache");
    std::fs::create_dir_all(&dir).with_context(|| dir.display().to_string())?;
    for rep in representations(&*src, s, a) {
        for (k, opts) in rep.rungs.iter().enumerate() {
            let path = dir.join(format!("bytes-{}-{name}-{k}.pin", std::process::id()));
            let bytes = bake_to(&*src, opts, rep.variant, &path)
                .with_context(|| format!("{}: rung {k}", rep.name))?;
            let rendered = render_file(&es, &path, (rep.estimator, rep.lookup), a, s.spp);
            let _ = std::fs::remove_file(&path);
            let (img, seconds) = rendered.with_context(|| format!("{}: rung {k}", rep.name))?;
            rows.push(row(&rep.name, bytes, &img, seconds)?);
        }
    }
    // NanoVDB's own sizes: the source converted by `nanovdb_convert`, tracked as the source.
    let nanovdb = if file.extension().is_some_and(|e| e == "vdb") {
        nanovdb_rows(name, &es, &file, &dir, a, s)?
    } else {
        Vec::new()
    };
    for (bytes, img, seconds) in &nanovdb {
        rows.push(row(NANOVDB, *bytes, img, *seconds)?);
    }
    let note = format!(
        "**{name}**: {} ({} bytes); reference: ratio tracking of the source, {} spp, its own noise RMSE {noise:.2e}.",
        file.file_name().map_or_else(
            || file.display().to_string(),
            |n| n.to_string_lossy().into_owned()
        ),
        file_bytes,
        s.ref_spp
    );
    Ok((rows, note))
}

/// The NanoVDB representation's name; its rungs are `nanovdb_convert --fp4`, `--fp8`,
/// `--fp16` and float.
pub const NANOVDB: &str = "NanoVDB fp4/fp8/fp16/f32 (ratio)";

/// The source VDB `file` converted by `nanovdb_convert` at each of its value widths,
/// each rendered with ratio tracking: (file bytes, image, seconds). Empty where the tool is
/// not installed.
fn nanovdb_rows(
    name: &str,
    es: &EvalScene,
    file: &Path,
    dir: &Path,
    a: &EvalArgs,
    s: &BytesSizes,
) -> Result<Vec<(u64, Image, f64)>> {
    if !nanovdb_convert_installed() {
        pin_cli::errln!("  NanoVDB: nanovdb_convert is not installed: no NanoVDB rows");
        return Ok(Vec::new());
    }
    let scale = match name {
        "smoke" => scenes::SMOKE_DENSITY_SCALE,
        _ => scenes::PRODUCTION_DENSITY_SCALE,
    };
    let mut out = Vec::new();
    for flag in ["--fp4", "--fp8", "--fp16", ""] {
        let path = dir.join(format!(
            "bytes-{}-{name}{}.nvdb",
            std::process::id(),
            flag.trim_start_matches('-')
        ));
        let mut cmd = std::process::Command::new("nanovdb_convert");
        if !flag.is_empty() {
            cmd.arg(flag);
        }
        let status = cmd
            .arg("-f")
            .arg(file)
            .arg(&path)
            .stdout(std::process::Stdio::null())
            .status()
            .context("running nanovdb_convert")?;
        if !status.success() {
            let _ = std::fs::remove_file(&path);
            anyhow::bail!("nanovdb_convert {flag} {} failed: {status}", file.display());
        }
        let bytes = std::fs::metadata(&path)
            .with_context(|| path.display().to_string())?
            .len();
        let rendered = (|| -> Result<(Image, f64)> {
            // NanoVDB's reader directly: `open_volume_typed` hands every VDB-like path to
            // the OpenVDB reader.
            let scale = pin_volume::DensityScale::new(scale)?;
            let source = pin_volume::nanovdb::open(&path, &Default::default(), scale)?
                .with_dense_cache(
                    pinbake::bake::DEFAULT_DENSE_COPY_BYTES
                        .min(pin_volume::files::default_memory_limit() / 4),
                );
            let opened = crate::volume::Opened::Vdb(Arc::new(source));
            let m = OpenedMedium::volume(opened, None, pin_volume::files::default_memory_limit());
            let medium = m
                .desc(16, None)
                .cpu_medium(EstimatorSpec::RatioTracking, LOOKUP)
                .map_err(|e| anyhow!("{e}"))?;
            render_spp(es, vec![medium], EstimatorSpec::RatioTracking, a, s.spp)
        })();
        let _ = std::fs::remove_file(&path);
        let (img, seconds) = rendered.with_context(|| format!("NanoVDB {flag}"))?;
        out.push((bytes, img, seconds));
    }
    Ok(out)
}

/// Whether `nanovdb_convert` runs here.
fn nanovdb_convert_installed() -> bool {
    std::process::Command::new("nanovdb_convert")
        .arg("--version")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok()
}

/// Bakes `opts` from `src` into `path` (with `variant`'s entries); the file's size in bytes
/// (less what the variant's format would save).
fn bake_to(
    src: &dyn DensitySource,
    opts: &BakeOptions,
    variant: Option<PinVariant>,
    path: &Path,
) -> Result<u64> {
    let (mut grid, _) = pinbake::bake(src, opts, &|_| {})?;
    let saved = variant.map_or(0, |v| v.apply(&mut grid));
    let bytes = grid.to_bytes()?;
    std::fs::write(path, &bytes).with_context(|| format!("writing {}", path.display()))?;
    let size = std::fs::metadata(path)
        .with_context(|| path.display().to_string())?
        .len();
    Ok(size.saturating_sub(saved))
}

/// Renders the pin file at `path` alone (its pins, embedded density and majorants) with
/// `estimator`: the image and the seconds its `spp` samples took.
fn render_file(
    es: &EvalScene,
    path: &Path,
    (estimator, lookup): (EstimatorSpec, SamplerOptions),
    a: &EvalArgs,
    spp: u32,
) -> Result<(Image, f64)> {
    let grid = Arc::new(crate::volume::load_pins(path)?);
    let opened = OpenedMedium::pin_file(path, grid)?;
    let desc: MediumDesc = opened.desc(16, None);
    let medium = desc
        .cpu_medium(estimator, lookup)
        .map_err(|e| anyhow!("{}: {e}", path.display()))?;
    render_spp(es, vec![medium], estimator, a, spp)
}

/// One render of `spp` samples (pin queries in batches where the estimator answers them so).
fn render_spp(
    es: &EvalScene,
    media: Vec<Medium>,
    estimator: EstimatorSpec,
    a: &EvalArgs,
    spp: u32,
) -> Result<(Image, f64)> {
    let scene = scene_with(es, media);
    let st = settings(es, pass_seed(a.seed, 0), Budget::Spp(spp), a.threads);
    let t = Instant::now();
    let out = if estimator.plan().sample_loop == SampleLoop::Wavefront {
        render_wavefront(&scene, &st, DEFAULT_WAVEFRONT_BATCH)
    } else {
        render(&scene, &st)
    }
    .map_err(|e| anyhow!("{e}"))?;
    Ok((out.image, t.elapsed().as_secs_f64()))
}

fn write_csv(path: &Path, rows: &[BytesRow]) -> Result<()> {
    let mut s = String::from(BYTES_HEADER);
    s.push('\n');
    for r in rows {
        s.push_str(&format!(
            "{},{},{},{:.6},{:.6},{:.6},{:.6}\n",
            r.scene,
            r.representation,
            r.bytes,
            r.mean_error,
            r.block8_error,
            r.rmse,
            r.seconds_per_spp
        ));
    }
    std::fs::write(path, s).with_context(|| format!("writing {}", path.display()))
}

/// The representation names of `rows` in order of first appearance.
pub fn representation_names(rows: &[BytesRow]) -> Vec<String> {
    let mut names: Vec<String> = Vec::new();
    for r in rows {
        if !names.contains(&r.representation) {
            names.push(r.representation.clone());
        }
    }
    names
}

/// Bytes in KB/MB for the tables.
fn human(bytes: u64) -> String {
    match bytes {
        b if b >= 10_000_000 => format!("{:.0} MB", b as f64 / 1e6),
        b if b >= 1_000_000 => format!("{:.1} MB", b as f64 / 1e6),
        b if b >= 10_000 => format!("{:.0} KB", b as f64 / 1e3),
        b => format!("{:.1} KB", b as f64 / 1e3),
    }
}

/// The report: per scene, the lowest block error at each size class, then every row.
fn markdown(
    (rows, notes, scene_names): (&[BytesRow], &[String], &[String]),
    s: &BytesSizes,
    a: &EvalArgs,
    total: f64,
) -> String {
    let mut md = String::new();
    md.push_str("# Error against bytes\n\n");
    md.push_str(&format!(
        "Each representation baked at a ladder of sizes, written to a file (bytes: that file's \
         size), rendered from the file alone at {px}x{px} px, {spp} spp, {b} bounces, and \
         compared with a converged ratio-tracking reference of the full-resolution source: \
         mean relative error, 8x8-block relative error (both on the channel mean) and RMSE. \
         `{SOURCE_FILE}` is the source volume file itself rendered with ratio tracking at the \
         same samples: its error is the noise floor of {spp} spp. Seconds per spp are wall \
         time on {threads} threads. Run in {total:.0} s: `pinrender eval --bytes{quick}{variants} \
         --scenes {scenes} --out {out}`.\n\n",
        px = s.image,
        spp = s.spp,
        b = s.max_bounces,
        threads = super::worker_threads(a),
        quick = if a.quick { " --quick" } else { "" },
        variants = if a.pin_variants {
            " --pin-variants"
        } else {
            ""
        },
        scenes = scene_names.join(","),
        out = a.out.display(),
    ));
    md.push_str(if nanovdb_convert_installed() {
        "`NanoVDB …` rows: the source VDB converted by `nanovdb_convert --fp4`, `--fp8`, \
         `--fp16` and without a flag (f32), tracked like the source.\n\n"
    } else {
        "No NanoVDB rows: `nanovdb_convert` is not installed (Debian: libnanovdb-tools).\n\n"
    });
    let scenes: Vec<&str> = {
        let mut v: Vec<&str> = Vec::new();
        for r in rows {
            if !v.contains(&r.scene.as_str()) {
                v.push(&r.scene);
            }
        }
        v
    };
    for (k, scene) in scenes.iter().enumerate() {
        md.push_str(&format!("## {scene}\n\n"));
        if let Some(n) = notes.get(k) {
            md.push_str(&format!("{n}\n\n"));
        }
        let of: Vec<&BytesRow> = rows.iter().filter(|r| r.scene == *scene).collect();
        // The winner per decade of bytes: the lowest block error among the files of at most
        // that many bytes.
        md.push_str(
            "| at most | lowest block error | representation | its bytes |\n|---|---|---|---|\n",
        );
        let mut edge = 10_000u64;
        let largest = of.iter().map(|r| r.bytes).max().unwrap_or(0);
        loop {
            let best = of
                .iter()
                .filter(|r| r.bytes <= edge && r.representation != SOURCE_FILE)
                .min_by(|a, b| a.block8_error.total_cmp(&b.block8_error));
            if let Some(b) = best {
                md.push_str(&format!(
                    "| {} | {:.2}% | {} | {} |\n",
                    human(edge),
                    100.0 * b.block8_error,
                    b.representation,
                    human(b.bytes)
                ));
            }
            if edge >= largest {
                break;
            }
            edge = edge.saturating_mul(10);
        }
        md.push_str(
            "\n| representation | bytes | mean error | 8x8-block error | RMSE | s/spp |\n\
             |---|---|---|---|---|---|\n",
        );
        for r in &of {
            md.push_str(&format!(
                "| {} | {} | {:+.2}% | {:.2}% | {:.4} | {:.4} |\n",
                r.representation,
                human(r.bytes),
                100.0 * r.mean_error,
                100.0 * r.block8_error,
                r.rmse,
                r.seconds_per_spp
            ));
        }
        md.push('\n');
    }
    md
}
