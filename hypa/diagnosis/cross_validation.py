"""A round cross-validated over folds (:func:`evaluate_folds`), and the folds' scores pooled.

The folds (:meth:`Problem.folds`) hold out blocked stretches of all records, training and
validation, in turn: each fold fits on every other block and scores on the rest, and the folds'
errors pool into the error over all blocks (:func:`pool`), so one validation record unlike the
training does not decide. A candidate's values are the folds' mean; an offset's standard error
pools over the folds that can judge it (:func:`pooled_z`). The generic filter every cause must
beat is cross-validated the same way (:func:`evaluate_generic`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence

import torch

from hypa.diagnosis.edits import GRADIENT, Candidate
from hypa.diagnosis.finding import ALTERNATIVE, SIMPLER, Finding
from hypa.diagnosis.generic import GenericFit, fit_generic
from hypa.diagnosis.problem import Problem
from hypa.diagnosis.race import SCREEN, evaluate_round
from hypa.models.spec import ModelSpec

# a gradient fit goes on to the other folds from this share of what it needs on the first (evaluate_folds)
CONTENDER = 0.8
# ... and the first fold's best few go on whatever the margin: one fold's best can be its own fluke
RUNNERS_UP = 3


def evaluate_folds(candidates: Callable[[ModelSpec], list[Candidate]], folds: Sequence[Problem],
                   bases: Sequence[ModelSpec], scores: Sequence[float], windows: Sequence[Mapping[str, torch.Tensor]],
                   base_score: float, min_gain: float, refine: Sequence[str] = (),
                   keep: Callable[[Candidate], bool] = lambda _: True, side: Sequence[Callable[[], None]] = ()
                   ) -> list[Finding]:
    """A round cross-validated (:meth:`Problem.folds`): the candidates of each fold's base model
    that ``keep`` keeps, fitted on the fold's blocks and scored on its held-out ones
    (:func:`evaluate_round`), their scores pooled over the folds (the error over all blocks, each
    scored by a fit that never saw it), their values the folds' mean (each fold's in ``folds``).

    All run the first fold, the gradient fits screened by their score test there
    (:func:`~hypa.diagnosis.race.evaluate_round`: a fit runs where its first step promises
    ``SCREEN`` of ``min_gain``, or among the best few promises). A gradient fit goes on to the
    others only where it could be named or listed beside the one named: its gain there at least
    ``CONTENDER`` (a margin for the folds'
    spread) of ``min_gain`` and of what :func:`~hypa.diagnosis.finding.alternatives` asks beside
    the fold's best; the ``RUNNERS_UP`` best of the first fold go on wherever their gain reaches
    ``CONTENDER`` of ``min_gain``, as one fold's best may fit that fold alone (an input limit that
    clips one fold's peaks). The rest stop at it (``screened``, listed after the others with the
    first fold's gain). Offsets and structural candidates (cheap) run every fold.
    """
    def listed(k: int) -> list[Candidate]:
        return [c for c in candidates(bases[k]) if keep(c)]

    first = evaluate_round(listed(0), folds[0], windows[0], scores[0], refine, screen=SCREEN * min_gain, side=side,
                           base=bases[0])
    if len(folds) == 1:
        return first
    fitted = [f for f in first if f.error is None]
    best = max(fitted, key=lambda f: f.gain, default=None)

    def contends(f: Finding) -> bool:  # could be named, or listed beside the one named (alternatives)
        if f.candidate is None or f.candidate.fit != GRADIENT:
            return True
        if f.error is not None or best is None or best.gain <= 0:
            return False
        share = SIMPLER if f.numbers < best.numbers else ALTERNATIVE
        return f.gain >= CONTENDER * max(min_gain, share * best.gain)

    fits = [f for f in fitted if f.candidate is not None and f.candidate.fit == GRADIENT]
    leading = sorted(fits, key=lambda f: -f.gain)[:RUNNERS_UP]
    going = {f.key for f in first if contends(f)} | {f.key for f in leading if f.gain >= CONTENDER * min_gain}
    per_fold = [{f.key: f for f in first}]
    for k in range(1, len(folds)):
        found = evaluate_round([c for c in listed(k) if c.key in going], folds[k], windows[k], scores[k], refine)
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


def evaluate_generic(folds: Sequence[Problem], bases: Sequence[ModelSpec], scores: Sequence[float],
                     base_score: float) -> GenericFit:
    """The generic filter (:func:`~hypa.diagnosis.generic.fit_generic`) cross-validated as the candidates are."""
    fits = [fit_generic(p, p.build(b), s) for p, b, s in zip(folds, bases, scores)]
    score = pool(folds, [g.score for g in fits])
    return GenericFit(score, 1.0 - score / base_score if base_score > 0 else 0.0, fits[0].numbers)
