//! The farm path on a real scheduler: a single-node Slurm cluster (`scripts/slurm-local.sh`,
//! Debian's `slurm-wlm` and `munge`) runs `docs/farm.md`'s scripts as written there (this test
//! reads them out of the document, so the document cannot drift from what works):
//! a 4-tile bake of the hydrogen volume as a job array, the merge as a job that depends on the
//! array, compared byte for byte with a monolithic bake; the same bake in 4 parts split by
//! volume (`--part`), merged the same way; and a 3-frame sequence as a job array
//! over frames, compared with local bakes of the same frames. Where the daemons cannot start,
//! the test fails with the reason; it never passes without having run the jobs.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_pinbake");

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The fenced code block that follows `<!-- slurm: NAME -->` in docs/farm.md.
fn farm_script(name: &str) -> String {
    let doc = std::fs::read_to_string(root().join("docs/farm.md")).unwrap();
    let marker = format!("<!-- slurm: {name} -->");
    let at = doc
        .find(&marker)
        .unwrap_or_else(|| panic!("docs/farm.md has no {marker}"));
    let rest = &doc[at + marker.len()..];
    let start = rest
        .find("```bash\n")
        .expect("a bash block after the marker")
        + 8;
    let end = rest[start..].find("```").expect("the block ends") + start;
    rest[start..end].to_string()
}

/// Stops the cluster when the test ends, however it ends.
struct Cluster {
    dir: PathBuf,
    conf: String,
}

