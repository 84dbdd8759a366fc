#!/usr/bin/env bash
# CI's web step (part of the README's test command): the committed viewer
# bundle (web/dist, embedded by `octolod serve`) must be what web/build.mjs
# makes from web/src and the locked packages, and the page's own tests
# (web/test/page.test.mjs: a fixture tileset in headless Chromium) pass.
# The Rust side (tests/it/web.rs, tests/it/gltf.rs) runs in `cargo test`.
# OCTOLOD_SKIP_WEB_TESTS=1 skips it, as it does those tests.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${OCTOLOD_SKIP_WEB_TESTS:-}" = 1 ]; then
  echo "web-ci: OCTOLOD_SKIP_WEB_TESTS=1: skipped" >&2
  exit 0
fi
node web/build.mjs --check
node --test web/test/page.test.mjs
