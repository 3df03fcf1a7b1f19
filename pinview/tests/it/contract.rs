//! The scripting contract: the screenshot and the EXR against `pinrender render --backend
//! gpu`, the JSON line, the default estimator, and that a camera or sun change changes the
//! image.

use crate::support::*;

/// (viewer EXR bits, pinrender EXR bits, viewer PNG, pinrender PNG, JSON line).
type Both = (
    Vec<u32>,
    Vec<u32>,
    (u32, u32, Vec<u8>),
    (u32, u32, Vec<u8>),
    serde_json::Value,
);

/// Renders `file` with pinview (`--frames spp`) and with `pinrender render --backend gpu`
/// (`--spp spp`), both with `flags`, and returns (viewer EXR, pinrender EXR, viewer PNG,
/// pinrender PNG, JSON).
fn both(
    display: &Display,
    dir: &std::path::Path,
    tag: &str,
    input: (&str, &str),
    flags: &[&str],
    spp: u32,
) -> Both {
    let shot = dir.join(format!("{tag}-view.png"));
    let saved = dir.join(format!("{tag}-view.exr"));
    let reference = dir.join(format!("{tag}-ref.exr"));
    let n = spp.to_string();
    let mut view_args = vec![input.1];
    view_args.extend_from_slice(flags);
    view_args.extend_from_slice(&[
        "--frames",
        &n,
        "--screenshot",
        s(&shot),
        "--save",
        s(&saved),
        "--json",
    ]);
    let out = pinview(Some(display), &view_args);
    ok(&out, "pinview");
    let mut render_args = vec![input.0, input.1, "--backend", "gpu", "--spp", &n];
    render_args.extend_from_slice(flags);
    render_args.extend_from_slice(&["--out", s(&reference)]);
    ok(&pinrender_render(&render_args), "pinrender render");
    (
        exr_bits(&saved),
        exr_bits(&reference),
        png_rgb(&shot),
        png_rgb(&reference.with_extension("png")),
        json(&out),
    )
}

fn assert_png_close(view: &(u32, u32, Vec<u8>), reference: &(u32, u32, Vec<u8>)) {
    assert_eq!((view.0, view.1), (reference.0, reference.1), "PNG sizes");
    let worst = view
        .2
        .iter()
        .zip(&reference.2)
        .map(|(&a, &b)| (i32::from(a) - i32::from(b)).abs())
        .max()
        .unwrap();
    let off = view
        .2
        .iter()
        .zip(&reference.2)
        .filter(|(a, b)| a != b)
        .count();
    // The window's tone map runs in f32 on the GPU: a code may be one step off where the
    // value sits on a rounding boundary; the EXR is compared bit for bit.
    assert!(
        worst <= 1,
        "a screenshot code is {worst} steps off pinrender's PNG"
    );
    assert!(
        off * 50 <= view.2.len(),
        "{off} screenshot codes differ from pinrender's PNG"
    );
    assert!(view.2.iter().any(|&c| c > 30), "the screenshot is black");
}

/// A pin file without density, 3 passes: the viewer's EXR has the bits of `pinrender render
/// --backend gpu`, its screenshot is within one code of the PNG, and the JSON line has every
/// field; run again with the same flags it gives the same bits, and moving the sun or the
/// camera changes them (one test: the first run is the base of the second check).
#[test]
fn pins_alone_matches_pinrender_and_the_sun_and_camera_change_it() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "c.pin", 1.0, None);
    let mut flags = VIEW.to_vec();
    flags.extend_from_slice(&["--seed", "7", "--g", "0.3", "--max-bounces", "3"]);
    let Some(display) = display() else { return };
    let (view, reference, vpng, rpng, j) = both(
        &display,
        dir.path(),
        "pins",
        ("--pins", s(&pins)),
        &flags,
        3,
    );
    assert_eq!(view.len(), 48 * 40 * 3);
    assert!(
        view == reference,
        "the viewer's EXR differs from pinrender render --backend gpu"
    );
    assert_png_close(&vpng, &rpng);
    // Without --estimator both use pins: the file has no density.
    assert_eq!(j["estimator"], "pins");
    assert_eq!(j["width"], 48);
    assert_eq!(j["height"], 40);
    assert_eq!(j["passes"], 3);
    for key in ["adapter", "backend"] {
        assert!(j[key].as_str().is_some_and(|v| !v.is_empty()), "{key}: {j}");
    }
    for key in ["first_image_s", "ms_per_pass"] {
        assert!(j[key].as_f64().is_some_and(|v| v > 0.0), "{key}: {j}");
    }
    // The steps to the first image, each measured, add up to it.
    let steps = &j["first_image_breakdown"];
    let mut sum = 0.0;
    for key in [
        "file_open_s",
        "window_and_device_s",
        "upload_s",
        "pipeline_s",
        "first_pass_s",
    ] {
        let v = steps[key].as_f64().unwrap_or(-1.0);
        assert!(v > 0.0, "first_image_breakdown.{key}: {j}");
        sum += v;
    }
    let first = j["first_image_s"].as_f64().unwrap_or_default();
    assert!(
        (sum - first).abs() < 1e-9,
        "the steps add to {sum}, not {first}: {j}"
    );
    // GPU time where the adapter has timestamp queries and is not a CPU (the viewer requests
    // them there), else wall.
    let source = j["pass_time_source"].as_str().unwrap_or_default();
    assert!(
        ["gpu-timestamps", "wall"].contains(&source),
        "pass_time_source: {j}"
    );
    assert_eq!(
        source == "gpu-timestamps",
        adapter_has_timestamps(),
        "pass_time_source does not follow the adapter: {j}"
    );
    // The same flags again, then the sun and the camera moved.
    let d = &display;
    let exr = |tag: &str, extra: &[&str]| view_exr(d, dir.path(), &pins, tag, extra);
    let again = exr("again", &[]);
    assert!(view == again, "the same view must give the same bits");
    let sun = exr("sun", &["--sun-dir", "-0.8,0.3,-0.5"]);
    assert!(sun != view, "moving the sun left the image unchanged");
    let camera = exr("camera", &["--camera-origin", "2.4,0.9,0.7"]);
    assert!(camera != view, "moving the camera left the image unchanged");
}

