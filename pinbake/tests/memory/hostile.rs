//! Hostile input through the `pinbake` binary (docs/background.md section 3, docs/stability.md "Hostile use"):
//! every damaged VDB of `data/oiio_damaged` through `bake`, damaged NanoVDB files (generated
//! from a valid one: truncated, lying sizes, offsets and counts, bad magic, unknown version
//! and codec, BLOSC, huge declared grids), and generated corrupt
//! pin files (truncated, flipped, lying header) through `verify` and `inspect`. Each must
//! give a one-line error and exit code 1 within generous bounds on peak RSS (wait4's
//! ru_maxrss, which includes the isolated VDB worker) and wall time. Prints the table that
//! `docs/stability.md` quotes (`-- --nocapture`).
//!
//! Then hostile and careless use (`docs/stability.md` "Hostile use"): outputs that
//! are devices, FIFOs, symlinks to them or the input itself; special files as input;
//! non-UTF-8 arguments; sizes beyond memory; out-of-range values (exit 2); signals during a
//! bake. Each checks the exit code, a one-line stderr, bounded time and memory, and that
//! nothing was damaged.

mod budget;
mod farm;
mod python_twins;

use crate::{nanovdb, openvdb};

use std::ffi::{OsStr, OsString};
use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use glam::DVec3;
use pin_format::{Directions, checksum};
use pin_volume::{Aabb, HomogeneousBox};
use pinbake::{BakeOptions, bake};

const BIN: &str = env!("CARGO_BIN_EXE_pinbake");
const MAX_RSS_KIB: i64 = 256 * 1024;
const MAX_SECONDS: f64 = 10.0;

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(name)
}

struct Run {
    code: Option<i32>,
    /// The signal that ended the process, if one did.
    signal: Option<i32>,
    stderr: String,
    rss_kib: i64,
    seconds: f64,
}

fn run(args: &[&str]) -> Run {
    let args: Vec<&OsStr> = args.iter().map(OsStr::new).collect();
    run_os(&args, Duration::from_secs(60))
}

/// Runs the binary and reaps it with `wait4` to get its own peak RSS (children included).
/// A process still running after `limit` is killed (the test then fails on its time): a
/// FIFO that blocks an open must not hang the suite.
#[allow(clippy::zombie_processes)] // reaped by wait4 below, which std cannot see
fn run_os(args: &[&OsStr], limit: Duration) -> Run {
    let started = Instant::now();
    let child = Command::new(BIN)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id() as libc::pid_t;
    let mut pipe = child.stderr.unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = Vec::new();
        use std::io::Read;
        let _ = pipe.read_to_end(&mut s);
        String::from_utf8_lossy(&s).into_owned()
    });
    let mut status = 0;
    // SAFETY: an all-zero rusage is a valid value; wait4 reaps our own child.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    loop {
        let r = unsafe { libc::wait4(pid, &mut status, libc::WNOHANG, &mut ru) };
        if r == pid {
            break;
        }
        assert_eq!(r, 0, "wait4 failed");
        if started.elapsed() > limit {
            // SAFETY: our own child, not yet reaped.
            unsafe { libc::kill(pid, libc::SIGKILL) };
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    Run {
        code: libc::WIFEXITED(status).then(|| libc::WEXITSTATUS(status)),
        signal: libc::WIFSIGNALED(status).then(|| libc::WTERMSIG(status)),
        stderr: reader.join().unwrap(),
        rss_kib: ru.ru_maxrss,
        seconds: started.elapsed().as_secs_f64(),
    }
}

fn check(name: &str, r: &Run, table: &mut Vec<String>) {
    let lines: Vec<&str> = r.stderr.lines().collect();
    table.push(format!(
        "| {name} | {:?} | {} | {:.2} | `{}` |",
        r.code,
        r.rss_kib / 1024,
        r.seconds,
        lines
            .first()
            .copied()
            .unwrap_or("")
            .chars()
            .take(140)
            .collect::<String>()
            .replace('|', "\\|")
    ));
    assert_eq!(
        r.code,
        Some(1),
        "{name}: exit {:?}, stderr {:?}",
        r.code,
        r.stderr
    );
    assert_eq!(lines.len(), 1, "{name}: not one line: {:?}", r.stderr);
    assert!(
        lines[0].starts_with("pinbake: error: "),
        "{name}: {:?}",
        lines[0]
    );
    assert!(
        r.rss_kib < MAX_RSS_KIB,
        "{name}: peak RSS {} KiB",
        r.rss_kib
    );
    assert!(r.seconds < MAX_SECONDS, "{name}: {} s", r.seconds);
}

