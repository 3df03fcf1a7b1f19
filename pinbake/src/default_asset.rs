//! The asset a bake with no grid flags writes: the smallest file whose image from the file
//! alone is predicted within the target 8x8-block error of the full-resolution volume, and no
//! larger than the byte budget (`--max-bytes`; by default the source file plus
//! [`ALLOWANCE`]).
//!
//! Per byte, the density itself gives a far better image than pins alone (docs/scale.md,
//! "The default asset"): so a voxel source gets its density embedded, box-filtered to the
//! coarsest of [`FACTORS`] whose predicted error meets the target, on the source's own
//! lattice ([`crate::lattice_box`]), as a dense or sparse f16 section (the smaller), and a
//! small pin grid ([`ASSET_PIN_CELLS`] cells along the longest axis, octahedral:
//! [`ASSET_PIN_OCTAHEDRAL`]) for the estimators that read pins. Pins alone, at the pins-only
//! choice of [`crate::choose`], are weighed beside them with their own predicted error.
//! An analytic field or a rotated grid (no lattice to embed) keeps the pins-only choice.
//!
//! The prediction ([`predicted_density_error`]): at the source's resolution the file holds the
//! source's voxels (the f16 rounding and the renderer's noise floor, [`FULL_RES_ERROR`]); below
//! it, the pins' bias model's spatial term ([`crate::choose::model`]) at the coarse voxel's
//! size times the square root of the factor, scaled by [`DENSITY_MODEL_SCALE`], measured on
//! the bundled volumes (docs/scale.md).

use glam::DVec3;
use pin_format::Directions;

pub use crate::asset_choice::{Alternative, AssetChoice};
use crate::choose::{self, VolumeStats};
use crate::lattice_box::LatticeBox;
use pin_volume::DensitySource;

/// Bytes a default asset may take beyond its source file: headers, the majorants and the
/// small pin grid.
pub const ALLOWANCE: u64 = 64 << 10;

/// The 8x8-block error a default asset aims for when no `--target-error` is given.
pub const DEFAULT_ASSET_TARGET: f64 = 0.01;

/// Reductions of the source's resolution the default weighs (source voxels per embedded
/// voxel along each axis).
pub const FACTORS: &[u32] = &[1, 2, 3, 4, 6, 8, 12, 16];

/// The small pin grid beside an embedded density: cells along the longest axis (fewer where
/// the volume has fewer voxels) and the octahedral resolution.
pub const ASSET_PIN_CELLS: u32 = 6;
pub const ASSET_PIN_OCTAHEDRAL: u32 = 4;

/// Predicted block error of a density at the source's resolution.
pub const FULL_RES_ERROR: f64 = 0.002;

/// A coarse density's block error at `factor` source voxels per voxel over the pins' spatial
/// bias at a cell of that size, divided by `sqrt(factor)` (docs/scale.md, "The default
/// asset": the measured rows of `scripts/asset_sweep.sh` on the gaffer sphere and the smoke
/// give 0.64 to 0.95: 0.9, the sphere's at factor 2).
pub const DENSITY_MODEL_SCALE: f64 = 0.9;

/// The pins beside an embedded density: [`ASSET_PIN_CELLS`] and octahedral:
/// [`ASSET_PIN_OCTAHEDRAL`], one pin per entry.
pub fn asset_pins(stats: &VolumeStats) -> (choose::Fixed, u64) {
    let cells = choose::proportional_cells(ASSET_PIN_CELLS, stats.extent, stats.voxels);
    let dirs = Directions::Octahedral {
        n: ASSET_PIN_OCTAHEDRAL,
    };
    let bytes = choose::pin_bytes(cells, dirs.count(), 1);
    (
        choose::Fixed {
            cells: Some(cells),
            directions: Some(dirs),
            pins_per_entry: Some(1),
        },
        bytes,
    )
}

/// The predicted block error of the file's density at `factor` source voxels per embedded
/// voxel, for a volume of `stats` whose voxels are `voxel` wide (see the module docs).
pub fn predicted_density_error(stats: &VolumeStats, voxel: DVec3, factor: u32) -> f64 {
    if factor <= 1 {
        return FULL_RES_ERROR;
    }
    let longest = stats.extent.iter().copied().fold(0.0, f64::max);
    let h = (voxel * f64::from(factor)).max_element() / longest;
    // The error grows faster than the voxel: a box filter blurs across the rays as well as
    // along them (measured 3x from factor 2 to 4 on the sphere, 2.1x on the smoke).
    (DENSITY_MODEL_SCALE
        * f64::from(factor).sqrt()
        * choose::model(
            (choose::MODEL_A, choose::MODEL_K, choose::MODEL_P),
            stats.model_variation,
            h,
            0.0,
        ))
    .max(FULL_RES_ERROR)
}

