//! Status and save messages: toasts over the image, each kept for the JSON line's
//! `messages`; a file written is named by its absolute path, whatever the working directory;
//! a sound file gets no warning from the background check.

use crate::support::*;

#[test]
fn messages_name_what_was_written_by_its_absolute_path() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, None);
    let Some(display) = display() else { return };
    let mut args = vec![s(&pins)];
    args.extend_from_slice(&VIEW);
    args.extend_from_slice(&[
        "--estimator",
        "pins",
        "--frames",
        "1",
        "--save",
        "view.exr",
        "--screenshot",
        "view.png",
        "--json",
    ]);
    let out = viewer_command(Some(&display))
        .args(&args)
        .current_dir(dir.path())
        .output()
        .expect("running pinview");
    ok(&out, "pinview with relative outputs");
    let j = json(&out);
    let messages: Vec<&str> = j["messages"]
        .as_array()
        .expect("messages")
        .iter()
        .filter_map(|m| m.as_str())
        .collect();
    let root = std::fs::canonicalize(dir.path()).unwrap();
    for name in ["view.exr", "view.png"] {
        let want = format!("wrote {}", root.join(name).display());
        let plain = format!("wrote {}", dir.path().join(name).display());
        assert!(
            messages.iter().any(|m| *m == want || *m == plain),
            "no message names {name}'s absolute path: {j}"
        );
        assert!(dir.path().join(name).is_file());
    }
    // The background check of a sound file warns of nothing (`verify`).
    assert!(
        !j["notes"].to_string().contains(crate::verify::WARNING),
        "{j}"
    );
}
