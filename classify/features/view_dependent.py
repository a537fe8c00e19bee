"""View-dependent colour: how the luminance of a point changes with the direction it is seen from.

A Lambertian (collaborative) surface looks the same from every fusing view; specular and shiny ones show
highlights in the few views whose rays mirror the light, and transparent ones show what lies behind them, which
changes with the viewpoint. Per point, over the views that fused it (``PointCloud.visibility``; held-out photos
never take part), the photo's luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` (RGB / 255, nearest pixel of the
projection) gives four features, each dimensionless:

``lum_cv_views``
    std / mean of Y over the fusing views (the mean floored at :data:`LUM_FLOOR`); neutral (< 2 views): 0.
``lum_peak_views``
    max − median of Y over the fusing views: a highlight seen in few views; neutral (< 2 views): 0.
``lum_lobe_corr``
    Pearson correlation, over the fusing views other than the brightest, of Y with the cosine between the view's
    ray and the brightest view's ray: a specular lobe fades with the angle from its peak (the cosine between the
    rays equals that between their mirror directions about any normal, so this needs no normal). Neutral (fewer
    than :data:`MIN_CORR_VIEWS` other views, or a constant Y or cosine): 0.
``specular_up_corr``
    Pearson correlation, over the fusing views, of Y with the up (+z) component of the view's mirror direction
    about the point's MVS normal (``r = 2 (n · w) n − w``, ``w`` the unit direction point → camera: where light
    must come from to reach the camera by mirror reflection): shiny surfaces under light from above (sky, ceiling)
    are brighter in the views that mirror the sky. Takes +z as up, as the height features do. Neutral (no normal,
    fewer than :data:`MIN_CORR_VIEWS` views, or a constant Y or component): 0.

The per-view samples of a chunk are kept as flat (point, view) entries and reduced with vectorised segment
operations (sorting by point, then luminance), so medians and the brightest view cost no loop per point.
"""

from __future__ import annotations

import numpy as np

from classify.features.fusing import fusing_chunks, segment_bounds
from classify.features.multiview import MultiViewOptions, ViewData

VIEW_DEPENDENT_NAMES = ("lum_cv_views", "lum_peak_views", "lum_lobe_corr", "specular_up_corr")
LUM_FLOOR = 0.02  # floor of the mean luminance in lum_cv_views (~5 grey levels: dark points do not explode)
MIN_CORR_VIEWS = 3  # views a correlation needs
LUMA = np.array([0.2126, 0.7152, 0.0722])


def view_dependent_features(
    positions: np.ndarray,
    visibility: list[np.ndarray] | None,
    normals: np.ndarray | None,
    views: ViewData,
    options: MultiViewOptions = MultiViewOptions(),
) -> dict[str, np.ndarray]:
    """The features of :data:`VIEW_DEPENDENT_NAMES`, each (N,) float32 and finite, for points (N, 3) float64
    (metres, the cameras' local frame).

    visibility: per point, the image ids that fused it (None: the frustum views whose depth map agrees).
    normals: (N, 3) MVS normals (any length and sign; zero rows or None: no normal). options: chunking.
    """
    pts = np.asarray(positions, dtype=np.float64)
    n = len(pts)
    out = {name: np.zeros(n, dtype=np.float32) for name in VIEW_DEPENDENT_NAMES}
    nrm = None
    if normals is not None:
        nrm = np.asarray(normals, dtype=np.float64)
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm = np.where(length > 1e-12, nrm / np.maximum(length, 1e-300), 0.0)
    for sl, samples in fusing_chunks(pts, visibility, views, options.chunk_size, options.depth_tolerance):
        owners, lums, rays = [], [], []
        for s in samples:
            rgb = s.sample(views.image(s.view.name)).astype(np.float64) / 255.0
            lums.append(rgb[:, 0] * LUMA[0] + rgb[:, 1] * LUMA[1] + rgb[:, 2] * LUMA[2] if rgb.ndim == 2 else rgb)
            owners.append(s.idx)
            rays.append(s.ray)
        if not owners:
            continue
        cols = luminance_features(
            np.concatenate(owners),
            np.concatenate(lums),
            np.concatenate(rays),
            None if nrm is None else nrm[sl],
            sl.stop - sl.start,
        )
        for name, v in cols.items():
            out[name][sl] = v
    return out