fn valid_pin(dir: &Path) -> Vec<u8> {
    let src = HomogeneousBox::new(Aabb::new(DVec3::ZERO, DVec3::ONE), 1.5).unwrap();
    let opts = BakeOptions {
        cells: [4, 4, 4],
        directions: Directions::Octahedral { n: 2 },
        step: 0.05,
        threads: Some(1),
        majorant: Some([2, 2, 2]),
        ..BakeOptions::default()
    };
    let (owned, _) = bake(&src, &opts, &|_| {}).unwrap();
    let bytes = owned.to_bytes().unwrap();
    std::fs::write(dir.join("valid.pin"), &bytes).unwrap();
    bytes
}

fn put_u64(b: &mut [u8], at: usize, v: u64) {
    b[at..at + 8].copy_from_slice(&v.to_le_bytes());
}

/// Re-seals the header checksum so that a lie gets past it to the structural checks.
fn reseal(b: &mut [u8]) {
    let c = checksum(&b[..56]);
    put_u64(b, 56, c);
}

/// The corrupt pin files: (name, bytes).
fn corrupt_pins(valid: &[u8]) -> Vec<(&'static str, Vec<u8>)> {
    let n = valid.len();
    let mut v = vec![
        ("empty file", Vec::new()),
        ("63 bytes (header cut)", valid[..63].to_vec()),
        ("truncated to half", valid[..n / 2].to_vec()),
        ("last byte cut", valid[..n - 1].to_vec()),
        ("one byte appended", [valid, &[0]].concat()),
        ("not a pin file (raw voxels)", vec![7u8; 4096]),
    ];
    let mut flip = |name, at: usize| {
        let mut b = valid.to_vec();
        b[at] ^= 0x40;
        v.push((name, b));
    };
    flip("flipped magic byte", 1);
    flip("flipped header byte (section count)", 16);
    flip("flipped byte in the first section", 64 + 3);
    flip("flipped byte mid-file (pins)", n / 2);
    flip("flipped byte in the section table", n - 20);
    let mut lie = |name, at: usize, val: u64| {
        let mut b = valid.to_vec();
        put_u64(&mut b, at, val);
        reseal(&mut b);
        v.push((name, b));
    };
    lie(
        "lying header: file_size 2^62 (checksum resealed)",
        32,
        1 << 62,
    );
    lie(
        "lying header: table_offset past the end (resealed)",
        24,
        1 << 40,
    );
    lie(
        "lying header: section_count 1024, entry size 4096 (resealed)",
        16,
        (4096u64 << 32) | 1024,
    );
    lie("lying header: version 2.0 (resealed)", 8, {
        let old = u64::from_le_bytes(valid[8..16].try_into().unwrap());
        (old & !0xffff_ffff) | 2
    });
    v
}

#[test]
fn hostile_inputs_fail_in_one_line_with_bounded_memory_and_time() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("never.pin");
    let mut table = vec![
        "| input | command | exit | peak RSS MiB | s | message |".to_string(),
        "|---|---|---|---|---|---|".to_string(),
    ];
    let mut rows = Vec::new();
    let mut damaged: Vec<PathBuf> = std::fs::read_dir(data("oiio_damaged"))
        .expect("data/oiio_damaged")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "vdb"))
        .collect();
    damaged.sort();
    assert_eq!(damaged.len(), 7);
    for p in &damaged {
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        let r = run(&[
            "bake",
            p.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--cells",
            "4",
        ]);
        check(&format!("{name} | bake"), &r, &mut rows);
        assert!(r.stderr.contains(&name));
        assert!(!out.exists(), "{name}: an output file appeared");
    }
    let valid = valid_pin(dir.path());
    let ok = run(&["verify", dir.path().join("valid.pin").to_str().unwrap()]);
    assert_eq!(ok.code, Some(0), "the valid file verifies: {}", ok.stderr);
    for (i, (name, bytes)) in corrupt_pins(&valid).into_iter().enumerate() {
        let path = dir.path().join(format!("corrupt{i}.pin"));
        std::fs::write(&path, &bytes).unwrap();
        let r = run(&["verify", path.to_str().unwrap()]);
        check(&format!("{name} | verify"), &r, &mut rows);
        // `inspect` is the O(1) structural open: data damage behind a valid structure (a
        // flipped pin byte) is only caught by `verify`, so inspect may succeed there.
        let r = run(&["inspect", path.to_str().unwrap()]);
        let data_only = name.contains("first section") || name.contains("mid-file");
        if data_only && r.code == Some(0) {
            rows.push(format!("| {name} | inspect | Some(0) | {} | {:.2} | (structure intact; damage is in checksummed data, caught by verify) |", r.rss_kib / 1024, r.seconds));
        } else {
            check(&format!("{name} | inspect"), &r, &mut rows);
        }
    }
    table.extend(rows);
    eprintln!("\n{}", table.join("\n"));
}

