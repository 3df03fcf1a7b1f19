//! The worker side: the child process that reads the VDB with vdb-rs, checks what it
//! reads, and streams the chosen grid to the parent (`worker_main`).

use super::*;

/// Entry point of `pinbake __vdb-worker <file> <grid-selector> <fog|levelset-to-fog>`; `args`
/// are the arguments after the subcommand (an empty selector means the default choice).
///
/// Writes the binary description to stdout and returns 0, or writes one line to stderr and
/// returns 2. Meant to run in its own process only (see [`VdbSource::open`]); it installs a
/// silent panic hook.
pub fn worker_main(args: &[std::ffi::OsString]) -> i32 {
    // The file may be any path; the selector, mode and part come from our own command line.
    let usage = || {
        tell_parent(&format!(
            "usage: pinbake {WORKER_SUBCOMMAND} <file> <grid-selector> <fog|levelset-to-fog> [<part I/N|stats> <density-scale> [summarise|skip]]"
        ));
        2
    };
    let (file, selector, mode, part, how) = match args {
        [file, selector, mode] => (file, selector, mode, None, None),
        [file, selector, mode, part, scale] => (file, selector, mode, Some((part, scale)), None),
        [file, selector, mode, part, scale, how] => {
            (file, selector, mode, Some((part, scale)), Some(how))
        }
        _ => return usage(),
    };
    let (Some(selector), Some(mode)) = (selector.to_str(), mode.to_str()) else {
        return usage();
    };
    let part = match part {
        None => None,
        Some((part, scale)) => {
            let parsed = (|| {
                let scale = DensityScale::new(scale.to_str()?.parse().ok()?).ok()?;
                let part = part.to_str()?;
                if part == "stats" {
                    return (how.is_none()).then_some(PartRead {
                        part: VdbPart { index: 0, count: 1 },
                        scale,
                        mode: PartMode::Stats,
                    });
                }
                let (i, n) = part.split_once('/')?;
                let part = VdbPart {
                    index: i.parse().ok()?,
                    count: n.parse().ok()?,
                };
                let mode = match how.map(|h| h.to_str()) {
                    None | Some(Some("summarise")) => PartMode::Summarise,
                    Some(Some("skip")) => PartMode::Skip,
                    _ => return None,
                };
                (part.count > 0 && part.index < part.count).then_some(PartRead {
                    part,
                    scale,
                    mode,
                })
            })();
            match parsed {
                Some(p) => Some(p),
                None => return usage(),
            }
        }
    };
    std::panic::set_hook(Box::new(|_| {}));
    let to_fog = mode == "levelset-to-fog";
    let selector = (!selector.is_empty()).then_some(selector);
    let stdout = std::io::stdout();
    let mut out = BufWriter::with_capacity(1 << 20, stdout.lock());
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        worker_run(Path::new(file), selector, to_fog, part, &mut out)
    }));
    let r = match r {
        Ok(r) => r,
        Err(payload) => Err(format!(
            "could not be parsed (corrupt or unsupported file): {}",
            panic_text(&*payload)
        )),
    };
    match r.and_then(|()| {
        out.flush()
            .map_err(|e| format!("writing to the parent failed: {e}"))
    }) {
        Ok(()) => 0,
        Err(e) => {
            tell_parent(&one_line(&e));
            2
        }
    }
}

/// One line on stderr, which the parent reads as the worker's error; a stderr that cannot
/// take it loses the line, and the exit code still says what happened.
fn tell_parent(line: &str) {
    let _ = writeln!(std::io::stderr().lock(), "{line}");
}

pub(super) fn panic_text(p: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = p.downcast_ref::<&str>() {
        s.to_string()
    } else if let Some(s) = p.downcast_ref::<String>() {
        s.clone()
    } else {
        "panic".into()
    }
}

/// Scalar value types the worker can read; `to_f32` widens or narrows to the stream's f32.
pub(super) trait Val: bytemuck::Pod {
    fn to_f32(self) -> f32;
}
impl Val for f32 {
    fn to_f32(self) -> f32 {
        self
    }
}
impl Val for f64 {
    fn to_f32(self) -> f32 {
        self as f32
    }
}
/// Native half grids are read as raw bits (vdb-rs would otherwise reinterpret them).
impl Val for u16 {
    fn to_f32(self) -> f32 {
        half::f16::from_bits(self).to_f32()
    }
}

/// Little reader for the few header fields the worker checks itself, with every length
/// bounded (this runs before vdb-rs sees the file).
pub(super) struct Peek<R: Read> {
    pub(super) r: R,
}

