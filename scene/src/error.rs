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
    pub(crate) fn at(
        file: &std::path::Path,
        at: impl Into<String>,
        why: impl Into<String>,
    ) -> Self {
        SceneError::At {
            file: file.to_path_buf(),
            at: at.into(),
            why: why.into(),
        }
    }
}
