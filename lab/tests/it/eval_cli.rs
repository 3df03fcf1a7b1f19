//! `pinrender eval --quick` end to end: every scene and estimator gets a CSV row per budget
//! with finite errors, and the plots, montages and report are written under the output
//! contract (`errors.csv`, `errors.png`, `summary.md`). The sizes are shrunk below the quick
//! run's (16 px, 4 reference spp, three tiny budgets) so the test checks the plumbing fast. The GPU path tracer
//! (`pins`, backend `gpu`) must give rows too: CI has lavapipe, and a missing adapter should be
//! noticed (as in the GPU unit tests), not skipped.

use std::collections::BTreeSet;
use std::process::Command;

/// What a user picks (the renderer's own estimators, ray marching at the baseline step): the
/// quick run's rows per scene. The lab's estimators run in the full eval and when named
/// (the `--estimators` run below).
const USER: &[&str] = &[
    "rm@0.015", "delta", "ratio", "residual", "pins", "pinms", "pinres",
];
const EXPECTED: [(&str, &[&str]); 6] = [
    ("smoke", USER),
    ("hydrogen", USER),
    ("cosine", USER),
    ("box", USER),
    (
        "box-ss",
        &["rm@0.015", "delta", "ratio", "residual", "pins"],
    ),
    ("instances", USER),
];

/// The lab's estimators (and rm's other steps): never in a quick run unless named.
const LAB: [&str; 10] = [
    "rm@0.05",
    "rm@0.005",
    "urm",
    "jackknife",
    "pinurm",
    "pinms+cache",
    "cosine-closed-form",
    "box-closed-form",
    "whole-volume",
    "residual@min",
];

/// Shrinks `--quick` further: the test checks the plumbing, not the figures.
const TINY: [&str; 6] = [
    "--size",
    "16",
    "--ref-spp",
    "4",
    "--budgets",
    "0.01,0.02,0.03",
];

/// What the GPU path tracer runs besides `rm@STEP`.
const GPU_ESTIMATORS: [&str; 8] = [
    "delta",
    "ratio",
    "residual",
    "urm",
    "jackknife",
    "pins",
    "pinms",
    "pinres",
];

