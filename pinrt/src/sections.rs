//! Typed, read-only views of a pin file's optional majorant and density sections
//! (`docs/format.md` sections 5.5 and 5.6), so that a renderer can track or march the medium
//! from the `.pin` alone.
//!
//! Both views borrow the grid's bytes (no copy) and are validated when made: the dimensions
//! are checked against the section's actual length (a length or count in the file is never
//! trusted on its own), and every value is checked finite and `>= 0` once, so that readers
//! of a view need no checks of their own. Made from a file ([`PinGrid::majorants`] and the
//! others), a view is also checked against its section's checksum, in the same pass over
//! the bytes: a damaged section is refused even where its values stay in range. Both live in the grid's local box
//! `[box_min, box_max]` (placed in the world by the grid's `local_to_world`).

use pin_format::{ControlView, DensityView, MajorantView};

use crate::error::Result;
use crate::loader::PinGrid;

/// The majorant section: a conservative upper bound of the extinction per brick; the bricks
/// tile the grid box uniformly, `x` fastest. Like [`Density`], a view of the grid's bytes,
/// validated when made (dimensions against the bytes present, every value finite and
/// `>= 0`), in the grid's local box.
#[derive(Clone, Copy, Debug)]
pub struct Majorants<'g> {
    dims: [u32; 3],
    values: &'g [f32],
    box_min: [f64; 3],
    box_max: [f64; 3],
}

/// The embedded density: the extinction the pins were baked from, as f16 voxels over the
/// grid box (voxel centres at `box_min + (i + 0.5) * extent / dims`), `x` fastest.
#[derive(Clone, Copy, Debug)]
pub struct Density<'g> {
    dims: [u32; 3],
    values: &'g [half::f16],
    box_min: [f64; 3],
    box_max: [f64; 3],
}

/// The control section (format 1.1): per brick of a grid tiling the grid box uniformly
/// (`x` fastest), a control extinction, a residual majorant and a majorant, for residual ratio
/// tracking (docs/format.md section 5.8). A view of the grid's bytes, validated when made by
/// the format's rules (every value finite and `>= 0`, control at most the majorant, a residual
/// majorant of 0 only in an empty brick), in the grid's local box.
#[derive(Clone, Copy, Debug)]
pub struct Control<'g> {
    view: ControlView<'g>,
    box_min: [f64; 3],
    box_max: [f64; 3],
}

impl<'g> Control<'g> {
    /// Validates a section view over the box `[box_min, box_max]`.
    pub fn new(
        view: ControlView<'g>,
        box_min: [f64; 3],
        box_max: [f64; 3],
    ) -> std::result::Result<Self, String> {
        check_dims("control", view.dims, view.control.len())?;
        view.check_values().map_err(|e| e.to_string())?;
        Ok(Self {
            view,
            box_min,
            box_max,
        })
    }

    /// Bricks along x, y, z (each `>= 1`).
    pub fn dims(&self) -> [u32; 3] {
        self.view.dims
    }

    /// The control extinction per brick.
    pub fn control(&self) -> &'g [f32] {
        self.view.control
    }

    /// The residual majorant per brick (0 only in an empty brick).
    pub fn residual(&self) -> &'g [f32] {
        self.view.residual
    }

    /// The majorant per brick.
    pub fn majorant(&self) -> &'g [f32] {
        self.view.majorant
    }

    /// The grid's local box the bricks tile.
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        (self.box_min, self.box_max)
    }
}

/// `dims[0] * dims[1] * dims[2]` when every dim is `>= 1` and the product equals `len`.
fn check_dims(what: &str, dims: [u32; 3], len: usize) -> std::result::Result<(), String> {
    let n = dims
        .iter()
        .try_fold(1u64, |acc, &d| acc.checked_mul(u64::from(d)));
    match n {
        Some(n) if dims.iter().all(|&d| d >= 1) && n == len as u64 => Ok(()),
        _ => Err(format!(
            "{what} dims {dims:?} do not match its {len} stored values"
        )),
    }
}

/// The index and value of the first value that is not finite and `>= 0`.
fn first_bad(values: impl Iterator<Item = f32>) -> Option<(usize, f32)> {
    values
        .enumerate()
        .find(|(_, v)| !(v.is_finite() && *v >= 0.0))
}

