//! `pinbake bake PATTERN --frames RANGE -o PATTERN`: animated sequences end to end. Frames are
//! small generated raw grids (a blob that moves from frame to frame), one frame is missing and
//! one is corrupt (wrong size): those are reported, the rest bake, the exit code is 1, and the
//! JSON lists every frame. Each frame's file equals a single bake of that frame, byte for byte.

use std::path::Path;
use std::process::{Command, Output, Stdio};

const BIN: &str = env!("CARGO_BIN_EXE_pinbake");
const FAST: &[&str] = &[
    "--cells",
    "4",
    "--dirs",
    "octahedral:2",
    "--step",
    "0.05",
    "--dims",
    "8,8,8",
    "--type",
    "f32",
];

fn pinbake(args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .stdin(Stdio::null())
        .output()
        .expect("run pinbake")
}

/// An 8^3 f32 grid with a Gaussian blob whose centre moves with the frame number.
fn write_frame(path: &Path, frame: i64) {
    let c = 2.0 + frame as f32;
    let mut bytes = Vec::with_capacity(8 * 8 * 8 * 4);
    for z in 0..8 {
        for y in 0..8 {
            for x in 0..8 {
                let d2 =
                    (x as f32 - c).powi(2) + (y as f32 - 4.0).powi(2) + (z as f32 - 4.0).powi(2);
                bytes.extend_from_slice(&(3.0 * (-d2 / 4.0).exp()).to_le_bytes());
            }
        }
    }
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn a_sequence_bakes_every_frame_and_reports_the_failures() {
    let dir = tempfile::tempdir().unwrap();
    for f in [1, 2, 4] {
        write_frame(&dir.path().join(format!("blob.{f:04}.raw")), f);
    }
    // Frame 3 is missing; frame 5 is truncated.
    std::fs::write(dir.path().join("blob.0005.raw"), [0u8; 100]).unwrap();
    let input = dir.path().join("blob.####.raw");
    let output = dir.path().join("out_%03d.pin");
    let mut args = vec![
        "bake",
        input.to_str().unwrap(),
        "--frames",
        "1-5",
        "-o",
        output.to_str().unwrap(),
        "--json",
    ];
    args.extend_from_slice(FAST);
    let o = pinbake(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(
        o.status.code(),
        Some(1),
        "a failed frame makes exit 1: {err}"
    );
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
    let frames = v["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 5);
    assert_eq!(v["ok"], 3);
    assert_eq!(v["failed"], 2);
    for (i, fr) in frames.iter().enumerate() {
        let n = i as i64 + 1;
        assert_eq!(fr["frame"], n);
        let out = dir.path().join(format!("out_{n:03}.pin"));
        assert_eq!(fr["output"], out.display().to_string());
        let ok = n != 3 && n != 5;
        assert_eq!(fr["ok"], ok, "frame {n}: {fr}");
        assert_eq!(
            out.is_file(),
            ok,
            "frame {n}: only good frames leave a file"
        );
        if ok {
            assert!(fr["summary"]["pins"].as_u64().unwrap() > 0);
        } else {
            let e = fr["error"].as_str().unwrap();
            assert!(
                e.contains(&format!("blob.{n:04}.raw")),
                "names the file: {e}"
            );
        }
    }
    // Each failure is one stderr line naming the frame.
    assert!(err.lines().any(|l| l.contains("frame 3:")), "{err}");
    assert!(err.lines().any(|l| l.contains("frame 5:")), "{err}");

    // A frame of the sequence is byte-identical to a single bake of that frame.
    let single = dir.path().join("single.pin");
    let frame2 = dir.path().join("blob.0002.raw");
    let mut args = vec![
        "bake",
        frame2.to_str().unwrap(),
        "-o",
        single.to_str().unwrap(),
    ];
    args.extend_from_slice(FAST);
    let o = pinbake(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        std::fs::read(&single).unwrap(),
        std::fs::read(dir.path().join("out_002.pin")).unwrap()
    );
    // Different frames are different volumes.
    assert_ne!(
        std::fs::read(dir.path().join("out_001.pin")).unwrap(),
        std::fs::read(dir.path().join("out_002.pin")).unwrap()
    );
}

#[test]
fn sequence_usage_errors_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let out_pat = dir.path().join("o.####.pin");
    let out_plain = dir.path().join("o.pin");
    let cases: [(&str, &str, &str); 5] = [
        ("blob.raw", "1-3", out_pat.to_str().unwrap()),
        ("blob.####.raw", "1-3", out_plain.to_str().unwrap()),
        ("blob.####.raw", "3-1", out_pat.to_str().unwrap()),
        ("blob.##.##.raw", "1-3", out_pat.to_str().unwrap()),
        ("blob.####.raw", "1-3x0", out_pat.to_str().unwrap()),
    ];
    for (input, frames, output) in cases {
        let o = pinbake(&["bake", input, "--frames", frames, "-o", output]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{input} {frames} {output}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
    }
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        0,
        "nothing written"
    );
}

#[test]
fn no_frame_overwrites_another_frames_input() {
    let dir = tempfile::tempdir().unwrap();
    for f in 1..=10 {
        write_frame(&dir.path().join(format!("f.{f:04}.raw")), f);
    }
    let frame10 = std::fs::read(dir.path().join("f.0010.raw")).unwrap();
    // Frame 1's output is `f.0010.raw`: frame 10's input.
    let input = dir.path().join("f.####.raw");
    let output = dir.path().join("f.00#0.raw");
    let mut args = vec![
        "bake",
        input.to_str().unwrap(),
        "--frames",
        "1-10",
        "-o",
        output.to_str().unwrap(),
        "--json",
    ];
    args.extend_from_slice(FAST);
    let o = pinbake(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(
        std::fs::read(dir.path().join("f.0010.raw")).unwrap(),
        frame10,
        "frame 10's input is intact"
    );
    assert!(
        err.contains("frame 1:") && err.contains("is the input file"),
        "{err}"
    );
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
    assert_eq!(v["failed"], 1);
    assert_eq!(v["frames"][0]["ok"], false);
}

#[test]
fn a_frame_range_beyond_i64_is_a_usage_error_under_a_small_budget() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.####.pin");
    let o = pinbake(&[
        "bake",
        "f.####.raw",
        "--frames=-9223372036854775808-9223372036854775807",
        "--max-memory",
        "64M",
        "-o",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("more than 1000000 frames"), "{err}");
}

/// [`pinbake`], and the peak resident memory of that one process in bytes: reaped with
/// `wait4`, so that the other tests' children do not count (as they would in
/// `getrusage(RUSAGE_CHILDREN)`).
#[allow(clippy::zombie_processes)] // reaped by wait4 below, which std cannot see
fn pinbake_with_peak(args: &[&str]) -> (Output, u64) {
    use std::io::Read;
    use std::os::unix::process::ExitStatusExt;
    let mut child = Command::new(BIN)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run pinbake");
    let pid = child.id() as libc::pid_t;
    let (mut out, mut err) = (child.stdout.take().unwrap(), child.stderr.take().unwrap());
    let stdout = std::thread::spawn(move || {
        let mut v = Vec::new();
        let _ = out.read_to_end(&mut v);
        v
    });
    let stderr = std::thread::spawn(move || {
        let mut v = Vec::new();
        let _ = err.read_to_end(&mut v);
        v
    });
    let mut status = 0;
    // SAFETY: an all-zero rusage is a valid value; wait4 reaps our own child.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    assert_eq!(unsafe { libc::wait4(pid, &mut status, 0, &mut ru) }, pid);
    let output = Output {
        status: std::process::ExitStatus::from_raw(status),
        stdout: stdout.join().unwrap(),
        stderr: stderr.join().unwrap(),
    };
    (output, ru.ru_maxrss as u64 * 1024)
}

#[test]
fn missing_frames_cost_neither_memory_nor_lines() {
    let dir = tempfile::tempdir().unwrap();
    for f in [1, 2, 4] {
        write_frame(&dir.path().join(format!("blob.{f:04}.raw")), f);
    }
    let input = dir.path().join("blob.####.raw");
    let output = dir.path().join("out.####.pin");
    let mut args = vec![
        "bake",
        input.to_str().unwrap(),
        "--frames",
        "1-200000",
        "--max-memory",
        "100M",
        "-o",
        output.to_str().unwrap(),
        "--json",
    ];
    args.extend_from_slice(FAST);
    let (o, peak) = pinbake_with_peak(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    // Frame 3 alone, then frames 5-200000 as one line.
    assert_eq!(err.trim().lines().count(), 2, "{err}");
    assert!(err.contains("frames 5 to 200000 (199996 frames"), "{err}");
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
    assert_eq!(v["frames"].as_array().unwrap().len(), 200_000);
    assert_eq!(
        (v["ok"].as_u64(), v["failed"].as_u64()),
        (Some(3), Some(199_997))
    );
    // The results are streamed: the whole list held in memory took 190 MB.
    assert!(peak < 64 << 20, "peak RSS {peak} bytes");
}
