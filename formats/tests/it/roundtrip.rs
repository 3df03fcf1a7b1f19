//! Round trip over random grids: write, parse, copy back, compare; plus determinism and the
//! atomic writer.

use crate::common::*;
use pin_format::*;
use proptest::prelude::*;

fn arb_directions() -> impl Strategy<Value = Directions> {
    prop_oneof![
        (1u32..=8, 1u32..=4).prop_map(|(n_phi, n_theta)| Directions::Polar { n_phi, n_theta }),
        (1u32..=4).prop_map(|n| Directions::Octahedral { n }),
    ]
}

fn arb_metadata() -> impl Strategy<Value = Metadata> {
    (
        ".{0,12}",
        "[0-9a-z.]{0,8}",
        ".{0,12}",
        "[0-9a-f]{0,32}",
        ".{0,24}",
        any::<u64>(),
        any::<f64>(),
        any::<f64>(),
        any::<Option<u64>>(),
        proptest::collection::vec((".{0,6}", ".{0,10}"), 0..4),
    )
        .prop_map(
            |(tool, ver, name, hash, desc, seed, step, scale, time, extra)| Metadata {
                tool,
                tool_version: ver,
                source_name: name,
                source_hash: hash,
                source_description: desc,
                seed,
                // NaN would make the PartialEq comparison fail, not the format.
                step_size: if step.is_nan() { 0.5 } else { step },
                density_scale: if scale.is_nan() { 1.0 } else { scale },
                bake_unix_time: time,
                extra,
            },
        )
}

fn arb_dims(max: u32) -> impl Strategy<Value = [u32; 3]> {
    [1..=max, 1..=max, 1..=max]
}

prop_compose! {
    fn arb_params()(
        dims in arb_dims(5),
        directions in arb_directions(),
        pins_per_entry in 1u32..=3,
        sparse_empty in proptest::option::of(prop_oneof![Just(0.0), Just(1.0), 0.0..1.0f64]),
        tile_pick in proptest::option::of((any::<u32>(), any::<u32>(), any::<u32>())),
        majorant in proptest::option::of(arb_dims(3)),
        density in proptest::option::of(arb_dims(4)),
        metadata in proptest::option::of(arb_metadata()),
        seed in any::<u64>(),
    ) -> GridParams {
        let tile = tile_pick.map(|(a, b, c)| {
            let z = dims[2];
            let z_begin = a % z;
            let z_end = z_begin + 1 + b % (z - z_begin);
            let tile_count = 1 + c % 4;
            (c / 4 % tile_count, tile_count, z_begin, z_end)
        });
        GridParams { dims, directions, pins_per_entry, sparse_empty, tile, majorant, density, metadata, seed }
    }
}

fn check_round_trip(grid: &OwnedPinGrid) {
    let bytes = grid.to_bytes().expect("valid grid writes");
    assert_eq!(
        bytes.len() as u64 % 8,
        0,
        "every file ends on a section-table entry"
    );
    let file = PinFile::parse(&bytes).expect("written file parses");
    file.verify().expect("written file verifies");
    let back = OwnedPinGrid::from_file(&file).expect("copies back");
    assert_eq!(&back, grid);

    // Every section starts on a 64-byte boundary and the table lists them in file order.
    for s in file.sections() {
        assert_eq!(s.offset % 64, 0);
    }
    assert!(file.sections().is_sorted_by_key(|s| s.offset));

    // entry() agrees with the owned data everywhere, EMPTY for empty and uncovered cells.
    let mut empties = 0u64;
    for_each_expected(grid, |cell, dir, pin, want| {
        let got = file.entry(cell, dir, pin);
        assert_eq!(got, want, "cell {cell:?} dir {dir} pin {pin}");
        let covered = file.shape().local_cell(cell).is_some();
        if covered && dir == 0 && pin == 0 && file.cell_pins(cell).is_none() {
            empties += 1;
        }
    });
    assert_eq!(empties, file.empty_cells());
    // Out of range cells read as empty, never panic.
    let d = grid.desc.dims;
    assert_eq!(file.entry([d[0], 0, 0], 0, 0), PinEntry::EMPTY);
    assert_eq!(file.entry([0, 0, d[2]], 0, 0), PinEntry::EMPTY);
    assert_eq!(
        file.entry([u32::MAX; 3], u32::MAX, u32::MAX),
        PinEntry::EMPTY
    );

    // Deterministic: same grid, same bytes.
    assert_eq!(grid.to_bytes().unwrap(), bytes);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn round_trip(params in arb_params()) {
        check_round_trip(&build_grid(&params));
    }

    #[test]
    fn atomic_write_matches_to_bytes(params in arb_params()) {
        let grid = build_grid(&params);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("grid.pin");
        grid.write_atomic(&path).unwrap();
        prop_assert_eq!(std::fs::read(&path).unwrap(), grid.to_bytes().unwrap());
        // Nothing but the target is left behind.
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        prop_assert_eq!(names.len(), 1);
    }
}

