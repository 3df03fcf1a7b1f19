//! The worker-to-parent stream: its tags and limits, the grid descriptions it carries, the
//! writer helpers the worker uses and the parent's bounded parser (`parse_stream`).

use super::*;

pub(super) const STREAM_MAGIC: &[u8; 8] = b"PBVDBW02";
pub(super) const STREAM_END: &[u8; 8] = b"PBVDBEND";
pub(super) const TAG_END: u8 = 0;
pub(super) const TAG_LEAF: u8 = 1;
pub(super) const TAG_TILE: u8 = 2;
pub(super) const MAX_NAME: usize = 1024;
/// Leaf encodings: 512 f32 values, or 512 f16 bit patterns (half grids, floats saved as
/// half and level sets, whose values are all exact in half).
pub(crate) const LEAF_F32: u8 = 0;
pub(crate) const LEAF_HALF: u8 = 1;
/// Bytes the parent keeps per leaf beside its values: the origin while parsing, then its
/// maximum, its hash-table slot and key.
pub(super) const LEAF_OVERHEAD_BYTES: u64 = 40;

/// Why the parent did not get a grid from the worker.
#[derive(Debug)]
pub(crate) enum StreamError {
    /// The worker failed or its stream is bad: one line.
    Message(String),
    /// The leaves the worker announced need `need` bytes, more than the `limit` given.
    Budget { need: u64, limit: u64 },
}

impl From<String> for StreamError {
    fn from(m: String) -> Self {
        StreamError::Message(m)
    }
}

impl From<&str> for StreamError {
    fn from(m: &str) -> Self {
        StreamError::Message(m.to_string())
    }
}

impl std::fmt::Display for StreamError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StreamError::Message(m) => f.write_str(m),
            StreamError::Budget { need, limit } => write!(
                f,
                "the grid's leaves need {need} bytes, more than the {limit} bytes the memory budget leaves for them (--max-memory)"
            ),
        }
    }
}

/// The leaf values as the parent keeps them, in stream order.
pub(crate) enum LeafValues {
    F32(Vec<[f32; 512]>),
    /// f16 bit patterns; the source maps them to scaled f32 through a table.
    Half(Vec<[u16; 512]>),
}

/// Bytes the parent needs for `leaves` leaves of `encoding` (values and per-leaf overhead).
pub(crate) fn leaf_table_bytes(leaves: u64, encoding: u8) -> u64 {
    let values = if encoding == LEAF_HALF { 1024 } else { 2048 };
    leaves.saturating_mul(values + LEAF_OVERHEAD_BYTES)
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ValueKind {
    Float = 0,
    FloatSavedAsHalf = 1,
    Half = 2,
    Double = 3,
    /// NanoVDB's quantised leaves (never on the worker's wire).
    Fp4 = 4,
    Fp8 = 5,
    Fp16 = 6,
    FpN = 7,
}

impl ValueKind {
    pub(super) fn from_u8(v: u8) -> Option<Self> {
        Some(match v {
            0 => Self::Float,
            1 => Self::FloatSavedAsHalf,
            2 => Self::Half,
            3 => Self::Double,
            _ => return None,
        })
    }
    pub(super) fn name(self) -> &'static str {
        match self {
            Self::Float => "float",
            Self::FloatSavedAsHalf => "float saved as half",
            Self::Half => "half",
            Self::Double => "double",
            Self::Fp4 => "fp4",
            Self::Fp8 => "fp8",
            Self::Fp16 => "fp16",
            Self::FpN => "fpN",
        }
    }
}

/// The part of a grid descriptor the worker needs, independent of vdb-rs types.
#[derive(Clone, Debug)]
pub(crate) struct GridInfo {
    /// Descriptor name as stored (repeated names carry `\x1e<n>`).
    pub(crate) name: String,
    pub(crate) grid_type: String,
    pub(crate) class: String,
}

impl GridInfo {
    pub(crate) fn display(&self) -> String {
        display_name(&self.name)
    }
    pub(super) fn value_kind(&self, half_meta: bool) -> Option<ValueKind> {
        let t = self.grid_type.as_str();
        if t == "Tree_float_5_4_3_HalfFloat" || (t == "Tree_float_5_4_3" && half_meta) {
            Some(ValueKind::FloatSavedAsHalf)
        } else if t == "Tree_float_5_4_3" {
            Some(ValueKind::Float)
        } else if t == "Tree_half_5_4_3" {
            Some(ValueKind::Half)
        } else if t == "Tree_double_5_4_3" || t == "Tree_double_5_4_3_HalfFloat" {
            Some(ValueKind::Double)
        } else {
            None
        }
    }
    pub(super) fn is_scalar_float(&self) -> bool {
        self.value_kind(false).is_some() || NANOVDB_FLOAT_TYPES.contains(&self.grid_type.as_str())
    }
}

