//! `pinbake bake`.

use pinbake::control::ControlDims;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use pin_format::Directions;
use pin_volume::SourceSpec;
use pinbake::cli_args::SourceArgs;
use pinbake::{BakeInput, BakeRequest, EmbedDensity, PlanError, Tile};

#[derive(Args, Debug, Clone)]
#[command(after_help = "\
INPUT is one of:
  FILE.vdb                 an OpenVDB fog volume (float or half grid)
  FILE.raw                 a headerless grid; dims/type from --dims/--type or the file name
                           convention NAME_XxYxZ_TYPE.raw (e.g. hydrogen_atom_128x128x128_uint8.raw)
  procedural:SPEC          an analytic field: box, sphere, cosine:seed=7,freq=16, fractal:octaves=4

Examples:
  pinbake bake smoke.vdb -o smoke.pin
  pinbake bake hydrogen_atom_128x128x128_uint8.raw --density-scale 0.1 -o h.pin --json
  pinbake bake procedural:cosine:seed=3 --cells 37 --dirs octahedral:8 -o noise.pin
  pinbake bake smoke.vdb --tile 0/4 -o part0.pin    (then `pinbake merge part*.pin -o all.pin`)
  pinbake bake 'smoke.####.vdb' --frames 1-240 -o 'smoke.####.pin'   (one file per frame)")]
pub struct BakeArgs {
    /// Input volume (see below).
    pub input: PathBuf,
    /// Output pin file; written atomically (a temp file renamed into place). Must be a new
    /// path or a regular file other than the input.
    #[arg(short, long)]
    pub output: PathBuf,

    /// How to read the input (the same flags as `pinrender --volume`).
    #[command(flatten)]
    pub volume: SourceArgs,

