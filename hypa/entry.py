"""Glue for the Hydra entry points: configuration nodes -> typed objects.

Only entry points (``python -m hypa.*``) import this; everything below them takes typed
arguments, never a config object.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from hypa.data import HypaDataModule, datamodule_from_config
from hypa.errors import UserError
from hypa.vehicle import VehicleParameters

log = logging.getLogger(__name__)


def vehicle_from_config(node: DictConfig) -> VehicleParameters:
    """The nominal vehicle parameters (``vehicle`` group); unknown names are an error."""
    values = OmegaConf.to_container(node, resolve=True)
    unknown = set(values) - set(VehicleParameters.names())
    if unknown:
        raise UserError(
            f"unknown vehicle parameters {sorted(unknown)}; known: {', '.join(VehicleParameters.names())}"
        )
    try:
        return VehicleParameters(**{k: float(v) for k, v in values.items()})
    except ValueError as error:  # a value out of its range: vehicle.cf=-1
        raise UserError(str(error)) from None


def data_dir_from_config(cfg: DictConfig) -> Path:
    """The folder of measured-data files: the test bench's cache, or ``data.dir`` (a relative
    folder is taken from where the command was run, also when Hydra changed the directory)."""
    source = cfg.data.source
    if source == "testbench" and cfg.data.get("dir") is not None:
        raise UserError(f"data.dir={cfg.data.dir} is read only for measured files: add dataset=files (the default "
                        "data set is the simulated test bench)")
    if source == "testbench":
        from hypa.testbench import TestbenchConfig, ensure_dataset

        testbench = TestbenchConfig.from_hydra(cfg.get("testbench"))
        folder = ensure_dataset(testbench)
        log.info("test-bench data: %s", folder)
        return folder
    if source == "files":
        if OmegaConf.is_missing(cfg.data, "dir") or cfg.data.dir is None:
            from hydra.core.hydra_config import HydraConfig

            choice = HydraConfig.get().runtime.choices.get("dataset", "files") if HydraConfig.initialized() else "files"
            raise UserError(f"dataset={choice} needs the folder of your files: data.dir=PATH")
        folder = Path(str(cfg.data.dir)).expanduser()
        if not folder.is_absolute():
            folder = _original_cwd() / folder
        return folder
    raise UserError(
        f"unknown data.source {source!r}; use testbench or files (dataset=testbench, "
        f"dataset=files data.dir=PATH, or a conf/dataset/*.yaml)"
    )


def _original_cwd() -> Path:
    """Where the command was run: Hydra's original working directory inside a Hydra app."""
    from hydra.core.hydra_config import HydraConfig

    if HydraConfig.initialized():
        from hydra.utils import get_original_cwd

        return Path(get_original_cwd())
    return Path.cwd()


def datamodule(cfg: DictConfig) -> HypaDataModule:
    """Resolve the data folder and build the DataModule from the ``data`` node."""
    return datamodule_from_config(cfg.data, data_dir_from_config(cfg))


def data_overrides(overrides: Sequence[str]) -> list[str]:
    """The command-line overrides that choose the data and the vehicle (``dataset``, ``data``,
    ``testbench``, ``vehicle`` groups and their keys): what ``hypa.train`` needs to see the same data."""
    groups = ("dataset", "data", "testbench", "vehicle")
    return [o for o in overrides if o.lstrip("+~").split("=", 1)[0].split(".", 1)[0] in groups]


def user_config_dirs() -> list[Path]:
    """The folders given with ``--config-dir`` (a user's own datasets, models, systems' configs)."""
    from hydra.core.hydra_config import HydraConfig

    return [Path(s.path.removeprefix("file://")) for s in HydraConfig.get().runtime.config_sources
            if s.provider == "command-line" and s.schema == "file"]
