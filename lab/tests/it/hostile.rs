//! Hostile and careless use of the `pinrender` binary (`docs/stability.md` "Hostile
//! use"): outputs that are devices, FIFOs, symlinks to them or an input; special files as
//! input; non-UTF-8 arguments; sizes beyond memory; out-of-range values (exit 2, before any
//! rendering); the private bench cache; silently ignored flags. Each case checks the exit
//! code, a one-line stderr, bounded time, and that nothing was damaged.

use std::ffi::{OsStr, OsString};
use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::{FileTypeExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Instant;

#[path = "hostile/budget.rs"]
mod budget;
#[path = "hostile/outputs.rs"]
mod outputs;
#[path = "hostile/sections.rs"]
mod sections;

const BIN: &str = env!("CARGO_BIN_EXE_pinrender");
const MAX_SECONDS: f64 = 20.0;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(name)
}

struct Run {
    out: Output,
    seconds: f64,
}

impl Run {
    fn stderr(&self) -> String {
        String::from_utf8_lossy(&self.out.stderr).into_owned()
    }
}

/// A child's private cache home (`XDG_CACHE_HOME`): pinrender's own caches (bench, pipeline
/// cache) go there, untouched by the user's. Mesa's shader cache, which follows
/// `XDG_CACHE_HOME` too, stays the one this test binary uses (`$MESA_SHADER_CACHE_DIR`, else
/// Mesa's default under `$XDG_CACHE_HOME` or `~/.cache`; Mesa adds `mesa_shader_cache`), so
/// that a GPU pipeline one test's renders compiled is not compiled again, for seconds on
/// lavapipe, by every other test's: the driver's cache is no behaviour of pinrender's.
trait PrivateCache {
    fn private_cache(&mut self, home: &Path) -> &mut Self;
}

impl PrivateCache for Command {
    fn private_cache(&mut self, home: &Path) -> &mut Self {
        let nonempty = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty());
        if nonempty("MESA_SHADER_CACHE_DIR").is_none()
            && let Some(base) = nonempty("XDG_CACHE_HOME")
                .map(PathBuf::from)
                .or_else(|| nonempty("HOME").map(|h| PathBuf::from(h).join(".cache")))
        {
            self.env("MESA_SHADER_CACHE_DIR", base);
        }
        self.env("XDG_CACHE_HOME", home)
    }
}

/// Runs pinrender with a private cache home and runtime dir, killed after 60 s (a FIFO that
/// blocked an open would otherwise hang the suite).
fn run_env(args: &[OsString], cache_home: &Path) -> Run {
    let t = Instant::now();
    let out = Command::new("timeout")
        .args(["-s", "KILL", "60"])
        .arg(BIN)
        .args(args)
        .private_cache(cache_home)
        .env("XDG_RUNTIME_DIR", cache_home)
        .stdin(Stdio::null())
        .output()
        .expect("run pinrender");
    Run {
        out,
        seconds: t.elapsed().as_secs_f64(),
    }
}

fn os(args: &[&str]) -> Vec<OsString> {
    args.iter().map(OsString::from).collect()
}

fn run(args: &[&str], home: &Path) -> Run {
    run_env(&os(args), home)
}

/// Exit `code`, one stderr line `pinrender: error: ...` containing `needle`, in bounded time.
fn expect(name: &str, r: &Run, code: i32, needle: &str) {
    let err = r.stderr();
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(r.out.status.code(), Some(code), "{name}: {err}");
    assert_eq!(lines.len(), 1, "{name}: not one line: {err:?}");
    assert!(
        lines[0].starts_with("pinrender: error: "),
        "{name}: {err:?}"
    );
    assert!(
        lines[0].contains(needle),
        "{name}: {err:?} lacks {needle:?}"
    );
    assert!(!err.contains("panicked"), "{name}: {err}");
    assert!(r.seconds < MAX_SECONDS, "{name}: {} s", r.seconds);
}

