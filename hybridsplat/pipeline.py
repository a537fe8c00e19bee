"""The end-to-end pipeline: photos or a synthetic scene -> sparse -> dense -> Gaussians -> export -> eval -> report.

Every stage runs through :class:`hybridsplat.manifest.Manifest`, so it records its inputs' hashes, configuration,
timings, peak memory and counts, is skipped on re-run when nothing it depends on changed, and is skipped with a
reason when the project does not need it or the toolkit does not have it yet. Stage order and outputs follow
the project-folder contract in ``docs/conventions.md`` and DESIGN.md.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import ConfigError
from core.io.atomic import write_text_atomic
from hybridsplat.manifest import Manifest, StageOutcome

Progress = Callable[[str], None]


@dataclass(frozen=True)
class PipelineConfig:
    """Options of ``hybridsplat run`` (written to ``PROJECT/config.toml``).

    known_poses: use the input's known cameras (a data_synth scene's ``sparse/0``) and only triangulate.
    mvs_backend: ``auto`` (COLMAP PatchMatch on CUDA, else our CPU MVS), ``cpu`` or ``colmap``.
    max_image_size: longer side of the dense images in pixels (-1: full resolution).
    convert_mode: MVS-to-Gaussian conversion, ``paper`` (Eq. 1–4) or ``adaptive``.
    tau_gsd: completeness / F-score threshold in ground-sample distances (when the scene knows its GSD).
    lpips_weights: LPIPS v0.1 AlexNet weights (.npz); None searches ``$HYBRIDSPLAT_LPIPS_WEIGHTS`` and defaults.
    seed: seed of every random choice.
    """

    known_poses: bool = True
    mvs_backend: str = "auto"
    max_image_size: int = -1
    convert_mode: str = "adaptive"
    tau_gsd: float = 3.0
    lpips_weights: str | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if self.mvs_backend not in ("auto", "cpu", "colmap"):
            raise ConfigError(f"mvs_backend must be auto, cpu or colmap, got {self.mvs_backend!r}")
        if self.convert_mode not in ("paper", "adaptive"):
            raise ConfigError(f"convert_mode must be paper or adaptive, got {self.convert_mode!r}")
        if self.tau_gsd <= 0:
            raise ConfigError(f"tau_gsd must be positive, got {self.tau_gsd}")

    def to_toml(self) -> str:
        lines = ["# hybridsplat run: effective configuration", "[pipeline]"]
        for key, value in asdict(self).items():
            if value is None:
                lines.append(f"# {key} = (not set)")
            elif isinstance(value, bool):
                lines.append(f"{key} = {'true' if value else 'false'}")
            elif isinstance(value, (int, float)):
                lines.append(f"{key} = {value}")
            else:
                lines.append(f"{key} = {json.dumps(str(value))}")
        return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class SceneTruth:
    """What a data_synth scene offers for evaluation (all optional for real photo folders)."""

    reference_cloud: Path | None
    test_model: Path | None
    test_photos: Path | None
    test_labels: Path | None
    non_collaborative_ids: tuple[int, ...]
    gsd_m: float | None


def scene_truth(input_path: Path) -> SceneTruth:
    """Ground truth next to the input: gt/lidar.ply, sparse/test, test/, gt/labels/test and scene.json."""

    def existing(p: Path) -> Path | None:
        return p if p.exists() else None

    non_collab: tuple[int, ...] = ()
    gsd = None
    scene_json = input_path / "scene.json"
    if scene_json.is_file():
        meta = json.loads(scene_json.read_text(encoding="utf-8"))
        non_collab = tuple(int(m["id"]) for m in meta.get("materials", []) if not m.get("collaborative", True))
        gsd = meta.get("gsd_m")
    return SceneTruth(
        reference_cloud=existing(input_path / "gt" / "lidar.ply"),
        test_model=existing(input_path / "sparse" / "test"),
        test_photos=existing(input_path / "test"),
        test_labels=existing(input_path / "gt" / "labels" / "test"),
        non_collaborative_ids=non_collab,
        gsd_m=float(gsd) if gsd else None,
    )


def write_truth_masks(labels_dir: Path, out_dir: Path, non_collaborative_ids: tuple[int, ...]) -> int:
    """Binary masks (255 = non-collaborative material) from per-pixel material labels; returns how many."""
    from core.io.images import read_image, write_image

    count = 0
    for label_path in sorted(labels_dir.glob("*.png")):
        labels = read_image(label_path, grayscale=True)
        mask = np.isin(labels, np.asarray(non_collaborative_ids, dtype=labels.dtype)).astype(np.uint8) * 255
        write_image(out_dir / label_path.name, mask)
        count += 1
    return count


def run_pipeline(
    input_path: str | Path,
    project: str | Path,
    config: PipelineConfig = PipelineConfig(),
    progress: Progress | None = None,
) -> Manifest:
    """Run every stage that exists on ``input_path`` (photos folder or data_synth scene) into ``project``."""
    from recon.project import resolve_input

    say = progress or (lambda message: None)
    input_path, project = Path(input_path), Path(project)
    project.mkdir(parents=True, exist_ok=True)
    write_text_atomic(project / "config.toml", config.to_toml())
    manifest = Manifest(project)
    scene = resolve_input(input_path)
    truth = scene_truth(input_path)

    sparse, dense = project / "sparse", project / "dense"
    fused = dense / "fused.ply"
    export = project / "export"
    mvs_gaussians = export / "mvs_gaussians.ply"
    merged = export / "merged.ply"
    merged_points = export / "merged_points.ply"

    # -- recon --------------------------------------------------------------------------------------
    def sfm() -> StageOutcome:
        from recon.sfm import SfmOptions
        from recon.stages import sfm_stage

        report = sfm_stage(input_path, project, config.known_poses, SfmOptions(seed=config.seed))
        return StageOutcome(
            counts={
                "images": report.num_images,
                "registered": len(report.registered),
                "points": report.num_points,
                "reprojection_error_px": report.mean_reprojection_error,
            }
        )

    say("sfm: " + ("triangulating with known poses" if config.known_poses else "features, matching, mapping"))
    ref_inputs = [scene.reference_model] if scene.reference_model else []
    manifest.run_stage(
        "sfm",
        sfm,
        inputs=[scene.image_dir, *ref_inputs],
        outputs=[sparse],
        config={"known_poses": config.known_poses, "seed": config.seed},
    )

    def mvs() -> StageOutcome:
        from recon.mvs import MvsOptions
        from recon.stages import mvs_stage

        report = mvs_stage(project, MvsOptions(backend=config.mvs_backend, max_image_size=config.max_image_size))
        return StageOutcome(
            counts={
                "backend": report.backend,
                "views": report.num_views,
                "points": report.num_points,
                "seconds_per_view": report.seconds_per_view,
            }
        )

    say("mvs: depth maps and fusion")
    manifest.run_stage(
        "mvs",
        mvs,
        inputs=[sparse, scene.image_dir],
        outputs=[fused, Path(str(fused) + ".vis")],
        config={"backend": config.mvs_backend, "max_image_size": config.max_image_size},
    )

    manifest.run_stage(
        "classify",
        lambda: StageOutcome(
            skipped=True,
            reason="no classifier stage in this version: every MVS point is kept as collaborative",
        ),
        inputs=[],
        outputs=[],
    )

    # -- fusion -------------------------------------------------------------------------------------
    def convert() -> StageOutcome:
        from core.io.gaussian_ply import write_gaussian_ply
        from fusion.convert import convert_points
        from recon.workspace import read_fused

        cloud = read_fused(dense)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = convert_points(cloud, config.convert_mode)
        write_gaussian_ply(mvs_gaussians, result.gaussians, extra_fields=True)
        return StageOutcome(
            counts={
                "gaussians": len(result.gaussians),
                "mean_nn_spacing_m": result.stats.mean_nn_spacing,
                "warnings": [str(w.message) for w in caught],
            }
        )

    say(f"convert: MVS points to Gaussians ({config.convert_mode})")
    manifest.run_stage(
        "convert", convert, inputs=[fused], outputs=[mvs_gaussians], config={"mode": config.convert_mode}
    )

    manifest.run_stage(
        "train",
        lambda: StageOutcome(
            skipped=True,
            reason="no masked splat training in this version (no non-collaborative regions are classified yet)",
        ),
        inputs=[],
        outputs=[],
    )

    def merge() -> StageOutcome:
        from core.io.gaussian_ply import read_gaussian_ply
        from fusion.export import export_gaussian_ply, export_points
        from fusion.merge import merge_gaussians

        result = merge_gaussians(None, read_gaussian_ply(mvs_gaussians))
        ply = export_gaussian_ply(merged, result.gaussians)
        export_points(merged_points, result.gaussians)
        export_points(merged_points.with_suffix(".las"), result.gaussians)
        return StageOutcome(counts={"merged": len(result.gaussians), "written": ply.num_written})

    say("merge and export")
    manifest.run_stage(
        "merge",
        merge,
        inputs=[mvs_gaussians],
        outputs=[merged, merged_points, merged_points.with_suffix(".las")],
    )

    # -- eval ---------------------------------------------------------------------------------------
    def evaluate() -> StageOutcome:
        from core.io.colmap import read_model
        from core.io.gaussian_ply import read_gaussian_ply
        from eval.evaluate import ImageInputs, evaluate_product
        from eval.geometry import GeometryOptions
        from recon.workspace import read_fused

        if truth.reference_cloud is None and truth.test_model is None:
            return StageOutcome(skipped=True, reason="no ground truth next to the input (gt/lidar.ply, sparse/test)")
        tau = config.tau_gsd * truth.gsd_m if truth.gsd_m else None
        geometry = GeometryOptions(tau=tau)
        images = None
        if truth.test_model is not None and truth.test_photos is not None:
            masks = None
            if truth.test_labels is not None and truth.non_collaborative_ids:
                masks = project / "eval" / "truth_masks"
                write_truth_masks(truth.test_labels, masks, truth.non_collaborative_ids)
            cameras, _ = read_model(truth.test_model)
            images = ImageInputs(cameras, list(cameras), truth.test_photos, masks)
        lpips_model = _lpips_or_none(config.lpips_weights)
        counts: dict[str, Any] = {"lpips": lpips_model is not None}
        products = {
            "mvs": (read_fused(dense), read_gaussian_ply(mvs_gaussians)),
            "merged": (merged_points, read_gaussian_ply(merged)),
        }
        for name, (cloud, gaussians) in products.items():
            say(f"eval: {name}")
            evaluate_product(
                project,
                name,
                cloud=cloud,
                reference=truth.reference_cloud,
                gaussians=gaussians,
                images=images,
                geometry=geometry,
                lpips_model=lpips_model,
            )
        evaluate_product(project, "splats", skip_reason="no splats were trained (see stage 'train')")
        return StageOutcome(counts=counts)

    manifest.run_stage(
        "eval",
        evaluate,
        inputs=[fused, mvs_gaussians, merged, *(p for p in (truth.reference_cloud, truth.test_model) if p)],
        outputs=[project / "eval" / "metrics.json"],
        config={"tau_gsd": config.tau_gsd, "lpips_weights": config.lpips_weights},
    )

    def report() -> StageOutcome:
        from eval.report import write_report

        paths = write_report(project)
        return StageOutcome(counts={"files": [str(p) for p in asdict(paths).values()]})

    say("report")
    manifest.run_stage(
        "report", report, inputs=[project / "eval" / "metrics.json", manifest.path], outputs=[project / "report"]
    )
    return manifest


def _lpips_or_none(weights: str | None) -> object | None:
    """The LPIPS model when weights can be found; None (LPIPS left out of the report) otherwise."""
    from core.errors import HybridSplatError
    from eval.lpips import LPIPS

    try:
        return LPIPS.from_path(weights)
    except HybridSplatError as err:
        warnings.warn(f"LPIPS left out: {err.one_line()}", stacklevel=2)
        return None
