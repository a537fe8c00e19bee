"""The options classes converted to declared constraints (core.constraints) keep what they accepted and refused.

Each row is a value on one side of a bound that the hand-written check before the conversion drew (the tables are
the old checks' truth, written out by hand): a refused value must raise the one message naming that option, an
accepted one must build. Rules across fields stay hand-written and are tested with their classes."""

from __future__ import annotations

import math
import re

import pytest

from classify.features.geometric import GeometricOptions
from classify.mask_options import ExplainedBy, HoleArea, MaskOptions
from classify.model import ForestOptions
from classify.options import ClassifyOptions
from classify.stream import ClassifyStreamOptions
from core.constraints import Constrained, ConstraintError
from core.errors import ConfigError
from fusion.appearance import AppearanceOptions
from fusion.background import BackgroundOptions
from fusion.clean_options import CleanOptions, SurveyPointOptions
from fusion.convert_options import ConvertOptions
from fusion.export import ExportOptions
from fusion.merge_options import MergeOptions
from fusion.mesh.options import (
    DecimateOptions,
    MeshOptions,
    OrientedPointOptions,
    PoissonOptions,
    SnapshotOptions,
)
from fusion.mesh.tsdf import TSDFOptions
from fusion.tiles3d import TilesetOptions
from hybridsplat.config import InputOptions
from hybridsplat.stages.mesh import MeshStageOptions
from recon.mvs import MvsOptions
from recon.mvs_cpu_options import CpuMvsOptions
from recon.sfm import SfmOptions
from recon.tiling import TileOptions

NAN, INF = math.nan, math.inf

#: (class, required keyword arguments) of the classes below that have fields without defaults
REQUIRED: dict[type, dict] = {
    ClassifyStreamOptions: {"memory_limit_mb": 1024.0},
    ExportOptions: {"crop_min": (0.0, 0.0, 0.0), "crop_max": (1.0, 1.0, 1.0)},  # the crop_* rows replace one
}

