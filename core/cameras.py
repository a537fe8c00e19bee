"""Cameras in COLMAP's conventions.

- Intrinsics (:class:`Camera`) follow COLMAP's camera models and parameter order. Pixel coordinates are
  continuous with the centre of the top-left pixel at (0.5, 0.5), as in COLMAP.
- Poses (:class:`View`) are world-to-camera: ``x_cam = R(q) @ x_world + t`` with ``q = (w, x, y, z)``.
- Camera axes are OpenCV's: x right, y down, z forward (depth = z > 0 in front of the camera).

Projection, unprojection, distortion and undistortion are vectorised and accept numpy arrays or torch
tensors (the result has the type of the input). Use float64 where precision matters.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

import numpy as np

from core.errors import ConfigError, DataError

ArrayLike = Any  # numpy.ndarray or torch.Tensor


class CameraModel(str, Enum):
    """COLMAP camera models supported by the toolkit, with their parameter names in COLMAP's order."""

    SIMPLE_PINHOLE = "SIMPLE_PINHOLE"
    PINHOLE = "PINHOLE"
    SIMPLE_RADIAL = "SIMPLE_RADIAL"
    RADIAL = "RADIAL"
    OPENCV = "OPENCV"
    FULL_OPENCV = "FULL_OPENCV"

    @property
    def param_names(self) -> tuple[str, ...]:
        return _PARAM_NAMES[self]

    @property
    def has_distortion(self) -> bool:
        return self not in (CameraModel.SIMPLE_PINHOLE, CameraModel.PINHOLE)


_PARAM_NAMES: dict[CameraModel, tuple[str, ...]] = {
    CameraModel.SIMPLE_PINHOLE: ("f", "cx", "cy"),
    CameraModel.PINHOLE: ("fx", "fy", "cx", "cy"),
    CameraModel.SIMPLE_RADIAL: ("f", "cx", "cy", "k"),
    CameraModel.RADIAL: ("f", "cx", "cy", "k1", "k2"),
    CameraModel.OPENCV: ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    CameraModel.FULL_OPENCV: ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
}


def _is_torch(x: ArrayLike) -> bool:
    return type(x).__module__.startswith("torch")


def _stack(parts: list[ArrayLike], like: ArrayLike) -> ArrayLike:
    if _is_torch(like):
        import torch

        return torch.stack(parts, dim=-1)
    return np.stack(parts, axis=-1)


def _numel(x: ArrayLike) -> int:
    return int(x.numel()) if _is_torch(x) else int(np.size(x))


def _ones_like(x: ArrayLike) -> ArrayLike:
    if _is_torch(x):
        import torch

        return torch.ones_like(x)
    return np.ones_like(x)


