"""The full fuzz set runs only when asked for (``make fuzz`` = ``pytest -m fuzz tests/fuzz``).

Cases marked ``fuzz`` are skipped unless the ``-m`` expression names the marker; the fast subset
(unmarked) runs with the normal tests.
"""

from __future__ import annotations

import pytest


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if "fuzz" in (config.option.markexpr or ""):
        return
    skip = pytest.mark.skip(reason="full fuzz set: run with `make fuzz` (pytest -m fuzz)")
    for item in items:
        if item.get_closest_marker("fuzz") is not None:
            item.add_marker(skip)
