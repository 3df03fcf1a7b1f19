//! Every refusal: one line, the file, the JSON path, the problem.

use crate::{folder, refusal, write};

const OK_ASSETS: &str = r#""assets": {"a": {"volume": "a.vdb"}, "b": {"pins": "a.pin"}}"#;

fn with_instances(instances: &str) -> String {
    format!(r#"{{{OK_ASSETS}, "instances": {instances}}}"#)
}

fn with(extra: &str) -> String {
    format!(r#"{{{OK_ASSETS}, "instances": [{{"asset": "a"}}], {extra}}}"#)
}

#[test]
fn transforms_name_the_instance() {
    let mut list = vec![r#"{"asset": "a"}"#; 17];
    list.push(r#"{"asset": "a", "transform": [1,0,0,0, 0,1,0,0, 0,0,0,0]}"#);
    let e = refusal(&with_instances(&format!("[{}]", list.join(","))));
    assert!(
        e.starts_with("instances[17].transform: scales the z axis by 0"),
        "{e}"
    );
    let e = refusal(&with_instances(r#"[{"asset": "a", "transform": [1,2,3]}]"#));
    assert!(
        e.starts_with(
            "instances[0].transform: a matrix transform has 12 numbers (row-major 3x4), got 3"
        ),
        "{e}"
    );
    let e = refusal(&with_instances(
        r#"[{"asset": "a", "transform": [1,0,0,0,0,1,0,0,0,0,1,0,9]}]"#,
    ));
    assert!(e.contains("got more"), "{e}");
    let e = refusal(&with_instances(
        r#"[{"asset": "a", "transform": {"rotate": [0,0,0]}}]"#,
    ));
    assert!(
        e.starts_with(r#"instances[0].transform: unknown key "rotate", expected translate, rotate_deg or scale"#),
        "{e}"
    );
    let e = refusal(&with_instances(
        r#"[{"asset": "a", "transform": {"scale": [1,2]}}]"#,
    ));
    assert!(e.starts_with("instances[0].transform.scale: "), "{e}");
    let e = refusal(&with_instances(
        r#"[{"asset": "a", "transform": {"scale": 1e-9}}]"#,
    ));
    assert!(e.contains("scales the x axis by 1e-9"), "{e}");
    let e = refusal(&with_instances(
        r#"[{"asset": "a", "transform": {"translate": [2e12, 0, 0]}}]"#,
    ));
    assert!(
        e.starts_with("instances[0].transform: translation 2e12,0,0 must be within"),
        "{e}"
    );
    let e = refusal(&with_instances(
        r#"[{"asset": "a", "transform": "identity"}]"#,
    ));
    assert!(
        e.starts_with("instances[0].transform: invalid type: string"),
        "{e}"
    );
    let e = refusal(&with_instances(
        r#"[{"asset": "a", "transform": {"scale": 2, "scale": 3}}]"#,
    ));
    assert!(e.contains("scale is given twice"), "{e}");
    let e = refusal(&with_instances(
        r#"[{"asset": "a", "transform": [1,1e9,0,0, 0,1,0,0, 0,0,1,0]}]"#,
    ));
    assert!(e.contains("scales the y axis by 1e9"), "{e}");
    let e = refusal(&with_instances(
        r#"[{"asset": "a", "transform": [1,1,0,0, 0,1e-9,0,0, 0,0,1,0]}]"#,
    ));
    assert!(e.contains("singular or too sheared"), "{e}");
}

#[test]
fn names_and_files_name_their_key() {
    let e = refusal(&with_instances(r#"[{"asset": "a"}, {"asset": "clod"}]"#));
    assert_eq!(
        e,
        r#"instances[1].asset: no asset named "clod" (the file names a, b)"#
    );
    let e = refusal(r#"{"assets": {"x": {}}, "instances": [{"asset": "x"}]}"#);
    assert_eq!(e, "assets.x: needs a volume, pins, or both");
    let e =
        refusal(r#"{"assets": {"x": {"volume": "missing.vdb"}}, "instances": [{"asset": "x"}]}"#);
    assert!(
        e.starts_with("assets.x.volume: ") && e.contains("missing.vdb"),
        "{e}"
    );
    let e = refusal(r#"{"assets": {"x": {"pins": "."}}, "instances": [{"asset": "x"}]}"#);
    assert!(
        e.starts_with("assets.x.pins: ") && e.ends_with("is a directory"),
        "{e}"
    );
    let e = refusal(r#"{"assets": {"x": {"pins": ""}}, "instances": [{"asset": "x"}]}"#);
    assert_eq!(e, "assets.x.pins: is an empty path");
    let e = refusal(
        r#"{"assets": {"x": {"pins": "a.pin"}, "x": {"pins": "a.pin"}}, "instances": [{"asset": "x"}]}"#,
    );
    assert!(e.starts_with("assets: asset x is given twice"), "{e}");
    let e = refusal(r#"{"assets": {"": {"pins": "a.pin"}}, "instances": []}"#);
    assert!(e.starts_with("assets: an asset name must be"), "{e}");
    let e = refusal(r#"{"assets": {"x": {"pins": "a.pin", "scale": 2}}, "instances": []}"#);
    assert!(
        e.starts_with("assets.x.scale: unknown field `scale`"),
        "{e}"
    );
    let e =
        refusal(r#"{"assets": {"x": {"pins": "a.pin", "density_scale": -1}}, "instances": []}"#);
    assert!(
        e.starts_with("assets.x.density_scale: -1 must be positive"),
        "{e}"
    );
    let e = refusal(r#"{"assets": {}, "instances": []}"#);
    assert_eq!(e, "assets: names no asset");
    let e = refusal(&with_instances("[]"));
    assert_eq!(e, "instances: places no instance");
}

#[test]
fn values_use_the_flags_ranges() {
    let cases = [
        (
            r#""camera": {"fov": 0}"#,
            "camera.fov: 0 must be in (0, 180) degrees",
        ),
        (
            r#""camera": {"origin": [0,0,0], "target": [0,0,0]}"#,
            "camera: origin and target are the same point",
        ),
        (
            r#""camera": {"origin": [0,0]}"#,
            "camera.origin: invalid length 2",
        ),
        (
            r#""sun": {"direction": [0,0,0]}"#,
            "sun.direction: 0,0,0 is not a direction",
        ),
        (
            r#""sun": {"radiance": -1}"#,
            "sun.radiance: -1 must be finite and >= 0",
        ),
        (
            r#""env_radiance": -0.5"#,
            "env_radiance: -0.5 must be finite and >= 0",
        ),
        (r#""albedo": 1.5"#, "albedo: 1.5 must be in [0, 1]"),
        (r#""g": 1"#, "g: 1 must be in (-1, 1)"),
        (
            r#""max_bounces": -1"#,
            "max_bounces: invalid value: integer `-1`, expected u32",
        ),
        (r#""lights": []"#, "lights: unknown field `lights`"),
    ];
    for (extra, want) in cases {
        let e = refusal(&with(extra));
        assert!(e.starts_with(want), "{extra}: {e}");
    }
}

#[test]
fn broken_text_says_where() {
    let e = refusal("{\"assets\": {\n  \"a\": {\"pins\": \"a.pin\"},\n}");
    assert!(e.starts_with("not JSON: "), "{e}");
    assert!(e.contains("(line 3, column 1)"), "{e}");
    let e =
        refusal(r#"{"assets": {"a": {"pins": "a.pin"}}, "instances": [{"asset": "a"}]} trailing"#);
    assert!(e.starts_with("not JSON: trailing characters"), "{e}");
    let e = refusal(r#"{"instances": [{"asset": "a"}]}"#);
    assert!(e.starts_with("missing field `assets`"), "{e}");
    let e = refusal("");
    assert!(e.starts_with("not JSON: EOF"), "{e}");
}

#[test]
fn files_that_are_not_scenes_are_refused_before_reading() {
    let dir = folder();
    let e = pin_scene::load(dir.path(), None).unwrap_err().to_string();
    assert!(e.ends_with("is a directory"), "{e}");
    let missing = dir.path().join("nope.json");
    let e = pin_scene::load(&missing, None).unwrap_err().to_string();
    assert!(e.starts_with(&format!("{}: ", missing.display())), "{e}");
    // Larger than a scene may be: refused from its length, not read.
    let big = write(dir.path(), "");
    std::fs::File::options()
        .write(true)
        .open(&big)
        .unwrap()
        .set_len(pin_scene::MAX_SCENE_BYTES + 1)
        .unwrap();
    let e = pin_scene::load(&big, None).unwrap_err().to_string();
    assert!(e.contains("more than a scene file may be"), "{e}");
}

/// Input is quoted at most a few dozen characters: a 60 MiB key made a 125 MB line (quoted
/// twice), and a string past `MAX_STRING_BYTES` is refused before it is parsed, so that no
/// copy of it is made.
#[test]
fn messages_quote_little_of_the_input() {
    let key = "k".repeat(2000);
    for text in [
        with(&format!(r#""{key}": 1"#)),
        with_instances(&format!(r#"[{{"asset": "{key}"}}]"#)),
        format!(r#"{{"assets": {{"{key}": {{"volume": "a.vdb"}}}}, "instances": []}}"#),
        format!(
            r#"{{"assets": {{"a": {{"volume": "{key}.vdb"}}}}, "instances": [{{"asset": "a"}}]}}"#
        ),
    ] {
        let e = refusal(&text);
        assert!(e.len() < 400, "{} bytes: {e}", e.len());
        assert!(!e.contains(&key), "{e}");
    }
    let huge = "x".repeat(pin_scene::MAX_STRING_BYTES + 1);
    let e = refusal(&with(&format!(r#""{huge}": 1"#)));
    assert!(
        e.starts_with(&format!(
            "a string of {} bytes at line 1, column",
            pin_scene::MAX_STRING_BYTES + 1
        )),
        "{e}"
    );
    assert!(e.len() < 200, "{e}");
}

/// A UTF-8 byte-order mark before the document is skipped (it was "not JSON ... line 1,
/// column 1").
#[test]
fn a_byte_order_mark_is_skipped() {
    let dir = folder();
    let text = format!("\u{feff}{}", with(r#""albedo": 0.5"#));
    let p = write(dir.path(), &text);
    let s = pin_scene::load(&p, None).unwrap();
    assert_eq!(s.albedo, Some(0.5));
}

/// A radiance the renderer's f32 cannot hold is refused at the scene check, by JSON path
/// (it passed, then failed as "invalid sun: radiance [inf, inf, inf]").
#[test]
fn a_radiance_beyond_f32_is_refused_by_path() {
    let e = refusal(&with(r#""sun": {"radiance": 1e308}"#));
    assert!(e.starts_with("sun.radiance: "), "{e}");
    assert!(e.contains("beyond f32"), "{e}");
    let e = refusal(&with(r#""env_radiance": 1e39"#));
    assert!(e.starts_with("env_radiance: "), "{e}");
}
