//! `pinbake bench`: the thesis' largest configuration (37^3 cells x 16x4 directions) baked
//! from a 512^3 voxelisation of cosine noise (and from the analytic noise), for 1 and 2 threads.
//!
//! Every row reports `wall_s`, `pins_per_s`, `threads`, `peak_rss_bytes` (the process's
//! high-water mark so far, from /proc; null where unavailable) and `integration_error` (the
//! mean absolute error of the interval transmittances against a 16x supersampled march, over
//! 256 random pins: [`pinbake::pin::integration_error_of`]). Beside them: `cpu_s` (user +
//! system CPU seconds of the bake, steadier than wall time on a shared machine).
//!
//! `--backend cpu,gpu` runs each bake on both backends (`backend` in each row); a GPU row adds
//! `gpu`, where its time went ([`pinbake::GpuBakeTimes`]: device, upload, jobs, dispatch). A
//! `--default` row set bakes the 512^3 grid with the default options, and `--source INPUT` adds
//! rows for the default bake of any input (`bake` in each row names the configuration).

use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use glam::DVec3;
use pin_format::Directions;
use pin_volume::procedural::ProceduralKind;
use pin_volume::{DenseGrid, DensitySource, ProceduralSpec};
use pinbake::BakeOptions;
use pinbake::pin::{Field, integration_error_of};
use rayon::prelude::*;
use serde_json::json;

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Spatial cells per axis (1..=4096).
    #[arg(long, default_value_t = 37, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub cells: u32,
    /// Voxels per axis of the voxelised noise volume (1..=4096).
    #[arg(long, default_value_t = 512, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub voxels: u32,
    /// Thread counts to run, comma separated.
    #[arg(long, default_value = "1,2", value_delimiter = ',', value_parser = pinbake::cli_args::parse_threads)]
    pub threads: Vec<usize>,
    /// Refuse a configuration that needs more than this many bytes of memory (K/M/G/T
    /// suffixes; default: half of the physical memory).
    #[arg(long, value_parser = pin_cli::parse::parse_bytes)]
    pub max_memory: Option<u64>,
    /// Only the voxelised grid (skip the slower analytic-noise rows).
    #[arg(long)]
    pub grid_only: bool,
    /// Backends to run each bake on, comma separated: cpu, gpu.
    #[arg(long, default_value = "cpu", value_delimiter = ',', value_parser = ["cpu", "gpu"])]
    pub backend: Vec<String>,
    /// Also bake the voxelised grid with the default options (the default cells and
    /// directions), beside the thesis' 37^3 x 16x4.
    #[arg(long)]
    pub default: bool,
    /// Also bake this input (a volume file or `procedural:...`) with the default options.
    #[arg(long)]
    pub source: Option<std::path::PathBuf>,
    #[command(flatten)]
    pub volume: pinbake::cli_args::SourceArgs,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// The bake's entries computed on `name` ("cpu" or "gpu").
fn backend_of(name: &str) -> pinbake::BakeBackend {
    match name {
        "gpu" => pinbake::BakeBackend::Gpu(pinbake::GpuBakeOptions::default()),
        _ => pinbake::BakeBackend::Cpu,
    }
}

