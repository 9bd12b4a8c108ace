"""The reference an export is checked against: one record's inputs and hypa's own free run of it."""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hypa.models.rollout import free_run, model_inputs

if TYPE_CHECKING:
    from hypa.data import HypaDataModule, Record
    from hypa.export.step import ModelStep


@dataclass
class Reference:
    """One record, SI: ``u`` (L, m + q) the step's inputs (the model's inputs, then its scheduling
    signals), ``outputs`` hypa's free run (L, p) (rows before ``first`` are the measured samples
    that started it), ``initial_state`` (r,) the step's state at sample ``first`` = P + 1."""

    record: str
    time: np.ndarray  # (L,) [s]
    input_names: tuple[str, ...]  # inputs, then scheduling signals: the columns of u
    u: np.ndarray  # (L, m + q)
    output_names: tuple[str, ...]
    outputs: np.ndarray  # (L, p)
    output_std: np.ndarray  # (p,): the outputs' training-set standard deviations
    first: int
    initial_state: np.ndarray  # (r,)
    free_run_seconds: float  # hypa's free run of the whole record (the fastest of three)

    def write_csv(self, path: Path) -> Path:
        """``time``, the inputs and scheduling signals, then hypa's free-run outputs: one column per channel."""
        with path.open("w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["time", *self.input_names, *self.output_names])
            for t, u, y in zip(self.time, self.u, self.outputs):
                writer.writerow([repr(float(t)), *(repr(float(v)) for v in u), *(repr(float(v)) for v in y)])
        return path


def reference_run(step: ModelStep, dm: HypaDataModule, record: Record) -> Reference:
    """hypa's free run of ``record`` (``rollout.free_run``), timed, and the step's state where it takes over."""
    model, dtype = step.model, step.dtype
    free_run(model, dm, record, dtype=dtype)  # the first run builds and caches the physics' matrices: time the rest
    seconds = []
    for _ in range(3):
        started = time.perf_counter()
        prediction = free_run(model, dm, record, dtype=dtype)
        seconds.append(time.perf_counter() - started)
    u, y_past, s = model_inputs(dm, record, dtype=dtype)
    initial = step.initial_state(u, y_past, s).double().numpy()
    names = (*model.input_names, *model.scheduling_names)
    inputs = np.stack([record[n] for n in names], -1) if names else np.zeros((len(record.time), 0))
    outputs = np.stack([prediction.predicted[n] for n in step.output_names], -1)
    std = np.array([model.measured_scale[n][1] for n in step.output_names])
    return Reference(record.name, np.asarray(record.time, dtype=float), names, inputs.astype(float), step.output_names,
                     outputs, std, prediction.first, initial, min(seconds))
