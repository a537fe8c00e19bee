"""The control stage's work (:mod:`hybridsplat.stages.control`): read the GCP and marks files, detect targets,
adjust the model to control, measure every point, write control/ and the statement."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np

from core.errors import DataError
from hybridsplat.stages.base import StageContext
from hybridsplat.stages.control import (
    ControlResult,
    _finite,
    check_marks_in_photos,
    statement_payload,
    write_record,
)
from recon.control import ControlOptions


def _registered(rec) -> tuple[dict[str, int], dict[str, tuple[int, int]]]:
    images = {rec.image(i).name: int(i) for i in rec.reg_image_ids()}
    sizes = {n: (int(rec.image(i).camera.width), int(rec.image(i).camera.height)) for n, i in images.items()}
    return images, sizes


def _marks(ctx: StageContext, gcp, images: dict[str, int], sizes: dict[str, tuple[int, int]]):
    """Detected marks of the GCP file's points, with the manual ones over them; (marks, detected, manual)."""
    from core.io.control import merge_marks, read_marks_csv
    from recon.targets import detect_marks

    known = set(gcp.by_id())
    manual: tuple = ()
    if ctx.config.input.marks:
        path = Path(ctx.config.input.marks)
        manual = read_marks_csv(path)
        check_marks_in_photos(manual, sizes, known, path)
    names = sorted(images)

    def progress(done: int) -> None:
        ctx.progress("detecting coded targets", done, len(names))

    detected = [m for m in detect_marks(((n, ctx.source.image_dir / n) for n in names), progress=progress)
                if m.point_id in known]  # fmt: skip
    return merge_marks(detected, manual), detected, manual


def _write_model(rec, out_dir: Path) -> None:
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    try:
        rec.write(str(tmp))
        tmp.rename(out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def run_control(ctx: StageContext, options: ControlOptions) -> ControlResult:
    """The stage's run (module docstring)."""
    from core.io.control import read_gcp_csv, write_marks_csv
    from core.io.json_io import write_json_atomic
    from eval.accuracy import PointResidual, accuracy_statement
    from recon.align import local_origin
    from recon.control import ImageMark, adjust_to_control
    from recon.model import read_reconstruction

    inp, layout = ctx.config.input, ctx.layout
    gcp_path = Path(str(inp.control))
    gcp = read_gcp_csv(gcp_path, inp.units, inp.crs)
    rec = read_reconstruction(layout.sparse)
    images, sizes = _registered(rec)
    marks, detected, manual = _marks(ctx, gcp, images, sizes)
    by_point: dict[str, list[ImageMark]] = {}
    for m in marks:
        by_point.setdefault(m.point_id, []).append(ImageMark(images[m.image], m.uv))
    unmeasured = {}
    for p in gcp.points:
        n = len(by_point.get(p.id, ()))
        if n < 2 and inp.marks:  # a person marked the points: each needs two photos
            raise DataError(
                f"line {p.line}: point {p.id!r} has {n} mark(s) in the photos; it needs at least 2", gcp_path
            )
        if n < 2:
            unmeasured[p.id] = f"{n} mark(s) found, 2 needed"
    origin = local_origin(np.stack([p.xyz_m for p in gcp.points]))
    survey = {p.id: (p.role.value, p.xyz_m - origin) for p in gcp.points}
    ctx.progress("adjustment held to control", 0, 1)
    report = adjust_to_control(rec, by_point, survey, options)
    ctx.progress("adjustment held to control", 1, 1)
    layout.control_dir.mkdir(parents=True, exist_ok=True)
    _write_model(rec, layout.control_sparse)
    write_marks_csv(layout.control_marks, marks)
    points = {p.id: p for p in gcp.points}
    residuals = []
    for mp in report.points:
        if not np.isfinite(mp.model).all():
            unmeasured.setdefault(mp.id, "its marks disagree (no two within the mark tolerance)")
            continue
        d = mp.model - mp.survey
        cp = points[mp.id]
        survey_m = tuple(float(v) for v in mp.survey)
        residuals.append(PointResidual(mp.id, mp.role, survey_m, float(d[0]), float(d[1]), float(d[2]), mp.marks,
                                       mp.reprojection_px, cp.sigma_xy_m, cp.sigma_z_m))  # fmt: skip
    statement = accuracy_statement(residuals)
    payload = statement_payload(statement, origin, gcp.units.value, gcp.crs)
    write_json_atomic(layout.control_accuracy, payload)
    write_record(ctx, origin, {"alignment_rms_m": report.alignment.rms_inliers, "dropped_marks": report.dropped_marks,
                               "initial_cost": report.initial_cost, "final_cost": report.final_cost})  # fmt: skip
    roles = [p.role.value for p in gcp.points]
    return ControlResult(
        control_points=roles.count("control"),
        check_points=roles.count("check"),
        marks=len(marks),
        detected=len(detected),
        manual=len(manual),
        alignment_rms_m=float(report.alignment.rms_inliers),
        adjusted=report.adjusted,
        rmse_h_m=_finite(statement.rmse_h),
        rmse_v_m=_finite(statement.rmse_v),
        rmse_3d_m=_finite(statement.rmse_3d),
        informal=statement.informal,
        unmeasured=unmeasured,
    )
