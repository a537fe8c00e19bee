"""Plots without matplotlib: SVG charts (histograms, per-view bars) and colour-mapped raster previews.

SVG is written by hand because it is a few lines of text, keeps the HTML report self-contained and
needs no plotting dependency; rasters are numpy arrays encoded as PNG through core.io.images/OpenCV.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence

import cv2
import numpy as np

from core.errors import DataError

# Viridis sampled at 9 evenly spaced stops (perceptually uniform, readable in grey and by colour-blind readers).
_VIRIDIS = np.array(
    [
        [68, 1, 84],
        [71, 44, 122],
        [59, 81, 139],
        [44, 113, 142],
        [33, 144, 141],
        [39, 173, 129],
        [92, 200, 99],
        [170, 220, 50],
        [253, 231, 37],
    ],
    dtype=np.float64,
)
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b")


def colormap(values: np.ndarray, vmin: float = 0.0, vmax: float | None = None) -> np.ndarray:
    """(N, 3) uint8 viridis colours for (N,) values mapped linearly from [vmin, vmax] (clamped)."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if vmax is None:
        vmax = float(np.percentile(v, 99)) if len(v) else 1.0
    span = max(vmax - vmin, 1e-12)
    t = np.clip((v - vmin) / span, 0.0, 1.0) * (len(_VIRIDIS) - 1)
    lo = np.floor(t).astype(np.int64).clip(0, len(_VIRIDIS) - 2)
    frac = (t - lo)[:, None]
    return np.round(_VIRIDIS[lo] * (1 - frac) + _VIRIDIS[lo + 1] * frac).astype(np.uint8)


