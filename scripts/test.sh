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
cargo test "${PROFILE_FLAGS[@]}" --no-fail-fast "$@" || status=$?
echo "== python package"
bash scripts/python-test.sh || status=$?
exit "$status"
