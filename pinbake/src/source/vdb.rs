//! OpenVDB float, half and double grids, read through vdb-rs in an isolated child process.
//!
//! # Why a child process
//!
//! vdb-rs 0.6 reads every valid file we have, but on damaged input it panics in many places
//! and can abort the whole process on huge allocations (which `catch_unwind` cannot stop). A bad
//! file must be an error, never a dead baker, so the parse runs in `pinbake __vdb-worker` under
//! an address-space limit (64 MiB + 64 x the file size, at most 16 GiB) and a wall-clock
//! timeout, with `catch_unwind` inside as well. The worker checks what vdb-rs does not (the
//! magic, the file version, the grid's transform type, the `file_bbox_*` metadata against
//! absurd or inverted boxes) before handing the file to vdb-rs, then streams a compact binary
//! description to stdout: the grid list, the chosen grid's transform, and its non-empty leaf
//! nodes (origin + 512 values) and constant tiles. The parent re-validates every count and
//! value in that stream and builds a sparse table, never a dense grid.
//!
//! # Placement and sampling
//!
//! Voxel centres sit at integer index coordinates; world = M index + t for every linear map
//! OpenVDB writes (`UniformScaleMap`, `ScaleMap`, `UniformScaleTranslateMap`,
//! `ScaleTranslateMap`, `TranslationMap`, `AffineMap`, `UnitaryMap`; the frustum map is an
//! "unsupported encoding"). Axis-aligned maps keep the per-axis arithmetic and bake in world
//! space; a rotated or sheared grid bakes in its own frame and the pin file records the
//! placement (see [`DensitySource::bake_frame`] and `GridFrame`). Sampling is trilinear
//! between voxel centres. Fog volumes: inactive voxels and tiles are 0 whatever value they
//! hold (an inactive value is not density), active values below 0 are clamped to 0.
//!
//! # Grid selection
//!
//! `VdbOptions::grid`: an exact name; `name#k` for the k-th of repeated names (OpenVDB stores
//! them as `name\x1ek`); a repeated name on its own is an error listing the choices. Without a
//! name: `density`, else the only float grid, else an error listing the grids (sorted).
//!
//! # Level sets
//!
//! Refused unless `levelset_to_fog`, which maps the interior (negative distance) to density 1.
//! vdb-rs loses the background value and the sign of inactive values, so the worker rebuilds
//! the inside/outside classification with OpenVDB's signed flood fill over leaves and internal
//! nodes; root tiles (kept by our vdb-rs patch) are inside when negative. See docs/vdb.md for
//! every vdb-rs problem this module works around and the patches in vendor/vdb-rs.
//!
//! Not for: vector, integer or point grids; multi-grid compositing; writing VDB files.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use glam::{DMat3, DVec3, IVec3};

use super::{
    Aabb, DenseGrid, DensityScale, DensitySource, Mip, MipAllocError, SourceError, one_line,
};

/// The hidden subcommand the `pinbake` binary dispatches to [`worker_main`].
pub const WORKER_SUBCOMMAND: &str = super::VDB_WORKER_SUBCOMMAND;

/// The first thing every executable that opens a VDB does (the worker is this executable run
/// again with [`WORKER_SUBCOMMAND`]): with `args` (all of `args_os`, the program name first)
/// naming the subcommand, it serves the read and returns the exit code; otherwise `None`.
pub fn serve_vdb_worker_if_asked(args: &[std::ffi::OsString]) -> Option<std::process::ExitCode> {
    if args.get(1).is_some_and(|a| a == WORKER_SUBCOMMAND) {
        let code = worker_main(&args[2..]).clamp(0, 255) as u8;
        return Some(std::process::ExitCode::from(code));
    }
    None
}

const STREAM_MAGIC: &[u8; 8] = b"PBVDBW01";
const STREAM_END: &[u8; 8] = b"PBVDBEND";
const TAG_END: u8 = 0;
const TAG_LEAF: u8 = 1;
const TAG_TILE: u8 = 2;
const MAX_NAME: usize = 1024;
/// Largest accepted extent of a grid, per axis, in voxels (OpenImageIO uses the same).
pub const MAX_AXIS_VOXELS: i64 = 1 << 20;
const MIB: u64 = 1 << 20;

/// How to open a VDB file.
#[derive(Clone, Debug, PartialEq)]
pub struct VdbOptions {
    /// Grid to read (see the module docs); `None` picks `density` or the only float grid.
    pub grid: Option<String>,
    /// Accept a level set and bake its interior (negative distance) as density 1.
    pub levelset_to_fog: bool,
    /// Multiplier applied to every value (finite, `>= 0`).
    pub density_scale: f64,
    /// Executable that understands `__vdb-worker` (normally the `pinbake` binary itself).
    pub worker_exe: PathBuf,
    /// Address-space limit of the worker in bytes; `None`: 64 MiB + 64 x file size, <= 16 GiB.
    pub memory_limit: Option<u64>,
    /// Wall-clock limit of the worker.
    pub timeout: Duration,
}

impl Default for VdbOptions {
    fn default() -> Self {
        Self {
            grid: None,
            levelset_to_fog: false,
            density_scale: 1.0,
            worker_exe: std::env::current_exe().unwrap_or_else(|_| PathBuf::from("pinbake")),
            memory_limit: None,
            timeout: Duration::from_secs(60),
        }
    }
}

impl VdbOptions {
    /// Options with defaults and the given worker executable.
    pub fn with_worker(worker_exe: impl Into<PathBuf>) -> Self {
        Self {
            worker_exe: worker_exe.into(),
            ..Self::default()
        }
    }
}

/// The default memory limit of the worker for a file of `file_size` bytes.
pub fn default_memory_limit(file_size: u64) -> u64 {
    (64 * MIB)
        .saturating_add(file_size.saturating_mul(64))
        .min(16 << 30)
}

// ---------------------------------------------------------------------------------------------
// Child side
// ---------------------------------------------------------------------------------------------

