//! The viewport: without `--width`/`--height` the image fills the window's central panel (in
//! physical pixels) and is still the batch render's bits at that size; a `resize` event
//! fixes the size it asks for.

use std::time::Duration;

use crate::support::*;

const LIMIT: Duration = Duration::from_secs(240);

#[test]
fn without_a_size_the_image_fills_the_panel_and_keeps_the_batch_bits() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, None);
    let Some(display) = display() else { return };
    let exr = dir.path().join("view.exr");
    let args = [
        s(&pins),
        "--camera-origin",
        "0.5,0.6,2.6",
        "--camera-target",
        "0.5,0.5,0.5",
        "--estimator",
        "pins",
        "--frames",
        "1",
        "--save",
        s(&exr),
        "--json",
    ];
    let out = pinview_within(Some(&display), &args, LIMIT);
    ok(&out, "pinview without a size");
    let j = json(&out);
    let v = &j["viewport"];
    assert_eq!(v["follow"], true, "{j}");
    let ppp = v["pixels_per_point"].as_f64().unwrap();
    let panel = [
        v["panel_points"][0].as_f64().unwrap(),
        v["panel_points"][1].as_f64().unwrap(),
    ];
    let (w, h) = (j["width"].as_u64().unwrap(), j["height"].as_u64().unwrap());
    assert_eq!(
        (w, h),
        (
            (panel[0] * ppp).floor() as u64,
            (panel[1] * ppp).floor() as u64
        ),
        "the image is not the panel's size: {j}"
    );
    assert!(
        h > 512,
        "the default window's panel is taller than 512: {j}"
    );
    let command = j["command"].as_str().unwrap();
    assert!(
        command.contains(&format!("--width {w} --height {h} ")),
        "{command}"
    );
    let batch = render_command(command, &dir.path().join("batch.exr"));
    assert!(
        batch == exr_bits(&exr),
        "not the batch render's bits at {w} x {h}"
    );
}

#[test]
fn a_resize_event_fixes_the_size_it_asks_for() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, None);
    let events = write_file(
        dir.path(),
        "events.json",
        r#"[{"at_s": 0.1, "action": "resize", "width": 40, "height": 32}]"#,
    );
    let Some(display) = display() else { return };
    let args = [
        s(&pins),
        "--estimator",
        "pins",
        "--input-script",
        s(&events),
        "--frames",
        "1",
        "--json",
    ];
    let out = pinview_within(Some(&display), &args, LIMIT);
    ok(&out, "pinview resize");
    let j = json(&out);
    assert_eq!(
        (j["width"].as_u64(), j["height"].as_u64()),
        (Some(40), Some(32)),
        "{j}"
    );
    assert_eq!(j["viewport"]["follow"], false, "{j}");
}

/// Following the window, every size the image takes fits `--max-memory` as the starting
/// size must, beside the compare side's image and the medium's read: a budget the default
/// panel's two images exceed (and smaller ones fit) gives the largest image of the panel's
/// aspect within it, with a note, and the run succeeds.
#[test]
fn a_followed_size_is_reduced_to_fit_the_memory_budget() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, Some(12));
    let Some(display) = display() else { return };
    // 56 MiB: two starting 512 x 512 images (48 MiB at 96 bytes a pixel) and the file fit,
    // two of the default panel's (516 x 684 points at 1 pixel a point under Xvfb: 64.6 MiB)
    // do not.
    let limit: u64 = 56 << 20;
    let args = [
        s(&pins),
        "--estimator",
        "pins",
        "--compare",
        "pins",
        "--max-memory",
        "56M",
        "--frames",
        "1",
        "--json",
    ];
    let out = pinview_within(Some(&display), &args, LIMIT);
    ok(&out, "pinview within --max-memory 56M");
    let j = json(&out);
    let v = &j["viewport"];
    assert_eq!(v["follow"], true, "{j}");
    // The main view and the compare side; the pin file's read as `pinrender render`
    // charges it (3 bytes a byte of the file).
    assert_eq!(v["images"], 2, "{j}");
    let reserved = v["reserved_bytes"].as_u64().expect("reserved_bytes");
    assert_eq!(reserved, 3 * std::fs::metadata(&pins).unwrap().len(), "{j}");
    let (w, h) = (j["width"].as_u64().unwrap(), j["height"].as_u64().unwrap());
    let bytes = |w: u64, h: u64| 2 * w * h * pinrender::front::flags::BYTES_PER_PIXEL + reserved;
    assert!(bytes(w, h) <= limit, "{w} x {h} exceeds the budget: {j}");
    let full = [
        v["reduced_from"][0].as_u64().expect("reduced_from"),
        v["reduced_from"][1].as_u64().expect("reduced_from"),
    ];
    assert!(bytes(full[0], full[1]) > limit, "{j}");
    // The panel's aspect, and nearly all of the budget.
    let aspect = |a: u64, b: u64| a as f64 / b as f64;
    assert!(
        (aspect(w, h) - aspect(full[0], full[1])).abs() < 0.01,
        "{w} x {h} is not the panel's {full:?} aspect"
    );
    assert!(bytes(w + 1, h + 1) > limit, "{w} x {h} is not the largest");
    let notes = j["notes"].to_string();
    assert!(
        notes.contains("--max-memory")
            && notes.contains(&format!("{w} x {h}"))
            && notes.contains("2 images"),
        "{j}"
    );
    let command = j["command"].as_str().unwrap();
    assert!(
        command.contains(&format!("--width {w} --height {h} ")),
        "{command}"
    );
}

/// A scripted `resize` fits `--max-memory` too: one past it is refused before anything is
/// shown, with one line naming the events file, the event and the size (exit 1).
#[test]
fn a_resize_event_past_the_memory_budget_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, None);
    let events = write_file(
        dir.path(),
        "events.json",
        r#"[{"at_s": 0.1, "action": "resize", "width": 2048, "height": 2048}]"#,
    );
    let Some(display) = display() else { return };
    let args = [
        s(&pins),
        "--estimator",
        "pins",
        "--width",
        "32",
        "--height",
        "32",
        "--max-memory",
        "64M",
        "--input-script",
        s(&events),
        "--frames",
        "1",
        "--json",
    ];
    let out = pinview_within(Some(&display), &args, LIMIT);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("events.json: event 1") && err.contains("2048x2048"),
        "{err}"
    );
}

/// The starting size counts every side rendering at it: one image fits the budget, the
/// compare side's second does not, and the viewer refuses in one line before it opens
/// anything (exit 1).
#[test]
fn the_starting_size_counts_the_compare_sides_image() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, Some(12));
    // 512 x 512 at 96 bytes a pixel: 24 MiB an image.
    let base = [
        s(&pins),
        "--width",
        "512",
        "--height",
        "512",
        "--max-memory",
        "40M",
    ];
    let with_compare = [&base[..], &["--compare", "pins", "--frames", "1"]].concat();
    let out = pinview(None, &with_compare);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("2 images of 512x512"), "{err}");
}