#[test]
fn fixed_grids_round_trip() {
    check_round_trip(&full_grid());
    check_round_trip(&dense_grid());
    check_round_trip(&golden_grid());
}

#[test]
fn all_empty_sparse_grid_has_no_pin_section() {
    let mut p = GridParams {
        dims: [4, 4, 4],
        directions: Directions::THESIS_DEFAULT,
        pins_per_entry: 2,
        sparse_empty: Some(1.0),
        tile: None,
        majorant: None,
        density: None,
        metadata: None,
        seed: 3,
    };
    let grid = build_grid(&p);
    assert!(grid.pins.is_empty());
    let bytes = grid.to_bytes().unwrap();
    let file = PinFile::parse(&bytes).unwrap();
    assert!(
        file.sections()
            .iter()
            .all(|s| s.kind != layout::SectionKind::Pins as u32)
    );
    file.verify().unwrap();
    assert_eq!(file.empty_cells(), 64);
    check_round_trip(&grid);

    // An empty cell costs 4 bytes of index, a stored one block_len * 8 bytes of pins.
    p.sparse_empty = Some(0.0);
    let full = build_grid(&p).to_bytes().unwrap();
    let block = 64 * 2 * 8;
    assert!(full.len() >= bytes.len() + 64 * block);
}

#[test]
fn overwrite_replaces_atomically_and_drop_leaves_target_alone() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.pin");
    let a = dense_grid();
    let b = full_grid();
    a.write_atomic(&path).unwrap();
    b.write_atomic(&path).unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), b.to_bytes().unwrap());

    // A writer dropped before commit (a killed bake) removes its temp file and leaves the
    // target untouched.
    let mut w = AtomicPinFile::create(&path).unwrap();
    a.write_into(w.writer()).unwrap();
    let temp = w.temp_path().to_path_buf();
    assert!(temp.exists());
    assert_ne!(temp, path);
    drop(w);
    assert!(!temp.exists());
    assert_eq!(std::fs::read(&path).unwrap(), b.to_bytes().unwrap());
}

/// A signal handler registered through `create_announced` knows the temp file's path before
/// the file exists, so no moment has the file on disk and the handler unaware of it.
#[test]
fn temp_path_is_announced_before_the_file_exists() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.pin");
    let mut announced = Vec::new();
    let w = AtomicPinFile::create_announced(&path, |p| {
        if let Some(p) = p {
            assert!(!p.exists(), "announced after creation");
        }
        announced.push(p.map(|p| p.to_path_buf()));
    })
    .unwrap();
    assert_eq!(announced, vec![Some(w.temp_path().to_path_buf())]);
    assert!(w.temp_path().exists());
    // A directory that cannot hold the file: the failed attempt is withdrawn.
    let mut events = Vec::new();
    let missing = dir.path().join("no").join("a.pin");
    assert!(AtomicPinFile::create_announced(&missing, |p| events.push(p.is_some())).is_err());
    assert_eq!(events, vec![true, false]);
}

/// Temp files a SIGKILL left behind are swept by the next write to the same target; a live
/// writer's (locked) temp file and other targets' temp files are not.
#[test]
fn next_write_sweeps_only_dead_writers_temp_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let path = d.join("a.pin");
    let stale = d.join(".a.pin.Xy12Zq.partial");
    std::fs::write(&stale, b"killed").unwrap();
    let other_target = d.join(".a.pin.bak.Xy12Zq.partial");
    std::fs::write(&other_target, b"other").unwrap();
    let not_ours = d.join(".a.pin.Xy12Zq.partial.keep");
    std::fs::write(&not_ours, b"keep").unwrap();
    let live = AtomicPinFile::create(&path).unwrap();
    let live_temp = live.temp_path().to_path_buf();
    assert!(!stale.exists(), "the dead writer's temp file stayed");
    dense_grid().write_atomic(&path).unwrap();
    assert!(live_temp.exists(), "a live writer's temp file was swept");
    assert!(other_target.exists() && not_ours.exists());
    drop(live);
    assert!(!live_temp.exists());
}

#[test]
fn streamed_sections_equal_one_shot_sections() {
    // Writing a section in many small pieces gives the same bytes as one call.
    let grid = full_grid();
    let one = grid.to_bytes().unwrap();
    let mut w = PinFileWriter::new(std::io::Cursor::new(Vec::new())).unwrap();
    for s in PinFile::parse(&one).unwrap().sections() {
        let body = &one[s.offset as usize..(s.offset + s.length) as usize];
        w.begin_section(s.kind, s.flags).unwrap();
        for chunk in body.chunks(7) {
            w.write(chunk).unwrap();
        }
        w.end_section().unwrap();
    }
    assert_eq!(w.finish().unwrap().into_inner(), one);
}

