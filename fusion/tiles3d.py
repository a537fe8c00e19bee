"""A Gaussian set as a georeferenced 3D Tiles 1.1 tileset of glTF splat tiles (``KHR_gaussian_splatting``).

:func:`write_splat_tileset` writes, next to ``out`` (a ``tileset.json`` path)::

    tileset.json                every layer: root (transform) → one tile per layer → k-d tree → leaf contents
    survey/tileset.json         the same tiles of one layer alone (when ``layer_tilesets``), same transform
    survey/r.glb, survey/r01.glb, …   one GLB per leaf tile (fusion.gltf_splats layout); fill/…, background/…
    survey_points/…, mesh/mesh.glb    optional: the survey points and a mesh in the same frame (fusion.tiles3d_points)

3D Tiles conventions followed (CesiumGS/3d-tiles ``specification/README.adoc``, head 390f766, 2026-04-30)
-------------------------------------------------------------------------------------------------------
- ``asset.version`` "1.1"; glTF (``.glb``) tile content; ``transform`` column-major 4×4 on the root tile only, so
  every bounding volume below is in the root's frame (the *tile frame*, z-up, metres); ``refine: "ADD"``.
- glTF y-up: a client applies, in order, the glTF node matrix, the fixed y-up → z-up rotation (x, y, z) → (x, −z, y)
  and the tile transforms. Our GLB node matrix is the inverse rotation (:data:`fusion.gltf_splats.Z_UP_TO_Y_UP`), so
  the two cancel and ``POSITION`` values are tile-frame coordinates (the spec's informative workflow for z-up data).
- No levels of detail: every splat lies in exactly one leaf of its layer. Leaves have ``geometricError`` 0; a parent
  (no content) has its box's diagonal: rendering nothing there is off by at most that much, so a client refines a
  tile once it spans ``maximumScreenSpaceError`` pixels, and sub-pixel tiles are not loaded.
- Tiling: per layer, a k-d tree: a tile holding more than ``max_splats_per_tile`` splats is split in two at the
  median of its means along its longest axis (ties by splat order), until every leaf holds at most that many.
  Boxes (``boundingVolume.box``, axis-aligned in the tile frame) enclose each splat's 3σ ellipsoid (the
  extension's kernel cut-off; half-sizes at least 1 mm), and each parent's box encloses its children's.
- Layers: the ``source`` field (:class:`fusion.convert_options.Source`) splits the set; each layer is its own
  subtree under the root, its files live in a folder named after it (``survey/``, ``fill/``, ``background/``; other
  codes: ``unknown/``, ``source_<n>/``), and it is named twice: as 3D Tiles 1.1 metadata (``schema`` class
  ``layer`` with ``name`` and ``source``; one ``groups`` entry per layer; each content's ``group`` points at it) and
  by the folder. CesiumJS merges all splats of one tileset into one sorted primitive, so there a layer is toggled
  by loading ``<layer>/tileset.json`` files as separate tilesets and switching their ``show``.
- Tile content compression (``TilesetOptions.compression``): ``spz`` (default) writes every GLB with
  ``KHR_gaussian_splatting_compression_spz_2`` (SPZ v2, :mod:`fusion.gltf_splats`) and lists both splat extensions
  in ``3DTILES_content_gltf``'s ``extensionsUsed`` *and* ``extensionsRequired`` — CesiumJS
  (GaussianSplat3DTileContent.js, read 2026) draws splats only then; ``none`` writes float32 attributes, declared
  in ``extensionsUsed`` only, which CesiumJS shows as points. SPZ positions are fixed point about the tile frame's
  origin with the most fractional bits each leaf allows; boxes are padded by half the coarsest step, so they enclose
  the decoded positions, and the summary reports that bound (``position_quantisation_m``; ±30 µm for a set within
  ±512 m of its origin, ±0.12 mm within ±2 048 m), on top of ``placement_error_m``.

Georeferencing (``crs``)
------------------------
World coordinates are ``origin + local`` in ``crs`` (any CRS pyproj knows whose axes are east, north and up:
projected, possibly compound with a vertical CRS, or geocentric). ECEF is EPSG:4978 (WGS 84), through pyproj.

``placement="exact"`` (default): the tile frame is the topocentric east-north-up frame of the WGS 84 ellipsoid at
the origin, and the root transform is that frame's rigid placement (ENU rotation, origin's ECEF translation). Each
splat's mean is converted on its own: p = Rᵀ (ECEF(origin + local) − ECEF(origin)), in float64, then float32 — so a
splat's final ECEF position matches pyproj's to float32 rounding (< 0.1 mm within 1 km), earth curvature and the
projection's scale and convergence included. Orientations and sizes go through the Jacobian J of local → tile
frame at the origin (Σ' = J Σ Jᵀ, exact for that J: meridian convergence γ, point scale k, units), SH coefficients
are rotated by J's rotation part; J's variation across the set is not applied to splat shapes (at distance r and
height difference Δh from the origin: a tilt of r / R rad, 1.6e-4 at 1 km, and a horizontal scale change of Δh / R,
8e-6 per 50 m; R = 6 371 km). The GLB positions are therefore *not* the set's local offsets.

``placement="grid"``: the GLB positions are the set's local offsets (float32, unchanged) and the root transform is
the affine map T(x) = ECEF(origin) + J · x with J = ∂ECEF/∂(E, N, h) at the origin (central differences through
pyproj): convergence, scale factor, height and unit factors are applied; earth curvature and the change of the
projection's distortion within the set are not — the error grows like r² / (2 R) + r · |Δh| / R (the sagitta, and
the height factor's change): ≈ 2 cm at 500 m, 8 cm at 1 km, plus 4 mm at 500 m for 50 m of height difference.
The summary records the error measured on the set (``placement_error_m``).

Both report the meridian convergence and point scale factor at the origin (pyproj ``Proj.get_factors``) and the
datum transformation pyproj chose: a "ballpark" one (a missing geoid grid, unknown datum) is refused with a
:class:`ConfigError`; a fallback used because a better grid is not installed is accepted with a warning stating
its accuracy (it moves the whole tileset, not the relative geometry).

Without a CRS the tileset is not georeferenced: the root transform is the translation by the origin (identity
rotation), GLB positions are the local offsets, and the tileset frame is the set's world frame — a globe viewer
puts it near the earth's centre unless the user places it (CesiumJS: ``Cesium3DTileset.modelMatrix``).
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import Enum
from os import PathLike
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from core.constraints import Choice, Constrained, Constraints, Interval
from core.errors import ConfigError, DataError
from core.gaussians import GaussianSet
from core.io.atomic import check_output_file, output_transaction, remove_output, write_bytes_atomic
from core.io.json_io import write_json_atomic
from core.pointcloud import PointCloud
from fusion.convert_options import LAYERS, Source
from fusion.gltf_splats import (
    EXTENSION,
    SPZ_EXTENSION,
    ColorSpace,
    GltfCompression,
    encode_splat_glb,
    generator,
    rotate_sh_rest,
)

MIN_HALF_SIZE = 1e-3
"""Smallest half-size (metres) of a tile box on any axis: no degenerate box for a flat or single-splat tile."""

EXTENT_SIGMAS = 3.0
"""Splat extent in σ used for the boxes: the ``KHR_gaussian_splatting`` ellipse kernel's cut-off."""

