//! The NanoVDB reader against known grids and against NanoVDB itself.
//!
//! * Written here (`nanovdb/mod.rs`, NanoVDB 32.4's layout): every value type (float,
//!   double, half, Fp4, Fp8, Fp16, FpN at every bit width), uncompressed and ZIP, with
//!   inactive voxels, negative values, lower-node tiles, root tiles and level sets: the
//!   value at every voxel.
//! * The OpenVDB corpus (`openvdb/corpus.cpp`) converted with `nanovdb_convert` plain,
//!   `--fp4`, `--fp8`, `--fp16`, `--fpN` and `--zip`: every sampled voxel against OpenVDB's
//!   own reading of the source `.vdb` (exact for float, within half a quantum for the
//!   quantised leaves), and a bake of every float grid against the bake of the `.vdb`, byte
//!   for byte. Without `nanovdb_convert` (Debian's `libnanovdb-tools`) this test fails.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::nanovdb::{Grid, Type, file_bytes, leaf};
use crate::{nanovdb, openvdb};
use glam::{DVec3, IVec3};
use pin_format::Directions;
use pin_volume::DensitySource;
use pin_volume::vdb::{VdbOptions, VdbSource};
use pinbake::BakeOptions;

fn open_nvdb(path: &Path, grid: Option<&str>, level_set: bool) -> Result<VdbSource, String> {
    let opt = VdbOptions {
        grid: grid.map(str::to_string),
        levelset_to_fog: level_set,
        ..VdbOptions::with_worker(env!("CARGO_BIN_EXE_pinbake"))
    };
    pin_volume::nanovdb::open(path, &opt, pin_volume::DensityScale::ONE).map_err(|e| e.to_string())
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// A smooth field with negative values and zeros, different in every voxel.
fn field(o: [i32; 3], k: usize) -> f32 {
    let x = o[0] as f32 + (k >> 6) as f32;
    let y = o[1] as f32 + ((k >> 3) & 7) as f32;
    let z = o[2] as f32 + (k & 7) as f32;
    (x * 0.37).sin() * 2.0 + (y * 0.11).cos() + z * 0.05 - 0.5
}

/// Index of voxel `k` (NanoVDB's order) of the leaf at `o`.
fn voxel_of(o: [i32; 3], k: usize) -> IVec3 {
    IVec3::from_array(o) + IVec3::new((k >> 6) as i32, ((k >> 3) & 7) as i32, (k & 7) as i32)
}

fn sample_grid(ty: Type) -> Grid {
    let origins = [[0, 0, 0], [8, 0, 0], [64, 120, 8], [120, 120, 120]];
    let mut leaves: Vec<nanovdb::Leaf> =
        origins.iter().map(|&o| leaf(o, |k| field(o, k))).collect();
    // Every third voxel of the second leaf inactive, holding a value that is not density.
    for k in (0..512).step_by(3) {
        leaves[1].active[k] = false;
        leaves[1].values[k] = 7.0;
    }
    let mut g = Grid::new(ty, leaves);
    g.lower_tiles = vec![(5, 2.5, true), (6, 9.0, false), (7, -1.0, true)];
    g.root_tiles = vec![([4096, 0, -4096], 0.75, true), ([8192, 0, 0], 3.0, false)];
    g
}

/// What the reader must give at index `c` of `g`: the stored value (decoded as NanoVDB
/// does) for active voxels, clamped at 0; 0 for inactive ones and outside.
fn expected(g: &Grid, c: IVec3) -> f32 {
    for l in &g.leaves {
        let o = IVec3::from_array(l.origin);
        let d = c - o;
        if d.cmpge(IVec3::ZERO).all() && d.cmplt(IVec3::splat(8)).all() {
            let k = (d.x * 64 + d.y * 8 + d.z) as usize;
            if !l.active[k] {
                return 0.0;
            }
            let v = l.values[k];
            let v = match g.ty {
                Type::Float => v,
                Type::Double => f64::from(v) as f32,
                Type::Half => half::f16::from_f32(v).to_f32(),
                Type::Fp4 | Type::Fp8 | Type::Fp16 | Type::FpN(_) => {
                    let bits = match g.ty {
                        Type::Fp4 => 4,
                        Type::Fp8 => 8,
                        Type::Fp16 => 16,
                        Type::FpN(b) => b,
                        _ => unreachable!(),
                    };
                    let (min, q) = nanovdb::quantum(l, bits);
                    let code = ((v - min) / q + 0.5) as u32;
                    code as f32 * q + min
                }
            };
            return v.max(0.0);
        }
    }
    for (n, v, a) in &g.lower_tiles {
        let o = IVec3::new((n >> 8) as i32, ((n >> 4) & 15) as i32, (n & 15) as i32) * 8;
        let d = c - o;
        if d.cmpge(IVec3::ZERO).all() && d.cmplt(IVec3::splat(8)).all() {
            return if *a { v.max(0.0) } else { 0.0 };
        }
    }
    for (o, v, a) in &g.root_tiles {
        let d = c - IVec3::from_array(*o);
        if d.cmpge(IVec3::ZERO).all() && d.cmplt(IVec3::splat(4096)).all() {
            return if *a { v.max(0.0) } else { 0.0 };
        }
    }
    0.0
}

fn all_types() -> Vec<Type> {
    let mut t = vec![
        Type::Float,
        Type::Double,
        Type::Half,
        Type::Fp4,
        Type::Fp8,
        Type::Fp16,
    ];
    t.extend([1, 2, 4, 8, 16].map(Type::FpN));
    t
}

#[test]
fn every_value_type_and_codec_reads_every_voxel() {
    let dir = tempfile::tempdir().unwrap();
    for ty in all_types() {
        let g = sample_grid(ty);
        for codec in [0u16, 1] {
            let at = format!("{ty:?} codec {codec}");
            let p = write(dir.path(), "g.nvdb", &file_bytes(&g, codec));
            let src = open_nvdb(&p, None, false).unwrap_or_else(|e| panic!("{at}: {e}"));
            let mut checked = 0;
            for l in &g.leaves {
                for k in 0..512 {
                    let c = voxel_of(l.origin, k);
                    assert_eq!(src.voxel(c), expected(&g, c), "{at}: voxel {c}");
                    checked += 1;
                }
            }
            for c in [
                IVec3::new(3, 2, 41),
                IVec3::new(1, 1, 50),
                IVec3::new(2, 2, 60),
                IVec3::new(4096 + 17, 3, -4000),
                IVec3::new(8192, 0, 0),
                IVec3::new(-5, 0, 0),
            ] {
                assert_eq!(src.voxel(c), expected(&g, c), "{at}: voxel {c}");
                checked += 1;
            }
            assert!(checked > 2000);
            // The tiles hold what they should (not only what `expected` says).
            assert_eq!(src.voxel(IVec3::new(3, 2, 41)), 2.5, "{at}");
            assert_eq!(src.voxel(IVec3::new(1, 1, 50)), 0.0, "{at}: inactive tile");
            assert_eq!(
                src.voxel(IVec3::new(4096 + 17, 3, -4000)),
                0.75,
                "{at}: root tile"
            );
            // Placement: NanoVDB's double-precision map.
            let w = src.index_to_world(DVec3::new(2.0, 4.0, 6.0));
            assert_eq!(w, DVec3::new(2.0, 0.0, 6.0), "{at}");
            assert!(
                src.describe().starts_with("nanovdb g.nvdb grid 'density'"),
                "{}",
                src.describe()
            );
        }
    }
}

/// A float grid whose every density is a half value (a VDB saved as half, converted) is kept
/// at half the bytes with the same values; one value that is not keeps the grid in f32.
#[test]
fn float_grids_of_half_values_are_kept_as_half() {
    let dir = tempfile::tempdir().unwrap();
    let mut g = sample_grid(Type::Float);
    for l in &mut g.leaves {
        for v in &mut l.values {
            *v = half::f16::from_f32(*v).to_f32();
        }
    }
    let p = write(dir.path(), "h.nvdb", &file_bytes(&g, 0));
    let halfs = open_nvdb(&p, None, false).unwrap();
    g.leaves[2].values[100] = 1.0 + f32::EPSILON;
    let p = write(dir.path(), "f.nvdb", &file_bytes(&g, 0));
    let floats = open_nvdb(&p, None, false).unwrap();
    for l in &g.leaves {
        for k in 0..512 {
            let c = voxel_of(l.origin, k);
            assert_eq!(floats.voxel(c), expected(&g, c), "voxel {c}");
            if c != voxel_of(g.leaves[2].origin, 100) {
                assert_eq!(halfs.voxel(c), floats.voxel(c), "voxel {c}");
            }
        }
    }
    assert_eq!(
        floats.voxel(voxel_of(g.leaves[2].origin, 100)),
        1.0 + f32::EPSILON
    );
    // 1 KiB instead of 2 per leaf, plus the 256 KiB table of the 65536 half values.
    let (h, f) = (halfs.memory_bytes(), floats.memory_bytes());
    assert_eq!(
        f + 256 * 1024 - h,
        1024 * g.leaves.len() as u64,
        "half {h} B, float {f} B"
    );
}

#[test]
fn level_sets_are_refused_unless_baked_as_fog() {
    let dir = tempfile::tempdir().unwrap();
    let mut g = sample_grid(Type::Float);
    g.level_set = true;
    let p = write(dir.path(), "ls.nvdb", &file_bytes(&g, 0));
    let e = open_nvdb(&p, None, false).unwrap_err();
    assert!(
        e.contains("level set") && e.contains("--levelset-to-fog"),
        "{e}"
    );
    let src = open_nvdb(&p, None, true).unwrap();
    // Inside (negative, active or not) is 1, outside 0; the inactive 7.0 values are outside.
    for l in &g.leaves {
        for k in 0..512 {
            let c = voxel_of(l.origin, k);
            let want = if l.values[k] < 0.0 { 1.0 } else { 0.0 };
            assert_eq!(src.voxel(c), want, "voxel {c}");
        }
    }
    assert_eq!(
        src.voxel(IVec3::new(2, 2, 60)),
        1.0,
        "a negative lower tile is inside"
    );
    assert_eq!(
        src.voxel(IVec3::new(3, 2, 41)),
        0.0,
        "a positive one is outside"
    );
}

#[test]
fn grid_selection_follows_the_vdb_rules() {
    let dir = tempfile::tempdir().unwrap();
    let mut g = sample_grid(Type::Fp8);
    g.name = "smoke".into();
    let p = write(dir.path(), "one.nvdb", &file_bytes(&g, 0));
    // The only float grid is picked without a name; a wrong name lists the grids.
    assert!(open_nvdb(&p, None, false).is_ok());
    let e = open_nvdb(&p, Some("density"), false).unwrap_err();
    assert!(
        e.contains("has no grid named 'density'; grids: smoke"),
        "{e}"
    );
    assert!(e.starts_with(&p.display().to_string()), "{e}");
}

// ---------------------------------------------------------------------------------------------
// The OpenVDB corpus through nanovdb_convert
// ---------------------------------------------------------------------------------------------

const CONVERT: &str = "nanovdb_convert";

/// The conversions checked: (label, nanovdb_convert options, bits of the quantised leaves).
const MODES: [(&str, &[&str], Option<u32>); 6] = [
    ("float", &[], None),
    ("zip", &["--zip"], None),
    ("fp4", &["--fp4"], Some(4)),
    ("fp8", &["--fp8"], Some(8)),
    ("fp16", &["--fp16"], Some(16)),
    ("fpN", &["--fpN", "--abs-error", "0.001"], Some(16)),
];
/// The absolute error the FpN conversion asks for.
const FPN_ABS_ERROR: f32 = 0.001;

/// Converts `vdb` to `out` with `opts`, or says why it could not.
fn convert(vdb: &Path, out: &Path, opts: &[&str]) -> Result<(), String> {
    let o = Command::new(CONVERT)
        .args(["-f"])
        .args(opts)
        .arg(vdb)
        .arg(out)
        .output()
        .map_err(|e| {
            format!(
                "cannot run {CONVERT}: {e} (apt-get install -y libnanovdb-tools; scripts/deps.sh installs it)"
            )
        })?;
    if !o.status.success() {
        return Err(format!(
            "{CONVERT} {opts:?} {}: {} {}",
            vdb.display(),
            o.status,
            String::from_utf8_lossy(&o.stderr).trim()
        ));
    }
    Ok(())
}

/// A conversion: its mode's label, the bits of its quantised leaves and the file.
type Converted = (&'static str, Option<u32>, PathBuf);

fn hash_of(bytes: &[u8]) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    bytes.hash(&mut h);
    h.finish()
}

fn small_bake() -> BakeOptions {
    BakeOptions {
        cells: [4, 4, 4],
        directions: Directions::Polar {
            n_phi: 4,
            n_theta: 2,
        },
        step: 0.02,
        majorant: Some([2, 2, 2]),
        threads: Some(2),
        ..BakeOptions::default()
    }
}

/// The pin bytes of a bake of `src`, without its metadata (which names the input file).
fn bake_bytes(src: &dyn DensitySource) -> Result<Vec<u8>, String> {
    let (mut grid, _) = pinbake::bake(src, &small_bake(), &|_| {}).map_err(|e| e.to_string())?;
    grid.metadata = None;
    grid.to_bytes().map_err(|e| e.to_string())
}

#[test]
fn the_openvdb_corpus_through_nanovdb_convert_reads_as_the_vdb() {
    let dir = openvdb::corpus(env!("CARGO_TARGET_TMPDIR"), "pinbake");
    let files = openvdb::manifest(dir);
    assert!(files.len() >= 18, "corpus has only {} files", files.len());
    let out = tempfile::tempdir().unwrap();
    let mut problems = Vec::new();
    let mut samples = 0u64;
    let mut grids_ok = std::collections::BTreeMap::<&str, u32>::new();
    let mut bakes_equal = 0u32;
    // The corpus writes each grid set in six compressions of the file, which OpenVDB reads
    // into the same grids: their plain conversions are the same bytes, and so are their
    // quantised ones, which are converted from the grids read. A file whose plain
    // conversion equals an earlier file's takes that file's other conversions instead of
    // running nanovdb_convert five more times (about half the runs), and every check below
    // still runs on it. (hash of the plain bytes, their file, that file's conversions)
    let mut plain: Vec<(u64, PathBuf, Vec<Converted>)> = Vec::new();
    let mut reused = 0u32;
    for f in &files {
        // The grids OpenVDB reads as scalar fog or level sets with a linear map.
        let wanted: Vec<&openvdb::Grid> = f
            .grids
            .iter()
            .filter(|g| {
                g.scalar && g.map != "NonlinearFrustumMap" && g.grid_type.starts_with("Tree_float")
            })
            .collect();
        if wanted.is_empty() {
            continue;
        }
        let mut converted: Vec<Converted> = Vec::new();
        // The conversions of an earlier file whose plain conversion has the same bytes.
        let mut same_as: Option<Vec<Converted>> = None;
        let mut plain_hash = None;
        for (mode, opts, bits) in MODES {
            if let Some(c) = same_as.iter().flatten().find(|c| c.0 == mode) {
                reused += 1;
                converted.push(c.clone());
                continue;
            }
            let nv = out.path().join(format!(
                "{}.{mode}.nvdb",
                f.file.file_stem().unwrap().to_string_lossy()
            ));
            match convert(&f.file, &nv, opts) {
                Ok(()) => converted.push((mode, bits, nv.clone())),
                Err(e) if e.starts_with("cannot run") => panic!("{e}"),
                Err(e) => problems.push(e),
            }
            if mode == "float" && nv.is_file() {
                let bytes = std::fs::read(&nv).unwrap();
                let h = hash_of(&bytes);
                same_as = plain.iter().find_map(|(ph, path, conv)| {
                    (*ph == h && std::fs::read(path).unwrap() == bytes).then(|| conv.clone())
                });
                plain_hash = Some((h, nv));
            }
        }
        if same_as.is_none()
            && let Some((h, nv)) = plain_hash
        {
            plain.push((h, nv, converted.clone()));
        }
        for g in &wanted {
            let level_set = g.class == "level set";
            // The .vdb through the OpenVDB path, read and baked once for every conversion.
            let vdb = VdbSource::open(
                &f.file,
                &VdbOptions {
                    grid: Some(g.selector()),
                    levelset_to_fog: level_set,
                    ..VdbOptions::with_worker(env!("CARGO_BIN_EXE_pinbake"))
                },
                pin_volume::DensityScale::ONE,
            )
            .expect("the corpus .vdb reads (tests/vdb_corpus.rs)");
            let mut vdb_bake = None;
            for (mode, bits, nv) in &converted {
                let (mode, bits) = (*mode, *bits);
                let level_set = g.class == "level set";
                let at = format!("{} ({mode}) grid '{}'", f.file.display(), g.name);
                let src = match open_nvdb(nv, Some(&g.selector()), level_set) {
                    Ok(s) => s,
                    Err(e) => {
                        problems.push(format!("{at}: not read: {e}"));
                        continue;
                    }
                };
                // Quantised leaves round each stored value to the nearest code of its leaf:
                // off by at most half a quantum, and a leaf's quantum is at most the range
                // of every stored value over the codes (FpN: the absolute error asked for).
                // Plus the f32 rounding of `code * quantum + minimum`.
                let (lo, hi) = g.leaf_range.unwrap_or((0.0, 0.0));
                let tol = match bits {
                    None => 0.0,
                    Some(_) if mode == "fpN" => FPN_ABS_ERROR,
                    Some(b) => 0.5 * (hi - lo) as f32 / ((1u32 << b) - 1) as f32,
                } * 1.0001
                    + 4.0 * f32::EPSILON * lo.abs().max(hi.abs()) as f32;
                let mut bad = 0;
                for (c, v, active) in &g.samples {
                    let c = IVec3::from_array(*c);
                    let ours = src.voxel(c);
                    let theirs = vdb.voxel(c);
                    samples += 1;
                    // Clamping at 0 only brings the two closer; a level set's inside test
                    // may flip where the distance is within the error of 0.
                    let ok = ours == theirs
                        || (!level_set && (ours - theirs).abs() <= tol)
                        || (level_set && (*v as f32).abs() <= tol);
                    if !ok {
                        bad += 1;
                        if bad <= 3 {
                            problems.push(format!(
                                "{at}: voxel {c}: ours {ours}, the .vdb {theirs} (OpenVDB {v}, active {active})"
                            ));
                        }
                    }
                }
                if bad > 3 {
                    problems.push(format!(
                        "{at}: {bad} of {} sampled voxels differ",
                        g.samples.len()
                    ));
                }
                if bits.is_none() && !level_set {
                    if src.index_bounds() != vdb.index_bounds() {
                        problems.push(format!(
                            "{at}: index bounds {:?}, the .vdb {:?}",
                            src.index_bounds(),
                            vdb.index_bounds()
                        ));
                    }
                    for (i, w) in &g.index_to_world {
                        let ours = src.index_to_world(DVec3::from_array(*i));
                        let w = DVec3::from_array(*w);
                        let tol = 1e-12 * (1.0 + w.abs().max_element());
                        if (ours - w).abs().max_element() > tol {
                            problems
                                .push(format!("{at}: index {i:?} -> world {ours}, OpenVDB {w}"));
                        }
                    }
                    let theirs = vdb_bake.get_or_insert_with(|| bake_bytes(&vdb));
                    match (bake_bytes(&src), theirs.as_ref()) {
                        (Ok(a), Ok(b)) if a == *b => bakes_equal += 1,
                        (Ok(_), Ok(_)) => {
                            problems.push(format!("{at}: the bake differs from the .vdb's"))
                        }
                        (a, b) => problems.push(format!(
                            "{at}: bake failed: {:?} / {:?}",
                            a.err(),
                            b.err()
                        )),
                    }
                }
                if bad == 0 {
                    *grids_ok.entry(mode).or_default() += 1;
                }
            }
        }
    }
    eprintln!(
        "grids read as their .vdb, per conversion: {grids_ok:?}; {samples} voxels compared; {bakes_equal} float bakes byte-equal; {reused} conversions reused"
    );
    assert!(
        problems.is_empty(),
        "{} problems:\n{}",
        problems.len(),
        problems.join("\n")
    );
    for (mode, _, _) in MODES {
        assert!(
            grids_ok.get(mode).copied().unwrap_or(0) >= 10,
            "{mode}: {grids_ok:?}"
        );
    }
    assert!(bakes_equal >= 20, "{bakes_equal}");
}
