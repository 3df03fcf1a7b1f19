//! "copy command" reaches the system clipboard: a scripted copy in the window under Xvfb,
//! read back from the X server's CLIPBOARD selection while the window still serves it, is
//! the line printed on stdout; and the GPU stack's libraries print nothing about
//! `XDG_RUNTIME_DIR` on the way. The same run is the scripted input's end by time.

use std::process::Stdio;
use std::time::{Duration, Instant};

use crate::support::*;

/// The text the owner of `display`'s CLIPBOARD selection gives as UTF-8, or `None` where no
/// one owns it (or it does not answer within a second).
fn read_clipboard(display: &str) -> Option<String> {
    use x11rb::connection::Connection;
    use x11rb::protocol::Event;
    use x11rb::protocol::xproto::{AtomEnum, ConnectionExt as _, CreateWindowAux, WindowClass};
    let (conn, screen) = x11rb::connect(Some(display)).ok()?;
    let root = conn.setup().roots[screen].root;
    let win = conn.generate_id().ok()?;
    conn.create_window(
        x11rb::COPY_DEPTH_FROM_PARENT,
        win,
        root,
        0,
        0,
        1,
        1,
        0,
        WindowClass::INPUT_OUTPUT,
        x11rb::COPY_FROM_PARENT,
        &CreateWindowAux::new(),
    )
    .ok()?;
    let atom = |name: &str| {
        conn.intern_atom(false, name.as_bytes())
            .ok()?
            .reply()
            .ok()
            .map(|r| r.atom)
    };
    let (clipboard, utf8, property) = (
        atom("CLIPBOARD")?,
        atom("UTF8_STRING")?,
        atom("PINVIEW_TEST_CLIPBOARD")?,
    );
    conn.convert_selection(win, clipboard, utf8, property, x11rb::CURRENT_TIME)
        .ok()?;
    conn.flush().ok()?;
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(1) {
        match conn.poll_for_event().ok()? {
            Some(Event::SelectionNotify(e)) => {
                if e.property == x11rb::NONE {
                    return None;
                }
                let reply = conn
                    .get_property(true, win, property, AtomEnum::ANY, 0, 1 << 20)
                    .ok()?
                    .reply()
                    .ok()?;
                return String::from_utf8(reply.value).ok();
            }
            Some(_) => {}
            None => std::thread::sleep(Duration::from_millis(10)),
        }
    }
    None
}

/// One window run checks two things: "copy command" reaches the X clipboard (read back
/// while the window serves it), and a scripted run that cannot reach its passes
/// (`--frames` 2^32 - 1) ends 10 s after its last event, which keeps the window up for the
/// read.
#[test]
fn copy_command_reaches_the_x_clipboard_and_a_run_ends_10_s_after_its_last_event() {
    let dir = tempfile::tempdir().unwrap();
    let pin = bake(dir.path(), "c.pin", 1.0, None);
    let script = write_file(
        dir.path(),
        "events.json",
        r#"[{"at_s": 0, "action": "copy_command"},
            {"at_s": 0.2, "action": "exposure", "stops": -1}]"#,
    );
    let Some(display) = display() else { return };
    let mut args = vec![
        s(&pin),
        "--estimator",
        "pins",
        "--input-script",
        s(&script),
        "--frames",
        "4294967295",
        "--json",
    ];
    args.extend_from_slice(&VIEW);
    // Without XDG_RUNTIME_DIR: the viewer makes a private one before the GPU stack and the
    // clipboard look for a Wayland display.
    let t = Instant::now();
    let mut child = viewer_command(Some(&display))
        .args(&args)
        .env_remove("XDG_RUNTIME_DIR")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut copied = None;
    while child.try_wait().unwrap().is_none() {
        assert!(
            t.elapsed() < Duration::from_secs(240),
            "pinview did not end"
        );
        if let Some(text) = read_clipboard(&display.name) {
            copied = Some(text);
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    let took = t.elapsed().as_secs_f64();
    let out = child.wait_with_output().unwrap();
    ok(&out, "pinview --input-script copy_command, ended by time");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let printed = stdout
        .lines()
        .find(|l| l.starts_with("pinrender render "))
        .unwrap_or_else(|| panic!("no command on stdout: {stdout}"));
    assert_eq!(
        copied.as_deref(),
        Some(printed),
        "the X clipboard does not hold the command printed"
    );
    assert!(printed.contains(s(&pin)), "{printed}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("XDG_RUNTIME_DIR"), "{err}");
    let j = json(&out);
    assert_eq!(j["events"][0]["action"], "copy_command", "{j}");
    // The end: 10 s after the last event, not N passes after it. `at_s` counts from the first
    // image shown, at `first_image_s` from the process's start (after the spawn).
    assert_eq!(j["script_end"], "timeout", "{j}");
    let first = j["first_image_s"].as_f64().unwrap_or(f64::INFINITY);
    assert!(
        took >= first + 10.2,
        "ended {took} s after the start, before the last event's at_s + 10 s from the first \
         image at {first} s: {j}"
    );
    let e = &j["events"][1];
    assert_eq!(e["action"], "exposure", "{j}");
    assert!(e["first_pixels_ms"].as_f64().is_some(), "{j}");
}
