//! Hostile use of the C ABI from a C program (`tests/c/hostile.c`, compiled with the system
//! `cc` against the static library): a FIFO is refused without blocking, a directory says
//! so, a path with a newline keeps the message on one line, a buffer that cannot be copied
//! is `PINRT_STATUS_OUT_OF_MEMORY` instead of an abort, and misaligned `opts` and grid
//! pointers are `PINRT_STATUS_INVALID_ARGUMENT`. Each case fails when its check in the
//! library is taken out (the FIFO by the C program's alarm).

use std::process::Command;

use pin_volume::{DensitySource, ProceduralSpec, SourceSpec, open_source};
use pinbake::{BakeOptions, bake};

use crate::common::compile_c;

pub fn the_c_abi_keeps_the_hostile_use_contract() {
    let dir = tempfile::tempdir().unwrap();
    let spec: ProceduralSpec = "box".parse().unwrap();
    let source = open_source(&SourceSpec::Procedural(spec), pin_volume::DensityScale::ONE).unwrap();
    let opts = BakeOptions {
        cells: [4; 3],
        ..BakeOptions::default()
    };
    let (grid, _) = bake(source.as_ref() as &dyn DensitySource, &opts, &|_| {}).unwrap();
    let pin = dir.path().join("box.pin");
    grid.write_atomic(&pin).unwrap();

    let exe = compile_c(
        "capi/tests/c/hostile.c",
        &["-O1", "-D_DEFAULT_SOURCE"],
        dir.path(),
        "hostile",
    );
    let work = dir.path().join("work");
    std::fs::create_dir(&work).unwrap();
    let out = Command::new(&exe).arg(&pin).arg(&work).output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    print!("{stdout}");
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for case in [
        "fifo",
        "directory",
        "newline in path",
        "uncopyable buffer",
        "misaligned opts",
        "misaligned grid",
        "aligned query",
    ] {
        assert!(stdout.contains(&format!("ok {case}")), "{case}: {stdout}");
    }
}
