"""No test skips itself because one of the project's own modules fails to import: that hides a broken module as a
skip. ``pytest.importorskip`` is for optional third-party packages only (gsplat, CUDA builds)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OWN_PACKAGES = ("core", "data_synth", "recon", "classify", "fusion", "eval", "hybridsplat")
CALL = re.compile(r"importorskip\(\s*[\"']([A-Za-z_][\w.]*)[\"']")


def test_no_test_importorskips_the_projects_own_modules():
    offenders = []
    for path in sorted((ROOT / "tests").rglob("*.py")):
        if path == Path(__file__).resolve():  # its own example below
            continue
        for lineno, line in enumerate(path.read_text().splitlines(), 1):
            for module in CALL.findall(line):
                if module.split(".")[0] in OWN_PACKAGES:
                    offenders.append(f"{path.relative_to(ROOT)}:{lineno}: {module}")
    assert not offenders, "importorskip of the project's own modules:\n" + "\n".join(offenders)


def test_the_pattern_finds_an_importorskip_call():
    assert CALL.findall('x = pytest.importorskip("fusion.render", reason="r")') == ["fusion.render"]
