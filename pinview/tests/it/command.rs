//! The JSON line's `command` opens the input as the viewer opened it: a raw volume's read
//! flags and its density scale are in it, and running it gives the saved EXR's bytes.

use crate::support::*;

#[test]
fn the_command_of_a_raw_volume_repeats_its_read_flags_and_bits() {
    let dir = tempfile::tempdir().unwrap();
    // 12 x 10 x 8 big-endian u16 voxels, in a file whose name gives no dims.
    let (nx, ny, nz) = (12u32, 10u32, 8u32);
    let values: Vec<u8> = (0..nx * ny * nz)
        .flat_map(|i| ((i * 37 % 251) as u16 * 40).to_be_bytes())
        .collect();
    let raw = dir.path().join("volume.raw");
    std::fs::write(&raw, values).unwrap();
    let exr = dir.path().join("view.exr");
    let args = [
        s(&raw),
        "--dims",
        "12,10,8",
        "--type",
        "u16",
        "--endian",
        "big",
        "--density-scale",
        "2",
        "--estimator",
        "ratio",
        "--width",
        "24",
        "--height",
        "16",
        "--offscreen",
        "--frames",
        "3",
        "--save",
        s(&exr),
        "--json",
    ];
    let out = pinview(None, &args);
    ok(&out, "pinview --offscreen of a raw volume");
    let j = json(&out);
    let command = j["command"].as_str().unwrap();
    for flag in [
        "--dims=12,10,8",
        "--type=u16",
        "--endian=big",
        "--density-scale=2",
    ] {
        assert!(command.contains(flag), "{flag} missing: {command}");
    }
    let batch_exr = dir.path().join("batch.exr");
    let batch = render_command(command, &batch_exr);
    assert!(
        batch == exr_bits(&exr),
        "not the saved EXR's bits: {command}"
    );
    // The files themselves, byte for byte.
    assert!(std::fs::read(&batch_exr).unwrap() == std::fs::read(&exr).unwrap());
}

/// A volume opened without `--density-scale` opens at its first look's scale: the power of
/// two that brings the median optical depth along the view to the target, which the JSON
/// states, the command carries and the batch render matches bit for bit; with
/// `--density-scale 1` the file's own values stand, and there is no first look.
#[test]
fn a_volume_opens_at_its_first_looks_scale_and_the_command_carries_it() {
    let dir = tempfile::tempdir().unwrap();
    // 12 x 10 x 8 u8 voxels of 1 to 7, one unit apart: a median depth of about 32 along
    // the view at the file's own scale, a nearly opaque block, so the first look lowers it.
    let values: Vec<u8> = (0..12u32 * 10 * 8).map(|i| (1 + i % 7) as u8).collect();
    let raw = dir.path().join("block_12x10x8_uint8.raw");
    std::fs::write(&raw, values).unwrap();
    let exr = dir.path().join("view.exr");
    let view = |extra: &[&str]| {
        let mut args = vec![
            s(&raw),
            "--estimator",
            "ratio",
            "--width",
            "24",
            "--height",
            "16",
            "--offscreen",
            "--frames",
            "2",
            "--json",
        ];
        args.extend_from_slice(extra);
        let out = pinview(None, &args);
        ok(&out, "pinview --offscreen of a raw volume");
        json(&out)
    };
    let j = view(&["--save", s(&exr)]);
    let look = &j["first_look"];
    let scale = look["scale"].as_f64().expect("first_look.scale");
    let depth = look["median_depth"]
        .as_f64()
        .expect("first_look.median_depth");
    let target = pinrender::front::first_look::TARGET_DEPTH;
    assert!(depth > 8.0 && scale < 1.0, "{j}");
    assert_eq!(scale, 2f64.powf((target / depth).log2().round()), "{j}");
    let command = j["command"].as_str().unwrap();
    assert!(
        command.contains(&format!("--density-scale={scale}")),
        "{command}"
    );
    let batch_exr = dir.path().join("batch.exr");
    assert!(
        render_command(command, &batch_exr) == exr_bits(&exr),
        "not the saved EXR's bits: {command}"
    );
    // The file's own scale, asked for.
    let own = view(&["--density-scale", "1"]);
    assert!(own["first_look"].is_null(), "{own}");
    let command = own["command"].as_str().unwrap();
    assert!(!command.contains("--density-scale"), "{command}");
}
