"""Stage ``eval``: every product against the ground truth (C2C to the reference cloud) and the held-out photos.

Held-out views are the input's own (a data_synth scene's ``test/`` with ``sparse/test``) or the photos held out of
MVS and training (their undistorted copies in the dense workspace). Masked image metrics use the held-out views'
masks: the true non-collaborative materials of a data_synth scene.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import ConfigError
from hybridsplat.project_io import model_origin, read_model_at, unrefined_layers
from hybridsplat.records import TypedRecord
from hybridsplat.stages import sizes
from hybridsplat.stages.base import (
    MEMORY_LIMIT_HELP,
    CliOption,
    ReportSection,
    Stage,
    StageContext,
    StageResult,
    omitted_if_none,
)

_PREVIEW_WIDTH = 800  # eval.plots.preview_image: 800 px wide, at most 4 times as high
_HISTOGRAM_BINS = 50  # eval.c2c.histogram
_PANELS = 4  # eval.render_eval.evaluate_pairs: panels of the first 4 held-out views


@dataclass(frozen=True)
class EvalStageOptions:
    """Options of the ``eval`` stage.

    tau_gsd: completeness / F-score threshold in ground-sample distances (scenes that know their GSD).
    tau_m: the same threshold in metres (used when set; for real data with a LiDAR reference); None: from tau_gsd.
    reference: a reference cloud (PLY/LAS/LAZ/E57) for C2C; default: the input's own (a data_synth scene's LiDAR).
    lpips_weights: LPIPS v0.1 AlexNet weights (.npz); empty = $HYBRIDSPLAT_LPIPS_WEIGHTS or ../shared/data/lpips.
    cache: reuse the stored measurement of a product whose files, evaluation inputs and evaluation code are
    unchanged (``PROJECT/cache/eval/``, :mod:`eval.cache`): after a retraining only the new products are measured.
    memory_limit_mb (MiB): None reads the reference cloud whole; a number reads it in chunks and measures the C2C and
    the per-material scores cell by cell within about that peak memory (:mod:`eval.geometry_stream`, the same
    figures; at least :data:`eval.c2c_stream.BASE_MB` + :data:`eval.c2c_stream.MIN_WORK_MB`, else a
    :class:`ConfigError`). The products themselves stay in memory (they are rendered).
    """

    tau_gsd: float = 3.0
    tau_m: float | None = None
    reference: str = ""
    lpips_weights: str = ""
    cache: bool = True
    memory_limit_mb: float | None = None

    def __post_init__(self) -> None:
        if self.tau_gsd <= 0 or (self.tau_m is not None and not self.tau_m > 0):
            raise ConfigError(f"tau_gsd must be > 0 and tau_m > 0 (or none), got {self.tau_gsd}, {self.tau_m}")
        if self.memory_limit_mb is not None:
            from eval.c2c_stream import plan_c2c_memory

            plan_c2c_memory(self.memory_limit_mb)  # a ConfigError naming the value


@dataclass(frozen=True)
class ProductSource:
    """A product to measure: the files it is read from (its cache key) and how to load it as (cloud, Gaussians)."""

    files: tuple[Path, ...]
    load: Callable[[], tuple[Any, Any]]


@dataclass(frozen=True)
class HeldOutViews:
    model: Path  # COLMAP model with the held-out cameras
    origin: np.ndarray  # world coordinates of that model's local frame
    photos: Path
    names: tuple[str, ...] | None  # None: every view of the model


STREAM_TEMP_BYTES = 80
"""Temporary bytes a point of the streamed C2C takes in eval/ (cell record 32, halo copies up to 16, distances and
nearest indices 16, far points 32 at most for the few beyond the halo, rounded up)."""


SPOOL_BYTES = 32
"""Bytes a reference point takes spooled in eval/ (:func:`eval.geometry_stream.spool_reference`: float64 positions
and the int64 material)."""


def _cloud_points(path: Path) -> int:
    """Points of a reference cloud from its header (LAS/LAZ, PLY); 0 for other formats, which are read whole."""
    suffix = path.suffix.lower()
    if suffix in (".las", ".laz") and path.is_file():
        import laspy

        with laspy.open(path) as reader:
            return int(reader.header.point_count)
    return sizes.ply_vertices(path).count if suffix == ".ply" else 0


FILTERED_MVS = "mvs_filtered"
"""The control product beside ``merged``: its MVS part alone (the MVS Gaussians and survey points the merge kept,
``source`` = MVS), so that what the merge's filter gains is told apart from what the splats add."""


