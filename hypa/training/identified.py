"""Physics fitted by identification instead of gradient epochs (``identification.enabled=true``).

- A model without networks has its trainable physical parameters identified by their output
  error over the training records (:func:`hypa.identification.identify`: trust-region least
  squares, deterministic), then validated once and saved as the run's best checkpoint, so every
  reader of the run (``hypa.evaluate``, ``hypa.explain``, the benchmark) sees the identified model.
- A staged hybrid whose first stage trains physics only, with every network bypassed (the
  residual hybrids: ``silverbox_hybrid``, ``emps_hybrid``, ``racecar_hybrid``), has that stage
  identified the same way; the later stages then train their networks on the identified physics.

The report goes to ``identification.md``, ``run.json`` (``identification``) and TensorBoard (text
and the parameters as ``physics/<name>``).
"""

from __future__ import annotations

import logging
from typing import Any

import lightning as L
from lightning.pytorch.loggers import TensorBoardLogger

from hypa.data import HypaDataModule
from hypa.identification import Identification, IdentificationError, IdentificationSettings, Stretches, identify
from hypa.metadata import sha256
from hypa.models.spec import StageSpec
from hypa.training.divergence import DivergedError
from hypa.training.module import HybridModule
from hypa.training.run_folder import RunFolder, write_text_atomic

log = logging.getLogger(__name__)


def identifiable(module: HybridModule) -> bool:
    """A model without networks and with trainable physical parameters."""
    model = module.model
    return bool(model.trainable_physics) and not any(b.kind == "ann" for b in model.spec.blocks)


def identifiable_stage(module: HybridModule, stage: StageSpec) -> bool:
    """A stage that trains physics blocks only, with every network bypassed: an identification problem."""
    blocks = {b.name: b for b in module.model.spec.blocks}
    anns = {name for name, b in blocks.items() if b.kind == "ann"}
    return bool(stage.train) and not anns & set(stage.train) and anns <= set(stage.bypass)


def identify_stage(module: HybridModule, stage: StageSpec, dm: HypaDataModule, folder: RunFolder,
                   settings: IdentificationSettings, logger: TensorBoardLogger) -> Identification:
    """Identify the physics of ``stage`` (its networks bypassed) and report it; the later stages train on it."""
    module.model.set_stage(stage.train, stage.bypass)
    return _identify(module, dm, folder, settings, logger)


def _identify(module: HybridModule, dm: HypaDataModule, folder: RunFolder, settings: IdentificationSettings,
              logger: TensorBoardLogger) -> Identification:
    stretch = len(max(dm.records("train"), key=len)) if settings.stretch_s is None else \
        max(1, round(settings.stretch_s / dm.dt))
    stretches = Stretches.cut(dm, dm.records("train"), stretch)
    result = identify(module.model, stretches, settings=settings, progress=lambda text: log.info("%s", text))
    print(result.summary(), flush=True)
    for warning in result.warnings:
        print(f"  warning: {warning}", flush=True)
    write_text_atomic(folder.path / "identification.md", result.markdown())
    folder.update_record(identification=result.to_dict())
    experiment = logger.experiment
    experiment.add_text("identification", result.markdown().replace("\n", "  \n"), 0)
    for name, value in result.values().items():
        experiment.add_scalar(f"physics/{name}", value, 0)
    return result


def fit_by_identification(trainer: L.Trainer, module: HybridModule, dm: HypaDataModule, folder: RunFolder,
                          settings: IdentificationSettings, logger: TensorBoardLogger) -> dict[str, Any]:
    """Identify, validate once, save the checkpoint and record it; returns the run's result fields."""
    result = _identify(module, dm, folder, settings, logger)
    module.model.parameters_.set_trainable(None, False)  # the identified values are the run's
    try:
        validated = trainer.validate(module, datamodule=dm, verbose=False)[0]
    except DivergedError:
        raise IdentificationError(f"the identified model predicts non-finite values on the validation data "
                                  f"({', '.join(result.warnings) or 'no warning from the fit'}); its report: "
                                  f"{folder.path / 'identification.md'}") from None
    val_loss = float(validated["val/loss"])
    best, last = folder.checkpoints / "best-identified.ckpt", folder.checkpoints / "last.ckpt"
    for path in (best, last):  # the full checkpoint (second argument: not weights only), as ModelCheckpoint writes it
        trainer.save_checkpoint(path, False)
    folder.update_record(best_checkpoint={"path": folder.relative(best), "val_loss": val_loss, "epoch": 0,
                                          "sha256": sha256(best)}, last_checkpoint=folder.relative(last))
    return {"best_val_loss": val_loss, "checkpoint": str(best), "last_checkpoint": str(last), "epochs": 0,
            "identification": result}
