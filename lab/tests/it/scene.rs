//! `pinrender render --scene`: a scene file's instances on the CPU and the GPU path.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_pinrender");
const COSINE: &str = "procedural:cosine:seed=5,freq=4,density=6";
const SMALL: [&str; 6] = ["--width", "24", "--height", "16", "--spp", "2"];

fn pinrender(args: &[&str]) -> Output {
    Command::new(BIN).arg("render").args(args).output().unwrap()
}

fn ok(out: &Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Bakes the cosine field's pins (4^3 cells) into `dir/c.pin`.
fn bake(dir: &Path) -> PathBuf {
    let p: pin_volume::ProceduralSpec = COSINE["procedural:".len()..].parse().unwrap();
    let src = p.build(pin_volume::DensityScale::ONE).unwrap();
    let opts = pinbake::BakeOptions {
        cells: [4; 3],
        ..pinbake::BakeOptions::default()
    };
    let (grid, _) = pinbake::bake(src.as_ref(), &opts, &|_| {}).unwrap();
    let path = dir.join("c.pin");
    grid.write_atomic(&path).unwrap();
    path
}

fn scene(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn exr(p: &Path) -> Vec<[f32; 3]> {
    pinrender::render::Image::read_exr(p).unwrap().rgb
}

/// One instance with no transform is the asset as it is: the same bits as `--volume` with
/// `--pins`, for an estimator that reads the density and one that reads the pins.
#[test]
fn one_untransformed_instance_is_the_volume_itself() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let pins = bake(d);
    let sc = scene(
        d,
        "one.json",
        &format!(
            r#"{{"assets": {{"c": {{"volume": "{COSINE}", "pins": "c.pin"}}}}, "instances": [{{"asset": "c"}}]}}"#
        ),
    );
    for est in ["ratio", "pins", "pinms"] {
        let a = d.join(format!("scene-{est}.exr"));
        let b = d.join(format!("volume-{est}.exr"));
        let mut args = vec!["--scene", sc.to_str().unwrap(), "--estimator", est];
        args.extend(SMALL);
        args.extend(["--out", a.to_str().unwrap()]);
        ok(&pinrender(&args));
        let mut args = vec!["--volume", COSINE, "--estimator", est];
        if est != "ratio" {
            args.extend(["--pins", pins.to_str().unwrap()]);
        }
        args.extend(SMALL);
        args.extend(["--out", b.to_str().unwrap()]);
        ok(&pinrender(&args));
        assert_eq!(exr(&a), exr(&b), "{est}");
    }
}

/// Three instances, turned and stretched: every estimator renders them, the flags override
/// the file's look, and moving an instance changes the image.
#[test]
fn instances_render_and_flags_override_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake(d);
    let body = |albedo: &str, x: f64| {
        format!(
            r#"{{"assets": {{"c": {{"volume": "{COSINE}", "pins": "c.pin"}}}},
               "instances": [
                 {{"asset": "c"}},
                 {{"asset": "c", "transform": {{"translate": [{x}, 0, 0], "rotate_deg": [0, 90, 0], "scale": [1, 1.5, 1]}}}},
                 {{"asset": "c", "transform": {{"translate": [-1.5, 0.2, 0.3], "rotate_deg": [10, 0, 30], "scale": 0.7}}}}
               ],
               "camera": {{"origin": [0.5, 1.5, 6], "target": [0.5, 0.5, 0.5], "fov": 50}}{albedo}}}"#
        )
    };
    let plain = scene(d, "plain.json", &body("", 1.5));
    let half = scene(d, "half.json", &body(r#", "albedo": 0.5"#, 1.5));
    let moved = scene(d, "moved.json", &body("", 2.5));
    let render = |sc: &Path, est: &str, extra: &[&str], name: &str| {
        let out = d.join(name);
        let mut args = vec!["--scene", sc.to_str().unwrap(), "--estimator", est];
        args.extend(SMALL);
        args.extend(extra);
        args.extend(["--out", out.to_str().unwrap()]);
        ok(&pinrender(&args));
        exr(&out)
    };
    for est in ["ratio", "delta", "residual", "rm@0.05", "pins", "pinms"] {
        let img = render(&plain, est, &[], &format!("{est}.exr"));
        assert!(
            img.iter().flatten().all(|v| v.is_finite() && *v >= 0.0),
            "{est}"
        );
    }
    let base = render(&plain, "pinms", &[], "base.exr");
    // The file's albedo 0.5 differs from the default 0.9; --albedo 0.9 restores it.
    assert_ne!(render(&half, "pinms", &[], "half.exr"), base);
    assert_eq!(
        render(&half, "pinms", &["--albedo", "0.9"], "over.exr"),
        base
    );
    assert_ne!(render(&moved, "pinms", &[], "moved.exr"), base);
    // The GPU path renders turned and stretched instances with every estimator.
    for est in ["ratio", "delta", "residual", "rm@0.05", "pins", "pinms"] {
        let gpu = render(
            &plain,
            est,
            &["--backend", "gpu"],
            &format!("gpu-{est}.exr"),
        );
        assert!(
            gpu.iter().flatten().all(|v| v.is_finite() && *v >= 0.0)
                && gpu.iter().flatten().any(|v| *v > 0.0),
            "{est}"
        );
    }
    // The lab's estimators are refused on either backend (exit 2).
    for backend in ["cpu", "gpu"] {
        let o = pinrender(&[
            "--scene",
            plain.to_str().unwrap(),
            "--estimator",
            "urm",
            "--backend",
            backend,
            "--out",
            d.join("urm.exr").to_str().unwrap(),
        ]);
        assert_eq!(o.status.code(), Some(2), "{backend}");
    }
}

/// A transform valid by the scene format renders with every estimator: the runtime follows
/// the format's one singularity rule (`pin_format::transform_condition`), under which axes
/// scaled 1e-6, 1e6 and 1 are well conditioned (pins and pinms refused it as "singular").
#[test]
fn a_scale_the_scene_format_accepts_renders_with_pins() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake(d);
    let sc = scene(
        d,
        "thin.json",
        &format!(
            r#"{{"assets": {{"c": {{"volume": "{COSINE}", "pins": "c.pin"}}}},
               "instances": [{{"asset": "c", "transform": {{"scale": [1e-6, 1e6, 1]}}}}],
               "camera": {{"origin": [0, 0, 3e6], "target": [0, 5e5, 0.5], "fov": 60}}}}"#
        ),
    );
    for est in ["ratio", "pins", "pinms"] {
        let out = d.join(format!("thin-{est}.exr"));
        let mut args = vec!["--scene", sc.to_str().unwrap(), "--estimator", est];
        args.extend(SMALL);
        args.extend(["--out", out.to_str().unwrap()]);
        ok(&pinrender(&args));
        assert!(
            exr(&out)
                .iter()
                .flatten()
                .all(|v| v.is_finite() && *v >= 0.0),
            "{est}"
        );
    }
}

