//! Pins made visible: the entry `--pin-at` reports is the one the pixel's ray enters first,
//! read from the file; the overlays change the window's image and nothing else; a held entry
//! stays held when the camera orbits. One test, so that each window run serves every check
//! it can (a run with `--pin-at` is both an overlay and an entry to check).

use std::time::Duration;

use crate::support::*;

/// The world ray of pixel `(x, y)`'s centre with the camera at `origin` looking at `target`
/// ([`VIEW`]'s size and field of view), as `pinrender` builds it.
fn pixel_ray(origin: [f32; 3], target: [f32; 3], x: f32, y: f32) -> ([f64; 3], [f64; 3]) {
    let camera = pinrender::render::Camera {
        origin,
        target,
        vfov_deg: 40.0,
        width: 48,
        height: 40,
    };
    let (o, d) = camera.frame().unwrap().ray(x + 0.5, y + 0.5);
    (o.to_array().map(f64::from), d.to_array().map(f64::from))
}

/// [`VIEW`]'s camera.
const ORIGIN: [f32; 3] = [0.5, 0.6, 2.6];
const TARGET: [f32; 3] = [0.5, 0.5, 0.5];

/// Checks the JSON line's `pin` for pixel `(x, y)` of the camera `(origin, target)`: the cell
/// the pixel's ray enters first, found here by a slab test on the box, the format's own
/// direction binning, and the entries `PinGrid::entry` reads there (`null` for a pixel whose
/// ray misses). Returns whether the ray hits the box.
fn check_pin(
    grid: &pinrt::PinGrid,
    j: &serde_json::Value,
    (origin, target): ([f32; 3], [f32; 3]),
    (x, y): (u32, u32),
) -> bool {
    let desc = *grid.desc();
    let at = format!("{x},{y}");
    let (o, d) = pixel_ray(origin, target, x as f32, y as f32);
    let ext: Vec<f64> = (0..3).map(|a| desc.box_max[a] - desc.box_min[a]).collect();
    let ou: Vec<f64> = (0..3).map(|a| (o[a] - desc.box_min[a]) / ext[a]).collect();
    let du: Vec<f64> = (0..3).map(|a| d[a] / ext[a]).collect();
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    for a in 0..3 {
        let (p, q) = ((0.0 - ou[a]) / du[a], (1.0 - ou[a]) / du[a]);
        t0 = t0.max(p.min(q));
        t1 = t1.min(p.max(q));
    }
    if !(t0.max(0.0) < t1) {
        assert!(j["pin"].is_null(), "pixel {at} misses the box: {j}");
        return false;
    }
    let t = t0.max(0.0);
    let dims = grid.shape().dims;
    let cell: Vec<u32> = (0..3)
        .map(|a| (((ou[a] + du[a] * t) * f64::from(dims[a])) as u32).min(dims[a] - 1))
        .collect();
    let p = &j["pin"];
    let got: Vec<u32> = p["cell"]
        .as_array()
        .unwrap_or_else(|| panic!("pixel {at}: no pin: {j}"))
        .iter()
        .map(|v| v.as_u64().unwrap() as u32)
        .collect();
    assert_eq!(got, cell, "pixel {at}: {j}");
    let reversed = du[2] < 0.0;
    let dl: Vec<f32> = du
        .iter()
        .map(|&v| (if reversed { -v } else { v }) as f32)
        .collect();
    let direction = grid.shape().directions.index_of([dl[0], dl[1], dl[2]]);
    assert_eq!(p["direction"].as_u64(), Some(u64::from(direction)), "{j}");
    assert_eq!(p["reversed"].as_bool(), Some(reversed), "{j}");
    let stored = p["pins"].as_array().unwrap();
    assert_eq!(stored.len() as u32, grid.shape().pins_per_entry, "{j}");
    let cell = [cell[0], cell[1], cell[2]];
    for (k, e) in stored.iter().enumerate() {
        let want = grid.entry(cell, direction, k as u32);
        assert_eq!(
            e["mask"].as_u64(),
            Some(u64::from(want.mask)),
            "pin {k}: {j}"
        );
        assert_eq!(
            e["t_min"].as_f64(),
            Some(f64::from(want.t_min)),
            "pin {k}: {j}"
        );
    }
    true
}

