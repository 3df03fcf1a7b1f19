//! `pinbake::plan`: the one front door for a bake that ends in a file.
//!
//! A [`BakeRequest`] says what the caller wants (the flags of `pinbake bake`, with its
//! defaults); [`bake_to_file`] does everything a bake owes its user, in one place, for
//! every entry point (the `pinbake` binary, Python's `pinrt.bake`, pipelines in Rust):
//!
//! 1. the documented ranges of every option ([`BakeRequest::validate`]; a value outside
//!    them is [`PlanError::Usage`], exit 2 on the command line, `ValueError` in Python);
//! 2. the output rule: a new path or a regular file that is none of the inputs (an
//!    [`InputSet`], which for a sequence holds every frame's input), checked before the
//!    work and again just before the rename;
//! 3. the memory budget (`max_memory`, default half of the physical memory) before the
//!    source is opened and again once the bake's size is chosen;
//! 4. the choice of cells, directions and pins per entry from the volume
//!    ([`crate::choose`]) for those not given, the metadata and the options;
//! 5. the bake, the atomic write (a temp file beside the target, removed on SIGINT/SIGTERM)
//!    and the summary object of `pinbake bake --json` ([`Baked::summary`]).
//!
//! What it is not for: baking into memory without a file (`crate::bake` with options from
//! [`choose`]), or the command-line parsing (the `pinbake` binary).

use std::path::{Path, PathBuf};
use std::time::Instant;

use pin_format::{Directions, OwnedPinGrid};
use serde_json::{Value, json};

use crate::bake::{BakeOptions, BakeStats, Provenance, Tile};
use crate::choose::Choice;
use crate::error::BakeError;
use crate::part::Part;
use pin_volume::files::{FileError, InputSet, MemoryBudget, PendingPin};
use pin_volume::{self as source, DenseGrid, DensitySource, SourceError, SourceSpec};

/// What to bake from.
pub enum BakeInput {
    /// A file or procedural field (`source::open_source`).
    Source(SourceSpec),
    /// Voxels in memory: `values` x-fastest over `dims`, placed by `spacing` and `origin`
    /// (the raw-grid convention), before the request's density scale.
    Array {
        dims: [u32; 3],
        values: Vec<f32>,
        spacing: [f64; 3],
        origin: [f64; 3],
    },
}

impl BakeInput {
    /// The input's name in messages.
    fn name(&self) -> String {
        match self {
            BakeInput::Source(SourceSpec::Procedural(p)) => format!("procedural:{p}"),
            BakeInput::Source(spec) => spec_path(spec)
                .map(|p| p.display().to_string())
                .unwrap_or_default(),
            BakeInput::Array { dims, .. } => {
                format!("array {}x{}x{}", dims[0], dims[1], dims[2])
            }
        }
    }

    /// The file read, if any.
    pub fn path(&self) -> Option<&Path> {
        match self {
            BakeInput::Source(spec) => spec_path(spec),
            BakeInput::Array { .. } => None,
        }
    }
}

fn spec_path(spec: &SourceSpec) -> Option<&Path> {
    match spec {
        SourceSpec::Procedural(_) => None,
        #[cfg(feature = "vdb")]
        SourceSpec::Vdb(p, _) => Some(p),
        #[cfg(not(feature = "vdb"))]
        SourceSpec::Vdb(p) => Some(p),
        SourceSpec::Raw(p, _) => Some(p),
    }
}

/// The options of a bake, as `pinbake bake`'s flags; `Default` is its defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct BakeRequest {
    /// Spatial cells (chosen from the volume when `None`).
    pub cells: Option<[u32; 3]>,
    /// Direction cells (chosen when `None`).
    pub directions: Option<Directions>,
    /// Pins per (cell, direction) entry (chosen when `None`).
    pub pins_per_entry: Option<u32>,
    /// The predicted 8x8-block error to choose for, a fraction in (0, 1] (the default rule
    /// when `None`).
    pub target_error: Option<f64>,
    /// Ray-marching step relative to the longest box edge, in [1e-5, 1].
    pub step: f64,
    pub seed: u64,
    /// Crop the box to the non-empty region.
    pub crop: bool,
    /// Pins through random points of their cells (the thesis' bake) instead of the centres.
    pub jitter_pins: bool,
    pub tile: Option<Tile>,
    /// Majorant bricks per axis, 1..=4096 each; `None` leaves the section out.
    pub majorant: Option<[u32; 3]>,
    /// An embedded f16 density: dense, 1..=4096 voxels per axis, or sparse bricks (format
    /// 1.1) with these voxel dims.
    pub embed_density: Option<crate::EmbedDensity>,
    /// The control section for residual ratio tracking (format 1.1), by these options.
    pub embed_control: Option<crate::control::ControlOptions>,
    /// Worker threads, 1..=[`crate::limits::max_threads`] (all cores when `None`).
    pub threads: Option<usize>,
    /// Density multiplier, finite and >= 0: the source is opened with it
    /// ([`source::open_source`]) and the file records it.
    pub density_scale: f64,
    /// The memory budget in bytes (half of the physical memory when `None`).
    pub max_memory: Option<u64>,
    /// Where the pins' entries are computed: the CPU, or a wgpu compute pass.
    pub backend: crate::BakeBackend,
    /// The most bytes the file may take: the default asset's budget
    /// ([`crate::default_asset`]; when `None`, the source file's size plus
    /// [`crate::default_asset::ALLOWANCE`]), and a bound a bake of named parameters that is
    /// predicted larger is refused by.
    pub max_bytes: Option<u64>,
}

