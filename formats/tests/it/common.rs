//! Helpers shared by the integration tests: deterministic grid builders and byte patchers that
//! change one field of a file and recompute exactly the checksums that cover it, so that a lie
//! gets past the checksums and reaches the structural checks.
#![allow(dead_code)]

use std::ops::Range;

use pin_format::layout::*;
use pin_format::*;

/// Header bytes covered by `FileHeader::header_checksum`.
pub const HEADER_CHECKSUM_SPAN: usize = 56;
pub const HEADER_LEN: usize = size_of::<FileHeader>();
pub const ENTRY_LEN: usize = size_of::<SectionEntry>();

/// SplitMix64: tiny, deterministic, good enough to fill test grids.
#[derive(Clone, Debug)]
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    pub fn next_u32(&mut self) -> u32 {
        (self.next_u64() >> 32) as u32
    }
    /// Uniform in `[0, 1)`.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in `0..n` (`n > 0`).
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n
    }
}

/// A valid pin: t_min in [0, 1] with exact 0 and 1 common; mask 0 whenever t_min is 1.
pub fn random_pin(rng: &mut Rng) -> PinEntry {
    let t_min = match rng.below(8) {
        0 => 0.0,
        1 => 1.0,
        _ => rng.unit() as f32,
    };
    let mask = if t_min == 1.0 { 0 } else { rng.next_u32() };
    PinEntry { mask, t_min }
}

/// Everything that decides the shape of a test grid; the contents come from `seed`.
#[derive(Clone, Debug)]
pub struct GridParams {
    pub dims: [u32; 3],
    pub directions: Directions,
    pub pins_per_entry: u32,
    /// `Some(p)`: sparse with a cell index, each covered cell empty with probability `p`.
    pub sparse_empty: Option<f64>,
    /// `(tile_index, tile_count, z_begin, z_end)`.
    pub tile: Option<(u32, u32, u32, u32)>,
    pub majorant: Option<[u32; 3]>,
    pub density: Option<[u32; 3]>,
    pub metadata: Option<Metadata>,
    pub seed: u64,
}

/// Builds a valid grid: canonical block numbering (the n-th non-empty covered cell in x-fastest
/// order owns block n), random bake parameters, random bulk values.
pub fn build_grid(p: &GridParams) -> OwnedPinGrid {
    let mut rng = Rng(p.seed);
    let tile = p
        .tile
        .map(|(tile_index, tile_count, z_begin, z_end)| TileDesc {
            tile_index,
            tile_count,
            z_begin,
            z_end,
        });
    let layers = tile.map_or(p.dims[2], |t| t.z_end - t.z_begin);
    let covered = p.dims[0] as usize * p.dims[1] as usize * layers as usize;
    let block_len = p.directions.count() as usize * p.pins_per_entry as usize;
    let (cell_index, stored) = match p.sparse_empty {
        None => (None, covered),
        Some(prob) => {
            let mut next = 0u32;
            let ix: Vec<u32> = (0..covered)
                .map(|_| {
                    if rng.unit() < prob {
                        EMPTY_CELL
                    } else {
                        next += 1;
                        next - 1
                    }
                })
                .collect();
            (Some(ix), next as usize)
        }
    };
    let pins = (0..stored * block_len)
        .map(|_| random_pin(&mut rng))
        .collect();
    let mut desc = grid_desc(p.dims, p.directions, p.pins_per_entry, stored as u64);
    for i in 0..3 {
        desc.box_min[i] = rng.unit() * 20.0 - 10.0;
        desc.box_max[i] = desc.box_min[i] + 0.001 + rng.unit() * 5.0;
        desc.source_box_min[i] = desc.box_min[i] - rng.unit();
        desc.source_box_max[i] = desc.box_max[i] + rng.unit();
    }
    for v in &mut desc.local_to_world {
        *v = rng.unit() * 4.0 - 2.0;
    }
    desc.step_size = rng.unit() * 0.1;
    desc.density_scale = rng.unit() * 10.0;
    desc.seed = rng.next_u64();
    desc.flags = rng.next_u32() & (GRID_FLAG_CROPPED | GRID_FLAG_JITTERED_PINS);
    let majorant = p.majorant.map(|dims| {
        let n = dims.iter().product::<u32>() as usize;
        let values = (0..n)
            .map(|_| match rng.below(5) {
                0 => 0.0,
                _ => (rng.unit() * 1000.0) as f32,
            })
            .collect();
        (MajorantHeader { dims, reserved: 0 }, values)
    });
    let density = p.density.map(|dims| {
        let n = dims.iter().product::<u32>() as usize;
        let values = (0..n)
            .map(|_| match rng.below(4) {
                0 => half::f16::ZERO,
                _ => half::f16::from_f64(rng.unit() * 100.0),
            })
            .collect();
        (
            DensityHeader {
                dims,
                encoding: DENSITY_F16,
            },
            values,
        )
    });
    OwnedPinGrid {
        desc,
        tile,
        cell_index,
        pins,
        majorant,
        density,
        sparse_density: None,
        control: None,
        metadata: p.metadata.clone(),
    }
}

