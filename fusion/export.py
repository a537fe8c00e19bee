"""Viewer-ready export of Gaussian sets: 3DGS PLY, antimatter15 ``.splat``, Niantic's SPZ (version 2), PlayCanvas'
compressed PLY and SOG (``.sog`` bundle or unbundled ``meta.json``), and point clouds (PLY / LAS / LAZ).

Every writer first applies :class:`ExportOptions` (:func:`prepare`): crop to an axis-aligned box given in world
coordinates, drop Gaussians whose opacity α is below ``min_opacity`` (default 1/255: invisible once quantised to
8 bits), and reduce (or zero-pad) the SH degree. Payloads are float32 (or quantised: :mod:`fusion.spz_format`,
:mod:`fusion.compressed_ply_format`, :mod:`fusion.sog_format` state their precision) in the set's local frame; the
float64 origin goes to a ``<name>.origin.json`` sidecar (:mod:`core.io.origin`), so georeferenced scenes keep their
millimetres.

Point-cloud export (for CloudCompare and survey tools): one point per Gaussian at its mean, colour from the SH DC
term, and the fields ``source`` (uint8, :class:`fusion.convert.Source`), ``classification`` (uint8, the class codes
of the classifier; 0 where unknown), ``opacity`` (α, float32) and ``scale`` (largest σ, metres, float32).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import ClassVar

import numpy as np

from core.constraints import Choice, Constrained, Constraints, Interval, NoneOr, SequenceOf
from core.errors import ConfigError, DataError, FormatError
from core.gaussians import GaussianSet
from core.io import write_point_cloud
from core.io.gaussian_ply import write_gaussian_ply
from core.io.origin import remove_origin, write_origin
from core.pointcloud import PointCloud
from fusion.compressed_ply_format import write_compressed_ply
from fusion.convert_options import Source
from fusion.merge import subset
from fusion.sog_format import is_sog_path, write_sog
from fusion.splat_format import write_splat
from fusion.spz_format import (
    EXPORT_SH1_BITS,
    EXPORT_SH_REST_BITS,
    SPZ_VERSION,
    SPZ_WRITABLE_VERSIONS,
    finest_fractional_bits,
    write_spz,
)

GLTF_COMPRESSIONS = ("spz", "none")
"""Values of :attr:`ExportOptions.gltf_compression` (those of :class:`fusion.gltf_splats.GltfCompression`)."""


@dataclass(frozen=True)
class ExportOptions(Constrained):
    """Filters applied before writing.

    ``crop_min`` / ``crop_max``: world coordinates (metres) of an axis-aligned box, both or neither; Gaussians whose
    mean lies outside are dropped (bounds inclusive). ``min_opacity``: α threshold (0 keeps everything).
    ``sh_degree``: SH degree written to 3DGS PLY, SPZ, compressed PLY and SOG (None keeps the set's degree).
    ``extra_fields``: append the set's fields (``source``, ``classification``…) to the 3DGS PLY as float32 properties
    after ``rot_3``. ``crs``: the coordinate reference system of the world coordinates (e.g. ``"EPSG:32633"``),
    kept through the export: written to every output's ``.origin.json`` sidecar (written then even at a zero
    origin) and as the WKT of a LAS/LAZ output; None writes none. ``spz_version``: 2 (default: every SPZ reader) or
    3 (smallest-three rotations, exact near 180°; see :mod:`fusion.spz_format`). ``gltf_compression``: how a
    tileset's glTF tiles store the splats: ``spz`` (default: ``KHR_gaussian_splatting_compression_spz_2``, SPZ v2,
    what CesiumJS draws as splats) or ``none`` (float32 ``KHR_gaussian_splatting`` attributes; see
    :mod:`fusion.gltf_splats`).
    """

    crop_min: tuple[float, float, float] | None = None
    crop_max: tuple[float, float, float] | None = None
    min_opacity: float = 1.0 / 255.0
    sh_degree: int | None = None
    extra_fields: bool = False
    crs: str | None = None
    spz_version: int = SPZ_VERSION
    gltf_compression: str = "spz"

    constraints: ClassVar[Constraints] = {
        "crop_min": NoneOr(SequenceOf(Interval(float, None, None), length=3)),
        "crop_max": NoneOr(SequenceOf(Interval(float, None, None), length=3)),
        "min_opacity": Interval(float, 0, 1, closed="left"),
        "sh_degree": NoneOr(Interval(int, 0, 3)),
        "spz_version": Choice(SPZ_WRITABLE_VERSIONS),
        "gltf_compression": Choice(GLTF_COMPRESSIONS),
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        if (self.crop_min is None) != (self.crop_max is None):
            raise ConfigError("crop needs both crop_min and crop_max (world coordinates, metres)")
        if self.crop_min is not None:
            lo, hi = np.asarray(self.crop_min, float), np.asarray(self.crop_max, float)
            if (lo > hi).any():
                raise ConfigError(
                    f"crop_min must not exceed crop_max on any axis, got {self.crop_min} > {self.crop_max}"
                )


@dataclass
class ExportReport:
    """What one export wrote: the file, how many Gaussians went in, how many each filter dropped, what came out."""

    path: Path
    format: str
    num_input: int
    dropped_crop: int
    dropped_opacity: int
    num_written: int
    sh_degree: int
    origin: tuple[float, float, float]
    notes: list[str] = field(default_factory=list)  # format-specific lines (a tileset's transform, placement)


@dataclass
class Prepared:
    gaussians: GaussianSet
    num_input: int
    dropped_crop: int
    dropped_opacity: int


def prepare(gaussians: GaussianSet, options: ExportOptions | None = None) -> Prepared:
    """Apply crop, opacity threshold and SH degree of ``options`` (order: crop, opacity, degree)."""
    options = options or ExportOptions()
    gs = gaussians
    n0 = len(gs)
    dropped_crop = 0
    if options.crop_min is not None:
        lo = np.asarray(options.crop_min, np.float64) - gs.origin
        hi = np.asarray(options.crop_max, np.float64) - gs.origin
        keep = np.all((gs.means >= lo) & (gs.means <= hi), axis=1)
        dropped_crop = int(n0 - keep.sum())
        gs = subset(gs, keep)
    dropped_opacity = 0
    if options.min_opacity > 0:
        keep = gs.opacities >= np.float32(options.min_opacity)
        dropped_opacity = int(len(gs) - keep.sum())
        gs = subset(gs, keep)
    if len(gs) == 0:
        raise DataError(
            f"nothing to export: of {n0} Gaussians, {dropped_crop} lie outside the crop box and "
            f"{dropped_opacity} are below opacity {options.min_opacity:.4g}"
        )
    if options.sh_degree is not None and options.sh_degree != gs.sh_degree:
        gs = gs.with_sh_degree(options.sh_degree)
    return Prepared(gs, n0, dropped_crop, dropped_opacity)


def export_gaussian_ply(
    path: str | PathLike[str], gaussians: GaussianSet, options: ExportOptions | None = None
) -> ExportReport:
    """Write a 3DGS PLY (viewer property order, binary LE float32, channel-major f_rest, zero normals) + sidecar."""
    options = options or ExportOptions()
    prep = prepare(gaussians, options)
    out = write_gaussian_ply(path, prep.gaussians, extra_fields=options.extra_fields)
    if options.crs:
        write_origin(out, prep.gaussians.origin, options.crs)
    return _report(out, "3dgs-ply", prep)


def export_splat(
    path: str | PathLike[str], gaussians: GaussianSet, options: ExportOptions | None = None
) -> ExportReport:
    """Write an antimatter15 ``.splat`` (32 bytes per Gaussian, SH DC only) + origin sidecar when non-zero."""
    prep = prepare(gaussians, options)
    out = write_splat(path, prep.gaussians)
    _write_origin_sidecar(out, prep.gaussians, options)
    return _report(out, "splat", prep)


def _write_origin_sidecar(path: Path, gaussians: GaussianSet, options: ExportOptions | None) -> None:
    crs = options.crs if options is not None else None
    if np.any(gaussians.origin != 0) or crs:
        write_origin(path, gaussians.origin, crs)
    else:
        remove_origin(path)


def export_spz(path: str | PathLike[str], gaussians: GaussianSet, options: ExportOptions | None = None) -> ExportReport:
    """Write Niantic's SPZ (version 2 unless ``options.spz_version``, gzip; positions in 24-bit fixed point around
    the local origin with the finest step the extent allows, 2^-12 m or finer, coarser only beyond ±2048 m; SH bytes
    in buckets of :data:`fusion.spz_format.EXPORT_SH1_BITS` / ``EXPORT_SH_REST_BITS`` bits) + origin sidecar when
    non-zero. See :mod:`fusion.spz_format`."""
    prep = prepare(gaussians, options)
    path = Path(path)
    version = SPZ_VERSION if options is None else options.spz_version
    write_spz(path, prep.gaussians, version=version, fractional_bits=finest_fractional_bits(prep.gaussians.means),
              sh1_bits=EXPORT_SH1_BITS, sh_rest_bits=EXPORT_SH_REST_BITS)  # fmt: skip
    _write_origin_sidecar(path, prep.gaussians, options)
    return _report(path, "spz", prep)


def export_compressed_ply(
    path: str | PathLike[str], gaussians: GaussianSet, options: ExportOptions | None = None
) -> ExportReport:
    """Write PlayCanvas' compressed PLY (chunks of 256, Morton order) + origin sidecar when non-zero. See
    :mod:`fusion.compressed_ply_format`."""
    prep = prepare(gaussians, options)
    path = Path(path)
    write_compressed_ply(path, prep.gaussians)
    _write_origin_sidecar(path, prep.gaussians, options)
    return _report(path, "compressed-ply", prep)


def export_sog(path: str | PathLike[str], gaussians: GaussianSet, options: ExportOptions | None = None) -> ExportReport:
    """Write PlayCanvas' SOG (version 2; a ``.sog`` bundle, or ``meta.json`` and its WebP images in its folder;
    Morton order, codebooks, SH palette) + origin sidecar when non-zero. See :mod:`fusion.sog_format`."""
    prep = prepare(gaussians, options)
    path = Path(path)
    write_sog(path, prep.gaussians)
    _write_origin_sidecar(path, prep.gaussians, options)
    return _report(path, "sog", prep)


def export_tileset(
    path: str | PathLike[str],
    gaussians: GaussianSet,
    options: ExportOptions | None = None,
    points: PointCloud | str | PathLike[str] | None = None,
    mesh: str | PathLike[str] | None = None,
) -> ExportReport:
    """Write a 3D Tiles 1.1 tileset of glTF ``KHR_gaussian_splatting`` tiles at ``path`` (a ``tileset.json``; the
    GLBs go into one folder per layer beside it), placed on the earth through ``options.crs`` (its root transform;
    no CRS: the origin as translation), SPZ-compressed unless ``options.gltf_compression`` is ``none``. ``points``
    (the survey points: a cloud or a file such as export/merged_points.ply) and ``mesh`` (a ``.glb``, e.g.
    export/mesh.glb) go beside the splats as a point-cloud layer and a mesh tile, in the same frame; the export
    filters (crop, opacity) apply to the Gaussians only. See :mod:`fusion.tiles3d` and :mod:`fusion.tiles3d_points`."""
    from fusion.tiles3d import TilesetOptions, write_splat_tileset

    options = options or ExportOptions()
    prep = prepare(gaussians, options)
    tiles = TilesetOptions(compression=options.gltf_compression)  # type: ignore[arg-type]
    summary = write_splat_tileset(prep.gaussians, path, options.crs, tiles, points=points, mesh=mesh)
    report = _report(Path(path), "3d-tiles", prep)
    report.notes = summary.lines()
    return report


def is_tileset_path(path: str | PathLike[str]) -> bool:
    """Whether ``path`` names a 3D Tiles tileset (``tileset.json`` or any ``*.json``)."""
    return Path(path).suffix.lower() == ".json"


def is_compressed_ply_path(path: str | PathLike[str]) -> bool:
    """Whether ``path`` names a PlayCanvas compressed PLY (``*.compressed.ply``, any case)."""
    return Path(path).name.lower().endswith(".compressed.ply")


def gaussians_to_points(gaussians: GaussianSet) -> PointCloud:
    """One point per Gaussian (mean, DC colour) with ``source``, ``classification``, ``opacity``, ``scale`` fields.

    Other per-Gaussian fields are carried as they are. Missing ``source`` is ``Source.UNKNOWN``, missing
    ``classification`` is 0.
    """
    n = len(gaussians)
    colors = np.clip(np.rint(gaussians.base_colors.astype(np.float64) * 255.0), 0, 255).astype(np.uint8)
    fields = dict(gaussians.fields)
    fields["source"] = np.asarray(fields.get("source", np.full(n, Source.UNKNOWN)), dtype=np.uint8)
    cls = np.asarray(fields.get("classification", np.zeros(n)))
    if cls.size and (not np.isfinite(cls.astype(np.float64)).all() or cls.min() < 0 or cls.max() > 255):
        raise DataError("classification codes must lie in 0..255 to be exported")
    fields["classification"] = cls.astype(np.uint8)
    fields["opacity"] = gaussians.opacities.astype(np.float32)
    fields["scale"] = gaussians.scales.max(axis=1).astype(np.float32) if n else np.zeros(0, np.float32)
    return PointCloud(gaussians.means.copy(), gaussians.origin.copy(), colors=colors, fields=fields)


def export_points(
    path: str | PathLike[str], gaussians: GaussianSet, options: ExportOptions | None = None, chunk: int | None = None
) -> ExportReport:
    """Write the Gaussians' centres as a point cloud (.ply with sidecar, or .las/.laz at 1 mm) with class and source.

    ``chunk``: write that many points at a time (:func:`fusion.export_stream.export_points_chunked`, the same bytes;
    :func:`fusion.export_stream.export_chunk_points` gives it for a memory limit); None writes the cloud whole."""
    if chunk is not None:
        from fusion.export_stream import export_points_chunked

        return export_points_chunked(path, gaussians, options, chunk=chunk)  # type: ignore[return-value]
    path = Path(path)
    if path.suffix.lower() not in (".ply", ".las", ".laz"):
        raise FormatError(f"point export needs .ply, .las or .laz, got {path.suffix!r}", path)
    prep = prepare(gaussians, options)
    crs = options.crs if options is not None else None
    points = gaussians_to_points(prep.gaussians)
    if crs and path.suffix.lower() in (".las", ".laz"):
        from core.io.las import write_las

        out = write_las(path, points, crs=crs)
    else:
        out = write_point_cloud(path, points)
        if crs:
            write_origin(out, points.origin, crs)
    return _report(out, path.suffix.lower().lstrip("."), prep)


def export_gaussians(
    path: str | PathLike[str], gaussians: GaussianSet, options: ExportOptions | None = None
) -> ExportReport:
    """Dispatch on the suffix: ``.splat`` → :func:`export_splat`, ``.spz`` → :func:`export_spz`,
    ``.compressed.ply`` → :func:`export_compressed_ply`, ``.sog`` and ``…meta.json`` → :func:`export_sog`, other
    ``.json`` → :func:`export_tileset` (3D Tiles),
    ``.las``/``.laz`` → :func:`export_points`, ``.ply`` →
    3DGS PLY (:func:`export_gaussian_ply`); use :func:`export_points` for a point-cloud PLY."""
    suffix = Path(path).suffix.lower()
    if suffix == ".splat":
        return export_splat(path, gaussians, options)
    if suffix == ".spz":
        return export_spz(path, gaussians, options)
    if is_compressed_ply_path(path):
        return export_compressed_ply(path, gaussians, options)
    if is_sog_path(path):
        return export_sog(path, gaussians, options)
    if is_tileset_path(path):
        return export_tileset(path, gaussians, options)
    if suffix in (".las", ".laz"):
        return export_points(path, gaussians, options)
    if suffix == ".ply":
        return export_gaussian_ply(path, gaussians, options)
    raise FormatError(
        f"unknown export format {suffix!r}; expected .ply, .compressed.ply, .splat, .spz, .sog, .las, .laz, "
        "meta.json (SOG, unbundled) or tileset.json (3D Tiles)",
        path,
    )


def _report(path: Path, fmt: str, prep: Prepared) -> ExportReport:
    gs = prep.gaussians
    return ExportReport(
        path=Path(path),
        format=fmt,
        num_input=prep.num_input,
        dropped_crop=prep.dropped_crop,
        dropped_opacity=prep.dropped_opacity,
        num_written=len(gs),
        sh_degree=gs.sh_degree,
        origin=tuple(float(v) for v in gs.origin),  # type: ignore[arg-type]
    )
