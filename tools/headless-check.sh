#!/usr/bin/env bash
# CI check: the headless octolod (no `view` feature: no wgpu, winit, PNG
# output; `cargo install octolod --no-default-features`) and every target
# (lib, bins, tests, benches) still compile, with no compiler or clippy
# warnings. Tests that
# need the viewer (the renderer, `octolod render`, PNGs) are under
# #[cfg(feature = "view")]; everything else builds both ways.
set -euo pipefail
cd "$(dirname "$0")/.."
log=$(mktemp)
trap 'rm -f "$log"' EXIT
# Cargo replays a cached crate's warnings, so a warm check still shows them.
cargo clippy --locked --no-default-features --all-targets --message-format short 2>&1 | tee "$log" >&2
if grep -E '^warning: `[^`]+` \(.*\) generated [0-9]+ warnings?' "$log" >/dev/null; then
  echo "headless-check: warnings without the view feature (above)" >&2
  exit 1
fi
echo "headless-check: --no-default-features builds every target without warnings" >&2
