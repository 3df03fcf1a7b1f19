//! The front end `pinrender render` shares with the viewer: a NanoVDB file goes through the
//! one source dispatch, and a scene's assets are charged to one budget, each file once.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_pinrender");
const SMALL: [&str; 6] = ["--width", "24", "--height", "16", "--spp", "2"];

fn pinrender(args: &[&str]) -> Output {
    Command::new(BIN).arg("render").args(args).output().unwrap()
}

fn ok(out: &Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The smoke converted to NanoVDB by NanoVDB's own tool (Debian's `libnanovdb-tools`, which
/// `scripts/deps.sh` installs; without it this test fails).
fn converted(dir: &Path) -> (PathBuf, PathBuf) {
    let vdb = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/openvdb_smoke1.vdb");
    let nvdb = dir.join("smoke.nvdb");
    let out = Command::new("nanovdb_convert")
        .arg(&vdb)
        .arg(&nvdb)
        .output()
        .expect("nanovdb_convert (libnanovdb-tools) is needed for this test");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    (vdb, nvdb)
}

/// `pinrender render --volume X.nvdb` reads the file as pinbake does, so its image has the
/// bits of the render of the `.vdb` it was converted from, on the CPU with a tracker and
/// with pins baked in memory.
#[test]
fn a_nanovdb_file_renders_as_the_vdb_it_was_converted_from() {
    let dir = tempfile::tempdir().unwrap();
    let (vdb, nvdb) = converted(dir.path());
    for estimator in ["ratio", "pinms"] {
        let mut images = Vec::new();
        for (tag, input) in [("vdb", &vdb), ("nvdb", &nvdb)] {
            let out = dir.path().join(format!("{tag}-{estimator}.exr"));
            let mut args = vec!["--volume", s(input), "--estimator", estimator];
            args.extend_from_slice(&SMALL);
            args.extend_from_slice(&["--pin-cells", "8", "--out", s(&out)]);
            ok(&pinrender(&args));
            images.push(std::fs::read(&out).unwrap());
        }
        assert!(
            images[0] == images[1],
            "{estimator}: the .nvdb renders other bits"
        );
    }
}

/// A raw file of `n`^3 f32 voxels.
fn raw(dir: &Path, name: &str, n: usize) -> PathBuf {
    let values: Vec<u8> = (0..n * n * n)
        .flat_map(|i| (1.0 + (i % 7) as f32).to_le_bytes())
        .collect();
    let p = dir.join(name);
    std::fs::write(&p, values).unwrap();
    p
}

/// A scene of `names` assets, each naming one of `files`, with an instance each.
fn scene(dir: &Path, files: &[&Path], names: usize) -> PathBuf {
    let assets: Vec<String> = (0..names)
        .map(|k| format!("\"a{k}\": {{\"volume\": {:?}}}", s(files[k % files.len()])))
        .collect();
    let instances: Vec<String> = (0..names)
        .map(|k| format!("{{\"asset\": \"a{k}\", \"transform\": {{\"translate\": [{k}, 0, 0]}}}}"))
        .collect();
    let text = format!(
        "{{\"assets\": {{{}}}, \"instances\": [{}]}}",
        assets.join(", "),
        instances.join(", ")
    );
    let p = dir.join("s.json");
    std::fs::write(&p, text).unwrap();
    p
}

/// A scene's assets are charged to the command's one budget together, and a file named by
/// many assets is read once and charged once: 100 names of one 1 MiB raw file (read at 8x,
/// 8 MiB) render under 12 MiB, while two files of that size under the same budget are
/// refused with one line naming the second asset.
#[test]
fn a_scenes_assets_add_up_and_one_file_is_read_once() {
    let dir = tempfile::tempdir().unwrap();
    // The dims and type are read from the names, as the raw reader reads them.
    let a = raw(dir.path(), "a_64x64x64_float32.raw", 64);
    let b = raw(dir.path(), "b_64x64x64_float32.raw", 64);
    let render = |scene: &Path, tag: &str| {
        let out = dir.path().join(format!("{tag}.exr"));
        let mut args = vec!["--scene", s(scene), "--estimator", "ratio"];
        args.extend_from_slice(&["--width", "8", "--height", "8", "--spp", "1"]);
        args.extend_from_slice(&["--max-memory", "12M", "--out", s(&out)]);
        pinrender(&args)
    };
    let one = scene(dir.path(), &[&a], 100);
    let text = std::fs::read_to_string(&one).unwrap();
    assert!(text.contains("a99"), "{text}");
    ok(&render(&one, "one"));
    let two = scene(dir.path(), &[&a, &b], 2);
    let out = render(&two, "two");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains("assets.a1.volume") && err.contains("reading"),
        "{err}"
    );
}
