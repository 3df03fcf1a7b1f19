//! The parent side: `VdbSource`, the sparse 8^3-block grid the stream becomes, its dense
//! copy, and its `DensitySource` sampling and marching.

use super::*;
use crate::part_facts::{LeafSummary, PartFacts};

/// A block of 8^3 voxels: a leaf's values or a constant tile.
#[derive(Clone, Copy, Debug)]
pub(super) enum Block {
    Dense(u32),
    Const(f32),
}

/// The leaf values as the samplers read them, in the order `Block::Dense` indexes them
/// (OpenVDB's order inside a leaf: `x * 64 + y * 8 + z`).
pub(super) enum Leaves {
    /// Scaled f32 values.
    F32(Vec<[f32; 512]>),
    /// f16 bit patterns and the scaled f32 value of every pattern (a 256 KiB table): the
    /// values a scaled f32 copy would hold, bit for bit, at half its bytes.
    Half(Vec<[u16; 512]>, Box<[f32]>),
}

impl Leaves {
    pub(super) fn len(&self) -> usize {
        match self {
            Leaves::F32(v) => v.len(),
            Leaves::Half(v, _) => v.len(),
        }
    }

    pub(super) fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Voxel `k` of leaf `leaf`.
    #[inline(always)]
    pub(super) fn get(&self, leaf: usize, k: usize) -> f32 {
        match self {
            Leaves::F32(v) => v[leaf][k],
            Leaves::Half(v, lut) => lut[v[leaf][k] as usize],
        }
    }

    /// The eight corners of the cell whose lower corner is voxel `b` of leaf `leaf` (all
    /// inside the leaf), in the order x, then y, then z varying fastest-to-slowest.
    #[inline(always)]
    pub(super) fn cell(&self, leaf: usize, b: usize) -> [f32; 8] {
        const OFF: [usize; 8] = [0, 64, 8, 72, 1, 65, 9, 73];
        match self {
            Leaves::F32(v) => {
                let l = &v[leaf];
                OFF.map(|o| l[b + o])
            }
            Leaves::Half(v, lut) => {
                let l = &v[leaf];
                OFF.map(|o| lut[l[b + o] as usize])
            }
        }
    }
}

/// Every 8^3 block of the stored blocks' box, x fastest: the table [`VdbSource::block`]
/// reads instead of hashing, where it is at most [`BLOCK_INDEX_SLOTS_PER_BLOCK`] slots per
/// stored block (a compact cloud; a few blocks far apart keep the hash table alone).
pub(super) struct BlockIndex {
    lo: IVec3,
    dims: IVec3,
    slots: Vec<Option<Block>>,
}

/// See [`BlockIndex`]: 8 bytes a slot, so at most 32 bytes of index per stored block.
pub const BLOCK_INDEX_SLOTS_PER_BLOCK: u64 = 4;

impl BlockIndex {
    /// The index of `entries` (block keys and blocks), or `None` when its box would hold
    /// more than [`BLOCK_INDEX_SLOTS_PER_BLOCK`] slots per entry or cannot be allocated.
    pub(super) fn build(entries: &[(IVec3, Block)]) -> Option<Self> {
        let (mut lo, mut hi) = (IVec3::MAX, IVec3::MIN);
        for (k, _) in entries {
            lo = lo.min(*k);
            hi = hi.max(*k);
        }
        if entries.is_empty() {
            return None;
        }
        let n = (hi.as_i64vec3() - lo.as_i64vec3()) + 1;
        let count = (n.x as u64)
            .checked_mul(n.y as u64)?
            .checked_mul(n.z as u64)?;
        if count > BLOCK_INDEX_SLOTS_PER_BLOCK.saturating_mul(entries.len() as u64) {
            return None;
        }
        let mut slots = Vec::new();
        slots.try_reserve_exact(usize::try_from(count).ok()?).ok()?;
        slots.resize(count as usize, None);
        let mut ix = Self {
            lo,
            dims: n.as_ivec3(),
            slots,
        };
        for (k, b) in entries {
            let at = ix.slot(*k)?;
            ix.slots[at] = Some(*b);
        }
        Some(ix)
    }

    #[inline(always)]
    fn slot(&self, k: IVec3) -> Option<usize> {
        let r = k - self.lo;
        if r.cmplt(IVec3::ZERO).any() || r.cmpge(self.dims).any() {
            return None;
        }
        Some(
            r.x as usize
                + self.dims.x as usize * (r.y as usize + self.dims.y as usize * r.z as usize),
        )
    }

    #[inline(always)]
    pub(super) fn get(&self, k: IVec3) -> Option<Block> {
        self.slot(k).and_then(|i| self.slots[i])
    }

    pub(super) fn bytes(&self) -> u64 {
        (self.slots.len() * size_of::<Option<Block>>()) as u64
    }
}

/// A block resolved through the tree: [`VdbSource::block_at`].
#[derive(Clone, Copy, Debug)]
pub(super) enum Resolved {
    Leaf(u32),
    Const(f32),
}

/// Fast hasher for packed integer keys (the std SipHash is ~4x slower here and the keys are
/// not attacker-chosen in a way that matters: a slow file only slows its own bake).
#[derive(Default)]
pub(super) struct KeyHasher(pub(super) u64);

impl Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.write_u64(u64::from(*b));
        }
    }
    fn write_u64(&mut self, k: u64) {
        let h = (self.0 ^ k ^ (k >> 29)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        self.0 = h ^ (h >> 32);
    }
}

pub(super) type KeyMap<V> = HashMap<u64, V, BuildHasherDefault<KeyHasher>>;

/// Packs a block key relative to `base`; `None` when outside the packable range (and
/// therefore absent: every stored key is packable).
#[inline(always)]
pub(super) fn pack(k: IVec3, base: IVec3) -> Option<u64> {
    let r = k.as_i64vec3() - base.as_i64vec3();
    const LIM: i64 = 1 << 21;
    if r.x < 0 || r.y < 0 || r.z < 0 || r.x >= LIM || r.y >= LIM || r.z >= LIM {
        return None;
    }
    Some((r.x as u64) | ((r.y as u64) << 21) | ((r.z as u64) << 42))
}

/// An OpenVDB grid held sparsely: 8^3 blocks keyed by position, trilinear between voxel
/// centres at integer index coordinates.
pub struct VdbSource {
    pub(super) blocks: KeyMap<Block>,
    pub(super) block_base: IVec3,
    /// The blocks as a dense table over their box, where it is small ([`BlockIndex`]).
    pub(super) index: Option<BlockIndex>,
    /// 128^3 constant tiles keyed by `index >> 7`.
    pub(super) big: KeyMap<f32>,
    pub(super) big_base: IVec3,
    /// 4096^3 constant root tiles keyed by `index >> 12`.
    pub(super) huge: KeyMap<f32>,
    pub(super) huge_base: IVec3,
    /// Leaf values, OpenVDB order (`x * 64 + y * 8 + z`).
    pub(super) leaves: Leaves,
    pub(super) leaf_max: Vec<f32>,
    /// Index to world: `world = lin * index + translation`.
    pub(super) lin: DMat3,
    pub(super) inv_lin: DMat3,
    pub(super) translation: DVec3,
    /// `(scale, 1 / scale)` of an axis-aligned map, which keeps the per-axis arithmetic (and
    /// so the bits) of the scale-and-translate maps this reader started with.
    pub(super) diag: Option<(DVec3, DVec3)>,
    /// `lin` and `translation` as the pin format's row-major 3x4 `local_to_world`.
    pub(super) xf: [f64; 12],
    /// Index box (inclusive voxel coordinates) of the non-zero voxels.
    pub(super) index_min: IVec3,
    pub(super) index_max: IVec3,
    pub(super) bounds: Aabb,
    pub(super) global_max: f32,
    pub(super) label: String,
    /// A dense copy of the active box that the samplers read instead of the tree
    /// ([`VdbSource::with_dense_cache`]).
    pub(super) cache: Option<DenseCache>,
    /// What the worker process held at most beside this process's table while the grid
    /// was read: its tree topology (estimated per leaf, [`WORKER_BYTES_PER_LEAF`]).
    pub(super) reader_peak_bytes: u64,
    /// What the worker held at most before this process's table existed: for a part read
    /// that dropped the topology outside its slab ([`VdbOptions::grid_stats`] given), the
    /// whole tree's topology, held alone; 0 otherwise.
    pub(super) reader_alone_bytes: u64,
    /// Read for one part of a farm bake: the index-z slab `[lo, hi)` whose samples this
    /// source holds (with a margin of a leaf each side), and the non-zero leaves of the
    /// grid it does not hold, which its statistics count all the same.
    pub(super) part: Option<(i64, i64)>,
    /// A part's leaf facts for the merge's checks ([`PartFacts`]).
    pub(super) part_facts: Option<PartFacts>,
    pub(super) unloaded_leaves: u64,
}

