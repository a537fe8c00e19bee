"""Detection of coded targets (ArUco markers, ``cv2.aruco``) in photos: marks of control and check points.

:func:`detect_markers` finds the markers of a dictionary in one photo with OpenCV's ``ArucoDetector``, refines
their four corners to sub-pixel precision (OpenCV's contour refinement: a line fitted to each side's edge
points, the corners their intersections), and takes the marker's centre as the intersection of the corner quad's
diagonals (under a pinhole projection this is exactly the image of the square's centre). Pixel coordinates are in
COLMAP's convention: the centre of the top-left pixel is (0.5, 0.5) (OpenCV's is (0, 0), hence the +0.5).
:func:`detect_marks` runs it over photos and names each mark's point by ``point_id(marker_id)``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.io.control import Mark
from core.io.images import read_image

DEFAULT_DICTIONARY = "DICT_4X4_50"


@dataclass(frozen=True)
class DetectedMarker:
    """One marker in a photo: ``marker_id``; ``corners`` (4, 2) float64 px (COLMAP convention) in the marker's
    order (top-left, top-right, bottom-right, bottom-left of the printed marker); ``center`` (2,) float64 px."""

    marker_id: int
    corners: np.ndarray
    center: np.ndarray


def default_point_id(marker_id: int) -> str:
    """The point id of a marker in the synthetic scenes' control files (``T07`` for marker 7)."""
    return f"T{marker_id:02d}"


def quad_center(corners: np.ndarray) -> np.ndarray:
    """(2,) float64 intersection of the diagonals (corner 0 to 2, corner 1 to 3) of a quad (4, 2)."""
    c = np.asarray(corners, dtype=np.float64)
    p, r = c[0], c[2] - c[0]
    q, s = c[1], c[3] - c[1]
    denom = r[0] * s[1] - r[1] * s[0]
    if abs(denom) < 1e-12:
        return c.mean(axis=0)
    t = ((q[0] - p[0]) * s[1] - (q[1] - p[1]) * s[0]) / denom
    return p + t * r


def _detector(dictionary: str):
    import cv2

    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_CONTOUR  # a line fit to each edge's contour
    params.minMarkerPerimeterRate = 0.01
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)), params)


def detect_markers(image: np.ndarray, dictionary: str = DEFAULT_DICTIONARY) -> list[DetectedMarker]:
    """Markers of ``dictionary`` in ``image`` ((H, W, 3) RGB or (H, W) uint8), sorted by id; a marker id seen twice
    in one photo is dropped (ambiguous)."""
    import cv2

    gray = image if image.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    corners, ids, _ = _detector(dictionary).detectMarkers(gray)
    if ids is None:
        return []
    found: dict[int, list[np.ndarray]] = {}
    for quad, mid in zip(corners, ids.ravel().tolist(), strict=True):
        found.setdefault(int(mid), []).append(np.asarray(quad, dtype=np.float64).reshape(4, 2) + 0.5)
    return [DetectedMarker(m, q[0], quad_center(q[0])) for m, q in sorted(found.items()) if len(q) == 1]


def detect_marks(
    images: Iterable[tuple[str, Path]],
    dictionary: str = DEFAULT_DICTIONARY,
    point_id: Callable[[int], str] = default_point_id,
    progress: Callable[[int], None] | None = None,
) -> tuple[Mark, ...]:
    """Marks (``source="detected"``) of every marker found in photos given as (name, path) pairs."""
    out: list[Mark] = []
    for k, (name, path) in enumerate(images):
        for marker in detect_markers(read_image(path), dictionary):
            out.append(Mark(name, point_id(marker.marker_id), marker.center, "detected"))
        if progress is not None:
            progress(k + 1)
    return tuple(out)
