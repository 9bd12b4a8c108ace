"""A round's candidates fitted and scored (:func:`evaluate_round`): every fit that runs runs to its end.

A round's budget is work, never seconds of a busy machine. The gradient fits are screened first
by a score test (:meth:`~hypa.diagnosis.fitting.GradientFit.promise`: what
the first Gauss-Newton step from the model as it was promises, one Jacobian each); those that
promise enough run to convergence, the others are reported "not fitted" with what they promised.
The fits run on worker processes (:mod:`hypa.diagnosis.workers`) where the platform can fork;
the calling process meanwhile runs the cheap candidates (offsets, structural edits) and the
round's side jobs.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import nullcontext
from dataclasses import dataclass
from functools import partial

import torch

from hypa.diagnosis.edits import GRADIENT, Candidate
from hypa.diagnosis.finding import FIT_ERRORS, Finding, evaluate, failed, scored
from hypa.diagnosis.fitting import GradientFit, base_model
from hypa.diagnosis.problem import Problem
from hypa.diagnosis.workers import Workers, can_fork
from hypa.identification.stretches import Stretches
from hypa.models.spec import ModelSpec

SCREEN = 0.25  # a fit runs where its first Gauss-Newton step promises this share of min_gain ...
SCREEN_BEST = 3  # ... and the round's best few promises run whatever they promise (the test is first order)
SCREENING = 0.0  # the share that asks a runner for its promise only (:meth:`_Runner.advance`)


class NotPromising(ValueError):
    """A candidate whose score test promises too little to fit it (reported, never named)."""


@dataclass
class _Runner:
    """A gradient fit in the race: its score on the validation stretches now and at the previous rung."""

    fit: GradientFit
    seconds: float
    score: float = math.inf
    previous: float = math.inf
    error: Exception | None = None
    values: dict[str, float] | None = None  # the fitted values, when the fit ran in a worker process
    promise: float | None = None  # the score test (nonlinear fits, once screened)

    def advance(self, share: float, val: Stretches) -> None:
        """Fit to ``share`` of the steps and score; ``SCREENING``: the score test only."""
        started = time.perf_counter()
        self.previous = self.score
        try:
            if share == SCREENING:
                self.promise = self.fit.promise()
            else:
                self.fit.advance(share)
                self.score = val.score(self.fit.model)
        except FIT_ERRORS as error:
            self.score, self.error = math.inf, error
        self.seconds += time.perf_counter() - started


def evaluate_round(candidates: Sequence[Candidate], problem: Problem, windows: Mapping[str, torch.Tensor],
                   base_score: float, refine: Sequence[str] = (), screen: float | None = None,
                   side: Sequence[Callable[[], None]] = (), base: ModelSpec | None = None) -> list[Finding]:
    """Every candidate of a round fitted and scored (best first).

    With ``screen`` (a share of the fit error), each gradient fit is first screened
    (:meth:`~hypa.diagnosis.fitting.GradientFit.promise`); those promising at least ``screen``,
    and the ``SCREEN_BEST`` best promises whatever they are, run to convergence, and the others
    are reported not fitted, with what they promised (``screen=None``: every fit runs); ``base``,
    the round's model, is what the promises are measured against (a fit that starts elsewhere).
    ``side``: other work for this process while the workers fit (run with the offsets).
    """
    findings, runners, others = [], [], []
    for c in candidates:
        if c.fit != GRADIENT:
            others.append(c)
            continue
        started = time.perf_counter()
        try:
            runners.append(_Runner(GradientFit(c, problem, windows, refine), time.perf_counter() - started))
        except FIT_ERRORS as error:
            findings.append(failed(c, error, time.perf_counter() - started))
    if screen is not None and base is not None and runners:
        measured = base_model(problem, windows, base, refine)
        for runner in runners:
            runner.fit.base = measured
    val = problem.stretches("val")
    count = min(problem.workers, len(runners)) if can_fork() else 1
    jobs = [partial(append_result, findings, evaluate, c, problem, windows, base_score, refine)
            for c in others] + list(side)
    with Workers(runners, count, val) if count > 1 else nullcontext() as workers:

        def run(shares: Mapping[int, float], jobs: Sequence[Callable[[], None]] = ()) -> None:
            if workers is not None:
                workers.run(shares, jobs)
                return
            for i, share in shares.items():
                runners[i].advance(share, val)
            for job in jobs:
                job()

        screened = screen is not None
        run(dict.fromkeys(range(len(runners)), SCREENING if screened else 1.0), jobs)
        if screened:
            run(dict.fromkeys(_promising(runners, screen), 1.0))
    for runner in runners:
        if runner.error is not None:
            findings.append(failed(runner.fit.candidate, runner.error, runner.seconds))
            continue
        if runner.fit.done == 0 and not runner.fit.diverged:
            findings.append(failed(runner.fit.candidate, _not_run(runner, problem, screen), runner.seconds))
            continue
        values = runner.values if runner.values is not None else runner.fit.values()
        finding = scored(runner.fit.candidate, problem, values, runner.score, base_score, runner.seconds)
        fit = runner.fit
        finding.steps = (fit.done, fit.done if fit.converged else fit.total)
        if fit.diverged:  # reported with its last sane values, never named
            sane = finding.describe().split(": ", 1)[-1]
            finding.error = f"did not converge: {fit.diverged} (last sane: {sane})"
            finding.score, finding.gain = math.inf, -math.inf
        elif fit.timed_out:
            finding.note = (finding.note + "; " if finding.note else "") + (
                f"stopped at the time limit per fit (diagnosis.fit_seconds = {problem.fit_seconds:g} s) after "
                f"{fit.done} of at most {fit.total} steps: its gain is at least this")
        findings.append(finding)
    return sorted(findings, key=lambda f: f.score)


def _promising(runners: Sequence[_Runner], screen: float) -> list[int]:
    """The screened runners that go on to their fit: a promise of at least ``screen``, or among the
    ``SCREEN_BEST`` best (a finite, positive promise), or a swapped system (``Candidate.replaces``:
    its start is a guess in another parametrization, a user's Torricelli tanks at a k in another
    unit, where a first-order promise says little; moved first to where it reproduced the model it
    replaces, a Coulomb friction went to 0 N, where its gradient vanishes)."""
    promised = {i: r.promise for i, r in enumerate(runners) if r.promise is not None and r.error is None
                and math.isfinite(r.promise)}
    best = sorted((i for i in promised if promised[i] > 0), key=lambda i: -promised[i])[:SCREEN_BEST]
    swapped = {i for i, r in enumerate(runners) if r.error is None and r.fit.candidate.replaces}
    return sorted(set(best) | swapped | {i for i, p in promised.items() if p >= screen})


def _not_run(runner: _Runner, problem: Problem, screen: float | None) -> Exception:
    """Why a fit took no step (a reason, as the report's "not fitted (...)" says it)."""
    if runner.fit.timed_out:
        return NotPromising(f"the time limit per fit (diagnosis.fit_seconds = {problem.fit_seconds:g} s) "
                            "came before its first step")
    if runner.promise is None or not math.isfinite(runner.promise):
        return NotPromising("its error is not finite where the fit starts")
    return NotPromising(f"its first Gauss-Newton step promises {100 * runner.promise:.2g} % of the fit error; "
                        f"a fit runs from {100 * (screen or 0.0):.2g} % or among the round's {SCREEN_BEST} best "
                        "promises")


def append_result(results: list, call: Callable[..., object], *args) -> None:
    """``call(*args)`` appended to ``results``: a job for a round (its offsets, its ``side`` work)."""
    results.append(call(*args))
