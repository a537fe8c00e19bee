"""Rendering trainable splats together with frozen context Gaussians for one training view.

The frozen Gaussians never change, so their projection, colour and culling are computed once per view and cached
(:class:`ContextProjection`); each step only the trainable splats are projected (with autograd) and both sets are
composited in one rasterisation so that occlusion between them is exact (the context's own gradients are never
computed). Same conventions and kernels as :func:`fusion.render.render` (backends ``cpu`` and ``reference``).

With ``geometry`` (the steps of the geometric losses, :class:`fusion.train.options.GeometryOptions`) the same
rasterisation composites 8 features (colour, z, camera-frame normal, plane distance) and returns the
:class:`fusion.render.types.RenderGeometry` of both sets together; the context's normals and plane distances are
cached with its projection (computed once per view, no gradients), the trainable ones come from
:func:`fusion.render.normals_cpu.gaussian_normals_cpu` (``cpu``) or
:func:`fusion.render.projection.gaussian_normals` (``reference``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from core.errors import ConfigError
from fusion.render.api import geometry_from_raster
from fusion.render.cpu import rasterize_cpu, rasterize_geometry_cpu
from fusion.render.normals_cpu import gaussian_normals_cpu
from fusion.render.project_cpu import project_splats_cpu
from fusion.render.projection import gaussian_normals, project_gaussians
from fusion.render.reference import rasterize_reference, rasterize_reference_geometry
from fusion.render.sh import sh_to_colour
from fusion.render.types import RenderGeometry
from fusion.train.params import ContextGaussians
from fusion.train.views import TrainView, boxes_touch_tiles


@dataclass(frozen=True)
class ContextProjection:
    """The frozen Gaussians that matter for one view (visible and touching an active tile), projected; with their
    camera-frame normals (M, 3) and plane distances (M,) when the run has geometric losses (else None)."""

    means2d: torch.Tensor  # (M, 2)
    conics: torch.Tensor  # (M, 3)
    depths: torch.Tensor  # (M,)
    extents: torch.Tensor  # (M, 2)
    opacities: torch.Tensor  # (M,)
    colours: torch.Tensor  # (M, 3)
    index: torch.Tensor  # (M,) int64 rows of the frozen set
    normals: torch.Tensor | None = None  # (M, 3) camera frame, facing the camera
    plane: torch.Tensor | None = None  # (M,) metres, distance of the camera centre to each Gaussian's plane

    def __len__(self) -> int:
        return int(self.means2d.shape[0])


@dataclass(frozen=True)
class StepRender:
    """A training render: colour (H, W, 3) over the background, alpha (H, W), and the trainable splats'
    projected means (N, 2, gradients retained) and visibility (N,) bool; the geometry of both sets (normals, plane
    and median depth of :class:`RenderGeometry`, camera frame) on geometric steps, else None.

    The geometry covers only ``window`` = (row0, row1, col0, col1), the bounding box of the view's rendered pixels
    (the loss pixels and their SSIM reach: every pixel a geometric term reads, 4-neighbours included), so that its
    per-pixel tensor work scales with the region, not the photo; :meth:`crop` cuts a full map to it and
    :meth:`window_K` shifts the intrinsics to it."""

    colour: torch.Tensor
    alpha: torch.Tensor
    means2d: torch.Tensor
    visible: torch.Tensor
    geometry: RenderGeometry | None = None
    window: tuple[int, int, int, int] | None = None

    def crop(self, full: torch.Tensor) -> torch.Tensor:
        """A full-image map (H, W, ...) cut to the geometry's window."""
        r0, r1, c0, c1 = self.window if self.window is not None else (0, full.shape[0], 0, full.shape[1])
        return full[r0:r1, c0:c1]

    def window_K(self, K: torch.Tensor) -> torch.Tensor:
        """The (3, 3) intrinsics of the window (principal point shifted by its corner)."""
        if self.window is None:
            return K
        shifted = K.clone()
        shifted[0, 2] -= self.window[2]
        shifted[1, 2] -= self.window[0]
        return shifted


