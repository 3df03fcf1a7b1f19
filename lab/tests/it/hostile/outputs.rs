//! The output rule of `pinrender render` (`pin_volume::files`): an output never names an input
//! (`--reference` included, through symlinks, whatever the backend), and the EXR and its PNG
//! land together after every check has passed, or not at all.

use super::*;

/// A reference image rendered into `d` at `size`x`size` pixels.
fn reference(d: &Path, name: &str, size: u32) -> PathBuf {
    let path = d.join(name);
    let mut args = render_args(&path);
    args[4] = size.to_string();
    args[6] = size.to_string();
    let r = run(&strs(&args), d);
    assert_eq!(r.out.status.code(), Some(0), "{}", r.stderr());
    path
}

fn with_reference(out: &Path, reference: &Path, extra: &[&str]) -> Vec<String> {
    let mut args = render_args(out);
    args.extend(["--reference".to_string(), reference.display().to_string()]);
    args.extend(extra.iter().map(|s| s.to_string()));
    args
}

#[test]
fn an_output_never_replaces_the_reference() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let r = reference(d, "ref.exr", 8);
    let bytes = std::fs::read(&r).unwrap();
    let link = d.join("link.exr");
    std::os::unix::fs::symlink(&r, &link).unwrap();
    for out in [&r, &link] {
        for extra in [&[][..], &["--backend", "gpu"]] {
            let args = with_reference(out, &r, extra);
            expect(
                &format!("--out {} {extra:?}", out.display()),
                &run(&strs(&args), d),
                1,
                "is the input file",
            );
            assert_eq!(std::fs::read(&r).unwrap(), bytes);
        }
    }
    // The PNG beside the EXR is an output too: a reference named like it is refused.
    let side = d.join("side.png");
    std::fs::copy(&r, &side).unwrap();
    expect(
        "--out side.exr --reference side.png",
        &run(&strs(&with_reference(&d.join("side.exr"), &side, &[])), d),
        1,
        "is the input file",
    );
    assert_eq!(std::fs::read(&side).unwrap(), bytes);
    assert!(!d.join("side.exr").exists());
}

#[test]
fn a_reference_of_another_size_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let r = reference(d, "ref16.exr", 16);
    let out = d.join("o.exr");
    std::fs::write(&out, b"old exr").unwrap();
    std::fs::write(d.join("o.png"), b"old png").unwrap();
    let t = Instant::now();
    expect(
        "8x8 render, 16x16 reference",
        &run(&strs(&with_reference(&out, &r, &[])), d),
        1,
        "ref16.exr: invalid reference: the image is 16x16, the render 8x8",
    );
    assert!(t.elapsed().as_secs_f64() < MAX_SECONDS);
    assert_eq!(std::fs::read(&out).unwrap(), b"old exr");
    assert_eq!(std::fs::read(d.join("o.png")).unwrap(), b"old png");
}

#[test]
fn a_reference_that_is_not_a_regular_file_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let fifo = d.join("ref.exr");
    mkfifo(&fifo);
    for r in [fifo.as_path(), Path::new("/dev/zero"), d] {
        let out = d.join("o.exr");
        expect(
            &format!("--reference {}", r.display()),
            &run(&strs(&with_reference(&out, r, &[])), d),
            1,
            if r == d {
                "is a directory"
            } else {
                "not a regular file"
            },
        );
        assert!(!out.exists());
    }
}

/// Writing fails (a file size limit stands in for a full disk): the old EXR and PNG both stay,
/// and no temp file is left beside them.
#[test]
fn a_failed_write_leaves_the_old_pair() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("o.exr");
    std::fs::write(&out, b"old exr").unwrap();
    std::fs::write(d.join("o.png"), b"old png").unwrap();
    let args = render_args(&out);
    // SIGXFSZ ignored (inherited through exec), so the write fails with EFBIG instead of
    // killing the process; `ulimit -f 1`: 512 bytes at most per file.
    let o = Command::new("sh")
        .arg("-c")
        .arg("trap '' XFSZ; ulimit -f 1; exec \"$@\"")
        .arg("sh")
        .arg(BIN)
        .args(&args)
        .private_cache(d)
        .env("XDG_RUNTIME_DIR", d)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert_eq!(std::fs::read(&out).unwrap(), b"old exr");
    assert_eq!(std::fs::read(d.join("o.png")).unwrap(), b"old png");
    let names: Vec<String> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        !names
            .iter()
            .any(|n| n.contains(".partial") || n.contains(".tmp-")),
        "{names:?}"
    );
}

/// `--out` names what is written: an EXR (with its PNG beside it) or a PNG. Another name is
/// a usage error before anything renders (an EXR named `x.txt` was written).
#[test]
fn an_output_named_as_another_format_is_a_usage_error() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for name in ["x.txt", "x", "x.exr.tmp"] {
        let out = d.join(name);
        expect(
            &format!("--out {name}"),
            &run(&strs(&render_args(&out)), d),
            2,
            "must end in .exr",
        );
        assert!(!out.exists() && !out.with_extension("png").exists());
    }
}

/// A scene's `max_bounces` above the GPU's limit is named by the scene's key, not by a flag
/// the user never gave ("--max-bounces 4294967295").
#[test]
fn a_scene_value_beyond_the_gpu_is_named_by_its_key() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("deep.json");
    std::fs::write(
        &scene,
        r#"{"assets": {"b": {"volume": "procedural:box"}}, "instances": [{"asset": "b"}],
            "max_bounces": 4294967295}"#,
    )
    .unwrap();
    let out = d.join("o.exr");
    let r = run(
        &[
            "render",
            "--scene",
            scene.to_str().unwrap(),
            "--backend",
            "gpu",
            "--out",
            out.to_str().unwrap(),
        ],
        d,
    );
    expect(
        "scene max_bounces",
        &r,
        1,
        "deep.json: max_bounces: 4294967295 exceeds",
    );
    assert!(
        !r.stderr().contains("--max-bounces 4294967295"),
        "{}",
        r.stderr()
    );
}

/// Without `XDG_RUNTIME_DIR` a GPU error is still one line: the tool gives the GPU stack a
/// private runtime directory, so Mesa's Wayland library no longer adds two lines of its own.
#[test]
fn a_gpu_error_without_a_runtime_dir_is_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("s.exr");
    let o = Command::new(BIN)
        .args([
            "render",
            "--volume",
            "procedural:sphere",
            "--backend",
            "gpu",
        ])
        .args(["--width", "8", "--height", "8", "--spp", "1", "--out"])
        .arg(&out)
        .env_remove("XDG_RUNTIME_DIR")
        .private_cache(d)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.starts_with("pinrender: error: "), "{err}");
}
