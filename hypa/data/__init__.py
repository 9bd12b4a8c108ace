"""Measured data: declared channels -> files -> SI records -> pieces -> decimated -> selected
-> normalized windows.

One module per step: :mod:`expressions` and :mod:`channels` (what a channel is; its units are
:mod:`hypa.core.units`, shared with the physics), :mod:`files` (reading files as they are),
:mod:`io` (one file -> an SI record), :mod:`splits`,
:mod:`decimation`, :mod:`selection`, :mod:`dataset` (the steps in order), :mod:`records`,
:mod:`normalization`, :mod:`windows` and :mod:`datamodule` (the Lightning DataModule that ties
them together and gives a model its :mod:`signature`); :mod:`schema` and :mod:`from_config` meet
the configuration.

Names are imported lazily (PEP 562), so the data schema (:mod:`hypa.data.schema`, which
:func:`hypa.commands.config.register_configs` stores) is read without importing Lightning.
"""

from __future__ import annotations

from hypa.core.lazy import lazy_exports

_EXPORTS: dict[str, str] = {
    "ChannelSpec": "channels",
    "ROLES": "channels",
    "DataConfig": "schema",
    "ChannelConfig": "schema",
    "DataError": "errors",
    "DataSet": "records",
    "Record": "records",
    "SPLITS": "records",
    "Expression": "expressions",
    "HypaDataModule": "datamodule",
    "Normalization": "normalization",
    "DataSignature": "signature",
    "Piece": "splits",
    "SplitSpec": "splits",
    "Condition": "selection",
    "WindowDataset": "windows",
    "window_starts": "windows",
    "datamodule_from_config": "from_config",
    "decimate": "decimation",
    "decimate_time": "decimation",
    "decimation_factor": "decimation",
    "lowpass_taps": "decimation",
    "find_split_files": "files",
    "read_columns": "files",
    "read_metadata": "files",
    "load_record": "io",
    "load_dataset": "dataset",
    "KNOWN_UNITS": "hypa.core.units",
    "unit": "hypa.core.units",
    "unit_factor": "hypa.core.units",
}

__all__ = sorted(_EXPORTS)  # noqa: PLE0605 -- a list of the lazy exports' names


__getattr__, __dir__ = lazy_exports(__name__, globals(), _EXPORTS)
