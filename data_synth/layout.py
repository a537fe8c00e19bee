"""Paths of a synthetic scene folder (a contract with the other packages and with users)::

    SCENE/
      images/<name>.png              training photos, 8-bit sRGB
      test/<name>.png                held-out photos (never in sparse/0)
      sparse/0/                      COLMAP binary model of the true training cameras (no points)
      sparse/test/                   COLMAP binary model of the test cameras
      gt/mesh.ply                    float64 vertices (local frame) + face int ``material``
      gt/lidar.ply, gt/lidar.las     simulated LiDAR, field ``material`` (+ LAS classification)
      gt/depth/<split>/<name>.npy    float32 z-depth (metres), 0 where no surface
      gt/labels/<split>/<name>.png   uint8 material id per pixel, 255 = background
      scene.json                     legend, origin, GSD, rig, statistics, view lists (+ targets, when laid)
      control/gcp.csv                the coded targets' exact centres (world, metres), control or check (when laid)

``split`` is ``train`` or ``test``; ``<name>`` is the image file name (``train_000.png``) without ``.png`` for
depth files (``train_000.npy``) and with the same name for labels.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

SPLITS = ("train", "test")


@dataclass(frozen=True)
class SceneLayout:
    """All paths of a scene folder rooted at ``root``."""

    root: Path

    @property
    def images_dir(self) -> Path:
        return self.root / "images"

    @property
    def test_dir(self) -> Path:
        return self.root / "test"

    @property
    def sparse_train(self) -> Path:
        return self.root / "sparse" / "0"

    @property
    def sparse_test(self) -> Path:
        return self.root / "sparse" / "test"

    @property
    def gt_dir(self) -> Path:
        return self.root / "gt"

    @property
    def mesh(self) -> Path:
        return self.gt_dir / "mesh.ply"

    @property
    def lidar_ply(self) -> Path:
        return self.gt_dir / "lidar.ply"

    @property
    def lidar_las(self) -> Path:
        return self.gt_dir / "lidar.las"

    @property
    def scene_json(self) -> Path:
        return self.root / "scene.json"

    @property
    def gcp_csv(self) -> Path:
        """The targets' control file (:mod:`core.io.control` format), present when the scene has targets."""
        return self.root / "control" / "gcp.csv"

    def image(self, split: str, name: str) -> Path:
        """Photo of image ``name`` (e.g. ``train_000.png``) in ``split``."""
        return (self.images_dir if split == "train" else self.test_dir) / name

    def depth(self, split: str, name: str) -> Path:
        return self.gt_dir / "depth" / split / (Path(name).stem + ".npy")

    def labels(self, split: str, name: str) -> Path:
        return self.gt_dir / "labels" / split / (Path(name).stem + ".png")
