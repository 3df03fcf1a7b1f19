//! End-to-end tests of the `pinbake` binary on every file in data/.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

const BIN: &str = env!("CARGO_BIN_EXE_pinbake");

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(name)
}

fn pinbake(args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .stdin(Stdio::null())
        .output()
        .expect("run pinbake")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Small, fast bake settings for tests.
const FAST: &[&str] = &["--cells", "6", "--dirs", "octahedral:2", "--step", "0.05"];

fn bake_ok(input: &str, out: &Path, extra: &[&str]) -> serde_json::Value {
    let mut args = vec!["bake", input, "-o", out.to_str().unwrap(), "--json"];
    args.extend_from_slice(FAST);
    args.extend_from_slice(extra);
    let o = pinbake(&args);
    assert!(o.status.success(), "bake {input} failed: {}", stderr(&o));
    serde_json::from_slice(&o.stdout).expect("bake --json prints one JSON object")
}

fn assert_clean_failure(o: &Output, needle: &str, out: &Path) {
    assert_eq!(o.status.code(), Some(1), "stderr: {}", stderr(o));
    let err = stderr(o);
    assert_eq!(
        err.trim_end().lines().count(),
        1,
        "one-line error, got: {err}"
    );
    assert!(err.contains(needle), "error should mention {needle}: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(!out.exists(), "no output file on failure");
}

#[test]
fn every_valid_volume_bakes_and_verifies() {
    let dir = tempfile::tempdir().unwrap();
    let cases: &[(&str, &[&str])] = &[
        ("openvdb_smoke1.vdb", &[]),
        ("gaffer_sphere_density.vdb", &[]),
        ("oiio_sphere_density.vdb", &[]),
        ("arnold_grids_3x_density.vdb", &["--grid", "density#1"]),
        ("openvdb_sphere_levelset.vdb", &["--levelset-to-fog"]),
        (
            "hydrogen_atom_128x128x128_uint8.raw",
            &["--density-scale", "0.05"],
        ),
        ("water_esp_31x34x33_float32.raw", &["--clamp-negative"]),
    ];
    for (i, (name, extra)) in cases.iter().enumerate() {
        let out = dir.path().join(format!("{i}.pin"));
        let path = data(name);
        let v = bake_ok(path.to_str().unwrap(), &out, extra);
        for key in [
            "dims",
            "directions",
            "pins_per_entry",
            "pins",
            "empty_cells",
            "file_bytes",
            "t_min",
            "seconds",
            "pins_per_s",
        ] {
            assert!(!v[key].is_null(), "{name}: --json lacks {key}: {v}");
        }
        assert_eq!(v["dims"], serde_json::json!([6, 6, 6]));
        assert_eq!(
            v["directions"],
            serde_json::json!({"kind": "octahedral", "n": 2})
        );
        assert!(
            v["t_min"]["min"].as_f64().unwrap() < 1.0,
            "{name} saw no medium"
        );
        assert_eq!(
            v["file_bytes"].as_u64().unwrap(),
            std::fs::metadata(&out).unwrap().len()
        );
        let o = pinbake(&["verify", out.to_str().unwrap()]);
        assert!(o.status.success(), "{name}: {}", stderr(&o));
        let o = pinbake(&["inspect", out.to_str().unwrap(), "--json"]);
        assert!(o.status.success());
        let iv: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(iv["pins"], v["pins"]);
        assert_eq!(iv["empty_cells"], v["empty_cells"]);
    }
}

#[test]
fn refused_inputs_fail_cleanly() {
    // The damaged VDBs of data/oiio_damaged: hostile.rs, with bounds on memory and time.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("never.pin");

    // A level set without the conversion flag says how to convert.
    let ls = data("openvdb_sphere_levelset.vdb");
    let o = pinbake(&["bake", ls.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert_clean_failure(&o, "--levelset-to-fog", &out);

    // Repeated grid names without an index, and a grid that does not exist.
    let arnold = data("arnold_grids_3x_density.vdb");
    let o = pinbake(&[
        "bake",
        arnold.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--grid",
        "nope",
    ]);
    assert_clean_failure(&o, "nope", &out);

    // Raw: wrong size, NaN-free signed data without --clamp-negative.
    let h = data("hydrogen_atom_128x128x128_uint8.raw");
    let o = pinbake(&[
        "bake",
        h.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--dims",
        "128,128,127",
        "--type",
        "u8",
    ]);
    assert_clean_failure(&o, "hydrogen_atom", &out);
    let w = data("water_esp_31x34x33_float32.raw");
    let o = pinbake(&["bake", w.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert_clean_failure(&o, "negative", &out);

    // A pin file that is not one.
    let o = pinbake(&["verify", h.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("hydrogen_atom"));
}

#[test]
fn usage_errors_exit_2() {
    let o = pinbake(&["bake"]);
    assert_eq!(o.status.code(), Some(2));
    let o = pinbake(&["bake", "x.raw", "-o", "y.pin", "--dirs", "spiral:3"]);
    assert_eq!(o.status.code(), Some(2));
    let o = pinbake(&["bake", "x.raw", "-o", "y.pin", "--tile", "3/2"]);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn threads_and_tiles_give_identical_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let input = data("gaffer_sphere_density.vdb");
    let input = input.to_str().unwrap();
    let one = dir.path().join("one.pin");
    let two = dir.path().join("two.pin");
    bake_ok(input, &one, &["--threads", "1", "--seed", "5"]);
    bake_ok(input, &two, &["--threads", "2", "--seed", "5"]);
    let a = std::fs::read(&one).unwrap();
    assert_eq!(a, std::fs::read(&two).unwrap());

    // Tiles as parallel local processes, the way a farm runs them, then merge.
    let n = 3;
    let children: Vec<_> = (0..n)
        .map(|i| {
            let out = dir.path().join(format!("tile{i}.pin"));
            let tile = format!("{i}/{n}");
            let mut args = vec![
                "bake".to_string(),
                input.to_string(),
                "-o".into(),
                out.to_str().unwrap().into(),
                "--seed".into(),
                "5".into(),
                "--tile".into(),
                tile,
            ];
            args.extend(FAST.iter().map(|s| s.to_string()));
            Command::new(BIN)
                .args(&args)
                .stdout(Stdio::null())
                .spawn()
                .unwrap()
        })
        .collect();
    for mut c in children {
        assert!(c.wait().unwrap().success());
    }
    let merged = dir.path().join("merged.pin");
    let mut args = vec!["merge".to_string()];
    for i in (0..n).rev() {
        args.push(
            dir.path()
                .join(format!("tile{i}.pin"))
                .to_str()
                .unwrap()
                .into(),
        );
    }
    args.extend(["-o".into(), merged.to_str().unwrap().into()]);
    let o = Command::new(BIN).args(&args).output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        std::fs::read(&merged).unwrap(),
        a,
        "merged tiles == monolithic bake"
    );
}

#[test]
fn killed_bake_never_leaves_a_file_under_the_target_name() {
    use std::os::unix::process::ExitStatusExt;
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("smoke.pin");
    std::fs::write(&target, b"previous good file").unwrap();
    let input = data("openvdb_smoke1.vdb");
    // Kill at a spread of moments: while the worker reads, while baking, while writing.
    for (i, delay_ms) in [5u64, 40, 120, 300, 700].into_iter().enumerate() {
        let mut child = Command::new(BIN)
            .args([
                "bake",
                input.to_str().unwrap(),
                "-o",
                target.to_str().unwrap(),
                "--cells",
                "24",
                "--seed",
                &i.to_string(),
            ])
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(delay_ms));
        let _ = child.kill(); // SIGKILL
        let status = child.wait().unwrap();
        let content = std::fs::read(&target).unwrap();
        if status.signal() == Some(9) {
            assert_eq!(content, b"previous good file", "killed after {delay_ms} ms");
        } else {
            // The bake won the race: the target is a complete, valid file.
            assert!(status.success());
            let f = pin_format::PinFile::parse(&content).unwrap();
            f.verify().unwrap();
            std::fs::write(&target, b"previous good file").unwrap();
        }
    }
}

/// A process started as a VDB reader never starts another one: a `worker_exe` that does not
/// understand `__vdb-worker` (a test harness runs its tests instead, which open the VDB
/// again) would otherwise spawn itself without end.
#[test]
fn a_worker_never_spawns_a_worker() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("smoke.pin");
    let o = Command::new(BIN)
        .args(["bake"])
        .arg(data("openvdb_smoke1.vdb"))
        .arg("-o")
        .arg(&out)
        .env(pin_volume::vdb::WORKER_ENV, "1")
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert_clean_failure(&o, "refusing to start a VDB reader", &out);
}

/// Without `--cells` a bake never uses more spatial cells than the volume has voxels
/// along an axis, the directions are an octahedral set, and `--json` says what was chosen and
/// why.
#[test]
fn default_bake_fits_the_voxels() {
    let dir = tempfile::tempdir().unwrap();
    let input = data("water_esp_31x34x33_float32.raw");
    let bake = |name: &str, extra: &[&str]| -> serde_json::Value {
        let out = dir.path().join(name);
        let mut args = vec![
            "bake",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--json",
            "--clamp-negative",
            "--no-crop",
            "--step",
            "0.1",
            "--majorant",
            "0",
            // A grid parameter named: the pins-only choice, not the default asset
            // (tests/it/default_asset.rs).
            "--pins-per-entry",
            "1",
        ];
        args.extend_from_slice(extra);
        let o = pinbake(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        // The choice's warning is printed on stderr as one line, and only then.
        let warned: Vec<_> = stderr(&o)
            .lines()
            .filter(|l| l.starts_with("pinbake: warning: "))
            .map(str::to_string)
            .collect();
        match v["choice"]["warning"].as_str() {
            Some(w) => assert!(warned.len() == 1 && warned[0].ends_with(w), "{warned:?}"),
            None => assert!(warned.is_empty(), "{warned:?}"),
        }
        v
    };
    let dims = |v: &serde_json::Value| -> Vec<u64> {
        v["dims"]
            .as_array()
            .unwrap()
            .iter()
            .map(|d| d.as_u64().unwrap())
            .collect()
    };
    // Cells and directions chosen, within the voxels, reported.
    let v = bake("water.pin", &[]);
    assert!(
        dims(&v).iter().zip([31, 34, 33]).all(|(d, n)| *d <= n),
        "{v}"
    );
    assert_eq!(v["directions"]["kind"], "octahedral");
    let c = &v["choice"];
    assert_eq!(c["cells"], v["dims"]);
    assert_eq!(c["directions"], v["directions"]);
    assert_eq!(c["pins_per_entry"], 1);
    assert_eq!(c["target_error"], pinbake::choose::DEFAULT_TARGET_ERROR);
    assert_eq!(c["target_met"], true);
    assert_eq!(c["warning"], serde_json::Value::Null);
    assert!(c["predicted_error"].as_f64().unwrap() <= pinbake::choose::DEFAULT_TARGET_ERROR);
    assert_eq!(c["bytes"], v["file_bytes"]);
    for p in ["cells", "directions", "pins_per_entry"] {
        assert!(
            c["reason"][p].as_str().is_some_and(|r| !r.is_empty()),
            "{p}"
        );
    }
    assert_eq!(c["volume"]["voxels"], serde_json::json!([31, 34, 33]));
    assert_eq!(c["asset"], serde_json::Value::Null);
    // A target nothing reaches: the most accurate bake, whose cells are capped by the voxels
    // (directions given, to keep the test fast).
    let v = bake(
        "fine.pin",
        &["--target-error", "0.001", "--dirs", "octahedral:2"],
    );
    assert_eq!(dims(&v), [31, 34, 33]);
    assert_eq!(v["choice"]["target_met"], false);
    assert_eq!(v["choice"]["reason"]["directions"], "given (--dirs)");
    assert!(
        v["choice"]["warning"]
            .as_str()
            .is_some_and(|w| w.contains("0.001")),
        "{v}"
    );
    // An explicit --cells is taken as given, finer than the voxels or not.
    let out = dir.path().join("water40.pin");
    let o = pinbake(&[
        "bake",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--json",
        "--clamp-negative",
        "--cells",
        "40,2,3",
        "--dirs",
        "octahedral:2",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["dims"], serde_json::json!([40, 2, 3]));
    assert_eq!(v["choice"]["reason"]["cells"], "given (--cells)");
    assert_eq!(v["choice"]["reason"]["directions"], "given (--dirs)");
}

/// A raw f32 grid of `n^3` voxels over the unit cube: a Gaussian blob, with cosine detail of
/// `f` cycles per box when `f > 0`.
fn write_blob(path: &Path, n: usize, f: f64) {
    let mut bytes = Vec::with_capacity(n * n * n * 4);
    for i in 0..n * n * n {
        let p = [i % n, (i / n) % n, i / (n * n)].map(|c| (c as f64 + 0.5) / n as f64);
        let r2: f64 = p.iter().map(|x| (x - 0.5) * (x - 0.5)).sum();
        let detail = 1.0
            + if f > 0.0 {
                0.9 * (std::f64::consts::TAU * f * p[0]).cos()
                    * (std::f64::consts::TAU * f * p[1]).cos()
            } else {
                0.0
            };
        let v = (20.0 * (-r2 / 0.045).exp() * detail) as f32;
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(path, bytes).unwrap();
}

/// `--target-error`: a smaller target never gives a smaller file, a smooth volume never gets a
/// larger file than a detailed one at the same target, and bad values are usage errors (exit 2).
#[test]
fn target_error_chooses_monotone_bakes() {
    let dir = tempfile::tempdir().unwrap();
    let smooth = dir.path().join("smooth_16x16x16_f32.raw");
    let detailed = dir.path().join("detailed_16x16x16_f32.raw");
    write_blob(&smooth, 16, 0.0);
    write_blob(&detailed, 16, 4.0);
    let bake = |input: &Path, target: &str| -> serde_json::Value {
        let out = dir.path().join("t.pin");
        let o = pinbake(&[
            "bake",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--json",
            "--spacing",
            "0.0625",
            "--step",
            "0.1",
            "--majorant",
            "0",
            // The pins-only choice (a grid parameter named): the default asset's own target
            // is tests/it/default_asset.rs's.
            "--pins-per-entry",
            "1",
            "--target-error",
            target,
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let cells = |v: &serde_json::Value| -> u64 {
        v["dims"]
            .as_array()
            .unwrap()
            .iter()
            .map(|d| d.as_u64().unwrap())
            .product()
    };
    let mut last = 0;
    let mut fewer = 0;
    for target in ["0.2", "0.1", "0.07", "0.05", "0.035", "0.025"] {
        let v = bake(&detailed, target);
        let bytes = v["file_bytes"].as_u64().unwrap();
        assert!(bytes >= last, "target {target}: {bytes} < {last}");
        assert!(cells(&v) <= 16 * 16 * 16);
        last = bytes;
        // At a coarse target both may get the same smallest bake; never the smooth one more
        // bytes. (Not more cells either would be too strong: the model may buy the detailed
        // volume's accuracy with directions rather than cells.)
        let s = bake(&smooth, target);
        let (sb, vb) = (
            s["file_bytes"].as_u64().unwrap(),
            v["file_bytes"].as_u64().unwrap(),
        );
        assert!(
            sb <= vb,
            "target {target}: smooth {} vs detailed {}",
            s["choice"],
            v["choice"]
        );
        fewer += usize::from(sb < vb);
    }
    assert!(
        fewer >= 2,
        "the smooth volume got a smaller file at {fewer} targets"
    );
    for bad in [
        &["--target-error", "0"][..],
        &["--target-error", "1.5"],
        &["--target-error", "x"],
    ] {
        let mut args = vec!["bake", "x.raw", "-o", "y.pin"];
        args.extend_from_slice(bad);
        let o = pinbake(&args);
        assert_eq!(o.status.code(), Some(2), "{bad:?}: {}", stderr(&o));
    }
    // With every parameter given there is nothing left to choose.
    let o = pinbake(&[
        "bake",
        smooth.to_str().unwrap(),
        "-o",
        dir.path().join("n.pin").to_str().unwrap(),
        "--cells",
        "4",
        "--dirs",
        "octahedral:4",
        "--pins-per-entry",
        "1",
        "--target-error",
        "0.05",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--target-error"), "{}", stderr(&o));
}

/// `pinbake bench --json`: every row carries the fields scripts read, with sane
/// values, on a tiny configuration.
#[test]
fn bench_json_rows_carry_time_memory_and_integration_error() {
    let o = pinbake(&[
        "bench",
        "--voxels",
        "16",
        "--cells",
        "4",
        "--grid-only",
        "--threads",
        "1,2",
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
    let rows = v["results"].as_array().unwrap();
    assert_eq!(rows.len(), 2, "one row per thread count");
    for (r, threads) in rows.iter().zip([1, 2]) {
        assert_eq!(r["threads"], threads, "{r}");
        assert!(r["wall_s"].as_f64().unwrap() > 0.0, "{r}");
        assert!(r["pins_per_s"].as_f64().unwrap() > 0.0, "{r}");
        assert_eq!(r["pins"], 4 * 4 * 4 * 64, "{r}");
        // Linux reports the high-water mark; a bake of this size stays far below 1 GB.
        let rss = r["peak_rss_bytes"].as_u64().unwrap();
        assert!(rss > 0 && rss < 1 << 30, "{r}");
        // The midpoint rule at step 0.01 on smooth noise: small but not zero.
        let e = r["integration_error"].as_f64().unwrap();
        assert!(e > 0.0 && e < 1e-2, "{r}");
        assert!(r["integration_error_max"].as_f64().unwrap() >= e, "{r}");
        // CPU seconds of the bake (Linux).
        assert!(r["cpu_s"].as_f64().unwrap() >= 0.0, "{r}");
    }
}

/// `pinbake bench --backend cpu,gpu`: a row per configuration and backend, the GPU's rows
/// with where their time went, the CPU's with none; `--default` and `--source` add the default
/// bakes of the grid and of any input (on the CPU here: lavapipe takes ~30 s for each).
#[test]
fn bench_json_rows_cover_both_backends_and_the_default_bakes() {
    let rows_of = |extra: &[&str]| {
        let mut args = vec![
            "bench",
            "--voxels",
            "16",
            "--cells",
            "4",
            "--grid-only",
            "--threads",
            "2",
            "--json",
        ];
        args.extend_from_slice(extra);
        let o = pinbake(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
        v["results"].as_array().unwrap().clone()
    };
    let key = |r: &serde_json::Value| {
        format!(
            "{} | {} | {}",
            r["source"].as_str().unwrap().rsplit('/').next().unwrap(),
            r["bake"].as_str().unwrap(),
            r["backend"].as_str().unwrap()
        )
    };
    let rows = rows_of(&["--backend", "cpu,gpu"]);
    let keys: Vec<String> = rows.iter().map(key).collect();
    assert_eq!(
        keys,
        [
            "noise 16^3 grid | 4^3 x 16x4 | cpu",
            "noise 16^3 grid | 4^3 x 16x4 | gpu"
        ]
    );
    let (cpu, gpu) = (&rows[0], &rows[1]);
    assert!(cpu["gpu"].is_null(), "{cpu}");
    assert_eq!(cpu["pins"], gpu["pins"], "{gpu}");
    assert_eq!(cpu["stored_pins"], gpu["stored_pins"], "{gpu}");
    let g = &gpu["gpu"];
    assert!(g["dispatches"].as_u64().unwrap() >= 1, "{gpu}");
    assert!(!g["adapter"].as_str().unwrap().is_empty(), "{gpu}");
    let parts: f64 = ["device_s", "upload_s", "jobs_s", "dispatch_s"]
        .iter()
        .map(|k| g[k].as_f64().unwrap())
        .sum();
    // The steps are part of the bake's wall time.
    assert!(
        parts > 0.0 && parts <= gpu["wall_s"].as_f64().unwrap(),
        "{gpu}"
    );
    // The mean t_min of the two bakes agrees within docs/gpu.md's per-pin bound.
    let (a, b) = (
        cpu["t_min_mean"].as_f64().unwrap(),
        gpu["t_min_mean"].as_f64().unwrap(),
    );
    assert!((a - b).abs() < 1e-4, "{a} against {b}");

    let smoke = data("openvdb_smoke1.vdb");
    let rows = rows_of(&["--default", "--source", smoke.to_str().unwrap()]);
    let keys: Vec<String> = rows.iter().map(key).collect();
    assert_eq!(
        keys,
        [
            "noise 16^3 grid | 4^3 x 16x4 | cpu",
            "noise 16^3 grid | default | cpu",
            "openvdb_smoke1.vdb | default | cpu"
        ]
    );
    // The default bakes are larger than the 4^3 one.
    assert!(rows[1]["pins"].as_u64() > rows[0]["pins"].as_u64());
}

/// A bake records its source's identity (what `pinrender` checks `--pins` against): the same
/// volume read the same way gives the same identity, another density scale another one.
#[test]
fn bakes_record_the_source_identity() {
    let dir = tempfile::tempdir().unwrap();
    let identity = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        bake_ok("procedural:cosine:seed=2", &out, extra);
        let bytes = std::fs::read(&out).unwrap();
        let file = pin_format::PinFile::parse(&bytes).unwrap();
        let meta = file.metadata().unwrap().unwrap();
        pin_volume::SourceIdentity::from_extra(&meta.extra)
            .expect("identity recorded")
            .unwrap()
    };
    let a = identity("a.pin", &[]);
    assert_eq!(a, identity("b.pin", &["--seed", "9"]));
    let scaled = identity("c.pin", &["--density-scale", "3"]);
    assert!(!a.differences(&scaled).is_empty());
}

/// `--part I/N` bakes merged by `pinbake merge` (any order) are the monolithic bake's bytes
/// for 1, 2, 3 and 5 parts of a VDB (3 of them as parallel processes, as a farm runs them);
/// missing, duplicated, mismatched and damaged parts are refused with one line and exit 1,
/// and no output is left behind.
#[test]
fn parts_merge_into_the_monolithic_bytes_and_bad_parts_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let input = data("openvdb_smoke1.vdb");
    let input = input.to_str().unwrap();
    let whole = dir.path().join("whole.pin");
    bake_ok(input, &whole, &["--seed", "5"]);
    let want = std::fs::read(&whole).unwrap();
    let part_path = |n: u32, i: u32| dir.path().join(format!("p{n}_{i}.part"));
    let part_args = |n: u32, i: u32, seed: &str, out: &Path| {
        let mut a: Vec<String> = [
            "bake",
            input,
            "-o",
            out.to_str().unwrap(),
            "--seed",
            seed,
            "--part",
            &format!("{i}/{n}"),
            "--json",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        a.extend(FAST.iter().map(|s| s.to_string()));
        a
    };
    let merge = |paths: &[PathBuf], out: &Path| {
        let mut a = vec!["merge".to_string()];
        a.extend(paths.iter().map(|p| p.to_str().unwrap().to_string()));
        a.extend(["-o".into(), out.to_str().unwrap().into(), "--json".into()]);
        Command::new(BIN).args(&a).output().unwrap()
    };
    for n in [1u32, 2, 3, 5] {
        if n == 3 {
            let children: Vec<_> = (0..n)
                .map(|i| {
                    Command::new(BIN)
                        .args(part_args(n, i, "5", &part_path(n, i)))
                        .stdout(Stdio::null())
                        .spawn()
                        .unwrap()
                })
                .collect();
            for mut c in children {
                assert!(c.wait().unwrap().success());
            }
        } else {
            for i in 0..n {
                let o = Command::new(BIN)
                    .args(part_args(n, i, "5", &part_path(n, i)))
                    .output()
                    .unwrap();
                assert!(o.status.success(), "{}", stderr(&o));
                let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
                assert_eq!(v["part"]["index"], i);
                assert!(v["samples"].as_u64().unwrap() > 0 || n > 1);
            }
        }
        let paths: Vec<PathBuf> = (0..n).rev().map(|i| part_path(n, i)).collect();
        let out = dir.path().join(format!("merged{n}.pin"));
        let o = merge(&paths, &out);
        assert!(o.status.success(), "{}", stderr(&o));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(v["kind"], "parts");
        assert!(
            std::fs::read(&out).unwrap() == want,
            "{n} parts merged == monolithic bake"
        );
    }

    // Refusals: one line, exit 1, no output.
    let bad = dir.path().join("bad.pin");
    let refused = |paths: &[PathBuf], what: &str| {
        let o = merge(paths, &bad);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{what}: {e}");
        assert_eq!(e.trim_end().lines().count(), 1, "{what}: {e}");
        assert!(!bad.exists(), "{what}: no output");
        e
    };
    let p3: Vec<PathBuf> = (0..3).map(|i| part_path(3, i)).collect();
    let e = refused(&p3[..2], "missing");
    assert!(e.contains("part 2 of 3 is missing"), "{e}");
    let e = refused(
        &[p3[0].clone(), p3[1].clone(), p3[1].clone(), p3[2].clone()],
        "twice",
    );
    assert!(e.contains("given twice"), "{e}");
    let o = Command::new(BIN)
        .args(part_args(3, 1, "6", &dir.path().join("seed6.part")))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let e = refused(
        &[p3[0].clone(), dir.path().join("seed6.part"), p3[2].clone()],
        "mismatched",
    );
    assert!(e.contains("seed6.part") && e.contains("differs"), "{e}");
    let mut damaged = std::fs::read(&p3[1]).unwrap();
    let mid = damaged.len() / 2;
    damaged[mid] ^= 1;
    let dpath = dir.path().join("damaged.part");
    std::fs::write(&dpath, &damaged).unwrap();
    let e = refused(&[p3[0].clone(), dpath.clone(), p3[2].clone()], "damaged");
    assert!(e.contains("damaged.part") && e.contains("checksum"), "{e}");
    std::fs::write(&dpath, &damaged[..mid]).unwrap();
    refused(&[p3[0].clone(), dpath, p3[2].clone()], "truncated");
    let e = refused(&[p3[0].clone(), whole.clone()], "a pin file among parts");
    assert!(e.contains("not a part file"), "{e}");

    // A part bake without named cells and directions is a usage error.
    let o = pinbake(&[
        "bake",
        input,
        "-o",
        dir.path().join("x.part").to_str().unwrap(),
        "--part",
        "0/2",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--cells"), "{}", stderr(&o));
}

/// `pinbake grid-stats` and `bake --part I/N --grid-stats FILE`: parts that skip the leaves
/// outside their slab merge into the monolithic bytes (with a density scale, parts in any
/// order, mixed with parts made without statistics); every bad statistics file or
/// mismatched option is one line, exit 1 (2 for usage), no output; parts made with
/// statistics that lie about a fact that decides the bytes are refused by the merge.
#[test]
fn grid_stats_parts_merge_into_the_monolithic_bytes_and_bad_stats_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = |n: &str| dir.path().join(n);
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let input = data("openvdb_smoke1.vdb");
    let input = input.to_str().unwrap();
    let whole = d("whole.pin");
    bake_ok(input, &whole, &["--density-scale", "0.5"]);
    let want = std::fs::read(&whole).unwrap();
    let stats = d("stats.json");
    let o = pinbake(&[
        "grid-stats",
        input,
        "--density-scale",
        "0.5",
        "-o",
        &s(&stats),
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["format"], "pinbake-grid-stats-1");
    assert!(v["nonzero_leaves"].as_u64().unwrap() > 0);
    let part = |i: u32, n: u32, stats: Option<&Path>, out: &Path| {
        let mut a: Vec<String> = ["bake", input, "-o", &s(out), "--density-scale", "0.5"]
            .iter()
            .map(|x| x.to_string())
            .collect();
        a.extend(["--part".into(), format!("{i}/{n}")]);
        if let Some(st) = stats {
            a.extend(["--grid-stats".into(), s(st)]);
        }
        a.extend(FAST.iter().map(|x| x.to_string()));
        Command::new(BIN)
            .args(&a)
            .stdin(Stdio::null())
            .output()
            .unwrap()
    };
    let merge = |paths: &[PathBuf], out: &Path| {
        let mut a = vec!["merge".to_string()];
        a.extend(paths.iter().map(|p| s(p)));
        a.extend(["-o".into(), s(out)]);
        Command::new(BIN).args(&a).output().unwrap()
    };
    for n in [2u32, 4] {
        let paths: Vec<PathBuf> = (0..n).map(|i| d(&format!("g{n}_{i}.part"))).collect();
        for (i, p) in paths.iter().enumerate() {
            let o = part(i as u32, n, Some(&stats), p);
            assert!(o.status.success(), "{}", stderr(&o));
        }
        let out = d(&format!("merged{n}.pin"));
        let rev: Vec<PathBuf> = paths.iter().rev().cloned().collect();
        let o = merge(&rev, &out);
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(
            std::fs::read(&out).unwrap() == want,
            "{n} parts == monolithic"
        );
    }
    // A part made without statistics is the same part.
    let plain = d("plain_1.part");
    assert!(part(1, 2, None, &plain).status.success());
    assert_eq!(
        std::fs::read(&plain).unwrap(),
        std::fs::read(d("g2_1.part")).unwrap()
    );

    // Bad statistics: one line, exit 1, no output.
    let out = d("refused.part");
    let text = std::fs::read_to_string(&stats).unwrap();
    let edited = |name: &str, from: &str, to: &str| {
        assert!(text.contains(from), "{from} in {text}");
        let p = d(name);
        std::fs::write(&p, text.replacen(from, to, 1)).unwrap();
        p
    };
    let key = |k: &str| {
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        format!("\"{k}\":{}", v[k])
    };
    let cases: Vec<(PathBuf, &str)> = vec![
        (edited("junk.json", "{", "["), "not a grid statistics file"),
        (
            edited(
                "version.json",
                "pinbake-grid-stats-1",
                "pinbake-grid-stats-9",
            ),
            "this version",
        ),
        (
            edited("hash.json", "\"file_xxh3\":\"", "\"file_xxh3\":\"0"),
            "another file",
        ),
        (
            edited("size.json", &key("file_bytes"), "\"file_bytes\":7"),
            "a file of 7 bytes",
        ),
        (
            edited(
                "scale.json",
                &key("density_scale"),
                "\"density_scale\":0.25",
            ),
            "density scale",
        ),
        (
            edited("grid.json", "\"grid\":\"density\"", "\"grid\":\"smoke\""),
            "grid 'smoke'",
        ),
        (
            edited("active.json", &key("active_voxels"), "\"active_voxels\":7"),
            "tree",
        ),
        (
            edited("leaves.json", &key("leaves"), "\"leaves\":1"),
            "damaged",
        ),
        (
            edited("few.json", &key("nonzero_leaves"), "\"nonzero_leaves\":1"),
            "values",
        ),
        (
            edited("max.json", &key("max_value"), "\"max_value\":0.001"),
            "values",
        ),
        (
            edited("unknown.json", "{", "{\"extra\":1,"),
            "not a grid statistics file",
        ),
        (d("missing.json"), "missing.json"),
    ];
    for (p, needle) in &cases {
        let o = part(0, 2, Some(p), &out);
        assert_clean_failure(&o, needle, &out);
    }
    // Statistics with a box larger than the grid's: the part cannot tell (its own voxels
    // lie inside), but its grid description differs, and the merge refuses it among
    // correct parts.
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let hi = v["nonzero_box"][1][0].as_i64().unwrap();
    v["nonzero_box"][1][0] = serde_json::json!(hi + 8);
    let wide = d("wide.json");
    std::fs::write(&wide, serde_json::to_string(&v).unwrap()).unwrap();
    let lying = d("lying_1.part");
    let o = part(1, 2, Some(&wide), &lying);
    assert!(o.status.success(), "{}", stderr(&o));
    let bad = d("bad.pin");
    let o = merge(&[d("g2_0.part"), lying], &bad);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("differs"), "{}", stderr(&o));
    assert!(!bad.exists());

    // Usage: --grid-stats without --part, grid-stats of a raw or procedural input.
    let o = pinbake(&["bake", input, "-o", &s(&out), "--grid-stats", &s(&stats)]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let o = pinbake(&["grid-stats", "procedural:sphere", "-o", &s(&d("p.json"))]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(!d("p.json").exists());
    let o = part(0, 2, Some(&stats), &out);
    assert!(o.status.success());
    std::fs::remove_file(&out).unwrap();
    let o = Command::new(BIN)
        .args(["bake", "procedural:sphere", "-o", &s(&out), "--part", "0/2"])
        .args(["--grid-stats", &s(&stats)])
        .args(FAST)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(!out.exists());
    // The statistics file is never written over the input.
    let o = pinbake(&["grid-stats", input, "-o", input]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
}

/// The section table of a pin file: (kind, offset, length) per entry, from the header's
/// table offset and count.
fn sections_of(b: &[u8]) -> Vec<(u32, usize, usize)> {
    let u32_at = |at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap());
    let u64_at = |at: usize| u64::from_le_bytes(b[at..at + 8].try_into().unwrap()) as usize;
    let (count, table) = (u32_at(16) as usize, u64_at(24));
    (0..count)
        .map(|i| {
            let e = table + 32 * i;
            (u32_at(e), u64_at(e + 8), u64_at(e + 16))
        })
        .collect()
}

/// Rewrites every section, table and header checksum so that a lie reaches the checks
/// behind them.
fn reseal_all(b: &mut [u8]) {
    let table = u64::from_le_bytes(b[24..32].try_into().unwrap()) as usize;
    for (i, (_, off, len)) in sections_of(b).into_iter().enumerate() {
        let c = pin_format::checksum(&b[off..off + len]);
        let at = table + 32 * i + 24;
        b[at..at + 8].copy_from_slice(&c.to_le_bytes());
    }
    let count = u32::from_le_bytes(b[16..20].try_into().unwrap()) as usize;
    let c = pin_format::checksum(&b[table..table + 32 * count]);
    b[48..56].copy_from_slice(&c.to_le_bytes());
    let c = pin_format::checksum(&b[..56]);
    b[56..64].copy_from_slice(&c.to_le_bytes());
}

/// `memory_estimate_bytes` of `pinbake bake INPUT --cells 4 --json` with `extra` flags,
/// written to `out`.
fn memory_estimate(input: &Path, out: &Path, extra: &[&str]) -> u64 {
    let mut args = vec![
        "bake",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--cells",
        "4",
        "--json",
    ];
    args.extend_from_slice(extra);
    let o = pinbake(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    v["memory_estimate_bytes"].as_u64().unwrap()
}

#[test]
fn sparse_embedded_density_bakes_verifies_and_refuses_a_lying_index() {
    let dir = tempfile::tempdir().unwrap();
    let sparse = dir.path().join("sparse.pin");
    let input = data("openvdb_smoke1.vdb");
    bake_ok(
        input.to_str().unwrap(),
        &sparse,
        &["--embed-density", "sparse"],
    );
    // The spool leaves nothing beside the output.
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 1, "{names:?}");
    let o = pinbake(&["verify", sparse.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = pinbake(&["inspect", sparse.to_str().unwrap(), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["version"], "1.1");
    let sd = &v["sparse_density"];
    assert_eq!(sd["brick"], 8);
    assert_eq!(sd["encoding"], "f16");
    let bricks: u64 = (0..3)
        .map(|a| sd["brick_dims"][a].as_u64().unwrap())
        .product();
    let stored = sd["brick_count"].as_u64().unwrap();
    assert!(stored > 0 && stored < bricks, "{stored} of {bricks}");
    // The memory estimate counts the section: its index, one batch of candidate bricks (the
    // smoke's fit in one, so at least its stored bricks) and the spool's 1 MiB buffer; the
    // bricks themselves wait in a spool file, not in memory.
    let est_out = dir.path().join("estimate.pin");
    let estimate = |extra: &[&str]| memory_estimate(&input, &est_out, extra);
    let added = estimate(&["--embed-density", "sparse"]) - estimate(&[]);
    let buffer = 1 << 20;
    assert!(
        added >= 4 * bricks + 1024 * stored + buffer
            && added < 4 * bricks + 1024 * (2 * stored + 256) + buffer,
        "estimate grew by {added} for {stored} of {bricks} bricks"
    );
    // A capped size, and the dense form, which keeps the file 1.0.
    let capped = dir.path().join("capped.pin");
    bake_ok(
        input.to_str().unwrap(),
        &capped,
        &["--embed-density", "sparse:16"],
    );
    let o = pinbake(&["inspect", capped.to_str().unwrap(), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let dims: Vec<u64> = (0..3)
        .map(|a| v["sparse_density"]["dims"][a].as_u64().unwrap())
        .collect();
    assert_eq!(*dims.iter().max().unwrap(), 16, "{dims:?}");
    let dense = dir.path().join("dense.pin");
    bake_ok(input.to_str().unwrap(), &dense, &["--embed-density", "8"]);
    let o = pinbake(&["inspect", dense.to_str().unwrap(), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["version"], "1.0");
    assert!(v.get("sparse_density").is_none());
    for bad in ["sparse:0", "sparse:x", "sparsely", "sparse:1,2"] {
        let o = pinbake(&[
            "bake",
            input.to_str().unwrap(),
            "-o",
            "/dev/null",
            "--embed-density",
            bad,
        ]);
        assert_eq!(o.status.code(), Some(2), "{bad}: {}", stderr(&o));
    }

    // A brick index entry past the stored bricks, with every checksum resealed: the O(1)
    // open accepts the structure, verify names the section and the entry.
    let mut b = std::fs::read(&sparse).unwrap();
    let (_, off, _) = sections_of(&b).into_iter().find(|s| s.0 == 8).unwrap();
    let index_at = off + 32;
    b[index_at..index_at + 4].copy_from_slice(&(stored as u32 + 5).to_le_bytes());
    reseal_all(&mut b);
    let lying = dir.path().join("lying.pin");
    std::fs::write(&lying, &b).unwrap();
    let o = pinbake(&["verify", lying.to_str().unwrap()]);
    let out = dir.path().join("none.pin");
    assert_clean_failure(&o, "sparse-density", &out);
    assert!(stderr(&o).contains("lying.pin"), "{}", stderr(&o));
    // A brick count that disagrees with the section length fails the open itself.
    let mut b = std::fs::read(&sparse).unwrap();
    b[off + 20..off + 24].copy_from_slice(&(stored as u32 - 1).to_le_bytes());
    reseal_all(&mut b);
    std::fs::write(&lying, &b).unwrap();
    let o = pinbake(&["inspect", lying.to_str().unwrap()]);
    assert_clean_failure(&o, "sparse-density", &out);
}

/// `--embed-control` writes the control section (kind 9) and makes the file 1.1; verify
/// passes, and refuses a residual majorant of 0 in a brick that is not empty (checksums
/// resealed); a bad edge is a usage error.
#[test]
fn embedded_control_bakes_and_verifies() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("control.pin");
    let input = data("openvdb_smoke1.vdb");
    bake_ok(input.to_str().unwrap(), &out, &["--embed-control", "8"]);
    let o = pinbake(&["verify", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = pinbake(&["inspect", out.to_str().unwrap(), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["version"], "1.1");
    let b = std::fs::read(&out).unwrap();
    let (_, off, len) = sections_of(&b).into_iter().find(|s| s.0 == 9).unwrap();
    let dims: Vec<usize> = (0..3)
        .map(|a| u32::from_le_bytes(b[off + 4 * a..off + 4 * a + 4].try_into().unwrap()) as usize)
        .collect();
    let n = dims.iter().product::<usize>();
    assert_eq!(len, 16 + 12 * n);
    let f32_at =
        |i: usize| f32::from_le_bytes(b[off + 16 + 4 * i..off + 20 + 4 * i].try_into().unwrap());
    let full = (0..n).find(|&k| f32_at(2 * n + k) > 0.0).unwrap();
    assert!(
        (0..n).any(|k| f32_at(2 * n + k) == 0.0),
        "the smoke has empty bricks"
    );
    // inspect --json describes the section as it is stored.
    let c = &v["control"];
    assert_eq!(c["dims"], serde_json::json!(dims), "{c}");
    assert_eq!(c["bricks"], n as u64);
    assert_eq!(c["bytes"], len as u64);
    let empty = (0..n).filter(|&k| f32_at(n + k) == 0.0).count();
    assert_eq!(c["empty_bricks"], empty as u64);
    // The memory estimate counts the section: 24 bytes per brick at its peak.
    let est_out = dir.path().join("estimate.pin");
    let estimate = |extra: &[&str]| memory_estimate(&input, &est_out, extra);
    assert_eq!(
        estimate(&["--embed-control", "8"]) - estimate(&[]),
        24 * n as u64
    );
    let mut bad = b.clone();
    let at = off + 16 + 4 * (n + full);
    bad[at..at + 4].copy_from_slice(&0f32.to_le_bytes());
    reseal_all(&mut bad);
    let path = dir.path().join("bad.pin");
    std::fs::write(&path, &bad).unwrap();
    let o = pinbake(&["verify", path.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("control"), "{}", stderr(&o));
    for bad in ["0", "65", "x"] {
        let o = pinbake(&[
            "bake",
            input.to_str().unwrap(),
            "-o",
            "/dev/null",
            "--embed-control",
            bad,
        ]);
        assert_eq!(o.status.code(), Some(2), "{bad}: {}", stderr(&o));
    }
}

/// The pins and cell index of a pin file (its metadata names the input, so whole files of
/// inputs under other names differ).
fn pins_of(path: &Path) -> (Vec<pin_format::PinEntry>, Option<Vec<u32>>) {
    let (words, len) = pin_format::input::read_aligned(path).unwrap();
    let bytes = &bytemuck::cast_slice::<u64, u8>(&words)[..len];
    let f = pin_format::PinFile::parse(bytes).unwrap();
    (f.pins().to_vec(), f.cell_index().map(<[u32]>::to_vec))
}

/// A format is recognised by its content (its magic), not its name: an OpenVDB file named
/// `.nvdb` and a NanoVDB file named `.vdb` bake as what they are, to the same pins as under
/// their own names (the first went to the NanoVDB reader, "is not a NanoVDB file").
#[test]
fn formats_are_recognised_by_content_whatever_the_name() {
    use pin_volume::InputKind;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let vdb = data("gaffer_sphere_density.vdb");
    let misnamed_vdb = d.join("sphere.nvdb");
    std::fs::copy(&vdb, &misnamed_vdb).unwrap();
    let nano = crate::nanovdb::file_bytes(
        &crate::nanovdb::Grid::new(
            crate::nanovdb::Type::Float,
            vec![crate::nanovdb::leaf([0, 0, 0], |k| (k % 7) as f32 * 0.25)],
        ),
        0,
    );
    let nvdb = d.join("leaf.nvdb");
    let misnamed_nvdb = d.join("leaf.vdb");
    std::fs::write(&nvdb, &nano).unwrap();
    std::fs::write(&misnamed_nvdb, &nano).unwrap();
    assert_eq!(InputKind::of(&misnamed_vdb), InputKind::Vdb);
    assert_eq!(InputKind::of(&misnamed_nvdb), InputKind::NanoVdb);
    // No magic (a raw file), missing or not regular: the extension decides, so each is
    // refused by the reader its name asks for.
    assert_eq!(InputKind::of(&d.join("missing.nvdb")), InputKind::NanoVdb);
    assert_eq!(InputKind::of(&d.join("missing.vdb")), InputKind::Vdb);
    assert_eq!(
        InputKind::of(&data("water_esp_31x34x33_float32.raw")),
        InputKind::Raw
    );
    for (right, wrong) in [(&vdb, &misnamed_vdb), (&nvdb, &misnamed_nvdb)] {
        let (a, b) = (d.join("right.pin"), d.join("wrong.pin"));
        bake_ok(right.to_str().unwrap(), &a, &[]);
        bake_ok(wrong.to_str().unwrap(), &b, &[]);
        assert_eq!(pins_of(&a), pins_of(&b), "{}", wrong.display());
    }
}

/// A GPU flag with the CPU backend is a usage error (it was ignored silently).
#[test]
fn a_gpu_slab_budget_needs_the_gpu_backend() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.pin");
    let o = pinbake(&[
        "bake",
        "procedural:box",
        "-o",
        out.to_str().unwrap(),
        "--gpu-slab-bytes",
        "1M",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert_eq!(stderr(&o).trim_end().lines().count(), 1, "{}", stderr(&o));
    assert!(
        stderr(&o).contains("--gpu-slab-bytes applies to --backend gpu"),
        "{}",
        stderr(&o)
    );
    assert!(!out.exists());
}
