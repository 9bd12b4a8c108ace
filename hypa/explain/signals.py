"""The building blocks of the explanation ladder: recordings, units, and exact discrete filters.

Every form of the ladder is a sum of gains times *regressors*, signals made from the block's
inputs by a delay and a filter. The filters here are exact discretizations of continuous
transfer functions under a **first-order hold** (the input varies linearly between samples),
as a sampled, band-limited signal does; a zero-order hold would add half a sample of delay
to every lag. Each record is filtered separately from a steady start (the filter state in
equilibrium with the record's first sample), so no transient is invented at a record's start.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any

import numpy as np
from scipy import signal

from hypa.errors import UserError
from hypa.metrics import rms

MIN_SAMPLES = 16  # a record shorter than this holds no dynamics worth fitting


@dataclass(frozen=True)
class Recording:
    """Named 1-D signals of one record on one time base (SI units, sample time set elsewhere)."""

    name: str
    signals: Mapping[str, np.ndarray] = field(default_factory=dict)
    start: int = 0  # the sample of the source (a free run's time base) where the signals start

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self.signals:
            raise UserError(f"recording {self.name!r} has no signal {name!r} "
                            f"(it has {', '.join(sorted(self.signals)) or 'none'})")
        return np.asarray(self.signals[name], dtype=float)

    @classmethod
    def from_prediction(cls, prediction: Any, names: list[str] | tuple[str, ...]) -> Recording:
        """The signals ``names`` of a free run (a :class:`hypa.models.rollout.Prediction`),
        cropped to the samples where all of them have values.

        Internal signals (``prediction.signals``) start later than the measured inputs, so the
        common stretch is where the block's inputs and output all exist.
        """
        grid = {}
        for name in names:
            if name in prediction.signals:
                grid[name] = prediction.signal_on_grid(name)
            elif name in prediction.inputs:
                grid[name] = np.asarray(prediction.inputs[name], dtype=float)
            elif name in prediction.predicted:
                grid[name] = np.asarray(prediction.predicted[name], dtype=float)
            else:
                raise UserError(f"record {prediction.record!r} has no signal {name!r} (it has "
                                f"{', '.join(sorted({*prediction.signals, *prediction.inputs}))})")
        finite = np.all([np.isfinite(v) for v in grid.values()], axis=0)
        index = np.flatnonzero(finite)
        if index.size == 0:
            raise UserError(f"record {prediction.record!r}: signals {list(names)} never all have values")
        stretch = slice(index[0], index[-1] + 1)
        return cls(prediction.record, {n: v[stretch] for n, v in grid.items()}, int(index[0]))


def check_recordings(records: list[Recording], names: list[str], what: str) -> None:
    """One-line errors for what would otherwise fail deep inside a fit: no records, missing or
    non-finite signals, signals of different lengths, records too short to hold dynamics."""
    if not records:
        raise UserError(f"no {what} recordings: give at least one")
    for record in records:
        lengths = {name: record[name].shape for name in names}
        if any(len(shape) != 1 for shape in lengths.values()):
            raise UserError(f"recording {record.name!r}: signals must be 1-D arrays, got shapes {lengths}")
        if len({shape[0] for shape in lengths.values()}) > 1:
            raise UserError(f"recording {record.name!r}: signals of different lengths {lengths}")
        length = next(iter(lengths.values()))[0]
        if length < MIN_SAMPLES:
            raise UserError(f"recording {record.name!r} has {length} samples; needs at least {MIN_SAMPLES}")
        for name in names:
            if not np.all(np.isfinite(record[name])):
                raise UserError(f"recording {record.name!r}: signal {name!r} holds NaN or infinite values")


# --- units -----------------------------------------------------------------------------------

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
                raise UserError(f"cannot read unit {unit!r} (write e.g. 'rad', 'rad/s', 'm/s^2')")
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


# --- exact discrete filters (first-order hold) -------------------------------------------------

Filter = tuple[np.ndarray, np.ndarray]  # (b, a) of a discrete transfer function


def lag_filter(tau: float, dt: float) -> Filter:
    """1 / (1 + τ s) [τ in s] discretized exactly for an input linear between samples.

    With a = exp(-dt/τ) and c = (τ/dt)(1 - a):  x[n] = a x[n-1] + (1 - c) u[n] + (c - a) u[n-1].
    τ = 0 gives the identity, so a lag of zero is exactly the static gain.
    """
    if tau <= 1e-9 * dt:
        return np.array([1.0, 0.0]), np.array([1.0, 0.0])
    b, a = _lag_terms(complex(tau), dt)
    return b.real, a.real


def _lag_terms(tau: complex, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`lag_filter` for a complex time constant (one pole of a pair), as (b, a)."""
    a = np.exp(-dt / tau)
    c = tau / dt * -np.expm1(-dt / tau)
    return np.array([1.0 - c, c - a]), np.array([1.0, -a])


def second_order_filters(frequency: float, damping: float, dt: float) -> tuple[Filter, Filter]:
    """1 / D(s) and s / D(s) with D(s) = 1 + 2ζ s/ω + s²/ω², ω = 2π ``frequency`` [Hz],
    discretized exactly for an input linear between samples (first-order hold).

    The second lets a fitted zero (1 + T s) / D(s) stay linear in its coefficients. With the
    poles p1, p2 of D, 1/D = ω²/(p1 - p2) (1/(s - p1) - 1/(s - p2)) and 1/(s - p) is a lag
    of time constant -1/p and gain -1/p, discretized as :func:`lag_filter` (in complex numbers
    for a complex pair). A double pole (ζ = 1) is moved apart by 1e-6 in ζ.
    """
    omega = 2 * np.pi * frequency
    zeta = damping if abs(damping - 1.0) > 1e-6 else 1.0 + 1e-6
    p1, p2 = np.roots([1.0 / omega**2, 2.0 * zeta / omega, 1.0]).astype(complex)
    (b1, a1), (b2, a2) = _lag_terms(-1.0 / p1, dt), _lag_terms(-1.0 / p2, dt)
    den = np.convolve(a1, a2)
    filters = []
    for w1, w2 in ((1.0, -1.0), (p1, -p2)):  # 1/D and s/D
        scale = omega**2 / (p1 - p2)
        num = scale * (w1 * -1.0 / p1 * np.convolve(b1, a2) + w2 * -1.0 / p2 * np.convolve(b2, a1))
        filters.append((num.real, den.real))
    return filters[0], filters[1]