fn mkfifo(path: &Path) {
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
    // SAFETY: a valid C string; creates a FIFO in our temp dir.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

/// A fast render of the procedural box.
fn render_args(out: &Path) -> Vec<String> {
    [
        "render",
        "--volume",
        "procedural:box",
        "--width",
        "8",
        "--height",
        "8",
        "--spp",
        "1",
        "--out",
    ]
    .iter()
    .map(|s| s.to_string())
    .chain([out.to_str().unwrap().to_string()])
    .collect()
}

fn strs(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

#[test]
fn render_outputs_only_to_regular_files_or_new_paths() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let input = d.join("w_31x34x33_f32.raw");
    std::fs::copy(data("water_esp_31x34x33_float32.raw"), &input).unwrap();
    let input_bytes = std::fs::read(&input).unwrap();
    let fifo = d.join("fifo.exr");
    mkfifo(&fifo);
    let link = |name: &str, to: &Path| {
        let p = d.join(name);
        std::os::unix::fs::symlink(to, &p).unwrap();
        p
    };
    let to_null = link("to_null.exr", Path::new("/dev/null"));
    let to_stdout = link("to_stdout.png", Path::new("/proc/self/fd/1"));
    // The PNG beside the EXR is checked too.
    let png_fifo = d.join("img.png");
    mkfifo(&png_fifo);
    let cases: [(&Path, &str); 5] = [
        (&fifo, "fifo.exr: not a regular file"),
        (&to_null, "to_null.exr: not a regular file"),
        (&to_stdout, "to_stdout.png: not a regular file"),
        (&d.join("img.exr"), "img.png: not a regular file"),
        (d, "is a directory"),
    ];
    for (out, needle) in cases {
        let args = render_args(out);
        expect(
            &format!("render --out {}", out.display()),
            &run(&strs(&args), d),
            1,
            needle,
        );
    }
    let mut args = render_args(&input);
    args[2] = input.to_str().unwrap().to_string();
    expect(
        "render --out INPUT",
        &run(&strs(&args), d),
        1,
        "is the input file",
    );
    assert_eq!(std::fs::read(&input).unwrap(), input_bytes);
    assert!(
        std::fs::symlink_metadata(&fifo)
            .unwrap()
            .file_type()
            .is_fifo()
    );
    assert!(
        std::fs::symlink_metadata(&png_fifo)
            .unwrap()
            .file_type()
            .is_fifo()
    );
    assert_eq!(
        std::fs::read_link(&to_null).unwrap(),
        Path::new("/dev/null")
    );
    assert!(!d.join("img.exr").exists());

    // --out x.png writes the PNG only (it used to write an EXR there, then overwrite it).
    let png = d.join("only.png");
    let r = run(&strs(&render_args(&png)), d);
    assert_eq!(r.out.status.code(), Some(0), "{}", r.stderr());
    assert_eq!(&std::fs::read(&png).unwrap()[1..4], b"PNG");
    let r = run(&strs(&render_args(&d.join("both.exr"))), d);
    assert_eq!(r.out.status.code(), Some(0), "{}", r.stderr());
    assert!(d.join("both.exr").exists() && d.join("both.png").exists());
}

#[test]
fn special_files_as_input_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("o.exr");
    let fifo_raw = d.join("pipe_2x2x2_u8.raw");
    mkfifo(&fifo_raw);
    let fifo_pin = d.join("pipe.pin");
    mkfifo(&fifo_pin);
    for (volume, needle) in [
        (fifo_raw.as_path(), "not a regular file"),
        (Path::new("/dev/zero"), "/dev/zero: not a regular file"),
        (d, "is a directory"),
    ] {
        let mut args = render_args(&out);
        args[2] = volume.to_str().unwrap().to_string();
        expect(
            &format!("--volume {}", volume.display()),
            &run(&strs(&args), d),
            1,
            needle,
        );
    }
    for (pins, needle) in [
        (fifo_pin.as_path(), "pipe.pin: not a regular file"),
        (d, "is a directory"),
    ] {
        let mut args = render_args(&out);
        args.extend(["--estimator", "pins", "--pins", pins.to_str().unwrap()].map(String::from));
        expect(
            &format!("--pins {}", pins.display()),
            &run(&strs(&args), d),
            1,
            needle,
        );
        let r = run(
            &[
                "bench",
                "--no-gpu",
                "--volume",
                "procedural:box",
                "--rays",
                "10",
                "--pins",
                pins.to_str().unwrap(),
            ],
            d,
        );
        expect("bench --pins", &r, 1, needle);
    }
    assert!(!out.exists());
}

