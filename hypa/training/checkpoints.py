"""Checkpoints that can be trusted: written whole, recorded in ``run.json``, read without running code.

- :class:`AtomicCheckpointIO` writes every checkpoint to a temporary name and renames it into
  place, so a full disk or a killed process never leaves a truncated ``best-*.ckpt``.
- :class:`RecordedCheckpoint` is Lightning's ``ModelCheckpoint`` that records the best checkpoint
  (path, validation loss, epoch, SHA-256) in the run folder's ``run.json`` each time it changes:
  ``hypa evaluate`` and every other reader take that record, never "the last ``best-*`` by name".
  A hybrid's training starts with its identified physics as the best so far
  (:meth:`RecordedCheckpoint.keep_the_start`): an epoch must beat it on validation to replace it.
- :func:`load_module` reads a checkpoint as data (:mod:`hypa.core.trust`): bounded before it is read
  (torch's zip format, no compressed member), ``torch.load(weights_only=True)`` (only tensors,
  numbers, strings and containers), its settings checked by the schema of :class:`HybridModule`'s
  arguments before anything is built, and no import path in it imported unless the user trusts it.
"""

from __future__ import annotations

import inspect
import logging
import math
import pickle
import re
import zipfile
from collections.abc import Collection
from pathlib import Path
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.plugins.io import TorchCheckpointIO

