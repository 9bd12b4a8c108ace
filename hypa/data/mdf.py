"""ASAM MDF measurement files (``.mf4``; MDF 3 ``.mdf`` too) -> an SI :class:`Record`.

An MDF file keeps its channels in groups, each group with time stamps of its own (its master
channel, in seconds), so channels logged at different rates (a CAN bus at 100 Hz, an analog
card at 1 kHz) sit side by side. hypa reads them with ``asammdf`` (``pip install 'hypa[mdf]'``)
and brings every channel it needs onto one regular time base:

* **Channels** by their name in the file (the declared ``column``, default the channel's
  name), with the file's conversion to physical values applied. A name in more than one group
  is an error (hypa cannot tell which is meant), so is a name the file lacks (the message
  lists the file's channels). An ``expression`` reads the channels it names, in the file's
  units, each resampled first; its result is in the declared ``unit``.
* **Units** come from the file. A channel without a unit in the file takes the declared one.
  Where the file's unit differs from the declared one but measures the same quantity (``deg``
  in the file, ``rad`` declared), the file wins: its numbers are in its unit, whatever a
  default declaration says. A different quantity (``mm`` in the file, ``rad`` declared) is an
  error naming both, and so is a unit hypa does not know (:mod:`hypa.core.units`).
* **Time** comes from the file's time stamps, never from an assumed rate. Each channel's
  stamps must increase strictly; a step more than :data:`GAP_STEPS` times its median step is a
  gap (an error; one or two dropped samples are bridged). The record covers the time where
  every channel read has samples, starting at 0 s.
* **Resampling** onto ``rate_hz`` (``data.sample_rate_hz``: the rate the files are read at;
  ``None``, for library use: the fastest channel's). A faster channel is first made regular at
  its own median rate, low-pass filtered by hypa's anti-aliasing filter
  (:func:`hypa.data.decimation.lowpass`: nothing above the new Nyquist frequency folds back),
  then linearly interpolated at the new time stamps; a slower or equally fast one is linearly
  interpolated (exact for ramps; accurate well below the channel's own Nyquist frequency).
  Decimation to ``data.rate_hz`` follows as for every other file.
"""

from __future__ import annotations

import difflib
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hypa.core.units import KNOWN_UNITS, unit
from hypa.data.channels import ChannelSpec
from hypa.data.decimation import lowpass
from hypa.data.errors import DataError
from hypa.data.expressions import Expression
from hypa.data.records import Record

log = logging.getLogger(__name__)

RATE_TOLERANCE = 0.01  # a channel at most 1 % faster than the target is interpolated, not filtered
GAP_STEPS = 3.0  # a time step above this many median steps is a gap, not a dropped sample
COVERAGE_WARNING = 0.99  # warn when the common time span is shorter than this share of a channel's
LISTED = 12  # channel names listed when one is missing
_SYNC = {0: "none", 1: "time", 2: "angle", 3: "distance", 4: "index"}


@dataclass(frozen=True, eq=False)
class Signal:
    """One MDF channel as the file holds it: time stamps [s], physical values in the file's
    ``unit`` (``""`` when it gives none) and the ``group`` it was read from."""

    name: str
    time: np.ndarray
    values: np.ndarray
    unit: str
    group: int

    @property
    def step_s(self) -> float:
        """Median time step [s] (robust to jitter and a dropped sample)."""
        return float(np.median(np.diff(self.time)))

    @property
    def rate_hz(self) -> float:
        """Median sample rate [Hz]."""
        return 1.0 / self.step_s


def read_signals(path: Path, names: Sequence[str]) -> dict[str, Signal]:
    """The channels ``names`` of an MDF file, checked (numeric, finite, time strictly
    increasing without gaps), unconverted. A missing name is a :class:`DataError` listing
    what the file has."""
    path = Path(path)
    with _open(path) as mdf:
        available = _channel_index(mdf)
        for name in names:
            if name not in available:
                raise DataError(_missing_message(path, name, None, list(available)))
        return {name: _read(mdf, path, name, available[name]) for name in dict.fromkeys(names)}