_TILE_FILE = re.compile(r"^r[01]*\.glb$")


class Placement(str, Enum):
    """How a georeferenced set is put on the earth (see the module docstring)."""

    EXACT = "exact"
    GRID = "grid"


class TilesetWarning(UserWarning):
    """The tileset was written, but its placement is less accurate than the data (the message says how much)."""


@dataclass(frozen=True)
class TilesetOptions(Constrained):
    """Options of :func:`write_splat_tileset`.

    ``max_splats_per_tile``: most splats in one leaf GLB (≥ 1; 100 000 ≈ 6 MB at SH degree 0, 24 MB at degree 3);
    also the most survey points in one point tile (100 000 points ≈ 1.6 MB).
    ``placement``: ``exact`` or ``grid`` (ignored without a CRS). ``color_space``: the extension's ``colorSpace``.
    ``layer_tilesets``: also write ``<layer>/tileset.json`` per layer (same tiles, same transform).
    ``compression``: ``spz`` (default; ``KHR_gaussian_splatting_compression_spz_2``, the form CesiumJS draws as
    splats, several times smaller) or ``none`` (float32 attributes: exact to float32, drawn by CesiumJS as points).
    """

    max_splats_per_tile: int = 100_000
    placement: Placement = Placement.EXACT
    color_space: ColorSpace = ColorSpace.SRGB
    layer_tilesets: bool = True
    compression: GltfCompression = GltfCompression.SPZ

    constraints: ClassVar[Constraints] = {
        "max_splats_per_tile": Interval(int, 1, None),
        "placement": Choice(Placement),
        "color_space": Choice(ColorSpace),
        "compression": Choice(GltfCompression),
    }


@dataclass(frozen=True)
class TileRecord:
    """One leaf content: its URI (relative to ``tileset.json``), layer, splat count, file size (bytes) and box
    (12 numbers: centre, then the three half-axis vectors, metres, tile frame)."""

    uri: str
    layer: str
    splats: int
    bytes: int
    box: tuple[float, ...]


@dataclass(frozen=True)
class LayerRecord:
    """One layer: name, ``source`` code (None for the survey points and the mesh), splats (points, mesh vertices),
    leaf tiles, bytes of its GLBs, its own tileset (or None), kind (``splats``, ``points`` or ``mesh``)."""

    name: str
    source: int | None
    splats: int
    tiles: int
    bytes: int
    tileset: str | None
    kind: str = "splats"


