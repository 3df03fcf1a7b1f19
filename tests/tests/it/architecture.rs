//! `docs/architecture.md` against the code: every crate of the workspace (and the Python
//! extension's own workspace) has a code-map section headed by its folder, the section's
//! `**Depends on:**` line names exactly the workspace crates its manifest depends on (normal
//! dependencies, optional ones included), and every top-level module of the crate (a
//! `src/NAME.rs` file or a `src/NAME/` folder) is named in its section. A crate, a dependency
//! or a module added without its line in the map fails here.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

struct Package {
    name: String,
    /// The folder relative to the repository root, e.g. `pinrender`.
    dir: String,
    /// Names of the crates it depends on (normal kind).
    deps: BTreeSet<String>,
}

fn packages(manifest: &Path) -> Vec<Package> {
    let out = std::process::Command::new(env!("CARGO"))
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .arg("--manifest-path")
        .arg(manifest)
        .output()
        .expect("cargo metadata runs");
    assert!(
        out.status.success(),
        "cargo metadata: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let root = std::fs::canonicalize(repo()).unwrap();
    meta["packages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let manifest = PathBuf::from(p["manifest_path"].as_str().unwrap());
            let dir = manifest.parent().unwrap().strip_prefix(&root).unwrap();
            Package {
                name: p["name"].as_str().unwrap().to_string(),
                dir: dir.to_string_lossy().into_owned(),
                deps: p["dependencies"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .filter(|d| d["kind"].is_null())
                    .map(|d| d["name"].as_str().unwrap().to_string())
                    .collect(),
            }
        })
        .collect()
}

/// The text of the section headed `### \`DIR/\`` up to the next heading of level 2 or 3.
fn section<'a>(doc: &'a str, dir: &str) -> Option<&'a str> {
    let head = format!("### `{dir}/`");
    let start = doc.lines().position(|l| l.starts_with(&head))?;
    let lines: Vec<&str> = doc.lines().collect();
    let end = (start + 1..lines.len())
        .find(|&i| lines[i].starts_with("## ") || lines[i].starts_with("### "))
        .unwrap_or(lines.len());
    let from = doc.find(lines[start]).unwrap();
    let to = if end < lines.len() {
        doc[from..].find(lines[end]).unwrap() + from
    } else {
        doc.len()
    };
    Some(&doc[from..to])
}

/// The backquoted words on the section's `**Depends on:**` line.
fn depends_on(section: &str) -> Option<BTreeSet<String>> {
    let line = section.lines().find(|l| l.starts_with("**Depends on:**"))?;
    Some(
        line.split('`')
            .skip(1)
            .step_by(2)
            .map(str::to_string)
            .collect(),
    )
}

fn top_level_modules(src: &Path) -> Vec<String> {
    let mut names = Vec::new();
    for entry in std::fs::read_dir(src).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if path.is_dir() {
            names.push(format!("{name}/"));
        } else if name.ends_with(".rs") && !["lib.rs", "main.rs", "tests.rs"].contains(&&*name) {
            names.push(name);
        }
    }
    names.sort();
    names
}

/// Whether `text` names `module` as a word of its own (`bake.rs`, not `prebake.rs`).
fn names(text: &str, module: &str) -> bool {
    text.match_indices(module).any(|(i, _)| {
        !text[..i]
            .chars()
            .next_back()
            .is_some_and(|c| c.is_alphanumeric() || c == '_')
    })
}

#[test]
fn the_code_map_names_every_crate_dependency_and_module() {
    let doc = std::fs::read_to_string(repo().join("docs/architecture.md")).unwrap();
    let mut all = packages(&repo().join("Cargo.toml"));
    all.extend(packages(&repo().join("python/Cargo.toml")));
    let ours: BTreeSet<String> = all.iter().map(|p| p.name.clone()).collect();
    let mut problems = Vec::new();
    for p in &all {
        let Some(sec) = section(&doc, &p.dir) else {
            problems.push(format!(
                "no section `### \\`{}/\\`` for crate {}",
                p.dir, p.name
            ));
            continue;
        };
        let want: BTreeSet<String> = p.deps.intersection(&ours).cloned().collect();
        match depends_on(sec) {
            None => problems.push(format!("{}: no **Depends on:** line", p.dir)),
            Some(got) => {
                // Other backquoted words on the line (feature names, files) are not crates.
                let got: BTreeSet<String> = got.intersection(&ours).cloned().collect();
                if got != want {
                    problems.push(format!(
                        "{}: the map says it depends on {got:?}, its manifest on {want:?}",
                        p.dir
                    ));
                }
            }
        }
        let src = repo().join(&p.dir).join("src");
        if src.is_dir() {
            for m in top_level_modules(&src) {
                if !names(sec, &m) {
                    problems.push(format!("{}: module {m} is not in its section", p.dir));
                }
            }
        }
    }
    assert!(
        problems.is_empty(),
        "docs/architecture.md is out of date:\n{}",
        problems.join("\n")
    );
}

