"""Units of measured channels, read by pint: any unit pint knows, and a user's own.

A channel declares the unit of its file column (``unit``) and the unit it is shown in
(``display_unit``); inside hypa every value is SI::

    SI value      = file value * factor(unit) + offset(unit)     (offset: degC, degF only)
    display value = SI value / factor(display_unit)

Units are parsed by `pint <https://pint.readthedocs.io>`_, so temperatures (``K``, ``degC``,
``degF`` and their differences ``delta_degC``), pressures (``kPa``, ``bar``, ``psi``), flows
(``l/min``, ``m^3/h``), currents, torques (``N*m``), powers and every prefix work without a
table here. A data set adds its own names in ``data.units`` (``{counts: "0.001 * m"}``, pint's
definition syntax), e.g. for a sensor's raw counts.

Two units are of the same kind when their SI base units agree, with the radian kept apart from
the dimensionless (pint counts angles as dimensionless): ``display_unit: deg`` on a rate in
``rad/s`` is an error instead of a plot off by a factor, and so is ``deg`` on a ``%`` channel.
Spellings hypa has always read keep their meaning: ``-``, ``1`` or an empty string is
dimensionless; ``g`` is the standard gravity (an accelerometer's unit, not the gram);
``1/min`` is revolutions per minute; ``°``, ``°/s``, ``Nm``, ``kmph``, ``m/s2`` as logging tools
write them. A display unit with an offset (``degC``) is refused: shown values are scaled only,
so a temperature is shown in ``K`` (its errors are the same in ``delta_degC``).

A value that is no channel (a fitted parameter, a diagnosis's estimate) is shown by
:func:`readable`: in the unit an engineer reads (:data:`READABLE`: angles in deg, times in ms),
with the factor from pint. The unit of a ratio of two units (a fitted gain) is written by
:func:`unit_ratio`.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Self

import pint

from hypa.core.errors import DataError

# hypa's spellings -> pint's (what measurement tools and earlier hypa configs write)
_ALIASES = {"-": "dimensionless", "1": "dimensionless", "": "dimensionless", "%": "percent", "°": "degree",
            "°/s": "degree/s", "g": "g_n", "1/min": "revolutions/minute", "Nm": "N*m", "N m": "N*m",
            "kNm": "kN*m", "kmph": "km/h", "m/s2": "m/s**2", "rad/s2": "rad/s**2"}
# SI base units (pint's text) -> the name hypa shows; others are shown as pint abbreviates them
_SI_NAMES = {"dimensionless": "-", "second": "s", "1 / second": "Hz", "radian": "rad", "radian / second": "rad/s",
             "radian / second ** 2": "rad/s^2", "meter": "m", "meter / second": "m/s", "meter / second ** 2": "m/s^2",
             "kilogram": "kg", "kilogram * meter / second ** 2": "N", "kilogram * meter ** 2 / second ** 2": "Nm",
             "kilogram / meter / second ** 2": "Pa", "kilogram * meter ** 2 / ampere / second ** 3": "V",
             "ampere": "A", "kilogram * meter ** 2 / second ** 3": "W", "kelvin": "K", "meter ** 3 / second": "m^3/s",
             "meter ** 3": "m^3", "kilogram / second": "kg/s", "ampere * second": "C",
             "kilogram * meter ** 2 / ampere ** 2 / second ** 3": "ohm",
             "ampere ** 2 * second ** 4 / kilogram / meter ** 2": "F"}
_KINDS = {"-": "dimensionless", "s": "time", "Hz": "frequency", "rad": "angle", "rad/s": "angular rate",
          "rad/s^2": "angular acceleration", "m": "length", "m/s": "speed", "m/s^2": "acceleration", "kg": "mass",
          "N": "force", "Nm": "torque or energy", "Pa": "pressure", "V": "voltage", "A": "current", "W": "power",
          "K": "temperature", "m^3/s": "volume flow", "m^3": "volume", "kg/s": "mass flow", "C": "charge",
          "ohm": "resistance", "F": "capacitance"}

_REGISTRY = pint.UnitRegistry()
_USER: dict[str, str] = {}  # the users' own names (data.units) defined so far: name -> definition


@dataclass(frozen=True)
class Unit:
    """A unit: its ``name``, its kind (``dimension``), ``factor`` and ``offset`` to SI
    (``SI = value * factor + offset``) and the SI unit ``si``."""

    name: str
    dimension: str
    factor: float
    si: str
    offset: float = 0.0


def define_units(units: Mapping[str, str] | None) -> None:
    """Make a data set's own unit names known (``data.units``: name -> pint definition, e.g.
    ``counts: 0.001 * m``). A name defined again the same way is fine; otherwise a DataError."""
    for name, definition in (units or {}).items():
        name, definition = str(name).strip(), str(definition).strip()
        if _USER.get(name) == definition:
            continue
        if name in _USER or name in _ALIASES:
            raise DataError(f"data.units.{name}: {name!r} is already a unit ({_USER.get(name) or _ALIASES[name]}); "
                            "choose another name")
        try:
            _REGISTRY.define(f"{name} = {definition}")
            _REGISTRY.Quantity(1.0, name).to_base_units()
        except Exception as error:  # noqa: BLE001 -- pint's many error types: one line naming the setting
            raise DataError(f"data.units.{name}: cannot define {name!r} as {definition!r} "
                            f"({type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}); "
                            "write it as pint reads it, e.g. counts: 0.001 * m") from None
        _USER[name] = definition
        _parse.cache_clear()


@functools.cache
def _parse(text: str) -> Unit | None:
    spelled = re.sub(r"(?<![A-Za-z])([a-zA-Zµμ]?)Ohm\b", r"\1ohm", _ALIASES.get(text, text)).replace("^", "**")
    try:
        zero = _REGISTRY.Quantity(0.0, spelled).to_base_units()
        one = _REGISTRY.Quantity(1.0, spelled).to_base_units()
    except Exception:  # noqa: BLE001 -- pint's undefined-unit, syntax and offset errors alike: not a unit
        return None
    base = str(one.units)
    si = _SI_NAMES.get(base) or f"{one.units:~P}"
    return Unit(text, _KINDS.get(si, base), float(one.magnitude - zero.magnitude), si, float(zero.magnitude))


def unit(name: str, channel: str | None = None) -> Unit:
    """The :class:`Unit` called ``name``; an unknown one is a DataError naming the channel."""
    text = "" if name is None else str(name).strip()
    found = _parse(text)
    if found is not None:
        return found
    where = f" of channel {channel!r}" if channel else ""
    raise DataError(
        f"unknown unit {text!r}{where}: give it as pint reads it (m/s, deg/s, kPa, degC, l/min, N*m, mA, ...; "
        "'-' for a dimensionless channel), or name your own in data.units, e.g. counts: 0.001 * m"
    )


def unit_factor(name: str, channel: str | None = None) -> float:
    """Factor that converts a value in unit ``name`` to SI (``SI = value * factor``); a unit with
    an offset (degC) is refused here: :func:`unit` gives both."""
    found = unit(name, channel)
    if found.offset:
        raise DataError(f"unit {found.name!r}{f' of {channel!r}' if channel else ''} has an offset to SI "
                        f"({found.offset:g} {found.si}); it cannot be used here, give a unit without one")
    return found.factor


def display_factor(unit_name: str, display_unit: str | None, channel: str | None = None) -> float:
    """Factor from SI to ``display_unit`` (``display = SI * factor``), checked against the
    kind of ``unit_name``; ``None`` shows the SI unit (factor 1)."""
    measured = unit(unit_name, channel)
    if display_unit is None:
        return 1.0
    shown = unit(display_unit, channel)
    if shown.si != measured.si:
        raise DataError(
            f"display unit {shown.name!r} of channel {channel!r} is a unit of {shown.dimension} ({shown.si}), "
            f"but its unit {measured.name!r} is one of {measured.dimension} ({measured.si}); units of "
            f"{measured.dimension}: {', '.join(units_of(measured.dimension)) or measured.si}"
        )
    if shown.offset:
        raise DataError(f"display unit {shown.name!r} of channel {channel!r} has an offset ({shown.offset:g} "
                        f"{shown.si}); shown values are only scaled: show it in {measured.si}")
    return 1.0 / shown.factor


COMMON = ("-", "%", "s", "ms", "min", "h", "Hz", "kHz", "rad", "mrad", "deg", "rad/s", "deg/s", "rpm", "rad/s^2",
          "deg/s^2", "m", "mm", "cm", "km", "m/s", "mm/s", "km/h", "mph", "m/s^2", "g", "kg", "t", "N", "kN", "Nm",
          "Pa", "kPa", "MPa", "bar", "mbar", "psi", "V", "mV", "A", "mA", "W", "kW", "K", "degC", "degF",
          "delta_degC", "l/min", "m^3/s", "kg/s")
KNOWN_UNITS: tuple[str, ...] = COMMON  # examples for messages; pint reads many more


def units_of(dimension: str) -> tuple[str, ...]:
    """The common units of a kind (e.g. ``"angle"`` -> rad, mrad, deg)."""
    return tuple(name for name in COMMON if (u := _parse(name)) is not None and u.dimension == dimension)


# --- a value given with its unit (a physical parameter) -------------------------------------

_NUMBER = re.compile(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*?)\s*")


def value_in(value: object, declared: str, name: str) -> float:
    """``value`` as a number in the unit ``declared`` (a parameter's, e.g. ``C``): a plain number is
    taken to be in it already; a value with a unit (``"2.5 Ah"``, ``"40 mOhm"``, ``{value: 2.5, unit:
    Ah}``, or any object with ``value`` and ``unit`` attributes) is converted by pint. A unit of
    another kind is a DataError naming ``name``: "capacity: 2.5 V is not a charge (the class declares C)".
    """
    if isinstance(value, bool):
        raise DataError(f"{name} must be a number (with a unit or not), got {value!r}")
    if isinstance(value, int | float) and not hasattr(value, "unit"):
        return float(value)
    if isinstance(value, Mapping) or hasattr(value, "unit"):
        get = value.get if isinstance(value, Mapping) else lambda key: getattr(value, key, None)
        extra = sorted(set(map(str, value)) - {"value", "unit"}) if isinstance(value, Mapping) else []
        if extra or get("value") is None or get("unit") is None:
            raise DataError(f"{name}: a value with a unit is {{value: <number>, unit: <unit>}} or '2.5 Ah', "
                            f"got {value!r}")
        number, given = get("value"), str(get("unit")).strip()
        text = f"{number} {given}"
        try:
            number = float(number)
        except (TypeError, ValueError):
            raise DataError(f"{name}: the value of {value!r} must be a number") from None
    elif isinstance(value, str):
        text = value.strip()
        match = _NUMBER.fullmatch(value)
        if match is None:
            raise DataError(f"{name}: cannot read {value!r} as a number with a unit (write e.g. '2.5 Ah', "
                            "'40 mOhm', or {value: 2.5, unit: Ah})")
        number, given = float(match.group(1)), match.group(2)
        if not given:
            return number  # a number written as text: in the declared unit
    else:
        try:
            return float(value)  # a numpy or torch scalar
        except (TypeError, ValueError):
            raise DataError(f"{name} must be a number or a number with a unit ('2.5 Ah'), got {value!r}") from None
    found = _parse(given)
    if found is None:
        raise DataError(f"{name}: unknown unit {given!r} in {text!r} (write it as pint reads it: Ah, mAh, mOhm, "
                        "kF, kN/m, deg, ...)")
    target = _parse("" if declared is None else str(declared).strip())
    if target is None:
        raise DataError(f"{name}: {text} has a unit, but the class declares {declared!r}, which is no unit pint "
                        f"reads: give a plain number in {declared}")
    if found.si != target.si:
        kind = target.dimension
        what = kind if kind == "dimensionless" else f"{'an' if kind[:1] in 'aeiou' else 'a'} {kind}"
        raise DataError(f"{name}: {text} is not {what} (the class declares {declared or '-'})")
    return (number * found.factor + found.offset - target.offset) / target.factor


class GivenQuantity(float):
    """A number given with its unit (a model YAML's ``capacity: 2.5 Ah``): its float value is in SI base
    units (9000.0), ``value`` and ``unit`` are as given, and :func:`value_in` converts it to the
    unit a parameter declares. Written back as it was given (``str``: ``2.5 Ah``)."""

    value: float
    unit: str

    def __new__(cls, value: float, unit_name: str, si_value: float) -> Self:
        given = super().__new__(cls, si_value)
        given.value, given.unit = float(value), unit_name
        return given

    def __repr__(self) -> str:
        return f"{self.value:g} {self.unit}"

    __str__ = __repr__

    def __reduce__(self) -> tuple:
        return GivenQuantity, (self.value, self.unit, float(self))


def given_value(value: object, name: str) -> float:
    """A configured value: a plain number as a float, a number with a unit (``"2.5 Ah"``, ``{value: 2.5,
    unit: Ah}``) as a :class:`GivenQuantity` (checked here: an unknown unit is a DataError naming
    ``name``; converted to a parameter's declared unit where the parameter is known)."""
    if isinstance(value, bool):
        raise DataError(f"{name} must be a number (with a unit or not), got {value!r}")
    if isinstance(value, GivenQuantity) or (isinstance(value, int | float) and not isinstance(value, bool)):
        return value if isinstance(value, GivenQuantity) else float(value)
    if isinstance(value, str) and _NUMBER.fullmatch(value) and not _NUMBER.fullmatch(value).group(2):
        return float(value)
    if isinstance(value, str):
        match = _NUMBER.fullmatch(value)
        number, given = (float(match.group(1)), match.group(2)) if match else (None, "")
    elif isinstance(value, Mapping):
        number, given = value.get("value"), str(value.get("unit", "")).strip()
    else:
        return value_in(value, "", name)  # a numpy scalar, or refused in one line
    found = _parse(given) if number is not None else None
    if found is None:
        value_in(value, "", name)  # raises the one-line reason (unreadable, unknown unit, ...)
        raise DataError(f"{name}: cannot read {value!r}")
    number = value_in(value, found.name, name)  # checks the mapping's keys and number
    return GivenQuantity(number, found.name, number * found.factor + found.offset)


# --- how values are shown, and the unit of a ratio --------------------------------------------

#: The unit an engineer reads a value in, by its SI unit (others are shown in SI); a channel's own
#: ``display_unit`` takes precedence for the channel's values.
READABLE: dict[str, str] = {"s": "ms", "rad": "deg", "rad/s": "deg/s"}


def readable(si: str) -> tuple[str, float]:
    """(unit, factor from SI) to show a value in SI unit ``si`` (:data:`READABLE`; others: ``si``, 1)."""
    shown = READABLE.get(si)
    return (si, 1.0) if shown is None else (shown, display_factor(si, shown))


_SUPERSCRIPT = str.maketrans("⁻⁰¹²³⁴⁵⁶⁷⁸⁹", "-0123456789")
_TO_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def parse_unit(unit: str) -> dict[str, int]:
    """``"m/s^2"`` -> ``{"m": 1, "s": -2}``; ``"-"``, ``"1"`` and ``""`` are dimensionless."""
    powers: dict[str, int] = {}
    numerator, *denominators = unit.replace(" ", "").split("/")
    for sign, part in [(1, numerator), *((-1, d) for d in denominators)]:
        for token in re.split(r"[·*.]", part):
            if token in ("", "-", "1"):
                continue
            match = re.fullmatch(r"([^\d^⁻⁰¹²³⁴⁵⁶⁷⁸⁹-]+)\^?(-?\d+)?", token.translate(_SUPERSCRIPT))
            if match is None:
                raise DataError(f"cannot read unit {unit!r} (write e.g. 'rad', 'rad/s', 'm/s^2')")
            base, power = match.group(1), int(match.group(2) or 1)
            powers[base] = powers.get(base, 0) + sign * power
    return {base: power for base, power in powers.items() if power != 0}


def format_unit(powers: Mapping[str, int]) -> str:
    """``{"m": 1, "s": -2}`` -> ``"m/s²"``; dimensionless -> ``"-"``."""
    def product(items: list[tuple[str, int]]) -> str:
        return "·".join(b + (str(p).translate(_TO_SUPERSCRIPT) if p != 1 else "") for b, p in items)

    above = [(b, p) for b, p in powers.items() if p > 0]
    below = [(b, -p) for b, p in powers.items() if p < 0]
    if not above and not below:
        return "-"
    return (product(above) or "1") + (f"/{product(below)}" if below else "")


def unit_ratio(numerator: str, denominator: str, power: int = 1) -> str:
    """The unit of a coefficient from ``denominator**power`` to ``numerator`` (rad / (rad/s) = s)."""
    powers = dict(parse_unit(numerator))
    for base, p in parse_unit(denominator).items():
        powers[base] = powers.get(base, 0) - power * p
    return format_unit({b: p for b, p in powers.items() if p != 0})
