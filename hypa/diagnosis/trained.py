"""Step 4 with training: train the written extension through ``hypa.train`` and free-run it.

``python -m hypa.diagnose extension.train=true`` runs the printed train command (its progress
on the console, its run folder inside the diagnosis folder), loads the best checkpoint and
free-runs it over the validation records, so the report can put the trained HyPA-Net beside
the nominal and the parametric extension.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hypa.data import HypaDataModule
from hypa.diagnosis.config import train_arguments
from hypa.diagnosis.model import STATES
from hypa.errors import UserError


class ExtensionTrainingError(UserError):
    """``hypa.train`` failed on the written extension (its own output says why; the message gives
    the command to rerun it alone), so ``hypa.diagnose`` reports it in one line."""


@dataclass(frozen=True)
class TrainedExtension:
    """The trained extension's free runs over the validation records (in the records' order)."""

    folder: Path  # its hypa.train run folder
    states: list[np.ndarray]  # per record (L, 2) [rad/s, rad], sample 0 = the measured state
    rear_wheel_angle: list[np.ndarray | None]  # per record (L,) [rad] where the model has one


def train_extension(config_dir: Path, run_dir: Path, dm: HypaDataModule, data_overrides: Sequence[str] = (),
                    extra_overrides: Sequence[str] = ()) -> TrainedExtension:
    """Train ``<config_dir>/model/diagnosed.yaml`` into ``run_dir`` and free-run it on ``dm``'s
    validation records. ``extra_overrides``: more ``hypa.train`` overrides (e.g. a shorter
    training: ``trainer.max_epochs=5``)."""
    from hypa.evaluation.runs import free_run, load_run

    argv = [sys.executable, "-m", "hypa.train", *train_arguments(config_dir, data_overrides),
            f"hydra.run.dir={run_dir}", *extra_overrides]
    completed = subprocess.run(argv, check=False)  # its output goes to the console: progress
    if completed.returncode != 0:
        raise ExtensionTrainingError(f"hypa.train failed (exit status {completed.returncode}) on the extended "
                                     f"model: {' '.join(argv[1:])}")
    run = load_run(run_dir)
    states, rear = [], []
    for record in dm.records("val"):
        prediction = free_run(run.module.model, dm, record)
        states.append(np.stack([prediction.predicted[s] for s in STATES], axis=-1))
        rear.append(prediction.signal_on_grid("rear_wheel_angle") if "rear_wheel_angle" in prediction.signals
                    else None)
    return TrainedExtension(Path(run_dir), states, rear)
