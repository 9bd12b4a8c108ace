"""Markdown for the reports every command writes (``REPORT.md``, ``summary.md``, ``diagnosis.md``,
``benchmark.md``, ``explanation.md``, ``fleet.md``): one way to write a table, one way to write
the relative change of an error, and the reports' JSON without a non-finite number.

    table(["parameter", "value", "unit"], [["mass", "92.6", "kg"]], align="lrl")

gives the header row, the alignment row and one row per entry. A cell is written with ``str``;
a ``|`` inside a cell is escaped (``\\|``) unless it already is, so a cell never splits a row.
Numbers are rounded by the caller, which knows their unit.

    change_text(-0.95)        # '-95 %'
    percent_change(2.0, 2.1)  # '+5 %'
    change_text(8.5e17)       # 'did not converge (error more than 100×)'

A relative change of an error (new / old − 1) is written by :func:`change_text` in every report:
a fit that diverged reads "did not converge", never "-8.5e19 %".
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from typing import Any

_ALIGN = {"l": "---", "r": "---:", "c": ":---:"}
_PIPE = re.compile(r"(?<!\\)\|")


def cell(value: object) -> str:
    """One cell: ``str(value)`` on one line, its bare ``|`` escaped."""
    return _PIPE.sub(r"\\|", str(value).replace("\n", " "))


def row(cells: Iterable[object]) -> str:
    """``| a | b | c |``."""
    return "| " + " | ".join(cell(c) for c in cells) + " |"


def table(header: Sequence[object], rows: Iterable[Sequence[object]], align: str | None = None) -> list[str]:
    """The lines of a markdown table: the header, the alignment row, the rows.

    ``align``: one letter per column, ``l`` (left, the default), ``r`` (right, for numbers) or
    ``c``; a row with another number of cells than the header is refused (ValueError): it would
    shift every column after it.
    """
    align = align or "l" * len(header)
    if len(align) != len(header) or set(align) - set(_ALIGN):
        raise ValueError(f"align needs one of l, r, c per column ({len(header)}), got {align!r}")
    lines = [row(header), "|" + "|".join(_ALIGN[a] for a in align) + "|"]
    for i, cells in enumerate(rows):
        cells = list(cells)
        if len(cells) != len(header):
            raise ValueError(f"row {i} has {len(cells)} cells for {len(header)} columns: {cells}")
        lines.append(row(cells))
    return lines


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
    percent = 100 * change
    if abs(percent) < 1e-3:
        return "0 %"
    decimals = max(0, 1 - math.floor(math.log10(abs(percent))))  # two significant digits, at least whole percent
    if abs(round(percent, decimals)) >= 10:
        decimals = 0
    while percent > -100 and round(percent, decimals) <= -100 and decimals < 6:  # a drop is not "-100 %"
        decimals += 1
    text = f"{percent:+.{decimals}f}"
    return (text.rstrip("0").rstrip(".") if "." in text else text) + " %"  # +5 %, not +5.0 %


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


def json_ready(value: Any) -> Any:
    """``value`` (nested dicts, lists and tuples of plain values) with every number that is not finite
    replaced by ``None``: JSON has no NaN or Infinity (Python writes them, other readers refuse them),
    so a report writes ``null`` there. numpy numbers become Python ones; the rest is kept as it is."""
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if isinstance(value, bool) or value is None or isinstance(value, (str, int)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if hasattr(value, "item") and callable(value.item):  # a numpy scalar (or a 0-d array)
        return json_ready(value.item())
    return value
