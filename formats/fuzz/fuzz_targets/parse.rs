//! Feeds arbitrary bytes to the reader, as they are and again with every checksum repaired.
//! On a successful parse: verify, look up every stored
//! pin and a sample of empty cells, and if the file verifies, copy it out, rewrite it and check
//! that the rewrite reads back to the same bytes. Any panic is a finding.
//!
//! Run: `cd formats/fuzz && cargo +nightly fuzz run parse` (seed corpus in `corpus/parse/`).
#![no_main]

use libfuzzer_sys::fuzz_target;
use pin_format::{OwnedPinGrid, PinEntry, PinFile, checksum};

fuzz_target!(|data: &[u8]| {
    // Readers need a 4-byte aligned buffer (an mmap always is); libFuzzer's is not promised.
    let mut words = vec![0u32; data.len().div_ceil(4)];
    let buf = &mut bytemuck::cast_slice_mut::<u32, u8>(&mut words)[..data.len()];
    buf.copy_from_slice(data);
    check(buf);
    // Random bytes rarely carry valid checksums; repair them so that mutations of lengths,
    // offsets and grid fields reach the structural checks behind the checksums too.
    if fix_checksums(buf) {
        check(buf);
    }
});

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

/// Recomputes every section checksum, the table checksum and the header checksum where the
/// header and table are in bounds. Returns whether anything was done.
fn fix_checksums(b: &mut [u8]) -> bool {
    if b.len() < 64 {
        return false;
    }
    let count = u32::from_le_bytes(b[16..20].try_into().unwrap()) as usize;
    let entry = u32::from_le_bytes(b[20..24].try_into().unwrap()) as usize;
    let table = u64_at(b, 24);
    let Some(table_len) = count
        .checked_mul(entry)
        .filter(|_| entry >= 32 && count <= 1024)
    else {
        return false;
    };
    let Some(table_end) = table
        .checked_add(table_len as u64)
        .filter(|&e| e <= b.len() as u64)
    else {
        return false;
    };
    if table < 64 {
        return false;
    }
    let table = table as usize;
    for i in 0..count {
        let e = table + i * entry;
        let (off, len) = (u64_at(b, e + 8), u64_at(b, e + 16));
        if let Some(end) = off.checked_add(len).filter(|&end| end <= b.len() as u64) {
            let sum = checksum(&b[off as usize..end as usize]);
            b[e + 24..e + 32].copy_from_slice(&sum.to_le_bytes());
        }
    }
    // A section overlapping the table may have moved under us; that is fine, it only makes
    // some checksums wrong again.
    let sum = checksum(&b[table..table_end as usize]);
    b[48..56].copy_from_slice(&sum.to_le_bytes());
    let sum = checksum(&b[..56]);
    b[56..64].copy_from_slice(&sum.to_le_bytes());
    true
}

fn check(buf: &[u8]) {
    let Ok(file) = PinFile::parse(buf) else {
        return;
    };
    let verified = file.verify().is_ok();
    let shape = *file.shape();
    let [dx, dy, _] = shape.dims;
    // Every covered cell (bounded by the input size: the cell index or the pins are at least
    // 4 bytes per covered cell), plus the layers just outside a tile.
    let z_lo = shape.z_begin.saturating_sub(1);
    let z_hi = shape.z_end.saturating_add(1).min(shape.dims[2]);
    let mut walked = 0u64;
    for z in z_lo..z_hi {
        for y in 0..dy {
            for x in 0..dx {
                walked += 1;
                if walked > 1 << 16 {
                    break;
                }
                let cell = [x, y, z];
                match file.cell_pins(cell) {
                    Some(pins) => {
                        assert_eq!(pins.len() as u64, shape.block_len);
                        for dir in 0..shape.directions.count() {
                            for pin in 0..shape.pins_per_entry {
                                let e = file.entry(cell, dir, pin);
                                let want = pins[(dir * shape.pins_per_entry + pin) as usize];
                                assert_eq!(bytemuck::bytes_of(&e), bytemuck::bytes_of(&want));
                            }
                        }
                    }
                    None => assert_eq!(file.entry(cell, 0, 0), PinEntry::EMPTY),
                }
            }
        }
    }
    let _ = file.entry([u32::MAX; 3], u32::MAX, u32::MAX);
    let _ = file.empty_cells();
    let _ = file.metadata();
    if verified {
        let owned = OwnedPinGrid::from_file(&file).expect("a verified file copies out");
        let bytes = owned.to_bytes().expect("a verified file rewrites");
        let again = PinFile::parse(&bytes).expect("a rewrite parses");
        again.verify().expect("a rewrite verifies");
        let twice = OwnedPinGrid::from_file(&again).unwrap().to_bytes().unwrap();
        assert_eq!(twice, bytes, "rewriting is idempotent");
    }
}
