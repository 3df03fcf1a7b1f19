#!/bin/bash
# Production-scale volumes, generated where they are used and never committed: compiles
# cloud.cpp (next to this file) against Debian's libopenvdb-dev and writes, under
# "$CARGO_TARGET_DIR/production" (default target/production), each volume once (a file that
# exists is kept; delete it to regenerate):
#
#   half    cloud-half.vdb: 992 x 674 x 1225 voxels, about 263 M active (the size of the WDAS
#           cloud's half-resolution file)
#   full    cloud-full.vdb: 1790 x 1216 x 2210 voxels, about 1.5 G active (the full WDAS size)
#   seq     seq/cloud.0001.vdb .. seq/cloud.0024.vdb: 24 frames, 440 x 299 x 543, >= 20 M each
#   nvdb    seq/cloud.0001.nvdb: frame 1 converted by nanovdb_convert (libnanovdb-tools),
#           skipped with a note when the tool is missing
#   half-nvdb  cloud-half.nvdb: the half cloud converted by nanovdb_convert (float leaves;
#           the tool is required)
#   small   cloud-small.vdb: 124 x 84 x 153 (for tests and quick checks)
#   custom  NAME NX NY NZ: cloud-NAME.vdb at any size
#
# Usage: scripts/production/generate.sh [half|full|seq|nvdb|half-nvdb|small|all|custom NAME NX NY NZ]...
# Prints the path of each volume it made or found. Needs: apt-get install -y g++
# libopenvdb-dev libboost-dev (libnanovdb-tools for nvdb). Memory: about 5 bytes per active
# voxel while a cloud is written (7.5 GB for the full one), so run it alone.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
out="${CARGO_TARGET_DIR:-$root/target}/production"
mkdir -p "$out/seq"
hash=$(sha256sum "$here/cloud.cpp" | cut -c1-16)
# CLOUD_OPT: the generator's optimisation level (-O2; the tests' small cloud takes -O0, whose
# compile is half as long and writes the same cloud).
opt=${CLOUD_OPT:--O2}
exe="$out/cloud-$hash"
[ "$opt" = -O2 ] || exe="$exe$opt"
if [ ! -x "$exe" ]; then
  if ! dpkg -s libopenvdb-dev >/dev/null 2>&1 && [ ! -e /usr/include/openvdb/openvdb.h ]; then
    echo "generate.sh: OpenVDB headers missing: apt-get install -y g++ libopenvdb-dev libboost-dev" >&2
    exit 1
  fi
  "${CXX:-c++}" -std=c++17 "$opt" "$here/cloud.cpp" -o "$exe.part" -lopenvdb -ltbb -lImath
  mv "$exe.part" "$exe"
fi

# cloud FILE NX NY NZ [FRAME]: writes FILE unless it exists (atomically, via a .part file).
cloud() {
  local file=$1
  if [ ! -s "$file" ]; then
    "$exe" "$file.part" "$2" "$3" "$4" 1 "${5:-0}" >"$file.json.part"
    mv "$file.part" "$file"
    # The generator names the file it wrote, the temporary one.
    sed "s#$file.part#$file#" "$file.json.part" >"$file.json"
    rm "$file.json.part"
  fi
  echo "$file"
}

seq_frames() {
  for f in $(seq 1 24); do
    cloud "$out/seq/cloud.$(printf %04d "$f").vdb" 440 299 543 "$f"
  done
}

# nvdb SRC DST [required]: converts SRC to DST with nanovdb_convert unless DST exists.
nvdb() {
  local src=$1 dst=$2
  if ! command -v nanovdb_convert >/dev/null; then
    echo "generate.sh: nanovdb_convert missing (apt-get install -y libnanovdb-tools); no .nvdb written" >&2
    [ "${3:-}" = required ] && exit 1
    return 0
  fi
  if [ ! -s "$dst" ]; then
    nanovdb_convert -f "$src" "$dst.part.nvdb" >&2
    mv "$dst.part.nvdb" "$dst"
  fi
  echo "$dst"
}

[ $# -gt 0 ] || set -- small
while [ $# -gt 0 ]; do
  case "$1" in
    small) cloud "$out/cloud-small.vdb" 124 84 153 ;;
    half) cloud "$out/cloud-half.vdb" 992 674 1225 ;;
    full) cloud "$out/cloud-full.vdb" 1790 1216 2210 ;;
    seq) seq_frames ;;
    nvdb)
      [ -s "$out/seq/cloud.0001.vdb" ] || cloud "$out/seq/cloud.0001.vdb" 440 299 543 1 >/dev/null
      nvdb "$out/seq/cloud.0001.vdb" "$out/seq/cloud.0001.nvdb"
      ;;
    half-nvdb)
      cloud "$out/cloud-half.vdb" 992 674 1225 >/dev/null
      nvdb "$out/cloud-half.vdb" "$out/cloud-half.nvdb" required
      ;;
    all)
      cloud "$out/cloud-small.vdb" 124 84 153
      cloud "$out/cloud-half.vdb" 992 674 1225
      seq_frames
      nvdb "$out/seq/cloud.0001.vdb" "$out/seq/cloud.0001.nvdb"
      cloud "$out/cloud-full.vdb" 1790 1216 2210
      ;;
    custom)
      [ $# -ge 5 ] || { echo "usage: generate.sh custom NAME NX NY NZ" >&2; exit 2; }
      cloud "$out/cloud-$2.vdb" "$3" "$4" "$5"
      shift 4
      ;;
    *) echo "generate.sh: unknown volume '$1' (half, full, seq, nvdb, half-nvdb, small, all, custom)" >&2; exit 2 ;;
  esac
  shift
done