impl<R: Read> Peek<R> {
    pub(super) fn bytes(&mut self, n: usize) -> Result<Vec<u8>, String> {
        let mut v = vec![0u8; n];
        self.r
            .read_exact(&mut v)
            .map_err(|_| "is truncated (ends inside the header)".to_string())?;
        Ok(v)
    }
    pub(super) fn u32(&mut self) -> Result<u32, String> {
        let b = self.bytes(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    pub(super) fn string(&mut self, max: usize) -> Result<String, String> {
        let n = self.u32()? as usize;
        if n > max {
            return Err(format!("has a {n}-byte name field (corrupt header)"));
        }
        Ok(String::from_utf8_lossy(&self.bytes(n)?).into_owned())
    }
}

/// Checks the magic and version and returns the version.
pub(super) fn check_header(path: &Path) -> Result<u32, String> {
    let f = std::fs::File::open(path).map_err(|e| format!("cannot open: {e}"))?;
    let mut p = Peek {
        r: BufReader::new(f),
    };
    let head = p
        .bytes(8)
        .map_err(|_| "is not an OpenVDB file (too short)".to_string())?;
    if head[..4] != [0x20, 0x42, 0x44, 0x56] {
        return Err("is not an OpenVDB file (bad magic number)".into());
    }
    let version = p.u32()?;
    if !(218..=224).contains(&version) {
        return Err(format!(
            "has OpenVDB file version {version}; this reader handles 218..=224"
        ));
    }
    Ok(version)
}

/// Bytes of a linear map's payload after its name, or `None` for a map this reader does not
/// read (the frustum map, or a name OpenVDB does not write).
pub(super) fn linear_map_payload(name: &str) -> Option<usize> {
    Some(match name {
        // Scale, voxel size, inverse scale, inverse scale squared, inverse twice scale.
        "UniformScaleMap" | "ScaleMap" => 5 * 24,
        // The same after a translation.
        "UniformScaleTranslateMap" | "ScaleTranslateMap" => 6 * 24,
        "TranslationMap" => 24,
        // One 4x4 matrix of doubles.
        "AffineMap" | "UnitaryMap" => 128,
        _ => return None,
    })
}

/// Reads a grid's transform map name and its tree's buffer count (after its compression flags
/// and metadata), so that an encoding vdb-rs would panic on becomes a message.
pub(super) fn peek_grid(
    path: &Path,
    grid_pos: u64,
    version: u32,
) -> Result<(String, Option<u32>), String> {
    use std::io::{Seek, SeekFrom};
    let mut f = std::fs::File::open(path).map_err(|e| format!("cannot open: {e}"))?;
    f.seek(SeekFrom::Start(grid_pos))
        .map_err(|e| format!("cannot seek to grid data: {e}"))?;
    let mut p = Peek {
        r: BufReader::new(f),
    };
    if version >= 222 {
        p.u32()?;
    }
    let count = p.u32()?;
    if count > 1 << 16 {
        return Err(format!("grid has {count} metadata entries (corrupt)"));
    }
    for _ in 0..count {
        p.string(1 << 16)?;
        p.string(1 << 16)?;
        let len = p.u32()? as usize;
        if len > 1 << 24 {
            return Err(format!("grid has a {len}-byte metadata value (corrupt)"));
        }
        p.bytes(len)?;
    }
    let map = p.string(1 << 10)?;
    let Some(payload) = linear_map_payload(&map) else {
        return Ok((map, None));
    };
    p.bytes(payload)?;
    Ok((map, Some(p.u32()?)))
}

pub(super) fn meta_vec3i(gd: &vdb_rs::GridDescriptor, key: &str) -> Option<glam024::IVec3> {
    match gd.meta_data.0.get(key) {
        Some(vdb_rs::MetadataValue::Vec3i(v)) => Some(*v),
        _ => None,
    }
}

pub(super) fn meta_string(gd: &vdb_rs::GridDescriptor, key: &str) -> String {
    match gd.meta_data.0.get(key) {
        Some(vdb_rs::MetadataValue::String(s)) => s.clone(),
        _ => String::new(),
    }
}

/// OpenImageIO-style plausibility checks of the recorded bounding box.
pub(super) fn check_bbox(
    name: &str,
    min: Option<glam024::IVec3>,
    max: Option<glam024::IVec3>,
) -> Result<(), String> {
    let (Some(min), Some(max)) = (min, max) else {
        return Ok(());
    };
    let (lo, hi) = (min.to_array().map(i64::from), max.to_array().map(i64::from));
    let shown = || {
        format!(
            "[{},{},{}]-[{},{},{}]",
            lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
        )
    };
    if (0..3).any(|a| hi[a] < lo[a]) {
        return Err(format!(
            "grid '{name}' has an inverted bounding box {}; contains no readable grids",
            shown()
        ));
    }
    let ext: [i64; 3] = std::array::from_fn(|a| hi[a] - lo[a] + 1);
    if ext.iter().any(|&e| e > MAX_AXIS_VOXELS) {
        return Err(format!(
            "grid '{name}' has an out-of-range bounding box {} ({}x{}x{} voxels; at most {MAX_AXIS_VOXELS} per axis). Possible corrupt input?",
            shown(),
            ext[0],
            ext[1],
            ext[2]
        ));
    }
    // No limit on the box's volume: the reader is sparse, and OpenVDB writes valid grids
    // with a few voxels 200,000 apart on every axis (see tests/vdb_corpus.rs).
    Ok(())
}

pub(super) fn worker_run(
    path: &Path,
    selector: Option<&str>,
    to_fog: bool,
    part: Option<PartRead>,
    out: &mut impl Write,
) -> Result<(), String> {
    let version = check_header(path)?;
    let file = std::fs::File::open(path).map_err(|e| format!("cannot open: {e}"))?;
    let mut reader = vdb_rs::VdbReader::new(BufReader::new(file))
        .map_err(|e| format!("could not be parsed: {}", parse_err_text(e)))?;

    // vdb-rs keeps descriptors in a HashMap: sort for stable listings and selection.
    let mut grids: Vec<GridInfo> = reader
        .grid_descriptors
        .values()
        .map(|gd| GridInfo {
            name: gd.name.clone(),
            grid_type: gd.grid_type.clone(),
            class: meta_string(gd, "class"),
        })
        .collect();
    grids.sort_by(|a, b| a.name.cmp(&b.name));
    let chosen = select_grid(&grids, selector)?;
    let info = grids[chosen].clone();
    let shown = info.display();
    let gd = reader
        .grid_descriptors
        .get(&info.name)
        .cloned()
        .ok_or("grid vanished")?;
    let kind = info.value_kind(gd.meta_data.is_half_float()).ok_or_else(|| {
        format!(
            "grid '{shown}' has type {}; only float, half and double scalar grids are supported",
            one_line(&info.grid_type)
        )
    })?;
    if !gd.instance_parent.is_empty() {
        return Err(format!(
            "grid '{shown}' is an instance of '{}', which this reader does not resolve; select that grid",
            display_name(&gd.instance_parent)
        ));
    }
    let level_set = info.class == "level set";
    if level_set && !to_fog {
        return Err(format!(
            "grid '{shown}' is a level set (signed distance), not a density; pass --levelset-to-fog to bake its interior as density 1"
        ));
    }
    check_bbox(
        &shown,
        meta_vec3i(&gd, "file_bbox_min"),
        meta_vec3i(&gd, "file_bbox_max"),
    )?;
    let (map_name, buffers) = peek_grid(path, gd.grid_pos, version)?;
    let Some(buffers) = buffers else {
        return Err(format!(
            "unsupported encoding: grid '{shown}' uses transform '{}'; only linear maps (scale, translation, affine) are supported",
            one_line(&map_name)
        ));
    };
    if buffers != 1 {
        return Err(format!(
            "unsupported encoding: grid '{shown}' has a tree with {buffers} value buffers; only single-buffer trees are supported"
        ));
    }

    // Header of the stream.
    out.write_all(STREAM_MAGIC).map_err(wr)?;
    put_u32(out, grids.len() as u32)?;
    for g in &grids {
        put_str(out, &g.name)?;
        put_str(out, &g.grid_type)?;
        put_str(out, &g.class)?;
    }
    put_u32(out, chosen as u32)?;
    put_u8(out, kind as u8)?;
    put_u8(out, u8::from(level_set))?;

    let name = info.name.as_str();
    match kind {
        ValueKind::Float | ValueKind::FloatSavedAsHalf => {
            let (mut g, mut leaves) = reader
                .read_grid_topology::<f32>(name)
                .map_err(|e| read_err(&shown, e))?;
            emit_grid(
                &mut g,
                &mut leaves,
                (kind, version, level_set),
                &shown,
                part,
                out,
            )
        }
        ValueKind::Half => {
            let (mut g, mut leaves) = reader
                .read_grid_topology::<u16>(name)
                .map_err(|e| read_err(&shown, e))?;
            emit_grid(
                &mut g,
                &mut leaves,
                (kind, version, level_set),
                &shown,
                part,
                out,
            )
        }
        ValueKind::Double => {
            let (mut g, mut leaves) = reader
                .read_grid_topology::<f64>(name)
                .map_err(|e| read_err(&shown, e))?;
            emit_grid(
                &mut g,
                &mut leaves,
                (kind, version, level_set),
                &shown,
                part,
                out,
            )
        }
        ValueKind::Fp4 | ValueKind::Fp8 | ValueKind::Fp16 | ValueKind::FpN => Err(format!(
            "grid '{shown}': no OpenVDB grid type maps to {}",
            kind.name()
        )),
    }
}

pub(super) fn read_err(grid: &str, e: vdb_rs::ParseError) -> String {
    format!("grid '{grid}' could not be read: {}", parse_err_text(e))
}

/// vdb-rs prints its I/O errors as a bare "IoError"; say what happened.
pub(super) fn parse_err_text(e: vdb_rs::ParseError) -> String {
    match e {
        vdb_rs::ParseError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            "the file is truncated (unexpected end of file)".into()
        }
        vdb_rs::ParseError::IoError(io) => format!("I/O error: {io}"),
        vdb_rs::ParseError::UnsupportedVersion(v) => format!("unsupported file version {v}"),
        other => other.to_string(),
    }
}

/// A node's bit mask (child or value mask) as stored by vdb-rs: bit `i` of word `i / 64`.
/// Out-of-range bits read as 0, so a short mask from a damaged file cannot panic.
#[derive(Clone, Copy)]
pub(super) struct Mask<'a>(pub(super) &'a [u64]);

