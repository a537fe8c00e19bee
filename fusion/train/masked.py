"""Masked training as the pipeline runs it: splats seeded and trained only inside region masks, next to the
trusted MVS Gaussians frozen as context (the ``train`` stage), and plain whole-scene 3DGS from SfM points (the
``baseline`` stage). Both are functions of arrays and Gaussian sets; the stages read and write the files.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from core.errors import ConfigError
from fusion.train.options import InitOptions, TrainOptions

if TYPE_CHECKING:
    from core.cameras import Cameras
    from core.gaussians import GaussianSet

#: fields of TrainOptions that these functions set themselves (the seed; the snapshot steps are their own option)
_SET_HERE = ("seed", "snapshot_iterations")


@dataclass(frozen=True)
class MaskedTrainingOptions:
    """Options of :func:`train_in_masks` (the pipeline's ``train`` stage).

    training: the trainer's options (:class:`fusion.train.TrainOptions`, ``[train.training]``); its ``downscale`` is
        a lower bound (see ``max_image_size``) and its strategy's ``cap`` a hard budget (see
        ``splats_per_mask_pixel``). init: how splats are seeded (:class:`fusion.train.init.InitOptions`).
    max_image_size: the training downscale is raised until the longer side of every photo is at most this many
        pixels (CPU-sized; 0 = no limit). splats_per_mask_pixel: the Gaussian budget is also at most this × the
        mask pixels of all training photos at the training resolution (at least 1000), so that small regions get
        small budgets. snapshot_iterations: steps after which the splats are kept (splats/snapshots/, for meshing).
    """

    training: TrainOptions = field(default_factory=TrainOptions, metadata={"runtime": _SET_HERE})
    init: InitOptions = field(default_factory=InitOptions, metadata={"runtime": ("seed",)})
    max_image_size: int = 640
    splats_per_mask_pixel: float = 0.25
    snapshot_iterations: tuple[int, ...] = (500, 1000, 1500)

    def __post_init__(self) -> None:
        if self.max_image_size < 0:
            raise ConfigError(f"max_image_size must be >= 0 (0: no limit), got {self.max_image_size}")
        if not self.splats_per_mask_pixel > 0:
            raise ConfigError(f"splats_per_mask_pixel must be > 0, got {self.splats_per_mask_pixel}")


@dataclass(frozen=True)
class WholeSceneOptions:
    """Options of :func:`train_whole_scene` (the pipeline's ``baseline`` stage): plain 3DGS, mask = whole image,
    no frozen context, one initial Gaussian per SfM point.

    enabled: train the baseline at all (off by default: it costs a whole-scene training; a comparison needs it).
    training: the trainer's options (``[baseline.training]``); the baseline's budget is 2000 steps, twice the
        hybrid's: the whole scene has more to learn than its masks. max_image_size: as for masked training, so that
        both train at the same resolution. checkpoints: steps (< iterations) after which the splats are also kept,
        points of one run's time-against-error curve (a checkpoint is the state of the longer run at that step,
        learning rates and densification scheduled for ``iterations`` steps).
    """

    enabled: bool = False
    training: TrainOptions = field(
        default_factory=lambda: TrainOptions(iterations=2000), metadata={"runtime": _SET_HERE}
    )
    max_image_size: int = 640
    checkpoints: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if self.max_image_size < 0:
            raise ConfigError(f"max_image_size must be >= 0 (0: no limit), got {self.max_image_size}")
        if any(not 1 <= int(s) < self.training.iterations for s in self.checkpoints):
            raise ConfigError(f"baseline: checkpoints must be steps from 1 to iterations - 1 "
                              f"({self.training.iterations - 1}), got {list(self.checkpoints)}")  # fmt: skip


def training_downscale(cameras: Cameras, downscale: int, max_image_size: int) -> int:
    """The integer photo downscale for training: at least ``downscale``, and enough that the longer side of every
    camera is at most ``max_image_size`` pixels (0 = no limit)."""
    longest = max(max(cameras.camera_of(v).width, cameras.camera_of(v).height) for v in cameras)
    return max(downscale, -(-longest // max_image_size) if max_image_size else 1)


def train_in_masks(
    cameras: Cameras,
    images: Mapping[str, np.ndarray],
    masks: Mapping[str, np.ndarray],
    mvs: GaussianSet,
    needs: np.ndarray,
    sfm_points: tuple[np.ndarray, np.ndarray] | None,
    options: MaskedTrainingOptions,
    seed: int,
    progress: Callable[[Any], None] | None = None,
    neighbours: GaussianSet | None = None,
) -> tuple[Any, Any, dict[str, Any]]:
    """Seed splats inside ``masks`` (training masks by image name, bool) and train them with the MVS Gaussians that
    need no splats (``needs`` (N,) bool per MVS Gaussian) frozen as context; ``neighbours`` (a tiled run's
    neighbouring tiles' splats in this tile's overlap) are frozen beside them.

    sfm_points: SfM points (M, 3) in the cameras' local frame and their colours, or None. Returns the trainer's
    result (:class:`fusion.train.TrainResult`), the seeds (:class:`fusion.train.init.Seeds`) and
    ``{"downscale", "cap"}``, the resolution and budget used."""
    from fusion.train.init import seed_splats
    from fusion.train.trainer import train_splats

    sfm_local, sfm_colors = sfm_points if sfm_points is not None else (None, None)
    seeds = seed_splats(cameras, masks, images, mvs.means, np.clip(mvs.base_colors * 255, 0, 255), needs,
                        sfm_local, sfm_colors, replace(options.init, seed=seed))  # fmt: skip
    training = options.training
    downscale = training_downscale(cameras, training.downscale, options.max_image_size)
    mask_pixels = sum(int(m.sum()) for m in masks.values()) / downscale**2
    cap = min(training.strategy.cap, max(1000, round(options.splats_per_mask_pixel * mask_pixels)))
    train_opts = replace(training, downscale=downscale, seed=seed, snapshot_iterations=options.snapshot_iterations,
                         strategy=replace(training.strategy, cap=cap))  # fmt: skip
    context = mvs.subset(~needs)
    if neighbours is not None and len(neighbours):
        from core.gaussians import GaussianSet

        context = GaussianSet.concatenate([context, neighbours])
    result = train_splats(cameras, images, masks, seeds.gaussians, context, train_opts, progress)
    return result, seeds, {"downscale": downscale, "cap": cap}


def train_whole_scene(
    cameras: Cameras,
    images: Mapping[str, np.ndarray],
    sfm_points: tuple[np.ndarray, np.ndarray | None],
    options: WholeSceneOptions,
    seed: int,
    progress: Callable[[Any], None] | None = None,
) -> tuple[Any, int]:
    """Plain whole-scene 3DGS from the SfM points ((M, 3) in the cameras' local frame, colours or None). Returns the
    trainer's result and the downscale used."""
    from fusion.train.init import sfm_seeds
    from fusion.train.trainer import train_splats

    init = sfm_seeds(sfm_points[0], sfm_points[1], cameras.origin)
    downscale = training_downscale(cameras, options.training.downscale, options.max_image_size)
    train_opts = replace(options.training, downscale=downscale, seed=seed,
                         snapshot_iterations=tuple(int(s) for s in options.checkpoints))  # fmt: skip
    return train_splats(cameras, images, None, init, None, train_opts, progress), downscale