impl Default for BakeRequest {
    fn default() -> Self {
        let d = BakeOptions::default();
        Self {
            cells: None,
            directions: None,
            pins_per_entry: None,
            target_error: None,
            step: d.step,
            seed: d.seed,
            crop: d.crop,
            jitter_pins: d.jitter_pins,
            tile: None,
            majorant: d.majorant,
            embed_density: None,
            embed_control: None,
            threads: None,
            density_scale: d.density_scale,
            max_memory: None,
            backend: crate::BakeBackend::Cpu,
            max_bytes: None,
        }
    }
}

/// Why a bake was refused or failed. Messages are one line and name the file.
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    /// An option outside its range, or options that contradict each other.
    #[error("{0}")]
    Usage(String),
    #[error(transparent)]
    File(#[from] FileError),
    #[error(transparent)]
    Source(#[from] SourceError),
    /// The voxels of a [`BakeInput::Array`] are not a density (negative, not finite).
    #[error("array: {0}")]
    Array(SourceError),
    #[error("{input}: {source}")]
    Bake { input: String, source: BakeError },
    #[error("{}: {source}", pin_format::input::quoted(.path))]
    Write {
        path: PathBuf,
        source: pin_format::FormatError,
    },
}

impl PlanError {
    /// Whether the error is a refused memory budget or a failed allocation (Python raises
    /// `MemoryError` for these).
    pub fn is_memory(&self) -> bool {
        matches!(
            self,
            PlanError::File(FileError::Memory { .. })
                | PlanError::Source(SourceError::Memory { .. })
                | PlanError::Bake {
                    source: BakeError::Memory { .. } | BakeError::Alloc { .. },
                    ..
                }
        )
    }
}

fn usage(msg: String) -> PlanError {
    PlanError::Usage(msg)
}

impl BakeRequest {
    /// The density scale, validated: the one rule every surface applies
    /// ([`source::DensityScale::new`]).
    pub fn scale(&self) -> Result<source::DensityScale, PlanError> {
        source::DensityScale::new(self.density_scale).map_err(|_| {
            usage(format!(
                "density_scale: {} must be finite and >= 0",
                pin_format::text::num(self.density_scale)
            ))
        })
    }

    /// The documented range of every option (`docs/stability.md`, "Hostile use"): the same
    /// bounds the command line's parsers apply, so a library or Python caller cannot start
    /// a bake the command line would refuse (a step of 1e-12 ran for hours).
    pub fn validate(&self) -> Result<(), PlanError> {
        use crate::limits;
        limits::check_rel_step(self.step).map_err(|e| usage(format!("step: {e}")))?;
        self.scale()?;
        if let Some(e) = self.target_error
            && !(e.is_finite() && e > 0.0 && e <= 1.0)
        {
            return Err(usage(format!(
                "target_error: {} must be a fraction in (0, 1]",
                pin_format::text::num(e)
            )));
        }
        let max = pin_format::MAX_PINS_PER_ENTRY;
        if let Some(k) = self.pins_per_entry
            && !(1..=max).contains(&k)
        {
            return Err(usage(format!("pins_per_entry: {k} is not in 1..={max}")));
        }
        if let Some(t) = self.threads {
            limits::check_threads(t).map_err(|e| usage(format!("threads: {e}")))?;
        }
        if let Some(c) = self.cells
            && c.contains(&0)
        {
            return Err(usage(format!(
                "cells: {c:?}: every count must be at least 1"
            )));
        }
        for (name, v) in [
            ("majorant", self.majorant),
            (
                "embed_density",
                self.embed_density.and_then(crate::EmbedDensity::dense),
            ),
        ] {
            if let Some(d) = v
                && d.iter().any(|&n| !(1..=4096).contains(&n))
            {
                return Err(usage(format!(
                    "{name}: {d:?}: each axis must be in 1..=4096"
                )));
            }
        }
        if let Some(crate::control::ControlOptions {
            dims: crate::control::ControlDims::Edge(e),
            ..
        }) = self.embed_control
            && !(1..=64).contains(&e)
        {
            return Err(usage(format!(
                "embed_control: {e} is not a brick edge of 1..=64 voxels"
            )));
        }
        if let Some(d) = self.directions {
            let (k, r) = d.to_desc();
            Directions::from_desc(k, r).map_err(|e| usage(format!("directions: {e}")))?;
        }
        if let Some(t) = self.tile
            && (t.count == 0 || t.index >= t.count)
        {
            return Err(usage(format!(
                "tile: index {} must be in 0..{}",
                t.index, t.count
            )));
        }
        if self.max_bytes == Some(0) {
            return Err(usage("max_bytes: must be at least 1".into()));
        }
        if self.target_error.is_some()
            && self.cells.is_some()
            && self.directions.is_some()
            && self.pins_per_entry.is_some()
        {
            return Err(usage(
                "--target-error has nothing to choose: --cells, --dirs and --pins-per-entry are all given"
                    .into(),
            ));
        }
        Ok(())
    }
}

/// Checks the placement of an in-memory or raw grid: the ranges of `--spacing` and
/// `--origin` ([`crate::limits::check_spacing`], [`crate::limits::check_origin`]).
fn validate_input(input: &BakeInput) -> Result<(), PlanError> {
    let placement = match input {
        BakeInput::Array {
            dims,
            values,
            spacing,
            origin,
        } => {
            let n = dims.iter().map(|&d| d as u64).product::<u64>();
            if dims.contains(&0) || n != values.len() as u64 {
                return Err(usage(format!(
                    "array: {} values do not fill {}x{}x{} voxels",
                    values.len(),
                    dims[0],
                    dims[1],
                    dims[2]
                )));
            }
            Some((*spacing, *origin))
        }
        BakeInput::Source(SourceSpec::Raw(_, o)) => Some((o.spacing, o.origin)),
        BakeInput::Source(_) => None,
    };
    if let Some((spacing, origin)) = placement {
        crate::limits::check_spacing(spacing).map_err(|e| usage(format!("spacing: {e}")))?;
        crate::limits::check_origin(origin).map_err(|e| usage(format!("origin: {e}")))?;
    }
    if let BakeInput::Array {
        dims,
        spacing,
        origin,
        ..
    } = input
    {
        let max = [0, 1, 2].map(|a| origin[a] + spacing[a] * f64::from(dims[a]));
        pin_format::check_placement(*origin, max, &pin_format::IDENTITY_LOCAL_TO_WORLD)
            .map_err(|e| usage(format!("spacing and origin: {e}")))?;
    }
    Ok(())
}

/// What a bake reports while it runs: the pin count once it is known, then progress.
pub trait Progress: Sync {
    fn start(&self, _total_pins: u64) {}
    fn advance(&self, _pins: u64) {}
    /// A flag the caller sets to stop the bake ([`BakeOptions::cancel`]): the bake then
    /// fails with [`BakeError::Cancelled`] and leaves no output and no temp file.
    fn cancel_flag(&self) -> Option<std::sync::Arc<std::sync::atomic::AtomicBool>> {
        None
    }
}

/// No progress report.
impl Progress for () {}

/// A finished bake to a file.
pub struct Baked {
    pub grid: OwnedPinGrid,
    pub stats: BakeStats,
    pub choice: Choice,
    /// The path written: the output, or the file an output symlink points to.
    pub written: PathBuf,
    /// The output as the caller named it.
    pub output: PathBuf,
    pub file_bytes: u64,
    /// The peak memory this bake was estimated to need ([`memory_estimate`]), which
    /// `max_memory` was checked against.
    pub memory_estimate_bytes: u64,
    /// Wall time from the start of the bake (after the source was opened and the bake
    /// chosen) to the end of the write.
    pub seconds: f64,
}

impl Baked {
    /// The summary object of `pinbake bake --json` (`crate::summary` plus the bake's times,
    /// its output and its `choice`).
    pub fn summary(&self) -> Result<Value, pin_format::FormatError> {
        let mut v = crate::summary::summary_json(&self.grid, self.file_bytes)?;
        v["seconds"] = json!(self.seconds);
        v["bake_seconds"] = json!(self.stats.seconds);
        v["pins_per_s"] = json!(self.stats.pins_per_s);
        // A GPU bake's breakdown (device, upload, jobs, dispatch); absent for the CPU's.
        if let Some(gpu) = &self.stats.gpu {
            v["gpu"] = json!(gpu);
        }
        v["output"] = json!(self.output.display().to_string());
        v["memory_estimate_bytes"] = json!(self.memory_estimate_bytes);
        v["choice"] = crate::summary::choice_json(&self.choice, self.file_bytes);
        Ok(v)
    }
}

/// What a bake process holds besides its source and its bake: the binary, the thread
/// pool's stacks, the allocator's arenas (measured: 22 MB peak for a bake of a 1 MB VDB).
pub const PROCESS_BASE_BYTES: u64 = 24 << 20;

/// The peak memory of a bake of `source` with `opts` (before its dense copy is sized) and
/// the part of it that is that copy: the process base, what the source holds (exactly, where
/// it can say: [`DensitySource::footprint`]; else `input_bytes`), and the larger of what its
/// reader held beside it while opening and what the bake adds (the output and the sections
/// built after the pins, the per-pin state, and the dense copy that the bake makes when it
/// fits in `limit`).
pub fn memory_estimate(
    source: &dyn DensitySource,
    opts: &BakeOptions,
    input_bytes: u64,
    limit: u64,
) -> (u64, u64) {
    let (held, opening) = match source.footprint() {
        Some(f) => (f.held, f.while_opening.saturating_sub(f.held)),
        None => (input_bytes, 0),
    };
    // The sections built after the pins (sparse density, control) are held beside the
    // output until the file is written.
    let output = crate::bake::estimate_output_bytes(opts)
        .saturating_add(crate::bake::estimate_section_bytes(source, opts));
    // The layered march's per-pin state exists only beside a large dense grid.
    let layered = |grid_bytes: u64| {
        if grid_bytes >= crate::sweep::Sweep::default().min_grid_bytes as u64 {
            crate::bake::estimate_working_bytes(opts)
        } else {
            0
        }
    };
    let dense = source
        .as_dense_grid()
        .map_or(0, |g| size_of_val(g.data()) as u64);
    let before_copy = PROCESS_BASE_BYTES.saturating_add(held);
    let bake = output.saturating_add(layered(dense));
    let without = before_copy.saturating_add(bake.max(opening));
    let allowed = crate::bake::dense_copy_limit(&BakeOptions {
        dense_copy_bytes: limit.saturating_sub(without),
        ..opts.clone()
    });
    let copy = source
        .dense_copy_size()
        .filter(|&c| c <= allowed)
        .unwrap_or(0);
    let bake = output
        .saturating_add(copy)
        .saturating_add(layered(dense.max(copy)));
    (before_copy.saturating_add(bake.max(opening)), copy)
}

/// The spooled sparse density as the section to stream into the pin file, its bricks read
/// from the start of the spool.
fn streamed(
    spool: &mut Option<crate::sparse_density::SparseSpool>,
) -> Result<Option<pin_format::StreamedSparseDensity<'_>>, pin_format::FormatError> {
    Ok(spool.as_mut().map(|s| s.streamed()).transpose()?)
}