/// `--backend gpu` renders a scene of turned, stretched and mirrored instances with the
/// estimators that read the density as the CPU does: the image means of ratio tracking on
/// both backends agree within 5 standard errors of their difference, estimated from 6
/// replicate renders (distinct seeds) per side.
#[test]
fn gpu_scene_renders_agree_with_the_cpu() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake(d);
    let sc = scene(
        d,
        "three.json",
        &format!(
            r#"{{"assets": {{"c": {{"volume": "{COSINE}", "pins": "c.pin"}}}},
               "instances": [
                 {{"asset": "c", "transform": {{"rotate_deg": [20, 35, -10], "scale": [1.6, 0.7, 1]}}}},
                 {{"asset": "c", "transform": {{"translate": [1.2, 0.2, -0.3], "rotate_deg": [0, 90, 30], "scale": [0.6, 1.3, -0.9]}}}},
                 {{"asset": "c", "transform": {{"translate": [-1.1, 0.4, 0.3], "rotate_deg": [-40, 10, 0], "scale": 0.8}}}}
               ],
               "camera": {{"origin": [0.3, 1.5, 5], "target": [0.2, 0.4, 0.3], "fov": 50}}}}"#
        ),
    );
    let mean = |est: &str, backend: &str, seed: u64| {
        let out = d.join(format!("{est}-{backend}-{seed}.exr"));
        let seed = seed.to_string();
        ok(&pinrender(&[
            "--scene",
            sc.to_str().unwrap(),
            "--estimator",
            est,
            "--backend",
            backend,
            "--width",
            "24",
            "--height",
            "16",
            "--spp",
            "8",
            "--seed",
            &seed,
            "--out",
            out.to_str().unwrap(),
        ]));
        let img = exr(&out);
        img.iter().flatten().map(|v| f64::from(*v)).sum::<f64>() / (img.len() * 3) as f64
    };
    let stats = |v: &[f64]| {
        let n = v.len() as f64;
        let m = v.iter().sum::<f64>() / n;
        let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0);
        (m, var / n)
    };
    // Ratio tracking here; every estimator in `gpu_render::tests` (pinrender).
    let gpu: Vec<f64> = (0..6).map(|k| mean("ratio", "gpu", 10 + k)).collect();
    let cpu: Vec<f64> = (0..6).map(|k| mean("ratio", "cpu", 50 + k)).collect();
    let ((g, gv), (c, cv)) = (stats(&gpu), stats(&cpu));
    let z = (g - c) / (gv + cv).sqrt();
    assert!(z.abs() < 5.0, "gpu {g} cpu {c}, z = {z}");
    // The instances are in the picture: the sky alone is 0.3 exactly.
    assert!((g - 0.3).abs() > 5.0 * gv.sqrt(), "{g} +- {}", gv.sqrt());
}

