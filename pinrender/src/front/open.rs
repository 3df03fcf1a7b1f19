//! One way from a file on the command line to a medium, for `pinrender render` and the
//! viewer: a volume (read through pinbake's one source dispatch, its pins loaded, baked now
//! or checked for a bake later) or a pin file alone, every allocation charged to the
//! command's one memory budget before it is made.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Result, anyhow};
use pin_volume::files::MemoryBudget;
use pinbake::cli_args::SourceArgs;

use super::{Holds, RenderFlags};
use crate::volume::{self, OpenedMedium, VolumeArgs};

/// What the command does with a volume's pins.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PinsWanted {
    /// None are read: the estimator reads no pins (a pin file alone is its own pins).
    No,
    /// Loaded from the pin file given, else baked in memory now, with the control section
    /// where `control` (`pinres`).
    Now { control: bool },
    /// Baked later in the background with the control section (the viewer): the bake is
    /// planned and charged to the budget now, so that a bake that cannot fit is refused
    /// before anything is shown.
    Later,
}

/// A medium to open.
#[derive(Clone, Copy, Debug)]
pub struct Input<'a> {
    /// The volume (a path or `procedural:SPEC`), read with `read`.
    pub volume: Option<&'a Path>,
    pub read: &'a SourceArgs,
    /// A pin file: the volume's pins, or (without a volume) the medium itself.
    pub pins: Option<&'a Path>,
    pub wanted: PinsWanted,
    /// Render with pins whose recorded source is not the volume (`--allow-mismatched-pins`).
    pub allow_mismatched_pins: bool,
    /// The device a GPU render uploads a pin file's embedded density to: its sparse section
    /// is checked against the device's bindings before it is read.
    pub gpu: Option<&'a wgpu::Limits>,
}

impl Input<'_> {
    /// The file read: the volume, else the pin file.
    pub fn path(&self) -> Option<&Path> {
        self.volume.or(self.pins)
    }
}

/// What reading a volume file is charged per byte of the file: its voxels up to 8x (f32
/// values from bytes, a VDB's leaves).
pub const VOLUME_READ_FACTOR: u64 = 8;
/// What reading a pin file is charged per byte: mapped in place, its dense density section
/// widened to f32, at most 3x its length.
pub const PIN_FILE_READ_FACTOR: u64 = 3;

/// The bytes reading `path` is charged at, `factor` per byte of the file (0 when it cannot
/// be read: the open that follows reports that).
pub fn read_cost(path: &Path, factor: u64) -> u64 {
    std::fs::metadata(path).map_or(0, |m| m.len().saturating_mul(factor))
}

/// Charges the read of `input`'s file to `budget`: a volume's voxels up to 8x its file (f32
/// values from bytes, a VDB's leaves); a pin file alone is mapped in place (at most its length
/// resident), its sparse density's f16 values read there too, and a dense section widened to
/// f32 (twice the f16 bytes it stores): at most 3x its length. A procedural field reads
/// nothing.
pub fn check_read(input: &Input, budget: &MemoryBudget) -> Result<()> {
    let Some(path) = input.path() else {
        return Ok(());
    };
    budget.check(&format!("reading {}", path.display()), read_charge(input))?;
    Ok(())
}

/// The bytes [`check_read`] charges for `input`'s file (0 for a procedural field).
pub fn read_charge(input: &Input) -> u64 {
    let Some(path) = input.path() else {
        return 0;
    };
    let factor = if input.volume.is_some() {
        VOLUME_READ_FACTOR
    } else {
        PIN_FILE_READ_FACTOR
    };
    read_cost(path, factor)
}

/// Opens `input` within `budget`: the read charged ([`check_read`]), a volume through
/// pinbake's source dispatch with its dense copies bounded by the budget, its pins as
/// `input.wanted` says (in-memory bakes with `flags.pin_cells` and `flags.seed`), or a pin file
/// alone with its embedded density.
pub fn open_medium(
    input: &Input,
    flags: &RenderFlags,
    budget: &MemoryBudget,
) -> Result<OpenedMedium> {
    check_read(input, budget)?;
    let Some(v) = input.volume else {
        let path = input
            .pins
            .ok_or_else(|| anyhow!("no volume and no pin file to open"))?;
        let grid = Arc::new(volume::load_pins(path)?);
        if let Some(limits) = input.gpu {
            check_gpu_bricks(path, &grid, limits)?;
        }
        return OpenedMedium::pin_file(path, grid);
    };
    let args = VolumeArgs {
        volume: Some(v.to_path_buf()),
        read: input.read.clone(),
    };
    let opened = volume::open_volume_within(v, &args, budget)?;
    let medium = OpenedMedium::volume(opened, None, budget.limit);
    with_pins(medium, input, flags, budget)
}