def filtered(u: np.ndarray, filt: Filter) -> np.ndarray:
    """``u`` through a discrete filter from a steady start (state in equilibrium with u[0])."""
    b, a = filt
    y, _ = signal.lfilter(b, a, u, zi=signal.lfilter_zi(b, a) * u[0])
    return y


def delayed(u: np.ndarray, delay: float, dt: float) -> np.ndarray:
    """u(t - delay) by linear interpolation between samples [delay in s], u[0] before the start."""
    if delay <= 0.0:
        return u
    shift = delay / dt
    whole, frac = int(np.floor(shift)), shift - np.floor(shift)
    padded = np.concatenate([np.full(whole + 1, u[0]), u])
    late = padded[1 : len(u) + 1]  # u[n - whole]
    later = padded[: len(u)]  # u[n - whole - 1]
    return (1.0 - frac) * late + frac * later


# --- what a fit leaves unexplained -------------------------------------------------------------

@dataclass(frozen=True)
class Band:
    """An octave of the frequency axis and the part of the unexplained output that lies in it."""

    low: float  # [Hz]
    high: float  # [Hz]
    share: float  # of the residual's power (all bands sum to 1)
    unexplained: float  # residual power / output power in this band


@dataclass(frozen=True)
class AmplitudeBin:
    """A quartile of an input's magnitude and the error of the fit where the input is that large."""

    low: float  # |input| [input unit]
    high: float
    rms_error: float  # [output unit]
    share: float  # of the residual's sum of squares (all bins sum to 1)


@dataclass(frozen=True)
class Remainder:
    """What the chosen form leaves unexplained on the validation records, and where."""

    share: float  # of the output variance (1 - R²)
    bands: tuple[Band, ...]
    amplitude_signal: str
    amplitude_unit: str
    amplitudes: tuple[AmplitudeBin, ...]

    @property
    def worst_band(self) -> Band:
        return max(self.bands, key=lambda b: b.share)

    @property
    def worst_amplitude(self) -> AmplitudeBin:
        return max(self.amplitudes, key=lambda b: b.rms_error)

    def describe(self) -> str:
        """E.g. ``unexplained 7 %: 45 % of it at 2-4 Hz; largest error where |u| is 0.05-0.1 rad``."""
        band, amp = self.worst_band, self.worst_amplitude
        unit = "" if self.amplitude_unit == "-" else f" {self.amplitude_unit}"
        return (f"unexplained {100 * self.share:.0f} %: {100 * band.share:.0f} % of it at "
                f"{band.low:.3g}-{band.high:.3g} Hz; largest error where |{self.amplitude_signal}| "
                f"is {amp.low:.3g}-{amp.high:.3g}{unit}")


def remainder(y: list[np.ndarray], predicted: list[np.ndarray], u: list[np.ndarray], dt: float,
              name: str, unit: str, octaves: int = 6) -> Remainder:
    """The residual ``y - predicted`` of records by octave band (Welch, averaged over records
    by length) and by quartile of ``|u|``."""
    residual = [a - b for a, b in zip(y, predicted)]
    y_all, r_all = np.concatenate(y), np.concatenate(residual)
    share = float(np.sum(r_all**2) / np.sum((y_all - y_all.mean()) ** 2))
    freq, p_res = _spectrum(residual, dt)
    _, p_out = _spectrum([v - y_all.mean() for v in y], dt)
    edges = [0.0, *(freq[-1] / 2.0 ** np.arange(octaves - 1, -1, -1))]
    edges = [e for e in edges if e == 0.0 or e > 2 * freq[1]]
    bands = []
    for low, high in pairwise(edges):
        inside = (freq >= low) & ((freq < high) | (high == edges[-1]))
        res, out = np.sum(p_res[inside]), np.sum(p_out[inside])
        bands.append(Band(float(low), float(high), float(res / max(np.sum(p_res), 1e-300)),
                          float(res / out) if out > 0 else float("nan")))
    magnitude = np.abs(np.concatenate(u))
    quartiles = np.quantile(magnitude, [0.0, 0.25, 0.5, 0.75, 1.0])
    which = np.clip(np.searchsorted(quartiles, magnitude, side="right") - 1, 0, 3)
    total = max(float(np.sum(r_all**2)), 1e-300)
    amplitudes = tuple(AmplitudeBin(float(quartiles[i]), float(quartiles[i + 1]),
                                    rms(r_all[which == i]) if np.any(which == i) else 0.0,
                                    float(np.sum(r_all[which == i] ** 2) / total)) for i in range(4))
    return Remainder(share, tuple(bands), name, unit, amplitudes)


def _spectrum(records: list[np.ndarray], dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Power per frequency bin [unit²], Welch on every record (mean kept), weighted by length."""
    n = min(256, min(len(r) for r in records))
    total = None
    for r in records:
        freq, psd = signal.welch(r, fs=1.0 / dt, nperseg=n, detrend=False)
        total = psd * len(r) if total is None else total + psd * len(r)
    weight = sum(len(r) for r in records)
    return freq, total / weight * (freq[1] - freq[0])
