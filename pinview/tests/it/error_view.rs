//! The error view: a ratio-tracking reference in the background, the RMSE against it and the
//! heat map of |estimate - reference|, checked against `pinrender render` of both at the
//! passes and seeds the JSON reports.

use crate::support::*;

fn exr_rgb(path: &std::path::Path) -> Vec<[f32; 3]> {
    pinrender::render::Image::read_exr(path).unwrap().rgb
}

#[test]
fn error_view_measures_the_estimate_against_a_ratio_reference() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, Some(12));
    let Some(display) = display() else { return };
    let (est_exr, heat_png) = (dir.path().join("est.exr"), dir.path().join("heat.png"));
    let mut args = vec![s(&pins)];
    args.extend_from_slice(&VIEW);
    args.extend_from_slice(&[
        "--seed",
        "4",
        "--estimator",
        "pinms",
        "--error-view",
        "--frames",
        "2",
        "--save",
        s(&est_exr),
        "--screenshot",
        s(&heat_png),
        "--json",
    ]);
    let out = pinview(Some(&display), &args);
    ok(&out, "pinview --error-view");
    let j = json(&out);
    assert_eq!(j["passes"], 2, "{j}");
    // An estimator asked for is shown from the first image: no switch.
    assert_eq!(j["first_image_estimator"], "pinms", "{j}");
    assert!(j["estimator_switch_s"].is_null(), "{j}");
    let e = &j["error"];
    assert_eq!(e["reference"], "ratio", "{j}");
    let passes = e["reference_passes"].as_u64().unwrap_or(0);
    assert!(passes >= 1, "the reference has no pass: {j}");
    let seed = e["reference_seed"].as_u64().unwrap();
    assert_ne!(seed, 4, "the reference shares the estimate's seed: {j}");
    let ref_exr = dir.path().join("ref.exr");
    let mut r = vec![
        "--pins",
        s(&pins),
        "--backend",
        "gpu",
        "--estimator",
        "ratio",
    ];
    r.extend_from_slice(&VIEW);
    let (p, sd) = (passes.to_string(), seed.to_string());
    r.extend_from_slice(&["--spp", &p, "--seed", &sd, "--out", s(&ref_exr)]);
    ok(&pinrender_render(&r), "pinrender render (reference)");
    let (est, reference) = (exr_rgb(&est_exr), exr_rgb(&ref_exr));
    let sum: f64 = est
        .iter()
        .zip(&reference)
        .flat_map(|(a, b)| (0..3).map(move |c| f64::from(a[c]) - f64::from(b[c])))
        .map(|d| d * d)
        .sum();
    let expected = (sum / (est.len() * 3) as f64).sqrt();
    let rmse = e["rmse"].as_f64().unwrap_or(-1.0);
    assert!(expected > 0.0, "estimate and reference are the same image");
    assert!(
        (rmse - expected).abs() <= 1e-9 * expected,
        "RMSE {rmse}, from the two renders {expected}: {j}"
    );
    // The heat map is black exactly where estimate == reference (the background, which
    // both see unattenuated) and bright where they differ.
    let (w, h, heat) = png_rgb(&heat_png);
    assert_eq!((w, h), (48, 40));
    let (mut equal, mut lit) = (0, 0);
    for (i, (a, b)) in est.iter().zip(&reference).enumerate() {
        let px = &heat[i * 3..i * 3 + 3];
        if a == b {
            equal += 1;
            assert_eq!(px, [0, 0, 0], "pixel {i}: equal values, heat {px:?}");
        } else if (0..3).map(|c| (a[c] - b[c]).abs()).sum::<f32>() > 0.3 {
            lit += usize::from(px.iter().any(|&c| c > 0));
        }
    }
    assert!(equal > 0, "no pixel where estimate and reference agree");
    assert!(lit > 0, "the heat map is dark where they differ");
}

#[test]
fn a_pin_file_without_density_has_no_reference() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "c.pin", 1.0, None);
    let Some(display) = display() else { return };
    let shot = dir.path().join("shot.png");
    let mut args = vec![s(&pins)];
    args.extend_from_slice(&VIEW);
    args.extend_from_slice(&[
        "--error-view",
        "--frames",
        "1",
        "--screenshot",
        s(&shot),
        "--json",
    ]);
    let out = pinview(Some(&display), &args);
    ok(&out, "pinview --error-view on pins alone");
    let j = json(&out);
    assert!(j["error"]["reference"].is_null(), "{j}");
    let why = j["error"]["why"].as_str().unwrap_or_default();
    assert!(why.contains("no density"), "{j}");
    // The render is shown as without the error view.
    let (_, _, rgb) = png_rgb(&shot);
    assert!(rgb.iter().any(|&c| c > 30), "the screenshot is black");
}
