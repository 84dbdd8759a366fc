#!/usr/bin/env bash
# CI hygiene (issue 36): formatting (rustfmt.toml), lints with warnings as
# errors over every target (the benchmark tool's too: feature `peers`), the
# API docs with warnings as errors (broken or private intra-doc links), and
# the benchmark tool's own unit tests (report layout, old reports reading
# back), which plain `cargo test` does not build. The headless build's lints
# run in tools/headless-check.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
if command -v rustup >/dev/null 2>&1; then
  rustup component list --installed 2>/dev/null | grep -q '^rustfmt' || rustup component add rustfmt
  rustup component list --installed 2>/dev/null | grep -q '^clippy' || rustup component add clippy
fi
cargo fmt --check
cargo clippy --locked --all-targets --features peers -- -D warnings
RUSTDOCFLAGS="-D warnings" cargo doc --locked --no-deps
cargo test --locked --features peers --bin octolod-bench
echo "lint: cargo fmt, clippy and rustdoc clean; bench tool tests pass" >&2
