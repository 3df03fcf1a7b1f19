//! Zero-copy reader over `&[u8]` (an mmap or an in-memory buffer).
//!
//! [`PinFile::parse`] costs O(number of sections): it checks the header, the table, every
//! section's bounds, alignment and size against the grid description, and the checksums of
//! the small fixed-size sections, but never touches the bulk arrays. [`PinFile::verify`]
//! reads everything.

use bytemuck::Pod;

use crate::checksum::checksum;
use crate::checksum::header_checksum;
use crate::control::ControlView;
use crate::error::{FormatError, Result};
use crate::layout::*;
use crate::metadata::{MAX_METADATA_BYTES, Metadata};
use crate::shape::GridShape;
use crate::sparse::SparseDensityView;

/// The majorant grid: max extinction per brick over the grid box.
#[derive(Clone, Copy, Debug)]
pub struct MajorantView<'a> {
    pub dims: [u32; 3],
    pub values: &'a [f32],
}

/// The embedded density field (f16 bits, x fastest) over the grid box.
#[derive(Clone, Copy, Debug)]
pub struct DensityView<'a> {
    pub dims: [u32; 3],
    pub values: &'a [half::f16],
}

/// A parsed, validated pin file borrowing its bytes.
#[derive(Clone, Debug)]
pub struct PinFile<'a> {
    bytes: &'a [u8],
    header: FileHeader,
    sections: Vec<SectionEntry>,
    desc: GridDesc,
    shape: GridShape,
    tile: Option<TileDesc>,
    pins: &'a [PinEntry],
    cell_index: Option<&'a [u32]>,
    majorant: Option<MajorantView<'a>>,
    density: Option<DensityView<'a>>,
    sparse_density: Option<SparseDensityView<'a>>,
    control: Option<ControlView<'a>>,
    metadata: Option<&'a [u8]>,
}

fn read_pod<T: Pod>(bytes: &[u8]) -> T {
    bytemuck::pod_read_unaligned(&bytes[..size_of::<T>()])
}

fn cast<T: Pod>(kind: SectionKind, bytes: &[u8]) -> Result<&[T]> {
    bytemuck::try_cast_slice(bytes).map_err(|e| FormatError::BadData(kind, format!("{e:?}")))
}

fn section_err(index: usize, kind: u32, problem: impl Into<String>) -> FormatError {
    let kind = SectionKind::from_u32(kind)
        .map(|k| k.name().to_string())
        .unwrap_or_else(|| format!("kind {kind}"));
    FormatError::BadSection {
        index,
        kind,
        problem: problem.into(),
    }
}

fn size_err(kind: SectionKind, len: u64, want: u64, what: &str) -> FormatError {
    FormatError::BadData(
        kind,
        format!("section is {len} bytes but {what} needs {want}"),
    )
}

/// Product of three dims as u64 (cannot overflow: each is < 2^32, checked afterwards anyway).
fn volume(dims: [u32; 3], kind: SectionKind) -> Result<u64> {
    if dims.contains(&0) {
        return Err(FormatError::BadData(kind, "zero dimension".into()));
    }
    dims.iter()
        .try_fold(1u64, |acc, &d| acc.checked_mul(u64::from(d)))
        .ok_or_else(|| FormatError::BadData(kind, "dimension product overflows".into()))
}

