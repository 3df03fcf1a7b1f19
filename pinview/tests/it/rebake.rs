//! The density-scale re-bake: the volume read again at the new scale and its pins baked on
//! the GPU, swapped in for the old medium, checked against `pinrender render` at that scale.

use std::path::Path;

use crate::support::*;

/// A 16^3 f32 raw volume filling the unit box (spacing 1/16): a smooth field of extinction
/// up to 6.
fn raw_volume(dir: &Path) -> std::path::PathBuf {
    let n = 16;
    let mut bytes = Vec::with_capacity(n * n * n * 4);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let (x, y, z) = (x as f32, y as f32, z as f32);
                let v = 6.0 * (0.5 + 0.5 * (0.7 * x).cos() * (0.5 * y + 0.3 * z).cos());
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    let path = dir.join("v.raw");
    std::fs::write(&path, bytes).unwrap();
    path
}

const RAW: [&str; 6] = [
    "--dims",
    "16,16,16",
    "--type",
    "f32",
    "--spacing",
    "0.0625,0.0625,0.0625",
];

fn rgb(path: &Path) -> Vec<[f32; 3]> {
    pinrender::render::Image::read_exr(path).unwrap().rgb
}

fn rmse(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let sum: f64 = a
        .iter()
        .zip(b)
        .flat_map(|(p, q)| (0..3).map(move |c| f64::from(p[c]) - f64::from(q[c])))
        .map(|d| d * d)
        .sum();
    (sum / (a.len() * 3) as f64).sqrt()
}

#[test]
fn rebake_swaps_in_the_volume_and_its_gpu_pins_at_the_new_scale() {
    let dir = tempfile::tempdir().unwrap();
    let vol = raw_volume(dir.path());
    let Some(display) = display() else { return };
    let view = |est: &str, tag: &str| {
        let exr = dir.path().join(format!("{tag}.exr"));
        let mut args = vec![s(&vol)];
        args.extend_from_slice(&RAW);
        args.extend_from_slice(&VIEW);
        // Opened at the file's own scale (its first look would choose 2 itself), re-baked
        // at 2.
        args.extend_from_slice(&["--density-scale", "1"]);
        args.extend_from_slice(&["--seed", "2", "--estimator", est, "--rebake-scale", "2"]);
        // A small bake: the test is about the swap, and lavapipe bakes slowly.
        args.extend_from_slice(&["--pin-cells", "6"]);
        args.extend_from_slice(&["--frames", "2", "--save", s(&exr), "--json"]);
        let out = pinview(Some(&display), &args);
        ok(&out, "pinview --rebake-scale");
        let j = json(&out);
        assert_eq!(j["rebake"]["density_scale"], 2.0, "{j}");
        assert_eq!(j["rebake"]["backend"], "gpu", "{j}");
        (exr, j["command"].as_str().unwrap().to_string())
    };
    let render = |est: &str, scale: &str, tag: &str| {
        let exr = dir.path().join(format!("{tag}.exr"));
        let mut args = vec!["--volume", s(&vol)];
        args.extend_from_slice(&RAW);
        args.extend_from_slice(&VIEW);
        args.extend_from_slice(&["--seed", "2", "--estimator", est, "--density-scale", scale]);
        args.extend_from_slice(&["--backend", "gpu", "--spp", "2", "--out", s(&exr)]);
        args.extend_from_slice(&["--pin-cells", "6"]);
        ok(&pinrender_render(&args), "pinrender render");
        exr
    };
    // Ratio tracking reads the volume alone: the same bits as a render at the new scale.
    let (ratio, command) = view("ratio", "ratio-view");
    // The command carries the re-bake's scale and the read flags, and renders the same bits.
    assert!(
        command.contains("--density-scale=2 ") && command.contains("--dims=16,16,16 "),
        "{command}"
    );
    assert!(
        exr_bits(&ratio) == render_command(&command, &dir.path().join("ratio-command.exr")),
        "the command after the re-bake does not render the saved bits: {command}"
    );
    assert!(
        exr_bits(&ratio) == exr_bits(&render("ratio", "2", "ratio-2")),
        "ratio after the re-bake is not the volume at density scale 2"
    );
    assert!(exr_bits(&ratio) != exr_bits(&render("ratio", "1", "ratio-1")));
    // Pins read the new bake: near `pinrender`'s (CPU) bake at scale 2, far from scale 1's.
    let pins = rgb(&view("pins", "pins-view").0);
    let near = rmse(&pins, &rgb(&render("pins", "2", "pins-2")));
    let far = rmse(&pins, &rgb(&render("pins", "1", "pins-1")));
    assert!(
        near < 0.5 * far,
        "pins after the re-bake: RMSE {near} to scale 2's bake, {far} to scale 1's"
    );
}
