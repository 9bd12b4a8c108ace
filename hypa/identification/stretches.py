"""Records cut into stretches: long windows that tile them, each started from the data.

A stretch starts like a training window, from its first ``first`` samples (the measured state,
or the estimate of an unmeasured one from its past samples) and then runs free. Cut into
stretches, a free run that would drift or diverge over a whole record (an integrating or
unstable system) restarts from the data every stretch: multiple shooting, with each segment's
initial state taken from the measurements. One stretch per record is single shooting (the
output error over the whole record). The diagnosis scores candidates on them; the
identification fits parameters on them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from hypa.data import HypaDataModule, Record
from hypa.models import ComposedModel


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
    positions: tuple[tuple[tuple[int, int], ...], ...] = ()  # per batch, per stretch: (record index, first sample)
    scale: torch.Tensor | None = None  # the outputs' weights in :meth:`score` when not their own (:meth:`weights`)

    @property
    def samples(self) -> int:
        """How many predicted samples (what :meth:`score` averages over)."""
        return sum(int(b["y"].shape[0]) * (int(b["y"].shape[1]) - self.first) for b in self.batches)

    @property
    def count(self) -> int:
        """How many stretches."""
        return sum(int(b["y"].shape[0]) for b in self.batches)

    def to(self, dtype: torch.dtype) -> Stretches:
        """The same stretches with inputs and outputs in ``dtype`` (float64 for finite differences)."""
        return Stretches(tuple({k: v.to(dtype) for k, v in b.items()} for b in self.batches), self.first,
                         self.positions, self.scale)

    @classmethod
    def cut(cls, dm: HypaDataModule, records: Sequence[Record], samples: int, step: int | None = None) -> Stretches:
        """Each record cut into stretches predicting ``samples`` each, started every ``step``
        samples (default: ``samples``, tiling the record), the last one ending at the record's end."""
        first, groups, positions, signature = dm.past + 1, {}, {}, dm.signature
        for index, record in enumerate(records):
            length = min(len(record), first + samples)
            if length <= first:
                continue
            starts = list(range(0, len(record) - length + 1, step or samples))
            if starts[-1] != len(record) - length:
                starts.append(len(record) - length)
            arrays = signature.arrays(record)
            for start in starts:
                groups.setdefault(length, []).append({k: a[start : start + length] for k, a in arrays.items()})
                positions.setdefault(length, []).append((index, start))
        batches = tuple({k: torch.as_tensor(np.stack([w[k] for w in group]), dtype=torch.float32) for k in group[0]}
                        for group in groups.values())
        return cls(batches, first, tuple(tuple(positions[length]) for length in groups))

    @torch.no_grad()
    def predict(self, model: ComposedModel, initial: Sequence[Mapping[str, torch.Tensor]] | None = None,
                states: list[dict[str, torch.Tensor]] | None = None) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """(predicted, measured) normalized outputs (B, L - first, p) per batch, float64.

        ``initial``: per batch, the blocks' states at the stretches' starts instead of the data's
        (:meth:`ComposedModel.signals`); ``states``, when given, receives per batch the states
        the blocks ran through.
        """
        out = []
        for i, b in enumerate(self.batches):
            s = b["s"] if b["s"].shape[-1] else None
            ran: dict[str, torch.Tensor] | None = None if states is None else {}
            y_past = b["y"][:, : self.first]
            pred = model.outputs(model.signals(b["u"], y_past, s, None if initial is None else initial[i], ran),
                                 self.first - 1)
            if states is not None:
                states.append(ran)
            out.append((pred.double(), b["y"][:, self.first :].double()))
        return out

    @torch.no_grad()
    def physical_states(self, model: ComposedModel, blocks: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """The states each started physics block (of ``blocks``; all by default) runs through over the
        stretches from the data's starts, in the states' units: block name -> (samples, n) float64,
        the stretches one after the other."""
        ran: list[dict[str, torch.Tensor]] = []
        self.predict(model, states=ran)
        out = {}
        for name in model.started_blocks():
            if blocks is None or name in blocks:
                block = model.blocks[name]
                parts = [(states[name].double() * block.state_std.double() + block.state_mean.double())
                         .reshape(-1, states[name].shape[-1]) for states in ran]
                out[name] = torch.cat(parts).numpy()
        return out

    def weights(self) -> torch.Tensor:
        """1 / the variance of each (normalized) output over the predicted samples (or ``scale``
        where given: the variance over a larger set, so that scores of its parts add up)."""
        if self.scale is not None:
            return self.scale
        y = torch.cat([b["y"][:, self.first :].reshape(-1, b["y"].shape[-1]) for b in self.batches]).double()
        return 1.0 / torch.clamp(y.var(0, unbiased=False), min=1e-300)

    def score(self, model: ComposedModel) -> float:
        """Mean over outputs of the error energy relative to the output's variance (1 - R²)."""
        pairs = self.predict(model)
        count = sum(p.shape[0] * p.shape[1] for p, _ in pairs)
        mse = sum(((p - y) ** 2).sum((0, 1)) for p, y in pairs) / count
        out = (mse * self.weights()).numpy()
        return float(np.mean(out)) if np.all(np.isfinite(out)) else math.inf