/// The NanoVDB grid types the baker reads, by the names the NanoVDB reader lists them under
/// (`nanovdb::open`): its grids reach the source through this stream too.
pub(crate) const NANOVDB_FLOAT_TYPES: [&str; 7] = [
    "nanovdb:float",
    "nanovdb:double",
    "nanovdb:half",
    "nanovdb:fp4",
    "nanovdb:fp8",
    "nanovdb:fp16",
    "nanovdb:fpN",
];

/// `density\x1e1` is shown (and selected) as `density#1`.
pub(crate) fn display_name(name: &str) -> String {
    one_line(name)
}

/// Picks the grid per the rules in the module docs. `grids` must be sorted by name.
pub(crate) fn select_grid(grids: &[GridInfo], selector: Option<&str>) -> Result<usize, String> {
    let list = || {
        grids
            .iter()
            .map(|g| g.display())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let by_name = |sel: &str| -> Result<Option<usize>, String> {
        if let Some(i) = grids.iter().position(|g| g.name == sel) {
            return Ok(Some(i));
        }
        if let Some((base, k)) = sel.rsplit_once('#') {
            let want = format!("{base}\u{1e}{k}");
            if let Some(i) = grids.iter().position(|g| g.name == want) {
                return Ok(Some(i));
            }
        }
        let same: Vec<usize> = (0..grids.len())
            .filter(|&i| grids[i].name.split('\u{1e}').next() == Some(sel))
            .collect();
        match same.len() {
            0 => Ok(None),
            1 => Ok(Some(same[0])),
            n => Err(format!(
                "{n} grids are named '{}'; pick one with --grid: {}",
                one_line(sel),
                same.iter()
                    .map(|&i| grids[i].display())
                    .collect::<Vec<_>>()
                    .join(", ")
            )),
        }
    };
    if grids.is_empty() {
        return Err("contains no grids".into());
    }
    match selector {
        Some(sel) => by_name(sel)?
            .ok_or_else(|| format!("has no grid named '{}'; grids: {}", one_line(sel), list())),
        None => {
            if let Some(i) = by_name("density")? {
                return Ok(i);
            }
            let floats: Vec<usize> = (0..grids.len())
                .filter(|&i| grids[i].is_scalar_float())
                .collect();
            match floats.len() {
                1 => Ok(floats[0]),
                0 => Err(format!("has no float grid; grids: {}", list())),
                _ => Err(format!(
                    "has no grid named 'density' and several float grids; pick one with --grid: {}",
                    list()
                )),
            }
        }
    }
}

pub(super) fn wr(e: std::io::Error) -> String {
    format!("writing to the parent failed: {e}")
}
pub(super) fn put_u8(o: &mut impl Write, v: u8) -> Result<(), String> {
    o.write_all(&[v]).map_err(wr)
}
pub(super) fn put_u32(o: &mut impl Write, v: u32) -> Result<(), String> {
    o.write_all(&v.to_le_bytes()).map_err(wr)
}
pub(super) fn put_u64(o: &mut impl Write, v: u64) -> Result<(), String> {
    o.write_all(&v.to_le_bytes()).map_err(wr)
}
pub(super) fn put_f64(o: &mut impl Write, v: f64) -> Result<(), String> {
    o.write_all(&v.to_le_bytes()).map_err(wr)
}
pub(super) fn put_ivec(o: &mut impl Write, v: [i32; 3]) -> Result<(), String> {
    for c in v {
        o.write_all(&c.to_le_bytes()).map_err(wr)?;
    }
    Ok(())
}
pub(super) fn put_str(o: &mut impl Write, s: &str) -> Result<(), String> {
    let mut end = s.len().min(MAX_NAME);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    put_u32(o, end as u32)?;
    o.write_all(&s.as_bytes()[..end]).map_err(wr)
}

/// The parsed worker stream, before densities are scaled.
pub(crate) struct Stream {
    pub(crate) grids: Vec<GridInfo>,
    pub(crate) chosen: usize,
    pub(crate) kind: ValueKind,
    pub(crate) level_set: bool,
    /// Index to world, row-major 3x4.
    pub(crate) xf: [f64; 12],
    /// Leaf origins and values, index for index.
    pub(crate) origins: Vec<[i32; 3]>,
    pub(crate) leaves: LeafValues,
    pub(crate) tiles: Vec<([i32; 3], u8, f32)>,
    pub(crate) active: u64,
    pub(crate) negatives: u64,
    /// What the worker says about the slab it read, when it read one part of the grid.
    pub(crate) part: Option<PartStream>,
    /// The whole grid's statistics from a statistics pass ([`GridStats`]), which a part read
    /// that skipped the leaves outside its slab counts in place of those leaves.
    pub(crate) stats: Option<GridStats>,
}

/// What a part of a farm bake needs to know about the whole grid and cannot learn from its
/// slab: the facts of the leaves it does not decode that decide the bake's bytes (the box of
/// the non-zero voxels, the count of non-zero leaves, the largest value, the negative values
/// clamped), and the facts of the topology and the file every part checks it against. Made
/// once per bake by a statistics pass over every leaf ([`VdbSource::grid_stats`], `pinbake
/// grid-stats`), given to every part ([`VdbOptions::grid_stats`], `pinbake bake --part I/N
/// --grid-stats FILE`). Values are after the density scale, as the source holds them.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridStats {
    /// Always [`GridStats::FORMAT`].
    pub format: String,
    /// Size of the VDB file in bytes.
    pub file_bytes: u64,
    /// The file's content hash as the bake's provenance records it (xxh3-128, hex).
    pub file_xxh3: String,
    /// The grid read, as the bake's description names it.
    pub grid: String,
    pub levelset_to_fog: bool,
    pub density_scale: f64,
    /// Leaves of the tree (its topology).
    pub leaves: u64,
    /// Active voxels of leaves and tiles (its topology).
    pub active_voxels: u64,
    /// Active negative values clamped to 0 (leaves and tiles).
    pub negative_values: u64,
    /// Leaves holding a non-zero value.
    pub nonzero_leaves: u64,
    /// Index box of the leaves' non-zero voxels, inclusive; `null` when there are none.
    pub nonzero_box: Option<[[i32; 3]; 2]>,
    /// The leaves' largest value.
    pub max_value: f32,
    /// Where the statistics were read from (`pinbake bake --grid-stats FILE`), for messages;
    /// not part of the file.
    #[serde(skip)]
    pub path: Option<std::path::PathBuf>,
}

