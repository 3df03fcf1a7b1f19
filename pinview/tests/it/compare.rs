//! Split view: two estimators at equal time. Each half of the screenshot is `pinrender
//! render --backend gpu` of its estimator at the passes that side got.

use crate::support::*;

/// The columns `x0..x1` of an RGB image `w` wide.
fn columns(img: &(u32, u32, Vec<u8>), x0: usize, x1: usize) -> Vec<u8> {
    let w = img.0 as usize;
    img.2
        .chunks_exact(w * 3)
        .flat_map(|row| row[x0 * 3..x1 * 3].iter().copied())
        .collect()
}

/// At most one code off anywhere, and at most one code in fifty off (the window's tone map
/// runs in f32 on the GPU; see `contract`).
fn close(view: &[u8], reference: &[u8]) -> bool {
    let worst = view
        .iter()
        .zip(reference)
        .map(|(&a, &b)| (i32::from(a) - i32::from(b)).abs())
        .max()
        .unwrap_or(0);
    let off = view.iter().zip(reference).filter(|(a, b)| a != b).count();
    view.len() == reference.len() && worst <= 1 && off * 50 <= view.len()
}

#[test]
fn compare_halves_are_each_estimator_at_its_passes() {
    let dir = tempfile::tempdir().unwrap();
    let pins = bake(dir.path(), "d.pin", 1.0, Some(12));
    let Some(display) = display() else { return };
    let shot = dir.path().join("split.png");
    let mut args = vec![s(&pins)];
    args.extend_from_slice(&VIEW);
    args.extend_from_slice(&[
        "--seed",
        "5",
        "--estimator",
        "pins",
        "--compare",
        "ratio",
        "--frames",
        "3",
        "--screenshot",
        s(&shot),
        "--json",
    ]);
    let out = pinview(Some(&display), &args);
    ok(&out, "pinview --compare");
    let j = json(&out);
    // The first estimator's fields are as without --compare.
    assert_eq!(j["estimator"], "pins", "{j}");
    assert_eq!(j["passes"], 3, "{j}");
    let c = &j["compare"];
    assert_eq!(c["estimator"], "ratio", "{j}");
    let passes = c["passes"].as_u64().unwrap_or(0);
    assert!(passes >= 1, "the second side rendered no pass: {j}");
    let ms = c["ms_per_pass"].as_f64().unwrap_or(0.0);
    assert!(ms > 0.0, "compare.ms_per_pass: {j}");
    // Equal time as charged by the measured pass times: within one pass of either side (the
    // last pass is whole).
    let (a, b) = (
        c["first_seconds"].as_f64().unwrap_or(-1.0),
        c["seconds"].as_f64().unwrap_or(-1.0),
    );
    let slack = 1e-3
        * (c["clock_ms_per_pass"].as_f64().unwrap_or(0.0)
            + c["first_clock_ms_per_pass"].as_f64().unwrap_or(0.0));
    assert!(
        a > 0.0 && (a - b).abs() <= slack,
        "unequal time: first {a} s, second {b} s (slack {slack} s): {j}"
    );
    let split = c["split_column"].as_u64().unwrap() as usize;
    assert_eq!(split, 24, "the divider starts in the middle: {j}");

    let render = |est: &str, spp: &str, tag: &str| {
        let exr = dir.path().join(format!("{tag}.exr"));
        let mut r = vec!["--pins", s(&pins), "--backend", "gpu", "--spp", spp];
        r.extend_from_slice(&VIEW);
        r.extend_from_slice(&["--seed", "5", "--estimator", est, "--out", s(&exr)]);
        ok(&pinrender_render(&r), "pinrender render");
        png_rgb(&exr.with_extension("png"))
    };
    let view = png_rgb(&shot);
    assert_eq!((view.0, view.1), (48, 40));
    let left = render("pins", "3", "left");
    let right = render("ratio", &passes.to_string(), "right");
    assert!(
        close(&columns(&view, 0, split), &columns(&left, 0, split)),
        "the left half is not pins at 3 passes"
    );
    assert!(
        close(&columns(&view, split, 48), &columns(&right, split, 48)),
        "the right half is not ratio at {passes} passes"
    );
    // The halves are two estimators' noise, not one image twice.
    assert!(
        !close(&columns(&view, split, 48), &columns(&left, split, 48)),
        "the right half is the left estimator's image"
    );
}