/// A valid NanoVDB file and damaged copies of it, each with a word its error must contain.
fn damaged_nanovdbs() -> Vec<(&'static str, Vec<u8>, &'static str)> {
    use nanovdb::{Grid, Type, file_bytes, grid_bytes, grid_offset, leaf};
    let g = Grid::new(
        Type::Float,
        vec![
            leaf([0, 0, 0], |k| k as f32 * 0.01),
            leaf([8, 0, 0], |k| 1.0 + k as f32 * 0.01),
        ],
    );
    let valid = file_bytes(&g, 0);
    let (_, lay) = grid_bytes(&g);
    let go = grid_offset(&g.name);
    let set = |at: usize, bytes: &[u8]| {
        let mut f = valid.clone();
        f[at..at + bytes.len()].copy_from_slice(bytes);
        f
    };
    let mut cases = vec![
        ("empty file", Vec::new(), "empty"),
        ("truncated header", valid[..12].to_vec(), "past the end"),
        ("truncated metadata", valid[..100].to_vec(), "past the end"),
        (
            "truncated grid",
            valid[..go + 5000].to_vec(),
            "past the end",
        ),
        (
            "truncated last leaf",
            valid[..valid.len() - 100].to_vec(),
            "past the end",
        ),
        ("bad magic", set(0, b"NanoVDBX"), "not a NanoVDB file"),
        (
            "unknown version",
            set(8, &((40u32 << 21) | (1 << 10)).to_le_bytes()),
            "NanoVDB 40.1.0",
        ),
        (
            "unknown codec",
            set(14, &7u16.to_le_bytes()),
            "unknown codec 7",
        ),
        ("BLOSC codec", set(14, &2u16.to_le_bytes()), "BLOSC"),
        (
            "lying grid size",
            set(16, &(u64::MAX / 2).to_le_bytes()),
            "stores",
        ),
        (
            "lying stored size",
            set(16 + 8, &(u64::MAX / 2).to_le_bytes()),
            "past the end",
        ),
        (
            "lying name size",
            set(16 + 136, &u32::MAX.to_le_bytes()),
            "grid name",
        ),
        (
            "huge declared leaf count",
            set(go + lay.tree + 32, &u32::MAX.to_le_bytes()),
            "more than its",
        ),
        (
            "lying root offset",
            set(go + lay.tree + 24, &(u64::MAX - 8).to_le_bytes()),
            "root",
        ),
        (
            "huge root table",
            set(go + lay.root + 24, &u32::MAX.to_le_bytes()),
            "root tile table",
        ),
        (
            "upper child offset outside",
            set(go + lay.root + 64 + 8, &(1i64 << 40).to_le_bytes()),
            "child offset",
        ),
        (
            "negative leaf offset",
            set(go + lay.lower + 1088, &(-(1i64 << 40)).to_le_bytes()),
            "child offset",
        ),
        (
            "grid type unsupported",
            {
                let f = set(16 + 32, &6u32.to_le_bytes());
                let mut f2 = f.clone();
                f2[go + 636..go + 640].copy_from_slice(&6u32.to_le_bytes());
                f2
            },
            "type vec3f",
        ),
        (
            "metadata and grid types differ",
            set(go + 636, &14u32.to_le_bytes()),
            "corrupt",
        ),
        ("grid magic", set(go, b"garbage!"), "bad magic"),
        (
            "NaN value",
            set(go + lay.first_leaf + 96 + 40, &f32::NAN.to_le_bytes()),
            "value NaN",
        ),
    ];
    // Both leaves of the lower node pointing at the first one: more leaves reached than
    // the one declared.
    {
        let mut f = set(go + lay.tree + 32, &1u32.to_le_bytes());
        let first = (lay.first_leaf - lay.lower) as i64;
        f[go + lay.lower + 1088 + 8 * 16..go + lay.lower + 1088 + 8 * 17]
            .copy_from_slice(&first.to_le_bytes());
        cases.push(("shared leaf node", f, "more leaf nodes"));
    }
    // A second root entry at the same key as the first.
    {
        let mut g2 = g.clone();
        g2.root_tiles = vec![([0, 0, 0], 1.0, true)];
        cases.push(("repeated root key", file_bytes(&g2, 0), "two root entries"));
    }
    // ZIP: a declared grid far beyond what the compressed bytes can expand to, and a
    // damaged zlib stream.
    let zip = file_bytes(&g, 1);
    {
        let mut f = zip.clone();
        f[16..24].copy_from_slice(&(1u64 << 50).to_le_bytes());
        cases.push(("ZIP huge declared grid", f, "more than zlib"));
        let mut f = zip.clone();
        let n = f.len();
        for b in &mut f[go + 8 + 40..n - 8] {
            *b ^= 0x5a;
        }
        cases.push(("ZIP damaged stream", f, "ZIP data"));
    }
    // An FpN leaf whose bit-width code is past 16 bits.
    {
        let gn = Grid::new(Type::FpN(4), g.leaves.clone());
        let (_, ln) = grid_bytes(&gn);
        let mut f = file_bytes(&gn, 0);
        f[go + ln.first_leaf + 15] = 7 << 5;
        cases.push(("FpN bit width", f, "bit width"));
    }
    cases
}

