"""Train a HyPA-Net (or a baseline) on measured data.

    hypa train model=v2 ann=lstm                 # the paper's V2 on the default data
    hypa train model=physical                    # physics only, parameters fitted
    hypa train model=blackbox ann=transformer    # a pure network
    hypa train -m model=v1,v2,v3 ann=lstm,s4 seed=0,1,2     # a sweep (parallel)
    hypa train dataset=files data.dir=PATH vehicle.cf=...    # your data

    hypa train trainer.strategy=ddp trainer.devices=2            # across 2 processes (GPUs)

Writes the best and last checkpoints and TensorBoard logs into the Hydra run folder and prints
where; returns the best validation loss (for Hydra sweepers). Across processes rank 0 writes all
of it (:mod:`hypa.training.distributed`).
"""

from __future__ import annotations

import logging
import math
import os
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import lightning as L
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from hypa.commands.config import TrainConfig, typed
from hypa.core.errors import UserError, hydra_command, settings

log = logging.getLogger(__name__)


def run_name(model: str, ann: str, blocks: Any, model_file: str | None = None) -> str:
    """Folder name of a run: the model, and its network where it has one (``model_file``: the model
    that file holds; its own checks come when the run reads it)."""
    if model_file:
        from hypa.core.trust import read_yaml

        try:
            read = read_yaml(Path(model_file).expanduser())
            model, blocks = str(read.get("name", Path(model_file).stem)), read.get("blocks")
        except Exception:  # noqa: BLE001 -- a folder name only: the run reads the file and names what is wrong
            model, blocks = Path(str(model_file)).stem, None
    has_ann = any(hasattr(b, "get") and b.get("kind") == "ann" for b in (blocks or {}).values())  # dict or DictConfig
    name = f"{model}-{ann}" if has_ann else model
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)[:100] or "model"


def channels(*roles: str, _root_: DictConfig) -> list[str]:
    """``${channels:input,scheduling}``: the data set's channels with these roles, in declared order
    (so one model YAML, e.g. ``blackbox``, serves every data set)."""
    return [name for name, c in _root_.data.channels.items() if c.role in roles]


OmegaConf.register_new_resolver("run_name", run_name, replace=True)
OmegaConf.register_new_resolver("channels", channels, replace=True)


