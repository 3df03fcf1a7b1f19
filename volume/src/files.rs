//! Files and memory under hostile or careless use (see `docs/stability.md`, "Hostile use").
//!
//! Every surface of the baker (its library front door `pinbake::plan`, the command-line tools
//! `pinbake` and `pinrender`, the Python extension) goes through these checks for every path
//! and every size that comes from a user:
//!
//! * inputs must be regular files ([`check_input`], [`read_input`]): a FIFO would block
//!   forever, `/dev/zero` would be read until memory runs out, a directory has no bytes;
//! * outputs may only be a new path or an existing regular file that is not one of the
//!   inputs ([`check_output`]): renaming over a device node or a symlink to one replaces it,
//!   and writing over the input destroys it before it has been read; two outputs of one
//!   command may not name the same file ([`check_outputs_among`]), or one would silently
//!   replace the other;
//! * the files one command writes land together ([`write_together`]): each is written to a
//!   temp file beside its target and all are renamed only once every one is written, so a
//!   failure (a full disk, an interrupt) leaves every earlier file as it was;
//! * every allocation whose size comes from input or flags is first compared with a memory
//!   budget ([`MemoryBudget`], default: half of the physical memory) and then made fallibly;
//! * the temporary `.NAME.*.partial` file of an atomic write is announced to a hook
//!   ([`watch_partial_files`]) that the binaries point at their signal handlers, so that
//!   SIGINT, SIGTERM and SIGHUP unlink it; those a SIGKILL leaves behind are removed by the
//!   next write to the same target (`pin_format::AtomicPinFile::create`).

use std::fs::{File, Metadata};
use std::io::Read;
use std::path::{Path, PathBuf};

/// Why a path or a size was refused. Messages are one line and name the file.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    #[error("{}: is a directory", .0.display())]
    IsDirectory(PathBuf),
    /// A device, FIFO or socket (or a symlink to one).
    #[error("{}: not a regular file", .0.display())]
    NotRegular(PathBuf),
    #[error(
        "{}: is the input file {}; refusing to overwrite it (choose another output)",
        .output.display(),
        .input.display()
    )]
    SameAsInput { output: PathBuf, input: PathBuf },
    #[error(
        "{}: is also the output {}; two outputs of one command must name different files",
        .second.display(),
        .first.display()
    )]
    SameOutput { first: PathBuf, second: PathBuf },
    #[error("{}: is a symlink to a missing file; refusing to replace the link", .0.display())]
    DanglingSymlink(PathBuf),
    #[error(
        "{}: not a private directory (must be a directory of this user that nobody else can write)",
        .0.display()
    )]
    NotPrivate(PathBuf),
    /// The OS error is part of the message and deliberately not a `source()`: an error
    /// chain printer would otherwise print it twice.
    #[error("{}: {err}", .path.display())]
    Io { path: PathBuf, err: std::io::Error },
    #[error("{what} needs {} bytes, more than the memory budget of {} bytes (--max-memory)", .need, .limit)]
    Memory { what: String, need: u64, limit: u64 },
    #[error("{}: writing needs about {need} bytes, more than the {free} bytes free on its file system", .path.display())]
    Disk { path: PathBuf, need: u64, free: u64 },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> FileError + '_ {
    move |err| FileError::Io {
        path: path.to_path_buf(),
        err,
    }
}

impl From<pin_format::input::InputError> for FileError {
    fn from(e: pin_format::input::InputError) -> Self {
        use pin_format::input::InputError as E;
        match e {
            E::IsDirectory(p) => FileError::IsDirectory(p),
            E::NotRegular(p) => FileError::NotRegular(p),
            E::Io { path, err } => FileError::Io { path, err },
            E::OutOfMemory { path, bytes } => FileError::Memory {
                what: format!("reading {}", path.display()),
                need: bytes,
                limit: 0,
            },
        }
    }
}

/// Checks that `path` names a regular file (symlinks followed) and returns its length.
/// `stat` never blocks, so a FIFO is refused here before anything opens it. The rule is
/// `pin_format::input`'s, which every reader of the workspace follows.
pub fn check_input(path: &Path) -> Result<u64, FileError> {
    Ok(pin_format::input::check_regular(path)?)
}