pub use pin_volume::files::hash_file;

/// The cells, directions and pins per entry of a bake of `source`: those `req` gives, the
/// rest chosen from the volume ([`crate::choose`]).
pub fn choose(source: &dyn DensitySource, req: &BakeRequest) -> Result<Choice, BakeError> {
    let stats = crate::choose::analyse(source, req.crop)?;
    let fixed = crate::choose::Fixed {
        cells: req.cells,
        directions: req.directions,
        pins_per_entry: req.pins_per_entry,
    };
    Ok(match req.target_error {
        Some(e) => crate::choose::choose(&stats, fixed, e),
        None => crate::choose::choose_default(&stats, fixed),
    })
}

/// The bake options of `choice` for `req`, with `metadata` (from [`crate::bake::bake_metadata`]
/// or default).
pub fn options(req: &BakeRequest, choice: &Choice, metadata: pin_format::Metadata) -> BakeOptions {
    BakeOptions {
        cells: choice.cells,
        directions: choice.directions,
        pins_per_entry: choice.pins_per_entry,
        step: req.step,
        seed: req.seed,
        crop: req.crop,
        jitter_pins: req.jitter_pins,
        tile: req.tile,
        majorant: req.majorant,
        embed_density: req.embed_density,
        embed_control: req.embed_control,
        threads: req.threads,
        density_scale: req.density_scale,
        metadata,
        dense_copy_bytes: crate::bake::DEFAULT_DENSE_COPY_BYTES,
        cancel: None,
    }
}

