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

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import nullcontext
from functools import partial
from dataclasses import dataclass, field

import numpy as np
import torch

from hypa.data import HypaDataModule, Record
from hypa.diagnosis.catalogue import Entry, catalogue_candidates, load_catalogue
from hypa.diagnosis.edits import AFFINE, GRADIENT, Candidate, applied, frozen, set_free
from hypa.diagnosis.workers import Workers, can_fork, default_workers
from hypa.models import ComposedModel
from hypa.models.spec import ModelSpec, ModelSpecError
from hypa.physics import SchedulingError, UnstablePhysicsError


REFINE_LR = 0.2  # the learning rate of the earlier causes' knobs, relative to the candidate's own
ALTERNATIVE = 0.95  # a candidate explaining this share of the named one's gain is reported beside it
LM_ITERATIONS = 8  # Levenberg-Marquardt steps of a nonlinear fit (the knobs are few: 1 to 7)
LM_WINDOWS_PER_BATCH = 2  # its fixed windows: this many batches' worth (256 by default)
LM_PROBE = 1e-5  # the finite-difference step on a raw knob (a relative 1e-5 for positive parameters)
LM_DAMPING = 1e-2  # the starting damping (relative to the normal matrix's diagonal)
OFFSET_Z = 5.0  # an offset below min_gain is still named this many standard errors away from zero ...
OFFSET_GAIN = 0.01  # ... when it lowers the validation error by at least this share (a small sensor bias)


@dataclass(frozen=True)
class Problem:
    """The data and the fixed settings every candidate model is built with."""

    dm: HypaDataModule
    physical_values: Mapping[str, float]
    hold: str = "foh"
    horizon: int = 100
    steps: int = 60  # Adam steps per linear candidate fit (nonlinear physics: LM_ITERATIONS Levenberg-Marquardt steps)
    batch: int = 128  # training windows per step
    lr: float = 0.05  # on the raw (relative) parameters: about 5 % of a value per step
    seed: int = 0
    stretch_s: float = 20.0  # [s] the free runs that score a candidate restart from the data this often
    workers: int = field(default_factory=default_workers)  # processes fitting a round's candidates at once

    def stretches(self, split: str) -> Stretches:
        """The ``split``'s records cut into stretches of ``stretch_s`` (made once, then cached)."""
        cache = self.__dict__.setdefault("_stretches", {})
        if split not in cache:
            cache[split] = Stretches.cut(self.dm, self.dm.records(split), max(1, round(self.stretch_s / self.dm.dt)))
        return cache[split]

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
    steps: tuple[int, int] | None = None  # gradient fits: (steps done, of); fewer: stopped early, behind others
    z: float | None = None  # offsets: |estimate| / its standard error (clustered by training stretch)
    small: bool = False  # named below min_gain: an offset far from zero by its standard error

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
                "text": self.describe()}


READABLE = {"rad": ("deg", 180.0 / math.pi), "rad/s": ("deg/s", 180.0 / math.pi)}  # SI unit -> (shown, factor)


def format_value(value: float, unit: str) -> str:
    """Rounded to 3 significant digits with its unit (seconds below 1 s as ms, angles in degrees)."""
    if unit == "s" and abs(value) < 1.0:
        return f"{value * 1e3:.3g} ms"
    unit, factor = READABLE.get(unit, (unit, 1.0))
    return f"{value * factor:.3g} {'' if unit == '-' else unit}".rstrip()


def _windows(dm: HypaDataModule) -> dict[str, torch.Tensor]:
    """Every training window in one batch (u, y and s when the data has scheduling signals)."""
    dataset = dm.dataset("train")
    loader = torch.utils.data.DataLoader(dataset, batch_size=len(dataset), shuffle=False)
    batch = next(iter(loader))
    return {k: v for k, v in batch.items() if k in ("u", "y", "s")}


