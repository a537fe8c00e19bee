"""Training labels per point: from a data_synth scene's truth, a labelled scalar field (PLY/LAS), or 2D masks.

Every source returns class codes (N,) uint8 of a :class:`classify.classes.ClassSet`, with
:data:`classify.classes.UNLABELLED` (255) for points without a label (ignored in training).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from classify.classes import UNLABELLED, ClassSet
from core.cameras import Cameras
from core.errors import ConfigError, DataError
from core.pointcloud import PointCloud


# -- data_synth truth -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PointTruth:
    """Truth of each fused point of a synthetic scene.

    codes: (N,) uint8 class codes. needs_splats: (N,) bool, the binary truth. material: (N,) int32 material id of
    the nearest GT surface (−1 if none). distance: (N,) float64 metres to the nearest GT surface. far: (N,) bool,
    farther than τ from every surface. tau: the threshold (metres). ambiguous: (N,) bool, within τ of both a
    collaborative and a non-collaborative GT surface: at the cloud's resolution such a point belongs to either, so
    scores leave it out (the ignore band, as boundary-tolerant segmentation benchmarks do; issue 30).
    """

    codes: np.ndarray
    needs_splats: np.ndarray
    material: np.ndarray
    distance: np.ndarray
    far: np.ndarray
    tau: float
    ambiguous: np.ndarray

    @property
    def scored(self) -> np.ndarray:
        """(N,) bool: the points a band-ignored score counts (not :attr:`ambiguous`)."""
        return ~self.ambiguous


def _closest(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (N,) float64 and nearest face index (N,) int64 of points to a triangle mesh (open3d, float32 inside:
    callers pass coordinates near the origin)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),
        o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.uint32)),
    )
    ans = scene.compute_closest_points(o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32)))
    closest = ans["points"].numpy().astype(np.float64)
    return np.linalg.norm(closest - points, axis=1), ans["primitive_ids"].numpy().astype(np.int64)


def point_truth(
    positions: np.ndarray,
    mesh_vertices: np.ndarray,
    mesh_faces: np.ndarray,
    face_material: np.ndarray,
    material_kind: dict[int, str],
    classes: ClassSet,
    tau: float,
) -> PointTruth:
    """The issue's truth per fused point (positions (N, 3) float64, the mesh's local frame).

    A point's label is the class of the material of its nearest GT surface when that surface is within ``tau``
    metres. A point farther than ``tau`` from every surface (virtual points behind mirrors, points refracted
    through glass, noise) truly needs splats; its class is that of the nearest *non-collaborative* surface (the
    surface that caused it), or the first needs-splats class when the scene has none.
    """
    if not (tau > 0 and np.isfinite(tau)):
        raise ConfigError(f"tau must be a positive distance in metres, got {tau}")
    pts = np.asarray(positions, dtype=np.float64)
    centre = mesh_vertices.mean(axis=0)
    dist, face = _closest(mesh_vertices - centre, mesh_faces, pts - centre)
    material = np.asarray(face_material, dtype=np.int32)[face]
    code_of_material = {m: classes.code_of_kind(kind) for m, kind in material_kind.items()}
    lut = np.full(int(max(code_of_material, default=0)) + 1, UNLABELLED, dtype=np.uint8)
    for m, code in code_of_material.items():
        lut[m] = code
    codes = lut[material]
    far = dist > tau
    face_codes = lut[np.asarray(face_material)]
    labelled = face_codes != UNLABELLED
    bad_faces = np.flatnonzero(labelled & classes.needs_splats_of(face_codes))
    good_faces = np.flatnonzero(labelled & ~classes.needs_splats_of(face_codes))
    if far.any():
        if len(bad_faces):
            _, f2 = _closest(mesh_vertices - centre, mesh_faces[bad_faces], pts[far] - centre)
            codes[far] = lut[np.asarray(face_material)[bad_faces[f2]]]
        else:
            codes[far] = next(c.code for c in classes.classes if c.needs_splats)
    needs = classes.needs_splats_of(codes) | far
    ambiguous = np.zeros(len(pts), dtype=bool)
    near = ~far
    if len(bad_faces) and len(good_faces) and near.any():
        # The nearest surface is of one kind; the point is ambiguous when a surface of the other kind is within τ too.
        other = np.where(needs[near], 1, 0)
        idx = np.flatnonzero(near)
        for kind_faces, of_other in ((good_faces, other == 1), (bad_faces, other == 0)):
            sel = idx[of_other]
            if len(sel):
                d_other, _ = _closest(mesh_vertices - centre, mesh_faces[kind_faces], pts[sel] - centre)
                ambiguous[sel] = d_other <= tau
    return PointTruth(codes, needs, material, dist, far, float(tau), ambiguous)


def scene_point_truth(cloud: PointCloud, scene: object, classes: ClassSet, tau_gsd: float = 3.0) -> PointTruth:
    """:func:`point_truth` for a :class:`data_synth.Scene`, with τ = ``tau_gsd`` × the scene's GSD."""
    mesh = scene.mesh  # type: ignore[attr-defined]
    kinds = {m.id: m.kind for m in scene.materials}  # type: ignore[attr-defined]
    pts = cloud.with_origin(np.asarray(scene.origin)).positions  # type: ignore[attr-defined]
    return point_truth(
        pts,
        mesh.vertices,
        mesh.faces,
        mesh.face_material,
        kinds,
        classes,
        tau_gsd * float(scene.gsd_m),  # type: ignore[attr-defined]
    )


