//! "copy command" reaches the system clipboard: a scripted copy in the window under Xvfb,
//! read back from the X server's CLIPBOARD selection while the window still serves it, is
//! the line printed on stdout; and the GPU stack's libraries print nothing about
//! `XDG_RUNTIME_DIR` on the way.

use std::process::{Command, Stdio};
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

#[test]
fn copy_command_reaches_the_x_clipboard_and_stdout() {
    let dir = tempfile::tempdir().unwrap();
    let pin = bake(dir.path(), "c.pin", 1.0, None);
    let script = dir.path().join("events.json");
    // The copy at the first image; a later event keeps the window (the selection's owner)
    // up while the clipboard is read.
    std::fs::write(
        &script,
        r#"[{"at_s": 0, "action": "copy_command"},
            {"at_s": 6, "action": "exposure", "stops": 0}]"#,
    )
    .unwrap();
    let Some(display) = display() else { return };
    let mut args = vec![
        s(&pin),
        "--estimator",
        "pins",
        "--input-script",
        s(&script),
        "--frames",
        "1",
        "--json",
    ];
    args.extend_from_slice(&VIEW);
    // Without XDG_RUNTIME_DIR: the viewer makes a private one before the GPU stack and the
    // clipboard look for a Wayland display.
    let mut child = Command::new(PINVIEW)
        .args(&args)
        .env("DISPLAY", &display.name)
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("XDG_RUNTIME_DIR")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let mut copied = None;
    while child.try_wait().unwrap().is_none() {
        assert!(
            start.elapsed() < Duration::from_secs(240),
            "pinview did not end"
        );
        if let Some(text) = read_clipboard(&display.name) {
            copied = Some(text);
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    let out = child.wait_with_output().unwrap();
    ok(&out, "pinview --input-script copy_command");
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
    let j = json(&out);
    assert_eq!(j["events"][0]["action"], "copy_command", "{j}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("XDG_RUNTIME_DIR"), "{err}");
}
