//! The sun gizmo answers a drag: under Xvfb, the sun's point is found on the window (its
//! colour, in the controls panel), dragged left and down with the XTEST extension, and the
//! view's sun direction (the JSON line's `command`) turns that way.

use std::process::Stdio;
use std::time::{Duration, Instant};

use x11rb::connection::Connection;
use x11rb::protocol::xproto::{self, ConnectionExt as _, ImageFormat};
use x11rb::protocol::xtest::ConnectionExt as _;
use x11rb::rust_connection::RustConnection;

use crate::support::*;

/// The gizmo's sun point colour (`src/sun_gizmo.rs`).
const SUN: [u8; 3] = [255, 210, 60];
/// The controls panel's width in pixels (the gizmo is searched there only, where the box's
/// sun arrow of the same colour is never drawn).
const PANEL: u16 = 340;

/// The centre of the pixels of the sun's colour in the panel, `(x, y)` on the root window.
fn find_sun(conn: &RustConnection, root: u32) -> Option<(i16, i16)> {
    let height = 1200;
    let image = conn
        .get_image(ImageFormat::Z_PIXMAP, root, 0, 0, PANEL, height, !0)
        .ok()?
        .reply()
        .ok()?;
    // 32 bits a pixel on the 24-bit screen, blue first.
    let (mut sx, mut sy, mut n) = (0u64, 0u64, 0u64);
    for (k, px) in image.data.chunks_exact(4).enumerate() {
        let rgb = [px[2], px[1], px[0]];
        if rgb.iter().zip(SUN).all(|(&a, b)| a.abs_diff(b) <= 3) {
            sx += (k % PANEL as usize) as u64;
            sy += (k / PANEL as usize) as u64;
            n += 1;
        }
    }
    (n >= 20).then(|| ((sx / n) as i16, (sy / n) as i16))
}

fn fake(conn: &RustConnection, root: u32, kind: u8, detail: u8, (x, y): (i16, i16)) {
    conn.xtest_fake_input(kind, detail, 0, root, x, y, 0)
        .unwrap();
    conn.flush().unwrap();
    std::thread::sleep(Duration::from_millis(120));
}

/// The `--sun-dir` of a JSON line's `command`, normalised.
fn sun_dir(j: &serde_json::Value) -> [f64; 3] {
    let command = j["command"].as_str().unwrap();
    let words: Vec<&str> = command.split_whitespace().collect();
    let at = words.iter().position(|w| *w == "--sun-dir").unwrap();
    let v: Vec<f64> = words[at + 1]
        .split(',')
        .map(|x| x.parse().unwrap())
        .collect();
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    [v[0] / n, v[1] / n, v[2] / n]
}

#[test]
fn dragging_the_sun_gizmo_turns_the_sun() {
    let dir = tempfile::tempdir().unwrap();
    let pin = bake(dir.path(), "c.pin", 1.0, None);
    // An event late enough to keep the window up while the drag is made.
    let script = write_file(
        dir.path(),
        "events.json",
        r#"[{"at_s": 6, "action": "exposure", "stops": 0}]"#,
    );
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
        "--sun-dir",
        "0.3,1,0.2",
    ];
    args.extend_from_slice(&VIEW);
    let child = viewer_command(Some(&display))
        .args(&args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let (conn, screen) = x11rb::connect(Some(&display.name)).unwrap();
    let root = conn.setup().roots[screen].root;
    let start = Instant::now();
    let at = loop {
        if let Some(at) = find_sun(&conn, root) {
            break Some(at);
        }
        if start.elapsed() > Duration::from_secs(60) {
            break None;
        }
        std::thread::sleep(Duration::from_millis(250));
    };
    let at = at.expect("the sun gizmo's point was not seen in the controls within 60 s");
    // Let the panel settle (the first frames lay it out twice), then drag.
    std::thread::sleep(Duration::from_millis(500));
    let at = find_sun(&conn, root).unwrap_or(at);
    fake(&conn, root, xproto::MOTION_NOTIFY_EVENT, 0, at);
    fake(&conn, root, xproto::BUTTON_PRESS_EVENT, 1, at);
    for k in 1..=6 {
        fake(
            &conn,
            root,
            xproto::MOTION_NOTIFY_EVENT,
            0,
            (at.0 - 5 * k, at.1 + 4 * k),
        );
    }
    fake(
        &conn,
        root,
        xproto::BUTTON_RELEASE_EVENT,
        1,
        (at.0 - 30, at.1 + 24),
    );
    let out = child.wait_with_output().unwrap();
    ok(&out, "pinview");
    let j = json(&out);
    let d = sun_dir(&j);
    let n = (0.09f64 + 1.0 + 0.04).sqrt();
    let before = [0.3 / n, 1.0 / n, 0.2 / n];
    // The camera looks along -z with +x right and +y up: left and down in the gizmo.
    assert!(d[0] < before[0] - 0.1, "{d:?} from {before:?}: {j}");
    assert!(d[1] < before[1] - 0.05, "{d:?} from {before:?}: {j}");
}
