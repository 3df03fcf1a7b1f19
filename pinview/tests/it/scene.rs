//! A scene file of instanced volumes (docs/scene.md): the viewer renders it with the media
//! `pinrender render --scene --backend gpu` builds, to the bit; a bad scene is one line.

use std::path::{Path, PathBuf};
use std::process::Output;

use crate::support::*;

/// Three instances of one baked asset, placed apart, rotated and scaled; the scene sets the
/// camera and the look, which the renders must take from it.
const SCENE: &str = r#"{
  "assets": {"cloud": {"pins": "c.pin"}},
  "instances": [
    {"asset": "cloud"},
    {"asset": "cloud", "transform": {"translate": [1.1, 0.2, -0.3], "rotate_deg": [0, 40, 10], "scale": 0.8}},
    {"asset": "cloud", "transform": {"translate": [-1.0, -0.1, 0.2], "scale": [1.2, 0.7, 1]}}
  ],
  "camera": {"origin": [0.3, 1.2, 4.2], "target": [0.3, 0.4, 0.3], "fov": 50},
  "sun": {"direction": [-0.4, 1, 0.3], "radiance": 4},
  "albedo": 0.8,
  "g": 0.3,
  "max_bounces": 3
}"#;

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn a_scene_matches_pinrender_bit_for_bit() {
    matches_pinrender("pins", None);
}

/// A tracker over the pin file's embedded density renders the scene's turned and stretched
/// instances as `pinrender render --scene --backend gpu` does, to the bit.
#[test]
fn a_scene_matches_pinrender_bit_for_bit_with_a_tracker() {
    matches_pinrender("ratio", Some(16));
}

/// The viewer's 3 passes of `estimator` over [`SCENE`] (its pins baked with an embedded
/// density of `embed`^3 voxels where given) against `pinrender render --scene --backend gpu
/// --spp 3`.
fn matches_pinrender(estimator: &str, embed: Option<u32>) {
    let dir = tempfile::tempdir().unwrap();
    bake(dir.path(), "c.pin", 1.0, embed);
    let scene = write(dir.path(), "sky.json", SCENE);
    let Some(display) = display() else { return };
    let saved = dir.path().join("view.exr");
    let shot = dir.path().join("view.png");
    let reference = dir.path().join("ref.exr");
    // The sky's radiance from a flag (the scene leaves it out), the rest from the scene.
    let flags = [
        "--width",
        "48",
        "--height",
        "40",
        "--seed",
        "7",
        "--env-radiance",
        "0.5",
    ];
    let mut view_args = vec![s(&scene), "--estimator", estimator, "--frames", "3"];
    view_args.extend_from_slice(&flags);
    view_args.extend_from_slice(&["--screenshot", s(&shot), "--save", s(&saved), "--json"]);
    let out = pinview(Some(&display), &view_args);
    ok(&out, "pinview");
    let mut render_args = vec![
        "--scene",
        s(&scene),
        "--backend",
        "gpu",
        "--estimator",
        estimator,
    ];
    render_args.extend_from_slice(&["--spp", "3", "--out", s(&reference)]);
    render_args.extend_from_slice(&flags);
    ok(&pinrender_render(&render_args), "pinrender render --scene");
    let (view, want) = (exr_bits(&saved), exr_bits(&reference));
    assert_eq!(view.len(), 48 * 40 * 3);
    assert!(
        view == want,
        "the viewer's EXR of the scene differs from pinrender render --scene --backend gpu"
    );
    assert!(
        png_rgb(&shot).2.iter().any(|&c| c > 30),
        "the screenshot is black"
    );
    let j = json(&out);
    assert_eq!(j["estimator"], estimator, "{j}");
    assert_eq!(j["instances"], 3, "{j}");
    assert_eq!(j["passes"], 3, "{j}");
}

fn one_line(out: &Output, code: i32, needles: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(code), "exit code; stderr: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "one line expected: {err}");
    assert!(lines[0].starts_with("pinview: error: "), "{err}");
    for needle in needles {
        assert!(lines[0].contains(needle), "'{needle}' missing from: {err}");
    }
    assert!(!err.contains("panicked"), "{err}");
    assert!(out.stdout.is_empty(), "nothing on stdout on failure");
}

#[test]
fn a_bad_scene_is_one_line_naming_the_file_and_the_json_path() {
    let dir = tempfile::tempdir().unwrap();
    bake(dir.path(), "c.pin", 1.0, None);
    let Some(display) = display() else { return };
    let d = Some(&display);
    let run = |scene: &Path, extra: &[&str]| {
        let mut args = vec![s(scene), "--frames", "1"];
        args.extend_from_slice(extra);
        pinview(d, &args)
    };
    let missing = dir.path().join("missing.json");
    one_line(&run(&missing, &[]), 1, &["missing.json"]);
    let not_json = write(dir.path(), "broken.json", "{\"assets\": ");
    one_line(&run(&not_json, &[]), 1, &["broken.json", "not JSON"]);
    let flat = write(
        dir.path(),
        "flat.json",
        r#"{"assets": {"c": {"pins": "c.pin"}},
            "instances": [{"asset": "c"}, {"asset": "c"}, {"asset": "c"},
                          {"asset": "c", "transform": {"scale": [1, 1, 0]}}]}"#,
    );
    one_line(
        &run(&flat, &[]),
        1,
        &[
            "flat.json",
            "instances[3].transform",
            "scales the z axis by 0",
        ],
    );
    let lost = write(
        dir.path(),
        "lost.json",
        r#"{"assets": {"c": {"pins": "nowhere.pin"}}, "instances": [{"asset": "c"}]}"#,
    );
    one_line(
        &run(&lost, &[]),
        1,
        &["lost.json", "assets.c.pins", "nowhere.pin"],
    );
    // A tracker reads the density, which these pins do not hold: pinrender's own line.
    let good = write(dir.path(), "good.json", SCENE);
    one_line(
        &run(&good, &["--estimator", "ratio"]),
        1,
        &["good.json", "assets.cloud.pins", "no embedded density"],
    );
    // What needs one medium is a usage error.
    one_line(
        &run(&good, &["--compare", "pins"]),
        2,
        &["--compare", "good.json"],
    );
    one_line(&run(&good, &["--error-view"]), 2, &["--error-view"]);
}

