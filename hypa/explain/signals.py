"""The building blocks of the explanation ladder: recordings, and the physics' filters and dead time.

Every form of the ladder is a sum of gains times *regressors*, signals made from the block's
inputs by a delay and a filter. The filters are hypa.physics's own elements (the lag
:class:`~hypa.physics.elements.FirstOrderLag`, the two poles of
:class:`~hypa.physics.elements.SecondOrder`) discretized exactly by
:func:`~hypa.physics.discretization.discretize` under a **first-order hold** (the input varies
linearly between samples), as a sampled, band-limited signal does; a zero-order hold would add
half a sample of delay to every lag. The delay is the physics's
:class:`~hypa.physics.elements.DeadTime`. Each record is filtered separately from a steady start
(the filter state in equilibrium with the record's first sample), so no transient is invented
at a record's start. What a fit leaves unexplained is :mod:`hypa.explain.residual`.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from scipy import signal

from hypa.core.errors import UserError
from hypa.physics.discretization import discretize
from hypa.physics.elements import DeadTime, FirstOrderLag, SecondOrder
from hypa.physics.lti import LTIModel
from hypa.physics.parameters import ParameterSpec, PhysicalParameters

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


# --- the physics's filters and dead time (first-order hold) ------------------------------------

Filter = tuple[np.ndarray, np.ndarray]  # (b, a) of a discrete transfer function


@functools.lru_cache(maxsize=4096)  # the searches' grids come back to the same time constants
def lag_filter(tau: float, dt: float) -> Filter:
    """1 / (1 + τ s) [τ in s], the physics's :class:`~hypa.physics.elements.FirstOrderLag` under
    a first-order hold: with a = exp(-dt/τ) and c = (τ/dt)(1 - a),
    x[n] = a x[n-1] + (1 - c) u[n] + (c - a) u[n-1]. τ = 0 gives the identity, so a lag of zero
    is exactly the static gain.
    """
    if tau <= 1e-9 * dt:
        identity = np.array([1.0, 0.0])
        identity.flags.writeable = False  # cached: shared by every caller
        return identity, identity
    return _held(FirstOrderLag(), {"tau_s": tau}, dt)[0]


@functools.lru_cache(maxsize=4096)
def second_order_filters(frequency: float, damping: float, dt: float) -> tuple[Filter, Filter]:
    """1 / D(s) and s / D(s) with D(s) = 1 + 2ζ s/ω + s²/ω², ω = 2π ``frequency`` [Hz]: the two
    states of the physics's :class:`~hypa.physics.elements.SecondOrder` (the low-passed input and
    its rate) under a first-order hold.

    The second lets a fitted zero (1 + T s) / D(s) stay linear in its coefficients.
    """
    lowpassed, rate = _held(SecondOrder(), {"gain": 1.0, "zero_s": 0.0, "natural_frequency_hz": frequency,
                                            "damping": damping}, dt)
    return lowpassed, rate


def _held(model: LTIModel, values: Mapping[str, float], dt: float) -> list[Filter]:
    """One discrete filter from a physics element's input to each of its states, under
    :func:`~hypa.physics.discretization.discretize`'s first-order hold.

    The hold's x[n+1] = Φ x[n] + Γ0 u[n] + Γ1 u[n+1] is, in w[n] = x[n] - Γ1 u[n], the standard
    w[n+1] = Φ w[n] + (Γ0 + Φ Γ1) u[n], x[n] = w[n] + Γ1 u[n]: the denominator is det(zI - Φ), the
    numerators follow from the Markov parameters h_0 = Γ1, h_k = Φ^(k-1) (Γ0 + Φ Γ1).
    """
    p = {name: torch.tensor(float(value), dtype=torch.float64) for name, value in values.items()}
    space = model.matrices(p)
    held = discretize(space.a, space.b, dt, "foh")
    phi, (gamma_0, gamma_1) = held.phi.numpy(), (t.numpy()[:, 0] for t in held.taps)
    den, power = [1.0], np.eye(len(phi))  # det(zI - Φ) by Faddeev-LeVerrier (np.poly's eigenvalues cost more)
    for k in range(1, len(phi) + 1):
        power = phi @ power
        den.append(-np.trace(power) / k)
        power = power + den[-1] * np.eye(len(phi))
    den = np.array(den)
    markov, step = [gamma_1], gamma_0 + phi @ gamma_1
    for _ in range(len(phi)):
        markov.append(step)
        step = phi @ step
    num = np.array([sum(den[i] * markov[j - i] for i in range(j + 1)) for j in range(len(den))])  # (n + 1, n)
    num.flags.writeable = den.flags.writeable = False  # cached: shared by every caller
    return [(num[:, state], den) for state in range(len(phi))]


def filtered(u: np.ndarray, filt: Filter) -> np.ndarray:
    """``u`` (T,) or signals (T, m) through a discrete filter from a steady start (state in
    equilibrium with u[0])."""
    b, a = filt
    y, _ = signal.lfilter(b, a, u, axis=0, zi=np.multiply.outer(signal.lfilter_zi(b, a), u[0]))
    return y


def delayed(u: np.ndarray, delay: float, dt: float) -> np.ndarray:
    """u(t - delay) [delay in s] of a signal (T,) or signals (T, m): the physics's
    :class:`~hypa.physics.elements.DeadTime` (linear between samples, u[0] before the start)."""
    if delay <= 0.0:
        return u
    dead_time = _dead_time(dt)
    dead_time.parameters_.set_values({"delay_s": float(delay)})
    x = torch.from_numpy(np.ascontiguousarray(u, dtype=float))
    with torch.no_grad():
        return dead_time(x.reshape(1, len(x), -1)).reshape(x.shape).numpy()


@functools.lru_cache(maxsize=8)
def _dead_time(dt: float) -> DeadTime:
    """One DeadTime per sample time, its delay set per call: building its parameters costs more
    than a shift (a fit shifts thousands of times; the fits run one after another, in one thread
    per process). Signed storage keeps the delay exact."""
    return DeadTime(PhysicalParameters([ParameterSpec("delay_s", 1.0, "s", positive=False)]), "delay_s", dt)
