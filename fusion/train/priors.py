"""Geometric priors for new splats: depth and normals from the trusted MVS surface at the mask borders.

Photometric loss alone lets a splat sit anywhere along the rays that reproduce its colour: on mirrors and glass it
settles at the depth of what is *reflected or refracted*, in front of or behind the real surface. The priors pull
the splats near a region's border towards the surface that the trusted MVS points define around the region, so that
new splats meet the MVS surface without a seam (DN-Splatter's depth and normal priors, 2DGS's normal consistency).

Per training view (:func:`view_priors`, computed once, at the training resolution, in the training frame):

- prior depth: the z-buffer of the trusted MVS points (``needs_splats = 0``; the fused and filtered output of the
  MVS depth maps — the raw depth maps also hold the wrong depths of the non-collaborative surfaces) in a band of
  ``band_px`` around the mask, interpolated into the mask by first-order normalised convolution of the inverse depth
  (:func:`fill_inverse_depth_linear`: exact on planes);
- prior normal: the normal of that interpolated depth surface (cross product of its back-projected neighbours),
  facing the camera;
- validity: only where the prior's surface point lands inside the masks of the other views that see it
  (:func:`hull_consistent`): an object standing in front of its background interpolates to the background behind
  it, which other views see outside the object's mask;
- weight: ``exp(-d / border_px)`` with d the distance (px) of a mask pixel to the mask's edge (``border_px`` None:
  1 everywhere in the mask, for regions continuous with their surroundings such as a window in a facade), times the
  edge-aware factor ``exp(-|∇I| / edge_scale)`` of the photo (DN-Splatter: depth changes where the image has edges,
  so the prior is trusted less there); zero outside the mask, where no depth could be interpolated, and beyond
  ``3 · border_px``.

Per geometric step (:func:`prior_loss`, on the steps :class:`fusion.train.options.GeometryOptions` schedules):
the *rendered* depth of the trainable + frozen render (plane or median depth, :mod:`fusion.train.render`) against
the prior depth, ``depth_weight · Σ w |log z − log z_prior| / Σ w`` (edge-aware log-L1,
:func:`fusion.train.geometry_loss.mvs_depth_loss`), plus ``normal_weight · Σ w (1 − cos(n, n_prior)) / Σ w`` with n
the rendered (alpha-blended) normal, over the pixels with a prior weight w where the rendered depth is valid
(DN-Splatter's per-pixel priors). This replaced (issue 31) a prior on the splat *centres* projected into the view
(the centre's depth and its smallest axis against the prior), which moved centres rather than the surface the
splats render; the options and their weights kept their names and scale (log-L1 and 1 − cos).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from fusion.train.geometry_loss import mvs_depth_loss
from fusion.train.options import PriorOptions
from fusion.train.views import TrainView


@dataclass(frozen=True)
class ViewPrior:
    """The prior of one training view at its training resolution.

    depth: (H, W) float32 z-depth (metres) of the interpolated trusted surface (0 where the weight is 0).
    normal: (H, W, 3) float32 unit normals in the training frame, facing the camera (0 where the weight is 0).
    weight: (H, W) float32 in [0, 1]; pixels: number of pixels with a weight > 0.
    """

    depth: torch.Tensor
    normal: torch.Tensor
    weight: torch.Tensor
    pixels: int


def zbuffer(points: np.ndarray, viewmat: np.ndarray, K: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H, W) float64 z-depth of the nearest of ``points`` (N, 3, training frame) per pixel; 0 where none lands.

    viewmat: (4, 4) training frame → camera (OpenCV axes); K: (3, 3) pinhole, pixel centres at +0.5.
    """
    cam = points @ viewmat[:3, :3].T + viewmat[:3, 3]
    z = cam[:, 2]
    front = z > 1e-6
    uv = (cam[front] @ K.T)[:, :2] / z[front, None]
    col = np.floor(uv[:, 0]).astype(np.int64)
    row = np.floor(uv[:, 1]).astype(np.int64)
    ok = (col >= 0) & (col < width) & (row >= 0) & (row < height)
    depth = np.full(height * width, np.inf)
    np.minimum.at(depth, row[ok] * width + col[ok], z[front][ok])
    depth[~np.isfinite(depth)] = 0.0
    return depth.reshape(height, width)