@dataclass(frozen=True)
class TilesetSummary:
    """What :func:`write_splat_tileset` wrote and how it is placed.

    ``transform``: the root tile's transform as written (16 numbers, column-major; tile frame → ECEF metres, or →
    world coordinates without a CRS). ``placement``: ``exact``, ``grid`` or ``none`` (no CRS). Georeferenced only:
    ``origin_ecef`` (metres), ``origin_lon_lat_h`` (degrees, degrees, metres on WGS 84), ``convergence_deg`` and
    ``scale_factor`` (meridian convergence and point scale of a projected CRS at the origin, pyproj's
    ``get_factors``; None for a geocentric CRS), ``grid_north_azimuth_deg`` (grid north's azimuth from true north,
    clockwise, from the Jacobian), ``transform_scale`` (lengths of the transform's axis columns),
    ``placement_error_m`` (largest distance between our ECEF of a splat — float32 position through the written
    transforms — and pyproj's ECEF of origin + local, over ≤ 256 splats and the 8 corners of the set's bounds),
    ``datum_transformation`` and ``datum_accuracy_m`` (pyproj's operation; accuracy −1 when unknown).
    ``compression``: the tiles' ``none`` or ``spz``; ``position_quantisation_m``: SPZ only, the largest distance per
    axis between a stored (fixed-point) position and the float64 tile-frame one, half the step at the fewest
    fractional bits any tile uses (each tile takes the most its own positions allow); not in ``placement_error_m``.
    """

    path: Path
    crs: str | None
    placement: str
    origin: tuple[float, float, float]
    transform: tuple[float, ...]
    splats: int
    bytes: int
    layers: tuple[LayerRecord, ...]
    tiles: tuple[TileRecord, ...]
    notes: tuple[str, ...]
    origin_ecef: tuple[float, float, float] | None = None
    origin_lon_lat_h: tuple[float, float, float] | None = None
    convergence_deg: float | None = None
    scale_factor: float | None = None
    grid_north_azimuth_deg: float | None = None
    transform_scale: tuple[float, float, float] | None = None
    placement_error_m: float | None = None
    datum_transformation: str | None = None
    datum_accuracy_m: float | None = None
    compression: str = GltfCompression.NONE.value
    position_quantisation_m: float | None = None

    @property
    def georeferenced(self) -> bool:
        return self.crs is not None

    def lines(self) -> list[str]:
        """A short human-readable report (one item per line)."""
        splat_tiles = sum(layer.tiles for layer in self.layers if layer.kind == "splats")
        more = len(self.tiles) - splat_tiles
        beside = f" (+ {more} tiles of survey points or mesh)" if more else ""
        out = [f"{self.path}: {self.splats} splats in {splat_tiles} tiles{beside}, {self.bytes / 1e6:.1f} MB"]
        for layer in self.layers:
            if layer.kind == "splats":
                out.append(f"  layer {layer.name} (source {layer.source}): {layer.splats} splats, {layer.tiles} tiles")
            else:
                items = "points" if layer.kind == "points" else "vertices"
                out.append(f"  layer {layer.name}: {layer.splats} {items}, {layer.tiles} tiles")
        if self.crs is None:
            out.append("  not georeferenced (no CRS): the root transform is the translation by the origin")
        else:
            out.append(f"  {self.crs}, placement {self.placement}, origin ECEF {_fmt(self.origin_ecef, 3)} m")
            if self.convergence_deg is not None:
                out.append(
                    f"  at the origin: meridian convergence {self.convergence_deg:.6f}°, "
                    f"scale factor {self.scale_factor:.8f}"
                )
            out.append(f"  placement error (sampled, vs pyproj): {self.placement_error_m * 1000:.3f} mm")
        if self.position_quantisation_m is not None:
            bits = -round(math.log2(self.position_quantisation_m)) - 1
            out.append(
                f"  glTF tiles: SPZ v2 ({bits} fractional bits or more): positions within "
                f"{self.position_quantisation_m * 1e6:.3g} µm per axis of the float64 tile frame"
            )
        out += [f"  note: {n}" for n in self.notes]
        return out


def _fmt(values: Any, digits: int) -> str:
    return "(" + ", ".join(f"{v:.{digits}f}" for v in values) + ")" if values is not None else "-"


# -- georeferencing ----------------------------------------------------------------------------------------------


@dataclass
class TileFrame:
    """The tile frame: how local offsets map into it, and how it is placed (``transform``, row-major 4×4)."""

    transform: np.ndarray
    placement: str
    crs_name: str | None = None
    to_ecef: Any = None  # pyproj Transformer, CRS → EPSG:4978, always_xy
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    origin_ecef: np.ndarray | None = None
    enu: np.ndarray | None = None  # (3, 3) columns: east, north, up unit vectors in ECEF
    jacobian: np.ndarray | None = None  # (3, 3) local → tile frame at the origin (exact placement only)
    info: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    path: Path | None = None  # the output, named in errors

    def positions(self, local: np.ndarray) -> np.ndarray:
        """(N, 3) float64 tile-frame coordinates of local offsets (N, 3)."""
        if self.placement != Placement.EXACT.value:
            return np.asarray(local, np.float64)
        ecef = self.ecef_truth(local)
        return (ecef - self.origin_ecef) @ self.enu  # rows: Rᵀ · (p − o)

    def ecef_truth(self, local: np.ndarray) -> np.ndarray:
        """pyproj's ECEF (N, 3) of origin + local (the independent truth)."""
        import pyproj

        world = self.origin + np.asarray(local, np.float64)
        try:
            x, y, z = self.to_ecef.transform(world[:, 0], world[:, 1], world[:, 2])
        except pyproj.exceptions.ProjError as err:
            raise ConfigError(f"CRS {self.crs_name!r}: pyproj cannot transform to ECEF ({err})", self.path) from None
        out = np.c_[x, y, z]
        if not np.isfinite(out).all():
            raise ConfigError(
                f"CRS {self.crs_name!r}: pyproj returned non-finite ECEF coordinates (outside the CRS's area?)",
                self.path,
            )
        return out


