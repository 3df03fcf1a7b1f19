//! Which entry a query reads: the spatial cell, the direction cell, the pin, and the address.
//!
//! The direction cell reproduces `pin_format::Directions::index_of` operation for operation
//! (using the format crate's own `atan2_turns` and `octahedral_uv`), with an optional jitter in
//! continuous cell coordinates:
//!
//! * polar: `c_theta = (1 - z / |d|) n_theta`, `c_phi = atan2_turns(y, x) n_phi`; jitter adds
//!   `(xi - 0.5) * strength` to each (`strength` in cells); `c_phi` wraps around once (azimuth
//!   is periodic), `c_theta` clamps.
//! * octahedral: `c_u = u n`, `c_v = v n` of the hemi-octahedral square, jittered the same way,
//!   both clamped to the square (no wrap across its edges).
//!
//! Cells are `floor` of the coordinates clamped to `[0, n - 1]` (NaN to 0), as in the format.

use pin_format::{Directions, EMPTY_CELL, GridShape, PinEntry, atan2_turns, octahedral_uv};

use crate::chord::bin;
use crate::loader::PinGrid;

/// The hot-path view of a grid: slices into the mapped bytes plus precomputed sizes.
#[derive(Clone, Copy, Debug)]
pub struct GridView<'g> {
    pub pins: &'g [PinEntry],
    pub index: Option<&'g [u32]>,
    /// Sizes, slab and direction cells, validated by the format crate.
    pub shape: GridShape,
    pub dims_f: [f32; 3],
    pub stored_cells: u64,
}

impl<'g> GridView<'g> {
    pub fn new(grid: &'g PinGrid) -> Self {
        let shape = *grid.shape();
        Self {
            pins: grid.pins(),
            index: grid.cell_index(),
            shape,
            dims_f: shape.dims.map(|d| d as f32),
            stored_cells: grid.desc().stored_cells,
        }
    }

    /// Linear index of a cell within the covered slab, or `None` outside it (other tiles).
    #[inline(always)]
    pub fn local_cell(&self, cell: [u32; 3]) -> Option<u64> {
        self.shape.local_cell(cell)
    }

    /// Block number of a covered cell; `None` for an empty cell or a corrupt index entry.
    #[inline(always)]
    pub fn block_of(&self, local: u64) -> Option<u64> {
        match self.index {
            None => Some(local),
            Some(ix) => {
                let b = *ix.get(local as usize)?;
                if b == EMPTY_CELL || u64::from(b) >= self.stored_cells {
                    None
                } else {
                    Some(u64::from(b))
                }
            }
        }
    }

    /// Index into [`Self::pins`] of `(cell, direction, pin)`, `None` for an empty cell.
    #[inline(always)]
    pub fn entry_index(&self, cell: [u32; 3], direction: u32, pin: u32) -> Option<u64> {
        let block = self.block_of(self.local_cell(cell)?)?;
        let within = u64::from(direction) * u64::from(self.shape.pins_per_entry) + u64::from(pin);
        if within >= self.shape.block_len {
            return None;
        }
        Some(block * self.shape.block_len + within)
    }
}

/// Direction jitter: `strength` in cells and two uniforms.
#[derive(Clone, Copy, Debug)]
pub struct DirJitter {
    pub strength: f32,
    pub xi: [f32; 2],
}