#[test]
fn eval_quick_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("eval");
    let docs = dir.path().join("docs");
    std::fs::create_dir_all(&docs).unwrap();
    // A hand-written page in the docs folder: the eval writes its report beside it, never
    // into it.
    let page = "# Evaluation\n\nhand-written, kept verbatim\n";
    std::fs::write(docs.join("evaluation.md"), page).unwrap();
    let status = Command::new(env!("CARGO_BIN_EXE_pinrender"))
        .args(["eval", "--quick", "--out"])
        .arg(&out)
        .args(TINY)
        .arg("--docs")
        .arg(&docs)
        .status()
        .unwrap();
    assert!(status.success(), "pinrender eval --quick failed: {status}");

    let csv = std::fs::read_to_string(out.join("errors.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("scene,estimator,backend,seconds,rmse,relmse,budget_s,spp")
    );
    let mut seen = BTreeSet::new();
    let mut gpu_seen = BTreeSet::new();
    let mut budgets = BTreeSet::new();
    for line in lines {
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(f.len(), 8, "{line}");
        match f[2] {
            "cpu" => {}
            "gpu" => {
                assert!(
                    GPU_ESTIMATORS.contains(&f[1]) || f[1].starts_with("rm@"),
                    "an estimator the GPU does not have: {line}"
                );
                gpu_seen.insert((f[0].to_string(), f[1].to_string()));
            }
            other => panic!("unknown backend {other}: {line}"),
        }
        let spp: u32 = f[7].parse().unwrap();
        assert!(spp >= 1, "{line}");
        for v in [f[3], f[4], f[5], f[6]] {
            let x: f64 = v.parse().unwrap();
            assert!(x.is_finite() && x >= 0.0, "{line}");
        }
        assert!(
            !LAB.contains(&f[1]),
            "a lab estimator in a quick run: {line}"
        );
        if f[2] == "cpu" {
            seen.insert((f[0].to_string(), f[1].to_string()));
        }
        budgets.insert(f[6].to_string());
    }
    assert_eq!(budgets.len(), 3, "three budgets");
    // Every scene, the quick run's GPU rows (the estimators that read the bake; instances
    // included).
    assert!(
        !gpu_seen.is_empty(),
        "no gpu rows (is a wgpu adapter, e.g. lavapipe, installed?)"
    );
    for (scene, ests) in EXPECTED {
        for e in ests.iter().filter(|e| ["pins", "pinms"].contains(e)) {
            assert!(
                gpu_seen.contains(&(scene.to_string(), e.to_string())),
                "no gpu rows for {scene} / {e}"
            );
        }
    }
    assert!(
        gpu_seen.iter().all(|(_, e)| e == "pins" || e == "pinms"),
        "{gpu_seen:?}"
    );
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
    let summary = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(
        summary.contains("This report measures how quickly each way"),
        "summary.md says what the reader is looking at"
    );
    // It opens with one line per scene on what the bake buys at each budget.
    let opening: Vec<&str> = summary
        .lines()
        .skip_while(|l| !l.starts_with("What the bake buys"))
        .skip(2)
        .take_while(|l| l.starts_with("- **"))
        .collect();
    assert_eq!(opening.len(), EXPECTED.len(), "{summary}");
    for ((scene, _), line) in EXPECTED.iter().zip(&opening) {
        assert!(
            line.starts_with(&format!("- **{scene}**: 0.01 s: ")),
            "{line}"
        );
        assert_eq!(
            line.matches(" s: ").count(),
            3,
            "a ratio per budget: {line}"
        );
    }
    // Per scene and budget, the best estimator reading the bake against the best without.
    assert!(
        summary.contains("| budget | best reading the bake | RMSE | best without | RMSE |"),
        "summary.md compares the bake's estimators with the others"
    );
    for png in ["errors.png", "errors_all.png"] {
        assert!(out.join(png).is_file(), "{png}");
        assert!(docs.join("eval").join(png).is_file(), "docs copy of {png}");
    }
    assert_eq!(
        std::fs::read_to_string(docs.join("evaluation.md")).unwrap(),
        page,
        "the hand-written page is not rewritten"
    );
    let md = std::fs::read_to_string(docs.join("eval").join("report.md")).unwrap();
    assert!(md.starts_with("# pinrender eval"), "{md}");
    assert!(md.contains("| **rm@0.015** |"));
    assert!(md.contains("| pins (gpu) |"), "gpu row in the table");
    assert!(md.contains("| pinms (gpu) |"), "gpu PinMS row in the table");
    assert!(!md.contains("GPU: not measured** (no GPU"));
    assert!(md.contains("WGSL"));

    // --no-gpu: no gpu rows, and the report says so. With --clock cpu, the budgets count
    // CPU time per worker thread and the report names that clock. An estimator named in
    // --estimators runs even where the scene's own list leaves it out (residual@min), and the
    // lab's estimators run when named, in a quick run too.
    let out2 = dir.path().join("eval-nogpu");
    let status = Command::new(env!("CARGO_BIN_EXE_pinrender"))
        .args([
            "eval",
            "--quick",
            "--no-gpu",
            "--clock",
            "cpu",
            "--scenes",
            "box",
            "--estimators",
            "ratio,residual@min,urm,jackknife,pinurm,pinms+cache,box-closed-form",
            "--out",
        ])
        .arg(&out2)
        .args(TINY)
        .status()
        .unwrap();
    assert!(status.success());
    let csv = std::fs::read_to_string(out2.join("errors.csv")).unwrap();
    assert!(!csv.contains(",gpu,"), "{csv}");
    assert!(csv.contains("\nbox,residual@min,cpu,"), "{csv}");
    assert!(csv.contains("\nbox,ratio,cpu,"), "{csv}");
    for lab in [
        "urm",
        "jackknife",
        "pinurm",
        "pinms+cache",
        "box-closed-form",
    ] {
        assert!(csv.contains(&format!("\nbox,{lab},cpu,")), "{lab}: {csv}");
    }
    assert!(!csv.contains(",delta,"), "{csv}");
    let md = std::fs::read_to_string(out2.join("summary.md")).unwrap();
    assert!(md.contains("GPU: not measured** (`--no-gpu`)"), "{md}");
    assert!(md.contains("CPU time per worker thread"), "{md}");
    assert!(!md.contains("s of wall time per estimator"), "{md}");

    // A second run reuses the cached references and still succeeds.
    let status = Command::new(env!("CARGO_BIN_EXE_pinrender"))
        .args(["eval", "--quick", "--scenes", "box", "--out"])
        .arg(&out)
        .args(TINY)
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
        // The production-scale scenes and the cloudscape are for the full run only (CI runs
        // --quick).
        &["eval", "--quick", "--scenes", "cloud"][..],
        &["eval", "--quick", "--scenes", "production"][..],
        &["eval", "--quick", "--scenes", "cloudscape"][..],
        &["eval", "--quick", "--threads", "0"][..],
        &["eval", "--quick", "--clock", "sundial"][..],
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

/// A full run that includes the production scene checks its OpenVDB file before any scene
/// runs: a missing file is one line naming it and how to write it, and nothing is rendered.
#[test]
fn eval_refuses_a_missing_production_cloud_before_rendering() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("cloud-half.vdb");
    let out = Command::new(env!("CARGO_BIN_EXE_pinrender"))
        .args(["eval", "--scenes", "box,production", "--production"])
        .arg(&missing)
        .arg("--out")
        .arg(dir.path().join("out"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(&*missing.to_string_lossy()) && err.contains("generate.sh half"),
        "{err}"
    );
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(!dir.path().join("out").join("box").exists(), "a scene ran");
}

fn data(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(name)
}

/// Mean grey value of an EXR written by `pinrender render`.
fn exr_mean(path: &std::path::Path) -> f64 {
    let img = pinrender::render::Image::read_exr(path).unwrap();
    img.rgb
        .iter()
        .map(|p| p.iter().map(|&c| f64::from(c)).sum::<f64>() / 3.0)
        .sum::<f64>()
        / img.rgb.len() as f64
}

/// `pinrender render --backend gpu` renders the same scene as the CPU backend: the image
/// means agree (the per-pixel statistics are tested in `pinrender::gpu_render`), for a tracker
/// with scattering, for near-deterministic ray marching without, and for a lab kernel. (The
/// residual estimators go through the command line's GPU backend in `pin_alone` and `scene`;
/// each GPU estimator here is a pipeline of seconds on lavapipe.)
#[test]
fn render_backends_agree() {
    let dir = tempfile::tempdir().unwrap();
    let raw = data("hydrogen_atom_128x128x128_uint8.raw");
    let render = |backend: &str, est: &str, albedo: &str, spp: &str, seed: &str| -> f64 {
        let out = dir.path().join(format!("{backend}-{est}-{albedo}.exr"));
        let o = Command::new(env!("CARGO_BIN_EXE_pinrender"))
            .args(["render", "--volume"])
            .arg(&raw)
            .args([
                "--spacing",
                "0.0078125",
                "--density-scale",
                "0.6",
                "--width",
                "32",
                "--height",
                "32",
                "--max-bounces",
                "4",
                "--estimator",
                est,
                "--albedo",
                albedo,
                "--spp",
                spp,
                "--seed",
                seed,
                "--backend",
                backend,
                "--out",
            ])
            .arg(&out)
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "{backend} {est}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(out.with_extension("png").is_file());
        exr_mean(&out)
    };
    for (est, albedo, spp, tol) in [
        ("ratio", "0.9", "128", 0.03),
        ("rm@0.02", "0", "16", 0.005),
        // The lab's comb estimator: a shader kernel on the GPU, combs and delta tracking on
        // the CPU.
        ("urm", "0.9", "128", 0.03),
    ] {
        let cpu = render("cpu", est, albedo, spp, "1");
        let gpu = render("gpu", est, albedo, spp, "2");
        assert!(cpu > 0.01, "{est}: empty image");
        let rel = (gpu - cpu).abs() / cpu;
        assert!(rel < tol, "{est}: cpu {cpu} gpu {gpu} (rel {rel})");
    }

    // The procedural sphere has no GPU form: a one-line error, exit 1, no image.
    let out = dir.path().join("sphere.exr");
    let o = Command::new(env!("CARGO_BIN_EXE_pinrender"))
        .args([
            "render",
            "--volume",
            "procedural:sphere",
            "--width",
            "8",
            "--height",
            "8",
            "--backend",
            "gpu",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("no form"), "{err}");
    assert!(!out.exists());
    // An unknown backend is a usage error.
    let o = Command::new(env!("CARGO_BIN_EXE_pinrender"))
        .args([
            "render",
            "--volume",
            "procedural:box",
            "--backend",
            "tpu",
            "--out",
        ])
        .arg(dir.path().join("x.exr"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
}

/// `pinrender render --reference` prints the mean and 8x8-block errors against a reference
/// image; the lookup options (jitter, chain stride, lookup point, start inside) are accepted
/// and checked.
#[test]
fn render_compares_with_a_reference() {
    let dir = tempfile::tempdir().unwrap();
    let run = |extra: &[&str], out: &str| {
        Command::new(env!("CARGO_BIN_EXE_pinrender"))
            .args([
                "render",
                "--volume",
                "procedural:cosine:seed=2,freq=2,density=3",
                "--width",
                "16",
                "--height",
                "16",
                "--max-bounces",
                "2",
                "--pin-cells",
                "4",
                "--spp",
                "8",
                "--out",
            ])
            .arg(dir.path().join(out))
            .args(extra)
            .output()
            .unwrap()
    };
    let o = run(&["--estimator", "ratio"], "ref.exr");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let reference = dir.path().join("ref.exr");
    let r = reference.to_str().unwrap();
    // The reference against itself: zero error.
    let o = run(&["--estimator", "ratio", "--reference", r], "same.exr");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let line = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        line.starts_with("mean_error +0.0000 block8_rms_error 0.0000"),
        "{line}"
    );
    assert!(line.trim_end().ends_with("rmse 0.000000"), "{line}");
    // Pins with jitter: some error, printed as one line of numbers.
    let o = run(
        &[
            "--estimator",
            "pins",
            "--spatial-jitter",
            "0.5",
            "--directional-jitter",
            "2",
            "--reference",
            r,
        ],
        "pins.exr",
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let line = String::from_utf8_lossy(&o.stdout).into_owned();
    let f: Vec<&str> = line.split_whitespace().collect();
    assert_eq!(f[0], "mean_error");
    let block: f64 = f[3].parse().unwrap();
    assert!(block > 0.0 && block.is_finite(), "{line}");
    // The per-pixel RMSE (radiance), last.
    assert_eq!(f[8], "rmse", "{line}");
    let rmse: f64 = f[9].parse().unwrap();
    assert!(rmse > 0.0 && rmse.is_finite(), "{line}");
    // Chained lookups from the segment start: another image, still one line of numbers.
    let o = run(
        &[
            "--estimator",
            "pins",
            "--chain-stride",
            "4",
            "--lookup-point",
            "start",
            "--reference",
            r,
        ],
        "chained.exr",
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let chained = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(chained.starts_with("mean_error "), "{chained}");
    assert_ne!(
        std::fs::read(dir.path().join("chained.exr")).unwrap(),
        std::fs::read(dir.path().join("pins.exr")).unwrap()
    );
    // Rays from inside the box looked up like the others (docs/sampling.md section 14): the
    // scattered and shadow rays read other pins than the default's.
    let default = |out: &str, extra: &[&str]| {
        let mut a = vec!["--estimator", "pins", "--seed", "3"];
        a.extend_from_slice(extra);
        let o = run(&a, out);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(dir.path().join(out)).unwrap()
    };
    let on = default("inside.exr", &[]);
    assert_eq!(on, default("inside_true.exr", &["--start-inside", "true"]));
    assert_ne!(
        on,
        default("inside_false.exr", &["--start-inside", "false"])
    );
    // A bad strength, stride, lookup point or rule is a usage error; a missing reference
    // fails before rendering.
    for bad in [
        ["--spatial-jitter", "-1"],
        ["--chain-stride", "0"],
        ["--chain-stride", "33"],
        ["--lookup-point", "end"],
        ["--start-inside", "maybe"],
    ] {
        let o = run(&["--estimator", "pins", bad[0], bad[1]], "bad.exr");
        assert_eq!(o.status.code(), Some(2), "{bad:?}");
    }
    let o = run(
        &["--estimator", "pins", "--reference", "/nonexistent/ref.exr"],
        "missing.exr",
    );
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("/nonexistent/ref.exr"), "{err}");
    assert!(!dir.path().join("missing.exr").exists());
}

/// `pinrender bench --json` on a tiny CPU run: every row carries `volume, method, query,
/// backend, queries_per_s, cpu_queries_per_s`; every transmittance row its mean absolute error against the
/// converged march; the strongest no-bake estimators (`urm`, `jackknife`) and the trackers
/// (`ratio`, `residual`, `residual@min`, `delta`, transmittance and distance) sit beside pins
/// (single and batched) and ray marching on the same rays; the ratio-tracking family's
/// transmittance rows carry their variance per lookup.
#[test]
fn bench_json_rows_have_rates_and_errors() {
    let o = Command::new(env!("CARGO_BIN_EXE_pinrender"))
        .args([
            "bench",
            "--volume",
            "procedural:box",
            "--rays",
            "2000",
            "--cells",
            "4",
            "--no-gpu",
            "--json",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
    let rows = v["results"].as_array().unwrap();
    let mut methods = BTreeSet::new();
    for r in rows {
        for key in ["volume", "method", "query", "backend"] {
            assert!(r[key].is_string(), "{key} in {r}");
        }
        assert_eq!(r["backend"], "cpu", "--no-gpu: {r}");
        assert!(r["queries_per_s"].as_f64().unwrap() > 0.0, "{r}");
        // CPU rows also carry their rate over the thread's CPU time, which the ratios use.
        assert!(r["cpu_queries_per_s"].as_f64().unwrap() > 0.0, "{r}");
        if r["query"] == "transmittance" {
            let e = r["mean_abs_error"].as_f64().unwrap();
            assert!((0.0..=1.0).contains(&e), "{r}");
        }
        let method = r["method"].as_str().unwrap();
        if ["ratio", "residual", "residual@min"].contains(&method) && r["query"] == "transmittance"
        {
            for key in [
                "per_ray_variance",
                "lookups_per_query",
                "variance_x_lookups",
            ] {
                let v = r[key].as_f64().unwrap();
                assert!(v.is_finite() && v >= 0.0, "{key} in {r}");
            }
            assert!(r["variance_rays"].as_u64().unwrap() > 0, "{r}");
        }
        // Pin rows name the bake they measured and its size.
        if r["method"].as_str().unwrap().starts_with("pins") {
            assert!(r["bake"].as_str().unwrap().contains(" x "), "{r}");
            assert!(r["pin_bytes"].as_u64().unwrap() > 0, "{r}");
        }
        methods.insert(format!(
            "{}/{}",
            r["method"].as_str().unwrap(),
            r["query"].as_str().unwrap()
        ));
    }
    let bake_of = |method: &str| {
        rows.iter()
            .find(|r| r["method"] == method)
            .map(|r| r["bake"].clone())
            .unwrap()
    };
    assert_eq!(bake_of("pins-batched"), "4x4x4 x octahedral:16");
    assert_eq!(bake_of("pins"), bake_of("pins-batched"));
    for m in [
        "pins/transmittance",
        "pins/distance",
        "pins-batched/transmittance",
        "pins-batched/distance",
        "pins-default-batched/transmittance",
        "pins-default-batched/distance",
        "pins-render-batched/transmittance",
        "pins-render-batched/distance",
        "ratio/transmittance",
        "ratio/distance",
        "residual/transmittance",
        "residual/distance",
        "residual@min/transmittance",
        "residual@min/distance",
        "delta/transmittance",
        "delta/distance",
        "rm@0.015/transmittance",
        "urm/transmittance",
        "jackknife/transmittance",
    ] {
        assert!(methods.contains(m), "{m} missing from {methods:?}");
    }
}

/// `pinrender estimators --json` is a contract scripts read: every estimator with its name,
/// whether it reads a pin file, and whether it is unbiased.
#[test]
fn the_estimator_catalogue_is_json_with_the_contract_fields() {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_pinrender"))
        .args(["estimators", "--json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rows = v["estimators"].as_array().unwrap();
    let get = |name: &str| rows.iter().find(|r| r["name"] == name).cloned().unwrap();
    for r in rows {
        assert!(
            r["name"].is_string() && r["needs_bake"].is_boolean() && r["unbiased"].is_boolean()
        );
    }
    assert_eq!(get("pins")["needs_bake"], true);
    assert_eq!(get("pinms")["needs_bake"], true);
    assert_eq!(get("pinms")["unbiased"], false);
    assert_eq!(get("ratio")["needs_bake"], false);
    assert_eq!(get("ratio")["unbiased"], true);
    assert_eq!(get("residual")["unbiased"], true);
    assert_eq!(get("rm@STEP")["unbiased"], false);
    assert_eq!(get("pinurm")["needs_bake"], true);
    assert_eq!(get("pinurm")["unbiased"], true);
    assert_eq!(get("pinurm")["gpu"], false);
    assert_eq!(get("pinres")["needs_bake"], true);
    assert_eq!(get("pinres")["unbiased"], true);
    assert_eq!(get("pinres")["gpu"], true);
    assert_eq!(get("residual")["gpu"], true);
}
