//! Our VDB reader against OpenVDB itself: every file of the corpus that `openvdb/corpus.cpp`
//! writes with OpenVDB 10 (every compression, half and float, tiles at every level, non-zero
//! inactive values, repeated and odd names, vector and bool grids alongside, every linear
//! transform, huge sparse extents, one-voxel grids, level sets) is read through the isolated
//! worker and compared with what OpenVDB reads back from the same file: the value at every
//! sampled voxel exactly, the active bounding box, index-to-world, and a bake of every float
//! grid. Prints the matrix of encodings against results.

use std::collections::BTreeMap;

use crate::openvdb;
use glam::{DVec3, IVec3};
use pin_format::Directions;
use pin_volume::vdb::{VdbOptions, VdbSource};
use pin_volume::{Density, DensitySource};
use pinbake::BakeOptions;

fn open(file: &std::path::Path, grid: &str, level_set: bool) -> Result<VdbSource, String> {
    let opt = VdbOptions {
        grid: Some(grid.to_string()),
        levelset_to_fog: level_set,
        ..VdbOptions::with_worker(env!("CARGO_BIN_EXE_pinbake"))
    };
    VdbSource::open(file, &opt, pin_volume::DensityScale::ONE).map_err(|e| e.to_string())
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

/// The value our reader must give at a voxel where OpenVDB reads `v` (`active` or not).
/// Fog volumes: active values clamped at 0, inactive voxels 0 (inactive values are not
/// density, whatever they hold). Level sets baked as fog: 1 inside (negative), else 0.
fn expected(v: f64, active: bool, level_set: bool) -> f32 {
    if level_set {
        if v < 0.0 { 1.0 } else { 0.0 }
    } else if active {
        (v as f32).max(0.0)
    } else {
        0.0
    }
}

/// Compares one float grid with OpenVDB's dump; returns a list of problems.
fn check_grid(file: &openvdb::File, g: &openvdb::Grid, samples: &mut u64) -> Vec<String> {
    let level_set = g.class == "level set";
    let at = format!("{} grid '{}'", file.file.display(), g.name);
    let src = match open(&file.file, &g.selector(), level_set) {
        Ok(s) => s,
        Err(e) => return vec![format!("{at}: not read: {e}")],
    };
    let mut problems = Vec::new();
    let mut bad = 0usize;
    for (c, v, active) in &g.samples {
        let want = expected(*v, *active, level_set);
        let got = src.voxel(IVec3::from_array(*c));
        *samples += 1;
        if got != want {
            bad += 1;
            if bad <= 3 {
                problems.push(format!(
                    "{at}: voxel {c:?}: ours {got}, OpenVDB {v} (active {active}) -> expected {want}"
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
    if !level_set {
        let (lo, hi) = src.index_bounds();
        if (lo.to_array(), hi.to_array()) != g.active_bbox {
            problems.push(format!(
                "{at}: index bounds {lo}..{hi}, OpenVDB's active box {:?}",
                g.active_bbox
            ));
        }
    }
    for (i, w) in &g.index_to_world {
        let ours = src.index_to_world(DVec3::from_array(*i));
        let w = DVec3::from_array(*w);
        // Both evaluate the same affine map in f64; only the order of the additions differs.
        let tol = 1e-12 * (1.0 + w.abs().max_element());
        if (ours - w).abs().max_element() > tol {
            problems.push(format!(
                "{at}: index {i:?} -> world {ours}, OpenVDB says {w}"
            ));
        }
    }
    let rotated = g.map == "AffineMap" || g.map == "UnitaryMap";
    if src.is_axis_aligned() == rotated {
        problems.push(format!(
            "{at}: map {} but axis-aligned = {}",
            g.map,
            src.is_axis_aligned()
        ));
    }
    if g.grid_type == "Tree_float_5_4_3" || g.grid_type == "Tree_float_5_4_3_HalfFloat" {
        let says_half = src.describe().contains("saved as half");
        if says_half != g.half {
            problems.push(format!(
                "{at}: half = {}, ours says {}",
                g.half,
                src.describe()
            ));
        }
    }
    match pinbake::bake(&src, &small_bake(), &|_| {}) {
        Ok((grid, stats)) => {
            let m = grid.desc.local_to_world;
            let ok = if src.is_axis_aligned() {
                m == [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]
            } else {
                // A rigid placement of the grid's own frame, at OpenVDB's index origin.
                let q = glam::DMat3::from_cols_array(&[
                    m[0], m[4], m[8], m[1], m[5], m[9], m[2], m[6], m[10],
                ]);
                let w0 = DVec3::from_array(g.index_to_world[0].1);
                (q.transpose() * q - glam::DMat3::IDENTITY)
                    .to_cols_array()
                    .iter()
                    .all(|e| e.abs() < 1e-12)
                    && (DVec3::new(m[3], m[7], m[11]) - w0).abs().max_element() < 1e-12
            };
            if !ok {
                problems.push(format!("{at}: baked local_to_world {m:?}"));
            }
            if !(stats.t_min_min >= 0.0 && stats.t_min_max <= 1.0) {
                problems.push(format!("{at}: bake statistics out of range: {stats:?}"));
            }
        }
        Err(e) => problems.push(format!("{at}: bake failed: {e}")),
    }
    problems
}

#[test]
fn openvdb_corpus_reads_exactly_and_every_float_grid_bakes() {
    let dir = openvdb::corpus(env!("CARGO_TARGET_TMPDIR"), "pinbake");
    let files = openvdb::manifest(dir);
    assert!(files.len() >= 18, "corpus has only {} files", files.len());
    let mut problems = Vec::new();
    let mut samples = 0u64;
    // encoding -> (float grids read exactly, float grids failing, other grids refused by type)
    let mut matrix: BTreeMap<String, (u32, u32, u32)> = BTreeMap::new();
    let mut maps: BTreeMap<String, u32> = BTreeMap::new();
    let mut unsupported: BTreeMap<String, u32> = BTreeMap::new();
    for f in &files {
        for g in &f.grids {
            let row = matrix.entry(f.encoding.clone()).or_default();
            if !g.scalar {
                // Vector and bool grids sit beside the float grids; asking for one by name
                // is a clear refusal, never a misread.
                match open(&f.file, &g.selector(), false) {
                    Ok(_) => problems.push(format!(
                        "{}: grid '{}' of type {} was accepted",
                        f.file.display(),
                        g.name,
                        g.grid_type
                    )),
                    Err(e) if e.contains("only float, half and double scalar grids") => row.2 += 1,
                    Err(e) => problems.push(format!("{}: {e}", f.file.display())),
                }
                continue;
            }
            if g.map == "NonlinearFrustumMap" {
                // Valid, but not a linear map: refused as an unsupported encoding, never
                // blamed on the file.
                match open(&f.file, &g.selector(), false) {
                    Err(e) if e.contains("unsupported encoding") && !e.contains("corrupt") => {
                        *unsupported.entry(g.map.clone()).or_default() += 1
                    }
                    other => problems.push(format!(
                        "{}: frustum grid: {:?}",
                        f.file.display(),
                        other.map(|s| s.describe())
                    )),
                }
                continue;
            }
            let p = check_grid(f, g, &mut samples);
            if p.is_empty() {
                row.0 += 1;
                *maps.entry(g.map.clone()).or_default() += 1;
            } else {
                row.1 += 1;
                problems.extend(p);
            }
        }
    }
    eprintln!("encoding            float grids exact  failing  other grids refused");
    for (enc, (ok, bad, other)) in &matrix {
        eprintln!("{enc:<20}{ok:>17}{bad:>9}{other:>22}");
    }
    eprintln!("transform maps read exactly: {maps:?}; {samples} voxels compared");
    eprintln!("refused as unsupported encodings: {unsupported:?}");
    if unsupported.get("NonlinearFrustumMap") != Some(&1) {
        problems.push("the frustum grid was not refused as an unsupported encoding".into());
    }
    // Every map OpenVDB's linear transforms simplify to is covered (a pure translation is
    // written as a UniformScaleTranslateMap; OpenVDB's Transform never keeps a TranslationMap).
    for m in [
        "UniformScaleMap",
        "ScaleMap",
        "UniformScaleTranslateMap",
        "ScaleTranslateMap",
        "AffineMap",
    ] {
        if !maps.contains_key(m) {
            problems.push(format!("no grid with a {m} was read exactly"));
        }
    }
    assert!(
        problems.is_empty(),
        "{} problems:\n{}",
        problems.len(),
        problems.join("\n")
    );
}

/// The sampled voxels that `value` gets wrong against OpenVDB's dump of `g`.
fn mismatches(g: &openvdb::Grid, level_set: bool, value: impl Fn(IVec3) -> f32) -> usize {
    g.samples
        .iter()
        .filter(|(c, v, a)| value(IVec3::from_array(*c)) != expected(*v, *a, level_set))
        .count()
}

/// The comparison can fail: readers with plausible bugs (inactive values kept as density,
/// voxels off by one, half values read as rounded floats) disagree with OpenVDB's dump of
/// the half-float Blosc grid at sampled voxels, while ours agrees everywhere.
#[test]
fn the_value_check_detects_a_wrong_reader() {
    let dir = openvdb::corpus(env!("CARGO_TARGET_TMPDIR"), "pinbake");
    let files = openvdb::manifest(dir);
    let f = files
        .iter()
        .find(|f| f.file.ends_with("enc_half_blosc_mask.vdb"))
        .expect("the half Blosc file in the corpus");
    let g = f.grids.iter().find(|g| g.name == "density").unwrap();
    assert!(g.half);
    let src = open(&f.file, "density", false).unwrap();
    assert_eq!(mismatches(g, false, |c| src.voxel(c)), 0);
    let dump: std::collections::HashMap<[i32; 3], (f64, bool)> =
        g.samples.iter().map(|(c, v, a)| (*c, (*v, *a))).collect();
    let kept_inactive = mismatches(g, false, |c| {
        let (v, a) = dump[&c.to_array()];
        if a { src.voxel(c) } else { v as f32 }
    });
    assert!(
        kept_inactive > 0,
        "the corpus must hold non-zero inactive values"
    );
    let shifted = mismatches(g, false, |c| src.voxel(c + IVec3::X));
    assert!(shifted > 0, "{shifted}");
    // The comparison is exact: values one f32 ulp off (a different half conversion, say)
    // must show.
    let perturbed = mismatches(g, false, |c| {
        let v = src.voxel(c);
        if v > 0.0 {
            f32::from_bits(v.to_bits() + 1)
        } else {
            v
        }
    });
    assert!(perturbed > 0, "{perturbed}");
}

/// Part reads that skip the leaves outside their slab undecoded, with the grid's statistics
/// from `VdbSource::grid_stats`, hold the whole read's statistics and merge into its bake's
/// bytes, in every encoding of the corpus (float and half; none, ZIP, Blosc, each with and
/// without active-mask compression: every way `skip_leaf` must find a leaf's end) and on
/// the grids with tiles at levels 1 and 2 (`density`, `density64`) and root tiles (`roots`).
/// At the density scale 2^-150 every value below 1 becomes 0 in f32: most leaves are then
/// active but all zero, some tiles too, and the non-zero box is smaller than the active box.
/// Verified to fail when `VdbSource::from_stream` ignores the statistics' non-zero box (a
/// part's bounds then differ from the whole read's) and when `skip_leaf` does not move past
/// a leaf's inactive values (the next leaf is misread: "could not be read").
#[test]
fn parts_skip_leaves_undecoded_in_every_encoding() {
    use pinbake::{Part, bake_part, merge_parts};
    let dir = openvdb::corpus(env!("CARGO_TARGET_TMPDIR"), "pinbake");
    let files = openvdb::manifest(dir);
    let mut checked = 0;
    let mut shrunk = 0;
    for f in files
        .iter()
        .filter(|f| f.file.to_string_lossy().contains("enc_"))
    {
        for grid in ["density", "density64", "roots"] {
            for scale in [1.0, 2f64.powi(-150)] {
                let base = VdbOptions {
                    grid: Some(grid.into()),
                    ..VdbOptions::with_worker(env!("CARGO_BIN_EXE_pinbake"))
                };
                let ds = pin_volume::DensityScale::new(scale).unwrap();
                let at = format!("{} {grid} x {scale}", f.file.display());
                let whole = match VdbSource::open(&f.file, &base, ds) {
                    Ok(s) => s,
                    // Every value of `roots` but the root tiles' is below 1.
                    Err(e) if e.to_string().contains("all are zero") => continue,
                    Err(e) => panic!("{at}: {e}"),
                };
                let stats = VdbSource::grid_stats(&f.file, &base, ds)
                    .unwrap_or_else(|e| panic!("{at}: {e}"));
                let g = f.grids.iter().find(|g| g.name == grid).unwrap();
                let (lo, hi) = whole.index_bounds();
                if IVec3::from_array(g.active_bbox.0).cmplt(lo).any()
                    || IVec3::from_array(g.active_bbox.1).cmpgt(hi).any()
                {
                    shrunk += 1;
                }
                let opts = small_bake();
                let want = pinbake::bake(&whole, &opts, &|_| {})
                    .unwrap()
                    .0
                    .to_bytes()
                    .unwrap();
                // Three parts: a first, a middle and a last part, every kind of boundary.
                let count = 3;
                let parts: Vec<_> = (0..count)
                    .map(|index| {
                        let o = VdbOptions {
                            part: Some(pin_volume::VdbPart { index, count }),
                            grid_stats: Some(Box::new(stats.clone())),
                            ..base.clone()
                        };
                        let s = VdbSource::open(&f.file, &o, ds)
                            .unwrap_or_else(|e| panic!("{at} {index}/{count}: {e}"));
                        assert_eq!(s.describe(), whole.describe(), "{at}");
                        assert_eq!(s.bounds(), whole.bounds(), "{at}");
                        assert_eq!(s.stored_voxels(), whole.stored_voxels(), "{at}");
                        let d = bake_part(&s, &opts, Part { index, count }, &|_| {}).unwrap();
                        (format!("{at} {index}/{count}"), d)
                    })
                    .collect();
                let got = merge_parts(&parts).unwrap().0.to_bytes().unwrap();
                assert!(
                    got == want,
                    "{at}: {count} parts differ from the whole bake"
                );
                checked += 1;
            }
        }
    }
    // 12 encodings x (density, density64) x 2 scales, and roots at scale 1.
    assert!(checked >= 12 * 5, "{checked} grids checked");
    assert!(
        shrunk >= 12,
        "{shrunk} grids with a non-zero box inside the active box"
    );
}
