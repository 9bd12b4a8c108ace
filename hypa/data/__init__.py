"""Measured data: files -> validated SI records -> anti-aliased decimation -> normalized windows.

The flow, one module per step: :mod:`channels` (standard names, units), :mod:`io` (reading
and validation), :mod:`decimation`, :mod:`records`, :mod:`normalization`, :mod:`windows`
and :mod:`datamodule` (the Lightning DataModule that ties them together).
"""

from hypa.data.channels import (
    DEFAULT_EVAL_CHANNELS,
    DEFAULT_INPUTS,
    DEFAULT_STATES,
    EVAL_ONLY_CHANNELS,
    KNOWN_UNITS,
    SI_UNITS,
    unit_factor,
)
from hypa.data.datamodule import HypaDataModule
from hypa.data.decimation import decimate, decimate_time, decimation_factor, lowpass_taps
from hypa.data.errors import DataError
from hypa.data.from_config import datamodule_from_config
from hypa.data.io import find_split_files, load_dataset, load_record, read_columns, read_metadata
from hypa.data.normalization import Normalization
from hypa.data.records import SPLITS, DataSet, Record
from hypa.data.windows import WindowDataset, window_starts

__all__ = [
    "DEFAULT_EVAL_CHANNELS",
    "DEFAULT_INPUTS",
    "DEFAULT_STATES",
    "EVAL_ONLY_CHANNELS",
    "KNOWN_UNITS",
    "SI_UNITS",
    "SPLITS",
    "DataError",
    "DataSet",
    "HypaDataModule",
    "Normalization",
    "Record",
    "WindowDataset",
    "datamodule_from_config",
    "decimate",
    "decimate_time",
    "decimation_factor",
    "find_split_files",
    "load_dataset",
    "load_record",
    "lowpass_taps",
    "read_columns",
    "read_metadata",
    "unit_factor",
    "window_starts",
]
