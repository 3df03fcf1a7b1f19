//! The fixed-size, `repr(C)` records of a pin file, exactly as they sit on disk.
//!
//! Every record is plain old data (bytemuck `Pod`): no padding, little-endian on disk, so a
//! little-endian host reads them by copying bytes and bulk arrays by casting in place.
//! Changing any field here changes the file format; the golden-bytes test guards that.

use bytemuck::{Pod, Zeroable};

/// First eight bytes of every pin file. PNG-style: a non-ASCII byte catches 7-bit transfers,
/// and CR LF / SUB / LF catch text-mode newline translation.
pub const MAGIC: [u8; 8] = *b"\x89PIN\r\n\x1a\n";
/// Readers reject any other major version.
pub const VERSION_MAJOR: u16 = 1;
/// Readers accept any minor version of their major; newer minors only add sections or append
/// fields to records whose length is recorded.
pub const VERSION_MINOR: u16 = 0;
/// The minor version a file with a [`SectionKind::SparseDensity`] section carries (1.1); files
/// without one stay 1.0, byte for byte.
pub const VERSION_MINOR_SPARSE_DENSITY: u16 = 1;
/// Every section starts at a multiple of this many bytes (one cache line; GPUs bind from it).
pub const SECTION_ALIGN: u64 = 64;
/// Bits in one pin mask, one per interval along the chord.
pub const BITS_PER_PIN: u32 = 32;
/// Upper bound on the section table length accepted by readers.
pub const MAX_SECTIONS: u32 = 1024;
/// Marks a cell with no stored pins in the sparse cell index.
pub const EMPTY_CELL: u32 = u32::MAX;

/// The file header at offset 0 (64 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct FileHeader {
    pub magic: [u8; 8],
    pub version_major: u16,
    pub version_minor: u16,
    /// Size of this header in bytes (64 in version 1.0).
    pub header_size: u32,
    pub section_count: u32,
    /// Size of one section table entry in bytes (32 in version 1.0).
    pub section_entry_size: u32,
    /// Byte offset of the section table (a multiple of 64).
    pub table_offset: u64,
    /// Total length of the file in bytes; a mismatch means truncation or appended garbage.
    pub file_size: u64,
    /// Reserved, zero.
    pub flags: u64,
    /// xxh3-64 of the section table bytes.
    pub table_checksum: u64,
    /// xxh3-64 of header bytes `[0, 56)`.
    pub header_checksum: u64,
}

/// One entry of the section table (32 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct SectionEntry {
    /// A [`SectionKind`] value; unknown kinds are skipped unless `flags` has [`SECTION_REQUIRED`].
    pub kind: u32,
    pub flags: u32,
    pub offset: u64,
    pub length: u64,
    /// xxh3-64 of the section's `length` bytes.
    pub checksum: u64,
}

/// Section flag: a reader that does not know this section kind must reject the file.
pub const SECTION_REQUIRED: u32 = 1;

/// The kinds of section defined by version 1.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum SectionKind {
    /// [`GridDesc`]: required.
    GridDesc = 1,
    /// Array of [`PinEntry`]: required unless no cell stores pins.
    Pins = 2,
    /// Array of `u32`, one per covered cell: block number or [`EMPTY_CELL`].
    CellIndex = 3,
    /// [`MajorantHeader`] then `f32` per brick.
    Majorant = 4,
    /// [`DensityHeader`] then `f16` per voxel.
    Density = 5,
    /// bincode-encoded [`crate::Metadata`].
    Metadata = 6,
    /// [`TileDesc`]: this file holds one z-slab of a larger grid.
    Tile = 7,
    /// [`SparseDensityHeader`], a `u32` per brick (slot or [`EMPTY_BRICK`]), then the
    /// stored bricks' voxels (format 1.1).
    SparseDensity = 8,
    /// [`ControlHeader`], then three `f32` arrays of one value per brick: the control
    /// extinction, the residual majorant and the majorant (format 1.1).
    Control = 9,
}

impl SectionKind {
    pub const ALL: [SectionKind; 9] = [
        SectionKind::GridDesc,
        SectionKind::Pins,
        SectionKind::CellIndex,
        SectionKind::Majorant,
        SectionKind::Density,
        SectionKind::Metadata,
        SectionKind::Tile,
        SectionKind::SparseDensity,
        SectionKind::Control,
    ];

    pub fn from_u32(v: u32) -> Option<Self> {
        Self::ALL.into_iter().find(|k| *k as u32 == v)
    }

    pub fn name(self) -> &'static str {
        match self {
            SectionKind::GridDesc => "grid",
            SectionKind::Pins => "pins",
            SectionKind::CellIndex => "cell-index",
            SectionKind::Majorant => "majorant",
            SectionKind::Density => "density",
            SectionKind::Metadata => "metadata",
            SectionKind::Tile => "tile",
            SectionKind::SparseDensity => "sparse-density",
            SectionKind::Control => "control",
        }
    }
}

/// Direction parametrisation codes stored in [`GridDesc::direction_kind`].
pub const DIRECTIONS_POLAR: u32 = 0;
pub const DIRECTIONS_OCTAHEDRAL: u32 = 1;

/// [`GridDesc::flags`]: the box was cropped to the non-empty region of the source.
pub const GRID_FLAG_CROPPED: u32 = 1;
/// [`GridDesc::flags`]: pins run through random points/directions inside their cell (else centres).
pub const GRID_FLAG_JITTERED_PINS: u32 = 2;