/// Opens `path` for reading only if it is a regular file (`pin_format::input::open_regular`:
/// non-blocking, the type checked again on the open descriptor).
pub fn open_input(path: &Path) -> Result<(File, u64), FileError> {
    Ok(pin_format::input::open_regular(path)?)
}

/// Reads a whole regular file into a buffer whose start is 8-byte aligned (pin files are
/// cast in place), after checking its length against `budget`.
pub fn read_input(path: &Path, budget: &MemoryBudget) -> Result<Vec<u8>, FileError> {
    let (f, len) = open_input(path)?;
    budget.check(&format!("reading {}", path.display()), len)?;
    let mut bytes = Vec::new();
    try_alloc(&mut bytes, len, path)?;
    // One byte more than the length: a file that grows while being read is not read forever,
    // and the pin reader's size check reports the difference.
    f.take(len.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(io(path))?;
    Ok(bytes)
}

fn try_alloc(v: &mut Vec<u8>, len: u64, path: &Path) -> Result<(), FileError> {
    let n = usize::try_from(len).unwrap_or(usize::MAX);
    v.try_reserve_exact(n).map_err(|_| FileError::Memory {
        what: format!("reading {}", path.display()),
        need: len,
        limit: 0,
    })
}

/// The files a command reads, identified once by device and inode, so that an output is
/// compared with any number of them in constant time: a sequence compares every frame's
/// output with every frame's input (frame 1's output may name frame 10's input).
#[derive(Debug, Default)]
pub struct InputSet {
    files: std::collections::HashMap<(u64, u64), PathBuf>,
}

/// Bytes one [`InputSet`] entry may take beyond its path (key, hash slot, `PathBuf`), for
/// callers that count the set against a [`MemoryBudget`].
pub const INPUT_SET_ENTRY_BYTES: u64 = 96;

impl InputSet {
    /// The set of `inputs` (see [`InputSet::add`]).
    pub fn of(inputs: &[&Path]) -> Result<Self, FileError> {
        let mut set = Self::default();
        for input in inputs {
            set.add(input)?;
        }
        Ok(set)
    }

    /// Adds `path` if it exists (a missing input fails on its own when it is read). Returns
    /// whether it exists. The entry is allocated fallibly.
    pub fn add(&mut self, path: &Path) -> Result<bool, FileError> {
        let m = match std::fs::metadata(path) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
            // Unreadable for another reason (permissions): it cannot be compared, and the
            // bake that reads it fails with this error itself.
            Err(_) => return Ok(true),
        };
        if let Some(id) = file_id(&m) {
            self.files.try_reserve(1).map_err(|_| FileError::Memory {
                what: "the list of input files".into(),
                need: INPUT_SET_ENTRY_BYTES.saturating_mul(self.files.len() as u64 + 1),
                limit: 0,
            })?;
            self.files.entry(id).or_insert_with(|| path.to_path_buf());
        }
        Ok(true)
    }

    /// The number of distinct existing files.
    pub fn len(&self) -> usize {
        self.files.len()
    }

    pub fn is_empty(&self) -> bool {
        self.files.is_empty()
    }

    /// Checks an output path against the output rule and returns the path to write to.
    ///
    /// Accepted: a path that does not exist yet, or an existing regular file that is none
    /// of the inputs (same device and inode; hard links and symlinks count as the same
    /// file). A symlink to a regular file is resolved, so the write replaces the file it
    /// points to and the link stays. Refused: directories, devices, FIFOs, sockets,
    /// symlinks to them and dangling symlinks.
    pub fn check_output(&self, output: &Path) -> Result<PathBuf, FileError> {
        check_output_among(output, &[self])
    }
}

