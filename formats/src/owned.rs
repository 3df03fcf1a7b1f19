//! An owned, in-memory pin grid: what producers fill in and what tests compare.
//!
//! The baker fills one and writes it with [`OwnedPinGrid::write_into`] (through
//! [`crate::AtomicPinFile`]'s [`crate::PinFileWriter`]); tools that rewrite files and the
//! round-trip tests use it too.

#[cfg(feature = "writer")]
use std::io::{Cursor, Seek, Write};
#[cfg(feature = "writer")]
use std::path::Path;

use crate::control::OwnedControl;
use crate::error::{FormatError, Result};
use crate::layout::*;
use crate::metadata::Metadata;
use crate::reader::PinFile;
use crate::shape::GridShape;
use crate::sparse::OwnedSparseDensity;
#[cfg(feature = "writer")]
use crate::writer::{AtomicPinFile, PinFileWriter};

/// A whole pin grid in memory, sections optional as in the file.
#[derive(Clone, Debug, PartialEq)]
pub struct OwnedPinGrid {
    pub desc: GridDesc,
    pub tile: Option<TileDesc>,
    /// One u32 per covered cell, or `None` for dense storage.
    pub cell_index: Option<Vec<u32>>,
    pub pins: Vec<PinEntry>,
    pub majorant: Option<(MajorantHeader, Vec<f32>)>,
    pub density: Option<(DensityHeader, Vec<half::f16>)>,
    /// The sparse, bricked density (format 1.1; its presence makes the file 1.1).
    pub sparse_density: Option<OwnedSparseDensity>,
    /// The per-brick control of residual ratio tracking (format 1.1; its presence makes the
    /// file 1.1).
    pub control: Option<OwnedControl>,
    pub metadata: Option<Metadata>,
}

impl OwnedPinGrid {
    /// Checks the same invariants a reader checks, so that a written file always parses.
    pub fn validate(&self) -> Result<GridShape> {
        let shape = GridShape::new(&self.desc, self.tile.as_ref())?;
        let pins = shape.pin_count(self.desc.stored_cells)?;
        if self.pins.len() as u64 != pins {
            return Err(FormatError::InvalidInput(format!(
                "{} pins given, grid needs {pins}",
                self.pins.len()
            )));
        }
        match &self.cell_index {
            None if self.desc.stored_cells != shape.covered_cells => {
                return Err(FormatError::InvalidInput(
                    "dense grid must store every covered cell".into(),
                ));
            }
            Some(ix) if ix.len() as u64 != shape.covered_cells => {
                return Err(FormatError::InvalidInput(format!(
                    "cell index has {} entries, grid covers {} cells",
                    ix.len(),
                    shape.covered_cells
                )));
            }
            _ => {}
        }
        // Checked: absurd dims must be an error, not an overflow panic.
        let volume = |dims: [u32; 3]| {
            dims.iter()
                .try_fold(1u64, |acc, &d| acc.checked_mul(u64::from(d)))
                .unwrap_or(0)
        };
        if let Some((h, v)) = &self.majorant {
            let n = volume(h.dims);
            if n == 0 || v.len() as u64 != n {
                return Err(FormatError::InvalidInput("majorant size mismatch".into()));
            }
        }
        if let Some((h, v)) = &self.density {
            let n = volume(h.dims);
            if n == 0 || v.len() as u64 != n || h.encoding != DENSITY_F16 {
                return Err(FormatError::InvalidInput("density size mismatch".into()));
            }
        }
        if let Some(s) = &self.sparse_density {
            s.view()
                .map_err(|e| FormatError::InvalidInput(format!("sparse density: {e}")))?;
        }
        if let Some(c) = &self.control {
            let bytes = c.to_bytes()?;
            crate::control::ControlView::parse(&bytes)
                .and_then(|v| v.check_values())
                .map_err(|e| FormatError::InvalidInput(format!("control: {e}")))?;
        }
        Ok(shape)
    }