/// 4,096 instances render on the GPU at a tiny size within 64 MiB of `--max-memory`: an
/// asset is uploaded once and each instance adds a record (`docs/scene.md`); 2 MiB, less
/// than the file's own read bound, is refused with one line before anything is opened.
#[test]
fn four_thousand_instances_render_on_the_gpu_in_little_memory() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake(d);
    let mut instances = Vec::new();
    for i in 0..4096 {
        let (x, y, z) = (i % 16, (i / 16) % 16, i / 256);
        instances.push(format!(
            r#"{{"asset": "c", "transform": {{"translate": [{}, {}, {}], "rotate_deg": [{}, {}, 0], "scale": [1.2, 0.8, 1]}}}}"#,
            x as f64 * 1.5,
            y as f64 * 1.5,
            z as f64 * 1.5,
            i % 30,
            (i * 7) % 90
        ));
    }
    let sc = scene(
        d,
        "many.json",
        &format!(
            r#"{{"assets": {{"c": {{"volume": "{COSINE}", "pins": "c.pin"}}}}, "instances": [{}]}}"#,
            instances.join(",")
        ),
    );
    let out = d.join("many.exr");
    let args = |mem: &'static str| {
        vec![
            "--scene".to_string(),
            sc.to_str().unwrap().to_string(),
            "--backend".into(),
            "gpu".into(),
            "--estimator".into(),
            "pinms".into(),
            "--width".into(),
            "16".into(),
            "--height".into(),
            "12".into(),
            "--spp".into(),
            "1".into(),
            "--max-memory".into(),
            mem.into(),
            "--out".into(),
            out.to_str().unwrap().to_string(),
        ]
    };
    let run = |mem| {
        Command::new(BIN)
            .arg("render")
            .args(args(mem))
            .output()
            .unwrap()
    };
    ok(&run("64M"));
    assert!(exr(&out).iter().flatten().all(|v| v.is_finite()));
    std::fs::remove_file(&out).unwrap();
    let o = run("2M");
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.lines().count() == 1 && err.contains("many.json") && err.contains("--max-memory"),
        "{err}"
    );
    assert!(!out.exists());
}