/// The statistics a statistics pass's stream (worker mode `stats`) carries.
pub(super) fn stats_of_stream(
    st: &Stream,
    file_bytes: u64,
    file_xxh3: String,
    opt: &VdbOptions,
    scale: DensityScale,
) -> Result<GridStats, String> {
    let p = st.part.ok_or("worker sent no statistics")?;
    if !st.origins.is_empty() {
        return Err("worker sent leaves in a statistics pass".into());
    }
    let nonzero_box = (p.skipped_kept > 0).then_some([p.skipped_lo, p.skipped_hi]);
    if nonzero_box.is_some_and(|[lo, hi]| (0..3).any(|a| lo[a] > hi[a])) {
        return Err("worker sent an inverted box (corrupt stream)".into());
    }
    Ok(GridStats {
        format: GridStats::FORMAT.into(),
        file_bytes,
        file_xxh3,
        grid: st.grids[st.chosen].display(),
        levelset_to_fog: opt.levelset_to_fog,
        density_scale: scale.get(),
        leaves: p.total_leaves,
        active_voxels: st.active,
        negative_values: st.negatives,
        nonzero_leaves: p.skipped_kept,
        nonzero_box,
        max_value: p.skipped_max,
        path: None,
    })
}

/// Statistics given for a part read must be those of this file read this way.
fn check_stats_options(
    g: &GridStats,
    file_size: u64,
    opt: &VdbOptions,
    scale: DensityScale,
) -> Result<(), String> {
    let differs = |what: &str, stats: String, here: String| {
        Err(format!(
            "{} were made for {what} {stats}, this bake has {here} (make them again with the bake's options)",
            g.named()
        ))
    };
    if g.file_bytes != file_size {
        return differs(
            "a file of",
            format!("{} bytes", g.file_bytes),
            format!("{file_size} bytes"),
        );
    }
    if g.density_scale.to_bits() != scale.get().to_bits() {
        return differs(
            "density scale",
            format!("{:?}", g.density_scale),
            format!("{:?}", scale.get()),
        );
    }
    if g.levelset_to_fog != opt.levelset_to_fog {
        return differs(
            "--levelset-to-fog",
            g.levelset_to_fog.to_string(),
            opt.levelset_to_fog.to_string(),
        );
    }
    Ok(())
}

/// Where the part's slab (index z `core`, whole leaf layers) holds a z face of the
/// statistics' box, the slab's own leaves (`slab`) must reach that face, since a correct
/// box's face is a non-zero voxel of a leaf in the slab that holds it. A slab that holds the
/// box's whole z range holds every non-zero leaf: its leaves must be the statistics' exactly.
/// (The faces along x and y, and the z faces outside the slab, only the merge can check.)
fn check_stats_against_slab(
    w: &GridStats,
    core: (i64, i64),
    slab: LeafSummary,
) -> Result<(), String> {
    let Some([wlo, whi]) = w.nonzero_box else {
        return Ok(());
    };
    let in_core = |z: i32| core.0 <= i64::from(z) && i64::from(z) < core.1;
    let (slo, shi) = match slab.nonzero_box {
        Some([a, b]) => (Some(a[2]), Some(b[2])),
        None => (None, None),
    };
    let face = |name: &str, want: i32, got: Option<i32>| {
        format!(
            "put the {name} z face of the non-zero box at index z {want}, inside this part's slab, where its leaves' non-zero voxels {}",
            match got {
                Some(z) => format!("reach index z {z}"),
                None => "are none".into(),
            }
        )
    };
    if in_core(wlo[2]) && slo != Some(wlo[2]) {
        return Err(face("lower", wlo[2], slo));
    }
    if in_core(whi[2]) && shi != Some(whi[2]) {
        return Err(face("upper", whi[2], shi));
    }
    if in_core(wlo[2]) && in_core(whi[2]) && slab != w.leaf_summary() {
        return Err(format!(
            "say {}, but this part's slab holds the box's whole z range and {slab}",
            w.leaf_summary()
        ));
    }
    Ok(())
}

/// The grid statistics must describe the grid this part read: the same grid, topology
/// (leaves, active voxels) and at least what the part's own leaves hold.
fn check_stats_against_read(
    w: &GridStats,
    (grid, active, negatives, total_leaves): (&str, u64, u64, u64),
    (lo, hi): (IVec3, IVec3),
    own_max: f32,
    own_leaves: u64,
) -> Result<(), String> {
    if w.grid != grid {
        return Err(format!(
            "are for grid '{}', this part reads grid '{grid}'",
            one_line(&w.grid)
        ));
    }
    if w.leaves != total_leaves || w.active_voxels != active {
        return Err(format!(
            "do not match this file's tree ({} leaves and {} active voxels in the statistics, {total_leaves} and {active} in the file)",
            w.leaves, w.active_voxels
        ));
    }
    let inside = own_leaves == 0
        || w.nonzero_box.is_some_and(|[wlo, whi]| {
            lo.cmpge(IVec3::from_array(wlo)).all() && hi.cmple(IVec3::from_array(whi)).all()
        });
    if own_leaves > w.nonzero_leaves
        || !inside
        || own_max > w.max_value
        || negatives > w.negative_values
    {
        return Err(
            "do not match the values of this file's leaves (made from another file?)".into(),
        );
    }
    Ok(())
}

/// The worker's memory per leaf of the file: vdb-rs keeps every leaf's node (value mask,
/// origin, an empty buffer) and its hash-table slot while the values stream through.
/// Measured: 83 MB for the 539 K leaves of the 263 M-voxel cloud, about 155 bytes each.
pub const WORKER_BYTES_PER_LEAF: u64 = 160;

/// Every voxel of the index box `[lo, lo + dims)` (the active box and a border of one zero
/// voxel), x fastest: what [`VdbSource::sample_index`] reads in place of the tree.
pub(super) struct DenseCache {
    pub(super) lo: IVec3,
    pub(super) dims: IVec3,
    pub(super) stride_y: usize,
    pub(super) stride_z: usize,
    pub(super) data: Vec<f32>,
}

impl std::fmt::Debug for VdbSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.label)
    }
}

