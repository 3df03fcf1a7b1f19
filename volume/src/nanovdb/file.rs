//! The NanoVDB file: segments of a 16-byte header (magic, version, grid count, codec) and
//! one 176-byte metadata record plus name per grid, followed by the grids' buffers, raw or
//! zlib-compressed (`nanovdb/util/IO.h`). Nothing here trusts a size: every record and buffer
//! is checked against the file's length before it is read.

use super::bytes::Bytes;
use super::leaf::type_name;

/// "NanoVDB0", little-endian: the magic of a file segment and (in NanoVDB 32.4) of a grid.
pub const MAGIC: u64 = 0x3042_4456_6f6e_614e;
/// "NanoVDB1": the grid magic of later NanoVDB 32 releases.
pub(super) const GRID_MAGIC: u64 = 0x3142_4456_6f6e_614e;
/// The file format's major version: NanoVDB changes it whenever the layout changes.
pub(super) const MAJOR_VERSION: u32 = 32;

const HEADER_BYTES: u64 = 16;
const META_BYTES: u64 = 176;
/// Longest grid name accepted (NanoVDB's own limit for names stored in the grid is 255
/// bytes; long names live in blind data).
const MAX_NAME_BYTES: u64 = 1 << 16;
/// zlib cannot expand data by more than about 1032:1: a ZIP grid declaring more is lying.
const MAX_ZLIB_RATIO: u64 = 1100;

/// How a grid's buffer is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Codec {
    None,
    Zip,
}

/// One grid as the file's metadata describes it.
#[derive(Clone, Debug)]
pub(super) struct GridEntry {
    pub(super) name: String,
    pub(super) grid_type: u32,
    pub(super) grid_class: u32,
    /// Bytes of the grid's buffer once decoded.
    pub(super) grid_size: u64,
    /// Where its stored bytes start in the file and how many there are.
    pub(super) data_offset: u64,
    pub(super) file_size: u64,
    pub(super) codec: Codec,
}

/// The version word's major number (`nanovdb::Version`: major << 21 | minor << 10 | patch).
pub(super) fn version_text(v: u32) -> String {
    format!("{}.{}.{}", v >> 21, (v >> 10) & 0x7ff, v & 0x3ff)
}

/// Whether `head` (the first bytes of a file) is a NanoVDB file.
pub fn has_magic(head: &[u8]) -> bool {
    head.len() >= 8 && u64::from_le_bytes(head[..8].try_into().unwrap_or([0; 8])) == MAGIC
}