#[test]
fn non_utf8_arguments_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let bad = OsStr::from_bytes(b"\xff.raw");
    let mut cases: Vec<(Vec<OsString>, i32)> = Vec::new();
    let mut a = os(&["render", "--out", "o.exr", "--volume"]);
    a.push(bad.into());
    cases.push((a, 1));
    let mut a = os(&[
        "render",
        "--volume",
        "procedural:box",
        "--out",
        "o.exr",
        "--estimator",
    ]);
    a.push(bad.into());
    cases.push((a, 2));
    let mut a = os(&["bench", "--no-gpu", "--volume"]);
    a.push(bad.into());
    cases.push((a, 1));
    let mut a = os(&["eval", "--no-gpu", "--scenes"]);
    a.push(bad.into());
    cases.push((a, 2));
    for (args, code) in &cases {
        expect(&format!("{args:?}"), &run_env(args, d), *code, "");
    }
    // A non-UTF-8 output path is a path like any other.
    let out = d.join(OsStr::from_bytes(b"\xff.png"));
    let mut a: Vec<OsString> = render_args(Path::new("x"))
        .into_iter()
        .map(OsString::from)
        .collect();
    *a.last_mut().unwrap() = out.clone().into();
    let r = run_env(&a, d);
    assert_eq!(r.out.status.code(), Some(0), "{}", r.stderr());
    assert!(out.exists());
}

#[test]
fn sizes_beyond_memory_fail_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("o.exr");
    let cases: &[(&[&str], i32, &str)] = &[
        (&["--width", "32768", "--height", "32768"], 2, "1..=16384"),
        (
            &["--width", "16384", "--height", "16384"],
            1,
            "memory budget",
        ),
        (
            &["--estimator", "pinms", "--pin-cells", "1000"],
            1,
            "memory budget",
        ),
        (
            &["--estimator", "pins", "--pin-cells", "300"],
            1,
            "memory budget",
        ),
        (&["--majorant-bricks", "1024"], 1, "memory budget"),
        (&["--majorant-bricks", "5000"], 2, "1..=1024"),
        (&["--pin-cells", "5000"], 2, "1..=4096"),
    ];
    for (extra, code, needle) in cases {
        // 2G keeps the limit machine-independent (the default is half the physical memory).
        let mut args = vec![
            "render",
            "--volume",
            "procedural:box",
            "--out",
            out.to_str().unwrap(),
            "--max-memory",
            "2G",
        ];
        args.extend(*extra);
        expect(&format!("render {extra:?}"), &run(&args, d), *code, needle);
    }
    let r = run(
        &[
            "bench",
            "--no-gpu",
            "--rays",
            "100000000",
            "--max-memory",
            "2G",
        ],
        d,
    );
    expect("bench --rays 1e8", &r, 1, "memory budget");
    let r = run(
        &["bench", "--no-gpu", "--cells", "1000", "--max-memory", "2G"],
        d,
    );
    expect("bench --cells 1000", &r, 1, "memory budget");
    // The default 37^3 bake's output (208 MB) fits in 250M; with its layered march's
    // working set (109 MB, once left out) it does not.
    let r = run(&["bench", "--no-gpu", "--max-memory", "250M"], d);
    expect("bench working set", &r, 1, "memory budget");
    assert!(!out.exists());
}

