//! A farm part's VDB read: its slab's leaves, the whole grid's statistics, and the merge of
//! the parts' bakes into the whole grid's bake.

use std::path::PathBuf;

use pin_format::Directions;
use pin_volume::vdb::{GridStats, VdbOptions, VdbPart, VdbSource};
use pin_volume::{Density, DensityScale, DensitySource};
use pinbake::bake::{BakeOptions, Provenance, bake_metadata};
use pinbake::part::{Part, bake_part};

fn data(name: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../data")).join(name)
}

/// A part read (`VdbOptions::part`, through the worker process) keeps only its slab's leaves and a margin, counts
/// the others in its statistics (box, leaf count, description, stored voxels), and the
/// parts of a bake merge into the whole grid's bake: for a rotated grid (the smoke, baked
/// in its frame), a level set and an axis-aligned grid, with density scales; both ways,
/// the leaves outside the slab decoded and summarised, and skipped undecoded with the
/// grid's statistics from the statistics pass. A density scale of 2^-150 over the
/// gaffer sphere's median leaf maximum turns the smaller values to 0 in f32: active
/// leaves that are all zero, and a non-zero box smaller than the active one, which the
/// statistics must give exactly.
#[test]
fn parts_hold_their_slab_and_merge_into_the_whole_bake() {
    for (file, to_fog, scale) in [
        ("openvdb_smoke1.vdb", false, 1.0),
        ("openvdb_sphere_levelset.vdb", true, 2.5),
        ("gaffer_sphere_density.vdb", false, 0.5),
        ("gaffer_sphere_density.vdb", false, f64::NAN),
    ] {
        let tiny = scale.is_nan();
        let p = data(file);
        let vdb_opts = |part: Option<VdbPart>, grid_stats: Option<Box<GridStats>>| VdbOptions {
            levelset_to_fog: to_fog,
            part,
            grid_stats,
            ..VdbOptions::with_worker(env!("CARGO_BIN_EXE_pinbake"))
        };
        let scale = if tiny {
            let s = VdbSource::open(&p, &vdb_opts(None, None), DensityScale::ONE).unwrap();
            let mut m = s.leaf_maxima().to_vec();
            m.sort_by(f32::total_cmp);
            2f64.powi(-150) / f64::from(m[m.len() / 2])
        } else {
            scale
        };
        let ds = DensityScale::new(scale).unwrap();
        // The statistics pass.
        let stats = VdbSource::grid_stats(&p, &vdb_opts(None, None), ds).unwrap();
        // A part read summarises the leaves outside its slab, or skips them given the
        // statistics.
        let read = |part: Option<VdbPart>, skip: bool| {
            let g = skip.then(|| Box::new(stats.clone()));
            VdbSource::open(&p, &vdb_opts(part, g), ds).unwrap()
        };
        let (cells, directions) = ([5, 4, 6], Directions::Octahedral { n: 3 });
        let opts = |s: &VdbSource| BakeOptions {
            cells,
            directions,
            density_scale: scale,
            majorant: Some([3, 2, 3]),
            metadata: bake_metadata(
                s,
                Provenance {
                    source_name: file.into(),
                    source_hash: String::new(),
                    seed: 0,
                    step: 0.01,
                    density_scale: scale,
                    crop: true,
                },
                cells,
                directions,
            ),
            ..BakeOptions::default()
        };
        let whole = read(None, false);
        let (lo, hi) = whole.index_bounds();
        assert_eq!(stats.nonzero_box, Some([lo.to_array(), hi.to_array()]));
        if tiny {
            assert!(
                stats.nonzero_leaves < stats.leaves,
                "{file}: no zero leaves"
            );
            let (alo, ahi) = VdbSource::open(&p, &vdb_opts(None, None), DensityScale::ONE)
                .unwrap()
                .index_bounds();
            assert!(
                alo.cmplt(lo).any() || ahi.cmpgt(hi).any(),
                "{file}: the box did not shrink"
            );
        }
        let want = pinbake::bake(&whole, &opts(&whole), &|_| {})
            .unwrap()
            .0
            .to_bytes()
            .unwrap();
        for (count, skip) in [1, 2, 3, 5]
            .into_iter()
            .flat_map(|n| [(n, false), (n, true)])
        {
            let parts: Vec<_> = (0..count)
                .map(|index| {
                    let s = read(Some(VdbPart { index, count }), skip);
                    assert_eq!(s.describe(), whole.describe(), "{file}");
                    assert_eq!(s.bounds(), whole.bounds(), "{file}");
                    assert_eq!(s.index_bounds(), whole.index_bounds(), "{file}");
                    assert_eq!(s.stored_voxels(), whole.stored_voxels(), "{file}");
                    if file == "openvdb_smoke1.vdb" && count == 3 {
                        assert!(
                            s.leaf_maxima().len() < whole.leaf_maxima().len() * 3 / 4,
                            "{file} part {index}: {} of {} leaves",
                            s.leaf_maxima().len(),
                            whole.leaf_maxima().len()
                        );
                    }
                    let d = bake_part(&s, &opts(&s), Part { index, count }, &|_| {}).unwrap();
                    (format!("{file} {index}/{count}"), d)
                })
                .collect();
            let got = pinbake::merge_parts(&parts).unwrap().0.to_bytes().unwrap();
            assert!(
                got == want,
                "{file}: {count} parts (skipping: {skip}) differ from the whole bake"
            );
        }
    }
}
