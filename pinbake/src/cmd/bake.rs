//! `pinbake bake`.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use pin_format::Directions;
use pinbake::choose::Choice;
use pinbake::cli_args::VolumeArgs;
use pinbake::source::{self, DensitySource, SourceSpec};
use pinbake::{BakeOptions, Tile};

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
    pub volume: VolumeArgs,

    /// Spatial cells: N or X,Y,Z (default: chosen from the volume, never more than it has
    /// voxels along an axis; see --target-error).
    #[arg(long, value_parser = parse_u32x3, help_heading = "Grid")]
    pub cells: Option<[u32; 3]>,
    /// Direction cells: octahedral:N or polar:PHIxTHETA (default: an octahedral set chosen
    /// from the volume; the thesis used polar:16x4, which is biased near +-z; see
    /// docs/sampling.md).
    #[arg(long, value_parser = parse_dirs, help_heading = "Grid")]
    pub dirs: Option<Directions>,
    /// Pins stored per (cell, direction) entry (default: chosen, 1).
    #[arg(long, help_heading = "Grid",
          value_parser = clap::value_parser!(u32).range(1..=i64::from(pin_format::MAX_PINS_PER_ENTRY)))]
    pub pins_per_entry: Option<u32>,
    /// The smallest bake whose predicted 8x8-block error of pins alone is at most E (a
    /// fraction, e.g. 0.05), for the parameters not given. Without it: 0.06, but never below
    /// 20 cells along the longest axis (or the voxels) and octahedral:16, since the model is
    /// fitted on one view per volume and other views measured up to 3.6x more
    /// (docs/evaluation.md, "Bias against bytes"). --json reports the choice.
    #[arg(long, value_name = "E", value_parser = parse_target_error, help_heading = "Grid")]
    pub target_error: Option<f64>,
    /// Ray-marching step relative to the longest box edge, in [1e-5, 1].
    #[arg(long, default_value_t = 0.01, value_parser = pinbake::limits::parse_step, help_heading = "Grid")]
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
    /// Embed the density as an f16 grid of N or X,Y,Z voxels, at most 4096 per axis (for
    /// ray-marched primary rays).
    #[arg(long, value_parser = parse_u32x3_max4096, help_heading = "Grid")]
    pub embed_density: Option<[u32; 3]>,

    /// Bake only tile I of N (a slab of z layers); join tiles with `pinbake merge`.
    #[arg(long, value_parser = parse_tile, help_heading = "Execution")]
    pub tile: Option<Tile>,
    /// Worker threads (default: all cores; at most 64 per core and 4096).
    #[arg(long, value_parser = pinbake::limits::parse_threads, help_heading = "Execution")]
    pub threads: Option<usize>,
    /// Refuse to start a bake that would need more than this many bytes of memory (K/M/G/T
    /// suffixes; default: half of the physical memory).
    #[arg(long, value_parser = pinbake::files::parse_bytes, help_heading = "Execution")]
    pub max_memory: Option<u64>,
    /// Bake an animated sequence: INPUT and --output each hold one frame field (`####` or
    /// `%04d`); FRAMES is A-B, A-BxSTEP, single frames, or a comma list of those. A frame that
    /// fails is reported and the rest go on; the exit code is 1 if any failed.
    #[arg(long, value_name = "FRAMES", help_heading = "Execution")]
    pub frames: Option<String>,
    /// Print one JSON summary object on stdout (with --frames: {"frames": [...], ...}).
    #[arg(long, help_heading = "Execution")]
    pub json: bool,
    /// No progress bar even on a terminal.
    #[arg(long, short, help_heading = "Execution")]
    pub quiet: bool,
}

/// Spatial cells per axis the memory check assumes before the volume is open.
pub const DEFAULT_MAX_CELLS: u32 = pinbake::bake::DEFAULT_MAX_CELLS;

/// `--target-error`: a finite fraction in (0, 1].
fn parse_target_error(s: &str) -> Result<f64, String> {
    let e: f64 = s.trim().parse().map_err(|e| format!("'{s}': {e}"))?;
    if !(e.is_finite() && e > 0.0 && e <= 1.0) {
        return Err(format!("{s}: must be a fraction in (0, 1], e.g. 0.05"));
    }
    Ok(e)
}

pub use pinbake::cli_args::parse_u32x3;