pub fn sample_metadata() -> Metadata {
    Metadata {
        tool: "pinbake".into(),
        tool_version: "0.1.0".into(),
        source_name: "smoke.vdb".into(),
        source_hash: "0123456789abcdef".into(),
        source_description: "density float 64x64x64".into(),
        seed: 42,
        step_size: 0.01,
        density_scale: 1.5,
        bake_unix_time: Some(1_700_000_000),
        extra: vec![("channel".into(), "density".into())],
    }
}

/// A small grid with every section kind: sparse, tiled, majorant, density, metadata.
pub fn full_grid() -> OwnedPinGrid {
    build_grid(&GridParams {
        dims: [3, 2, 4],
        directions: Directions::Polar {
            n_phi: 4,
            n_theta: 2,
        },
        pins_per_entry: 2,
        sparse_empty: Some(0.4),
        tile: Some((1, 2, 2, 4)),
        majorant: Some([2, 2, 1]),
        density: Some([3, 3, 2]),
        metadata: Some(sample_metadata()),
        seed: 7,
    })
}

/// A dense, untiled grid with majorant and no optional extras.
pub fn dense_grid() -> OwnedPinGrid {
    build_grid(&GridParams {
        dims: [2, 3, 2],
        directions: Directions::Octahedral { n: 2 },
        pins_per_entry: 1,
        sparse_empty: None,
        tile: None,
        majorant: Some([1, 1, 1]),
        density: None,
        metadata: None,
        seed: 11,
    })
}

/// The golden file: 2x1x1 cells, octahedral n = 1, one pin per entry, sparse with cell 1
/// empty, a 1x1x1 majorant, no density, fixed metadata.
pub fn golden_grid() -> OwnedPinGrid {
    let mut desc = grid_desc([2, 1, 1], Directions::Octahedral { n: 1 }, 1, 1);
    desc.box_min = [-1.0, -0.5, 0.0];
    desc.box_max = [1.0, 0.5, 1.0];
    desc.step_size = 0.125;
    desc.density_scale = 2.0;
    desc.seed = 0x0123_4567_89AB_CDEF;
    desc.flags = GRID_FLAG_CROPPED;
    desc.source_box_min = [-2.0, -1.0, 0.0];
    desc.source_box_max = [2.0, 1.0, 2.0];
    OwnedPinGrid {
        desc,
        tile: None,
        cell_index: Some(vec![0, EMPTY_CELL]),
        pins: vec![PinEntry {
            mask: 0x8000_0001,
            t_min: 0.25,
        }],
        majorant: Some((
            MajorantHeader {
                dims: [1, 1, 1],
                reserved: 0,
            },
            vec![3.5],
        )),
        density: None,
        sparse_density: None,
        control: None,
        metadata: Some(Metadata {
            tool: "pinbake".into(),
            tool_version: "0.1.0".into(),
            source_name: "golden".into(),
            source_hash: String::new(),
            source_description: "hand-made".into(),
            seed: 1,
            step_size: 0.125,
            density_scale: 2.0,
            bake_unix_time: None,
            extra: vec![("k".into(), "v".into())],
        }),
    }
}