def geometry_window(view: TrainView) -> tuple[int, int, int, int]:
    """(row0, row1, col0, col1): the bounding box of ``view.render_pixels`` (the whole image when None or empty)."""
    if view.render_pixels is None or not view.render_pixels.any():
        return 0, view.height, 0, view.width
    rows = np.flatnonzero(view.render_pixels.any(axis=1))
    cols = np.flatnonzero(view.render_pixels.any(axis=0))
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def project_context(
    context: ContextGaussians | None, view: TrainView, geometry: bool = False
) -> ContextProjection | None:
    """Project the frozen set into ``view`` once (no gradients), keeping only the Gaussians that can matter; with
    ``geometry`` also their normals and plane distances."""
    if context is None or len(context) == 0:
        return None
    # The numba kernels (float64 inside, one scalar code path per Gaussian) for either backend, not the float32
    # torch twins: a near-flat surfel's 2D covariance determinant cancels, and the float32 conics were neither
    # accurate nor reproducible from run to run (docs/experiments/2026-11-29-resume-determinism.md).
    with torch.no_grad():
        sp = project_splats_cpu(
            context.means, context.quats, context.log_scales, context.logit_opacities, context.sh_coeffs[:, :1],
            context.sh_coeffs[:, 1:], view.viewmat, view.K, view.width, view.height,
            int(round(context.sh_coeffs.shape[1] ** 0.5)) - 1,
        )  # fmt: skip
        keep = sp.visible
        if view.tile_prefix is not None:
            keep = keep & boxes_touch_tiles(sp.means2d, sp.extents, view.tile_prefix)
        idx = torch.nonzero(keep).squeeze(1)
        normals = plane = None
        if geometry:
            normals, plane = gaussian_normals_cpu(context.means[idx], context.quats[idx], context.log_scales[idx],
                                                  view.viewmat)  # fmt: skip
            normals, plane = normals.contiguous(), plane.contiguous()
        return ContextProjection(
            sp.means2d[idx].contiguous(),
            sp.conics[idx].contiguous(),
            sp.depths[idx].contiguous(),
            sp.extents[idx].contiguous(),
            sp.opacities[idx].contiguous(),
            sp.colours[idx].contiguous(),
            idx,
            normals,
            plane,
        )


def _project_trainable(
    params: dict[str, torch.Tensor], view: TrainView, sh_degree: int, backend: str, geometry: bool
) -> tuple[torch.Tensor, ...]:
    """The trainable splats projected into ``view``: means2d, conics, depths, extents, visible, colours, opacities,
    and with ``geometry`` their camera-frame normals (N, 3) and plane distances (N,) (else two None)."""
    normals = plane = None
    if backend == "cpu":
        sp = project_splats_cpu(
            params["means"], params["quats"], params["log_scales"], params["logit_opacities"], params["sh_dc"],
            params["sh_rest"], view.viewmat, view.K, view.width, view.height, sh_degree,
        )  # fmt: skip
        out = (sp.means2d, sp.conics, sp.depths, sp.extents, sp.visible, sp.colours, sp.opacities)
        if geometry:
            normals, plane = gaussian_normals_cpu(params["means"], params["quats"], params["log_scales"], view.viewmat)
        return (*out, normals, plane)
    proj = project_gaussians(
        params["means"], params["quats"], params["log_scales"], view.viewmat, view.K, view.width, view.height
    )
    k = (sh_degree + 1) ** 2
    sh = torch.cat([params["sh_dc"], params["sh_rest"][:, : k - 1]], dim=1)
    colours = sh_to_colour(sh, params["means"] - view.camera_centre, sh_degree)
    if geometry:
        normals, plane = gaussian_normals(params["means"], params["quats"], params["log_scales"], view.viewmat)
    opacities = torch.sigmoid(params["logit_opacities"])
    return proj.means2d, proj.conics, proj.depths, proj.extents, proj.visible, colours, opacities, normals, plane


