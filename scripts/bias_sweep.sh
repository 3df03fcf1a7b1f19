#!/usr/bin/env bash
# The pin model's bias against the pin file's bytes on the eval scenes.
# For each scene: a ratio-tracking reference, then pins-only renders (every ray) of bakes that
# vary the spatial cells, the direction set (kind and count), the pins per entry and the
# lookup jitter. Bias is what `pinrender render --reference` prints: the mean relative error
# and the RMS of the 8x8-pixel block means' relative errors.
#
# Writes WORKDIR/bias.csv with the header
#   scene,config,cells,dirs,directions,pins_per_entry,jitter,bytes,density_f16_bytes,
#   ratio,mean_error,block8_rms_error,variation,model_variation
# (ratio = bytes / density_f16_bytes; density_f16_bytes = the scene's voxels x 2, or 64^3 x 2
# for the analytic scenes, which have no voxels; variation = the volume statistic g that
# `pinbake bake --json` reports as choice.volume.variation; model_variation = its
# choice.volume.model_variation, the input of the bias model in pinbake/src/choose.rs;
# config `noise-floor` is ratio tracking at the pins' spp, an unbiased
# estimator's error against the same reference) and, with PLOT=1 (default), the plot
# WORKDIR/bias.png via `pinrender plot-bias`.
#
# Usage: bias_sweep.sh WORKDIR [SCENE...]   (scenes: smoke hydrogen cosine box, the default,
# and torus water blob sphere, volumes outside the eval: torus from scripts/torus_volume.py;
# water is data/water_esp_31x34x33_float32.raw with its negative values set to 0; blob is the
# two-Gaussian grid of docs/evaluation.md; the three are read from VOLDIR, default WORKDIR;
# production, the OpenVDB cloud of `scripts/production/generate.sh half`, read from
# PRODUCTION_VDB, default target/production/cloud-half.vdb)
# Environment: SIZE (64), REF_SPP (2048), PIN_SPP (256), THREADS (2), CONFIGS (space-separated
# config names; default all), PLOT (1).
#
# The CLI cannot build the eval's `instances` scene (64 placed copies of a generated blob), and
# the eval's box is [0,1]x[0,0.7]x[0,0.85]; here `box` is the unit cube at the same extinction.
# Cameras look at the box centre from the eval scene's direction and distance (40 degree fov),
# with the eval's sun direction, albedo 0.95 and 8 bounces.
set -euo pipefail
work=$1
shift
scenes=("$@")
[ ${#scenes[@]} -gt 0 ] || scenes=(smoke hydrogen cosine box)
here=$(cd "$(dirname "$0")" && pwd)
data="$here/../data"
bin=${BIN:-${CARGO_TARGET_DIR:-$here/../target}/release}
voldir=${VOLDIR:-$work}
production=${PRODUCTION_VDB:-$bin/../production/cloud-half.vdb}
SIZE=${SIZE:-64} REF_SPP=${REF_SPP:-2048} PIN_SPP=${PIN_SPP:-256} THREADS=${THREADS:-2}
mkdir -p "$work"
csv="$work/bias.csv"
[ -f "$csv" ] || echo "scene,config,cells,dirs,directions,pins_per_entry,jitter,bytes,density_f16_bytes,ratio,mean_error,block8_rms_error,variation,model_variation" >"$csv"

# name|volume args|box min|box max|camera direction|fill|density voxels (for the f16 bytes)
scene_def() {
    case $1 in
    smoke) echo "$data/openvdb_smoke1.vdb --density-scale 2|-34.048,-12.619,-26.429|19.286,93.571,27.381|0.4,0.15,1|0.95|112x224x113" ;;
    hydrogen) echo "$data/hydrogen_atom_128x128x128_uint8.raw --spacing 0.0078125 --density-scale 0.6|0,0,0|1,1,1|0.5,0.35,1|0.8|128x128x128" ;;
    cosine) echo "procedural:cosine:seed=7,freq=16,waves=8,density=4|0,0,0|1,1,1|0.6,0.45,1|0.8|64x64x64" ;;
    box) echo "procedural:box:density=4|0,0,0|1,1,1|0.55,0.5,1|0.8|64x64x64" ;;
    # Volumes outside the eval (docs/evaluation.md, "Direction sets and lookup jitter"), for
    # the bias model's fit and its held-out check; torus, water and blob are read from VOLDIR.
    torus) echo "$voldir/torus_48x40x44_float32.raw --spacing 0.025|0,0,0|1.2,1,1.1|0.5,0.35,1|0.8|48x40x44" ;;
    water) echo "$voldir/water_31x34x33_float32.raw --spacing 0.03125|0,0,0|0.96875,1.0625,1.03125|0.5,0.35,1|0.8|31x34x33" ;;
    blob) echo "$voldir/blob_40x44x36_float32.raw --spacing 0.025|0,0,0|1,1.1,0.9|0.5,0.35,1|0.8|40x44x36" ;;
    sphere) echo "$data/gaffer_sphere_density.vdb --density-scale 20|-1.2,1,-1.2|1.2,3,1.2|0.5,0.35,1|0.8|12x10x12" ;;
    # The production-scale OpenVDB cloud of scripts/production/generate.sh half (voxel
    # 10/1225, active index box 43..953 x 34..637 x 46..1155), as the eval's production scene.
    production) echo "$production --density-scale 0.5|0.34694,0.27347,0.37143|7.78367,5.20408,9.43265|0.5,0.3,1|0.8|911x604x1110" ;;
    *) echo "unknown scene $1" >&2; exit 2 ;;
    esac
}

