//! What the viewer shares with `pinrender render`: one memory budget for everything the
//! command holds, pinbake's frame patterns, and pinbake's source dispatch (NanoVDB).

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::support::*;

/// The stderr line of a refused run, without the tool's name.
fn refusal(out: &std::process::Output, tool: &str) -> String {
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(1), "{tool}: {err}");
    assert_eq!(err.lines().count(), 1, "{tool}: {err}");
    err.trim_end()
        .strip_prefix(&format!("{tool}: "))
        .unwrap_or(&err)
        .to_string()
}

/// A raw file of 32^3 f32 voxels (128 KiB: its read is charged 1 MiB), dims in its name.
fn raw(dir: &Path) -> PathBuf {
    let values: Vec<u8> = (0..32 * 32 * 32)
        .flat_map(|i: u32| (1.0 + (i % 5) as f32).to_le_bytes())
        .collect();
    let p = dir.join("v_32x32x32_float32.raw");
    std::fs::write(&p, values).unwrap();
    p
}

/// The viewer's background bake is charged to `--max-memory` before anything is shown: a
/// budget the volume's read fits in but its bake does not is refused with one line (exit 1),
/// where a budget without the limit opens it. No display is needed: the file is opened
/// before any window or adapter.
#[test]
fn the_background_bake_is_refused_by_a_budget_the_read_fits_in() {
    let dir = tempfile::tempdir().unwrap();
    let v = raw(dir.path());
    let args = |budget: &'static str| {
        vec![
            s(&v).to_string(),
            "--width".into(),
            "8".into(),
            "--height".into(),
            "8".into(),
            "--max-memory".into(),
            budget.into(),
            "--offscreen".into(),
            "--frames".into(),
            "1".into(),
        ]
    };
    let run = |budget| {
        let a = args(budget);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        pinview(None, &a)
    };
    let line = refusal(&run("1536K"), "pinview");
    assert!(
        line.contains("baking") && line.contains("in memory"),
        "{line}"
    );
    // The read alone fits: 1 MiB of the 1.5 MiB.
    assert!(!line.contains("reading"), "{line}");
}

/// The viewer's image buffers are charged as `pinrender render` charges its images: a
/// 2048x2048 view under 64M is refused with `pinrender render`'s own line.
#[test]
fn image_buffers_are_charged_as_the_renderer_charges_them() {
    let dir = tempfile::tempdir().unwrap();
    let pin = bake(dir.path(), "c.pin", 1.0, None);
    let size = ["--width", "2048", "--height", "2048", "--max-memory", "64M"];
    let mut args = vec![s(&pin)];
    args.extend_from_slice(&size);
    args.extend_from_slice(&["--offscreen", "--frames", "1"]);
    let viewer = refusal(&pinview(None, &args), "pinview");
    let out = dir.path().join("r.exr");
    let mut args = vec!["--pins", s(&pin)];
    args.extend_from_slice(&size);
    args.extend_from_slice(&["--out", s(&out)]);
    let renderer = refusal(&pinrender_render(&args), "pinrender");
    assert_eq!(viewer, renderer);
    assert!(viewer.contains("2048x2048"), "{viewer}");
}

/// `pinview 'sim.%04d.pin'` plays the sequence `pinbake bake --frames` wrote under that
/// pattern, negative frames included, in frame order.
#[test]
fn a_printf_pattern_plays_what_pinbake_wrote() {
    let dir = tempfile::tempdir().unwrap();
    let pinbake = Path::new(PINVIEW).parent().unwrap().join("pinbake");
    assert!(pinbake.exists(), "build pinbake: {}", pinbake.display());
    let input = pinbake::frames::FramePattern::parse("w.%04d.raw")
        .unwrap()
        .unwrap();
    for frame in -1..=1i64 {
        let values: Vec<u8> = (0..8 * 8 * 8)
            .flat_map(|i: i64| (1.0 + ((i + frame) % 3) as f32).to_le_bytes())
            .collect();
        std::fs::write(dir.path().join(input.name(frame)), values).unwrap();
    }
    let out = Command::new(&pinbake)
        .current_dir(dir.path())
        .args(["bake", "w.%04d.raw", "--dims", "8,8,8", "--type", "f32"])
        .args(["--frames=-1-1", "--cells", "4", "-o", "sim.%04d.pin"])
        .output()
        .unwrap();
    ok(&out, "pinbake bake --frames");
    assert!(dir.path().join("sim.-0001.pin").exists());
    let Some(display) = display() else { return };
    let pattern = dir.path().join("sim.%04d.pin");
    let mut args = vec![s(&pattern)];
    args.extend_from_slice(&VIEW);
    args.extend_from_slice(&["--play", "--frame-passes", "1", "--frames", "3", "--json"]);
    let out = pinview(Some(&display), &args);
    ok(&out, "pinview");
    let j = json(&out);
    assert_eq!(j["frames_played"], serde_json::json!([-1, 0, 1]), "{j}");
    assert_eq!(j["frame"], 1, "{j}");
}

/// `pinview X.nvdb` opens the file through pinbake's dispatch: its image has the bits of the
/// `.vdb` it was converted from (`nanovdb_convert`, Debian's `libnanovdb-tools`, which
/// `scripts/deps.sh` installs; without it this test fails).
#[test]
fn a_nanovdb_file_views_as_the_vdb_it_was_converted_from() {
    let dir = tempfile::tempdir().unwrap();
    let vdb = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/openvdb_smoke1.vdb");
    let nvdb = dir.path().join("smoke.nvdb");
    let out = Command::new("nanovdb_convert")
        .arg(&vdb)
        .arg(&nvdb)
        .output()
        .expect("nanovdb_convert (libnanovdb-tools) is needed for this test");
    ok(&out, "nanovdb_convert");
    let mut images = Vec::new();
    for (tag, input) in [("vdb", &vdb), ("nvdb", &nvdb)] {
        let exr = dir.path().join(format!("{tag}.exr"));
        let mut args = vec![s(input), "--estimator", "ratio", "--pin-cells", "4"];
        args.extend_from_slice(&["--width", "24", "--height", "16"]);
        args.extend_from_slice(&["--offscreen", "--frames", "1", "--save", s(&exr)]);
        ok(&pinview(None, &args), tag);
        images.push(exr_bits(&exr));
    }
    assert!(images[0] == images[1], "the .nvdb views other bits");
}
