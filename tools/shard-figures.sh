#!/usr/bin/env bash
# Sharded build figures (docs/sharded.md): for each shard count, plan, every
# shard built one after another on this machine (as separate processes, the
# way a scheduler runs them), merge; wall and CPU seconds and peak RSS of
# each command from GNU time, against the monolithic build of the same input.
#   tools/shard-figures.sh INPUT [MEM] [SHARD COUNTS...]
# Needs target/release/octolod (cargo build --release) and /usr/bin/time.
set -euo pipefail
in=${1:?usage: tools/shard-figures.sh INPUT [MEM] [COUNTS...]}
mem=${2:-128M}
shift $(( $# >= 2 ? 2 : 1 ))
counts=("${@:-1 4 16}")
[ $# -eq 0 ] && counts=(1 4 16)
bin=${OCTOLOD:-target/release/octolod}
work=$(mktemp -d "${TMPDIR:-/tmp}/shard-figures.XXXXXX")
trap 'rm -rf "$work"' EXIT
# One command: prints "wall_s cpu_s maxrss_kib".
measure() {
  /usr/bin/time -f "%e %U %S %M" -o "$work/time" "$@" >/dev/null
  awk '{printf "%.2f %.2f %d\n", $1, $2 + $3, $4}' "$work/time"
}
echo "input: $in ($(stat -c %s "$in") bytes), --mem $mem, $(nproc) cores"
read -r w c r < <(measure "$bin" -q build "$in" -o "$work/mono.octolod" --mem "$mem")
echo "monolithic: wall ${w} s, cpu ${c} s, peak RSS $((r / 1024)) MiB"
rm -rf "$work/mono.octolod"
for n in "${counts[@]}"; do
  read -r pw pc pr < <(measure "$bin" -q plan "$in" -o "$work/plan.json" --shards "$n" --mem "$mem" --force)
  sw=0; sc=0; smax=0; slow=0; dirs=()
  for ((i = 0; i < n; i++)); do
    read -r w c r < <(measure "$bin" -q build "$in" --plan "$work/plan.json" --shard "$i" -o "$work/s$i" --mem "$mem")
    sw=$(echo "$sw + $w" | bc); sc=$(echo "$sc + $c" | bc)
    (( r > smax )) && smax=$r
    slow=$(echo "if ($w > $slow) $w else $slow" | bc)
    dirs+=("$work/s$i")
  done
  read -r mw mc mr < <(measure "$bin" -q merge "$work/plan.json" "${dirs[@]}" -o "$work/m.octolod" --mem "$mem")
  levels=$(python3 -c "import json; print(json.load(open('$work/plan.json'))['shard_levels'])")
  merged=$("$bin" merge "$work/plan.json" "${dirs[@]}" -o "$work/m2.octolod" --mem "$mem" --json -q | python3 -c "import json,sys; j=json.load(sys.stdin); print(j['merged_triangles'], 'triangles simplified, packs linked', j['linked_bytes'] >> 20, 'MiB, copied', j['copied_bytes'] >> 20, 'MiB')")
  under=$([ $((smax * 1024)) -le "$(numfmt --from=iec "$mem")" ] && echo "under --mem" || echo "OVER --mem")
  echo "shards $n (levels per shard $levels): plan ${pw} s ($((pr / 1024)) MiB); shards: sum wall ${sw} s, slowest ${slow} s, cpu ${sc} s, peak RSS per task $((smax / 1024)) MiB ($under); merge ${mw} s wall, ${mc} s cpu, $((mr / 1024)) MiB, ${merged}"
  rm -rf "$work"/s* "$work"/m.octolod "$work"/m2.octolod
done