#[test]
fn out_of_range_values_are_usage_errors_before_rendering() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("o.exr");
    let raw = data("water_esp_31x34x33_float32.raw");
    let vdb = data("openvdb_smoke1.vdb");
    // A render that would take minutes: a usage error must come before it.
    let slow = ["--width", "512", "--height", "512", "--spp", "100000"];
    let cases: &[(&str, &[&str], &str)] = &[
        ("procedural:box", &["--exposure", "nan"], "--exposure"),
        ("procedural:box", &["--exposure", "0"], "--exposure"),
        ("procedural:box", &["--estimator", "rm@1e-12"], "[1e-5, 1]"),
        ("procedural:box", &["--estimator", "rm@0"], "[1e-5, 1]"),
        (
            "procedural:box",
            &["--estimator", "nosuch"],
            "unknown estimator",
        ),
        ("procedural:box", &["--threads", "10000"], "--threads"),
        ("procedural:box", &["--threads", "0"], "--threads"),
        (
            "procedural:box",
            &["--density-scale", "nan"],
            "--density-scale",
        ),
        ("procedural:box", &["--spp", "0"], "--spp"),
        ("procedural:box", &["--seconds", "nan"], "--seconds"),
        (
            "procedural:box",
            &["--sun-radiance", "inf"],
            "--sun-radiance",
        ),
        ("procedural:box", &["--fov", "nan"], "--fov"),
        ("procedural:box", &["--max-memory", "0"], "--max-memory"),
        ("procedural:box", &["--dims", "4"], "--dims does not apply"),
        (raw.to_str().unwrap(), &["--spacing", "1e153"], "1e153"),
        (
            raw.to_str().unwrap(),
            &["--grid", "density"],
            "--grid does not apply to a raw volume",
        ),
        (
            vdb.to_str().unwrap(),
            &["--dims", "4"],
            "--dims does not apply to an OpenVDB volume",
        ),
    ];
    for (volume, extra, needle) in cases {
        let mut args = vec!["render", "--volume", volume, "--out", out.to_str().unwrap()];
        args.extend(slow);
        args.extend(*extra);
        expect(
            &format!("render {volume} {extra:?}"),
            &run(&args, d),
            2,
            needle,
        );
    }
    let r = run(&["render", "--out", out.to_str().unwrap()], d);
    expect("no --volume", &r, 2, "--volume");
    assert!(!out.exists());
    for extra in [
        &["--rays", "0"][..],
        &["--cells", "0"][..],
        &["--rays=-5"][..],
    ] {
        let mut args = vec!["bench", "--no-gpu"];
        args.extend(extra);
        expect(&format!("bench {extra:?}"), &run(&args, d), 2, "");
    }
    let ev = d.join("ev");
    let e = ev.to_str().unwrap();
    for (extra, needle) in [
        (
            &["--estimators", "nosuch"][..],
            "unknown estimator 'nosuch'",
        ),
        (&["--estimators", "rm@1e-9"][..], "rm@STEP"),
        (&["--scenes", "nosuch"][..], "unknown scene"),
        (&["--threads", "10000"][..], "--threads"),
        (&["--budgets", "nan"][..], "--budgets"),
    ] {
        let mut args = vec!["eval", "--quick", "--no-gpu", "--out", e];
        args.extend(extra);
        expect(&format!("eval {extra:?}"), &run(&args, d), 2, needle);
    }
    assert!(!ev.exists());
    // eval --out must be a directory: a FIFO there is refused, not opened.
    let fifo = d.join("fifo");
    mkfifo(&fifo);
    let r = run(
        &[
            "eval",
            "--quick",
            "--no-gpu",
            "--out",
            fifo.to_str().unwrap(),
        ],
        d,
    );
    expect("eval --out FIFO", &r, 1, "not a directory");
    // A symlink to a device planted in the output folder is refused, not written through.
    std::fs::create_dir(&ev).unwrap();
    std::os::unix::fs::symlink("/dev/null", ev.join("report.md")).unwrap();
    let r = run(&["eval", "--quick", "--no-gpu", "--out", e], d);
    expect(
        "eval --out with a planted link",
        &r,
        1,
        "report.md: not a regular file",
    );
    assert!(
        std::fs::symlink_metadata(ev.join("report.md"))
            .unwrap()
            .is_symlink()
    );
}