def _resolve_frame(origin: np.ndarray, crs: str | None, placement: Placement, out: Path) -> TileFrame:
    if crs is None:
        t = np.eye(4)
        t[:3, 3] = origin
        note = (
            "not georeferenced (no CRS): the tileset frame is the set's world frame (origin + local), not ECEF; "
            "a globe viewer puts it near the earth's centre unless placed (CesiumJS: Cesium3DTileset.modelMatrix)"
        )
        return TileFrame(transform=t, placement="none", origin=origin, notes=[note])
    import pyproj
    from pyproj.transformer import TransformerGroup

    try:
        src = pyproj.CRS.from_user_input(crs)
    except pyproj.exceptions.CRSError as err:
        raise ConfigError(f"unknown CRS {crs!r} ({err})", out) from None
    if src.is_geographic and not src.is_projected:
        raise ConfigError(
            f"CRS {crs!r} is geographic (degrees): local offsets must be metres; use a projected CRS (e.g. UTM) "
            "or a geocentric one",
            out,
        )
    if not (src.is_projected or src.is_geocentric):
        raise ConfigError(f"CRS {crs!r} is not projected or geocentric, so it cannot be placed on the earth", out)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # pyproj's missing-grid warning: reported below, our words
        group = TransformerGroup(src, "EPSG:4978", always_xy=True)
    if not group.transformers:
        raise ConfigError(f"pyproj has no transformation from {crs!r} to ECEF (EPSG:4978)", out)
    to_ecef = group.transformers[0]
    description = to_ecef.description or ""
    if "ballpark" in description.lower():
        raise ConfigError(
            f"the only transformation from {crs!r} to WGS 84 available here is a ballpark one ({description}): "
            "positions or heights could be off by metres to tens of metres. Give the CRS by its EPSG code (a datum "
            "PROJ knows), install the PROJ grid it needs (projsync, or the proj-data package), or, for heights, use "
            "a CRS with ellipsoidal heights",
            out,
        )
    frame = TileFrame(
        transform=np.eye(4), placement=placement.value, crs_name=crs, to_ecef=to_ecef, origin=origin.copy(), path=out
    )
    frame.info["datum_transformation"] = description
    frame.info["datum_accuracy_m"] = float(to_ecef.accuracy)
    if not group.best_available:
        message = (
            f"the best transformation from {crs!r} to WGS 84 needs a PROJ grid that is not installed; using "
            f"{description!r} (accuracy {to_ecef.accuracy} m, −1 = unknown): the whole tileset may be displaced by "
            "that much (relative geometry is unaffected)"
        )
        warnings.warn(message, TilesetWarning, stacklevel=3)
        frame.notes.append(message)
    _place(frame, src, out)
    return frame


def _place(frame: TileFrame, src: Any, out: Path) -> None:
    """Fill the ECEF origin, ENU axes, Jacobian, projection factors and the root transform of ``frame``."""
    import pyproj

    o = frame.origin
    o_ecef = frame.ecef_truth(np.zeros((1, 3)))[0]
    geodetic = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    lon, lat, h = geodetic.transform(*o_ecef)
    enu = enu_axes(lon, lat)
    jac = _jacobian(frame)
    topo = enu.T @ jac  # local → ENU at the origin
    if np.linalg.det(topo) <= 0:
        raise ConfigError(
            f"CRS {frame.crs_name!r}: its axes (x, y, z in pyproj's always_xy order) do not form a right-handed "
            "east/north/up frame (e.g. east/south axes); reproject to a CRS with east, north and up axes",
            out,
        )
    frame.origin_ecef, frame.enu = o_ecef, enu
    units = np.linalg.norm(topo, axis=0)  # metres per local unit along x, y, z
    if units.max() > 1.01 * units.min():
        message = (
            f"CRS {frame.crs_name!r}: one local unit is {units[0]:.6g} m along x, {units[1]:.6g} m along y and "
            f"{units[2]:.6g} m along z (pyproj gives a 2D CRS ellipsoidal heights in metres); local z and the splats' "
            "vertical sizes are read in those units — use a compound CRS whose vertical unit matches if they are not"
        )
        warnings.warn(message, TilesetWarning, stacklevel=4)
        frame.notes.append(message)
    transform = np.eye(4)
    transform[:3, 3] = o_ecef
    if frame.placement == Placement.EXACT.value:
        transform[:3, :3] = enu
        frame.jacobian = topo
    else:
        transform[:3, :3] = jac
    frame.transform = transform
    frame.info.update(
        origin_ecef=tuple(float(v) for v in o_ecef),
        origin_lon_lat_h=(float(lon), float(lat), float(h)),
        grid_north_azimuth_deg=float(math.degrees(math.atan2(topo[0, 1], topo[1, 1]))),
        transform_scale=tuple(float(v) for v in np.linalg.norm(transform[:3, :3], axis=0)),
    )
    frame.info.update(_projection_factors(src, o))
    frame.notes.append(_PLACEMENT_NOTES[frame.placement])


_PLACEMENT_NOTES = {
    Placement.EXACT.value: "placement exact: GLB positions are topocentric east/north/up metres at the origin (each "
    "splat through pyproj), not the set's grid offsets; splat axes and sizes mapped by the grid→ENU Jacobian at the "
    "origin, SH rotated by its rotation (convergence)",
    Placement.GRID.value: "placement grid: GLB positions are the set's grid offsets; the root transform is the "
    "grid→ECEF Jacobian at the origin (convergence, scale factor, height and units applied); earth curvature and "
    "distortion changes inside the set are not modelled (error ≈ r²/2R + r·|Δh|/R: 2 cm at 500 m, 8 cm at 1 km)",
}