/// Majorant and embedded-density grids: 1..=4096 voxels per axis (the format's limit).
fn parse_u32x3_max4096(s: &str) -> Result<[u32; 3], String> {
    let v = parse_u32x3(s)?;
    if v.iter().any(|&d| d > 4096) {
        return Err(format!("{v:?}: at most 4096 per axis"));
    }
    Ok(v)
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

pub fn parse_dirs(s: &str) -> Result<Directions, String> {
    let (kind, res) = s
        .split_once(':')
        .ok_or("expected polar:PHIxTHETA or octahedral:N")?;
    let d = match kind {
        "polar" => {
            let (a, b) = res
                .split_once('x')
                .ok_or("polar needs PHIxTHETA, e.g. 16x4")?;
            Directions::Polar {
                n_phi: a.parse().map_err(|e| format!("'{a}': {e}"))?,
                n_theta: b.parse().map_err(|e| format!("'{b}': {e}"))?,
            }
        }
        "octahedral" | "oct" => Directions::Octahedral {
            n: res.parse().map_err(|e| format!("'{res}': {e}"))?,
        },
        other => return Err(format!("unknown parametrisation '{other}'")),
    };
    let (k, r) = d.to_desc();
    Directions::from_desc(k, r).map_err(|e| e.to_string())
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

/// What the input names. Flags meant for another kind of input are usage errors: ignoring
/// them would bake something other than what the user asked for.
pub fn source_spec(args: &BakeArgs) -> Result<SourceSpec> {
    args.volume.source_spec(&args.input, "input", || {
        std::env::current_exe().context("locating the pinbake binary")
    })
}

/// Hex xxh3-128 of a file, streamed so a large volume is not read twice into memory.
fn hash_file(path: &Path) -> Result<String> {
    use std::io::Read;
    let (mut f, _) = pinbake::files::open_input(path)?;
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = f
            .read(&mut buf)
            .with_context(|| format!("{}", path.display()))?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(format!("{:032x}", h.digest128()))
}

/// The bake's cells, directions and pins per entry: the ones given, the rest chosen from the
/// volume (`pinbake::choose`).
pub fn choose_from_args(args: &BakeArgs, source: &dyn DensitySource) -> Result<Choice> {
    let stats = pinbake::choose::analyse(source, !args.no_crop)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.input.display()))?;
    let fixed = pinbake::choose::Fixed {
        cells: args.cells,
        directions: args.dirs,
        pins_per_entry: args.pins_per_entry,
    };
    Ok(match args.target_error {
        Some(e) => pinbake::choose::choose(&stats, fixed, e),
        None => pinbake::choose::choose_default(&stats, fixed),
    })
}

