"""Name what the physics gets wrong, on any system: candidates fitted and scored with the model itself.

The nominal model is a :class:`~hypa.models.ModelSpec` (the physics a user trusts, frozen). Each
candidate cause (:mod:`hypa.diagnosis.edits`) is an edit of it; the edited model is built as a
:class:`~hypa.models.ComposedModel` (the class ``hypa.train`` trains), its knobs are fitted on
the training windows (:mod:`hypa.diagnosis.fitting`: gradient fits of the physical parameters,
least squares for an offset; on worker processes, :mod:`hypa.diagnosis.workers`), and it is
scored free-running over held-out data (:mod:`hypa.diagnosis.problem`). Judged by
cross-validation over blocked stretches of all records, training and validation
(:meth:`Problem.folds`, :func:`evaluate_folds`): each fold fits on every other block and scores
on the rest, and the folds' errors pool into the error over all blocks, so one validation record
unlike the training does not decide. A greedy search names the
candidate with the largest gain, writes its fitted values (each fold's) into the model and searches again
from there, until no candidate improves the cross-validated error by ``min_gain``. What remains is
then tested for structure (:func:`residual_structure`): where significant error is left that
no catalogue entry explains, the diagnosis says where it lives instead of naming a proxy.

Nothing is named on more than the data can support (:class:`~hypa.diagnosis.problem.Evidence`):
a fit of as many numbers as the training windows without overlap, or more, is not run, an offset's
standard error needs more training stretches than the offsets fitted with it, and data that
cannot support a fit of one number are refused (:meth:`Problem.require_data`). Each such
shortfall is listed in :attr:`Search.too_short`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field
from functools import partial

import numpy as np
import torch

from hypa.diagnosis.catalogue import Entry, catalogue_candidates, load_catalogue
from hypa.diagnosis.edits import AFFINE, GRADIENT, Candidate, applied, averaged, frozen
from hypa.diagnosis.fitting import GradientFit, fit_affine, fit_gradient, fit_offsets
from hypa.diagnosis.generic import MARGIN as GENERIC_MARGIN
from hypa.diagnosis.generic import GenericFit, fit_generic
from hypa.diagnosis.problem import Problem, Stretches, TooLittleData, format_value
from hypa.diagnosis.scales import duration
from hypa.diagnosis.workers import Workers, can_fork
from hypa.models.spec import ModelSpec, ModelSpecError
from hypa.physics import SchedulingError, UnstablePhysicsError


ALTERNATIVE = 0.95  # a candidate explaining this share of the named one's gain is reported beside it ...
SIMPLER = 0.75  # ... and one with fewer numbers from this share on (the data cannot prefer the richer claim)
OFFSET_Z = 5.0  # an offset below min_gain is still named this many standard errors away from zero ...
OFFSET_GAIN = 0.005  # ... when it lowers the validation error by at least this share (a small sensor bias)
CONTENDER = 0.8  # a gradient fit goes on to the other folds from this share of what it needs on the first (evaluate_folds)


@dataclass
class Finding:
    """A candidate after its fit: fitted values [SI], validation score and gain over the base model."""

    cause: str
    target: str
    values: dict[str, float]
    units: dict[str, str]
    score: float
    gain: float
    seconds: float
    error: str | None = None
    candidate: Candidate | None = field(default=None, repr=False)
    alternatives: list[str] = field(default_factory=list)  # candidates that explain (almost) as much
    note: str = ""  # what a value-less cause means on these data (scheduling: the ranges)
    refined: dict[str, float] = field(default_factory=dict)  # earlier causes' knobs, re-fitted with it
    steps: tuple[int, int] | None = None  # gradient fits: (steps done, of); fewer: stopped early, behind others
    z: float | None = None  # offsets: |estimate| / its standard error (clustered by training stretch)
    small: bool = False  # named below min_gain: an offset far from zero by its standard error
    too_short: str = ""  # why the data are too short: to fit it (then not fitted) or to judge its standard error
    generic: float | None = None  # named: the gain of the generic linear filter it had to beat (generic.py)
    folds: list[Finding] = field(default_factory=list, repr=False)  # cross-validated: the fit of each fold
    screened: bool = False  # judged on the first fold only: far behind that fold's best (see evaluate_folds)

    @property
    def key(self) -> str:
        return f"{self.cause}:{self.target}"

    def describe(self) -> str:
        """One line in units: ``input_delay on steering_angle: 236 ms``."""
        if self.error:
            return f"{self.cause} on {self.target}: not fitted ({self.error})"
        parts = [f"{k.split('/')[-1]} {format_value(v, self.units.get(k, ''))}" for k, v in self.values.items()
                 if k != self.target] + [format_value(v, self.units.get(k, "")) for k, v in self.values.items()
                                         if k == self.target] + ([self.note] if self.note else [])
        return f"{self.cause} on {self.target}" + (f": {', '.join(parts)}" if parts else "")

    def to_dict(self) -> dict:
        return {"cause": self.cause, "target": self.target, "values": self.values, "units": self.units,
                "score": self.score, "gain": self.gain, "seconds": self.seconds, "error": self.error,
                "alternatives": self.alternatives, "refined": self.refined,
                "steps": list(self.steps) if self.steps else None, "z": self.z, "small": self.small,
                "too_short": self.too_short, "generic": self.generic, "text": self.describe(),
                "folds": [f.values for f in self.folds], "screened": self.screened}


_FIT_ERRORS = (UnstablePhysicsError, SchedulingError, ModelSpecError, ValueError, ArithmeticError,
               torch.linalg.LinAlgError)  # a candidate that fails is reported, never ends the diagnosis


def evaluate(candidate: Candidate, problem: Problem, windows: Mapping[str, torch.Tensor], base_score: float,
             refine: Sequence[str] = ()) -> Finding:
    """Fit a candidate (with ``refine``, see :class:`GradientFit`) and score it on the validation
    stretches. ``values`` holds the candidate's own knobs, ``refined`` the others."""
    started, z = time.perf_counter(), None
    try:
        if candidate.fit == GRADIENT:
            values = fit_gradient(candidate, problem, windows, refine)
        elif candidate.fit == AFFINE:
            values, z = fit_affine(candidate, problem)
        else:
            values = {}
        value = problem.stretches("val").score(problem.build(applied(candidate, values)))
    except _FIT_ERRORS as error:
        return _failed(candidate, error, time.perf_counter() - started)
    finding = _finding(candidate, problem, values, value, base_score, time.perf_counter() - started)
    finding.z = z
    if candidate.fit == AFFINE and z is None:
        finding.too_short = f"its standard error is not judged: {problem.evidence().error_shortfall(1)}"
    return finding