@dataclass(frozen=True)
class Stretches:
    """Records cut into long windows (stretches) that tile them, batched by length: what the
    search simulates to score a candidate (validation) and to fit an offset (training).

    Each stretch starts like a training window, from its first ``first`` samples (the measured
    state, or the estimate of an unmeasured one from the past), and predicts the next
    ``samples``; consecutive stretches predict consecutive samples, the last one of a record
    ends at its end. A batch is ``{"u", "y", "s"}``: normalized inputs and outputs, SI scheduling.
    """

    batches: tuple[dict[str, torch.Tensor], ...]
    first: int

    @classmethod
    def cut(cls, dm: HypaDataModule, records: Sequence[Record], samples: int) -> Stretches:
        first, groups = dm.past + 1, {}
        norm = dm.normalization
        for record in records:
            length = min(len(record), first + samples)
            if length <= first:
                continue
            starts = list(range(0, len(record) - length + 1, samples))
            if starts[-1] != len(record) - length:
                starts.append(len(record) - length)
            arrays = {"u": norm.normalize(record.stack(dm.input_names), dm.input_names),
                      "y": norm.normalize(record.stack(dm.output_names), dm.output_names),
                      "s": record.stack(dm.scheduling_names)}
            for start in starts:
                groups.setdefault(length, []).append({k: a[start : start + length] for k, a in arrays.items()})
        batches = tuple({k: torch.as_tensor(np.stack([w[k] for w in group]), dtype=torch.float32) for k in group[0]}
                        for group in groups.values())
        return cls(batches, first)

    @torch.no_grad()
    def predict(self, model: ComposedModel) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """(predicted, measured) normalized outputs (B, L - first, p) per batch, float64."""
        out = []
        for b in self.batches:
            s = b["s"] if b["s"].shape[-1] else None
            pred = model(b["u"], b["y"][:, : self.first], s)
            out.append((pred.double(), b["y"][:, self.first :].double()))
        return out

    def weights(self) -> torch.Tensor:
        """1 / the variance of each (normalized) output over the predicted samples."""
        y = torch.cat([b["y"][:, self.first :].reshape(-1, b["y"].shape[-1]) for b in self.batches]).double()
        return 1.0 / torch.clamp(y.var(0, unbiased=False), min=1e-300)

    def score(self, model: ComposedModel) -> float:
        """Mean over outputs of the error energy relative to the output's variance (1 - R²)."""
        pairs = self.predict(model)
        count = sum(p.shape[0] * p.shape[1] for p, _ in pairs)
        mse = sum(((p - y) ** 2).sum((0, 1)) for p, y in pairs) / count
        out = (mse * self.weights()).numpy()
        return float(np.mean(out)) if np.all(np.isfinite(out)) else math.inf


