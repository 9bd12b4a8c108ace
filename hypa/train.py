"""Train a HyPA-Net (or a baseline) on measured data.

    python -m hypa.train model=v2 ann=lstm                 # the paper's V2 on the default data
    python -m hypa.train model=physical                    # physics only, parameters fitted
    python -m hypa.train model=blackbox ann=transformer    # a pure network
    python -m hypa.train -m model=v1,v2,v3 ann=lstm,s4 seed=0,1,2     # a sweep (parallel)
    python -m hypa.train dataset=files data.dir=PATH vehicle.cf=...    # your data

Writes the best and last checkpoints and TensorBoard logs into the Hydra run folder and prints
where; returns the best validation loss (for Hydra sweepers).
"""

from __future__ import annotations

import logging
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import lightning as L
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from hypa.errors import UserError, hydra_command, setting, settings

if TYPE_CHECKING:
    from hypa.identification import IdentificationSettings

log = logging.getLogger(__name__)


def run_name(model: str, ann: str, blocks: Any) -> str:
    """Folder name of a run: the model, and its network where it has one."""
    has_ann = any(b.get("kind") == "ann" for b in (blocks or {}).values())
    return f"{model}-{ann}" if has_ann else model


def channels(*roles: str, _root_: DictConfig) -> list[str]:
    """``${channels:input,scheduling}``: the data set's channels with these roles, in declared order
    (so one model YAML, e.g. ``blackbox``, serves every data set)."""
    return [name for name, c in _root_.data.channels.items() if c.role in roles]


OmegaConf.register_new_resolver("run_name", run_name, replace=True)
OmegaConf.register_new_resolver("channels", channels, replace=True)


