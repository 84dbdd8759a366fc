#!/usr/bin/env bash
# Soup-stage benchmark: generates a large binary PLY (default 120 M triangles,
# about 2.3 GB) once, then reports warm-cache decode throughput and the soup
# stage's throughput and peak RSS under a memory budget (default 128M).
#
#   tools/soup-bench.sh [TRIANGLES] [MEM] [WORKDIR]
#
# Needs about 4x the input size of free disk in WORKDIR (scratch buckets + soup).
set -euo pipefail
cd "$(dirname "$0")/.."
tris=${1:-120000000}
mem=${2:-128M}
dir=${3:-out/bench}
mkdir -p "$dir"
cargo build --release --quiet --bin octolod --bin octolod-gen
bin=target/release
in="$dir/sphere-$tris.ply"
if [[ ! -f $in ]]; then
  "$bin/octolod-gen" --shape sphere --tris "$tris" --seed 1 -o "$in" --quiet
fi
size=$(stat -L -c %s "$in")
echo "input: $in, $size bytes, budget $mem, $(nproc) cores"
# Warm the page cache, then time pure decoding.
"$bin/octolod" ply-info "$in" --quiet >/dev/null
"$bin/octolod" ply-info "$in" --quiet | grep -E "^(faces|decoded)"
timefile="$dir/time.txt"
if [[ -x /usr/bin/time ]]; then
  /usr/bin/time -v "$bin/octolod" soup "$in" -o "$dir/out.soup" --mem "$mem" --json --quiet 2>"$timefile" | tee "$dir/soup.json"
  grep -E "Maximum resident|Elapsed" "$timefile"
else
  "$bin/octolod" soup "$in" -o "$dir/out.soup" --mem "$mem" --json --quiet | tee "$dir/soup.json"
fi
python3 - "$dir/soup.json" "$size" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
size = int(sys.argv[2])
print(f"soup: {r['triangles']/1e6:.1f} M triangles in {r['seconds']:.1f} s = {r['mtris_per_s']:.2f} M tri/s, "
      f"{size/1e6/r['seconds']:.0f} MB/s of PLY; peak RSS {r['peak_rss_bytes']/2**20:.0f} MiB "
      f"(budget {r['mem_budget_bytes']/2**20:.0f} MiB, limit budget+64 MiB: "
      f"{'OK' if r['peak_rss_bytes'] <= r['mem_budget_bytes'] + (64 << 20) else 'EXCEEDED'}); "
      f"vertex slabs {r['vertex_slabs']}, slot buckets {r['slot_buckets']}, spilled {r['spilled_bytes']/1e9:.1f} GB")
PY
rm -f "$dir/out.soup"