#[test]
fn a_missing_module_or_dependency_is_caught() {
    // The checks themselves, on a made-up section: the mutation the test above must catch.
    let doc = "### `x/`\n**Depends on:** `pin-format`\n`a.rs` and `b/`.\n## Next\n";
    let sec = section(doc, "x").unwrap();
    assert_eq!(
        depends_on(sec),
        Some(BTreeSet::from(["pin-format".to_string()]))
    );
    assert!(names(sec, "a.rs") && names(sec, "b/") && !names(sec, "c.rs"));
    assert!(!names("`data.rs`", "a.rs"));
    assert!(!sec.contains("Next"));
    assert!(section(doc, "y").is_none());
}

/// The runtime's claim in the map: `cargo tree -p pinrt -e normal` (default features and
/// none) shows no writer dependencies, because pinrt reads pin-format without its `writer`
/// feature.
#[test]
fn the_runtime_links_no_writer() {
    for features in [&[][..], &["--no-default-features"][..]] {
        let out = std::process::Command::new(env!("CARGO"))
            .args([
                "tree",
                "-p",
                "pinrt",
                "-e",
                "normal",
                "--prefix",
                "none",
                "--offline",
            ])
            .args(features)
            .current_dir(repo())
            .output()
            .expect("cargo tree runs");
        assert!(
            out.status.success(),
            "cargo tree: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let tree = String::from_utf8_lossy(&out.stdout);
        for writer_dep in ["tempfile ", "rustix ", "getrandom ", "fastrand "] {
            assert!(
                !tree.lines().any(|l| l.starts_with(writer_dep)),
                "pinrt {features:?} links {writer_dep}:\n{tree}"
            );
        }
        assert!(tree.lines().any(|l| l.starts_with("pin-format ")), "{tree}");
    }
}

/// The map's claim for the renderer: `cargo tree -p pinrender -e normal` (every feature) shows
/// no `pinlab`, while the lab's tree shows `pinrender` (so the search below can find a crate).
#[test]
fn the_renderer_depends_on_no_lab() {
    let tree = |package: &str| {
        let out = std::process::Command::new(env!("CARGO"))
            .args(["tree", "-p", package, "-e", "normal", "--all-features"])
            .args(["--prefix", "none", "--offline"])
            .current_dir(repo())
            .output()
            .expect("cargo tree runs");
        assert!(
            out.status.success(),
            "cargo tree: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let renderer = tree("pinrender");
    assert!(
        !renderer.lines().any(|l| l.starts_with("pinlab ")),
        "pinrender depends on the lab:\n{renderer}"
    );
    let lab = tree("pinlab");
    assert!(lab.lines().any(|l| l.starts_with("pinrender ")), "{lab}");
}

/// The map's claim for the renderer's library: `cargo tree -p pinrender -e normal` with its
/// default features shows `pin-volume` and no `pinbake` (only the `cli` feature bakes pins in
/// memory), while with `cli` it shows pinbake (so the search can find it).
#[test]
fn the_renderer_library_depends_on_no_baker() {
    let tree = |features: &[&str]| {
        let out = std::process::Command::new(env!("CARGO"))
            .args(["tree", "-p", "pinrender", "-e", "normal"])
            .args(features)
            .args(["--prefix", "none", "--offline"])
            .current_dir(repo())
            .output()
            .expect("cargo tree runs");
        assert!(
            out.status.success(),
            "cargo tree: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let library = tree(&[]);
    assert!(
        !library.lines().any(|l| l.starts_with("pinbake ")),
        "pinrender's library links pinbake:\n{library}"
    );
    assert!(
        library.lines().any(|l| l.starts_with("pin-volume ")),
        "{library}"
    );
    let cli = tree(&["--features", "cli"]);
    assert!(cli.lines().any(|l| l.starts_with("pinbake ")), "{cli}");
}