    /// Streams the grid into `w` in the canonical section order.
    #[cfg(feature = "writer")]
    pub fn write_into<W: Write + Seek>(&self, w: &mut PinFileWriter<W>) -> Result<()> {
        self.write_sections(w, None)
    }

    /// [`OwnedPinGrid::write_into`], with the sparse density section taken from `sparse`,
    /// whose bricks are copied from a reader as the section is written: a grid whose bricks
    /// would not fit beside the rest (a production-scale bake spools them to a temporary
    /// file) is written without ever holding them. The bytes are those of the same grid with
    /// the bricks in [`OwnedPinGrid::sparse_density`]. The grid's own `sparse_density` must
    /// be `None`.
    #[cfg(feature = "writer")]
    pub fn write_streamed_into<W: Write + Seek>(
        &self,
        w: &mut PinFileWriter<W>,
        sparse: StreamedSparseDensity<'_>,
    ) -> Result<()> {
        if self.sparse_density.is_some() {
            return Err(FormatError::InvalidInput(
                "a grid with a sparse density of its own cannot also stream one".into(),
            ));
        }
        crate::sparse::SparseDensityView::check_index(&sparse.header, sparse.index)
            .map_err(|e| FormatError::InvalidInput(format!("sparse density: {e}")))?;
        self.write_sections(w, Some(sparse))
    }

    #[cfg(feature = "writer")]
    fn write_sections<W: Write + Seek>(
        &self,
        w: &mut PinFileWriter<W>,
        streamed: Option<StreamedSparseDensity<'_>>,
    ) -> Result<()> {
        self.validate()?;
        w.add_section(
            SectionKind::GridDesc as u32,
            SECTION_REQUIRED,
            bytemuck::bytes_of(&self.desc),
        )?;
        if let Some(t) = &self.tile {
            w.add_section(
                SectionKind::Tile as u32,
                SECTION_REQUIRED,
                bytemuck::bytes_of(t),
            )?;
        }
        if let Some(ix) = &self.cell_index {
            w.add_section(
                SectionKind::CellIndex as u32,
                SECTION_REQUIRED,
                bytemuck::cast_slice(ix),
            )?;
        }
        if !self.pins.is_empty() {
            w.add_section(
                SectionKind::Pins as u32,
                SECTION_REQUIRED,
                bytemuck::cast_slice(&self.pins),
            )?;
        }
        if let Some((h, v)) = &self.majorant {
            w.begin_section(SectionKind::Majorant as u32, 0)?;
            w.write(bytemuck::bytes_of(h))?;
            w.write(bytemuck::cast_slice(v))?;
            w.end_section()?;
        }
        if let Some((h, v)) = &self.density {
            w.begin_section(SectionKind::Density as u32, 0)?;
            w.write(bytemuck::bytes_of(h))?;
            w.write(bytemuck::cast_slice(v))?;
            w.end_section()?;
        }
        if let Some(s) = &self.sparse_density {
            w.begin_section(SectionKind::SparseDensity as u32, 0)?;
            w.write(bytemuck::bytes_of(&s.header))?;
            for part in s.body_parts() {
                w.write(part)?;
            }
            w.end_section()?;
        }
        if let Some(s) = streamed {
            w.begin_section(SectionKind::SparseDensity as u32, 0)?;
            w.write(bytemuck::bytes_of(&s.header))?;
            w.write(bytemuck::cast_slice(s.index))?;
            copy_bricks(w, &s.header, s.values)?;
            w.end_section()?;
        }
        if let Some(c) = &self.control {
            w.add_section(SectionKind::Control as u32, 0, &c.to_bytes()?)?;
        }
        if let Some(m) = &self.metadata {
            w.add_section(SectionKind::Metadata as u32, 0, &m.encode()?)?;
        }
        Ok(())
    }

