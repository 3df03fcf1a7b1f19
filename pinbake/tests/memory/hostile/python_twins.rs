//! The command line's side of the rules the Python package follows (`python/tests/
//! test_hostile.py`): the same library code refuses the same requests, here through the
//! `pinbake` binary. Bakes that would run for minutes are refused before they start, and a
//! placement that f32 queries cannot represent is refused at bake, at open and by `verify`.

use super::*;

/// A raw f32 grid of `n^3` voxels of white noise: detail no bake in the choice's range
/// resolves to a tiny target.
fn noise_raw(dir: &Path, n: usize) -> PathBuf {
    let path = dir.join(format!("noise_{n}x{n}x{n}_f32.raw"));
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut bytes = Vec::with_capacity(n * n * n * 4);
    for _ in 0..n * n * n {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let v = (state >> 40) as f32 / (1u64 << 24) as f32 * 40.0;
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(&path, bytes).unwrap();
    path
}

#[test]
fn a_target_error_asking_for_gigabytes_is_refused_before_the_bake() {
    let dir = tempfile::tempdir().unwrap();
    let input = noise_raw(dir.path(), 64);
    let out = dir.path().join("o.pin");
    let r = run(&[
        "bake",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--target-error",
        "1e-9",
        // The pins-only choice (a grid flag turns the default asset's rule off; that rule
        // keeps to its byte budget and says when the target is out of reach).
        "--pins-per-entry",
        "1",
    ]);
    // Was: 180 s and 2.1 GB written, with only `target_met: false` to say so.
    expect("--target-error 1e-9", &r, 2, "cannot be met");
    assert!(r.stderr.contains("MiB"), "{}", r.stderr);
    assert!(!out.exists());
    assert!(partials(dir.path()).is_empty());
}

#[test]
fn a_control_grid_beyond_its_limit_is_refused_before_the_bake() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.pin");
    let o = out.to_str().unwrap();
    let mut args = vec!["bake", "procedural:box", "-o", o, "--embed-control", "1"];
    args.extend(FAST);
    // Was: 170 s at 400 MB for the analytic field's 256^3 bricks.
    let r = run(&args);
    expect("--embed-control 1", &r, 2, "256x256x256 bricks");
    assert!(r.stderr.contains("at least 2 voxels"), "{}", r.stderr);
    assert!(!out.exists());
    let mut args = vec!["bake", "procedural:box", "-o", o, "--embed-control", "2"];
    args.extend(FAST);
    let r = run(&args);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
}

#[test]
fn placements_f32_cannot_represent_are_refused_at_bake() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.pin");
    let o = out.to_str().unwrap();
    for (spec, needle) in [
        // Was: baked and verified, then answered T = 1 through an opaque box.
        ("procedural:box:extent=1e39", "beyond +-1e12"),
        // Was: a file that every query refused.
        ("procedural:box:extent=1e-300", "1e-300 wide"),
    ] {
        let mut args = vec!["bake", spec, "-o", o];
        args.extend(FAST);
        let r = run(&args);
        assert_ne!(r.code, Some(0), "{spec}: {}", r.stderr);
        expect(spec, &r, r.code.unwrap_or(-1), needle);
        assert!(!r.stderr.contains("00000000"), "{spec}: {}", r.stderr);
        assert!(!out.exists());
    }
    // A NanoVDB grid whose index-to-world map shears by 1e100.
    let mut grid = nanovdb::Grid::new(
        nanovdb::Type::Float,
        vec![nanovdb::leaf([0, 0, 0], |k| k as f32 * 0.01)],
    );
    grid.mat = [0.5, 1e100, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.5];
    let sheared = dir.path().join("sheared.nvdb");
    std::fs::write(&sheared, nanovdb::file_bytes(&grid, 0)).unwrap();
    let mut args = vec!["bake", sheared.to_str().unwrap(), "-o", o];
    args.extend(FAST);
    let r = run(&args);
    expect("1e100 shear", &r, 1, "placement");
    assert!(!out.exists());
}

/// `valid_pin`'s bytes with the grid description's `local_to_world` entry `at` set to `v`,
/// every checksum resealed: only the placement rule can catch it.
fn with_transform_entry(valid: &[u8], at: usize, v: f64) -> Vec<u8> {
    let mut b = valid.to_vec();
    let u32_at = |b: &[u8], o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap());
    let u64_at = |b: &[u8], o: usize| u64::from_le_bytes(b[o..o + 8].try_into().unwrap());
    let count = u32_at(&b, 16) as usize;
    let table = u64_at(&b, 24) as usize;
    let entry = (0..count)
        .map(|i| table + 32 * i)
        .find(|&e| u32_at(&b, e) == 1)
        .expect("a grid description");
    let (offset, length) = (
        u64_at(&b, entry + 8) as usize,
        u64_at(&b, entry + 16) as usize,
    );
    // GridDesc: local_to_world starts at byte 88.
    let field = offset + 88 + 8 * at;
    b[field..field + 8].copy_from_slice(&v.to_le_bytes());
    let section = checksum(&b[offset..offset + length]);
    put_u64(&mut b, entry + 24, section);
    let table_sum = checksum(&b[table..table + 32 * count]);
    put_u64(&mut b, 48, table_sum);
    reseal(&mut b);
    b
}

#[test]
fn verify_and_open_refuse_a_singular_or_sheared_placement() {
    let dir = tempfile::tempdir().unwrap();
    let valid = valid_pin(dir.path());
    for (name, at, v, needle) in [
        ("singular", 10, 0.0, "singular"),
        ("1e100 shear", 1, 1e100, "local-to-world"),
    ] {
        let path = dir.path().join(format!("{}.pin", name.replace(' ', "_")));
        std::fs::write(&path, with_transform_entry(&valid, at, v)).unwrap();
        // Was: `verify` passed, and every query refused the file.
        let r = run(&["verify", path.to_str().unwrap()]);
        expect(&format!("verify {name}"), &r, 1, needle);
        let r = run(&["inspect", path.to_str().unwrap()]);
        expect(&format!("inspect {name}"), &r, 1, needle);
    }
}