/// A volume's `medium` (opened from `input.volume`) with its pins as `input.wanted` says:
/// loaded from `input.pins` and checked against the volume, baked in memory within `budget`,
/// or a later bake planned and charged. The second step of [`open_medium`], apart for a
/// caller whose messages tell the volume's failures from the pins'.
pub fn with_pins(
    mut medium: OpenedMedium,
    input: &Input,
    flags: &RenderFlags,
    budget: &MemoryBudget,
) -> Result<OpenedMedium> {
    let (Some(v), Some((opened, _))) = (input.volume, &medium.opened) else {
        return Ok(medium);
    };
    let source = opened.source();
    match input.wanted {
        PinsWanted::No => {}
        PinsWanted::Later => {
            volume::in_memory_bake_options(
                source.as_ref(),
                flags.pin_cells,
                flags.seed,
                true,
                budget,
            )?;
        }
        PinsWanted::Now { control } => {
            let grid = volume::pins_for(
                input.pins,
                source.as_ref(),
                flags.pin_cells,
                flags.seed,
                control,
                budget,
            )?;
            if let Some(p) = input.pins {
                volume::check_pins_match(
                    p,
                    &grid,
                    v,
                    source.as_ref(),
                    input.read.density_scale,
                    input.allow_mismatched_pins,
                )?;
            }
            medium.pins = Some(Arc::new(grid));
        }
    }
    Ok(medium)
}

/// Refuses a pin file whose sparse density neither expands to a dense copy the GPU takes
/// nor fits its brick bindings, from the section's header alone: before the bricks are
/// widened to f32 (the full-size cloud's took 27 s and 9.7 GB before the packing refused them).
fn check_gpu_bricks(path: &Path, grid: &pinrt::PinGrid, limits: &wgpu::Limits) -> Result<()> {
    // The section's view, lengths checked: O(1), where `PinGrid::sparse_density` checks
    // every value.
    let file = grid.file().map_err(|e| anyhow!("{e}"))?;
    let Some(sparse) = file.sparse_density() else {
        return Ok(());
    };
    let h = sparse.header;
    let limit = pinrt::gpu::binding_limit(limits);
    let voxels = h.dims.iter().map(|&d| u64::from(d)).product::<u64>();
    if voxels <= volume::GPU_DENSE_VOXELS.min(limit / 4) {
        return Ok(());
    }
    let bindings = crate::gpu_render::value_bindings(limits);
    crate::gpu_render::check_brick_values_fit(limit, bindings, h.brick, u64::from(h.brick_count))
        .map_err(|e| anyhow!("{}: {e}", path.display()))
}

/// What the input of `pinrender render` holds, read from the pin file's section table only
/// (no density read): pins where a pin file is given; a density with a volume, or where the
/// pin file embeds one; the control section where the pin file has one.
pub fn holds(volume: Option<&Path>, pins: Option<&Path>) -> Result<Holds> {
    let Some(p) = pins else {
        return Ok(Holds {
            pins: false,
            density: volume.is_some(),
            volume: volume.is_some(),
            control: false,
        });
    };
    let grid = volume::load_pins(p)?;
    let file = grid.file().map_err(|e| anyhow!("{}: {e}", p.display()))?;
    Ok(Holds {
        pins: true,
        density: volume.is_some() || file.density().is_some() || file.sparse_density().is_some(),
        volume: volume.is_some(),
        control: file.control().is_some(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{ESTIMATORS, EstimatorSpec};
    use pin_volume::DensityScale;
    use std::path::PathBuf;

    /// A cosine field's pins (4^3 cells), with `embed` density voxels per axis.
    fn bake(dir: &Path, name: &str, embed: Option<u32>) -> PathBuf {
        let p: pin_volume::ProceduralSpec = "cosine:seed=5,freq=4,density=6".parse().unwrap();
        let src = p.build(DensityScale::ONE).unwrap();
        let opts = pinbake::BakeOptions {
            cells: [4; 3],
            embed_density: embed.map(|n| pinbake::EmbedDensity::Dense([n; 3])),
            majorant: embed.map(|_| [4; 3]),
            ..pinbake::BakeOptions::default()
        };
        let (grid, _) = pinbake::bake(src.as_ref(), &opts, &|_| {}).unwrap();
        let path = dir.join(name);
        grid.write_atomic(&path).unwrap();
        path
    }

    #[test]
    fn the_default_estimator_follows_the_input() {
        let dir = tempfile::tempdir().unwrap();
        let bare = bake(dir.path(), "bare.pin", None);
        let dense = bake(dir.path(), "dense.pin", Some(8));
        let volume = Path::new("procedural:cosine");
        let d = |v: Option<&Path>, p: Option<&Path>| {
            super::super::default_estimator(holds(v, p).unwrap(), ESTIMATORS)
        };
        assert_eq!(d(None, Some(&bare)), EstimatorSpec::Pins);
        assert_eq!(d(None, Some(&dense)), EstimatorSpec::RatioTracking);
        assert_eq!(d(Some(volume), None), EstimatorSpec::RatioTracking);
        assert_eq!(d(Some(volume), Some(&bare)), EstimatorSpec::PinMs);
        // A file that is not a pin file is an error naming it, not a default.
        let junk = dir.path().join("junk.pin");
        std::fs::write(&junk, b"junk").unwrap();
        let e = holds(None, Some(&junk)).unwrap_err().to_string();
        assert!(e.contains("junk.pin"), "{e}");
    }
}
