//! The bulk sections a renderer reads whole (majorant, density, sparse density, control),
//! checked on first use: the section's checksum and every value of verify's rules in one
//! pass over its bytes.
//!
//! Each piece of a section is hashed (xxh3, streamed) and its values checked while the piece
//! is in cache, so a checked read costs what the value checks alone cost. A checksum
//! mismatch wins over a bad value (damage explains the value): after the first bad value the
//! rest is only hashed. The pins and the cell index are not read here: a sampler reads them
//! lazily, and only verify reads them whole (in one pass each too).

use bytemuck::Pod;
use xxhash_rust::xxh3::Xxh3;

use crate::control::{ControlView, check_brick};
use crate::error::{FormatError, Result};
use crate::layout::{EMPTY_CELL, SectionKind};
use crate::reader::{DensityView, MajorantView, PinFile};
use crate::sparse::{IndexOrder, SparseDensityView, SparseValues};

/// Bytes hashed before their values are checked: small enough to stay in the L2 cache.
const PIECE_BYTES: usize = 64 << 10;

/// One section's bytes fed in file order to the hasher, with the first bad value kept.
struct Pass {
    hasher: Xxh3,
    fed: u64,
    first_bad: Option<FormatError>,
}

impl Pass {
    fn new() -> Self {
        Self {
            hasher: Xxh3::new(),
            fed: 0,
            first_bad: None,
        }
    }

    /// Bytes without values to check (a section's header).
    fn bytes(&mut self, b: &[u8]) {
        self.hasher.update(b);
        self.fed += b.len() as u64;
    }

    /// `values`, piece by piece: hashed, then `check(first index, piece)` while no bad value
    /// has been found.
    fn values<T: Pod>(&mut self, values: &[T], mut check: impl FnMut(usize, &[T]) -> Result<()>) {
        let per_piece = (PIECE_BYTES / size_of::<T>()).max(1);
        for (k, piece) in values.chunks(per_piece).enumerate() {
            self.bytes(bytemuck::cast_slice(piece));
            if self.first_bad.is_none()
                && let Err(e) = check(k * per_piece, piece)
            {
                self.first_bad = Some(e);
            }
        }
    }

    /// A check after the values (counts), unless a value already failed.
    fn then(&mut self, check: impl FnOnce() -> Result<()>) {
        if self.first_bad.is_none()
            && let Err(e) = check()
        {
            self.first_bad = Some(e);
        }
    }

    /// The checksum against the table's, then the first bad value.
    fn finish(self, file: &PinFile<'_>, kind: SectionKind) -> Result<()> {
        let entry = file
            .sections()
            .iter()
            .find(|s| s.kind == kind as u32)
            .ok_or(FormatError::MissingSection(kind))?;
        // Every view covers its section exactly (parse checks the length equations).
        debug_assert_eq!(self.fed, entry.length, "{} fed", kind.name());
        if self.fed != entry.length || self.hasher.digest() != entry.checksum {
            return Err(FormatError::SectionChecksum {
                kind: kind.name().into(),
                offset: entry.offset,
            });
        }
        self.first_bad.map_or(Ok(()), Err)
    }
}

/// The section's bytes before its arrays. A parsed view has its section and its header in
/// range, so the errors are for a file that breaks that, not a panic.
fn head<'a>(file: &PinFile<'a>, kind: SectionKind, len: usize) -> Result<&'a [u8]> {
    let s = file
        .sections()
        .iter()
        .find(|s| s.kind == kind as u32)
        .ok_or(FormatError::MissingSection(kind))?;
    let start = s.offset as usize;
    start
        .checked_add(len)
        .and_then(|end| file.bytes().get(start..end))
        .ok_or_else(|| FormatError::BadData(kind, "the section's header is out of range".into()))
}

/// The first value that is not finite and `>= 0` in `piece` (starting at `first`), as
/// `what(index, value)`.
fn nonneg<T: Copy>(
    first: usize,
    piece: &[T],
    to_f32: impl Fn(T) -> f32,
    what: impl Fn(usize, f32) -> FormatError,
) -> Result<()> {
    match piece.iter().position(|&v| {
        let v = to_f32(v);
        !(v.is_finite() && v >= 0.0)
    }) {
        Some(i) => Err(what(first + i, to_f32(piece[i]))),
        None => Ok(()),
    }
}

