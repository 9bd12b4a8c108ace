"""A trained run (checkpoint + its configuration) and its predictions on measured data.

Two ways to evaluate, as a simulation user needs both: windowed (N steps from each measured
initial state, exactly as in training) and free-running over a whole record (the model starts
from the record's first measured state and never sees a measured state again).
"""

from __future__ import annotations

import inspect
import io
import json
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from hypa.ann import ann_hyperparameters
from hypa.data import HypaDataModule, Record
from hypa.errors import UserError, one_line
from hypa.models import ComposedModel
from hypa.training import HybridModule

log = logging.getLogger(__name__)

@dataclass
class TrainedRun:
    """A run folder of ``python -m hypa.train``: its best checkpoint and its configuration."""

    folder: Path
    checkpoint: Path
    config: DictConfig
    module: HybridModule
    data_dir: Path | None = None  # the resolved data folder the run was trained on (run.json)
    info: dict = field(default_factory=dict)  # the run's run.json (data checksums, versions; hypa.metadata)

    @property
    def label(self) -> str:
        """Table-1 style name: the model, with its network where it has one (``v1 lstm``)."""
        model = self.module.model
        has_ann = any(b.kind == "ann" for b in model.spec.blocks)
        return f"{model.spec.name} {self.module.hparams.ann_name}" if has_ann else model.spec.name


def find_checkpoint(folder: Path) -> Path:
    """The best checkpoint of a run folder (``checkpoints/best-*.ckpt``, else ``last.ckpt``)."""
    best = sorted((folder / "checkpoints").glob("best-*.ckpt"))
    if best:
        return best[-1]
    last = folder / "checkpoints" / "last.ckpt"
    if last.is_file():
        return last
    raise FileNotFoundError(f"no checkpoint in {folder / 'checkpoints'} (is {folder} a hypa.train run folder?)")


def load_run(path: Path | str) -> TrainedRun:
    """Load a run from its folder or from one of its checkpoints (CPU)."""
    path = Path(path).expanduser().resolve()
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist: give a hypa.train run folder or a .ckpt file")
    if path.is_file():
        checkpoint, folder = path, path.parent.parent if path.parent.name == "checkpoints" else path.parent
    else:
        folder, checkpoint = path, find_checkpoint(path)
    config_file = folder / ".hydra" / "config.yaml"
    if not config_file.is_file():
        raise FileNotFoundError(f"{config_file} is missing: {folder} is not a hypa.train run folder")
    config = OmegaConf.load(config_file)
    module = load_module(checkpoint)
    trained, configured = module.hparams.model_config.get("name"), OmegaConf.select(config, "model.name")
    if configured is not None and trained != configured:
        raise UserError(f"{checkpoint} holds model {trained}, but its run folder {folder} trained model "
                        f"{configured}; give the run folder (or a checkpoint) of the run to evaluate")
    info_file = folder / "run.json"
    info = json.loads(info_file.read_text()) if info_file.is_file() else {}
    data_dir = Path(info["data_dir"]) if "data_dir" in info else None
    return TrainedRun(folder=folder, checkpoint=checkpoint, config=config, module=module, data_dir=data_dir,
                      info=info)


def load_module(checkpoint: Path) -> HybridModule:
    """The trained module of a ``hypa.train`` checkpoint, on the CPU, in eval mode.

    A file that is no checkpoint (a text file, a truncated download), a checkpoint of another
    program's model or one whose weights do not fit its model is the user's error, named by
    the file (checked here, where the file is read, not by catching everything around it).
    """
    checkpoint = Path(checkpoint)
    content = checkpoint.read_bytes()  # read once, unpickled twice: checked, then by Lightning
    try:
        state = torch.load(io.BytesIO(content), map_location="cpu", weights_only=False)
    except Exception as error:  # unpickling, zip, EOF, import errors: whatever it is, it is no checkpoint
        raise UserError(f"{checkpoint}: not a readable checkpoint ({type(error).__name__}: {one_line(error)}); "
                        "give a .ckpt written by hypa.train") from error
    hparams = state.get("hyper_parameters") if isinstance(state, dict) else None
    if not isinstance(hparams, dict) or "model_config" not in hparams or "state_dict" not in state:
        raise UserError(f"{checkpoint}: not a checkpoint of hypa.train (it holds no hypa model configuration)")
    accepted = inspect.signature(HybridModule.__init__).parameters
    unknown = sorted(set(hparams) - set(accepted))
    missing = sorted(n for n, p in accepted.items() if n != "self" and p.default is p.empty and n not in hparams)
    if unknown or missing:
        raise UserError(f"{checkpoint}: written by another version of hypa (settings {unknown or missing} "
                        f"{'unknown' if unknown else 'missing'} here); evaluate it with that version or retrain")
    _warn_new_network_settings(checkpoint, hparams)
    try:
        module = HybridModule.load_from_checkpoint(io.BytesIO(content), map_location="cpu")
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