/// Bytes of a file beyond its sections, at most: the header, the section table, the metadata
/// (the source's name and hash; about 1.3 KiB for the bundled volumes), so that a file chosen
/// within the budget is within it.
const HEADER_BYTES: u64 = 4 << 10;

/// Weighs the alternatives for `source` (the pins-only choice `pins_only` among them) and
/// picks the smallest whose predicted error is at most `target` within `max_bytes`; when none
/// meets the target within the budget, the lowest predicted error within it; when nothing fits,
/// the smallest. `None` where the source has no lattice to embed ([`LatticeBox::new`]).
pub fn choose_asset(
    source: &dyn DensitySource,
    crop: bool,
    pins_only: &choose::Choice,
    majorant: Option<[u32; 3]>,
    target: f64,
    max_bytes: u64,
) -> Option<AssetChoice> {
    let voxel = source
        .voxel_size()
        .filter(|v| v.is_finite() && v.cmpgt(DVec3::ZERO).all())?;
    crate::lattice_box::source_lattice(source)?;
    let stats = &pins_only.stats;
    let majorant_bytes =
        majorant.map_or(0, |d| d.iter().map(|&n| u64::from(n)).product::<u64>() * 4);
    let (_, pin_bytes) = asset_pins(stats);
    let fixed = HEADER_BYTES + majorant_bytes + pin_bytes;
    let mut alternatives = vec![Alternative {
        representation: "pins",
        factor: 0,
        dims: pins_only.cells,
        bytes: HEADER_BYTES + majorant_bytes + pins_only.predicted_pin_bytes,
        predicted_error: pins_only.predicted_error,
    }];
    for &f in FACTORS {
        let Some(lattice) = LatticeBox::new(source, crop, f) else {
            continue;
        };
        let dims = lattice.voxels().map(|n| n / f);
        if dims
            .iter()
            .any(|&d| d > crate::sparse_density::MAX_SPARSE_DIM)
        {
            continue;
        }
        let bbox = lattice.bake_box();
        let error = predicted_density_error(stats, voxel, f);
        let voxels: u64 = dims.iter().map(|&d| u64::from(d)).product();
        if dims.iter().all(|&d| d <= 4096) {
            alternatives.push(Alternative {
                representation: "dense",
                factor: f,
                dims,
                bytes: fixed + voxels * 2,
                predicted_error: error,
            });
        }
        let sparse = crate::sparse_density::sparse_density_file_bytes(&lattice, &bbox, dims);
        alternatives.push(Alternative {
            representation: "sparse",
            factor: f,
            dims,
            bytes: fixed + sparse,
            predicted_error: error,
        });
        // Coarser factors only lose once one is this small: the smallest file meeting the
        // target is among those weighed so far or coarser, so keep going.
    }
    let fits = |a: &&Alternative| a.bytes <= max_bytes;
    let meets = |a: &&Alternative| a.predicted_error <= target;
    let key = |a: &Alternative| (a.bytes, ordered(a.predicted_error));
    let (chosen, target_met, fit, why) = if let Some(a) = alternatives
        .iter()
        .filter(fits)
        .filter(meets)
        .min_by_key(|a| key(a))
    {
        (
            a,
            true,
            true,
            "the smallest file within the budget predicted to meet the target",
        )
    } else if let Some(a) = alternatives
        .iter()
        .filter(fits)
        .min_by_key(|a| (ordered(a.predicted_error), a.bytes))
    {
        (
            a,
            false,
            true,
            "no file within the budget is predicted to meet the target: the lowest predicted error within it",
        )
    } else {
        let a = alternatives.iter().min_by_key(|a| key(a))?;
        (a, false, false, "no file fits the budget: the smallest")
    };
    let chosen = chosen.clone();
    let reason = format!(
        "{why}: {} at {} (factor {}), {} bytes, predicted block error {:.4} (target {}, budget {} bytes)",
        chosen.representation,
        dims_text(chosen.dims),
        chosen.factor,
        chosen.bytes,
        chosen.predicted_error,
        pin_format::text::num(target),
        max_bytes
    );
    Some(AssetChoice {
        chosen,
        alternatives,
        max_bytes,
        target_error: target,
        target_met,
        fits: fit,
        reason,
    })
}

fn dims_text(d: [u32; 3]) -> String {
    format!("{}x{}x{}", d[0], d[1], d[2])
}

/// A total order for finite non-negative errors (NaN last).
fn ordered(e: f64) -> u64 {
    if e.is_nan() { u64::MAX } else { e.to_bits() }
}
