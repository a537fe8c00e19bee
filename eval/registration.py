"""Optional fine registration before measuring: open3d point-to-plane ICP of the compared cloud onto the reference.

Off by default in the pipeline: a C2C after ICP hides a georeferencing error, so the applied transform and
its RMSE are always reported next to the distances. Both clouds are moved to one float64 local origin
before open3d sees them; the transform is returned in that local frame and in world coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import ConfigError, DataError
from core.pointcloud import PointCloud
from eval.c2c import common_origin


@dataclass(frozen=True)
class ICPResult:
    """ICP outcome.

    local_transform: (4, 4) float64, maps compared local positions (relative to ``origin``) onto the reference.
    world_transform: (4, 4) float64, the same map in world coordinates.
    origin: (3,) float64 world coordinates of the local frame.
    fitness: share of compared points with a correspondence within ``max_correspondence`` metres.
    inlier_rmse: RMSE (metres) of those correspondences after alignment.
    """

    local_transform: np.ndarray
    world_transform: np.ndarray
    origin: np.ndarray
    fitness: float
    inlier_rmse: float
    max_correspondence: float

    def as_dict(self) -> dict[str, object]:
        return {
            "method": "icp_point_to_plane",
            "local_transform": self.local_transform.tolist(),
            "world_transform": self.world_transform.tolist(),
            "origin": self.origin.tolist(),
            "fitness": self.fitness,
            "inlier_rmse": self.inlier_rmse,
            "max_correspondence": self.max_correspondence,
        }

    def apply(self, cloud: PointCloud) -> PointCloud:
        """``cloud`` moved by the transform (positions re-expressed in this result's origin)."""
        local = cloud.with_origin(self.origin)
        r, t = self.local_transform[:3, :3], self.local_transform[:3, 3]
        moved = local.positions @ r.T + t
        normals = None if local.normals is None else (local.normals.astype(np.float64) @ r.T).astype(np.float32)
        return PointCloud(moved, self.origin.copy(), local.colors, normals, dict(local.fields), local.visibility)


def icp_point_to_plane(
    compared: PointCloud,
    reference: PointCloud,
    max_correspondence: float,
    max_iterations: int = 50,
    voxel_size: float | None = None,
) -> ICPResult:
    """Point-to-plane ICP from the identity. ``max_correspondence`` and ``voxel_size`` (optional
    downsampling of both clouds before ICP) in metres; reference normals are estimated when absent."""
    import open3d as o3d

    if not (max_correspondence > 0):
        raise ConfigError(f"max_correspondence must be a positive distance in metres, got {max_correspondence}")
    if len(compared) < 3 or len(reference) < 3:
        raise DataError("ICP needs at least 3 points in each cloud")
    origin = common_origin(reference, compared)
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(compared.with_origin(origin).positions))
    dst = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(reference.with_origin(origin).positions))
    if reference.normals is not None:
        dst.normals = o3d.utility.Vector3dVector(reference.normals.astype(np.float64))
    if voxel_size:
        src, dst = src.voxel_down_sample(voxel_size), dst.voxel_down_sample(voxel_size)
    if not dst.has_normals():
        dst.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=3 * max_correspondence, max_nn=30))
    result = o3d.pipelines.registration.registration_icp(
        src,
        dst,
        max_correspondence,
        np.eye(4),
        o3d.pipelines.registration.TransformationEstimationPointToPlane(),
        o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=max_iterations),
    )
    local = np.asarray(result.transformation, dtype=np.float64)
    shift, unshift = np.eye(4), np.eye(4)
    shift[:3, 3], unshift[:3, 3] = -origin, origin
    world = unshift @ local @ shift
    return ICPResult(local, world, origin, float(result.fitness), float(result.inlier_rmse), float(max_correspondence))