def _failed(candidate: Candidate, error: Exception, seconds: float) -> Finding:
    short = isinstance(error, TooLittleData)
    return Finding(candidate.cause, candidate.target, {}, {}, math.inf, -math.inf, seconds,
                   ("too little data: " if short else "") + str(error).split("\n")[0], candidate,
                   too_short=str(error) if short else "")


def _finding(candidate: Candidate, problem: Problem, values: Mapping[str, float], value: float, base_score: float,
             seconds: float) -> Finding:
    units = dict(candidate.units) or {candidate.target: problem.dm.channels[candidate.target].unit
                                      if candidate.fit == AFFINE else ""}
    gain = 1.0 - value / base_score if base_score > 0 else 0.0
    note = _scheduling_note(candidate, problem) if candidate.cause == "scheduling" else ""
    own = {k: v for k, v in values.items() if k in candidate.knobs or candidate.fit == AFFINE}
    refined = {k: v for k, v in values.items() if k not in own}
    return Finding(candidate.cause, candidate.target, own, units, value, gain, seconds, None, candidate, note=note,
                   refined=refined)


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
        except _FIT_ERRORS as error:
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
    (``Finding.steps``); its gain is a lower bound. ``rungs=(1.0,)``: no race, every fit to its end. ``side``: other work for this process
    while the workers fit (run with the offsets).
    """
    findings, runners, others = [], [], []
    for c in candidates:
        if c.fit != GRADIENT:
            others.append(c)
            continue
        started = time.perf_counter()
        try:
            runners.append(_Runner(GradientFit(c, problem, windows, refine), time.perf_counter() - started))
        except _FIT_ERRORS as error:
            findings.append(_failed(c, error, time.perf_counter() - started))
    val, alive = problem.stretches("val"), list(runners)
    count = min(problem.workers, len(runners)) if can_fork() else 1
    with Workers(runners, count, val) if count > 1 else nullcontext() as workers:
        for k, share in enumerate(rungs):
            # linear fits (the lifted form: cheap) run to the end at once
            shares = {i: share if r.fit.nonlinear else 1.0 for i, r in enumerate(runners) if r in alive}
            # the offsets and structural candidates: in this process, while the workers fit
            jobs = [partial(_append, findings, evaluate, c, problem, windows, base_score, refine)
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
            findings.append(_failed(runner.fit.candidate, runner.error, runner.seconds))
            continue
        values = runner.values if runner.values is not None else runner.fit.values()
        finding = _finding(runner.fit.candidate, problem, values, runner.score, base_score, runner.seconds)
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


def _append(findings: list[Finding], evaluate_one: Callable[..., Finding], *args) -> None:
    findings.append(evaluate_one(*args))


def evaluate_folds(candidates: Callable[[ModelSpec], list[Candidate]], folds: Sequence[Problem],
                   bases: Sequence[ModelSpec], scores: Sequence[float], windows: Sequence[Mapping[str, torch.Tensor]],
                   base_score: float, min_gain: float, refine: Sequence[str] = (),
                   keep: Callable[[Candidate], bool] = lambda _: True, side: Sequence[Callable[[], None]] = ()
                   ) -> list[Finding]:
    """A round cross-validated (:meth:`Problem.folds`): the candidates of each fold's base model
    that ``keep`` keeps, fitted on the fold's blocks and scored on its held-out ones
    (:func:`evaluate_round`), their scores pooled over the folds (the error over all blocks, each
    scored by a fit that never saw it), their values the folds' mean (each fold's in ``folds``).

    All run the first fold. A gradient fit goes on to the others only where it could be named or
    listed beside the one named: its gain there at least ``CONTENDER`` (a margin for the folds'
    spread) of ``min_gain`` and of what :func:`alternatives` asks beside the fold's best. The rest
    stop at it (``screened``, listed after the others with the first fold's gain). Offsets and
    structural candidates (cheap) run every fold.
    """
    def listed(k: int) -> list[Candidate]:
        return [c for c in candidates(bases[k]) if keep(c)]

    first = evaluate_round(listed(0), folds[0], windows[0], scores[0], refine, side=side)
    if len(folds) == 1:
        return first
    fitted = [f for f in first if f.error is None]
    best = max(fitted, key=lambda f: f.gain, default=None)

    def contends(f: Finding) -> bool:  # could be named, or listed beside the one named (alternatives)
        if f.candidate is None or f.candidate.fit != GRADIENT:
            return True
        if f.error is not None or best is None or best.gain <= 0:
            return False
        share = SIMPLER if _numbers(f) < _numbers(best) else ALTERNATIVE
        return f.gain >= CONTENDER * max(min_gain, share * best.gain)

    going = {f.key for f in first if contends(f)}
    per_fold = [{f.key: f for f in first}]
    for k in range(1, len(folds)):
        found = evaluate_round([c for c in listed(k) if c.key in going], folds[k], windows[k], scores[k], refine,
                               rungs=(1.0,))  # the contenders: each fit to its end
        per_fold.append({f.key: f for f in found})
    pooled, screened = [], []
    for f in first:
        if all(f.key in found for found in per_fold):
            pooled.append(_pooled([found[f.key] for found in per_fold], folds, base_score))
        else:
            f.screened = f.error is None
            screened.append(f)
    return sorted(pooled, key=lambda f: f.score) + sorted(screened, key=lambda f: -f.gain)


def _pooled(fits: Sequence[Finding], folds: Sequence[Problem], base_score: float) -> Finding:
    """One candidate's fits over the folds as one finding (see :func:`evaluate_folds`)."""
    failed = next((f for f in fits if f.error), None)
    if failed is not None:
        return dataclasses.replace(failed, folds=list(fits))
    score = pool(folds, [f.score for f in fits])
    return dataclasses.replace(
        fits[0], values=_mean([f.values for f in fits]), refined=_mean([f.refined for f in fits]), score=score,
        gain=1.0 - score / base_score if base_score > 0 else 0.0, seconds=sum(f.seconds for f in fits),
        z=pooled_z([next(iter(f.values.values()), 0.0) for f in fits], [f.z for f in fits]),
        too_short="" if any(f.z is not None for f in fits) else next((f.too_short for f in fits if f.too_short), ""),
        folds=list(fits))


def pooled_z(values: Sequence[float], zs: Sequence[float | None]) -> float | None:
    """|mean| / its standard error for one offset estimated independently in each fold (its
    ``values`` with their ``zs`` = |value| / standard error), from the folds whose stretches
    could judge it (``None``: none could)."""
    judged = [(v, z) for v, z in zip(values, zs) if z is not None]
    if not judged:
        return None
    errors = [abs(v) / z if z > 0 else math.inf for v, z in judged]
    spread = math.sqrt(sum(e * e for e in errors)) / len(judged)
    mean = abs(sum(v for v, _ in judged)) / len(judged)
    return mean / spread if spread > 0 else math.inf


def _mean(values: Sequence[Mapping[str, float]]) -> dict[str, float]:
    return {k: sum(v[k] for v in values) / len(values) for k in values[0]}


def pool(folds: Sequence[Problem], scores: Sequence[float]) -> float:
    """The folds' scores as the score over all their held-out blocks."""
    return float(sum(p.held_out * s for p, s in zip(folds, scores)))


def _next_rung(alive: list[_Runner], k: int, base_score: float) -> list[_Runner]:
    """The runners that go on after rung ``k`` (successive halving, see :func:`evaluate_round`)."""
    alive = [r for r in alive if r.error is None and not r.fit.finished]
    if k + 1 == len(RUNGS):
        return []
    racing = sorted(alive, key=lambda r: r.score)[: max(3 - k, math.ceil(len(alive) / 2))]
    if k > 0:  # after half its steps, worse than the base model and not improving: it will not win
        racing = [r for r in racing if r.score < base_score or r.score < r.previous]
    return racing


def _scheduling_note(candidate: Candidate, problem: Problem) -> str:
    """``fixed at 20 m/s in the model, measured 5.1–32 m/s``."""
    dm, name = problem.dm, candidate.target
    values = np.concatenate([r[name] for r in dm.records("train")])
    fixed = {**problem.physical_values, **candidate.spec.parameters}.get(name)
    unit = dm.channels[name].unit
    held = f"fixed at {fixed:.3g} {unit} in the model, " if fixed is not None else ""
    return f"{held}measured {values.min():.3g}–{values.max():.3g} {unit}"


@dataclass
class Search:
    """The greedy search: the nominal score, every round's findings (best first), the named ones
    (their ``values`` final: re-fitted jointly with the causes named after them) and the model
    with them applied."""

    nominal_score: float
    rounds: list[list[Finding]]
    named: list[Finding]
    spec: ModelSpec
    final_score: float
    seconds: float
    dropped: list[Finding] = field(default_factory=list)  # named, then dropped by the joint fit of the offsets
    too_short: list[str] = field(default_factory=list)  # what the data were too short to fit or judge, and why
    generic: list[GenericFit] = field(default_factory=list)  # per round: the generic filter every cause must beat
    standin: str = ""  # why the search stopped at a cause no better than the generic filter ("" if it did not)
    folds: int = 1  # cross-validation folds the scores are pooled over (1: the validation records alone)
    blocks: int = 0  # the blocks of all records the folds hold out in turn (0: no cross-validation)


def name_causes(nominal: ModelSpec, problem: Problem, catalogue: Sequence[Entry] | None = None,
                candidates: Callable[[ModelSpec], list[Candidate]] | None = None, max_causes: int = 8,
                min_gain: float = 0.15, floor: float = 1e-4, progress: Callable[[str], None] = lambda _: None) -> Search:
    """Greedy forward search over the catalogue from the frozen ``nominal`` model.

    ``catalogue``: the entries (default: the built-in catalogues, :func:`load_catalogue`);
    ``candidates(spec)``, if given, lists the candidates of a base model instead. Each round fits all of them, names the best if it lowers the validation
    error (1 - R², mean over outputs) by at least ``min_gain`` (relative), applies it and goes on;
    below ``floor`` (share of the output variance: sensor noise) there is nothing left to name.
    Refuses data too short to fit even one number (:meth:`Problem.require_data`); a candidate
    that fits more numbers than the data support is not fitted, an offset whose standard error the
    training stretches cannot judge is not named on it (:class:`~hypa.diagnosis.problem.Evidence`):
    both are listed in ``Search.too_short``.
    """
    problem = problem.scaled(frozen(nominal))
    problem.require_data()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny tensors: a second thread only waits (and on a busy machine, 20x slower)
    try:
        return _search(nominal, problem, catalogue, candidates, max_causes, min_gain, floor, progress)
    finally:
        torch.set_num_threads(threads)


def _search(nominal: ModelSpec, problem: Problem, catalogue: Sequence[Entry] | None,
            candidates: Callable[[ModelSpec], list[Candidate]] | None, max_causes: int, min_gain: float,
            floor: float, progress: Callable[[str], None]) -> Search:
    started = time.perf_counter()
    dm = problem.dm
    uncertain = {b.name: b.trainable for b in nominal.blocks}
    entries = load_catalogue() if catalogue is None else list(catalogue)
    if candidates is None:
        measured = [*dm.input_names, *dm.output_names, *dm.scheduling_names]
        channels = {n: (max(float(np.max(np.abs(r[n]))) for r in dm.records("train")), dm.channels[n].unit)
                    for n in measured}

        def candidates(spec: ModelSpec) -> list[Candidate]:
            return catalogue_candidates(entries, spec, dm.input_names, dm.output_names, dm.scheduling_names,
                                        problem.physical_values, dm.dt, uncertain, channels)
    torch.manual_seed(problem.seed)
    folds = problem.folds()
    windows = [p.windows() for p in folds]
    bases = [frozen(nominal)] * len(folds)
    scores = [p.stretches("val").score(p.build(b)) for p, b in zip(folds, bases)]
    base_score = nominal_score = pool(folds, scores)
    error = "cross-validated error" if len(folds) > 1 else "validation error"
    progress(f"time scales: {problem.time_scales.describe()}")
    if len(folds) > 1:
        progress(f"judged by cross-validation: {len(problem.blocks())} blocks of {duration(problem.time_scales.stretch_s)} "
                 f"from all {len(dm.records('train')) + len(dm.records('val'))} records (training and validation), "
                 f"{len(folds)} folds: each candidate fitted on every other block and scored on the rest")
    progress(f"nominal model: {error} {100 * base_score:.3g} % of the output variance (the search's "
             f"score: free runs restarted from the data every {duration(problem.time_scales.stretch_s)})")

    def round_of(keep: Callable[[Candidate], bool], refine: Sequence[str] = (),
                 side: Sequence[Callable[[], None]] = ()) -> list[Finding]:
        return evaluate_folds(candidates, folds, bases, scores, windows, base_score, min_gain, refine, keep, side)

    def adopt(best: Finding) -> None:
        nonlocal bases, scores, base_score
        fits = best.folds or [best]
        bases = [applied(f.candidate, {**f.refined, **f.values}) for f in fits]
        scores, base_score = [f.score for f in fits], best.score
        named.append(best)

    rounds, named, refine, findings, generic, standin = [], [], [], [], [], ""
    while len(named) < max_causes and base_score > floor:
        done = {f.key for f in named}
        bar: list[GenericFit] = []  # fitted by this process while the workers fit the candidates
        findings = round_of(lambda c: c.key not in done, refine,
                            side=[partial(_append, bar, _generic, folds, bases, scores, base_score)])
        rounds.append(findings)
        generic.append(bar[0] if bar else _generic(folds, bases, scores, base_score))
        if not findings or findings[0].gain < min_gain:
            break
        best, bar = findings[0], generic[-1]
        simpler = best.candidate is not None and len(best.candidate.knobs) < bar.numbers
        if not (best.score < (1.0 - GENERIC_MARGIN) * bar.score or (simpler and best.gain >= SIMPLER * bar.gain)):
            standin = (f"{best.describe()} would lower the {error} by {100 * best.gain:.2g} %, but "
                       f"{bar.describe()}: not named (a cause must beat it by {100 * GENERIC_MARGIN:.0f} % of its "
                       f"error, or explain {100 * SIMPLER:.0f} % as much with fewer numbers); what is left may be "
                       "dynamics the catalogue cannot express")
            progress(standin)
            findings = [f for f in findings if f.candidate is not None and f.candidate.fit == AFFINE]
            break
        best.alternatives, best.generic = alternatives(best, findings[1:]), bar.gain
        if bar.gain >= SIMPLER * best.gain:  # the generic filter explains most of it too: a possible stand-in
            best.alternatives.append(f"{bar.describe()}")
        adopt(best)
        refine += [k for k in best.candidate.knobs if best.candidate.fit == GRADIENT and k not in refine]
        progress(f"named {best.describe()} ({error} {100 * best.gain:.0f} % lower; a generic linear filter: "
                 f"{100 * generic[-1].gain:.0f} %)"
                 + (f"; the data cannot tell it from {' or '.join(best.alternatives)}" if best.alternatives else ""))
        findings = []
    # below min_gain: offsets (one number each, exact least squares) that sit far from zero by their
    # standard error, a small sensor bias, one at a time (the best first, the others fitted again on top)
    unjudged: dict[str, str] = {}
    findings = _small_offsets(findings, unjudged, error)
    while findings and len(named) < max_causes:
        best = findings[0]
        best.small = True
        best.alternatives = alternatives(best, findings[1:])
        adopt(best)
        progress(f"named {best.describe()} ({error} {100 * best.gain:.2g} % lower: small, but "
                 f"{best.z:.0f} standard errors from zero)")
        findings = round_of(lambda c, keys={f.key for f in findings[1:]}: c.key in keys)
        if findings:
            rounds.append(findings)
        findings = _small_offsets(findings, unjudged, error)
    too_short = _not_fitted(rounds) + list(unjudged.values())
    named, dropped, bases, scores = _joint_offsets(named, bases, scores, folds, progress, too_short)
    for k, f in enumerate(named):  # the final values: re-fitted jointly with every later cause
        for later in named[k + 1 :]:
            f.values.update({name: v for name, v in later.refined.items() if name in f.values})
    return Search(nominal_score, rounds, named, averaged(bases), pool(folds, scores), time.perf_counter() - started,
                  dropped, too_short, generic, standin, folds=len(folds),
                  blocks=len(problem.blocks()) if len(folds) > 1 else 0)


def _generic(folds: Sequence[Problem], bases: Sequence[ModelSpec], scores: Sequence[float],
             base_score: float) -> GenericFit:
    """The generic filter (:func:`~hypa.diagnosis.generic.fit_generic`) cross-validated as the candidates are."""
    fits = [fit_generic(p, p.build(b), s) for p, b, s in zip(folds, bases, scores)]
    score = pool(folds, [g.score for g in fits])
    return GenericFit(score, 1.0 - score / base_score if base_score > 0 else 0.0, fits[0].numbers)


def alternatives(best: Finding, others: Sequence[Finding]) -> list[str]:
    """What the data cannot tell ``best`` from, each with its gain: a candidate explaining almost
    as much (``ALTERNATIVE``), or one with fewer numbers explaining most of it (``SIMPLER``: a
    rear-steering path of four numbers beside a refit of one stiffness)."""
    return [f"{f.describe()} ({100 * f.gain:.2g} % lower)" for f in others if f.error is None and not f.screened
            and (f.gain >= ALTERNATIVE * best.gain or (_numbers(f) < _numbers(best) and f.gain >= SIMPLER * best.gain))]


def _numbers(f: Finding) -> int:
    return len(f.candidate.knobs) if f.candidate is not None else 0


def _not_fitted(rounds: Sequence[Sequence[Finding]]) -> list[str]:
    """One line per candidate the data were too short to fit, from the first round it was not fitted in."""
    lines: dict[str, str] = {}
    for findings in rounds:
        for f in findings:
            if f.too_short and f.error and f.key not in lines:
                lines[f.key] = f"{f.cause} on {f.target} not fitted: {f.too_short}"
    return list(lines.values())


def _small_offsets(findings: Sequence[Finding], unjudged: dict[str, str], error: str) -> list[Finding]:
    """The findings below min_gain that are named as small offsets (:func:`_significant`); an offset
    that would be weighed as one but whose standard error the data cannot judge goes to ``unjudged``."""
    for f in findings:
        if f.error is None and f.too_short and f.gain >= OFFSET_GAIN:
            unjudged[f.key] = (f"{f.cause} on {f.target} lowers the {error} by {100 * f.gain:.2g} %, "
                               f"but {f.too_short}, so it is not named as a small bias")
    return [f for f in findings if _significant(f)]


def _joint_offsets(named: list[Finding], bases: list[ModelSpec], scores: list[float], folds: Sequence[Problem],
                   progress: Callable[[str], None], too_short: list[str]
                   ) -> tuple[list[Finding], list[Finding], list[ModelSpec], list[float]]:
    """The named offsets fitted again all together (in each fold); while one of them is then under
    OFFSET_Z standard errors from zero in a fold (it stood in for the others: a steering offset
    for a yaw-rate and a side-slip bias), the weakest is dropped; an offset as weak in that fit
    lists it as the alternative the data cannot tell it from. Where the training stretches cannot
    judge them together, they stay as named and ``too_short`` says why. Returns the named causes,
    the dropped ones, each fold's model with the final offsets and its score."""
    offsets = [f for f in named if f.candidate is not None and f.candidate.fit == AFFINE]
    dropped: list[Finding] = []
    if len(offsets) < 2:
        return named, dropped, bases, scores
    shortfalls = [p.evidence().error_shortfall(len(offsets)) for p in folds]
    judged = [k for k, short in enumerate(shortfalls) if not short]  # the folds whose stretches can judge them
    if not judged:
        shortfall = shortfalls[0]
        too_short.append(f"the {len(offsets)} named offsets are not weighed against each other: {shortfall}")
        return named, dropped, bases, scores
    while True:
        fitted = [fit_offsets(b, [f.target for f in offsets], p) for b, p in zip(bases, folds)]
        z = {f.target: pooled_z([fitted[k][0][f.target] for k in judged], [fitted[k][1][f.target] for k in judged])
             for f in offsets}
        weakest = min(offsets, key=lambda f: z[f.target])
        if z[weakest.target] >= OFFSET_Z or len(offsets) == 1:
            break
        offsets.remove(weakest)
        dropped.append(weakest)
        for other in offsets:  # as weak in the joint fit: the data cannot tell the two apart
            if z[other.target] < OFFSET_Z:
                other.alternatives = [a for a in other.alternatives
                                      if not a.startswith(f"{weakest.cause} on {weakest.target}:")]
                other.alternatives.append(weakest.describe())
        bases = [dataclasses.replace(b, sensor_offsets={k: v for k, v in b.sensor_offsets.items()
                                                        if k != weakest.target}) for b in bases]
        weakest.note = (f"dropped: fitted together with the other offsets it is {z[weakest.target]:.1f} "
                        "standard errors from zero (they carry what it explained)")
        progress(f"{weakest.cause} on {weakest.target}: {weakest.note}")
    if not dropped:
        return named, dropped, bases, scores
    for f in offsets:
        f.values, f.z = {f.target: sum(values[f.target] for values, _ in fitted) / len(fitted)}, z[f.target]
    bases = [dataclasses.replace(b, sensor_offsets={**b.sensor_offsets, **values}) for b, (values, _) in zip(bases, fitted)]
    scores = [p.stretches("val").score(p.build(b)) for p, b in zip(folds, bases)]
    return [f for f in named if all(f is not d for d in dropped)], dropped, bases, scores


def _significant(f: Finding) -> bool:
    """An offset fitted, far from zero by its standard error, and lowering the validation error."""
    return f.error is None and f.z is not None and f.z >= OFFSET_Z and f.gain >= OFFSET_GAIN
