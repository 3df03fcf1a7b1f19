#!/usr/bin/env bash
# The test command from the README: every crate, every feature, in the release profile that
# the main job builds too (the dependency tree is compiled once), then the Python package's
# tests (scripts/python-test.sh: a wheel around the extension the build compiled, a fresh
# venv, pytest). Fixtures come from data/.
#
# The test binaries run two at a time, the longest first (scripts/run-tests.py): each has
# idle stretches (a test waiting on a child process, one test left on one core) that the
# other fills. Arguments go to `cargo test` instead (e.g. a test name filter), which then
# runs the binaries one after another as usual.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/deps.sh
source scripts/env.sh
status=0
MESSAGES=$(mktemp "${TMPDIR:-/tmp}/pinrt-build.XXXXXX")
PY_WORK=$(mktemp -d "${TMPDIR:-/tmp}/pinrt-python.XXXXXX")
venv=""
trap '[ -n "$venv" ] && kill -- -"$venv" 2>/dev/null; rm -rf "$PY_WORK" "$PY_WORK.log" "$MESSAGES"' EXIT
cargo build "${PROFILE_FLAGS[@]}" "${BUILD_TARGETS[@]}" \
  --message-format=json-render-diagnostics > "$MESSAGES"
# The Python package's venv and wheel (pip's downloads, the packing) beside the Rust tests,
# in a process group of its own so that an interrupted run stops it.
setsid bash scripts/python-test.sh --prebuilt --build-only "$PY_WORK" > "$PY_WORK.log" 2>&1 &
venv=$!
if [ $# -eq 0 ]; then
  python3 scripts/run-tests.py < "$MESSAGES" || status=$?
  echo "== doc tests"
  cargo test "${PROFILE_FLAGS[@]}" --doc || status=$?
else
  cargo test "${PROFILE_FLAGS[@]}" --no-fail-fast "$@" || status=$?
fi
echo "== python package"
if wait "$venv"; then
  venv=""
  cat "$PY_WORK.log"
  bash scripts/python-test.sh --from "$PY_WORK" || status=$?
else
  venv=""
  cat "$PY_WORK.log"
  echo "the Python package's venv or wheel was not made (above)" >&2
  status=1
fi
rm -f "$PY_WORK.log"
exit "$status"
