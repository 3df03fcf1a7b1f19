//! Scripted runs end, whatever `--compare`, `--play` or the mix of files in a sequence: each
//! run here has a time limit, and one that does not end fails.

use std::time::Duration;

use crate::support::*;

/// Far above what these 48 x 40 runs take on a loaded CPU adapter.
const LIMIT: Duration = Duration::from_secs(180);

#[test]
fn a_comparison_of_one_pass_ends_with_a_pass_on_each_side() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, Some(12));
    let Some(display) = display() else { return };
    let exr = dir.path().join("one.exr");
    // 8 x 8: the first side's one pass is one call of the pacer even on a loaded CPU
    // adapter, so its time is never measured (the case that waited for ever).
    let mut args = vec![s(&pins)];
    args.extend_from_slice(&VIEW[..4]);
    args.extend_from_slice(&[
        "--width",
        "8",
        "--height",
        "8",
        "--estimator",
        "pins",
        "--compare",
        "ratio",
        "--frames",
        "1",
        "--save",
        s(&exr),
        "--json",
    ]);
    let out = pinview_within(Some(&display), &args, LIMIT);
    ok(&out, "pinview --compare --frames 1");
    let j = json(&out);
    assert_eq!(j["passes"], 1, "{j}");
    assert_eq!(j["compare"]["passes"], 1, "{j}");
    assert_eq!(j["compare"]["estimator"], "ratio", "{j}");
}

/// A sequence whose first frame embeds a density (shown with ratio tracking, the default for
/// a pin file that embeds one) and whose second holds pins only.
fn mixed_sequence(dir: &std::path::Path) -> std::path::PathBuf {
    bake(dir, "mix.0001.pin", 1.0, Some(12));
    bake(dir, "mix.0002.pin", 2.0, None);
    dir.join("mix.####.pin")
}

/// One run over the mixed sequence: `--play --frames 1` with the default 16 passes a frame
/// (more than the run asks for) still plays to the last frame and renders its pass there;
/// that frame cannot answer ratio tracking, so it falls back to its pins with a note, and
/// its image is its own pins render at the passes shown.
#[test]
fn playing_ends_on_the_last_frame_and_a_frame_that_cannot_answer_falls_back() {
    let dir = tempfile::tempdir().unwrap();
    let pattern = mixed_sequence(dir.path());
    let Some(display) = display() else { return };
    let exr = dir.path().join("last.exr");
    let mut args = vec![s(&pattern)];
    args.extend_from_slice(&VIEW);
    args.extend_from_slice(&["--play", "--frames", "1", "--save", s(&exr), "--json"]);
    let out = pinview_within(Some(&display), &args, LIMIT);
    ok(&out, "pinview --play --frames 1 over a mixed sequence");
    let j = json(&out);
    assert_eq!(j["frames_played"], serde_json::json!([1, 2]), "{j}");
    assert_eq!(j["passes"], 1, "{j}");
    assert_eq!(j["estimator"], "pins", "{j}");
    let notes = j["notes"].to_string();
    assert!(
        notes.contains("mix.0002.pin") && notes.contains("no embedded density, which ratio needs"),
        "no note of the fallback: {j}"
    );
    let reference = dir.path().join("ref.exr");
    let bits = render_command(j["command"].as_str().unwrap(), &reference);
    assert!(
        exr_bits(&exr) == bits,
        "frame 2 is not its pins render: {j}"
    );
}
