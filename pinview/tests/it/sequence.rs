//! Frame sequences: play steps through the frames; each frame is the pin file pinrender
//! renders.

use crate::support::*;

#[test]
fn play_steps_through_the_frames() {
    let dir = tempfile::tempdir().unwrap();
    for (k, scale) in [(1, 0.5), (2, 1.0), (3, 2.0)] {
        bake(dir.path(), &format!("sim.{k:04}.pin"), scale, None);
    }
    let pattern = dir.path().join("sim.####.pin");
    let Some(display) = display() else { return };
    let run = |extra: &[&str], tag: &str| {
        let exr = dir.path().join(format!("{tag}.exr"));
        let mut args = vec![s(&pattern)];
        args.extend_from_slice(&VIEW);
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--frames", "2", "--save", s(&exr), "--json"]);
        let out = pinview(Some(&display), &args);
        ok(&out, "pinview");
        (json(&out), exr_bits(&exr))
    };
    // Paused: the first frame.
    let (j, first) = run(&[], "first");
    assert_eq!(j["frame"], 1, "{j}");
    assert_eq!(j["frames_played"], serde_json::json!([1]), "{j}");
    assert!(j["playback_fps"].is_null(), "{j}");
    assert_eq!(j["pipelines_compiled"], 1, "{j}");
    // Playing, one pass per frame: every frame shown in turn, ending on the last.
    let (j, last) = run(&["--play", "--frame-passes", "1"], "last");
    assert_eq!(j["frame"], 3, "{j}");
    assert_eq!(j["frames_played"], serde_json::json!([1, 2, 3]), "{j}");
    // Each frame swaps its buffers into the pipeline the first one compiled.
    assert_eq!(j["pipelines_compiled"], 1, "{j}");
    // Two steps taken while playing, over a positive time.
    assert!(
        j["playback_fps"]
            .as_f64()
            .is_some_and(|f| f > 0.0 && f.is_finite()),
        "{j}"
    );
    assert!(first != last, "the frames differ, so must their images");
    // The last frame's image is that file's own render.
    let reference = dir.path().join("ref3.exr");
    let frame3 = dir.path().join("sim.0003.pin");
    let mut args = vec!["--pins", s(&frame3), "--backend", "gpu", "--spp", "2"];
    args.extend_from_slice(&VIEW);
    args.extend_from_slice(&["--out", s(&reference)]);
    ok(&pinrender_render(&args), "pinrender render");
    assert!(
        last == exr_bits(&reference),
        "frame 3 differs from its pinrender render"
    );
}
