"""Region masks per registered photo: where splats must be trained.

A mask pixel is set (255 in the PNG) where

- a point classified as needing splats projects, drawn with its footprint (``footprint × spacing`` metres at
  the point's depth, in pixels) and only where no collaborative point lies in front (z-buffer of all points);
- the MVS cloud has a hole: pixels inside the scene's valid area that no fused point explains. A point explains
  the pixels within ``hole_gsd`` ground sample distances (GSD: metres per pixel at the block's median depth, as
  data_synth and the evaluation define it; the evaluation's τ is 3 GSD) of its projection, i.e.
  ``hole_gsd × GSD`` metres at the point's depth, when it is seen in this photo: with
  ``explained_by="seen"`` (default) only points that this photo fused (``fused.ply.vis``) or whose colour
  matches the photo at their projection (within ``colour_tolerance``); a point hidden behind a surface that MVS
  missed (glass, metal, thin wires in front of it) is neither, so the missed surface becomes a hole.
  ``"all"`` lets every projected point explain its pixels (the hidden ones too). (``hole_gsd = 0``: the older
  radius of ``hole_footprint`` point spacings, a different multiple of τ on differently sampled clouds; see
  docs/experiments/2026-11-27-domain-defaults.md.) The valid area (``hole_area``) is by default (``"hull_below"``) the
  convex hull of the cloud's projection united with every pixel below the upper envelope of the cloud's
  projection, "up" being the projection of the world ``up`` axis (sky lies above the scene in upright photos; a
  photo looking along ``up``, e.g. nadir, is all scene), so that unreconstructed surfaces outside the hull count
  as holes while the sky does not. ``"hull"`` and ``"below"`` are the two parts alone; ``"enclosed"``: only
  uncovered regions enclosed by covered pixels (no sky, but border holes are missed). With ``grow_area`` > 0 and
  the photo, the valid area grows by what *looks like* the reconstructed scene: OpenCV's GrabCut segments
  the photo from colour models of the pixels covered by points (certain scene), the rest of the valid area
  (probably scene) and the pixels outside it (probably not). The far part of a table or terrain seen at a
  grazing angle, which MVS did not reconstruct, lies above the cloud's outline but looks like the table or the
  terrain; sky and backdrop do not. The growth is on by default because it covers most of the needs-splats
  pixels the cloud's outline misses at a small cost in the rest (measured on held-out scenes; see
  docs/experiments/2026-11-27-domain-defaults.md). Pixels at infinity (no parallax between the
  photo and its neighbours but parallax at the view's median point depth, :func:`at_infinity`: sky, a distant
  backdrop; not a uniform surface, which agrees at every depth) outside what the cloud's points
  enclose are no valid area and GrabCut's certain background; with such a backdrop in view, the area below the
  envelope outside the hull keeps only what GrabCut puts with the scene;
- a user mask (the pipeline's ``--splat-masks``) is set.

The union is closed (fills gaps between footprints) and dilated (a safety margin for training). Held-out
photos get masks for evaluation only; the caller decides which views to pass.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from classify.mask_options import EXPLAINED_BY, HOLE_AREAS, ExplainedBy, HoleArea, MaskOptions  # noqa: F401 (re-exported)
from core.cameras import Cameras, View
from core.errors import DataError


@dataclass(frozen=True)
class PhotoMask:
    """The mask of one photo: ``mask`` (H, W) bool (True = needs splats); ``coverage`` its share of the image;
    ``points_px`` share from non-collaborative points, ``holes_px`` from MVS holes, ``user_px`` from user masks
    (shares of the image before closing/dilation); ``empty`` when nothing is set (training skips the photo);
    ``train_margin_px`` the extra dilation radius (pixels) of the training mask (see ``train_margin_spacings``)."""

    name: str
    mask: np.ndarray
    coverage: float
    points_px: float
    holes_px: float
    user_px: float
    train_margin_px: int = 0

    @property
    def empty(self) -> bool:
        return not bool(self.mask.any())


@dataclass(frozen=True)
class SeenInView:
    """Which points a photo sees: those it fused, or whose colour matches the photo at their projection.

    visibility: per point, the image ids that fused it (``PointCloud.visibility``; None: colours only).
    colors: (N, 3) uint8 point colours (None: fused only). photo: image name → (H, W, 3) uint8 photo at the
    camera's resolution (other sizes are sampled proportionally)."""

    visibility: list[np.ndarray] | None
    colors: np.ndarray | None
    photo: Callable[[str], np.ndarray] | None

    def __post_init__(self) -> None:
        if self.visibility is not None:
            counts = np.fromiter((len(v) for v in self.visibility), dtype=np.int64, count=len(self.visibility))
            flat = np.concatenate(self.visibility) if counts.sum() else np.zeros(0, np.int64)
            object.__setattr__(self, "_flat", np.asarray(flat, dtype=np.int64))
            object.__setattr__(self, "_owner", np.repeat(np.arange(len(self.visibility)), counts))

    def explains(
        self, view: View, idx: np.ndarray, col: np.ndarray, row: np.ndarray, size: tuple[int, int], tolerance: float
    ) -> np.ndarray:
        """(M,) bool for the points ``idx`` (M,) projected at pixels (col, row) of ``view`` (camera ``size`` =
        (width, height)): fused by it, or of the photo's colour there (best of the 3×3 pixels around, mean
        |ΔRGB| / 255 < ``tolerance``)."""
        ok = np.zeros(len(idx), dtype=bool)
        if self.visibility is not None:
            fused = np.zeros(len(self.visibility), dtype=bool)
            fused[self._owner[self._flat == view.image_id]] = True  # type: ignore[attr-defined]
            ok |= fused[idx]
        if self.colors is not None and self.photo is not None and len(idx):
            img = np.asarray(self.photo(view.name))
            if img.ndim == 2:
                img = np.repeat(img[..., None], 3, axis=2)
            h, w = img.shape[:2]
            c = (np.asarray(col) * (w / size[0])).astype(np.int64)
            r = (np.asarray(row) * (h / size[1])).astype(np.int64)
            pc = np.asarray(self.colors, dtype=np.float32)[idx].reshape(-1, 3)
            best = np.full(len(idx), np.inf, dtype=np.float32)
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    px = img[np.clip(r + dy, 0, h - 1), np.clip(c + dx, 0, w - 1)].astype(np.float32).reshape(-1, 3)
                    best = np.minimum(best, np.abs(px - pc).mean(axis=1))
            ok |= best < tolerance * 255.0
        return ok