impl Mask<'_> {
    #[inline]
    pub(super) fn get(&self, i: usize) -> bool {
        self.0.get(i / 64).is_some_and(|w| (w >> (i % 64)) & 1 == 1)
    }
    pub(super) fn count_ones(&self, n: usize) -> u64 {
        (0..n).filter(|&i| self.get(i)).count() as u64
    }
    pub(super) fn first_one(&self, n: usize) -> Option<usize> {
        (0..n).find(|&i| self.get(i))
    }
}

/// Local (x, y, z) of a linear node index (x slowest, as in OpenVDB).
pub(super) fn local(idx: usize, log2: u32) -> [i32; 3] {
    let m = (1usize << log2) - 1;
    [
        (idx >> (2 * log2)) as i32,
        ((idx >> log2) & m) as i32,
        (idx & m) as i32,
    ]
}

/// `origin + local(idx) << child_log2`, checked (origins come from the file).
pub(super) fn child_origin(
    origin: [i32; 3],
    idx: usize,
    log2: u32,
    child_log2: u32,
) -> Result<[i32; 3], String> {
    let l = local(idx, log2);
    let mut r = [0i32; 3];
    for a in 0..3 {
        r[a] = origin[a]
            .checked_add(l[a] << child_log2)
            .ok_or("node origin overflows i32 (corrupt file)")?;
    }
    Ok(r)
}

