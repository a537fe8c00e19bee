"""Every malformed input of :mod:`fuzz.cases` through the real command line, in a subprocess limited to
60 s and a 2 GB address space: a non-zero exit (2), one short line naming the file, no traceback, no
output left behind, and torch never imported (bad input is found before it). The fast subset runs in
``make test``; every case under ``make fuzz``."""

from __future__ import annotations

from pathlib import Path

import pytest

from fuzz.cases import all_cases
from fuzz.harness import heavy_imports, run_case

CASES = all_cases()


@pytest.mark.parametrize(
    "case", [c if c.fast else pytest.param(c, marks=pytest.mark.fuzz) for c in CASES], ids=[c.name for c in CASES]
)
def test_malformed_input_gives_one_clean_line(case, tmp_path: Path) -> None:
    outcome = run_case(case, tmp_path / "case", record_modules=True)
    assert outcome.code is not None, f"{case.name}: killed after {outcome.seconds:.0f} s (hang)"
    assert outcome.verdict == "clean", (
        f"{case.name}: {outcome.verdict}, exit {outcome.code}, leftovers {outcome.leftovers}\n{outcome.stderr}"
    )
    assert outcome.modules is not None and "hybridsplat.cli" in outcome.modules, "the module list was not recorded"
    assert "torch" not in heavy_imports(outcome.modules), f"{case.name}: torch imported before the error"


def test_fast_subset_covers_the_issue_families() -> None:
    """The normal test run exercises every file family named in the issue; names are unique."""
    fast = {c.name.split("-")[0] for c in CASES if c.fast}
    assert {"ply", "las", "laz", "colmap", "sidecar", "gs", "export", "metrics", "usage"} <= fast
    assert len({c.name for c in CASES}) == len(CASES)
