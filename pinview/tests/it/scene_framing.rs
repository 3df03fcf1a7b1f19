//! A scene of 256 instances whose camera stands inside one of them (a camera meant for
//! another placement) opens in the window framed from outside every instance's box, looking
//! at them, with a note; `--camera-origin` keeps the camera asked for, and the scripted
//! `frame all` moves it out; "reset view" (the scripted `reset`) returns to the camera framed
//! from outside that the scene opened with, not to the scene's own inside one.

use crate::support::*;

/// Instance `i` of the 16 x 16 slab: the unit box of [`bake`]'s asset moved by this.
fn offset(i: u32) -> [f64; 3] {
    [f64::from(i % 16) * 1.5, 0.0, f64::from(i / 16) * 1.5]
}

/// The `--camera-origin` of a JSON line's `command`.
fn origin(j: &serde_json::Value) -> [f64; 3] {
    let command = j["command"].as_str().unwrap();
    let words: Vec<&str> = command.split_whitespace().collect();
    let at = words.iter().position(|w| *w == "--camera-origin").unwrap();
    let v: Vec<f64> = words[at + 1]
        .split(',')
        .map(|x| x.parse().unwrap())
        .collect();
    [v[0], v[1], v[2]]
}

fn inside_an_instance(p: [f64; 3]) -> Option<u32> {
    (0..256).find(|&i| {
        let o = offset(i);
        (0..3).all(|k| p[k] >= o[k] && p[k] <= o[k] + 1.0)
    })
}

#[test]
fn a_scene_with_its_camera_inside_opens_outside_every_instance() {
    let dir = tempfile::tempdir().unwrap();
    bake(dir.path(), "c.pin", 1.0, None);
    let instances: Vec<String> = (0..256)
        .map(|i| {
            let [x, y, z] = offset(i);
            format!(r#"{{"asset": "c", "transform": {{"translate": [{x}, {y}, {z}]}}}}"#)
        })
        .collect();
    let scene = write_file(
        dir.path(),
        "slab.json",
        format!(
            r#"{{"assets": {{"c": {{"pins": "c.pin"}}}}, "instances": [{}],
                "camera": {{"origin": [3.5, 0.5, 3.5], "target": [12, 0.5, 12]}}}}"#,
            instances.join(",")
        ),
    );
    assert_eq!(inside_an_instance([3.5, 0.5, 3.5]), Some(2 + 16 * 2));
    let Some(display) = display() else { return };
    let run = |extra: &[&str]| {
        let mut args = vec![
            s(&scene),
            "--estimator",
            "pins",
            "--frames",
            "1",
            "--width",
            "32",
            "--height",
            "24",
            "--json",
        ];
        args.extend_from_slice(extra);
        let out = pinview(Some(&display), &args);
        ok(&out, "pinview slab.json");
        json(&out)
    };
    let j = run(&[]);
    assert_eq!(j["instances"], 256, "{j}");
    let o = origin(&j);
    let opened = o;
    assert_eq!(
        inside_an_instance(o),
        None,
        "{o:?} is inside an instance: {j}"
    );
    // Outside the union's box, looking at its centre.
    assert!(
        o[1] > 1.0 || o[0] > 23.5 || o[2] > 23.5 || o[0] < 0.0 || o[2] < 0.0,
        "{o:?}"
    );
    assert!(
        j["command"]
            .as_str()
            .unwrap()
            .contains("--camera-target 11.75,0.5,11.75"),
        "{j}"
    );
    let notes = j["notes"].to_string();
    assert!(
        notes.contains("inside instance") && notes.contains("of 256"),
        "{j}"
    );
    // The flag keeps its camera, wherever it stands; the scripted `frame all` then frames.
    let j = run(&["--camera-origin", "3.5,0.5,3.5"]);
    assert_eq!(origin(&j), [3.5, 0.5, 3.5], "{j}");
    let events = dir.path().join("frame_all.json");
    std::fs::write(&events, r#"[{"at_s": 0, "action": "frame_all"}]"#).unwrap();
    let j = run(&[
        "--camera-origin",
        "3.5,0.5,3.5",
        "--input-script",
        s(&events),
    ]);
    let o = origin(&j);
    assert_eq!(
        inside_an_instance(o),
        None,
        "{o:?} is inside an instance: {j}"
    );
    assert!(
        j["command"]
            .as_str()
            .unwrap()
            .contains("--camera-target 11.75,0.5,11.75"),
        "{j}"
    );
    // An orbit, then a reset: back to the camera the scene opened with, outside.
    let events = write_file(
        dir.path(),
        "reset.json",
        r#"[{"at_s": 0, "action": "orbit", "dx_deg": 40, "dy_deg": 10},
            {"at_s": 0.2, "action": "reset"}]"#,
    );
    let j = run(&["--input-script", s(&events)]);
    let o = origin(&j);
    assert_eq!(
        inside_an_instance(o),
        None,
        "{o:?} is inside an instance after a reset: {j}"
    );
    assert_eq!(o, opened, "the reset is not the opening camera: {j}");
}
