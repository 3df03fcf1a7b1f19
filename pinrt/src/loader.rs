//! Loading pin files: memory-mapped (O(1), zero-copy), read into memory, or from a buffer.
//!
//! ## Memory mapping and its one hazard
//!
//! [`PinGrid::open`] maps the file and validates its structure in O(number of sections); the
//! pin array is never copied or read until queries touch it, so opening a multi-gigabyte grid
//! is instant and pages are shared between processes. The price: if another process truncates
//! or rewrites the file *in place* while it is mapped, touching a vanished page raises
//! `SIGBUS` and kills the process (a Rust program cannot catch that). Pin files written by
//! `pin_format`'s atomic writer are replaced by rename, which is safe (the mapping keeps the old
//! inode alive). If you cannot rule out in-place modification (network file systems, files
//! owned by other tools), use [`PinGrid::read_into_memory`], which copies the file once.

use std::path::{Path, PathBuf};

use pin_format::{GridDesc, GridShape, PinEntry, PinFile};

use crate::error::{Error, Result};
use crate::lookup::GridView;

/// The name of a grid that has no file, in messages.
const MEMORY: &str = "<memory>";

enum Storage {
    Mmap(memmap2::Mmap),
    Bytes(Vec<u8>),
    /// 8-byte aligned copy: the words and the byte length.
    Words(Vec<u64>, usize),
}

impl Storage {
    fn bytes(&self) -> &[u8] {
        match self {
            Storage::Mmap(m) => m,
            Storage::Bytes(v) => v,
            Storage::Words(w, len) => &bytemuck::cast_slice(w)[..*len],
        }
    }

    /// An 8-byte aligned copy, allocated fallibly.
    fn aligned_copy(bytes: &[u8]) -> Result<Storage> {
        let mut words = pin_format::input::zeroed_words(bytes.len().div_ceil(8), Path::new(MEMORY))
            .map_err(Error::Input)?;
        bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..bytes.len()].copy_from_slice(bytes);
        Ok(Storage::Words(words, bytes.len()))
    }
}

/// A loaded, structurally validated pin grid that owns (or maps) its bytes.
///
/// `PinGrid` is `Send + Sync`: any number of threads may sample one grid concurrently.
///
/// **Memory mapping and its one hazard.** [`PinGrid::open`] maps the file: if another process
/// truncates or rewrites the file *in place* while it is mapped, touching a vanished page
/// raises `SIGBUS` and kills the process. Files replaced by rename (as `pin_format`'s atomic
/// writer does) are safe. Where in-place modification cannot be ruled out, use
/// [`PinGrid::read_into_memory`], which copies the file once.
pub struct PinGrid {
    storage: Storage,
    path: Option<PathBuf>,
    desc: GridDesc,
    shape: GridShape,
    /// Byte offset and length of the pin array.
    pins: (usize, usize),
    /// Byte offset and length of the cell index, if the grid is sparse.
    index: Option<(usize, usize)>,
}

impl std::fmt::Debug for PinGrid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PinGrid")
            .field("path", &self.path)
            .field("shape", &self.shape)
            .field("pins", &self.pins().len())
            .field("sparse", &self.index.is_some())
            .field("mapped", &matches!(self.storage, Storage::Mmap(_)))
            .finish()
    }
}

fn offset_in(outer: &[u8], inner: &[u8]) -> usize {
    if inner.is_empty() {
        return 0;
    }
    inner.as_ptr() as usize - outer.as_ptr() as usize
}

impl PinGrid {
    fn from_storage(storage: Storage, path: Option<PathBuf>) -> Result<Self> {
        let name = || path.clone().unwrap_or_else(|| PathBuf::from(MEMORY));
        let bytes = storage.bytes();
        let file = PinFile::parse(bytes).map_err(|source| Error::Format {
            path: name(),
            source,
        })?;
        let pins_bytes: &[u8] = bytemuck::cast_slice(file.pins());
        let pins = (offset_in(bytes, pins_bytes), pins_bytes.len());
        let index = file.cell_index().map(|ix| {
            let b: &[u8] = bytemuck::cast_slice(ix);
            (offset_in(bytes, b), b.len())
        });
        let desc = *file.desc();
        let shape = *file.shape();
        drop(file);
        Ok(Self {
            storage,
            path,
            desc,
            shape,
            pins,
            index,
        })
    }