/// Describes the 5D grid (296 bytes). Everything needed to interpret the other sections.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GridDesc {
    /// Spatial cells along x, y, z; each >= 1.
    pub dims: [u32; 3],
    /// [`DIRECTIONS_POLAR`] or [`DIRECTIONS_OCTAHEDRAL`].
    pub direction_kind: u32,
    /// Polar: (n_phi, n_theta). Octahedral: (n, n).
    pub direction_res: [u32; 2],
    pub pins_per_entry: u32,
    /// Always [`BITS_PER_PIN`].
    pub bits_per_pin: u32,
    /// Number of cell blocks in the pin section.
    pub stored_cells: u64,
    /// Box in the volume's local space that the grid covers (the unit cube of the pin model).
    pub box_min: [f64; 3],
    pub box_max: [f64; 3],
    /// Row-major 3x4 affine map from the volume's local space to world space.
    pub local_to_world: [f64; 12],
    /// Ray-marching step used by the bake, relative to the longest box edge.
    pub step_size: f64,
    pub density_scale: f64,
    pub seed: u64,
    /// `GRID_FLAG_*` bits.
    pub flags: u32,
    pub reserved0: u32,
    /// The source's own box before cropping.
    pub source_box_min: [f64; 3],
    pub source_box_max: [f64; 3],
    pub reserved: [u64; 4],
}

/// One pin: the ratio bitmask and the minimum interval transmittance (8 bytes).
///
/// Bit 31 of `mask` is the interval nearest the chord's start (the entry point when walking
/// along the pin's direction, which has z >= 0).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct PinEntry {
    pub mask: u32,
    pub t_min: f32,
}

impl PinEntry {
    /// What an empty cell reads as: no medium anywhere along the pin.
    pub const EMPTY: PinEntry = PinEntry {
        mask: 0,
        t_min: 1.0,
    };

    pub fn is_empty(&self) -> bool {
        self.mask == 0 && self.t_min == 1.0
    }
}

/// Prefix of the majorant section (16 bytes), followed by `f32` per brick, x fastest.
/// The bricks tile the grid box uniformly.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct MajorantHeader {
    pub dims: [u32; 3],
    pub reserved: u32,
}

/// Prefix of the control section (16 bytes, format 1.1), followed by three `f32` arrays of
/// `n = dims.x * dims.y * dims.z` values each, x fastest: the control extinction `c`, the
/// residual majorant `m` and the majorant `M` of every brick. The bricks tile the grid box
/// uniformly, as the majorant section's do (docs/format.md section 5.8).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct ControlHeader {
    pub dims: [u32; 3],
    pub reserved: u32,
}

/// Density encodings for [`DensityHeader::encoding`].
pub const DENSITY_F16: u32 = 0;

/// Prefix of the density section (16 bytes), followed by one IEEE binary16 per voxel, x
/// fastest. Voxel centres sit at `box_min + (i + 0.5) * extent / dims`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct DensityHeader {
    pub dims: [u32; 3],
    pub encoding: u32,
}

/// [`DensityHeader::encoding`] / [`SparseDensityHeader::encoding`]: IEEE binary32 voxels
/// (sparse density only).
pub const DENSITY_F32: u32 = 1;
/// Marks a brick with no stored voxels (all zero) in the sparse density's brick index.
pub const EMPTY_BRICK: u32 = u32::MAX;
/// Largest brick edge, in voxels, of a sparse density (a brick is at most 64^3 voxels).
pub const MAX_BRICK: u32 = 64;

/// Prefix of the sparse density section (32 bytes, format 1.1). It is followed by the brick
/// index, one `u32` per brick of the brick grid (`ceil(dims / brick)` per axis, x fastest):
/// the brick's slot or [`EMPTY_BRICK`]; then `brick_count` bricks of `brick^3` voxels each
/// (x fastest inside a brick) in the encoding's element type. Voxel `(x, y, z)` lives in brick
/// `(x, y, z) / brick` at `(x, y, z) % brick`; voxel centres sit where the dense section's do.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct SparseDensityHeader {
    /// Voxels along x, y, z over the grid box; each >= 1.
    pub dims: [u32; 3],
    /// [`DENSITY_F16`] or [`DENSITY_F32`].
    pub encoding: u32,
    /// Brick edge in voxels: a power of two, 1..=[`MAX_BRICK`].
    pub brick: u32,
    /// Stored bricks.
    pub brick_count: u32,
    /// Reserved, zero.
    pub reserved: [u32; 2],
}

/// The tile section (16 bytes): this file covers cell layers `z_begin..z_end`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct TileDesc {
    pub tile_index: u32,
    pub tile_count: u32,
    pub z_begin: u32,
    pub z_end: u32,
}

const _: () = {
    assert!(size_of::<FileHeader>() == 64);
    assert!(size_of::<SectionEntry>() == 32);
    assert!(size_of::<GridDesc>() == 296);
    assert!(size_of::<PinEntry>() == 8);
    assert!(size_of::<MajorantHeader>() == 16);
    assert!(size_of::<DensityHeader>() == 16);
    assert!(size_of::<TileDesc>() == 16);
    assert!(size_of::<SparseDensityHeader>() == 32);
};
