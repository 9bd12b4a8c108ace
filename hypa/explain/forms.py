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

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace

import numpy as np

from hypa.core.errors import UserError
from hypa.explain.fitting import LADDER, Data, FittedForm, Fitter, Form, Value, to_data
from hypa.explain.residual import Remainder, remainder
from hypa.explain.signals import Recording, check_recordings

DEFAULT_PENALTY = 0.002  # score lost per parameter (share of the output variance)
DEFAULT_MARGIN = 0.005  # a richer form must beat a simpler one by this much (share of the variance)

__all__ = [
    "DEFAULT_MARGIN",
    "DEFAULT_PENALTY",
    "LADDER",
    "Explanation",
    "FittedForm",
    "Form",
    "Value",
    "choose",
    "describe",
    "explain",
    "frequency_response",
    "predict",
    "second_order_text",
]


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
    data_train, data_val = to_data(train, output, inputs, extra), to_data(val, output, inputs, extra)
    if np.var(data_val.y_all) <= 1e-24 * max(np.mean(data_val.y_all**2), 1e-300):
        raise UserError(f"output {output!r} is constant on the validation records: nothing to explain")
    fit = Fitter(data_train, data_val, dt, inputs, extra, units, output, penalty, max_lag, max_delay)
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
    data = Data([np.zeros(len(r[names[0]])) for r in records],
                 [[r[n] for n in explanation.inputs] for r in records],
                 [[r[n] for n in explanation.extra] for r in records])
    fit = Fitter(data, data, explanation.dt, explanation.inputs, explanation.extra, {},
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
