"""Length units the user speaks (m, mm, cm, ft) and the toolkit's internal unit (metres, see DESIGN.md).

Coordinates are converted to metres once, on input; reports convert back only to print. ``ft`` is the
international foot (0.3048 m exactly), not the US survey foot (1200/3937 m, 2 ppm longer).
"""

from __future__ import annotations

import enum
import math

from core.errors import ConfigError


class Units(str, enum.Enum):
    """A length unit; ``value * unit.metres`` is the length in metres."""

    M = "m"
    MM = "mm"
    CM = "cm"
    FT = "ft"

    @property
    def metres(self) -> float:
        """Metres per one of this unit."""
        return _METRES[self]

    @classmethod
    def parse(cls, name: str | Units) -> Units:
        """``"mm"`` → Units.MM (case-insensitive; "metre", "meters", "feet" ... accepted). ConfigError otherwise."""
        if isinstance(name, Units):
            return name
        key = str(name).strip().lower()
        key = _ALIASES.get(key, key)
        try:
            return cls(key)
        except ValueError:
            raise ConfigError(f"unknown length unit {name!r} (expected one of m, mm, cm, ft)") from None

    def to_metres(self, value):
        """A length or array of lengths in this unit → metres (float64 arithmetic)."""
        return value * self.metres

    def from_metres(self, value):
        """A length or array of lengths in metres → this unit."""
        return value / self.metres

    def format(self, value_m: float, digits: int = 3) -> str:
        """A length given in metres, printed in this unit with ``digits`` significant digits: ``"1.23 mm"``.

        Large values keep all their integer digits (no exponent notation); NaN/inf print as "n/a".
        """
        if value_m is None or not math.isfinite(float(value_m)):
            return "n/a"
        v = float(self.from_metres(float(value_m)))
        if v == 0:
            return f"0 {self.value}"
        decimals = max(0, digits - 1 - math.floor(math.log10(abs(v))))
        return f"{v:.{min(decimals, 9)}f} {self.value}"


_METRES = {Units.M: 1.0, Units.MM: 1e-3, Units.CM: 1e-2, Units.FT: 0.3048}
_ALIASES = {
    "metre": "m",
    "metres": "m",
    "meter": "m",
    "meters": "m",
    "millimetre": "mm",
    "millimetres": "mm",
    "millimeter": "mm",
    "millimeters": "mm",
    "centimetre": "cm",
    "centimetres": "cm",
    "centimeter": "cm",
    "centimeters": "cm",
    "foot": "ft",
    "feet": "ft",
}