def disk_kernel(radius: int) -> np.ndarray:
    """OpenCV's elliptic structuring element of ``radius`` pixels ((2r + 1) × (2r + 1), uint8)."""
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def splat_footprints(
    shape: tuple[int, int], col: np.ndarray, row: np.ndarray, radius_px: np.ndarray, max_radius: int
) -> np.ndarray:
    """(H, W) bool: the union of disks of integer radius ``radius_px`` (clipped to 0..max_radius) around pixels.

    Hand-written because no library rasterises many disks of varying radius at once: points are grouped by
    radius, each group's centres drawn once and dilated with one disk (a few OpenCV dilations per image)."""
    h, w = shape
    out = np.zeros((h, w), dtype=np.uint8)
    c = np.clip(col.astype(np.int64), 0, w - 1)
    r = np.clip(row.astype(np.int64), 0, h - 1)
    rad = np.clip(np.round(radius_px).astype(np.int64), 0, max_radius)
    for value in np.unique(rad):
        sel = rad == value
        layer = np.zeros((h, w), dtype=np.uint8)
        layer[r[sel], c[sel]] = 1
        if value > 0:
            layer = cv2.dilate(layer, disk_kernel(int(value)))
        out |= layer
    return out.astype(bool)


def _below_envelope(
    cameras: Cameras, view: View, points: np.ndarray, covered: np.ndarray, up: np.ndarray
) -> np.ndarray:
    """(H, W) bool: pixels on the far side of the covered region's upper envelope from "up" in the image.

    "Up" in the image is the projection of ``up`` at the points' centroid; when it is shorter than a tenth of the
    image (the view looks along ``up``) or mostly sideways, every pixel counts (nadir photos see no sky)."""
    h, w = covered.shape
    if len(points) == 0 or not covered.any():
        return np.zeros((h, w), dtype=bool)
    c = points.mean(axis=0)
    scale = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))) or 1.0
    ends, z = cameras.project(view, np.stack([c, c + 0.1 * scale * up / max(np.linalg.norm(up), 1e-12)]))
    if np.any(z <= 0):
        return np.ones((h, w), dtype=bool)
    d = ends[1] - ends[0]
    if np.linalg.norm(d) < 0.01 * max(h, w) or abs(d[1]) < abs(d[0]):
        return np.ones((h, w), dtype=bool)
    rows_up = d[1] < 0  # up points to smaller rows: the sky is at the top
    cols = np.flatnonzero(covered.any(axis=0))
    grid = covered[:, cols]
    edge = grid.argmax(axis=0) if rows_up else h - 1 - grid[::-1].argmax(axis=0)
    env = np.interp(np.arange(w), cols, edge)
    rr = np.arange(h)[:, None]
    return rr >= env[None, :] if rows_up else rr <= env[None, :]


