"""The LightningModule: loss, optimizer and metrics around a composed model (no physics here)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import lightning as L
import torch
from torch import Tensor, nn
from torchmetrics import MeanAbsoluteError, MeanSquaredError, MetricCollection, PearsonCorrCoef, R2Score

from hypa.data import DataSignature, HypaDataModule
from hypa.models import ComposedModel, ModelSpec, ModelSpecError, parse_model_spec, spec_config
from hypa.models.building import model_hold
from hypa.models.memo import FrozenMemo
from hypa.training.baseline import NETWORK_LR, PHYSICS_LR


class HybridModule(L.LightningModule):
    """Trains a :class:`ComposedModel` with MSE on the normalized outputs (paper, Sec. 5).

    Build one with :meth:`from_data` (the data module or its :class:`~hypa.data.DataSignature`
    and a model config). The constructor is the checkpoint's form: everything needed to rebuild
    the model is a plain, serializable argument, so ``HybridModule.load_from_checkpoint(path)``
    restores the model with its normalization.

    Args:
        model_config: the model, parsed (a :class:`ModelSpec`) or as the ``model`` config group (blocks,
            outputs, stages) in a plain dict; the checkpoint stores the plain dict.
        physical_values: nominal physical parameters by name (SI units); ``None``: the systems'
            nominal values.
        normalization: training-set statistics (``Normalization.state_dict()``).
        input_names / output_names: measured inputs and outputs (targets) in data order.
        eval_names: SI evaluation channels present in validation batches (never trained on);
            a model signal of the same name (an implicitly learned rear-wheel angle) is
            compared with them.
        dt: sample time [s]; horizon: lifted steps N per matrix product (the data's window unless
            ``physics.horizon`` says otherwise).
        hold: ``zoh`` | ``foh`` of a model whose spec fixes none (``None``: ``zoh``). Checkpoints
            hold the run's ``physics.hold`` here even for a model with its own ``hold:``, which is
            what it trained with, so here the spec's wins; :meth:`from_data` refuses a conflict.
        ann_name / ann_hparams: the network of every ANN block.
        lr: NAdam learning rate of the networks; physics_lr: of the physical parameters
            (they live in log space, where a step is relative, so they take a larger one).
        weight_decay: NAdam weight decay of the networks.
        scheduling_names: measured scheduling signals (SI, in the batches' ``s``).
        past: P, samples before each window's start that may start the model.
    """

    def __init__(
        self,
        model_config: Mapping[str, Any] | ModelSpec,
        physical_values: Mapping[str, float] | None,
        normalization: Mapping[str, Any],
        input_names: Sequence[str],
        output_names: Sequence[str],
        eval_names: Sequence[str] = (),
        dt: float = 1 / 32,
        horizon: int = 100,
        hold: str | None = None,
        ann_name: str = "lstm",
        ann_hparams: Mapping[str, Any] | None = None,
        lr: float = NETWORK_LR,
        physics_lr: float = PHYSICS_LR,
        weight_decay: float = 0.0,
        scheduling_names: Sequence[str] = (),
        past: int = 0,
    ) -> None:
        super().__init__()
        # a spec (from_data) is kept as it is; the checkpoint stores its plain config (read back as data)
        spec = model_config if isinstance(model_config, ModelSpec) else parse_model_spec(model_config)
        self.save_hyperparameters(ignore=["model_config"])
        self.hparams["model_config"] = spec_config(spec) if isinstance(model_config, ModelSpec) else dict(model_config)
        # the checkpoint stores no data window: the horizon stands in (the model takes the horizon only)
        data = DataSignature(input_names, output_names, normalization, dt, horizon, past, eval_names, scheduling_names)
        self.model = ComposedModel.from_data(data, spec, physical_values, horizon=horizon,
                                             hold=None if spec.hold else hold, ann_name=ann_name,
                                             ann_hparams=ann_hparams)
        self.output_names, self.eval_names, self.past = data.output_names, data.eval_names, data.past
        self._check_past()
        self.loss = nn.MSELoss()
        per_output = lambda: MetricCollection({"mae": MeanAbsoluteError(), "mse": MeanSquaredError(),  # noqa: E731
                                               "r2": R2Score()})
        self.val_metrics = nn.ModuleDict({n: per_output() for n in self.output_names})
        internal = {b_out for b in self.model.spec.blocks for b_out in b.outputs} - set(self.output_names)
        self.compared = tuple(n for n in self.eval_names if n in internal)  # learned vs measured
        self.signal_metrics = nn.ModuleDict({n: MetricCollection({"corr": PearsonCorrCoef(),
                                                                  "rmse": MeanSquaredError(squared=False)})
                                             for n in self.compared})

    @classmethod
    def from_data(
        cls,
        data: DataSignature | HypaDataModule,
        model_config: Mapping[str, Any] | ModelSpec,
        *,
        physical_values: Mapping[str, float] | None = None,
        horizon: int | None = None,
        hold: str | None = None,
        ann_name: str = "lstm",
        ann_hparams: Mapping[str, Any] | None = None,
        lr: float = NETWORK_LR,
        physics_lr: float = PHYSICS_LR,
        weight_decay: float = 0.0,
    ) -> HybridModule:
        """The module of ``model_config`` (a ``conf/model`` dict or a :class:`ModelSpec`) on
        ``data`` (a data module after ``setup()`` or its :class:`~hypa.data.DataSignature`): the
        channels, normalization, dt [s] and past P come from the data.

        ``physical_values``: nominal physical parameters [SI] (``None``: the systems' own);
        ``horizon``: lifted steps N (``None``: the data's window); ``hold``: for a model whose
        spec fixes none (``None``: the spec's, else ``zoh``; a different one than the spec's is a
        ``ModelSpecError``); the rest as in the class.
        """
        data = DataSignature.of(data)
        # a spec travels as it is (stored as its config); a config is stored as given
        given = model_config if isinstance(model_config, ModelSpec) else dict(model_config)
        spec = given if isinstance(given, ModelSpec) else parse_model_spec(given)
        return cls(
            model_config=given, physical_values=None if physical_values is None else dict(physical_values),
            normalization=data.normalization.state_dict(), input_names=list(data.input_names),
            output_names=list(data.output_names), eval_names=list(data.eval_names), dt=data.dt,
            horizon=data.window if horizon is None else int(horizon), hold=model_hold(spec, hold),
            ann_name=ann_name, ann_hparams=None if ann_hparams is None else dict(ann_hparams), lr=lr,
            physics_lr=physics_lr, weight_decay=weight_decay, scheduling_names=list(data.scheduling_names),
            past=data.past,
        )

    def _check_past(self) -> None:
        """A state estimated from the past needs at least as many measured values as states."""
        for name, past in self.model.past_needed().items():
            if self.past < past:
                states = self.model.blocks[name].model.n_states
                seen = sum(m is not None for m in self.model.starts[name].observed) * (self.past + 1)
                raise ModelSpecError(f"block {name!r} estimates its {states} states from {seen} measured value(s) "
                                     f"(data.past={self.past}): too few to determine them; set data.past to at least "
                                     f"{past} (more for noisy data)")

    def on_fit_start(self) -> None:
        # while a stage trains networks only, the frozen physics' outputs of each window are kept
        # (hypa.models.memo): computed in the first epoch, read in the later ones
        self.model.memo = FrozenMemo()

    def on_fit_end(self) -> None:
        self.model.memo = None

    def forward(self, u: Tensor, y_past: Tensor, s: Tensor | None = None) -> Tensor:
        """Normalized predicted outputs (B, L-P-1, p) from inputs (B, L, m), measured outputs
        up to the window start (B, P+1, p) and scheduling signals (B, L, q)."""
        return self.model(u, y_past, s)

    def training_step(self, batch: dict[str, Tensor], batch_idx: int) -> Tensor:
        y, start = batch["y"], self.past + 1
        loss = self.loss(self(batch["u"], y[:, :start], batch.get("s")), y[:, start:])
        self.log("train/loss", loss, on_step=True, on_epoch=True, prog_bar=True, batch_size=y.shape[0], sync_dist=True)
        return loss

    def validation_step(self, batch: dict[str, Tensor], batch_idx: int) -> None:
        u, y, first = batch["u"], batch["y"], self.past + 1
        signals = self.model.signals(u, y[:, :first], batch.get("s"))
        pred = self.model.outputs(signals, self.past)
        # sync_dist: across processes (trainer.strategy=ddp) the mean over every rank's share of the validation
        # windows, so early stopping, the stages and the best checkpoint decide the same on every rank
        self.log("val/loss", self.loss(pred, y[:, first:]), prog_bar=True, batch_size=y.shape[0], sync_dist=True)
        for i, name in enumerate(self.output_names):  # metrics in SI units
            p = self.model.to_physical(name, pred[..., i]).flatten()
            t = self.model.to_physical(name, y[:, first:, i]).flatten()
            self.val_metrics[name].update(p, t)
        # (not in the sanity check: a zero-initialized learned signal has no variance to correlate)
        if self.trainer.sanity_checking:
            return
        for name in self.compared:
            values, start = signals[name]
            learned = self.model.to_physical(name, values[..., 0])
            measured = batch["eval"][:, start : start + learned.shape[1], self.eval_names.index(name)]
            self.signal_metrics[name].update(learned.flatten().float(), measured.flatten().float())

    def on_validation_epoch_end(self) -> None:
        for name, metrics in self.val_metrics.items():
            self.log_dict({f"val/{name}/{k}": v for k, v in metrics.compute().items()}, sync_dist=True)
            metrics.reset()
        for name, metrics in self.signal_metrics.items():
            if metrics["rmse"].update_count:
                self.log_dict({f"val/{name}/{k}": v for k, v in metrics.compute().items()}, sync_dist=True)
                metrics.reset()
    def on_train_epoch_end(self) -> None:
        params = self.model.parameters_
        for name in self.model.trainable_physics:
            self.log(f"physics/{name}", params.value(name).detach().float(), sync_dist=True)

    def configure_optimizers(self) -> torch.optim.Optimizer:
        # Every parameter is handed over, frozen ones too: a staged training only flips
        # requires_grad, and NAdam skips parameters without gradients.
        physics = list(self.model.parameters_.parameters())
        ids = {id(p) for p in physics}
        networks = [p for p in self.model.parameters() if id(p) not in ids]
        groups = [{"params": networks, "lr": self.hparams.lr, "weight_decay": self.hparams.weight_decay},
                  {"params": physics, "lr": self.hparams.physics_lr, "weight_decay": 0.0}]
        return torch.optim.NAdam([g for g in groups if g["params"]])