pub fn run(args: BenchArgs) -> Result<ExitCode> {
    let mut spec = ProceduralSpec::new(ProceduralKind::Cosine);
    spec.noise.seed = 7;
    let noise = spec.build_noise()?;
    let n = args.voxels;
    let voxels = u64::from(n).pow(3);
    // The bake every row runs (the thesis' 16x4 directions), its thread count aside.
    let bench_bake = BakeOptions {
        cells: [args.cells; 3],
        directions: Directions::THESIS_DEFAULT,
        majorant: None,
        ..BakeOptions::default()
    };
    // The voxels, that bake's output (the check used to size it for the default
    // octahedral:16, 4x too large) and its layered march's working set (which it left out:
    // up to ~110 MB).
    pin_volume::files::MemoryBudget::new(args.max_memory).check(
        "the benchmark volume and bake",
        voxels
            .saturating_mul(4)
            .saturating_add(pinbake::bake::estimate_output_bytes(&bench_bake))
            .saturating_add(pinbake::bake::estimate_working_bytes(&bench_bake))
            .saturating_add(if args.default || args.source.is_some() {
                pinbake::bake::estimate_output_bytes(&BakeOptions::default()).saturating_add(
                    pinbake::bake::estimate_working_bytes(&BakeOptions::default()),
                )
            } else {
                0
            }),
    )?;
    let t0 = Instant::now();
    let h = 1.0 / f64::from(n);
    let row = n as usize;
    let mut data = Vec::new();
    data.try_reserve_exact(row * row * row)
        .map_err(|_| anyhow::anyhow!("cannot allocate {} bytes for the voxels", voxels * 4))?;
    data.resize(row * row * row, 0.0f32);
    // One x-row per call so the noise can step its waves incrementally.
    data.par_chunks_mut(row).enumerate().for_each(|(i, out)| {
        let (y, z) = ((i % row) as f64, (i / row) as f64);
        let start = DVec3::new(0.5 * h, (y + 0.5) * h, (z + 0.5) * h);
        noise.extinction_along(start, DVec3::new(h, 0.0, 0.0), row, out);
    });
    let grid = DenseGrid::new([n; 3], data, DVec3::splat(h), DVec3::ZERO, "bench noise")?;
    let voxelise_s = t0.elapsed().as_secs_f64();

    let extra = match &args.source {
        None => None,
        Some(input) => {
            let spec = args.volume.source_spec(input, "--source", || {
                std::env::current_exe().context("locating the pinbake binary")
            })?;
            let source = pin_volume::open_source(&spec, args.volume.density_scale)
                .with_context(|| input.display().to_string())?;
            Some((input.display().to_string(), source))
        }
    };
    let grid_name = format!("noise {n}^3 grid");
    let thesis = format!("{}^3 x 16x4", args.cells);
    let mut sources: Vec<(String, &str, &dyn DensitySource, BakeOptions)> = Vec::new();
    if !args.grid_only {
        sources.push(("noise analytic".into(), &thesis, &noise, bench_bake.clone()));
    }
    sources.push((grid_name.clone(), &thesis, &grid, bench_bake.clone()));
    if args.default {
        sources.push((grid_name, "default", &grid, BakeOptions::default()));
    }
    if let Some((name, source)) = &extra {
        sources.push((
            name.clone(),
            "default",
            source.as_ref(),
            BakeOptions::default(),
        ));
    }
    let mut rows = Vec::new();
    for (name, config, source, base) in sources {
        // The bake's own rule against the 16x supersampled march of the source.
        let (bbox, _) = pinbake::bake::bake_box(source, base.crop)?;
        let placement = pinbake::pin::Placement::over(&bbox, base.step);
        let err = integration_error_of(Field::of(source), source, &placement, 256, 16, 1);
        for backend in &args.backend {
            for &threads in &args.threads {
                let opts = BakeOptions {
                    threads: Some(threads),
                    ..base.clone()
                };
                let cpu0 = cpu_seconds();
                let t = Instant::now();
                let (g, stats) = pinbake::bake_on(source, &opts, backend_of(backend), &|_| {})?;
                let wall = t.elapsed().as_secs_f64();
                let cpu = cpu_seconds().zip(cpu0).map(|(b, a)| b - a);
                let pins = pinbake::bake::pin_count(&opts);
                rows.push(json!({
                    "source": name,
                    "bake": config,
                    "backend": backend,
                    "threads": threads,
                    "pins": pins,
                    "stored_pins": g.pins.len(),
                    "wall_s": wall,
                    "pins_per_s": pins as f64 / wall,
                    "t_min_mean": stats.t_min_mean,
                    "peak_rss_bytes": peak_rss_bytes(),
                    "integration_error": err.mean_abs_transmittance,
                    "integration_error_max": err.max_abs_transmittance,
                    "optical_depth_rel_error": err.mean_rel_optical_depth,
                    "cpu_s": cpu,
                    "gpu": stats.gpu,
                }));
            }
        }
    }
    if args.json {
        pin_cli::outln!("{}", json!({"voxelise_s": voxelise_s, "results": rows}))?;
    } else {
        pin_cli::outln!(
            "pinbake bench: {c}^3 cells x 16x4 directions = {} pins, step 0.01 (voxelising {n}^3 took {voxelise_s:.1} s)",
            u64::from(args.cells).pow(3) * 64,
            c = args.cells
        )?;
        pin_cli::outln!(
            "{:<22} {:<12} {:<8} {:>8} {:>10} {:>14} {:>12} {:>12}",
            "source",
            "bake",
            "backend",
            "threads",
            "wall s",
            "pins/s",
            "peak RSS MB",
            "T error"
        )?;
        for r in &rows {
            pin_cli::outln!(
                "{:<22} {:<12} {:<8} {:>8} {:>10.2} {:>14.0} {:>12.0} {:>12.2e}",
                r["source"].as_str().unwrap_or(""),
                r["bake"].as_str().unwrap_or(""),
                r["backend"].as_str().unwrap_or(""),
                r["threads"],
                r["wall_s"].as_f64().unwrap_or(0.0),
                r["pins_per_s"].as_f64().unwrap_or(0.0),
                r["peak_rss_bytes"].as_f64().unwrap_or(f64::NAN) / 1e6,
                r["integration_error"].as_f64().unwrap_or(f64::NAN)
            )?;
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// The process's peak resident set so far (`VmHWM` in /proc/self/status), if the OS says.
fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// User plus system CPU seconds of this process so far (`/proc/self/stat`, in clock ticks of
/// 1/100 s on Linux), if the OS says: on a shared machine CPU time is the steadier figure.
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let (u, s): (f64, f64) = (f.get(11)?.parse().ok()?, f.get(12)?.parse().ok()?);
    Some((u + s) / 100.0)
}
