//! What the binary says about itself and the small commands beside the renders: the render
//! help's account of the default estimator, and `plot-bias` over a sweep's CSV.

use std::process::Command;

fn pinrender() -> Command {
    Command::new(env!("CARGO_BIN_EXE_pinrender"))
}

#[test]
fn render_help_says_what_the_default_estimator_is() {
    let out = pinrender().args(["render", "--help"]).output().unwrap();
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout);
    assert!(
        help.contains("ratio when it embeds a density")
            && help.contains("pins when it holds nothing else")
            && help.contains("with --volume alone, ratio"),
        "{help}"
    );
}

const SWEEP_CSV: &str = "scene,config,cells,dirs,directions,pins_per_entry,jitter,bytes,density_f16_bytes,ratio,mean_error,block8_rms_error
h,noise-floor,,,,,,0,100,0,-0.0003,0.0039
h,c8-oct4,8,octahedral:4,16,1,1,84832,100,0.0202,+0.0138,0.0883
h,c8-oct8,8,octahedral:8,64,1,1,281440,100,0.0671,+0.0329,0.0805
h,c16-polar16x4,16,polar:16x4,64,1,1,2130784,100,0.5080,+0.0314,0.0707
";

#[test]
fn plot_bias_draws_the_sweep_and_names_a_short_line() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("sweep.csv");
    std::fs::write(&csv, SWEEP_CSV).unwrap();
    let png = dir.path().join("b.png");
    let out = pinrender()
        .arg("plot-bias")
        .arg(&csv)
        .arg("--out")
        .arg(&png)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let bytes = std::fs::read(&png).unwrap();
    assert!(
        bytes.len() > 1000 && bytes.starts_with(b"\x89PNG"),
        "{} bytes",
        bytes.len()
    );
    // A short line is one error naming the file and the line; no image is written.
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, format!("{SWEEP_CSV}h,x,1\n")).unwrap();
    let png2 = dir.path().join("c.png");
    let out = pinrender()
        .arg("plot-bias")
        .arg(&bad)
        .arg("--out")
        .arg(&png2)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("line 6") && err.trim().lines().count() == 1,
        "{err}"
    );
    assert!(!png2.exists());
}