impl<'g> Majorants<'g> {
    /// Validates a section view over the box `[box_min, box_max]`.
    pub fn new(
        view: MajorantView<'g>,
        box_min: [f64; 3],
        box_max: [f64; 3],
    ) -> std::result::Result<Self, String> {
        check_dims("majorant", view.dims, view.values.len())?;
        if let Some((i, v)) = first_bad(view.values.iter().copied()) {
            return Err(format!("majorant value {v} at {i} is not finite and >= 0"));
        }
        Ok(Self {
            dims: view.dims,
            values: view.values,
            box_min,
            box_max,
        })
    }

    /// Bricks along x, y, z (each `>= 1`).
    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// All bricks, `x` fastest; each finite and `>= 0`.
    pub fn values(&self) -> &'g [f32] {
        self.values
    }

    /// The grid's local box the bricks tile.
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        (self.box_min, self.box_max)
    }

    /// Brick `(x, y, z)`, or `None` outside the brick grid.
    pub fn get(&self, brick: [u32; 3]) -> Option<f32> {
        if (0..3).any(|a| brick[a] >= self.dims[a]) {
            return None;
        }
        let [x, y, z] = brick.map(|v| v as usize);
        let [nx, ny, _] = self.dims.map(|v| v as usize);
        self.values.get(x + nx * (y + ny * z)).copied()
    }
}

impl<'g> Density<'g> {
    /// Validates a section view over the box `[box_min, box_max]`.
    pub fn new(
        view: DensityView<'g>,
        box_min: [f64; 3],
        box_max: [f64; 3],
    ) -> std::result::Result<Self, String> {
        check_dims("density", view.dims, view.values.len())?;
        if let Some((i, v)) = first_bad(view.values.iter().map(|h| h.to_f32())) {
            return Err(format!("density value {v} at {i} is not finite and >= 0"));
        }
        Ok(Self {
            dims: view.dims,
            values: view.values,
            box_min,
            box_max,
        })
    }

    /// Voxels along x, y, z (each `>= 1`).
    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// The stored f16 voxels, `x` fastest; each finite and `>= 0`.
    pub fn values(&self) -> &'g [half::f16] {
        self.values
    }

    /// The voxels widened to f32 (exact), `x` fastest.
    pub fn to_f32(&self) -> Vec<f32> {
        self.values.iter().map(|h| h.to_f32()).collect()
    }

    /// The grid's local box the voxels fill.
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        (self.box_min, self.box_max)
    }

    /// The size of one voxel per axis (local units).
    pub fn spacing(&self) -> [f64; 3] {
        [0, 1, 2].map(|a| (self.box_max[a] - self.box_min[a]) / f64::from(self.dims[a]))
    }

    /// Voxel `(x, y, z)`, or `None` outside the voxel grid.
    pub fn get(&self, voxel: [u32; 3]) -> Option<f32> {
        if (0..3).any(|a| voxel[a] >= self.dims[a]) {
            return None;
        }
        let [x, y, z] = voxel.map(|v| v as usize);
        let [nx, ny, _] = self.dims.map(|v| v as usize);
        self.values.get(x + nx * (y + ny * z)).map(|h| h.to_f32())
    }

    /// The field at a local point: trilinear between voxel centres, the edge voxel's value in
    /// the outer half voxel, 0 outside the box (the format's convention).
    pub fn extinction(&self, p: [f64; 3]) -> f32 {
        trilinear(self.dims, (self.box_min, self.box_max), p, |v| {
            self.get(v).unwrap_or(0.0)
        })
    }
}