def enu_axes(lon_deg: float, lat_deg: float) -> np.ndarray:
    """(3, 3) columns: the east, north and up unit vectors in ECEF at a geodetic longitude/latitude (degrees)."""
    lam, phi = math.radians(lon_deg), math.radians(lat_deg)
    east = [-math.sin(lam), math.cos(lam), 0.0]
    north = [-math.sin(phi) * math.cos(lam), -math.sin(phi) * math.sin(lam), math.cos(phi)]
    up = [math.cos(phi) * math.cos(lam), math.cos(phi) * math.sin(lam), math.sin(phi)]
    return np.array([east, north, up]).T


def _jacobian(frame: TileFrame) -> np.ndarray:
    """∂ECEF/∂local (3, 3) at the origin: central differences of pyproj with a step of 1 CRS unit (pyproj is float64:
    ECEF ~6e6 m rounds at 1e-9 m; the truncation error is of order step² / R² — negligible)."""
    jac = np.empty((3, 3))
    for axis in range(3):
        d = np.zeros(3)
        d[axis] = 1.0
        plus, minus = frame.ecef_truth(np.stack([d, -d]))
        jac[:, axis] = (plus - minus) / 2.0
    return jac


def _projection_factors(src: Any, origin: np.ndarray) -> dict[str, float]:
    """Meridian convergence (degrees) and point scale factor at the origin of a projected (or compound) CRS."""
    import pyproj

    horizontal = src.sub_crs_list[0] if src.is_compound else src
    if not horizontal.is_projected:
        return {}
    to_geog = pyproj.Transformer.from_crs(horizontal, horizontal.geodetic_crs, always_xy=True)
    lon, lat = to_geog.transform(origin[0], origin[1])
    factors = pyproj.Proj(horizontal).get_factors(lon, lat)
    return {"convergence_deg": float(factors.meridian_convergence), "scale_factor": float(factors.meridional_scale)}


def _to_frame(gaussians: GaussianSet, frame: TileFrame) -> GaussianSet:
    """A new set in the tile frame (means float64, origin zero): the same offsets, or the exact conversion. The
    input is not modified (``GaussianSet.subset`` with a slice shares memory, so arrays are copied here)."""
    if frame.jacobian is None:
        out = gaussians.subset(slice(None))
        out.origin = np.zeros(3)
        return out
    from scipy.spatial.transform import Rotation

    jac = frame.jacobian
    u, _s, vt = np.linalg.svd(jac)
    rotation = u @ vt  # polar rotation part of J (det J > 0 was checked)
    quats = np.empty((len(gaussians), 4))
    log_scales = np.empty((len(gaussians), 3))
    for chunk in _chunks(len(gaussians), 1 << 20):
        rot = Rotation.from_quat(gaussians.quats[chunk][:, [1, 2, 3, 0]].astype(np.float64)).as_matrix()
        m = jac @ rot * np.exp(gaussians.log_scales[chunk].astype(np.float64))[:, None, :]  # J · R · diag(σ)
        u_i, s_i, _ = np.linalg.svd(m)  # Σ' = J Σ Jᵀ = U S² Uᵀ
        u_i[np.linalg.det(u_i) < 0, :, 2] *= -1.0  # a proper rotation; the flipped axis's sign is irrelevant
        quats[chunk] = Rotation.from_matrix(u_i).as_quat()[:, [3, 0, 1, 2]]  # scipy: x, y, z, w
        log_scales[chunk] = np.log(np.maximum(s_i, np.finfo(np.float64).tiny))
    return GaussianSet(
        frame.positions(gaussians.means),
        log_scales,
        quats,
        gaussians.logit_opacities.copy(),
        gaussians.sh_dc.copy(),
        rotate_sh_rest(gaussians.sh_rest, rotation),  # type: ignore[arg-type]
        np.zeros(3),
        {k: v.copy() for k, v in gaussians.fields.items()},
    )


def _position_tolerance(means: np.ndarray, compression: GltfCompression) -> float:
    """How far a stored position may lie from ``means`` beyond float32 rounding (metres): half the SPZ fixed-point
    step at the finest fractional bits the whole set fits (each leaf fits at least as many), so boxes padded by it
    enclose the positions a reader decodes; 0 without compression."""
    if GltfCompression(compression) is not GltfCompression.SPZ:
        return 0.0
    from fusion.spz_format import MAX_FRACTIONAL_BITS, choose_fractional_bits

    bits = choose_fractional_bits(means, MAX_FRACTIONAL_BITS)
    return 0.0 if bits is None else 2.0 ** -(bits + 1)  # None: the encoder refuses the set


def _chunks(n: int, size: int) -> Iterator[slice]:
    for start in range(0, n, size):
        yield slice(start, min(n, start + size))


def _placement_error(gaussians: GaussianSet, frame: TileFrame) -> float | None:
    """Largest |our ECEF − pyproj ECEF| (metres) over ≤ 256 splats and the 8 corners of the local bounds."""
    if frame.to_ecef is None:
        return None
    local = gaussians.means
    pick = np.unique(np.linspace(0, len(local) - 1, min(256, len(local))).astype(np.int64))
    lo, hi = local.min(axis=0), local.max(axis=0)
    corners = np.array([[(lo, hi)[(k >> a) & 1][a] for a in range(3)] for k in range(8)])
    sample = np.concatenate([local[pick], corners])
    ours = frame.positions(sample).astype(np.float32).astype(np.float64)
    ecef = ours @ frame.transform[:3, :3].T + frame.transform[:3, 3]
    return float(np.linalg.norm(ecef - frame.ecef_truth(sample), axis=1).max())


# -- tiling ------------------------------------------------------------------------------------------------------