/// Everything [`bake_to_file`] and [`bake_part_to_file`] do before the bake itself.
fn prepare(
    input: BakeInput,
    output: &Path,
    req: &BakeRequest,
    inputs: &InputSet,
    part: Option<Part>,
) -> Result<Prepared, PlanError> {
    req.validate()?;
    validate_input(&input)?;
    if let Some(p) = part {
        validate_part(req, p)?;
    }
    let name = input.name();
    let own = match input.path() {
        Some(p) => InputSet::of(&[p])?,
        None => InputSet::default(),
    };
    // Before the bake, not after it: minutes of work for a refused path help nobody.
    pin_volume::files::check_output_among(output, &[inputs, &own])?;
    let budget = MemoryBudget::new(req.max_memory);
    let probe = BakeOptions {
        // Before the source is open: the default's upper bound.
        cells: req.cells.unwrap_or([crate::bake::DEFAULT_MAX_CELLS; 3]),
        directions: req.directions.unwrap_or(crate::bake::DEFAULT_DIRECTIONS),
        pins_per_entry: req.pins_per_entry.unwrap_or(1),
        majorant: req.majorant,
        // The dense section, whose size the options fix (a sparse one is counted once the
        // source is open).
        embed_density: req.embed_density.filter(|e| e.dense().is_some()),
        ..BakeOptions::default()
    };
    let input_bytes = match &input {
        // f32 voxels in memory: up to 4x the file for 8-bit input. A VDB's leaves are not
        // guessed from its (compressed) size: the worker counts them before they are read,
        // and the source refuses a table larger than what the budget leaves it (below).
        BakeInput::Source(spec) => match spec_path(spec) {
            Some(p) if matches!(spec, SourceSpec::Raw(..)) => std::fs::metadata(p)
                .map(|m| m.len())
                .unwrap_or(0)
                .saturating_mul(4),
            _ => 0,
        },
        // Already in memory (the grid takes it over without a copy), and held throughout.
        BakeInput::Array { values, .. } => (values.len() as u64).saturating_mul(4),
    };
    // The default asset's budget: what the user gave, else the input's own size.
    let max_bytes = req.max_bytes.unwrap_or_else(|| {
        let source_bytes = match &input {
            BakeInput::Source(spec) => spec_path(spec)
                .and_then(|p| std::fs::metadata(p).ok())
                .map_or(u64::MAX, |m| m.len()),
            BakeInput::Array { values, .. } => (values.len() as u64).saturating_mul(4),
        };
        source_bytes.saturating_add(crate::default_asset::ALLOWANCE)
    });
    let what = format!("baking {name}");
    let need = crate::bake::estimate_output_bytes(&probe)
        .saturating_add(input_bytes)
        .saturating_add(PROCESS_BASE_BYTES);
    budget.check(&what, need)?;
    #[cfg(feature = "vdb")]
    let input = match input {
        BakeInput::Source(SourceSpec::Vdb(path, mut o)) => {
            let left = budget.limit.saturating_sub(need);
            o.max_leaf_bytes = Some(o.max_leaf_bytes.map_or(left, |m| m.min(left)));
            o.part = part.map(|p| source::VdbPart {
                index: p.index,
                count: p.count,
            });
            BakeInput::Source(SourceSpec::Vdb(path, o))
        }
        other => other,
    };
    // The temp file beside the target exists from here on, registered for removal on
    // SIGINT/SIGTERM; a stale one of an earlier killed bake is swept away by its creation.
    let pending = PendingPin::create(output).map_err(|source| PlanError::Write {
        path: output.to_path_buf(),
        source,
    })?;
    let bake_err = |source| PlanError::Bake {
        input: name.clone(),
        source,
    };
    let (mut source, provenance_name, hash): (Box<dyn DensitySource>, String, String) = match input
    {
        BakeInput::Source(spec) => {
            let scale = req.scale()?;
            let (n, h) = match &spec {
                // The field's own description: its density scaled.
                SourceSpec::Procedural(p) => {
                    (format!("procedural:{}", p.scaled(scale)), String::new())
                }
                other => {
                    let p = spec_path(other).unwrap_or(Path::new(""));
                    (file_name(p), hash_file(p)?)
                }
            };
            // Grid statistics of another file (or of this file before it changed) would
            // make this part's bytes those of another bake.
            #[cfg(feature = "vdb")]
            if let SourceSpec::Vdb(path, o) = &spec
                && let (Some(_), Some(g)) = (&o.part, &o.grid_stats)
                && g.file_xxh3 != h
            {
                return Err(PlanError::Source(SourceError::Vdb {
                    path: path.clone(),
                    message: format!(
                        "{} were made for another file (content hash {}, this file's is {h}); make them again with `pinbake grid-stats`",
                        g.named(),
                        one_line_hash(&g.file_xxh3)
                    ),
                }));
            }
            (source::open_source(&spec, scale)?, n, h)
        }
        BakeInput::Array {
            dims,
            mut values,
            spacing,
            origin,
        } => {
            let scale = req.density_scale as f32;
            if scale != 1.0 {
                values.iter_mut().for_each(|v| *v *= scale);
            }
            let g = DenseGrid::new(
                dims,
                values,
                spacing.into(),
                origin.into(),
                format!("NumPy array {}x{}x{}", dims[0], dims[1], dims[2]),
            )
            .map_err(PlanError::Array)?;
            (Box::new(g), "<array>".into(), String::new())
        }
    };
    crate::placement::check_source_placement(source.as_ref(), req.crop).map_err(bake_err)?;
    let mut choice = choose(source.as_ref(), req).map_err(bake_err)?;
    let mut embed_density = req.embed_density;
    if default_asset_applies(req) {
        let target = req
            .target_error
            .unwrap_or(crate::default_asset::DEFAULT_ASSET_TARGET);
        if let Some(asset) = crate::default_asset::choose_asset(
            source.as_ref(),
            req.crop,
            &choice,
            req.majorant,
            target,
            max_bytes,
        ) {
            if let Some(embed) = asset.embed() {
                source = on_lattice(source, req.crop, asset.factor());
                let stats = crate::choose::analyse(source.as_ref(), req.crop).map_err(bake_err)?;
                let (fixed, _) = crate::default_asset::asset_pins(&stats);
                choice = crate::choose::choose(&stats, fixed, target);
                embed_density = Some(embed);
            }
            if !asset.target_met || !asset.fits {
                choice.warning = Some(asset.reason.clone());
            }
            choice.asset = Some(asset);
        }
    } else if let Some(factor) = match req.embed_density {
        Some(crate::EmbedDensity::Sparse(crate::sparse_density::SparseDims::Source)) => Some(1),
        Some(crate::EmbedDensity::Voxels { factor, .. }) => Some(factor),
        // Dense counts that name the source's resolution (or a whole F of it): its voxels on
        // its lattice, as `voxels:F`, not a resampling over the cropped box.
        Some(crate::EmbedDensity::Dense(dims)) => {
            let factor = crate::lattice_box::dims_factor(source.as_ref(), req.crop, dims);
            if let Some(factor) = factor {
                embed_density = Some(crate::EmbedDensity::Voxels {
                    factor,
                    sparse: false,
                });
            }
            factor
        }
        _ => None,
    } {
        // The source's own voxels: the box on its lattice, so that they are embedded as they
        // are (or averaged in whole blocks).
        source = match crate::lattice_box::LatticeBox::owning(source, req.crop, factor) {
            Ok(l) => Box::new(l),
            Err(_) if matches!(req.embed_density, Some(crate::EmbedDensity::Voxels { .. })) => {
                return Err(usage(format!(
                    "{name}: embed_density voxels: the input has no voxel lattice to embed (an analytic field or a rotated grid); name the voxels per axis instead"
                )));
            }
            Err(s) => s,
        };
        choice = choose(source.as_ref(), req).map_err(bake_err)?;
    }
    // `voxels:F`: the dims of the lattice box in blocks of F.
    if let Some(crate::EmbedDensity::Voxels { factor, sparse }) = embed_density {
        let (bbox, _) = crate::placement::bake_box(source.as_ref(), req.crop).map_err(bake_err)?;
        let voxel = source.voxel_size().unwrap_or(bbox.extent());
        let dims = [0, 1, 2].map(|a| {
            ((bbox.extent()[a] / (voxel[a] * f64::from(factor)))
                .round()
                .max(1.0)) as u32
        });
        embed_density = Some(if sparse {
            crate::EmbedDensity::Sparse(crate::sparse_density::SparseDims::Exact(dims))
        } else {
            if dims.iter().any(|&d| d > 4096) {
                return Err(usage(format!(
                    "{name}: embed_density voxels:{factor}: {dims:?} voxels, more than the dense section's 4096 per axis; use sparse-voxels or a larger factor"
                )));
            }
            crate::EmbedDensity::Dense(dims)
        });
    }
    if let Some(c) = &req.embed_control {
        crate::control::check_control(source.as_ref(), req.crop, c).map_err(|e| {
            let e = match e {
                BakeError::Options(m) => m,
                other => other.to_string(),
            };
            usage(format!("{name}: embed_control: {e}"))
        })?;
    }
    if req.target_error.is_some() && embed_density.is_none() {
        // Before the bake: a target asking for gigabytes of pins is refused, not run.
        crate::choose::check_target(&choice).map_err(|e| usage(format!("{name}: {e}")))?;
    }
    let metadata = crate::bake::bake_metadata(
        source.as_ref(),
        Provenance {
            source_name: provenance_name,
            source_hash: hash,
            seed: req.seed,
            step: req.step,
            density_scale: req.density_scale,
            crop: req.crop,
        },
        choice.cells,
        choice.directions,
    );
    let mut opts = options(req, &choice, metadata);
    opts.embed_density = embed_density;
    check_max_bytes(source.as_ref(), &opts, &choice, req.max_bytes)
        .map_err(|e| usage(format!("{name}: {e}")))?;
    // The check above assumed the default's size; a chosen bake may be larger, and a large
    // dense grid is marched by layers with a batch of per-pin state beside it.
    let (need, copy) = memory_estimate(source.as_ref(), &opts, input_bytes, budget.limit);
    budget.check(&what, need)?;
    // The disk before the first pin: the sections whose size is known, and a sparse
    // density's spool beside the file that copies it.
    pin_volume::files::check_free_space(
        output,
        crate::bake::estimate_min_file_bytes(source.as_ref(), &opts),
    )?;
    // A sparse VDB is copied into a dense grid when the copy fits in what the budget leaves.
    opts.dense_copy_bytes = budget.limit.saturating_sub(need.saturating_sub(copy));
    Ok(Prepared {
        source,
        opts,
        choice,
        need,
        pending,
        own,
        name,
    })
}

