"""config.toml of hybridsplat 0.2 → 0.3: the stage tables' old flat keys mapped to where the options live now.

0.3 made each stage's options the domain's own options dataclass (docs/migration.md), so some keys moved
into sub-tables (``[train] iterations`` → ``[train.training] iterations``), and "a negative value turns a check
off" became ``"none"``. :func:`migrate_table` rewrites an old stage table into the new form; it is applied to
every table read from config.toml and to the options recorded in an old manifest, so that a finished 0.2 project
loads, and its stages stay up to date when their effective options did not change.

A key that is known under the new layout is left as it is: a table already in the new form passes unchanged.

Options (and single values of options) that a version removed are listed in :data:`REMOVED`: a table that still
sets one is refused by :func:`hybridsplat.options.options_from_table` with one :class:`core.errors.ConfigError`
naming the key, the version and why (:func:`removed_setting`), whether it comes from config.toml, a manifest or the
command line, instead of a traceback or a silently ignored value.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

NONE = "none"


def _off_if_negative(value: Any) -> Any:
    return NONE if isinstance(value, (int, float)) and not isinstance(value, bool) and value < 0 else value


def _off_if_zero(value: Any) -> Any:
    return NONE if value == 0 and not isinstance(value, bool) else value


def _none_as_word(value: Any) -> Any:
    """An old manifest recorded None as JSON null; a table spells it ``"none"``."""
    return NONE if value is None else value


def _put(table: dict[str, Any], path: str, value: Any) -> None:
    """``table[path] = value`` for a dotted path; a table value is merged into what is there already."""
    node = table
    parts = path.split(".")
    for part in parts[:-1]:
        node = node.setdefault(part, {})
    if isinstance(value, dict) and isinstance(node.get(parts[-1]), dict):
        for key, item in value.items():
            _put(node[parts[-1]], key, item)
    else:
        node[parts[-1]] = value


def _same(value: Any) -> Any:
    return value


#: the trainer's keys of 0.2's [train] and [baseline] tables → their place under ``training``
_TRAINING: dict[str, tuple[str, Callable[[Any], Any]]] = {
    "iterations": ("training.iterations", _same),
    "downscale": ("training.downscale", _same),
    "cap": ("training.strategy.cap", _same),
    "sh_degree": ("training.sh_degree", _same),
    "refine_start": ("training.strategy.refine_start", _same),
    "refine_until": ("training.refine_until", _same),
}

#: per stage: old key → (new dotted path, value transform)
_MOVED: dict[str, dict[str, tuple[str, Callable[[Any], Any]]]] = {
    "sfm": {"align_threshold_m": ("align_threshold_m", _off_if_zero)},
    "mvs": {"threads": ("num_threads", _off_if_zero), "min_num_pixels": ("fusion.min_num_pixels", _same)},
    "train": {
        **_TRAINING,
        "flat": ("training.flat", _same),
        "photometric": ("training.photometric", _same),
        "lpips_weight": ("training.lpips_weight", _same),
        "lpips_start": ("training.lpips_start", _same),
        "hard_views": ("training.hard_views", lambda v: {} if v else NONE),
        "rays_per_view": ("init.rays_per_view", _same),
    },
    "clean": {
        name: (name, _off_if_negative)
        for name in ("min_opacity", "max_scale_scene", "max_scale_spacing", "cluster_eps_spacing")
    },
    "merge": {
        "points_min_opacity": ("points.min_opacity", _off_if_negative),
        "points_max_thickness_spacing": ("points.max_thickness_spacing", _off_if_negative),
        "points_max_extent_spacing": ("points.max_extent_spacing", _off_if_negative),
        "points_min_views": ("points.min_views", lambda v: max(int(v), 0)),
        "points_min_mask_share": ("points.min_mask_share", _off_if_negative),
        "points_max_rim_spacing": ("points.max_rim_spacing", _off_if_negative),
        "points_needs_mvs": ("needs_mvs", _same),
        "points_needs_mvs_max_rim_spacing": ("needs_mvs_max_rim_spacing", _off_if_negative),
        "points_needs_mvs_classes": ("needs_mvs_classes", _same),
    },
    "mesh": {
        "source": ("mesh.source", _same),
        "snapshots": ("mesh.use_snapshots", _same),
        "decimator": ("mesh.decimate.method", _same),
    },
    "baseline": _TRAINING,
    "eval": {"tau_m": ("tau_m", _off_if_zero)},
}

#: the train stage's five prior weights of 0.2 became one optional table, ``[train.training.priors]``
_OLD_PRIOR_KEYS = ("depth_prior", "normal_prior", "prior_border_px", "prior_edge_scale", "prior_hull_share")


def _train_priors(old: dict[str, Any]) -> Any:
    depth, normal = float(old.get("depth_prior", 0.0)), float(old.get("normal_prior", 0.0))
    if depth <= 0 and normal <= 0:
        return NONE
    border, edge, hull = (
        old.get("prior_border_px", 8.0),
        old.get("prior_edge_scale", 0.1),
        old.get("prior_hull_share", 0.8),
    )
    return {
        "depth_weight": max(depth, 0.0),
        "normal_weight": max(normal, 0.0),
        "border_px": border if border > 0 else NONE,
        "edge_scale": edge if edge > 0 else NONE,
        "hull_share": hull if hull >= 0 else NONE,
    }


def migrate_table(stage: str, table: dict[str, Any]) -> dict[str, Any]:
    """The stage table ``table`` with the keys of hybridsplat 0.2 moved to their 0.3 places (see the module)."""
    moved = _MOVED.get(stage, {})
    old_priors = stage == "train" and any(k in table for k in _OLD_PRIOR_KEYS)
    if not old_priors and not any(k in table and not isinstance(table[k], dict) for k in moved):
        return {k: _none_as_word(v) for k, v in table.items()}
    out: dict[str, Any] = {}
    for key, value in table.items():
        if key in _OLD_PRIOR_KEYS and stage == "train":
            continue
        if key in moved and not (moved[key][0] == key and isinstance(value, dict)):
            path, transform = moved[key]
            _put(out, path, transform(_none_as_word(value) if value is None else value))
        else:
            _put(out, key, _none_as_word(value))
    if old_priors:
        _put(out, "training.priors", _train_priors(table))
    return out


# -- removed options -------------------------------------------------------------------------------------------

NEXT_VERSION = "0.4"
"""The version that the removals of issue 54 (experiments the measurements went against) ship in."""


@dataclass(frozen=True)
class Removed:
    """An option a version removed: ``key`` of the options dataclass ``options`` (``module.QualName``), as
    config.toml spells it in ``section``; ``value``: the one value that was removed (None: the option itself);
    ``why``: one clause; ``version``: the version that removed it. The record of its measurements stays in
    docs/experiments/, the user's note in docs/migration.md."""

    options: str
    section: str
    key: str
    value: Any = None
    why: str = ""
    version: str = NEXT_VERSION

    def message(self, prefix: str = "") -> str:
        """``[section] key = value`` removed in ``version``: ``why``; see docs/migration.md."""
        value = "" if self.value is None else f" = {json.dumps(self.value)}"
        setting = f"[{self.section}] {prefix}{self.key}{value}"
        return f"{setting} was removed in {self.version}: {self.why}; see docs/migration.md"


REMOVED: tuple[Removed, ...] = (
    Removed(
        "classify.mask_options.MaskOptions",
        "masks",
        "hole_area",
        "region",
        "looking for holes only in the rays that meet the survey region cost the held-out picture more than it "
        "bought the survey (use the default, hull_below)",
    ),
)


def removed_setting(options_type: type, key: str, value: Any) -> Removed | None:
    """The :class:`Removed` entry that ``key = value`` of ``options_type`` sets, or None when it is not removed."""
    name = f"{options_type.__module__}.{options_type.__qualname__}"
    for entry in REMOVED:
        if entry.options == name and entry.key == key and (entry.value is None or entry.value == value):
            return entry
    return None