impl VdbSource {
    /// Opens `path` with the isolated worker; see the module docs. Every failure, including a
    /// crash, timeout or memory exhaustion of the worker, is a one-line [`SourceError::Vdb`].
    /// Every value is multiplied by `scale` as it is read.
    pub fn open(path: &Path, opt: &VdbOptions, scale: DensityScale) -> Result<Self, SourceError> {
        let fail = |m: String| SourceError::Vdb {
            path: path.to_path_buf(),
            message: m,
        };
        // A FIFO, device or directory is refused before the worker could block on it or
        // read it without end.
        let file_size = crate::files::check_input(path).map_err(SourceError::from_file)?;
        let stats = match (&opt.part, &opt.grid_stats) {
            (Some(_), Some(g)) => {
                check_stats_options(g, file_size, opt, scale).map_err(fail)?;
                Some(GridStats::clone(g))
            }
            _ => None,
        };
        let mut stream = Self::read_stream(path, opt, scale, file_size, false)?;
        stream.stats = stats;
        Self::from_stream(path, stream, scale).map_err(fail)
    }

    /// The whole grid's statistics ([`GridStats`]) for the parts of a farm bake with `opt`'s
    /// grid, level-set mode and density scale (its `part` and `grid_stats` are ignored): the
    /// reader decodes every leaf and sends none, so this needs the reader's memory (its
    /// topology) and not the leaf table's.
    pub fn grid_stats(
        path: &Path,
        opt: &VdbOptions,
        scale: DensityScale,
    ) -> Result<GridStats, SourceError> {
        let fail = |m: String| SourceError::Vdb {
            path: path.to_path_buf(),
            message: m,
        };
        let file_size = crate::files::check_input(path).map_err(SourceError::from_file)?;
        let file_xxh3 = crate::files::hash_file(path).map_err(SourceError::from_file)?;
        let st = Self::read_stream(path, opt, scale, file_size, true)?;
        stats_of_stream(&st, file_size, file_xxh3, opt, scale).map_err(fail)
    }

    /// Runs the worker for a read (`stats_pass`: the statistics pass) and parses its stream.
    fn read_stream(
        path: &Path,
        opt: &VdbOptions,
        scale: DensityScale,
        file_size: u64,
        stats_pass: bool,
    ) -> Result<Stream, SourceError> {
        let fail = |m: String| SourceError::Vdb {
            path: path.to_path_buf(),
            message: m,
        };
        let limit = opt
            .memory_limit
            .unwrap_or_else(|| default_memory_limit(file_size));
        // A large valid file takes a while to read: the timeout guards against a reader
        // that hangs, so it never cuts a read short that runs at a plausible rate.
        let floor = Duration::from_secs_f64(file_size as f64 / MIN_READ_BYTES_PER_S);
        let opt = VdbOptions {
            timeout: opt.timeout.max(floor),
            ..opt.clone()
        };
        let max_leaf_bytes = opt.max_leaf_bytes.unwrap_or(u64::MAX);
        match run_worker(
            path,
            &opt,
            scale,
            file_size,
            limit,
            max_leaf_bytes,
            stats_pass,
        ) {
            Ok(s) => Ok(s),
            Err(e @ StreamError::Budget { .. }) => Err(SourceError::Memory {
                path: path.to_path_buf(),
                message: e.to_string(),
            }),
            Err(StreamError::Message(m)) => Err(fail(m)),
        }
    }

    /// Bytes this grid holds in memory: its leaf values (f16 or f32), the per-leaf maximum,
    /// the block table and the dense cache if any. What [`VdbOptions::max_leaf_bytes`]
    /// bounds, and what a bake counts against its memory budget for the source.
    pub fn memory_bytes(&self) -> u64 {
        let leaves = self.leaves.len() as u64;
        let values = match &self.leaves {
            Leaves::F32(_) => leaves * 2048,
            Leaves::Half(_, lut) => leaves * 1024 + (lut.len() * 4) as u64,
        };
        let tables = (self.blocks.capacity() + self.big.capacity() + self.huge.capacity()) as u64
            * 24
            + (self.leaf_max.capacity() * 4) as u64;
        let cache = self.cache.as_ref().map_or(0, |c| (c.data.len() * 4) as u64);
        let index = self.index.as_ref().map_or(0, BlockIndex::bytes);
        values + tables + cache + index
    }