# -- scalar fields (CloudCompare / LAS) -------------------------------------------------------------------------
def labels_from_field(values: np.ndarray, classes: ClassSet, las_codes: bool = True) -> np.ndarray:
    """Class codes (N,) uint8 from a labelled scalar field.

    las_codes: True reads the values as LAS classification codes (mapped through each class's ``las_codes``);
    False reads them as the project's class codes. Values that map to no class → UNLABELLED.
    """
    v = np.asarray(values)
    if v.ndim != 1:
        raise DataError(f"a label field must be one value per point, got shape {v.shape}")
    if not np.all(np.isfinite(v.astype(np.float64))):
        raise DataError("the label field contains NaN or infinite values")
    iv = np.round(v.astype(np.float64)).astype(np.int64)
    if las_codes:
        return classes.code_of_las(iv)
    known = np.isin(iv, classes.codes.astype(np.int64))
    return np.where(known, iv, UNLABELLED).astype(np.uint8)


def transfer_labels(
    source_positions: np.ndarray, source_codes: np.ndarray, target_positions: np.ndarray, max_distance: float
) -> np.ndarray:
    """Codes (M,) uint8 of each target point's nearest labelled source point within ``max_distance`` metres
    (UNLABELLED beyond). Both position arrays (·, 3) float64 in one frame."""
    src = np.asarray(source_positions, dtype=np.float64)
    codes = np.asarray(source_codes, dtype=np.uint8)
    keep = codes != UNLABELLED
    out = np.full(len(target_positions), UNLABELLED, dtype=np.uint8)
    if not keep.any():
        return out
    tgt = np.asarray(target_positions, dtype=np.float64)
    d, i = cKDTree(src[keep]).query(tgt, k=1, distance_upper_bound=max_distance)
    hit = np.isfinite(d)
    out[hit] = codes[keep][i[hit]]
    return out


# -- 2D label masks ---------------------------------------------------------------------------------------------
def labels_from_masks(
    positions: np.ndarray,
    cameras: Cameras,
    masks: dict[str, np.ndarray],
    visibility: list[np.ndarray] | None = None,
    min_votes: int = 1,
) -> np.ndarray:
    """Class codes (N,) uint8 from per-photo label images, by majority vote over the views.

    masks: image name → (H, W) uint8 class codes (255 = unlabelled), at the camera's resolution (other sizes are
    sampled proportionally). A point votes in a view where it projects inside the image and, when ``visibility``
    (image ids per point) is given, only in the views that saw it. Ties go to the lowest code; points with fewer
    than ``min_votes`` votes stay UNLABELLED.
    """
    pts = np.asarray(positions, dtype=np.float64)
    n = len(pts)
    pairs: list[np.ndarray] = []  # point index * 256 + label, one entry per vote
    seen: dict[int, np.ndarray] = {}
    if visibility is not None:
        if len(visibility) != n:
            raise DataError(f"visibility lists {len(visibility)} points, the cloud has {n}")
        counts = np.fromiter((len(v) for v in visibility), dtype=np.int64, count=n)
        flat = np.concatenate(visibility) if counts.sum() else np.zeros(0, np.int64)
        owner = np.repeat(np.arange(n), counts)
        for view in cameras:
            seen[view.image_id] = np.unique(owner[flat == view.image_id])
    for view in cameras:
        if view.name not in masks:
            continue
        mask = np.asarray(masks[view.name])
        cam = cameras.camera_of(view)
        idx = seen[view.image_id] if visibility is not None else np.arange(n)
        uv, z = cameras.project(view, pts[idx])
        inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] < cam.height)
        idx, uv = idx[inside], uv[inside]
        col = np.clip((uv[:, 0] * mask.shape[1] / cam.width).astype(np.int64), 0, mask.shape[1] - 1)
        row = np.clip((uv[:, 1] * mask.shape[0] / cam.height).astype(np.int64), 0, mask.shape[0] - 1)
        lab = mask[row, col].astype(np.int64)
        ok = lab != UNLABELLED
        pairs.append(idx[ok] * 256 + lab[ok])
    out = np.full(n, UNLABELLED, dtype=np.uint8)
    if not pairs or not sum(len(p) for p in pairs):
        return out
    keys, counts = np.unique(np.concatenate(pairs), return_counts=True)
    point, label = keys // 256, keys % 256
    # Per point, the label with most votes; lexsort puts ties at the lowest label last-to-first.
    order = np.lexsort((-label, counts, point))
    last = np.r_[point[order][1:] != point[order][:-1], True]
    win = order[last]
    ok = counts[win] >= max(1, min_votes)
    out[point[win][ok]] = label[win][ok].astype(np.uint8)
    return out