impl GridStats {
    /// The `format` field of a statistics file.
    pub const FORMAT: &'static str = "pinbake-grid-stats-1";

    /// "the grid statistics in FILE" (or without the file when they were not read from one):
    /// how messages name them.
    pub fn named(&self) -> String {
        match &self.path {
            Some(p) => format!("the grid statistics in {}", p.display()),
            None => "the grid statistics".into(),
        }
    }

    /// The leaves' summary the statistics give.
    pub fn leaf_summary(&self) -> crate::part_facts::LeafSummary {
        crate::part_facts::LeafSummary {
            nonzero_leaves: self.nonzero_leaves,
            nonzero_box: self.nonzero_box,
            max_value: self.max_value,
        }
    }

    /// The statistics as one line of JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).unwrap_or_default()
    }

    /// Parses a statistics file's text; a message for anything else.
    pub fn from_json(text: &str) -> Result<Self, String> {
        let s: Self = serde_json::from_str(text)
            .map_err(|e| format!("is not a grid statistics file: {e}"))?;
        if s.format != Self::FORMAT {
            return Err(format!(
                "is not a grid statistics file of this version (format '{}', expected '{}')",
                one_line(&s.format),
                Self::FORMAT
            ));
        }
        let valid_box = s
            .nonzero_box
            .is_none_or(|[lo, hi]| (0..3).all(|a| lo[a] <= hi[a]));
        if !(s.max_value.is_finite() && s.max_value >= 0.0 && s.density_scale.is_finite())
            || s.density_scale < 0.0
            || s.nonzero_leaves > s.leaves
            || !valid_box
            || (s.nonzero_leaves == 0) != s.nonzero_box.is_none()
            || (s.nonzero_leaves == 0) != (s.max_value == 0.0)
        {
            return Err("is a damaged grid statistics file (inconsistent values)".into());
        }
        Ok(s)
    }
}

/// One part of a farm bake (`pinbake bake --part I/N`): the worker keeps and sends only the
/// leaves of z-slab `index` of `count` (and a margin of one leaf each side); it decodes and
/// summarises the others, or moves past them undecoded when the grid's statistics are given
/// ([`VdbOptions::grid_stats`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VdbPart {
    pub index: u32,
    pub count: u32,
}

