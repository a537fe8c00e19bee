"""Measuring in the reconstruction: multi-ray intersection of picks, error ellipsoids, distances, exports.

No UI here: the viewer (``hybridsplat view``) and ``hybridsplat measure`` both call these functions.

- :mod:`eval.measure.triangulate` — :class:`Pick`, :func:`triangulate` (least squares on reprojection
  error, covariance by first-order propagation of pixel σ), :func:`distance`, confidence ellipsoids.
- :mod:`eval.measure.picks` — the PICKS.json format and its binding to a COLMAP model's cameras.
- :mod:`eval.measure.export` — CSV and WGS84 GeoJSON (RFC 7946, via pyproj).
- :mod:`eval.measure.project` — reading a project's cameras, origin, unit and CRS; measuring a PICKS file.
"""

from eval.measure.export import Measurements, measurements_from, to_geojson, write_csv, write_geojson
from eval.measure.triangulate import (
    CHI2_3_95,
    Distance,
    MeasuredPoint,
    Pick,
    TriangulationOptions,
    confidence_ellipsoid,
    distance,
    triangulate,
)

__all__ = [
    "CHI2_3_95",
    "Distance",
    "MeasuredPoint",
    "Measurements",
    "Pick",
    "TriangulationOptions",
    "confidence_ellipsoid",
    "distance",
    "measurements_from",
    "to_geojson",
    "triangulate",
    "write_csv",
    "write_geojson",
]