from hypa.ann import ann_hyperparameters, build_ann, check_hyperparameters
from hypa.core.errors import UserError, one_line
from hypa.core.machine import available_memory
from hypa.core.metadata import sha256
from hypa.core.trust import check_imports, check_name, count_nodes
from hypa.models import ModelSpecError, parse_model_spec
from hypa.models.spec import builds_networks, model_imports
from hypa.physics.discretization import HOLDS
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

    def load_checkpoint(self, path: Any, map_location: Any | None = None, weights_only: bool | None = None) -> Any:
        """A checkpoint to resume from, read as :func:`read_checkpoint` reads one (bounded, no code)."""
        return read_checkpoint(Path(path))


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

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """A resumed checkpoint's record of the best and last files, kept only where each names a file
        of this run's checkpoint folder: the checkpoint is data, and the rotation removes the files it
        names (a crafted ``../../x`` would otherwise be deleted when a better epoch comes)."""
        state = dict(state_dict)
        for key in ("best_model_path", "kth_best_model_path", "last_model_path"):
            if key in state and not self._ours(state[key]):
                log.warning("the resumed checkpoint names %r as its %s, outside %s: not kept", state[key], key,
                            self.dirpath)
                state[key] = ""
        models = state.get("best_k_models")
        if isinstance(models, dict):
            state["best_k_models"] = {k: v for k, v in models.items() if self._ours(k) and isinstance(v, torch.Tensor)}
        if not state.get("best_model_path"):
            state["best_model_score"] = None
        super().load_state_dict(state)

    def _ours(self, path: Any) -> bool:
        """Whether ``path`` is a file directly in this run's checkpoint folder (not a link)."""
        if not isinstance(path, str) or not path or self.dirpath is None:
            return not path
        candidate = Path(path)
        return candidate.parent.resolve() == Path(self.dirpath).resolve() and not candidate.is_symlink()

    def _remove_checkpoint(self, trainer: L.Trainer, filepath: str) -> None:
        # the rotation saves the new best, then removes the old one: run.json names the new one first,
        # so a process killed in between leaves a record of a checkpoint that exists
        self._record(trainer)
        if not self._ours(filepath):  # never a file outside this run's checkpoint folder
            log.warning("not removing %s: not a checkpoint of %s", filepath, self.dirpath)
            return
        super()._remove_checkpoint(trainer, filepath)

    def _record(self, trainer: L.Trainer) -> None:
        path = Path(self.best_model_path) if self.best_model_path else None
        if not trainer.is_global_zero or path is None or self.best_model_path == self._recorded or not path.is_file():
            return
        score = float(self.best_model_score) if self.best_model_score is not None else float("nan")
        self.folder.update_record(best_checkpoint={"path": self.folder.relative(path), "val_loss": score,
                                                   "monitor": self.monitor, "epoch": trainer.current_epoch,
                                                   "sha256": sha256(path)},
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


def read_checkpoint(checkpoint: Path) -> dict[str, Any]:
    """A checkpoint file's content, read as data: bounded before it is read, no code run.

    - It must be torch's zip format with every member stored, as ``torch.save`` writes it: a
      compressed member (a zip bomb) is refused before anything is unpacked, so what is read is
      never more than the file.
    - ``torch.load(weights_only=True, mmap=True)``: only tensors, numbers, strings and containers,
      the tensors mapped from the file rather than read (the model decides what is copied).
    - The nested values are counted before any is walked (:func:`hypa.core.trust.count_nodes`).

    A file that is no checkpoint (a text file, a truncated download, a pickle that would run
    code) or one of another program is the user's error, named by the file.
    """
    checkpoint = Path(checkpoint)
    _check_archive(checkpoint)
    try:
        state = torch.load(checkpoint, map_location="cpu", weights_only=True, mmap=True)
    except pickle.UnpicklingError as error:  # torch's advice (to load it unrestricted) would run the code
        found = re.search(r"GLOBAL ([\w.]+)|global: ([\w.]+)", str(error))
        what = f" ({next(g for g in found.groups() if g)})" if found else ""
        raise UserError(f"{checkpoint}: not a readable checkpoint: it holds objects that a hypa checkpoint never "
                        f"holds{what}, which were not loaded and did not run; "
                        "give a .ckpt written by hypa train") from None
    except Exception as error:  # noqa: BLE001 -- a zip or EOF error: a text file, a truncated download
        raise UserError(f"{checkpoint}: not a readable checkpoint ({type(error).__name__}: {one_line(error)[:200]}); "
                        "give a .ckpt written by hypa train") from None
    if not isinstance(state, dict) or not isinstance(state.get("state_dict"), dict):
        raise UserError(f"{checkpoint}: not a checkpoint of hypa train (it holds no model weights)")
    count_nodes({k: v for k, v in state.items() if k != "state_dict"}, str(checkpoint))
    return state


def _check_archive(checkpoint: Path) -> None:
    """Refuse a file that is not torch's zip format, or one whose members are compressed or add up to
    more than the file: what ``torch.load`` unpacks is then never more than the file itself."""
    try:
        size = checkpoint.stat().st_size
        with zipfile.ZipFile(checkpoint) as archive:
            members = archive.infolist()
    except FileNotFoundError:
        raise
    except (OSError, zipfile.BadZipFile, ValueError) as error:
        raise UserError(f"{checkpoint}: not a readable checkpoint ({one_line(error)[:200]}); give a .ckpt written "
                        "by hypa train") from None
    if len(members) > MAX_MEMBERS:
        raise UserError(f"{checkpoint}: {len(members):,} members, more than a checkpoint of hypa train holds; not read")
    compressed = [m.filename for m in members if m.compress_type != zipfile.ZIP_STORED]
    if compressed:
        raise UserError(f"{checkpoint}: {compressed[0]} is compressed, which torch.save never does (a zip bomb?); "
                        "not read: give a .ckpt written by hypa train")
    unpacked = sum(m.file_size for m in members)
    if unpacked > size:
        raise UserError(f"{checkpoint}: its members add up to {unpacked:,} bytes, more than the file's {size:,}; "
                        "the file is damaged or crafted; not read")


def checked_settings(state: dict[str, Any], source: Path | str, trust: Collection[str] = ()) -> dict[str, Any]:
    """The stored settings (``hyper_parameters``) of a checkpoint, checked against the schema of
    :class:`HybridModule`'s arguments before anything is built from them: every value of its type
    and range, the model through the model schema, the network's hyperparameters plain values it
    accepts, and no import path that ``trust`` does not name (:func:`~hypa.models.spec.model_imports`).
    Returns them as plain Python values."""
    hparams = state.get("hyper_parameters")
    if not isinstance(hparams, dict) or "model_config" not in hparams:
        raise UserError(f"{source}: not a checkpoint of hypa train (it holds no hypa model configuration)")
    accepted = inspect.signature(HybridModule.__init__).parameters
    unknown = sorted(set(map(str, hparams)) - set(accepted))
    missing = sorted(n for n, p in accepted.items() if n != "self" and p.default is p.empty and n not in hparams)
    if unknown or missing:
        raise UserError(f"{source}: written by another version of hypa (settings {unknown or missing} "
                        f"{'unknown' if unknown else 'missing'} here); evaluate it with that version or retrain")
    out = {key: _plain(value, f"{source}: its setting {key}") for key, value in hparams.items()}

    def bad(key: str, expected: str) -> UserError:
        return UserError(f"{source}: its setting {key} is {str(out[key])[:80]!r}, not {expected}; the checkpoint is "
                         "damaged or was not written by hypa train")

    if not isinstance(out["model_config"], dict):
        raise bad("model_config", "a model (blocks wired by signals)")
    try:
        parse_model_spec(out["model_config"])
    except ModelSpecError as error:
        raise UserError(f"{source}: its model: {error}") from None
    for key in ("input_names", "output_names", "eval_names", "scheduling_names"):
        if key in out and not (isinstance(out[key], list) and all(isinstance(n, str) for n in out[key])):
            raise bad(key, "a list of channel names")
        for name in out.get(key, []):
            check_name(name, f"{source}: its setting {key}")
    for key, positive in (("dt", True), ("lr", False), ("physics_lr", False), ("weight_decay", False)):
        value = out.get(key, 0.0)
        if not _number(value) or not math.isfinite(value) or value < 0 or (positive and value == 0):
            raise bad(key, "a positive finite number" if positive else "a finite number >= 0")
    for key, low in (("horizon", 1), ("past", 0)):
        value = out.get(key, low)
        if not (isinstance(value, int) and not isinstance(value, bool) and low <= value <= MAX_STEPS):
            raise bad(key, f"an integer from {low} to {MAX_STEPS:,}")
    lifted = 8 * out.get("horizon", 1) ** 2  # [bytes] the smallest lifted matrix (one input, one output, float64)
    room = available_memory()
    if room is not None and lifted > room / 2:
        raise UserError(f"{source}: its setting horizon={out['horizon']:,} asks for lifted matrices of at least "
                        f"{lifted / 2**30:,.0f} GiB, more than half of the {room / 2**30:.3g} GiB available here; "
                        "the checkpoint is damaged or crafted; not built")
    if out.get("hold") is not None and out["hold"] not in HOLDS:
        raise bad("hold", f"one of {', '.join(HOLDS)} or null")
    values = out.get("physical_values")
    if values is not None and not (isinstance(values, dict) and all(
            isinstance(k, str) and _number(v) and math.isfinite(v) for k, v in values.items())):
        raise bad("physical_values", "a mapping of parameter names to finite numbers")
    _check_normalization(out["normalization"], source)
    if not isinstance(out.get("ann_name", "lstm"), str) or not out.get("ann_name", "lstm"):
        raise bad("ann_name", "a network's name")
    check_imports(model_imports(out["model_config"], out.get("ann_name", "lstm")), trust, source)
    ann = out.get("ann_hparams")
    if ann is not None:
        if not isinstance(ann, dict):
            raise bad("ann_hparams", "a mapping of the network's settings")
        if builds_networks(out["model_config"]):
            try:
                check_hyperparameters(out.get("ann_name", "lstm"), ann)
            except (TypeError, ValueError) as error:
                raise UserError(f"{source}: its network: {one_line(error)}") from None
    return out


MAX_MEMBERS = 100_000  # files in a checkpoint's archive (torch.save writes one per tensor storage, plus five)
MAX_STEPS = 10_000_000  # a window's steps (horizon, past) a checkpoint may ask for


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _plain(value: Any, where: str) -> Any:
    """``value`` as plain Python (dict with string keys, list, str, int, float, bool, None); a tensor
    or any other object among a checkpoint's settings is the file's error."""
    if isinstance(value, (str, bool, int, float)) or value is None:
        return value
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise UserError(f"{where}: a mapping whose keys are not all names; the checkpoint is damaged or crafted")
        return {k: _plain(v, where) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v, where) for v in value]
    raise UserError(f"{where}: holds a {type(value).__name__}, which hypa never stores there; the checkpoint is "
                    "damaged or crafted")


