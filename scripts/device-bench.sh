#!/usr/bin/env bash
# GPU figures for a machine with a hardware adapter and no network.
#
#   bash scripts/device-bench.sh --pack DIR     # on the build machine: stripped release
#                                               # binaries, the smoke, the scene writer and
#                                               # this script into DIR (< 64 MiB)
#   bash DIR/device-bench.sh [OUT]              # on the GPU machine, from DIR: about 5 minutes
#
# Four parts, each written to OUT as soon as it is done (a part that fails is reported and the
# next one runs):
#   1. The GPU bake: `pinbake bench --default --backend cpu,gpu` on the 512^3 voxelised
#      procedural noise (the thesis' 37^3 x 16x4 and the default bake) and the smoke's default
#      bake, with the GPU's device, upload, jobs and dispatch seconds. -> bake-bench.json;
#      the smoke's default bake again with its density in 2 MB z slabs (--gpu-slab-bytes),
#      which must give the same file. -> bake-slabs.json
#   2. Milliseconds per pass at 1920x1080 and 1 spp for pins, pinms, pinres, ratio and
#      residual on a 512^3 fractal cloud (a procedural fractal baked with a dense 512^3
#      embedded density and a control section) and on the cosine field (--embed-density 128),
#      through `pinrender render --backend gpu` (each figure: (t(65 spp) - t(1 spp)) / 64, so
#      upload and pipeline compile cancel; the render line gives seconds to 10 ms, so the
#      difference spans 64 passes). -> device-bench.json, device-bench.md
#   3. Render time against instance count (1, 16, 256, 4096 smoke instances, rotated and
#      scaled: scripts/cloudscape_scene.py) on the GPU path, pins (the GPU path renders scenes
#      with pins only). -> instances.csv
#   4. The viewer at 1080p: `pinview --offscreen --frames 32` (no display needed) for pins and
#      pinms, and in a window when a display or Xvfb is at hand (about 30 s).
#      -> device-bench.md rows, device-bench.json `pinview` (pins off-screen), `pinview_runs`
#   5. The viewer headless on the bundled smoke (its default bake) at 1080p for pins, pinms
#      and ratio: the first image with an empty pipeline cache and again with the one that
#      run wrote (the wgpu pipeline cache and the driver's shader cache both in OUT's own
#      directories), ms per pass (`pinview --offscreen --frames 16`), and in a window under
#      Xvfb (or the display) the response to a scripted orbit, zoom and sun
#      (`--input-script`: first changed pixels and first full pass after each).
#      -> viewer-bench.md (also on stdout), viewer-bench.json
# --quick (or DEVICE_BENCH_QUICK=1) runs every part at toy sizes (to check the script on any
# machine; on lavapipe its figures say so); DEVICE_BENCH_PARTS="2 3" runs only those parts:
#   DEVICE_BENCH_PARTS=5 bash scripts/device-bench.sh --quick OUT   # from the repository,
#                                                                  # with target/release built
set -uo pipefail

if [ "${1:-}" = "--quick" ]; then
  export DEVICE_BENCH_QUICK=1
  shift
fi

if [ "${1:-}" = "--pack" ]; then
  set -e
  dir=${2:?usage: device-bench.sh --pack DIR}
  cd "$(dirname "$0")/.."
  cargo build --release -p pinbake -p pinlab -p pinview --all-features --bins
  mkdir -p "$dir"
  for b in pinbake pinrender pinview; do
    cp "target/release/$b" "$dir/$b"
    strip "$dir/$b"
  done
  cp scripts/device-bench.sh scripts/cloudscape_scene.py data/openvdb_smoke1.vdb "$dir/"
  # The shared libraries they load beyond the C runtime, if any: a bare GPU image may lack
  # them.
  mkdir -p "$dir/lib"
  for b in pinbake pinrender pinview; do
    ldd "$dir/$b" | awk '$3 ~ /^\// {print $3}'
  done | sort -u | grep -Ev '/(libc|libm|libgcc_s|libdl|libpthread|librt|ld-linux[^/]*)\.so' |
    xargs -r cp -L -t "$dir/lib"
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
out=$(cd "$out" && pwd)
B=$here
# Run from the repository's scripts/: the binaries of target/release and the bundled smoke.
if [ ! -x "$B/pinview" ] && [ -x "$here/../target/release/pinview" ]; then
  B=$(cd "$here/../target/release" && pwd)
  smoke_vdb=$(cd "$here/../data" && pwd)/openvdb_smoke1.vdb
