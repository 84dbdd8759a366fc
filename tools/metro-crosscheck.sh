#!/usr/bin/env bash
# Cross-check `octolod metro` against MeshLab (pymeshlab) on generated pairs.
# Slow (minutes) and needs PyPI once: kept out of .ci/run. See README.
set -euo pipefail
cd "$(dirname "$0")/.."
venv=${OCTOLOD_VENV:-out/venv-meshlab}
if [[ ! -x $venv/bin/python ]]; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet pymeshlab
fi
cargo build --release --quiet --bin octolod --bin octolod-gen
exec "$venv/bin/python" tools/metro-crosscheck.py "$@"