impl<'a> PinFile<'a> {
    /// The pins' checksum and values (verify's rules) in one pass; for verify, since a
    /// sampler reads the pins lazily.
    pub(crate) fn check_pins(&self) -> Result<()> {
        let kind = SectionKind::Pins;
        if !self.sections().iter().any(|s| s.kind == kind as u32) {
            return Ok(());
        }
        let mut pass = Pass::new();
        pass.values(self.pins(), |first, piece| {
            match piece.iter().position(|p| {
                !(p.t_min >= 0.0 && p.t_min <= 1.0) || (p.t_min == 1.0 && p.mask != 0)
            }) {
                Some(i) => Err(FormatError::BadData(
                    kind,
                    format!(
                        "pin {} has t_min {} and mask {:#010x}",
                        first + i,
                        piece[i].t_min,
                        piece[i].mask
                    ),
                )),
                None => Ok(()),
            }
        });
        pass.finish(self, kind)
    }

    /// The cell index's checksum and canonical form (the n-th non-empty cell in cell order
    /// owns block n, `stored_cells` of them) in one pass; for verify.
    pub(crate) fn check_cell_index(&self) -> Result<()> {
        let Some(index) = self.cell_index() else {
            return Ok(());
        };
        let kind = SectionKind::CellIndex;
        let mut pass = Pass::new();
        let mut next = 0u64;
        pass.values(index, |first, piece| {
            for (k, &block) in piece.iter().enumerate() {
                if block == EMPTY_CELL {
                    continue;
                }
                if u64::from(block) != next {
                    return Err(FormatError::BadData(
                        kind,
                        format!(
                            "cell {} points at block {block}, expected {next}",
                            first + k
                        ),
                    ));
                }
                next += 1;
            }
            Ok(())
        });
        let stored = self.desc().stored_cells;
        pass.then(|| {
            if next != stored {
                return Err(FormatError::BadData(
                    kind,
                    format!("{next} non-empty cells but {stored} stored"),
                ));
            }
            Ok(())
        });
        pass.finish(self, kind)
    }

    /// The majorant section with its checksum and every value checked (finite, `>= 0`), in
    /// one pass; `None` if the file has none.
    pub fn checked_majorant(&self) -> Result<Option<MajorantView<'a>>> {
        let Some(m) = self.majorant() else {
            return Ok(None);
        };
        let kind = SectionKind::Majorant;
        let mut pass = Pass::new();
        pass.bytes(head(self, kind, 16)?);
        pass.values(m.values, |first, piece| {
            nonneg(
                first,
                piece,
                |v| v,
                |i, v| FormatError::BadData(kind, format!("brick {i} has majorant {v}")),
            )
        });
        pass.finish(self, kind)?;
        Ok(Some(m))
    }

    /// The dense density section with its checksum and every voxel checked (finite, `>= 0`),
    /// in one pass; `None` if the file has none.
    pub fn checked_density(&self) -> Result<Option<DensityView<'a>>> {
        let Some(d) = self.density() else {
            return Ok(None);
        };
        let kind = SectionKind::Density;
        let mut pass = Pass::new();
        pass.bytes(head(self, kind, 16)?);
        pass.values(d.values, |first, piece| {
            nonneg(first, piece, half::f16::to_f32, |i, v| {
                FormatError::BadData(kind, format!("voxel {i} has density {v}"))
            })
        });
        pass.finish(self, kind)?;
        Ok(Some(d))
    }

    /// The sparse density section (format 1.1) with its checksum, its index's canonical
    /// order and every stored voxel (finite, `>= 0`) checked, in one pass; `None` if the
    /// file has none.
    pub fn checked_sparse_density(&self) -> Result<Option<SparseDensityView<'a>>> {
        let Some(s) = self.sparse_density() else {
            return Ok(None);
        };
        let kind = SectionKind::SparseDensity;
        let mut pass = Pass::new();
        pass.bytes(head(
            self,
            kind,
            size_of::<crate::layout::SparseDensityHeader>(),
        )?);
        let mut order = IndexOrder::new();
        pass.values(s.index, |_, piece| order.feed(&s.header, piece));
        pass.then(|| order.finish(&s.header));
        let bad = |i: usize, v: f32| {
            FormatError::BadData(kind, format!("stored voxel {i} has density {v}"))
        };
        match s.values {
            SparseValues::F16(v) => pass.values(v, |first, piece| {
                nonneg(first, piece, half::f16::to_f32, bad)
            }),
            SparseValues::F32(v) => pass.values(v, |first, piece| nonneg(first, piece, |x| x, bad)),
        }
        pass.finish(self, kind)?;
        Ok(Some(s))
    }

    /// The control section (format 1.1) with its checksum and every brick's rules checked
    /// (docs/format.md section 5.8) in one pass: the control and residual arrays are hashed,
    /// and each piece of the majorant array is hashed and checked with the same bricks of
    /// the other two. `None` if the file has none.
    pub fn checked_control(&self) -> Result<Option<ControlView<'a>>> {
        let Some(c) = self.control() else {
            return Ok(None);
        };
        let kind = SectionKind::Control;
        let mut pass = Pass::new();
        pass.bytes(head(self, kind, size_of::<crate::layout::ControlHeader>())?);
        pass.values(c.control, |_, _| Ok(()));
        pass.values(c.residual, |_, _| Ok(()));
        pass.values(c.majorant, |first, piece| {
            piece.iter().enumerate().try_for_each(|(k, &mx)| {
                let i = first + k;
                check_brick(i, c.control[i], c.residual[i], mx)
            })
        });
        pass.finish(self, kind)?;
        Ok(Some(c))
    }
}

