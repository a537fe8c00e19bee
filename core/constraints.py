"""Declared constraints of option values, checked in one place with one message.

An options dataclass declares what each of its fields may hold in a class-level mapping ``constraints`` (field
name → constraint), as scikit-learn's ``_parameter_constraints``, and derives from :class:`Constrained`, whose
``__post_init__`` checks every declared field (:func:`validate`)::

    @dataclass(frozen=True)
    class MaskOptions(Constrained):
        footprint: float = 1.5
        grow_area: int = 3
        hole_area: HoleArea = HoleArea.HULL_BELOW
        sample_spacing: float | None = None

        constraints: ClassVar[Constraints] = {
            "footprint": Interval(float, 0, None, closed="neither"),
            "grow_area": Interval(int, 0, None),
            "hole_area": Choice(HoleArea),
            "sample_spacing": NoneOr(Interval(float, 0, None, closed="neither")),
        }

A value outside its declaration is refused with a :class:`ConstraintError` (a :class:`core.errors.ConfigError`) that
always reads ``option <name> must be <allowed>, got <value>``, e.g.
``option max_image_size must be an int in [-1, inf) or none, got 0.5``. A class whose options depend on each other
keeps those rules by hand: its ``__post_init__`` calls ``super().__post_init__()`` first, then checks them.

Conventions of the declarations:

- :class:`Interval` over ``int`` accepts integers (Python's and NumPy's), never a bool; over ``float`` it accepts any
  real number but a bool, and never NaN. A bound given as ``None`` is unbounded and open: ±inf are refused there
  (``Interval(float, 0, None)`` is a finite value ≥ 0); a bound given as ``math.inf`` with that side closed accepts
  inf itself.
- :class:`Choice` over an ``Enum`` accepts a member or its value and stores the member in the field (so a dataclass
  built from the string ``"hull"`` holds ``HoleArea.HULL``); over a set of plain values it accepts those only.
- :class:`NoneOr` accepts ``None`` besides what its constraint accepts (written ``none`` in config.toml).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable, Mapping
from enum import Enum
from typing import Any, ClassVar, Literal

import numpy as np

from core.errors import ConfigError

__all__ = [
    "AnyOf",
    "Choice",
    "Constrained",
    "Constraint",
    "ConstraintError",
    "Interval",
    "NoneOr",
    "OfType",
    "SequenceOf",
    "TupleOf",
    "Constraints",
    "check",
    "validate",
]


class ConstraintError(ConfigError):
    """A value outside its declared constraint: ``option <option> must be <allowed>, got <value>``.

    option: the option's name (dotted when nested: ``training.iterations``); value: what was given; allowed: the
    constraint's description (``an int in [1, inf)``)."""

    def __init__(self, option: str, value: Any, allowed: str, path: Any = None) -> None:
        self.option, self.value, self.allowed = option, value, allowed
        super().__init__(f"option {option} must be {allowed}, got {show(value)}", path)

    def renamed(self, prefix: str, path: Any = None) -> ConstraintError:
        """The same error for the option ``prefix + option`` (a nested table's key path), located at ``path``."""
        return ConstraintError(prefix + self.option, self.value, self.allowed, path if path is not None else self.path)


def show(value: Any) -> str:
    """A value as the messages write it: numbers and bools as written in Python, ``none``, strings quoted."""
    if value is None:
        return "none"
    if isinstance(value, Enum):
        return repr(value.value)
    if isinstance(value, (bool, str)):
        return repr(value)
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        return repr(float(value))
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(show(v) for v in value) + "]"
    return repr(value)


class Constraint:
    """What a field may hold: :meth:`convert` returns the value to store, or raises ``ValueError`` when refused;
    :attr:`description` is what the message says is allowed (``an int in [1, inf)``)."""

    description: str = "a valid value"

    def convert(self, value: Any) -> Any:
        """``value`` as stored (an enum member for its value...), or ``ValueError`` when the constraint refuses it."""
        raise NotImplementedError

    def accepts(self, value: Any) -> bool:
        """Whether ``value`` satisfies the constraint."""
        try:
            self.convert(value)
        except ValueError:
            return False
        return True

    def __repr__(self) -> str:
        return f"<{type(self).__name__}: {self.description}>"


