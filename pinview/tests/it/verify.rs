//! A pin file whose pins section was damaged after the bake (one flipped bit in its payload,
//! its header and lengths intact) still renders, and the background check says so in the
//! window and in the JSON line's `notes`, alone or as a scene's asset; a sound file has no
//! such note (here as a scene's asset; alone in `toasts`' run).

use std::path::Path;

use crate::support::*;

pub const WARNING: &str = "fails its check";

fn run(display: &Display, pin: &Path) -> serde_json::Value {
    let mut args = vec![s(pin), "--estimator", "pins", "--frames", "2", "--json"];
    args.extend_from_slice(&VIEW);
    let out = pinview(Some(display), &args);
    ok(&out, "pinview");
    let j = json(&out);
    assert_eq!(j["passes"], 2, "{j}");
    j
}

#[test]
fn a_damaged_pins_section_renders_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let good = bake(dir.path(), "good.pin", 1.0, None);
    let bytes = std::fs::read(&good).unwrap();
    let (offset, length) = {
        let file = pin_format::PinFile::parse(&bytes).unwrap();
        file.sections()
            .iter()
            .find(|s| s.kind == pin_format::SectionKind::Pins as u32)
            .map(|s| (s.offset, s.length))
            .expect("a pins section")
    };
    let mut damaged = bytes.clone();
    damaged[(offset + length / 2) as usize] ^= 1;
    let bad = dir.path().join("bad.pin");
    std::fs::write(&bad, &damaged).unwrap();
    let Some(display) = display() else { return };
    let j = run(&display, &bad);
    let notes = j["notes"].as_array().unwrap();
    assert!(
        notes
            .iter()
            .any(|n| n.as_str().unwrap().contains(WARNING)
                && n.as_str().unwrap().contains("bad.pin")),
        "{j}"
    );
    // A sound pin file alone has no such note: `toasts`' run checks it.
    // A scene whose asset is the damaged file: the same warning.
    let scene = write_file(
        dir.path(),
        "two.json",
        r#"{"assets": {"a": {"pins": "good.pin"}, "b": {"pins": "bad.pin"}},
            "instances": [{"asset": "a"}, {"asset": "b", "transform": {"translate": [1.2, 0, 0]}}]}"#,
    );
    let j = run(&display, &scene);
    assert_eq!(j["instances"], 2, "{j}");
    let notes = j["notes"].to_string();
    assert!(notes.contains(WARNING) && notes.contains("bad.pin"), "{j}");
    assert!(!notes.contains("good.pin"), "{j}");
}
