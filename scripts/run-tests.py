#!/usr/bin/env python3
"""Runs the workspace's test binaries in parallel lanes: scripts/test.sh's runner.

`cargo test` runs its test binaries one after another, and each binary has idle stretches:
a test waiting on a child process (a viewer under Xvfb, a Slurm job, a VDB worker), a
single test left running on one core while the other idles. Here the binaries that
`cargo test --no-run` built (their JSON messages on stdin) run LANES at a time, the longest
first, each in its package's directory with cargo's environment, as `cargo test` would run
it. A binary's output is printed whole when it ends, so lanes never interleave; the run ends
with one line per binary (its wall time, and the CPU time of it and of the processes its
tests started) and exits 1 if any failed.

    cargo test ... --no-run --message-format=json |
        run-tests.py [--lanes N] [--job NAME COMMAND]... [-- TEST ARGS]

A --job (scripts/test.sh: the doc tests, the Python package's tests) is a shell command that
a lane runs once the binaries have all started, so that it fills the lane that ends first.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time

# Seconds each binary took in a bare-clone run (2 cores, lavapipe), to start the long ones
# first; a binary not listed is taken as short. Only the order depends on these.
EXPECTED_S = {
    ("pinview", "it"): 104,
    ("pinlab", "it"): 105,
    ("pinbake", "it"): 77,
    ("pinrender", "pinrender"): 62,
    ("pinlab", "pinlab"): 8,
    ("pinbake", "memory"): 8,
    ("pin-tests", "it"): 7,
    ("pinrt-capi", "it"): 6,
}


def test_binaries(messages):
    """(package name, target name, executable, package directory) of each test binary."""
    out = []
    for line in messages:
        line = line.strip()
        if not line.startswith("{"):
            continue
        m = json.loads(line)
        if m.get("reason") != "compiler-artifact" or not m.get("executable"):
            continue
        if not m.get("profile", {}).get("test"):
            continue
        # "path+file:///work/main/pinbake#0.1.0", or "...#name@version" where the
        # directory's name is not the package's.
        pkg_dir = os.path.dirname(m["manifest_path"])
        name = package_name(m["package_id"], pkg_dir)
        out.append((name, m["target"]["name"], m["executable"], pkg_dir))
    return out


def package_name(package_id, pkg_dir):
    # Cargo before 1.77: "pinbake 0.1.0 (path+file:///work/main/pinbake)".
    if " (" in package_id:
        return package_id.split(" ", 1)[0]
    tail = package_id.rsplit("#", 1)[-1]
    if "@" in tail:
        return tail.split("@", 1)[0]
    # A path package whose id names only the version: read its manifest's name.
    with open(os.path.join(pkg_dir, "Cargo.toml"), encoding="utf-8") as f:
        in_package = False
        for row in f:
            row = row.strip()
            if row.startswith("["):
                in_package = row == "[package]"
            elif in_package and row.startswith("name"):
                return row.split("=", 1)[1].strip().strip('"')
    return os.path.basename(pkg_dir)


def binary_run(binary, test_args):
    """A test binary as a run: in its package's directory, with cargo's environment."""
    name, target, exe, pkg_dir = binary
    env = {
        "CARGO_MANIFEST_DIR": pkg_dir,
        "CARGO_PKG_NAME": name,
        "CARGO_CRATE_NAME": target.replace("-", "_"),
    }
    return (f"{name} {target}", f"{name} {target} ({os.path.basename(exe)})",
            [exe, *test_args], pkg_dir, env)


def job_run(name, command):
    """A --job as a run: a shell command in the current directory."""
    return (name, name, ["bash", "-c", command], os.getcwd(), {})


def run_one(run, results, lock, printer):
    name, label, argv, cwd, env = run
    with tempfile.TemporaryFile() as log:
        t = time.monotonic()
        child = subprocess.Popen(argv, cwd=cwd, env={**os.environ, **env}, stdout=log,
                                 stderr=subprocess.STDOUT)
        # wait4: the binary's own CPU time and that of every process it waited for (the
        # viewers, renders and compilers its tests start), apart from the other lane's.
        _, status, usage = os.wait4(child.pid, 0)
        child.returncode = rc = os.waitstatus_to_exitcode(status)
        seconds = time.monotonic() - t
        cpu = usage.ru_utime + usage.ru_stime
        log.seek(0)
        text = log.read().decode("utf-8", "replace")
    with lock:
        results.append((name, rc, seconds, cpu))
        printer(f"== {label}: {seconds:.1f} s, "
                f"{cpu:.1f} s of CPU, {'ok' if rc == 0 else f'FAILED (exit {rc})'}\n{text}")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--lanes", type=int, default=2, help="binaries run at once (default 2)")
    p.add_argument("--job", nargs=2, action="append", default=[], metavar=("NAME", "COMMAND"),
                   help="a shell command run in a lane after the binaries have started, "
                        "reported as they are (repeatable)")
    p.add_argument("test_args", nargs="*", help="arguments for every test binary")
    a = p.parse_args()
    if a.lanes < 1:
        p.error("--lanes must be at least 1")
    binaries = test_binaries(sys.stdin)
    if not binaries:
        print("run-tests.py: no test binaries in cargo's messages", file=sys.stderr)
        return 1
    binaries.sort(key=lambda b: (-EXPECTED_S.get((b[0], b[1]), 0), b[0], b[1]))
    # The jobs last: they are short, and fill the lane that ends first.
    queue = [binary_run(b, a.test_args) for b in binaries]
    queue += [job_run(name, command) for name, command in a.job]
    results, lock = [], threading.Lock()

    def printer(text):
        sys.stdout.write(text if text.endswith("\n") else text + "\n")
        sys.stdout.flush()

    def lane():
        while True:
            with lock:
                if not queue:
                    return
                run = queue.pop(0)
            run_one(run, results, lock, printer)

    t = time.monotonic()
    lanes = [threading.Thread(target=lane) for _ in range(min(a.lanes, len(queue)))]
    for th in lanes:
        th.start()
    for th in lanes:
        th.join()
    failed = [r for r in results if r[1] != 0]
    cpu = sum(r[3] for r in results)
    print(f"== test binaries and jobs: {len(results)} in {time.monotonic() - t:.1f} s "
          f"on {len(lanes)} lanes ({cpu:.0f} s of CPU), {len(failed)} failed")
    print("   wall (s)  CPU (s)  binary or job")
    for name, rc, seconds, cpu in sorted(results, key=lambda r: -r[2]):
        print(f"   {seconds:8.1f} {cpu:8.1f}  {name}"
              f"{'' if rc == 0 else f'  FAILED (exit {rc})'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