def _reduced_rgb(photo: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The photo ((h, w, 3) or (h, w), any size) as contiguous (H, W, 3) uint8 at ``size`` = (H, W) (area
    averaging when it is resized)."""
    img = photo if photo.ndim == 3 else np.repeat(photo[..., None], 3, axis=2)
    img = np.ascontiguousarray(img[..., :3], dtype=np.uint8)
    if img.shape[:2] != size:
        img = cv2.resize(img, (size[1], size[0]), interpolation=cv2.INTER_AREA)
    return img


def _grow_area(
    photo: np.ndarray,
    covered: np.ndarray,
    area: np.ndarray,
    iterations: int,
    max_px: int = 640,
    background: np.ndarray | None = None,
) -> np.ndarray:
    """(H, W) bool (the shape of ``covered``): the pixels that look like the reconstructed scene.

    OpenCV's GrabCut (colour mixture models + a smoothness term, ``iterations`` rounds) on the photo (any size,
    (h, w, 3) or (h, w) uint8), initialised with the pixels covered by points (``covered`` (H, W) bool: certain
    scene), the rest of ``area`` (H, W) bool (probably scene) and every other pixel (probably not scene); run at
    most ``max_px`` pixels on the long side and scaled back (nearest). Empty when a seed class is missing."""
    h, w = covered.shape
    scale = min(1.0, max_px / max(h, w))
    sh, sw = max(1, round(h * scale)), max(1, round(w * scale))
    img = _reduced_rgb(photo, (sh, sw))
    gc = np.full((h, w), cv2.GC_PR_BGD, dtype=np.uint8)
    gc[area] = cv2.GC_PR_FGD
    if background is not None:
        gc[background] = cv2.GC_BGD
    gc[covered] = cv2.GC_FGD
    if (sh, sw) != (h, w):
        gc = cv2.resize(gc, (sw, sh), interpolation=cv2.INTER_NEAREST)
    if not (gc == cv2.GC_PR_BGD).any() or not (gc == cv2.GC_FGD).any():
        return np.zeros((h, w), dtype=bool)
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(0)  # GrabCut seeds its k-means from OpenCV's global generator: fixed for determinism
    cv2.grabCut(img, gc, None, bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    scene = ((gc == cv2.GC_FGD) | (gc == cv2.GC_PR_FGD)).astype(np.uint8)
    if (sh, sw) != (h, w):
        scene = cv2.resize(scene, (w, h), interpolation=cv2.INTER_NEAREST)
    return scene.astype(bool)


def at_infinity(
    cameras: Cameras,
    view: View,
    photo: Callable[[str], np.ndarray],
    sources: int = 4,
    max_angle_deg: float = 45.0,
    tolerance: float = 0.01,
    window: int = 5,
    max_px: int = 640,
    finite_depth: float | None = None,
) -> np.ndarray:
    """(H, W) bool: pixels of ``view`` whose colour shows no parallax: they lie at infinity (sky, a distant
    backdrop), where multi-view stereo finds nothing and no splat is needed.

    A direction seen from two camera positions maps between the photos by the cameras' rotation alone (the
    "infinite homography") when it is at infinity; a finite surface moves by its parallax (baseline × focal /
    depth pixels). Each of the ``sources`` nearest other cameras whose optical axis is within ``max_angle_deg``
    is resampled along the same directions (``cv2.remap``); a pixel is at infinity when one of them agrees with
    the photo there within ``tolerance`` (mean |ΔRGB| / 255 over a ``window`` × ``window`` box). One is enough:
    finite objects hide different parts of a backdrop from each camera. A uniform finite region wider than its
    parallax agrees too (a blank wall seen from close cameras), so callers apply this only outside the
    reconstructed scene's outline. With ``finite_depth`` (z-depth in metres, e.g. the median depth of the view's
    points), a pixel is at infinity only where a neighbour agrees at infinity *and disagrees* at that finite depth:
    a uniform region agrees at every depth, so the photos cannot say where it is (a textureless slab, a blank wall
    running out of the photo), and it is not called infinity. Runs at most ``max_px`` pixels on the long side.
    Hand-written: OpenCV warps by a homography but has no parallax test over a block of cameras."""
    cam = cameras.camera_of(view)
    h, w = cam.height, cam.width
    axis, centre = view.rotation[2], view.center  # optical axis: third row of the world-to-camera rotation
    near = []
    for other in cameras:
        dist = float(np.linalg.norm(other.center - centre))
        if (
            other.image_id != view.image_id
            and dist > 0
            and axis @ other.rotation[2] >= np.cos(np.radians(max_angle_deg))
        ):
            near.append((dist, other.image_id, other))
    chosen = [o for _, _, o in sorted(near, key=lambda c: c[:2])[:sources]]
    scale = min(1.0, max_px / max(h, w))
    sh, sw = max(1, round(h * scale)), max(1, round(w * scale))

    def load(v: View) -> np.ndarray:
        return _reduced_rgb(np.asarray(photo(v.name)), (sh, sw))

    def agreement(other: View, source: np.ndarray, d_cam: np.ndarray) -> np.ndarray:
        """(sh, sw) bool: ``other``'s photo resampled at the points ``d_cam`` (its camera frame) agrees with ref."""
        ocam = cameras.camera_of(other)
        front = d_cam[:, 2] > 1e-6
        uv = np.full((len(d_cam), 2), -1e6)
        uv[front] = ocam.project(d_cam[front])
        ox = (uv[:, 0] * (sw / ocam.width) - 0.5).reshape(sh, sw).astype(np.float32)
        oy = (uv[:, 1] * (sh / ocam.height) - 0.5).reshape(sh, sw).astype(np.float32)
        inside = ((ox >= 0) & (oy >= 0) & (ox <= sw - 1) & (oy <= sh - 1)).astype(np.uint8)
        warped = cv2.remap(source, ox, oy, cv2.INTER_LINEAR).astype(np.float32)
        diff = cv2.blur(np.abs(warped - ref).mean(axis=2), (window, window)) / 255.0
        return cv2.erode(inside, np.ones((window, window), np.uint8)).astype(bool) & (diff < tolerance)

    agree = np.zeros((sh, sw), dtype=bool)
    if chosen:
        ref = load(view).astype(np.float32)
        rows, cols = np.mgrid[0:sh, 0:sw]
        pix = np.c_[(cols.ravel() + 0.5) / scale, (rows.ravel() + 0.5) / scale]
        rays = cam.unproject(pix, 1.0)  # camera frame, z = 1
        dirs = rays @ view.rotation  # world directions of the pixels' rays (d_w = Rᵀ d_c)
    for other in chosen:
        source = load(other)
        at_inf = agreement(other, source, dirs @ other.rotation.T)
        if finite_depth is not None and finite_depth > 0 and at_inf.any():
            # The same rays ending at z = finite_depth, in the other camera's frame: R_o (C + d Rᵀ r) + t_o.
            finite = (view.center + finite_depth * dirs) @ other.rotation.T + other.translation
            at_inf &= ~agreement(other, source, finite)
        agree |= at_inf
    if (sh, sw) != (h, w):
        agree = cv2.resize(agree.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)
    return agree