fi
smoke_vdb=${smoke_vdb:-$B/openvdb_smoke1.vdb}
export LD_LIBRARY_PATH="$here/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
work=$(mktemp -d)
trap 'rm -rf "$work"; [ -n "${xvfb_pid:-}" ] && kill "$xvfb_pid" 2>/dev/null || true' EXIT
threads=$(nproc)
if [ "${DEVICE_BENCH_QUICK:-0}" = 1 ]; then
  VOXELS=64 CELLS=8 EMBED=64 W=192 H=108 COUNTS="1 16" VW=320 VH=180 QUICK=(--cells 8)
else
  VOXELS=512 CELLS=37 EMBED=512 W=1920 H=1080 COUNTS="1 16 256 4096" VW=1920 VH=1080 QUICK=()
fi
# A part that fails leaves its line in the log and the next part runs.
failed=()
parts=" ${DEVICE_BENCH_PARTS:-1 2 3 4 5} "
wanted() { [[ "$parts" == *" $1 "* ]]; }
part() { echo "== $1" >&2; }
load() { cut -d' ' -f1-3 /proc/loadavg; }
# Seconds of one render, from pinrender's summary line ("... in S s -> ...").
seconds_of() { sed -n 's/.* in \([0-9.]*\) s -> .*/\1/p' "$1" | tail -1; }
adapter=unknown

if wanted 1; then
part "1. GPU bake against CPU bake ($VOXELS^3 noise, the smoke; $threads threads)"
if timeout 240 "$B/pinbake" bench --voxels "$VOXELS" --cells "$CELLS" --grid-only --default \
  --backend cpu,gpu --threads "$threads" --source "$smoke_vdb" --json \
  >"$out/bake-bench.json"; then
  python3 - "$out/bake-bench.json" >"$out/bake-bench.md" <<'PY'
import json, sys
rows = json.load(open(sys.argv[1]))["results"]
print("| source | bake | backend | wall s | pins/s | GPU: device s | upload s | jobs s | dispatch s |")
print("|---|---|---|---|---|---|---|---|---|")
for r in rows:
    g = r.get("gpu") or {}
    f = lambda k: "%.3f" % g[k] if k in g else ""
    print("| %s | %s | %s | %.3f | %.3g | %s | %s | %s | %s |" % (
        r["source"].split("/")[-1], r["bake"], r["backend"], r["wall_s"], r["pins_per_s"],
        f("device_s"), f("upload_s"), f("jobs_s"), f("dispatch_s")))
adapters = {(r.get("gpu") or {}).get("adapter") for r in rows} - {None}
print("\nGPU bake adapter: %s" % ", ".join(sorted(adapters)))
PY
  cat "$out/bake-bench.md" >&2
else
  failed+=("GPU bake bench")
fi
# The density in z slabs: the smoke's default bake in one slab and in slabs of 2 MB (about 20
# planes each), which must be the same file. -> bake-slabs.json
for s in whole 2M; do
  extra=()
  [ "$s" = whole ] || extra=(--gpu-slab-bytes "$s")
  timeout 120 "$B/pinbake" bake "$smoke_vdb" --seed 3 --backend gpu --json -q \
    ${extra[@]+"${extra[@]}"} ${QUICK[@]+"${QUICK[@]}"} -o "$work/slabs-$s.pin" >"$work/slabs-$s.json" ||
    failed+=("GPU bake in slabs ($s)")
done
if cmp -s "$work/slabs-whole.pin" "$work/slabs-2M.pin"; then
  python3 - "$work/slabs-whole.json" "$work/slabs-2M.json" >"$out/bake-slabs.json" <<'PY'
import json, sys
rows = []
for f in sys.argv[1:]:
    d = json.load(open(f))
    rows.append({"seconds": d.get("seconds"), "gpu": d.get("gpu")})
print(json.dumps({"source": "openvdb_smoke1.vdb default bake, one slab then 2 MB slabs",
                  "same_bytes": True, "rows": rows}, indent=1))
PY
  cat "$out/bake-slabs.json" >&2
else
  failed+=("GPU bake in slabs: not the same bytes as one slab")
fi
fi

rows=()
md="| scene | estimator | ms per pass (${W}x${H}, 1 spp) |\n|---|---|---|\n"
if wanted 2; then
part "2. bakes for the render figures"
timeout 300 "$B/pinbake" bake procedural:fractal:seed=7,octaves=4 --embed-density "$EMBED" \
  --embed-control "${QUICK[@]}" -o "$work/cloud.pin" --quiet >&2 || failed+=("cloud bake")
