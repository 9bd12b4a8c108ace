"""The schema of the ``data`` config node (``conf/dataset/*.yaml``), as Hydra structured configs.

Every dataset file starts from :class:`DataConfig` (``defaults: [/hypa/data_schema@data]``), so
Hydra rejects a misspelled key such as ``data.windw=50`` while composing, naming the key.
A channel declaration and a test piece are checked against :class:`ChannelConfig` and
:class:`PieceConfig` when the DataModule is built (:func:`hypa.data.from_config.validated`):
Hydra cannot add a typed dict entry from the command line (``+data.channels.x={...}``), so the
schema keeps ``channels`` and ``test`` open and the check happens one step later.

This module imports only dataclasses and OmegaConf. The commands' schemas type their ``data`` node
with :class:`DataConfig` too (:mod:`hypa.commands.config`, which registers this one beside them when
:mod:`hypa.commands` is imported, before any command composes its configuration).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from omegaconf import MISSING

SCHEMA_GROUP = "hypa"
SCHEMA_NAME = "data_schema"


@dataclass
class ChannelConfig:
    """One channel: its role, where it comes from (a column or an expression) and its units."""

    role: str = MISSING  # input | output | scheduling | evaluation | auxiliary
    column: str | None = None  # column in the files (default: the channel's name)
    unit: str = MISSING  # unit of the column / expression result ('-' dimensionless)
    display_unit: str | None = None  # unit in plots and tables (default: SI)
    expression: str | None = None  # derived channel, e.g. "arctan2(`vy(m/s)`, `vx(m/s)`)"


@dataclass
class TimeConfig:
    """The time base: a column (its offset removed) or none (samples at ``sample_rate_hz``)."""

    column: str | None = "time"
    unit: str = "s"


@dataclass
class PieceConfig:
    """A stretch of one file: ``start``/``stop`` an int sample index or a float fraction."""

    file: str = MISSING
    start: Any = None  # None: the first sample
    stop: Any = None  # None: after the last sample (exclusive)


@dataclass
class SplitsConfig:
    """Explicit splits; ``test`` is a list of pieces or a mapping test-set name -> pieces."""

    train: list[PieceConfig] = MISSING
    val: list[PieceConfig] = MISSING
    test: Any = None


@dataclass
class DataConfig:
    """The ``data`` node. ``source`` and ``dir`` are read by the entry point only."""

    source: str = "files"  # files | testbench
    dir: str | None = None
    time: TimeConfig = field(default_factory=TimeConfig)
    sample_rate_hz: float = MISSING  # [Hz] rate of the files
    rate_hz: float | None = None  # [Hz] model rate; None: no decimation
    channels: dict[str, Any] = field(default_factory=dict)  # name -> ChannelConfig
    splits: SplitsConfig | None = None  # None: train*, val*, test* files in dir
    select: list[str] = field(default_factory=list)  # conditions, e.g. "velocity > 5"
    units: dict[str, str] = field(default_factory=dict)  # the data set's own unit names -> pint definition
    window: int = 100  # predicted samples N per window
    past: int | None = None  # past samples P before the window start; null: as many as the model's estimated
    # starts want (hypa train, hypa diagnose, hypa simulate choose it and record it; 0 where no model is built)
    stride: int = 5
    eval_stride: int = 50
    batch_size: int = 32
    num_workers: int = 0
    seed: int = 0


def register_configs() -> None:
    """Store :class:`DataConfig` in Hydra's ConfigStore as ``/hypa/data_schema``."""
    from hydra.core.config_store import ConfigStore

    ConfigStore.instance().store(group=SCHEMA_GROUP, name=SCHEMA_NAME, node=DataConfig)
