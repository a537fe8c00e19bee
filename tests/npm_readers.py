"""Where the independent npm readers are: ``node_tools/`` (installed by scripts/bootstrap.sh from the pinned
``scripts/node_tools/package.json`` and its lock), else where the check scripts install them, else the PATH.

Tests that need one skip with the reason when node or the package is absent (the bootstrap's npm step is optional:
a machine without node or without the npm registry still passes the rest).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
NODE_TOOLS = REPO / "node_tools"


def splat_transform() -> str:
    """The ``splat-transform`` executable (@playcanvas/splat-transform)."""
    if shutil.which("node") is None:
        pytest.skip("node is not installed (needed by @playcanvas/splat-transform)")
    candidates = [
        os.environ.get("HYBRIDSPLAT_SPLAT_TRANSFORM", ""),
        str(NODE_TOOLS / "node_modules" / ".bin" / "splat-transform"),
        "/tmp/hybridsplat-splat-transform/node_modules/.bin/splat-transform",
        shutil.which("splat-transform") or "",
    ]
    for c in candidates:
        if c and Path(c).is_file():
            return c
    pytest.skip("@playcanvas/splat-transform is not installed: run scripts/bootstrap.sh (needs npm)")


def gltf_tools_prefix() -> Path:
    """The npm prefix holding gltf-validator and @loaders.gl/3d-tiles (their ``node_modules`` is under it)."""
    if shutil.which("node") is None:
        pytest.skip("node is not installed")
    candidates = [os.environ.get("GT_PREFIX", ""), str(NODE_TOOLS), "/tmp/hybridsplat-gltf-tools"]
    for c in candidates:
        prefix = Path(c)
        needed = [prefix / "node_modules" / "gltf-validator", prefix / "node_modules" / "@loaders.gl" / "3d-tiles"]
        if c and all(p.is_dir() for p in needed):
            return prefix
    pytest.skip("gltf-validator / @loaders.gl/3d-tiles are not installed: run scripts/bootstrap.sh (needs npm)")


def cesium_build() -> Path:
    """CesiumJS's browser build (``Build/Cesium`` of npm ``cesium``: ``Cesium.js``, ``Workers/``, ``Assets/``…)."""
    candidates = [
        os.environ.get("HYBRIDSPLAT_CESIUM", ""),
        str(NODE_TOOLS / "node_modules" / "cesium" / "Build" / "Cesium"),
    ]
    for c in candidates:
        if c and (Path(c) / "Cesium.js").is_file():
            return Path(c)
    pytest.skip("CesiumJS (npm cesium) is not installed: run scripts/bootstrap.sh (needs npm)")
