#!/usr/bin/env bash
# The main job on bundled data: install what is missing, build, bake the OpenVDB smoke into
# a pin grid, verify and inspect it, and render it with pins (PinMS) and with a tracker.
# Outputs land in ./out/.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/deps.sh
source scripts/env.sh
DATA=data
mkdir -p out
# Everything scripts/test.sh runs, built once (scripts/env.sh says why in one invocation).
cargo build "${PROFILE_FLAGS[@]}" "${BUILD_TARGETS[@]}"
BIN="$BIN_DIR/pinbake"
# Pins chosen from the volume (octahedral:16 directions, up to 20^3 cells) with a 64^3 f16 copy
# of the density, box-filtered (a named --embed-density leaves the default asset rule out).
$BIN bake "$DATA/openvdb_smoke1.vdb" -o out/smoke.pin \
  --density-scale 4 --embed-density 64 --json > out/smoke.bake.json
$BIN verify out/smoke.pin
$BIN inspect out/smoke.pin
# The default asset (no grid flags): the smallest file predicted within 1% block error of
# the volume, no larger than the input plus 64 KiB (choice.asset in the JSON says what).
$BIN bake "$DATA/hydrogen_atom_128x128x128_uint8.raw" --density-scale 0.05 -o out/hydrogen.pin \
  --json > out/hydrogen.bake.json
$BIN inspect out/hydrogen.pin --json > out/hydrogen.inspect.json
R="$BIN_DIR/pinrender"
for est in pins pinms ratio; do
  pins=()
  case $est in pins | pinms) pins=(--pins out/smoke.pin) ;; esac
  $R render --volume "$DATA/openvdb_smoke1.vdb" "${pins[@]}" --density-scale 4 \
    --estimator $est --width 256 --height 256 --spp 32 --seed 1 --out out/smoke_$est.exr
done
# The same smoke from its .pin alone: its majorant and embedded density sections, no --volume.
for est in pins pinms; do
  $R render --pins out/smoke.pin --estimator $est --width 256 --height 256 --spp 32 --seed 1 \
    --out out/smoke_${est}_pin_alone.exr
done
# The error-against-run-time report on sub-second budgets with the estimators a user picks,
# about 30 s of CPU on 2 cores (the full one with the lab's estimators: `pinrender eval`).
$R eval --quick --out out/eval
# Error against the bytes of the file a user ships: pins alone, the embedded f16 density (dense,
# sparse), density + pins with PinMS and NanoVDB's sizes on the smoke at 32 px, about 15 s (the
# full one: `pinrender eval --bytes`, docs/evaluation.md).
$R eval --bytes --quick --out out/eval
cat <<EOT
main job done. Read first: out/eval/summary.md (what the report shows, tables, errors.png).
  pin files:   out/smoke.pin, out/hydrogen.pin (pinbake inspect FILE describes them)
  renders:     out/smoke_pins.png, out/smoke_pinms.png, out/smoke_ratio.png (and .exr);
               out/smoke_pins_pin_alone.png, out/smoke_pinms_pin_alone.png (from the .pin alone)
  raw figures: out/eval/errors.csv
  error against bytes: out/eval/bytes.md (tables), out/eval/bytes.png, out/eval/bytes.csv
EOT
