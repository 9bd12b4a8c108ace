"""Markdown for the reports every command writes (``REPORT.md``, ``summary.md``, ``diagnosis.md``,
``benchmark.md``, ``explanation.md``, ``fleet.md``): one way to write a table, one way to write
the relative change of an error, and the reports' JSON without a non-finite number.

    table(["parameter", "value", "unit"], [["mass", "92.6", "kg"]], align="lrl")

gives the header row, the alignment row and one row per entry. A cell is written with ``str``;
a ``|`` inside a cell is escaped (``\\|``) unless it already is, so a cell never splits a row.
Numbers are written by :mod:`hypa.reporting.numbers`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from typing import Any

__all__ = ["cell", "json_ready", "row", "table"]

_MOVED = ("DIVERGED", "change_text", "elapsed", "percent_change", "share_text")  # to hypa.reporting.numbers


def __getattr__(name: str) -> Any:
    """The number formats this module re-exported until 2026-11-28: still found, with a deprecation warning."""
    if name not in _MOVED:
        raise AttributeError(f"module 'hypa.reporting.markdown' has no attribute {name!r}")
    import warnings

    from hypa.reporting import numbers

    warnings.warn(f"hypa.reporting.markdown.{name} is deprecated and goes in the next release: use "
                  f"hypa.reporting.numbers.{name}", DeprecationWarning, stacklevel=2)
    return getattr(numbers, name)

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
