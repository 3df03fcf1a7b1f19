//! A typed, read-only view of a pin file's sparse, bricked density section (format 1.1,
//! `docs/format.md` section 5.6a): zero-copy from the mapped file, validated once when made
//! (every index entry canonical and in range, every stored voxel finite and `>= 0`, and, from
//! a file, the section's checksum in the same pass), with the dense view's voxel and
//! trilinear conventions.

use pin_format::{SparseDensityView, SparseValues};

use crate::error::Result;
use crate::loader::PinGrid;
use crate::sections::trilinear;

/// The embedded sparse density: bricks of `brick^3` voxels over the grid box, found through a
/// top-level index of one `u32` per brick; empty bricks read as 0. Voxel centres and the
/// field between them follow [`crate::Density`].
#[derive(Clone, Copy, Debug)]
pub struct SparseDensity<'g> {
    view: SparseDensityView<'g>,
    box_min: [f64; 3],
    box_max: [f64; 3],
}

impl<'g> SparseDensity<'g> {
    /// Validates a section view over the box `[box_min, box_max]`: linear in the section.
    pub fn new(
        view: SparseDensityView<'g>,
        box_min: [f64; 3],
        box_max: [f64; 3],
    ) -> std::result::Result<Self, String> {
        view.check_entries().map_err(|e| e.to_string())?;
        if let Some((i, v)) = view.first_bad_value() {
            return Err(format!(
                "sparse density value {v} at {i} is not finite and >= 0"
            ));
        }
        Ok(Self {
            view,
            box_min,
            box_max,
        })
    }

    /// Voxels along x, y, z (each `>= 1`).
    pub fn dims(&self) -> [u32; 3] {
        self.view.header.dims
    }

    /// Brick edge in voxels (a power of two).
    pub fn brick(&self) -> u32 {
        self.view.header.brick
    }

    /// Bricks along x, y, z.
    pub fn brick_dims(&self) -> [u32; 3] {
        self.view.brick_dims
    }

    /// One entry per brick, x fastest: slot or [`pin_format::layout::EMPTY_BRICK`]; checked.
    pub fn index(&self) -> &'g [u32] {
        self.view.index
    }

    /// The stored bricks' voxels, slot after slot.
    pub fn values(&self) -> SparseValues<'g> {
        self.view.values
    }

    /// Stored bricks.
    pub fn brick_count(&self) -> u32 {
        self.view.header.brick_count
    }

    /// The grid's local box the voxels fill.
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        (self.box_min, self.box_max)
    }

    /// The size of one voxel per axis (local units).
    pub fn spacing(&self) -> [f64; 3] {
        let d = self.dims();
        [0, 1, 2].map(|a| (self.box_max[a] - self.box_min[a]) / f64::from(d[a]))
    }

    /// Voxel `(x, y, z)` (0 in an empty brick), or `None` outside the voxel grid.
    #[inline]
    pub fn get(&self, voxel: [u32; 3]) -> Option<f32> {
        self.view.get(voxel)
    }

    /// The field at a local point, as [`crate::Density::extinction`] defines it.
    pub fn extinction(&self, p: [f64; 3]) -> f32 {
        trilinear(self.dims(), (self.box_min, self.box_max), p, |v| {
            self.get(v).unwrap_or(0.0)
        })
    }
}

impl PinGrid {
    /// The sparse density section (format 1.1), validated: its checksum, its index and
    /// every stored voxel, in one pass over its bytes; `None` if the file has none.
    pub fn sparse_density(&self) -> Result<Option<SparseDensity<'_>>> {
        let file = self.file()?;
        let d = self.desc();
        let view = file
            .checked_sparse_density()
            .map_err(|e| self.format_err(e))?;
        Ok(view.map(|view| SparseDensity {
            view,
            box_min: d.box_min,
            box_max: d.box_max,
        }))
    }
}

#[cfg(test)]
mod tests {
    use half::f16;
    use pin_format::layout::{DENSITY_F16, EMPTY_BRICK};
    use pin_format::{
        DensityHeader, Directions, OwnedPinGrid, OwnedSparseDensity, OwnedSparseValues, PinEntry,
        SparseDensityHeader, grid_desc,
    };

    use super::*;

    /// A 5x3x2 field over a 2x1x1 box as both a dense and a sparse section (bricks of 2).
    fn both() -> PinGrid {
        let dims = [5u32, 3, 2];
        let value = |x: u32, y: u32, z: u32| {
            if (2..4).contains(&x) && y < 2 {
                0.0
            } else {
                (x + 10 * y + 100 * z) as f32 * 0.25
            }
        };
        let dense: Vec<f16> = (0..30)
            .map(|i| f16::from_f32(value(i % 5, (i / 5) % 3, i / 15)))
            .collect();
        let bdims = [3u32, 2, 1];
        let mut index = vec![];
        let mut values = vec![];
        for by in 0..bdims[1] {
            for bx in 0..bdims[0] {
                let mut brick = vec![f16::ZERO; 8];
                let mut any = false;
                for (i, b) in brick.iter_mut().enumerate() {
                    let [x, y, z] = [
                        bx * 2 + i as u32 % 2,
                        by * 2 + (i as u32 / 2) % 2,
                        i as u32 / 4,
                    ];
                    if x < dims[0] && y < dims[1] {
                        *b = f16::from_f32(value(x, y, z));
                        any |= b.to_f32() != 0.0;
                    }
                }
                if any {
                    index.push((values.len() / 8) as u32);
                    values.extend(brick);
                } else {
                    index.push(EMPTY_BRICK);
                }
            }
        }
        assert!(index.contains(&EMPTY_BRICK));
        let mut desc = grid_desc([1, 1, 1], Directions::Octahedral { n: 1 }, 1, 1);
        desc.box_max = [2.0, 1.0, 1.0];
        let owned = OwnedPinGrid {
            pins: vec![PinEntry::EMPTY; 1],
            desc,
            tile: None,
            cell_index: None,
            majorant: None,
            density: Some((
                DensityHeader {
                    dims,
                    encoding: DENSITY_F16,
                },
                dense,
            )),
            control: None,
            sparse_density: Some(OwnedSparseDensity {
                header: SparseDensityHeader {
                    dims,
                    encoding: DENSITY_F16,
                    brick: 2,
                    brick_count: (values.len() / 8) as u32,
                    reserved: [0; 2],
                },
                index,
                values: OwnedSparseValues::F16(values),
            }),
            metadata: None,
        };
        PinGrid::from_bytes(owned.to_bytes().unwrap()).unwrap()
    }

    #[test]
    fn sparse_reads_what_dense_reads() {
        let grid = both();
        let d = grid.density().unwrap().unwrap();
        let s = grid.sparse_density().unwrap().unwrap();
        assert_eq!(s.dims(), d.dims());
        assert_eq!(s.spacing(), d.spacing());
        for z in 0..3 {
            for y in 0..4 {
                for x in 0..6 {
                    assert_eq!(s.get([x, y, z]), d.get([x, y, z]), "{x} {y} {z}");
                }
            }
        }
        let mut rng = 1u64;
        for _ in 0..2000 {
            let mut p = [0.0; 3];
            for (a, v) in p.iter_mut().enumerate() {
                rng = rng
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let u = (rng >> 11) as f64 / (1u64 << 53) as f64;
                *v = u * 1.2 * [2.0, 1.0, 1.0][a] - 0.1;
            }
            assert_eq!(s.extinction(p), d.extinction(p), "{p:?}");
        }
    }
}