    pub(crate) fn from_stream(
        path: &Path,
        st: Stream,
        scale: DensityScale,
    ) -> Result<Self, String> {
        let grid = st.grids[st.chosen].display();
        let x = st.xf;
        let lin = DMat3::from_cols_array(&[x[0], x[4], x[8], x[1], x[5], x[9], x[2], x[6], x[10]]);
        let translation = DVec3::new(x[3], x[7], x[11]);
        let inv_lin = lin.inverse();
        if !(x.iter().all(|v| v.is_finite())
            && lin.determinant() != 0.0
            && inv_lin.is_finite()
            && inv_lin.determinant() != 0.0)
        {
            return Err(format!(
                "grid '{grid}' has a degenerate transform (index to world {:?})",
                st.xf
            ));
        }
        let off_diagonal = [x[1], x[2], x[4], x[6], x[8], x[9]];
        let diag = off_diagonal.iter().all(|v| *v == 0.0).then(|| {
            let s = DVec3::new(x[0], x[5], x[10]);
            (s, s.recip())
        });
        let mut blocks: KeyMap<Block> = KeyMap::default();
        let mut big: KeyMap<f32> = KeyMap::default();
        let mut huge: KeyMap<f32> = KeyMap::default();
        let mut leaf_max = Vec::new();
        let mut lo = IVec3::MAX;
        let mut hi = IVec3::MIN;
        let mut global_max = 0.0f32;
        let check = |v: f32, at: IVec3| -> Result<f32, String> {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("worker sent value {v} at ({at}) (corrupt stream)"));
            }
            scale.apply(v as f64).ok_or_else(|| {
                format!(
                    "grid '{grid}' value {v} at voxel ({},{},{}) times density scale {scale} overflows f32",
                    at.x, at.y, at.z
                )
            })
        };
        // Keys are collected first so they can be packed relative to their minimum.
        let mut entries: Vec<(IVec3, Block)> =
            Vec::with_capacity(st.origins.len() + st.tiles.len());
        let mut big_entries: Vec<(IVec3, f32)> = Vec::new();
        let mut huge_entries: Vec<(IVec3, f32)> = Vec::new();
        // Scaled in place (f32 leaves) or through a table of the 65536 half patterns (half
        // leaves, which keep their bits: the same values as scaling each one, at half the
        // bytes); leaves left all zero are dropped by compacting the table in place, so that
        // no second copy of the leaves ever exists.
        let origins = st.origins;
        let origins_len = origins.len();
        let mut values = st.leaves;
        let lut: Option<Box<[f32]>> = match &values {
            LeafValues::Half(_) => Some(
                (0..=u16::MAX)
                    .map(|b| {
                        let v = half::f16::from_bits(b).to_f32();
                        if v.is_finite() && v >= 0.0 {
                            scale.apply(v as f64).unwrap_or(f32::NAN)
                        } else {
                            f32::NAN
                        }
                    })
                    .collect(),
            ),
            LeafValues::F32(_) => None,
        };
        let mut kept = 0usize;
        // The kept leaves' summary, and that of those in the part's own slab (not its margin).
        let core = st.part.map(|p| p.core);
        let (mut own, mut in_slab) = (LeafSummary::EMPTY, LeafSummary::EMPTY);
        for (i, o) in origins.iter().enumerate() {
            let o = IVec3::from_array(*o);
            if (o & 7) != IVec3::ZERO {
                return Err(format!("worker sent a misaligned leaf at {o}"));
            }
            let mut m = 0.0f32;
            let (mut llo, mut lhi) = (IVec3::MAX, IVec3::MIN);
            let mut note = |k: usize, s: f32| {
                if s != 0.0 {
                    let at = o + IVec3::from_array(local(k, 3));
                    llo = llo.min(at);
                    lhi = lhi.max(at);
                }
                m = m.max(s);
            };
            match (&mut values, &lut) {
                (LeafValues::F32(v), _) => {
                    for (k, x) in v[i].iter_mut().enumerate() {
                        let s = check(*x, o + IVec3::from_array(local(k, 3)))?;
                        note(k, s);
                        *x = s;
                    }
                    v.swap(kept, i);
                }
                (LeafValues::Half(v), Some(lut)) => {
                    for (k, b) in v[i].iter().enumerate() {
                        let s = lut[*b as usize];
                        if s.is_nan() {
                            // The same message as scaling the value itself would give.
                            let raw = half::f16::from_bits(*b).to_f32();
                            check(raw, o + IVec3::from_array(local(k, 3)))?;
                        }
                        note(k, s);
                    }
                    v.swap(kept, i);
                }
                (LeafValues::Half(_), None) => unreachable!("half leaves always have a table"),
            }
            if m == 0.0 {
                continue;
            }
            lo = lo.min(llo);
            hi = hi.max(lhi);
            let leaf = LeafSummary {
                nonzero_leaves: 1,
                nonzero_box: Some([llo.to_array(), lhi.to_array()]),
                max_value: m,
            };
            own = own.union(leaf);
            if core.is_none_or(|(a, b)| a <= i64::from(o.z) && i64::from(o.z) < b) {
                in_slab = in_slab.union(leaf);
            }
            global_max = global_max.max(m);
            entries.push((o >> 3, Block::Dense(kept as u32)));
            leaf_max.push(m);
            kept += 1;
        }
        drop(origins);
        // A part that moved past the leaves outside its slab counts them from the grid's
        // statistics, after checking that its own leaves agree with them.
        if let (Some(w), Some(p)) = (&st.stats, &st.part) {
            let read = (grid.as_str(), st.active, st.negatives, p.total_leaves);
            check_stats_against_read(w, read, (lo, hi), global_max, kept as u64)
                .and_then(|()| check_stats_against_slab(w, p.core, in_slab))
                .map_err(|e| format!("{} {e}", w.named()))?;
            if let Some([wlo, whi]) = w.nonzero_box {
                lo = lo.min(IVec3::from_array(wlo));
                hi = hi.max(IVec3::from_array(whi));
            }
            global_max = global_max.max(w.max_value);
        }
        let leaves = match (values, lut) {
            (LeafValues::F32(mut v), _) => {
                v.truncate(kept);
                v.shrink_to_fit();
                Leaves::F32(v)
            }
            (LeafValues::Half(mut v), Some(lut)) => {
                v.truncate(kept);
                v.shrink_to_fit();
                Leaves::Half(v, lut)
            }
            (LeafValues::Half(_), None) => unreachable!("half leaves always have a table"),
        };
        for (o, level, v) in &st.tiles {
            let o = IVec3::from_array(*o);
            let s = check(*v, o)?;
            if s == 0.0 {
                continue;
            }
            global_max = global_max.max(s);
            let size = match level {
                1 => 8,
                2 => 128,
                3 => 4096,
                _ => return Err("worker sent a tile of unknown size".into()),
            };
            if (o & (size - 1)) != IVec3::ZERO {
                return Err(format!("worker sent a misaligned tile at {o}"));
            }
            lo = lo.min(o);
            hi = hi.max(o + (size - 1));
            match size {
                8 => entries.push((o >> 3, Block::Const(s))),
                128 => big_entries.push((o >> 7, s)),
                _ => huge_entries.push((o >> 12, s)),
            }
        }
        // A part read with the statistics given moves past the other leaves and drops their
        // topology first (a level set's part decodes every leaf and keeps it).
        let pruned = st.part.is_some() && st.stats.is_some() && !st.level_set;
        // A part's statistics are those of the whole grid: the leaves the worker left out
        // count as a whole read would count them.
        let unloaded_leaves = match (&st.stats, st.part) {
            (Some(w), Some(_)) => w.nonzero_leaves - kept as u64,
            (None, p) => p.map_or(0, |p| p.skipped_kept),
            (Some(_), None) => 0,
        };
        if let Some(p) = st.part
            && st.stats.is_none()
            && p.skipped_kept > 0
        {
            lo = lo.min(IVec3::from_array(p.skipped_lo));
            hi = hi.max(IVec3::from_array(p.skipped_hi));
            global_max = global_max.max(p.skipped_max);
        }
        if leaves.is_empty()
            && unloaded_leaves == 0
            && entries.is_empty()
            && big_entries.is_empty()
            && huge_entries.is_empty()
        {
            return Err(format!(
                "grid '{grid}' has {} active voxels but all are zero{}",
                st.active,
                if scale.get() == 0.0 {
                    " (density scale 0)"
                } else {
                    ""
                }
            ));
        }
        let span = (hi.as_i64vec3() - lo.as_i64vec3()).max_element() + 1;
        if span > MAX_AXIS_VOXELS {
            return Err(format!(
                "grid '{grid}' spans {span} voxels along an axis; at most {MAX_AXIS_VOXELS} are supported. Possible corrupt input?"
            ));
        }
        let block_base = lo >> 3;
        let index = BlockIndex::build(&entries);
        for (k, b) in entries {
            let key = pack(k, block_base).ok_or("block key out of range")?;
            if blocks.insert(key, b).is_some() {
                return Err(format!("worker sent two blocks at {}", k * 8));
            }
        }
        let big_base = lo >> 7;
        for (k, v) in big_entries {
            let key = pack(k, big_base).ok_or("tile key out of range")?;
            if big.insert(key, v).is_some() {
                return Err(format!("worker sent two tiles at {}", k * 128));
            }
        }
        let huge_base = lo >> 12;
        for (k, v) in huge_entries {
            let key = pack(k, huge_base).ok_or("tile key out of range")?;
            if huge.insert(key, v).is_some() {
                return Err(format!("worker sent two root tiles at {}", k * 4096));
            }
        }

        // Trilinear support reaches one voxel beyond the outermost non-zero centre.
        let to_world = |i: DVec3| match diag {
            Some((s, _)) => i * s + translation,
            None => lin * i + translation,
        };
        let (ilo, ihi) = ((lo - 1).as_dvec3(), (hi + 1).as_dvec3());
        let mut bounds = Aabb::new(DVec3::INFINITY, DVec3::NEG_INFINITY);
        for c in 0..8 {
            let i = DVec3::select(
                glam::BVec3::new(c & 1 != 0, c & 2 != 0, c & 4 != 0),
                ihi,
                ilo,
            );
            let w = to_world(i);
            bounds = Aabb::new(bounds.min.min(w), bounds.max.max(w));
        }
        // A transform with an absurd translation or scale (found by fuzzing: a translation
        // of -1.7e277) maps the grid to a box that f64 cannot resolve: its extent rounds to
        // zero or overflows. Nothing downstream can place pins in such a box.
        if !bounds.is_valid() || !bounds.extent().is_finite() {
            return Err(format!(
                "grid '{grid}' has an unusable index-to-world transform ({:?}): its world box is empty or not finite",
                st.xf
            ));
        }
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let mut label = format!(
            "vdb {} grid '{grid}' ({}{}), {} leaves, {} tiles, voxel size {}",
            one_line(&name),
            st.kind.name(),
            if st.level_set {
                ", level set to fog"
            } else {
                ""
            },
            leaves.len() as u64 + unloaded_leaves,
            blocks.len() - leaves.len() + big.len() + huge.len(),
            match diag {
                Some((s, _)) => s.to_string(),
                None => format!("{:?} (affine)", st.xf),
            },
        );
        let negatives = match (&st.stats, st.part) {
            (Some(w), Some(_)) => w.negative_values,
            _ => st.negatives,
        };
        // The grid's leaves as this part baked them: the statistics', or its own and the
        // summary of those it decoded and left out.
        let part_facts = st.part.map(|p| PartFacts {
            grid: match &st.stats {
                Some(w) => w.leaf_summary(),
                None => own.union(LeafSummary {
                    nonzero_leaves: p.skipped_kept,
                    nonzero_box: (p.skipped_kept > 0).then_some([p.skipped_lo, p.skipped_hi]),
                    max_value: p.skipped_max,
                }),
            },
            negative_values: negatives,
            slab: in_slab,
            slab_negative_values: p.slab_leaf_negatives,
            tile_negative_values: p.tile_negatives,
        });
        if negatives > 0 {
            label.push_str(&format!(", {negatives} negative values clamped to 0"));
        }
        Ok(Self {
            blocks,
            block_base,
            index,
            big,
            big_base,
            huge,
            huge_base,
            leaves,
            leaf_max,
            lin,
            inv_lin,
            translation,
            diag,
            xf: st.xf,
            index_min: lo,
            index_max: hi,
            bounds,
            global_max,
            label,
            cache: None,
            reader_peak_bytes: if pruned {
                // The worker dropped the other leaves' topology before the first leaf came.
                origins_len as u64
            } else {
                st.part.map_or(origins_len as u64, |p| p.total_leaves)
            }
            .saturating_mul(WORKER_BYTES_PER_LEAF),
            reader_alone_bytes: if pruned {
                st.part
                    .map_or(0, |p| p.total_leaves)
                    .saturating_mul(WORKER_BYTES_PER_LEAF)
            } else {
                0
            },
            part: st.part.map(|p| p.core),
            part_facts,
            unloaded_leaves,
        })
    }

    /// Names the reader that built this source at the head of its description ("vdb" for
    /// the OpenVDB worker, "nanovdb" for the NanoVDB reader).
    pub(crate) fn set_reader_label(&mut self, reader: &str) {
        if let Some(rest) = self.label.strip_prefix("vdb ") {
            self.label = format!("{reader} {rest}");
        }
    }

    /// World position of index-space point `i` (voxel centres are at integers).
    pub fn index_to_world(&self, i: DVec3) -> DVec3 {
        match self.diag {
            Some((s, _)) => i * s + self.translation,
            None => self.lin * i + self.translation,
        }
    }

    /// Index-space position of world point `p`.
    #[inline]
    pub fn world_to_index(&self, p: DVec3) -> DVec3 {
        match self.diag {
            Some((_, inv)) => (p - self.translation) * inv,
            None => self.inv_lin * (p - self.translation),
        }
    }

    /// The index-to-world map as a row-major 3x4 matrix (the pin format's `local_to_world`).
    pub fn index_to_world_matrix(&self) -> [f64; 12] {
        self.xf
    }

    /// True when the map only scales and translates each axis (no rotation or shear): the
    /// index box is then a world-space box.
    pub fn is_axis_aligned(&self) -> bool {
        self.diag.is_some()
    }

    /// Largest value that trilinear sampling can return in the index-space box `[a, b]`.
    pub(super) fn max_in_index_box(&self, a: DVec3, b: DVec3) -> f32 {
        // Voxels within one voxel of the region influence it.
        let ilo = (a.floor() - 1.0).max(self.index_min.as_dvec3()).as_ivec3();
        let ihi = (b.ceil() + 1.0).min(self.index_max.as_dvec3()).as_ivec3();
        if !ilo.cmple(ihi).all() {
            return 0.0;
        }
        let (klo, khi): (IVec3, IVec3) = (ilo >> 3, ihi >> 3);
        let n_keys = (khi.as_i64vec3() - klo.as_i64vec3()) + 1;
        let n_keys = n_keys.x * n_keys.y * n_keys.z;
        let block_max = |b: &Block| match *b {
            Block::Dense(l) => self.leaf_max[l as usize],
            Block::Const(v) => v,
        };
        let mut m = 0.0f32;
        if n_keys as usize <= self.blocks.len() {
            for z in klo.z..=khi.z {
                for y in klo.y..=khi.y {
                    for x in klo.x..=khi.x {
                        if let Some(b) = self.block(IVec3::new(x, y, z)) {
                            m = m.max(block_max(&b));
                        }
                    }
                }
            }
        } else {
            let lim = (1u64 << 21) - 1;
            for (k, b) in &self.blocks {
                let key = IVec3::new(
                    (k & lim) as i32,
                    ((k >> 21) & lim) as i32,
                    ((k >> 42) & lim) as i32,
                ) + self.block_base;
                if key.cmpge(klo).all() && key.cmple(khi).all() {
                    m = m.max(block_max(b));
                }
            }
        }
        if m < self.global_max {
            let (blo, bhi): (IVec3, IVec3) = (ilo >> 7, ihi >> 7);
            let lim = (1u64 << 21) - 1;
            for (k, v) in &self.big {
                let key = IVec3::new(
                    (k & lim) as i32,
                    ((k >> 21) & lim) as i32,
                    ((k >> 42) & lim) as i32,
                ) + self.big_base;
                if key.cmpge(blo).all() && key.cmple(bhi).all() {
                    m = m.max(*v);
                }
            }
            let (hlo, hhi): (IVec3, IVec3) = (ilo >> 12, ihi >> 12);
            for (k, v) in &self.huge {
                let key = IVec3::new(
                    (k & lim) as i32,
                    ((k >> 21) & lim) as i32,
                    ((k >> 42) & lim) as i32,
                ) + self.huge_base;
                if key.cmpge(hlo).all() && key.cmple(hhi).all() {
                    m = m.max(*v);
                }
            }
        }
        m
    }

    /// The grid as a [`DenseGrid`] with the same values and the same trilinear field, for a
    /// bake that marches it with [`DenseGrid::march_runs`] instead of walking the tree per
    /// sample; `None` for a rotated or sheared map (its voxels are not boxes of the bake
    /// frame), an empty grid, a copy of more than `max_bytes` bytes (or one that cannot be
    /// allocated), or a copy that would be mostly zeros (more than twice the
    /// [`Self::stored_voxels`]: a cloud in its box, a few leaves far apart), which the bake
    /// marches through the tree instead.
    ///
    /// The copy holds every voxel centre the trilinear field reaches, one beyond the stored
    /// ones on each side: those are zero, so the dense grid's clamp-to-edge outer half voxel
    /// reads zero where this source does, and its box covers [`Density::bounds`]. A
    /// mirrored axis (negative scale) is stored reversed, so that the copy's index grows with
    /// world position. Values at voxel centres are bit-identical; between them the two
    /// samplers interpolate the same corners with the same f32 weights formula, but compute
    /// the continuous index with different f64 roundings (`(p - t) / s` against
    /// `p / s - o / s - 0.5`), so a sample can differ by a few ulps (docs/performance.md).
    pub fn dense_copy(&self, max_bytes: u64) -> Option<DenseGrid> {
        let (lo, n, mirrored, lattice) = self.dense_box()?;
        let count = (n.x as u64)
            .checked_mul(n.y as u64)?
            .checked_mul(n.z as u64)?;
        if count.checked_mul(4)? > max_bytes || self.stored_voxels() < count / 2 {
            return None;
        }
        let data = self.dense_values(lo, n, 0..n.z as usize, mirrored)?;
        DenseGrid::new(
            lattice.dims,
            data,
            lattice.spacing,
            lattice.origin,
            format!("dense copy of {}", self.label),
        )
        .ok()
    }

    /// The index box [`Self::dense_copy`] copies, whatever the budget: its lower corner, its
    /// voxels per axis, its mirrored axes and its lattice; `None` for a rotated or sheared map
    /// or an empty grid.
    fn dense_box(&self) -> Option<(IVec3, glam::I64Vec3, [bool; 3], DenseLattice)> {
        let (scale, _) = self.diag?;
        if !self.index_min.cmple(self.index_max).all() {
            return None;
        }
        let (lo, hi) = (self.index_min - 1, self.index_max + 1);
        let n = (hi.as_i64vec3() - lo.as_i64vec3()) + 1;
        if n.max_element() > i64::from(u32::MAX) {
            return None;
        }
        // Copy index j along an axis is index `lo + j`, or `hi - j` where the map mirrors it.
        let mirrored = [0, 1, 2].map(|a| scale[a] < 0.0);
        let corner = (lo.as_dvec3() - 0.5) * scale;
        let far = (hi.as_dvec3() + 0.5) * scale;
        let origin = corner.min(far) + self.translation;
        let dims = [n.x as u32, n.y as u32, n.z as u32];
        Some((
            lo,
            n,
            mirrored,
            DenseLattice::new(dims, scale.abs(), origin),
        ))
    }

    /// [`DensitySource::dense_lattice`]: the lattice of [`Self::dense_copy`].
    pub fn dense_lattice(&self) -> Option<DenseLattice> {
        self.dense_box().map(|b| b.3)
    }

    /// [`DensitySource::dense_planes`]: planes `[z_begin, z_end)` of [`Self::dense_copy`].
    pub fn dense_planes(&self, z_begin: u32, z_end: u32) -> Option<Vec<f32>> {
        let (lo, n, mirrored, _) = self.dense_box()?;
        if z_begin >= z_end || i64::from(z_end) > n.z {
            return None;
        }
        self.dense_values(lo, n, z_begin as usize..z_end as usize, mirrored)
    }

    /// The index-z slab of a part read ([`VdbOptions::part`]) with infinite open ends.
    pub(super) fn part_index_slab(&self) -> Option<(f64, f64)> {
        let f = |z: i64| match z {
            i64::MIN => f64::NEG_INFINITY,
            i64::MAX => f64::INFINITY,
            z => z as f64,
        };
        self.part.map(|(a, b)| (f(a), f(b)))
    }

    /// The largest value of each stored leaf, one per leaf (a part read holds its slab's
    /// leaves and a margin only).
    pub fn leaf_maxima(&self) -> &[f32] {
        &self.leaf_max
    }

    /// Voxels the tree stores values for: its leaves' and its constant tiles' (a dense copy
    /// holding more than twice this would be mostly zeros).
    pub fn stored_voxels(&self) -> u64 {
        let consts = self.blocks.len() - self.leaves.len();
        ((self.leaves.len() + consts) as u64 + self.unloaded_leaves)
            .saturating_mul(512)
            .saturating_add((self.big.len() as u64) << 21)
            .saturating_add((self.huge.len() as u64).saturating_mul(1 << 36))
    }

    /// The voxels of planes `zs` of the index box at `lo` with `n` voxels per axis, x
    /// fastest; an axis with `mirrored` set runs from the box's top down. `None` if the
    /// memory cannot be had.
    pub(super) fn dense_values(
        &self,
        lo: IVec3,
        n: glam::I64Vec3,
        zs: std::ops::Range<usize>,
        mirrored: [bool; 3],
    ) -> Option<Vec<f32>> {
        use rayon::prelude::*;
        let count = usize::try_from(n.x as u64)
            .ok()?
            .checked_mul(usize::try_from(n.y as u64).ok()?)?
            .checked_mul(zs.len())?;
        let mut data: Vec<f32> = Vec::new();
        data.try_reserve_exact(count).ok()?;
        data.resize(count, 0.0);
        let (nx, ny) = (n.x as usize, n.y as usize);
        let top = lo + (n - 1).as_ivec3();
        let at = |a: usize, j: usize| {
            if mirrored[a] {
                top[a] - j as i32
            } else {
                lo[a] + j as i32
            }
        };
        data.par_chunks_mut(nx * ny)
            .enumerate()
            .for_each(|(z, slab)| {
                let iz = at(2, zs.start + z);
                for (y, row) in slab.chunks_mut(nx).enumerate() {
                    let iy = at(1, y);
                    for (x, v) in row.iter_mut().enumerate() {
                        *v = self.voxel(IVec3::new(at(0, x), iy, iz));
                    }
                }
            });
        Some(data)
    }

    /// This grid with a dense copy of its active box (plus a border of one zero voxel) that
    /// every sampler reads instead of the tree, when the copy takes at most `max_bytes`
    /// (unchanged otherwise, and for an empty grid). The samples are bit-identical with or
    /// without it: the same index arithmetic, corners and interpolation, only the corner
    /// loads come from one array instead of hash lookups. For renderers, whose trackers
    /// sample the density one point at a time (the bake marches [`Self::dense_copy`]).
    pub fn with_dense_cache(mut self, max_bytes: u64) -> Self {
        if !self.index_min.cmple(self.index_max).all() {
            return self;
        }
        let lo = self.index_min - 1;
        let n = (self.index_max.as_i64vec3() - lo.as_i64vec3()) + 2;
        let fits = (n.x as u64)
            .checked_mul(n.y as u64)
            .and_then(|c| c.checked_mul(n.z as u64))
            .is_some_and(|c| c.saturating_mul(4) <= max_bytes);
        if !fits {
            return self;
        }
        if n.max_element() > i64::from(i32::MAX) {
            return self;
        }
        if let Some(data) = self.dense_values(lo, n, 0..n.z as usize, [false; 3]) {
            self.cache = Some(DenseCache {
                lo,
                dims: n.as_ivec3(),
                stride_y: n.x as usize,
                stride_z: (n.x * n.y) as usize,
                data,
            });
        }
        self
    }

    /// True when [`Self::with_dense_cache`] made a copy.
    pub fn has_dense_cache(&self) -> bool {
        self.cache.is_some()
    }

    /// Inclusive index box of the non-zero voxels.
    pub fn index_bounds(&self) -> (IVec3, IVec3) {
        (self.index_min, self.index_max)
    }

    /// Value of one voxel (0 where nothing is stored).
    #[inline]
    pub fn voxel(&self, i: IVec3) -> f32 {
        if let Some(b) = self.block(i >> 3) {
            return match b {
                Block::Dense(l) => {
                    let l8 = i & 7;
                    self.leaves
                        .get(l as usize, ((l8.x << 6) | (l8.y << 3) | l8.z) as usize)
                }
                Block::Const(v) => v,
            };
        }
        if !self.big.is_empty()
            && let Some(v) = pack(i >> 7, self.big_base).and_then(|k| self.big.get(&k))
        {
            return *v;
        }
        if self.huge.is_empty() {
            return 0.0;
        }
        pack(i >> 12, self.huge_base)
            .and_then(|k| self.huge.get(&k).copied())
            .unwrap_or(0.0)
    }

    #[inline]
    pub(super) fn sample_index(&self, u: DVec3) -> f32 {
        let f = u.floor();
        let i = f.as_ivec3();
        let t = (u - f).as_vec3();
        let l = i & 7;
        let c: [f32; 8] = if let Some(cache) = &self.cache {
            // The cell's lower corner relative to the copy; a cell not wholly inside it has
            // only zero voxels (the border and beyond), as the tree would say.
            let r = i.as_i64vec3() - cache.lo.as_i64vec3();
            if r.cmplt(glam::I64Vec3::ZERO).any() || r.cmpge((cache.dims - 1).as_i64vec3()).any() {
                return 0.0;
            }
            let (sy, sz) = (cache.stride_y, cache.stride_z);
            let b = r.x as usize + r.y as usize * sy + r.z as usize * sz;
            let d = &cache.data[b..=b + 1 + sy + sz];
            [
                d[0],
                d[1],
                d[sy],
                d[sy + 1],
                d[sz],
                d[sz + 1],
                d[sz + sy],
                d[sz + sy + 1],
            ]
        } else if l.x < 7 && l.y < 7 && l.z < 7 {
            // All eight corners in one block: one lookup.
            match self.block(i >> 3) {
                Some(Block::Dense(li)) => {
                    let b = ((l.x << 6) | (l.y << 3) | l.z) as usize;
                    self.leaves.cell(li as usize, b)
                }
                Some(Block::Const(v)) => [v; 8],
                None if self.big.is_empty() && self.huge.is_empty() => return 0.0,
                None => self.corners(i),
            }
        } else {
            self.corners(i)
        };
        let c00 = c[0] + (c[1] - c[0]) * t.x;
        let c10 = c[2] + (c[3] - c[2]) * t.x;
        let c01 = c[4] + (c[5] - c[4]) * t.x;
        let c11 = c[6] + (c[7] - c[6]) * t.x;
        let c0 = c00 + (c10 - c00) * t.y;
        let c1 = c01 + (c11 - c01) * t.y;
        (c0 + (c1 - c0) * t.z).max(0.0)
    }

    /// Corner values in the order (x, then y, then z varying fastest-to-slowest). The
    /// eight corners lie in one to eight blocks; each block is looked up once (a cell on a
    /// leaf's face touches two, where eight [`Self::voxel`] calls made eight lookups).
    pub(super) fn corners(&self, i: IVec3) -> [f32; 8] {
        let l = i & 7;
        let k = i >> 3;
        // Along each axis the corners stay in block `k` unless the cell starts on the
        // block's last voxel.
        let span = |a: i32| if a == 7 { 2 } else { 1 };
        let mut c = [0f32; 8];
        for bz in 0..span(l.z) {
            for by in 0..span(l.y) {
                for bx in 0..span(l.x) {
                    let b = IVec3::new(bx, by, bz);
                    let block = self.block_at(k + b);
                    for (n, v) in c.iter_mut().enumerate() {
                        let d = IVec3::new((n & 1) as i32, ((n >> 1) & 1) as i32, (n >> 2) as i32);
                        let at = l + d;
                        if (at >> 3) == b {
                            *v = match block {
                                Resolved::Leaf(li) => {
                                    let a = at & 7;
                                    self.leaves
                                        .get(li as usize, ((a.x << 6) | (a.y << 3) | a.z) as usize)
                                }
                                Resolved::Const(v) => v,
                            };
                        }
                    }
                }
            }
        }
        c
    }

    /// The stored 8^3 block `k` (voxel index `>> 3`), if any: one load from the dense block
    /// index where there is one, else a hash lookup.
    #[inline(always)]
    pub(super) fn block(&self, k: IVec3) -> Option<Block> {
        match &self.index {
            Some(ix) => ix.get(k),
            None => pack(k, self.block_base).and_then(|key| self.blocks.get(&key).copied()),
        }
    }

    /// What covers the 8^3 block `k` (voxel index `>> 3`): a leaf, or a constant (a tile's
    /// value, 0 where nothing is stored).
    #[inline]
    pub(super) fn block_at(&self, k: IVec3) -> Resolved {
        if let Some(b) = self.block(k) {
            return match b {
                Block::Dense(l) => Resolved::Leaf(l),
                Block::Const(v) => Resolved::Const(v),
            };
        }
        if !self.big.is_empty()
            && let Some(v) = pack(k >> 4, self.big_base).and_then(|key| self.big.get(&key))
        {
            return Resolved::Const(*v);
        }
        if self.huge.is_empty() {
            return Resolved::Const(0.0);
        }
        Resolved::Const(
            pack(k >> 9, self.huge_base)
                .and_then(|key| self.huge.get(&key).copied())
                .unwrap_or(0.0),
        )
    }
}

