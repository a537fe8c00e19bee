"""The eval stage's geometry with bounded memory (issue 34): C2C and per-material scores against a reference cloud
read in chunks, through :func:`eval.c2c_stream.exact_nearest`, with the figures of the in-memory path.

:func:`compare_clouds_streamed` is :func:`eval.c2c.compare_clouds` and :func:`geometry_per_material_streamed` is
:func:`eval.per_material.geometry_per_material` with the reference as a :class:`core.io.point_stream.PointSource`
(a LAS/LAZ or binary PLY file read ``chunk`` points at a time). Both clouds go through the cells as chunks; the
compared cloud is a product the stage holds in memory anyway (it renders it and writes its distance cloud), so its
per-point results (distances, nearest reference index) are in memory too and the figures over them are the
in-memory functions' own. What is over the reference (reverse statistics, completeness, materials) is read by
chunks from memory-mapped files in a temporary work folder.

Exact (equal to the in-memory figures bit for bit): every distance both ways (the nearest point is searched up to
the halo in the cells, then in the whole other cloud for the points with none that near), the forward statistics,
per-class statistics, histogram, precision / recall / F-score, the reverse counts, min, max and percentiles, the
completeness per material. Within float rounding: the reverse mean, std and rmse (float64 sums by chunks, not
numpy's pairwise sums: a few ulps) and — only where two reference points of different materials are exactly
equidistant from a product point — which material a product point is counted on. Units: metres.
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import ConfigError, DataError
from core.io.point_stream import PointSource, cloud_source, las_source, ply_source
from core.pointcloud import PointCloud, choose_origin
from eval.c2c import C2CResult, ThresholdScores, per_class_stats
from eval.c2c_stream import C2CPlan, ChunkSource, array_chunks, exact_nearest, las_chunks, streamed_distance_stats
from eval.per_material import MaterialGeometry

_HALO_SHARE = 0.005  # the cells' search radius: this share of the reference's x-y diagonal (metres), at least 2 τ


def reference_source(path: str | PathLike[str], chunk: int) -> PointSource:
    """The reference cloud at ``path`` as chunks of ``chunk`` points, with the origin and positions that
    :func:`core.io.read_point_cloud` gives it: LAS/LAZ (:func:`las_source`, the origin of ``read_las`` from the data)
    and binary PLY (:func:`ply_source`) streamed; other formats (E57, ASCII PLY) are read whole, then cut."""
    from core.errors import FormatError
    from core.io import read_point_cloud

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".las", ".laz"):
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for world in las_chunks(path, np.zeros(3), chunk)():  # ints·scale + offset, as read_las takes its origin
            if len(world):
                lo, hi = np.minimum(lo, world.min(axis=0)), np.maximum(hi, world.max(axis=0))
        origin = choose_origin(np.array([lo, hi])) if np.isfinite(lo).all() else np.zeros(3)
        return las_source(path, origin, chunk)
    if suffix == ".ply":
        try:
            return ply_source(path, chunk=chunk)
        except FormatError:  # ASCII, or the vertex element not first: read whole below
            pass
    cloud = read_point_cloud(path)
    return PointSource(cloud_source(cloud, chunk).chunks, path)


def _scan(reference: PointSource) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(lo, hi) of the local positions (metres), the chunks' origin and the point count, checked finite."""
    lo, hi, origin, count = np.full(3, np.inf), np.full(3, -np.inf), np.zeros(3), 0
    for chunk in reference.chunks():
        chunk.validate(f"reference cloud {reference.name}")
        if len(chunk):
            lo, hi = np.minimum(lo, chunk.positions.min(axis=0)), np.maximum(hi, chunk.positions.max(axis=0))
        origin, count = chunk.origin, count + len(chunk)
    if count == 0:
        raise DataError(f"the reference cloud {reference.name} is empty; C2C needs at least one reference point")
    return lo, hi, origin, count


def _halo(lo: np.ndarray, hi: np.ndarray, tau: float | None) -> float:
    """The cells' search radius (metres): a share of the x-y diagonal, at least 2 τ, never 0."""
    diagonal = float(np.hypot(hi[0] - lo[0], hi[1] - lo[1]))
    return max(_HALO_SHARE * diagonal, 2 * tau if tau is not None else 0.0, 1e-6)


