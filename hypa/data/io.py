"""One measured file -> a validated SI :class:`Record` of the declared channels.

Every problem raises :class:`DataError` naming the file, the column and the row; nothing is
dropped or repaired silently. The time base is a column (converted to seconds, its offset
removed so that it starts at 0, e.g. for Unix time) or, without a time column, the sample
index divided by the sample rate. A time column must increase strictly, with a regular step
at ``sample_rate_hz`` (1 % on the median step, 10 % on every single step).

ASAM MDF files (``.mf4``, ``.mdf``) have a time base per channel group; :mod:`hypa.data.mdf`
reads them and resamples every channel onto a regular time base at ``sample_rate_hz``
(``data.time`` does not apply to them).
"""

from __future__ import annotations

import difflib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from hypa.core.units import unit_factor
from hypa.data.channels import ChannelSpec
from hypa.data.errors import DataError
from hypa.data.expressions import Expression
from hypa.data.files import MDF_SUFFIXES, read_columns
from hypa.data.mdf import load_mdf_record
from hypa.data.records import Record

RATE_TOLERANCE = 0.01  # measured vs configured sample rate (relative)
STEP_TOLERANCE = 0.10  # a single time step vs the median step (relative)


def load_record(
    path: Path,
    channels: Sequence[ChannelSpec],
    time_column: str | None = "time",
    time_unit: str = "s",
    sample_rate_hz: float | None = 1024.0,
    with_eval: bool = True,
) -> Record:
    """Read one file into a :class:`Record` of ``channels`` in SI units.

    Evaluation channels are read only ``with_eval`` and only where the file has what they need
    (they are optional); every other channel must be in the file. An MDF file is resampled
    onto ``sample_rate_hz`` (``None``: its fastest channel's rate); a table file needs it.
    """
    path = Path(path)
    if path.suffix.lower() in MDF_SUFFIXES:
        return load_mdf_record(path, channels, sample_rate_hz, with_eval)
    if sample_rate_hz is None:
        raise DataError(f"{path}: the sample rate of a {path.suffix} file must be given")
    raw = read_columns(path)
    values: dict[str, np.ndarray | float] = {}
    for channel in channels:
        if channel.role == "evaluation" and not with_eval:
            continue
        optional = channel.role == "evaluation"
        if channel.expression is None:
            column = channel.column or channel.name
            if column not in raw:
                if optional:
                    continue
                raise DataError(_missing_column_message(path, channel.name, column, list(raw)))
            values[channel.name] = _numeric(path, channel.name, column, raw[column])
        else:
            expression = Expression(channel.expression, channel.name)
            if optional and not all(name in raw for name in expression.names):
                continue
            inputs = {n: _numeric(path, n, n, raw[n]) for n in expression.names if n in raw}
            values[channel.name] = expression.evaluate({**inputs, **_rest(raw, inputs)}, str(path))
    time = None
    if time_column is not None:
        if time_column not in raw:
            raise DataError(_missing_column_message(path, "time", time_column, list(raw)))
        time = _numeric(path, "time", time_column, raw[time_column])
    length = _length(path, values, time)
    converted: dict[str, np.ndarray] = {}
    for channel in channels:
        if channel.name in values:
            array = np.broadcast_to(np.asarray(values[channel.name], dtype=np.float64), (length,))
            if channel.expression is not None:
                _check_finite(path, f"channel {channel.name!r} ({channel.expression})", array)
            converted[channel.name] = array * channel.factor + channel.offset
    if time is None:
        time = np.arange(length) / float(sample_rate_hz)
    else:
        time = np.asarray(time, dtype=np.float64) * unit_factor(time_unit, "time")
        time = time - time[0]  # Unix time and other offsets: the record starts at 0 s
        _check_time(path, time_column, time, sample_rate_hz)
    return Record(path=path, time=time, channels=converted, sample_rate_hz=float(sample_rate_hz))


def _rest(raw: dict[str, np.ndarray], used: dict) -> dict[str, None]:
    """The file's other names, so that an expression's error message can list them all."""
    return {name: None for name in raw if name not in used}