#[test]
fn a_streamed_sparse_density_writes_the_bytes_of_an_owned_one() {
    for f32 in [false, true] {
        let mut grid = sparse_grid();
        let sd = sparse_density([21, 9, 17], 4, f32, 5);
        grid.sparse_density = Some(sd.clone());
        let want = grid.to_bytes().unwrap();
        let [_, values] = sd.body_parts();
        let index = sd.index.clone();
        grid.sparse_density = None;
        let write = |values: &[u8], header: SparseDensityHeader, index: &[u32]| {
            let mut w = PinFileWriter::new(std::io::Cursor::new(Vec::new())).unwrap();
            let mut r = values;
            grid.write_streamed_into(
                &mut w,
                StreamedSparseDensity {
                    header,
                    index,
                    values: &mut r,
                },
            )
            .map(|()| w.finish().unwrap().into_inner())
        };
        assert!(
            write(values, sd.header, &index).unwrap() == want,
            "f32 {f32}"
        );
        // A reader short of the header's count, or with bytes left over, is an error, not a
        // file.
        let short = write(&values[..values.len() - 1], sd.header, &index).unwrap_err();
        assert!(short.to_string().contains("still to copy"), "{short}");
        let mut long = values.to_vec();
        long.push(0);
        let extra = write(&long, sd.header, &index).unwrap_err();
        assert!(extra.to_string().contains("more bytes"), "{extra}");
        // The index is checked as an owned section's is.
        let mut lying = index.clone();
        let at = lying
            .iter()
            .position(|&s| s != layout::EMPTY_BRICK)
            .unwrap();
        lying[at] = 7777;
        assert!(write(values, sd.header, &lying).is_err());
        assert!(write(values, sd.header, &index[1..]).is_err());
        // A grid cannot carry both an owned and a streamed sparse density.
        let mut both = grid.clone();
        both.sparse_density = Some(sd.clone());
        let mut w = PinFileWriter::new(std::io::Cursor::new(Vec::new())).unwrap();
        let mut r = values;
        let e = both.write_streamed_into(
            &mut w,
            StreamedSparseDensity {
                header: sd.header,
                index: &index,
                values: &mut r,
            },
        );
        assert!(e.is_err());
    }
}

#[test]
fn writer_rejects_misuse() {
    let mut w = PinFileWriter::new(std::io::Cursor::new(Vec::new())).unwrap();
    assert!(matches!(w.write(b"x"), Err(FormatError::InvalidInput(_))));
    assert!(matches!(w.end_section(), Err(FormatError::InvalidInput(_))));
    w.begin_section(1, 0).unwrap();
    assert!(matches!(
        w.begin_section(2, 0),
        Err(FormatError::InvalidInput(_))
    ));
    assert!(matches!(w.finish(), Err(FormatError::InvalidInput(_))));

    // Invalid owned grids are refused before anything is written.
    let mut g = dense_grid();
    g.pins.pop();
    assert!(matches!(g.to_bytes(), Err(FormatError::InvalidInput(_))));
    let mut g = full_grid();
    g.cell_index.as_mut().unwrap().push(EMPTY_CELL);
    assert!(matches!(g.to_bytes(), Err(FormatError::InvalidInput(_))));
    let mut g = full_grid();
    g.majorant.as_mut().unwrap().0.dims = [u32::MAX; 3];
    assert!(matches!(g.to_bytes(), Err(FormatError::InvalidInput(_))));
    let mut g = full_grid();
    g.density.as_mut().unwrap().0.dims = [u32::MAX, u32::MAX, 0];
    assert!(matches!(g.to_bytes(), Err(FormatError::InvalidInput(_))));
    let mut g = dense_grid();
    g.desc.dims = [0, 1, 1];
    assert!(matches!(g.to_bytes(), Err(FormatError::BadGrid(_))));
}

#[test]
fn metadata_that_encodes_also_decodes() {
    // Many tiny extra entries: small on disk, but bincode's decode limit counts 48 bytes of
    // reservation per (String, String). A written file must always read back.
    let m = Metadata {
        extra: (0..30_000)
            .map(|_| (String::new(), String::new()))
            .collect(),
        ..Metadata::default()
    };
    match m.encode() {
        Ok(bytes) => assert_eq!(Metadata::decode(&bytes).unwrap(), m),
        Err(e) => assert!(matches!(e, FormatError::InvalidInput(_)), "{e}"),
    }
}

#[cfg(unix)]
#[test]
fn atomic_write_gives_ordinary_file_permissions() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("plain");
    std::fs::File::create(&plain).unwrap();
    let path = dir.path().join("a.pin");
    dense_grid().write_atomic(&path).unwrap();
    let mode = |p: &std::path::Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    assert_eq!(
        mode(&path),
        mode(&plain),
        "same as File::create under the same umask"
    );
}
