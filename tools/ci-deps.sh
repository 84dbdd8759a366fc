#!/usr/bin/env bash
# Installs what the tests need beyond the Rust toolchain: a Vulkan driver
# that renders without a GPU or display (Mesa's lavapipe, Debian/Ubuntu
# package mesa-vulkan-drivers), for the viewer's headless rendering tests;
# for the browser viewer's tests (web/), Chromium, Node.js (18 or newer)
# and npm, then web/'s locked npm packages (`npm ci --prefix web`, when
# web/node_modules is missing or older than web/package-lock.json).
# Installs only what is missing; OCTOLOD_SKIP_WEB_TESTS=1 skips the web part.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
apt_install() {
  local sudo=""
  if [ "$(id -u)" != 0 ]; then
    if command -v sudo >/dev/null 2>&1; then sudo="sudo"; else
      echo "ci-deps: need root (or sudo) to apt-get install $*" >&2; exit 1
    fi
  fi
  if ! command -v apt-get >/dev/null 2>&1; then
    echo "ci-deps: no apt-get: install $* yourself" >&2; exit 1
  fi
  export DEBIAN_FRONTEND=noninteractive
  $sudo apt-get update -qq
  $sudo apt-get install -y -qq --no-install-recommends "$@" >/dev/null
}
# The meshopt crate compiles meshoptimizer's C++ (the collapse simplifier).
if ! command -v c++ >/dev/null 2>&1 && ! command -v g++ >/dev/null 2>&1; then
  echo "ci-deps: installing g++ for meshoptimizer" >&2
  apt_install g++
fi
# The browser viewer's tests: headless Chromium driven by web/test/shoot.mjs.
if [ "${OCTOLOD_SKIP_WEB_TESTS:-}" != 1 ]; then
  web_pkgs=()
  if ! [ -x /usr/lib/chromium/chromium ] && ! command -v chromium >/dev/null 2>&1; then
    web_pkgs+=(chromium)
  fi
  if ! command -v node >/dev/null 2>&1; then
    web_pkgs+=(nodejs)
    command -v npm >/dev/null 2>&1 || web_pkgs+=(npm)
  elif ! command -v npm >/dev/null 2>&1; then
    web_pkgs+=(npm)
  fi
  if [ ${#web_pkgs[@]} -gt 0 ]; then
    echo "ci-deps: installing ${web_pkgs[*]} for the browser viewer's tests" >&2
    apt_install "${web_pkgs[@]}"
  fi
  node_major="$(node -p 'process.versions.node.split(".")[0]')"
  if [ "$node_major" -lt 18 ]; then
    echo "ci-deps: node $(node --version) is too old for web/ (needs 18 or newer)" >&2; exit 1
  fi
  if ! [ -f "$root/web/node_modules/.package-lock.json" ] \
     || [ "$root/web/package-lock.json" -nt "$root/web/node_modules/.package-lock.json" ]; then
    echo "ci-deps: npm ci --prefix web" >&2
    npm ci --prefix "$root/web" --no-audit --no-fund --loglevel=error >&2
  fi
fi
if ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1; then
  exit 0
fi
if [ "${OCTOLOD_SKIP_GPU_TESTS:-}" = 1 ]; then
  echo "ci-deps: no lavapipe, OCTOLOD_SKIP_GPU_TESTS=1: GPU tests will be skipped" >&2
  exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
  echo "ci-deps: no apt-get: install Mesa's lavapipe Vulkan driver yourself" \
       "(or set OCTOLOD_SKIP_GPU_TESTS=1 to skip the rendering tests)" >&2
  exit 1
fi
echo "ci-deps: installing mesa-vulkan-drivers (lavapipe) for headless rendering tests" >&2
apt_install mesa-vulkan-drivers libvulkan1