WITHOUT_BACKGROUND = "merged_no_background"
"""The control beside ``merged``: the same product without its background layer (``source`` = BACKGROUND), so that
what the background adds to the whole image is told apart from what the survey and fill layers do."""


UNREFINED = "merged_unrefined"
"""The control beside ``merged``: the same product with every layer as before the appearance stage (the survey layer
as converted, the fill and background as trained), so that what the refinement adds is told apart from what the
layers themselves do."""


def _converted_survey(gaussians: Any, converted_path: Path, gaussians_path: Path) -> Any:
    """``gaussians`` with their survey rows given back the attributes of export/mvs_gaussians.ply."""
    from core.io.gaussian_ply import read_gaussian_ply
    from fusion.appearance import with_converted_survey

    return with_converted_survey(gaussians, read_gaussian_ply(converted_path), gaussians_path)


def _without_background(gaussians_path: Path) -> Any:
    from core.io.gaussian_ply import read_gaussian_ply
    from fusion.convert_options import Source

    gaussians = read_gaussian_ply(gaussians_path)
    if "source" not in gaussians.fields:
        return gaussians
    return gaussians.subset(np.asarray(gaussians.fields["source"]) != Source.BACKGROUND)


def _filtered_mvs(points_path: Path, gaussians_path: Path, converted_path: Path) -> tuple[Any, Any]:
    """(survey points, Gaussians) of the merged product whose ``source`` is MVS, with their converted attributes
    (``converted_path``: export/mvs_gaussians.ply)."""
    from core.io import read_point_cloud
    from core.io.gaussian_ply import read_gaussian_ply
    from fusion.convert_options import Source

    points, gaussians = read_point_cloud(points_path), read_gaussian_ply(gaussians_path)
    for name, data in (("survey points", points), ("Gaussians", gaussians)):
        if "source" not in data.fields:
            raise ConfigError(f"the merged {name} have no 'source' field: the MVS part cannot be told apart")
    is_mvs = np.asarray(points.fields["source"]) == Source.MVS
    survey = gaussians.subset(np.asarray(gaussians.fields["source"]) == Source.MVS)
    return points.subset(is_mvs), _converted_survey(survey, converted_path, gaussians_path)


@dataclass(frozen=True)
class ProductHeadline(TypedRecord):
    """A product's headline figures: its C2C mean distance to the reference (m), its whole-image PSNR (dB) and
    LPIPS on the held-out views; None where not measured."""

    c2c_mean_m: float | None = omitted_if_none()
    psnr: float | None = omitted_if_none()
    lpips: float | None = omitted_if_none()


_HEADLINE_KEYS = tuple(f.name for f in fields(ProductHeadline))


@dataclass(frozen=True)
class EvalResult(StageResult):
    """What the eval stage measured: whether LPIPS was (``lpips``: its weights were found), the held-out ``views``
    and the ``renderer`` that rendered them (cpu | gsplat | reference; None without held-out views), each product's
    headline figures (``products``: product name → :class:`ProductHeadline`), the products ``reused`` from the
    cache, the materials scored (``per_material``), and with ``memory_limit_mb`` (MiB) the run's peak resident
    memory (MiB).

    Its JSON keeps the manifest's flat form: a product's headline figures as ``<product>_c2c_mean_m``,
    ``<product>_psnr`` and ``<product>_lpips``."""

    lpips: bool = False
    views: int = 0
    renderer: str | None = omitted_if_none()
    products: dict[str, ProductHeadline] = field(default_factory=dict)
    reused: int | None = omitted_if_none()
    per_material: int | None = omitted_if_none()
    memory_limit_mb: float | None = omitted_if_none()
    peak_rss_mb: float | None = omitted_if_none()

    def as_dict(self) -> dict[str, Any]:
        data = super().as_dict()
        for name, figures in data.pop("products").items():
            data.update({f"{name}_{key}": value for key, value in figures.items()})
        return data

    @classmethod
    def from_json(cls, data: Any, where: str | PathLike[str] | None = None, key: str = "") -> EvalResult:
        if not isinstance(data, Mapping):
            return super().from_json(data, where, key)
        flat, products = dict(data), {}
        for name in list(flat):
            for figure in _HEADLINE_KEYS:
                if name.endswith("_" + figure) and len(name) > len(figure) + 1:
                    products.setdefault(name[: -len(figure) - 1], {})[figure] = flat.pop(name)
                    break
        return super().from_json({**flat, "products": products}, where, key)


