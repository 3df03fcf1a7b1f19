#!/usr/bin/env bash
# The main job on bundled data: install what is missing, build, bake the OpenVDB smoke into
# a pin grid, verify it and print what is inside. Outputs land in ./out/.
set -euo pipefail
cd "$(dirname "$0")/.."
export DEBIAN_FRONTEND=noninteractive
SUDO=""
if [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null; then SUDO=sudo; fi
if ! dpkg -s mesa-vulkan-drivers libvulkan1 >/dev/null 2>&1; then
  $SUDO apt-get update -qq && $SUDO apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
fi
DATA=../shared/data
mkdir -p out
cargo build --release -p pinbake
BIN=target/release/pinbake
$BIN bake "$DATA/openvdb_smoke1.vdb" -o out/smoke.pin --cells 37 --dirs polar:16x4 \
  --embed-density 64 --json > out/smoke.bake.json
$BIN verify out/smoke.pin
$BIN inspect out/smoke.pin
$BIN bake "$DATA/hydrogen_atom_128x128x128_uint8.raw" --density-scale 0.05 -o out/hydrogen.pin \
  --dirs octahedral:8 --json > out/hydrogen.bake.json
$BIN inspect out/hydrogen.pin --json > out/hydrogen.inspect.json
echo "main job done: out/smoke.pin, out/hydrogen.pin (bake summaries in out/*.json)"