/// `--reference` compares a scene's render with a converged image as it does a volume's:
/// the one stdout line, an RMSE of 0 against the render's own image, above 0 against
/// another seed's; a reference of another size is an error naming it, exit 1.
#[test]
fn a_scene_render_is_compared_with_its_reference() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake(d);
    let sc = scene(
        d,
        "two.json",
        &format!(
            r#"{{"assets": {{"c": {{"volume": "{COSINE}", "pins": "c.pin"}}}}, "instances": [{{"asset": "c"}}, {{"asset": "c", "transform": {{"translate": [0.6, 0, 0], "rotate_deg": [0, 40, 0]}}}}]}}"#
        ),
    );
    let sc = sc.to_str().unwrap();
    let reference = d.join("ref.exr");
    let mut args = vec!["--scene", sc, "--estimator", "ratio"];
    args.extend(SMALL);
    ok(&pinrender(
        &[&args[..], &["--out", reference.to_str().unwrap()]].concat(),
    ));
    let rmse = |extra: &[&str], name: &str| {
        let out = d.join(name);
        let all = [
            &args[..],
            extra,
            &[
                "--reference",
                reference.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ],
        ]
        .concat();
        let o = pinrender(&all);
        ok(&o);
        let line = String::from_utf8(o.stdout).unwrap();
        let f: Vec<&str> = line.split_whitespace().collect();
        assert_eq!(f[0], "mean_error", "{line}");
        assert_eq!(f[8], "rmse", "{line}");
        f[9].parse::<f64>().unwrap()
    };
    assert_eq!(rmse(&[], "same.exr"), 0.0);
    assert!(rmse(&["--seed", "3"], "other.exr") > 0.0);
    let small = d.join("small.exr");
    let o = pinrender(&[
        "--scene",
        sc,
        "--estimator",
        "ratio",
        "--width",
        "8",
        "--height",
        "8",
        "--spp",
        "1",
        "--reference",
        reference.to_str().unwrap(),
        "--out",
        small.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    let last = err.lines().last().unwrap_or_default();
    assert!(
        last.contains("ref.exr") && last.contains("24x16") && last.contains("8x8"),
        "{err}"
    );
    // Refused before the render: nothing is written.
    assert!(!small.exists() && !small.with_extension("png").exists());
}

#[test]
fn bad_scenes_are_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake(d);
    let out = d.join("x.exr");
    let bad = scene(
        d,
        "bad.json",
        r#"{"assets": {"c": {"pins": "c.pin"}}, "instances": [{"asset": "c"}, {"asset": "c", "transform": [1,0,0,0, 0,1,0,0, 0,0,0,0]}]}"#,
    );
    let o = pinrender(&[
        "--scene",
        bad.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains("bad.json: instances[1].transform: scales the z axis by 0"),
        "{err}"
    );
    assert!(!out.exists());
    let o = pinrender(&[
        "--scene",
        bad.to_str().unwrap(),
        "--volume",
        COSINE,
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    // A density estimator over pins without a density is refused, naming the asset.
    let good = scene(
        d,
        "good.json",
        r#"{"assets": {"c": {"pins": "c.pin"}}, "instances": [{"asset": "c"}]}"#,
    );
    let o = pinrender(&[
        "--scene",
        good.to_str().unwrap(),
        "--estimator",
        "ratio",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("assets.c.pins") && err.contains("no embedded density"),
        "{err}"
    );
    // The output must not replace the scene file.
    let o = pinrender(&[
        "--scene",
        good.to_str().unwrap(),
        "--out",
        good.to_str().unwrap(),
    ]);
    assert_ne!(o.status.code(), Some(0));
    assert!(std::fs::read_to_string(&good).unwrap().contains("assets"));
}