/// Without `--estimator`, a pin file that embeds its density shows pins at once and switches
/// to ratio tracking (`pinrender render`'s default for it) once that renderer is built; the
/// passes are then ratio's, bit for bit.
#[test]
fn embedded_density_defaults_to_ratio_and_matches() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, Some(12));
    let mut flags = VIEW.to_vec();
    flags.extend_from_slice(&["--seed", "3"]);
    let Some(display) = display() else { return };
    let (view, reference, vpng, rpng, j) = both(
        &display,
        dir.path(),
        "ratio",
        ("--pins", s(&pins)),
        &flags,
        2,
    );
    assert_eq!(j["estimator"], "ratio", "{j}");
    assert!(
        view == reference,
        "ratio: the viewer's EXR differs from pinrender's"
    );
    // The window showed pins at once and switched to ratio once its renderer was built; the
    // passes above are ratio's alone.
    assert_eq!(j["first_image_estimator"], "pins", "{j}");
    let first = j["first_image_s"].as_f64().unwrap_or(-1.0);
    let switch = j["estimator_switch_s"].as_f64().unwrap_or(-1.0);
    assert!(first > 0.0 && switch > first, "{j}");
    assert!(
        j["messages"]
            .to_string()
            .contains("ratio shown: its pipeline is ready"),
        "{j}"
    );
    assert_eq!(j["notes"], serde_json::json!([]), "{j}");
    assert_png_close(&vpng, &rpng);
}

#[test]
fn a_volume_is_tracked_with_ratio_like_pinrender() {
    let dir = tempfile::tempdir().unwrap();
    let mut flags = VIEW.to_vec();
    flags.extend_from_slice(&["--seed", "11", "--estimator", "ratio"]);
    let Some(display) = display() else { return };
    let (view, reference, .., j) = both(
        &display,
        dir.path(),
        "ratio",
        ("--volume", COSINE),
        &flags,
        2,
    );
    assert!(
        view == reference,
        "ratio on a volume: the viewer's EXR differs"
    );
    // The window measured the volume's first look: this field (a median depth near 6 along
    // the view, docs/viewer.md) already reads at its own scale, so the render above, at the
    // file's scale, is the one shown.
    let depth = j["first_look"]["median_depth"]
        .as_f64()
        .expect("first_look");
    assert!(depth > 4.0 && depth < 12.0, "{j}");
    assert_eq!(j["first_look"]["scale"], 1.0, "{j}");
}

/// One pinview EXR of the pin file with the flags of the first test, 3 passes, and `extra`.
fn view_exr(
    display: &Display,
    dir: &std::path::Path,
    pins: &std::path::Path,
    tag: &str,
    extra: &[&str],
) -> Vec<u32> {
    let out_path = dir.join(format!("{tag}.exr"));
    let mut args = vec![s(pins)];
    // An --camera-origin in `extra` replaces the default one (clap takes each flag once).
    let skip = if extra.contains(&"--camera-origin") {
        2
    } else {
        0
    };
    args.extend_from_slice(&VIEW[skip..]);
    args.extend_from_slice(&["--seed", "7", "--g", "0.3", "--max-bounces", "3"]);
    args.extend_from_slice(extra);
    args.extend_from_slice(&["--frames", "3", "--save", s(&out_path)]);
    ok(&pinview(Some(display), &args), "pinview");
    exr_bits(&out_path)
}
