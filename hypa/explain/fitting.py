"""Fitting the forms of :mod:`hypa.explain.forms`: their structure (:class:`Form`), their fitted
values (:class:`Value`, :class:`FittedForm`), and the :class:`Fitter` that builds a form's
regressors (each record filtered exactly under a first-order hold from a steady start), searches
its time constants (a grid, then Nelder-Mead, the gains solved by least squares inside) and
propagates a cluster-robust covariance to the reported values."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from hypa.core.metrics import errors
from hypa.core.units import unit_ratio
from hypa.explain.signals import Recording, delayed, filtered, lag_filter, second_order_filters

NONLINEAR = {"static": (), "lag": ("lag",), "lag_delay": ("lag", "delay"),
             "second_order": ("natural_frequency", "damping", "delay")}
# upper bounds of the searched time constants: the natural frequency in units of the Nyquist
# frequency, the damping (beyond it the second order is a lag and a pole faster than the samples)
UPPER = {"natural_frequency": 1.0, "damping": 20.0}
CLUSTER_S = 2.0  # [s] segments of the sandwich covariance: longer than the residual's correlation


@dataclass(frozen=True)
class Form:
    """The structure of one rung: its dynamics, a cubic input term, and how extra signals enter."""

    rung: int
    name: str
    dynamics: str  # a key of NONLINEAR
    cubic: bool = False
    extra: str = "none"  # "none", "direct" or "filtered"


LADDER = (Form(1, "gain", "static"), Form(2, "lag", "lag"), Form(3, "lag and delay", "lag_delay"),
          Form(4, "second order", "second_order"))


@dataclass(frozen=True)
class Value:
    """One fitted value in SI units with its 1σ uncertainty; ``signal`` names the signal it scales."""

    kind: str  # offset, gain, lag, delay, natural_frequency, damping, zero, cubic
    value: float
    std: float
    unit: str
    signal: str = ""

    @property
    def name(self) -> str:
        return f"{self.kind}:{self.signal}" if self.signal else self.kind


@dataclass(frozen=True)
class FittedForm:
    """One rung fitted on the training records and scored on the validation records."""

    form: Form
    values: tuple[Value, ...]
    n_parameters: int
    r2_train: float
    r2_val: float
    score: float  # r2_val - penalty * n_parameters
    theta: tuple[float, ...] = field(repr=False, default=())  # time constants (SI), as fitted
    gains: tuple[float, ...] = field(repr=False, default=())  # the linear coefficients

    def value(self, kind: str, signal: str = "") -> Value | None:
        """The fitted value of one kind (and signal), None where the form has none."""
        return next((v for v in self.values if v.kind == kind and v.signal == signal), None)


@dataclass(frozen=True)
class Data:
    """The arrays of one split, per record: output, inputs, extra signals."""

    y: list[np.ndarray]
    u: list[list[np.ndarray]]
    e: list[list[np.ndarray]]

    @property
    def y_all(self) -> np.ndarray:
        return np.concatenate(self.y)


def to_data(records: Sequence[Recording], output: str, inputs: tuple[str, ...], extra: tuple[str, ...]) -> Data:
    return Data([r[output] for r in records], [[r[n] for n in inputs] for r in records],
                 [[r[n] for n in extra] for r in records])


class Fitter:
    """Fits forms to one problem: regressors, the searches of time constants, scores, uncertainty."""

    def __init__(self, train: Data, val: Data, dt: float, inputs: tuple[str, ...],
                 extra: tuple[str, ...], units: dict[str, str], output: str, penalty: float,
                 max_lag: float, max_delay: float) -> None:
        self.train, self.val, self.dt = train, val, dt
        self.inputs, self.extra, self.units, self.output = inputs, extra, units, output
        self.penalty, self.max_lag, self.max_delay = penalty, max_lag, max_delay
        self.sst = float(np.sum((train.y_all - train.y_all.mean()) ** 2)) or 1.0

    # --- regressors ---------------------------------------------------------------------------

    def regressors(self, form: Form, theta: Sequence[float], data: Data) -> list[np.ndarray]:
        """Per record, the columns the gains multiply: offset, per input its response (and the
        response's derivative for a zero, its cubic's response), then the extra signals."""
        delay, filters = self._dynamics(form, theta)
        out = []
        for u, e in zip(data.u, data.e):
            # every signal that passes the dynamics, through one dead time and each filter at once:
            # per input u_i (and u_i³), then the extra signals that enter filtered
            passing = [s for x in u for s in ((x, x**3) if form.cubic else (x,))]
            passing += list(e) if form.extra == "filtered" else []
            late = delayed(np.column_stack(passing), delay, self.dt)
            through = [filtered(late, f) for f in filters] or [late]  # each (T, len(passing))
            columns, k = [np.ones_like(u[0])], 0
            for _ in u:
                columns += [t[:, k] for t in through]  # the response (and its rate for a zero)
                columns += [through[0][:, k + 1]] if form.cubic else []
                k += 2 if form.cubic else 1
            if form.extra != "none":
                columns += [x if form.extra == "direct" else through[0][:, k + j] for j, x in enumerate(e)]
            out.append(np.column_stack(columns))
        return out

    def _dynamics(self, form: Form, theta: Sequence[float]) -> tuple[float, list]:
        """(delay [s], filters) of a form with time constants ``theta`` (SI)."""
        p = dict(zip(NONLINEAR[form.dynamics], theta))
        if form.dynamics == "static":
            return 0.0, []
        if form.dynamics == "second_order":
            return p["delay"], list(second_order_filters(p["natural_frequency"], p["damping"], self.dt))
        return p.get("delay", 0.0), [lag_filter(p["lag"], self.dt)]

    def gain_names(self, form: Form) -> list[tuple[str, str]]:
        """(kind, signal) of each column of :meth:`regressors`."""
        names = [("offset", "")]
        for u in self.inputs:
            names += [("gain", u)] + ([("zero", u)] if form.dynamics == "second_order" else [])
            names += [("cubic", u)] if form.cubic else []
        return names + ([("gain", e) for e in self.extra] if form.extra != "none" else [])

    # --- fitting ------------------------------------------------------------------------------

    def solve(self, form: Form, theta: Sequence[float], data: Data) -> tuple[np.ndarray, float]:
        """Least-squares gains for time constants ``theta`` and the training sum of squares."""
        X, y = np.concatenate(self.regressors(form, theta, data)), data.y_all
        gains = np.linalg.lstsq(X, y, rcond=None)[0]
        return gains, float(np.sum((y - X @ gains) ** 2))

    def fit(self, form: Form, starts: Sequence[Sequence[float]]) -> FittedForm:
        """Fit one form: its time constants from the best of ``starts`` by Nelder-Mead, then the gains."""
        theta = self._search(form, starts) if NONLINEAR[form.dynamics] else np.array([])
        gains, sse = self.solve(form, theta, self.train)
        return self._fitted(form, theta, gains, sse)

    def lag_grid(self, with_delay: bool) -> list[np.ndarray]:
        """Starts of the lag search (0 and a geometric grid [s]) times delays [s]; Nelder-Mead refines."""
        lags = [0.0, *np.geomspace(self.dt / 4, self.max_lag, 12)]
        if not with_delay:
            return [np.array([t]) for t in lags]
        delays = np.linspace(0.0, self.max_delay, min(11, int(self.max_delay / self.dt) + 1))
        return [np.array([t, d]) for t in lags for d in delays]

    def second_order_grid(self, lag: float, delay: float) -> list[np.ndarray]:
        """Starts of the second-order search: natural frequency [Hz] × damping at no delay and at the
        delay of the lag-and-delay form, and the second-order form closest to that lag (two real poles, the
        faster one far away, so the search starts no worse than the lag)."""
        nyquist = 0.5 / self.dt
        # at no delay too: a second order with a zero (a lead, a non-minimum-phase transient)
        # may need none where the lag-and-delay form found one to mimic it
        grid = [np.array([f, z, d]) for f in np.geomspace(0.05, 0.4 * nyquist, 12)
                for z in (0.3, 0.6, 1.0, 2.0, 4.0) for d in sorted({0.0, delay})]
        if lag > 0:
            grid.append(np.array([3.0 / (np.pi * lag), 3.0, delay]))  # slow pole 2ζ/ω = τ
        return grid

    def _search(self, form: Form, candidates: Sequence[Sequence[float]]) -> np.ndarray:
        """The time constants with the least training error: best candidate, then Nelder-Mead
        in log time constants (lags, frequencies, dampings stay positive) and delay / dt."""
        to_z, from_z, steps = self._coordinates(form)

        def cost(z: np.ndarray) -> float:
            return self.solve(form, from_z(z), self.train)[1]

        z0 = min((to_z(np.asarray(c, dtype=float)) for c in candidates), key=cost)
        simplex = np.vstack([z0, z0 + np.diag(steps)])
        result = optimize.minimize(cost, z0, method="Nelder-Mead", options={
            "initial_simplex": simplex, "xatol": 1e-3, "fatol": 1e-9 * self.sst, "maxiter": 300})
        return from_z(result.x)

    def _coordinates(self, form: Form) -> tuple[Callable, Callable, np.ndarray]:
        """Maps between time constants (SI) and the unconstrained search coordinates."""
        names, dt = NONLINEAR[form.dynamics], self.dt
        is_delay = np.array([n == "delay" for n in names])
        # a mode above the Nyquist frequency is not resolved by the samples (and written as a physics
        # block it would be needlessly stiff): two real poles, one of them that fast, are a lag
        upper = np.array([UPPER.get(n, np.inf) for n in names]) * np.array(
            [0.5 / dt if n == "natural_frequency" else 1.0 for n in names])

        def to_z(theta: np.ndarray) -> np.ndarray:
            return np.where(is_delay, theta / dt, np.log(np.clip(theta, dt / 100, upper)))

        def from_z(z: np.ndarray) -> np.ndarray:
            return np.where(is_delay, np.abs(z) * dt, np.minimum(np.exp(np.minimum(z, 50.0)), upper))

        return to_z, from_z, np.where(is_delay, 0.5, 0.3)

    def _fitted(self, form: Form, theta: np.ndarray, gains: np.ndarray, sse: float) -> FittedForm:
        """Scores on validation and the values with their uncertainties."""
        X_val = np.concatenate(self.regressors(form, theta, self.val))
        y_val = self.val.y_all
        r2_val = errors(X_val @ gains, y_val)["r2"]
        n = len(theta) + len(gains)
        values = self._values(form, theta, gains)
        return FittedForm(form, values, n, 1.0 - sse / self.sst, float(r2_val),
                          float(r2_val - self.penalty * n), tuple(theta), tuple(gains))

    def predict(self, fitted: FittedForm, data: Data) -> list[np.ndarray]:
        """The form's output per record of ``data``."""
        return [X @ np.array(fitted.gains) for X in self.regressors(fitted.form, fitted.theta, data)]

    # --- uncertainty --------------------------------------------------------------------------

    def _values(self, form: Form, theta: np.ndarray, gains: np.ndarray) -> tuple[Value, ...]:
        """The reported values (time constants, gains, zeros, cubics) with delta-method 1σ."""
        names = [(n, "") for n in NONLINEAR[form.dynamics]] + self.gain_names(form)

        def report(params: np.ndarray) -> np.ndarray:
            out = params.copy()
            for i, (kind, signal) in enumerate(names):
                if kind in ("zero", "cubic"):
                    out[i] = params[i] / params[names.index(("gain", signal))]
            return out

        params = np.concatenate([theta, gains])
        cov = self._covariance(form, theta, gains)
        steps = 1e-6 * np.maximum(np.abs(params), 1e-6)
        jac = np.column_stack([(report(params + h * np.eye(len(params))[j]) - report(params)) / h
                               for j, h in enumerate(steps)])
        std = np.sqrt(np.maximum(np.diag(jac @ cov @ jac.T), 0.0))
        reported = report(params)
        return tuple(Value(kind, float(reported[i]), float(std[i]), self._unit(kind, signal), signal)
                     for i, (kind, signal) in enumerate(names))

    def _unit(self, kind: str, signal: str) -> str:
        y = self.units[self.output]
        return {"offset": y, "lag": "s", "delay": "s", "zero": "s", "natural_frequency": "Hz",
                "damping": "-", "gain": unit_ratio(y, self.units.get(signal, "-")),
                "cubic": unit_ratio("-", self.units.get(signal, "-"), 2)}[kind]

    def _covariance(self, form: Form, theta: np.ndarray, gains: np.ndarray) -> np.ndarray:
        """Cluster-robust (sandwich) covariance of (theta, gains) over segments of the records."""
        X = self.regressors(form, theta, self.train)
        columns = [self._sensitivity(form, theta, gains, j) for j in range(len(theta))]
        J = [np.column_stack([*(c[r] for c in columns), X[r]]) for r in range(len(X))]
        length = max(round(CLUSTER_S / self.dt), 8)
        bread = sum(j.T @ j for j in J)
        meat = np.zeros_like(bread)
        clusters = 0
        for j, x, y in zip(J, X, self.train.y):
            residual = y - x @ gains
            for start in range(0, len(y), length):
                score = j[start : start + length].T @ residual[start : start + length]
                meat += np.outer(score, score)
                clusters += 1
        inverse = np.linalg.pinv(bread)
        return inverse @ meat @ inverse * clusters / max(clusters - 1, 1)

    def _sensitivity(self, form: Form, theta: np.ndarray, gains: np.ndarray, j: int) -> list[np.ndarray]:
        """d(prediction)/d(theta_j) per training record, by a (one-sided at zero) difference."""
        h = 1e-3 * max(abs(theta[j]), self.dt) if NONLINEAR[form.dynamics][j] != "delay" else 0.1 * self.dt
        low, high = theta.copy(), theta.copy()
        low[j], high[j] = max(theta[j] - h, 0.0), theta[j] + h
        x_low, x_high = self.regressors(form, low, self.train), self.regressors(form, high, self.train)
        return [(b - a) @ gains / (high[j] - low[j]) for a, b in zip(x_low, x_high)]