// ---------------------------------------------------------------------------------------------
// Byte patchers.

pub fn header(b: &[u8]) -> FileHeader {
    bytemuck::pod_read_unaligned(&b[..HEADER_LEN])
}

pub fn header_checksum_of(h: &FileHeader) -> u64 {
    checksum(&bytemuck::bytes_of(h)[..HEADER_CHECKSUM_SPAN])
}

/// Writes `h` at offset 0 with its checksum recomputed.
pub fn write_header(b: &mut [u8], mut h: FileHeader) {
    h.header_checksum = header_checksum_of(&h);
    b[..HEADER_LEN].copy_from_slice(bytemuck::bytes_of(&h));
}

/// Changes header fields and fixes the header checksum.
pub fn patch_header(b: &mut [u8], f: impl FnOnce(&mut FileHeader)) {
    let mut h = header(b);
    f(&mut h);
    write_header(b, h);
}

pub fn table_range(b: &[u8]) -> Range<usize> {
    let h = header(b);
    let start = h.table_offset as usize;
    start..start + h.section_count as usize * h.section_entry_size as usize
}

pub fn table(b: &[u8]) -> Vec<SectionEntry> {
    b[table_range(b)]
        .chunks_exact(ENTRY_LEN)
        .map(bytemuck::pod_read_unaligned)
        .collect()
}

/// Recomputes the table checksum (over the table bytes the header names) and the header
/// checksum.
pub fn fix_table_checksum(b: &mut [u8]) {
    let sum = checksum(&b[table_range(b)]);
    patch_header(b, |h| h.table_checksum = sum);
}

/// Changes table entries (same count) and fixes the table and header checksums.
pub fn patch_table(b: &mut [u8], f: impl FnOnce(&mut Vec<SectionEntry>)) {
    let mut t = table(b);
    let n = t.len();
    f(&mut t);
    assert_eq!(t.len(), n, "patch_table keeps the entry count");
    let r = table_range(b);
    b[r].copy_from_slice(bytemuck::cast_slice(&t));
    fix_table_checksum(b);
}

pub fn section_position(b: &[u8], kind: SectionKind) -> usize {
    table(b)
        .iter()
        .position(|s| s.kind == kind as u32)
        .unwrap_or_else(|| panic!("no {} section", kind.name()))
}

pub fn section_range(b: &[u8], kind: SectionKind) -> Range<usize> {
    let s = table(b)[section_position(b, kind)];
    s.offset as usize..(s.offset + s.length) as usize
}

/// Changes a section's bytes in place and fixes its checksum, the table's and the header's.
pub fn patch_section(b: &mut [u8], kind: SectionKind, f: impl FnOnce(&mut [u8])) {
    let r = section_range(b, kind);
    f(&mut b[r.clone()]);
    let sum = checksum(&b[r]);
    let i = section_position(b, kind);
    patch_table(b, |t| t[i].checksum = sum);
}

/// Changes the grid description and fixes every checksum that covers it.
pub fn patch_grid(b: &mut [u8], f: impl FnOnce(&mut GridDesc)) {
    patch_section(b, SectionKind::GridDesc, |s| {
        let mut d: GridDesc = bytemuck::pod_read_unaligned(&s[..size_of::<GridDesc>()]);
        f(&mut d);
        s[..size_of::<GridDesc>()].copy_from_slice(bytemuck::bytes_of(&d));
    });
}

/// A copy of `bytes` whose first byte sits `shift` bytes past an 8-byte boundary.
pub struct Shifted {
    buf: Vec<u64>,
    shift: usize,
    len: usize,
}

