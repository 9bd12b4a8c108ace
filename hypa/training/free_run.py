"""The validation free run: each validation epoch, the model simulated over every whole validation
record, as ``hypa evaluate`` and the benchmark score it (``val/free_run``).

``val/loss`` scores windows: each starts from its ``data.past`` samples and predicts ``data.window``.
Where a state no sensor reads is poorly known at a window's start (a slow tank's level from 16 s of
data), most of that loss is each window's start, and a correction network learns to mend starts
that a long free run does not have: on the cascaded tanks its best windows made the free run worse
(0.307 V of the identified physics -> 0.398 V). Where a free run drifts (an integrating axis), the
windows cannot see it at all. A model that is used as a simulator is chosen by
``early_stopping.monitor=val/free_run``: the epochs, the stages' best and the kept checkpoint by its
free runs. On a short validation record, though, one free run is a noisier judge than many windows
(EMPS: 5 s of validation; chosen by it the hybrid scored 5.39-5.44 mm on the test record against
5.27-5.37 mm by its windows). ``early_stopping.monitor=auto`` (``hypa benchmark budget=full``) lets the
identified physics decide, before the networks' first epoch: where its windows' loss exceeds its free
runs' (the windows' starts are most of their error: the tanks, 0.135 against 0.036), the free runs
choose; elsewhere the windows (EMPS: 8.4e-5 against 4.4e-3, a free run that drifts).
"""

from __future__ import annotations

import math

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import Callback

from hypa.data import HypaDataModule
from hypa.models import ComposedModel
from hypa.models.rollout import free_run

FREE_RUN = "val/free_run"
WINDOWS = "val/loss"
AUTO = "auto"  # early_stopping.monitor: chosen by the identified physics (:func:`chosen_monitor`)


def free_run_loss(model: ComposedModel, dm: HypaDataModule) -> float:
    """The mean squared error of the normalized outputs (the unit of ``val/loss``) over the predicted
    samples of free runs of every validation record, each from its first ``data.past`` + 1 samples;
    ``inf`` where a free run is not finite (never a best epoch). ``nan`` where no record is longer
    than its start."""
    total, count = 0.0, 0
    was_training = model.training
    model.eval()
    try:
        for record in dm.records("val"):
            if len(record) <= dm.past + 1:
                continue
            run = free_run(model, dm, record)
            for name in dm.output_names:
                _, std = model.measured_scale[name]
                measured = np.asarray(run.measured[name][run.first:], float)
                seen = np.isfinite(measured)
                error = (np.asarray(run.predicted[name][run.first:], float)[seen] - measured[seen]) / float(std)
                if not np.isfinite(error).all():
                    return math.inf
                total, count = total + float(np.sum(error**2)), count + int(seen.sum())
    finally:
        model.train(was_training)
    return total / count if count else math.nan


@torch.no_grad()
def windows_loss(module: L.LightningModule, dm: HypaDataModule) -> float:
    """``val/loss`` outside a trainer: the mean squared error of the normalized outputs over every
    validation window, each started from its first ``data.past`` + 1 samples. The random stream is left
    as it was (a data loader draws its workers' seed from it): the run trains as it would without this."""
    total, count, first = 0.0, 0, dm.past + 1
    was_training = module.training
    module.eval()
    try:
        with torch.random.fork_rng(devices=[]):
            for batch in dm.val_dataloader():
                y = batch["y"]
                pred = module(batch["u"], y[:, :first], batch.get("s"))
                total, count = total + float(((pred - y[:, first:]) ** 2).sum()), count + pred.numel()
    finally:
        module.train(was_training)
    return total / count if count else math.nan


def chosen_monitor(module: L.LightningModule, dm: HypaDataModule) -> tuple[str, float, float]:
    """What ``early_stopping.monitor=auto`` chooses for a hybrid, from its identified physics (its
    networks not yet trained): :data:`FREE_RUN` where the windows' loss exceeds the free runs' (the
    windows' starts, not the dynamics, are most of their error), else :data:`WINDOWS`; with both values."""
    windows, free = windows_loss(module, dm), free_run_loss(module.model, dm)
    return (FREE_RUN if windows > free else WINDOWS), windows, free


class FreeRunValidation(Callback):
    """Logs :data:`FREE_RUN` each validation (module docstring); the sanity check before training is
    skipped. Every process computes it on the whole validation records, so that under DDP every rank
    stops and keeps the same epoch."""

    def on_validation_epoch_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        if trainer.sanity_checking:
            return
        value = free_run_loss(module.model, trainer.datamodule)
        module.log(FREE_RUN, value, prog_bar=True, sync_dist=True)