/// Values of an internal node's entries that are not children. vdb-rs stores one value per
/// entry from file version 222 on, one per non-child entry before that.
pub(super) fn tile_values<T: Val>(
    data: &[T],
    child_mask: Mask<'_>,
    n: usize,
    version: u32,
) -> Result<Vec<f32>, String> {
    let mut v = vec![0.0f32; n];
    let mut rank = 0usize;
    for (i, slot) in v.iter_mut().enumerate() {
        let child = child_mask.get(i);
        let di = if version >= 222 { i } else { rank };
        if !child {
            rank += 1;
            *slot = data
                .get(di)
                .ok_or("internal node has too few values (corrupt file)")?
                .to_f32();
        }
    }
    Ok(v)
}

/// Emits the transform, the leaf count and encoding, the leaves, tiles and the trailer.
///
/// `g` is the topology only: each leaf's values are read from `leaves` as the walk reaches
/// it (the file's order) and sent on at once, so the worker holds one leaf's values at a
/// time, not the grid's (a 1.5 G-voxel cloud would otherwise need 6 GB here).
pub(super) fn emit_grid<T: Val, R: Read + std::io::Seek>(
    g: &mut vdb_rs::Grid<T>,
    leaves: &mut vdb_rs::LeafData<'_, R>,
    (kind, version, level_set): (ValueKind, u32, bool),
    shown: &str,
    part: Option<PartRead>,
    out: &mut impl Write,
) -> Result<(), String> {
    for v in affine_rows(&g.transform, shown)? {
        put_f64(out, v)?;
    }
    let leaf_count: u64 = g
        .tree
        .root_nodes
        .iter()
        .flat_map(|n5| n5.nodes.values())
        .map(|n4| n4.nodes.len() as u64)
        .sum();
    // A part keeps the leaves whose origin lies in its slab widened by one leaf each side
    // (trilinear samples in the slab reach one voxel past it).
    let slab = match part {
        None => None,
        // The statistics pass keeps no leaf: its slab is empty.
        Some(PartRead {
            mode: PartMode::Stats,
            ..
        }) => Some((i64::MAX, i64::MAX)),
        Some(p) => Some(part_slab(g, p.part)?),
    };
    let stats_only = matches!(part, Some(p) if p.mode == PartMode::Stats);
    let keep = |o3: [i32; 3]| {
        !stats_only
            && slab.is_none_or(|(lo, hi): (i64, i64)| {
                let z = i64::from(o3[2]);
                z >= lo.saturating_sub(8) && z < hi.saturating_add(8)
            })
    };
    // A part read with the grid's statistics given (`Skip`) moves past the leaves it does
    // not keep without decompressing them; a level set's flood fill needs every leaf's
    // first and last sign, so its leaves are always decoded.
    let skip = matches!(part, Some(p) if p.mode == PartMode::Skip) && !level_set;
    // Those leaves' topology (a value mask and its node, about 160 bytes a leaf: 0.5 GB for a
    // 1.5 G-voxel cloud) is dropped before the parent allocates its leaf table, so that the
    // two never add up; only their active voxels are kept, counted here.
    let mut active: u64 = 0;
    if skip {
        active = prune_leaves(g, &keep)?;
    }
    // The parent sizes its leaf table from this count before the first leaf arrives.
    let sent_count = match slab {
        None => leaf_count,
        Some(_) => {
            let mut n = 0u64;
            for_each_leaf_origin(g, |o3| n += u64::from(keep(o3)))?;
            n
        }
    };
    put_u64(out, sent_count)?;
    // Half values travel (and are kept) as their 16 bits: every value of a half grid, a
    // float grid saved as half and a level set's 0 and 1 is exact in half.
    let half = level_set || matches!(kind, ValueKind::FloatSavedAsHalf | ValueKind::Half);
    let encoding = if half { LEAF_HALF } else { LEAF_F32 };
    put_u8(out, encoding)?;
    if let (Some(p), Some((lo, hi))) = (part, slab) {
        put_u32(out, p.part.index)?;
        put_u32(out, p.part.count)?;
        put_u64(out, lo as u64)?;
        put_u64(out, hi as u64)?;
        put_u64(out, leaf_count)?;
    }
    let mut skipped = Skipped::default();

    let mut negatives: u64 = 0;
    // A part's account of the negative values: those of the leaves of its own slab (not its
    // margin) and those of the tiles (which every part reads), for the merge's checks.
    let (mut leaf_negatives, mut slab_leaf_negatives) = (0u64, 0u64);
    let in_core = |o3: [i32; 3]| slab.is_some_and(|(lo, hi)| (lo..hi).contains(&i64::from(o3[2])));
    let mut leaf_buf = [0f32; 512];
    for n5 in &g.tree.root_nodes {
        let o5 = n5.origin.to_array();
        let c5 = Mask(n5.child_mask.as_raw_slice());
        let v5 = Mask(n5.value_mask.as_raw_slice());
        let t5 = tile_values(&n5.data, c5, 32 * 32 * 32, version)?;
        // Level sets: inside flags of each node4 child's first and last entry, for the node5
        // flood fill.
        let mut n4_first_last: HashMap<usize, (bool, bool)> = HashMap::new();
        for i5 in n5.child_mask.iter_ones() {
            let n4 = n5
                .nodes
                .get(&(i5 as u32))
                .ok_or("internal node child missing (corrupt file)")?;
            let o4 = child_origin(o5, i5, 5, 7)?;
            let c4 = Mask(n4.child_mask.as_raw_slice());
            let v4 = Mask(n4.value_mask.as_raw_slice());
            let t4 = tile_values(&n4.data, c4, 16 * 16 * 16, version)?;
            let mut leaf_first_last: HashMap<usize, (bool, bool)> = HashMap::new();
            for i4 in n4.child_mask.iter_ones() {
                let o3 = child_origin(o4, i4, 4, 3)?;
                if skip && !keep(o3) {
                    // Pruned: its active voxels are counted already.
                    leaves.skip_leaf::<T>().map_err(|e| read_err(shown, e))?;
                    continue;
                }
                let leaf = n4
                    .nodes
                    .get(&(i4 as u32))
                    .ok_or("leaf node missing (corrupt file)")?;
                let buffer: Vec<T> = leaves.next_leaf().map_err(|e| read_err(shown, e))?;
                if buffer.len() != 512 {
                    return Err(format!(
                        "leaf has {} values, expected 512 (corrupt file)",
                        buffer.len()
                    ));
                }
                let mask = Mask(leaf.value_mask.as_raw_slice());
                active += mask.count_ones(512);
                let mut any = false;
                if level_set {
                    let vals: Vec<f32> = buffer.iter().map(|v| v.to_f32()).collect();
                    let inside = leaf_inside(&vals, mask);
                    leaf_first_last.insert(i4, (inside[0], inside[511]));
                    for (o, ins) in leaf_buf.iter_mut().zip(inside.iter()) {
                        *o = if *ins { 1.0 } else { 0.0 };
                        any |= *ins;
                    }
                } else {
                    for (k, o) in leaf_buf.iter_mut().enumerate() {
                        let v = if mask.get(k) { buffer[k].to_f32() } else { 0.0 };
                        if !v.is_finite() {
                            let l = local(k, 3);
                            return Err(format!(
                                "grid '{shown}' has value {v} at voxel ({},{},{})",
                                o3[0] + l[0],
                                o3[1] + l[1],
                                o3[2] + l[2]
                            ));
                        }
                        if v < 0.0 {
                            leaf_negatives += 1;
                            slab_leaf_negatives += u64::from(in_core(o3));
                        }
                        *o = v.max(0.0);
                        any |= *o != 0.0;
                    }
                }
                if any && !keep(o3) {
                    if let Some(p) = part {
                        skipped.add(&leaf_buf, half, p.scale, o3, shown)?;
                    }
                } else if any {
                    put_u8(out, TAG_LEAF)?;
                    put_ivec(out, o3)?;
                    if half {
                        let mut bits = [0u16; 512];
                        for (b, v) in bits.iter_mut().zip(&leaf_buf) {
                            *b = half::f16::from_f32(*v).to_bits();
                        }
                        out.write_all(bytemuck::cast_slice(&bits)).map_err(wr)?;
                    } else {
                        out.write_all(bytemuck::cast_slice(&leaf_buf)).map_err(wr)?;
                    }
                }
            }
            // Node4 tiles (8^3 each).
            let inside4 = level_set.then(|| {
                internal_inside(4, c4, v4, &t4, |i| {
                    leaf_first_last.get(&i).copied().unwrap_or((false, false))
                })
            });
            if let Some(ins) = &inside4 {
                let entry = |i: usize| {
                    if c4.get(i) {
                        leaf_first_last
                            .get(&i)
                            .map(|f| if i == 0 { f.0 } else { f.1 })
                    } else {
                        Some(ins[i])
                    }
                };
                n4_first_last.insert(
                    i5,
                    (entry(0).unwrap_or(false), entry(4095).unwrap_or(false)),
                );
            }
            for i4 in 0..4096 {
                if c4.get(i4) {
                    continue;
                }
                let is_active = v4.get(i4);
                active += u64::from(is_active) * 512;
                let v = tile_density(&t4, &inside4, i4, is_active, shown, o4, 4, &mut negatives)?;
                if v != 0.0 {
                    put_u8(out, TAG_TILE)?;
                    put_ivec(out, child_origin(o4, i4, 4, 3)?)?;
                    put_u8(out, 1)?;
                    out.write_all(&v.to_le_bytes()).map_err(wr)?;
                }
            }
        }
        // Node5 tiles (128^3 each).
        let inside5 = level_set.then(|| {
            internal_inside(5, c5, v5, &t5, |i| {
                n4_first_last.get(&i).copied().unwrap_or((false, false))
            })
        });
        for i5 in 0..32768 {
            if c5.get(i5) {
                continue;
            }
            let is_active = v5.get(i5);
            active = active.saturating_add(u64::from(is_active) << 21);
            let v = tile_density(&t5, &inside5, i5, is_active, shown, o5, 5, &mut negatives)?;
            if v != 0.0 {
                put_u8(out, TAG_TILE)?;
                put_ivec(out, child_origin(o5, i5, 5, 7)?)?;
                put_u8(out, 2)?;
                out.write_all(&v.to_le_bytes()).map_err(wr)?;
            }
        }
    }
    // Root tiles (4096^3 each). A level set's signed flood fill leaves the inside ones at
    // -background, so their sign is the inside test.
    for t in &g.tree.root_tiles {
        let o = t.origin.to_array();
        if o.iter().any(|c| c & 4095 != 0) {
            return Err(format!(
                "root tile at ({},{},{}) is misaligned (corrupt file)",
                o[0], o[1], o[2]
            ));
        }
        let v = t.value.to_f32();
        active = active.saturating_add(u64::from(t.active) << 36);
        let d = if level_set {
            if v < 0.0 { 1.0 } else { 0.0 }
        } else if !t.active {
            0.0
        } else if !v.is_finite() {
            return Err(format!(
                "grid '{shown}' has value {v} in the root tile at ({},{},{})",
                o[0], o[1], o[2]
            ));
        } else {
            if v < 0.0 {
                negatives += 1;
            }
            v.max(0.0)
        };
        if d != 0.0 {
            put_u8(out, TAG_TILE)?;
            put_ivec(out, o)?;
            put_u8(out, 3)?;
            out.write_all(&d.to_le_bytes()).map_err(wr)?;
        }
    }
    if active == 0 {
        return Err(format!(
            "grid '{shown}' has no active voxels; contains no readable grids"
        ));
    }
    put_u8(out, TAG_END)?;
    put_u64(out, active)?;
    put_u64(out, negatives + leaf_negatives)?;
    if part.is_some() {
        put_u64(out, skipped.kept)?;
        put_ivec(out, skipped.lo)?;
        put_ivec(out, skipped.hi)?;
        out.write_all(&skipped.max.to_le_bytes()).map_err(wr)?;
        put_u64(out, slab_leaf_negatives)?;
        // The tiles' negative values.
        put_u64(out, negatives)?;
    }
    out.write_all(STREAM_END).map_err(wr)
}