@dataclass(frozen=True)
class Camera:
    """Intrinsics of one COLMAP camera.

    Attributes
    ----------
    model: COLMAP camera model.
    width, height: image size in pixels.
    params: float64 parameters in COLMAP's order (``model.param_names``); focal lengths and principal
        point in pixels, distortion coefficients unitless.
    camera_id: COLMAP camera id.
    """

    model: CameraModel
    width: int
    height: int
    params: np.ndarray
    camera_id: int = 1

    def __post_init__(self) -> None:
        model = CameraModel(self.model)
        object.__setattr__(self, "model", model)
        params = np.asarray(self.params, dtype=np.float64).reshape(-1)
        object.__setattr__(self, "params", params)
        if params.size != len(model.param_names):
            raise ConfigError(
                f"camera model {model.value} takes {len(model.param_names)} parameters "
                f"{model.param_names}, got {params.size}"
            )
        if not np.all(np.isfinite(params)):
            raise DataError(f"camera {self.camera_id}: parameters must be finite, got {params.tolist()}")
        if self.width <= 0 or self.height <= 0:
            raise ConfigError(f"camera {self.camera_id}: image size must be positive, got {self.width}x{self.height}")

    # -- intrinsics ---------------------------------------------------------------------------
    @classmethod
    def pinhole(cls, fx: float, fy: float, cx: float, cy: float, width: int, height: int, camera_id: int = 1) -> Camera:
        """A PINHOLE camera from focal lengths and principal point in pixels."""
        return cls(CameraModel.PINHOLE, width, height, np.array([fx, fy, cx, cy]), camera_id)

    @property
    def focal(self) -> tuple[float, float]:
        """(fx, fy) in pixels."""
        p = self.params
        if self.model in (CameraModel.PINHOLE, CameraModel.OPENCV, CameraModel.FULL_OPENCV):
            return float(p[0]), float(p[1])
        return float(p[0]), float(p[0])

    @property
    def principal_point(self) -> tuple[float, float]:
        """(cx, cy) in pixels, COLMAP convention (image centre = (width/2, height/2))."""
        p = self.params
        if self.model in (CameraModel.PINHOLE, CameraModel.OPENCV, CameraModel.FULL_OPENCV):
            return float(p[2]), float(p[3])
        return float(p[1]), float(p[2])

    @property
    def distortion(self) -> np.ndarray:
        """Distortion coefficients in COLMAP's order (empty for pinhole models)."""
        start = {
            CameraModel.SIMPLE_PINHOLE: 3,
            CameraModel.PINHOLE: 4,
            CameraModel.SIMPLE_RADIAL: 3,
            CameraModel.RADIAL: 3,
            CameraModel.OPENCV: 4,
            CameraModel.FULL_OPENCV: 4,
        }[self.model]
        return self.params[start:]

    def K(self) -> np.ndarray:
        """3×3 float64 intrinsic matrix (COLMAP pixel convention)."""
        fx, fy = self.focal
        cx, cy = self.principal_point
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    def as_pinhole(self) -> Camera:
        """The same focal lengths and principal point without distortion."""
        fx, fy = self.focal
        cx, cy = self.principal_point
        return Camera.pinhole(fx, fy, cx, cy, self.width, self.height, self.camera_id)

    def scaled(self, factor: float) -> Camera:
        """The camera for an image resized by ``factor`` (e.g. 0.5 halves width and height)."""
        width = max(1, round(self.width * factor))
        height = max(1, round(self.height * factor))
        sx, sy = width / self.width, height / self.height
        p = self.params.copy()
        if self.model in (CameraModel.PINHOLE, CameraModel.OPENCV, CameraModel.FULL_OPENCV):
            p[[0, 2]] *= sx
            p[[1, 3]] *= sy
        else:
            p[0] *= (sx + sy) / 2
            p[1] *= sx
            p[2] *= sy
        return Camera(self.model, width, height, p, self.camera_id)

    # -- distortion in normalised image coordinates -------------------------------------------
    def distort(self, uv: ArrayLike) -> ArrayLike:
        """Apply lens distortion to normalised coordinates ``uv = (x/z, y/z)``, shape (..., 2)."""
        if not self.model.has_distortion:
            return uv
        u, v = uv[..., 0], uv[..., 1]
        du, dv = self._distortion_delta(u, v)
        return _stack([u + du, v + dv], uv)

    def _distortion_delta(self, u: ArrayLike, v: ArrayLike) -> tuple[ArrayLike, ArrayLike]:
        d = self.distortion
        u2, v2, uv = u * u, v * v, u * v
        r2 = u2 + v2
        if self.model is CameraModel.SIMPLE_RADIAL:
            radial = d[0] * r2
            return u * radial, v * radial
        if self.model is CameraModel.RADIAL:
            radial = d[0] * r2 + d[1] * r2 * r2
            return u * radial, v * radial
        if self.model is CameraModel.OPENCV:
            k1, k2, p1, p2 = d
            radial = k1 * r2 + k2 * r2 * r2
            return (
                u * radial + 2 * p1 * uv + p2 * (r2 + 2 * u2),
                v * radial + 2 * p2 * uv + p1 * (r2 + 2 * v2),
            )
        if self.model is CameraModel.FULL_OPENCV:
            k1, k2, p1, p2, k3, k4, k5, k6 = d
            r4 = r2 * r2
            r6 = r4 * r2
            radial = (1 + k1 * r2 + k2 * r4 + k3 * r6) / (1 + k4 * r2 + k5 * r4 + k6 * r6)
            return (
                u * radial + 2 * p1 * uv + p2 * (r2 + 2 * u2) - u,
                v * radial + 2 * p2 * uv + p1 * (r2 + 2 * v2) - v,
            )
        return u * 0, v * 0

    def undistort(self, uv_distorted: ArrayLike, iterations: int = 100, tol: float = 1e-14) -> ArrayLike:
        """Invert :meth:`distort` by Newton iterations (numerical Jacobian, as COLMAP does), shape (..., 2).

        Converges to ~1e-12 for the distortion magnitudes of real lenses; points far outside the
        valid field of a strongly distorted lens may not converge and are returned at the last iterate.
        """
        if not self.model.has_distortion:
            return uv_distorted
        target_u, target_v = uv_distorted[..., 0], uv_distorted[..., 1]
        u, v = target_u * 1, target_v * 1
        eps = 1e-9
        for _ in range(iterations):
            du, dv = self._distortion_delta(u, v)
            ru, rv = u + du - target_u, v + dv - target_v
            du_u, dv_u = self._distortion_delta(u + eps, v)
            du_v, dv_v = self._distortion_delta(u, v + eps)
            j00 = 1 + (du_u - du) / eps
            j10 = (dv_u - dv) / eps
            j01 = (du_v - du) / eps
            j11 = 1 + (dv_v - dv) / eps
            det = j00 * j11 - j01 * j10
            step_u = (j11 * ru - j01 * rv) / det
            step_v = (-j10 * ru + j00 * rv) / det
            u, v = u - step_u, v - step_v
            step = abs(step_u) + abs(step_v)
            if _numel(step) == 0 or float(step.max()) < tol:
                break
        return _stack([u, v], uv_distorted)

    # -- pixels ---------------------------------------------------------------------------------
    def project(self, points_cam: ArrayLike) -> ArrayLike:
        """Project camera-frame points (..., 3) to pixels (..., 2); points need z > 0 to be meaningful."""
        z = points_cam[..., 2]
        uv = _stack([points_cam[..., 0] / z, points_cam[..., 1] / z], points_cam)
        return self.normalized_to_pixels(self.distort(uv))

    def normalized_to_pixels(self, uv: ArrayLike) -> ArrayLike:
        """Map normalised (distorted) coordinates (..., 2) to pixels with the focal lengths and principal point."""
        fx, fy = self.focal
        cx, cy = self.principal_point
        return _stack([uv[..., 0] * fx + cx, uv[..., 1] * fy + cy], uv)

    def pixels_to_normalized(self, pixels: ArrayLike) -> ArrayLike:
        """Inverse of :meth:`normalized_to_pixels` (no undistortion)."""
        fx, fy = self.focal
        cx, cy = self.principal_point
        return _stack([(pixels[..., 0] - cx) / fx, (pixels[..., 1] - cy) / fy], pixels)

    def unproject(self, pixels: ArrayLike, depth: ArrayLike | float = 1.0) -> ArrayLike:
        """Camera-frame points (..., 3) at z-depth ``depth`` (along the optical axis) seen at ``pixels`` (..., 2).

        With ``depth = 1`` the result is the ray direction with unit z.
        """
        uv = self.undistort(self.pixels_to_normalized(pixels))
        ones = _ones_like(uv[..., 0])
        return _stack([uv[..., 0], uv[..., 1], ones], uv) * (depth if np.isscalar(depth) else depth[..., None])

    def undistort_pixels(self, pixels: ArrayLike, target: Camera | None = None) -> ArrayLike:
        """Pixels of the distorted image mapped to the pixels of ``target`` (default: :meth:`as_pinhole`)."""
        target = target or self.as_pinhole()
        return target.normalized_to_pixels(self.undistort(self.pixels_to_normalized(pixels)))

    def distort_pixels(self, pixels: ArrayLike, source: Camera | None = None) -> ArrayLike:
        """Pixels of an undistorted image (camera ``source``, default :meth:`as_pinhole`) mapped into this camera."""
        source = source or self.as_pinhole()
        return self.normalized_to_pixels(self.distort(source.pixels_to_normalized(pixels)))


