//! docs/scene.schema.json and the reader accept the same keys.

use serde_json::Value;

use crate::{folder, refusal, write};

fn schema() -> Value {
    let p = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/scene.schema.json");
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

fn keys(v: &Value) -> Vec<String> {
    let mut k: Vec<String> = v["properties"]
        .as_object()
        .unwrap()
        .keys()
        .cloned()
        .collect();
    k.sort();
    k
}

/// Each object's keys in the schema, as the reader's structs spell them.
#[test]
fn the_schema_lists_the_readers_keys() {
    let s = schema();
    let d = &s["$defs"];
    let transform = &d["instance"]["properties"]["transform"]["oneOf"][1];
    let expect: [(&Value, &[&str]); 6] = [
        (
            &s,
            &[
                "albedo",
                "assets",
                "camera",
                "env_radiance",
                "g",
                "instances",
                "max_bounces",
                "sun",
            ],
        ),
        (&d["asset"], &["density_scale", "grid", "pins", "volume"]),
        (&d["instance"], &["asset", "transform"]),
        (&s["properties"]["camera"], &["fov", "origin", "target"]),
        (&s["properties"]["sun"], &["direction", "radiance"]),
        (transform, &["rotate_deg", "scale", "translate"]),
    ];
    for (obj, want) in expect {
        assert_eq!(keys(obj), want);
        assert_eq!(obj["additionalProperties"], Value::Bool(false));
    }
}

/// A document that uses every key of the schema loads; one key more is refused where the
/// schema refuses it too.
#[test]
fn every_schema_key_is_accepted_and_no_other() {
    let full = r#"{
      "assets": {"a": {"volume": "a.vdb", "pins": "a.pin", "density_scale": 1, "grid": "density"}},
      "instances": [
        {"asset": "a", "transform": [1,0,0,0, 0,1,0,0, 0,0,1,0]},
        {"asset": "a", "transform": {"translate": [1,0,0], "rotate_deg": [0,0,45], "scale": [1,1,2]}}
      ],
      "camera": {"origin": [0,0,-4], "target": [0,0,0], "fov": 35},
      "sun": {"direction": [0,1,0], "radiance": 3},
      "env_radiance": 0.3, "albedo": 0.9, "g": 0.2, "max_bounces": 8
    }"#;
    let dir = folder();
    pin_scene::load(&write(dir.path(), full), None).unwrap();
    for (place, extra) in [
        (
            r#""env_radiance": 0.3,"#,
            r#""env_radiance": 0.3, "exposure": 1,"#,
        ),
        (r#""fov": 35"#, r#""fov": 35, "up": [0,1,0]"#),
        (r#""radiance": 3"#, r#""radiance": 3, "size": 1"#),
        (r#""grid": "density""#, r#""grid": "density", "frame": 1"#),
        (
            r#""scale": [1,1,2]"#,
            r#""scale": [1,1,2], "pivot": [0,0,0]"#,
        ),
        (
            r#""asset": "a", "transform": [1"#,
            r#""asset": "a", "name": "x", "transform": [1"#,
        ),
    ] {
        let text = full.replacen(place, extra, 1);
        assert_ne!(text, full);
        let e = refusal(&text);
        assert!(e.contains("unknown"), "{extra}: {e}");
    }
}