/// How a part read treats the leaves outside its slab.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum PartMode {
    /// Decodes them and summarises them in the stream's trailer (the grid's statistics
    /// without a statistics file).
    Summarise,
    /// Moves past them undecoded: the parent has the grid's statistics from elsewhere
    /// ([`super::GridStats`]).
    Skip,
    /// Keeps no leaf and summarises every one: the statistics pass.
    Stats,
}

/// A part read as the worker's command line asks for it.
#[derive(Clone, Copy, Debug)]
pub(super) struct PartRead {
    pub(super) part: VdbPart,
    pub(super) scale: DensityScale,
    pub(super) mode: PartMode,
}

/// Removes from `g` every leaf whose origin `keep` refuses, and gives their freed memory back
/// to the system; returns how many active voxels they had. Their child bits stay set, so a
/// walk still knows where they were (and moves past their values unread).
fn prune_leaves<T>(
    g: &mut vdb_rs::Grid<T>,
    keep: &impl Fn([i32; 3]) -> bool,
) -> Result<u64, String> {
    let mut active = 0u64;
    for n5 in &mut g.tree.root_nodes {
        let o5 = n5.origin.to_array();
        for i5 in n5.child_mask.iter_ones() {
            let n4 = n5
                .nodes
                .get_mut(&(i5 as u32))
                .ok_or("internal node child missing (corrupt file)")?;
            let o4 = child_origin(o5, i5, 5, 7)?;
            for i4 in n4.child_mask.iter_ones() {
                if keep(child_origin(o4, i4, 4, 3)?) {
                    continue;
                }
                if let Some(leaf) = n4.nodes.remove(&(i4 as u32)) {
                    active += Mask(leaf.value_mask.as_raw_slice()).count_ones(512);
                }
            }
            n4.nodes.shrink_to_fit();
        }
    }
    give_back_freed_memory();
    Ok(active)
}

