# Sourced by the scripts: one build profile for the main job and the tests, the real target
# directory, and a valid XDG runtime dir so Mesa's Vulkan loader does not warn on every start.
# shellcheck shell=bash
PROFILE_FLAGS=(--release --workspace --all-features)
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