_TYPE_WORDS = {int: "an int", float: "a float", bool: "a bool", str: "a str"}


def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _bound_text(bound: float | None, sign: int) -> str:
    if bound is None or math.isinf(bound):
        return "inf" if sign > 0 else "-inf"
    return str(int(bound)) if float(bound).is_integer() and abs(bound) < 1e15 else repr(float(bound))


class Interval(Constraint):
    """A number of ``kind`` (``int`` or ``float``) between ``left`` and ``right`` (``None``: unbounded, inf refused).

    closed: which ends belong to the interval, ``"both"`` (default), ``"left"``, ``"right"`` or ``"neither"``.
    ``Interval(float, 0, 1, closed="right")`` is (0, 1]; ``Interval(int, 1, None)`` is [1, inf)."""

    def __init__(
        self,
        kind: type,
        left: float | None,
        right: float | None,
        *,
        closed: Literal["both", "left", "right", "neither"] = "both",
    ) -> None:
        if kind not in (int, float):
            raise TypeError(f"Interval kind must be int or float, got {kind!r}")
        if closed not in ("both", "left", "right", "neither"):
            raise ValueError(f"closed must be both, left, right or neither, got {closed!r}")
        if left is not None and right is not None and left > right:
            raise ValueError(f"Interval left bound {left} is above its right bound {right}")
        self.kind, self.left, self.right, self.closed = kind, left, right, closed
        opening = "[" if closed in ("both", "left") and left is not None else "("
        closing = "]" if closed in ("both", "right") and right is not None else ")"
        self.description = f"{_TYPE_WORDS[kind]} in {opening}{_bound_text(left, -1)}, {_bound_text(right, 1)}{closing}"

    def convert(self, value: Any) -> Any:
        if not (_is_int(value) if self.kind is int else _is_real(value)):
            raise ValueError(value)
        v = float(value)
        if math.isnan(v):
            raise ValueError(value)
        left_closed = self.closed in ("both", "left")
        right_closed = self.closed in ("both", "right")
        if self.left is None:
            ok_left = not math.isinf(v) or v > 0
        else:
            ok_left = v >= self.left if left_closed else v > self.left
        if self.right is None:
            ok_right = not math.isinf(v) or v < 0
        else:
            ok_right = v <= self.right if right_closed else v < self.right
        if not (ok_left and ok_right):
            raise ValueError(value)
        return value


class Choice(Constraint):
    """One of the members of an ``Enum`` (a member or its value; the member is stored), or of a set of values."""

    def __init__(self, choices: type[Enum] | Iterable[Any]) -> None:
        if isinstance(choices, type) and issubclass(choices, Enum):
            self.enum: type[Enum] | None = choices
            self.values: tuple[Any, ...] = tuple(m.value for m in choices)
        else:
            self.enum = None
            self.values = tuple(choices)
        self.description = "one of " + ", ".join(str(v) for v in self.values)

    def convert(self, value: Any) -> Any:
        if self.enum is not None:
            try:
                return self.enum(value)
            except (ValueError, TypeError):
                raise ValueError(value) from None
        if not any(_kind(value) is _kind(v) and value == v for v in self.values):
            raise ValueError(value)
        return value


def _kind(value: Any) -> type:
    """What a choice compares by besides equality: a bool is no int, an int (NumPy's too) no float."""
    if isinstance(value, bool):
        return bool
    if isinstance(value, numbers.Integral):
        return int
    if isinstance(value, numbers.Real):
        return float
    return type(value)


class OfType(Constraint):
    """A value of one of ``types`` (``bool`` is no ``int`` here)."""

    def __init__(self, *types: type) -> None:
        self.types = types
        self.description = " or ".join(_TYPE_WORDS.get(t, f"a {t.__name__}") for t in types)

    def convert(self, value: Any) -> Any:
        for t in self.types:
            if t is int and _is_int(value):
                return value
            if t is float and _is_real(value):
                return value
            if t not in (int, float) and isinstance(value, t):
                return value
        raise ValueError(value)