#[test]
fn interactive_a_bad_scene_keeps_its_window_open() {
    let dir = tempfile::tempdir().unwrap();
    let flat = write(
        dir.path(),
        "flat.json",
        r#"{"assets": {"c": {"pins": "c.pin"}}, "instances": [{"asset": "c"}]}"#,
    );
    let Some(display) = display() else { return };
    let mut child = viewer_command(Some(&display))
        .arg(s(&flat))
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // Without --frames the refused scene (its pins are missing) is shown in a window, which
    // stays until closed, rather than the process ending at once.
    std::thread::sleep(std::time::Duration::from_secs(4));
    let exited = child.try_wait().unwrap();
    let _ = child.kill();
    let _ = child.wait();
    assert_eq!(exited, None, "pinview ended instead of showing the error");
}

/// 4,096 turned and stretched instances of one asset with a density and pins render in the
/// viewer within a small `--max-memory` (off-screen: the same media and session as the
/// window), as `pinrender render --scene` does; a budget below what the scene needs is one
/// line naming the file.
#[test]
fn four_thousand_instances_open_within_max_memory() {
    let dir = tempfile::tempdir().unwrap();
    bake(dir.path(), "c.pin", 1.0, Some(8));
    let instances: Vec<String> = (0..4096)
        .map(|i| {
            let (x, y, z) = (i % 16, (i / 16) % 16, i / 256);
            format!(
                r#"{{"asset": "c", "transform": {{"translate": [{}, {}, {}], "rotate_deg": [{}, {}, 0], "scale": [1.2, 0.8, 1]}}}}"#,
                f64::from(x) * 1.5,
                f64::from(y) * 1.5,
                f64::from(z) * 1.5,
                i % 30,
                (i * 7) % 90
            )
        })
        .collect();
    let scene = write(
        dir.path(),
        "many.json",
        &format!(
            r#"{{"assets": {{"c": {{"pins": "c.pin"}}}}, "instances": [{}]}}"#,
            instances.join(",")
        ),
    );
    let run = |estimator: &str, mem: &str| {
        pinview(
            None,
            &[
                s(&scene),
                "--estimator",
                estimator,
                "--offscreen",
                "--frames",
                "1",
                "--width",
                "16",
                "--height",
                "12",
                "--max-memory",
                mem,
                "--json",
            ],
        )
    };
    for estimator in ["pins", "ratio"] {
        let out = run(estimator, "64M");
        ok(&out, estimator);
        let j = json(&out);
        assert_eq!(j["instances"], 4096, "{j}");
        assert_eq!(j["passes"], 1, "{j}");
    }
    one_line(&run("pins", "100K"), 1, &["many.json"]);
}

/// A scene's first image comes within the bounds of a single file's of the same pixels: 256
/// instances of the bake in a 16 x 16 slab against the bake alone, off-screen, pins at 96 x
/// 54. Compared without `warm_up_s` (the driver's first-dispatch compile, which a scene's own
/// pipeline layout pays once in a run whose shader cache lacks it, and a single file's
/// does not): the scene's time to its first image at most twice the single file's plus 1 s.
#[test]
fn a_scenes_first_image_is_within_a_single_files_bounds() {
    let dir = tempfile::tempdir().unwrap();
    let pin = bake(dir.path(), "c.pin", 1.0, None);
    let instances: Vec<String> = (0..256)
        .map(|i| {
            let (x, z) = (f64::from(i % 16) * 1.5, f64::from(i / 16) * 1.5);
            format!(r#"{{"asset": "c", "transform": {{"translate": [{x}, 0, {z}]}}}}"#)
        })
        .collect();
    let scene = write(
        dir.path(),
        "slab.json",
        &format!(
            r#"{{"assets": {{"c": {{"pins": "c.pin"}}}}, "instances": [{}]}}"#,
            instances.join(",")
        ),
    );
    let first = |input: &Path| {
        let out = pinview(
            None,
            &[
                s(input),
                "--estimator",
                "pins",
                "--offscreen",
                "--frames",
                "1",
                "--width",
                "96",
                "--height",
                "54",
                "--json",
            ],
        );
        ok(&out, s(input));
        let j = json(&out);
        let t =
            j["first_image_s"].as_f64().unwrap_or(-1.0) - j["warm_up_s"].as_f64().unwrap_or(0.0);
        assert!(t > 0.0, "{j}");
        (t, j)
    };
    let (single, _) = first(&pin);
    let (many, j) = first(&scene);
    assert_eq!(j["instances"], 256, "{j}");
    assert!(
        many <= 2.0 * single + 1.0,
        "the scene's first image took {many:.2} s, the single file's {single:.2} s: {j}"
    );
}
