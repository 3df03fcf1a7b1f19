//! Scripted input (`--input-script`): events replayed in the real window, each answered
//! with its times, and the run's end N passes after the last event (the end 10 s after it
//! is checked by `clipboard`'s run).

use std::time::Duration;

use crate::support::*;

const LIMIT: Duration = Duration::from_secs(180);

#[test]
fn events_move_the_view_and_each_is_answered() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, None);
    let events = write_file(
        dir.path(),
        "events.json",
        r#"[
            {"at_s": 0.0, "action": "orbit", "dx_deg": 30, "dy_deg": 10},
            {"at_s": 0.3, "action": "zoom", "factor": 1.5},
            {"at_s": 0.6, "action": "pan", "dx": 0.05, "dy": -0.05},
            {"at_s": 0.9, "action": "sun", "dir": [-0.4, 1, 0.3]},
            {"at_s": 1.2, "action": "exposure", "stops": 1},
            {"at_s": 1.5, "action": "resize", "width": 40, "height": 32}
        ]"#,
    );
    let Some(display) = display() else { return };
    let exr = dir.path().join("view.exr");
    let mut args = vec![s(&pins)];
    args.extend_from_slice(&VIEW);
    args.extend_from_slice(&[
        "--seed",
        "3",
        "--input-script",
        s(&events),
        "--frames",
        "2",
        "--save",
        s(&exr),
        "--json",
    ]);
    let out = pinview_within(Some(&display), &args, LIMIT);
    ok(&out, "pinview --input-script");
    let j = json(&out);
    let e = j["events"].as_array().expect("events");
    let actions: Vec<&str> = e.iter().map(|e| e["action"].as_str().unwrap()).collect();
    assert_eq!(
        actions,
        ["orbit", "zoom", "pan", "sun", "exposure", "resize"],
        "{j}"
    );
    for e in e {
        let first = e["first_pixels_ms"].as_f64();
        let full = e["first_full_pass_ms"].as_f64();
        assert!(
            first.is_some_and(|f| f >= 0.0) && full.is_some_and(|p| p >= first.unwrap()),
            "an event without its times: {j}"
        );
    }
    // At 48 x 40 (no larger than the coarse image) a whole pass answers each event.
    assert!(e.iter().all(|e| e["first_pixels"] == "pass"), "{j}");
    assert!(j["longest_frame_gap_ms"].as_f64().is_some(), "{j}");
    assert_eq!(j["script_end"], "passes", "{j}");
    // N passes after the last event, on the resized image.
    assert_eq!(
        (&j["passes"], &j["width"], &j["height"]),
        (&2.into(), &40.into(), &32.into())
    );
    // The saved image is the batch render of the moved view: each event took effect.
    let command = j["command"].as_str().unwrap();
    assert!(command.contains("--exposure 2 "), "{command}");
    assert!(command.contains("--sun-dir -0.4,1,0.3 "), "{command}");
    let bits = render_command(command, &dir.path().join("batch.exr"));
    assert!(
        exr_bits(&exr) == bits,
        "the saved image is not the moved view's render"
    );
    // And the view did move: the unmoved view's render differs.
    let mut unmoved = vec!["--pins", s(&pins), "--backend", "gpu", "--spp", "2"];
    unmoved.extend_from_slice(&VIEW);
    let still = dir.path().join("still.exr");
    unmoved.extend_from_slice(&["--seed", "3", "--out", s(&still)]);
    ok(&pinrender_render(&unmoved), "pinrender render");
    assert!(exr_bits(&still) != bits);
}

#[test]
fn a_bad_events_file_is_one_line_and_exit_1() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, None);
    let Some(display) = display() else { return };
    for (events, want) in [
        (
            r#"[{"at_s": 0, "action": "spin"}]"#,
            "event 1: unknown action \"spin\"",
        ),
        (
            r#"[{"at_s": 0, "action": "frame", "index": 2}]"#,
            "event 1: frame 2",
        ),
    ] {
        let path = write_file(dir.path(), "bad.json", events);
        let mut args = vec![s(&pins)];
        args.extend_from_slice(&VIEW);
        args.extend_from_slice(&["--input-script", s(&path), "--frames", "1"]);
        let out = pinview_within(Some(&display), &args, LIMIT);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{events}: {err}");
        assert_eq!(err.lines().count(), 1, "{events}: {err}");
        assert!(
            err.contains(s(&path)) && err.contains(want),
            "{events}: {err}"
        );
    }
}

#[test]
fn a_changed_view_answers_with_a_coarse_image_before_its_first_pass() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, Some(12));
    let events = write_file(
        dir.path(),
        "events.json",
        r#"[
            {"at_s": 0.0, "action": "orbit", "dx_deg": 20, "dy_deg": 0},
            {"at_s": 1.0, "action": "zoom", "factor": 1.25},
            {"at_s": 2.0, "action": "sun", "dir": [-0.5, 1, 0.3]}
        ]"#,
    );
    let Some(display) = display() else { return };
    let exr = dir.path().join("view.exr");
    let args = [
        s(&pins),
        "--camera-origin",
        "0.5,0.6,2.6",
        "--camera-target",
        "0.5,0.5,0.5",
        "--width",
        "256",
        "--height",
        "256",
        // The cheapest estimator: the coarse image answers whatever the estimator.
        "--estimator",
        "pins",
        "--input-script",
        s(&events),
        "--frames",
        "1",
        "--save",
        s(&exr),
        "--json",
    ];
    let out = pinview_within(Some(&display), &args, LIMIT);
    ok(&out, "pinview --input-script at 256 x 256");
    let j = json(&out);
    for e in j["events"].as_array().unwrap() {
        assert_eq!(e["first_pixels"], "coarse", "{j}");
        let (first, full) = (
            e["first_pixels_ms"].as_f64(),
            e["first_full_pass_ms"].as_f64(),
        );
        if let (Some(first), Some(full)) = (first, full) {
            assert!(first <= full, "{j}");
        }
    }
    // The coarse image leaves the accumulation alone: its pass is the batch render's.
    let bits = render_command(
        j["command"].as_str().unwrap(),
        &dir.path().join("batch.exr"),
    );
    assert!(exr_bits(&exr) == bits, "{j}");
}