#[test]
fn hostile_nanovdb_files_fail_in_one_line_with_bounded_memory_and_time() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("never.pin");
    let mut rows = vec![
        "| input | command | exit | peak RSS MiB | s | message |".to_string(),
        "|---|---|---|---|---|---|".to_string(),
    ];
    // The undamaged file bakes.
    let cases = damaged_nanovdbs();
    let valid = dir.path().join("valid.nvdb");
    std::fs::write(
        &valid,
        nanovdb::file_bytes(
            &nanovdb::Grid::new(
                nanovdb::Type::Float,
                vec![nanovdb::leaf([0, 0, 0], |k| k as f32 * 0.01)],
            ),
            0,
        ),
    )
    .unwrap();
    let mut args = vec!["bake", valid.to_str().unwrap(), "-o", out.to_str().unwrap()];
    args.extend(FAST);
    let r = run(&args);
    assert_eq!(
        r.code,
        Some(0),
        "the valid NanoVDB file bakes: {}",
        r.stderr
    );
    std::fs::remove_file(&out).unwrap();
    for (i, (name, bytes, needle)) in cases.iter().enumerate() {
        let path = dir.path().join(format!("damaged{i}.nvdb"));
        std::fs::write(&path, bytes).unwrap();
        let r = run(&[
            "bake",
            path.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--cells",
            "4",
        ]);
        check(&format!("nvdb {name} | bake"), &r, &mut rows);
        assert!(
            r.stderr.contains(&format!("damaged{i}.nvdb")),
            "{name}: {}",
            r.stderr
        );
        assert!(
            r.stderr.contains(needle),
            "{name}: {:?} lacks {needle:?}",
            r.stderr
        );
        assert!(!out.exists(), "{name}: an output file appeared");
    }
    // Named as anything else, a NanoVDB file is told by its magic.
    let renamed = dir.path().join("cloud.bin");
    std::fs::copy(&valid, &renamed).unwrap();
    let mut args = vec![
        "bake",
        renamed.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ];
    args.extend(FAST);
    let r = run(&args);
    assert_eq!(
        r.code,
        Some(0),
        "a NanoVDB file without its extension bakes: {}",
        r.stderr
    );
    eprintln!("\n{}", rows.join("\n"));
}

// ---------------------------------------------------------------------------------------
// Hostile and careless use.

/// Small, fast bake settings.
const FAST: [&str; 6] = ["--cells", "4", "--dirs", "octahedral:2", "--step", "0.05"];

/// Exit `code`, one stderr line starting with `pinbake: error: ` and containing `needle`,
/// no panic, bounded time and peak RSS.
fn expect(name: &str, r: &Run, code: i32, needle: &str) {
    let lines: Vec<&str> = r.stderr.lines().collect();
    assert_eq!(
        r.code,
        Some(code),
        "{name}: exit {:?} (signal {:?}), stderr {:?}",
        r.code,
        r.signal,
        r.stderr
    );
    assert_eq!(lines.len(), 1, "{name}: not one line: {:?}", r.stderr);
    assert!(
        lines[0].starts_with("pinbake: error: "),
        "{name}: {:?}",
        lines[0]
    );
    assert!(
        lines[0].contains(needle),
        "{name}: {:?} lacks {needle:?}",
        lines[0]
    );
    assert!(!r.stderr.contains("panicked"), "{name}: {}", r.stderr);
    assert!(
        r.rss_kib < MAX_RSS_KIB,
        "{name}: peak RSS {} KiB",
        r.rss_kib
    );
    assert!(r.seconds < MAX_SECONDS, "{name}: {} s", r.seconds);
}

fn os(args: &[&str]) -> Vec<OsString> {
    args.iter().map(OsString::from).collect()
}

fn run_args(args: &[OsString]) -> Run {
    let a: Vec<&OsStr> = args.iter().map(OsString::as_os_str).collect();
    run_os(&a, Duration::from_secs(30))
}

fn mkfifo(path: &Path) {
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
    // SAFETY: a valid C string; creates a FIFO in our temp dir.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

fn partials(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".partial"))
        .collect();
    v.sort();
    v
}

fn copy_raw(dir: &Path) -> PathBuf {
    let input = dir.join("w_31x34x33_f32.raw");
    std::fs::copy(data("water_esp_31x34x33_float32.raw"), &input).unwrap();
    input
}

