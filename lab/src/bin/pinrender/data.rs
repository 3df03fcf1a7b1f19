//! Where `pinrender` finds the sample volumes that ship in the repository's `data/` folder.
//!
//! Nothing is compiled in: the folder is looked up at run time, so an installed binary, a
//! clone moved elsewhere and CI all behave the same. Order: `--data DIR`, then the
//! `PINBAKE_DATA` environment variable, then a `data/` folder holding `SOURCES.md` beside the
//! executable or in one of its ancestors (a `target/*/pinrender` inside a clone), then the same
//! search upwards from the working directory.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use anyhow::{Result, bail};

static OVERRIDE: OnceLock<PathBuf> = OnceLock::new();

/// The environment variable naming the data folder.
pub const ENV: &str = "PINBAKE_DATA";

/// Use `dir` for every later lookup (the `--data` flag). The first call wins.
pub fn set_dir(dir: PathBuf) {
    let _ = OVERRIDE.set(dir);
}

fn holds_data(dir: &Path) -> bool {
    dir.join("SOURCES.md").is_file()
}

fn search_up(start: &Path) -> Option<PathBuf> {
    start
        .ancestors()
        .map(|a| a.join("data"))
        .find(|d| holds_data(d))
}

/// The data folder, or an error that says how to name it.
pub fn dir() -> Result<PathBuf> {
    if let Some(d) = OVERRIDE.get() {
        if !d.is_dir() {
            bail!("{}: --data must name a folder", d.display());
        }
        return Ok(d.clone());
    }
    if let Some(d) = std::env::var_os(ENV) {
        let d = PathBuf::from(d);
        if !d.is_dir() {
            bail!("{}: {ENV} must name a folder", d.display());
        }
        return Ok(d);
    }
    let from_exe = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().and_then(search_up));
    let from_cwd = || std::env::current_dir().ok().and_then(|c| search_up(&c));
    match from_exe.or_else(from_cwd) {
        Some(d) => Ok(d),
        None => bail!(
            "cannot find the sample volumes (a data/ folder with SOURCES.md) beside the executable \
             or the working directory: pass --data DIR or set {ENV}=DIR (the repository's data/)"
        ),
    }
}

/// `name` inside the data folder; an error naming the file when it is missing.
pub fn path(name: &str) -> Result<PathBuf> {
    let p = dir()?.join(name);
    if !p.is_file() {
        bail!(
            "{}: sample volume not found in the data folder",
            p.display()
        );
    }
    Ok(p)
}