/// [`InputSet::check_output`] against the union of `sets`, with the output looked at once
/// (a bake compares it with the caller's inputs and with its own).
pub fn check_output_among(output: &Path, sets: &[&InputSet]) -> Result<PathBuf, FileError> {
    let link = match std::fs::symlink_metadata(output) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Ok(output.to_path_buf());
        }
        Err(e) => return Err(io(output)(e)),
    };
    let target = match std::fs::metadata(output) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound && link.is_symlink() => {
            return Err(FileError::DanglingSymlink(output.to_path_buf()));
        }
        Err(e) => return Err(io(output)(e)),
    };
    pin_format::input::require_regular(output, &target)?;
    let id = file_id(&target);
    if let Some(input) = id.and_then(|id| sets.iter().find_map(|s| s.files.get(&id))) {
        return Err(FileError::SameAsInput {
            output: output.to_path_buf(),
            input: input.clone(),
        });
    }
    if link.is_symlink() {
        return std::fs::canonicalize(output).map_err(io(output));
    }
    Ok(output.to_path_buf())
}

/// [`InputSet::check_output`] against `inputs`. Missing inputs are ignored (they fail on
/// their own).
pub fn check_output(output: &Path, inputs: &[&Path]) -> Result<PathBuf, FileError> {
    InputSet::of(inputs)?.check_output(output)
}

/// The output rule for every output of one command: each passes [`check_output_among`]
/// against `sets`, and no two of them name the same file (the same device and inode for
/// existing files, symlinks and hard links followed; the same directory and name for new
/// ones). Returns the paths to write to, in the order given.
pub fn check_outputs_among(
    outputs: &[&Path],
    sets: &[&InputSet],
) -> Result<Vec<PathBuf>, FileError> {
    let mut checked: Vec<(PathBuf, OutputId)> = Vec::with_capacity(outputs.len());
    for (i, output) in outputs.iter().enumerate() {
        let target = check_output_among(output, sets)?;
        let id = output_id(&target);
        if let Some(j) = checked.iter().position(|(_, other)| *other == id) {
            return Err(FileError::SameOutput {
                first: outputs[j].to_path_buf(),
                second: outputs[i].to_path_buf(),
            });
        }
        checked.push((target, id));
    }
    Ok(checked.into_iter().map(|(p, _)| p).collect())
}

/// [`check_outputs_among`] against `inputs`.
pub fn check_outputs(outputs: &[&Path], inputs: &[&Path]) -> Result<Vec<PathBuf>, FileError> {
    check_outputs_among(outputs, &[&InputSet::of(inputs)?])
}

/// What an output path will write to, for comparing two outputs: an existing file by its
/// identity, a new one by its directory (resolved) and name.
#[derive(Debug, PartialEq, Eq)]
enum OutputId {
    Existing((u64, u64)),
    New(PathBuf),
}

fn output_id(target: &Path) -> OutputId {
    if let Some(id) = std::fs::metadata(target).ok().as_ref().and_then(file_id) {
        return OutputId::Existing(id);
    }
    let dir = parent_dir(target);
    let dir = std::fs::canonicalize(&dir).unwrap_or(dir);
    OutputId::New(match target.file_name() {
        Some(name) => dir.join(name),
        None => target.to_path_buf(),
    })
}

/// Writes one file of [`write_together`] into the temp file it is given (buffered, seekable
/// for formats that patch their offsets). Its error is reported against the target's path.
pub type WriteFile<'a> = Box<dyn FnOnce(&mut std::io::BufWriter<File>) -> std::io::Result<()> + 'a>;