impl Density for VdbSource {
    fn bounds(&self) -> Aabb {
        self.bounds
    }

    #[inline]
    fn extinction(&self, p: DVec3) -> f32 {
        // The box test also keeps the index conversion in i32 range and rejects NaN.
        if !(p.cmpge(self.bounds.min).all() && p.cmple(self.bounds.max).all()) {
            return 0.0;
        }
        self.sample_index(self.world_to_index(p))
    }

    fn max_extinction_in(&self, region: Aabb) -> f32 {
        let lo = region.min.max(self.bounds.min);
        let hi = region.max.min(self.bounds.max);
        if !lo.cmple(hi).all() {
            return 0.0;
        }
        // The index box around the region's corners (for an axis-aligned map, the images of
        // `lo` and `hi`).
        let (mut a, mut b) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for c in 0..8 {
            let p = DVec3::select(glam::BVec3::new(c & 1 != 0, c & 2 != 0, c & 4 != 0), hi, lo);
            let i = self.world_to_index(p);
            a = a.min(i);
            b = b.max(i);
        }
        self.max_in_index_box(a, b)
    }
}

impl DensitySource for VdbSource {
    fn describe(&self) -> String {
        self.label.clone()
    }
    fn extinction_along(&self, origin: DVec3, step: DVec3, n: usize, out: &mut [f32]) {
        for (i, o) in out.iter_mut().take(n).enumerate() {
            let p = origin + step * i as f64;
            *o = if p.cmpge(self.bounds.min).all() && p.cmple(self.bounds.max).all() {
                self.sample_index(self.world_to_index(p))
            } else {
                0.0
            };
        }
    }

