"""Fitting a candidate cause's knobs: physical parameters by Levenberg-Marquardt on finite
differences of forward runs, to convergence, and sensor offsets by exact least squares."""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence

import numpy as np
import torch

from hypa.diagnosis.edits import Candidate, set_free
from hypa.diagnosis.problem import Problem, TooLittleData
from hypa.models.spec import ModelSpec, ModelSpecError
from hypa.physics.fmu import FMUError
from hypa.physics.parameters import LOG, SIGNED
from hypa.reporting.numbers import quantity

LM_ITERATIONS = 40  # Levenberg-Marquardt steps at most (a fit ends earlier where it converges)
LM_WINDOWS_PER_BATCH = 2  # its fixed windows: this many batches' worth (256 by default)
LM_PROBE = 1e-5  # the finite-difference step on a raw knob (a relative 1e-5 for positive parameters)
LM_TOLERANCE = 1e-3  # converged: a step lowered the error by less than this share
LM_DAMPING = 1e-2  # the starting damping (relative to the normal matrix's diagonal)
LM_ROUND_OFF = 100.0  # a Jacobian column within this many times the finite differences' noise is round-off (_live)
LM_MAX_STEP = 1.0  # the largest move of a raw knob per Levenberg-Marquardt step (a factor e for a positive one)
SANE_DECADES = 3.0  # a positive knob more than this many decades from where its fit started has diverged
SANE_SIGNED = 1e3  # so has a signed knob beyond this many times its nominal magnitude
CONSTANT_Z = 5.0  # an offset whose stretch estimates correlate with an input's mean this many standard errors ...
CONSTANT_STRETCHES = 6  # ... (judged from this many training stretches up) is not constant (_follows_inputs),
CONSTANT_SHARE = 0.5  # ... where the part that follows the input is this share of its mean or more (a bias with
# a small gain error beside it stays an offset: the gain is a cause of its own)