def ground_sample_distance(cameras: Cameras, positions: np.ndarray, names: list[str] | None = None) -> float:
    """The block's ground sample distance (metres per pixel): over the views (those named in ``names``), the median
    of (median depth of the points (N, 3) float64 inside the view's frustum) / focal length in pixels, as data_synth
    defines a scene's GSD from its depth maps. 0 when no view sees a point."""
    pts = np.asarray(positions, dtype=np.float64)
    per_view = []
    for view in cameras:
        if names is not None and view.name not in names:
            continue
        cam = cameras.camera_of(view)
        uv, z = cameras.project(view, pts)
        inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] < cam.height)
        if inside.any():
            per_view.append(float(np.median(z[inside])) / cam.focal[0])
    return float(np.median(per_view)) if per_view else 0.0


@dataclass(frozen=True)
class _Projected:
    """The points of one view that project onto its photo padded by ``pad`` pixels (in front of the camera):
    ``idx`` (M,) int64 indices into the cloud, pixel ``col`` / ``row`` (M,) float64 and depth ``z`` (M,) metres."""

    idx: np.ndarray
    col: np.ndarray
    row: np.ndarray
    z: np.ndarray
    h: int
    w: int
    pad: int

    def draw(self, sel: np.ndarray, radius_px: np.ndarray) -> np.ndarray:
        """(h, w) bool footprints of the points ``sel`` (M,) bool with radii ``radius_px`` (M,), drawn on the canvas
        padded by ``pad`` (points just outside the photo still cover its border pixels) and cropped."""
        h, w, pad = self.h, self.w, self.pad
        canvas = splat_footprints(
            (h + 2 * pad, w + 2 * pad), self.col[sel] + pad, self.row[sel] + pad, radius_px[sel], pad
        )
        return canvas[pad : pad + h, pad : pad + w]