timeout 300 "$B/pinbake" bake procedural:cosine:seed=5,freq=4,density=6 --embed-density 128 \
  --embed-control "${QUICK[@]}" -o "$work/instances.pin" --quiet >&2 || failed+=("cosine bake")

seconds() {
  timeout 120 "$B/pinrender" render --pins "$1" --estimator "$2" --backend gpu --width "$W" \
    --height "$H" --spp "$3" --seed 1 --out "$work/x.exr" 2>"$work/r.log" >/dev/null
  seconds_of "$work/r.log"
}

for scene in cloud instances; do
  for est in pins pinms pinres ratio residual; do
    # The first render of each pipeline compiles it into the driver's cache.
    seconds "$work/$scene.pin" "$est" 1 >/dev/null
    t1=$(seconds "$work/$scene.pin" "$est" 1)
    t65=$(seconds "$work/$scene.pin" "$est" 65)
    if [ -z "$t1" ] || [ -z "$t65" ]; then
      echo "$scene $est: failed: $(tail -n 1 "$work/r.log")" >&2
      failed+=("$scene $est")
      continue
    fi
    ms=$(python3 -c "print(round(($t65 - $t1) / 64 * 1000, 3))")
    echo "$scene $est: $ms ms per pass" >&2
    rows+=("{\"scene\": \"$scene\", \"estimator\": \"$est\", \"ms_per_pass\": $ms}")
    md+="| $scene | $est | $ms |\n"
  done
done
# The adapter the GPU bake opened (pinrender's render line does not name it).
adapter=$(python3 -c 'import json,sys; print(next((r["gpu"]["adapter"] for r in json.load(open(sys.argv[1]))["results"] if r.get("gpu")), "unknown"))' "$out/bake-bench.json" 2>/dev/null || echo unknown)
printf "adapter: %s; load %s\n\n$md" "$adapter" "$(load)" >"$out/device-bench.md"
cat "$out/device-bench.md" >&2
fi

if wanted 3; then
part "3. render time against instance count (smoke instances, GPU path, ${W}x${H})"
"$B/pinbake" bake "$smoke_vdb" -o "$work/smoke.pin" --embed-control "${QUICK[@]}" --quiet >&2 ||
  failed+=("smoke bake")
cp "$smoke_vdb" "$work/smoke.vdb"
echo "instances,estimator,spp,seconds,ms_per_pass" >"$out/instances.csv"
# A first render compiles the pipeline into the driver's cache, which a cold driver takes
# seconds for: without it the first figure's 1-spp run pays that and the difference is noise.
python3 "$here/cloudscape_scene.py" "$work/warm.json" 1 1 "smoke=smoke.vdb,smoke.pin"
timeout 120 "$B/pinrender" render --scene "$work/warm.json" --estimator pins --backend gpu \
  --width 64 --height 64 --spp 1 --out "$work/warm.exr" 2>/dev/null >/dev/null
for n in $COUNTS; do
  python3 "$here/cloudscape_scene.py" "$work/sky$n.json" "$n" 1 "smoke=smoke.vdb,smoke.pin"
  # Passes enough that their time dwarfs the render line's 10 ms resolution and the
  # run-to-run spread of start-up.
  case $n in 1 | 16) extra=64 ;; 256) extra=16 ;; *) extra=8 ;; esac
  for est in pins; do
    t=()
    for spp in 1 $((extra + 1)); do
      timeout 120 "$B/pinrender" render --scene "$work/sky$n.json" --estimator "$est" \
        --backend gpu --width "$W" --height "$H" --spp "$spp" --seed 1 \
        --out "$work/sky.exr" 2>"$work/s.log" >/dev/null
      t+=("$(seconds_of "$work/s.log")")
    done
    if [ -z "${t[0]}" ] || [ -z "${t[1]}" ]; then
      echo "$n $est: failed: $(tail -n 1 "$work/s.log")" >&2
      failed+=("instances $n $est")
      continue
    fi
    ms=$(python3 -c "print(round((${t[1]} - ${t[0]}) / $extra * 1000, 3))")
    echo "$n,$est,$((extra + 1)),${t[1]},$ms" >>"$out/instances.csv"
    echo "$n instances, $est: $ms ms per pass" >&2
  done
done

fi