class GradientFit:
    """A candidate's physical knobs being fitted on the training windows (the training loss),
    together with ``refine``, the knobs of the causes named before it (the causes are fitted
    jointly: a rear-steering ratio fitted on linear tires moves once saturation joins it).
    Resumable: the search advances only the promising fits to their full number of steps.

    Every fit takes Levenberg-Marquardt steps on a fixed set of training windows, in double
    precision, its Jacobian from finite differences of forward runs (one per knob: the knobs are
    few, and no backward pass through a step-by-step simulation, which costs about eight times
    the forward run), until a step lowers the error by less than ``LM_TOLERANCE`` (at most
    ``LM_ITERATIONS`` steps). Its budget is work, never seconds: every fit that runs runs to its
    end, on any machine (``Problem.fit_seconds``, off by default, is a user's cap and says so),
    whatever its start (an earlier cause's knobs at their optimum, a nominal value far off).
    :meth:`promise` is the screen that decides which fits of a round run."""

    def __init__(self, candidate: Candidate, problem: Problem, windows: Mapping[str, torch.Tensor],
                 refine: Sequence[str] = ()) -> None:
        self.candidate, self.problem, self.windows = candidate, problem, windows
        self.model = problem.build(set_free(candidate.spec, refine) if refine else candidate.spec)
        self.refine = [k for k in refine if k in self.model.parameters_.names]
        params = [p for p in self.model.parameters() if p.requires_grad]
        if not params:
            raise ModelSpecError(f"{candidate.key}: nothing to fit")
        shortfall = problem.evidence().fit_shortfall(sum(p.numel() for p in params))
        if shortfall:
            raise TooLittleData(shortfall)
        self.started, self.diverged, self.timed_out = time.perf_counter(), "", False
        raw = self.model.parameters_.raw
        self._knobs = {n: raw[n] for n in raw if raw[n].requires_grad}
        self._start = {n: float(p.detach()) for n, p in self._knobs.items()}
        self._sane = dict(self._start)  # the last values that passed :meth:`_check`
        # simulated step by step (Lur'e, scheduled, curved): a fit that costs several linear ones
        self.nonlinear = any(getattr(getattr(b, "model", None), "is_nonlinear", False)
                             for b in self.model.blocks.values())
        self.total, self.done = LM_ITERATIONS, 0
        self.damping = LM_DAMPING
        self.converged = False  # a step lowered the error by less than LM_TOLERANCE, or none lowered it
        self._last: torch.Tensor | None = None  # the residual at the knobs now, where known
        self._linearized: tuple[torch.Tensor, torch.Tensor] | None = None  # (residual, Jacobian) at the knobs now
        self.fixed = fixed_windows(problem, windows)
        self.knobs = params
        # the round's base model on the same windows (:func:`base_model`): its fit error is what
        # :meth:`promise` measures against (None: the start's), and a fit that starts at it (a weight at 0)
        # has its Jacobian's columns for the knobs of ``refine``, so its first Jacobian needs only its own
        self.base: Base | None = None

    @property
    def finished(self) -> bool:
        """Every step done, or stopped for good: diverged, or at the problem's time limit per fit."""
        return self.done >= self.total or bool(self.diverged) or self.timed_out or self.converged

    def _check(self) -> str:
        """Why the knobs left their physical range (not finite, a positive one more than
        ``SANE_DECADES`` decades from its start, a signed one beyond ``SANE_SIGNED`` times its
        nominal magnitude); empty when they did not."""
        params = self.model.parameters_
        for name, raw in self._knobs.items():
            value, storage = float(raw.detach()), params.specs[name].storage
            far = (abs(value - self._start[name]) > SANE_DECADES * math.log(10.0) if storage == LOG
                   else storage == SIGNED and abs(value) > SANE_SIGNED)
            if not math.isfinite(value):
                return f"{name} is no longer a finite number"
            if far:
                return (f"{name} left its physical range (more than {SANE_DECADES:g} decades from its start)"
                        if storage == LOG else f"{name} left its physical range (beyond {SANE_SIGNED:g} times "
                        "its nominal size)")
        return ""

    def advance(self, share: float) -> None:
        """Go on until ``share`` of the total steps are done (or the fit stopped for good: it
        diverged, :meth:`_check`, and keeps its last sane values; or it reached the problem's
        time limit per fit)."""
        while self.done < math.ceil(share * self.total) and not self.finished:
            limit = self.problem.fit_seconds
            if limit is not None and time.perf_counter() - self.started > limit:
                self.timed_out = True
                break
            try:
                self._least_squares_step()
            except (ArithmeticError, torch.linalg.LinAlgError) as error:
                self.diverged = f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}"
            self.diverged = self.diverged or self._check()
            if self.diverged:
                with torch.no_grad():
                    for name, raw in self._knobs.items():
                        raw.fill_(self._sane[name])
                break
            self._sane = {n: float(p.detach()) for n, p in self._knobs.items()}
            self.done += 1

    def _residual(self) -> torch.Tensor:
        return window_residual(self.model, self.fixed, self.problem.dm.past + 1)

    @torch.no_grad()
    def _linearize(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The residual at the knobs now and its Jacobian (finite differences of forward runs)."""
        if self._linearized is not None:
            return self._linearized
        r0 = self._last if self._last is not None else self._residual()  # the previous step's accepted run
        if not math.isfinite(float(r0 @ r0)):
            raise ValueError("the model's error is not finite at the start of a step")
        shared = self.base.columns if self.base is not None and self.done == 0 and self._at_base(r0) else {}
        names = {id(p): n for n, p in self._knobs.items()}
        columns = _columns(self._residual, [(names.get(id(k), ""), k) for k in self.knobs], r0, shared)
        self._linearized = (r0, torch.stack(columns, 1))
        return self._linearized

    def _at_base(self, residual: torch.Tensor) -> bool:
        """Whether the fit starts at the round's base model (its error on the windows the base's, to round-off)."""
        return self.base is not None and math.isclose(float(residual @ residual), self.base.cost, rel_tol=1e-9)

    def promise(self) -> float | None:
        """The score test of a fit: the share of the round's fit error (the base model's,
        ``base.cost``, on the same windows) that the first Gauss-Newton step from where the fit
        starts promises to remove, 1 - (r'r - g' (J'J)⁻¹ g) / base with g = J'r (a
        Lagrange-multiplier test: what the knobs could explain to first order). Most fits start
        at the model as it was (a weight at 0: r'r is the base's); one that cannot (a state's limit
        starts at the 90th percentile of where it goes, clipping the rest) must first win back
        what its start costs: a step that only undoes the clipping promises nothing. (A swapped
        system, ``Candidate.replaces``, is fitted whatever it promises: its start is a guess in
        another parametrization, :func:`hypa.diagnosis.race.evaluate_round`.) One
        Jacobian, which the fit's first step then reuses. ``None`` for a fit that has started or
        stopped; ``NaN`` where the start is not finite."""
        if self.done or self.finished:
            return None
        try:
            r0, jacobian = self._linearize()
        except (ArithmeticError, ValueError, torch.linalg.LinAlgError):
            return math.nan
        jacobian, _ = _live(jacobian, r0)
        gradient = jacobian.T @ r0
        # gelsd (SVD): a knob whose column is 0 where the fit starts (a mode's time constant while its
        # weights are 0) must drop out, not zero the whole solution (gelsy, the default, did that)
        normal = jacobian.T @ jacobian
        solution = torch.linalg.lstsq(normal, gradient.unsqueeze(-1), driver="gelsd").solution.squeeze(-1)
        promised, cost = float(gradient @ solution), float(r0 @ r0)
        base = cost if self.base is None else self.base.cost
        if not (base > 0 and math.isfinite(promised)):
            return math.nan
        return min(max(1.0 - (cost - promised) / base, 0.0), 1.0)

    @torch.no_grad()
    def _least_squares_step(self) -> None:
        """One Levenberg-Marquardt step on the raw knobs (relative for positive parameters, so one
        finite-difference step fits all); the damping grows until the step lowers the error."""
        r0, jacobian = self._linearize()
        self._linearized = None  # the knobs move: the next step linearizes again
        cost = float(r0 @ r0)
        jacobian, dead = _live(jacobian, r0)
        normal, gradient = jacobian.T @ jacobian, jacobian.T @ r0
        normal = normal + torch.diag(dead.to(normal.dtype))
        while self.damping < 1e6:
            step = torch.linalg.solve(normal + self.damping * torch.diag(torch.diagonal(normal) + 1e-12), -gradient)
            step = step * min(1.0, LM_MAX_STEP / max(float(step.abs().max()), 1e-300))  # a trust region
            for knob, delta in zip(self.knobs, step):
                knob += delta
            try:  # a model that fails at the trial values (an FMU that refuses them) is a step rejected
                trial = self._residual()
            except FMUError:
                trial = torch.full_like(r0, math.nan)
            if bool(torch.isfinite(trial).all()) and float(trial @ trial) < cost:
                self.damping, self._last = max(self.damping / 3.0, 1e-6), trial
                self.converged = float(trial @ trial) > (1.0 - LM_TOLERANCE) * cost
                return
            for knob, delta in zip(self.knobs, step):
                knob -= delta
            self.damping *= 4.0
        self.converged = True  # no step lowers the error: a minimum to the finite differences' precision
        self._last = r0

    def values(self) -> dict[str, float]:
        return {k: float(self.model.parameters_.value(k).detach()) for k in (*self.candidate.knobs, *self.refine)}


def _live(jacobian: torch.Tensor, r0: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The Jacobian with the columns that are round-off zeroed, and which they are. A column is round-off where
    it is no larger than the finite differences' own noise, ``LM_ROUND_OFF`` times ε / ``LM_PROBE`` times the
    residual's norm (a lag's time constant while its gain is 0, through an FMU that reads the lag's zeros as a
    sum of tiny ones): such a knob sits out the step, whose direction its noise would otherwise decide."""
    noise = LM_ROUND_OFF * torch.finfo(jacobian.dtype).eps / LM_PROBE * float(torch.linalg.norm(r0))
    dead = jacobian.norm(dim=0) <= noise
    return jacobian * (~dead).to(jacobian.dtype), dead


def fixed_windows(problem: Problem, windows: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The training windows a fit takes its steps on, in double precision: ``LM_WINDOWS_PER_BATCH``
    batches' worth drawn with the problem's seed (the same ones for every fit of a round)."""
    count = windows["u"].shape[0]
    generator = torch.Generator().manual_seed(problem.seed)
    index = torch.randperm(count, generator=generator)[: LM_WINDOWS_PER_BATCH * problem.batch]
    return {k: v[index].double() for k, v in windows.items()}


@torch.no_grad()
def window_residual(model: torch.nn.Module, fixed: Mapping[str, torch.Tensor], first: int) -> torch.Tensor:
    """The model's prediction errors on ``fixed`` windows (each started from its first ``first`` samples), flat."""
    return (model(fixed["u"], fixed["y"][:, :first], fixed.get("s")) - fixed["y"][:, first:]).reshape(-1)


@dataclasses.dataclass(frozen=True)
class Base:
    """A round's base model on the windows its fits take their steps on: its residual (flat) and
    its Jacobian's columns for the knobs of ``refine`` (raw knob -> column)."""

    residual: torch.Tensor
    columns: Mapping[str, torch.Tensor]

    @property
    def cost(self) -> float:
        return float(self.residual @ self.residual)


@torch.no_grad()
def _columns(residual: Callable[[], torch.Tensor], knobs: Sequence[tuple[str, torch.Tensor]], r0: torch.Tensor,
             known: Mapping[str, torch.Tensor]) -> list[torch.Tensor]:
    """The Jacobian's columns for ``knobs`` ((name, raw tensor) each) by forward differences of
    ``residual`` about ``r0``; a column ``known`` by the knob's name is taken as it is."""
    columns = []
    for name, knob in knobs:
        if name in known:
            columns.append(known[name])
            continue
        knob += LM_PROBE
        columns.append((residual() - r0) / LM_PROBE)
        knob -= LM_PROBE
    return columns


def base_model(problem: Problem, windows: Mapping[str, torch.Tensor], spec: ModelSpec, refine: Sequence[str]
               ) -> Base:
    """A round's base model ``spec`` on the windows every fit of the round takes its steps on: its
    residual and its Jacobian's columns for the knobs of ``refine``, computed once for the round
    instead of once per candidate (:meth:`GradientFit.promise`)."""
    fixed, first = fixed_windows(problem, windows), problem.dm.past + 1
    model = problem.build(set_free(spec, refine) if refine else spec)
    residual = window_residual(model, fixed, first)
    raw = model.parameters_.raw
    knobs = [(name, raw[name]) for name in raw if raw[name].requires_grad]
    columns = _columns(lambda: window_residual(model, fixed, first), knobs, residual, {})
    return Base(residual, {name: c for (name, _), c in zip(knobs, columns)})


def fit_gradient(candidate: Candidate, problem: Problem, windows: Mapping[str, torch.Tensor],
                 refine: Sequence[str] = ()) -> dict[str, float]:
    """The candidate's knobs (and ``refine``) fitted to the full number of steps (:class:`GradientFit`)."""
    fit = GradientFit(candidate, problem, windows, refine)
    fit.advance(1.0)
    return fit.values()


def fit_affine(candidate: Candidate, problem: Problem) -> tuple[dict[str, float], float | None]:
    """One offset (the candidate's channel): its least-squares value and |value| / standard error
    (``None`` where the training stretches are too few to judge it, see :func:`fit_offsets`)."""
    channel = candidate.target
    batches, weights = _offset_responses(candidate.spec, [channel], problem)
    values, z = _solve_offsets(batches, weights, [channel], problem)
    span = max(float(np.ptp(r[channel])) for r in problem.records("train"))
    unit = problem.dm.channels[channel].unit
    if not abs(values[channel]) <= span:  # e.g. a position offset the initial-state estimate absorbs
        raise ValueError(f"offset {quantity(values[channel], unit)} beyond the channel's whole range "
                         f"({quantity(span, unit)}): not identifiable from these data")
    follows = _follows_inputs(batches, weights, problem)
    if follows:
        raise ValueError(f"not a constant offset ({quantity(values[channel], unit)} on average): {follows}")
    return values, z[channel]


def _follows_inputs(batches: Sequence[tuple[torch.Tensor, torch.Tensor]], weights: torch.Tensor,
                    problem: Problem) -> str:
    """Why one offset is not constant, or "": its estimate on each training stretch alone follows
    the stretch's mean of an input, ``CONSTANT_Z`` standard errors of their correlation or more, and
    by ``CONSTANT_SHARE`` of its mean or more (a sensor's bias does not change with what drives the
    system; the apparent offset of a slow mode the model misses, a wrong gain or a drift does).
    Judged from ``CONSTANT_STRETCHES`` stretches up."""
    estimates = []
    for g, r in batches:  # g (B, L, p, 1), r (B, L, p): each stretch's own least-squares offset
        gram = torch.einsum("blp,blp,p->b", g[..., 0], g[..., 0], weights)
        estimates.append(torch.einsum("blp,blp,p->b", g[..., 0], r, weights) / torch.clamp(gram, min=1e-300))
    estimate = torch.cat(estimates).numpy()
    train = problem.stretches("train")
    means = torch.cat([b["u"][:, train.first :].double().mean(1) for b in train.batches]).numpy()  # (stretches, m)
    count = len(estimate)
    if count < CONSTANT_STRETCHES or not np.isfinite(estimate).all() or np.ptp(estimate) == 0:
        return ""
    for j, name in enumerate(problem.dm.input_names):
        if np.ptp(means[:, j]) == 0:
            continue
        r = float(np.corrcoef(estimate, means[:, j])[0, 1])
        t = abs(r) * math.sqrt(count - 2) / math.sqrt(max(1.0 - r * r, 1e-12))
        moves = abs(r) * float(np.std(estimate))  # the part of the stretches' spread that follows the input
        share = moves / max(abs(float(np.mean(estimate))), 1e-300)
        if t >= CONSTANT_Z and share >= CONSTANT_SHARE:
            return (f"its estimate on each of the {count} training stretches follows the stretch's mean {name} "
                    f"(correlation {r:.2f}, {t:.0f} standard errors; it moves by {100 * share:.0f} % of its mean "
                    "with it): a slow dynamic or a gain the model misses, not a sensor's bias")
    return ""


def fit_offsets(spec: ModelSpec, channels: Sequence[str], problem: Problem) -> tuple[dict[str, float],
                                                                                      dict[str, float | None]]:
    """Joint least squares of the sensor offsets of ``channels`` in ``spec`` (whatever values the
    spec holds for them are replaced). The (linear) model's outputs are affine in each offset, so
    one simulation of the training stretches with them at zero and one per offset (a probe) give
    the responses exactly. Returns the offsets [SI] and each one's |value| over its standard
    error, clustered by stretch (the residuals of one stretch are correlated, those of different
    stretches far less; the sandwich covariance of the weighted least squares). With no more
    stretches than offsets that ratio is ``None``: the stretches' shares sum to zero at the
    optimum, so they cannot judge as many directions as there are offsets (one stretch gives a
    standard error of exactly zero)."""
    return _solve_offsets(*_offset_responses(spec, channels, problem), channels, problem)


def _offset_responses(spec: ModelSpec, channels: Sequence[str], problem: Problem
                      ) -> tuple[list[tuple[torch.Tensor, torch.Tensor]], torch.Tensor]:
    """Per batch of training stretches, the outputs' responses to each offset (B, L, p, k) and the
    residual with them at zero (B, L, p); the outputs' weights (:func:`fit_offsets`)."""
    zeroed = {**spec.sensor_offsets, **dict.fromkeys(channels, 0.0)}
    train = problem.stretches("train")
    base = train.predict(problem.build(dataclasses.replace(spec, sensor_offsets=zeroed)))
    responses = []
    for channel in channels:
        probe = 0.1 * problem.scale([channel])[channel][1]
        moved = train.predict(problem.build(dataclasses.replace(spec, sensor_offsets={**zeroed, channel: probe})))
        responses.append([(p1 - p0) / probe for (p1, _), (p0, _) in zip(moved, base)])
    batches = [(torch.stack([resp[b] for resp in responses], -1), y - p0) for b, (p0, y) in enumerate(base)]
    return batches, train.weights()


def _solve_offsets(batches: Sequence[tuple[torch.Tensor, torch.Tensor]], weights: torch.Tensor,
                   channels: Sequence[str], problem: Problem) -> tuple[dict[str, float], dict[str, float | None]]:
    """The offsets' least squares and their clustered standard errors (:func:`fit_offsets`)."""
    k = len(channels)
    gram = sum(torch.einsum("blpi,blpj,p->ij", g, g, weights) for g, _ in batches)  # g: (B, L, p, k)
    rhs = sum(torch.einsum("blpi,blp,p->i", g, r, weights) for g, r in batches)
    if torch.linalg.matrix_rank(gram) < k:
        raise ValueError(f"offsets of {', '.join(channels)} cannot be told apart on these data")
    offsets = torch.linalg.solve(gram, rhs)
    values = {c: float(v) for c, v in zip(channels, offsets)}
    if problem.evidence().error_shortfall(k):
        return values, dict.fromkeys(channels)
    scores = torch.cat([torch.einsum("blpi,blp,p->bi", g, r - torch.einsum("blpi,i->blp", g, offsets), weights)
                        for g, r in batches])  # (stretches, k): each stretch's share of the normal equations
    inverse = torch.linalg.inv(gram)
    spread = torch.sqrt(torch.clamp(torch.diagonal(inverse @ (scores.T @ scores) @ inverse), min=0.0))
    return values, {c: abs(values[c]) / float(e) if float(e) > 0 else math.inf for c, e in zip(channels, spread)}
