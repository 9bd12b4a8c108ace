"""Checkpoints that can be trusted: written whole, recorded in ``run.json``, read without running code.

- :class:`AtomicCheckpointIO` writes every checkpoint to a temporary name and renames it into
  place, so a full disk or a killed process never leaves a truncated ``best-*.ckpt``.
- :class:`RecordedCheckpoint` is Lightning's ``ModelCheckpoint`` that records the best checkpoint
  (path, validation loss, epoch, SHA-256) in the run folder's ``run.json`` each time it changes:
  ``hypa.evaluate`` and every other reader take that record, never "the last ``best-*`` by name".
  A hybrid's training starts with its identified physics as the best so far
  (:meth:`RecordedCheckpoint.keep_the_start`): an epoch must beat it on validation to replace it.
- :func:`load_module` reads a checkpoint with ``torch.load(weights_only=True)``: a hypa checkpoint
  holds only tensors, numbers, strings and containers, so a crafted file cannot run code.
"""

from __future__ import annotations

import inspect
import io
import logging
import math
import pickle
import re
from pathlib import Path
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.plugins.io import TorchCheckpointIO

from hypa.ann import ann_hyperparameters
from hypa.errors import UserError, one_line
from hypa.metadata import sha256
from hypa.training.module import HybridModule
from hypa.training.run_folder import RunFolder, write_atomic

log = logging.getLogger(__name__)

START_CHECKPOINT = "best-start.ckpt"  # a hybrid's model before its networks' first epoch (keep_the_start)


class AtomicCheckpointIO(TorchCheckpointIO):
    """Lightning's checkpoint writer with the write made atomic (temporary name, then rename)."""

    def save_checkpoint(self, checkpoint: dict[str, Any], path: Any, storage_options: Any | None = None) -> None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            write_atomic(path, lambda file: torch.save(checkpoint, file))
        except OSError as error:  # a full disk, a read-only folder: the previous checkpoints stay whole
            raise type(error)(error.errno, f"{error.strerror or error} while writing the checkpoint {path}; "
                                           "the checkpoints written before it are intact") from None


class RecordedCheckpoint(ModelCheckpoint):
    """``ModelCheckpoint`` (best by ``val/loss`` and ``last.ckpt``) into ``<run>/checkpoints`` that
    records its best checkpoint in the run's ``run.json`` (``best_checkpoint``)."""

    def __init__(self, folder: RunFolder, monitor: str = "val/loss") -> None:
        super().__init__(dirpath=folder.checkpoints, filename="best-{epoch:02d}", monitor=monitor, mode="min",
                         save_top_k=1, save_last=True)
        self.folder = folder
        self._recorded = ""

    def on_validation_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        super().on_validation_end(trainer, module)
        self._record(trainer)

    def on_train_epoch_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        super().on_train_epoch_end(trainer, module)
        self._record(trainer)

    def _record(self, trainer: L.Trainer) -> None:
        path = Path(self.best_model_path) if self.best_model_path else None
        if not trainer.is_global_zero or path is None or self.best_model_path == self._recorded or not path.is_file():
            return
        score = float(self.best_model_score) if self.best_model_score is not None else float("nan")
        self.folder.update_record(best_checkpoint={"path": self.folder.relative(path), "val_loss": score,
                                                   "epoch": trainer.current_epoch, "sha256": sha256(path)},
                                  last_checkpoint=self.folder.relative(self.folder.checkpoints / "last.ckpt"))
        self._recorded = self.best_model_path

    def keep_the_start(self, trainer: L.Trainer, module: L.LightningModule, datamodule: L.LightningDataModule) -> float:
        """Validate ``module`` before its first epoch, save it (``best-start.ckpt``) and make it the best
        checkpoint so far, so that the run's best is never worse on validation than where training
        started: a hybrid whose correction only overfits keeps its identified physics (the correction's
        output still zero). An epoch that beats it replaces it, as any better epoch does. Returns its
        validation loss."""
        loop = trainer.validate_loop  # no_grad, not inference mode: what it caches (the physics' matrices, the
        inference, loop.inference_mode = loop.inference_mode, False  # metrics' states) must serve training next
        try:
            val_loss = float(trainer.validate(module, datamodule=datamodule, verbose=False)[0][self.monitor])
        finally:
            loop.inference_mode = inference
        path = Path(self.dirpath) / START_CHECKPOINT
        trainer.save_checkpoint(path, False)  # the full checkpoint, as ModelCheckpoint writes it
        score = torch.tensor(val_loss if math.isfinite(val_loss) else math.inf)
        self.best_k_models = {str(path): score}
        self.best_model_path = self.kth_best_model_path = str(path)
        self.best_model_score = self.kth_value = score
        self._record(trainer)
        return val_loss


