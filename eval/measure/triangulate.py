"""Multi-ray intersection of picks: a 3D point with its 3×3 covariance from pixel uncertainties.

The photogrammetric forward intersection: the same feature picked in two or more images with known
cameras (COLMAP intrinsics with distortion, fixed poses) gives one point ``X`` (local frame, metres) that
minimises the weighted reprojection error

    E(X) = Σ_i ‖ π_i(X) − p_i ‖² / σ_i²

where ``π_i`` projects through camera ``i`` (distortion included) and ``p_i`` is the pick in pixels with
its standard deviation ``σ_i`` (pixels, isotropic). The solver starts from the linear least-squares
intersection of the rays (the point closest to all of them), then runs Gauss–Newton on ``E``.

First-order propagation of the pick noise gives the covariance ``Σ_X = (Jᵀ W J)⁻¹`` with ``J`` the
stacked 2×3 Jacobians of the projections at the solution and ``W = diag(1/σ_i²)``: the *a priori*
covariance, which depends only on the ray geometry and on the σ's (camera poses are taken as exact).
The *a posteriori* variance factor ``σ₀² = Σ r_i²/σ_i² / (2n − 3)`` is reported beside it as a check of
the σ's (≈ 1 when they are right; undefined with two rays' single redundancy it is still reported).

Degenerate input (fewer than two picks, the same image twice, nearly parallel rays, a solution behind a
camera, non-finite values) raises :class:`core.errors.DataError` naming the point and the problem.

Written by hand: OpenCV's and pycolmap's triangulation return no covariance, take no per-pick weights and
do not report degenerate geometry in words; the whole method is 3×3 linear algebra.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from core.cameras import Camera, View
from core.errors import ConfigError, DataError


@dataclass(frozen=True)
class Pick:
    """One observation of a point: a pixel in one posed image.

    camera, view: intrinsics and world-to-camera pose (local frame) of the image.
    pixel: (2,) float64, COLMAP pixel coordinates (centre of the top-left pixel at (0.5, 0.5)), in the
        distorted (original) image.
    sigma_px: standard deviation of the pick in pixels (isotropic, > 0).
    """

    camera: Camera
    view: View
    pixel: np.ndarray
    sigma_px: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "pixel", np.asarray(self.pixel, dtype=np.float64).reshape(2))

    @property
    def image(self) -> str:
        return self.view.name


@dataclass(frozen=True)
class TriangulationOptions:
    """Options of :func:`triangulate`.

    min_angle_deg: the largest angle between any two rays must reach this (degrees, default 1.0); below it
        the depth is unconstrained and the point is refused as "nearly parallel rays".
    max_iterations: Gauss–Newton iterations at most (default 20; 3–5 are typical).
    step_tolerance: stop when the update is below this fraction of the mean ray length (default 1e-12).
    check_bounds: refuse picks outside the image (default True).
    """

    min_angle_deg: float = 1.0
    max_iterations: int = 20
    step_tolerance: float = 1e-12
    check_bounds: bool = True

    def __post_init__(self) -> None:
        if not (0.0 <= self.min_angle_deg < 90.0):
            raise ConfigError(f"min_angle_deg must be in [0, 90), got {self.min_angle_deg}")
        if self.max_iterations < 1:
            raise ConfigError(f"max_iterations must be >= 1, got {self.max_iterations}")


@dataclass(frozen=True)
class MeasuredPoint:
    """A triangulated point.

    name: the point's label.
    local: (3,) float64 position in the local frame of the cameras (metres).
    origin: (3,) float64 world coordinates of that frame's origin; ``world = origin + local``.
    covariance: (3, 3) float64 a-priori covariance of the position (m², same axes as world).
    residuals_px: (n, 2) float64 reprojection residuals (projected − picked) in pixels, one row per pick.
    images: image names of the picks, in order.
    sigma0: a-posteriori standard deviation of unit weight (dimensionless; ≈ 1 when the σ's fit).
    max_angle_deg: largest intersection angle between two of the rays (degrees).
    """

    name: str
    local: np.ndarray
    origin: np.ndarray
    covariance: np.ndarray
    residuals_px: np.ndarray
    images: tuple[str, ...]
    sigma0: float
    max_angle_deg: float

    @property
    def world(self) -> np.ndarray:
        """(3,) float64 world coordinates ``origin + local``."""
        return self.origin + self.local

    @property
    def sigma(self) -> np.ndarray:
        """(3,) standard deviations along the world axes (metres)."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def sigma_3d(self) -> float:
        """Root of the covariance trace: the 3D standard error (metres)."""
        return float(np.sqrt(max(float(np.trace(self.covariance)), 0.0)))

    @property
    def n_rays(self) -> int:
        return len(self.images)

    def ellipsoid(self, probability: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
        """Semi-axes (3,) in metres and their directions (3, 3, columns) of the confidence ellipsoid.

        The ellipsoid ``(x − X)ᵀ Σ⁻¹ (x − X) ≤ χ²₃(probability)`` holds the true point with that
        probability under the first-order Gaussian model.
        """
        return confidence_ellipsoid(self.covariance, probability)

    def mahalanobis2(self, truth_local: np.ndarray) -> float:
        """Squared Mahalanobis distance of a (local-frame) true position from the estimate."""
        d = np.asarray(truth_local, np.float64).reshape(3) - self.local
        return float(d @ np.linalg.solve(self.covariance, d))


@dataclass(frozen=True)
class Distance:
    """The distance between two measured points (metres) with its first-order standard deviation."""

    a: str
    b: str
    length: float
    sigma: float


CHI2_3_95 = float(chi2.ppf(0.95, 3))
"""χ²₃(0.95) ≈ 7.815: squared Mahalanobis radius of the 95 % ellipsoid in 3D."""


def confidence_ellipsoid(covariance: np.ndarray, probability: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Semi-axes (3,) and axis directions (3, 3, columns) of the ``probability`` ellipsoid of a 3×3 covariance."""
    if not (0.0 < probability < 1.0):
        raise ConfigError(f"probability must be in (0, 1), got {probability}")
    values, vectors = np.linalg.eigh(np.asarray(covariance, np.float64))
    radius2 = float(chi2.ppf(probability, 3))
    return np.sqrt(np.clip(values, 0.0, None) * radius2), vectors


def _fail(name: str, problem: str) -> DataError:
    return DataError(f"point {name!r}: {problem}" if name else problem)


@dataclass(frozen=True)
class _Ray:
    """A pick with its pose matrices computed once (quaternion → matrix is the costly part)."""

    pick: Pick
    R: np.ndarray  # (3, 3) world-to-camera rotation
    t: np.ndarray  # (3,)
    centre: np.ndarray  # (3,) local frame
    direction: np.ndarray  # (3,) unit, local frame


def _prepare(picks: Sequence[Pick]) -> list[_Ray]:
    rays = []
    for p in picks:
        R = p.view.rotation
        d = R.T @ p.camera.unproject(p.pixel[None])[0]
        rays.append(_Ray(p, R, p.view.translation, -R.T @ p.view.translation, d / np.linalg.norm(d)))
    return rays


_PROBES = np.array([[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])


def _camera_jacobian(ray: _Ray, x_local: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Projected pixel (2,), its Jacobian d pixel / d X (2, 3) and the z-depth at a local point (3,)."""
    camera = ray.pick.camera
    xc = ray.R @ x_local + ray.t
    z = float(xc[2])
    uv = xc[:2] / z
    d_uv = np.array([[1.0 / z, 0.0, -xc[0] / z**2], [0.0, 1.0 / z, -xc[1] / z**2]])
    if camera.model.has_distortion:
        # Central differences of the distortion polynomial in normalised coordinates: truncation error
        # O(h²) ≈ 1e-12 relative, far below any pixel noise.
        h = 1e-6
        dist = camera.distort(uv + h * _PROBES)
        d_dist = np.stack([(dist[1] - dist[2]) / (2 * h), (dist[3] - dist[4]) / (2 * h)], axis=1)
        uv_d = dist[0]
    else:
        d_dist = np.eye(2)
        uv_d = uv
    fx, fy = camera.focal
    cx, cy = camera.principal_point
    pixel = np.array([uv_d[0] * fx + cx, uv_d[1] * fy + cy])
    J = (np.array([[fx], [fy]]) * d_dist) @ d_uv @ ray.R
    return pixel, J, z


def _check_picks(picks: Sequence[Pick], name: str, options: TriangulationOptions) -> None:
    if len(picks) < 2:
        raise _fail(name, f"needs picks in at least 2 images to intersect rays, got {len(picks)}")
    seen: set[str] = set()
    for p in picks:
        if p.image in seen:
            raise _fail(name, f"image {p.image!r} is picked twice; one pick per image")
        seen.add(p.image)
        if not np.all(np.isfinite(p.pixel)):
            raise _fail(name, f"pick in {p.image!r} is not finite: {p.pixel.tolist()}")
        if not (np.isfinite(p.sigma_px) and p.sigma_px > 0):
            raise _fail(name, f"pick in {p.image!r}: sigma_px must be a positive number, got {p.sigma_px}")
        if options.check_bounds:
            u, v = p.pixel
            if not (0.0 <= u <= p.camera.width and 0.0 <= v <= p.camera.height):
                raise _fail(
                    name,
                    f"pick ({u:.2f}, {v:.2f}) is outside image {p.image!r} ({p.camera.width}×{p.camera.height} pixels)",
                )


def _max_angle_deg(dirs: np.ndarray) -> float:
    cos = np.clip(dirs @ dirs.T, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos.min())))


def intersect_rays(centres: np.ndarray, dirs: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """The point (3,) minimising the weighted sum of squared distances to rays.

    centres: (n, 3) float64 ray origins; dirs: (n, 3) unit directions; weights: (n,) (default ones).
    Solves ``Σ w_i (I − d_i d_iᵀ) X = Σ w_i (I − d_i d_iᵀ) c_i``; raises :class:`DataError` when singular.
    """
    w = np.ones(len(centres)) if weights is None else np.asarray(weights, np.float64)
    P = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]
    A = np.einsum("n,nij->ij", w, P)
    b = np.einsum("n,nij,nj->i", w, P, centres)
    eig = np.linalg.eigvalsh(A)
    if not eig[0] > 1e-12 * eig[-1]:
        raise DataError("the rays are parallel: their intersection is undefined")
    return np.linalg.solve(A, b)


def triangulate(
    picks: Sequence[Pick],
    origin: np.ndarray | None = None,
    options: TriangulationOptions = TriangulationOptions(),
    name: str = "",
) -> MeasuredPoint:
    """Intersect the rays of ``picks`` (2 or more images) into a point with its covariance.

    origin: (3,) float64 world coordinates of the cameras' local frame (default zeros).
    Raises :class:`DataError` for degenerate input (see the module docstring).
    """
    origin = np.zeros(3) if origin is None else np.asarray(origin, np.float64).reshape(3)
    _check_picks(picks, name, options)
    rays = _prepare(picks)
    centres = np.stack([r.centre for r in rays])
    dirs = np.stack([r.direction for r in rays])
    if not (np.all(np.isfinite(centres)) and np.all(np.isfinite(dirs))):
        raise _fail(name, "a ray is not finite (camera pose or undistortion failed)")
    angle = _max_angle_deg(dirs)
    if angle < options.min_angle_deg:
        raise _fail(
            name,
            f"the rays are (nearly) parallel: largest intersection angle {angle:.3g}° < {options.min_angle_deg}°; "
            "pick the point in images taken from more different directions",
        )
    try:
        x = intersect_rays(centres, dirs)
    except DataError as err:
        raise _fail(name, err.problem) from None
    _check_in_front(picks, centres, dirs, x, name)

    sigma = np.array([p.sigma_px for p in picks], np.float64)
    scale = float(np.mean(np.linalg.norm(x - centres, axis=1)))
    for _ in range(options.max_iterations):
        J, r, _z = _linearise(rays, x)
        w = np.repeat(1.0 / sigma**2, 2)
        N = J.T @ (w[:, None] * J)
        step = -np.linalg.solve(N, J.T @ (w * r))
        x = x + step
        if np.linalg.norm(step) <= options.step_tolerance * scale:
            break
    J, r, z = _linearise(rays, x)
    if np.any(z <= 0):
        bad = picks[int(np.argmin(z))].image
        raise _fail(name, f"the intersection lies behind the camera of image {bad!r}; the picks do not match")
    w = np.repeat(1.0 / sigma**2, 2)
    N = J.T @ (w[:, None] * J)
    eig = np.linalg.eigvalsh(N) if np.all(np.isfinite(N)) else np.zeros(3)
    if not eig[0] > 1e-14 * eig[-1]:
        raise _fail(name, "the ray geometry does not determine the point (singular normal equations)")
    covariance = np.linalg.inv(N)
    covariance = 0.5 * (covariance + covariance.T)
    dof = 2 * len(picks) - 3
    sigma0 = float(np.sqrt(float(r @ (w * r)) / dof))
    return MeasuredPoint(
        name=name,
        local=x,
        origin=origin,
        covariance=covariance,
        residuals_px=r.reshape(-1, 2),
        images=tuple(p.image for p in picks),
        sigma0=sigma0,
        max_angle_deg=angle,
    )


def _check_in_front(picks: Sequence[Pick], centres: np.ndarray, dirs: np.ndarray, x: np.ndarray, name: str) -> None:
    along = np.einsum("ij,ij->i", x[None] - centres, dirs)
    if np.any(along <= 0):
        bad = picks[int(np.argmin(along))].image
        raise _fail(name, f"the rays meet behind the camera of image {bad!r} (they diverge); the picks do not match")


def _linearise(rays: Sequence[_Ray], x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stacked Jacobian (2n, 3), residuals projected − picked (2n,) and z-depths (n,) at ``x``."""
    rows, res, depths = [], [], []
    for ray in rays:
        pixel, J, z = _camera_jacobian(ray, x)
        rows.append(J)
        res.append(pixel - ray.pick.pixel)
        depths.append(z)
    return np.concatenate(rows), np.concatenate(res), np.asarray(depths)


def distance(a: MeasuredPoint, b: MeasuredPoint) -> Distance:
    """Euclidean distance (metres) between two points and its σ by first-order propagation.

    The two points are taken as independent (separate picks, exact cameras):
    ``σ² = gᵀ (Σ_a + Σ_b) g`` with ``g`` the unit vector from ``a`` to ``b``. A zero distance gets the
    largest axis σ of the summed covariance instead of a NaN direction.
    """
    delta = (b.origin + b.local) - (a.origin + a.local)
    length = float(np.linalg.norm(delta))
    cov = a.covariance + b.covariance
    if length > 0:
        g = delta / length
        var = float(g @ cov @ g)
    else:
        var = float(np.linalg.eigvalsh(cov).max())
    return Distance(a.name, b.name, length, float(np.sqrt(max(var, 0.0))))