/// The format's voxel field at a local point `p` of `bounds` for `dims` voxels read through
/// `at`: trilinear between voxel centres, the edge voxel's value in the outer half voxel, 0
/// outside the box. One function for the dense and the sparse section, so they agree.
pub(crate) fn trilinear(
    dims: [u32; 3],
    (box_min, box_max): ([f64; 3], [f64; 3]),
    p: [f64; 3],
    at: impl Fn([u32; 3]) -> f32,
) -> f32 {
    if !(0..3).all(|a| p[a] >= box_min[a] && p[a] <= box_max[a]) {
        return 0.0;
    }
    let mut i0 = [0u32; 3];
    let mut i1 = [0u32; 3];
    let mut f = [0f64; 3];
    for a in 0..3 {
        let n = f64::from(dims[a]);
        let spacing = (box_max[a] - box_min[a]) / n;
        let u = ((p[a] - box_min[a]) / spacing - 0.5).clamp(0.0, n - 1.0);
        let fl = u.floor();
        i0[a] = fl as u32;
        i1[a] = (i0[a] + 1).min(dims[a] - 1);
        f[a] = u - fl;
    }
    let at = |x, y, z| f64::from(at([x, y, z]));
    let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
    let c0 = lerp(
        lerp(at(i0[0], i0[1], i0[2]), at(i1[0], i0[1], i0[2]), f[0]),
        lerp(at(i0[0], i1[1], i0[2]), at(i1[0], i1[1], i0[2]), f[0]),
        f[1],
    );
    let c1 = lerp(
        lerp(at(i0[0], i0[1], i1[2]), at(i1[0], i0[1], i1[2]), f[0]),
        lerp(at(i0[0], i1[1], i1[2]), at(i1[0], i1[1], i1[2]), f[0]),
        f[1],
    );
    lerp(c0, c1, f[2]) as f32
}

impl PinGrid {
    /// The majorant section, validated: its checksum and every value, in one pass over its
    /// bytes (each call reads it again); `None` if the file has none.
    pub fn majorants(&self) -> Result<Option<Majorants<'_>>> {
        let file = self.file()?;
        let d = self.desc();
        let view = file.checked_majorant().map_err(|e| self.format_err(e))?;
        Ok(view.map(|view| Majorants {
            dims: view.dims,
            values: view.values,
            box_min: d.box_min,
            box_max: d.box_max,
        }))
    }

    /// The control section (format 1.1), validated: its checksum and every brick's rules,
    /// in one pass over its bytes; `None` if the file has none.
    pub fn control(&self) -> Result<Option<Control<'_>>> {
        let file = self.file()?;
        let d = self.desc();
        let view = file.checked_control().map_err(|e| self.format_err(e))?;
        Ok(view.map(|view| Control {
            view,
            box_min: d.box_min,
            box_max: d.box_max,
        }))
    }

    /// The embedded density section, validated: its checksum and every voxel, in one pass
    /// over its bytes; `None` if the file has none.
    pub fn density(&self) -> Result<Option<Density<'_>>> {
        let file = self.file()?;
        let d = self.desc();
        let view = file.checked_density().map_err(|e| self.format_err(e))?;
        Ok(view.map(|view| Density {
            dims: view.dims,
            values: view.values,
            box_min: d.box_min,
            box_max: d.box_max,
        }))
    }
}

#[cfg(test)]
mod tests {
    use half::f16;
    use pin_format::{
        DensityHeader, Directions, MajorantHeader, OwnedPinGrid, PinEntry, grid_desc,
    };

    use super::*;

    fn grid_with(
        majorant: Option<([u32; 3], Vec<f32>)>,
        density: Option<([u32; 3], Vec<f16>)>,
    ) -> Vec<u8> {
        let mut desc = grid_desc([1, 1, 1], Directions::Octahedral { n: 1 }, 1, 1);
        desc.box_min = [0.0; 3];
        desc.box_max = [2.0, 1.0, 1.0];
        let owned = OwnedPinGrid {
            pins: vec![PinEntry::EMPTY; 1],
            desc,
            tile: None,
            cell_index: None,
            majorant: majorant.map(|(dims, v)| (MajorantHeader { dims, reserved: 0 }, v)),
            density: density.map(|(dims, v)| {
                let encoding = 0; // f16, the only encoding
                (DensityHeader { dims, encoding }, v)
            }),
            sparse_density: None,
            control: None,
            metadata: None,
        };
        owned.to_bytes().unwrap()
    }