/// Returns the heap's free pages to the system (glibc keeps freed small blocks, such as the
/// pruned leaves' masks, in the process otherwise). Elsewhere a no-op.
fn give_back_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only releases memory the allocator holds free; it has no
    // preconditions.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Calls `f` with the origin of every leaf of `g`, in the file's order.
fn for_each_leaf_origin<T>(g: &vdb_rs::Grid<T>, mut f: impl FnMut([i32; 3])) -> Result<(), String> {
    for n5 in &g.tree.root_nodes {
        let o5 = n5.origin.to_array();
        for i5 in n5.child_mask.iter_ones() {
            let n4 = n5
                .nodes
                .get(&(i5 as u32))
                .ok_or("internal node child missing (corrupt file)")?;
            let o4 = child_origin(o5, i5, 5, 7)?;
            for i4 in n4.child_mask.iter_ones() {
                f(child_origin(o4, i4, 4, 3)?);
            }
        }
    }
    Ok(())
}

/// The index-z slab `[lo, hi)` of part `p`: whole leaf layers (8 voxels of z each), cut
/// where the count of leaves below reaches `k / count` of all leaves, so that each part holds
/// about as many leaves as the others; the first part is open below and the last above. A
/// function of the topology only, so that every part of one bake cuts the same boundaries.
fn part_slab<T>(g: &vdb_rs::Grid<T>, p: VdbPart) -> Result<(i64, i64), String> {
    let mut layers: std::collections::BTreeMap<i64, u64> = std::collections::BTreeMap::new();
    for_each_leaf_origin(g, |o| *layers.entry(i64::from(o[2])).or_default() += 1)?;
    let total: u64 = layers.values().sum();
    // Cut `k`: the first layer with at least `k * total / count` leaves below it.
    let cut = |k: u32| {
        if k == 0 {
            return i64::MIN;
        }
        if k == p.count {
            return i64::MAX;
        }
        let want = u128::from(k) * u128::from(total) / u128::from(p.count);
        let mut below = 0u128;
        for (&z, &n) in &layers {
            if below >= want {
                return z;
            }
            below += u128::from(n);
        }
        i64::MAX
    };
    if total == 0 {
        // Tiles only, which every part keeps: part 0 takes every sample.
        return Ok(if p.index == 0 {
            (i64::MIN, i64::MAX)
        } else {
            (i64::MAX, i64::MAX)
        });
    }
    Ok((cut(p.index), cut(p.index + 1)))
}