def train(cfg: DictConfig) -> dict[str, Any]:
    """Fit the configured model; returns the best validation loss and the output paths."""
    from hydra.types import RunMode

    from hypa.commands.entry import (
        data_dir_from_config,
        flat_hparams,
        from_cwd,
        model_datamodule,
        network_settings,
        user_callbacks,
        vehicle_from_config,
    )
    from hypa.commands.output_folder import record_training_run
    from hypa.core.metadata import run_metadata
    from hypa.models import parse_model_spec
    from hypa.models.building import model_hold
    from hypa.models.schema import ModelConfig, plain_model
    from hypa.models.spec import model_imports, read_model_file
    from hypa.training import HybridModule, StagedTraining, ValidationFigures
    from hypa.training.baseline import network_defaults
    from hypa.training.checkpoints import START_CHECKPOINT, AtomicCheckpointIO, RecordedCheckpoint, load_module
    from hypa.training.distributed import (
        SameModelOnEveryRank,
        join_rank_zero_log,
        launched_as_rank_zero,
        lightning_strategy,
    )
    from hypa.training.divergence import DivergedError, StopOnNonFiniteLoss
    from hypa.training.identified import (
        choose_hold,
        fit_by_identification,
        identified_elsewhere,
        identify_physics,
        plan,
    )
    from hypa.training.run_folder import CONFIG_FILE, RunFolder, write_text_atomic

    # every value checked first (hypa.commands.config), so a bad override fails before any data are read or generated
    config = typed(cfg, TrainConfig)
    lr, physics_lr, weight_decay = config.optimizer.lr, config.optimizer.physics_lr, config.optimizer.weight_decay
    epochs, patience = config.trainer.max_epochs, config.patience  # None: see network_defaults
    hold, horizon = config.physics.hold, config.horizon
    if config.model_file:  # a model file is data: read through the model schema, it replaces model=
        model_config = read_model_file(from_cwd(config.model_file), config.trust)
        cfg.model = OmegaConf.merge(OmegaConf.structured(ModelConfig), model_config)  # what the run records
    else:
        model_config = plain_model(OmegaConf.to_container(cfg.model, resolve=True))
    model_hold(parse_model_spec(model_config), hold, "physics.hold")  # against the model's own: refused before the data
    ann_name, ann = network_settings(cfg.ann)
    with settings("vehicle"):
        physical_values = vehicle_from_config(cfg.vehicle).as_dict() if cfg.vehicle else {}
    identification = config.identification.settings()
    extra_callbacks = user_callbacks(config.callbacks)  # built before any data are read: a bad one fails first
    lightning_strategy(config.trainer.strategy, staged=False)  # ddp_spawn: refused before any data are read
    zero = launched_as_rank_zero()  # the run's only process, or rank 0 of several: it owns the run folder
    distributed = str(config.trainer.strategy).startswith("ddp")
    if distributed and HydraConfig.get().mode == RunMode.MULTIRUN:
        raise UserError("trainer.strategy=ddp in a sweep (-m): Lightning starts the other ranks by running the "
                        "command line again, which would start the sweep again; train each configuration as "
                        "its own command")

    out, ckpt_path = Path(HydraConfig.get().runtime.output_dir), None
    if config.ckpt_path:
        ckpt_path = from_cwd(config.ckpt_path)
        if not ckpt_path.is_file():
            raise FileNotFoundError(f"ckpt_path={ckpt_path} does not exist")
        own = [*config.trust, *model_imports(model_config, ann_name).values()]  # what this command names is code
        resumed = load_module(ckpt_path, own).hparams.model_config.get("name")  # no hypa checkpoint: one line
        if resumed != model_config.get("name"):
            raise UserError(f"ckpt_path={ckpt_path} holds model {resumed}, not model={model_config.get('name')}; "
                            f"resume with model={resumed}")
        if ckpt_path.parent.name == "checkpoints":  # resume in the interrupted run's own folder
            out = ckpt_path.parent.parent
    with settings("logger"):
        logger = instantiate(config.logger, save_dir=str(out))
    # one run, one folder: refused before any data are read; the other ranks of a run across processes follow it
    with RunFolder.claim(out, resume=ckpt_path) if zero else RunFolder.follow(out) as folder:
        if zero:
            record_training_run(folder, ckpt_path)  # Hydra's .hydra/, now that the folder is held
        else:
            join_rank_zero_log(out)
        if ckpt_path is not None:
            log.info("resuming %s in %s", ckpt_path.name, out)
        L.seed_everything(config.seed, workers=True)
        torch.set_num_threads(config.torch_threads)
        os.environ.setdefault("OMP_NUM_THREADS", str(config.torch_threads))  # else Lightning's ddp sets cores / ranks
        with settings("testbench"):  # the test bench's settings build its data (files: a folder only)
            data_dir = data_dir_from_config(cfg)
        dm = model_datamodule(cfg, data_dir, model_config, physical_values)  # data.past null: chosen for the model
        # the settings left null: an end-to-end network's from its training data, the fixed defaults otherwise;
        # written into the run's configuration (what was trained, for hypa evaluate and TensorBoard)
        ann, weight_decay, epochs, patience = network_defaults(model_config, ann_name, ann, dm, lr, weight_decay,
                                                               epochs, patience, config.trainer.limit_train_batches)
        for key, value in (("optimizer.weight_decay", weight_decay), ("trainer.max_epochs", epochs),
                           ("early_stopping.patience", patience), *((f"ann.{k}", v) for k, v in ann.items())):
            OmegaConf.update(cfg, key, value)
        # where the data were, resolved, so hypa evaluate finds them from any working directory; what
        # the run was made from (code, packages, data checksums), so hypa evaluate notices other data
        folder.update_record(data_dir=str(data_dir.resolve()), **run_metadata(dm.files, data_dir))
        # the run's own resolved configuration, written while this process holds the folder (a refused
        # second run may already have overwritten Hydra's .hydra/config.yaml)
        if folder.writer:
            write_text_atomic(out / CONFIG_FILE, OmegaConf.to_yaml(cfg, resolve=True))
        def build(with_hold: str | None) -> HybridModule:  # channels, normalization, dt and past from the data module
            return HybridModule.from_data(
                dm, model_config, physical_values=physical_values, horizon=horizon,
                hold=with_hold,  # physics.hold: for a model without its own hold (one that contradicts it is refused)
                ann_name=ann_name, ann_hparams=ann, lr=lr, physics_lr=physics_lr, weight_decay=weight_decay,
            )

        module = build(hold)
        spec = parse_model_spec(model_config)
        stages = spec.stages
        started = time.perf_counter()
        how = plan(module, stages) if identification is not None and ckpt_path is None else None
        identified = None
        if how is not None and hold is None and spec.hold is None:  # no hold given: the data choose it
            if distributed:
                log.info("physics.hold is not set: zoh (across processes the data do not choose it; set it)")
            elif zero:
                module, identified, choice = choose_hold(build, how, stages, dm, identification)
                print(choice.line(), flush=True)
                folder.update_record(hold=choice.to_dict())
                OmegaConf.update(cfg, "physics.hold", choice.chosen)  # what every later command rebuilds
                if folder.writer:
                    write_text_atomic(out / CONFIG_FILE, OmegaConf.to_yaml(cfg, resolve=True))
        if how in ("stage", "first"):  # a hybrid: its physics identified, then its networks train on it
            if zero:
                identify_physics(module, how, stages, dm, folder, identification, logger, identified)
            else:  # rank 0's values arrive when training starts (SameModelOnEveryRank)
                identified_elsewhere(module, how, stages)
            stages = stages[1:] if how == "stage" else stages
        elif how == "model" and not zero:  # started by torchrun or SLURM: rank 0 identifies alone, without epochs
            log.info("physics-only model: identified by rank 0 alone")
            return {"best_val_loss": math.nan}
        checkpoint = RecordedCheckpoint(folder)
        callbacks: list[L.Callback] = [
            SameModelOnEveryRank(),
            StopOnNonFiniteLoss(hint=f"lower optimizer.lr={lr:g} or optimizer.physics_lr={physics_lr:g}"),
            instantiate(config.early_stopping, patience=patience, min_delta=config.min_delta),
            *extra_callbacks,
        ]
        if stages:
            callbacks.append(StagedTraining(stages, max_epochs=epochs))
        if config.figures.enabled:
            figures = config.figures
            callbacks.append(ValidationFigures(figures.seconds, figures.start_s, figures.every_n_epochs))
        callbacks.append(checkpoint)
        trainer_args = OmegaConf.to_container(cfg.trainer, resolve=True)  # with any +trainer.<Lightning argument>
        trainer_args["max_epochs"] = epochs * max(len(stages), 1)
        if how == "model" and distributed:  # no epochs: one process validates the identified model
            log.info("physics-only model: identified and validated in one process (trainer.strategy=%s is for "
                     "epochs)", config.trainer.strategy)
            trainer_args.update(strategy="auto", devices=1, num_nodes=1)
        elif how != "model":  # a stage leaves networks or fixed physical parameters unused: DDP must be told
            unused = bool(stages) or any(not p.requires_grad for p in module.parameters())
            trainer_args["strategy"] = lightning_strategy(trainer_args.get("strategy", "auto"), staged=unused)
        with settings("trainer"):  # passed to Lightning as given: its ValueError / TypeError is the user's
            trainer = L.Trainer(**trainer_args, callbacks=callbacks, logger=logger, default_root_dir=str(out),
                                plugins=[AtomicCheckpointIO()])
        log.info("model %s:\n%s", model_config["name"], module.model)
        if how == "model":
            result = fit_by_identification(trainer, module, dm, folder, identification, logger, identified)
            ended = "identification"
        else:
            kept_start = how in ("stage", "first") and ckpt_path is None and not distributed
            if kept_start:
                start = checkpoint.keep_the_start(trainer, module, dm)  # the networks must beat the physics
                log.info("before the networks' first epoch (the identified physics): val/loss %.5g", start)
            try:
                with warnings.catch_warnings():
                    if kept_start:  # Lightning's warning of a folder it did not write: best-start.ckpt is this run's
                        warnings.filterwarnings("ignore", message="Checkpoint directory .* exists and is not empty")
                    trainer.fit(module, datamodule=dm, ckpt_path=ckpt_path, weights_only=True)
            except DivergedError as error:
                best = folder.record.get("best_checkpoint")
                kept = (f"the best checkpoint before it (epoch {best['epoch']}, val/loss {best['val_loss']:.5g}) "
                        "stays the run's record" if best else "no checkpoint was recorded")
                folder.update_record(stopped=str(error), training_time_s=time.perf_counter() - started)
                raise DivergedError(f"{error}; {kept}") from None
            if trainer.interrupted:  # Ctrl-C: Lightning stops gracefully; the run is not finished, say how to go on
                folder.update_record(stopped=f"interrupted at epoch {trainer.current_epoch}")
                log.warning("interrupted at epoch %d; resume with ckpt_path=%s", trainer.current_epoch,
                            folder.checkpoints / "last.ckpt")
            best = checkpoint.best_model_score
            result = {"best_val_loss": float(best) if best is not None else float("nan"),
                      "checkpoint": checkpoint.best_model_path, "last_checkpoint": checkpoint.last_model_path,
                      "epochs": trainer.current_epoch}
            ended = f"{result['epochs']} epochs"
            if Path(checkpoint.best_model_path).name == START_CHECKPOINT:
                ended += "; no epoch beat the model it started from (the identified physics), which the run keeps"
        result.update(tensorboard=str(out / "tensorboard"), training_time_s=time.perf_counter() - started)
        folder.update_record(training_time_s=result["training_time_s"], best_val_loss=result["best_val_loss"])
        logger.log_hyperparams(flat_hparams(OmegaConf.to_container(cfg, resolve=True)),
                               {"hp/best_val_loss": result["best_val_loss"]})
        logger.finalize("success")  # written now: after fit, nothing else flushes it before the process ends
    if not zero:
        return result
    print(f"best val/loss {result['best_val_loss']:.5g} after {ended}\n"
          f"checkpoint:  {result['checkpoint']}\n"
          f"tensorboard: tensorboard --logdir {result['tensorboard']}")
    return result


@hydra_command("hypa train", "train")
def main(cfg: DictConfig) -> float:
    """The best validation loss, for sweepers; inf for a run without a finite one (diverged, or no
    validation): Optuna's sweeper aborts the whole study on a NaN, whereas inf ranks the trial last.
    In a sweep a diverged run says so in one line and ranks last; alone it is an error (exit status 1)."""
    from hydra.types import RunMode

    from hypa.training.divergence import DivergedError

    try:
        loss = train(cfg)["best_val_loss"]
    except DivergedError as error:
        if not HydraConfig.initialized() or HydraConfig.get().mode != RunMode.MULTIRUN:
            raise
        print(f"hypa train: {error}", file=sys.stderr, flush=True)
        return math.inf
    return loss if math.isfinite(loss) else math.inf


if __name__ == "__main__":
    sys.exit(main())
