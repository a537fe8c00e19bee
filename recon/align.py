"""Robust similarity alignment (7-DoF: scale, rotation, translation) between corresponding 3D points.

Used to bring an SfM model into a reference frame from camera centres (GNSS, known cameras) or ground control
points: RANSAC over minimal 3-point samples (Umeyama on each), then a least-squares Umeyama fit on the
inliers, with per-point residuals reported. Umeyama (1991), "Least-squares estimation of transformation
parameters between two point patterns", closed form via SVD; written here because it is ten lines and
pycolmap's own alignment works on whole reconstructions, not on arbitrary point sets (GCPs).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from core.errors import DataError, ReconstructionError


@dataclass(frozen=True)
class Similarity:
    """``x_dst = scale · R @ x_src + t`` (R (3, 3) float64 proper rotation, t (3,) float64 metres)."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform points (N, 3) float64."""
        return self.scale * np.asarray(points, dtype=np.float64) @ self.rotation.T + self.translation

    def inverse(self) -> Similarity:
        Rt = self.rotation.T
        return Similarity(1.0 / self.scale, Rt, -(Rt @ self.translation) / self.scale)

    def matrix(self) -> np.ndarray:
        """3×4 matrix [s·R | t]."""
        return np.concatenate([self.scale * self.rotation, self.translation[:, None]], axis=1)