def render_step(
    params: dict[str, torch.Tensor],
    view: TrainView,
    context: ContextProjection | None,
    sh_degree: int,
    background: torch.Tensor,
    backend: str = "cpu",
    loss_pixels_only: bool = False,
    geometry: bool = False,
) -> StepRender:
    """Render trainable splats (``params`` as in :mod:`fusion.train.params`) plus the cached context into ``view``.

    loss_pixels_only: composite only ``view.render_pixels`` (the pixels the L1 + D-SSIM loss reads; the others get
    the background and no gradient). Exact for that loss, which reads nothing else; a loss with a wider reach
    (MS-SSIM, an LPIPS crop) renders every pixel. geometry: also composite normals and plane distances and return
    :attr:`StepRender.geometry` (the context must then be projected with ``geometry=True``).
    """
    if backend not in ("cpu", "reference"):
        raise ConfigError(f"training renders with the 'cpu' or 'reference' backend, got {backend!r}")
    means2d, conics, depths, extents, visible, colours, opacities, normals, plane = _project_trainable(
        params, view, sh_degree, backend, geometry
    )
    if means2d.requires_grad:
        means2d.retain_grad()
    if view.tile_prefix is not None and len(visible):
        visible = visible & boxes_touch_tiles(means2d, extents, view.tile_prefix)
    features = torch.cat([colours, depths[:, None]], dim=1)
    if geometry:
        features = torch.cat([features, normals, plane[:, None]], dim=1)
    parts = [(means2d, conics, depths, extents, opacities, features, visible)]
    if context is not None and len(context):
        ctx_features = torch.cat([context.colours, context.depths[:, None]], dim=1)
        if geometry:
            if context.normals is None or context.plane is None:
                raise ConfigError("render_step(geometry=True) needs the context projected with geometry=True")
            ctx_features = torch.cat([ctx_features, context.normals, context.plane[:, None]], dim=1)
        ones = torch.ones(len(context), dtype=torch.bool)
        parts.append((context.means2d, context.conics, context.depths, context.extents, context.opacities,
                      ctx_features, ones))  # fmt: skip
    if len(parts) == 1:
        m2, con, dep, ext, opa, feat, vis = parts[0]
    else:
        m2, con, dep, ext, opa, feat, vis = (torch.cat(list(x), dim=0) for x in zip(*parts, strict=True))
    pixels = view.render_pixels if loss_pixels_only else None
    image, median_id = _rasterize(m2, con, opa, feat, ext, dep, vis, view, pixels, len(means2d), backend, geometry)
    alpha = image[..., -1]
    colour = image[..., :3] + (1 - alpha)[..., None] * background
    if not geometry:
        return StepRender(colour, alpha, means2d, visible)
    r0, r1, c0, c1 = window = geometry_window(view)
    out = StepRender(colour, alpha, means2d, visible, None, window)
    geo = geometry_from_raster(image[r0:r1, c0:c1], alpha[r0:r1, c0:c1], dep, median_id[r0:r1, c0:c1],
                               feat[:, 4:7], out.window_K(view.K))  # fmt: skip
    return StepRender(colour, alpha, means2d, visible, geo, window)


def _rasterize(
    m2, con, opa, feat, ext, dep, vis, view: TrainView, pixels, n_trainable: int, backend: str, geometry: bool
) -> tuple[torch.Tensor, torch.Tensor | None]:  # fmt: skip
    """One rasterisation of the concatenated rows (the first ``n_trainable`` trainable, the rest frozen): the
    (H, W, C + 1) image and, with ``geometry``, the (H, W) median Gaussian ids (else None)."""
    if backend == "cpu":
        frozen = np.zeros(len(m2), bool)
        frozen[n_trainable:] = True  # the context: its backward only composites
        if geometry:
            return rasterize_geometry_cpu(m2, con, opa, feat, ext, dep.detach(), vis, view.width, view.height,
                                          pixels=pixels, frozen=frozen)  # fmt: skip
        return rasterize_cpu(m2, con, opa, feat, ext, dep.detach(), vis, view.width, view.height, pixels=pixels,
                             frozen=frozen), None  # fmt: skip
    if geometry:
        return rasterize_reference_geometry(m2, con, opa, feat, ext, dep.detach(), vis, view.width, view.height,
                                            pixels=pixels)  # fmt: skip
    return rasterize_reference(m2, con, opa, feat, ext, dep.detach(), vis, view.width, view.height,
                               pixels=pixels), None  # fmt: skip
