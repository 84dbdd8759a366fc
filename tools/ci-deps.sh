#!/usr/bin/env bash
# Installs what the tests need beyond the Rust toolchain: a Vulkan driver
# that renders without a GPU or display (Mesa's lavapipe, Debian/Ubuntu
# package mesa-vulkan-drivers), for the viewer's headless rendering tests.
# Does nothing when a lavapipe ICD is already installed.
set -euo pipefail
if ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1; then
  exit 0
fi
if [ "${OCTOLOD_SKIP_GPU_TESTS:-}" = 1 ]; then
  echo "ci-deps: no lavapipe, OCTOLOD_SKIP_GPU_TESTS=1: GPU tests will be skipped" >&2
  exit 0
fi
SUDO=""
if [ "$(id -u)" != 0 ]; then
  if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
    echo "ci-deps: need root (or sudo) to apt-get install mesa-vulkan-drivers" >&2; exit 1
  fi
fi
if ! command -v apt-get >/dev/null 2>&1; then
  echo "ci-deps: no apt-get: install Mesa's lavapipe Vulkan driver yourself" \
       "(or set OCTOLOD_SKIP_GPU_TESTS=1 to skip the rendering tests)" >&2
  exit 1
fi
echo "ci-deps: installing mesa-vulkan-drivers (lavapipe) for headless rendering tests" >&2
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends mesa-vulkan-drivers libvulkan1 >/dev/null