def _check_normalization(state: Any, source: Path | str) -> None:
    """``normalization``: names, and a finite mean and a positive finite std for each."""
    ok = isinstance(state, dict) and isinstance(state.get("names"), list) and all(
        isinstance(n, str) for n in state["names"])
    for key in ("mean", "std"):
        ok = ok and isinstance(state.get(key), list) and len(state[key]) == len(state["names"]) and all(
            _number(v) and math.isfinite(v) for v in state[key])
    if not ok or any(v <= 0 for v in state["std"]):
        raise UserError(f"{source}: its normalization is not names with finite means and positive scales; the "
                        "checkpoint is damaged or crafted")


def _network_bytes(hparams: dict[str, Any]) -> int:
    """The bytes of the smallest network the settings ask for (one input, one output), sized on the
    ``meta`` device (nothing allocated); 0 for a model without networks or one that cannot be sized so."""
    if not builds_networks(hparams["model_config"]):
        return 0
    try:
        with torch.device("meta"):
            network = build_ann(hparams.get("ann_name", "lstm"), 1, 1, **(hparams.get("ann_hparams") or {}))
    except Exception:  # noqa: BLE001 -- a network whose construction needs values: built with the module
        return 0
    return sum(p.numel() * p.element_size() for p in network.state_dict().values())