def preview_image(positions: np.ndarray, values: np.ndarray, width: int = 800, vmax: float | None = None) -> np.ndarray:
    """(H, W, 3) uint8 orthographic preview of points coloured by ``values`` (e.g. C2C distances).

    positions: (N, 3) float64 local coordinates (metres). The view looks along the cloud's axis of least
    variance: top-down (north up) for mostly horizontal data, frontal with z up for a façade; the nearest
    point wins each pixel.
    Background is white.
    """
    pts = np.asarray(positions, dtype=np.float64)
    vals = np.asarray(values, dtype=np.float64).reshape(-1)
    if len(pts) == 0:
        raise DataError("cannot preview an empty cloud")
    centred = pts - pts.mean(axis=0)
    sample = centred[:: max(1, len(centred) // 200_000)]
    _, _, vt = np.linalg.svd(sample, full_matrices=False)
    normal = vt[2] if vt[2, 2] >= 0 else -vt[2]
    up = np.array([0.0, 0.0, 1.0])
    if abs(normal[2]) > 0.7:  # mostly horizontal data: map view, x right, y (north) up
        right, up_axis, normal = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), up
    else:  # a façade or an object side: horizontal right, z up
        right = np.cross(up, normal)
        right /= np.linalg.norm(right)
        up_axis = np.cross(normal, right)
    u, v, depth = centred @ right, -(centred @ up_axis), centred @ normal
    span_u = max(float(np.ptp(u)), 1e-9)
    span_v = max(float(np.ptp(v)), 1e-9)
    height = int(np.clip(round(width * span_v / span_u), 16, 4 * width))
    scale = min((width - 1) / span_u, (height - 1) / span_v)
    cols = ((u - u.min()) * scale).astype(np.int64).clip(0, width - 1)
    rows = ((v - v.min()) * scale).astype(np.int64).clip(0, height - 1)
    order = np.argsort(depth, kind="stable")  # far first, near points overwrite
    image = np.full((height, width, 3), 255, dtype=np.uint8)
    image[rows[order], cols[order]] = colormap(vals[order], 0.0, vmax)
    return image


def png_bytes(image: np.ndarray) -> bytes:
    """PNG encoding of an (H, W, 3) RGB or (H, W) grey uint8 image."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise DataError("PNG encoding failed")
    return buf.tobytes()


def data_uri(image: np.ndarray) -> str:
    """A ``data:image/png;base64,...`` URI for inlining an image in HTML."""
    return "data:image/png;base64," + base64.b64encode(png_bytes(image)).decode("ascii")


def _nice_ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    span = max(hi - lo, 1e-12)
    raw = span / n
    mag = 10 ** np.floor(np.log10(raw))
    step = min((m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw), default=raw)
    start = np.ceil(lo / step) * step
    return [float(t) for t in np.arange(start, hi + step * 1e-6, step)]


def _fmt(v: float) -> str:
    if v == int(v) and abs(v) < 1e7:
        return f"{int(v):,}"
    return f"{v:.3g}"


def svg_bars(
    series: Sequence[tuple[str, Sequence[float]]],
    labels: Sequence[str],
    title: str,
    x_label: str,
    y_label: str,
    edges: Sequence[float] | None = None,
    width: int = 640,
    height: int = 300,
) -> str:
    """An SVG bar chart: one or more named series of equal length, grouped per category.

    With ``edges`` (len = categories + 1) the x axis is numeric (a histogram) and ``labels`` is ignored.
    """
    if not series:
        raise DataError("nothing to plot")
    n = len(series[0][1])
    left, right, top, bottom = 60, 12, 28 + (14 if len(series) > 1 else 0), 44
    pw, ph = width - left - right, height - top - bottom
    ymax = max([max(vals, default=0.0) for _, vals in series] + [1e-12])
    yticks = _nice_ticks(0.0, ymax)
    ymax = max(ymax, yticks[-1]) if yticks else ymax
    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
        f'viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="11">',
        f'<text x="{width / 2}" y="16" text-anchor="middle" font-size="13">{html.escape(title)}</text>',
    ]
    for t in yticks:
        y = top + ph - t / ymax * ph
        out.append(f'<line x1="{left}" x2="{left + pw}" y1="{y:.1f}" y2="{y:.1f}" stroke="#ddd"/>')
        out.append(f'<text x="{left - 4}" y="{y + 4:.1f}" text-anchor="end">{_fmt(t)}</text>')
    slot = pw / max(n, 1)
    bar = slot * 0.9 / len(series)
    for s, (name, vals) in enumerate(series):
        colour = PALETTE[s % len(PALETTE)]
        for i, val in enumerate(vals):
            h = max(float(val), 0.0) / ymax * ph
            x = left + i * slot + slot * 0.05 + s * bar
            out.append(
                f'<rect x="{x:.2f}" y="{top + ph - h:.2f}" width="{max(bar, 0.5):.2f}" height="{h:.2f}" '
                f'fill="{colour}"><title>{html.escape(name)}: {_fmt(float(val))}</title></rect>'
            )
    if edges is not None:
        e0, e1 = float(edges[0]), float(edges[-1])
        for t in _nice_ticks(e0, e1):
            x = left + (t - e0) / max(e1 - e0, 1e-12) * pw
            out.append(f'<text x="{x:.1f}" y="{top + ph + 14}" text-anchor="middle">{_fmt(t)}</text>')
    else:
        step = max(1, n // 12)
        for i in range(0, n, step):
            x = left + (i + 0.5) * slot
            out.append(
                f'<text x="{x:.1f}" y="{top + ph + 14}" text-anchor="middle">{html.escape(str(labels[i]))[:14]}</text>'
            )
    out.append(f'<line x1="{left}" x2="{left}" y1="{top}" y2="{top + ph}" stroke="#333"/>')
    out.append(f'<line x1="{left}" x2="{left + pw}" y1="{top + ph}" y2="{top + ph}" stroke="#333"/>')
    out.append(f'<text x="{left + pw / 2}" y="{height - 6}" text-anchor="middle">{html.escape(x_label)}</text>')
    out.append(
        f'<text x="14" y="{top + ph / 2}" text-anchor="middle" transform="rotate(-90 14 {top + ph / 2})">'
        f"{html.escape(y_label)}</text>"
    )
    if len(series) > 1:
        for s, (name, _) in enumerate(series):
            x = left + 8 + s * 110
            out.append(f'<rect x="{x}" y="{top - 18}" width="10" height="10" fill="{PALETTE[s % len(PALETTE)]}"/>')
            out.append(f'<text x="{x + 14}" y="{top - 9}">{html.escape(name)}</text>')
    out.append("</svg>")
    return "\n".join(out)


def svg_histogram(edges: Sequence[float], counts: Sequence[int], title: str, x_label: str = "distance (m)") -> str:
    """An SVG histogram of C2C distances from :func:`eval.c2c.histogram` output."""
    return svg_bars([("points", [float(c) for c in counts])], [], title, x_label, "points", edges=list(edges))
