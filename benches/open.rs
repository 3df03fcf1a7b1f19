//! Open time: `mmap` + `PinFile::parse` for a ~1 GiB and a ~1 KiB pin file. Opening is O(1)
//! in the file size, so both must take the same time.
//!
//! `cargo bench -p pin-benches --bench open` runs criterion. With `PIN_OPEN_BENCH_QUICK=1` it
//! prints a small table instead (no criterion statistics, a few seconds after the files are
//! written). Files go to a temp dir under `PIN_OPEN_BENCH_DIR` (default: the system temp dir).

use std::fs::File;
use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use criterion::Criterion;
use memmap2::Mmap;
use pin_format::layout::{SECTION_REQUIRED, SectionKind};
use pin_format::{AtomicPinFile, Directions, OwnedPinGrid, PinEntry, PinFile, grid_desc};

/// 64^3 cells x (16 x 4 directions) x 8 pins per entry x 8 bytes = 1 GiB of pins.
const BIG_DIMS: [u32; 3] = [64, 64, 64];
/// 16 x 16 x 1 cells of the same shape: 1 MiB.
const MEDIUM_DIMS: [u32; 3] = [16, 16, 1];
const BIG_PINS_PER_ENTRY: u32 = 8;

/// Streams a dense file through the atomic writer, one 1 MiB chunk of pins at a time.
fn write_big(path: &Path, dims: [u32; 3]) {
    let dirs = Directions::THESIS_DEFAULT;
    let cells: u64 = dims.iter().map(|&d| u64::from(d)).product();
    let desc = grid_desc(dims, dirs, BIG_PINS_PER_ENTRY, cells);
    let pins = cells * u64::from(dirs.count() * BIG_PINS_PER_ENTRY);
    let mut file = AtomicPinFile::create(path).unwrap();
    let w = file.writer();
    w.add_section(
        SectionKind::GridDesc as u32,
        SECTION_REQUIRED,
        bytemuck::bytes_of(&desc),
    )
    .unwrap();
    w.begin_section(SectionKind::Pins as u32, SECTION_REQUIRED)
        .unwrap();
    const CHUNK: u64 = 1 << 17; // pins: 1 MiB
    let mut chunk = vec![PinEntry::EMPTY; CHUNK as usize];
    let mut done = 0u64;
    while done < pins {
        let n = CHUNK.min(pins - done) as usize;
        for (i, p) in chunk[..n].iter_mut().enumerate() {
            let k = done + i as u64;
            *p = PinEntry {
                mask: (k as u32).wrapping_mul(0x9E37_79B9) | 1,
                t_min: (k % 1000) as f32 / 1000.0,
            };
        }
        w.write(bytemuck::cast_slice(&chunk[..n])).unwrap();
        done += n as u64;
    }
    w.end_section().unwrap();
    file.commit().unwrap();
}

/// A ~1 KiB file: 4x4x1 cells, octahedral 2x2, one pin per entry, dense.
fn write_small(path: &Path) {
    let dirs = Directions::Octahedral { n: 2 };
    let grid = OwnedPinGrid {
        desc: grid_desc([4, 4, 1], dirs, 1, 16),
        tile: None,
        cell_index: None,
        pins: (0..64)
            .map(|i| PinEntry {
                mask: i * 0x0101_0101,
                t_min: 0.5,
            })
            .collect(),
        majorant: None,
        density: None,
        sparse_density: None,
        control: None,
        metadata: None,
    };
    grid.write_atomic(path).unwrap();
}

struct Files {
    _dir: tempfile::TempDir,
    big: PathBuf,
    medium: PathBuf,
    small: PathBuf,
}

