"""What a learned block learned: a ladder of parametric forms fitted to its input → output behaviour.

The rungs, simplest first (u: the block's inputs, e: other signals, y: the block's output;
every record filtered from a steady start, first-order hold, see :mod:`hypa.explain.signals`):

    1. gain              y = b + Σ k_i u_i
    2. lag               y = b + Σ k_i u_i / (1 + τ s)
    3. lag and delay     y = b + Σ k_i u_i e^(-s d) / (1 + τ s)
    4. second order      y = b + Σ k_i (1 + T_i s) u_i e^(-s d) / (1 + 2ζ s/ω + s²/ω²)
    5. odd nonlinearity  the dynamics chosen among 1-4, fed with u_i + c_i u_i³
                         (the cubic part passes the poles and the delay, not a zero)
    6. extra signals     the form chosen among 1-5 plus Σ g_j e_j, the e_j either direct or
                         through the same poles and delay (whichever fits the training data better)

Every form is linear in its gains (b, k_i, k_i T_i, k_i c_i, g_j) once its time constants are
set, so the time constants are searched (a grid, then Nelder-Mead) with the gains solved by
least squares inside (variable projection); rung 4 starts from rung 3, rungs 5 and 6 from the
forms they build on.

Selection: each form is fitted on the training records and scored on the validation records
by R² (the share of the output's variance it explains), less ``penalty`` per parameter
(gains, offset, time constants); the chosen form is the one with the fewest parameters (then
the lowest rung) whose score is within ``margin`` of the best score. With the defaults
(0.002 and 0.005) a parameter must explain 0.2 % of the output's variance on data it was not
fitted to, and a richer form must beat the simpler one by half a percent more, so freedom
alone (a gain with noise fitted by a second-order form) never wins.

Uncertainty (1σ): a cluster-robust sandwich covariance of all parameters of a form over
~2 s segments of the training records (residuals of a learned block are coloured, so the
plain least-squares covariance would be far too optimistic), propagated to the reported
values (a zero T_i = (k_i T_i) / k_i, a cubic c_i) by the delta method.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace

import numpy as np
from scipy import optimize

from hypa.errors import UserError
from hypa.explain.signals import (
    Recording,
    Remainder,
    check_recordings,
    delayed,
    filtered,
    lag_filter,
    remainder,
    second_order_filters,
    unit_ratio,
)

NONLINEAR = {"static": (), "lag": ("lag",), "lag_delay": ("lag", "delay"),
             "second_order": ("natural_frequency", "damping", "delay")}
# upper bounds of the searched time constants: the natural frequency in units of the Nyquist
# frequency, the damping (beyond it the second order is a lag and a pole faster than the samples)
UPPER = {"natural_frequency": 1.0, "damping": 20.0}
DEFAULT_PENALTY = 0.002  # score lost per parameter (share of the output variance)
DEFAULT_MARGIN = 0.005  # a richer form must beat a simpler one by this much (share of the variance)
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
class Explanation:
    """The ladder fitted to one learned block, the chosen form and what it leaves unexplained."""

    output: str
    inputs: tuple[str, ...]
    extra: tuple[str, ...]
    dt: float  # [s]
    forms: tuple[FittedForm, ...]
    chosen: int  # index into forms
    remainder: Remainder
    penalty: float
    margin: float
    output_std: float  # [output unit] on validation

    @property
    def best(self) -> FittedForm:
        return self.forms[self.chosen]

    def describe(self) -> str:
        """One line in rounded numbers, e.g. ``y = 0.12 · u, lag 65 ms, − 0.004 s ·
        w; explains 93 % of the learned block``."""
        return describe(self)

    def unresolved(self) -> str | None:
        """Where extra signals were tried and the chosen form has none: the sentence that says a
        dependence on them is not resolved by these data (with what the richest such form adds)."""
        with_extra = [f for f in self.forms if f.form.extra != "none"]
        if not self.extra or not with_extra or self.best.form.extra != "none":
            return None
        richest = max(with_extra, key=lambda f: f.score)
        return (f"a dependence on {', '.join(self.extra)} is not resolved by these data: the best form with them "
                f"({richest.form.name}) explains {100 * (richest.r2_val - self.best.r2_val):+.1f} % of the "
                f"variance more on validation, less than its {richest.n_parameters - self.best.n_parameters} "
                f"extra parameter(s) and the margin cost")

    def to_dict(self) -> dict:
        """Plain JSON-ready values (SI units, as in the dataclasses)."""
        out = asdict(self)
        for form in out["forms"]:
            form.pop("theta"), form.pop("gains")
        out["chosen_form"] = self.best.form.name
        out["description"] = self.describe()
        out["unresolved"] = self.unresolved()
        return out


@dataclass(frozen=True)
class _Data:
    """The arrays of one split, per record: output, inputs, extra signals."""

    y: list[np.ndarray]
    u: list[list[np.ndarray]]
    e: list[list[np.ndarray]]

    @property
    def y_all(self) -> np.ndarray:
        return np.concatenate(self.y)


def explain(train: Sequence[Recording], val: Sequence[Recording], dt: float, output: str,
            inputs: Sequence[str], extra: Sequence[str] = (), units: Mapping[str, str] | None = None,
            penalty: float = DEFAULT_PENALTY, margin: float = DEFAULT_MARGIN,
            max_lag: float = 2.0, max_delay: float = 0.25) -> Explanation:
    """Fit the ladder to the block ``inputs`` → ``output`` and choose the simplest form that explains it.

    ``dt`` [s] is the records' sample time, ``units`` the unit of each signal (``"rad"``,
    ``"rad/s"``; missing ones are ``"-"``), ``max_lag`` and ``max_delay`` [s] bound the grids
    the searches start from (the searches may leave them).
    """
    inputs, extra = tuple(inputs), tuple(extra)
    names = _check_arguments(output, inputs, extra, dt, penalty, margin)
    check_recordings(list(train), names, "training")
    check_recordings(list(val), names, "validation")
    units = {n: (units or {}).get(n, "-") for n in names}
    data_train, data_val = _data(train, output, inputs, extra), _data(val, output, inputs, extra)
    if np.var(data_val.y_all) <= 1e-24 * max(np.mean(data_val.y_all**2), 1e-300):
        raise UserError(f"output {output!r} is constant on the validation records: nothing to explain")
    fit = _Fitter(data_train, data_val, dt, inputs, extra, units, output, penalty, max_lag, max_delay)
    forms = [fit.fit(LADDER[0], [])]
    forms.append(fit.fit(LADDER[1], fit.lag_grid(with_delay=False)))
    forms.append(fit.fit(LADDER[2], fit.lag_grid(with_delay=True)))
    forms.append(fit.fit(LADDER[3], fit.second_order_grid(*forms[2].theta)))
    base = forms[choose(forms, margin)]
    forms.append(fit.fit(replace(base.form, rung=5, name="odd nonlinearity", cubic=True), [base.theta]))
    if extra:
        base = forms[choose(forms, margin)]
        variants = [fit.fit(replace(base.form, rung=6, name=f"extra signals ({how})", extra=how),
                            [base.theta]) for how in ("direct", "filtered")]
        forms.append(max(variants, key=lambda f: f.r2_train))
    chosen = choose(forms, margin)
    predicted = fit.predict(forms[chosen], data_val)
    rest = remainder(data_val.y, predicted, [u[0] for u in data_val.u], dt, inputs[0], units[inputs[0]])
    return Explanation(output, inputs, extra, dt, tuple(forms), chosen, rest, penalty, margin,
                       float(np.std(data_val.y_all)))


def predict(explanation: Explanation, records: Sequence[Recording], form: int | None = None) -> list[np.ndarray]:
    """The output of a fitted form (default: the chosen one) per record, from the records' inputs
    and extra signals (each filtered from a steady start, as in the fit)."""
    fitted = explanation.forms[explanation.chosen if form is None else form]
    names = [*explanation.inputs, *explanation.extra]
    check_recordings(list(records), names, "prediction")
    data = _Data([np.zeros(len(r[names[0]])) for r in records],
                 [[r[n] for n in explanation.inputs] for r in records],
                 [[r[n] for n in explanation.extra] for r in records])
    fit = _Fitter(data, data, explanation.dt, explanation.inputs, explanation.extra, {},
                  explanation.output, explanation.penalty, 0.0, 0.0)
    return fit.predict(fitted, data)


def frequency_response(fitted: FittedForm, signal: str, frequency_hz: np.ndarray) -> np.ndarray:
    """The linear part of a fitted form from input ``signal`` to the output, k (1 + T s) e^(-s d) / D(s)
    at ``frequency_hz`` [Hz] (complex, output unit per input unit; a cubic term is left out: the
    response to small inputs)."""
    s = 2j * np.pi * np.asarray(frequency_hz, dtype=float)
    gain = fitted.value("gain", signal)
    if gain is None:
        raise UserError(f"the form {fitted.form.name!r} has no gain on {signal!r}")
    zero, lag, delay = (fitted.value(kind, signal if kind == "zero" else "") for kind in ("zero", "lag", "delay"))
    frequency, damping = fitted.value("natural_frequency"), fitted.value("damping")
    response = gain.value * (1.0 + (zero.value if zero else 0.0) * s)
    if delay is not None:
        response = response * np.exp(-s * delay.value)
    if lag is not None:
        response = response / (1.0 + lag.value * s)
    if frequency is not None:
        omega = 2 * np.pi * frequency.value
        response = response / (1.0 + 2 * damping.value * s / omega + (s / omega) ** 2)
    return response


def choose(forms: Sequence[FittedForm], margin: float) -> int:
    """The form with the fewest parameters (then the lowest rung) scoring within ``margin`` of the best."""
    best = max(f.score for f in forms)
    candidates = [i for i, f in enumerate(forms) if f.score >= best - margin]
    return min(candidates, key=lambda i: (forms[i].n_parameters, forms[i].form.rung))


def _check_arguments(output: str, inputs: tuple[str, ...], extra: tuple[str, ...], dt: float,
                     penalty: float, margin: float) -> list[str]:
    """The signal names the fit reads, after one-line checks of the arguments."""
    if not inputs:
        raise UserError("no inputs: name at least one input signal of the block")
    names = [output, *inputs, *extra]
    if len(set(names)) != len(names):
        raise UserError(f"output {output!r}, inputs {list(inputs)} and extra {list(extra)} must be "
                        "different signals")
    if not (np.isfinite(dt) and dt > 0):
        raise UserError(f"sample time dt must be a positive number of seconds, got {dt}")
    if penalty < 0 or margin < 0:
        raise UserError(f"penalty ({penalty}) and margin ({margin}) must not be negative")
    return names


def _data(records: Sequence[Recording], output: str, inputs: tuple[str, ...], extra: tuple[str, ...]) -> _Data:
    return _Data([r[output] for r in records], [[r[n] for n in inputs] for r in records],
                 [[r[n] for n in extra] for r in records])


class _Fitter:
    """Fits forms to one problem: regressors, the searches of time constants, scores, uncertainty."""

    def __init__(self, train: _Data, val: _Data, dt: float, inputs: tuple[str, ...],
                 extra: tuple[str, ...], units: dict[str, str], output: str, penalty: float,
                 max_lag: float, max_delay: float) -> None:
        self.train, self.val, self.dt = train, val, dt
        self.inputs, self.extra, self.units, self.output = inputs, extra, units, output
        self.penalty, self.max_lag, self.max_delay = penalty, max_lag, max_delay
        self.sst = float(np.sum((train.y_all - train.y_all.mean()) ** 2)) or 1.0

    # --- regressors ---------------------------------------------------------------------------

    def regressors(self, form: Form, theta: Sequence[float], data: _Data) -> list[np.ndarray]:
        """Per record, the columns the gains multiply: offset, per input its response (and the
        response's derivative for a zero, its cubic's response), then the extra signals."""
        delay, filters = self._dynamics(form, theta)

        def response(x: np.ndarray, which: slice = slice(None)) -> list[np.ndarray]:
            x = delayed(x, delay, self.dt)
            return [filtered(x, f) for f in filters[which]] if filters else [x]

        out = []
        for u, e in zip(data.u, data.e):
            columns = [np.ones_like(u[0])]
            for x in u:
                columns += response(x)
                columns += response(x**3, slice(0, 1)) if form.cubic else []
            if form.extra != "none":
                columns += [x if form.extra == "direct" else response(x, slice(0, 1))[0] for x in e]
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

    def solve(self, form: Form, theta: Sequence[float], data: _Data) -> tuple[np.ndarray, float]:
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
        r2_val = 1.0 - np.sum((y_val - X_val @ gains) ** 2) / np.sum((y_val - y_val.mean()) ** 2)
        n = len(theta) + len(gains)
        values = self._values(form, theta, gains)
        return FittedForm(form, values, n, 1.0 - sse / self.sst, float(r2_val),
                          float(r2_val - self.penalty * n), tuple(theta), tuple(gains))

    def predict(self, fitted: FittedForm, data: _Data) -> list[np.ndarray]:
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


# --- the one line ------------------------------------------------------------------------------

def describe(explanation: Explanation) -> str:
    """The chosen form in rounded numbers (two significant digits) with units, times in ms, and
    its share of the variance; the full values and their uncertainties are in the FittedForm."""
    fitted = explanation.best
    terms = []
    for signal in explanation.inputs:
        gain = fitted.value("gain", signal)
        cubic = fitted.value("cubic", signal)
        term = signal if cubic is None else (f"({signal} {_signed(cubic.value)} {_unit_text(cubic.unit)}"
                                             f"· {signal}³)")
        terms.append(f"{_signed(gain.value, first=not terms)} {_unit_text(gain.unit)}· {term}")
        zero = fitted.value("zero", signal)
        if zero is not None:
            terms.append(f"zero {_ms(zero.value)} ({signal})")
    dynamics = {"lag": "lag {} ms", "delay": "delay {} ms"}
    for kind, text in dynamics.items():
        v = fitted.value(kind)
        if v is not None and (kind != "delay" or v.value >= explanation.dt / 2):
            terms.append(text.format(_ms(v.value).removesuffix(" ms")))
    if fitted.value("natural_frequency") is not None:
        terms.append(second_order_text(fitted.value("natural_frequency").value, fitted.value("damping").value))
    for signal in explanation.extra:
        gain = fitted.value("gain", signal)
        if gain is not None:
            terms.append(f"{_signed(gain.value)} {_unit_text(gain.unit)}· {signal}")
    offset = fitted.value("offset")
    if abs(offset.value) > max(3 * offset.std, 0.01 * explanation.output_std):
        terms.append(f"{_signed(offset.value)} {_unit_text(offset.unit)}(offset)".rstrip())
    r2 = fitted.r2_val
    share = f"explains {round(100 * r2)} %" if r2 > 0 else f"explains nothing (R² {r2:.2f})"
    line = ", ".join(terms)
    return f"{explanation.output} = {line}; {share} of the learned block ({fitted.form.name})"


def second_order_text(frequency: float, damping: float) -> str:
    """``second order 1.2 Hz, damping 0.5`` for a resonance; two real poles (damping ≥ 1) read as
    the lags they are, ``lags 300 ms and 70 ms`` (1 + 2ζ s/ω + s²/ω² = (1 + T1 s)(1 + T2 s))."""
    if damping < 1.0:
        return f"second order {frequency:.2g} Hz, damping {damping:.2g}"
    omega, root = 2 * np.pi * frequency, np.sqrt(damping**2 - 1.0)
    return f"lags {_ms((damping + root) / omega)} and {_ms((damping - root) / omega)}"


def _signed(x: float, first: bool = False) -> str:
    text = f"{abs(x):.2g}"
    if first:
        return text if x >= 0 else f"−{text}"
    return f"+ {text}" if x >= 0 else f"− {text}"


def _unit_text(unit: str) -> str:
    return "" if unit == "-" else f"{unit} "


def _ms(seconds: float) -> str:
    """Two significant digits in ms, without an exponent below 10⁶ ms (120 ms, not 1.2e+02 ms)."""
    return f"{float(f'{1000 * seconds:.2g}'):g} ms"
