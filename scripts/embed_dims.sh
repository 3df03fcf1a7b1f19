#!/usr/bin/env bash
# The embedded density against its source, at the same seed: renders a VDB (or any volume
# `pinbake bake` reads) with ratio tracking and the file of `pinbake bake --embed-density
# COUNTS --cells 2 --dirs octahedral:1` from the file alone, each against a converged
# ratio-tracking reference of the volume (128 px, 8 bounces, the framing of
# scripts/asset_sweep.sh), and prints `pinrender render --reference`'s line for each: at the
# source's resolution the file's block error is the volume's own (its noise), not a multiple.
#
# Usage: embed_dims.sh WORKDIR VOLUME COUNTS [SPP (256)] [REF_SPP (4096)]
# Environment: BIN (target/release), THREADS (2).
set -euo pipefail
work=$1 vol=$2 counts=$3 spp=${4:-256} ref_spp=${5:-4096}
here=$(cd "$(dirname "$0")" && pwd)
bin=${BIN:-${CARGO_TARGET_DIR:-$here/../target}/release}
threads=${THREADS:-2}
mkdir -p "$work"
probe=$("$bin/pinbake" bake "$vol" --cells 1 --dirs octahedral:1 --majorant 0 -q --json -o "$work/probe.pin")
rm -f "$work/probe.pin"
read -r lo hi <<<"$(python3 -c 'import json,sys; b=json.loads(sys.argv[1])["world_box"]; print(",".join(map(str,b["min"])), ",".join(map(str,b["max"])))' "$probe")"
read -r origin target <<<"$(awk -v lo="$lo" -v hi="$hi" -v d=0.5,0.35,1 -v f=0.8 'BEGIN {
    split(lo, a, ","); split(hi, b, ","); split(d, v, ",");
    r = 0; n = 0;
    for (i = 1; i <= 3; i++) { c[i] = (a[i] + b[i]) / 2; r += (b[i] - a[i])^2; n += v[i]^2 }
    dist = sqrt(r) / 2 / (sin(0.349066) / cos(0.349066)) * f;
    printf "%.5f,%.5f,%.5f %.5f,%.5f,%.5f\n", c[1] + v[1] / sqrt(n) * dist,
        c[2] + v[2] / sqrt(n) * dist, c[3] + v[3] / sqrt(n) * dist, c[1], c[2], c[3] }')"
common=(--width 128 --height 128 --camera-origin="$origin" --camera-target="$target" --fov 40
    --sun-dir=-0.5,0.8,0.35 --sun-radiance 3 --env-radiance 0.3 --albedo 0.95 --max-bounces 8
    --threads "$threads")
ref="$work/$(basename "$vol").ref$ref_spp.exr"
if [ ! -f "$ref" ]; then
    "$bin/pinrender" render --volume "$vol" "${common[@]}" --estimator ratio --spp "$ref_spp" \
        --seed 1 --out "$work/ref.tmp.exr" >/dev/null
    mv "$work/ref.tmp.exr" "$ref"
fi
echo "volume: $("$bin/pinrender" render --volume "$vol" "${common[@]}" --estimator ratio \
    --spp "$spp" --seed 2 --reference "$ref" --out "$work/m.exr" 2>/dev/null)"
pin="$work/embed.pin"
"$bin/pinbake" bake "$vol" --embed-density "$counts" --cells 2 --dirs octahedral:1 -q -o "$pin"
echo "--embed-density $counts ($(stat -c %s "$pin") bytes): $("$bin/pinrender" render --pins "$pin" \
    "${common[@]}" --estimator ratio --spp "$spp" --seed 2 --reference "$ref" --out "$work/m.exr" 2>/dev/null)"
rm -f "$work"/m.exr "$work"/m.png