/// Writes several files as one: each `(target, write)` to a temp file `.NAME.*.partial`
/// beside its target, synced, and only once every one of them is written are they renamed
/// into place, in order. A failure before the renames (a full disk, a write error, an
/// interrupt) removes the temp files and leaves every target as it was: an EXR and its PNG
/// land together or not at all. Targets must have passed [`check_outputs_among`].
///
/// The temp file being written is announced to the [`watch_partial_files`] hook; the hook
/// holds one path, so an interrupt while a later file is written leaves the earlier temp
/// files (never a target) behind. Callers encode before calling this, so that the window
/// is the few milliseconds of the writes themselves.
pub fn write_together(files: Vec<(PathBuf, WriteFile<'_>)>) -> Result<(), FileError> {
    let mut staged: Vec<(tempfile::TempPath, PathBuf)> = Vec::with_capacity(files.len());
    for (target, write) in files {
        let dir = parent_dir(&target);
        let name = target
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let announced = Announced;
        let temp = tempfile::Builder::new()
            .prefix(&format!(".{name}."))
            .suffix(".partial")
            .make_in(&dir, |path| {
                announce_partial(Some(path));
                // 0666 narrowed by the umask, as `File::create` gives: an image is a file
                // others read, where tempfile would create it 0600.
                let mut o = std::fs::OpenOptions::new();
                o.read(true).write(true).create_new(true);
                #[cfg(unix)]
                std::os::unix::fs::OpenOptionsExt::mode(&mut o, 0o666);
                o.open(path)
            })
            .map_err(io(&target))?;
        let (file, temp) = temp.into_parts();
        let mut out = std::io::BufWriter::with_capacity(1 << 20, file);
        let written = write(&mut out)
            .and_then(|()| out.into_inner().map_err(|e| e.into_error()))
            .and_then(|f| f.sync_all());
        // The temp file is removed (TempPath's drop) before its announcement ends.
        if let Err(err) = written {
            drop(temp);
            drop(announced);
            drop(staged);
            return Err(FileError::Io { path: target, err });
        }
        drop(announced);
        staged.push((temp, target));
    }
    for (temp, target) in staged {
        temp.persist(&target).map_err(|e| FileError::Io {
            path: target.clone(),
            err: e.error,
        })?;
        // The rename made durable where the file system supports it.
        if let Ok(d) = File::open(parent_dir(&target)) {
            let _ = d.sync_all();
        }
    }
    Ok(())
}

#[cfg(unix)]
fn file_id(m: &Metadata) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    Some((m.dev(), m.ino()))
}

#[cfg(not(unix))]
fn file_id(_: &Metadata) -> Option<(u64, u64)> {
    None
}

/// Creates `dir` (and its parents) with mode 0700 if missing, then refuses it unless it is
/// a real directory (not a symlink) owned by this user that no one else can write: a cache
/// there cannot be planted or swapped by another user.
pub fn ensure_private_dir(dir: &Path) -> Result<(), FileError> {
    let mut b = std::fs::DirBuilder::new();
    b.recursive(true);
    #[cfg(unix)]
    std::os::unix::fs::DirBuilderExt::mode(&mut b, 0o700);
    b.create(dir).map_err(io(dir))?;
    let m = std::fs::symlink_metadata(dir).map_err(io(dir))?;
    if !m.is_dir() {
        return Err(FileError::NotPrivate(dir.to_path_buf()));
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        // SAFETY: geteuid has no preconditions.
        let me = unsafe { libc::geteuid() };
        if m.uid() != me || m.mode() & 0o022 != 0 {
            return Err(FileError::NotPrivate(dir.to_path_buf()));
        }
    }
    Ok(())
}

/// A ceiling on the bytes one command may allocate for data whose size comes from input or
/// flags. Sizes are checked against it before the allocation, which is then made with
/// `try_reserve`: an overcommitting kernel would otherwise accept a 500 GB request and kill
/// the process (or a neighbour) later, and an allocation failure aborts without a message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryBudget {
    pub limit: u64,
}

impl MemoryBudget {
    /// `--max-memory` if given, else [`default_memory_limit`].
    pub fn new(limit: Option<u64>) -> Self {
        Self {
            limit: limit.unwrap_or_else(default_memory_limit),
        }
    }

    /// Refuses `need` bytes for `what` above the limit.
    pub fn check(&self, what: &str, need: u64) -> Result<(), FileError> {
        if need > self.limit {
            return Err(FileError::Memory {
                what: what.to_string(),
                need,
                limit: self.limit,
            });
        }
        Ok(())
    }
}

/// Bytes that an unprivileged writer may still write to the file system holding `dir`, if
/// the system says.
pub fn free_space(dir: &Path) -> Option<u64> {
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStrExt;
        let path = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
        // SAFETY: `path` is a NUL-terminated string and `st` a writable statvfs that the call
        // fills on success; it is read only then.
        let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
        if unsafe { libc::statvfs(path.as_ptr(), &mut st) } != 0 {
            return None;
        }
        #[allow(clippy::unnecessary_cast)] // the field types differ between systems
        Some((st.f_bavail as u64).saturating_mul(st.f_frsize as u64))
    }
    #[cfg(not(unix))]
    {
        let _ = dir;
        None
    }
}

