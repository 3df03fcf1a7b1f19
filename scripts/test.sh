#!/usr/bin/env bash
# The test command from the README: every crate, every feature, in the release profile that
# the main job builds too (the dependency tree is compiled once). Fixtures come from data/.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/deps.sh
source scripts/env.sh
exec cargo test "${PROFILE_FLAGS[@]}" --no-fail-fast "$@"