class GradientFit:
    """A candidate's physical knobs being fitted on the training windows (the training loss),
    together with ``refine``, the knobs of the causes named before it (the causes are fitted
    jointly: a rear-steering ratio fitted on linear tires moves once saturation joins it).
    Resumable: the search advances only the promising fits to their full number of steps.

    Linear physics (the lifted form, one graph node per window) takes ``problem.steps`` Adam
    steps on random batches. Nonlinear physics is simulated step by step, and there the
    backward pass through the step loop costs about eight times the forward run: such a fit
    takes ``LM_ITERATIONS`` Levenberg-Marquardt steps on a fixed set of windows instead, its
    Jacobian from finite differences of forward runs (one per knob, no autograd; a few knobs)."""

    def __init__(self, candidate: Candidate, problem: Problem, windows: Mapping[str, torch.Tensor],
                 refine: Sequence[str] = ()) -> None:
        self.candidate, self.problem, self.windows = candidate, problem, windows
        self.model = problem.build(set_free(candidate.spec, refine) if refine else candidate.spec)
        self.refine = [k for k in refine if k in self.model.parameters_.names]
        params = [p for p in self.model.parameters() if p.requires_grad]
        if not params:
            raise ModelSpecError(f"{candidate.key}: nothing to fit")
        # the earlier causes' knobs start at their optimum: slower steps, so that Adam's first
        # steps (about lr each, whatever the gradient) do not throw them off it
        settled = {id(self.model.parameters_.raw[k]) for k in self.refine}
        groups = [{"params": [p for p in params if id(p) not in settled], "lr": problem.lr},
                  {"params": [p for p in params if id(p) in settled], "lr": REFINE_LR * problem.lr}]
        self.optimizer = torch.optim.Adam([g for g in groups if g["params"]])
        self.generator = torch.Generator().manual_seed(problem.seed)
        self.nonlinear = nonlinear = any(getattr(getattr(b, "model", None), "is_nonlinear", False)
                                         for b in self.model.blocks.values())
        self.total, self.done = LM_ITERATIONS if nonlinear else problem.steps, 0
        self.batch, self.damping = problem.batch, LM_DAMPING
        if nonlinear:  # Levenberg-Marquardt: a fixed set of windows, in double precision (finite differences)
            count = windows["u"].shape[0]
            index = torch.randperm(count, generator=self.generator)[: LM_WINDOWS_PER_BATCH * problem.batch]
            self.fixed = {k: v[index].double() for k, v in windows.items()}
            self.knobs = params

    def advance(self, share: float) -> None:
        """Go on until ``share`` of the total steps are done."""
        first, count, w = self.problem.dm.past + 1, self.windows["u"].shape[0], self.windows
        while self.done < math.ceil(share * self.total):
            if self.nonlinear:
                self._least_squares_step()
            else:
                index = torch.randperm(count, generator=self.generator)[: self.batch]
                u, y = w["u"][index], w["y"][index]
                loss = torch.mean((self.model(u, y[:, :first], w["s"][index] if "s" in w else None)
                                   - y[:, first:]) ** 2)
                self.optimizer.zero_grad()
                loss.backward()
                self.optimizer.step()
            self.done += 1

    @torch.no_grad()
    def _residual(self) -> torch.Tensor:
        w, first = self.fixed, self.problem.dm.past + 1
        return (self.model(w["u"], w["y"][:, :first], w.get("s")) - w["y"][:, first:]).reshape(-1)

    @torch.no_grad()
    def _least_squares_step(self) -> None:
        """One Levenberg-Marquardt step on the raw knobs (relative for positive parameters, so one
        finite-difference step fits all); the damping grows until the step lowers the error."""
        r0 = self._residual()
        cost = float(r0 @ r0)
        if not math.isfinite(cost):
            raise ValueError("the model's error is not finite at the start of a step")
        columns = []
        for knob in self.knobs:
            knob += LM_PROBE
            columns.append((self._residual() - r0) / LM_PROBE)
            knob -= LM_PROBE
        jacobian = torch.stack(columns, 1)
        normal, gradient = jacobian.T @ jacobian, jacobian.T @ r0
        while self.damping < 1e6:
            step = torch.linalg.solve(normal + self.damping * torch.diag(torch.diagonal(normal) + 1e-12), -gradient)
            for knob, delta in zip(self.knobs, step):
                knob += delta
            trial = self._residual()
            if bool(torch.isfinite(trial).all()) and float(trial @ trial) < cost:
                self.damping = max(self.damping / 3.0, 1e-6)
                return
            for knob, delta in zip(self.knobs, step):
                knob -= delta
            self.damping *= 4.0

    def values(self) -> dict[str, float]:
        return {k: float(self.model.parameters_.value(k).detach()) for k in (*self.candidate.knobs, *self.refine)}


def fit_gradient(candidate: Candidate, problem: Problem, windows: Mapping[str, torch.Tensor],
                 refine: Sequence[str] = ()) -> dict[str, float]:
    """The candidate's knobs (and ``refine``) fitted to the full number of steps (:class:`GradientFit`)."""
    fit = GradientFit(candidate, problem, windows, refine)
    fit.advance(1.0)
    return fit.values()


def fit_affine(candidate: Candidate, problem: Problem) -> tuple[dict[str, float], float]:
    """One offset (the candidate's channel): its least-squares value and |value| / standard error."""
    channel = candidate.target
    values, z = fit_offsets(candidate.spec, [channel], problem)
    span = max(float(np.ptp(r[channel])) for r in problem.dm.records("train"))
    if not abs(values[channel]) <= span:  # e.g. a position offset the initial-state estimate absorbs
        unit = problem.dm.channels[channel].unit
        raise ValueError(f"offset {format_value(values[channel], unit)} beyond the channel's whole range "
                         f"({format_value(span, unit)}): not identifiable from these data")
    return values, z[channel]


