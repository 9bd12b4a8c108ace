"""Training across processes (``trainer.strategy=ddp``): one process owns the run, every process trains the same model.

With ``trainer.strategy=ddp trainer.devices=N``, Lightning's launcher starts ``hypa train`` again
for ranks 1..N-1 (the same command line, the same run folder) when the first process reaches
``trainer.fit``; torchrun or SLURM start every rank at once. In either case:

- rank 0 alone owns the run folder (:func:`launched_as_rank_zero` says which process is, from the
  launchers' variables, before Lightning knows): the lock, ``run.json``, ``config.yaml``,
  ``identification.md``, the checkpoints, the TensorBoard log, the final lines on the terminal;
- rank 0 alone identifies the physics (deterministic, but run once: the other ranks would only
  repeat it, one after the other with Lightning's launcher); :class:`SameModelOnEveryRank` gives
  every rank rank 0's weights when the processes meet, before DDP wraps the model;
- every parameter a stage may train is registered with DDP (its gradients averaged over the
  ranks), although a staged model freezes some of them when it starts: :func:`lightning_strategy`
  lets DDP find the parameters a stage leaves unused.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

import lightning as L
import torch
from lightning.fabric.utilities.rank_zero import rank_zero_only
from lightning.pytorch.callbacks import Callback
from lightning.pytorch.strategies import DDPStrategy

from hypa.core.errors import UserError

log = logging.getLogger(__name__)

# set by Lightning's subprocess launcher (LOCAL_RANK, NODE_RANK), torchrun (RANK, GROUP_RANK), SLURM, LSF
RANK_VARIABLES = ("RANK", "LOCAL_RANK", "NODE_RANK", "GROUP_RANK", "SLURM_PROCID", "JSM_NAMESPACE_RANK")


def launched_as_rank_zero() -> bool:
    """Whether this process is rank 0 of its run (a single process is): every rank variable a
    launcher sets is 0 or unset."""
    return all(int(os.environ.get(name) or 0) == 0 for name in RANK_VARIABLES)


def lightning_strategy(name: Any, staged: bool) -> Any:
    """``trainer.strategy`` as Lightning takes it. ``ddp`` with a model that freezes or bypasses
    parameters (stages, fixed physical parameters): DDP told to find the parameters a step leaves
    unused, which it would otherwise wait for. ``ddp_spawn`` is refused: it pickles the trainer
    into new processes, so the run folder's lock and record would be copies (use ``ddp``)."""
    if not isinstance(name, str):
        return name
    if name.startswith(("ddp_spawn", "ddp_fork", "ddp_notebook")):
        raise UserError(f"trainer.strategy={name}: not supported by hypa train (the run folder is held by one "
                        "process, which these would copy); use trainer.strategy=ddp")
    if name == "ddp" and staged:
        return DDPStrategy(find_unused_parameters=True)
    return name


def join_rank_zero_log(folder: Path, main_log: str = "train.log") -> None:
    """On a rank > 0: log into rank 0's ``train.log`` (lines marked with the rank), not into a log
    of its own (Lightning's launcher names this rank's Hydra job ``train_ddp_process_<rank>``)."""
    root, target = logging.getLogger(), (Path(folder) / main_log).resolve()
    formats = [h.formatter for h in root.handlers if h.formatter is not None]
    for handler in [h for h in root.handlers if isinstance(h, logging.FileHandler)]:
        own = Path(handler.baseFilename)
        if own.parent == target.parent and own != target:
            root.removeHandler(handler)
            handler.close()
            if own.stat().st_size == 0:
                own.unlink()
    handler = logging.FileHandler(target, mode="a")
    form = formats[0]._fmt if formats and formats[0]._fmt else "[%(asctime)s][%(name)s][%(levelname)s] - %(message)s"
    handler.setFormatter(logging.Formatter(f"[rank {rank_zero_only.rank}]{form}"))
    root.addHandler(handler)


class SameModelOnEveryRank(Callback):
    """Rank 0's weights on every rank when training starts, every parameter registered with DDP,
    and a check at the end that the ranks still hold the same weights (a no-op in one process)."""

    def __init__(self) -> None:
        self._frozen: list[torch.nn.Parameter] = []

    def setup(self, trainer: L.Trainer, module: L.LightningModule, stage: str) -> None:
        if trainer.world_size == 1 or stage != "fit":
            return
        # the physics rank 0 identified (the other ranks skipped it): here, after the processes met and before
        # DDP wraps the model (which broadcasts too, but only the parameters that then require gradients)
        state = trainer.strategy.broadcast({k: v.cpu() for k, v in module.state_dict().items()}, src=0)
        module.load_state_dict(state)
        # DDP averages the gradients only of parameters requiring them when it wraps the model: a network frozen
        # in stage 1 (or during identification) must be among them for stage 2; the stage is set again after
        self._frozen = [p for p in module.parameters() if not p.requires_grad]
        for parameter in self._frozen:
            parameter.requires_grad_(True)

    def on_fit_start(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        for parameter in self._frozen:
            parameter.requires_grad_(False)
        self._frozen = []

    def on_fit_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        if trainer.world_size == 1:
            return
        sums = torch.stack([p.detach().double().sum() for p in module.parameters()])
        every = trainer.strategy.all_gather(sums)  # (world size, parameters)
        spread = float((every - every[0]).abs().max())
        if trainer.is_global_zero:
            if spread == 0.0:
                log.info("the same weights on all %d processes", trainer.world_size)
            else:
                log.warning("the %d processes ended with different weights (largest difference of a parameter's "
                            "sum: %.3g); the checkpoint holds rank 0's", trainer.world_size, spread)
