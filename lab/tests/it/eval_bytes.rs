//! `pinrender eval --bytes --quick` end to end, shrunk (16 px, 8 reference spp): the CSV
//! contract (`bytes.csv` with its exact header, `bytes.png`, `bytes.md`) and its invariants:
//! every representation's bytes positive and growing along its ladder, every error finite,
//! and the source file's row carrying that file's real size.

use std::collections::BTreeMap;
use std::process::Command;

const HEADER: &str = "scene,representation,bytes,mean_error,block8_error,rmse,seconds_per_spp";

#[test]
fn eval_bytes_quick_writes_the_contract_and_its_ladders_grow() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bytes");
    let run = Command::new(env!("CARGO_BIN_EXE_pinrender"))
        .args([
            "eval",
            "--bytes",
            "--quick",
            "--size",
            "16",
            "--ref-spp",
            "8",
        ])
        .args(["--threads", "2", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(run.status.success(), "{run:?}");
    let csv = std::fs::read_to_string(out.join("bytes.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some(HEADER));
    // (scene, representation) -> the bytes of its rungs in file order.
    let mut ladders: BTreeMap<(String, String), Vec<u64>> = BTreeMap::new();
    for line in lines {
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(f.len(), 7, "{line}");
        let bytes: u64 = f[2].parse().unwrap_or_else(|e| panic!("{line}: {e}"));
        assert!(bytes > 0, "{line}");
        for (k, v) in f[3..].iter().enumerate() {
            let v: f64 = v.parse().unwrap_or_else(|e| panic!("{line}: {e}"));
            assert!(v.is_finite(), "{line}");
            // The block error, RMSE and seconds per spp are magnitudes.
            if k > 0 {
                assert!(v >= 0.0, "{line}");
            }
        }
        ladders
            .entry((f[0].to_string(), f[1].to_string()))
            .or_default()
            .push(bytes);
    }
    for ((scene, rep), bytes) in &ladders {
        assert!(
            bytes.windows(2).all(|w| w[0] < w[1]),
            "{scene}: {rep}: bytes do not grow along the ladder: {bytes:?}"
        );
    }
    // The quick run: the smoke, every kind of representation, the pin ladders of 3 rungs.
    let reps: Vec<&str> = ladders.keys().map(|(_, r)| r.as_str()).collect();
    for want in [
        "source file (ratio)",
        "pins oct:8",
        "dense f16 (ratio)",
        "sparse f16 (ratio)",
        "dense f16 + pins c8 oct:8 (pinms)",
    ] {
        assert!(reps.contains(&want), "no {want} in {reps:?}");
    }
    assert_eq!(ladders[&("smoke".into(), "pins oct:8".into())].len(), 3);
    // Bytes are the size of the file a user ships: the source's row is the VDB's own size.
    let vdb = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/openvdb_smoke1.vdb");
    assert_eq!(
        ladders[&("smoke".into(), "source file (ratio)".into())],
        vec![std::fs::metadata(vdb).unwrap().len()]
    );
    let png = std::fs::read(out.join("bytes.png")).unwrap();
    assert!(png.starts_with(b"\x89PNG"), "bytes.png is not a PNG");
    let md = std::fs::read_to_string(out.join("bytes.md")).unwrap();
    assert!(
        md.contains("## smoke") && md.contains("| pins oct:8 |"),
        "{md}"
    );
    // The bakes' files are gone: only the reference cache stays.
    for e in std::fs::read_dir(out.join("cache")).unwrap() {
        let name = e.unwrap().file_name().into_string().unwrap();
        assert!(!name.starts_with("bytes-"), "left behind: {name}");
    }
}

#[test]
fn eval_bytes_rejects_scenes_without_a_volume_file() {
    let dir = tempfile::tempdir().unwrap();
    for args in [
        &["eval", "--bytes", "--quick", "--scenes", "cosine"][..],
        &["eval", "--bytes", "--quick", "--scenes", "teapot"][..],
        &["eval", "--quick", "--pin-variants"][..],
        // The error-against-time flags do not apply to --bytes.
        &["eval", "--bytes", "--quick", "--budgets", "1"][..],
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_pinrender"))
            .args(args)
            .arg("--out")
            .arg(dir.path())
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2), "{args:?}: {out:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        let first = err.lines().next().unwrap_or_default();
        assert!(
            ["cosine", "teapot", "--bytes"]
                .iter()
                .any(|w| first.contains(w)),
            "{args:?}: {err}"
        );
    }
}
