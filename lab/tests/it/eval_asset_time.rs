//! `pinrender eval --default-asset` end to end, shrunk (hydrogen at 16 px, 8 reference spp,
//! one 0.01 s budget): `asset_time.csv` with its exact header and `asset_time.md`, a row per
//! estimator the default file allows alone and beside the volume, the default rule's pick
//! marked once per input and budget, and the file's real size.

use std::process::Command;

const HEADER: &str =
    "scene,input,estimator,default,budget_s,spp,seconds,rmse,block8_error,mean_error,file_bytes";

#[test]
fn eval_default_asset_measures_each_estimator_the_default_file_allows() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("asset");
    let run = Command::new(env!("CARGO_BIN_EXE_pinrender"))
        .args(["eval", "--default-asset", "--scenes", "hydrogen"])
        .args(["--size", "16", "--ref-spp", "8", "--budgets", "0.01"])
        .args(["--clock", "cpu", "--threads", "2", "--no-gpu", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(run.status.success(), "{run:?}");
    let csv = std::fs::read_to_string(out.join("asset_time.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some(HEADER));
    let rows: Vec<Vec<String>> = lines
        .map(|l| l.split(',').map(String::from).collect())
        .collect();
    let pick = |input: &str| -> Vec<String> {
        rows.iter()
            .filter(|r| r[1] == input && r[3] == "true")
            .map(|r| r[2].clone())
            .collect()
    };
    // The default file of a raw grid embeds its density: ratio tracking alone, PinMS beside
    // the volume (the rule of `pinrender::front::default_estimator`).
    assert_eq!(pick("file"), ["ratio"], "{csv}");
    assert_eq!(pick("volume+file"), ["pinms"], "{csv}");
    for input in ["file", "volume+file"] {
        for est in ["ratio", "pins", "pinms", "delta"] {
            assert!(
                rows.iter().any(|r| r[1] == input && r[2] == est),
                "{input} {est}: {csv}"
            );
        }
    }
    let bytes = std::fs::metadata(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../data/hydrogen_atom_128x128x128_uint8.raw"),
    )
    .unwrap()
    .len();
    for r in &rows {
        assert_eq!(r.len(), 11, "{r:?}");
        assert!(r[5].parse::<u32>().unwrap() >= 1, "{r:?}");
        for v in &r[6..10] {
            assert!(v.parse::<f64>().unwrap().is_finite(), "{r:?}");
        }
        // The default bake is no larger than its source (plus the allowance).
        let file: u64 = r[10].parse().unwrap();
        assert!(file > 0 && file <= bytes + (64 << 10), "{r:?}");
    }
    let md = std::fs::read_to_string(out.join("asset_time.md")).unwrap();
    assert!(
        md.contains("## hydrogen") && md.contains("ratio (default)"),
        "{md}"
    );
}
