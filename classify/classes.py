"""Project-defined point classes (a small TOML file) and how they map to needs-splats and to data_synth kinds.

The default set ships as ``classify/classes.toml``: collaborative, reflective, transparent, textureless, thin.
"""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np
import tomllib

from core.errors import ConfigError, FormatError, InputFileError

DEFAULT_CLASSES_TOML = Path(__file__).with_name("classes.toml")

UNLABELLED = 255
"""Label value of points without a label (ignored in training)."""


@dataclass(frozen=True)
class PointClass:
    """One class: ``name``, uint8 ``code``, ``needs_splats``, data_synth ``kinds``, LAS ``las_codes``, ``meaning``."""

    name: str
    code: int
    needs_splats: bool
    kinds: tuple[str, ...] = ()
    las_codes: tuple[int, ...] = ()
    meaning: str = ""


@dataclass(frozen=True)
class ClassSet:
    """The classes of a project, ordered by code."""

    classes: tuple[PointClass, ...]

    def __post_init__(self) -> None:
        codes = [c.code for c in self.classes]
        names = [c.name for c in self.classes]
        if not self.classes:
            raise ConfigError("a class set needs at least one class")
        if len(set(codes)) != len(codes) or len(set(names)) != len(names):
            raise ConfigError(f"class names and codes must be unique, got {names} / {codes}")
        if any(not 0 <= c < UNLABELLED for c in codes):
            raise ConfigError(f"class codes must lie in 0..254, got {codes}")
        if not any(not c.needs_splats for c in self.classes):
            raise ConfigError("a class set needs at least one class with needs_splats = false")

    @property
    def codes(self) -> np.ndarray:
        return np.array([c.code for c in self.classes], dtype=np.uint8)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.classes)

    def by_name(self, name: str) -> PointClass:
        for c in self.classes:
            if c.name == name:
                return c
        raise ConfigError(f"unknown class {name!r}; classes: {', '.join(self.names)}")

    def by_code(self, code: int) -> PointClass:
        for c in self.classes:
            if c.code == code:
                return c
        raise ConfigError(f"unknown class code {code}; codes: {list(self.codes)}")

    def needs_splats_of(self, codes: np.ndarray) -> np.ndarray:
        """(N,) bool: whether each class code needs splats (unknown codes → True: not trusted)."""
        table = np.ones(256, dtype=bool)
        for c in self.classes:
            table[c.code] = c.needs_splats
        return table[np.asarray(codes, dtype=np.uint8)]

    def code_of_kind(self, kind: str) -> int:
        """The code of the class a data_synth material kind maps onto; :class:`ConfigError` if none does."""
        for c in self.classes:
            if kind in c.kinds:
                return c.code
        raise ConfigError(f"no class maps the material kind {kind!r}; add it to a class's 'kinds'")

    def code_of_las(self, las_codes: np.ndarray) -> np.ndarray:
        """(N,) uint8 class codes for LAS classification codes; codes no class lists → :data:`UNLABELLED`."""
        table = np.full(256, UNLABELLED, dtype=np.uint8)
        for c in self.classes:
            for code in c.las_codes:
                table[code] = c.code
        return table[np.clip(np.asarray(las_codes, dtype=np.int64), 0, 255)]

    @property
    def collaborative_code(self) -> int:
        """The code of the first class that does not need splats."""
        return next(c.code for c in self.classes if not c.needs_splats)

    def to_dict(self) -> dict[str, object]:
        """A JSON/TOML-ready description (stored with models)."""
        return {
            "class": [
                {
                    "name": c.name,
                    "code": c.code,
                    "needs_splats": c.needs_splats,
                    "kinds": list(c.kinds),
                    "las_codes": list(c.las_codes),
                    "meaning": c.meaning,
                }
                for c in self.classes
            ]
        }

    @classmethod
    def from_dict(cls, data: dict[str, object], source: str | PathLike[str] | None = None) -> ClassSet:
        """Parse the ``[[class]]`` tables; malformed entries raise :class:`FormatError` naming ``source``."""
        try:
            entries = data["class"]
            classes = tuple(
                PointClass(
                    name=str(e["name"]),
                    code=int(e["code"]),
                    needs_splats=bool(e["needs_splats"]),
                    kinds=tuple(str(k) for k in e.get("kinds", ())),
                    las_codes=tuple(int(k) for k in e.get("las_codes", ())),
                    meaning=str(e.get("meaning", "")),
                )
                for e in entries  # type: ignore[union-attr]
            )
        except (KeyError, TypeError, ValueError, AttributeError) as err:
            problem = f"class definitions need [[class]] tables with name, code, needs_splats ({err})"
            raise FormatError(problem, source) from err
        return cls(tuple(sorted(classes, key=lambda c: c.code)))


def load_classes(path: str | PathLike[str] | None = None) -> ClassSet:
    """The classes of a TOML file (default: the shipped ``classes.toml``)."""
    p = Path(path) if path is not None else DEFAULT_CLASSES_TOML
    if not p.is_file():
        raise InputFileError("class definition file does not exist", p)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as err:
        raise FormatError(f"not valid TOML ({err})", p) from err
    return ClassSet.from_dict(data, p)