    /// Spatial cells: N or X,Y,Z (default: chosen from the volume, never more than it has
    /// voxels along an axis; see --target-error).
    #[arg(long, value_parser = parse_u32x3, help_heading = "Grid")]
    pub cells: Option<[u32; 3]>,
    /// Direction cells: octahedral:N or polar:PHIxTHETA (default: an octahedral set chosen
    /// from the volume; the thesis used polar:16x4, which is biased near +-z; see
    /// docs/sampling.md).
    #[arg(long, value_parser = pinbake::cli_args::parse_dirs, help_heading = "Grid")]
    pub dirs: Option<Directions>,
    /// Pins stored per (cell, direction) entry (default: chosen, 1).
    #[arg(long, help_heading = "Grid",
          value_parser = clap::value_parser!(u32).range(1..=i64::from(pin_format::MAX_PINS_PER_ENTRY)))]
    pub pins_per_entry: Option<u32>,
    /// The predicted 8x8-block error of the image from the file to choose for (a fraction,
    /// e.g. 0.05; default 0.01). With no grid flags, the smallest file meeting it within
    /// --max-bytes: for a voxel input its density (box-filtered to the coarsest resolution
    /// predicted to meet E) and a small pin grid, or pins alone where they are smaller
    /// (docs/scale.md, "The default asset"). With --cells, --dirs or --pins-per-entry named,
    /// the others are chosen for pins alone to meet E (without E: 0.06, never below 20 cells
    /// along the longest axis and octahedral:16). --json reports the choice.
    #[arg(long, value_name = "E", value_parser = parse_target_error, help_heading = "Grid")]
    pub target_error: Option<f64>,
    /// The most bytes the file may take (K/M/G/T suffixes). Without grid flags the bake
    /// writes the smallest file predicted within the target error of the full-resolution
    /// volume in at most this many bytes (default: the input file's size plus 64 KiB); a bake
    /// of named parameters predicted larger is refused. --json reports the choice
    /// (`choice.asset`).
    #[arg(long, value_name = "SIZE", value_parser = pin_cli::parse::parse_bytes, help_heading = "Grid")]
    pub max_bytes: Option<u64>,
    /// Ray-marching step relative to the longest box edge, in [1e-5, 1].
    #[arg(long, default_value_t = 0.01, value_parser = pinbake::cli_args::parse_step, help_heading = "Grid")]
    pub step: f64,
    /// Seed of the pins' random lines and mask bits.
    #[arg(long, default_value_t = 0, help_heading = "Grid")]
    pub seed: u64,
    /// Keep the source's full box instead of cropping to the non-empty region.
    #[arg(long, help_heading = "Grid")]
    pub no_crop: bool,
    /// Pins through cell centres and direction-cell centres (the default; docs/sampling.md
    /// section 13).
    #[arg(long, help_heading = "Grid", conflicts_with = "jitter_pins")]
    pub center_pins: bool,
    /// Pins through random points and directions inside their cells (the thesis' bake; more
    /// bias with the runtime's lookup jitter, docs/evaluation.md).
    #[arg(long, help_heading = "Grid")]
    pub jitter_pins: bool,
    /// Majorant bricks per axis (N or X,Y,Z); 0 leaves the majorant grid out.
    #[arg(long, default_value = "16", value_parser = parse_u32x3_or_zero, help_heading = "Grid")]
    pub majorant: [u32; 3],
    /// Embed the density: `sparse` (bricked f16 at the source's voxel size, stored only
    /// where non-zero; a format 1.1 file), `sparse:N` (at most N voxels per axis),
    /// `sparse:X,Y,Z` (exactly those voxels), N or X,Y,Z for a dense f16 grid of at most
    /// 4096 per axis, or `voxels:F` / `sparse-voxels:F` (dense or sparse: the source's own
    /// voxels, each F^3 of them averaged into one, on the source's lattice; F 1 by default)
    /// (for tracked and ray-marched rays from the .pin alone). Dense counts that name the
    /// source's resolution or a whole F of it (between its stored voxels and those of its box
    /// on its lattice, divided by F: `23,10,23` for a 23x10x23 VDB) are `voxels:F`: the
    /// section holds the lattice box's voxels, a rim of zeros included. Below the source's
    /// resolution every form is box-filtered (the mean over the embedded voxel). Default:
    /// chosen with the pins, see --max-bytes.
    #[arg(long, value_parser = parse_embed_density, help_heading = "Grid")]
    pub embed_density: Option<EmbedDensity>,
    /// Embed the control of residual ratio tracking (a format 1.1 file): per brick of EDGE
    /// source voxels per axis (1..=64; without a value or `auto`: 4, or coarser so that the
    /// longest axis has about 64 bricks), a control extinction, a residual majorant and a
    /// majorant, for `pinrender`'s unbiased `pinres` estimator (docs/final-frames.md).
    #[arg(long, value_name = "EDGE", num_args = 0..=1, default_missing_value = "auto",
          value_parser = parse_control_edge, help_heading = "Grid")]
    pub embed_control: Option<ControlDims>,

    /// Bake only tile I of N (a slab of z layers); join tiles with `pinbake merge`.
    #[arg(long, value_parser = parse_tile, help_heading = "Execution")]
    pub tile: Option<Tile>,
    /// Bake only part I of N of a bake split by volume: the pins' samples in z-slab I of the
    /// volume, into a part file (a VDB is read for that slab only); join the N part files
    /// with `pinbake merge`. Needs --cells and --dirs; N is at most 1024.
    #[arg(long, value_parser = parse_part, help_heading = "Execution", conflicts_with = "tile")]
    pub part: Option<pinbake::Part>,
    /// With --part and an OpenVDB input: the whole grid's statistics that `pinbake grid-stats`
    /// wrote for this input and these volume options; the part then skips the leaves outside
    /// its slab without decoding them (about 1/N of the read).
    #[arg(
        long,
        value_name = "FILE",
        requires = "part",
        help_heading = "Execution"
    )]
    pub grid_stats: Option<PathBuf>,
    /// Worker threads (default: all cores; at most 64 per core and 4096).
    #[arg(long, value_parser = pinbake::cli_args::parse_threads, help_heading = "Execution")]
    pub threads: Option<usize>,
    /// Refuse to start a bake that would need more than this many bytes of memory (K/M/G/T
    /// suffixes; default: half of the physical memory).
    #[arg(long, value_parser = pin_cli::parse::parse_bytes, help_heading = "Execution")]
    pub max_memory: Option<u64>,
    /// Bake an animated sequence: INPUT and --output each hold one frame field (`####` or
    /// `%04d`); FRAMES is A-B, A-BxSTEP, single frames, or a comma list of those. A frame that
    /// fails is reported and the rest go on; the exit code is 1 if any failed.
    #[arg(long, value_name = "FRAMES", help_heading = "Execution")]
    pub frames: Option<String>,
    /// Where the pins' entries are computed: `cpu`, or `gpu` (a wgpu compute pass; the rest
    /// of the bake and the file are the same; docs/gpu.md states how close its entries are).
    #[arg(long, default_value = "cpu", value_parser = ["cpu", "gpu"], help_heading = "Execution", conflicts_with = "part")]
    pub backend: String,
    /// The most GPU bytes one dispatch of the GPU bake takes (tests force small tiles; the
    /// file is the same).
    #[arg(long, hide = true, value_parser = pin_cli::parse::parse_bytes, help_heading = "Execution")]
    pub gpu_tile_bytes: Option<u64>,
    /// The most GPU bytes of density one dispatch of the GPU bake binds: the volume goes up in
    /// z slabs of this size, each uploaded, marched and freed (default: what the device binds;
    /// a sparse volume without a dense copy within --max-memory builds each slab from the
    /// file within that budget too). The file is the same for any size.
    #[arg(long, value_parser = pin_cli::parse::parse_bytes, help_heading = "Execution", value_name = "BYTES")]
    pub gpu_slab_bytes: Option<u64>,
    /// Destroys the GPU device after N dispatches (tests: a device lost mid-bake).
    #[arg(long, hide = true, help_heading = "Execution")]
    pub gpu_lose_device_after: Option<u64>,
    /// Print one JSON summary object on stdout (with --frames: {"frames": [...], ...}).
    #[arg(long, help_heading = "Execution")]
    pub json: bool,
    /// No progress bar even on a terminal.
    #[arg(long, short, help_heading = "Execution")]
    pub quiet: bool,
}