/// The statistics of the leaves a part leaves out, as the parent would compute them from
/// the values it scales ([`PartStream`]).
struct Skipped {
    kept: u64,
    lo: [i32; 3],
    hi: [i32; 3],
    max: f32,
}

impl Default for Skipped {
    fn default() -> Self {
        Self {
            kept: 0,
            lo: [i32::MAX; 3],
            hi: [i32::MIN; 3],
            max: 0.0,
        }
    }
}

impl Skipped {
    fn add(
        &mut self,
        values: &[f32; 512],
        half: bool,
        scale: DensityScale,
        o3: [i32; 3],
        shown: &str,
    ) -> Result<(), String> {
        let mut m = 0.0f32;
        for (k, &v) in values.iter().enumerate() {
            // What the parent keeps: the half pattern's value where the leaf travels as half.
            let v = if half {
                half::f16::from_f32(v).to_f32()
            } else {
                v
            };
            let l = local(k, 3);
            let at = [o3[0] + l[0], o3[1] + l[1], o3[2] + l[2]];
            let s = scale.apply(f64::from(v)).ok_or_else(|| {
                format!(
                    "grid '{shown}' value {v} at voxel ({},{},{}) times density scale {scale} overflows f32",
                    at[0], at[1], at[2]
                )
            })?;
            if s != 0.0 {
                for ((lo, hi), c) in self.lo.iter_mut().zip(&mut self.hi).zip(at) {
                    *lo = (*lo).min(c);
                    *hi = (*hi).max(c);
                }
            }
            m = m.max(s);
        }
        if m != 0.0 {
            self.kept += 1;
            self.max = self.max.max(m);
        }
        Ok(())
    }
}