def load_mdf_record(
    path: Path,
    channels: Sequence[ChannelSpec],
    rate_hz: float | None = None,
    with_eval: bool = True,
) -> Record:
    """Read the declared ``channels`` of an MDF file into a :class:`Record` in SI units on a
    regular time base at ``rate_hz`` (``None``: the fastest channel's rate); see the module
    docstring. Evaluation channels are read only ``with_eval`` and only where the file has
    what they need."""
    path = Path(path)
    if rate_hz is not None and not rate_hz > 0:
        raise DataError(f"{path}: the rate to read an MDF file at must be positive, got {rate_hz}")
    with _open(path) as mdf:
        available = _channel_index(mdf)
        wanted: list[ChannelSpec] = []
        for channel in channels:
            if channel.role == "evaluation" and not with_eval:
                continue
            missing = [name for name in channel.file_names() if name not in available]
            if missing:
                if channel.role == "evaluation":
                    continue
                raise DataError(_missing_message(path, missing[0], channel, list(available)))
            wanted.append(channel)
        needed = dict.fromkeys(name for channel in wanted for name in channel.file_names())
        signals = {name: _read(mdf, path, name, available[name]) for name in needed}
    if not signals:
        raise DataError(f"{path}: none of the declared channels is in the file")
    factors = {channel.name: file_factor(path, channel, signals[channel.column or channel.name].unit)
               for channel in wanted if channel.expression is None}  # unit errors before any work
    time, rate = _time_base(path, signals, rate_hz)
    resampled = {name: resample(s.time, s.values, time, rate) for name, s in signals.items()}
    converted: dict[str, np.ndarray] = {}
    for channel in wanted:
        if channel.expression is None:
            factor, offset = factors[channel.name]
            converted[channel.name] = resampled[channel.column or channel.name] * factor + offset
        else:
            expression = Expression(channel.expression, channel.name)
            values = expression.evaluate({n: resampled[n] for n in expression.names}, str(path))
            values = np.broadcast_to(values, time.shape) * channel.factor + channel.offset
            bad = np.flatnonzero(~np.isfinite(values))
            if bad.size:
                raise DataError(
                    f"{path}: channel {channel.name!r} ({channel.expression}) has {bad.size} "
                    f"non-finite value(s); first at {bad[0] / rate:.6g} s"
                )
            converted[channel.name] = values
    for name, s in signals.items():
        how = "anti-aliased and resampled" if _filtered(s.rate_hz, rate) else "interpolated"
        log.debug("%s: %r (group %d) %d samples at %.6g Hz [%s], %s to %.6g Hz", path, name,
                  s.group, s.time.size, s.rate_hz, s.unit, how, rate)
    relative = np.arange(time.size) / rate  # the record starts at 0 s, as every other file
    return Record(path=path, time=relative, channels=converted, sample_rate_hz=rate)