    fn occupied_bounds(&self) -> Option<Aabb> {
        Some(self.bounds)
    }

    fn voxel_size(&self) -> Option<DVec3> {
        // The world length of one index step per axis; a negative scale mirrors the grid and
        // the voxel is as large either way.
        Some(match self.diag {
            Some((s, _)) => s.abs(),
            None => DVec3::new(
                self.lin.x_axis.length(),
                self.lin.y_axis.length(),
                self.lin.z_axis.length(),
            ),
        })
    }

    fn solid_boxes(&self, floor: f32) -> Vec<Aabb> {
        // Axis-aligned maps only: a rotated tile's box is not a box of the world's axes.
        // A part read answers for its slab only.
        let Some((scale, _)) = self.diag.filter(|_| self.part.is_none()) else {
            return Vec::new();
        };
        let lim = (1u64 << 21) - 1;
        let unpack = |k: u64, base: IVec3| {
            IVec3::new(
                (k & lim) as i32,
                ((k >> 21) & lim) as i32,
                ((k >> 42) & lim) as i32,
            ) + base
        };
        let tiles = (self
            .big
            .iter()
            .map(|(k, v)| (unpack(*k, self.big_base) << 7, 128, *v)))
        .chain(
            self.huge
                .iter()
                .map(|(k, v)| (unpack(*k, self.huge_base) << 12, 4096, *v)),
        );
        tiles
            .filter(|&(_, _, v)| v >= floor)
            .filter_map(|(origin, size, _): (IVec3, i32, f32)| {
                // Trilinear sampling reads the voxel centres around a point: inside the
                // tile's centres less one voxel on each side, every one it reads is the
                // tile's.
                let lo = (origin + 1).as_dvec3();
                let hi = (origin + (size - 2)).as_dvec3();
                let (a, b) = (lo * scale + self.translation, hi * scale + self.translation);
                let b = Aabb::new(a.min(b), a.max(b));
                b.is_valid().then_some(b)
            })
            .collect()
    }

