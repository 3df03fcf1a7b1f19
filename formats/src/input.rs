//! Opening a file for reading: the one rule every reader of this workspace follows (the
//! baker's inputs, `pinrt::PinGrid`, and through them the C ABI and the Python package).
//!
//! * Only regular files are read. `stat` comes first and never blocks, so a FIFO is refused
//!   before anything opens it; the open itself is non-blocking and the type is checked again
//!   on the open descriptor, so a FIFO swapped in between cannot hang the reader either. A
//!   directory says so; `/dev/zero` would otherwise be read until memory runs out.
//! * Buffers whose size comes from the file are allocated fallibly ([`read_aligned`]): an
//!   allocation failure is an error naming the size, never an abort.
//! * Paths in messages go through [`quoted`]: a name with a newline or another control
//!   character is printed escaped and in quotes, so it cannot cut a one-line message.

use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

/// Why a file was not opened or read. Messages are one line and name the file.
#[derive(Debug, thiserror::Error)]
pub enum InputError {
    #[error("{}: is a directory", quoted(.0))]
    IsDirectory(PathBuf),
    /// A device, FIFO or socket (or a symlink to one).
    #[error("{}: not a regular file", quoted(.0))]
    NotRegular(PathBuf),
    /// The OS error is part of the message and deliberately not a `source()`: an error
    /// chain printer would otherwise print it twice.
    #[error("{}: {err}", quoted(.path))]
    Io { path: PathBuf, err: std::io::Error },
    #[error("{}: out of memory for {bytes} bytes", quoted(.path))]
    OutOfMemory { path: PathBuf, bytes: u64 },
}

/// `path` for a one-line message: as it is when it is UTF-8 without control characters,
/// otherwise (and when empty) in double quotes with Rust's escapes (`"a\nb.pin"`, `""`).
pub fn quoted(path: &Path) -> String {
    match path.to_str() {
        Some(s) if !s.is_empty() && !s.chars().any(char::is_control) && !s.starts_with('"') => {
            s.to_owned()
        }
        _ => format!("{:?}", path.as_os_str()),
    }
}

/// Refuses `m` unless it describes a regular file: "is a directory" or "not a regular file"
/// naming `path` (the baker's output rule uses it too).
pub fn require_regular(path: &Path, m: &std::fs::Metadata) -> Result<(), InputError> {
    if m.is_dir() {
        Err(InputError::IsDirectory(path.to_path_buf()))
    } else if !m.is_file() {
        Err(InputError::NotRegular(path.to_path_buf()))
    } else {
        Ok(())
    }
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> InputError + '_ {
    move |err| InputError::Io {
        path: path.to_path_buf(),
        err,
    }
}

/// Checks that `path` names a regular file (symlinks followed) and returns its length,
/// without opening it.
pub fn check_regular(path: &Path) -> Result<u64, InputError> {
    let m = std::fs::metadata(path).map_err(io(path))?;
    require_regular(path, &m)?;
    Ok(m.len())
}

/// Opens `path` for reading only if it is a regular file, and returns it with its length.
pub fn open_regular(path: &Path) -> Result<(File, u64), InputError> {
    check_regular(path)?;
    let mut o = std::fs::OpenOptions::new();
    o.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        o.custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY);
    }
    let f = o.open(path).map_err(io(path))?;
    let m = f.metadata().map_err(io(path))?;
    require_regular(path, &m)?;
    Ok((f, m.len()))
}

/// A zeroed buffer of `words` u64 words, allocated fallibly (`what` names it in the error).
pub fn zeroed_words(words: usize, path: &Path) -> Result<Vec<u64>, InputError> {
    let mut v: Vec<u64> = Vec::new();
    v.try_reserve_exact(words)
        .map_err(|_| InputError::OutOfMemory {
            path: path.to_path_buf(),
            bytes: (words as u64).saturating_mul(8),
        })?;
    v.resize(words, 0);
    Ok(v)
}

/// Reads a whole regular file into an 8-byte aligned buffer (pin files are cast in place):
/// the words and the byte length. At most `len + 1` bytes are read, so a file that grows
/// while being read is not read forever (the pin reader's size check reports it).
pub fn read_aligned(path: &Path) -> Result<(Vec<u64>, usize), InputError> {
    let (mut f, len) = open_regular(path)?;
    let len = usize::try_from(len).map_err(|_| InputError::OutOfMemory {
        path: path.to_path_buf(),
        bytes: len,
    })?;
    let mut words = zeroed_words(len.div_ceil(8), path)?;
    let buf = &mut bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..len];
    f.read_exact(buf).map_err(io(path))?;
    Ok((words, len))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn special_files_are_refused_without_blocking() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(
            open_regular(dir.path()).unwrap_err().to_string(),
            format!("{}: is a directory", dir.path().display())
        );
        #[cfg(unix)]
        {
            let fifo = dir.path().join("fifo");
            let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
            // SAFETY: a valid NUL-terminated path.
            assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
            assert!(matches!(
                open_regular(&fifo),
                Err(InputError::NotRegular(_))
            ));
            assert!(matches!(
                read_aligned(Path::new("/dev/zero")),
                Err(InputError::NotRegular(_))
            ));
        }
        let f = dir.path().join("f");
        std::fs::write(&f, [7u8; 13]).unwrap();
        let (words, len) = read_aligned(&f).unwrap();
        assert_eq!(len, 13);
        assert_eq!(&bytemuck::cast_slice::<u64, u8>(&words)[..13], &[7u8; 13]);
    }

    #[test]
    fn control_characters_cannot_cut_a_message() {
        assert_eq!(quoted(Path::new("a/b.pin")), "a/b.pin");
        assert_eq!(quoted(Path::new("a\nb.pin")), "\"a\\nb.pin\"");
        assert_eq!(quoted(Path::new("")), "\"\"");
        let e = InputError::IsDirectory(PathBuf::from("x\r\ny"));
        assert_eq!(e.to_string().lines().count(), 1);
    }

    #[test]
    fn huge_buffers_are_errors() {
        assert!(matches!(
            zeroed_words(usize::MAX / 8, Path::new("big")),
            Err(InputError::OutOfMemory { .. })
        ));
    }
}