def _local(reference: PointSource, origin: np.ndarray) -> ChunkSource:
    """The reference's positions relative to ``origin`` as :meth:`PointCloud.with_origin` gives them."""
    return lambda: (chunk.with_origin(origin).positions for chunk in reference.chunks())


def _count_below(values: np.ndarray, tau: float, chunk: int) -> int:
    return sum(int(np.count_nonzero(values[i : i + chunk] < tau)) for i in range(0, len(values), chunk))


def compare_clouds_streamed(
    compared: PointCloud,
    reference: PointSource,
    plan: C2CPlan,
    max_dist: float | None = None,
    tau: float | None = None,
    class_field: str = "classification",
    work_dir: str | PathLike[str] | None = None,
    workers: int = -1,
) -> C2CResult:
    """:func:`eval.c2c.compare_clouds` of ``compared`` against a streamed ``reference`` with the cell and chunk
    sizes of ``plan``; temporary files (about 48 bytes a point of both clouds) in ``work_dir``. Returns the same
    :class:`C2CResult` (see the module's note on what is exact)."""
    compared.validate("compared cloud")
    if len(compared) == 0:
        raise DataError("the compared cloud is empty; C2C needs at least one compared point")
    if max_dist is not None and not (max_dist > 0 and np.isfinite(max_dist)):
        raise ConfigError(f"max_dist must be a positive finite distance in metres, got {max_dist}")
    if tau is not None and not (tau > 0 and np.isfinite(tau)):
        raise ConfigError(f"tau must be a positive finite distance in metres, got {tau}")
    lo, hi, ref_origin, n_ref = _scan(reference)
    origin = ref_origin + choose_origin(np.array([lo, hi]))  # eval.c2c.common_origin(reference, compared)
    cmp_local = compared.with_origin(origin).positions
    bound = None if max_dist is None else (max_dist if tau is None else max(max_dist, tau))
    reverse = scores = None
    with tempfile.TemporaryDirectory(prefix="hybridsplat_eval_c2c_", dir=work_dir) as tmp:
        near = exact_nearest(
            array_chunks(cmp_local, plan.chunk), _local(reference, origin), _halo(lo, hi, tau), tmp,
            points_per_cell=plan.points_per_cell, block=plan.chunk, exact_reverse=tau is not None, workers=workers,
        )  # fmt: skip
        d = np.array(near.forward)
        if bound is not None:
            d = np.minimum(d, bound)  # as nearest_distances clamps what lies beyond its search bound
        if tau is not None:
            reverse = streamed_distance_stats(near.reverse, chunk=plan.chunk)
            precision = float(np.count_nonzero(d < tau) / len(d))
            recall = _count_below(near.reverse, tau, plan.chunk) / n_ref
            fscore = 2.0 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
            scores = ThresholdScores(float(tau), precision, recall, fscore)
        del near  # the memory maps close before their folder goes
    if max_dist is not None:
        d = np.minimum(d, max_dist)
    from eval.c2c import distance_stats

    per_class = {}
    if class_field in compared.fields:
        per_class = per_class_stats(d, compared.fields[class_field], max_dist)
    return C2CResult(d, distance_stats(d, max_dist), reverse, scores, per_class)


def _materials(reference: PointSource, field: str) -> Iterator[np.ndarray]:
    for chunk in reference.chunks():
        if field not in chunk.fields:
            raise DataError(f"the reference cloud {reference.name} has no {field!r} field")
        yield np.asarray(chunk.fields[field]).astype(np.int64).reshape(-1)


