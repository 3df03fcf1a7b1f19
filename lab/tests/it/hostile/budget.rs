//! The trackers' bricks under `--max-memory`: a VDB of a few hundred bytes, written by
//! OpenVDB, whose eight active 4096^3 root tiles declare 2^39 voxels. Its bricks (1.07 G of
//! them) are refused from the tree's counts before one is listed, and the render reads the
//! tree instead; listing them to count them passed 8 GB under a 200 MB budget.

use super::*;

#[path = "../../../../pinbake/tests/openvdb/mod.rs"]
mod openvdb;

/// Runs pinrender (under `timeout`) and returns its exit code, stderr and peak RSS in KiB
/// (wait4's, which counts the waited-for descendants).
#[allow(clippy::zombie_processes)] // reaped by wait4 below, which std cannot see
fn run_rss(args: &[&str], home: &Path) -> (Option<i32>, String, i64) {
    let mut child = Command::new("timeout")
        .args(["-s", "KILL", "60"])
        .arg(BIN)
        .args(args)
        .private_cache(home)
        .env("XDG_RUNTIME_DIR", home)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run pinrender");
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
    let (mut status, mut usage) = (0, unsafe { std::mem::zeroed::<libc::rusage>() });
    // SAFETY: a child of this process; status and usage are valid for writes.
    let pid = unsafe { libc::wait4(child.id() as i32, &mut status, 0, &mut usage) };
    assert_eq!(pid, child.id() as i32);
    let code = libc::WIFEXITED(status).then(|| libc::WEXITSTATUS(status));
    (code, stderr, usage.ru_maxrss)
}

#[test]
fn root_tiles_render_within_max_memory() {
    let corpus = openvdb::corpus(env!("CARGO_TARGET_TMPDIR"), "pinrender-hostile");
    let vdb = corpus.join("root_tiles.vdb");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("roots.exr");
    let common = [
        "render",
        "--volume",
        vdb.to_str().unwrap(),
        "--width",
        "16",
        "--height",
        "16",
        "--spp",
        "2",
        "--max-memory",
        "200M",
        "--out",
        out.to_str().unwrap(),
    ];
    // Ratio tracking reads the tree where the bricks do not fit.
    let (code, err, rss) = run_rss(&common, dir.path());
    assert_eq!(code, Some(0), "{err}");
    assert!(
        rss < 200 * 1024,
        "peak RSS {rss} KiB under --max-memory 200M"
    );
    assert!(out.exists());
    // The GPU path needs the bricks: one line naming the sizes, within the budget too.
    let mut gpu = common.to_vec();
    gpu.extend(["--backend", "gpu"]);
    let (code, err, rss) = run_rss(&gpu, dir.path());
    assert_eq!(code, Some(1), "{err}");
    let lines: Vec<&str> = err
        .lines()
        .filter(|l| !l.contains("XDG_RUNTIME_DIR"))
        .collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].contains("bricks do not fit"), "{err}");
    assert!(rss < 400 * 1024, "peak RSS {rss} KiB (GPU refusal)");
}

/// A 512^3 box of active 8^3 tiles, a file of a few hundred KB: its dense copy (512 MiB) is
/// charged to `--max-memory` before it is made, so the trackers read the tree instead (it
/// peaked at 539 MB under 16M), and the GPU's dense copy is refused within the budget too.
#[test]
fn tile_heavy_vdbs_render_within_max_memory() {
    let corpus = openvdb::corpus(env!("CARGO_TARGET_TMPDIR"), "pinrender-hostile");
    let vdb = corpus.join("tiles_512.vdb");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tiles.exr");
    let common = [
        "render",
        "--volume",
        vdb.to_str().unwrap(),
        "--width",
        "16",
        "--height",
        "16",
        "--spp",
        "1",
        "--max-memory",
        "16M",
        "--out",
        out.to_str().unwrap(),
    ];
    for estimator in ["ratio", "rm@0.05"] {
        let mut args = common.to_vec();
        args.extend(["--estimator", estimator]);
        let (code, err, rss) = run_rss(&args, dir.path());
        assert_eq!(code, Some(0), "{estimator}: {err}");
        assert!(
            rss < 128 * 1024,
            "{estimator}: peak RSS {rss} KiB under --max-memory 16M"
        );
    }
    let mut gpu = common.to_vec();
    gpu.extend(["--backend", "gpu"]);
    let (code, err, rss) = run_rss(&gpu, dir.path());
    assert_eq!(code, Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("do not fit"), "{err}");
    assert!(rss < 400 * 1024, "peak RSS {rss} KiB (GPU refusal)");
}

/// A scene file whose text is exactly its load bound (`pin_scene::load_bound`): one 60 MiB
/// unknown key. Loading stays within the bound (it peaked at 436 MB: the parser's copies of
/// the key), and the refusal is one short line.
#[test]
fn a_scene_at_its_load_bound_stays_within_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("key.json");
    let mut text = Vec::with_capacity(61 << 20);
    text.extend_from_slice(br#"{"assets": {"b": {"volume": "procedural:box"}}, ""#);
    text.resize(text.len() + (60 << 20), b'k');
    text.extend_from_slice(br#"": 1, "instances": [{"asset": "b"}]}"#);
    std::fs::write(&scene, &text).unwrap();
    let bound = pin_scene::load_bound(text.len() as u64);
    let out = d.join("o.exr");
    let (code, err, rss) = run_rss(
        &[
            "render",
            "--scene",
            scene.to_str().unwrap(),
            "--max-memory",
            &bound.to_string(),
            "--out",
            out.to_str().unwrap(),
        ],
        d,
    );
    assert_eq!(code, Some(1), "{}", &err[..err.len().min(400)]);
    assert_eq!(err.lines().count(), 1);
    assert!(err.len() < 400, "{} bytes", err.len());
    assert!(err.contains("a string of"), "{err}");
    assert!(
        (rss as u64) * 1024 < bound,
        "peak RSS {rss} KiB above the load bound of {bound} bytes"
    );
}
