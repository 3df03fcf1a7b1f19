//! `pinrender`: the reference renderer and benchmarks on real volumes and pin files.
//!
//! Subcommands: `bench` (pins vs ray marching queries per second, CPU and wgpu), `render`
//! (one image with a chosen estimator), `eval` (error against run time of every estimator on
//! the evaluation scenes), `shaders` (pin.wgsl in SPIR-V, GLSL, HLSL and MSL). Exit codes: 0 success, 1 bad input, 2 usage error.

mod bench;
mod bias_plot;
mod data;
mod eval;
mod plot_canvas;
mod render_cmd;
mod scene_cmd;
mod shaders;

// The volume adapters live in the library (its tests link against them); the subcommands
// reach them as `crate::volume`.
use pinrender::volume;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(
    name = "pinrender",
    version,
    about = "Render and benchmark pin grids against ray marching and trackers."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Queries per second: pins vs ray marching (steps 0.015 and 0.005) on the same rays.
    Bench(Box<bench::RenderBenchArgs>),
    /// Render one image of a volume with a chosen estimator.
    Render(Box<render_cmd::RenderArgs>),
    /// Error against run time of every estimator on the evaluation scenes (CSV, plots, report).
    Eval(Box<eval::EvalArgs>),
    /// Plot scripts/bias_sweep.sh's CSV: pins' block error against pin bytes (PNG).
    PlotBias(bias_plot::PlotBiasArgs),
    /// Write shaders/pin.wgsl as SPIR-V, GLSL 450, HLSL and MSL (naga) into a directory.
    Shaders(shaders::ShadersArgs),
    /// List every estimator: its --estimator name, whether it reads a pin file (needs_bake),
    /// whether it is unbiased, and whether the GPU path tracer runs it.
    Estimators {
        /// One JSON object: {"estimators": [{"name", "needs_bake", "unbiased", "gpu",
        /// "summary"}]}.
        #[arg(long)]
        json: bool,
    },
}

/// `pinrender estimators`: the catalogue of [`pinlab::estimators`] (the renderer's and the
/// lab's).
fn list_estimators(json: bool) -> anyhow::Result<()> {
    let catalogue = pinlab::estimators();
    if json {
        let rows: Vec<serde_json::Value> = catalogue
            .iter()
            .map(|e| {
                serde_json::json!({
                    "name": e.name,
                    "needs_bake": e.estimator.needs_pins(),
                    "unbiased": e.estimator.is_unbiased(),
                    "gpu": e.estimator.runs_on_gpu(),
                    "summary": e.summary,
                })
            })
            .collect();
        pin_cli::outln!("{}", serde_json::json!({ "estimators": rows }))?;
        return Ok(());
    }
    for e in catalogue {
        pin_cli::outln!(
            "{:<13} {:<10} {:<8} {:<8} {}",
            e.name,
            if e.estimator.needs_pins() {
                "bake"
            } else {
                "no bake"
            },
            if e.estimator.is_unbiased() {
                "unbiased"
            } else {
                "biased"
            },
            if e.estimator.runs_on_gpu() {
                "cpu+gpu"
            } else {
                "cpu"
            },
            e.summary
        )?;
    }
    Ok(())
}

fn main() -> ExitCode {
    // `args_os`: a path need not be UTF-8 (`std::env::args` panics on one).
    let args: Vec<std::ffi::OsString> = std::env::args_os().collect();
    // The isolated OpenVDB reader re-executes this binary (see `pin_volume::vdb`).
    if let Some(code) = pin_volume::vdb::serve_vdb_worker_if_asked(&args) {
        return code;
    }
    // Partial output files (`bench --save-pins`) are unlinked on SIGINT, SIGTERM and SIGHUP.
    pin_volume::files::watch_partial_files(pin_cli::signals::track);
    pin_cli::run_main("pinrender", args, |cli: Cli| {
        match cli.command {
            Command::Bench(a) => bench::run(*a),
            // A scene file renders through its own command, which builds on the render
            // command's outputs (so the render command does not call back into it).
            Command::Render(a) => match a.scene.clone() {
                Some(path) => scene_cmd::run(*a, &path),
                None => render_cmd::run(*a),
            },
            Command::Estimators { json } => list_estimators(json),
            Command::Eval(a) => eval::run(*a),
            Command::Shaders(a) => shaders::run(a),
            Command::PlotBias(a) => bias_plot::run(a),
        }
        .map(|()| ExitCode::SUCCESS)
    })
}

/// Returns a [`pin_cli::UsageError`] (exit code 2) from the enclosing function.
pub(crate) use pin_cli::usage;
