//! Damaged and lying files: each case must give one specific, typed error, never a panic.
//!
//! Lies are planted with the checksums that cover them recomputed, so that they get past the
//! checksum checks and reach the structural ones.

use crate::common::*;
use pin_format::layout::*;
use pin_format::*;

fn parse_err(b: &[u8]) -> FormatError {
    match PinFile::parse(b) {
        Ok(_) => panic!("parse accepted a damaged file"),
        Err(e) => e,
    }
}

fn verify_err(b: &[u8]) -> FormatError {
    let f = PinFile::parse(b).expect("damage of this kind passes the O(1) parse");
    match f.verify() {
        Ok(()) => panic!("verify accepted a damaged file"),
        Err(e) => e,
    }
}

macro_rules! assert_err {
    ($e:expr, $pat:pat $(if $guard:expr)?) => {{
        let e = $e;
        assert!(matches!(e, $pat $(if $guard)?), "got {e:?} ({e})");
    }};
}

fn u32s(b: &[u8]) -> Vec<u32> {
    b.chunks_exact(4)
        .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

fn files() -> Vec<(&'static str, Vec<u8>)> {
    vec![
        ("golden", golden_grid().to_bytes().unwrap()),
        ("full", full_grid().to_bytes().unwrap()),
        ("dense", dense_grid().to_bytes().unwrap()),
        ("sparse", sparse_grid().to_bytes().unwrap()),
        ("sparse-f32", sparse_grid_f32().to_bytes().unwrap()),
    ]
}

#[test]
fn every_truncation_of_header_and_table_fails_to_parse() {
    for (_, b) in files() {
        let table_bytes = table_range(&b);
        for n in (0..HEADER_LEN).chain(table_bytes) {
            let e = parse_err(&b[..n]);
            if n < HEADER_LEN {
                assert_err!(e, FormatError::TooShort { .. });
            } else {
                assert_err!(e, FormatError::SizeMismatch { .. });
            }
        }
        // Every section boundary, and one byte into each section.
        for s in table(&b) {
            for n in [s.offset, s.offset + 1, s.offset + s.length] {
                assert_err!(
                    parse_err(&b[..n as usize]),
                    FormatError::SizeMismatch { .. }
                );
            }
        }
        // Appended garbage is as bad as truncation.
        let mut longer = b.clone();
        longer.extend_from_slice(&[0; 64]);
        assert_err!(parse_err(&longer), FormatError::SizeMismatch { .. });
    }
}

#[test]
fn truncation_with_a_matching_file_size_is_still_caught() {
    // The lie: the header is patched to claim the truncated length.
    for (_, b) in files() {
        let sections = table(&b);
        for s in &sections {
            let mut t = b[..s.offset as usize + 64.min(s.length as usize)].to_vec();
            let len = t.len() as u64;
            patch_header(&mut t, |h| h.file_size = len);
            assert_err!(parse_err(&t), FormatError::BadHeader(_));
        }
    }
    // Also the other way round: table kept, a section cut short under it.
    let mut b = full_grid().to_bytes().unwrap();
    let i = section_position(&b, SectionKind::Pins);
    patch_table(&mut b, |t| t[i].length += 64 * 1024);
    assert_err!(parse_err(&b), FormatError::BadSection { .. });
}

#[test]
fn bad_magic_and_short_prefixes() {
    assert_err!(parse_err(b""), FormatError::TooShort { .. });
    assert_err!(parse_err(b"\x89PI"), FormatError::TooShort { .. });
    assert_err!(parse_err(b"GIF89a"), FormatError::BadMagic);
    assert_err!(parse_err(&[0u8; 4096]), FormatError::BadMagic);
    let mut b = golden_grid().to_bytes().unwrap();
    b[3] = b'X';
    assert_err!(parse_err(&b), FormatError::BadMagic);
    // Text-mode newline translation (CR LF -> LF) breaks the magic.
    let mut t = golden_grid().to_bytes().unwrap();
    t.remove(4);
    assert_err!(parse_err(&t), FormatError::BadMagic);
}

#[test]
fn flipped_bytes_in_each_region() {
    for (_, b) in files() {
        let sections = table(&b);
        let t = table_range(&b);
        for pos in 0..b.len() {
            let mut d = b.clone();
            d[pos] ^= 0x5A;
            let in_section = sections
                .iter()
                .find(|s| (s.offset..s.offset + s.length).contains(&(pos as u64)));
            if pos < 8 {
                assert_err!(parse_err(&d), FormatError::BadMagic);
            } else if (8..10).contains(&pos) {
                assert_err!(parse_err(&d), FormatError::UnsupportedVersion { .. });
            } else if pos < HEADER_LEN {
                assert_err!(parse_err(&d), FormatError::HeaderChecksum);
            } else if t.contains(&pos) {
                assert_err!(parse_err(&d), FormatError::TableChecksum);
            } else if let Some(s) = in_section {
                let kind = SectionKind::from_u32(s.kind).unwrap();
                let rel = pos as u64 - s.offset;
                match kind {
                    // Small fixed records are checksummed by parse.
                    SectionKind::GridDesc | SectionKind::Tile => {
                        assert_err!(parse_err(&d), FormatError::SectionChecksum { .. })
                    }
                    // The 16-byte prefix of majorant and density is read by parse; a flip
                    // there breaks the size equation or the encoding.
                    SectionKind::Majorant | SectionKind::Density if rel < 16 => {
                        let ok_or_data = match PinFile::parse(&d) {
                            Err(FormatError::BadData(k, _)) => k == kind,
                            Ok(f) => matches!(f.verify(), Err(FormatError::SectionChecksum { .. })),
                            Err(_) => false,
                        };
                        assert!(ok_or_data, "{} byte {rel}", kind.name());
                    }
                    // The sparse density's 32-byte header, likewise; its reserved words are
                    // read by nobody, so only verify's checksum sees a flip there.
                    SectionKind::SparseDensity if rel < 32 => {
                        let ok_or_data = match PinFile::parse(&d) {
                            Err(FormatError::BadData(k, _)) => k == kind,
                            Ok(f) => matches!(f.verify(), Err(FormatError::SectionChecksum { .. })),
                            Err(_) => false,
                        };
                        assert!(ok_or_data, "{} byte {rel}", kind.name());
                    }
                    // Bulk: parse does not look, verify must.
                    _ => assert_err!(verify_err(&d), FormatError::SectionChecksum { .. }),
                }
            } else {
                // Padding between sections is covered by no checksum and read by nobody.
                let f = PinFile::parse(&d).unwrap();
                f.verify().unwrap();
            }
        }
    }
}

#[test]
fn lying_section_table() {
    let b = full_grid().to_bytes().unwrap();
    let n = table(&b).len();
    let len = b.len() as u64;
    for i in 0..n {
        // Offset past the end.
        let mut d = b.clone();
        patch_table(&mut d, |t| t[i].offset = len.next_multiple_of(64) + 64);
        assert_err!(parse_err(&d), FormatError::BadSection { .. });
        // Offset at u64::MAX rounded to alignment.
        let mut d = b.clone();
        patch_table(&mut d, |t| t[i].offset = u64::MAX - 63);
        assert_err!(parse_err(&d), FormatError::BadSection { .. });
        // Length overflow.
        let mut d = b.clone();
        patch_table(&mut d, |t| t[i].length = u64::MAX);
        assert_err!(parse_err(&d), FormatError::BadSection { .. });
        // Misaligned offset.
        for delta in [1u64, 4, 8, 32] {
            let mut d = b.clone();
            patch_table(&mut d, |t| t[i].offset += delta);
            assert_err!(parse_err(&d), FormatError::BadSection { .. });
        }
        // Overlapping the header, the table, and the previous section.
        let mut d = b.clone();
        patch_table(&mut d, |t| t[i].offset = 0);
        assert_err!(parse_err(&d), FormatError::BadSection { .. });
        let mut d = b.clone();
        let toff = header(&b).table_offset;
        patch_table(&mut d, |t| {
            t[i].offset = toff;
            t[i].length = t[i].length.min(len - toff);
        });
        assert_err!(parse_err(&d), FormatError::BadSection { .. });
        if i > 0 {
            let mut d = b.clone();
            patch_table(&mut d, |t| t[i].offset = t[i - 1].offset);
            assert_err!(parse_err(&d), FormatError::BadSection { .. });
        }
    }
    // Two sections swapped in place: lengths no longer match what the grid needs.
    let mut d = b.clone();
    let (p, ix) = (
        section_position(&b, SectionKind::Pins),
        section_position(&b, SectionKind::CellIndex),
    );
    patch_table(&mut d, |t| {
        let (a, c) = (t[p].kind, t[ix].kind);
        t[p].kind = c;
        t[ix].kind = a;
    });
    assert_err!(parse_err(&d), FormatError::BadData(..));
}

#[test]
fn lying_header_fields() {
    let b = full_grid().to_bytes().unwrap();
    let h0 = header(&b);
    type Patch = Box<dyn Fn(&mut FileHeader)>;
    let cases: Vec<(&str, Patch)> = vec![
        ("count huge", Box::new(|h| h.section_count = u32::MAX)),
        (
            "count over limit",
            Box::new(|h| h.section_count = MAX_SECTIONS + 1),
        ),
        ("count past table", Box::new(|h| h.section_count += 1)),
        (
            "entry size huge",
            Box::new(|h| h.section_entry_size = u32::MAX),
        ),
        ("entry size 4097", Box::new(|h| h.section_entry_size = 4097)),
        ("entry size zero", Box::new(|h| h.section_entry_size = 0)),
        ("entry size small", Box::new(|h| h.section_entry_size = 31)),
        ("table misaligned", Box::new(|h| h.table_offset += 8)),
        (
            "table past end",
            Box::new(|h| h.table_offset = u64::MAX - 63),
        ),
        ("table in header", Box::new(|h| h.table_offset = 0)),
        ("header size small", Box::new(|h| h.header_size = 63)),
        ("header size huge", Box::new(|h| h.header_size = u32::MAX)),
        (
            "header size past table",
            Box::new(move |h| h.header_size = h0.table_offset as u32 + 64),
        ),
    ];
    for (what, f) in cases {
        let mut d = b.clone();
        patch_header(&mut d, f);
        let e = parse_err(&d);
        assert!(matches!(e, FormatError::BadHeader(_)), "{what}: {e:?}");
    }
    // A lie about the file size.
    let mut d = b.clone();
    patch_header(&mut d, |h| h.file_size += 64);
    assert_err!(parse_err(&d), FormatError::SizeMismatch { .. });
    // Wrong table checksum: a table edited without it.
    let mut d = b.clone();
    patch_header(&mut d, |h| h.table_checksum ^= 1);
    assert_err!(parse_err(&d), FormatError::TableChecksum);
    // Entry size 64 with the table checksum over the longer span fixed: the table reads as
    // half as many garbled entries.
    let mut d = b.clone();
    patch_header(&mut d, |h| {
        h.section_entry_size = 64;
        h.section_count /= 2;
    });
    fix_table_checksum(&mut d);
    assert!(PinFile::parse(&d).is_err());
}

#[test]
fn versions() {
    for major in [0u16, 2, u16::MAX] {
        let mut d = golden_grid().to_bytes().unwrap();
        patch_header(&mut d, |h| h.version_major = major);
        assert_err!(
            parse_err(&d),
            FormatError::UnsupportedVersion { major: m, supported: 1, .. } if m == major
        );
        // Rejected before the checksum is even looked at.
        d[56] ^= 0xFF;
        assert_err!(parse_err(&d), FormatError::UnsupportedVersion { .. });
    }
    // Any minor of major 1 reads.
    let mut d = golden_grid().to_bytes().unwrap();
    patch_header(&mut d, |h| h.version_minor = 9);
    PinFile::parse(&d).unwrap().verify().unwrap();
}

/// The golden grid plus one extra section of raw kind `kind`.
fn with_extra_section(kind: u32, flags: u32, body: &[u8]) -> Vec<u8> {
    let mut w = PinFileWriter::new(std::io::Cursor::new(Vec::new())).unwrap();
    golden_grid().write_into(&mut w).unwrap();
    w.add_section(kind, flags, body).unwrap();
    w.finish().unwrap().into_inner()
}

#[test]
fn unknown_and_duplicate_sections() {
    // Unknown, not required: skipped by parse, still checksummed by verify.
    let d = with_extra_section(99, 0, b"from the future");
    let f = PinFile::parse(&d).unwrap();
    f.verify().unwrap();
    assert_eq!(OwnedPinGrid::from_file(&f).unwrap(), golden_grid());
    let off = table(&d).last().unwrap().offset as usize;
    let mut bad = d.clone();
    bad[off] ^= 1;
    assert_err!(verify_err(&bad), FormatError::SectionChecksum { .. });
    // Unknown flag bits on an unknown section are ignored too.
    PinFile::parse(&with_extra_section(1000, 0xFFFF_FFFE, b"x")).unwrap();
    // Unknown, required: rejected.
    assert_err!(
        parse_err(&with_extra_section(99, SECTION_REQUIRED, b"x")),
        FormatError::UnknownRequiredSection { kind: 99 }
    );
    assert_err!(
        parse_err(&with_extra_section(0, SECTION_REQUIRED | 2, b"")),
        FormatError::UnknownRequiredSection { kind: 0 }
    );
    // Duplicates of every known kind.
    let grid = golden_grid().to_bytes().unwrap();
    let sections = table(&grid);
    for s in &sections {
        let body = &grid[s.offset as usize..(s.offset + s.length) as usize];
        let d = with_extra_section(s.kind, s.flags, body);
        let k = SectionKind::from_u32(s.kind).unwrap();
        assert_err!(parse_err(&d), FormatError::DuplicateSection(x) if x == k);
    }
    let d = with_extra_section(SectionKind::Tile as u32, 0, &[0; 16]);
    assert_err!(parse_err(&d), FormatError::BadGrid(_));
}

#[test]
fn missing_sections() {
    // The grid description, hidden as an unknown optional kind.
    let mut d = golden_grid().to_bytes().unwrap();
    let g = section_position(&d, SectionKind::GridDesc);
    patch_table(&mut d, |t| {
        t[g].kind = 77;
        t[g].flags = 0;
    });
    assert_err!(
        parse_err(&d),
        FormatError::MissingSection(SectionKind::GridDesc)
    );
    // The pins while cells are stored.
    let mut d = golden_grid().to_bytes().unwrap();
    let p = section_position(&d, SectionKind::Pins);
    patch_table(&mut d, |t| {
        t[p].kind = 77;
        t[p].flags = 0;
    });
    assert_err!(
        parse_err(&d),
        FormatError::MissingSection(SectionKind::Pins)
    );
    // The cell index of a sparse grid: the dense rule then fails.
    let mut d = full_grid().to_bytes().unwrap();
    let ix = section_position(&d, SectionKind::CellIndex);
    patch_table(&mut d, |t| {
        t[ix].kind = 77;
        t[ix].flags = 0;
    });
    assert_err!(parse_err(&d), FormatError::BadGrid(_));
    // No sections at all.
    let empty = PinFileWriter::new(std::io::Cursor::new(Vec::new()))
        .unwrap()
        .finish()
        .unwrap()
        .into_inner();
    assert_eq!(empty.len(), 64);
    assert_err!(
        parse_err(&empty),
        FormatError::MissingSection(SectionKind::GridDesc)
    );
}

#[test]
fn lying_grid_description() {
    type Patch = Box<dyn Fn(&mut GridDesc)>;
    let bad_grid: Vec<(&str, Patch)> = vec![
        ("dims x zero", Box::new(|g| g.dims[0] = 0)),
        ("dims z zero", Box::new(|g| g.dims[2] = 0)),
        ("dims all zero", Box::new(|g| g.dims = [0; 3])),
        ("dim over MAX_DIM", Box::new(|g| g.dims[1] = MAX_DIM + 1)),
        ("dims u32::MAX", Box::new(|g| g.dims = [u32::MAX; 3])),
        (
            "cells over MAX_CELLS",
            Box::new(|g| g.dims = [MAX_DIM, MAX_DIM, MAX_DIM]),
        ),
        (
            "cells just over MAX_CELLS",
            Box::new(|g| g.dims = [1 << 16, 1 << 16, 1]),
        ),
        ("stored 2^40", Box::new(|g| g.stored_cells = 1 << 40)),
        ("stored u64::MAX", Box::new(|g| g.stored_cells = u64::MAX)),
        ("bits per pin", Box::new(|g| g.bits_per_pin = 64)),
        ("pins per entry 0", Box::new(|g| g.pins_per_entry = 0)),
        (
            "pins per entry huge",
            Box::new(|g| g.pins_per_entry = u32::MAX),
        ),
        ("direction kind", Box::new(|g| g.direction_kind = 7)),
        ("direction res 0", Box::new(|g| g.direction_res = [0, 0])),
        (
            "direction res huge",
            Box::new(|g| g.direction_res = [u32::MAX, u32::MAX]),
        ),
        (
            "octahedral not square",
            Box::new(|g| {
                g.direction_kind = DIRECTIONS_OCTAHEDRAL;
                g.direction_res = [2, 3];
            }),
        ),
        // Flag bits no version defines (`pinbake verify` accepted 0xFFFFFFFF).
        ("flags all set", Box::new(|g| g.flags = u32::MAX)),
        ("flags bit 2", Box::new(|g| g.flags = 4)),
        ("box NaN", Box::new(|g| g.box_min[1] = f64::NAN)),
        ("box inf", Box::new(|g| g.box_max[2] = f64::INFINITY)),
        ("box inverted", Box::new(|g| g.box_min[0] = g.box_max[0])),
        (
            "box extent overflow",
            Box::new(|g| {
                g.box_min[0] = -f64::MAX;
                g.box_max[0] = f64::MAX;
            }),
        ),
        (
            "source box NaN",
            Box::new(|g| g.source_box_max[0] = f64::NAN),
        ),
        (
            "transform NaN",
            Box::new(|g| g.local_to_world[5] = f64::NAN),
        ),
        ("step negative", Box::new(|g| g.step_size = -1.0)),
        ("scale NaN", Box::new(|g| g.density_scale = f64::NAN)),
    ];
    for (what, f) in &bad_grid {
        for b in [
            golden_grid().to_bytes().unwrap(),
            full_grid().to_bytes().unwrap(),
        ] {
            let mut d = b.clone();
            patch_grid(&mut d, f);
            let e = parse_err(&d);
            assert!(matches!(e, FormatError::BadGrid(_)), "{what}: {e:?}");
        }
    }
    // Plausible lies that pass the grid checks but break a section size equation.
    let bad_data: Vec<(&str, Patch, SectionKind)> = vec![
        (
            "stored one less",
            Box::new(|g| g.stored_cells -= 1),
            SectionKind::Pins,
        ),
        (
            "stored zero",
            Box::new(|g| g.stored_cells = 0),
            SectionKind::Pins,
        ),
        (
            "ppe doubled",
            Box::new(|g| g.pins_per_entry *= 2),
            SectionKind::Pins,
        ),
        (
            "more directions",
            Box::new(|g| g.direction_res[0] += 1),
            SectionKind::Pins,
        ),
        (
            "dims grow",
            Box::new(|g| g.dims[0] += 1),
            SectionKind::CellIndex,
        ),
        (
            "dims grow y",
            Box::new(|g| g.dims[1] = 3),
            SectionKind::CellIndex,
        ),
    ];
    for (what, f, kind) in &bad_data {
        let mut d = full_grid().to_bytes().unwrap();
        patch_grid(&mut d, f);
        let e = parse_err(&d);
        assert!(
            matches!(&e, FormatError::BadData(k, _) if k == kind),
            "{what}: {e:?}"
        );
    }
    // Dense grid: stored must equal covered.
    let mut d = dense_grid().to_bytes().unwrap();
    patch_grid(&mut d, |g| g.stored_cells -= 1);
    assert_err!(parse_err(&d), FormatError::BadGrid(_));
    // A grid record that is too short.
    let mut d = golden_grid().to_bytes().unwrap();
    let g = section_position(&d, SectionKind::GridDesc);
    patch_table(&mut d, |t| t[g].length = 100);
    assert_err!(
        parse_err(&d),
        FormatError::BadData(SectionKind::GridDesc, _)
    );
}

#[test]
fn lying_tile() {
    type Patch = Box<dyn Fn(&mut [u8])>;
    let set = |f: fn(&mut TileDesc)| -> Patch {
        Box::new(move |s: &mut [u8]| {
            let mut t: TileDesc = bytemuck::pod_read_unaligned(&s[..16]);
            f(&mut t);
            s[..16].copy_from_slice(bytemuck::bytes_of(&t));
        })
    };
    let cases: Vec<(&str, Patch, bool)> = vec![
        ("count zero", set(|t| t.tile_count = 0), true),
        ("index >= count", set(|t| t.tile_index = t.tile_count), true),
        ("empty slab", set(|t| t.z_end = t.z_begin), true),
        ("slab past dims", set(|t| t.z_end = 5), true),
        (
            "slab u32::MAX",
            set(|t| {
                t.z_begin = 0;
                t.z_end = u32::MAX;
            }),
            true,
        ),
        // A different valid slab of the same height: parse passes; the index is still right.
        (
            "shifted slab",
            set(|t| {
                t.z_begin = 0;
                t.z_end = 2;
            }),
            false,
        ),
        // A different height: the index no longer matches.
        ("taller slab", set(|t| t.z_begin = 0), false),
    ];
    for (what, f, grid_err) in cases {
        let mut d = full_grid().to_bytes().unwrap();
        patch_section(&mut d, SectionKind::Tile, f);
        let r = PinFile::parse(&d);
        match (what, r) {
            (_, Err(FormatError::BadGrid(_))) if grid_err => {}
            ("shifted slab", Ok(f)) => f.verify().unwrap(),
            ("taller slab", Err(FormatError::BadData(SectionKind::CellIndex, _))) => {}
            (_, r) => panic!("{what}: {r:?}"),
        }
    }
    // Too short a tile record.
    let mut d = full_grid().to_bytes().unwrap();
    let t = section_position(&d, SectionKind::Tile);
    patch_table(&mut d, |e| e[t].length = 8);
    assert_err!(parse_err(&d), FormatError::BadData(SectionKind::Tile, _));
}

#[test]
fn lying_majorant_and_density_headers() {
    for kind in [SectionKind::Majorant, SectionKind::Density] {
        for dims in [[0, 1, 1], [1, 1, 0], [u32::MAX; 3], [2, 2, 2], [1, 1, 1]] {
            let mut d = full_grid().to_bytes().unwrap();
            patch_section(&mut d, kind, |s| {
                s[..12].copy_from_slice(bytemuck::cast_slice(&dims))
            });
            assert_err!(parse_err(&d), FormatError::BadData(k, _) if k == kind);
        }
        // Shorter than its 16-byte prefix.
        let mut d = full_grid().to_bytes().unwrap();
        let i = section_position(&d, kind);
        patch_table(&mut d, |t| t[i].length = 12);
        assert_err!(parse_err(&d), FormatError::BadData(k, _) if k == kind);
    }
    let mut d = full_grid().to_bytes().unwrap();
    patch_section(&mut d, SectionKind::Density, |s| s[12] = 1);
    assert_err!(parse_err(&d), FormatError::BadData(SectionKind::Density, _));
}

#[test]
fn misaligned_buffer() {
    let b = golden_grid().to_bytes().unwrap();
    for shift in 1..8 {
        let s = Shifted::new(&b, shift);
        let r = PinFile::parse(s.bytes());
        if shift % 4 == 0 {
            // 4-byte alignment is all the element types need.
            r.unwrap().verify().unwrap();
        } else {
            assert_err!(r.unwrap_err(), FormatError::Misaligned(4));
        }
    }
    // Magic and version are still reported first from an odd address.
    let mut bad = b.clone();
    bad[0] = 0;
    assert_err!(
        PinFile::parse(Shifted::new(&bad, 1).bytes()).unwrap_err(),
        FormatError::BadMagic
    );
}

#[test]
fn bad_metadata_bytes() {
    let garbage: [&[u8]; 4] = [
        &[0xFF; 9],
        &[200, 1, 2, 3],
        // A valid-looking string length of 1 MiB - 1 in a 5-byte section.
        &[0xFC, 0xFF, 0xFF, 0x0F, 0x00],
        &[0x80, 0xC0, 0xFF, 0x00],
    ];
    for g in garbage {
        let mut w = PinFileWriter::new(std::io::Cursor::new(Vec::new())).unwrap();
        let mut grid = golden_grid();
        grid.metadata = None;
        grid.write_into(&mut w).unwrap();
        w.add_section(SectionKind::Metadata as u32, 0, g).unwrap();
        let d = w.finish().unwrap().into_inner();
        let f = PinFile::parse(&d).expect("metadata is not decoded by parse");
        assert_err!(f.verify().unwrap_err(), FormatError::BadMetadata(_));
        assert_err!(
            f.metadata().unwrap().unwrap_err(),
            FormatError::BadMetadata(_)
        );
        assert_err!(
            OwnedPinGrid::from_file(&f).unwrap_err(),
            FormatError::BadMetadata(_)
        );
    }
    // Trailing bytes after a valid value.
    let mut d = golden_grid().to_bytes().unwrap();
    let m = section_position(&d, SectionKind::Metadata);
    patch_table(&mut d, |t| t[m].length += 1);
    let sum = checksum(&d[section_range(&d, SectionKind::Metadata)]);
    patch_table(&mut d, |t| t[m].checksum = sum);
    assert_err!(verify_err(&d), FormatError::BadMetadata(_));
    // Over the size limit: refused by parse without decoding.
    let big = vec![0u8; MAX_METADATA_BYTES + 1];
    let mut w = PinFileWriter::new(std::io::Cursor::new(Vec::new())).unwrap();
    let mut grid = golden_grid();
    grid.metadata = None;
    grid.write_into(&mut w).unwrap();
    w.add_section(SectionKind::Metadata as u32, 0, &big)
        .unwrap();
    let d = w.finish().unwrap().into_inner();
    assert_err!(parse_err(&d), FormatError::BadMetadata(_));
}

#[test]
fn non_canonical_cell_index_is_caught_by_verify() {
    let b = full_grid().to_bytes().unwrap();
    let ix: Vec<u32> = u32s(&b[section_range(&b, SectionKind::CellIndex)]);
    let stored: Vec<usize> = (0..ix.len()).filter(|&i| ix[i] != EMPTY_CELL).collect();
    assert!(stored.len() >= 2);
    type Edit = Box<dyn Fn(&mut [u32])>;
    let (a, c) = (stored[0], stored[1]);
    let first_empty = ix.iter().position(|&x| x == EMPTY_CELL).unwrap();
    let cases: Vec<(&str, Edit)> = vec![
        ("swapped blocks", Box::new(move |x| x.swap(a, c))),
        ("duplicate block", Box::new(move |x| x[c] = x[a])),
        ("block out of range", Box::new(move |x| x[a] = 1_000_000)),
        ("dropped cell", Box::new(move |x| x[c] = EMPTY_CELL)),
        ("extra cell", Box::new(move |x| x[first_empty] = 0)),
    ];
    for (what, edit) in cases {
        let mut d = b.clone();
        patch_section(&mut d, SectionKind::CellIndex, |s| {
            let mut v: Vec<u32> = u32s(s);
            edit(&mut v);
            s.copy_from_slice(bytemuck::cast_slice(&v));
        });
        let f = PinFile::parse(&d).unwrap();
        let e = f.verify().unwrap_err();
        assert!(
            matches!(e, FormatError::BadData(SectionKind::CellIndex, _)),
            "{what}: {e:?}"
        );
        // Lookups on the bad index never panic; out-of-range blocks read as empty.
        for z in 0..4 {
            for y in 0..2 {
                for x in 0..3 {
                    for dir in 0..8 {
                        let _ = f.entry([x, y, z], dir, 1);
                    }
                }
            }
        }
        if what == "block out of range" {
            let cell = [
                (a % 3) as u32,
                (a / 3 % 2) as u32,
                (a / 6) as u32 + f.shape().z_begin,
            ];
            assert_eq!(f.cell_pins(cell), None);
            assert_eq!(f.entry(cell, 0, 0), PinEntry::EMPTY);
        }
    }
}

#[test]
fn bad_values_are_caught_by_verify() {
    fn pin_case(p: PinEntry) -> FormatError {
        let mut d = golden_grid().to_bytes().unwrap();
        patch_section(&mut d, SectionKind::Pins, |s| {
            s.copy_from_slice(bytemuck::bytes_of(&p))
        });
        verify_err(&d)
    }
    for p in [
        PinEntry {
            mask: 1,
            t_min: f32::NAN,
        },
        PinEntry {
            mask: 0,
            t_min: f32::NAN,
        },
        PinEntry {
            mask: 1,
            t_min: -0.5,
        },
        PinEntry {
            mask: 1,
            t_min: 1.5,
        },
        PinEntry {
            mask: 1,
            t_min: f32::INFINITY,
        },
        PinEntry {
            mask: 1,
            t_min: 1.0,
        },
    ] {
        assert_err!(pin_case(p), FormatError::BadData(SectionKind::Pins, _));
    }
    for v in [f32::NAN, -1.0, f32::INFINITY] {
        let mut d = golden_grid().to_bytes().unwrap();
        patch_section(&mut d, SectionKind::Majorant, |s| {
            s[16..20].copy_from_slice(&v.to_le_bytes())
        });
        assert_err!(
            verify_err(&d),
            FormatError::BadData(SectionKind::Majorant, _)
        );
    }
    for v in [
        half::f16::NAN,
        half::f16::INFINITY,
        half::f16::from_f32(-2.0),
    ] {
        let mut d = full_grid().to_bytes().unwrap();
        patch_section(&mut d, SectionKind::Density, |s| {
            s[20..22].copy_from_slice(&v.to_le_bytes())
        });
        assert_err!(
            verify_err(&d),
            FormatError::BadData(SectionKind::Density, _)
        );
    }
    // Edge values that are valid: t_min exactly 0 with any mask, 1 with mask 0, -0.0.
    for p in [
        PinEntry {
            mask: u32::MAX,
            t_min: 0.0,
        },
        PinEntry {
            mask: 0,
            t_min: 1.0,
        },
        PinEntry {
            mask: 5,
            t_min: -0.0,
        },
    ] {
        let mut d = golden_grid().to_bytes().unwrap();
        patch_section(&mut d, SectionKind::Pins, |s| {
            s.copy_from_slice(bytemuck::bytes_of(&p))
        });
        PinFile::parse(&d).unwrap().verify().unwrap();
    }
}

#[test]
fn lying_sparse_density_header_and_lengths() {
    let kind = SectionKind::SparseDensity;
    for grid in [sparse_grid(), sparse_grid_f32()] {
        let good = grid.to_bytes().unwrap();
        // Header words: dims, encoding, brick edge, brick count.
        let lies: [(usize, u32); 10] = [
            (0, 0),
            (2, 0),
            (0, u32::MAX),
            (1, 100),
            (3, 2),
            (3, 7),
            (4, 3),
            (4, 128),
            (
                5,
                grid.sparse_density.as_ref().unwrap().header.brick_count + 1,
            ),
            (5, u32::MAX),
        ];
        for (word, v) in lies {
            let mut d = good.clone();
            patch_section(&mut d, kind, |s| {
                s[word * 4..word * 4 + 4].copy_from_slice(&v.to_le_bytes())
            });
            assert_err!(parse_err(&d), FormatError::BadData(k, _) if k == kind);
        }
        // A section length shorter than the header, or one that cuts into the bricks.
        for len in [0u64, 20, 33] {
            let mut d = good.clone();
            let i = section_position(&d, kind);
            patch_table(&mut d, |t| t[i].length = len);
            assert_err!(parse_err(&d), FormatError::BadData(k, _) if k == kind);
        }
    }
}

#[test]
fn bad_sparse_index_entries_and_values_are_caught_by_verify() {
    let kind = SectionKind::SparseDensity;
    let grid = sparse_grid();
    let sparse = grid.sparse_density.as_ref().unwrap();
    let count = sparse.header.brick_count;
    let first = sparse.index.iter().position(|&s| s != EMPTY_BRICK).unwrap();
    let last = sparse
        .index
        .iter()
        .rposition(|&s| s != EMPTY_BRICK)
        .unwrap();
    let empty = sparse.index.iter().position(|&s| s == EMPTY_BRICK).unwrap();
    let good = grid.to_bytes().unwrap();
    assert_eq!(header(&good).version_minor, 1);
    PinFile::parse(&good).unwrap().verify().unwrap();
    let entry = |b: usize| 32 + 4 * b;
    // Out of range, a slot used twice, an empty brick dropped from the count, a NaN voxel.
    let cases: Vec<(usize, u32, &str)> = vec![
        (entry(first), count, "slot"),
        (entry(first), u32::MAX - 1, "slot"),
        (entry(empty), 0, "slot"),
        (entry(last), EMPTY_BRICK, "non-empty bricks"),
    ];
    for (at, v, want) in cases {
        let mut d = good.clone();
        patch_section(&mut d, kind, |s| {
            s[at..at + 4].copy_from_slice(&v.to_le_bytes())
        });
        let f = PinFile::parse(&d).unwrap();
        // Lookups stay bounded whatever the entry says.
        let view = f.sparse_density().unwrap();
        for z in 0..9 {
            let _ = view.get([4, 2, z]);
        }
        let e = f.verify().unwrap_err();
        assert_err!(&e, FormatError::BadData(k, m) if *k == kind && m.contains(want));
    }
    let mut d = good.clone();
    let values_at = 32 + 4 * sparse.index.len();
    patch_section(&mut d, kind, |s| {
        s[values_at..values_at + 2].copy_from_slice(&half::f16::NAN.to_bits().to_le_bytes())
    });
    assert_err!(verify_err(&d), FormatError::BadData(k, _) if k == kind);
}

#[test]
fn only_a_sparse_density_makes_a_file_1_1() {
    for g in [golden_grid(), full_grid(), dense_grid()] {
        assert_eq!(header(&g.to_bytes().unwrap()).version_minor, 0);
    }
    for g in [sparse_grid(), sparse_grid_f32()] {
        let b = g.to_bytes().unwrap();
        assert_eq!(header(&b).version_minor, 1);
        let back = OwnedPinGrid::from_file(&PinFile::parse(&b).unwrap()).unwrap();
        assert_eq!(back, g);
    }
}

/// A grid with a 3x2x2 control section (format 1.1): the third brick empty.
fn control_grid() -> OwnedPinGrid {
    let mut g = full_grid();
    let n = 12;
    let mut control = OwnedControl {
        dims: [3, 2, 2],
        control: (0..n).map(|i| 0.5 + i as f32 * 0.1).collect(),
        residual: (0..n).map(|i| 0.25 + i as f32 * 0.05).collect(),
        majorant: (0..n).map(|i| 1.0 + i as f32 * 0.2).collect(),
    };
    control.control[2] = 0.0;
    control.residual[2] = 0.0;
    control.majorant[2] = 0.0;
    g.control = Some(control);
    g
}

/// The control section round-trips and makes the file 1.1; a lying header, a length that
/// does not match its dims, and a truncated section are parse errors of the control section
/// (lengths are checked before any count is used); values that break the section's rules pass
/// parse and fail verify.
#[test]
fn lying_control_section() {
    let kind = SectionKind::Control;
    let g = control_grid();
    let good = g.to_bytes().unwrap();
    assert_eq!(header(&good).version_minor, 1);
    let f = PinFile::parse(&good).unwrap();
    f.verify().unwrap();
    assert_eq!(OwnedPinGrid::from_file(&f).unwrap(), g);
    // Without the section the same grid is the same 1.0 bytes as ever.
    let mut plain = g.clone();
    plain.control = None;
    assert_eq!(plain.to_bytes().unwrap(), full_grid().to_bytes().unwrap());
    for (word, v) in [(0usize, 0u32), (1, 3), (2, u32::MAX), (0, 4)] {
        let mut d = good.clone();
        patch_section(&mut d, kind, |s| {
            s[word * 4..word * 4 + 4].copy_from_slice(&v.to_le_bytes())
        });
        assert_err!(parse_err(&d), FormatError::BadData(k, _) if k == kind);
    }
    for len in [0u64, 15, 16, 16 + 12 * 12 - 4] {
        let mut d = good.clone();
        let i = section_position(&d, kind);
        patch_table(&mut d, |t| t[i].length = len);
        assert_err!(parse_err(&d), FormatError::BadData(k, _) if k == kind);
    }
    // (array, brick, value, what the message names): a NaN, a negative, a control above the
    // majorant, a residual majorant of 0 in a brick that is not empty.
    let at = |array: usize, brick: usize| 16 + 4 * (12 * array + brick);
    for (array, brick, v, want) in [
        (0, 0, f32::NAN, "finite"),
        (2, 5, -1.0, "finite"),
        (1, 7, f32::INFINITY, "finite"),
        (0, 1, 10.0, "above its majorant"),
        (1, 4, 0.0, "residual majorant 0"),
    ] {
        let mut d = good.clone();
        patch_section(&mut d, kind, |s| {
            s[at(array, brick)..at(array, brick) + 4].copy_from_slice(&v.to_le_bytes())
        });
        let e = verify_err(&d);
        assert_err!(&e, FormatError::BadData(k, m) if *k == kind && m.contains(want));
    }
    // An owned grid that breaks the rules is refused before anything is written.
    let mut bad = g.clone();
    bad.control.as_mut().unwrap().residual[0] = 0.0;
    assert!(bad.to_bytes().is_err());
    bad.control.as_mut().unwrap().residual.pop();
    assert!(bad.to_bytes().is_err());
}