def load_checkpoint(checkpoint: Path) -> tuple[dict[str, Any], bytes]:
    """A checkpoint file's content (``torch.load(weights_only=True)``: no code runs) and its bytes.

    A file that is no checkpoint (a text file, a truncated download, a pickle that would run
    code) or one of another program is the user's error, named by the file.
    """
    checkpoint = Path(checkpoint)
    content = checkpoint.read_bytes()  # read once, unpickled twice: checked here, then by Lightning
    try:
        state = torch.load(io.BytesIO(content), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:  # torch's advice (to load it unrestricted) would run the code
        found = re.search(r"GLOBAL ([\w.]+)|global: ([\w.]+)", str(error))
        what = f" ({next(g for g in found.groups() if g)})" if found else ""
        raise UserError(f"{checkpoint}: not a readable checkpoint: it holds objects that a hypa checkpoint never "
                        f"holds{what}, which were not loaded and did not run; "
                        "give a .ckpt written by hypa.train") from None
    except Exception as error:  # noqa: BLE001 -- a zip or EOF error: a text file, a truncated download
        raise UserError(f"{checkpoint}: not a readable checkpoint ({type(error).__name__}: {one_line(error)[:200]}); "
                        "give a .ckpt written by hypa.train") from None
    hparams = state.get("hyper_parameters") if isinstance(state, dict) else None
    if not isinstance(hparams, dict) or "model_config" not in hparams or "state_dict" not in state:
        raise UserError(f"{checkpoint}: not a checkpoint of hypa.train (it holds no hypa model configuration)")
    return state, content


def load_module(checkpoint: Path) -> HybridModule:
    """The trained module of a ``hypa.train`` checkpoint, on the CPU, in eval mode.

    A checkpoint whose weights do not fit its model, or one written by another version of hypa,
    is the user's error too (checked here, where the file is read, not by catching everything
    around it).
    """
    state, content = load_checkpoint(checkpoint)
    hparams = state["hyper_parameters"]
    accepted = inspect.signature(HybridModule.__init__).parameters
    unknown = sorted(set(hparams) - set(accepted))
    missing = sorted(n for n, p in accepted.items() if n != "self" and p.default is p.empty and n not in hparams)
    if unknown or missing:
        raise UserError(f"{checkpoint}: written by another version of hypa (settings {unknown or missing} "
                        f"{'unknown' if unknown else 'missing'} here); evaluate it with that version or retrain")
    _warn_new_network_settings(checkpoint, hparams)
    try:
        module = HybridModule.load_from_checkpoint(io.BytesIO(content), map_location="cpu", weights_only=True)
    except RuntimeError as error:
        if "state_dict" not in str(error):
            raise
        raise UserError(f"{checkpoint}: its weights do not fit its model ({one_line(error)[:300]})") from error
    module.eval()
    return module


def _warn_new_network_settings(checkpoint: Path, hparams: dict) -> None:
    """Warn when the checkpoint's network was trained before a setting it now takes existed: the
    code's default then applies to weights trained without it (S4's and Mamba's ``max_decay``
    change what the trained layers compute), so the run may not behave as it did in training."""
    uses_ann = any(b.get("kind") == "ann" for b in (hparams["model_config"].get("blocks") or {}).values()
                   if isinstance(b, dict))
    name = hparams.get("ann_name")
    if not uses_ann or not name:
        return
    try:
        defaults = ann_hyperparameters(str(name))
    except ValueError:  # an unknown network: building the module names it
        return
    new = {k: v for k, v in defaults.items() if k != "zero_init" and k not in (hparams.get("ann_hparams") or {})}
    if new:
        settings = ", ".join(f"ann.{k}={v}" for k, v in new.items())
        log.warning("%s was trained before the %s setting(s) %s existed; their defaults apply now and may change "
                    "what the network computes: retrain the run to evaluate it as hypa is now", checkpoint, name,
                    settings)
