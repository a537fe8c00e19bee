"""fusion.render: differentiable Gaussian-splat rendering with interchangeable backends.

- :func:`render` — functional API over torch tensors (means, quats, log-scales, logit opacities, SH, one pinhole
  camera) returning a :class:`RenderResult`; backends ``reference`` (pure PyTorch), ``cpu`` (numba, hand-written
  backward) and ``gsplat`` (CUDA), ``auto`` picks gsplat on CUDA else cpu.
- :func:`render_gaussian_set` — a :class:`core.GaussianSet` at a COLMAP camera/view, large-coordinate safe.
- :func:`render_brute_force` — the float64 per-pixel oracle used by the tests.

The names are imported lazily (:func:`core.lazy.lazy_exports`): ``import fusion.render`` or a torch-free
submodule does not load torch; the first use of a name imports its submodule.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from core.lazy import lazy_exports

if TYPE_CHECKING:
    from fusion.render.api import render, resolve_backend
    from fusion.render.brute_force import render_brute_force
    from fusion.render.gsplat_backend import gsplat_available
    from fusion.render.projection import Projection, project_gaussians
    from fusion.render.scene import render_gaussian_set
    from fusion.render.sh import sh_to_colour
    from fusion.render.types import Backend, RenderedImage, RenderResult

#: name -> submodule that defines it (imported on first access: the package itself imports nothing heavy)
_EXPORTS: dict[str, str] = {
    "Backend": "types",
    "Projection": "projection",
    "RenderResult": "types",
    "RenderedImage": "types",
    "gsplat_available": "gsplat_backend",
    "project_gaussians": "projection",
    "render": "api",
    "render_brute_force": "brute_force",
    "render_gaussian_set": "scene",
    "resolve_backend": "api",
    "sh_to_colour": "sh",
}

__all__ = [
    "Backend",
    "Projection",
    "RenderResult",
    "RenderedImage",
    "gsplat_available",
    "project_gaussians",
    "render",
    "render_brute_force",
    "render_gaussian_set",
    "resolve_backend",
    "sh_to_colour",
]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