/// The worker's account of a part read ([`VdbPart`]). The slab boundaries are cut from the
/// topology alone (leaf layers split evenly), so every part of one bake agrees on them; the
/// summary of the leaves left out is what the parent needs for the statistics a whole read
/// computes (the non-zero box, the leaf count, the largest value), after the density scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PartStream {
    pub(super) index: u32,
    pub(super) count: u32,
    /// The slab in index z, `[lo, hi)`; `i64::MIN` and `i64::MAX` for the open ends.
    pub(super) core: (i64, i64),
    /// Leaves of the whole tree (what the worker's topology held).
    pub(super) total_leaves: u64,
    /// Leaves left out that hold a non-zero value after the density scale.
    pub(super) skipped_kept: u64,
    /// Index box of their non-zero voxels (inclusive; `lo > hi` when there are none).
    pub(super) skipped_lo: [i32; 3],
    pub(super) skipped_hi: [i32; 3],
    /// Their largest value after the density scale.
    pub(super) skipped_max: f32,
    /// Active negative values clamped to 0 in the leaves of the slab itself (not its margin)
    /// and in the tiles: a part's share of the grid's count, for the merge's checks.
    pub(super) slab_leaf_negatives: u64,
    pub(super) tile_negatives: u64,
}

pub(super) struct StreamReader<R: Read> {
    pub(super) r: R,
}

impl<R: Read> StreamReader<R> {
    pub(super) fn fill(&mut self, buf: &mut [u8]) -> Result<(), String> {
        self.r
            .read_exact(buf)
            .map_err(|_| "worker stream ended early".to_string())
    }
    pub(super) fn u8(&mut self) -> Result<u8, String> {
        let mut b = [0u8; 1];
        self.fill(&mut b)?;
        Ok(b[0])
    }
    pub(super) fn u32(&mut self) -> Result<u32, String> {
        let mut b = [0u8; 4];
        self.fill(&mut b)?;
        Ok(u32::from_le_bytes(b))
    }
    pub(super) fn u64(&mut self) -> Result<u64, String> {
        let mut b = [0u8; 8];
        self.fill(&mut b)?;
        Ok(u64::from_le_bytes(b))
    }
    pub(super) fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_bits(self.u64()?))
    }
    pub(super) fn ivec(&mut self) -> Result<[i32; 3], String> {
        let mut v = [0i32; 3];
        for c in &mut v {
            *c = self.u32()? as i32;
        }
        Ok(v)
    }
    pub(super) fn string(&mut self) -> Result<String, String> {
        let n = self.u32()? as usize;
        if n > MAX_NAME {
            return Err(format!("worker stream has a {n}-byte name"));
        }
        let mut b = vec![0u8; n];
        self.fill(&mut b)?;
        Ok(String::from_utf8_lossy(&b).into_owned())
    }
}

/// [`parse_stream_within`] without a memory limit, errors as text.
#[cfg(test)]
pub(super) fn parse_stream(r: impl Read, file_size: u64) -> Result<Stream, String> {
    parse_stream_within(r, file_size, u64::MAX, false).map_err(|e| e.to_string())
}

