"""Progress as lines where no terminal shows a bar: a log file, CI, a pipe, a notebook's cell.

Lightning's bar redraws one line with carriage returns; written to a file it reads as a couple of
lines for a whole run. Where the output is not a terminal, ``hypa train`` turns the bar off and
prints an epoch line instead, at most one every ``every_s`` seconds (and always the first and the
last epoch of each stage; epochs and the best are counted within a stage)::

    stage 2/2 (correction), epoch 31/85: train/loss 0.00213, val/loss 0.00188 (best 0.00181 at epoch 27);
    2.8 s an epoch, at most 6.6 min more

Only the process of rank 0 prints. :class:`EpochLines` comes before
:class:`~hypa.training.staging.StagedTraining` among the trainer's callbacks, which switches the
stage when an epoch's validation ends. The cadence is a matter of display: what the run computes
never depends on it.
"""

from __future__ import annotations

import math
import sys
import time
from typing import Any, TextIO

import lightning as L
from lightning.pytorch.callbacks import Callback
from lightning.pytorch.trainer.states import TrainerFn

from hypa.reporting.numbers import elapsed, significant
from hypa.training.staging import StagedTraining


def wants_lines(stream: TextIO | None = None) -> bool:
    """Whether progress should be lines rather than a bar: ``stream`` (stdout) is not a terminal."""
    stream = sys.stdout if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    return not (callable(isatty) and isatty())


class EpochLines(Callback):
    """One line per epoch at most every ``every_s`` seconds, on ``stream`` (stdout): the stage, the
    epoch of the run's budget, the losses and the best so far, the time an epoch takes and the
    longest the rest may take (the epoch budget left; early stopping usually ends sooner). The best is
    of ``monitor``, the run's selection metric (shown after the losses where it is not one of them)."""

    def __init__(self, every_s: float = 5.0, stream: TextIO | None = None, monitor: str = "val/loss") -> None:
        if not every_s >= 0:
            raise ValueError(f"every_s must be >= 0, got {every_s}")
        self.monitor, self.every_s, self.stream = monitor, float(every_s), stream
        self._started = self._last = -math.inf
        self._epochs = 0
        self._best: tuple[float, int] | None = None
        self._stage: int | None = None
        self._unprinted: str | None = None

    def on_train_start(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        self._started, self._last, self._epochs, self._unprinted = time.perf_counter(), -math.inf, 0, None

    def on_validation_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        if trainer.sanity_checking or trainer.state.fn != TrainerFn.FITTING or not trainer.is_global_zero:
            return
        self._epochs += 1
        staged = next((c for c in trainer.callbacks if isinstance(c, StagedTraining)), None)
        stage = staged.stage if staged is not None else None
        if stage != self._stage:  # a new stage: its own best; the last line of the stage before first
            if self._unprinted is not None:
                self._print(self._unprinted)
            self._best, self._unprinted = None, None
        val = _metric(trainer, self.monitor)
        if val is not None and (self._best is None or val < self._best[0]):
            self._best = (val, self._epoch(trainer, staged))
        now = time.perf_counter()
        line = self.line(trainer, staged, (now - self._started) / self._epochs)
        if stage != self._stage or now - self._last >= self.every_s:
            self._last, self._stage, self._unprinted = now, stage, None
            self._print(line)
        else:
            self._unprinted = line

    def on_train_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        if self._unprinted is not None and trainer.is_global_zero:  # the last epoch's line, always
            self._print(self._unprinted)
            self._unprinted = None

    def line(self, trainer: L.Trainer, staged: StagedTraining | None, per_epoch_s: float) -> str:
        """The line for the epoch just validated: within its stage where the run has stages."""
        epoch, budget = trainer.current_epoch + 1, trainer.max_epochs or 0
        left_epochs = max(budget - epoch, 0)
        where = f"epoch {epoch}/{budget}" if budget > 0 else f"epoch {epoch}"
        if staged is not None and len(staged.stages) > 1:
            in_stage = self._epoch(trainer, staged)
            left_epochs = (max(staged.max_epochs - in_stage, 0)
                           + (len(staged.stages) - staged.stage - 1) * staged.max_epochs)
            where = (f"stage {staged.stage + 1}/{len(staged.stages)} ({staged.current.name}), "
                     f"epoch {in_stage}/{staged.max_epochs}")
        shown = ("train/loss", "val/loss", *((self.monitor,) if self.monitor not in ("train/loss", "val/loss") else ()))
        losses = [f"{name} {significant(value)}" for name in shown if (value := _metric(trainer, name)) is not None]
        if self._best is not None and losses:
            losses[-1] += f" (best {significant(self._best[0])} at epoch {self._best[1]})"
        timing = f"{elapsed(per_epoch_s)} an epoch"
        if left_epochs > 0:
            timing += f", at most {elapsed(left_epochs * per_epoch_s)} more"
        return f"{where}: {', '.join(losses) or 'no loss logged'}; {timing}"

    @staticmethod
    def _epoch(trainer: L.Trainer, staged: StagedTraining | None) -> int:
        """The epoch just validated, from 1: within its stage where the run has several."""
        if staged is not None and len(staged.stages) > 1:
            return trainer.current_epoch - staged.stage_start_epoch + 1
        return trainer.current_epoch + 1

    def _print(self, line: str) -> None:
        print(line, file=self.stream or sys.stdout, flush=True)


def _metric(trainer: L.Trainer, name: str) -> float | None:
    """A logged epoch metric as a float (``train/loss`` is logged per step and per epoch)."""
    metrics: dict[str, Any] = trainer.callback_metrics
    value = metrics.get(f"{name}_epoch", metrics.get(name))
    return None if value is None else float(value)
