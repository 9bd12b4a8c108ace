"""Step 4 with training: train the written extension through ``hypa.train`` and free-run it.

``python -m hypa.diagnose extension.train=true`` runs the printed train command (its progress
on the console, its run folder inside the diagnosis folder), loads the best checkpoint and
free-runs it over the validation records, so the report can put the trained model (the named
causes, plus a correction network where structure stays unexplained) beside the nominal one.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from hypa.data import HypaDataModule
from hypa.errors import UserError
from hypa.evaluation.runs import Prediction


class ExtensionTrainingError(UserError):
    """``hypa.train`` failed on the written extension (its own output says why; the message gives
    the command to rerun it alone), so ``hypa.diagnose`` reports it in one line."""


def train_extension(arguments: Sequence[str], run_dir: Path, dm: HypaDataModule,
                    extra_overrides: Sequence[str] = ()) -> list[Prediction]:
    """Run ``python -m hypa.train ARGUMENTS`` into ``run_dir`` and free-run its best checkpoint
    over ``dm``'s validation records. ``extra_overrides``: more ``hypa.train`` overrides (e.g. a
    shorter training: ``trainer.max_epochs=5``)."""
    from hypa.evaluation.runs import free_run, load_run

    argv = [sys.executable, "-m", "hypa.train", *arguments, f"hydra.run.dir={run_dir}", *extra_overrides]
    completed = subprocess.run(argv, check=False)  # its output goes to the console: progress
    if completed.returncode != 0:
        raise ExtensionTrainingError(f"hypa.train failed (exit status {completed.returncode}) on the extended "
                                     f"model: {' '.join(argv[1:])}")
    model = load_run(run_dir).module.model
    return [free_run(model, dm, record) for record in dm.records("val")]