def train(cfg: DictConfig) -> dict[str, Any]:
    """Fit the configured model; returns the best validation loss and the output paths."""
    from hypa.data import datamodule_from_config
    from hypa.entry import data_dir_from_config, vehicle_from_config
    from hypa.metadata import run_metadata
    from hypa.models import parse_model_spec
    from hypa.physics import HOLDS
    from hypa.training import HybridModule, StagedTraining, ValidationFigures
    from hypa.training.baseline import network_defaults
    from hypa.training.checkpoints import AtomicCheckpointIO, RecordedCheckpoint, load_module
    from hypa.training.divergence import DivergedError, StopOnNonFiniteLoss
    from hypa.training.identified import fit_by_identification, identify_physics, plan
    from hypa.training.run_folder import CONFIG_FILE, RunFolder, write_text_atomic

    # every plain value first, so a bad override fails before any data are read or generated
    seed, threads = setting(cfg, "seed", int), setting(cfg, "torch_threads", int, minimum=1)
    epochs = setting(cfg, "trainer.max_epochs", int, optional=True, minimum=1)  # None: see network_defaults
    hold = setting(cfg, "physics.hold", str, choices=HOLDS)
    horizon = setting(cfg, "physics.horizon", int, optional=True) or setting(cfg, "data.window", int)
    lr, physics_lr = (setting(cfg, f"optimizer.{k}", float, positive=True) for k in ("lr", "physics_lr"))
    weight_decay = setting(cfg, "optimizer.weight_decay", float, optional=True, minimum=0.0)
    patience = setting(cfg, "early_stopping.patience", int, optional=True, minimum=0)
    min_delta = setting(cfg, "early_stopping.min_delta", float, minimum=0.0)
    model_config = OmegaConf.to_container(cfg.model, resolve=True)
    ann = OmegaConf.to_container(cfg.ann, resolve=True)
    ann_name = network_name(str(ann.pop("name")), ann.pop("_target_", None))
    check_ann_settings(ann_name, ann)
    with settings("vehicle"):
        physical_values = vehicle_from_config(cfg.vehicle).as_dict() if cfg.vehicle else {}
    identification = identification_settings(cfg)
    extra_callbacks = user_callbacks(cfg)  # built before any data are read: a bad one fails first

    out, ckpt_path = Path(HydraConfig.get().runtime.output_dir), None
    if cfg.ckpt_path:
        from hydra.utils import get_original_cwd

        ckpt_path = Path(str(cfg.ckpt_path)).expanduser()
        ckpt_path = ckpt_path if ckpt_path.is_absolute() else Path(get_original_cwd()) / ckpt_path
        if not ckpt_path.is_file():
            raise FileNotFoundError(f"ckpt_path={ckpt_path} does not exist")
        resumed = load_module(ckpt_path).hparams.model_config.get("name")  # no hypa checkpoint: one line
        if resumed != model_config.get("name"):
            raise UserError(f"ckpt_path={ckpt_path} holds model {resumed}, not model={model_config.get('name')}; "
                            f"resume with model={resumed}")
        if ckpt_path.parent.name == "checkpoints":  # resume in the interrupted run's own folder
            out = ckpt_path.parent.parent
    with settings("logger"):
        logger = instantiate(cfg.logger, save_dir=str(out))
    with RunFolder.claim(out, resume=ckpt_path) as folder:  # one run, one folder: refused before any data are read
        if ckpt_path is not None:
            log.info("resuming %s in %s", ckpt_path.name, out)
        L.seed_everything(seed, workers=True)
        torch.set_num_threads(threads)
        with settings("testbench"):  # the test bench's settings build its data (files: a folder only)
            data_dir = data_dir_from_config(cfg)
        dm = datamodule_from_config(cfg.data, data_dir)
        dm.setup()
        # the settings left null: an end-to-end network's from its training data, the fixed defaults otherwise;
        # written into the run's configuration (what was trained, for hypa.evaluate and TensorBoard)
        ann, weight_decay, epochs, patience = network_defaults(model_config, ann_name, ann, dm, lr, weight_decay,
                                                               epochs, patience, cfg.trainer.limit_train_batches)
        for key, value in (("optimizer.weight_decay", weight_decay), ("trainer.max_epochs", epochs),
                           ("early_stopping.patience", patience), *((f"ann.{k}", v) for k, v in ann.items())):
            OmegaConf.update(cfg, key, value)
        # where the data were, resolved, so hypa.evaluate finds them from any working directory; what
        # the run was made from (code, packages, data checksums), so hypa.evaluate notices other data
        folder.update_record(data_dir=str(data_dir.resolve()), **run_metadata(dm.files, data_dir))
        # the run's own resolved configuration, written while this process holds the folder (a refused
        # second run may already have overwritten Hydra's .hydra/config.yaml)
        write_text_atomic(out / CONFIG_FILE, OmegaConf.to_yaml(cfg, resolve=True))
        module = HybridModule(
            model_config=model_config,
            physical_values=physical_values,
            normalization=dm.normalization.state_dict(),
            input_names=dm.input_names, output_names=dm.output_names, eval_names=dm.eval_names,
            scheduling_names=dm.scheduling_names, past=dm.past,
            dt=dm.dt, horizon=horizon, hold=hold,
            ann_name=ann_name, ann_hparams=ann,
            lr=lr, physics_lr=physics_lr, weight_decay=weight_decay,
        )
        stages = parse_model_spec(model_config).stages
        started = time.perf_counter()
        how = plan(module, stages) if identification is not None and ckpt_path is None else None
        if how in ("stage", "first"):  # a hybrid: its physics identified, then its networks train on it
            identify_physics(module, how, stages, dm, folder, identification, logger)
            stages = stages[1:] if how == "stage" else stages
        checkpoint = RecordedCheckpoint(folder)
        callbacks: list[L.Callback] = [
            StopOnNonFiniteLoss(hint=f"lower optimizer.lr={lr:g} or optimizer.physics_lr={physics_lr:g}"),
            instantiate(cfg.early_stopping, patience=patience, min_delta=min_delta),
            *extra_callbacks,
        ]
        if stages:
            callbacks.append(StagedTraining(stages, max_epochs=epochs))
        if cfg.figures.enabled:
            callbacks.append(ValidationFigures(setting(cfg, "figures.seconds", float, positive=True),
                                               setting(cfg, "figures.start_s", float, minimum=0.0),
                                               setting(cfg, "figures.every_n_epochs", int, minimum=1)))
        callbacks.append(checkpoint)
        trainer_args = OmegaConf.to_container(cfg.trainer, resolve=True)
        trainer_args["max_epochs"] = epochs * max(len(stages), 1)
        with settings("trainer"):  # passed to Lightning as given: its ValueError / TypeError is the user's
            trainer = L.Trainer(**trainer_args, callbacks=callbacks, logger=logger, default_root_dir=str(out),
                                plugins=[AtomicCheckpointIO()])
        log.info("model %s:\n%s", model_config["name"], module.model)
        if how == "model":
            result = fit_by_identification(trainer, module, dm, folder, identification, logger)
            ended = "identification"
        else:
            try:
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
        result.update(tensorboard=str(out / "tensorboard"), training_time_s=time.perf_counter() - started)
        folder.update_record(training_time_s=result["training_time_s"], best_val_loss=result["best_val_loss"])
        logger.log_hyperparams(_flat(OmegaConf.to_container(cfg, resolve=True)),
                               {"hp/best_val_loss": result["best_val_loss"]})
        logger.finalize("success")  # written now: after fit, nothing else flushes it before the process ends
    print(f"best val/loss {result['best_val_loss']:.5g} after {ended}\n"
          f"checkpoint:  {result['checkpoint']}\n"
          f"tensorboard: tensorboard --logdir {result['tensorboard']}")
    return result


