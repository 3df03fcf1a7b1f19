//! Why a scene file was refused: one line naming the file and, where the problem sits in
//! the document, its JSON path.

use std::path::PathBuf;

use pin_format::input::{InputError, quoted};

#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be opened or read (it names the file itself).
    #[error(transparent)]
    Input(#[from] InputError),
    /// Not JSON: where the text stops parsing.
    #[error("{}: not JSON: {why} (line {line}, column {column})", quoted(.file))]
    Syntax {
        file: PathBuf,
        line: usize,
        column: usize,
        why: String,
    },
    /// A value in the document is wrong: `at` is its JSON path (`instances[17].transform`).
    #[error("{}: {at}: {why}", quoted(.file))]
    At {
        file: PathBuf,
        at: String,
        why: String,
    },
    /// The file as a whole: too large, or beyond the memory budget.
    #[error("{}: {why}", quoted(.file))]
    File { file: PathBuf, why: String },
}

impl SceneError {
    /// A refusal at the JSON path `at`; the input both quote (an asset name, a key, a path)
    /// is clipped ([`clip`]), so a line stays short whatever the file holds.
    pub(crate) fn at(
        file: &std::path::Path,
        at: impl Into<String>,
        why: impl Into<String>,
    ) -> Self {
        SceneError::At {
            file: file.to_path_buf(),
            at: clip(&at.into()),
            why: clip(&why.into()),
        }
    }
}

/// The longest run of text without a space that a message quotes whole: a longer one (a
/// key, a name or a path from the file) keeps its first [`CLIP_HEAD`] and last
/// [`CLIP_TAIL`] characters, enough to recognise a path by.
pub const CLIP_RUN: usize = 128;
/// Characters kept from the start of a clipped run.
pub const CLIP_HEAD: usize = 48;
/// Characters kept from the end of a clipped run.
pub const CLIP_TAIL: usize = 24;
/// The longest message text [`clip`] returns, in characters (before the file's name).
pub const CLIP_TOTAL: usize = 400;

/// `text` with every space-free run longer than [`CLIP_RUN`] characters cut to its start
/// and end around a note of its length, and the whole cut to [`CLIP_TOTAL`]: a 60 MiB key
/// quoted twice made a 125 MB error line.
pub fn clip(text: &str) -> String {
    let mut out = String::with_capacity(text.len().min(CLIP_TOTAL * 4));
    for (i, run) in text.split(' ').enumerate() {
        if i > 0 {
            out.push(' ');
        }
        let chars = run.chars().count();
        if chars > CLIP_RUN {
            out.extend(run.chars().take(CLIP_HEAD));
            out.push_str(&format!("...({} bytes)...", run.len()));
            out.extend(run.chars().skip(chars - CLIP_TAIL));
        } else {
            out.push_str(run);
        }
        if out.chars().nth(CLIP_TOTAL).is_some() {
            break;
        }
    }
    if out.chars().nth(CLIP_TOTAL).is_some() {
        out = out.chars().take(CLIP_TOTAL).collect();
        out.push_str("...");
    }
    out
}
