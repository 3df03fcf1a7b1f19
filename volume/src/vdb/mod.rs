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
//! description to stdout: the grid list, the chosen grid's transform, the leaf count, and its
//! non-empty leaf nodes (origin + 512 values, as f16 bits for half data) and constant tiles.
//! The worker reads the topology first and then one leaf's values at a time, so it never
//! holds the grid's values. The parent re-validates every count and value in that stream and
//! builds a sparse table, sized once from the count (and refused against
//! `VdbOptions::max_leaf_bytes` before a leaf is read), never a dense grid.
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
    Aabb, DenseGrid, DenseLattice, Density, DensityScale, DensitySource, SourceError, one_line,
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

/// Largest accepted extent of a grid, per axis, in voxels (OpenImageIO uses the same).
pub const MAX_AXIS_VOXELS: i64 = 1 << 20;
const MIB: u64 = 1 << 20;
/// The slowest read rate of a valid file that the worker's timeout allows for: a timeout of
/// at least the file size over this rate, whatever [`VdbOptions::timeout`] says (a 3 GB
/// cloud takes more than a minute on a loaded 2-core machine).
pub const MIN_READ_BYTES_PER_S: f64 = 8e6;

/// How to open a VDB file.
#[derive(Clone, Debug, PartialEq)]
pub struct VdbOptions {
    /// Grid to read (see the module docs); `None` picks `density` or the only float grid.
    pub grid: Option<String>,
    /// Accept a level set and bake its interior (negative distance) as density 1.
    pub levelset_to_fog: bool,
    /// Executable that understands `__vdb-worker` (normally the `pinbake` binary itself).
    pub worker_exe: PathBuf,
    /// Address-space limit of the worker in bytes; `None`: 64 MiB + 64 x file size, <= 16 GiB.
    pub memory_limit: Option<u64>,
    /// Wall-clock limit of the worker.
    pub timeout: Duration,
    /// The most bytes the grid's leaf table may take in this process (values and per-leaf
    /// overhead, [`VdbSource::memory_bytes`]): a grid that needs more is refused with
    /// [`SourceError::Memory`] as soon as the worker has counted its leaves, before they are
    /// read. `None`: no limit beyond what the allocator gives.
    pub max_leaf_bytes: Option<u64>,
    /// Read one z-slab of the grid for one part of a farm bake ([`VdbPart`]): the leaf
    /// table holds about `1 / count` of the grid; `None` reads the whole grid. Without
    /// [`Self::grid_stats`] the leaves outside the slab are decoded for the grid's
    /// statistics but neither sent nor kept.
    pub part: Option<VdbPart>,
    /// The whole grid's statistics ([`GridStats`], from [`VdbSource::grid_stats`] with the
    /// same file, grid, level-set mode and density scale), for a part read: the reader then
    /// moves past the leaves outside the slab without decoding them (a level set's leaves
    /// are decoded all the same, for its flood fill). Statistics that do not match the file
    /// or what the part reads are an error. Ignored without [`Self::part`].
    pub grid_stats: Option<Box<GridStats>>,
}

