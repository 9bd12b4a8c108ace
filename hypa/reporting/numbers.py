"""Numbers as every report and progress line writes them, once for all of hypa.

    significant(0.0123456)          # '0.0123'  (3 significant digits; '–' where not finite)
    quantity(0.0123, "s")            # '12.3 ms' (with its unit, in the unit an engineer reads)
    change_text(-0.95)               # '-95 %'   (the relative change of an error)
    percent_change(2.0, 2.1)         # '+5 %'
    share_text(0.015)                # '1.5 %'   (an error as a share of the output's variance)
    percent(0.42)                    # '42 %'    (a share or a gain, unsigned, two significant digits)
    elapsed(204.0)                   # '3.4 min'
    r_squared(0.9999963)             # '0.9999963' (a fit's R²: never '1.0000' while it is not 1)

A relative change of an error (new / old − 1) is written by :func:`change_text` everywhere: a fit
that diverged reads "did not converge", never "-8.5e19 %". Tables are :mod:`hypa.reporting.markdown`'s.
"""

from __future__ import annotations

import math

from hypa.core.units import readable


def significant(value: float | None, digits: int = 3) -> str:
    """``value`` to ``digits`` significant digits (``0.0123``, ``1.23e+04``); ``–`` where it is
    missing or not finite."""
    if value is None or not math.isfinite(value):
        return "–"
    return f"{value:.{digits}g}"


def r_squared(value: float | None) -> str:
    """A coefficient of determination to 4 decimals, or as many more (at most 8) as show 1 − R² to two
    significant digits (0.9842, 0.99934, 0.9999963): a near-perfect fit never reads 1.0000. ``–``
    where missing or not finite."""
    if value is None or not math.isfinite(value):
        return "–"
    decimals = 4 if value >= 1 or value < 0.999 else min(8, math.ceil(-math.log10(1 - value)) + 1)
    return f"{value:.{decimals}f}"


def quantity(value: float, unit: str, digits: int = 3) -> str:
    """``value`` [SI ``unit``] to ``digits`` significant digits with its unit, in the unit an
    engineer reads (seconds below 1 s as ms, angles in degrees: :func:`hypa.core.units.readable`);
    a dimensionless one (``-``) without a unit."""
    if unit != "s" or abs(value) < 1.0:
        unit, factor = readable(unit)
    else:
        factor = 1.0
    return f"{significant(value * factor, digits)} {'' if unit == '-' else unit}".rstrip()


def plain(value: float | None, digits: int = 4) -> str:
    """``digits`` significant digits without an exponent, for a table an engineer reads (179500,
    61.23, 0.0512); below 0.001 (or 0) the shortest form; empty where missing."""
    if value is None or not math.isfinite(value):
        return "" if value is None else str(value)
    if value == 0 or abs(value) < 1e-3:
        return f"{value:.{digits}g}"
    decimals = digits - 1 - math.floor(math.log10(abs(value)))
    return f"{round(value, decimals):.{max(decimals, 0)}f}"


def percent(fraction: float | None) -> str:
    """A share or a gain (0.42) in percent, unsigned rules of :func:`change_text`: two significant
    digits, at least whole percent (``42 %``, ``3.2 %``, ``0.41 %``); ``–`` where not known."""
    if fraction is None or not math.isfinite(fraction):
        return "–"
    return _two_digits(100 * fraction) + " %"


def _two_digits(value: float, sign: str = "") -> str:
    """Two significant digits, at least whole units, trailing zeros left out (``sign`` ``+``: signed);
    a value below -99.5 is not rounded to -100 (a drop to zero is the only -100 %)."""
    if abs(value) < 1e-3:
        return "0"
    decimals = max(0, 1 - math.floor(math.log10(abs(value))))
    if abs(round(value, decimals)) >= 10:
        decimals = 0
    while value > -100 and round(value, decimals) <= -100 and decimals < 6:
        decimals += 1
    text = f"{value:{sign}.{decimals}f}"
    return text.rstrip("0").rstrip(".") if "." in text else text


DIVERGED = 100.0  # an error that grew more than this many times: its fit did not converge


def change_text(change: float | None) -> str:
    """The relative change of an error, ``change`` = new / old − 1, as every report writes it.

    A signed percent with two significant digits and at least whole percent, trailing zeros left
    out (``-95 %``, ``+3.2 %``, ``-0.4 %``, ``+5 %``, ``+150 %``); a drop is never rounded to ``-100 %`` unless the
    error reached zero (``-99.6 %``); below 0.001 % it reads ``0 %``. An error that grew more than
    :data:`DIVERGED` times, or a change that is not finite, reads ``did not converge`` (the fit
    diverged: its percent would say nothing); ``None`` (not known) reads ``–``.
    """
    if change is None:
        return "–"
    change = float(change)
    if not math.isfinite(change):
        return "did not converge"
    if change + 1 > DIVERGED:
        return f"did not converge (error more than {DIVERGED:g}×)"
    return _two_digits(100 * change, "+") + " %"  # +5 %, not +5.0 %


def share_text(share: float | None) -> str:
    """An error as a share of the output's variance (1 − R²) in percent, three significant digits
    (``1.5 %``, ``120 %``); a model whose error is more than :data:`DIVERGED` times the variance, or
    not finite, ``did not converge``; ``None`` ``–``."""
    if share is None:
        return "–"
    if not math.isfinite(share) or share > DIVERGED:
        return "did not converge"
    return f"{100 * share:.3g} %"


def percent_change(before: float, after: float) -> str:
    """:func:`change_text` of an error that went from ``before`` to ``after`` (``before`` 0: an error
    that appeared where there was none did not converge; 0 to 0 is no change)."""
    if before == 0:
        return "0 %" if after == 0 else change_text(math.inf)
    return change_text(after / before - 1)


def elapsed(seconds: float | None) -> str:
    """A duration [s] as a report shows it: two significant digits, at least whole units, in s, min or
    h (``0.4 s``, ``12 s``, ``3.4 min``, ``75 min``, ``2.5 h``); ``–`` where it is not known."""
    if seconds is None or not math.isfinite(seconds) or seconds < 0:
        return "–"
    for unit, size, up_to in (("s", 1.0, 60.0), ("min", 60.0, 6000.0), ("h", 3600.0, math.inf)):
        if seconds < up_to:
            value = seconds / size
            return f"{value:.2g} {unit}" if value < 10 else f"{value:.0f} {unit}"
    return "–"  # not reached
