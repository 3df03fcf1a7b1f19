//! Budgets that hold before the first allocation: a VDB of a few hundred bytes, written by
//! OpenVDB, whose eight active 4096^3 root tiles declare 2^39 voxels. Its sparse density is
//! 1.07 G bricks: the bake must refuse it from the tree's counts (memory) and from its
//! tiles (disk) before it lists a single brick.

use super::*;

/// `root_tiles.vdb` of the OpenVDB corpus (`tests/openvdb/corpus.cpp`).
fn root_tiles() -> PathBuf {
    super::openvdb::corpus(env!("CARGO_TARGET_TMPDIR"), "pinbake").join("root_tiles.vdb")
}

#[test]
fn root_tiles_sparse_density_is_refused_by_memory_before_it_is_built() {
    let vdb = root_tiles();
    assert!(
        std::fs::metadata(&vdb).unwrap().len() < 4096,
        "a small file"
    );
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("roots.pin");
    for limit in ["100M", "200M"] {
        let r = run(&[
            "bake",
            vdb.to_str().unwrap(),
            "--embed-density",
            "sparse",
            "--max-memory",
            limit,
            "-o",
            out.to_str().unwrap(),
        ]);
        // Listing the candidate bricks to count them held gigabytes before the check.
        expect(&format!("--max-memory {limit}"), &r, 1, "--max-memory");
        assert!(r.rss_kib < 64 * 1024, "{limit}: peak RSS {} KiB", r.rss_kib);
        assert!(!out.exists());
    }
    assert_eq!(partials(dir.path()), Vec::<String>::new());
}

#[test]
fn root_tiles_sparse_density_is_refused_by_disk_before_it_starts() {
    let vdb = root_tiles();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("roots.pin");
    // A budget that the estimate (the index and candidate lists of 1.07 G brick slots)
    // passes: only the disk can refuse, and the tiles alone need 2 x 1.1 TB (the spool and
    // the file that copies it), more than any test machine's disk.
    let r = run(&[
        "bake",
        vdb.to_str().unwrap(),
        "--embed-density",
        "sparse",
        "--max-memory",
        "1T",
        "-o",
        out.to_str().unwrap(),
    ]);
    expect("disk", &r, 1, "bytes free on its file system");
    let line = r.stderr.trim();
    assert!(line.contains("roots.pin"), "names the output: {line}");
    // 2^39 voxels in 1 KiB bricks of 8^3, less the bricks that touch a tile's border,
    // twice: at least 2 TB.
    let need: u64 = line
        .split("needs about ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no size in {line}"));
    assert!(
        (2_000_000_000_000..=2_200_000_000_000).contains(&need),
        "{need}"
    );
    assert!(!out.exists());
    assert_eq!(partials(dir.path()), Vec::<String>::new());
}
