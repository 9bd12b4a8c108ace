"""The one place where the data configuration (``conf/dataset/*.yaml``) meets typed code.

Entry points call :func:`datamodule_from_config`; everything below it takes typed arguments.
The node is checked against the schema (:mod:`hypa.data.schema`) first, so a misspelled key,
also inside a channel declaration or a split piece, is a :class:`DataError` naming the key and
the known ones, whether the node comes from Hydra, a plain YAML file or a run's stored config.
``source`` and ``dir`` are the entry point's business (it resolves the test bench's cache or
the user's folder into ``data_dir``) and are not read here.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from hypa.core.errors import UserError
from hypa.core.plugins import plugins
from hypa.core.units import define_units
from hypa.data.channels import ChannelSpec
from hypa.data.errors import DataError
from hypa.data.normalization import Normalization
from hypa.data.schema import ChannelConfig, DataConfig, PieceConfig
from hypa.data.splits import Piece, SplitSpec

log = logging.getLogger(__name__)



def data_sources() -> dict[str, Any]:
    """The data sources that make their files from their settings: ``data.source`` -> ``folder(settings)
    -> Path``, registered by the domain packages (the entry points ``hypa.data_sources``,
    :mod:`hypa.core.plugins`: the paper's test bench, ``dataset=testbench``)."""
    return plugins("data_sources")


def datamodule_from_config(
    data_cfg: DictConfig | Mapping[str, Any],
    data_dir: Path,
    normalization: Normalization | Mapping[str, Any] | None = None,
    auxiliary_inputs: bool = False,
    as_inputs: Sequence[str] = (),
):
    """Build the :class:`~hypa.data.HypaDataModule` from the ``data`` node and the resolved
    data folder (``normalization``: e.g. a checkpoint's, instead of fitting it; ``auxiliary_inputs``:
    every varying auxiliary channel held as an input too, for the diagnosis; ``as_inputs``: channels of
    the node declared inputs, as if the node said so, e.g. those a model reads, :func:`read_as_inputs`).
    The node itself is only read."""
    from hypa.data.datamodule import HypaDataModule

    cfg = validated(data_cfg)
    for name in as_inputs:
        if name not in cfg.channels:
            raise DataError(f"{name} is no channel of the data (data.channels has {', '.join(cfg.channels)})")
        cfg.channels[name].role = "input"
    define_units(dict(cfg.units or {}))  # before any channel's unit is read
    return HypaDataModule(
        data_dir=Path(data_dir),
        channels=channels_from_config(cfg.channels),
        time_column=cfg.time.column,
        time_unit=cfg.time.unit,
        sample_rate_hz=float(cfg.sample_rate_hz),
        rate_hz=None if cfg.rate_hz is None else float(cfg.rate_hz),
        splits=splits_from_config(cfg.splits),
        select=list(cfg.select),
        window=cfg.window,
        past=0 if cfg.past is None else cfg.past,  # null: chosen for a model (hypa.commands.entry.model_datamodule)
        stride=cfg.stride,
        eval_stride=cfg.eval_stride,
        batch_size=cfg.batch_size,
        num_workers=cfg.num_workers,
        normalization=normalization,
        seed=cfg.seed,
        auxiliary_inputs=auxiliary_inputs,
    )


def read_as_inputs(data_cfg: Any, model: Any) -> list[str]:
    """The auxiliary channels of the ``data`` node that a block of ``model`` (a parsed model, or its
    config as a dict) reads (a diagnosed model's ``unread_channel``): a channel the model reads is an
    input (:func:`datamodule_from_config`'s ``as_inputs``), and the run's recorded configuration says
    so, ``data.channels.NAME.role: input`` (so that evaluating or resuming the run builds the same
    data). The node itself is only read."""
    if isinstance(model, Mapping):
        read = {s for b in (model.get("blocks") or {}).values() if isinstance(b, Mapping)
                for s in (b.get("inputs") or ())}
    else:  # a ModelSpec (the data layer does not import the models: its blocks are read by their fields)
        read = {s for b in model.blocks for s in b.inputs}
    channels = data_cfg.get("channels") or {}
    return [str(n) for n, c in channels.items()
            if str(n) in read and isinstance(c, Mapping) and c.get("role") == "auxiliary"]


def validated(data_cfg: DictConfig | Mapping[str, Any]) -> DataConfig:
    """The node as a :class:`DataConfig` (resolved; interpolations such as ``${oc.env:...}``
    evaluated), or a :class:`DataError` naming the first bad key."""
    cfg = _typed(DataConfig, data_cfg, "data")
    cfg.channels = {
        str(name): _typed(ChannelConfig, node, f"data.channels.{name}")
        for name, node in (cfg.channels or {}).items()
    }
    return cfg


def channels_from_config(channels: Mapping[str, ChannelConfig]) -> list[ChannelSpec]:
    """Channel declarations -> :class:`ChannelSpec` (the YAML's ``unit`` is the file unit)."""
    return [
        ChannelSpec(name, c.role, c.unit, column=c.column, display_unit=c.display_unit,
                    expression=c.expression)
        for name, c in channels.items()
    ]


def splits_from_config(splits: Any) -> SplitSpec | None:
    """``data.splits`` -> :class:`SplitSpec` (``None``: the folder's train*/val*/test* files)."""
    if splits is None:
        return None
    train = [_piece(p, f"data.splits.train.{i}") for i, p in enumerate(splits.train)]
    val = [_piece(p, f"data.splits.val.{i}") for i, p in enumerate(splits.val)]
    test = splits.test
    if test is None:
        return SplitSpec.of(train, val)
    if isinstance(test, Mapping):
        named = {}
        for name, pieces in test.items():
            if not isinstance(pieces, (list, tuple)):
                raise DataError(f"data.splits.test.{name} must be a list of pieces, got {pieces!r}")
            named[str(name)] = [_piece(p, f"data.splits.test.{name}.{i}")
                                for i, p in enumerate(pieces)]
        return SplitSpec.of(train, val, named)
    if isinstance(test, (list, tuple)):
        pieces = [_piece(p, f"data.splits.test.{i}") for i, p in enumerate(test)]
        return SplitSpec.of(train, val, pieces)
    raise DataError(
        f"data.splits.test must be a list of pieces or a mapping test-set name -> pieces, "
        f"got {test!r}"
    )


def _piece(node: Any, where: str) -> Piece:
    piece = node if isinstance(node, PieceConfig) else _typed(PieceConfig, node, where)
    return Piece(piece.file, piece.start, piece.stop)


def _typed(schema: type, node: Any, where: str):
    """``node`` merged onto ``schema`` and converted to the dataclass; errors name the key."""
    if isinstance(node, DictConfig):
        node = OmegaConf.to_container(node, resolve=True)
    if dataclasses.is_dataclass(node):
        node = dataclasses.asdict(node)
    if not isinstance(node, Mapping):
        raise DataError(f"{where} must be a mapping of keys {_keys(schema)}, got {node!r}")
    try:
        merged = OmegaConf.merge(OmegaConf.structured(schema), node)
        return OmegaConf.to_object(merged)
    except OmegaConfBaseException as error:
        key = getattr(error, "full_key", None) or getattr(error, "key", None) or ""
        first = str(error).splitlines()[0] if str(error) else type(error).__name__
        name = f"{where}.{key}" if key else where
        if "not in" in first or type(error).__name__ == "ConfigKeyError":
            raise DataError(f"{name}: unknown key; {where} has the keys {_keys(schema)}") from None
        if type(error).__name__ == "MissingMandatoryValue":
            raise DataError(
                f"{name} is missing (required); {where} has the keys {_keys(schema)}"
            ) from None
        raise DataError(f"{name}: {first}") from None


def _keys(schema: type) -> str:
    return ", ".join(f.name for f in dataclasses.fields(schema))


def data_dir_from_config(cfg: DictConfig | Mapping[str, Any], cwd: Path | None = None) -> Path:
    """The folder of measured-data files for a command's configuration ``cfg``: its ``data`` node's
    ``dir`` (a relative folder taken from ``cwd``, where the command was run: the current directory
    by default), or, for a data source that makes its files (``data.source: testbench``), the
    folder it makes (or finds cached) from its own settings, the node of ``cfg`` named like it."""
    data = cfg["data"]
    source = data["source"]
    sources = data_sources() if source != "files" else {}
    if source in sources and data.get("dir") is not None:
        raise UserError(f"data.dir={data['dir']} is read only for measured files: add dataset=files (data.source="
                        f"{source} makes its own data)")
    if source in sources:  # a simulated source: its folder made (or found cached) from its settings
        return sources[source](cfg.get(source))
    if source == "files":
        if (OmegaConf.is_config(data) and OmegaConf.is_missing(data, "dir")) or data.get("dir") is None:
            raise UserError("the data set needs the folder of your files: data.dir=PATH (dataset=files, or a "
                            "dataset of your own)")
        folder = Path(str(data["dir"])).expanduser()
        return folder if folder.is_absolute() else (cwd or Path.cwd()) / folder
    raise UserError(
        f"unknown data.source {source!r}; use {' or '.join(['files', *data_sources()])} (dataset=testbench, "
        f"dataset=files data.dir=PATH, or a conf/dataset/*.yaml)"
    )
