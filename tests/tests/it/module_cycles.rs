//! No import circle inside any crate (`docs/architecture.md`, "No two modules import each
//! other"): for every library and binary of the workspace (and of the Python extension's own
//! workspace), the modules its files declare form no cycle through their `crate::`, `super::`
//! and `self::` paths.
//!
//! The graph is built from the source text, at file level: each file that a `mod NAME;`
//! declares is a node (an inline `mod tests { .. }` counts as its file); a path in code (a
//! `use`, with its groups expanded, or an inline `crate::a::b::f()`) is an edge to the module
//! file that defines its longest prefix, following `pub use` re-exports to the defining file.
//! Comments, string literals and inline test modules (`#[cfg(test)] mod tests { .. }`) are
//! not read. Edges between a module and its own ancestors or
//! descendants are not counted: a parent declares and re-exports its children, and a child
//! uses its parent's items (`use super::*`), which is how a facade is written, not a circle.
//! Test targets, examples and benches are not checked.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// A module's path from its crate root (`[]` is the root).
type ModPath = Vec<String>;

struct Module {
    file: PathBuf,
    /// Names that `pub use`/`pub(crate) use` statements of the file bind, with their full
    /// (unresolved) path segments.
    reexports: BTreeMap<String, Vec<String>>,
    /// Every `crate`/`super`/`self` path of the file's code, as segments.
    paths: Vec<Vec<String>>,
}

