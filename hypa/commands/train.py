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
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import lightning as L
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from hypa.commands.config import TrainConfig, hydra_command, model_node, typed
from hypa.core.errors import UserError, settings

if TYPE_CHECKING:
    from hypa.data import HypaDataModule
    from hypa.models import ModelSpec

log = logging.getLogger(__name__)


@dataclass
class Request:
    """A training run as its configuration asks for it, every value checked before any data are
    read (:func:`resolve`)."""

    config: TrainConfig
    model_config: dict[str, Any]  # the model, read once (model= or model_file=)
    spec: ModelSpec
    ann_name: str
    ann: dict[str, Any]
    physical_values: dict[str, float]
    identification: Any  # IdentificationSettings, or None: no identification
    callbacks: list[L.Callback]  # the user's own (callbacks=)
    out: Path  # the run folder
    ckpt_path: Path | None  # a checkpoint to resume from
    zero: bool  # this process owns the run folder (the only process, or rank 0 of several)
    distributed: bool


@dataclass
class Prepared:
    """The data and the model of a run, with what the data chose: the settings left null, the hold
    (``recorded``: dotted key -> value, what the run's ``config.yaml`` records beside the overrides)."""

    dm: HypaDataModule
    module: Any  # HybridModule
    how: str | None  # the identification's plan (hypa.training.identified.plan)
    stages: list[Any]
    identified: Any  # an identification already done while choosing the hold
    weight_decay: float
    epochs: int
    patience: int
    recorded: dict[str, Any] = field(default_factory=dict)


def resolve(cfg: DictConfig, out: Path | None = None) -> Request:
    """The run the configuration asks for, checked (:mod:`hypa.commands.config`): a bad override, a
    model file that is not a model, a hold the model contradicts, a bad callback or strategy, or a
    checkpoint of another model fails here, before any data are read or generated. ``out``: the run
    folder (None: the one Hydra made for this command)."""
    from hydra.types import RunMode

    from hypa.commands.entry import from_cwd, network_settings, user_callbacks, vehicle_from_config
    from hypa.models import parse_model_spec
    from hypa.models.building import model_hold
    from hypa.models.spec import model_imports, read_model_file
    from hypa.training.checkpoints import load_module
    from hypa.training.distributed import launched_as_rank_zero, lightning_strategy

    config = typed(cfg, TrainConfig)
    # a model file is data: read through the model schema, it replaces model=
    model_config = read_model_file(from_cwd(config.model_file), config.trust) if config.model_file else \
        model_node(cfg)
    spec = parse_model_spec(model_config)
    model_hold(spec, config.physics.hold, "physics.hold")  # against the model's own: refused before the data
    ann_name, ann = network_settings(cfg.ann)
    with settings("vehicle"):
        physical_values = vehicle_from_config(cfg.vehicle).as_dict() if cfg.vehicle else {}
    callbacks = user_callbacks(config.callbacks)  # built before any data are read: a bad one fails first
    lightning_strategy(config.trainer.strategy, staged=False)  # ddp_spawn: refused before any data are read
    distributed = str(config.trainer.strategy).startswith("ddp")
    if distributed and HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN:
        raise UserError("trainer.strategy=ddp in a sweep (-m): Lightning starts the other ranks by running the "
                        "command line again, which would start the sweep again; train each configuration as "
                        "its own command")
    out, ckpt_path = Path(out if out is not None else HydraConfig.get().runtime.output_dir), None
    if config.ckpt_path and config.identification.start:
        raise UserError("identification.start with ckpt_path: a resumed run continues from its checkpoint's values; "
                        "give one of them")
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
    return Request(config, model_config, spec, ann_name, ann, physical_values, config.identification.settings(),
                   callbacks, out, ckpt_path, launched_as_rank_zero(), distributed)


