//! Subcommands of the `pinbake` binary.

mod bake;
mod bench;
mod frames;
mod inspect;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};

pub use bake::BakeArgs;
pub use bench::BenchArgs;

const ABOUT: &str = "Bake volumetric density into pin transmittance grids.";

const LONG_ABOUT: &str = "\
Bake volumetric density (OpenVDB, headerless raw grids or procedural fields) into a compact
pin grid file that pinrt samples on the CPU and the GPU.

Typical use:
  pinbake bake smoke.vdb -o smoke.pin
  pinbake inspect smoke.pin
  pinbake verify smoke.pin

Farm bakes: run `pinbake bake ... --tile I/N -o part_I.pin` for I in 0..N anywhere, then
`pinbake merge part_*.pin -o full.pin` gives the same bytes as a single bake.

Exit codes: 0 success, 1 bad input or failed check, 2 usage error.";

#[derive(Parser, Debug)]
#[command(name = "pinbake", version, about = ABOUT, long_about = LONG_ABOUT)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Bake a volume into a pin file.
    Bake(Box<BakeArgs>),
    /// Print a pin file's header, sections, sizes and t_min statistics.
    Inspect {
        /// The pin file.
        file: PathBuf,
        /// Print one JSON object instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Check every checksum and value of a pin file (exit 1 on damage).
    Verify {
        /// The pin file(s).
        #[arg(required = true)]
        files: Vec<PathBuf>,
    },
    /// Join the tiles of a `--tile I/N` bake into one file.
    Merge {
        /// Tile files, any order.
        #[arg(required = true)]
        tiles: Vec<PathBuf>,
        /// Output pin file (written atomically).
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Bake the thesis' largest configuration and print pins/s for 1 and 2 threads.
    Bench(BenchArgs),
}

pub fn run(cli: Cli) -> Result<ExitCode> {
    match cli.command {
        Command::Bake(args) => bake::run(*args),
        Command::Inspect { file, json } => inspect::run(&file, json),
        Command::Verify { files } => {
            for file in &files {
                let bytes = read_file(file)?;
                let parsed = pin_format::PinFile::parse(&bytes)
                    .with_context(|| format!("{}", file.display()))?;
                parsed
                    .verify()
                    .with_context(|| format!("{}", file.display()))?;
                println!("{}: ok", file.display());
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Merge { tiles, output } => {
            let data: Vec<(String, Vec<u8>)> = tiles
                .iter()
                .map(|t| Ok((t.display().to_string(), read_file(t)?)))
                .collect::<Result<_>>()?;
            let parsed = data
                .iter()
                .map(|(n, b)| {
                    pin_format::PinFile::parse(b)
                        .map(|f| (n.clone(), f))
                        .with_context(|| n.clone())
                })
                .collect::<Result<Vec<_>>>()?;
            let merged = pinbake::merge_tiles(&parsed)?;
            merged
                .write_atomic(&output)
                .with_context(|| format!("{}", output.display()))?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Bench(args) => bench::run(args),
    }
}

/// Reads a whole file into a buffer whose start is 8-byte aligned (the reader casts in place).
pub fn read_file(path: &std::path::Path) -> Result<Vec<u8>> {
    std::fs::read(path).with_context(|| format!("{}", path.display()))
}