/// Refuses to write `need` bytes to `path` (a file to be written, or a directory to write
/// into) when its file system has less free: a bake that would fill the disk stops before
/// its first byte, not when the disk is full. Passes where the system cannot tell.
pub fn check_free_space(path: &Path, need: u64) -> Result<(), FileError> {
    let dir = if path.is_dir() {
        path.to_path_buf()
    } else {
        parent_dir(path)
    };
    check_free(path, need, free_space(&dir))
}

fn check_free(path: &Path, need: u64, free: Option<u64>) -> Result<(), FileError> {
    match free {
        Some(free) if need > free => Err(FileError::Disk {
            path: path.to_path_buf(),
            need,
            free,
        }),
        _ => Ok(()),
    }
}

/// Half of the physical memory (or of the cgroup's limit when lower), 4 GiB if unknown:
/// leaves room for the rest of the machine and for the estimates' slack.
pub fn default_memory_limit() -> u64 {
    physical_memory().map_or(4 << 30, |m| m / 2)
}

/// Physical memory in bytes, capped by a cgroup v2 `memory.max` when one is set.
pub fn physical_memory() -> Option<u64> {
    #[cfg(unix)]
    let phys = {
        // SAFETY: sysconf has no preconditions.
        let (pages, size) = unsafe {
            (
                libc::sysconf(libc::_SC_PHYS_PAGES),
                libc::sysconf(libc::_SC_PAGESIZE),
            )
        };
        (pages > 0 && size > 0).then(|| (pages as u64).saturating_mul(size as u64))
    };
    #[cfg(not(unix))]
    let phys: Option<u64> = None;
    let cgroup = std::fs::read_to_string("/sys/fs/cgroup/memory.max")
        .ok()
        .and_then(|s| s.trim().parse::<u64>().ok());
    match (phys, cgroup) {
        (Some(p), Some(c)) => Some(p.min(c)),
        (p, c) => p.or(c),
    }
}

/// The directory that holds `path` (`.` for a bare file name).
pub fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Writes `grid` atomically to `target` (temp file beside it, fsync, rename), with the temp
/// file announced to the [`watch_partial_files`] hook while it exists.
pub fn write_pin_atomic(
    grid: &pin_format::OwnedPinGrid,
    target: &Path,
) -> Result<(), pin_format::FormatError> {
    PendingPin::create(target)?.write(grid)
}

/// Where the partial files of atomic writes are announced: `Some(path)` before the file is
/// created, `None` once it is gone (renamed into place or removed).
pub type PartialFileHook = fn(Option<&Path>);

static PARTIAL_FILE_HOOK: std::sync::OnceLock<PartialFileHook> = std::sync::OnceLock::new();

/// Sets the hook (once per process; a later call is ignored) that hears of every partial
/// `.NAME.*.partial` file this library writes. The binaries point it at
/// `pin_cli::signals::track`, so that an interrupt unlinks the file. A library sets no signal
/// handlers of its own: that would take Ctrl-C away from its host (Python's
/// `KeyboardInterrupt`); without a hook, a file left by a killed process is removed by the
/// next write to the same target (`pin_format::AtomicPinFile::create`).
pub fn watch_partial_files(hook: PartialFileHook) {
    let _ = PARTIAL_FILE_HOOK.set(hook);
}

fn announce_partial(path: Option<&Path>) {
    if let Some(hook) = PARTIAL_FILE_HOOK.get() {
        hook(path);
    }
}

/// Announces `path` as a partial file to the [`watch_partial_files`] hook, and its end when
/// the guard drops: for an atomic write that is not a pin file's.
pub fn announce_partial_file(path: &Path) -> Announced {
    announce_partial(Some(path));
    Announced
}

/// Announces `None` when the partial file is gone.
pub struct Announced;

impl Drop for Announced {
    fn drop(&mut self) {
        announce_partial(None);
    }
}