pub fn options_from_args(
    args: &BakeArgs,
    source: &dyn DensitySource,
    spec: &SourceSpec,
    choice: &Choice,
) -> Result<BakeOptions> {
    let (name, hash) = match spec {
        SourceSpec::Procedural(p) => (format!("procedural:{p}"), String::new()),
        #[cfg(feature = "vdb")]
        SourceSpec::Vdb(path, _) => (file_name(path), hash_file(path)?),
        #[cfg(not(feature = "vdb"))]
        SourceSpec::Vdb(path) => (file_name(path), hash_file(path)?),
        SourceSpec::Raw(path, _) => (file_name(path), hash_file(path)?),
    };
    let cells = choice.cells;
    let metadata = pinbake::bake::bake_metadata(
        source,
        pinbake::bake::Provenance {
            source_name: name,
            source_hash: hash,
            seed: args.seed,
            step: args.step,
            density_scale: args.volume.density_scale,
            crop: !args.no_crop,
        },
        cells,
        choice.directions,
    );
    Ok(BakeOptions {
        cells,
        directions: choice.directions,
        pins_per_entry: choice.pins_per_entry,
        step: args.step,
        seed: args.seed,
        crop: !args.no_crop,
        jitter_pins: args.jitter_pins,
        tile: args.tile,
        majorant: majorant_dims(args.majorant),
        embed_density: args.embed_density,
        threads: args.threads,
        density_scale: args.volume.density_scale,
        metadata,
        // `bake_one` lowers it to what `--max-memory` leaves.
        dense_copy_bytes: pinbake::bake::DEFAULT_DENSE_COPY_BYTES,
    })
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

pub fn run(args: BakeArgs) -> Result<ExitCode> {
    if args.frames.is_some() {
        return super::frames::run_sequence(args);
    }
    let inputs = pinbake::files::InputSet::of(&[args.input.as_path()])?;
    let summary = bake_one(&args, &inputs)?;
    if args.json {
        pinbake::outln!("{summary}")?;
    }
    Ok(ExitCode::SUCCESS)
}

/// The usage errors of a bake that need several flags or the input's kind (ranges of single
/// flags are checked by their parsers): exit 2 before any work.
pub fn check_usage(args: &BakeArgs) -> Result<SourceSpec> {
    if args.target_error.is_some()
        && args.cells.is_some()
        && args.dirs.is_some()
        && args.pins_per_entry.is_some()
    {
        super::usage!(
            "--target-error has nothing to choose: --cells, --dirs and --pins-per-entry are all given"
        );
    }
    source_spec(args)
}

/// One bake: the JSON summary (printed by the caller with `--json`; without it, the one-line
/// human summary goes to stderr here). `inputs` are the files the output must not be: the
/// input, or with `--frames` every frame's input.
pub fn bake_one(args: &BakeArgs, inputs: &pinbake::files::InputSet) -> Result<serde_json::Value> {
    let spec = check_usage(args)?;
    let input_path: Option<&Path> = match &spec {
        SourceSpec::Procedural(_) => None,
        _ => Some(args.input.as_path()),
    };
    // Before the bake, not after it: minutes of work for a refused path help nobody.
    inputs.check_output(&args.output)?;
    let budget = pinbake::files::MemoryBudget::new(args.max_memory);
    let probe = BakeOptions {
        // Before the source is open: the default's upper bound.
        cells: args.cells.unwrap_or([DEFAULT_MAX_CELLS; 3]),
        directions: args.dirs.unwrap_or(pinbake::bake::DEFAULT_DIRECTIONS),
        pins_per_entry: args.pins_per_entry.unwrap_or(1),
        majorant: majorant_dims(args.majorant),
        embed_density: args.embed_density,
        ..BakeOptions::default()
    };
    let input_bytes = match input_path {
        None => 0,
        // f32 voxels in memory: up to 4x the file for 8-bit input; a VDB's leaves and
        // the worker's copy up to 8x its compressed file.
        Some(p) => {
            let len = std::fs::metadata(p).map(|m| m.len()).unwrap_or(0);
            let factor = if matches!(spec, SourceSpec::Raw(..)) {
                4
            } else {
                8
            };
            len.saturating_mul(factor)
        }
    };
    let need = pinbake::bake::estimate_output_bytes(&probe).saturating_add(input_bytes);
    budget.check(&format!("baking {}", args.input.display()), need)?;
    // The temp file beside the target exists from here on, registered for removal on
    // SIGINT/SIGTERM; a stale one of an earlier killed bake is swept away by its creation.
    let pending = pinbake::files::PendingPin::create(&args.output)
        .with_context(|| format!("{}", args.output.display()))?;
    let source = source::open_source(&spec)?;
    let choice = choose_from_args(args, source.as_ref())?;
    let mut opts = options_from_args(args, source.as_ref(), &spec, &choice)?;
    // The check above assumed the default's size; a chosen bake may be larger, and a large
    // dense grid is marched by layers with a batch of per-pin state beside it.
    let need = pinbake::bake::estimate_output_bytes(&opts)
        .saturating_add(input_bytes)
        .saturating_add(pinbake::bake::estimate_working_bytes(&opts));
    budget.check(&format!("baking {}", args.input.display()), need)?;
    // A sparse VDB is copied into a dense grid when the copy fits in what the budget leaves.
    opts.dense_copy_bytes = budget.limit.saturating_sub(need);

    let total = pinbake::bake::pin_count(&opts);
    let bar = if !args.quiet && std::io::stderr().is_terminal() {
        let bar = ProgressBar::new(total);
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} baking [{bar:40}] {pos}/{len} pins  {per_sec}  eta {eta}",
            )
            .expect("static template")
            .progress_chars("=> "),
        );
        bar.enable_steady_tick(Duration::from_millis(200));
        bar
    } else {
        ProgressBar::hidden()
    };
    let started = Instant::now();
    let progress = |n: u64| bar.inc(n);
    let (grid, stats) = pinbake::bake(source.as_ref(), &opts, &progress)
        .with_context(|| args.input.display().to_string())?;
    bar.finish_and_clear();
    // Checked again just before the rename: the path may have been replaced during the bake.
    let target = inputs.check_output(&args.output)?;
    if target != args.output {
        // A symlink to a regular file: the file it points to is replaced, the link stays.
        drop(pending);
        pinbake::files::write_pin_atomic(&grid, &target)
    } else {
        pending.write(&grid)
    }
    .with_context(|| format!("{}", args.output.display()))?;
    let file_bytes = std::fs::metadata(&target)
        .with_context(|| format!("{}", args.output.display()))?
        .len();
    let seconds = started.elapsed().as_secs_f64();
    let mut v = super::inspect::summary_json(&grid, file_bytes, Some(&stats));
    v["seconds"] = serde_json::json!(seconds);
    v["bake_seconds"] = serde_json::json!(stats.seconds);
    v["pins_per_s"] = serde_json::json!(stats.pins_per_s);
    v["output"] = serde_json::json!(args.output.display().to_string());
    v["choice"] = choice_json(&choice, file_bytes);
    if !args.json {
        pinbake::errln!(
            "baked {} -> {}: {} cells ({} empty), {} pins stored, {} bytes, {:.2} s ({:.3} Mpins/s)",
            args.input.display(),
            args.output.display(),
            stats.covered_cells,
            stats.empty_cells,
            stats.pins,
            file_bytes,
            seconds,
            stats.pins_per_s / 1e6
        );
    }
    Ok(v)
}

/// `--json`'s `choice` object: what was chosen, why, and what the model predicts.
fn choice_json(c: &Choice, file_bytes: u64) -> serde_json::Value {
    serde_json::json!({
        "cells": c.cells,
        "directions": super::inspect::directions_json(c.directions),
        "pins_per_entry": c.pins_per_entry,
        "predicted_error": c.predicted_error,
        "target_error": c.target_error,
        "target_met": c.target_met,
        "capped_by_voxels": c.capped_by_voxels,
        "predicted_pin_bytes": c.predicted_pin_bytes,
        "bytes": file_bytes,
        "reason": {
            "cells": c.reason_cells,
            "directions": c.reason_directions,
            "pins_per_entry": c.reason_pins_per_entry,
        },
        "volume": c.stats,
    })
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