    /// The whole file in memory.
    #[cfg(feature = "writer")]
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let mut w = PinFileWriter::new(Cursor::new(Vec::new()))?;
        self.write_into(&mut w)?;
        Ok(w.finish()?.into_inner())
    }

    /// Writes atomically: a temp file beside `path`, fsync, rename.
    #[cfg(feature = "writer")]
    pub fn write_atomic(&self, path: impl AsRef<Path>) -> Result<()> {
        let mut f = AtomicPinFile::create(path)?;
        self.write_into(f.writer())?;
        f.commit()
    }

    /// Copies a parsed file into owned form (unknown sections are dropped).
    pub fn from_file(file: &PinFile<'_>) -> Result<Self> {
        Ok(Self {
            desc: *file.desc(),
            tile: file.tile().copied(),
            cell_index: file.cell_index().map(<[u32]>::to_vec),
            pins: file.pins().to_vec(),
            majorant: file.majorant().map(|m| {
                (
                    MajorantHeader {
                        dims: m.dims,
                        reserved: 0,
                    },
                    m.values.to_vec(),
                )
            }),
            density: file.density().map(|d| {
                (
                    DensityHeader {
                        dims: d.dims,
                        encoding: DENSITY_F16,
                    },
                    d.values.to_vec(),
                )
            }),
            sparse_density: file
                .sparse_density()
                .map(|v| OwnedSparseDensity::from_view(&v)),
            control: file.control().map(|v| OwnedControl::from_view(&v)),
            metadata: file.metadata().transpose()?,
        })
    }
}

/// A sparse density section whose bricks are read from `values` while the section is
/// written ([`OwnedPinGrid::write_streamed_into`]): `header.brick_count` bricks of
/// `header.brick`^3 voxels in the header's encoding, in slot order, and nothing after them.
#[cfg(feature = "writer")]
pub struct StreamedSparseDensity<'a> {
    pub header: SparseDensityHeader,
    pub index: &'a [u32],
    pub values: &'a mut dyn std::io::Read,
}

/// Copies the bricks that `header` counts from `values` into the open section: exactly the bytes its header counts (a
/// short reader, or one with bytes left over, is an error rather than a wrong file).
#[cfg(feature = "writer")]
fn copy_bricks<W: Write + Seek>(
    w: &mut PinFileWriter<W>,
    header: &SparseDensityHeader,
    values: &mut dyn std::io::Read,
) -> Result<()> {
    let elem: u64 = if header.encoding == DENSITY_F16 { 2 } else { 4 };
    let mut left = u64::from(header.brick_count) * u64::from(header.brick).pow(3) * elem;
    let mut buf = vec![0u8; 1 << 20];
    while left > 0 {
        let n = (left.min(buf.len() as u64)) as usize;
        values.read_exact(&mut buf[..n]).map_err(|e| {
            FormatError::InvalidInput(format!(
                "sparse density bricks: {left} bytes still to copy: {e}"
            ))
        })?;
        w.write(&buf[..n])?;
        left -= n as u64;
    }
    let mut extra = [0u8; 1];
    if values.read(&mut extra).map_err(FormatError::Io)? != 0 {
        return Err(FormatError::InvalidInput(
            "sparse density bricks: more bytes than the header counts".into(),
        ));
    }
    Ok(())
}

/// A grid description with the given shape and everything else at neutral defaults
/// (unit box at the origin, identity transform).
pub fn grid_desc(
    dims: [u32; 3],
    directions: crate::Directions,
    pins_per_entry: u32,
    stored_cells: u64,
) -> GridDesc {
    let (direction_kind, direction_res) = directions.to_desc();
    GridDesc {
        dims,
        direction_kind,
        direction_res,
        pins_per_entry,
        bits_per_pin: BITS_PER_PIN,
        stored_cells,
        box_min: [0.0; 3],
        box_max: [1.0; 3],
        local_to_world: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
        step_size: 0.01,
        density_scale: 1.0,
        seed: 0,
        flags: 0,
        reserved0: 0,
        source_box_min: [0.0; 3],
        source_box_max: [1.0; 3],
        reserved: [0; 4],
    }
}