/// Whether the default asset rule chooses the bake ([`crate::default_asset`]): no grid
/// parameter, no embedded density and no tile named (a target error and a byte budget are
/// what it chooses by).
pub fn default_asset_applies(req: &BakeRequest) -> bool {
    req.cells.is_none()
        && req.directions.is_none()
        && req.pins_per_entry.is_none()
        && req.embed_density.is_none()
        && req.tile.is_none()
}

/// `source` with its bake box on its own voxel lattice in blocks of `factor`
/// ([`crate::lattice_box`]); the source as it is where it has none.
fn on_lattice(source: Box<dyn DensitySource>, crop: bool, factor: u32) -> Box<dyn DensitySource> {
    match crate::lattice_box::LatticeBox::owning(source, crop, factor) {
        Ok(l) => Box::new(l),
        Err(s) => s,
    }
}

/// Refuses a bake predicted larger than `max_bytes` (`--max-bytes`): its pins (every cell
/// stored), majorants and embedded density. A default asset was chosen within it, and says
/// so where nothing fits.
fn check_max_bytes(
    source: &dyn DensitySource,
    opts: &BakeOptions,
    choice: &Choice,
    max_bytes: Option<u64>,
) -> Result<(), String> {
    let Some(max) = max_bytes else {
        return Ok(());
    };
    if let Some(a) = &choice.asset {
        return match a.fits {
            true => Ok(()),
            false => Err(format!(
                "no asset fits in --max-bytes {max}: the smallest weighed is {} bytes",
                a.chosen.bytes
            )),
        };
    }
    let vol = |d: [u32; 3], b: u64| d.iter().map(|&n| u64::from(n)).product::<u64>() * b;
    let density = match opts.embed_density {
        Some(crate::EmbedDensity::Dense(d)) => vol(d, 2),
        Some(crate::EmbedDensity::Sparse(spec)) => crate::placement::bake_box(source, opts.crop)
            .ok()
            .and_then(|(bbox, _)| {
                let dims = crate::sparse_density::sparse_dims(source, &bbox, spec).ok()?;
                Some(crate::sparse_density::sparse_density_file_bytes(
                    source, &bbox, dims,
                ))
            })
            .unwrap_or(0),
        Some(crate::EmbedDensity::Voxels { .. }) | None => 0,
    };
    let bytes = choice
        .predicted_pin_bytes
        .saturating_add(opts.majorant.map_or(0, |d| vol(d, 4)))
        .saturating_add(density);
    if bytes > max {
        return Err(format!(
            "the bake is predicted at {bytes} bytes, more than --max-bytes {max}; name fewer --cells or --dirs, or a smaller --embed-density"
        ));
    }
    Ok(())
}

