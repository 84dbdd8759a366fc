#!/usr/bin/env bash
# Build-cost comparison against the v1 hierarchy (issue 9's cost point):
# builds v1 (commit 1e3a1a1, or $OLD) and the working tree's release
# binary, generates the 120 M-triangle sphere once, then runs
# `octolod build IN -o DIR -q` (--mem 512M, the default) with each binary
# in alternated order (old-new, new-old, ...), the store removed and
# `sync` + 5 s of rest between runs, and prints wall / user / system
# seconds and peak RSS from /usr/bin/time for every run, then the medians.
# Only runs made in the same invocation are compared: this is how the
# README's "Costs" figures were made, on a machine whose speed drifts
# from hour to hour.
#
#   tools/cost-pairs.sh [PAIRS] [TRIANGLES] [WORKDIR]
#
# Needs /usr/bin/time (package `time`), about 12 GB of free disk in
# WORKDIR (input 2.3 GB, store 4.4 GB, scratch) and a 2-minute build of
# each binary; each pair takes about 5 minutes at 120 M triangles. The old
# commit is checked out as a git worktree in WORKDIR/src-OLD and kept for
# the next run; `git worktree remove WORKDIR/src-OLD` drops it.
set -euo pipefail
cd "$(dirname "$0")/.."
pairs=${1:-3}
tris=${2:-120000000}
dir=${3:-out/cost}
old=${OLD:-1e3a1a1}
[[ -x /usr/bin/time ]] || { echo "cost-pairs: needs /usr/bin/time (apt-get install time)" >&2; exit 2; }
mkdir -p "$dir"
cargo build --release --locked --quiet --bin octolod --bin octolod-gen
new_bin=target/release/octolod
old_src="$dir/src-$old"
if [[ ! -d $old_src ]]; then
  git worktree add --detach "$old_src" "$old" >/dev/null
fi
CARGO_TARGET_DIR="$dir/target-$old" cargo build --release --locked --quiet \
  --manifest-path "$old_src/Cargo.toml" --bin octolod
old_bin="$dir/target-$old/release/octolod"
in="$dir/sphere-$tris.ply"
if [[ ! -f $in ]]; then
  target/release/octolod-gen --shape sphere --tris "$tris" --seed 1 -o "$in" --quiet
fi
echo "input $in, $(nproc) cores; old = $old, new = $(git rev-parse --short HEAD)$(git diff --quiet || echo ' + changes')"
printf '%-4s %-4s %8s %8s %8s %9s\n' pair bin wall_s user_s sys_s rss_mib
results="$dir/runs.txt"
: >"$results"
run() { # name binary pair
  local store="$dir/store-$1"
  rm -rf "$store"; sync; sleep 5
  /usr/bin/time -f "%e %U %S %M" -o "$dir/time-$1" "$2" build "$in" -o "$store" -q >/dev/null
  rm -rf "$store"
  read -r wall user sys rss <"$dir/time-$1"
  printf '%-4s %-4s %8.1f %8.1f %8.1f %9.0f\n' "$3" "$1" "$wall" "$user" "$sys" "$((rss / 1024))"
  echo "$1 $wall $user $sys $rss" >>"$results"
}
for p in $(seq 1 "$pairs"); do
  if (( p % 2 )); then run old "$old_bin" "$p"; run new "$new_bin" "$p"
  else run new "$new_bin" "$p"; run old "$old_bin" "$p"; fi
done
python3 - "$results" <<'PY'
import statistics, sys
runs = {}
for line in open(sys.argv[1]):
    name, *v = line.split()
    runs.setdefault(name, []).append([float(x) for x in v])
for name in ("old", "new"):
    r = runs[name]
    med = [statistics.median(col) for col in zip(*r)]
    print(f"median {name}: wall {med[0]:.1f} s, user {med[1]:.1f} s, system {med[2]:.1f} s, "
          f"peak RSS {med[3] / 1024:.0f} MiB ({len(r)} runs)")
o = statistics.median(x[0] for x in runs["old"])
n = statistics.median(x[0] for x in runs["new"])
print(f"new / old wall (medians): {n / o:.3f}")
PY