    /// Memory-maps `path` and validates its structure: O(1) in the grid size, no copy.
    /// See the module docs for the `SIGBUS` hazard of mapped files modified in place.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        // A regular file only, opened without blocking: a FIFO would block forever.
        let (file, _) = pin_format::input::open_regular(path).map_err(Error::Input)?;
        // SAFETY: the mapping is read-only; the documented hazard is external truncation or
        // in-place modification of the file while mapped (SIGBUS / changing bytes). Every
        // value read from it is validated or sanitised before use, so changed bytes cannot
        // cause memory unsafety, only wrong answers.
        let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_storage(Storage::Mmap(map), Some(path.to_path_buf()))
    }

    /// [`PinGrid::open`] then [`PinGrid::verify`]: every section's checksum and every value
    /// checked before the grid is returned, each section in one pass over its bytes (linear
    /// in the file size). For pipelines that want damage refused at open rather than found
    /// by a later `verify`: a plain open checks the structure only, and a sampler reads the
    /// pins lazily, unchecked (`docs/format.md` section 9 says what is checked when).
    pub fn open_checked(path: impl AsRef<Path>) -> Result<Self> {
        let grid = Self::open(path)?;
        grid.verify()?;
        Ok(grid)
    }

    /// Reads the whole file into an aligned buffer: immune to later changes of the file.
    /// The buffer is allocated fallibly: a file larger than memory is an error.
    pub fn read_into_memory(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let (words, len) = pin_format::input::read_aligned(path).map_err(Error::Input)?;
        // A file that grew since it was opened is caught by the size check in the header.
        Self::from_storage(Storage::Words(words, len), Some(path.to_path_buf()))
    }

    /// Takes ownership of a buffer (copied once into an aligned buffer if it is not 8-aligned).
    pub fn from_bytes(bytes: Vec<u8>) -> Result<Self> {
        let storage = if (bytes.as_ptr() as usize).is_multiple_of(8) {
            Storage::Bytes(bytes)
        } else {
            Storage::aligned_copy(&bytes)?
        };
        Self::from_storage(storage, None)
    }

    /// A grid from a borrowed buffer, copied once into an aligned buffer that is allocated
    /// fallibly (the C ABI's `pinrt_open_memory` and Python's `from_bytes`: the host keeps
    /// its buffer, and a copy that does not fit is an error, not an abort).
    pub fn from_slice(bytes: &[u8]) -> Result<Self> {
        Self::from_storage(Storage::aligned_copy(bytes)?, None)
    }

    /// Full check: every section checksum and every value (linear in the file size; each
    /// section's bytes are read once).
    pub fn verify(&self) -> Result<()> {
        self.file()?
            .verify()
            .map_err(|source| self.format_err(source))
    }

    pub(crate) fn format_err(&self, source: pin_format::FormatError) -> Error {
        Error::Format {
            path: self
                .path
                .clone()
                .unwrap_or_else(|| PathBuf::from("<memory>")),
            source,
        }
    }

    /// A `pin_format` view of the bytes (re-parsed: O(sections)), for metadata and sections
    /// this type does not surface.
    pub fn file(&self) -> Result<PinFile<'_>> {
        PinFile::parse(self.bytes()).map_err(|e| self.format_err(e))
    }

    /// The file this grid came from, if any.
    pub fn path(&self) -> Option<&Path> {
        self.path.as_deref()
    }

    /// Whether the bytes are a memory map (as opposed to an owned buffer).
    pub fn is_mapped(&self) -> bool {
        matches!(self.storage, Storage::Mmap(_))
    }

    /// The whole file.
    pub fn bytes(&self) -> &[u8] {
        self.storage.bytes()
    }

    pub fn desc(&self) -> &GridDesc {
        &self.desc
    }

    pub fn shape(&self) -> &GridShape {
        &self.shape
    }

    /// The pin section's bytes, exactly as stored (what the GPU upload copies).
    pub fn pins_bytes(&self) -> &[u8] {
        &self.bytes()[self.pins.0..self.pins.0 + self.pins.1]
    }

    /// The cell index section's bytes, if the grid is sparse.
    pub fn cell_index_bytes(&self) -> Option<&[u8]> {
        self.index.map(|(o, l)| &self.bytes()[o..o + l])
    }

    /// All stored pins, cast in place.
    pub fn pins(&self) -> &[PinEntry] {
        bytemuck::cast_slice(self.pins_bytes())
    }

    /// The sparse cell index (block number or `EMPTY_CELL` per covered cell), cast in place.
    pub fn cell_index(&self) -> Option<&[u32]> {
        self.cell_index_bytes().map(bytemuck::cast_slice)
    }

    /// One entry by cell, direction cell and pin number; empty cells read as
    /// [`PinEntry::EMPTY`]. Same answer as `PinFile::entry`.
    pub fn entry(&self, cell: [u32; 3], direction: u32, pin: u32) -> PinEntry {
        GridView::new(self)
            .entry_index(cell, direction, pin)
            .and_then(|i| self.pins().get(i as usize).copied())
            .unwrap_or(PinEntry::EMPTY)
    }
}