/// Entry point of `pinbake __vdb-worker <file> <grid-selector> <fog|levelset-to-fog>`; `args`
/// are the arguments after the subcommand (an empty selector means the default choice).
///
/// Writes the binary description to stdout and returns 0, or writes one line to stderr and
/// returns 2. Meant to run in its own process only (see [`VdbSource::open`]); it installs a
/// silent panic hook.
pub fn worker_main(args: &[std::ffi::OsString]) -> i32 {
    // The file may be any path; the selector and mode come from our own command line.
    let [file, selector, mode] = args else {
        crate::errln!(
            "usage: pinbake {WORKER_SUBCOMMAND} <file> <grid-selector> <fog|levelset-to-fog>"
        );
        return 2;
    };
    let (Some(selector), Some(mode)) = (selector.to_str(), mode.to_str()) else {
        crate::errln!(
            "usage: pinbake {WORKER_SUBCOMMAND} <file> <grid-selector> <fog|levelset-to-fog>"
        );
        return 2;
    };
    std::panic::set_hook(Box::new(|_| {}));
    let to_fog = mode == "levelset-to-fog";
    let selector = (!selector.is_empty()).then_some(selector);
    let stdout = std::io::stdout();
    let mut out = BufWriter::with_capacity(1 << 20, stdout.lock());
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        worker_run(Path::new(file), selector, to_fog, &mut out)
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
            crate::errln!("{}", one_line(&e));
            2
        }
    }
}

fn panic_text(p: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = p.downcast_ref::<&str>() {
        s.to_string()
    } else if let Some(s) = p.downcast_ref::<String>() {
        s.clone()
    } else {
        "panic".into()
    }
}

/// Scalar value types the worker can read; `to_f32` widens or narrows to the stream's f32.
trait Val: bytemuck::Pod {
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

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum ValueKind {
    Float = 0,
    FloatSavedAsHalf = 1,
    Half = 2,
    Double = 3,
}

impl ValueKind {
    fn from_u8(v: u8) -> Option<Self> {
        Some(match v {
            0 => Self::Float,
            1 => Self::FloatSavedAsHalf,
            2 => Self::Half,
            3 => Self::Double,
            _ => return None,
        })
    }
    fn name(self) -> &'static str {
        match self {
            Self::Float => "float",
            Self::FloatSavedAsHalf => "float saved as half",
            Self::Half => "half",
            Self::Double => "double",
        }
    }
}

/// The part of a grid descriptor the worker needs, independent of vdb-rs types.
#[derive(Clone, Debug)]
struct GridInfo {
    /// Descriptor name as stored (repeated names carry `\x1e<n>`).
    name: String,
    grid_type: String,
    class: String,
}