impl<'a> PinFile<'a> {
    /// Validates the structure in O(sections) and returns typed views into `bytes`.
    ///
    /// `bytes` must be 4-byte aligned (any mmap or `Vec` allocation is).
    pub fn parse(bytes: &'a [u8]) -> Result<Self> {
        let len = bytes.len() as u64;
        let header_len = size_of::<FileHeader>() as u64;
        if len < 8 || bytes[..8] != MAGIC {
            return Err(if len < 8 && MAGIC.starts_with(bytes) {
                FormatError::TooShort {
                    len,
                    need: header_len,
                }
            } else {
                FormatError::BadMagic
            });
        }
        if len < header_len {
            return Err(FormatError::TooShort {
                len,
                need: header_len,
            });
        }
        let header: FileHeader = read_pod(bytes);
        if header.version_major != VERSION_MAJOR {
            return Err(FormatError::UnsupportedVersion {
                major: header.version_major,
                minor: header.version_minor,
                supported: VERSION_MAJOR,
            });
        }
        if header_checksum(&header) != header.header_checksum {
            return Err(FormatError::HeaderChecksum);
        }
        if header.file_size != len {
            return Err(FormatError::SizeMismatch {
                expected: header.file_size,
                actual: len,
            });
        }
        if !(bytes.as_ptr() as usize).is_multiple_of(4) {
            return Err(FormatError::Misaligned(4));
        }
        if u64::from(header.header_size) < header_len || u64::from(header.header_size) > len {
            return Err(FormatError::BadHeader("header size out of range"));
        }
        let entry_size = u64::from(header.section_entry_size);
        if entry_size < size_of::<SectionEntry>() as u64 || entry_size > 4096 {
            return Err(FormatError::BadHeader("section entry size out of range"));
        }
        if header.section_count > MAX_SECTIONS {
            return Err(FormatError::BadHeader("too many sections"));
        }
        if !header.table_offset.is_multiple_of(SECTION_ALIGN) {
            return Err(FormatError::BadHeader(
                "section table is not 64-byte aligned",
            ));
        }
        let table_len = u64::from(header.section_count) * entry_size;
        let table_end = header
            .table_offset
            .checked_add(table_len)
            .filter(|&e| e <= len && header.table_offset >= u64::from(header.header_size))
            .ok_or(FormatError::BadHeader("section table outside the file"))?;
        let table = &bytes[header.table_offset as usize..table_end as usize];
        if checksum(table) != header.table_checksum {
            return Err(FormatError::TableChecksum);
        }

        // The only allocation of parse: at most the table's own size (checked to fit above).
        let mut sections = Vec::with_capacity(header.section_count as usize);
        for chunk in table.chunks_exact(entry_size as usize) {
            sections.push(read_pod::<SectionEntry>(chunk));
        }
        // Bounds, alignment and overlap (with each other, the header and the table).
        let fixed = [
            (0, u64::from(header.header_size)),
            (header.table_offset, table_end),
        ];
        let mut known: [Option<usize>; 16] = [None; 16];
        for (i, s) in sections.iter().enumerate() {
            if s.offset % SECTION_ALIGN != 0 {
                return Err(section_err(i, s.kind, "offset is not 64-byte aligned"));
            }
            let end = s
                .offset
                .checked_add(s.length)
                .filter(|&e| e <= len)
                .ok_or_else(|| section_err(i, s.kind, "extends past the end of the file"))?;
            if s.length > 0 && fixed.iter().any(|&(a, b)| a < b && s.offset < b && a < end) {
                return Err(section_err(
                    i,
                    s.kind,
                    "overlaps the header or the section table",
                ));
            }
            match SectionKind::from_u32(s.kind) {
                Some(k) => {
                    let slot = &mut known[k as usize];
                    if slot.is_some() {
                        return Err(FormatError::DuplicateSection(k));
                    }
                    *slot = Some(i);
                }
                None if s.flags & SECTION_REQUIRED != 0 => {
                    return Err(FormatError::UnknownRequiredSection { kind: s.kind });
                }
                None => {}
            }
        }
        // Sections against each other, sorted by offset through a stack array of section
        // numbers, so that parse allocates nothing but the table vector.
        let mut order_buf = [0u16; MAX_SECTIONS as usize];
        let order = &mut order_buf[..sections.len()];
        for (i, o) in order.iter_mut().enumerate() {
            *o = i as u16;
        }
        order.sort_unstable_by_key(|&i| sections[usize::from(i)].offset);
        let mut reach = 0u64;
        for &i in order.iter() {
            let s = &sections[usize::from(i)];
            if s.length == 0 {
                continue;
            }
            if s.offset < reach {
                return Err(section_err(
                    usize::from(i),
                    s.kind,
                    "overlaps another section",
                ));
            }
            // Bounds were checked above; sorted and disjoint so far, so ends increase.
            reach = s.offset + s.length;
        }
        let body = |k: SectionKind| -> Option<(usize, &'a [u8])> {
            known[k as usize].map(|i| {
                let s = &sections[i];
                (i, &bytes[s.offset as usize..(s.offset + s.length) as usize])
            })
        };
        let small_checked = |k: SectionKind, need: usize| -> Result<Option<&'a [u8]>> {
            match body(k) {
                None => Ok(None),
                Some((i, b)) => {
                    if b.len() < need {
                        return Err(size_err(k, b.len() as u64, need as u64, "its record"));
                    }
                    if checksum(b) != sections[i].checksum {
                        return Err(FormatError::SectionChecksum {
                            kind: k.name().into(),
                            offset: sections[i].offset,
                        });
                    }
                    Ok(Some(b))
                }
            }
        };