class EvalStage(Stage):
    name = "eval"
    Options = EvalStageOptions
    Result = EvalResult
    title = "evaluation against ground truth"
    run_options = (
        CliOption("reference", "--lidar", is_path=True,
                  help="Reference cloud (PLY/LAS/LAZ/E57, e.g. a LiDAR scan) for the C2C evaluation."),
        CliOption("lpips_weights", is_path=True, help="LPIPS v0.1 AlexNet weights (.npz)."),
        CliOption("memory_limit_mb", "--memory-limit", help=MEMORY_LIMIT_HELP),
    )  # fmt: skip

    def _reference(self, ctx: StageContext) -> Path | None:
        opts: EvalStageOptions = ctx.options(self)
        return Path(opts.reference) if opts.reference else ctx.source.spec.reference_cloud

    def _held_out(self, ctx: StageContext) -> HeldOutViews | None:
        holdout = ctx.source.holdout
        if holdout.source == "every":  # photos of the input: their undistorted copies in the dense workspace
            ws = ctx.layout.dense_workspace
            return HeldOutViews(ws.sparse, model_origin(ctx.layout), ws.images, holdout.names)
        if holdout.source == "input":  # the input's own views, in the input's frame
            return HeldOutViews(holdout.model, np.asarray(ctx.source.spec.origin, np.float64), holdout.image_dir, None)
        return None

    def inputs(self, ctx: StageContext) -> list[Path]:
        layout, spec = ctx.layout, ctx.source.spec
        truth = [self._reference(ctx), ctx.source.holdout.model, ctx.source.holdout.image_dir, spec.test_labels]
        products = [layout.fused_ply, layout.mvs_gaussians, layout.merged_ply, layout.merged_points_ply,
                    layout.splats_export, layout.baseline_splats, layout.baseline_checkpoints_dir,
                    layout.mesh_path("ply"), layout.control_accuracy]  # fmt: skip
        return [*products, *(p for p in truth if p)]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.eval_dir]

    def fingerprint(self, ctx: StageContext) -> dict[str, Any]:
        return {"held_out": sorted(ctx.source.holdout.names)}

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of eval/ and (with ``cache``) as much again in cache/eval: per product measured (the fused cloud,
        the baseline and its checkpoints, the splats, the merged points) 16 KiB + 1 KiB a held-out view of JSON;
        with a reference, its C2C cloud as PLY and LAS (the product's points with its extra fields, ``source``,
        ``classification``, ``opacity``, ``scale``, normals and ``c2c``), the histogram SVG and the 800 px wide
        preview PNG (one pixel a point); with held-out views, a render | photo | error panel PNG for each of the
        first 4; plus the held-out views' truth masks (greyscale PNGs), 128 KiB of metrics and the log (64 KiB).
        With a memory limit, the streamed C2C's temporary files in eval/ too (:data:`STREAM_TEMP_BYTES` a point of
        the reference and of the largest product, one product at a time) and the spooled reference
        (:data:`SPOOL_BYTES` a point)."""
        opts: EvalStageOptions = ctx.options(self)
        views, size = self._view_bound(ctx)
        reference = self._reference(ctx)
        clouds = _clouds(ctx)
        products = sum(_product_bytes(cloud, renders, reference is not None, views, size) for cloud, renders in clouds)
        fixed = self._masks_bytes(ctx, size) + 2 * sizes.JSON_BYTES + sizes.LOG_BYTES
        if opts.memory_limit_mb is not None and reference is not None:
            largest = max((cloud.count for cloud, _ in clouds), default=0)
            fixed += STREAM_TEMP_BYTES * (_cloud_points(reference) + largest) + SPOOL_BYTES * _cloud_points(reference)
        return (2 if opts.cache else 1) * products + fixed

    def _view_bound(self, ctx: StageContext) -> tuple[int, tuple[int, int]]:
        """The number of held-out views and the largest of their sizes (px): (0, (0, 0)) without any."""
        holdout = ctx.source.holdout
        if holdout.source == "every":
            return len(holdout.names), sizes.largest(sizes.camera_sizes(ctx.layout.dense_workspace.sparse))
        if holdout.source == "input" and holdout.model is not None:
            return sizes.model_count(holdout.model, "images"), sizes.largest(sizes.camera_sizes(holdout.model))
        return 0, (0, 0)

    def _masks_bytes(self, ctx: StageContext, size: tuple[int, int]) -> int:
        """Upper bytes of eval/masks/: a greyscale PNG of ``size`` per truth label image (data_synth scenes)."""
        spec = ctx.source.spec
        if ctx.source.holdout.source != "input" or spec.test_labels is None or not spec.non_collaborative_ids:
            return 0
        labels = len(list(spec.test_labels.glob("*.png"))) if spec.test_labels.is_dir() else 0
        return labels * sizes.png_bytes(*size, 1)

    def needs(self, ctx: StageContext) -> str | None:
        if self._reference(ctx) is None and self._held_out(ctx) is None:
            return "nothing to compare with: no reference cloud and no held-out photos (see --holdout)"
        return None

    def run(self, ctx: StageContext) -> EvalResult:
        """Every product measured (:meth:`_measure`). With ``memory_limit_mb`` and a reference cloud, the reference
        is read in chunks and spooled once into eval/ (:func:`eval.geometry_stream.spool_reference`, removed after)
        for every product's streamed C2C and per-material scores, and the limit and peak memory are recorded."""
        opts: EvalStageOptions = ctx.options(self)
        _copy_accuracy(ctx.layout)
        reference = self._reference(ctx)
        if opts.memory_limit_mb is None or reference is None:
            return self._measure(ctx, None)
        import tempfile

        from eval.c2c_stream import plan_c2c_memory
        from eval.geometry_stream import reference_source, spool_reference
        from hybridsplat.manifest import PeakMemory

        plan = plan_c2c_memory(opts.memory_limit_mb)
        ctx.layout.eval_dir.mkdir(parents=True, exist_ok=True)
        # the stage's own peak (sampled resident memory), not ru_maxrss, which keeps the earlier stages' peaks
        with PeakMemory() as memory:
            with tempfile.TemporaryDirectory(prefix="hybridsplat_eval_reference_", dir=ctx.layout.eval_dir) as tmp:
                source = reference_source(reference, plan.chunk)
                result = self._measure(ctx, spool_reference(source, tmp, plan.chunk))
        return replace(result, memory_limit_mb=opts.memory_limit_mb, peak_rss_mb=memory.peak_mb)

    def _measure(self, ctx: StageContext, spooled: Any) -> EvalResult:
        """The stage's work; ``spooled``: the reference as chunks (a :class:`core.io.point_stream.PointSource`) with
        a memory limit, None without."""
        from core.io.json_io import write_json_atomic
        from eval.cache import files_in
        from eval.evaluate import evaluate_product
        from eval.geometry import GeometryOptions
        from eval.metrics_io import read_metrics, record_product

        opts: EvalStageOptions = ctx.options(self)
        layout, spec = ctx.layout, ctx.source.spec
        reference = self._reference(ctx)
        tau = opts.tau_m if opts.tau_m is not None else (opts.tau_gsd * spec.gsd_m if spec.gsd_m else None)
        images = self._image_inputs(ctx)
        lpips_model = _lpips_or_none(opts.lpips_weights or None)
        products = self._products(ctx)
        cache = self._cache(ctx, reference, tau, images, lpips_model) if opts.cache else None
        renderer = None
        if images is not None:
            from fusion.render.api import resolve_backend

            renderer = resolve_backend("auto").value  # what rendered the held-out views (the report says)
        headlines: dict[str, ProductHeadline] = {}
        measured: dict[str, tuple[Any, Any]] = {}
        stored_tables: dict[str, Any] = {}
        keys: dict[str, str] = {}
        written: dict[str, list[str]] = {}
        for done, (name, source) in enumerate(products.items()):
            ctx.progress("products", done, len(products))
            if isinstance(source, str):
                evaluate_product(layout.metrics_json, name, skip_reason=source)
                continue
            if cache is not None:
                keys[name] = cache.key(name, [ctx.content_hash(f) for f in source.files])
                stored = cache.restore(keys[name], layout.eval_dir)
                if stored is not None:
                    record_product(layout.metrics_json, name, stored.metrics)
                    stored_tables[name] = stored.per_material  # {"rows": ..., "sigma_calibration": ...}
                    headlines[name] = _headline(stored.metrics)
                    continue
            before = files_in(layout.eval_dir)
            cloud, gaussians = source.load()
            result = evaluate_product(
                layout.metrics_json,
                name,
                cloud=cloud if reference is not None else None,
                reference=spooled if spooled is not None else reference,
                gaussians=gaussians,
                images=images,
                geometry=GeometryOptions(tau=tau, memory_limit_mb=opts.memory_limit_mb),
                lpips_model=lpips_model,
            )
            after = files_in(layout.eval_dir)
            written[name] = [r for r, t in after.items() if before.get(r) != t and r != layout.metrics_json.name]
            measured[name] = (cloud, gaussians)
            headlines[name] = _headline(result.as_dict())
        ctx.progress("products", len(products), len(products))
        per_material = self._per_material(
            ctx, measured, stored_tables, spooled if spooled is not None else reference, tau, images
        )
        if per_material is not None:
            write_json_atomic(layout.per_material_json, per_material)
        if cache is not None:
            entries = read_metrics(layout.metrics_json)["products"]
            tables = per_material["products"] if per_material is not None else {}
            calibrations = per_material.get("sigma_calibration", {}) if per_material is not None else {}
            for name in measured:
                stored_entry = {"rows": tables.get(name), "sigma_calibration": calibrations.get(name)}
                cache.store(keys[name], layout.eval_dir, written[name], entries[name], stored_entry)
        return EvalResult(
            lpips=lpips_model is not None,
            views=len(images.views) if images else 0,
            renderer=renderer,
            products=headlines,
            reused=len(stored_tables) or None,  # the products restored from the cache
            per_material=len(per_material["materials"]) if per_material is not None else None,
        )

    def _image_inputs(self, ctx: StageContext) -> Any:
        """The held-out views to render (an :class:`eval.evaluate.ImageInputs`), None without any: their cameras,
        photos and (a data_synth scene's own test views) the masks of their true non-collaborative materials."""
        from eval.evaluate import ImageInputs

        held_out = self._held_out(ctx)
        if held_out is None:
            return None
        cameras, _ = read_model_at(held_out.model, held_out.origin)
        views = [v for v in cameras if held_out.names is None or v.name in held_out.names]
        masks = self._truth_masks(ctx) if held_out.names is None else None
        return ImageInputs(cameras, views, held_out.photos, masks)

    def _cache(self, ctx: StageContext, reference: Path | None, tau: float | None, images: Any, lpips: Any) -> Any:
        """The project's store of measurements, keyed by what every product's measurement depends on."""
        from eval.cache import ProductCache
        from eval.lpips import find_weights
        from hybridsplat.manifest import hash_path, package_versions

        opts: EvalStageOptions = ctx.options(self)
        settings: dict[str, Any] = {
            "tau": tau,
            "reference": ctx.content_hash(reference) if reference is not None else None,
            "lpips": hash_path(find_weights(opts.lpips_weights or None)) if lpips is not None else None,
            "versions": package_versions(),
        }
        if images is not None:
            from fusion.render.api import resolve_backend

            settings["renderer"] = resolve_backend("auto").value  # gsplat on a GPU, the CPU rasteriser elsewhere
            settings["views"] = [[v.name, hash_path(Path(images.photos) / v.name)] for v in images.views]
            settings["poses"] = [[v.quat_wxyz.tolist(), v.translation.tolist()] for v in images.views]
            intrinsics = (images.cameras.camera_of(v) for v in images.views)
            settings["intrinsics"] = [[c.model.name, c.width, c.height, c.params.tolist()] for c in intrinsics]
            settings["masks"] = hash_path(images.masks) if images.masks is not None else None
        return ProductCache(ctx.layout.eval_cache_dir, settings)

    def _products(self, ctx: StageContext) -> dict[str, ProductSource | str]:
        """name → the product to measure, or the reason it is not measured (recorded as skipped).

        The splats alone are measured for geometry only (their renders without the MVS context mean nothing). The
        baseline's checkpoints (splats/baseline_checkpoints/baseline_<step>.ply) are products ``baseline_<step>``.
        """
        from core.io.gaussian_ply import read_gaussian_ply
        from fusion.export import gaussians_to_points
        from recon.workspace import read_fused

        def splat_product(path: Path) -> ProductSource:
            def load() -> tuple[Any, Any]:
                gaussians = read_gaussian_ply(path)
                return gaussians_to_points(gaussians), gaussians

            return ProductSource((path,), load)

        layout = ctx.layout
        products: dict[str, ProductSource | str] = {
            "mvs": ProductSource(
                (layout.fused_ply, layout.mvs_gaussians),
                lambda: (read_fused(layout.dense), read_gaussian_ply(layout.mvs_gaussians)),
            ),
        }
        if layout.baseline_splats.is_file():
            products["baseline"] = splat_product(layout.baseline_splats)
        else:
            products["baseline"] = "not trained: the whole-scene baseline is off (run --baseline to compare with it)"
        if layout.baseline_checkpoints_dir.is_dir():
            for path in sorted(layout.baseline_checkpoints_dir.glob("baseline_*.ply")):
                products[f"baseline_{int(path.stem.split('_')[1])}"] = splat_product(path)
        if layout.splats_export.is_file():
            products["splats"] = ProductSource(
                (layout.splats_export,), lambda: (gaussians_to_points(read_gaussian_ply(layout.splats_export)), None)
            )
        else:
            products["splats"] = "no trained splats: the train stage was skipped or had nothing to train"
        products["merged"] = ProductSource(
            (layout.merged_points_ply, layout.merged_ply),
            lambda: (layout.merged_points_ply, read_gaussian_ply(layout.merged_ply)),
        )
        products[WITHOUT_BACKGROUND] = ProductSource(
            (layout.merged_points_ply, layout.merged_ply),
            lambda: (layout.merged_points_ply, _without_background(layout.merged_ply)),
        )
        layers = [p for p in (layout.cleaned_splats, layout.background_splats) if p.is_file()]
        products[UNREFINED] = ProductSource(
            (layout.merged_points_ply, layout.merged_ply, layout.mvs_gaussians, *layers),
            lambda: (layout.merged_points_ply, unrefined_layers(layout, read_gaussian_ply(layout.merged_ply))),
        )
        products[FILTERED_MVS] = ProductSource(
            (layout.merged_points_ply, layout.merged_ply, layout.mvs_gaussians),
            lambda: _filtered_mvs(layout.merged_points_ply, layout.merged_ply, layout.mvs_gaussians),
        )
        return products

    def _per_material(self, ctx: StageContext, products, stored, reference, tau, images) -> dict[str, Any] | None:
        """Accuracy, completeness and held-out PSNR per ground-truth material (data_synth scenes), or None.

        products: name → (cloud, Gaussians) measured now; stored: name → ``{"rows": table, "sigma_calibration":
        table or None}`` restored from the cache."""
        from core.io import read_point_cloud
        from eval.per_material import as_table, psnr_per_material

        spec = ctx.source.spec
        if reference is None or spec.description is None or not spec.description.materials or tau is None:
            return None
        opts: EvalStageOptions = ctx.options(self)
        ref = _MaterialReference(reference, opts.memory_limit_mb, ctx.layout.eval_dir)
        if not ref.has_materials():
            return None
        geometry_per_material = ref.geometry
        names = {m.id: m.name for m in spec.description.materials}
        kinds = {m.name: {"kind": m.kind, "collaborative": m.collaborative} for m in spec.description.materials}
        labels_dir = spec.test_labels
        result: dict[str, Any] = {"tau_m": tau, "materials": kinds, "products": {}}
        for name, (cloud, gaussians) in products.items():
            if not hasattr(cloud, "world_positions"):
                cloud = read_point_cloud(cloud)
            geometry = geometry_per_material(cloud.world_positions, tau)
            pixels = {}
            if gaussians is not None and images is not None and labels_dir is not None:
                pixels = psnr_per_material(_label_pairs(gaussians, images, labels_dir))
            result["products"][name] = as_table(geometry, pixels, names)
            calibration = _sigma_calibration(cloud, ref, names)
            if calibration is not None:
                result.setdefault("sigma_calibration", {})[name] = calibration
        for name, entry in stored.items():
            if entry is not None and entry.get("rows") is not None:
                result["products"][name] = entry["rows"]
            if entry is not None and entry.get("sigma_calibration") is not None:
                result.setdefault("sigma_calibration", {})[name] = entry["sigma_calibration"]
        mesh_points = _mesh_points(ctx.layout.mesh_path("ply"), tau)
        if mesh_points is not None:  # the mesh stage's product: geometry only, from points sampled on its surface
            geometry = geometry_per_material(mesh_points, tau)
            result["products"]["mesh"] = as_table(geometry, {}, names)
        return result

    def _truth_masks(self, ctx: StageContext) -> Path | None:
        """Masks of the true non-collaborative materials of the held-out views (data_synth), or None."""
        from core.io.images import read_image, write_image

        spec = ctx.source.spec
        if spec.test_labels is None or not spec.non_collaborative_ids:
            return None
        out = ctx.layout.eval_masks_dir
        for label_path in sorted(spec.test_labels.glob("*.png")):
            labels = read_image(label_path, grayscale=True)
            mask = np.isin(labels, np.asarray(spec.non_collaborative_ids, dtype=labels.dtype)).astype(np.uint8) * 255
            write_image(out / label_path.name, mask)
        return out

    def report_section(self, result: EvalResult) -> ReportSection | None:
        """With ``memory_limit_mb``: how the geometry was measured, the limit and the peak memory; else None."""
        if result.memory_limit_mb is None:
            return None
        line = (
            f"The C2C distances and the per-material scores read the reference cloud in chunks and compared it cell "
            f"by cell within --memory-limit {result.memory_limit_mb:g} MiB (peak resident memory of the run "
            f"{result.peak_rss_mb or 0:.0f} MiB; the products themselves are held in memory). The figures are those "
            "of the in-memory evaluation; the reverse mean, std and RMSE agree to float rounding (sums by chunks)."
        )
        return ReportSection("Evaluation with bounded memory", (line,))

    def summary(self, result: EvalResult) -> str:
        parts = [f"{result.reused} unchanged product(s) reused"] if result.reused else []
        if result.memory_limit_mb is not None:
            parts.append(f"C2C streamed within {result.memory_limit_mb:g} MiB (peak {result.peak_rss_mb or 0:.0f} MiB)")
        for name in ("mvs", "baseline", "merged"):
            headline = result.products.get(name)
            if headline is None:
                continue
            if headline.c2c_mean_m is not None:
                parts.append(f"{name} C2C mean {headline.c2c_mean_m:.3g} m")
            if headline.psnr is not None:
                lpips = f" LPIPS {headline.lpips:.3f}" if headline.lpips is not None else ""
                parts.append(f"{name} PSNR {headline.psnr:.2f} dB{lpips}")
        return ", ".join(parts)


