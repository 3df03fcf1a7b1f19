//! The OpenVDB compatibility corpus: `corpus.cpp` (next to this file) is compiled against
//! Debian's `libopenvdb-dev` and writes VDB files with OpenVDB itself, then reads them back
//! with OpenVDB and dumps what it sees to `manifest.json`. Shared by pinbake's `vdb_corpus`
//! test and the cross-crate `vdb_rotated` test (included there by path).
//!
//! Without a C++ compiler or the OpenVDB headers the tests fail with the reason: a
//! compatibility test that passes without OpenVDB would prove nothing.

#![allow(dead_code)]

use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

const SOURCE: &str = include_str!("corpus.cpp");
/// The compiler flags: -O0, since the compile (OpenVDB's headers) is most of the cost: 21 s
/// of CPU at -O0 where -O1 took 37, for a run of 7 s instead of 1.5, once per source.
const CXXFLAGS: [&str; 2] = ["-std=c++17", "-O0"];

/// What `apt-get install` needs for the generator.
pub const APT_PACKAGES: &str = "g++ libopenvdb-dev libboost-dev";

/// Builds the generator and writes the corpus, both once per source (keyed by its hash)
/// under `tmp`, shared by every test binary that includes this module: the corpus is only
/// read, so a binary that finds it complete uses it as it is. `tag` names this binary's
/// temporary files. Returns the corpus directory.
pub fn corpus(tmp: &str, tag: &str) -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| match generate(Path::new(tmp), tag) {
        Ok(d) => d,
        Err(e) => panic!(
            "the OpenVDB compatibility corpus could not be generated: {e}\n\
             (it needs a C++ compiler and OpenVDB 10: apt-get install -y {APT_PACKAGES})"
        ),
    })
}

