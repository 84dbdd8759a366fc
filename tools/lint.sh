#!/usr/bin/env bash
# CI hygiene (issue 36): formatting (rustfmt.toml), lints with warnings as
# errors over every target, and the API docs with warnings as errors (broken
# or private intra-doc links). The headless build's lints run in
# tools/headless-check.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
if command -v rustup >/dev/null 2>&1; then
  rustup component list --installed 2>/dev/null | grep -q '^rustfmt' || rustup component add rustfmt
  rustup component list --installed 2>/dev/null | grep -q '^clippy' || rustup component add clippy
fi
cargo fmt --check
cargo clippy --locked --all-targets -- -D warnings
RUSTDOCFLAGS="-D warnings" cargo doc --locked --no-deps
echo "lint: cargo fmt, clippy and rustdoc clean" >&2
