"""Physics fitted by identification instead of gradient epochs (``identification.enabled``, the default).

:func:`plan` says what the identification does for a model; every model with trainable
physical parameters gets one of:

- ``model``: a model without networks has its trainable physical parameters identified by their
  output error over the training records (:func:`hypa.identification.identify`: trust-region
  least squares, deterministic), then validated once and saved as the run's best checkpoint, so
  every reader of the run (``hypa.evaluate``, ``hypa.explain``, the benchmark) sees the
  identified model. No epochs.
- ``stage``: a staged hybrid whose first stage trains physics only, with every network bypassed
  (the residual hybrids: ``silverbox_hybrid``, ``emps_hybrid``, ``racecar_hybrid``), has that
  stage identified the same way; the later stages then train their networks on the identified
  physics.
- ``first``: any other hybrid whose networks can all be bypassed (each corrects a physics signal,
  ``residual_of``) has its physics identified with the networks bypassed before its configured
  training starts, so its networks start on the identified physics, never on the nominal one.
- ``None``: no trainable physical parameters, or a network feeds the physics (V1's rear
  steering): there is no physics-only model to identify, and the physics trains with the
  networks by epochs.

The report goes to ``identification.md``, ``run.json`` (``identification``) and TensorBoard (text
and the parameters as ``physics/<name>``).

Across processes (``trainer.strategy=ddp``) rank 0 alone identifies; the other ranks take the
same stage settings with :func:`identified_elsewhere` and receive rank 0's values when training
starts (:class:`hypa.training.distributed.SameModelOnEveryRank`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any, Literal

import lightning as L
from lightning.pytorch.loggers import Logger

from hypa.data import HypaDataModule
from hypa.identification import Identification, IdentificationError, IdentificationSettings, identify_records
from hypa.metadata import sha256
from hypa.models.spec import StageSpec
from hypa.training.divergence import DivergedError
from hypa.training.module import HybridModule
from hypa.training.run_folder import RunFolder, write_text_atomic

log = logging.getLogger(__name__)

Plan = Literal["model", "stage", "first"]


def plan(module: HybridModule, stages: Sequence[StageSpec]) -> Plan | None:
    """What the identification does for this model (see the module docstring)."""
    model = module.model
    if not model.trainable_physics:
        return None
    blocks = model.spec.blocks
    anns = {b.name for b in blocks if b.kind == "ann"}
    if not anns:
        return "model"
    first = stages[0] if stages else None
    if first is not None and first.train and not anns & set(first.train) and anns <= set(first.bypass):
        return "stage"
    if all(b.residual_of for b in blocks if b.kind == "ann"):
        return "first"
    return None


def identify_physics(module: HybridModule, how: Plan, stages: Sequence[StageSpec], dm: HypaDataModule,
                     folder: RunFolder, settings: IdentificationSettings,
                     logger: Logger) -> Identification:
    """Identify a hybrid's physics (``how``: ``stage`` or ``first``) and report it; the networks then
    train on it. ``stage`` leaves the first stage's settings (the trainer's stage callback sets the
    next); ``first`` restores every block to training with nothing bypassed."""
    model = module.model
    if how == "stage":
        model.set_stage(stages[0].train, stages[0].bypass)
        return _identify(module, dm, folder, settings, logger)
    anns = [b.name for b in model.spec.blocks if b.kind == "ann"]
    model.set_stage([b.name for b in model.spec.blocks if b.kind != "ann"], anns)
    try:
        return _identify(module, dm, folder, settings, logger)
    finally:
        model.set_stage(None)


def identified_elsewhere(module: HybridModule, how: Plan, stages: Sequence[StageSpec]) -> None:
    """On a rank > 0: the stage settings :func:`identify_physics` leaves (``how``: ``stage`` or
    ``first``), without identifying; the identified values come from rank 0 when training starts."""
    if how == "stage":
        module.model.set_stage(stages[0].train, stages[0].bypass)


def _identify(module: HybridModule, dm: HypaDataModule, folder: RunFolder, settings: IdentificationSettings,
              logger: Logger) -> Identification:
    result = identify_records(module.model, dm, dm.records("train"), settings,
                              progress=lambda text: log.info("%s", text))
    print(result.summary(), flush=True)
    for warning in result.warnings:
        print(f"  warning: {warning}", flush=True)
    write_text_atomic(folder.path / "identification.md", result.markdown())
    folder.update_record(identification=result.to_dict())
    experiment = getattr(logger, "experiment", None)
    if hasattr(experiment, "add_text"):  # TensorBoard: the report beside the scalars
        experiment.add_text("identification", result.markdown().replace("\n", "  \n"), 0)
    logger.log_metrics({f"physics/{name}": value for name, value in result.values().items()}, step=0)
    return result


def fit_by_identification(trainer: L.Trainer, module: HybridModule, dm: HypaDataModule, folder: RunFolder,
                          settings: IdentificationSettings, logger: Logger) -> dict[str, Any]:
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
