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
