//! Frame sequences: a pattern such as `sim.####.pin` or `sim.%04d.pin` names the files of
//! its frames as `pinbake --frames` writes them (`pinbake::frames`: zero-padded, negative
//! frames with their sign). The frames that exist are listed once; frames
//! are opened ahead on worker threads, at most [`LOOK_AHEAD`] beyond the one shown, so memory
//! stays bounded whatever the sequence's length.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::thread::JoinHandle;

use anyhow::{Result, anyhow, bail};

use pinbake::frames::FramePattern;

use crate::open::Medium;

/// Frames opened ahead of the one shown.
pub const LOOK_AHEAD: usize = 2;

/// The frame pattern `path`'s file name holds, by `pinbake --frames`' own rule
/// ([`pinbake::frames::FramePattern`]: a run of `#`, or `%d` / `%0Nd`; negative frames keep
/// their sign), `None` for the name of one file. A malformed field (`%4d`, two fields) is a
/// usage error.
pub fn pattern(path: &Path) -> Result<Option<FramePattern>> {
    let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
        return Ok(None);
    };
    FramePattern::parse(name).map_err(|e| anyhow::Error::new(pin_cli::UsageError(e.0)))
}

/// The frames of a pattern that exist, in frame order.
pub fn list_frames(path: &Path) -> Result<Vec<(i64, PathBuf)>> {
    let pattern =
        pattern(path)?.ok_or_else(|| anyhow!("{}: not a frame pattern", path.display()))?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let entries = std::fs::read_dir(&dir).map_err(|e| anyhow!("{}: {e}", dir.display()))?;
    let mut frames = Vec::new();
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(name) = name.to_str() else { continue };
        if let Some(n) = pattern.frame_of(name) {
            frames.push((n, dir.join(name)));
        }
    }
    frames.sort();
    if frames.is_empty() {
        bail!(
            "{}: no frame matches the pattern (the file names `pinbake --frames` writes for it)",
            path.display()
        );
    }
    Ok(frames)
}

/// A sequence being shown: its frames, the one shown, and the frames opening ahead.
pub struct Sequence {
    pub frames: Vec<(i64, PathBuf)>,
    pub current: usize,
    pub playing: bool,
    opening: HashMap<usize, JoinHandle<Result<Medium>>>,
    open: Opener,
}

/// Opens one frame's file.
pub type Opener = Arc<dyn Fn(&Path) -> Result<Medium> + Send + Sync>;

impl Sequence {
    pub fn new(frames: Vec<(i64, PathBuf)>, open: Opener) -> Self {
        Self {
            frames,
            current: 0,
            playing: false,
            opening: HashMap::new(),
            open,
        }
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Starts opening the frames after `current` (at most [`LOOK_AHEAD`]) and forgets those
    /// that are no longer ahead.
    fn look_ahead(&mut self) {
        let n = self.frames.len();
        let wanted: Vec<usize> = (1..=LOOK_AHEAD.min(n.saturating_sub(1)))
            .map(|k| (self.current + k) % n)
            .collect();
        self.opening.retain(|i, _| wanted.contains(i));
        for i in wanted {
            if !self.opening.contains_key(&i) {
                let path = self.frames[i].1.clone();
                let open = self.open.clone();
                if let Ok(h) = std::thread::Builder::new()
                    .name("pinview frame".into())
                    .spawn(move || open(&path))
                {
                    self.opening.insert(i, h);
                }
            }
        }
    }

    /// Moves to frame `index` and returns its medium: the one opened ahead if there is one,
    /// else opened now.
    pub fn go_to(&mut self, index: usize) -> Result<Medium> {
        let index = index % self.frames.len();
        self.current = index;
        let medium = match self.opening.remove(&index) {
            Some(h) => h
                .join()
                .unwrap_or_else(|_| Err(anyhow!("opening a frame panicked"))),
            None => (self.open)(&self.frames[index].1),
        };
        self.look_ahead();
        medium
    }
}
