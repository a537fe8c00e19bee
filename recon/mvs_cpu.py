"""Our CPU multi-view stereo: coarse-to-fine plane sweep + PatchMatch-style refinement (torch + numba).

Per reference view (images gray float32 in [0, 1], pinhole cameras in COLMAP pixel units):

1. Coarsest level (longer side ``coarse_size``): sweep ``num_planes`` fronto-parallel planes uniform in inverse
   depth over the view's sparse depth range; winner-take-all, then a median and a box filter.
2. Each finer level (factor 2): the inverse depth is upsampled; per pixel, hypotheses = the upsampled value
   and the values of the nearest coarse pixels (keeps discontinuities sharp).
   At every level, ``refine_rounds`` (``finest_rounds`` at the finest) PatchMatch-style rounds follow: Jacobi
   propagation (the hypotheses of the neighbours at 1 px and, with ``far_propagation``, 4 px), local-plane
   hypotheses (window means of the map) plus perturbations ± step, the step halving each round; then a parabola
   refinement. The ``quality`` preset sets these efforts (:mod:`recon.mvs_cpu_options`).
3. Photo-consistency: zero-mean NCC over a (2r+1)² window between the reference and each warped source; the
   window is warped per pixel with each pixel's own hypothesis, so slanted surfaces are followed implicitly.
   Cost = 1 − NCC; aggregation = mean of the ``best_k`` lowest costs over sources (robust to occlusion).
   Pixels without texture (window std below ``min_texture_std``) or with cost above ``max_cost`` are invalid.
   The cost is one numba kernel (:func:`recon.mvs_cpu_kernels.ncc_costs`: warp, sliding window sums in float64,
   NCC and best-k fused, rows streamed through the cache); :func:`cost_reference` is its torch version, kept as
   the oracle of its tests.

After all views: geometric consistency (forward-backward reprojection through each source's depth map:
reprojection error ≤ ``geom_max_reproj_px`` and relative depth error ≤ ``geom_max_rel_depth`` in at least
``geom_min_consistent`` sources; the depth becomes the mean of the consistent estimates) and camera-facing
normals from a windowed plane fit on the filtered depth map (numba, float64).

Pixel convention: array element (row, col) is the ray ``K⁻¹·(col, row, 1)`` (COLMAP's dense convention, see
``recon.workspace``); images are sampled there bilinearly (COLMAP pixel centres are at +0.5).

Written by hand because no maintained library offers a CPU MVS that writes COLMAP maps (COLMAP's PatchMatch
needs CUDA). Profile per part, before and after: ``bench/bench_mvs_profile.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from recon.mvs_cpu_kernels import INVALID_COST as _INVALID_COST
from recon.mvs_cpu_kernels import bordered, box_sums, ncc_costs, plane_normals
from recon.mvs_cpu_options import CpuMvsOptions  # re-exported: the options live apart, without torch

# neighbour offsets (dy, dx) whose hypotheses each pixel tries in a propagation round (near and far)
_PROPAGATION = ((0, 1), (0, -1), (1, 0), (-1, 0), (0, 4), (0, -4), (4, 0), (-4, 0))


# -- sampling helpers ------------------------------------------------------------------------------
def pixel_rays(K: np.ndarray, height: int, width: int) -> torch.Tensor:
    """(H, W, 3) float32 rays ``K⁻¹·(col, row, 1)`` (unit z) of a pinhole camera."""
    Kinv = torch.as_tensor(np.linalg.inv(K), dtype=torch.float64)
    rows, cols = torch.meshgrid(
        torch.arange(height, dtype=torch.float64), torch.arange(width, dtype=torch.float64), indexing="ij"
    )
    pix = torch.stack([cols, rows, torch.ones_like(cols)], dim=-1)
    return (pix @ Kinv.T).to(torch.float32)


def _box(x: torch.Tensor, r: int) -> torch.Tensor:
    """Separable mean over a (2r+1)² window, (N, 1, H, W); borders average the valid part."""
    k = 2 * r + 1
    x = F.avg_pool2d(x, (1, k), stride=1, padding=(0, r), count_include_pad=False)
    return F.avg_pool2d(x, (k, 1), stride=1, padding=(r, 0), count_include_pad=False)


def _sample(images: torch.Tensor, u: torch.Tensor, v: torch.Tensor, sizes: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of ``images`` (S, 1, Hp, Wp) at continuous COLMAP pixel coords u, v (S, ...).

    ``sizes`` (S, 2) holds each image's (W, H) inside the padded tensor; the result has the shape of u.
    """
    hp, wp = images.shape[-2:]
    gx = 2.0 * u / wp - 1.0
    gy = 2.0 * v / hp - 1.0
    shape = u.shape
    grid = torch.stack([gx, gy], dim=-1).reshape(shape[0], -1, shape[-1], 2)
    out = F.grid_sample(images, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    return out.reshape(shape)


def _resize(img: np.ndarray, width: int, height: int) -> np.ndarray:
    import cv2

    if img.shape[1] == width and img.shape[0] == height:
        return img
    interp = cv2.INTER_AREA if width < img.shape[1] else cv2.INTER_LINEAR
    return cv2.resize(img, (width, height), interpolation=interp)


def _scale_K(K: np.ndarray, sx: float, sy: float) -> np.ndarray:
    K = K.copy()
    K[0, :] *= sx
    K[1, :] *= sy
    return K


# -- photo-consistency -----------------------------------------------------------------------------
@dataclass
class _Level:
    """Tensors of one pyramid level for one reference view."""

    rays: torch.Tensor  # (H, W, 3)
    ref_mu: torch.Tensor  # (1, 1, H, W) window mean of the reference
    ref_std: torch.Tensor  # (1, 1, H, W)
    ref: torch.Tensor  # (1, 1, H, W) reference sampled on its COLMAP grid
    srcs: torch.Tensor  # (S, 1, Hp, Wp) padded sources
    sizes: torch.Tensor  # (S, 2) (W, H) of each source
    src_hw: np.ndarray  # (S, 2) int64 (H, W) of each source
    srcs_bordered: np.ndarray  # (S, Hp + 2, Wp + 2) the padded sources with a zero border (the numba kernel's input)
    P: torch.Tensor  # (S, 3, H, W) K_src · R · ray: homogeneous source pixel of each ray at unit inverse depth
    q: torch.Tensor  # (S, 3) K_src · t
    radius: int
    best_k: int


def _make_level(ref_img, src_imgs, K_ref, K_srcs, src_from_ref, radius, best_k) -> _Level:
    h, w = ref_img.shape
    ref_full = torch.from_numpy(ref_img)[None, None]
    rows, cols = torch.meshgrid(
        torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij"
    )
    sizes1 = torch.tensor([[w, h]], dtype=torch.float32)
    ref = _sample(ref_full, cols[None], rows[None], sizes1)[None]  # COLMAP grid: element (r, c) at (c, r)
    mu = _box(ref, radius)
    var = (_box(ref * ref, radius) - mu * mu).clamp_min(0.0)
    hp = max(s.shape[0] for s in src_imgs)
    wp = max(s.shape[1] for s in src_imgs)
    srcs = torch.zeros(len(src_imgs), 1, hp, wp)
    for i, s in enumerate(src_imgs):
        srcs[i, 0, : s.shape[0], : s.shape[1]] = torch.from_numpy(s)
    sizes = torch.tensor([[s.shape[1], s.shape[0]] for s in src_imgs], dtype=torch.float32)
    m = np.stack(src_from_ref).astype(np.float64)
    Ksrc = np.stack(K_srcs).astype(np.float64)
    KR = torch.as_tensor(Ksrc @ m[:, :3, :3], dtype=torch.float32)  # (S, 3, 3)
    rays = pixel_rays(K_ref, h, w)
    return _Level(
        rays=rays,
        ref_mu=mu,
        ref_std=var.sqrt(),
        ref=ref,
        srcs=srcs,
        sizes=sizes,
        src_hw=np.array([s.shape for s in src_imgs], np.int64),
        srcs_bordered=bordered(srcs[:, 0].numpy()),
        P=torch.einsum("sij,hwj->sihw", KR, rays).contiguous(),
        q=torch.as_tensor(np.einsum("sij,sj->si", Ksrc, m[:, :3, 3]), dtype=torch.float32),
        radius=radius,
        best_k=best_k,
    )


def _cost(level: _Level, inv_depth: torch.Tensor) -> torch.Tensor:
    """Aggregated matching cost (B, H, W) for per-pixel inverse-depth hypotheses (B, H, W), 1/metres.

    The numba kernel :func:`recon.mvs_cpu_kernels.ncc_costs`; :func:`cost_reference` is its torch oracle.
    """
    costs = ncc_costs(
        level.srcs_bordered,
        level.src_hw,
        level.P.numpy(),
        level.q.numpy(),
        level.ref[0, 0].numpy(),
        level.ref_mu[0, 0].numpy(),
        level.ref_std[0, 0].numpy(),
        inv_depth.contiguous().numpy(),
        level.radius,
        level.best_k,
        torch.get_num_threads(),
    )
    return torch.from_numpy(costs)


def cost_reference(level: _Level, inv_depth: torch.Tensor) -> torch.Tensor:
    """Torch reference of :func:`_cost` (tensors over sources × hypotheses × pixels): the oracle of its tests."""
    b, h, w = inv_depth.shape
    s = level.srcs.shape[0]
    inv = inv_depth.clamp_min(1e-8)[None]  # (1, B, H, W)
    # homogeneous source pixel of X = ray / inv, scaled by inv (> 0): P·ray + q·inv
    q = level.q[:, :, None, None, None]
    z = level.P[:, 2, None] + q[:, 2] * inv  # (S, B, H, W), sign of the source depth
    zc = z.clamp_min(1e-9)
    u = (level.P[:, 0, None] + q[:, 0] * inv) / zc
    v = (level.P[:, 1, None] + q[:, 1] * inv) / zc
    wlim = level.sizes[:, 0, None, None, None]
    hlim = level.sizes[:, 1, None, None, None]
    valid = (z > 1e-9) & (u >= 0.5) & (v >= 0.5) & (u <= wlim - 0.5) & (v <= hlim - 0.5)
    warped = _sample(level.srcs, u, v, level.sizes)  # (S, B, H, W)
    r = level.radius
    flat = warped.reshape(s * b, 1, h, w)
    mu = _box(flat, r)
    var = (_box(flat * flat, r) - mu * mu).clamp_min(0.0)
    cross = _box(flat * level.ref, r) - mu * level.ref_mu
    ncc = cross / (var.sqrt() * level.ref_std + 1e-6)
    cost = (1.0 - ncc).reshape(s, b, h, w).clamp(0.0, _INVALID_COST)
    cost = torch.where(valid & (var.reshape(s, b, h, w) > 1e-8), cost, torch.full_like(cost, _INVALID_COST))
    k = min(level.best_k, s)
    best = torch.topk(cost, k, dim=0, largest=False).values
    return best.mean(dim=0)


def _evaluate(level: _Level, hyps: torch.Tensor, batch: int) -> torch.Tensor:
    """Costs (N, H, W) of hypotheses (N, H, W), evaluated ``batch`` at a time."""
    return torch.cat([_cost(level, hyps[i : i + batch]) for i in range(0, hyps.shape[0], batch)])


def _take_best(
    level: _Level, hyps: torch.Tensor, best: torch.Tensor, best_cost: torch.Tensor, batch: int
) -> tuple[torch.Tensor, torch.Tensor]:
    for i in range(0, hyps.shape[0], batch):
        chunk = hyps[i : i + batch]
        costs = _cost(level, chunk)
        c, idx = costs.min(dim=0)
        better = c < best_cost
        best = torch.where(better, chunk.gather(0, idx[None])[0], best)
        best_cost = torch.where(better, c, best_cost)
    return best, best_cost


def _parabola(level: _Level, best: torch.Tensor, best_cost: torch.Tensor, step: float, batch: int):
    """Sub-step refinement: parabola through costs at best − step, best, best + step."""
    cm, cp = _evaluate(level, torch.stack([best - step, best + step]), batch)
    denom = cm - 2 * best_cost + cp
    offset = torch.where(denom > 1e-6, 0.5 * (cm - cp) / denom.clamp_min(1e-6), torch.zeros_like(denom))
    offset = offset.clamp(-1.0, 1.0)
    refined = best + offset * step
    refined_cost = best_cost - 0.25 * (cm - cp) * offset  # value of the parabola at its vertex
    ok = (cm < _INVALID_COST) & (cp < _INVALID_COST)
    return torch.where(ok, refined, best), torch.where(ok, refined_cost.clamp_min(0.0), best_cost)


def _median(x: torch.Tensor, r: int) -> torch.Tensor:
    """Median over a (2r+1)² window of an (H, W) map (edges replicated)."""
    if r <= 0:
        return x
    k = 2 * r + 1
    padded = F.pad(x[None, None], (r, r, r, r), mode="replicate")
    return F.unfold(padded, k).median(dim=1).values.reshape(x.shape)


def _shift(x: torch.Tensor, dy: int, dx: int) -> torch.Tensor:
    """``x`` (H, W) moved so that output (r, c) = x(r + dy, c + dx), edges replicated."""
    h, w = x.shape
    rows = (torch.arange(h) + dy).clamp(0, h - 1)
    cols = (torch.arange(w) + dx).clamp(0, w - 1)
    return x[rows][:, cols]


# -- per-view estimation ---------------------------------------------------------------------------
@dataclass
class DepthEstimate:
    """Photometric result for one view: z-depth (H, W) float32 metres (0 = invalid) and cost (H, W) float32."""

    depth: np.ndarray
    cost: np.ndarray


def estimate_depth(
    ref_img: np.ndarray,
    src_imgs: list[np.ndarray],
    K_ref: np.ndarray,
    K_srcs: list[np.ndarray],
    src_from_ref: list[np.ndarray],
    depth_range: tuple[float, float],
    options: CpuMvsOptions = CpuMvsOptions(),
) -> DepthEstimate:
    """Depth map of a reference view from source views.

    ref_img, src_imgs: (H, W) float32 gray in [0, 1]. K_*: 3×3 pinhole intrinsics (COLMAP pixel units) of the
    given images. src_from_ref: 4×4 (or 3×4) rigid transforms from the reference to each source camera frame.
    depth_range: (near, far) z-depth in metres. Returns depth at the reference's resolution.
    """
    if not src_imgs:
        h, w = ref_img.shape
        return DepthEstimate(np.zeros((h, w), np.float32), np.full((h, w), _INVALID_COST, np.float32))
    near = max(float(depth_range[0]), 1e-6)
    far = max(float(depth_range[1]), near * 1.01)
    inv_lo, inv_hi = 1.0 / far, 1.0 / near
    effort = options.effort()
    h, w = ref_img.shape
    levels = max(1, int(math.ceil(math.log2(max(h, w) / max(options.coarse_size, 8)))) + 1)
    batch = options.batch_hypotheses
    with torch.no_grad():
        for lvl in range(levels):
            level = _pyramid_level(ref_img, src_imgs, K_ref, K_srcs, src_from_ref, 2.0 ** (lvl + 1 - levels), options)
            if lvl == 0:
                best, best_cost = _sweep(level, inv_lo, inv_hi, effort.num_planes, options)
                step = (inv_hi - inv_lo) / max(effort.num_planes - 1, 1)
            else:
                best, best_cost = _upsample(level, best, inv_lo, inv_hi, batch)
                step *= 4.0  # upsampling error exceeds the last step of the coarser level
            rounds = effort.finest_rounds if lvl == levels - 1 else effort.refine_rounds
            best, best_cost = _refine(level, best, best_cost, step, rounds, effort.far_propagation, options)
            step *= 0.5**rounds
            best, best_cost = _parabola(level, best, best_cost, step, batch)
        tex_ok = level.ref_std[0, 0] >= options.min_texture_std
        ok = tex_ok & (best_cost <= options.max_cost) & (best > 0)
        depth = torch.where(ok, 1.0 / best.clamp_min(1e-8), torch.zeros_like(best))
    return DepthEstimate(depth.numpy().astype(np.float32), best_cost.numpy().astype(np.float32))


def _pyramid_level(
    ref_img: np.ndarray,
    src_imgs: list[np.ndarray],
    K_ref: np.ndarray,
    K_srcs: list[np.ndarray],
    src_from_ref: list[np.ndarray],
    f: float,
    options: CpuMvsOptions,
) -> _Level:
    """The images and cameras of :func:`estimate_depth` scaled by ``f`` (≤ 1), as a :class:`_Level`."""
    h, w = ref_img.shape
    lw, lh = max(8, round(w * f)), max(8, round(h * f))
    srcs_l, Ks_l = [], []
    for img, K in zip(src_imgs, K_srcs, strict=True):
        sw, sh = max(8, round(img.shape[1] * f)), max(8, round(img.shape[0] * f))
        srcs_l.append(_resize(img, sw, sh))
        Ks_l.append(_scale_K(K, sw / img.shape[1], sh / img.shape[0]))
    # window: finest radius at every level (a coarse pixel covers more surface, so the window grows in metres)
    K_l = _scale_K(K_ref, lw / w, lh / h)
    return _make_level(_resize(ref_img, lw, lh), srcs_l, K_l, Ks_l, src_from_ref, options.window_radius, options.best_k)


def _sweep(
    level: _Level, inv_lo: float, inv_hi: float, num_planes: int, options: CpuMvsOptions
) -> tuple[torch.Tensor, torch.Tensor]:
    """Winner-take-all over fronto-parallel planes uniform in inverse depth [inv_lo, inv_hi] (1/metres), then a
    median and a box filter; returns (inverse depth, its cost), each (H, W)."""
    h, w = level.ref.shape[-2:]
    planes = torch.linspace(inv_lo, inv_hi, num_planes)
    costs = _evaluate(level, planes[:, None, None].expand(-1, h, w).contiguous(), options.batch_hypotheses)
    idx = costs.min(dim=0).indices
    # fronto-parallel sweeps are noisy on slanted surfaces; a median keeps edges and lets the
    # per-pixel (implicitly slanted) windows of the refinement rounds start from a coherent surface
    r = options.median_radius
    best = _box(_median(planes[idx], r)[None, None], r)[0, 0]
    return best, _cost(level, best[None])[0]


def _upsample(
    level: _Level, prev: torch.Tensor, inv_lo: float, inv_hi: float, batch: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """The coarser level's inverse depth (h, w) brought to this level: per pixel the best of the bilinear upsampling
    and the nearest coarse pixel's and its 4 neighbours' values (keeps discontinuities sharp)."""
    size = tuple(level.ref.shape[-2:])
    up = F.interpolate(prev[None, None], size=size, mode="bilinear", align_corners=False)[0, 0]
    near_n = [
        F.interpolate(_shift(prev, dy, dx)[None, None], size=size, mode="nearest")[0, 0]
        for dy, dx in ((0, 0), (0, 1), (1, 0), (0, -1), (-1, 0))
    ]
    hyps = torch.stack([up] + near_n).clamp(inv_lo * 0.5, inv_hi * 2)
    return _take_best(level, hyps, up, torch.full(size, float("inf")), batch)


def _refine(
    level: _Level,
    best: torch.Tensor,
    best_cost: torch.Tensor,
    step: float,
    rounds: int,
    far: bool,
    options: CpuMvsOptions,
) -> tuple[torch.Tensor, torch.Tensor]:
    """PatchMatch-style rounds: the neighbours' hypotheses (Jacobi propagation; ``far``: those 4 px away too),
    local-plane hypotheses and perturbations ± k·step (1/metres), the step halving each round."""
    offsets = _PROPAGATION if far else _PROPAGATION[:4]
    for _ in range(rounds):
        cand = [_shift(best, dy, dx) for dy, dx in offsets]
        # local-plane hypotheses: inverse depth is affine in pixel coordinates on a plane, so window means
        # of it are exact on planes and turn sweep staircases into slopes
        cand += [_box(best[None, None], r)[0, 0] for r in (1, 3)]
        cand += [best + k * step for k in range(-options.refine_steps, options.refine_steps + 1) if k]
        best, best_cost = _take_best(level, torch.stack(cand), best, best_cost, options.batch_hypotheses)
        step *= 0.5
    return best, best_cost


# -- geometric consistency and normals ---------------------------------------------------------------
def geometric_filter(
    depth_ref: np.ndarray,
    K_ref: np.ndarray,
    src_depths: list[np.ndarray],
    K_srcs: list[np.ndarray],
    src_from_ref: list[np.ndarray],
    max_reproj_px: float = 1.0,
    max_rel_depth: float = 0.01,
    min_consistent: int = 2,
) -> tuple[np.ndarray, np.ndarray]:
    """Forward-backward consistency of a depth map (H, W) against source depth maps.

    A pixel is projected with its depth into each source, the source's depth at the nearest element is
    back-projected and projected back; it agrees when the reprojection error ≤ ``max_reproj_px`` and the
    relative z difference ≤ ``max_rel_depth``. Returns (filtered depth with the mean of the agreeing
    estimates, 0 elsewhere; number of agreeing sources (H, W) int32).
    """
    h, w = depth_ref.shape
    d = torch.from_numpy(np.asarray(depth_ref, np.float32))
    rays = pixel_rays(K_ref, h, w)
    X = rays * d[..., None]
    rows, cols = torch.meshgrid(
        torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij"
    )
    count = torch.zeros(h, w, dtype=torch.int32)
    total = d.clone()
    for dsrc, Ks, M in zip(src_depths, K_srcs, src_from_ref, strict=True):
        M = torch.as_tensor(np.asarray(M, np.float64)[:3], dtype=torch.float32)
        Ks_t = torch.as_tensor(Ks, dtype=torch.float32)
        Xs = X @ M[:, :3].T + M[:, 3]
        z = Xs[..., 2].clamp_min(1e-6)
        u = Ks_t[0, 0] * Xs[..., 0] / z + Ks_t[0, 2]
        v = Ks_t[1, 1] * Xs[..., 1] / z + Ks_t[1, 2]
        hs, ws = dsrc.shape
        ci, ri = torch.round(u).long(), torch.round(v).long()
        inside = (Xs[..., 2] > 1e-6) & (ci >= 0) & (ri >= 0) & (ci < ws) & (ri < hs) & (d > 0)
        ci, ri = ci.clamp(0, ws - 1), ri.clamp(0, hs - 1)
        ds = torch.from_numpy(np.asarray(dsrc, np.float32))[ri, ci]
        pix = torch.stack([ci.float(), ri.float(), torch.ones_like(u)], dim=-1)
        Xb = (pix @ torch.linalg.inv(Ks_t).T) * ds[..., None]  # back in the source frame
        Xr = (Xb - M[:, 3]) @ M[:, :3]  # to the reference frame
        zr = Xr[..., 2]
        zrc = zr.clamp_min(1e-6)
        K = torch.as_tensor(K_ref, dtype=torch.float32)
        ur = K[0, 0] * Xr[..., 0] / zrc + K[0, 2]
        vr = K[1, 1] * Xr[..., 1] / zrc + K[1, 2]
        err = torch.hypot(ur - cols, vr - rows)
        rel = (zr - d).abs() / d.clamp_min(1e-6)
        agree = inside & (ds > 0) & (zr > 0) & (err <= max_reproj_px) & (rel <= max_rel_depth)
        count += agree.int()
        total += torch.where(agree, zr, torch.zeros_like(zr))
    keep = (count >= min_consistent) & (d > 0)
    mean = total / (count.float() + 1.0)
    out = torch.where(keep, mean, torch.zeros_like(mean))
    return out.numpy().astype(np.float32), count.numpy()


def normals_from_depth(depth: np.ndarray, K: np.ndarray, radius: int = 2, min_points: int = 6) -> np.ndarray:
    """Camera-frame unit normals (H, W, 3) float32 from a depth map by a plane fit over a (2r+1)² window.

    Normals face the camera (n · X < 0); pixels with fewer than ``min_points`` valid neighbours, or invalid
    depth, get (0, 0, 0). Neighbours deeper or nearer by more than 5 % are excluded (no fit across edges).
    """
    h, w = depth.shape
    d = np.asarray(depth, np.float32)
    valid = d > 0
    X = pixel_rays(K, h, w).numpy() * d[..., None]
    # neighbours across depth discontinuities are left out: a point fits when its depth is within 5 % of the
    # mean valid depth of its own window
    sums = box_sums(np.stack([valid, d * valid], axis=-1), radius, torch.get_num_threads())
    mean_d = sums[..., 1] / np.maximum(sums[..., 0], 1)
    fit = valid & (np.abs(d - mean_d) <= 0.05 * np.maximum(mean_d, 1e-6))
    return plane_normals(X, valid, fit, radius, min_points, torch.get_num_threads())
