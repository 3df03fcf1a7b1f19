#!/bin/bash
# The production-scale bake benchmark: bakes each volume with pinbake's default settings and
# prints, per volume, the wall time, the peak memory (the largest sum of the resident sets of
# pinbake and its VDB reader process at once, sampled every 20 ms, or the kernel's peak of
# the largest process if that is higher), the file's bytes, the bake's own memory estimate
# (what --max-memory is checked against) and the ratios peak / file and estimate / peak.
#
#   scripts/scale-bench.sh [--json] [small|half|half-nvdb|full|seq|FILE]...   (default: small half)
#
# The volumes are generated on first use by scripts/production/generate.sh (cached under the
# target directory, never committed); half-nvdb is the half cloud converted once to NanoVDB by
# nanovdb_convert (float leaves) and cached beside it. --json prints one JSON object instead of the table:
# {"machine": {...}, "runs": [{"volume", "file_bytes", "wall_s", "peak_rss_bytes",
# "memory_estimate_bytes", "peak_over_file", "estimate_over_peak", "cells", "frames",
# "user_s", "system_s"}]}. PINBAKE (default: the release binary of this checkout) and
# BAKE_OPTS (extra flags for every bake) may be set. Run it alone: the full cloud needs
# several GB and the timings are wall times.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/.." && pwd)
target="${CARGO_TARGET_DIR:-$root/target}"
pinbake="${PINBAKE:-$target/release/pinbake}"
json=0
volumes=()
for a in "$@"; do
  case "$a" in
    --json) json=1 ;;
    *) volumes+=("$a") ;;
  esac
done
[ ${#volumes[@]} -gt 0 ] || volumes=(small half)
[ -x "$pinbake" ] || { echo "scale-bench.sh: $pinbake not built (cargo build --release -p pinbake --all-features)" >&2; exit 1; }
work=$(mktemp -d "${TMPDIR:-/tmp}/scale-bench.XXXXXX")
trap 'rm -rf "$work"' EXIT
runs="$work/runs.jsonl"
: >"$runs"

for v in "${volumes[@]}"; do
  frames=""
  case "$v" in
    small | half | full | half-nvdb) input=$("$here/production/generate.sh" "$v" | tail -1) ;;
    seq)
      "$here/production/generate.sh" seq >/dev/null
      input="$target/production/seq/cloud.####.vdb"
      frames="1-24"
      ;;
    *) input="$v" ;;
  esac
  out="$work/out.pin"
  args=(bake "$input" -o "$out" --json)
  if [ -n "$frames" ]; then
    args=(bake "$input" --frames "$frames" -o "$work/out.####.pin" --json)
  fi
  # shellcheck disable=SC2086 # BAKE_OPTS is a list of flags
  python3 "$here/production/peak_rss.py" --json-out "$work/rss.json" -- \
    "$pinbake" "${args[@]}" ${BAKE_OPTS:-} >"$work/bake.json"
  python3 - "$v" "$input" "$frames" "$work/rss.json" "$work/bake.json" >>"$runs" <<'EOF'
import glob, json, os, sys
name, path, frames, rss_path, bake_path = sys.argv[1:]
rss = json.load(open(rss_path))
bake = json.load(open(bake_path))
files = sorted(glob.glob(path.replace("####", "[0-9][0-9][0-9][0-9]"))) if frames else [path]
file_bytes = max(os.path.getsize(f) for f in files)
# A sequence: the largest frame and the largest estimate (frames are baked one at a time).
summaries = bake.get("frames", [bake]) if frames else [bake]
summaries = [s.get("summary", s) for s in summaries]
estimate = max(s.get("memory_estimate_bytes", 0) for s in summaries)
peak = max(rss["peak_tree_rss_bytes"], rss["peak_process_rss_bytes"])
print(json.dumps({
    "volume": name,
    "file": path,
    "file_bytes": file_bytes,
    "frames": len(files),
    "wall_s": rss["wall_s"],
    "user_s": rss["user_s"],
    "system_s": rss["system_s"],
    "peak_rss_bytes": peak,
    "memory_estimate_bytes": estimate,
    "peak_over_file": round(peak / file_bytes, 3),
    "estimate_over_peak": round(estimate / peak, 3) if peak else None,
    "cells": summaries[0].get("dims"),
    "exit_code": rss["exit_code"],
}))
EOF
done

python3 - "$json" "$runs" <<'EOF'
import json, os, platform, sys
as_json, runs_path = sys.argv[1] == "1", sys.argv[2]
runs = [json.loads(l) for l in open(runs_path)]
machine = {"cpus": os.cpu_count(), "memory_bytes": os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"),
           "load_average": os.getloadavg(), "kernel": platform.release()}
if as_json:
    print(json.dumps({"machine": machine, "runs": runs}, indent=1))
    sys.exit(0)
print(f"{os.cpu_count()} CPUs, load average {machine['load_average'][0]:.1f} at the end (timings are wall times)")
print("| volume | frames | file | wall | peak RSS | estimate | peak / file | estimate / peak | cells |")
print("|---|---:|---:|---:|---:|---:|---:|---:|---|")
mb = lambda b: f"{b / 1e6:,.0f} MB"
for r in runs:
    print(f"| {r['volume']} | {r['frames']} | {mb(r['file_bytes'])} | {r['wall_s']:.1f} s | {mb(r['peak_rss_bytes'])} | "
          f"{mb(r['memory_estimate_bytes'])} | {r['peak_over_file']:.2f} | {r['estimate_over_peak']:.2f} | {r['cells']} |")
EOF