REFUSED = [
    (MaskOptions, "footprint", [0.0, -1.0, NAN]),
    (MaskOptions, "max_radius_px", [0, -3]),
    (MaskOptions, "close_px", [-1]),
    (MaskOptions, "dilate_px", [-1]),
    (MaskOptions, "hole_gsd", [-0.5, NAN, INF]),
    (MaskOptions, "grow_area", [-1]),
    (MaskOptions, "grow_max_px", [15, 0]),
    (MaskOptions, "dilate_spacings", [-1.0, NAN, INF]),
    (MaskOptions, "train_margin_spacings", [-1e-9, NAN, INF]),
    (MaskOptions, "hole_area", ["region", "", None]),
    (MaskOptions, "explained_by", ["some"]),
    (GeometricOptions, "search", ["octree"]),
    (GeometricOptions, "backend", ["torch"]),
    (GeometricOptions, "k", [2, 0]),
    (GeometricOptions, "voxel_factors", [(), (1.0, 0.0), (1.0, NAN), (INF,), (-1.0,)]),
    (GeometricOptions, "chunk_size", [0, -5]),
    (ForestOptions, "smooth_passes", [-1]),
    (ForestOptions, "folds", [1, 0]),
    (ForestOptions, "n_estimators", [0]),
    (ForestOptions, "min_samples_leaf", [0]),
    (ForestOptions, "max_samples_per_class", [0]),
    (ForestOptions, "class_weight", ["none", "uniform"]),
    (ClassifyOptions, "threshold", [0.0, 1.0, -0.1, 1.5, NAN]),
    (ClassifyStreamOptions, "points_per_cell", [0, -1, 2.5]),
    (ClassifyStreamOptions, "chunk_size", [0]),
    (OrientedPointOptions, "min_opacity", [-0.01, 1.0, NAN]),
    (OrientedPointOptions, "full_weight_opacity", [0.0, 1.01, NAN]),
    (OrientedPointOptions, "sample_spacing", [0.0, -1.0, NAN, INF]),
    (OrientedPointOptions, "footprint_sigmas", [0.0, NAN, INF]),
    (OrientedPointOptions, "max_samples_per_gaussian", [0]),
    (OrientedPointOptions, "isotropy_ratio", [0.0, 1.5]),
    (OrientedPointOptions, "normal_neighbors", [2]),
    (OrientedPointOptions, "normal_fallback", ["guess"]),
    (PoissonOptions, "depth", [1, 15]),
    (PoissonOptions, "min_depth", [1, 15]),
    (PoissonOptions, "max_depth", [15, 1]),
    (PoissonOptions, "cell_factor", [0.0, NAN, INF]),
    (PoissonOptions, "scale", [0.99, NAN]),
    (PoissonOptions, "point_weight", [-0.1, NAN]),
    (PoissonOptions, "density_quantile", [-0.1, 1.0]),
    (PoissonOptions, "support_factor", [0.0, NAN, INF]),
    (PoissonOptions, "support_neighbors", [0]),
    (PoissonOptions, "min_component_fraction", [1.0, -0.5]),
    (DecimateOptions, "method", ["vertex-clustering"]),
    (DecimateOptions, "tolerance", [1.0, -0.01]),
    (DecimateOptions, "max_attempts", [0]),
    (SnapshotOptions, "region_radius", [0.0, NAN, INF]),
    (SnapshotOptions, "min_opacity", [1.0, -1.0]),
    (MeshOptions, "budget", [0, -5, 2.5, True, "10"]),
    (MeshOptions, "source", ["lidar"]),
    (MeshOptions, "mvs_priority", [-1.0, NAN, INF]),
    (MeshOptions, "color_neighbors", [0]),
    (TSDFOptions, "voxel_size", [0.0, NAN, INF]),
    (TSDFOptions, "trunc_voxels", [0.0, -1.0, NAN]),
    (TSDFOptions, "min_alpha", [0.0, 1.1]),
    (TSDFOptions, "depth_max", [0.0, -1.0, NAN]),
    (MeshStageOptions, "budget", [-1, True, 1.5]),
    (MeshStageOptions, "formats", [(), ("stl",), ("ply", "fbx")]),
    (MeshStageOptions, "method", ["marching"]),
    (TilesetOptions, "max_splats_per_tile", [0, True, 2.0, "10"]),
    (TilesetOptions, "placement", ["nearest"]),
    (TilesetOptions, "color_space", ["cmyk"]),
    (TilesetOptions, "compression", ["zip"]),
    (ExportOptions, "crop_min", [(0.0, 0.0), (0.0, 0.0, NAN), (0.0, INF, 0.0), "abc"]),
    (ExportOptions, "crop_max", [(1.0, 1.0, 1.0, 1.0), (1.0, 1.0, -INF)]),
    (ExportOptions, "min_opacity", [1.0, -0.1, NAN]),
    (ExportOptions, "sh_degree", [4, -1]),
    (ExportOptions, "spz_version", [1, 4]),
    (ExportOptions, "gltf_compression", ["draco"]),
    (BackgroundOptions, "shell_radius", [1.0, 0.5, (), (8.0, 1.0), NAN]),
    (BackgroundOptions, "min_pairs", [0]),
    (BackgroundOptions, "max_image_size", [15]),
    (BackgroundOptions, "seed_stride_px", [0]),
    (BackgroundOptions, "max_seeds", [0]),
    (BackgroundOptions, "unseen_step_deg", [-1.0, 30.5, NAN]),
    (BackgroundOptions, "alpha_threshold", [0.0, 1.0]),
    (BackgroundOptions, "min_share", [1.0, -0.1]),
    (CleanOptions, "mask_dilation_px", [-1]),
    (CleanOptions, "min_cluster_size", [0]),
    (CleanOptions, "max_scale_scene", [0.0, -1.0, NAN]),
    (CleanOptions, "max_scale_spacing", [0.0]),
    (CleanOptions, "cluster_eps_spacing", [0.0]),
    (SurveyPointOptions, "min_views", [-1]),
    (SurveyPointOptions, "occlusion_tolerance", [-0.1, NAN]),
    (SurveyPointOptions, "min_mask_share", [-0.1, 1.1]),
    (SurveyPointOptions, "max_behind_share", [1.1]),
    (SurveyPointOptions, "behind_margin_spacing", [-1.0, INF, NAN]),
    (SurveyPointOptions, "min_opacity", [0.0]),
    (SurveyPointOptions, "max_thickness_spacing", [0.0]),
    (SurveyPointOptions, "max_extent_spacing", [-2.0]),
    (SurveyPointOptions, "max_rim_spacing", [0.0]),
    (AppearanceOptions, "max_image_size", [-1]),
    (AppearanceOptions, "max_scale_spacings", [0.0, NAN]),
    (AppearanceOptions, "spacing_neighbours", [0, 65]),
    (AppearanceOptions, "max_passes", [-1.0, NAN]),
    (MergeOptions, "viewer_formats", [("ply", "fbx"), ("x",)]),
    (MergeOptions, "needs_mvs_max_rim_spacing", [0.0, -1.0, NAN]),
    (ConvertOptions, "opacity_logit_min", [NAN, -INF]),
    (ConvertOptions, "opacity_logit_max", [INF]),
    (ConvertOptions, "min_spacing", [0.0, -1.0]),
    (ConvertOptions, "max_spacing", [INF]),
    (ConvertOptions, "fallback_spacing", [0.0, INF]),
    (ConvertOptions, "k_neighbors", [0, 65]),
    (ConvertOptions, "tangent_scale", [0.0, NAN]),
    (ConvertOptions, "thickness_ratio", [0.0, 1.5]),
    (ConvertOptions, "max_opacity", [0.0, 1.0]),
    (ConvertOptions, "view_saturation", [0.0]),
    (ConvertOptions, "outlier_spacing_factor", [0.0, INF]),
    (ConvertOptions, "chunk_size", [0]),
    (ConvertOptions, "neighbor_backend", ["octree"]),
    (InputOptions, "units", ["furlong"]),
    (InputOptions, "holdout", [-2]),
    (MvsOptions, "backend", ["gpu"]),
    (MvsOptions, "max_image_size", [0, -2, 1.5]),
    (CpuMvsOptions, "quality", ["best"]),
    (SfmOptions, "matcher", ["brute"]),
    (SfmOptions, "mapper", ["magic"]),
    (SfmOptions, "spatial_neighbours", [0, -3]),
    (SfmOptions, "align_threshold_m", [0.0, -1.0, NAN]),
    (TileOptions, "photos_per_tile", [0]),
    (TileOptions, "points_per_tile", [0]),
    (TileOptions, "min_points_seen", [0]),
    (TileOptions, "overlap_m", [-0.1, NAN, INF]),
    (TileOptions, "extent_quantile", [0.5, -0.01]),
    (TileOptions, "up", ["w"]),
]

