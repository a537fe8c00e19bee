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

Options removed since (issue 54: experiments without a measured gain are deleted, :data:`REMOVED`) are left out
when they are off, as every config.toml and manifest of an earlier version spells them; set to anything else they
are refused with one error that names them and why they went (docs/migration.md).
"""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from core.errors import ConfigError

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


def migrate_table(stage: str, table: dict[str, Any], where: Path | str | None = None) -> dict[str, Any]:
    """The stage table ``table`` with the keys of hybridsplat 0.2 moved to their 0.3 places and the removed options
    at their "off" value left out (see the module); a removed option set to anything else is a :class:`ConfigError`
    naming it and ``where`` (the file)."""
    table = drop_removed(stage, table, where)
    moved = _MOVED.get(stage, {})
    if not any(k in table and not isinstance(table[k], dict) for k in moved):
        return {k: _none_as_word(v) for k, v in table.items()}
    out: dict[str, Any] = {}
    for key, value in table.items():
        if key in moved and not (moved[key][0] == key and isinstance(value, dict)):
            path, transform = moved[key]
            _put(out, path, transform(_none_as_word(value) if value is None else value))
        else:
            _put(out, key, _none_as_word(value))
    return out


# -- removed options ---------------------------------------------------------------------------------------------

#: the version whose configuration no longer has the options of :data:`REMOVED`
REMOVED_IN = "0.4"


def _is_none(value: Any) -> bool:
    """Spelled None: a table that is off (``"none"`` / ``"off"`` in config.toml, null in an old manifest)."""
    return value is None or (isinstance(value, str) and value.lower() in ("none", "off"))


def _not_positive(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and value <= 0


def _is_false(value: Any) -> bool:
    return value is False


def _any(value: Any) -> bool:
    """Any value: an option that only acts together with a removed switch (which is checked on its own)."""
    return True


@dataclass(frozen=True)
class Removed:
    """A removed option: ``why`` it went (one clause, for the error) and ``off``, whether a value is one that asks
    for what the pipeline does anyway (config.toml files and manifests of earlier versions spell every option, the
    removed ones at those values: they are left out without a word)."""

    why: str
    off: Callable[[Any], bool]


_PRIORS = "the MVS depth / normal priors: no measured gain worth their training time"
_GEOMETRY = "flat fill splats and the geometric losses: no measured gain worth their training time"
_PHOTOMETRIC = "the SmoothL1 + MS-SSIM loss: never shown to help (L1 + SSIM is the loss)"
_HARD_VIEWS = "hard-view mining: never shown to help (every view is seen once per epoch)"
_MCMC = "MCMC densification: never shown to help (DefaultStrategy is the strategy)"
_LPIPS = "the LPIPS training term lowered the held-out PSNR (LPIPS stays an evaluation metric: [eval] lpips_weights)"
_SPLAT_SURFACE = "the splat-surface points: their F-score gain on the tuning layouts did not hold on the scoring ones"

#: per training stage (each composes a ``TrainOptions`` as ``training``): removed dotted path → :class:`Removed`
_REMOVED_TRAINING: dict[str, Removed] = {
    "training.priors": Removed(_PRIORS, _is_none),
    "training.geometry": Removed(_GEOMETRY, _is_none),
    "training.flat": Removed(_GEOMETRY, _is_false),
    "training.flat_reg": Removed(_GEOMETRY, _any),
    "training.lpips_weight": Removed(_LPIPS, _not_positive),
    **{f"training.{key}": Removed(_LPIPS, _any) for key in ("lpips_start", "lpips_margin")},
    "training.photometric": Removed(_PHOTOMETRIC, lambda value: value == "l1_ssim"),
    "training.smoothl1_beta": Removed(_PHOTOMETRIC, _any),
    "training.hard_views": Removed(_HARD_VIEWS, _is_none),
    "training.strategy.kind": Removed(_MCMC, lambda value: value == "DefaultStrategy"),
}

#: per stage: removed option (dotted path inside the stage's table, or a key of 0.2's flat tables) → :class:`Removed`
REMOVED: dict[str, dict[str, Removed]] = {
    **{stage: dict(_REMOVED_TRAINING) for stage in ("train", "background", "appearance", "baseline")},
}
REMOVED["train"].update({
    "flat": Removed(_GEOMETRY, _is_false),  # 0.2's flat [train] table
    "lpips_weight": Removed(_LPIPS, _not_positive),
    "lpips_start": Removed(_LPIPS, _any),
    "photometric": Removed(_PHOTOMETRIC, lambda value: value == "l1_ssim"),
    "hard_views": Removed(_HARD_VIEWS, _is_false),
    "lpips_weights": Removed(_LPIPS, _any),  # the weights of the LPIPS term (0.2 and 0.3 alike)
    # 0.2's flat [train] table: its prior weights (0 = off) and the prior's shape, which acted only with them
    "depth_prior": Removed(_PRIORS, _not_positive),
    "normal_prior": Removed(_PRIORS, _not_positive),
    **{key: Removed(_PRIORS, _any) for key in ("prior_border_px", "prior_edge_scale", "prior_hull_share")},
})  # fmt: skip
REMOVED["merge"] = {
    "splat_surface": Removed(_SPLAT_SURFACE, _is_false),
    # options that acted only with splat_surface (a table: splat_surface_points)
    **{key: Removed(_SPLAT_SURFACE, _any) for key in (
        "splat_surface_keep_centres", "splat_surface_support", "splat_surface_sigma_scale", "splat_surface_points",
    )},
}  # fmt: skip


def _spelled(value: Any) -> str:
    """A value as config.toml spells it (a table as ``{...}``)."""
    return "{...}" if isinstance(value, dict) else json.dumps(value)


def drop_removed(stage: str, table: dict[str, Any], where: Path | str | None = None) -> dict[str, Any]:
    """``table`` (a stage's table of config.toml, or the options a manifest recorded) without the removed options
    (:data:`REMOVED`) that are off. Any removed option set otherwise is refused in one :class:`ConfigError` naming
    each one (``stage.path = value``), why it was removed and where the record is."""
    removed = REMOVED.get(stage, {})
    out = table
    refused = []
    for path, rule in removed.items():
        *parents, last = path.split(".")
        node: Any = table
        for part in parents:
            node = node.get(part) if isinstance(node, dict) else None
        if not isinstance(node, dict) or last not in node:
            continue
        if not rule.off(node[last]):
            refused.append(f"{stage}.{path} = {_spelled(node[last])} ({rule.why})")
            continue
        if out is table:
            out = copy.deepcopy(table)
        target = out
        for part in parents:
            target = target[part]
        del target[last]
    if refused:
        raise ConfigError(
            f"option(s) removed in {REMOVED_IN}: {'; '.join(refused)}; delete them (docs/migration.md says what "
            "each did and where its record is)",
            where,
        )
    return out


# -- removed options -------------------------------------------------------------------------------------------

NEXT_VERSION = REMOVED_IN
"""The version that the removals of issue 54 (experiments the measurements went against) ship in."""


@dataclass(frozen=True)
class RemovedValue:
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


REMOVED_VALUES: tuple[RemovedValue, ...] = (
    RemovedValue(
        "classify.mask_options.MaskOptions",
        "masks",
        "hole_area",
        "region",
        "looking for holes only in the rays that meet the survey region cost the held-out picture more than it "
        "bought the survey (use the default, hull_below)",
    ),
)


def removed_setting(options_type: type, key: str, value: Any) -> RemovedValue | None:
    """The :class:`RemovedValue` entry that ``key = value`` of ``options_type`` sets, or None when it is not removed."""
    name = f"{options_type.__module__}.{options_type.__qualname__}"
    for entry in REMOVED_VALUES:
        if entry.options == name and entry.key == key and (entry.value is None or entry.value == value):
            return entry
    return None
