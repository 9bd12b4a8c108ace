"""Stop a run whose loss is no longer a number, before its weights can become a checkpoint.

Lightning's ``ModelCheckpoint`` turns a NaN validation loss into ``inf`` and still saves the
first one as "best", and ``EarlyStopping`` only stops after the checkpoint is written. This
callback raises :class:`DivergedError` (one line, naming the epoch) at the first non-finite
training loss (after the optimizer step that made it, before the next validation) or validation
loss (in ``on_validation_end``, which Lightning runs before any checkpoint callback's).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback

from hypa.core.errors import UserError


class DivergedError(UserError):
    """The training or validation loss became NaN or infinite."""


class StopOnNonFiniteLoss(Callback):
    """Raise :class:`DivergedError` at the first non-finite training or validation loss."""

    def __init__(self, monitor: str = "val/loss", hint: str = "") -> None:
        self.monitor, self.hint = monitor, hint

    def on_train_batch_end(self, trainer: L.Trainer, module: L.LightningModule, outputs: Any, batch: Any,
                           batch_idx: int) -> None:
        loss = outputs.get("loss") if isinstance(outputs, Mapping) else outputs
        if isinstance(loss, torch.Tensor) and not bool(torch.isfinite(loss.detach()).all()):
            self._stop(f"training loss {float(loss.detach().float().mean()):g} at epoch {trainer.current_epoch} "
                       f"(batch {batch_idx})")

    def on_validation_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        value = trainer.callback_metrics.get(self.monitor)
        if value is not None and not math.isfinite(float(value)):
            when = "in the check before training" if trainer.sanity_checking else f"at epoch {trainer.current_epoch}"
            self._stop(f"validation loss {float(value):g} {when}")

    def _stop(self, what: str) -> None:
        raise DivergedError(f"{what}: the training diverged{'; ' + self.hint if self.hint else ''}")
