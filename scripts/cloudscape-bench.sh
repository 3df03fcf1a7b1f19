#!/bin/bash
# The cloudscape benchmark (docs/scene.md, "Cloudscapes measured"): production clouds
# scattered as many overlapping, turned and stretched instances, rendered by every
# estimator that takes a scene.
#
#   1. Clouds from the production generator (scripts/production/generate.sh custom) at the
#      sizes of $SIZES, each baked once with pinbake (pins with the residual control, so that
#      every bake-reading estimator can render it).
#   2. Scenes of 1, 16, 256 and 4,096 instances (scripts/cloudscape_scene.py, seed 1).
#   3. (a) Render time against instance count at $SPP spp per estimator on the CPU, and for
#      `pins` at $GPU_SPP spp on the GPU path (on this machine wgpu runs on lavapipe: CPU, not
#      GPU speed).
#      (b) On the 256-instance scene, RMSE against run time ($BUDGETS seconds) per estimator
#      against a converged reference (ratio tracking at $REF_SPP spp). (c) From (b): the time
#      each estimator needs to reach the RMSE ratio tracking reaches in $TARGET_BUDGET s.
#
# Everything is written under "$CARGO_TARGET_DIR/cloudscape" (default target/cloudscape) and
# kept between runs (a file that exists is reused; delete it to regenerate): times.csv,
# errors.csv, time_to_rmse.csv and summary.md, the tables printed at the end.
#
# Usage: scripts/cloudscape-bench.sh
# Environment (defaults in brackets): SIZES ["62x42x77 124x84x153"], COUNTS ["1 16 256 4096"],
# ESTIMATORS ["ratio residual delta pins pinms pinres"], WIDTH [128], HEIGHT [72], SPP [64],
# GPU_SPP [4],
# BUDGETS ["0.5 1 2 5 10"], TARGET_BUDGET [2], REF_SPP [16384], THREADS [all cores],
# GPU [1: also the GPU path's pins]. Needs the release binaries:
#   cargo build --release -p pinlab --bin pinrender -p pinbake --bin pinbake
# and the generator's build dependencies (scripts/production/generate.sh says which).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/.." && pwd)
target="${CARGO_TARGET_DIR:-$root/target}"
out="$target/cloudscape"
pinrender="$target/release/pinrender"
pinbake="$target/release/pinbake"
for b in "$pinrender" "$pinbake"; do
  [ -x "$b" ] || { echo "cloudscape-bench.sh: $b missing: cargo build --release -p pinlab --bin pinrender -p pinbake --bin pinbake" >&2; exit 1; }
done
SIZES=${SIZES:-"62x42x77 124x84x153"}
COUNTS=${COUNTS:-"1 16 256 4096"}
ESTIMATORS=${ESTIMATORS:-"ratio residual delta pins pinms pinres"}
WIDTH=${WIDTH:-128}
HEIGHT=${HEIGHT:-72}
SPP=${SPP:-64}
GPU_SPP=${GPU_SPP:-4}
BUDGETS=${BUDGETS:-"0.5 1 2 5 10"}
TARGET_BUDGET=${TARGET_BUDGET:-2}
REF_SPP=${REF_SPP:-16384}
GPU=${GPU:-1}
threads=()
[ -n "${THREADS:-}" ] && threads=(--threads "$THREADS")
mkdir -p "$out"

# 1. Clouds and their bakes.
assets=()
for size in $SIZES; do
  IFS=x read -r nx ny nz <<<"$size"
  name="cs$nx"
  vdb=$(CARGO_TARGET_DIR="$target" "$here/production/generate.sh" custom "$name" "$nx" "$ny" "$nz")
  pin="$out/$name.pin"
  if [ ! -s "$pin" ]; then
    "$pinbake" bake "$vdb" -o "$pin" --embed-control --quiet "${threads[@]}"
  fi
  assets+=("$name=$vdb,$pin")
done

# 2. Scenes.
for n in $COUNTS; do
  [ -s "$out/sky$n.json" ] || python3 "$here/cloudscape_scene.py" "$out/sky$n.json" "$n" 1 "${assets[@]}"
done

view=(--width "$WIDTH" --height "$HEIGHT" "${threads[@]}")
# seconds_of LOG: the render time of a `pinrender render` summary line on stderr.
seconds_of() { sed -n 's/.* spp in \([0-9.]*\) s -> .*/\1/p' "$1" | tail -n 1; }

# 3a. Render time against instance count.
times="$out/times.csv"
echo "instances,estimator,backend,spp,seconds" >"$times"
for n in $COUNTS; do
  runs=()
  for e in $ESTIMATORS; do runs+=("$e:cpu"); done
  [ "$GPU" = 1 ] && runs+=("pins:gpu")
  for r in "${runs[@]}"; do
    e=${r%:*} backend=${r#*:} spp=$SPP label=cpu
    [ "$backend" = gpu ] && spp=$GPU_SPP label="gpu on lavapipe (CPU; not GPU speed)"
    log="$out/time-$n-$e-$backend.log"
    "$pinrender" render --scene "$out/sky$n.json" --estimator "$e" --backend "$backend" \
      "${view[@]}" --spp "$spp" --out "$out/time-$n-$e-$backend.png" 2>"$log"
    echo "$n,$e,$label,$spp,$(seconds_of "$log")" >>"$times"
  done
done

# 3b. The converged reference and RMSE against run time on 256 instances.
ref="$out/ref256-$REF_SPP.exr"
if [ ! -s "$ref" ]; then
  "$pinrender" render --scene "$out/sky256.json" --estimator ratio "${view[@]}" \
    --spp "$REF_SPP" --seed 99 --out "$ref" 2>"$out/ref256.log"
fi
errors="$out/errors.csv"
echo "estimator,budget_s,seconds,spp,rmse" >"$errors"
for e in $ESTIMATORS; do
  for b in $BUDGETS; do
    line=$("$pinrender" render --scene "$out/sky256.json" --estimator "$e" "${view[@]}" \
      --seconds "$b" --reference "$ref" --out "$out/err-$e-$b.exr" 2>/dev/null)
    # mean_error M block8_rms_error B spp N seconds S rmse R
    read -r _ _ _ _ _ spp _ secs _ rmse <<<"$line"
    echo "$e,$b,$secs,$spp,$rmse" >>"$errors"
  done
done

# 3c and the tables.
python3 "$here/cloudscape_report.py" "$out" "$TARGET_BUDGET" "$REF_SPP"
cat "$out/summary.md"