@dataclass(frozen=True)
class AlignmentResult:
    """A fitted similarity and how well it fits.

    residuals: (N,) float64 distances |T(src) − dst| in the destination frame (metres) for every pair;
    inliers: (N,) bool; rms_inliers: root mean square residual of the inliers.
    """

    transform: Similarity
    residuals: np.ndarray
    inliers: np.ndarray
    rms_inliers: float

    @property
    def num_inliers(self) -> int:
        return int(self.inliers.sum())


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True, weights: np.ndarray | None = None) -> Similarity:
    """Least-squares similarity mapping ``src`` (N, 3) onto ``dst`` (N, 3), N ≥ 3 non-collinear points."""
    src = np.asarray(src, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(dst, dtype=np.float64).reshape(-1, 3)
    if len(src) != len(dst) or len(src) < 3:
        raise DataError(f"similarity needs >= 3 corresponding points, got {len(src)} and {len(dst)}")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    mu_s, mu_d = w @ src, w @ dst
    xs, xd = src - mu_s, dst - mu_d
    cov = (xd * w[:, None]).T @ xs
    U, S, Vt = np.linalg.svd(cov)
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    var_s = float(w @ (xs * xs).sum(axis=1))
    scale = float(np.trace(np.diag(S) @ D) / var_s) if with_scale and var_s > 0 else 1.0
    t = mu_d - scale * R @ mu_s
    return Similarity(scale, R, t)


def _degenerate(p: np.ndarray) -> bool:
    """Three points nearly collinear (triangle area tiny relative to its sides)."""
    a, b = p[1] - p[0], p[2] - p[0]
    return np.linalg.norm(np.cross(a, b)) < 1e-9 * max(np.dot(a, a), np.dot(b, b), 1e-300)


def ransac_similarity(
    src: np.ndarray,
    dst: np.ndarray,
    threshold: float,
    iterations: int = 1000,
    seed: int = 0,
    with_scale: bool = True,
    min_inliers: int = 3,
) -> AlignmentResult:
    """Robust similarity: RANSAC on 3-point samples, then Umeyama on the inliers (refit until stable).

    threshold: inlier distance in the destination frame (metres). With fewer than 3 pairs raises
    :class:`DataError`; when no sample reaches ``min_inliers`` raises :class:`ReconstructionError`.
    """
    src = np.asarray(src, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(dst, dtype=np.float64).reshape(-1, 3)
    n = len(src)
    if n != len(dst) or n < 3:
        raise DataError(f"alignment needs >= 3 corresponding points, got {n} and {len(dst)}")
    if not (np.isfinite(src).all() and np.isfinite(dst).all()):
        raise DataError("alignment points contain NaN or infinite coordinates")
    rng = np.random.default_rng(seed)
    best_inl = np.zeros(n, dtype=bool)
    best_err = np.inf
    samples = [np.arange(3)] if n == 3 else (rng.choice(n, 3, replace=False) for _ in range(iterations))
    for idx in samples:
        if _degenerate(src[idx]) or _degenerate(dst[idx]):
            continue
        T = umeyama(src[idx], dst[idx], with_scale)
        res = np.linalg.norm(T.apply(src) - dst, axis=1)
        inl = res <= threshold
        err = float(np.sum(np.minimum(res, threshold) ** 2))  # MSAC score
        if inl.sum() > best_inl.sum() or (inl.sum() == best_inl.sum() and err < best_err):
            best_inl, best_err = inl, err
    if best_inl.sum() < max(3, min_inliers):
        raise ReconstructionError(
            f"no similarity fits >= {max(3, min_inliers)} of {n} point pairs within {threshold:g} m "
            "(wrong correspondences, or threshold too small)"
        )
    inl = best_inl
    for _ in range(10):
        T = umeyama(src[inl], dst[inl], with_scale)
        res = np.linalg.norm(T.apply(src) - dst, axis=1)
        new = res <= threshold
        if new.sum() < 3 or np.array_equal(new, inl):
            break
        inl = new
    rms = float(np.sqrt(np.mean(res[inl] ** 2)))
    return AlignmentResult(T, res, inl, rms)


def transform_reconstruction(rec, sim: Similarity) -> None:
    """Apply a similarity to a ``pycolmap.Reconstruction`` in place (poses and points)."""
    import pycolmap

    from core.cameras import rotmat_to_quat

    q = rotmat_to_quat(sim.rotation)
    rot = pycolmap.Rotation3d(np.array([q[1], q[2], q[3], q[0]]))
    rec.transform(pycolmap.Sim3d(sim.scale, rot, sim.translation))


def align_reconstruction_to_centers(
    rec,
    reference_centers: dict[str, np.ndarray],
    threshold: float,
    seed: int = 0,
) -> AlignmentResult:
    """Align a ``pycolmap.Reconstruction`` in place so that its camera centres match ``reference_centers``.

    reference_centers: image name -> (3,) float64 centre in the reference frame (metres). Residuals are per
    common image, in the order of ``sorted(common names)``.
    """
    names = sorted(rec.image(i).name for i in rec.reg_image_ids())
    common = [n for n in names if n in reference_centers]
    if len(common) < 3:
        raise ReconstructionError(f"alignment needs >= 3 registered images with reference centres, got {len(common)}")
    by_name = {rec.image(i).name: rec.image(i) for i in rec.reg_image_ids()}
    src = np.stack([np.asarray(by_name[n].projection_center()) for n in common])
    dst = np.stack([np.asarray(reference_centers[n], dtype=np.float64) for n in common])
    result = ransac_similarity(src, dst, threshold, seed=seed)
    transform_reconstruction(rec, result.transform)
    return result


@dataclass(frozen=True)
class ReferenceAlignment:
    """An SfM model aligned to a reference (``--reference``).

    origin: (3,) float64 world coordinates (metres) of the local frame the aligned model is written in (zeros
    for references near the origin; the rounded centroid of the reference centres for georeferenced ones, so that
    float32 products such as fused.ply keep millimetres). result: the fit, with residuals in metres.
    threshold_m: the RANSAC inlier distance used.
    """

    result: AlignmentResult
    origin: np.ndarray
    threshold_m: float


# Coordinates beyond this (metres) are georeferenced (UTM: ~1e5-1e7): the model gets a local origin, because
# float32 (fused.ply, GPU) resolves only ~1 m at 1e7 m.
LOCAL_ORIGIN_ABOVE_M = 1e4


def local_origin(points: np.ndarray) -> np.ndarray:
    """(3,) float64 origin for points (N, 3) metres: zeros when they lie within ``LOCAL_ORIGIN_ABOVE_M`` of the
    world origin, else their centroid rounded to whole metres (a stable, readable offset)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0 or np.abs(p).max() <= LOCAL_ORIGIN_ABOVE_M:
        return np.zeros(3)
    return np.round(p.mean(axis=0))


def align_to_reference(
    rec, centers: Mapping[str, np.ndarray], threshold_m: float | None = None, seed: int = 0
) -> ReferenceAlignment:
    """Align a ``pycolmap.Reconstruction`` in place to reference camera centres (metres, e.g.
    ``recon.reference.Reference.centers``), into a local frame around :func:`local_origin` of the centres.

    threshold_m: RANSAC inlier distance; default 2 % of the reference centres' extent (a GNSS-tagged block of
    100 m tolerates 2 m errors; tighten it for survey-grade references).
    """
    names = sorted(rec.image(i).name for i in rec.reg_image_ids())
    common = [n for n in names if n in centers]
    if len(common) < 3:
        raise ReconstructionError(
            f"alignment needs >= 3 registered images with reference centres, got {len(common)} "
            f"(registered: {len(names)}, in the reference: {len(centers)}; do the image names match?)"
        )
    dst = np.stack([np.asarray(centers[n], dtype=np.float64) for n in common])
    origin = local_origin(dst)
    if threshold_m is None:
        extent = float(np.linalg.norm(dst.max(axis=0) - dst.min(axis=0)))
        threshold_m = max(0.02 * extent, 1e-6)
    local = {n: np.asarray(centers[n], dtype=np.float64) - origin for n in common}
    result = align_reconstruction_to_centers(rec, local, float(threshold_m), seed=seed)
    return ReferenceAlignment(result, origin, float(threshold_m))