    fn bake_frame(&self) -> Option<(Box<dyn DensitySource + '_>, [f64; 12])> {
        // Axis-aligned grids keep baking in world space, as they always have.
        let (frame, local_to_world) = GridFrame::new(self)?;
        Some((Box::new(frame), local_to_world))
    }

    fn dense_copy(&self, max_bytes: u64) -> Option<DenseGrid> {
        VdbSource::dense_copy(self, max_bytes)
    }

    fn dense_lattice(&self) -> Option<DenseLattice> {
        VdbSource::dense_lattice(self)
    }

    fn dense_planes(&self, z_begin: u32, z_end: u32) -> Option<Vec<f32>> {
        VdbSource::dense_planes(self, z_begin, z_end)
    }

    fn part_slab(&self) -> Option<[f64; 2]> {
        // World z of index z per axis (a rotated grid answers through its GridFrame).
        let (scale, _) = self.diag?;
        let (a, b) = self.part_index_slab()?;
        let (a, b) = (
            a * scale.z + self.translation.z,
            b * scale.z + self.translation.z,
        );
        Some([a.min(b), a.max(b)])
    }

    fn part_facts(&self) -> Option<PartFacts> {
        self.part_facts
    }

    fn footprint(&self) -> Option<super::super::Footprint> {
        let held = self.memory_bytes();
        Some(super::super::Footprint {
            held,
            while_opening: held
                .saturating_add(self.reader_peak_bytes)
                .max(self.reader_alone_bytes),
        })
    }

