//! Random pin grids for tests, benchmarks and examples (not a baker: the masks are random bits,
//! not the result of marching a volume).

use pin_format::{Directions, EMPTY_CELL, OwnedPinGrid, PinEntry, grid_desc};

use crate::rng::Rng;

/// A random `t_min` drawn from a mix that covers the stiff values: exactly 0, subnormal, tiny,
/// uniform, near 1 and exactly 1 (with mask 0, as the format requires).
pub fn random_entry(rng: &mut Rng) -> PinEntry {
    let t_min = match rng.next_u32() % 10 {
        0 => 0.0,
        1 => 1e-40,
        2 => 1e-6 * rng.next_f32(),
        3 => 1.0,
        4 => 1.0 - 1e-6 * rng.next_f32(),
        5 => 0.999_999_9,
        _ => rng.next_f32(),
    };
    let mask = if t_min >= 1.0 { 0 } else { rng.next_u32() };
    PinEntry { mask, t_min }
}

/// A random grid. `sparse`: a cell index with about a third of the cells empty.
pub fn random_grid(
    directions: Directions,
    dims: [u32; 3],
    pins_per_entry: u32,
    sparse: bool,
    seed: u32,
) -> OwnedPinGrid {
    let mut rng = Rng::for_query(seed, 0x5eed);
    let cells = (dims[0] * dims[1] * dims[2]) as usize;
    let block = (directions.count() * pins_per_entry) as usize;
    let mut index = Vec::new();
    let mut stored = 0u32;
    if sparse {
        for _ in 0..cells {
            if rng.next_u32().is_multiple_of(3) {
                index.push(EMPTY_CELL);
            } else {
                index.push(stored);
                stored += 1;
            }
        }
    } else {
        stored = cells as u32;
    }
    let pins = (0..stored as usize * block)
        .map(|_| random_entry(&mut rng))
        .collect();
    OwnedPinGrid {
        desc: grid_desc(dims, directions, pins_per_entry, u64::from(stored)),
        tile: None,
        cell_index: sparse.then_some(index),
        pins,
        majorant: None,
        density: None,
        sparse_density: None,
        control: None,
        metadata: None,
    }
}

/// A grid of one cell and one direction cell holding `entry` (every query reads it).
pub fn single_entry_grid(entry: PinEntry) -> OwnedPinGrid {
    OwnedPinGrid {
        desc: grid_desc([1, 1, 1], Directions::Octahedral { n: 1 }, 1, 1),
        tile: None,
        cell_index: None,
        pins: vec![entry],
        majorant: None,
        density: None,
        sparse_density: None,
        control: None,
        metadata: None,
    }
}