/// `--target-error`: a finite fraction in (0, 1].
fn parse_target_error(s: &str) -> Result<f64, String> {
    let e: f64 = s.trim().parse().map_err(|e| format!("'{s}': {e}"))?;
    if !(e.is_finite() && e > 0.0 && e <= 1.0) {
        return Err(format!("{s}: must be a fraction in (0, 1], e.g. 0.05"));
    }
    Ok(e)
}

pub use pin_cli::parse::parse_u32x3;

/// Majorant and embedded-density grids: 1..=4096 voxels per axis (the format's limit).
fn parse_u32x3_max4096(s: &str) -> Result<[u32; 3], String> {
    let v = parse_u32x3(s)?;
    if v.iter().any(|&d| d > 4096) {
        return Err(format!("{v:?}: at most 4096 per axis"));
    }
    Ok(v)
}

/// `--embed-control`: source voxels per brick edge, 1..=64.
fn parse_control_edge(s: &str) -> Result<ControlDims, String> {
    if s.trim() == "auto" {
        return Ok(ControlDims::Auto);
    }
    match s.trim().parse::<u32>() {
        Ok(e) if (1..=pinbake::control::MAX_CONTROL_EDGE).contains(&e) => Ok(ControlDims::Edge(e)),
        _ => Err(format!("'{s}': `auto` or a brick edge of 1..=64 voxels")),
    }
}

/// `--embed-density`: `sparse`, `sparse:N`, `sparse:X,Y,Z`, or dense N / X,Y,Z.
fn parse_embed_density(s: &str) -> Result<EmbedDensity, String> {
    s.parse()
}

fn parse_u32x3_or_zero(s: &str) -> Result<[u32; 3], String> {
    if s.trim() == "0" {
        Ok([0; 3])
    } else {
        parse_u32x3_max4096(s)
    }
}

fn majorant_dims(d: [u32; 3]) -> Option<[u32; 3]> {
    (d != [0; 3]).then_some(d)
}

