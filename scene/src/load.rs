//! Reading a scene file: bounded in size and memory, parsed with the JSON path of every
//! refusal, then checked as a whole (asset names, files, camera).

use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use pin_format::input::{InputError, check_regular, open_regular};

use crate::error::SceneError;
use crate::limits::{MAX_ASSETS, MAX_INSTANCES, MAX_SCENE_BYTES};
use crate::model::{Asset, Camera, Instance, Scene, Sun};
use crate::raw::{RawInstance, RawScene};
use crate::transform::IDENTITY;

/// The shortest text of one instance (`{"asset":"a"},`): how many a file's length can hold.
const MIN_INSTANCE_TEXT: u64 = 14;

/// Bytes that loading a scene file of `file_len` bytes holds at most: the text, every
/// instance it can hold as read (with a short asset name) and as checked, and the assets.
pub fn load_bound(file_len: u64) -> u64 {
    let instances = (file_len / MIN_INSTANCE_TEXT + 1).min(MAX_INSTANCES as u64);
    let per_instance =
        (std::mem::size_of::<RawInstance>() + 32 + std::mem::size_of::<Instance>()) as u64;
    let assets = (file_len / 8 + 1).min(MAX_ASSETS as u64) * 1024;
    file_len
        .saturating_add(instances * per_instance)
        .saturating_add(assets)
}

/// Reads and checks the scene file `path`. `max_memory` bounds what loading may hold
/// ([`load_bound`] of the file's length is checked before it is read).
pub fn load(path: &Path, max_memory: Option<u64>) -> Result<Scene, SceneError> {
    let (f, len) = open_regular(path)?;
    let whole = |why: String| SceneError::File {
        file: path.to_path_buf(),
        why,
    };
    if len > MAX_SCENE_BYTES {
        return Err(whole(format!(
            "is {len} bytes, more than a scene file may be ({MAX_SCENE_BYTES})"
        )));
    }
    if let Some(limit) = max_memory {
        let need = load_bound(len);
        if need > limit {
            return Err(whole(format!(
                "reading it may take {need} bytes, more than --max-memory {limit}"
            )));
        }
    }
    let mut text = Vec::new();
    text.try_reserve_exact(len as usize + 1)
        .map_err(|_| InputError::OutOfMemory {
            path: path.to_path_buf(),
            bytes: len,
        })?;
    // At most one byte more than the length checked: a file that grows is not read forever.
    f.take(MAX_SCENE_BYTES + 1)
        .read_to_end(&mut text)
        .map_err(|err| InputError::Io {
            path: path.to_path_buf(),
            err,
        })?;
    if text.len() as u64 > MAX_SCENE_BYTES {
        return Err(whole(format!(
            "grew past {MAX_SCENE_BYTES} bytes while it was read"
        )));
    }
    parse(&text, path)
}

/// The longest string a scene may hold, in bytes: a path (4096 on Linux) or a procedural
/// spec with room to spare. Longer ones are refused before the text is parsed, so that no
/// copy of one is made (a 60 MiB key peaked at 436 MB: the parser's path, its message and
/// their copies).
pub const MAX_STRING_BYTES: usize = 16 << 10;

/// Parses and checks a scene's text; `file` names it in messages and anchors its relative
/// paths (which must name regular files). A UTF-8 byte-order mark at the start is skipped
/// (RFC 8259 lets a parser ignore it; editors on some systems write one).
pub fn parse(text: &[u8], file: &Path) -> Result<Scene, SceneError> {
    let text = text.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(text);
    check_string_lengths(text, file)?;
    let mut de = serde_json::Deserializer::from_slice(text);
    let raw: RawScene = serde_path_to_error::deserialize(&mut de).map_err(|e| {
        let at = e.path().to_string();
        serde_error(file, &at, e.into_inner())
    })?;
    de.end().map_err(|e| serde_error(file, ".", e))?;
    resolve(raw, file)
}

/// Refuses a string literal longer than [`MAX_STRING_BYTES`], from one pass over the bytes
/// that allocates nothing: the line and column of its start. (A string that never ends is
/// left to the parser, which names where.)
fn check_string_lengths(text: &[u8], file: &Path) -> Result<(), SceneError> {
    let (mut line, mut column) = (1usize, 0usize);
    let mut i = 0;
    while i < text.len() {
        let b = text[i];
        if b == b'\n' {
            line += 1;
            column = 0;
        } else {
            column += 1;
        }
        if b != b'"' {
            i += 1;
            continue;
        }
        let (start_line, start_column) = (line, column);
        let mut j = i + 1;
        while j < text.len() && text[j] != b'"' {
            j += if text[j] == b'\\' { 2 } else { 1 };
        }
        let len = j.min(text.len()) - (i + 1);
        if len > MAX_STRING_BYTES {
            return Err(SceneError::File {
                file: file.to_path_buf(),
                why: format!(
                    "a string of {len} bytes at line {start_line}, column {start_column}, longer \
                     than a scene's strings may be ({MAX_STRING_BYTES})"
                ),
            });
        }
        // Strings hold no raw newline (JSON), so the column moves by the bytes skipped.
        column += j.min(text.len()) - i;
        i = j + 1;
    }
    Ok(())
}