/// The map as a row-major 3x4 matrix: `world = M[..3] * index + M[3]` row by row.
pub(super) fn affine_rows(map: &vdb_rs::Map, shown: &str) -> Result<[f64; 12], String> {
    let diag = |s: glam024::DVec3, t: glam024::DVec3| {
        [s.x, 0.0, 0.0, t.x, 0.0, s.y, 0.0, t.y, 0.0, 0.0, s.z, t.z]
    };
    Ok(match map {
        vdb_rs::Map::UniformScaleMap { scale_values, .. } => {
            diag(*scale_values, glam024::DVec3::ZERO)
        }
        vdb_rs::Map::ScaleTranslateMap {
            scale_values,
            translation,
            ..
        } => diag(*scale_values, *translation),
        vdb_rs::Map::TranslationMap { translation } => diag(glam024::DVec3::ONE, *translation),
        vdb_rs::Map::AffineMap { matrix } => {
            // Column-major with column vectors; the last row must be (0, 0, 0, 1).
            let row = |r: usize| matrix.row(r);
            let w = row(3);
            if w != glam024::DVec4::new(0.0, 0.0, 0.0, 1.0) {
                return Err(format!(
                    "unsupported encoding: grid '{shown}' has a projective transform matrix (last row {w}); only affine maps are supported"
                ));
            }
            let (a, b, c) = (row(0), row(1), row(2));
            [a.x, a.y, a.z, a.w, b.x, b.y, b.z, b.w, c.x, c.y, c.z, c.w]
        }
    })
}

/// Density of an internal-node tile: fog tiles count when active, level-set tiles when inside.
#[allow(clippy::too_many_arguments)]
pub(super) fn tile_density(
    values: &[f32],
    inside: &Option<Vec<bool>>,
    i: usize,
    is_active: bool,
    shown: &str,
    origin: [i32; 3],
    log2: u32,
    negatives: &mut u64,
) -> Result<f32, String> {
    if let Some(ins) = inside {
        return Ok(if ins[i] { 1.0 } else { 0.0 });
    }
    if !is_active {
        return Ok(0.0);
    }
    let v = values[i];
    if !v.is_finite() {
        let child_log2 = if log2 == 5 { 7 } else { 3 };
        let o = child_origin(origin, i, log2, child_log2)?;
        return Err(format!(
            "grid '{shown}' has value {v} in the tile at ({},{},{})",
            o[0], o[1], o[2]
        ));
    }
    if v < 0.0 {
        *negatives += 1;
    }
    Ok(v.max(0.0))
}

/// OpenVDB's signed flood fill within a leaf: inactive voxels take the sign of the last
/// active voxel seen scanning x, then y, then z.
pub(super) fn leaf_inside(vals: &[f32], mask: Mask<'_>) -> [bool; 512] {
    let mut inside = [false; 512];
    let Some(first) = mask.first_one(512) else {
        inside.fill(vals[0] < 0.0);
        return inside;
    };
    let mut x_in = vals[first] < 0.0;
    for x in 0..8 {
        let x00 = x << 6;
        if mask.get(x00) {
            x_in = vals[x00] < 0.0;
        }
        let mut y_in = x_in;
        for y in 0..8 {
            let xy0 = x00 + (y << 3);
            if mask.get(xy0) {
                y_in = vals[xy0] < 0.0;
            }
            let mut z_in = y_in;
            for z in 0..8 {
                let xyz = xy0 + z;
                if mask.get(xyz) {
                    z_in = vals[xyz] < 0.0;
                }
                inside[xyz] = z_in;
            }
        }
    }
    inside
}

/// OpenVDB's signed flood fill over an internal node: tiles between children take the sign of
/// the preceding child's last value; active tiles keep their own sign.
pub(super) fn internal_inside(
    log2: u32,
    child_mask: Mask<'_>,
    value_mask: Mask<'_>,
    values: &[f32],
    child_first_last: impl Fn(usize) -> (bool, bool),
) -> Vec<bool> {
    let dim = 1usize << log2;
    let n = dim * dim * dim;
    let mut inside = vec![false; n];
    let Some(first) = child_mask.first_one(n) else {
        for (i, slot) in inside.iter_mut().enumerate() {
            *slot = value_mask.get(i) && values[i] < 0.0;
        }
        return inside;
    };
    let mut x_in = child_first_last(first).0;
    for x in 0..dim {
        let x00 = x << (2 * log2);
        if child_mask.get(x00) {
            x_in = child_first_last(x00).1;
        }
        let mut y_in = x_in;
        for y in 0..dim {
            let xy0 = x00 + (y << log2);
            if child_mask.get(xy0) {
                y_in = child_first_last(xy0).1;
            }
            let mut z_in = y_in;
            for z in 0..dim {
                let xyz = xy0 + z;
                if child_mask.get(xyz) {
                    z_in = child_first_last(xyz).1;
                } else if value_mask.get(xyz) {
                    inside[xyz] = values[xyz] < 0.0;
                } else {
                    inside[xyz] = z_in;
                }
            }
        }
    }
    inside
}

// ---------------------------------------------------------------------------------------------
// Parent side
// ---------------------------------------------------------------------------------------------
