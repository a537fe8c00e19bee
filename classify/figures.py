"""Figures of the classification for the HTML report: the classified cloud, the feature importances, masks on photos.

Each function returns PNG bytes (matplotlib's object API on the Agg canvas: no display, no global state); the
stages write them to the paths the project layout names and the report embeds them.
"""

from __future__ import annotations

import io
from collections.abc import Sequence

import numpy as np

from classify.classes import ClassSet
from core.errors import DataError

# One colour per class code (matplotlib's tab10 order, collaborative grey), RGB in [0, 1].
_PALETTE = (
    (0.62, 0.62, 0.62),
    (0.84, 0.15, 0.16),
    (0.12, 0.47, 0.71),
    (1.00, 0.50, 0.05),
    (0.58, 0.40, 0.74),
    (0.17, 0.63, 0.17),
    (0.55, 0.34, 0.29),
    (0.89, 0.47, 0.76),
    (0.74, 0.74, 0.13),
    (0.09, 0.75, 0.81),
)


def class_colour(code: int) -> tuple[float, float, float]:
    """The RGB colour (components in [0, 1]) used for class ``code`` in every figure."""
    return _PALETTE[int(code) % len(_PALETTE)]


def _figure(width_in: float, height_in: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in))
    FigureCanvasAgg(fig)
    return fig


def _png(fig, dpi: int = 100) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    return buf.getvalue()


def classified_cloud_png(
    positions: np.ndarray,
    classification: np.ndarray,
    classes: ClassSet,
    max_points: int = 200_000,
    seed: int = 0,
    counts: dict[int, int] | None = None,
) -> bytes:
    """Top-down (x–y) and side (x–z) scatter plots of the cloud coloured by class, with a legend of the point counts.

    positions: (N, 3) float64 metres, local frame (z up). classification: (N,) uint8 class codes. At most
    ``max_points`` points are drawn (a seeded sample, :func:`plotted_points`); the collaborative class is drawn
    first and small so that the rarer needs-splats classes stay visible on top. counts: class code → points of the
    whole cloud, when ``positions`` and ``classification`` are already that sample (a streamed cloud's).
    """
    pts = np.asarray(positions, dtype=np.float64)
    codes = np.asarray(classification)
    if len(pts) != len(codes):
        raise DataError(f"{len(codes)} classes for {len(pts)} points")
    if len(pts) == 0:
        raise DataError("cannot plot an empty cloud")
    if counts is None:
        idx = plotted_points(len(pts), max_points, seed)
        p, c = (pts, codes) if idx is None else (pts[idx], codes[idx])
        counts = {int(code): int(np.count_nonzero(codes == code)) for code in np.unique(codes)}
    else:
        p, c = pts, codes
    fig = _figure(11.0, 5.2)
    top, side = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    size = float(np.clip(4e4 / len(p), 0.3, 6.0))
    for spec in sorted(classes.classes, key=lambda s: (s.needs_splats, s.code)):
        sel = c == spec.code
        n_all = counts.get(spec.code, 0)
        if not sel.any():
            continue
        label = f"{spec.name} ({n_all:,})" + (" — splats" if spec.needs_splats else "")
        s = size if not spec.needs_splats else size * 2.5
        for ax, (a, b) in ((top, (0, 1)), (side, (0, 2))):
            ax.scatter(p[sel, a], p[sel, b], s=s, c=[class_colour(spec.code)], linewidths=0, label=label)
    top.set_title("top view (x, y)")
    side.set_title("side view (x, z)")
    for ax in (top, side):
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    side.set_ylabel("z (m)")
    handles, labels = top.get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=min(5, len(labels)), markerscale=4, frameon=False)
    fig.subplots_adjust(bottom=0.2)
    return _png(fig)


def plotted_points(n: int, max_points: int = 200_000, seed: int = 0) -> np.ndarray | None:
    """The rows (ascending int64) of a cloud of ``n`` points that :func:`classified_cloud_png` draws: a seeded
    sample of ``max_points`` when there are more, else None (every point)."""
    if n <= max_points:
        return None
    return np.sort(np.random.default_rng(seed).choice(n, max_points, replace=False))


def importances_png(names: Sequence[str], importances: Sequence[float], top: int = 20) -> bytes:
    """A horizontal bar chart of the ``top`` largest feature importances (mean decrease in impurity)."""
    vals = np.asarray(importances, dtype=np.float64)
    if len(vals) != len(names) or len(vals) == 0:
        raise DataError(f"{len(vals)} importances for {len(names)} features")
    order = np.argsort(-vals)[:top][::-1]
    fig = _figure(6.5, 0.28 * len(order) + 1.0)
    ax = fig.add_subplot(1, 1, 1)
    ax.barh(np.arange(len(order)), vals[order], color="#4c72b0")
    ax.set_yticks(np.arange(len(order)), [names[i] for i in order], fontsize=8)
    ax.set_xlabel("importance (mean decrease in impurity)")
    ax.set_title(f"feature importances (top {len(order)} of {len(vals)})")
    return _png(fig)


def overlay(photo: np.ndarray, mask: np.ndarray, colour: tuple[int, int, int] = (255, 0, 0), alpha: float = 0.45):
    """The photo (H, W, 3) uint8 RGB with the mask (H, W) bool blended in ``colour`` and its outline drawn."""
    import cv2

    img = np.asarray(photo)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    m = np.asarray(mask, dtype=bool)
    if m.shape != img.shape[:2]:
        m = cv2.resize(m.astype(np.uint8), (img.shape[1], img.shape[0]), interpolation=cv2.INTER_NEAREST) > 0
    out = img.astype(np.float32)
    out[m] = (1 - alpha) * out[m] + alpha * np.asarray(colour, dtype=np.float32)
    out = out.astype(np.uint8)
    contours, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(out, contours, -1, colour, 1)
    return out


def masks_png(panels: Sequence[tuple[str, np.ndarray, np.ndarray, float]], columns: int = 2) -> bytes:
    """Photos with their masks overlaid (red), one panel per (name, photo (H, W, 3) uint8, mask (H, W) bool,
    coverage share), in a grid of ``columns``."""
    if not panels:
        raise DataError("no photo to show")
    cols = min(columns, len(panels))
    rows = int(np.ceil(len(panels) / cols))
    h, w = panels[0][1].shape[:2]
    fig = _figure(5.0 * cols, 5.0 * cols * rows * h / max(w, 1) / cols + 0.4 * rows)
    for i, (name, photo, mask, cov) in enumerate(panels):
        ax = fig.add_subplot(rows, cols, i + 1)
        ax.imshow(overlay(photo, mask))
        ax.set_title(f"{name}: mask {cov:.1%} of the photo", fontsize=9)
        ax.axis("off")
    return _png(fig)