class NoneOr(Constraint):
    """``None``, or a value ``constraint`` accepts."""

    def __init__(self, constraint: Constraint) -> None:
        self.constraint = constraint
        self.description = f"{constraint.description} or none"

    def convert(self, value: Any) -> Any:
        return None if value is None else self.constraint.convert(value)


class AnyOf(Constraint):
    """A value that one of ``constraints`` accepts (the first that does converts it)."""

    def __init__(self, *constraints: Constraint) -> None:
        self.constraints = constraints
        self.description = " or ".join(c.description for c in constraints)

    def convert(self, value: Any) -> Any:
        for constraint in self.constraints:
            try:
                return constraint.convert(value)
            except ValueError:
                continue
        raise ValueError(value)


class SequenceOf(Constraint):
    """A tuple (or a list or 1-D array, stored as a tuple) whose every item ``item`` accepts; ``length``: how many
    items exactly (None: any number), ``min_length``: at least how many."""

    def __init__(self, item: Constraint, length: int | None = None, min_length: int = 0) -> None:
        self.item, self.length, self.min_length = item, length, min_length
        if length is not None:
            count = f"{length} "
        elif min_length > 0:
            count = f"{min_length} or more "
        else:
            count = ""
        self.description = f"a list of {count}values, each {item.description}"

    def convert(self, value: Any) -> Any:
        if isinstance(value, np.ndarray):
            value = tuple(value.tolist()) if value.ndim == 1 else value
        if isinstance(value, (str, bytes)) or not isinstance(value, (tuple, list)):
            raise ValueError(value)
        if (self.length is not None and len(value) != self.length) or len(value) < self.min_length:
            raise ValueError(value)
        return tuple(self.item.convert(v) for v in value)


#: the type of a class's ``constraints`` declaration (field name → constraint)
Constraints = Mapping[str, Constraint]


class TupleOf(Constraint):
    """A fixed-length tuple (or list, stored as a tuple) whose i-th item ``items[i]`` accepts: a pair
    ``[class name, factor]`` is ``TupleOf(OfType(str), Interval(float, 1, None))``."""

    def __init__(self, *items: Constraint) -> None:
        self.items = items
        self.description = "a list [" + ", ".join(c.description for c in items) + "]"

    def convert(self, value: Any) -> Any:
        if isinstance(value, (str, bytes)) or not isinstance(value, (tuple, list)) or len(value) != len(self.items):
            raise ValueError(value)
        return tuple(c.convert(v) for c, v in zip(self.items, value, strict=True))


def check(name: str, value: Any, constraint: Constraint) -> Any:
    """``value`` as ``constraint`` stores it, or a :class:`ConstraintError` naming option ``name``."""
    try:
        return constraint.convert(value)
    except ValueError:
        raise ConstraintError(name, value, constraint.description) from None


def validate(options: Any, constraints: Mapping[str, Constraint] | None = None) -> None:
    """Check every field of the dataclass instance ``options`` that ``constraints`` (default: its class's
    ``constraints``) declares, and store the converted value (an enum member for its value) in place."""
    declared = type(options).constraints if constraints is None else constraints
    for name, constraint in declared.items():
        value = getattr(options, name)
        converted = check(name, value, constraint)
        if converted is not value:
            object.__setattr__(options, name, converted)


class Constrained:
    """Base of an options dataclass whose fields are declared in ``constraints``: :func:`validate` runs after
    ``__init__``. A subclass with rules across fields calls ``super().__post_init__()`` in its own first."""

    constraints: ClassVar[Mapping[str, Constraint]] = {}

    def __post_init__(self) -> None:
        validate(self)

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        names = {name for base in cls.__mro__ for name in base.__dict__.get("__annotations__", {})}
        unknown = sorted(set(cls.__dict__.get("constraints", {})) - names)
        if unknown:
            raise TypeError(f"{cls.__name__}.constraints declares {', '.join(unknown)}: no field of the class")
