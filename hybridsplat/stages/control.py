"""Stage ``control``: the sparse model held to ground control points, and the accuracy statement of its check points
(PROJECT/control).

With ``--control gcp.csv`` (and optionally ``--marks marks.csv``): coded targets are detected in the registered
photos (:mod:`recon.targets`), manual marks replace or add to them, the model is brought to the control points and
adjusted with them held (:mod:`recon.control`), and every point is measured with the adjusted cameras. The adjusted
model is ``control/sparse`` (in the control frame, around ``origin``), which every later stage reads
(:func:`hybridsplat.project_io.sparse_model`); ``control/accuracy.json`` holds the statement (:mod:`eval.accuracy`),
``control/marks.csv`` every mark used, ``control/residuals.png`` the check points' residuals over the site. Without
``--control`` the stage is skipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import DataError
from core.io.json_io import write_json_atomic
from hybridsplat.stages.base import ReportSection, Stage, StageContext, StageResult, omitted_if_none
from recon.control import ControlOptions


@dataclass(frozen=True)
class ControlResult(StageResult):
    """What the control stage made: ``control_points`` and ``check_points`` in the GCP file, ``marks`` used
    (``detected`` by the target detector, ``manual`` from the marks file), the similarity's RMS over the control
    points (m), whether the model was ``adjusted`` (bundle adjustment held to control), the check points' RMSE_H,
    RMSE_V and RMSE_3D (m, ASPRS Edition 2, survey sigma folded in; None without a measured check point), whether
    the statement is ``informal`` (fewer than 30 check points), and the points not measured (id → why)."""

    control_points: int = 0
    check_points: int = 0
    marks: int = 0
    detected: int = 0
    manual: int = 0
    alignment_rms_m: float = 0.0
    adjusted: bool = False
    rmse_h_m: float | None = omitted_if_none()
    rmse_v_m: float | None = omitted_if_none()
    rmse_3d_m: float | None = omitted_if_none()
    informal: bool = True
    unmeasured: dict[str, str] = field(default_factory=dict)


class ControlStage(Stage):
    name = "control"
    Options = ControlOptions
    Result = ControlResult
    title = "survey control and check points"
    uses_seed = False

    def inputs(self, ctx: StageContext) -> list[Path]:
        extra = [Path(p) for p in (ctx.config.input.control, ctx.config.input.marks) if p]
        return [ctx.layout.sparse, ctx.layout.record("sfm"), ctx.source.image_dir, *extra]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.control_dir, ctx.layout.record(self.name)]

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of control/: the sparse model again (its size on disk), 64 KiB of marks, statement and record, and
        the residual plot (at most 512 KiB)."""
        from hybridsplat.disk_space import tree_bytes

        return tree_bytes([ctx.layout.sparse]) + 64 * 1024 + 512 * 1024

    def needs(self, ctx: StageContext) -> str | None:
        if not ctx.config.input.control:
            return "no --control file of ground control points"
        return None

    def run(self, ctx: StageContext) -> ControlResult:
        from hybridsplat.stages.control_run import run_control

        return run_control(ctx, ctx.options(self))

    def summary(self, result: ControlResult) -> str:
        text = f"{result.control_points} control, {result.check_points} check points, {result.marks} marks"
        if result.rmse_h_m is not None and result.rmse_v_m is not None:
            text += f"; check RMSE_H {result.rmse_h_m:.3g} m, RMSE_V {result.rmse_v_m:.3g} m"
        return text

    def report_section(self, result: ControlResult) -> ReportSection | None:
        lines = [
            f"{result.control_points} control points held and {result.check_points} check points measured, from "
            f"{result.marks} marks ({result.detected} detected, {result.manual} manual); similarity RMS over the "
            f"control points {result.alignment_rms_m:.3g} m; "
            + ("bundle adjustment held to control." if result.adjusted else "no bundle adjustment."),
        ]
        lines += [f"not measured: {pid} ({why})" for pid, why in sorted(result.unmeasured.items())]
        return ReportSection("Survey control", tuple(lines))


def _finite(value: float) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def check_marks_in_photos(marks, sizes: dict[str, tuple[int, int]], known: set[str], path: Path) -> None:
    """DataError naming ``path`` and the line of the first manual mark on an unknown photo or point, or outside
    its photo (pixels of COLMAP's convention lie in [0, width] × [0, height])."""
    for m in marks:
        if m.point_id not in known:
            raise DataError(f"line {m.line}: point {m.point_id!r} is not in the control file", path)
        if m.image not in sizes:
            raise DataError(f"line {m.line}: photo {m.image!r} is not a registered photo of the project", path)
        w, h = sizes[m.image]
        if not (0 <= m.uv[0] <= w and 0 <= m.uv[1] <= h):
            raise DataError(
                f"line {m.line}: mark ({m.uv[0]:g}, {m.uv[1]:g}) lies outside photo {m.image} ({w} x {h} px)", path
            )


def statement_payload(statement: Any, origin: np.ndarray, units: str, crs: str | None) -> dict[str, Any]:
    """``accuracy.json``: the statement plus the frame it is in (origin, units for display, CRS)."""
    return {**statement.to_json(), "origin": [float(v) for v in origin], "units": units, "crs": crs}


def write_record(ctx: StageContext, origin: np.ndarray, payload: dict[str, Any]) -> None:
    write_json_atomic(ctx.layout.record("control"), {"origin": [float(v) for v in origin], **payload})
