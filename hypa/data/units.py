"""Units of measured channels: a table of unit -> (dimension, factor to SI).

A channel declares the unit of its file column (``unit``) and the unit it is shown in
(``display_unit``); inside hypa every value is SI::

    SI value      = file value * factor(unit)
    display value = SI value / factor(display_unit)

Both units must have the same dimension, so ``display_unit: deg`` on a rate in ``rad/s`` is an
error instead of a plot off by a factor. ``-`` (also ``1`` or an empty string) is dimensionless.
``°``, ``°/s`` and ``1/min`` (rpm) are spelled as measurement tools write them into MDF files.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hypa.data.errors import DataError

_STANDARD_GRAVITY = 9.80665  # [m/s^2], ISO 80000-3


@dataclass(frozen=True)
class Unit:
    """A unit: its ``name``, its physical ``dimension``, ``factor`` to SI and the SI unit ``si``."""

    name: str
    dimension: str
    factor: float
    si: str


# dimension -> its SI unit, then every unit by dimension with its factor to that SI unit.
_TABLE: dict[tuple[str, str], dict[str, float]] = {
    ("dimensionless", "-"): {"-": 1.0, "1": 1.0, "": 1.0, "%": 0.01},
    ("time", "s"): {"s": 1.0, "ms": 1e-3, "us": 1e-6, "min": 60.0, "h": 3600.0},
    ("frequency", "Hz"): {"Hz": 1.0, "kHz": 1e3},
    ("angle", "rad"): {"rad": 1.0, "mrad": 1e-3, "deg": math.pi / 180.0, "°": math.pi / 180.0},
    ("angular rate", "rad/s"): {"rad/s": 1.0, "deg/s": math.pi / 180.0, "°/s": math.pi / 180.0,
                                "rpm": 2.0 * math.pi / 60.0, "1/min": 2.0 * math.pi / 60.0},
    ("angular acceleration", "rad/s^2"): {"rad/s^2": 1.0, "rad/s2": 1.0,
                                          "deg/s^2": math.pi / 180.0},
    ("length", "m"): {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "um": 1e-6, "km": 1e3},
    ("speed", "m/s"): {"m/s": 1.0, "mm/s": 1e-3, "km/h": 1.0 / 3.6, "kmph": 1.0 / 3.6,
                       "mph": 0.44704},
    ("acceleration", "m/s^2"): {"m/s^2": 1.0, "m/s2": 1.0, "m/s²": 1.0, "g": _STANDARD_GRAVITY},
    ("mass", "kg"): {"kg": 1.0, "t": 1e3},
    ("force", "N"): {"N": 1.0, "kN": 1e3},
    ("torque", "Nm"): {"Nm": 1.0, "N m": 1.0, "kNm": 1e3},
    ("pressure", "Pa"): {"Pa": 1.0, "kPa": 1e3, "MPa": 1e6, "bar": 1e5, "mbar": 1e2},
    ("voltage", "V"): {"V": 1.0, "mV": 1e-3, "kV": 1e3},
    ("current", "A"): {"A": 1.0, "mA": 1e-3},
    ("power", "W"): {"W": 1.0, "kW": 1e3},
    ("temperature", "K"): {"K": 1.0},  # absolute kelvin (degC needs an offset, not a factor)
}

UNITS: dict[str, Unit] = {
    name: Unit(name, dimension, factor, si)
    for (dimension, si), units in _TABLE.items()
    for name, factor in units.items()
}
KNOWN_UNITS: tuple[str, ...] = tuple(name for name in UNITS if name)


def unit(name: str, channel: str | None = None) -> Unit:
    """The :class:`Unit` called ``name``; an unknown one is a DataError naming the channel."""
    text = "" if name is None else str(name).strip()
    if text in UNITS:
        return UNITS[text]
    where = f" of channel {channel!r}" if channel else ""
    raise DataError(
        f"unknown unit {text!r}{where}; known units: {', '.join(KNOWN_UNITS)} "
        f"('-' for a dimensionless channel; a scale factor goes into an expression)"
    )


def unit_factor(name: str, channel: str | None = None) -> float:
    """Factor that converts a value in unit ``name`` to SI (``SI = value * factor``)."""
    return unit(name, channel).factor


def display_factor(unit_name: str, display_unit: str | None, channel: str | None = None) -> float:
    """Factor from SI to ``display_unit`` (``display = SI * factor``), checked against the
    dimension of ``unit_name``; ``None`` shows the SI unit (factor 1)."""
    measured = unit(unit_name, channel)
    if display_unit is None:
        return 1.0
    shown = unit(display_unit, channel)
    if shown.dimension != measured.dimension:
        raise DataError(
            f"display unit {shown.name!r} of channel {channel!r} is a unit of {shown.dimension}, "
            f"but its unit {measured.name!r} is one of {measured.dimension}; units of "
            f"{measured.dimension}: {', '.join(units_of(measured.dimension))}"
        )
    return 1.0 / shown.factor


def units_of(dimension: str) -> tuple[str, ...]:
    """Every known unit of a dimension (e.g. ``"angle"`` -> rad, mrad, deg)."""
    return tuple(name for name, u in UNITS.items() if u.dimension == dimension and name)