/// The window's image region (`window_image_rect`) of a `--window-screenshot` run, the
/// render's screenshot and the JSON line.
fn window_image(
    display: &Display,
    dir: &std::path::Path,
    pins: &str,
    tag: &str,
    extra: &[&str],
) -> (Vec<u8>, Vec<u8>, serde_json::Value) {
    let win = dir.join(format!("{tag}-window.png"));
    let shot = dir.join(format!("{tag}-render.png"));
    let mut args = vec![pins];
    args.extend_from_slice(&VIEW);
    args.extend_from_slice(extra);
    args.extend_from_slice(&[
        "--frames",
        "1",
        "--screenshot",
        s(&shot),
        "--window-screenshot",
        s(&win),
        "--json",
    ]);
    let out = pinview(Some(display), &args);
    ok(&out, "pinview --window-screenshot");
    let j = json(&out);
    let r: Vec<usize> = j["window_image_rect"]
        .as_array()
        .unwrap_or_else(|| panic!("no window_image_rect: {j}"))
        .iter()
        .map(|v| v.as_f64().unwrap().round() as usize)
        .collect();
    let (w, _, rgb) = png_rgb(&win);
    let crop = (r[1]..r[3])
        .flat_map(|y| {
            let row = y * w as usize * 3;
            rgb[row + r[0] * 3..row + r[2] * 3].to_vec()
        })
        .collect();
    (crop, png_rgb(&shot).2, j)
}

/// `--pin-at` reports the entry the pixel's ray enters first (three pixels that hit the box,
/// one of them from an orbited camera, and one that misses); the grid and pins overlays
/// change the window's image and not the render; a held entry stays held when the camera
/// orbits (scripted input), while the same pixel under the orbited camera reads another.
#[test]
fn pins_made_visible() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "c.pin", 1.0, None);
    let grid = pinrt::PinGrid::open(&pins).unwrap();
    assert_eq!(
        grid.desc().local_to_world,
        [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    );
    let Some(display) = display() else { return };
    let d = &display;
    let p = s(&pins);
    let view = (ORIGIN, TARGET);
    let (base, base_render, _) = window_image(d, dir.path(), p, "base", &[]);
    let (again, _, _) = window_image(d, dir.path(), p, "again", &[]);
    assert!(
        base == again,
        "the same view must show the same window image"
    );
    // The grid, with a held pixel whose ray misses the box (nothing held, nothing drawn).
    let (grid_image, grid_render, j) = window_image(
        d,
        dir.path(),
        p,
        "grid",
        &["--grid-overlay", "--pin-at", "0,0"],
    );
    assert!(!check_pin(&grid, &j, view, (0, 0)));
    assert!(
        grid_image != base,
        "the grid overlay left the window image unchanged"
    );
    let (pin_image, pin_render, still) =
        window_image(d, dir.path(), p, "pin", &["--pin-at", "24,20"]);
    assert!(check_pin(&grid, &still, view, (24, 20)));
    assert!(
        pin_image != base,
        "the pins overlay left the window image unchanged"
    );
    assert!(
        base_render == grid_render && base_render == pin_render,
        "an overlay changed the render's screenshot"
    );
    let run = |extra: &[&str]| {
        let mut args = vec![p];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--frames", "1", "--json"]);
        let out = pinview_within(Some(d), &args, Duration::from_secs(180));
        ok(&out, "pinview --pin-at");
        json(&out)
    };
    let mut args = VIEW.to_vec();
    args.extend_from_slice(&["--pin-at", "20,14"]);
    assert!(check_pin(&grid, &run(&args), view, (20, 14)));
    // Held, then orbited: the entry picked at the start.
    let events = write_file(
        dir.path(),
        "orbit.json",
        r#"[{"at_s": 0, "action": "orbit", "dx_deg": 50, "dy_deg": 20}]"#,
    );
    let mut args = VIEW.to_vec();
    args.extend_from_slice(&["--pin-at", "24,20", "--input-script", s(&events)]);
    let moved = run(&args);
    assert_eq!(moved["events"][0]["action"], "orbit", "{moved}");
    assert_eq!(
        still["pin"], moved["pin"],
        "the held entry changed with the view"
    );
    // The orbit moved the camera: the same pixel now reads another entry, the one its ray
    // from there enters first.
    let command = moved["command"].as_str().unwrap().to_string();
    let words: Vec<&str> = command.split_whitespace().collect();
    let at = |flag: &str| words[words.iter().position(|w| *w == flag).unwrap() + 1];
    let point = |flag: &str| {
        let v: Vec<f32> = at(flag).split(',').map(|x| x.parse().unwrap()).collect();
        [v[0], v[1], v[2]]
    };
    let orbited = (point("--camera-origin"), point("--camera-target"));
    let fresh = run(&[
        "--camera-origin",
        at("--camera-origin"),
        "--camera-target",
        at("--camera-target"),
        "--width",
        "48",
        "--height",
        "40",
        "--pin-at",
        "24,20",
    ]);
    assert_ne!(
        fresh["pin"], still["pin"],
        "the orbit did not change the pixel's entry"
    );
    assert!(check_pin(&grid, &fresh, orbited, (24, 20)));
}
