//! Golden bytes: a tiny fixed file whose every byte is committed. Any change to the layout,
//! the section order, padding, checksums or the metadata encoding fails this test.
//!
//! Regenerate (only together with a version bump and a docs/format.md update):
//! `PIN_BLESS=1 cargo test -p pin-format --test it golden`.

use std::path::PathBuf;

use crate::common::*;
use pin_format::layout::*;
use pin_format::*;

fn golden_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/golden/tiny.pin")
}

const LAYOUT_CHANGED: &str = "the bytes of the golden pin file changed: a layout change needs a \
    format version bump and a docs/format.md update (then regenerate with PIN_BLESS=1)";

#[test]
fn golden_bytes_are_unchanged() {
    let bytes = golden_grid().to_bytes().unwrap();
    if std::env::var_os("PIN_BLESS").is_some() {
        std::fs::write(golden_path(), &bytes).unwrap();
    }
    let golden = std::fs::read(golden_path()).expect("tests/golden/tiny.pin is committed");
    if bytes != golden {
        let first = bytes
            .iter()
            .zip(&golden)
            .position(|(a, b)| a != b)
            .unwrap_or(bytes.len().min(golden.len()));
        panic!(
            "{LAYOUT_CHANGED}\nfirst difference at byte {first} (0x{first:x}); \
             written {} bytes, golden {} bytes",
            bytes.len(),
            golden.len()
        );
    }
}

#[test]
fn golden_file_reads_back() {
    let golden = std::fs::read(golden_path()).unwrap();
    let file = PinFile::parse(&golden).unwrap();
    file.verify().unwrap();
    assert_eq!(OwnedPinGrid::from_file(&file).unwrap(), golden_grid());
    assert_eq!(
        file.entry([0, 0, 0], 0, 0),
        PinEntry {
            mask: 0x8000_0001,
            t_min: 0.25
        }
    );
    assert_eq!(file.entry([1, 0, 0], 0, 0), PinEntry::EMPTY);
    assert_eq!(file.empty_cells(), 1);
}

fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes(b[o..o + 4].try_into().unwrap())
}
fn u64_at(b: &[u8], o: usize) -> u64 {
    u64::from_le_bytes(b[o..o + 8].try_into().unwrap())
}
fn f64_at(b: &[u8], o: usize) -> f64 {
    f64::from_le_bytes(b[o..o + 8].try_into().unwrap())
}

/// Reads the golden file with nothing but the offsets written in docs/format.md, the way a C
/// reader would, so the spec and the code cannot drift apart silently.
#[test]
fn golden_file_matches_the_written_spec() {
    let b = std::fs::read(golden_path()).unwrap();
    // Header.
    assert_eq!(&b[0..8], b"\x89PIN\r\n\x1a\n", "{LAYOUT_CHANGED}");
    assert_eq!(u16::from_le_bytes([b[8], b[9]]), 1);
    assert_eq!(u16::from_le_bytes([b[10], b[11]]), 0);
    assert_eq!(u32_at(&b, 12), 64, "header_size");
    let count = u32_at(&b, 16) as usize;
    assert_eq!(u32_at(&b, 20), 32, "section_entry_size");
    let table_offset = u64_at(&b, 24) as usize;
    assert_eq!(u64_at(&b, 32), b.len() as u64, "file_size");
    assert_eq!(u64_at(&b, 40), 0, "flags");
    assert_eq!(
        u64_at(&b, 48),
        checksum(&b[table_offset..table_offset + 32 * count])
    );
    assert_eq!(u64_at(&b, 56), checksum(&b[0..56]));
    // Section table.
    let mut sections = Vec::new();
    for i in 0..count {
        let e = table_offset + 32 * i;
        let (kind, flags, off, len, sum) = (
            u32_at(&b, e),
            u32_at(&b, e + 4),
            u64_at(&b, e + 8) as usize,
            u64_at(&b, e + 16) as usize,
            u64_at(&b, e + 24),
        );
        assert_eq!(off % 64, 0);
        assert_eq!(checksum(&b[off..off + len]), sum);
        sections.push((kind, flags, off, len));
    }
    let kinds: Vec<(u32, u32)> = sections.iter().map(|s| (s.0, s.1)).collect();
    // Canonical order: grid, (tile), cell index, pins, majorant, (density), metadata.
    assert_eq!(kinds, [(1, 1), (3, 1), (2, 1), (4, 0), (6, 0)]);
    // Grid description.
    let g = sections[0].2;
    assert_eq!(sections[0].3, 296);
    assert_eq!(
        [u32_at(&b, g), u32_at(&b, g + 4), u32_at(&b, g + 8)],
        [2, 1, 1]
    );
    assert_eq!(u32_at(&b, g + 12), DIRECTIONS_OCTAHEDRAL);
    assert_eq!([u32_at(&b, g + 16), u32_at(&b, g + 20)], [1, 1]);
    assert_eq!(u32_at(&b, g + 24), 1, "pins_per_entry");
    assert_eq!(u32_at(&b, g + 28), 32, "bits_per_pin");
    assert_eq!(u64_at(&b, g + 32), 1, "stored_cells");
    assert_eq!(f64_at(&b, g + 40), -1.0, "box_min.x");
    assert_eq!(f64_at(&b, g + 64), 1.0, "box_max.x");
    assert_eq!(f64_at(&b, g + 88), 1.0, "local_to_world[0]");
    assert_eq!(f64_at(&b, g + 184), 0.125, "step_size");
    assert_eq!(f64_at(&b, g + 192), 2.0, "density_scale");
    assert_eq!(u64_at(&b, g + 200), 0x0123_4567_89AB_CDEF, "seed");
    assert_eq!(u32_at(&b, g + 208), GRID_FLAG_CROPPED, "flags");
    assert_eq!(f64_at(&b, g + 216), -2.0, "source_box_min.x");
    assert_eq!(f64_at(&b, g + 240), 2.0, "source_box_max.x");
    // Cell index, pins, majorant.
    let ix = sections[1].2;
    assert_eq!([u32_at(&b, ix), u32_at(&b, ix + 4)], [0, EMPTY_CELL]);
    let p = sections[2].2;
    assert_eq!(u32_at(&b, p), 0x8000_0001);
    assert_eq!(
        f32::from_le_bytes(b[p + 4..p + 8].try_into().unwrap()),
        0.25
    );
    let m = sections[3].2;
    assert_eq!(sections[3].3, 20);
    assert_eq!(
        [u32_at(&b, m), u32_at(&b, m + 4), u32_at(&b, m + 8)],
        [1, 1, 1]
    );
    assert_eq!(
        f32::from_le_bytes(b[m + 16..m + 20].try_into().unwrap()),
        3.5
    );
    // Metadata: bincode 2 standard, varint: length-prefixed UTF-8 strings first.
    let md = sections[4].2;
    assert_eq!(b[md], 7);
    assert_eq!(&b[md + 1..md + 8], b"pinbake");
    // Padding between sections is zero.
    let mut covered = vec![false; b.len()];
    covered[..64].fill(true);
    covered[table_offset..table_offset + 32 * count].fill(true);
    for s in &sections {
        covered[s.2..s.2 + s.3].fill(true);
    }
    for (i, c) in covered.iter().enumerate() {
        if !c {
            assert_eq!(b[i], 0, "padding byte {i}");
        }
    }
}
