"""Oriented points (position + outward unit normal + colour) drawn from a Gaussian set, for surface reconstruction.

Per Gaussian i (α_i its opacity, σ its three standard deviations, R_i its rotation):

- normal: the column of R_i of the shortest axis (a flat Gaussian lies in the surface). MVS Gaussians from
  :mod:`fusion.convert` (``adaptive``) are surfels whose third axis was rotated onto the MVS normal, so when the
  shortest axis is that third axis the normal keeps the MVS sign ("trusted"). A Gaussian whose two shortest σ differ
  by less than ``isotropy_ratio`` (``paper`` conversion: spheres) has no usable normal: PCA of its neighbouring centres
  is used instead (``NormalFallback.ESTIMATE``), or the set is refused (``ERROR``), or such Gaussians are left out
  (``DROP``).
- weight: w_i = min(1, α_i / ``full_weight_opacity``); Gaussians with α_i < ``min_opacity`` are ignored. screened
  Poisson in open3d has no per-point confidence (it normalises the normals), so the weight acts on the sampling.
- sampling: the expected number of points is w_i · max(1, σ_a σ_b / s²), with σ_a, σ_b the two in-surface σ and s the
  reference spacing (``sample_spacing``, default the median of √(σ_a σ_b) over the kept Gaussians: a typical surfel
  gives one point, a splat covering 10× that area gives ten). The fractional part is rounded stochastically (seeded).
  The first point of a Gaussian is its mean; the others lie uniformly in its ellipse of semi-axes
  ``footprint_sigmas`` · (σ_a, σ_b) in the surface plane.
- orientation: normals without a trusted sign are flipped to face the nearest of ``viewpoints`` (camera centres,
  local frame) when given; otherwise to agree with the trusted normals nearby; otherwise open3d's consistent
  tangent-plane propagation, then all flipped together so that most point away from the centroid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from core.errors import DataError
from core.gaussians import GaussianSet
from fusion.convert import Source, pca_normals
from fusion.mesh.options import NormalFallback, OrientedPointOptions  # noqa: F401 (re-exported)
from fusion.mesh.types import OrientedPoints


@dataclass
class OrientedPointStats:
    """Counts of :func:`oriented_points_from_gaussians`."""

    gaussians_in: int
    dropped_faint: int
    dropped_isotropic: int  # only with NormalFallback.DROP
    estimated_normals: int
    trusted_normals: int
    points_out: int
    sample_spacing: float


def rotation_matrices(quats: np.ndarray) -> np.ndarray:
    """(N, 3, 3) float64 rotation matrices of quaternions (N, 4) (w, x, y, z), normalised first.

    Column j of R is the Gaussian's j-th axis in the local frame.
    """
    q = np.asarray(quats, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1),
        ],
        axis=1,
    )


def oriented_points_from_gaussians(
    gaussians: GaussianSet,
    options: OrientedPointOptions | None = None,
    viewpoints: np.ndarray | None = None,
    weight_override: np.ndarray | None = None,
) -> tuple[OrientedPoints, OrientedPointStats]:
    """Oriented points from Gaussians (rules in the module docstring), in the set's local frame and origin.

    viewpoints: (M, 3) float64 camera centres relative to ``gaussians.origin``, or None.
    weight_override: (N,) weights in [0, 1] replacing w_i (e.g. 1 for snapshot splats whose opacity is raised to 1).
    The ``source`` field of the set (absent: 0) is carried per point. Raises :class:`DataError` for an empty set,
    NaN parameters, or when nothing is left after the opacity cut.
    """
    options = options or OrientedPointOptions()
    n0 = len(gaussians)
    if n0 == 0:
        raise DataError("cannot mesh an empty Gaussian set (0 Gaussians)")
    gaussians.validate("Gaussian set to mesh")
    weight, keep = _weights(gaussians, options, weight_override)
    dropped_faint = int(n0 - keep.sum())
    idx = np.flatnonzero(keep)
    if len(idx) == 0:
        raise DataError(f"all {n0} Gaussians are fainter than min_opacity {options.min_opacity}: nothing to mesh")

    source = np.asarray(gaussians.fields.get("source", np.zeros(n0)), dtype=np.uint8)
    s = _surfels(gaussians, idx, source, options)
    dropped_iso = 0
    if s.isotropic.any() and options.normal_fallback is NormalFallback.ERROR:
        raise DataError(
            f"{int(s.isotropic.sum())} of {len(s.idx)} Gaussians are near-isotropic "
            f"(σ_min > {options.isotropy_ratio}·σ_mid) and carry no normal; convert MVS points in 'adaptive' mode "
            "or use normal_fallback='estimate'"
        )
    if s.isotropic.any() and options.normal_fallback is NormalFallback.DROP:
        dropped_iso = int(s.isotropic.sum())
        if not (~s.isotropic).any():
            raise DataError(f"all {len(s.idx)} Gaussians are near-isotropic and normal_fallback is 'drop'")
        s = s.without_isotropic()

    centres = gaussians.means[s.idx]
    estimated = 0
    if s.isotropic.any():
        iso = s.isotropic
        s.normal[iso] = _pca_normals(centres, np.flatnonzero(iso), options.normal_neighbors)
        # an isotropic Gaussian has no preferred in-surface axes: build a basis around the estimated normal
        s.axis_a[iso], s.axis_b[iso] = _tangent_basis(s.normal[iso])
        estimated = int(iso.sum())
    normal = orient_normals(centres, s.normal, s.trusted, viewpoints, options.normal_neighbors)

    owner, pos, spacing = _sample_ellipses(centres, s, weight[s.idx], options)
    gi = s.idx[owner]
    reach = options.footprint_sigmas * s.sig[owner, 2]  # the ellipse's long semi-axis
    colors = gaussians.base_colors[gi]
    points = OrientedPoints(pos, normal[owner], colors, source[gi], gi, gaussians.origin.copy(), reach)
    stats = OrientedPointStats(n0, dropped_faint, dropped_iso, estimated, int(s.trusted.sum()), len(points), spacing)
    return points, stats


def _weights(
    gaussians: GaussianSet, options: OrientedPointOptions, weight_override: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """(N,) float64 sampling weight w_i in [0, 1] and (N,) bool "kept" of every Gaussian (see the module docstring)."""
    alpha = gaussians.opacities.astype(np.float64)
    if weight_override is not None:
        weight = np.clip(np.asarray(weight_override, dtype=np.float64).reshape(-1), 0.0, 1.0)
        if len(weight) != len(gaussians):
            raise DataError(f"weight_override has {len(weight)} entries for {len(gaussians)} Gaussians")
        return weight, weight > 0
    weight = np.minimum(1.0, alpha / options.full_weight_opacity)
    return weight, alpha >= options.min_opacity


@dataclass
class _Surfels:
    """The kept Gaussians ``idx`` (n,) as surfels: σ ascending ``sig`` (n, 3) metres; unit ``normal`` (shortest axis)
    and in-surface axes ``axis_a`` / ``axis_b`` (middle / longest), (n, 3) local frame; ``isotropic`` (no usable
    shortest axis) and ``trusted`` (normal sign from MVS) (n,) bool."""

    idx: np.ndarray
    sig: np.ndarray
    normal: np.ndarray
    axis_a: np.ndarray
    axis_b: np.ndarray
    isotropic: np.ndarray
    trusted: np.ndarray

    def without_isotropic(self) -> _Surfels:
        sel = ~self.isotropic
        return _Surfels(
            self.idx[sel],
            self.sig[sel],
            self.normal[sel],
            self.axis_a[sel],
            self.axis_b[sel],
            np.zeros(int(sel.sum()), dtype=bool),
            self.trusted[sel],
        )


def _surfels(gaussians: GaussianSet, idx: np.ndarray, source: np.ndarray, options: OrientedPointOptions) -> _Surfels:
    log_s = gaussians.log_scales[idx].astype(np.float64)
    order = np.argsort(log_s, axis=1)  # axis indices, shortest first
    sig = np.exp(np.take_along_axis(log_s, order, axis=1))  # (n, 3) ascending
    rot = rotation_matrices(gaussians.quats[idx])
    rows = np.arange(len(idx))
    normal = rot[rows, :, order[:, 0]]  # (n, 3) column of the shortest axis
    axis_a = rot[rows, :, order[:, 1]]
    axis_b = rot[rows, :, order[:, 2]]
    isotropic = sig[:, 0] > options.isotropy_ratio * sig[:, 1]
    trusted = (~isotropic) & (source[idx] == Source.MVS) & (order[:, 0] == 2)
    return _Surfels(idx, sig, normal, axis_a, axis_b, isotropic, trusted)


def _sample_ellipses(
    centres: np.ndarray, s: _Surfels, weight: np.ndarray, options: OrientedPointOptions
) -> tuple[np.ndarray, np.ndarray, float]:
    """Points in the surfels' ellipses (see the module docstring; seeded): the surfel of each point (P,) int64, the
    positions (P, 3) float64 local, and the reference spacing s in metres."""
    sig = s.sig
    footprint = sig[:, 1] * sig[:, 2]
    spacing = options.sample_spacing or float(np.sqrt(np.median(footprint)))
    spacing = max(spacing, 1e-9)
    expected = weight * np.maximum(1.0, footprint / spacing**2)
    expected = np.minimum(expected, options.max_samples_per_gaussian)
    rng = np.random.default_rng(options.seed)
    counts = np.floor(expected + rng.random(len(s.idx))).astype(np.int64)
    counts = np.minimum(counts, options.max_samples_per_gaussian)

    owner = np.repeat(np.arange(len(s.idx)), counts)
    first = np.zeros(len(owner), dtype=bool)
    starts = np.cumsum(counts) - counts
    first[starts[counts > 0]] = True
    # uniform in the unit disc (r = √u), scaled to the ellipse of footprint_sigmas · σ; the first point is the mean
    r = np.sqrt(rng.random(len(owner))) * options.footprint_sigmas
    phi = rng.random(len(owner)) * 2 * np.pi
    u, v = r * np.cos(phi), r * np.sin(phi)
    u[first] = 0.0
    v[first] = 0.0
    axis_a, axis_b = s.axis_a, s.axis_b
    pos = centres[owner] + axis_a[owner] * (u * sig[owner, 1])[:, None] + axis_b[owner] * (v * sig[owner, 2])[:, None]
    return owner, pos, spacing


def _pca_normals(centres: np.ndarray, rows: np.ndarray, k: int) -> np.ndarray:
    """Unit PCA normals (len(rows), 3) of ``centres[rows]`` from their k nearest centres (fewer when there are not)."""
    k = min(k, len(centres) - 1)
    if k < 2:
        raise DataError(f"{len(centres)} Gaussians are too few to estimate normals (need at least 3)")
    _, nb = cKDTree(centres).query(centres[rows], k=k + 1)
    return pca_normals(centres, rows, nb[:, 1:])


def _tangent_basis(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (N, 3) each, orthogonal to each other and to the unit ``normals`` (N, 3)."""
    helper = np.where(np.abs(normals[:, [0]]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    a = np.cross(normals, helper)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    return a, np.cross(normals, a)


def orient_normals(
    positions: np.ndarray,
    normals: np.ndarray,
    trusted: np.ndarray,
    viewpoints: np.ndarray | None = None,
    k: int = 16,
) -> np.ndarray:
    """Flip the untrusted unit normals (N, 3) so they point out of the surface; trusted ones are kept.

    positions: (N, 3) float64 local; trusted: (N,) bool; viewpoints: (M, 3) camera centres (local) or None.
    Order of rules: face the nearest viewpoint; else agree with the distance-weighted mean of the k nearest trusted
    normals; else open3d's consistent tangent-plane propagation, then a global flip so that most normals point away
    from the centroid (right for closed or convex-ish objects; aerial scenes should pass viewpoints).
    """
    normals = np.array(normals, dtype=np.float64)
    todo = ~np.asarray(trusted, dtype=bool)
    if not todo.any():
        return normals
    rows = np.flatnonzero(todo)
    if viewpoints is not None and len(viewpoints):
        vp = np.asarray(viewpoints, dtype=np.float64).reshape(-1, 3)
        _, nearest = cKDTree(vp).query(positions[rows])
        facing = np.einsum("ij,ij->i", normals[rows], vp[nearest] - positions[rows])
        normals[rows[facing < 0]] *= -1
        return normals
    ref = np.flatnonzero(~todo)
    if len(ref):
        kk = min(k, len(ref))
        d, nb = cKDTree(positions[ref]).query(positions[rows], k=kk)
        d, nb = d.reshape(len(rows), kk), nb.reshape(len(rows), kk)
        mean = (normals[ref][nb] / (d[..., None] + 1e-9)).sum(axis=1)
        normals[rows[np.einsum("ij,ij->i", normals[rows], mean) < 0]] *= -1
        return normals
    import open3d as o3d

    outward_of = positions - positions.mean(axis=0)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(positions))
    pcd.normals = o3d.utility.Vector3dVector(normals)
    try:
        if len(positions) > 3:
            pcd.orient_normals_consistent_tangent_plane(int(min(k, len(positions) - 1)))
    except RuntimeError:  # qhull refuses degenerate layouts (collinear, cospherical): orient each point on its own
        flip = np.einsum("ij,ij->i", normals, outward_of) < 0
        normals[flip] *= -1
        return normals
    normals = np.asarray(pcd.normals, dtype=np.float64).copy()
    outward = np.einsum("ij,ij->i", normals, outward_of)
    if (outward > 0).sum() < (outward < 0).sum():
        normals *= -1
    return normals