def _length(path: Path, values: dict, time: np.ndarray | float | None) -> int:
    """The common length of every column read (a scalar broadcasts)."""
    lengths = {name: np.size(v) for name, v in values.items() if np.ndim(v) > 0 and np.size(v) > 1}
    if time is not None:
        lengths["time"] = int(np.size(time))
    if len(set(lengths.values())) > 1:
        raise DataError(f"{path}: columns have different lengths: {lengths}")
    if not lengths:
        raise DataError(f"{path}: no channel is a column of samples (only scalars)")
    length = next(iter(lengths.values()))
    if length < 2:
        raise DataError(f"{path}: a record needs at least 2 samples, got {length}")
    return length


def _label(name: str, column: str) -> str:
    return f"column {column!r}" if column == name else f"column {column!r} ({name})"


def _where(path: Path, name: str, column: str) -> str:
    return f"{path}: {_label(name, column)}"


def _row(path: Path, row: int) -> str:
    """Row as a 0-based sample index, and for CSV also the line an editor shows."""
    line = f" (line {row + 2} of the CSV)" if path.suffix.lower() == ".csv" else ""
    return f"row {row}{line}"


def _missing_column_message(path: Path, name: str, column: str, available: list[str]) -> str:
    guess = difflib.get_close_matches(column, available, n=1, cutoff=0.5)
    hint = f" (did you mean {guess[0]!r}?)" if guess else ""
    where = "data.time.column" if name == "time" else f"data.channels.{name}.column"
    return (
        f"{path}: column {column!r} for channel {name!r} not found{hint}; the file has: "
        f"{', '.join(available) or 'no columns'}. Set {where}=<column>."
    )


def _numeric(path: Path, name: str, column: str, raw: np.ndarray) -> np.ndarray | float:
    """The column as finite float64 (a 1x1 MATLAB variable as a float), or a DataError naming
    the offending row."""
    array = np.asarray(raw)
    if array.ndim == 2 and 1 in array.shape:  # MATLAB stores vectors as (n, 1) or (1, n)
        array = array.ravel()
    if array.ndim == 0 or (path.suffix.lower() == ".mat" and array.size == 1):
        array = array.reshape(1)
        scalar = True
    else:
        scalar = False
    if array.ndim != 1:
        raise DataError(f"{_where(path, name, column)} is not a 1-D column (shape {array.shape})")
    if array.size == 0:
        raise DataError(f"{_where(path, name, column)} has no rows")
    if array.dtype.kind in "biuf":
        values = array.astype(np.float64)
    else:
        values = np.empty(array.size)
        for row, item in enumerate(array):
            try:
                values[row] = np.nan if item is None else float(item)
            except (TypeError, ValueError):  # noqa: PERF203 -- the error names its row
                raise DataError(
                    f"{_where(path, name, column)}, {_row(path, row)}: {item!r} is not a number"
                ) from None
    _check_finite(path, _label(name, column), values)
    return float(values[0]) if scalar else values


def _check_finite(path: Path, what: str, values: np.ndarray) -> None:
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise DataError(
            f"{path}: {what} has {bad.size} missing or non-finite value(s) "
            f"(NaN, inf or empty); first at {_row(path, int(bad[0]))}"
        )


def _check_time(path: Path, column: str, time: np.ndarray, sample_rate_hz: float) -> None:
    where = _where(path, "time", column)
    step = np.diff(time)
    backwards = np.flatnonzero(step <= 0)
    if backwards.size:
        row = int(backwards[0]) + 1
        raise DataError(
            f"{where}, {_row(path, row)}: time is not strictly increasing "
            f"({time[row]!r} s after {time[row - 1]!r} s, offset removed)"
        )
    median = float(np.median(step))
    measured = 1.0 / median
    if abs(measured - sample_rate_hz) > RATE_TOLERANCE * sample_rate_hz:
        raise DataError(
            f"{where}: measured sample rate {measured:.6g} Hz (median step {median * 1e3:.6g} ms) "
            f"differs from the configured sample_rate_hz={sample_rate_hz:g} Hz by more than "
            f"{RATE_TOLERANCE:.0%}; set data.sample_rate_hz or check the time unit "
            f"(data.time.unit)"
        )
    irregular = np.flatnonzero(np.abs(step - median) > STEP_TOLERANCE * median)
    if irregular.size:
        row = int(irregular[0]) + 1
        raise DataError(
            f"{where}, {_row(path, row)}: irregular time step of {step[row - 1] * 1e3:.6g} ms "
            f"where the median step is {median * 1e3:.6g} ms ({irregular.size} such step(s)); "
            f"gaps are not interpolated, split the file at the gap"
        )
