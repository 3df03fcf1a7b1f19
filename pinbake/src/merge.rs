//! Joining the tiles of a farm bake into the file a monolithic bake would have written.
//!
//! Tiles carry the full grid description (only `stored_cells` differs), their z-slab, and
//! their own canonical cell index. Merging concatenates pins in tile order and renumbers the
//! index, which reproduces the monolithic canonical numbering exactly.

use pin_format::{EMPTY_CELL, OwnedPinGrid, PinFile};

#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    #[error("no tiles given")]
    Empty,
    #[error("{0}: not a tile (no tile section)")]
    NotATile(String),
    #[error("{name}: {problem}")]
    Mismatch { name: String, problem: String },
    #[error("tiles do not cover the grid: {0}")]
    Coverage(String),
    #[error(transparent)]
    Format(#[from] pin_format::FormatError),
}

/// Merges parsed tiles (any order) into one canonical grid. `names` label errors.
pub fn merge_tiles(tiles: &[(String, PinFile<'_>)]) -> Result<OwnedPinGrid, MergeError> {
    let (first_name, first) = tiles.first().ok_or(MergeError::Empty)?;
    let count = first
        .tile()
        .ok_or_else(|| MergeError::NotATile(first_name.clone()))?
        .tile_count;
    let mut order: Vec<&(String, PinFile<'_>)> = tiles.iter().collect();
    for (name, t) in tiles {
        let td = t.tile().ok_or_else(|| MergeError::NotATile(name.clone()))?;
        if td.tile_count != count {
            return Err(MergeError::Mismatch {
                name: name.clone(),
                problem: format!("is tile of {} but others are of {count}", td.tile_count),
            });
        }
        let mut a = *t.desc();
        let mut b = *first.desc();
        a.stored_cells = 0;
        b.stored_cells = 0;
        if bytemuck::bytes_of(&a) != bytemuck::bytes_of(&b) {
            return Err(MergeError::Mismatch {
                name: name.clone(),
                problem: format!("grid description differs from {first_name}"),
            });
        }
        let same_meta = t.metadata().transpose()? == first.metadata().transpose()?;
        let same_major = t.majorant().map(|m| (m.dims, m.values))
            == first.majorant().map(|m| (m.dims, m.values));
        let same_density =
            t.density().map(|d| (d.dims, d.values)) == first.density().map(|d| (d.dims, d.values));
        if !(same_meta && same_major && same_density) {
            return Err(MergeError::Mismatch {
                name: name.clone(),
                problem: format!("metadata, majorant or density differs from {first_name}"),
            });
        }
    }
    order.sort_by_key(|(_, t)| t.tile().map(|d| d.tile_index));
    let mut z = 0;
    for (i, (name, t)) in order.iter().enumerate() {
        let td = t.tile().expect("checked above");
        if td.tile_index as usize != i {
            return Err(MergeError::Coverage(format!(
                "tile {i} of {count} is missing or duplicated (found {name} as tile {})",
                td.tile_index
            )));
        }
        if td.z_begin != z {
            return Err(MergeError::Coverage(format!(
                "{name} starts at layer {} but layer {z} is next",
                td.z_begin
            )));
        }
        z = td.z_end;
    }
    if order.len() != count as usize || z != first.desc().dims[2] {
        return Err(MergeError::Coverage(format!(
            "{} of {count} tiles given, layers 0..{z} of {} covered",
            order.len(),
            first.desc().dims[2]
        )));
    }

    let mut index = Vec::new();
    let mut pins = Vec::new();
    let mut stored = 0u64;
    for (name, t) in &order {
        t.verify().map_err(|e| MergeError::Mismatch {
            name: name.clone(),
            problem: e.to_string(),
        })?;
        let base = u32::try_from(stored).map_err(|_| {
            MergeError::Coverage("more stored cells than a cell index can number".into())
        })?;
        match t.cell_index() {
            Some(ix) => index.extend(ix.iter().map(|&b| {
                if b == EMPTY_CELL {
                    EMPTY_CELL
                } else {
                    b + base
                }
            })),
            None => index.extend((0..t.shape().covered_cells as u32).map(|b| b + base)),
        }
        pins.extend_from_slice(t.pins());
        stored += t.desc().stored_cells;
    }
    let mut desc = *first.desc();
    desc.stored_cells = stored;
    let grid = OwnedPinGrid {
        desc,
        tile: None,
        cell_index: Some(index),
        pins,
        majorant: None,
        density: None,
        sparse_density: None,
        control: None,
        metadata: first.metadata().transpose()?,
    };
    let mut grid = grid;
    let full = OwnedPinGrid::from_file(first)?;
    grid.majorant = full.majorant;
    grid.density = full.density;
    // Like the majorants, the control covers the whole box in every tile.
    grid.control = full.control;
    grid.validate()?;
    Ok(grid)
}
