#!/usr/bin/env bash
# Cross-check `octolod metro` against MeshLab (pymeshlab) on generated pairs.
# Slow (minutes) and needs PyPI once: kept out of .ci/run. See README.
# Prints the table and keeps a copy in tools/metro-crosscheck.last.txt;
# exits non-zero when any row misses the bar (mean/RMS 2 %, max 5 %).
set -euo pipefail
cd "$(dirname "$0")/.."
venv=${OCTOLOD_VENV:-out/venv-meshlab}
if [[ ! -x $venv/bin/python ]]; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet pymeshlab
fi
cargo build --release --quiet --bin octolod --bin octolod-gen
last=tools/metro-crosscheck.last.txt
set +e
{
  echo "# tools/metro-crosscheck.sh $* ($(date -u +%Y-%m-%d), octolod $(git describe --always --dirty 2>/dev/null || echo '?'))"
  "$venv/bin/python" tools/metro-crosscheck.py "$@"
} 2>&1 | tee "$last.tmp"
rc=${PIPESTATUS[0]}
set -e
mv "$last.tmp" "$last"
echo "exit $rc" >> "$last"
exit "$rc"
