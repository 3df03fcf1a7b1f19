//! `--offscreen`: the viewer's session, passes and tone map with no window and no display;
//! its EXR is `pinrender render --backend gpu`'s bits and the window's, its screenshot the
//! window's.

use crate::failures::one_line;
use crate::support::*;

#[test]
fn offscreen_renders_the_window_bits_without_a_display() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, Some(12));
    let mut flags = VIEW.to_vec();
    flags.extend_from_slice(&["--seed", "5", "--estimator", "pinms"]);
    let run = |display: Option<&Display>, tag: &str, extra: &[&str]| {
        let png = dir.path().join(format!("{tag}.png"));
        let exr = dir.path().join(format!("{tag}.exr"));
        let mut args = vec![s(&pins)];
        args.extend_from_slice(&flags);
        args.extend_from_slice(extra);
        args.extend_from_slice(&[
            "--frames",
            "3",
            "--screenshot",
            s(&png),
            "--save",
            s(&exr),
            "--json",
        ]);
        let out = pinview(display, &args);
        ok(&out, tag);
        (exr_bits(&exr), png_rgb(&png), json(&out))
    };
    // No DISPLAY at all.
    let (exr, png, j) = run(None, "offscreen", &["--offscreen"]);
    assert_eq!(j["offscreen"], true, "{j}");
    assert_eq!(j["passes"], 3, "{j}");
    assert_eq!(j["estimator"], "pinms", "{j}");
    // 48 x 40 is small enough that no preview is made.
    assert!(j["first_preview_s"].is_null(), "{j}");
    for key in [
        "ms_per_pass",
        "samples_per_second",
        "first_image_s",
        "longest_frame_gap_ms",
    ] {
        assert!(j[key].as_f64().is_some_and(|v| v > 0.0), "{key}: {j}");
    }
    assert!(
        j["gpu_bytes"]["pins"].as_u64().is_some_and(|b| b > 0),
        "{j}"
    );
    let steps = &j["first_image_breakdown"];
    let sum: f64 = [
        "file_open_s",
        "window_and_device_s",
        "upload_s",
        "pipeline_s",
        "first_pass_s",
    ]
    .iter()
    .map(|k| steps[*k].as_f64().unwrap_or(-1.0))
    .sum();
    let first = j["first_image_s"].as_f64().unwrap_or_default();
    assert!((sum - first).abs() < 1e-9, "{sum} != {first}: {j}");
    let reference = dir.path().join("ref.exr");
    let mut render = vec!["--pins", s(&pins), "--backend", "gpu", "--spp", "3"];
    render.extend_from_slice(&flags);
    render.extend_from_slice(&["--out", s(&reference)]);
    ok(&pinrender_render(&render), "pinrender render");
    assert!(
        exr == exr_bits(&reference),
        "the off-screen EXR differs from pinrender render --backend gpu"
    );
    assert!(png.2.iter().any(|&c| c > 30), "the screenshot is black");
    let Some(display) = display() else { return };
    let (wexr, wpng, wj) = run(Some(&display), "window", &[]);
    assert_eq!(wj["offscreen"], false, "{wj}");
    assert!(exr == wexr, "the off-screen EXR differs from the window's");
    assert!(
        png == wpng,
        "the off-screen screenshot differs from the window's"
    );
}

#[test]
fn offscreen_refuses_what_needs_the_window() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "c.pin", 1.0, None);
    let p = s(&pins);
    for flag in [
        &["--compare", "pins"][..],
        &["--pin-at", "3,4"],
        &["--grid-overlay"],
    ] {
        let mut args = vec![p, "--offscreen", "--frames", "1"];
        args.extend_from_slice(flag);
        one_line(&pinview(None, &args), 2, flag[0]);
    }
    let pattern = dir.path().join("c.####.pin");
    one_line(
        &pinview(None, &[s(&pattern), "--offscreen", "--frames", "1"]),
        2,
        "frame pattern",
    );
    // It needs --frames (the passes to render).
    let out = pinview(None, &[p, "--offscreen"]);
    assert_eq!(out.status.code(), Some(2), "{out:?}");
}
