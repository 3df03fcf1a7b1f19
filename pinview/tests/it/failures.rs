//! Failure lines: one line on stderr naming the problem (and the file), exit 1 (2 for usage),
//! never a panic.

use std::process::Output;

use crate::support::*;

pub fn one_line(out: &Output, code: i32, needle: &str) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(code), "exit code; stderr: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "one line expected: {err}");
    assert!(lines[0].starts_with("pinview: error: "), "{err}");
    assert!(lines[0].contains(needle), "'{needle}' missing from: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(out.stdout.is_empty(), "nothing on stdout on failure");
}

#[test]
fn failures_are_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let Some(display) = display() else { return };
    let d = Some(&display);
    let pins = bake(dir.path(), "c.pin", 1.0, None);
    let missing = dir.path().join("missing.pin");
    one_line(
        &pinview(d, &[s(&missing), "--frames", "1"]),
        1,
        "missing.pin",
    );
    let garbage = dir.path().join("garbage.pin");
    std::fs::write(&garbage, b"not a pin file at all, just some bytes").unwrap();
    one_line(
        &pinview(d, &[s(&garbage), "--frames", "1"]),
        1,
        "garbage.pin",
    );
    // A pin file without density cannot be tracked.
    one_line(
        &pinview(d, &[s(&pins), "--estimator", "ratio", "--frames", "1"]),
        1,
        "no embedded density",
    );
    // Nor compared with a tracker.
    one_line(
        &pinview(d, &[s(&pins), "--compare", "pinms", "--frames", "1"]),
        1,
        "no embedded density",
    );
    // A re-bake is of a volume.
    one_line(
        &pinview(d, &[s(&pins), "--rebake-scale", "2", "--frames", "1"]),
        2,
        "--rebake-scale",
    );
    // So is the viewer's own bake.
    one_line(
        &pinview(d, &[s(&pins), "--pin-cells", "6", "--frames", "1"]),
        2,
        "--pin-cells",
    );
    // A frame pattern that matches nothing.
    let pattern = dir.path().join("sim.####.pin");
    one_line(
        &pinview(d, &[s(&pattern), "--frames", "1"]),
        1,
        "no frame matches",
    );
    // Usage errors: exit 2.
    one_line(&pinview(d, &[s(&pins), "--frames", "0"]), 2, "--frames");
    one_line(
        &pinview(d, &[s(&pins), "--albedo", "2", "--frames", "1"]),
        2,
        "--albedo",
    );
    one_line(
        &pinview(d, &[s(&pins), "--screenshot", "x.png"]),
        2,
        "--frames",
    );
    one_line(
        &pinview(d, &[s(&pins), "--estimator", "pinurm", "--frames", "1"]),
        2,
        "unknown estimator 'pinurm'",
    );
    one_line(
        &pinview(d, &[s(&pins), "--density-scale", "2", "--frames", "1"]),
        2,
        "--density-scale",
    );
    // An output that is an input is refused before any window opens.
    one_line(
        &pinview(d, &[s(&pins), "--frames", "1", "--save", s(&pins)]),
        1,
        "c.pin",
    );
}

#[test]
fn no_display_is_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "c.pin", 1.0, None);
    let out = pinview(None, &[s(&pins), "--frames", "1"]);
    one_line(&out, 1, "no display");
}

#[test]
fn render_flags_follow_the_scene_ranges() {
    // The bounds and messages of `pinrender render` and of the scene file
    // (`pin_scene::ranges`); usage errors come before any window, so no display is needed.
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "c.pin", 1.0, None);
    let cases = [
        // A squared length that overflows f32: its unit vector would round to zero.
        (
            "--sun-dir",
            "1e30,0,0",
            pin_scene::ranges::direction([1e30, 0.0, 0.0]),
        ),
        ("--sun-dir", "0,0,0", pin_scene::ranges::direction([0.0; 3])),
        (
            "--fov",
            "180",
            pin_scene::ranges::fov(180.0).map(|_| [0.0; 3]),
        ),
        ("--g", "-1", pin_scene::ranges::hg_g(-1.0).map(|_| [0.0; 3])),
        (
            "--albedo",
            "1.5",
            pin_scene::ranges::albedo(1.5).map(|_| [0.0; 3]),
        ),
    ];
    for (flag, value, rule) in cases {
        let message = rule.expect_err(value);
        let out = pinview(None, &[s(&pins), flag, value, "--frames", "1"]);
        one_line(&out, 2, flag);
        one_line(&out, 2, &message);
    }
}

/// Without --frames, a damaged pin file given at launch shows its line in the failure
/// window, which stays until closed, as a refused scene does, rather than the process ending
/// at once with nothing on screen.
#[test]
fn interactive_a_damaged_file_keeps_its_window_open() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, None);
    let bytes = std::fs::read(&pins).unwrap();
    let cut = dir.path().join("cut.pin");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let Some(display) = display() else { return };
    let mut child = viewer_command(Some(&display))
        .arg(s(&cut))
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_secs(4));
    let exited = child.try_wait().unwrap();
    let _ = child.kill();
    let _ = child.wait();
    assert_eq!(exited, None, "pinview ended instead of showing the failure");
}

/// Two outputs of one run may not name one file: one would be written over the other. Refused
/// before the window opens (so no display is needed here), whatever was already there.
#[test]
fn two_outputs_may_not_name_one_file() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "c.pin", 1.0, None);
    let x = dir.path().join("x.png");
    std::fs::write(&x, b"old").unwrap();
    let link = dir.path().join("link.png");
    std::os::unix::fs::symlink(&x, &link).unwrap();
    for (first, second) in [
        ("--screenshot", "--save"),
        ("--screenshot", "--window-screenshot"),
    ] {
        for other in [&x, &link] {
            let out = pinview(
                None,
                &[s(&pins), "--frames", "1", first, s(&x), second, s(other)],
            );
            one_line(&out, 1, "two outputs of one command");
            assert_eq!(std::fs::read(&x).unwrap(), b"old");
        }
    }
}