def fit_offsets(spec: ModelSpec, channels: Sequence[str], problem: Problem) -> tuple[dict[str, float],
                                                                                      dict[str, float]]:
    """Joint least squares of the sensor offsets of ``channels`` in ``spec`` (whatever values the
    spec holds for them are replaced). The (linear) model's outputs are affine in each offset, so
    one simulation of the training stretches with them at zero and one per offset (a probe) give
    the responses exactly. Returns the offsets [SI] and each one's |value| over its standard
    error, clustered by stretch (the residuals of one stretch are correlated, those of different
    stretches far less; the sandwich covariance of the weighted least squares)."""
    zeroed = {**spec.sensor_offsets, **{c: 0.0 for c in channels}}
    train = problem.stretches("train")
    base = train.predict(problem.build(dataclasses.replace(spec, sensor_offsets=zeroed)))
    responses = []
    for channel in channels:
        probe = 0.1 * problem.scale([channel])[channel][1]
        moved = train.predict(problem.build(dataclasses.replace(spec, sensor_offsets={**zeroed, channel: probe})))
        responses.append([(p1 - p0) / probe for (p1, _), (p0, _) in zip(moved, base)])
    weights, k = train.weights(), len(channels)
    batches = [(torch.stack([resp[b] for resp in responses], -1), y - p0) for b, (p0, y) in enumerate(base)]
    gram = sum(torch.einsum("blpi,blpj,p->ij", g, g, weights) for g, _ in batches)  # g: (B, L, p, k)
    rhs = sum(torch.einsum("blpi,blp,p->i", g, r, weights) for g, r in batches)
    if torch.linalg.matrix_rank(gram) < k:
        raise ValueError(f"offsets of {', '.join(channels)} cannot be told apart on these data")
    offsets = torch.linalg.solve(gram, rhs)
    scores = torch.cat([torch.einsum("blpi,blp,p->bi", g, r - torch.einsum("blpi,i->blp", g, offsets), weights)
                        for g, r in batches])  # (stretches, k): each stretch's share of the normal equations
    inverse = torch.linalg.inv(gram)
    spread = torch.sqrt(torch.clamp(torch.diagonal(inverse @ (scores.T @ scores) @ inverse), min=0.0))
    values = {c: float(v) for c, v in zip(channels, offsets)}
    return values, {c: abs(values[c]) / float(e) if float(e) > 0 else math.inf for c, e in zip(channels, spread)}


_FIT_ERRORS = (UnstablePhysicsError, SchedulingError, ModelSpecError, ValueError)


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
    return finding