/// The lookup's view of a loaded grid: made here, so that the lookup needs no loader.
impl<'g> GridView<'g> {
    pub fn new(grid: &'g PinGrid) -> Self {
        let shape = *grid.shape();
        Self {
            pins: grid.pins(),
            index: grid.cell_index(),
            shape,
            dims_f: shape.dims.map(|d| d as f32),
            stored_cells: grid.desc().stored_cells,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::random_grid;
    use pin_format::Directions;

    #[test]
    fn open_errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("no-such-grid.pin");
        let e = PinGrid::open(&missing).unwrap_err();
        assert!(e.to_string().contains("no-such-grid.pin"), "{e}");
        let e = PinGrid::read_into_memory(&missing).unwrap_err();
        assert!(e.to_string().contains("no-such-grid.pin"), "{e}");

        let garbage = dir.path().join("garbage.pin");
        std::fs::write(
            &garbage,
            b"this is not a pin file at all, not even close....",
        )
        .unwrap();
        let e = PinGrid::open(&garbage).unwrap_err();
        assert!(
            e.to_string().contains("garbage.pin") && e.to_string().contains("magic"),
            "{e}"
        );
        let empty = dir.path().join("empty.pin");
        std::fs::write(&empty, b"").unwrap();
        let e = PinGrid::open(&empty).unwrap_err();
        assert!(e.to_string().contains("empty.pin"), "{e}");
    }

    #[test]
    fn truncated_file_is_an_error_not_a_panic() {
        let g = random_grid(Directions::THESIS_DEFAULT, [3, 2, 4], 2, true, 5);
        let bytes = g.to_bytes().unwrap();
        let dir = tempfile::tempdir().unwrap();
        for cut in [0, 7, 8, 63, 64, 100, bytes.len() / 2, bytes.len() - 1] {
            let p = dir.path().join(format!("cut{cut}.pin"));
            std::fs::write(&p, &bytes[..cut]).unwrap();
            let e = PinGrid::open(&p).unwrap_err();
            assert!(e.to_string().contains(&format!("cut{cut}.pin")), "{e}");
            assert!(PinGrid::read_into_memory(&p).is_err());
            assert!(PinGrid::from_bytes(bytes[..cut].to_vec()).is_err());
        }
        let mut longer = bytes.clone();
        longer.push(0);
        let e = PinGrid::from_bytes(longer).unwrap_err();
        assert!(e.to_string().contains("<memory>"), "{e}");
    }

    #[test]
    fn all_loaders_agree_with_pin_file() {
        let g = random_grid(Directions::Octahedral { n: 3 }, [4, 3, 2], 3, true, 11);
        let bytes = g.to_bytes().unwrap();
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("g.pin");
        std::fs::write(&p, &bytes).unwrap();
        let file = PinFile::parse(&bytes).unwrap();
        // An unaligned buffer gets copied.
        let mut shifted = vec![0u8; bytes.len() + 1];
        shifted[1..].copy_from_slice(&bytes);
        let unaligned = shifted[1..].to_vec();
        for grid in [
            PinGrid::open(&p).unwrap(),
            PinGrid::read_into_memory(&p).unwrap(),
            PinGrid::from_bytes(bytes.clone()).unwrap(),
            PinGrid::from_bytes(unaligned).unwrap(),
        ] {
            grid.verify().unwrap();
            assert_eq!(grid.pins(), file.pins());
            assert_eq!(grid.cell_index(), file.cell_index());
            for z in 0..2 {
                for y in 0..3 {
                    for x in 0..4 {
                        for d in 0..9 {
                            for k in 0..3 {
                                assert_eq!(
                                    grid.entry([x, y, z], d, k),
                                    file.entry([x, y, z], d, k)
                                );
                            }
                        }
                    }
                }
            }
            assert_eq!(grid.entry([9, 0, 0], 0, 0), PinEntry::EMPTY);
        }
        assert!(PinGrid::open(&p).unwrap().is_mapped());
    }

    #[test]
    fn verify_reports_damage() {
        let g = random_grid(Directions::THESIS_DEFAULT, [2, 2, 2], 1, false, 3);
        let mut bytes = g.to_bytes().unwrap();
        let grid = PinGrid::from_bytes(bytes.clone()).unwrap();
        let off = grid.pins.0 + 3;
        bytes[off] ^= 0x55;
        let damaged = PinGrid::from_bytes(bytes).unwrap(); // O(1) open does not see it
        let e = damaged.verify().unwrap_err();
        assert!(e.to_string().contains("checksum"), "{e}");
    }

    #[test]
    fn grid_is_send_sync() {
        fn check<T: Send + Sync>() {}
        check::<PinGrid>();
        check::<crate::Sampler<'static>>();
    }
}