class _MaterialReference:
    """The reference cloud of the per-material scores: read whole (no memory limit; ``reference`` a path or a
    :class:`core.pointcloud.PointCloud`) or as
    chunks (``reference`` a :class:`core.io.point_stream.PointSource`;
    :func:`eval.geometry_stream.geometry_per_material_streamed`, temporary files in ``work_dir``)."""

    def __init__(self, reference: Any, memory_limit_mb: float | None, work_dir: Path) -> None:
        self.work_dir, self.cloud, self.source, self.plan = work_dir, None, None, None
        if memory_limit_mb is None:
            from core.io import read_point_cloud
            from core.pointcloud import PointCloud

            self.cloud = reference if isinstance(reference, PointCloud) else read_point_cloud(reference)
        else:
            from eval.c2c_stream import plan_c2c_memory
            from eval.geometry_stream import reference_source

            self.plan = plan_c2c_memory(memory_limit_mb)
            is_path = isinstance(reference, (str, Path))
            self.source = reference_source(reference, self.plan.chunk) if is_path else reference

    def has_materials(self) -> bool:
        """Whether the reference has a per-point ``material`` field (its first chunk, when streamed)."""
        if self.cloud is not None:
            return "material" in self.cloud.fields
        chunks = iter(self.source.chunks())  # type: ignore[union-attr]
        first = next(chunks, None)
        getattr(chunks, "close", lambda: None)()
        return first is not None and "material" in first.fields

    def geometry(self, compared_world: np.ndarray, tau: float) -> dict[int, Any]:
        """Accuracy and completeness at ``tau`` (metres) per material of (N, 3) float64 world points."""
        from eval.per_material import geometry_per_material

        if self.cloud is not None:
            return geometry_per_material(compared_world, self.cloud.world_positions, self.cloud.fields["material"], tau)
        from eval.geometry_stream import geometry_per_material_streamed

        self.work_dir.mkdir(parents=True, exist_ok=True)
        return geometry_per_material_streamed(compared_world, self.source, tau, self.plan, self.work_dir)  # type: ignore[arg-type]


