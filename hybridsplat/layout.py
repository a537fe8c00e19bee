"""The project folder: the one place that spells the paths under PROJECT/.

Names are a contract with users and scripts (``docs/conventions.md``, section "The project folder", is checked
against this class by ``tests/test_layout.py``); change them only with a note in docs/migration.md. COLMAP's
own names inside ``dense/`` belong to :class:`recon.workspace.DenseWorkspace`, which this layout hands out.
"""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from pathlib import Path

from recon.workspace import DenseWorkspace

MESH_FORMATS = ("ply", "obj", "glb")


@dataclass(frozen=True)
class TileAppearanceFiles:
    """A tile's part of a tiled appearance stage: its inputs, written by the parent (the parent's survey Gaussians
    that do not need splats and its cleaned fill splats, those in the tile's bounds, in the parent's order), what the
    tile refined of them (same rows), and its record (what the inputs were, for a resumed run)."""

    survey: Path
    fill: Path
    survey_refined: Path
    fill_refined: Path
    record: Path


@dataclass(frozen=True)
class ProjectLayout:
    """Paths of one project folder ``root`` (nothing is created here; stages create what they write)."""

    root: Path

    def __init__(self, root: str | PathLike[str]) -> None:
        object.__setattr__(self, "root", Path(root))

    # -- top level ------------------------------------------------------------------------------
    @property
    def manifest(self) -> Path:
        """Every stage: inputs' hashes, configuration, versions, timings, peak memory, counts, skip reasons."""
        return self.root / "manifest.json"

    @property
    def config(self) -> Path:
        """The effective configuration (TOML), read back by the per-stage commands."""
        return self.root / "config.toml"

    @property
    def lock(self) -> Path:
        """The file a command that writes the project locks (``flock``; :mod:`hybridsplat.project_lock`)."""
        return self.root / ".hybridsplat.lock"

    @property
    def lock_holder(self) -> Path:
        """Who holds the write lock (pid, host, command, stage; JSON); gone when the lock is released."""
        return self.root / ".hybridsplat.lock.json"

    @property
    def logs_dir(self) -> Path:
        return self.root / "logs"

    def log(self, stage: str) -> Path:
        """Text log of a stage (COLMAP and glog output go here, never to the terminal)."""
        return self.logs_dir / f"{stage}.log"

    def record(self, stage: str) -> Path:
        """JSON record of what a stage found (e.g. the SfM report, the input description)."""
        return self.logs_dir / f"{stage}.json"

    # -- recon ----------------------------------------------------------------------------------
    @property
    def sparse(self) -> Path:
        """COLMAP sparse model, aligned to the reference frame when one was given."""
        return self.root / "sparse"

    @property
    def control_dir(self) -> Path:
        """Survey control (``--control``): the model held to it, the marks and the accuracy statement."""
        return self.root / "control"

    @property
    def control_sparse(self) -> Path:
        """COLMAP sparse model adjusted to the control points, in the control frame; later stages read it."""
        return self.control_dir / "sparse"

    @property
    def control_marks(self) -> Path:
        """Every mark the adjustment used (detected and manual), ``image,point_id,u,v``."""
        return self.control_dir / "marks.csv"

    @property
    def control_accuracy(self) -> Path:
        """The check points' accuracy statement as the control stage computed it (JSON)."""
        return self.control_dir / "accuracy.json"

    @property
    def dense(self) -> Path:
        return self.root / "dense"

    @property
    def dense_workspace(self) -> DenseWorkspace:
        return DenseWorkspace(self.dense)

    @property
    def fused_ply(self) -> Path:
        return self.dense_workspace.fused_ply

    @property
    def fused_vis(self) -> Path:
        return self.dense_workspace.fused_vis

    # -- classify -------------------------------------------------------------------------------
    @property
    def classify_dir(self) -> Path:
        return self.root / "classify"

    @property
    def classified_points(self) -> Path:
        """Dense cloud + ``classification``, ``probability``, ``needs_splats`` fields."""
        return self.classify_dir / "points.ply"

    @property
    def classify_report(self) -> Path:
        return self.classify_dir / "report.json"

    @property
    def masks_dir(self) -> Path:
        """One PNG per photo (255 = needs splats)."""
        return self.classify_dir / "masks"

    def mask_path(self, image_name: str) -> Path:
        """Region mask of photo ``image_name`` (COLMAP's convention: ``0001.jpg`` -> ``0001.jpg.png``)."""
        return self.masks_dir / f"{image_name}.png"

    @property
    def user_masks_dir(self) -> Path:
        """The user's ``--splat-masks``, normalised to ``<image name>.png``."""
        return self.classify_dir / "user_masks"

    @property
    def classify_figures_dir(self) -> Path:
        """Figures of the classification for the report (PNG)."""
        return self.classify_dir / "figures"

    @property
    def classes_figure(self) -> Path:
        """The classified cloud, top and side views coloured by class."""
        return self.classify_figures_dir / "classes.png"

    @property
    def importances_figure(self) -> Path:
        """The classifier's feature importances."""
        return self.classify_figures_dir / "importances.png"

    @property
    def masks_figure(self) -> Path:
        """A few photos with their region masks overlaid."""
        return self.classify_figures_dir / "masks.png"

    # -- splats ---------------------------------------------------------------------------------
    @property
    def splats_dir(self) -> Path:
        return self.root / "splats"

    @property
    def trained_splats(self) -> Path:
        return self.splats_dir / "trained.ply"

    @property
    def cleaned_splats(self) -> Path:
        return self.splats_dir / "cleaned.ply"

    @property
    def neighbour_splats(self) -> Path:
        """In a tile's project: the neighbouring tiles' cleaned splats that lie in this tile's overlap, frozen as
        context in its training (written by the tiled run before the tile trains; absent elsewhere)."""
        return self.splats_dir / "neighbours.ply"

    def tile_appearance_files(self) -> TileAppearanceFiles:
        """In a tile's project: the files of its part of a tiled appearance stage
        (:mod:`hybridsplat.tile_appearance`); absent elsewhere."""
        return TileAppearanceFiles(
            survey=self.splats_dir / "tile_survey.ply",
            fill=self.splats_dir / "tile_fill.ply",
            survey_refined=self.splats_dir / "tile_survey_refined.ply",
            fill_refined=self.splats_dir / "tile_fill_refined.ply",
            record=self.logs_dir / "appearance_tile.json",
        )

    @property
    def background_splats(self) -> Path:
        """The background layer: what the photos see beyond the survey region (``fusion.background``)."""
        return self.splats_dir / "background.ply"

    @property
    def survey_splats(self) -> Path:
        """The survey layer with its appearance refined for viewers, one Gaussian per converted MVS Gaussian, same
        order and positions (``fusion.appearance``)."""
        return self.splats_dir / "survey.ply"

    @property
    def refined_fill_splats(self) -> Path:
        """The fill layer (splats/cleaned.ply) with its appearance refined for viewers beside the survey layer, row
        for row, positions bit for bit (``fusion.appearance``, ``refine_context``)."""
        return self.splats_dir / "fill_refined.ply"

    @property
    def refined_background_splats(self) -> Path:
        """The background layer (splats/background.ply) with its appearance refined for viewers beside the survey
        layer, row for row, positions bit for bit (``fusion.appearance``, ``refine_context``)."""
        return self.splats_dir / "background_refined.ply"

    def refined_layers(self) -> dict[Path, Path]:
        """Each layer the appearance stage can refine for viewers → its refined copy: splats/cleaned.ply →
        splats/fill_refined.ply, splats/background.ply → splats/background_refined.ply."""
        return {self.cleaned_splats: self.refined_fill_splats, self.background_splats: self.refined_background_splats}

    @property
    def snapshots_dir(self) -> Path:
        return self.splats_dir / "snapshots"

    @property
    def baseline_splats(self) -> Path:
        """The whole-scene 3DGS baseline (for comparison)."""
        return self.splats_dir / "baseline.ply"

    @property
    def baseline_checkpoints_dir(self) -> Path:
        """The baseline's splats at chosen steps of its training, ``baseline_<step:06d>.ply``."""
        return self.splats_dir / "baseline_checkpoints"

    # -- export ---------------------------------------------------------------------------------
    @property
    def export_dir(self) -> Path:
        return self.root / "export"

    @property
    def mvs_gaussians(self) -> Path:
        return self.export_dir / "mvs_gaussians.ply"

    @property
    def splats_export(self) -> Path:
        return self.export_dir / "splats.ply"

    @property
    def merged_ply(self) -> Path:
        """The product for splat viewers (3DGS PLY, local coordinates; origin in ``merged.origin.json``)."""
        return self.export_dir / "merged.ply"

    def merged_viewer(self, fmt: str) -> Path:
        """The viewer product in another format (``fusion.merge_options.VIEWER_FORMATS``), e.g. export/merged.spz."""
        from fusion.merge_options import VIEWER_FORMATS

        if fmt not in VIEWER_FORMATS:
            raise ValueError(f"viewer format must be one of {tuple(VIEWER_FORMATS)}, got {fmt!r}")
        return self.export_dir / VIEWER_FORMATS[fmt]

    @property
    def merged_points_ply(self) -> Path:
        return self.export_dir / "merged_points.ply"

    @property
    def merged_points_las(self) -> Path:
        return self.export_dir / "merged_points.las"

    def mesh_path(self, fmt: str = "ply") -> Path:
        if fmt not in MESH_FORMATS:
            raise ValueError(f"mesh format must be one of {MESH_FORMATS}, got {fmt!r}")
        return self.export_dir / f"mesh.{fmt}"

    # -- measurement (hybridsplat measure / view) --------------------------------------------------
    @property
    def measurements_csv(self) -> Path:
        """Measured points: world coordinates, unit, σ, covariance, CRS (``eval.measure.export``)."""
        return self.export_dir / "measurements.csv"

    @property
    def measurement_distances_csv(self) -> Path:
        return self.export_dir / "measurements_distances.csv"

    @property
    def measurements_geojson(self) -> Path:
        """The measurements in WGS84 (RFC 7946); written only when the project's CRS is known."""
        return self.export_dir / "measurements.geojson"

    @property
    def picks_json(self) -> Path:
        """The viewer's photo picks in the PICKS.json format of ``hybridsplat measure``."""
        return self.export_dir / "picks.json"

    # -- eval and report ------------------------------------------------------------------------
    @property
    def eval_dir(self) -> Path:
        return self.root / "eval"

    @property
    def accuracy_json(self) -> Path:
        """The accuracy statement of the survey control (ASPRS Edition 2), copied here by the eval stage."""
        return self.eval_dir / "accuracy.json"

    @property
    def metrics_json(self) -> Path:
        return self.eval_dir / "metrics.json"

    @property
    def per_material_json(self) -> Path:
        """Accuracy, completeness and held-out PSNR per ground-truth material, per product (data_synth scenes)."""
        return self.eval_dir / "per_material.json"

    @property
    def eval_masks_dir(self) -> Path:
        """Masks of the held-out views used for the masked image metrics."""
        return self.eval_dir / "masks"

    @property
    def eval_cache_dir(self) -> Path:
        """Stored measurements of products by content (:mod:`eval.cache`); safe to delete."""
        return self.root / "cache" / "eval"

    @property
    def report_dir(self) -> Path:
        return self.root / "report"

    @property
    def report_html(self) -> Path:
        return self.report_dir / "report.html"

    @property
    def report_md(self) -> Path:
        return self.report_dir / "report.md"

    @property
    def report_json(self) -> Path:
        """The report's stable schema (``hybridsplat.report/1``)."""
        return self.report_dir / "report.json"

    # -- tiles (``run --tiles``) ----------------------------------------------------------------------
    @property
    def tiles_dir(self) -> Path:
        """Sub-projects of a tiled run, one folder per tile (``tiles/r0c1/``: a project of its own)."""
        return self.root / "tiles"

    @property
    def tile_plan(self) -> Path:
        """The tile plan (:func:`recon.tiling.write_tile_plan`): frame, grid, cores, bounds, photos per tile."""
        return self.tiles_dir / "plan.json"

    def tile_project(self, name: str) -> Path:
        """The sub-project of tile ``name`` (``r{row}c{column}``)."""
        return self.tiles_dir / name

    @property
    def empty_tile_record(self) -> Path:
        """In a tile's project: why its MVS fused no point, with the hash of the model it was run on (the tile then
        adds nothing to the run, and a second run does not redo it while the model is the same)."""
        return self.logs_dir / "empty_tile.json"

    # -- the documented contract ----------------------------------------------------------------
    def documented_paths(self) -> dict[str, Path]:
        """Every user-facing path, relative to the root, as listed in docs/conventions.md."""
        paths = {
            "manifest.json": self.manifest,
            "config.toml": self.config,
            ".hybridsplat.lock": self.lock,
            ".hybridsplat.lock.json": self.lock_holder,
            "sparse/": self.sparse,
            "control/sparse/": self.control_sparse,
            "control/marks.csv": self.control_marks,
            "control/accuracy.json": self.control_accuracy,
            "dense/": self.dense,
            "dense/fused.ply": self.fused_ply,
            "dense/fused.ply.vis": self.fused_vis,
            "classify/points.ply": self.classified_points,
            "classify/report.json": self.classify_report,
            "classify/masks/": self.masks_dir,
            "classify/user_masks/": self.user_masks_dir,
            "classify/figures/classes.png": self.classes_figure,
            "classify/figures/importances.png": self.importances_figure,
            "classify/figures/masks.png": self.masks_figure,
            "splats/trained.ply": self.trained_splats,
            "splats/cleaned.ply": self.cleaned_splats,
            "splats/snapshots/": self.snapshots_dir,
            "splats/background.ply": self.background_splats,
            "splats/survey.ply": self.survey_splats,
            "splats/fill_refined.ply": self.refined_fill_splats,
            "splats/background_refined.ply": self.refined_background_splats,
            "splats/baseline.ply": self.baseline_splats,
            "splats/baseline_checkpoints/": self.baseline_checkpoints_dir,
            "export/mvs_gaussians.ply": self.mvs_gaussians,
            "export/splats.ply": self.splats_export,
            "export/merged.ply": self.merged_ply,
            **{f"export/{name}": self.export_dir / name for name in _viewer_names()},
            "export/merged_points.ply": self.merged_points_ply,
            "export/merged_points.las": self.merged_points_las,
            **{f"export/mesh.{f}": self.mesh_path(f) for f in MESH_FORMATS},
            "export/measurements.csv": self.measurements_csv,
            "export/measurements_distances.csv": self.measurement_distances_csv,
            "export/measurements.geojson": self.measurements_geojson,
            "export/picks.json": self.picks_json,
            "eval/metrics.json": self.metrics_json,
            "eval/accuracy.json": self.accuracy_json,
            "eval/per_material.json": self.per_material_json,
            "eval/masks/": self.eval_masks_dir,
            "cache/eval/": self.eval_cache_dir,
            "report/": self.report_dir,
            "tiles/": self.tiles_dir,
            "tiles/plan.json": self.tile_plan,
            "logs/": self.logs_dir,
        }
        return {name: path.relative_to(self.root) for name, path in paths.items()}


def _viewer_names() -> list[str]:
    from fusion.merge_options import VIEWER_FORMATS

    return list(VIEWER_FORMATS.values())