def load_module(checkpoint: Path, trust: Collection[str] = ()) -> HybridModule:
    """The trained module of a ``hypa train`` checkpoint, on the CPU, in eval mode.

    The file is read as data (:func:`read_checkpoint`), its settings checked
    (:func:`checked_settings`; ``trust``: the import paths the user trusts), the module built from
    them and its weights copied in. A checkpoint whose weights do not fit its model, or one written
    by another version of hypa, is the user's error too.
    """
    state = read_checkpoint(checkpoint)
    hparams = checked_settings(state, checkpoint, trust)
    _warn_new_network_settings(checkpoint, hparams)
    weights = state["state_dict"]
    if not all(isinstance(k, str) and isinstance(v, torch.Tensor) and (v.is_floating_point() or v.dtype in (
            torch.int64, torch.int32, torch.bool)) for k, v in weights.items()):
        raise UserError(f"{checkpoint}: its weights are not named real tensors; the checkpoint is damaged or crafted")
    stored = sum(v.numel() * v.element_size() for v in weights.values())
    needed = _network_bytes(hparams)
    if needed > 2 * stored + 2**20:  # the weights hold every parameter: sizes that ask for more are not built
        raise UserError(f"{checkpoint}: its settings make a network of {needed / 2**20:,.1f} MiB, but it holds "
                        f"{stored / 2**20:.1f} MiB of weights; the checkpoint is damaged or crafted; not built")
    try:
        module = HybridModule(**hparams)
    except UserError:
        raise
    except (TypeError, ValueError, KeyError, IndexError, RuntimeError, AttributeError) as error:  # checked values
        raise UserError(f"{checkpoint}: its settings do not build a model ({type(error).__name__}: "  # that still
                        f"{one_line(error)[:300]})") from None  # do not fit together: the file's error, one line
    weights = _with_added_parameters(checkpoint, module, weights)
    try:
        module.load_state_dict(weights)
    except RuntimeError as error:
        raise UserError(f"{checkpoint}: its weights do not fit its model ({one_line(error)[:300]})") from None
    module.eval()
    return module


PHYSICAL = "model.parameters_.raw."  # the state-dict keys of the physical parameters


def _with_added_parameters(checkpoint: Path, module: HybridModule, weights: dict) -> dict:
    """``weights`` with the physical parameters a system gained after the checkpoint was saved (a
    circuit's output offset) at their values in the model now, said in one warning: a system's new
    parameter starts where the system is what it was (an offset of 0). Any other missing weight
    stays missing (``load_state_dict`` refuses it)."""
    own = module.state_dict()
    added = sorted(k for k in own if k.startswith(PHYSICAL) and k not in weights)
    if not added:
        return weights
    names = [k[len(PHYSICAL):] for k in added]
    values = module.model.parameters_.as_floats()
    log.warning("%s predates the physical parameter(s) %s of its model: they take the model's values (%s), as the "
                "system was before it had them", checkpoint, ", ".join(names),
                ", ".join(f"{n} = {values[n]:g}" for n in names))
    return {**weights, **{k: own[k] for k in added}}


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
