"""Shared data types and file formats: cameras, point clouds, Gaussian sets, errors.

Conventions (see docs/conventions.md): metres; COLMAP cameras (world-to-camera rotation as a
quaternion w, x, y, z and a translation; OpenCV axes x right, y down, z forward; pixel centres at
+0.5); float64 positions relative to a float64 local origin; Gaussians stored pre-activation.
"""

from core.cameras import Camera, CameraModel, Cameras, View
from core.errors import (
    ConfigError,
    DataError,
    FormatError,
    HybridSplatError,
    InputFileError,
    ReconstructionError,
)
from core.gaussians import SH_C0, GaussianSet
from core.pointcloud import PointCloud

__all__ = [
    "SH_C0",
    "Camera",
    "CameraModel",
    "Cameras",
    "ConfigError",
    "DataError",
    "FormatError",
    "GaussianSet",
    "HybridSplatError",
    "InputFileError",
    "PointCloud",
    "ReconstructionError",
    "View",
]