@dataclass
class TileNode:
    path: str
    lo: np.ndarray
    hi: np.ndarray
    index: np.ndarray | None = None  # leaf: splat indices (ascending)
    children: list[TileNode] = field(default_factory=list)


def _extents(gs: GaussianSet) -> np.ndarray:
    """(N, 3) half-extents of each splat's 3σ ellipsoid along the frame axes: 3 · √(Σⱼ (R diag σ)ₖⱼ²)."""
    from scipy.spatial.transform import Rotation

    out = np.empty((len(gs), 3))
    for chunk in _chunks(len(gs), 1 << 20):
        rot = Rotation.from_quat(gs.quats[chunk][:, [1, 2, 3, 0]].astype(np.float64)).as_matrix()
        m = rot * np.exp(gs.log_scales[chunk].astype(np.float64))[:, None, :]
        out[chunk] = EXTENT_SIGMAS * np.sqrt((m * m).sum(axis=2))
    return out


def build_tree(pos: np.ndarray, ext: np.ndarray, index: np.ndarray, max_n: int, path: str = "r") -> TileNode:
    lo = (pos[index] - ext[index]).min(axis=0)
    hi = (pos[index] + ext[index]).max(axis=0)
    if len(index) <= max_n:
        return TileNode(path, lo, hi, index=np.sort(index))
    centres = pos[index]
    axis = int(np.argmax(centres.max(axis=0) - centres.min(axis=0)))
    order = index[np.argsort(centres[:, axis], kind="stable")]
    half = len(order) // 2
    kids = [
        build_tree(pos, ext, order[:half], max_n, path + "0"),
        build_tree(pos, ext, order[half:], max_n, path + "1"),
    ]
    return TileNode(path, lo, hi, children=kids)


def leaf_nodes(node: TileNode) -> Iterator[TileNode]:
    if node.index is not None:
        yield node
    for child in node.children:
        yield from leaf_nodes(child)


def tile_box(lo: np.ndarray, hi: np.ndarray) -> list[float]:
    centre = (lo + hi) / 2.0
    half = np.maximum((hi - lo) / 2.0, MIN_HALF_SIZE)
    return [float(v) for v in centre] + [float(half[0]), 0.0, 0.0, 0.0, float(half[1]), 0.0, 0.0, 0.0, float(half[2])]


def _diagonal(box: list[float]) -> float:
    return 2.0 * math.sqrt(box[3] ** 2 + box[7] ** 2 + box[11] ** 2)


def tile_json(node: TileNode, prefix: str, group: int) -> dict[str, Any]:
    box = tile_box(node.lo, node.hi)
    tile: dict[str, Any] = {"boundingVolume": {"box": box}}
    if node.index is not None:
        tile["geometricError"] = 0.0
        tile["content"] = {"uri": f"{prefix}{node.path}.glb", "group": group}
    else:
        tile["geometricError"] = _diagonal(box)
        tile["children"] = [tile_json(c, prefix, group) for c in node.children]
    return tile


# -- the writer --------------------------------------------------------------------------------------------------


def layer_name(code: int) -> str:
    """Folder and metadata name of a ``source`` code: survey, fill, background, unknown, or ``source_<n>``."""
    for name, src in LAYERS.items():
        if int(src) == code:
            return name
    return "unknown" if code == int(Source.UNKNOWN) else f"source_{code}"


def _layers(gaussians: GaussianSet) -> list[tuple[str, int, np.ndarray]]:
    """(name, code, indices) per layer present, in LAYERS order then by code. No ``source`` field: all survey."""
    source = gaussians.fields.get("source")
    if source is None:
        return [("survey", int(Source.MVS), np.arange(len(gaussians)))]
    codes = np.asarray(source).astype(np.int64)
    present = [int(c) for c in np.unique(codes)]
    known = [int(s) for s in LAYERS.values()]
    ordered = [c for c in known if c in present] + [c for c in present if c not in known]
    return [(layer_name(c), c, np.flatnonzero(codes == c)) for c in ordered]


def _schema() -> dict[str, Any]:
    return {
        "id": "hybridsplat_layers",
        "classes": {
            "layer": {
                "name": "Layer",
                "description": "A layer of the merged product: its kind (splats, points: the survey points, mesh) "
                "and, for splats, the source code of its Gaussians (Source in fusion/convert_options.py: 1 survey "
                "(MVS), 2 fill (trained splats), 3 background).",
                "properties": {
                    "name": {"type": "STRING", "required": True},
                    "kind": {"type": "STRING", "required": True},
                    "source": {"type": "SCALAR", "componentType": "UINT8"},
                },
            }
        },
    }


def gltf_extensions(compression: GltfCompression) -> dict[str, list[str]]:
    """``3DTILES_content_gltf`` of a tileset whose GLBs are written with ``compression``: CesiumJS draws splats
    only when both splat extensions are listed as required (``none``: used only, the content's own choice)."""
    if GltfCompression(compression) is GltfCompression.SPZ:
        return {
            "extensionsUsed": [EXTENSION, SPZ_EXTENSION, "KHR_materials_unlit"],
            "extensionsRequired": [EXTENSION, SPZ_EXTENSION],
        }
    return {"extensionsUsed": [EXTENSION, "KHR_materials_unlit"]}


def _group(name: str, code: int | None) -> dict[str, Any]:
    """A metadata group of class ``layer``: splat layers carry their ``source`` code, the others none."""
    if code is None:
        from fusion.tiles3d_points import KINDS

        return {"class": "layer", "properties": {"name": name, "kind": KINDS[name]}}
    return {"class": "layer", "properties": {"name": name, "kind": "splats", "source": code}}