/// Every grid of every segment of the file `b`.
pub(super) fn read_entries(b: &Bytes<'_>) -> Result<Vec<GridEntry>, String> {
    let mut grids = Vec::new();
    let mut at = 0u64;
    while at < b.len() {
        let magic = b.u64(at, "segment header")?;
        if magic != MAGIC {
            return Err(if magic == MAGIC.swap_bytes() {
                "is a big-endian NanoVDB file, which this reader does not read".to_string()
            } else if at == 0 {
                "is not a NanoVDB file (bad magic)".to_string()
            } else {
                format!("has a bad segment magic at byte {at} (corrupt file)")
            });
        }
        let version = b.u32(at + 8, "segment header")?;
        if version >> 21 != MAJOR_VERSION {
            return Err(format!(
                "was written by NanoVDB {}; this reader knows file format {MAJOR_VERSION} (NanoVDB {MAJOR_VERSION}.x) only",
                version_text(version)
            ));
        }
        let count = b.u16(at + 12, "segment header")?;
        let codec = match b.u16(at + 14, "segment header")? {
            0 => Codec::None,
            1 => Codec::Zip,
            2 => {
                return Err(
                    "is BLOSC-compressed, which this reader does not read (convert it again without --blosc, or with --zip)"
                        .into(),
                );
            }
            c => return Err(format!("uses unknown codec {c} (corrupt or newer file)")),
        };
        if count == 0 {
            return Err(format!(
                "has a segment with no grids at byte {at} (corrupt file)"
            ));
        }
        at += HEADER_BYTES;
        let mut metas = Vec::with_capacity(usize::from(count));
        for _ in 0..count {
            let m = b.slice(at, META_BYTES, "grid metadata")?;
            let m = Bytes::new(m);
            let grid_size = m.u64(0, "grid metadata")?;
            let file_size = m.u64(8, "grid metadata")?;
            let grid_type = m.u32(32, "grid metadata")?;
            let grid_class = m.u32(36, "grid metadata")?;
            let name_size = u64::from(m.u32(136, "grid metadata")?);
            if name_size > MAX_NAME_BYTES {
                return Err(format!(
                    "declares a grid name of {name_size} bytes (at most {MAX_NAME_BYTES}; corrupt file)"
                ));
            }
            let raw = b.slice(at + META_BYTES, name_size, "grid name")?;
            let end = raw.iter().position(|&c| c == 0).unwrap_or(raw.len());
            let name = String::from_utf8_lossy(&raw[..end]).into_owned();
            at += META_BYTES + name_size;
            metas.push((name, grid_type, grid_class, grid_size, file_size));
        }
        for (name, grid_type, grid_class, grid_size, file_size) in metas {
            if b.len() - at.min(b.len()) < file_size {
                return Err(format!(
                    "grid '{}' declares {file_size} stored bytes at byte {at}, past the end of the {}-byte file (truncated or corrupt)",
                    super::one_line(&name),
                    b.len()
                ));
            }
            match codec {
                Codec::None if file_size != grid_size => {
                    return Err(format!(
                        "grid '{}' stores {file_size} bytes for a {grid_size}-byte grid (corrupt file)",
                        super::one_line(&name)
                    ));
                }
                Codec::Zip if grid_size > file_size.saturating_mul(MAX_ZLIB_RATIO) + 4096 => {
                    return Err(format!(
                        "grid '{}' declares {grid_size} bytes from {file_size} compressed ones, more than zlib can expand to (corrupt file)",
                        super::one_line(&name)
                    ));
                }
                _ => {}
            }
            grids.push(GridEntry {
                name,
                grid_type,
                grid_class,
                grid_size,
                data_offset: at,
                file_size,
                codec,
            });
            at += file_size;
        }
    }
    if grids.is_empty() {
        return Err("is empty".into());
    }
    Ok(grids)
}

/// The decoded buffer of a ZIP grid: `grid_size` bytes from the zlib stream after its 8-byte
/// compressed size. Refused when the budget cannot hold it or the stream does not give
/// exactly that many bytes.
pub(super) fn unzip(b: &Bytes<'_>, e: &GridEntry, budget: u64) -> Result<Vec<u8>, String> {
    use std::io::Read;
    let shown = super::one_line(&e.name);
    let zsize = b.u64(e.data_offset, "compressed grid size")?;
    if zsize.checked_add(8) != Some(e.file_size) {
        return Err(format!(
            "grid '{shown}' declares {zsize} compressed bytes in a {}-byte record (corrupt file)",
            e.file_size
        ));
    }
    if e.grid_size > budget {
        return Err(format!(
            "grid '{shown}' needs {} bytes decompressed, more than the {budget} bytes the memory budget leaves (--max-memory)",
            e.grid_size
        ));
    }
    let z = b.slice(e.data_offset + 8, zsize, "compressed grid")?;
    let mut out = Vec::new();
    out.try_reserve_exact(e.grid_size as usize).map_err(|_| {
        format!(
            "grid '{shown}' needs {} bytes decompressed, more than this machine gives",
            e.grid_size
        )
    })?;
    let got = flate2::read::ZlibDecoder::new(z)
        .take(e.grid_size + 1)
        .read_to_end(&mut out)
        .map_err(|err| {
            format!("grid '{shown}': its ZIP data does not decompress ({err}; corrupt file)")
        })?;
    if got as u64 != e.grid_size {
        return Err(format!(
            "grid '{shown}': its ZIP data gives {got} bytes, the metadata says {} (corrupt file)",
            e.grid_size
        ));
    }
    Ok(out)
}

/// The type name of an entry, for listings.
pub(super) fn entry_type(e: &GridEntry) -> String {
    type_name(e.grid_type)
}