view=null
views=()
if wanted 4; then
part "4. the viewer at ${VW}x${VH}: off-screen, and in a window where there is a display"
if [ ! -f "$work/cloud.pin" ]; then
  timeout 300 "$B/pinbake" bake procedural:fractal:seed=7,octaves=4 --embed-density "$EMBED" \
    --embed-control "${QUICK[@]}" -o "$work/cloud.pin" --quiet >&2 || failed+=("cloud bake")
fi
# One figure of a pinview JSON line: ms per pass, time to the first image, the pipeline
# compile and the longest gap between two frames.
view_row() {
  python3 -c 'import json,sys; j=json.load(sys.stdin); b=j["first_image_breakdown"]
print("%.3f (first image %.2f s, pipeline %.2f s; longest frame gap %.0f ms)" % (j["ms_per_pass"],
  j["first_image_s"], b["pipeline_s"], j["longest_frame_gap_ms"]))'
}
# --offscreen: the viewer's session, slices and tone map into a texture with no window, so
# no X server is needed.
for est in pins pinms; do
  if v=$(timeout 90 "$B/pinview" "$work/cloud.pin" --estimator "$est" --width "$VW" \
    --height "$VH" --frames 32 --offscreen --screenshot "$work/view-$est.png" --json \
    2>"$work/v.log"); then
    views+=("$v")
    [ "$est" = pins ] && view=$v
    printf "| cloud | %s, pinview --offscreen --frames 32 | %s |\n" "$est" \
      "$(echo "$v" | view_row)" >>"$out/device-bench.md"
  else
    echo "pinview --offscreen $est: failed: $(tail -n 1 "$work/v.log")" >&2
    failed+=("viewer offscreen $est")
  fi
done
# The window too where a display or Xvfb is at hand: its longest gap between frames while
# the pipeline compiles and the passes render.
if [ -z "${DISPLAY:-}" ] && command -v Xvfb >/dev/null; then
  Xvfb :77 -screen 0 2400x1300x24 -nolisten tcp >/dev/null 2>&1 &
  xvfb_pid=$!
  sleep 1
  export DISPLAY=:77
fi
if [ -n "${DISPLAY:-}" ]; then
  if v=$(timeout 90 "$B/pinview" "$work/cloud.pin" --estimator pins --width "$VW" --height "$VH" \
    --frames 32 --screenshot "$work/view.png" --json 2>"$work/v.log"); then
    views+=("$v")
    printf "| cloud | pins, pinview window --frames 32 | %s |\n" \
      "$(echo "$v" | view_row)" >>"$out/device-bench.md"
  else
    echo "pinview window: failed: $(tail -n 1 "$work/v.log")" >&2
    failed+=("viewer window")
  fi
else
  echo "no display and no Xvfb: the viewer's window is not measured (off-screen it is)" >&2
fi
fi

if wanted 5; then
part "5. the viewer on the smoke at ${VW}x${VH}: first image cold and warm, ms per pass, event response"
"$B/pinbake" bake "$smoke_vdb" -o "$work/smoke-view.pin" --quiet >&2 || failed+=("smoke bake for the viewer")
cat >"$work/events.json" <<'JSON'
[{"at_s": 0.5, "action": "orbit", "dx_deg": 20, "dy_deg": 5},
 {"at_s": 3.0, "action": "zoom", "factor": 1.3},
 {"at_s": 5.5, "action": "sun", "dir": [-0.4, 1, 0.3]}]
JSON
if [ -z "${DISPLAY:-}" ] && [ -z "${xvfb_pid:-}" ] && command -v Xvfb >/dev/null; then
  Xvfb :78 -screen 0 2400x1300x24 -nolisten tcp >/dev/null 2>&1 &
  xvfb_pid=$!
  sleep 1
  export DISPLAY=:78
fi
for est in pins pinms ratio; do
  # Caches of this run only: the first run is cold, the second warm from what it wrote.
  export PINRT_PIPELINE_CACHE="$out/cache-$est/wgpu" MESA_SHADER_CACHE_DIR="$out/cache-$est/mesa" \
    __GL_SHADER_DISK_CACHE_PATH="$out/cache-$est/nvidia"
  rm -rf "$out/cache-$est"
  mkdir -p "$PINRT_PIPELINE_CACHE" "$MESA_SHADER_CACHE_DIR" "$__GL_SHADER_DISK_CACHE_PATH"
  for run in cold warm; do
    timeout 300 "$B/pinview" "$work/smoke-view.pin" --estimator "$est" --width "$VW" \
      --height "$VH" --frames 16 --offscreen --json >"$work/view-$est-$run.json" \
      2>"$work/v.log" || { echo "pinview $est $run: $(tail -n 1 "$work/v.log")" >&2; failed+=("viewer $est $run"); }
  done
  if [ -n "${DISPLAY:-}" ]; then
    timeout 300 "$B/pinview" "$work/smoke-view.pin" --estimator "$est" --width "$VW" \
      --height "$VH" --frames 4 --input-script "$work/events.json" --json \
      >"$work/view-$est-events.json" 2>"$work/v.log" ||
      { echo "pinview $est events: $(tail -n 1 "$work/v.log")" >&2; failed+=("viewer $est events"); }
  fi
  unset PINRT_PIPELINE_CACHE MESA_SHADER_CACHE_DIR __GL_SHADER_DISK_CACHE_PATH