def _tileset_json(
    layers: list[tuple[str, int | None, dict[str, Any]]],
    frame: TileFrame,
    extras: dict[str, Any],
    gltf: dict[str, list[str]],
) -> dict[str, Any]:
    """A tileset whose root (with the transform) holds one subtree per layer (name, code or None, tile)."""
    boxes = np.array([t["boundingVolume"]["box"] for _, _, t in layers])
    lo = (boxes[:, :3] - boxes[:, [3, 7, 11]]).min(axis=0)
    hi = (boxes[:, :3] + boxes[:, [3, 7, 11]]).max(axis=0)
    root_box = tile_box(lo, hi)
    error = _diagonal(root_box)
    return {
        "asset": {"version": "1.1", "extras": extras},
        "extensionsUsed": ["3DTILES_content_gltf"],
        "extensions": {"3DTILES_content_gltf": {k: list(v) for k, v in gltf.items()}},
        "schema": _schema(),
        "groups": [_group(name, code) for name, code, _ in layers],
        "geometricError": error,
        "root": {
            "transform": [float(v) for v in frame.transform.T.reshape(-1)],  # column-major
            "boundingVolume": {"box": root_box},
            "geometricError": error,
            "refine": "ADD",
            "children": [tile for _, _, tile in layers],
        },
    }


def write_splat_tileset(
    gaussians: GaussianSet,
    out: str | PathLike[str],
    crs: str | None,
    options: TilesetOptions | None = None,
    points: PointCloud | str | PathLike[str] | None = None,
    mesh: str | PathLike[str] | None = None,
) -> TilesetSummary:
    """Write ``gaussians`` as a 3D Tiles 1.1 tileset of ``KHR_gaussian_splatting`` GLB tiles at ``out``.

    Parameters
    ----------
    gaussians:
        The set (means float64 local, metres; ``origin`` float64 world, in ``crs``); its ``source`` field, when
        present, splits it into layers (absent: one survey layer). Apply export filters (crop, opacity, SH degree:
        :func:`fusion.export.prepare`) before.
    out:
        The ``tileset.json`` path (suffix ``.json``); GLBs and per-layer tilesets go into layer folders beside it.
    crs:
        The CRS of ``origin + local`` (e.g. ``"EPSG:32633"``; any pyproj input), or None: not georeferenced.
    options:
        :class:`TilesetOptions` (tile size, placement, colour space, per-layer tilesets).
    points:
        The survey points (a :class:`PointCloud`: positions float64 local metres, origin float64 world in ``crs``,
        uint8 RGB colours or none; or a point-cloud file such as export/merged_points.ply, read with its origin
        sidecar, whose CRS must be ``crs``): k-d tiled POINTS GLBs in ``survey_points/`` (metadata group
        "survey points"), at most ``max_splats_per_tile`` per tile. See :mod:`fusion.tiles3d_points`.
    mesh:
        A ``.glb`` mesh (export/mesh.glb, with its ``mesh.origin.json`` sidecar) written as ``mesh/mesh.glb``, one
        tile (metadata group "mesh").

    Returns a :class:`TilesetSummary` (counts and bytes per tile and layer, the transform, convergence, scale and
    measured placement error). Writes all files or none (one output transaction); GLBs named like ours
    (``r[01]*.glb``) and layer tilesets that the new tileset no longer lists are removed from the layer folders.

    Raises :class:`ConfigError` naming ``out`` for an unknown or unusable CRS (geographic, left-handed axes, a
    ballpark datum transformation) or bad options; :class:`DataError` naming ``out`` for an empty set or NaN/inf
    values (means, origin, scales, rotations, opacities, SH) or a zero quaternion; errors of ``points`` and ``mesh``
    (empty, NaN, not a GLB, another CRS, far from the splats) name their file (``out`` for an in-memory cloud).
    """
    options = options or TilesetOptions()
    out = Path(out)
    if out.suffix.lower() != ".json":
        raise ConfigError("a 3D Tiles tileset path must end in .json (e.g. DIR/tileset.json)", out)
    check_output_file(out)
    if len(gaussians) == 0:
        raise DataError("nothing to export: the Gaussian set is empty", out)
    try:
        gaussians.validate("tileset export")
    except DataError as err:
        raise DataError(err.problem, out) from None
    if not np.isfinite(gaussians.origin).all():
        raise DataError(f"origin must be finite, got {gaussians.origin.tolist()}", out)
    frame = _resolve_frame(gaussians.origin, crs, options.placement, out)
    in_frame = _to_frame(gaussians, frame)
    pos = in_frame.means.astype(np.float32).astype(np.float64)  # what the GLBs hold: boxes enclose those exactly
    quantisation = _position_tolerance(in_frame.means, options.compression)
    ext = _extents(in_frame) + quantisation

    extras = _asset_extras(gaussians, crs, frame, options.compression)
    others = _other_layers(points, mesh, gaussians.origin, crs, frame, int(options.max_splats_per_tile), out)
    with output_transaction():
        tiles, records = _write_files(in_frame, _layers(gaussians), pos, ext, frame, out, options, extras, others)
    return TilesetSummary(
        path=out,
        crs=crs,
        placement=frame.placement,
        origin=tuple(float(v) for v in gaussians.origin),  # type: ignore[arg-type]
        transform=tuple(float(v) for v in frame.transform.T.reshape(-1)),
        splats=len(gaussians),
        bytes=sum(t.bytes for t in tiles),
        layers=tuple(records),
        tiles=tuple(tiles),
        notes=tuple(frame.notes),
        placement_error_m=_placement_error(gaussians, frame),
        compression=options.compression.value,
        position_quantisation_m=quantisation if options.compression is GltfCompression.SPZ else None,
        **{k: v for k, v in frame.info.items()},
    )


