"""TensorBoard figures each validation epoch: the model free-running over a validation stretch."""

from __future__ import annotations

import lightning as L
from lightning.pytorch.callbacks import Callback

from hypa.models.rollout import free_run
from hypa.reporting.figures import time_series


class ValidationFigures(Callback):
    """Predicted vs measured outputs (and each learned signal the files measure for evaluation,
    such as an implicitly learned rear-wheel angle) on ``seconds`` of the first validation
    record from ``start_s``, free-running from its start; axes in the channels' display units.
    The stretch is at least one training window long (data sampled every few seconds: 30 s would be
    a handful of samples) and at most the record."""

    def __init__(self, seconds: float = 30.0, start_s: float = 10.0, every_n_epochs: int = 1) -> None:
        self.seconds, self.start_s, self.every_n_epochs = seconds, start_s, every_n_epochs

    def on_validation_epoch_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        if not trainer.is_global_zero or trainer.sanity_checking or trainer.current_epoch % self.every_n_epochs:
            return
        experiment = getattr(trainer.logger, "experiment", None)
        if experiment is None or not hasattr(experiment, "add_figure"):
            return
        dm = trainer.datamodule
        record = dm.records("val")[0]
        samples = min(max(int(self.seconds / dm.dt), dm.window), len(record) - dm.past - 1)
        first = max(0, min(int(self.start_s / dm.dt), len(record) - samples - dm.past - 1))
        stretch = slice(first, first + samples + dm.past + 1)
        was_training = module.model.training
        module.model.eval()
        prediction = free_run(module.model, dm, record, stretch)
        module.model.train(was_training)
        units = {n: c.display_unit for n, c in dm.channels.items()}
        scale = {n: c.display_factor for n, c in dm.channels.items()}
        shown = slice(prediction.first, None)
        name = module.model.spec.name
        fig = time_series(prediction.time[shown], {n: prediction.measured[n][shown] for n in dm.output_names},
                          {name: {n: prediction.predicted[n][shown] for n in dm.output_names}}, units=units,
                          scale=scale, title=f"epoch {trainer.current_epoch}: free run")
        experiment.add_figure("val/outputs", fig, trainer.global_step, close=True)
        for signal in module.compared:
            if signal in prediction.signals and signal in prediction.measured:
                learned = prediction.signal_on_grid(signal)
                fig = time_series(prediction.time, {signal: prediction.measured[signal]},
                                  {f"{name} (learned)": {signal: learned}}, units=units, scale=scale,
                                  title=f"implicitly learned {signal}")
                experiment.add_figure(f"val/{signal}", fig, trainer.global_step, close=True)