        let desc_bytes = small_checked(SectionKind::GridDesc, size_of::<GridDesc>())?
            .ok_or(FormatError::MissingSection(SectionKind::GridDesc))?;
        let desc: GridDesc = read_pod(desc_bytes);
        let tile =
            small_checked(SectionKind::Tile, size_of::<TileDesc>())?.map(read_pod::<TileDesc>);
        let shape = GridShape::new(&desc, tile.as_ref())?;

        let cell_index = match body(SectionKind::CellIndex) {
            None => {
                if desc.stored_cells != shape.covered_cells {
                    return Err(FormatError::BadGrid(format!(
                        "no cell index, so all {} covered cells must be stored, but {} are",
                        shape.covered_cells, desc.stored_cells
                    )));
                }
                None
            }
            Some((_, b)) => {
                let want = shape.covered_cells * 4;
                if b.len() as u64 != want {
                    return Err(size_err(
                        SectionKind::CellIndex,
                        b.len() as u64,
                        want,
                        "one u32 per covered cell",
                    ));
                }
                Some(cast::<u32>(SectionKind::CellIndex, b)?)
            }
        };

        let pin_count = shape.pin_count(desc.stored_cells)?;
        let pins = match body(SectionKind::Pins) {
            None if pin_count == 0 => &[][..],
            None => return Err(FormatError::MissingSection(SectionKind::Pins)),
            Some((_, b)) => {
                let want = pin_count
                    .checked_mul(8)
                    .ok_or_else(|| FormatError::BadGrid("pin bytes overflow".into()))?;
                if b.len() as u64 != want {
                    return Err(size_err(
                        SectionKind::Pins,
                        b.len() as u64,
                        want,
                        &format!("{pin_count} pins"),
                    ));
                }
                cast::<PinEntry>(SectionKind::Pins, b)?
            }
        };

        let prefixed = |k: SectionKind, elem: u64| -> Result<Option<([u32; 4], &'a [u8])>> {
            let Some((_, b)) = body(k) else {
                return Ok(None);
            };
            if b.len() < 16 {
                return Err(size_err(k, b.len() as u64, 16, "its header"));
            }
            let head: [u32; 4] = read_pod(b);
            let n = volume([head[0], head[1], head[2]], k)?;
            let want = n
                .checked_mul(elem)
                .and_then(|x| x.checked_add(16))
                .ok_or_else(|| FormatError::BadData(k, "size overflows".into()))?;
            if b.len() as u64 != want {
                return Err(size_err(k, b.len() as u64, want, "its dimensions"));
            }
            Ok(Some((head, &b[16..])))
        };
        let majorant = match prefixed(SectionKind::Majorant, 4)? {
            None => None,
            Some((h, b)) => Some(MajorantView {
                dims: [h[0], h[1], h[2]],
                values: cast::<f32>(SectionKind::Majorant, b)?,
            }),
        };
        let density = match prefixed(SectionKind::Density, 2)? {
            None => None,
            Some((h, b)) => {
                if h[3] != DENSITY_F16 {
                    return Err(FormatError::BadData(
                        SectionKind::Density,
                        format!("unknown encoding {}", h[3]),
                    ));
                }
                Some(DensityView {
                    dims: [h[0], h[1], h[2]],
                    values: cast::<half::f16>(SectionKind::Density, b)?,
                })
            }
        };
        // Format 1.1: every length checked against the section's size inside.
        let sparse_density = body(SectionKind::SparseDensity)
            .map(|(_, b)| SparseDensityView::parse(b))
            .transpose()?;
        let control = body(SectionKind::Control)
            .map(|(_, b)| ControlView::parse(b))
            .transpose()?;
        let metadata = match body(SectionKind::Metadata) {
            Some((_, b)) if b.len() > MAX_METADATA_BYTES => {
                return Err(FormatError::BadMetadata(format!(
                    "section is {} bytes, limit {MAX_METADATA_BYTES}",
                    b.len()
                )));
            }
            other => other.map(|(_, b)| b),
        };

