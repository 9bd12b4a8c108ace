"""The generic stand-in every named cause must beat: "unmodelled dynamics", a small linear filter.

A catalogue cause is a claim about the physics (a dead time, a rear-steering path, a stiffening
spring). Much of what a residual holds can be matched by any flexible enough edit, so a claim is
only made when it explains clearly more than a model that claims nothing: a linear filter from
the measured inputs and the declared scheduling channels to each output's residual, added to the
model being extended.

The filter is a bank: each channel itself and low-passed at the nominal model's time scales
(first-order filters with time constants from two samples, or the fastest mode's, to the slowest
decay time of :class:`~hypa.diagnosis.scales.Scales`, a factor ``RATIO`` apart, at most ``BANK``;
started at rest at the channel's first value). Each output's residual is a linear combination of the bank's signals,
fitted by exact least squares on the training stretches (the residual is affine in the
weights, as an offset's is) and scored, like every candidate, on the validation stretches. Its
score is the bar (:func:`hypa.diagnosis.search.name_causes`): a cause is named only when its
validation error is below ``1 - MARGIN`` times the filter's, or when it fits fewer numbers than
the filter and explains at least ``SIMPLER`` (75 %) as much (a fixed operating point replaced by
the measured speed fits none); where the filter explains that much of a named cause's gain, it
is listed among what the data cannot tell the cause from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy import signal

from hypa.diagnosis.problem import Problem
from hypa.identification.stretches import Stretches
from hypa.models import ComposedModel

MARGIN = 0.1  # a named cause leaves at most (1 - MARGIN) of the generic filter's validation error
RIDGE = 1e-4  # relative Tikhonov term of the least squares (the bank's signals are correlated)
RATIO = 4.0  # the bank's time constants lie this far apart ...
BANK = 5  # ... and are at most this many


@dataclass(frozen=True)
class GenericFit:
    """The filter's validation score (1 - R², mean over outputs), its gain over the model it
    extends and how many numbers it fitted."""

    score: float
    gain: float
    numbers: int

    def describe(self) -> str:
        return (f"a generic linear filter from the inputs to the residual ({self.numbers} numbers): "
                f"error {100 * self.gain:.2g} % lower")


def time_constants(problem: Problem) -> list[float]:
    """The bank's low-pass time constants [s]: from 2 dt (or the fastest mode's, if slower) to the
    slowest decay time, ``RATIO`` apart, at most ``BANK`` of them (spread evenly in log time)."""
    scales = problem.time_scales
    low, high = max(2 * scales.dt, min(scales.fastest_s, scales.slowest_s)), scales.slowest_s
    if high <= low:
        return [low]
    count = min(BANK, 1 + math.ceil(math.log(high / low) / math.log(RATIO)))
    return [low * (high / low) ** (k / (count - 1)) for k in range(count)] if count > 1 else [low]


def _bank(stretches: Stretches, problem: Problem, taus: list[float]) -> list[torch.Tensor]:
    """Per batch: the bank's signals (B, L - first, F) at the predicted samples, float64."""
    dm, out = problem.dm, []
    scale = problem.scale(dm.scheduling_names)
    for batch in stretches.batches:
        channels = [batch["u"].double()]
        if batch["s"].shape[-1]:
            mean = torch.tensor([scale[n][0] for n in dm.scheduling_names], dtype=torch.float64)
            std = torch.tensor([scale[n][1] or 1.0 for n in dm.scheduling_names], dtype=torch.float64)
            channels.append((batch["s"].double() - mean) / std)
        x = torch.cat(channels, -1).numpy()  # (B, L, c)
        start = x[:, :1]
        signals = [x]
        for tau in taus:  # y[k] = a y[k-1] + (1 - a) x[k-1], at rest at the first value: y[0] = x[0]
            a = math.exp(-dm.dt / tau)
            signals.append(start + signal.lfilter([0.0, 1.0 - a], [1.0, -a], x - start, axis=1))
        out.append(torch.as_tensor(np.concatenate(signals, -1)[:, stretches.first :]))
    return out


def fit_generic(problem: Problem, model: ComposedModel, base_score: float) -> GenericFit:
    """The filter fitted on the training stretches of ``model``'s residual and scored on the validation ones."""
    taus = time_constants(problem)
    train, val = problem.stretches("train"), problem.stretches("val")
    pairs = train.predict(model)
    bank = _bank(train, problem, taus)
    features = bank[0].shape[-1]
    gram = sum(torch.einsum("blf,blg->fg", b, b) for b in bank)
    gram = gram + RIDGE * torch.trace(gram) / features * torch.eye(features, dtype=gram.dtype)
    rhs = sum(torch.einsum("blf,blp->fp", b, y - p) for b, (p, y) in zip(bank, pairs))
    theta = torch.linalg.solve(gram, rhs)  # (F, p): each output's filter weights
    predicted = [(p + b @ theta, y) for b, (p, y) in zip(_bank(val, problem, taus), val.predict(model))]
    count = sum(p.shape[0] * p.shape[1] for p, _ in predicted)
    mse = sum(((p - y) ** 2).sum((0, 1)) for p, y in predicted) / count
    per_output = (mse * val.weights()).numpy()
    score = float(np.mean(per_output)) if np.all(np.isfinite(per_output)) else math.inf
    return GenericFit(score, 1.0 - score / base_score if base_score > 0 else 0.0, int(theta.numel()))