def fill_inverse_depth_linear(
    depth: np.ndarray,
    valid: np.ndarray,
    sigmas: tuple[float, ...] = (2, 4, 8, 16, 32),
    min_weight: float = 1e-3,
    min_spread_px: float = 1.0,
) -> np.ndarray:
    """(H, W) z-depth interpolated from the ``valid`` pixels of ``depth`` by first-order normalised convolution of
    the inverse depth: per pixel, a Gaussian-weighted least-squares fit ``1/z ≈ a + b·du + c·dv`` to the valid
    pixels around it, at the smallest σ (px) whose weight reaches ``min_weight`` and whose fit is well conditioned.
    The inverse depth of a plane is affine in the pixel coordinates, so planes are interpolated exactly (a
    zeroth-order normalised convolution, :func:`fusion.train.init.fill_depth`, flattens a tilted plane's ramp).
    Where no σ gives a well-conditioned fit (the valid pixels' spread around the pixel < ``min_spread_px`` in some
    direction), the zeroth-order value at the largest σ; NaN where no valid pixel is in reach."""
    h, w = depth.shape
    out = np.full((h, w), np.nan)
    todo = np.ones((h, w), bool)
    good = valid & (depth > 0)
    f = np.where(good, 1.0 / np.where(good, depth, 1.0), 0.0)
    wv = good.astype(np.float64)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    for sigma in sigmas:
        k = int(2 * round(3 * sigma) + 1)

        def blur(x: np.ndarray, k: int = k, sigma: float = sigma) -> np.ndarray:
            return cv2.GaussianBlur(x, (k, k), sigma, borderType=cv2.BORDER_CONSTANT)

        # moments of the valid pixels relative to each output pixel: Σw, Σw·du, ... with du = u' − u
        s0 = blur(wv)
        su, sv = blur(wv * u) - u * s0, blur(wv * v) - v * s0
        suu = blur(wv * u * u) - 2 * u * blur(wv * u) + u * u * s0
        svv = blur(wv * v * v) - 2 * v * blur(wv * v) + v * v * s0
        suv = blur(wv * u * v) - u * blur(wv * v) - v * blur(wv * u) + u * v * s0
        sf = blur(wv * f)
        sfu, sfv = blur(wv * f * u) - u * sf, blur(wv * f * v) - v * sf
        A = np.stack([np.stack([s0, su, sv], -1), np.stack([su, suu, suv], -1), np.stack([sv, suv, svv], -1)], -2)
        b = np.stack([sf, sfu, sfv], -1)
        ready = todo & (s0 > min_weight)
        # the spread of the valid pixels around the output pixel (covariance of du, dv, px²): its smaller eigenvalue
        # must reach min_spread² or the slope across a thin line of samples is undetermined
        n0 = np.maximum(s0, 1e-12)
        cuu, cvv, cuv = suu / n0 - (su / n0) ** 2, svv / n0 - (sv / n0) ** 2, suv / n0 - su * sv / n0**2
        low = 0.5 * (cuu + cvv) - np.sqrt(0.25 * (cuu - cvv) ** 2 + cuv**2)
        well = low[ready] >= min_spread_px**2
        idx = np.flatnonzero(ready)
        sol = np.full(len(idx), np.nan)
        if well.any():
            sol[well] = np.linalg.solve(A[ready][well], b[ready][well][..., None])[:, 0, 0]
        last = sigma == sigmas[-1]
        use = well & (sol > 0)
        if last:  # no larger window left: the zeroth-order value where the fit is undetermined
            value = np.where(use, sol, sf[ready] / s0[ready])
            done = idx
        else:  # undetermined: wait for a larger window
            value, done = sol[use], idx[use]
        out.reshape(-1)[done] = 1.0 / np.maximum(value, 1e-12)
        ready = np.zeros_like(ready)
        ready.reshape(-1)[done] = True
        todo &= ~ready
        if not todo.any():
            break
    return out


