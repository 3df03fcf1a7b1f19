//! The output rule for commands that write several files (`pin_volume::files`): no two outputs
//! name one file, and the files land together or not at all.

use std::io::Write;
use std::path::{Path, PathBuf};

use pin_volume::files::{FileError, WriteFile, check_outputs, write_together};

fn bytes(b: &'static [u8]) -> WriteFile<'static> {
    Box::new(move |out| out.write_all(b))
}

/// Writes some bytes, then fails as a full disk does.
fn disk_full() -> WriteFile<'static> {
    Box::new(|out| {
        out.write_all(&[7u8; 4096])?;
        Err(std::io::Error::from(std::io::ErrorKind::StorageFull))
    })
}

fn leftovers(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().ends_with(".partial"))
        .collect()
}

#[test]
fn two_outputs_may_not_name_one_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let input = d.join("in.pin");
    std::fs::write(&input, b"x").unwrap();
    let (a, b) = (d.join("a.png"), d.join("b.exr"));
    // New paths: the same name twice, and the same name through another spelling.
    for (x, y) in [
        (a.clone(), a.clone()),
        (a.clone(), d.join(".").join("a.png")),
    ] {
        let e = check_outputs(&[&x, &y], &[&input]).unwrap_err();
        assert!(matches!(e, FileError::SameOutput { .. }), "{e}");
        assert_eq!(e.to_string().lines().count(), 1);
    }
    // Existing files: a symlink and a hard link to the other output.
    std::fs::write(&a, b"old").unwrap();
    let link = d.join("link.png");
    std::os::unix::fs::symlink(&a, &link).unwrap();
    let hard = d.join("hard.png");
    std::fs::hard_link(&a, &hard).unwrap();
    for other in [&link, &hard] {
        let e = check_outputs(&[&a, other], &[&input]).unwrap_err();
        assert!(matches!(e, FileError::SameOutput { .. }), "{e}");
    }
    // Distinct outputs pass; an input among them is still refused as the input.
    assert_eq!(
        check_outputs(&[&a, &b], &[&input]).unwrap(),
        vec![a.clone(), b]
    );
    let e = check_outputs(&[&a, &input], &[&input]).unwrap_err();
    assert!(matches!(e, FileError::SameAsInput { .. }), "{e}");
}

#[test]
fn files_written_together_land_together_or_not_at_all() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (exr, png) = (d.join("img.exr"), d.join("img.png"));
    std::fs::write(&exr, b"old exr").unwrap();
    std::fs::write(&png, b"old png").unwrap();
    // The disk fills while the second file is written: the first is not replaced either.
    let e = write_together(vec![
        (exr.clone(), bytes(b"new exr")),
        (png.clone(), disk_full()),
    ])
    .unwrap_err();
    assert!(e.to_string().starts_with(&png.display().to_string()), "{e}");
    assert_eq!(std::fs::read(&exr).unwrap(), b"old exr");
    assert_eq!(std::fs::read(&png).unwrap(), b"old png");
    assert!(leftovers(d).is_empty(), "{:?}", leftovers(d));
    // A second file that cannot be created (its directory is missing): the same.
    let e = write_together(vec![
        (exr.clone(), bytes(b"new exr")),
        (d.join("missing/img.png"), bytes(b"new png")),
    ])
    .unwrap_err();
    assert!(e.to_string().contains("missing/img.png"), "{e}");
    assert_eq!(std::fs::read(&exr).unwrap(), b"old exr");
    assert!(leftovers(d).is_empty());
    // Both written: both replaced.
    write_together(vec![
        (exr.clone(), bytes(b"new exr")),
        (png.clone(), bytes(b"new png")),
    ])
    .unwrap();
    assert_eq!(std::fs::read(&exr).unwrap(), b"new exr");
    assert_eq!(std::fs::read(&png).unwrap(), b"new png");
    assert!(leftovers(d).is_empty());
}
