#!/usr/bin/env bash
# Installs what the tests need beyond the Rust toolchain: a Vulkan driver
# that renders without a GPU or display (Mesa's lavapipe, Debian/Ubuntu
# package mesa-vulkan-drivers), for the viewer's headless rendering tests.
# Does nothing when a lavapipe ICD is already installed.
set -euo pipefail
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