def identification_settings(cfg: DictConfig) -> IdentificationSettings | None:
    """``identification.*``: how a physics-only model is identified; ``None`` when not enabled."""
    from hypa.identification import IdentificationSettings

    enabled = OmegaConf.select(cfg, "identification.enabled", default=False)
    if not isinstance(enabled, bool):
        raise UserError(f"identification.enabled={enabled} is not true or false")
    if not enabled:
        return None
    key = "identification."
    with settings("identification"):
        return IdentificationSettings(
            stretch_s=setting(cfg, key + "stretch_s", float, optional=True, positive=True),
            max_evaluations=setting(cfg, key + "max_evaluations", int, optional=True, minimum=1),
            tolerance=setting(cfg, key + "tolerance", float, positive=True),
            max_seconds=setting(cfg, key + "max_seconds", float, optional=True, positive=True))


def network_name(name: str, target: Any) -> str:
    """The network of ``ann``: its config name where ``_target_`` is that name's block (``lstm``), else
    the ``_target_`` itself, the import path of a network of the user's own (``mypkg.nets.MyBlock``)."""
    from hypa.ann import ANN_BLOCKS, network_class

    if target is None:
        return name
    with settings(f"ann._target_={target}"):
        cls = network_class(str(target))
    return name if ANN_BLOCKS.get(name) is cls else str(target)


def user_callbacks(cfg: DictConfig) -> list[L.Callback]:
    """The Lightning callbacks of ``callbacks`` (name -> ``_target_`` config), built by ``instantiate``."""
    built = []
    for name, node in (cfg.get("callbacks") or {}).items():
        with settings(f"callbacks.{name}"):
            callback = instantiate(node)
        if not isinstance(callback, L.Callback):
            raise UserError(f"callbacks.{name}: {type(callback).__name__} is not a lightning Callback")
        built.append(callback)
    return built


def check_ann_settings(name: str, hparams: dict[str, Any]) -> None:
    """Check the network settings ``ann=name``: a number where the network's default is one,
    then the network built alone from them (tiny sizes in and out), so that its own checks (a
    size < 1, heads that do not divide the width, an unknown name or key) report the user's
    values rather than failing deep inside the model built around them. Converts in place."""
    from hypa.ann import ann_hyperparameters, build_ann

    with settings(f"ann={name}"):
        defaults = ann_hyperparameters(name)
    node = OmegaConf.create({"ann": hparams})
    for key, default in defaults.items():
        if key in hparams and isinstance(default, (int, float)) and not isinstance(default, bool):
            hparams[key] = setting(node, f"ann.{key}", type(default), optional=True)  # null: see network_defaults
    with settings(f"ann={name}"):
        build_ann(name, 1, 1, **{k: v for k, v in hparams.items() if v is not None})


def _flat(tree: Any, prefix: str = "") -> dict[str, Any]:
    """Nested config -> {'a/b': value} with scalars only (what TensorBoard's hparams take)."""
    if isinstance(tree, dict):
        return {k: v for key, sub in tree.items() for k, v in _flat(sub, f"{prefix}{key}/").items()}
    if isinstance(tree, (int, float, str, bool)) or tree is None:
        return {prefix.rstrip("/"): "null" if tree is None else tree}
    return {prefix.rstrip("/"): str(tree)}


@hydra_command("hypa.train", "train")
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
        print(f"hypa.train: {error}", file=sys.stderr, flush=True)
        return math.inf
    return loss if math.isfinite(loss) else math.inf


if __name__ == "__main__":
    main()