def _project(cameras: Cameras, view: View, positions: np.ndarray, pad: int) -> _Projected:
    cam = cameras.camera_of(view)
    h, w = cam.height, cam.width
    uv, z = cameras.project(view, positions)
    inside = (z > 0) & (uv[:, 0] >= -pad) & (uv[:, 1] >= -pad) & (uv[:, 0] < w + pad) & (uv[:, 1] < h + pad)
    idx = np.flatnonzero(inside)
    return _Projected(idx, uv[idx, 0], uv[idx, 1], z[idx], h, w, pad)


def photo_mask(
    cameras: Cameras,
    view: View,
    positions: np.ndarray,
    needs_splats: np.ndarray,
    spacing: float,
    options: MaskOptions = MaskOptions(),
    user_mask: np.ndarray | None = None,
    seen: SeenInView | None = None,
    gsd: float | None = None,
) -> PhotoMask:
    """The mask of one view from the classified cloud (positions (N, 3) float64 in the cameras' frame,
    needs_splats (N,) bool, spacing metres). seen: what tells which points this photo sees (for
    ``explained_by="seen"``; None: every point explains its pixels)."""
    if spacing <= 0 or not np.isfinite(spacing):
        raise DataError(f"point spacing must be positive, got {spacing}")
    fx = cameras.camera_of(view).focal[0]
    # Points projecting just outside the photo still cover its border pixels with their footprints: they are drawn
    # on a canvas padded by the largest footprint, then cropped (else the border reads as a hole).
    pr = _project(cameras, view, positions, int(options.max_radius_px))
    h, w = pr.h, pr.w
    radius = options.footprint * spacing * fx / pr.z
    from_points = _front_footprints(pr, np.asarray(needs_splats, dtype=bool)[pr.idx], radius, options)
    holes = np.zeros((h, w), dtype=bool)
    if options.holes and len(pr.idx):
        holes = _mvs_holes(cameras, view, positions, pr, radius, fx, options, seen, gsd)
    user = _user_pixels(user_mask, h, w)
    union = (from_points | holes | user).astype(np.uint8)
    mask, margin = _close_and_dilate(union, pr, spacing, fx, options)
    npx = float(h * w)
    return PhotoMask(
        view.name,
        mask,
        float(mask.sum() / npx),
        float(from_points.sum() / npx),
        float(holes.sum() / npx),
        float(user.sum() / npx),
        margin,
    )