fn parse_tile(s: &str) -> Result<Tile, String> {
    let (i, n) = s.split_once('/').ok_or("expected I/N, e.g. 0/4")?;
    let index: u32 = i.trim().parse().map_err(|e| format!("'{i}': {e}"))?;
    let count: u32 = n.trim().parse().map_err(|e| format!("'{n}': {e}"))?;
    if count == 0 || index >= count {
        return Err(format!("tile index must be in 0..{count}"));
    }
    Ok(Tile { index, count })
}

/// `--part I/N`: at most [`pinbake::part::MAX_PARTS`] parts (a part file of more is damage,
/// and the merge could not hold their lattices).
fn parse_part(s: &str) -> Result<pinbake::Part, String> {
    let t = parse_tile(s).map_err(|e| e.replace("tile", "part"))?;
    if t.count > pinbake::part::MAX_PARTS {
        return Err(format!(
            "{} parts: a bake splits into at most {} parts",
            t.count,
            pinbake::part::MAX_PARTS
        ));
    }
    Ok(pinbake::Part {
        index: t.index,
        count: t.count,
    })
}

/// What the input names. Flags meant for another kind of input are usage errors: ignoring
/// them would bake something other than what the user asked for.
pub fn source_spec(args: &BakeArgs) -> Result<SourceSpec> {
    let spec = args.volume.source_spec(&args.input, "input", || {
        std::env::current_exe().context("locating the pinbake binary")
    })?;
    let Some(stats) = &args.grid_stats else {
        return Ok(spec);
    };
    match spec {
        SourceSpec::Vdb(path, mut o)
            if pin_volume::InputKind::of(&path) != pin_volume::InputKind::NanoVdb
                && !pin_volume::nanovdb::is_nanovdb_file(&path) =>
        {
            o.grid_stats = Some(Box::new(super::read_grid_stats(stats)?));
            Ok(SourceSpec::Vdb(path, o))
        }
        _ => Err(anyhow::Error::new(super::UsageError(format!(
            "--grid-stats is for an OpenVDB input; {} is read whole by every part",
            args.input.display()
        )))),
    }
}

/// The request `args` makes of [`pinbake::plan`].
pub fn request(args: &BakeArgs) -> BakeRequest {
    BakeRequest {
        cells: args.cells,
        directions: args.dirs,
        pins_per_entry: args.pins_per_entry,
        target_error: args.target_error,
        step: args.step,
        seed: args.seed,
        crop: !args.no_crop,
        jitter_pins: args.jitter_pins,
        tile: args.tile,
        majorant: majorant_dims(args.majorant),
        embed_density: args.embed_density,
        embed_control: args
            .embed_control
            .map(|dims| pinbake::control::ControlOptions {
                dims,
                ..pinbake::control::ControlOptions::default()
            }),
        threads: args.threads,
        density_scale: args.volume.density_scale.get(),
        max_memory: args.max_memory,
        max_bytes: args.max_bytes,
        backend: match args.backend.as_str() {
            "gpu" => pinbake::BakeBackend::Gpu(pinbake::GpuBakeOptions {
                tile_bytes: args.gpu_tile_bytes,
                slab_bytes: args.gpu_slab_bytes,
                lose_device_after: args.gpu_lose_device_after,
            }),
            _ => pinbake::BakeBackend::Cpu,
        },
    }
}

/// One volume (a sequence, `--frames`, is `frames::run_sequence`).
pub fn run(args: BakeArgs) -> Result<ExitCode> {
    let inputs = pin_volume::files::InputSet::of(&[args.input.as_path()])?;
    let summary = bake_one(&args, &inputs)?;
    if args.json {
        pin_cli::outln!("{summary}")?;
    }
    Ok(ExitCode::SUCCESS)
}

/// The usage errors of a bake that need several flags or the input's kind (ranges of single
/// flags are checked by their parsers): exit 2 before any work.
pub fn check_usage(args: &BakeArgs) -> Result<SourceSpec> {
    // A GPU flag with the CPU backend would be ignored silently.
    if args.backend != "gpu" && args.gpu_slab_bytes.is_some() {
        return Err(anyhow::Error::new(super::UsageError(
            "--gpu-slab-bytes applies to --backend gpu".into(),
        )));
    }
    request(args).validate().map_err(plan_error)?;
    source_spec(args)
}

