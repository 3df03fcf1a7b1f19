//! The window answers while pipelines compile: the shown estimator's, the second side's and
//! the reference's renderers are built off the window's thread (their first dispatch too,
//! on a device of their own on a CPU adapter), so the longest time between two painted
//! frames stays far below a compile (which the window once waited for). A coarse preview
//! comes before the first whole pass and never into it.

use crate::support::*;

#[test]
fn the_window_paints_while_the_pipelines_compile() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, Some(12));
    let Some(display) = display() else { return };
    let mut args = vec![s(&pins)];
    args.extend_from_slice(&VIEW);
    args.extend_from_slice(&[
        "--estimator",
        "pinms",
        "--compare",
        "ratio",
        "--error-view",
        "--frames",
        "2",
        "--json",
    ]);
    // Mesa's shader cache as the environment has it: warm, it spares lavapipe the LLVM
    // compile at the first dispatch, but not the passes that build each pipeline, which take
    // seconds for the three here in every process (cold, the run takes 25 s more of CPU
    // and shows the same thing).
    let out = pinview(Some(&display), &args);
    ok(&out, "pinview");
    let j = json(&out);
    let gap = j["longest_frame_gap_ms"].as_f64().unwrap_or(-1.0);
    let compile = 1e3
        * j["first_image_breakdown"]["pipeline_s"]
            .as_f64()
            .unwrap_or(0.0);
    let frames = j["frames_painted"].as_u64().unwrap_or(0);
    assert!(gap > 0.0 && compile > 0.0, "{j}");
    // The window painted before the first image: while the three pipelines compiled.
    assert!(frames > 3, "{frames} frames painted: {j}");
    // A window that waited for a compile would go that long without a frame. On lavapipe a
    // frame of the window alone takes 60-250 ms (the CPU rasterises it beside the compile),
    // its first (egui's shaders compiled) up to about 450 ms on loaded cores; the three
    // pipelines take seconds.
    assert!(
        gap < 0.5 * compile,
        "the longest gap between frames, {gap:.0} ms, is not far below the pipeline \
         compile's {compile:.0} ms: {j}"
    );
    assert!(gap < 1000.0, "a frame took {gap:.0} ms: {j}");
}

#[test]
fn a_coarse_preview_comes_before_the_first_pass_and_not_into_it() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, Some(12));
    let exr = dir.path().join("p.exr");
    // 160 x 40: a preview of 80 x 20 (the longer side over 128 pixels).
    let mut flags = VIEW[..4].to_vec();
    flags.extend_from_slice(&["--width", "160", "--height", "40", "--seed", "5"]);
    flags.extend_from_slice(&["--estimator", "pinms"]);
    let reference = dir.path().join("ref.exr");
    let mut render = vec!["--pins", s(&pins), "--backend", "gpu", "--spp", "2"];
    render.extend_from_slice(&flags);
    render.extend_from_slice(&["--out", s(&reference)]);
    ok(&pinrender_render(&render), "pinrender render");
    let check = |display: Option<&Display>, extra: &[&str]| {
        let mut args = vec![s(&pins)];
        args.extend_from_slice(&flags);
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--frames", "2", "--save", s(&exr), "--json"]);
        let out = pinview(display, &args);
        ok(&out, "pinview");
        let j = json(&out);
        let preview = j["first_preview_s"].as_f64().unwrap_or(-1.0);
        let first = j["first_image_s"].as_f64().unwrap_or(-1.0);
        assert!(
            preview > 0.0 && preview < first,
            "the preview ({preview} s) does not come before the first pass ({first} s): {j}"
        );
        assert!(j["warm_up_s"].as_f64().is_some_and(|v| v > 0.0), "{j}");
        // The preview is a session of its own: the accumulation holds the two passes alone.
        assert!(
            exr_bits(&exr) == exr_bits(&reference),
            "with a preview the EXR differs from pinrender render --spp 2: {j}"
        );
    };
    check(None, &["--offscreen"]);
    let Some(display) = display() else { return };
    check(Some(&display), &[]);
}
