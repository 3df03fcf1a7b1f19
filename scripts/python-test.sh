#!/usr/bin/env bash
# The Python package (python/): builds the abi3 wheel, installs it into a fresh virtual
# environment and runs its pytest suite against the Rust tools (pinbake for bakes, pinrt's
# query_reference example for sampler values). Needs python3 with venv and PyPI access for
# maturin, numpy and pytest. Run from anywhere.
#
#   python-test.sh [--prebuilt] [PYTEST ARGS]          build, install and test in a temporary directory
#   python-test.sh [--prebuilt] --build-only DIR       the venv and the wheel into DIR, then stop
#   python-test.sh --from DIR [ARGS]                   install and test what --build-only left in DIR
#                                                      (waiting for it first where it still runs)
#
# The wheel comes from maturin, as a user or a release builds it; with --prebuilt it is packed
# (scripts/python-wheel.py) around the extension that the workspace's build has compiled
# already (scripts/main-job.sh, scripts/test.sh), which saves compiling the extension's
# dependency tree a second time with other features. scripts/test.sh runs
# --prebuilt --build-only beside the Rust tests and --from after them.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/env.sh
REPO=$PWD

MODE=all
WORK=""
PREBUILT=0
if [ "${1:-}" = --prebuilt ]; then
  PREBUILT=1
  shift
fi
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

if [ "$MODE" = build ]; then
  # What --from waits for: this run's process while it builds, then its exit status.
  rm -f "$WORK/build.status"
  echo $$ > "$WORK/build.pid"
  trap 'echo $? > "$WORK/build.status"' EXIT
elif [ "$MODE" = test ] && [ -e "$WORK/build.pid" ]; then
  while [ ! -e "$WORK/build.status" ] && kill -0 "$(cat "$WORK/build.pid")" 2>/dev/null; do
    sleep 0.2
  done
  # The build's log, where the caller kept it there (scripts/test.sh).
  [ -f "$WORK/build.log" ] && cat "$WORK/build.log"
  if [ "$(cat "$WORK/build.status" 2>/dev/null)" != 0 ]; then
    echo "python-test.sh: the venv or the wheel in $WORK was not made (--build-only failed)" >&2
    exit 1
  fi
fi

if [ "$MODE" != test ]; then
  python3 -m venv "$WORK/venv"
  if [ "$PREBUILT" = 1 ]; then
    "$PY" -m pip install -q --disable-pip-version-check numpy pytest
    python3 scripts/python-wheel.py "$BIN_DIR/lib_native.so" "$WORK/wheels" >/dev/null
  else
    cargo build "${PROFILE_FLAGS[@]}" --bin pinbake --example query_reference
    "$PY" -m pip install -q --disable-pip-version-check maturin numpy pytest
    # In the workspace's target directory: what the extension shares with the workspace's
    # build at the same features is not compiled twice.
    CARGO_TARGET_DIR="$TARGET_DIR" "$WORK/venv/bin/maturin" build --release \
      -m python/Cargo.toml -o "$WORK/wheels"
  fi
fi
[ "$MODE" = build ] && exit 0

"$PY" -m pip install -q --disable-pip-version-check "$WORK"/wheels/pinrt-*.whl
# From outside the checkout, so that `import pinrt` can only find the installed wheel.
cd "$WORK"
PINBAKE_EXE="$BIN_DIR/pinbake" PINRT_REFERENCE_EXE="$BIN_DIR/examples/query_reference" \
  "$PY" -m pytest -q -p no:cacheprovider "$REPO/python/tests" "$@"