/// The source text without comments, string literals and char literals (each replaced by a
/// space), so that only code is read.
fn code_only(src: &str) -> String {
    let b = src.as_bytes();
    let mut out = String::with_capacity(src.len());
    let mut i = 0;
    while i < b.len() {
        if b[i..].starts_with(b"//") {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i..].starts_with(b"/*") {
            let mut depth = 0;
            while i < b.len() {
                if b[i..].starts_with(b"/*") {
                    depth += 1;
                    i += 2;
                } else if b[i..].starts_with(b"*/") {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
            out.push(' ');
        } else if b[i] == b'r' && (b.get(i + 1) == Some(&b'"') || b.get(i + 1) == Some(&b'#')) {
            // A raw string r"..", r#".."#: skip to its closing quote and hashes.
            let mut j = i + 1;
            let mut hashes = 0;
            while b.get(j) == Some(&b'#') {
                hashes += 1;
                j += 1;
            }
            if b.get(j) != Some(&b'"') {
                out.push('r');
                i += 1;
                continue;
            }
            j += 1;
            let close: Vec<u8> = std::iter::once(b'"')
                .chain(std::iter::repeat_n(b'#', hashes))
                .collect();
            while j < b.len() && !b[j..].starts_with(&close) {
                j += 1;
            }
            i = j + close.len();
            out.push(' ');
        } else if b[i] == b'"' {
            i += 1;
            while i < b.len() && b[i] != b'"' {
                if b[i] == b'\\' {
                    i += 1;
                }
                i += 1;
            }
            i += 1;
            out.push(' ');
        } else if b[i] == b'\'' {
            // A char literal ('a', '\n', '\u{1e}'), not a lifetime ('a without a closing quote).
            let rest = &src[i + 1..];
            let len = if rest.starts_with('\\') {
                rest.find('\'').map(|k| k + 1)
            } else {
                rest.chars()
                    .next()
                    .filter(|c| rest[c.len_utf8()..].starts_with('\''))
                    .map(|c| c.len_utf8() + 1)
            };
            match len {
                Some(n) => {
                    i += 1 + n;
                    out.push(' ');
                }
                None => {
                    out.push('\'');
                    i += 1;
                }
            }
        } else {
            let c = src[i..].chars().next().unwrap();
            out.push(c);
            i += c.len_utf8();
        }
    }
    out
}

/// The paths a `use` tree names, its groups expanded: `a::{b, c::{d, e as f}, self}` gives
/// `a::b`, `a::c::d`, `a::c::e` and `a`. Each path comes with the name it binds.
fn expand_use(tree: &str) -> Vec<(Vec<String>, String)> {
    fn split_top(s: &str) -> Vec<&str> {
        let (mut parts, mut depth, mut start) = (Vec::new(), 0, 0);
        for (i, c) in s.char_indices() {
            match c {
                '{' => depth += 1,
                '}' => depth -= 1,
                ',' if depth == 0 => {
                    parts.push(&s[start..i]);
                    start = i + 1;
                }
                _ => {}
            }
        }
        parts.push(&s[start..]);
        parts
    }
    fn walk(prefix: &[String], tree: &str, out: &mut Vec<(Vec<String>, String)>) {
        let tree = tree.trim();
        if tree.is_empty() {
            return;
        }
        if let Some(brace) = tree.find('{') {
            let head: Vec<String> = tree[..brace]
                .split("::")
                .map(str::trim)
                .filter(|s| !s.is_empty())
                .map(str::to_string)
                .collect();
            let inner = &tree[brace + 1..tree.rfind('}').unwrap_or(tree.len())];
            let p: Vec<String> = prefix.iter().cloned().chain(head).collect();
            for part in split_top(inner) {
                walk(&p, part, out);
            }
            return;
        }
        let (path, alias) = match tree.split_once(" as ") {
            Some((p, a)) => (p.trim(), Some(a.trim())),
            None => (tree, None),
        };
        let mut p: Vec<String> = prefix.to_vec();
        for seg in path.split("::").map(str::trim).filter(|s| !s.is_empty()) {
            if seg != "self" || p.is_empty() {
                p.push(seg.to_string());
            }
        }
        let name = alias
            .map(str::to_string)
            .or_else(|| p.last().cloned())
            .unwrap_or_default();
        out.push((p, name));
    }
    let mut out = Vec::new();
    walk(&[], tree, &mut out);
    out
}

/// `code` without its inline test modules (`#[cfg(test)] mod NAME { .. }`): a module's tests
/// may use its neighbours without making them its dependencies.
fn without_tests(code: &str) -> String {
    let mut out = String::with_capacity(code.len());
    let mut rest = code;
    while let Some(at) = rest.find("#[cfg(test)]") {
        out.push_str(&rest[..at]);
        let after = &rest[at + "#[cfg(test)]".len()..];
        let t = after.trim_start();
        let inline_mod = t
            .strip_prefix("mod ")
            .and_then(|m| m.find(['{', ';']).map(|k| (k, m)))
            .filter(|(k, m)| m.as_bytes()[*k] == b'{');
        match inline_mod {
            Some((k, _)) => {
                let open = after.len() - t.len() + 4 + k;
                let mut depth = 0;
                let mut end = after.len();
                for (i, c) in after[open..].char_indices() {
                    match c {
                        '{' => depth += 1,
                        '}' => {
                            depth -= 1;
                            if depth == 0 {
                                end = open + i + 1;
                                break;
                            }
                        }
                        _ => {}
                    }
                }
                rest = &after[end..];
            }
            None => {
                out.push_str("#[cfg(test)]");
                rest = after;
            }
        }
    }
    out.push_str(rest);
    out
}

/// The `crate`/`super`/`self` paths of a file's code (its inline tests left out) and its
/// re-exports.
fn read_module(file: &Path) -> Module {
    let code = without_tests(&code_only(&std::fs::read_to_string(file).unwrap()));
    let mut paths = Vec::new();
    let mut reexports = BTreeMap::new();
    let mut rest = String::with_capacity(code.len());
    let mut i = 0;
    let bytes = code.as_bytes();
    let is_word = |c: u8| c.is_ascii_alphanumeric() || c == b'_';
    while i < code.len() {
        let at_word = i == 0 || !is_word(bytes[i - 1]);
        if at_word && code[i..].starts_with("use ") {
            let end = code[i..].find(';').map_or(code.len(), |k| i + k);
            let before = code[..i].trim_end();
            let public = ["pub", "pub(crate)", "pub(super)"]
                .iter()
                .any(|v| before.ends_with(v));
            for (p, name) in expand_use(&code[i + 4..end]) {
                if matches!(
                    p.first().map(String::as_str),
                    Some("crate" | "super" | "self")
                ) {
                    paths.push(p.clone());
                }
                if public {
                    reexports.insert(name, p);
                }
            }
            i = end + 1;
            continue;
        }
        let c = code[i..].chars().next().unwrap();
        rest.push(c);
        i += c.len_utf8();
    }
    // Inline paths: `crate::a::b`, `super::super::c`, `self::d`.
    let rb = rest.as_bytes();
    let mut k = 0;
    while k < rest.len() {
        let at_word = k == 0 || !is_word(rb[k - 1]) && rb[k - 1] != b':';
        let head = ["crate::", "super::", "self::"]
            .into_iter()
            .find(|h| rest[k..].starts_with(h));
        if let (true, Some(_)) = (at_word, head) {
            let mut end = k;
            while end < rest.len() && (is_word(rb[end]) || rest[end..].starts_with("::")) {
                end += if rb[end] == b':' { 2 } else { 1 };
            }
            let p: Vec<String> = rest[k..end]
                .split("::")
                .filter(|s| !s.is_empty())
                .map(str::to_string)
                .collect();
            paths.push(p);
            k = end;
        } else {
            k += rest[k..].chars().next().unwrap().len_utf8();
        }
    }
    Module {
        file: file.to_path_buf(),
        reexports,
        paths,
    }
}

/// The modules of the crate rooted at `root` (a `lib.rs`, `main.rs` or a binary's file), by
/// their path, following `mod NAME;` declarations (an inline `mod NAME {` is its file's).
fn crate_modules(root: &Path) -> BTreeMap<ModPath, Module> {
    let mut out = BTreeMap::new();
    let mut todo = vec![(Vec::<String>::new(), root.to_path_buf())];
    while let Some((path, file)) = todo.pop() {
        let m = read_module(&file);
        let code = code_only(&std::fs::read_to_string(&file).unwrap());
        // Where this file's child modules live: beside a root or `mod.rs`, else in the folder
        // named after the file.
        let stem = file.file_stem().unwrap().to_string_lossy().into_owned();
        let dir = if path.is_empty() || stem == "mod" {
            file.parent().unwrap().to_path_buf()
        } else {
            file.parent().unwrap().join(&stem)
        };
        let mut explicit: Option<String> = None;
        for line in code.lines() {
            let t = line.trim();
            if let Some(p) = t.strip_prefix("#[path = ") {
                explicit = Some(p.trim_end_matches(']').trim().to_string());
                continue;
            }
            let decl = t
                .trim_start_matches("pub(crate) ")
                .trim_start_matches("pub(super) ")
                .trim_start_matches("pub ");
            if let Some(name) = decl.strip_prefix("mod ").and_then(|n| n.strip_suffix(';')) {
                let name = name.trim();
                let child = match explicit.take() {
                    // `#[path]` strings were blanked with the literals: such a module is
                    // not followed (none of the checked targets has one).
                    Some(_) => None,
                    None => [
                        dir.join(format!("{name}.rs")),
                        dir.join(name).join("mod.rs"),
                    ]
                    .into_iter()
                    .find(|p| p.is_file()),
                };
                if let Some(child) = child {
                    let mut p = path.clone();
                    p.push(name.to_string());
                    todo.push((p, child));
                }
            } else if !t.starts_with("#[") {
                explicit = None;
            }
        }
        out.insert(path, m);
    }
    out
}

/// The module file that defines what `path` names, seen from module `from`: its longest
/// prefix that is a module, through that module's re-exports where the next segment is one.
fn resolve(
    mods: &BTreeMap<ModPath, Module>,
    from: &ModPath,
    path: &[String],
    depth: usize,
) -> Option<ModPath> {
    let mut at: ModPath = from.clone();
    let mut segs = path.iter().peekable();
    match segs.peek().map(|s| s.as_str()) {
        Some("crate") => {
            at.clear();
            segs.next();
        }
        Some("self") => {
            segs.next();
        }
        Some("super") => {
            while segs.peek().map(|s| s.as_str()) == Some("super") {
                at.pop()?;
                segs.next();
            }
        }
        _ => return None,
    }
    for seg in segs {
        let mut next = at.clone();
        next.push(seg.clone());
        if mods.contains_key(&next) {
            at = next;
            continue;
        }
        // An item of `at`, or one that `at` re-exports from elsewhere.
        if depth < 8
            && let Some(target) = mods[&at].reexports.get(seg)
        {
            let target = if matches!(
                target.first().map(String::as_str),
                Some("crate" | "super" | "self")
            ) {
                target.clone()
            } else {
                // A relative path (`pub use child::Item`): from `at` itself.
                std::iter::once("self".to_string())
                    .chain(target.iter().cloned())
                    .collect()
            };
            if let Some(t) = resolve(mods, &at, &target, depth + 1) {
                return Some(t);
            }
        }
        break;
    }
    Some(at)
}

/// Every cycle of the crate's module graph, as its modules' files (one strongly connected
/// component of two or more files each).
pub fn cycles_of_crate(root: &Path) -> Vec<Vec<PathBuf>> {
    let mods = crate_modules(root);
    let related = |a: &ModPath, b: &ModPath| a.starts_with(b) || b.starts_with(a);
    let mut edges: BTreeMap<ModPath, BTreeSet<ModPath>> = BTreeMap::new();
    for (from, m) in &mods {
        for p in &m.paths {
            if let Some(to) = resolve(&mods, from, p, 0)
                && !related(from, &to)
            {
                edges.entry(from.clone()).or_default().insert(to);
            }
        }
    }
    // Strongly connected components by Tarjan's algorithm (recursive: module trees are
    // shallow and small).
    struct Tarjan<'a> {
        edges: &'a BTreeMap<ModPath, BTreeSet<ModPath>>,
        index: BTreeMap<ModPath, usize>,
        low: BTreeMap<ModPath, usize>,
        stack: Vec<ModPath>,
        on_stack: BTreeSet<ModPath>,
        sccs: Vec<Vec<ModPath>>,
    }
    impl Tarjan<'_> {
        fn visit(&mut self, v: &ModPath) {
            let i = self.index.len();
            self.index.insert(v.clone(), i);
            self.low.insert(v.clone(), i);
            self.stack.push(v.clone());
            self.on_stack.insert(v.clone());
            for w in self.edges.get(v).into_iter().flatten() {
                if !self.index.contains_key(w) {
                    self.visit(w);
                    let lw = self.low[w];
                    let lv = self.low.get_mut(v).unwrap();
                    *lv = (*lv).min(lw);
                } else if self.on_stack.contains(w) {
                    let iw = self.index[w];
                    let lv = self.low.get_mut(v).unwrap();
                    *lv = (*lv).min(iw);
                }
            }
            if self.low[v] == self.index[v] {
                let mut scc = Vec::new();
                while let Some(w) = self.stack.pop() {
                    self.on_stack.remove(&w);
                    let done = &w == v;
                    scc.push(w);
                    if done {
                        break;
                    }
                }
                if scc.len() > 1 {
                    self.sccs.push(scc);
                }
            }
        }
    }
    let mut t = Tarjan {
        edges: &edges,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        sccs: Vec::new(),
    };
    for v in mods.keys() {
        if !t.index.contains_key(v) {
            t.visit(v);
        }
    }
    t.sccs
        .into_iter()
        .map(|scc| {
            let mut files: Vec<PathBuf> = scc.iter().map(|p| mods[p].file.clone()).collect();
            files.sort();
            files
        })
        .collect()
}

