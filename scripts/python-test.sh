#!/usr/bin/env bash
# The Python package (python/): builds the abi3 wheel with maturin, installs it into a fresh
# virtual environment and runs its pytest suite against the Rust tools (pinbake for bakes,
# pinrt's query_reference example for sampler values). Needs python3 with venv and PyPI
# access for maturin, numpy and pytest. Run from anywhere.
#
#   python-test.sh [PYTEST ARGS]          build, install and test in a temporary directory
#   python-test.sh --build-only DIR       the venv and the wheel into DIR, then stop
#   python-test.sh --from DIR [ARGS]      install and test what --build-only left in DIR
#
# scripts/test.sh runs --build-only beside the Rust tests and --from after them.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/env.sh
REPO=$PWD

MODE=all
WORK=""
case "${1:-}" in
  --build-only | --from)
    [ $# -ge 2 ] || { echo "python-test.sh: $1 needs a directory" >&2; exit 2; }
    [ "$1" = --build-only ] && MODE=build || MODE=test
    WORK=$(cd "$2" && pwd)
    shift 2
    ;;
esac
if [ -z "$WORK" ]; then
  WORK=$(mktemp -d "${TMPDIR:-/tmp}/pinrt-python.XXXXXX")
  trap 'rm -rf "$WORK"' EXIT
fi
PY="$WORK/venv/bin/python"

if [ "$MODE" != test ]; then
  cargo build "${PROFILE_FLAGS[@]}" --bin pinbake --example query_reference
  python3 -m venv "$WORK/venv"
  "$PY" -m pip install -q --disable-pip-version-check maturin numpy pytest
  # The extension shares the target directory: the crates it has in common with the main
  # build (same versions, features and profile) are not compiled twice.
  CARGO_TARGET_DIR="$TARGET_DIR" "$WORK/venv/bin/maturin" build --release \
    -m python/Cargo.toml -o "$WORK/wheels"
fi
[ "$MODE" = build ] && exit 0

"$PY" -m pip install -q --disable-pip-version-check "$WORK"/wheels/pinrt-*.whl
# From outside the checkout, so that `import pinrt` can only find the installed wheel.
cd "$WORK"
PINBAKE_EXE="$BIN_DIR/pinbake" PINRT_REFERENCE_EXE="$BIN_DIR/examples/query_reference" \
  "$PY" -m pytest -q -p no:cacheprovider "$REPO/python/tests" "$@"
