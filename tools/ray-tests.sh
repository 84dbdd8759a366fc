#!/usr/bin/env bash
# octolod-ray's tests: a venv (default /tmp/octolod-ray-venv, or $1) with the
# package (python/octolod_ray, which pins ray) and pytest, then
# python/tests on a simulated 3-node Ray cluster on this machine. Uses
# target/debug (or release) octolod and octolod-gen ($OCTOLOD_BIN / $OCTOLOD_GEN_BIN
# override them); builds them with cargo only when they are missing.
# Arguments after the venv go to pytest (e.g. tools/ray-tests.sh "" -k resume).
#
# Needs CPython >= 3.10 with venv ($PYTHON, else python3.11, else python3;
# on Debian, as root, python3-venv is installed when missing) and PyPI.
set -euo pipefail
cd "$(dirname "$0")/.."

venv=${1:-}
venv=${venv:-/tmp/octolod-ray-venv}
shift $(( $# > 0 ? 1 : 0 ))

py=${PYTHON:-}
if [ -z "$py" ]; then
  if command -v python3.11 >/dev/null 2>&1; then py=python3.11; else py=python3; fi
fi
if ! "$py" -c 'import sys; sys.exit(sys.version_info < (3, 10))' 2>/dev/null; then
  echo "ray-tests: $py is missing or older than 3.10 (set PYTHON)" >&2
  exit 1
fi

if ! "$venv/bin/python" -m pip --version >/dev/null 2>&1; then
  # None yet, or a half-made one (Debian's venv without ensurepip leaves one).
  if [ -e "$venv" ] && [ ! -f "$venv/pyvenv.cfg" ]; then
    echo "ray-tests: $venv exists and is not a venv" >&2
    exit 1
  fi
  rm -rf "$venv"
  if ! "$py" -m venv "$venv" 2>/dev/null; then
    rm -rf "$venv"
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
      # Debian's python3 lacks ensurepip until python3-venv is installed.
      ver=$("$py" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')
      apt-get update -qq
      DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "python$ver-venv" >/dev/null ||
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq python3-venv >/dev/null
      "$py" -m venv "$venv"
    else
      echo "ray-tests: '$py -m venv' failed (on Debian: apt-get install python3-venv)" >&2
      exit 1
    fi
  fi
fi

"$venv/bin/python" -m pip install -q --disable-pip-version-check "./python/octolod_ray[test]"

tdir=${CARGO_TARGET_DIR:-target}
case $tdir in /*) ;; *) tdir=$PWD/$tdir ;; esac
# The binaries `cargo test` built (the dev profile is optimised), else release.
profile=debug
if [ ! -x "$tdir/debug/octolod" ] && [ -x "$tdir/release/octolod" ]; then profile=release; fi
export OCTOLOD_BIN=${OCTOLOD_BIN:-$tdir/$profile/octolod}
export OCTOLOD_GEN_BIN=${OCTOLOD_GEN_BIN:-$tdir/$profile/octolod-gen}
if [ ! -x "$OCTOLOD_BIN" ] || [ ! -x "$OCTOLOD_GEN_BIN" ]; then
  if ! command -v cargo >/dev/null 2>&1; then
    echo "ray-tests: $OCTOLOD_BIN or $OCTOLOD_GEN_BIN is missing and cargo is not installed" >&2
    exit 1
  fi
  echo "ray-tests: building octolod and octolod-gen (cargo build)" >&2
  cargo build --locked --bin octolod --bin octolod-gen
fi
for b in "$OCTOLOD_BIN" "$OCTOLOD_GEN_BIN"; do
  if [ ! -x "$b" ]; then
    echo "ray-tests: $b not found" >&2
    exit 1
  fi
done

# The tests make their own cluster: never one named by the environment.
unset RAY_ADDRESS
exec "$venv/bin/python" -m pytest -p no:cacheprovider -q python/tests "$@"