def _sigma_calibration(cloud: Any, ref: Any, names: dict[int, str]) -> dict[str, Any] | None:
    """The σ calibration table (:func:`eval.sigma_calibration.calibration_per_material`) of the product's points that
    carry a σ (a ``sigma`` field, metres; a σ of 0 or not finite is no estimate and leaves its point out), when any
    does and the reference is held in memory (not under ``memory_limit_mb``); else None, so that the tables of a
    product without σ are as before."""
    from eval.sigma_calibration import calibration_per_material

    sigma = cloud.fields.get("sigma")
    if sigma is None or ref.cloud is None:
        return None
    sigma = np.asarray(sigma, np.float64)
    carried = np.isfinite(sigma) & (sigma > 0)
    if not carried.any():
        return None
    reference = ref.cloud
    return calibration_per_material(cloud.world_positions[carried], sigma[carried],
                                    reference.world_positions, reference.fields["material"], names)  # fmt: skip


def _clouds(ctx: StageContext) -> list[tuple[sizes.PlyVertices, bool]]:
    """The products the stage measures, as the header of the file their points come from, and whether they are
    rendered at the held-out views (the splats alone are not)."""
    layout = ctx.layout
    checkpoints = sorted(layout.baseline_checkpoints_dir.glob("baseline_*.ply"))
    files = [(layout.fused_ply, True), (layout.baseline_splats, True), *((p, True) for p in checkpoints),
             (layout.splats_export, False), (layout.merged_points_ply, True),
             (layout.merged_points_ply, True), (layout.merged_points_ply, True)]  # fmt: skip  # the controls
    return [(sizes.ply_vertices(path), renders) for path, renders in files if path.is_file()]