#[test]
fn bench_cache_is_private_and_verified() {
    let dir = tempfile::tempdir().unwrap();
    let home = dir.path();
    let args = [
        "bench",
        "--no-gpu",
        "--json",
        "--volume",
        "procedural:box",
        "--cells",
        "4",
        "--rays",
        "64",
    ];
    let r = run(&args, home);
    assert_eq!(r.out.status.code(), Some(0), "{}", r.stderr());
    let cache = home.join("pinbake");
    let mode = std::fs::metadata(&cache).unwrap().permissions().mode();
    assert_eq!(mode & 0o777, 0o700, "cache dir mode {mode:o}");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&cache)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    // The `--cells` bake and the volume's default bake.
    assert_eq!(files.len(), 2, "{files:?}");
    for file in &files {
        let cached = std::fs::read(file).unwrap();
        // A planted (here: garbage) file at the cache path is not used: it is rebaked.
        std::fs::write(file, b"planted").unwrap();
        let r = run(&args, home);
        assert_eq!(r.out.status.code(), Some(0), "{}", r.stderr());
        assert_eq!(r.stderr().matches("baking").count(), 1, "{}", r.stderr());
        assert_eq!(&std::fs::read(file).unwrap(), &cached, "{}", file.display());
    }
    // A second run reuses the good file without baking.
    let r = run(&args, home);
    assert!(!r.stderr().contains("baking"), "{}", r.stderr());
    // A cache directory others can write is refused.
    std::fs::set_permissions(&cache, std::fs::Permissions::from_mode(0o777)).unwrap();
    let r = run(&args, home);
    expect("world-writable cache", &r, 1, "not a private directory");
}

/// `--pins` is refused where it would be ignored (an estimator without pins) and where it
/// would render wrongly (a tile of a farm bake, which covers only its slab of cells).
#[test]
fn pins_that_cannot_serve_the_render_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let home = dir.path();
    let out = dir.path().join("img.exr");
    let tile = dir.path().join("tile.pin");
    // A 2-tile bake's first tile, written with the library (no pinbake binary in this crate).
    let spec: pin_volume::ProceduralSpec = "box".parse().unwrap();
    let src = pin_volume::open_source(
        &pin_volume::SourceSpec::Procedural(spec),
        pin_volume::DensityScale::ONE,
    )
    .unwrap();
    let opts = pinbake::BakeOptions {
        cells: [4; 3],
        tile: Some(pinbake::Tile { index: 0, count: 2 }),
        ..pinbake::BakeOptions::default()
    };
    let (grid, _) = pinbake::bake(src.as_ref(), &opts, &|_| {}).unwrap();
    std::fs::write(&tile, grid.to_bytes().unwrap()).unwrap();

    let mut args = render_args(&out);
    args.extend(["--estimator", "ratio", "--pins"].map(String::from));
    args.push("/nonexistent.pin".into());
    expect(
        "--pins with ratio",
        &run(&strs(&args), home),
        2,
        "--pins is used only by",
    );
    let mut args = render_args(&out);
    args.extend(["--estimator", "pins", "--pins"].map(String::from));
    args.push(tile.to_str().unwrap().into());
    expect(
        "a tile as --pins",
        &run(&strs(&args), home),
        1,
        "pinbake merge",
    );
    assert!(!out.exists());
}

/// A tiny render with `--reference` (a reference rendered first into `d`) whose standard
/// output is `stdout`: the output, and the image path it writes.
fn reference_render_into(d: &Path, stdout: impl Into<Stdio>) -> (Output, PathBuf) {
    let reference = d.join("ref.exr");
    let r = run(&strs(&render_args(&reference)), d);
    assert_eq!(r.out.status.code(), Some(0), "{}", r.stderr());
    let out = d.join("o.exr");
    let mut args = render_args(&out);
    args.extend(["--reference".to_string(), reference.display().to_string()]);
    let o = Command::new(BIN)
        .args(&args)
        .private_cache(d)
        .env("XDG_RUNTIME_DIR", d)
        .stdin(Stdio::null())
        .stdout(stdout)
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    (o, out)
}

