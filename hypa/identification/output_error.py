"""Grey-box identification: the physical parameters that minimize the output (simulation) error.

The criterion is the free-run error of the model over the training records, each output
weighted by 1 / its variance, so that the cost is the mean over outputs of 1 - R²:

    V(θ) = (1 / p) Σ_o Σ_k (ŷ_o,k(θ) - y_o,k)² / (N σ_o²)

where ŷ(θ) runs free over each training record from the state the data give at its start (single
shooting) or, with the records cut into stretches, over each stretch from its own initial state,
estimated with the parameters and tied to the previous stretch's end by a continuity term
(multiple shooting, for a system whose free run integrates, drifts or diverges: :mod:`hypa.
identification.shooting`). It is minimized by scipy's trust-region reflective least squares
(``least_squares(method="trf")``) with a Jacobian from forward differences of float64 model runs,
in coordinates where a step means the same for every parameter (:func:`coordinates`): the log of
a positive parameter, a bounded one scaled to [0, 1] with those bounds, a signed one relative to
its nominal value. The trust region is measured in these coordinates, not rescaled by the
Jacobian's columns (scipy's ``x_scale="jac"``): that rescaling gives a parameter the data barely
see at one iterate (a tank's overflow level just above the levels reached) a step as large as its
sensitivity is weak, which throws it out of the data's range, where its gradient is 0 for good.
Nothing is random: the same data give the same parameters (to the round-off).

It stops at scipy's tolerances or, earlier, once it has settled at what the data can resolve:
when the last ``SETTLE`` iterations together lowered the cost by less than ``resolution`` (1 %)
of σ² τ, the rise in cost from moving the estimates by one standard deviation (σ² the residual
variance, τ the output errors' correlation time, below). Parameters the data cannot tell apart
otherwise creep along their valley for hundreds of iterations at an unchanged error.

Each estimate gets ± 1σ from the Jacobian at the optimum: σ² (JᵀJ)⁻¹ with σ² the residual
variance, its entries (i, j) scaled by √(τ_i τ_j). τ_j is the correlation time in samples
(1 + 2 Σ ρ_k over the lags where the autocorrelation ρ_k is positive) of the terms that parameter
j's gradient sums, the errors times their sensitivity to it: a free run's errors are smooth, so
N samples weigh as N / τ_j independent ones (without it, σ would be √τ_j times too small). It is
a diagonal approximation of the sandwich (Newey-West) covariance, asymptotic and local: read it
as the order of the uncertainty. The correlation matrix comes from the same
covariance. Warnings name a parameter that did not move, one at its bound, one the data do not
determine (σ larger than its value) and pairs that cannot be told apart (|ρ| > 0.99).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from scipy import sparse
from scipy.optimize import least_squares

from hypa.core.errors import UserError, one_line
from hypa.data import HypaDataModule, Record
from hypa.identification.result import Estimate, Identification
from hypa.identification.shooting import CONTINUITY, REFUSED_ERRORS, Refused, Shooting
from hypa.identification.stretches import Stretches
from hypa.models import ComposedModel
from hypa.physics.parameters import BOUNDED, LOG, ParameterSpec
from hypa.reporting.numbers import elapsed

log = logging.getLogger(__name__)

_INSIDE = 1e-9  # a bounded parameter stays this share of its interval inside its bounds
_MOVED = 1e-6  # a smaller change in the fit's coordinates: the parameter did not move
_AT_BOUND = 1e-4  # a bounded parameter this close to a bound (share of its interval): at its bound
_JOINED = 1e-3  # continuity defects (RMS, state std) above this: the stretches do not join (multiple shooting)
_DECADES = 4.0  # an unbounded parameter is searched within this many decades of its start (signed: 1e4 x |start|)
SETTLE = 5  # accepted iterations over which the fit's progress is weighed against the data's resolution
KEEP = 0.01  # a second fit (a limit out of reach started where it acts) is kept if it lowers the error by this share


class IdentificationError(UserError):
    """The identification cannot start (the model's free run is not finite at its nominal values)."""


@dataclass(frozen=True)
class IdentificationSettings:
    """How the output error is minimized.

    ``stretch_s`` [s]: the records are cut into stretches this long, each with its own estimated
    initial state, joined by continuity (multiple shooting); ``None`` runs each training record
    free from its start (single shooting). ``max_evaluations``:
    model runs at most (``None``: scipy's 100 per parameter); ``tolerance``: scipy's ``ftol``,
    ``xtol`` and ``gtol``; ``resolution``: converged once ``SETTLE`` iterations lower the cost by
    less than this share of the data's resolution σ² τ (the module docstring; ``None``: scipy's
    tolerances only); ``max_seconds``: stop after this long with the best point so far
    (``None``: no limit; a limit makes the result depend on the machine's speed);
    ``correlated``: |ρ| above which two parameters cannot be told apart.
    """

    stretch_s: float | None = None
    max_evaluations: int | None = None
    tolerance: float = 1e-8
    resolution: float | None = 0.01
    max_seconds: float | None = None
    correlated: float = 0.99

    def __post_init__(self) -> None:
        if self.stretch_s is not None and not (math.isfinite(self.stretch_s) and self.stretch_s > 0):
            raise ValueError(f"identification.stretch_s must be > 0 or null, got {self.stretch_s}")
        if self.max_evaluations is not None and self.max_evaluations < 1:
            raise ValueError(f"identification.max_evaluations must be >= 1 or null, got {self.max_evaluations}")
        if not (math.isfinite(self.tolerance) and 0 < self.tolerance < 1):
            raise ValueError(f"identification.tolerance must lie in (0, 1), got {self.tolerance}")
        if self.resolution is not None and not (math.isfinite(self.resolution) and self.resolution > 0):
            raise ValueError(f"identification.resolution must be > 0 or null, got {self.resolution}")
        if self.max_seconds is not None and not self.max_seconds > 0:
            raise ValueError(f"identification.max_seconds must be > 0 or null, got {self.max_seconds}")
        if not 0 < self.correlated < 1:
            raise ValueError(f"identification.correlated must lie in (0, 1), got {self.correlated}")


@dataclass(frozen=True)
class _Coordinate:
    """One parameter in the fit's coordinates z: physical θ = ``physical(z)``, dθ/dz = ``slope(z)``."""

    spec: ParameterSpec
    scale: float  # signed: |nominal| (1 when 0)

    def z(self, value: float) -> float:
        if self.spec.storage == BOUNDED:
            lo, hi = self.spec.bounds
            return (value - lo) / (hi - lo)
        return math.log(value) if self.spec.storage == LOG else value / self.scale

    def physical(self, z: float) -> float:
        if self.spec.storage == BOUNDED:
            lo, hi = self.spec.bounds
            return lo + (hi - lo) * z
        return math.exp(z) if self.spec.storage == LOG else z * self.scale

    def slope(self, z: float) -> float:
        if self.spec.storage == BOUNDED:
            return self.spec.bounds[1] - self.spec.bounds[0]
        return math.exp(z) if self.spec.storage == LOG else self.scale

    def limits(self, z0: float) -> tuple[float, float]:
        """The search range in z: a bounded parameter's bounds; otherwise ``_DECADES`` decades around
        its start, so that a fit the data push toward 0 or infinity stops at a finite, reported edge
        (a cornering stiffness of 1e18 N/rad is no estimate) instead of leaving the physics' range."""
        if self.spec.storage == BOUNDED:
            return _INSIDE, 1 - _INSIDE
        if self.spec.storage == LOG:
            return z0 - _DECADES * math.log(10), z0 + _DECADES * math.log(10)
        reach = 10**_DECADES * max(1.0, abs(z0))
        return z0 - reach, z0 + reach


def coordinates(model: ComposedModel, names: Sequence[str]) -> list[_Coordinate]:
    """The fit's coordinate of each parameter: log for positive, [0, 1] for bounded, relative for signed."""
    specs = model.parameters_.specs
    return [_Coordinate(specs[n], abs(specs[n].value) or 1.0) for n in names]


class _Stop(Exception):
    """Raised inside the residual to end the fit at its time limit."""


class _Settled(Exception):
    """Raised at an iterate ``v`` where the fit has settled at the data's resolution (its text says why)."""

    def __init__(self, v: np.ndarray, message: str) -> None:
        super().__init__(message)
        self.v = v


def settled(costs: Sequence[float], output: np.ndarray, problem: Shooting, share: float | None) -> str | None:
    """Why the fit has settled (see the module docstring), or ``None`` while it still makes progress.

    ``costs``: the cost at each accepted iterate so far (this continuity weight's); ``output``:
    the output rows of the residual at the last one."""
    if share is None or len(costs) <= SETTLE:
        return None
    gain = costs[-SETTLE - 1] - costs[-1]
    sigma2 = _residual_variance(float(output @ output), output.size, problem.p)
    tau = problem.output_correlation_time(output)
    resolution = sigma2 * tau
    if not gain < share * resolution:
        return None
    return (f"converged at the data's resolution: the last {SETTLE} iterations lowered the cost by {gain:.2g}, "
            f"under {share:g} of what moving the estimates by their σ costs ({resolution:.2g}: the residual "
            f"variance {sigma2:.2g} times the errors' correlation time {tau:.3g} samples; "
            "identification.resolution)")


def _silent(text: str) -> None:
    """No progress lines (the default): only the work cap's line is logged."""


def identify(model: ComposedModel, stretches: Stretches, names: Sequence[str] | None = None,
             settings: IdentificationSettings = IdentificationSettings(),
             progress: Callable[[str], None] = _silent) -> Identification:
    """Fit ``names`` (default: the model's trainable physical parameters) to minimize the output
    error over ``stretches`` (see the module docstring): single shooting with one stretch per
    record, multiple shooting with several (:mod:`hypa.identification.shooting`). The model is
    left at the identified values.

    Raises :class:`IdentificationError` when the model's free run is not finite at the start.
    """
    names = tuple(model.parameters_.trainable_names if names is None else names)
    if not names:
        raise IdentificationError("nothing to identify: the model has no trainable physical parameters")
    started = time.perf_counter()
    coords = coordinates(model, names)
    initial = model.parameters_.as_floats()
    z0 = np.array([c.z(initial[n]) for c, n in zip(coords, names)])
    limits = [c.limits(float(v)) for c, v in zip(coords, z0)]

    def set_z(z: np.ndarray) -> None:
        model.parameters_.set_values({n: c.physical(float(v)) for n, c, v in zip(names, coords, z)})

    problem = Shooting(model, stretches, set_z, len(names))
    v0 = problem.start(z0)
    lower = np.concatenate([[lo for lo, _ in limits], np.full(problem.size - len(names), -np.inf)])
    upper = np.concatenate([[hi for _, hi in limits], np.full(problem.size - len(names), np.inf)])
    best: dict[str, object] = {"cost": math.inf, "v": v0.copy()}
    fitting = True
    failed = np.full(1, np.inf)
    runs = [0]  # scipy's residual evaluations for the current continuity weight (its nfev, when it stops early)
    costs: list[float] = []  # at each accepted iterate, for the current continuity weight

    def residual(v: np.ndarray) -> np.ndarray:
        if fitting and settings.max_seconds is not None and time.perf_counter() - started > settings.max_seconds:
            raise _Stop
        try:
            r = problem.residual(v)
        except Refused:
            return np.full(failed.size, np.inf)  # no step there
        failed.resize(r.size, refcheck=False)
        cost = float(r @ r)
        if cost < best["cost"]:
            best.update(cost=cost, v=v.copy())
        return r

    def counted(v: np.ndarray) -> np.ndarray:
        runs[0] += 1
        return residual(v)

    try:
        error_initial = problem.output_cost(v0)
    except Refused:
        raise IdentificationError("the model's free run over the training data is not finite at its starting "
                                  "parameters: start nearer (the model's parameters), or restart the free runs "
                                  "from the data more often (identification.stretch_s)") from None
    iterates: list[np.ndarray] = []
    # the work cap: scipy's max_nfev (its default 100 per variable) for each continuity weight
    cap = (settings.max_evaluations or 100 * problem.size) * (len(CONTINUITY) if problem.junctions else 1)

    def jacobian(v: np.ndarray):
        iterates.append(v.copy())
        base = residual(v)
        progress(f"identification: iteration {len(iterates)}, output error "
                 f"{100 * problem.output_cost(v):.4g} % of the output variance"
                 + (f", continuity defects {problem.defect_rms(v):.2g} state std" if problem.junctions else ""))
        if fitting:
            costs.append(float(base @ base))
            why = settled(costs, problem.simulate(v)[0], problem, settings.resolution)
            if why is not None:
                raise _Settled(v.copy(), why)
        J = problem.jacobian(v, base, upper)
        if len(iterates) == 1 and fitting:  # the pace of one step: what the cap may cost, said once
            line = remaining(cap, time.perf_counter() - started, settings)
            (log.info if progress is _silent else progress)(f"identification: {line}")  # said once, either way
        return J

    v, converged, message, evaluations, capped = v0, False, "", 0, None
    for mu in CONTINUITY if problem.junctions else (None,):
        if mu is not None:
            problem.mu = mu
            best.update(cost=math.inf)
        costs.clear()
        runs[0] = 0
        try:
            result = least_squares(counted, v, jac=jacobian, bounds=(lower, upper), method="trf", x_scale=1.0,
                                   ftol=settings.tolerance, xtol=settings.tolerance, gtol=settings.tolerance,
                                   max_nfev=settings.max_evaluations)
            v, converged, message = result.x, result.status > 0, result.message
            evaluations += int(result.nfev)
            capped = "max_evaluations" if result.status == 0 else None  # scipy's max_nfev: the work cap
            if capped:
                message = (f"stopped at the cap of {settings.max_evaluations or 100 * problem.size} model runs "
                           "(identification.max_evaluations" + ("" if settings.max_evaluations else
                                                                ": null, scipy's 100 per variable")
                           + "; not converged)")
        except _Settled as at:
            v, converged, message, capped = at.v, True, str(at), None
            evaluations += runs[0]
        except _Stop:
            v, converged = np.asarray(best["v"]), False
            message, evaluations = (f"stopped at the cap of {settings.max_seconds:g} s (identification.max_seconds; "
                                    "the time limit), at the best point so far (not converged)"), -1
            capped = "max_seconds"
            break
    fitting = False  # the report's evaluations below run whatever the time limit
    J = jacobian(v)
    iterates.pop()  # that evaluation was for the covariance, not a step
    final_step = float(np.max(np.abs(iterates[-1][: len(names)] - iterates[-2][: len(names)]))) \
        if len(iterates) > 1 else 0.0
    error_final = problem.output_cost(v)
    defect = problem.defect_rms(v)
    z = v[: len(names)]
    tau = problem.correlation_times(v, J)
    cov_z = np.sqrt(np.outer(tau, tau)) * _covariance(J, error_final, problem.samples * problem.outputs)[
        : len(names), : len(names)]
    estimates = []
    for j, (name, c) in enumerate(zip(names, coords)):
        slope = c.slope(float(z[j]))
        variance = cov_z[j, j] * slope**2
        std = math.sqrt(variance) if math.isfinite(variance) else None
        estimates.append(Estimate(name, c.spec.unit, initial[name], c.physical(float(z[j])), std, c.spec.bounds))
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.sqrt(np.diag(cov_z))
        correlation = np.clip(cov_z / np.outer(d, d), -1.0, 1.0)
    correlation[~np.isfinite(correlation)] = np.nan
    warnings = _warnings(estimates, limits, z0, z, correlation, settings.correlated, converged, message, capped)
    if defect > _JOINED:
        warnings.append(f"the stretches do not join into one free run per record (continuity defects "
                        f"{defect:.2g} state std): the model cannot follow the whole records; the estimates "
                        "fit the stretches")
    identification = Identification(
        tuple(estimates), correlation.tolist(), converged, message, len(iterates), evaluations, final_step,
        error_initial, error_final, problem.stretches, problem.samples, time.perf_counter() - started,
        tuple(warnings), "multiple" if problem.junctions else "single", defect,
        {name: float(t) for name, t in zip(names, tau)}, capped)
    for line in warnings:
        log.warning("identification: %s", line)
    return identification


def identify_records(model: ComposedModel, dm: HypaDataModule, records: Sequence[Record],
                     settings: IdentificationSettings = IdentificationSettings(),
                     progress: Callable[[str], None] = _silent) -> Identification:
    """:func:`identify` over ``records`` of ``dm``: single shooting over whole records, or multiple
    shooting over stretches of ``settings.stretch_s``.

    Without ``stretch_s``, a model whose free run over a whole record is not finite at its start
    (an unstable model, or one that overflows) is fitted by multiple shooting instead, its
    stretches halved until every free run from the data is finite; the report says so.

    A fit that leaves a parameter where the free runs never meet its effect (a limit the state
    stays far inside of: :meth:`LTIModel.unreached`) has lost it for good, its gradient being 0
    there; a second fit starts it where it acts (the state's extreme over the runs), the others at
    the first fit's values, and the better of the two by the output error is kept (the report says
    which, with both errors; kept only where it gains more than ``KEEP`` of the error). A fit
    stopped at its time limit is not fitted again; the second fit has what is left of it.
    """
    first, longest = dm.past + 1, max(len(r) for r in records)
    samples = longest
    if settings.stretch_s is not None:
        stretches = Stretches.cut(dm, records, max(1, round(settings.stretch_s / dm.dt)))
    else:
        stretches = Stretches.cut(dm, records, samples)
        while samples > 2 * first and not math.isfinite(stretches.to(torch.float64).score(model)):
            samples //= 2
            stretches = Stretches.cut(dm, records, samples)
    result = identify(model, stretches, settings=settings, progress=progress)
    restart = {} if result.capped == "max_seconds" else unreached(model, stretches, result.values())
    if restart:
        result = _restarted(model, stretches, settings, progress, result, restart)
    if settings.stretch_s is None and samples < longest:
        note = (f"the free run over whole records is not finite at the starting parameters: multiple shooting "
                f"over stretches of {samples * dm.dt:.3g} s instead (identification.stretch_s sets them)")
        log.warning("identification: %s", note)
        result.warnings = (note, *result.warnings)
    return result


def unreached(model: ComposedModel, stretches: Stretches, names: Sequence[str]) -> dict[str, float]:
    """Those of ``names`` whose effect the model's runs over ``stretches`` never meet, each with a
    value where it acts (every started physics block's :meth:`LTIModel.unreached`, from the lowest and
    highest value of each of its states over the runs, in the states' units)."""
    try:
        states = stretches.to(torch.float64).physical_states(model)
    except REFUSED_ERRORS:  # a run the physics refuses at these values: nothing to say about its reach
        return {}
    values, out = model.parameters_.as_floats(), {}
    for name, x in states.items():
        system = model.blocks[name].model
        reach = {s: (lo, hi) for s, lo, hi in zip(system.state_names, x.min(0).tolist(), x.max(0).tolist())}
        out.update(system.unreached(reach, values))
    return {n: v for n, v in out.items() if n in names}


def _restarted(model: ComposedModel, stretches: Stretches, settings: IdentificationSettings,
               progress: Callable[[str], None], first: Identification, restart: dict[str, float]) -> Identification:
    """The better of ``first`` and a fit from its values with ``restart``'s (see identify_records):
    the second is kept only where it lowers the output error by more than ``KEEP`` of the first's,
    so a limit the data never reach is not moved to their edge for a gain at the noise's level. The
    second fit has what is left of ``max_seconds``; the report counts both fits' iterations, model
    runs and time, and keeps the user's initial values and error."""
    start = ", ".join(f"{n} = {first.values()[n]:.4g}" for n in restart)
    again = ", ".join(f"{n} = {v:.4g}" for n, v in restart.items())
    lost = f"{start} never reached by the free runs (no gradient there): a second fit from {again}"
    left = None if settings.max_seconds is None else settings.max_seconds - first.seconds
    if left is not None and left <= 0:
        return first
    progress(f"identification: {lost}, where it acts")
    model.parameters_.set_values(restart)
    try:
        second = identify(model, stretches, settings=dataclasses.replace(settings, max_seconds=left),
                          progress=progress)
    except (IdentificationError, *REFUSED_ERRORS) as error:  # the first fit stands
        model.parameters_.set_values(first.values())
        first.warnings = (f"{lost} could not run ({one_line(error)}): the first is kept", *first.warnings)
        return first
    better = second.error_final < (1 - KEEP) * first.error_final
    kept = second if better else first
    if not better:
        model.parameters_.set_values(first.values())
    else:  # its own start was the first fit's end: "did not move from" would name that, not the user's start
        second.warnings = tuple(w for w in second.warnings if " did not move from " not in w)
    initial = {e.name: e.initial for e in first.estimates}
    kept.estimates = tuple(dataclasses.replace(e, initial=initial[e.name]) for e in kept.estimates)
    kept.seconds, kept.error_initial = first.seconds + second.seconds, first.error_initial
    kept.iterations = first.iterations + second.iterations
    kept.evaluations = -1 if -1 in (first.evaluations, second.evaluations) else first.evaluations + second.evaluations
    note = (f"{lost} reached {100 * second.error_final:.3g} % of the output variance against "
            f"{100 * first.error_final:.3g} %: " + ("the second is kept" if better else
                                                    f"the first is kept (the second must gain more than {KEEP:.0%})"))
    kept.warnings = (note, *kept.warnings)
    return kept


def _residual_variance(cost: float, m: int, p: int) -> float:
    """σ² of ``m`` residuals whose squares sum to ``cost``, ``p`` parameters fitted to them."""
    return cost / max(m - p, 1)


def _covariance(J, cost: float, m: int) -> np.ndarray:
    """σ² (JᵀJ)⁻¹ in the fit's coordinates (J dense or sparse; m residuals of the output error);
    infinite variance along a direction J does not see."""
    J = J.toarray() if sparse.issparse(J) else J
    p = J.shape[1]
    sigma2 = _residual_variance(cost, m, p)
    _u, s, vt = np.linalg.svd(J, full_matrices=False)
    tiny = s <= s.max(initial=0.0) * 1e-10 if s.size else s
    with np.errstate(divide="ignore"):
        inverse = np.where(tiny, np.inf, 1.0 / np.where(tiny, 1.0, s) ** 2)
    if np.any(tiny):  # an undetermined direction: every parameter in it has no finite variance
        cov = (vt.T * np.where(tiny, 0.0, inverse)) @ vt
        blind = np.any(np.abs(vt[tiny]) > 1e-6, axis=0)
        cov[blind, :] = np.inf
        cov[:, blind] = np.inf
        return sigma2 * cov
    return sigma2 * (vt.T * inverse) @ vt


def remaining(cap: int, seconds: float, settings: IdentificationSettings) -> str:
    """What the work cap may still cost, from the pace of the first iteration (``seconds``: its model
    runs for the residual and the Jacobian): at most ``cap`` model runs, each at most one such step.
    Said, never acted on: only ``max_seconds`` stops on the clock."""
    worst = cap * seconds
    line = (f"at most {cap} model runs (identification.max_evaluations), about {elapsed(worst)} at this pace "
            f"({elapsed(seconds)} per iteration)")
    if settings.max_seconds is not None and settings.max_seconds < worst:
        line += f"; identification.max_seconds stops it after {elapsed(settings.max_seconds)}"
    return line


def _warnings(estimates: Sequence[Estimate], limits: Sequence[tuple[float, float]], z0: np.ndarray, z: np.ndarray,
              correlation: np.ndarray, correlated: float, converged: bool, message: str,
              capped: str | None = None) -> list[str]:
    out = [] if converged else [message if capped else f"did not converge: {message}"]
    for j, e in enumerate(estimates):
        lo, hi = limits[j]
        if abs(z[j] - z0[j]) < _MOVED:
            out.append(f"{e.name} did not move from {e.initial:.4g} {e.unit}".rstrip()
                       + ": the data barely depend on it, or it started at its optimum")
        if e.bounds is not None and min(z[j], 1 - z[j]) < _AT_BOUND:
            out.append(f"{e.name} = {e.value:.4g} {e.unit} is at its bound ({e.bounds[0]:g}, {e.bounds[1]:g})")
        elif e.bounds is None and min(z[j] - lo, hi - z[j]) < _AT_BOUND * (hi - lo):
            out.append(f"{e.name} = {e.value:.4g} {e.unit} ran to the edge of its search range ({_DECADES:g} decades "
                       f"from its start {e.initial:.4g}): the data push it toward "
                       f"{'zero' if z[j] - lo < hi - z[j] else 'infinity'}, so the model cannot fit them with a "
                       "physical value; it is no estimate")
        if e.std is None or e.std > abs(e.value):
            spread = ("its uncertainty is not finite: the data do not see it, alone or with others" if e.std is None
                      else f"± {e.std:.3g} {e.unit}, a larger uncertainty than its value")
            out.append(f"{e.name} is not determined by the data ({spread})")
    # parameters linked by |ρ| > correlated, directly or through others: one group, one warning
    group = list(range(len(estimates)))

    def root(i: int) -> int:
        while group[i] != i:
            i = group[i]
        return i

    for i in range(len(estimates)):
        for j in range(i + 1, len(estimates)):
            if math.isfinite(correlation[i, j]) and abs(correlation[i, j]) > correlated:
                group[root(j)] = root(i)
    groups = {r: [i for i in range(len(estimates)) if root(i) == r] for r in map(root, range(len(estimates)))}
    for members in groups.values():
        if len(members) > 1:
            names = ", ".join(estimates[i].name for i in members)
            strongest = max(abs(correlation[i, j]) for i in members for j in members if i < j)
            out.append(f"{names} cannot be told apart on these data (|correlation| up to {strongest:.3f}): "
                       "read them together, or fix all but one")
    return out
