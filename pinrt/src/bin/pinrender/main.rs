//! `pinrender`: the reference renderer and benchmarks on real volumes and pin files.
//!
//! Subcommands: `bench` (pins vs ray marching queries per second, CPU and wgpu), `render`
//! (one image with a chosen estimator), `eval` (error against run time of every estimator on
//! the evaluation scenes). Exit codes: 0 success, 1 bad input, 2 usage error.

mod bench;
mod data;
mod eval;
mod render_cmd;
mod volume;

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
    Bench(Box<bench::BenchArgs>),
    /// Render one image of a volume with a chosen estimator.
    Render(Box<render_cmd::RenderArgs>),
    /// Error against run time of every estimator on the evaluation scenes (CSV, plots, report).
    Eval(Box<eval::EvalArgs>),
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().collect();
    // The isolated OpenVDB reader re-executes this binary (see `pinbake::source::vdb`).
    if args.get(1).map(String::as_str) == Some("__vdb-worker") {
        return ExitCode::from(pinbake::source::vdb::worker_main(&args[2..]).clamp(0, 255) as u8);
    }
    let cli = Cli::parse_from(args);
    let result = match cli.command {
        Command::Bench(a) => bench::run(*a),
        Command::Render(a) => render_cmd::run(*a),
        Command::Eval(a) => eval::run(*a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let msg = format!("{e:#}").replace(['\n', '\r'], " ");
            eprintln!("pinrender: error: {msg}");
            ExitCode::from(1)
        }
    }
}
