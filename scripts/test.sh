#!/usr/bin/env bash
# The test command from the README: every crate, every feature, in the release profile that
# the main job builds too (the dependency tree is compiled once), then the Python package's
# tests (scripts/python-test.sh: wheel, fresh venv, pytest). Fixtures come from data/.
# Arguments go to `cargo test` (e.g. a test name filter).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/deps.sh
source scripts/env.sh
status=0
# The Python wheel builds beside the Rust tests, at the lowest priority: cargo holds the
# target directory's lock only while it compiles, and the tests leave a core idle for part
# of their run (processes they wait on, Xvfb, Slurm), which the wheel's compile takes.
# In a process group of its own, so that an interrupted run stops it with its compilers.
PY_WORK=$(mktemp -d "${TMPDIR:-/tmp}/pinrt-python.XXXXXX")
setsid nice -n 19 bash scripts/python-test.sh --build-only "$PY_WORK" > "$PY_WORK/build.log" 2>&1 &
wheel=$!
trap 'kill -- -"$wheel" 2>/dev/null || true; rm -rf "$PY_WORK"' EXIT
cargo test "${PROFILE_FLAGS[@]}" --no-fail-fast "$@" || status=$?
echo "== python package"
if wait "$wheel"; then
  cat "$PY_WORK/build.log"
  bash scripts/python-test.sh --from "$PY_WORK" || status=$?
else
  cat "$PY_WORK/build.log"
  echo "the Python wheel did not build (above)" >&2
  status=1
fi
exit "$status"
