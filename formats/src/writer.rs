//! Streaming writer: sections go out one after another, the table and header last.
//!
//! The header is written as zeros first and patched at the end, so nothing is held in memory
//! but the small section table. [`AtomicPinFile`] adds the temp-file + fsync + rename dance so
//! that a killed writer never leaves a partial file under the target name.

use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use bytemuck::Zeroable;

use crate::checksum::{StreamingChecksum, checksum, header_checksum};
use crate::error::{FormatError, Result};
use crate::layout::{
    FileHeader, MAGIC, MAX_SECTIONS, SECTION_ALIGN, SectionEntry, SectionKind, VERSION_MAJOR,
    VERSION_MINOR, VERSION_MINOR_SPARSE_DENSITY,
};

struct OpenSection {
    kind: u32,
    flags: u32,
    offset: u64,
    hasher: StreamingChecksum,
}

/// Writes a pin file to any seekable byte sink.
pub struct PinFileWriter<W: Write + Seek> {
    out: W,
    pos: u64,
    sections: Vec<SectionEntry>,
    open: Option<OpenSection>,
}

const ZEROS: [u8; SECTION_ALIGN as usize] = [0; SECTION_ALIGN as usize];

impl<W: Write + Seek> PinFileWriter<W> {
    /// Starts a file at the sink's current position, which must be its start.
    pub fn new(mut out: W) -> Result<Self> {
        out.write_all(bytemuck::bytes_of(&FileHeader::zeroed()))?;
        Ok(Self {
            out,
            pos: size_of::<FileHeader>() as u64,
            sections: Vec::new(),
            open: None,
        })
    }

    fn pad_to_alignment(&mut self) -> Result<()> {
        let rem = self.pos % SECTION_ALIGN;
        if rem != 0 {
            let pad = (SECTION_ALIGN - rem) as usize;
            self.out.write_all(&ZEROS[..pad])?;
            self.pos += pad as u64;
        }
        Ok(())
    }

    /// Opens a section of raw kind `kind`; follow with [`write`](Self::write) calls and
    /// [`end_section`](Self::end_section).
    pub fn begin_section(&mut self, kind: u32, flags: u32) -> Result<()> {
        if self.open.is_some() {
            return Err(FormatError::InvalidInput(
                "begin_section while another section is open".into(),
            ));
        }
        if self.sections.len() >= MAX_SECTIONS as usize {
            return Err(FormatError::InvalidInput("too many sections".into()));
        }
        self.pad_to_alignment()?;
        self.open = Some(OpenSection {
            kind,
            flags,
            offset: self.pos,
            hasher: StreamingChecksum::new(),
        });
        Ok(())
    }

    /// Appends bytes to the open section.
    pub fn write(&mut self, bytes: &[u8]) -> Result<()> {
        let open = self
            .open
            .as_mut()
            .ok_or_else(|| FormatError::InvalidInput("write with no open section".into()))?;
        open.hasher.update(bytes);
        self.out.write_all(bytes)?;
        self.pos += bytes.len() as u64;
        Ok(())
    }

    pub fn end_section(&mut self) -> Result<()> {
        let open = self
            .open
            .take()
            .ok_or_else(|| FormatError::InvalidInput("end_section with no open section".into()))?;
        self.sections.push(SectionEntry {
            kind: open.kind,
            flags: open.flags,
            offset: open.offset,
            length: self.pos - open.offset,
            checksum: open.hasher.digest(),
        });
        Ok(())
    }

    /// A whole section in one call.
    pub fn add_section(&mut self, kind: u32, flags: u32, bytes: &[u8]) -> Result<()> {
        self.begin_section(kind, flags)?;
        self.write(bytes)?;
        self.end_section()
    }

    /// Writes the section table and the header; returns the sink.
    pub fn finish(mut self) -> Result<W> {
        if self.open.is_some() {
            return Err(FormatError::InvalidInput(
                "finish while a section is open".into(),
            ));
        }
        self.pad_to_alignment()?;
        let table_offset = self.pos;
        let table: &[u8] = bytemuck::cast_slice(&self.sections);
        self.out.write_all(table)?;
        self.pos += table.len() as u64;
        let mut header = FileHeader {
            magic: MAGIC,
            version_major: VERSION_MAJOR,
            version_minor: version_minor(&self.sections),
            header_size: size_of::<FileHeader>() as u32,
            section_count: self.sections.len() as u32,
            section_entry_size: size_of::<SectionEntry>() as u32,
            table_offset,
            file_size: self.pos,
            flags: 0,
            table_checksum: checksum(table),
            header_checksum: 0,
        };
        header.header_checksum = header_checksum(&header);
        self.out.seek(SeekFrom::Start(0))?;
        self.out.write_all(bytemuck::bytes_of(&header))?;
        self.out.seek(SeekFrom::Start(self.pos))?;
        self.out.flush()?;
        Ok(self.out)
    }
}

