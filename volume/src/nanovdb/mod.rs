//! NanoVDB files (`.nvdb`, as `nanovdb_convert` writes them): float, double, half and the
//! quantised Fp4, Fp8, Fp16 and FpN grids, uncompressed or ZIP (zlib); BLOSC is refused.
//!
//! # Reading
//!
//! NanoVDB is a flat, pointer-free image of a VDB tree: grid header, tree header, root
//! tiles, upper 32^3 nodes, lower 16^3 nodes and 8^3 leaves, linked by byte offsets. An
//! uncompressed grid is read in place from a memory map of the file; a ZIP grid is inflated
//! once into a buffer of exactly its declared size (refused against the memory budget
//! first). The walk ([`tree`]) decodes one leaf at a time into the same sparse 8^3-block
//! table the OpenVDB path builds (`VdbSource`): its values, tiles, transform and
//! statistics, with the OpenVDB worker's rules (inactive voxels are 0, negative values
//! clamp to 0, a level set is refused unless baked as fog). So a NanoVDB grid converted from
//! a VDB answers every `DensitySource` query as the VDB does, and a float grid bakes to the
//! same bytes. Quantised leaves decode as NanoVDB does (`code * quantum + minimum` in f32)
//! and are kept as f32; half leaves and fog level sets keep their 16 bits.
//!
//! The parse is our own, bounds-checked code over the file's bytes, so it runs in this
//! process: every offset, size and count is checked against the bytes there, and the node
//! counts of the tree header bound the walk and the leaf table by the file's size.
//!
//! # Grid selection and placement
//!
//! As for OpenVDB (`vdb` module docs): `VdbOptions::grid` names one, else `density`, else
//! the only float-like grid. The grids of a repeated name are `name#0`, `name#1`, ... in
//! file order (the name alone is an error listing them), as in OpenVDB files. World = M index + t with NanoVDB's
//! double-precision map (`mMatD`, `mVecD`), which `nanovdb_convert` copies from OpenVDB's
//! affine map, so the placement is OpenVDB's.
//!
//! Not read: vector, integer, mask, index and point grids; BLOSC files; big-endian files;
//! files of another NanoVDB file format than 32. `VdbOptions::part` is ignored: the whole
//! grid is read for every part, which holds the whole field.

use std::path::Path;

use super::vdb::{
    GridInfo, Stream, StreamError, ValueKind, VdbOptions, VdbSource, leaf_table_bytes,
};
use super::{DensityScale, SourceError, one_line};

mod bytes;
mod file;
mod grid;
mod leaf;
mod tree;

pub use file::{MAGIC, has_magic};

use bytes::Bytes;
use leaf::ValueType;

/// Whether `path` holds a NanoVDB file: its first 8 bytes are NanoVDB's magic. An
/// unreadable file is not one (opening it reports why).
pub fn is_nanovdb_file(path: &Path) -> bool {
    super::has_nanovdb_magic(path)
}

/// The mapped or inflated bytes of the chosen grid.
enum Buffer {
    Mapped(memmap2::Mmap, u64, u64),
    Owned(Vec<u8>),
}

impl Buffer {
    fn bytes(&self) -> &[u8] {
        match self {
            Buffer::Mapped(m, off, len) => &m[*off as usize..(*off + *len) as usize],
            Buffer::Owned(v) => v,
        }
    }

    /// Drops the mapped pages of grid bytes `off..off + len` from this process's memory once
    /// the walk is done with them, so that the resident pages of the file stay a window, not
    /// the whole grid. A later read of them faults the same bytes back in from the file.
    fn release(&self, off: u64, len: u64) {
        if let Buffer::Mapped(m, base, glen) = self {
            let end = off.saturating_add(len).min(*glen);
            if off < end {
                // SAFETY: the map is a private, read-only mapping of a file pinbake does not
                // write: MADV_DONTNEED drops pages that are read back unchanged from the
                // file, so every slice into the map keeps its contents. Failure only leaves
                // the pages resident.
                let _ = unsafe {
                    m.unchecked_advise_range(
                        memmap2::UncheckedAdvice::DontNeed,
                        (base + off) as usize,
                        (end - off) as usize,
                    )
                };
            }
        }
    }
}

/// Opens the NanoVDB file `path` with the options of the OpenVDB path (`grid`,
/// `levelset_to_fog`, `max_leaf_bytes`), every value multiplied by `scale`; see the module
/// docs. Every failure is one line naming the file.
pub fn open(path: &Path, opt: &VdbOptions, scale: DensityScale) -> Result<VdbSource, SourceError> {
    let fail = |m: String| SourceError::NanoVdb {
        path: path.to_path_buf(),
        message: m,
    };
    let file_size = crate::files::check_input(path).map_err(SourceError::from_file)?;
    let file = std::fs::File::open(path).map_err(|e| SourceError::Io {
        path: path.to_path_buf(),
        source: e,
    })?;
    if file_size == 0 {
        return Err(fail("is empty".into()));
    }
    // SAFETY: the map is only read, through bounds-checked slices; a file truncated by
    // another process while mapped would fault, as any reader of a file changed under it
    // may misbehave, and pinbake never writes its inputs.
    let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|e| SourceError::Io {
        path: path.to_path_buf(),
        source: e,
    })?;
    let budget = opt.max_leaf_bytes.unwrap_or(u64::MAX);
    let (st, value) = read(map, opt, budget).map_err(|e| match e {
        StreamError::Budget { .. } => SourceError::Memory {
            path: path.to_path_buf(),
            message: e.to_string(),
        },
        StreamError::Message(m) => fail(m),
    })?;
    let mut src = VdbSource::from_stream(path, st, scale).map_err(fail)?;
    src.set_reader_label("nanovdb");
    let _ = value;
    Ok(src)
}

