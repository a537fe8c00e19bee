"""Point clouds with float64 positions relative to a float64 local origin.

World coordinates of point i are ``origin + positions[i]``. Georeferenced data (UTM, national grids,
1e5–1e7 m) keeps its large offset in ``origin`` so that ``positions`` stay small: anything that goes to
float32 or to the GPU takes ``positions``, never world coordinates.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from core.errors import DataError


@dataclass
class PointCloud:
    """A point cloud.

    Attributes
    ----------
    positions: (N, 3) float64, metres, relative to ``origin``.
    origin: (3,) float64, metres, world coordinates of the local origin.
    colors: (N, 3) uint8 RGB or None (float input is read as [0, 1] and converted).
    normals: (N, 3) float32 unit normals or None.
    fields: named per-point scalar fields, each (N,) (e.g. ``classification`` uint8, ``c2c`` float64,
        ``confidence`` float32, ``material`` int32). Names are kept verbatim on export.
    visibility: per point, the ids of the images that see it (COLMAP ``fused.ply.vis``), or None.
    """

    positions: np.ndarray
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    colors: np.ndarray | None = None
    normals: np.ndarray | None = None
    fields: dict[str, np.ndarray] = field(default_factory=dict)
    visibility: list[np.ndarray] | None = None

    def __post_init__(self) -> None:
        self.positions = np.ascontiguousarray(np.asarray(self.positions, dtype=np.float64).reshape(-1, 3))
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        n = len(self.positions)
        if self.colors is not None:
            self.colors = _as_colors(self.colors, n)
        if self.normals is not None:
            self.normals = np.asarray(self.normals, dtype=np.float32).reshape(-1, 3)
            _check_len("normals", len(self.normals), n)
        self.fields = {name: np.asarray(values).reshape(-1) for name, values in self.fields.items()}
        for name, values in self.fields.items():
            _check_len(f"field {name!r}", len(values), n)
        if self.visibility is not None:
            _check_len("visibility", len(self.visibility), n)
            self.visibility = [np.asarray(v, dtype=np.int64).reshape(-1) for v in self.visibility]

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def from_world(cls, world_positions: np.ndarray, origin: np.ndarray | None = None, **kwargs: object) -> PointCloud:
        """A cloud from world coordinates; the origin defaults to the rounded bounding-box centre."""
        world = np.asarray(world_positions, dtype=np.float64).reshape(-1, 3)
        if origin is None:
            origin = choose_origin(world)
        return cls(world - np.asarray(origin, dtype=np.float64), origin, **kwargs)  # type: ignore[arg-type]

    # -- access ---------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.positions)

    @property
    def world_positions(self) -> np.ndarray:
        """(N, 3) float64 world coordinates, ``origin + positions``."""
        return self.positions + self.origin

    def with_origin(self, origin: np.ndarray) -> PointCloud:
        """The same points expressed relative to another origin (float64, no loss of precision)."""
        origin = np.asarray(origin, dtype=np.float64).reshape(3)
        return replace(self, positions=self.positions + (self.origin - origin), origin=origin)

    def subset(self, index: np.ndarray | slice) -> PointCloud:
        """The points selected by a boolean mask, an index array or a slice; every attribute follows."""
        vis = None
        if self.visibility is not None:
            picked = np.arange(len(self))[index]
            vis = [self.visibility[i] for i in picked]
        return PointCloud(
            positions=self.positions[index],
            origin=self.origin.copy(),
            colors=None if self.colors is None else self.colors[index],
            normals=None if self.normals is None else self.normals[index],
            fields={k: v[index] for k, v in self.fields.items()},
            visibility=vis,
        )

    def chunks(self, chunk_size: int = 1_000_000) -> Iterator[PointCloud]:
        """Consecutive sub-clouds of at most ``chunk_size`` points (views where possible, no copy of positions)."""
        if chunk_size <= 0:
            raise DataError(f"chunk_size must be positive, got {chunk_size}")
        for start in range(0, len(self), chunk_size):
            yield self.subset(slice(start, start + chunk_size))

    def validate(self, name: str = "point cloud") -> None:
        """Raise :class:`DataError` if positions contain NaN or inf (naming the first bad point)."""
        bad = ~np.isfinite(self.positions).all(axis=1)
        if bad.any():
            first = int(np.flatnonzero(bad)[0])
            raise DataError(f"{name}: {int(bad.sum())} points have NaN or infinite coordinates (first: point {first})")

    @staticmethod
    def concatenate(clouds: Sequence[PointCloud]) -> PointCloud:
        """One cloud from several; expressed in the first cloud's origin. Attributes absent in any are dropped."""
        if not clouds:
            raise DataError("cannot concatenate an empty list of clouds")
        origin = clouds[0].origin
        moved = [c.with_origin(origin) for c in clouds]
        colors = None if any(c.colors is None for c in moved) else np.concatenate([c.colors for c in moved])
        normals = None if any(c.normals is None for c in moved) else np.concatenate([c.normals for c in moved])
        names = set.intersection(*(set(c.fields) for c in moved))
        fields = {k: np.concatenate([c.fields[k] for c in moved]) for k in sorted(names)}
        vis = None
        if all(c.visibility is not None for c in moved):
            vis = [v for c in moved for v in c.visibility]  # type: ignore[union-attr]
        return PointCloud(np.concatenate([c.positions for c in moved]), origin, colors, normals, fields, vis)


def choose_origin(world_positions: np.ndarray, granularity: float = 1.0) -> np.ndarray:
    """A local origin for world coordinates: the bounding-box centre rounded to ``granularity`` metres.

    Returns zeros for clouds already near the origin (|coordinates| < 1e4 m) so small scenes keep their frame.
    """
    world = np.asarray(world_positions, dtype=np.float64).reshape(-1, 3)
    finite = world[np.isfinite(world).all(axis=1)]
    if len(finite) == 0 or np.abs(finite).max() < 1e4:
        return np.zeros(3)
    centre = (finite.min(axis=0) + finite.max(axis=0)) / 2
    return np.round(centre / granularity) * granularity


def _check_len(what: str, got: int, expected: int) -> None:
    if got != expected:
        raise DataError(f"{what} has {got} entries but the cloud has {expected} points")


def _as_colors(colors: np.ndarray, n: int) -> np.ndarray:
    c = np.asarray(colors)
    if c.dtype != np.uint8:
        if np.issubdtype(c.dtype, np.floating):
            if not np.isfinite(c).all():
                raise DataError("colours contain NaN or infinite values")
            c = np.clip(np.round(c * 255.0), 0, 255)  # float colours are in [0, 1]
        elif c.size and (c.min() < 0 or c.max() > 255):
            raise DataError(f"integer colours must lie in 0..255, got {c.min()}..{c.max()}")
        c = c.astype(np.uint8)
    c = c.reshape(-1, 3)
    _check_len("colours", len(c), n)
    return c
