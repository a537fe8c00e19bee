"""Plots for reports: matplotlib charts (SVG text or PNG bytes), colour-mapped point previews, JPEG thumbnails.

Charts are drawn with matplotlib's object API (``matplotlib.figure.Figure`` on the Agg canvas): no display, no
pyplot global state, safe to call from any thread. SVG keeps text as text (``svg.fonttype = none``) and a fixed
hash salt, so the same data give the same bytes. Lengths arrive in metres and are drawn in the unit asked for
(:class:`core.units.Units`); image rasters are uint8 RGB arrays.
"""

from __future__ import annotations

import base64
import io
from collections.abc import Mapping, Sequence
from os import PathLike
from pathlib import Path

import cv2
import numpy as np

from core.errors import DataError, InputFileError
from core.units import Units

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
_RC = {"svg.fonttype": "none", "svg.hashsalt": "hybridsplat", "font.size": 9, "axes.titlesize": 10}


# -- rasters ----------------------------------------------------------------------------------------
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


def _view_axes(centred: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, up, normal) unit vectors: a map view for mostly horizontal data, a frontal z-up view otherwise."""
    sample = centred[:: max(1, len(centred) // 200_000)]
    _, _, vt = np.linalg.svd(sample, full_matrices=False)
    normal = vt[2] if vt[2, 2] >= 0 else -vt[2]
    up = np.array([0.0, 0.0, 1.0])
    if abs(normal[2]) > 0.7:  # mostly horizontal data: map view, x right, y (north) up
        return np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), up
    right = np.cross(up, normal)
    right /= np.linalg.norm(right)
    return right, np.cross(normal, right), normal


def preview_image(positions: np.ndarray, values: np.ndarray, width: int = 800, vmax: float | None = None) -> np.ndarray:
    """(H, W, 3) uint8 orthographic preview of points coloured by ``values`` (e.g. C2C distances).

    positions: (N, 3) float64 local coordinates (metres). The view looks along the cloud's axis of least
    variance: top-down (north up) for mostly horizontal data, frontal with z up for a façade; the nearest
    point wins each pixel. Background is white.
    """
    pts = np.asarray(positions, dtype=np.float64)
    vals = np.asarray(values, dtype=np.float64).reshape(-1)
    if len(pts) == 0:
        raise DataError("cannot preview an empty cloud")
    centred = pts - pts.mean(axis=0)
    right, up_axis, normal = _view_axes(centred)
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


def jpeg_thumbnail(image: np.ndarray | str | PathLike[str], max_side: int = 1200, quality: int = 82) -> bytes:
    """JPEG bytes of an image (array (H, W, 3) RGB / (H, W) uint8, or an image file) downscaled so that its longer
    side is at most ``max_side`` pixels (area interpolation; never upscaled)."""
    if isinstance(image, (str, PathLike)):
        path = Path(image)
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)  # BGR
        if img is None:
            raise InputFileError("cannot read image (missing, corrupt or unsupported format)", path)
    else:
        img = np.asarray(image)
        if img.dtype != np.uint8:
            raise DataError(f"thumbnail needs a uint8 image, got {img.dtype}")
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR) if img.ndim == 3 else img
    h, w = img.shape[:2]
    scale = min(1.0, max_side / max(h, w))
    if scale < 1.0:
        img = cv2.resize(img, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise DataError("JPEG encoding failed")
    return buf.tobytes()


def jpeg_data_uri(data: bytes) -> str:
    return "data:image/jpeg;base64," + base64.b64encode(data).decode("ascii")


# -- charts -----------------------------------------------------------------------------------------
def _figure(width_in: float, height_in: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _svg(fig) -> str:
    """The figure as an inline-ready SVG string (no XML declaration or DOCTYPE), deterministic bytes."""
    import matplotlib

    buf = io.StringIO()
    with matplotlib.rc_context(_RC):
        fig.savefig(buf, format="svg", metadata={"Date": None, "Creator": None})
    text = buf.getvalue()
    return text[text.index("<svg") :]


def _jpeg(fig, dpi: int = 110, quality: int = 85) -> bytes:
    import matplotlib

    buf = io.BytesIO()
    with matplotlib.rc_context(_RC):
        fig.savefig(buf, format="jpg", dpi=dpi, pil_kwargs={"quality": int(quality)})
    return buf.getvalue()


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
    """An SVG bar chart: one or more named series of equal length, grouped per category (``labels``).

    With ``edges`` (len = categories + 1) the x axis is numeric (a histogram) and ``labels`` is ignored.
    None values are drawn as missing bars. ``width``/``height`` in pixels at 100 dpi.
    """
    import matplotlib

    if not series:
        raise DataError("nothing to plot")
    with matplotlib.rc_context(_RC):
        fig = _figure(width / 100, height / 100)
        ax = fig.add_subplot()
        if edges is not None:
            e = np.asarray(edges, dtype=np.float64)
            for s, (name, vals) in enumerate(series):
                ax.bar(e[:-1], np.asarray(vals, float), width=np.diff(e), align="edge", color=PALETTE[s % 6],
                       label=name, edgecolor="white", linewidth=0.3)  # fmt: skip
        else:
            n = len(series[0][1])
            x = np.arange(n)
            bar = 0.85 / len(series)
            for s, (name, vals) in enumerate(series):
                v = np.array([np.nan if val is None else float(val) for val in vals])
                ax.bar(x - 0.425 + (s + 0.5) * bar, v, width=bar, color=PALETTE[s % 6], label=name)
            step = max(1, n // 16)
            ax.set_xticks(x[::step], [str(lb)[:16] for lb in list(labels)[::step]], rotation=30 if n > 6 else 0,
                          ha="right" if n > 6 else "center")  # fmt: skip
        ax.set_title(title)
        ax.set_xlabel(x_label)
        ax.set_ylabel(y_label)
        ax.grid(axis="y", color="#ddd", linewidth=0.6)
        ax.set_axisbelow(True)
        if len(series) > 1:
            ax.legend(frameon=False, fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))
        return _svg(fig)


def svg_histogram(
    edges: Sequence[float], counts: Sequence[int], title: str, x_label: str | None = None, units: Units = Units.M
) -> str:
    """An SVG histogram of C2C distances (``edges`` in metres, from :func:`eval.c2c.histogram`), drawn in ``units``."""
    units = Units.parse(units)
    e = units.from_metres(np.asarray(edges, dtype=np.float64))
    return svg_bars(
        [("points", [float(c) for c in counts])], [], title, x_label or f"distance ({units.value})", "points", edges=e
    )


def metric_bars_svg(series: Sequence[tuple[str, Sequence[float | None]]], views: Sequence[str], metric: str) -> str:
    """Per-view bars of one image metric (PSNR, SSIM, LPIPS ...), one series per product."""
    width = int(np.clip(120 + 28 * len(views) * max(1, len(series)) ** 0.5, 480, 1100))
    return svg_bars(series, views, f"{metric} per held-out view", "view", metric, width=width)


def stage_bars_svg(names: Sequence[str], seconds: Sequence[float | None], peak_mb: Sequence[float | None]) -> str:
    """Two horizontal bar charts side by side: time (s) and peak memory (MB) per pipeline stage."""
    import matplotlib

    if not names:
        raise DataError("no stage to plot")
    with matplotlib.rc_context(_RC):
        fig = _figure(9.0, 0.6 + 0.28 * len(names))
        y = np.arange(len(names))[::-1]
        for k, (vals, label, colour) in enumerate(((seconds, "time (s)", PALETTE[0]), (peak_mb, "peak memory (MB)",
                                                                                       PALETTE[1]))):  # fmt: skip
            ax = fig.add_subplot(1, 2, k + 1)
            v = np.array([np.nan if x is None else float(x) for x in vals])
            ax.barh(y, v, color=colour)
            ax.set_yticks(y, list(names) if k == 0 else [""] * len(names))
            ax.set_xlabel(label)
            ax.grid(axis="x", color="#ddd", linewidth=0.6)
            ax.set_axisbelow(True)
        return _svg(fig)


def c2c_views_jpeg(
    positions: np.ndarray,
    distances_m: np.ndarray,
    vmax_m: float,
    title: str,
    units: Units = Units.M,
    max_points: int = 60_000,
    seed: int = 0,
) -> bytes:
    """JPEG of two orthographic views (plan / main face, and a side view) of a cloud coloured by distance, with a
    colour bar in ``units``. positions (N, 3) float64 metres (local frame), distances_m (N,) metres; at most
    ``max_points`` points are drawn (a seeded random subset), far points first so that near ones stay visible."""
    import matplotlib

    units = Units.parse(units)
    pts = np.asarray(positions, dtype=np.float64)
    d = np.asarray(distances_m, dtype=np.float64).reshape(-1)
    if len(pts) == 0 or len(pts) != len(d):
        raise DataError(f"need N > 0 points with N distances, got {len(pts)} and {len(d)}")
    if len(pts) > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(len(pts), max_points, replace=False))
        pts, d = pts[keep], d[keep]
    d = np.where(np.isfinite(d), d, vmax_m)
    centred = pts - pts.mean(axis=0)
    right, up, normal = _view_axes(centred)
    views = (("plan" if normal[2] > 0.99 else "front", right, up, normal), ("side", normal, up, -right))
    if normal[2] > 0.99:  # map view first, then a side view looking north (x right, z up)
        views = (views[0], ("side", np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])))
    with matplotlib.rc_context(_RC):
        fig = _figure(9.0, 4.2)
        axes = fig.subplots(1, 2)
        scale = units.from_metres(1.0)
        for ax, (label, r, u, n) in zip(axes, views, strict=True):
            order = np.argsort(-(centred @ n), kind="stable")  # far first
            sc = ax.scatter((centred @ r)[order] * scale, (centred @ u)[order] * scale, c=d[order] * scale, s=0.6,
                            cmap="viridis", vmin=0.0, vmax=max(vmax_m, 1e-12) * scale, linewidths=0,
                            rasterized=True)  # fmt: skip
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_title(f"{title} — {label}")
            ax.set_xlabel(f"{units.value}")
            ax.tick_params(labelsize=7)
        fig.colorbar(sc, ax=axes, shrink=0.85, label=f"distance ({units.value})")
        return _jpeg(fig)


def accuracy_residuals_svg(points: Sequence[Mapping], units: Units) -> str:
    """The surveyed points over the site (x, y of ``survey_m``, metres): check points as circles, control points as
    triangles; an arrow per point its horizontal residual (dx, dy) scaled so the largest is a tenth of the site, the
    colour its vertical residual dz (diverging, symmetric, in ``units``)."""
    xy = np.array([p["survey_m"][:2] for p in points], dtype=np.float64)
    d = np.array([[p["dx"], p["dy"], p["dz"]] for p in points], dtype=np.float64)
    check = np.array([p["role"] == "check" for p in points])
    extent = float(np.ptp(xy, axis=0).max()) if len(xy) > 1 else 1.0
    largest = float(np.hypot(d[:, 0], d[:, 1]).max()) or 1.0
    scale = 0.1 * max(extent, 1e-9) / largest
    dz = np.asarray(units.from_metres(d[:, 2]), dtype=np.float64)
    vmax = float(np.abs(dz).max()) or 1.0
    fig = _figure(7.0, 5.0)
    ax = fig.add_subplot(1, 1, 1)
    for mask, marker, label in ((check, "o", "check"), (~check, "^", "control")):
        if mask.any():
            art = ax.scatter(xy[mask, 0], xy[mask, 1], c=dz[mask], cmap="coolwarm", vmin=-vmax, vmax=vmax,
                             marker=marker, s=60, edgecolors="k", label=label)  # fmt: skip
    ax.quiver(xy[:, 0], xy[:, 1], d[:, 0] * scale, d[:, 1] * scale, angles="xy", scale_units="xy", scale=1.0,
              width=0.004, color="k")  # fmt: skip
    for (x, y), p in zip(xy, points, strict=True):
        ax.annotate(str(p["id"]), (x, y), textcoords="offset points", xytext=(5, 5), fontsize=7)
    fig.colorbar(art, ax=ax, label=f"dz ({units.value})")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m, control frame)")
    ax.set_ylabel("y (m, control frame)")
    ax.set_title(f"residuals: arrows ×{scale:.3g} (largest {units.format(largest)}), colour dz", fontsize=9)
    ax.legend(loc="best", fontsize=8)
    return _svg(fig)
