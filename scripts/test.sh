#!/usr/bin/env bash
# The test command from the README: every crate, every feature, in the release profile that
# the main job builds too (the dependency tree is compiled once), then the Python package's
# tests (scripts/python-test.sh: a wheel around the extension the build compiled, a fresh
# venv, pytest). Fixtures come from data/.
#
# The test binaries run two at a time, the longest first (scripts/run-tests.py): each has
# idle stretches (a test waiting on a child process, one test left on one core) that the
# other fills. The doc tests and the Python package's tests run last in those lanes, in the
# one that ends first. Arguments go to `cargo test` instead (e.g. a test name filter), which
# then runs the binaries one after another as usual, and the Python tests after it.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/deps.sh
source scripts/env.sh
status=0
MESSAGES=$(mktemp "${TMPDIR:-/tmp}/pinrt-build.XXXXXX")
PY_WORK=$(mktemp -d "${TMPDIR:-/tmp}/pinrt-python.XXXXXX")
venv=""
trap 'if [ -n "$venv" ]; then kill -- -"$venv" 2>/dev/null || true; fi; rm -rf "$PY_WORK" "$MESSAGES"' EXIT
cargo build "${PROFILE_FLAGS[@]}" "${BUILD_TARGETS[@]}" \
  --message-format=json-render-diagnostics > "$MESSAGES"
# The Python package's venv and wheel (pip's downloads, the packing) beside the Rust tests,
# in a process group of its own so that an interrupted run stops it; its log is printed with
# the Python tests, which wait for it (python-test.sh --from).
setsid bash scripts/python-test.sh --prebuilt --build-only "$PY_WORK" > "$PY_WORK/build.log" 2>&1 &
venv=$!
# Written here too, before the build's own line, so that the Python job can never start
# before it and skip the wait (python-test.sh --from waits while this process runs).
echo "$venv" > "$PY_WORK/build.pid"
PYTHON_TESTS="bash scripts/python-test.sh --from '$PY_WORK'"
if [ $# -eq 0 ]; then
  python3 scripts/run-tests.py --job "doc tests" "cargo test ${PROFILE_FLAGS[*]} --doc" \
    --job "python package" "$PYTHON_TESTS" < "$MESSAGES" || status=$?
else
  cargo test "${PROFILE_FLAGS[@]}" --no-fail-fast "$@" || status=$?
  echo "== python package"
  bash -c "$PYTHON_TESTS" || status=$?
fi
exit "$status"