def resample(time: np.ndarray, values: np.ndarray, new_time: np.ndarray,
             rate_hz: float) -> np.ndarray:
    """``values`` stamped ``time`` at the instants ``new_time`` of a regular time base at
    ``rate_hz``: anti-aliased first where the channel is faster (module docstring), then
    linearly interpolated. ``new_time`` lies within ``time[0] .. time[-1]``."""
    time = np.asarray(time, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    step = float(np.median(np.diff(time)))
    if _filtered(1.0 / step, rate_hz):
        count = round((time[-1] - time[0]) / step) + 1
        regular = time[0] + np.arange(count) * step  # the filter needs equidistant samples
        values = lowpass(np.interp(regular, time, values), 1.0 / (step * rate_hz))
        time = regular
    return np.interp(new_time, time, values)


def file_factor(path: Path, channel: ChannelSpec, file_unit: str) -> tuple[float, float]:
    """Factor and offset from the file's unit of ``channel`` to SI (see "Units" in the module docstring)."""
    text = str(file_unit or "").strip()
    if not text:
        return channel.factor, channel.offset
    column = channel.column or channel.name
    try:
        measured = unit(text)
    except DataError:
        raise DataError(
            f"{path}: MDF channel {column!r} (channel {channel.name!r}) is in {text!r}, a unit "
            f"hypa does not know (pint cannot read it; common units: {', '.join(KNOWN_UNITS)}). To use the declared "
            f"unit instead, read it as an expression: data.channels.{channel.name}.expression="
            f"'`{column}`' data.channels.{channel.name}.column=null"
        ) from None
    declared = unit(channel.file_unit, channel.name)
    if measured.dimension != declared.dimension:
        raise DataError(
            f"{path}: MDF channel {column!r} (channel {channel.name!r}) is in {text!r} "
            f"({measured.dimension}) in the file, but declared in {declared.name!r} "
            f"({declared.dimension}); check data.channels.{channel.name}.column, or declare "
            f"data.channels.{channel.name}.unit={text}"
        )
    if (measured.factor, measured.offset) != (declared.factor, declared.offset):
        log.info("%s: channel %r is in %r in the file (declared %r); the file's unit is used",
                 path, channel.name, text, declared.name)
    return measured.factor, measured.offset


def _filtered(channel_rate_hz: float, rate_hz: float) -> bool:
    """Whether a channel at ``channel_rate_hz`` needs the anti-aliasing filter."""
    return channel_rate_hz > rate_hz * (1.0 + RATE_TOLERANCE)


def _open(path: Path):
    try:
        from asammdf import MDF
    except ImportError as error:
        raise DataError(
            f"{path}: reading MDF files (.mf4, .mdf) needs the package asammdf: "
            f"pip install 'hypa[mdf]'"
        ) from error
    if not path.is_file():
        raise DataError(f"{path}: no such file")
    try:
        return MDF(path)
    except Exception as error:  # asammdf's parser fails in many ways on a file that is not MDF
        raise DataError(f"{path}: cannot be read as an MDF file ({error})") from error


def _channel_index(mdf) -> dict[str, list[tuple[int, int]]]:
    """Channel name -> its (group, index) places, master (time) channels left out."""
    masters = dict(mdf.masters_db)
    index: dict[str, list[tuple[int, int]]] = {}
    for name, places in mdf.channels_db.items():
        kept = [(g, i) for g, i in places if masters.get(g) != i]
        if kept:
            index[name] = kept
    return index


def _missing_message(path: Path, name: str, channel: ChannelSpec | None,
                     available: list[str]) -> str:
    guess = difflib.get_close_matches(name, available, n=1, cutoff=0.5)
    hint = f" (did you mean {guess[0]!r}?)" if guess else ""
    shown = ", ".join(available[:LISTED]) or "no channels"
    more = f", ... ({len(available) - LISTED} more)" if len(available) > LISTED else ""
    if channel is None:
        return f"{path}: channel {name!r} not found{hint}; the file has: {shown}{more}"
    if channel.expression is not None:
        what = f"expression of channel {channel.name!r} ({channel.expression}) uses {name!r}"
        fix = f"Correct data.channels.{channel.name}.expression"
    else:
        what = f"channel {name!r} for {channel.name!r}"
        fix = f"Set data.channels.{channel.name}.column=<MDF channel name>"
    return (f"{path}: {what}, which the file does not have{hint}; it has {len(available)} "
            f"channel(s): {shown}{more}. {fix}.")


def _read(mdf, path: Path, name: str, places: list[tuple[int, int]]) -> Signal:
    if len(places) > 1:
        groups = ", ".join(str(g) for g, _ in places)
        raise DataError(
            f"{path}: MDF channel {name!r} is in {len(places)} groups ({groups}) and hypa cannot "
            f"tell which is meant; save a file that holds it once (e.g. asammdf's MDF.filter)"
        )
    group, index = places[0]
    where = f"{path}: MDF channel {name!r} (group {group})"
    try:
        signal = mdf.get(name, group=group, index=index)
    except Exception as error:  # asammdf's own errors for a damaged block or record
        raise DataError(f"{where} cannot be read ({error})") from error
    sync = (getattr(signal, "master_metadata", None) or (None, 1))[1]
    if sync not in (0, 1):
        raise DataError(f"{where} is recorded over {_SYNC.get(sync, sync)}, not time; hypa "
                        f"needs time stamps")
    values = np.asarray(signal.samples)
    if values.ndim != 1 or values.dtype.kind not in "biuf":
        raise DataError(f"{where} is not a numeric 1-D channel (samples of type {values.dtype}, "
                        f"shape {values.shape})")
    time = np.asarray(signal.timestamps, dtype=np.float64)
    values = values.astype(np.float64)
    if values.size < 2:
        raise DataError(f"{where} has {values.size} sample(s); it needs at least 2")
    for what, array in (("time stamps", time), ("values", values)):
        bad = np.flatnonzero(~np.isfinite(array))
        if bad.size:
            raise DataError(f"{where}: {bad.size} non-finite {what} (NaN or inf); first at "
                            f"sample {bad[0]}")
    step = np.diff(time)
    backwards = np.flatnonzero(step <= 0)
    if backwards.size:
        k = int(backwards[0]) + 1
        raise DataError(f"{where}, sample {k}: time is not strictly increasing ({time[k]!r} s "
                        f"after {time[k - 1]!r} s)")
    median = float(np.median(step))
    gaps = np.flatnonzero(step > GAP_STEPS * median)
    if gaps.size:
        k = int(gaps[0])
        raise DataError(
            f"{where}: a gap of {step[k] * 1e3:.6g} ms after {time[k]:.6g} s where its median "
            f"step is {median * 1e3:.6g} ms ({gaps.size} such gap(s)); gaps are not interpolated, "
            f"cut the file at the gap"
        )
    return Signal(name, time, values, str(signal.unit or "").strip(), group)


def _time_base(path: Path, signals: dict[str, Signal],
               rate_hz: float | None) -> tuple[np.ndarray, float]:
    """The regular time stamps [s, file time] where every signal has samples, and the rate."""
    rate = float(rate_hz) if rate_hz is not None else max(s.rate_hz for s in signals.values())
    start = max(float(s.time[0]) for s in signals.values())
    stop = min(float(s.time[-1]) for s in signals.values())
    spans = ", ".join(f"{n!r} {s.time[0]:.6g}..{s.time[-1]:.6g} s" for n, s in signals.items())
    count = math.floor((stop - start) * rate + 1e-6) + 1 if stop > start else 0
    if count < 2:
        raise DataError(
            f"{path}: the channels overlap in time for less than two samples at {rate:g} Hz "
            f"({spans})"
        )
    for s in signals.values():
        if stop - start < COVERAGE_WARNING * (s.time[-1] - s.time[0]):
            log.warning("%s: the channels overlap only from %.6g to %.6g s; the rest is not "
                        "used (%s)", path, start, stop, spans)
            break
    return start + np.arange(count) / rate, rate