impl GridInfo {
    fn display(&self) -> String {
        display_name(&self.name)
    }
    fn value_kind(&self, half_meta: bool) -> Option<ValueKind> {
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
    fn is_scalar_float(&self) -> bool {
        self.value_kind(false).is_some()
    }
}

/// `density\x1e1` is shown (and selected) as `density#1`.
fn display_name(name: &str) -> String {
    one_line(name)
}

/// Picks the grid per the rules in the module docs. `grids` must be sorted by name.
fn select_grid(grids: &[GridInfo], selector: Option<&str>) -> Result<usize, String> {
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

/// Little reader for the few header fields the worker checks itself, with every length
/// bounded (this runs before vdb-rs sees the file).
struct Peek<R: Read> {
    r: R,
}

impl<R: Read> Peek<R> {
    fn bytes(&mut self, n: usize) -> Result<Vec<u8>, String> {
        let mut v = vec![0u8; n];
        self.r
            .read_exact(&mut v)
            .map_err(|_| "is truncated (ends inside the header)".to_string())?;
        Ok(v)
    }
    fn u32(&mut self) -> Result<u32, String> {
        let b = self.bytes(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn string(&mut self, max: usize) -> Result<String, String> {
        let n = self.u32()? as usize;
        if n > max {
            return Err(format!("has a {n}-byte name field (corrupt header)"));
        }
        Ok(String::from_utf8_lossy(&self.bytes(n)?).into_owned())
    }
}

/// Checks the magic and version and returns the version.
fn check_header(path: &Path) -> Result<u32, String> {
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
fn linear_map_payload(name: &str) -> Option<usize> {
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
fn peek_grid(path: &Path, grid_pos: u64, version: u32) -> Result<(String, Option<u32>), String> {
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

fn meta_vec3i(gd: &vdb_rs::GridDescriptor, key: &str) -> Option<glam024::IVec3> {
    match gd.meta_data.0.get(key) {
        Some(vdb_rs::MetadataValue::Vec3i(v)) => Some(*v),
        _ => None,
    }
}

fn meta_string(gd: &vdb_rs::GridDescriptor, key: &str) -> String {
    match gd.meta_data.0.get(key) {
        Some(vdb_rs::MetadataValue::String(s)) => s.clone(),
        _ => String::new(),
    }
}

/// OpenImageIO-style plausibility checks of the recorded bounding box.
fn check_bbox(
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

fn worker_run(
    path: &Path,
    selector: Option<&str>,
    to_fog: bool,
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
            let g = reader
                .read_grid::<f32>(name)
                .map_err(|e| read_err(&shown, e))?;
            emit_grid(&g, version, level_set, &shown, out)
        }
        ValueKind::Half => {
            let g = reader
                .read_grid::<u16>(name)
                .map_err(|e| read_err(&shown, e))?;
            emit_grid(&g, version, level_set, &shown, out)
        }
        ValueKind::Double => {
            let g = reader
                .read_grid::<f64>(name)
                .map_err(|e| read_err(&shown, e))?;
            emit_grid(&g, version, level_set, &shown, out)
        }
    }
}

fn read_err(grid: &str, e: vdb_rs::ParseError) -> String {
    format!("grid '{grid}' could not be read: {}", parse_err_text(e))
}

/// vdb-rs prints its I/O errors as a bare "IoError"; say what happened.
fn parse_err_text(e: vdb_rs::ParseError) -> String {
    match e {
        vdb_rs::ParseError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            "the file is truncated (unexpected end of file)".into()
        }
        vdb_rs::ParseError::IoError(io) => format!("I/O error: {io}"),
        vdb_rs::ParseError::UnsupportedVersion(v) => format!("unsupported file version {v}"),
        other => other.to_string(),
    }
}

fn wr(e: std::io::Error) -> String {
    format!("writing to the parent failed: {e}")
}
fn put_u8(o: &mut impl Write, v: u8) -> Result<(), String> {
    o.write_all(&[v]).map_err(wr)
}
fn put_u32(o: &mut impl Write, v: u32) -> Result<(), String> {
    o.write_all(&v.to_le_bytes()).map_err(wr)
}
fn put_u64(o: &mut impl Write, v: u64) -> Result<(), String> {
    o.write_all(&v.to_le_bytes()).map_err(wr)
}
fn put_f64(o: &mut impl Write, v: f64) -> Result<(), String> {
    o.write_all(&v.to_le_bytes()).map_err(wr)
}
fn put_ivec(o: &mut impl Write, v: [i32; 3]) -> Result<(), String> {
    for c in v {
        o.write_all(&c.to_le_bytes()).map_err(wr)?;
    }
    Ok(())
}
fn put_str(o: &mut impl Write, s: &str) -> Result<(), String> {
    let mut end = s.len().min(MAX_NAME);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    put_u32(o, end as u32)?;
    o.write_all(&s.as_bytes()[..end]).map_err(wr)
}

/// A node's bit mask (child or value mask) as stored by vdb-rs: bit `i` of word `i / 64`.
/// Out-of-range bits read as 0, so a short mask from a damaged file cannot panic.
#[derive(Clone, Copy)]
struct Mask<'a>(&'a [u64]);

impl Mask<'_> {
    #[inline]
    fn get(&self, i: usize) -> bool {
        self.0.get(i / 64).is_some_and(|w| (w >> (i % 64)) & 1 == 1)
    }
    fn count_ones(&self, n: usize) -> u64 {
        (0..n).filter(|&i| self.get(i)).count() as u64
    }
    fn first_one(&self, n: usize) -> Option<usize> {
        (0..n).find(|&i| self.get(i))
    }
}

/// Local (x, y, z) of a linear node index (x slowest, as in OpenVDB).
fn local(idx: usize, log2: u32) -> [i32; 3] {
    let m = (1usize << log2) - 1;
    [
        (idx >> (2 * log2)) as i32,
        ((idx >> log2) & m) as i32,
        (idx & m) as i32,
    ]
}

/// `origin + local(idx) << child_log2`, checked (origins come from the file).
fn child_origin(
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
fn tile_values<T: Val>(
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

/// Emits the transform, leaves, tiles and the trailer.
fn emit_grid<T: Val>(
    g: &vdb_rs::Grid<T>,
    version: u32,
    level_set: bool,
    shown: &str,
    out: &mut impl Write,
) -> Result<(), String> {
    for v in affine_rows(&g.transform, shown)? {
        put_f64(out, v)?;
    }

    let mut active: u64 = 0;
    let mut negatives: u64 = 0;
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
                let leaf = n4
                    .nodes
                    .get(&(i4 as u32))
                    .ok_or("leaf node missing (corrupt file)")?;
                if leaf.buffer.len() != 512 {
                    return Err(format!(
                        "leaf has {} values, expected 512 (corrupt file)",
                        leaf.buffer.len()
                    ));
                }
                let o3 = child_origin(o4, i4, 4, 3)?;
                let mask = Mask(leaf.value_mask.as_raw_slice());
                active += mask.count_ones(512);
                let mut any = false;
                if level_set {
                    let vals: Vec<f32> = leaf.buffer.iter().map(|v| v.to_f32()).collect();
                    let inside = leaf_inside(&vals, mask);
                    leaf_first_last.insert(i4, (inside[0], inside[511]));
                    for (o, ins) in leaf_buf.iter_mut().zip(inside.iter()) {
                        *o = if *ins { 1.0 } else { 0.0 };
                        any |= *ins;
                    }
                } else {
                    for (k, o) in leaf_buf.iter_mut().enumerate() {
                        let v = if mask.get(k) {
                            leaf.buffer[k].to_f32()
                        } else {
                            0.0
                        };
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
                            negatives += 1;
                        }
                        *o = v.max(0.0);
                        any |= *o != 0.0;
                    }
                }
                if any {
                    put_u8(out, TAG_LEAF)?;
                    put_ivec(out, o3)?;
                    let bytes: &[u8] = bytemuck::cast_slice(&leaf_buf);
                    out.write_all(bytes).map_err(wr)?;
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
    put_u64(out, negatives)?;
    out.write_all(STREAM_END).map_err(wr)
}

/// The map as a row-major 3x4 matrix: `world = M[..3] * index + M[3]` row by row.
fn affine_rows(map: &vdb_rs::Map, shown: &str) -> Result<[f64; 12], String> {
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
fn tile_density(
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
fn leaf_inside(vals: &[f32], mask: Mask<'_>) -> [bool; 512] {
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
fn internal_inside(
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

/// A block of 8^3 voxels: a leaf's values or a constant tile.
#[derive(Clone, Copy, Debug)]
enum Block {
    Dense(u32),
    Const(f32),
}

/// Fast hasher for packed integer keys (the std SipHash is ~4x slower here and the keys are
/// not attacker-chosen in a way that matters: a slow file only slows its own bake).
#[derive(Default)]
struct KeyHasher(u64);

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

type KeyMap<V> = HashMap<u64, V, BuildHasherDefault<KeyHasher>>;

/// Packs a block key relative to `base`; `None` when outside the packable range (and
/// therefore absent: every stored key is packable).
#[inline(always)]
fn pack(k: IVec3, base: IVec3) -> Option<u64> {
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
    blocks: KeyMap<Block>,
    block_base: IVec3,
    /// 128^3 constant tiles keyed by `index >> 7`.
    big: KeyMap<f32>,
    big_base: IVec3,
    /// 4096^3 constant root tiles keyed by `index >> 12`.
    huge: KeyMap<f32>,
    huge_base: IVec3,
    /// Leaf values, OpenVDB order (`x * 64 + y * 8 + z`).
    leaves: Vec<[f32; 512]>,
    leaf_max: Vec<f32>,
    /// Index to world: `world = lin * index + translation`.
    lin: DMat3,
    inv_lin: DMat3,
    translation: DVec3,
    /// `(scale, 1 / scale)` of an axis-aligned map, which keeps the per-axis arithmetic (and
    /// so the bits) of the scale-and-translate maps this reader started with.
    diag: Option<(DVec3, DVec3)>,
    /// `lin` and `translation` as the pin format's row-major 3x4 `local_to_world`.
    xf: [f64; 12],
    /// Index box (inclusive voxel coordinates) of the non-zero voxels.
    index_min: IVec3,
    index_max: IVec3,
    bounds: Aabb,
    global_max: f32,
    label: String,
    /// A dense copy of the active box that the samplers read instead of the tree
    /// ([`VdbSource::with_dense_cache`]).
    cache: Option<DenseCache>,
}

/// Every voxel of the index box `[lo, lo + dims)` (the active box and a border of one zero
/// voxel), x fastest: what [`VdbSource::sample_index`] reads in place of the tree.
struct DenseCache {
    lo: IVec3,
    dims: IVec3,
    stride_y: usize,
    stride_z: usize,
    data: Vec<f32>,
}

impl std::fmt::Debug for VdbSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.label)
    }
}

/// The parsed worker stream, before densities are scaled.
struct Stream {
    grids: Vec<GridInfo>,
    chosen: usize,
    kind: ValueKind,
    level_set: bool,
    /// Index to world, row-major 3x4.
    xf: [f64; 12],
    leaves: Vec<([i32; 3], [f32; 512])>,
    tiles: Vec<([i32; 3], u8, f32)>,
    active: u64,
    negatives: u64,
}

struct StreamReader<R: Read> {
    r: R,
}

impl<R: Read> StreamReader<R> {
    fn fill(&mut self, buf: &mut [u8]) -> Result<(), String> {
        self.r
            .read_exact(buf)
            .map_err(|_| "worker stream ended early".to_string())
    }
    fn u8(&mut self) -> Result<u8, String> {
        let mut b = [0u8; 1];
        self.fill(&mut b)?;
        Ok(b[0])
    }
    fn u32(&mut self) -> Result<u32, String> {
        let mut b = [0u8; 4];
        self.fill(&mut b)?;
        Ok(u32::from_le_bytes(b))
    }
    fn u64(&mut self) -> Result<u64, String> {
        let mut b = [0u8; 8];
        self.fill(&mut b)?;
        Ok(u64::from_le_bytes(b))
    }
    fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_bits(self.u64()?))
    }
    fn ivec(&mut self) -> Result<[i32; 3], String> {
        let mut v = [0i32; 3];
        for c in &mut v {
            *c = self.u32()? as i32;
        }
        Ok(v)
    }
    fn string(&mut self) -> Result<String, String> {
        let n = self.u32()? as usize;
        if n > MAX_NAME {
            return Err(format!("worker stream has a {n}-byte name"));
        }
        let mut b = vec![0u8; n];
        self.fill(&mut b)?;
        Ok(String::from_utf8_lossy(&b).into_owned())
    }
}

/// Parses the worker's stream. Counts are checked against limits derived from the file size:
/// a leaf costs at least 128 bytes in a VDB file (two 64-byte masks), a tile at least two mask
/// bits, so a stream claiming more is corrupt whatever the child says.
fn parse_stream(r: impl Read, file_size: u64) -> Result<Stream, String> {
    let mut s = StreamReader { r };
    let mut magic = [0u8; 8];
    s.fill(&mut magic)?;
    if &magic != STREAM_MAGIC {
        return Err("worker stream has a bad magic".into());
    }
    let n = s.u32()? as u64;
    if n == 0 || n > 4096.max(file_size / 16) {
        return Err(format!("worker stream lists {n} grids"));
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
    let mut leaves = Vec::new();
    let mut tiles = Vec::new();
    loop {
        match s.u8()? {
            TAG_END => break,
            TAG_LEAF => {
                if leaves.len() as u64 >= max_leaves {
                    return Err(format!(
                        "worker stream has more than {max_leaves} leaves for a {file_size}-byte file"
                    ));
                }
                let o = s.ivec()?;
                let mut bytes = [0u8; 2048];
                s.fill(&mut bytes)?;
                let mut vals = [0f32; 512];
                for (v, b) in vals.iter_mut().zip(bytes.chunks_exact(4)) {
                    *v = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                }
                leaves.push((o, vals));
            }
            TAG_TILE => {
                if tiles.len() as u64 >= max_tiles {
                    return Err(format!(
                        "worker stream has more than {max_tiles} tiles for a {file_size}-byte file"
                    ));
                }
                let o = s.ivec()?;
                let level = s.u8()?;
                let mut b = [0u8; 4];
                s.fill(&mut b)?;
                tiles.push((o, level, f32::from_le_bytes(b)));
            }
            t => return Err(format!("worker stream has a bad record tag {t}")),
        }
    }
    let active = s.u64()?;
    let negatives = s.u64()?;
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
        leaves,
        tiles,
        active,
        negatives,
    })
}

impl VdbSource {
    /// Opens `path` with the isolated worker; see the module docs. Every failure, including a
    /// crash, timeout or memory exhaustion of the worker, is a one-line [`SourceError::Vdb`].
    pub fn open(path: &Path, opt: &VdbOptions) -> Result<Self, SourceError> {
        let fail = |m: String| SourceError::Vdb {
            path: path.to_path_buf(),
            message: m,
        };
        let scale = DensityScale::new(opt.density_scale).map_err(|e| fail(e.to_string()))?;
        // A FIFO, device or directory is refused before the worker could block on it or
        // read it without end.
        let file_size = crate::files::check_input(path).map_err(SourceError::from_file)?;
        let limit = opt
            .memory_limit
            .unwrap_or_else(|| default_memory_limit(file_size));
        let stream = run_worker(path, opt, file_size, limit).map_err(fail)?;
        Self::from_stream(path, stream, scale).map_err(fail)
    }

    fn from_stream(path: &Path, st: Stream, scale: DensityScale) -> Result<Self, String> {
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
        let mut leaves = Vec::new();
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
        let mut entries: Vec<(IVec3, Block)> = Vec::with_capacity(st.leaves.len() + st.tiles.len());
        let mut big_entries: Vec<(IVec3, f32)> = Vec::new();
        let mut huge_entries: Vec<(IVec3, f32)> = Vec::new();
        for (o, vals) in &st.leaves {
            let o = IVec3::from_array(*o);
            if (o & 7) != IVec3::ZERO {
                return Err(format!("worker sent a misaligned leaf at {o}"));
            }
            let mut scaled = [0f32; 512];
            let mut m = 0.0f32;
            for (k, v) in vals.iter().enumerate() {
                let l = local(k, 3);
                let at = o + IVec3::from_array(l);
                let s = check(*v, at)?;
                if s != 0.0 {
                    lo = lo.min(at);
                    hi = hi.max(at);
                }
                m = m.max(s);
                scaled[k] = s;
            }
            if m == 0.0 {
                continue;
            }
            global_max = global_max.max(m);
            entries.push((o >> 3, Block::Dense(leaves.len() as u32)));
            leaves.push(scaled);
            leaf_max.push(m);
        }
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
        if leaves.is_empty()
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
            leaves.len(),
            blocks.len() - leaves.len() + big.len() + huge.len(),
            match diag {
                Some((s, _)) => s.to_string(),
                None => format!("{:?} (affine)", st.xf),
            },
        );
        if st.negatives > 0 {
            label.push_str(&format!(", {} negative values clamped to 0", st.negatives));
        }
        Ok(Self {
            blocks,
            block_base,
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
        })
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
    fn max_in_index_box(&self, a: DVec3, b: DVec3) -> f32 {
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
                        if let Some(b) = pack(IVec3::new(x, y, z), self.block_base)
                            .and_then(|k| self.blocks.get(&k))
                        {
                            m = m.max(block_max(b));
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
    /// frame), an empty grid, or a copy of more than `max_bytes` bytes (or one that cannot be
    /// allocated).
    ///
    /// The copy holds every voxel centre the trilinear field reaches, one beyond the stored
    /// ones on each side: those are zero, so the dense grid's clamp-to-edge outer half voxel
    /// reads zero where this source does, and its box covers [`DensitySource::bounds`]. A
    /// mirrored axis (negative scale) is stored reversed, so that the copy's index grows with
    /// world position. Values at voxel centres are bit-identical; between them the two
    /// samplers interpolate the same corners with the same f32 weights formula, but compute
    /// the continuous index with different f64 roundings (`(p - t) / s` against
    /// `p / s - o / s - 0.5`), so a sample can differ by a few ulps (docs/performance.md).
    pub fn dense_copy(&self, max_bytes: u64) -> Option<DenseGrid> {
        let (scale, _) = self.diag?;
        if !self.index_min.cmple(self.index_max).all() {
            return None;
        }
        let (lo, hi) = (self.index_min - 1, self.index_max + 1);
        let n = (hi.as_i64vec3() - lo.as_i64vec3()) + 1;
        if n.max_element() > i64::from(u32::MAX) {
            return None;
        }
        let count = (n.x as u64)
            .checked_mul(n.y as u64)?
            .checked_mul(n.z as u64)?;
        if count.checked_mul(4)? > max_bytes {
            return None;
        }
        // Copy index j along an axis is index `lo + j`, or `hi - j` where the map mirrors it.
        let mirrored = [0, 1, 2].map(|a| scale[a] < 0.0);
        let data = self.dense_values(lo, n, count, mirrored)?;
        let corner = (lo.as_dvec3() - 0.5) * scale;
        let far = (hi.as_dvec3() + 0.5) * scale;
        let origin = corner.min(far) + self.translation;
        let dims = [n.x as u32, n.y as u32, n.z as u32];
        DenseGrid::new(
            dims,
            data,
            scale.abs(),
            origin,
            format!("dense copy of {}", self.label),
        )
        .ok()
    }

    /// The voxels of the index box at `lo` with `n` voxels per axis (`count` in all), x
    /// fastest; an axis with `mirrored` set runs from the box's top down. `None` if the
    /// memory cannot be had.
    fn dense_values(
        &self,
        lo: IVec3,
        n: glam::I64Vec3,
        count: u64,
        mirrored: [bool; 3],
    ) -> Option<Vec<f32>> {
        use rayon::prelude::*;
        let count = usize::try_from(count).ok()?;
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
                let iz = at(2, z);
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
        let Some(count) = (n.x as u64)
            .checked_mul(n.y as u64)
            .and_then(|c| c.checked_mul(n.z as u64))
            .filter(|c| c.saturating_mul(4) <= max_bytes)
        else {
            return self;
        };
        if n.max_element() > i64::from(i32::MAX) {
            return self;
        }
        if let Some(data) = self.dense_values(lo, n, count, [false; 3]) {
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
        if let Some(k) = pack(i >> 3, self.block_base)
            && let Some(b) = self.blocks.get(&k)
        {
            return match *b {
                Block::Dense(l) => {
                    let l8 = i & 7;
                    self.leaves[l as usize][((l8.x << 6) | (l8.y << 3) | l8.z) as usize]
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
    fn sample_index(&self, u: DVec3) -> f32 {
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
            // All eight corners in one block: one hash lookup.
            match pack(i >> 3, self.block_base).and_then(|k| self.blocks.get(&k)) {
                Some(Block::Dense(li)) => {
                    let leaf = &self.leaves[*li as usize];
                    let b = ((l.x << 6) | (l.y << 3) | l.z) as usize;
                    [
                        leaf[b],
                        leaf[b + 64],
                        leaf[b + 8],
                        leaf[b + 72],
                        leaf[b + 1],
                        leaf[b + 65],
                        leaf[b + 9],
                        leaf[b + 73],
                    ]
                }
                Some(Block::Const(v)) => [*v; 8],
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

    /// Corner values in the order (x, then y, then z varying fastest-to-slowest).
    fn corners(&self, i: IVec3) -> [f32; 8] {
        let mut c = [0f32; 8];
        for (n, v) in c.iter_mut().enumerate() {
            let d = IVec3::new((n & 1) as i32, ((n >> 1) & 1) as i32, ((n >> 2) & 1) as i32);
            *v = self.voxel(i + d);
        }
        c
    }
}

impl DensitySource for VdbSource {
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

    fn describe(&self) -> String {
        self.label.clone()
    }

    fn bake_frame(&self) -> Option<(Box<dyn DensitySource + '_>, [f64; 12])> {
        // Axis-aligned grids keep baking in world space, as they always have.
        let (frame, local_to_world) = GridFrame::new(self)?;
        Some((Box::new(frame), local_to_world))
    }

    fn dense_copy(&self, max_bytes: u64) -> Option<DenseGrid> {
        VdbSource::dense_copy(self, max_bytes)
    }

    fn prefiltered(&self, step: f64) -> Result<Option<Mip>, MipAllocError> {
        // Axis-aligned maps only: a rotated or sheared grid's voxels are not boxes of the bake
        // frame, and it keeps point sampling.
        let Some((scale, _)) = self.diag else {
            return Ok(None);
        };
        // The fine grid is every voxel centre the trilinear field reaches (one beyond the
        // stored ones, where it falls to zero), each the centre of a unit index cell.
        let (lo, hi) = (self.index_min - 1, self.index_max + 1);
        let n = (hi - lo + 1).as_i64vec3();
        if n.cmple(glam::I64Vec3::ZERO).any() || n.max_element() > i64::from(u32::MAX) {
            return Ok(None);
        }
        let fine = [n.x as u32, n.y as u32, n.z as u32];
        let extent = n.as_dvec3() * scale.abs();
        // The dense level (and the pass that reads every fine voxel) must stay about the size
        // of what the sparse grid stores: a few leaves under a huge tile box keep point
        // sampling instead of a dense copy of the box.
        let stored = (self.leaves.len() as u64 * 512).max(1 << 24);
        let coarse: u64 = Mip::coarse_dims(fine, extent, step)
            .iter()
            .map(|&c| c as u64)
            .product();
        let fine_count = n.x as u64 * n.y as u64 * n.z as u64;
        if coarse > stored || fine_count > 8 * stored {
            return Ok(None);
        }
        // Fine index j along an axis is index `lo + j`, or `hi - j` where the map mirrors
        // that axis (so that j grows with world position, as the mip's voxels do).
        let at = |a: usize, j: usize| {
            if scale[a] > 0.0 {
                lo[a] + j as i32
            } else {
                hi[a] - j as i32
            }
        };
        let corner = DVec3::new(
            (lo.x as f64 - 0.5) * scale.x,
            (lo.y as f64 - 0.5) * scale.y,
            (lo.z as f64 - 0.5) * scale.z,
        );
        let far = DVec3::new(
            (hi.x as f64 + 0.5) * scale.x,
            (hi.y as f64 + 0.5) * scale.y,
            (hi.z as f64 + 0.5) * scale.z,
        );
        let origin = corner.min(far) + self.translation;
        let fill = |y: usize, z: usize, row: &mut [f32]| {
            let (iy, iz) = (at(1, y), at(2, z));
            for (x, v) in row.iter_mut().enumerate() {
                *v = self.voxel(IVec3::new(at(0, x), iy, iz));
            }
        };
        Mip::build(fine, origin, extent, step, &fill)
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
struct GridFrame<'a> {
    grid: &'a VdbSource,
    /// Local to index (`R^-1`).
    to_index: DMat3,
    /// The local box: `R` applied to the index box.
    bounds: Aabb,
}

impl<'a> GridFrame<'a> {
    /// The frame and its `local_to_world` (row-major 3x4), or `None` when the map is
    /// axis-aligned or degenerate.
    fn new(grid: &'a VdbSource) -> Option<(Self, [f64; 12])> {
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

    fn index_inside(&self, u: DVec3) -> bool {
        let g = self.grid;
        u.cmpge((g.index_min - 1).as_dvec3()).all() && u.cmple((g.index_max + 1).as_dvec3()).all()
    }
}

impl DensitySource for GridFrame<'_> {
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

    fn occupied_bounds(&self) -> Option<Aabb> {
        Some(self.bounds)
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

    fn describe(&self) -> String {
        format!("{}, baked in the grid's own frame", self.grid.label)
    }
}

/// Set in the worker's environment. A process that has it and is asked to start a worker is
/// itself a "worker" that did not understand `__vdb-worker` (e.g. a test harness given as
/// `worker_exe`, which would run its tests, open the VDB again and spawn itself without end);
/// it refuses instead of recursing.
pub const WORKER_ENV: &str = "PINBAKE_VDB_WORKER";

/// Spawns the worker with limits, parses its stream and turns every failure mode into text.
fn run_worker(path: &Path, opt: &VdbOptions, file_size: u64, limit: u64) -> Result<Stream, String> {
    if std::env::var_os(WORKER_ENV).is_some() {
        return Err(format!(
            "refusing to start a VDB reader from inside a VDB reader process: '{}' does not \
             handle `{WORKER_SUBCOMMAND}` (set VdbOptions::worker_exe to pinbake or pinrender)",
            opt.worker_exe.display()
        ));
    }
    let mut cmd = Command::new(&opt.worker_exe);
    cmd.env(WORKER_ENV, "1")
        .arg(WORKER_SUBCOMMAND)
        .arg(path)
        .arg(opt.grid.as_deref().unwrap_or(""))
        .arg(if opt.levelset_to_fog {
            "levelset-to-fog"
        } else {
            "fog"
        })
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    #[cfg(unix)]
    {
        use std::os::unix::process::CommandExt;
        // SAFETY: the closure runs between fork and exec and only calls setrlimit, which is
        // async-signal-safe; it touches no locks and allocates nothing.
        unsafe {
            cmd.pre_exec(move || {
                let lim = libc::rlimit {
                    rlim_cur: limit as libc::rlim_t,
                    rlim_max: limit as libc::rlim_t,
                };
                let none = libc::rlimit {
                    rlim_cur: 0,
                    rlim_max: 0,
                };
                // A crash of the worker on a hostile file should not leave a core dump behind.
                libc::setrlimit(libc::RLIMIT_CORE, &none);
                if libc::setrlimit(libc::RLIMIT_AS, &lim) != 0
                    || libc::setrlimit(libc::RLIMIT_DATA, &lim) != 0
                {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
    }
    let mut child = cmd.spawn().map_err(|e| {
        format!(
            "cannot start the VDB reader '{}': {e}",
            opt.worker_exe.display()
        )
    })?;
    let stdout = child.stdout.take().ok_or("worker has no stdout")?;
    let stderr = child.stderr.take().ok_or("worker has no stderr")?;
    let parser = std::thread::spawn(move || {
        let mut r = BufReader::with_capacity(1 << 16, stdout);
        let res = parse_stream(&mut r, file_size);
        // Drain so that the child never blocks on a full pipe after we stopped reading.
        let _ = std::io::copy(&mut r, &mut std::io::sink());
        res
    });
    let err_reader = std::thread::spawn(move || {
        let mut buf = Vec::new();
        let _ = stderr.take(64 * 1024).read_to_end(&mut buf);
        String::from_utf8_lossy(&buf).into_owned()
    });
    let deadline = Instant::now() + opt.timeout;
    let mut timed_out = false;
    let status = loop {
        match child.try_wait() {
            Ok(Some(s)) => break s,
            Ok(None) => {}
            Err(e) => return Err(format!("waiting for the VDB reader failed: {e}")),
        }
        if Instant::now() >= deadline {
            timed_out = true;
            let _ = child.kill();
            break child
                .wait()
                .map_err(|e| format!("waiting for the VDB reader failed: {e}"))?;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let parsed = parser
        .join()
        .unwrap_or_else(|_| Err("worker stream parser panicked".into()));
    let stderr_text = err_reader.join().unwrap_or_default();
    let last_line = stderr_text
        .lines()
        .rev()
        .find(|l| !l.trim().is_empty())
        .map(one_line);
    if timed_out {
        return Err(format!(
            "VDB reader timed out after {} s",
            opt.timeout.as_secs_f64()
        ));
    }
    if status.success() {
        return parsed;
    }
    if stderr_text.contains("memory allocation of") {
        // The default limit is 64 MiB + 64 x the file size; every stored node carries its
        // masks uncompressed, so a valid file stays below it (docs/vdb.md).
        return Err(if opt.memory_limit.is_some() {
            format!(
                "VDB reader needs more than {} MiB of memory (the limit it was given)",
                limit / MIB
            )
        } else {
            format!(
                "VDB reader needs more than {} MiB of memory, more than a valid file of {file_size} bytes needs (docs/vdb.md): the file is probably corrupt",
                limit / MIB
            )
        });
    }
    #[cfg(unix)]
    {
        use std::os::unix::process::ExitStatusExt;
        if let Some(sig) = status.signal() {
            return Err(format!("VDB reader crashed (signal {sig})"));
        }
    }
    Err(last_line.unwrap_or_else(|| format!("VDB reader failed ({status})")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(name: &str) -> PathBuf {
        PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../data")).join(name)
    }

    /// Runs the worker logic in-process (valid files only: the isolation is tested in
    /// tests/sources.rs with the real binary).
    fn in_process(file: &str, sel: Option<&str>, to_fog: bool) -> Result<VdbSource, String> {
        let p = data(file);
        let mut buf = Vec::new();
        worker_run(&p, sel, to_fog, &mut buf)?;
        let size = std::fs::metadata(&p).unwrap().len();
        let st = parse_stream(&buf[..], size)?;
        VdbSource::from_stream(&p, st, DensityScale::ONE)
    }

    fn gi(name: &str, ty: &str) -> GridInfo {
        GridInfo {
            name: name.into(),
            grid_type: ty.into(),
            class: String::new(),
        }
    }

    /// The smoke with its map mirrored on x and z (negative scales): the dense copy stores
    /// those axes reversed and still holds the tree's field (a few f32 ulps of the largest
    /// value, from the index arithmetic), and the dense cache gives the tree's bits.
    #[test]
    fn dense_copy_and_cache_of_a_mirrored_grid() {
        let p = data("openvdb_smoke1.vdb");
        let size = std::fs::metadata(&p).unwrap().len();
        let mirrored = || {
            let mut buf = Vec::new();
            worker_run(&p, None, false, &mut buf).unwrap();
            let mut st = parse_stream(&buf[..], size).unwrap();
            st.xf[0] = -st.xf[0];
            st.xf[10] *= -0.5;
            st.xf[3] = 4.0;
            VdbSource::from_stream(&p, st, DensityScale::ONE).unwrap()
        };
        let tree = mirrored();
        assert!(tree.is_axis_aligned());
        let copy = tree.dense_copy(u64::MAX).unwrap();
        let cached = mirrored().with_dense_cache(u64::MAX);
        assert!(cached.has_dense_cache());
        let (lo, hi) = tree.index_bounds();
        let m = (hi - lo + 1).as_dvec3() - 1.0;
        let mut rng = crate::rng::CounterRng::new(3, 0, 0);
        let mut nonzero = 0;
        for _ in 0..50_000 {
            let f = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64());
            let w = tree.index_to_world(lo.as_dvec3() - 1.0 + f * (m + 2.0));
            let (a, b) = (copy.extinction(w), tree.extinction(w));
            assert!(
                (a - b).abs() <= 4.0 * f32::EPSILON * copy.max_value(),
                "{w}: copy {a}, tree {b}"
            );
            assert_eq!(cached.extinction(w).to_bits(), b.to_bits(), "{w}");
            nonzero += usize::from(b > 0.0);
        }
        assert!(nonzero > 5_000, "{nonzero}");
    }

    #[test]
    fn selection_rules() {
        let f = "Tree_float_5_4_3";
        let three = [
            gi("density\u{1e}0", f),
            gi("density\u{1e}1", f),
            gi("density\u{1e}2", f),
        ];
        assert_eq!(select_grid(&three, Some("density#1")), Ok(1));
        let e = select_grid(&three, Some("density")).unwrap_err();
        assert!(e.contains("density#0, density#1, density#2"), "{e}");
        assert!(select_grid(&three, None).is_err());
        let e = select_grid(&three, Some("temp")).unwrap_err();
        assert!(e.contains("no grid named 'temp'"), "{e}");
        let mixed = [gi("Cd", "Tree_vec3s_5_4_3"), gi("heat", f)];
        assert_eq!(select_grid(&mixed, None), Ok(1));
        let two = [gi("a", f), gi("b", f)];
        let e = select_grid(&two, None).unwrap_err();
        assert!(e.contains("a, b"), "{e}");
        let with_density = [gi("a", f), gi("density", f)];
        assert_eq!(select_grid(&with_density, None), Ok(1));
        assert!(select_grid(&[], None).is_err());
    }

    #[test]
    fn bbox_checks_follow_oiio() {
        let v = glam024::IVec3::new;
        assert!(check_bbox("g", Some(v(0, 0, 0)), Some(v(10, 10, 10))).is_ok());
        assert!(check_bbox("g", None, None).is_ok());
        let e = check_bbox("g", Some(v(100, 100, 100)), Some(v(-100, -100, -100))).unwrap_err();
        assert!(e.contains("inverted"), "{e}");
        let e = check_bbox(
            "g",
            Some(v(i32::MIN, i32::MIN, i32::MIN)),
            Some(v(i32::MAX, i32::MAX, i32::MAX)),
        )
        .unwrap_err();
        assert!(e.contains("out-of-range"), "{e}");
        // A huge but sparse box is valid.
        assert!(check_bbox("g", Some(v(0, 0, 0)), Some(v(200000, 200000, 200000))).is_ok());
        let e = check_bbox("g", Some(v(0, 0, 0)), Some(v(2000000, 0, 0))).unwrap_err();
        assert!(e.contains("bounding box"), "{e}");
    }

    #[test]
    fn stream_limits_are_enforced() {
        // Garbage, truncated and oversized streams are errors, never allocations.
        assert!(parse_stream(&b"nonsense"[..], 100).is_err());
        let mut s = STREAM_MAGIC.to_vec();
        s.extend_from_slice(&u32::MAX.to_le_bytes());
        assert!(parse_stream(&s[..], 100).is_err());
        let mut s = STREAM_MAGIC.to_vec();
        s.extend_from_slice(&1u32.to_le_bytes());
        s.extend_from_slice(&u32::MAX.to_le_bytes());
        assert!(
            parse_stream(&s[..], 100)
                .err()
                .unwrap()
                .contains("byte name")
        );
        // A valid stream from a real file, truncated anywhere, is an error.
        let p = data("gaffer_sphere_density.vdb");
        let mut buf = Vec::new();
        worker_run(&p, None, false, &mut buf).unwrap();
        for cut in [0, 7, 20, buf.len() / 2, buf.len() - 1] {
            assert!(parse_stream(&buf[..cut], 1 << 20).is_err(), "cut {cut}");
        }
        // A stream claiming more leaves than the file can hold is rejected.
        let e = parse_stream(&buf[..], 10).err().unwrap();
        assert!(e.contains("leaves"), "{e}");
        let mut extra = buf.clone();
        extra.push(0);
        assert!(parse_stream(&extra[..], 1 << 20).is_err());
    }

    #[test]
    fn in_process_reads_and_samples() {
        let s = in_process("oiio_sphere_density.vdb", None, false).unwrap();
        let (lo, hi) = s.index_bounds();
        assert!(lo.cmpge(IVec3::splat(-12)).all() && hi.cmple(IVec3::splat(12)).all());
        assert!(s.extinction(DVec3::ZERO) > 0.0);
        assert_eq!(s.extinction(DVec3::splat(5.0)), 0.0);
        // Voxel centres reproduce voxel values exactly.
        for i in -12..=12 {
            let c = IVec3::new(i, 0, 0);
            let v = s.voxel(c);
            assert!((s.extinction(s.index_to_world(c.as_dvec3())) - v).abs() <= 1e-5 * v.max(1.0));
        }
        let e = in_process("openvdb_sphere_levelset.vdb", None, false).unwrap_err();
        assert!(
            e.contains("level set") && e.contains("--levelset-to-fog"),
            "{e}"
        );
        let fog = in_process("openvdb_sphere_levelset.vdb", None, true).unwrap();
        // The sphere's centre is deep inside (a tile region), the corner outside.
        assert_eq!(fog.extinction(DVec3::ZERO), 1.0);
        assert_eq!(fog.extinction(DVec3::splat(2.9)), 0.0);
    }

    #[test]
    fn flood_fill_in_a_leaf() {
        let mut vals = [0f32; 512];
        let mut words = [0u64; 8];
        // A plane of active voxels at z = 3 with negative values: voxels after it along z
        // inherit "inside" only until the next active voxel.
        for x in 0..8 {
            for y in 0..8 {
                let i = (x << 6) | (y << 3) | 3;
                words[i / 64] |= 1 << (i % 64);
                vals[i] = -1.0;
                let j = (x << 6) | (y << 3) | 6;
                words[j / 64] |= 1 << (j % 64);
                vals[j] = 1.0;
            }
        }
        let ins = leaf_inside(&vals, Mask(&words));
        assert!(ins[3] && ins[4] && ins[5] && !ins[6] && !ins[7]);
    }
}
