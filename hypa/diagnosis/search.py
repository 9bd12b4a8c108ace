"""Name what the physics gets wrong, on any system: candidates fitted and scored with the model itself.

The nominal model is a :class:`~hypa.models.ModelSpec` (the physics a user trusts, frozen). Each
candidate cause (:mod:`hypa.diagnosis.edits`) is an edit of it; the edited model is built as a
:class:`~hypa.models.ComposedModel` (the class ``hypa train`` trains), its knobs are fitted on
the training windows (:mod:`hypa.diagnosis.fitting`: gradient fits of the physical parameters,
least squares for an offset; on worker processes, :mod:`hypa.diagnosis.workers`), and it is
scored free-running over held-out data (:mod:`hypa.diagnosis.problem`; one candidate:
:mod:`hypa.diagnosis.finding`, a round's fits raced: :mod:`hypa.diagnosis.race`). Judged by
cross-validation over blocked stretches of all records, training and validation
(:meth:`Problem.folds`, :mod:`hypa.diagnosis.cross_validation`): each fold fits on every other block and scores
on the rest, and the folds' errors pool into the error over all blocks, so one validation record
unlike the training does not decide. A greedy search names the
candidate with the largest gain, writes its fitted values (each fold's) into the model and searches again
from there, until no candidate improves the cross-validated error by ``min_gain``. What remains is
then tested for structure (:mod:`hypa.diagnosis.structure`): where significant error is left that
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
from dataclasses import dataclass, field
from functools import partial

import numpy as np
import torch

from hypa.diagnosis.catalogue import Entry, catalogue_candidates, load_catalogue, state_blocks
from hypa.diagnosis.cross_validation import evaluate_folds, evaluate_generic, pool, pooled_z
from hypa.diagnosis.edits import AFFINE, GRADIENT, Candidate, applied, averaged, frozen, home, set_free
from hypa.diagnosis.finding import ALTERNATIVE, SIMPLER, Finding, alternatives
from hypa.diagnosis.fitting import fit_offsets
from hypa.diagnosis.generic import MARGIN as GENERIC_MARGIN
from hypa.diagnosis.generic import GenericFit
from hypa.diagnosis.problem import Problem
from hypa.diagnosis.race import append_result
from hypa.diagnosis.scales import duration
from hypa.diagnosis.states import state_scales
from hypa.models.spec import ModelSpec
from hypa.reporting.numbers import percent, quantity

OFFSET_Z = 5.0  # an offset below min_gain is still named this many standard errors away from zero ...
OFFSET_GAIN = 0.005  # ... when it lowers the validation error by at least this share (a small sensor bias)


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
                min_gain: float = 0.15, floor: float = 1e-4,
                progress: Callable[[str], None] = lambda _: None) -> Search:
    """Greedy forward search over the catalogue from the frozen ``nominal`` model.

    ``catalogue``: the entries (default: the built-in catalogues, :func:`load_catalogue`);
    ``candidates(spec)``, if given, lists the candidates of a base model instead. Each round fits
    all of them, names the best if it lowers the validation error (1 - R², mean over outputs) by
    at least ``min_gain`` (relative), applies it and goes on;
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

        listed: dict[str, list[Candidate]] = {}  # by the spec's text: _prune rebuilds the same models often

        def candidates(spec: ModelSpec) -> list[Candidate]:
            key = repr(spec)
            if key not in listed:
                listed[key] = _listed(spec)
            return list(listed[key])

        def _listed(spec: ModelSpec) -> list[Candidate]:
            # the states' operating points, spreads and free-run ranges in this round's model: a state
            # no sensor reads moves with the values fitted so far (the tanks' upper level with k4 / k1)
            model = problem.build(frozen(spec))
            states = state_scales(model, problem.stretches("train"), state_blocks(entries, spec))
            # a signal between blocks: its peak, |mean| + 3 spreads in the model's scaling (a block's input)
            internal = {name: (abs(float(mean)) + 3 * float(std), "") for name, (mean, std) in model.scales.items()
                        if name not in channels}
            found = catalogue_candidates(entries, spec, dm.input_names, dm.output_names, dm.scheduling_names,
                                         problem.physical_values, dm.dt, uncertain, {**internal, **channels}, states)
            return [c for c in found if _both_directions(c, spec, ranges, states)]

        ranges = {n: _range(np.concatenate([r[n] for r in dm.records("train")])) for n in measured}
    torch.manual_seed(problem.seed)
    folds = problem.folds()
    windows = [p.windows() for p in folds]
    bases = [frozen(nominal)] * len(folds)
    scores = [p.stretches("val").score(p.build(b)) for p, b in zip(folds, bases)]
    base_score = nominal_score = pool(folds, scores)
    error = "cross-validated error" if len(folds) > 1 else "validation error"
    progress(f"time scales: {problem.time_scales.describe()}")
    if len(folds) > 1:
        progress(f"judged by cross-validation: {len(problem.blocks())} blocks of "
                 f"{duration(problem.time_scales.stretch_s)} "
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
    identified: list[Finding] = []  # the nominal's uncertain values, identified before any structural cause
    if any(uncertain.values()) and max_causes > 0:
        found = _identify(nominal, candidates, folds, bases, scores, windows, base_score, min_gain, floor,
                          error, progress)
        if found is not None:
            identified, bases, scores, base_score = found
            refine += [k for f in identified for k in f.candidate.knobs if k not in refine]
    while len(named) < max_causes and base_score > floor:
        done, round_started = {f.key for f in named}, time.perf_counter()
        bar: list[GenericFit] = []  # fitted by this process while the workers fit the candidates
        findings = round_of(lambda c: c.key not in done, refine,  # noqa: B023 -- round_of applies it before returning
                            side=[partial(append_result, bar, evaluate_generic, folds, bases, scores, base_score)])
        rounds.append(findings)
        generic.append(bar[0] if bar else evaluate_generic(folds, bases, scores, base_score))
        progress(_round_line(len(rounds), findings, time.perf_counter() - round_started, max_causes - len(named)))
        if not findings or findings[0].gain < min_gain:
            break
        best, bar = findings[0], generic[-1]
        simpler = best.candidate is not None and len(best.candidate.knobs) < bar.numbers
        if not (best.score < (1.0 - GENERIC_MARGIN) * bar.score or (simpler and best.gain >= SIMPLER * bar.gain)):
            standin = (f"{best.describe()} would lower the {error} by {percent(best.gain)}, but "
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
        progress(f"named {best.describe()} ({error} {percent(best.gain)} lower; a generic linear filter: "
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
        progress(f"named {best.describe()} ({error} {percent(best.gain)} lower: small, but "
                 f"{best.z:.0f} standard errors from zero)")
        findings = round_of(lambda c, keys={f.key for f in findings[1:]}: c.key in keys)
        if findings:
            rounds.append(findings)
        findings = _small_offsets(findings, unjudged, error)
    too_short = _not_fitted(rounds) + list(unjudged.values())
    named, dropped, bases, scores = _joint_offsets(named, bases, scores, folds, progress, too_short)
    # the identified values, after the causes (each of which re-fitted them): each stays named only
    # where, with every cause named, it still lowers the error by min_gain (:func:`_prune`); one that
    # the causes made unnecessary goes back to its nominal value
    named, bases, scores = _prune(nominal, named + identified, dropped, bases, scores, folds, candidates, min_gain,
                                  floor, error, progress)
    final = averaged(bases)
    for k, f in enumerate(named):  # the final values: re-fitted jointly with every later cause
        for later in named[k + 1 :]:
            f.values.update({name: v for name, v in later.refined.items() if name in f.values})
        held = _knob_values(final, f.candidate) if f.candidate is not None and f.candidate.fit == GRADIENT else None
        f.values.update(held or {})  # what the model written holds (an identified value the causes re-fitted)
    for f in identified:
        if any(f is g for g in named):
            progress(f"named {f.describe()} (identified first: it removed {percent(f.gain)} of the {error} "
                     "that its nominal value left, and the causes named still need it)")
    return Search(nominal_score, rounds, named, final, pool(folds, scores), time.perf_counter() - started,
                  dropped, too_short, generic, standin, folds=len(folds),
                  blocks=len(problem.blocks()) if len(folds) > 1 else 0)


def _range(values: np.ndarray) -> tuple[float, float, float]:
    """A signal's 10th and 90th percentiles and its spread."""
    return float(np.percentile(values, 10)), float(np.percentile(values, 90)), float(np.std(values))


def _both_directions(candidate: Candidate, base: ModelSpec, ranges: Mapping[str, tuple[float, float, float]],
                     states: Mapping[str, tuple[float, ...]]) -> bool:
    """False for a parameter made to differ with the direction of a signal that does not take both
    directions (a pump voltage, a tank's level: its 10th and 90th percentiles not on either side of
    zero by a tenth of its spread): on such a signal the dependence is a constant factor, a
    parameter refit in disguise, not a cause of its own."""
    before = {b.name: b.depends for b in base.blocks}
    for block in candidate.spec.blocks:
        for parameter, how in block.depends.items():
            if how.get("kind") != "direction" or before.get(block.name, {}).get(parameter) == how:
                continue
            signal = how.get("by", "")
            if signal in ranges:
                low, high, spread = ranges[signal]
            elif f"{block.name}/{signal}" in states:
                _, spread, low, high = states[f"{block.name}/{signal}"][:4]
            else:
                continue
            if not (low < -0.1 * spread and high > 0.1 * spread):
                return False
    return True


def _round_line(number: int, findings: Sequence[Finding], seconds: float, left: int) -> str:
    """``round 1: 23 candidates (9 fitted to convergence, 14 not), 41 s; at most 7 more rounds``
    (a round after a nonlinear cause simulates every candidate step by step: it can take longer)."""
    fitted = sum(1 for f in findings if f.error is None)
    return (f"round {number}: {len(findings)} candidates ({fitted} fitted to convergence, {len(findings) - fitted} "
            f"not), {duration(seconds)}"
            + (f"; at most {left - 1} more round{'s' if left > 2 else ''}" if left > 1 else ""))


def _identify(nominal: ModelSpec, candidates: Callable[[ModelSpec], list[Candidate]], folds: Sequence[Problem],
              bases: Sequence[ModelSpec], scores: Sequence[float], windows: Sequence, base_score: float,
              min_gain: float, floor: float, error: str, progress: Callable[[str], None]
              ) -> tuple[list[Finding], list[ModelSpec], list[float], float] | None:
    """The nominal model's uncertain parameters (its ``trainable`` ones) identified together before
    any structural cause is judged, so that a poor nominal value does not breed stand-ins (an input
    limit or a curved state doing a gain's work). Fitted in each fold as a candidate is; then each
    is put back to its nominal value in turn (the others as identified), and the one whose return
    costs least goes back while that raises the error by less than ``min_gain`` (the mirror of
    naming one: :func:`_prune`'s rule). The rest are named ``parameter_mismatch``, the most
    needed first, each with the share of the error its identified value removes. Returns the
    named findings, each fold's model and score with them, and the pooled score; ``None`` where
    the identification does not lower the error."""
    singles = {c.knobs[0]: c for c in candidates(bases[0]) if c.cause == "parameter_mismatch" and len(c.knobs) == 1}
    if not singles:
        return None
    knobs = tuple(singles)
    units = {k: u for c in singles.values() for k, u in c.units.items()}

    def joint(spec: ModelSpec) -> list[Candidate]:
        return [Candidate("parameter_mismatch", ", ".join(knobs), set_free(frozen(spec), knobs), GRADIENT, knobs,
                          units)]

    started = time.perf_counter()
    progress(f"identifying the nominal's uncertain parameters first ({', '.join(knobs)})")
    fits = evaluate_folds(joint, folds, bases, scores, windows, base_score, min_gain)
    fit = fits[0] if fits else None
    if fit is None or fit.error or fit.screened or not fit.gain > 0:
        why = (f"not fitted ({fit.error})" if fit is not None and fit.error else
               f"it lowers the first fold's error by only {100 * max(fit.gain, 0.0):.2g} %" if fit is not None
               else "nothing to fit")
        progress(f"the nominal's values are kept: identified, {why}")
        return None
    # a sensor or input offset (one number, exact least squares) that explains about as much is the
    # simpler account: a conductance re-fitted to shift a steady level is a stand-in for a sensor bias
    offsets = evaluate_folds(lambda b: [c for c in candidates(b) if c.fit == AFFINE], folds, bases, scores, windows,
                             base_score, min_gain)
    rival = max((f for f in offsets if f.error is None and not f.screened), key=lambda f: f.gain, default=None)
    if rival is not None and rival.gain >= ALTERNATIVE * fit.gain:
        progress(f"the nominal's values are kept: {rival.describe()} explains about as much as identifying them "
                 f"({percent(rival.gain)} against {percent(fit.gain)} lower) with fewer numbers")
        return None
    per_fold = fit.folds or [fit]
    model = folds[0].build(frozen(nominal))
    start = {k: float(model.parameters_.value(k).detach()) for k in knobs}
    values = [dict(f.values) for f in per_fold]

    def models(kept: Sequence[str]) -> list[ModelSpec]:
        return [applied(joint(b)[0], {k: v[k] if k in kept else start[k] for k in knobs})
                for b, v in zip(bases, values)]

    def scored(kept: Sequence[str]) -> tuple[list[ModelSpec], list[float]]:
        specs = models(kept)
        return specs, [p.stretches("val").score(p.build(m)) for p, m in zip(folds, specs)]

    kept, shares = list(knobs), {}
    current_specs, current_scores = scored(kept)
    current = pool(folds, current_scores)
    progress(f"identified: {', '.join(_shift(k, start[k], fit.values[k], units.get(k, '')) for k in knobs)} "
             f"({error} {100 * base_score:.3g} % → {100 * current:.3g} % of the output variance)")
    while kept:
        trials = {k: scored([j for j in kept if j != k]) for k in kept}
        worse = {k: pool(folds, trial[1]) for k, trial in trials.items()}
        share = {k: (w - current) / w if w > 0 else 0.0 for k, w in worse.items()}
        weakest = min(kept, key=lambda k: share[k])
        if share[weakest] >= min_gain and worse[weakest] > floor:
            shares.update(share)
            break
        kept.remove(weakest)
        current_specs, current_scores = trials[weakest]
        current = worse[weakest]
    if not kept:
        progress("no uncertain parameter is off by more than the data can tell: the nominal's values are kept")
        return None
    seconds = time.perf_counter() - started
    named = []
    for k in sorted(kept, key=lambda k: -shares[k]):
        c = singles[k]
        own = [Finding(c.cause, c.target, {k: v[k]}, dict(c.units), f.score, shares[k], f.seconds, candidate=c,
                       refined={j: v[j] for j in kept if j != k}) for f, v in zip(per_fold, values)]
        mean = sum(v[k] for v in values) / len(values)
        named.append(Finding(c.cause, c.target, {k: mean}, dict(c.units), current, shares[k], seconds / len(kept),
                             candidate=c, refined={j: sum(v[j] for v in values) / len(values) for j in kept if j != k},
                             steps=fit.steps, folds=own if len(own) > 1 else []))
    progress(f"the search starts from the nominal model with {', '.join(f.target for f in named)} as identified "
             f"({error} {100 * current:.3g} % of the output variance); every cause re-fits them")
    return named, current_specs, current_scores, current


def _shift(name: str, before: float, after: float, unit: str) -> str:
    """``k1 0.02 → 0.0101 1/s``, ``tau 0.1 → 0.236 ms``, ``gain 1 → 0.721`` (a dimensionless one)."""
    before_text, after_text = quantity(before, unit), quantity(after, unit)
    same_unit = before_text.partition(" ")[2] == after_text.partition(" ")[2]
    return f"{name} {before_text.partition(' ')[0] if same_unit else before_text} → {after_text}"


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
            unjudged[f.key] = (f"{f.cause} on {f.target} lowers the {error} by {percent(f.gain)}, "
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
    bases = [dataclasses.replace(b, sensor_offsets={**b.sensor_offsets, **values})
             for b, (values, _) in zip(bases, fitted)]
    scores = [p.stretches("val").score(p.build(b)) for p, b in zip(folds, bases)]
    return [f for f in named if all(f is not d for d in dropped)], dropped, bases, scores


def _knob_values(spec: ModelSpec, candidate: Candidate) -> dict[str, float] | None:
    """The values ``spec`` holds for ``candidate``'s knobs (None where one is missing)."""
    values = {}
    for knob in candidate.knobs:
        blocks, local = home(spec, knob)
        if candidate.fit == AFFINE:
            found = spec.sensor_offsets.get(knob)
        elif blocks:
            found = spec.block(blocks[0]).parameters.get(local)
        else:
            found = spec.parameters.get(knob)
        if found is None:
            return None
        values[knob] = float(found)
    return values


def _rebuilt(nominal: ModelSpec, causes: Sequence[Finding], final: ModelSpec,
             candidates: Callable[[ModelSpec], list[Candidate]]) -> ModelSpec | None:
    """The nominal model with ``causes`` applied in turn, each at its values in ``final`` (None where
    one no longer applies)."""
    spec = frozen(nominal)
    for f in causes:
        match = [c for c in candidates(spec) if c.key == f.key]
        values = _knob_values(final, match[0]) if match else None
        if values is None:
            return None
        spec = applied(match[0], values)
    return spec


def _prune(nominal: ModelSpec, named: list[Finding], dropped: list[Finding], bases: list[ModelSpec],
           scores: list[float], folds: Sequence[Problem], candidates: Callable[[ModelSpec], list[Candidate]],
           min_gain: float, floor: float, error: str, progress: Callable[[str], None]
           ) -> tuple[list[Finding], list[ModelSpec], list[float]]:
    """The fitted causes that the causes named after them made unnecessary, dropped (the latest
    first): a cause that stood in for others early in the greedy search (a nonlinearity fitted
    before a parameter's mismatch was) keeps its knobs in every later fit, and where these end
    near where it started, removing it from the final model, with every other value as fitted,
    raises the cross-validated error by less than ``min_gain`` (or leaves it below ``floor``).
    Each fold's model is rebuilt from the nominal one with the other causes at their final values;
    where that does not reproduce the final model's error (a cause that no longer applies), nothing is dropped."""
    fitted = [f for f in named if f.candidate is not None and f.candidate.fit == GRADIENT and not f.small]
    if len(named) < 2 or not fitted:
        return named, bases, scores
    current = pool(folds, scores)
    again = [_rebuilt(nominal, named, b, candidates) for b in bases]
    if any(s is None for s in again) or not math.isclose(
            pool(folds, [p.stretches("val").score(p.build(s)) for p, s in zip(folds, again)]), current,
            rel_tol=1e-4, abs_tol=1e-12):
        return named, bases, scores
    for f in reversed(fitted):
        kept = [g for g in named if g is not f]
        without = [_rebuilt(nominal, kept, b, candidates) for b in bases]
        if any(s is None for s in without):
            continue
        trial = [p.stretches("val").score(p.build(s)) for p, s in zip(folds, without)]
        worse = pool(folds, trial)
        share = (worse - current) / worse if worse > 0 else 0.0
        if share >= min_gain and worse > floor:
            continue
        why = (f"with the causes named after it, it lowers the {error} by only {100 * max(share, 0.0):.2g} % "
               f"(under {percent(min_gain)})" if share < min_gain else
               f"without it the {error} is {100 * worse:.2g} % of the output variance, below the noise floor "
               f"({100 * floor:.2g} %)")
        f.note = f"dropped: {why}: the other causes named carry what it explained"
        progress(f"{f.cause} on {f.target}: {f.note}")
        named, bases, scores, current = kept, without, trial, worse
        dropped.append(f)
    return named, bases, scores


def _significant(f: Finding) -> bool:
    """An offset fitted, far from zero by its standard error, and lowering the validation error."""
    return f.error is None and f.z is not None and f.z >= OFFSET_Z and f.gain >= OFFSET_GAIN
