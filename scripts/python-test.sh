#!/usr/bin/env bash
# The Python package (python/): builds the abi3 wheel with maturin, installs it into a fresh
# virtual environment and runs its pytest suite against the Rust tools (pinbake for bakes,
# pinrt's query_reference example for sampler values). Needs python3 with venv and PyPI
# access for maturin, numpy and pytest. Run from anywhere.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/env.sh
REPO=$PWD

cargo build "${PROFILE_FLAGS[@]}" --bin pinbake --example query_reference

WORK=$(mktemp -d "${TMPDIR:-/tmp}/pinrt-python.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
python3 -m venv "$WORK/venv"
PY="$WORK/venv/bin/python"
"$PY" -m pip install -q --disable-pip-version-check maturin numpy pytest

# The extension shares the target directory: the crates it has in common with the main build
# (same versions, features and profile) are not compiled twice.
CARGO_TARGET_DIR="$TARGET_DIR" "$WORK/venv/bin/maturin" build --release \
  -m python/Cargo.toml -o "$WORK/wheels"
"$PY" -m pip install -q --disable-pip-version-check "$WORK"/wheels/pinrt-*.whl

# From outside the checkout, so that `import pinrt` can only find the installed wheel.
cd "$WORK"
PINBAKE_EXE="$BIN_DIR/pinbake" PINRT_REFERENCE_EXE="$BIN_DIR/examples/query_reference" \
  "$PY" -m pytest -q -p no:cacheprovider "$REPO/python/tests" "$@"
