//! Subcommands of the `pinbake` binary.

mod bake;
mod bench;
mod frames;
mod inspect;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use pinbake::files::MemoryBudget;

pub use bake::BakeArgs;
pub use bench::BenchArgs;

const ABOUT: &str = "Bake volumetric density into pin transmittance grids.";

const LONG_ABOUT: &str = "\
Bake volumetric density (OpenVDB, NanoVDB, headerless raw grids or procedural fields) into a
compact pin grid file that pinrt samples on the CPU and the GPU.

Typical use:
  pinbake bake smoke.vdb -o smoke.pin
  pinbake inspect smoke.pin
  pinbake verify smoke.pin

Farm bakes: run `pinbake bake ... --tile I/N -o part_I.pin` for I in 0..N anywhere, then
`pinbake merge part_*.pin -o full.pin` gives the same bytes as a single bake. For a volume
too large for one node, `--part I/N` splits the volume instead (each part reads only its
slab of a VDB); `pinbake merge` of the part files gives the same bytes too.

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
    /// Join the tiles of a `--tile I/N` bake, or the part files of a `--part I/N` bake, into
    /// one file.
    Merge {
        /// Tile files or part files (not both), any order.
        #[arg(required = true)]
        tiles: Vec<PathBuf>,
        /// Output pin file (written atomically; a new path or a regular file, not a tile).
        #[arg(short, long)]
        output: PathBuf,
        /// Refuse tiles whose total size exceeds this many bytes (K/M/G/T suffixes; default:
        /// half of the physical memory).
        #[arg(long, value_parser = pin_cli::parse::parse_bytes)]
        max_memory: Option<u64>,
        /// Print one JSON object (the merged file's summary, as `inspect --json`, with the
        /// merge's seconds) on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Bake the thesis' largest configuration and print pins/s for 1 and 2 threads.
    Bench(BenchArgs),
}

pub fn run(cli: Cli) -> Result<ExitCode> {
    match cli.command {
        Command::Bake(args) => bake::run(*args),
        Command::Inspect { file, json } => inspect::run(&file, json),
        Command::Verify { files } => {
            let budget = MemoryBudget::new(None);
            for file in &files {
                let bytes = read_file(file, &budget)?;
                let parsed = pin_format::PinFile::parse(&bytes)
                    .with_context(|| format!("{}", file.display()))?;
                parsed
                    .verify()
                    .with_context(|| format!("{}", file.display()))?;
                pin_cli::outln!("{}: ok", file.display())?;
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Merge {
            tiles,
            output,
            max_memory,
            json,
        } => merge(&tiles, &output, max_memory, json),
        Command::Bench(args) => bench::run(args),
    }
}

/// `pinbake merge`: tiles or parts, told apart by their first bytes.
fn merge(
    tiles: &[PathBuf],
    output: &std::path::Path,
    max_memory: Option<u64>,
    json: bool,
) -> Result<ExitCode> {
    let started = std::time::Instant::now();
    let inputs: Vec<&std::path::Path> = tiles.iter().map(PathBuf::as_path).collect();
    check_output(output, &inputs)?;
    // The inputs are held in memory together, and the merged grid once more.
    let mut total = 0u64;
    for t in tiles {
        total = total.saturating_add(pinbake::files::check_input(t)?);
    }
    let budget = MemoryBudget::new(max_memory);
    budget.check("merging the tiles", total.saturating_mul(2))?;
    let data: Vec<(String, Vec<u8>)> = tiles
        .iter()
        .map(|t| Ok((t.display().to_string(), read_file(t, &budget)?)))
        .collect::<Result<_>>()?;
    let parts = data
        .iter()
        .filter(|(_, b)| pinbake::part_file::is_part_file(b))
        .count();
    let merged = if parts == 0 {
        let parsed = data
            .iter()
            .map(|(n, b)| {
                pin_format::PinFile::parse(b)
                    .map(|f| (n.clone(), f))
                    .with_context(|| n.clone())
            })
            .collect::<Result<Vec<_>>>()?;
        pinbake::merge_tiles(&parsed)?
    } else {
        if parts != data.len() {
            let tile = data
                .iter()
                .find(|(_, b)| !pinbake::part_file::is_part_file(b))
                .map_or("", |(n, _)| n.as_str());
            anyhow::bail!(
                "{tile}: not a part file; merge either tiles (--tile) or parts (--part), not both"
            );
        }
        let decoded = data
            .into_iter()
            .map(|(n, b)| {
                let d = pinbake::part_file::decode(&b).with_context(|| n.clone())?;
                Ok((n, d))
            })
            .collect::<Result<Vec<_>>>()?;
        pinbake::merge_parts(&decoded)?.0
    };
    // Checked again just before the write: the path may have changed meanwhile.
    let target = check_output(output, &inputs)?;
    pinbake::files::write_pin_atomic(&merged, &target)
        .with_context(|| format!("{}", output.display()))?;
    if json {
        let bytes = std::fs::metadata(&target)
            .with_context(|| format!("{}", output.display()))?
            .len();
        let mut v = pinbake::summary::summary_json(&merged, bytes)
            .with_context(|| format!("{}", output.display()))?;
        v["merged"] = serde_json::json!(tiles.len());
        v["kind"] = serde_json::json!(if parts == 0 { "tiles" } else { "parts" });
        v["output"] = serde_json::json!(output.display().to_string());
        v["seconds"] = serde_json::json!(started.elapsed().as_secs_f64());
        pin_cli::outln!("{v}")?;
    }
    Ok(ExitCode::SUCCESS)
}

/// Reads a whole regular file (refusing devices, FIFOs and directories, and files larger
/// than the memory budget) into a buffer whose start is 8-byte aligned on the supported
/// allocators (the reader casts in place and reports a misaligned buffer).
pub fn read_file(path: &std::path::Path, budget: &MemoryBudget) -> Result<Vec<u8>> {
    Ok(pinbake::files::read_input(path, budget)?)
}

/// [`pinbake::files::check_output`] with its error as an `anyhow` error.
pub fn check_output(output: &std::path::Path, inputs: &[&std::path::Path]) -> Result<PathBuf> {
    Ok(pinbake::files::check_output(output, inputs)?)
}

pub use pin_cli::UsageError;

/// Returns a [`UsageError`] from the enclosing function.
pub(crate) use pin_cli::usage;