def quat_to_rotmat(q: ArrayLike) -> ArrayLike:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) in (w, x, y, z) order; normalised first."""
    if _is_torch(q):
        import torch

        q = q / torch.linalg.norm(q, dim=-1, keepdim=True)
    else:
        q = np.asarray(q, dtype=np.float64)
        q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]  # fmt: skip
    flat = _stack(rows, q)
    return flat.reshape(*flat.shape[:-1], 3, 3)


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """Quaternion (w, x, y, z), w ≥ 0, from a rotation matrix (3, 3) or (N, 3, 3), float64."""
    from scipy.spatial.transform import Rotation

    xyzw = Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_quat()
    wxyz = np.concatenate([xyzw[..., 3:], xyzw[..., :3]], axis=-1)
    return np.where(wxyz[..., :1] < 0, -wxyz, wxyz)


@dataclass(frozen=True)
class View:
    """One registered image: its name, its camera and its world-to-camera pose.

    ``x_cam = R(quat_wxyz) @ x_world + translation`` (COLMAP's ``cam_from_world``), metres.
    """

    image_id: int
    name: str
    camera_id: int
    quat_wxyz: np.ndarray
    translation: np.ndarray

    def __post_init__(self) -> None:
        q = np.asarray(self.quat_wxyz, dtype=np.float64).reshape(4)
        t = np.asarray(self.translation, dtype=np.float64).reshape(3)
        norm = np.linalg.norm(q)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t)) and norm > 0):
            raise DataError(f"image {self.name!r}: pose must be finite with a non-zero quaternion")
        object.__setattr__(self, "quat_wxyz", q / norm)
        object.__setattr__(self, "translation", t)

    @classmethod
    def from_matrix(cls, image_id: int, name: str, camera_id: int, cam_from_world: np.ndarray) -> View:
        """A view from a 3×4 (or 4×4) world-to-camera matrix."""
        m = np.asarray(cam_from_world, dtype=np.float64)
        return cls(image_id, name, camera_id, rotmat_to_quat(m[:3, :3]), m[:3, 3])

    @property
    def rotation(self) -> np.ndarray:
        """World-to-camera rotation matrix (3, 3), float64."""
        return quat_to_rotmat(self.quat_wxyz)

    @property
    def cam_from_world(self) -> np.ndarray:
        """3×4 world-to-camera matrix [R | t], float64."""
        return np.concatenate([self.rotation, self.translation[:, None]], axis=1)

    @property
    def viewmat(self) -> np.ndarray:
        """4×4 world-to-camera matrix, float64 (gsplat's ``viewmats``)."""
        m = np.eye(4)
        m[:3] = self.cam_from_world
        return m

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, ``-Rᵀ t``, float64 (3,)."""
        return -self.rotation.T @ self.translation

    def world_to_camera(self, points: ArrayLike) -> ArrayLike:
        """World points (..., 3) to the camera frame."""
        R, t = self.rotation, self.translation
        if _is_torch(points):
            import torch

            R = torch.as_tensor(R, dtype=points.dtype, device=points.device)
            t = torch.as_tensor(t, dtype=points.dtype, device=points.device)
        return points @ R.T + t

    def camera_to_world(self, points: ArrayLike) -> ArrayLike:
        """Camera-frame points (..., 3) to world coordinates."""
        R, t = self.rotation, self.translation
        if _is_torch(points):
            import torch

            R = torch.as_tensor(R, dtype=points.dtype, device=points.device)
            t = torch.as_tensor(t, dtype=points.dtype, device=points.device)
        return (points - t) @ R


@dataclass
class Cameras:
    """A set of intrinsics and posed views: a COLMAP sparse model without its 3D points.

    ``origin`` (float64, metres) is the local origin of the model's frame: world coordinates of a
    point are ``origin + local``; poses act on local coordinates.
    """

    cameras: dict[int, Camera] = field(default_factory=dict)
    views: dict[int, View] = field(default_factory=dict)
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        for view in self.views.values():
            if view.camera_id not in self.cameras:
                raise DataError(f"image {view.name!r} refers to camera {view.camera_id}, which does not exist")

    def __len__(self) -> int:
        return len(self.views)

    def __iter__(self) -> Iterator[View]:
        return iter(self.views[i] for i in sorted(self.views))

    def camera_of(self, view: View | int) -> Camera:
        """Intrinsics of a view (given as a :class:`View` or an image id)."""
        view = self.views[view] if isinstance(view, int) else view
        return self.cameras[view.camera_id]

    def by_name(self, name: str) -> View:
        """The view with image name ``name``."""
        for view in self.views.values():
            if view.name == name:
                return view
        raise KeyError(name)

    def project(self, view: View | int, points_local: ArrayLike) -> tuple[ArrayLike, ArrayLike]:
        """Pixels (..., 2) and z-depths (...) of local-frame points (..., 3) in a view."""
        view = self.views[view] if isinstance(view, int) else view
        cam_pts = view.world_to_camera(points_local)
        return self.camera_of(view).project(cam_pts), cam_pts[..., 2]

    def unproject(self, view: View | int, pixels: ArrayLike, depth: ArrayLike | float) -> ArrayLike:
        """Local-frame points (..., 3) seen at ``pixels`` with z-depth ``depth`` in a view."""
        view = self.views[view] if isinstance(view, int) else view
        return view.camera_to_world(self.camera_of(view).unproject(pixels, depth))