impl Files {
    fn all(&self) -> [(&'static str, &Path); 3] {
        [
            ("1KiB", &self.small),
            ("1MiB", &self.medium),
            ("1GiB", &self.big),
        ]
    }
}

fn make_files() -> Files {
    let dir = match std::env::var_os("PIN_OPEN_BENCH_DIR") {
        Some(d) => tempfile::tempdir_in(d),
        None => tempfile::tempdir(),
    }
    .unwrap();
    let big = dir.path().join("big.pin");
    let medium = dir.path().join("medium.pin");
    let small = dir.path().join("small.pin");
    let t = Instant::now();
    write_big(&big, BIG_DIMS);
    eprintln!(
        "wrote {} ({} bytes) in {:.2?}",
        big.display(),
        std::fs::metadata(&big).unwrap().len(),
        t.elapsed()
    );
    write_big(&medium, MEDIUM_DIMS);
    write_small(&small);
    Files {
        _dir: dir,
        big,
        medium,
        small,
    }
}

/// What "opening" a pin file costs a renderer: open, map, parse. Returns something derived
/// from the parse so nothing is optimised away.
fn open(path: &Path) -> u64 {
    let f = File::open(path).unwrap();
    // SAFETY: the benchmark owns the file; nobody truncates it while mapped.
    let map = unsafe { Mmap::map(&f) }.unwrap();
    let file = PinFile::parse(&map).unwrap();
    file.desc().stored_cells + file.pins().len() as u64
}

fn criterion_benches(c: &mut Criterion, files: &Files) {
    let mut g = c.benchmark_group("open");
    for (name, path) in files.all() {
        g.bench_function(format!("mmap+parse/{name}"), |b| {
            b.iter(|| black_box(open(black_box(path))))
        });
    }
    for (name, path) in files.all() {
        let f = File::open(path).unwrap();
        // SAFETY: as above.
        let map = unsafe { Mmap::map(&f) }.unwrap();
        g.bench_function(format!("parse-only/{name}"), |b| {
            b.iter(|| black_box(PinFile::parse(black_box(&map[..])).unwrap().pins().len()))
        });
    }
    g.finish();
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

/// Median of `N` timed runs of `f` after a warm-up.
fn time_median(mut f: impl FnMut()) -> Duration {
    const N: usize = 2000;
    for _ in 0..100 {
        f();
    }
    median(
        (0..N)
            .map(|_| {
                let t = Instant::now();
                f();
                t.elapsed()
            })
            .collect(),
    )
}

/// Open + map + unmap without touching a page: the OS part of opening.
fn map_only(path: &Path) -> usize {
    let f = File::open(path).unwrap();
    // SAFETY: as above.
    let map = unsafe { Mmap::map(&f) }.unwrap();
    map.len()
}

fn quick(files: &Files) {
    println!(
        "{:<6} {:>12} {:>22} {:>18} {:>18} {:>10}",
        "file", "bytes", "open+mmap (untouched)", "open+mmap+parse", "parse (mapped)", "sections"
    );
    for (name, path) in files.all() {
        let len = std::fs::metadata(path).unwrap().len();
        let mapped = time_median(|| {
            black_box(map_only(black_box(path)));
        });
        let full = time_median(|| {
            black_box(open(black_box(path)));
        });
        let f = File::open(path).unwrap();
        // SAFETY: as above.
        let map = unsafe { Mmap::map(&f) }.unwrap();
        let parse = time_median(|| {
            black_box(PinFile::parse(black_box(&map[..])).unwrap().pins().len());
        });
        let sections = PinFile::parse(&map).unwrap().sections().len();
        println!("{name:<6} {len:>12} {mapped:>22.2?} {full:>18.2?} {parse:>18.2?} {sections:>10}");
    }
    // For contrast: the full O(n) check of the big file (page cache warm after writing).
    let f = File::open(&files.big).unwrap();
    // SAFETY: as above.
    let map = unsafe { Mmap::map(&f) }.unwrap();
    let file = PinFile::parse(&map).unwrap();
    let t = Instant::now();
    file.verify().unwrap();
    println!(
        "verify (O(n), every checksum and value) of the 1GiB file: {:.2?}",
        t.elapsed()
    );
}

fn main() {
    let files = make_files();
    if std::env::var_os("PIN_OPEN_BENCH_QUICK").is_some() {
        quick(&files);
        return;
    }
    let mut c = Criterion::default().configure_from_args();
    criterion_benches(&mut c, &files);
    c.final_summary();
}
