//! The seed corpus of the libFuzzer target (`formats/fuzz/corpus/parse/`): small valid files
//! and a few damaged ones, generated here so they follow the format.
//!
//! Regenerate after a layout change: `PIN_WRITE_CORPUS=1 cargo test -p pin-format --test it fuzz_corpus`.

use std::path::PathBuf;

use crate::common::*;
use pin_format::layout::*;
use pin_format::*;

fn corpus_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus/parse")
}

/// `(file name, bytes, verifies)`.
fn seeds() -> Vec<(&'static str, Vec<u8>, bool)> {
    let golden = golden_grid().to_bytes().unwrap();
    let full = full_grid().to_bytes().unwrap();
    let tiled_dense = build_grid(&GridParams {
        dims: [2, 2, 3],
        directions: Directions::Octahedral { n: 1 },
        pins_per_entry: 3,
        sparse_empty: None,
        tile: Some((0, 3, 0, 1)),
        majorant: None,
        density: Some([2, 1, 1]),
        metadata: None,
        seed: 5,
    })
    .to_bytes()
    .unwrap();
    let all_empty = build_grid(&GridParams {
        dims: [5, 1, 1],
        directions: Directions::THESIS_DEFAULT,
        pins_per_entry: 1,
        sparse_empty: Some(1.0),
        tile: None,
        majorant: Some([1, 1, 1]),
        density: None,
        metadata: Some(Metadata::default()),
        seed: 9,
    })
    .to_bytes()
    .unwrap();
    let minimal = {
        let mut g = golden_grid();
        g.cell_index = None;
        g.majorant = None;
        g.metadata = None;
        g.desc.stored_cells = 2;
        g.pins.push(PinEntry::EMPTY);
        g.to_bytes().unwrap()
    };

    let truncated = golden[..golden.len() - 40].to_vec();
    let mut flipped_pins = full.clone();
    let p = section_range(&full, SectionKind::Pins);
    flipped_pins[p.start + 3] ^= 0x10;
    let mut lying_stored = full.clone();
    patch_grid(&mut lying_stored, |g| g.stored_cells += 1);
    let mut overlap = golden.clone();
    patch_table(&mut overlap, |t| t[1].offset = t[0].offset);
    let mut nan_pin = golden.clone();
    patch_section(&mut nan_pin, SectionKind::Pins, |s| {
        s[4..8].copy_from_slice(&f32::NAN.to_le_bytes())
    });
    let mut future = golden.clone();
    patch_header(&mut future, |h| h.version_minor = 3);
    let unknown_required = {
        let mut w = PinFileWriter::new(std::io::Cursor::new(Vec::new())).unwrap();
        golden_grid().write_into(&mut w).unwrap();
        w.add_section(42, SECTION_REQUIRED, b"needs a newer reader")
            .unwrap();
        w.finish().unwrap().into_inner()
    };

    vec![
        ("valid-golden.pin", golden, true),
        ("valid-full.pin", full, true),
        ("valid-tiled-dense.pin", tiled_dense, true),
        ("valid-all-empty.pin", all_empty, true),
        ("valid-minimal-dense.pin", minimal, true),
        ("valid-future-minor.pin", future, true),
        ("bad-truncated.pin", truncated, false),
        ("bad-flipped-pins.pin", flipped_pins, false),
        ("bad-lying-stored-cells.pin", lying_stored, false),
        ("bad-overlapping-sections.pin", overlap, false),
        ("bad-nan-t-min.pin", nan_pin, false),
        ("bad-unknown-required.pin", unknown_required, false),
    ]
}

#[test]
fn fuzz_seed_corpus_is_current() {
    let dir = corpus_dir();
    let write = std::env::var_os("PIN_WRITE_CORPUS").is_some();
    if write {
        std::fs::create_dir_all(&dir).unwrap();
    }
    for (name, bytes, verifies) in seeds() {
        let ok = PinFile::parse(&bytes).and_then(|f| f.verify()).is_ok();
        assert_eq!(ok, verifies, "{name}");
        let path = dir.join(name);
        if write {
            std::fs::write(&path, &bytes).unwrap();
        }
        let on_disk = std::fs::read(&path).unwrap_or_else(|e| {
            panic!(
                "{}: {e}; regenerate with PIN_WRITE_CORPUS=1",
                path.display()
            )
        });
        assert!(
            on_disk == bytes,
            "{name} is stale; regenerate with PIN_WRITE_CORPUS=1 (a layout change also needs \
             a version bump and a docs/format.md update)"
        );
    }
}