/// The library and binary roots of every package of both workspaces.
fn crate_roots() -> Vec<PathBuf> {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut roots = Vec::new();
    for manifest in [repo.join("Cargo.toml"), repo.join("python/Cargo.toml")] {
        let out = std::process::Command::new(env!("CARGO"))
            .args([
                "metadata",
                "--format-version",
                "1",
                "--no-deps",
                "--offline",
            ])
            .arg("--manifest-path")
            .arg(&manifest)
            .output()
            .expect("cargo metadata runs");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let meta: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        for p in meta["packages"].as_array().unwrap() {
            for t in p["targets"].as_array().unwrap() {
                let kinds: Vec<&str> = t["kind"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .filter_map(|k| k.as_str())
                    .collect();
                if kinds
                    .iter()
                    .any(|k| matches!(*k, "lib" | "rlib" | "cdylib" | "bin"))
                {
                    roots.push(PathBuf::from(t["src_path"].as_str().unwrap()));
                }
            }
        }
    }
    roots.sort();
    roots.dedup();
    roots
}

#[test]
fn no_crate_has_an_import_circle() {
    let roots = crate_roots();
    assert!(roots.len() >= 14, "{roots:?}");
    let mut problems = Vec::new();
    for root in &roots {
        for cycle in cycles_of_crate(root) {
            problems.push(format!(
                "{}: {}",
                root.display(),
                cycle
                    .iter()
                    .map(|f| f.display().to_string())
                    .collect::<Vec<_>>()
                    .join(" <-> ")
            ));
        }
    }
    assert!(
        problems.is_empty(),
        "modules that import each other:\n{}",
        problems.join("\n")
    );
}

/// The check on a made-up crate: two sibling modules that import each other (one through a
/// `use` group, the other through an inline path and a re-export of the root) are caught;
/// a child that uses its parent's items, and a parent that re-exports its child, are not.
#[test]
fn a_circle_is_caught() {
    let dir = tempfile::tempdir().unwrap();
    let w = |name: &str, text: &str| {
        let p = dir.path().join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    };
    w(
        "lib.rs",
        "mod a;\nmod b;\nmod c;\npub use b::Thing;\n// use crate::c::X; a comment\n",
    );
    w("a.rs", "use crate::{c, b::{self as bee}};\nmod inner;\n");
    w("a/inner.rs", "use super::super::c::f;\n");
    w("b.rs", "pub struct Thing;\nfn g() { crate::a::h(); }\n");
    w("c/mod.rs", "pub use self::leaf::f;\nmod leaf;\n");
    w("c/leaf.rs", "use super::*;\npub fn f() {}\n");
    let lib = dir.path().join("lib.rs");
    let cycles = cycles_of_crate(&lib);
    assert_eq!(
        cycles,
        vec![vec![dir.path().join("a.rs"), dir.path().join("b.rs")]],
        "{cycles:?}"
    );
    // Without b's call back into a, and with a reaching b only through the root's
    // re-export, there is none; a string or a comment naming a module is no edge.
    w(
        "b.rs",
        "pub struct Thing;\nfn g() { let _ = \"crate::a::h\"; } // crate::a\n",
    );
    w("a.rs", "use crate::Thing;\nmod inner;\n");
    assert!(cycles_of_crate(&lib).is_empty());
    // A re-export is followed to the file that defines the item.
    w("b.rs", "pub struct Thing;\nfn g() { crate::a::h(); }\n");
    assert_eq!(cycles_of_crate(&lib).len(), 1);
    // A test module that uses a neighbour is not an import of the module.
    w(
        "b.rs",
        "pub struct Thing;\n#[cfg(test)]\nmod tests {\n    fn t() { crate::a::h(); }\n}\n",
    );
    assert!(cycles_of_crate(&lib).is_empty());
}
