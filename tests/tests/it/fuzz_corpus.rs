//! Bounded CI smoke for the fuzz targets of `pinbake/fuzz/`: replays every committed corpus
//! file through the same entry points the fuzzer runs (`pin_tests::fuzz_raw`,
//! `pin_tests::fuzz_vdb`), without libFuzzer. Also the regression inputs, if any, under
//! `pinbake/fuzz/regressions/<target>/`.

use std::path::PathBuf;

use pin_tests::Outcome;

fn corpus(target: &str) -> Vec<PathBuf> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../pinbake/fuzz");
    let mut v = Vec::new();
    for sub in ["corpus", "regressions"] {
        if let Ok(rd) = std::fs::read_dir(root.join(sub).join(target)) {
            v.extend(rd.map(|e| e.unwrap().path()).filter(|p| p.is_file()));
        }
    }
    v.sort();
    v
}

#[test]
fn raw_corpus_replays_cleanly() {
    let files = corpus("raw");
    assert!(
        files.len() >= 10,
        "the raw seed corpus is missing: {files:?}"
    );
    let dir = tempfile::tempdir().unwrap();
    let (mut acc, mut baked) = (0, 0);
    for f in &files {
        let data = std::fs::read(f).unwrap();
        match pin_tests::fuzz_raw(&data, dir.path()) {
            Outcome::Accepted { baked: b, .. } => {
                acc += 1;
                baked += usize::from(b);
            }
            Outcome::Refused(_) | Outcome::TooShort => {}
        }
    }
    eprintln!(
        "raw corpus: {} files, {acc} accepted ({baked} baked and verified)",
        files.len()
    );
    assert!(acc >= 5 && baked >= 5);
}

#[test]
fn vdb_guard_corpus_replays_cleanly() {
    let files = corpus("vdb_guard");
    assert!(
        files.len() >= 8,
        "the vdb_guard seed corpus is missing: {files:?}"
    );
    let dir = tempfile::tempdir().unwrap();
    let mut acc = 0;
    for f in &files {
        let data = std::fs::read(f).unwrap();
        if let Outcome::Accepted { .. } =
            pin_tests::fuzz_vdb(&data, dir.path(), &crate::common::vdb_worker())
        {
            acc += 1;
        }
    }
    eprintln!("vdb_guard corpus: {} files, {acc} accepted", files.len());
    assert!(acc >= 1, "the valid seed must open");
}
