"""Declared option constraints (core.constraints): each constraint type against values chosen on both sides of its
bounds, the one message template, None handling, bools refused as numbers, NaN and inf refused by intervals, and the
way hybridsplat.options names a nested option and its file."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import ClassVar

import numpy as np
import pytest

from core.constraints import (
    AnyOf,
    Choice,
    Constrained,
    ConstraintError,
    Constraints,
    Interval,
    NoneOr,
    OfType,
    SequenceOf,
    TupleOf,
    check,
)
from core.errors import ConfigError
from hybridsplat.options import options_from_table, with_option


@pytest.mark.parametrize(
    ("constraint", "inside", "outside"),
    [
        (Interval(int, 1, None), [1, 2, 10**12, np.int64(3)], [0, -1, 1.0, 2.5, True, "2", None]),
        (Interval(int, -1, 5, closed="neither"), [0, 4], [-1, 5, -2, 6]),
        (Interval(float, 0, 1, closed="right"), [1e-300, 0.5, 1, 1.0, np.float32(0.25)], [0, 0.0, -0.1, 1.0001]),
        (Interval(float, 0, 1, closed="left"), [0, 0.0, 0.999], [1, 1.0, -1e-12]),
        (Interval(float, 0, 1, closed="neither"), [0.5], [0.0, 1.0]),
        (Interval(float, 0, None), [0.0, 1e300], [-1e-300, math.inf, math.nan, -math.inf, False]),
        (Interval(float, None, None), [-1e300, 0.0, 1e300], [math.inf, -math.inf, math.nan, np.nan]),
        (Interval(float, 0, math.inf), [0.0, 1.0, math.inf], [math.nan, -1.0, -math.inf]),
        (Interval(float, 0, math.inf, closed="left"), [0.0, 1e300], [math.inf]),
    ],
)
def test_interval_accepts_inside_refuses_outside(constraint: Interval, inside: list, outside: list) -> None:
    for value in inside:
        assert constraint.accepts(value), value
    for value in outside:
        assert not constraint.accepts(value), value


@pytest.mark.parametrize(
    ("constraint", "text"),
    [
        (Interval(int, 1, None), "an int in [1, inf)"),
        (Interval(int, -1, None), "an int in [-1, inf)"),
        (Interval(float, 0, 1, closed="right"), "a float in (0, 1]"),
        (Interval(float, 0, 1, closed="left"), "a float in [0, 1)"),
        (Interval(float, 0.5, 2.25, closed="neither"), "a float in (0.5, 2.25)"),
        (Interval(float, None, None), "a float in (-inf, inf)"),
        (Interval(float, 0, math.inf), "a float in [0, inf]"),
        (NoneOr(Interval(int, -1, None)), "an int in [-1, inf) or none"),
        (OfType(bool), "a bool"),
        (Choice(("a", "b")), "one of a, b"),
        (SequenceOf(Interval(float, 0, None), length=3), "a list of 3 values, each a float in [0, inf)"),
        (SequenceOf(OfType(str), min_length=1), "a list of 1 or more values, each a str"),
    ],
)
def test_description(constraint, text: str) -> None:
    assert constraint.description == text


def test_message_template_names_option_allowed_and_value() -> None:
    with pytest.raises(ConstraintError) as info:
        check("max_image_size", 0.5, NoneOr(Interval(int, -1, None)))
    assert str(info.value) == "option max_image_size must be an int in [-1, inf) or none, got 0.5"
    assert (info.value.option, info.value.value) == ("max_image_size", 0.5)
    assert isinstance(info.value, ConfigError)
    with pytest.raises(ConstraintError, match=r"^option x must be a float in \[0, inf\), got nan$"):
        check("x", math.nan, Interval(float, 0, None))
    with pytest.raises(ConstraintError, match=r"^option x must be an int in \[1, inf\), got True$"):
        check("x", True, Interval(int, 1, None))
    with pytest.raises(ConstraintError, match=r"^option x must be a float in \(0, 1\], got 'a'$"):
        check("x", "a", Interval(float, 0, 1, closed="right"))
    with pytest.raises(ConstraintError, match=r"^option x must be one of a, b, got none$"):
        check("x", None, Choice(("a", "b")))


def test_none_only_where_declared() -> None:
    assert check("x", None, NoneOr(Interval(float, 0, None))) is None
    assert check("x", 2.0, NoneOr(Interval(float, 0, None))) == 2.0
    with pytest.raises(ConstraintError, match="got none"):
        check("x", None, Interval(float, 0, None))
    with pytest.raises(ConstraintError, match=r"or none, got -1.0"):
        check("x", -1.0, NoneOr(Interval(float, 0, None)))


class Colour(str, Enum):
    RED = "red"
    GREEN = "green"


def test_choice_of_enum_converts_its_value_and_refuses_others() -> None:
    assert check("c", "red", Choice(Colour)) is Colour.RED
    assert check("c", Colour.GREEN, Choice(Colour)) is Colour.GREEN
    with pytest.raises(ConstraintError, match=r"^option c must be one of red, green, got 'blue'$"):
        check("c", "blue", Choice(Colour))
    with pytest.raises(ConstraintError):
        check("c", ["red"], Choice(Colour))  # unhashable: refused, not a TypeError


def test_choice_of_values_compares_type_too() -> None:
    c = Choice((1, 2))
    assert c.accepts(1) and c.accepts(np.int64(2)) and not c.accepts(3)
    assert not c.accepts(True)  # True == 1 in Python, but a bool is no choice of ints
    assert not c.accepts(1.0)


def test_of_type_refuses_bool_as_int_and_accepts_int_as_float() -> None:
    assert OfType(int).accepts(3) and not OfType(int).accepts(True)
    assert OfType(float).accepts(3) and not OfType(float).accepts(False)
    assert OfType(bool).accepts(False) and not OfType(bool).accepts(0)
    assert OfType(str).accepts("a") and not OfType(str).accepts(b"a")


def test_sequence_of_checks_length_and_each_item_and_stores_a_tuple() -> None:
    c = SequenceOf(Interval(float, 0, None), length=2)
    assert check("s", [1.0, 2], c) == (1.0, 2)
    assert isinstance(check("s", [1.0, 2], c), tuple)
    assert check("s", np.array([1.5, 2.0]), c) == (1.5, 2.0)
    assert not c.accepts(np.zeros((2, 2)))
    for bad in ([1.0], [1.0, 2.0, 3.0], [1.0, -1.0], "ab", 1.0, [1.0, math.nan]):
        with pytest.raises(ConstraintError):
            check("s", bad, c)
    assert not SequenceOf(OfType(str), min_length=1).accepts(())


def test_interval_declaration_errors() -> None:
    with pytest.raises(TypeError):
        Interval(str, 0, 1)
    with pytest.raises(ValueError):
        Interval(float, 1, 0)
    with pytest.raises(ValueError):
        Interval(float, 0, 1, closed="open")  # type: ignore[arg-type]


@dataclass(frozen=True)
class Inner(Constrained):
    """A nested options class for the tests (iterations: count; rate: 1/s)."""

    iterations: int = 10
    rate: float | None = None

    constraints: ClassVar[Constraints] = {
        "iterations": Interval(int, 1, None),
        "rate": NoneOr(Interval(float, 0, None, closed="neither")),
    }


@dataclass(frozen=True)
class Outer(Constrained):
    """An options class composing :class:`Inner`, with a rule across fields (low <= high)."""

    low: float = 0.0
    high: float = 1.0
    colour: Colour = Colour.RED
    inner: Inner = field(default_factory=Inner)

    constraints: ClassVar[Constraints] = {
        "low": Interval(float, 0, None),
        "high": Interval(float, 0, None),
        "colour": Choice(Colour),
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.low > self.high:
            raise ConfigError(f"low must be <= high, got {self.low} > {self.high}")


def test_constrained_dataclass_validates_converts_and_keeps_cross_field_rules() -> None:
    assert Outer(colour="green").colour is Colour.GREEN  # type: ignore[arg-type]
    with pytest.raises(ConstraintError, match=r"^option low must be a float in \[0, inf\), got -1.0$"):
        Outer(low=-1.0)
    with pytest.raises(ConfigError, match="low must be <= high"):
        Outer(low=2.0, high=1.0)
    with pytest.raises(ConstraintError, match=r"^option iterations must be an int in \[1, inf\), got 0$"):
        Inner(iterations=0)


def test_declaring_an_unknown_field_is_a_type_error() -> None:
    with pytest.raises(TypeError, match="nope"):

        class Wrong(Constrained):  # noqa: F841
            x: int = 1
            constraints: ClassVar[Constraints] = {"nope": Interval(int, 0, None)}


def test_options_from_table_names_the_dotted_option_and_the_file() -> None:
    where = "/p/config.toml"
    with pytest.raises(ConstraintError) as info:
        options_from_table(Outer, {"inner": {"iterations": 0}}, where, prefix="")
    assert str(info.value) == "/p/config.toml: option inner.iterations must be an int in [1, inf), got 0"
    with pytest.raises(ConstraintError) as info:
        options_from_table(Outer, {"low": -2}, where, prefix="train.")
    assert str(info.value) == "/p/config.toml: option train.low must be a float in [0, inf), got -2.0"
    # a wrong type gets the declaration's message, not the type's alone
    with pytest.raises(ConstraintError) as info:
        options_from_table(Outer, {"inner": {"iterations": 2.5}}, where)
    assert str(info.value) == "/p/config.toml: option inner.iterations must be an int in [1, inf), got 2.5"
    with pytest.raises(ConstraintError, match=r"option inner.rate must be a float in \(0, inf\) or none, got 'x'"):
        options_from_table(Outer, {"inner": {"rate": "x"}}, where)
    with pytest.raises(ConstraintError, match=r"^--options: option colour must be one of red, green, got 'blue'$"):
        with_option(Outer(), "colour", "blue")
    assert options_from_table(Outer, {"inner": {"rate": "none"}, "colour": "green"}, where) == Outer(colour="green")
    with pytest.raises(ConfigError, match=r"^/p/config.toml: low must be <= high"):
        options_from_table(Outer, {"low": 3.0}, where)


def test_any_of_takes_the_first_that_accepts() -> None:
    c = AnyOf(Interval(float, 1, None, closed="neither"), SequenceOf(Interval(float, 1, None, closed="neither")))
    assert c.description == "a float in (1, inf) or a list of values, each a float in (1, inf)"
    assert check("r", 8.0, c) == 8.0 and check("r", [2.0, 3.0], c) == (2.0, 3.0)
    for bad in (1.0, [2.0, 0.5], "8", None):
        with pytest.raises(ConstraintError, match=r"^option r must be a float in \(1, inf\) or a list"):
            check("r", bad, c)


def test_tuple_of_checks_each_position() -> None:
    pair = TupleOf(OfType(str), Interval(float, 1, None))
    assert pair.description == "a list [a str, a float in [1, inf)]"
    assert check("p", ["glass", 2], pair) == ("glass", 2)
    for bad in (["glass"], ["glass", 0.5], [1.5, "glass"], ["glass", 2.0, 3.0], "ab"):
        assert not pair.accepts(bad), bad
    nested = SequenceOf(pair)
    with pytest.raises(
        ConstraintError, match=r"^option p must be a list of values, each a list \[a str, .*got \[\['a', 0.5\]\]$"
    ):
        check("p", (("a", 0.5),), nested)
