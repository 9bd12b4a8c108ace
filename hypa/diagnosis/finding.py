"""One candidate fitted and scored: the :class:`Finding`, and what the data cannot tell it from.

A candidate cause (:mod:`hypa.diagnosis.edits`) is fitted on the training windows
(:mod:`hypa.diagnosis.fitting`) and scored free-running on the validation stretches
(:func:`evaluate`); a fit that fails is reported as a finding with its error, never ends the
diagnosis (``FIT_ERRORS``). Beside the cause named, the search lists the candidates the data
cannot tell from it (:func:`alternatives`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from hypa.diagnosis.edits import AFFINE, GRADIENT, Candidate, applied
from hypa.diagnosis.fitting import fit_affine, fit_gradient
from hypa.diagnosis.problem import Problem, TooLittleData
from hypa.models.spec import ModelSpecError
from hypa.physics import SchedulingError, UnstablePhysicsError
from hypa.physics.fmu import FMUError
from hypa.reporting.numbers import quantity

ALTERNATIVE = 0.95  # a candidate explaining this share of the named one's gain is reported beside it ...
SIMPLER = 0.75  # ... and one with fewer numbers from this share on (the data cannot prefer the richer claim)


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
        parts = [f"{k.split('/')[-1]} {quantity(v, self.units.get(k, ''))}" for k, v in self.values.items()
                 if k != self.target] + [quantity(v, self.units.get(k, "")) for k, v in self.values.items()
                                         if k == self.target]
        note = self.note or _limited_note(self.candidate, self.values, self.units)
        parts += [note] if note else []
        return f"{self.cause} on {self.target}" + (f": {', '.join(parts)}" if parts else "")

    def to_dict(self) -> dict:
        return {"cause": self.cause, "target": self.target, "values": self.values, "units": self.units,
                "score": self.score, "gain": self.gain, "seconds": self.seconds, "error": self.error,
                "alternatives": self.alternatives, "refined": self.refined,
                "steps": list(self.steps) if self.steps else None, "z": self.z, "small": self.small,
                "too_short": self.too_short, "generic": self.generic, "text": self.describe(),
                "folds": [f.values for f in self.folds], "screened": self.screened}

    @property
    def numbers(self) -> int:
        """How many numbers its fit sets (its candidate's knobs)."""
        return len(self.candidate.knobs) if self.candidate is not None else 0


FIT_ERRORS = (UnstablePhysicsError, SchedulingError, ModelSpecError, ValueError, ArithmeticError,
              torch.linalg.LinAlgError, FMUError)  # a candidate that fails is reported, never ends the diagnosis


def evaluate(candidate: Candidate, problem: Problem, windows: Mapping[str, torch.Tensor], base_score: float,
             refine: Sequence[str] = ()) -> Finding:
    """Fit a candidate (with ``refine``, see :class:`~hypa.diagnosis.fitting.GradientFit`) and score it on the
    validation stretches. ``values`` holds the candidate's own knobs, ``refined`` the others."""
    started, z = time.perf_counter(), None
    try:
        if candidate.fit == GRADIENT:
            values = fit_gradient(candidate, problem, windows, refine)
        elif candidate.fit == AFFINE:
            values, z = fit_affine(candidate, problem)
        else:
            values = {}
        value = problem.stretches("val").score(problem.build(applied(candidate, values)))
    except FIT_ERRORS as error:
        return failed(candidate, error, time.perf_counter() - started)
    finding = scored(candidate, problem, values, value, base_score, time.perf_counter() - started)
    finding.z = z
    if candidate.fit == AFFINE and z is None:
        finding.too_short = f"its standard error is not judged: {problem.evidence().error_shortfall(1)}"
    return finding


def failed(candidate: Candidate, error: Exception, seconds: float) -> Finding:
    """A candidate whose fit failed: its error on one line, no values, an infinite score."""
    short = isinstance(error, TooLittleData)
    return Finding(candidate.cause, candidate.target, {}, {}, math.inf, -math.inf, seconds,
                   ("too little data: " if short else "") + str(error).split("\n")[0], candidate,
                   too_short=str(error) if short else "")


def scored(candidate: Candidate, problem: Problem, values: Mapping[str, float], value: float, base_score: float,
           seconds: float) -> Finding:
    """A candidate fitted to ``values`` and scored ``value`` on the validation stretches."""
    units = dict(candidate.units) or {candidate.target: problem.dm.channels[candidate.target].unit
                                      if candidate.fit == AFFINE else ""}
    gain = 1.0 - value / base_score if base_score > 0 else 0.0
    note = (_scheduling_note(candidate, problem) if candidate.cause == "scheduling" else
            _curved_note(candidate, problem) or _inside_note(candidate, problem, values))
    own = {k: v for k, v in values.items() if k in candidate.knobs or candidate.fit == AFFINE}
    refined = {k: v for k, v in values.items() if k not in own}
    return Finding(candidate.cause, candidate.target, own, units, value, gain, seconds, None, candidate, note=note,
                   refined=refined)


def _curved_note(candidate: Candidate, problem: Problem) -> str:
    """What a curved state's weights w mean (``hypa.physics.curved``): ``each coupling from
    voltage is (1 + w z²) times the linear one, z = (voltage + 0.0011 V) / 1.67 V``; "" for any
    other candidate."""
    block, _, state = candidate.target.partition("/")
    if not state or block not in candidate.spec.block_names:
        return ""
    b = candidate.spec.block(block)
    if state not in b.curved:
        return ""
    level, spread = b.parameters.get(f"{state}_level", 0.0), b.parameters.get(f"{state}_spread", 1.0)
    unit = problem.dm.channels[state].unit if state in problem.dm.channels else ""
    if b.curved[state] == "root":
        return (f"each coupling from {state} is (1 - w) times the linear one plus w times its root through the "
                f"same flow at {quantity(level, unit)} (w = 1: all √{state})")
    sign, shift = ("+", -level) if level < 0 else ("-", level)
    return (f"each coupling from {state} is (1 + w z{'²' if b.curved[state] == 3 else ''}) times the linear one, "
            f"z = ({state} {sign} {quantity(shift, unit)}) / {quantity(spread, unit)}")


INSIDE = 0.1  # a limit that bends more than this share of the samples sits inside the signal's range


def _inside_note(candidate: Candidate, problem: Problem, values: Mapping[str, float]) -> str:
    """What an input's limit is where it sits inside the range the input spans (it bends more
    than ``INSIDE`` of the training samples: below the 90th percentile of the input's size) rather
    than at its peaks: "" where it does not, or for any other candidate. (A 0.6 deg steering limit
    was named on a log whose steering spans -0.47...1.04 deg: a gain that changes with the
    steering's size, not an actuator's range.)"""
    blocks = [b for b in candidate.spec.blocks if b.kind == "saturation" and f"{b.name}/limit" in values]
    if not blocks or blocks[0].inputs[0] not in problem.dm.channels:
        return ""
    channel, limit = blocks[0].inputs[0], abs(values[f"{blocks[0].name}/limit"])
    signal = np.concatenate([np.asarray(r[channel], float) for r in problem.records("train")])
    share = float(np.mean(np.abs(signal) > limit)) if signal.size else 0.0
    if share <= INSIDE:
        return ""
    unit = problem.dm.channels[channel].unit
    low, high = np.percentile(signal, [10, 90])
    return (f"the limit sits inside the range {channel} spans ({quantity(float(low), unit)} to "
            f"{quantity(float(high), unit)}, 10th to 90th percentile) and bends {100 * share:.0f} % of the "
            "training samples: a gain that falls with the input's size, not a range reached at its peaks")


def _limited_note(candidate: Candidate | None, values: Mapping[str, float], units: Mapping[str, str]) -> str:
    """What a limited state's values mean (``hypa.physics.limited``): ``upper stops below 9.06:
    what would carry it further spills, 51 % of it reaching lower, the rest lost``; "" for any
    other candidate."""
    block, _, state = (candidate.target if candidate else "").partition("/")
    if not state or block not in candidate.spec.block_names:
        return ""
    side = candidate.spec.block(block).limited.get(state)
    key = f"{block}/{state}_limit"
    if side is None or key not in values:
        return ""
    from hypa.physics.limited import spill_name

    prefix = f"{block}/{spill_name(state, '')}"
    shares = {k[len(prefix):]: v for k, v in values.items() if k.startswith(prefix)}
    spilled = "".join(f", {100 * v:.2g} % of it reaching {row}" for row, v in shares.items())
    rest = ", the rest lost" if shares and sum(shares.values()) < 0.995 else ""
    return (f"{state} stops {'above' if side == 'lower' else 'below'} {quantity(values[key], units.get(key, ''))}: "
            f"what would carry it further spills{spilled}{rest}" + ("" if shares else " away"))


def _scheduling_note(candidate: Candidate, problem: Problem) -> str:
    """``fixed at 20 m/s in the model, measured 5.1–32 m/s``."""
    dm, name = problem.dm, candidate.target
    values = np.concatenate([r[name] for r in dm.records("train")])
    fixed = {**problem.physical_values, **candidate.spec.parameters}.get(name)
    unit = dm.channels[name].unit
    held = f"fixed at {fixed:.3g} {unit} in the model, " if fixed is not None else ""
    return f"{held}measured {values.min():.3g}–{values.max():.3g} {unit}"


def alternatives(best: Finding, others: Sequence[Finding]) -> list[str]:
    """What the data cannot tell ``best`` from, each with its gain: a candidate explaining almost
    as much (``ALTERNATIVE``), or one with fewer numbers explaining most of it (``SIMPLER``: a
    rear-steering path of four numbers beside a refit of one stiffness)."""
    return [f"{f.describe()} ({100 * f.gain:.2g} % lower)" for f in others if f.error is None and not f.screened
            and (f.gain >= ALTERNATIVE * best.gain or (f.numbers < best.numbers and f.gain >= SIMPLER * best.gain))]