#[test]
fn outputs_only_to_regular_files_or_new_paths() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let input = copy_raw(d);
    let input_bytes = std::fs::read(&input).unwrap();
    let fifo = d.join("fifo.pin");
    mkfifo(&fifo);
    let link = |name: &str, to: &Path| {
        let p = d.join(name);
        std::os::unix::fs::symlink(to, &p).unwrap();
        p
    };
    let to_fifo = link("to_fifo.pin", &fifo);
    // Devices only through symlinks in our temp dir: if the check failed, the rename would
    // replace the link, never the device.
    let to_null = link("to_null.pin", Path::new("/dev/null"));
    let to_stdout = link("to_stdout.pin", Path::new("/proc/self/fd/1"));
    let dangling = link("dangling.pin", &d.join("nothing"));
    let hard = d.join("hard.raw");
    std::fs::hard_link(&input, &hard).unwrap();
    let to_input = link("to_input.pin", &input);
    let sub = d.join("sub");
    std::fs::create_dir(&sub).unwrap();
    let cases: [(&Path, &str); 9] = [
        (&fifo, "fifo.pin: not a regular file"),
        (&to_fifo, "to_fifo.pin: not a regular file"),
        (&to_null, "to_null.pin: not a regular file"),
        (&to_stdout, "to_stdout.pin: not a regular file"),
        (&dangling, "symlink to a missing file"),
        (&sub, "sub: is a directory"),
        (&input, "is the input file"),
        (&hard, "is the input file"),
        (&to_input, "is the input file"),
    ];
    for (out, needle) in cases {
        let mut args = vec!["bake", input.to_str().unwrap(), "-o", out.to_str().unwrap()];
        args.extend(FAST);
        expect(
            &format!("bake -o {}", out.display()),
            &run(&args),
            1,
            needle,
        );
    }
    // Nothing was damaged: the FIFO, the links and the input are as they were.
    assert!(
        std::fs::symlink_metadata(&fifo)
            .unwrap()
            .file_type()
            .is_fifo()
    );
    for (l, to) in [
        (&to_fifo, fifo.as_path()),
        (&to_null, Path::new("/dev/null")),
        (&to_stdout, Path::new("/proc/self/fd/1")),
        (&to_input, input.as_path()),
    ] {
        assert_eq!(std::fs::read_link(l).unwrap(), to);
    }
    assert_eq!(std::fs::read(&input).unwrap(), input_bytes);
    assert!(sub.read_dir().unwrap().next().is_none());
    assert_eq!(partials(d), Vec::<String>::new());

    // merge: the output may not be a tile or a device either.
    let valid = valid_pin(d);
    let tile = d.join("valid.pin");
    for (out, needle) in [
        (&tile, "is the input file"),
        (&to_null, "not a regular file"),
    ] {
        let r = run(&["merge", tile.to_str().unwrap(), "-o", out.to_str().unwrap()]);
        expect("merge", &r, 1, needle);
    }
    assert_eq!(std::fs::read(&tile).unwrap(), valid);

    // A symlink to a regular file is followed: the file is replaced, the link stays.
    let old = d.join("old.pin");
    std::fs::write(&old, b"old").unwrap();
    let to_old = link("to_old.pin", &old);
    let mut args = vec!["bake", "procedural:box", "-o", to_old.to_str().unwrap()];
    args.extend(FAST);
    let r = run(&args);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert_eq!(std::fs::read_link(&to_old).unwrap(), old);
    let r = run(&["verify", old.to_str().unwrap()]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
}

#[test]
fn special_files_as_input_are_refused_without_reading() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let fifo = d.join("pipe.pin");
    mkfifo(&fifo);
    let fifo_raw = d.join("pipe_2x2x2_u8.raw");
    mkfifo(&fifo_raw);
    let fifo_vdb = d.join("pipe.vdb");
    mkfifo(&fifo_vdb);
    let fifo_nvdb = d.join("pipe.nvdb");
    mkfifo(&fifo_nvdb);
    let out = d.join("out.pin");
    let special: [(&Path, &str); 4] = [
        (Path::new("/dev/zero"), "/dev/zero: not a regular file"),
        (
            Path::new("/dev/urandom"),
            "/dev/urandom: not a regular file",
        ),
        (&fifo, "pipe.pin: not a regular file"),
        (d, "is a directory"),
    ];
    for (input, needle) in special {
        let i = input.to_str().unwrap();
        let name = |c: &str| format!("{c} {i}");
        expect(&name("inspect"), &run(&["inspect", i]), 1, needle);
        expect(&name("verify"), &run(&["verify", i]), 1, needle);
        let r = run(&["merge", i, "-o", out.to_str().unwrap()]);
        expect(&name("merge"), &r, 1, needle);
    }
    for (input, extra) in [
        (&fifo_raw, &[][..]),
        (&fifo_vdb, &[][..]),
        (&fifo_nvdb, &[][..]),
        (
            &PathBuf::from("/dev/zero"),
            &["--dims", "2", "--type", "u8"][..],
        ),
    ] {
        let mut args = vec!["bake", input.to_str().unwrap(), "-o", out.to_str().unwrap()];
        args.extend(FAST);
        args.extend(extra);
        expect(
            &format!("bake {}", input.display()),
            &run(&args),
            1,
            "not a regular file",
        );
    }
    assert!(!out.exists());
}