    #[test]
    fn majorant_and_density_read_back_with_the_format_convention() {
        let bytes = grid_with(
            Some(([2, 1, 1], vec![1.5, 4.0])),
            Some(([2, 1, 1], vec![f16::from_f32(1.0), f16::from_f32(3.0)])),
        );
        let grid = PinGrid::from_bytes(bytes).unwrap();
        let m = grid.majorants().unwrap().unwrap();
        assert_eq!(m.dims(), [2, 1, 1]);
        assert_eq!(m.get([1, 0, 0]), Some(4.0));
        assert_eq!(m.get([2, 0, 0]), None);
        let d = grid.density().unwrap().unwrap();
        assert_eq!(d.spacing(), [1.0; 3]);
        let e = |x: f64| d.extinction([x, 0.5, 0.5]);
        assert_eq!(e(0.1), 1.0); // outer half voxel: the edge value
        assert_eq!(e(0.5), 1.0); // a centre
        assert!((e(1.0) - 2.0).abs() < 1e-6); // halfway between centres
        assert_eq!(e(1.9), 3.0);
        assert_eq!(e(2.1), 0.0); // outside the box
        assert_eq!(d.to_f32(), vec![1.0, 3.0]);
    }

    /// A value changed within range (the low bit of the last one): the values pass, the
    /// checksum does not, and the error names the grid and the section.
    #[test]
    fn damaged_sections_are_refused_on_first_use() {
        let clean = grid_with(
            Some(([2, 1, 1], vec![1.5, 4.0])),
            Some(([2, 1, 1], vec![f16::from_f32(1.0), f16::from_f32(3.0)])),
        );
        let file = pin_format::PinFile::parse(&clean).unwrap();
        let end = |kind: pin_format::SectionKind| {
            let s = file
                .sections()
                .iter()
                .find(|s| s.kind == kind as u32)
                .unwrap();
            (s.offset + s.length) as usize
        };
        let cases = [
            (end(pin_format::SectionKind::Majorant) - 4, "'majorant'"),
            (end(pin_format::SectionKind::Density) - 2, "'density'"),
        ];
        for (at, name) in cases {
            let mut bytes = clean.clone();
            bytes[at] ^= 1;
            let grid = PinGrid::from_bytes(bytes).unwrap();
            let e = if name == "'majorant'" {
                grid.majorants().map(|_| ()).unwrap_err()
            } else {
                grid.density().map(|_| ()).unwrap_err()
            }
            .to_string();
            assert!(
                e.starts_with("<memory>: checksum mismatch in section ") && e.contains(name),
                "{e}"
            );
        }
    }

    #[test]
    fn absent_sections_are_none() {
        let grid = PinGrid::from_bytes(grid_with(None, None)).unwrap();
        assert!(grid.majorants().unwrap().is_none());
        assert!(grid.density().unwrap().is_none());
    }

    #[test]
    fn views_refuse_values_and_dims_they_cannot_trust() {
        let b = ([0.0; 3], [1.0; 3]);
        let ok = [1.0f32, 2.0];
        assert!(
            Majorants::new(
                MajorantView {
                    dims: [2, 1, 1],
                    values: &ok
                },
                b.0,
                b.1
            )
            .is_ok()
        );
        // A count that disagrees with the values actually there.
        for dims in [[3, 1, 1], [0, 1, 1], [u32::MAX, u32::MAX, 2]] {
            let e = Majorants::new(MajorantView { dims, values: &ok }, b.0, b.1).unwrap_err();
            assert!(e.contains("do not match"), "{e}");
        }
        for bad in [f32::NAN, -1.0, f32::INFINITY] {
            let v = [1.0, bad];
            let e = Majorants::new(
                MajorantView {
                    dims: [2, 1, 1],
                    values: &v,
                },
                b.0,
                b.1,
            );
            assert!(e.unwrap_err().contains("at 1"));
        }
        let v = [f16::from_f32(1.0), f16::NAN];
        let e = Density::new(
            DensityView {
                dims: [2, 1, 1],
                values: &v,
            },
            b.0,
            b.1,
        );
        assert!(e.unwrap_err().contains("not finite"));
        let v = [f16::from_f32(-0.5)];
        assert!(
            Density::new(
                DensityView {
                    dims: [1, 1, 1],
                    values: &v
                },
                b.0,
                b.1
            )
            .is_err()
        );
    }
}
