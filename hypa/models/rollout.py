"""The free run: a composed model simulated over a measured record, never seeing a measured output
after its start, and what it predicted (``Prediction``).

The one rollout every command uses (evaluation, the benchmark, explain, the diagnosis, the
validation figures in TensorBoard): it needs a model and the data module's channels and
normalization, nothing of training or of a run folder.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import torch

from hypa.metrics import errors

if TYPE_CHECKING:
    from hypa.data import HypaDataModule, Record
    from hypa.models.composed import ComposedModel


@dataclass
class Prediction:
    """Measured and predicted signals of one record (SI units, the record's time base).

    ``predicted`` holds the model outputs: samples before ``first`` are the measured ones that
    started the model (the past and the window start), the rest the prediction; ``signals``
    the model's internal physical signals (e.g. an input a network learns implicitly),
    each on its own sample range.
    """

    record: str
    time: np.ndarray  # (T,)
    measured: dict[str, np.ndarray]  # outputs and evaluation channels, (T,)
    predicted: dict[str, np.ndarray]  # outputs, (T,)
    inputs: dict[str, np.ndarray]
    signals: dict[str, tuple[np.ndarray, int]] = field(default_factory=dict)  # values, first sample
    first: int = 1  # first predicted sample (past + 1)

    def signal_on_grid(self, name: str) -> np.ndarray:
        """An internal signal on the record's time base (NaN where the model has no value)."""
        values, start = self.signals[name]
        out = np.full_like(self.time, np.nan, dtype=float)
        out[start : start + len(values)] = values[: len(out) - start]
        return out


def model_inputs(dm: HypaDataModule, record: Record, stretch: slice = slice(None)) -> tuple[torch.Tensor, ...]:
    """(u, y_past, s) of one record for the model, batch of one: normalized inputs, normalized
    measured outputs up to the window start (the first ``past`` + 1 samples), SI scheduling."""
    arrays = {k: a[stretch] for k, a in dm.signature.arrays(record).items()}
    arrays["y"] = arrays["y"][: dm.past + 1]
    return tuple(torch.as_tensor(arrays[k], dtype=torch.float32)[None] for k in "uys")


@torch.no_grad()
def free_run(model: ComposedModel, dm: HypaDataModule, record: Record, stretch: slice = slice(None)) -> Prediction:
    """Simulate a record (or a stretch of it) from its start, never seeing a measured output after it.

    The first ``dm.past`` + 1 samples start the model (the measured state, or the estimate of
    an unmeasured one from the past); every later sample is predicted.
    """
    device = next(model.buffers(), torch.zeros(0)).device
    u, y_past, s = (t.to(device) for t in model_inputs(dm, record, stretch))
    first = dm.past + 1
    signals = model.signals(u, y_past, s)
    pred = model.outputs(signals, dm.past)[0].cpu()
    y = record.stack(dm.output_names)[stretch]
    predicted = {n: np.concatenate([y[:first, i], model.to_physical(n, pred[:, i]).double().numpy()])
                 for i, n in enumerate(dm.output_names)}
    internal = {}
    for name, (values, start) in signals.items():
        if name not in dm.input_names and name not in model.spec.outputs:
            internal[name] = (model.to_physical(name, values[0, :, 0]).double().cpu().numpy(), start)
    measured = {n: record[n][stretch] for n in (*dm.output_names, *dm.eval_channels) if n in record}
    return Prediction(record.name, record.time[stretch], measured, predicted,
                      {n: record[n][stretch] for n in dm.input_names}, internal, first)


def free_run_metrics(runs: Sequence[Prediction], outputs: Sequence[str]) -> dict[str, dict[str, float]]:
    """Per output, over the predicted samples of all free runs: ``rmse`` [SI], ``mse`` and ``r2``."""
    out = {}
    for name in outputs:
        y = np.concatenate([r.measured[name][r.first:] for r in runs])
        p = np.concatenate([r.predicted[name][r.first:] for r in runs])
        e = errors(p, y)
        out[name] = {"rmse": e["rmse"], "mse": e["mse"], "r2": e["r2"]}
    return out
