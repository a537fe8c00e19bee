"""Options of the evaluation report (:mod:`eval.report`), without its plotting imports."""

from __future__ import annotations

from dataclasses import dataclass

DEFAULT_MAX_PANELS = 4


@dataclass(frozen=True)
class ReportOptions:
    """max_panels: render | photo | error panels shown per product (its lowest-PSNR held-out views)."""

    max_panels: int = DEFAULT_MAX_PANELS