impl Shifted {
    pub fn new(bytes: &[u8], shift: usize) -> Self {
        let mut buf = vec![0u64; (bytes.len() + shift).div_ceil(8) + 1];
        let raw: &mut [u8] = bytemuck::cast_slice_mut(&mut buf);
        raw[shift..shift + bytes.len()].copy_from_slice(bytes);
        Self {
            buf,
            shift,
            len: bytes.len(),
        }
    }
    pub fn bytes(&self) -> &[u8] {
        let raw: &[u8] = bytemuck::cast_slice(&self.buf);
        &raw[self.shift..self.shift + self.len]
    }
}

/// Every entry the reader should return for `grid`, computed from the owned data alone:
/// calls `f(cell, direction, pin, expected)` for every cell of the full grid.
pub fn for_each_expected(grid: &OwnedPinGrid, mut f: impl FnMut([u32; 3], u32, u32, PinEntry)) {
    let d = grid.desc.dims;
    let dirs = Directions::from_desc(grid.desc.direction_kind, grid.desc.direction_res).unwrap();
    let ppe = grid.desc.pins_per_entry;
    let block_len = (dirs.count() * ppe) as usize;
    let (zb, ze) = grid.tile.map_or((0, d[2]), |t| (t.z_begin, t.z_end));
    for z in 0..d[2] {
        for y in 0..d[1] {
            for x in 0..d[0] {
                let block = if z < zb || z >= ze {
                    None
                } else {
                    let local = (x + d[0] * (y + d[1] * (z - zb))) as usize;
                    match &grid.cell_index {
                        None => Some(local),
                        Some(ix) if ix[local] == EMPTY_CELL => None,
                        Some(ix) => Some(ix[local] as usize),
                    }
                };
                for dir in 0..dirs.count() {
                    for pin in 0..ppe {
                        let e = block.map_or(PinEntry::EMPTY, |b| {
                            grid.pins[b * block_len + (dir * ppe + pin) as usize]
                        });
                        f([x, y, z], dir, pin, e);
                    }
                }
            }
        }
    }
}

/// A random sparse density of `dims` voxels in bricks of `brick`: about half the bricks
/// empty, the stored ones in canonical slot order, f32 voxels if `f32` else f16.
pub fn sparse_density(dims: [u32; 3], brick: u32, f32: bool, seed: u64) -> OwnedSparseDensity {
    let mut rng = Rng(seed);
    let bdims = brick_dims(dims, brick);
    let n = bdims.iter().product::<u32>() as usize;
    let mut index = Vec::with_capacity(n);
    let mut count = 0u32;
    for _ in 0..n {
        if rng.below(2) == 0 {
            index.push(EMPTY_BRICK);
        } else {
            index.push(count);
            count += 1;
        }
    }
    let voxels = count as usize * (brick as usize).pow(3);
    let vals: Vec<f64> = (0..voxels).map(|_| rng.unit() * 50.0).collect();
    let values = if f32 {
        OwnedSparseValues::F32(vals.iter().map(|&v| v as f32).collect())
    } else {
        OwnedSparseValues::F16(vals.iter().map(|&v| half::f16::from_f64(v)).collect())
    };
    OwnedSparseDensity {
        header: SparseDensityHeader {
            dims,
            encoding: if f32 { DENSITY_F32 } else { DENSITY_F16 },
            brick,
            brick_count: count,
            reserved: [0; 2],
        },
        index,
        values,
    }
}

/// [`full_grid`] with a sparse f16 density as well (a format 1.1 file).
pub fn sparse_grid() -> OwnedPinGrid {
    let mut g = full_grid();
    g.sparse_density = Some(sparse_density([5, 3, 9], 2, false, 3));
    g
}

/// [`dense_grid`] with a sparse f32 density of one brick grid cell per axis, no dense one.
pub fn sparse_grid_f32() -> OwnedPinGrid {
    let mut g = dense_grid();
    g.sparse_density = Some(sparse_density([9, 4, 4], 4, true, 8));
    g
}
