"""Staged training as a callback: the two-stage V2 schedule of the paper.

Stage 1 trains the rear-steering network with the correction bypassed; stage 2 freezes it and
trains the correction. Each stage stops early on its own: when Lightning's ``EarlyStopping``
(or the per-stage epoch budget) ends a stage that is not the last, the best weights of that
stage are restored, the next stage is switched in and early stopping starts afresh. The stage
is saved in checkpoints, so a run interrupted in stage 2 resumes in stage 2.
"""

from __future__ import annotations

import copy
import logging
import math
from collections.abc import Sequence
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback, EarlyStopping
from lightning.pytorch.trainer.states import TrainerFn

from hypa.models import StageSpec

log = logging.getLogger(__name__)


class StagedTraining(Callback):
    """Switches between ``stages`` of a model; ``max_epochs`` is each stage's epoch budget."""

    def __init__(self, stages: Sequence[StageSpec], max_epochs: int, monitor: str = "val/loss") -> None:
        if not stages:
            raise ValueError("StagedTraining needs at least one stage")
        self.stages, self.max_epochs, self.monitor = tuple(stages), max_epochs, monitor
        self.stage, self.stage_start_epoch = 0, 0
        self._best, self._best_weights = math.inf, None

    @property
    def current(self) -> StageSpec:
        return self.stages[self.stage]

    def apply(self, module: L.LightningModule) -> None:
        module.model.set_stage(self.current.train, self.current.bypass)

    def on_train_start(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        self.apply(module)  # after a resume too: the stage comes from the checkpoint
        log.info("stage %d/%d (%s): training %s, bypassing %s", self.stage + 1, len(self.stages),
                 self.current.name, list(self.current.train), list(self.current.bypass))

    def on_train_epoch_start(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        module.log("stage", float(self.stage), on_step=False, on_epoch=True, sync_dist=True)

    def on_validation_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        if (trainer.sanity_checking or trainer.state.fn != TrainerFn.FITTING
                or self.monitor not in trainer.callback_metrics):  # trainer.validate before fit: no epoch spent
            return
        value = float(trainer.callback_metrics[self.monitor])
        if value < self._best:
            self._best = value
            self._best_weights = copy.deepcopy(module.model.state_dict())
        budget_spent = trainer.current_epoch + 1 - self.stage_start_epoch >= self.max_epochs
        if (trainer.should_stop or budget_spent) and self.stage + 1 < len(self.stages):
            self._next_stage(trainer, module)
        elif budget_spent:
            trainer.should_stop = True

    def _next_stage(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        trainer.should_stop = False
        if self._best_weights is not None:
            module.model.load_state_dict(self._best_weights)
        finished = self.current.name
        self.stage += 1
        self.stage_start_epoch = trainer.current_epoch + 1
        self._best, self._best_weights = math.inf, None
        for callback in trainer.callbacks:
            if isinstance(callback, EarlyStopping):
                callback.wait_count, callback.stopped_epoch = 0, 0
                if hasattr(callback, "stopping_reason_message"):
                    callback.stopping_reason_message = None
                callback.best_score = torch.tensor(math.inf if callback.mode == "min" else -math.inf)
        self.apply(module)
        message = (f"stage {finished!r} done after epoch {trainer.current_epoch}: switching to stage "
                   f"{self.stage + 1}/{len(self.stages)} ({self.current.name}), training {list(self.current.train)}")
        log.info(message)
        if trainer.logger is not None and hasattr(trainer.logger, "experiment"):
            experiment = trainer.logger.experiment
            if hasattr(experiment, "add_text"):
                experiment.add_text("stages", message, trainer.global_step)

    def state_dict(self) -> dict[str, Any]:
        # the stage's best weights too: a run resumed in stage 1 must still start stage 2 from them
        return {"stage": self.stage, "stage_start_epoch": self.stage_start_epoch, "best": self._best,
                "best_weights": self._best_weights}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.stage = int(state_dict["stage"])
        self.stage_start_epoch = int(state_dict["stage_start_epoch"])
        self._best = float(state_dict.get("best", math.inf))
        self._best_weights = state_dict.get("best_weights")