        Ok(Self {
            bytes,
            header,
            sections,
            desc,
            shape,
            tile,
            pins,
            cell_index,
            majorant,
            density,
            sparse_density,
            control,
            metadata,
        })
    }

    /// Checks every section checksum and every value: pins, index order, majorants, density,
    /// metadata. Linear in the file size, and each section's bytes are read once: hashed and
    /// checked piece by piece (as the `checked_*` reads of the bulk sections do).
    pub fn verify(&self) -> Result<()> {
        // Hashed and checked in one pass each below; the rest only has a checksum here.
        const ONE_PASS: [SectionKind; 6] = [
            SectionKind::CellIndex,
            SectionKind::Pins,
            SectionKind::Majorant,
            SectionKind::Density,
            SectionKind::SparseDensity,
            SectionKind::Control,
        ];
        for s in &self.sections {
            if ONE_PASS.iter().any(|&k| k as u32 == s.kind) {
                continue;
            }
            let b = &self.bytes[s.offset as usize..(s.offset + s.length) as usize];
            if checksum(b) != s.checksum {
                let kind = SectionKind::from_u32(s.kind)
                    .map(|k| k.name().to_string())
                    .unwrap_or_else(|| format!("kind {}", s.kind));
                return Err(FormatError::SectionChecksum {
                    kind,
                    offset: s.offset,
                });
            }
        }
        self.check_cell_index()?;
        self.check_pins()?;
        self.checked_majorant()?;
        self.checked_density()?;
        self.checked_sparse_density()?;
        self.checked_control()?;
        if self.metadata.is_some() {
            self.metadata().transpose()?;
        }
        Ok(())
    }

    pub fn header(&self) -> &FileHeader {
        &self.header
    }
    pub fn sections(&self) -> &[SectionEntry] {
        &self.sections
    }
    pub fn desc(&self) -> &GridDesc {
        &self.desc
    }
    pub fn shape(&self) -> &GridShape {
        &self.shape
    }
    pub fn tile(&self) -> Option<&TileDesc> {
        self.tile.as_ref()
    }
    /// All stored pins, block after block.
    pub fn pins(&self) -> &'a [PinEntry] {
        self.pins
    }
    pub fn cell_index(&self) -> Option<&'a [u32]> {
        self.cell_index
    }
    pub fn majorant(&self) -> Option<MajorantView<'a>> {
        self.majorant
    }
    pub fn density(&self) -> Option<DensityView<'a>> {
        self.density
    }
    /// The control section (format 1.1), lengths checked; values by `verify`.
    pub fn control(&self) -> Option<ControlView<'a>> {
        self.control
    }
    /// The sparse, bricked density (format 1.1), lengths checked; entries by `verify`.
    pub fn sparse_density(&self) -> Option<SparseDensityView<'a>> {
        self.sparse_density
    }
    pub fn bytes(&self) -> &'a [u8] {
        self.bytes
    }
    /// Decodes the metadata section, if present.
    pub fn metadata(&self) -> Option<Result<Metadata>> {
        self.metadata.map(Metadata::decode)
    }

    /// The pins of one cell (`block_len` entries: direction-major, then pin), or `None` for an
    /// empty cell or one outside the covered slab. A corrupt index entry reads as empty.
    #[inline]
    pub fn cell_pins(&self, cell: [u32; 3]) -> Option<&'a [PinEntry]> {
        let local = self.shape.local_cell(cell)?;
        let block = match self.cell_index {
            None => local,
            Some(index) => {
                let b = *index.get(local as usize)?;
                if b == EMPTY_CELL {
                    return None;
                }
                u64::from(b)
            }
        };
        let n = self.shape.block_len as usize;
        let start = (block as usize).checked_mul(n)?;
        self.pins.get(start..start.checked_add(n)?)
    }

    /// One pin entry; empty cells read as [`PinEntry::EMPTY`].
    #[inline]
    pub fn entry(&self, cell: [u32; 3], direction: u32, pin: u32) -> PinEntry {
        let i = direction as usize * self.shape.pins_per_entry as usize + pin as usize;
        self.cell_pins(cell)
            .and_then(|b| b.get(i).copied())
            .unwrap_or(PinEntry::EMPTY)
    }

    /// Number of covered cells that store no pins.
    pub fn empty_cells(&self) -> u64 {
        self.shape.covered_cells - self.desc.stored_cells
    }
}