# config name|bake flags|jitter (spatial = directional, in cells)|other render flags
configs=()
for c in 8 12 16 24; do
    for n in 4 8 16; do
        configs+=("c${c}-oct${n}|--cells $c --dirs octahedral:$n|1")
    done
done
configs+=(
    "c32-oct8|--cells 32 --dirs octahedral:8|1"
    "c16-polar16x4|--cells 16 --dirs polar:16x4|1"
    "c12-oct8-k4|--cells 12 --dirs octahedral:8 --pins-per-entry 4|1"
    "c16-oct8-j0|--cells 16 --dirs octahedral:8|0"
    "c16-oct8-j0.5|--cells 16 --dirs octahedral:8|0.5"
    "c16-oct8-j2|--cells 16 --dirs octahedral:8|2"
    # What `pinbake bake` chooses by itself (cells and directions from the volume): the
    # default target and a tighter one, to check the model's prediction against a render.
    "default||1"
    # The default bake with the thesis' jittered pins (the default before docs/sampling.md
    # section 13).
    "default-jittered|--jitter-pins|1"
    # The default bake with rays from inside the box looked up like the others (the render
    # default before docs/sampling.md section 14).
    "default-noinside||1|--start-inside false"
    "target0.03|--target-error 0.03|1"
)

for s in "${scenes[@]}"; do
    IFS='|' read -r vol lo hi dir fill vox <<<"$(scene_def "$s")"
    read -r -a volargs <<<"$vol"
    # The eval's frame_camera: distance = half the box diagonal / tan(fov/2) x fill.
    read -r origin target <<<"$(awk -v lo="$lo" -v hi="$hi" -v d="$dir" -v f="$fill" 'BEGIN {
        split(lo, a, ","); split(hi, b, ","); split(d, v, ",");
        r = 0; n = 0;
        for (i = 1; i <= 3; i++) { c[i] = (a[i] + b[i]) / 2; r += (b[i] - a[i])^2; n += v[i]^2 }
        dist = sqrt(r) / 2 / (sin(0.349066) / cos(0.349066)) * f;
        printf "%.5f,%.5f,%.5f %.5f,%.5f,%.5f\n", c[1] + v[1] / sqrt(n) * dist,
            c[2] + v[2] / sqrt(n) * dist, c[3] + v[3] / sqrt(n) * dist, c[1], c[2], c[3] }')"
    dens_bytes=$(awk -v v="$vox" 'BEGIN { split(v, a, "x"); print a[1] * a[2] * a[3] * 2 }')
    common=(--width "$SIZE" --height "$SIZE" --camera-origin="$origin" --camera-target="$target"
        --fov 40 --sun-dir=-0.5,0.8,0.35 --sun-radiance 3 --env-radiance 0.3 --albedo 0.95
        --max-bounces 8 --threads "$THREADS")
    probe=$("$bin/pinbake" bake "${volargs[@]}" --cells 1 --dirs octahedral:1 --majorant 0 \
        -q --json -o "$work/probe.pin")
    variation=$(grep -o '"variation":[0-9.e+-]*' <<<"$probe" | cut -d: -f2)
    mvar=$(grep -o '"model_variation":[0-9.e+-]*' <<<"$probe" | cut -d: -f2)
    rm -f "$work/probe.pin"
    ref="$work/$s.ref.exr"
    if [ ! -f "$ref" ]; then
        echo "== $s: reference ($REF_SPP spp)" >&2
        "$bin/pinrender" render --volume "${volargs[@]}" "${common[@]}" --estimator ratio \
            --spp "$REF_SPP" --seed 1 --out "$work/$s.tmp.exr" >/dev/null
        mv "$work/$s.tmp.exr" "$ref"
        rm -f "$work/$s.tmp.png" # render's tone-mapped preview
    fi
    # The noise floor: an unbiased estimator (ratio tracking) at the pins' spp.
    if ! grep -q "^$s,noise-floor," "$csv"; then
        line=$("$bin/pinrender" render --volume "${volargs[@]}" "${common[@]}" --estimator ratio \
            --spp "$PIN_SPP" --seed 2 --reference "$ref" --out "$work/pins.exr" 2>/dev/null)
        read -r _ mean _ block _ <<<"$line"
        echo "$s,noise-floor,,,,,,0,$dens_bytes,0,$mean,$block,$variation,$mvar" | tee -a "$csv"
    fi
    for c in "${configs[@]}"; do
        IFS='|' read -r cname bake jit extra <<<"$c"
        if [ -n "${CONFIGS:-}" ] && [[ " $CONFIGS " != *" $cname "* ]]; then
            continue
        fi
        if grep -q "^$s,$cname," "$csv"; then
            continue
        fi
        read -r -a bakeargs <<<"$bake"
        read -r -a extraargs <<<"${extra:-}"
        pin="$work/$s.$(echo "$bake" | tr -c 'a-z0-9' _).pin"
        [ -f "$pin" ] || "$bin/pinbake" bake "${volargs[@]}" "${bakeargs[@]}" --threads "$THREADS" \
            -q -o "$pin" >/dev/null
        bytes=$(stat -c %s "$pin")
        line=$("$bin/pinrender" render --volume "${volargs[@]}" "${common[@]}" --estimator pins \
            --pins "$pin" --spp "$PIN_SPP" --seed 2 --spatial-jitter "$jit" \
            --directional-jitter "$jit" "${extraargs[@]}" --reference "$ref" \
            --out "$work/pins.exr" 2>/dev/null)
        read -r _ mean _ block _ <<<"$line"
        cells=$(awk '{ for (i = 1; i <= NF; i++) if ($i == "--cells") print $(i + 1) }' <<<"$bake")
        dirs=$(awk '{ for (i = 1; i <= NF; i++) if ($i == "--dirs") print $(i + 1) }' <<<"$bake")
        if [ -z "$cells" ]; then # chosen by pinbake: read them back from the file
            info=$("$bin/pinbake" inspect "$pin" --json)
            cells=$(grep -o '"dims":\[[0-9,]*\]' <<<"$info" | grep -o '[0-9,]*' | tr , x)
            dirs=octahedral:$(grep -o '"directions":{"kind":"octahedral","n":[0-9]*' <<<"$info" | grep -o '[0-9]*$')
        fi
        ppe=$(awk '{ k = 1; for (i = 1; i <= NF; i++) if ($i == "--pins-per-entry") k = $(i + 1); print k }' <<<"$bake")
        ndirs=$(awk -v d="$dirs" 'BEGIN { split(d, a, ":"); split(a[2], b, "x");
            print (a[1] == "polar") ? b[1] * b[2] : b[1] * b[1] }')
        ratio=$(awk -v a="$bytes" -v b="$dens_bytes" 'BEGIN { printf "%.4f", a / b }')
        echo "$s,$cname,$cells,$dirs,$ndirs,$ppe,$jit,$bytes,$dens_bytes,$ratio,$mean,$block,$variation,$mvar" | tee -a "$csv"
        rm -f "$work/pins.exr" "$work/pins.png"
    done
done
if [ "${PLOT:-1}" = 1 ]; then
    "$bin/pinrender" plot-bias "$csv" --out "$work/bias.png"
fi