def _front_footprints(pr: _Projected, bad: np.ndarray, radius: np.ndarray, options: MaskOptions) -> np.ndarray:
    """(H, W) bool footprints of the needs-splats points ``bad`` (M,) bool that no collaborative point hides: a
    z-buffer of the collaborative points (their nearest depth per pixel, spread over a 3×3 neighbourhood)."""
    good = ~bad
    zbuf = np.full((pr.h + 2 * pr.pad, pr.w + 2 * pr.pad), np.inf)
    ci, ri = (pr.col + pr.pad).astype(np.int64), (pr.row + pr.pad).astype(np.int64)
    np.minimum.at(zbuf, (ri[good], ci[good]), pr.z[good])
    zbuf = ndimage.minimum_filter(zbuf, size=3)
    front = bad & (pr.z <= zbuf[ri, ci] * (1.0 + options.occlusion_tolerance))
    return pr.draw(front, radius)


def _mvs_holes(
    cameras: Cameras,
    view: View,
    positions: np.ndarray,
    pr: _Projected,
    radius: np.ndarray,
    fx: float,
    options: MaskOptions,
    seen: SeenInView | None,
    gsd: float | None,
) -> np.ndarray:
    """(H, W) bool: pixels of the valid area that no (seen) point explains, without holes under ``min_hole_px``."""
    hole_radius = radius * (options.hole_footprint / options.footprint)
    if options.hole_gsd > 0:
        g = gsd if gsd is not None and gsd > 0 else float(np.median(pr.z)) / fx
        hole_radius = options.hole_gsd * g * fx / pr.z
    covered = pr.draw(np.ones(len(pr.idx), dtype=bool), hole_radius)
    area = _valid_area(cameras, view, positions, pr, covered, options, seen)
    if options.explained_by == "seen" and seen is not None:
        explained = seen.explains(view, pr.idx, pr.col, pr.row, (pr.w, pr.h), options.colour_tolerance)
        covered = pr.draw(explained, hole_radius)
    holes = area & ~covered
    if options.min_hole_px > 1 and holes.any():
        lab, n = ndimage.label(holes)
        sizes = np.bincount(lab.ravel(), minlength=n + 1)
        holes = holes & (sizes[lab] >= options.min_hole_px)
    return holes


def _valid_area(
    cameras: Cameras,
    view: View,
    positions: np.ndarray,
    pr: _Projected,
    covered: np.ndarray,
    options: MaskOptions,
    seen: SeenInView | None,
) -> np.ndarray:
    """(H, W) bool: where the scene is (``hole_area``), grown by GrabCut and less the backdrop at infinity."""
    h, w = pr.h, pr.w
    area = np.zeros((h, w), dtype=bool)
    below = np.zeros((h, w), dtype=bool)
    hull_area = np.zeros((h, w), dtype=bool)
    if options.hole_area in ("below", "hull_below"):
        up = np.asarray(options.up, dtype=np.float64)
        below = _below_envelope(cameras, view, positions[pr.idx], covered, up)
        area |= below
    if options.hole_area in ("hull", "hull_below") and len(pr.idx) >= options.min_points_hull:
        hull_img = np.zeros((h, w), dtype=np.uint8)
        hull = cv2.convexHull(np.c_[pr.col, pr.row].astype(np.float32))
        cv2.fillPoly(hull_img, [np.round(hull).astype(np.int32).reshape(-1, 2)], 1)
        hull_area = hull_img.astype(bool)
        area |= hull_area
    if options.hole_area == "enclosed":
        area = ndimage.binary_fill_holes(covered)
    photo = None if seen is None or seen.photo is None else seen.photo
    # Backdrop at infinity, outside what the cloud's points enclose (a blank wall inside the scene is kept).
    backdrop = np.zeros((h, w), dtype=bool)
    if options.infinity and photo is not None and (area & ~covered).any():
        depth = float(np.median(pr.z)) if len(pr.idx) else None
        backdrop = at_infinity(cameras, view, photo, finite_depth=depth) & ~ndimage.binary_fill_holes(covered)
    if options.grow_area > 0 and photo is not None:
        grown = _grow_area(
            np.asarray(photo(view.name)), covered, area, options.grow_area, options.grow_max_px, background=backdrop
        )
        if backdrop.any() and grown.any():
            # With a backdrop in view, the area below the cloud's envelope is only a guess outside its hull:
            # what GrabCut puts with the backdrop there is no hole.
            area &= ~(below & ~hull_area)
        area |= grown
    area &= ~backdrop
    return area