def prepare(request: Request, cfg: DictConfig, folder: Any) -> Prepared:
    """The run's data and model (built in the held ``folder``): the data module for the model
    (``data.past`` null: chosen for it), the settings left null (an end-to-end network's from its
    training data, the fixed defaults otherwise), the module and, for a model that fixes no hold,
    the hold the data choose (identifying its physics under each)."""
    from hypa.commands.entry import data_dir_from_config, from_cwd, model_datamodule
    from hypa.core.metadata import run_metadata
    from hypa.training import HybridModule
    from hypa.training.baseline import network_defaults
    from hypa.training.identified import choose_hold, plan, start_values

    config = request.config
    with settings("testbench"):  # the test bench's settings build its data (files: a folder only)
        data_dir = data_dir_from_config(cfg)
    data = model_datamodule(cfg, data_dir, request.spec, request.physical_values)
    dm = data.dm
    ann, weight_decay, epochs, patience = network_defaults(
        request.spec, request.ann_name, request.ann, dm, config.optimizer.lr, config.optimizer.weight_decay,
        config.trainer.max_epochs, config.patience, config.trainer.limit_train_batches, config.budget)
    if config.trainer.max_epochs is None and any(b.kind == "ann" for b in request.spec.blocks) and request.zero:
        other = "full" if config.budget == "short" else "short"
        print(f"networks: at most {epochs} epoch(s){' per stage' if len(request.spec.stages) > 1 else ''}, "
              f"patience {patience} (budget={config.budget}; budget={other} for "
              f"{'the longer' if other == 'full' else 'the shorter'} one, or set trainer.max_epochs)", flush=True)
    recorded = {**data.recorded(),  # a chosen data.past, the auxiliary channels the model reads as inputs
                "optimizer.weight_decay": weight_decay, "trainer.max_epochs": epochs,
                "early_stopping.patience": patience, **{f"ann.{k}": v for k, v in ann.items()}}
    # where the data were, resolved, so hypa evaluate finds them from any working directory; what
    # the run was made from (code, packages, data checksums), so hypa evaluate notices other data
    folder.update_record(data_dir=str(data_dir.resolve()), **run_metadata(dm.files, data_dir))

    start, started = None, {}
    if config.identification.start:
        start = from_cwd(config.identification.start)
        log.info("identification: starting from the values %s identified", start)

    def build(with_hold: str | None) -> HybridModule:  # channels, normalization, dt and past from the data module
        module = HybridModule.from_data(
            dm, request.spec, physical_values=request.physical_values, horizon=config.horizon,
            hold=with_hold,  # physics.hold: for a model without its own hold (one that contradicts it is refused)
            ann_name=request.ann_name, ann_hparams=ann, lr=config.optimizer.lr,
            physics_lr=config.optimizer.physics_lr, weight_decay=weight_decay)
        if start is not None:  # another run's identified values, read once as data, checked against this model
            parameters = module.model.parameters_
            if not started:
                started.update(start_values(start, parameters))
            parameters.set_values(started)
        return module

    hold, stages = config.physics.hold, list(request.spec.stages)
    module, identified = build(hold), None
    if not any(p.requires_grad for p in module.parameters()):  # no network, no physical parameter to fit
        name = request.spec.name
        raise UserError(f"model {name!r} has nothing to train (no network and no trainable physical parameter): "
                        f"run it at its values with hypa simulate model={name}, or name the parameters to identify "
                        "in a block's trainable:")
    how = plan(module, stages) if request.identification is not None and request.ckpt_path is None else None
    if how is not None and hold is None and request.spec.hold is None:  # no hold given: the data choose it
        if request.distributed:
            log.info("physics.hold is not set: zoh (across processes the data do not choose it; set it)")
        elif request.zero:
            module, identified, choice = choose_hold(build, how, stages, dm, request.identification)
            print(choice.line(), flush=True)
            folder.update_record(hold=choice.to_dict())
            recorded["physics.hold"] = choice.chosen  # what every later command rebuilds
    return Prepared(dm, module, how, stages, identified, weight_decay, epochs, patience, recorded)


def recorded_config(cfg: DictConfig, request: Request, prepared: Prepared) -> DictConfig:
    """The run's configuration as ``config.yaml`` records it: the composed one, the model that was
    read, and what the data chose (the input ``cfg`` itself is left as it was)."""
    from hypa.models.schema import ModelConfig

    recorded = cfg.copy()
    if request.config.model_file:  # the model the file held, as the run read it
        recorded.model = OmegaConf.merge(OmegaConf.structured(ModelConfig), request.model_config)
    for key, value in prepared.recorded.items():
        OmegaConf.update(recorded, key, value)
    return recorded


def selection_metric(config: TrainConfig) -> str:
    """What chooses a run's epochs, its stages' best and its kept checkpoint: ``early_stopping.monitor``
    (``val/loss``, the windows; ``val/free_run``, free runs of the whole validation records;
    ``auto``, one of them chosen by a hybrid's identified physics, :mod:`hypa.training.free_run`; or any
    metric the module logs)."""
    return str(config.early_stopping.get("monitor") or "val/loss")


