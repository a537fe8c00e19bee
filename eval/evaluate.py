"""One call per product for the pipeline: geometry and image metrics, recorded in ``PROJECT/eval/metrics.json``.

The pipeline's eval stage calls :func:`evaluate_product` for ``mvs``, ``splats``, ``merged`` (and
``baseline_gs``), then ``eval.report.write_report``. A product without inputs is recorded as
skipped with the reason, never left out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

from core.cameras import Cameras, View
from core.gaussians import GaussianSet
from core.pointcloud import PointCloud
from eval.geometry import GeometryOptions, evaluate_geometry
from eval.metrics_io import ProductMetrics, update_metrics


@dataclass(frozen=True)
class ImageInputs:
    """Held-out views to render and compare: photos ``photos/<view.name>``, masks ``masks/<stem>.png`` (optional)."""

    cameras: Cameras
    views: Sequence[View]
    photos: Path
    masks: Path | None = None


def evaluate_product(
    metrics_file: str | PathLike[str],
    name: str,
    *,
    cloud: PointCloud | str | PathLike[str] | None = None,
    reference: PointCloud | str | PathLike[str] | None = None,
    gaussians: GaussianSet | None = None,
    images: ImageInputs | None = None,
    geometry: GeometryOptions = GeometryOptions(),
    lpips_model: object | None = None,
    skip_reason: str | None = None,
) -> ProductMetrics:
    """Measure product ``name`` and record it in the metrics file ``metrics_file`` (other products kept).

    ``cloud`` + ``reference`` give C2C/C2M (distance clouds, plots and renders go next to ``metrics_file``);
    ``gaussians`` + ``images`` give
    image metrics (``lpips_model``: an :class:`eval.lpips.LPIPS`, or None to leave LPIPS out). With
    ``skip_reason``, or when neither part has inputs, the product is recorded as skipped.
    """
    eval_dir = Path(metrics_file).parent
    if skip_reason is None and (cloud is None or reference is None) and (gaussians is None or images is None):
        skip_reason = "nothing to measure: no cloud with a reference and no Gaussian set with held-out views"
    if skip_reason is not None:
        product = ProductMetrics.skip(skip_reason)
    else:
        c2c = None
        if cloud is not None and reference is not None:
            c2c = evaluate_geometry(cloud, reference, eval_dir, name, geometry)
        image_eval = None
        if gaussians is not None and images is not None:
            from eval.render_eval import evaluate_gaussians

            image_eval = evaluate_gaussians(
                gaussians, images.cameras, images.views, images.photos, images.masks, lpips_model, eval_dir, name
            )
        product = ProductMetrics(c2c=c2c, images=image_eval)
    update_metrics(metrics_file, name, product)
    return product
