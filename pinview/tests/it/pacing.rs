//! The window answers while pipelines compile: the shown estimator's, the second side's and
//! the reference's renderers are built off the window's thread, so the longest time between
//! two painted frames stays far below a compile (which the window once waited for).

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
    // frame of the window alone takes 60-250 ms (the CPU rasterises it beside the compile);
    // a compile takes 0.7 s or more.
    assert!(
        gap < 0.5 * compile,
        "the longest gap between frames, {gap:.0} ms, is not far below the pipeline \
         compile's {compile:.0} ms: {j}"
    );
    assert!(gap < 1000.0, "a frame took {gap:.0} ms: {j}");
}