#[test]
fn non_utf8_arguments_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let bad = OsStr::from_bytes(b"\xff.pin");
    let bad_in_dir = d.join(bad);
    let out = d.join("o.pin");
    let mut cases: Vec<(Vec<OsString>, i32)> = Vec::new();
    for cmd in ["inspect", "verify"] {
        cases.push((vec![cmd.into(), bad.into()], 1));
    }
    cases.push((
        vec!["merge".into(), bad.into(), "-o".into(), out.clone().into()],
        1,
    ));
    cases.push((
        vec!["bake".into(), bad.into(), "-o".into(), out.clone().into()],
        1,
    ));
    let mut a = os(&["bake", "procedural:box", "--grid"]);
    a.extend([bad.into(), "-o".into(), out.clone().into()]);
    cases.push((a, 2));
    let mut a = os(&["bench", "--threads"]);
    a.push(bad.into());
    cases.push((a, 2));
    for (args, code) in &cases {
        let r = run_args(args);
        expect(&format!("{args:?}"), &r, *code, "");
    }
    // A non-UTF-8 output path is a path like any other.
    let mut a = os(&["bake", "procedural:box", "-o"]);
    a.push(bad_in_dir.clone().into());
    a.extend(os(&FAST));
    let r = run_args(&a);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    let r = run_args(&[OsString::from("verify"), bad_in_dir.into()]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
}

#[test]
fn sizes_beyond_memory_fail_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("big.pin");
    let o = out.to_str().unwrap();
    let cases: [(&[&str], i32, &str); 8] = [
        (&["--cells", "1000"], 1, "memory budget"),
        (&["--cells", "350"], 1, "memory budget"),
        (&["--embed-density", "2000"], 1, "memory budget"),
        (&["--embed-density", "1024"], 1, "memory budget"),
        // The estimate counts the f16 grid (2 GiB) plus the default bake's pins, index and
        // majorant grid (at their upper bound, 20^3 cells x 256 directions) and the process
        // base (24 MiB, `plan::PROCESS_BASE_BYTES`): just above 2 GiB.
        (&["--embed-density", "1024"], 1, "2205465856 bytes"),
        (&["--majorant", "2000"], 1, "memory budget"),
        (&["--cells", "300", "--majorant", "0"], 1, "memory budget"),
        (&["--embed-density", "5000"], 2, "at most 4096"),
    ];
    for (extra, code, needle) in cases {
        // 2G keeps the limit machine-independent (the default is half the physical memory).
        let mut args = vec!["bake", "procedural:box", "-o", o, "--max-memory", "2G"];
        args.extend(extra);
        expect(&format!("bake {extra:?}"), &run(&args), code, needle);
        assert!(!out.exists());
    }
    let r = run(&["bench", "--grid-only", "--voxels", "5000"]);
    expect("bench --voxels 5000", &r, 2, "1..=4096");
    let r = run(&[
        "bench",
        "--grid-only",
        "--voxels",
        "4096",
        "--max-memory",
        "2G",
    ]);
    expect("bench --voxels 4096", &r, 1, "memory budget");
    // 64^3 voxels (1 MiB) and a 37^3 x 16x4 bake (52 MB of output) fit in 60M; the layered
    // march's working set (~110 MB, which the check used to leave out) does not.
    let r = run(&[
        "bench",
        "--grid-only",
        "--voxels",
        "64",
        "--max-memory",
        "60M",
    ]);
    expect("bench working set", &r, 1, "memory budget");
    assert_eq!(partials(dir.path()), Vec::<String>::new());
}

/// `--embed-density 512 --max-memory 300M` passed its check and then peaked at 7.6 GB (a
/// `Result` per voxel collected before the f16 grid). Now the peak is the 256 MiB grid plus
/// the process; a mutation back to the per-voxel `Result` fails this by a factor of ten.
#[test]
fn embedded_density_peak_stays_near_its_size() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("dense.pin");
    let r = run(&[
        "bake",
        "procedural:box",
        "-o",
        out.to_str().unwrap(),
        "--cells",
        "4",
        "--dirs",
        "octahedral:2",
        "--majorant",
        "0",
        "--embed-density",
        "512",
        "--max-memory",
        "300M",
        "--quiet",
    ]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    let grid_kib = 512 * 512 * 512 * 2 / 1024;
    assert!(
        r.rss_kib < grid_kib + 96 * 1024,
        "peak RSS {} KiB for a {grid_kib} KiB grid",
        r.rss_kib
    );
    assert!(std::fs::metadata(&out).unwrap().len() > 512 * 512 * 512 * 2);
}

