//! The sparse, bricked density section (kind 8, format 1.1): its zero-copy view, the length
//! checks a parse makes before any of its counts is used, and the per-entry checks of verify.
//!
//! Kept apart from the dense density of `reader.rs` so that the section can change alone.

use bytemuck::Pod;

use crate::error::{FormatError, Result};
use crate::layout::{
    DENSITY_F16, DENSITY_F32, EMPTY_BRICK, MAX_BRICK, SectionKind, SparseDensityHeader,
};

const KIND: SectionKind = SectionKind::SparseDensity;

/// The stored bricks' voxels, in the section's encoding.
#[derive(Clone, Copy, Debug)]
pub enum SparseValues<'a> {
    F16(&'a [half::f16]),
    F32(&'a [f32]),
}

impl SparseValues<'_> {
    pub fn len(&self) -> usize {
        match self {
            SparseValues::F16(v) => v.len(),
            SparseValues::F32(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Value `i` widened to f32 (exact for both encodings), `None` past the end.
    #[inline]
    pub fn get(&self, i: usize) -> Option<f32> {
        match self {
            SparseValues::F16(v) => v.get(i).map(|h| h.to_f32()),
            SparseValues::F32(v) => v.get(i).copied(),
        }
    }

    /// Bytes per voxel.
    pub fn elem_bytes(&self) -> usize {
        match self {
            SparseValues::F16(_) => 2,
            SparseValues::F32(_) => 4,
        }
    }

    /// The voxels as raw bytes (for upload).
    pub fn bytes(&self) -> &[u8] {
        match self {
            SparseValues::F16(v) => bytemuck::cast_slice(v),
            SparseValues::F32(v) => bytemuck::cast_slice(v),
        }
    }
}

/// A view of the sparse density section borrowing the file's bytes.
///
/// After [`SparseDensityView::parse`] every length agrees with the section's size; the index
/// entries themselves are checked by [`SparseDensityView::check_entries`] (linear, so not
/// part of an O(1) parse), and [`SparseDensityView::get`] is bounds-checked regardless.
#[derive(Clone, Copy, Debug)]
pub struct SparseDensityView<'a> {
    pub header: SparseDensityHeader,
    /// Bricks along x, y, z: `ceil(dims / brick)`.
    pub brick_dims: [u32; 3],
    /// One entry per brick, x fastest: a slot `< brick_count` or [`EMPTY_BRICK`].
    pub index: &'a [u32],
    pub values: SparseValues<'a>,
}

fn bad(problem: impl Into<String>) -> FormatError {
    FormatError::BadData(KIND, problem.into())
}

fn cast<T: Pod>(bytes: &[u8]) -> Result<&[T]> {
    bytemuck::try_cast_slice(bytes).map_err(|e| bad(format!("{e:?}")))
}

/// Bricks per axis for `dims` voxels in bricks of `brick`.
pub fn brick_dims(dims: [u32; 3], brick: u32) -> [u32; 3] {
    dims.map(|d| d.div_ceil(brick))
}

/// The canonical-order check of an index fed in pieces, in brick order: every entry is
/// [`EMPTY_BRICK`] or the next slot, and the slots used are exactly the header's
/// `brick_count`. One implementation for the whole index (verify) and for the pieces a
/// checked read hashes ([`crate::PinFile::checked_sparse_density`]).
pub(crate) struct IndexOrder {
    next: u64,
    bricks_seen: usize,
}

impl IndexOrder {
    pub(crate) fn new() -> Self {
        Self {
            next: 0,
            bricks_seen: 0,
        }
    }

    /// The next `entries` of the index.
    pub(crate) fn feed(&mut self, header: &SparseDensityHeader, entries: &[u32]) -> Result<()> {
        for (k, &slot) in entries.iter().enumerate() {
            if slot == EMPTY_BRICK {
                continue;
            }
            if u64::from(slot) != self.next {
                return Err(bad(format!(
                    "brick {} points at slot {slot}, expected {} (of {})",
                    self.bricks_seen + k,
                    self.next,
                    header.brick_count
                )));
            }
            self.next += 1;
        }
        self.bricks_seen += entries.len();
        Ok(())
    }

    /// After the last entry: the slots used are the header's count.
    pub(crate) fn finish(&self, header: &SparseDensityHeader) -> Result<()> {
        if self.next != u64::from(header.brick_count) {
            return Err(bad(format!(
                "{} non-empty bricks but {} stored",
                self.next, header.brick_count
            )));
        }
        Ok(())
    }
}

/// Every entry of `index` is [`EMPTY_BRICK`] or the next slot, and the slots used are
/// exactly the header's `brick_count`.
fn check_index_entries(header: &SparseDensityHeader, index: &[u32]) -> Result<()> {
    let mut order = IndexOrder::new();
    order.feed(header, index)?;
    order.finish(header)
}

impl<'a> SparseDensityView<'a> {
    /// Checks the header and every length against the section's size `b.len()` (which the
    /// reader has checked against the file's), then views the index and the bricks in place.
    pub fn parse(b: &'a [u8]) -> Result<Self> {
        let head_len = size_of::<SparseDensityHeader>();
        if b.len() < head_len {
            return Err(bad(format!(
                "section is {} bytes but its header needs {head_len}",
                b.len()
            )));
        }
        let header: SparseDensityHeader = bytemuck::pod_read_unaligned(&b[..head_len]);
        let elem: u64 = match header.encoding {
            DENSITY_F16 => 2,
            DENSITY_F32 => 4,
            e => return Err(bad(format!("unknown encoding {e}"))),
        };
        let bricks = Self::brick_count_of(&header)?;
        let brick_voxels = u64::from(header.brick).pow(3);
        let index_bytes = bricks.checked_mul(4).ok_or_else(|| bad("size overflows"))?;
        let want = index_bytes
            .checked_add(head_len as u64)
            .and_then(|x| {
                u64::from(header.brick_count)
                    .checked_mul(brick_voxels * elem)
                    .and_then(|v| x.checked_add(v))
            })
            .ok_or_else(|| bad("size overflows"))?;
        if b.len() as u64 != want {
            return Err(bad(format!(
                "section is {} bytes but {bricks} index entries and {} bricks of {}^3 need {want}",
                b.len(),
                header.brick_count,
                header.brick
            )));
        }
        let index_end = head_len + index_bytes as usize;
        let index = cast::<u32>(&b[head_len..index_end])?;
        let body = &b[index_end..];
        let values = match header.encoding {
            DENSITY_F16 => SparseValues::F16(cast::<half::f16>(body)?),
            _ => SparseValues::F32(cast::<f32>(body)?),
        };
        Self::from_parts(header, index, values)
    }

    /// Bricks in the brick grid of a header whose dims and brick edge are valid.
    fn brick_count_of(header: &SparseDensityHeader) -> Result<u64> {
        if header.dims.contains(&0) {
            return Err(bad("zero dimension"));
        }
        if !(header.brick.is_power_of_two() && header.brick <= MAX_BRICK) {
            return Err(bad(format!(
                "brick edge {} is not a power of two in 1..={MAX_BRICK}",
                header.brick
            )));
        }
        let bdims = brick_dims(header.dims, header.brick);
        let bricks = bdims
            .iter()
            .try_fold(1u64, |acc, &d| acc.checked_mul(u64::from(d)))
            .ok_or_else(|| bad("brick grid size overflows"))?;
        // Canonical files use each slot once, so no more slots than bricks.
        if u64::from(header.brick_count) > bricks {
            return Err(bad(format!(
                "{} stored bricks but the brick grid {bdims:?} has {bricks}",
                header.brick_count
            )));
        }
        Ok(bricks)
    }

    /// A view over separate parts (an owned grid's), with the same checks as a parse.
    pub fn from_parts(
        header: SparseDensityHeader,
        index: &'a [u32],
        values: SparseValues<'a>,
    ) -> Result<Self> {
        let bricks = Self::brick_count_of(&header)?;
        let enc_ok = matches!(
            (header.encoding, &values),
            (DENSITY_F16, SparseValues::F16(_)) | (DENSITY_F32, SparseValues::F32(_))
        );
        if !enc_ok {
            return Err(bad(format!("unknown encoding {}", header.encoding)));
        }
        let want = u64::from(header.brick_count) * u64::from(header.brick).pow(3);
        if index.len() as u64 != bricks || values.len() as u64 != want {
            return Err(bad(format!(
                "{} index entries and {} voxels, the header needs {bricks} and {want}",
                index.len(),
                values.len()
            )));
        }
        let bdims = brick_dims(header.dims, header.brick);
        Ok(Self {
            header,
            brick_dims: bdims,
            index,
            values,
        })
    }

    /// Every index entry is [`EMPTY_BRICK`] or the next slot in brick order (the canonical
    /// form: no slot twice, none out of range, all used); linear in the index.
    pub fn check_entries(&self) -> Result<()> {
        check_index_entries(&self.header, self.index)
    }

    /// The checks of [`SparseDensityView::from_parts`] and
    /// [`SparseDensityView::check_entries`] on a header and its index alone, for a writer
    /// whose bricks are streamed into the section rather than held (their count is then the
    /// header's `brick_count`, which the copy checks).
    pub fn check_index(header: &SparseDensityHeader, index: &[u32]) -> Result<()> {
        let bricks = Self::brick_count_of(header)?;
        if !matches!(header.encoding, DENSITY_F16 | DENSITY_F32) {
            return Err(bad(format!("unknown encoding {}", header.encoding)));
        }
        if index.len() as u64 != bricks {
            return Err(bad(format!(
                "{} index entries, the header needs {bricks}",
                index.len()
            )));
        }
        check_index_entries(header, index)
    }

    /// The first stored voxel that is not finite and `>= 0`: (value index, value).
    pub fn first_bad_value(&self) -> Option<(usize, f32)> {
        let ok = |v: f32| v.is_finite() && v >= 0.0;
        match self.values {
            SparseValues::F16(v) => v
                .iter()
                .position(|h| !ok(h.to_f32()))
                .map(|i| (i, v[i].to_f32())),
            SparseValues::F32(v) => v.iter().position(|x| !ok(*x)).map(|i| (i, v[i])),
        }
    }

    /// Voxels per brick.
    pub fn brick_voxels(&self) -> usize {
        (self.header.brick as usize).pow(3)
    }

    /// Voxel `(x, y, z)`: its value, 0 in an empty brick, `None` outside the voxel grid or
    /// where an (unchecked) index entry points past the stored bricks.
    #[inline]
    pub fn get(&self, voxel: [u32; 3]) -> Option<f32> {
        let h = &self.header;
        if (0..3).any(|a| voxel[a] >= h.dims[a]) {
            return None;
        }
        let b = h.brick;
        let [bx, by, bz] = voxel.map(|v| (v / b) as usize);
        let [nx, ny, _] = self.brick_dims.map(|v| v as usize);
        let slot = *self.index.get(bx + nx * (by + ny * bz))?;
        if slot == EMPTY_BRICK {
            return Some(0.0);
        }
        let [lx, ly, lz] = voxel.map(|v| (v % b) as usize);
        let b = b as usize;
        let at = (slot as usize)
            .checked_mul(self.brick_voxels())?
            .checked_add(lx + b * (ly + b * lz))?;
        self.values.get(at)
    }
}

/// The stored voxels of an owned sparse density.
#[derive(Clone, Debug, PartialEq)]
pub enum OwnedSparseValues {
    F16(Vec<half::f16>),
    F32(Vec<f32>),
}

/// A sparse density in memory: what a baker fills in and what tests compare.
#[derive(Clone, Debug, PartialEq)]
pub struct OwnedSparseDensity {
    pub header: SparseDensityHeader,
    pub index: Vec<u32>,
    pub values: OwnedSparseValues,
}

impl OwnedSparseDensity {
    /// A checked view (lengths and every index entry).
    pub fn view(&self) -> Result<SparseDensityView<'_>> {
        let values = match &self.values {
            OwnedSparseValues::F16(v) => SparseValues::F16(v),
            OwnedSparseValues::F32(v) => SparseValues::F32(v),
        };
        let v = SparseDensityView::from_parts(self.header, &self.index, values)?;
        v.check_entries()?;
        Ok(v)
    }

    /// Copies a file's section.
    pub fn from_view(v: &SparseDensityView<'_>) -> Self {
        Self {
            header: v.header,
            index: v.index.to_vec(),
            values: match v.values {
                SparseValues::F16(x) => OwnedSparseValues::F16(x.to_vec()),
                SparseValues::F32(x) => OwnedSparseValues::F32(x.to_vec()),
            },
        }
    }

    /// The section's bytes after its header: index then bricks.
    pub fn body_parts(&self) -> [&[u8]; 2] {
        let v: &[u8] = match &self.values {
            OwnedSparseValues::F16(x) => bytemuck::cast_slice(x),
            OwnedSparseValues::F32(x) => bytemuck::cast_slice(x),
        };
        [bytemuck::cast_slice(&self.index), v]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn section(h: SparseDensityHeader, index: &[u32], values: &[f32]) -> Vec<u8> {
        let mut b = bytemuck::bytes_of(&h).to_vec();
        b.extend_from_slice(bytemuck::cast_slice(index));
        b.extend_from_slice(bytemuck::cast_slice(values));
        b
    }

    fn head(dims: [u32; 3], brick: u32, brick_count: u32) -> SparseDensityHeader {
        SparseDensityHeader {
            dims,
            encoding: DENSITY_F32,
            brick,
            brick_count,
            reserved: [0; 2],
        }
    }

    #[test]
    fn lookup_goes_through_the_index() {
        // 3x1x1 voxels in bricks of 2: bricks (0) empty... (1) stored.
        let mut vals = vec![0.0; 8];
        vals[0] = 5.0; // voxel (2,0,0) is (0,0,0) of brick 1
        let b = section(head([3, 1, 1], 2, 1), &[EMPTY_BRICK, 0], &vals);
        let v = SparseDensityView::parse(&b).unwrap();
        v.check_entries().unwrap();
        assert_eq!(v.brick_dims, [2, 1, 1]);
        assert_eq!(v.get([0, 0, 0]), Some(0.0));
        assert_eq!(v.get([2, 0, 0]), Some(5.0));
        assert_eq!(v.get([3, 0, 0]), None);
    }

    #[test]
    fn bad_lengths_and_entries_are_named() {
        let vals = vec![1.0; 8];
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (vec![0; 12], "header needs"),
            (section(head([0, 1, 1], 2, 0), &[], &[]), "zero dimension"),
            (section(head([2, 2, 2], 3, 1), &[0], &vals), "power of two"),
            (section(head([2, 2, 2], 2, 2), &[0], &vals), "stored bricks"),
            (section(head([2, 2, 2], 2, 1), &[0], &vals[..7]), "need"),
            (
                section(head([u32::MAX, u32::MAX, u32::MAX], 1, 1), &[0], &vals),
                "overflows",
            ),
        ];
        for (b, want) in cases {
            let e = SparseDensityView::parse(&b).unwrap_err().to_string();
            assert!(e.contains(want) && e.contains("sparse-density"), "{e}");
        }
        let mut h = head([2, 2, 2], 2, 1);
        h.encoding = 7;
        let e = SparseDensityView::parse(&section(h, &[0], &vals)).unwrap_err();
        assert!(e.to_string().contains("unknown encoding 7"));
        // Parses (lengths agree) but the entry points past the one stored brick.
        let b = section(head([2, 2, 2], 2, 1), &[3], &vals);
        let v = SparseDensityView::parse(&b).unwrap();
        assert!(
            v.check_entries()
                .unwrap_err()
                .to_string()
                .contains("slot 3")
        );
        assert_eq!(v.get([0, 0, 0]), None);
    }
}
