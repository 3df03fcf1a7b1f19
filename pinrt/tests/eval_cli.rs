//! `pinrender eval --quick` end to end: every scene and estimator gets a CSV row per budget
//! with finite errors, and the plots, montages and report are written.

use std::collections::BTreeSet;
use std::process::Command;

const EXPECTED: [(&str, &[&str]); 6] = [
    (
        "smoke",
        &[
            "rm@0.05",
            "rm@0.015",
            "rm@0.005",
            "delta",
            "ratio",
            "pins",
            "pinms",
            "pinms+cache",
        ],
    ),
    (
        "hydrogen",
        &[
            "rm@0.05",
            "rm@0.015",
            "rm@0.005",
            "delta",
            "ratio",
            "pins",
            "pinms",
            "pinms+cache",
        ],
    ),
    (
        "cosine",
        &[
            "rm@0.05",
            "rm@0.015",
            "rm@0.005",
            "delta",
            "ratio",
            "pins",
            "pinms",
            "pinms+cache",
            "cosine-closed-form",
        ],
    ),
    (
        "box",
        &[
            "rm@0.05",
            "rm@0.015",
            "rm@0.005",
            "delta",
            "ratio",
            "pins",
            "pinms",
            "pinms+cache",
            "box-closed-form",
        ],
    ),
    (
        "box-ss",
        &[
            "rm@0.05",
            "rm@0.015",
            "rm@0.005",
            "delta",
            "ratio",
            "pins",
            "box-closed-form",
            "whole-volume",
        ],
    ),
    (
        "instances",
        &[
            "rm@0.05",
            "rm@0.015",
            "rm@0.005",
            "delta",
            "ratio",
            "pins",
            "pinms",
            "pinms+cache",
        ],
    ),
];

#[test]
fn eval_quick_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("eval");
    let docs = dir.path().join("docs");
    std::fs::create_dir_all(&docs).unwrap();
    // A docs file with the companion-papers marker: everything from it on must survive.
    let tail = "<!-- companion papers -->\n\n## Paper sections\n\nkept verbatim\n";
    std::fs::write(docs.join("evaluation.md"), format!("# old head\n\n{tail}")).unwrap();
    let status = Command::new(env!("CARGO_BIN_EXE_pinrender"))
        .args(["eval", "--quick", "--out"])
        .arg(&out)
        .arg("--docs")
        .arg(&docs)
        .status()
        .unwrap();
    assert!(status.success(), "pinrender eval --quick failed: {status}");

    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("scene,estimator,backend,budget_s,spp,seconds,rmse,rel_mse")
    );
    let mut seen = BTreeSet::new();
    let mut budgets = BTreeSet::new();
    for line in lines {
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(f.len(), 8, "{line}");
        assert_eq!(f[2], "cpu");
        let spp: u32 = f[4].parse().unwrap();
        assert!(spp >= 1, "{line}");
        for v in [f[3], f[5], f[6], f[7]] {
            let x: f64 = v.parse().unwrap();
            assert!(x.is_finite() && x >= 0.0, "{line}");
        }
        seen.insert((f[0].to_string(), f[1].to_string()));
        budgets.insert(f[3].to_string());
    }
    assert_eq!(budgets.len(), 2, "two --quick budgets");
    for (scene, ests) in EXPECTED {
        for e in ests {
            assert!(
                seen.contains(&(scene.to_string(), e.to_string())),
                "no rows for {scene} / {e}"
            );
        }
        for f in [
            format!("error_vs_time_{scene}.png"),
            format!("images_{scene}.png"),
        ] {
            assert!(out.join(&f).is_file(), "{f}");
            assert!(docs.join("eval").join(&f).is_file(), "docs copy of {f}");
        }
        assert!(out.join(scene).join("reference.exr").is_file());
    }
    assert!(out.join("report.md").is_file());
    let md = std::fs::read_to_string(docs.join("evaluation.md")).unwrap();
    assert!(md.ends_with(tail), "the companion-papers part must be kept");
    assert!(!md.contains("# old head"));
    assert!(md.contains("| **rm@0.015** |"));

    // A second run reuses the cached references and still succeeds.
    let status = Command::new(env!("CARGO_BIN_EXE_pinrender"))
        .args(["eval", "--quick", "--scenes", "box", "--out"])
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
}

#[test]
fn eval_rejects_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    for args in [
        &["eval", "--quick", "--budgets", "-1"][..],
        &["eval", "--quick", "--budgets", "nan"][..],
        &["eval", "--quick", "--scenes", "teapot"][..],
        &["eval", "--quick", "--threads", "0"][..],
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_pinrender"))
            .args(args)
            .arg("--out")
            .arg(dir.path())
            .output()
            .unwrap();
        assert!(!out.status.success(), "{args:?} should fail");
        assert!(
            out.status.code() == Some(1) || out.status.code() == Some(2),
            "{args:?}: {:?}",
            out.status
        );
    }
}