/// The stream the OpenVDB worker would have sent for the chosen grid of the mapped file.
fn read(
    map: memmap2::Mmap,
    opt: &VdbOptions,
    budget: u64,
) -> Result<(Stream, ValueType), StreamError> {
    let b = Bytes::new(&map);
    let entries = file::read_entries(&b)?;
    // Names as the selection rules see them: the grids of a repeated name are `name\x1e<k>`,
    // k = 0, 1, ... in file order, as OpenVDB's files store them.
    let mut count = std::collections::HashMap::<&str, u32>::new();
    for e in &entries {
        *count.entry(e.name.as_str()).or_insert(0) += 1;
    }
    let mut seen = std::collections::HashMap::<&str, u32>::new();
    let mut grids: Vec<(GridInfo, usize)> = Vec::with_capacity(entries.len());
    for (i, e) in entries.iter().enumerate() {
        let name = if count[e.name.as_str()] > 1 {
            let k = seen.entry(e.name.as_str()).or_insert(0);
            *k += 1;
            format!("{}\u{1e}{}", e.name, *k - 1)
        } else {
            e.name.clone()
        };
        let grid_type = format!("nanovdb:{}", file::entry_type(e));
        let class = if e.grid_class == grid::CLASS_LEVEL_SET {
            "level set"
        } else {
            ""
        };
        grids.push((
            GridInfo {
                name,
                grid_type,
                class: class.into(),
            },
            i,
        ));
    }
    grids.sort_by(|a, b| a.0.name.cmp(&b.0.name));
    let infos: Vec<GridInfo> = grids.iter().map(|g| g.0.clone()).collect();
    let chosen = super::vdb::select_grid(&infos, opt.grid.as_deref())?;
    let e = &entries[grids[chosen].1];
    let shown = infos[chosen].display();
    let value = ValueType::from_code(e.grid_type).ok_or_else(|| {
        format!(
            "grid '{shown}' has type {}; only float, double, half, fp4, fp8, fp16 and fpN scalar grids are supported",
            one_line(&file::entry_type(e))
        )
    })?;
    if e.grid_class == grid::CLASS_LEVEL_SET && !opt.levelset_to_fog {
        return Err(format!(
            "grid '{shown}' is a level set (signed distance), not a density; pass --levelset-to-fog to bake its interior as density 1"
        )
        .into());
    }
    let buffer = match e.codec {
        file::Codec::None => Buffer::Mapped(map, e.data_offset, e.grid_size),
        file::Codec::Zip => {
            let v = file::unzip(&b, e, budget)?;
            drop(map);
            Buffer::Owned(v)
        }
    };
    let gb = Bytes::new(buffer.bytes());
    let h = grid::read_header(&gb, &shown, value, e.grid_size)?;
    if h.level_set != (e.grid_class == grid::CLASS_LEVEL_SET) {
        return Err(format!("grid '{shown}': its class differs between the file's metadata and the grid (corrupt file)").into());
    }
    // The leaf table is sized from the declared count before a leaf is read.
    let release = |off: u64, len: u64| buffer.release(off, len);
    let half = tree::keeps_half(&gb, &h, &release);
    let encoding = if half {
        super::vdb::LEAF_HALF
    } else {
        super::vdb::LEAF_F32
    };
    let need = leaf_table_bytes(h.node_count[0], encoding);
    let limit = opt.max_leaf_bytes.unwrap_or(u64::MAX);
    if need > limit {
        return Err(StreamError::Budget { need, limit });
    }
    let t = tree::walk(gb, &h, &shown, half, &release)?;
    drop(buffer);
    if t.active == 0 {
        return Err(format!("grid '{shown}' has no active voxels").into());
    }
    let kind = match value {
        ValueType::Float => ValueKind::Float,
        ValueType::Double => ValueKind::Double,
        ValueType::Half => ValueKind::Half,
        ValueType::Fp4 => ValueKind::Fp4,
        ValueType::Fp8 => ValueKind::Fp8,
        ValueType::Fp16 => ValueKind::Fp16,
        ValueType::FpN => ValueKind::FpN,
    };
    Ok((
        Stream {
            grids: infos,
            chosen,
            kind,
            level_set: h.level_set,
            xf: h.xf,
            origins: t.origins,
            leaves: t.leaves,
            tiles: t.tiles,
            active: t.active,
            negatives: t.negatives,
            part: None,
            stats: None,
        },
        value,
    ))
}
