//! A grid's own header (`nanovdb::GridData`, 672 bytes) and its tree header (`TreeData`,
//! 64 bytes): magic, version, size, type and class, the index-to-world map, and the node
//! offsets and counts the tree walk starts from, each checked against the buffer's size.

use super::bytes::Bytes;
use super::file::{GRID_MAGIC, MAGIC, MAJOR_VERSION, version_text};
use super::leaf::ValueType;

const GRID_DATA_BYTES: u64 = 672;
const TREE_DATA_BYTES: u64 = 64;
/// Offsets inside `GridData`.
const MAP_MAT_D: u64 = 384;
const MAP_VEC_D: u64 = 528;
const GRID_CLASS: u64 = 632;
const GRID_TYPE: u64 = 636;
/// `GridClass::LevelSet`.
pub(super) const CLASS_LEVEL_SET: u32 = 1;
/// Sizes of the upper (32^3) and lower (16^3) internal nodes, the same for every value type
/// this reader decodes.
pub(super) const UPPER_BYTES: u64 = 270_400;
pub(super) const LOWER_BYTES: u64 = 33_856;

/// What the tree walk needs from a grid's headers.
#[derive(Clone, Debug)]
pub(super) struct GridHeader {
    pub(super) value: ValueType,
    pub(super) level_set: bool,
    /// Index to world, row-major 3x4 (NanoVDB's `mMatD` is row-major for column vectors).
    pub(super) xf: [f64; 12],
    /// Byte offset of the root node in the buffer.
    pub(super) root: u64,
    /// Byte offset of the first leaf (the leaves follow one another in NanoVDB's layout),
    /// as the tree header says; only a hint, every leaf is reached through its parent.
    pub(super) first_leaf: u64,
    /// Declared counts of leaf, lower and upper nodes.
    pub(super) node_count: [u64; 3],
}

/// Reads and checks the headers of a grid whose decoded buffer is `b`; `grid_type` and
/// `grid_size` are what the file's metadata said about it.
pub(super) fn read_header(
    b: &Bytes<'_>,
    shown: &str,
    value: ValueType,
    grid_size: u64,
) -> Result<GridHeader, String> {
    if b.len() < GRID_DATA_BYTES + TREE_DATA_BYTES {
        return Err(format!(
            "grid '{shown}' is {} bytes, too short for its headers (corrupt file)",
            b.len()
        ));
    }
    let magic = b.u64(0, "grid header")?;
    if magic != MAGIC && magic != GRID_MAGIC {
        return Err(format!("grid '{shown}' has a bad magic (corrupt file)"));
    }
    let version = b.u32(16, "grid header")?;
    if version >> 21 != MAJOR_VERSION {
        return Err(format!(
            "grid '{shown}' was written by NanoVDB {}; this reader knows file format {MAJOR_VERSION} only",
            version_text(version)
        ));
    }
    let size = b.u64(32, "grid header")?;
    if size != grid_size {
        return Err(format!(
            "grid '{shown}' says it is {size} bytes, the file's metadata {grid_size} (corrupt file)"
        ));
    }
    let t = b.u32(GRID_TYPE, "grid header")?;
    if ValueType::from_code(t) != Some(value) {
        return Err(format!(
            "grid '{shown}' has type code {t} in its header, not the {} its metadata says (corrupt file)",
            value.name()
        ));
    }
    let level_set = b.u32(GRID_CLASS, "grid header")? == CLASS_LEVEL_SET;
    let mut xf = [0.0f64; 12];
    for r in 0..3 {
        for c in 0..3 {
            xf[4 * r + c] = b.f64(MAP_MAT_D + 8 * (3 * r + c) as u64, "grid map")?;
        }
        xf[4 * r + 3] = b.f64(MAP_VEC_D + 8 * r as u64, "grid map")?;
    }
    let tree = GRID_DATA_BYTES;
    let root_rel = b.u64(tree + 24, "tree header")?;
    let root = tree
        .checked_add(root_rel)
        .filter(|r| *r < b.len())
        .ok_or_else(|| {
            format!("grid '{shown}' has its root past the end of its buffer (corrupt file)")
        })?;
    let first_leaf = tree.saturating_add(b.u64(tree, "tree header")?);
    let mut node_count = [0u64; 3];
    for (i, n) in node_count.iter_mut().enumerate() {
        *n = u64::from(b.u32(tree + 32 + 4 * i as u64, "tree header")?);
    }
    // Every declared node must fit in the buffer: this bounds the walk and the leaf table
    // by the file's size, whatever the child offsets claim.
    let need = node_count[0]
        .saturating_mul(value.min_leaf_size())
        .saturating_add(node_count[1].saturating_mul(LOWER_BYTES))
        .saturating_add(node_count[2].saturating_mul(UPPER_BYTES));
    if need > b.len() {
        return Err(format!(
            "grid '{shown}' declares {} leaves, {} lower and {} upper nodes, more than its {} bytes hold (corrupt file)",
            node_count[0],
            node_count[1],
            node_count[2],
            b.len()
        ));
    }
    Ok(GridHeader {
        value,
        level_set,
        xf,
        root,
        first_leaf,
        node_count,
    })
}