/// A render whose summary line goes to a pipe that nobody reads any more (`pinrender render
/// ... --reference R | head -c 1` after `head` exited): the process ends quietly at that
/// write, killed by SIGPIPE as other Unix filters are, with its image already written;
/// before, `println!` panicked ("failed printing to stdout", exit 101).
#[test]
fn a_closed_stdout_ends_the_process_quietly() {
    use std::os::unix::process::ExitStatusExt;
    let dir = tempfile::tempdir().unwrap();
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let (o, out) = reference_render_into(dir.path(), writer);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(
        o.status.signal(),
        Some(libc::SIGPIPE),
        "{:?}: {stderr}",
        o.status
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(out.exists() && out.with_extension("png").exists());
}

/// `> /dev/full`: the `--reference` line cannot be written. One error line naming standard
/// output, exit 1 (the image is written before it); before, `println!` panicked (exit 101).
/// `2> /dev/full`: the error line is lost, the exit code is not (1 for a bad file, 2 for a
/// bad flag); before, `eprintln!` panicked (exit 101).
#[test]
fn a_full_stderr_keeps_the_exit_code() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.vdb");
    let out = dir.path().join("x.exr");
    for (args, code) in [
        (
            vec![
                "render",
                "--volume",
                missing.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ],
            1,
        ),
        (vec!["render", "--bogus-flag"], 2),
    ] {
        let full = dev_full();
        let status = Command::new(BIN)
            .args(&args)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(full)
            .status()
            .unwrap();
        assert_eq!(status.code(), Some(code), "{args:?}: {status:?}");
    }
    assert!(!out.exists());
}

#[test]
fn a_full_stdout_is_an_error_line() {
    let dir = tempfile::tempdir().unwrap();
    let full = dev_full();
    let (o, _) = reference_render_into(dir.path(), full);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    let last = stderr.lines().last().unwrap_or("");
    assert!(
        last.starts_with("pinrender: error: standard output: No space left on device"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
}

/// `/dev/full` opened for writing: every write fails with "No space left on device".
fn dev_full() -> std::fs::File {
    std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap()
}

/// The resident-memory high-water mark of a running process, in bytes.
fn peak_rss(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let line = status.lines().find(|l| l.starts_with("VmHWM:")).unwrap();
    let kb: u64 = line.split_whitespace().nth(1).unwrap().parse().unwrap();
    kb * 1024
}

/// The sample buffers of the batched (pins) loop do not grow with `--spp`: a render of
/// 2^32 - 1 samples per pixel aborted at once asking for 64 GiB, and `--spp 8192` over 2048
/// pixels peaked at 466 MB under `--max-memory 100M`. Both now render along in bounded
/// memory (killed after three seconds); the second runs at 2^20 samples per pixel, so that it
/// is still rendering then (8192 finish in about 1.5 s).
#[test]
fn sample_buffers_stay_bounded_whatever_the_samples_per_pixel() {
    let dir = tempfile::tempdir().unwrap();
    for (spp, width) in [("4294967295", "1"), ("1048576", "2048")] {
        let out = dir.path().join(format!("spp{spp}.png"));
        let mut child = Command::new(BIN)
            .args([
                "render",
                "--volume",
                "procedural:cosine",
                "--estimator",
                "pins",
                "--pin-cells",
                "8",
                "--spp",
                spp,
                "--width",
                width,
                "--height",
                "1",
                "--max-memory",
                "100M",
                "--out",
                out.to_str().unwrap(),
            ])
            .stdin(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_secs(3));
        let still_running = child.try_wait().unwrap().is_none();
        let peak = if still_running {
            peak_rss(child.id())
        } else {
            0
        };
        let _ = child.kill();
        let o = child.wait_with_output().unwrap();
        assert!(
            still_running,
            "--spp {spp}: ended early: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(
            peak < 100 << 20,
            "--spp {spp} --width {width}: peak RSS {peak} bytes"
        );
        assert!(!out.exists(), "no image from a killed render");
    }
}