def _product_bytes(cloud: sizes.PlyVertices, renders: bool, geometry: bool, views: int, size: tuple[int, int]) -> int:
    """Upper bytes the measurement of one product writes (see :meth:`EvalStage.expected_bytes`)."""
    total = 16 * sizes.KIB + sizes.KIB * views
    if geometry:
        fields = len(cloud.extras) + 8
        total += sizes.point_ply_bytes(cloud.count, fields) + sizes.las_bytes(cloud.count, fields)
        total += sizes.svg_bytes(_HISTOGRAM_BINS)
        total += sizes.sparse_png_bytes(_PREVIEW_WIDTH, 4 * _PREVIEW_WIDTH, cloud.count)
    if renders:
        width, height = size
        total += min(views, _PANELS) * sizes.png_bytes(3 * width + 8, height, 3)
    return total


def _headline(entry: dict[str, Any]) -> ProductHeadline:
    """The stage's headline figures of one product (C2C mean, whole-image PSNR and LPIPS) from its metrics entry
    (eval/metrics.json's, :mod:`eval.metrics_io`)."""
    c2c, images = entry.get("c2c"), entry.get("images")
    full = (images.get("full") or {}) if images is not None else {}
    return ProductHeadline(c2c.get("mean") if c2c is not None else None, full.get("psnr"), full.get("lpips"))