/// The lowest minor version that can describe `sections`: 1.0 unless a 1.1 section (sparse
/// density, control) is there, so that files without one stay byte-identical 1.0 files.
fn version_minor(sections: &[SectionEntry]) -> u16 {
    let newer = [
        SectionKind::SparseDensity as u32,
        SectionKind::Control as u32,
    ];
    if sections.iter().any(|s| newer.contains(&s.kind)) {
        VERSION_MINOR_SPARSE_DENSITY
    } else {
        VERSION_MINOR
    }
}

/// Length of the random part of a temp file name (tempfile's default, set explicitly below).
const TEMP_RAND_LEN: usize = 6;

/// Removes `PREFIX*.partial` files in `dir` that no live writer holds: temp files of writes
/// to the same target that were killed before they could clean up (SIGKILL, power loss).
/// A writer holds an exclusive lock on its temp file from creation to rename, so a file whose
/// lock can be taken belongs to nobody. Failures are ignored: this is tidying, not the write.
fn remove_stale_partials(dir: &Path, prefix: &str) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(name) = name.to_str() else { continue };
        // Exactly PREFIX + tempfile's random part + ".partial": the temp files of "a" must
        // not match those of "a.pin".
        let Some(rand) = name
            .strip_prefix(prefix)
            .and_then(|r| r.strip_suffix(".partial"))
        else {
            continue;
        };
        if rand.len() != TEMP_RAND_LEN || !rand.bytes().all(|b| b.is_ascii_alphanumeric()) {
            continue;
        }
        // Only regular files (never follow a planted symlink), opened without blocking.
        if !e.file_type().is_ok_and(|t| t.is_file()) {
            continue;
        }
        let path = e.path();
        if let Ok(f) = File::open(&path)
            && f.try_lock().is_ok()
        {
            let _ = std::fs::remove_file(&path);
        }
    }
}

/// A pin file being written to a temporary file beside its final path.
///
/// [`commit`](Self::commit) fsyncs, renames over the target and fsyncs the directory. Dropping
/// without committing deletes the temporary file; the target is never touched until then.
pub struct AtomicPinFile {
    writer: PinFileWriter<BufWriter<File>>,
    temp: tempfile::TempPath,
    target: PathBuf,
}

impl AtomicPinFile {
    pub fn create(target: impl AsRef<Path>) -> Result<Self> {
        Self::create_announced(target, |_| {})
    }

    /// As [`create`](Self::create), telling `announce` the temp file's path *before* the
    /// file exists: `announce(Some(path))` just before each attempt to create it, and
    /// `announce(None)` when that attempt failed (the name was taken: the path is not ours).
    ///
    /// This is for a signal handler that unlinks the temp file: registered only after the
    /// creation, a signal between the two would leave the file behind. Registered before,
    /// a file that exists is always one the handler knows.
    pub fn create_announced(
        target: impl AsRef<Path>,
        mut announce: impl FnMut(Option<&Path>),
    ) -> Result<Self> {
        let target = target.as_ref().to_path_buf();
        let dir = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let name = target
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "pin".into());
        let prefix = format!(".{name}.");
        let mut builder = tempfile::Builder::new();
        builder
            .prefix(&prefix)
            .suffix(".partial")
            .rand_bytes(TEMP_RAND_LEN);
        remove_stale_partials(&dir, &prefix);
        let temp = builder.make_in(&dir, |path| {
            announce(Some(path));
            // What tempfile's own `tempfile_in` opens (read, write, create_new), but with
            // the mode `File::create` would give (0666, narrowed by the umask): a pin file
            // is an asset others read, where tempfile creates 0600 files.
            let mut o = std::fs::OpenOptions::new();
            o.read(true).write(true).create_new(true);
            #[cfg(unix)]
            std::os::unix::fs::OpenOptionsExt::mode(&mut o, 0o666);
            o.open(path).inspect_err(|_| announce(None))
        })?;
        let (file, temp) = temp.into_parts();
        // The lock marks the temp file as live for `remove_stale_partials` of other writers;
        // the kernel drops it when the process dies, however it dies. A filesystem without
        // locks fails the sweeper's lock attempt the same way, so the file is never swept
        // there, and the write itself does not need the lock.
        let _ = file.try_lock();
        let writer = PinFileWriter::new(BufWriter::with_capacity(1 << 20, file))?;
        Ok(Self {
            writer,
            temp,
            target,
        })
    }

    pub fn writer(&mut self) -> &mut PinFileWriter<BufWriter<File>> {
        &mut self.writer
    }

    /// Path of the temporary file (for tests that simulate a crash).
    pub fn temp_path(&self) -> &Path {
        &self.temp
    }

    pub fn commit(self) -> Result<()> {
        let buf = self.writer.finish()?;
        let file = buf.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        // Rename while the file (and its lock) is still open, so that a concurrent writer's
        // stale-file sweep cannot take it for litter between the close and the rename.
        self.temp.persist(&self.target).map_err(|e| e.error)?;
        drop(file);
        if let Some(dir) = self.target.parent() {
            let dir = if dir.as_os_str().is_empty() {
                Path::new(".")
            } else {
                dir
            };
            // Make the rename itself durable; some filesystems do not support this, which
            // only weakens durability, not atomicity.
            if let Ok(d) = File::open(dir) {
                let _ = d.sync_all();
            }
        }
        Ok(())
    }
}