#[test]
fn out_of_range_values_are_usage_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let input = copy_raw(d);
    let raw = input.to_str().unwrap();
    let out = d.join("o.pin");
    let o = out.to_str().unwrap();
    let smoke = data("openvdb_smoke1.vdb");
    let vdb = smoke.to_str().unwrap();
    let cases: &[(&str, &[&str], &str)] = &[
        ("procedural:box", &["--step", "0"], "--step"),
        ("procedural:box", &["--step", "1e-12"], "[1e-5, 1]"),
        ("procedural:box", &["--step", "nan"], "--step"),
        (
            "procedural:box",
            &["--pins-per-entry", "0"],
            "--pins-per-entry",
        ),
        (
            "procedural:box",
            &["--density-scale", "nan"],
            "--density-scale",
        ),
        ("procedural:box", &["--density-scale=-1"], "--density-scale"),
        ("procedural:box", &["--threads", "10000"], "--threads"),
        ("procedural:box", &["--threads", "0"], "--threads"),
        ("procedural:box", &["--max-memory", "0"], "--max-memory"),
        ("procedural:box", &["--max-memory", "nanG"], "--max-memory"),
        ("procedural:box", &["--majorant", "5000"], "--majorant"),
        ("procedural:box", &["--type", "u8"], "--type does not apply"),
        (raw, &["--spacing", "1e153"], "1e153"),
        (raw, &["--origin", "1e300,0,0"], "1e300"),
        (
            raw,
            &["--grid", "density"],
            "--grid does not apply to a raw input",
        ),
        (
            raw,
            &["--levelset-to-fog"],
            "--levelset-to-fog does not apply",
        ),
        (raw, &["--endian", "middle"], "--endian"),
        (
            vdb,
            &["--dims", "4"],
            "--dims does not apply to an OpenVDB input",
        ),
        (vdb, &["--type", "f32"], "--type does not apply"),
    ];
    for (input, extra, needle) in cases {
        let mut args = vec!["bake", input, "-o", o, "--cells", "4"];
        args.extend(*extra);
        expect(&format!("bake {input} {extra:?}"), &run(&args), 2, needle);
        assert!(!out.exists());
    }
    for extra in [
        &["--voxels", "0"][..],
        &["--rays", "1"][..],
        &["--threads", "0"][..],
        &["--cells", "0"][..],
    ] {
        let mut args = vec!["bench", "--grid-only"];
        args.extend(extra);
        expect(&format!("bench {extra:?}"), &run(&args), 2, "");
    }
}

/// Starts a slow bake to `out` and returns it once its temp file exists (one more
/// `.partial` in the directory than `before`).
fn slow_bake(out: &Path, before: usize) -> std::process::Child {
    let child = Command::new(BIN)
        .args([
            "bake",
            "procedural:cosine",
            "--cells",
            "48",
            "--threads",
            "1",
        ])
        .args(["--quiet", "-o"])
        .arg(out)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t = Instant::now();
    while partials(out.parent().unwrap()).len() <= before {
        assert!(
            t.elapsed() < Duration::from_secs(20),
            "no temp file appeared"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    child
}

#[test]
fn interrupted_bakes_leave_no_partial_files() {
    use std::os::unix::process::ExitStatusExt;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let target = d.join("t.pin");
    let old = valid_pin(d);
    std::fs::copy(d.join("valid.pin"), &target).unwrap();
    // Another target's temp file: never touched by writes to t.pin.
    let other = d.join(".t.pin.bak.abcdef.partial");
    std::fs::write(&other, b"x").unwrap();
    let others = partials(d);
    for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
        let mut child = slow_bake(&target, 1);
        assert_eq!(partials(d).len(), 2);
        // SAFETY: our own running child.
        unsafe { libc::kill(child.id() as libc::pid_t, sig) };
        let status = child.wait().unwrap();
        assert_eq!(status.signal(), Some(sig), "{status:?}");
        assert_eq!(partials(d), others, "signal {sig} left a temp file");
        assert_eq!(std::fs::read(&target).unwrap(), old, "the target changed");
    }
    // SIGKILL cannot be handled: the temp file stays until the next write to the target.
    let mut child = slow_bake(&target, 1);
    child.kill().unwrap();
    child.wait().unwrap();
    assert_eq!(partials(d).len(), 2, "SIGKILL leaves the temp file");
    assert_eq!(std::fs::read(&target).unwrap(), old);
    let mut args = vec!["bake", "procedural:box", "-o", target.to_str().unwrap()];
    args.extend(FAST);
    let r = run(&args);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert_eq!(partials(d), others, "the stale temp file was not removed");
    assert!(other.exists());
}

#[test]
fn messages_are_one_line_and_compact() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let missing = d.join("missing.pin");
    let r = run(&["inspect", missing.to_str().unwrap()]);
    expect("missing", &r, 1, "missing.pin: No such file or directory");
    assert_eq!(r.stderr.matches("No such file").count(), 1, "{}", r.stderr);
    let r = run(&[
        "bake",
        missing.with_extension("raw").to_str().unwrap(),
        "-o",
        "x.pin",
    ]);
    expect("missing raw", &r, 1, "missing.raw");
    assert_eq!(r.stderr.matches("os error 2").count(), 1, "{}", r.stderr);
    let r = run(&["verify", d.to_str().unwrap()]);
    expect("directory", &r, 1, "is a directory");
    assert!(!r.stderr.contains("bytes"), "{}", r.stderr);
    let out = d.join("o.pin");
    let mut args = vec!["bake", "procedural:box", "-o", out.to_str().unwrap()];
    args.extend(FAST);
    args.extend(["--density-scale", "1e308"]);
    let r = run(&args);
    expect("1e308", &r, 1, "1e308");
    assert!(r.stderr.len() < 300, "{}", r.stderr);
}