done
python3 - "$work" "$VW" "$VH" "$(load)" "$out/viewer-bench.json" >"$out/viewer-bench.md" <<'PY'
import json, os, sys
work, w, h, load, out = sys.argv[1:]
def read(name):
    try:
        return json.load(open(os.path.join(work, name)))
    except (OSError, ValueError):
        return None
rows, adapter, cpu = [], "unknown", False
for est in ["pins", "pinms", "ratio"]:
    cold, warm, ev = (read("view-%s-%s.json" % (est, r)) for r in ["cold", "warm", "events"])
    for j in (cold, warm, ev):
        if j:
            adapter, cpu = j["adapter"], j["device_type"] == "Cpu"
    events = {e["action"]: e for e in (ev or {}).get("events", [])}
    rows.append({
        "estimator": est,
        "first_image_cold_s": cold and cold["first_image_s"],
        "pipeline_cold_s": cold and cold["first_image_breakdown"]["pipeline_s"],
        "first_image_warm_s": warm and warm["first_image_s"],
        "pipeline_warm_s": warm and warm["first_image_breakdown"]["pipeline_s"],
        "ms_per_pass": warm and warm["ms_per_pass"],
        "pass_time_source": warm and warm["pass_time_source"],
        "events": {a: {k: e.get(k) for k in ("first_pixels_ms", "first_full_pass_ms")}
                   for a, e in events.items()},
        "longest_frame_gap_ms": ev and ev["longest_frame_gap_ms"],
    })
label = "lavapipe (CPU Vulkan), not GPU speed" if cpu else adapter
json.dump({"adapter": adapter, "cpu_adapter": cpu, "width": int(w), "height": int(h),
           "load": load, "file": "openvdb_smoke1.vdb, default bake", "rows": rows},
          open(out, "w"), indent=1)
f = lambda v, d=2: "" if v is None else ("%.*f" % (d, v))
print("Viewer on the smoke's default bake, %sx%s, %s; load %s\n" % (w, h, label, load))
print("| estimator | first image cold s (pipeline s) | warm s (pipeline s) | ms per pass | orbit ms: first pixels / full pass | zoom ms | sun ms |")
print("|---|---|---|---|---|---|---|")
for r in rows:
    ev = lambda a: "%s / %s" % (f(r["events"].get(a, {}).get("first_pixels_ms"), 0),
                                f(r["events"].get(a, {}).get("first_full_pass_ms"), 0)) if a in r["events"] else ""
    print("| %s | %s (%s) | %s (%s) | %s | %s | %s | %s |" % (
        r["estimator"], f(r["first_image_cold_s"]), f(r["pipeline_cold_s"]),
        f(r["first_image_warm_s"]), f(r["pipeline_warm_s"]), f(r["ms_per_pass"], 1),
        ev("orbit"), ev("zoom"), ev("sun")))
PY
cat "$out/viewer-bench.md"
fi

{
  echo "{\"adapter\": \"$adapter\", \"load\": \"$(load)\", \"rows\": ["
  (IFS=,; echo "${rows[*]}")
  echo "], \"pinview\": $view, \"pinview_runs\": ["
  (IFS=,; echo "${views[*]}")
  echo "], \"failed\": ["
  (IFS=,; for f in "${failed[@]}"; do printf '"%s",' "$f"; done | sed 's/,$//')
  echo "]}"
} >"$out/device-bench.json"
[ -f "$out/device-bench.md" ] && cat "$out/device-bench.md"
[ -f "$out/instances.csv" ] && cat "$out/instances.csv"
if [ ${#failed[@]} -gt 0 ]; then
  echo "device-bench: failed: ${failed[*]}" >&2
  exit 1
fi