@dataclass
class Prediction:
    """Measured and predicted signals of one record (SI units, the record's time base).

    ``predicted`` holds the model outputs: samples before ``first`` are the measured ones that
    started the model (the past and the window start), the rest the prediction; ``signals``
    the model's internal physical signals (e.g. an input a network learns implicitly),
    each on its own sample range.
    """

    record: str
    time: np.ndarray  # (T,)
    measured: dict[str, np.ndarray]  # outputs and evaluation channels, (T,)
    predicted: dict[str, np.ndarray]  # outputs, (T,)
    inputs: dict[str, np.ndarray]
    signals: dict[str, tuple[np.ndarray, int]] = field(default_factory=dict)  # values, first sample
    first: int = 1  # first predicted sample (past + 1)

    def signal_on_grid(self, name: str) -> np.ndarray:
        """An internal signal on the record's time base (NaN where the model has no value)."""
        values, start = self.signals[name]
        out = np.full_like(self.time, np.nan, dtype=float)
        out[start : start + len(values)] = values[: len(out) - start]
        return out


def model_inputs(dm: HypaDataModule, record: Record, stretch: slice = slice(None)) -> tuple[torch.Tensor, ...]:
    """(u, y_past, s) of one record for the model, batch of one: normalized inputs, normalized
    measured outputs up to the window start (the first ``past`` + 1 samples), SI scheduling."""
    norm, past = dm.normalization, dm.past
    u = norm.normalize(record.stack(dm.input_names)[stretch], dm.input_names)
    y = norm.normalize(record.stack(dm.output_names)[stretch][: past + 1], dm.output_names)
    s = record.stack(dm.scheduling_names)[stretch]
    return tuple(torch.as_tensor(a, dtype=torch.float32)[None] for a in (u, y, s))


@torch.no_grad()
def free_run(model: ComposedModel, dm: HypaDataModule, record: Record, stretch: slice = slice(None)) -> Prediction:
    """Simulate a record (or a stretch of it) from its start, never seeing a measured output after it.

    The first ``dm.past`` + 1 samples start the model (the measured state, or the estimate of
    an unmeasured one from the past); every later sample is predicted.
    """
    device = next(model.buffers(), torch.zeros(0)).device
    u, y_past, s = (t.to(device) for t in model_inputs(dm, record, stretch))
    first = dm.past + 1
    signals = model.signals(u, y_past, s)
    pred = model.outputs(signals, dm.past)[0].cpu()
    y = record.stack(dm.output_names)[stretch]
    predicted = {n: np.concatenate([y[:first, i], model.to_physical(n, pred[:, i]).double().numpy()])
                 for i, n in enumerate(dm.output_names)}
    internal = {}
    for name, (values, start) in signals.items():
        if name not in dm.input_names and name not in model.spec.outputs:
            internal[name] = (model.to_physical(name, values[0, :, 0]).double().cpu().numpy(), start)
    measured = {n: record[n][stretch] for n in (*dm.output_names, *dm.eval_channels) if n in record}
    return Prediction(record.name, record.time[stretch], measured, predicted,
                      {n: record[n][stretch] for n in dm.input_names}, internal, first)


def free_run_metrics(runs: Sequence[Prediction], outputs: Sequence[str]) -> dict[str, dict[str, float]]:
    """Per output, over the predicted samples of all free runs: ``rmse`` [SI], ``mse`` and ``r2``."""
    out = {}
    for name in outputs:
        y = np.concatenate([r.measured[name][r.first:] for r in runs])
        p = np.concatenate([r.predicted[name][r.first:] for r in runs])
        mse = float(np.mean((p - y) ** 2))
        out[name] = {"rmse": mse**0.5, "mse": mse, "r2": 1.0 - mse / float(np.var(y))}
    return out


@torch.no_grad()
def windowed(module: HybridModule, dm: HypaDataModule, split: str) -> dict[str, np.ndarray]:
    """All windows of a split: ``pred`` and ``target`` (W, N, p) in SI, ``record`` and ``start``
    (W,) to locate each window (``start`` is its first sample, the first past one)."""
    model, first = module.model, dm.past + 1
    out = {"pred": [], "target": [], "record": [], "start": []}
    loader = dm.val_dataloader() if split == "val" else dm.test_dataloader()
    for batch in loader:
        u, y = batch["u"], batch["y"]
        pred = model(u, y[:, :first], batch.get("s"))
        out["pred"].append(torch.stack([model.to_physical(n, pred[..., i]) for i, n in enumerate(dm.output_names)], -1))
        out["target"].append(torch.stack([model.to_physical(n, y[:, first:, i])
                                          for i, n in enumerate(dm.output_names)], -1))
        out["record"].append(batch["record"])
        out["start"].append(batch["start"])
    return {k: torch.cat(v).double().numpy() for k, v in out.items()}