def _failed(candidate: Candidate, error: Exception, seconds: float) -> Finding:
    return Finding(candidate.cause, candidate.target, {}, {}, math.inf, -math.inf, seconds,
                   str(error).split("\n")[0], candidate)


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
                   base_score: float, refine: Sequence[str] = ()) -> list[Finding]:
    """Every candidate of a round fitted and scored (best first).

    Fits of nonlinear physics (simulated step by step, the expensive ones) race by successive
    halving: all run a quarter of their steps and are scored on the validation stretches, the
    better half (at least 3) goes on to half the steps, the better half of those (at least 2) to
    the end, unless still worse than the base model and no better than at the quarter. Linear
    fits always run to the end: early in a fit (Adam's first steps are about the learning rate
    whatever the gradient) a resonant system's error is no guide. A fit stopped early says so
    (``Finding.steps``); its gain is a lower bound.
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
        for k, share in enumerate(RUNGS):
            # linear fits (the lifted form: cheap) run to the end at once
            shares = {i: share if r.fit.nonlinear else 1.0 for i, r in enumerate(runners) if r in alive}
            # the offsets and structural candidates: in this process, while the workers fit
            jobs = [partial(_append, findings, evaluate, c, problem, windows, base_score, refine)
                    for c in (others if k == 0 else ())]
            if workers is not None:
                workers.run(shares, jobs)
            else:
                for i, s in shares.items():
                    runners[i].advance(s, val)
                for job in jobs:
                    job()
            alive = _next_rung(alive, k, base_score)
            if not alive:
                break
    for runner in runners:
        if runner.error is not None:
            findings.append(_failed(runner.fit.candidate, runner.error, runner.seconds))
            continue
        values = runner.values if runner.values is not None else runner.fit.values()
        finding = _finding(runner.fit.candidate, problem, values, runner.score, base_score, runner.seconds)
        finding.steps = (runner.fit.done, runner.fit.total)
        findings.append(finding)
    return sorted(findings, key=lambda f: f.score)


def _append(findings: list[Finding], evaluate_one: Callable[..., Finding], *args) -> None:
    findings.append(evaluate_one(*args))


def _next_rung(alive: list[_Runner], k: int, base_score: float) -> list[_Runner]:
    """The runners that go on after rung ``k`` (successive halving, see :func:`evaluate_round`)."""
    alive = [r for r in alive if r.error is None and r.fit.done < r.fit.total]
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


def name_causes(nominal: ModelSpec, problem: Problem, catalogue: Sequence[Entry] | None = None,
                candidates: Callable[[ModelSpec], list[Candidate]] | None = None, max_causes: int = 8,
                min_gain: float = 0.15, floor: float = 1e-4, progress: Callable[[str], None] = lambda _: None) -> Search:
    """Greedy forward search over the catalogue from the frozen ``nominal`` model.

    ``catalogue``: the entries (default: the built-in catalogues, :func:`load_catalogue`);
    ``candidates(spec)``, if given, lists the candidates of a base model instead. Each round fits all of them, names the best if it lowers the validation
    error (1 - R², mean over outputs) by at least ``min_gain`` (relative), applies it and goes on;
    below ``floor`` (share of the output variance: sensor noise) there is nothing left to name.
    """
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
    windows = _windows(dm)
    base = frozen(nominal)
    base_score = nominal_score = problem.stretches("val").score(problem.build(base))
    progress(f"nominal model: validation error {100 * base_score:.3g} % of the output variance")
    rounds, named, refine, findings = [], [], [], []
    while len(named) < max_causes and base_score > floor:
        done = {f.key for f in named}
        findings = evaluate_round([c for c in candidates(base) if c.key not in done], problem, windows, base_score,
                                  refine)
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
        findings = []
    # below min_gain: offsets (one number each, exact least squares) that sit far from zero by their
    # standard error, a small sensor bias, one at a time (the best first, the others fitted again on top)
    findings = [f for f in findings if _significant(f)]
    while findings and len(named) < max_causes:
        best = findings[0]
        best.small = True
        best.alternatives = [f.describe() for f in findings[1:] if f.gain >= ALTERNATIVE * best.gain]
        named.append(best)
        base, base_score = applied(best.candidate, best.values), best.score
        progress(f"named {best.describe()} (validation error {100 * best.gain:.2g} % lower: small, but "
                 f"{best.z:.0f} standard errors from zero)")
        keys = {f.key for f in findings[1:]}
        findings = sorted((evaluate(c, problem, windows, base_score) for c in candidates(base) if c.key in keys),
                          key=lambda f: f.score)
        if findings:
            rounds.append(findings)
        findings = [f for f in findings if _significant(f)]
    named, dropped, base, base_score = _joint_offsets(named, base, base_score, problem, progress)
    for k, f in enumerate(named):  # the final values: re-fitted jointly with every later cause
        for later in named[k + 1 :]:
            f.values.update({name: v for name, v in later.refined.items() if name in f.values})
    return Search(nominal_score, rounds, named, base, base_score, time.perf_counter() - started, dropped)


def _joint_offsets(named: list[Finding], spec: ModelSpec, score: float, problem: Problem,
                   progress: Callable[[str], None]) -> tuple[list[Finding], list[Finding], ModelSpec, float]:
    """The named offsets fitted again all together; while one of them is then under OFFSET_Z
    standard errors from zero (it stood in for the others: a steering offset for a yaw-rate and a
    side-slip bias), the weakest is dropped; an offset as weak in that fit lists it as the
    alternative the data cannot tell it from. Returns the named causes, the dropped ones, the model
    with the final offsets and its validation score."""
    offsets = [f for f in named if f.candidate is not None and f.candidate.fit == AFFINE]
    dropped: list[Finding] = []
    if len(offsets) < 2:
        return named, dropped, spec, score
    while True:
        values, z = fit_offsets(spec, [f.target for f in offsets], problem)
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
        spec = dataclasses.replace(spec, sensor_offsets={k: v for k, v in spec.sensor_offsets.items()
                                                         if k != weakest.target})
        weakest.note = (f"dropped: fitted together with the other offsets it is {z[weakest.target]:.1f} "
                        "standard errors from zero (they carry what it explained)")
        progress(f"{weakest.cause} on {weakest.target}: {weakest.note}")
    if not dropped:
        return named, dropped, spec, score
    for f in offsets:
        f.values, f.z = {f.target: values[f.target]}, z[f.target]
    spec = dataclasses.replace(spec, sensor_offsets={**spec.sensor_offsets, **values})
    return ([f for f in named if all(f is not d for d in dropped)], dropped, spec,
            problem.stretches("val").score(problem.build(spec)))


def _significant(f: Finding) -> bool:
    """An offset fitted, far from zero by its standard error, and lowering the validation error."""
    return f.error is None and f.z is not None and f.z >= OFFSET_Z and f.gain >= OFFSET_GAIN