/// A bake ready to run: the source open, the options chosen and checked against the budget,
/// the output's temp file created.
struct Prepared {
    source: Box<dyn DensitySource>,
    opts: BakeOptions,
    choice: Choice,
    need: u64,
    pending: PendingPin,
    own: InputSet,
    name: String,
}

/// Bakes `input` into the file `output` under every rule of the module docs. `inputs` are
/// the files `output` must not be; the input itself is added to them here.
pub fn bake_to_file(
    input: BakeInput,
    output: &Path,
    req: &BakeRequest,
    inputs: &InputSet,
    progress: &dyn Progress,
) -> Result<Baked, PlanError> {
    let Prepared {
        source,
        mut opts,
        choice,
        need,
        pending,
        own,
        name,
    } = prepare(input, output, req, inputs, None)?;
    let bake_err = |source| PlanError::Bake {
        input: name.clone(),
        source,
    };
    opts.cancel = progress.cancel_flag();
    progress.start(crate::bake::pin_count(&opts));
    let started = Instant::now();
    let advance = |n: u64| progress.advance(n);
    // An embedded sparse density's bricks wait in an unnamed file beside the output (the
    // same file system, which must hold the output anyway), not in memory.
    let spool_dir = pin_volume::files::parent_dir(pending.temp_path());
    let (grid, mut spool, stats) =
        crate::bake::bake_spooled_on(source.as_ref(), &opts, req.backend, &advance, &spool_dir)
            .map_err(bake_err)?;
    // Checked again just before the rename: the path may have been replaced during the bake.
    let target = pin_volume::files::check_output_among(output, &[inputs, &own])?;
    let write_err = |source| PlanError::Write {
        path: output.to_path_buf(),
        source,
    };
    if target != output {
        // A symlink to a regular file: the file it points to is replaced, the link stays.
        drop(pending);
        pin_volume::files::PendingPin::create(&target)
            .and_then(|p| p.write_spooled(&grid, streamed(&mut spool)?))
            .map_err(write_err)?;
    } else {
        streamed(&mut spool)
            .and_then(|sparse| pending.write_spooled(&grid, sparse))
            .map_err(write_err)?;
    }
    let file_bytes = std::fs::metadata(&target)
        .map_err(|err| FileError::Io {
            path: output.to_path_buf(),
            err,
        })?
        .len();
    Ok(Baked {
        grid,
        stats,
        choice,
        memory_estimate_bytes: need,
        written: target,
        output: output.to_path_buf(),
        file_bytes,
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// A finished part of a bake split by volume ([`bake_part_to_file`]).
pub struct BakedPart {
    pub part: Part,
    /// The slab of the bake frame's z whose samples the part took.
    pub slab: [f64; 2],
    /// Samples written (pins' samples in the slab).
    pub samples: u64,
    pub choice: Choice,
    pub output: PathBuf,
    pub file_bytes: u64,
    /// What the budget was checked against, as for a whole bake ([`memory_estimate`]).
    pub memory_estimate_bytes: u64,
    /// Wall time from the start of the bake to the end of the write.
    pub seconds: f64,
}

impl BakedPart {
    /// The summary object of `pinbake bake --part I/N --json`.
    pub fn summary(&self) -> Value {
        let num = |v: f64| if v.is_finite() { json!(v) } else { Value::Null };
        json!({
            "part": { "index": self.part.index, "count": self.part.count },
            "slab_z": [num(self.slab[0]), num(self.slab[1])],
            "samples": self.samples,
            "choice": crate::summary::choice_json(&self.choice, self.file_bytes),
            "output": self.output.display().to_string(),
            "file_bytes": self.file_bytes,
            "memory_estimate_bytes": self.memory_estimate_bytes,
            "seconds": self.seconds,
        })
    }
}

/// The options a part bake needs (docs/farm.md): the cells and directions named, so that no
/// part chooses them from its slab alone; no tile, no embedded density, no target error.
fn validate_part(req: &BakeRequest, part: Part) -> Result<(), PlanError> {
    if part.count == 0 || part.index >= part.count {
        return Err(usage(format!(
            "part: index {} must be in 0..{}",
            part.index, part.count
        )));
    }
    if req.cells.is_none() || req.directions.is_none() {
        return Err(usage(
            "--part needs --cells and --dirs: every part must bake the same grid, and a part sees only its slab of the volume to choose from".into(),
        ));
    }
    if req.tile.is_some() {
        return Err(usage(
            "--part and --tile split a bake in two ways: give one".into(),
        ));
    }
    if req.target_error.is_some() {
        return Err(usage(
            "--part takes no --target-error (name --cells and --dirs)".into(),
        ));
    }
    if req.embed_density.is_some() {
        return Err(usage("--embed-density is not available with --part".into()));
    }
    if req.embed_control.is_some() {
        return Err(usage("--embed-control is not available with --part".into()));
    }
    Ok(())
}

/// Bakes part `part` of a bake split by volume ([`crate::part`]) into the part file `output`
/// (atomically), under the rules of [`bake_to_file`]; a VDB is read for that part only.
/// `pinbake merge` of every part gives the bytes of [`bake_to_file`] with the same request.
pub fn bake_part_to_file(
    input: BakeInput,
    output: &Path,
    req: &BakeRequest,
    part: Part,
    inputs: &InputSet,
    progress: &dyn Progress,
) -> Result<BakedPart, PlanError> {
    let Prepared {
        source,
        opts,
        choice,
        need,
        pending,
        own,
        name,
    } = prepare(input, output, req, inputs, Some(part))?;
    // The part file is not a pin file: its own atomic write replaces the pin's temp file.
    drop(pending);
    let bake_err = |source| PlanError::Bake {
        input: name.clone(),
        source,
    };
    progress.start(crate::bake::pin_count(&opts));
    let started = Instant::now();
    let advance = |n: u64| progress.advance(n);
    let write_err = |e: crate::part_file::PartFileError| PlanError::Write {
        path: output.to_path_buf(),
        source: pin_format::FormatError::InvalidInput(e.to_string()),
    };
    // The samples go to the part file as they are taken, batch by batch: a part holds its
    // slab of the source and one batch, not all its samples.
    let target = pin_volume::files::check_output_among(output, &[inputs, &own])?;
    let mut file = crate::part_file::PartFileWriter::create(&target).map_err(write_err)?;
    let data = crate::part::bake_part_into(source.as_ref(), &opts, part, &advance, &mut file)
        .map_err(bake_err)?;
    drop(source);
    // Checked again just before the rename: the path may have been replaced during the bake.
    if pin_volume::files::check_output_among(output, &[inputs, &own])? != target {
        return Err(write_err(crate::part_file::PartFileError::Write(
            "the output was replaced by a link elsewhere during the bake".into(),
        )));
    }
    let samples = file.samples_written();
    let file_bytes = file.finish().map_err(write_err)?;
    Ok(BakedPart {
        part,
        slab: data.slab,
        samples,
        choice,
        output: output.to_path_buf(),
        file_bytes,
        memory_estimate_bytes: need,
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// A hash from a statistics file, shown safely in a one-line message.
#[cfg(feature = "vdb")]
fn one_line_hash(h: &str) -> String {
    h.chars().take(64).filter(char::is_ascii_hexdigit).collect()
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}
