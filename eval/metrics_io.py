"""Typed per-product evaluation results and the writer/reader of ``PROJECT/eval/metrics.json``.

The pipeline calls :func:`update_metrics` once per product (``mvs``, ``splats``, ``merged``,
``baseline_gs``); ``hybridsplat report`` reads the file back with :func:`read_metrics`. Layout::

    {"schema": "hybridsplat.metrics/1",
     "products": {"<name>": {"skipped": false, "reason": null,
                             "c2c": {count, mean, std, median, rmse, p90, p95, p99, min, max, max_dist,
                                     outlier_count, outlier_share, tau, completeness, precision, recall, fscore,
                                     method, reference, reverse: {...}, per_class: {"<class>": {...}},
                                     histogram: {edges, counts}, registration: {...} | null, files: {...}},
                             "images": {"full": {views, mse, psnr, ssim, ms_ssim, lpips, delta_e, std: {...}},
                                        "masked": {...} | null,
                                        "per_view": [{view, mask_share, full: {...}, masked: {...} | null,
                                                      files: {...}}]}}}}

Distances are metres, image metrics use colours in [0, 1] (see :mod:`eval.image_metrics`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

from core.errors import FormatError, InputFileError
from core.io.json_io import read_json, to_jsonable, write_json_atomic
from eval.c2c import C2CResult, DistanceStats, ThresholdScores, histogram
from eval.image_metrics import ImageScores, ScoreSummary, summarize

SCHEMA = "hybridsplat.metrics/1"
PRODUCTS = ("mvs", "baseline", "splats", "merged")


@dataclass(frozen=True)
class C2CSummary:
    """Geometry metrics of one product (compared cloud against a reference cloud or mesh)."""

    stats: DistanceStats
    method: str = "c2c"  # "c2c" (cloud reference) or "c2m" (mesh reference)
    reference: str | None = None
    reverse: DistanceStats | None = None
    scores: ThresholdScores | None = None
    per_class: Mapping[int, DistanceStats] = field(default_factory=dict)
    histogram_edges: tuple[float, ...] = ()
    histogram_counts: tuple[int, ...] = ()
    registration: Mapping[str, Any] | None = None
    files: Mapping[str, str] = field(default_factory=dict)

    @classmethod
    def from_result(
        cls,
        result: C2CResult,
        method: str = "c2c",
        reference: str | None = None,
        registration: Mapping[str, Any] | None = None,
        files: Mapping[str, str] | None = None,
        bins: int = 50,
    ) -> C2CSummary:
        """Summarise a :class:`C2CResult` (or a C2M result with the same fields), histogram included."""
        d = result.distances
        upper = result.stats.max_dist if result.stats.max_dist is not None else None
        edges, counts = histogram(d, bins=bins, upper=upper)
        return cls(
            stats=result.stats,
            method=method,
            reference=reference,
            reverse=getattr(result, "reverse", None),
            scores=getattr(result, "scores", None),
            per_class=dict(result.per_class),
            histogram_edges=tuple(float(e) for e in edges),
            histogram_counts=tuple(int(c) for c in counts),
            registration=registration,
            files=dict(files or {}),
        )

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = self.stats.as_dict()
        s = self.scores
        out.update(
            tau=None if s is None else s.tau,
            completeness=None if s is None else s.completeness,
            precision=None if s is None else s.precision,
            recall=None if s is None else s.recall,
            fscore=None if s is None else s.fscore,
            method=self.method,
            reference=self.reference,
            reverse=None if self.reverse is None else self.reverse.as_dict(),
            per_class={str(k): v.as_dict() for k, v in sorted(self.per_class.items())},
            histogram={"edges": list(self.histogram_edges), "counts": list(self.histogram_counts)},
            registration=None if self.registration is None else dict(self.registration),
            files=dict(self.files),
        )
        return out


@dataclass(frozen=True)
class ViewScores:
    """Image metrics of one held-out view: whole image, and inside the mask when one exists."""

    view: str
    full: ImageScores
    masked: ImageScores | None = None
    mask_share: float | None = None  # share of pixels inside the mask
    files: Mapping[str, str] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {
            "view": self.view,
            "mask_share": self.mask_share,
            "full": self.full.as_dict(),
            "masked": None if self.masked is None else self.masked.as_dict(),
            "files": dict(self.files),
        }


@dataclass(frozen=True)
class ImageEval:
    """Per-view image metrics of one product and their aggregates (mean, std over views)."""

    per_view: Sequence[ViewScores]
    full: ScoreSummary | None
    masked: ScoreSummary | None

    @classmethod
    def from_views(cls, views: Sequence[ViewScores]) -> ImageEval:
        masked = [v.masked for v in views if v.masked is not None]
        return cls(list(views), summarize([v.full for v in views]), summarize(masked))

    def as_dict(self) -> dict[str, Any]:
        return {
            "full": None if self.full is None else self.full.as_dict(),
            "masked": None if self.masked is None else self.masked.as_dict(),
            "per_view": [v.as_dict() for v in self.per_view],
        }


@dataclass(frozen=True)
class ProductMetrics:
    """Everything measured for one product; ``skipped`` with a ``reason`` when the product does not exist."""

    c2c: C2CSummary | None = None
    images: ImageEval | None = None
    skipped: bool = False
    reason: str | None = None

    @classmethod
    def skip(cls, reason: str) -> ProductMetrics:
        return cls(skipped=True, reason=reason)

    def as_dict(self) -> dict[str, Any]:
        return {
            "skipped": self.skipped,
            "reason": self.reason,
            "c2c": None if self.c2c is None else self.c2c.as_dict(),
            "images": None if self.images is None else self.images.as_dict(),
        }


def to_json_safe(value: Any) -> Any:
    """JSON-safe copy (numpy to Python, non-finite floats to None); alias of :func:`core.io.json_io.to_jsonable`."""
    return to_jsonable(value)


def write_metrics(path: str | PathLike[str], products: Mapping[str, ProductMetrics]) -> Path:
    """Write (replace) the metrics file ``path`` with ``products``; atomic. Returns the path."""
    payload = {"schema": SCHEMA, "products": {name: p.as_dict() for name, p in products.items()}}
    return write_json_atomic(path, payload)


def update_metrics(path: str | PathLike[str], name: str, product: ProductMetrics) -> Path:
    """Add or replace one product in the metrics file ``path`` (other products are kept); atomic."""
    path = Path(path)
    payload = read_metrics(path) if path.exists() else {"schema": SCHEMA, "products": {}}
    payload["products"][name] = product.as_dict()
    return write_json_atomic(path, payload)


def record_product(path: str | PathLike[str], name: str, entry: Mapping[str, Any]) -> Path:
    """Add or replace product ``name`` with an entry already in the file's layout (a stored measurement, see
    :mod:`eval.cache`), checked like :func:`read_metrics` checks it; atomic."""
    path = Path(path)
    _check_product(entry, f"products.{name}", path)
    payload = read_metrics(path) if path.exists() else {"schema": SCHEMA, "products": {}}
    payload["products"][name] = dict(entry)
    return write_json_atomic(path, payload)


def read_metrics(path: str | PathLike[str]) -> dict[str, Any]:
    """Read a metrics file as plain JSON data, checked.

    Every value the report uses is checked for its JSON type (numbers or null for metrics, booleans,
    strings, objects and lists where the layout in this module's docstring has them); a wrong type raises
    :class:`FormatError` naming the file and the key path (e.g. ``products.mvs.c2c.mean``).
    """
    p = Path(path)
    if not p.exists():
        raise InputFileError("metrics file does not exist", p)
    payload = read_json(p)
    if not isinstance(payload, dict) or not isinstance(payload.get("products"), dict):
        raise FormatError("expected an object with a 'products' object", p)
    for name, product in payload["products"].items():
        _check_product(product, f"products.{name}", p)
    return payload


_NUMBER = (int, float)


def _fail(where: str, expected: str, value: Any, path: Path) -> None:
    raise FormatError(f"{where} must be {expected}, found {type(value).__name__} {str(value)[:40]!r}", path)


def _check_type(obj: Mapping[str, Any], key: str, types: tuple[type, ...], where: str, path: Path) -> None:
    """``obj[key]`` must be missing, null or one of ``types`` (bool is not a number)."""
    v = obj.get(key)
    if v is None:
        return
    if isinstance(v, bool) and bool not in types:
        _fail(f"{where}.{key}", "/".join(t.__name__ for t in types), v, path)
    if not isinstance(v, types):
        _fail(f"{where}.{key}", "/".join(t.__name__ for t in types), v, path)


def _check_stats(stats: Any, where: str, path: Path) -> None:
    if stats is None:
        return
    if not isinstance(stats, dict):
        _fail(where, "an object or null", stats, path)
    for key, value in stats.items():
        if key in ("method", "reference"):
            _check_type(stats, key, (str,), where, path)
        elif key in ("reverse",):
            _check_stats(value, f"{where}.reverse", path)
        elif key == "per_class":
            if value is not None and not isinstance(value, dict):
                _fail(f"{where}.per_class", "an object", value, path)
            for cls, block in (value or {}).items():
                _check_stats(block, f"{where}.per_class.{cls}", path)
        elif key in ("registration", "files", "histogram"):
            if value is not None and not isinstance(value, dict):
                _fail(f"{where}.{key}", "an object or null", value, path)
            if key == "histogram" and value is not None:
                for part in ("edges", "counts"):
                    seq = value.get(part, [])
                    if not isinstance(seq, list) or not all(
                        isinstance(x, _NUMBER) and not isinstance(x, bool) for x in seq
                    ):
                        _fail(f"{where}.histogram.{part}", "a list of numbers", seq, path)
        elif key == "std" and isinstance(value, dict):
            _check_stats(value, f"{where}.std", path)
        else:
            _check_type(stats, key, _NUMBER, where, path)


def _check_product(product: Any, where: str, path: Path) -> None:
    if not isinstance(product, dict):
        _fail(where, "an object", product, path)
    _check_type(product, "skipped", (bool,), where, path)
    _check_type(product, "reason", (str,), where, path)
    _check_stats(product.get("c2c"), f"{where}.c2c", path)
    images = product.get("images")
    if images is None:
        return
    if not isinstance(images, dict):
        _fail(f"{where}.images", "an object or null", images, path)
    for part in ("full", "masked"):
        _check_stats(images.get(part), f"{where}.images.{part}", path)
    views = images.get("per_view", [])
    if not isinstance(views, list):
        _fail(f"{where}.images.per_view", "a list", views, path)
    for i, view in enumerate(views):
        vw = f"{where}.images.per_view[{i}]"
        if not isinstance(view, dict):
            _fail(vw, "an object", view, path)
        _check_type(view, "view", (str,), vw, path)
        _check_type(view, "mask_share", _NUMBER, vw, path)
        for part in ("full", "masked"):
            _check_stats(view.get(part), f"{vw}.{part}", path)