/// A [`PlanError`] for the binary: usage errors exit 2.
fn plan_error(e: PlanError) -> anyhow::Error {
    match e {
        PlanError::Usage(m) => anyhow::Error::new(super::UsageError(m)),
        e => anyhow::Error::new(e),
    }
}

/// The progress bar of a bake on a terminal (none when piped or with `--quiet`).
struct Bar {
    enabled: bool,
    bar: std::sync::OnceLock<ProgressBar>,
}

impl Bar {
    /// Clears the bar once the bake is done (nothing when none was shown).
    fn finish(&self) {
        if let Some(b) = self.bar.get() {
            b.finish_and_clear();
        }
    }
}

impl pinbake::plan::Progress for Bar {
    fn start(&self, total: u64) {
        if !self.enabled {
            return;
        }
        let bar = ProgressBar::new(total);
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} baking [{bar:40}] {pos}/{len} pins  {per_sec}  eta {eta}",
            )
            .expect("static template")
            .progress_chars("=> "),
        );
        bar.enable_steady_tick(Duration::from_millis(200));
        let _ = self.bar.set(bar);
    }

    fn advance(&self, n: u64) {
        if let Some(b) = self.bar.get() {
            b.inc(n);
        }
    }
}

/// One bake: the JSON summary (printed by the caller with `--json`; without it, the one-line
/// human summary goes to stderr here). `inputs` are the files the output must not be: with
/// `--frames` every frame's input (the frame's own is added by the plan).
pub fn bake_one(
    args: &BakeArgs,
    inputs: &pin_volume::files::InputSet,
) -> Result<serde_json::Value> {
    let spec = check_usage(args)?;
    let started = Instant::now();
    let bar = Bar {
        enabled: !args.quiet && std::io::stderr().is_terminal(),
        bar: std::sync::OnceLock::new(),
    };
    if let Some(part) = args.part {
        let baked = pinbake::plan::bake_part_to_file(
            BakeInput::Source(spec),
            &args.output,
            &request(args),
            part,
            inputs,
            &bar,
        )
        .map_err(plan_error)?;
        bar.finish();
        let seconds = started.elapsed().as_secs_f64();
        let mut v = baked.summary();
        v["seconds"] = serde_json::json!(seconds);
        if !args.json {
            pin_cli::errln!(
                "baked part {}/{} of {} -> {}: {} samples, {} bytes, {:.2} s",
                part.index,
                part.count,
                args.input.display(),
                args.output.display(),
                baked.samples,
                baked.file_bytes,
                seconds
            );
        }
        return Ok(v);
    }
    let baked = pinbake::plan::bake_to_file(
        BakeInput::Source(spec),
        &args.output,
        &request(args),
        inputs,
        &bar,
    )
    .map_err(plan_error)?;
    bar.finish();
    let seconds = started.elapsed().as_secs_f64();
    if let Some(w) = &baked.choice.warning
        && !args.quiet
    {
        pin_cli::errln!("pinbake: warning: {}: {w}", args.input.display());
    }
    let mut v = baked
        .summary()
        .with_context(|| args.output.display().to_string())?;
    v["seconds"] = serde_json::json!(seconds);
    if !args.json {
        let stats = &baked.stats;
        pin_cli::errln!(
            "baked {} -> {}: {} cells ({} empty), {} pins stored, {} bytes, {:.2} s ({:.3} Mpins/s)",
            args.input.display(),
            args.output.display(),
            stats.covered_cells,
            stats.empty_cells,
            stats.pins,
            baked.file_bytes,
            seconds,
            stats.pins_per_s / 1e6
        );
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn target_error_is_a_fraction() {
        assert_eq!(parse_target_error("0.05"), Ok(0.05));
        assert_eq!(parse_target_error("1"), Ok(1.0));
        for bad in ["0", "-0.1", "1.5", "nan", "inf", "x"] {
            assert!(parse_target_error(bad).is_err(), "{bad}");
        }
    }
}