def depth_normals(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(H, W, 3) unit camera-frame normals of a z-depth map (H, W), facing the camera; 0 where undefined (NaN or
    non-positive depth at the pixel or at a neighbour used by the central differences)."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    good = np.isfinite(depth) & (depth > 0)
    pts = rays * np.where(good, depth, 0.0)[..., None]
    du = np.zeros_like(pts)
    dv = np.zeros_like(pts)
    du[:, 1:-1] = pts[:, 2:] - pts[:, :-2]
    dv[1:-1] = pts[2:] - pts[:-2]
    n = np.cross(du, dv)
    ok = good.copy()
    ok[:, 1:-1] &= good[:, 2:] & good[:, :-2]
    ok[1:-1] &= good[2:] & good[:-2]
    ok[:, [0, -1]] = False
    ok[[0, -1], :] = False
    norm = np.linalg.norm(n, axis=-1)
    ok &= norm > 0
    n = np.where(ok[..., None], n / np.maximum(norm, 1e-30)[..., None], 0.0)
    facing = (n * pts).sum(-1) > 0  # pointing away from the camera: flip
    n[facing] *= -1
    return n


def edge_weight(image: np.ndarray, scale: float | None) -> np.ndarray:
    """(H, W) ``exp(-|∇I| / scale)`` of an (H, W, 3) float image in [0, 1] (channel-mean Sobel magnitude / 8 so that
    it is a per-pixel difference); ones when ``scale`` is None."""
    if scale is None:
        return np.ones(image.shape[:2])
    grey = np.asarray(image, np.float32).mean(axis=-1)
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return np.exp(-np.sqrt(gx * gx + gy * gy) / scale).astype(np.float64)


def view_priors(views: Sequence[TrainView], trusted: np.ndarray, options: PriorOptions) -> list[ViewPrior | None]:
    """The prior of each view (None for a view without mask or without any trusted depth near its mask).

    trusted: (N, 3) positions of the trusted MVS points in the training frame (metres).
    """
    out: list[ViewPrior | None] = []
    pts = np.asarray(trusted, np.float64).reshape(-1, 3)
    kernel = np.ones((2 * options.band_px + 1,) * 2, np.uint8)
    for view in views:
        if view.loss_mask is None or len(pts) == 0:
            out.append(None)
            continue
        mask = (view.loss_mask | view.holdout_mask).numpy()
        vm, K = view.viewmat.numpy().astype(np.float64), view.K.numpy().astype(np.float64)
        depth = zbuffer(pts, vm, K, view.width, view.height)
        band = (cv2.dilate(mask.astype(np.uint8), kernel) > 0) & ~mask & (depth > 0)
        if not band.any():
            out.append(None)
            continue
        filled = fill_inverse_depth_linear(np.where(band, depth, 0.0), band)
        weight = mask & np.isfinite(filled)
        w = weight.astype(np.float64)
        if options.border_px is not None:
            dist = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5).astype(np.float64)
            w *= np.exp(-dist / options.border_px) * (dist <= 3 * options.border_px)
        w *= edge_weight(view.image.numpy(), options.edge_scale)
        normals_cam = depth_normals(filled, K)
        w *= np.linalg.norm(normals_cam, axis=-1) > 0  # a normal is needed for both terms to be consistent
        w = np.where(np.isfinite(w), w, 0.0)
        if options.hull_share is not None:
            w *= hull_consistent(view, views, np.where(w > 0, filled, np.nan), options.hull_share)
        normals = normals_cam @ vm[:3, :3]  # camera → training frame: Rᵀ n, row-wise n @ R
        d = np.where(w > 0, np.nan_to_num(filled, nan=0.0), 0.0)
        out.append(
            ViewPrior(
                torch.from_numpy(d.astype(np.float32)),
                torch.from_numpy(normals.astype(np.float32)),
                torch.from_numpy(w.astype(np.float32)),
                int((w > 0).sum()),
            )
        )
    return out


