#!/usr/bin/env bash
# The test command from the README: every crate, every feature, fixtures from ../shared/data.
set -euo pipefail
cd "$(dirname "$0")/.."
exec cargo test --workspace --all-features --no-fail-fast "$@"