ACCEPTED = [
    (MaskOptions, "footprint", [1e-6, 100.0]),
    (MaskOptions, "max_radius_px", [1]),
    (MaskOptions, "close_px", [0]),
    (MaskOptions, "hole_gsd", [0.0, 3.0]),
    (MaskOptions, "grow_area", [0]),
    (MaskOptions, "grow_max_px", [16]),
    (MaskOptions, "dilate_spacings", [0.0]),
    (MaskOptions, "train_margin_spacings", [0.0, 5]),
    (MaskOptions, "hole_area", ["hull", HoleArea.ENCLOSED]),
    (MaskOptions, "explained_by", ["all", ExplainedBy.SEEN]),
    (GeometricOptions, "search", ["kdtree"]),
    (GeometricOptions, "backend", ["numpy", "pgeof"]),
    (GeometricOptions, "k", [3]),
    (GeometricOptions, "voxel_factors", [(0.5,), (1.0, 4.0)]),
    (GeometricOptions, "chunk_size", [1]),
    (ForestOptions, "smooth_passes", [0]),
    (ForestOptions, "folds", [2]),
    (ForestOptions, "class_weight", [None, "balanced", "balanced_subsample"]),
    (ClassifyOptions, "threshold", [None, 1e-9, 0.5, 0.999]),
    (ClassifyStreamOptions, "points_per_cell", [None, 1]),
    (OrientedPointOptions, "min_opacity", [0.0, 0.99]),
    (OrientedPointOptions, "full_weight_opacity", [1.0]),
    (OrientedPointOptions, "isotropy_ratio", [1.0]),
    (OrientedPointOptions, "normal_neighbors", [3]),
    (PoissonOptions, "depth", [None, 2, 10]),
    (PoissonOptions, "scale", [1.0]),
    (PoissonOptions, "point_weight", [0.0]),
    (PoissonOptions, "density_quantile", [0.0, 0.5]),
    (PoissonOptions, "support_factor", [None, 0.5]),
    (DecimateOptions, "method", ["open3d", "fast-simplification"]),
    (DecimateOptions, "tolerance", [0.0]),
    (MeshOptions, "budget", [None, 1]),
    (MeshOptions, "source", ["mvs", "survey"]),
    (MeshOptions, "mvs_priority", [0.0]),
    (TSDFOptions, "min_alpha", [1.0]),
    (TSDFOptions, "depth_max", [None, 5.0, INF]),
    (MeshStageOptions, "budget", [0, 10]),
    (MeshStageOptions, "formats", [("ply",), ("glb", "obj")]),
    (MeshStageOptions, "method", ["tsdf"]),
    (TilesetOptions, "max_splats_per_tile", [1]),
    (TilesetOptions, "placement", ["grid"]),
    (TilesetOptions, "compression", ["none"]),
    (ExportOptions, "crop_min", [(-1.0, -2.0, 0.0), [0, 0, 0]]),
    (ExportOptions, "min_opacity", [0.0]),
    (ExportOptions, "sh_degree", [None, 0, 3]),
    (ExportOptions, "spz_version", [2, 3]),
    (ExportOptions, "gltf_compression", ["none"]),
    (BackgroundOptions, "shell_radius", [1.5, (8.0, 32.0), INF]),
    (BackgroundOptions, "max_image_size", [16]),
    (BackgroundOptions, "unseen_step_deg", [0.0, 30.0]),
    (BackgroundOptions, "min_share", [0.0]),
    (CleanOptions, "mask_dilation_px", [0]),
    (CleanOptions, "max_scale_scene", [None, 1e-6, INF]),
    (SurveyPointOptions, "min_views", [0]),
    (SurveyPointOptions, "occlusion_tolerance", [0.0, INF]),
    (SurveyPointOptions, "min_mask_share", [None, 0.0, 1.0]),
    (SurveyPointOptions, "behind_margin_spacing", [0.0]),
    (SurveyPointOptions, "max_rim_spacing", [None, INF]),
    (AppearanceOptions, "max_image_size", [0]),
    (AppearanceOptions, "spacing_neighbours", [1, 64]),
    (AppearanceOptions, "max_passes", [0.0, INF]),
    (MergeOptions, "viewer_formats", [()]),
    (MergeOptions, "needs_mvs_max_rim_spacing", [None, 1.0]),
    (ConvertOptions, "thickness_ratio", [1.0]),
    (ConvertOptions, "k_neighbors", [1, 64]),
    (ConvertOptions, "neighbor_backend", ["kdtree"]),
    (InputOptions, "holdout", [-1, 0, 8]),
    (MvsOptions, "max_image_size", [-1, 1, 4000]),
    (CpuMvsOptions, "quality", ["fast", "high"]),
    (SfmOptions, "spatial_neighbours", [1]),
    (SfmOptions, "align_threshold_m", [None, 0.01]),
    (TileOptions, "overlap_m", [None, 0.0, 5.0]),
    (TileOptions, "extent_quantile", [0.0, 0.49]),
]


