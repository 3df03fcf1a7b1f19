//! The split view's divider: a drag that starts on its handle (a few points either side of
//! the line) moves the divider and neither orbits the camera nor restarts the sessions.

use std::time::Duration;

use crate::support::*;

#[test]
fn a_drag_on_the_divider_moves_it_and_not_the_camera() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, Some(12));
    // The image is 48 pixels wide, shown at one point a pixel: the line stands at x = 24.
    // The drag starts 8 points right of it (within the handle's reach) and ends at 12.
    let events = write_file(
        dir.path(),
        "events.json",
        r#"[{"at_s": 0.2, "action": "drag", "from": [32, 20], "to": [12, 22]}]"#,
    );
    let Some(display) = display() else { return };
    let mut args = vec![s(&pins)];
    args.extend_from_slice(&VIEW);
    args.extend_from_slice(&[
        "--seed",
        "5",
        "--estimator",
        "pins",
        "--compare",
        "ratio",
        "--input-script",
        s(&events),
        "--frames",
        "2",
        "--json",
    ]);
    let out = pinview_within(Some(&display), &args, Duration::from_secs(180));
    ok(&out, "pinview --compare with a drag on the divider");
    let j = json(&out);
    assert_eq!(j["events"][0]["action"], "drag", "{j}");
    assert_eq!(j["script_end"], "passes", "{j}");
    // The divider followed the pointer to where it was let go.
    let split = j["compare"]["split_column"].as_u64();
    assert_eq!(split, Some(12), "the divider did not follow the drag: {j}");
    // The camera stayed where the flags put it: the batch command has the flags' origin.
    let command = j["command"].as_str().unwrap_or("");
    assert!(
        command.contains("--camera-origin 0.5,0.6,2.6 "),
        "the drag on the divider moved the camera: {command}"
    );
}
