"""Standard channel names, their SI units, and conversion of file units to SI.

Every array inside hypa carries one of the standard names below and is in SI units.
Measured files may use other column names and units; the data configuration maps them
(``columns: {standard name: file column}``, ``units: {standard name: file unit}``) and
:func:`unit_factor` converts on read, so that ``SI value = file value * factor``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from hypa.data.errors import DataError

#: Standard channel name -> SI unit.
SI_UNITS: dict[str, str] = {
    "time": "s",
    "steering_wheel_angle": "rad",
    "yaw_rate": "rad/s",
    "side_slip": "rad",
    "lateral_acceleration": "m/s^2",
    "velocity": "m/s",
    "rear_wheel_angle": "rad",
}

#: Channels used only to evaluate a trained model (the paper trains without the measured
#: rear wheel angle and uses it afterwards to judge the implicitly learned RWS block).
EVAL_ONLY_CHANNELS: frozenset[str] = frozenset({"rear_wheel_angle"})

DEFAULT_INPUTS: tuple[str, ...] = ("steering_wheel_angle",)
DEFAULT_STATES: tuple[str, ...] = ("yaw_rate", "side_slip")
DEFAULT_EVAL_CHANNELS: tuple[str, ...] = ("rear_wheel_angle", "lateral_acceleration")

_STANDARD_GRAVITY = 9.80665  # [m/s^2], ISO 80000-3

# Unit -> (physical dimension, factor to SI). The dimension catches a mapping such as
# ``yaw_rate: deg`` (an angle where a rate is expected) before it silently trains a model
# on values off by a factor of the sample rate.
_UNITS: dict[str, tuple[str, float]] = {
    "rad": ("angle", 1.0),
    "deg": ("angle", math.pi / 180.0),
    "rad/s": ("angular rate", 1.0),
    "deg/s": ("angular rate", math.pi / 180.0),
    "m/s^2": ("acceleration", 1.0),
    "m/s2": ("acceleration", 1.0),
    "m/s²": ("acceleration", 1.0),
    "g": ("acceleration", _STANDARD_GRAVITY),
    "m/s": ("speed", 1.0),
    "km/h": ("speed", 1.0 / 3.6),
    "s": ("time", 1.0),
    "ms": ("time", 1e-3),
}
_SI_DIMENSION: dict[str, str] = {name: _UNITS[unit][0] for name, unit in SI_UNITS.items()}

KNOWN_UNITS: tuple[str, ...] = tuple(_UNITS)


def unit_factor(unit: str | float | int, channel: str | None = None) -> float:
    """Factor that converts a file value in ``unit`` to SI (``SI = value * factor``).

    ``unit`` is one of :data:`KNOWN_UNITS` or a plain positive number (given as a number
    or a numeric string), which is taken as the factor itself. When ``channel`` is a
    standard name, a named unit must have that channel's dimension (e.g. an angle for
    ``steering_wheel_angle``).
    """
    if isinstance(unit, bool):  # bool is an int; ``True`` is certainly not a unit
        raise DataError(f"unit {unit!r} for channel {channel!r} is not a unit")
    if isinstance(unit, (int, float)):
        return _positive_factor(float(unit), channel)
    text = str(unit).strip()
    if text in _UNITS:
        dimension, factor = _UNITS[text]
        expected = _SI_DIMENSION.get(channel or "")
        if expected is not None and dimension != expected:
            raise DataError(
                f"unit {text!r} is a unit of {dimension}, but channel {channel!r} is a "
                f"{expected} in {SI_UNITS[channel]!r}; units of {expected}: "
                f"{', '.join(u for u, (d, _) in _UNITS.items() if d == expected)}"
            )
        return factor
    try:
        return _positive_factor(float(text), channel)
    except ValueError:
        pass
    raise DataError(
        f"unknown unit {text!r} for channel {channel!r}; known units: "
        f"{', '.join(KNOWN_UNITS)}, or a plain number (SI value = file value * number)"
    )


def _positive_factor(value: float, channel: str | None) -> float:
    if not (math.isfinite(value) and value > 0):
        raise DataError(
            f"unit factor for channel {channel!r} must be a positive number, got {value}"
        )
    return value


def check_channel_roles(
    inputs: Sequence[str], states: Sequence[str], eval_channels: Sequence[str]
) -> None:
    """Reject channel lists that would leak evaluation-only data into training."""
    if not inputs:
        raise DataError("at least one input channel is required")
    if not states:
        raise DataError("at least one state channel is required")
    for role, names in (("input", inputs), ("state", states)):
        leaked = [name for name in names if name in EVAL_ONLY_CHANNELS]
        if leaked:
            raise DataError(
                f"{leaked} may not be used as {role} channel(s): they are for evaluation only "
                f"and must never reach a training batch (list them in eval_channels)"
            )
        if "time" in names:
            raise DataError(f"'time' is the time base, not an {role} channel")
    everything = [*inputs, *states]
    duplicated = sorted({name for name in everything if everything.count(name) > 1})
    if duplicated:
        raise DataError(f"channel(s) {duplicated} appear more than once among inputs and states")
    overlap = sorted(set(eval_channels) & set(everything))
    if overlap:
        raise DataError(f"channel(s) {overlap} are both model channels and eval_channels")


def check_mapping_keys(mapping: Mapping[str, object], what: str, used: Sequence[str]) -> None:
    """A key that is neither a standard name nor a used channel is almost surely a typo."""
    allowed = set(SI_UNITS) | set(used)
    unknown = sorted(key for key in mapping if key not in allowed)
    if unknown:
        raise DataError(
            f"data.{what} has unknown channel name(s) {unknown}; keys are standard names: "
            f"{', '.join(SI_UNITS)}"
        )
