"""The one place where the data configuration (``conf/data/*.yaml``) meets typed code.

Entry points call :func:`datamodule_from_config`; everything below it takes typed
arguments. ``source`` and ``dir`` are the entry point's business (it resolves the test
bench cache or the user's folder into ``data_dir``) and are not read here.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from hypa.data.datamodule import HypaDataModule
from hypa.data.normalization import Normalization


def datamodule_from_config(
    data_cfg: DictConfig | Mapping[str, Any],
    data_dir: Path,
    normalization: Normalization | Mapping[str, Any] | None = None,
) -> HypaDataModule:
    """Build the DataModule from the ``data`` config group and the resolved data folder."""
    if isinstance(data_cfg, DictConfig):
        cfg = OmegaConf.to_container(data_cfg, resolve=True)
    else:
        cfg = dict(data_cfg)
    return HypaDataModule(
        data_dir=Path(data_dir),
        inputs=list(cfg["inputs"]),
        states=list(cfg["states"]),
        eval_channels=list(cfg.get("eval_channels") or []),
        columns=dict(cfg.get("columns") or {}),
        units=dict(cfg.get("units") or {}),
        sample_rate_hz=float(cfg["sample_rate_hz"]),
        rate_hz=float(cfg["rate_hz"]),
        window=int(cfg["window"]),
        stride=int(cfg["stride"]),
        eval_stride=int(cfg["eval_stride"]),
        batch_size=int(cfg["batch_size"]),
        num_workers=int(cfg.get("num_workers", 0)),
        normalization=normalization,
        seed=int(cfg.get("seed", 0)),
    )