/// Parses the worker's stream. Counts are checked against limits derived from the file size:
/// a leaf costs at least 128 bytes in a VDB file (two 64-byte masks), a tile at least two mask
/// bits, so a stream claiming more is corrupt whatever the child says. The leaf table is
/// sized once from the worker's leaf count, and refused ([`StreamError::Budget`]) before
/// anything is allocated when it needs more than `max_bytes`. `part`: the worker was asked for
/// one part ([`VdbPart`]), so the stream carries its [`PartStream`] fields.
pub(super) fn parse_stream_within(
    r: impl Read,
    file_size: u64,
    max_bytes: u64,
    part: bool,
) -> Result<Stream, StreamError> {
    let mut s = StreamReader { r };
    let mut magic = [0u8; 8];
    s.fill(&mut magic)?;
    if &magic != STREAM_MAGIC {
        return Err("worker stream has a bad magic".into());
    }
    let n = s.u32()? as u64;
    if n == 0 || n > 4096.max(file_size / 16) {
        return Err(format!("worker stream lists {n} grids").into());
    }
    let mut grids = Vec::with_capacity(n.min(4096) as usize);
    for _ in 0..n {
        grids.push(GridInfo {
            name: s.string()?,
            grid_type: s.string()?,
            class: s.string()?,
        });
    }
    let chosen = s.u32()? as usize;
    if chosen >= grids.len() {
        return Err("worker stream chose a grid out of range".into());
    }
    let kind = ValueKind::from_u8(s.u8()?).ok_or("worker stream has a bad value kind")?;
    let level_set = match s.u8()? {
        0 => false,
        1 => true,
        _ => return Err("worker stream has a bad grid class".into()),
    };
    let mut xf = [0f64; 12];
    for v in &mut xf {
        *v = s.f64()?;
    }
    let max_leaves = file_size / 64 + 1;
    let max_tiles = file_size.saturating_mul(4) + 64;
    let announced = s.u64()?;
    if announced > max_leaves {
        return Err(format!(
            "worker stream has more than {max_leaves} leaves for a {file_size}-byte file"
        )
        .into());
    }
    let encoding = s.u8()?;
    if encoding != LEAF_F32 && encoding != LEAF_HALF {
        return Err("worker stream has a bad leaf encoding".into());
    }
    let part_head = if part {
        let index = s.u32()?;
        let count = s.u32()?;
        let lo = s.u64()? as i64;
        let hi = s.u64()? as i64;
        let total_leaves = s.u64()?;
        if count == 0 || index >= count || lo > hi || total_leaves > max_leaves {
            return Err("worker stream has a bad part record".into());
        }
        Some((index, count, (lo, hi), total_leaves))
    } else {
        None
    };
    let need = leaf_table_bytes(announced, encoding);
    if need > max_bytes {
        return Err(StreamError::Budget {
            need,
            limit: max_bytes,
        });
    }
    let n = announced as usize;
    let alloc_err = || format!("cannot allocate {need} bytes for the grid's {n} leaves");
    let mut origins: Vec<[i32; 3]> = Vec::new();
    origins.try_reserve_exact(n).map_err(|_| alloc_err())?;
    let mut leaves = if encoding == LEAF_HALF {
        let mut v = Vec::new();
        v.try_reserve_exact(n).map_err(|_| alloc_err())?;
        LeafValues::Half(v)
    } else {
        let mut v = Vec::new();
        v.try_reserve_exact(n).map_err(|_| alloc_err())?;
        LeafValues::F32(v)
    };
    let mut tiles = Vec::new();
    loop {
        match s.u8()? {
            TAG_END => break,
            TAG_LEAF => {
                if origins.len() >= n {
                    return Err(
                        format!("worker stream has more than the {n} leaves it announced").into(),
                    );
                }
                origins.push(s.ivec()?);
                // Read straight into the table's next slot (the host is little-endian).
                match &mut leaves {
                    LeafValues::Half(v) => {
                        v.push([0u16; 512]);
                        let last = v.last_mut().ok_or("no leaf slot")?;
                        s.fill(bytemuck::cast_slice_mut(last))?;
                    }
                    LeafValues::F32(v) => {
                        v.push([0f32; 512]);
                        let last = v.last_mut().ok_or("no leaf slot")?;
                        s.fill(bytemuck::cast_slice_mut(last))?;
                    }
                }
            }
            TAG_TILE => {
                if tiles.len() as u64 >= max_tiles {
                    return Err(format!(
                        "worker stream has more than {max_tiles} tiles for a {file_size}-byte file"
                    )
                    .into());
                }
                let o = s.ivec()?;
                let level = s.u8()?;
                let mut b = [0u8; 4];
                s.fill(&mut b)?;
                tiles.push((o, level, f32::from_le_bytes(b)));
            }
            t => return Err(format!("worker stream has a bad record tag {t}").into()),
        }
    }
    let active = s.u64()?;
    let negatives = s.u64()?;
    let part = match part_head {
        None => None,
        Some((index, count, core, total_leaves)) => {
            let skipped_kept = s.u64()?;
            let skipped_lo = s.ivec()?;
            let skipped_hi = s.ivec()?;
            let mut b = [0u8; 4];
            s.fill(&mut b)?;
            let skipped_max = f32::from_le_bytes(b);
            let slab_leaf_negatives = s.u64()?;
            let tile_negatives = s.u64()?;
            if skipped_kept > total_leaves
                || !(skipped_max.is_finite() && skipped_max >= 0.0)
                || slab_leaf_negatives.saturating_add(tile_negatives) > negatives
            {
                return Err("worker stream has a bad part summary".into());
            }
            Some(PartStream {
                index,
                count,
                core,
                total_leaves,
                skipped_kept,
                skipped_lo,
                skipped_hi,
                skipped_max,
                slab_leaf_negatives,
                tile_negatives,
            })
        }
    };
    s.fill(&mut magic)?;
    if &magic != STREAM_END {
        return Err("worker stream has a bad trailer".into());
    }
    if s.r.read(&mut [0u8; 1]).map_err(|e| e.to_string())? != 0 {
        return Err("worker stream has trailing bytes".into());
    }
    Ok(Stream {
        grids,
        chosen,
        kind,
        level_set,
        xf,
        origins,
        leaves,
        tiles,
        active,
        negatives,
        part,
        stats: None,
    })
}
