"""A trained run (checkpoint + its configuration) and its windowed predictions on measured data.

Two ways to evaluate, as a simulation user needs both: windowed (``windowed``: N steps from
each measured initial state, exactly as in training) and free-running over a whole record
(``hypa.models.rollout.free_run``: the model starts from the record's first measured state and
never sees a measured state again).
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import OmegaConf

from hypa.core.errors import UserError, one_line
from hypa.core.metadata import sha256
from hypa.core.trust import check_links, has_interpolation, inside, read_yaml
from hypa.data import HypaDataModule
from hypa.models.rollout import Prediction, free_run, free_run_metrics, model_inputs  # their former home
from hypa.training import HybridModule
from hypa.training.checkpoints import load_module
from hypa.training.run_folder import CONFIG_FILE, RECORD_FILE, read_record

log = logging.getLogger(__name__)

class RunSettings(Mapping[str, Any]):
    """A run's recorded configuration (its ``config.yaml``), read as data: plain values, read-only,
    with the settings the readers use typed (:func:`run_config`)."""

    def __init__(self, values: Mapping[str, Any]) -> None:
        self._values = dict(values)

    def __getitem__(self, key: str) -> Any:
        return self._values[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def _at(self, path: str, kind: type) -> Any:
        node: Any = self._values
        for key in path.split("."):
            node = node.get(key) if isinstance(node, Mapping) else None
        return node if isinstance(node, kind) and not isinstance(node, bool) else None

    @property
    def data(self) -> Mapping[str, Any]:
        """The ``data`` node (channels, splits, window, past, ...)."""
        return self._values["data"]

    @property
    def model_name(self) -> str | None:
        return self._at("model.name", str)

    @property
    def seed(self) -> int | None:
        return self._at("seed", int)

    @property
    def max_epochs(self) -> int | None:
        """``trainer.max_epochs`` as the run resolved it (its default by data size filled in)."""
        return self._at("trainer.max_epochs", int)

    @property
    def table1_row(self) -> str | None:
        """The paper's Table 1 row the run trained for (``hypa reproduce``), if any."""
        return self._at("table1_row", str)


@dataclass
class TrainedRun:
    """A run folder of ``hypa train``: its best checkpoint and its recorded configuration."""

    folder: Path
    checkpoint: Path
    settings: RunSettings
    module: HybridModule
    data_dir: Path | None = None  # the resolved data folder the run was trained on (run.json)
    info: dict = field(default_factory=dict)  # the run's run.json (data checksums, versions; hypa.core.metadata)

    @property
    def config(self) -> RunSettings:
        """The former name of :attr:`settings` (one release, with a warning)."""
        import warnings

        warnings.warn("TrainedRun.config is TrainedRun.settings now", DeprecationWarning, stacklevel=2)
        return self.settings

    @property
    def label(self) -> str:
        """Table-1 style name: the model, with its network where it has one (``v1 lstm``)."""
        model = self.module.model
        has_ann = any(b.kind == "ann" for b in model.spec.blocks)
        return f"{model.spec.name} {self.module.hparams.ann_name}" if has_ann else model.spec.name


def recorded_checkpoint(folder: Path, record: dict) -> Path:
    """The best checkpoint that a run folder's ``run.json`` records, checked against its SHA-256.

    Never "the last ``best-*`` by name": a checkpoint that is not the recorded one (another run's,
    a damaged or replaced file) would be scored under this run's settings without a word. The
    record is data: its path must stay inside the folder (:func:`hypa.core.trust.inside`), and a record
    without a checksum is refused, with the way to take the file anyway (name it).
    """
    best = record.get("best_checkpoint")
    if not isinstance(best, dict) or "path" not in best:
        if not (folder / RECORD_FILE).is_file() and not (folder / "checkpoints").is_dir():
            raise FileNotFoundError(f"no checkpoint in {folder / 'checkpoints'} (is {folder} a hypa train run folder?)")
        raise UserError(f"{folder / RECORD_FILE} records no best checkpoint (a run of an older hypa, or one that "
                        f"stopped before its first validation); {_choice(folder)}")
    path = inside(folder, best["path"], f"{folder / RECORD_FILE}: best_checkpoint.path")
    if not path.is_file():
        raise FileNotFoundError(f"{path}, the best checkpoint that {folder / RECORD_FILE} records, is missing; "
                                f"{_choice(folder)}")
    checksum = best.get("sha256")
    if not isinstance(checksum, str):
        raise UserError(f"{folder / RECORD_FILE} records no checksum of {path.name}, so nothing shows that it is this "
                        f"run's checkpoint; to use it anyway, name the file itself: run='{path}'")
    if sha256(path) != checksum:
        raise UserError(f"{path} is not the checkpoint that {folder / RECORD_FILE} records (its checksum differs: "
                        "replaced or damaged); give the checkpoint file itself to use it anyway")
    return path


