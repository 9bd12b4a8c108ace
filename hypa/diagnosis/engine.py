"""Name what the physics gets wrong, on any system: candidates fitted and scored with the model itself.

The nominal model is a :class:`~hypa.models.ModelSpec` (the physics a user trusts, frozen). Each
candidate cause (:mod:`hypa.diagnosis.edits`) is an edit of it; the edited model is built as a
:class:`~hypa.models.ComposedModel` (the class ``hypa.train`` trains), its knobs are fitted on
the training windows (gradient descent on the physical parameters, or least squares for an
offset), and it is scored free-running over the validation records. A greedy search names the
candidate with the largest gain, writes its fitted values into the model and searches again
from there, until no candidate improves the validation error by ``min_gain``. What remains is
then tested for structure (:func:`residual_structure`): where significant error is left that
no catalogue entry explains, the diagnosis says where it lives instead of naming a proxy.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from hypa.data import HypaDataModule, Record
from hypa.diagnosis.catalogue import Entry, catalogue_candidates, load_catalogue
from hypa.diagnosis.edits import AFFINE, GRADIENT, Candidate, applied, frozen, set_free
from hypa.evaluation.runs import free_run
from hypa.models import ComposedModel
from hypa.models.spec import ModelSpec, ModelSpecError
from hypa.physics import SchedulingError, UnstablePhysicsError


ALTERNATIVE = 0.95  # a candidate explaining this share of the named one's gain is reported beside it


@dataclass(frozen=True)
class Problem:
    """The data and the fixed settings every candidate model is built with."""

    dm: HypaDataModule
    physical_values: Mapping[str, float]
    hold: str = "foh"
    horizon: int = 100
    steps: int = 60  # gradient steps per candidate fit (half for nonlinear physics, simulated step by step)
    batch: int = 128  # training windows per step
    lr: float = 0.05  # on the raw (relative) parameters: about 5 % of a value per step
    seed: int = 0

    def scale(self, names: Sequence[str]) -> dict[str, tuple[float, float]]:
        norm = self.dm.normalization.subset(list(names))
        return {n: (float(m), float(s)) for n, m, s in zip(names, norm.mean.tolist(), norm.std.tolist())}

    def build(self, spec: ModelSpec) -> ComposedModel:
        dm = self.dm
        return ComposedModel(spec, self.physical_values, dm.input_names, dm.output_names, self.scale(dm.input_names),
                             self.scale(dm.output_names), dm.dt, self.horizon, self.hold,
                             scheduling_names=dm.scheduling_names, scheduling_scale=self.scale(dm.scheduling_names))


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
                "alternatives": self.alternatives, "refined": self.refined, "text": self.describe()}


def format_value(value: float, unit: str) -> str:
    """Rounded to 3 significant digits with its unit (seconds below 1 s as ms)."""
    if unit == "s" and abs(value) < 1.0:
        return f"{value * 1e3:.3g} ms"
    return f"{value:.3g} {'' if unit == '-' else unit}".rstrip()


def _windows(dm: HypaDataModule) -> dict[str, torch.Tensor]:
    """Every training window in one batch (u, y and s when the data has scheduling signals)."""
    dataset = dm.dataset("train")
    loader = torch.utils.data.DataLoader(dataset, batch_size=len(dataset), shuffle=False)
    batch = next(iter(loader))
    return {k: v for k, v in batch.items() if k in ("u", "y", "s")}


def score(model: ComposedModel, dm: HypaDataModule, records: Sequence[Record]) -> float:
    """Mean over outputs of the free-run error energy relative to the output's variance (1 - R²)."""
    err, var = np.zeros(len(dm.output_names)), np.zeros(len(dm.output_names))
    for record in records:
        run = free_run(model, dm, record)
        for i, name in enumerate(dm.output_names):
            y, p = run.measured[name][run.first:], run.predicted[name][run.first:]
            err[i] += float(np.sum((p - y) ** 2))
            var[i] += float(np.sum((y - np.mean(y)) ** 2))
    out = err / np.maximum(var, 1e-300)
    return float(np.mean(out)) if np.all(np.isfinite(out)) else math.inf


