# Sourced by the scripts: one build profile for the main job and the tests, the real target
# directory, and a valid XDG runtime dir so Mesa's Vulkan loader does not warn on every start.
# shellcheck shell=bash
PROFILE_FLAGS=(--release --workspace --all-features)
# What the main job builds and the tests run: every library (the Python extension's among
# them), binary and test harness, and the one example a test runs (the Python tests' query
# reference; the others are benchmarks run by hand). With tests among the targets, cargo
# resolves the dependencies' features with the dev-dependencies, as `cargo test` does, so
# `cargo test` afterwards compiles only those other examples (a plain `cargo build` would
# resolve other features and compile some two dozen crates, wgpu among them, a second time).
BUILD_TARGETS=(--lib --tests --example query_reference)
TARGET_DIR=$(cargo metadata --format-version 1 --no-deps 2>/dev/null |
  python3 -c 'import json,sys; print(json.load(sys.stdin)["target_directory"])' 2>/dev/null ||
  echo "${CARGO_TARGET_DIR:-target}")
BIN_DIR="$TARGET_DIR/release"
if [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "$XDG_RUNTIME_DIR" ] || [ ! -w "$XDG_RUNTIME_DIR" ]; then
  XDG_RUNTIME_DIR=$(mktemp -d "${TMPDIR:-/tmp}/pinbake-xdg.XXXXXX")
  chmod 700 "$XDG_RUNTIME_DIR"
  export XDG_RUNTIME_DIR
fi
# The sample volumes bundled with the repository (pinrender finds them itself; explicit here).
export PINBAKE_DATA="${PINBAKE_DATA:-$PWD/data}"