#[cfg(all(test, feature = "writer"))]
mod tests {
    use half::f16;

    use crate::layout::{
        DENSITY_F16, DensityHeader, EMPTY_BRICK, MajorantHeader, SparseDensityHeader,
    };
    use crate::{
        Directions, OwnedControl, OwnedPinGrid, OwnedSparseDensity, OwnedSparseValues, PinEntry,
        PinFile, SectionKind, grid_desc,
    };

    /// A grid with all four bulk sections, each larger than one piece of the pass (so that
    /// the piece boundaries are exercised), all valid.
    fn grid() -> Vec<u8> {
        let n = 40_000usize;
        let dims = [200u32, 200, 1];
        let bricks = [100u32, 100, 1];
        let sparse_index: Vec<u32> = (0..(n / 4) as u32)
            .map(|i| {
                if i % 3 == 0 {
                    EMPTY_BRICK
                } else {
                    i - i / 3 - 1
                }
            })
            .collect();
        let stored = sparse_index.iter().filter(|&&s| s != EMPTY_BRICK).count();
        let owned = OwnedPinGrid {
            desc: grid_desc([1, 1, 1], Directions::Octahedral { n: 1 }, 1, 1),
            tile: None,
            cell_index: None,
            pins: vec![PinEntry::EMPTY; 1],
            majorant: Some((
                MajorantHeader {
                    dims: bricks,
                    reserved: 0,
                },
                (0..bricks[0] * bricks[1]).map(|i| i as f32).collect(),
            )),
            density: Some((
                DensityHeader {
                    dims,
                    encoding: DENSITY_F16,
                },
                (0..n).map(|i| f16::from_f32((i % 7) as f32)).collect(),
            )),
            sparse_density: Some(OwnedSparseDensity {
                header: SparseDensityHeader {
                    dims,
                    encoding: DENSITY_F16,
                    brick: 2,
                    brick_count: stored as u32,
                    reserved: [0; 2],
                },
                index: sparse_index,
                values: OwnedSparseValues::F16(vec![f16::from_f32(0.5); stored * 8]),
            }),
            control: Some(OwnedControl {
                dims: bricks,
                control: vec![1.0; 10_000],
                residual: vec![0.5; 10_000],
                majorant: vec![2.0; 10_000],
            }),
            metadata: None,
        };
        owned.to_bytes().unwrap()
    }

    fn section_range(bytes: &[u8], kind: SectionKind) -> std::ops::Range<usize> {
        let file = PinFile::parse(bytes).unwrap();
        let s = file
            .sections()
            .iter()
            .find(|s| s.kind == kind as u32)
            .unwrap();
        s.offset as usize..(s.offset + s.length) as usize
    }

    fn checked(bytes: &[u8], kind: SectionKind) -> crate::Result<()> {
        let file = PinFile::parse(bytes).unwrap();
        match kind {
            SectionKind::Majorant => file.checked_majorant().map(|_| ()),
            SectionKind::Density => file.checked_density().map(|_| ()),
            SectionKind::SparseDensity => file.checked_sparse_density().map(|_| ()),
            SectionKind::Control => file.checked_control().map(|_| ()),
            _ => unreachable!(),
        }
    }

    const BULK: [SectionKind; 4] = [
        SectionKind::Majorant,
        SectionKind::Density,
        SectionKind::SparseDensity,
        SectionKind::Control,
    ];

