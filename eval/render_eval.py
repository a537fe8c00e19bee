"""Image evaluation of products: render Gaussian sets at held-out cameras and compare with the photos.

:func:`evaluate_pairs` scores (rendered, photo, mask) triples; :func:`evaluate_folders` pairs image files
by name (for ``hybridsplat eval images``); :func:`evaluate_gaussians` renders a :class:`core.GaussianSet`
through ``fusion.render`` (imported lazily) at the given views and scores the renders. Side-by-side
panels (render | photo | error map) are written as PNG under ``out_dir/plots`` for the report.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from core.cameras import Cameras, View
from core.errors import DataError, InputFileError
from core.gaussians import GaussianSet
from core.io.images import IMAGE_SUFFIXES, read_image, write_image
from eval.image_metrics import error_map, image_scores, to_float_image
from eval.metrics_io import ImageEval, ViewScores
from eval.plots import colormap


@dataclass(frozen=True)
class ImagePair:
    """One comparison: ``rendered`` and ``photo`` (H, W, 3) uint8 or float in [0, 1]; ``mask`` (H, W) bool or None."""

    view: str
    rendered: np.ndarray
    photo: np.ndarray
    mask: np.ndarray | None = None


def side_by_side(rendered: np.ndarray, photo: np.ndarray, max_error: float = 0.25) -> np.ndarray:
    """(H, 3W + 8, 3) uint8 panel: render | photo | per-pixel RMS colour error (viridis, 0 .. ``max_error``)."""
    a, b = to_float_image(rendered), to_float_image(photo)
    err = error_map(a, b)
    err_rgb = colormap(err.reshape(-1), 0.0, max_error).reshape(*err.shape, 3)
    gap = np.full((a.shape[0], 4, 3), 255, dtype=np.uint8)
    to8 = lambda x: np.clip(np.round(x * 255), 0, 255).astype(np.uint8)  # noqa: E731
    return np.concatenate([to8(a), gap, to8(b), gap, err_rgb], axis=1)


def evaluate_pairs(
    pairs: Iterable[ImagePair],
    lpips_model: object | None = None,
    out_dir: str | PathLike[str] | None = None,
    name: str = "product",
    max_panels: int = 4,
) -> ImageEval:
    """Score every pair whole-image and (when it has a non-empty mask) masked; aggregate over views.

    With ``out_dir``, the first ``max_panels`` views get a side-by-side panel ``plots/render_<name>_<view>.png``.
    """
    views: list[ViewScores] = []
    for i, pair in enumerate(pairs):
        full = image_scores(pair.rendered, pair.photo, None, lpips_model)
        masked = share = None
        if pair.mask is not None:
            mask = np.asarray(pair.mask).astype(bool)
            share = float(mask.mean())
            if mask.any():
                masked = image_scores(pair.rendered, pair.photo, mask, lpips_model)
        files: dict[str, str] = {}
        if out_dir is not None and i < max_panels:
            rel = f"plots/render_{name}_{Path(pair.view).stem}.png"
            write_image(Path(out_dir) / rel, side_by_side(pair.rendered, pair.photo))
            files["panel"] = rel
        views.append(ViewScores(pair.view, full, masked, share, files))
    return ImageEval.from_views(views)


def _index_images(folder: Path) -> dict[str, Path]:
    if not folder.is_dir():
        raise InputFileError("image folder does not exist", folder)
    return {p.stem: p for p in sorted(folder.iterdir()) if p.suffix.lower() in IMAGE_SUFFIXES}


def load_mask(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool mask from a PNG (non-zero = inside); must match ``shape``."""
    m = read_image(path, grayscale=True) > 0
    if m.shape != shape:
        raise DataError(f"mask is {m.shape[1]}×{m.shape[0]} but the image is {shape[1]}×{shape[0]}", path)
    return m


def folder_pairs(
    renders: str | PathLike[str], photos: str | PathLike[str], masks: str | PathLike[str] | None = None
) -> list[ImagePair]:
    """Pairs of images with the same file stem in ``renders`` and ``photos`` (masks matched the same way).

    Raises :class:`InputFileError` when no names match.
    """
    r, p = _index_images(Path(renders)), _index_images(Path(photos))
    m = _index_images(Path(masks)) if masks is not None else {}
    common = sorted(set(r) & set(p))
    if not common:
        raise InputFileError(f"no image in {renders} has a photo of the same name in {photos}", Path(renders))
    pairs = []
    for stem in common:
        rendered, photo = read_image(r[stem]), read_image(p[stem])
        if rendered.shape != photo.shape:
            raise DataError(
                f"render is {rendered.shape[1]}×{rendered.shape[0]}, photo {photo.shape[1]}×{photo.shape[0]}", r[stem]
            )
        mask = load_mask(m[stem], photo.shape[:2]) if stem in m else None
        pairs.append(ImagePair(r[stem].name, rendered, photo, mask))
    return pairs


def evaluate_folders(
    renders: str | PathLike[str],
    photos: str | PathLike[str],
    masks: str | PathLike[str] | None = None,
    lpips_model: object | None = None,
    out_dir: str | PathLike[str] | None = None,
    name: str = "images",
) -> ImageEval:
    """Score renders against photos matched by file name (see :func:`folder_pairs`)."""
    return evaluate_pairs(folder_pairs(renders, photos, masks), lpips_model, out_dir, name)


def render_view(
    gaussians: GaussianSet, cameras: Cameras, view: View, background: Sequence[float] | None = None
) -> np.ndarray:
    """(H, W, 3) float32 colour in [0, 1] of ``gaussians`` seen from ``view`` (through ``fusion.render``)."""
    from fusion.render import render_gaussian_set  # lazy: eval depends on fusion only for rendering

    result = render_gaussian_set(
        gaussians,
        cameras.camera_of(view),
        view,
        cameras_origin=cameras.origin,
        background=None if background is None else np.asarray(background, dtype=np.float64),
    )
    colour = result.colour.detach().cpu().numpy() if hasattr(result.colour, "detach") else np.asarray(result.colour)
    return np.clip(colour.astype(np.float32), 0.0, 1.0)


def evaluate_gaussians(
    gaussians: GaussianSet,
    cameras: Cameras,
    views: Sequence[View],
    photos: str | PathLike[str],
    masks: str | PathLike[str] | None = None,
    lpips_model: object | None = None,
    out_dir: str | PathLike[str] | None = None,
    name: str = "merged",
    background: Sequence[float] | None = None,
) -> ImageEval:
    """Render ``gaussians`` at each held-out ``view`` and compare with ``photos/<view.name>``.

    Masks (optional) are ``masks/<stem>.png``; a view without a mask file gets only whole-image metrics.
    Photos must have the camera's size (use undistorted photos for distorted camera models).
    """
    photo_dir = Path(photos)
    mask_dir = Path(masks) if masks is not None else None

    def pairs() -> Iterable[ImagePair]:
        for view in views:
            photo_path = photo_dir / view.name
            photo = read_image(photo_path)
            rendered = render_view(gaussians, cameras, view, background)
            if rendered.shape[:2] != photo.shape[:2]:
                raise DataError(
                    f"photo is {photo.shape[1]}×{photo.shape[0]} but the camera renders "
                    f"{rendered.shape[1]}×{rendered.shape[0]}",
                    photo_path,
                )
            mask = None
            if mask_dir is not None and (mask_dir / f"{Path(view.name).stem}.png").is_file():
                mask = load_mask(mask_dir / f"{Path(view.name).stem}.png", photo.shape[:2])
            yield ImagePair(view.name, rendered, photo, mask)

    return evaluate_pairs(pairs(), lpips_model, out_dir, name)
