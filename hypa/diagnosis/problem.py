"""The diagnosis' data and fixed settings (:class:`Problem`), the long windows (stretches)
that score a candidate on held-out records and fit an offset on the others, the
cross-validation folds over blocks of all records (:meth:`Problem.folds`: what is held out and
what is fitted in each), and what the data can support (:class:`Evidence`).

**How much data a fit needs** (the rule comes from the data and the model, no length is
assumed). The errors of one free run are correlated: they all follow from its start and the
same few parameters, so at worst a run is one piece of evidence, not ``N`` samples. Counted so:

- a gradient fit of ``k`` numbers (the candidate's knobs and the earlier causes' knobs re-fitted
  with it) needs more than ``k`` training windows without overlap (``data.past + data.window + 1``
  samples each, counted per record): with ``k`` or fewer, ``k`` knobs can match every window's
  error whatever its cause, so the candidate is not fitted and the report says why;
- the standard error of ``k`` offsets fitted together needs more than ``k`` training stretches
  (the clusters of the sandwich estimator): the stretches' shares of the normal equations sum to
  zero at the least-squares optimum, so ``G`` stretches judge at most ``G - 1`` directions; with
  ``G <= k`` no standard error is reported (one stretch gives one of exactly zero: "10^15
  standard errors from zero") and no offset is named as significant on it.

Data with fewer than two windows without overlap cannot support a fit of even one number:
:meth:`Problem.require_data` refuses them in one line, with the length that would do.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import torch

from hypa.core.errors import UserError
from hypa.data import HypaDataModule, Record
from hypa.diagnosis.scales import FOLDS, Scales, block_bounds  # FOLDS: each candidate is fitted once per fold
from hypa.diagnosis.workers import default_workers
from hypa.identification.stretches import Stretches
from hypa.models import ComposedModel
from hypa.models.building import model_hold
from hypa.models.spec import ModelSpec

NOMINAL_HOLD = "foh"  # the diagnosis' hold for a model that fixes none: with zoh a real dead time comes out dt/2 short


def nominal_hold(spec: ModelSpec, hold: str | None) -> str:
    """The hold the diagnosis builds ``spec`` with: ``hold`` (``physics.hold``) where given, else the
    model's own, else :data:`NOMINAL_HOLD`; a given one that contradicts the model's is a ``ModelSpecError``."""
    return model_hold(spec, hold if hold is not None or spec.hold else NOMINAL_HOLD, "physics.hold")


@dataclass(frozen=True)
class Problem:
    """The data and the fixed settings every candidate model is built with.

    ``physical_values``: nominal physical parameters [SI] (``None``: the systems' own);
    ``hold``: ``zoh`` | ``foh`` for a model whose spec fixes none (``None``: the spec's, else
    ``zoh``; give ``foh`` for smooth inputs: with ``zoh`` a real dead time comes out dt/2 short;
    a different one than the spec's is a ``ModelSpecError``); ``horizon``: lifted steps N per
    matrix product (``None``: the data module's window).
    """

    dm: HypaDataModule
    physical_values: Mapping[str, float] | None = None
    hold: str | None = None
    horizon: int | None = None
    batch: int = 128  # a fit's fixed training windows: twice this (hypa.diagnosis.fitting.LM_WINDOWS_PER_BATCH)
    seed: int = 0
    fit_seconds: float | None = None  # [s] a user's cap per candidate fit (says so where it stops one); None: none
    stretch_s: float | None = None  # [s] the scoring free runs' length; None: from the model's scales
    workers: int = field(default_factory=default_workers)  # processes fitting a round's candidates at once
    scales: Scales | None = None  # the time scales (:meth:`scaled`: from the nominal model and the data)
    fold: int | None = None  # cross-validation (:meth:`folds`): these blocks are held out, the others fitted

    def __post_init__(self) -> None:
        object.__setattr__(self, "physical_values", dict(self.physical_values or {}))
        if self.horizon is None:
            object.__setattr__(self, "horizon", self.dm.window)

    def scaled(self, nominal: ModelSpec) -> Problem:
        """This problem with its time scales read from the (frozen) ``nominal`` model and the data
        (:class:`~hypa.diagnosis.scales.Scales`); itself when they are set already."""
        if self.scales is not None:
            return self
        dm, model = self.dm, self.build(nominal)
        train = [len(r) for r in dm.records("train")]
        scales = Scales.of(model.eigenvalues().tolist(), dm.dt, [*train, *(len(r) for r in dm.records("val"))],
                           train, dm.window)
        if self.stretch_s is not None:
            scales = dataclasses.replace(scales, stretch=max(1, round(self.stretch_s / dm.dt)))
        return dataclasses.replace(self, scales=scales)

    @property
    def time_scales(self) -> Scales:
        if self.scales is None:
            raise RuntimeError("the problem's time scales are not set: use problem.scaled(nominal_spec)")
        return self.scales

    def records(self, split: str) -> list[Record]:
        """The records a split means here: the data module's, or in a fold (:meth:`folds`) its
        held-out blocks (``"val"``) and the blocks it is fitted on (``"train"``)."""
        if self.fold is None:
            return self.dm.records(split)
        return [b for i, b in enumerate(self.blocks()) if (i % FOLDS == self.fold) == (split == "val")]

    def blocks(self) -> list[Record]:
        """Every record, training and validation, cut into blocks of one scoring stretch each (a
        remainder shorter than half a stretch joins the block before it), in record order."""
        cache = self.__dict__
        if "_blocks" not in cache:
            first, stretch = self.dm.past + 1, self.time_scales.stretch
            size, blocks = first + stretch, []
            for record in [*self.dm.records("train"), *self.dm.records("val")]:
                blocks += [record.piece(a, b) for a, b in block_bounds(len(record), size) if b - a > first]
            cache["_blocks"] = blocks
        return cache["_blocks"]

    def folds(self) -> list[Problem]:
        """The cross-validation folds (made once): fold ``k`` holds out every ``FOLDS``-th block
        from the ``k``-th on and is fitted on the others, so each candidate is judged on every
        record (training and validation) by a fit that never saw the block it is scored on, and
        the folds' scores add up to the error over all blocks. ``[self]`` (the data module's
        train/validation split) when there are fewer blocks than folds."""
        cache = self.__dict__
        if "_folds" not in cache:
            count = len(self.blocks()) if self.fold is None else 0
            cache["_folds"] = [self._fold(k) for k in range(FOLDS)] if count >= FOLDS else [self]
        return cache["_folds"]

    def _fold(self, k: int) -> Problem:
        """Fold ``k``, sharing this problem's blocks and their stretches (cut once for all folds)."""
        fold = dataclasses.replace(self, fold=k)
        fold.__dict__.update(_blocks=self.blocks(), _all_stretches=self._whole())
        return fold

    @property
    def held_out(self) -> float:
        """This problem's share of the samples scored over its folds (1 outside cross-validation)."""
        return 1.0 if self.fold is None else self.stretches("val").samples / self._whole().samples

    def _whole(self) -> Stretches:
        cache = self.__dict__
        if "_all_stretches" not in cache:
            cache["_all_stretches"] = Stretches.cut(self.dm, self.blocks(), self.time_scales.stretch)
        return cache["_all_stretches"]

    def stretches(self, split: str) -> Stretches:
        """The ``split``'s records cut into scoring stretches (made once, then cached). A fold's
        held-out stretches weigh each output by its variance over all blocks, so the folds'
        scores, weighted by :attr:`held_out`, are the score over all blocks."""
        cache = self.__dict__.setdefault("_stretches", {})
        if split not in cache:
            cut = Stretches.cut(self.dm, self.records(split), self.time_scales.stretch)
            if self.fold is not None and split == "val":
                cut = dataclasses.replace(cut, scale=self._whole().weights())
            cache[split] = cut
        return cache[split]

    @property
    def fit_window(self) -> int:
        """[samples] predicted by a fit window here: the scales' (:attr:`Scales.fit_window`), at most
        what the longest of this problem's training records holds after ``data.past`` (a fold's
        training blocks are one scoring stretch each, which a user's ``data.window`` may exceed)."""
        longest = max((len(r) for r in self.records("train")), default=0)
        return max(1, min(self.time_scales.fit_window, longest - self.dm.past - 1))

    def windows(self) -> dict[str, torch.Tensor]:
        """The training windows the gradient fits draw from (made once, then cached): the data
        module's own where the scales' fit window is ``data.window``, else the training records
        cut into windows of that length overlapping as much as ``data.stride`` makes the data
        module's."""
        cache = self.__dict__
        if "_windows" not in cache:
            dm, length = self.dm, self.fit_window
            if length == dm.window and self.fold is None:
                cache["_windows"] = training_windows(dm)
            else:
                stride = max(1, round(length * dm.stride / dm.window))
                cache["_windows"] = _cut_windows(dm, self.records("train"), dm.past + 1 + length, stride)
        return cache["_windows"]

    def evidence(self) -> Evidence:
        """How much independent evidence the training records hold (made once, then cached)."""
        cache = self.__dict__
        if "_evidence" not in cache:
            dm = self.dm
            span = dm.past + self.fit_window + 1
            records = self.records("train")
            cache["_evidence"] = Evidence(
                seconds=sum(len(r) for r in records) * dm.dt, records=len(records),
                windows=sum(len(r) // span for r in records), window_samples=span, dt=dm.dt,
                stretches=self.stretches("train").count, stretch_s=self.time_scales.stretch_s,
                fold=self.fold is not None)
        return cache["_evidence"]

    def require_data(self) -> None:
        """Refuse (:class:`TooShortError`) data that cannot support a fit of even one number."""
        reason = self.evidence().refusal()
        if reason:
            raise TooShortError(reason)

    def scale(self, names: Sequence[str]) -> dict[str, tuple[float, float]]:
        norm = self.dm.normalization.subset(list(names))
        return {n: (float(m), float(s)) for n, m, s in zip(names, norm.mean.tolist(), norm.std.tolist())}

    def build(self, spec: ModelSpec) -> ComposedModel:
        dm = self.dm
        return ComposedModel(spec, self.physical_values, dm.input_names, dm.output_names, self.scale(dm.input_names),
                             self.scale(dm.output_names), dm.dt, self.horizon, self.hold,
                             scheduling_names=dm.scheduling_names, scheduling_scale=self.scale(dm.scheduling_names))


class TooShortError(UserError):
    """The training records cannot support a fit of even one number (:meth:`Evidence.refusal`)."""


class TooLittleData(ValueError):
    """A candidate's fit needs more independent training windows than the data hold: not fitted."""


def _plural(count: int, word: str, plural: str | None = None) -> str:
    return f"{count} {word if count == 1 else plural or word + 's'}"


@dataclass(frozen=True)
class Evidence:
    """The training data counted as independent pieces (see the module docstring): ``windows``
    without overlap (``window_samples`` each), ``stretches`` (the offsets' clusters)."""

    seconds: float  # [s] of training data
    records: int
    windows: int
    window_samples: int
    dt: float  # [s]
    stretches: int
    stretch_s: float  # [s]
    fold: bool = False  # the training blocks of one cross-validation fold, not the whole training data

    def fit_shortfall(self, k: int) -> str | None:
        """Why a fit of ``k`` numbers is not supported (``None``: it is)."""
        if self.windows > k:
            return None
        where = (f" in a cross-validation fold fitted on {self.seconds:.3g} s of the data" if self.fold
                 else f" in {self.seconds:.3g} s of training data")
        return (f"{_plural(k, 'number')} to fit from {_plural(self.windows, 'training window')} without overlap "
                f"({self.window_samples * self.dt:.3g} s each){where}: needs {k + 1}, about "
                f"{(k + 1) * self.window_samples * self.dt:.3g} s")

    def error_shortfall(self, k: int) -> str | None:
        """Why the clustered standard errors of ``k`` offsets fitted together are not judged (``None``: they are)."""
        if self.stretches > k:
            return None
        return (f"{_plural(self.stretches, 'training stretch', 'training stretches')} for "
                f"{_plural(k, 'offset')}: the standard error clustered by stretch needs {k + 1} "
                f"({k + 1} records, or one over {k * self.stretch_s:g} s)")

    def refusal(self) -> str | None:
        """The one-line refusal when not even one number can be fitted (``None``: some can)."""
        if self.windows > 1:
            return None
        return (f"{self.seconds:.3g} s of training data in {_plural(self.records, 'record')}: "
                f"{_plural(self.windows, 'window')} of {self.window_samples} samples (data.past + data.window + 1, "
                f"{self.window_samples * self.dt:.3g} s) without overlap, too short to fit even one number (that "
                f"needs 2 such windows); give at least {2 * self.window_samples * self.dt:.3g} s of training data, "
                "or a shorter data.window")


def _cut_windows(dm: HypaDataModule, records: Sequence[Record], length: int, stride: int) -> dict[str, torch.Tensor]:
    """Every record cut into windows of ``length`` samples every ``stride`` (u, y, s)."""
    cut = Stretches.cut(dm, records, length - dm.past - 1, step=stride)
    full = next((b for b in cut.batches if b["u"].shape[1] == length), None)
    if full is None:
        raise TooShortError(f"no training record holds a fit window of {length} samples")
    return full if full["s"].shape[-1] else {k: v for k, v in full.items() if k != "s"}


def training_windows(dm: HypaDataModule) -> dict[str, torch.Tensor]:
    """Every training window in one batch (u, y and s when the data has scheduling signals)."""
    dataset = dm.dataset("train")
    loader = torch.utils.data.DataLoader(dataset, batch_size=len(dataset), shuffle=False)
    batch = next(iter(loader))
    return {k: v for k, v in batch.items() if k in ("u", "y", "s")}