/// A pin file whose temp file is created (and announced to [`watch_partial_files`]) before
/// the work that produces the grid: a long bake holds its `.NAME.*.partial` from the start,
/// so an interrupted bake is cleaned up the same way as an interrupted write.
pub struct PendingPin {
    // Declared first so that it drops first: the announcement that the file is gone comes
    // after the file is removed (or renamed), never before.
    file: pin_format::AtomicPinFile,
    _announced: Announced,
}

impl PendingPin {
    pub fn create(target: &Path) -> Result<Self, pin_format::FormatError> {
        // Announced before the file exists (see `AtomicPinFile::create_announced`): a signal
        // that arrives once the file is there always finds its path.
        let announced = Announced;
        let file = pin_format::AtomicPinFile::create_announced(target, announce_partial)?;
        Ok(Self {
            file,
            _announced: announced,
        })
    }

    /// The temporary file's path.
    pub fn temp_path(&self) -> &Path {
        self.file.temp_path()
    }

    pub fn write(mut self, grid: &pin_format::OwnedPinGrid) -> Result<(), pin_format::FormatError> {
        grid.write_into(self.file.writer())?;
        self.file.commit()
    }

    /// [`PendingPin::write`], with the sparse density streamed from `sparse` when there is
    /// one (the spool of `pinbake::bake::bake_spooled`).
    pub fn write_spooled(
        mut self,
        grid: &pin_format::OwnedPinGrid,
        sparse: Option<pin_format::StreamedSparseDensity<'_>>,
    ) -> Result<(), pin_format::FormatError> {
        match sparse {
            None => grid.write_into(self.file.writer())?,
            Some(s) => grid.write_streamed_into(self.file.writer(), s)?,
        }
        self.file.commit()
    }
}

/// Hex xxh3-128 of a file, streamed (a large volume is not read twice into memory): the
/// metadata's source hash.
pub fn hash_file(path: &Path) -> Result<String, FileError> {
    let (mut f, _) = open_input(path)?;
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = f.read(&mut buf).map_err(|err| FileError::Io {
            path: path.to_path_buf(),
            err,
        })?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(format!("{:032x}", h.digest128()))
}

#[cfg(test)]
mod tests {
    #[test]
    fn free_space_is_checked_against_the_need() {
        let dir = tempfile::tempdir().unwrap();
        let free = super::free_space(dir.path()).expect("statvfs answers on a temp dir");
        assert!(free > 0);
        assert!(super::check_free_space(dir.path(), 1).is_ok());
        let e = super::check_free_space(&dir.path().join("out.pin"), u64::MAX).unwrap_err();
        let line = e.to_string();
        assert!(
            line.contains("out.pin") && line.contains(&u64::MAX.to_string()),
            "{line}"
        );
        assert!(line.contains(" bytes free"), "{line}");
        // Unknown free space passes; a known one refuses exactly above it.
        assert!(super::check_free(dir.path(), u64::MAX, None).is_ok());
        assert!(super::check_free(dir.path(), 10, Some(10)).is_ok());
        assert!(super::check_free(dir.path(), 11, Some(10)).is_err());
    }

    use super::*;