fn generate(tmp: &Path, tag: &str) -> Result<PathBuf, String> {
    std::fs::create_dir_all(tmp).map_err(|e| format!("{}: {e}", tmp.display()))?;
    let mut h = std::collections::hash_map::DefaultHasher::new();
    (SOURCE, CXXFLAGS).hash(&mut h);
    let key = format!("{:016x}", h.finish());
    let exe = tmp.join(format!("openvdb-corpus-{key}"));
    // Written under a private name and renamed when complete, so that a binary running at
    // the same time never reads a half-written corpus; the manifest is written last.
    let dir = tmp.join(format!("openvdb-corpus-{key}.d"));
    if dir.join("manifest.json").is_file() {
        return Ok(dir);
    }
    if !exe.exists() {
        let src = tmp.join(format!("openvdb-corpus-{tag}.cpp"));
        std::fs::write(&src, SOURCE).map_err(|e| format!("{}: {e}", src.display()))?;
        // Built under a private name and renamed, so that test binaries running at the same
        // time never execute a half-written file.
        let part = tmp.join(format!("openvdb-corpus-{tag}.part"));
        let cxx = std::env::var("CXX").unwrap_or_else(|_| "c++".into());
        let out = Command::new(&cxx)
            .args(CXXFLAGS)
            .arg(&src)
            .arg("-o")
            .arg(&part)
            .args(["-lopenvdb", "-ltbb", "-lImath"])
            .output()
            .map_err(|e| format!("cannot run the C++ compiler '{cxx}': {e}"))?;
        if !out.status.success() {
            let err = String::from_utf8_lossy(&out.stderr);
            let tail: Vec<&str> = err.lines().rev().take(8).collect();
            return Err(format!(
                "building corpus.cpp failed ({}): {}",
                out.status,
                tail.into_iter().rev().collect::<Vec<_>>().join(" | ")
            ));
        }
        std::fs::rename(&part, &exe).map_err(|e| format!("{}: {e}", exe.display()))?;
    }
    let part = tmp.join(format!("openvdb-corpus-{key}.{tag}.part"));
    let _ = std::fs::remove_dir_all(&part);
    std::fs::create_dir_all(&part).map_err(|e| format!("{}: {e}", part.display()))?;
    let out = Command::new(&exe)
        .arg(&part)
        .output()
        .map_err(|e| format!("cannot run {}: {e}", exe.display()))?;
    if !out.status.success() {
        return Err(format!(
            "{} failed ({}): {}",
            exe.display(),
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    if std::fs::rename(&part, &dir).is_err() {
        // Another binary finished first: its corpus is the same; use it.
        let _ = std::fs::remove_dir_all(&part);
        if !dir.join("manifest.json").is_file() {
            return Err(format!("{}: no manifest.json", dir.display()));
        }
    }
    Ok(dir)
}

/// One grid as OpenVDB reads it back.
#[derive(Debug)]
pub struct Grid {
    /// OpenVDB's name for it, `name[k]` for the k-th of repeated names.
    pub name: String,
    pub grid_type: String,
    pub class: String,
    pub half: bool,
    pub map: String,
    /// (index point, world point) pairs of OpenVDB's `indexToWorld`.
    pub index_to_world: Vec<([f64; 3], [f64; 3])>,
    pub active_bbox: ([i32; 3], [i32; 3]),
    pub active_voxels: u64,
    pub scalar: bool,
    /// The smallest and largest value stored in any leaf, active or not (scalar grids).
    pub leaf_range: Option<(f64, f64)>,
    /// (voxel, value, active).
    pub samples: Vec<([i32; 3], f64, bool)>,
}

impl Grid {
    /// The selector pinbake takes for this grid (`name#k` for repeated names).
    pub fn selector(&self) -> String {
        match self.name.strip_suffix(']').and_then(|s| s.rsplit_once('[')) {
            Some((base, k)) if k.chars().all(|c| c.is_ascii_digit()) => format!("{base}#{k}"),
            _ => self.name.clone(),
        }
    }
}

#[derive(Debug)]
pub struct File {
    pub file: PathBuf,
    /// `half|float` / `none|zip|blosc|mask|zip+mask|blosc+mask`.
    pub encoding: String,
    pub grids: Vec<Grid>,
}

fn v3<T: Copy + Default>(v: &serde_json::Value, f: impl Fn(&serde_json::Value) -> T) -> [T; 3] {
    let a = v.as_array().expect("a 3-vector");
    [f(&a[0]), f(&a[1]), f(&a[2])]
}

/// Parses `manifest.json` of a corpus directory.
pub fn manifest(dir: &Path) -> Vec<File> {
    let text = std::fs::read_to_string(dir.join("manifest.json")).expect("manifest.json");
    let v: serde_json::Value = serde_json::from_str(&text).expect("manifest.json is JSON");
    let f64_of = |x: &serde_json::Value| x.as_f64().expect("a number");
    let i32_of = |x: &serde_json::Value| x.as_i64().expect("an integer") as i32;
    v["files"]
        .as_array()
        .expect("files")
        .iter()
        .map(|f| File {
            file: dir.join(f["file"].as_str().unwrap()),
            encoding: f["encoding"].as_str().unwrap().to_string(),
            grids: f["grids"]
                .as_array()
                .unwrap()
                .iter()
                .map(|g| Grid {
                    name: g["name"].as_str().unwrap().to_string(),
                    grid_type: g["type"].as_str().unwrap().to_string(),
                    class: g["class"].as_str().unwrap().to_string(),
                    half: g["half"].as_bool().unwrap(),
                    map: g["map"].as_str().unwrap().to_string(),
                    index_to_world: g["index_to_world"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .map(|p| (v3(&p[0], f64_of), v3(&p[1], f64_of)))
                        .collect(),
                    active_bbox: (
                        v3(&g["active_bbox"][0], i32_of),
                        v3(&g["active_bbox"][1], i32_of),
                    ),
                    active_voxels: g["active_voxels"].as_u64().unwrap(),
                    scalar: g["scalar"].as_bool().unwrap(),
                    leaf_range: g["leaf_range"]
                        .as_array()
                        .map(|r| (f64_of(&r[0]), f64_of(&r[1]))),
                    samples: g["samples"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .map(|s| {
                            let s = s.as_array().unwrap();
                            (
                                [i32_of(&s[0]), i32_of(&s[1]), i32_of(&s[2])],
                                f64_of(&s[3]),
                                s[4].as_i64() == Some(1),
                            )
                        })
                        .collect(),
                })
                .collect(),
        })
        .collect()
}
