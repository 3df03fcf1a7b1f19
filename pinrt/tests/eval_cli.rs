//! `pinrender eval --quick` end to end: every scene and estimator gets a CSV row per budget
//! with finite errors, and the plots, montages and report are written. The GPU path tracer
//! (`pins`, backend `gpu`) must give rows too: CI has lavapipe, and a missing adapter should be
//! noticed (as in the GPU unit tests), not skipped.

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
    let mut gpu_scenes = BTreeSet::new();
    let mut budgets = BTreeSet::new();
    for line in lines {
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(f.len(), 8, "{line}");
        match f[2] {
            "cpu" => {}
            "gpu" => {
                assert_eq!(f[1], "pins", "only pins runs on the GPU: {line}");
                gpu_scenes.insert(f[0].to_string());
            }
            other => panic!("unknown backend {other}: {line}"),
        }
        let spp: u32 = f[4].parse().unwrap();
        assert!(spp >= 1, "{line}");
        for v in [f[3], f[5], f[6], f[7]] {
            let x: f64 = v.parse().unwrap();
            assert!(x.is_finite() && x >= 0.0, "{line}");
        }
        if f[2] == "cpu" {
            seen.insert((f[0].to_string(), f[1].to_string()));
        }
        budgets.insert(f[3].to_string());
    }
    assert_eq!(budgets.len(), 2, "two --quick budgets");
    // One pin grid as the only medium: the GPU path tracer applies; not to box-ss/instances.
    assert!(
        !gpu_scenes.is_empty(),
        "no gpu rows (is a wgpu adapter, e.g. lavapipe, installed?)"
    );
    for s in &gpu_scenes {
        assert!(
            ["smoke", "hydrogen", "cosine", "box"].contains(&s.as_str()),
            "unexpected gpu rows for {s}"
        );
    }
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
    assert!(md.contains("| pins (gpu) |"), "gpu row in the table");
    assert!(!md.contains("GPU: not measured** (no GPU"));
    assert!(md.contains("WGSL"));

    // --no-gpu: no gpu rows, and the report says so.
    let out2 = dir.path().join("eval-nogpu");
    let status = Command::new(env!("CARGO_BIN_EXE_pinrender"))
        .args(["eval", "--quick", "--no-gpu", "--scenes", "box", "--out"])
        .arg(&out2)
        .status()
        .unwrap();
    assert!(status.success());
    let csv = std::fs::read_to_string(out2.join("results.csv")).unwrap();
    assert!(!csv.contains(",gpu,"), "{csv}");
    let md = std::fs::read_to_string(out2.join("report.md")).unwrap();
    assert!(md.contains("GPU: not measured** (`--no-gpu`)"), "{md}");

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