    #[test]
    fn outputs_new_regular_and_refused() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in.raw");
        std::fs::write(&input, b"abc").unwrap();
        let new = dir.path().join("new.pin");
        assert_eq!(check_output(&new, &[&input]).unwrap(), new);
        let old = dir.path().join("old.pin");
        std::fs::write(&old, b"x").unwrap();
        assert_eq!(check_output(&old, &[&input]).unwrap(), old);
        assert!(matches!(
            check_output(&input, &[&input]),
            Err(FileError::SameAsInput { .. })
        ));
        assert!(matches!(
            check_output(dir.path(), &[]),
            Err(FileError::IsDirectory(_))
        ));
        #[cfg(unix)]
        {
            let hard = dir.path().join("hard.raw");
            std::fs::hard_link(&input, &hard).unwrap();
            assert!(matches!(
                check_output(&hard, &[&input]),
                Err(FileError::SameAsInput { .. })
            ));
            let link = dir.path().join("link.pin");
            std::os::unix::fs::symlink(&old, &link).unwrap();
            assert_eq!(
                check_output(&link, &[&input]).unwrap(),
                std::fs::canonicalize(&old).unwrap()
            );
            let dangling = dir.path().join("dangling.pin");
            std::os::unix::fs::symlink(dir.path().join("nothing"), &dangling).unwrap();
            assert!(matches!(
                check_output(&dangling, &[]),
                Err(FileError::DanglingSymlink(_))
            ));
            let fifo = dir.path().join("fifo");
            let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
            assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
            assert!(matches!(
                check_output(&fifo, &[]),
                Err(FileError::NotRegular(_))
            ));
            let to_fifo = dir.path().join("to_fifo.pin");
            std::os::unix::fs::symlink(&fifo, &to_fifo).unwrap();
            assert!(matches!(
                check_output(&to_fifo, &[]),
                Err(FileError::NotRegular(_))
            ));
            // The same FIFO as an input: refused by stat, without blocking on open.
            assert!(matches!(open_input(&fifo), Err(FileError::NotRegular(_))));
        }
    }

    #[test]
    fn an_input_set_refuses_every_member_as_output() {
        let dir = tempfile::tempdir().unwrap();
        let paths: Vec<PathBuf> = (0..50)
            .map(|i| dir.path().join(format!("f{i}.raw")))
            .collect();
        for p in &paths {
            std::fs::write(p, b"x").unwrap();
        }
        let mut set = InputSet::default();
        for p in &paths {
            assert!(set.add(p).unwrap());
        }
        assert!(!set.add(&dir.path().join("missing.raw")).unwrap());
        assert_eq!(set.len(), 50);
        for p in &paths {
            assert!(matches!(
                set.check_output(p),
                Err(FileError::SameAsInput { .. })
            ));
        }
        let other = dir.path().join("other.pin");
        std::fs::write(&other, b"y").unwrap();
        assert_eq!(set.check_output(&other).unwrap(), other);
    }

    #[test]
    fn inputs_must_be_regular_and_fit_the_budget() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(
            check_input(dir.path()).unwrap_err().to_string(),
            format!("{}: is a directory", dir.path().display())
        );
        let f = dir.path().join("f");
        std::fs::write(&f, [1u8; 100]).unwrap();
        let big = MemoryBudget { limit: 1000 };
        assert_eq!(read_input(&f, &big).unwrap(), vec![1u8; 100]);
        let small = MemoryBudget { limit: 99 };
        assert!(matches!(
            read_input(&f, &small),
            Err(FileError::Memory { need: 100, .. })
        ));
        #[cfg(unix)]
        assert!(matches!(
            check_input(Path::new("/dev/zero")),
            Err(FileError::NotRegular(_))
        ));
    }

    #[test]
    fn error_lines_print_each_cause_once() {
        let e = FileError::Io {
            path: PathBuf::from("a.pin"),
            err: std::io::Error::from(std::io::ErrorKind::NotFound),
        };
        #[derive(Debug, thiserror::Error)]
        #[error("{path}: {source}")]
        struct Twice {
            path: String,
            source: std::io::Error,
        }
        let t = Twice {
            path: "b.pin".into(),
            source: std::io::Error::from(std::io::ErrorKind::NotFound),
        };
        use pin_format::text::error_line;
        assert_eq!(error_line(&e), "a.pin: entity not found");
        assert_eq!(error_line(&t), "b.pin: entity not found");
    }

    #[test]
    #[cfg(unix)]
    fn private_dirs() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let cache = dir.path().join("a/pinbake");
        ensure_private_dir(&cache).unwrap();
        let mode = std::fs::metadata(&cache).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o700);
        std::fs::set_permissions(&cache, std::fs::Permissions::from_mode(0o777)).unwrap();
        assert!(matches!(
            ensure_private_dir(&cache),
            Err(FileError::NotPrivate(_))
        ));
        let link = dir.path().join("link");
        std::os::unix::fs::symlink(&cache, &link).unwrap();
        assert!(ensure_private_dir(&link).is_err());
    }

    #[test]
    fn physical_memory_is_known() {
        assert!(physical_memory().is_some_and(|m| m > 1 << 20));
    }
}
