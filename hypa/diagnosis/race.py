"""A round's gradient fits raced by successive halving (:func:`evaluate_round`).

Every candidate of a round is fitted and scored (:mod:`hypa.diagnosis.finding`); the gradient
fits of nonlinear physics, the expensive ones, are ranked after shares of their steps
(``RUNGS``) and only the better ones go on. The fits run on worker processes
(:mod:`hypa.diagnosis.workers`) where the platform can fork; the calling process meanwhile runs
the cheap candidates (offsets, structural edits) and the round's side jobs.
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
from hypa.diagnosis.fitting import GradientFit
from hypa.diagnosis.problem import Problem
from hypa.diagnosis.workers import Workers, can_fork
from hypa.identification.stretches import Stretches

RUNGS = (0.25, 0.5, 1.0)  # shares of the fit steps after which the gradient fits are ranked


@dataclass
class _Runner:
    """A gradient fit in the race: its score on the validation stretches now and at the previous rung."""

    fit: GradientFit
    seconds: float
    score: float = math.inf
    previous: float = math.inf
    error: Exception | None = None
    values: dict[str, float] | None = None  # the fitted values, when the fit ran in a worker process

    def advance(self, share: float, val: Stretches) -> None:
        started = time.perf_counter()
        self.previous = self.score
        try:
            self.fit.advance(share)
            self.score = val.score(self.fit.model)
        except FIT_ERRORS as error:
            self.score, self.error = math.inf, error
        self.seconds += time.perf_counter() - started


def evaluate_round(candidates: Sequence[Candidate], problem: Problem, windows: Mapping[str, torch.Tensor],
                   base_score: float, refine: Sequence[str] = (), rungs: Sequence[float] = RUNGS,
                   side: Sequence[Callable[[], None]] = ()) -> list[Finding]:
    """Every candidate of a round fitted and scored (best first).

    Fits of nonlinear physics (simulated step by step, the expensive ones) race by successive
    halving: all run a quarter of their steps and are scored on the validation stretches, the
    better half (at least 3) goes on to half the steps, the better half of those (at least 2) to
    the end, unless still worse than the base model and no better than at the quarter. Linear
    fits always run to the end: early in a fit (Adam's first steps are about the learning rate
    whatever the gradient) a resonant system's error is no guide. A fit stopped early says so
    (``Finding.steps``); its gain is a lower bound. ``rungs=(1.0,)``: no race, every fit to its end.
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
    val, alive = problem.stretches("val"), list(runners)
    count = min(problem.workers, len(runners)) if can_fork() else 1
    with Workers(runners, count, val) if count > 1 else nullcontext() as workers:
        for k, share in enumerate(rungs):
            # linear fits (the lifted form: cheap) run to the end at once
            shares = {i: share if r.fit.nonlinear else 1.0 for i, r in enumerate(runners) if r in alive}
            # the offsets and structural candidates: in this process, while the workers fit
            jobs = [partial(append_result, findings, evaluate, c, problem, windows, base_score, refine)
                    for c in (others if k == 0 else ())] + list(side if k == 0 else ())
            if workers is not None:
                workers.run(shares, jobs)
            else:
                for i, s in shares.items():
                    runners[i].advance(s, val)
                for job in jobs:
                    job()
            alive = _next_rung(alive, k, base_score) if k + 1 < len(rungs) else []
            if not alive:
                break
    for runner in runners:
        if runner.error is not None:
            findings.append(failed(runner.fit.candidate, runner.error, runner.seconds))
            continue
        values = runner.values if runner.values is not None else runner.fit.values()
        finding = scored(runner.fit.candidate, problem, values, runner.score, base_score, runner.seconds)
        finding.steps = (runner.fit.done, runner.fit.total)
        if runner.fit.diverged:  # reported with its last sane values, never named
            sane = finding.describe().split(": ", 1)[-1]
            finding.error = f"did not converge: {runner.fit.diverged} (last sane: {sane})"
            finding.score, finding.gain = math.inf, -math.inf
        elif runner.fit.timed_out:
            finding.note = (finding.note + "; " if finding.note else "") + (
                f"stopped at the time limit per fit ({problem.fit_seconds:g} s)")
        findings.append(finding)
    return sorted(findings, key=lambda f: f.score)


def append_result(results: list, call: Callable[..., object], *args) -> None:
    """``call(*args)`` appended to ``results``: a job for a round (its offsets, its ``side`` work)."""
    results.append(call(*args))


def _next_rung(alive: list[_Runner], k: int, base_score: float) -> list[_Runner]:
    """The runners that go on after rung ``k`` (successive halving, see :func:`evaluate_round`)."""
    alive = [r for r in alive if r.error is None and not r.fit.finished]
    if k + 1 == len(RUNGS):
        return []
    racing = sorted(alive, key=lambda r: r.score)[: max(3 - k, math.ceil(len(alive) / 2))]
    if k > 0:  # after half its steps, worse than the base model and not improving: it will not win
        racing = [r for r in racing if r.score < base_score or r.score < r.previous]
    return racing
