"""Measurements as files: CSV (world coordinates, unit, σ, CRS) and GeoJSON in WGS84 (RFC 7946).

CSV (``points``), one row per point, comma-separated, header first::

    id,x,y,z,sigma_x,sigma_y,sigma_z,sigma_3d,cov_xx,cov_xy,cov_xz,cov_yy,cov_yz,cov_zz,n_rays,
    max_angle_deg,sigma0,rms_residual_px,images,unit,crs

x, y, z are world coordinates (local + origin) in the project's unit, written with enough digits to
round-trip float64; σ's in the same unit, the covariance in unit². ``crs`` is empty when unknown.
Distances go to a second CSV: ``a,b,length,sigma,unit``.

GeoJSON (only with a CRS): a FeatureCollection in WGS84 longitude/latitude (RFC 7946 §4: no "crs"
member), one Point feature per point (third coordinate: the height as in the source CRS, untransformed
when that CRS is 2D) and one LineString per distance; properties carry the source coordinates and σ's.
The transform is pyproj's (PROJ), always in (easting, northing) → (longitude, latitude) axis order.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from dataclasses import dataclass
from os import PathLike

import numpy as np

from core.errors import ConfigError, DataError
from core.io.atomic import write_text_atomic
from eval.measure.triangulate import Distance, MeasuredPoint

POINT_COLUMNS = (
    "id", "x", "y", "z", "sigma_x", "sigma_y", "sigma_z", "sigma_3d",
    "cov_xx", "cov_xy", "cov_xz", "cov_yy", "cov_yz", "cov_zz",
    "n_rays", "max_angle_deg", "sigma0", "rms_residual_px", "images", "unit", "crs",
)  # fmt: skip
DISTANCE_COLUMNS = ("a", "b", "length", "sigma", "unit")


@dataclass(frozen=True)
class Measurements:
    """Measured points and distances with the frame they are expressed in.

    unit: linear unit of the world coordinates (``"m"`` for every project so far).
    crs: the world coordinates' CRS as a string pyproj understands (``"EPSG:32632"``, WKT), or None.
    """

    points: tuple[MeasuredPoint, ...]
    distances: tuple[Distance, ...] = ()
    unit: str = "m"
    crs: str | None = None


def _fmt(x: float) -> str:
    return repr(float(x))  # shortest repr that round-trips float64


def points_csv(m: Measurements) -> str:
    """The points CSV as text."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(POINT_COLUMNS)
    for p in m.points:
        c = p.covariance
        rms = float(np.sqrt(np.mean(np.sum(p.residuals_px**2, axis=1))))
        w.writerow(
            [p.name, *map(_fmt, p.world), *map(_fmt, p.sigma), _fmt(p.sigma_3d)]
            + [_fmt(c[i, j]) for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))]
            + [p.n_rays, f"{p.max_angle_deg:.3f}", f"{p.sigma0:.4g}", f"{rms:.4g}", ";".join(p.images)]
            + [m.unit, m.crs or ""]
        )
    return buf.getvalue()


def distances_csv(m: Measurements) -> str:
    """The distances CSV as text."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(DISTANCE_COLUMNS)
    for d in m.distances:
        w.writerow([d.a, d.b, _fmt(d.length), _fmt(d.sigma), m.unit])
    return buf.getvalue()


def write_csv(path: str | PathLike[str], m: Measurements, distances_path: str | PathLike[str] | None = None) -> None:
    """Write the points CSV (and the distances CSV when a path is given) atomically."""
    write_text_atomic(path, points_csv(m))
    if distances_path is not None:
        write_text_atomic(distances_path, distances_csv(m))


def to_wgs84(world: np.ndarray, crs: str) -> np.ndarray:
    """(n, 3) world coordinates in ``crs`` → (n, 3) longitude (°), latitude (°), height (unchanged for 2D CRSs)."""
    from pyproj import CRS, Transformer
    from pyproj.exceptions import CRSError

    try:
        source = CRS.from_user_input(crs)
    except CRSError as err:
        raise ConfigError(f"unknown CRS {crs!r} ({err})") from err
    transformer = Transformer.from_crs(source, CRS.from_epsg(4326), always_xy=True)
    world = np.asarray(world, np.float64).reshape(-1, 3)
    lon, lat = transformer.transform(world[:, 0], world[:, 1])
    out = np.column_stack([np.asarray(lon, np.float64), np.asarray(lat, np.float64), world[:, 2]])
    if not np.all(np.isfinite(out)):
        raise ConfigError(f"coordinates cannot be transformed from {crs!r} to WGS84 (outside the CRS's area?)")
    return out


def _point_properties(p: MeasuredPoint, m: Measurements) -> dict:
    return {
        "id": p.name,
        "x": float(p.world[0]),
        "y": float(p.world[1]),
        "z": float(p.world[2]),
        "sigma_x": float(p.sigma[0]),
        "sigma_y": float(p.sigma[1]),
        "sigma_z": float(p.sigma[2]),
        "sigma_3d": p.sigma_3d,
        "n_rays": p.n_rays,
        "unit": m.unit,
        "source_crs": m.crs,
    }


def to_geojson(m: Measurements) -> dict:
    """A RFC 7946 FeatureCollection in WGS84 of the points and distances; needs ``m.crs``."""
    if not m.crs:
        raise ConfigError("GeoJSON needs the project's CRS (RFC 7946 is WGS84); none is known")
    features: list[dict] = []
    if m.points:
        world = np.stack([p.world for p in m.points])
        geo = to_wgs84(world, m.crs)
        by_name = {}
        for p, g in zip(m.points, geo, strict=True):
            by_name[p.name] = g
            features.append(
                {
                    "type": "Feature",
                    "geometry": {"type": "Point", "coordinates": [float(v) for v in g]},
                    "properties": _point_properties(p, m),
                }
            )
        for d in m.distances:
            features.append(
                {
                    "type": "Feature",
                    "geometry": {
                        "type": "LineString",
                        "coordinates": [[float(v) for v in by_name[d.a]], [float(v) for v in by_name[d.b]]],
                    },
                    "properties": {"a": d.a, "b": d.b, "length": d.length, "sigma": d.sigma, "unit": m.unit},
                }
            )
    return {"type": "FeatureCollection", "features": features}


def write_geojson(path: str | PathLike[str], m: Measurements) -> None:
    """Write :func:`to_geojson` atomically (UTF-8)."""
    write_text_atomic(path, json.dumps(to_geojson(m), indent=2) + "\n")


def measurements_from(
    points: Sequence[MeasuredPoint], pairs: Sequence[tuple[str, str]] = (), unit: str = "m", crs: str | None = None
) -> Measurements:
    """Bundle points with the distances between the named pairs."""
    from eval.measure.triangulate import distance

    by_name = {p.name: p for p in points}
    missing = sorted({n for pair in pairs for n in pair if n not in by_name})
    if missing:
        raise DataError(f"distances name points that were not measured: {', '.join(missing)}")
    dists = tuple(distance(by_name[a], by_name[b]) for a, b in pairs)
    return Measurements(tuple(points), dists, unit, crs)