def _write_files(
    in_frame: GaussianSet,
    layers: list[tuple[str, int, np.ndarray]],
    pos: np.ndarray,
    ext: np.ndarray,
    frame: TileFrame,
    out: Path,
    options: TilesetOptions,
    extras: dict[str, Any],
    others: list[Any],
) -> tuple[list[TileRecord], list[LayerRecord]]:
    """Tile each layer, write its GLBs (and its own tileset), then the points and mesh layers (``others``,
    :class:`fusion.tiles3d_points.ExtraLayer`), then ``out``; inside the caller's transaction."""
    from fusion.tiles3d_points import layer_tileset_writer, write_extra_layers

    folder = out.parent
    tiles: list[TileRecord] = []
    records: list[LayerRecord] = []
    subtrees: list[tuple[str, int | None, dict[str, Any]]] = []
    for group, (name, code, index) in enumerate(layers):
        tree = build_tree(pos, ext, index, int(options.max_splats_per_tile))
        written: dict[str, int] = {}
        for leaf in leaf_nodes(tree):
            data = encode_splat_glb(
                in_frame.subset(leaf.index),  # type: ignore[arg-type]
                options.color_space,
                name=f"{name}/{leaf.path}",
                extras={"layer": name, "source": code, "tile": leaf.path},
                compression=options.compression,
            )
            write_bytes_atomic(folder / name / f"{leaf.path}.glb", data)
            written[f"{leaf.path}.glb"] = len(data)
            box = tuple(tile_box(leaf.lo, leaf.hi))
            count = len(leaf.index)  # type: ignore[arg-type]
            tiles.append(TileRecord(f"{name}/{leaf.path}.glb", name, count, len(data), box))
        subtrees.append((name, code, tile_json(tree, f"{name}/", group)))
        layer_tileset = None
        if options.layer_tilesets:
            layer_tileset = f"{name}/tileset.json"
            write_json_atomic(
                folder / layer_tileset,
                _tileset_json(
                    [(name, code, tile_json(tree, "", 0))], frame, extras, gltf_extensions(options.compression)
                ),
            )
        remove_stale_tiles(folder / name, set(written), keep_tileset=options.layer_tilesets)
        records.append(LayerRecord(name, code, len(index), len(written), sum(written.values()), layer_tileset))
    for stale in {layer_name(int(c)) for c in Source} - {r.name for r in records}:
        remove_stale_tiles(folder / stale, set(), keep_tileset=False)

    def own_tileset(ls: list[Any], gltf: dict[str, list[str]], note: str) -> dict[str, Any]:
        return _tileset_json(ls, frame, {**extras, "glTF": note}, gltf)

    own = layer_tileset_writer(folder, own_tileset, options.layer_tilesets)
    more_tiles, more_records, more_subtrees = write_extra_layers(others, folder, len(subtrees), own)
    tiles, records, subtrees = tiles + more_tiles, records + more_records, subtrees + more_subtrees
    write_json_atomic(out, _tileset_json(subtrees, frame, extras, gltf_extensions(options.compression)))
    return tiles, records


def _other_layers(
    points: Any, mesh: Any, origin: np.ndarray, crs: str | None, frame: TileFrame, max_n: int, out: Path
) -> list[Any]:
    """The survey points' and the mesh's layers (:class:`fusion.tiles3d_points.ExtraLayer`), checked and encoded
    before anything is written."""
    from fusion.tiles3d_points import mesh_layer, points_layer

    layers = []
    if points is not None:
        layers.append(points_layer(points, origin, crs, frame, max_n, out))
    if mesh is not None:
        layers.append(mesh_layer(mesh, origin, crs, frame))
    return layers


def _asset_extras(
    gaussians: GaussianSet, crs: str | None, frame: TileFrame, compression: GltfCompression
) -> dict[str, Any]:
    extras: dict[str, Any] = {
        "generator": generator(),
        "crs": crs,
        "origin": [float(v) for v in gaussians.origin],
        "units": "m",
        "placement": frame.placement,
        "georeferenced": crs is not None,
        "glTF": (
            "KHR_gaussian_splatting with KHR_gaussian_splatting_compression_spz_2 (SPZ v2)"
            if compression is GltfCompression.SPZ
            else "KHR_gaussian_splatting (uncompressed)"
        )
        + ", see fusion/gltf_splats.py",
    }
    for key in ("convergence_deg", "scale_factor", "origin_lon_lat_h"):
        if key in frame.info:
            extras[key] = frame.info[key]
    return extras


def remove_stale_tiles(layer_dir: Path, written: set[str], keep_tileset: bool) -> None:
    """Queue removal of our own tile files (``r[01]*.glb``) in ``layer_dir`` not written now, and of its
    ``tileset.json`` when no layer tileset is written there."""
    if not layer_dir.is_dir():
        return
    for p in layer_dir.iterdir():
        if p.is_file() and _TILE_FILE.match(p.name) and p.name not in written:
            remove_output(p)
    if not keep_tileset and (layer_dir / "tileset.json").is_file():
        remove_output(layer_dir / "tileset.json")