def resolved_monitor(request: Request, how: str | None, module: Any, dm: HypaDataModule) -> str:
    """The run's selection metric: ``early_stopping.monitor``, where it is ``auto`` chosen by a hybrid's
    identified physics (:func:`hypa.training.free_run.chosen_monitor`, said in one line), else ``val/loss``."""
    from hypa.training.free_run import AUTO, WINDOWS, chosen_monitor

    monitor = selection_metric(request.config)
    if monitor != AUTO:
        return monitor
    if how not in ("stage", "first") or request.distributed or request.ckpt_path is not None:
        return WINDOWS  # no identified physics to judge by here (across processes each rank would judge alone)
    chosen, windows, free = chosen_monitor(module, dm)
    print(f"epochs chosen by {chosen}: the identified physics' validation windows {windows:.3g} against its free "
          f"runs {free:.3g} (early_stopping.monitor=auto)", flush=True)
    return chosen


def lightning_trainer(request: Request, prepared: Prepared, stages: list[Any], cfg: DictConfig, logger: Any,
                      checkpoint: Any) -> L.Trainer:
    """The Lightning trainer of a run: its callbacks (finite losses, early stopping, the user's, the
    stages, the figures, the recorded checkpoint; epoch lines instead of the bar where the output is
    not a terminal) and ``cfg.trainer``'s arguments, with the epochs of every stage and the strategy
    the model needs."""
    from hydra.utils import instantiate

    from hypa.training import StagedTraining, ValidationFigures
    from hypa.training.checkpoints import AtomicCheckpointIO
    from hypa.training.distributed import SameModelOnEveryRank, lightning_strategy
    from hypa.training.divergence import StopOnNonFiniteLoss
    from hypa.training.free_run import FREE_RUN, FreeRunValidation
    from hypa.training.progress import EpochLines, wants_lines

    config, how = request.config, prepared.how
    lr, physics_lr = config.optimizer.lr, config.optimizer.physics_lr
    monitor = checkpoint.monitor  # the run's selection metric (auto resolved in fit)
    free_runs = [FreeRunValidation()] if monitor == FREE_RUN else []  # a diverged free run is a bad epoch, not the end
    callbacks: list[L.Callback] = [
        SameModelOnEveryRank(),
        StopOnNonFiniteLoss(hint=f"lower optimizer.lr={lr:g} or optimizer.physics_lr={physics_lr:g}"),
        *free_runs,
        instantiate(config.early_stopping, monitor=monitor, patience=prepared.patience, min_delta=config.min_delta,
                    **({"check_finite": False} if free_runs else {})),
        *request.callbacks,
    ]
    if stages:
        callbacks.append(StagedTraining(stages, max_epochs=prepared.epochs, monitor=monitor))
    if config.figures.enabled:
        figures = config.figures
        callbacks.append(ValidationFigures(figures.seconds, figures.start_s, figures.every_n_epochs))
    callbacks.append(checkpoint)
    trainer_args = OmegaConf.to_container(cfg.trainer, resolve=True)  # with any +trainer.<Lightning argument>
    if not trainer_args.get("enable_progress_bar", True) or wants_lines():  # no bar (turned off; a file, a pipe): lines
        trainer_args["enable_progress_bar"] = False
        callbacks.insert(0, EpochLines(monitor=monitor))  # before the stages: the line is of the stage it trained
    trainer_args["max_epochs"] = prepared.epochs * max(len(stages), 1)
    if how == "model" and request.distributed:  # no epochs: one process validates the identified model
        log.info("physics-only model: identified and validated in one process (trainer.strategy=%s is for "
                 "epochs)", config.trainer.strategy)
        trainer_args.update(strategy="auto", devices=1, num_nodes=1)
    elif how != "model":  # a stage leaves networks or fixed physical parameters unused: DDP must be told
        unused = bool(stages) or any(not p.requires_grad for p in prepared.module.parameters())
        trainer_args["strategy"] = lightning_strategy(trainer_args.get("strategy", "auto"), staged=unused)
    with settings("trainer"):  # passed to Lightning as given: its ValueError / TypeError is the user's
        return L.Trainer(**trainer_args, callbacks=callbacks, logger=logger, default_root_dir=str(request.out),
                         plugins=[AtomicCheckpointIO()])


