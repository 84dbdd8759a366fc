#!/usr/bin/env bash
# CI's fuzz step (part of the README's test command): the store fuzz
# target `store_open` and the PLY one `ply_parse`, each for
# ${OCTOLOD_FUZZ_SECS:-60} s from its seeds, then every recorded regression
# replayed; the STL, OBJ and glTF targets for half that. A crash, panic, OOM or timeout fails the step and leaves the
# reproducer under fuzz/artifacts/ (see fuzz/README.md).
#
# Needs only stable Rust: RUSTC_BOOTSTRAP=1 lets it take the sanitizer
# flags cargo-fuzz passes. Installs cargo-fuzz when missing.
set -euo pipefail
cd "$(dirname "$0")/../fuzz"
secs=${OCTOLOD_FUZZ_SECS:-60}
if ! command -v cargo-fuzz >/dev/null 2>&1; then
  echo "fuzz-ci: installing cargo-fuzz 0.13.2" >&2
  cargo install cargo-fuzz --locked --version 0.13.2 >&2
fi
export RUSTC_BOOTSTRAP=1
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
# The targets' scratch files (one per fuzzing process, named by its pid)
# go inside $work and leave with it, not into the machine's /tmp.
mkdir -p "$work/tmp"
export TMPDIR="$work/tmp"
mkdir -p "$work/store_open" "$work/ply_parse" "$work/stl_parse" "$work/obj_parse" "$work/gltf_parse"
cp seeds/store/* "$work/store_open/"
cp seeds/*.ply "$work/ply_parse/"
cp seeds/*.stl "$work/stl_parse/"
cp seeds/*.obj "$work/obj_parse/"
cp seeds/*.glb "$work/gltf_parse/"
run() { # target, libFuzzer arguments...
  local t=$1; shift
  cargo fuzz run "$t" "$@"   # release, with debug assertions (its default)
}
run store_open "$work/store_open" -- -max_total_time="$secs" -rss_limit_mb=2048 -timeout=10 -max_len=256
run store_open regressions/store/* -- -rss_limit_mb=2048 -timeout=10
run ply_parse "$work/ply_parse" -- -dict=ply.dict -max_total_time="$secs" -rss_limit_mb=2048 -timeout=10 -max_len=4096
run ply_parse regressions/*.ply -- -rss_limit_mb=2048 -timeout=10
# The STL, OBJ and glTF readers (issue 33) for half as long each.
run stl_parse "$work/stl_parse" -- -max_total_time="$((secs / 2))" -rss_limit_mb=2048 -timeout=10 -max_len=4096
run obj_parse "$work/obj_parse" -- -max_total_time="$((secs / 2))" -rss_limit_mb=2048 -timeout=10 -max_len=4096
run gltf_parse "$work/gltf_parse" -- -max_total_time="$((secs / 2))" -rss_limit_mb=2048 -timeout=10 -max_len=4096
echo "fuzz-ci: store_open and ply_parse ran ${secs} s each, stl_parse, obj_parse and gltf_parse $((secs / 2)) s each, from their seeds; every regression replayed cleanly" >&2
