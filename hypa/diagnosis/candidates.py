"""One candidate per catalogue cause: fit its knob of :class:`ModelSpec` on the training records.

Every candidate starts from a ``base`` spec (the nominal physics, or the causes already
adopted) and shares one protocol: ``fit(train_records) -> estimate`` (SI units),
``predict(record) -> (L, 2)`` free-run states [rad/s, rad], ``n_params`` (what the penalty
counts) and ``summary()`` (the estimate in words). Fitting minimizes the training error

    J(θ) = Σ_records Σ_k Σ_c w_c (ŷ_c,k(θ) - y_c,k)²,      w_c = 1 / var(y_c on the training records)

(scale-free: both states weigh alike). Knobs that enter nonlinearly are searched on a coarse
grid refined twice around the best point (one batched pass per grid, so a saturating base
model costs a few passes, not hundreds); knobs that enter linearly (sensor offsets, the rear
steering ratio for a given time constant) are solved by least squares on the sensitivity
ŷ(θ + h) - ŷ(θ), exact for the linear physics and one Gauss-Newton step otherwise.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

from hypa.data import Record
from hypa.diagnosis.model import OFFSET_CHANNELS, STATES, ModelSpec, ay_threshold, simulate_batch

PARAMETERS = ("cf", "cr", "izz", "steering_ratio", "mass")  # lf / lr: same wheelbase trade-off as cf / cr
_UNITS = {"cf": "N/rad", "cr": "N/rad", "izz": "kg m²", "steering_ratio": "", "mass": "kg",
          "steering_wheel_angle": "rad", "yaw_rate": "rad/s", "side_slip": "rad"}


class Candidate(Protocol):
    cause: str
    n_params: int

    def fit(self, train_records: Sequence[Record]) -> dict: ...
    def predict(self, record: Record) -> np.ndarray: ...
    def summary(self) -> str: ...


class _Fitted:
    """Shared machinery: batched simulation, the training error J and the grid search."""

    cause = ""
    n_params = 0

    def __init__(self, base: ModelSpec, dt: float, weights: np.ndarray, only: str | None = None,
                 exclude: Sequence[str] = ()) -> None:
        """``only``: restrict a multi-choice candidate (parameter, offset channel) to one choice;
        ``exclude``: choices it may not take (channels whose offset is already adopted)."""
        self.base, self.dt, self.weights = base, float(dt), np.asarray(weights, dtype=float)
        self.only, self.exclude = only, tuple(exclude)
        self.spec: ModelSpec | None = None
        self.estimate: dict = {}
        self._records: Sequence[Record] = ()

    def simulate(self, specs: Sequence[ModelSpec], record: Record) -> np.ndarray:
        """(K, L, 2) free runs of ``specs`` over ``record``."""
        return simulate_batch(specs, record["steering_wheel_angle"], record.stack(STATES)[0], self.dt)

    def errors(self, specs: Sequence[ModelSpec]) -> np.ndarray:
        """J of each spec over the training records, (K,)."""
        total = np.zeros(len(specs))
        with np.errstate(over="ignore", invalid="ignore"):  # a grid point that diverges scores inf
            for record in self._records:
                residual = self.simulate(specs, record) - record.stack(STATES)[None]
                total += np.einsum("kld,d->k", residual**2, self.weights)
        return np.where(np.isfinite(total), total, np.inf)

    def grid_search(self, make: Callable[[float], ModelSpec], grid: np.ndarray, rounds: int = 2,
                    points: int = 7) -> tuple[float, float]:
        """Best θ of ``grid`` (then ``rounds`` finer grids between its neighbours) and its J."""
        values = np.asarray(grid, dtype=float)
        for round_ in range(rounds + 1):
            errors = self.errors([make(v) for v in values])
            i = int(np.argmin(errors))
            best, best_error = float(values[i]), float(errors[i])
            if round_ < rounds:
                values = np.linspace(values[max(i - 1, 0)], values[min(i + 1, len(values) - 1)], points)
        return best, best_error

    def linear_solve(self, makes: Sequence[Callable[[float], ModelSpec]], steps: Sequence[float]) -> list[float]:
        """Per make: θ minimizing J where ŷ(θ) ≈ ŷ(0) + θ S, S = (ŷ(h) - ŷ(0)) / h (weighted least
        squares); all 2 x len(makes) simulations in one batch."""
        n = len(makes)
        num, den = np.zeros(n), np.zeros(n)
        for record in self._records:
            sims = self.simulate([m(0.0) for m in makes] + [m(h) for m, h in zip(makes, steps)], record)
            sensitivity = (sims[n:] - sims[:n]) / np.asarray(steps)[:, None, None]  # (n, L, 2)
            num += np.einsum("kld,kld,d->k", sensitivity, record.stack(STATES)[None] - sims[:n], self.weights)
            den += np.einsum("kld,d->k", sensitivity**2, self.weights)
        return [float(a / b) if b > 0 else 0.0 for a, b in zip(num, den)]

    def fit(self, train_records: Sequence[Record]) -> dict:
        self._records = list(train_records)
        self.spec, self.estimate = self._fit()
        return self.estimate

    def _fit(self) -> tuple[ModelSpec, dict]:
        raise NotImplementedError

    def choice(self) -> str | None:
        """Which of its options a multi-choice candidate took (to refit just that one later)."""
        return None

    def predict(self, record: Record) -> np.ndarray:
        if self.spec is None:
            raise RuntimeError("fit() first")
        return self.simulate([self.spec], record)[0]

    def summary(self) -> str:
        return ", ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}" for k, v in self.estimate.items())


class Discretization(_Fitted):
    """The input is smooth, so a first-order hold replaces the zero-order hold (0 parameters)."""

    cause, n_params = "discretization", 0

    def _fit(self):
        return self.base.replace(hold="foh"), {"hold": "foh"}

    def summary(self) -> str:
        return f"a first-order hold instead of the {self.base.hold.upper()}"


class ParameterMismatch(_Fitted):
    """One vehicle parameter re-fitted (factor 0.4 ... 2.5 of its value); the best one on J wins."""

    cause, n_params = "parameter_mismatch", 1

    def _fit(self):
        nominal = self.base.vehicle.as_dict()
        factors = np.geomspace(0.4, 2.5, 15)
        coarse = [(n, f) for n in ([self.only] if self.only else PARAMETERS) for f in factors]
        errors = self.errors([self.base.with_vehicle(**{n: nominal[n] * f}) for n, f in coarse])
        name = coarse[int(np.argmin(errors))][0]
        factor, _ = self.grid_search(lambda f: self.base.with_vehicle(**{name: nominal[name] * f}), factors)
        value = nominal[name] * factor
        return self.base.with_vehicle(**{name: value}), {"parameter": name, "value": float(value)}

    def choice(self) -> str:
        return self.estimate["parameter"]

    def summary(self) -> str:
        e = self.estimate
        return f"{e['parameter']} = {e['value']:.4g} {_UNITS[e['parameter']]}"


class InputDelay(_Fitted):
    """Dead time d ∈ [0, 0.3] s between the measured steering and the front wheels."""

    cause, n_params = "input_delay", 1

    def _fit(self):
        delay, _ = self.grid_search(lambda d: self.base.replace(delay_s=d), np.arange(0.0, 0.31, 0.02))
        return self.base.replace(delay_s=delay), {"delay_s": float(delay)}

    def summary(self) -> str:
        return f"a dead time of {1000 * self.estimate['delay_s']:.0f} ms on the steering input"


class UnmodeledLag(_Fitted):
    """First-order lag τ ∈ [0, 0.4] s between the steering wheel and the front wheels."""

    cause, n_params = "unmodeled_lag", 1

    def _fit(self):
        tau, _ = self.grid_search(lambda t: self.base.replace(lag_tau_s=t), np.arange(0.0, 0.41, 0.025))
        return self.base.replace(lag_tau_s=tau), {"tau_s": float(tau)}

    def summary(self) -> str:
        return f"a first-order steering lag of τ = {1000 * self.estimate['tau_s']:.0f} ms"


class Saturation(_Fitted):
    """Saturating axles (magic formula, peak friction μ ∈ [0.3, 4]); reported as a_y threshold."""

    cause, n_params = "saturation", 1

    def _fit(self):
        log_mu, _ = self.grid_search(lambda m: self.base.replace(mu=math.exp(m)), np.log(np.geomspace(0.3, 4.0, 16)))
        mu = math.exp(log_mu)
        return self.base.replace(mu=mu), {"ay_threshold": ay_threshold(mu), "mu": mu}

    def summary(self) -> str:
        return (f"axle forces 5 % below linear from |a_y| = {self.estimate['ay_threshold']:.2f} m/s² "
                f"(peak friction μ = {self.estimate['mu']:.2f})")


class SensorOffset(_Fitted):
    """A constant bias on one channel (the one with the lowest J of the three). Each biased
    channel is a cause of its own: after one is adopted, the others are tested again."""

    cause, n_params = "sensor_offset", 1
    _STEPS = {"steering_wheel_angle": 0.01, "yaw_rate": 0.01, "side_slip": 0.005}  # sensitivity steps

    def _fit(self):
        channels = [self.only] if self.only else [c for c in OFFSET_CHANNELS if c not in self.exclude]
        makes = [lambda b, c=c: self.base.with_offset(c, self.base.offsets[OFFSET_CHANNELS.index(c)] + b)
                 for c in channels]
        specs = [m(b) for m, b in zip(makes, self.linear_solve(makes, [self._STEPS[c] for c in channels]))]
        best = int(np.argmin(self.errors(specs))) if len(specs) > 1 else 0
        channel = channels[best]
        return specs[best], {"channel": channel, "offset": float(specs[best].offsets[OFFSET_CHANNELS.index(channel)])}

    def choice(self) -> str:
        return self.estimate["channel"]

    def summary(self) -> str:
        e = self.estimate
        return f"a bias of {e['offset']:.3g} {_UNITS[e['channel']]} on the {e['channel']} sensor"


class UnmodeledInput(_Fitted):
    """Rear-wheel steering δr = k · lag_τ(δsw / i_s) through B's rear column (2 parameters).

    For each τ the response is linear in k (least squares); τ is searched on a grid, refined once.
    """

    cause, n_params = "unmodeled_input", 2

    def _fit(self):
        taus = np.array([0.0, 0.02, 0.05, 0.08, 0.12, 0.18, 0.25, 0.35])
        for _ in range(2):
            makes = [lambda k, t=t: self.base.replace(rear_ratio=k, rear_tau_s=t) for t in taus]
            specs = [make(k) for make, k in zip(makes, self.linear_solve(makes, [0.1] * len(makes)))]
            i = int(np.argmin(self.errors(specs)))
            best = specs[i]
            taus = np.linspace(taus[max(i - 1, 0)], taus[min(i + 1, len(taus) - 1)], 5)
        return best, {"channel": "rear_wheel_angle", "ratio": float(best.rear_ratio),
                      "tau_s": float(best.rear_tau_s)}

    def summary(self) -> str:
        e = self.estimate
        return (f"rear-wheel steering δr = {e['ratio']:.3f} δf, lagged by τ = {1000 * e['tau_s']:.0f} ms, "
                "acting through the rear-wheel-angle column of B")


CATALOGUE: dict[str, type[_Fitted]] = {kind.cause: kind for kind in (
    ParameterMismatch, UnmodeledInput, InputDelay, UnmodeledLag, Saturation, SensorOffset, Discretization)}