impl Cluster {
    fn start(dir: &Path) -> Cluster {
        let out = Command::new("bash")
            .arg(root().join("scripts/slurm-local.sh"))
            .arg("start")
            .arg(dir)
            // Room for the 11 tasks of the three arrays at once (8 CPUs each, as docs/farm.md
            // asks; memory is not a consumable here): on the default 16-CPU node Slurm ran
            // two at a time, about 3 s apart, which was most of this test's time.
            .env("SLURM_LOCAL_CPUS", "96")
            .stdin(Stdio::null())
            .output()
            .expect("run scripts/slurm-local.sh");
        assert!(
            out.status.success(),
            "the local Slurm cluster did not start (install slurm-wlm and munge; .ci/run does): {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let stdout = String::from_utf8_lossy(&out.stdout);
        let conf = stdout
            .trim()
            .strip_prefix("export SLURM_CONF=")
            .expect("slurm-local.sh prints the SLURM_CONF line")
            .to_string();
        Cluster {
            dir: dir.to_path_buf(),
            conf,
        }
    }

    /// A command that talks to this cluster, with `pinbake` first on PATH (jobs inherit it).
    fn cmd(&self, program: &str, cwd: &Path) -> Command {
        let bin_dir = Path::new(BIN).parent().unwrap();
        let path = format!(
            "{}:{}",
            bin_dir.display(),
            std::env::var("PATH").unwrap_or_default()
        );
        let mut c = Command::new(program);
        c.env("SLURM_CONF", &self.conf)
            .env("PATH", path)
            .current_dir(cwd)
            .stdin(Stdio::null());
        c
    }

    /// Waits until job `id` (every task of an array) has ended; its final state.
    fn wait(&self, id: &str, cwd: &Path) -> String {
        let started = Instant::now();
        loop {
            let out = self
                .cmd("scontrol", cwd)
                .args(["show", "job", id])
                .output()
                .expect("scontrol");
            let text = String::from_utf8_lossy(&out.stdout).into_owned();
            let states: Vec<&str> = text
                .split_whitespace()
                .filter_map(|w| w.strip_prefix("JobState="))
                .collect();
            let done = !states.is_empty()
                && states.iter().all(|s| {
                    matches!(
                        *s,
                        "COMPLETED"
                            | "FAILED"
                            | "CANCELLED"
                            | "TIMEOUT"
                            | "NODE_FAIL"
                            | "OUT_OF_MEMORY"
                    )
                });
            if done {
                return states.join(",");
            }
            assert!(
                started.elapsed() < Duration::from_secs(240),
                "job {id} did not finish in 240 s: {text}"
            );
            std::thread::sleep(Duration::from_millis(500));
        }
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new("bash")
            .arg(root().join("scripts/slurm-local.sh"))
            .arg("stop")
            .arg(&self.dir)
            .status();
    }
}

fn pinbake(args: &[&str]) {
    let o = Command::new(BIN)
        .args(args)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// An 8^3 f32 frame: a blob that moves with the frame number.
fn write_frame(path: &Path, frame: i64) {
    let mut bytes = Vec::new();
    for z in 0..8 {
        for y in 0..8 {
            for x in 0..8 {
                let d2 = (x as f32 - 2.0 - frame as f32).powi(2)
                    + (y as f32 - 4.0).powi(2)
                    + (z as f32 - 4.0).powi(2);
                bytes.extend_from_slice(&(3.0 * (-d2 / 4.0).exp()).to_le_bytes());
            }
        }
    }
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn slurm_farm_reproduces_the_monolithic_bake() {
    let tmp = tempfile::tempdir().unwrap();
    let work = tmp.path().join("work");
    std::fs::create_dir_all(&work).unwrap();
    let cluster = Cluster::start(&tmp.path().join("slurm"));

    // Tiles: the array and the dependent merge, as docs/farm.md writes them.
    for name in ["bake-array.sh", "submit-tiles.sh"] {
        std::fs::write(work.join(name), farm_script(name)).unwrap();
    }
    let input = root().join("data/hydrogen_atom_128x128x128_uint8.raw");
    let opts = "--cells 8 --dirs octahedral:4 --seed 1 --density-scale 0.05 --step 0.02";
    let parts = work.join("parts");
    let merged = work.join("hydrogen.pin");
    let out = cluster
        .cmd("bash", &work)
        .arg("submit-tiles.sh")
        .env("INPUT", &input)
        .env("BAKE_OPTS", opts)
        .env("N", "4")
        .env("PARTS", &parts)
        .env("OUT", &merged)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "submit-tiles.sh: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let tiles_merge_job = String::from_utf8_lossy(&out.stdout).trim().to_string();
    assert!(
        !tiles_merge_job.is_empty(),
        "submit-tiles.sh prints the merge job id"
    );

    // Parts: the same bake split by volume, its array and dependent merge as written, in
    // folders of their own.
    for name in ["bake-parts.sh", "submit-parts.sh"] {
        std::fs::write(work.join(name), farm_script(name)).unwrap();
    }
    let split = work.join("split");
    let merged_parts = work.join("hydrogen-parts.pin");
    let out = cluster
        .cmd("bash", &work)
        .arg("submit-parts.sh")
        .env("INPUT", &input)
        .env("BAKE_OPTS", opts)
        .env("N", "4")
        .env("PARTS", &split)
        .env("OUT", &merged_parts)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "submit-parts.sh: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let parts_merge_job = String::from_utf8_lossy(&out.stdout).trim().to_string();

    // Frames: one array task per frame.
    std::fs::write(work.join("bake-frames.sh"), farm_script("bake-frames.sh")).unwrap();
    for f in 1..=3 {
        write_frame(&work.join(format!("blob.{f:04}.raw")), f);
    }
    let frame_opts = "--cells 4 --dirs octahedral:2 --step 0.05 --dims 8,8,8 --type f32";
    let out = cluster
        .cmd("sbatch", &work)
        .args(["--parsable", "--array=1-3", "bake-frames.sh"])
        .env("FRAMES_IN", work.join("blob.####.raw"))
        .env("FRAMES_OUT", work.join("slurm.####.pin"))
        .env("BAKE_OPTS", frame_opts)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "sbatch bake-frames.sh: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let frames_job = String::from_utf8_lossy(&out.stdout).trim().to_string();

    // The three ran side by side (each phase is mostly Slurm's start-up latency); now each
    // result is checked as it would be alone.
    let state = cluster.wait(&tiles_merge_job, &work);
    assert_eq!(state, "COMPLETED", "the merge job ({tiles_merge_job})");
    for i in 0..4 {
        assert!(parts.join(format!("part_{i}.pin")).is_file(), "tile {i}");
    }
    let mono = work.join("mono.pin");
    let mut args = vec![
        "bake",
        input.to_str().unwrap(),
        "-o",
        mono.to_str().unwrap(),
    ];
    args.extend(opts.split(' '));
    pinbake(&args);
    assert_eq!(
        std::fs::read(&merged).unwrap(),
        std::fs::read(&mono).unwrap(),
        "the Slurm-merged tiles equal the monolithic bake byte for byte"
    );
    let state = cluster.wait(&parts_merge_job, &work);
    assert_eq!(
        state, "COMPLETED",
        "the parts' merge job ({parts_merge_job})"
    );
    assert_eq!(
        std::fs::read(&merged_parts).unwrap(),
        std::fs::read(&mono).unwrap(),
        "the Slurm-merged parts equal the monolithic bake byte for byte"
    );
    let state = cluster.wait(&frames_job, &work);
    assert!(
        state.split(',').all(|s| s == "COMPLETED"),
        "every frame task completed: {state}"
    );
    let local = work.join("local.####.pin");
    let blob = work.join("blob.####.raw");
    let mut args = vec![
        "bake",
        blob.to_str().unwrap(),
        "--frames",
        "1-3",
        "-o",
        local.to_str().unwrap(),
    ];
    args.extend(frame_opts.split(' '));
    pinbake(&args);
    for f in 1..=3 {
        let a = std::fs::read(work.join(format!("slurm.{f:04}.pin"))).unwrap();
        let b = std::fs::read(work.join(format!("local.{f:04}.pin"))).unwrap();
        assert_eq!(a, b, "frame {f}: the Slurm task equals the local bake");
    }
    drop(cluster);
}