def luminance_features(
    owner: np.ndarray, lum: np.ndarray, ray: np.ndarray, normals: np.ndarray | None, m: int
) -> dict[str, np.ndarray]:
    """The features (each (m,) float64) of m points from E flat samples: ``owner`` (E,) int64 point of each
    sample in [0, m), ``lum`` (E,) float64 luminance in [0, 1], ``ray`` (E, 3) float64 unit viewing ray camera →
    point; normals (m, 3) unit or zero rows, or None."""
    # By point, then luminance (ascending): one float64 key (luminance in [0, 1] squeezed into [0, 0.5]; a point
    # index below 2^30 leaves ~2^-22 of resolution, far finer than 8-bit photos) sorts ~3x faster than lexsort.
    lum = np.clip(lum, 0.0, 1.0)
    order = np.argsort(owner + 0.5 * lum, kind="stable")
    owner, lum, ray = owner[order], lum[order], ray[order]
    counts, starts = segment_bounds(owner, m)
    safe = np.maximum(counts, 1)
    mean = np.bincount(owner, lum, m) / safe
    var = np.maximum(np.bincount(owner, lum * lum, m) / safe - mean**2, 0.0)
    many = counts >= 2
    out = {"lum_cv_views": np.where(many, np.sqrt(var) / np.maximum(mean, LUM_FLOOR), 0.0)}
    last = starts + counts - 1  # the brightest sample of each point (valid where counts > 0)
    lo, hi = starts + (counts - 1) // 2, starts + counts // 2
    top = np.minimum(last, len(lum) - 1)
    median = 0.5 * (lum[np.minimum(lo, len(lum) - 1)] + lum[np.minimum(hi, len(lum) - 1)])
    out["lum_peak_views"] = np.where(many, lum[top] - median if len(lum) else 0.0, 0.0)
    # Lobe: the other samples' luminance against the cosine of their ray to the brightest ray.
    is_top = np.zeros(len(lum), dtype=bool)
    is_top[top[counts > 0]] = True
    cos_top = np.sum(ray * ray[top[owner]], axis=1) if len(lum) else np.zeros(0)
    others = ~is_top
    out["lum_lobe_corr"] = pearson(owner[others], cos_top[others], lum[others], m)
    out["specular_up_corr"] = np.zeros(m)
    if normals is not None and len(lum):
        n_e = normals[owner]
        w = -ray  # point → camera
        up = 2.0 * np.sum(n_e * w, axis=1) * n_e[:, 2] - w[:, 2]  # z of the mirror direction
        has = np.linalg.norm(n_e, axis=1) > 0
        corr = pearson(owner[has], up[has], lum[has], m)
        out["specular_up_corr"] = corr
    return out


def pearson(owner: np.ndarray, x: np.ndarray, y: np.ndarray, m: int) -> np.ndarray:
    """Per group of ``owner`` (E,) int64 in [0, m): the Pearson correlation (m,) float64 of ``x`` and ``y`` (E,);
    0 for groups under :data:`MIN_CORR_VIEWS` samples or with a (numerically) constant x or y."""
    c = np.bincount(owner, minlength=m).astype(np.float64)
    safe = np.maximum(c, 1)
    mx, my = np.bincount(owner, x, m) / safe, np.bincount(owner, y, m) / safe
    dx, dy = x - mx[owner], y - my[owner]  # centred: no cancellation in the sums below
    sxy = np.bincount(owner, dx * dy, m)
    sxx = np.bincount(owner, dx * dx, m)
    syy = np.bincount(owner, dy * dy, m)
    ok = (c >= MIN_CORR_VIEWS) & (sxx > 1e-12 * safe) & (syy > 1e-12 * safe)
    r = sxy / np.sqrt(np.maximum(sxx * syy, 1e-300))
    return np.where(ok, np.clip(r, -1.0, 1.0), 0.0)