def _choice(folder: Path) -> str:
    """What to give instead: the folder's checkpoints, the newest first (a run killed while it replaced its
    best keeps the new one)."""
    checkpoints = folder / "checkpoints"
    files = sorted((p for p in checkpoints.glob("*.ckpt") if p.is_file() and not p.is_symlink()),
                   key=lambda p: p.stat().st_mtime, reverse=True) if checkpoints.is_dir() else []
    best = [p for p in files if p.name.startswith("best")]
    if best:
        return f"its newest best checkpoint is {best[0].name}: give run='{best[0]}' to evaluate it"
    if files:
        return f"give one of its checkpoints: run='{checkpoints}/<{' | '.join(p.name for p in files)}>'"
    return "it has no checkpoint"


def load_run(path: Path | str, trust: Collection[str] = ()) -> TrainedRun:
    """Load a run from its folder (its recorded best checkpoint) or from one of its checkpoints (CPU).

    The folder is data (:mod:`hypa.core.trust`): ``trust`` names the import paths (a user's system or
    network) its model may import."""
    path = Path(path).expanduser().absolute()
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist: give a hypa train run folder or a .ckpt file")
    if path.is_file():
        checkpoint, folder = path, path.parent.parent if path.parent.name == "checkpoints" else path.parent
        info = read_record(folder)
    else:
        folder, info = path, read_record(path)
        checkpoint = recorded_checkpoint(folder, info)
    module = load_module(checkpoint, trust)
    settings = run_config(folder)
    trained, configured = module.hparams.model_config.get("name"), settings.model_name
    if configured is not None and trained != configured:
        raise UserError(f"{checkpoint} holds model {trained}, but its run folder {folder} trained model "
                        f"{configured}; give the run folder (or a checkpoint) of the run to evaluate")
    data_dir = Path(info["data_dir"]) if isinstance(info.get("data_dir"), str) and info["data_dir"] else None
    return TrainedRun(folder=folder, checkpoint=checkpoint, settings=settings, module=module, data_dir=data_dir,
                      info=info)


def run_config(folder: Path) -> RunSettings:
    """A run folder's configuration: the ``config.yaml`` that hypa train wrote while it held the
    folder (Hydra's ``.hydra/config.yaml`` for runs of older versions), read as data
    (:func:`hypa.core.trust.read_yaml`: bounded, plain values, no aliases expanded, no interpolation
    resolved). A broken file is one line."""
    config_file = folder / CONFIG_FILE
    if not config_file.is_file():
        config_file = folder / ".hydra" / "config.yaml"
    if not config_file.is_file():
        raise FileNotFoundError(f"{folder / CONFIG_FILE} is missing: {folder} is not a hypa train run folder")
    check_links(config_file, folder)
    values = read_yaml(config_file, "run configuration")
    if not isinstance(values, dict) or not isinstance(values.get("data"), dict):
        raise UserError(f"{config_file}: not a hypa train run configuration (no data settings); the run folder "
                        "is damaged")
    if has_interpolation(values):
        raise UserError(f"{config_file}: holds an interpolation (${{...}}), which hypa train never writes there "
                        "(it records resolved values); the run folder is damaged or crafted")
    try:
        OmegaConf.create(values)  # what the readers' schemas take: keys and values OmegaConf can hold
    except Exception as error:  # noqa: BLE001 -- OmegaConf refuses a key or value it cannot hold
        raise UserError(f"{config_file}: not a readable run configuration ({one_line(error)[:200]}); "
                        "the run folder is damaged") from None
    return RunSettings(values)


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


__all__ = [
    "Prediction",
    "RunSettings",
    "TrainedRun",
    "free_run",
    "free_run_metrics",
    "load_run",
    "model_inputs",
    "recorded_checkpoint",
    "run_config",
    "windowed",
]
