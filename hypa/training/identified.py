"""Physics fitted by identification instead of gradient epochs (``identification.enabled``, the default).

:func:`plan` says what the identification does for a model; every model with trainable
physical parameters gets one of:

- ``model``: a model without networks has its trainable physical parameters identified by their
  output error over the training records (:func:`hypa.identification.identify`: trust-region
  least squares, deterministic), then validated once and saved as the run's best checkpoint, so
  every reader of the run (``hypa evaluate``, ``hypa.explain``, the benchmark) sees the
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

``identification.start=RUN`` starts the identification from the values another run identified
(:func:`start_values`: its ``run.json``'s numbers, read as data): a fit started at its optimum
settles in a few iterations (``hypa benchmark`` starts a hybrid's later seeds from its first
seed's physics, which no seed enters).

Across processes (``trainer.strategy=ddp``) rank 0 alone identifies; the other ranks take the
same stage settings with :func:`identified_elsewhere` and receive rank 0's values when training
starts (:class:`hypa.training.distributed.SameModelOnEveryRank`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import lightning as L
from lightning.pytorch.loggers import Logger

from hypa.core.errors import UserError
from hypa.core.metadata import sha256
from hypa.data import HypaDataModule
from hypa.identification import Identification, IdentificationError, IdentificationSettings, identify_records
from hypa.models.spec import StageSpec
from hypa.physics.parameters import PhysicalParameters
from hypa.training.divergence import DivergedError
from hypa.training.module import HybridModule
from hypa.training.run_folder import RunFolder, read_record, write_text_atomic

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
                     logger: Logger, result: Identification | None = None) -> Identification:
    """Identify a hybrid's physics (``how``: ``stage`` or ``first``) and report it; the networks then
    train on it. ``stage`` leaves the first stage's settings (the trainer's stage callback sets the
    next); ``first`` restores every block to training with nothing bypassed. ``result``: the
    identification already done on this module (:func:`choose_hold`), reported as it is."""
    model = module.model
    if how == "stage":
        model.set_stage(stages[0].train, stages[0].bypass)
        return _identify(module, dm, folder, settings, logger, result)
    _physics_only(module)
    try:
        return _identify(module, dm, folder, settings, logger, result)
    finally:
        model.set_stage(None)


def start_values(folder: Path, parameters: PhysicalParameters) -> dict[str, float]:
    """The values the run in ``folder`` identified (``run.json``'s ``identification.parameters``), to
    start this run's identification from (``identification.start``). Data: finite numbers only, each
    a trainable parameter of ``parameters`` (this model's) within its spec; anything else is refused
    in one line. Parameters the run did not identify keep the model's values."""
    where = f"identification.start={folder}"
    if not Path(folder).is_dir():
        raise UserError(f"{where}: not a folder (a hypa train run folder whose physics was identified)")
    record = read_record(Path(folder))
    identified = record.get("identification") if isinstance(record.get("identification"), dict) else {}
    found = identified.get("parameters")
    if not isinstance(found, dict) or not found:
        raise UserError(f"{where}: its run.json holds no identified parameters (a hypa train run whose physics was "
                        "identified)")
    values = {}
    for name, entry in found.items():
        value = entry.get("value") if isinstance(entry, dict) else None
        number = float(value) if isinstance(value, float) or (isinstance(value, int) and not isinstance(value, bool)
                                                              and abs(value) < 2**1023) else math.nan
        if not math.isfinite(number):
            raise UserError(f"{where}: the identified value of {str(name)[:80]!r} is not a finite number")
        values[str(name)] = number
    trainable = parameters.trainable_names
    foreign = [name[:80] for name in values if name not in trainable]
    if foreign:
        raise UserError(f"{where}: that run identified {', '.join(foreign[:5])}, which this model does not train "
                        f"(it trains {', '.join(trainable) or 'nothing'})")
    try:
        for name, value in values.items():
            parameters.specs[name].check(value)
    except ValueError as error:
        raise UserError(f"{where}: {error}") from None
    return values


def _physics_only(module: HybridModule) -> None:
    """Every network bypassed, every physics block trained (``first``)."""
    blocks = module.model.spec.blocks
    module.model.set_stage([b.name for b in blocks if b.kind != "ann"], [b.name for b in blocks if b.kind == "ann"])


@dataclass(frozen=True)
class HoldChoice:
    """The hold the data chose (:func:`choose_hold`): each hold's identified output error (mean 1 - R²)."""

    chosen: str
    errors: dict[str, float]

    def line(self) -> str:
        other = next(h for h in self.errors if h != self.chosen)
        return (f"hold: {self.chosen}, chosen by the data: the identified physics' output error is "
                f"{100 * self.errors[self.chosen]:.3g} % of the output variance under {_HOLD_NAMES[self.chosen]}, "
                f"{100 * self.errors[other]:.3g} % under {_HOLD_NAMES[other]} (physics.hold=zoh|foh|cubic, or the "
                "model's hold:, fixes it and saves the second fit)")

    def to_dict(self) -> dict[str, Any]:
        return {"chosen": self.chosen, "by": "identification", "output_error": dict(self.errors)}


_HOLD_NAMES = {"zoh": "a zero-order hold", "foh": "a first-order hold", "cubic": "a cubic hold"}


def choose_hold(build: Callable[[str], HybridModule], how: Plan, stages: Sequence[StageSpec], dm: HypaDataModule,
                settings: IdentificationSettings) -> tuple[HybridModule, Identification, HoldChoice]:
    """The hold of a model that fixes none, chosen by the data: the physics identified under a zero-order
    and under a first-order hold (``build(hold)`` gives each its module, with the stage settings
    :func:`identify_physics` uses), the one with the smaller output error over the training records
    kept (a tie: ``zoh``).

    How the inputs move between samples is a property of the data, not of the physics: a signal
    held by a digital controller over each sample is a zero-order hold, a smooth measured signal
    is closer to a first-order one, and the samples alone cannot tell. The two fits have the same
    parameters, so their training errors compare directly. Returns the kept module with its
    identified values, its identification (report it with ``result=``) and the choice.
    """
    fits = {}
    for hold in ("zoh", "foh"):
        log.info("identification under %s (physics.hold is not set: the data choose)", _HOLD_NAMES[hold])
        module = build(hold)
        model = module.model
        if how == "stage":
            model.set_stage(stages[0].train, stages[0].bypass)
        elif how == "first":
            _physics_only(module)
        try:
            fits[hold] = (module, identify_records(model, dm, dm.records("train"), settings,
                                                   progress=lambda text: log.info("%s", text)))
        finally:
            model.set_stage(None)
    errors = {hold: fit[1].error_final for hold, fit in fits.items()}
    chosen = "foh" if errors["foh"] < errors["zoh"] else "zoh"  # NaN (a failed fit) never wins
    module, result = fits[chosen]
    return module, result, HoldChoice(chosen, errors)


def identified_elsewhere(module: HybridModule, how: Plan, stages: Sequence[StageSpec]) -> None:
    """On a rank > 0: the stage settings :func:`identify_physics` leaves (``how``: ``stage`` or
    ``first``), without identifying; the identified values come from rank 0 when training starts."""
    if how == "stage":
        module.model.set_stage(stages[0].train, stages[0].bypass)


def _identify(module: HybridModule, dm: HypaDataModule, folder: RunFolder, settings: IdentificationSettings,
              logger: Logger, result: Identification | None = None) -> Identification:
    if result is None:
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
                          settings: IdentificationSettings, logger: Logger,
                          result: Identification | None = None, monitor: str = "val/loss") -> dict[str, Any]:
    """Identify (or report ``result``, done already), validate once, save the checkpoint and record it
    with its ``monitor`` (the run's selection metric); returns the run's result fields."""
    result = _identify(module, dm, folder, settings, logger, result)
    module.model.parameters_.set_trainable(None, False)  # the identified values are the run's
    try:
        validated = trainer.validate(module, datamodule=dm, verbose=False)[0]
    except DivergedError:
        raise IdentificationError(f"the identified model predicts non-finite values on the validation data "
                                  f"({', '.join(result.warnings) or 'no warning from the fit'}); its report: "
                                  f"{folder.path / 'identification.md'}") from None
    val_loss = float(validated[monitor] if monitor in validated else validated["val/loss"])
    best, last = folder.checkpoints / "best-identified.ckpt", folder.checkpoints / "last.ckpt"
    for path in (best, last):  # the full checkpoint (second argument: not weights only), as ModelCheckpoint writes it
        trainer.save_checkpoint(path, False)
    folder.update_record(best_checkpoint={"path": folder.relative(best), "val_loss": val_loss,
                                          "monitor": monitor if monitor in validated else "val/loss", "epoch": 0,
                                          "sha256": sha256(best)}, last_checkpoint=folder.relative(last))
    return {"best_val_loss": val_loss, "checkpoint": str(best), "last_checkpoint": str(last), "epochs": 0,
            "identification": result}
