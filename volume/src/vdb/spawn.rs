//! Starting the worker: the executable, its environment and memory limit, and turning its
//! exit into one line.

use super::*;

/// Set in the worker's environment. A process that has it and is asked to start a worker is
/// itself a "worker" that did not understand `__vdb-worker` (e.g. a test harness given as
/// `worker_exe`, which would run its tests, open the VDB again and spawn itself without end);
/// it refuses instead of recursing.
pub const WORKER_ENV: &str = "PINBAKE_VDB_WORKER";

/// Spawns the worker with limits, parses its stream and turns every failure mode into text.
/// The worker's arguments after the level-set mode: none for a whole read; the part, the
/// density scale and how to treat the leaves outside the slab for a part read (`skip` when
/// the grid's statistics are given); `stats` and the scale for the statistics pass.
pub(super) fn worker_part_args(
    opt: &VdbOptions,
    scale: DensityScale,
    stats_pass: bool,
) -> Vec<String> {
    let scale = format!("{:?}", scale.get());
    if stats_pass {
        return vec!["stats".into(), scale];
    }
    match opt.part {
        None => Vec::new(),
        Some(p) => {
            let how = if opt.grid_stats.is_some() {
                "skip"
            } else {
                "summarise"
            };
            vec![format!("{}/{}", p.index, p.count), scale, how.into()]
        }
    }
}

pub(super) fn run_worker(
    path: &Path,
    opt: &VdbOptions,
    scale: DensityScale,
    file_size: u64,
    limit: u64,
    max_leaf_bytes: u64,
    stats_pass: bool,
) -> Result<Stream, StreamError> {
    if std::env::var_os(WORKER_ENV).is_some() {
        return Err(format!(
            "refusing to start a VDB reader from inside a VDB reader process: '{}' does not \
             handle `{WORKER_SUBCOMMAND}` (set VdbOptions::worker_exe to pinbake or pinrender)",
            opt.worker_exe.display()
        )
        .into());
    }
    let mut cmd = Command::new(&opt.worker_exe);
    cmd.env(WORKER_ENV, "1")
        .arg(WORKER_SUBCOMMAND)
        .arg(path)
        .arg(opt.grid.as_deref().unwrap_or(""))
        .arg(if opt.levelset_to_fog {
            "levelset-to-fog"
        } else {
            "fog"
        })
        .args(worker_part_args(opt, scale, stats_pass))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    #[cfg(unix)]
    {
        use std::os::unix::process::CommandExt;
        // SAFETY: the closure runs between fork and exec and only calls setrlimit, which is
        // async-signal-safe; it touches no locks and allocates nothing.
        unsafe {
            cmd.pre_exec(move || {
                let lim = libc::rlimit {
                    rlim_cur: limit as libc::rlim_t,
                    rlim_max: limit as libc::rlim_t,
                };
                let none = libc::rlimit {
                    rlim_cur: 0,
                    rlim_max: 0,
                };
                // A crash of the worker on a hostile file should not leave a core dump behind.
                libc::setrlimit(libc::RLIMIT_CORE, &none);
                if libc::setrlimit(libc::RLIMIT_AS, &lim) != 0
                    || libc::setrlimit(libc::RLIMIT_DATA, &lim) != 0
                {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
    }
    let mut child = cmd.spawn().map_err(|e| {
        format!(
            "cannot start the VDB reader '{}': {e}",
            opt.worker_exe.display()
        )
    })?;
    let stdout = child.stdout.take().ok_or("worker has no stdout")?;
    let part = opt.part.is_some() || stats_pass;
    let stderr = child.stderr.take().ok_or("worker has no stderr")?;
    let parser = std::thread::spawn(move || {
        let mut r = BufReader::with_capacity(1 << 16, stdout);
        let res = parse_stream_within(&mut r, file_size, max_leaf_bytes, part);
        // Drain so that the child never blocks on a full pipe after we stopped reading;
        // a refused budget closes the pipe instead, and the child ends at its next write.
        if !matches!(res, Err(StreamError::Budget { .. })) {
            let _ = std::io::copy(&mut r, &mut std::io::sink());
        }
        res
    });
    let err_reader = std::thread::spawn(move || {
        let mut buf = Vec::new();
        let _ = stderr.take(64 * 1024).read_to_end(&mut buf);
        String::from_utf8_lossy(&buf).into_owned()
    });
    let deadline = Instant::now() + opt.timeout;
    let mut timed_out = false;
    let status = loop {
        match child.try_wait() {
            Ok(Some(s)) => break s,
            Ok(None) => {}
            Err(e) => return Err(format!("waiting for the VDB reader failed: {e}").into()),
        }
        if Instant::now() >= deadline {
            timed_out = true;
            let _ = child.kill();
            break child
                .wait()
                .map_err(|e| format!("waiting for the VDB reader failed: {e}"))?;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let parsed = parser
        .join()
        .unwrap_or_else(|_| Err("worker stream parser panicked".into()));
    if let Err(StreamError::Budget { .. }) = parsed {
        return parsed;
    }
    let stderr_text = err_reader.join().unwrap_or_default();
    let last_line = stderr_text
        .lines()
        .rev()
        .find(|l| !l.trim().is_empty())
        .map(one_line);
    if timed_out {
        return Err(format!("VDB reader timed out after {} s", opt.timeout.as_secs_f64()).into());
    }
    if status.success() {
        return parsed;
    }
    // A limit below what the executable itself maps stops the dynamic loader before main,
    // or the kernel at exec (SIGSEGV before a line is written) when the executable's own
    // segments exceed it.
    #[cfg(unix)]
    let killed_at_exec = {
        use std::os::unix::process::ExitStatusExt;
        status.signal() == Some(libc::SIGSEGV)
            && stderr_text.trim().is_empty()
            && std::fs::metadata(&opt.worker_exe).is_ok_and(|m| m.len() > limit)
    };
    #[cfg(not(unix))]
    let killed_at_exec = false;
    if stderr_text.contains("memory allocation of")
        || stderr_text.contains("failed to map segment")
        || killed_at_exec
    {
        // The default limit is 64 MiB + 64 x the file size; every stored node carries its
        // masks uncompressed, so a valid file stays below it (docs/vdb.md).
        return Err(StreamError::Message(if opt.memory_limit.is_some() {
            format!(
                "VDB reader needs more than {} MiB of memory (the limit it was given)",
                limit / MIB
            )
        } else {
            format!(
                "VDB reader needs more than {} MiB of memory, more than a valid file of {file_size} bytes needs (docs/vdb.md): the file is probably corrupt",
                limit / MIB
            )
        }));
    }
    #[cfg(unix)]
    {
        use std::os::unix::process::ExitStatusExt;
        if let Some(sig) = status.signal() {
            return Err(format!("VDB reader crashed (signal {sig})").into());
        }
    }
    Err(last_line
        .unwrap_or_else(|| format!("VDB reader failed ({status})"))
        .into())
}