/// Direction cell of `d` (`d.z >= 0` or `-0.0`; finite, non-zero, need not be normalised).
/// Without jitter this equals `directions.index_of(d)`.
#[inline(always)]
pub fn direction_cell(directions: &Directions, d: [f32; 3], jitter: Option<DirJitter>) -> u32 {
    match *directions {
        Directions::Polar { n_phi, n_theta } => {
            let len2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            let z = d[2] / len2.sqrt();
            let mut ct = (1.0 - z) * n_theta as f32;
            let mut cp = atan2_turns(d[1], d[0]) * n_phi as f32;
            if let Some(j) = jitter {
                ct += (j.xi[0] - 0.5) * j.strength;
                cp += (j.xi[1] - 0.5) * j.strength;
                let n = n_phi as f32;
                if cp < 0.0 {
                    cp += n;
                } else if cp >= n {
                    cp -= n;
                }
            }
            bin(ct, n_theta) * n_phi + bin(cp, n_phi)
        }
        Directions::Octahedral { n } => {
            let (u, v) = octahedral_uv(d);
            let mut cu = u * n as f32;
            let mut cv = v * n as f32;
            if let Some(j) = jitter {
                cu += (j.xi[0] - 0.5) * j.strength;
                cv += (j.xi[1] - 0.5) * j.strength;
            }
            bin(cv, n) * n + bin(cu, n)
        }
    }
}

/// Spatial cell of a unit-cube point: `floor(p * dims + (xi - 0.5) * strength)` clamped into
/// the grid (points outside the box, e.g. from rounding at faces, land in the border cells).
#[inline(always)]
pub fn spatial_cell(p: [f32; 3], view: &GridView<'_>, jitter: Option<(f32, [f32; 3])>) -> [u32; 3] {
    let mut c = [
        p[0] * view.dims_f[0],
        p[1] * view.dims_f[1],
        p[2] * view.dims_f[2],
    ];
    if let Some((s, xi)) = jitter {
        for a in 0..3 {
            c[a] += (xi[a] - 0.5) * s;
        }
    }
    [
        bin(c[0], view.shape.dims[0]),
        bin(c[1], view.shape.dims[1]),
        bin(c[2], view.shape.dims[2]),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn random_dir(r: &mut Rng) -> [f32; 3] {
        loop {
            let d = [
                r.next_f32() * 2.0 - 1.0,
                r.next_f32() * 2.0 - 1.0,
                r.next_f32(),
            ];
            if d.iter().map(|x| x * x).sum::<f32>() > 1e-6 {
                return d;
            }
        }
    }

    #[test]
    fn unjittered_cells_equal_index_of() {
        let mut r = Rng::new(12);
        for dirs in [
            Directions::THESIS_DEFAULT,
            Directions::Polar {
                n_phi: 7,
                n_theta: 3,
            },
            Directions::Octahedral { n: 8 },
            Directions::Octahedral { n: 1 },
        ] {
            for _ in 0..20_000 {
                let mut d = random_dir(&mut r);
                // Scale freely: index_of does not need unit length.
                let s = [1e-20f32, 1.0, 3.0, 1e20][(r.next_u32() % 4) as usize];
                d = d.map(|x| x * s);
                assert_eq!(
                    direction_cell(&dirs, d, None),
                    dirs.index_of(d),
                    "{dirs:?} {d:?}"
                );
            }
            for d in [
                [0.0, 0.0, 1.0],
                [1.0, 0.0, 0.0],
                [-1.0, 0.0, -0.0],
                [0.0, -1.0, 0.0],
                [1.0, 1.0, 0.0],
                [1e-30, -1e-30, 1.0],
            ] {
                assert_eq!(direction_cell(&dirs, d, None), dirs.index_of(d));
            }
        }
    }

    #[test]
    fn jitter_stays_in_range_and_moves_cells() {
        let mut r = Rng::new(13);
        for dirs in [Directions::THESIS_DEFAULT, Directions::Octahedral { n: 4 }] {
            let mut moved = 0;
            for _ in 0..10_000 {
                let d = random_dir(&mut r);
                let j = DirJitter {
                    strength: 1.0,
                    xi: [r.next_f32(), r.next_f32()],
                };
                let c = direction_cell(&dirs, d, Some(j));
                assert!(c < dirs.count());
                moved += u32::from(c != dirs.index_of(d));
                // Zero strength is a no-op.
                let z = DirJitter {
                    strength: 0.0,
                    xi: j.xi,
                };
                assert_eq!(direction_cell(&dirs, d, Some(z)), dirs.index_of(d));
            }
            assert!(moved > 1000 && moved < 9000, "{dirs:?}: {moved}");
        }
    }
}
