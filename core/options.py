"""What options dataclasses of every package share: marking the fields that are not user configuration.

A domain options dataclass (``recon.sfm.SfmOptions``, ``fusion.train.TrainOptions`` ...) is also what the pipeline
writes to ``config.toml`` (:mod:`hybridsplat.options`). Fields the pipeline fills in itself at run time (its seed,
the held-out photos, a folder given on the command line) are declared with :func:`runtime_field`, and are then
neither written to nor read from config.toml.
"""

from __future__ import annotations

import dataclasses
from typing import Any


def runtime_field(default: Any = None, **kwargs: Any) -> Any:
    """A dataclass field set at run time by the caller (a seed, a mask folder), not part of config.toml."""
    return dataclasses.field(default=default, metadata={"runtime": True}, **kwargs)


def runtime_factory(factory: Any, **kwargs: Any) -> Any:
    """:func:`runtime_field` with a default factory (an empty frozenset of held-out names...)."""
    return dataclasses.field(default_factory=factory, metadata={"runtime": True}, **kwargs)


def enum_choice(enum_type: type, value: Any, name: str) -> Any:
    """``enum_type(value)``, or a :class:`core.errors.ConfigError` naming the option and its allowed values."""
    from core.errors import ConfigError

    try:
        return enum_type(value)
    except ValueError:
        allowed = ", ".join(str(m.value) for m in enum_type)
        raise ConfigError(f"{name} must be one of {allowed}, got {value!r}") from None