def _build(cls: type, name: str, value: object) -> object:
    return cls(**{**REQUIRED.get(cls, {}), name: value})


@pytest.mark.parametrize(("cls", "name", "values"), REFUSED, ids=lambda x: getattr(x, "__name__", None))
def test_refused_with_the_one_message(cls: type, name: str, values: list) -> None:
    for value in values:
        with pytest.raises(ConstraintError, match=rf"^option {re.escape(name)} must be .+, got ") as info:
            _build(cls, name, value)
        assert info.value.option == name


@pytest.mark.parametrize(("cls", "name", "values"), ACCEPTED, ids=lambda x: getattr(x, "__name__", None))
def test_accepted(cls: type, name: str, values: list) -> None:
    for value in values:
        built = _build(cls, name, value)
        stored = getattr(built, name)
        assert stored == value or (hasattr(stored, "value") and stored.value == value) or stored == tuple(value)


def test_every_declaration_names_a_field_and_defaults_satisfy_it() -> None:
    classes = {cls for cls, _, _ in REFUSED + ACCEPTED}
    for cls in classes:
        assert issubclass(cls, Constrained)
        default = cls(**REQUIRED.get(cls, {}))
        for name, constraint in cls.constraints.items():
            assert constraint.accepts(getattr(default, name)), (cls.__name__, name)


def test_poisson_depth_range_across_fields() -> None:
    assert PoissonOptions(min_depth=7, max_depth=7).min_depth == 7
    with pytest.raises(ConfigError, match=r"^min_depth must be <= max_depth, got 9 > 8$"):
        PoissonOptions(min_depth=9, max_depth=8)


def test_export_crop_rules_across_fields() -> None:
    with pytest.raises(ConfigError, match="crop needs both crop_min and crop_max"):
        ExportOptions(crop_min=(0.0, 0.0, 0.0))
    with pytest.raises(ConfigError, match="crop_min must not exceed crop_max"):
        ExportOptions(crop_min=(0.0, 2.0, 0.0), crop_max=(1.0, 1.0, 1.0))
