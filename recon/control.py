"""Survey control: a sparse model brought to ground control points and adjusted with them held, check points
measured afterwards.

:func:`adjust_to_control` works on a ``pycolmap.Reconstruction`` in place:

1. each control point is triangulated from its marks with the model's cameras (:func:`triangulate_marks`: a
   linear multi-view DLT on undistorted normalised rays, refined by least squares on the reprojection error;
   marks further than ``max_mark_error_px`` from the refined point's projection are dropped, worst first);
2. a similarity (:func:`recon.align.ransac_similarity`) takes the model onto the surveyed control coordinates (a
   local frame: survey coordinates minus ``origin``);
3. a bundle adjustment (pycolmap, Ceres) in which the control points are extra 3D points, their marks ordinary
   observations and their coordinates held constant: the cameras, the intrinsics (optionally) and the tie points
   move to agree with them; the control points are then removed from the model again;
4. every point, control and check, is triangulated again from its marks with the adjusted cameras; its residual
   (model minus survey, metres), its number of marks and its reprojection RMS (px) are what the accuracy
   statement (:mod:`eval.accuracy`) is made of. Check points never enter steps 2 and 3.

Marks are in COLMAP's pixel convention (top-left pixel centre at (0.5, 0.5)), as pycolmap's cameras expect.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from core.errors import DataError, ReconstructionError
from recon.align import AlignmentResult, ransac_similarity, transform_reconstruction


@dataclass(frozen=True)
class ControlOptions:
    """Options of the adjustment to control.

    adjust: run the bundle adjustment held to control (False: the similarity only). refine_focal_length,
    refine_extra_params: let the adjustment refine the intrinsics (the principal point stays fixed).
    max_mark_error_px: marks further than this from their point's reprojection are dropped (a wrong or smeared
    detection). align_threshold_m: RANSAC inlier distance of the similarity (metres; default 5 % of the control
    points' extent). loss_px: Cauchy loss scale of the adjustment (px), as in the SfM refinement.
    """

    adjust: bool = True
    refine_focal_length: bool = True
    refine_extra_params: bool = True
    max_mark_error_px: float = 3.0
    align_threshold_m: float | None = None
    loss_px: float = 1.0


@dataclass(frozen=True)
class ImageMark:
    """A mark on a registered image of the model: ``image_id``, ``uv`` (2,) float64 px (COLMAP convention)."""

    image_id: int
    uv: np.ndarray


@dataclass(frozen=True)
class Triangulated:
    """A point triangulated from its marks: ``xyz`` (3,) float64 model frame, ``used`` marks kept (indices into
    the marks given), ``reprojection_px`` RMS of the kept marks (px)."""

    xyz: np.ndarray
    used: tuple[int, ...]
    reprojection_px: float


@dataclass(frozen=True)
class MeasuredPoint:
    """A surveyed point after the adjustment: its ``id`` and ``role``, ``survey`` and ``model`` coordinates (3,)
    float64 in the control frame (metres), ``marks`` used, ``reprojection_px``; ``model`` is NaN when fewer than
    two marks were usable."""

    id: str
    role: str
    survey: np.ndarray
    model: np.ndarray
    marks: int
    reprojection_px: float


@dataclass
class ControlReport:
    """What :func:`adjust_to_control` did: the ``alignment`` (similarity onto the control points), the adjustment's
    ``initial_cost`` / ``final_cost`` (Ceres), the per-point results and the marks dropped (point id → count)."""

    alignment: AlignmentResult | None = None
    adjusted: bool = False
    initial_cost: float = math.nan
    final_cost: float = math.nan
    points: list[MeasuredPoint] = field(default_factory=list)
    dropped_marks: dict[str, int] = field(default_factory=dict)


def _projections(rec, image_ids: Sequence[int]) -> list[tuple[np.ndarray, object]]:
    out = []
    for i in image_ids:
        image = rec.image(i)
        out.append((np.asarray(image.cam_from_world().matrix(), dtype=np.float64), image.camera))
    return out


def _reproject(xyz: np.ndarray, proj: list[tuple[np.ndarray, object]]) -> np.ndarray:
    """(N, 2) pixels of one point in N images (NaN where it is behind a camera)."""
    out = np.full((len(proj), 2), np.nan)
    for k, (P, camera) in enumerate(proj):
        pc = P[:, :3] @ xyz + P[:, 3]
        if pc[2] > 0:
            out[k] = np.asarray(camera.img_from_cam(pc[None, :]), dtype=np.float64).reshape(2)
    return out


def _dlt(rays: np.ndarray, proj: list[tuple[np.ndarray, object]]) -> np.ndarray:
    rows = []
    for (x, y), (P, _) in zip(rays, proj, strict=True):
        rows += [x * P[2] - P[0], y * P[2] - P[1]]
    _, _, vt = np.linalg.svd(np.asarray(rows))
    h = vt[-1]
    return h[:3] / h[3] if abs(h[3]) > 1e-15 else np.full(3, np.nan)


def _refine(xyz: np.ndarray, uv: np.ndarray, proj: list[tuple[np.ndarray, object]]) -> np.ndarray:
    from scipy.optimize import least_squares

    def residual(p: np.ndarray) -> np.ndarray:
        r = _reproject(p, proj) - uv
        return np.nan_to_num(r, nan=1e6).ravel()

    scale = max(float(np.linalg.norm(xyz)), 1.0)
    return least_squares(residual, xyz, x_scale=scale, xtol=1e-14, ftol=1e-14, gtol=1e-14, method="lm").x


def triangulate_marks(rec, marks: Sequence[ImageMark], max_error_px: float = math.inf) -> Triangulated | None:
    """A point from its marks on registered images of ``rec`` (module docstring, step 1); None with fewer than two
    usable marks."""
    keep = list(range(len(marks)))
    while len(keep) >= 2:
        sub = [marks[k] for k in keep]
        proj = _projections(rec, [m.image_id for m in sub])
        uv = np.stack([m.uv for m in sub])
        rays = np.stack([np.asarray(c.cam_from_img(u[None, :]), dtype=np.float64).reshape(2) for u, (_, c) in
                         zip(uv, proj, strict=True)])  # fmt: skip
        xyz = _dlt(rays, proj)
        if not np.isfinite(xyz).all():
            return None
        xyz = _refine(xyz, uv, proj)
        err = np.linalg.norm(_reproject(xyz, proj) - uv, axis=1)
        err = np.where(np.isfinite(err), err, np.inf)
        worst = int(np.argmax(err))
        if err[worst] <= max_error_px:
            return Triangulated(xyz, tuple(keep), float(np.sqrt(np.mean(err**2))))
        keep.pop(worst)
    return None


def _align(rec, points: Mapping[str, np.ndarray], marks, options: ControlOptions, report: ControlReport):
    src, dst, ids = [], [], []
    for pid, survey in points.items():
        tri = triangulate_marks(rec, marks.get(pid, ()), options.max_mark_error_px)
        if tri is not None:
            src.append(tri.xyz)
            dst.append(survey)
            ids.append(pid)
    if len(ids) < 3:
        raise ReconstructionError(
            f"the model needs >= 3 control points with >= 2 usable marks each to be brought to control, got "
            f"{len(ids)} ({', '.join(ids) or 'none'})"
        )
    dst_a = np.asarray(dst)
    threshold = options.align_threshold_m
    if threshold is None:
        threshold = max(0.05 * float(np.linalg.norm(dst_a.max(axis=0) - dst_a.min(axis=0))), 1e-6)
    result = ransac_similarity(np.asarray(src), dst_a, float(threshold))
    transform_reconstruction(rec, result.transform)
    report.alignment = result


def _add_control_points(rec, points: Mapping[str, np.ndarray], marks) -> list[int]:
    """Add each control point with its marks as observations; their 3D ids. A mark takes the place of a keypoint of
    its image that belongs to no 3D point (COLMAP keeps every keypoint; pycolmap cannot append one to a registered
    image), so only such unused keypoints' coordinates change in the model."""
    import pycolmap

    free = {i: [k for k, p in enumerate(rec.image(i).points2D) if not p.has_point3D()] for i in rec.reg_image_ids()}
    added = []
    for pid, xyz in points.items():
        obs = [m for m in marks.get(pid, ()) if free.get(m.image_id)]
        if len(obs) < 2:
            continue
        point_id = rec.add_point3D(np.asarray(xyz, np.float64), pycolmap.Track(), np.zeros(3, np.uint8))
        for m in obs:
            slot = free[m.image_id].pop()
            rec.image(m.image_id).point2D(slot).xy = np.asarray(m.uv, np.float64)
            rec.add_observation(point_id, pycolmap.TrackElement(m.image_id, slot))
        added.append(point_id)
    return added


def _bundle_adjust(rec, constant_points: Sequence[int], options: ControlOptions, report: ControlReport) -> None:
    import pycolmap

    config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.reg_image_ids():
        config.add_image(image_id)
    for point_id in constant_points:
        config.add_constant_point(point_id)
    ba = pycolmap.BundleAdjustmentOptions()
    ba.refine_principal_point = False
    ba.refine_focal_length = options.refine_focal_length
    ba.refine_extra_params = options.refine_extra_params
    ba.print_summary = False
    ba.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    ba.ceres.loss_function_scale = float(options.loss_px)
    solver = ba.ceres.solver_options
    solver.max_num_iterations = 200
    solver.function_tolerance = solver.gradient_tolerance = solver.parameter_tolerance = 1e-12
    solver.num_threads = 1  # deterministic sums
    adjuster = pycolmap.create_default_bundle_adjuster(ba, config, rec)
    summary = adjuster.solve()
    ceres = summary.ceres_summary
    report.initial_cost, report.final_cost = float(ceres.initial_cost), float(ceres.final_cost)
    report.adjusted = True


def adjust_to_control(
    rec,
    marks: Mapping[str, Sequence[ImageMark]],
    survey: Mapping[str, tuple[str, np.ndarray]],
    options: ControlOptions | None = None,
) -> ControlReport:
    """Bring ``rec`` to control and adjust it with the control points held (module docstring), in place.

    marks: point id → its marks on registered images. survey: point id → (role ``control`` | ``check``, (3,)
    float64 surveyed coordinates in the local control frame, metres). Returns the report with every surveyed
    point measured with the final cameras.
    """
    options = options or ControlOptions()
    report = ControlReport()
    control = {pid: np.asarray(xyz, np.float64) for pid, (role, xyz) in survey.items() if role == "control"}
    if not control:
        raise DataError("the control file holds no point with role 'control'")
    _align(rec, control, marks, options, report)
    if options.adjust:
        kept = {}
        for pid in control:  # only marks that agree with the point (the same rule as the alignment's)
            tri = triangulate_marks(rec, marks.get(pid, ()), options.max_mark_error_px)
            if tri is not None:
                kept[pid] = [marks[pid][k] for k in tri.used]
        added = _add_control_points(rec, control, kept)
        _bundle_adjust(rec, added, options, report)
        for point_id in added:
            rec.delete_point3D(point_id)
    report.points, report.dropped_marks = measure_points(rec, marks, survey, options.max_mark_error_px)
    return report


def measure_points(
    rec, marks: Mapping[str, Sequence[ImageMark]], survey: Mapping[str, tuple[str, np.ndarray]], max_error_px: float
) -> tuple[list[MeasuredPoint], dict[str, int]]:
    """Every surveyed point triangulated from its marks with ``rec``'s cameras (NaN where it cannot be), and the
    marks dropped per point."""
    points, dropped = [], {}
    for pid, (role, xyz) in survey.items():
        obs = marks.get(pid, ())
        tri = triangulate_marks(rec, obs, max_error_px)
        model = tri.xyz if tri is not None else np.full(3, np.nan)
        used = len(tri.used) if tri is not None else 0
        if len(obs) - used:
            dropped[pid] = len(obs) - used
        rms = tri.reprojection_px if tri is not None else math.nan
        points.append(MeasuredPoint(pid, role, np.asarray(xyz, np.float64), model, used, rms))
    return points, dropped