impl Default for VdbOptions {
    fn default() -> Self {
        Self {
            grid: None,
            levelset_to_fog: false,
            worker_exe: std::env::current_exe().unwrap_or_else(|_| PathBuf::from("pinbake")),
            memory_limit: None,
            timeout: Duration::from_secs(60),
            max_leaf_bytes: None,
            part: None,
            grid_stats: None,
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

mod reader;
mod source;
mod spawn;
mod wire;

use reader::*;
use spawn::*;
use wire::*;

pub use reader::worker_main;
pub use source::VdbSource;
pub use spawn::WORKER_ENV;
pub use wire::{GridStats, VdbPart};
// What the NanoVDB reader builds a `VdbSource` from: the worker's stream, made in-process.
pub(crate) use wire::{
    GridInfo, LEAF_F32, LEAF_HALF, LeafValues, Stream, StreamError, ValueKind, leaf_table_bytes,
    select_grid,
};

#[cfg(test)]
mod tests {
    use super::*;
    use source::Leaves;

    fn data(name: &str) -> PathBuf {
        PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../data")).join(name)
    }

    /// Runs the worker logic in-process (valid files only: the isolation is tested in
    /// tests/sources.rs with the real binary).
    fn in_process(file: &str, sel: Option<&str>, to_fog: bool) -> Result<VdbSource, String> {
        let p = data(file);
        let mut buf = Vec::new();
        worker_run(&p, sel, to_fog, None, &mut buf)?;
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

    /// The baker's counter generator (`pinbake::rng::CounterRng`, same sequence), for the
    /// random sample points of these tests.
    struct TestRng {
        key: u64,
        counter: u64,
    }

    impl TestRng {
        fn mix(mut z: u64) -> u64 {
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            z ^ (z >> 31)
        }
        fn new(seed: u64, a: u64, b: u64) -> Self {
            let m = Self::mix;
            let key = m(m(m(seed ^ 0x5049_4e42_414b_4531) ^ a).wrapping_add(b));
            Self { key, counter: 0 }
        }
        fn next_f64(&mut self) -> f64 {
            self.counter = self.counter.wrapping_add(1);
            let u = Self::mix(
                self.key
                    .wrapping_add(self.counter.wrapping_mul(0x9e37_79b9_7f4a_7c15)),
            );
            (u >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
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
            worker_run(&p, None, false, None, &mut buf).unwrap();
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
        let mut rng = TestRng::new(3, 0, 0);
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

    /// A stream of `origins` leaves, each with every voxel set to `value`.
    fn stream_of(origins: &[[i32; 3]], value: f32) -> Stream {
        Stream {
            grids: vec![gi("density", "Tree_float_5_4_3")],
            chosen: 0,
            kind: ValueKind::Float,
            level_set: false,
            xf: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
            origins: origins.to_vec(),
            leaves: LeafValues::F32(vec![[value; 512]; origins.len()]),
            tiles: Vec::new(),
            active: 512 * origins.len() as u64,
            negatives: 0,
            part: None,
            stats: None,
        }
    }

    /// A half grid keeps its leaves as 16-bit patterns (half the bytes of f32) with the
    /// values a scaled f32 copy would hold, bit for bit.
    #[test]
    fn half_leaves_hold_the_scaled_values_at_half_the_bytes() {
        let p = data("openvdb_smoke1.vdb");
        let size = std::fs::metadata(&p).unwrap().len();
        let mut buf = Vec::new();
        worker_run(&p, None, false, None, &mut buf).unwrap();
        let scale = DensityScale::new(0.37).unwrap();
        let st = parse_stream(&buf[..], size).unwrap();
        let LeafValues::Half(bits) = &st.leaves else {
            panic!("the smoke is half: its leaves must travel as f16");
        };
        let (first_origin, first_bits) = (IVec3::from_array(st.origins[0]), bits[0]);
        let s = VdbSource::from_stream(&p, st, scale).unwrap();
        let Leaves::Half(kept, _) = &s.leaves else {
            panic!("half leaves must stay f16");
        };
        assert!(s.memory_bytes() < kept.len() as u64 * 1100 + (300 << 10));
        assert!(s.memory_bytes() >= kept.len() as u64 * 1024);
        let mut nonzero = 0;
        for (k, b) in first_bits.iter().enumerate() {
            let want = scale
                .apply(f64::from(half::f16::from_bits(*b).to_f32()))
                .unwrap();
            let at = first_origin + IVec3::from_array(local(k, 3));
            assert_eq!(s.voxel(at).to_bits(), want.to_bits(), "{at}");
            nonzero += usize::from(want != 0.0);
        }
        assert!(nonzero > 0);
    }

    /// The worker announces its leaf count first; a table larger than the limit is refused
    /// before a leaf is read, and a limit it fits in reads the same grid.
    #[test]
    fn a_leaf_table_over_the_limit_is_refused_before_it_is_read() {
        let p = data("openvdb_smoke1.vdb");
        let size = std::fs::metadata(&p).unwrap().len();
        let mut buf = Vec::new();
        worker_run(&p, None, false, None, &mut buf).unwrap();
        let full = parse_stream(&buf[..], size).unwrap();
        let need = leaf_table_bytes(full.origins.len() as u64, LEAF_HALF);
        match parse_stream_within(&buf[..], size, need - 1, false) {
            Err(StreamError::Budget { need: n, limit }) => {
                assert_eq!((n, limit), (need, need - 1));
            }
            Err(e) => panic!("expected a budget refusal, got {e}"),
            Ok(_) => panic!("expected a budget refusal"),
        }
        let fits = parse_stream_within(&buf[..], size, need, false).unwrap();
        assert_eq!(fits.origins, full.origins);
        // The count follows the magic, the grid list, the choice, kind, class and map.
        let mut off = 8 + 4;
        for g in &full.grids {
            off += 12 + g.name.len() + g.grid_type.len() + g.class.len();
        }
        off += 4 + 1 + 1 + 96;
        let announced = u64::from_le_bytes(buf[off..off + 8].try_into().unwrap());
        assert!(announced >= full.origins.len() as u64);
        // More leaves than announced is a bad stream.
        let mut fewer = buf.clone();
        let short = full.origins.len() as u64 - 1;
        fewer[off..off + 8].copy_from_slice(&short.to_le_bytes());
        let e = parse_stream(&fewer[..], size).err().unwrap();
        assert!(e.contains("more than the"), "{e}");
    }

    /// No dense copy that would be mostly zeros: two leaves far apart keep the tree, one
    /// leaf (a full box) is copied.
    #[test]
    fn no_dense_copy_of_a_mostly_empty_box() {
        let p = data("openvdb_smoke1.vdb");
        let one =
            VdbSource::from_stream(&p, stream_of(&[[0, 0, 0]], 0.5), DensityScale::ONE).unwrap();
        assert_eq!(one.stored_voxels(), 512);
        assert!(one.dense_copy(u64::MAX).is_some());
        assert_eq!(one.dense_copy_size(), Some(10 * 10 * 10 * 4));
        let two = VdbSource::from_stream(
            &p,
            stream_of(&[[0, 0, 0], [64, 0, 0]], 0.5),
            DensityScale::ONE,
        )
        .unwrap();
        assert_eq!(two.stored_voxels(), 1024);
        assert!(two.dense_copy(u64::MAX).is_none());
        assert_eq!(two.dense_copy_size(), None);
        // The tree samples both leaves all the same.
        assert_eq!(two.voxel(IVec3::new(67, 3, 3)), 0.5);
        assert_eq!(two.voxel(IVec3::new(30, 3, 3)), 0.0);
    }

    /// Cells on a leaf's faces, edges and corners read their corners across the blocks (the
    /// lookup per block must equal one lookup per voxel).
    #[test]
    fn corners_across_blocks_equal_voxel_lookups() {
        let p = data("openvdb_smoke1.vdb");
        let mut st = stream_of(&[[0, 0, 0], [8, 0, 0], [0, 8, 8], [8, 8, 8]], 0.0);
        if let LeafValues::F32(v) = &mut st.leaves {
            for (n, leaf) in v.iter_mut().enumerate() {
                for (k, x) in leaf.iter_mut().enumerate() {
                    *x = (n * 512 + k) as f32;
                }
            }
        }
        let s = VdbSource::from_stream(&p, st, DensityScale::ONE).unwrap();
        for x in -1..16 {
            for y in -1..16 {
                for z in -1..16 {
                    let i = IVec3::new(x, y, z);
                    let want: [f32; 8] = std::array::from_fn(|n| {
                        let d = IVec3::new((n & 1) as i32, ((n >> 1) & 1) as i32, (n >> 2) as i32);
                        s.voxel(i + d)
                    });
                    assert_eq!(s.corners(i), want, "{i}");
                }
            }
        }
    }

    /// The dense block index answers every lookup as the hash table does: the same
    /// samples, bit for bit, with and without it.
    #[test]
    fn the_block_index_samples_as_the_hash_table() {
        let indexed = in_process("openvdb_smoke1.vdb", None, false).unwrap();
        assert!(indexed.index.is_some(), "the smoke's blocks are compact");
        let mut hashed = in_process("openvdb_smoke1.vdb", None, false).unwrap();
        hashed.index = None;
        let b = indexed.bounds();
        let mut rng = TestRng::new(5, 0, 0);
        let mut nonzero = 0;
        for _ in 0..100_000 {
            let f = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64());
            let p = b.min + f * b.extent();
            let (x, y) = (indexed.extinction(p), hashed.extinction(p));
            assert_eq!(x.to_bits(), y.to_bits(), "{p}");
            nonzero += usize::from(x > 0.0);
        }
        assert!(nonzero > 10_000, "{nonzero}");
        let whole = Aabb::new(b.min, b.max);
        assert_eq!(
            indexed.max_extinction_in(whole),
            hashed.max_extinction_in(whole)
        );
        // Far-apart blocks keep the hash table alone.
        let p = data("openvdb_smoke1.vdb");
        let sparse = VdbSource::from_stream(
            &p,
            stream_of(&[[0, 0, 0], [800, 0, 0]], 1.0),
            DensityScale::ONE,
        )
        .unwrap();
        assert!(sparse.index.is_none());
        assert_eq!(sparse.voxel(IVec3::new(803, 1, 1)), 1.0);
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
        worker_run(&p, None, false, None, &mut buf).unwrap();
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