fn serde_error(file: &Path, at: &str, e: serde_json::Error) -> SceneError {
    use serde_json::error::Category;
    let full = e.to_string();
    let suffix = format!(" at line {} column {}", e.line(), e.column());
    let why = full.strip_suffix(&suffix).unwrap_or(&full).to_string();
    match e.classify() {
        Category::Syntax | Category::Eof | Category::Io => SceneError::Syntax {
            file: file.to_path_buf(),
            line: e.line(),
            column: e.column(),
            why: crate::error::clip(&why),
        },
        Category::Data if at == "." => SceneError::File {
            file: file.to_path_buf(),
            why: crate::error::clip(&format!("{why} (line {}, column {})", e.line(), e.column())),
        },
        Category::Data => SceneError::at(
            file,
            at,
            format!("{why} (line {}, column {})", e.line(), e.column()),
        ),
    }
}

/// An asset's file: resolved against the scene's folder, and a regular file.
fn asset_file(
    file: &Path,
    base: &Path,
    at: impl Fn() -> String,
    given: Option<String>,
) -> Result<Option<PathBuf>, SceneError> {
    let Some(given) = given else {
        return Ok(None);
    };
    if given.is_empty() {
        return Err(SceneError::at(file, at(), "is an empty path"));
    }
    // A procedural volume (`procedural:cosine:...`, as `pinbake bake` takes it) is no file.
    if given.starts_with("procedural:") {
        return Ok(Some(PathBuf::from(given)));
    }
    let resolved = base.join(&given);
    check_regular(&resolved).map_err(|e| SceneError::at(file, at(), e.to_string()))?;
    Ok(Some(resolved))
}

fn resolve(raw: RawScene, file: &Path) -> Result<Scene, SceneError> {
    let base = match file.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    if raw.assets.0.is_empty() {
        return Err(SceneError::at(file, "assets", "names no asset"));
    }
    let mut assets = Vec::with_capacity(raw.assets.0.len());
    for (name, a) in raw.assets.0 {
        let at = |field: &str| format!("assets.{name}.{field}");
        if a.volume.is_none() && a.pins.is_none() {
            return Err(SceneError::at(
                file,
                format!("assets.{name}"),
                "needs a volume, pins, or both",
            ));
        }
        if let Some(g) = &a.grid
            && (g.is_empty() || g.chars().any(char::is_control))
        {
            return Err(SceneError::at(
                file,
                at("grid"),
                "must be a grid name without control characters",
            ));
        }
        let volume = asset_file(file, &base, || at("volume"), a.volume)?;
        let pins = asset_file(file, &base, || at("pins"), a.pins)?;
        assets.push(Asset {
            name,
            volume,
            pins,
            density_scale: a.density_scale,
            grid: a.grid,
        });
    }
    if raw.instances.0.is_empty() {
        return Err(SceneError::at(file, "instances", "places no instance"));
    }
    let index: HashMap<&str, u32> = assets
        .iter()
        .enumerate()
        .map(|(i, a)| (a.name.as_str(), i as u32))
        .collect();
    let mut instances = Vec::new();
    instances
        .try_reserve_exact(raw.instances.0.len())
        .map_err(|_| SceneError::File {
            file: file.to_path_buf(),
            why: format!("out of memory for {} instances", raw.instances.0.len()),
        })?;
    for (i, inst) in raw.instances.0.iter().enumerate() {
        let Some(&asset) = index.get(inst.asset.as_str()) else {
            return Err(SceneError::at(
                file,
                format!("{}.asset", Scene::instance_path(i)),
                format!("no asset named {:?} ({})", inst.asset, names(&assets)),
            ));
        };
        instances.push(Instance {
            asset,
            local_to_world: inst.transform.as_ref().map_or(IDENTITY, |t| t.0),
        });
    }
    let camera = raw.camera.map_or(Camera::default(), |c| Camera {
        origin: c.origin,
        target: c.target,
        fov: c.fov,
    });
    if let (Some(o), Some(t)) = (camera.origin, camera.target)
        && o == t
    {
        return Err(SceneError::at(
            file,
            "camera",
            "origin and target are the same point",
        ));
    }
    let sun = raw.sun.map_or(Sun::default(), |s| Sun {
        direction: s.direction,
        radiance: s.radiance,
    });
    Ok(Scene {
        file: file.to_path_buf(),
        assets,
        instances,
        camera,
        sun,
        env_radiance: raw.env_radiance,
        albedo: raw.albedo,
        g: raw.g,
        max_bounces: raw.max_bounces,
    })
}

/// The assets a file names, for a message: the first few.
fn names(assets: &[Asset]) -> String {
    let shown: Vec<&str> = assets.iter().take(5).map(|a| a.name.as_str()).collect();
    let more = if assets.len() > 5 { ", ..." } else { "" };
    format!("the file names {}{more}", shown.join(", "))
}