def fit(request: Request, prepared: Prepared, cfg: DictConfig, folder: Any, logger: Any) -> dict[str, Any]:
    """Train the prepared model: a hybrid's physics identified first, then its networks for the
    configured epochs; a physics-only model identified (no epochs). Returns the best validation
    loss, the checkpoints, the epochs and the time (``cfg``: the recorded configuration)."""
    from hypa.training.checkpoints import START_CHECKPOINT, RecordedCheckpoint
    from hypa.training.divergence import DivergedError
    from hypa.training.identified import fit_by_identification, identified_elsewhere, identify_physics

    module, how, stages, dm = prepared.module, prepared.how, prepared.stages, prepared.dm
    started = time.perf_counter()
    if how in ("stage", "first"):  # a hybrid: its physics identified, then its networks train on it
        if request.zero:
            identify_physics(module, how, stages, dm, folder, request.identification, logger, prepared.identified)
        else:  # rank 0's values arrive when training starts (SameModelOnEveryRank)
            identified_elsewhere(module, how, stages)
        stages = stages[1:] if how == "stage" else stages
    elif how == "model" and not request.zero:  # started by torchrun or SLURM: rank 0 identifies alone, without epochs
        log.info("physics-only model: identified by rank 0 alone")
        return {"best_val_loss": math.nan}
    checkpoint = RecordedCheckpoint(folder, monitor=resolved_monitor(request, how, module, dm))
    trainer = lightning_trainer(request, prepared, stages, cfg, logger, checkpoint)
    log.info("model %s", module.model.extra_repr())  # its wiring in one line; every module with its values:
    log.debug("model %s:\n%s", request.model_config["name"], module.model)
    if how == "model":
        result = fit_by_identification(trainer, module, dm, folder, request.identification, logger,
                                       prepared.identified, monitor=checkpoint.monitor)
        result["ended"] = "identification"
    else:
        kept_start = how in ("stage", "first") and request.ckpt_path is None and not request.distributed
        if kept_start:
            start = checkpoint.keep_the_start(trainer, module, dm)  # the networks must beat the physics
            log.info("before the networks' first epoch (the identified physics): %s %.5g", checkpoint.monitor, start)
        try:
            with warnings.catch_warnings():
                if kept_start:  # Lightning's warning of a folder it did not write: best-start.ckpt is this run's
                    warnings.filterwarnings("ignore", message="Checkpoint directory .* exists and is not empty")
                trainer.fit(module, datamodule=dm, ckpt_path=request.ckpt_path, weights_only=True)
        except DivergedError as error:
            best = folder.record.get("best_checkpoint")
            kept = (f"the best checkpoint before it (epoch {best['epoch']}, {checkpoint.monitor} "
                    f"{best['val_loss']:.5g}) stays the run's record" if best else "no checkpoint was recorded")
            folder.update_record(stopped=str(error), training_time_s=time.perf_counter() - started)
            raise DivergedError(f"{error}; {kept}") from None
        finally:  # what the fit kept of the frozen physics (hypa.models.memo) ends with it, however it ends
            module.model.memo = None
        if trainer.interrupted:  # Ctrl-C: Lightning stops gracefully; the run is not finished, say how to go on
            folder.update_record(stopped=f"interrupted at epoch {trainer.current_epoch}")
            log.warning("interrupted at epoch %d; resume with ckpt_path=%s", trainer.current_epoch,
                        folder.checkpoints / "last.ckpt")
        best = checkpoint.best_model_score
        result = {"best_val_loss": float(best) if best is not None else float("nan"),
                  "checkpoint": checkpoint.best_model_path, "last_checkpoint": checkpoint.last_model_path,
                  "epochs": trainer.current_epoch, "ended": f"{trainer.current_epoch} epochs",
                  "interrupted": trainer.interrupted}
        if Path(checkpoint.best_model_path).name == START_CHECKPOINT:
            result["ended"] += "; no epoch beat the model it started from (the identified physics), which the run keeps"
    result.update(tensorboard=str(request.out / "tensorboard"), training_time_s=time.perf_counter() - started,
                  monitor=checkpoint.monitor)
    return result