    #[test]
    fn valid_sections_pass_and_match_the_whole_checksum() {
        let bytes = grid();
        PinFile::parse(&bytes).unwrap().verify().unwrap();
        for kind in BULK {
            checked(&bytes, kind).unwrap();
        }
    }

    /// A value changed to another valid value (in range): the values pass, the checksum does
    /// not, and the error names the section.
    #[test]
    fn in_range_damage_fails_the_checksum_and_names_the_section() {
        let clean = grid();
        for kind in BULK {
            let r = section_range(&clean, kind);
            // Early in the first array, and the last byte of the last piece (for control
            // the majorant array's last brick: 2.0 -> 8.0, still above its control).
            for at in [r.start + 40, r.end - 1] {
                let mut bytes = clean.clone();
                bytes[at] ^= 0x01;
                let e = checked(&bytes, kind).unwrap_err().to_string();
                assert!(
                    e.contains("checksum mismatch") && e.contains(&format!("'{}'", kind.name())),
                    "{}: {e}",
                    kind.name()
                );
                // Verify agrees.
                let v = PinFile::parse(&bytes).unwrap().verify().unwrap_err();
                assert!(v.to_string().contains(kind.name()), "{v}");
            }
        }
    }

    /// `bytes` with the value at `at` (an f32) set to `v` and every checksum recomputed: a
    /// bad value under a valid checksum (a writer's bug, or a resealed file).
    fn resealed(bytes: &[u8], at: usize, v: f32) -> Vec<u8> {
        let file = PinFile::parse(bytes).unwrap();
        let (table, entry_size) = (
            file.header().table_offset as usize,
            file.header().section_entry_size as usize,
        );
        let sections = file.sections().to_vec();
        let mut out = bytes.to_vec();
        out[at..at + 4].copy_from_slice(&v.to_le_bytes());
        for (i, s) in sections.iter().enumerate() {
            let sum = crate::checksum(&out[s.offset as usize..(s.offset + s.length) as usize]);
            let e = table + i * entry_size + 24;
            out[e..e + 8].copy_from_slice(&sum.to_le_bytes());
        }
        let sum = crate::checksum(&out[table..table + sections.len() * entry_size]);
        out[48..56].copy_from_slice(&sum.to_le_bytes());
        let sum = crate::checksum(&out[..56]);
        out[56..64].copy_from_slice(&sum.to_le_bytes());
        out
    }

    /// A bad value under a valid checksum is named as verify names it.
    #[test]
    fn bad_values_under_a_valid_checksum_are_named() {
        let clean = grid();
        let cases = [
            (
                SectionKind::Majorant,
                16 + 4,
                f32::NAN,
                "brick 1 has majorant NaN",
            ),
            // Control of brick 2 above its majorant (2.0).
            (
                SectionKind::Control,
                16 + 8,
                3.0,
                "brick 2 has control 3 above its majorant 2",
            ),
            // Residual of brick 0 set to 0 where the majorant is 2.
            (
                SectionKind::Control,
                16 + 40_000,
                0.0,
                "brick 0 has residual majorant 0",
            ),
            // Index entry 2 (slot 1) set to slot 0: a slot used twice.
            (
                SectionKind::SparseDensity,
                32 + 8,
                0.0,
                "brick 2 points at slot 0, expected 1",
            ),
        ];
        for (kind, at, v, want) in cases {
            let r = section_range(&clean, kind);
            let bytes = resealed(&clean, r.start + at, v);
            let e = checked(&bytes, kind).unwrap_err().to_string();
            let v = PinFile::parse(&bytes)
                .unwrap()
                .verify()
                .unwrap_err()
                .to_string();
            assert!(e.contains(want), "{}: {e}", kind.name());
            assert_eq!(e, v, "checked read and verify name the same value");
        }
        let owned_none = OwnedPinGrid {
            desc: grid_desc([1, 1, 1], Directions::Octahedral { n: 1 }, 1, 1),
            tile: None,
            cell_index: None,
            pins: vec![PinEntry::EMPTY; 1],
            majorant: None,
            density: None,
            sparse_density: None,
            control: None,
            metadata: None,
        };
        let bytes = owned_none.to_bytes().unwrap();
        let file = PinFile::parse(&bytes).unwrap();
        assert!(file.checked_majorant().unwrap().is_none());
        assert!(file.checked_control().unwrap().is_none());
        assert!(file.checked_density().unwrap().is_none());
        assert!(file.checked_sparse_density().unwrap().is_none());
    }
}
