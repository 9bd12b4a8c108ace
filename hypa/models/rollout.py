"""The free run: a composed model simulated over a measured record, never seeing a measured output
after its start, and what it predicted (``Prediction``).

The one rollout every command uses (evaluation, the benchmark, explain, the diagnosis, the
validation figures in TensorBoard): it needs a model and the data module's channels and
normalization, nothing of training or of a run folder. :func:`free_run_levels` says where a free
run sits at a level the data never reach (a state no data initialize, an output offset).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import torch

from hypa.core.metrics import errors

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


def model_inputs(dm: HypaDataModule, record: Record, stretch: slice = slice(None),
                 dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, ...]:
    """(u, y_past, s) of one record for the model, batch of one: normalized inputs, normalized
    measured outputs up to the window start (the first ``past`` + 1 samples), SI scheduling."""
    arrays = {k: a[stretch] for k, a in dm.signature.arrays(record).items()}
    arrays["y"] = arrays["y"][: dm.past + 1]
    return tuple(torch.as_tensor(arrays[k], dtype=dtype)[None] for k in "uys")


@torch.no_grad()
def free_run(model: ComposedModel, dm: HypaDataModule, record: Record, stretch: slice = slice(None),
             dtype: torch.dtype = torch.float32) -> Prediction:
    """Simulate a record (or a stretch of it) from its start, never seeing a measured output after it.

    The first ``dm.past`` + 1 samples start the model (the measured state, or the estimate of
    an unmeasured one from the past); every later sample is predicted. ``dtype``: of the inputs
    (a model in float64 runs in float64 with float64 inputs).
    """
    device = next(model.buffers(), torch.zeros(0)).device
    u, y_past, s = (t.to(device) for t in model_inputs(dm, record, stretch, dtype))
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


LEVEL_SPREADS = 5.0  # a free run whose mean is this many spreads (the data's or its own) from the data's: off level


def free_run_levels(runs: Sequence[Prediction], outputs: Sequence[str], model: ComposedModel | None = None,
                    units: Mapping[str, str] | None = None) -> list[str]:
    """One line per output whose free runs sit at a level the data never reach: the mean of the
    predicted samples over all ``runs`` further than ``LEVEL_SPREADS`` spreads from the measured
    mean, the spread the larger of the data's and the free run's own standard deviation (the data's
    own scale: a 0 V run of a 3.7 V cell whose voltage moves by 0.1 V is 37 spreads off; a run that
    only drifts or oscillates is not flagged by its level). Each line names the output and, given
    the ``model``, the states it reads that no dynamics pull back (A's null space: an integrator, a
    state of charge, an OCV), else all the states it reads: "the free run of 'voltage' sits at 0 V
    while the data sit at 3.7 V (37 spreads away): a state that no data initialize (ocv?) or an
    output offset". ``units``: each output's unit for the message. Empty where every level is right.
    """
    lines = []
    for name in outputs:
        measured = np.concatenate([np.asarray(r.measured[name][r.first:], float) for r in runs]) if runs else []
        predicted = np.concatenate([np.asarray(r.predicted[name][r.first:], float) for r in runs]) if runs else []
        seen = np.isfinite(measured)
        if not seen.any() or len(predicted) != len(measured):
            continue
        measured, predicted = measured[seen], predicted[seen]
        if not np.isfinite(predicted).all():
            continue  # a diverged run: not a level (the metrics say it)
        level, data = float(predicted.mean()), float(measured.mean())
        spread = max(float(measured.std()), float(predicted.std()),
                     np.finfo(float).eps * max(abs(level), abs(data), 1.0))
        away = abs(level - data) / spread
        if away <= LEVEL_SPREADS:
            continue
        unit = f" {units[name]}" if units and units.get(name) else ""
        duration = max(float(r.time[-1] - r.time[r.first - 1]) for r in runs if len(r.time) > r.first)
        states = _level_states(model, name, duration) if model is not None else ()
        where = f"a state that no data initialize ({' or '.join(states)}?) or an output offset" if states else \
            "an output offset, or a state that no data initialize"
        lines.append(f"the free run of {name!r} sits at {level:.3g}{unit} while the data sit at {data:.3g}{unit} "
                     f"({away:.0f} spreads away): {where}")
    return lines


def _level_states(model: ComposedModel, output: str, duration: float) -> tuple[str, ...]:
    """The states of the physics block writing ``output`` that it reads (C, and a nonlinear output's
    slope at the states' operating point), those of modes slower than the record (``duration`` [s]:
    |λ| duration < 1, an integrator's λ = 0 too) first: a wrong start of those stays wrong over the
    whole run, a faster state's fades."""
    import torch

    block_spec = next((b for b in model.order if output in b.outputs), None)
    if block_spec is None or block_spec.kind != "physics":
        return ()
    block = model.blocks[block_spec.name]
    system, row = block.model, block_spec.outputs.index(output)
    if not system.n_states or system.outputs_are_states:
        return (system.state_names[row],) if system.outputs_are_states else ()
    with torch.no_grad():
        ss = block.state_space(torch.float64)
        reads = ss.c[row].abs() > 0
    if system.has_nonlinear_output:
        dtype = torch.float64
        zero_u = block.input_mean.new_zeros(len(system.input_names), dtype=dtype)
        with torch.enable_grad():
            slope = torch.func.jacrev(lambda x: block.nonlinear_output(x, zero_u))(
                block.state_mean.new_zeros(system.n_states, dtype=dtype))
        reads = reads | (slope[row].detach().abs() > 0)
    with torch.no_grad():
        rates, vectors = torch.linalg.eig(ss.a)  # modes [1/s] and their directions
        slow = rates.abs() * duration < 1.0
        weight = vectors[:, slow].abs()  # (n, slow modes)
        free = (weight > 1e-6 * weight.amax(0, keepdim=True)).any(1) if bool(slow.any()) else reads & False
    names = [s for j, s in enumerate(system.state_names) if bool(reads[j])]
    held = [s for j, s in enumerate(system.state_names) if bool(reads[j]) and bool(free[j])]
    return tuple(held or names)