    fn dense_copy_size(&self) -> Option<u64> {
        self.diag?;
        let n = (self.index_max.as_i64vec3() - self.index_min.as_i64vec3()) + 3;
        let count = (n.x as u64)
            .checked_mul(n.y as u64)?
            .checked_mul(n.z as u64)?;
        (self.stored_voxels() >= count / 2).then(|| count.saturating_mul(4))
    }
}

/// A rotated or sheared grid in its own frame, which is where the baker works on it: the
/// index axes, turned into world units. With `index_to_world = Q R + t` (QR decomposition of
/// the linear part: `Q` orthonormal, `R` upper triangular), local = `R index`, and the rigid
/// `[Q | t]` places the result. Index space itself would not do: pins store optical depth,
/// and a non-uniform scale or shear makes a unit of index length a direction-dependent world
/// length; a rigid placement keeps lengths, so local extinction is world extinction.
///
/// For a rotation times a per-axis scale, `R` is that scale and the pin box is exactly the
/// grid's index box scaled; for a shear it is the box around the sheared index box.
pub(super) struct GridFrame<'a> {
    pub(super) grid: &'a VdbSource,
    /// Local to index (`R^-1`).
    pub(super) to_index: DMat3,
    /// The local box: `R` applied to the index box.
    pub(super) bounds: Aabb,
}

impl<'a> GridFrame<'a> {
    /// The frame and its `local_to_world` (row-major 3x4), or `None` when the map is
    /// axis-aligned or degenerate.
    pub(super) fn new(grid: &'a VdbSource) -> Option<(Self, [f64; 12])> {
        if grid.diag.is_some() {
            return None;
        }
        // Gram-Schmidt on the columns of the linear part (the image of each index axis).
        let m = grid.lin;
        let q0 = m.x_axis.normalize();
        let q1 = (m.y_axis - q0 * q0.dot(m.y_axis)).normalize();
        let q2 = (m.z_axis - q0 * q0.dot(m.z_axis) - q1 * q1.dot(m.z_axis)).normalize();
        let q = DMat3::from_cols(q0, q1, q2);
        let r = q.transpose() * m;
        let to_index = r.inverse();
        if !(q.is_finite() && to_index.is_finite()) {
            return None;
        }
        let (lo, hi) = (
            (grid.index_min - 1).as_dvec3(),
            (grid.index_max + 1).as_dvec3(),
        );
        let (mut a, mut b) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for c in 0..8 {
            let i = DVec3::select(glam::BVec3::new(c & 1 != 0, c & 2 != 0, c & 4 != 0), hi, lo);
            let l = r * i;
            a = a.min(l);
            b = b.max(l);
        }
        let t = grid.translation;
        let xf = [
            q.x_axis.x, q.y_axis.x, q.z_axis.x, t.x, q.x_axis.y, q.y_axis.y, q.z_axis.y, t.y,
            q.x_axis.z, q.y_axis.z, q.z_axis.z, t.z,
        ];
        Some((
            Self {
                grid,
                to_index,
                bounds: Aabb::new(a, b),
            },
            xf,
        ))
    }

    pub(super) fn index_inside(&self, u: DVec3) -> bool {
        let g = self.grid;
        u.cmpge((g.index_min - 1).as_dvec3()).all() && u.cmple((g.index_max + 1).as_dvec3()).all()
    }
}

impl Density for GridFrame<'_> {
    fn bounds(&self) -> Aabb {
        self.bounds
    }

    fn extinction(&self, p: DVec3) -> f32 {
        if !(p.cmpge(self.bounds.min).all() && p.cmple(self.bounds.max).all()) {
            return 0.0;
        }
        let u = self.to_index * p;
        if !self.index_inside(u) {
            return 0.0;
        }
        self.grid.sample_index(u)
    }

    fn max_extinction_in(&self, region: Aabb) -> f32 {
        let lo = region.min.max(self.bounds.min);
        let hi = region.max.min(self.bounds.max);
        if !lo.cmple(hi).all() {
            return 0.0;
        }
        let (mut a, mut b) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for c in 0..8 {
            let p = DVec3::select(glam::BVec3::new(c & 1 != 0, c & 2 != 0, c & 4 != 0), hi, lo);
            let u = self.to_index * p;
            a = a.min(u);
            b = b.max(u);
        }
        self.grid.max_in_index_box(a, b)
    }
}

impl DensitySource for GridFrame<'_> {
    fn describe(&self) -> String {
        format!("{}, baked in the grid's own frame", self.grid.label)
    }

    fn occupied_bounds(&self) -> Option<Aabb> {
        Some(self.bounds)
    }

    fn part_slab(&self) -> Option<[f64; 2]> {
        // Local z is `R index` with `R` upper triangular: index z times its last diagonal
        // entry (the other two entries of that row are zero up to rounding, which the
        // leaf of margin absorbs).
        let (a, b) = self.grid.part_index_slab()?;
        let r22 = 1.0 / self.to_index.z_axis.z;
        let (a, b) = (a * r22, b * r22);
        Some([a.min(b), a.max(b)])
    }

    fn part_facts(&self) -> Option<PartFacts> {
        self.grid.part_facts
    }
}
