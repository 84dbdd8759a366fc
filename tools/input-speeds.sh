#!/usr/bin/env bash
# Decode speed of every input reader on the same generated mesh, side by
# side in one run (issue 33): the mesh is written by octolod-gen as binary
# and ascii PLY, OBJ, binary and ascii STL, and as a GLB (level 0 of its
# store, extracted: the same triangles); each file is decoded by
# `octolod info-input` (release build, warm page cache, best of 3) and the
# table printed gives MB/s, M triangles/s and the ratio to the PLY reader
# of the same kind (ascii OBJ/STL against ascii PLY, binary STL/GLB
# against binary PLY).
#
# usage: tools/input-speeds.sh [TRIS] [SHAPE] [GEN-ATTR-FLAGS...]
#   e.g. tools/input-speeds.sh 2000000 sphere
#        tools/input-speeds.sh 2000000 scan --normals --uvs   (OBJ corner path)
# Files go to a temp directory (removed at the end; about 70 bytes per
# triangle in all for position-only meshes).
set -euo pipefail
cd "$(dirname "$0")/.."
tris="${1:-2000000}"
shape="${2:-sphere}"
shift $(( $# > 2 ? 2 : $# ))
attrs=("$@")
cargo build --release --quiet --bin octolod --bin octolod-gen
bin=target/release
dir="$(mktemp -d "${TMPDIR:-/tmp}/octolod-input-speeds.XXXXXX")"
trap 'rm -rf "$dir"' EXIT
gen() { "$bin/octolod-gen" --shape "$shape" --tris "$tris" "${attrs[@]}" -q "$@" >/dev/null; }
gen -o "$dir/m.ply"
gen --format ascii -o "$dir/m-ascii.ply"
gen --format obj -o "$dir/m.obj"
gen --format stl-binary -o "$dir/m.stl"
gen --format stl-ascii -o "$dir/m-ascii.stl"
"$bin/octolod" build "$dir/m.ply" -o "$dir/m.octolod" -q >/dev/null
"$bin/octolod" extract "$dir/m.octolod" --level 0 -o "$dir/m.glb" -q >/dev/null
rm -rf "$dir/m.octolod"

# best MB/s and M faces/s of 3 decodes
speed() {
  local best_mb=0 best_mf=0 line mb mf
  for _ in 1 2 3; do
    line="$("$bin/octolod" info-input "$1" -q | grep '^decoded:')"
    mb="$(sed -E 's/.*\(([0-9.]+) MB\/s.*/\1/' <<<"$line")"
    mf="$(sed -E 's/.*, ([0-9.]+) M faces\/s.*/\1/' <<<"$line")"
    if awk -v a="$mb" -v b="$best_mb" 'BEGIN{exit !(a>b)}'; then best_mb="$mb"; best_mf="$mf"; fi
  done
  echo "$best_mb $best_mf"
}
read -r ply_mb ply_mf < <(speed "$dir/m.ply")
read -r plya_mb plya_mf < <(speed "$dir/m-ascii.ply")
echo "mesh: $shape, $tris triangles requested, attributes: ${attrs[*]:-position only}; $(nproc) cores; $(date -u +%F)"
printf '%-22s %10s %10s %12s %s\n' file MB MB/s "M tris/s" "against"
row() { # name path mb mf ref_mb ref_name
  local size; size="$(stat -c %s "$2")"
  printf '%-22s %10.1f %10.1f %12.2f %s\n' "$1" "$(awk -v s="$size" 'BEGIN{print s/1e6}')" "$3" "$4" "$5"
}
row "PLY binary" "$dir/m.ply" "$ply_mb" "$ply_mf" "-"
row "PLY ascii" "$dir/m-ascii.ply" "$plya_mb" "$plya_mf" "-"
for f in "OBJ:m.obj:a" "STL ascii:m-ascii.stl:a" "STL binary:m.stl:b" "GLB:m.glb:b"; do
  IFS=: read -r name file kind <<<"$f"
  read -r mb mf < <(speed "$dir/$file")
  if [ "$kind" = a ]; then ref="$plya_mb"; rn="PLY ascii"; else ref="$ply_mb"; rn="PLY binary"; fi
  row "$name" "$dir/$file" "$mb" "$mf" "$(awk -v a="$mb" -v b="$ref" 'BEGIN{printf "%.2fx ", a/b}')$rn MB/s"
done