def _user_pixels(user_mask: np.ndarray | None, h: int, w: int) -> np.ndarray:
    """(h, w) bool: the user mask (any size, (H, W) or (H, W, C), non-zero = set) at the photo's size."""
    user = np.zeros((h, w), dtype=bool)
    if user_mask is not None:
        um = np.asarray(user_mask)
        if um.shape[:2] != (h, w):
            um = cv2.resize(um.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)
        user = (um[..., 0] if um.ndim == 3 else um) > 0
    return user


def _close_and_dilate(
    union: np.ndarray, pr: _Projected, spacing: float, fx: float, options: MaskOptions
) -> tuple[np.ndarray, int]:
    """The closed and dilated mask (H, W) bool of ``union`` (H, W) uint8, and the training margin in pixels (both
    radii from the point spacing at the view's median depth, capped at 4 × ``max_radius_px``)."""
    if options.close_px > 0:
        union = cv2.morphologyEx(union, cv2.MORPH_CLOSE, disk_kernel(options.close_px))
    dilate = options.dilate_px
    margin = 0
    if len(pr.idx):
        spacing_px = spacing * fx / float(np.median(pr.z))
        if options.dilate_spacings > 0:
            dilate = max(dilate, min(int(round(options.dilate_spacings * spacing_px)), 4 * options.max_radius_px))
        margin = min(int(round(options.train_margin_spacings * spacing_px)), 4 * options.max_radius_px)
    if dilate > 0:
        union = cv2.dilate(union, disk_kernel(dilate))
    return union.astype(bool), margin


def region_masks(
    cameras: Cameras,
    positions: np.ndarray,
    needs_splats: np.ndarray,
    spacing: float,
    options: MaskOptions = MaskOptions(),
    user_masks: dict[str, np.ndarray] | None = None,
    names: list[str] | None = None,
    seen: SeenInView | None = None,
    cloud_downscale: float = 1.0,
) -> list[PhotoMask]:
    """:func:`photo_mask` for every view of ``cameras`` (or those named in ``names``), in image-id order.

    seen: which points each photo sees (``explained_by="seen"``), see :class:`SeenInView`. cloud_downscale: how
    many times smaller than these cameras' images the cloud's depth maps were (the MVS image size, e.g. 3072 px
    photos reconstructed at 1000 px: 3.07). The hole radius is ``hole_gsd`` GSDs *of the cloud*: a cloud sampled
    from smaller images has coarser pixels, and a radius in the photos' GSD would leave gaps between its points
    that read as holes everywhere."""
    pts = np.asarray(positions, dtype=np.float64)
    flags = np.asarray(needs_splats, dtype=bool)
    if len(flags) != len(pts):
        raise DataError(f"{len(flags)} needs-splats flags for {len(pts)} points")
    if not (cloud_downscale >= 1.0 and np.isfinite(cloud_downscale)):
        raise DataError(f"cloud_downscale must be >= 1, got {cloud_downscale}")
    gsd = ground_sample_distance(cameras, pts, names) * cloud_downscale if options.hole_gsd > 0 else None
    out = []
    for view in cameras:
        if names is not None and view.name not in names:
            continue
        user = None if user_masks is None else user_masks.get(view.name)
        out.append(photo_mask(cameras, view, pts, flags, spacing, options, user, seen, gsd))
    return out
