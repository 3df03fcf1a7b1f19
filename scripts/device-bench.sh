#!/usr/bin/env bash
# GPU figures for a machine with a hardware adapter and no network.
#
#   bash scripts/device-bench.sh --pack DIR     # on the build machine: stripped release
#                                               # binaries and this script into DIR (< 64 MiB)
#   bash DIR/device-bench.sh [OUT]              # on the GPU machine, from DIR: under 8 minutes
#
# Measures milliseconds per pass at 1920x1080 and 1 spp for pins, pinms, pinres, ratio and
# residual on a 512^3 fractal cloud (a procedural fractal baked with a dense 512^3 embedded
# density and a control section) and on an instances scene (the cosine field baked with
# --embed-density 128, as four placements are not a CLI input: one instance), through
# `pinrender render --backend gpu` (each figure: (t(17 spp) - t(1 spp)) / 16, so upload and
# pipeline compile cancel), plus the viewer headless at 1080p (`pinview --frames`, under Xvfb
# when no display is set). Writes OUT/device-bench.json and OUT/device-bench.md.
set -euo pipefail

if [ "${1:-}" = "--pack" ]; then
  dir=${2:?usage: device-bench.sh --pack DIR}
  cd "$(dirname "$0")/.."
  cargo build --release -p pinbake -p pinrender -p pinview --all-features --bins
  mkdir -p "$dir"
  for b in pinbake pinrender pinview; do
    cp "target/release/$b" "$dir/$b"
    strip "$dir/$b"
  done
  cp scripts/device-bench.sh "$dir/"
  du -ch "$dir"/* | tail -1
  total=$(du -cb "$dir"/* | tail -1 | cut -f1)
  if [ "$total" -gt $((64 << 20)) ]; then
    echo "device-bench: the pack is $total bytes, over 64 MiB" >&2
    exit 1
  fi
  exit 0
fi

here=$(cd "$(dirname "$0")" && pwd)
out=${1:-$here/bench-out}
mkdir -p "$out"
B=$here
work=$(mktemp -d)
trap 'rm -rf "$work"; [ -n "${xvfb_pid:-}" ] && kill "$xvfb_pid" 2>/dev/null || true' EXIT

echo "== bakes" >&2
"$B/pinbake" bake procedural:fractal:seed=7,octaves=4 --embed-density 512 --embed-control \
  -o "$work/cloud.pin" >&2
"$B/pinbake" bake procedural:cosine:seed=5,freq=4,density=6 --embed-density 128 --embed-control \
  -o "$work/instances.pin" >&2

# Seconds of one render, from pinrender's summary line ("... in S s -> ...").
seconds() {
  "$B/pinrender" render --pins "$1" --estimator "$2" --backend gpu --width 1920 --height 1080 \
    --spp "$3" --seed 1 --out "$work/x.exr" 2>&1 >/dev/null | sed -n 's/.* in \([0-9.]*\) s -> .*/\1/p' | tail -1
}

rows=()
md="| scene | estimator | ms per pass (1920x1080, 1 spp) |\n|---|---|---|\n"
for scene in cloud instances; do
  for est in pins pinms pinres ratio residual; do
    t1=$(seconds "$work/$scene.pin" "$est" 1)
    t17=$(seconds "$work/$scene.pin" "$est" 17)
    ms=$(python3 -c "print(round(($t17 - $t1) / 16 * 1000, 3))")
    echo "$scene $est: $ms ms per pass" >&2
    rows+=("{\"scene\": \"$scene\", \"estimator\": \"$est\", \"ms_per_pass\": $ms}")
    md+="| $scene | $est | $ms |\n"
  done
done

echo "== viewer at 1080p" >&2
if [ -z "${DISPLAY:-}" ]; then
  Xvfb :77 -screen 0 2400x1300x24 -nolisten tcp >/dev/null 2>&1 &
  xvfb_pid=$!
  sleep 1
  export DISPLAY=:77
fi
view=$("$B/pinview" "$work/cloud.pin" --estimator pins --width 1920 --height 1080 --frames 32 \
  --screenshot "$work/view.png" --json)
echo "$view" >&2
adapter=$(echo "$view" | python3 -c 'import json,sys; j=json.load(sys.stdin); print(j["adapter"], "(", j["backend"], j["device_type"], ")")')
view_ms=$(echo "$view" | python3 -c 'import json,sys; print(round(json.load(sys.stdin)["ms_per_pass"], 3))')
md+="| cloud | pins, pinview --frames 32 | $view_ms |\n"

{
  echo "{\"adapter\": \"$adapter\", \"load\": \"$(cut -d' ' -f1-3 /proc/loadavg)\", \"rows\": ["
  (IFS=,; echo "${rows[*]}")
  echo "], \"pinview\": $view}"
} > "$out/device-bench.json"
printf "adapter: %s; load %s\n\n$md" "$adapter" "$(cut -d' ' -f1-3 /proc/loadavg)" > "$out/device-bench.md"
cat "$out/device-bench.md"