def fit_gradient(candidate: Candidate, problem: Problem, windows: Mapping[str, torch.Tensor],
                 refine: Sequence[str] = ()) -> dict[str, float]:
    """Fit the candidate's physical knobs on the training windows (the training loss, Adam),
    together with ``refine``, the knobs of the causes named before it (the causes are fitted
    jointly: a rear-steering ratio fitted on linear tires moves once saturation joins it)."""
    model = problem.build(set_free(candidate.spec, refine) if refine else candidate.spec)
    refine = [k for k in refine if k in model.parameters_.names]
    params = [p for p in model.parameters() if p.requires_grad]
    if not params:
        raise ModelSpecError(f"{candidate.key}: nothing to fit")
    optimizer = torch.optim.Adam(params, lr=problem.lr)
    generator = torch.Generator().manual_seed(problem.seed)
    first, count = problem.dm.past + 1, windows["u"].shape[0]
    nonlinear = any(getattr(getattr(b, "model", None), "is_nonlinear", False) for b in model.blocks.values())
    for _ in range(problem.steps // 2 if nonlinear else problem.steps):
        index = torch.randperm(count, generator=generator)[: problem.batch]
        u, y = windows["u"][index], windows["y"][index]
        s = windows["s"][index] if "s" in windows else None
        loss = torch.mean((model(u, y[:, :first], s) - y[:, first:]) ** 2)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    return {k: float(model.parameters_.value(k).detach()) for k in (*candidate.knobs, *refine)}


def fit_affine(candidate: Candidate, problem: Problem) -> dict[str, float]:
    """Least squares of one offset b: the (linear) model's outputs are affine in it, so two free
    runs over the training records (b = 0 and a probe) give the response to b exactly."""
    channel, dm = candidate.target, problem.dm
    probe = 0.1 * problem.scale([channel])[channel][1]
    base = candidate.spec

    def runs(offset: float) -> list:
        spec = applied(candidate, {channel: offset}) if offset else base
        model = problem.build(spec)
        return [free_run(model, dm, r) for r in dm.records("train")]

    zero, moved = runs(0.0), runs(probe)
    num = den = 0.0
    for a, b in zip(zero, moved):
        for name in dm.output_names:
            y = a.measured[name][a.first:]
            weight = 1.0 / max(float(np.var(y)), 1e-300)
            g = (b.predicted[name][a.first:] - a.predicted[name][a.first:]) / probe
            r = y - a.predicted[name][a.first:]
            num += weight * float(np.dot(g, r))
            den += weight * float(np.dot(g, g))
    return {channel: num / den if den > 0 else 0.0}


def evaluate(candidate: Candidate, problem: Problem, windows: Mapping[str, torch.Tensor], base_score: float,
             refine: Sequence[str] = ()) -> Finding:
    """Fit a candidate (with ``refine``, see :func:`fit_gradient`) and score it free-running on
    the validation records. ``values`` holds the candidate's own knobs, ``refined`` the others."""
    started = time.perf_counter()
    units = dict(candidate.units) or {candidate.target: problem.dm.channels[candidate.target].unit
                                      if candidate.fit == AFFINE else ""}
    try:
        if candidate.fit == GRADIENT:
            values = fit_gradient(candidate, problem, windows, refine)
        elif candidate.fit == AFFINE:
            values = fit_affine(candidate, problem)
        else:
            values = {}
        spec = applied(candidate, values)
        value = score(problem.build(spec), problem.dm, problem.dm.records("val"))
    except (UnstablePhysicsError, SchedulingError, ModelSpecError, ValueError) as error:
        return Finding(candidate.cause, candidate.target, {}, {}, math.inf, -math.inf,
                       time.perf_counter() - started, str(error).split("\n")[0], candidate)
    gain = 1.0 - value / base_score if base_score > 0 else 0.0
    note = _scheduling_note(candidate, problem) if candidate.cause == "scheduling" else ""
    own = {k: v for k, v in values.items() if k in candidate.knobs or candidate.fit == AFFINE}
    refined = {k: v for k, v in values.items() if k not in own}
    return Finding(candidate.cause, candidate.target, own, units, value, gain, time.perf_counter() - started,
                   None, candidate, note=note, refined=refined)


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


def name_causes(nominal: ModelSpec, problem: Problem, catalogue: Sequence[Entry] | None = None,
                candidates: Callable[[ModelSpec], list[Candidate]] | None = None, max_causes: int = 5,
                min_gain: float = 0.15, floor: float = 1e-4, progress: Callable[[str], None] = lambda _: None) -> Search:
    """Greedy forward search over the catalogue from the frozen ``nominal`` model.

    ``catalogue``: the entries (default: the built-in catalogues, :func:`load_catalogue`);
    ``candidates(spec)``, if given, lists the candidates of a base model instead. Each round fits all of them, names the best if it lowers the validation
    error (1 - R², mean over outputs) by at least ``min_gain`` (relative), applies it and goes on;
    below ``floor`` (share of the output variance: sensor noise) there is nothing left to name.
    """
    started = time.perf_counter()
    dm = problem.dm
    uncertain = {b.name: b.trainable for b in nominal.blocks}
    entries = load_catalogue() if catalogue is None else list(catalogue)
    if candidates is None:
        def candidates(spec: ModelSpec) -> list[Candidate]:
            return catalogue_candidates(entries, spec, dm.input_names, dm.output_names, dm.scheduling_names,
                                        problem.physical_values, dm.dt, uncertain)
    torch.manual_seed(problem.seed)
    windows = _windows(dm)
    base = frozen(nominal)
    base_score = nominal_score = score(problem.build(base), dm, dm.records("val"))
    progress(f"nominal model: validation error {100 * base_score:.3g} % of the output variance")
    rounds, named, refine = [], [], []
    while len(named) < max_causes and base_score > floor:
        done = {f.key for f in named}
        findings = [evaluate(c, problem, windows, base_score, refine) for c in candidates(base) if c.key not in done]
        findings.sort(key=lambda f: f.score)
        rounds.append(findings)
        if not findings or findings[0].gain < min_gain:
            break
        best = findings[0]
        best.alternatives = [f.describe() for f in findings[1:] if f.gain >= ALTERNATIVE * best.gain]
        named.append(best)
        base, base_score = applied(best.candidate, {**best.refined, **best.values}), best.score
        refine += [k for k in best.candidate.knobs if best.candidate.fit == GRADIENT and k not in refine]
        progress(f"named {best.describe()} (validation error {100 * best.gain:.0f} % lower)"
                 + (f"; the data cannot tell it from {' or '.join(best.alternatives)}" if best.alternatives else ""))
    for k, f in enumerate(named):  # the final values: re-fitted jointly with every later cause
        for later in named[k + 1 :]:
            f.values.update({name: v for name, v in later.refined.items() if name in f.values})
    return Search(nominal_score, rounds, named, base, base_score, time.perf_counter() - started)