def geometry_per_material_streamed(
    compared_world: np.ndarray,
    reference: PointSource,
    tau: float,
    plan: C2CPlan,
    work_dir: str | PathLike[str] | None = None,
    field: str = "material",
) -> dict[int, MaterialGeometry]:
    """:func:`eval.per_material.geometry_per_material` of (N, 3) float64 world points against a streamed reference
    with a per-point ``field`` (material ids), in the same frame (world minus the reference's first point)."""
    cmp_world = np.asarray(compared_world, np.float64).reshape(-1, 3)
    chunks = iter(reference.chunks())
    first = next(chunks, None)
    getattr(chunks, "close", lambda: None)()  # the reader behind the first chunk is let go
    if first is None or len(first) == 0:
        return {}
    anchor = first.world_positions[0]
    with tempfile.TemporaryDirectory(prefix="hybridsplat_eval_material_", dir=work_dir) as tmp:
        owner = d_acc = reverse = near = None
        if len(cmp_world):
            lo, hi, _, _ = _scan(reference)
            world = lambda: (chunk.world_positions - anchor for chunk in reference.chunks())  # noqa: E731
            near = exact_nearest(
                array_chunks(cmp_world - anchor, plan.chunk), world, _halo(lo, hi, tau), tmp,
                points_per_cell=plan.points_per_cell, block=plan.chunk, exact_reverse=False,
            )  # fmt: skip
            d_acc, reverse = np.array(near.forward), near.reverse
            owner = np.empty(len(cmp_world), np.int64)
            materials = np.lib.format.open_memmap(Path(tmp) / "material.npy", "w+", np.int64, (len(reverse),))
            start = 0
            for labels in _materials(reference, field):
                materials[start : start + len(labels)] = labels
                start += len(labels)
            owner[:] = materials[np.asarray(near.nearest)]
            del materials
        totals, hits = _completeness(reference, field, reverse, tau)
        del reverse, near
    out: dict[int, MaterialGeometry] = {}
    for m in sorted(totals):
        on_m = d_acc[owner == m] if owner is not None else np.zeros(0)  # type: ignore[index]
        out[m] = MaterialGeometry.of(on_m, hits[m] / totals[m], totals[m], tau)
    return out


def _completeness(
    reference: PointSource, field: str, reverse: np.ndarray | None, tau: float
) -> tuple[dict[int, int], dict[int, int]]:
    """Reference points per material id, and those with a compared point within ``tau`` (reverse ≤ τ; none when
    ``reverse`` is None: an empty product)."""
    totals: dict[int, int] = {}
    hits: dict[int, int] = {}
    start = 0
    for labels in _materials(reference, field):
        ids, inverse = np.unique(labels, return_inverse=True)
        near = np.zeros(len(labels), bool) if reverse is None else reverse[start : start + len(labels)] <= tau
        counts = np.bincount(inverse, minlength=len(ids))
        within = np.bincount(inverse[near], minlength=len(ids))
        for m, c, h in zip(ids.tolist(), counts.tolist(), within.tolist(), strict=True):
            totals[m], hits[m] = totals.get(m, 0) + c, hits.get(m, 0) + h
        start += len(labels)
    return totals, hits


def spool_reference(
    source: PointSource, folder: str | PathLike[str], chunk: int, field: str = "material"
) -> PointSource:
    """``source`` copied once into raw files in ``folder`` (its positions as float64 relative to its chunks' origin,
    24 bytes a point, and ``field`` as int64 when it has one, 8 more): the later passes (a C2C and a per-material
    score per product, several passes each) read those ``chunk`` points at a time instead of decoding the LAS/LAZ
    again. The chunks hold the same values (positions, origin, ``field``; no other attribute), so every figure is
    the same as from ``source``; ``path`` stays the source's (named in errors and summaries)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    positions, labels = folder / "positions.f8", folder / f"{field}.i8"
    count, origin, has_field = 0, np.zeros(3), None
    with open(positions, "wb") as pos_out, open(labels, "wb") as lab_out:
        for cloud in source.chunks():
            cloud.validate(f"reference cloud {source.name}")
            has_field = (field in cloud.fields) if has_field is None else has_field
            pos_out.write(np.ascontiguousarray(cloud.positions, np.float64).tobytes())
            if has_field:
                lab_out.write(np.asarray(cloud.fields[field]).astype(np.int64).reshape(-1).tobytes())
            count, origin = count + len(cloud), cloud.origin.copy()

    def chunks() -> Iterator[PointCloud]:
        for a in range(0, count, chunk):
            n = min(chunk, count - a)
            xyz = np.fromfile(positions, np.float64, count=3 * n, offset=24 * a).reshape(n, 3)
            fields = {field: np.fromfile(labels, np.int64, count=n, offset=8 * a)} if has_field else {}
            yield PointCloud(xyz, origin, fields=fields)

    return PointSource(chunks, source.path)
