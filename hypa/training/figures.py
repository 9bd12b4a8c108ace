"""TensorBoard figures each validation epoch: the model free-running over a validation stretch."""

from __future__ import annotations

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback

from hypa.plots import DEG, time_series
from hypa.plots import DISPLAY_UNITS as UNITS


class ValidationFigures(Callback):
    """Predicted vs measured states (and learned vs measured rear-wheel angle, when the model
    learns one and the file has it) on ``seconds`` of the first validation record, from
    ``start_s``, simulated free-running from the measured state at the start."""

    def __init__(self, seconds: float = 30.0, start_s: float = 10.0, every_n_epochs: int = 1) -> None:
        self.seconds, self.start_s, self.every_n_epochs = seconds, start_s, every_n_epochs

    def on_validation_epoch_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        if trainer.sanity_checking or trainer.current_epoch % self.every_n_epochs:
            return
        experiment = getattr(trainer.logger, "experiment", None)
        if experiment is None or not hasattr(experiment, "add_figure"):
            return
        dm = trainer.datamodule
        record = dm.records("val")[0]
        first = int(min(self.start_s, max(record.duration_s - self.seconds, 0)) / dm.dt)
        stretch = slice(first, first + int(self.seconds / dm.dt) + 1)
        norm, model = dm.normalization, module.model
        u = torch.as_tensor(norm.normalize(record.stack(dm.input_names)[stretch], dm.input_names))
        y = record.stack(dm.state_names)[stretch]
        x0 = torch.as_tensor(norm.normalize(y[:1], dm.state_names))
        with torch.no_grad():
            signals = model.signals(u[None].to(module.device, torch.float32), x0.to(module.device, torch.float32))
            pred = model.outputs(signals)[0].cpu()
        time = record.time[stretch]
        predicted = {n: model.to_physical(n, pred[:, i]).numpy() for i, n in enumerate(dm.state_names)}
        measured = {n: y[1:, i] for i, n in enumerate(dm.state_names)}
        fig = time_series(time[1:], measured, {model.spec.name: predicted}, units=UNITS,
                          scale={n: DEG for n in measured}, title=f"epoch {trainer.current_epoch}: free run")
        experiment.add_figure("val/states", fig, trainer.global_step, close=True)
        if "rear_wheel_angle" in signals and "rear_wheel_angle" in record:
            values, start = signals["rear_wheel_angle"]
            learned = model.to_physical("rear_wheel_angle", values[0, :, 0]).cpu().numpy()
            n = len(learned)
            fig = time_series(time[start : start + n], {"rear_wheel_angle": record["rear_wheel_angle"][stretch][start : start + n]},
                              {f"{model.spec.name} (learned)": {"rear_wheel_angle": learned}}, units=UNITS,
                              scale={"rear_wheel_angle": DEG}, title="implicitly learned rear-wheel angle")
            experiment.add_figure("val/rear_wheel_angle", fig, trainer.global_step, close=True)
