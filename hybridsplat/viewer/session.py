"""The measuring state behind the viewer, free of any UI: clicks → picks → points → distances → files.

A click in the browser is a ray (origin = the viewer camera's centre, a direction). It becomes a :class:`Pick`:

- *snapped*: when the viewer camera sits at a photo's camera (after "jump to camera"), the ray is expressed as
  a pixel of that photo (its COLMAP camera, distortion included) with σ in photo pixels; such picks are also
  saved to ``picks.json`` for ``hybridsplat measure``;
- *free*: otherwise, as a pixel of a pinhole camera built from the viewer's canvas (vertical field of view,
  canvas size) with σ in screen pixels.

Either way the pick's ray is exactly the click ray; σ says how precisely the user clicked.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.cameras import Cameras, View
from core.errors import DataError
from eval.measure import MeasuredPoint, Measurements, Pick, TriangulationOptions, measurements_from, triangulate
from eval.measure.picks import ImagePick, PicksFile, PointPicks
from hybridsplat.viewer.scene import virtual_camera


@dataclass(frozen=True)
class ClientCamera:
    """The viewer's camera at a click: centre (3,) local, rotation camera → world (wxyz), vertical fov (rad),
    canvas size in pixels."""

    position: np.ndarray
    wxyz: np.ndarray
    fov_y: float
    width: int
    height: int


def snapped_view(cameras: Cameras, position: np.ndarray, tolerance: float) -> View | None:
    """The photo camera whose centre is within ``tolerance`` (metres) of ``position``, or None."""
    best, best_d = None, tolerance
    for view in cameras:
        d = float(np.linalg.norm(view.center - np.asarray(position, np.float64)))
        if d <= best_d:
            best, best_d = view, d
    return best


def pick_from_click(
    cameras: Cameras,
    client: ClientCamera,
    ray_origin: np.ndarray,
    ray_direction: np.ndarray,
    sigma_px: float,
    snap_tolerance: float,
    free_name: str = "<viewer>",
) -> Pick:
    """The pick of a click ray (local frame). Snapped to a photo when the viewer camera sits at one.

    free_name: the image name given to a free pick (unique per click: triangulation refuses one image twice).
    """
    origin = np.asarray(ray_origin, np.float64)
    direction = np.asarray(ray_direction, np.float64)
    norm = float(np.linalg.norm(direction))
    if not (np.all(np.isfinite(origin)) and np.isfinite(norm) and norm > 0):
        raise DataError("the click ray is not finite")
    direction = direction / norm
    view = snapped_view(cameras, origin, snap_tolerance)
    if view is not None:
        camera = cameras.camera_of(view)
        # Any point on the ray projects to the same pixel when the ray starts at the camera centre.
        target = view.center + direction
        xc = view.world_to_camera(target[None])
        if xc[0, 2] > 0:
            pixel = camera.project(xc)[0]
            if 0 <= pixel[0] <= camera.width and 0 <= pixel[1] <= camera.height:
                return Pick(camera, view, pixel, sigma_px)
    camera, view = virtual_camera(origin, client.wxyz, client.fov_y, client.width, client.height)
    xc = view.world_to_camera((origin + direction)[None])
    if xc[0, 2] <= 0:
        raise DataError("the click ray points behind the viewer camera")
    named = View(view.image_id, free_name, view.camera_id, view.quat_wxyz, view.translation)
    return Pick(camera, named, camera.project(xc)[0], sigma_px)


@dataclass
class MeasureSession:
    """Picks of the point being measured, the measured points, and the distances between consecutive ones.

    origin / unit / crs: the georeference of the local frame. options: triangulation options.
    """

    origin: np.ndarray
    unit: str = "m"
    crs: str | None = None
    options: TriangulationOptions = field(default_factory=TriangulationOptions)
    current: list[Pick] = field(default_factory=list)
    points: list[MeasuredPoint] = field(default_factory=list)
    pairs: list[tuple[str, str]] = field(default_factory=list)
    point_picks: dict[str, list[Pick]] = field(default_factory=dict)
    clicks: int = 0

    def free_name(self) -> str:
        """A fresh image name for a free (viewer-camera) pick."""
        self.clicks += 1
        return f"<viewer {self.clicks}>"

    def add_pick(self, pick: Pick) -> int:
        """Add a pick to the current point (replacing an earlier pick in the same photo); returns the count."""
        self.current = [p for p in self.current if p.image != pick.image] + [pick]
        return len(self.current)

    def finish_point(self, name: str | None = None) -> MeasuredPoint:
        """Triangulate the current picks into the next point; the picks are cleared only on success."""
        name = name or f"P{len(self.points) + 1}"
        point = triangulate(self.current, self.origin, self.options, name)
        self.points.append(point)
        self.point_picks[name] = list(self.current)
        if len(self.points) >= 2:
            self.pairs.append((self.points[-2].name, name))
        self.current = []
        return point

    def clear_picks(self) -> None:
        self.current = []

    def undo_point(self) -> None:
        """Remove the last point (and the distance that ends at it)."""
        if self.points:
            gone = self.points.pop().name
            self.point_picks.pop(gone, None)
            self.pairs = [p for p in self.pairs if gone not in p]

    def measurements(self) -> Measurements:
        return measurements_from(self.points, self.pairs, self.unit, self.crs)

    def picks_file(self) -> PicksFile:
        """The snapped picks of measured points as a PICKS.json (free picks have no photo and are left out)."""
        points = []
        for p in self.points:
            snapped = [q for q in self.point_picks.get(p.name, []) if not q.image.startswith("<viewer")]
            if len(snapped) >= 2:
                picks = tuple(ImagePick(q.image, float(q.pixel[0]), float(q.pixel[1]), q.sigma_px) for q in snapped)
                points.append(PointPicks(p.name, picks))
        names = {p.id for p in points}
        return PicksFile(tuple(points), tuple(pair for pair in self.pairs if set(pair) <= names))
