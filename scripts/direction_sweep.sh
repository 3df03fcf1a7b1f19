#!/usr/bin/env bash
# Pins-only renders of one volume from four view directions (+z, -z, +x, diagonal)
# against a ratio-tracking reference, for several direction sets at equal bytes and for the
# lookup jitter and lookup chaining. Prints one CSV row per (bake, lookup options, view):
#   volume,config,bytes,spatial_jitter,directional_jitter,view,mean_error,block8_rms_error
# (the chain stride and lookup point are in the config name: `-cS` a stride of S intervals,
# `-mid` lookups at the middle of each piece; without them one lookup at the segment start;
# `-inside` rays that start inside the box looked up at their start without spatial jitter,
# `pinrender render --start-inside true`, docs/sampling.md section 14; without it false;
# `-nearS` the nearest-line lookup over S cells, `--nearest-line S`, section 15; without it
# 0, the lookup before it).
# Usage: direction_sweep.sh NAME WORKDIR CX,CY,CZ DISTANCE -- VOLUME-ARGS...
# (VOLUME-ARGS: what `pinbake bake` and `pinrender render --volume` both accept, e.g.
#  `FILE.raw --spacing 0.025`; the first one is the input.)
# Environment: REF_SPP (default 1024), PIN_SPP (256), SIZE (96), EQUAL_CELLS (20: the cells
# per axis of the 256-direction bakes, about the bytes of 32^3 x 64 directions), CONFIGS
# (space-separated config names to run; default all), LIGHT (render lighting options; default
# a sun and a dim sky, so that the medium stands out from the background and transmittance
# errors show).
set -euo pipefail
name=$1 work=$2 centre=$3 dist=$4
shift 5
input=$1
shift
rest=("$@")
bin=${CARGO_TARGET_DIR:-$(dirname "$0")/../target}/release
REF_SPP=${REF_SPP:-1024} PIN_SPP=${PIN_SPP:-256} SIZE=${SIZE:-96} EQUAL_CELLS=${EQUAL_CELLS:-20}
mkdir -p "$work"
IFS=, read -r cx cy cz <<<"$centre"
views=("pz:0,0,1" "mz:0,0,-1" "px:1,0,0" "diag:0.577,0.577,0.577")
cam() { # view vector -> camera origin
    IFS=, read -r vx vy vz <<<"$1"
    awk -v cx="$cx" -v cy="$cy" -v cz="$cz" -v d="$dist" -v x="$vx" -v y="$vy" -v z="$vz" \
        'BEGIN { printf "%.5f,%.5f,%.5f", cx + d * x, cy + d * y, cz + d * z }'
}
read -r -a light <<<"${LIGHT:---sun-radiance 3 --env-radiance 0.05}"
common=(--width "$SIZE" --height "$SIZE" --camera-target "$centre" --threads 2 "${light[@]}")
# A camera straight above/below along y would be degenerate; none of the views is.
for v in "${views[@]}"; do
    ref="$work/ref_${v%%:*}.exr"
    [ -f "$ref" ] || "$bin/pinrender" render --volume "$input" "${rest[@]}" "${common[@]}" \
        --camera-origin "$(cam "${v#*:}")" --estimator ratio --spp "$REF_SPP" --seed 1 \
        --out "$ref" 2>/dev/null
done
configs=(
    "polar16x4|--dirs polar:16x4|1|1"
    "polar16x4-j0|--dirs polar:16x4|0|0"
    "polar8x8|--dirs polar:8x8|1|1"
    "oct8|--dirs octahedral:8|1|1"
    "oct8-j0|--dirs octahedral:8|0|0"
    "oct8-j0.5|--dirs octahedral:8|0.5|0.5"
    "oct8-j2|--dirs octahedral:8|2|2"
    "oct8-s1d0|--dirs octahedral:8|1|0"
    "oct8-s0d1|--dirs octahedral:8|0|1"
    "oct16@${EQUAL_CELLS}|--dirs octahedral:16 --cells $EQUAL_CELLS|1|1"
    "polar32x8@${EQUAL_CELLS}|--dirs polar:32x8 --cells $EQUAL_CELLS|1|1"
    "oct16@${EQUAL_CELLS}-mid|--dirs octahedral:16 --cells $EQUAL_CELLS|1|1|32|middle"
    "oct16@${EQUAL_CELLS}-c16|--dirs octahedral:16 --cells $EQUAL_CELLS|1|1|16|start"
    "oct16@${EQUAL_CELLS}-c8|--dirs octahedral:16 --cells $EQUAL_CELLS|1|1|8|start"
    "oct16@${EQUAL_CELLS}-c8mid|--dirs octahedral:16 --cells $EQUAL_CELLS|1|1|8|middle"
    "oct16@${EQUAL_CELLS}-c4|--dirs octahedral:16 --cells $EQUAL_CELLS|1|1|4|start"
    "oct16@${EQUAL_CELLS}-c2|--dirs octahedral:16 --cells $EQUAL_CELLS|1|1|2|start"
    "oct16@${EQUAL_CELLS}-c16mid|--dirs octahedral:16 --cells $EQUAL_CELLS|1|1|16|middle"
    "oct16@${EQUAL_CELLS}-c4mid|--dirs octahedral:16 --cells $EQUAL_CELLS|1|1|4|middle"
    "oct16@${EQUAL_CELLS}-mid-j0.5|--dirs octahedral:16 --cells $EQUAL_CELLS|0.5|0.5|32|middle"
    "oct16@${EQUAL_CELLS}-c8-j0|--dirs octahedral:16 --cells $EQUAL_CELLS|0|0|8|start"
    "oct16@${EQUAL_CELLS}-c4-j0.5|--dirs octahedral:16 --cells $EQUAL_CELLS|0.5|0.5|4|start"
    # What `pinbake bake` chooses by itself (docs/evaluation.md, "Bias against bytes").
    "chosen||1|1|32|start"
    "chosen-mid||1|1|32|middle"
    # Pins through cell and direction-cell centres (docs/sampling.md section 13).
    "chosen-centre-mid|--center-pins|1|1|32|middle"
    "chosen-centre-mid-j0.5|--center-pins|0.5|0.5|32|middle"
    "chosen-centre-mid-j0|--center-pins|0|0|32|middle"
    # Rays from inside the box at their start (docs/sampling.md section 14; the default).
    "chosen-centre-mid-inside|--center-pins|1|1|32|middle|true"
    "chosen-centre-mid-inside-j0.5|--center-pins|0.5|0.5|32|middle|true"
    # The nearest-line lookup (docs/sampling.md section 15; the default, S = 8).
    "chosen-centre-mid-inside-near8|--center-pins|1|1|32|middle|true|8"
)
for c in "${configs[@]}"; do
    IFS='|' read -r cname bake sj dj stride point inside nearest <<<"$c"
    if [ -n "${CONFIGS:-}" ] && [[ " $CONFIGS " != *" $cname "* ]]; then
        continue
    fi
    pin="$work/$(echo "$bake" | tr -c 'a-z0-9' _).pin"
    # shellcheck disable=SC2086
    [ -f "$pin" ] || "$bin/pinbake" bake "$input" "${rest[@]}" $bake -q -o "$pin" >/dev/null
    bytes=$(stat -c %s "$pin")
    for v in "${views[@]}"; do
        line=$("$bin/pinrender" render --volume "$input" "${rest[@]}" "${common[@]}" \
            --camera-origin "$(cam "${v#*:}")" --estimator pins --pins "$pin" --spp "$PIN_SPP" \
            --seed 2 --spatial-jitter "$sj" --directional-jitter "$dj" \
            --chain-stride "${stride:-32}" --lookup-point "${point:-start}" \
            --start-inside "${inside:-false}" --nearest-line "${nearest:-0}" \
            --reference "$work/ref_${v%%:*}.exr" --out "$work/pins.exr" 2>/dev/null)
        read -r _ mean _ block _ <<<"$line"
        echo "$name,$cname,$bytes,$sj,$dj,${v%%:*},$mean,$block"
    done
done
