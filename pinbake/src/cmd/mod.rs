//! Subcommands of the `pinbake` binary.

mod bake;
mod bench;
mod frames;
mod inspect;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use pin_volume::files::MemoryBudget;

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
slab of a VDB); `pinbake merge` of the part files gives the same bytes too. Run
`pinbake grid-stats smoke.vdb -o stats.json` once and give every part `--grid-stats
stats.json`: each part then decodes only its slab's leaves.

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
        /// Refuse a merge that would hold more than this many bytes (K/M/G/T suffixes;
        /// default: half of the physical memory): twice the inputs' size, and for parts the
        /// merged grid's pins and tables on top, checked before they are allocated.
        #[arg(long, value_parser = pin_cli::parse::parse_bytes)]
        max_memory: Option<u64>,
        /// Print one JSON object (the merged file's summary, as `inspect --json`, with the
        /// merge's seconds) on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Write the whole grid's statistics that the parts of a farm bake of an OpenVDB file
    /// take with `bake --part I/N --grid-stats FILE`: one pass over every leaf, once per bake.
    GridStats(Box<GridStatsArgs>),
    /// Bake the thesis' largest configuration and print pins/s for 1 and 2 threads.
    Bench(Box<BenchArgs>),
}

/// `pinbake grid-stats INPUT -o STATS`.
#[derive(clap::Args, Debug)]
pub struct GridStatsArgs {
    /// The OpenVDB file the parts will bake.
    pub input: PathBuf,
    /// The statistics file (JSON; written atomically; a new path or a regular file other
    /// than the input).
    #[arg(short, long)]
    pub output: PathBuf,
    /// How to read the input: the same grid, level-set and density-scale flags as every
    /// part's bake.
    #[command(flatten)]
    pub volume: pinbake::cli_args::SourceArgs,
    /// Cap the reader's memory at this many bytes (K/M/G/T suffixes; default: 64 MiB + 64 x
    /// the file's size, at most 16 GiB): the statistics pass holds the tree's topology in the
    /// reader and no leaves, so a pass over a larger tree is refused in one line.
    #[arg(long, value_parser = pin_cli::parse::parse_bytes)]
    pub max_memory: Option<u64>,
    /// Print the statistics and the seconds as one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

pub fn run(cli: Cli) -> Result<ExitCode> {
    match cli.command {
        // A sequence bakes each frame as `bake` does one volume.
        Command::Bake(args) if args.frames.is_some() => frames::run_sequence(*args),
        Command::Bake(args) => bake::run(*args),
        Command::Inspect { file, json } => inspect::run(&file, json),
        Command::Verify { files } => {
            for file in &files {
                let bytes = map_pin_file(file)?;
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
        Command::GridStats(args) => grid_stats(&args),
        Command::Bench(args) => bench::run(*args),
    }
}

/// `pinbake grid-stats`: the statistics pass of a farm bake split by volume.
fn grid_stats(args: &GridStatsArgs) -> Result<ExitCode> {
    use pin_volume::{InputKind, SourceSpec, VdbSource, nanovdb};
    let started = std::time::Instant::now();
    let spec = args.volume.source_spec(&args.input, "input", || {
        std::env::current_exe().context("locating the pinbake binary")
    })?;
    let (path, opts) = match spec {
        SourceSpec::Vdb(path, o)
            if InputKind::of(&path) != InputKind::NanoVdb && !nanovdb::is_nanovdb_file(&path) =>
        {
            (path, o)
        }
        _ => usage!(
            "grid-stats reads an OpenVDB file; {} is not one (its parts read it whole)",
            args.input.display()
        ),
    };
    let target = check_output(&args.output, &[&path])?;
    let mut opts = opts;
    if let Some(max) = args.max_memory {
        let size = pin_volume::files::check_input(&path)?;
        let default = pin_volume::vdb::default_memory_limit(size);
        opts.memory_limit = Some(max.min(default));
    }
    let stats = VdbSource::grid_stats(&path, &opts, args.volume.density_scale)?;
    let text = format!("{}\n", stats.to_json());
    write_text_atomic(&target, &text)
        .with_context(|| format!("writing {}", args.output.display()))?;
    let seconds = started.elapsed().as_secs_f64();
    if args.json {
        let mut v: serde_json::Value = serde_json::from_str(&text)?;
        v["output"] = serde_json::json!(args.output.display().to_string());
        v["seconds"] = serde_json::json!(seconds);
        pin_cli::outln!("{v}")?;
    } else {
        pin_cli::errln!(
            "grid statistics of {} -> {}: {} leaves, {} non-zero, {:.2} s",
            args.input.display(),
            args.output.display(),
            stats.leaves,
            stats.nonzero_leaves,
            seconds
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// Reads a statistics file of `pinbake grid-stats` (at most 1 MiB).
pub fn read_grid_stats(path: &std::path::Path) -> Result<pin_volume::GridStats> {
    use std::io::Read;
    let shown = path.display();
    let (f, size) = pin_volume::files::open_input(path)?;
    if size > 1 << 20 {
        anyhow::bail!("{shown}: is not a grid statistics file ({size} bytes)");
    }
    let mut text = String::new();
    f.take(1 << 20)
        .read_to_string(&mut text)
        .map_err(|_| anyhow::anyhow!("{shown}: is not a grid statistics file (not text)"))?;
    let mut stats =
        pin_volume::GridStats::from_json(&text).map_err(|e| anyhow::anyhow!("{shown}: {e}"))?;
    stats.path = Some(path.to_path_buf());
    Ok(stats)
}

/// Writes `text` to a temp file beside `target`, synced, renamed into place.
fn write_text_atomic(target: &std::path::Path, text: &str) -> std::io::Result<()> {
    use std::io::Write;
    let dir = match target.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => std::path::Path::new("."),
    };
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "stats".into());
    let temp = dir.join(format!(".{name}.{}.partial", std::process::id()));
    let _announced = pin_volume::files::announce_partial_file(&temp);
    let result = (|| {
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&temp)?;
        f.write_all(text.as_bytes())?;
        f.sync_all()?;
        std::fs::rename(&temp, target)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&temp);
    }
    result
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
        total = total.saturating_add(pin_volume::files::check_input(t)?);
    }
    let budget = MemoryBudget::new(max_memory);
    budget.check("merging these files", total.saturating_mul(2))?;
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
        // The grid and its tables come on top of the part files and their decoded copies.
        let left = budget.limit.saturating_sub(total.saturating_mul(2));
        pinbake::part::merge_parts_within(&decoded, Some(left))?.0
    };
    // Checked again just before the write: the path may have changed meanwhile.
    let target = check_output(output, &inputs)?;
    pin_volume::files::write_pin_atomic(&merged, &target)
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
    Ok(pin_volume::files::read_input(path, budget)?)
}

/// A pin file's bytes for a command that reads them once (`inspect`, `verify`): mapped, so
/// that a file of any size is read in place from the page cache, not copied into memory
/// (a copy made a 3.2 GB file cost 3.2 GB and 16 s to inspect, and one larger than the
/// memory budget could not be inspected at all).
pub enum PinBytes {
    Mapped(memmap2::Mmap),
    /// An empty file, which has nothing to map.
    Empty,
}

impl std::ops::Deref for PinBytes {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            Self::Mapped(m) => m,
            Self::Empty => &[],
        }
    }
}

/// Maps `path` read-only (a regular file only, opened without blocking). As for every
/// mapped reader (`pinrt::PinGrid::open`), a file truncated in place while the command runs
/// raises SIGBUS; pin files are replaced by rename, never rewritten in place.
pub fn map_pin_file(path: &std::path::Path) -> Result<PinBytes> {
    let (file, len) = pin_volume::files::open_input(path)?;
    if len == 0 {
        return Ok(PinBytes::Empty);
    }
    // SAFETY: read-only; every value read from the map is validated before use, so changed
    // bytes give wrong answers or errors, not memory unsafety (see above for truncation).
    let map = unsafe { memmap2::Mmap::map(&file) }
        .with_context(|| format!("{}: cannot map the file", path.display()))?;
    Ok(PinBytes::Mapped(map))
}

/// [`pin_volume::files::check_output`] with its error as an `anyhow` error.
pub fn check_output(output: &std::path::Path, inputs: &[&std::path::Path]) -> Result<PathBuf> {
    Ok(pin_volume::files::check_output(output, inputs)?)
}

pub use pin_cli::UsageError;

/// Returns a [`UsageError`] from the enclosing function.
pub(crate) use pin_cli::usage;