def hull_consistent(view: TrainView, views: Sequence[TrainView], depth: np.ndarray, min_share: float) -> np.ndarray:
    """(H, W) bool: the pixels of ``view`` whose prior surface point (z-depth ``depth``, NaN = none) lands inside the
    masks of at least ``min_share`` of the other views that see it in their image; True where no other view sees it.

    The surroundings of a region interpolate to the right surface when the region is flush with them (a window in
    a facade, a mirror on a wall); for an object standing in front of its background they interpolate to the
    background behind it, and that background point is then seen *outside* the object's mask from other views."""
    rows, cols = np.nonzero(np.isfinite(depth))
    keep = np.ones(depth.shape, bool)
    if len(rows) == 0:
        return keep
    K = view.K.numpy().astype(np.float64)
    vm = view.viewmat.numpy().astype(np.float64)
    z = depth[rows, cols]
    cam = np.stack([(cols + 0.5 - K[0, 2]) / K[0, 0] * z, (rows + 0.5 - K[1, 2]) / K[1, 1] * z, z], axis=1)
    world = (cam - vm[:3, 3]) @ vm[:3, :3]  # x = Rᵀ (x_cam − t), row-wise
    inside = np.zeros(len(z), np.int32)
    seen = np.zeros(len(z), np.int32)
    for other in views:
        if other is view or other.loss_mask is None:
            continue
        omask = (other.loss_mask | other.holdout_mask).numpy()
        ovm, oK = other.viewmat.numpy().astype(np.float64), other.K.numpy().astype(np.float64)
        oc = world @ ovm[:3, :3].T + ovm[:3, 3]
        front = oc[:, 2] > 1e-6
        zc = np.where(front, oc[:, 2], 1.0)
        u = np.floor(oK[0, 0] * oc[:, 0] / zc + oK[0, 2]).astype(np.int64)
        v = np.floor(oK[1, 1] * oc[:, 1] / zc + oK[1, 2]).astype(np.int64)
        ok = front & (u >= 0) & (u < other.width) & (v >= 0) & (v < other.height)
        seen += ok
        hit = np.zeros(len(z), bool)
        hit[ok] = omask[v[ok], u[ok]]
        inside += hit
    good = (seen == 0) | (inside >= min_share * seen)
    keep[rows, cols] = good
    return keep


@dataclass(frozen=True)
class PriorTerms:
    """The weighted prior loss (0-d tensor with its graph) and its parts (detached): the weighted mean of
    |log z − log z_prior| and of 1 − cos(n, n_prior) over the prior pixels where the rendered depth is valid, and
    their count."""

    loss: torch.Tensor
    depth: torch.Tensor
    normal: torch.Tensor
    pixels: int


def prior_loss(
    normal: torch.Tensor, depth: torch.Tensor, valid: torch.Tensor, view: TrainView, prior: ViewPrior | None,
    options: PriorOptions, window: tuple[int, int, int, int] | None = None,
) -> PriorTerms:  # fmt: skip
    """The depth + normal prior of one geometric render of ``view`` (see the module).

    normal: (h, w, 3) the rendered camera-frame normal (``RenderGeometry.normal``, premultiplied by alpha).
    depth: (h, w) the rendered z-depth (metres; plane or median depth), valid: (h, w) bool its validity.
    window: (row0, row1, col0, col1) of the view the maps cover (None: the whole view, h, w = H, W).
    """
    zero = torch.zeros((), dtype=depth.dtype)
    if prior is None or prior.pixels == 0 or not options.active:
        return PriorTerms(zero, zero, zero, 0)
    r0, r1, c0, c1 = window if window is not None else (0, view.height, 0, view.width)
    weight, prior_depth = prior.weight[r0:r1, c0:c1], prior.depth[r0:r1, c0:c1]
    used = valid & (weight > 0) & (depth.detach() > 1e-6)
    if view.loss_mask is not None:
        used = used & view.loss_mask[r0:r1, c0:c1]  # never the hold-out pixels
    count = int(used.sum())
    if count == 0:
        return PriorTerms(zero, zero, zero, 0)
    d_term = mvs_depth_loss(depth, prior_depth, weight, used, kind="log")
    loss = options.depth_weight * d_term
    n_term = zero
    if options.normal_weight > 0:
        rot = view.viewmat[:3, :3].to(normal.dtype)
        prior_cam = prior.normal[r0:r1, c0:c1].to(normal.dtype) @ rot.T  # training → camera
        unit = normal / (normal * normal).sum(-1).clamp_min(1e-12).sqrt()[..., None]
        w = weight.to(normal.dtype) * used
        n_term = (w * (1.0 - (unit * prior_cam).sum(-1))).sum() / w.sum().clamp_min(1e-12)
        loss = loss + options.normal_weight * n_term
    return PriorTerms(loss, d_term.detach(), n_term.detach(), count)
