"""A trained run (checkpoint + its configuration) and its predictions on measured data.

Two ways to evaluate, as a simulation user needs both: windowed (N steps from each measured
initial state, exactly as in training) and free-running over a whole record (the model starts
from the record's first measured state and never sees a measured state again).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from hypa.data import HypaDataModule, Record
from hypa.errors import UserError, one_line
from hypa.metadata import sha256
from hypa.models import ComposedModel
from hypa.training import HybridModule
from hypa.training.checkpoints import load_module
from hypa.training.run_folder import CONFIG_FILE, RECORD_FILE, read_record

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


def recorded_checkpoint(folder: Path, record: dict) -> Path:
    """The best checkpoint that a run folder's ``run.json`` records, checked against its SHA-256.

    Never "the last ``best-*`` by name": a checkpoint that is not the recorded one (another run's,
    a damaged or replaced file) would be scored under this run's settings without a word.
    """
    best = record.get("best_checkpoint")
    if not isinstance(best, dict) or "path" not in best:
        if not (folder / RECORD_FILE).is_file() and not (folder / "checkpoints").is_dir():
            raise FileNotFoundError(f"no checkpoint in {folder / 'checkpoints'} (is {folder} a hypa.train run folder?)")
        files = sorted(p.name for p in (folder / "checkpoints").glob("*.ckpt"))
        choice = f"give one of its checkpoints: run={folder / 'checkpoints'}/<{' | '.join(files)}>" if files else \
            "it has no checkpoint"
        raise UserError(f"{folder / RECORD_FILE} records no best checkpoint (a run of an older hypa, or one that "
                        f"stopped before its first validation); {choice}")
    path = Path(str(best["path"]))
    path = path if path.is_absolute() else folder / path
    if not path.is_file():
        raise FileNotFoundError(f"{path}, the best checkpoint that {folder / RECORD_FILE} records, is missing")
    if "sha256" in best and sha256(path) != best["sha256"]:
        raise UserError(f"{path} is not the checkpoint that {folder / RECORD_FILE} records (its checksum differs: "
                        "replaced or damaged); give the checkpoint file itself to use it anyway")
    return path


def load_run(path: Path | str) -> TrainedRun:
    """Load a run from its folder (its recorded best checkpoint) or from one of its checkpoints (CPU)."""
    path = Path(path).expanduser().resolve()
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist: give a hypa.train run folder or a .ckpt file")
    if path.is_file():
        checkpoint, folder = path, path.parent.parent if path.parent.name == "checkpoints" else path.parent
        info = read_record(folder)
    else:
        folder, info = path, read_record(path)
        checkpoint = recorded_checkpoint(folder, info)
    module = load_module(checkpoint)
    config = run_config(folder)
    trained, configured = module.hparams.model_config.get("name"), OmegaConf.select(config, "model.name")
    if configured is not None and trained != configured:
        raise UserError(f"{checkpoint} holds model {trained}, but its run folder {folder} trained model "
                        f"{configured}; give the run folder (or a checkpoint) of the run to evaluate")
    data_dir = Path(info["data_dir"]) if "data_dir" in info else None
    return TrainedRun(folder=folder, checkpoint=checkpoint, config=config, module=module, data_dir=data_dir,
                      info=info)


def run_config(folder: Path) -> DictConfig:
    """A run folder's configuration: the ``config.yaml`` that hypa.train wrote while it held the
    folder (Hydra's ``.hydra/config.yaml`` for runs of older versions). A broken file is one line."""
    config_file = folder / CONFIG_FILE
    if not config_file.is_file():
        config_file = folder / ".hydra" / "config.yaml"
    if not config_file.is_file():
        raise FileNotFoundError(f"{folder / CONFIG_FILE} is missing: {folder} is not a hypa.train run folder")
    try:
        config = OmegaConf.load(config_file)
    except Exception as error:  # YAML's scanner and parser errors, an unreadable byte
        raise UserError(f"{config_file}: not a readable run configuration ({one_line(error)[:200]}); "
                        "the run folder is damaged") from None
    if not isinstance(config, DictConfig) or not isinstance(config.get("data"), DictConfig):
        raise UserError(f"{config_file}: not a hypa.train run configuration (no data settings); the run folder "
                        "is damaged")
    return config


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
