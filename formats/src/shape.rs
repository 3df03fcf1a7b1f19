//! Derived sizes of a grid and the validation of a [`GridDesc`].
//!
//! All arithmetic on counts read from a file happens here, checked, in u64, before any of it
//! is used to index or to size anything.

use crate::directions::Directions;
use crate::error::{FormatError, Result};
use crate::layout::{BITS_PER_PIN, GridDesc, TileDesc};

/// Largest number of cells along one axis.
pub const MAX_DIM: u32 = 1 << 20;
/// Largest number of spatial cells (the cell index stores u32 block numbers with a sentinel).
pub const MAX_CELLS: u64 = u32::MAX as u64 - 1;
/// Largest pins-per-entry value.
pub const MAX_PINS_PER_ENTRY: u32 = 256;

/// The validated shape of a grid (or of one tile of it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GridShape {
    pub dims: [u32; 3],
    pub directions: Directions,
    pub pins_per_entry: u32,
    /// Cell layers `z_begin..z_end` this file covers (the whole grid unless tiled).
    pub z_begin: u32,
    pub z_end: u32,
    /// Cells of the full grid.
    pub total_cells: u64,
    /// Cells this file covers (`dims.x * dims.y * (z_end - z_begin)`).
    pub covered_cells: u64,
    /// Pins per spatial cell: directions x pins per entry.
    pub block_len: u64,
}

fn bad(msg: impl Into<String>) -> FormatError {
    FormatError::BadGrid(msg.into())
}

fn finite3(v: &[f64; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl GridShape {
    /// Validates a grid description (and tile, if any) and derives its sizes.
    pub fn new(desc: &GridDesc, tile: Option<&TileDesc>) -> Result<Self> {
        if desc.bits_per_pin != BITS_PER_PIN {
            return Err(bad(format!(
                "bits per pin is {}, only {BITS_PER_PIN} is defined",
                desc.bits_per_pin
            )));
        }
        for (axis, &d) in ["x", "y", "z"].iter().zip(&desc.dims) {
            if d == 0 {
                return Err(bad(format!("zero cells along {axis}")));
            }
            if d > MAX_DIM {
                return Err(bad(format!("{d} cells along {axis} exceed {MAX_DIM}")));
            }
        }
        let total_cells = desc.dims.iter().map(|&d| u64::from(d)).product::<u64>();
        if total_cells > MAX_CELLS {
            return Err(bad(format!("{total_cells} cells exceed {MAX_CELLS}")));
        }
        let directions = Directions::from_desc(desc.direction_kind, desc.direction_res)?;
        if desc.pins_per_entry == 0 || desc.pins_per_entry > MAX_PINS_PER_ENTRY {
            return Err(bad(format!(
                "pins per entry {} not in 1..={MAX_PINS_PER_ENTRY}",
                desc.pins_per_entry
            )));
        }
        if !finite3(&desc.box_min) || !finite3(&desc.box_max) {
            return Err(bad("box corner is not finite"));
        }
        if (0..3).any(|i| desc.box_min[i] >= desc.box_max[i]) {
            return Err(bad("box is empty or inverted"));
        }
        if (0..3).any(|i| !(desc.box_max[i] - desc.box_min[i]).is_finite()) {
            return Err(bad("box extent overflows"));
        }
        if !finite3(&desc.source_box_min) || !finite3(&desc.source_box_max) {
            return Err(bad("source box corner is not finite"));
        }
        if desc.local_to_world.iter().any(|x| !x.is_finite()) {
            return Err(bad("local-to-world transform is not finite"));
        }
        crate::placement::check_placement(desc.box_min, desc.box_max, &desc.local_to_world)
            .map_err(bad)?;
        if !desc.step_size.is_finite() || desc.step_size < 0.0 {
            return Err(bad("step size must be finite and >= 0"));
        }
        if !desc.density_scale.is_finite() || desc.density_scale < 0.0 {
            return Err(bad("density scale must be finite and >= 0"));
        }
        let known = crate::layout::GRID_FLAG_CROPPED | crate::layout::GRID_FLAG_JITTERED_PINS;
        if desc.flags & !known != 0 {
            return Err(bad(format!(
                "flags {:#x} set bits this version does not define (it knows {known:#x})",
                desc.flags
            )));
        }
        let (z_begin, z_end) = match tile {
            None => (0, desc.dims[2]),
            Some(t) => {
                if t.tile_count == 0 || t.tile_index >= t.tile_count {
                    return Err(bad(format!(
                        "tile {} of {} is out of range",
                        t.tile_index, t.tile_count
                    )));
                }
                if t.z_begin >= t.z_end || t.z_end > desc.dims[2] {
                    return Err(bad(format!(
                        "tile layers {}..{} outside 0..{}",
                        t.z_begin, t.z_end, desc.dims[2]
                    )));
                }
                (t.z_begin, t.z_end)
            }
        };
        let covered_cells =
            u64::from(desc.dims[0]) * u64::from(desc.dims[1]) * u64::from(z_end - z_begin);
        if desc.stored_cells > covered_cells {
            return Err(bad(format!(
                "{} stored cells but only {covered_cells} cells covered",
                desc.stored_cells
            )));
        }
        let block_len = u64::from(directions.count()) * u64::from(desc.pins_per_entry);
        Ok(Self {
            dims: desc.dims,
            directions,
            pins_per_entry: desc.pins_per_entry,
            z_begin,
            z_end,
            total_cells,
            covered_cells,
            block_len,
        })
    }

    /// Number of pins for `stored_cells` blocks, or an error if it overflows.
    pub fn pin_count(&self, stored_cells: u64) -> Result<u64> {
        stored_cells
            .checked_mul(self.block_len)
            .ok_or_else(|| bad("pin count overflows"))
    }

    /// Linear index of a cell within the covered slab (x fastest), or `None` outside it.
    #[inline]
    pub fn local_cell(&self, cell: [u32; 3]) -> Option<u64> {
        if cell[0] >= self.dims[0]
            || cell[1] >= self.dims[1]
            || cell[2] < self.z_begin
            || cell[2] >= self.z_end
        {
            return None;
        }
        let (x, y, z) = (
            u64::from(cell[0]),
            u64::from(cell[1]),
            u64::from(cell[2] - self.z_begin),
        );
        Some(x + u64::from(self.dims[0]) * (y + u64::from(self.dims[1]) * z))
    }
}