def train(cfg: DictConfig, out: Path | None = None) -> dict[str, Any]:
    """Fit the configured model (:func:`resolve`, :func:`prepare`, :func:`fit`) in its own run
    folder ``out`` (None: the one Hydra made for this command; another is a run of its own, without
    Hydra's record ``.hydra/``); returns the best validation loss and the output paths."""
    from hydra.utils import instantiate

    from hypa.commands.entry import flat_hparams
    from hypa.commands.output_folder import record_training_run
    from hypa.training.distributed import join_rank_zero_log
    from hypa.training.run_folder import CONFIG_FILE, RunFolder, write_text_atomic

    request = resolve(cfg, out)
    out, zero, config = request.out, request.zero, request.config
    with settings("logger"):
        logger = instantiate(config.logger, save_dir=str(out))
    # one run, one folder: refused before any data are read; the other ranks of a run across processes follow it
    with RunFolder.claim(out, resume=request.ckpt_path) if zero else RunFolder.follow(out) as folder:
        if zero:
            record_training_run(folder, request.ckpt_path)  # Hydra's .hydra/, now that the folder is held
        else:
            join_rank_zero_log(out)
        if request.ckpt_path is not None:
            log.info("resuming %s in %s", request.ckpt_path.name, out)
        L.seed_everything(config.seed, workers=True)
        torch.set_num_threads(config.torch_threads)
        os.environ.setdefault("OMP_NUM_THREADS", str(config.torch_threads))  # else Lightning's ddp sets cores / ranks
        prepared = prepare(request, cfg, folder)
        recorded = recorded_config(cfg, request, prepared)
        if folder.writer:  # written once, while this process holds the folder (a refused second run may
            # already have overwritten Hydra's .hydra/config.yaml)
            write_text_atomic(out / CONFIG_FILE, OmegaConf.to_yaml(recorded, resolve=True))
        result = fit(request, prepared, recorded, folder, logger)
        if "training_time_s" not in result:  # a rank > 0 of a physics-only model: rank 0 identifies
            return result
        folder.update_record(training_time_s=result["training_time_s"], best_val_loss=result["best_val_loss"])
        logger.log_hyperparams(flat_hparams(OmegaConf.to_container(recorded, resolve=True)),
                               {"hp/best_val_loss": result["best_val_loss"]})
        logger.finalize("success")  # written now: after fit, nothing else flushes it before the process ends
    if not zero:
        return result
    print(f"best {result['monitor']} {result['best_val_loss']:.5g} after {result['ended']}\n"
          f"checkpoint:  {result['checkpoint']}\n"
          f"tensorboard: tensorboard --logdir {result['tensorboard']}")
    return result


def train_here(arguments: Sequence[str], out: Path, what: str = "training",
               error: type[UserError] = UserError) -> dict[str, Any]:
    """``hypa train ARGUMENTS`` in this process, into the run folder ``out``, from inside another
    command's Hydra job (the diagnosis trains its extension so): the arguments are composed with the
    running command's configuration search path (a ``--config-dir`` among them must be one the
    running command was given), the torch threads are restored afterwards. A failure is ``error``
    in one line that names ``what`` and the command to run it alone; Ctrl-C ends the training as it
    ends ``hypa train`` (Lightning's graceful stop, then the calling command's exit status 130)."""
    import shlex

    from hydra import compose

    from hypa.commands.config import register_configs
    from hypa.commands.entry import user_config_dirs
    from hypa.core.errors import one_line, user_error_types

    register_configs()  # the caller's command registered them already; cheap when so

    overrides, dirs, rest = [], [], list(arguments)
    while rest:
        word = rest.pop(0)
        if word == "--config-dir" and rest:
            dirs.append(Path(rest.pop(0)))
        else:
            overrides.append(word)
    alone = f"run it alone: python -m hypa train {' '.join(shlex.quote(a) for a in arguments)}"
    known = {d.resolve() for d in user_config_dirs()}
    missing = [str(d) for d in dirs if d.resolve() not in known]
    if missing:
        raise error(f"{what}: --config-dir {missing[0]} is not among this command's; {alone}")
    threads = torch.get_num_threads()
    try:
        result = train(compose(config_name="train", overrides=overrides), out)
    except user_error_types() as failure:
        raise error(f"{what} failed: {one_line(failure)}; {alone}") from failure
    finally:
        torch.set_num_threads(threads)
    if result.get("interrupted"):  # Ctrl-C between Lightning's epochs: the calling command stops too
        raise KeyboardInterrupt
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