/// Runs the binary with its standard output on a pipe whose reader is already gone (a
/// `... --json | head -c 1` that stopped reading): the status and stderr.
fn run_into_closed_pipe(args: &[&str]) -> (std::process::ExitStatus, String) {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let out = Command::new(BIN)
        .args(args)
        .stdin(Stdio::null())
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    (
        out.status,
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// `2> /dev/full`: the error line cannot be written, so the exit code is all that is left to
/// say what happened: 1 for a bad file, 2 for a bad flag, 0 when nothing went wrong. Before,
/// `eprintln!` panicked on every error path (exit 101).
#[test]
fn a_full_stderr_keeps_the_exit_code() {
    let dir = tempfile::tempdir().unwrap();
    valid_pin(dir.path());
    let pin = dir.path().join("valid.pin");
    let missing = dir.path().join("missing.pin");
    let out = dir.path().join("o.pin");
    let mut bake = vec!["bake", "procedural:box", "-o", out.to_str().unwrap()];
    bake.extend(FAST);
    for (args, code) in [
        (vec!["inspect", missing.to_str().unwrap()], 1),
        (vec!["verify", missing.to_str().unwrap()], 1),
        (vec!["bake", "procedural:box", "--bogus-flag"], 2),
        (vec!["bake", "procedural:nothing", "-o", "x.pin"], 1),
        (vec!["inspect", pin.to_str().unwrap()], 0),
        (bake, 0),
    ] {
        let full = dev_full();
        let status = Command::new(BIN)
            .args(&args)
            .current_dir(dir.path())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(full)
            .status()
            .unwrap();
        assert_eq!(status.code(), Some(code), "{args:?}: {status:?}");
    }
    assert!(out.exists());
}

/// `> /dev/full`: the summary cannot be written. One error line naming standard output,
/// exit 1; before, `println!` panicked (exit 101).
#[test]
fn a_full_stdout_is_an_error_line() {
    let dir = tempfile::tempdir().unwrap();
    valid_pin(dir.path());
    let pin = dir.path().join("valid.pin");
    for args in [
        vec!["inspect", "--json", pin.to_str().unwrap()],
        vec!["inspect", pin.to_str().unwrap()],
        vec!["verify", pin.to_str().unwrap()],
    ] {
        let full = dev_full();
        let out = Command::new(BIN)
            .args(&args)
            .stdin(Stdio::null())
            .stdout(full)
            .stderr(Stdio::piped())
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{args:?}: {stderr}");
        assert!(
            stderr.starts_with("pinbake: error: standard output: No space left on device"),
            "{args:?}: {stderr}"
        );
    }
}

#[test]
fn a_closed_stdout_ends_the_process_quietly() {
    use std::os::unix::process::ExitStatusExt;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    valid_pin(d);
    let pin = d.join("valid.pin");
    let (status, stderr) = run_into_closed_pipe(&["inspect", "--json", pin.to_str().unwrap()]);
    // Killed by SIGPIPE at the write, as other Unix filters are; before, `println!` panicked
    // ("failed printing to stdout", exit 101).
    assert_eq!(status.signal(), Some(libc::SIGPIPE), "{status:?}: {stderr}");
    assert!(stderr.is_empty(), "{stderr}");
    // A bake that prints its summary after publishing the file: the file is whole.
    let out = d.join("o.pin");
    let mut args = vec![
        "bake",
        "procedural:box",
        "-o",
        out.to_str().unwrap(),
        "--json",
    ];
    args.extend(FAST);
    let (status, stderr) = run_into_closed_pipe(&args);
    assert_eq!(status.signal(), Some(libc::SIGPIPE), "{status:?}: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let r = run(&["verify", out.to_str().unwrap()]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    // No temporary file left beside it.
    let names: Vec<_> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 2, "{names:?}");
}

/// `/dev/full` opened for writing: every write fails with "No space left on device".
fn dev_full() -> std::fs::File {
    std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap()
}