def _mesh_points(path: Path, tau: float, max_points: int = 2_000_000) -> np.ndarray | None:
    """(N, 3) float64 world points uniform on the project's mesh, about τ/3 apart (at most ``max_points``; seeded),
    or None without a mesh."""
    from fusion.mesh import read_mesh

    if not path.is_file():
        return None
    mesh = read_mesh(path)
    n = int(min(max_points, max(10_000, mesh.triangle_areas().sum() / (tau / 3) ** 2)))
    return mesh.sample_surface(n, seed=0) + mesh.origin


def _label_pairs(gaussians, images, labels_dir: Path):
    """(rendered, photo, material labels) of every held-out view that has a label image."""
    from core.io.images import read_image
    from eval.render_eval import render_view

    for view in images.views:
        label_path = labels_dir / f"{Path(view.name).stem}.png"
        if not label_path.is_file():
            continue
        photo = read_image(Path(images.photos) / view.name)
        yield render_view(gaussians, images.cameras, view), photo, read_image(label_path, grayscale=True)


def _lpips_or_none(weights: str | None) -> object | None:
    """The LPIPS model when weights can be found, else None (LPIPS left out, said once as a warning)."""
    import warnings

    from core.errors import HybridSplatError
    from eval.lpips import LPIPS

    try:
        return LPIPS.from_path(weights)
    except HybridSplatError as err:
        warnings.warn(f"LPIPS left out of the image metrics: {err.one_line()}", stacklevel=2)
        return None


def _copy_accuracy(layout) -> None:
    """The survey control's accuracy statement (control stage) into eval/, beside the other measurements."""
    if layout.control_accuracy.is_file():
        from core.io.atomic import write_text_atomic

        write_text_atomic(layout.accuracy_json, layout.control_accuracy.read_text(encoding="utf-8"))
